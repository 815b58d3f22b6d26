"""The fast paths give exactly what the reference paths give (no timing here: see scripts/bench.py).

* replay's bulk engine (one scan, compiled batch filters, CSV block writer)
  against the daemon's per-message Pipeline, on the kind of log the benchmark
  replays: an idealised 400 Hz RAW_IMU stream with magnetometer from
  firmware_sim;
* ``run_many`` (parallel, cached loop, ``stride``) against one filter run per
  parameter set;
* the cached per-kernel batch loop against the generic loop and the
  per-sample path;
* ``decode_scan`` of an existing scan against ``read_tlog_arrays``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavahrs.filters import NAMES, create
from mavahrs.filters.base import _batch_loops, make_inputs, run_many, run_rows
from mavahrs.filters.layout import FLAG_NOT_INITIALISED, IN_MAG, OUT_FLAGS, OUT_Q
from mavahrs.filters.madgwick import Madgwick, MadgwickSettings
from mavahrs.filters.mahony import Mahony, MahonySettings


@pytest.fixture(scope="module")
def ideal_400hz_tlog(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """10 s of hover as scripts/bench.py generates it: RAW_IMU at 400 Hz (one IMU + compass), SIMSTATE 10 Hz."""
    fs_main = pytest.importorskip("firmware_sim.__main__")
    from firmware_sim.endpoint import Endpoint
    from firmware_sim.simulation import Simulation
    from firmware_sim.streamer import write_tlog

    path = tmp_path_factory.mktemp("perf") / "ideal400.tlog"
    args = ["--tlog", str(path), "--fast", "-q", "--ideal", "--scenario", "hover", "--duration", "10", "--seed", "2",
            "--imus", "1", "--preset", "none", "--stream", "RAW_IMU=400", "--stream", "HEARTBEAT=1",
            "--stream", "SIMSTATE=10"]  # fmt: skip
    ns = fs_main.build_parser().parse_args(args)
    sim, ep = fs_main.settings_from_args(ns)
    write_tlog(Endpoint(Simulation(sim), ep), str(path), ns.duration)
    return path


@pytest.fixture(scope="module")
def sensor_rows() -> np.ndarray:
    """4000 rows at 400 Hz: turning, noisy accelerometer and magnetometer, a few invalid samples."""
    rng = np.random.default_rng(42)
    n = 4000
    t = np.arange(n) / 400.0
    gyro = 0.4 * np.stack([np.sin(0.7 * t), np.cos(0.5 * t), np.sin(0.3 * t + 1.0)], axis=1) + rng.normal(0, 0.01, (n, 3))
    accel = np.array([0.0, 0.0, -9.80665]) + rng.normal(0, 0.3, (n, 3))
    mag = np.array([22.0, 1.0, 43.0]) + rng.normal(0, 0.5, (n, 3))
    mag[1500:1600] = np.nan  # compass silent for a while
    accel[2000] = 0.0  # an invalid accelerometer sample
    return make_inputs(gyro, accel, mag, dt_s=np.full(n, 1 / 400.0))


# --------------------------------------------------------------------------- replay engines


@pytest.mark.slow
def test_fast_replay_equals_the_per_message_pipeline(ideal_400hz_tlog: Path, tmp_path: Path) -> None:
    from mavahrs.replay import ReplaySettings, replay

    filters = ("madgwick", "best")
    fast = replay(ideal_400hz_tlog, ReplaySettings(filters=filters, engine="fast"), csv_path=tmp_path / "fast.csv")
    ref = replay(ideal_400hz_tlog, ReplaySettings(filters=filters, engine="pipeline"), csv_path=tmp_path / "ref.csv")
    assert fast.engine == "fast" and ref.engine == "pipeline"
    assert fast.inputs.n == ref.inputs.n >= 3990  # 10 s at 400 Hz
    csv = (tmp_path / "fast.csv").read_bytes()
    assert csv == (tmp_path / "ref.csv").read_bytes()
    assert csv.count(b"\n") == fast.inputs.n + 1
    np.testing.assert_array_equal(fast.inputs.rows, ref.inputs.rows)
    for name in filters:
        a, b = fast.tracks[name], ref.tracks[name]
        np.testing.assert_array_equal(a.out, b.out)
        np.testing.assert_array_equal(a.sent, b.sent)
        assert fast.frames(name) == ref.frames(name)
        init = (a.out[:, OUT_FLAGS].astype(np.int64) & FLAG_NOT_INITIALISED) == 0
        assert init.mean() > 0.99  # a real run, not NaN rows compared with NaN rows


def test_decode_scan_equals_read_tlog_arrays(ideal_400hz_tlog: Path) -> None:
    from mavahrs.evaluation.tlogdata import REPLAY_TYPES
    from mavahrs.protocol.fast_tlog import decode_scan, read_tlog_arrays, scan_tlog

    types = list(REPLAY_TYPES)
    data = np.fromfile(ideal_400hz_tlog, np.uint8)
    once = decode_scan(scan_tlog(data, types), types)
    ref = read_tlog_arrays(ideal_400hz_tlog, types)
    assert set(once) == set(ref)
    assert once["RAW_IMU"].shape[0] >= 3990 and once["SIMSTATE"].shape[0] >= 90
    for name in types:
        np.testing.assert_array_equal(once[name], ref[name])


# --------------------------------------------------------------------------- batch loops


@pytest.mark.parametrize("name", [*NAMES, "best"])
def test_cached_batch_loop_equals_generic_loop_and_per_sample(name: str, sensor_rows: np.ndarray) -> None:
    cached = create(name)
    out_cached = cached.run(sensor_rows)  # the per-kernel loop cached on disk
    generic = create(name)
    out_generic = np.zeros_like(out_cached)
    run_rows(generic._step, generic._state, generic._params, sensor_rows, out_generic)  # kernel as an argument
    np.testing.assert_array_equal(out_cached, out_generic)
    np.testing.assert_array_equal(cached.raw_state, generic.raw_state)
    per_sample = create(name)
    out_rows = np.array([per_sample.update_row(r).copy() for r in sensor_rows[:500]])
    np.testing.assert_array_equal(out_cached[:500], out_rows)
    assert _batch_loops(cached._step)[0] is not run_rows


def test_interpreted_batch_matches_compiled(sensor_rows: np.ndarray) -> None:
    rows = sensor_rows[:400]
    for name in ("madgwick", "mahony"):
        a = create(name).run(rows)
        b = create(name, compiled=False).run(rows)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- run_many


def _madgwick_grid() -> list[MadgwickSettings]:
    return [MadgwickSettings(beta_rad_s=b, zeta_rad_s=z) for b in (0.005, 0.041, 0.2) for z in (0.0, 0.01)]


def test_run_many_row_k_equals_a_single_run_with_params_k(sensor_rows: np.ndarray) -> None:
    grid = _madgwick_grid()
    many = [Madgwick(s) for s in grid]
    q = run_many(many, sensor_rows)
    assert q.shape == (len(grid), sensor_rows.shape[0], 4)
    spread = np.ptp(q[:, -1, :], axis=0).max()
    assert spread > 1e-4  # the parameter sets really differ
    for k, s in enumerate(grid):
        single = Madgwick(s)
        out = single.run(sensor_rows)
        np.testing.assert_allclose(q[k], out[:, OUT_Q : OUT_Q + 4], rtol=0, atol=1e-12)
        np.testing.assert_allclose(many[k].raw_state, single.raw_state, rtol=0, atol=1e-12)
        assert many[k].diagnostics == single.diagnostics


def test_run_many_continues_and_strides(sensor_rows: np.ndarray) -> None:
    grid = [MahonySettings(kp_accel=kp, kp_mag=kp / 2) for kp in (0.2, 1.0, 3.0)]
    split = 1237
    stride = 40
    many = [Mahony(s) for s in grid]
    first = run_many(many, sensor_rows[:split], stride=stride)
    second = run_many(many, sensor_rows[split:], stride=stride)
    assert first.shape[1] == -(-split // stride)
    for k, s in enumerate(grid):
        out = Mahony(s).run(sensor_rows)[:, OUT_Q : OUT_Q + 4]
        np.testing.assert_allclose(first[k], out[:split:stride], rtol=0, atol=1e-12)
        np.testing.assert_allclose(second[k], out[split::stride], rtol=0, atol=1e-12)


def test_run_many_interpreted_and_without_magnetometer(sensor_rows: np.ndarray) -> None:
    rows = sensor_rows[:300].copy()
    rows[:, IN_MAG : IN_MAG + 3] = np.nan
    grid = _madgwick_grid()[:3]
    compiled = run_many([Madgwick(s) for s in grid], rows, stride=7)
    interpreted = run_many([Madgwick(s, compiled=False) for s in grid], rows, stride=7)
    np.testing.assert_allclose(compiled, interpreted, rtol=0, atol=1e-9)
    single = Madgwick(grid[1]).run(rows)[::7, OUT_Q : OUT_Q + 4]
    np.testing.assert_allclose(compiled[1], single, rtol=0, atol=1e-12)


@pytest.mark.parametrize("stride", [0, -3, 1.5, True])
def test_run_many_rejects_a_bad_stride(stride: object, sensor_rows: np.ndarray) -> None:
    with pytest.raises(ValueError, match="stride"):
        run_many([Madgwick()], sensor_rows[:10], stride=stride)  # type: ignore[arg-type]



_QUICK_START = r"""
import json, sys
import numpy as np
from mavahrs.filters.jit import on_first_compile, quick_start
installed = quick_start()
compiled = []
on_first_compile(compiled.append)
from mavahrs.filters import create
rows = np.load(sys.argv[1])
out = create("madgwick").run(rows)
registries = "numba.np.arraymath" in sys.modules  # (loaded by a compilation, with the BLAS probe hidden)
blas = bool(sys.modules["numba.np.arraymath"]._HAVE_BLAS) if registries else None
import scipy.linalg  # importable as usual afterwards
print(json.dumps({"installed": installed, "compiled": bool(compiled), "registries": registries,
                  "blas": blas, "q": out[:, :4].tolist(),
                  "lu": scipy.linalg.lu_factor(np.eye(2))[0].tolist()}))
