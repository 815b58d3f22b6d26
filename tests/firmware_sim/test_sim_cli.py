"""``python -m firmware_sim``: arguments, exit codes, tlog output readable by pymavlink's tools."""

from __future__ import annotations

import json
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from firmware_sim.__main__ import main
from firmware_sim.endpoint import EPOCH_2025_06_01_US
from firmware_sim.simulation import SimSettings, Simulation
from firmware_sim.trajectory import SCENARIOS
from mavahrs.geometry import quaternion as quat
from mavahrs.geometry.rotation import from_euler_rad


def test_help_lists_options_with_units_and_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for text in ("--out", "--tlog", "--fast", "--scenario", "--loop-rate", "--ideal", "--declination-deg",
                 "--autopilot", "--sysid", "--lat", "--imu2-freeze-at", "--noiseless", "(default 400.0)", "uT", "Hz",
                 "exit codes"):
        assert text in out, text
    for name in SCENARIOS:
        assert name in out


def test_noiseless_option_removes_only_the_random_sensor_errors() -> None:
    from firmware_sim.__main__ import build_parser, settings_from_args
    from firmware_sim.imu_model import ImuErrorSettings, MagSettings

    sim, _ = settings_from_args(build_parser().parse_args(["--tlog", "x.tlog", "--fast", "--noiseless"]))
    assert sim.imu == ImuErrorSettings().noiseless() and sim.mag == MagSettings().noiseless()
    assert sim.imu.accel_noise_density_m_s2_rthz == 0.0 and sim.imu.gyro_bias_walk_rad_s_rts == 0.0
    assert sim.mag.noise_ut == 0.0 and sim.mag.lsb_ut == MagSettings().lsb_ut
    assert sim.imu.accel_bias_sigma_m_s2 == ImuErrorSettings().accel_bias_sigma_m_s2


@pytest.mark.parametrize(
    "argv",
    [
        ["--scenario", "nope"],
        ["--fast"],
        ["--stream", "FOO=10"],
        ["--stream", "RAW_IMU=fast"],
        ["--mag-soft-iron", "1,2,3"],
        ["--out", "bogus:thing"],
        ["--tlog", "x.tlog", "--fast", "--duration", "0"],
        ["--attitude-fault", "1,2,3,4,5,6", "--tlog", "x.tlog", "--fast"],
    ],
)
def test_bad_arguments_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "error" in capsys.readouterr().err


def test_link_that_cannot_be_opened_exits_3(capsys: pytest.CaptureFixture[str]) -> None:
    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(("127.0.0.1", 0))
    try:
        rc = main(["--out", f"udpin:127.0.0.1:{busy.getsockname()[1]}", "--duration", "1", "-q"])
    finally:
        busy.close()
    assert rc == 3
    assert "udpin" in capsys.readouterr().err


def test_list_scenarios(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--list-scenarios"]) == 0
    out = capsys.readouterr().out
    assert [line.split()[0] for line in out.splitlines()] == list(SCENARIOS)


@pytest.mark.slow
def test_fast_tlog_opens_with_mavlogdump_and_simstate_is_the_truth(tmp_path: Path, sim_env_vars: dict[str, str]) -> None:
    path = tmp_path / "aggressive.tlog"
    assert main(["--tlog", str(path), "--fast", "--scenario", "aggressive", "--duration", "12", "--seed", "1", "-q"]) == 0
    dump = shutil.which("mavlogdump.py")
    cmd = [dump] if dump else [sys.executable, "-m", "pymavlink.tools.mavlogdump"]
    res = subprocess.run([*cmd, "--types", "SIMSTATE,RAW_IMU", str(path)], capture_output=True, text=True,
                         timeout=120, env=sim_env_vars)
    assert res.returncode == 0, res.stderr[-2000:]
    lines = res.stdout.splitlines()
    assert sum("RAW_IMU {" in ln for ln in lines) == 3000  # 12 s at 250 Hz (bench preset)
    assert sum("SIMSTATE {" in ln for ln in lines) == 3000
    assert lines[0].startswith("2025-06-01 00:00:00")

    # SIMSTATE against the model's truth, tick by tick (it goes out in the RAW_IMU's tick)
    log = mavutil.mavlink_connection(str(path))
    ref = Simulation(SimSettings(scenario="aggressive", seed=1, jit=True)).next_block(400 * 12)
    ticks, eulers, t_records = [], [], []
    tick = None
    while (msg := log.recv_match(type=["RAW_IMU", "SIMSTATE"])) is not None:
        if msg.get_type() == "RAW_IMU":
            tick = msg.time_usec // 2500
            t_records.append(msg._timestamp)
        elif tick is not None:
            ticks.append(tick)
            eulers.append((msg.roll, msg.pitch, msg.yaw))
    q_log = from_euler_rad(*np.array(eulers).T)
    err_deg = np.degrees(quat.angle_between(q_log, ref.truth.q_body_to_ned[np.array(ticks)]))
    assert len(ticks) == 3000 and err_deg.max() < 1e-3
    assert np.degrees(np.abs(ref.truth.gyro_rad_s).max()) > 100.0  # it really manoeuvred
    # tlog record time = UNIX epoch of the simulated boot + send time
    assert t_records[0] * 1e6 == pytest.approx(EPOCH_2025_06_01_US, abs=3000)


def test_live_run_records_a_tlog_writes_stats_and_stops_cleanly_on_sigterm(
    tmp_path: Path, run_sim
) -> None:  # type: ignore[no-untyped-def]
    stats = tmp_path / "stats.json"
    rec = tmp_path / "live.tlog"
    with run_sim("--out", "udpout:127.0.0.1:9", "--duration", "0", "--preset", "bench",
                 "--tlog", str(rec), "--stats-json", str(stats)) as (proc, info):
        assert info["LINK"].startswith("udpout:127.0.0.1:9")
        time.sleep(1.5)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
    data = json.loads(stats.read_text())
    assert data["ticks"] > 100 and data["sent"]["RAW_IMU"] > 50
    log = mavutil.mavlink_connection(str(rec))
    n = 0
    while log.recv_match(type="RAW_IMU") is not None:
        n += 1
    assert n == data["sent"]["RAW_IMU"]


def test_duration_ends_a_live_run(tmp_path: Path, sim_env_vars: dict[str, str], repo_root: Path) -> None:
    stats = tmp_path / "s.json"
    res = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "-q", "--out", "udpout:127.0.0.1:9", "--duration", "1",
         "--autopilot", "px4", "--stats-json", str(stats)],
        cwd=str(repo_root), env=sim_env_vars, capture_output=True, text=True, timeout=120,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    data = json.loads(stats.read_text())
    assert data["ticks"] == 400
    assert data["sent"]["HIGHRES_IMU"] == 50  # PX4 default stream


def test_fast_tlog_reports_the_files_size_in_mib(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The size printed is the file's (frames plus the 8-byte stamps), in MiB with the unit said
    (it printed the frames' bytes / 10^6 as "MB": 66.1 MB for a 77 957 898-byte file)."""
    import re

    path = tmp_path / "hover.tlog"
    assert main(["--tlog", str(path), "--fast", "--scenario", "hover", "--duration", "2", "-q"]) == 0
    out = capsys.readouterr().out
    m = re.search(r", ([0-9.]+) MiB \((\d+) bytes\) in ", out)
    assert m, out
    size = path.stat().st_size
    assert int(m.group(2)) == size
    assert float(m.group(1)) == pytest.approx(size / 2**20, abs=0.05)
