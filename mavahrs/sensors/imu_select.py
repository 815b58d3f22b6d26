r"""Which IMU instance feeds the filter: fixed (``--imu 0|1|2``) or ``auto`` with fail-over.

An autopilot may send several IMU instances: RAW_IMU (or SCALED_IMU,
HIGHRES_IMU ``id`` 0) is instance 0, SCALED_IMU2 instance 1, SCALED_IMU3
instance 2.  :class:`ImuSelector` watches every instance's samples and
decides, per sample, whether it goes to the filter.  An instance is

* **absent** — its accelerometer and gyro read exactly zero (ArduPilot sends
  SCALED_IMU2 with zero accel/gyro when only a second compass exists): never
  fed to a filter, whatever the mode;
* **stale** — no sample for ``stale_s`` while other instances keep arriving;
* **frozen** — identical accel and gyro values for ``freeze_s`` (and at least
  ``freeze_min_samples`` samples) while another live instance shows that a
  working sensor would have changed: it changes in at least
  ``freeze_other_change_fraction`` of its recent samples (its noise; a running
  share, time constant ``freeze_s``/2), or its smoothed gyro or accelerometer
  has moved by more than ``freeze_motion_gyro_rad_s`` /
  ``freeze_motion_accel_m_s2`` since this instance's values stopped changing
  (the vehicle moved: a noiseless reading changes by whole units only, not in
  every sample, while the vehicle turns slowly).  A noiseless simulator in a
  steady state (ArduPilot SITL on the ground, in the hover) repeats values in
  every instance, the other one flickering by one unit now and then — no
  fault, and no reason to switch (judged by "the other changed at all", it
  made ``auto`` flap between IMU 0 and IMU 1 every 2 s);
* **saturated** — an axis at its limit within the last ``saturation_hold_s``;
* **disagreeing** — its smoothed gyro or accel differs from the median of
  three or more instances by more than a threshold for ``disagree_s`` (with
  two instances a disagreement cannot say which one is wrong: it is reported,
  not acted on).

``auto`` keeps the current instance while it is healthy, otherwise switches
to the lowest-numbered healthy one; it returns to a lower-numbered instance
only after that one has been healthy for ``recover_s``.  When nothing is
healthy it keeps the best of what is there.  Time is the autopilot's sample
time (all instances share the boot clock), so replay behaves like live; the
caller calls :meth:`ImuSelector.reset` when the autopilot reboots.

The rules are one compiled step of the sample chain, :func:`select_step`, on
the selector's state in two plain arrays (:func:`new_state`; one slot per
instance number below :data:`MAX_SLOTS`): the live pipeline calls it per
sample through :class:`ImuSelector` (which names the reasons and queues the
changes for notices), and replay runs :func:`select_loop`, the same step in a
compiled loop over a log's samples (tlogs with several instances, DataFlash
``IMU`` records, ULog ``vehicle_imu`` instances).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import ConfigError
from mavahrs.filters.jit import kernel
from mavahrs.sensors.sample import ACCEL, GYRO
from mavahrs.sensors.scaling import S_SAT, Scaled

__all__ = ["ImuSelectSettings", "ImuSelector", "InstanceStatus", "SelectionChange", "MAX_INSTANCES", "MAX_SLOTS",
           "new_state", "select_step", "select_loop", "select_reset", "select_problem"]

MAX_INSTANCES = 3


@dataclass(frozen=True)
class ImuSelectSettings:
    """How the IMU instance is chosen.

    Attributes:
        imu: ``"auto"`` or an instance number ``"0"``, ``"1"``, ``"2"``.
        stale_s: an instance with no sample for this long (autopilot time,
            while others arrive) is stale, s.
        freeze_s: identical accel+gyro values for this long = frozen, s.
        freeze_min_samples: … and for at least this many samples.
        freeze_other_change_fraction: … while another instance's values
            change in at least this share of its recent samples (running
            share, time constant ``freeze_s``/2): 0.5 lies between a live
            sensor's ≈ 1 and the few one-unit flickers of a noiseless
            simulator at rest (≈ 0.07 in ArduPilot SITL); or
        freeze_motion_gyro_rad_s: … another instance's smoothed gyro moved by
            more than this since the values stopped changing, rad/s (the
            vehicle turns; far above a one-unit flicker, 0.001 rad/s);
        freeze_motion_accel_m_s2: … or its smoothed accelerometer by more
            than this, m/s² (one unit is 0.0098 m/s²).
        zero_samples: this many consecutive all-zero samples mark an instance
            absent (the first sample decides at start-up).
        saturation_hold_s: an instance stays "saturated" this long after its
            last saturated sample, s.
        disagree_gyro_rad_s: smoothed-gyro difference from the median that
            counts as disagreement, rad/s.
        disagree_accel_m_s2: smoothed-accel difference that counts, m/s².
        disagree_s: the disagreement must last this long, s.
        smoothing_s: time constant of the smoothing used for comparisons, s.
        recover_s: an instance must be healthy this long before ``auto``
            switches back to it, s.
    """

    imu: str = "auto"
    stale_s: float = 0.25
    freeze_s: float = 0.5
    freeze_min_samples: int = 5
    freeze_other_change_fraction: float = 0.5
    freeze_motion_gyro_rad_s: float = 0.05
    freeze_motion_accel_m_s2: float = 0.5
    zero_samples: int = 3
    saturation_hold_s: float = 1.0
    disagree_gyro_rad_s: float = math.radians(15.0)
    disagree_accel_m_s2: float = 3.0
    disagree_s: float = 0.3
    smoothing_s: float = 0.05
    recover_s: float = 2.0

    def __post_init__(self) -> None:
        if self.imu != "auto" and self.imu not in {str(i) for i in range(MAX_INSTANCES)}:
            raise ConfigError(f"imu must be auto, 0, 1 or 2, got {self.imu!r}")
        for name in ("stale_s", "freeze_s", "freeze_motion_gyro_rad_s", "freeze_motion_accel_m_s2",
                     "saturation_hold_s", "disagree_gyro_rad_s", "disagree_accel_m_s2", "disagree_s", "smoothing_s",
                     "recover_s"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"IMU selection setting {name} must be a positive number, got {v!r}")
        if self.freeze_min_samples < 2 or self.zero_samples < 1:
            raise ConfigError("freeze_min_samples must be ≥ 2 and zero_samples ≥ 1")
        if not 0.0 < self.freeze_other_change_fraction <= 1.0:
            raise ConfigError(
                f"freeze_other_change_fraction must be in (0, 1], got {self.freeze_other_change_fraction!r}"
            )

    @property
    def fixed(self) -> int | None:
        """The forced instance, or None for auto."""
        return None if self.imu == "auto" else int(self.imu)


@dataclass(frozen=True)
class InstanceStatus:
    """One instance as seen so far.  ``state`` is ok/absent/stale/frozen/saturated/disagrees."""

    imu_id: int
    source: str
    samples: int
    state: str
    selected: bool


@dataclass(frozen=True)
class SelectionChange:
    """The selected instance changed (``old`` None at start).

    ``bad_since_us``: autopilot time from which the old instance's samples were
    already wrong (frozen, saturated, disagreeing) — the caller may undo what
    they did to the filter; None when nothing wrong was fed (stale, start).
    """

    old: int | None
    new: int | None
    reason: str
    bad_since_us: int | None = None


# ---------------------------------------------------------------------------------------------------------------
# The step, compiled: state in two plain arrays (new_state), one slot per instance number below MAX_SLOTS.
#: instance numbers the state holds (RAW_IMU / HIGHRES_IMU ``id``, DataFlash ``I``, ULog multi id): 0 … MAX_SLOTS-1
MAX_SLOTS = 16
#: ``none`` for a time or an instance (no stamp or instance equals it)
NONE = np.iinfo(np.int64).min
_FAR_PAST = -(10**18)
_INT64_END = 1 << 63
#: what is wrong with an instance (``_problem``), as :meth:`ImuSelector.instances` names it
P_OK, P_ABSENT, P_STALE, P_FROZEN, P_SATURATED, P_DISAGREES = range(6)
PROBLEM_NAMES = ("", "absent (all-zero)", "stale", "frozen", "saturated", "disagrees")
#: why the instance in use is the one it is (with the instance ``a`` and problem ``p`` it names)
(R_WAITING, R_FIXED_NO_DATA, R_FIXED, R_RECOVERED, R_HEALTHY, R_FIRST, R_OLD_BAD, R_NONE_HEALTHY_KEEP,
 R_NONE_HEALTHY_USING, R_NO_USABLE) = range(10)  # fmt: skip
# int64 state: the selection, its reason, the counters, the settings, the last evaluation's problems,
# the changes not yet popped, then per instance its fields and its marks of the others
(G_SELECTED, G_REPORTED, G_T_LATEST, G_RESUME, G_LAST_EVAL, G_DUP_SOURCE, G_REASON, G_REASON_A, G_REASON_P,
 G_N_CHANGES, G_CHANGES_TOTAL, G_FIXED, G_STALE_US, G_FREEZE_US, G_SAT_US, G_DISAGREE_US, G_RECOVER_US, G_EVAL_US,
 G_FREEZE_MIN, G_ZERO_N, G_SMOOTH_LAG_US) = range(21)  # fmt: skip
G_PROBLEMS = 21
#: changes held until popped (the pipeline pops after every sample; a loop counts them in G_CHANGES_TOTAL)
CH_MAX = 8
(CH_OLD, CH_NEW, CH_REASON, CH_A, CH_P, CH_BAD) = range(6)
CH_LEN = 6
G_CHANGES = G_PROBLEMS + MAX_SLOTS
(I_SEEN, I_SOURCE, I_SAMPLES, I_LAST_T, I_ZERO_RUN, I_ABSENT, I_NONZERO_SEEN, I_HAS_PREV, I_SAME_COUNT,
 I_SAME_SINCE, I_LAST_SAT, I_SAT_SINCE, I_EMA_READY, I_DISAGREE_SINCE, I_HEALTHY_SINCE) = range(15)  # fmt: skip
I_MARKED = 15  # MAX_SLOTS flags: a mark of that other instance was taken when this one's run of repeats began
I_LEN = I_MARKED + MAX_SLOTS
G_INST = G_CHANGES + CH_MAX * CH_LEN
ST_LEN = G_INST + MAX_SLOTS * I_LEN
# float64 state: settings, scratch for the median, then per instance its previous values, running change
# share, smoothed values and the others' smoothed values when its run of repeats began
(F_CHANGE_TAU_US, F_FRACTION, F_MOTION_GYRO, F_MOTION_ACCEL, F_DISAGREE_GYRO, F_DISAGREE_ACCEL, F_SMOOTHING_S) = range(7)
F_SCRATCH = 7
J_PREV, J_CHANGE_RATE, J_EMA = 0, 6, 7
J_MARK = 13
J_LEN = J_MARK + 6 * MAX_SLOTS
F_INST = F_SCRATCH + MAX_SLOTS + 6
FS_LEN = F_INST + MAX_SLOTS * J_LEN


def new_state(settings: ImuSelectSettings | None = None) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """A selector that has seen nothing, ``(int64 array, float64 array)``, with ``settings`` in it."""
    s = settings if settings is not None else ImuSelectSettings()
    st = np.zeros(ST_LEN, np.int64)
    fs = np.zeros(FS_LEN)
    st[G_FIXED] = NONE if s.fixed is None else s.fixed
    st[G_STALE_US] = int(s.stale_s * 1e6)
    st[G_FREEZE_US] = int(s.freeze_s * 1e6)
    st[G_SAT_US] = int(s.saturation_hold_s * 1e6)
    st[G_DISAGREE_US] = int(s.disagree_s * 1e6)
    st[G_RECOVER_US] = int(s.recover_s * 1e6)
    st[G_EVAL_US] = 20_000  # re-evaluate the choice at most every 20 ms of autopilot time
    st[G_FREEZE_MIN] = s.freeze_min_samples
    st[G_ZERO_N] = s.zero_samples
    st[G_SMOOTH_LAG_US] = int(2e6 * s.smoothing_s)  # the smoothing's lag, for when a disagreement began
    fs[F_CHANGE_TAU_US] = 0.5 * s.freeze_s * 1e6
    fs[F_FRACTION] = s.freeze_other_change_fraction
    fs[F_MOTION_GYRO] = s.freeze_motion_gyro_rad_s
    fs[F_MOTION_ACCEL] = s.freeze_motion_accel_m_s2
    fs[F_DISAGREE_GYRO] = s.disagree_gyro_rad_s
    fs[F_DISAGREE_ACCEL] = s.disagree_accel_m_s2
    fs[F_SMOOTHING_S] = s.smoothing_s
    select_reset(st, fs)
    return st, fs


@kernel
def select_reset(st, fs):  # type: ignore[no-untyped-def]
    """Forget every instance (an autopilot reboot, a new link); the settings stay."""
    st[G_SELECTED] = st[G_FIXED]
    st[G_REPORTED] = NONE
    st[G_T_LATEST] = 0
    st[G_RESUME] = 0
    st[G_LAST_EVAL] = _FAR_PAST
    st[G_DUP_SOURCE] = 0
    st[G_REASON] = R_WAITING
    st[G_REASON_A] = NONE
    st[G_REASON_P] = P_OK
    st[G_N_CHANGES] = 0
    for k in range(MAX_SLOTS):
        st[G_PROBLEMS + k] = P_OK
        st[G_INST + k * I_LEN + I_SEEN] = 0


@kernel
def _new_instance(st, fs, k, src, t):  # type: ignore[no-untyped-def]
    b = G_INST + k * I_LEN
    for j in range(I_LEN):
        st[b + j] = 0
    st[b + I_SEEN] = 1
    st[b + I_SOURCE] = src
    st[b + I_LAST_T] = t
    st[b + I_LAST_SAT] = _FAR_PAST
    st[b + I_SAT_SINCE] = _FAR_PAST
    st[b + I_DISAGREE_SINCE] = NONE
    st[b + I_HEALTHY_SINCE] = NONE
    f = F_INST + k * J_LEN
    for j in range(J_LEN):
        fs[f + j] = 0.0


@kernel
def _others_changed(st, fs, k):  # type: ignore[no-untyped-def]
    """While instance ``k`` repeats its values: does another live instance change in most of its recent samples
    (noise), or have its smoothed values moved clearly since the repeats began (motion)?"""
    t = st[G_T_LATEST]
    b = G_INST + k * I_LEN
    f = F_INST + k * J_LEN
    for o in range(MAX_SLOTS):
        ob = G_INST + o * I_LEN
        if o == k or st[ob + I_SEEN] == 0:
            continue
        if st[ob + I_ABSENT] != 0 or t - st[ob + I_LAST_T] > st[G_STALE_US] or st[ob + I_SAMPLES] < st[G_FREEZE_MIN]:
            continue
        of = F_INST + o * J_LEN
        if fs[of + J_CHANGE_RATE] >= fs[F_FRACTION]:
            return True
        if st[b + I_MARKED + o] != 0 and st[ob + I_EMA_READY] != 0:
            m = f + J_MARK + 6 * o
            e = of + J_EMA
            dg = math.sqrt((fs[e] - fs[m]) ** 2 + (fs[e + 1] - fs[m + 1]) ** 2 + (fs[e + 2] - fs[m + 2]) ** 2)
            da = math.sqrt((fs[e + 3] - fs[m + 3]) ** 2 + (fs[e + 4] - fs[m + 4]) ** 2 + (fs[e + 5] - fs[m + 5]) ** 2)
            if dg > fs[F_MOTION_GYRO] or da > fs[F_MOTION_ACCEL]:
                return True
    return False


@kernel
def select_problem(st, fs, k):  # type: ignore[no-untyped-def]
    """What is wrong with instance ``k`` now (a ``P_*`` code; :data:`P_OK` for nothing)."""
    t = st[G_T_LATEST]
    b = G_INST + k * I_LEN
    if st[b + I_ABSENT] != 0:
        return P_ABSENT
    last = st[b + I_LAST_T]
    if st[G_RESUME] > last:
        last = st[G_RESUME]
    if t - last > st[G_STALE_US]:
        return P_STALE
    if (st[b + I_SAME_COUNT] >= st[G_FREEZE_MIN] and t - st[b + I_SAME_SINCE] >= st[G_FREEZE_US]
            and _others_changed(st, fs, k)):  # fmt: skip
        return P_FROZEN
    if t - st[b + I_LAST_SAT] <= st[G_SAT_US]:
        return P_SATURATED
    ds = st[b + I_DISAGREE_SINCE]
    if ds != NONE and t - ds >= st[G_DISAGREE_US]:
        return P_DISAGREES
    return P_OK


@kernel
def _update_disagreement(st, fs):  # type: ignore[no-untyped-def]
    """Each live instance's smoothed gyro and accelerometer against the median of three or more."""
    t = st[G_T_LATEST]
    n_live = 0
    for k in range(MAX_SLOTS):
        b = G_INST + k * I_LEN
        if (st[b + I_SEEN] != 0 and st[b + I_ABSENT] == 0 and st[b + I_EMA_READY] != 0
                and t - st[b + I_LAST_T] <= st[G_STALE_US]):  # fmt: skip
            n_live += 1
    # (after a link outage the instances that have not spoken again simply do not vote)
    if n_live < 3:
        for k in range(MAX_SLOTS):
            st[G_INST + k * I_LEN + I_DISAGREE_SINCE] = NONE
        return
    for ax in range(6):  # the median of each axis: the middle one of the sorted values (upper middle if even)
        n = 0
        for k in range(MAX_SLOTS):
            b = G_INST + k * I_LEN
            if (st[b + I_SEEN] != 0 and st[b + I_ABSENT] == 0 and st[b + I_EMA_READY] != 0
                    and t - st[b + I_LAST_T] <= st[G_STALE_US]):  # fmt: skip
                x = fs[F_INST + k * J_LEN + J_EMA + ax]
                j = n
                while j > 0 and fs[F_SCRATCH + j - 1] > x:  # insertion sort (no allocation)
                    fs[F_SCRATCH + j] = fs[F_SCRATCH + j - 1]
                    j -= 1
                fs[F_SCRATCH + j] = x
                n += 1
        fs[F_SCRATCH + MAX_SLOTS + ax] = fs[F_SCRATCH + n // 2]
    med = F_SCRATCH + MAX_SLOTS  # the six medians, after the room to sort one axis's values
    for k in range(MAX_SLOTS):
        b = G_INST + k * I_LEN
        if (st[b + I_SEEN] != 0 and st[b + I_ABSENT] == 0 and st[b + I_EMA_READY] != 0
                and t - st[b + I_LAST_T] <= st[G_STALE_US]):  # fmt: skip
            e = F_INST + k * J_LEN + J_EMA
            dg = math.sqrt((fs[e] - fs[med]) ** 2 + (fs[e + 1] - fs[med + 1]) ** 2 + (fs[e + 2] - fs[med + 2]) ** 2)
            da = math.sqrt((fs[e + 3] - fs[med + 3]) ** 2 + (fs[e + 4] - fs[med + 4]) ** 2
                           + (fs[e + 5] - fs[med + 5]) ** 2)  # fmt: skip
            if dg > fs[F_DISAGREE_GYRO] or da > fs[F_DISAGREE_ACCEL]:
                if st[b + I_DISAGREE_SINCE] == NONE:
                    st[b + I_DISAGREE_SINCE] = t
            else:
                st[b + I_DISAGREE_SINCE] = NONE


@kernel
def _set(st, new, reason, a, p, bad):  # type: ignore[no-untyped-def]
    """Select ``new`` for ``reason``; a change of what was reported is queued (``bad``: see SelectionChange)."""
    if new != st[G_REPORTED]:
        n = st[G_N_CHANGES]
        if n == CH_MAX:  # nobody pops (a loop over a log): keep the latest CH_MAX
            for j in range(CH_LEN * (CH_MAX - 1)):
                st[G_CHANGES + j] = st[G_CHANGES + CH_LEN + j]
            n -= 1
        c = G_CHANGES + n * CH_LEN
        st[c + CH_OLD] = st[G_REPORTED]
        st[c + CH_NEW] = new
        st[c + CH_REASON] = reason
        st[c + CH_A] = a
        st[c + CH_P] = p
        st[c + CH_BAD] = bad
        st[G_N_CHANGES] = n + 1
        st[G_CHANGES_TOTAL] += 1
        st[G_REPORTED] = new
    st[G_SELECTED] = new
    st[G_REASON] = reason
    st[G_REASON_A] = a
    st[G_REASON_P] = p


@kernel
def _bad_since(st, k, problem):  # type: ignore[no-untyped-def]
    """From when instance ``k``'s samples were already wrong (NONE: nothing wrong was fed)."""
    if k < 0 or k >= MAX_SLOTS:
        return NONE
    b = G_INST + k * I_LEN
    if st[b + I_SEEN] == 0:
        return NONE
    if problem == P_FROZEN:
        return st[b + I_SAME_SINCE]
    if problem == P_SATURATED:
        return st[b + I_SAT_SINCE]
    if problem == P_DISAGREES and st[b + I_DISAGREE_SINCE] != NONE:
        return st[b + I_DISAGREE_SINCE] - st[G_SMOOTH_LAG_US]
    return NONE


@kernel
def _evaluate(st, fs):  # type: ignore[no-untyped-def]
    """Judge every instance and choose (the rules in the module docstring)."""
    t = st[G_T_LATEST]
    st[G_LAST_EVAL] = t
    _update_disagreement(st, fs)
    for k in range(MAX_SLOTS):
        b = G_INST + k * I_LEN
        if st[b + I_SEEN] == 0:
            continue
        p = select_problem(st, fs, k)
        st[G_PROBLEMS + k] = p
        if p != P_OK:
            st[b + I_HEALTHY_SINCE] = NONE
        elif st[b + I_HEALTHY_SINCE] == NONE:
            st[b + I_HEALTHY_SINCE] = t
    old = st[G_SELECTED]
    fixed = st[G_FIXED]
    if fixed != NONE:
        if st[G_INST + fixed * I_LEN + I_SEEN] == 0:
            _set(st, fixed, R_FIXED_NO_DATA, fixed, P_OK, NONE)
        else:
            _set(st, fixed, R_FIXED, fixed, st[G_PROBLEMS + fixed], NONE)
        return
    old_seen = old != NONE and st[G_INST + old * I_LEN + I_SEEN] != 0
    first_healthy = NONE
    for k in range(MAX_SLOTS):
        if st[G_INST + k * I_LEN + I_SEEN] != 0 and st[G_PROBLEMS + k] == P_OK:
            first_healthy = k
            break
    if old_seen and st[G_PROBLEMS + old] == P_OK:
        # stay, unless a lower-numbered instance has been healthy long enough
        for k in range(old):
            b = G_INST + k * I_LEN
            if st[b + I_SEEN] != 0 and st[G_PROBLEMS + k] == P_OK:
                hs = st[b + I_HEALTHY_SINCE]
                if hs == NONE or hs == 0:  # (0 counted as "not yet", as the Python selector's ``or t`` did)
                    hs = t
                if t - hs >= st[G_RECOVER_US]:
                    _set(st, k, R_RECOVERED, k, P_OK, NONE)
                    return
        r = st[G_REASON]
        if r == R_WAITING or r == R_NONE_HEALTHY_KEEP or r == R_NONE_HEALTHY_USING or r == R_NO_USABLE:
            _set(st, old, R_HEALTHY, NONE, P_OK, NONE)
        else:
            _set(st, old, r, st[G_REASON_A], st[G_REASON_P], NONE)
        return
    if first_healthy != NONE:
        if old == NONE:
            _set(st, first_healthy, R_FIRST, NONE, P_OK, NONE)
        else:
            p = st[G_PROBLEMS + old] if old_seen else P_OK  # P_OK here: "gone"
            _set(st, first_healthy, R_OLD_BAD, old, p, _bad_since(st, old, p) if old_seen else NONE)
        return
    # nothing healthy: keep what is there if it still delivers, else any delivering instance
    if old_seen and st[G_PROBLEMS + old] != P_ABSENT and st[G_PROBLEMS + old] != P_STALE:
        _set(st, old, R_NONE_HEALTHY_KEEP, old, st[G_PROBLEMS + old], NONE)
        return
    for k in range(MAX_SLOTS):
        p = st[G_PROBLEMS + k]
        if st[G_INST + k * I_LEN + I_SEEN] != 0 and p != P_ABSENT and p != P_STALE:
            _set(st, k, R_NONE_HEALTHY_USING, k, p, NONE)
            return
    _set(st, NONE, R_NO_USABLE, NONE, P_OK, NONE)


@kernel
def select_step(st, fs, src, k, t, gx, gy, gz, ax, ay, az, saturated):  # type: ignore[no-untyped-def]
    """The selector's step on one sample: does it feed the filter?

    Instance ``k`` (below :data:`MAX_SLOTS`) of message ``src`` (a number the caller gives each message
    type; two message types carrying one instance: the later one is refused while the first still
    speaks), autopilot time ``t`` µs, gyro rad/s, accelerometer m/s², ``saturated`` whether a gyro or
    accelerometer axis is at its limit.  The state (:func:`new_state`) records the instance's health
    and the choice (the rules in the module docstring); a change of the chosen instance is queued in
    the state for :class:`ImuSelector` to report.
    """
    if k < 0 or k >= MAX_SLOTS:
        return False
    b = G_INST + k * I_LEN
    if st[b + I_SEEN] == 0:
        _new_instance(st, fs, k, src, t)
    elif st[b + I_SOURCE] != src:
        if t - st[b + I_LAST_T] <= st[G_STALE_US] and st[b + I_SAMPLES] != 0:
            st[G_DUP_SOURCE] += 1
            return False
        st[b + I_SOURCE] = src  # the old message stopped: follow the new one
    if t - st[G_T_LATEST] > st[G_STALE_US] and st[G_T_LATEST] != 0:
        st[G_RESUME] = t  # every instance was silent (link outage): judge staleness from here
    if t > st[G_T_LATEST]:
        st[G_T_LATEST] = t
    dt_us = t - st[b + I_LAST_T]
    st[b + I_SAMPLES] += 1
    st[b + I_LAST_T] = t
    # all-zero accel and gyro: no such IMU
    if gx == 0.0 and gy == 0.0 and gz == 0.0 and ax == 0.0 and ay == 0.0 and az == 0.0:
        st[b + I_ZERO_RUN] += 1
        if st[b + I_ZERO_RUN] >= st[G_ZERO_N] or st[b + I_NONZERO_SEEN] == 0:
            if st[b + I_ABSENT] == 0:
                st[b + I_ABSENT] = 1
                _evaluate(st, fs)
        return False
    st[b + I_ZERO_RUN] = 0
    st[b + I_NONZERO_SEEN] = 1
    if st[b + I_ABSENT] != 0:
        st[b + I_ABSENT] = 0
        st[b + I_HEALTHY_SINCE] = NONE
    # frozen: identical values
    f = F_INST + k * J_LEN
    p = f + J_PREV
    same = (st[b + I_HAS_PREV] != 0 and gx == fs[p] and gy == fs[p + 1] and gz == fs[p + 2] and ax == fs[p + 3]
            and ay == fs[p + 4] and az == fs[p + 5])  # fmt: skip
    if same:
        st[b + I_SAME_COUNT] += 1
        if st[b + I_SAME_COUNT] == 2:  # a run of identical values begins: where are the others?
            for o in range(MAX_SLOTS):
                ob = G_INST + o * I_LEN
                marked = o != k and st[ob + I_SEEN] != 0 and st[ob + I_EMA_READY] != 0
                st[b + I_MARKED + o] = 1 if marked else 0
                if marked:
                    oe = F_INST + o * J_LEN + J_EMA
                    for j in range(6):
                        fs[f + J_MARK + 6 * o + j] = fs[oe + j]
    else:
        fs[p] = gx
        fs[p + 1] = gy
        fs[p + 2] = gz
        fs[p + 3] = ax
        fs[p + 4] = ay
        fs[p + 5] = az
        st[b + I_HAS_PREV] = 1
        st[b + I_SAME_COUNT] = 1
        st[b + I_SAME_SINCE] = t
    if dt_us > 0:
        a = dt_us / (fs[F_CHANGE_TAU_US] + dt_us)
        fs[f + J_CHANGE_RATE] += a * ((0.0 if same else 1.0) - fs[f + J_CHANGE_RATE])
    if saturated:
        if t - st[b + I_LAST_SAT] > st[G_SAT_US]:
            st[b + I_SAT_SINCE] = t  # a new saturation episode
        st[b + I_LAST_SAT] = t
    # smoothing for the disagreement check (NaN-free values only)
    if ax == ax and gx == gx:
        e = f + J_EMA
        if st[b + I_EMA_READY] != 0 and dt_us > 0:
            dt = dt_us * 1e-6
            a = dt / (fs[F_SMOOTHING_S] + dt)  # first-order low-pass
            fs[e] += a * (gx - fs[e])
            fs[e + 1] += a * (gy - fs[e + 1])
            fs[e + 2] += a * (gz - fs[e + 2])
            fs[e + 3] += a * (ax - fs[e + 3])
            fs[e + 4] += a * (ay - fs[e + 4])
            fs[e + 5] += a * (az - fs[e + 5])
        else:
            fs[e] = gx
            fs[e + 1] = gy
            fs[e + 2] = gz
            fs[e + 3] = ax
            fs[e + 4] = ay
            fs[e + 5] = az
            st[b + I_EMA_READY] = 1
    if t - st[G_LAST_EVAL] >= st[G_EVAL_US] or st[G_SELECTED] == NONE:
        _evaluate(st, fs)
    return k == st[G_SELECTED] and st[b + I_ABSENT] == 0


@kernel
def select_loop(st, fs, src, k, t, gyro, accel, saturated, use, feed):  # type: ignore[no-untyped-def]
    """:func:`select_step` over a log's samples in order: ``feed[i]`` whether sample ``i`` feeds the filter.

    ``src``, ``k``, ``t``: (N,) message number, instance and time (µs) of each sample; ``gyro``,
    ``accel``: (N, 3); ``saturated``: (N,) a gyro or accelerometer axis at its limit; ``use``: (N,)
    whether it is a sample at all (not one is looked at otherwise, and it does not feed).
    """
    for i in range(t.shape[0]):
        if use[i]:
            feed[i] = select_step(st, fs, src[i], k[i], t[i], gyro[i, 0], gyro[i, 1], gyro[i, 2], accel[i, 0],
                                  accel[i, 1], accel[i, 2], saturated[i])  # fmt: skip
        else:
            feed[i] = False


def _reason_text(settings: ImuSelectSettings, r: int, a: int, p: int, problems: dict[int, int]) -> str:
    if r == R_WAITING:
        return "waiting for IMU data"
    if r == R_FIXED_NO_DATA:
        return f"fixed by --imu {a}; no data from it yet"
    if r == R_FIXED:
        return f"fixed by --imu {a}" + (f" ({PROBLEM_NAMES[p]})" if p else "")
    if r == R_RECOVERED:
        return f"instance {a} healthy again for {settings.recover_s:g} s"
    if r == R_HEALTHY:
        return "healthy"
    if r == R_FIRST:
        return "first healthy instance"
    if r == R_OLD_BAD:
        return f"instance {a} {PROBLEM_NAMES[p] or 'gone'}"
    if r == R_NONE_HEALTHY_KEEP:
        return f"no healthy instance; keeping {a} ({PROBLEM_NAMES[p]})"
    if r == R_NONE_HEALTHY_USING:
        return f"no healthy instance; using {a} ({PROBLEM_NAMES[p]})"
    return "no usable IMU instance" + ("" if not problems else f" ({_describe(problems)})")


def _describe(problems: dict[int, int]) -> str:
    return ", ".join(f"{k}: {PROBLEM_NAMES[p] or 'ok'}" for k, p in sorted(problems.items()))


def _opt(x: int) -> int | None:
    return None if x == NONE else int(x)


class ImuSelector:
    """:func:`select_step` with its state, for one link (the pipeline's): per sample, does it feed the filter?

    The state (``st``, ``fs``) is what the step works on; replay runs :func:`select_loop` on a state of its
    own.  Message types are numbered here in the order they are first seen.
    """

    __slots__ = ("settings", "st", "fs", "_sources", "_names")

    def __init__(self, settings: ImuSelectSettings | None = None) -> None:
        self.settings = settings or ImuSelectSettings()
        self.st, self.fs = new_state(self.settings)
        self._sources: dict[str, int] = {}
        self._names: list[str] = []

    def reset(self) -> None:
        """Forget every instance (autopilot reboot, new link)."""
        select_reset(self.st, self.fs)

    # ------------------------------------------------------------------ per sample
    def observe(self, source: str, v: Scaled) -> bool:
        """Record one scaled sample; True when it should feed the filter."""
        src = self._sources.get(source)
        if src is None:
            src = self._sources[source] = len(self._names)
            self._names.append(source)
        t = v[1]
        if t >= _INT64_END:  # a uint64 time_usec beyond int64: the same bits, signed
            t -= 1 << 64
        return bool(select_step(self.st, self.fs, src, v[0], t, v[2], v[3], v[4], v[5], v[6], v[7],
                                (v[S_SAT] & (GYRO | ACCEL)) != 0))  # fmt: skip

    # ------------------------------------------------------------------ reporting
    @property
    def selected(self) -> int | None:
        """The instance that feeds the filter (None: none usable, or none seen yet)."""
        s = self.st[G_SELECTED]
        return None if s == NONE else int(s)

    @property
    def changed(self) -> bool:
        """Selection changes are waiting to be popped."""
        return bool(self.st[G_N_CHANGES])

    @property
    def switches(self) -> int:
        """Changes of the selected instance so far (the first choice included)."""
        return int(self.st[G_CHANGES_TOTAL])

    @property
    def duplicate_source(self) -> int:
        """Samples refused because another message already carries the instance."""
        return int(self.st[G_DUP_SOURCE])

    @property
    def next_evaluation_us(self) -> int:
        """Autopilot time from which the next sample re-evaluates the choice (and may switch)."""
        return int(self.st[G_LAST_EVAL] + self.st[G_EVAL_US])

    def _problems(self) -> dict[int, int]:
        st = self.st
        return {k: int(st[G_PROBLEMS + k]) for k in range(MAX_SLOTS) if st[G_INST + k * I_LEN + I_SEEN]}

    @property
    def reason(self) -> str:
        """Why the selected instance is the one in use."""
        st = self.st
        return _reason_text(self.settings, int(st[G_REASON]), int(st[G_REASON_A]), int(st[G_REASON_P]),
                            self._problems())  # fmt: skip

    def pop_changes(self) -> list[SelectionChange]:
        """Selection changes since the last call (for notices)."""
        st = self.st
        out = []
        for i in range(int(st[G_N_CHANGES])):
            c = st[G_CHANGES + i * CH_LEN : G_CHANGES + (i + 1) * CH_LEN].tolist()
            why = _reason_text(self.settings, c[CH_REASON], c[CH_A], c[CH_P], self._problems())
            out.append(SelectionChange(_opt(c[CH_OLD]), _opt(c[CH_NEW]), why, _opt(c[CH_BAD])))
        st[G_N_CHANGES] = 0
        return out

    def instances(self) -> tuple[InstanceStatus, ...]:
        """Every instance seen, with its state as of the last sample (read-only: no re-evaluation)."""
        st, out = self.st, []
        sel = self.selected
        for k in range(MAX_SLOTS):
            b = G_INST + k * I_LEN
            if st[b + I_SEEN]:
                p = int(select_problem(st, self.fs, k))
                out.append(InstanceStatus(k, self.source_of(k) or "", int(st[b + I_SAMPLES]),
                                          PROBLEM_NAMES[p] or "ok", k == sel))  # fmt: skip
        return tuple(out)

    def n_instances(self) -> int:
        """Instances seen so far."""
        return sum(1 for k in range(MAX_SLOTS) if self.st[G_INST + k * I_LEN + I_SEEN])

    def source_of(self, imu_id: int) -> str | None:
        """The message carrying instance ``imu_id`` (None: not seen)."""
        if not 0 <= imu_id < MAX_SLOTS or not self.st[G_INST + imu_id * I_LEN + I_SEEN]:
            return None
        return self._names[int(self.st[G_INST + imu_id * I_LEN + I_SOURCE])]

    def is_absent(self, imu_id: int) -> bool:
        return 0 <= imu_id < MAX_SLOTS and bool(self.st[G_INST + imu_id * I_LEN + I_SEEN]) and bool(
            self.st[G_INST + imu_id * I_LEN + I_ABSENT]
        )
