"""Steps in the autopilot's attitude on flights where the learnt threshold, or the autopilot's own error, once
hid them (issue 24), through ``mavahrs audit``'s path as ``scripts/bench_monitor.py`` runs it: a fault from
boot time 100 s in the autopilot's ATTITUDE, the first in-flight WARNING after it.

* firmware_sim flips 1: the flips' divergence, at 300–600°/s mostly the two estimates' timing (the
  ``sync_s`` term), was learnt as the flight's normal and raised the tilt threshold to 1.87°: a 2° tilt
  step warned after 4.0 s.  Learnt only below ``learn_max_rate_dps``: 1.1 s.
* ArduCopter SITL magnetic: EKF3's own heading 2° off (inside the model's 3.6°) was learnt and the heading
  threshold rose to 5.0°: a −6° heading step (which the autopilot's own error partly cancels) warned after
  11.1 s.  The learnt threshold at most ``learn_max_factor`` × the model's: 3.8 s; with the change test
  (``MonitorSettings.change_test``: the divergence against its own baseline) 0.8 s.
* firmware_sim aggressive 1: the simulated autopilot's own tilt error, ≈ 0.9°, lies against a 2° tilt step
  (the faulted autopilot only 1.1–1.5° from the truth): 3.9 s with the absolute test alone, 0.6 s with the
  change test; the flight as recorded has no WARNING while the autopilot is within 1° / 3° of the truth.
* firmware_sim magnetic 2: the autopilot's own heading 2–3° off the other way of a −6° step: 6.0 s with
  the absolute test alone, 2.4 s with the change test.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.faults import AttitudeFault, FaultShape, inject_faults

ONSET_S = 100.0


def _first_after(path: Path, fault: AttitudeFault, tmp: Path, onset_s: float = ONSET_S,
                 monitor: object = None) -> tuple[float, list[float]]:  # fmt: skip
    """Latency of the first in-flight WARNING after the onset on the faulted copy, s (inf: none), and the
    WARNING times on the flight as recorded (``monitor``: the MonitorSettings, default the defaults)."""
    from mavahrs.fleet.audit import AuditSettings, summarise_log
    from mavahrs.replay import ReplaySettings
    from mavahrs.service.pipeline import PipelineSettings

    audit = None if monitor is None else AuditSettings(replay=ReplaySettings(pipeline=PipelineSettings(monitor=monitor)))
    clean = summarise_log(path, audit)
    assert clean.ok, clean.error
    copy = tmp / f"{path.stem}_fault.tlog"
    inject_faults(path, copy, [fault])
    row = summarise_log(copy, audit)
    copy.unlink()
    assert row.ok, row.error
    times = [float(x) for x in row.alarm_times_s.split(";") if x]
    after = [t - onset_s for t in times if t >= onset_s]
    return (after[0] if after else float("inf")), [float(x) for x in clean.alarm_times_s.split(";") if x]


def _sim_flight(tmp: Path, scenario: str, seed: int, duration_s: float) -> Path:
    pytest.importorskip("firmware_sim", reason="firmware_sim (the simulator with known truth) is not importable")
    path = tmp / f"{scenario}_{seed}.tlog"
    subprocess.run([sys.executable, "-m", "firmware_sim", "--fast", "--tlog", str(path), "--scenario", scenario,
                    "--duration", str(duration_s), "--seed", str(seed), "-q"],
                   check=True, cwd=Path(__file__).parents[2])  # fmt: skip
    return path


def test_a_tilt_step_after_flips_is_warned_within_2_s(tmp_path: Path) -> None:
    path = _sim_flight(tmp_path, "flips", 1, 106.0)
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0), tmp_path)
    assert not [t for t in clean if t >= ONSET_S - 5.0], clean  # the latency is the fault's, not a warning already on
    assert 0.1 < latency <= 2.0, latency  # 0.1 s: the least a CUSUM at three times its threshold needs


def test_a_heading_step_on_the_magnetic_flight_is_not_hidden_by_the_learnt_threshold(
    shared_data: Path, tmp_path: Path
) -> None:
    path = shared_data / "sitl" / "arducopter_magnetic.tlog"
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), heading_deg=-6.0), tmp_path)
    assert not [t for t in clean if ONSET_S - 5.0 <= t <= ONSET_S + 10.0], clean
    assert 0.1 < latency <= 3.0, latency  # 11.1 s with the learnt threshold uncapped, 3.8 s without the change test


def _false_warnings(path: Path, times_s: list[float]) -> list[tuple[float, float, float]]:
    """Of the WARNING times on a firmware_sim flight as recorded, those that came while the simulated
    autopilot was within 1° of tilt and 3° of heading of the truth (SIMSTATE) over the 2 s before:
    (time s, its largest tilt error °, heading error °) — the benchmark's "false"."""
    from mavahrs.replay import ReplaySettings, replay
    from mavahrs.service.monitor import align_attitudes, divergence_series

    res = replay(path, ReplaySettings())
    truth = next(k for k in res.references if k.endswith("truth"))
    t_ap, q_ap = res.references["autopilot ATTITUDE"]
    t_tr, q_tr = res.references[truth]
    q_t = align_attitudes(t_tr / 1000.0, q_tr, t_ap / 1000.0, tolerance_ms=30.0)
    tilt, hdg = divergence_series(t_ap / 1000.0, q_ap, t_ap / 1000.0, q_t)
    t_s = t_ap / 1e6
    out = []
    for t in times_s:
        m = (t_s > t - 2.0) & (t_s <= t)
        e_t, e_h = float(np.nanmax(tilt[m])), float(np.nanmax(np.abs(hdg[m])))
        if e_t < 1.0 and e_h < 3.0:
            out.append((t, e_t, e_h))
    return out


