"""Every command takes every log format, chosen by content: evaluate, tune, plot and audit.

On the synthetic 400 Hz DataFlash flight of ``tests/conftest.py`` (its IMU the exact derivative of its
SIM truth), a telemetry log from ``mavahrs.warmup.synthetic_frames`` and, where present, the shared PX4
bench ULog ``../shared/data/px4_ulog/sample.ulg`` (linked into tmp_path, not copied).  A file that is no
log gets an error naming the supported formats, never a traceback.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mavahrs.cli import main
from mavahrs.logs import FORMATS


def _named_formats(text: str) -> bool:
    """The message names the three formats (``mavahrs.logs.FORMATS``, in whatever words)."""
    return all(suffix in text for suffix in (".tlog", ".BIN", ".ulg")) and len(FORMATS) == 3


def test_evaluate_scores_a_dataflash_log_against_sim_whatever_its_name(dataflash_log, tmp_path: Path, capsys) -> None:
    path, _ = dataflash_log
    odd = tmp_path / "flight_2026.dat"
    odd.symlink_to(path)
    assert main(["evaluate", str(odd), "-f", "mahony,best", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["recordings"] == 1
    assert rep["per_recording"]["flight_2026"]["notes"][0].startswith("reference: SIM truth")
    assert rep["filters"]["mahony"]["inclination_rms_deg"] < 0.15  # measured 0.05°
    assert rep["filters"]["mahony"]["heading_rms_deg"] < 0.1  # measured 0.02°
    # best on an autopilot's log is the ESKF, here without GNSS, as the daemon runs it: measured 0.25° / 0.12°
    assert rep["filters"]["best"]["inclination_rms_deg"] < 0.5
    assert rep["filters"]["best"]["heading_rms_deg"] < 0.3


def test_evaluate_tune_plot_name_the_formats_for_a_file_that_is_no_log(tmp_path: Path, capsys) -> None:
    text = tmp_path / "flight.BIN"
    text.write_text("this is a note, not a log\n" * 10)
    for cmd in (["evaluate", str(text)], ["tune", str(text)], ["plot", str(text), "-o", str(tmp_path / "x.png")]):
        assert main(cmd) == 1, cmd
        err = capsys.readouterr().err
        assert "Traceback" not in err and _named_formats(err), (cmd, err)


def test_tune_reads_the_rest_of_a_dataflash_log(write_df, tmp_path: Path, capsys) -> None:
    path, fl = write_df(tmp_path / "rest.BIN", duration_s=6.0, gyro_noise_rad_s=0.003)
    assert main(["tune", str(path), "--end", "2.5", "--json"]) == 0  # the synthetic flight rests for 3 s
    out = json.loads(capsys.readouterr().out)
    assert out["samples"] == pytest.approx(2.5 * 400, abs=2) and out["rate_hz"] == pytest.approx(400.0)
    # the logged noise is found (SD 3 mrad/s) and the bias is zero within its uncertainty (SD/√N ≈ 0.1 mrad/s)
    assert all(abs(sd - 0.003) < 0.0003 for sd in out["noise_sd_rad_s"])
    assert all(abs(b) < 5e-4 for b in out["b0_rad_s"])


def test_plot_replays_a_dataflash_log(dataflash_log, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    path, _ = dataflash_log
    png = tmp_path / "df.png"
    assert main(["plot", str(path), "-o", str(png), "-f", "best", "--end", "10"]) == 0
    assert png.stat().st_size > 20_000


def test_audit_a_folder_mixing_the_formats(dataflash_log, tmp_path: Path, shared_data: Path, capsys) -> None:
    from mavahrs.fleet.audit import read_table
    from mavahrs.protocol.tlog import tlog_record
    from mavahrs.warmup import synthetic_frames

    path, _ = dataflash_log
    folder = tmp_path / "flights"
    (folder / "copter").mkdir(parents=True)
    (folder / "copter" / "onboard.BIN").symlink_to(path)
    data = path.read_bytes()
    (folder / "copter" / "cut.BIN").write_bytes(data[: len(data) // 2 + 5])  # truncated inside a record
    (folder / "gcs.tlog").write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames(3.0)))
    (folder / "empty.BIN").write_bytes(b"")
    (folder / "notes.ulg").write_text("not a ULog\n" * 20)
    (folder / "README.txt").write_text("flights of 2026\n")  # not a log by name nor by content: not a row
    ulg = shared_data / "px4_ulog" / "sample.ulg"
    if ulg.exists():
        (folder / "px4.ulg").symlink_to(ulg)
    table = tmp_path / "fleet.csv"
    rc = main(["audit", str(folder), "--serial", "--no-progress", "-o", str(table)])
    cap = capsys.readouterr()
    assert rc == 1  # two unreadable logs
    assert "audit: 2 of " in cap.err and "logs could not be read (their rows carry the error)" in cap.err
    rows = {Path(r.path).name: r for r in read_table(table)}
    expect = {"onboard.BIN", "cut.BIN", "gcs.tlog", "empty.BIN", "notes.ulg"} | ({"px4.ulg"} if ulg.exists() else set())
    assert set(rows) == expect
    assert rows["empty.BIN"].error == "empty file"
    assert _named_formats(rows["notes.ulg"].error)
    ok = rows["onboard.BIN"]
    assert ok.error == "" and ok.log_format == "dataflash" and ok.autopilot == "ARDUPILOTMEGA"
    assert 399.0 < ok.imu_rate_hz < 401.0 and ok.imu_message == "IMU" and ok.truncated is False
    assert rows["cut.BIN"].error == "" and rows["cut.BIN"].truncated is True
    assert rows["gcs.tlog"].error == "" and rows["gcs.tlog"].log_format == "tlog"
    if ulg.exists():
        assert rows["px4.ulg"].error == "" and rows["px4.ulg"].log_format == "ulog"
    assert "unreadable:" in cap.out and "Traceback" not in cap.err
    # the same folder on a Dask cluster (a scheduler and two workers over loopback): the same rows
    pytest.importorskip("distributed", reason="the fleet extra (Dask) is not installed")
    import os

    from mavahrs.fleet.audit import TIMING_FIELDS
    from mavahrs.fleet.dask_engine import loopback_cluster

    repo = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(repo), *filter(None, [os.environ.get("PYTHONPATH")])]))
    with loopback_cluster(tmp_path / "cluster", 2, env=env) as address:
        cluster_table = tmp_path / "cluster.csv"
        rc = main(["audit", str(folder), "--scheduler", address, "--no-progress", "-o", str(cluster_table)])
    cap = capsys.readouterr()
    assert rc == 1 and f"on the cluster at {address}" in cap.out, cap.out[-2000:]

    def fixed(r):  # type: ignore[no-untyped-def]
        return {k: repr(v) for k, v in r.as_dict().items() if k not in TIMING_FIELDS}

    on_cluster = {Path(r.path).name: fixed(r) for r in read_table(cluster_table)}
    assert on_cluster == {name: fixed(r) for name, r in rows.items()}
