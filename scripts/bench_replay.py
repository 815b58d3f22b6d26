#!/usr/bin/env python3
r"""Replay throughput: ``mavahrs replay LOG --csv OUT`` against a pymavlink + imufusion loop writing a CSV, for
1-, 10- and 30-minute 400 Hz logs, in one run (the start-up share shows in the shorter ones).

For each duration (``--minutes``, default 1 10 30) a hover flight is generated with ``firmware_sim
--fast --ideal`` (one IMU with compass, RAW_IMU at 400 Hz, HEARTBEAT, SIMSTATE truth at 10 Hz) into a
temporary directory, removed with everything written there once that duration is measured.  On it:

* **mavahrs** — ``python -m mavahrs replay LOG --filter madgwick --csv OUT --no-progress``, whole
  process, wall and CPU (user + system) time; one warming run on the 1-minute log first (kernels
  loaded from numba's cache, bytecode written), then the fastest of ``--repeat`` runs;
* **reference** — the loop of ``scripts/bench.py --reference-loop imufusion``: pymavlink's
  ``mavlink_connection`` + ``recv_match(type="RAW_IMU")``, imufusion's ``Ahrs.update`` per sample,
  one CSV row per sample (time, quaternion, Euler angles; mavahrs's CSV has 18 columns), whole
  process, on the whole file (``--reference-prefix S``: on the first S seconds instead, its loop
  time scaled to the whole file, as bench.py does).

The ratio is reference time / mavahrs time for the same file (wall, and CPU — the figure to trust
on a shared machine).  Target: ≥ ``--target`` (25×) on the 30-minute log, judged on wall time
(exit status 1 if missed).  Needs the ``bench`` extra (imufusion).

    python3 scripts/bench_replay.py                         # 1, 10, 30 minutes (~10 min on an idle PC)
    python3 scripts/bench_replay.py --minutes 1 10          # not judged without 30
    python3 scripts/bench_replay.py --minutes 30 --reference-prefix 300 --json replay.json
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
os.environ.setdefault("MAVLINK20", "1")
os.environ.setdefault("MAVLINK_DIALECT", "ardupilotmega")


def _bench() -> Any:
    from _sibling import load_script

    return load_script("bench", "mavahrs_bench")


B = _bench()


def replay_mavahrs(log: Path, out_csv: Path, filter_name: str) -> tuple[float, float, int]:
    """(wall s, CPU s, IMU samples) of one ``mavahrs replay`` process."""
    cmd = [sys.executable, "-m", "mavahrs", "replay", str(log), "--filter", filter_name, "--csv", str(out_csv),
           "--no-progress"]  # fmt: skip
    wall, cpu, out = B.timed_process(cmd)
    m = re.search(r"(\d+) IMU samples", out)
    return wall, cpu, int(m.group(1)) if m else 0


def reference(log: Path, out_csv: Path, prefix_s: float | None, samples: int) -> dict[str, Any]:
    """The pymavlink + imufusion loop on the whole file (or on a prefix, scaled to ``samples``)."""
    src = B.prefix_tlog(log, prefix_s) if prefix_s else log
    wall, cpu, out = B.timed_process([sys.executable, str(REPO / "scripts" / "bench.py"), "--reference-loop",
                                      "imufusion", str(src), str(out_csv)])  # fmt: skip
    r = json.loads(out.strip().splitlines()[-1])
    k = samples / r["samples"] if prefix_s else 1.0
    if prefix_s:
        src.unlink()
    return {**r, "measured_wall_s": wall, "measured_cpu_s": cpu, "scale": k,
            "wall_s": wall + r["loop_wall_s"] * (k - 1.0), "cpu_s": cpu + r["loop_cpu_s"] * (k - 1.0)}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, nargs="+", default=[1.0, 10.0, 30.0], help="log lengths (default 1 10 30)")
    ap.add_argument("--repeat", type=int, default=2, help="mavahrs runs per log, the fastest counts (default 2)")
    ap.add_argument("--filter", default="madgwick", help="mavahrs's filter (default madgwick, as imufusion's)")
    ap.add_argument("--reference-prefix", type=float, metavar="S",
                    help="run the reference on the first S seconds and scale its loop time (default: whole file)")
    ap.add_argument("--target", type=float, default=25.0, help="wall-time ratio wanted on 30 minutes (default 25)")
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    args = ap.parse_args(argv)
    if importlib.util.find_spec("imufusion") is None:
        print("imufusion is not installed: pip install 'mavahrs[bench]'", file=sys.stderr)
        return 2

    B._byte_compile_mavahrs()
    results: list[dict[str, Any]] = []
    warmed = False
    for minutes in args.minutes:
        with tempfile.TemporaryDirectory(prefix="mavahrs-bench-replay-") as tmp_name:
            tmp = Path(tmp_name)
            seconds = int(round(minutes * 60))
            t0 = time.perf_counter()
            log = B.ensure_tlog(tmp, seconds, seed=1)
            gen_s = time.perf_counter() - t0
            if not warmed:  # kernels from the cache (compiled once after an edit), bytecode, page cache
                replay_mavahrs(log, tmp / "warm.csv", args.filter)
                (tmp / "warm.csv").unlink()
                warmed = True
            runs = [replay_mavahrs(log, tmp / "mavahrs.csv", args.filter) for _ in range(args.repeat)]
            wall, cpu, samples = min(runs)
            ref = reference(log, tmp / "imufusion.csv", args.reference_prefix, samples)
            sanity = B._compare_csvs(tmp / "mavahrs.csv", [tmp / "imufusion.csv"])["imufusion"]
            csv_bytes = (tmp / "mavahrs.csv").stat().st_size + (tmp / "imufusion.csv").stat().st_size
            for name in ("mavahrs.csv", "imufusion.csv"):  # (30 min: ~0.2 GB of CSV) disk kept small
                (tmp / name).unlink()
            row = {"minutes": minutes, "samples": samples, "log_bytes": log.stat().st_size, "generate_s": gen_s,
                   "mavahrs": {"runs": runs, "wall_s": wall, "cpu_s": cpu},
                   "reference": ref, "ratio_wall": ref["wall_s"] / wall, "ratio_cpu": ref["cpu_s"] / cpu,
                   "mean_abs_diff_deg": sanity, "csv_bytes": csv_bytes}  # fmt: skip
            results.append(row)
            scaled = f" (scaled ×{ref['scale']:.1f} from a prefix)" if args.reference_prefix else ""
            print(f"{minutes:g} min ({samples} samples, {log.stat().st_size / 1e6:.0f} MB): mavahrs {wall:.2f} s wall "
                  f"{cpu:.2f} s CPU; pymavlink+imufusion {ref['wall_s']:.1f} s wall {ref['cpu_s']:.1f} s CPU"
                  f"{scaled}; "
                  f"ratio {row['ratio_wall']:.1f}× wall, {row['ratio_cpu']:.1f}× CPU; mean |Δroll| "
                  f"{sanity['roll_deg']:.2f}°, |Δpitch| {sanity['pitch_deg']:.2f}° vs imufusion", flush=True)  # fmt: skip
    print("\nreplay to CSV, ratio over pymavlink + imufusion (same file, same run):")
    print("  minutes   samples   mavahrs wall   reference wall   ratio wall   ratio CPU")
    for r in results:
        print(f"  {r['minutes']:>7g} {r['samples']:>9} {r['mavahrs']['wall_s']:>12.2f} s {r['reference']['wall_s']:>14.1f} s"
              f" {r['ratio_wall']:>10.1f}× {r['ratio_cpu']:>10.1f}×")
    print(f"  (load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)")
    judged = [r for r in results if r["minutes"] >= 30]
    ok = all(r["ratio_wall"] >= args.target for r in judged)
    if judged:
        print(f"target ≥ {args.target:g}× on 30 minutes (wall): {'PASS' if ok else 'FAIL'}")
    if args.json:
        Path(args.json).write_text(json.dumps({"results": results, "target": args.target}, indent=2))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