def test_a_tilt_step_against_the_autopilots_own_error_is_warned_within_2_s(tmp_path: Path) -> None:
    path = _sim_flight(tmp_path, "aggressive", 1, 106.0)
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0), tmp_path)
    assert not [t for t in clean if t >= ONSET_S - 5.0], clean
    assert 0.1 < latency <= 2.0, latency  # 3.9 s with the absolute test alone
    assert _false_warnings(path, clean) == []  # and no crying wolf on the flight as recorded


def test_a_heading_step_against_the_autopilots_own_heading_error_is_warned_within_3_s(tmp_path: Path) -> None:
    path = _sim_flight(tmp_path, "magnetic", 2, 106.0)
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), heading_deg=-6.0), tmp_path)
    # (the flight as recorded has a correct WARNING of its own at 101.6 s: the simulated autopilot's heading
    # 3.4° off, the other way of the step, which on the faulted copy it partly cancels)
    assert 0.1 < latency <= 3.0, latency  # 6.0 s with the absolute test alone
    assert _false_warnings(path, clean) == []


def test_a_tilt_step_in_a_yaw_spin_is_warned_within_2_s(tmp_path: Path) -> None:
    # firmware_sim aggressive 3 spins about the vertical at 350–440°/s from 99.2 s to 101.3 s, then turns at
    # 120–130°/s: the timing term ω·sync_s of the whole rate made the tilt thresholds 3.8–4.6° in the spin and
    # 1.9° after it (3.6 s); a yaw turn over a timing error turns the divergence's heading, not its tilt, so the
    # tilt's term takes the earth-frame turn's horizontal part only
    path = _sim_flight(tmp_path, "aggressive", 3, 106.0)
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0), tmp_path)
    assert not [t for t in clean if t >= ONSET_S - 5.0], clean
    assert 0.1 < latency <= 2.0, latency  # 3.6 s with the whole turn rate in the tilt's timing term
    assert _false_warnings(path, clean) == []


def test_a_step_while_a_warning_is_already_on_is_warned_within_2_s(tmp_path: Path) -> None:
    # firmware_sim aggressive 21: a correct WARNING at 95.4 s (the simulated autopilot 1.6° off in tilt) is
    # still on when the fault comes at 100 s; without a test of a new step within the warning no WARNING came
    # for the fault at all
    path = _sim_flight(tmp_path, "aggressive", 21, 106.0)
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0), tmp_path)
    # the warning already on (since change_step_outside raised at 89.4 s, and said again at 98.4 s with new
    # evidence: not over before the onset)
    assert [t for t in clean if ONSET_S - 15.0 <= t < ONSET_S], clean
    assert not [t for t in clean if t >= ONSET_S], clean  # … and no other on the flight as recorded until 106 s
    assert 0.1 < latency <= 2.0, latency  # none before
    assert _false_warnings(path, clean) == []


