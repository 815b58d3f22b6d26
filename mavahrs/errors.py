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
