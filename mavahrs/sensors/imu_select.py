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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mavahrs.errors import ConfigError
from mavahrs.sensors.sample import ACCEL, GYRO
from mavahrs.sensors.scaling import S_SAT, Scaled

__all__ = ["ImuSelectSettings", "ImuSelector", "InstanceStatus", "SelectionChange", "MAX_INSTANCES"]

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


@dataclass
class _Inst:
    imu_id: int
    source: str
    samples: int = 0
    last_t_us: int = 0
    zero_run: int = 0
    absent: bool = False
    nonzero_seen: bool = False
    prev: tuple[float, ...] = ()
    same_count: int = 0
    same_since_us: int = 0
    #: running share of recent samples whose accel+gyro differed from the previous one's (time constant freeze_s/2)
    change_rate: float = 0.0
    #: the other instances' smoothed values when this instance's current run of identical values began
    run_marks: dict[int, tuple[float, ...]] = field(default_factory=dict)
    last_sat_us: int = -(10**18)
    sat_since_us: int = -(10**18)
    ema: list[float] = field(default_factory=lambda: [0.0] * 6)
    ema_ready: bool = False
    disagree_since_us: int | None = None
    healthy_since_us: int | None = None


class ImuSelector:
    """Per-sample decision: does this instance's sample feed the filter?"""

    def __init__(self, settings: ImuSelectSettings | None = None) -> None:
        self.settings = settings or ImuSelectSettings()
        s = self.settings
        self._stale_us = int(s.stale_s * 1e6)
        self._freeze_us = int(s.freeze_s * 1e6)
        self._change_tau_us = 0.5 * s.freeze_s * 1e6
        self._sat_us = int(s.saturation_hold_s * 1e6)
        self._disagree_us = int(s.disagree_s * 1e6)
        self._recover_us = int(s.recover_s * 1e6)
        self._eval_us = 20_000  # re-evaluate the choice at most every 20 ms of autopilot time
        self.reset()

    def reset(self) -> None:
        """Forget every instance (autopilot reboot, new link)."""
        self._inst: dict[int, _Inst] = {}
        self.selected: int | None = self.settings.fixed
        self.reason = "waiting for IMU data"
        self._reported: int | None = None
        self._t_latest = 0
        self._resume_us = 0
        self._last_eval_us = -(10**18)
        self._changes: list[SelectionChange] = []
        #: samples refused because another message already carries the instance
        self.duplicate_source = 0

    # ------------------------------------------------------------------ per sample
    def observe(self, source: str, v: Scaled) -> bool:
        """Record one scaled sample; True when it should feed the filter."""
        imu_id, t = v[0], v[1]
        inst = self._inst.get(imu_id)
        if inst is None:
            inst = self._inst[imu_id] = _Inst(imu_id, source, last_t_us=t)
        elif inst.source != source:
            if t - inst.last_t_us <= self._stale_us and inst.samples:
                self.duplicate_source += 1
                return False
            inst.source = source  # the old message stopped: follow the new one
        if t - self._t_latest > self._stale_us and self._t_latest:
            self._resume_us = t  # every instance was silent (link outage): judge staleness from here
        if t > self._t_latest:
            self._t_latest = t
        dt_us = t - inst.last_t_us
        inst.samples += 1
        inst.last_t_us = t
        gx, gy, gz, ax, ay, az = v[2], v[3], v[4], v[5], v[6], v[7]
        # all-zero accel and gyro: no such IMU
        if gx == 0.0 and gy == 0.0 and gz == 0.0 and ax == 0.0 and ay == 0.0 and az == 0.0:
            inst.zero_run += 1
            if inst.zero_run >= self.settings.zero_samples or not inst.nonzero_seen:
                if not inst.absent:
                    inst.absent = True
                    self._evaluate(force=True)
            return False
        inst.zero_run = 0
        inst.nonzero_seen = True
        if inst.absent:
            inst.absent = False
            inst.healthy_since_us = None
        # frozen: identical values
        cur = (gx, gy, gz, ax, ay, az)
        same = cur == inst.prev
        if same:
            inst.same_count += 1
            if inst.same_count == 2:  # a run of identical values begins: where are the others?
                inst.run_marks = {o.imu_id: tuple(o.ema) for o in self._inst.values() if o is not inst and o.ema_ready}
        else:
            inst.prev = cur
            inst.same_count = 1
            inst.same_since_us = t
        if dt_us > 0:
            a = dt_us / (self._change_tau_us + dt_us)
            inst.change_rate += a * ((0.0 if same else 1.0) - inst.change_rate)
        if v[S_SAT] & (GYRO | ACCEL):
            if t - inst.last_sat_us > self._sat_us:
                inst.sat_since_us = t  # a new saturation episode
            inst.last_sat_us = t
        # smoothing for the disagreement check (NaN-free values only)
        if ax == ax and gx == gx:
            e = inst.ema
            if inst.ema_ready and dt_us > 0:
                dt = dt_us * 1e-6
                a = dt / (self.settings.smoothing_s + dt)  # first-order low-pass
                for i in range(6):
                    e[i] += a * (cur[i] - e[i])
            else:
                e[:] = cur
                inst.ema_ready = True
        if t - self._last_eval_us >= self._eval_us or self.selected is None:
            self._evaluate()
        return imu_id == self.selected and not inst.absent

    # ------------------------------------------------------------------ decisions
    def _problems(self, inst: _Inst) -> str:
        t = self._t_latest
        if inst.absent:
            return "absent (all-zero)"
        if t - max(inst.last_t_us, self._resume_us) > self._stale_us:
            return "stale"
        if (
            inst.same_count >= self.settings.freeze_min_samples
            and t - inst.same_since_us >= self._freeze_us
            and self._others_changed(inst)
        ):
            return "frozen"
        if t - inst.last_sat_us <= self._sat_us:
            return "saturated"
        if inst.disagree_since_us is not None and t - inst.disagree_since_us >= self._disagree_us:
            return "disagrees"
        return ""

    def _others_changed(self, inst: _Inst) -> bool:
        """While ``inst`` repeats its values: does another live instance change in most of its recent samples
        (noise), or have its smoothed values moved clearly since the repeats began (motion)?"""
        t = self._t_latest
        s = self.settings
        for o in self._inst.values():
            if o is inst or o.absent or t - o.last_t_us > self._stale_us or o.samples < s.freeze_min_samples:
                continue
            if o.change_rate >= s.freeze_other_change_fraction:
                return True
            mark = inst.run_marks.get(o.imu_id)
            if mark is not None and o.ema_ready:
                e = o.ema
                dg = math.sqrt((e[0] - mark[0]) ** 2 + (e[1] - mark[1]) ** 2 + (e[2] - mark[2]) ** 2)
                da = math.sqrt((e[3] - mark[3]) ** 2 + (e[4] - mark[4]) ** 2 + (e[5] - mark[5]) ** 2)
                if dg > s.freeze_motion_gyro_rad_s or da > s.freeze_motion_accel_m_s2:
                    return True
        return False

    def _update_disagreement(self) -> None:
        t = self._t_latest
        live = [i for i in self._inst.values() if not i.absent and i.ema_ready and t - i.last_t_us <= self._stale_us]
        # (after a link outage the instances that have not spoken again simply do not vote)
        if len(live) < 3:
            for i in self._inst.values():
                i.disagree_since_us = None
            return
        med = [sorted(i.ema[k] for i in live)[len(live) // 2] for k in range(6)]
        g_lim, a_lim = self.settings.disagree_gyro_rad_s, self.settings.disagree_accel_m_s2
        for i in live:
            e = i.ema
            dg = math.sqrt((e[0] - med[0]) ** 2 + (e[1] - med[1]) ** 2 + (e[2] - med[2]) ** 2)
            da = math.sqrt((e[3] - med[3]) ** 2 + (e[4] - med[4]) ** 2 + (e[5] - med[5]) ** 2)
            if dg > g_lim or da > a_lim:
                if i.disagree_since_us is None:
                    i.disagree_since_us = t
            else:
                i.disagree_since_us = None

    def _evaluate(self, force: bool = False) -> None:
        t = self._t_latest
        self._last_eval_us = t
        self._update_disagreement()
        problems = {}
        for inst in self._inst.values():
            p = self._problems(inst)
            problems[inst.imu_id] = p
            if p:
                inst.healthy_since_us = None
            elif inst.healthy_since_us is None:
                inst.healthy_since_us = t
        old = self.selected
        fixed = self.settings.fixed
        if fixed is not None:
            p = problems.get(fixed)
            if p is None:
                self._set(fixed, f"fixed by --imu {fixed}; no data from it yet")
            else:
                self._set(fixed, f"fixed by --imu {fixed}" + (f" ({p})" if p else ""))
            return
        healthy = sorted(k for k, p in problems.items() if not p)
        if old is not None and old in healthy:
            # stay, unless a lower-numbered instance has been healthy long enough
            for k in healthy:
                if k < old and t - (self._inst[k].healthy_since_us or t) >= self._recover_us:
                    self._set(k, f"instance {k} healthy again for {self.settings.recover_s:g} s")
                    return
            keep = not self.reason.startswith(("waiting", "no "))
            self._set(old, self.reason if keep else "healthy")
            return
        if healthy:
            why = "first healthy instance" if old is None else f"instance {old} {problems.get(old) or 'gone'}"
            bad = self._bad_since(old, problems.get(old, "")) if old is not None else None
            self._set(healthy[0], why, bad)
            return
        # nothing healthy: keep what is there if it still delivers, else any delivering instance
        usable = sorted(k for k, p in problems.items() if p not in ("absent (all-zero)", "stale"))
        if old is not None and old in usable:
            self._set(old, f"no healthy instance; keeping {old} ({problems[old]})")
        elif usable:
            self._set(usable[0], f"no healthy instance; using {usable[0]} ({problems[usable[0]]})")
        else:
            self._set(None, "no usable IMU instance" + ("" if not problems else f" ({_describe(problems)})"))

    def _bad_since(self, imu_id: int, problem: str) -> int | None:
        inst = self._inst.get(imu_id)
        if inst is None:
            return None
        if problem == "frozen":
            return inst.same_since_us
        if problem == "saturated":
            return inst.sat_since_us
        if problem == "disagrees" and inst.disagree_since_us is not None:
            return inst.disagree_since_us - int(2e6 * self.settings.smoothing_s)  # the smoothing's lag
        return None

    def _set(self, new: int | None, reason: str, bad_since_us: int | None = None) -> None:
        if new != self._reported:
            self._changes.append(SelectionChange(self._reported, new, reason, bad_since_us))
            self._reported = new
        self.selected = new
        self.reason = reason

    # ------------------------------------------------------------------ reporting
    def pop_changes(self) -> list[SelectionChange]:
        """Selection changes since the last call (for notices)."""
        out, self._changes = self._changes, []
        return out

    def instances(self) -> tuple[InstanceStatus, ...]:
        """Every instance seen, with its state as of the last sample (read-only: no re-evaluation)."""
        return tuple(
            InstanceStatus(i.imu_id, i.source, i.samples, self._problems(i) or "ok",
                           i.imu_id == self.selected)  # fmt: skip
            for i in sorted(self._inst.values(), key=lambda i: i.imu_id)
        )

    def is_absent(self, imu_id: int) -> bool:
        inst = self._inst.get(imu_id)
        return inst is not None and inst.absent


def _describe(problems: dict[int, str]) -> str:
    return ", ".join(f"{k}: {p or 'ok'}" for k, p in sorted(problems.items()))
