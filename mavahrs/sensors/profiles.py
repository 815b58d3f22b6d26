r"""What each autopilot puts in each IMU message: units, timestamps, calibration.

A :class:`MessageScale` says how one MAVLink message's fields become SI
values, and what the autopilot has already done to them; an
:class:`AutopilotProfile` holds one per message.  The profile is chosen from
the autopilot's HEARTBEAT (``autopilot`` field, :func:`profile_for_autopilot`)
unless the user names one.  Every entry cites where its facts come from; the
table is reproduced in ``docs/pipeline.md``.

Sources (read for this module):

* MAVLink ``common.xml`` field units (as carried by pymavlink 2.4 dialects):
  RAW_IMU and SCALED_IMU/2/3 ``xacc`` mG, ``xgyro`` mrad/s, ``xmag`` mgauss,
  ``temperature`` cdegC (0 = not provided, 1 = 0 °C); HIGHRES_IMU m/s², rad/s,
  gauss, ``fields_updated`` bit mask (bits 0–2 accel, 3–5 gyro, 6–8 mag).
  SCALED_IMU ``xmag`` was changed from mT to mgauss in mavlink/mavlink PR #1199
  (2019) because ArduPilot already sent mgauss.
* ArduPilot ``libraries/GCS_MAVLink/GCS_Common.cpp``:
  ``send_raw_imu()`` sends ``ins.get_accel(0) * 1000 / GRAVITY_MSS`` (mG),
  ``ins.get_gyro(0) * 1000`` (mrad/s), ``compass.get_field(0)`` (mgauss),
  ``time_usec = AP_HAL::micros64()`` — the time the message is *sent* in the
  scheduler loop, not the sample time — ``id = 0`` and
  ``temperature = ins.get_temperature(0) * 100``.  ``get_accel``/``get_gyro``
  are the calibrated (offsets, scale, temperature calibration), board-rotated
  and low-pass filtered (INS_ACCEL_FILTER / INS_GYRO_FILTER) values the EKF
  uses; ``get_field`` has offsets, soft-iron diagonals/off-diagonals and motor
  compensation applied.  ``send_scaled_imu(instance)`` (SCALED_IMU2/3) sends
  the same quantities for instance 1/2 with ``time_boot_ms = AP_HAL::millis()``;
  when the board has a second compass but no second IMU, accel and gyro are
  sent as zeros (seen in ArduSub logs).  ``send_highres_imu()`` sends SI
  accel/gyro of the primary IMU with ``time_usec = micros64()`` and the
  magnetometer as ``compass.get_field() * 1000`` under the comment "convert to
  gauss" — 10⁶ too large (|m| ≈ 5·10⁵); fixed to ``* 0.001`` by ArduPilot PR
  #32286 (2026).  Both scalings are accepted here (see ``mag_legacy_to_ut``).
* PX4 ``src/modules/mavlink/streams/HIGHRES_IMU.hpp``: accel and gyro are the
  ``vehicle_imu`` integrals divided by their integration time (calibrated,
  averaged over the interval) minus the EKF's bias estimate; mag is
  ``vehicle_magnetometer`` (calibrated) minus the EKF mag bias, in gauss;
  ``time_usec = imu.timestamp_sample`` (the sample time); ``temperature`` is
  the barometer's, not the IMU's; ``id`` is left 0.
* PX4 ``streams/SCALED_IMU.hpp`` (and ``SCALED_IMU2/3.hpp``): accel/gyro from
  ``vehicle_imu`` (calibrated) in mG and mrad/s, mag from the raw
  ``sensor_mag`` topic ×1000 (gauss → mgauss) *without* the user's
  calibration, ``time_boot_ms = imu.timestamp / 1000`` (publication time),
  temperature cdegC with 0 → 1.
* PX4 does not have a RAW_IMU stream (its ``streams/`` directory has none).
  The only PX4 RAW_IMU producer found is a 2017 Snapdragon branch that MAVROS
  reads with ``MILLIMS2_TO_MS2`` for accel (mm/s²) and mrad/s for gyro (MAVROS
  ``imu.cpp`` ``handle_raw_imu``, PR #893).  The ``px4`` profile uses those
  units for RAW_IMU and marks them uncertain; the pipeline's accel-norm check
  says so when the numbers do not look like gravity.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from mavahrs.errors import ConfigError

__all__ = [
    "G_M_S2",
    "MessageScale",
    "AutopilotProfile",
    "PROFILES",
    "PROFILE_NAMES",
    "IMU_MESSAGES",
    "INSTANCE_OF_MESSAGE",
    "get_profile",
    "profile_for_autopilot",
    "MAV_AUTOPILOT_ARDUPILOTMEGA",
    "MAV_AUTOPILOT_PX4",
]

#: Standard gravity used by MAVLink's mG (ArduPilot GRAVITY_MSS, PX4 CONSTANTS_ONE_G).
G_M_S2 = 9.80665
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12

_MG = G_M_S2 / 1000.0  # 1 mG in m/s²
_MRAD = 1e-3  # 1 mrad/s in rad/s
_MGAUSS = 0.1  # 1 mgauss in µT
_GAUSS = 100.0  # 1 gauss in µT

#: The IMU messages the pipeline reads.
IMU_MESSAGES: tuple[str, ...] = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
#: Fixed IMU instance of each message (HIGHRES_IMU and RAW_IMU carry an ``id`` field instead).
INSTANCE_OF_MESSAGE: Mapping[str, int] = MappingProxyType(
    {"RAW_IMU": 0, "SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2, "HIGHRES_IMU": 0}
)


@dataclass(frozen=True)
class MessageScale:
    """How one message's fields become SI values, and what was done to them upstream.

    Attributes:
        message: MAVLink message name.
        accel_to_m_s2: multiply the wire value by this to get m/s².
        gyro_to_rad_s: … to get rad/s.
        mag_to_ut: … to get µT.
        time_field: ``"time_usec"`` or ``"time_boot_ms"``.
        time_to_us: multiply the time field by this to get µs.
        temperature_to_c: multiply ``temperature`` by this to get °C; None =
            the field is not the IMU's temperature (or absent): ignore it.
        integer_fields: the vectors are int16 on the wire (saturate at ±32767).
        accel_range_m_s2: sensor full scale; a reading at ≥ 98 % is saturated.
        gyro_range_rad_s: sensor full scale, rad/s.
        mag_calibrated: the autopilot already applied hard/soft-iron
            calibration: a user calibration is not applied again.
        accel_gyro_calibrated: offsets/scale (and, PX4 HIGHRES_IMU, the EKF
            bias estimate) are already removed.
        low_passed: the values are filtered/averaged upstream.
        sample_time: the timestamp is the sample time (False: the send time
            in the autopilot's scheduler loop, jittering by its loop period).
        mag_legacy_to_ut: when the field norm in µT exceeds
            ``mag_plausible_max_ut``, rescale the raw values by this instead
            (ArduPilot HIGHRES_IMU before PR #32286); None = no fallback.
        mag_plausible_max_ut: largest believable field norm, µT.
        truncated: the integer fields are the float values truncated toward
            zero (a C cast; PX4 ``SCALED_IMU.hpp``: ``msg.xgyro = gyro(0) * 1e3f``),
            not rounded: a reading n stands for [n, n+1) (n > 0), (n−1, n] (n < 0).
            Measured on the PX4 SIH tlog (SCALED_IMU less HIGHRES_IMU, mean
            residual −0.43 / +0.40 mrad/s for n > 0 / n < 0).  Used where a
            reading is compared with a float one (:mod:`mavahrs.ingest.autopilot_bias`).
        delay_s: how far the values trail their time stamp, s: the group
            delay of the autopilot's low-pass (ArduPilot's INS_GYRO_FILTER,
            a 20 Hz second-order filter by default: √2/(2π·20 Hz) ≈ 11 ms;
            measured on ArduCopter SITL against its true rates: 10–12 ms).
            The velocity-aided filter compares GNSS fixes with its velocity
            this much later and advances its output by it.  0 = not known.
        source: where these facts come from.
        note: anything a user should know.
    """

    message: str
    accel_to_m_s2: float
    gyro_to_rad_s: float
    mag_to_ut: float
    time_field: str
    time_to_us: int
    temperature_to_c: float | None
    integer_fields: bool
    accel_range_m_s2: float = 16.0 * G_M_S2
    gyro_range_rad_s: float = math.radians(2000.0)
    mag_calibrated: bool = False
    accel_gyro_calibrated: bool = True
    low_passed: bool = True
    sample_time: bool = False
    mag_legacy_to_ut: float | None = None
    mag_plausible_max_ut: float = 2000.0
    truncated: bool = False
    delay_s: float = 0.0
    source: str = ""
    note: str = ""

    def __post_init__(self) -> None:
        if self.message not in IMU_MESSAGES:
            raise ConfigError(f"MessageScale for unknown message {self.message!r}; expected one of {IMU_MESSAGES}")
        if self.time_field not in ("time_usec", "time_boot_ms"):
            raise ConfigError(f"{self.message}: time_field must be time_usec or time_boot_ms")
        for name in ("accel_to_m_s2", "gyro_to_rad_s", "mag_to_ut", "accel_range_m_s2", "gyro_range_rad_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{self.message}: {name} must be a positive number, got {v!r}")


@dataclass(frozen=True)
class AutopilotProfile:
    """The scaling of every IMU message as one autopilot sends it.

    Attributes:
        name: ``"ardupilot"``, ``"px4"`` or ``"generic"``.
        description: one line for people.
        messages: message name → :class:`MessageScale`.
        primary_message: the message to request for instance 0.
        secondary_messages: messages carrying instances 1 and 2.
        velocity_order: the GNSS velocity messages ``velocity_source = auto``
            takes, in order of preference (:mod:`mavahrs.sensors.velocity`).
            ArduPilot and generic: GLOBAL_POSITION_INT (the EKF's velocity, 3 ms
            old), then the receiver's GPS_RAW_INT (90–200 ms old).  PX4: the
            receiver's GPS_RAW_INT first (``sensor_gps``, stamped at its sample
            time), then GLOBAL_POSITION_INT — PX4 fills the latter with EKF2's
            output-predictor velocity (``vehicle_local_position``), whose error
            follows EKF2's own attitude and tracking errors: against the simulator's
            truth on the PX4 SITL flight 0.19–0.26 m/s RMS per axis in the
            manoeuvres, the receiver's 0.06–0.08 m/s at no measurable lag
            (``docs/accuracy.md``, "PX4: which velocity").
        bias_free_message: a message carrying the same IMU samples as
            ``primary_message`` *without* the autopilot's EKF gyro-bias estimate
            subtracted, from which that estimate is recovered and added back
            (:mod:`mavahrs.ingest.autopilot_bias`); None = the primary message has
            no bias subtracted (or no twin).  PX4: SCALED_IMU (``vehicle_imu``
            instance 0, calibrated only) beside HIGHRES_IMU (the same minus
            ``estimator_sensor_bias``).
    """

    name: str
    description: str
    messages: Mapping[str, MessageScale] = field(default_factory=dict)
    primary_message: str = "RAW_IMU"
    secondary_messages: tuple[str, ...] = ("SCALED_IMU2", "SCALED_IMU3")
    velocity_order: tuple[str, ...] = ("GLOBAL_POSITION_INT", "GPS_RAW_INT", "GPS2_RAW")
    bias_free_message: str | None = None

    def scale_for(self, message: str) -> MessageScale | None:
        return self.messages.get(message)


def _int_msg(message: str, time_field: str, **kw: object) -> MessageScale:
    """mG / mrad/s / mgauss int16 message (RAW_IMU as ArduPilot sends it, SCALED_IMU*)."""
    return MessageScale(
        message=message,
        accel_to_m_s2=_MG,
        gyro_to_rad_s=_MRAD,
        mag_to_ut=_MGAUSS,
        time_field=time_field,
        time_to_us=1 if time_field == "time_usec" else 1000,
        temperature_to_c=0.01,
        integer_fields=True,
        **kw,  # type: ignore[arg-type]
    )


_AP_SRC = "ArduPilot GCS_Common.cpp send_raw_imu/send_scaled_imu; MAVLink common.xml units"
#: group delay of ArduPilot's default INS_GYRO_FILTER / INS_ACCEL_FILTER (20 Hz, second order), s
AP_INS_DELAY_S = math.sqrt(2.0) / (2.0 * math.pi * 20.0)
_ARDUPILOT = AutopilotProfile(
    name="ardupilot",
    description="ArduPilot",
    messages=MappingProxyType(
        {
            "RAW_IMU": _int_msg(
                "RAW_IMU", "time_usec", mag_calibrated=True, source=_AP_SRC, delay_s=AP_INS_DELAY_S,
                note="calibrated, board-rotated, low-passed; time_usec is the send time (loop-period jitter)",
            ),
            "SCALED_IMU": _int_msg(
                "SCALED_IMU", "time_boot_ms", mag_calibrated=True, source=_AP_SRC, delay_s=AP_INS_DELAY_S,
                note="identical to RAW_IMU on ArduPilot, ms timestamps",
            ),
            "SCALED_IMU2": _int_msg(
                "SCALED_IMU2", "time_boot_ms", mag_calibrated=True, source=_AP_SRC, delay_s=AP_INS_DELAY_S,
                note="instance 1; accel/gyro all zero when only a second compass exists",
            ),
            "SCALED_IMU3": _int_msg(
                "SCALED_IMU3", "time_boot_ms", mag_calibrated=True, source=_AP_SRC, delay_s=AP_INS_DELAY_S,
                note="instance 2; accel/gyro all zero when only a third compass exists",
            ),
            "HIGHRES_IMU": MessageScale(
                message="HIGHRES_IMU", accel_to_m_s2=1.0, gyro_to_rad_s=1.0, mag_to_ut=_GAUSS,
                time_field="time_usec", time_to_us=1, temperature_to_c=None, integer_fields=False,
                mag_calibrated=True, mag_legacy_to_ut=1e-4, delay_s=AP_INS_DELAY_S,
                source="ArduPilot GCS_Common.cpp send_highres_imu; PR #32286",
                note="mag was sent as mgauss×1000 before PR #32286 (rescaled automatically); temperature is the baro's",
            ),  # fmt: skip
        }
    ),
    primary_message="RAW_IMU",
)

_PX4_SRC = "PX4 src/modules/mavlink/streams/SCALED_IMU*.hpp; MAVLink common.xml units"
_PX4 = AutopilotProfile(
    name="px4",
    description="PX4",
    messages=MappingProxyType(
        {
            "RAW_IMU": MessageScale(
                message="RAW_IMU", accel_to_m_s2=1e-3, gyro_to_rad_s=_MRAD, mag_to_ut=_MGAUSS,
                time_field="time_usec", time_to_us=1, temperature_to_c=0.01, integer_fields=True,
                mag_calibrated=False, accel_gyro_calibrated=False, low_passed=False, sample_time=True,
                source="MAVROS imu.cpp handle_raw_imu (PR #893): PX4 RAW_IMU accel in mm/s²; no RAW_IMU stream in PX4 main",
                note="uncertain: current PX4 sends no RAW_IMU; units from the only known PX4 producer",
            ),  # fmt: skip
            "SCALED_IMU": _int_msg(
                "SCALED_IMU", "time_boot_ms", mag_calibrated=False, sample_time=False, source=_PX4_SRC,
                truncated=True,
                note="mag is the raw sensor_mag (not calibrated); time is the publication time; no EKF bias "
                "subtracted (HIGHRES_IMU's is recovered from it)",
            ),
            "SCALED_IMU2": _int_msg(
                "SCALED_IMU2", "time_boot_ms", mag_calibrated=False, source=_PX4_SRC, note="instance 1",
            ),
            "SCALED_IMU3": _int_msg(
                "SCALED_IMU3", "time_boot_ms", mag_calibrated=False, source=_PX4_SRC, note="instance 2",
            ),
            "HIGHRES_IMU": MessageScale(
                message="HIGHRES_IMU", accel_to_m_s2=1.0, gyro_to_rad_s=1.0, mag_to_ut=_GAUSS,
                time_field="time_usec", time_to_us=1, temperature_to_c=None, integer_fields=False,
                mag_calibrated=True, sample_time=True, source="PX4 src/modules/mavlink/streams/HIGHRES_IMU.hpp",
                note="EKF bias estimates already subtracted (the gyro's is added back from SCALED_IMU when the "
                "stream carries it: mavahrs.ingest.autopilot_bias); temperature is the baro's",
            ),  # fmt: skip
        }
    ),
    primary_message="HIGHRES_IMU",
    velocity_order=("GPS_RAW_INT", "GLOBAL_POSITION_INT", "GPS2_RAW"),
    bias_free_message="SCALED_IMU",
)

_GENERIC_SRC = "MAVLink common.xml field units"
_GENERIC = AutopilotProfile(
    name="generic",
    description="any other MAVLink autopilot: common.xml units, nothing assumed calibrated",
    messages=MappingProxyType(
        {
            "RAW_IMU": _int_msg("RAW_IMU", "time_usec", source=_GENERIC_SRC, low_passed=False),
            "SCALED_IMU": _int_msg("SCALED_IMU", "time_boot_ms", source=_GENERIC_SRC, low_passed=False),
            "SCALED_IMU2": _int_msg("SCALED_IMU2", "time_boot_ms", source=_GENERIC_SRC, low_passed=False),
            "SCALED_IMU3": _int_msg("SCALED_IMU3", "time_boot_ms", source=_GENERIC_SRC, low_passed=False),
            "HIGHRES_IMU": MessageScale(
                message="HIGHRES_IMU", accel_to_m_s2=1.0, gyro_to_rad_s=1.0, mag_to_ut=_GAUSS,
                time_field="time_usec", time_to_us=1, temperature_to_c=None, integer_fields=False,
                low_passed=False, source=_GENERIC_SRC,
            ),  # fmt: skip
        }
    ),
    primary_message="RAW_IMU",
)

#: All profiles by name.
PROFILES: Mapping[str, AutopilotProfile] = MappingProxyType(
    {p.name: p for p in (_ARDUPILOT, _PX4, _GENERIC)}
)
PROFILE_NAMES: tuple[str, ...] = tuple(PROFILES)


def get_profile(name: str) -> AutopilotProfile:
    """The profile called ``name`` (``ardupilot``, ``px4``, ``generic``)."""
    try:
        return PROFILES[name]
    except KeyError:
        raise ConfigError(
            f"unknown autopilot profile {name!r}; choose one of {', '.join(PROFILE_NAMES)} or auto"
        ) from None


#: MAV_TYPE values of multirotors (quad, hexa, octo, tri, coaxial, deca, dodeca, generic): the
#: vehicles whose horizontal specific force is mostly rotor drag (the ESKF's drag measurement)
MULTIROTOR_MAV_TYPES = frozenset((2, 3, 13, 14, 15, 29, 35, 43))


def profile_for_autopilot(autopilot: int) -> AutopilotProfile:
    """The profile for a HEARTBEAT ``autopilot`` value (MAV_AUTOPILOT_*)."""
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        return _ARDUPILOT
    if autopilot == MAV_AUTOPILOT_PX4:
        return _PX4
    return _GENERIC
