r"""The configuration mavahrs recommends: ``filter="best"`` (also the daemon's default filter).

``best`` is one estimator in every condition: the error-state Kalman filter of
:mod:`mavahrs.filters.eskf` (attitude, NED velocity and gyro bias as states).  What changes
with the inputs is only which measurements it has, and the measurement model of the
accelerometer is chosen by what is known of the source, never by a separately tuned fallback:

* **with GNSS velocity** — every fix is compared with the velocity integrated from the
  specific force at the fix's own time; the tilt, the gyro bias and, while the vehicle
  accelerates, the heading follow through their covariance (ArduCopter SITL 0.22° mean
  inclination RMS, EKF3 0.15–0.26°; ``scripts/bench_estimator.py``);
* **without, nothing known of the source** (the Python API's default: a hand-held sensor, a
  research rig's raw IMU, an indoor flight) — the gravity measurement is the specific force
  low-passed for 2 s in the estimated NED frame (VQF's quasi-inertial low-pass, Laidig & Seel
  2023, as the ESKF's measurement): short accelerations and rotor vibration average out, so
  the gyro bias is learnt in motion through the tilt it causes; every magnetometer reading up
  to 100 Hz, heading only (:func:`best_eskf_settings`); beside it runs the multirotor
  hypothesis (:func:`multirotor_eskf_settings`, what :meth:`Best.set_multirotor` sets), and its
  attitude is the output once the likelihood ratio of the two hypotheses' predictions of the
  specific force across the thrust axis says "multirotor" (:class:`MultirotorDetectSettings`;
  firmware_sim raw ``aggressive`` 7.0 → 1.1°, the vibrating SITL set 5.01 → 1.29°, no BROAD or
  RepoIMU TStick trial switched);
* **without, on an autopilot's stream** (the pipeline calls :meth:`Best.set_vehicle_stream`) —
  a vehicle's accelerations last the whole manoeuvre, which a 2 s low-pass would carry: the
  specific force averaged over 0.1 s in NED (an autopilot-filtered stream's sample; a raw
  IMU's rotor vibration averaged out) is the gravity measurement, trusted within 5 % of g,
  with a weak zero-mean-velocity pseudo-measurement, as autopilot EKFs fuse without GNSS
  (:func:`vehicle_eskf_settings`; :meth:`Best.set_multirotor` through the API);
* **and on a multirotor** (its HEARTBEAT type, or :meth:`Best.set_multirotor` through the
  API) — the rotor-drag measurement besides (Leishman et al. 2014): the specific force across
  the thrust axis is −k × the body-frame velocity, which makes the velocity, hence the tilt,
  observable through sustained manoeuvres (ArduCopter SITL without GNSS 0.63°).

Measured with one setting for all data (``scripts/bench_estimator.py``, ``docs/accuracy.md``),
inclination RMS, degrees:

=========================================  ==============  ==================  ========
data                                       ``best``        ``best`` before     VQF 2.x
=========================================  ==============  ==================  ========
BROAD 9-axis (16 trials): incl. / heading  0.66 / 1.66     0.705 / 1.69        0.71 / 2.30
BROAD 6-axis                               0.655           0.704               0.71
BROAD as a raw IMU (1–5 °/s bias, no rest)  1.09            1.98                4.85
SITL raw, 200 Hz, vibration, plain API      1.29            5.01                11.67
the same, ``set_multirotor()``              1.24            2.25; 23.8          –
ArduCopter SITL with GNSS / without         0.22 / 0.63     (unchanged)         8.2
=========================================  ==============  ==================  ========

The Madgwick configuration that ``best`` ran through the API without GNSS until 2026-12
(:func:`best_settings`: β = 0.01, the accelerometer low-passed in the quasi-inertial frame,
heading-only magnetometer, tuned on BROAD) stays selectable as
``BestSettings(unaided_filter="madgwick")`` for comparison, and runs beside the ESKF for one
job: after a restart in a manoeuvre (a link outage) its first GNSS v̇ re-aligns it by TRIAD,
and the ESKF restarts its aiding from that attitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mavahrs.filters.base import (
    P_FILTER,
    S_BIAS,
    S_FILTER,
    S_INIT,
    S_Q,
    AttitudeFilter,
    FilterSettings,
    FilterState,
)
from mavahrs.filters.eskf import (
    COVARIANCE_STATE,
    DRAG_PARAM,
    DRAG_QUADRATIC_PARAM,
    ERROR_STATE_LEN,
    GRAVITY_LOWPASS_STATE,
    MAG_MODEL_STATE,
    MEASURED_NOISE_STATE,
    MULTIROTOR_AXIS_SIGMA_RAD,
    MULTIROTOR_DRAG_1_S,
    START_DONE_STATE,
    THRUST_AXIS_REF_STATE,
    THRUST_AXIS_STATE,
    VELOCITY_STATE,
    Eskf,
    EskfSettings,
    axis_basis,
    declination_of,
    eskf_aided,
    heading_walk_of,
    mag_delay_of,
    mag_noise_of,
    thrust_axis_of,
)
from mavahrs.filters.eskf import DELAY_PARAM as _DELAY_OFFSET
from mavahrs.filters.eskf import step as _eskf_step
from mavahrs.filters.gains import G_M_S2
from mavahrs.filters.gnss import gnss_compensation_fresh
from mavahrs.filters.jit import kernel
from mavahrs.filters.layout import IN_ACCEL, IN_DT, IN_VEL, IN_VEL_AGE, IN_WIDTH, OUT_BIAS, OUT_Q, OUT_WIDTH
from mavahrs.filters.madgwick import FM_GNSS, PM_GNSS, Madgwick, MadgwickSettings
from mavahrs.filters.madgwick import step as _madgwick_step
from mavahrs.filters.magfield import MF_LEN, export_model, import_model, mag_model_summary, mag_status
from mavahrs.filters.rest import RestBiasSettings

__all__ = ["best_settings", "best_eskf_settings", "vehicle_eskf_settings", "multirotor_eskf_settings",
           "MultirotorDetectSettings", "BestSettings", "Best", "create_best", "BEST_FILTER"]

#: the registry name of the filter ``"best"`` uses without GNSS velocity
BEST_FILTER = "madgwick"
#: a vehicle's gravity measurement: the specific force averaged over 0.1 s in NED (the drag measurement's
#: period), not the single sample, so that a raw IMU's rotor vibration does not fail its 5 % norm gate
VEHICLE_GRAVITY_LOWPASS_S = 0.1
#: a vehicle's gyro-bias random walk while velocity-aided, rad/s per √s (``EskfSettings.bias_walk_aided_rad_s2``;
#: the ESKF's default walk 5e-5 stays without GNSS): an autopilot's gyro drifts in flight (ArduPilot SITL's
#: SIM_DRIFT_SPEED ramps it ≈ 0.001 °/s per second on every axis; a real MEMS gyro with temperature), and a ramp the
#: bias state cannot follow is a steady tilt error in hover and after landing (ArduCopter SITL .BIN: 0.22° in roll
#: and pitch from 215 s to the end, EKF3 0.14°; EKF3's EK3_GBIAS_P_NSE is 1e-3).  ArduCopter SITL onboard .BIN
#: 0.216 → 0.146° inclination (EKF3 0.170°), the five shared tlogs 0.08–0.26 → 0.08–0.21°; 2e-4 gave 0.117° and
#: 1.5e-4 0.124° on the .BIN but cost more where the drift is small: PX4 SITL's ULog 0.98 → 1.02° (1e-4: 0.99°),
#: the onboard tlog with the receiver's velocity 0.38 → 0.42° (1e-4: 0.38°), the magnetic flight's heading
#: 0.54 → 0.61° (1e-4: 0.57°); docs/accuracy.md
VEHICLE_BIAS_WALK_RAD_S2 = 1e-4
#: on an autopilot's stream, the largest attitude correction one ESKF measurement update may make, rad
#: (``EskfSettings.max_attitude_step_rad``; :meth:`Best.set_vehicle_stream`), for ``VEHICLE_MAX_ATTITUDE_STEP_WINDOW_S``
#: after the attitude covariance was re-opened: after a ground station's slow IMU stream a freshly re-opened
#: covariance read velocity residuals as 47–80° of tilt in one fix (firmware_sim ``aggressive`` 3 after 30 s at 4 Hz:
#: 60.6° inclination RMS over 2–20 s after the rate returned → 7.0°, its worst 171.8° → 26.3°; docs/accuracy.md "One
#: update that moves the attitude far").  Not on a raw IMU through the API (bounded at every update, BROAD as a raw IMU
#: 1.10 → 1.73°: its start corrections are large and right)
VEHICLE_MAX_ATTITUDE_STEP_RAD = 0.1
#: s: … only this long after a re-opening (at every update: chosen flights better, but single held-out flights worse)
VEHICLE_MAX_ATTITUDE_STEP_WINDOW_S = 5.0
#: a vehicle's compass delay (behind the IMU's attitude) is learnt from its readings over this long, s
#: (``EskfSettings.mag_learn_tau_s``): ArduCopter SITL's readings (RAW_IMU and DataFlash), rotated with the
#: simulator's true attitude, point the field's azimuth within 0.11–0.23° (1 σ) when taken 0.05 s before their
#: stamps, 2.4–3.2° at 0 or 0.1 s (five tlogs and the .BIN, 0.05 s on every one); PX4 SITL's 0.03 s (3.3°);
#: firmware_sim's 0 s (0.75°): no one delay fits every autopilot.  Heading RMS, shared SITL: 400 Hz 0.69 → 0.73,
#: aggressive 0.60 → 0.50, gentle 0.25 → 0.12, magnetic 0.45 → 0.33, onboard 0.78 → 0.73, .BIN 0.66 → 0.61,
#: PX4 1.15 → 1.13; firmware_sim unchanged within 0.03; docs/accuracy.md
VEHICLE_MAG_LEARN_TAU_S = 20.0
#: a vehicle's compass noise per reading is learnt from its own heading innovations over this long, s
#: (``EskfSettings.mag_noise_tau_s``; still at most 10 readings/s): PX4 SITL's readings scatter 2.9–3.3° about
#: the truth, learnt 3.0–3.5° (σ 5° fixed before); ArduCopter SITL's 0.1–0.2°, learnt down to the 1° floor.
#: PX4 SITL tlog heading 1.11 → 1.11° (hover 220–250 s 1.61 → 1.31°), its ULog 1.41 → 1.29° (hover 1.82 →
#: 1.45°); ArduCopter SITL 400 Hz 0.56 → 0.54, onboard 0.52 → 0.47, others within 0.01.  Every reading
#: (PX4's 14/s; ``mag_rate_hz`` 20) took the PX4 hover to 1.10° but ArduCopter's gentle flight 0.12 → 0.16° and
#: the magnetic one with the receiver's velocity 0.30 → 0.46°: ArduPilot's compass errors beyond 10 Hz are not
#: independent in a way the learnt lag-2 correlation did not show; docs/accuracy.md ("PX4 calm-segment heading")
VEHICLE_MAG_NOISE_TAU_S = 30.0
#: a vehicle's heading process noise is raised to what its compass's heading innovations show (``EskfSettings.
#: heading_walk_tau_s``, covariance matching over 2 s windows; τ, s): PX4 SIH's HIGHRES_IMU (EKF2's moving bias
#: subtracted) tlog heading 1.10 → 1.07° (hover 220–250 s 1.31 → 1.07°), its ULog 1.29 → 1.26° (hover 1.43 → 1.19°);
#: ArduCopter SITL, the magnetic flights and firmware_sim within 0.004°.  τ 30 / 10 / 5 s: hover 1.28 / 1.19 /
#: 1.12° (windows of 3 / 1 / 2 s); docs/accuracy.md ("PX4 calm heading, round four")
VEHICLE_HEADING_WALK_TAU_S = 3.0
#: the drag measurement's noise, m/s², with the thrust axis as states (a raw IMU declared a multirotor): the
#: default 0.5 (EK3_DRAG_M_NSE) also covered a learnt axis's error, which is now a state (raw SITL set
#: declared a multirotor 1.11 → 1.00°, vibrating 1.47 → 1.24°; 0.8: 1.28 / 1.66°; docs/accuracy.md)
AXIS_STATES_DRAG_NOISE_M_S2 = 0.35
#: nothing known of the source: a raw MEMS gyro's bias is up to ≈ 5 °/s per axis (issue 22; the rest detector's
#: rate limit is 6 °/s too), so the bias estimate is held within 6 °/s (the ESKF's default 10 °/s let an undeclared
#: multirotor's sustained thrust tilt, taken for gravity by the 2 s low-pass, be learnt as 9–10 °/s of bias):
#: firmware_sim's raw ``aggressive`` flights through the plain API, seeds 1–6, 15.9 → 11.0° mean (VQF 11.9°), BROAD
#: unchanged; a vehicle's stream keeps the ESKF's default (docs/accuracy.md)
BEST_BIAS_LIMIT_RAD_S = math.radians(6.0)
#: the plain path's gyro scale-factor states, prior 1-σ per axis (``EskfSettings.gyro_scale_state_sigma``): a
#: factory-calibrated MEMS gyro's residual scale error; BROAD's hand-held IMU reads 0.2–0.5 % low on its axes
#: in the rotation trials (its integrated error in a 1000 °/s rotation is what the tilt shows), and the
#: gravity measurement, low-passed 2 s, sees it lagged (the states' h is g·(J − LP[J]), J = ∫ C diag(ω) dt).
#: BROAD development trials (alternate ones of the 16): inclination 0.730 → 0.640°; 0.5 % / 1 %: 0.649 /
#: 0.672° with heading 1.88 / 2.19° (1.80° without); docs/accuracy.md "Gyro scale-factor states".  A vehicle's
#: stream keeps them off (``vehicle_eskf_settings``).  OFF on the plain path too (0): before the multirotor detection
#: switches, the generic hypothesis learns an undeclared multirotor's slow thrust tilt as scale — the vibrating
#: SITL set through the plain API 1.29 → 1.43°, firmware_sim raw ``vibration`` 7.30 → 7.55° (seed 4 no longer
#: better than VQF), against BROAD 0.66 → 0.61° whose check half gained only 0.011°.  Set 0.0025 (0.25 %) in
#: ``EskfSettings.gyro_scale_state_sigma`` for a hand-held IMU
BEST_GYRO_SCALE_SIGMA = 0.0
#: the plain path's body-offset learner's pair interval, s (``EskfSettings.mag_body_offset_lag_s``; 0 = off): while
#: the schedule rejects the compass, a body-fixed offset (a magnet on the sensor) is fitted from turns and the
#: reading less it used again.  BROAD attached-magnet trials 1.73 → 1.02° heading (docs/accuracy.md round three, bmag2); off on
#: an autopilot's stream (:func:`vehicle_eskf_settings`, whose magnetometer model learns the vehicle's own field)
BEST_MAG_BODY_OFFSET_LAG_S = 0.5
#: the plain path's compass reading that the gain schedule rejects (dip test) with its norm in tolerance is fused at
#: σ × this (``EskfSettings.mag_rejected_sigma_scale``; 0 = not fused): in fast turns a raw IMU's compass fails the
#: dip test (BROAD's is ≈ 10 ms late) while the gyro's heading drifts 0.2–0.3 °/s.  Chosen on BROAD trials 01 04 08
#: 11 15 24 28 32 (1.646 → 1.195°; 3 / 4 / 7: 1.242 / 1.203 / 1.251), confirmed on 02 06 10 14 18 26 30 34
#: (1.508 → 1.441°; trial 06 1.76 → 3.35° worse); all 16 1.58 → 1.32°, stationary magnet 1.92 → 1.48°,
#: attached 1.02 → 0.97°; off on an autopilot's stream (docs/accuracy.md round five, smag3)
BEST_MAG_REJECTED_SIGMA_SCALE = 5.0
#: the start checked against the specific force averaged over this long in the estimate's frame, s, and the tilt
#: re-aligned to it when more than 30° apart (``EskfSettings.initial_average_s``; every path of ``best``; the plain
#: path's gravity low-pass τ): firmware_sim's ``vibration`` flights declared a multirotor started 61–118° off from
#: the first sample and diverged, seeds 1–6 31.7 → 6.7° mean; nothing else measured changed (docs/accuracy.md)
BEST_INITIAL_AVERAGE_S = 2.0
#: the multirotor hypothesis's re-alignment at the end of its start window only beyond this, rad
#: (``EskfSettings.initial_realign_rad``, 30° elsewhere; ``multirotor_eskf_settings``): a multirotor accelerates
#: through whole manoeuvres at its tilt, so the 2 s window's mean specific force is off the vertical by up to that
#: tilt — 34° on firmware_sim raw ``aggressive`` seed 13 while the estimate was 8° off: the re-alignment put it 34°
#: off and its thrust axis settled 42° off (6.0° RMS; 1.7° without the re-alignment) — while a vibrating raw IMU's
#: first sample is 60–120° off, still re-aligned (docs/accuracy.md)
MULTIROTOR_INITIAL_REALIGN_RAD = math.radians(45.0)

#: the multirotor hypothesis takes a detected rest only once the bias of at least one axis is known within this
#: (1-σ, rad/s; ``EskfSettings.rest_check_sigma_rad_s``; the detection's own bias gate, ``bias_sigma_rad_s``): a
#: multirotor hovering in a slow turn is as still as rest to the detector, and before its bias is learnt in flight the
#: 3σ check passes the turn — firmware_sim raw ``hover`` seed 5 took a rest at 1.5 s, its bias σ collapsed to
#: 0.03 °/s with 1–2 °/s of error left (declared 5.37°, the plain path stayed generic, 4.29°); with it 0.71° both
#: (the raw SITL set declared unchanged, 1.00°; docs/accuracy.md)
MULTIROTOR_REST_CHECK_SIGMA_RAD_S = math.radians(0.5)


#: a multirotor's *hovering* rest (the rotors running: the accelerometer's vibration RMS about the rest detector's
#: 0.5 s low-pass above ``MULTIROTOR_REST_HOVER_VIBRATION_M_S2``; hardly moving: the INS horizontal speed below
#: ``MULTIROTOR_REST_HOVER_SPEED_M_S``) fuses the rate across the vertical with a per-rest constant wobble of
#: σ ``MULTIROTOR_REST_WOBBLE_SIGMA_RAD_S`` (``EskfSettings.rest_wobble_sigma_rad_s``): its thrust is fixed in the
#: body, so the hover's slow tilting wobble moves nothing the detector sees and was learnt as a horizontal gyro bias
#: (firmware_sim raw ``hover`` 135 3.07 → 1.40°).  A rest with the motors off (landed: 0.017–0.034 m/s² against
#: ≥ 0.048 flying) or in a steady fast dash (estimated 10–17 m/s; ``aggressive``'s still rests, which the
#: ungated noise under-used: 12 of 30 flights worse) keeps the plain update.  Declared, chosen on seeds 100–129,
#: confirmed on 130–189: ``hover`` 1.24 → 1.07 / 0.98 → 0.91°, ``aggressive`` 1.02 → 1.02 / 1.19 → 1.19°
#: (docs/accuracy.md, sixteenth round)
MULTIROTOR_REST_WOBBLE_SIGMA_RAD_S = math.radians(0.3)
MULTIROTOR_REST_HOVER_VIBRATION_M_S2 = 0.04
MULTIROTOR_REST_HOVER_SPEED_M_S = 5.0

#: a vehicle's stream: the accelerometer's bias as three ESKF states while velocity-aided (``EskfSettings.
#: accel_bias_sigma_m_s2``, constant, ``accel_bias_aided_only``), prior 1-σ per axis, m/s²; 0 = off.  OFF: at 0.02
#: firmware_sim (residual bias σ 0.05 m/s² + temperature drift, both autopilots' streams, 21 flights, 7 not looked at
#: while choosing) measured inclination better on 20, mean 0.36 → 0.31°, heading 0.64 → 0.59°, and the real
#: firmware's flights, whose IMU streams carry no bias (ArduCopter SITL, PX4 SIH's HIGHRES_IMU with EKF2's bias
#: removed), level within ±0.03° (0.05 cost PX4's ULog 0.99 → 1.02° inclination, EKF2 1.01) — but the second
#: opinion's correct WARNING on firmware_sim ``aggressive`` 11 at 55.8 s (the simulated autopilot 1.5° off) was no
#: longer raised (tests/service/test_monitor_evidence.py) (docs/accuracy.md, "Accelerometer-bias states (branch
#: accb)").  Branch accv measured 0.02 on the monitor (docs/monitor.md, round sixteen): magnetic 102's false tilt
#: WARNING at 123.0 s and hover 102's at 97.1 s gone, hover 102's at 35.9 s only moved (37.2 s: a hover cannot
#: tell the 0.17 m/s² bias from tilt, our error 0.96 → 0.90°); the 30-flight dev set's latencies all within their
#: criteria, 0 false, estimator gates level (SITL 0.15/0.32, no GNSS 0.64, PX4 0.81/1.03) — but 7 of its 23
#: correct WARNINGs lost (autopilot 1.07–1.75° off; 3 gained, 19), aggressive 2's at 146.6 s among them
VEHICLE_ACCEL_BIAS_SIGMA_M_S2 = 0.0
#: a vehicle's stream: the accelerometer's bias *considered* without states (``EskfSettings.
#: accel_bias_consider_sigma_m_s2``), 1-σ per axis, m/s²; 0 = off.  OFF: at 0.05 (firmware_sim's draw per axis) the
#: estimate is unchanged and the published tilt σ holds our error where a 2–3 σ bias stands in the tilt (firmware_sim
#: hover / magnetic 32, aggressive 11 on the legs after its banks, magnetic / hover 102: none beyond 2σ for 1.5 s,
#: against 2.3–2.6σ), and it removes the monitor's false WARNINGs on hover 32 (96.4 s), magnetic 32 (93.8 s) and
#: magnetic 102 (123.0 s) and warns magnetic 32's 2° step (1.4 s) — but the larger threshold on the legs also takes
#: away the CUSUM our own error had built there, so aggressive 11's correct WARNING (the autopilot 1.4° off) comes at
#: 104.8 s, not 101.0 s, and magnetic 32's false one at 40.2 s (the autopilot 0.80° off) is no longer hidden under a
#: warning that our own 0.83° had raised (docs/monitor.md round twenty-one)
VEHICLE_ACCEL_BIAS_CONSIDER_SIGMA_M_S2 = 0.0


def best_settings() -> MadgwickSettings:
    """The Madgwick configuration ``best`` runs without velocity aiding (a new frozen dataclass).

    Beside the 2 s accelerometer low-pass a 3 s one (VQF's τ) is blended in as far as the
    motion acceleration ā it removes outweighs the rotation rate ω̄ (τ·√(ā/ω̄) with ā/ω̄ in
    m/s² per rad/s, both averaged over 5 s and held at rest) and the manoeuvre weight allows:
    handheld translation is averaged longer, while rotation (whose gyro errors the stored
    average carries) and sustained acceleration keep 2 s.  The manoeuvre weight starts at 3 %
    of g (was 5 %).  BROAD: inclination 0.715 → 0.702° (9-axis; VQF 0.714°), translation
    trials 0.51 → 0.47°; without GNSS, ``firmware_sim`` and ArduCopter SITL flights improve
    too (``docs/accuracy.md``).
    """
    return MadgwickSettings(
        beta_rad_s=0.01,
        zeta_rad_s=0.0005,
        accel_lowpass_s=2.0,
        accel_lowpass_order=2,
        accel_lowpass_adapt_ratio=1.0,
        accel_lowpass_max_s=3.0,
        accel_lowpass_adapt_avg_s=5.0,
        mag_correction="heading",
        beta_heading_rad_s=0.005,
        large_error_tau_s=2.0,
        large_heading_error_tau_s=20.0,
        lowpass_norm_tolerance=0.03,
        lowpass_norm_min_weight=0.2,
        gnss_acceleration=True,
        rest=RestBiasSettings(rate_limit_rad_s=math.radians(1.0)),
    )


def best_eskf_settings() -> EskfSettings:
    """The ESKF ``best`` runs when nothing is known of the source (the Python API's default).

    Without velocity aiding the gravity measurement is the specific force low-passed for 2 s in
    the estimated NED frame (``gravity_lowpass_s``, the quasi-inertial low-pass of VQF, here as
    the ESKF's measurement, σ 0.7 m/s²): the accelerations of a hand-held sensor or an indoor
    flight average out within seconds, and so does a raw IMU's rotor vibration, which the single
    sample's 5 % norm gate rejected on most samples (held-back real multirotor flights: 2.5°
    against 0.86° with the bias removed beforehand).  Every magnetometer reading up to 100 Hz is
    fused at σ 10° (the information rate of 10 Hz at 5°, spread over more readings: a room's
    field errors average out), and the innovation gate is 4σ: a low-passed reference has little
    noise, and a 3σ gate on it refused the corrections that bring a large error back (a state
    90° off: 1.16° RMS 45–60 s later at 3σ, 0.29° at 4σ; at 5σ the 6-axis case learnt a
    wrong bias from them, 1.39°).  Measured (``scripts/bench_estimator.py``, ``docs/accuracy.md``):
    BROAD 9-axis 0.66° inclination / 1.66° heading (the Madgwick configuration 0.705 / 1.69,
    VQF 0.71 / 2.30), 6-axis 0.655°, as a raw IMU (bias, no rest) 1.09° (Madgwick
    configuration 1.98°, VQF 4.85°).  The bias estimate is held within a raw MEMS gyro's range,
    6 °/s (``BEST_BIAS_LIMIT_RAD_S``): an undeclared multirotor's sustained thrust tilt, which the
    2 s low-pass holds as gravity, was learnt as 9–10 °/s of bias (firmware_sim's raw
    ``aggressive`` flights 15.9 → 11.0° mean; BROAD unchanged).  σ 0.7 m/s² rather than 0.5: an
    undeclared multirotor's sustained thrust tilt pulls less on the tilt (firmware_sim raw
    ``aggressive`` 1/2/4/5 12.7 → 8.7° mean, better than VQF on all 20 raw flights measured; the
    vibrating SITL set 5.49 → 5.01°) for BROAD 9-axis heading 1.66 → 1.70° (VQF 2.30°),
    inclination 0.656 → 0.660°, raw 1.09 → 1.10°.  No gyro scale-factor noise here
    (``gyro_scale_sigma`` 0; a vehicle's stream has it, where the monitor reads the heading σ): on
    BROAD it let the magnetometer pull harder in rotation, heading 1.70 → 1.76° (magnet trials
    1.92 / 1.73 → 2.13 / 2.04°, rotation 1.82 → 1.66°).  On an autopilot's stream or a
    declared multirotor :func:`vehicle_eskf_settings` replaces these.  The gyro's scale-factor error states
    (``gyro_scale_state_sigma``) are off here (``BEST_GYRO_SCALE_SIGMA``: at 0.25 % BROAD 9-axis inclination
    0.66 → 0.61°, as a raw IMU 1.10 → 0.87°, but an undeclared vibrating multirotor 1.29 → 1.43°).  ``sensor_delay_s`` is set per stream by the
    pipeline from the autopilot's scaling profile (:meth:`Best.set_sensor_delay`).
    """
    return EskfSettings(
        gravity_lowpass_s=2.0,
        gravity_noise_m_s2=0.7,
        bias_limit_rad_s=BEST_BIAS_LIMIT_RAD_S,
        heading_noise_rad=math.radians(10.0),
        mag_rate_hz=100.0,
        gate_sigma=4.0,
        initial_average_s=BEST_INITIAL_AVERAGE_S,
        gyro_scale_sigma=0.0,
        gyro_scale_tilt_sigma=0.0,
        gyro_scale_state_sigma=BEST_GYRO_SCALE_SIGMA,
        mag_body_offset_lag_s=BEST_MAG_BODY_OFFSET_LAG_S,
        mag_rejected_sigma_scale=BEST_MAG_REJECTED_SIGMA_SCALE,
    )


def vehicle_eskf_settings(eskf: EskfSettings) -> EskfSettings:
    """``eskf`` with the measurement models of a vehicle's stream (:class:`EskfSettings` defaults for them).

    A vehicle's accelerations last for the whole manoeuvre (legs, banked circles), so a 2 s
    low-pass carries them into the gravity measurement: the specific force averaged over 0.1 s
    in NED (``VEHICLE_GRAVITY_LOWPASS_S``; the drag measurement's period), σ 3 m/s² within 5 % of
    g, and for a multirotor the rotor-drag measurement, measure better (ArduCopter SITL without
    GNSS 1.41° without drag, 0.62–0.63° with it, against 8.06° / 3.65–10° with the 2 s low-pass;
    ``docs/accuracy.md``).  The 0.1 s average is the single sample on an autopilot's stream
    (already low-passed: 0.62 → 0.63°), but on a raw IMU it averages the rotor vibration that
    failed the sample's 5 % gate on most samples: the raw SITL flights at 200 Hz with vibration,
    declared a multirotor, 23.8° (one flight diverged, 108°) → 2.25° mean inclination.  The
    magnetometer at most 10 Hz, σ 5° at most, its delay and noise learnt (``VEHICLE_MAG_LEARN_TAU_S``),
    gated at 3σ (an autopilot's compass is read at 10 Hz), the accelerometer's bias as states while
    velocity-aided if ``VEHICLE_ACCEL_BIAS_SIGMA_M_S2`` > 0 (off), and
    the gyro's scale-factor error as the tilt's process noise (``gyro_scale_tilt_sigma``, what the monitor's
    tilt σ needs after a flip), its learnt model (:mod:`mavahrs.filters.magfield`) on unless set either way: ArduCopter's
    motor-interference flight 1.76 → 0.54° heading, the other shared flights within 0.02°.  The output moved back by
    half the step (``output_half_step``: an autopilot's samples are point samples of a low-passed rate, the
    right-rectangle step leads by ½ E[dt²]/E[dt]): SITL 0.16 / 0.34 → 0.15 / 0.31° inclination / heading, firmware_sim
    flips 0.54 → 0.43° (docs/monitor.md round fourteen); a raw IMU through the API keeps it off
    (:func:`multirotor_eskf_settings`).
    """
    d = EskfSettings()
    # the magnetometer model: on unless set either way (an autopilot's compass, motor current in the stream)
    mag_model = eskf.mag_model if eskf.mag_model.enabled is not None else replace(eskf.mag_model, enabled=True)
    return replace(
        eskf,
        mag_model=mag_model,
        gravity_lowpass_s=VEHICLE_GRAVITY_LOWPASS_S,
        gravity_noise_m_s2=d.gravity_noise_m_s2,
        heading_noise_rad=d.heading_noise_rad,
        mag_rate_hz=d.mag_rate_hz,
        mag_body_offset_lag_s=d.mag_body_offset_lag_s,
        mag_rejected_sigma_scale=d.mag_rejected_sigma_scale,
        mag_noise_tau_s=VEHICLE_MAG_NOISE_TAU_S,
        heading_walk_tau_s=VEHICLE_HEADING_WALK_TAU_S,
        gate_sigma=d.gate_sigma,
        bias_limit_rad_s=d.bias_limit_rad_s,
        gyro_scale_sigma=d.gyro_scale_sigma,
        gyro_scale_tilt_sigma=d.gyro_scale_tilt_sigma,
        gyro_scale_state_sigma=d.gyro_scale_state_sigma,
        bias_walk_aided_rad_s2=VEHICLE_BIAS_WALK_RAD_S2,
        mag_learn_tau_s=VEHICLE_MAG_LEARN_TAU_S,
        accel_bias_sigma_m_s2=VEHICLE_ACCEL_BIAS_SIGMA_M_S2,
        accel_bias_consider_sigma_m_s2=VEHICLE_ACCEL_BIAS_CONSIDER_SIGMA_M_S2,
        accel_bias_aided_only=True,
        output_half_step=True,
    )


#: s of every drag measurement rejected before the multirotor hypothesis re-opens its velocity's variance
#: (``EskfSettings.drag_reset_s``; 0 = never): ten drag periods, within a hover's drift, before a velocity that
#: random-walked unobserved drags the tilt with it (issue 22, branch vib: docs/accuracy.md "Seventh round")
MULTIROTOR_DRAG_RESET_S = 1.0
#: a raw IMU's multirotor (``set_multirotor()`` with no k, the plain path's multirotor hypothesis): the rotors'
#: momentum drag k, 1/s, beside the body's quadratic drag (``MULTIROTOR_BODY_DRAG_1_M``): k + c‖v‖ is the linear
#: model's 0.5 /s (``MULTIROTOR_DRAG_1_S``) at 10 m/s.  Momentum theory bounds it (``EskfSettings.drag_coefficient_1_s``:
#: g/(2 v_i) ≈ 1.3 /s for a fully turned inflow, open rotors a fraction); the autopilots document 0.1–0.15 /s for
#: open rotors (ArduPilot EK3_DRAG_MCOEF's example, 1.5 m/s² at 15 m/s = 0.1; PX4 EKF2_MCOEF's default 0.15),
#: "higher for ducted rotors" (both).  0.4 is above those typical values (nearer them than the linear 0.5);
#: measured in docs/accuracy.md "Eleventh round (branch drag2)" (issue 22)
MULTIROTOR_RAW_DRAG_1_S = 0.4
#: the body's bluff drag ½ρ C_d A / m = ρ / (2 B), 1/m, with B the ballistic coefficient m / (C_d A) of ArduPilot's
#: EK3_DRAG_BCOEF_X/Y (range 0–1000 kg/m², "a starting value is the mass divided by the frontal area") and PX4's
#: EKF2_BCOEF_X/Y (default 100 kg/m² → 0.006 /m at sea level, range 0–200); 0.01 /m is B ≈ 61 kg/m²
#: (ρ 1.225 kg/m³): a 1.5 kg quadrotor with C_d A = 0.025 m², inside both ranges (issue 22)
MULTIROTOR_BODY_DRAG_1_M = 0.01
#: s over which a declared raw multirotor's drag measurement (:meth:`Best.set_multirotor` through the API) matches its
#: noise to its innovations (``EskfSettings.drag_noise_match_s``; not the plain path's hypothesis): under a raw IMU's aliased vibration the velocity's covariance was
#: 10–30× overconfident in σ (firmware_sim raw ``vibration``) and the drag, trusting it, pulled the tilt to
#: 58–69°; 5 s is 100 innovations, the mean square's relative error ≈ 14 % (2 s measured the same on
#: firmware_sim, ArduCopter SITL's ``sitl-raw`` gentle 1.34 → 1.63°; docs/accuracy.md "Twelfth round (branch raw6)")
MULTIROTOR_DRAG_NOISE_MATCH_S = 5.0
#: block length of the declared multirotor's specific-force slow-error estimate (``EskfSettings.slow_force_block_s``:
#: the velocity's process noise carries the Hadamard variance of 0.1 s block means beyond the white noise's share)
MULTIROTOR_SLOW_FORCE_BLOCK_S = 0.1
#: a declared raw multirotor's accelerometer bias across its thrust axis as two constant error states, prior 1-σ,
#: m/s² (``EskfSettings.accel_bias_sigma_m_s2`` with ``accel_bias_across_thrust``, estimated without aiding): an
#: uncalibrated accelerometer's offset across the thrust reads as a tilt of offset/g wherever the vehicle flies
#: (0.3 m/s²: 1.75°), told apart only as the body yaws under it; along the thrust it is the unknown thrust's and
#: is not estimated.  0.03: at 0.05 (raw11) ArduCopter SITL's raw sets, whose IMU has no offset, lost 0.02–0.07°
#: even with the speed gate below; firmware_sim raw declared ``hover`` / ``aggressive`` 0.935 / 1.215 → 0.866 /
#: 1.165° on the seeds chosen on, lower on both held-out sets (docs/accuracy.md, eighteenth round)
MULTIROTOR_ACCEL_BIAS_SIGMA_M_S2 = 0.03
#: … estimated only below this INS horizontal speed, m/s, and only *considered* above it
#: (``EskfSettings.accel_bias_live_speed_m_s``): a drag model's misfit is fixed in the body, as an offset is, when
#: the vehicle flies with a steady body-frame velocity (ArduCopter SITL's legs and circles, its drag 0.25 /s +
#: 0.027 /m against the model's 0.4 + 0.01, lateral and forward unlike), and grows with the speed; an offset does
#: not.  ArduCopter SITL's ``sitl-vib`` declared / ``sitl-raw`` 1.33 / 0.91° with the states ungated (σ 0.05),
#: 1.29 / 0.90 (σ 0.03), 1.24 / 0.88 with this gate (main 1.26 / 0.89; docs/accuracy.md, eighteenth round)
MULTIROTOR_ACCEL_BIAS_LIVE_SPEED_M_S = 7.0
#: a raw IMU's multirotor through the API (declared, and since raw16 the plain path's multirotor hypothesis,
#: :func:`multirotor_eskf_settings`): its gyro bias's plausible range as a Gaussian prior, rad/s
#: (``EskfSettings.bias_prior_sigma_rad_s``: the pseudo-measurement b = 0 with this σ, per axis), fused only on an
#: axis whose estimate has been beyond it for ``MULTIROTOR_RAW_BIAS_PRIOR_AFTER_S`` (a soft bound on lasting
#: excursions: a second-long vibration pass the gyro really reads is followed).  5 °/s: the issue's raw MEMS gyro
#: (firmware_sim's raw preset draws its bias uniformly within ±5 °/s; a vehicle's models would bound it at the ESKF's
#: 10 °/s, an autopilot's calibrated gyro's).  4 °/s, inside that range, cost every set (firmware_sim raw declared
#: ``hover`` / ``aggressive`` 0.866 / 1.165 → 1.317 / 1.496°); 5 °/s 0.839 / 1.120 on the seeds chosen on (6 °/s 0.846 /
#: 1.135, the hard 7 °/s bound of raw13 0.856 / 1.134) and lower on all six held-out sets (``hover`` 130–159
#: 1.032 → 0.854; ``aggressive`` 160–189 1.174 → 1.126, 170's start under vibration 4.55 → 3.52°), ArduCopter SITL's
#: raw sets level or better (``sitl-raw`` 0.884 → 0.872; docs/accuracy.md, twentieth round)
MULTIROTOR_RAW_BIAS_PRIOR_SIGMA_RAD_S = math.radians(5.0)
#: … the time, s, an axis's estimate must have been beyond that σ without a break before the prior is fused on it
MULTIROTOR_RAW_BIAS_PRIOR_AFTER_S = 2.0
#: a raw IMU's multirotor through the API (declared, and since raw16 the plain path's multirotor hypothesis,
#: :func:`multirotor_eskf_settings`) starts in flight: the 1-σ of its first tilt, rad
#: (``EskfSettings.initial_tilt_rad``, at least this).  The tilt is taken from the first accelerometer sample, which
#: on a multirotor in a manoeuvre, its rotors' vibration on, is not gravity: on firmware_sim's raw flights (seeds
#: 100–129) that sample's tilt is 17.3° RMS off (mean 15.2°, largest 30.6°; averaging the first 0.25–2 s is no better
#: in a manoeuvre, 13–21°), against the 3° a sensor started at rest has.  With 3° the filter took the start's tilt
#: error for a gyro bias (``aggressive`` 101: 1.9 → 6.5 °/s wrong at 2.5 s) and closed the bias's covariance on it
#: (docs/accuracy.md, twenty-first round)
MULTIROTOR_RAW_INITIAL_TILT_RAD = math.radians(20.0)
#: … and its accelerometer as a gravity measurement (``EskfSettings.gravity_noise_m_s2``, at least this), m/s²: the
#: 0.1 s mean specific force, fused at every sample, holds a multirotor's manoeuvre for seconds, so one sample's
#: information is far less than 3 m/s² (the vehicle default) says.  With 3 the filter was inconsistent on the raw
#: flights (tilt NEES 10.5 in the first 20 s, 6.1 after, against 2; the bias's 22.9 / 9.9 against 3): a 5 °/s bias
#: left 3 °/s wrong at 20 s with its σ 0.3 °/s.  Chosen with the initial tilt on firmware_sim raw seeds 100–129,
#: confirmed on 130–219 and on ArduCopter SITL's raw sets (docs/accuracy.md, twenty-first round)
MULTIROTOR_RAW_GRAVITY_NOISE_M_S2 = 8.0


def multirotor_eskf_settings(eskf: EskfSettings, drag_coefficient_1_s: float | None = None) -> EskfSettings:
    """``eskf`` with a raw IMU's multirotor models (what :meth:`Best.set_multirotor` sets through the API).

    A vehicle's measurement models (:func:`vehicle_eskf_settings`), the rotor-drag measurement
    (k = ``drag_coefficient_1_s``, else one already set, else ``MULTIROTOR_RAW_DRAG_1_S`` 0.4 /s with the body's
    quadratic drag ``MULTIROTOR_BODY_DRAG_1_M`` 0.01 /m beside it: D = (k + c‖v‖) v), the thrust axis as two
    error states (σ 15°, any mounting) and the drag noise 0.35 m/s² (``AXIS_STATES_DRAG_NOISE_M_S2``);
    the start re-aligned only beyond ``MULTIROTOR_INITIAL_REALIGN_RAD`` (45°); a detected rest taken only once
    the bias is known within ``MULTIROTOR_REST_CHECK_SIGMA_RAD_S`` on some axis (a hover is as still as rest), and a
    hovering rest's rate across the vertical fused with a per-rest wobble (``MULTIROTOR_REST_WOBBLE_SIGMA_RAD_S``); the
    velocity's variance re-opened after ``MULTIROTOR_DRAG_RESET_S`` of every drag measurement rejected.
    """
    k = drag_coefficient_1_s
    if k is None:
        k = eskf.drag_coefficient_1_s or MULTIROTOR_RAW_DRAG_1_S
    eskf = replace(eskf, drag_coefficient_1_s=float(k))
    if eskf.drag_quadratic_1_m == 0.0 and drag_coefficient_1_s is None:
        eskf = replace(eskf, drag_quadratic_1_m=MULTIROTOR_BODY_DRAG_1_M)
    if eskf.thrust_axis_sigma_rad == 0.0:
        eskf = replace(eskf, thrust_axis_sigma_rad=MULTIROTOR_AXIS_SIGMA_RAD, drag_noise_m_s2=AXIS_STATES_DRAG_NOISE_M_S2)
    if eskf.initial_realign_rad < MULTIROTOR_INITIAL_REALIGN_RAD:
        eskf = replace(eskf, initial_realign_rad=MULTIROTOR_INITIAL_REALIGN_RAD)
    if eskf.rest_check_sigma_rad_s == 0.0:
        eskf = replace(eskf, rest_check_sigma_rad_s=MULTIROTOR_REST_CHECK_SIGMA_RAD_S)
    if eskf.drag_reset_s == 0.0:
        eskf = replace(eskf, drag_reset_s=MULTIROTOR_DRAG_RESET_S)
    if eskf.rest_wobble_sigma_rad_s == 0.0:
        eskf = replace(eskf, rest_wobble_sigma_rad_s=MULTIROTOR_REST_WOBBLE_SIGMA_RAD_S,
                       rest_hover_vibration_m_s2=MULTIROTOR_REST_HOVER_VIBRATION_M_S2,
                       rest_hover_speed_m_s=MULTIROTOR_REST_HOVER_SPEED_M_S)
    # the tilt's scale-factor noise as ``eskf`` has it (best's raw settings: none): on firmware_sim's raw
    # IMU declared a multirotor it cost aggressive 1–4 1.11 → 1.16° (flips 1–4 2.53 → 2.43°; docs/monitor.md
    # round eight); an autopilot's stream, where the monitor reads the tilt σ, has it from vehicle_eskf_settings
    # the output's timing as ``eskf`` has it too (off): a raw IMU's sample may be its interval's mean, with no
    # right-rectangle lead to remove (BROAD 0.66 → 0.86° with the half step; docs/monitor.md round fourteen)
    eskf = replace(vehicle_eskf_settings(eskf), gyro_scale_tilt_sigma=eskf.gyro_scale_tilt_sigma,
                   output_half_step=eskf.output_half_step)
    # a raw IMU's multirotor through the API, declared or the plain path's hypothesis, starts in flight: the first
    # tilt as uncertain as a manoeuvre makes it and the accelerometer as a gravity measurement weighed for the
    # manoeuvre it holds (each at least: a larger first tilt σ set is kept; the gravity noise is
    # vehicle_eskf_settings' own, as every vehicle model is), and the raw gyro's plausible bias range as a prior on
    # lasting excursions (one set is kept).  On the plain path's hypothesis since raw16: firmware_sim raw
    # ``aggressive`` through ``create("best")`` 1.206 → 0.975° on the seeds chosen on (docs/accuracy.md,
    # twenty-second round)
    eskf = replace(eskf, initial_tilt_rad=max(eskf.initial_tilt_rad, MULTIROTOR_RAW_INITIAL_TILT_RAD),
                   gravity_noise_m_s2=max(eskf.gravity_noise_m_s2, MULTIROTOR_RAW_GRAVITY_NOISE_M_S2))
    if eskf.bias_prior_sigma_rad_s == 0.0 and MULTIROTOR_RAW_BIAS_PRIOR_SIGMA_RAD_S > 0.0:
        eskf = replace(eskf, bias_prior_sigma_rad_s=MULTIROTOR_RAW_BIAS_PRIOR_SIGMA_RAD_S,
                       bias_prior_after_s=MULTIROTOR_RAW_BIAS_PRIOR_AFTER_S, bias_prior_spread_s=0.0)
    return eskf


@dataclass(frozen=True)
class MultirotorDetectSettings:
    r"""The plain path's choice between "nothing known" and "a multirotor", by likelihood (:class:`Best`).

    Two hypotheses run side by side on the plain path (nothing declared): *generic* (the ESKF
    of :func:`best_eskf_settings`: the specific force is gravity plus a motion acceleration of
    no particular direction) and *multirotor* (the ESKF of :func:`multirotor_eskf_settings`: the
    specific force is thrust along an axis fixed in the body, and across it the rotor drag
    −k·v_b).  Both predict the same measurement every ``period_s``: the mean specific force over
    the period, body frame, on the two axes across the multirotor hypothesis's thrust axis.
    The generic prediction is gravity, −Cᵀ g e_d, with variance ``accel_sigma_m_s2``² plus its
    tilt uncertainty (h = u × w, u = C e, w = −g e_d); the multirotor one is −k e·Cᵀv with its
    drag noise plus its velocity, tilt and axis uncertainty (the drag measurement's h); both
    add the mean's share of the measured sensor noise.  Each period adds the log-likelihood
    ratio ½Σ_c [y_G²/S_G + ln S_G − y_M²/S_M − ln S_M] (clipped to ±``clip_nats``: one
    period never decides) to a sum forgotten with ``forget_s`` (the predictions are made from
    each filter's state before the period's samples: the prediction-error decomposition of
    the likelihood; Magill 1965, Bar-Shalom et al. 2001 §11.6 — a multiple-model test with
    the two filters run independently, no interaction).  The output is the multirotor
    hypothesis's once the sum exceeds ``switch_nats`` (the prior in favour of "generic": short
    ambiguous stretches never switch) and the generic one's again below ``back_nats``.

    Attributes:
        enabled: run the multirotor hypothesis beside on the plain path (False: one ESKF, as before).
        accel_sigma_m_s2: the generic hypothesis's motion acceleration across the axis, 0.1 s mean, m/s².
        period_s: the comparison's period (the drag measurement's), s.
        forget_s: time constant of the evidence's forgetting, s: how long the prior lets old evidence count (a
            recording does not change its kind; the forgetting only lets a wrong early decision be undone).  120 s
            rather than 60: a gentle hover's evidence rises at ≈ 0.25 nats/s and levelled off at 15–24 nats over
            60 s (firmware_sim raw ``hover`` 4 stayed generic, 1.67°; 120 s: a multirotor from 44 s, 1.27°) while
            the hand-held trials' evidence comes in bursts (BROAD 9D/6D/raw largest 11.8 → 11.9 nats, RepoIMU
            TStick ≤ 0.8, none switched either way; docs/accuracy.md).
        switch_nats: evidence for "multirotor" beyond which its attitude is the output.
        back_nats: evidence below which the output is the generic hypothesis's again.
        clip_nats: the most one period adds either way.
        accel_tau_s: correlation time of the generic hypothesis's motion acceleration (Singer), s.
        bias_sigma_rad_s: no evidence while the generic hypothesis's gyro bias across the vertical is
            less certain than this (its 1-σ, the mean of the two horizontal axes'), rad/s.
        force_tolerance: no evidence from a period whose mean specific force is further than this
            fraction from g (a sensor shaken or swung hard fits neither hypothesis's noise).
    """

    enabled: bool = True
    accel_sigma_m_s2: float = 0.5
    period_s: float = 0.1
    forget_s: float = 120.0
    switch_nats: float = 25.0
    back_nats: float = 0.0
    clip_nats: float = 1.0
    accel_tau_s: float = 0.15
    bias_sigma_rad_s: float = math.radians(0.5)
    force_tolerance: float = 0.4

    def __post_init__(self) -> None:
        for name in ("accel_sigma_m_s2", "period_s", "forget_s", "clip_nats", "accel_tau_s", "bias_sigma_rad_s",
                     "force_tolerance"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"MultirotorDetectSettings.{name} must be > 0, got {v!r}")
        if not (math.isfinite(self.switch_nats) and math.isfinite(self.back_nats) and self.back_nats < self.switch_nats):
            raise ValueError("MultirotorDetectSettings: back_nats must be below switch_nats (both finite)")


@dataclass(frozen=True)
class BestSettings(FilterSettings):
    """Settings of :class:`Best`.

    Attributes:
        madgwick: the filter used without velocity aiding.
        eskf: the estimator (:func:`best_eskf_settings`: nothing known of the source; an
            autopilot's stream or a declared multirotor switches its measurement models to
            :func:`vehicle_eskf_settings`).
        multirotor_eskf: the multirotor hypothesis run beside ``eskf`` on the plain path
            (:func:`multirotor_eskf_settings`; :class:`MultirotorDetectSettings`).
        detect: the choice between the two by likelihood (``detect.enabled`` False: ``eskf`` alone).
        shared_bias: without velocity aiding the Madgwick part integrates
            the gyro less the ESKF's bias estimate (learnt in motion).
        fade_s: after the velocity-aided filter loses its aiding
            (``eskf.aiding_timeout_s`` without a fix), the output moves from
            its attitude to the Madgwick attitude over this long, s; and on the
            plain path from one hypothesis's attitude to the other's (``detect``).
        unaided_filter: the filter whose attitude is sent without velocity
            aiding: ``"eskf"`` (the default: one estimator in every condition,
            its zero-velocity and gravity updates; the Madgwick part runs beside
            it only to re-align a restart of the aiding) or ``"madgwick"`` (the
            tuned Madgwick configuration, integrating the gyro less the ESKF's
            bias; kept for comparison: BROAD 0.70° against the ESKF's 0.66°
            (total 1.86 against 1.81°), as a raw IMU 1.10° against 1.09°,
            ``docs/accuracy.md``).
    """

    madgwick: MadgwickSettings = field(default_factory=best_settings)
    eskf: EskfSettings = field(default_factory=best_eskf_settings)
    multirotor_eskf: EskfSettings = field(default_factory=lambda: multirotor_eskf_settings(best_eskf_settings()))
    detect: MultirotorDetectSettings = field(default_factory=MultirotorDetectSettings)
    fade_s: float = 2.0
    shared_bias: bool = True
    unaided_filter: str = "eskf"

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.fade_s) and self.fade_s >= 0.0):
            raise ValueError(f"BestSettings.fade_s must be ≥ 0 s, got {self.fade_s!r}")
        if self.unaided_filter not in ("eskf", "madgwick"):
            raise ValueError(f"BestSettings.unaided_filter must be 'eskf' or 'madgwick', got {self.unaided_filter!r}")
        if (self.madgwick.max_gap_s != self.max_gap_s or self.eskf.max_gap_s != self.max_gap_s
                or self.multirotor_eskf.max_gap_s != self.max_gap_s):  # fmt: skip
            raise ValueError("BestSettings: max_gap_s must be the same for best and both of its filters")


# layout of the composite (offsets from S_FILTER / P_FILTER), fixed by the two filters' sizes
_LM = S_FILTER + Madgwick.internal_len  # a whole Madgwick state
_LE = S_FILTER + Eskf.internal_len
_PLM = len(best_settings().common_params()) + len(Madgwick.filter_params(best_settings()))
_PLE = len(EskfSettings().common_params()) + len(Eskf.filter_params(EskfSettings()))
_SM = S_FILTER  # Madgwick state
_SE = _SM + _LM  # ESKF state
_OM = _SE + _LE  # Madgwick's output row
_OE = _OM + OUT_WIDTH  # ESKF's output row
_W = _OE + OUT_WIDTH  # output weight of the ESKF, 0 … 1
_QOUT = _W + 1  # the attitude last written to the common prefix (4): detects a state set by hand
_ROW = _QOUT + 4  # scratch: the input row as the ESKF sees it
_SE2 = _ROW + IN_WIDTH  # the multirotor hypothesis's ESKF state (plain path)
_OE2 = _SE2 + _LE  # its output row
_DF = _OE2 + OUT_WIDTH  # this period's sums, body frame: specific force (3), generic prediction (3),
#                         multirotor prediction (3), samples (1), time (1)
_LLR = _DF + 11  # the evidence for "multirotor" against "generic", nats (forgotten)
_MODE = _LLR + 1  # 1: the output is the multirotor hypothesis's
_T_MODE = _MODE + 1  # seconds the output was the multirotor hypothesis's
_SWITCHES = _T_MODE + 1  # how often the output changed hypothesis
_LLR_MAX = _SWITCHES + 1  # the largest evidence seen
_AG = _LLR_MAX + 1  # the generic hypothesis's last motion acceleration (its residual, body, 3)
_DH = _AG + 3  # scratch: a prediction's h on the error state (ERROR_STATE_LEN)
_W2 = _DH + ERROR_STATE_LEN  # output weight of the multirotor hypothesis, 0 … 1 (moves over fade_s)
_N_STATE = _W2 + 1 - S_FILTER
_PM = P_FILTER  # Madgwick params
_PE = _PM + _PLM  # ESKF params
_FADE = _PE + _PLE
_SHARE_BIAS = _FADE + 1
_ESKF_ONLY = _SHARE_BIAS + 1  # 1: the ESKF's attitude in every condition, the Madgwick part not run
_PE2 = _ESKF_ONLY + 1  # the multirotor hypothesis's ESKF params
_DET_ON = _PE2 + _PLE  # 1: the multirotor hypothesis runs beside (the plain path)
_DET_SIGMA = _DET_ON + 1  # MultirotorDetectSettings: accel_sigma_m_s2, period_s, forget_s, switch/back/clip nats
_DET_PERIOD = _DET_ON + 2
_DET_FORGET = _DET_ON + 3
_DET_SWITCH = _DET_ON + 4
_DET_BACK = _DET_ON + 5
_DET_CLIP = _DET_ON + 6
_DET_ACCEL_TAU = _DET_ON + 7
_DET_BIAS_VAR = _DET_ON + 8
_DET_NORM_TOL = _DET_ON + 9
_N_PARAMS = _DET_NORM_TOL + 1 - P_FILTER
_NE = ERROR_STATE_LEN
_KV = S_FILTER + VELOCITY_STATE  # offsets inside an ESKF's own block
_KP = S_FILTER + COVARIANCE_STATE
_KT = S_FILTER + THRUST_AXIS_STATE


@kernel(inline=True)
def _body_down(s):  # type: ignore[no-untyped-def]
    """The NED down axis in the body frame (C's third row) of the ESKF state ``s`` (its q)."""
    q0, q1, q2, q3 = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    return 2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2)


@kernel(inline=True)
def _to_ned(s, x, y, z):  # type: ignore[no-untyped-def]
    """C x: a body vector in NED with the attitude of the ESKF state ``s``."""
    q0, q1, q2, q3 = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    n = (1.0 - 2.0 * (q2 * q2 + q3 * q3)) * x + 2.0 * (q1 * q2 - q0 * q3) * y + 2.0 * (q1 * q3 + q0 * q2) * z
    e = 2.0 * (q1 * q2 + q0 * q3) * x + (1.0 - 2.0 * (q1 * q1 + q3 * q3)) * y + 2.0 * (q2 * q3 - q0 * q1) * z
    d = 2.0 * (q1 * q3 - q0 * q2) * x + 2.0 * (q2 * q3 + q0 * q1) * y + (1.0 - 2.0 * (q1 * q1 + q2 * q2)) * z
    return n, e, d


@kernel(inline=True)
def _detect_accumulate(state, se, se2, pe2, row):  # type: ignore[no-untyped-def]
    """This sample's specific force and both hypotheses' predictions of it (from their states before it)."""
    ax, ay, az = row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2]
    dt = row[IN_DT]
    if not (math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az) and dt > 0.0 and dt < 1.0):
        return  # an invalid sample (NaN, ±inf, a bad dt) is no evidence either way
    if not (se[S_INIT] > 0.0 and se2[S_INIT] > 0.0):
        return
    k = pe2[P_FILTER + DRAG_PARAM]
    dx, dy, dz = _body_down(se)
    q0, q1, q2, q3 = se2[S_Q], se2[S_Q + 1], se2[S_Q + 2], se2[S_Q + 3]
    vn, ve, vd = se2[_KV], se2[_KV + 1], se2[_KV + 2]
    # v_b = Cᵀ v
    vbx = (1.0 - 2.0 * (q2 * q2 + q3 * q3)) * vn + 2.0 * (q1 * q2 + q0 * q3) * ve + 2.0 * (q1 * q3 - q0 * q2) * vd
    vby = 2.0 * (q1 * q2 - q0 * q3) * vn + (1.0 - 2.0 * (q1 * q1 + q3 * q3)) * ve + 2.0 * (q2 * q3 + q0 * q1) * vd
    vbz = 2.0 * (q1 * q3 + q0 * q2) * vn + 2.0 * (q2 * q3 - q0 * q1) * ve + (1.0 - 2.0 * (q1 * q1 + q2 * q2)) * vd
    state[_DF] += ax
    state[_DF + 1] += ay
    state[_DF + 2] += az
    state[_DF + 3] -= G_M_S2 * dx  # generic: f = −Cᵀ g e_d
    state[_DF + 4] -= G_M_S2 * dy
    state[_DF + 5] -= G_M_S2 * dz
    k = k + pe2[P_FILTER + DRAG_QUADRATIC_PARAM] * math.sqrt(vn * vn + ve * ve + vd * vd)
    state[_DF + 6] -= k * vbx  # multirotor: across the thrust axis, f = −(k + c‖v‖) v_b
    state[_DF + 7] -= k * vby
    state[_DF + 8] -= k * vbz
    state[_DF + 9] += 1.0
    state[_DF + 10] += dt


@kernel(inline=True)
def _quad_form(s, h):  # type: ignore[no-untyped-def]
    """h P hᵀ with P the covariance of the ESKF state ``s`` (h: the 12 entries of the scratch ``h``)."""
    acc = 0.0
    for i in range(_NE):
        if h[i] != 0.0:
            for j in range(_NE):
                acc += h[i] * s[_KP + i * _NE + j] * h[j]
    return acc


@kernel(inline=True)
def _detect_period(state, params, se, se2, pe2, h):  # type: ignore[no-untyped-def]
    """At the end of a period: its log-likelihood ratio into the evidence, the hypothesis chosen."""
    n = state[_DF + 9]
    tp = state[_DF + 10]
    if tp < params[_DET_PERIOD]:
        return
    tx, ty, tz = se2[_KT], se2[_KT + 1], se2[_KT + 2]
    tn = math.sqrt(tx * tx + ty * ty + tz * tz)
    # the generic hypothesis's gyro bias across the vertical learnt: before, its gravity prediction turns
    # with the bias (a hand-held sensor with an unlearnt raw bias looks like thrust fixed in the body)
    dx, dy, dz = _body_down(se)
    kb = _KP + 6 * _NE + 6
    var_b = se[kb] + se[kb + _NE + 1] + se[kb + 2 * _NE + 2]
    var_v = 0.0
    for i in range(3):
        di = dx if i == 0 else (dy if i == 1 else dz)
        for j in range(3):
            dj = dx if j == 0 else (dy if j == 1 else dz)
            var_v += di * se[kb + i * _NE + j] * dj
    ready = (
        n > 0.0 and tn > 0.5
        and se[S_FILTER + START_DONE_STATE] > 0.0 and se2[S_FILTER + START_DONE_STATE] > 0.0
        and 0.5 * (var_b - var_v) < params[_DET_BIAS_VAR]
    )  # fmt: skip
    if ready:
        # the mean specific force near g: thrust ≈ weight (a multirotor) or gravity with little motion
        # acceleration; a hand-held sensor shaken or swung hard fits neither hypothesis's noise
        fx, fy, fz = state[_DF] / n, state[_DF + 1] / n, state[_DF + 2] / n
        ready = abs(math.sqrt(fx * fx + fy * fy + fz * fz) / G_M_S2 - 1.0) < params[_DET_NORM_TOL]
    if ready:
        k = pe2[P_FILTER + DRAG_PARAM]
        sig = params[_DET_SIGMA]
        # the mean's share of the measured white noise of the specific force (per axis, per sample)
        r_c = se[S_FILTER + MEASURED_NOISE_STATE + 1] / n
        fx, fy, fz = state[_DF] / n, state[_DF + 1] / n, state[_DF + 2] / n
        _, _, _, e1x, e1y, e1z, e2x, e2y, e2z = axis_basis(tx, ty, tz, int(se2[S_FILTER + THRUST_AXIS_REF_STATE]))
        tx, ty, tz = tx / tn, ty / tn, tz / tn
        vn, ve, vd = se2[_KV], se2[_KV + 1], se2[_KV + 2]
        c_q = pe2[P_FILTER + DRAG_QUADRATIC_PARAM]
        v_norm = math.sqrt(vn * vn + ve * ve + vd * vd)
        c_v = c_q / v_norm if v_norm > 1e-6 else 0.0
        k = k + c_q * v_norm
        utn, ute, utd = _to_ned(se2, tx, ty, tz)
        thrust = fx * tx + fy * ty + fz * tz + k * (utn * vn + ute * ve + utd * vd)
        # the generic hypothesis's motion acceleration as a first-order Markov process (Singer 1970): the
        # next period's is the last one's times ρ = exp(−T/τ); no acceleration model at all predicted a
        # hand-held translation's smooth acceleration worse than the multirotor's states did
        rho = math.exp(-tp / params[_DET_ACCEL_TAU])
        agx, agy, agz = rho * state[_AG], rho * state[_AG + 1], rho * state[_AG + 2]
        inc = 0.0
        for c in range(2):
            if c == 0:
                ex, ey, ez = e1x, e1y, e1z
            else:
                ex, ey, ez = e2x, e2y, e2z
            z = fx * ex + fy * ey + fz * ez
            # generic: gravity; h on the tilt error = u × w, u = C e, w = (0, 0, −g)
            yg = z - (state[_DF + 3] * ex + state[_DF + 4] * ey + state[_DF + 5] * ez) / n - (agx * ex + agy * ey + agz * ez)
            un, ue, ud = _to_ned(se, ex, ey, ez)
            for i in range(_NE):
                h[i] = 0.0
            h[0] = -ue * G_M_S2
            h[1] = un * G_M_S2
            sg = sig * sig + r_c + _quad_form(se, h)
            # multirotor: the drag measurement's prediction and h (eskf._drag_update)
            ym = z - (state[_DF + 6] * ex + state[_DF + 7] * ey + state[_DF + 8] * ez) / n
            un, ue, ud = _to_ned(se2, ex, ey, ez)
            uv = un * vn + ue * ve + ud * vd
            wn, we, wd = k * un + c_v * uv * vn, k * ue + c_v * uv * ve, k * ud + c_v * uv * vd
            h[0] = -(we * vd - wd * ve)
            h[1] = -(wd * vn - wn * vd)
            h[2] = -(wn * ve - we * vn)
            h[3] = -wn
            h[4] = -we
            h[5] = -wd
            h[9 + c] = thrust
            sm = sig * sig + r_c + _quad_form(se2, h)
            inc += 0.5 * (yg * yg / sg + math.log(sg) - ym * ym / sm - math.log(sm))
        clip = params[_DET_CLIP]
        inc = min(max(inc, -clip), clip) if math.isfinite(inc) else 0.0  # a state gone bad is no evidence
        forget = math.exp(-tp / params[_DET_FORGET])
        llr = state[_LLR] * forget + inc
        state[_LLR] = llr
        if llr > state[_LLR_MAX]:
            state[_LLR_MAX] = llr
        if state[_MODE] == 0.0 and llr > params[_DET_SWITCH]:
            state[_MODE] = 1.0
            state[_SWITCHES] += 1.0
        elif state[_MODE] > 0.0 and llr < params[_DET_BACK]:
            state[_MODE] = 0.0
            state[_SWITCHES] += 1.0
    if n > 0.0:  # the generic hypothesis's motion acceleration in this period (its residual)
        for i in range(3):
            a = (state[_DF + i] - state[_DF + 3 + i]) / n
            state[_AG + i] = a if math.isfinite(a) else 0.0
    for i in range(11):
        state[_DF + i] = 0.0


@kernel(inline=True)
def _blend_output(state, out, a, b, w):  # type: ignore[no-untyped-def]
    """``out`` = output row ``a`` (weight ``w``) moving to/from ``b``: the nearer one's row, its attitude the
    normalised linear blend of the two (same hemisphere) while 0 < w < 1; ``best``'s own attitude and bias
    (``S_Q``, ``S_BIAS``) follow it."""
    src = a if w >= 0.5 else b
    for i in range(OUT_WIDTH):
        out[i] = src[i]
    if 0.0 < w < 1.0:
        dot = 0.0
        for i in range(4):
            dot += a[OUT_Q + i] * b[OUT_Q + i]
        sgn = 1.0 if dot >= 0.0 else -1.0
        n = 0.0
        for i in range(4):
            out[OUT_Q + i] = w * a[OUT_Q + i] + (1.0 - w) * sgn * b[OUT_Q + i]
            n += out[OUT_Q + i] * out[OUT_Q + i]
        n = math.sqrt(n)
        for i in range(4):
            out[OUT_Q + i] /= n
    for i in range(4):
        state[S_Q + i] = out[OUT_Q + i]
        state[_QOUT + i] = out[OUT_Q + i]
    for i in range(3):
        state[S_BIAS + i] = out[OUT_BIAS + i]


@kernel
def step(state, params, row, out):  # type: ignore[no-untyped-def]
    """Both filters, then the output: the ESKF's while velocity-aided, else Madgwick's (faded)."""
    sm = state[_SM : _SM + _LM]
    se = state[_SE : _SE + _LE]
    pm = params[_PM : _PM + _PLM]
    pe = params[_PE : _PE + _PLE]
    om = state[_OM : _OM + OUT_WIDTH]
    oe = state[_OE : _OE + OUT_WIDTH]
    detect = params[_DET_ON] > 0.0 and params[_ESKF_ONLY] > 0.0
    se2 = state[_SE2 : _SE2 + _LE]
    pe2 = params[_PE2 : _PE2 + _PLE]
    oe2 = state[_OE2 : _OE2 + OUT_WIDTH]
    if detect:  # both hypotheses' predictions from their states before this sample
        _detect_accumulate(state, se, se2, pe2, row)
    fix = (
        not (row[IN_VEL] != row[IN_VEL])
        or not (row[IN_VEL + 1] != row[IN_VEL + 1])
        or not (row[IN_VEL + 2] != row[IN_VEL + 2])
    )
    erow = row
    if fix and not eskf_aided(se, pe):
        if (
            sm[S_INIT] > 0.0 and se[S_INIT] > 0.0
            and (pm[P_FILTER + PM_GNSS] == 0.0 or not gnss_compensation_fresh(sm, S_FILTER + FM_GNSS))
        ):  # fmt: skip
            # the ESKF (re)starts its aiding from the Madgwick attitude and bias, so nothing jumps;
            # Madgwick has had its first v̇ since its own (re)initialisation, which re-aligned it by
            # TRIAD (after a restart in a manoeuvre the accelerometer's start is 20–45° off)
            for i in range(4):
                se[S_Q + i] = sm[S_Q + i]
            for i in range(3):
                se[S_BIAS + i] = sm[S_BIAS + i]
        else:  # not yet: the ESKF sees this fix as no fix
            erow = state[_ROW : _ROW + IN_WIDTH]
            for i in range(IN_WIDTH):
                erow[i] = row[i]
            for i in range(3):
                erow[IN_VEL + i] = math.nan
            erow[IN_VEL_AGE] = math.nan
    _eskf_step(se, pe, erow, oe)
    aided = eskf_aided(se, pe)
    multirotor = False
    if detect:
        _eskf_step(se2, pe2, erow, oe2)
        if aided:  # velocity-aided: the fixes tell; no evidence gathered
            for i in range(11):
                state[_DF + i] = 0.0
        else:
            _detect_period(state, params, se, se2, pe2, state[_DH : _DH + ERROR_STATE_LEN])
            multirotor = state[_MODE] > 0.0
            d = row[IN_DT]
            if multirotor and d > 0.0 and d < 1.0:
                state[_T_MODE] += d
    if not aided and se[S_INIT] > 0.0 and sm[S_INIT] > 0.0 and params[_SHARE_BIAS] > 0.0:
        # one gyro bias: the ESKF's (a state, learnt in motion from the velocity it integrates); the
        # Madgwick part integrates the gyro less it and does not learn its own
        for i in range(3):
            sm[S_BIAS + i] = se[S_BIAS + i]
    _madgwick_step(sm, pm, row, om)
    w = state[_W]
    dt = row[IN_DT]
    if params[_ESKF_ONLY] > 0.0:
        # one estimator: the ESKF's attitude, aided or not.  The Madgwick part still runs beside it for
        # one job: after a (re)initialisation in a manoeuvre (a link outage mid-flight) its first v̇
        # re-aligns it by TRIAD, and the ESKF restarts its aiding from that attitude (above); without
        # it the ESKF restarted from the accelerometer 20–45° off and took 5 s to recover (60° at 3–5 s)
        state[_W] = 1.0 if aided else 0.0
        # the output moves between the hypotheses over fade_s (a switch is not a step in the attitude)
        w2 = state[_W2]
        if detect:
            fade = params[_FADE]
            d = row[IN_DT]
            inc = d / fade if (fade > 0.0 and d > 0.0 and d < 1.0) else 1.0
            w2 = min(w2 + inc, 1.0) if multirotor else max(w2 - inc, 0.0)
        else:
            w2 = 0.0
        state[_W2] = w2
        _blend_output(state, out, oe2, oe, w2)
        state[S_INIT] = se2[S_INIT] if w2 >= 0.5 else se[S_INIT]
        return
    if aided:
        w = 1.0
    elif w > 0.0:
        fade = params[_FADE]
        w = w - dt / fade if (fade > 0.0 and dt > 0.0 and dt < 1.0) else 0.0
        if w < 0.0 or not (w == w):
            w = 0.0
    state[_W] = w
    _blend_output(state, out, oe, om, w)
    state[S_INIT] = 1.0 if (sm[S_INIT] > 0.0 or se[S_INIT] > 0.0) else 0.0


class Best(AttitudeFilter):
    """The recommended filter: the ESKF (with GNSS, on a vehicle's stream, on a multirotor), else tuned Madgwick.

    See :class:`BestSettings` and the module docstring.
    """

    name = "best"
    settings_type = BestSettings
    step = step
    internal_len = _N_STATE

    @classmethod
    def filter_params(cls, settings: BestSettings) -> np.ndarray:  # type: ignore[override]
        p = np.zeros(_N_PARAMS)
        m = np.concatenate([settings.madgwick.common_params(), Madgwick.filter_params(settings.madgwick)])
        e = np.concatenate([settings.eskf.common_params(), Eskf.filter_params(settings.eskf)])
        p[_PM - P_FILTER : _PM - P_FILTER + _PLM] = m
        p[_PE - P_FILTER : _PE - P_FILTER + _PLE] = e
        p[_FADE - P_FILTER] = settings.fade_s
        p[_SHARE_BIAS - P_FILTER] = 1.0 if settings.shared_bias else 0.0
        p[_ESKF_ONLY - P_FILTER] = 1.0 if settings.unaided_filter == "eskf" else 0.0
        e2 = np.concatenate([settings.multirotor_eskf.common_params(), Eskf.filter_params(settings.multirotor_eskf)])
        p[_PE2 - P_FILTER : _PE2 - P_FILTER + _PLE] = e2
        d = settings.detect
        p[_DET_ON - P_FILTER] = 1.0 if d.enabled else 0.0
        p[_DET_SIGMA - P_FILTER] = d.accel_sigma_m_s2
        p[_DET_PERIOD - P_FILTER] = d.period_s
        p[_DET_FORGET - P_FILTER] = d.forget_s
        p[_DET_SWITCH - P_FILTER] = d.switch_nats
        p[_DET_BACK - P_FILTER] = d.back_nats
        p[_DET_CLIP - P_FILTER] = d.clip_nats
        p[_DET_ACCEL_TAU - P_FILTER] = d.accel_tau_s
        p[_DET_BIAS_VAR - P_FILTER] = d.bias_sigma_rad_s**2
        p[_DET_NORM_TOL - P_FILTER] = d.force_tolerance
        return p

    def initial_internal(self) -> np.ndarray:
        s = self._settings
        assert isinstance(s, BestSettings)
        internal = np.zeros(_N_STATE)
        internal[_SM - S_FILTER : _SM - S_FILTER + _LM] = Madgwick(s.madgwick, compiled=False).raw_state
        internal[_SE - S_FILTER : _SE - S_FILTER + _LE] = Eskf(s.eskf, compiled=False).raw_state
        internal[_SE2 - S_FILTER : _SE2 - S_FILTER + _LE] = Eskf(s.multirotor_eskf, compiled=False).raw_state
        internal[_QOUT - S_FILTER] = 1.0
        return internal

    @property
    def using_velocity_aiding(self) -> bool:
        """True while the output is the velocity-aided filter's."""
        return bool(self._state[_W] >= 0.5)

    @AttitudeFilter.state.setter  # type: ignore[attr-defined,misc]
    def state(self, value: FilterState) -> None:
        AttitudeFilter.state.fset(self, value)  # type: ignore[attr-defined]
        s = self._state
        if not np.array_equal(s[S_Q : S_Q + 4], s[_QOUT : _QOUT + 4]):
            # the attitude was set from outside: both filters continue from it
            for base in (_SM, _SE, _SE2):
                s[base + S_Q : base + S_Q + 4] = s[S_Q : S_Q + 4]
                s[base + S_BIAS : base + S_BIAS + 3] = s[S_BIAS : S_BIAS + 3]
                s[base + S_INIT] = s[S_INIT]
            for base in (_SE, _SE2):
                # the ESKF's low-passed gravity reference is in the old frame: it is built again
                s[base + S_FILTER + GRAVITY_LOWPASS_STATE + 3] = 0.0
                # … and a start window still open would re-align the attitude just set: it is over
                s[base + S_FILTER + START_DONE_STATE] = 1.0
            s[_QOUT : _QOUT + 4] = s[S_Q : S_Q + 4]

    def set_mag_reference(self, norm_ut: float, dip_rad: float) -> None:
        """Both filters' magnetometer rejection reference (see :meth:`AttitudeFilter.set_mag_reference`)."""
        s = self._settings
        assert isinstance(s, BestSettings)
        for sub, base, pbase in ((Madgwick(s.madgwick, compiled=False), _SM, _PM),
                                 (Eskf(s.eskf, compiled=False), _SE, _PE),
                                 (Eskf(s.multirotor_eskf, compiled=False), _SE2, _PE2)):  # fmt: skip
            n = _LM if base == _SM else _LE
            pn = _PLM if base == _SM else _PLE
            sub._state[:] = self._state[base : base + n]
            sub._params[:] = self._params[pbase : pbase + pn]
            sub.set_mag_reference(norm_ut, dip_rad)
            self._state[base : base + n] = sub._state
            self._params[pbase : pbase + pn] = sub._params
        self._settings = replace(
            s,
            madgwick=replace(s.madgwick, schedule=replace(s.madgwick.schedule, mag_reference_norm_ut=norm_ut,
                                                          mag_reference_dip_rad=dip_rad)),
            eskf=replace(s.eskf, schedule=replace(s.eskf.schedule, mag_reference_norm_ut=norm_ut,
                                                  mag_reference_dip_rad=dip_rad)),
            multirotor_eskf=replace(s.multirotor_eskf, schedule=replace(
                s.multirotor_eskf.schedule, mag_reference_norm_ut=norm_ut, mag_reference_dip_rad=dip_rad)),
        )  # fmt: skip
        AttitudeFilter.set_mag_reference(self, norm_ut, dip_rad)

    def _output_eskf(self) -> tuple[EskfSettings, int]:
        """The settings and state offset of the ESKF whose attitude is output: on the plain path the multirotor
        hypothesis's once the detection chose it (:meth:`multirotor_detection`), else the ESKF's."""
        s = self._settings
        assert isinstance(s, BestSettings)
        if self._state[_MODE] > 0.0:
            return s.multirotor_eskf, _SE2
        return s.eskf, _SE

    def mag_model_state(self) -> dict[str, object] | None:
        """The output ESKF's learnt magnetometer model (:meth:`Eskf.mag_model_state`), None when off."""
        eskf, base = self._output_eskf()
        if not eskf.mag_model.enabled:
            return None
        k = base + S_FILTER + MAG_MODEL_STATE
        return mag_model_summary(self._state[k : k + MF_LEN])

    def mag_status(self) -> dict[str, object]:
        """The magnetometer's state for the status page (:func:`magfield.mag_status`): the output ESKF's
        learnt model when on, else the trust in the last reading; its learnt declination (on the plain
        path the multirotor hypothesis's while its attitude is output)."""
        _eskf, base = self._output_eskf()
        return mag_status(self.mag_model_state(), self._out, *declination_of(self._state, base + S_FILTER))

    def mag_delay_s(self) -> float:
        """The compass reading's delay behind the IMU's attitude the velocity-aided filter's heading update uses, s
        (learnt on a vehicle's stream, ``VEHICLE_MAG_LEARN_TAU_S``; :func:`mavahrs.filters.eskf.mag_delay_of`)."""
        return mag_delay_of(self._state, _SE + S_FILTER, self._params[_PE:])

    def mag_noise_rad(self) -> tuple[float, float]:
        """The compass heading's noise per reading the velocity-aided filter uses, rad, and its learnt lag-1
        correlation (learnt on a vehicle's stream, ``VEHICLE_MAG_NOISE_TAU_S``; :func:`mavahrs.filters.eskf.mag_noise_of`)."""
        return mag_noise_of(self._state, _SE + S_FILTER, self._params[_PE:])

    def heading_walk_rad_s(self) -> tuple[float, float]:
        """The velocity-aided filter's heading extra random walk learnt from the compass, rad/√s, and the compass
        innovations' windows' mean ψ̄²/S̄ (on a vehicle's stream, ``VEHICLE_HEADING_WALK_TAU_S``; :func:`mavahrs.filters.eskf.heading_walk_of`)."""
        return heading_walk_of(self._state, _SE + S_FILTER)

    def export_mag_model(self) -> dict[str, object] | None:
        """The velocity-aided filter's model to keep across a restart (:func:`magfield.export_model`)."""
        s = self._settings
        assert isinstance(s, BestSettings)
        if not s.eskf.mag_model.enabled:
            return None
        k = _SE + S_FILTER + MAG_MODEL_STATE
        return export_model(self._state[k : k + MF_LEN])

    def load_mag_model(self, saved: object) -> str | None:
        """Start the velocity-aided filter's model from a saved one; return why not, None when taken."""
        s = self._settings
        assert isinstance(s, BestSettings)
        if not s.eskf.mag_model.enabled:
            return "the magnetometer model is off"
        k = _SE + S_FILTER + MAG_MODEL_STATE
        return import_model(self._state[k : k + MF_LEN], s.eskf.mag_model, saved)

    def _set_eskf(self, eskf: EskfSettings, **changes: Any) -> None:
        """New settings for the ESKF part (its whole parameter block recomputed) and ``changes`` to ``best``'s."""
        s = self._settings
        assert isinstance(s, BestSettings)
        self._settings = replace(s, eskf=eskf, **changes)
        self._params[_PE : _PE + _PLE] = np.concatenate([eskf.common_params(), Eskf.filter_params(eskf)])
        if "detect" in changes:
            self._params[_DET_ON] = 1.0 if changes["detect"].enabled else 0.0
            if not changes["detect"].enabled:  # declared: one ESKF, the one just set
                self._state[_MODE] = 0.0
                self._state[_W2] = 0.0
        if "unaided_filter" in changes:
            self._params[_ESKF_ONLY] = 1.0 if changes["unaided_filter"] == "eskf" else 0.0

    def set_vehicle_stream(self) -> None:
        """The input is an autopilot's IMU stream (a vehicle): the ESKF with a vehicle's measurement models.

        Called by the pipeline when it knows the autopilot's profile: the single accelerometer
        sample as the gravity measurement and the magnetometer at most 10 Hz
        (:func:`vehicle_eskf_settings`), the ESKF's attitude in every condition.
        """
        s = self._settings
        assert isinstance(s, BestSettings)
        was_vehicle = getattr(self, "_vehicle_stream", False)
        self._vehicle_stream = True
        # an autopilot's IMU is in the body frame: the thrust axis stays the running mean (as measured)
        eskf = s.eskf
        if eskf.thrust_axis_sigma_rad > 0.0:  # set by set_multirotor() before: its drag noise undone too
            eskf = replace(eskf, thrust_axis_sigma_rad=0.0, drag_noise_m_s2=EskfSettings().drag_noise_m_s2)
        declared = getattr(self, "_declared_multirotor", None)
        if declared is not None and not was_vehicle:
            # set_multirotor() came first and gave a raw IMU's drag models (k, the body's quadratic drag, the
            # noise matched to the innovations): undone, a vehicle's are set below, whatever the calls' order
            # (:func:`multirotor_eskf_settings`; what set_sensor_delay / set_mag_reference set since is kept)
            eskf = replace(declared[1], sensor_delay_s=s.eskf.sensor_delay_s, schedule=s.eskf.schedule)
        # an autopilot's IMU is calibrated and low-passed: its first sample is the start, no start window
        # (``initial_average_s``, built for a raw IMU's vibration through the API)
        # (the attitude part of one update bounded for a while after the attitude covariance is re-opened)
        eskf = replace(eskf, initial_average_s=0.0, max_attitude_step_rad=VEHICLE_MAX_ATTITUDE_STEP_RAD,
                       max_attitude_step_window_s=VEHICLE_MAX_ATTITUDE_STEP_WINDOW_S)
        self._set_eskf(vehicle_eskf_settings(eskf), unaided_filter="eskf", detect=replace(s.detect, enabled=False))
        if declared is not None and not was_vehicle:
            self.set_multirotor(declared[0])

    def set_multirotor(self, drag_coefficient_1_s: float | None = None) -> None:
        """The vehicle is a multirotor: the ESKF with a vehicle's models and the rotor-drag measurement.

        The pipeline calls it on a multirotor's HEARTBEAT (MAV_TYPE quadrotor, hexarotor, …); a
        Python API user whose IMU flies on a multirotor calls it too (or sets
        ``BestSettings(eskf=vehicle_eskf_settings(replace(best_eskf_settings(), drag_coefficient_1_s=0.5)))``).
        Without GNSS the drag makes the velocity, hence the tilt, observable even through
        sustained manoeuvres: ArduCopter SITL without GNSS 1.41 → 0.62° mean inclination RMS
        (``docs/accuracy.md``).  ``None``: a coefficient already set, else 0.5 /s
        (``EskfSettings.drag_coefficient_1_s``).  Through the API (not an autopilot's stream:
        a raw IMU, any mounting) the thrust axis is two states of the ESKF
        (``EskfSettings.thrust_axis_sigma_rad``, 15°) and the drag noise 0.35 m/s²: the raw
        SITL set declared a multirotor 1.89 → 1.00°, its vibrating 200 Hz version 2.25 → 1.24°.
        Through the API the accelerometer's offset across the thrust axis is two constant states too
        (``MULTIROTOR_ACCEL_BIAS_SIGMA_M_S2``), estimated below ``MULTIROTOR_ACCEL_BIAS_LIVE_SPEED_M_S``, and the
        gyro bias's plausible range is a prior fused on a lasting excursion beyond it
        (``MULTIROTOR_RAW_BIAS_PRIOR_SIGMA_RAD_S`` 5 °/s after ``MULTIROTOR_RAW_BIAS_PRIOR_AFTER_S`` 2 s; a prior set in
        the settings is kept).  Started in flight, its first tilt's σ is ``MULTIROTOR_RAW_INITIAL_TILT_RAD`` (20°) and
        the accelerometer as a gravity measurement ``MULTIROTOR_RAW_GRAVITY_NOISE_M_S2`` (8 m/s²).
        """
        s = self._settings
        assert isinstance(s, BestSettings)
        if getattr(self, "_declared_multirotor", None) is None:  # the settings before it (set_vehicle_stream)
            self._declared_multirotor = (drag_coefficient_1_s, s.eskf)
        # a raw IMU through the API, any mounting: the thrust axis as two states of the error state
        # (EskfSettings.thrust_axis_sigma_rad); an autopilot's stream keeps the running mean
        if not getattr(self, "_vehicle_stream", False):
            eskf = multirotor_eskf_settings(s.eskf, drag_coefficient_1_s)
            # declared, the multirotor model is the estimator, its drag noise matched to its innovations
            # (``MULTIROTOR_DRAG_NOISE_MATCH_S``); the plain path's hypothesis keeps R as set: a model whose noise
            # grows with its misfit fits anything (BROAD raw hand-held trials taken for multirotors, 136 nats)
            if eskf.drag_noise_match_s == 0.0:
                eskf = replace(eskf, drag_noise_match_s=MULTIROTOR_DRAG_NOISE_MATCH_S)
            if eskf.slow_force_block_s == 0.0:
                eskf = replace(eskf, slow_force_block_s=MULTIROTOR_SLOW_FORCE_BLOCK_S)
            # the accelerometer's bias across the thrust axis, constant (a σ set in the settings is kept)
            sig_a = s.eskf.accel_bias_sigma_m_s2 or MULTIROTOR_ACCEL_BIAS_SIGMA_M_S2
            if sig_a > 0.0:
                # (estimated: its σ is in P, not considered beside it)
                eskf = replace(eskf, accel_bias_sigma_m_s2=sig_a, accel_bias_tau_s=0.0, accel_bias_aided_only=False,
                               accel_bias_across_thrust=True, accel_bias_consider_sigma_m_s2=0.0,
                               accel_bias_live_speed_m_s=(s.eskf.accel_bias_live_speed_m_s
                                                          or MULTIROTOR_ACCEL_BIAS_LIVE_SPEED_M_S))
            # (the start in flight and the raw gyro's bias prior are multirotor_eskf_settings' own: the plain path's
            # hypothesis has them too)
        else:
            k = drag_coefficient_1_s
            if k is None:
                k = s.eskf.drag_coefficient_1_s or MULTIROTOR_DRAG_1_S
            eskf = vehicle_eskf_settings(replace(s.eskf, drag_coefficient_1_s=float(k)))
        # declared: the multirotor hypothesis is the estimator; nothing is left to detect
        self._set_eskf(eskf, unaided_filter="eskf", detect=replace(s.detect, enabled=False))

    def multirotor_detection(self) -> dict[str, float]:
        """The plain path's choice (:class:`MultirotorDetectSettings`): whether the output is now the multirotor
        hypothesis's (``multirotor`` 0/1), the seconds it was, how often it changed, the evidence (nats) now
        and its largest, and whether detection runs at all (``enabled``)."""
        s = self._state
        return {
            "enabled": float(self._params[_DET_ON]),
            "multirotor": float(s[_MODE]),
            "seconds_as_multirotor": float(s[_T_MODE]),
            "switches": float(s[_SWITCHES]),
            "evidence_nats": float(s[_LLR]),
            "max_evidence_nats": float(s[_LLR_MAX]),
        }

    def thrust_axis(self) -> np.ndarray | None:
        """The ESKF's thrust axis (unit, IMU frame; None: not learnt, or not a multirotor)."""
        return thrust_axis_of(self._state, (_SE2 if self._state[_MODE] > 0.0 else _SE) + S_FILTER)

    def set_sensor_delay(self, delay_s: float) -> None:
        """The IMU data's delay behind its time stamps (s), for the velocity-aided filter's output and fixes."""
        s = self._settings
        assert isinstance(s, BestSettings)
        eskf = replace(s.eskf, sensor_delay_s=delay_s)
        multirotor = replace(s.multirotor_eskf, sensor_delay_s=delay_s)
        self._settings = replace(s, eskf=eskf, multirotor_eskf=multirotor)
        self._params[_PE + P_FILTER + _DELAY_OFFSET] = eskf.sensor_delay_s
        self._params[_PE2 + P_FILTER + _DELAY_OFFSET] = multirotor.sensor_delay_s





def create_best(settings: FilterSettings | None = None, **kwargs: Any) -> AttitudeFilter:
    """The recommended filter.

    ``settings``: a :class:`BestSettings`, or a :class:`MadgwickSettings` for
    the part used without velocity aiding (the rest recommended).  ``kwargs``
    are passed to the constructor (e.g. ``compiled=False``).
    """
    if isinstance(settings, MadgwickSettings):
        settings = BestSettings(madgwick=settings, max_gap_s=settings.max_gap_s,
                                eskf=replace(best_eskf_settings(), max_gap_s=settings.max_gap_s),
                                multirotor_eskf=replace(multirotor_eskf_settings(best_eskf_settings()),
                                                        max_gap_s=settings.max_gap_s))  # fmt: skip
    return Best(settings, **kwargs)
