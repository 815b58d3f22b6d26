"""``mavahrs audit`` over a simulated fleet: locally on Dask, serially without Dask, and on a real Dask cluster
over loopback TCP; every row checked against what each flight was; resumable tables.

The fleet (generated once per module with firmware_sim): 38 short flights of mixed scenarios, autopilots,
loop rates, IMU counts and system ids, two of them with an injected autopilot attitude fault; one file of
random bytes and one empty file.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mavahrs.cli import main
from mavahrs.fleet.audit import (
    SERIAL_HINT,
    TIMING_FIELDS,
    AuditSettings,
    FleetRow,
    read_table,
    run_audit,
    serial_map,
    summarise_log,
)
from mavahrs.service.monitor import MonitorSettings

pytestmark = pytest.mark.slow
for _module in ("distributed", "pyarrow"):
    pytest.importorskip(_module, reason="the fleet extra is not installed: pip install '.[fleet]'")

REPO = Path(__file__).resolve().parents[2]
N_SIM = 38
CLEAN_S, FAULT_S = 15.0, 20.0


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, object]]:
    """The fleet's folder and, per file name, its FleetLog (None for the corrupt and the empty file)."""
    from firmware_sim.fleet import mixed_fleet, write_fleet_log

    folder = tmp_path_factory.mktemp("fleet")
    specs: dict[str, object] = {}
    for i, log in enumerate(mixed_fleet(N_SIM, faults=2, clean_s=CLEAN_S, fault_s=FAULT_S)):
        sub = folder / ("2025-06" if i % 2 else "2025-07")  # folders are searched recursively
        sub.mkdir(exist_ok=True)
        write_fleet_log(sub, log)
        specs[log.name] = log
    (folder / "corrupt.tlog").write_bytes(np.random.default_rng(18).integers(0, 256, 50_000, dtype=np.uint8).tobytes())
    (folder / "empty.tlog").write_bytes(b"")
    (folder / "README.txt").write_text("not a log: a folder is searched for *.tlog only")
    specs["corrupt.tlog"] = specs["empty.tlog"] = None
    return folder, specs


def _env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env.update(extra)
    return env


#: These tests check the audit's rows, tables and engines with the monitor's fixed thresholds (10° / 25°,
#: the 15° fault crosses 10°): the uncertainty-based default warns on firmware_sim's clean flights, whose
#: simulated autopilot attitude errs by up to 1.9° (tests/service/test_monitor_flights.py judges that mode
#: on the shared SITL flights).
FIXED_MONITOR = MonitorSettings(mode="fixed")
_FIXED_TOML = '[pipeline.monitor]\nmode = "fixed"\n'


