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

from mavahrs.replay.engine import (
    LOW_RATE_HZ,
    ComparisonRow,
    FilterTrack,
    ReplayInterrupted,
    ReplayResult,
    ReplaySettings,
    StreamSettings,
    attitude_at_reference,
    compare,
    csv_columns,
    format_comparison,
    format_second_opinion,
    format_velocity,
    gap_note,
    plot_replay,
    plot_second_opinion,
    replay,
    stream,
    write_tlog,
)

__all__ = [
    "ReplaySettings",
    "FilterTrack",
    "ReplayResult",
    "ComparisonRow",
    "replay",
    "format_second_opinion",
    "plot_second_opinion",
    "compare",
    "attitude_at_reference",
    "format_comparison",
    "format_velocity",
    "write_tlog",
    "plot_replay",
    "csv_columns",
    "LOW_RATE_HZ",
    "stream",
    "StreamSettings",
    "gap_note",
    "ReplayInterrupted",
]
