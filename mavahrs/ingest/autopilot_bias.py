r"""The autopilot's gyro-bias estimate taken back out of its IMU message, from a bias-free twin message.

PX4 subtracts EKF2's gyro-bias estimate from HIGHRES_IMU (``streams/HIGHRES_IMU.hpp``:
``vehicle_imu`` − ``estimator_sensor_bias``), but not from SCALED_IMU (``streams/SCALED_IMU.hpp``:
the same calibrated ``vehicle_imu``, in mrad/s).  An attitude computed from HIGHRES_IMU therefore
follows EKF2's bias, and is no independent second opinion of it.  When the stream also carries
SCALED_IMU of the same IMU, each SCALED_IMU less the HIGHRES_IMU of the same ``vehicle_imu`` sample
is EKF2's bias (within SCALED_IMU's 1 mrad/s steps; measured within 0.01 °/s of EKF2's logged
``estimator_sensor_bias`` over the PX4 SIH flight, docs/accuracy.md "PX4 calm heading, round five"),
and adding its running mean back to every HIGHRES_IMU gives the gyro as the sensor measured it
(PX4 truncates SCALED_IMU toward zero, a reading n mrad/s meaning [n, n + 1) for n > 0: measured on
the SIH tlog, −0.43 / +0.40 mrad/s mean residual for n > 0 / n < 0; the middle of that interval is
taken, else a steady rate of one sign leaves up to 0.5 mrad/s in the mean):

    b_k = b_{k-1} + α_k (d_k − b_{k-1}),   d_k = ω_SCALED(t_s) − ω_HIGHRES(t_h),   α_k = min(1, Δt_k / τ)
    ω_out = ω_HIGHRES + b

(an exponential mean of time constant τ over the pairs; its first ``min_pairs`` pairs an arithmetic
mean).  The pair: SCALED_IMU's ``time_boot_ms`` is the publication time truncated to the
millisecond, HIGHRES_IMU's ``time_usec`` the sample time, so the HIGHRES_IMU of the same sample is
the latest one stamped before ``t_s`` + 1 ms, and at most ``max_pair_lag_s`` before it.  A pair
is decided once a HIGHRES_IMU stamped at or after ``t_s`` + 1 ms has arrived (the two streams may
arrive in either order).

Bad input, each counted (:data:`COUNTER_NAMES`) and never written into a sample:

* a NaN/inf value, or a difference beyond ``max_bias_rad_s`` (EKF2_GYR_B_LIM): not a pair;
* no HIGHRES_IMU within ``max_pair_lag_s`` (a lost message): not a pair;
* a difference more than ``outlier_rad_s`` from the mean (a mismatched sample): an outlier, not used;
  ``min_pairs`` outliers in a row (EKF2 reset its bias) restart the mean from the new pairs;
* SCALED_IMU missing, late or too slow: the mean is applied while its last pair is at most
  ``hold_s`` old, and only once ``min_pairs`` pairs made it; otherwise HIGHRES_IMU passes as it is
  (today's behaviour) — so without SCALED_IMU nothing changes;
* the autopilot's clock going back (a reboot): the step starts again;
* SCALED_IMU from another IMU than HIGHRES_IMU's: its differences scatter beyond the outlier gate,
  the outlier rate (mean over τ) exceeds ``max_outlier_fraction`` and nothing is applied.

While HIGHRES_IMU is arriving, SCALED_IMU serves only this step (it is not a second carrier of
the instance for the IMU selector; :func:`bias_pair_step` says so); without HIGHRES_IMU for
``hold_s`` it is an ordinary IMU message again.

The running mean, its outlier gate and restarts are :mod:`mavahrs.ingest.pair_mean`'s (the magnetometer's
step, :mod:`mavahrs.ingest.autopilot_mag_bias`, keeps the same).  One compiled step per message on state in plain arrays (:func:`new_state`, :func:`constants`):
the live pipeline calls :func:`bias_pair_step` / :func:`bias_restore_step` per message through
:class:`AutopilotBias`, replay runs :func:`bias_restore_rows`, the same steps over a log's merged
messages in their order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import ConfigError
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
    S_N,
    clear_mean,
    counter_names,
    counter_values,
    mean_trusted,
    pair_mean_update,
    trusted_mean,
)

__all__ = [
    "AutopilotBiasSettings",
    "AutopilotBias",
    "COUNTER_NAMES",
    "ROLE_NONE",
    "ROLE_PRIMARY",
    "ROLE_PARTNER",
    "new_state",
    "constants",
    "bias_pair_step",
    "bias_restore_step",
    "bias_restore_rows",
]


@dataclass(frozen=True)
class AutopilotBiasSettings:
    """Taking the autopilot's gyro-bias estimate back out of its IMU message (PX4: HIGHRES_IMU, from SCALED_IMU).

    Applies where the autopilot profile names a bias-free twin of its primary IMU message
    (``AutopilotProfile.bias_free_message``: PX4's SCALED_IMU beside HIGHRES_IMU); elsewhere, and while
    the stream carries no twin, nothing changes.

    Attributes:
        enabled: recover the bias and add it back (default on: an estimate independent of the
            autopilot's EKF; on the PX4 SIH tlog hover heading 1.07 → 0.75°).
        time_constant_s: τ of the running mean of the pair differences, s (EKF2's bias moves over tens
            of seconds; one pair scatters by SCALED_IMU's 1 mrad/s steps).
        min_pairs: pairs needed before the mean is applied; also the outliers in a row that restart it.
        max_pair_lag_s: the HIGHRES_IMU of a pair is at most this before SCALED_IMU's stamp + 1 ms, s.
        hold_s: the mean is applied while its last pair is at most this old (HIGHRES_IMU's clock), s;
            SCALED_IMU is also a carrier of the IMU again after this long without HIGHRES_IMU.
        max_bias_rad_s: a difference beyond this on any axis is no bias (EKF2_GYR_B_LIM, 0.15 rad/s).
        outlier_rad_s: a difference further than this from the mean on any axis is an outlier, rad/s.
        max_outlier_fraction: the mean is not applied while the outliers' share (mean over τ) exceeds
            this (SCALED_IMU not of HIGHRES_IMU's IMU).
        request_rate_hz: the rate to ask the autopilot for the twin message at, Hz (0 = do not ask).
        mag_enabled: also take the autopilot's magnetometer bias back out of the primary message's field, from
            the twin's raw field with the autopilot's calibration (PX4: EKF2's ``mag_bias`` from HIGHRES_IMU, with
            SCALED_IMU and ``CAL_MAG*``, requested by PARAM_REQUEST_READ; :mod:`mavahrs.ingest.autopilot_mag_bias`);
            only while ``enabled`` and the calibration is known and modelled (on the PX4 SIH tlog `mavahrs evaluate` heading
            1.00 → 0.76°).
        mag_time_constant_s: τ of the running mean of the field pairs, s (a pair scatters by 1–2 µT; EKF2 learns
            its bias in tens of seconds).
        mag_max_bias_ut: a field difference beyond this on any axis is no bias, µT (EKF2's limit: 0.5 gauss).
        mag_outlier_ut: a field difference further than this from the mean on any axis is an outlier, µT.
    """

    enabled: bool = True
    time_constant_s: float = 2.0
    min_pairs: int = 25
    max_pair_lag_s: float = 0.006
    hold_s: float = 5.0
    max_bias_rad_s: float = 0.15
    outlier_rad_s: float = 0.01
    max_outlier_fraction: float = 0.2
    request_rate_hz: float = 50.0
    mag_enabled: bool = True
    mag_time_constant_s: float = 5.0
    mag_max_bias_ut: float = 50.0
    mag_outlier_ut: float = 10.0

    def __post_init__(self) -> None:
        for name in ("time_constant_s", "max_pair_lag_s", "hold_s", "max_bias_rad_s", "outlier_rad_s",
                     "mag_time_constant_s", "mag_max_bias_ut", "mag_outlier_ut"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"autopilot_bias.{name} must be a positive number, got {v!r}")
        if not (isinstance(self.min_pairs, int) and self.min_pairs >= 1):
            raise ConfigError(f"autopilot_bias.min_pairs must be an integer ≥ 1, got {self.min_pairs!r}")
        if not 0.0 < self.max_outlier_fraction <= 1.0:
            raise ConfigError(f"autopilot_bias.max_outlier_fraction must be in (0, 1], got {self.max_outlier_fraction!r}")
        if not (math.isfinite(self.request_rate_hz) and self.request_rate_hz >= 0):
            raise ConfigError(f"autopilot_bias.request_rate_hz must be ≥ 0 Hz, got {self.request_rate_hz!r}")


#: role of a message in :func:`bias_restore_rows`
ROLE_NONE, ROLE_PRIMARY, ROLE_PARTNER = 0, 1, 2

# constants (:func:`constants`): the running mean's (:mod:`mavahrs.ingest.pair_mean`), then the pair's lag and
# the partner's half step
_P_LAG_US = P_LEN
_P_HALF_STEP = P_LEN + 1
_P_LEN = P_LEN + 2
# state: the running mean (:mod:`mavahrs.ingest.pair_mean`: the mean, its pair count, the last pair's time, the
# outlier rate, outliers in a row), then the stamps, the counters, a ring of the last HIGHRES_IMU samples (t, gyro)
# and the SCALED_IMU samples waiting for their pair
_T_PRIMARY = MEAN_LEN  # the newest primary stamp seen (−inf: none)
_T_PARTNER = MEAN_LEN + 1  # the newest partner stamp seen
_T_FIRST = MEAN_LEN + 2  # the first partner stamp since the start (the primary's grace period runs from it)
_C = MEAN_LEN + 3  # counters, in COUNTER_NAMES order
COUNTER_NAMES = counter_names("unpaired")
_C_UNPAIRED = C_SECOND  # this step's own counter
_RING = _C + len(COUNTER_NAMES)
_RING_N = 16  # HIGHRES_IMU samples kept (64 ms at 250 Hz)
_HEAD = _RING + 4 * _RING_N  # next slot to write
_PEND = _HEAD + 1
_PEND_N = 8  # SCALED_IMU samples waiting
_PEND_COUNT = _PEND + 4 * _PEND_N
_LEN = _PEND_COUNT + 1
_TRUNC_US = 1000.0  # SCALED_IMU's time_boot_ms: the publication time truncated to the millisecond
#: before any primary message, the partner waits this long (from its first sample) for one before it is
#: an ordinary IMU message: at a start it may come first, and would otherwise carry the instance
_GRACE_US = 1.0e6


def constants(settings: AutopilotBiasSettings, step_rad_s: float = 0.0, truncated: bool = False) -> NDArray[np.float64]:
    """The step's constants from ``settings`` (times in µs).

    ``step_rad_s``: the partner's gyro resolution (SCALED_IMU: 1 mrad/s); ``truncated``: its values are
    truncated toward zero (a C float → int16 cast, as PX4's ``streams/SCALED_IMU.hpp`` does), so each
    reading n stands for [n, n + 1) steps (n > 0) or (n − 1, n] (n < 0): its middle is used.
    """
    p = np.empty(_P_LEN)
    p[_P_HALF_STEP] = 0.5 * step_rad_s if truncated else 0.0
    p[P_TAU_US] = settings.time_constant_s * 1e6
    p[P_MIN_PAIRS] = settings.min_pairs
    p[_P_LAG_US] = settings.max_pair_lag_s * 1e6
    p[P_HOLD_US] = settings.hold_s * 1e6
    p[P_MAX_BIAS] = settings.max_bias_rad_s
    p[P_OUTLIER] = settings.outlier_rad_s
    p[P_MAX_FRAC] = settings.max_outlier_fraction
    return p


def new_state() -> NDArray[np.float64]:
    """Empty state: no pair, no sample seen (the counters at 0)."""
    st = np.zeros(_LEN)
    _clear(st)
    return st


@kernel
def _clear(st):  # type: ignore[no-untyped-def]
    """Forget the mean, the ring and the waiting samples (the counters stay)."""
    clear_mean(st)
    st[_T_PRIMARY] = -math.inf
    st[_T_PARTNER] = -math.inf
    st[_T_FIRST] = -math.inf
    for i in range(_RING_N):
        st[_RING + 4 * i] = -math.inf
    st[_HEAD] = 0.0
    st[_PEND_COUNT] = 0.0


@kernel
def _resolve(st, p, final):  # type: ignore[no-untyped-def]
    """Pair the waiting partner samples whose primary sample is decided (all of them when ``final``)."""
    newest = st[_T_PRIMARY]
    m = int(st[_PEND_COUNT])
    keep = 0
    for j in range(m):
        o = _PEND + 4 * j
        t_s = st[o]
        edge = t_s + _TRUNC_US  # the primary sample of the pair is stamped before this
        if newest < edge and not final:  # a primary sample before ``edge`` may still come
            if keep != j:
                for q in range(4):
                    st[_PEND + 4 * keep + q] = st[o + q]
            keep += 1
            continue
        best = -1
        best_t = -math.inf
        for i in range(_RING_N):
            r = _RING + 4 * i
            t = st[r]
            if t < edge and t > best_t:
                best_t = t
                best = r
        if best < 0 or edge - best_t > p[_P_LAG_US]:
            st[_C + _C_UNPAIRED] += 1.0
            continue
        pair_mean_update(st, p, _C, best_t, st[o + 1] - st[best + 1], st[o + 2] - st[best + 2],
                         st[o + 3] - st[best + 3])  # fmt: skip
    st[_PEND_COUNT] = keep


@kernel
def bias_pair_step(st, p, t_us, g0, g1, g2):  # type: ignore[no-untyped-def]
    """A partner message (PX4: SCALED_IMU, its gyro ``g`` in rad/s, stamped ``t_us``) arrives.

    It waits for its primary sample (:func:`bias_restore_step`) and then updates the mean.  Returns 1
    when the primary message is arriving (a HIGHRES_IMU within ``hold_s`` of this stamp): then this
    message serves only this step; 0: it is an ordinary IMU message (no primary stream).  Before
    the first primary message the partner serves only this step for its first second (at a start it
    may arrive first; a stream without the primary message starts 1 s later).
    """
    if not (g0 == g0 and g1 == g1 and g2 == g2 and abs(g0) < math.inf and abs(g1) < math.inf
            and abs(g2) < math.inf):  # fmt: skip
        st[_C + C_BAD] += 1.0
        return _serves_only(st, p, t_us)
    if t_us < st[_T_PARTNER] - p[P_HOLD_US]:  # the autopilot's clock went back: a reboot
        st[_C + C_BACK] += 1.0
        _clear(st)
    if t_us > st[_T_PARTNER]:
        st[_T_PARTNER] = t_us
    h = p[_P_HALF_STEP]  # truncated toward zero: the middle of the reading's interval (0 stays 0: (−1, 1))
    g0 += h if g0 > 0.0 else (-h if g0 < 0.0 else 0.0)
    g1 += h if g1 > 0.0 else (-h if g1 < 0.0 else 0.0)
    g2 += h if g2 > 0.0 else (-h if g2 < 0.0 else 0.0)
    if st[_T_FIRST] == -math.inf:
        st[_T_FIRST] = t_us
    m = int(st[_PEND_COUNT])
    if m == _PEND_N:  # waiting too long for their primary: decide the oldest with what there is
        _resolve(st, p, True)
        m = 0
    o = _PEND + 4 * m
    st[o], st[o + 1], st[o + 2], st[o + 3] = t_us, g0, g1, g2
    st[_PEND_COUNT] = m + 1
    _resolve(st, p, False)
    return _serves_only(st, p, t_us)


@kernel
def _serves_only(st, p, t_us):  # type: ignore[no-untyped-def]
    """1 while the primary stream is arriving (or, none seen yet, in the partner's first second), else 0."""
    if st[_T_PRIMARY] == -math.inf:
        return 1 if st[_T_FIRST] != -math.inf and t_us - st[_T_FIRST] <= _GRACE_US else 0
    return 1 if t_us - st[_T_PRIMARY] <= p[P_HOLD_US] else 0


@kernel
def _restore(st, p, t_us, gyro, j):  # type: ignore[no-untyped-def]
    """:func:`bias_restore_step` on ``gyro[j : j + 3]``."""
    g0, g1, g2 = gyro[j], gyro[j + 1], gyro[j + 2]
    if not (abs(g0) < math.inf and abs(g1) < math.inf and abs(g2) < math.inf):  # NaN fails too
        st[_C + C_BAD] += 1.0
        st[_C + C_NOT_APPLIED] += 1.0
        return 0
    if t_us < st[_T_PRIMARY] - p[P_HOLD_US]:  # the autopilot's clock went back: a reboot
        st[_C + C_BACK] += 1.0
        _clear(st)
    if t_us > st[_T_PRIMARY]:
        st[_T_PRIMARY] = t_us
    h = int(st[_HEAD])
    r = _RING + 4 * h
    st[r], st[r + 1], st[r + 2], st[r + 3] = t_us, g0, g1, g2
    st[_HEAD] = (h + 1) % _RING_N
    if st[_PEND_COUNT] > 0.0:
        _resolve(st, p, False)
    if mean_trusted(st, p, t_us):
        gyro[j] = g0 + st[S_B]
        gyro[j + 1] = g1 + st[S_B + 1]
        gyro[j + 2] = g2 + st[S_B + 2]
        st[_C + C_APPLIED] += 1.0
        return 1
    if st[S_N] > 0.0 or st[_C + C_PAIRS] > 0.0:  # a twin stream was seen: say the sample went uncorrected
        st[_C + C_NOT_APPLIED] += 1.0
    return 0


@kernel
def bias_restore_step(st, p, t_us, row, j):  # type: ignore[no-untyped-def]
    """A primary message (PX4: HIGHRES_IMU) stamped ``t_us``, its gyro (rad/s) in ``row[j : j + 3]``.

    The raw gyro joins the ring the partner samples are paired with; then, while the mean is
    trusted (``min_pairs`` pairs, the last at most ``hold_s`` old, few outliers), the mean is
    added to it in place.  Returns 1 when added, 0 when the sample is left as it came.
    """
    return _restore(st, p, t_us, row, j)


@kernel
def bias_restore_rows(st, p, role, t_us, gyro, bad, use, applied):  # type: ignore[no-untyped-def]
    """:func:`bias_pair_step` / :func:`bias_restore_step` over a log's merged messages in their order.

    ``role``: (N,) :data:`ROLE_PRIMARY`, :data:`ROLE_PARTNER` or :data:`ROLE_NONE` per message;
    ``t_us``: (N,) stamps; ``gyro``: (N, 3) rad/s, the primary's corrected in place; ``bad``: (N,)
    nonzero where the scaling step found the gyro saturated or invalid (a partner's is then no pair); ``use``: (N,)
    whether it is a sample — a partner that serves only this step is set False (not an IMU sample
    for the selector); ``applied[i]``: 1 where the mean was added.
    """
    for i in range(t_us.shape[0]):
        applied[i] = 0
        if not use[i]:
            continue
        if role[i] == ROLE_PRIMARY:
            applied[i] = _restore(st, p, t_us[i], gyro[i], 0)
        elif role[i] == ROLE_PARTNER:
            g0 = math.nan if bad[i] else gyro[i, 0]
            if bias_pair_step(st, p, t_us[i], g0, gyro[i, 1], gyro[i, 2]):
                use[i] = False


class AutopilotBias:
    """The step with its state, for one link (the pipeline's): see the module doc."""

    __slots__ = ("settings", "_st", "_p")

    def __init__(self, settings: AutopilotBiasSettings | None = None, step_rad_s: float = 0.0,
                 truncated: bool = False) -> None:  # fmt: skip
        self.settings = settings or AutopilotBiasSettings()
        self._st = new_state()
        self._p = constants(self.settings, step_rad_s, truncated)

    def reset(self) -> None:
        """Forget the mean and the samples (an autopilot reboot); the counts are kept."""
        _clear(self._st)

    def pair(self, t_us: int, gx: float, gy: float, gz: float) -> bool:
        """A partner message's gyro (rad/s); True: it serves only this step (see :func:`bias_pair_step`)."""
        return bool(bias_pair_step(self._st, self._p, float(t_us), gx, gy, gz))

    def restore(self, t_us: int, row: NDArray[np.float64], j: int) -> bool:
        """A primary message's gyro in ``row[j : j + 3]``, corrected in place; True when the mean was added."""
        return bool(bias_restore_step(self._st, self._p, float(t_us), row, j))

    @property
    def bias_rad_s(self) -> tuple[float, float, float] | None:
        """The mean being added (rad/s), or None while none is trusted."""
        return trusted_mean(self._st, self._p, self._st[_T_PRIMARY])

    @property
    def counts(self) -> dict[str, int]:
        """The counters (:data:`COUNTER_NAMES`) since the start."""
        return counter_values(self._st, _C, COUNTER_NAMES)
