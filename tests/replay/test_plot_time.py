"""``replay --plot``: the attitude plot's time axis is the autopilot's boot clock, as its second-opinion chart, the
STATUSTEXT times replay and audit print and ``inject-fault --at`` are. Until user6 it counted from the first
sample: on the gentle ArduCopter SITL flight (first sample at boot 72.6 s) a WARNING at 82.9 s was drawn at 10.3 s."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest


def test_the_replay_plot_counts_the_autopilots_boot_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mavahrs import replay as rp
    from mavahrs.evaluation import plots

    log = tmp_path / "late.tlog"  # the simulator booted 50 s before the log starts
    subprocess.run([sys.executable, "-m", "firmware_sim", "--tlog", str(log), "--fast", "-q", "--scenario", "hover",
                    "--duration", "8", "--seed", "1", "--boot-offset-s", "50"], check=True, timeout=120)  # fmt: skip
    drawn: list[tuple[Any, dict[str, Any]]] = []

    def capture(path, t_s, est, **kw):  # type: ignore[no-untyped-def]
        drawn.append((t_s, kw))
        return Path(path)

    monkeypatch.setattr(plots, "plot_attitude", capture)
    result = rp.replay(str(log), rp.ReplaySettings(filters=("madgwick",)))
    rp.plot_replay(result, tmp_path / "late.png")
    ((t_s, kw),) = drawn
    assert kw["time_label"] == "autopilot boot time, s"
    assert t_s[0] == pytest.approx(result.inputs.t_us[0] * 1e-6) and 50.0 <= t_s[0] < 51.0
    assert t_s[-1] == pytest.approx(58.0, abs=0.1)
    for t_other, _q in kw["others"].values():  # the autopilot's own attitude on the same clock
        assert 50.0 <= t_other[0] < 51.0