def test_a_step_half_a_second_after_a_correct_warning_is_warned_within_2_s(tmp_path: Path) -> None:
    # firmware_sim aggressive 2: a correct WARNING at 100.9 s (the simulated autopilot 1.9° off in tilt); the
    # fault 0.4 s after it.  The in-warning test needs 2 s of its own baseline, fed 2 s late, so without a step
    # test over the warning's first seconds (change_step_s) no WARNING came for the fault at all (aggressive 41,
    # 99.6 s; that warning, the simulated autopilot 1.6° off, is no longer raised since our tilt σ holds the
    # scale-factor error of its manoeuvres: EskfSettings.gyro_scale_tilt_sigma)
    path = _sim_flight(tmp_path, "aggressive", 2, 107.0)
    from mavahrs.fleet.audit import summarise_log

    clean = [float(x) for x in summarise_log(path).alarm_times_s.split(";") if x]
    warned = [t for t in clean if 95.0 <= t < 102.0]
    assert warned, clean  # the correct warning
    onset = warned[-1] + 0.4
    assert not [t for t in clean if t >= onset], clean  # … and no other on the flight as recorded until 107 s
    assert _false_warnings(path, clean) == []
    fault = AttitudeFault(FaultShape("step", onset), tilt_deg=2.0)
    latency, _ = _first_after(path, fault, tmp_path, onset)
    assert 0.1 < latency <= 2.0, latency  # none before
    latency, _ = _first_after(path, AttitudeFault(FaultShape("step", onset), heading_deg=6.0), tmp_path, onset)
    assert 0.1 < latency <= 3.0, latency


def test_a_ramp_half_a_second_after_a_correct_warning_is_warned_before_2_5_deg(tmp_path: Path) -> None:
    # firmware_sim aggressive 11: a correct WARNING at 100.8 s (the simulated autopilot 1.4° off in tilt); a
    # 0.2°/s tilt ramp from 0.5 s later is a disagreement growing under the warning already on — within any 2 s
    # it moves too little for the step tests, so before the drift test (change_drift_s) it was never warned
    # (aggressive 41, whose 99.6 s warning is no longer raised: none; aggressive 43: 16.2 s, 3.2°).  That warning
    # (grey by issue 24's bar: the autopilot 1.1–1.4° off) comes at 106.7 s with the change test's baseline
    # through turns (change_baseline_turn, docs/monitor.md round twenty-three); the mechanism tested here is the
    # drift test's, so the case is built with the earth-frame baseline
    path = _sim_flight(tmp_path, "aggressive", 11, 117.0)
    from mavahrs.fleet.audit import AuditSettings, summarise_log
    from mavahrs.replay import ReplaySettings
    from mavahrs.service.monitor import MonitorSettings
    from mavahrs.service.pipeline import PipelineSettings

    mon = MonitorSettings(change_baseline_turn=False)
    audit = AuditSettings(replay=ReplaySettings(pipeline=PipelineSettings(monitor=mon)))
    clean = [float(x) for x in summarise_log(path, audit).alarm_times_s.split(";") if x]
    warned = [t for t in clean if 95.0 <= t < 102.0]
    assert warned, clean  # the correct warning, on when the ramp starts
    onset = warned[-1] + 0.5
    assert not [t for t in clean if t >= onset], clean  # … and no other on the flight as recorded until 117 s
    copy = tmp_path / "ramp.tlog"
    inject_faults(path, copy, [AttitudeFault(FaultShape("ramp", onset, ramp_s=50.0), tilt_deg=10.0)])
    row = summarise_log(copy, audit)
    copy.unlink()
    after = [float(x) - onset for x in row.alarm_times_s.split(";") if x and float(x) >= onset]
    assert after, row.alarm_times_s  # none before
    assert 0.2 * after[0] < 2.5, after  # the ramp's size, deg, when warned


def test_a_step_across_the_autopilots_drifting_error_is_warned_within_2_s(tmp_path: Path) -> None:
    # firmware_sim aggressive 63: the simulated autopilot's tilt error stands at +1.0° north at 100 s, having
    # moved there over the 10 s before, so the change test's baseline (10 s) lies between: the 2° step about
    # north (the divergence +1.0° → −1.0°) is a change of only 1.1–1.3° against it (threshold 1.43°) and was
    # warned after 5.1 s; the step test over the last change_step_s, outside a warning too
    # (change_step_outside), sees the 2.0° step
    path = _sim_flight(tmp_path, "aggressive", 63, 106.0)
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0), tmp_path)
    assert not [t for t in clean if t >= ONSET_S - 5.0], clean
    assert 0.1 < latency <= 2.0, latency  # 5.1 s with the change test's baseline alone
    assert _false_warnings(path, clean) == []


