"""Exceptions raised by mavahrs library code.

Each carries a message a user can act on (what, which field or value, what to
do).  The service layer catches them per message, counts and logs them.
"""

from __future__ import annotations

__all__ = [
    "MavahrsError",
    "ConfigError",
    "DecodeError",
    "ScalingError",
    "TimestampError",
    "TransportError",
    "DataError",
    "empty_window_error",
]


class MavahrsError(Exception):
    """Base of every mavahrs error."""


class ConfigError(MavahrsError, ValueError):
    """A setting, option or configuration file is invalid."""


class DecodeError(MavahrsError):
    """Bytes could not be decoded as MAVLink."""


class ScalingError(MavahrsError, ValueError):
    """A message's fields cannot be turned into an SI sample."""


class TimestampError(MavahrsError):
    """A timestamp is unusable (non-monotonic beyond recovery, missing)."""


class TransportError(MavahrsError, OSError):
    """A connection could not be opened or was lost."""


class DataError(MavahrsError, ValueError):
    """An input file (recording, dataset) is malformed or missing data."""


def empty_window_error(path: object, start_s: float | None, end_s: float | None,
                       first_s: float, last_s: float) -> DataError:  # fmt: skip
    """No IMU sample within ``--start``/``--end``: the window asked for and where the log's IMU data are
    (``first_s``/``last_s``: seconds from the log's start, as the window counts), one wording for every reader."""
    if start_s is not None and end_s is not None:
        window = f"between {start_s:g} and {end_s:g} s"
    elif start_s is not None:
        window = f"from {start_s:g} s"
    else:
        window = f"up to {end_s:g} s"
    return DataError(f"{path}: no IMU samples {window} after the log's start (--start/--end); its IMU data "
                     f"span {first_s:.1f}–{last_s:.1f} s")
