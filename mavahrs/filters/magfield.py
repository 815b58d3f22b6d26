r"""The magnetometer model learnt in flight: body-frame offset and local earth field, and when to trust it.

An autopilot's compass reads the earth's field rotated into the body plus a
body-fixed field of the vehicle's own: hard iron, and the field of the motor
currents (ArduPilot: ``COMPASS_MOT``, proportional to the current; its
simulator: ``SIM_MAG_MOT``), which appears at take-off and changes with the
throttle.  Near the ground a field anomaly (``SIM_MAG_ALY``: steel in the
ground, a car) changes the earth field itself.  ArduPilot's EKF3 and PX4's
EKF2 carry a body-field and an earth-field state for this; this module does
the same beside the velocity-aided ESKF (:mod:`mavahrs.filters.eskf`), as a
small Kalman filter of its own that takes the ESKF's attitude and heading
variance as given (a Schmidt-style decoupling: the attitude states are not
re-estimated here).

Measurement model (body → NED rotation ``C`` of the ESKF, its magnetic-north
NED frame)::

    m = Cᵀ F + B + w,     F = (F_H, 0, F_D),     w ~ N(0, σ_m² I)

The body field is ``B = b₀ + k·I``: hard iron b₀ (µT) and the field per
ampere of battery current k (µT/A, ArduPilot's ``COMPASS_MOT``; I from
SYS_STATUS / BATTERY_STATUS, ``IN_CURRENT``; without a current only b₀).
State ``x = (b₀, k, F_H, F_D)`` (8) with covariance ``P`` (8×8).  The
residual in NED, ``r = C (m − B) − F``, is linear in the state errors,
``r = C δB + δF_H e_N + δF_D e_D + F_H δψ e_E + w`` (δ = true − estimate): a heading error δψ of the
ESKF moves the field east (by ``F_H δψ``), so the east component's noise is
``σ_m² + F_H² P_ψψ``, with ``P_ψψ`` the ESKF's heading variance; the three
components are then uncorrelated and fused one after another (Kalman, scalar
updates; Solà 2017 eq. (275)–(279) with a diagonal R):

* while the ESKF's heading is certain (gyro and GNSS hold it), the residual
  teaches the offset in all three axes (this is how EKF3 learns a motor
  field after take-off);
* while it is not, only the heading-free parts are learnt: the vertical
  component and the horizontal magnitude (the field's direction changes in
  the body as the vehicle turns, so turns make every axis observable);
* the pair update (:func:`_pair_update`) learns the field per ampere on every axis from the
  current's changes and the offset from turns without the heading, from a reading and one
  ``pair_lag_s`` earlier; near the ground (GNSS-aided height) nothing is learnt (an anomaly);
* the take-off fit (:func:`_takeoff_fit`) learns the field per ampere from the lift-off's current
  jump near the ground, against a reading held there before, with the anomaly's fade with height
  as a model term, and fuses it from 1 m up (docs/filters/magfield.md);
* the earth field starts from the World Magnetic Model (``set_mag_reference``:
  the pipeline's WMM field at the vehicle's position) with σ
  ``earth_field_sigma_ut`` — a prior, not a constraint — or, before a
  position is known, from the first reading with a wide σ.

**Disturbance.**  A reading whose residual, in any component, is beyond
``gate_sigma`` of its predicted σ does not fit the model: the vehicle's own
field has changed or the vehicle is in an earth anomaly.  The offset returns
to its prior (a calibrated compass) and the model re-learns, the ESKF's
heading variance is re-opened (the heading a disturbed compass gave may be
wrong); for ``hold_s`` the magnetometer gives no heading at all
("disturbed": the heading is held by the gyro and GNSS), then, while the
offset across the horizontal field is still uncertain, only with the noise
that uncertainty implies (σ_B⊥ / F_H rad: "learning"), and once it is known
to ``trusted_heading_sigma_rad`` the magnetometer is "trusted".

State and parameters are flat blocks inside the ESKF's (offsets ``MF_*`` and
``MP_*`` from the block's start), so the ESKF's one kernel runs it per sample
and over whole logs alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mavahrs.filters.jit import kernel
from mavahrs.filters.layout import (
    FLAG_MAG_INVALID,
    FLAG_VELOCITY_AIDED,
    OUT_FLAGS,
    OUT_HEADING_SIGMA,
    OUT_MAG_WEIGHT,
)

__all__ = [
    "MagFieldSettings",
    "MF_HEAD_SIGMA",
    "MF_LEN",
    "MF_REF_ON",
    "MP_HFACTOR",
    "MP_LEN",
    "MAG_TRUSTED",
    "MAG_LEARNING",
    "MAG_DISTURBED",
    "MAG_STATES",
    "mag_model_reset",
    "mag_model_update",
    "mag_ref_rotate",
    "mag_refs_drop",
    "magfield_params",
    "mag_model_summary",
    "mag_state_text",
    "DISTURBED_TEXT",
    "DISTURBED_GYRO_TEXT",
    "HEADING_UNKNOWN_TEXT",
    "HEADING_UNKNOWN_SIGMA_DEG",
    "mag_status",
    "export_model",
    "import_model",
]

#: what the status line, ``/status.json`` readers and the replay header say while the compass is not used
DISTURBED_TEXT = "magnetometer disturbed: heading from GNSS"

NX = 8  # b₀ (3), k (3), F_H, F_D
_FH = 6
_FD = 7

#: magnetometer states (``MF_TRUST``)
MAG_TRUSTED = 0
MAG_LEARNING = 1
MAG_DISTURBED = 2
MAG_STATES = ("trusted", "learning", "disturbed")

# state offsets
MF_X = 0  # b₀ (3) µT, k (3) µT/A, F_H, F_D µT
MF_P = MF_X + NX  # covariance NX×NX
MF_INIT = MF_P + NX * NX  # 1 once the earth field was seeded
MF_REF_NORM = MF_INIT + 1  # the WMM reference the earth field was seeded from (µT; 0 = from data)
MF_REF_DIP = MF_REF_NORM + 1
MF_T = MF_REF_DIP + 1  # clock of the last reading fused
MF_STEP_T = MF_T + 1  # clock of the last misfit (a disturbance), −1e9: none
MF_TRUST = MF_STEP_T + 1  # MAG_* of the last reading
MF_STEPS = MF_TRUST + 1  # disturbances counted
MF_HEAD_SIGMA = MF_STEPS + 1  # 1-σ heading noise the model gives the last reading, rad
MF_RESID = MF_HEAD_SIGMA + 1  # the last reading's residual in NED (3), µT
MF_HEIGHT = MF_RESID + 3  # height above the start, m (the ESKF's vertical velocity integrated while aided)
MF_HEIGHT_MIN = MF_HEIGHT + 1  # the lowest height seen, m (the ground the anomaly is in)
MF_REF_ON = MF_HEIGHT_MIN + 1  # 1: a reference reading is held for a pair (heading-free) update
MF_REF_T = MF_REF_ON + 1  # its clock, s
MF_REF_M = MF_REF_T + 1  # its reading, µT, body (3)
MF_REF_C = MF_REF_M + 3  # its C_body_to_ned transposed (9: the body axes x, y, z in NED, 3 each)
MF_REF_I = MF_REF_C + 9  # its battery current, A
MF_REF_R = MF_REF_I + 1  # its noise variance, µT²
MF_PAIRS = MF_REF_R + 1  # pair updates fused
MF_LOW = MF_PAIRS + 1  # 1 while near the ground it started on (GNSS-aided: below the height, near the start)
MF_NORTH = MF_LOW + 1  # horizontal position from where the aided track began, m (north, east)
MF_EAST = MF_NORTH + 1
#: one held reference of the pair update: on, clock, reading (3), C's columns (9), current, noise (the
#: ``MF_REF_ON`` … ``MF_REF_R`` layout); slot 0 is at ``MF_REF_ON``, the others at ``MF_XREF``
REF_LEN = 16
#: most references held at once (``MagFieldSettings.pair_references``)
PAIR_SLOTS_MAX = 8
MF_XREF = MF_EAST + 1  # references 1 … PAIR_SLOTS_MAX − 1, REF_LEN each
MF_REF_LAST = MF_XREF + (PAIR_SLOTS_MAX - 1) * REF_LEN  # clock at which the last reference was taken
# the take-off fit (:func:`_takeoff_fit`): readings near the ground against one held there before the current rose
MF_TO_ON = MF_REF_LAST + 1  # 0: no reference; 1: reference held (on the ground, current steady); 2: fitting; 3: done
MF_TO_M = MF_TO_ON + 1  # the reference reading, µT, body (3)
MF_TO_C = MF_TO_M + 3  # its C_body_to_ned transposed (9, as MF_REF_C)
MF_TO_I = MF_TO_C + 9  # its battery current, A
MF_TO_L = MF_TO_I + 1  # normal matrix HᵀH of θ = (k, a) (6×6): a = the anomaly at the ground, reference's body axes
MF_TO_ETA = MF_TO_L + 36  # Hᵀz (6)
MF_TO_ZZ = MF_TO_ETA + 6  # zᵀz
MF_TO_N = MF_TO_ZZ + 1  # scalar residuals accumulated
MF_TO_SCR = MF_TO_N + 1  # scratch (27)
TO_ACC_LEN = MF_TO_SCR - MF_TO_L  # the sums above (44), at MF_TO_L (the current as is) and MF_TO_ACC2 (later)
MF_TO_K = MF_TO_SCR + 27  # what the fit gave: k (3), its σ (3), µT/A; the residual's RMS, µT; the anomaly (3), µT
MF_TO_CAND = MF_TO_K + 10  # the next reference (a reading held TO_REF_AGE_S on the ground): m (3), C (9), I, clock
MF_TO_PEND = MF_TO_CAND + 14  # a reading waiting for the current reported after it: m (3), C (9, row-major), h, clock, held
MF_TO_ACC2 = MF_TO_PEND + 15  # the same sums (TO_ACC_LEN) with the current reported later (MP_TO_LAG)
MF_TO_HG = MF_TO_ACC2 + 44  # the take-off fit's ground: the lowest height (MF_HEIGHT) since the reference was held, m
MF_TO_CAND_H = MF_TO_HG + 1  # … and the candidate's
#: the heading variance of the corrected reading while the fitted anomaly is taken out of it (fused early, near the
#: ground: its k's σ, the anomaly's fade, the reading's noise across the field over F_H², × ``MP_HFACTOR``²), rad²;
#: 0: not in that regime (:func:`mag_model_update`)
MF_TO_HVAR = MF_TO_CAND_H + 1
MF_TO_EXIT_T = MF_TO_HVAR + 1  # clock at which the vehicle left the ground's reach (``MF_LOW`` 1 → 0), s
MF_LEN = MF_TO_EXIT_T + 1

# parameter offsets
MP_ON = 0
MP_SIGMA_M = 1  # µT
MP_B0 = 2  # initial offset σ, µT
MP_Q_B = 3  # offset random walk², µT²/s
MP_F0 = 4  # earth field σ around WMM, µT
MP_Q_F = 5  # earth field random walk², µT²/s
MP_GATE = 6
MP_STEP = 7  # µT
MP_HOLD = 8  # s
MP_TRUST_SIGMA = 9  # rad
MP_F_DATA = 10  # earth field σ when seeded from the data, µT
MP_EAST = 11  # 1: learn the offset from the ESKF's heading too (the east residual)
MP_HFACTOR = 12  # the model's heading σ is multiplied by this before the ESKF uses it
MP_K0 = 13  # initial σ of the field per ampere, µT/A
MP_Q_K = 14  # its random walk², (µT/A)²/s
MP_PAIR_LAG = 15  # s between the two readings of a pair update; 0: no pair updates
MP_PAIR_HEIGHT = 16  # m above the lowest point seen before pair updates are made
MP_GROUND_RADIUS = 17  # m: … or this far (horizontally) from where the aided track began
MP_PAIR_SLOTS = 18  # references held at once, staggered by MP_PAIR_LAG / this (1 … PAIR_SLOTS_MAX)
MP_TO_HEIGHT = 19  # the take-off fit's anomaly decay height H, m (1/8 at H); 0: no take-off fit
MP_TO_INFL = 20  # the take-off fit's variance is multiplied by this (readings correlated by the held current)
MP_TO_DONE = 21  # µT/A: the fit is fused early (from TO_EARLY_M up) once every σ of its k is below this; 0: at 5 m
MP_TO_LAG = 22  # s: the fit also with the current reported this late (the next reading's), the better kept; 0: as is
MP_TO_FADE = 23  # the fitted anomaly's fade taken as uncertain by this fraction of itself (heading noise); 0: no heading
MP_TO_AFTER = 24  # s after leaving the ground's reach that the fit's corrected reading keeps its heading weight; 0: none
MP_LEN = 25


@dataclass(frozen=True)
class MagFieldSettings:
    """Settings of the in-flight magnetometer model (:mod:`mavahrs.filters.magfield`).

    Attributes:
        enabled: learn the offset and earth field and judge each reading by
            them (False: the ESKF's former heading update, gated only by the
            gain schedule's norm and dip test).  None (the default): on for an
            autopilot's stream (:func:`mavahrs.filters.best.vehicle_eskf_settings`,
            since 2026-12-06), off otherwise (a raw IMU through the Python API,
            BROAD: there it cost the ESKF's own tests and BROAD's bounds).  On
            an autopilot's stream a reading whose norm and dip agree with the WMM's is
            used as it is (gated by the ESKF as without the model), the model's
            corrected reading serves the readings the schedule rejects, and
            only while its heading σ is within ``max_heading_sigma_rad`` = 5°.
            ArduCopter's motor-interference flight 1.76 → 0.54°, firmware_sim
            ``mag_anomaly`` seeds 3/11/5/7/19/23 within 0.03° of off or
            better (seed 19 4.13 → 3.50°), the other SITL flights unchanged,
            PX4 1.18 → 1.16°; worse on firmware_sim's ``magnetic`` seed 5
            (0.40 → 1.07°) (``docs/filters/magfield.md``).
        noise_ut: 1-σ noise of one reading per axis, µT (quantisation,
            the field's wander in a flight).
        initial_offset_ut: 1-σ of the body offset before anything is learnt,
            µT (an autopilot's compass is calibrated: what is left is small).
        offset_walk_ut_s: random walk of the body offset, µT/√s (the motor
            field follows the throttle).
        earth_field_sigma_ut: 1-σ of the World Magnetic Model's field
            (horizontal and down) as the prior of the local field, µT.
        earth_field_walk_ut_s: random walk of the local earth field, µT/√s.
        data_field_sigma_ut: 1-σ of the earth field when it is seeded from
            the first reading (no position yet), µT.
        gate_sigma: a residual beyond this many σ (any NED component) is a
            disturbance.
        step_sigma_ut: after a disturbance the offset's σ is re-opened by
            this much, µT; 0 = the offset returns to its prior (0 ±
            ``initial_offset_ut``), so that an earth-frame anomaly is not
            learnt as the vehicle's own field (the motor part is carried by
            the per-ampere term).  Measured: with 20 µT the learnt offset
            follows a ground anomaly and the heading after take-off stays
            that far off (firmware_sim mag_anomaly seed 11: 4.9° vs 3.9°).
        hold_s: after a disturbance the magnetometer gives no heading for
            this long, s.
        trusted_heading_sigma_rad: the model's heading σ below which the
            magnetometer counts as trusted (status), rad.
        learn_from_heading: also learn the offset across the horizontal
            field from the ESKF's heading (its east residual, noise
            σ_m² + F_H² P_ψψ), as EKF3 does.  Off by default: a heading taken
            from a disturbed compass (a start in a ground anomaly) would be
            learnt as right; without it that part of the offset is learnt
            from turns only (heading-free).
        heading_sigma_factor: the heading σ the offset's uncertainty implies
            is multiplied by this before the ESKF weighs the reading (the
            linearised covariance of the heading-free fit is optimistic
            while the offset is still being learnt).
        max_heading_sigma_rad: a reading whose heading σ (so scaled) is
            beyond this gives the ESKF no heading at all; after a
            disturbance the ESKF's heading variance is re-opened to at
            least this when ``reopen_heading`` (the heading a disturbed
            compass gave may be wrong).  5°: a model still learning its
            offset gives no heading (20° before: its headings pulled the
            ESKF 4–6° off for 30 s after take-off on the anomaly flights).
        motor_ut_per_a_sigma: 1-σ prior of the body field per ampere of
            battery current, µT/A (ArduPilot's simulator: 0.4–0.5 µT/A per
            axis in its magnetic flights); learnt where the stream carries a
            current (SYS_STATUS / BATTERY_STATUS, ``IN_CURRENT``).
        motor_walk_ut_per_a_s: its random walk, µT/A per √s.
        min_body_field_ut: while the learnt body field (b₀ + k·I) is below
            this, µT, the reading is used as it is, gated by the gain
            schedule's norm and dip test as without the model (a small
            learnt offset on a clean compass is mostly the fit's own error:
            measured on the clean SITL flights); a disturbance still
            withholds it.
        reopen_heading: a disturbance re-opens the ESKF's heading variance to
            ``max_heading_sigma_rad`` (the heading the disturbed compass gave
            before may be wrong: a start in a ground anomaly).  Off by
            default: on PX4's SITL flight the model's disturbances re-opened
            a heading GNSS held well (1.05° without, 1.90° with it).
        pair_lag_s: the heading-free pair update (2026-12-06, third round): a
            reading and one ``pair_lag_s`` earlier, related by the rotation
            between them that the gyro measured (the estimate's C at both times,
            whose common heading error cancels), ``m_i − R m_j = (1 − R) b₀ +
            (I_i − I_j R) k`` with ``R = C_iᵀ C_j`` — the field per ampere is
            learnt on every axis from the current's changes, the offset from
            turns, neither needing the heading (the absolute update's east
            component needs it).  0 = off.
        pair_min_height_m: pair updates only once the vehicle is this far above
            the lowest point it was seen at (the ESKF's vertical velocity
            integrated while GNSS-aided): a ground anomaly changes with height
            and would be learnt as the motors' field at take-off (the current
            jumps as the anomaly fades).  Below it nothing is learnt from a
            reading (it is only judged), and on the way up the offset and the
            earth field start again from their priors.
        ground_radius_m: … unless the vehicle is this far horizontally from
            where its GNSS-aided track began (a rover or a boat never climbs:
            away from the start it learns as before).
        pair_references: readings held at once as pair references, taken
            ``pair_lag_s`` / this apart (1 … 8): each pairs with the reading
            ``pair_lag_s`` after it, so pairs are fused this many times per
            lag (1: one pair per lag, the third round's rate — 0.5 pairs/s, the
            field per ampere learnt 7 s after take-off on ``mag_anomaly``).
        takeoff_anomaly_height_m: the take-off fit (:func:`_takeoff_fit`): near
            the ground, readings against one held there before the current rose,
            with a ground anomaly that fades as ``(H / (h + H))³`` (a dipole
            ``H`` below the ground, ArduPilot's ``SIM_MAG_ALY_HGT``; h the
            GNSS-aided height) fitted beside the field per ampere; what it gives
            of the field per ampere is fused as the vehicle leaves the ground's
            reach (``pair_min_height_m``).  This ``H``, m; 0 = no take-off fit.
        takeoff_variance_factor: the take-off fit's variance (its residuals'
            mean square over the normal matrix) is multiplied by this: the
            readings are not independent (the current is reported at 1–2 Hz and
            held, the anomaly's shape is a model).
        takeoff_done_sigma_ut_per_a: the take-off fit is fused as soon as the
            vehicle is ``TO_EARLY_M`` up and every σ of its field per ampere is
            below this, µT/A; until it leaves the ground's reach the fitted
            anomaly, faded to the height, is then taken out of the corrected
            reading too (so that it can reset an unknown heading there).
            0 = fused only on leaving the ground's reach.
        takeoff_current_lag_s: the battery current may be reported late against
            the compass: the take-off fit is made twice, with each reading's own
            current and with the current of the next reading at least half this
            later, and the one with the smaller residuals is kept (0 = only the
            first).  firmware_sim ``mag_anomaly`` seed 11: the residual's RMS is
            least with the current 0.1 s later (1.0 µT against 2.2 µT at 0), the
            field per ampere 10–30 % too large with its own; seed 19 the other
            way round.
        takeoff_fade_sigma: while the take-off fit is fused early and the vehicle is
            still near the ground, its corrected reading (the fitted anomaly faded to
            the height taken out) gives the ESKF a heading once the heading is known
            (after the reset from it), with a variance of the reading's noise, the
            fit's σ of the field per ampere times the current, and this fraction of the
            faded anomaly's part across the field (the fade's H is a guess), over F_H²,
            × ``heading_sigma_factor``²; 0 = no heading from it.  Branch anom4, with the
            reset after 0.2 s: firmware_sim ``mag_anomaly`` 18 seeds mean 1.85 → 1.76°,
            seed 11 3.04 → 2.83° (docs/accuracy.md); 0.25 … 2 within 0.01 of each other.
        takeoff_heading_after_s: … and for this long after the vehicle left the
            ground's reach (the offset taken as 0, as the reset takes it; the anomaly
            not taken out), s.  0 (default): measured worse — 10 s: seed 19 1.66 →
            2.41° (the heading drifted −1°/s for 8 s); 2 s: 19 1.83, 29 1.97, 43 2.83.
    """

    enabled: bool | None = None
    noise_ut: float = 1.0
    initial_offset_ut: float = 3.0
    offset_walk_ut_s: float = 0.05
    earth_field_sigma_ut: float = 1.0
    earth_field_walk_ut_s: float = 0.0
    data_field_sigma_ut: float = 10.0
    gate_sigma: float = 4.0
    step_sigma_ut: float = 0.0
    hold_s: float = 3.0
    trusted_heading_sigma_rad: float = math.radians(3.0)
    learn_from_heading: bool = False
    heading_sigma_factor: float = 2.0
    max_heading_sigma_rad: float = math.radians(5.0)
    motor_ut_per_a_sigma: float = 1.0
    motor_walk_ut_per_a_s: float = 0.0005
    min_body_field_ut: float = 4.0
    reopen_heading: bool = False
    pair_lag_s: float = 2.0
    pair_min_height_m: float = 5.0
    ground_radius_m: float = 10.0
    pair_references: int = PAIR_SLOTS_MAX
    takeoff_anomaly_height_m: float = 2.0
    takeoff_variance_factor: float = 10.0
    takeoff_done_sigma_ut_per_a: float = 0.05
    takeoff_current_lag_s: float = 0.1
    takeoff_fade_sigma: float = 0.5
    takeoff_heading_after_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("noise_ut", "initial_offset_ut", "earth_field_sigma_ut", "data_field_sigma_ut",
                     "gate_sigma", "trusted_heading_sigma_rad", "heading_sigma_factor",
                     "max_heading_sigma_rad", "motor_ut_per_a_sigma"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"MagFieldSettings.{name} must be a finite number > 0, got {v!r}")
        for name in ("offset_walk_ut_s", "earth_field_walk_ut_s", "hold_s", "motor_walk_ut_per_a_s", "step_sigma_ut",
                     "min_body_field_ut", "pair_lag_s", "pair_min_height_m", "ground_radius_m",
                     "takeoff_anomaly_height_m", "takeoff_done_sigma_ut_per_a", "takeoff_current_lag_s",
                     "takeoff_fade_sigma", "takeoff_heading_after_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"MagFieldSettings.{name} must be ≥ 0, got {v!r}")
        if not (math.isfinite(self.takeoff_variance_factor) and self.takeoff_variance_factor >= 1.0):
            raise ValueError(f"MagFieldSettings.takeoff_variance_factor must be ≥ 1, got {self.takeoff_variance_factor!r}")
        if not (isinstance(self.pair_references, int) and 1 <= self.pair_references <= PAIR_SLOTS_MAX):
            raise ValueError(f"MagFieldSettings.pair_references must be an integer 1 … {PAIR_SLOTS_MAX}, "
                             f"got {self.pair_references!r}")


def magfield_params(s: MagFieldSettings) -> np.ndarray:
    """The parameter block of :class:`MagFieldSettings`."""
    p = np.zeros(MP_LEN)
    p[MP_ON] = 1.0 if s.enabled else 0.0
    p[MP_SIGMA_M] = s.noise_ut
    p[MP_B0] = s.initial_offset_ut
    p[MP_Q_B] = s.offset_walk_ut_s**2
    p[MP_F0] = s.earth_field_sigma_ut
    p[MP_Q_F] = s.earth_field_walk_ut_s**2
    p[MP_GATE] = s.gate_sigma
    p[MP_STEP] = s.step_sigma_ut
    p[MP_HOLD] = s.hold_s
    p[MP_TRUST_SIGMA] = s.trusted_heading_sigma_rad
    p[MP_F_DATA] = s.data_field_sigma_ut
    p[MP_EAST] = 1.0 if s.learn_from_heading else 0.0
    p[MP_HFACTOR] = s.heading_sigma_factor
    p[MP_K0] = s.motor_ut_per_a_sigma
    p[MP_Q_K] = s.motor_walk_ut_per_a_s**2
    p[MP_PAIR_LAG] = s.pair_lag_s
    p[MP_PAIR_HEIGHT] = s.pair_min_height_m
    p[MP_GROUND_RADIUS] = s.ground_radius_m
    p[MP_PAIR_SLOTS] = s.pair_references
    p[MP_TO_HEIGHT] = s.takeoff_anomaly_height_m
    p[MP_TO_INFL] = s.takeoff_variance_factor
    p[MP_TO_DONE] = s.takeoff_done_sigma_ut_per_a
    p[MP_TO_LAG] = s.takeoff_current_lag_s
    p[MP_TO_FADE] = s.takeoff_fade_sigma
    p[MP_TO_AFTER] = s.takeoff_heading_after_s
    return p


@kernel
def mag_model_reset(s, k, p):  # type: ignore[no-untyped-def]
    """Nothing learnt: offset 0 with its prior σ, earth field not yet seeded."""
    for i in range(MF_LEN):
        s[k + i] = 0.0
    b0 = p[MP_B0] * p[MP_B0]
    k0 = p[MP_K0] * p[MP_K0]
    for i in range(3):
        s[k + MF_P + i * NX + i] = b0
        s[k + MF_P + (3 + i) * NX + 3 + i] = k0
    s[k + MF_STEP_T] = -1.0e9
    s[k + MF_TRUST] = MAG_LEARNING
    s[k + MF_HEAD_SIGMA] = math.pi


@kernel
def _seed_field(s, k, p, f_h, f_d, sigma):  # type: ignore[no-untyped-def]
    kp = k + MF_P
    for i in range(_FH, NX):
        for j in range(NX):
            s[kp + i * NX + j] = 0.0
            s[kp + j * NX + i] = 0.0
    s[k + MF_X + _FH] = f_h
    s[k + MF_X + _FD] = f_d
    s[kp + _FH * NX + _FH] = sigma * sigma
    s[kp + _FD * NX + _FD] = sigma * sigma
    s[k + MF_INIT] = 1.0


@kernel(inline=True)
def _h_row(c, j, amps, h):  # type: ignore[no-untyped-def]
    """Row j of H for z = C m = C (b₀ + k·I) + F (innovation r): (C[j, :], I·C[j, :], [j = N], [j = D])."""
    for i in range(3):
        h[i] = c[3 * j + i]
        h[3 + i] = amps * c[3 * j + i]
    h[_FH] = 1.0 if j == 0 else 0.0
    h[_FD] = 1.0 if j == 2 else 0.0


@kernel(inline=True)
def _scalar_apply(s, kx, kp, ph, po, y, sv):  # type: ignore[no-untyped-def]
    """A scalar Kalman update of the model's state at ``kx`` and covariance at ``kp`` (NX, NX×NX), given
    ``P hᵀ`` at ``ph[po:po + NX]``, the innovation y and its variance sv = h P hᵀ + r: x ← x + P hᵀ y / sv,
    P ← P − P hᵀ (P hᵀ)ᵀ / sv (Solà 2017 eq. (275)–(279))."""
    inv = 1.0 / sv
    for a in range(NX):
        s[kx + a] += ph[po + a] * inv * y
    for a in range(NX):
        for b in range(NX):
            s[kp + a * NX + b] -= ph[po + a] * inv * ph[po + b]


@kernel
def mag_model_update(s, k, p, c, mx, my, mz, amps, p_psi, stale_rad, ref_norm, ref_dip, clk, out4, h, ph, vn, ve, vd):  # type: ignore[no-untyped-def]
    """Fuse one new reading ``m`` (µT, body) into the model; return its trust (``MAG_*``).

    ``c``: C_body_to_ned (9, row-major) of the ESKF; ``p_psi``: its heading
    variance, rad²; ``ref_norm``/``ref_dip``: the WMM reference (0: none);
    ``clk``: the ESKF's clock, s.  Writes the corrected field ``m − B`` (µT,
    body) and the heading noise variance the model adds (rad²) to ``out4``;
    ``amps``: the battery current, A (NaN: not known, the per-ampere term
    is then left out); ``stale_rad``: how far the vehicle turns over the
    reading's possible age (rate × the ESKF's ``mag_staleness_s``), rad —
    the field moves by that much times its strength in every component; ``h``, ``ph``: scratch of ``NX``;
    ``vn``, ``ve``, ``vd``: the ESKF's NED velocity, m/s, NaN while not GNSS-aided (the height and the
    distance from the start: near the ground it started on nothing is learnt, no pair update).
    """
    amps_known = math.isfinite(amps)  # NaN or ±inf (a corrupt current reading): not known
    if not amps_known:
        amps = 0.0
    kx = k + MF_X
    kp = k + MF_P
    m_norm = math.sqrt(mx * mx + my * my + mz * mz)
    sig_m2 = p[MP_SIGMA_M] * p[MP_SIGMA_M] + (stale_rad * m_norm) ** 2
    # ---- the earth field's prior: WMM when known (again when it changes), else the first reading
    if ref_norm > 0.0 and (ref_norm != s[k + MF_REF_NORM] or ref_dip != s[k + MF_REF_DIP]):
        if s[k + MF_REF_NORM] == 0.0 and s[k + MF_INIT] > 0.0:
            # the offset learnt so far was against a field seeded from the data: start it again (the field
            # per ampere is kept: before a position is known the vehicle is on the ground, its current ~0)
            for i in range(3):
                s[kx + i] = 0.0
                for j in range(NX):
                    s[kp + i * NX + j] = 0.0
                    s[kp + j * NX + i] = 0.0
                s[kp + i * NX + i] = p[MP_B0] * p[MP_B0] if i < 3 else p[MP_K0] * p[MP_K0]
        _seed_field(s, k, p, ref_norm * math.cos(ref_dip), ref_norm * math.sin(ref_dip), p[MP_F0])
        s[k + MF_REF_NORM] = ref_norm
        s[k + MF_REF_DIP] = ref_dip
    if s[k + MF_INIT] == 0.0:
        bx, by, bz = mx - s[kx] - amps * s[kx + 3], my - s[kx + 1] - amps * s[kx + 4], mz - s[kx + 2] - amps * s[kx + 5]
        nn = c[0] * bx + c[1] * by + c[2] * bz
        ne = c[3] * bx + c[4] * by + c[5] * bz
        nd = c[6] * bx + c[7] * by + c[8] * bz
        _seed_field(s, k, p, math.sqrt(nn * nn + ne * ne), nd, p[MP_F_DATA])
        s[k + MF_T] = clk
    # ---- process noise since the last reading
    dt = clk - s[k + MF_T]
    if vd == vd and dt > 0.0:
        s[k + MF_HEIGHT] -= vd * min(dt, 1.0)
        if s[k + MF_HEIGHT] < s[k + MF_HEIGHT_MIN]:
            s[k + MF_HEIGHT_MIN] = s[k + MF_HEIGHT]
        if vn == vn and ve == ve:
            s[k + MF_NORTH] += vn * min(dt, 1.0)
            s[k + MF_EAST] += ve * min(dt, 1.0)
    if dt > 0.0:
        if dt > 10.0:
            dt = 10.0
        for i in range(3):
            s[kp + i * NX + i] += p[MP_Q_B] * dt
            s[kp + (3 + i) * NX + 3 + i] += p[MP_Q_K] * dt
        for i in range(_FH, NX):
            s[kp + i * NX + i] += p[MP_Q_F] * dt
    s[k + MF_T] = clk
    # below the pair updates' height (GNSS-aided: the height is known) nothing is learnt from the
    # reading, it is only judged (fits or disturbed): at take-off a ground anomaly fades as the current
    # jumps, and each disturbance's re-opened offset passed part of it to the earth field (firmware_sim
    # mag_anomaly seed 29: the field down 14 µT off after take-off) and to the field per ampere; once
    # above, the offset and the earth field start again from their priors (the WMM's)
    learn = True
    if p[MP_PAIR_LAG] > 0.0 and vd == vd:
        if _near_start(s, k, p):
            learn = False
            s[k + MF_LOW] = 1.0
            if amps_known and p[MP_TO_HEIGHT] > 0.0:
                _takeoff_fit(s, k, p, c, mx, my, mz, amps, clk)
        elif s[k + MF_LOW] > 0.0:
            s[k + MF_LOW] = 0.0
            for i in range(3):
                s[kx + i] = 0.0
                for j in range(NX):
                    s[kp + i * NX + j] = 0.0
                    s[kp + j * NX + i] = 0.0
                s[kp + i * NX + i] = p[MP_B0] * p[MP_B0]
            if s[k + MF_REF_NORM] > 0.0:
                _seed_field(s, k, p, s[k + MF_REF_NORM] * math.cos(s[k + MF_REF_DIP]),
                            s[k + MF_REF_NORM] * math.sin(s[k + MF_REF_DIP]), p[MP_F0])  # fmt: skip
            if s[k + MF_TO_ON] == 2.0:
                _takeoff_fuse(s, k, p)
            s[k + MF_TO_ON] = 3.0
            s[k + MF_TO_EXIT_T] = clk
    f_h = s[kx + _FH]
    pp = max(p_psi, 0.0)
    r_e = sig_m2 + f_h * f_h * pp
    # the north residual is heading-free only to first order: F_H (1 − cos δψ) has variance ≈ F_H² P_ψψ² / 2
    r_n = sig_m2 + 0.5 * f_h * f_h * pp * pp
    # ---- does the reading fit? (every component against its predicted σ)
    gate = p[MP_GATE]
    fits = True
    for j in range(3):
        _h_row(c, j, amps, h)
        y = _residual(s, kx, c, mx, my, mz, amps, j)
        s[k + MF_RESID + j] = y
        if j == 1 and p[MP_EAST] == 0.0:
            continue
        sv = r_e if j == 1 else (r_n if j == 0 else sig_m2)
        for a in range(NX):
            acc = 0.0
            for b in range(NX):
                acc += s[kp + a * NX + b] * h[b]
            sv += h[a] * acc
        if y * y > gate * gate * sv:
            fits = False
    if not fits:
        # the vehicle's own field changed (or an anomaly): re-open the offset and re-learn
        st = p[MP_STEP] * p[MP_STEP]
        for i in range(3):
            if p[MP_STEP] > 0.0:
                s[kp + i * NX + i] += st
            else:  # back to the calibrated compass's prior: an earth-frame anomaly is not learnt as the vehicle's
                s[kx + i] = 0.0
                for j in range(NX):
                    s[kp + i * NX + j] = 0.0
                    s[kp + j * NX + i] = 0.0
                s[kp + i * NX + i] = p[MP_B0] * p[MP_B0]
        s[k + MF_STEP_T] = clk
        s[k + MF_STEPS] += 1.0
    # ---- the heading-free pair update (this reading against one ``MP_PAIR_LAG`` earlier)
    _pair_update(s, k, p, c, mx, my, mz, amps, sig_m2, clk, vd, h, ph)
    # ---- sequential scalar updates (R diagonal in NED)
    for j in range(3):
        if (j == 1 and p[MP_EAST] == 0.0) or not learn:
            continue
        _h_row(c, j, amps, h)
        y = _residual(s, kx, c, mx, my, mz, amps, j)
        sv = r_e if j == 1 else (r_n if j == 0 else sig_m2)
        for a in range(NX):
            acc = 0.0
            for b in range(NX):
                acc += s[kp + a * NX + b] * h[b]
            ph[a] = acc
            sv += h[a] * acc
        if not (sv > 0.0):
            continue
        lim = gate * math.sqrt(sv)  # a residual beyond the gate teaches at most the gate's worth (Huber)
        if y > lim:
            y = lim
        elif y < -lim:
            y = -lim
        _scalar_apply(s, kx, kp, ph, 0, y, sv)
    for a in range(NX):  # symmetric
        for b in range(a + 1, NX):
            v = 0.5 * (s[kp + a * NX + b] + s[kp + b * NX + a])
            s[kp + a * NX + b] = v
            s[kp + b * NX + a] = v
    out4[0] = mx - s[kx] - amps * s[kx + 3]
    out4[1] = my - s[kx + 1] - amps * s[kx + 4]
    out4[2] = mz - s[kx + 2] - amps * s[kx + 5]
    if s[k + MF_TO_ON] == 4.0 and s[k + MF_LOW] > 0.0:
        # fused early, still near the ground: the fitted anomaly faded to this height, R â s(h), R = Cᵀ C_g
        hh = p[MP_TO_HEIGHT]
        sc = (hh / (max(s[k + MF_HEIGHT] - s[k + MF_TO_HG], 0.0) + hh)) ** 3
        kr = k + MF_TO_C
        ka = k + MF_TO_K + 7
        for a in range(3):
            acc = 0.0
            for b in range(3):
                acc += (c[a] * s[kr + 3 * b] + c[3 + a] * s[kr + 3 * b + 1] + c[6 + a] * s[kr + 3 * b + 2]) * s[ka + b]
            out4[a] -= sc * acc
        # … and what that corrected reading's heading is worth (rad²): across the field (east in the model's
        # frame) the field per ampere's σ times the current, the reading's noise, and the fade's model error
        # (``MP_TO_FADE`` of the faded anomaly's east part C_g â s(h): H is a fixed guess, the anomaly's own
        # height is not known), over F_H² (as ``head_var`` below), × ``MP_HFACTOR``²
        kk = k + MF_TO_K
        var_e = sig_m2
        a_e = 0.0
        for i in range(3):
            var_e += (c[3 + i] * amps * s[kk + 3 + i]) ** 2
            a_e += s[kr + 3 * i + 1] * s[ka + i]
        var_e += (p[MP_TO_FADE] * sc * a_e) ** 2
        f_h = s[kx + _FH]
        if p[MP_TO_FADE] > 0.0 and f_h > 1.0:
            s[k + MF_TO_HVAR] = var_e / (f_h * f_h) * p[MP_HFACTOR] * p[MP_HFACTOR]
        else:
            s[k + MF_TO_HVAR] = 0.0
    elif s[k + MF_TO_ON] == 3.0 and p[MP_TO_FADE] > 0.0 and clk - s[k + MF_TO_EXIT_T] < p[MP_TO_AFTER]:
        # just above the ground's reach, the fit fused (k known to ``MP_TO_DONE``): the anomaly has faded, the
        # offset b₀ starts again from its prior (its σ keeps the model's own heading σ at 7–8°, no heading for
        # 5–8 s); the corrected reading keeps the weight it had below, b₀ taken as the calibrated compass's
        # (0), as the heading reset from it does: the reading's noise and the field per ampere's σ
        kk = k + MF_TO_K
        var_e = sig_m2
        known = True
        for i in range(3):
            known = known and 0.0 < s[kk + 3 + i] <= max(p[MP_TO_DONE], TO_KNOWN_K)
            var_e += (c[3 + i] * amps * s[kk + 3 + i]) ** 2
        f_h = s[kx + _FH]
        s[k + MF_TO_HVAR] = var_e / (f_h * f_h) * p[MP_HFACTOR] * p[MP_HFACTOR] if known and f_h > 1.0 else 0.0
    else:
        s[k + MF_TO_HVAR] = 0.0
    # heading noise from the offset left unknown across the horizontal field (east in the estimate's frame)
    _h_row(c, 1, amps, h)
    var_e = 0.0
    for a in range(6):
        acc = 0.0
        for b in range(6):
            acc += s[kp + a * NX + b] * h[b]
        var_e += h[a] * acc
    f_h = s[kx + _FH]
    head_var = var_e / (f_h * f_h) if f_h > 1.0 else 1.0e6
    out4[3] = head_var * p[MP_HFACTOR] * p[MP_HFACTOR]
    s[k + MF_HEAD_SIGMA] = math.sqrt(head_var)
    if clk - s[k + MF_STEP_T] < p[MP_HOLD]:
        trust = MAG_DISTURBED
    elif math.sqrt(head_var) > p[MP_TRUST_SIGMA]:
        trust = MAG_LEARNING
    else:
        trust = MAG_TRUSTED
    s[k + MF_TRUST] = trust
    return trust


@kernel
def mag_ref_rotate(s, k, rx, ry, rz, d_old, d_new):  # type: ignore[no-untyped-def]
    """Move the pair update's reference attitude with the estimate's frame (as the ESKF's stored NED
    vectors move): the ESKF corrected its attitude by δθ = (rx, ry, rz) (C ← Exp(δθ) C) and its
    declination correction from ``d_old`` to ``d_new`` (the model's frame is C rotated by it), so that
    ``R = C_iᵀ C_j`` stays the rotation the vehicle made, not the corrections GNSS made in between
    (a heading corrected by 2° within the pair's 2 s moves a 23 µT field by 0.8 µT)."""
    ang = math.sqrt(rx * rx + ry * ry + rz * rz)
    ca, sa = math.cos(ang), math.sin(ang)
    ux, uy, uz = (rx / ang, ry / ang, rz / ang) if ang > 0.0 else (0.0, 0.0, 1.0)
    co, so = math.cos(d_old), math.sin(d_old)
    cn, sn = math.cos(d_new), math.sin(d_new)
    for j in range(PAIR_SLOTS_MAX + 2):  # the pair references, then the take-off fit's reference and candidate
        ks = _slot(k, j) if j < PAIR_SLOTS_MAX else k + MF_TO_ON
        if s[ks] == 0.0 or (j >= PAIR_SLOTS_MAX and s[ks] == 3.0):
            continue
        if j < PAIR_SLOTS_MAX:
            kr = ks + (MF_REF_C - MF_REF_ON)
        else:
            kr = k + MF_TO_C if j == PAIR_SLOTS_MAX else k + MF_TO_CAND + 3
        for b in range(3):
            v0, v1, v2 = s[kr + 3 * b], s[kr + 3 * b + 1], s[kr + 3 * b + 2]
            # out of the model's frame (D_oldᵀ), rotated (Rodrigues), into the new one (D_new)
            a0, a1, a2 = co * v0 - so * v1, so * v0 + co * v1, v2
            dot = ux * a0 + uy * a1 + uz * a2
            b0 = a0 * ca + (uy * a2 - uz * a1) * sa + ux * dot * (1.0 - ca)
            b1 = a1 * ca + (uz * a0 - ux * a2) * sa + uy * dot * (1.0 - ca)
            b2 = a2 * ca + (ux * a1 - uy * a0) * sa + uz * dot * (1.0 - ca)
            s[kr + 3 * b] = cn * b0 + sn * b1
            s[kr + 3 * b + 1] = -sn * b0 + cn * b1
            s[kr + 3 * b + 2] = b2


@kernel(inline=True)
def _slot(k, j):  # type: ignore[no-untyped-def]
    """Start of pair reference ``j`` (``REF_LEN`` values, laid out as ``MF_REF_ON`` … ``MF_REF_R``)."""
    return k + MF_REF_ON if j == 0 else k + MF_XREF + (j - 1) * REF_LEN


@kernel
def mag_refs_drop(s, k):  # type: ignore[no-untyped-def]
    """Drop every held pair reference (their attitudes were held in a heading since reset)."""
    for j in range(PAIR_SLOTS_MAX):
        s[_slot(k, j)] = 0.0


@kernel(inline=True)
def _near_start(s, k, p):  # type: ignore[no-untyped-def]
    """Near the ground the vehicle started on: below ``MP_PAIR_HEIGHT`` above the lowest point seen and
    within ``MP_GROUND_RADIUS`` of where the aided track began (a ground anomaly's reach)."""
    dn, de = s[k + MF_NORTH], s[k + MF_EAST]
    return (
        s[k + MF_HEIGHT] - s[k + MF_HEIGHT_MIN] < p[MP_PAIR_HEIGHT]
        and dn * dn + de * de < p[MP_GROUND_RADIUS] * p[MP_GROUND_RADIUS]
    )


@kernel
def _pair_update(s, k, p, c, mx, my, mz, amps, sig_m2, clk, vd, h, ph):  # type: ignore[no-untyped-def]
    """Fuse the reading with every reference held ``MP_PAIR_LAG`` s earlier, then hold this one as a
    reference if the last was taken ``MP_PAIR_LAG`` / ``MP_PAIR_SLOTS`` ago or more (so that pairs come
    ``MP_PAIR_SLOTS`` times per lag, each reading in at most two pairs: once as the later, once as
    the reference).

    The earth field in the body at both times, ``e = m − b₀ − k·I``, is related by the rotation the
    vehicle made in between, ``e_i = R e_j`` with ``R = C_iᵀ C_j`` (the estimate's attitudes: a heading
    error common to both cancels), so ``z = m_i − R m_j = (1 − R) b₀ + (I_i·1 − I_j·R) k + w`` with
    ``w ~ N(0, (σ_i² + σ_j²) I)`` (R is a rotation: the noise stays isotropic and the three components
    independent; sequential scalar updates, Solà 2017 eq. (275)–(279)).  The current's changes teach
    k on every axis, turns teach b₀, without the heading; an anomaly that changes with height does
    not fit it, hence only above ``MP_PAIR_HEIGHT``.  A pair beyond the gate in any component is dropped.
    """
    lag = p[MP_PAIR_LAG]
    if not (lag > 0.0):
        return
    ok = vd == vd and not _near_start(s, k, p)
    if not ok:
        mag_refs_drop(s, k)
        return
    n = min(max(int(p[MP_PAIR_SLOTS]), 1), PAIR_SLOTS_MAX)
    free = -1
    for j in range(n):
        ks = _slot(k, j)
        if s[ks] > 0.0 and clk - s[ks + 1] > 3.0 * lag:
            s[ks] = 0.0  # a gap: the reference is too old
        if s[ks] > 0.0 and clk - s[ks + 1] >= lag:
            if _pair_fuse(s, k, p, ks, c, mx, my, mz, amps, sig_m2, h, ph):
                s[k + MF_PAIRS] += 1.0
            s[ks] = 0.0
        if s[ks] == 0.0 and free < 0:
            free = j
    if free >= 0 and (clk - s[k + MF_REF_LAST] >= lag / n or clk < s[k + MF_REF_LAST]):
        ks = _slot(k, free)
        s[ks] = 1.0
        s[ks + 1] = clk
        s[ks + 2] = mx
        s[ks + 3] = my
        s[ks + 4] = mz
        kr = ks + (MF_REF_C - MF_REF_ON)
        for b in range(3):
            for q in range(3):
                s[kr + 3 * b + q] = c[3 * q + b]
        s[ks + (MF_REF_I - MF_REF_ON)] = amps
        s[ks + (MF_REF_R - MF_REF_ON)] = sig_m2
        s[k + MF_REF_LAST] = clk


@kernel
def _pair_fuse(s, k, p, ks, c, mx, my, mz, amps, sig_m2, h, ph):  # type: ignore[no-untyped-def]
    """The pair update of the reading against the reference at ``ks`` (:func:`_pair_update`); False
    (and nothing fused) when the pair is beyond the gate in any component."""
    kx = k + MF_X
    kp = k + MF_P
    kr = ks + (MF_REF_C - MF_REF_ON)
    km = ks + (MF_REF_M - MF_REF_ON)
    ij = s[ks + (MF_REF_I - MF_REF_ON)]
    sv0 = sig_m2 + s[ks + (MF_REF_R - MF_REF_ON)]
    gate = p[MP_GATE]
    fits = True
    for rnd in range(2):  # 0: the gate on every component; 1: the updates
        if rnd == 1 and not fits:
            break
        for a in range(3):
            # row a of R = C_iᵀ C_j, and z_a = m_a − (R m_j)_a
            r0 = c[a] * s[kr + 0] + c[3 + a] * s[kr + 1] + c[6 + a] * s[kr + 2]
            r1 = c[a] * s[kr + 3] + c[3 + a] * s[kr + 4] + c[6 + a] * s[kr + 5]
            r2 = c[a] * s[kr + 6] + c[3 + a] * s[kr + 7] + c[6 + a] * s[kr + 8]
            ma = mx if a == 0 else (my if a == 1 else mz)
            z = ma - (r0 * s[km] + r1 * s[km + 1] + r2 * s[km + 2])
            h[0] = (1.0 if a == 0 else 0.0) - r0
            h[1] = (1.0 if a == 1 else 0.0) - r1
            h[2] = (1.0 if a == 2 else 0.0) - r2
            h[3] = (amps if a == 0 else 0.0) - ij * r0
            h[4] = (amps if a == 1 else 0.0) - ij * r1
            h[5] = (amps if a == 2 else 0.0) - ij * r2
            h[_FH] = 0.0
            h[_FD] = 0.0
            y = z
            for b in range(6):
                y -= h[b] * s[kx + b]
            sv = sv0
            for b in range(6):
                acc = 0.0
                for e in range(6):
                    acc += s[kp + b * NX + e] * h[e]
                sv += h[b] * acc
            if rnd == 0:
                if y * y > gate * gate * sv:
                    fits = False
                continue
            for b in range(NX):
                acc = 0.0
                for e in range(6):
                    acc += s[kp + b * NX + e] * h[e]
                ph[b] = acc
            _scalar_apply(s, kx, kp, ph, 0, y, sv)
    return fits


#: the take-off fit: within this height of the lowest point seen the vehicle is on the ground, m
TO_GROUND_M = 0.3
#: … and its current steady while within this of the reference's, A (the reference follows the readings)
TO_STEADY_A = 2.0
#: the reference is a reading at least this old, s: the current is reported late (SYS_STATUS / BATTERY_STATUS,
#: 1–10 Hz, held) — firmware_sim ``mag_anomaly``: the motors' field in the readings 0.1 s before the current
#: that drives it; a reference taken then was 20 µT off its current
TO_REF_AGE_S = 1.0
#: the take-off fit is not fused before the vehicle is this high, m (the anomaly's fade must have begun to tell it
#: from the current's jump)
TO_EARLY_M = 1.0
#: a field per ampere known to this σ on every axis, µT/A, is not overridden by the take-off fit (a saved model:
#: its k pulled 0.05 µT/A off by the fit, the heading 4.5° off at 13–14 s against 0.9° without the fit)
TO_KNOWN_K = 0.06
#: weak priors that keep the take-off fit's normal matrix invertible: σ of k, µT/A, and of the anomaly, µT
TO_PRIOR_K = 10.0
TO_PRIOR_A = 100.0


@kernel
def _takeoff_fit(s, k, p, c, mx, my, mz, amps, clk):  # type: ignore[no-untyped-def]
    """Near the ground (``_near_start``): accumulate the take-off fit's normal equations.

    On the ground with a steady current the latest reading is held as the reference ``m_g`` (current
    ``I_g``, attitude ``C_g``); once the current moves away from it or the vehicle rises, every reading
    is compared with it, as in the pair update but with the ground anomaly's change as a model term:
    the anomaly ``A`` (earth-fixed) fades with the height h as ``s(h) = (H / (h + H))³`` (a dipole H
    below the ground: ArduPilot's ``SIM_MAG_ALY_HGT``), so with ``R = Cᵀ C_g`` and ``a = C_gᵀ A``::

        z = m − R m_g − (1 − R) b₀ = (I·1 − I_g R) k + (s(h) − 1) R a + w

    linear in θ = (k, a): HᵀH and Hᵀz are summed (least squares, unit weights) and solved once when the
    vehicle leaves the ground's reach (:func:`_takeoff_fuse`).  The current's jump at lift-off comes
    before the height (the anomaly barely changed), the climb then fades the anomaly: the two are told
    apart, and k is known within 0.05 µT/A 2 s after lift-off on firmware_sim ``mag_anomaly`` for any
    H of 1–5 m (true 3), where without the anomaly term it is 0.1–0.2 µT/A off (docs/filters/magfield.md).
    """
    st = s[k + MF_TO_ON]
    hgt = s[k + MF_HEIGHT] - s[k + MF_HEIGHT_MIN]
    kc = k + MF_TO_CAND
    if st == 1.0 or st == 2.0 or st == 4.0:
        s[k + MF_TO_HG] = min(s[k + MF_TO_HG], s[k + MF_HEIGHT])
    steady = hgt < TO_GROUND_M and abs(amps - s[kc + 12]) < TO_STEADY_A
    if st == 4.0 and hgt >= TO_GROUND_M:
        return  # fused early: the anomaly is taken out of the corrected reading until the vehicle leaves
    if st == 0.0 or st >= 3.0 or (st == 1.0 and steady):
        # on the ground, the current steady: the reference is the candidate once that is TO_REF_AGE_S old
        # (and both were steady since), the candidate this reading
        if st == 1.0 and clk - s[kc + 13] >= TO_REF_AGE_S:
            for i in range(13):
                s[k + MF_TO_M + i] = s[kc + i]
            s[k + MF_TO_HG] = s[k + MF_TO_CAND_H]
        if st != 1.0 or clk - s[kc + 13] >= TO_REF_AGE_S:
            s[kc] = mx
            s[kc + 1] = my
            s[kc + 2] = mz
            for b in range(3):
                for q in range(3):
                    s[kc + 3 + 3 * b + q] = c[3 * q + b]
            s[kc + 12] = amps
            s[kc + 13] = clk
            s[k + MF_TO_CAND_H] = s[k + MF_HEIGHT]
        if st != 1.0:
            for i in range(13):
                s[k + MF_TO_M + i] = s[kc + i]
            s[k + MF_TO_HG] = s[k + MF_TO_CAND_H]
        s[k + MF_TO_ON] = 1.0
        for i in range(TO_ACC_LEN):
            s[k + MF_TO_L + i] = 0.0
            s[k + MF_TO_ACC2 + i] = 0.0
        s[k + MF_TO_PEND + 14] = 0.0
        return
    s[k + MF_TO_ON] = 2.0
    kq = k + MF_TO_PEND
    # the anomaly's fade is a function of the height above the ground the vehicle lifted off from: the lowest
    # height since the reference was held there (on the ground until lift-off), not the lowest seen since the
    # start: the integrated velocity wanders as the vehicle waits, and that minimum can lie well below the
    # ground it lifts off from (firmware_sim mag_anomaly seed 41: 0.18 m by lift-off, s(h) 0.77 on the ground,
    # k 20–30 % too large); since the reference, the velocity's drift adds only over 1–2 s, and a downward drift
    # (with the receiver's velocity only, no vertical component: 0.6 m/s) ends where the climb begins
    hgt = max(s[k + MF_HEIGHT] - s[k + MF_TO_HG], 0.0)
    _takeoff_add(s, k, p, k + MF_TO_L, c, 0, mx, my, mz, hgt, amps)
    if p[MP_TO_LAG] > 0.0:
        # … and the current reported late: the reading held, and fitted with the next reading's current
        if s[kq + 14] > 0.0 and clk - s[kq + 13] >= 0.5 * p[MP_TO_LAG]:
            _takeoff_add(s, k, p, k + MF_TO_ACC2, s, kq + 3, s[kq], s[kq + 1], s[kq + 2], s[kq + 12], amps)
            s[kq + 14] = 0.0
        if s[kq + 14] == 0.0:
            s[kq] = mx
            s[kq + 1] = my
            s[kq + 2] = mz
            for i in range(9):
                s[kq + 3 + i] = c[i]
            s[kq + 12] = hgt
            s[kq + 13] = clk
            s[kq + 14] = 1.0
    if p[MP_TO_DONE] > 0.0 and hgt >= TO_EARLY_M and _takeoff_solve_best(s, k, p):
        kk = k + MF_TO_K
        if max(s[kk + 3], max(s[kk + 4], s[kk + 5])) <= p[MP_TO_DONE]:
            _takeoff_fuse(s, k, p)
            s[k + MF_TO_ON] = 4.0


@kernel
def _takeoff_add(s, k, p, ka, ca, co, mx, my, mz, hgt, amps):  # type: ignore[no-untyped-def]
    """One reading (µT, body; its C_body_to_ned row-major at ``ca[co:co + 9]``, its height h) with the
    current ``amps`` into the take-off fit's normal equations at ``ka`` (:func:`_takeoff_fit`)."""
    hh = p[MP_TO_HEIGHT]
    sc = (hh / (max(hgt, 0.0) + hh)) ** 3 - 1.0
    ig = s[k + MF_TO_I]
    kr = k + MF_TO_C
    kx = k + MF_X
    kl = ka
    ke = ka + (MF_TO_ETA - MF_TO_L)
    kh = k + MF_TO_SCR  # H's row (6)
    for a in range(3):
        r0 = ca[co + a] * s[kr + 0] + ca[co + 3 + a] * s[kr + 1] + ca[co + 6 + a] * s[kr + 2]
        r1 = ca[co + a] * s[kr + 3] + ca[co + 3 + a] * s[kr + 4] + ca[co + 6 + a] * s[kr + 5]
        r2 = ca[co + a] * s[kr + 6] + ca[co + 3 + a] * s[kr + 7] + ca[co + 6 + a] * s[kr + 8]
        ma = mx if a == 0 else (my if a == 1 else mz)
        z = ma - (r0 * s[k + MF_TO_M] + r1 * s[k + MF_TO_M + 1] + r2 * s[k + MF_TO_M + 2])
        # the offset's part (1 − R) b₀, with the model's b₀
        z -= s[kx + a] - (r0 * s[kx] + r1 * s[kx + 1] + r2 * s[kx + 2])
        s[kh + 0] = (amps if a == 0 else 0.0) - ig * r0
        s[kh + 1] = (amps if a == 1 else 0.0) - ig * r1
        s[kh + 2] = (amps if a == 2 else 0.0) - ig * r2
        s[kh + 3] = sc * r0
        s[kh + 4] = sc * r1
        s[kh + 5] = sc * r2
        for i in range(6):
            s[ke + i] += s[kh + i] * z
            for j in range(6):
                s[kl + 6 * i + j] += s[kh + i] * s[kh + j]
        s[ka + (MF_TO_ZZ - MF_TO_L)] += z * z
        s[ka + (MF_TO_N - MF_TO_L)] += 1.0


@kernel(inline=True)
def _inv3(s, src, stride, dst):  # type: ignore[no-untyped-def]
    """``s[dst:dst+9]`` = the inverse of the 3×3 matrix at ``s[src]`` (rows ``stride`` apart); its determinant."""
    a, b, c = s[src], s[src + 1], s[src + 2]
    d, e, f = s[src + stride], s[src + stride + 1], s[src + stride + 2]
    g, h, i = s[src + 2 * stride], s[src + 2 * stride + 1], s[src + 2 * stride + 2]
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if not (abs(det) > 0.0):
        return 0.0
    inv = 1.0 / det
    s[dst + 0] = (e * i - f * h) * inv
    s[dst + 1] = (c * h - b * i) * inv
    s[dst + 2] = (b * f - c * e) * inv
    s[dst + 3] = (f * g - d * i) * inv
    s[dst + 4] = (a * i - c * g) * inv
    s[dst + 5] = (c * d - a * f) * inv
    s[dst + 6] = (d * h - e * g) * inv
    s[dst + 7] = (b * g - a * h) * inv
    s[dst + 8] = (a * e - b * d) * inv
    return det


@kernel
def _takeoff_solve(s, k, p, ka):  # type: ignore[no-untyped-def]
    """Solve the take-off fit (:func:`_takeoff_fit`): k̂, its σ, the residuals' RMS and the anomaly â into
    ``MF_TO_K`` (the scratch keeps D⁻¹ at 9 and (A − B D⁻¹ Bᵀ)⁻¹ at 18); False if it cannot be solved.

    With the normal matrix ``[[A, B], [Bᵀ, D]]`` of θ = (k, a) (weak priors added), k's estimate and
    covariance are the Schur complement's: ``Σ_k = σ̂² (A − B D⁻¹ Bᵀ)⁻¹`` and
    ``k̂ = Σ_k/σ̂² (η_k − B D⁻¹ η_a)``, σ̂² the residuals' mean square (at least the reading noise's),
    times ``MP_TO_INFL`` (the readings are not independent); ``â = D⁻¹ (η_a − Bᵀ k̂)``."""
    n = s[ka + (MF_TO_N - MF_TO_L)]
    if n < 30.0:
        return False
    kl = ka
    ke = ka + (MF_TO_ETA - MF_TO_L)
    ks = k + MF_TO_SCR
    for i in range(3):
        for j in range(3):
            s[ks + 3 * i + j] = s[kl + 6 * (3 + i) + 3 + j] + (1.0 / (TO_PRIOR_A * TO_PRIOR_A) if i == j else 0.0)
    if _inv3(s, ks, 3, ks + 9) == 0.0:  # D⁻¹ → scr[9:18]
        return False
    # M = A − B D⁻¹ Bᵀ → scr[0:9], its inverse → scr[18:27]
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for u in range(3):
                for v in range(3):
                    acc += s[kl + 6 * i + 3 + u] * s[ks + 9 + 3 * u + v] * s[kl + 6 * j + 3 + v]
            prior = 1.0 / (TO_PRIOR_K * TO_PRIOR_K) if i == j else 0.0
            s[ks + 3 * i + j] = s[kl + 6 * i + j] + prior - acc
    if _inv3(s, ks, 3, ks + 18) == 0.0:
        return False
    kk = k + MF_TO_K
    for i in range(3):  # g = η_k − B D⁻¹ η_a, for now in σ's slots
        acc = s[ke + i]
        for u in range(3):
            for v in range(3):
                acc -= s[kl + 6 * i + 3 + u] * s[ks + 9 + 3 * u + v] * s[ke + 3 + v]
        s[kk + 3 + i] = acc
    for i in range(3):
        s[kk + i] = s[ks + 18 + 3 * i] * s[kk + 3] + s[ks + 18 + 3 * i + 1] * s[kk + 4] + s[ks + 18 + 3 * i + 2] * s[kk + 5]
    # â = D⁻¹ (η_a − Bᵀ k̂); the residuals' sum of squares zᵀz − θ̂ᵀη
    rss = s[ka + (MF_TO_ZZ - MF_TO_L)]
    for i in range(3):
        rss -= s[kk + i] * s[ke + i]
    for i in range(3):
        acc = 0.0
        for v in range(3):
            w = s[ke + 3 + v]
            for u in range(3):
                w -= s[kl + 6 * u + 3 + v] * s[kk + u]
            acc += s[ks + 9 + 3 * i + v] * w
        s[kk + 7 + i] = acc
    for i in range(3):
        rss -= s[kk + 7 + i] * s[ke + 3 + i]
    ms = max(rss / max(n - 6.0, 1.0), 0.0)
    s[kk + 6] = math.sqrt(ms)
    var = max(ms, p[MP_SIGMA_M] * p[MP_SIGMA_M]) * p[MP_TO_INFL]
    for i in range(3):
        s[kk + 3 + i] = math.sqrt(max(var * s[ks + 18 + 4 * i], 0.0))
    return True


@kernel
def _takeoff_solve_best(s, k, p):  # type: ignore[no-untyped-def]
    """:func:`_takeoff_solve` with the current as reported and, where ``MP_TO_LAG`` > 0, with the current
    reported after the reading: the one whose residuals are the smaller is left in ``MF_TO_K``."""
    ok0 = _takeoff_solve(s, k, p, k + MF_TO_L)
    if not (p[MP_TO_LAG] > 0.0):
        return ok0
    rms0 = s[k + MF_TO_K + 6]
    if _takeoff_solve(s, k, p, k + MF_TO_ACC2):
        if not ok0 or s[k + MF_TO_K + 6] <= rms0:
            return True
        return _takeoff_solve(s, k, p, k + MF_TO_L)
    return ok0 and _takeoff_solve(s, k, p, k + MF_TO_L)


@kernel
def _takeoff_fuse(s, k, p):  # type: ignore[no-untyped-def]
    """Solve the take-off fit (:func:`_takeoff_solve`) and fuse its k into the model: three scalar
    measurements of k with the fit's σ (their cross-covariance left out)."""
    if not _takeoff_solve_best(s, k, p):
        return
    kk = k + MF_TO_K
    ks = k + MF_TO_SCR
    kx = k + MF_X
    kp = k + MF_P
    known = True
    for i in range(3, 6):
        known = known and s[kp + i * NX + i] <= TO_KNOWN_K * TO_KNOWN_K
    if known:
        return  # a model loaded from an earlier flight (or learnt before a landing): the fit does not override it
    for i in range(3):
        r = s[kk + 3 + i] * s[kk + 3 + i]
        sv = r + s[kp + (3 + i) * NX + 3 + i]
        if not (sv > 0.0):
            continue
        y = s[kk + i] - s[kx + 3 + i]
        for a in range(NX):  # P's column 3 + i
            s[ks + a] = s[kp + a * NX + 3 + i]
        _scalar_apply(s, kx, kp, s, ks, y, sv)


@kernel(inline=True)
def _residual(s, kx, c, mx, my, mz, amps, j):  # type: ignore[no-untyped-def]
    """Component j of r = C (m − b₀ − k·I) − (F_H, 0, F_D)."""
    bx = mx - s[kx] - amps * s[kx + 3]
    by = my - s[kx + 1] - amps * s[kx + 4]
    bz = mz - s[kx + 2] - amps * s[kx + 5]
    n = c[3 * j] * bx + c[3 * j + 1] * by + c[3 * j + 2] * bz
    if j == 0:
        return n - s[kx + _FH]
    if j == 2:
        return n - s[kx + _FD]
    return n


def mag_model_summary(block: np.ndarray) -> dict[str, object]:
    """The model's state as plain values (status page, ``/status.json``, replay header); ``takeoff_fit``:
    what the take-off fit gave (its field per ampere and σ, residual RMS, the ground anomaly in the
    reference's body axes) once it was solved."""
    b = np.asarray(block, dtype=np.float64)
    p = b[MF_P : MF_P + NX * NX].reshape(NX, NX)
    trust = int(b[MF_TRUST]) if np.isfinite(b[MF_TRUST]) else MAG_LEARNING
    out: dict[str, object] = {
        "state": MAG_STATES[min(max(trust, 0), 2)],
        "offset_ut": [round(float(v), 2) for v in b[MF_X : MF_X + 3]],
        "offset_sigma_ut": [round(float(math.sqrt(max(p[i, i], 0.0))), 2) for i in range(3)],
        "motor_ut_per_a": [round(float(v), 3) for v in b[MF_X + 3 : MF_X + 6]],
        "motor_sigma_ut_per_a": [round(float(math.sqrt(max(p[i, i], 0.0))), 3) for i in range(3, 6)],
        "earth_field_ut": {"horizontal": round(float(b[MF_X + _FH]), 2), "down": round(float(b[MF_X + _FD]), 2)},
        "heading_sigma_deg": round(math.degrees(float(b[MF_HEAD_SIGMA])), 2),
        "disturbances": int(b[MF_STEPS]),
        "pair_updates": int(b[MF_PAIRS]),
    }
    if b[MF_TO_ON] >= 3.0 and b[MF_TO_K + 6] > 0.0:  # the take-off fit was solved
        kt = MF_TO_K
        out["takeoff_fit"] = {
            "motor_ut_per_a": [round(float(v), 3) for v in b[kt : kt + 3]],
            "motor_sigma_ut_per_a": [round(float(v), 3) for v in b[kt + 3 : kt + 6]],
            "residual_ut": round(float(b[kt + 6]), 2),
            "anomaly_ut": [round(float(v), 1) for v in b[kt + 7 : kt + 10]],
        }
    return out


#: version of the saved model (:func:`export_model`)
MODEL_FORMAT = 1


def export_model(block: np.ndarray) -> dict[str, object] | None:
    """What is worth keeping across a restart of the daemon: the field per ampere (and the offset).

    None while nothing was learnt (the per-ampere σ still above half its prior on every axis), so
    that a file is never overwritten by an empty model (a daemon started and stopped on the bench).
    """
    b = np.asarray(block, dtype=np.float64)
    p = b[MF_P : MF_P + NX * NX].reshape(NX, NX)
    k_sig = np.sqrt(np.maximum(np.diag(p)[3:6], 0.0))
    if not (np.all(np.isfinite(b[MF_X : MF_X + NX])) and b[MF_INIT] > 0.0):
        return None
    prior = math.sqrt(max(p[3, 3], 0.0))
    if not np.any(k_sig < 0.5 * max(prior, 1e-9)) and b[MF_STEPS] == 0:
        return None
    return {
        "format": MODEL_FORMAT,
        "offset_ut": [float(v) for v in b[MF_X : MF_X + 3]],
        "motor_ut_per_a": [float(v) for v in b[MF_X + 3 : MF_X + 6]],
        "motor_sigma_ut_per_a": [float(v) for v in k_sig],
    }


def import_model(block: np.ndarray, settings: MagFieldSettings, saved: object) -> str | None:
    """Start ``block`` (a reset model) from a saved one; return why not, or None when taken.

    The field per ampere is taken with its σ (at least 0.05 µT/A); the offset as the prior's mean
    with the prior's σ (a payload may have changed it); the earth field is not kept (the WMM at the
    new position seeds it).
    """
    if not isinstance(saved, dict) or saved.get("format") != MODEL_FORMAT:
        return "not a saved magnetometer model (format)"
    try:
        off = np.asarray(saved["offset_ut"], dtype=np.float64)
        mot = np.asarray(saved["motor_ut_per_a"], dtype=np.float64)
        sig = np.asarray(saved["motor_sigma_ut_per_a"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        return "missing or non-numeric fields"
    if off.shape != (3,) or mot.shape != (3,) or sig.shape != (3,):
        return "wrong field sizes"
    if not (np.all(np.isfinite(off)) and np.all(np.isfinite(mot)) and np.all(np.isfinite(sig)) and np.all(sig >= 0)):
        return "non-finite values"
    if np.any(np.abs(off) > 200.0) or np.any(np.abs(mot) > 20.0):
        return "implausible values (offset > 200 µT or > 20 µT/A)"
    p = block[MF_P : MF_P + NX * NX].reshape(NX, NX)
    block[MF_X : MF_X + 3] = off
    block[MF_X + 3 : MF_X + 6] = mot
    for i in range(3):
        p[3 + i, :] = 0.0
        p[:, 3 + i] = 0.0
        p[3 + i, 3 + i] = max(float(sig[i]), 0.05) ** 2
    return None


#: the status line while the magnetometer is not used and no GNSS velocity holds the heading
DISTURBED_GYRO_TEXT = "magnetometer disturbed: heading from the gyro"
#: … while the compass is not trusted and nothing has told the heading yet (its 1-σ at or above
#: :data:`HEADING_UNKNOWN_SIGMA_DEG`): a start in a ground anomaly, where the heading at take-off is the
#: disturbed compass's until the first horizontal acceleration (firmware_sim ``mag_anomaly`` seed 11:
#: 28–31° off, σ 40–50°, until 16 s)
HEADING_UNKNOWN_TEXT = "heading unknown: compass disturbed"
#: heading 1-σ, degrees, at or above which an untrusted compass's heading is reported unknown (the ESKF's
#: re-opened heading is 45°; after the first horizontal accelerations it falls below 30° within 2 s)
HEADING_UNKNOWN_SIGMA_DEG = 30.0


def mag_status(
    model: dict[str, object] | None, out: np.ndarray, declination_rad: float, declination_sigma_rad: float
) -> dict[str, object]:
    """The magnetometer's state for the status page, ``/status.json`` and the status line.

    ``model``: the learnt model's summary (:func:`mag_model_summary`), or None while it is off; then
    the state is the trust the filter gave the last reading (``out``, its output row: weight ≥ 0.5
    trusted, a valid reading below it disturbed — the replay header's criterion), ``"absent"``
    without a magnetometer reading.  ``heading_from`` says what holds the heading while the
    compass is not used: GNSS while velocity-aided, else the gyro, and ``"unknown"`` while the
    compass is not trusted and the filter's heading 1-σ (``OUT_HEADING_SIGMA``, NaN for filters
    without one) is at or above :data:`HEADING_UNKNOWN_SIGMA_DEG`; ``filter_heading_sigma_deg`` where the
    filter gives it.  ``declination_*``: the filter's learnt correction of the WMM declination
    (``EskfSettings.declination_sigma_rad``).
    """
    flags = int(out[OUT_FLAGS]) if np.isfinite(out[OUT_FLAGS]) else 0
    if model is not None:
        status: dict[str, object] = dict(model)
        status["model"] = "on"
    else:
        if flags & FLAG_MAG_INVALID:
            state = "absent"
        else:
            state = "trusted" if float(out[OUT_MAG_WEIGHT]) >= 0.5 else "disturbed"
        status = {"state": state, "model": "off"}
    status["heading_from"] = "GNSS" if flags & FLAG_VELOCITY_AIDED else "gyro"
    sigma = float(out[OUT_HEADING_SIGMA])
    if math.isfinite(sigma):
        status["filter_heading_sigma_deg"] = round(math.degrees(sigma), 1)
        if status.get("state") != "trusted" and math.degrees(sigma) >= HEADING_UNKNOWN_SIGMA_DEG:
            status["heading_from"] = "unknown"
    status["declination_correction_deg"] = round(math.degrees(declination_rad), 2)
    status["declination_sigma_deg"] = round(math.degrees(declination_sigma_rad), 2)
    return status


def mag_state_text(summary: dict[str, object] | None) -> str:
    """The status line's magnetometer part, e.g. ``mag trusted (offset +0.2 −1.3 +0.7 µT, 0.41 −0.29 0.79 µT/A)``
    (with the model off: ``mag trusted``), and the learnt declination where it moved
    (``, declination −0.52 ± 0.26° from the WMM's``)."""
    if not summary:
        return ""
    state = summary.get("state")
    if summary.get("heading_from") == "unknown":
        return HEADING_UNKNOWN_TEXT
    if state == "disturbed":
        return DISTURBED_GYRO_TEXT if summary.get("heading_from") == "gyro" else DISTURBED_TEXT
    decl = summary.get("declination_correction_deg")
    d_text = ""
    if isinstance(decl, (int, float)) and decl != 0.0:
        d_text = f", declination {decl:+.2f} ± {summary.get('declination_sigma_deg', 0.0):.2f}° from the WMM's"
    if "offset_ut" not in summary:
        return f"mag {state}{d_text}"
    off = summary.get("offset_ut") or (0.0, 0.0, 0.0)
    mot = summary.get("motor_ut_per_a") or (0.0, 0.0, 0.0)
    return (f"mag {state} (offset {off[0]:+.1f} {off[1]:+.1f} {off[2]:+.1f} µT, "  # type: ignore[index]
            f"{mot[0]:+.2f} {mot[1]:+.2f} {mot[2]:+.2f} µT/A){d_text}")  # type: ignore[index]