"""


def test_quick_start_loads_cached_kernels_without_the_registries_and_changes_no_result(
    sensor_rows: np.ndarray, tmp_path: Path
) -> None:
    """The command-line start: a kernel from the disk cache loads without numba's compiler registries (which a
    compilation still loads, with the BLAS probe hidden); same filter output, scipy intact."""
    import json
    import subprocess
    import sys

    pytest.importorskip("numba")
    create("madgwick").run(sensor_rows[:8])  # (in the disk cache from here on)
    path = tmp_path / "rows.npy"
    np.save(path, sensor_rows)
    res = subprocess.run([sys.executable, "-c", _QUICK_START, str(path)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert got["installed"]
    if got["compiled"]:  # (a cold cache) the compiler loaded its registries, without probing for BLAS
        assert got["registries"] and got["blas"] is False
    else:  # loaded from the cache: nothing of the compiler was needed
        assert not got["registries"]
    assert got["lu"] == [[1.0, 0.0], [0.0, 1.0]]
    np.testing.assert_array_equal(np.array(got["q"]), create("madgwick").run(sensor_rows)[:, :4])


_NO_RUNTIME = r"""
import json, sys
import numpy as np
from mavahrs.filters.jit import on_first_compile, quick_start
quick_start()
compiled = []
on_first_compile(compiled.append)
from numba.core.runtime import rtsys
from mavahrs.protocol.fast_tlog import scan_tlog
from mavahrs.filters import create
scan = scan_tlog(sys.argv[1])
q = create("madgwick").run(np.load(sys.argv[2]))[:, :4]
runtime_before = bool(rtsys._init)
from mavahrs.evaluation.csvout import format_rows  # declared allocates: loads with numba's runtime
text = format_rows(np.array([[1.25, -2.5]]), [2, 1])
print(json.dumps({"compiled": bool(compiled), "runtime_before": runtime_before, "runtime_after": bool(rtsys._init),
                  "t_us": scan.t_us.tolist(), "q": q.tolist(), "csv": text.decode()}))