@pytest.fixture(scope="module", autouse=True)
def _fixed_monitor_config(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    global _CONFIG
    path = tmp_path_factory.mktemp("config") / "fixed_monitor.toml"
    path.write_text(_FIXED_TOML)
    _CONFIG = str(path)
    yield
    _CONFIG = None


_CONFIG: str | None = None


def _audit(*args: str, env: dict[str, str] | None = None, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    config = ["--config", _CONFIG] if _CONFIG else []
    return subprocess.run([sys.executable, "-m", "mavahrs", "audit", *args, *config], capture_output=True, text=True,
                          env=env or _env(), timeout=timeout, cwd=REPO)  # fmt: skip


def _fixed(row: FleetRow) -> dict[str, str]:
    """The fields that do not depend on timing, as text (NaN == NaN)."""
    return {k: repr(v) for k, v in row.as_dict().items() if k not in TIMING_FIELDS}


@pytest.fixture(scope="module")
def local_run(fleet: tuple[Path, dict[str, object]], tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """``mavahrs audit FOLDER -o fleet.parquet -o fleet.csv --plot`` on the default engine: a local Dask cluster."""
    folder, _ = fleet
    out = tmp_path_factory.mktemp("local")
    res = _audit(str(folder), "-o", str(out / "fleet.parquet"), "-o", str(out / "fleet.csv"),
                 "--plot", str(out / "fleet.png"), "--workers", "2")  # fmt: skip
    assert res.returncode == 1, res.stderr  # the fleet holds two unreadable logs
    return res, out


def test_every_row_of_the_fleet(fleet, local_run) -> None:  # type: ignore[no-untyped-def]
    folder, specs = fleet
    res, out = local_run
    rows = {Path(r.path).name: r for r in read_table(out / "fleet.parquet")}
    assert set(rows) == set(specs)  # every log present, nothing else (README.txt is not a log)
    mon = FIXED_MONITOR
    for name, spec in specs.items():
        r = rows[name]
        assert r.size_bytes == (next(folder.rglob(name))).stat().st_size
        if spec is None:
            continue
        assert r.error == "", (name, r.error)
        px4 = spec.autopilot == "px4"
        assert (r.system_id, r.component_id) == (spec.sysid, 1)
        assert (r.autopilot, r.vehicle_type) == ("PX4" if px4 else "ARDUPILOTMEGA", "QUADROTOR")
        assert r.start_utc.startswith("2025-06-01T00:00:00.0000")  # firmware_sim's epoch
        assert r.imu_message == ("HIGHRES_IMU" if px4 else "RAW_IMU") and r.imu_instance == 0
        assert abs(r.duration_s - spec.duration_s) < 0.01 and r.imu_rate_hz >= 140.0
        assert r.imu_samples == pytest.approx(r.duration_s * r.imu_rate_hz + 1, abs=1)
        assert r.gnss is True and r.engine == "fast" and r.reference == "autopilot ATTITUDE"
        assert r.compared_s == pytest.approx(spec.duration_s - mon.startup_grace_s, abs=0.1)
        assert 0.0 <= r.gyro_clip_fraction < 0.01 and 0.0 <= r.accel_clip_fraction < 0.01
        vib = max(r.vibration_x_m_s2, r.vibration_y_m_s2, r.vibration_z_m_s2)
        # ArduPilot's RAW_IMU is low-passed at 20 Hz; PX4's HIGHRES_IMU is vehicle_imu's interval mean, which keeps
        # most of the motors' vibration (firmware_sim: a clean flight 1.4, the vibration scenario 11 m/s² RMS)
        low, high = (3.0, 5.0) if px4 else (0.3, 0.5)
        assert (vib > high) if spec.scenario == "vibration" else (0.0 < vib < low), (name, vib)
        if spec.imus == 1 and not px4:
            assert "IMU instance 1 sends all-zero accelerometer and gyro (no such IMU): not used" in r.notes
        if spec.fault is None:  # clean: no alarm
            assert r.alarms == 0 and r.alarm_times_s == "" and math.isnan(r.first_alarm_s), name
            if spec.scenario != "vibration":  # (strong aliased vibration: brief divergences up to ~12°, no alarm)
                assert r.inclination_max_deg < 0.5 * mon.tilt_threshold_deg, name
                assert r.heading_max_deg < 0.5 * mon.heading_threshold_deg, name
                assert r.inclination_rms_deg < 3.0 and r.heading_rms_deg < 6.0, name
        else:  # flagged when the 15° fault has passed 10° for the monitor's trigger time
            due = spec.fault_onset_s + mon.trigger_s
            assert r.alarms == 1 and due - 0.3 <= r.first_alarm_s <= due + 0.3, (name, r.first_alarm_s, due)
            assert r.alarm_times_s == f"{r.first_alarm_s:.3f}"
            assert 13.0 < r.inclination_max_deg < 17.0, name
    assert rows["empty.tlog"].error == "empty file"
    assert rows["corrupt.tlog"].error == "no autopilot HEARTBEAT and no IMU messages (RAW_IMU, SCALED_IMU*, HIGHRES_IMU)"
    for name in ("empty.tlog", "corrupt.tlog"):
        r = rows[name]
        assert r.system_id is None and r.alarms is None and math.isnan(r.inclination_rms_deg)


def test_the_printed_summary_puts_the_worst_flights_first(fleet, local_run) -> None:  # type: ignore[no-untyped-def]
    _, specs = fleet
    res, out = local_run
    lines = res.stdout.splitlines()
    assert re.fullmatch(r"audited 40 logs \(40 replayed, 0 already in the table\) in \d+\.\d s on a local Dask "
                        r"cluster \(2 workers\): 2 flagged, 2 unreadable; \d+ IMU samples, \S+ samples/s", lines[0]), lines[0]
    # the start-up before the first log (the cluster, the kernels: loaded, or on a cold cache compiled), not timed above
    assert re.fullmatch(r"start-up before the first log \d+\.\d s, not in the figures above: starting the local cluster "
                        r"\d+\.\d s; meanwhile the filter kernels (loaded from the cache in \d+\.\d s|compiled once .*)",
                        lines[1]), lines[1]  # fmt: skip
    del lines[1]
    faulted = sorted(n for n, s in specs.items() if s is not None and s.fault is not None)
    assert re.fullmatch("flagged: the autopilot's attitude disagreed with mavahrs \\(second-opinion monitor "
                        r"WARNING\) in flight_03[67]_hover_fault.tlog at 14\.\d{3} s, flight_03[67]_hover_fault.tlog "
                        r"at 14\.\d{3} s", lines[1]), lines[1]
    assert all(n in lines[1] for n in faulted)
    head = lines.index("worst flights first (divergence from the log's own attitude, deg; top 10 of 38):")
    table = lines[head + 3 : head + 13]
    assert sorted(t.split()[0][:20] for t in table[:2]) == [n[:20] for n in faulted]
    assert all(t.split()[7] == "0" for t in table[2:])  # alarms column
    assert lines[-3:] == ["unreadable:", "  corrupt.tlog: no autopilot HEARTBEAT and no IMU messages (RAW_IMU, "
                          "SCALED_IMU*, HIGHRES_IMU)", "  empty.tlog: empty file"]  # fmt: skip
    assert f"wrote {out / 'fleet.parquet'}" in res.stderr and f"wrote {out / 'fleet.png'}" in res.stderr
    assert (out / "fleet.png").stat().st_size > 30_000


def test_plot_draws_one_chart_per_readable_log_and_nothing_else(fleet, local_run) -> None:  # type: ignore[no-untyped-def]
    """``--plot fleet.png``: ``fleet_flights/`` holds a second-opinion chart for each log replayed; the audit's own
    warm-up on a synthetic log (loading the kernels while the cluster starts) drew ``kernels_second_opinion.png``
    there too, a chart of no flight of the user's."""
    _, specs = fleet
    _, out = local_run
    charts = {p.name for p in (out / "fleet_flights").iterdir()}
    assert charts == {f"{Path(name).stem}_second_opinion.png" for name, spec in specs.items() if spec is not None}


def test_parquet_and_csv_hold_the_same_rows(local_run) -> None:  # type: ignore[no-untyped-def]
    _, out = local_run
    a, b = read_table(out / "fleet.parquet"), read_table(out / "fleet.csv")
    assert [repr(r) for r in a] == [repr(r) for r in b]
    assert len({r.worker for r in a}) == 2  # both local worker processes took tasks


def test_without_dask_audit_runs_serially_and_says_how_to_get_parallelism(fleet, local_run, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A ``dask`` package that cannot be imported (first on the path): same rows, one process, one hint line."""
    folder, _ = fleet
    _, out = local_run
    blocker = tmp_path / "blocker" / "dask"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text("raise ImportError('dask is not installed here')\n")
    env = _env()
    env["PYTHONPATH"] = os.pathsep.join([str(blocker.parent), env["PYTHONPATH"]])
    res = _audit(str(folder), "-o", str(tmp_path / "serial.csv"), env=env)
    assert res.returncode == 1, res.stderr  # the fleet holds two unreadable logs
    assert any(line.endswith(" " + SERIAL_HINT) for line in res.stderr.splitlines()), res.stderr
    assert SERIAL_HINT == ("audit: Dask is not installed: replaying the logs one after the other on one core "
                           "(for all cores or a cluster: pip install 'mavahrs[fleet]')")  # fmt: skip
    assert " on one process, serially: 2 flagged, 2 unreadable" in res.stdout.splitlines()[0]
    serial = read_table(tmp_path / "serial.csv")
    assert [_fixed(r) for r in serial] == [_fixed(r) for r in read_table(out / "fleet.parquet")]
    assert len({r.worker for r in serial}) == 1
    res = _audit(str(folder), "--scheduler", "tcp://127.0.0.1:1", env=env)
    assert res.returncode == 2 and "audit: --scheduler needs Dask: pip install 'mavahrs[fleet]'" in res.stderr
    # without pyarrow: CSV only, and a Parquet table is refused before anything is replayed
    (blocker.parent / "pyarrow").mkdir()
    (blocker.parent / "pyarrow" / "__init__.py").write_text("raise ImportError('pyarrow is not installed here')\n")
    res = _audit(str(folder), "-o", str(tmp_path / "fleet.parquet"), env=env)
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.strip().endswith("audit: Parquet needs pyarrow: pip install 'mavahrs[fleet]' (or write a .csv)")


def test_a_dask_cluster_over_loopback_gives_the_same_rows(fleet, local_run, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1; ``audit --scheduler`` sends them the logs."""
    import psutil

    from mavahrs.fleet.dask_engine import loopback_cluster

    folder, _ = fleet
    _, out = local_run
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    with loopback_cluster(tmp_path / "cluster", 2, env=_env()) as address:
        assert address.startswith("tcp://127.0.0.1:")
        daemons = [p for p in psutil.Process().children(recursive=True) if p.pid not in before]
        assert len(daemons) >= 3  # the scheduler, two workers (and their nannies' children)
        res = _audit(str(folder), "--scheduler", address, "-o", str(tmp_path / "cluster.parquet"))
        assert res.returncode == 1, res.stderr  # the fleet holds two unreadable logs
        assert f"on the cluster at {address} (2 workers)" in res.stdout.splitlines()[0]
        cluster = read_table(tmp_path / "cluster.parquet")
        assert [_fixed(r) for r in cluster] == [_fixed(r) for r in read_table(out / "fleet.parquet")]
        assert len({r.worker for r in cluster}) == 2  # both workers took tasks
        assert {r.worker.rsplit(":", 1)[1] for r in cluster} <= {str(p.pid) for p in daemons}
    _, alive = psutil.wait_procs(daemons, timeout=30)  # all stopped (the workers' own children after them)
    assert not alive


def test_resumable_table_skips_what_is_summarised_and_survives_an_interruption(fleet, local_run, tmp_path: Path,
                                                                               capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
    folder, _ = fleet
    _, out = local_run
    table = tmp_path / "fleet.parquet"
    table.write_bytes((out / "fleet.parquet").read_bytes())
    assert main(["audit", str(folder), "-o", str(table), "--serial", "--no-progress"]) == 1  # two unreadable logs
    assert "audited 40 logs (0 replayed, 40 already in the table) in" in capsys.readouterr().out
    # a log that changed (its modification time) is replayed again; --force replays all
    log = next(folder.rglob("flight_000_*.tlog"))
    st = log.stat()
    os.utime(log, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    try:
        assert main(["audit", str(folder), "-o", str(table), "--serial"]) == 1  # two unreadable logs
        assert "audited 40 logs (1 replayed, 39 already in the table) in" in capsys.readouterr().out
        assert {r.path: r.mtime_ns for r in read_table(table)}[str(log)] == st.st_mtime_ns + 1_000_000_000
    finally:
        os.utime(log, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert main(["audit", str(folder), "-o", str(table), "--serial", "--force"]) == 1  # two unreadable logs
    assert "audited 40 logs (40 replayed, 0 already in the table) in" in capsys.readouterr().out

    # Ctrl-C after 5 logs: the table holds those 5, a second run replays only the other 35
    from mavahrs.fleet.audit import expand_logs

    logs = expand_logs([str(folder)])
    csv = tmp_path / "partial.csv"

    def interrupted(fn, items):  # type: ignore[no-untyped-def]
        for k, row in serial_map(fn, items):
            if k == 5:
                raise KeyboardInterrupt
            yield k, row

    from mavahrs.replay import ReplaySettings
    from mavahrs.service.pipeline import PipelineSettings

    settings = AuditSettings(replay=ReplaySettings(pipeline=PipelineSettings(monitor=FIXED_MONITOR)))  # as _audit
    with pytest.raises(KeyboardInterrupt):
        run_audit(logs, lambda p: summarise_log(p, settings), interrupted, tables=[csv], flush_every_s=3600.0)
    assert [r.path for r in read_table(csv)] == [str(p) for p in logs[:5]]
    assert not list(tmp_path.glob(".*.tmp"))  # replaced atomically, nothing left behind
    again = run_audit(logs, lambda p: summarise_log(p, settings), tables=[csv])
    assert (again.replayed, again.reused) == (35, 5)
    assert [_fixed(r) for r in read_table(csv)] == [_fixed(r) for r in read_table(out / "fleet.parquet")]


def test_one_log_summary_is_a_pure_function_of_the_file(fleet) -> None:  # type: ignore[no-untyped-def]
    folder, _ = fleet
    log = next(folder.rglob("flight_037_*.tlog"))
    a, b = summarise_log(log), summarise_log(log)
    assert _fixed(a) == _fixed(b) and a.alarms == 1
    # the monitor's thresholds come from the daemon's settings: a 20° tilt threshold does not fire on the 15° fault
    from mavahrs.replay import ReplaySettings
    from mavahrs.service.pipeline import PipelineSettings

    lax = AuditSettings(replay=ReplaySettings(pipeline=PipelineSettings(monitor=MonitorSettings(mode="fixed", tilt_threshold_deg=20.0))))
    assert summarise_log(log, lax).alarms == 0
    missing = summarise_log(folder / "no-such.tlog")
    assert missing.error == "cannot read: No such file or directory" and missing.size_bytes == -1


def test_a_log_shorter_than_the_start_up_grace_says_why_nothing_is_compared(fleet, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Its row's divergence columns are empty: the notes and the printed table say it is too short."""
    folder, _ = fleet
    short = tmp_path / "short.tlog"
    short.write_bytes(next(folder.rglob("flight_000_*.tlog")).read_bytes()[:100_000])  # ~2.5 s, cut mid-record
    row = summarise_log(short)
    assert row.error == "" and row.reference and row.compared_s == 0.0 and math.isnan(row.inclination_rms_deg)
    assert "nothing compared" in row.notes and "start-up grace of 10 s" in row.notes and row.truncated
    res = _audit(str(tmp_path), "--serial", "-o", str(tmp_path / "short.csv"))
    assert res.returncode == 0, res.stderr
    tail = res.stdout.split("not compared (too short):\n", 1)[1]
    assert tail.startswith("  short.tlog: nothing compared: the log's "), res.stdout


def test_files_that_are_not_logs_are_skipped_with_one_line(fleet, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``mavahrs audit flights/*`` (the shell expands the glob): the folder's table, plot and notes are skipped,
    said in one line, and are no failure rows; a renamed log (by content) and a damaged .tlog (by name) stay."""
    import glob as globmod

    folder, _ = fleet
    flights = tmp_path / "flights"
    flights.mkdir()
    log = next(folder.rglob("flight_000_*.tlog"))
    (flights / "a.tlog").write_bytes(log.read_bytes()[:200_000])
    (flights / "renamed.dat").write_bytes(log.read_bytes()[:200_000])  # a tlog by its first bytes
    (flights / "damaged.tlog").write_bytes(b"not a tlog at all")
    (flights / "fleet.csv").write_text("path,error\n")
    (flights / "notes.txt").write_text("flown on Tuesday")
    (flights / "fleet.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    (flights / "README").write_text("no suffix, no log")
    res = _audit(*sorted(globmod.glob(str(flights / "*"))), "--serial", "--no-progress")
    assert res.returncode == 1, res.stderr  # the damaged .tlog only
    assert ("audit: skipped 4 files that are not flight logs (.tlog, .BIN, .ulg by name or content): "
            "README, fleet.csv, fleet.png and 1 more") in res.stderr  # fmt: skip
    assert "audit: 1 of 3 logs could not be read" in res.stderr
    assert "audited 3 logs (3 replayed" in res.stdout
    for name in ("fleet.csv", "notes.txt", "fleet.png"):
        assert name not in res.stdout
    # one such file: said in the singular ("skipped 1 file that is not flight log" until user8)
    res = _audit(str(flights / "a.tlog"), str(flights / "notes.txt"), "--serial", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert ("audit: skipped 1 file that is not a flight log (.tlog, .BIN, .ulg by name or content): "
            "notes.txt") in res.stderr  # fmt: skip
    # nothing but files that are not logs: a usage-level error, not an empty table
    res = _audit(str(flights / "notes.txt"), str(flights / "fleet.csv"), "--serial")
    assert res.returncode != 0 and "no flight log among the 2 files given (fleet.csv, notes.txt)" in res.stderr


def test_audit_help_and_usage_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["audit", "--help"]) == 0
    help_text = capsys.readouterr().out
    assert "mavahrs audit flights/ -o fleet.parquet --plot fleet.png" in help_text
    assert "--scheduler ADDRESS" in help_text and "DASK_SCHEDULER_ADDRESS" in help_text
    assert main(["audit", str(tmp_path / "nothing-*.tlog")]) == 1
    assert f"audit: {tmp_path / 'nothing-*.tlog'}: no such log (file, folder or glob)" in capsys.readouterr().err
    assert main(["audit", str(tmp_path), "-o", str(tmp_path / "fleet.xlsx")]) == 2
    assert f"audit: {tmp_path / 'fleet.xlsx'}: the table must be .parquet or .csv" in capsys.readouterr().err


def test_a_flag_on_a_log_whose_imu_is_too_slow_says_so(mavlink_logs_dir: Path) -> None:
    """The real VTOL tlog's IMU arrives at 4 Hz (replay: "too slow for meaningful attitude filtering"); its one
    WARNING headed the summary's "flagged:" line like a real disagreement. Now the line says the IMU rate."""
    import dataclasses

    from mavahrs.fleet.audit import AuditRun, format_summary

    row = summarise_log(mavlink_logs_dir / "UAVLogViewer" / "vtol.tlog")
    assert row.error == "" and 0 < row.imu_rate_hz < 50
    if not row.flagged:  # whether the monitor warns on a 4 Hz IMU depends on its settings: one WARNING given
        row = dataclasses.replace(row, alarms=1, alarm_times_s="60.0")
    text = format_summary(AuditRun([row], 1, 0, row.imu_samples, 1.0))
    flagged = next(ln for ln in text.splitlines() if ln.startswith("flagged:"))
    first = row.alarm_times_s.split(";")[0]
    assert f"vtol.tlog at {first}" in flagged and flagged.endswith(f"(IMU {row.imu_rate_hz:.0f} Hz: too slow to judge)")
