"""The re-send step (mavahrs.ingest.resend): one compiled step per message, and the loop over a log.

Behaviour against known input — ArduPilot sending a message twice, a noiseless sensor repeating its
values under a new stamp, the same stamp with other values, NaN magnetometers, streams judged apart,
a reboot — checked on the step the pipeline calls (:class:`ResendFilter`) and on the loop replay runs
(:func:`resend_rows`), which must give the same verdicts on the same messages.  The pipeline's use of it
(``exact_duplicates``, ``same_stamp_changed``) is tested in ``tests/service/test_pipeline.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.filters.layout import IN_GYRO, IN_MAG, IN_WIDTH
from mavahrs.ingest.resend import (
    N_STREAMS,
    NEW,
    RESENT,
    RESTAMPED,
    ResendFilter,
    new_state,
    resend_rows,
    stream_code,
)

NAN = math.nan
V = (0.0, 0.001, 0.0, 0.0, 0.0, -9.80665, 20.0, 1.5, 45.0)
NO_MAG = (*V[:6], NAN, NAN, NAN)
RAW0, SCALED2_1, HIGHRES0 = stream_code("RAW_IMU", 0), stream_code("SCALED_IMU2", 1), stream_code("HIGHRES_IMU", 0)

#: (stream, stamp µs, values, verdict)
MESSAGES = [
    (RAW0, 1000, V, NEW),
    (RAW0, 1000, V, RESENT),  # same stamp, same values: the autopilot sent it twice
    (RAW0, 3500, V, NEW),  # new stamp, same values: a genuine sample (a noiseless sensor)
    (SCALED2_1, 3500, V, NEW),  # another stream is judged on its own
    (RAW0, 3500, (*V[:8], 46.0), RESTAMPED),  # same stamp, other values: passed on (the timeline drops it)
    (RAW0, 3500, (*V[:8], 46.0), RESENT),  # … and compared with those values from then on
    (HIGHRES0, 6000, NO_MAG, NEW),
    (HIGHRES0, 6000, NO_MAG, RESENT),  # NaN equals NaN: a missing magnetometer is still the same message
    (HIGHRES0, 6000, (*V[:6], NAN, NAN, 1.0), RESTAMPED),
    (RAW0, 1000, V, NEW),  # an older stamp is not a re-send (the timeline judges it)
    (RAW0, 1000, (-0.0, *V[1:]), RESENT),  # −0 equals 0: the same value
]


def _row(values: tuple[float, ...]) -> np.ndarray:
    row = np.full(IN_WIDTH, -7.0)
    row[IN_GYRO : IN_MAG + 3] = values
    return row


def test_the_step_per_message() -> None:
    rf = ResendFilter()
    got = [rf.check(k, t, _row(v)) for k, t, v, _ in MESSAGES]
    assert got == [want for *_, want in MESSAGES]
    assert (rf.resent, rf.restamped) == (4, 2)


def test_a_reboot_forgets_the_streams_and_keeps_the_counts() -> None:
    rf = ResendFilter()
    assert rf.check(RAW0, 3500, _row(V)) == NEW and rf.check(RAW0, 3500, _row(V)) == RESENT
    rf.reset()
    assert rf.check(RAW0, 3500, _row(V)) == NEW  # the new boot's first message
    assert (rf.resent, rf.restamped) == (1, 0)


def test_the_loop_over_a_log_gives_the_steps_verdicts() -> None:
    n = len(MESSAGES) + 2
    k = np.array([m[0] for m in MESSAGES] + [RAW0, RAW0], np.int64)
    t = np.array([m[1] for m in MESSAGES] + [1000, 1000], np.int64)
    vals = np.array([m[2] for m in MESSAGES] + [V, V])
    use = np.ones(n, bool)
    use[-2] = False  # not a sample (a HIGHRES_IMU without a new gyro): not looked at, and not remembered
    out = np.full(n, -1, np.int64)
    resend_rows(*new_state(), k, t, vals[:, 0:3], vals[:, 3:6], vals[:, 6:9], use, out)
    assert out.tolist() == [want for *_, want in MESSAGES] + [NEW, RESENT]


def test_streams_by_message_and_instance() -> None:
    codes = {stream_code(m, i) for m in ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
             for i in range(16)}  # fmt: skip
    assert codes == set(range(N_STREAMS))
    with pytest.raises(KeyError):
        stream_code("ATTITUDE", 0)


def test_a_time_usec_beyond_int64_is_compared_as_sent() -> None:
    rf = ResendFilter()
    big = 2**64 - 5
    assert rf.check(RAW0, big, _row(V)) == NEW and rf.check(RAW0, big, _row(V)) == RESENT
    assert rf.check(RAW0, big - 1, _row(V)) == NEW
