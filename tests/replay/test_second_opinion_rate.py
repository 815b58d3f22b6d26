"""``mavahrs replay``'s second opinion judges what the daemon publishes (its 50 Hz ATTITUDE_QUATERNION), as
``mavahrs run`` and ``mavahrs audit`` do, while the replay's own outputs keep every sample.  Until user7 the replay
judged every sample by default, so its warnings could come a few ms before the daemon's (4 ms on the PX4 SIH
.ulg; here a repeated WARNING 20 ms early)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def tilt_step_tlog(sitl_gentle_tlog: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The shared gentle SITL flight with a 2° roll error put into the autopilot's attitude at boot 100–115 s."""
    from mavahrs.evaluation.faults import AttitudeFault, FaultShape, inject_faults

    dst = tmp_path_factory.mktemp("rate") / "gentle_tilt2.tlog"
    report = inject_faults(sitl_gentle_tlog, dst, [AttitudeFault(FaultShape("step", start_s=100.0, duration_s=15.0),
                                                                 roll_deg=2.0)])  # fmt: skip
    assert report.first_s >= 100.0
    return dst


def _said(result: object) -> list[tuple[float, str]]:
    from mavahrs.replay.engine import _monitor_of

    got = _monitor_of(result)  # type: ignore[arg-type]
    assert got is not None
    return [(e.t_ms, e.text) for e in got[0].events]


def test_replay_judges_the_daemons_published_attitudes_by_default(tilt_step_tlog: Path) -> None:
    from mavahrs import replay as rp
    from mavahrs.replay.engine import judged_samples
    from mavahrs.service.pipeline import PipelineSettings

    default = rp.replay(str(tilt_step_tlog), rp.ReplaySettings())
    # the daemon's own per-message Pipeline with its default settings: what it sends is what its monitor judges
    daemon = rp.replay(str(tilt_step_tlog), rp.ReplaySettings(pipeline=PipelineSettings(), engine="pipeline"))
    assert default.tracks["best"].sent.all(), "the replay's outputs still hold every sample"
    t_judged = default.inputs.t_us[judged_samples(default, "best")]
    t_daemon = daemon.inputs.t_us[np.flatnonzero(daemon.tracks["best"].sent)]
    assert t_daemon.size > 1000 and np.array_equal(t_judged, t_daemon)
    said = _said(default)
    assert said == _said(daemon)
    first = [t for t, text in said if "AP off" in text]
    assert first and 100_000.0 <= first[0] <= 101_500.0, said  # the step is warned within 1.5 s

    # every sample stays available, and is a different judgement on this flight
    every = rp.replay(str(tilt_step_tlog), rp.ReplaySettings(monitor_rate_hz=0.0))
    assert judged_samples(every, "best").size == every.inputs.n
    assert _said(every) != said


def test_replay_command_judges_at_the_config_files_rate_whatever_out_rate_says(tmp_path: Path) -> None:
    from mavahrs.cli import build_parser
    from mavahrs.cli.replay import settings_from_args
    from mavahrs.service.pipeline import PipelineSettings

    def settings(*argv: str):  # type: ignore[no-untyped-def]
        return settings_from_args(build_parser().parse_args(["replay", "x.tlog", *argv]))

    plain = settings()
    assert plain.pipeline_settings().out_rate_hz == 0.0
    assert plain.judged_rate_hz() == PipelineSettings().out_rate_hz
    assert settings("--out-rate", "100").judged_rate_hz() == PipelineSettings().out_rate_hz
    cfg = tmp_path / "mavahrs.toml"
    cfg.write_text("[pipeline]\nout_rate_hz = 25.0\n")
    configured = settings("--config", str(cfg))
    assert configured.judged_rate_hz() == 25.0 and configured.pipeline_settings().out_rate_hz == 0.0
    with pytest.raises(ValueError, match="monitor_rate_hz"):
        from mavahrs.replay import ReplaySettings

        ReplaySettings(monitor_rate_hz=-1.0)
