#!/usr/bin/env python3
"""Every output of the ESKF filters (`eskf`, `best`) on firmware_sim flights and the shared logs, saved, and two
such saves compared bit for bit: does a change that should not move the estimate (how the kernels are compiled,
say) leave every float as it was?

Usage (run the same script under each tree's package, each with its own kernel cache)::

    NUMBA_CACHE_DIR=/tmp/a PYTHONPATH=/path/to/main python3 scripts/compare_estimates.py dump main.npz
    NUMBA_CACHE_DIR=/tmp/b PYTHONPATH=. python3 scripts/compare_estimates.py dump mine.npz
    python3 scripts/compare_estimates.py compare main.npz mine.npz

``mavahrs`` is imported from ``PYTHONPATH`` (the checkout this script lies in only when nothing else is
given), so one copy of the script serves both trees; ``dump`` prints which package it ran.

What is saved, each as the whole output rows (``OUT_WIDTH`` columns: quaternion, its σ, flags, every
diagnostic) and the filter's state vector after the last sample:

* firmware_sim flights (``--scenarios``, ``--seeds``, ``--duration``; written as
  ``scripts/bench_sim_accuracy.py`` writes them, with and without GLOBAL_POSITION_INT) replayed with
  :func:`mavahrs.replay.replay` through the daemon's pipeline sample by sample (``engine="pipeline"``: the
  per-sample kernels) and with the batch engine (``engine="fast"``: the compiled loop over the rows);
* the shared logs (``../shared/data``) as ``scripts/bench_estimator.py`` feeds them: the ArduPilot SITL and PX4
  SITL tlogs as an autopilot's stream (vehicle mode, multirotor, sensor delay) and as plain rows (no vehicle
  mode), the SITL tlogs without GNSS, the raw-IMU variant (``make_raw``, ``set_multirotor()``), the vibrating
  variant (plain API), and the BROAD trials 9-axis and 6-axis;
* a gain sweep (:func:`mavahrs.filters.base.run_many`, the batch kernel for several filters) on the first
  SITL log.

``compare`` compares every array's bytes (NaN payloads included) and names the first difference.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # _sibling; mavahrs itself comes from PYTHONPATH (or is installed)

FILTERS = ("eskf", "best")


def _filter_out(name: str, rows: np.ndarray, *, delay_s: float = 0.0, vehicle: bool = False,
                multirotor: bool = False) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``name`` on ``rows`` as scripts/bench_estimator.py runs it; (output rows, state after the last row)."""
    from mavahrs.filters import create

    f = create(name)
    if multirotor and hasattr(f, "set_multirotor"):
        f.set_multirotor()
    if delay_s > 0.0 and hasattr(f, "set_sensor_delay"):
        f.set_sensor_delay(delay_s)
    if vehicle and hasattr(f, "set_vehicle_stream"):
        f.set_vehicle_stream()
    out = f.run(rows)
    return out, f._state.copy()


