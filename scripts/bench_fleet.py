#!/usr/bin/env python3
r"""Fleet throughput of ``mavahrs audit``: IMU samples replayed per second, 1 and 2 local Dask workers, a
Dask cluster over loopback TCP, and the scaling ratio (issue 18: ≥ 1.8× from 1 to 2 workers on 2 cores).

The fleet: ``--distinct`` simulated ``hover`` flights of ``--duration`` s (firmware_sim, ArduPilot, RAW_IMU at
250 Hz, ATTITUDE at 50 Hz; generated once into ``--workdir``), copied to ``--logs`` files — every copy is
replayed and summarised in full (:func:`mavahrs.fleet.audit.summarise_log`, one Dask task per log).  In each of
``--repeat`` rounds every engine in turn is started, replays one log on every worker (the kernels load from
numba's cache), replays the fleet (timed) and is stopped; each engine's best wall time counts.  One engine
runs at a time (on 2 cores another engine's idle Dask processes would take time from the timed one), and
the rounds interleave them (on a shared machine a change of load hits every engine alike).  Start-up is
not timed.

Engines: ``serial`` (this process, no Dask), ``local-1`` and ``local-2`` (a LocalCluster of 1 / 2 worker
processes, one thread each), ``cluster`` (``dask scheduler`` + two ``dask worker --nworkers 1 --nthreads 1``
processes on 127.0.0.1, as ``audit --scheduler`` uses them).

    python3 scripts/bench_fleet.py                  # ~1 min on 2 idle cores (16 logs x 120 s = 480 000 samples per pass)
    python3 scripts/bench_fleet.py --logs 48 --json fleet_bench.json
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


def make_fleet(workdir: Path, logs: int, distinct: int, duration_s: float) -> list[Path]:
    from firmware_sim.fleet import FleetLog, write_fleet_log

    src = workdir / f"distinct_{distinct}x{duration_s:g}s"
    src.mkdir(parents=True, exist_ok=True)
    originals = []
    for k in range(distinct):
        p = src / f"hover_{k}.tlog"
        if not p.exists():
            write_fleet_log(src, FleetLog(p.name, "hover", 1000 + k, duration_s, sysid=1 + k))
        originals.append(p)
    fleet = workdir / f"fleet_{logs}"
    shutil.rmtree(fleet, ignore_errors=True)
    fleet.mkdir()
    out = []
    for i in range(logs):
        dst = fleet / f"flight_{i:04d}.tlog"
        shutil.copyfile(originals[i % distinct], dst)
        out.append(dst)
    return out


def timed(mapper, logs: list[Path], repeat: int) -> tuple[float, int]:  # type: ignore[no-untyped-def]
    """Best wall time of ``repeat`` passes over the fleet, and the IMU samples of one pass."""
    from mavahrs.fleet.audit import AuditSettings, run_audit, summarise_log

    fn = functools.partial(summarise_log, settings=AuditSettings())
    best, samples = float("inf"), 0
    for _ in range(repeat):
        run = run_audit(logs, fn, mapper)
        bad = [r for r in run.rows if not r.ok]
        if bad:
            raise SystemExit(f"bench_fleet: {bad[0].path}: {bad[0].error}")
        best, samples = min(best, run.wall_s), run.samples
    return best, samples


def warm(engine, log: Path) -> None:  # type: ignore[no-untyped-def]
    from mavahrs.fleet.audit import summarise_log

    engine.on_every_worker(summarise_log, log)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=16, help="logs in the fleet (default 16)")
    ap.add_argument(
        "--distinct", type=int, default=4, help="distinct simulated flights copied to --logs files (4)"
    )
    ap.add_argument("--duration", type=float, default=120.0, help="seconds per flight (default 120)")
    ap.add_argument(
        "--repeat", type=int, default=2, help="rounds over the engines, the best counts (default 2)"
    )
    ap.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "mavahrs-bench-fleet")
    ap.add_argument(
        "--skip", action="append", default=[], choices=("serial", "local-1", "local-2", "cluster")
    )
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args(argv)

    from mavahrs.fleet.audit import serial_map
    from mavahrs.fleet.dask_engine import DaskEngine, loopback_cluster

    t = time.perf_counter()
    logs = make_fleet(args.workdir, args.logs, args.distinct, args.duration)
    print(f"fleet: {len(logs)} logs of {args.duration:g} s in {args.workdir} ({time.perf_counter() - t:.1f} s)",
          flush=True)  # fmt: skip
    results: dict[str, dict[str, float]] = {}
    from mavahrs.fleet.audit import summarise_log

    names = [n for n in ("serial", "local-1", "local-2", "cluster") if n not in args.skip]
    best: dict[str, tuple[float, int]] = {}
    # one engine at a time (started, warmed, timed, stopped): on 2 cores the idle processes of another
    # engine (Dask workers tick every few ms) would take time from the one being timed; the rounds are
    # interleaved, so a change of load on a shared machine hits every engine alike
    for _ in range(args.repeat):
        for name in names:
            with contextlib.ExitStack() as stack:
                if name == "serial":
                    summarise_log(logs[0])  # kernels loaded
                    mapper = serial_map
                elif name.startswith("local-"):
                    eng = stack.enter_context(DaskEngine(workers=int(name[-1])))
                    warm(eng, logs[0])
                    mapper = eng.map
                else:
                    tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="bench-fleet-")))
                    env = dict(
                        os.environ,
                        PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
                    )
                    address = stack.enter_context(loopback_cluster(tmp, 2, env=env))
                    eng = stack.enter_context(DaskEngine(scheduler=address))
                    warm(eng, logs[0])
                    mapper = eng.map
                wall, samples = timed(mapper, logs, 1)
            if name not in best or wall < best[name][0]:
                best[name] = (wall, samples)
    for name in names:
        wall, samples = best[name]
        results[name] = {"wall_s": wall, "samples": samples, "samples_per_s": samples / wall}
        print(f"{name:<10} {samples:>10} IMU samples in {wall:6.2f} s: {samples / wall:12.4g} samples/s", flush=True)
    one = results.get("local-1", {}).get("samples_per_s")
    if one:
        for name in ("local-2", "cluster"):
            if name in results:
                ratio = results[name]["samples_per_s"] / one
                results[name]["scaling_vs_local_1"] = ratio
                print(f"scaling {name} / local-1: {ratio:.2f}x (goal on 2 idle cores: >= 1.8x)")
    print(f"cores: {os.cpu_count()}; load average before the run: {os.getloadavg()[0]:.2f}")
    if args.json:
        args.json.write_text(json.dumps({"logs": len(logs), "duration_s": args.duration, "results": results},
                                        indent=2))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
