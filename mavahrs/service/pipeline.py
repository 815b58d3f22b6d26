r"""The daemon's functional core: decoded messages in, attitude frames out (deterministic, no I/O).

:class:`Pipeline` is what ``mavahrs run`` (the daemon), ``mavahrs replay`` and
the end-to-end tests all run.  It never reads a clock or touches a socket:
every call gets the time (``now_us``, the caller's monotonic clock in µs; used
only for timers, rate meters and rate-limited notices — the filter runs on the
autopilot's own sample timestamps).

Per message from the master link (:meth:`Pipeline.handle`):

* ``HEARTBEAT`` — the first autopilot heartbeat (``autopilot`` ≠
  MAV_AUTOPILOT_INVALID) fixes the *source*: IMU data is accepted only from
  that system/component (or the configured one), so another node on the
  network cannot inject a fake IMU stream; it also picks the scaling profile
  (ArduPilot/PX4/generic), our system id (the vehicle's) and starts the
  stream requests.  A heartbeat returning after silence restarts them.
* IMU messages (RAW_IMU, SCALED_IMU/2/3, HIGHRES_IMU) — scaled to SI
  (:mod:`mavahrs.sensors.scaling`); an exact re-send of the previous message
  (same stamp, same values: ArduPilot's 400 Hz telemetry catching up) is
  dropped and counted (``exact_duplicates``, :mod:`mavahrs.ingest.resend`); the rest is offered to the IMU selector
  (:mod:`mavahrs.sensors.imu_select`, its compiled step per sample); the selected instance's samples are
  timed by the timeline (duplicates and reordered samples dropped and counted,
  a reboot resets everything, a gap reaches the filter as a long ``dt`` so it
  re-initialises), calibrated (:mod:`mavahrs.sensors.calibration`), written
  into a preallocated filter row and run through the compiled filter kernel
  (``update_row``).  An ``ATTITUDE_QUATERNION`` follows at ``out_rate_hz`` of
  *sample* time (0 = every sample), stamped with the sample's own
  ``time_boot_ms``, body rates = gyro − bias, ``repr_offset_q`` zero; optionally
  ``ATTITUDE`` (Euler).
* ``GLOBAL_POSITION_INT`` — velocity (cm/s, true NED) into the filter's
  velocity column on the next sample, rotated into the filter's magnetic-NED
  frame; position and ``SYSTEM_TIME``/``GPS_RAW_INT``/``HOME_POSITION`` feed the
  World Magnetic Model (:class:`~mavahrs.sensors.geomag.DeclinationSource`) so
  outputs are referenced to true north.
* ``COMMAND_ACK`` / ``STATUSTEXT`` — to the stream requester; so are other
  nodes' ``REQUEST_DATA_STREAM`` / SET_MESSAGE_INTERVAL to the autopilot, when
  seen (a ground station resetting stream rates: ours are asked for again).

:meth:`Pipeline.tick` runs the timers (HEARTBEAT at ``heartbeat_hz``, stream
requests, link and rate checks); :meth:`Pipeline.status` reports;
:meth:`Pipeline.drain_notices` returns one-line messages to log (rate-limited
per kind).  The hot path does scalar Python arithmetic — no numpy small arrays,
no logging — and builds its output frames with ``struct`` (byte-identical to
pymavlink's encoding, a fifth of the cost; pymavlink signs when signing is on).
"""

from __future__ import annotations

import logging
import math
import struct
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from mavahrs import filters as _filters
from mavahrs.errors import ConfigError, MavahrsError
from mavahrs.filters.base import AttitudeFilter, FilterSettings
from mavahrs.filters.layout import (
    FLAG_MAG_INVALID,
    FLAG_NOT_INITIALISED,
    FLAG_REINITIALISED,
    FLAG_VELOCITY_AIDED,
    IN_ACCEL,
    IN_CURRENT,
    IN_GYRO,
    IN_MAG,
    IN_POS,
    IN_VEL,
    IN_VEL_AGE,
    IN_WIDTH,
    OUT_ACCEL_WEIGHT,
    OUT_BIAS,
    OUT_FLAGS,
    OUT_GAIN,
    OUT_HEADING_SIGMA,
    OUT_MAG_WEIGHT,
    OUT_Q,
)
from mavahrs.filters.magfield import mag_state_text
from mavahrs.ingest.autopilot_bias import AutopilotBias, AutopilotBiasSettings
from mavahrs.ingest.autopilot_mag_bias import MagBias
from mavahrs.ingest.resend import RESENT, ResendFilter, stream_code
from mavahrs.ingest.timeline import (
    DROP_KINDS,
    K_DUPLICATE,
    K_GAP,
    K_REBOOT,
    KIND_NAMES,
    T_RAW_MAX,
    Timeline,
    TimelineSettings,
    timeline_step,
)
from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.sensors.calibration import CalibrationSettings, Calibrator
from mavahrs.sensors.current import CURRENT_STALE_S, battery_current_a
from mavahrs.sensors.geomag import (
    DeclinationSource,
    MagneticFieldSettings,
    apply_declination_wxyz,
)
from mavahrs.sensors.imu_select import ImuSelector, ImuSelectSettings, InstanceStatus
from mavahrs.sensors.profiles import (
    IMU_MESSAGES,
    INSTANCE_OF_MESSAGE,
    MULTIROTOR_MAV_TYPES,
    PROFILE_NAMES,
    AutopilotProfile,
    get_profile,
    profile_for_autopilot,
)
from mavahrs.sensors.px4_mag_calibration import mag_calibration, missing_names, param_value, relevant_name
from mavahrs.sensors.sample import ACCEL, GYRO, MAG, write_row
from mavahrs.sensors.scaling import Scaler, ScalingSettings
from mavahrs.sensors.velocity import LABELS, VELOCITY_SOURCES, VelocitySelector, fix_age_s, source_messages
from mavahrs.service.monitor import AttitudeMonitor, MonitorSettings, MonitorStatus
from mavahrs.service.stats import Notices, RateMeter
from mavahrs.service.stream_requests import (
    MAV_CMD_SET_MESSAGE_INTERVAL,
    MAV_DATA_STREAM_EXTENDED_STATUS,
    MAV_DATA_STREAM_EXTRA1,
    MAV_DATA_STREAM_POSITION,
    MAV_DATA_STREAM_RAW_SENSORS,
    RequestDataStream,
    StreamRequester,
    StreamRequestSettings,
    StreamState,
)

__all__ = ["PipelineSettings", "Pipeline", "PipelineStatus", "Outgoing", "OUT_IDENTITIES", "SEPARATE_VEHICLE_SYSTEM_ID"]

#: how the output presents itself (:attr:`PipelineSettings.out_identity`)
OUT_IDENTITIES = ("component", "separate-vehicle", "none")
#: our system id as a separate vehicle when ``system_id`` is not set (``replay --stream``'s default too)
SEPARATE_VEHICLE_SYSTEM_ID = 42
_MAV_AUTOPILOT_INVALID = 8
_MAV_AUTOPILOT_GENERIC = 0
_MAV_TYPE_QUADROTOR = 2
_MAV_TYPE_ONBOARD_CONTROLLER = 18
#: The monitor's IMU check gets one gyro sample per instance at most this often, ms: an interval between two of
#: the autopilot's attitudes (20–100 ms) then holds several of every IMU's samples, whatever its stream rate (one
#: sample in 8 of a 50 Hz SCALED_IMU2 against a 10 Hz ATTITUDE named a healthy IMU in yaw spins)
_IMU_CHECK_STEP_MS = 10.0
#: PARAM_REQUEST_READ for PX4's CAL_MAG*: once a second, ten times (autopilot_mag_bias)
_PARAM_PERIOD_US = 1_000_000
_PARAM_ROUNDS = 10

#: MAV_TYPE of multirotors (coaxial, quad-, hexa-, octo-, tri-, dodeca-, decarotor, generic): rotor drag applies
_MAV_STATE_ACTIVE = 4
_NAN = math.nan
#: the drop counter of each timeline kind code that drops its sample (the timeline's "drop": a held jump)
_DROP_NAMES = tuple(("held_jump" if k == "drop" else k) if k in DROP_KINDS else None for k in KIND_NAMES)
_ZERO_Q = [0.0, 0.0, 0.0, 0.0]
_RAD2DEG = 180.0 / math.pi
_BACKLOG = 1024  # samples kept per unselected IMU instance for a seamless fail-over (2.5 s at 400 Hz)
_SNAPSHOT_US = 100_000  # filter state kept every 0.1 s of sample time …
_SNAPSHOTS = 30  # … for 3 s, to undo samples of an IMU found frozen/saturated/disagreeing
_GNSS_FRESH_US = 2_000_000  # a GNSS fix this recent counts as "in use" on the status page
_G = 9.80665
# Fast encoding of the fixed-layout messages sent per sample (see Pipeline._frame): MAVLink 2 header,
# payload as pymavlink packs it (common.xml field order: largest types first), CRC-16/MCRF4XX with CRC_EXTRA.
_V2_HEADER = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_AQ_ID, _AQ_CRC = mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, mavlink.MAVLink_attitude_quaternion_message.crc_extra
_AQ_PAYLOAD = struct.Struct("<Ifffffff")  # time_boot_ms, q1..q4, rates; repr_offset_q (zero) is truncated
_ATT_ID, _ATT_CRC = mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLink_attitude_message.crc_extra
_ATT_PAYLOAD = struct.Struct("<Iffffff")
_HB_ID, _HB_CRC = mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLink_heartbeat_message.crc_extra
_HB_PAYLOAD = struct.Struct("<IBBBBB")


#: velocity messages and the stream group (REQUEST_DATA_STREAM) each belongs to on ArduPilot
_VELOCITY_STREAMS = {
    "GLOBAL_POSITION_INT": MAV_DATA_STREAM_POSITION,
    "GPS_RAW_INT": MAV_DATA_STREAM_EXTENDED_STATUS,
    "GPS2_RAW": MAV_DATA_STREAM_EXTENDED_STATUS,
}


class Outgoing(NamedTuple):
    """One encoded frame and where it goes.

    Attributes:
        frame: the MAVLink bytes (our system/component id, our sequence).
        to_master: send on the master link (the autopilot).
        to_outputs: send to every ``--out`` output.
    """

    frame: bytes
    to_master: bool
    to_outputs: bool


