"""``mavahrs replay`` and ``mavahrs plot`` from the command line; a live daemon run replays identically."""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from pathlib import Path

import pytest

from mavahrs.cli import main


@pytest.mark.slow
def test_replay_writes_csv_tlog_and_plot(sim_hover_tlog: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("matplotlib")
    csv, out, png = tmp_path / "r.csv", tmp_path / "r.tlog", tmp_path / "r.png"
    rc = main(["replay", str(sim_hover_tlog), "-f", "mahony", "-f", "madgwick", "--csv", str(csv),
               "--output", str(out), "--plot", str(png), "--out-rate", "50", "--end", "8"])  # fmt: skip
    assert rc == 0
    cap = capsys.readouterr()
    assert "engine fast" in cap.out and "SIMSTATE truth" in cap.out
    assert "component 191" in cap.err and "component 192" in cap.err
    header = csv.read_text().splitlines()[0]
    assert header.startswith("time_s,mahony_qw") and "madgwick_mag_rejected" in header
    assert out.stat().st_size > sim_hover_tlog.stat().st_size / 4 and png.stat().st_size > 20_000
    # the replay CSV can be drawn again
    assert main(["plot", str(csv), "-o", str(tmp_path / "again.png")]) == 0


def test_replay_real_log_says_the_rate_is_too_low(mavlink_logs_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(mavlink_logs_dir / "ardusub_log_tools" / "small.tlog"), "-f", "mahony"]) == 0
    out = capsys.readouterr().out
    assert "too slow for meaningful attitude filtering" in out and "autopilot ATTITUDE" in out


