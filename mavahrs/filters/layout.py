"""Row layouts shared by every filter kernel (plain integer constants).

Kernels see one input row and write one output row per sample, both flat
``float64`` arrays, so that the same code runs interpreted, compiled, per
sample or over a whole recording.  Numba treats these module-level integers as
compile-time constants.

Input row (``IN_WIDTH`` values):

==========  =====================================================  ==========
index       meaning                                                unit
==========  =====================================================  ==========
IN_DT       time since the previous sample                         s
IN_GYRO+k   angular rate, body (sensor) axes, k = 0, 1, 2          rad/s
IN_ACCEL+k  specific force, body axes (level FRD at rest ≈ −g z)   m/s²
IN_MAG+k    magnetic field, body axes; NaN = no magnetometer       µT
IN_VEL+k    GNSS velocity in (magnetic) NED; NaN = no fix; a NaN   m/s
            component alone = that component unknown (GPS_RAW_INT
            and GPS2_RAW give no vertical: (vn, ve, NaN))
IN_VEL_AGE  age of the velocity in IN_VEL at this sample's time:   s
            sample time − the fix's own time stamp (0 when the
            fix's time stamp is on another clock); NaN when
            IN_VEL is NaN
IN_CURRENT  battery current (SYS_STATUS / BATTERY_STATUS), the     A
            compass's motor interference scales with it; NaN =
            not known
IN_POS+k    GNSS position of the same fix as IN_VEL (its age is    m
            IN_VEL_AGE), (magnetic) NED relative to the first
            fix's position (the origin: lat, lon, alt of the
            first fix the reader used); NaN = no fix in this
            row; a NaN down = no altitude
==========  =====================================================  ==========

Output row (``OUT_WIDTH`` values): the attitude and the diagnostics.

===============  ==========================================================
OUT_Q+k          q_body_to_ned, scalar first
OUT_GAIN         current main correction gain (β, K_P, α or k_g), after the
                 start-up boost and the rejection weights; ``eskf``: its
                 1-σ tilt uncertainty, rad (the Kalman gain follows it)
OUT_ACCEL_WEIGHT trust in the accelerometer this sample, 0 (rejected) … 1
OUT_MAG_WEIGHT   trust in the magnetometer this sample, 0 … 1 (0 without one)
OUT_BIAS+k       gyro bias estimate, body axes, rad/s
OUT_FLAGS        bit field of FLAG_* below
OUT_HEADING_SIGMA ``eskf`` (and ``best`` while it sends the ESKF's): its 1-σ
                 heading uncertainty, rad (√P of the error state's rotation
                 about down, NED); NaN for filters without a covariance
===============  ==========================================================
"""

from __future__ import annotations

IN_DT = 0
IN_GYRO = 1
IN_ACCEL = 4
IN_MAG = 7
IN_VEL = 10
IN_VEL_AGE = 13
IN_CURRENT = 14
IN_POS = 15
IN_WIDTH = 18

OUT_Q = 0
OUT_GAIN = 4
OUT_ACCEL_WEIGHT = 5
OUT_MAG_WEIGHT = 6
OUT_BIAS = 7
OUT_FLAGS = 10
OUT_HEADING_SIGMA = 11
OUT_WIDTH = 12

#: The accelerometer vector was zero or non-finite: its correction was skipped.
FLAG_ACCEL_INVALID = 1
#: The magnetometer vector was zero or non-finite (or absent): skipped.
FLAG_MAG_INVALID = 2
#: The gyro was non-finite: the propagation step was skipped.
FLAG_GYRO_INVALID = 4
#: dt was ≤ 0 or non-finite: no propagation this sample.
FLAG_DT_INVALID = 8
#: dt exceeded the maximum gap: the filter re-initialised from this sample.
FLAG_REINITIALISED = 16
#: The filter has not yet seen a valid accelerometer sample to start from.
FLAG_NOT_INITIALISED = 32
#: Still in the start-up convergence phase (boosted gains).
FLAG_STARTUP = 64
#: A sensor reading is at or beyond its saturation limit (caller-detected).
FLAG_SATURATED = 128
#: The attitude is GNSS-velocity-aided (``eskf``, and ``best`` while it sends the ESKF's): OUT_GAIN is then
#: the filter's 1-σ tilt uncertainty and OUT_HEADING_SIGMA its heading's, which the second-opinion monitor's
#: thresholds use.
FLAG_VELOCITY_AIDED = 256
#: The heading was set from this sample's magnetometer reading: the filter had started (or restarted) from an
#: accelerometer sample without one (a DataFlash log's IMU rows before its first MAG record, a stream whose
#: compass speaks later), its heading till now an arbitrary 0, not a measurement.
FLAG_HEADING_ALIGNED = 512

__all__ = [name for name in dir() if name.isupper()]
