"""Battery current from the autopilot's telemetry: the input of the compass's motor-interference model.

``SYS_STATUS.current_battery`` and ``BATTERY_STATUS.current_battery`` are in
centiamperes, −1 when the autopilot does not measure it (MAVLink common
message set).  The current is held for :data:`CURRENT_STALE_S` after its
message; later it is unknown (NaN in the filter's ``IN_CURRENT``).  The
magnetometer model (:mod:`mavahrs.filters.magfield`) learns the compass's
field per ampere from it, as ArduPilot's ``COMPASS_MOT`` with
``COMPASS_MOTCT = 2`` does.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["CURRENT_MESSAGES", "CURRENT_STALE_S", "battery_current_a"]

#: the messages a battery current is read from
CURRENT_MESSAGES = ("SYS_STATUS", "BATTERY_STATUS")
#: a current older than this (s) is not used
CURRENT_STALE_S = 5.0
#: more than this (A) is taken for a corrupt field, not a current
_MAX_A = 500.0


def battery_current_a(msg: Any) -> float | None:
    """The battery current of a SYS_STATUS / BATTERY_STATUS message, A (None: not measured or implausible)."""
    try:
        raw = float(msg.current_battery)
    except (AttributeError, TypeError, ValueError):
        return None
    if raw == -1.0 or not math.isfinite(raw):
        return None
    amps = raw * 0.01
    if not (-_MAX_A <= amps <= _MAX_A):
        return None
    return amps