def test_replay_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(tmp_path / "none.tlog")]) == 1
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(b"\x00" * 100)
    assert main(["replay", str(junk)]) == 1
    assert main(["replay", str(junk), "--start", "5", "--end", "1"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("\n") >= 3


@pytest.mark.slow
def test_plot_a_recording(broad_dir: Path, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    png = tmp_path / "b.png"
    trial = str(broad_dir / "02_undisturbed_slow_rotation_B.mat")
    assert main(["plot", trial, "-o", str(png), "-f", "mahony", "--start", "40", "--end", "60"]) == 0
    assert png.stat().st_size > 20_000


@pytest.mark.slow
def test_a_live_daemon_log_replays_to_identical_attitudes(tmp_path: Path) -> None:
    """``firmware_sim`` → UDP → ``mavahrs run --log``; replaying that tlog gives the daemon's own attitudes."""
    import os
    import signal
    import socket
    import subprocess
    import sys
    import threading
    import time

    import numpy as np

    from mavahrs.protocol.codec import MavCodec
    from mavahrs.protocol.tlog import read_tlog_messages
    from mavahrs.replay import ReplaySettings, replay

    pytest.importorskip("firmware_sim")
    repo = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(repo) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    log = tmp_path / "live.tlog"
    # a ground station: the daemon is stopped once it has sent enough attitudes (the event), not after a
    # fixed time — on a loaded machine the simulator alone can take longer than that to start streaming
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.2)
    daemon = subprocess.Popen(
        [sys.executable, "-m", "mavahrs", "run", "--master", f"udpin:127.0.0.1:{port}", "--filter", "madgwick",
         "--out-rate", "0", "--log", str(log), "--out", f"udpout:127.0.0.1:{gcs.getsockname()[1]}",
         "--status-interval", "0"],
        cwd=repo, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(daemon.stderr or ()), daemon=True)
    reader.start()
    sim = None
    try:
        # The simulator starts once the daemon serves: on a cold cache its kernels compile first (tens of
        # seconds on a fresh machine), and a simulator started at once would have streamed into the socket
        # at the default 1 Hz by then (seen in CI: 11 attitudes).
        deadline = time.monotonic() + 180
        while not any("mavahrs running" in ln for ln in lines):
            assert daemon.poll() is None and time.monotonic() < deadline, "".join(lines)[-2000:]
            time.sleep(0.05)
        sim = subprocess.Popen(
            [sys.executable, "-m", "firmware_sim", "-q", "--out", f"udpout:127.0.0.1:{port}", "--scenario", "hover",
             "--duration", "0", "--seed", "4", "--imus", "1"],
            cwd=repo, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        codec, attitudes = MavCodec(drop_duplicates=False), 0
        deadline = time.monotonic() + 180
        while attitudes < 1000:
            assert daemon.poll() is None and sim.poll() is None and time.monotonic() < deadline, (
                attitudes, "".join(lines)[-2000:])
            try:
                data = gcs.recv(65536)
            except TimeoutError:
                continue
            attitudes += sum(m.get_type() == "ATTITUDE_QUATERNION" for m in codec.receive_datagram(data))
        daemon.send_signal(signal.SIGTERM)  # the daemon's own stop: the tlog flushed and closed, exit 0
        assert daemon.wait(timeout=60) == 0, "".join(lines)[-2000:]
    finally:
        for p in (daemon, sim):
            if p is not None and p.poll() is None:
                p.terminate()
                p.wait(timeout=10)
        reader.join(5)
        gcs.close()
    # what the daemon sent, from its own log (component 191)
    live = [(m.time_boot_ms, (m.q1, m.q2, m.q3, m.q4)) for _, m in read_tlog_messages(log, ["ATTITUDE_QUATERNION"])
            if m.get_srcComponent() == 191]  # fmt: skip
    assert len(live) >= 1000  # as many as the ground station counted before the stop; the claim is equality
    res = replay(log, ReplaySettings(filters=("madgwick",)))
    tr = res.tracks["madgwick"]
    sent = np.flatnonzero(tr.sent)
    mine = [(int(res.inputs.t_us[i] // 1000), tuple(np.float32(tr.out[i, :4]).tolist())) for i in sent]
    live32 = [(t, tuple(np.float32(q).tolist())) for t, q in live]
    # bit for bit: this caught the daemon starting without a date for the magnetic model (replay
    # had one), which rotated the first GNSS velocity differently and the attitude by up to 3e-5
    assert mine == live32


def test_replay_header_names_the_velocity_source(sim_hover_tlog: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for flag, text in (
        ("none", "velocity: none (velocity_source none)"),
        ("gps2_raw", "velocity: none (velocity_source gps2_raw: no usable fix in the log)"),
    ):
        assert main(["replay", str(sim_hover_tlog), "-f", "mahony", "--end", "3", "--velocity-source", flag]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert lines[0].startswith(f"{sim_hover_tlog.name}: ") and lines[1] == text
    assert main(["replay", str(sim_hover_tlog), "-f", "mahony", "--end", "3"]) == 0
    line = capsys.readouterr().out.splitlines()[1]
    assert line.startswith("velocity: GLOBAL_POSITION_INT, ") and line.endswith(" fixes (velocity_source auto)")
    assert main(["replay", str(sim_hover_tlog), "--velocity-source", "gps"]) == 2
    assert "invalid choice: 'gps'" in capsys.readouterr().err


def _err_lines(err: str) -> list[str]:
    """The messages of the logged lines (after 'HH:MM:SS.mmm LEVEL ')."""
    return [line.split(" ", 2)[2] for line in err.splitlines() if line[:2].isdigit()]


def _write_tlog(path: Path, frames: list[tuple[int, bytes]]) -> Path:
    from mavahrs.protocol.tlog import tlog_record

    path.write_bytes(b"".join(tlog_record(t, f) for t, f in frames))
    return path


def _no_heartbeat(frames: list[tuple[int, bytes]]) -> list[tuple[int, bytes]]:
    return [(t, f) for t, f in frames if f[7:10] != b"\x00\x00\x00"]  # MAVLink 2 msgid 0 = HEARTBEAT


def test_replay_says_what_is_wrong_with_a_file_that_is_no_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = tmp_path / "passwd"
    text.write_text("root:x:0:0:root:/root:/bin/bash\ndaemon:x:1:1:daemon:/usr/sbin:/usr/sbin/nologin\n")
    assert main(["replay", str(text)]) == 1
    assert main(["replay", str(tmp_path)]) == 1  # as a missing file (docs/reliability.md)
    assert [m for m in _err_lines(capsys.readouterr().err) if m.startswith("replay:")] == [
        f"replay: {text}: no MAVLink messages in this file: expected a telemetry log (.tlog, as MAVProxy, "
        "QGroundControl, Mission Planner and mavahrs write them), an ArduPilot DataFlash log (.BIN) or a PX4 ULog "
        "(.ulg)",
        f"replay: {tmp_path} is a directory: replay takes one log file; for a folder of logs use "
        "`mavahrs audit FOLDER` (one row per flight)",
    ]


def test_replay_names_a_missing_output_folder_before_reading_the_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--csv` into a folder that does not exist failed only after the whole replay had run (a long log's
    minutes lost) with the OS's errno text; each output's folder is now checked first, the log not opened."""
    log = tmp_path / "no_log_here.tlog"
    log.write_bytes(b"\xfe" * 10)  # not read: the output check comes first
    missing = tmp_path / "nowhere"
    for option, name in (("--csv", "a.csv"), ("--output", "a.tlog"), ("--plot", "a.png")):
        assert main(["replay", str(log), option, str(missing / name)]) == 1
    assert [m for m in _err_lines(capsys.readouterr().err) if m.startswith("replay:")] == [
        f"replay: {option} {missing / name}: no such folder {missing}"
        for option, name in (("--csv", "a.csv"), ("--output", "a.tlog"), ("--plot", "a.png"))
    ]
    assert not missing.exists()


def test_replay_of_a_recording_with_truth_points_to_evaluate_and_plot(
    broad_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A BROAD .mat given to replay said "no autopilot HEARTBEAT and no IMU messages" (its bytes hold stray
    MAVLink-like frames); a RepoIMU .csv "no MAVLink messages … expected a telemetry log": neither said which
    command takes such a file."""
    trial = broad_dir / "02_undisturbed_slow_rotation_B.mat"
    assert main(["replay", str(trial)]) == 1
    assert [m for m in _err_lines(capsys.readouterr().err) if m.startswith("replay:")] == [
        f"replay: {trial}: not a flight log (no MAVLink IMU messages): a recording with a reference attitude "
        "(BROAD .mat, RepoIMU or documented .csv) is scored with `mavahrs evaluate` and drawn with `mavahrs plot`"
    ]


def test_replay_without_heartbeat_takes_the_only_imu_sender_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.warmup import synthetic_frames

    frames = synthetic_frames(3.0)
    one = _write_tlog(tmp_path / "one.tlog", _no_heartbeat(frames))
    for engine in ("fast", "pipeline"):
        assert main(["replay", str(one), "-f", "madgwick", "--engine", engine]) == 0
        out = capsys.readouterr().out.splitlines()
        assert out[0] == (
            f"one.tlog: 600 IMU samples of RAW_IMU (instance 0) from system 1/1 (generic scaling), 3.0 s at "
            f"200.0 Hz; engine {engine}"
        )
        assert out[1] == "velocity: GLOBAL_POSITION_INT, 30 fixes (velocity_source auto)"
        assert out[2] == (
            "note: no autopilot HEARTBEAT in the log: using the IMU data of system 1, component 1 (its only "
            "sender), with the generic scaling profile (--source and --profile choose otherwise)"
        )
    # a second sender of IMU data: no automatic choice; --source chooses
    other = MavCodec(2, 1)
    extra = [(t, other.encode(other.mav.raw_imu_encode(t, 0, 0, -1000, 0, 0, 0, 200, 30, 450, 0, 3500)))
             for t, _ in frames[::10]]  # fmt: skip
    two = _write_tlog(tmp_path / "two.tlog", sorted(_no_heartbeat(frames) + extra, key=lambda x: x[0]))
    assert main(["replay", str(two), "-f", "madgwick"]) == 1
    assert _err_lines(capsys.readouterr().err)[-1] == (
        f"replay: {two}: no autopilot HEARTBEAT, and IMU data from several senders (SYSID:COMPID 1:1, "
        "2:1): choose one with --source SYSID[:COMPID], or source_system/source_component in the config"
    )
    assert main(["replay", str(two), "-f", "madgwick", "--source", "1"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("two.tlog: 600 IMU samples of RAW_IMU (instance 0) from system 1/1 (generic scaling)")
    assert out[1] == "velocity: GLOBAL_POSITION_INT, 30 fixes (velocity_source auto)"
    assert out[2] == (
        "note: no autopilot HEARTBEAT in the log: using the IMU data of system 1, component 1 (as --source "
        "asks), with the generic scaling profile (--source and --profile choose otherwise)"
    )
    # all said on the command line: nothing to note
    assert main(["replay", str(two), "-f", "madgwick", "--source", "2:1", "--profile", "ardupilot"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("two.tlog: 67 IMU samples of RAW_IMU (instance 0) from system 2/1 (ardupilot scaling)")
    assert not any(line.startswith("note: no autopilot HEARTBEAT") for line in out)


def test_a_hole_in_data_received_in_a_burst_is_placed_on_the_autopilots_clock(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Queued data delivered at once (all tlog stamps within a few ms): the hole's times are real ones
    (the autopilot's boot time), not "from 0.0 s to 0.0 s of the log"."""
    from mavahrs.warmup import synthetic_frames

    frames = [(t, f) for t, f in synthetic_frames(10.0) if not 3_000_000 <= t < 6_000_000]
    burst = _write_tlog(tmp_path / "burst.tlog", [(1_000_000 + k, f) for k, (_, f) in enumerate(frames)])
    assert main(["replay", str(burst), "-f", "madgwick"]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note: gap")]
    assert notes == [
        "note: gap in the IMU data: no samples for 3.0 s, from 3.0 s to 6.0 s of the autopilot's clock (time "
        "since boot: the log received these samples in bursts, its own times do not show the gaps); the "
        "filters start again after it (their re-convergence is in the comparison below)"
    ]


def test_source_option_rejects_what_is_no_mavlink_id(capsys: pytest.CaptureFixture[str]) -> None:
    for bad in ("x", "1:2:3", "0", "1:256"):
        assert main(["replay", "any.tlog", "--source", bad]) == 2
    err = capsys.readouterr().err
    assert "argument --source: expected SYSID or SYSID:COMPID, e.g. 1 or 1:1; got 'x'" in err
    assert "argument --source: MAVLink system and component ids are 1–255; got '1:256'" in err


def test_replay_notes_a_hole_in_the_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from mavahrs.warmup import synthetic_frames

    frames = synthetic_frames(10.0)  # records from 1.0 s (Unix time) on: log time = t − 1 s
    whole = _write_tlog(tmp_path / "whole.tlog", frames)
    holed = _write_tlog(tmp_path / "holed.tlog", [(t, f) for t, f in frames if not 3_000_000 <= t < 6_000_000])
    twice = _write_tlog(tmp_path / "twice.tlog", [(t, f) for t, f in frames
                                                  if not (3_000_000 <= t < 4_000_000 or 7_000_000 <= t < 9_000_000)])
    for engine in ("fast", "pipeline"):
        assert main(["replay", str(whole), "-f", "madgwick", "--engine", engine]) == 0
        assert not any("gap" in line for line in capsys.readouterr().out.splitlines())
        assert main(["replay", str(holed), "-f", "madgwick", "--engine", engine]) == 0
        notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note: ")]
        assert notes == [
            "note: gap in the IMU data: no samples for 3.0 s, from 2.0 s to 5.0 s of the log; the filters start "
            "again after it (their re-convergence is in the comparison below)"
        ]
    assert main(["replay", str(twice), "-f", "madgwick"]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note: ")]
    assert notes == [
        "note: 2 gaps in the IMU data, 3.0 s without samples in all: 2.0–3.0 s, 6.0–8.0 s of the log; the "
        "filters start again after each (their re-convergence is in the comparison below)"
    ]


@pytest.mark.slow
@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_ctrl_c_in_a_fast_replay_keeps_every_row_and_frame_computed(
    shared_data: Path, tmp_path: Path, signame: str
) -> None:
    """SIGINT (Ctrl-C) or SIGTERM (`kill`, a job scheduler) to a real ``mavahrs replay --csv --output``
    (fast engine) once its CSV has rows.

    Every row written is whole and in time order, the tlog holds the frames of
    the same samples, and the last line says how far it got and what was kept.
    """
    import os
    import re
    import signal
    import subprocess
    import sys
    import time

    import numpy as np
    from pymavlink import mavutil

    log = shared_data / "sitl" / "arducopter_400hz_gps.tlog"
    if not log.is_file():
        pytest.skip(f"{log} not found")
    csv, out = tmp_path / "r.csv", tmp_path / "r.tlog"
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[2]) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavahrs", "replay", str(log), "-f", "all", "--engine", "fast", "--csv", str(csv),
         "--output", str(out), "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 300
        while proc.poll() is None and time.monotonic() < deadline:  # the first block of rows is the event
            if csv.is_file() and csv.read_bytes().count(b"\n") >= 2:
                break
            time.sleep(0.01)
        assert proc.poll() is None, "the replay ended before it could be interrupted"
        proc.send_signal(getattr(signal, signame))
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    said = re.search(r"replay interrupted at (\d+) % of the samples — kept (\d+) CSV rows in (\S+), (\d+) frames in (\S+)",
                     stderr)  # fmt: skip
    assert said, stderr
    percent, rows, frames = int(said[1]), int(said[2]), int(said[4])
    assert said[3] == str(csv) and said[5] == str(out)
    assert 0 < percent < 100

    text = csv.read_text()
    assert text.endswith("\n")
    lines = text.splitlines()
    header = lines[0].split(",")
    assert len(lines) - 1 == rows > 0
    assert all(line.count(",") == len(header) - 1 for line in lines[1:])  # whole rows
    table = np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)
    assert table.shape == (rows, len(header))
    assert np.all(np.diff(table[:, 0]) > 0)  # time-ordered, each sample once

    mlog = mavutil.mavlink_connection(str(out), dialect="ardupilotmega")
    ours: dict[int, list[int]] = {}
    while (m := mlog.recv_match(type="ATTITUDE_QUATERNION")) is not None:
        if m.get_srcComponent() >= 191:
            ours.setdefault(m.get_srcComponent(), []).append(m.time_boot_ms)
    mlog.close()
    assert sum(len(v) for v in ours.values()) == frames
    assert len(ours) == 6  # every filter, the same samples (out-rate 0: one frame per CSV row)
    for times in ours.values():
        assert len(times) == rows
        assert times[-1] == pytest.approx(table[-1, 0] * 1000, abs=1)  # the CSV's time column: seconds of the autopilot's clock


def test_filter_names_may_be_comma_separated() -> None:
    """``-f mahony,best`` is ``-f mahony -f best`` in every command that takes filters."""
    from mavahrs.cli import build_parser

    parser = build_parser()
    for cmd in ("replay", "evaluate", "plot", "audit"):
        extra = ["-o", "x.png"] if cmd == "plot" else []
        ns = parser.parse_args([cmd, "x.tlog", *extra, "-f", "mahony,best", "-f", "eskf"])
        assert ns.filters == ["mahony", "best", "eskf"], cmd


def test_a_truncated_log_is_noted_by_replay_and_evaluate(shared_data: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``head -c 100000`` of a SITL log: both replay engines and evaluate say it ends inside a frame."""
    log = shared_data / "sitl" / "arducopter_gentle.tlog"
    if not log.is_file():
        pytest.skip(f"{log} not found")
    cut = tmp_path / "cut.tlog"
    with open(log, "rb") as f:
        cut.write_bytes(f.read(100_000))
    for argv in (["replay", str(cut), "-f", "mahony"], ["replay", str(cut), "-f", "mahony", "--engine", "pipeline"],
                 ["evaluate", str(cut), "-f", "mahony"]):  # fmt: skip
        assert main(argv) == 0
        out = capsys.readouterr().out
        assert "the log ends inside a frame at byte " in out and "truncated?" in out, (argv, out)
    if importlib.util.find_spec("matplotlib") is not None:  # plot says it on its log lines, beside its figure
        assert main(["plot", str(cut), "-f", "mahony", "-o", str(tmp_path / "cut.png")]) == 0
        err = capsys.readouterr().err
        assert "cut.tlog: note: the log ends inside a frame at byte " in err and "truncated?" in err, err
    assert main(["replay", str(log), "-f", "mahony", "--end", "5"]) == 0
    assert "ends inside a frame" not in capsys.readouterr().out


def test_ctrl_c_while_replay_starts_says_nothing_was_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """A Ctrl-C in the first seconds (imports, the filter kernels: longer on a busy machine) ended with the bare
    'ERROR interrupted': nothing about the CSV and tlog that were asked for.  Now replay's own line says when it
    was interrupted and what was written."""
    from mavahrs.cli import common

    def interrupted() -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(common, "start_kernels", interrupted)
    log = tmp_path / "x.tlog"
    log.write_bytes(b"")
    csv, out = tmp_path / "x.csv", tmp_path / "o.tlog"
    code = main(["replay", str(log), "--csv", str(csv), "--output", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 130, err
    assert err.strip().endswith(f"ERROR replay interrupted while starting (loading the filters), before the log "
                                f"was read — kept no CSV ({csv} not written), no tlog ({out} not written)"), err  # fmt: skip
    assert not csv.exists() and not out.exists()


def _frames_in(path: Path) -> list[int]:
    """time_boot_ms of the ATTITUDE_QUATERNION frames our components (≥ 191) wrote into a tlog."""
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    times = []
    while (m := mlog.recv_match(type="ATTITUDE_QUATERNION")) is not None:
        if m.get_srcComponent() >= 191:
            times.append(m.time_boot_ms)
    mlog.close()
    return times


def test_ctrl_c_in_a_ulog_replay_keeps_the_csv_rows_and_the_frames_computed(
    shared_data: Path, tmp_path: Path, interrupt_replay: Callable[[int], None], capsys: pytest.CaptureFixture[str]
) -> None:
    """Ctrl-C while a .ulg was filtered (PX4's real board): replay said "internal error: IndexError" (exit 1),
    wrote no tlog and called its CSV rows "not written".  Now, as for a tlog: exit 130, the rows filtered are in
    the CSV and said, and --output holds the frames of the same samples."""
    log = shared_data / "px4_ulog" / "sample.ulg"
    if not log.is_file():
        pytest.skip(f"reference data not found at {log} (expected ../shared/data beside the checkout)")
    interrupt_replay(3)
    csv, out = tmp_path / "r.csv", tmp_path / "r.tlog"
    code = main(["replay", str(log), "--csv", str(csv), "--output", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 130, err
    assert "internal error" not in err
    assert f"kept 2000 CSV rows in {csv}, 2000 frames in {out} (the log up to the last filtered sample)" in err, err
    assert csv.read_text().count("\n") == 2001
    times = _frames_in(out)
    assert len(times) == 2000 and times == sorted(times)


def test_ctrl_c_after_the_samples_were_filtered_still_writes_the_tlog(
    sim_hover_tlog: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Ctrl-C while the comparison or second opinion was worked out (seconds on a long log, after the CSV was
    complete): the bare "ERROR interrupted" and no --output tlog. Now the tlog is written whole and the line says
    what was kept and what was not made."""
    import mavahrs.replay as rp

    def interrupted(*args: object, **kw: object) -> str:
        raise KeyboardInterrupt

    monkeypatch.setattr(rp, "format_second_opinion", interrupted)
    csv, out = tmp_path / "r.csv", tmp_path / "r.tlog"
    code = main(["replay", str(sim_hover_tlog), "--csv", str(csv), "--output", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 130, err
    rows = csv.read_text().count("\n") - 1
    said = f"replay interrupted after every sample was filtered — kept {rows} CSV rows in {csv} (complete), "
    assert said in err and "not made: the comparison (printed)" in err, err
    assert len(_frames_in(out)) == rows > 1000


def test_plot_of_a_replay_csv_takes_start_and_end_and_says_what_has_no_effect(
    sim_hover_tlog: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``plot OUT.csv --start 5 --end 8`` drew the whole CSV, and ``--filter`` / ``--no-mag`` were silently
    ignored there (``--no-mag`` on a flight log too). Now the window applies and the others are said."""
    from mavahrs.evaluation import plots

    csv = tmp_path / "r.csv"
    assert main(["replay", str(sim_hover_tlog), "-f", "mahony", "--csv", str(csv), "--end", "12"]) == 0
    drawn: list[tuple[float, float, list[str]]] = []
    labels: list[str] = []

    def capture(path, t_s, est, **kw):  # type: ignore[no-untyped-def]
        drawn.append((float(t_s[0]), float(t_s[-1]), sorted(est)))
        labels.append(kw.get("time_label", ""))
        return Path(path)

    monkeypatch.setattr(plots, "plot_attitude", capture)
    capsys.readouterr()
    assert main(["plot", str(csv), "--start", "5", "--end", "8", "-o", str(tmp_path / "w.png")]) == 0
    first, last, names = drawn[-1]
    # drawn on the CSV's own time_s (the autopilot's boot time, as replay --plot), the window from its first row
    t0 = float(csv.read_text().splitlines()[1].split(",")[0])
    assert 5.0 <= first - t0 < 5.1 and 7.9 < last - t0 <= 8.0 and names == ["mahony"]
    assert labels[-1] == "autopilot boot time, s"
    assert "has no effect" not in capsys.readouterr().err
    assert main(["plot", str(csv), "-f", "madgwick", "--no-mag", "-o", str(tmp_path / "f.png")]) == 0
    err = capsys.readouterr().err
    assert "plot: --filter has no effect here: a replay CSV is drawn as it is" in err, err
    assert "plot: --no-mag has no effect here" in err and drawn[-1][2] == ["mahony"]
    assert main(["plot", str(csv), "--start", "100", "-o", str(tmp_path / "n.png")]) == 1
    assert "no rows between --start 100.0" in capsys.readouterr().err


def test_a_source_that_sent_nothing_names_the_one_that_did(sim_hover_tlog: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``--source 2:1`` on a log whose IMU data all come from 1:1: the error says who sent them (until user8
    "no autopilot HEARTBEAT from system 2, component 1 and no IMU messages", as if the log had none)."""
    capsys.readouterr()
    assert main(["replay", str(sim_hover_tlog), "--source", "2:1"]) == 1
    err = capsys.readouterr().err
    assert (f"replay: {sim_hover_tlog}: no autopilot HEARTBEAT and no IMU messages from system 2, component 1; "
            "the log's IMU messages come from SYSID:COMPID 1:1 (--source)") in err, err  # fmt: skip


@pytest.mark.parametrize("log", ["sim", "px4_ulog/sample.ulg", "mavlink_logs/ardusub_log_tools/small.BIN"])
def test_a_window_past_the_log_says_where_its_imu_data_are(log: str, sim_hover_tlog: Path, shared_data: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``--start`` past the end: one wording for every format, naming the log's span (until user8 a tlog said
    "no IMU messages … from the autopilot", a .BIN "between 5000.0 and None s", a .ulg "the requested window")."""
    path = sim_hover_tlog if log == "sim" else shared_data / log
    capsys.readouterr()
    assert main(["replay", str(path), "--start", "5000"]) == 1
    err = capsys.readouterr().err
    assert f"replay: {path}: no IMU samples from 5000 s after the log's start (--start/--end); its IMU data span " in err
    assert "None" not in err and "from the autopilot" not in err
    assert main(["replay", str(path), "--start", "5000", "--end", "6000"]) == 1
    assert "no IMU samples between 5000 and 6000 s after the log's start" in capsys.readouterr().err


@pytest.mark.parametrize("log", ["px4_ulog/sample.ulg", "mavlink_logs/ardusub_log_tools/small.BIN"])
def test_source_on_an_onboard_log_is_said_to_be_ignored(log: str, shared_data: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``--source`` chooses a sender in a telemetry log; an onboard log has one, its own, and the option was
    dropped without a word (user8). The replay runs and its notes say so; without the option they do not."""
    path = shared_data / log
    if not path.is_file():
        pytest.skip(f"{path} not found")
    said = "--source ignored: "
    capsys.readouterr()
    assert main(["replay", str(path), "-f", "madgwick", "--source", "2:1"]) == 0
    out = capsys.readouterr().out
    assert any(line.startswith("note: " + said) for line in out.splitlines()), out
    assert main(["replay", str(path), "-f", "madgwick"]) == 0
    assert said not in capsys.readouterr().out
