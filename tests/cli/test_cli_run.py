"""The command-line framework and ``mavahrs run``: exit codes, one-line errors, help, config printing."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mavahrs.cli import SUBCOMMANDS, _load, main
from mavahrs.cli.common import EXIT_CONNECTION, EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[2]
QUICK = ["--filter", "mahony", "--status-interval", "0"]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == EXIT_OK
    assert capsys.readouterr().out.strip() == "mavahrs 0.1.0"


def test_help_imports_nothing_heavy() -> None:
    """``mavahrs --help`` must answer fast: no numpy, numba, scipy or pymavlink import on the way."""
    code = (
        "import sys, contextlib, io\n"
        "from mavahrs.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "    rc = main(['--help'])\n"
        "heavy = sorted(m for m in ('numpy', 'numba', 'scipy', 'pymavlink', 'serial', 'matplotlib') if m in sys.modules)\n"
        "print(rc, heavy, 'run' in out.getvalue())\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), timeout=60)
    assert r.stdout.split("\n")[0] == "0 [] True", r.stdout + r.stderr


def test_run_help_lists_units_and_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--help"]) == EXIT_OK
    out = capsys.readouterr().out
    for text in (
        "(default: udpin:0.0.0.0:14550)",
        "(default: 115200)",
        "Hz; 0 = one per IMU sample (default: 50 Hz)",
        "(default: 400 Hz)",
        "(default: 10 s)",
        "(default: 191)",
        "madgwick, mahony, complementary, gyroplatform",
        "exit codes: 0 ok, 1 runtime failure, 2 usage/config error, 3 connection failure",
    ):
        assert text in " ".join(out.split()), text
    assert "?" not in out.replace("?)", "")  # every placeholder resolved


def test_no_command_and_bad_options_are_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == EXIT_USAGE
    assert main(["run", "--out-rate", "fast"]) == EXIT_USAGE
    assert main(["frobnicate"]) == EXIT_USAGE
    assert "invalid choice" in capsys.readouterr().err


def test_print_config_is_the_effective_toml(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[daemon]\noutputs = ["udpout:127.0.0.1:9"]\n[pipeline]\nout_rate_hz = 20\n')
    rc = main(["run", "--config", str(cfg), "--out-rate", "10", "--filter", "mahony", "--imu", "1",
               "--set", "daemon.input_queue=99", "--print-config"])
    assert rc == EXIT_OK
    data = tomllib.loads(capsys.readouterr().out)
    assert data["pipeline"]["out_rate_hz"] == 10.0  # the flag wins over the file
    assert data["pipeline"]["imu"] == "1" and data["pipeline"]["filter_name"] == "mahony"
    assert data["daemon"]["outputs"] == ["udpout:127.0.0.1:9"] and data["daemon"]["input_queue"] == 99
    assert "mahony" in data["filter"] and "schedule" in data["filter"]["mahony"]
    assert data["daemon"]["fast_lane"] is True  # the default
    assert main(["run", "--no-fast-lane", "--print-config"]) == EXIT_OK
    assert tomllib.loads(capsys.readouterr().out)["daemon"]["fast_lane"] is False


def test_source_option_sets_the_pipeline_source(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--source", "3:1", "--print-config"]) == EXIT_OK
    pipeline = tomllib.loads(capsys.readouterr().out)["pipeline"]
    assert (pipeline["source_system"], pipeline["source_component"]) == (3, 1)
    assert main(["run", "--source", "7", "--set", "pipeline.source_component=2", "--print-config"]) == EXIT_OK
    pipeline = tomllib.loads(capsys.readouterr().out)["pipeline"]
    assert (pipeline["source_system"], pipeline["source_component"]) == (7, 2)


@pytest.mark.parametrize(
    ("argv", "code", "needle"),
    [
        (["--master", "bogus"], EXIT_USAGE, "is not a serial device path or a network address"),
        (["--master", "/nonexistent/ttyUSB9", *QUICK], EXIT_CONNECTION, "cannot open serial port /nonexistent/ttyUSB9: no such device"),
        (["--master", "udpin:127.0.0.1:0", "--out", "udpout:127.0.0.1:0"], EXIT_USAGE, "outside 1…65535"),
        (["--set", "daemon.tick_hz=-1"], EXIT_USAGE, "daemon.tick_hz must be a positive number"),
        (["--filter", "kalman"], EXIT_USAGE, "unknown filter 'kalman'"),
        (["--imu", "7"], EXIT_USAGE, "imu"),
        (["--set", "daemon.fast_lane=1"], EXIT_USAGE, "daemon.fast_lane must be true or false"),
    ],
)
def test_bad_input_is_one_line_and_the_documented_code(
    argv: list[str], code: int, needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", *argv]) == code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err and "Traceback" not in err, err


def test_busy_port_and_missing_heartbeat_exit_3(capsys: pytest.CaptureFixture[str]) -> None:
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    try:
        port = holder.getsockname()[1]
        assert main(["run", *QUICK, "--master", f"udpin:127.0.0.1:{port}"]) == EXIT_CONNECTION
        assert "already in use" in capsys.readouterr().err
    finally:
        holder.close()
    assert main(["run", *QUICK, "--master", "udpin:127.0.0.1:0", "--heartbeat-timeout", "0.5"]) == EXIT_CONNECTION
    err = capsys.readouterr().err
    assert re.search(r"no heartbeat from udpin:127\.0\.0\.1:[1-9][0-9]* within 0\.5 s \(nothing received", err), err
    assert "Traceback" not in err


def test_status_page_port_taken_is_a_set_up_error_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    """`--http PORT` on a port another program holds: exit 2 (set-up/config), not 3 (a lost autopilot link)."""
    pytest.importorskip("aiohttp")
    holder = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    holder.bind(("127.0.0.1", 0))
    holder.listen(1)
    try:
        port = holder.getsockname()[1]
        rc = main(["run", *QUICK, "--master", "udpin:127.0.0.1:0", "--heartbeat-timeout", "0",
                   "--http", f"127.0.0.1:{port}"])  # fmt: skip
        err = capsys.readouterr().err
    finally:
        holder.close()
    assert rc == EXIT_USAGE, err
    assert f"status page: cannot listen on 127.0.0.1:{port}" in err and "choose another port" in err, err
    assert "Traceback" not in err


def test_json_log_lines_carry_the_status(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stats = tmp_path / "stats.json"
    rc = main(["--log-format", "json", "run", "--filter", "mahony", "--master", "udpin:127.0.0.1:0",
               "--heartbeat-timeout", "0", "--duration", "1.0", "--status-interval", "0.4",
               "--stats-json", str(stats)])
    assert rc == EXIT_OK
    lines = [json.loads(line) for line in capsys.readouterr().err.splitlines()]
    assert {"time", "level", "logger", "message"} <= set(lines[0])
    statuses = [line["status"] for line in lines if "status" in line]
    assert statuses and {"in_hz", "out_hz", "drops", "gain", "crc_errors", "latency_p50_us", "log"} <= set(statuses[0])
    assert lines[-1]["message"].startswith("mavahrs stopped (duration)")
    summary = json.loads(stats.read_text())
    assert summary["counters"]["datagrams_in"] == 0 and "latency" in summary


def test_internal_errors_are_one_line_with_a_hint(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    import mavahrs.cli.run as run_module

    def broken(args: object) -> int:
        raise ZeroDivisionError("oops")

    monkeypatch.setattr(run_module, "run", broken)
    assert main(["run"]) == EXIT_FAILURE
    err = capsys.readouterr().err.strip()
    assert err.endswith("internal error: ZeroDivisionError: oops (run with -v for the traceback)")
    assert main(["-v", "run"]) == EXIT_FAILURE
    assert "Traceback" in capsys.readouterr().err


def test_missing_subcommand_modules_are_skipped_other_import_errors_are_not(monkeypatch: pytest.MonkeyPatch) -> None:
    assert _load("no_such_command_module") is None
    assert "run" in SUBCOMMANDS and _load("run") is not None
    import importlib

    real = importlib.import_module

    def fake(name: str, *a: object) -> object:
        if name == "mavahrs.cli.no_such_command_module":
            raise ModuleNotFoundError("No module named 'somelib'", name="somelib")
        return real(name, *a)

    monkeypatch.setattr(importlib, "import_module", fake)
    with pytest.raises(ModuleNotFoundError, match="somelib"):
        _load("no_such_command_module")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signals_stop_cleanly_with_exit_code_0(tmp_path: Path, sig: signal.Signals) -> None:
    log = tmp_path / "x.tlog"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavahrs", "run", *QUICK, "--master", "udpin:127.0.0.1:0",
         "--heartbeat-timeout", "0", "--log", str(log)],
        stderr=subprocess.PIPE, text=True, env=_env(), cwd=tmp_path,
    )
    try:
        deadline = time.monotonic() + 60
        line = ""
        while "mavahrs running" not in line and time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line:
                break
        assert "mavahrs running" in line
        proc.send_signal(sig)
        rc = proc.wait(20)
        rest = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()
    assert rc == EXIT_OK, rest
    assert f"mavahrs stopped ({sig.name})" in rest and "Traceback" not in rest
    # stopped before the autopilot was found: nothing was recorded, and no empty tlog is left behind
    assert not log.exists()
    assert f"removed the empty log file {log}" in rest
    assert "log 0 frames (nothing recorded: empty file removed)" in rest


def test_an_interrupt_before_run_has_its_own_handlers_is_still_exit_code_0(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Ctrl-C / SIGTERM between the command line's start and `run`'s own handlers (the command line's handler
    raises there): `run` ends with 0 and says so (it was 130); other commands still end with 130."""
    import mavahrs.cli.run as run_module

    real_install = run_module._StartupSignals.install

    def interrupted_at_install(self: object) -> dict[object, object]:
        raise KeyboardInterrupt  # as the command line's SIGTERM handler and Ctrl-C raise

    monkeypatch.setattr(run_module._StartupSignals, "install", interrupted_at_install)
    assert main(["run", "--master", "udpin:127.0.0.1:0"]) == EXIT_OK
    err = capsys.readouterr().err
    assert "mavahrs stopped (interrupted) while starting" in err and "ERROR" not in err
    monkeypatch.setattr(run_module._StartupSignals, "install", real_install)
    import mavahrs.cli.replay as replay_module

    def interrupted(*_a: object, **_k: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(replay_module, "run", interrupted)
    assert main(["replay", "x.tlog"]) == EXIT_INTERRUPTED
    assert capsys.readouterr().err.strip().endswith("ERROR interrupted")


def test_a_stop_signal_during_start_up_is_acted_on_between_its_steps(tmp_path: Path) -> None:
    """The start-up's handler never raises (a raise landing in numba's ctypes callbacks was dropped: the daemon
    ran on, or segfaulted); it remembers, the start-up stops at its next step, and a signal received before the
    daemon is built stops it as its own handler would: `run` returns at once, the stop said, links closed."""
    import logging

    from mavahrs.cli import common
    from mavahrs.cli.run import _StartupSignals, _StopRequested
    from mavahrs.service.daemon import DaemonSettings, build_daemon
    from mavahrs.service.pipeline import PipelineSettings

    log = logging.getLogger("mavahrs.test.startup")
    startup = _StartupSignals(log)
    startup.checkpoint()  # nothing received: goes on
    startup(signal.SIGTERM, None)  # what the signal does: no exception, whatever code it lands in
    with pytest.raises(_StopRequested, match="SIGTERM"):
        startup.checkpoint()

    daemon = build_daemon(
        DaemonSettings(master="udpin:127.0.0.1:0", heartbeat_timeout_s=0.0, status_interval_s=0.0,
                       log_path=str(tmp_path / "x.tlog")),
        PipelineSettings(), None,
    )  # fmt: skip
    startup.attach(daemon)  # received before: the daemon is stopped before it runs
    import threading

    results: list[object] = []
    runner = threading.Thread(target=lambda: results.append(daemon.run()), daemon=True)
    runner.start()  # with --heartbeat-timeout 0 it would otherwise run until stopped: a failure, not a hang
    runner.join(60)
    if runner.is_alive():
        daemon.stop()
        runner.join(10)
        pytest.fail("the daemon ran on although a stop signal came before it was built")
    (result,) = results
    assert (result.reason, result.signal_name) == ("signal", "SIGTERM")
    assert not (tmp_path / "x.tlog").exists()  # nothing recorded: the empty log removed, as on any stop

    # a signal the command line's handler received, whose raise was dropped on the way, counts too
    received = common.SIGNALS_RECEIVED
    received.append(signal.SIGINT)
    try:
        again = _StartupSignals(log)
        old = again.install()
        signal.signal(signal.SIGINT, old[signal.SIGINT])
        signal.signal(signal.SIGTERM, old[signal.SIGTERM])
        with pytest.raises(_StopRequested, match="SIGINT"):
            again.checkpoint()
    finally:
        received.clear()


def test_sigterm_while_the_kernels_load_stops_the_daemon(tmp_path: Path) -> None:
    """SIGTERM sent the moment the status page is up — the daemon is loading its filter kernels then (numba,
    LLVM's callbacks): exit code 0 and the stop said, never lost (it ran on), never a crash or an ignored
    exception.  Three starts, each signalled at that event."""
    for attempt in range(3):
        proc = subprocess.Popen(
            [sys.executable, "-m", "mavahrs", "run", "--filter", "best", "--status-interval", "0",
             "--master", "udpin:127.0.0.1:0", "--heartbeat-timeout", "0", "--http", "127.0.0.1:0"],
            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=_env(), cwd=tmp_path,
        )  # fmt: skip
        assert proc.stderr is not None
        try:
            seen = ""
            for line in proc.stderr:
                seen += line
                if "status page on http://" in line:
                    proc.send_signal(signal.SIGTERM)
                    break
            rc = proc.wait(60)
            rest = seen + proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            proc.stderr.close()
        assert rc == EXIT_OK, (attempt, rest)
        assert "mavahrs stopped (SIGTERM)" in rest, (attempt, rest)
        assert "Exception ignored" not in rest and "Traceback" not in rest, (attempt, rest)


def _may_use_sched_fifo() -> bool:
    """Whether a process of ours may switch itself to SCHED_FIFO (root or CAP_SYS_NICE, no seccomp rule against it)."""
    probe = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=60).returncode == 0


