"""``mavahrs evaluate``: tables, JSON, studies, tlogs with SIMSTATE, exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mavahrs.cli import main


def test_json_on_a_broad_trial(broad_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", str(broad_dir / "02_undisturbed_slow_rotation_B.mat"), "-f", "mahony", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    f = d["filters"]["mahony"]
    for key in ("total_rms_deg", "heading_rms_deg", "inclination_rms_deg", "roll_rms_rest_deg",
                "pitch_rms_motion_deg", "yaw_mean_deg", "roll_sd_deg"):  # fmt: skip
        assert isinstance(f[key], float), key
    assert 0 < f["inclination_rms_deg"] <= f["total_rms_deg"] < 10


def test_table_on_a_repoimu_trial(shared_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = shared_data / "repoimu_tstick" / "TStick_Test02_Trial1.csv"
    if not p.exists():
        pytest.skip("RepoIMU data absent")
    assert main(["evaluate", str(p), "-f", "mahony", "--align", "heading+body"]) == 0
    out = capsys.readouterr().out
    assert "heading offset" in out and "body misalignment" in out and "mahony" in out


def test_simulator_tlog_is_scored_against_simstate(sim_hover_tlog: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", str(sim_hover_tlog), "-f", "mahony", "--json", "--skip", "5"]) == 0
    d = json.loads(capsys.readouterr().out)
    rec = d["per_recording"]["hover"]
    assert any("truth" in n for n in rec["notes"])
    assert d["filters"]["mahony"]["inclination_rms_deg"] < 3.0
    assert d["filters"]["mahony"]["alignment"] == "none"


@pytest.mark.slow
def test_study_rate_with_plot(broad_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("matplotlib")
    png = tmp_path / "rate.png"
    trial = str(broad_dir / "02_undisturbed_slow_rotation_B.mat")
    assert main(["evaluate", trial, "--study", "rate", "-f", "mahony", "--plot", str(png)]) == 0
    out, err = capsys.readouterr()
    assert "Fig. 11" in out and "285.714" in out and png.stat().st_size > 10_000
    assert f"wrote {png}" in err  # as every command says it (it said "plot: …" until user6)
    single = tmp_path / "trial.png"
    assert main(["evaluate", trial, "-f", "mahony", "--plot", str(single)]) == 0
    assert f"wrote {single}" in capsys.readouterr().err and single.stat().st_size > 10_000


def test_errors_are_one_line_with_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", str(tmp_path / "missing.mat")]) == 1
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,foo\n1,2\n")
    assert main(["evaluate", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "no such file" in err and "gyro_x_rad_s" in err and "Traceback" not in err
    csv = tmp_path / "ok.csv"
    np.savetxt(csv, np.zeros((3, 7)), delimiter=",", comments="",
               header="time_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2")
    assert main(["evaluate", str(csv), "-f", "kalman"]) == 2


def test_velocity_source_flag_reaches_the_tlog_inputs(sim_gps_raw_tlog: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np

    from mavahrs.evaluation.loaders import load_any

    assert main(["evaluate", str(sim_gps_raw_tlog), "-f", "mahony", "--json", "--skip", "5",
                 "--velocity-source", "gps_raw_int"]) == 0  # fmt: skip
    assert json.loads(capsys.readouterr().out)["filters"]["mahony"]["inclination_rms_deg"] < 5.0
    rec = load_any(sim_gps_raw_tlog, velocity_source="gps_raw_int")[0]
    vel, age = rec.extra["velocity_ned_m_s"], rec.extra["velocity_age_s"]
    fed = np.isfinite(vel[:, 0])
    assert fed.sum() > 50 and np.isnan(vel[fed, 2]).all() and (age[fed] > 0.1).all()  # the receiver's, with its age
    assert np.isnan(age[~fed]).all()
    assert load_any(sim_gps_raw_tlog, velocity_source="none")[0].extra["velocity_ned_m_s"] is None


@pytest.mark.parametrize("command", ["replay", "evaluate"])
def test_help_lists_every_registered_filter(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    """`--help` names the filters from the registry (it listed them by hand and left out eskf)."""
    import re

    from mavahrs.filters import ALIASES, NAMES

    assert main([command, "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    m = re.search(r"--filter NAME, -f NAME (.*?)\(default", text)
    assert m, text
    listed = re.findall(r"[a-z]+", m.group(1).split(":", 1)[1])
    assert sorted(listed) == sorted([*NAMES, *ALIASES, "or", "all"]), m.group(0)


def test_a_missing_broad_folder_says_where_to_get_broad(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The README's ``evaluate ../shared/data/broad/`` for a user who has only the repository."""
    assert main(["evaluate", str(tmp_path / "shared" / "data" / "broad")]) == 1
    (tmp_path / "broad").mkdir()
    assert main(["evaluate", str(tmp_path / "broad")]) == 1
    assert main(["evaluate", str(tmp_path / "flights")]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 3, lines
    for line in lines[:2]:
        assert "dlaidig/broad" in line and "data_mat" in line and "CC BY 4.0" in line, line
    assert "no such file" in lines[2] and "dlaidig" not in lines[2]  # only where BROAD was meant


def _replay_truth_row(capsys: pytest.CaptureFixture[str], log: Path, *args: str) -> list[float]:
    assert main(["replay", str(log), "--no-progress", *args]) == 0
    out = capsys.readouterr().out
    row = next(ln for ln in out.splitlines() if ln.startswith("best") and "truth" in ln)
    return [float(x) for x in row.split()[-6:-3]]  # total, head, incl


def test_evaluate_and_replay_score_a_tlog_alike(sim_gps_raw_tlog: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same log scored 1.65 / 1.59° (best, total / heading) in evaluate and 1.04 / 0.96° in replay: evaluate's
    filter was not told the IMU stamps' delay, which the pipeline (replay, the daemon) tells it."""
    assert main(["evaluate", str(sim_gps_raw_tlog), "-f", "best", "--json", "--skip", "3"]) == 0
    ev = json.loads(capsys.readouterr().out)["filters"]["best"]
    rp = _replay_truth_row(capsys, sim_gps_raw_tlog, "-f", "best", "--skip", "3")
    # evaluate slerps the truth onto the IMU samples, replay the estimate onto the truth's times: equal but for that
    assert ev["total_rms_deg"] == pytest.approx(rp[0], abs=0.03)
    assert ev["heading_rms_deg"] == pytest.approx(rp[1], abs=0.03)
    assert ev["inclination_rms_deg"] == pytest.approx(rp[2], abs=0.03)


def test_replay_says_what_its_table_covers_and_skips_like_the_readme(sim_gps_raw_tlog: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """Replay's figures included the convergence, the README's tables leave out 10 s, and nothing said so."""
    assert main(["replay", str(sim_gps_raw_tlog), "--no-progress", "-f", "best"]) == 0
    out = capsys.readouterr().out
    assert "convergence" in out and "--skip" in out
    whole = _replay_truth_row(capsys, sim_gps_raw_tlog, "-f", "best")
    late = _replay_truth_row(capsys, sim_gps_raw_tlog, "-f", "best", "--skip", "6")
    assert late != whole
    assert main(["replay", str(sim_gps_raw_tlog), "--no-progress", "-f", "best", "--skip", "6"]) == 0
    out = capsys.readouterr().out
    samples = {ln.split()[0]: int(ln.split()[-7]) for ln in out.splitlines() if "truth" in ln}
    assert main(["replay", str(sim_gps_raw_tlog), "--no-progress", "-f", "best"]) == 0
    all_samples = {ln.split()[0]: int(ln.split()[-7]) for ln in capsys.readouterr().out.splitlines() if "truth" in ln}
    assert 0.4 < samples["best"] / all_samples["best"] < 0.6  # 6 of 12 s


def test_a_folder_marks_only_the_recordings_left_out(sim_hover_tlog: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """`evaluate fleet/` said "1 left out (… marked *)" and marked every row (each had an informative note)."""
    import shutil

    folder = tmp_path / "fleet"
    folder.mkdir()
    for name in "abcd":  # four: more than three recordings get the one-line-per-recording table
        shutil.copy(sim_hover_tlog, folder / f"{name}.tlog")
    assert main(["evaluate", str(folder), "-f", "mahony"]) == 0
    out = capsys.readouterr().out
    assert "per recording" in out, out
    marked = [ln for ln in out.splitlines() if ln.rstrip().endswith(" *")]
    assert "left out" not in out and not marked, out  # all four are in the mean


def test_messages_are_log_lines_and_the_field_is_logged_once(sim_hover_tlog: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """evaluate's errors were bare "mavahrs evaluate: error: …" lines beside the others' "HH:MM:SS.mmm LEVEL …";
    `--filter all` printed the magnetic-field line once per filter (a pipeline each)."""
    import re

    assert main(["evaluate", str(tmp_path / "missing.tlog")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all(re.match(r"\d\d:\d\d:\d\d\.\d{3} (INFO|WARNING|ERROR) ", ln) for ln in err), err
    assert main(["replay", str(sim_hover_tlog), "--no-progress", "-f", "all", "--engine", "pipeline"]) == 0
    err = capsys.readouterr().err
    assert err.count("magnetic field from") == 1, err


def test_a_folder_with_one_flights_tlog_and_bin_names_both_apart(shared_data: Path, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """`evaluate ../shared/data/sitl/` listed `arducopter_onboard` twice (its .tlog and its .BIN share the stem)
    and its --json kept one of them under that key; a folder's recordings whose stems collide are named by their file names, the others by their stems."""
    folder = tmp_path / "sitl"
    folder.mkdir()
    for name in ("arducopter_onboard.tlog", "arducopter_onboard.BIN", "arducopter_gentle.tlog"):
        (folder / name).symlink_to(shared_data / "sitl" / name)
    assert main(["evaluate", str(folder), "--skip", "10", "--json"]) == 0
    names = sorted(json.loads(capsys.readouterr().out)["per_recording"])  # was one key: the .BIN's lost
    assert names == ["arducopter_gentle", "arducopter_onboard.BIN", "arducopter_onboard.tlog"], names


def test_multirotor_flag_gives_a_raw_recording_the_rotor_drag_model(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """A raw multirotor IMU as a CSV (firmware_sim: raw preset, x axis up, started in flight, no GNSS, no
    magnetometer): ``--multirotor`` runs ``best`` as ``set_multirotor()`` does through the API, and that
    holds the tilt against the simulator's truth; without the flag, the plain API's ``best``."""
    sim_mod = pytest.importorskip("firmware_sim.simulation")
    from firmware_sim.imu_model import ImuErrorSettings
    from mavahrs.evaluation.metrics import attitude_errors_rad, rms_deg
    from mavahrs.filters import create
    from mavahrs.filters.base import make_inputs
    from mavahrs.geometry.quaternion import multiply

    rate_hz, seconds = 200, 60.0
    sim = sim_mod.Simulation(sim_mod.SimSettings(
        scenario="aggressive", seed=2, start_in_motion=True, imu_mount_deg=(0.0, 90.0, 0.0),
        imu=ImuErrorSettings.raw(), gnss=False, mag_count=0, imu_count=1, loop_rate_hz=rate_hz,
    ))  # fmt: skip
    blk = sim.next_block(int(rate_hz * seconds))
    mount = np.array([np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0])  # x axis up: the IMU → body rotation
    q_ref = multiply(blk.truth.q_body_to_ned, np.broadcast_to(mount, blk.truth.q_body_to_ned.shape).copy())
    t_s = (blk.t_us - blk.t_us[0]) / 1e6
    scored = t_s >= 10.0
    csv = tmp_path / "raw_multirotor.csv"
    header = "time_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,q_w,q_x,q_y,q_z,scored"
    cols = np.column_stack([t_s, blk.gyro_rad_s[0], blk.accel_m_s2[0], q_ref, scored.astype(float)])
    np.savetxt(csv, cols, delimiter=",", header=header, comments="", fmt="%.9g")

    def through_the_api(declared: bool) -> float:
        f = create("best")
        if declared:
            f.set_multirotor()
        dt = np.diff(t_s, prepend=t_s[0] - 1.0 / rate_hz)
        out = f.run(make_inputs(blk.gyro_rad_s[0], blk.accel_m_s2[0], None, dt_s=dt))
        return rms_deg(attitude_errors_rad(out[:, :4], q_ref)[2], scored)

    got = {}
    for flag in ([], ["--multirotor"]):
        assert main(["evaluate", str(csv), "-f", "best", "--json", *flag]) == 0
        got[bool(flag)] = json.loads(capsys.readouterr().out)["filters"]["best"]["inclination_rms_deg"]
    assert got[True] < 2.0  # declared: the drag model holds the tilt (≈ 1° on firmware_sim's raw flights)
    for declared, incl in got.items():
        assert incl == pytest.approx(through_the_api(declared), abs=0.02)


def test_evaluate_feeds_the_motor_current_as_replay_does(shared_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """ArduCopter SITL's flight with motor-current interference: the magnetometer model needs the battery
    current the chain puts in every row; evaluate rebuilt its rows without it and measured best's heading
    1.14° where replay measured 0.30°.  Now the two agree."""
    log = shared_data / "sitl" / "arducopter_magnetic.tlog"
    if not log.exists():
        pytest.skip(f"{log} absent (../shared data)")
    assert main(["evaluate", str(log), "-f", "best", "--json", "--skip", "10"]) == 0
    ev = json.loads(capsys.readouterr().out)["filters"]["best"]
    rp = _replay_truth_row(capsys, log, "-f", "best", "--skip", "10")
    assert ev["heading_rms_deg"] == pytest.approx(rp[1], abs=0.05)
    assert ev["inclination_rms_deg"] == pytest.approx(rp[2], abs=0.03)


def test_skip_leaves_out_the_start_of_a_documented_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--skip S`` on a documented-columns CSV scores as a ``scored`` column that is 0 for the first S seconds
    (it was ignored for these CSVs: the figure included the filter's convergence whatever S was)."""
    sim_mod = pytest.importorskip("firmware_sim.simulation")
    rate_hz, seconds, skip_s = 100, 30.0, 10.0
    sim = sim_mod.Simulation(sim_mod.SimSettings(scenario="aggressive", seed=7, gnss=False, mag_count=0,
                                                 imu_count=1, loop_rate_hz=rate_hz, start_in_motion=True))
    blk = sim.next_block(int(rate_hz * seconds))
    t_s = (blk.t_us - blk.t_us[0]) / 1e6
    header = "time_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,q_w,q_x,q_y,q_z"
    cols = np.column_stack([t_s, blk.gyro_rad_s[0], blk.accel_m_s2[0], blk.truth.q_body_to_ned])
    plain, marked = tmp_path / "rig.csv", tmp_path / "rig_scored.csv"
    np.savetxt(plain, cols, delimiter=",", header=header, comments="", fmt="%.9g")
    np.savetxt(marked, np.column_stack([cols, (t_s >= skip_s).astype(float)]), delimiter=",",
               header=header + ",scored", comments="", fmt="%.9g")

    def incl(path: Path, *extra: str) -> float:
        assert main(["evaluate", str(path), "-f", "mahony", "--json", *extra]) == 0
        return float(json.loads(capsys.readouterr().out)["filters"]["mahony"]["inclination_rms_deg"])

    skipped = incl(plain, "--skip", str(skip_s))
    assert skipped == pytest.approx(incl(marked), abs=1e-9)
    assert skipped != pytest.approx(incl(plain), abs=1e-6)  # the start's convergence is no longer scored


def test_a_ulog_without_truth_says_once_what_replay_compares_with(shared_data: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """PX4's bench ULog has no ``vehicle_attitude_groundtruth``: evaluate scores nothing (exit 1) and its note
    names the reference ``mavahrs replay`` uses (EKF2) once; it said "`mavahrs replay` compares with it" and
    then "(`mavahrs replay` compares with the log's EKF2 instead)" in the same note."""
    ulg = shared_data / "px4_ulog" / "sample.ulg"
    if not ulg.exists():
        pytest.skip(f"{ulg} absent (../shared data)")
    assert main(["evaluate", str(ulg), "--json"]) == 1
    notes = json.loads(capsys.readouterr().out)["per_recording"]["sample"]["notes"]
    truth = [n for n in notes if "no simulator truth" in n]
    assert len(truth) == 1 and truth[0].count("mavahrs replay") == 1 and "EKF2" in truth[0], truth


def test_a_csv_with_a_header_and_no_rows_is_one_error_line(tmp_path: Path) -> None:
    """A CSV with only its header: numpy's "UserWarning: genfromtxt: Empty input file" and the source line
    that raised it came before the error line.  Now only ``ERROR evaluate: …: no data rows`` (exit 1)."""
    import os
    import subprocess
    import sys

    csv = tmp_path / "rig.csv"
    csv.write_text("time_s,gx,gy,gz,ax,ay,az\n")
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[2]) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, "-m", "mavahrs", "evaluate", str(csv)], capture_output=True, text=True,
                          env=env, timeout=300)  # fmt: skip
    assert proc.returncode == 1
    lines = [ln for ln in proc.stderr.splitlines() if " INFO " not in ln]
    assert lines and lines[-1].endswith(f"ERROR evaluate: {csv}: no data rows"), proc.stderr
    assert "UserWarning" not in proc.stderr and "genfromtxt" not in proc.stderr, proc.stderr


def test_a_folders_plot_and_study_name_the_one_recording_they_use(shared_data: Path, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str],
                                                                  caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    """Given a folder, ``--plot`` draws one recording and ``--study compare`` studies one: they took the folder's
    first silently (RepoIMU's first, TStick_Test01_Static, has no reference to draw).  Now the first with a
    reference, named on stderr."""
    pytest.importorskip("matplotlib")
    folder = shared_data / "repoimu_tstick"
    if not (folder / "TStick_Test01_Static.csv").exists() or not (folder / "TStick_Test02_Trial1.csv").exists():
        pytest.skip("RepoIMU data absent")
    n_ref = len(list(folder.glob("TStick_Test*_Trial*.csv")))
    png = tmp_path / "first.png"
    with caplog.at_level("INFO", logger="mavahrs.cli"):
        assert main(["evaluate", str(folder), "-f", "mahony", "--plot", str(png)]) == 0
    assert png.stat().st_size > 10_000
    said = caplog.text + capsys.readouterr().err
    assert f"--plot draws one recording: TStick_Test02_Trial1, the first of {n_ref} with a reference" in said
    caplog.clear()
    with caplog.at_level("INFO", logger="mavahrs.cli"):
        assert main(["evaluate", str(folder), "--study", "compare"]) == 0
    out, err = capsys.readouterr()
    assert "on TStick_Test02_Trial1" in out
    assert f"--study compare runs on one recording: TStick_Test02_Trial1, the first of {n_ref}" in caplog.text + err


def test_a_folder_of_flight_logs_prints_no_magnetic_field_line_per_log(sim_hover_tlog: Path, tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``evaluate FOLDER``: one "magnetic field from WMM-2025 at …" INFO line per flight log, none naming its log
    (six on the shared SITL folder), before the table; now only with -v (one log still says it)."""
    import shutil

    folder = tmp_path / "logs"
    folder.mkdir()
    for name in ("one.tlog", "two.tlog"):
        shutil.copy(sim_hover_tlog, folder / name)
    said = "magnetic field from"
    assert main(["evaluate", str(folder), "-f", "mahony"]) == 0
    assert said not in capsys.readouterr().err
    assert main(["evaluate", str(folder / "one.tlog"), "-f", "mahony"]) == 0
    assert capsys.readouterr().err.count(said) == 1
    assert main(["-v", "evaluate", str(folder), "-f", "mahony"]) == 0
    assert capsys.readouterr().err.count(said) == 2


def test_truth_too_sparse_to_slerp_says_so(sim_tlog_writer, tmp_path: Path,  # type: ignore[no-untyped-def]
                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """A tlog whose simulator truth arrives at 1 Hz (what `mavahrs run --log` records from firmware_sim, which
    asks for no SIMSTATE): it said both "reference: SIMSTATE truth … every sample scored" and "no reference
    attitude in this recording" until user8; now one note says the truth is too sparse, and replay compares."""
    log = sim_tlog_writer(tmp_path / "sparse.tlog", "--scenario", "hover", "--duration", "8",
                         "--stream", "SIMSTATE=1", "--stream", "SIM_STATE=1")  # fmt: skip
    capsys.readouterr()
    assert main(["evaluate", str(log), "-f", "mahony"]) == 1
    cap = capsys.readouterr()
    text = cap.out + cap.err
    assert "truth, but too sparse to slerp onto the IMU samples: 8 sample(s), 1 s apart" in text, text
    assert "no reference attitude in this recording" not in text and "every sample scored" not in text
    assert "nothing was scored (no usable reference attitude in the input" in cap.err
    assert main(["replay", str(log), "-f", "mahony"]) == 0  # at the truth's own times
    assert "SIM_STATE truth" in capsys.readouterr().out


def test_a_mixed_folder_says_what_it_skipped_and_that_its_mean_mixes_kinds(
    broad_dir: Path, sim_hover_tlog: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A folder with a BROAD trial, a flight log and a note: the note was skipped and the trial and the flight
    averaged into one "mean over 2 recordings" without a word (user8). Both are said now, as log lines; a
    folder of one kind says neither."""
    import re
    import shutil

    folder = tmp_path / "mixed"
    folder.mkdir()
    (folder / "trial.mat").symlink_to(broad_dir / "02_undisturbed_slow_rotation_B.mat")
    shutil.copy(sim_hover_tlog, folder / "hover.tlog")
    (folder / "notes.txt").write_text("flown on Tuesday\n")
    assert main(["evaluate", str(folder), "-f", "mahony"]) == 0
    err = capsys.readouterr().err.splitlines()
    said = [ln for ln in err if "skipped" in ln or "kinds" in ln]
    assert all(re.match(r"\d\d:\d\d:\d\d\.\d{3} (INFO|WARNING) ", ln) for ln in said), said
    assert any("skipped 1 file that is not a recording or log" in ln and ln.endswith(": notes.txt") for ln in said), err
    assert any("different kinds of recording (" in ln and "1 BROAD trial" in ln and "1 flight log" in ln
               for ln in said), err  # fmt: skip
    (folder / "notes.txt").unlink()
    (folder / "trial.mat").unlink()
    assert main(["evaluate", str(folder), "-f", "mahony"]) == 0
    err = capsys.readouterr().err
    assert "skipped" not in err and "kinds" not in err, err
