"""Steps in the autopilot's attitude on flights where the learnt threshold once hid them (issue 24), through
``mavahrs audit``'s path as ``scripts/bench_monitor.py`` runs it: a fault from boot time 100 s in the
autopilot's ATTITUDE, the first in-flight WARNING after it.

* firmware_sim flips 1: the flips' divergence, at 300–600°/s mostly the two estimates' timing (the
  ``sync_s`` term), was learnt as the flight's normal and raised the tilt threshold to 1.87°: a 2° tilt
  step warned after 4.0 s.  Learnt only below ``learn_max_rate_dps``: 1.1 s.
* ArduCopter SITL magnetic: EKF3's own heading 2° off (inside the model's 3.6°) was learnt and the heading
  threshold rose to 5.0°: a −6° heading step (which the autopilot's own error partly cancels) warned after
  11.1 s.  The learnt threshold at most ``learn_max_factor`` × the model's: 3.8 s (issue 24 asks ≤ 3 s; not
  met here, see docs/monitor.md).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mavahrs.evaluation.faults import AttitudeFault, FaultShape, inject_faults

ONSET_S = 100.0


def _first_after(path: Path, fault: AttitudeFault, tmp: Path) -> tuple[float, list[float]]:
    """Latency of the first in-flight WARNING after the onset on the faulted copy, s (inf: none), and the
    WARNING times on the flight as recorded."""
    from mavahrs.fleet.audit import summarise_log

    clean = summarise_log(path)
    assert clean.ok, clean.error
    copy = tmp / f"{path.stem}_fault.tlog"
    inject_faults(path, copy, [fault])
    row = summarise_log(copy)
    copy.unlink()
    assert row.ok, row.error
    times = [float(x) for x in row.alarm_times_s.split(";") if x]
    after = [t - ONSET_S for t in times if t >= ONSET_S]
    return (after[0] if after else float("inf")), [float(x) for x in clean.alarm_times_s.split(";") if x]


def test_a_tilt_step_after_flips_is_warned_within_2_s(tmp_path: Path) -> None:
    pytest.importorskip("firmware_sim", reason="firmware_sim (the simulator with known truth) is not importable")
    path = tmp_path / "flips_1.tlog"
    subprocess.run([sys.executable, "-m", "firmware_sim", "--fast", "--tlog", str(path), "--scenario", "flips",
                    "--duration", "106", "--seed", "1", "-q"], check=True, cwd=Path(__file__).parents[2])  # fmt: skip
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0), tmp_path)
    assert not [t for t in clean if t >= ONSET_S - 5.0], clean  # the latency is the fault's, not a warning already on
    assert 0.3 < latency <= 2.0, latency


def test_a_heading_step_on_the_magnetic_flight_is_not_hidden_by_the_learnt_threshold(
    shared_data: Path, tmp_path: Path
) -> None:
    path = shared_data / "sitl" / "arducopter_magnetic.tlog"
    latency, clean = _first_after(path, AttitudeFault(FaultShape("step", ONSET_S), heading_deg=-6.0), tmp_path)
    assert not [t for t in clean if ONSET_S - 5.0 <= t <= ONSET_S + 10.0], clean
    assert 0.3 < latency <= 4.0, latency  # 11.1 s with the learnt threshold uncapped