_IMU_NAMES = ("IMU1", "IMU2", "IMU3", "IMU4")  # IMU instance → the name the monitor gives it


@dataclass(frozen=True)
class PipelineSettings:
    """Everything the pipeline does, with units and defaults.

    Attributes:
        filter_name: attitude filter (``madgwick``, ``mahony``,
            ``complementary``, ``gyroplatform``, ``best``).
        imu: IMU instance: ``auto`` (healthy instance, with fail-over) or
            ``0``/``1``/``2`` (RAW_IMU or SCALED_IMU or HIGHRES_IMU,
            SCALED_IMU2, SCALED_IMU3).
        autopilot_profile: scaling profile: ``auto`` (from the autopilot's
            HEARTBEAT), ``ardupilot``, ``px4`` or ``generic``.
        out_rate_hz: ATTITUDE_QUATERNION rate, Hz of sample time; 0 = one
            per IMU sample.
        system_id: our MAVLink system id; None = the vehicle's (from its
            HEARTBEAT), or 42 with ``out_identity = "separate-vehicle"``.
        component_id: our component id (191 = MAV_COMP_ID_ONBOARD_COMPUTER);
            used with ``out_identity = "component"`` only.
        out_identity: how the attitude presents itself to ground stations:
            ``component`` = a component of the vehicle (its system id,
            ``component_id``, HEARTBEAT as an onboard controller);
            ``separate-vehicle`` = a vehicle of its own (``system_id``, default
            42, component 1, HEARTBEAT with the autopilot's vehicle type and
            MAV_AUTOPILOT_GENERIC), which QGroundControl before 4.2 shows as a
            second vehicle instead of drawing it on the autopilot's HUD;
            ``none`` = send nothing but the stream requests (the attitude is
            in the status line and the ``--log`` recording only).
        heartbeat_hz: our HEARTBEAT rate, Hz (0 = none).
        send_attitude_euler: also send ATTITUDE (roll/pitch/yaw) with each
            ATTITUDE_QUATERNION.
        send_to_master: also send our output to the autopilot's link (it
            routes it on to its ground stations); False = outputs only.
        stream_rate_hz: IMU message rate to request, Hz.
        stream_request_interval_s: re-send stream requests this often, s.
        request_streams: send stream requests at all.
        secondary_imu_rate_hz: with ``imu = auto``, rate to request for the
            other IMU instances (to watch them for fail-over), Hz; 0 = do not
            request them.
        gnss_rate_hz: rate to request the velocity source's message(s) at
            (``auto``: GLOBAL_POSITION_INT and GPS_RAW_INT), Hz.
        autopilot_attitude_rate_hz: rate to request the autopilot's own
            ATTITUDE at while the second-opinion monitor is on, Hz (it compares at
            the rate that attitude arrives: ArduPilot sends it at its
            ``SRn_EXTRA1`` rate, 0–4 Hz unless a ground station asks); 0 = take
            what arrives.
        source_system: accept IMU data only from this system id; None = the
            first autopilot heartbeat's.
        source_component: … and this component id; None = the first
            autopilot heartbeat's (of ``source_system`` when given).
        velocity_source: GNSS velocity fed to the filter (acceleration
            compensation): ``auto`` (GLOBAL_POSITION_INT while it arrives, else
            GPS_RAW_INT, else GPS2_RAW — on PX4 GPS_RAW_INT first, then
            GLOBAL_POSITION_INT, then GPS2_RAW: the profile's ``velocity_order``;
            switches down only when the source in use has been silent for 2 s,
            never mixes two), ``global_position_int``,
            ``gps_raw_int``, ``gps2_raw`` or ``none``
            (:mod:`mavahrs.sensors.velocity`).  With
            ``monitor.receiver_velocity_only``, ``auto`` uses only GPS_RAW_INT and
            GPS2_RAW.
        use_gnss_velocity: deprecated, kept for old configurations: False =
            ``velocity_source = "none"`` whatever ``velocity_source`` says.
        heartbeat_timeout_s: no autopilot HEARTBEAT for this long = link
            lost (stream requests restart when it returns), s.
        no_imu_warning_s: warn when no IMU sample arrived for this long, s.
        low_imu_rate_hz: warn when fewer samples per second reach the filter
            (too slow for meaningful filtering), Hz.
        scaling: saturation/validity checks (:class:`ScalingSettings`).
        selection: IMU instance health thresholds (its ``imu`` field is
            replaced by ``imu`` above).
        calibration: gyro temperature model, magnetometer calibration, axis
            remap.
        streams: stream-request details (ladder, timeouts); its
            ``interval_s``/``enabled`` are replaced by the fields above.
        magnetic: declination / expected field (true-north output).
        monitor: the second opinion on the autopilot's attitude
            (NAMED_VALUE_FLOAT divergence, STATUSTEXT warnings).
        timeline: timestamp rules per IMU stream
            (:class:`mavahrs.ingest.timeline.TimelineSettings`: gap, reboot,
            forward-jump thresholds, wrap-around).
        autopilot_bias: the autopilot's gyro-bias estimate taken back out of
            its primary IMU message where the profile names a bias-free twin
            (PX4: EKF2's, from SCALED_IMU beside HIGHRES_IMU; on by default;
            :class:`mavahrs.ingest.autopilot_bias.AutopilotBiasSettings`).
    """

    filter_name: str = "best"
    imu: str = "auto"
    autopilot_profile: str = "auto"
    out_rate_hz: float = 50.0
    system_id: int | None = None
    component_id: int = 191
    out_identity: str = "component"
    heartbeat_hz: float = 1.0
    send_attitude_euler: bool = False
    send_to_master: bool = True
    stream_rate_hz: float = 400.0
    stream_request_interval_s: float = 10.0
    request_streams: bool = True
    secondary_imu_rate_hz: float = 50.0
    gnss_rate_hz: float = 10.0
    autopilot_attitude_rate_hz: float = 10.0
    source_system: int | None = None
    source_component: int | None = None
    velocity_source: str = "auto"
    use_gnss_velocity: bool = True
    heartbeat_timeout_s: float = 5.0
    no_imu_warning_s: float = 3.0
    low_imu_rate_hz: float = 50.0
    scaling: ScalingSettings = field(default_factory=ScalingSettings)
    selection: ImuSelectSettings = field(default_factory=ImuSelectSettings)
    calibration: CalibrationSettings = field(default_factory=CalibrationSettings)
    streams: StreamRequestSettings = field(default_factory=StreamRequestSettings)
    magnetic: MagneticFieldSettings = field(default_factory=MagneticFieldSettings)
    monitor: MonitorSettings = field(default_factory=MonitorSettings)
    timeline: TimelineSettings = field(default_factory=TimelineSettings)
    autopilot_bias: AutopilotBiasSettings = field(default_factory=AutopilotBiasSettings)

    def __post_init__(self) -> None:
        if self.autopilot_profile != "auto" and self.autopilot_profile not in PROFILE_NAMES:
            raise ConfigError(
                f"autopilot_profile must be auto or one of {', '.join(PROFILE_NAMES)}, got {self.autopilot_profile!r}"
            )
        if self.out_identity not in OUT_IDENTITIES:
            raise ConfigError(f"out_identity must be one of {', '.join(OUT_IDENTITIES)}, got {self.out_identity!r}")
        if self.filter_name not in _filters.NAMES + _filters.ALIASES:
            raise ConfigError(f"unknown filter {self.filter_name!r}; choose one of {', '.join(_filters.NAMES + _filters.ALIASES)}")
        for name in ("out_rate_hz", "heartbeat_hz", "secondary_imu_rate_hz", "gnss_rate_hz", "low_imu_rate_hz",
                     "autopilot_attitude_rate_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be ≥ 0 Hz, got {v!r}")
        for name in ("stream_rate_hz", "stream_request_interval_s", "heartbeat_timeout_s", "no_imu_warning_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be positive, got {v!r}")
        for name in ("system_id", "source_system"):
            v = getattr(self, name)
            if v is not None and not 1 <= v <= 255:
                raise ConfigError(f"{name} must be 1…255 or None, got {v!r}")
        for name in ("component_id", "source_component"):
            v = getattr(self, name)
            if v is not None and not 0 <= v <= 255:
                raise ConfigError(f"{name} must be 0…255 or None, got {v!r}")
        if self.velocity_source not in VELOCITY_SOURCES:
            raise ConfigError(
                f"velocity_source must be one of {', '.join(VELOCITY_SOURCES)}, got {self.velocity_source!r}"
            )
        if self.monitor.receiver_velocity_only and self.velocity_source == "global_position_int":
            raise ConfigError(
                "velocity_source = global_position_int contradicts monitor.receiver_velocity_only "
                "(the receiver's GPS_RAW_INT / GPS2_RAW only): choose auto, gps_raw_int, gps2_raw or none"
            )
        # validated by ImuSelectSettings
        replace(self.selection, imu=self.imu)

    @property
    def effective_velocity_source(self) -> str:
        """``velocity_source``, or ``none`` when the deprecated ``use_gnss_velocity`` is False."""
        return self.velocity_source if self.use_gnss_velocity else "none"

    @property
    def velocity_messages(self) -> tuple[str, ...]:
        """The messages the velocity may come from, in order of preference, before the profile is known.

        ``auto``: the ArduPilot / generic order; the pipeline's selector takes the profile's
        ``velocity_order`` once the autopilot's HEARTBEAT names it.
        """
        return source_messages(self.effective_velocity_source, self.monitor.receiver_velocity_only)

    @property
    def selection_settings(self) -> ImuSelectSettings:
        return replace(self.selection, imu=self.imu)

    @property
    def stream_settings(self) -> StreamRequestSettings:
        return replace(self.streams, interval_s=self.stream_request_interval_s, enabled=self.request_streams)