def dump(path: Path, scenarios: list[str], seeds: list[int], duration_s: float, data: Path) -> int:
    from _sibling import load_script

    import mavahrs
    from mavahrs.filters import create
    from mavahrs.filters.base import make_inputs, run_many
    from mavahrs.replay import ReplaySettings, replay

    sim = load_script("bench_sim_accuracy")
    est = load_script("bench_estimator")
    print(f"mavahrs from {Path(mavahrs.__file__).parent}", file=sys.stderr)
    arrays: dict[str, np.ndarray] = {}
    t0 = time.monotonic()

    def keep(key: str, out: np.ndarray, state: np.ndarray | None = None) -> None:
        arrays[key + "/out"] = np.ascontiguousarray(out)
        if state is not None:
            arrays[key + "/state"] = np.ascontiguousarray(state)

    with tempfile.TemporaryDirectory(prefix="mavahrs-cmp-") as tmp:
        for scenario in scenarios:
            for seed in seeds:
                for log, tag in zip(sim.write_flight(Path(tmp), scenario, seed, duration_s), ("gps", "nogps"), strict=True):
                    for engine in ("pipeline", "fast"):
                        res = replay(log, ReplaySettings(filters=FILTERS, engine=engine))
                        for name in FILTERS:
                            keep(f"sim/{scenario}{seed}/{tag}/{engine}/{name}", res.tracks[name].out)
                print(f"  firmware_sim {scenario} {seed}: {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)

    sitl = sorted((data / "sitl").glob("*.tlog"))
    for log in sitl + sorted((data / "px4_sitl").glob("*.tlog")):
        for variant in ("as-is", "no-gnss") if log.parent.name == "sitl" else ("as-is",):
            d = est.load_log(log, variant, None)
            rows, t = d["rows"], d["t_us"]
            delay = float(d["delay_s"])
            for name in FILTERS:
                keep(f"log/{log.stem}/{variant}/vehicle/{name}", *_filter_out(name, rows, delay_s=delay, vehicle=True,
                                                                               multirotor=True))  # fmt: skip
                keep(f"log/{log.stem}/{variant}/plain/{name}", *_filter_out(name, rows))
            if variant == "no-gnss":
                raw, _bias = est.make_raw(rows, log.stem)
                cut = t >= t[0] + est.RAW_CUT_S * 1e6
                raw, t_raw = raw[cut], t[cut]
                vib, _keep = est.make_vibrating(raw, t_raw, log.stem)
                for name in FILTERS:
                    keep(f"log/{log.stem}/raw/multirotor/{name}", *_filter_out(name, raw, multirotor=True))
                    keep(f"log/{log.stem}/vib/plain/{name}", *_filter_out(name, vib))
            print(f"  {log.stem} {variant}: {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)

    from mavahrs.evaluation.datasets import find_broad_trials, load_broad_trial

    for p in find_broad_trials(data / "broad"):
        rec = load_broad_trial(p)
        for tag, mag in (("9D", rec.mag_ut), ("6D", None)):
            rows = make_inputs(rec.gyro_rad_s, rec.accel_m_s2, mag, dt_s=rec.dt_s)
            for name in FILTERS:
                keep(f"broad/{rec.name}/{tag}/{name}", *_filter_out(name, rows))
    print(f"  BROAD: {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)

    if sitl:
        d = est.load_log(sitl[0], "as-is", None)
        for name in FILTERS:
            fs = [create(name) for _ in range(3)]
            fs[1].set_multirotor()
            fs[2].set_sensor_delay(0.01)
            keep(f"sweep/{sitl[0].stem}/{name}", run_many(fs, d["rows"]), np.stack([f._state for f in fs]))

    np.savez_compressed(path, **arrays)
    n = sum(a.shape[0] for k, a in arrays.items() if k.endswith("/out"))
    print(f"{len(arrays)} arrays, {n} output rows, {time.monotonic() - t0:.0f} s -> {path}", file=sys.stderr)
    return 0


def compare(a_path: Path, b_path: Path, outputs_only: bool = False) -> int:
    a, b = np.load(a_path), np.load(b_path)
    ka, kb = set(a.files), set(b.files)
    if outputs_only:  # the output rows alone (a change that adds a state slot moves every later offset of the state)
        ka = {k for k in ka if not k.endswith("/state")}
        kb = {k for k in kb if not k.endswith("/state")}
    if ka != kb:
        print(f"different cases: only in {a_path}: {sorted(ka - kb)[:5]}, only in {b_path}: {sorted(kb - ka)[:5]}")
        return 1
    bad = 0
    values = 0
    for k in sorted(ka):
        x, y = a[k], b[k]
        values += x.size
        if x.shape != y.shape or x.dtype != y.dtype:
            print(f"{k}: shape/dtype {x.shape} {x.dtype} vs {y.shape} {y.dtype}")
            bad += 1
            continue
        if x.tobytes() != y.tobytes():
            diff = np.argwhere(x.view(np.uint64) != y.view(np.uint64))
            first = tuple(int(i) for i in diff[0])
            print(f"{k}: {len(diff)} of {x.size} values differ, first at {first}: {x[first]!r} vs {y[first]!r}")
            bad += 1
    print(f"{len(ka)} arrays, {values} float64 values: " + ("bit-identical" if not bad else f"{bad} arrays differ"))
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump", help="run the filters and save every output")
    d.add_argument("out", type=Path)
    d.add_argument("--scenarios", nargs="+", default=["aggressive", "flips", "hover", "magnetic"])
    d.add_argument("--seeds", nargs="+", type=int, default=[1, 61])
    d.add_argument("--duration", type=float, default=60.0, help="seconds of each firmware_sim flight (default 60)")
    d.add_argument("--data", type=Path, default=HERE.parent.parent / "shared" / "data")
    c = sub.add_parser("compare", help="compare two saves bit for bit")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    c.add_argument("--outputs-only", action="store_true",
                   help="compare the output rows only, not the state vectors (a change that adds state)")
    args = parser.parse_args(argv)
    if args.cmd == "dump":
        return dump(args.out, args.scenarios, args.seeds, args.duration, args.data)
    return compare(args.a, args.b, args.outputs_only)


if __name__ == "__main__":
    sys.exit(main())