def _run_with_realtime_priority(tmp_path: Path, prefix: list[str]) -> tuple[int | None, int | None, str, str, str]:
    """``[prefix…] mavahrs run --realtime-priority 7`` for 3 s: (policy and priority seen from outside while it
    runs, its start-up line, the whole log, ``scheduling`` from --stats-json)."""
    stats = tmp_path / "stats.json"
    proc = subprocess.Popen(
        [*prefix, sys.executable, "-m", "mavahrs", "run", *QUICK, "--master", "udpin:127.0.0.1:0",
         "--heartbeat-timeout", "0", "--duration", "3", "--realtime-priority", "7", "--stats-json", str(stats)],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=_env(),
    )  # fmt: skip
    assert proc.stderr is not None
    lines = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        lines.append(line)
        if "mavahrs running" in line:
            break
    policy = os.sched_getscheduler(proc.pid) if proc.poll() is None else None
    priority = os.sched_getparam(proc.pid).sched_priority if proc.poll() is None else None
    _, rest = proc.communicate(timeout=60)
    log = "".join(lines) + rest
    assert proc.returncode == EXIT_OK, log
    running = next(line for line in lines if "mavahrs running" in line)
    return policy, priority, running, log, json.loads(stats.read_text())["scheduling"]


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no POSIX real-time scheduling on this system")
def test_realtime_priority_is_applied_or_refused_with_one_warning(tmp_path: Path) -> None:
    """``--realtime-priority 7``: the running daemon is under SCHED_FIFO 7 (checked from outside, in the start-up
    line and in --stats-json); where the system refuses, one warning and normal scheduling, not a failure.
    With the permission, the refusal is also shown by dropping CAP_SYS_NICE (util-linux ``setpriv``)."""
    refused_runs = []
    if _may_use_sched_fifo():
        policy, priority, running, log, scheduling = _run_with_realtime_priority(tmp_path, [])
        assert (policy, priority) == (os.SCHED_FIFO, 7), log
        assert "scheduling SCHED_FIFO priority 7" in running
        assert scheduling == "SCHED_FIFO priority 7"
        assert "cannot run under real-time scheduling" not in log
        setpriv = shutil.which("setpriv")
        if setpriv is not None:
            refused_runs.append([setpriv, "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice"])
    else:
        refused_runs.append([])
    for prefix in refused_runs:
        policy, _, running, log, scheduling = _run_with_realtime_priority(tmp_path, prefix)
        assert policy == os.SCHED_OTHER, log
        assert log.count("cannot run under real-time scheduling (SCHED_FIFO priority 7)") == 1, log
        assert "scheduling normal" in running and scheduling == "normal"


