"""``replay --plot``: the second-opinion monitor is judged once for the printed second opinion and its chart (it
was judged twice: 16.5 s each on the PX4 SIH .ulg), and a long judgement says when it starts."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest


def test_the_second_opinion_is_judged_once_per_replay(sitl_gentle_tlog: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    pytest.importorskip("matplotlib")
    log = sitl_gentle_tlog
    from mavahrs import replay as rp
    from mavahrs.fleet import audit

    calls: list[str] = []
    real = audit.replay_monitor

    def counting(result: Any, *args: Any, **kw: Any) -> Any:
        calls.append(result.path)
        return real(result, *args, **kw)

    monkeypatch.setattr(audit, "replay_monitor", counting)
    result = rp.replay(str(log), rp.ReplaySettings(filters=("best",)))
    text = rp.format_second_opinion(result)
    chart = rp.plot_second_opinion(result, tmp_path / "gentle.png")
    assert text.startswith("second opinion (best) vs autopilot ATTITUDE: 0 in-flight WARNING(s)")
    assert chart is not None and chart.name == "gentle_second_opinion.png" and chart.is_file()
    assert calls == [str(log)]


def test_a_long_judgement_says_it_has_started(sitl_gentle_tlog: Path, caplog: pytest.LogCaptureFixture,
                                              monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    log = sitl_gentle_tlog
    from mavahrs import replay as rp
    from mavahrs.replay import engine

    result = rp.replay(str(log), rp.ReplaySettings(filters=("best",), end_s=20.0))
    n = int(result.references["autopilot ATTITUDE"][0].shape[0])
    monkeypatch.setattr(engine, "_SAY_JUDGING_ABOVE", n - 1)  # this short flight counts as a long one
    with caplog.at_level(logging.INFO, logger="mavahrs.replay"):
        rp.format_second_opinion(result)
    assert f"second opinion: judging {n} attitudes of autopilot ATTITUDE against ours …" in caplog.text
