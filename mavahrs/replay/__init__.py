"""Replay: a flight log through the filters exactly as the daemon would have run them.

The engine users run (``mavahrs replay``, ``plot``, ``audit``): a log read by
:mod:`mavahrs.logs` (any format, by content) or, for a tlog, through the daemon's
own decoding (:mod:`mavahrs.evaluation.tlogdata`), then the filters, then the
outputs — per-sample CSV, a tlog with ATTITUDE_QUATERNION, a plot, a live stream
to a ground station — and the comparison with the attitudes the log holds.
Everything lives in :mod:`mavahrs.replay.engine`; this package hands its public
names on.  Evaluation against ground truth (metrics, alignment, studies) is
:mod:`mavahrs.evaluation`, which never imports replay.
"""

from __future__ import annotations

# the public names are engine's own list (one list: a name added there is handed on here)
from mavahrs.replay.engine import *  # noqa: F403
from mavahrs.replay.engine import __all__ as __all__