def test_realtime_priority_out_of_range_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", *QUICK, "--master", "udpin:127.0.0.1:0", "--realtime-priority", "100"]) == EXIT_USAGE
    assert "realtime_priority" in capsys.readouterr().err
    assert main(["run", *QUICK, "--master", "udpin:127.0.0.1:0", "--set", "daemon.realtime_priority=true"]) == EXIT_USAGE
    assert "realtime_priority" in capsys.readouterr().err
    # the API too: Python's bool is an int, and True would have meant SCHED_FIFO priority 1
    from mavahrs.service.daemon import DaemonSettings

    with pytest.raises(ValueError, match="realtime_priority"):
        DaemonSettings(realtime_priority=True)


def test_velocity_source_flag_and_toml(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[pipeline]\nvelocity_source = "gps2_raw"\n[pipeline.monitor]\nreceiver_velocity_only = true\n')
    assert main(["run", "--config", str(cfg), "--print-config"]) == EXIT_OK
    data = tomllib.loads(capsys.readouterr().out)
    assert data["pipeline"]["velocity_source"] == "gps2_raw" and data["pipeline"]["monitor"]["receiver_velocity_only"]
    assert main(["run", "--config", str(cfg), "--velocity-source", "none", "--print-config"]) == EXIT_OK
    assert tomllib.loads(capsys.readouterr().out)["pipeline"]["velocity_source"] == "none"  # the flag wins


def test_two_config_files_are_layered_in_order(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--config mine.toml --config gains.toml`` (a `mavahrs tune` file beside one's own): every setting of
    both, the later file's over the earlier's key by key, flags over both. Until user8 the second --config
    silently replaced the first: the daemon listened on the default port and logged nothing."""
    mine = tmp_path / "mine.toml"
    mine.write_text('[daemon]\nmaster = "udpin:127.0.0.1:14560"\nlog_path = "flight.tlog"\n'
                    '[pipeline]\nfilter_name = "madgwick"\nout_rate_hz = 20.0\n'
                    "[filter.madgwick]\nmax_gap_s = 0.4\n[pipeline.calibration]\naxis_remap = \"+x+y+z\"\n")  # fmt: skip
    gains = tmp_path / "gains.toml"
    gains.write_text("[pipeline]\nout_rate_hz = 25.0\n[pipeline.calibration.gyro_temperature]\n"
                     "b0_rad_s = [0.001, 0.002, 0.003]\nk_rad_s_per_c = [0.0, 0.0, 0.0]\nt0_c = 30.0\n"
                     "[filter.madgwick]\nbeta_rad_s = 0.05\n")  # fmt: skip
    assert main(["run", "--config", str(mine), "--config", str(gains), "--out-rate", "30", "--print-config"]) == EXIT_OK
    out = capsys.readouterr().out
    assert out.startswith(f"# mavahrs effective configuration (from {mine}, {gains})")
    data = tomllib.loads(out)
    assert data["daemon"]["master"] == "udpin:127.0.0.1:14560" and data["daemon"]["log_path"] == "flight.tlog"
    assert data["pipeline"]["filter_name"] == "madgwick" and data["pipeline"]["out_rate_hz"] == 30.0  # the flag
    assert data["pipeline"]["calibration"]["gyro_temperature"]["t0_c"] == 30.0
    assert data["filter"]["madgwick"]["max_gap_s"] == 0.4 and data["filter"]["madgwick"]["beta_rad_s"] == 0.05
    assert main(["run", "--config", str(mine), "--config", str(gains), "--print-config"]) == EXIT_OK
    assert tomllib.loads(capsys.readouterr().out)["pipeline"]["out_rate_hz"] == 25.0  # the later file
    # an error names the file it is in
    bad = tmp_path / "bad.toml"
    bad.write_text("[pipeline]\nout_rate = 3\n")
    assert main(["run", "--config", str(mine), "--config", str(bad), "--print-config"]) == EXIT_USAGE
    assert f"config file {bad}: unknown setting 'pipeline.out_rate'" in capsys.readouterr().err
