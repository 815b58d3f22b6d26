"""``mavahrs calibrate-mag``: synthetic tlogs and CSVs through the real command line."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from mavahrs.cli import main
from mavahrs.config import load_run_config
from mavahrs.geometry.quaternion import conjugate, random_unit, rotate
from mavahrs.geometry.rotation import to_euler_rad
from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.sensors.geomag import expected_field

LAT, LON, ALT = -35.36, 149.17, 600.0
UNIX_S = 1767225600 + 100 * 86400  # 2026-04-11
FIELD = expected_field(LAT, LON, ALT, 2026.0 + 100 / 365)
OFFSET_UT = np.array([18.0, -30.0, 9.0])
SOFT = np.array([[1.08, 0.05, -0.03], [0.05, 0.95, 0.04], [-0.03, 0.04, 1.02]])


def _write_tlog(path: Path, rng: np.random.Generator, *, autopilot: int, n: int = 1500, tilt_only: bool = False) -> np.ndarray:
    """HEARTBEAT, SYSTEM_TIME, GLOBAL_POSITION_INT, SCALED_IMU2 (distorted mag) and ATTITUDE at 20 Hz."""
    ap = MavCodec(system_id=1, component_id=1)
    q = random_unit(n, rng)
    if tilt_only:  # level turns only
        yaw = rng.uniform(-math.pi, math.pi, n)
        q = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)
    field_ned = np.array(FIELD.north_east_down_ut)
    mag = rotate(conjugate(q), np.broadcast_to(field_ned, (n, 3))) @ SOFT.T + OFFSET_UT
    mag += rng.normal(scale=0.2, size=mag.shape)
    acc = rotate(conjugate(q), np.broadcast_to([0.0, 0.0, -1000.0], (n, 3)))
    euler = to_euler_rad(q)
    out = bytearray()

    def rec(t_ms: int, msg: object) -> None:
        out.extend(struct.pack(">Q", UNIX_S * 10**6 + t_ms * 1000))
        out.extend(ap.encode(msg))

    rec(0, mavlink.MAVLink_heartbeat_message(2, autopilot, 0, 0, 4, 3))
    rec(1, mavlink.MAVLink_system_time_message(UNIX_S * 10**6, 1))
    rec(2, mavlink.MAVLink_global_position_int_message(2, int(LAT * 1e7), int(LON * 1e7), int(ALT * 1000), 0, 0, 0, 0, 0))
    for k in range(n):
        t = 1000 + 50 * k
        m = np.round(mag[k] * 10.0).astype(int)  # µT → mgauss
        a = np.round(acc[k]).astype(int)
        rec(t, mavlink.MAVLink_scaled_imu2_message(t, *a, 0, 0, 0, *m, 0))
        rec(t, mavlink.MAVLink_attitude_message(t, *euler[k], 0.0, 0.0, 0.0))
    path.write_bytes(bytes(out))
    return mag


def test_tlog_fit_is_printed_and_written(tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "dance.tlog"
    _write_tlog(log, rng, autopilot=mavlink.MAV_AUTOPILOT_PX4)
    cfg = tmp_path / "mavahrs.toml"
    cfg.write_text('# my settings\n[pipeline]\nout_rate_hz = 25.0\n\n[pipeline.calibration]\naxis_remap = "+x+y+z"\n')
    assert main(["calibrate-mag", str(log), "--output", str(cfg)]) == 0
    out = capsys.readouterr().out
    assert "SCALED_IMU2 (px4 profile), 1500 magnetometer samples" in out
    assert "WMM-2025" in out and "WARNING" not in out
    assert "[pipeline.calibration.mag]" in out
    heading = out.split("heading vs the autopilot's attitude: ")[1].split("\n")[0]
    raw_deg, cal_deg = (float(x.split("°")[0]) for x in heading.split("→"))
    assert raw_deg > 20.0 and cal_deg < 1.5, heading

    conf = load_run_config(cfg)
    assert conf.pipeline.out_rate_hz == 25.0  # the rest of the file is kept
    mag = conf.pipeline.calibration.mag
    f = FIELD.strength_ut
    assert np.linalg.norm(np.array(mag.offset_ut) - OFFSET_UT) < 0.02 * f
    np.testing.assert_allclose(np.array(mag.matrix) @ SOFT, np.eye(3), atol=0.01)
    # Run again: the table is replaced, not duplicated.
    assert main(["calibrate-mag", str(log), "-o", str(cfg)]) == 0
    text = cfg.read_text()
    assert text.count("[pipeline.calibration.mag]") == 1 and text.startswith("# my settings")
    assert load_run_config(cfg).pipeline.calibration.mag == mag


def test_already_calibrated_source_warns(tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "ardupilot.tlog"
    _write_tlog(log, rng, autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, n=600)
    assert main(["calibrate-mag", str(log), "--field-ut", "50"]) == 0
    out = capsys.readouterr().out
    assert "(ardupilot profile)" in out
    assert "WARNING: SCALED_IMU2 (ardupilot profile): the autopilot has already calibrated" in out
    assert "50.00 µT (given)" in out


def test_level_turns_are_refused(tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "flat.tlog"
    _write_tlog(log, rng, autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, n=600, tilt_only=True)
    cfg = tmp_path / "out.toml"
    assert main(["calibrate-mag", str(log), "-o", str(cfg)]) == 1
    err = capsys.readouterr().err
    assert "ellipsoid" in err or "coverage" in err
    assert "already calibrates" in err
    assert not cfg.exists()


def test_csv_input(tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]) -> None:
    q = random_unit(800, rng)
    m = rotate(conjugate(q), np.broadcast_to([20.0, 3.0, 45.0], (800, 3))) @ SOFT.T + OFFSET_UT
    csv = tmp_path / "mag.csv"
    csv.write_text("MX,MY,MZ\n" + "\n".join(f"{a:.3f},{b:.3f},{c:.3f}" for a, b, c in m) + "\n")
    assert main(["calibrate-mag", str(csv)]) == 0
    out = capsys.readouterr().out
    assert "CSV" in out and "(fit)" in out  # no position: the ellipsoid's own mean radius
    offset = [float(v) for v in out.split("offset_ut = [")[1].split("]")[0].split(",")]
    np.testing.assert_allclose(offset, OFFSET_UT, atol=0.05)


@pytest.mark.parametrize(
    "argv",
    [
        ["calibrate-mag", "missing.tlog"],
        ["calibrate-mag", "x.csv", "--lat", "10"],
        ["calibrate-mag", "x.csv", "--lat", "100", "--lon", "0"],
        ["calibrate-mag", "x.csv", "--field-ut", "5000"],
        ["calibrate-mag", "x.csv", "--min-coverage", "2"],
    ],
)
def test_bad_input_gives_an_exit_code(argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.csv").write_text("mx,my,mz\n1,2,3\n")
    assert main(argv) in (1, 2)
    assert main(["calibrate-mag", "x.csv", "--lat", "10"]) == 2


def test_csv_without_the_columns(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b,c\n1,2,3\n")
    assert main(["calibrate-mag", str(bad)]) == 1


def test_a_flight_of_flips_is_refused_for_its_coverage_not_as_no_ellipsoid(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """firmware_sim's `flips` (a calibrated magnetometer, |B| 57.0–59.3 µT, rolls and pitches through 50 % of the
    sphere): the general quadric through its readings is a hyperboloid, which was refused as "do not fit an
    ellipsoid"; fitted from a sphere instead, the refusal names the real reason, the coverage and the fit's
    condition (the soft iron is not determined by these attitudes)."""
    import subprocess
    import sys

    log = tmp_path / "flips.tlog"
    sim = subprocess.run([sys.executable, "-m", "firmware_sim", "--tlog", str(log), "--fast", "--scenario", "flips",
                          "--duration", "60", "--seed", "0", "-q"], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    capsys.readouterr()
    assert main(["calibrate-mag", str(log)]) == 1
    err = capsys.readouterr().err
    assert "orientation coverage" in err and "fit condition" in err, err
    assert "do not fit an ellipsoid" not in err, err


@pytest.mark.parametrize("rel", ["sitl/arducopter_onboard.BIN", "px4_ulog/sample.ulg"])
def test_an_onboard_log_is_named_not_read_as_a_tlog(shared_data: Path, rel: str, capsys: pytest.CaptureFixture[str]) -> None:
    """A .BIN or .ulg (which replay, evaluate, plot and audit take) was read as a tlog: "no magnetometer samples in
    RAW_IMU (samples per message: none)". Now the error names the format and what calibrate-mag reads."""
    path = shared_data / rel
    if not path.is_file():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data beside the checkout)")
    capsys.readouterr()
    assert main(["calibrate-mag", str(path)]) == 1
    err = capsys.readouterr().err
    kind = "an ArduPilot DataFlash log (.BIN)" if rel.endswith(".BIN") else "a PX4 ULog (.ulg)"  # "a ArduPilot" before user6
    assert f"is {kind}: calibrate-mag reads a telemetry log (.tlog) or a CSV" in err, err
    assert "RAW_IMU" not in err and "Traceback" not in err