"""


def test_kernels_without_reference_counting_load_without_numbas_runtime(
    ideal_400hz_tlog: Path, sensor_rows: np.ndarray, tmp_path: Path
) -> None:
    """A command's start: the tlog decoder and the filters (no reference counting) come from the disk cache without
    numba's runtime (17 ms to set up); a kernel that allocates (the CSV formatter) sets it up when it loads.
    Same results as in this process."""
    import json
    import subprocess
    import sys

    pytest.importorskip("numba")
    from mavahrs.evaluation.csvout import format_rows
    from mavahrs.protocol.fast_tlog import scan_tlog

    scan = scan_tlog(ideal_400hz_tlog)  # (all three in the disk cache from here on)
    expected_q = create("madgwick").run(sensor_rows)[:, :4]
    expected_csv = format_rows(np.array([[1.25, -2.5]]), [2, 1]).decode()
    path = tmp_path / "rows.npy"
    np.save(path, sensor_rows)
    res = subprocess.run([sys.executable, "-c", _NO_RUNTIME, str(ideal_400hz_tlog), str(path)],
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout.strip().splitlines()[-1])
    if not got["compiled"]:  # (a cold cache compiles, and compiling sets the runtime up)
        assert got["runtime_before"] is False
    assert got["runtime_after"] is True
    assert got["t_us"] == scan.t_us.tolist()
    np.testing.assert_array_equal(np.array(got["q"]), expected_q)
    assert got["csv"] == expected_csv
