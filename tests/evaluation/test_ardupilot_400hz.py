"""ArduPilot's 400 Hz stream as it really is (issue 16, item 5), on the SITL flight in ../shared.

``arducopter_400hz_gps.tlog``: SCHED_LOOP_RATE 800, RAW_IMU and SCALED_IMU2 asked at 400 Hz. The
autopilot sends about one message in four twice (same stamp, same values), and its noiseless simulated
IMUs repeat identical values for up to 1.6 s on the ground. Both the bulk replay path and the daemon's
pipeline must drop exactly the re-sends, keep every genuine repeated sample, and never fail over.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.tlogdata import prepare_inputs, read_tlog_data, run_pipelines
from mavahrs.filters.layout import IN_GYRO, IN_MAG
from mavahrs.service.pipeline import PipelineSettings

# from ../shared/data/README.md, section 4
RAW_IMU_RESENT, SCALED_IMU2_RESENT = 23_346, 23_345
RAW_IMU_UNIQUE = 76_295


@pytest.fixture(scope="module")
def log_data(shared_data: Path):
    path = shared_data / "sitl" / "arducopter_400hz_gps.tlog"
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data/sitl beside the checkout)")
    return read_tlog_data(path)


def test_bulk_path_drops_the_resends_keeps_repeats_and_never_fails_over(log_data) -> None:
    # prepare_inputs raises FastPathUnsupported on a fail-over: before the fix the noiseless ground phase
    # made IMU 0 "frozen" against IMU 1's one-unit flickers, every 2 s
    prep = prepare_inputs(log_data, PipelineSettings(out_rate_hz=0.0))
    assert prep.instance == 0 and prep.message == "RAW_IMU"
    assert prep.counts["exact_duplicates"] == RAW_IMU_RESENT + SCALED_IMU2_RESENT
    assert prep.counts["same_stamp_changed"] == 0
    assert prep.n == RAW_IMU_UNIQUE and prep.counts["dropped_timeline"] == 0
    # every fed sample has its own stamp, 2.5 or 3.125 ms apart (README: 60,425 and 15,869) …
    steps, counts = np.unique(np.diff(prep.t_us), return_counts=True)
    assert dict(zip(steps.tolist(), counts.tolist(), strict=True)) == {2500: 60_425, 3125: 15_869}
    # … and the genuine repeats (new stamp, same nine values: a noiseless sensor in a steady state) are kept
    nine = prep.rows[:, IN_GYRO : IN_MAG + 3]
    assert np.count_nonzero(np.all(nine[1:] == nine[:-1], axis=1)) == 29_627


def test_pipeline_agrees_and_does_not_switch_imu(log_data) -> None:
    """The daemon's own path over the ground phase (where it flapped) and take-off: the same rows, no switch."""
    ps = PipelineSettings(filter_name="mahony", out_rate_hz=0.0)
    end_s = 70.0
    fast = prepare_inputs(log_data, ps, end_s=end_s)
    prep, _, _, _ = run_pipelines(log_data, ps, [("mahony", None)], start_s=None, end_s=end_s, decimal_year=None)
    assert prep.counts["exact_duplicates"] == fast.counts["exact_duplicates"] > 10_000
    assert not any("switched" in n or "frozen" in n for n in prep.notes), prep.notes
    np.testing.assert_array_equal(prep.t_us, fast.t_us)
    np.testing.assert_array_equal(prep.rows[:, IN_GYRO : IN_MAG + 3], fast.rows[:, IN_GYRO : IN_MAG + 3])


def test_firmware_sim_800_hz_loop_replays_alike_on_both_engines(tmp_path: Path) -> None:
    """The same stream from firmware_sim (``--loop-rate 800 --noiseless``: RAW_IMU, SCALED_IMU2 and SIMSTATE asked at
    their fastest, 2 ms, re-sent by the 400 Hz telemetry task): both replay engines drop the same re-sends and
    give the same attitude, and a SIMSTATE sent twice is one truth sample."""
    fs_main = pytest.importorskip("firmware_sim.__main__")
    from firmware_sim.endpoint import Endpoint
    from firmware_sim.simulation import Simulation
    from firmware_sim.streamer import write_tlog
    from mavahrs.replay import ReplaySettings, compare, replay

    path = tmp_path / "sitl_like.tlog"
    ns = fs_main.build_parser().parse_args(["--tlog", str(path), "--fast", "-q", "--scenario", "hover", "--duration",
                                            "8", "--seed", "2", "--loop-rate", "800", "--noiseless"])  # fmt: skip
    sim, ep = fs_main.settings_from_args(ns)
    write_tlog(Endpoint(Simulation(sim), ep), str(path), ns.duration)
    s = dict(filters=("mahony",))
    fast = replay(path, ReplaySettings(engine="fast", **s))
    ref = replay(path, ReplaySettings(engine="pipeline", **s))
    assert fast.engine == "fast" and ref.engine == "pipeline"
    n = fast.inputs.counts["exact_duplicates"]
    assert n == ref.inputs.counts["exact_duplicates"] == pytest.approx(2 * 8 * 100, abs=4)  # 2 IMUs, 1 in 5 of 500/s
    assert fast.inputs.n == pytest.approx(8 * 400, abs=2)
    np.testing.assert_array_equal(fast.inputs.rows, ref.inputs.rows)
    np.testing.assert_array_equal(fast.tracks["mahony"].out, ref.tracks["mahony"].out)
    assert any(f"{n} exact duplicate IMU messages" in note for note in fast.notes)
    # the header says the count is over both instances, and what share of the filtered one's messages it is
    assert fast.inputs.counts["exact_duplicates_fed"] == pytest.approx(8 * 100, abs=2)
    assert any("every IMU instance" in note and "(20 %)" in note for note in fast.notes), fast.notes
    t_truth, _ = fast.references["SIMSTATE truth"]
    assert np.all(np.diff(t_truth) > 0) and t_truth.size == pytest.approx(8 * 400, abs=2)
    row = next(r for r in compare(fast) if r.reference == "SIMSTATE truth")
    assert row.inclination_rms_deg < 2.0
