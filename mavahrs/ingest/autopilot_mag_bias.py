r"""The autopilot's magnetometer-bias estimate taken back out of its IMU message, from the raw field of a twin.

PX4's HIGHRES_IMU field is ``vehicle_magnetometer`` less EKF2's learnt ``mag_bias``
(``streams/HIGHRES_IMU.hpp``); SCALED_IMU's is ``sensor_mag`` instance 0 before PX4's calibration
(``streams/SCALED_IMU.hpp``, milligauss truncated to int16).  With the calibration applied
(:mod:`mavahrs.sensors.px4_mag_calibration`, from the ``CAL_MAG*`` parameters), SCALED_IMU's field less
HIGHRES_IMU's is EKF2's bias plus the two fields' different sampling (SCALED_IMU holds about half of the
readings ``vehicle_magnetometer`` averages: single pairs scatter 1–2 µT on the PX4 SIH flight; 20 s means
within ≈ 0.1 µT of EKF2's logged ``mag_bias``, docs/accuracy.md "PX4 heading, round eight").  Its running mean
added to every HIGHRES_IMU field gives the field as PX4 calibrated it, without EKF2's estimate:

    d_k = mean(cal(m_SCALED) since the previous field update) − m_HIGHRES,k
    b_k = b_{k-1} + α_k (d_k − b_{k-1}),   α_k = min(1, Δt_k / τ)      (the first ``min_pairs``: arithmetic mean)
    m_out = m_HIGHRES + b

(the running mean of :mod:`mavahrs.ingest.pair_mean`, as the gyro's step keeps).  The pairs are taken in
arrival order: the SCALED_IMU fields that arrived since the previous HIGHRES_IMU field update are averaged and
paired with the next update.

Bad input, each counted (:data:`COUNTER_NAMES`) and never written into a sample:

* no calibration (parameters not received, ambiguous or not modelled): SCALED_IMU's field is not used
  (``uncalibrated``) and HIGHRES_IMU passes as it is;
* a NaN/inf field, or a difference beyond ``max_bias_ut`` on an axis: no pair;
* a difference more than ``outlier_ut`` from the mean: an outlier, not used; ``min_pairs`` in a row (EKF2
  reset its bias) restart the mean from the new pairs;
* no pair for ``hold_s``: the mean is not applied, and the next pair starts it again;
* too many outliers (mean over τ above ``max_outlier_fraction``: another compass, a wrong calibration): not applied;
* the autopilot's clock going back (a reboot), or the calibration changing: the step starts again.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from mavahrs.filters.jit import kernel
from mavahrs.ingest.pair_mean import (
    C_APPLIED,
    C_BACK,
    C_BAD,
    C_NOT_APPLIED,
    C_PAIRS,
    C_SECOND,
    MEAN_LEN,
    P_HOLD_US,
    P_LEN,
    P_MAX_BIAS,
    P_MAX_FRAC,
    P_MIN_PAIRS,
    P_OUTLIER,
    P_TAU_US,
    S_B,
    clear_mean,
    counter_names,
    counter_values,
    mean_trusted,
    pair_mean_update,
    trusted_mean,
)

__all__ = [
    "COUNTER_NAMES",
    "MagBias",
    "new_state",
    "constants",
    "mag_pair_step",
    "mag_restore_step",
    "mag_restore_rows",
]

# constants: the running mean's (:mod:`mavahrs.ingest.pair_mean`), then the partner's half step
_P_HALF_STEP = P_LEN
_P_LEN = P_LEN + 1
# state: the running mean (:mod:`mavahrs.ingest.pair_mean`), then
_ACC = MEAN_LEN  # the sum of the calibrated partner fields waiting (3)
_ACC_N = MEAN_LEN + 3
_T_PRIMARY = MEAN_LEN + 4  # the newest primary stamp
_T_PARTNER = MEAN_LEN + 5  # the newest partner stamp
_C = MEAN_LEN + 6  # counters, in COUNTER_NAMES order
COUNTER_NAMES = counter_names("uncalibrated")
_C_UNCAL = C_SECOND  # this step's own counter
_LEN = _C + len(COUNTER_NAMES)
#: the calibration: offset (3, µT) then the 3×3 matrix row by row, applied as M · (m − o)
CAL_LEN = 12


def constants(settings, step_ut: float = 0.0, truncated: bool = False) -> NDArray[np.float64]:  # type: ignore[no-untyped-def]
    """The step's constants from ``settings`` (an ``AutopilotBiasSettings``; times in µs).

    ``step_ut``: the partner's field resolution (SCALED_IMU: 0.1 µT); ``truncated``: truncated toward zero
    (PX4's float → int16), so the middle of each reading's interval is used.
    """
    p = np.empty(_P_LEN)
    p[P_TAU_US] = settings.mag_time_constant_s * 1e6
    p[P_MIN_PAIRS] = settings.min_pairs
    p[P_HOLD_US] = settings.hold_s * 1e6
    p[P_MAX_BIAS] = settings.mag_max_bias_ut
    p[P_OUTLIER] = settings.mag_outlier_ut
    p[P_MAX_FRAC] = settings.max_outlier_fraction
    p[_P_HALF_STEP] = 0.5 * step_ut if truncated else 0.0
    return p


def new_state() -> NDArray[np.float64]:
    """Empty state (counters at 0)."""
    st = np.zeros(_LEN)
    _clear(st)
    return st


@kernel
def _clear(st):  # type: ignore[no-untyped-def]
    """Forget the mean and the waiting fields (the counters stay)."""
    clear_mean(st)
    st[_ACC] = st[_ACC + 1] = st[_ACC + 2] = 0.0
    st[_ACC_N] = 0.0
    st[_T_PRIMARY] = -math.inf
    st[_T_PARTNER] = -math.inf


@kernel
def mag_pair_step(st, p, cal, t_us, m0, m1, m2):  # type: ignore[no-untyped-def]
    """A partner message's raw field (PX4 SCALED_IMU, µT) stamped ``t_us``; ``cal`` (:data:`CAL_LEN`) the
    calibration, its first value NaN when there is none.  The calibrated field waits for the next primary update."""
    if not (abs(m0) < math.inf and abs(m1) < math.inf and abs(m2) < math.inf):  # NaN fails too
        st[_C + C_BAD] += 1.0
        return
    if not (cal[0] == cal[0]):
        st[_C + _C_UNCAL] += 1.0
        return
    if t_us < st[_T_PARTNER] - p[P_HOLD_US]:  # the autopilot's clock went back: a reboot
        st[_C + C_BACK] += 1.0
        _clear(st)
    if t_us > st[_T_PARTNER]:
        st[_T_PARTNER] = t_us
    h = p[_P_HALF_STEP]  # truncated toward zero: the middle of the reading's interval
    m0 += h if m0 > 0.0 else (-h if m0 < 0.0 else 0.0)
    m1 += h if m1 > 0.0 else (-h if m1 < 0.0 else 0.0)
    m2 += h if m2 > 0.0 else (-h if m2 < 0.0 else 0.0)
    x0, x1, x2 = m0 - cal[0], m1 - cal[1], m2 - cal[2]
    st[_ACC] += cal[3] * x0 + cal[4] * x1 + cal[5] * x2
    st[_ACC + 1] += cal[6] * x0 + cal[7] * x1 + cal[8] * x2
    st[_ACC + 2] += cal[9] * x0 + cal[10] * x1 + cal[11] * x2
    st[_ACC_N] += 1.0


@kernel
def _restore(st, p, t_us, mag, j):  # type: ignore[no-untyped-def]
    m0, m1, m2 = mag[j], mag[j + 1], mag[j + 2]
    if not (abs(m0) < math.inf and abs(m1) < math.inf and abs(m2) < math.inf):  # no new field in this message
        return 0
    if t_us < st[_T_PRIMARY] - p[P_HOLD_US]:  # the autopilot's clock went back: a reboot
        st[_C + C_BACK] += 1.0
        _clear(st)
    if t_us > st[_T_PRIMARY]:
        st[_T_PRIMARY] = t_us
    applies = mean_trusted(st, p, t_us)
    b0, b1, b2 = st[S_B], st[S_B + 1], st[S_B + 2]  # the mean as it stood before this update's own pair
    k = st[_ACC_N]
    if k > 0.0:
        pair_mean_update(st, p, _C, t_us, st[_ACC] / k - m0, st[_ACC + 1] / k - m1, st[_ACC + 2] / k - m2)
        st[_ACC] = st[_ACC + 1] = st[_ACC + 2] = 0.0
        st[_ACC_N] = 0.0
    if applies:
        mag[j] = m0 + b0
        mag[j + 1] = m1 + b1
        mag[j + 2] = m2 + b2
        st[_C + C_APPLIED] += 1.0
        return 1
    if st[_C + C_PAIRS] > 0.0 or st[_C + _C_UNCAL] > 0.0:  # a twin stream was seen: say the field went uncorrected
        st[_C + C_NOT_APPLIED] += 1.0
    return 0


@kernel
def mag_restore_step(st, p, t_us, row, j):  # type: ignore[no-untyped-def]
    """A primary message (PX4 HIGHRES_IMU) stamped ``t_us``, its field (µT; NaN = none new) in ``row[j : j + 3]``.

    Pairs it with the partner fields that arrived since the previous update, then, while the mean is trusted,
    adds the mean (as it stood before this pair) in place.  Returns 1 when added, 0 when left as it came."""
    return _restore(st, p, t_us, row, j)


@kernel
def mag_restore_rows(st, p, cals, cal_index, role, t_us, mag, applied):  # type: ignore[no-untyped-def]
    """:func:`mag_pair_step` / :func:`mag_restore_step` over a log's merged messages in their order.

    ``cals``: (K, :data:`CAL_LEN`) the calibrations the log's parameters gave in turn (a row of NaN: none);
    ``cal_index``: (N,) the row known at each message (a change restarts the step, as
    :meth:`MagBias.set_calibration` does); ``role``: (N,) 1 primary, 2 partner, 0 neither; ``mag``: (N, 3) µT,
    the primary's corrected in place; ``applied[i]``: 1 where added.
    """
    last = -1
    for i in range(t_us.shape[0]):
        applied[i] = 0
        c = cal_index[i]
        if c != last:
            if last >= 0:
                _clear(st)
            last = c
        if role[i] == 1:
            applied[i] = _restore(st, p, t_us[i], mag[i], 0)
        elif role[i] == 2:
            mag_pair_step(st, p, cals[c], t_us[i], mag[i, 0], mag[i, 1], mag[i, 2])


class MagBias:
    """The step with its state and the calibration, for one link (the pipeline's): see the module doc."""

    __slots__ = ("_st", "_p", "_cal")

    def __init__(self, settings, step_ut: float = 0.0, truncated: bool = False) -> None:  # type: ignore[no-untyped-def]
        self._st = new_state()
        self._p = constants(settings, step_ut, truncated)
        self._cal = np.full(CAL_LEN, np.nan)

    def reset(self) -> None:
        """Forget the mean (an autopilot reboot); the calibration and the counts are kept."""
        _clear(self._st)

    def set_calibration(self, cal: NDArray[np.float64] | None) -> None:
        """The calibration (:data:`CAL_LEN` values) or None; a change restarts the mean."""
        new = np.full(CAL_LEN, np.nan) if cal is None else np.asarray(cal, np.float64).reshape(CAL_LEN)
        if not np.array_equal(new, self._cal, equal_nan=True):
            self._cal = new
            _clear(self._st)

    @property
    def calibrated(self) -> bool:
        return bool(self._cal[0] == self._cal[0])

    def pair(self, t_us: int, m0: float, m1: float, m2: float) -> None:
        """A partner message's raw field (µT)."""
        mag_pair_step(self._st, self._p, self._cal, float(t_us), m0, m1, m2)

    def restore(self, t_us: int, row: NDArray[np.float64], j: int) -> bool:
        """A primary message's field in ``row[j : j + 3]``, corrected in place; True when the mean was added."""
        return bool(mag_restore_step(self._st, self._p, float(t_us), row, j))

    @property
    def bias_ut(self) -> tuple[float, float, float] | None:
        """The mean being added (µT; the autopilot's bias is its negative), or None while none is trusted."""
        return trusted_mean(self._st, self._p, self._st[_T_PRIMARY])

    @property
    def counts(self) -> dict[str, int]:
        """The counters (:data:`COUNTER_NAMES`) since the start."""
        return counter_values(self._st, _C, COUNTER_NAMES)
