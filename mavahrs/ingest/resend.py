r"""Re-send dropping: a message with the same stamp *and* the same values as the previous one of its stream.

ArduPilot at ``SCHED_LOOP_RATE`` 800 keeps a 400 Hz request as a 2 ms
interval, and its 400 Hz telemetry task catches up by sending RAW_IMU twice in
one pass (about one message in four): the second copy is the autopilot
sending the sample again, not a sample.  It is dropped and counted, never
warned about.  A new stamp with the same values is a genuine sample (a
noiseless sensor in a steady state) and is kept; the same stamp with
*different* values is counted and passed on (the timeline then drops it as
``stale``).  Values are compared exactly, NaN equal to NaN (a missing
magnetometer is still the same message).

The step comes first in the sample chain, right after scaling, for every
message of every IMU instance (before the IMU selector).  It is one compiled
function, :func:`resend_row`, on state in plain arrays (:func:`new_state`):
the live pipeline calls it per message through :class:`ResendFilter` (on the
row the scaling step has just written), and replay runs :func:`resend_rows`,
the same step in a compiled loop over a log's messages.

A *stream* is an integer the caller chooses, below the state's size; the pipeline and
replay both use :func:`stream_code` (the message type's position in
:data:`~mavahrs.sensors.profiles.IMU_MESSAGES` and the IMU instance).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mavahrs.filters.jit import kernel
from mavahrs.filters.layout import IN_ACCEL, IN_GYRO, IN_MAG
from mavahrs.sensors.profiles import IMU_MESSAGES

__all__ = [
    "NEW",
    "RESENT",
    "RESTAMPED",
    "N_STREAMS",
    "stream_code",
    "new_state",
    "resend_row",
    "resend_rows",
    "ResendFilter",
]

#: :func:`resend_row`'s verdicts: a new sample, an exact re-send (drop it), the previous stamp with new values
NEW, RESENT, RESTAMPED = 0, 1, 2
#: instances per message type in :func:`stream_code` (RAW_IMU / HIGHRES_IMU ``id`` is below 16)
_INSTANCES = 16
#: streams a default state holds: every IMU message type × every instance
N_STREAMS = len(IMU_MESSAGES) * _INSTANCES
#: ``last_t`` of a stream not seen yet (no stamp equals it: stamps are ≥ 0)
_NONE = np.iinfo(np.int64).min
_INT64_END = 1 << 63
_MESSAGE_INDEX = {name: i for i, name in enumerate(IMU_MESSAGES)}


def stream_code(message: str, imu_id: int) -> int:
    """The stream of an IMU message type (one of :data:`~mavahrs.sensors.profiles.IMU_MESSAGES`) and instance."""
    return _MESSAGE_INDEX[message] * _INSTANCES + imu_id


def new_state(n_streams: int = N_STREAMS) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Empty state for ``n_streams`` streams: (last stamp per stream, its 9 values: gyro, accel, mag)."""
    return np.full(n_streams, _NONE, np.int64), np.zeros((n_streams, 9))


@kernel
def _resend(last_t, last_v, k, t, g0, g1, g2, a0, a1, a2, m0, m1, m2):  # type: ignore[no-untyped-def]
    """The step on one message's values (see :func:`resend_row`)."""
    v = last_v[k]
    same = True
    for j, x in enumerate((g0, g1, g2, a0, a1, a2, m0, m1, m2)):
        y = v[j]
        if not (x == y or (x != x and y != y)):
            same = False
        v[j] = x
    prev = last_t[k]
    last_t[k] = t
    if prev != t:
        return NEW
    return RESENT if same else RESTAMPED


@kernel
def resend_row(last_t, last_v, k, t, row):  # type: ignore[no-untyped-def]
    """The re-send step for one message of stream ``k`` stamped ``t`` (µs, as sent), its scaled values in ``row``.

    ``row`` is a filter input row (:mod:`mavahrs.filters.layout`) with the
    gyro, accelerometer and magnetometer columns written by the scaling step.
    Returns :data:`NEW`, :data:`RESENT` (drop it) or :data:`RESTAMPED`; the
    stream's stamp and values become this message's.
    """
    return _resend(last_t, last_v, k, t, row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2], row[IN_ACCEL],
                   row[IN_ACCEL + 1], row[IN_ACCEL + 2], row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2])  # fmt: skip


@kernel
def resend_rows(last_t, last_v, k, t, gyro, accel, mag, use, out):  # type: ignore[no-untyped-def]
    """:func:`resend_row` over a log's messages in order: ``out[i]`` its verdict (:data:`NEW` where not ``use``).

    ``k``, ``t``: (N,) stream and stamp of each message; ``gyro``, ``accel``,
    ``mag``: (N, 3) its scaled values; ``use``: (N,) whether it is a sample
    (a HIGHRES_IMU without a new gyro is not, and is not looked at).
    """
    for i in range(t.shape[0]):
        if use[i]:
            out[i] = _resend(last_t, last_v, k[i], t[i], gyro[i, 0], gyro[i, 1], gyro[i, 2], accel[i, 0],
                             accel[i, 1], accel[i, 2], mag[i, 0], mag[i, 1], mag[i, 2])  # fmt: skip
        else:
            out[i] = NEW


class ResendFilter:
    """:func:`resend_row` with its state, for one link (the pipeline's), and the counts.

    Attributes:
        resent: messages found to be exact re-sends (to drop).
        restamped: messages with the previous one's stamp but different values
            (a fault of the sender; passed on, the timeline drops them as ``stale``).
    """

    __slots__ = ("_last_t", "_last_v", "resent", "restamped")

    def __init__(self, n_streams: int = N_STREAMS) -> None:
        self._last_t, self._last_v = new_state(n_streams)
        self.resent = 0
        self.restamped = 0

    def reset(self) -> None:
        """Forget the streams (an autopilot reboot); the counts are kept."""
        self._last_t[:] = _NONE

    def check(self, stream: int, t_raw_us: int, row: NDArray[np.float64]) -> int:
        """``NEW``, ``RESENT`` (drop it) or ``RESTAMPED`` for one message (values in ``row``, see :func:`resend_row`)."""
        if t_raw_us >= _INT64_END:  # a uint64 time_usec beyond int64: the same bits, signed (equal stays equal)
            t_raw_us -= 1 << 64
        r: int = resend_row(self._last_t, self._last_v, stream, t_raw_us, row)
        if r:
            if r == RESENT:
                self.resent += 1
            else:
                self.restamped += 1
        return r
