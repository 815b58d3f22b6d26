r"""A second opinion on the autopilot's attitude.

mavahrs estimates the attitude independently of the autopilot's own estimator
(ArduPilot's EKF, PX4's EKF2).  When the two disagree for a while, one of them
is wrong — an estimator divergence, a failing IMU or magnetometer — and that is
what a pilot wants to hear.  :class:`AttitudeMonitor` (pure: time is passed in,
no I/O) compares them:

* our estimates come in with :meth:`AttitudeMonitor.add_estimate`
  (``time_boot_ms`` of the IMU sample they were computed from, and the
  ``q_body_to_ned`` *as published*, i.e. after the declination correction);
* the autopilot's ATTITUDE (Euler roll/pitch/yaw) or ATTITUDE_QUATERNION come in
  with :meth:`AttitudeMonitor.handle`; each is aligned with our estimates by
  ``time_boot_ms`` (both are the autopilot's boot clock) — interpolated
  between the two estimates around it, or the nearest one within
  ``align_tolerance_ms``;
* the divergence is the earth-frame error ``e = q_ours ⊗ q_autopilot*`` split
  as in BROAD (Laidig et al. 2021): tilt ``2·acos√(e_w² + e_z²)`` and heading
  ``2·atan(e_z/e_w)`` (signed, degrees);
* :meth:`AttitudeMonitor.tick` publishes both as NAMED_VALUE_FLOAT
  (``AHRS_TILT``, ``AHRS_HDG``) at ``rate_hz``;
* a STATUSTEXT at WARNING severity is raised once per episode when the
  divergence stays above its threshold for ``trigger_s`` (autopilot time), and
  one at INFO when it has stayed below ``clear_fraction`` × threshold for
  ``clear_s`` (hysteresis).

The methods return pymavlink message objects; the caller (the pipeline)
encodes them with its codec.  :func:`divergence_series` is the same
computation on whole arrays, for replay plots, and :func:`monitor_series`
runs the monitor's state machine over arrays and lists its warnings.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.geometry.quaternion import slerp
from mavahrs.geometry.rotation import euler_to_q_scalar
from mavahrs.protocol.codec import mavlink

__all__ = [
    "MonitorSettings",
    "MonitorStatus",
    "AttitudeMonitor",
    "MonitorEvent",
    "MonitorSeries",
    "divergence_series",
    "align_attitudes",
    "monitor_series",
    "attitude_of_message",
    "attitude_divergence_rad",
    "WARNING_TEXT",
    "IMU_TEXT",
    "PHASE_TEXT",
    "CLEARED_TEXT",
    "FlightPhase",
    "phase_events_of_arrays",
    "Evidence",
    "MonitorSensors",
]

Array = NDArray[np.float64]

#: STATUSTEXT raised in flight when the divergence is confirmed (formatted with the values, deg; ≤ 50 chars).
WARNING_TEXT = "mavahrs: AP off: tilt {tilt:.1f} hdg {heading:+.1f}"
#: The same on the ground, at take-off or touchdown (a NOTICE; ``phase`` from :data:`PHASE_WORDS`).
PHASE_TEXT = "mavahrs {phase}: AP off: tilt {tilt:.1f} hdg {heading:+.1f}"
#: How a phase is named in :data:`PHASE_TEXT`.
PHASE_WORDS = {"disarmed": "disarmed", "ground": "on ground", "takeoff": "take-off", "touchdown": "touchdown"}
#: Phases in which a disagreement is an in-flight WARNING ("unknown": the stream does not tell).
FLIGHT_PHASES = ("air", "unknown")
#: STATUSTEXT raised when one IMU's gyro disagrees with the others and with the autopilot's attitude (deg/s).
IMU_TEXT = "mavahrs: {imu} gyro off by {rate:.1f} dps [{imu}?]"
#: STATUSTEXT sent when it has cleared.
CLEARED_TEXT = "mavahrs: AP attitude agrees again"

_STATUSTEXT_MAX = 50
_NAME_MAX = 10
_REBOOT_MS = 1000.0  # time going back by more than this = autopilot reboot
_MAX_PENDING = 64
_EVIDENCE_PERIOD_MS = 1000.0  # while a disagreement is on, its evidence is looked at again this often
_MAX_UPDATES = 3  # … and said again, with what is new, at most this many times per episode
_STRIP_STEP_MS = 500.0  # the strip chart's history: a point per this, and every warning
_INTERVALS = 7  # autopilot attitude intervals kept for the typical one (median)




class _RecentRows:
    """The last seconds of ``(t_ms, e_north, e_east, e_down, ω_north, ω_east, ω_down, q_w, q_x, q_y, q_z)`` rows
    (the divergence vector, our earth-frame turn rate, rad/s, and our attitude, body→NED, beside it), oldest
    first: a deque's ``append`` /
    ``popleft`` / ``clear`` over one growing array, which the step test reads whole on every comparison
    (copying a deque of tuples into an array each time was most of a .ulg's monitor at EKF2's 250 Hz)."""

    def __init__(self, capacity: int = 64, width: int = 11) -> None:
        self._rows = np.empty((capacity, width))
        self._first = self._end = 0

    def append(self, row: Sequence[float]) -> None:
        if self._end == len(self._rows):  # full: move the live rows to the front, twice the room if half full
            live = self._end - self._first
            rows = np.empty((2 * len(self._rows), self._rows.shape[1])) if 2 * live > len(self._rows) else self._rows
            rows[:live] = self._rows[self._first : self._end]
            self._rows, self._first, self._end = rows, 0, live
        self._rows[self._end] = row
        self._end += 1

    def popleft(self) -> None:
        self._first += 1

    def clear(self) -> None:
        self._first = self._end = 0

    def array(self) -> NDArray[np.float64]:
        """The rows, oldest first (a view: valid until the next ``append``)."""
        return self._rows[self._first : self._end]

    def __len__(self) -> int:
        return self._end - self._first

    def __getitem__(self, k: int) -> NDArray[np.float64]:
        return self.array()[k]

    def __iter__(self) -> Any:
        return iter(self.array().tolist())

@dataclass(frozen=True)
class MonitorSettings:
    """How the autopilot's attitude is compared and when to complain.

    Attributes:
        enabled: compare at all.
        rate_hz: NAMED_VALUE_FLOAT publication rate, Hz (1–5; 0 = do not publish).
        mode: ``uncertainty`` (default): the thresholds follow what both
            estimators' errors allow (below); ``fixed``: the fixed angles
            ``tilt_threshold_deg`` / ``heading_threshold_deg``, a WARNING when
            the divergence stays above one of them for ``trigger_s``.
        sigma_k: ``uncertainty``: the threshold is this many times the combined
            1-σ of the difference, ``k·√(σ_ours² + σ_autopilot² + (ω·sync_s)²)``
            (tilt and heading each), and at least ``min_tilt_threshold_deg`` /
            ``min_heading_threshold_deg``.  Our σ is the filter's own (the
            ESKF's tilt and heading covariance, while GNSS-velocity-aided; its
            heading σ grows in fast rotation with the gyro's scale-factor
            error, ``EskfSettings.gyro_scale_sigma``) or the ``unaided_*``
            figure; the ESKF's σ is conservative (≈ 0.5° where its
            error is 0.05–0.2°), hence a k of 2 (1.4° of tilt, 3.6° of heading
            while aided).
        autopilot_tilt_sigma_deg, autopilot_heading_sigma_deg: the autopilot's
            1-σ error as the test allows it, deg: the tolerance, an autopilot
            within 1° of tilt and 3° of heading of the truth is not one to warn
            about, at ``sigma_k`` = 2 σ (0.5°, 1.5°).  (Its typical error is
            less — EKF3 on SITL ≈ 0.25° inclination, ≈ 1° heading; firmware_sim's
            simulated autopilot 0.3° per tilt axis — but within the tolerance it
            reaches 0.8–0.9° of tilt for seconds, and with our own error of
            about 0.5° the other way the divergence then reaches 1.2–1.3°, which
            a tilt term of 0.3° warned about on firmware_sim's magnetic flight.)
        heading_sigma_deg: our heading 1-σ while velocity-aided, deg: the
            least the test assumes.  The ESKF gives its own with each estimate
            (``OUT_HEADING_SIGMA``, :meth:`AttitudeMonitor.add_estimate`), used
            where it is larger (after a fast yaw, with the gyro's scale-factor
            error: up to 3°); a filter without a covariance gets this.  (A floor:
            in a hover the ESKF's heading σ, ≈ 0.7°, is a little below its
            error, 0.75° RMS on firmware_sim's hover 1, and taken alone it
            warned falsely once on the hover flight of seed 12.)
        unaided_tilt_sigma_deg, unaided_heading_sigma_deg: our 1-σ without
            GNSS velocity (Madgwick configuration: ≈ 2° inclination RMS in
            aggressive flight), deg.
        sync_s: timing uncertainty between the two estimates (the autopilot's
            attitude vs our sample of the same ``time_boot_ms``), s: a time
            offset δ makes the divergence ``q(t) ⊗ q(t − δ)*``, the earth-frame
            turn over δ, so its horizontal part ω_h·sync_s enters the tilt
            thresholds and its vertical part ω_v·sync_s the heading's (a yaw spin
            at 400°/s adds 2° to the heading's, not to the tilt's: firmware_sim
            aggressive 3, a 2° tilt step mid-spin warned after 3.6 s with the
            whole rate in both, 0.5 s split).
        min_tilt_threshold_deg, min_heading_threshold_deg: floors of the
            ``uncertainty`` thresholds, deg.
        heading_tolerance_floor: ``uncertainty``: the heading threshold is also
            at least ``sigma_k`` × (σ_autopilot + σ_ours): the autopilot's
            tolerance (3°) plus our own error at ``sigma_k`` σ, added rather
            than in quadrature.  The quadrature sum treats the autopilot's
            error as noise; its heading error is a compass error correlated
            for minutes, which can stand at the tolerance's edge while ours
            lies the other way (firmware_sim magnetic 3 at 147.6 s: the
            simulated autopilot 2.90° off, ours 0.7° the other way, a
            divergence of 3.67° against 3.61°, the level CUSUM built up over 3 s
            at 0.8–0.97 × the threshold: a WARNING for an autopilot inside its
            tolerance).  The least favourable autopilot the tolerance lets
            pass, not a tuned figure: with our σ at its 1° floor 5.0°.  Not for
            the tilt, which every GNSS fix observes (its error is short-lived:
            the quadrature sum holds, and tol + 2σ, 2.0°, would hide the 2°
            step this monitor is built for).
        cusum_reference: ``uncertainty``: the sequential test (a one-sided
            CUSUM, Page 1954) accumulates ``(z − cusum_reference)·Δt`` where
            ``z`` = divergence / threshold (the larger of tilt and heading,
            capped at 3); below the reference it leaks at most
            ``cusum_leak_per_s`` per second, so repeated short excursions add
            up (the sum is kept within twice the alarm level).  A WARNING when the sum reaches ``(1 − cusum_reference)·trigger_s``
            while ``z ≥ 1``: a divergence at the threshold warns after
            ``trigger_s``, twice the threshold after a fifth of it, a slow drift
            once the excess has built up.  0.75: halfway between the ratio
            the divergence keeps with no fault (≈ 0.5: our error and the
            autopilot's at their σ, the larger of tilt and heading) and 1 (Page's
            reference for a shift from one mean to the other); at 0.5 the sum
            grew from a no-fault divergence correlated over seconds (at 0.5–0.8
            of the threshold) to its cap, and one comparison at the threshold
            then warned (firmware_sim magnetic 91 at 131.3 s, the autopilot
            0.89° off; docs/monitor.md round twenty-two).
        cusum_leak_per_s: see ``cusum_reference``, 1/s.
        mag_norm_tolerance, mag_dip_tolerance_deg: who is likely wrong, the
            magnetometer: with a WARNING, ``[mag]`` when the measured field
            (median of the last 3 s) differs from the expected one (the
            geomagnetic model's, as the filter's rejection uses it) by more
            than this fraction of its strength or this much dip, deg.
        gnss_window_s, gnss_ratio, gnss_min_m_s: … the GNSS velocity: the
            specific force rotated into NED by each attitude and integrated
            over ``gnss_window_s`` must match the GNSS velocity change (a tilt
            error δ adds g·sin δ of horizontal acceleration, 1.0 m/s over 3 s
            for 2°).  ``[AP?]`` when, along the direction in which the two
            attitudes' integrals differ, the autopilot's misses the GNSS
            velocity change by more than ``gnss_ratio`` × ours (least squares
            over the windows of the last 3 × ``gnss_window_s``; see
            :class:`Evidence`) and they differ by at least ``gnss_min_m_s``,
            ``[us?]`` the other way round.  A disagreement in heading alone
            (the tilt within its threshold) needs them to differ by at least
            ``gnss_heading_min_m_s``: a heading error shows only through the
            horizontal acceleration it turns, in the manoeuvres in which the
            GNSS velocity's own lag is largest (no verdict, rather than a
            wrong one, below it).
        gnss_max_share_se: … and no verdict either way while the share's
            standard error is above this: the integration's own error (the
            accelerometer's bias and scale, the sensors' timing in fast
            manoeuvres) estimated from our miss *across* the difference, as
            large along it, over the difference, windows ``gnss_window_s`` apart
            counted as independent.  At 0.3 the two answers (share 0: the
            autopilot is off, 1: we are) lie 3.3 σ apart.  On firmware_sim
            (our attitude 0.2–0.4° from the truth, the simulated autopilot
            1–2.8° off) every ``us?`` was wrong and came with a standard error
            of 0.37–0.69 (the shared aggressive flight at 55.8 s: 0.41); the
            correct ``AP?`` verdicts 0.06–0.53 (six of the 30 above 0.3 are
            now no verdict).  The evidence is looked at again
            every second while the warning is on and the STATUSTEXT said again
            (up to 3 times) when it names something new.
        learn_k, learn_s: ``uncertainty``: the thresholds are also at least
            ``learn_k`` × the RMS of the divergence seen so far (a running
            mean over the first ``learn_s`` of comparisons, then an
            exponential one with that time constant; comparisons beyond the
            thresholds of the error model alone, or during a warning, are not
            learnt): where the two
            estimators' errors are larger than the model says (an autopilot
            whose own tilt error is 0.6° RMS), the test widens to what they
            really are, s.
        learn_max_rate_dps: … learnt only while our angular rate is at most
            this, deg/s: in a fast rotation the two estimates' timing (the
            ``sync_s`` term, ω·sync_s: 2° at 400°/s) dominates the divergence;
            it has its own term in the threshold, and learnt as the flight's
            normal divergence it raised the threshold everywhere after the
            spins and flips (firmware_sim aggressive 3, flips 1: a learnt
            1.9° that delayed a 2° tilt step to 3.6–4.0 s).  At 60°/s the
            timing term is 0.3°, under half the estimators' combined σ.
        learn_max_factor: … and the learnt threshold is at most this many
            times the error model's own (tilt and heading each): what is learnt
            widens the test by at most this share, so that a flight whose
            divergence runs near the model's threshold for a while (the
            autopilot's own heading 2° off on ArduCopter SITL's magnetic flight:
            a learnt 5.0° against the model's 3.6°) still warns of a step of
            the size the model is built for.
        change_test: ``uncertainty``: also test the divergence for a *change*
            (:class:`_ChangeTest`): a step fault is a change of the divergence
            against its own recent baseline, found whatever standing error of
            the autopilot's it lands on (an autopilot 0.9° off the other way
            hides most of a 2° step from the absolute test above).  The
            baseline is an exponential mean of the divergence vector (earth
            frame) over ``change_baseline_s`` of comparisons ``change_delay_s``
            old, frozen while a warning is on (at most 3 × ``change_baseline_s``);
            the change's tilt and heading are each divided by ``change_k`` ×
            their own RMS learnt over the flight (as ``learn_s``, below
            ``learn_max_rate_dps``, only within the change's thresholds), at
            least ``change_min_tilt_deg`` / ``change_min_heading_deg``, with the
            timing term, and at most ``change_max_factor`` × the error model's
            thresholds above; the change counts only where the divergence
            itself is beyond the floors ``min_tilt_threshold_deg`` /
            ``min_heading_threshold_deg`` (an autopilot within 1° / 3° is not one
            to warn about, whatever its error did).  Its own CUSUM
            (``change_cusum_reference``).  Only while our estimate is
            GNSS-velocity-aided (our unaided error drifts); the baseline starts
            again when the aiding comes back.
        change_k: see ``change_test``.
        change_baseline_s, change_delay_s: see ``change_test``, s.
        change_min_tilt_deg, change_min_heading_deg: see ``change_test``, deg.
        change_max_factor: see ``change_test``: the change's thresholds at most
            this many times the error model's (the absolute test's without the
            learnt part).
        change_in_warning_s: a new step while a warning is already on (the
            autopilot off for a while, then a fault on top): the divergence
            vector against its own mean *since the warning* (comparisons
            ``change_delay_s`` old, as the baseline above, used once fed this
            long), judged with the change test's thresholds and floors and
            CUSUM, raises a new in-flight WARNING (a new episode) where the
            divergence is also beyond its absolute threshold — without it the
            warning already on hides the fault, s (0 = off).  The change counts
            only where it leads away from agreement, and at most as far as the
            divergence is from where it was when the warning was raised and as
            it moved over the last ``change_delay_s`` (the same disagreement
            coming and going, or growing on, is the warning already on).
            (firmware_sim aggressive 21: a correct WARNING at 95.4 s, the
            simulated autopilot 1.6° off, was still on when a 2° step came at
            100 s: no WARNING for it; now 0.2 s.)
        change_step_s: a step in the first seconds of a warning, before the
            in-warning baseline (``change_in_warning_s``) is fed: over the last
            this many seconds of divergence vectors, the split into a segment
            before and one after that best shows a change in the mean (the
            generalised likelihood ratio's estimate; the segment before may lie
            before the warning, the split at least an eighth of this after it),
            judged as the in-warning
            test (thresholds, floors, CUSUM, away from agreement and from the
            disagreement warned of, its mean over these seconds before the
            warning) — without it a fault within 4 s after a correct warning
            was never warned (held-out firmware_sim aggressive 41 and 43: a
            WARNING at 99.5 s, the fault at 100 s), s (0 = off).
        change_step_spread_k: … counted only where the change is at least this
            many times the two segments' pooled RMS spread about their means: a
            step, not the autopilot's own error turning with the vehicle (on
            firmware_sim aggressive 42 a 2–2.5° tilt divergence circling once
            in 2–3 s; at 2 and 3 × it gave 2–7 more WARNINGs per flight there).
        change_step_body_fixed: within a warning, the tilt step test of
            ``change_step_s`` fits each split with a rotation fixed in the
            vehicle's body (seen in the earth frame through our attitude)
            beside the two segments' levels, and judges the levels' change and
            the spread about that fit (:func:`_body_fixed_split`): an error of
            the autopilot's fixed in its body circles in the earth frame as the
            vehicle yaws, and was spread as large as the step (firmware_sim
            aggressive 33: a 2° step under a correct warning in a 150°/s spin
            warned after 14.5 s; 1.5 s with it).  Without turning it is the
            plain split.
        change_baseline_turn: ``change_test``'s tilt against a baseline that may
            hold a part fixed in the vehicle's heading axes (an accelerometer
            bias's tilt error, the autopilot's or ours, turns with the vehicle
            in the earth frame): the baseline's comparisons fitted as a level
            fixed in the earth frame plus one fixed in our heading's axes (a
            Gaussian prior on it of the error model's level variance, σ_ours² +
            σ_autopilot²), predicted at our heading now; the change's
            threshold widened by that prediction's own variance (a turn since
            a baseline without turns: the prior's whole variance; where the
            baseline turned, small).  Off: the plain earth-frame mean.
        change_step_outside: the step test of ``change_step_s`` also outside
            a warning, beside the change test's baseline: over the last
            ``change_step_s`` the split that best shows a change in the mean,
            at least ``change_step_spread_k`` × the segments' pooled spread,
            away from agreement, as the change test's ratio (thresholds,
            floors, CUSUM).  The change test's 10 s baseline lags an autopilot
            error that moves by a degree over tens of seconds, so a step
            against it shows as a part of itself (firmware_sim aggressive 63:
            the divergence +1.0° → −1.0° north, a change of 1.2° against the
            baseline, 1.43° threshold: warned after 5.1 s; the split sees 2.0°).
        change_drift_s: a disagreement that *grows* while a warning is on (a
            ramp that starts under a correct warning: within any 2 s it moves
            too little for the step tests above): the divergence vector against
            the level the warning stands at (its mean over the warning's first
            ``change_step_s``), judged with the change test's thresholds — the
            noise of a change of the divergence, learnt before the warning —
            and floors, away from agreement, only where the divergence is also
            beyond its absolute threshold, and at most as far as the divergence
            is from every level it took in the ``change_step_s`` before the
            warning and its first ``change_step_s`` (an intermittent fault
            coming back is the warning already on), in a CUSUM of its own
            (reference ``change_cusum_reference``) that must reach this many
            seconds' worth at the threshold: the growth must last, s (0 = off).
            Once per warning: a WARNING it raised is not raised again as the
            disagreement grows on.  (firmware_sim aggressive 41 / 43: a 0.2°/s
            tilt ramp 0.5 s after a correct WARNING, never warned / after 16.2 s
            (3.2°) without it; 11.1 / 13.4 s, 2.2° / 2.7°, with it.)
        change_drift_slope_s: the growth the warning already stood on is
            not a new fault: the divergence's least-squares line over this
            many seconds, ending ``change_step_s`` into the warning (the
            window the warning's level is taken from and the seconds before
            it), extrapolated, is one more reference the drift test measures
            from (the nearest counts), where the line fits — its residual
            RMS within the change test's noise (threshold / ``change_k``) on
            that axis; counted only away from agreement and beyond the line's
            slope error by then (``change_k`` standard errors × the time
            since): a ramp already under way when warned grows along it and
            is the warning already on; a ramp that starts under the warning,
            a steeper slope or a step leaves it, s (0 = off).  (ArduCopter
            SITL gentle, a 0.2°/s tilt ramp: WARNINGs at 106.2 and 113.7 s
            without it, 106.2 s alone with it.)
        change_heading_sigma_growth: ``uncertainty``: the change test's heading
            cap takes our heading σ as far as it has *grown* within the
            baseline's span (``change_delay_s`` + ``change_baseline_s``): √(σ_floor²
            + σ_now² − σ_least²), σ_least our least σ over that span (at least
            the floor ``heading_sigma_deg``), instead of σ_now.  A change of the
            divergence is a change of the two errors: ours moves as far as its
            uncertainty has grown (a disturbed magnetometer, a spin: the
            error variance added since), not as far as a σ that stands high
            (firmware_sim hover 12: our σ 1.16° for a minute, our error −0.85°,
            the simulated autopilot's heading 3.6° off, a change of 3.9–4.1°
            against a 3.80° cap with σ_now: the correct WARNING at 148.0 s
            lost; docs/monitor.md, round fifteen).
        change_cusum_reference: the change test's own CUSUM, as
            ``cusum_reference`` (a WARNING when it reaches
            ``(1 − change_cusum_reference)·trigger_s`` with the change beyond
            its threshold): higher than the absolute test's, so that a change
            that lingers below its threshold (the autopilot's own error
            wandering for seconds) does not add up to one.
        tilt_threshold_deg: ``fixed``: tilt divergence that counts as a disagreement, deg.
        heading_threshold_deg: ``fixed``: heading divergence that counts, deg
            (0 = never alarm on heading, in either mode).
        trigger_s: ``fixed``: the divergence must last this long
            (continuously, in the autopilot's time) before the WARNING;
            ``uncertainty``: the CUSUM's scale (above), s.
        clear_s: it must stay below ``clear_fraction`` × threshold this long
            before the INFO "agrees again", s.
        clear_fraction: hysteresis factor on the thresholds for clearing.
        startup_grace_s: comparisons in the first seconds after our first
            estimate (or a :meth:`AttitudeMonitor.reset`) are published but do
            not count: both estimators may still be converging, s.
        min_imu_rate_hz: comparisons are not judged while fewer IMU samples
            per second than this reach our filter (the pipeline's
            ``low_imu_rate_hz``): at a ground station's 2–10 Hz stream our
            estimate cannot follow a manoeuvre (firmware_sim ``aggressive``
            at 4 / 10 / 25 Hz: 85 / 28 / 0.6° inclination error, with 1–17
            false WARNINGs), and its σ does not say so.  They are published
            (NAMED_VALUE_FLOAT, status) with no threshold; once the rate is
            back, ``startup_grace_s`` again (our filter re-converges).  Hz; 0 =
            judge at any rate.
        align_tolerance_ms: the autopilot's sample is compared with our
            estimate at the same time: interpolated when our estimates around
            it are at most 2× this apart, else the nearest one within this, ms.
        max_gap_s: comparisons further apart than this — or than
            ``gap_intervals`` × the autopilot's typical attitude interval,
            whichever is longer — break "continuously" (and restart the
            CUSUM), s.  (ATTITUDE at 1 Hz, as a ground station's stream rate
            may leave it, arrives every 1.000 ± 0.003 s: a fixed 1 s would
            break every other step.)
        gap_intervals: see ``max_gap_s``; the typical interval is the median of
            the last few intervals between the autopilot's attitudes.
        history_s: how much of our estimate history is kept for alignment, s.
        autopilot_component_id: only attitudes from this component are
            compared (1 = MAV_COMP_ID_AUTOPILOT1; 0 = any).
        tilt_name: NAMED_VALUE_FLOAT name for the tilt divergence (≤ 10 chars).
        heading_name: NAMED_VALUE_FLOAT name for the heading divergence.
        receiver_velocity_only: judge the autopilot with an estimate aided
            only by the GNSS receiver's own velocity (GPS_RAW_INT, GPS2_RAW),
            never by GLOBAL_POSITION_INT, which is the autopilot EKF's output:
            the estimate the monitor judges is the pipeline's own, so this
            makes the pipeline's ``velocity_source = auto`` use GPS_RAW_INT,
            else GPS2_RAW (and rejects ``global_position_int``).  The
            published attitude is then receiver-aided as well.
        ground_alt_m, air_alt_m: the flight's phase where the stream has no
            EXTENDED_SYS_STATE, from GLOBAL_POSITION_INT: on the ground below
            ``ground_alt_m`` above home and slower than ``still_speed_m_s``,
            airborne above ``air_alt_m`` (in between: unchanged), m.
        still_speed_m_s: see ``ground_alt_m``, m/s.
        transition_s: the take-off phase lasts this long after leaving the
            ground, the touchdown phase this long after landing, s.  A
            disagreement raised on the ground, at take-off or touchdown is a
            NOTICE naming the phase, not an in-flight WARNING.
        strip_s: how much of the divergence history the status page's strip
            chart shows (:attr:`MonitorStatus.strip`), s.
        imu_rate_tolerance_dps, imu_window_s: several IMUs
            (:meth:`AttitudeMonitor.add_imu_gyro`): each IMU's gyro against
            the body rate of the autopilot's attitude, averaged over
            ``imu_window_s``; an IMU whose rate is off by more than the
            tolerance while every other one is within half of it is named
            (``IMU2?`` in the evidence) and warned about once; it stays named
            until its error is below half the tolerance, deg/s, s.  (Healthy
            IMUs on firmware_sim's aggressive flight: ≤ 1.1°/s over 10 s, from
            the autopilot's attitude lagging in fast turns.)
    """

    enabled: bool = True
    rate_hz: float = 2.0
    mode: str = "uncertainty"
    sigma_k: float = 2.0
    autopilot_tilt_sigma_deg: float = 0.5
    autopilot_heading_sigma_deg: float = 1.5
    heading_sigma_deg: float = 1.0
    unaided_tilt_sigma_deg: float = 1.5
    unaided_heading_sigma_deg: float = 3.0
    sync_s: float = 0.005
    min_tilt_threshold_deg: float = 1.0
    min_heading_threshold_deg: float = 3.0
    heading_tolerance_floor: bool = True
    cusum_reference: float = 0.75
    cusum_leak_per_s: float = 0.2
    learn_k: float = 2.5
    learn_s: float = 60.0
    learn_max_rate_dps: float = 60.0
    learn_max_factor: float = 1.25
    mag_norm_tolerance: float = 0.08
    mag_dip_tolerance_deg: float = 6.0
    gnss_window_s: float = 3.0
    gnss_ratio: float = 2.0
    gnss_min_m_s: float = 0.3
    gnss_max_share_se: float = 0.3
    gnss_heading_min_m_s: float = 1.0
    change_test: bool = True
    change_k: float = 3.0
    change_baseline_s: float = 10.0
    change_delay_s: float = 2.0
    change_min_tilt_deg: float = 0.3
    change_min_heading_deg: float = 1.5
    change_cusum_reference: float = 0.8
    change_max_factor: float = 1.0
    change_in_warning_s: float = 2.0
    change_step_s: float = 2.0
    change_step_spread_k: float = 4.0
    change_drift_s: float = 3.0
    change_drift_slope_s: float = 8.0
    change_step_outside: bool = True
    change_heading_sigma_growth: bool = True
    change_step_body_fixed: bool = True
    change_baseline_turn: bool = True
    tilt_threshold_deg: float = 10.0
    heading_threshold_deg: float = 25.0
    trigger_s: float = 1.5
    clear_s: float = 5.0
    clear_fraction: float = 0.7
    startup_grace_s: float = 10.0
    min_imu_rate_hz: float = 50.0
    align_tolerance_ms: float = 50.0
    max_gap_s: float = 1.0
    gap_intervals: float = 2.5
    history_s: float = 2.0
    autopilot_component_id: int = 1
    tilt_name: str = "AHRS_TILT"
    heading_name: str = "AHRS_HDG"
    receiver_velocity_only: bool = False
    ground_alt_m: float = 1.0
    air_alt_m: float = 2.0
    still_speed_m_s: float = 0.5
    transition_s: float = 5.0
    strip_s: float = 300.0
    imu_rate_tolerance_dps: float = 1.5
    imu_window_s: float = 10.0

    def __post_init__(self) -> None:
        if self.mode not in ("uncertainty", "fixed"):
            raise ValueError(f"monitor mode must be uncertainty or fixed, got {self.mode!r}")
        for name in ("sigma_k", "autopilot_tilt_sigma_deg", "autopilot_heading_sigma_deg", "heading_sigma_deg",
                     "unaided_tilt_sigma_deg", "unaided_heading_sigma_deg", "sync_s", "min_tilt_threshold_deg",
                     "min_heading_threshold_deg", "cusum_leak_per_s", "ground_alt_m", "still_speed_m_s",
                     "transition_s", "learn_k", "learn_s", "learn_max_rate_dps", "learn_max_factor", "strip_s",
                     "imu_rate_tolerance_dps", "gnss_heading_min_m_s", "gnss_max_share_se", "imu_window_s", "change_k",
                     "change_baseline_s", "change_delay_s", "change_min_tilt_deg", "change_min_heading_deg",
                     "change_max_factor", "change_in_warning_s", "change_step_s", "change_step_spread_k",
                     "change_drift_s", "change_drift_slope_s"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"monitor setting {name} must be ≥ 0, got {v!r}")
        if not (0.0 < self.cusum_reference < 1.0 and 0.0 < self.change_cusum_reference < 1.0):
            raise ValueError(f"monitor cusum_reference must be in (0, 1), got {self.cusum_reference!r}")
        if not (self.sigma_k > 0 and self.min_tilt_threshold_deg + self.unaided_tilt_sigma_deg > 0):
            raise ValueError("monitor sigma_k and the tilt thresholds must be > 0")
        if not self.air_alt_m >= self.ground_alt_m:
            raise ValueError("monitor air_alt_m must be ≥ ground_alt_m")
        if not (self.rate_hz == 0.0 or 1.0 <= self.rate_hz <= 5.0):
            raise ValueError(f"monitor rate_hz must be 1–5 Hz (or 0 = off), got {self.rate_hz!r}")
        for name in ("tilt_threshold_deg", "heading_threshold_deg", "trigger_s", "clear_s", "startup_grace_s",
                     "min_imu_rate_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"monitor setting {name} must be ≥ 0, got {v!r}")
        if not self.tilt_threshold_deg > 0:
            raise ValueError("monitor tilt_threshold_deg must be > 0")
        if not 0.0 < self.clear_fraction <= 1.0:
            raise ValueError(f"monitor clear_fraction must be in (0, 1], got {self.clear_fraction!r}")
        for name in ("align_tolerance_ms", "max_gap_s", "history_s", "gap_intervals"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"monitor setting {name} must be > 0, got {v!r}")
        for name in ("tilt_name", "heading_name"):
            v = getattr(self, name)
            if not 0 < len(v.encode()) <= _NAME_MAX:
                raise ValueError(f"monitor {name} {v!r} must be 1–{_NAME_MAX} bytes (NAMED_VALUE_FLOAT.name)")


@dataclass(frozen=True)
class MonitorStatus:
    """The monitor's state, for the status line.

    Attributes:
        tilt_deg: latest tilt divergence, deg (NaN before the first comparison).
        heading_deg: latest heading divergence, deg, signed.
        warning: a disagreement episode is active.
        comparisons: comparisons made.
        unmatched: autopilot attitudes with no estimate of ours near their time.
        episodes: warnings raised so far.
        velocity_source: the GNSS velocity aiding the estimate judged (the
            status line's short name: ``GPI``, ``GPS_RAW``, ``GPS2_RAW``,
            ``none``); "" = not told.
        tilt_threshold_deg, heading_threshold_deg: the thresholds of the
            latest comparison, deg (NaN before the first).
        phase: the flight's phase (:class:`FlightPhase`).
        ground_episodes: of ``episodes``, those raised on the ground, at
            take-off or touchdown.
        cause: the evidence with the latest disagreement: ``mag`` (the
            magnetometer's field is not the expected one), ``AP?`` / ``us?``
            (the GNSS velocity agrees with ours / the autopilot's attitude),
            ``IMU2?`` (that IMU's own estimate is the odd one out); "" = none.
        evidence: the whole :class:`Evidence` of the latest disagreement
            while it is on (None otherwise).
        trigger: which test raised the warning that is on: ``level`` (the
            divergence beyond its threshold, the dashed line of the strip
            chart), ``step`` (a change of the divergence against its own
            recent baseline, which can warn below the line: an autopilot that
            was off one way and jumped 2° the other); "" = no warning.
        imu_late: the IMU check's gyro samples dropped because they came after
            the interval they belong to was judged (:class:`_ImuCheck`: a
            sample older than its IMU's judged intervals, e.g. a reordered or
            resent message); counted over the monitor's life, resets included.
        held: the latest comparison was not judged: fewer IMU samples per
            second than ``MonitorSettings.min_imu_rate_hz`` reach our filter.
        imu_rate_hz: that rate as told with our latest estimate, Hz (NaN: not told).
        held_comparisons: comparisons not judged for that, over the monitor's life.
        strip: the last ``strip_s`` of comparisons for the status page's strip
            chart, a point every 0.5 s and at each STATUSTEXT: ``(boot time s,
            tilt°, heading° signed, tilt threshold°, heading threshold° (0 = not
            judged), warning on, raised then: 0 / 1 NOTICE / 2 WARNING)``.
    """

    tilt_deg: float
    heading_deg: float
    warning: bool
    comparisons: int
    unmatched: int
    episodes: int
    velocity_source: str = ""
    tilt_threshold_deg: float = math.nan
    heading_threshold_deg: float = math.nan
    phase: str = "unknown"
    ground_episodes: int = 0
    cause: str = ""
    evidence: Evidence | None = None
    trigger: str = ""
    strip: tuple[tuple[float, float, float, float, float, bool, int], ...] = ()
    imu_late: int = 0
    held: bool = False
    imu_rate_hz: float = math.nan
    held_comparisons: int = 0

    def text(self) -> str:
        """E.g. ``AP cmp: tilt 0.8° hdg +1.2° (vel GPS_RAW)``: the divergence, and the velocity our side used."""
        if self.comparisons == 0:
            return "AP cmp: none"
        if not math.isfinite(self.tilt_deg):  # compared before, none since a reset (an autopilot reboot)
            return "AP cmp: none since reset"
        flag = " WARN" if self.warning else ""
        vel = f" (vel {self.velocity_source})" if self.velocity_source else ""
        thr = f" (thr {self.tilt_threshold_deg:.1f}°/{self.heading_threshold_deg:.1f}°)" if math.isfinite(
            self.tilt_threshold_deg) else ""  # fmt: skip
        why = f" [{self.cause}]" if self.warning and self.cause else ""
        hdg = f"{self.heading_deg:+.1f}°" if math.isfinite(self.heading_deg) else "–"
        if self.held:
            thr = f" (not judged: IMU {self.imu_rate_hz:.0f} Hz, too slow)"
        return f"AP cmp: tilt {self.tilt_deg:.1f}° hdg {hdg}{thr}{flag}{why}{vel}"


# --------------------------------------------------------------------------- scalar maths


_euler_to_q = euler_to_q_scalar  # aerospace Z-Y-X Euler angles (rad) → q_body_to_ned


def _divergence(a: Sequence[float], b: Sequence[float]) -> tuple[float, float]:
    """(tilt, heading) in rad of e = a ⊗ b*; heading signed (−π, π]."""
    na = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + a[3] * a[3])
    nb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3])
    w = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]) / (na * nb)
    z = (-a[0] * b[3] - a[1] * b[2] + a[2] * b[1] + a[3] * b[0]) / (na * nb)
    if w < 0.0:
        w, z = -w, -z
    tilt = 2.0 * math.acos(min(1.0, math.sqrt(w * w + z * z)))
    heading = 2.0 * math.atan2(z, w)
    return tilt, heading


def attitude_divergence_rad(a: Sequence[float], b: Sequence[float]) -> tuple[float, float]:
    """(tilt, heading) of ``a`` relative to ``b`` (both ``q_body_to_ned``), rad; heading signed (−π, π]."""
    return _divergence(a, b)


def _nlerp(a: Sequence[float], b: Sequence[float], f: float) -> tuple[float, float, float, float]:
    """Normalised linear interpolation (slerp to < 0.1 % for the few-ms gaps here)."""
    if a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] < 0.0:
        b = (-b[0], -b[1], -b[2], -b[3])
    q = [a[i] + (b[i] - a[i]) * f for i in range(4)]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q[0] / n, q[1] / n, q[2] / n, q[3] / n


def attitude_of_message(msg: Any) -> tuple[float, tuple[float, float, float, float]] | None:
    """``(time_boot_ms, q_body_to_ned)`` of an ATTITUDE or ATTITUDE_QUATERNION; None otherwise.

    ATTITUDE_QUATERNION's ``repr_offset_q`` (a display offset for tailsitters)
    is ignored: ``q1..q4`` is the attitude of the autopilot's body frame.
    """
    kind = msg.get_type()
    if kind == "ATTITUDE":
        q = _euler_to_q(msg.roll, msg.pitch, msg.yaw)
    elif kind == "ATTITUDE_QUATERNION":
        q = (msg.q1, msg.q2, msg.q3, msg.q4)
    else:
        return None
    if not all(math.isfinite(v) for v in q) or (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) < 0.25:
        return None
    return float(msg.time_boot_ms), q


# --------------------------------------------------------------------------- flight phase


class FlightPhase:
    """The flight's phase from what the autopilot streams (pure: times are the autopilot's ms).

    * HEARTBEAT's ``MAV_MODE_FLAG_SAFETY_ARMED``: ``disarmed`` when clear;
    * EXTENDED_SYS_STATE's ``landed_state`` (PX4, ArduPilot when streamed):
      on ground, in air, taking off, landing;
    * else GLOBAL_POSITION_INT (altitude above home and speed), see
      :class:`MonitorSettings` ``ground_alt_m``;
    * ``takeoff`` for ``transition_s`` after leaving the ground and
      ``touchdown`` for ``transition_s`` after landing.

    :meth:`phase` is one of ``unknown`` (nothing said yet), ``disarmed``,
    ``ground``, ``takeoff``, ``air``, ``touchdown``.
    """

    def __init__(self, settings: MonitorSettings | None = None) -> None:
        s = settings if settings is not None else MonitorSettings()
        self._ground_alt = s.ground_alt_m
        self._air_alt = s.air_alt_m
        self._still = s.still_speed_m_s
        self._transition_ms = 1000.0 * s.transition_s
        self.armed: bool | None = None
        self.landed: bool | None = None
        self._ess = False  # EXTENDED_SYS_STATE seen with a defined landed state: it decides
        self._ess_state = 0
        self._since_ms: float | None = None  # when ``landed`` last changed
        self._last_ms = 0.0
        self._speed = math.nan  # the latest "speed" event's, m/s (:meth:`on_event`)

    def _set_landed(self, landed: bool, t_ms: float) -> None:
        if self.landed is not None and landed != self.landed:
            self._since_ms = t_ms
        self.landed = landed

    def on_heartbeat(self, base_mode: int, t_ms: float | None = None) -> None:
        """The autopilot's HEARTBEAT (``base_mode``); ``t_ms`` (default: the latest time seen)."""
        t = self._last_ms if t_ms is None else float(t_ms)
        armed = bool(int(base_mode) & 128)
        if self.armed and not armed and self.landed is False:
            self._set_landed(True, t)  # disarmed in the air is a crash or a kill: either way, not flying
        self.armed = armed

    def on_landed_state(self, landed_state: int, t_ms: float | None = None) -> None:
        """EXTENDED_SYS_STATE ``landed_state`` (MAV_LANDED_STATE: 1 ground, 2 air, 3 take-off, 4 landing)."""
        t = self._last_ms if t_ms is None else float(t_ms)
        st = int(landed_state)
        if st == 0:
            return
        self._ess = True
        self._ess_state = st
        self._set_landed(st == 1, t)

    def on_position(self, t_ms: float, relative_alt_m: float, speed_m_s: float) -> None:
        """GLOBAL_POSITION_INT: altitude above home, m, and speed (3-D), m/s."""
        self._last_ms = max(self._last_ms, float(t_ms))
        if self._ess or not (math.isfinite(relative_alt_m) and math.isfinite(speed_m_s)):
            return
        if relative_alt_m < self._ground_alt and speed_m_s < self._still:
            self._set_landed(True, t_ms)
        elif relative_alt_m > self._air_alt:
            self._set_landed(False, t_ms)

    def on_event(self, t_ms: float, kind: str, value: float) -> None:
        """One ``(t_ms, kind, value)`` of :func:`phase_events_of_arrays` (a position takes the latest speed)."""
        if kind == "heartbeat":
            self.on_heartbeat(int(value), t_ms)
        elif kind == "landed":
            self.on_landed_state(int(value), t_ms)
        elif kind == "speed":
            self._speed = value
        elif kind == "position":
            self.on_position(t_ms, value, self._speed)

    def handle(self, msg: Any) -> None:
        """HEARTBEAT / EXTENDED_SYS_STATE / GLOBAL_POSITION_INT from the autopilot (others ignored)."""
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.on_heartbeat(msg.base_mode)
        elif kind == "EXTENDED_SYS_STATE":
            self.on_landed_state(msg.landed_state)
        elif kind == "GLOBAL_POSITION_INT":
            v = math.sqrt(msg.vx * msg.vx + msg.vy * msg.vy + msg.vz * msg.vz) * 0.01
            self.on_position(float(msg.time_boot_ms), msg.relative_alt * 1e-3, v)

    def phase(self, t_ms: float) -> str:
        """The phase at ``t_ms`` (the latest information)."""
        self._last_ms = max(self._last_ms, float(t_ms))
        if self.armed is False:
            return "disarmed"
        if self._ess and self._ess_state in (3, 4):
            return "takeoff" if self._ess_state == 3 else "touchdown"
        if self.landed is None:
            return "unknown" if self.armed is None else "air"
        recent = self._since_ms is not None and t_ms - self._since_ms < self._transition_ms
        if self.landed:
            return "touchdown" if recent else "ground"
        return "takeoff" if recent else "air"


def phase_events_of_arrays(
    heartbeat: tuple[ArrayLike, ArrayLike] | None = None,
    extended_sys_state: tuple[ArrayLike, ArrayLike] | None = None,
    position: tuple[ArrayLike, ArrayLike, ArrayLike] | None = None,
) -> list[tuple[float, str, float]]:
    """``(t_ms, kind, value)`` for :func:`monitor_series`, sorted by time.

    Args:
        heartbeat: (times ms, base_mode) of the autopilot's HEARTBEATs.
        extended_sys_state: (times ms, landed_state).
        position: (times ms, altitude above home m, speed m/s).
    """
    ev: list[tuple[float, str, float]] = []
    if heartbeat is not None:
        ev += [(float(t), "heartbeat", float(b)) for t, b in zip(*heartbeat, strict=True)]
    if extended_sys_state is not None:
        ev += [(float(t), "landed", float(b)) for t, b in zip(*extended_sys_state, strict=True)]
    if position is not None:
        t, alt, v = position
        ev += [(float(a), "position", float(b)) for a, b in zip(t, alt, strict=True)]
        ev = ev + [(float(a), "speed", float(b)) for a, b in zip(t, v, strict=True)]
    ev.sort(key=lambda e: (e[0], e[1] != "speed"))  # the speed just before its altitude
    return ev


@dataclass(frozen=True)
class Evidence:
    """Who is likely wrong, with a disagreement (:attr:`AttitudeMonitor.evidence`).

    Attributes:
        mag_norm_dev: the magnetometer's field strength (median of the last 3 s)
            off the expected one (the geomagnetic model's), as a fraction of it;
            NaN = not known (no magnetometer, or no expected field yet).
        mag_dip_dev_deg: its dip (inclination) off the expected one, deg (median).
        mag_offset_ut: the size of the magnetometer offsets learnt in flight,
            µT, by our magnetometer model (:mod:`mavahrs.filters.magfield`, when
            it is on and past learning; the pipeline passes them once a second
            with :meth:`AttitudeMonitor.set_mag_offsets`); NaN = not known.
        mag_disturbed: the field is not the expected one (``mag_norm_tolerance``,
            ``mag_dip_tolerance_deg``), or our magnetometer model finds it
            disturbed: the heading of whoever trusts it is suspect.
        gnss_m_s: how far apart the two attitudes put the horizontal velocity
            change (the specific force rotated into NED by each and integrated
            over ``gnss_window_s``), m/s, the largest over the recent windows;
            NaN = no GNSS velocity.
        gnss_blames_us: of that difference, the share the GNSS velocity change
            puts on our side: 0 = it agrees with our attitude (the autopilot's is
            wrong), 1 = with the autopilot's (ours is wrong); NaN = not judged.
        gnss_verdict: ``AP`` / ``us`` (who the GNSS velocity says is wrong: its
            miss along the difference is ``gnss_ratio`` × the other's and the
            difference at least ``gnss_min_m_s``, ``gnss_heading_min_m_s`` for a
            disagreement in heading alone, the share's standard error at most
            ``gnss_max_share_se``), "" = no verdict (unknown).
        gnss_share_se: the standard error of ``gnss_blames_us`` (our miss across
            the difference taken as the integration's own error), NaN = not judged.
        tilt_sigma_deg: our own 1-σ tilt uncertainty then (the ESKF's while
            velocity-aided), deg; NaN = not aided (the ``unaided`` figure applies).
        heading_sigma_deg: … and heading (the ESKF's), deg; NaN = not given.
        imu: the IMU whose gyro disagrees with the others' and with the
            autopilot's turn rate (``IMU2`` …), "" = none named (see
            :meth:`AttitudeMonitor.add_imu_gyro`).
    """

    mag_norm_dev: float = math.nan
    mag_dip_dev_deg: float = math.nan
    mag_offset_ut: float = math.nan
    mag_disturbed: bool = False
    gnss_m_s: float = math.nan
    gnss_blames_us: float = math.nan
    gnss_verdict: str = ""
    gnss_share_se: float = math.nan
    tilt_sigma_deg: float = math.nan
    heading_sigma_deg: float = math.nan
    imu: str = ""

    @property
    def cause(self) -> str:
        """The short form for STATUSTEXT: ``mag`` (magnetometer disturbed), ``AP?`` / ``us?`` (the GNSS
        velocity says the autopilot's / our attitude is wrong), ``IMU2?`` (that IMU), space-separated."""
        out = []
        if self.mag_disturbed:
            out.append("mag")
        if self.gnss_verdict:
            out.append(f"{self.gnss_verdict}?")
        if self.imu:
            out.append(f"{self.imu}?")
        return " ".join(out)

    def as_dict(self) -> dict[str, Any]:
        """For ``/status.json`` and the audit table (NaN → None)."""
        out: dict[str, Any] = {}
        for k, v in self.__dict__.items():
            out[k] = None if isinstance(v, float) and not math.isfinite(v) else v
        out["cause"] = self.cause
        return out

    def text(self) -> str:
        """A line for people: ``magnetometer disturbed (|B| +31 %, dip 4°); GNSS velocity agrees with ours …``."""
        parts = []
        if math.isfinite(self.mag_norm_dev):
            state = "disturbed" if self.mag_disturbed else "as expected"
            parts.append(f"magnetometer {state} (|B| {100 * self.mag_norm_dev:+.0f} %, dip {self.mag_dip_dev_deg:+.1f}°"
                         + (f", offsets {self.mag_offset_ut:.0f} µT" if math.isfinite(self.mag_offset_ut) else "") + ")")
        if math.isfinite(self.gnss_blames_us):
            side = {"AP": "ours (the autopilot's is off)", "us": "the autopilot's (ours is off)"}.get(
                self.gnss_verdict, "neither clearly")
            parts.append(f"GNSS velocity agrees with {side}: share on us {self.gnss_blames_us:.2f} of "
                         f"{self.gnss_m_s:.2f} m/s")
        elif math.isfinite(self.gnss_m_s):
            parts.append(f"GNSS velocity: attitudes differ by {self.gnss_m_s:.2f} m/s, too little to judge")
        if self.imu:
            parts.append(f"{self.imu}'s gyro disagrees with the other IMUs' and the autopilot's turn rate")
        parts.append((f"our tilt σ {self.tilt_sigma_deg:.2f}°" + (f", heading σ {self.heading_sigma_deg:.1f}°"
                      if math.isfinite(self.heading_sigma_deg) else "")) if math.isfinite(self.tilt_sigma_deg)
                     else "ours not GNSS-aided")
        return "; ".join(parts)


# --------------------------------------------------------------------------- monitor


class AttitudeMonitor:
    """Compares our attitude with the autopilot's; see the module docstring.

    Per our estimate :meth:`add_estimate` costs an append (plus an alignment
    when an autopilot attitude is waiting for it); comparisons happen at the
    autopilot's ATTITUDE rate.
    """

    def __init__(self, settings: MonitorSettings | None = None) -> None:
        self.settings = settings if settings is not None else MonitorSettings()
        s = self.settings
        self._tilt_thr = math.radians(s.tilt_threshold_deg)
        self._hdg_thr = math.radians(s.heading_threshold_deg)
        self._tol_ms = s.align_tolerance_ms
        self._history_ms = 1000.0 * s.history_s
        self._period_us = int(round(1e6 / s.rate_hz)) if s.rate_hz > 0 else 0
        self._max_gap_ms = 1000.0 * s.max_gap_s
        self._tilt_name = s.tilt_name.encode()
        self._heading_name = s.heading_name.encode()
        #: when False (declination unknown, or no magnetometer), heading is published but never alarmed
        self.heading_valid = True
        #: the GNSS velocity aiding our estimate, as the owner (the pipeline) tells it; shown in the status
        self.velocity_source = ""
        #: the phase in which the latest disagreement was raised
        self.last_phase = ""
        #: the evidence of who is likely wrong with it: "mag", "AP?", "us?", "mag AP?" … ("" = none)
        self.last_cause = ""
        self._trigger = ""  # which test raised the warning that is on (MonitorStatus.trigger)
        #: … and the whole evidence (None before the first disagreement)
        self.last_evidence: Evidence | None = None
        #: the latest STATUSTEXT was the same disagreement said again with new evidence (not a new episode)
        self.last_update = False
        self._comparisons = 0
        self._unmatched = 0
        #: comparisons not judged because our IMU input was slower than ``min_imu_rate_hz``
        self.held_comparisons = 0
        self._episodes = 0
        self._ground_episodes = 0
        #: (t_s, tilt°, heading°, tilt threshold°, heading threshold°, warning on, raised: 0 / 1 notice / 2 warning)
        self._strip: deque[tuple[float, float, float, float, float, bool, int]] = deque()
        self._next_publish_us: int | None = None
        self._quaternion_source = False
        self.phase = FlightPhase(s)
        u = s.mode == "uncertainty"
        self._k = s.sigma_k
        self._sig_ap = (math.radians(s.autopilot_tilt_sigma_deg), math.radians(s.autopilot_heading_sigma_deg))
        self._sig_unaided = (math.radians(s.unaided_tilt_sigma_deg), math.radians(s.unaided_heading_sigma_deg))
        self._sig_hdg = math.radians(s.heading_sigma_deg)
        self._min_thr = (math.radians(s.min_tilt_threshold_deg), math.radians(s.min_heading_threshold_deg))
        self._uncertainty = u
        self._h = (1.0 - s.cusum_reference) * s.trigger_s
        self._h_c = (1.0 - s.change_cusum_reference) * s.trigger_s
        self._h_d = (1.0 - s.change_cusum_reference) * s.change_drift_s
        self._learn_rate = math.radians(s.learn_max_rate_dps)
        self.reset()

    def reset(self) -> None:
        """Forget the alignment history and timers (e.g. after our filter re-initialised)."""
        self._estimates: deque[tuple[float, tuple[float, float, float, float]]] = deque()
        self._pending: deque[tuple[float, tuple[float, float, float, float]]] = deque()
        self._first_est_ms: float | None = None
        self._last_att_ms: float | None = None
        self._att_intervals: deque[float] = deque(maxlen=_INTERVALS)
        self._last_cmp_ms: float | None = None
        self._above_since_ms: float | None = None
        self._below_since_ms: float | None = None
        self._warning = False
        self._warned_in_flight = False
        self._next_evidence_ms = math.inf
        self._updates = 0
        self._tilt = math.nan
        self._heading = math.nan
        self._tilt_thr_now = math.nan
        self._hdg_thr_now = math.nan
        self._model_thr = (math.inf, math.inf)
        self._change_cap = (math.inf, math.inf)
        self._cusum = 0.0
        self._cusum_c = 0.0  # the change test's (MonitorSettings.change_test)
        self._cusum_w = 0.0  # … and its test of a new step while a warning is on (change_in_warning_s)
        self._cusum_d = 0.0  # … and of a disagreement that grows while a warning is on (change_drift_s)
        self._drift_acc = [0.0, 0.0, 0.0, 0.0]
        self._drift_seen: list[tuple[float, float, float]] = []
        self._drift_hist: deque[tuple[float, float, float, float]] = deque()  # (t_ms, e) over change_drift_slope_s
        self._drift_line: tuple[float, tuple[float, ...], tuple[float, ...], tuple[float, float], bool, bool] | None = None
        self._beyond_ms = -math.inf  # when the divergence was last beyond a threshold
        self._drift_armed = False  # the drift test judges the warning that is on (not one it raised itself)
        self._e = (0.0, 0.0, 0.0)  # the latest divergence vector, earth frame, rad (the change test's)
        self._e_warned = (0.0, 0.0, 0.0)  # … when the warning that is on was raised
        self._e_warned_mean = (0.0, 0.0, 0.0)  # … its mean over change_step_s before that
        self._recent = _RecentRows()  # (t_ms, e) over change_step_s
        self._learnt = [0.0, 0.0, 0.0]  # seconds learnt, mean tilt², mean heading² (rad²)
        self._change = _ChangeTest(self.settings) if self._uncertainty and self.settings.change_test else None
        in_warning = self._change is not None and self.settings.change_in_warning_s > 0.0
        self._in_warning = _ChangeTest(self.settings, self.settings.change_in_warning_s) if in_warning else None
        self._change_aided = False
        self._warning_since_ms = -math.inf
        old = getattr(self, "_evidence", None)
        self._evidence = _Evidence(self.settings)
        late = self._imus.late if hasattr(self, "_imus") else 0
        self._imus = _ImuCheck(self.settings)
        self._imus.late = late  # a counter: it outlives a reset, as the comparisons do
        self._imu_named = ""
        if old is not None:  # what the vehicle's field should be outlives a reset
            self._evidence.mag_ref, self._evidence.mag_offset_ut = old.mag_ref, old.mag_offset_ut
            self._evidence.mag_model_disturbed = old.mag_model_disturbed
        self._sigma = math.nan  # our latest 1-σ tilt, rad (NaN: not velocity-aided)
        self._sigma_hdg = math.nan  # our latest 1-σ heading, rad (NaN: not given: heading_sigma_deg)
        self._imu_rate_hz = math.nan  # IMU samples per second reaching our filter (NaN: not told)
        self._held = False  # the latest comparison was not judged: our IMU input too slow (min_imu_rate_hz)
        self._sig_hdg_least: deque[tuple[float, float]] = deque()  # (t_ms, σ) rising: the window's least σ first
        self._rate = 0.0  # our latest angular rate, rad/s (from successive estimates)
        self._rate_h = 0.0  # … its earth-frame horizontal part (what turns the tilt), rad/s
        self._rate_v = 0.0  # … and vertical part (what turns the heading), rad/s
        self._w_earth = (0.0, 0.0, 0.0)  # … as a vector, north, east, down, rad/s (signed: the step test's timing term)
        self._z_step = 0.0  # the in-warning test's step part now (:meth:`_step_in_warning`)
        self._thr_sigmas = (0.0, 0.0)  # our (tilt, heading) σ the thresholds were built from, rad
        self._fresh = False  # a comparison since the last publication

    # ------------------------------------------------------------------ inputs
    def add_estimate(
        self,
        t_boot_ms: float,
        q_body_to_ned: Sequence[float],
        tilt_sigma_rad: float = math.nan,
        heading_sigma_rad: float = math.nan,
        imu_rate_hz: float = math.nan,
    ) -> list[Any]:
        """Our published attitude at ``t_boot_ms``; returns STATUSTEXTs this resolves (usually none).

        ``tilt_sigma_rad``: our filter's 1-σ tilt uncertainty with this
        estimate (the ESKF's, while velocity-aided: ``OUT_GAIN`` when
        ``FLAG_VELOCITY_AIDED``); NaN = not known (the ``unaided`` figures are used).
        ``heading_sigma_rad``: its 1-σ heading uncertainty (the ESKF's
        ``OUT_HEADING_SIGMA``, with the tilt's); NaN = not known (``heading_sigma_deg``
        while the tilt's is given).
        ``imu_rate_hz``: IMU samples per second reaching our filter around this
        estimate; below ``MonitorSettings.min_imu_rate_hz`` comparisons are not
        judged; NaN = not known (judged).
        """
        if not self.settings.enabled:
            return []
        self._sigma = float(tilt_sigma_rad)
        self._sigma_hdg = float(heading_sigma_rad)
        self._imu_rate_hz = float(imu_rate_hz)
        est = self._estimates
        t = float(t_boot_ms)
        if est and t < est[-1][0]:
            if t < est[-1][0] - _REBOOT_MS:
                self._restart()
            else:
                return []  # out of order: ignore
        q = (float(q_body_to_ned[0]), float(q_body_to_ned[1]), float(q_body_to_ned[2]), float(q_body_to_ned[3]))
        if est and t > est[-1][0]:
            p = est[-1][1]
            dot = p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3] * q[3]
            dt = 1e-3 * (t - est[-1][0])
            self._rate = 2.0 * math.acos(min(1.0, abs(dot))) / dt
            # the same turn in the earth frame, q ⊗ p* (vector part −q_w p_v + p_w q_v − q_v × p_v): its
            # horizontal part tilts, its vertical part turns the heading — a timing error δ between the two
            # estimates shows as that turn over δ, split the same way (see MonitorSettings.sync_s)
            k = (2.0 if dot >= 0.0 else -2.0) / dt
            ex = -q[0] * p[1] + p[0] * q[1] - (q[2] * p[3] - q[3] * p[2])
            ey = -q[0] * p[2] + p[0] * q[2] - (q[3] * p[1] - q[1] * p[3])
            ez = -q[0] * p[3] + p[0] * q[3] - (q[1] * p[2] - q[2] * p[1])
            self._rate_h = abs(k) * math.sqrt(ex * ex + ey * ey)
            self._rate_v = abs(k * ez)
            self._w_earth = (k * ex, k * ey, k * ez)
        est.append((t, q))
        if self._first_est_ms is None:
            self._first_est_ms = t
        horizon = t - self._history_ms
        while est[0][0] < horizon:
            est.popleft()
        if self._pending and self._pending[0][0] <= t:
            return self._resolve()
        return []

    def handle(self, msg: Any, now_us: int) -> list[Any]:
        """An autopilot ATTITUDE / ATTITUDE_QUATERNION (others ignored); returns STATUSTEXTs."""
        if not self.settings.enabled:
            return []
        kind = msg.get_type()
        if kind not in ("ATTITUDE", "ATTITUDE_QUATERNION", "HEARTBEAT", "EXTENDED_SYS_STATE", "GLOBAL_POSITION_INT"):
            return []
        comp = self.settings.autopilot_component_id
        if comp and getattr(msg, "get_srcComponent", None) is not None and msg.get_srcComponent() != comp:
            return []
        if kind[0] != "A":
            self.phase.handle(msg)
            return []
        if kind == "ATTITUDE_QUATERNION":
            self._quaternion_source = True
        elif self._quaternion_source:
            return []  # the same attitude twice: use the quaternion
        att = attitude_of_message(msg)
        if att is None:
            return []
        return self.add_autopilot(*att)

    def add_sensors(
        self,
        t_boot_ms: float,
        accel_body_m_s2: Sequence[float] | None = None,
        mag_body_ut: Sequence[float] | None = None,
        vel_ne_m_s: Sequence[float] | None = None,
        vel_t_ms: float = math.nan,
    ) -> None:
        """The sample behind our next estimate, for the evidence of who is wrong (optional).

        ``accel_body_m_s2``: specific force; ``mag_body_ut``: the calibrated
        field; ``vel_ne_m_s``: the GNSS velocity (north, east; true north)
        fixed at ``vel_t_ms`` (the same fix may come again: counted once).
        """
        if self.settings.enabled:
            self._evidence.sensors(float(t_boot_ms), accel_body_m_s2, mag_body_ut, vel_ne_m_s, float(vel_t_ms))

    def add_imu_gyro(self, name: str, t_boot_ms: float, gyro_rad_s: Sequence[float]) -> None:
        """A gyro sample of one of the vehicle's IMUs (``IMU1``, ``IMU2`` …; the one our filter uses too),
        for naming the IMU that is off (see ``MonitorSettings.imu_rate_tolerance_dps``)."""
        if self.settings.enabled:
            self._imus.gyro(name, float(t_boot_ms), gyro_rad_s)

    def set_mag_reference(self, strength_ut: float, inclination_rad: float) -> None:
        """The field the magnetometer should measure (the geomagnetic model at the vehicle)."""
        self._evidence.mag_ref = (float(strength_ut), float(inclination_rad))

    def set_mag_offsets(self, offset_ut: Sequence[float] | None, *, disturbed: bool = False) -> None:
        """The magnetometer offsets our estimator's magnetometer model has learnt in flight, µT (None: none, or
        the model is off), for the evidence; ``disturbed``: the model itself finds the field disturbed (then
        ``mag`` is named with a disagreement whatever the field strength and dip say)."""
        ok = offset_ut is not None and all(math.isfinite(float(v)) for v in offset_ut)
        self._evidence.mag_offset_ut = math.sqrt(sum(float(v) ** 2 for v in offset_ut)) if ok else math.nan  # type: ignore[union-attr]
        self._evidence.mag_model_disturbed = bool(disturbed) and ok

    def add_autopilot(self, t_boot_ms: float, q_body_to_ned: Sequence[float]) -> list[Any]:
        """The autopilot's attitude at ``t_boot_ms`` (what :meth:`handle` extracts); returns STATUSTEXTs."""
        if not self.settings.enabled:
            return []
        t = float(t_boot_ms)
        last = self._last_att_ms
        if last is not None and t < last - _REBOOT_MS:
            self._restart()
        elif last is not None and t > last:
            self._att_intervals.append(t - last)
        self._last_att_ms = t
        q = (float(q_body_to_ned[0]), float(q_body_to_ned[1]), float(q_body_to_ned[2]), float(q_body_to_ned[3]))
        self._pending.append((t, q))
        if len(self._pending) > _MAX_PENDING:  # our estimates stopped: drop the oldest
            self._pending.popleft()
            self._unmatched += 1
        return self._resolve()

    def tick(self, now_us: int) -> list[Any]:
        """NAMED_VALUE_FLOATs when due (``rate_hz``, only with a fresh comparison)."""
        if not (self.settings.enabled and self._period_us):
            return []
        nxt = self._next_publish_us
        if nxt is not None and now_us < nxt:
            return []
        if not self._fresh:
            return []
        self._fresh = False
        # Keep the cadence without bursts after a pause.
        self._next_publish_us = now_us + self._period_us if nxt is None or now_us - nxt > self._period_us else nxt + self._period_us
        t_ms = int(self._last_cmp_ms or 0) & 0xFFFFFFFF
        return [
            mavlink.MAVLink_named_value_float_message(t_ms, self._tilt_name, math.degrees(self._tilt)),
            mavlink.MAVLink_named_value_float_message(t_ms, self._heading_name, math.degrees(self._heading)),
        ]

    # ------------------------------------------------------------------ internals
    def _restart(self) -> None:
        warning, episodes, flight = self._warning, self._episodes, self._warned_in_flight
        self.reset()
        self._warning, self._episodes, self._warned_in_flight = warning, episodes, flight  # it outlives a reboot

    def _resolve(self) -> list[Any]:
        out: list[Any] = []
        est = self._estimates
        pending = self._pending
        while pending:
            t_a, q_a = pending[0]
            if not est or t_a > est[-1][0]:
                break  # wait for our estimate of that time
            pending.popleft()
            q_e = self._align(t_a)
            if q_e is None:
                self._unmatched += 1
                continue
            out.extend(self._compare(t_a, q_e, q_a))
        return out

    def _align(self, t: float) -> tuple[float, float, float, float] | None:
        est = self._estimates
        tol = self._tol_ms
        # Search backwards: the autopilot's sample is usually near our newest estimate.
        i = len(est) - 1
        while i > 0 and est[i - 1][0] > t:
            i -= 1
        t1, q1 = est[i]
        if t1 < t:  # t is beyond our last: nearest only (cannot happen from _resolve)
            return q1 if t - t1 <= tol else None
        if i == 0 or t1 == t:
            return q1 if t1 - t <= tol else None
        t0, q0 = est[i - 1]
        if t1 - t0 <= 2.0 * tol:
            return _nlerp(q0, q1, (t - t0) / (t1 - t0))
        if t - t0 <= tol and t - t0 <= t1 - t:
            return q0
        return q1 if t1 - t <= tol else None

    def _gap_ms(self) -> float:
        """Comparisons further apart than this are not "continuous" (see ``MonitorSettings.max_gap_s``)."""
        iv = self._att_intervals
        if not iv:
            return self._max_gap_ms
        typical = sorted(iv)[len(iv) // 2]
        return max(self._max_gap_ms, self.settings.gap_intervals * typical)

    def _thresholds(self) -> tuple[float, float]:
        """(tilt, heading) thresholds now, rad (heading 0 = not judged)."""
        hdg_on = self.heading_valid and self._hdg_thr > 0.0
        if not self._uncertainty:
            self._model_thr = (self._tilt_thr, self._hdg_thr if hdg_on else 0.0)
            self._change_cap = self._model_thr
            return self._model_thr
        sig = self._sigma
        aided = math.isfinite(sig) and sig > 0.0
        s_t = sig if aided else self._sig_unaided[0]
        sh = self._sigma_hdg
        s_h = (max(sh, self._sig_hdg) if math.isfinite(sh) else self._sig_hdg) if aided else self._sig_unaided[1]
        self._thr_sigmas = (s_t, s_h)
        # the timing term: the earth-frame turn over sync_s, its horizontal part for the tilt, its vertical
        # part for the heading (a yaw spin does not tilt the divergence, a flip does not turn its heading)
        sync_t2 = (self._rate_h * self.settings.sync_s) ** 2
        sync2 = (self._rate_v * self.settings.sync_s) ** 2
        k = self._k
        tilt = max(self._min_thr[0], k * math.sqrt(s_t * s_t + self._sig_ap[0] ** 2 + sync_t2))
        hdg = max(self._min_thr[1], k * math.sqrt(s_h * s_h + self._sig_ap[1] ** 2 + sync2)) if hdg_on else 0.0
        # what is learnt as this flight's normal divergence: within the heading threshold of our floor σ, not
        # of a σ raised for a while (a fast yaw, a rejected magnetometer), which would learn the autopilot's
        # own heading error of those seconds into the floor (ArduCopter SITL magnetic: a learnt 6.1° that hid
        # a 6° heading step; with the floor's 3.6° gate the same as before the filter's σ was used)
        s_f = self._sig_hdg if aided else s_h
        hdg_learn = max(self._min_thr[1], k * math.sqrt(s_f * s_f + self._sig_ap[1] ** 2 + sync2)) if hdg_on else 0.0
        self._model_thr = (tilt, min(hdg, hdg_learn))
        # … but the change test's cap is the error model with our σ as it is: a change of the divergence as large
        # as what our own heading σ allows is not evidence against the autopilot (firmware_sim magnetic 101: a
        # 35 µT disturbance took our heading 2.5° off at σ 1.7°, the autopilot's 0.9° the other way; the change
        # test, capped at the floor σ's 3.6°, warned falsely at 25.2 s; docs/monitor.md, round eleven)
        self._change_cap = (tilt, hdg)
        if hdg_on and aided and self.settings.change_heading_sigma_growth and self._last_cmp_ms is not None:
            # … as far as our σ has grown within the baseline's span (the error variance added since), on the floor
            t_now = self._last_cmp_ms
            least = self._sig_hdg_least
            while least and least[-1][1] >= s_h:  # a sliding-window minimum (a rising deque)
                least.pop()
            least.append((t_now, s_h))
            span_ms = 1000.0 * (self.settings.change_delay_s + self.settings.change_baseline_s)
            while least[0][0] < t_now - span_ms:
                least.popleft()
            s_g2 = self._sig_hdg ** 2 + max(0.0, s_h * s_h - least[0][1] ** 2)
            self._change_cap = (tilt, max(self._min_thr[1], k * math.sqrt(s_g2 + self._sig_ap[1] ** 2 + sync2)))
        n, m_t, m_h = self._learnt
        if n >= 0.1 * self.settings.learn_s:  # learnt enough to judge
            lk, cap = self.settings.learn_k, self.settings.learn_max_factor
            tilt = max(tilt, min(lk * math.sqrt(m_t), cap * tilt))
            hdg = max(hdg, min(lk * math.sqrt(m_h), cap * hdg)) if hdg_on else 0.0
        if hdg_on and self.settings.heading_tolerance_floor:
            # the least favourable autopilot within its tolerance: its heading error standing at the tolerance
            # (a compass error is correlated for minutes, not noise that averages out), ours at k σ the other way
            hdg = max(hdg, k * (self._sig_ap[1] + s_h))
        return tilt, hdg

    def _change_test(
        self, t_ms: float, q_est: Sequence[float], q_ap: Sequence[float], learn: bool, dt_s: float
    ) -> tuple[float, float]:
        """The change test's (tilt, heading) ratios to its thresholds (0: not judged now)."""
        ch = self._change
        assert ch is not None
        if not (math.isfinite(self._sigma) and self._sigma > 0.0):  # not GNSS-aided: our error drifts
            if self._change_aided:
                ch.restart()
                self._recent.clear()
                self._drift_hist.clear()
            self._change_aided = False
            return 0.0, 0.0
        self._change_aided = True
        a, b = q_est, q_ap
        na = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + a[3] * a[3])
        nb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3])
        sgn = 2.0 / (na * nb) if a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] >= 0.0 else -2.0 / (na * nb)
        # e = a ⊗ b*: vector part −a_w b_v + b_w a_v − a_v × b_v (small angle: 2·v), earth frame
        e = (sgn * (-a[0] * b[1] + b[0] * a[1] - (a[2] * b[3] - a[3] * b[2])),
             sgn * (-a[0] * b[2] + b[0] * a[2] - (a[3] * b[1] - a[1] * b[3])),
             sgn * (-a[0] * b[3] + b[0] * a[3] - (a[1] * b[2] - a[2] * b[1])))  # fmt: skip
        self._e = e
        if self.settings.change_step_s > 0.0:
            rec = self._recent
            w = self._w_earth
            rec.append((t_ms, e[0], e[1], e[2], w[0], w[1], w[2], a[0] / na, a[1] / na, a[2] / na, a[3] / na))
            horizon = t_ms - 1000.0 * self.settings.change_step_s
            while rec and rec[0][0] < horizon:
                rec.popleft()
        if self.settings.change_drift_slope_s > 0.0:  # the drift test's line (_drift_line)
            hist = self._drift_hist
            hist.append((t_ms, e[0], e[1], e[2]))
            horizon = t_ms - 1000.0 * self.settings.change_drift_slope_s
            while hist and hist[0][0] < horizon:
                hist.popleft()
        hold = self._warning and t_ms - self._warning_since_ms < 3000.0 * self.settings.change_baseline_s
        yaw = None
        if self.settings.change_baseline_turn:  # our heading (body x axis in the horizontal)
            c = 1.0 - 2.0 * (a[2] * a[2] + a[3] * a[3]) / (na * na)
            sn = 2.0 * (a[1] * a[2] + a[0] * a[3]) / (na * na)
            r = math.hypot(c, sn)
            yaw = (c / r, sn / r) if r > 1e-6 else (1.0, 0.0)
        if not ch.update(t_ms, e, frozen=hold, yaw=yaw):
            return 0.0, 0.0
        extra2 = 0.0
        if yaw is not None:
            # the standing divergence may be fixed in the vehicle's axes (an accelerometer bias's tilt, ours or
            # the autopilot's): the change against the baseline predicted at our heading now, its threshold
            # widened by what that prediction does not know (its prior: the error model's level variance)
            s_t = self._thr_sigmas[0]
            prior2 = 0.5 * (s_t * s_t + self._sig_ap[0] ** 2)
            noise2 = 0.5 * max(ch._learnt[1], ch._floor2[0])
            ch.tilt, extra2 = ch.turned(e, yaw, prior2, noise2)
        f = self.settings.change_max_factor
        t_thr, h_thr = ch.judge((self._rate_h, self._rate_v), learn and not self._warning, dt_s,
                                (f * self._change_cap[0], f * self._change_cap[1]))
        if extra2 > 0.0:
            t_thr = math.sqrt(t_thr * t_thr + self._k ** 2 * extra2)
        return ch.tilt / t_thr, abs(ch.heading) / h_thr

    def _in_warning_test(self, t_ms: float, tilt: float, heading: float, hdg_on: bool) -> float:
        """A new step while an in-flight warning is on (``MonitorSettings.change_in_warning_s``): the divergence
        vector ``e`` against its mean ``ê`` since the warning, as the change test's ratio to its thresholds, with
        the thresholds' floors; 0 where the change leads back toward agreement, ``(e − ê)·e ≤ 0`` (ArduCopter
        SITL magnetic: EKF3's heading 36.9° off, then 21.0°, 7.5° — said again as new WARNINGs without it), or
        where it is not judged now.  The change is also at most the divergence's distance from ``e`` when the
        warning was raised: the same disagreement coming back is the warning already on (an intermittent fault,
        1 s in every 4 s: a new WARNING every 4–8 s without it), and at most its change over the last
        ``change_delay_s``: a disagreement growing on (a ramp, 0.2°/s: a new WARNING every 7–10 s without it)
        is the warning already on."""
        iw, ch = self._in_warning, self._change
        self._z_step = 0.0
        if iw is None or ch is None:
            return 0.0
        if not (self._warning and self._warned_in_flight and self._change_aided):
            if iw._fed_ms is not None or iw._buf:
                iw.restart()
            return 0.0
        e = self._e
        # a step in the last change_step_s against the level just before it (the generalised likelihood ratio's
        # split, as outside a warning: ``change_step_outside``), whether or not the baseline is fed yet
        step = self._z_step = self._step_in_warning(t_ms, tilt, heading, hdg_on)
        if not iw.update(t_ms, e, frozen=False):  # its baseline not fed yet: the step test alone
            return step
        m = iw._mean  # a change back toward agreement (e − ê against e) is not a new fault
        if (e[0] - m[0]) * e[0] + (e[1] - m[1]) * e[1] + (e[2] - m[2]) * e[2] <= 0.0:
            return step
        t_thr, h_thr = ch.thresholds
        w = self._e_warned  # … nor the disagreement warned of coming back (an intermittent fault)
        c_t = min(iw.tilt, math.hypot(e[0] - w[0], e[1] - w[1]))
        c_h = min(abs(iw.heading), abs(e[2] - w[2]))
        if iw._buf:  # … nor one growing on (a ramp): a step is a change within the last change_delay_s too
            r = iw._buf[0]
            c_t = min(c_t, math.hypot(e[0] - r[1], e[1] - r[2]))
            c_h = min(c_h, abs(e[2] - r[3]))
        c_t /= t_thr
        c_h = c_h / h_thr if hdg_on else 0.0
        if self._min_thr[0] > 0.0:
            c_t = min(c_t, tilt / self._min_thr[0])
        if self._min_thr[1] > 0.0:
            c_h = min(c_h, abs(heading) / self._min_thr[1])
        return max(c_t, c_h, step)

    def _step_in_warning(self, t_ms: float, tilt: float, heading: float, hdg_on: bool) -> float:
        """A step in the first seconds of a warning, before the in-warning baseline is fed
        (``MonitorSettings.change_step_s``): over the last ``change_step_s`` of divergence vectors, the split into
        a segment before and one after that best shows a step — the generalised likelihood ratio's estimate of
        a change in the mean at an unknown time (Basseville & Nikiforov 1993, §2.4.3): each segment's mean, the
        change between them, the largest such change over the splits — counted only where it stands out from
        the divergence's own motion within the two segments (at least ``change_step_spread_k`` × their pooled
        RMS spread: a step, not the autopilot's error turning with the vehicle), leads away from agreement and
        from the disagreement warned of (as :meth:`_in_warning_test`); as the change test's ratio to its
        thresholds, 0 where not judged.  The segment before may lie before the warning: the divergence warned
        of is then the reference.  Tilt (north, east) and heading each find their own split."""
        return max(self._step_ratio(t_ms, tilt, heading, hdg_on, in_warning=True))

    def _step_ratio(
        self, t_ms: float, tilt: float, heading: float, hdg_on: bool, *, in_warning: bool
    ) -> tuple[float, float]:
        """The step test of :meth:`_step_in_warning` (``in_warning``) or, outside a warning
        (``MonitorSettings.change_step_outside``), without the conditions that refer to the warning (the split
        after it, away from the disagreement warned of): the (tilt, heading) ratios, 0 where not judged.

        Within a warning each split's change is judged against the change test's thresholds with the timing term
        of the turn rate's change between the two segments (:meth:`_split_thresholds`): a timing offset δ between
        the two estimates makes the divergence δ·ω (``sync_s``), so the difference of two segments' means
        carries δ·(ω̄_after − ω̄_before), not δ·ω now — in a steady yaw spin the timing part is the same on both
        sides of a step (firmware_sim aggressive 81: a +6° heading step under a warning in a 314°/s spin,
        thresholds of 5.0–6.3° with the spin's whole rate).  Outside a warning the thresholds are the change
        test's, with the rate now: the segments' rates there measured a 2° tilt step on firmware_sim
        aggressive 1 0.7 → 2.7 s (docs/monitor.md round fourteen)."""
        ch = self._change
        assert ch is not None
        h_ms = 1000.0 * self.settings.change_step_s
        rec = self._recent
        if h_ms <= 0.0 or not rec or rec[0][0] > t_ms - 0.75 * h_ms:
            return 0.0, 0.0
        rows = rec.array()
        pts = rows[rows[:, 0] > t_ms - h_ms]
        n = len(pts)
        if n < 8:
            return 0.0, 0.0
        seg = max(3, n // 8)  # each segment at least an eighth of the history
        # … and the step at least as long after the warning was raised (the one it was raised for, which may
        # have come with the warning's own comparison, is not new)
        first = 0
        while in_warning and first < n and pts[first][0] <= self._warning_since_ms + 0.125 * h_ms:
            first += 1
        w = self._e_warned_mean if in_warning else None
        k_s2 = self.settings.change_step_spread_k ** 2
        best = [0.0, 0.0]
        splits = np.arange(max(seg, first), n - seg + 1)
        if splits.size:
            # every split at once (a .ulg's EKF2 at 250 Hz: 500 points in 2 s, judged on each of them; the
            # loop in Python over the splits took two minutes for a 4-minute flight); the same operations in
            # the same order as one split at a time
            rows = pts
            nb = splits[:, None].astype(np.float64)
            na = (n - splits)[:, None].astype(np.float64)
            for axes, out in (((1, 2), 0), ((3,), 1)):
                if in_warning:  # the timing term of the segments' mean rates' difference
                    rc = [a + 3 for a in axes]  # the turn rate's columns beside them (north, east / down)
                    r = np.zeros((n + 1, len(axes)))
                    np.cumsum(rows[:, rc], axis=0, out=r[1:])
                    dw = (r[n] - r[splits]) / na - r[splits] / nb
                    thr = self._split_thresholds(np.sqrt((dw * dw).sum(axis=1)), out)
                else:  # … outside a warning that of the rate now (the change test's thresholds)
                    thr = np.full(len(splits), ch.thresholds[out])
                x = rows[:, axes]
                p1 = np.zeros((n + 1, len(axes)))
                p2 = np.zeros((n + 1, len(axes)))
                np.cumsum(x, axis=0, out=p1[1:])  # prefix sums of each axis and of its square
                np.cumsum(x * x, axis=0, out=p2[1:])
                mb = p1[splits] / nb
                ma = (p1[n] - p1[splits]) / na
                spread = (np.maximum(0.0, p2[splits] / nb - mb * mb)
                          + np.maximum(0.0, (p2[n] - p2[splits]) / na - ma * ma)).sum(axis=1)  # fmt: skip
                d = ma - mb
                if in_warning and out == 0 and self.settings.change_step_body_fixed:
                    # the autopilot's error fixed in its body turns with the vehicle (the earth-frame divergence
                    # circles in a yaw spin): the two segments' levels fitted beside one body-fixed part shared by
                    # both, whose motion is then not spread (_body_fixed_split)
                    d, spread = _body_fixed_split(rows, splits, n)
                c2 = (d * d).sum(axis=1)
                step = ((d * ma).sum(axis=1) > 0.0) & ~(c2 < k_s2 * spread)  # away from agreement, and a step
                if not step.any():
                    continue
                c = np.sqrt(c2[step])
                if w is not None:  # … nor the disagreement warned of coming back: as it stood before the warning …
                    back = ((ma[step] - np.array([w[ax - 1] for ax in axes])) ** 2).sum(axis=1)
                    c = np.minimum(c, np.sqrt(back))
                    # … and as it was when raised (an intermittent fault, 1 s in every 4 s, on again; as
                    # :meth:`_in_warning_test`'s baseline test)
                    back = ((ma[step] - np.array([self._e_warned[ax - 1] for ax in axes])) ** 2).sum(axis=1)
                    c = np.minimum(c, np.sqrt(back))
                best[out] = max(best[out], float((c / thr[step]).max()))
        c_t = best[0]
        c_h = best[1] if hdg_on else 0.0
        if self._min_thr[0] > 0.0:
            c_t = min(c_t, tilt / self._min_thr[0])
        if self._min_thr[1] > 0.0:
            c_h = min(c_h, abs(heading) / self._min_thr[1])
        return c_t, c_h

    def _split_thresholds(self, rate: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
        """The change test's threshold (``axis`` 0: tilt, 1: heading), rad, with the timing term of the turn rate
        ``rate`` (rad/s, per element) in place of the rate now: :meth:`_ChangeTest.judge`'s
        ``change_k·√(max(learnt, floor²) + (ω·sync_s)²)``, at most ``change_max_factor`` × the error model's
        ``sigma_k·√(σ_ours² + σ_autopilot² + (ω·sync_s)²)`` (at least its floor) as :meth:`_thresholds` builds
        it.  With ``rate`` the rate now it is the change test's threshold now."""
        ch = self._change
        assert ch is not None
        now = ch.thresholds[axis]
        if not math.isfinite(now):  # not ready (or the heading not judged)
            return np.full(rate.shape, now)
        s = self.settings
        sync2 = (rate * s.sync_s) ** 2
        sig = self._thr_sigmas[axis]
        cap = np.maximum(self._min_thr[axis], self._k * np.sqrt(sig * sig + self._sig_ap[axis] ** 2 + sync2))
        learnt = ch._learnt[1 + axis]
        return np.minimum(s.change_k * np.sqrt(max(learnt, ch._floor2[axis]) + sync2), s.change_max_factor * cap)

    def _drift_in_warning(self, t_ms: float, tilt: float, heading: float, hdg_on: bool) -> float:
        """A disagreement that grows while an in-flight warning is on (``MonitorSettings.change_drift_s``): the
        divergence vector ``e`` against the level the warning stands at, ``e_w``, its mean over the first
        ``change_step_s`` of the warning (a step that raised it, or came in those seconds, is in that level: the
        step tests judge those), tilt ``|e − e_w|`` (north, east) and heading each as the change test's ratio to
        its thresholds — the noise of a change of the divergence, learnt before the warning (the change test
        learns nothing while a warning is on) —, with the thresholds' floors; at most the distance from the
        nearest level the divergence took in the ``change_step_s`` before the warning and in its first
        ``change_step_s`` (an intermittent fault coming back is the warning already on: 35 → 57 repeated
        WARNINGs on 24 flights without it); 0 where the growth leads back toward agreement
        (``(e − e_w)·e ≤ 0``), where not judged now, or where the warning on was raised by this test.  A ramp of rate r started at the warning is a change of about r·(t − change_step_s / 2) after t
        s; within any 2 s it moves too little for the step tests (Page's CUSUM on a change in the mean against
        a known pre-change level, Basseville & Nikiforov 1993 §2.2)."""
        ch = self._change
        if ch is None or self.settings.change_drift_s <= 0.0 or not self._drift_armed:
            return 0.0
        if not (self._warning and self._warned_in_flight and self._change_aided):
            return 0.0
        e = self._e
        acc = self._drift_acc
        if t_ms - self._warning_since_ms <= 1000.0 * self.settings.change_step_s:  # the warning's level
            acc[0] += 1.0
            acc[1] += e[0]
            acc[2] += e[1]
            acc[3] += e[2]
            self._drift_seen.append(e)
            return 0.0
        if acc[0] < 1.0:
            return 0.0
        if self._drift_line is None:  # once, as the warning's level is complete: the growth it stood on
            self._drift_line = self._fit_drift_line(ch.thresholds)
        w = (acc[1] / acc[0], acc[2] / acc[0], acc[3] / acc[0])
        d = (e[0] - w[0], e[1] - w[1], e[2] - w[2])
        if d[0] * e[0] + d[1] * e[1] + (d[2] * e[2] if hdg_on else 0.0) <= 0.0:
            return 0.0
        t_thr, h_thr = ch.thresholds
        g_t, g_h = math.hypot(d[0], d[1]), abs(d[2])
        for x in self._drift_seen:  # … nor a disagreement already warned of coming back (an intermittent fault)
            g_t = min(g_t, math.hypot(e[0] - x[0], e[1] - x[1]))
            g_h = min(g_h, abs(e[2] - x[2]))
        t_c, mean, slope, sd_slope, fit_t, fit_h = self._drift_line
        if fit_t or fit_h:  # … nor the growth the warning already stood on, going on at its rate
            dt = 1e-3 * (t_ms - t_c)
            x = [mean[i] + slope[i] * dt for i in range(3)]
            # only a departure from the line away from agreement (a growth that slows or stops is not a new
            # fault), beyond what the line's own slope error allows by now (change_k standard errors × dt)
            k_dt = self.settings.change_k * abs(dt)
            allow_t, allow_h = k_dt * sd_slope[0], k_dt * sd_slope[1]
            if fit_t:
                away = (e[0] - x[0]) * e[0] + (e[1] - x[1]) * e[1] > 0.0
                g_t = min(g_t, max(0.0, math.hypot(e[0] - x[0], e[1] - x[1]) - allow_t) if away else 0.0)
            if fit_h:
                away = (e[2] - x[2]) * e[2] > 0.0
                g_h = min(g_h, max(0.0, abs(e[2] - x[2]) - allow_h) if away else 0.0)
        c_t = g_t / t_thr
        c_h = g_h / h_thr if hdg_on else 0.0
        if self._min_thr[0] > 0.0:
            c_t = min(c_t, tilt / self._min_thr[0])
        if self._min_thr[1] > 0.0:
            c_h = min(c_h, abs(heading) / self._min_thr[1])
        return max(c_t, c_h)

    def _fit_drift_line(
        self, thresholds: tuple[float, float]
    ) -> tuple[float, tuple[float, ...], tuple[float, ...], tuple[float, float], bool, bool]:
        """The divergence's least-squares line over the last ``change_drift_slope_s`` (the warning's level
        window and the seconds before it): (its mean time, ms; its mean e; its slope, rad/s; whether it fits
        the tilt; the heading).  It fits an axis where the residual RMS about it is within the change test's
        noise, threshold / ``change_k`` (a step in the window, or a ramp that starts in it, leaves a residual
        of the order of its size; a steady growth at one rate leaves only the divergence's own noise).
        Ordinary least squares, slope = Σ(t − t̄)(e − ē) / Σ(t − t̄)², its standard error RMS / √Σ(t − t̄)²
        (residuals taken as independent: an underestimate where the autopilot's error wanders)."""
        s = self.settings
        none = (0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0), False, False)
        hist = self._drift_hist
        if s.change_drift_slope_s <= 0.0 or len(hist) < 8:
            return none
        rows = np.array(hist)
        t = 1e-3 * rows[:, 0]
        if t[-1] - t[0] < 0.75 * s.change_drift_slope_s:  # too short a history: no line
            return none
        tm = float(t.mean())
        dt = t - tm
        sxx = float(dt @ dt)
        if sxx <= 0.0:
            return none
        em = rows[:, 1:].mean(axis=0)
        slope = (dt @ (rows[:, 1:] - em)) / sxx
        res = rows[:, 1:] - em - np.outer(dt, slope)
        rms = np.sqrt((res * res).mean(axis=0))
        t_thr, h_thr = thresholds
        fit_t = math.hypot(rms[0], rms[1]) <= t_thr / s.change_k
        fit_h = float(rms[2]) <= h_thr / s.change_k
        sd = (math.hypot(rms[0], rms[1]) / math.sqrt(sxx), float(rms[2]) / math.sqrt(sxx))  # the slope's std. error
        return 1000.0 * tm, tuple(float(x) for x in em), tuple(float(x) for x in slope), sd, fit_t, fit_h

    def _imu_warning(self, t_ms: float) -> list[Any]:
        """A WARNING the first time an IMU is named (once per IMU until it agrees again)."""
        name, err = self._imus.named(self._imu_named) if self._imus._err else ("", math.nan)
        self._evidence.imu = name
        if name == self._imu_named:
            return []
        self._imu_named = name
        if not name:
            return []
        phase = self.phase.phase(t_ms)
        self.last_phase = phase
        self._evidence.sigma, self._evidence.sigma_hdg = self._sigma, self._sigma_hdg
        self.last_evidence = self._evidence.evidence()
        self.last_update = False
        self._episodes += 1
        text = IMU_TEXT.format(imu=name, rate=err)
        if phase in FLIGHT_PHASES:
            return [_statustext(mavlink.MAV_SEVERITY_WARNING, text)]
        self._ground_episodes += 1
        return [_statustext(mavlink.MAV_SEVERITY_NOTICE, text)]

    def _learn(self, tilt: float, heading: float, dt_s: float) -> None:
        """The divergence's mean square (:func:`_mean_squares`)."""
        self._learnt = _mean_squares(self._learnt, tilt, heading, dt_s, self.settings.learn_s)

    def _compare(self, t_ms: float, q_est: Sequence[float], q_ap: Sequence[float]) -> list[Any]:
        out = self._judge(t_ms, q_est, q_ap)
        strip = self._strip
        if not strip or t_ms - strip[-1][0] * 1000.0 >= _STRIP_STEP_MS or t_ms < strip[-1][0] * 1000.0 or out:
            if strip and t_ms < strip[-1][0] * 1000.0 - _REBOOT_MS:
                strip.clear()  # a reboot: the old time axis no longer applies
            said = 0
            for m in out:
                sev = int(m.severity)
                said = max(said, 2 if sev == mavlink.MAV_SEVERITY_WARNING else 1 if sev == mavlink.MAV_SEVERITY_NOTICE else 0)
            strip.append((t_ms / 1000.0, math.degrees(self._tilt), math.degrees(self._heading),
                          math.degrees(self._tilt_thr_now), math.degrees(self._hdg_thr_now), self._warning, said))
            horizon = t_ms / 1000.0 - self.settings.strip_s
            while strip and strip[0][0] < horizon:
                strip.popleft()
        return out

    def _judge(self, t_ms: float, q_est: Sequence[float], q_ap: Sequence[float]) -> list[Any]:
        s = self.settings
        tilt, heading = _divergence(q_est, q_ap)
        self._tilt, self._heading = tilt, heading
        self._evidence.compare(t_ms, q_est, q_ap)
        self._imus.compare(t_ms, q_ap)
        self._comparisons += 1
        self._fresh = True
        prev = self._last_cmp_ms
        gap = prev is not None and t_ms - prev > self._gap_ms()
        self._last_cmp_ms = t_ms
        if self._imu_rate_hz < s.min_imu_rate_hz:  # (NaN: not told, judged)
            # our estimate cannot follow the vehicle at this rate, and its σ does not say so: not judged, nothing
            # learnt; once the rate is back, the start-up grace again (our filter re-converges) and no
            # "continuous" timer carried across (a gap)
            self._held = True
            self.held_comparisons += 1
            self._tilt_thr_now = self._hdg_thr_now = math.nan
            return []
        if self._held:
            self._held = False
            self._first_est_ms = t_ms
            gap = True
        if gap:
            self._above_since_ms = self._below_since_ms = None
            self._cusum = self._cusum_c = self._cusum_w = self._cusum_d = 0.0
        t_thr, h_thr = self._thresholds()
        self._tilt_thr_now, self._hdg_thr_now = t_thr, h_thr
        hdg_on = h_thr > 0.0
        z_t = tilt / t_thr
        z_h = abs(heading) / h_thr if hdg_on else 0.0
        slow = self._rate <= self._learn_rate  # the timing term small: what is learnt is the estimators' errors
        z = max(z_t, z_h)
        z_c = 0.0  # the change against the divergence's own baseline (see _ChangeTest), its own CUSUM
        if self._change is not None:
            c_t, c_h = self._change_test(t_ms, q_est, q_ap, slow and prev is not None and not gap,
                                         0.0 if prev is None else 1e-3 * (t_ms - prev))
            if s.change_step_outside and not self._warning and (c_t > 0.0 or c_h > 0.0):
                # a step within the last change_step_s, which the 10 s baseline shows only as a part of itself
                s_t, s_h = self._step_ratio(t_ms, tilt, heading, hdg_on, in_warning=False)
                c_t, c_h = max(c_t, s_t), max(c_h, s_h)
            # a change that leaves the divergence within the thresholds' floors is not one to warn of (an
            # autopilot within 1° of tilt and 3° of heading is not, whatever its error did)
            c_t = min(c_t, tilt / self._min_thr[0]) if self._min_thr[0] > 0.0 else c_t
            c_h = min(c_h, abs(heading) / self._min_thr[1]) if self._min_thr[1] > 0.0 else c_h
            z_c = max(c_t, c_h if hdg_on else 0.0)
            z_t = max(z_t, c_t)
            z_h = max(z_h, c_h) if hdg_on else 0.0
        z_w = self._in_warning_test(t_ms, tilt, heading, hdg_on)
        z_d = self._drift_in_warning(t_ms, tilt, heading, hdg_on)
        # learnt: only what lies within the model's own thresholds (never a disagreement the learnt widening
        # itself let through, else a slowly growing fault would raise the threshold ahead of it)
        self._evidence.heading_only = hdg_on and z_t <= 1.0 and z_h > 1.0
        m_t, m_h = self._model_thr
        inside = tilt <= m_t and (not hdg_on or abs(heading) <= m_h)
        if self._uncertainty and not self._warning and inside and slow and prev is not None and not gap:
            self._learn(tilt, heading if hdg_on else 0.0, 1e-3 * (t_ms - prev))  # also in the start-up grace
        first = self._first_est_ms if self._first_est_ms is not None else t_ms
        if t_ms - first < 1000.0 * s.startup_grace_s:
            return []
        imu_out = self._imu_warning(t_ms)
        if imu_out:
            return imu_out
        k = s.clear_fraction
        above = z > 1.0
        below = z < k and z_c < 1.0  # (a change still beyond its threshold is not over)
        if above:
            self._below_since_ms = None
            if self._above_since_ms is None:
                self._above_since_ms = t_ms
        elif below:
            self._above_since_ms = None
            if self._below_since_ms is None:
                self._below_since_ms = t_ms
        else:  # between the clear and trigger thresholds: neither timer runs
            self._above_since_ms = self._below_since_ms = None
        if self._uncertainty:
            dt = 0.0 if (prev is None or gap) else 1e-3 * (t_ms - prev)
            step = (min(z, 3.0) - s.cusum_reference) * dt
            self._cusum = min(2.0 * self._h, max(0.0, self._cusum + max(step, -s.cusum_leak_per_s * dt)))
            step = (min(z_c, 3.0) - s.change_cusum_reference) * dt
            self._cusum_c = min(2.0 * self._h_c, max(0.0, self._cusum_c + max(step, -s.cusum_leak_per_s * dt)))
            step = (min(z_w, 3.0) - s.change_cusum_reference) * dt
            self._cusum_w = min(2.0 * self._h_c, max(0.0, self._cusum_w + max(step, -s.cusum_leak_per_s * dt)))
            step = (min(z_d, 3.0) - s.change_cusum_reference) * dt
            self._cusum_d = min(2.0 * self._h_d, max(0.0, self._cusum_d + max(step, -s.cusum_leak_per_s * dt)))
            level = above and self._cusum >= self._h
            confirmed = level or (z_c > 1.0 and self._cusum_c >= self._h_c)
            # a new step while a warning is on (change_in_warning_s) that leaves the divergence beyond its
            # threshold: a new episode (a step back toward agreement is not one to say again). Judged as a step
            # outside a warning is: beyond the level threshold *or* the change test's (z_c, which carries the
            # floors: the divergence beyond 1° / 3°). The level threshold alone let our heading σ in a fast yaw
            # (1.6–2.6°, the level threshold 5.9–8.3°) and the autopilot's own error standing the other way hold
            # a +6° heading step back for 5.7 s under a correct warning (firmware_sim aggressive 81; outside a
            # warning the same divergence was warned in 0.7 s: docs/monitor.md, rounds nine and eleven)
            # (outside a warning z_c carries the step test too, ``change_step_outside``: so does the gate here)
            again = z_w > 1.0 and self._cusum_w >= self._h_c and max(z, z_c, self._z_step) > 1.0
            # … or the disagreement grown on since the warning by more than the change test allows, lasting
            # (change_drift_s): a ramp that starts under a warning already on
            drift = self._drift_armed and z_d > 1.0 and self._cusum_d >= self._h_d and z > 1.0
            again = again or drift
        else:
            level = confirmed = self._above_since_ms is not None and t_ms - self._above_since_ms >= 1000.0 * s.trigger_s
            again = drift = False
        # an episode raised on the ground that is still on once airborne is raised again, in flight
        if (confirmed and (not self._warning or not self._warned_in_flight)) or again:
            phase = self.phase.phase(t_ms)
            if self._warning and phase not in FLIGHT_PHASES:
                return []
            if self._in_warning is not None:  # its baseline: the divergence from this warning on
                self._in_warning.restart()
                self._cusum_w = 0.0
            self._e_warned = self._e
            rec = self._recent  # … and as it stood over the seconds before (the step test's reference)
            self._e_warned_mean = tuple(sum(r[i] for r in rec) / len(rec) for i in (1, 2, 3)) if rec else self._e
            self._cusum_d = 0.0
            self._drift_acc = [0.0, 0.0, 0.0, 0.0]  # (n, Σe): the level it stands at (_drift_in_warning)
            self._drift_seen = [r[1:4] for r in rec]  # the levels already warned of (_drift_in_warning)
            self._drift_line = None  # … and the growth it stands on, fitted once its level is complete
            self._drift_armed = not drift  # a drift warned of is the warning now on: not raised again as it grows
            self._warning = True
            self._trigger = "step" if again or not level else "level"
            self._warning_since_ms = t_ms
            self._episodes += 1
            self.last_phase = phase
            self._warned_in_flight = phase in FLIGHT_PHASES
            self._evidence.sigma, self._evidence.sigma_hdg = self._sigma, self._sigma_hdg
            ev = self._evidence.evidence()
            self.last_evidence = ev
            self.last_update = False
            self._updates = 0
            self._next_evidence_ms = t_ms + _EVIDENCE_PERIOD_MS
            cause = ev.cause
            self.last_cause = cause
            if self._warned_in_flight:
                text = _fit(WARNING_TEXT, tilt, heading, "", cause)
                return [_statustext(mavlink.MAV_SEVERITY_WARNING, text)]
            self._ground_episodes += 1
            text = _fit(PHASE_TEXT, tilt, heading, PHASE_WORDS.get(phase, phase), cause)
            return [_statustext(mavlink.MAV_SEVERITY_NOTICE, text)]
        if above or z_c > 1.0 or z_w > 1.0 or z_d > 1.0:
            self._beyond_ms = t_ms  # the disagreement beyond a threshold (said again only while it is recent)
        if self._warning and t_ms >= self._next_evidence_ms:  # the evidence as it builds up: said again when new
            self._next_evidence_ms = t_ms + _EVIDENCE_PERIOD_MS
            self._evidence.sigma, self._evidence.sigma_hdg = self._sigma, self._sigma_hdg
            ev = self._evidence.evidence()
            new = [w for w in ev.cause.split() if w not in self.last_cause.split()]
            self.last_evidence = ev
            # … while the disagreement is still there, or was within the evidence's newest window (gnss_window_s):
            # once the divergence has been back within its thresholds longer (the warning waits clear_s to be
            # over) a new verdict would be about a disagreement gone (firmware_sim aggressive 41 at 27.5 s: `us?`
            # said with the two 0.3° apart, both within 0.2° of the truth)
            if new and t_ms - self._beyond_ms <= 1000.0 * s.gnss_window_s and self._updates < _MAX_UPDATES:
                self._updates += 1
                self.last_cause = ev.cause
                self.last_update = True
                template = WARNING_TEXT if self._warned_in_flight else PHASE_TEXT
                severity = mavlink.MAV_SEVERITY_WARNING if self._warned_in_flight else mavlink.MAV_SEVERITY_NOTICE
                return [_statustext(severity, _fit(template, tilt, heading, PHASE_WORDS.get(self.last_phase, self.last_phase), ev.cause))]
        if self._warning and self._below_since_ms is not None and t_ms - self._below_since_ms >= 1000.0 * s.clear_s:
            self._warning = False
            self._cusum = self._cusum_c = self._cusum_w = self._cusum_d = 0.0
            return [_statustext(mavlink.MAV_SEVERITY_INFO, CLEARED_TEXT)]
        return []

    # ------------------------------------------------------------------ outputs
    @property
    def last_comparison_ms(self) -> float:
        """Autopilot time of the latest comparison, ms (NaN before the first)."""
        return self._last_cmp_ms if self._last_cmp_ms is not None else math.nan

    @property
    def status(self) -> MonitorStatus:
        return MonitorStatus(
            tilt_deg=math.degrees(self._tilt),
            heading_deg=math.degrees(self._heading),
            warning=self._warning,
            comparisons=self._comparisons,
            unmatched=self._unmatched,
            episodes=self._episodes,
            velocity_source=self.velocity_source,
            tilt_threshold_deg=math.degrees(self._tilt_thr_now),
            heading_threshold_deg=math.degrees(self._hdg_thr_now),
            phase=self.phase.phase(self._last_cmp_ms) if self._last_cmp_ms is not None else self.phase.phase(0.0),
            ground_episodes=self._ground_episodes,
            cause=self.last_cause if self._warning else "",
            evidence=self.last_evidence if self._warning else None,
            trigger=self._trigger if self._warning else "",
            strip=tuple(self._strip),
            imu_late=self._imus.late,
            held=self._held,
            imu_rate_hz=self._imu_rate_hz,
            held_comparisons=self.held_comparisons,
        )

    @property
    def evidence(self) -> Evidence:
        """The evidence of who is likely wrong as it stands now (whether or not a warning is on)."""
        self._evidence.sigma, self._evidence.sigma_hdg = self._sigma, self._sigma_hdg
        return self._evidence.evidence()


class _ChangeTest:
    r"""The divergence's *change* against its own recent baseline (``MonitorSettings.change_test``; pure).

    Per comparison the divergence vector ``e`` (earth frame, rad: ``2·xyz`` of ``q_ours ⊗ q_autopilot*``).
    The baseline ``ê`` is its exponential mean (time constant ``change_baseline_s``, a running mean at first)
    over comparisons at least ``change_delay_s`` old, not fed while a warning is on; the change ``d = e − ê``
    is split as the divergence: tilt ``|d_n, d_e|``, heading ``d_d``.  Its mean squares are learnt as the
    absolute divergence's (running mean over ``learn_s``, then exponential; slow rotation only; within the
    change's own thresholds; never during a warning); the thresholds are
    ``change_k·√(max(learnt, min²) + (ω·sync_s)²)``, at most the cap given.  A step fault of size δ is a
    change of δ for ``change_delay_s`` and fades with the baseline's time constant after; a ramp of rate r
    settles to a change of about ``r·(change_delay_s + change_baseline_s)``.  (The CUSUM of Page 1954 on the
    change rather than on the level: Basseville & Nikiforov 1993, a change in the mean.)  ``ready_s``: fed this
    long before it judges (default ``change_baseline_s``; the test of a new step within a warning,
    ``change_in_warning_s``, its baseline the divergence since the warning).
    """

    def __init__(self, s: MonitorSettings, ready_s: float | None = None) -> None:
        self.s = s
        self._delay_ms = 1000.0 * s.change_delay_s
        self._tau = s.change_baseline_s
        self._ready_s = self._tau if ready_s is None else ready_s  # fed this long before it judges
        self._floor2 = (math.radians(s.change_min_tilt_deg) ** 2, math.radians(s.change_min_heading_deg) ** 2)
        self._learnt = [0.0, 0.0, 0.0]  # seconds learnt, mean tilt change², mean heading change² (rad²)
        self.thresholds = (math.inf, math.inf)
        self.tilt = self.heading = 0.0
        self.restart()

    def restart(self) -> None:
        """Forget the baseline (not the learnt noise): e.g. GNSS aiding lost and back."""
        self._buf: deque[tuple[float, ...]] = deque()  # (t_ms, e[, q]) not yet fed
        self._fed_s = 0.0
        self._fed_ms: float | None = None
        self._mean = [0.0, 0.0, 0.0]
        # the turn's weighted means (MonitorSettings.change_baseline_turn), with the baseline's weights: our heading
        # as z = e^{iψ} (cos, sin) and the tilt divergence in our heading's axes, conj(z)·(e_n + i e_e)
        self._z_mean = [0.0, 0.0]
        self._u_mean = [0.0, 0.0]

    def _feed(self, t: float, e: Sequence[float], q: Sequence[float] | None = None) -> None:
        prev = self._fed_ms
        self._fed_ms = t
        if prev is None:
            w = 1.0
        else:
            dt = 1e-3 * (t - prev)
            if not dt > 0.0:
                return
            self._fed_s += dt
            w = min(1.0, dt / max(min(self._fed_s, self._tau), 1e-9))  # a running mean at first
        m = self._mean
        for i in range(3):
            m[i] += w * (e[i] - m[i])
        if q is not None:  # the turn's means (q: cos ψ, sin ψ of our heading)
            c, sn = q[0], q[1]
            zm, um = self._z_mean, self._u_mean
            zm[0] += w * (c - zm[0])
            zm[1] += w * (sn - zm[1])
            um[0] += w * (c * e[0] + sn * e[1] - um[0])
            um[1] += w * (c * e[1] - sn * e[0] - um[1])

    def update(self, t: float, e: Sequence[float], frozen: bool, yaw: Sequence[float] | None = None) -> bool:
        """A comparison; True when the baseline is ready and :attr:`tilt` / :attr:`heading` hold the change.
        ``yaw``: our heading now as (cos ψ, sin ψ), kept beside the divergence for :meth:`turned`
        (``MonitorSettings.change_baseline_turn``); None: not kept."""
        buf = self._buf
        buf.append((t, e[0], e[1], e[2]) if yaw is None else (t, e[0], e[1], e[2], yaw[0], yaw[1]))
        horizon = t - self._delay_ms
        while buf and buf[0][0] <= horizon:
            row = buf.popleft()
            if frozen:
                self._fed_ms = row[0]  # the time frozen does not count as fed
            else:
                self._feed(row[0], row[1:4], row[4:6] if len(row) > 4 else None)
        if self._fed_s < self._ready_s:  # used once fed for its time constant (after GNSS comes back: our
            return False  # own error converging is not a change to warn of)
        m = self._mean
        self.tilt = math.hypot(e[0] - m[0], e[1] - m[1])
        self.heading = e[2] - m[2]
        return True

    def turned(self, e: Sequence[float], yaw: Sequence[float], prior2: float, noise2: float) -> tuple[float, float]:
        """The tilt's change against a baseline that may hold a part fixed in our heading's axes
        (``MonitorSettings.change_baseline_turn``): the baseline's tilt divergence ``E_s = A + z_s B`` (complex
        north + i east; ``A`` fixed in the earth frame, ``B`` in the vehicle's heading axes, ``z_s = e^{iψ_s}``)
        fitted to the baseline's weighted comparisons with a Gaussian prior of ``prior2`` per axis on ``B``
        (Bayesian ridge, λ = ``noise2`` / ``prior2``), predicted at our heading now: ``Ê = Ē + (z − z̄) B̂``.
        Returns ``|E − Ê|`` and the prediction's variance (both axes), ``|z − z̄|² · prior2 · λ / (1 − |z̄|² + λ)``:
        without a turn in the baseline (|z̄| = 1) a turn since adds the prior's whole variance for what the
        standing divergence's body-fixed part may turn into; where the baseline turned, ``B`` is measured and
        the prediction's variance small.  Rad, rad²."""
        m, zm, um = self._mean, self._z_mean, self._u_mean
        lam = noise2 / prior2 if prior2 > 0.0 else math.inf
        den = 1.0 - (zm[0] * zm[0] + zm[1] * zm[1]) + lam
        if not (math.isfinite(lam) and den > 0.0):
            return math.hypot(e[0] - m[0], e[1] - m[1]), 0.0
        # B̂ = (mean(conj(z) E) − conj(z̄) Ē) / den (complex)
        br = (um[0] - (zm[0] * m[0] + zm[1] * m[1])) / den
        bi = (um[1] - (zm[0] * m[1] - zm[1] * m[0])) / den
        dzr, dzi = yaw[0] - zm[0], yaw[1] - zm[1]
        pn = m[0] + dzr * br - dzi * bi
        pe = m[1] + dzr * bi + dzi * br
        g2 = dzr * dzr + dzi * dzi
        return math.hypot(e[0] - pn, e[1] - pe), 2.0 * g2 * prior2 * lam / den

    def judge(
        self, rate: tuple[float, float], learn: bool, dt_s: float, cap: tuple[float, float]
    ) -> tuple[float, float]:
        """(tilt, heading) thresholds of the change now, rad, at most ``cap`` (the absolute test's error
        model's); ``rate``: our earth-frame turn rate, horizontal and vertical, rad/s (the timing term of each);
        learns the change's noise when ``learn``."""
        n, m_t, m_h = self._learnt
        sync_t2 = (rate[0] * self.s.sync_s) ** 2
        sync2 = (rate[1] * self.s.sync_s) ** 2
        k = self.s.change_k
        ready = n >= 0.1 * self.s.learn_s
        f_t, f_h = self._floor2
        if ready:
            t_thr = min(k * math.sqrt(max(m_t, f_t) + sync_t2), cap[0])
            h_thr = min(k * math.sqrt(max(m_h, f_h) + sync2), cap[1]) if cap[1] > 0.0 else math.inf
        else:
            t_thr = h_thr = math.inf
        self.thresholds = (t_thr, h_thr)
        # learnt: what lies within the change's own thresholds (from the start, within those of the mean
        # square so far at 2 × change_k: the first seconds' noise is not cut off at a floor)
        gate_t = t_thr if ready else 2.0 * k * math.sqrt(max(m_t, f_t) + sync_t2)
        gate_h = h_thr if ready else 2.0 * k * math.sqrt(max(m_h, f_h) + sync2)
        if learn and self.tilt <= gate_t and abs(self.heading) <= gate_h:
            self._learnt = _mean_squares(self._learnt, self.tilt, self.heading, dt_s, self.s.learn_s)
        return t_thr, h_thr


#: the body-fixed part's prior in :func:`_body_fixed_split`, as a share of the window's samples (a ridge: the
#: part is fitted only as far as the vehicle's turning within the two segments tells it from their levels)
_BODY_FIXED_RIDGE = 0.1


def _body_fixed_split(rows: NDArray[np.float64], splits: NDArray[np.int64], n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The tilt step test's change and spread per split with a body-fixed part (``MonitorSettings.change_step_body_fixed``).

    The horizontal divergence ``e_t`` (north, east; ``rows`` columns 1–2) is fitted per split ``k`` as a level
    ``a₁`` before it and ``a₂`` after it plus ``M_t b``: a rotation vector ``b`` fixed in the body (an error of
    the autopilot's, or ours, that turns with the vehicle) seen in the earth frame, ``M_t`` the first two rows of
    our attitude's rotation matrix (``rows`` columns 7–10: q body→NED, w x y z).  Least squares with a ridge
    ``λ = _BODY_FIXED_RIDGE · n`` on ``b``: with the segments' levels eliminated, ``(Σ MᵀM − S₁ᵀS₁/n₁ − S₂ᵀS₂/n₂
    + λI) b = Σ Mᵀe − S₁ᵀē₁ − S₂ᵀē₂`` (``S`` a segment's sum of ``M``, ``ē`` its sum of ``e`` over its count), then
    ``a_i = (Σ_i e − S_i b) / n_i``.  Without turning ``b`` → 0 and this is the plain split (the means' change, the
    spread about them).  Returns ``a₂ − a₁`` (per split, 2) and the two segments' mean squared residuals summed."""
    e = rows[:, 1:3]
    w, x, y, z = rows[:, 7], rows[:, 8], rows[:, 9], rows[:, 10]
    m = np.empty((n, 2, 3))
    m[:, 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    m[:, 0, 1] = 2.0 * (x * y - w * z)
    m[:, 0, 2] = 2.0 * (x * z + w * y)
    m[:, 1, 0] = 2.0 * (x * y + w * z)
    m[:, 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    m[:, 1, 2] = 2.0 * (y * z - w * x)

    def prefix(v: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.zeros((n + 1, *v.shape[1:]))
        np.cumsum(v, axis=0, out=out[1:])
        return out

    p_m = prefix(m)  # Σ M (2×3)
    p_e = prefix(e)  # Σ e (2)
    p_mm = prefix(np.einsum("tij,tik->tjk", m, m))  # Σ MᵀM (3×3)
    p_me = prefix(np.einsum("tij,ti->tj", m, e))  # Σ Mᵀe (3)
    p_ee = prefix((e * e).sum(axis=1))
    n1 = splits.astype(np.float64)
    n2 = n - n1
    s1m, s2m = p_m[splits], p_m[n] - p_m[splits]
    s1e, s2e = p_e[splits], p_e[n] - p_e[splits]
    g = (p_mm[n] - np.einsum("kij,kil->kjl", s1m, s1m) / n1[:, None, None]
         - np.einsum("kij,kil->kjl", s2m, s2m) / n2[:, None, None] + _BODY_FIXED_RIDGE * n * np.eye(3))  # fmt: skip
    r = (p_me[n] - np.einsum("kij,ki->kj", s1m, s1e) / n1[:, None]
         - np.einsum("kij,ki->kj", s2m, s2e) / n2[:, None])  # fmt: skip
    b = np.linalg.solve(g, r[:, :, None])[:, :, 0]
    a1 = (s1e - np.einsum("kij,kj->ki", s1m, b)) / n1[:, None]
    a2 = (s2e - np.einsum("kij,kj->ki", s2m, b)) / n2[:, None]

    def ss(pee: NDArray[np.float64], se: NDArray[np.float64], sm: NDArray[np.float64], pme: NDArray[np.float64],
           pmm: NDArray[np.float64], a: NDArray[np.float64], cnt: NDArray[np.float64]) -> NDArray[np.float64]:
        """Σ |e − a − M b|² over a segment, from its sums."""
        return (pee - 2.0 * (a * se).sum(axis=1) - 2.0 * (b * pme).sum(axis=1) + cnt * (a * a).sum(axis=1)
                + 2.0 * np.einsum("ki,kij,kj->k", a, sm, b) + np.einsum("kj,kjl,kl->k", b, pmm, b))  # fmt: skip

    ss1 = ss(p_ee[splits], s1e, s1m, p_me[splits], p_mm[splits], a1, n1)
    ss2 = ss(p_ee[n] - p_ee[splits], s2e, s2m, p_me[n] - p_me[splits], p_mm[n] - p_mm[splits], a2, n2)
    return a2 - a1, np.maximum(0.0, ss1) / n1 + np.maximum(0.0, ss2) / n2


def _mean_squares(learnt: list[float], tilt: float, heading: float, dt_s: float, learn_s: float) -> list[float]:
    """``[seconds learnt, mean tilt², mean heading²]`` after ``dt_s`` more: a running mean over the first
    ``learn_s``, then exponential with that time constant (unchanged when ``dt_s`` ≤ 0)."""
    if not dt_s > 0.0:
        return learnt
    n, m_t, m_h = learnt
    n += dt_s
    w = dt_s / min(n, learn_s) if learn_s > 0 else 1.0
    return [n, m_t + w * (tilt * tilt - m_t), m_h + w * (heading * heading - m_h)]


def _fit(template: str, tilt_rad: float, heading_rad: float, phase: str, cause: str = "") -> str:
    """The warning text (+ `` [cause]``), ≤ 50 bytes: one decimal while it fits, else whole degrees, else the
    cause's last words dropped."""
    t, h = math.degrees(tilt_rad), math.degrees(heading_rad)
    words = cause.split()
    short = template.replace(":.1f}", ":.0f}").replace(":+.1f}", ":+.0f}")
    while True:
        tail = f" [{' '.join(words)}]" if words else ""
        for tpl in (template, short):
            text = tpl.format(tilt=t, heading=h, phase=phase) + tail
            if len(text.encode()) <= _STATUSTEXT_MAX or (not words and tpl is short):
                return text
        words.pop()


class _Evidence:
    """Who is likely wrong (pure; fed by the monitor): the magnetometer's field against the expected one, and
    which attitude turns the specific force into the GNSS velocity change.

    Per comparison, the mean specific force since the previous one is rotated into NED by our attitude and by
    the autopilot's and integrated (horizontal).  Per GNSS fix, over the window back to a fix ``gnss_window_s``
    earlier: our miss ``r = ∫a_ours − Δv`` and the two attitudes' difference ``D = ∫a_AP − ∫a_ours``; the
    autopilot's miss is ``r + D``.  The share of ``D`` the GNSS puts on us is the least-squares
    ``−Σ r·D / Σ |D|²`` over the recent windows (0: the GNSS velocity agrees with ours, 1: with the
    autopilot's); noise along other directions than the difference does not enter.
    """

    def __init__(self, s: MonitorSettings) -> None:
        self.s = s
        self.mag_ref: tuple[float, float] | None = None
        self.mag_offset_ut = math.nan
        self.mag_model_disturbed = False
        self.heading_only = False  # the disagreement judged is in heading alone (see gnss_heading_min_m_s)
        self.sigma = math.nan
        self.sigma_hdg = math.nan
        self.imu = ""
        self._f_sum = [0.0, 0.0, 0.0]
        self._f_n = 0
        self._accel: tuple[float, float, float] | None = None
        self._mag: deque[tuple[float, float, float]] = deque()  # (t_ms, norm dev, dip dev rad)
        self._mag_body: tuple[float, float, float] | None = None
        self._vel_t = -math.inf  # newest fix time taken
        self._pending: deque[tuple[float, float, float]] = deque()  # fixes not yet reached by a comparison
        self._last_ms: float | None = None
        self._int = [0.0, 0.0, 0.0, 0.0]  # ∫ horizontal acceleration, ours (n, e), the autopilot's (n, e)
        self._hist: deque[tuple[float, float, float, float, float]] = deque()  # (t, ∫…) at comparisons
        self._fixes: deque[tuple[float, float, float, float, float, float, float]] = deque()  # t, vn, ve, ∫…
        self._res: deque[tuple[float, float, float, float]] = deque()  # (t, r·D, |D|², |r ⊥ D|²)

    def sensors(self, t: float, accel: Any, mag: Any, vel: Any, vel_t: float) -> None:
        if accel is not None:
            x, y, z = accel
            if x - x == 0.0 and y - y == 0.0 and z - z == 0.0:  # finite
                f = self._f_sum
                f[0] += x
                f[1] += y
                f[2] += z
                self._f_n += 1
        self._mag_body = None
        if mag is not None:
            x, y, z = mag
            if x - x == 0.0 and y - y == 0.0 and z - z == 0.0:
                self._mag_body = (float(x), float(y), float(z))
        if vel is not None and math.isfinite(vel_t) and math.isfinite(vel[0]) and math.isfinite(vel[1]):
            if vel_t > self._vel_t:
                self._vel_t = vel_t
                self._pending.append((vel_t, float(vel[0]), float(vel[1])))
                if len(self._pending) > 50:
                    self._pending.popleft()

    def _integral_at(self, t: float) -> tuple[float, float, float, float] | None:
        h = self._hist
        if not h or t < h[0][0] or t > h[-1][0]:
            return None
        i = len(h) - 1
        while i > 0 and h[i - 1][0] >= t:
            i -= 1
        b = h[i]
        if i == 0 or b[0] == t:
            return b[1], b[2], b[3], b[4]
        a = h[i - 1]
        if b[0] - a[0] > 1000.0:
            return None
        u = (t - a[0]) / (b[0] - a[0])
        return tuple(a[k] + u * (b[k] - a[k]) for k in range(1, 5))  # type: ignore[return-value]

    def _fix(self, t: float, vn: float, ve: float) -> None:
        i = self._integral_at(t)
        if i is None:
            return
        self._fixes.append((t, vn, ve, i[0], i[1], i[2], i[3]))
        w = 1000.0 * self.s.gnss_window_s
        while len(self._fixes) > 1 and self._fixes[1][0] <= t - w:
            self._fixes.popleft()
        old = self._fixes[0]
        if t - old[0] >= 0.8 * w:
            dvn, dve = vn - old[1], ve - old[2]
            rn, re = i[0] - old[3] - dvn, i[1] - old[4] - dve
            dn, de = i[2] - old[5] - (i[0] - old[3]), i[3] - old[6] - (i[1] - old[4])
            dd = dn * dn + de * de
            rd = rn * dn + re * de
            perp = rn * rn + re * re - (rd * rd / dd if dd > 0.0 else 0.0)  # our miss across the difference
            self._res.append((t, rd, dd, max(0.0, perp)))
        while self._res and self._res[0][0] < t - 3.0 * w:
            self._res.popleft()

    def compare(self, t: float, q_est: Sequence[float], q_ap: Sequence[float]) -> None:
        last, self._last_ms = self._last_ms, t
        if self._f_n:
            n = self._f_n
            self._accel = (self._f_sum[0] / n, self._f_sum[1] / n, self._f_sum[2] / n)
            self._f_sum = [0.0, 0.0, 0.0]
            self._f_n = 0
        f = self._accel
        if last is not None and t - last >= 1000.0:
            self._fixes.clear()  # a gap: the integrals no longer match the fixes
            self._hist.clear()
        if f is not None and last is not None and 0.0 < t - last < 1000.0:
            dt = 1e-3 * (t - last)
            for k, q in ((0, q_est), (2, q_ap)):
                an, ae = _rotate_ne(q, f)
                self._int[k] += an * dt
                self._int[k + 1] += ae * dt
        if f is not None:
            h = self._hist
            h.append((t, *self._int))
            while h and h[0][0] < t - 2000.0:
                h.popleft()
            p = self._pending
            while p and p[0][0] <= t:
                self._fix(*p.popleft())
        m = self._mag_body
        if m is not None and self.mag_ref is not None:
            n = math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
            if n > 0.0:
                down = _rotate_d(q_est, m)
                dip = math.asin(max(-1.0, min(1.0, down / n)))
                ref_n, ref_dip = self.mag_ref
                self._mag.append((t, (n - ref_n) / ref_n if ref_n > 0 else 0.0, dip - ref_dip))
        while self._mag and self._mag[0][0] < t - 3000.0:
            self._mag.popleft()

    def evidence(self) -> Evidence:
        s = self.s
        kw: dict[str, Any] = {"tilt_sigma_deg": math.degrees(self.sigma), "imu": self.imu,
                              "heading_sigma_deg": math.degrees(self.sigma_hdg) if math.isfinite(self.sigma) else math.nan,
                              "mag_offset_ut": self.mag_offset_ut}
        if self._mag:
            norm = sorted(x[1] for x in self._mag)[len(self._mag) // 2]
            dip = sorted(x[2] for x in self._mag)[len(self._mag) // 2]
            kw.update(mag_norm_dev=norm, mag_dip_dev_deg=math.degrees(dip),
                      mag_disturbed=abs(norm) > s.mag_norm_tolerance or abs(dip) > math.radians(s.mag_dip_tolerance_deg))
        if self.mag_model_disturbed:  # the magnetometer model (:mod:`mavahrs.filters.magfield`) says so itself
            kw["mag_disturbed"] = True
        if self._res:
            rd = sum(r[1] for r in self._res)
            dd = sum(r[2] for r in self._res)
            d_rms = math.sqrt(max(r[2] for r in self._res))
            kw["gnss_m_s"] = d_rms
            if d_rms >= (s.gnss_heading_min_m_s if self.heading_only else s.gnss_min_m_s):
                share = -rd / dd
                kw["gnss_blames_us"] = share
                # its standard error: the integration's own error (accelerometer bias, the sensors' timing; as
                # large along the difference as across it) over the difference, windows gnss_window_s apart
                # counted as independent
                res = self._res
                n_eff = max(1.0, 1e-3 * (res[-1][0] - res[0][0]) / s.gnss_window_s + 1.0)
                se = math.sqrt(sum(x[3] for x in res) / len(res) / (dd / len(res)) / n_eff)
                kw["gnss_share_se"] = se
                r = s.gnss_ratio
                if se > s.gnss_max_share_se:  # the two sides not told apart: no verdict
                    pass
                elif share <= 1.0 / (1.0 + r):  # the autopilot's miss along D ≥ r × ours
                    kw["gnss_verdict"] = "AP"
                elif share >= r / (1.0 + r):
                    kw["gnss_verdict"] = "us"
        return Evidence(**kw)

    def cause(self, tilt: float, heading: float) -> str:
        return self.evidence().cause


class _ImuTrack:
    """One IMU's gyro samples not yet judged (:class:`_ImuCheck`)."""

    __slots__ = ("pending", "closed_ms", "newest_ms")

    def __init__(self) -> None:
        self.pending: list[tuple[float, float, float, float]] = []  # (t_ms, x, y, z), arrival order
        self.closed_ms = -math.inf  # every interval ending at or before this time is judged
        self.newest_ms = -math.inf  # the newest sample's time


class _ImuCheck:
    """Which IMU is off (pure): each IMU's gyro, averaged over each interval between two of the autopilot's
    attitudes *by the samples' own times*, against the body rate that attitude turned at over the interval
    (the rotation vector of ``q_prev* ⊗ q`` over Δt); the difference's exponential mean over ``imu_window_s``
    is each IMU's rate error.  With two or more IMUs, one is named when its error exceeds ``imu_rate_tolerance_dps`` and every
    other's is below half of it (a common-mode difference — the autopilot's own lag in a fast turn — names
    none).

    The streams arrive interleaved as the link delivers them, not in time order: an ATTITUDE may come before
    IMU samples older than it (a bursty link, another stream's queue).  So the samples are bucketed by their
    time, and an interval is judged for an IMU once that IMU has a sample beyond its end (each IMU's samples
    come in their own order); samples of an interval already judged are dropped (counted in ``late``)."""

    _HISTORY_MS = 2000.0  # attitudes (and an IMU's samples) kept waiting at most this long
    _MAX_GAP_MS = 250.0  # an interval longer than this (a gap, a reboot) is not judged

    def __init__(self, s: MonitorSettings) -> None:
        self.tol = math.radians(s.imu_rate_tolerance_dps)
        self.tau = s.imu_window_s
        self._att: deque[tuple[float, Sequence[float]]] = deque()  # the autopilot's attitudes (t_ms, q), in time order
        self._tracks: dict[str, _ImuTrack] = {}
        self._err: dict[str, list[float]] = {}  # name → [ex, ey, ez, seconds]
        self.late = 0  # samples that came after their interval was judged

    def gyro(self, name: str, t_ms: float, g: Sequence[float]) -> None:
        x, y, z = g
        if x - x != 0.0 or y - y != 0.0 or z - z != 0.0 or t_ms - t_ms != 0.0:  # NaN or ±inf (cheaper than isfinite)
            return
        tr = self._tracks.get(name)
        if tr is None:
            tr = self._tracks[name] = _ImuTrack()
        if t_ms <= tr.closed_ms:
            self.late += 1
            return
        tr.pending.append((t_ms, x, y, z))
        if t_ms > tr.newest_ms:
            tr.newest_ms = t_ms
            if tr.pending[0][0] < t_ms - 2.0 * self._HISTORY_MS:  # no attitude for a while: forget what cannot
                tr.pending = [p for p in tr.pending if p[0] >= t_ms - self._HISTORY_MS]  # be judged (in chunks)
            self._judge(name, tr)

    def compare(self, t: float, q: Sequence[float]) -> None:
        att = self._att
        if att and not 0.0 < t - att[-1][0] <= self._MAX_GAP_MS:
            if att[-1][0] - _REBOOT_MS <= t <= att[-1][0]:
                return  # a repeated or reordered attitude: no interval of its own
            att.clear()  # a gap or a reboot: judge again from here
            for tr in self._tracks.values():
                tr.pending = [p for p in tr.pending if t < p[0] <= t + self._HISTORY_MS]
                tr.closed_ms, tr.newest_ms = t, max((p[0] for p in tr.pending), default=-math.inf)
        att.append((t, q))
        if self.tau <= 0.0:
            return
        for name, tr in self._tracks.items():
            self._judge(name, tr)
        while len(att) > 2 and att[1][0] < t - self._HISTORY_MS:  # an IMU that stopped does not hold them
            att.popleft()
            start = att[0][0]
            for tr in self._tracks.values():
                if tr.closed_ms < start:
                    tr.closed_ms = start
                    tr.pending = [p for p in tr.pending if p[0] > start]

    def _judge(self, name: str, tr: _ImuTrack) -> None:
        """Judge every interval of ``tr`` whose end is known and that its samples have passed."""
        att = self._att
        if len(att) < 2 or self.tau <= 0.0:
            return
        i = len(att) - 1  # the interval after the last judged one (usually the newest but one)
        while i > 0 and att[i][0] > tr.closed_ms:
            i -= 1
        while i + 1 < len(att) and tr.newest_ms > att[i + 1][0]:
            (t0, a), (t1, b) = att[i], att[i + 1]
            i += 1
            n = sx = sy = sz = 0.0
            keep: list[tuple[float, float, float, float]] = []
            for p in tr.pending:
                if p[0] <= t1:
                    if p[0] > t0:
                        n += 1.0
                        sx += p[1]
                        sy += p[2]
                        sz += p[3]
                else:
                    keep.append(p)
            tr.pending = keep
            tr.closed_ms = t1
            if n:
                self._update(name, 1e-3 * (t1 - t0), a, b, (sx / n, sy / n, sz / n))

    def _update(self, name: str, dt: float, a: Sequence[float], b: Sequence[float], mean: Sequence[float]) -> None:
        # q_rel = a* ⊗ b (the body's turn over dt, body axes)
        w = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
        x = a[0] * b[1] - a[1] * b[0] - a[2] * b[3] + a[3] * b[2]
        y = a[0] * b[2] + a[1] * b[3] - a[2] * b[0] - a[3] * b[1]
        z = a[0] * b[3] - a[1] * b[2] + a[2] * b[1] - a[3] * b[0]
        # the rotation vector, not its small-angle 2·vec: a 10 Hz ATTITUDE in a 400 °/s spin turns 40° per interval
        n = math.sqrt(x * x + y * y + z * z)
        k = (2.0 * math.atan2(n, abs(w)) / n if n > 1e-12 else 2.0) * (1.0 if w >= 0.0 else -1.0) / dt
        rate = (k * x, k * y, k * z)
        e = self._err.get(name)
        if e is None:
            e = self._err[name] = [0.0, 0.0, 0.0, 0.0]
        e[3] += dt
        f = dt / min(e[3], self.tau)
        for i in range(3):
            e[i] += f * (mean[i] - rate[i] - e[i])

    def errors_dps(self) -> dict[str, float]:
        """Each IMU's rate error learnt so far, deg/s (those seen for half a window)."""
        return {k: math.degrees(math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]))
                for k, e in self._err.items() if e[3] >= 0.5 * self.tau}  # fmt: skip

    def named(self, current: str = "") -> tuple[str, float]:
        """The IMU that is off and its rate error (deg/s), ("", NaN) for none; ``current``: the one named
        before, kept while its error stays above half the tolerance (hysteresis)."""
        err = self.errors_dps()
        if len(err) < 2:
            return "", math.nan
        if current in err and math.radians(err[current]) > 0.5 * self.tol:
            return current, err[current]
        worst = max(err, key=lambda k: err[k])
        top = err[worst]
        if math.radians(top) > self.tol and all(v < 0.5 * top for k, v in err.items() if k != worst):
            return worst, top
        return "", math.nan


def _rotate_ne(q: Sequence[float], v: Sequence[float]) -> tuple[float, float]:
    """North and east components of q ⊗ v ⊗ q* (body → NED)."""
    w, x, y, z = q
    n = (1 - 2 * (y * y + z * z)) * v[0] + 2 * (x * y - w * z) * v[1] + 2 * (x * z + w * y) * v[2]
    e = 2 * (x * y + w * z) * v[0] + (1 - 2 * (x * x + z * z)) * v[1] + 2 * (y * z - w * x) * v[2]
    return n, e


def _rotate_d(q: Sequence[float], v: Sequence[float]) -> float:
    """Down component of q ⊗ v ⊗ q*."""
    w, x, y, z = q
    return 2 * (x * z - w * y) * v[0] + 2 * (y * z + w * x) * v[1] + (1 - 2 * (x * x + y * y)) * v[2]


def _statustext(severity: int, text: str) -> Any:
    return mavlink.MAVLink_statustext_message(severity, text.encode()[:_STATUSTEXT_MAX], 0, 0)


# --------------------------------------------------------------------------- arrays (replay)


def divergence_series(
    t_ms: ArrayLike,
    q_est: ArrayLike,
    t_att_ms: ArrayLike,
    q_autopilot: ArrayLike,
    *,
    tolerance_ms: float = 50.0,
) -> tuple[Array, Array]:
    """Tilt and heading divergence (deg) at each autopilot sample time.

    Args:
        t_ms: (N,) increasing times of our estimates, ms (autopilot boot clock).
        q_est: (N, 4) our ``q_body_to_ned`` (as published: true north).
        t_att_ms: (M,) times of the autopilot's attitudes, ms.
        q_autopilot: (M, 4) the autopilot's attitudes (see
            :func:`mavahrs.geometry.rotation.from_euler_rad` for ATTITUDE).
        tolerance_ms: as :attr:`MonitorSettings.align_tolerance_ms`.

    Returns:
        ``(tilt_deg, heading_deg)``, each (M,); NaN where no estimate of ours
        lies close enough.  Heading is signed (ours minus the autopilot's).
    """
    q_aligned = align_attitudes(t_ms, q_est, t_att_ms, tolerance_ms=tolerance_ms)
    qa = np.asarray(q_autopilot, dtype=np.float64).reshape(-1, 4)
    a = q_aligned / np.linalg.norm(q_aligned, axis=1, keepdims=True)
    b = qa / np.linalg.norm(qa, axis=1, keepdims=True)
    w = np.sum(a * b, axis=1)
    z = -a[:, 0] * b[:, 3] - a[:, 1] * b[:, 2] + a[:, 2] * b[:, 1] + a[:, 3] * b[:, 0]
    sign = np.where(w < 0.0, -1.0, 1.0)
    w, z = w * sign, z * sign
    tilt = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    heading = 2.0 * np.arctan2(z, w)
    return np.degrees(tilt), np.degrees(heading)


def align_attitudes(t_ms: ArrayLike, q: ArrayLike, t_query_ms: ArrayLike, *, tolerance_ms: float = 50.0) -> Array:
    """Attitudes ``q`` sampled at ``t_ms`` (increasing), evaluated at ``t_query_ms``.

    Interpolated (slerp) between the two samples around each query time when
    they are at most ``2·tolerance_ms`` apart, else the nearest sample within
    ``tolerance_ms``, else NaN — the alignment rule of :class:`AttitudeMonitor`.
    Returns (M, 4).
    """
    t = np.asarray(t_ms, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    ta = np.asarray(t_query_ms, dtype=np.float64)
    m = len(ta)
    q_aligned = np.full((m, 4), np.nan)
    if len(t):
        hi = np.searchsorted(t, ta, side="left")  # first sample at or after the query
        lo = hi - 1
        hi_c = np.clip(hi, 0, len(t) - 1)
        lo_c = np.clip(lo, 0, len(t) - 1)
        has_hi = hi < len(t)
        has_lo = lo >= 0
        exact = has_hi & (t[hi_c] == ta)
        bracket = has_hi & has_lo & ~exact & (t[hi_c] - t[lo_c] <= 2.0 * tolerance_ms)
        if np.any(bracket):
            f = (ta[bracket] - t[lo_c[bracket]]) / (t[hi_c[bracket]] - t[lo_c[bracket]])
            q_aligned[bracket] = slerp(q[lo_c[bracket]], q[hi_c[bracket]], f)
        d_lo = np.where(has_lo, ta - t[lo_c], np.inf)
        d_hi = np.where(has_hi, t[hi_c] - ta, np.inf)
        rest = ~bracket
        use_lo = rest & ~exact & (d_lo <= d_hi) & (d_lo <= tolerance_ms)
        use_hi = rest & (exact | ((d_hi < d_lo) & (d_hi <= tolerance_ms)))
        q_aligned[use_lo] = q[lo_c[use_lo]]
        q_aligned[use_hi] = q[hi_c[use_hi]]
    return q_aligned


@dataclass(frozen=True)
class MonitorEvent:
    """A STATUSTEXT the monitor raised: autopilot time (ms), severity, text, the flight's phase then."""

    t_ms: float
    severity: int
    text: str
    phase: str = ""
    evidence: Evidence | None = None
    #: the disagreement already raised, said again with new evidence (not a new warning)
    update: bool = False

    @property
    def cause(self) -> str:
        """The short evidence (:attr:`Evidence.cause`), "" for none."""
        return self.evidence.cause if self.evidence is not None else ""

    @property
    def in_flight(self) -> bool:
        """A disagreement raised in flight (WARNING), not on the ground, at take-off or touchdown."""
        return self.severity == mavlink.MAV_SEVERITY_WARNING and not self.update


@dataclass(frozen=True)
class MonitorSensors:
    """The samples behind our estimates, for the evidence in :func:`monitor_series` (one row per estimate).

    Attributes:
        accel_body_m_s2: (N, 3) specific force, body axes.
        mag_body_ut: (N, 3) the calibrated magnetic field, body axes (NaN rows: none), or None.
        vel_ne_m_s: (N, 2) the GNSS velocity north and east (true north; NaN: no fix), or None.
        vel_t_ms: (N,) when that velocity was fixed, ms (boot clock).
        mag_reference: ``(t_ms, strength µT, inclination rad)``: the expected field from then on.
    """

    accel_body_m_s2: ArrayLike
    mag_body_ut: ArrayLike | None = None
    vel_ne_m_s: ArrayLike | None = None
    vel_t_ms: ArrayLike | None = None
    mag_reference: Sequence[tuple[float, float, float]] = ()
    #: every IMU's gyro, ``(name, t_ms (K,), gyro_rad_s (K, 3))`` (``IMU1`` …), to name one that is off
    imus: Sequence[tuple[str, ArrayLike, ArrayLike]] = ()


@dataclass(frozen=True)
class MonitorSeries:
    """:func:`monitor_series` result: per autopilot sample divergence and the events."""

    t_ms: Array
    tilt_deg: Array
    heading_deg: Array
    events: tuple[MonitorEvent, ...]
    #: the thresholds in force at each comparison, deg (NaN: none made then; heading 0 = not judged)
    tilt_threshold_deg: Array | None = None
    heading_threshold_deg: Array | None = None
    #: comparisons made, and of them those not judged: our IMU input slower than ``min_imu_rate_hz``
    comparisons: int = 0
    held_comparisons: int = 0

    def held_note(self, settings: MonitorSettings | None = None) -> str:
        """E.g. ``not judged: 100 % of the comparisons (our IMU input below 50 Hz)``; "" when every comparison
        was judged, or fewer than 1 % were not (a log starting with a logger dropout: the rate from its first
        interval or two; PX4's sample.ulg, 2 of 3441) — ``held_comparisons`` keeps the count."""
        share = 100.0 * self.held_comparisons / max(self.comparisons, 1)
        if share < 1.0:
            return ""
        floor = (settings if settings is not None else MonitorSettings()).min_imu_rate_hz
        return f"not judged: {share:.0f} % of the comparisons (our IMU input below {floor:g} Hz)"


def monitor_series(
    t_ms: ArrayLike,
    q_est: ArrayLike,
    t_att_ms: ArrayLike,
    q_autopilot: ArrayLike,
    settings: MonitorSettings | None = None,
    *,
    heading_valid: bool = True,
    tilt_sigma_rad: ArrayLike | None = None,
    heading_sigma_rad: ArrayLike | None = None,
    phase_events: Sequence[tuple[float, str, float]] = (),
    sensors: MonitorSensors | None = None,
    imu_rate_hz: ArrayLike | None = None,
) -> MonitorSeries:
    """Run :class:`AttitudeMonitor` over whole arrays (replay): which warnings, when.

    Inputs as :func:`divergence_series`; samples are merged in time order, our
    estimate first on equal times.  The divergence columns come from
    :func:`divergence_series` (NaN where unmatched).  ``tilt_sigma_rad``: (N,)
    our 1-σ tilt per estimate (NaN: not velocity-aided; see
    :meth:`AttitudeMonitor.add_estimate`), ``heading_sigma_rad`` its heading's (None / NaN:
    ``heading_sigma_deg``); ``phase_events``: the flight's phase
    (:func:`phase_events_of_arrays`), applied in time order; ``sensors``: the
    samples behind the estimates, for the evidence of who is wrong
    (:attr:`MonitorEvent.evidence`; without them only our confidence);
    ``imu_rate_hz``: (N,) IMU samples per second reaching our filter around each
    estimate (:func:`input_rate_hz`; None: not known, every comparison judged).
    """
    s = settings if settings is not None else MonitorSettings()
    mon = AttitudeMonitor(s)
    mon.heading_valid = heading_valid
    sig = np.full(len(np.asarray(t_ms)), np.nan) if tilt_sigma_rad is None else np.asarray(tilt_sigma_rad, float)
    sig_h = np.full(len(sig), np.nan) if heading_sigma_rad is None else np.asarray(heading_sigma_rad, float)
    rate = np.full(len(sig), np.nan) if imu_rate_hz is None else np.asarray(imu_rate_hz, float)
    ph = mon.phase
    k, n_ph = 0, len(phase_events)

    def phase_until(t: float) -> None:
        nonlocal k
        while k < n_ph and phase_events[k][0] <= t:
            ph.on_event(*phase_events[k])
            k += 1

    t = np.asarray(t_ms, dtype=np.float64)
    q = np.asarray(q_est, dtype=np.float64).reshape(-1, 4)
    ta = np.asarray(t_att_ms, dtype=np.float64)
    qa = np.asarray(q_autopilot, dtype=np.float64).reshape(-1, 4)
    events: list[MonitorEvent] = []
    i = j = 0
    n, m = len(t), len(ta)
    acc = mag = vel = vt = None
    refs: list[tuple[float, float, float]] = []
    if sensors is not None:
        acc = np.asarray(sensors.accel_body_m_s2, float).reshape(-1, 3).tolist()
        mag = None if sensors.mag_body_ut is None else np.asarray(sensors.mag_body_ut, float).reshape(-1, 3).tolist()
        if sensors.vel_ne_m_s is not None and sensors.vel_t_ms is not None:
            vel = np.asarray(sensors.vel_ne_m_s, float).reshape(-1, 2).tolist()
            vt = np.asarray(sensors.vel_t_ms, float).tolist()
        refs = sorted(sensors.mag_reference)
    imus = [] if sensors is None else [
        (name, np.asarray(ti, float), np.asarray(g, float).reshape(-1, 3).tolist()) for name, ti, g in sensors.imus]
    imu_at = [0] * len(imus)

    def imus_until(t_now: float) -> None:
        for k, (name, ti, g) in enumerate(imus):
            a = imu_at[k]
            b = int(np.searchsorted(ti, t_now, side="right"))
            for x in range(a, b):
                mon.add_imu_gyro(name, ti[x], g[x])
            imu_at[k] = b

    r = 0
    thr_t: list[float] = []
    thr_v: list[tuple[float, float]] = []
    before = 0
    while i < n or j < m:
        if j >= m or (i < n and t[i] <= ta[j]):
            if n_ph:
                phase_until(t[i])
            if acc is not None:
                while r < len(refs) and refs[r][0] <= t[i]:
                    mon.set_mag_reference(refs[r][1], refs[r][2])
                    r += 1
                mon.add_sensors(t[i], acc[i], None if mag is None else mag[i], None if vel is None else vel[i],
                                math.nan if vt is None else vt[i])
            out = mon.add_estimate(t[i], q[i], sig[i], sig_h[i], rate[i])
            i += 1
        else:
            if n_ph:
                phase_until(ta[j])
            if imus:
                imus_until(ta[j])
            out = mon.add_autopilot(ta[j], qa[j])
            j += 1
        if mon._comparisons != before:
            thr_t.append(mon._last_cmp_ms or 0.0)
            thr_v.append((mon._tilt_thr_now, mon._hdg_thr_now))
            before = mon._comparisons
        for msg in out:
            phase = mon.last_phase if int(msg.severity) != mavlink.MAV_SEVERITY_INFO else ""
            info = int(msg.severity) == mavlink.MAV_SEVERITY_INFO
            ev = mon.last_evidence if not info else None
            events.append(MonitorEvent(mon.last_comparison_ms, int(msg.severity), _text(msg), phase, ev,
                                       mon.last_update and not info))
    tilt, heading = divergence_series(t, q, ta, qa, tolerance_ms=s.align_tolerance_ms)
    thr = np.full((len(ta), 2), np.nan)
    if thr_t:  # the thresholds at the comparisons, onto the autopilot's sample times (most are one-to-one)
        k_at = np.searchsorted(ta, np.asarray(thr_t), side="left").clip(0, max(len(ta) - 1, 0))
        thr[k_at] = np.degrees(np.asarray(thr_v))
    return MonitorSeries(ta, tilt, heading, tuple(events), thr[:, 0], thr[:, 1], mon._comparisons,
                         mon.held_comparisons)


def input_rate_hz(t_us: ArrayLike, rows: ArrayLike, window_s: float = 2.0) -> np.ndarray:
    """IMU samples per second reaching the filter at each of ``rows`` (indices into ``t_us``, the filtered
    samples' times, µs): those within the last ``window_s`` (the daemon's
    :class:`~mavahrs.service.stats.RateMeter` window) over that span; in the first ``window_s``, the intervals
    since the first sample over their span (at the first, its first interval's; NaN for a lone sample).  Where the times go back (an autopilot's reboot)
    the count starts again.  For :func:`monitor_series`'s ``imu_rate_hz``."""
    t = np.asarray(t_us, dtype=np.float64)
    k = np.asarray(rows, dtype=np.int64)
    if not k.size:
        return np.zeros(0)
    back = np.zeros(t.shape[0], np.int64)
    back[1:] = t[1:] < t[:-1]
    run = np.cumsum(back)
    starts = np.flatnonzero(np.diff(run, prepend=-1) > 0)  # first sample of each run
    first = starts[run[k]]
    t_run = t + run * 1e15  # rising over the runs, each far from the others
    lo = np.maximum(np.searchsorted(t_run, t_run[k] - window_s * 1e6, side="right"), first)
    full = t[k] - t[first] >= window_s * 1e6
    span_s = np.where(full, window_s, (t[k] - t[first]) * 1e-6)
    count = np.where(full, k - lo + 1, k - first)
    nxt = np.minimum(first + 1, t.shape[0] - 1)  # at a run's first sample: its first interval
    first_dt_s = np.where((nxt > first) & (run[nxt] == run[first]), (t[nxt] - t[first]) * 1e-6, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        at_first = np.where(first_dt_s > 0, 1.0 / first_dt_s, np.nan)
        return np.where(span_s > 0, count / span_s, at_first)


def _text(msg: Any) -> str:
    text = msg.text
    return text.decode(errors="replace") if isinstance(text, bytes) else str(text)