def test_a_heading_step_under_a_correct_warning_in_a_yaw_spin_is_warned_within_3_s(tmp_path: Path) -> None:
    # firmware_sim aggressive 81: a correct in-flight WARNING is still on at 100 s (the simulated autopilot's
    # tilt error keeps coming back to about 1°, so it never clears), and the +6° heading step falls into two fast
    # yaw spins (≈ 300 °/s) in which our heading σ lifts the level threshold past the divergence the step makes
    # (the autopilot's own heading error stood the other way). A new step under a warning had to cross that
    # level threshold as well as the in-warning test's: warned after 5.7 s (docs/monitor.md, round nine). It is
    # judged now as one outside a warning: beyond the change test's threshold suffices (round eleven).  That
    # warning (the autopilot 1–1.5° off: grey by issue 24's bar) is raised with the level CUSUM's reference at 0.5;
    # at the default 0.75 it is not (docs/monitor.md round twenty-two), so the case is built with 0.5, and the
    # step is also judged with the defaults, no warning standing
    from mavahrs.service.monitor import MonitorSettings

    path = _sim_flight(tmp_path, "aggressive", 81, 106.0)
    fault = AttitudeFault(FaultShape("step", ONSET_S), heading_deg=6.0)
    latency, clean = _first_after(path, fault, tmp_path, monitor=MonitorSettings(cusum_reference=0.5))
    assert [t for t in clean if ONSET_S - 20.0 <= t < ONSET_S], clean  # the warning already on at the onset
    assert not [t for t in clean if t >= ONSET_S], clean  # … and no other on the flight as recorded until 106 s
    assert 0.1 < latency <= 3.0, latency  # 5.7 s when the level threshold was needed too
    assert _false_warnings(path, clean) == []
    latency, clean = _first_after(path, fault, tmp_path)
    assert not [t for t in clean if t >= ONSET_S], clean
    assert 0.0 < latency <= 3.0, latency


def test_a_tilt_step_under_a_warning_in_a_yaw_spin_is_warned_within_2_s(tmp_path: Path) -> None:
    # firmware_sim aggressive 33: a correct WARNING at 98.9 s (the simulated autopilot 1.5–1.7° off in tilt) is on
    # at the onset, and the vehicle yaws at ≈ 150°/s: the autopilot's own error, fixed in its body, circles in the
    # earth frame (1.3–1.7° about the truth), so over the step test's 2 s the divergence's spread about the two
    # segments' means was as large as the 2° step, which was not counted (change_step_spread_k) and warned only
    # after 14.5 s.  The split fitted with a body-fixed part beside the two levels (change_step_body_fixed)
    # leaves the step itself.  That warning (grey by issue 24's bar: the autopilot 1.66–1.75° off) comes at 100.78 s
    # with the change test's baseline through turns (change_baseline_turn, docs/monitor.md round twenty-three); the
    # mechanism tested here is the in-warning step test's, so the case is built with the earth-frame baseline
    from mavahrs.service.monitor import MonitorSettings

    path = _sim_flight(tmp_path, "aggressive", 33, 106.0)
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0), tmp_path,
                                  monitor=MonitorSettings(change_baseline_turn=False))
    assert [t for t in clean if ONSET_S - 5.0 <= t < ONSET_S], clean  # the warning already on at the onset
    assert not [t for t in clean if t >= ONSET_S], clean  # … and no other on the flight as recorded until 106 s
    assert 0.1 < latency <= 2.0, latency  # 14.5 s with the plain split
    assert _false_warnings(path, clean) == []


def test_a_tilt_step_after_a_standing_divergence_turned_is_warned_within_2_s(tmp_path: Path) -> None:
    # firmware_sim magnetic 32: at 91–94 s the vehicle turns 71° in 3 s; the autopilot's own tilt error (fixed in
    # its body, 1.2° at 87 s, 0.5° at 93.8 s) and ours (0.7°) standing, the divergence turned in the earth frame
    # and the change test read it as a change of 1.4° against its earth-frame baseline: a WARNING at 93.84 s with the
    # autopilot 0.48° off, which stood over the 2° step at 100 s (the in-warning tests take a change only as far as
    # the divergence is from the disagreement warned of): no WARNING for it.  The baseline with a part fixed in the
    # vehicle's heading axes (change_baseline_turn): no false WARNING, the step warned within 2 s
    path = _sim_flight(tmp_path, "magnetic", 32, 106.0)
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0), tmp_path)
    assert _false_warnings(path, clean) == []
    assert not [t for t in clean if ONSET_S - 10.0 <= t], clean  # no warning standing at the onset
    assert 0.0 < latency <= 2.0, latency  # inf with the earth-frame baseline