@dataclass(frozen=True)
class PipelineStatus:
    """A snapshot for the status line and for tests.

    Attributes:
        connected: an autopilot heartbeat arrived within ``heartbeat_timeout_s``.
        vehicle: (system, component) IMU data is accepted from; None = not yet.
        autopilot_profile: scaling profile in use (None until known).
        filter_name: the filter running.
        input_rate_hz: IMU messages/s from the source (all instances).
        filter_rate_hz: samples/s reaching the filter.
        output_rate_hz: ATTITUDE_QUATERNION/s.
        samples_in: IMU messages accepted from the source.
        samples_filtered: samples run through the filter.
        outputs_sent: ATTITUDE_QUATERNION messages produced.
        drops: samples not filtered, by reason.
        samples_dropped: their total.
        counters: other events (saturation, invalid vectors, reboots, …);
            ``exact_duplicates``: IMU messages the autopilot sent twice (same
            stamp and values; dropped, not counted as drops),
            ``same_stamp_changed``: messages repeating the previous stamp with
            other values (the timeline drops those of the filtered instance as
            ``stale``).
        initialised: the filter has an attitude.
        gain: current correction gain (after boost and rejection).
        accel_weight: trust in the accelerometer 0…1.
        mag_weight: trust in the magnetometer 0…1.
        accel_rejected: accelerometer currently rejected.
        mag_rejected: magnetometer currently rejected.
        accel_rejection_pct: share of the samples filtered since the previous
            ``status()`` call with the accelerometer (mostly) rejected, %.
        mag_rejection_pct: the same for the magnetometer (samples with one), %.
        bias_deg_s: gyro bias estimate, °/s (x, y, z).
        q_body_to_ned: last attitude (true north when the declination is
            known), or None.
        imu_in_use: selected instance (None: none usable).
        imu_reason: why that instance.
        imu_instances: every instance seen.
        streams: stream-request state per wanted message.
        heading_reference: e.g. "true north (WMM-2025 D=+12.3°)".
        monitor: the comparison with the autopilot's attitude, e.g.
            "AP cmp: tilt 0.8° hdg +1.2° (vel GPI)".
        velocity: the GNSS velocity source feeding the filter and the rate
            of the fixes fed, e.g. "vel GPI 10 Hz", "vel GPS_RAW 5 Hz" or
            "vel none" (setting ``none``, or no source arriving).
        velocity_fixes: fixes fed so far, per message.
        velocity_skipped: velocity messages not fed, by reason (``no_fix``,
            ``unknown_velocity``, ``repeated``, ``reordered``, ``standby``).
        monitor_state: the same as figures (None when the comparison is off).
        gnss_velocity: GNSS velocity aiding: ``"in use"`` (a fix fed within
            the last 2 s), ``"no fix"``, ``"none"`` (no velocity message from
            the source yet) or ``"off"`` (``velocity_source = "none"``).
    """

    connected: bool
    vehicle: tuple[int, int] | None
    autopilot_profile: str | None
    filter_name: str
    input_rate_hz: float
    filter_rate_hz: float
    output_rate_hz: float
    samples_in: int
    samples_filtered: int
    outputs_sent: int
    drops: Mapping[str, int]
    samples_dropped: int
    counters: Mapping[str, int]
    initialised: bool
    gain: float
    accel_weight: float
    mag_weight: float
    accel_rejected: bool
    mag_rejected: bool
    accel_rejection_pct: float
    mag_rejection_pct: float
    bias_deg_s: tuple[float, float, float]
    q_body_to_ned: tuple[float, float, float, float] | None
    imu_in_use: int | None
    imu_reason: str
    imu_instances: tuple[InstanceStatus, ...]
    streams: tuple[StreamState, ...]
    heading_reference: str
    monitor: str = ""
    velocity: str = "vel none"
    velocity_fixes: Mapping[str, int] = field(default_factory=dict)
    velocity_skipped: Mapping[str, int] = field(default_factory=dict)
    monitor_state: MonitorStatus | None = None
    gnss_velocity: str = "none"
    #: the learnt magnetometer model (``best``/``eskf``: state trusted/learning/disturbed, offsets; None: none)
    magnetometer: Mapping[str, Any] | None = None

    def line(self) -> str:
        """One status line for the log, e.g. ``in 400 Hz → filter 400 Hz → out 50 Hz | … | vel GPI 10 Hz | …``."""
        drops = self.samples_dropped
        resent = self.counters.get("exact_duplicates", 0)
        early, foreign = self.drops.get("no_autopilot_yet", 0), self.drops.get("foreign_source", 0)
        why = ", ".join(  # drops that are no fault of the autopilot's stream: said, so that nobody hunts for one
            ([f"{early} before the autopilot's HEARTBEAT"] if early else [])
            + ([f"{foreign} from other systems"] if foreign else [])
        )
        imu = "none" if self.imu_in_use is None else str(self.imu_in_use)
        rej = ("A" if self.accel_rejected else "") + ("M" if self.mag_rejected else "")
        b = self.bias_deg_s
        return (
            f"in {self.input_rate_hz:.0f} Hz → filter {self.filter_rate_hz:.0f} Hz → out {self.output_rate_hz:.0f} Hz"
            f" | drops {drops}{f' ({why})' if why else ''}{f' (+{resent} re-sent)' if resent else ''}"
            f" | imu {imu} ({self.imu_reason})"
            f" | {self.velocity} | gain {self.gain:.3g}"
            f" acc {self.accel_weight:.2f} mag {self.mag_weight:.2f}{' rejecting ' + rej if rej else ''}"
            f" | bias {b[0]:+.2f} {b[1]:+.2f} {b[2]:+.2f} °/s | {self.heading_reference}"
            + (f" | {self.monitor}" if self.monitor else "")
            + (f" | {mag_state_text(self.magnetometer)}" if self.magnetometer else "")
        )


