"""A filter started before its first magnetometer reading takes its heading from that reading.

A DataFlash log's IMU rows come before its first MAG record (10 Hz), a stream's compass may speak
later than its IMU: the filter starts from the accelerometer alone, heading 0. Before, that arbitrary
heading stayed (the ESKF with its magnetometer model seeded from the data took the start's heading for
the field's north: ArduSub's ``small.BIN`` read 161° away from EKF3 for the whole log), or took tens
of seconds to leave (Madgwick's β). The first reading now sets the heading, as it would have at the start.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mavahrs.filters import create
from mavahrs.filters.layout import (
    FLAG_HEADING_ALIGNED,
    IN_ACCEL,
    IN_DT,
    IN_GYRO,
    IN_MAG,
    IN_WIDTH,
    OUT_FLAGS,
    OUT_Q,
)

DT_S = 0.0025  # 400 Hz IMU rows
MAG_EVERY = 40  # a reading on every 40th row (10 Hz), the first at 0.1 s
HEADING_DEG = 140.0  # the vehicle's true heading (magnetic), level


def _rows(duration_s: float = 20.0) -> np.ndarray:
    rng = np.random.default_rng(7)
    n = int(duration_s / DT_S)
    rows = np.full((n, IN_WIDTH), np.nan)
    rows[:, IN_DT] = DT_S
    rows[:, IN_GYRO : IN_GYRO + 3] = rng.normal(0.0, 0.002, (n, 3))
    rows[:, IN_ACCEL : IN_ACCEL + 3] = rng.normal(0.0, 0.05, (n, 3)) + (0.0, 0.0, -9.80665)
    dip = math.radians(60.0)
    f_ned = 48.0 * np.array([math.cos(dip), 0.0, math.sin(dip)])
    psi = math.radians(HEADING_DEG)
    # body = C_bodyᵀ f_NED with C a rotation about down by ψ
    f_body = np.array([math.cos(psi) * f_ned[0], -math.sin(psi) * f_ned[0], f_ned[2]])
    idx = np.arange(MAG_EVERY, n, MAG_EVERY)
    rows[idx, IN_MAG : IN_MAG + 3] = f_body + rng.normal(0.0, 0.3, (len(idx), 3))
    return rows


def _heading_error_deg(out: np.ndarray) -> np.ndarray:
    q = out[:, OUT_Q : OUT_Q + 4]
    yaw = np.degrees(np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2)))
    return (yaw - HEADING_DEG + 180.0) % 360.0 - 180.0


@pytest.mark.parametrize("name", ["best", "best-vehicle", "eskf", "madgwick", "mahony", "complementary", "gyroplatform"])
def test_the_first_reading_after_a_start_without_one_sets_the_heading(name: str) -> None:
    rows = _rows()
    f = create("best" if name == "best-vehicle" else name)
    if name == "best-vehicle":
        f.set_vehicle_stream()  # type: ignore[attr-defined]  # an autopilot's stream: the magnetometer model on
    out = f.run(rows)
    err = _heading_error_deg(out)
    t = np.arange(len(rows)) * DT_S
    assert abs(err[0]) > 100.0  # started without a reading: heading 0, 140° off
    aligned = np.flatnonzero(out[:, OUT_FLAGS].astype(int) & FLAG_HEADING_ALIGNED)
    # one alignment, on the first row with a reading (a filter may wrap more than one estimate: best)
    assert len(aligned) == 1 and aligned[0] == MAG_EVERY
    assert np.max(np.abs(err[t > 0.2])) < 3.0


def test_a_start_with_a_reading_is_not_aligned_again() -> None:
    rows = _rows()
    rows[0, IN_MAG : IN_MAG + 3] = rows[MAG_EVERY, IN_MAG : IN_MAG + 3]
    out = create("eskf").run(rows)
    assert not np.any(out[:, OUT_FLAGS].astype(int) & FLAG_HEADING_ALIGNED)
    assert np.max(np.abs(_heading_error_deg(out))) < 3.0


SUB_BIN = Path(__file__).resolve().parents[3] / "shared" / "data" / "mavlink_logs" / "ardusub_log_tools" / "small.BIN"


def test_ardusub_log_heading_follows_its_compass_not_the_start() -> None:
    """ArduSub's small.BIN (no GNSS; IMU rows before the first MAG record; its field 91 µT): ``best``
    as replay runs it against the log's EKF3 — before, 161° apart for the whole 24 s."""
    if not SUB_BIN.is_file():
        pytest.skip(f"shared data not found: {SUB_BIN}")
    from mavahrs.evaluation.metrics import euler_deg
    from mavahrs.logs import autopilot_reference, read_log

    log = read_log(SUB_BIN)
    f = create("best")
    f.set_vehicle_stream()  # type: ignore[attr-defined]  # as replay runs an autopilot's log
    out = f.run(log.inputs.rows)
    name = autopilot_reference(log.references)
    t_ref, q_ref = log.references[name]
    later = t_ref > log.inputs.t_us[0] + 1_000_000  # from 1 s on: the first MAG record is 0.1 s in
    t_ref, q_ref = t_ref[later], q_ref[later]
    j = np.clip(np.searchsorted(log.inputs.t_us, t_ref), 0, len(log.inputs.t_us) - 1)
    # ours is in the magnetic frame: the declination replay applies to its outputs, added
    ours = euler_deg(out[j, OUT_Q : OUT_Q + 4])[:, 2] + np.degrees(log.inputs.declination_rad[j])
    d = (ours - euler_deg(q_ref)[:, 2] + 180.0) % 360.0 - 180.0
    assert np.sqrt(np.mean(d**2)) < 5.0, f"heading {np.sqrt(np.mean(d**2)):.1f}° RMS from {name}"
