"""mavahrs — attitude estimation beside a MAVLink autopilot.

Public API (kept stable):

* :func:`estimate` — a whole recording to (N, 4) ``q_body_to_ned``;
* :mod:`mavahrs.filters` — ``create(name)``, ``NAMES``, per-sample filters;
* :mod:`mavahrs.geometry` — quaternion, rotation and frame functions.

Conventions: scalar-first Hamilton quaternions rotating body vectors into NED;
SI units (rad/s, m/s², µT, s).
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

__all__ = ["__version__", "estimate"]


def estimate(*args: Any, **kwargs: Any) -> Any:
    """See :func:`mavahrs.api.estimate` (imported lazily to keep start-up fast)."""
    from mavahrs.api import estimate as _estimate

    return _estimate(*args, **kwargs)


estimate.__doc__ = (estimate.__doc__ or "") + "\n\n" + "Wraps mavahrs.api.estimate."