class Pipeline:
    """Decoded MAVLink in, encoded attitude out; see the module docstring.

    Args:
        settings: what to do (:class:`PipelineSettings`).
        filter_settings: settings for the chosen filter (None = its defaults).
        filter: use this filter instance instead of creating one (replay of
            several filters, tests).
        decimal_year: today's date for the World Magnetic Model until the
            autopilot sends SYSTEM_TIME (the daemon passes it; None = wait).
    """

    def __init__(
        self,
        settings: PipelineSettings | None = None,
        filter_settings: FilterSettings | None = None,
        *,
        filter: AttitudeFilter | None = None,
        decimal_year: float | None = None,
    ) -> None:
        s = self.settings = settings or PipelineSettings()
        self._filter = filter if filter is not None else _filters.create(s.filter_name, filter_settings)
        self._filter_name = getattr(self._filter, "name", s.filter_name)
        #: a dt the filter surely treats as a gap (re-initialise): twice its max_gap_s
        self._gap_dt_s = 2.0 * float(getattr(getattr(self._filter, "settings", None), "max_gap_s", 1.0) or 1.0)
        separate = s.out_identity == "separate-vehicle"
        self._codec = MavCodec(
            system_id=(s.system_id or SEPARATE_VEHICLE_SYSTEM_ID) if separate else (s.system_id or 1),
            component_id=1 if separate else s.component_id,
        )
        self._mav = self._codec.mav
        #: the fast encoder applies: MAVLink 2, and the encoder state is the pymavlink MAVLink object's
        self._fast_encode = float(mavlink.WIRE_PROTOCOL_VERSION) == 2.0 and hasattr(self._mav, "signing")
        self._row = np.full(IN_WIDTH, _NAN)
        self._selector = ImuSelector(s.selection_settings)
        self._resends = ResendFilter()
        self._requester = StreamRequester(s.stream_settings)
        self._decl = DeclinationSource(s.magnetic, decimal_year=decimal_year)
        self._monitor = AttitudeMonitor(s.monitor)
        self._monitor_on = s.monitor.enabled
        self._next_mag_offsets_us = 0  # the magnetometer model's learnt offsets go to the monitor at 1 Hz
        self._velocity = VelocitySelector(s.effective_velocity_source, s.monitor.receiver_velocity_only)
        self._vel_meter = RateMeter()
        self._vel_meter_source: str | None = None
        self._notices = Notices()
        self._said: deque[tuple[int, str]] = deque(maxlen=100)  # the monitor's STATUSTEXTs, for the daemon's log
        if not s.use_gnss_velocity:
            self._notices.warning(
                "deprecated", "pipeline.use_gnss_velocity = false is deprecated: set velocity_source = \"none\"", 0
            )
        # where our frames go (stream requests always go to the autopilot); out_identity "none": nowhere
        self._to_master = s.send_to_master and s.out_identity != "none"
        self._to_outputs = s.out_identity != "none"
        #: our HEARTBEAT's (MAV_TYPE, MAV_AUTOPILOT); as a separate vehicle the type is the autopilot's
        self._hb_kind = (_MAV_TYPE_QUADROTOR if separate else _MAV_TYPE_ONBOARD_CONTROLLER,
                         _MAV_AUTOPILOT_GENERIC if separate else _MAV_AUTOPILOT_INVALID)  # fmt: skip
        self._out_period_us = int(round(1e6 / s.out_rate_hz)) if s.out_rate_hz > 0 else 0
        self._out_tol_us = min(self._out_period_us // 4, 1000)
        self._hb_period_us = int(round(1e6 / s.heartbeat_hz)) if s.heartbeat_hz > 0 and self._to_outputs else 0
        self._hb_timeout_us = int(s.heartbeat_timeout_s * 1e6)
        self._no_imu_us = int(s.no_imu_warning_s * 1e6)
        self._low_rate_window_us = int(s.stream_settings.rate_window_s * 1e6)
        self._low_rate_since_us: int | None = None
        self._handlers: dict[str, Callable[[Any, int], list[Outgoing]]] = {
            "HEARTBEAT": self._on_heartbeat,
            "GLOBAL_POSITION_INT": self._on_velocity,
            "GPS_RAW_INT": self._on_velocity,
            "GPS2_RAW": self._on_velocity,
            "HOME_POSITION": self._on_position_only,
            "SYSTEM_TIME": self._on_position_only,
            "COMMAND_ACK": self._on_command_ack,
            "STATUSTEXT": self._on_statustext,
            "REQUEST_DATA_STREAM": self._on_foreign_stream_request,
            "COMMAND_LONG": self._on_foreign_stream_request,
            "COMMAND_INT": self._on_foreign_stream_request,
            "ATTITUDE": self._on_autopilot_attitude,
            "ATTITUDE_QUATERNION": self._on_autopilot_attitude,
            "EXTENDED_SYS_STATE": self._on_flight_phase,
            "SYS_STATUS": self._on_current,
            "BATTERY_STATUS": self._on_current,
            "PARAM_VALUE": self._on_param_value,
        }
        for name in IMU_MESSAGES:
            self._handlers[name] = self._on_imu
        # source / vehicle
        self._source: tuple[int, int] | None = None
        if s.source_system is not None and s.source_component is not None and s.autopilot_profile != "auto":
            self._source = (s.source_system, s.source_component)  # known without waiting for a heartbeat
        self._profile: AutopilotProfile | None = None
        self._scaler: Scaler | None = None
        #: the autopilot's gyro bias added back (PX4 HIGHRES_IMU from SCALED_IMU); None: not for this profile
        self._ab: AutopilotBias | None = None
        self._ab_partner = ""
        self._ab_primary = ""
        self._ab_instance = 0
        #: the autopilot's magnetometer bias added back (PX4 HIGHRES_IMU from SCALED_IMU and CAL_MAG*); None: not
        #: for this profile.  The parameters it needs, as the autopilot sent them, and their requests' schedule
        self._mb: MagBias | None = None
        self._params: dict[str, float] = {}
        self._mb_reason = ""
        self._param_next_us = 0
        self._param_rounds = 0
        self._calibrators: dict[str, Calibrator] = {}
        self._sysid_known = s.system_id is not None or separate
        self._last_hb_us: int | None = None
        self._link_lost = False
        if self._source is not None:
            self._set_profile(get_profile(s.autopilot_profile))
            if not self._sysid_known:
                self._codec.system_id = self._source[0]
                self._sysid_known = True
            if separate:  # no HEARTBEAT awaited: a quadrotor, like replay --stream's
                self._become_separate_vehicle(self._source, _MAV_TYPE_QUADROTOR, 0)
        # counters and meters
        self._drops: dict[str, int] = {}
        self._counters: dict[str, int] = {}
        self._in_meter = RateMeter()
        self._filter_meter = RateMeter()
        self._out_meter = RateMeter()
        self.samples_in = 0
        self.samples_filtered = 0
        self.outputs_sent = 0
        self._accel_rejected_n = 0
        self._mag_rejected_n = 0
        # (samples filtered, accel rejected, mag rejected) at the last status() of each window
        self._status_marks: dict[str, tuple[int, int, int]] = {}
        self._gnss_seen_us: int | None = None  # last GNSS velocity message from the source
        self._gnss_fix_us: int | None = None  # … of those, the last with a fix
        self._ap_attitude_msg: Any = None  # the source's last ATTITUDE / ATTITUDE_QUATERNION (for the status page)
        self._ap_attitude_us = 0
        self._source_since_us: int | None = None
        #: called as ``hook(message, t_us, input_row, output_row)`` after every sample the filter ran on
        #: (replay/CSV writers; the rows are reused: copy what you keep).  None = nothing (the daemon).
        self.sample_hook: Callable[[str, int, np.ndarray, np.ndarray], None] | None = None
        self._next_hb_us: int | None = None
        self._last_imu_us: int | None = None
        self._last_tick_us: int | None = None
        self._reset_stream_state()
        self._field_changed()

    # ------------------------------------------------------------------ properties
    @property
    def codec(self) -> MavCodec:
        """The encoding codec (our ids, sequence numbers; signing is set up on it)."""
        return self._codec

    @property
    def filter(self) -> AttitudeFilter:
        return self._filter

    @property
    def source(self) -> tuple[int, int] | None:
        """(system, component) IMU data is accepted from, once known."""
        return self._source

    @property
    def profile(self) -> AutopilotProfile | None:
        return self._profile

    @property
    def declination(self) -> DeclinationSource:
        return self._decl

    # ------------------------------------------------------------------ state resets
    def _reset_stream_state(self) -> None:
        """Forget everything about the IMU streams' timing (start, reboot); their counts are kept."""
        if hasattr(self, "_timelines"):  # totals survive a reboot (status counters never go back)
            self._timeline_totals = self._timeline_counts()
        else:
            self._timeline_totals = {"lost_samples": 0, "time_wraps": 0, "jumps_rejected": 0}
        self._timelines: dict[int, Timeline] = {}
        self._backlog: dict[int, deque[tuple[str, tuple]]] = {}
        self._snapshots: deque[tuple[int, Any]] = deque(maxlen=_SNAPSHOTS)
        self._last_out_t = -1
        self._last_fed_imu: int | None = None
        self._last_fed_t: int | None = None
        self._next_out_t: int | None = None
        #: the velocity fix waiting for the next fed sample: (vn, ve, vd magnetic NED, fix time µs or None)
        self._vel: tuple[float, float, float, int | None] | None = None
        self._imu_fed: dict[int, float] = {}  # per instance, the time of the last sample the monitor got, ms
        self._monitor_fix: tuple[float, float, float] | None = None  # GNSS velocity (true N, E) and fix time, ms
        self._current_a = _NAN  # battery current (the compass's motor interference model), A
        self._current_us: int | None = None
        self._last_now_us = 0  # the receive time of the last message handled (µs)
        self._vel_written = True  # row's velocity columns hold NaN already
        if hasattr(self, "_velocity"):
            self._velocity.reset()
        self._norm_sum = 0.0
        self._norm_n = 0
        self._row[:] = _NAN

    def reset_link(self, now_us: int) -> None:
        """The daemon reconnected the master link: ask for the streams again."""
        if self._source is not None:
            self._requester.start()
            self._notices.info("link-reset", "master link reconnected: requesting the IMU stream again", now_us)

    # ------------------------------------------------------------------ entry points
    def handle(self, msg: Any, now_us: int) -> list[Outgoing]:
        """Process one decoded message from the master link; return frames to send."""
        self._last_now_us = now_us  # (the fast lane's clock: how fresh the battery current still is)
        h = self._handlers.get(msg.get_type())
        if h is None:
            return []
        try:
            return h(msg, now_us)
        except MavahrsError as exc:
            kind = type(exc).__name__
            self._count(self._drops, f"error:{kind}")
            self._notices.warning(f"error:{kind}", f"{msg.get_type()}: {exc}", now_us)
            return []

    def tick(self, now_us: int) -> list[Outgoing]:
        """Timers: HEARTBEAT, stream requests, link and rate checks; call a few times per second or more."""
        out: list[Outgoing] = []
        self._last_tick_us = now_us
        if self._hb_period_us and self._sysid_known and (self._source is not None or self._hb_kind[1] == _MAV_AUTOPILOT_INVALID):
            if self._next_hb_us is None or now_us >= self._next_hb_us:
                out.append(Outgoing(self._heartbeat_frame(), self._to_master, self._to_outputs))
                nxt = (self._next_hb_us or now_us) + self._hb_period_us
                self._next_hb_us = nxt if nxt > now_us else now_us + self._hb_period_us
        if self._source is not None:
            if self._last_hb_us is not None and not self._link_lost and now_us - self._last_hb_us > self._hb_timeout_us:
                self._link_lost = True
                self._requester.stop()
                self._notices.warning(
                    "hb-lost",
                    f"no HEARTBEAT from the autopilot (system {self._source[0]}, component {self._source[1]}) "
                    f"for {self.settings.heartbeat_timeout_s:g} s",
                    now_us,
                )
            heard = max(self._last_hb_us or 0, self._last_imu_us or 0)  # anything from the autopilot
            for req in self._requester.poll(now_us, heard):
                out.append(Outgoing(self._request_frame(req), True, False))
            if self._mb is not None and not self._link_lost and now_us >= self._param_next_us:
                out += self._request_params(now_us)
            if self._monitor_on:
                if now_us >= self._next_mag_offsets_us:
                    self._next_mag_offsets_us = now_us + 1_000_000
                    self._monitor_mag_model()
                for m in self._monitor.tick(now_us):
                    out.append(Outgoing(self._codec.encode(m), self._to_master, self._to_outputs))
            self._check_input(now_us)
        return out

    def drain_notices(self) -> list[tuple[int, str]]:
        """(logging level, one-line message) pairs for the daemon to log, oldest first."""
        return self._notices.drain() + self._requester.drain_notices()

    def drain_second_opinion(self) -> list[tuple[int, str]]:
        """The second-opinion monitor's STATUSTEXTs since the last call, as (logging level, text) for the daemon's
        log: WARNING for a WARNING, INFO for a NOTICE or "agrees again" (the STATUSTEXT goes to the ground
        station as well).  Not rate-limited here: the monitor says each once per episode.  (Until user6 the
        daemon's log showed only the status line's `WARN`: without a ground station the words never appeared.)"""
        out = list(self._said)
        self._said.clear()
        return out

    def _saying(self, msgs: list[Any]) -> list[Any]:
        """``msgs`` (the monitor's), with each STATUSTEXT's text kept for :meth:`drain_second_opinion`."""
        for m in msgs:
            if m.get_type() == "STATUSTEXT":
                text = m.text.decode("utf-8", "replace") if isinstance(m.text, bytes) else str(m.text)
                level = logging.WARNING if int(m.severity) <= mavlink.MAV_SEVERITY_WARNING else logging.INFO
                self._said.append((level, f"second opinion: {text.rstrip(chr(0))}"))
        return msgs

    # ------------------------------------------------------------------ handlers
    def _on_heartbeat(self, msg: Any, now_us: int) -> list[Outgoing]:
        hdr = msg.get_header()
        src = (hdr.srcSystem, hdr.srcComponent)
        if msg.autopilot == _MAV_AUTOPILOT_INVALID:
            return []  # a ground station, a companion (us), a gimbal…
        if self._source is not None and src != self._source and src == (self._codec.system_id, self._codec.component_id):
            return []  # our own HEARTBEAT as a separate vehicle (sent once the autopilot is known), relayed back
        s = self.settings
        if self._source is None:
            if s.source_system is not None and src[0] != s.source_system:
                return []
            if s.source_component is not None and src[1] != s.source_component:
                return []
            self._source = src
            profile = profile_for_autopilot(msg.autopilot) if s.autopilot_profile == "auto" else get_profile(s.autopilot_profile)
            self._set_profile(profile)
            multirotor = getattr(self._filter, "set_multirotor", None)
            if multirotor is not None and int(msg.type) in MULTIROTOR_MAV_TYPES:
                multirotor()  # the rotor-drag measurement (the ESKF's ``drag_coefficient_1_s``)
            if not self._sysid_known:
                self._codec.system_id = src[0]
                self._sysid_known = True
            self._notices.info(
                "source",
                f"autopilot found: system {src[0]}, component {src[1]} ({profile.description}); "
                f"IMU data accepted only from it, scaling profile {profile.name}",
                now_us,
            )
            if s.out_identity == "separate-vehicle":
                self._become_separate_vehicle(src, int(msg.type), now_us)
        if src != self._source:
            self._count(self._counters, "other_autopilot_heartbeats")
            self._notices.info(
                f"other-ap:{src}", f"ignoring a second autopilot (system {src[0]}, component {src[1]})", now_us, once=True
            )
            return []
        first = self._last_hb_us is None
        self._last_hb_us = now_us
        self._monitor.phase.handle(msg)  # armed / disarmed: the flight's phase
        if first:
            self._requester.start()
        elif self._link_lost:
            self._link_lost = False
            self._requester.start()
            self._notices.info("hb-back", "autopilot HEARTBEAT back: requesting the IMU stream again", now_us)
        return []

    def _become_separate_vehicle(self, autopilot: tuple[int, int], mav_type: int, now_us: int) -> None:
        """As a vehicle of our own: the autopilot's vehicle type in our HEARTBEAT, and never its system id."""
        self._hb_kind = (mav_type, _MAV_AUTOPILOT_GENERIC)
        ours = self._codec.system_id
        if ours == autopilot[0]:
            self._to_master = self._to_outputs = False
            self._hb_period_us = 0
            self._notices.warning(
                "separate-sysid",
                f"out_identity separate-vehicle: system id {ours} is the autopilot's own, so a ground station "
                "would take our attitude for the autopilot's; sending nothing (set pipeline.system_id, "
                "--sysid, to a free system id)",
                now_us,
            )
            return
        self._notices.info(
            "separate",
            f"attitude sent as a separate vehicle: system {ours}, component {self._codec.component_id} "
            f"(the autopilot is system {autopilot[0]})",
            now_us,
        )

    def _set_profile(self, profile: AutopilotProfile) -> None:
        self._profile = profile
        self._scaler = Scaler(profile, self.settings.scaling)
        set_delay = getattr(self._filter, "set_sensor_delay", None)
        ms = profile.scale_for(profile.primary_message)
        if set_delay is not None and ms is not None:  # the IMU data's low-pass delay (velocity-aided filter)
            set_delay(ms.delay_s)
        vehicle = getattr(self._filter, "set_vehicle_stream", None)
        if vehicle is not None:  # an autopilot's stream: ``best`` is the ESKF in every condition
            vehicle()
        self._velocity.set_auto_order(profile.velocity_order)  # PX4: the receiver before EKF2's velocity
        ab = self.settings.autopilot_bias
        if ab.enabled and profile.bias_free_message is not None:
            twin = profile.scale_for(profile.bias_free_message)
            assert twin is not None
            self._ab = AutopilotBias(ab, twin.gyro_to_rad_s if twin.integer_fields else 0.0, twin.truncated)
            self._ab_partner, self._ab_primary = profile.bias_free_message, profile.primary_message
            self._ab_instance = INSTANCE_OF_MESSAGE[profile.bias_free_message]  # the twin's IMU: HIGHRES_IMU id 0
        else:
            self._ab = None
            self._ab_partner = self._ab_primary = ""
        if self._ab is not None and ab.mag_enabled:
            twin = profile.scale_for(profile.bias_free_message)
            assert twin is not None
            self._mb = MagBias(ab, twin.mag_to_ut if twin.integer_fields else 0.0, twin.truncated)
            self._mb.set_calibration(mag_calibration(self._params)[0])
        else:
            self._mb = None
        self._calibrators = {
            name: Calibrator(self.settings.calibration, mag_already_calibrated=ms.mag_calibrated)
            for name, ms in profile.messages.items()
        }
        self._update_wants()

    def _message_for_instance(self, imu_id: int) -> str:
        assert self._profile is not None
        return self._profile.primary_message if imu_id == 0 else self._profile.secondary_messages[imu_id - 1]

    def _update_wants(self) -> None:
        """What to ask the autopilot for: the selected IMU at full rate, the others at the monitor rate."""
        s = self.settings
        if self._profile is None:
            return
        fixed = s.selection_settings.fixed
        current = self._selector.selected if self._selector.selected is not None else (fixed or 0)
        for imu_id in range(3):
            name = self._message_for_instance(imu_id)
            if imu_id == current:
                rate = s.stream_rate_hz
            elif fixed is None and not self._selector.is_absent(imu_id):
                rate = s.secondary_imu_rate_hz
            else:
                rate = 0.0
            self._requester.want(
                name, mavlink.__dict__[f"MAVLINK_MSG_ID_{name}"], rate, MAV_DATA_STREAM_RAW_SENSORS,
                warn_low_rate=imu_id == current,  # a board may have no second or third IMU
            )  # fmt: skip
        if self._ab is not None:  # the bias-free twin of the primary message (PX4: SCALED_IMU), at its own rate
            name = self._ab_partner
            self._requester.want(name, mavlink.__dict__[f"MAVLINK_MSG_ID_{name}"], s.autopilot_bias.request_rate_hz,
                                 MAV_DATA_STREAM_RAW_SENSORS, warn_low_rate=False)  # fmt: skip
        wanted = self._velocity.messages  # in the profile's order
        if s.effective_velocity_source == "auto":
            # GLOBAL_POSITION_INT and GPS_RAW_INT (PX4: GPS_RAW_INT first; receiver-only: GPS_RAW_INT and GPS2_RAW)
            wanted = wanted[:2]
        for name, group in _VELOCITY_STREAMS.items():
            # no low-rate warning: PX4 sends GLOBAL_POSITION_INT only with a position estimate, and
            # GPS2_RAW needs a second receiver
            rate = s.gnss_rate_hz if name in wanted else 0.0
            self._requester.want(name, mavlink.__dict__[f"MAVLINK_MSG_ID_{name}"], rate, group, warn_low_rate=False)
        # the autopilot's own attitude, for the second opinion: it compares at the rate this arrives (live
        # against firmware_sim's ArduPilot defaults, 45 ATTITUDE in 52 s when nobody asked)
        att_hz = s.autopilot_attitude_rate_hz if s.monitor.enabled else 0.0
        self._requester.want("ATTITUDE", mavlink.MAVLINK_MSG_ID_ATTITUDE, att_hz, MAV_DATA_STREAM_EXTRA1,
                             warn_low_rate=False)  # fmt: skip

    def _on_imu(self, msg: Any, now_us: int) -> list[Outgoing]:
        hdr = msg.get_header()
        if (hdr.srcSystem, hdr.srcComponent) != self._source:
            why = "no_autopilot_yet" if self._source is None else "foreign_source"
            self._count(self._drops, why)
            if self._source is not None:
                self._notices.warning(
                    f"foreign:{hdr.srcSystem}:{hdr.srcComponent}",
                    f"ignoring {msg.get_type()} from system {hdr.srcSystem}, component {hdr.srcComponent}: "
                    f"IMU data is accepted only from {self._source[0]}/{self._source[1]}",
                    now_us,
                )
            return []
        name = msg.get_type()
        self.samples_in += 1
        self._last_imu_us = now_us
        self._in_meter.add(now_us)
        meter = self._requester.meters.get(name)
        if meter is not None:
            meter.add(now_us)
        assert self._scaler is not None
        v = self._scaler.scale(msg)
        if v is None:
            self._count(self._drops, "no_new_gyro")
            return []
        if self._resends.check(stream_code(name, v[0]), v[1], self._scaler.row) == RESENT:
            return []  # the autopilot sent the same sample twice: not a loss, counted, no notice
        sat, inv = v[12], v[13]
        if sat or inv:
            self._count_flags(sat, inv, name, v[0], now_us)
        ab = self._ab
        if ab is not None:
            if name == self._ab_partner:  # PX4 SCALED_IMU: EKF2's bias against HIGHRES_IMU (ingest.autopilot_bias)
                if self._mb is not None:  # its raw field: EKF2's magnetometer bias (ingest.autopilot_mag_bias)
                    self._mb.pair(v[1], _NAN if (sat | inv) & MAG else v[8], v[9], v[10])
                bad = (sat | inv) & GYRO
                if ab.pair(v[1], _NAN if bad else v[2], v[3], v[4]):
                    self._count(self._counters, "bias_twin_samples")  # served the bias step only
                    return []
            elif name == self._ab_primary and v[0] == self._ab_instance:
                row = self._scaler.row
                if ab.restore(v[1], row, IN_GYRO):
                    v = (v[0], v[1], float(row[IN_GYRO]), float(row[IN_GYRO + 1]), float(row[IN_GYRO + 2]), *v[5:])
                if self._mb is not None and self._mb.restore(v[1], row, IN_MAG):
                    v = (*v[:8], float(row[IN_MAG]), float(row[IN_MAG + 1]), float(row[IN_MAG + 2]), *v[11:])
        if self._monitor_on and not inv:  # every IMU's gyro for the monitor to name an IMU that is off, at most
            t_ms = v[1] / 1000.0  # one sample per _IMU_CHECK_STEP_MS per instance (its mean over 10 s is what
            last = self._imu_fed.get(v[0])  # counts; every sample costs the page's events on a loaded machine)
            if last is None or not 0.0 <= t_ms - last < _IMU_CHECK_STEP_MS:
                self._imu_fed[v[0]] = t_ms
                self._monitor.add_imu_gyro(_IMU_NAMES[v[0]] if v[0] < 4 else f"IMU{v[0] + 1}", t_ms, v[2:5])
        return self._filter_sample(name, v, now_us, True)

    def _filter_sample(self, name: str, v: tuple, now_us: int, may_reset: bool) -> list[Outgoing]:
        sel = self._selector
        feed = sel.observe(name, v)
        if sel.changed:
            self._selection_changed(now_us)
        if not feed:
            imu_id = v[0]
            if sel.is_absent(imu_id):
                self._count(self._counters, "absent_instance_samples")  # not a loss: there is no such IMU
            elif imu_id == sel.selected:
                self._count(self._drops, "duplicate_source")
            else:
                self._count(self._counters, "other_instance_samples")  # watched, not filtered
                bl = self._backlog.get(imu_id)
                if bl is None:
                    bl = self._backlog[imu_id] = deque(maxlen=_BACKLOG)
                bl.append((name, v))
            return []
        bl = self._backlog.get(v[0])
        if bl:
            # just switched to this instance: first the samples it sent while the old one was failing,
            # so the filter integrates over them instead of across a gap
            out: list[Outgoing] = []
            last = self._last_fed_t if self._last_fed_t is not None else -1
            for bname, bv in bl:
                if last < bv[1] < v[1]:
                    self._count(self._counters, "backfilled")
                    out += self._feed(bname, bv, now_us, may_reset)
            bl.clear()
            return out + self._feed(name, v, now_us, may_reset)
        return self._feed(name, v, now_us, may_reset)

    def _feed(self, name: str, v: tuple, now_us: int, may_reset: bool) -> list[Outgoing]:
        """Time, calibrate, filter and (rate permitting) encode one selected sample."""
        imu_id, t = v[0], v[1]
        tl = self._timelines.get(imu_id)
        if tl is None:
            tl = self._timelines[imu_id] = Timeline(self.settings.timeline)
        # the timeline step (Timeline's own, called directly on its state: the hot path), keyed by gyro and accel
        kind, t, ev_dt, _mono = timeline_step(tl.st, tl.fs, t if t <= T_RAW_MAX else T_RAW_MAX, now_us, v[2], v[3],
                                              v[4], v[5], v[6], v[7], 6)  # fmt: skip
        if kind == K_REBOOT:
            if not may_reset:
                self._count(self._drops, "reboot_repeat")
                return []
            self._on_reboot(name, now_us)
            return self._filter_sample(name, v, now_us, False)
        if kind >= K_DUPLICATE:  # duplicate, stale, reordered, held (K_REBOOT handled above)
            self._count(self._drops, _DROP_NAMES[kind])
            return []
        if kind == K_GAP:
            self._count(self._counters, "gaps")
        last_t = self._last_fed_t
        if last_t is None:
            dt = _NAN  # first sample: the filter initialises from it
        elif imu_id == self._last_fed_imu and ev_dt == ev_dt:
            dt = ev_dt
        else:
            dt = (t - last_t) * 1e-6  # switched instance: time since the last sample fed
            if dt <= 0.0:
                self._count(self._drops, "switch_overlap")
                return []
        if kind == K_GAP and dt == dt:
            # The timeline's gap threshold may be shorter than the filter's own max_gap_s: make sure a gap
            # re-initialises the filter (from this sample's accelerometer) instead of integrating this one
            # gyro sample over the whole gap (tens of degrees off while the vehicle turns).
            dt = max(dt, self._gap_dt_s)
        self._last_fed_imu = imu_id
        self._last_fed_t = t
        row = self._row
        write_row(row, dt, v[2], v[3], v[4], v[5], v[6], v[7], v[8], v[9], v[10], v[12], v[13])
        vel = self._vel
        if vel is not None:
            row[IN_VEL], row[IN_VEL + 1], row[IN_VEL + 2], fix_t = vel
            row[IN_VEL_AGE] = fix_age_s(t, fix_t)
            row[IN_POS], row[IN_POS + 1], row[IN_POS + 2] = self._velocity.position_ned
            self._vel = None
            self._vel_written = False
        elif not self._vel_written:
            row[IN_VEL] = row[IN_VEL + 1] = row[IN_VEL + 2] = row[IN_VEL_AGE] = _NAN
            row[IN_POS] = row[IN_POS + 1] = row[IN_POS + 2] = _NAN
            self._vel_written = True
        fresh = self._current_us is not None and now_us - self._current_us <= CURRENT_STALE_S * 1e6
        row[IN_CURRENT] = self._current_a if fresh else _NAN
        cal = self._calibrators[name]
        if cal.active:
            cal.apply_row(row, v[11])
        if self._norm_n < 400:
            self._check_units(name, now_us)
        out = self._filter.update_row(row)
        self.samples_filtered += 1
        snaps = self._snapshots
        if not snaps or t - snaps[-1][0] >= _SNAPSHOT_US:
            snaps.append((t, self._filter.state))
        if self.sample_hook is not None:
            self.sample_hook(name, t, row, out)
        self._filter_meter.add(now_us)
        flags = int(out[OUT_FLAGS])
        if out[OUT_ACCEL_WEIGHT] < 0.5:
            self._accel_rejected_n += 1
        if out[OUT_MAG_WEIGHT] < 0.5 and not flags & FLAG_MAG_INVALID:
            self._mag_rejected_n += 1
        if flags & FLAG_REINITIALISED:
            self._count(self._counters, "filter_reinitialised")
        if flags & FLAG_NOT_INITIALISED:
            self._count(self._drops, "filter_not_initialised")
            return []
        # output rate, on sample time; never twice for one time (replayed samples after a roll-back)
        if t <= self._last_out_t:
            return []
        if self._out_period_us:
            nxt = self._next_out_t
            if nxt is not None and t < nxt - self._out_tol_us:
                return []
            nxt = (nxt if nxt is not None else t) + self._out_period_us
            self._next_out_t = nxt if nxt > t else t + self._out_period_us
        self._last_out_t = t
        return self._attitude_frames(t, out, row, now_us)

    def _attitude_frames(self, t_us: int, out: np.ndarray, row: np.ndarray, now_us: int) -> list[Outgoing]:
        qw, qx, qy, qz = float(out[OUT_Q]), float(out[OUT_Q + 1]), float(out[OUT_Q + 2]), float(out[OUT_Q + 3])
        d = self._decl.declination_rad
        if d:
            qw, qx, qy, qz = apply_declination_wxyz(qw, qx, qy, qz, d)
        p = float(row[IN_GYRO] - out[OUT_BIAS])
        q = float(row[IN_GYRO + 1] - out[OUT_BIAS + 1])
        r = float(row[IN_GYRO + 2] - out[OUT_BIAS + 2])
        t_ms = (t_us // 1000) & 0xFFFFFFFF
        frame = self._frame(_AQ_ID, _AQ_CRC, _AQ_PAYLOAD.pack(t_ms, qw, qx, qy, qz, p, q, r))
        if frame is None:
            frame = self._codec.encode(self._mav.attitude_quaternion_encode(t_ms, qw, qx, qy, qz, p, q, r, _ZERO_Q))
        to_master, to_outputs = self._to_master, self._to_outputs
        frames = [Outgoing(frame, to_master, to_outputs)]
        if self._monitor_on:
            aided = int(out[OUT_FLAGS]) & FLAG_VELOCITY_AIDED
            sigma = float(out[OUT_GAIN]) if aided else math.nan
            sigma_hdg = float(out[OUT_HEADING_SIGMA]) if aided else math.nan  # NaN from a filter without one
            fix = self._monitor_fix  # the evidence of who is wrong: the sample and the last GNSS velocity
            self._monitor.add_sensors(t_ms, row[IN_ACCEL : IN_ACCEL + 3].tolist(), row[IN_MAG : IN_MAG + 3].tolist(),
                                      fix, fix[2] if fix is not None else math.nan)  # fmt: skip
            said = self._monitor.add_estimate(t_ms, (qw, qx, qy, qz), sigma, sigma_hdg, self._filter_meter.rate(now_us))
            for m in self._saying(said) if said else ():
                frames.append(Outgoing(self._codec.encode(m), to_master, to_outputs))
        if self.settings.send_attitude_euler:
            roll = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
            pitch = math.asin(max(-1.0, min(1.0, 2.0 * (qw * qy - qz * qx))))
            yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            frame = self._frame(_ATT_ID, _ATT_CRC, _ATT_PAYLOAD.pack(t_ms, roll, pitch, yaw, p, q, r))
            if frame is None:
                frame = self._codec.encode(self._mav.attitude_encode(t_ms, roll, pitch, yaw, p, q, r))
            frames.append(Outgoing(frame, to_master, to_outputs))
        self.outputs_sent += 1
        self._out_meter.add(now_us)
        return frames

    def _on_velocity(self, msg: Any, now_us: int) -> list[Outgoing]:
        """GLOBAL_POSITION_INT / GPS_RAW_INT / GPS2_RAW: the position feeds the magnetic model; the velocity
        of the source in use (:class:`~mavahrs.sensors.velocity.VelocitySelector`) waits for the next sample."""
        if not self._from_source(msg):
            return []
        if self._decl.handle(msg):
            self._field_changed()
        if msg.get_type() == "GLOBAL_POSITION_INT":
            self._monitor.phase.handle(msg)  # altitude above home and speed: landed or flying
        meter = self._requester.meters.get(msg.get_type())
        if meter is not None:
            meter.add(now_us)
        self._gnss_seen_us = now_us
        f = self._decl.field  # the filter's earth frame is magnetic NED; GNSS velocity is true NED
        got = self._velocity.offer(msg, now_us, f.declination_rad if f is not None else None)
        if got is not None:
            fix, vn, ve, vd = got
            self._gnss_fix_us = now_us
            self._vel = (vn, ve, vd, fix.fix_time_us)
            d = f.declination_rad if f is not None else 0.0  # back to true north, as our published attitude
            fix_ms = fix.fix_time_us / 1000.0 if fix.fix_time_us is not None else math.nan  # (not datable: no verdict)
            self._monitor_fix = (vn * math.cos(d) - ve * math.sin(d), vn * math.sin(d) + ve * math.cos(d), fix_ms)
            if fix.message != self._vel_meter_source:  # the rate shown is the source in use's
                self._vel_meter.reset()
                self._vel_meter_source = fix.message
            self._vel_meter.add(now_us)
        return []

    def _on_current(self, msg: Any, now_us: int) -> list[Outgoing]:
        """SYS_STATUS / BATTERY_STATUS: the battery current, into every following sample's ``IN_CURRENT``."""
        if not self._from_source(msg):
            return []
        amps = battery_current_a(msg)
        if amps is not None:
            self._current_a = amps
            self._current_us = now_us
        return []

    def _on_position_only(self, msg: Any, now_us: int) -> list[Outgoing]:
        if self._from_source(msg) and self._decl.handle(msg):
            self._field_changed()
        return []

    def _field_changed(self) -> None:
        """The expected magnetic field is (newly) known: seed the filter's magnetometer rejection."""
        ref = self._decl.mag_reference()
        setter = getattr(self._filter, "set_mag_reference", None)
        if ref is not None and setter is not None:
            setter(ref[0], ref[1])
        if ref is not None:
            self._monitor.set_mag_reference(ref[0], ref[1])
        self._monitor.heading_valid = self._decl.known

    def _on_autopilot_attitude(self, msg: Any, now_us: int) -> list[Outgoing]:
        """The autopilot's own ATTITUDE / ATTITUDE_QUATERNION: compared with ours (issue 9, second opinion)."""
        if not self._from_source(msg):
            return []
        self._ap_attitude_msg, self._ap_attitude_us = msg, now_us  # converted only when asked for
        meter = self._requester.meters.get(msg.get_type())  # its delivered rate, as the other requested streams'
        if meter is not None:
            meter.add(now_us)
        if not self._monitor_on:
            return []
        said = self._monitor.handle(msg, now_us)
        return [Outgoing(self._codec.encode(m), self._to_master, self._to_outputs) for m in self._saying(said)] if said else []

    def _on_flight_phase(self, msg: Any, now_us: int) -> list[Outgoing]:
        """EXTENDED_SYS_STATE: the autopilot's landed state, for the monitor's flight phase."""
        if self._from_source(msg):
            self._monitor.phase.handle(msg)
        return []

    def _on_command_ack(self, msg: Any, now_us: int) -> list[Outgoing]:
        if not self._from_source(msg):
            return []
        tc = getattr(msg, "target_component", 0)
        if tc not in (0, self._codec.component_id):
            return []  # an answer to someone else's command
        self._requester.on_command_ack(msg.command, msg.result, now_us)
        return []

    def _on_statustext(self, msg: Any, now_us: int) -> list[Outgoing]:
        if self._from_source(msg):
            text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode("ascii", "replace")
            self._requester.on_statustext(text, now_us)
            if "SCHED_LOOP_RATE" in text or "rate" in text.lower() and "too fast" in text.lower():
                self._notices.info("ap-rate-text", f"autopilot says: {text.strip()}", now_us)
        return []

    def _on_foreign_stream_request(self, msg: Any, now_us: int) -> list[Outgoing]:
        """Another node (a ground station, MAVProxy, a router relaying one) changing the autopilot's stream rates.

        Visible when the link carries other nodes' traffic to the autopilot (a
        mavlink-router endpoint, a shared UDP network).  REQUEST_DATA_STREAM
        resets whole stream groups on ArduPilot (RAW_IMU with RAW_SENSORS, or
        all of them): ask again for what it changes, shortly after.
        """
        src = self._source
        if src is None:
            return []
        hdr = msg.get_header()
        sender = (hdr.srcSystem, hdr.srcComponent)
        if sender == src or sender == (self._codec.system_id, self._codec.component_id):
            return []  # the autopilot itself, or our own request relayed back
        if msg.target_system not in (0, src[0]) or msg.target_component not in (0, src[1]):
            return []
        who = f"system {sender[0]} component {sender[1]}"
        if msg.get_type() == "REQUEST_DATA_STREAM":
            self._requester.on_foreign_request(now_us, stream_id=int(msg.req_stream_id), sender=who)
        elif msg.command == MAV_CMD_SET_MESSAGE_INTERVAL:
            self._requester.on_foreign_request(now_us, message_id=int(msg.param1), interval_us=float(msg.param2), sender=who)
        return []

    def _from_source(self, msg: Any) -> bool:
        hdr = msg.get_header()
        return (hdr.srcSystem, hdr.srcComponent) == self._source

    # ------------------------------------------------------------------ events
    def _on_param_value(self, msg: Any, now_us: int) -> list[Outgoing]:
        """The autopilot's parameters that PX4's magnetometer calibration needs (``sensors.px4_mag_calibration``)."""
        hdr = msg.get_header()
        if self._source is None or (hdr.srcSystem, hdr.srcComponent) != self._source:
            return []
        pid = msg.param_id
        name = (pid.decode("ascii", "replace") if isinstance(pid, bytes) else str(pid)).rstrip("\0")
        if not relevant_name(name):
            return []
        self._params[name] = param_value(float(msg.param_value), int(msg.param_type))
        if self._mb is not None:
            cal, reason = mag_calibration(self._params)
            was = self._mb.calibrated
            self._mb.set_calibration(cal)
            if cal is not None and not was:
                self._notices.info("mag-bias-cal", "CAL_MAG* received: the autopilot's magnetometer bias is taken "
                                   f"back out of {self._ab_primary}'s field (from {self._ab_partner})", now_us)  # fmt: skip
            elif cal is None and not missing_names(self._params) and reason != self._mb_reason:
                self._notices.warning("mag-bias-cal", f"{reason}: {self._ab_primary}'s field used as the autopilot "
                                      "sends it (with its EKF's magnetometer bias)", now_us)  # fmt: skip
            self._mb_reason = reason
        return []

    def _request_params(self, now_us: int) -> list[Outgoing]:
        """PARAM_REQUEST_READ for the calibration's parameters not yet received: once a second, at most
        :data:`_PARAM_ROUNDS` times (then HIGHRES_IMU's field stays as sent, said once)."""
        self._param_next_us = now_us + _PARAM_PERIOD_US
        missing = missing_names(self._params)
        if not missing or self._source is None:
            return []
        self._param_rounds += 1
        if self._param_rounds > _PARAM_ROUNDS:
            if self._param_rounds == _PARAM_ROUNDS + 1:
                self._notices.warning("mag-bias-params", f"no answer to PARAM_REQUEST_READ for {', '.join(missing[:3])}"
                                      f"{' …' if len(missing) > 3 else ''}: {self._ab_primary}'s field used as the "
                                      "autopilot sends it (with its EKF's magnetometer bias)", now_us)  # fmt: skip
            return []
        ts, tc = self._source
        return [Outgoing(self._codec.encode(self._mav.param_request_read_encode(ts, tc, n.encode("ascii"), -1)), True, False)
                for n in missing]  # fmt: skip

    def _on_reboot(self, name: str, now_us: int) -> None:
        self._count(self._counters, "reboots")
        self._filter.reset()
        self._selector.reset()
        self._resends.reset()
        if self._ab is not None:
            self._ab.reset()
        if self._mb is not None:
            self._mb.reset()
        self._monitor.reset()
        self._reset_stream_state()
        self._requester.start()
        self._notices.warning(
            "reboot", f"autopilot rebooted ({name} time went back): filter restarted, streams requested again", now_us
        )

    def _selection_changed(self, now_us: int) -> None:
        for ch in self._selector.pop_changes():
            if ch.old is not None and ch.new is not None and ch.bad_since_us is not None:
                self._roll_back(ch.new, ch.bad_since_us, now_us)
            self._count(self._counters, "imu_switches" if ch.old is not None else "imu_selected")
            if ch.new is None:
                self._notices.warning("imu-none", f"no usable IMU instance: {ch.reason}", now_us)
            elif ch.old is None:
                self._notices.info("imu-sel", f"using IMU {ch.new} ({ch.reason})", now_us)
            else:
                self._notices.warning(f"imu-switch:{ch.old}:{ch.new}", f"switched from IMU {ch.old} to IMU {ch.new}: {ch.reason}", now_us)
        self._update_wants()

    def _roll_back(self, new_imu: int, bad_since_us: int, now_us: int) -> None:
        """Undo the filter steps taken on the old instance's bad samples, if the new one can replace them."""
        bl = self._backlog.get(new_imu)
        snaps = self._snapshots
        while snaps and snaps[-1][0] > bad_since_us:
            snaps.pop()
        if not snaps or not bl or bl[0][1][1] > snaps[-1][0] + _SNAPSHOT_US:
            return  # no state from before the fault, or the new instance's samples do not reach back that far
        t_snap, state = snaps[-1]
        self._filter.state = state
        undone = (self._last_fed_t or t_snap) - t_snap
        self._last_fed_t = t_snap
        self._last_fed_imu = None
        self._count(self._counters, "rolled_back")
        self._notices.info(
            "rollback", f"undid {undone * 1e-6:.2f} s of filtering on the failing IMU; re-filtered with IMU {new_imu}", now_us
        )

    def _count_flags(self, sat: int, inv: int, name: str, imu_id: int, now_us: int) -> None:
        for bit, label in ((GYRO, "gyro"), (ACCEL, "accel"), (MAG, "mag")):
            if sat & bit:
                self._count(self._counters, f"saturated_{label}")
                self._notices.warning(
                    f"sat:{label}", f"{name} (IMU {imu_id}): {label} saturated"
                    + (" — its correction is skipped for those samples" if bit != GYRO else " — attitude will lag"),
                    now_us,
                )  # fmt: skip
            if inv & bit:
                self._count(self._counters, f"invalid_{label}")
                self._notices.warning(
                    f"inv:{label}", f"{name} (IMU {imu_id}): {label} NaN, infinite or out of range — skipped", now_us
                )

    def _check_units(self, name: str, now_us: int) -> None:
        row = self._row
        ax, ay, az = row[4], row[5], row[6]
        n = math.sqrt(ax * ax + ay * ay + az * az)
        if n == n:
            self._norm_sum += n
            self._norm_n += 1
            if self._norm_n == 400:
                mean = self._norm_sum / 400
                if not 0.5 * _G < mean < 2.0 * _G:
                    assert self._profile is not None
                    self._notices.warning(
                        "units",
                        f"{name}: the accelerometer reads {mean:.3g} m/s² on average, not ≈ 9.8 — the "
                        f"{self._profile.name} profile's units for {name} look wrong; set autopilot_profile",
                        now_us,
                    )

    def _check_input(self, now_us: int) -> None:
        last = self._last_imu_us
        if self._source_since_us is None:
            self._source_since_us = now_us
        ref = last if last is not None else self._source_since_us
        if now_us - ref > self._no_imu_us:
            since = f" for {(now_us - ref) * 1e-6:.1f} s"
            self._notices.warning("no-imu", f"no IMU messages from the autopilot{since}", now_us)
            return
        if last is None:
            return
        rate = self._filter_meter.rate(now_us)
        # Judge the rate only once the requested one has had time to take effect (the autopilot streams
        # at its default 1-10 Hz until then), and only when it stays low for a whole window.
        sel = self._selector.selected
        settled = self._profile is None or sel is None or self._requester.rate_settled(self._message_for_instance(sel), now_us)
        if settled and self.samples_filtered > 20 and 0 < rate < self.settings.low_imu_rate_hz:
            if self._low_rate_since_us is None:
                self._low_rate_since_us = now_us
            elif now_us - self._low_rate_since_us >= self._low_rate_window_us:
                self._notices.warning(
                    "low-rate",
                    f"IMU samples reach the filter at {rate:.0f} Hz: too slow for meaningful attitude filtering "
                    f"(≥ {self.settings.low_imu_rate_hz:g} Hz needed)",
                    now_us,
                )
        else:
            self._low_rate_since_us = None

    # ------------------------------------------------------------------ encoding
    def _frame(self, msg_id: int, crc_extra: int, payload: bytes) -> bytes | None:
        """One MAVLink 2 frame with our ids and the codec's next sequence number, byte for byte what
        ``MavCodec.encode`` makes of the same message (tested) at a tenth of the cost; None when signing
        is on (the codec signs) — then the caller encodes through the codec."""
        mav = self._mav
        if not self._fast_encode or mav.signing.sign_outgoing:
            return None
        payload = payload.rstrip(b"\0") or b"\0"  # MAVLink 2 truncates trailing zero bytes (keeps one)
        seq = mav.seq
        head = _V2_HEADER.pack(0xFD, len(payload), 0, 0, seq, mav.srcSystem, mav.srcComponent, msg_id & 0xFFFF, msg_id >> 16)
        body = head + payload
        frame = body + _CRC.pack(mavlink.x25crc(body[1:] + bytes((crc_extra,))).crc)
        mav.seq = (seq + 1) % 256
        c = self._codec.counters
        c.packets_out += 1
        c.bytes_out += len(frame)
        return frame

    def _heartbeat_frame(self) -> bytes:
        mav_type, autopilot = self._hb_kind
        frame = self._frame(_HB_ID, _HB_CRC, _HB_PAYLOAD.pack(0, mav_type, autopilot, 0, _MAV_STATE_ACTIVE, 3))
        if frame is not None:
            return frame
        msg = self._mav.heartbeat_encode(mav_type, autopilot, 0, 0, _MAV_STATE_ACTIVE)
        return self._codec.encode(msg)

    def _request_frame(self, req: Any) -> bytes:
        assert self._source is not None
        ts, tc = self._source
        if isinstance(req, RequestDataStream):
            msg = self._mav.request_data_stream_encode(ts, tc, req.stream_id, req.rate_hz, 1)
        else:
            msg = self._mav.command_long_encode(
                ts, tc, MAV_CMD_SET_MESSAGE_INTERVAL, req.confirmation,
                float(req.message_id), float(req.interval_us), 0.0, 0.0, 0.0, 0.0, 0.0,
            )  # fmt: skip
        return self._codec.encode(msg)

    # ------------------------------------------------------------------ reporting
    @staticmethod
    def _count(d: dict[str, int], key: str) -> None:
        d[key] = d.get(key, 0) + 1

    def _timeline_counts(self) -> dict[str, int]:
        out = dict(self._timeline_totals)
        out["exact_duplicates"] = self._resends.resent
        out["same_stamp_changed"] = self._resends.restamped
        for tl in self._timelines.values():
            c = tl.counters
            out["lost_samples"] += c.lost_samples
            out["time_wraps"] += c.wraps
            out["jumps_rejected"] += c.jumps_rejected
        return out

    def live_attitude(self) -> tuple[int | None, tuple[float, float, float, float] | None, Any, int]:
        """Cheap, for a display: ``(time_boot_ms, q_body_to_ned, autopilot message, its receipt µs)``.

        The latest filter output (declination applied as in the output) and the sample time it
        belongs to, or ``(None, None, …)`` before the filter has an attitude; the source's last
        ATTITUDE / ATTITUDE_QUATERNION as received (None before one), unconverted (see
        :func:`~mavahrs.service.monitor.attitude_of_message`).
        """
        out = self._filter._out if hasattr(self._filter, "_out") else None
        ap = self._ap_attitude_msg
        if out is None or int(out[OUT_FLAGS]) & FLAG_NOT_INITIALISED or self._last_fed_t is None:
            return None, None, ap, self._ap_attitude_us
        q = tuple(out[OUT_Q : OUT_Q + 4].tolist())
        d = self._decl.declination_rad
        if d:
            q = apply_declination_wxyz(*q, d)
        return (self._last_fed_t // 1000) & 0xFFFFFFFF, q, ap, self._ap_attitude_us

    def _gnss_state(self, now_us: int) -> str:
        if self.settings.effective_velocity_source == "none":
            return "off"
        if self._gnss_seen_us is None:
            return "none"
        fix = self._gnss_fix_us
        return "in use" if fix is not None and now_us - fix <= _GNSS_FRESH_US else "no fix"

    def status(self, now_us: int | None = None, *, window: str = "log") -> PipelineStatus:
        """A snapshot; ``now_us`` defaults to the last tick's time (for the rates).

        ``window``: the rejection shares are over the samples since the previous call with the
        same window (the status line and the status page each have their own)."""
        now = now_us if now_us is not None else (self._last_tick_us or 0)
        diag = self._filter.diagnostics
        out = self._filter._out if hasattr(self._filter, "_out") else None
        init = bool(out is not None and not int(out[OUT_FLAGS]) & FLAG_NOT_INITIALISED)
        q = None
        if init and out is not None:
            q = (float(out[OUT_Q]), float(out[OUT_Q + 1]), float(out[OUT_Q + 2]), float(out[OUT_Q + 3]))
            d = self._decl.declination_rad
            if d:
                q = apply_declination_wxyz(*q, d)
        b = diag.gyro_bias_rad_s
        n0, a0, m0 = self._status_marks.get(window, (0, 0, 0))
        n = self.samples_filtered - n0
        acc_pct = 100.0 * (self._accel_rejected_n - a0) / n if n else 0.0
        mag_pct = 100.0 * (self._mag_rejected_n - m0) / n if n else 0.0
        self._status_marks[window] = (self.samples_filtered, self._accel_rejected_n, self._mag_rejected_n)
        connected = self._last_hb_us is not None and not self._link_lost and now - self._last_hb_us <= self._hb_timeout_us
        vs = self._velocity
        vel_in_use = vs.in_use(now)
        vel_label = LABELS[vel_in_use] if vel_in_use is not None else "none"
        self._monitor.velocity_source = vel_label
        return PipelineStatus(
            connected=connected,
            vehicle=self._source,
            autopilot_profile=self._profile.name if self._profile else None,
            filter_name=self._filter_name,
            input_rate_hz=self._in_meter.rate(now),
            filter_rate_hz=self._filter_meter.rate(now),
            output_rate_hz=self._out_meter.rate(now),
            samples_in=self.samples_in,
            samples_filtered=self.samples_filtered,
            outputs_sent=self.outputs_sent,
            drops=dict(self._drops),
            samples_dropped=sum(self._drops.values()),
            counters={**self._counters, "duplicate_source": self._selector.duplicate_source, **self._timeline_counts(),
                      **({f"autopilot_bias_{k}": n for k, n in self._ab.counts.items()} if self._ab is not None else {}),
                      **({f"autopilot_mag_bias_{k}": n for k, n in self._mb.counts.items()} if self._mb is not None else {})},
            initialised=init,
            gain=diag.gain,
            accel_weight=diag.accel_weight,
            mag_weight=diag.mag_weight,
            accel_rejected=diag.accel_rejected,
            mag_rejected=diag.mag_rejected,
            accel_rejection_pct=acc_pct,
            mag_rejection_pct=mag_pct,
            bias_deg_s=(b[0] * _RAD2DEG, b[1] * _RAD2DEG, b[2] * _RAD2DEG),
            q_body_to_ned=q,
            imu_in_use=self._selector.selected,
            imu_reason=self._selector.reason,
            imu_instances=self._selector.instances(),
            streams=self._requester.states(now),
            heading_reference=self._decl.status(),
            monitor=self._monitor.status.text() if self._monitor_on else "",
            velocity="vel none" if vel_in_use is None else f"vel {vel_label} {self._vel_meter.rate(now):.0f} Hz",
            velocity_fixes={m: vs.used(m) for m in vs.messages},
            velocity_skipped=dict(vs.counters),
            monitor_state=self._monitor.status if self._monitor_on else None,
            gnss_velocity=self._gnss_state(now),
            magnetometer=self._mag_status(),
        )

    def _monitor_mag_model(self) -> None:
        """The magnetometer model's learnt offsets and state (its public summary), for the monitor's evidence
        (None while the model is off, or still learning)."""
        state = self._mag_model_state()
        if not state or state.get("state") == "learning":
            self._monitor.set_mag_offsets(None)
            return
        self._monitor.set_mag_offsets(state.get("offset_ut"), disturbed=state.get("state") == "disturbed")

    def _mag_status(self) -> dict[str, Any] | None:
        """The magnetometer's state for the status (the filter's ``mag_status``: model or trust, declination)."""
        get = getattr(self._filter, "mag_status", None)
        return get() if get is not None else self._mag_model_state()

    def _mag_model_state(self) -> dict[str, Any] | None:
        get = getattr(self._filter, "mag_model_state", None)
        return get() if get is not None else None

    @property
    def velocity_selector(self) -> VelocitySelector:
        """The GNSS velocity source choice (counts of fixes fed and skipped)."""
        return self._velocity

