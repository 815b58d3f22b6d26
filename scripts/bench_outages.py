#!/usr/bin/env python3
r"""Link outages mid-manoeuvre: how fast the daemon's filter recovers, against the same flight uninterrupted.

Usage::

    python3 scripts/bench_outages.py                               # 7 seeds x 4 outage times, with and without GNSS
    python3 scripts/bench_outages.py --seeds 1 5 --starts 9 12 --json out.json
    python3 scripts/bench_outages.py --filter mahony --no-gnss-only

For every seed, ``firmware_sim`` flies the ``aggressive`` scenario (sustained
30–45° tilted acceleration, hard braking) for ``--duration`` seconds, once
uninterrupted and once per outage start with ``--blackout START:LENGTH`` (the
link carries nothing for LENGTH seconds: the daemon's timeline sees a gap and
the filter re-initialises from the next sample), each with GLOBAL_POSITION_INT
at 10 Hz and again without it:

    python -m firmware_sim --tlog F --fast --scenario aggressive --duration 20 --seed N \
        --declination-deg 0 --stream RAW_IMU=400 --stream SIMSTATE=50 --stream SCALED_IMU2=0 \
        [--stream GLOBAL_POSITION_INT=0] [--blackout START:1.5]

Each log is replayed through the daemon's pipeline (:func:`mavahrs.replay.replay`,
output at every sample) and scored against the SIMSTATE truth: inclination RMS
in windows after the end of the outage (0–1, 1–3, 3–5 s and the rest of the
flight), minus the uninterrupted run's RMS in the same window (the *excess*).
Printed: every case, then the mean and the worst excess over the cases.
The flights are generated once into ``--keep`` (default a temporary folder).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

WINDOWS_S = ((0.0, 1.0), (1.0, 3.0), (3.0, 5.0), (5.0, math.inf))


def _flight(folder: Path, seed: int, duration_s: float, gnss: bool, blackout: str | None) -> Path:
    name = f"aggressive_s{seed}_{duration_s:g}s_{'gnss' if gnss else 'nognss'}_{blackout or 'clean'}.tlog"
    path = folder / name.replace(":", "+")
    if not path.exists():
        cmd = [sys.executable, "-m", "firmware_sim", "--tlog", str(path), "--fast", "-q", "--scenario", "aggressive",
               "--duration", f"{duration_s:g}", "--seed", str(seed), "--declination-deg", "0",
               "--stream", "RAW_IMU=400", "--stream", "SIMSTATE=50", "--stream", "SCALED_IMU2=0"]
        if not gnss:
            cmd += ["--stream", "GLOBAL_POSITION_INT=0"]
        if blackout:
            cmd += ["--blackout", blackout]
        subprocess.run(cmd, check=True, cwd=REPO)
    return path


def _inclination_series(path: Path, filter_name: str) -> tuple[np.ndarray, np.ndarray]:
    """(seconds since the first truth sample, inclination error in degrees) at the truth's times."""
    from mavahrs.evaluation.metrics import attitude_errors_rad
    from mavahrs.replay import ReplaySettings, attitude_at_reference, replay
    from mavahrs.sensors.geomag import MagneticFieldSettings
    from mavahrs.service.pipeline import PipelineSettings

    ps = PipelineSettings(out_rate_hz=0.0, magnetic=MagneticFieldSettings(declination_deg=0.0))
    res = replay(path, ReplaySettings(filters=(filter_name,), pipeline=ps))
    (truth,) = [k for k in res.references if "truth" in k]
    t_ref, q_ref = res.references[truth]
    q = attitude_at_reference(res, filter_name, truth)
    err = np.full(t_ref.size, np.nan)
    ok = np.all(np.isfinite(q), axis=1)
    err[ok] = np.degrees(attitude_errors_rad(q[ok], q_ref[ok])[2])
    return (t_ref - t_ref[0]) * 1e-6, err


def _rms(t: np.ndarray, err: np.ndarray, a: float, b: float) -> float:
    sel = (t >= a) & (t < b) & np.isfinite(err)
    return float(np.sqrt(np.mean(err[sel] ** 2))) if sel.sum() > 10 else math.nan


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5, 6, 11])
    ap.add_argument("--starts", nargs="+", type=float, default=[6.0, 9.0, 12.0, 15.0],
                    help="outage start times, simulated s (default 6 9 12 15)")
    ap.add_argument("--length", type=float, default=1.5, help="outage length, s (default 1.5)")
    ap.add_argument("--duration", type=float, default=20.0, help="flight length, s (default 20)")
    ap.add_argument("--filter", default="best", help="mavahrs filter (default best)")
    ap.add_argument("--no-gnss-only", action="store_true", help="only the flights without GLOBAL_POSITION_INT")
    ap.add_argument("--gnss-only", action="store_true", help="only the flights with GLOBAL_POSITION_INT")
    ap.add_argument("--keep", type=Path, help="folder for the generated flights (re-used when present)")
    ap.add_argument("--json", type=Path, help="write every case and the summary as JSON")
    args = ap.parse_args(argv)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_outages_"))
    folder.mkdir(parents=True, exist_ok=True)
    modes = [g for g in (True, False) if not ((g and args.no_gnss_only) or (not g and args.gnss_only))]
    labels = " ".join(f"{a:g}-{b:g}s" if math.isfinite(b) else f"{a:g}s-end" for a, b in WINDOWS_S)
    result: dict[str, Any] = {"filter": args.filter, "length_s": args.length, "duration_s": args.duration, "modes": {}}
    for gnss in modes:
        mode = "with GLOBAL_POSITION_INT" if gnss else "without GNSS"
        print(f"{args.filter}, {mode}: inclination RMS after the outage (°; uninterrupted in brackets), "
              f"windows {labels}", flush=True)
        cases, excess, clean_rms = [], [], []
        for seed in args.seeds:
            t0, e0 = _inclination_series(_flight(folder, seed, args.duration, gnss, None), args.filter)
            clean_rms.append(_rms(t0, e0, 2.0, math.inf))
            for start in args.starts:
                path = _flight(folder, seed, args.duration, gnss, f"{start:g}:{args.length:g}")
                t, e = _inclination_series(path, args.filter)
                end = start + args.length
                cut = [_rms(t, e, end + a, end + b) for a, b in WINDOWS_S]
                ref = [_rms(t0, e0, end + a, end + b) for a, b in WINDOWS_S]
                excess.append([c - r for c, r in zip(cut, ref, strict=True)])
                cases.append({"seed": seed, "start_s": start, "rms_deg": cut, "uninterrupted_rms_deg": ref})
                print(f"  seed {seed:3d} outage at {start:5.1f} s: "
                      + "  ".join(f"{c:5.1f} ({r:4.1f})" for c, r in zip(cut, ref, strict=True)), flush=True)
        ex = np.array(excess)
        with np.errstate(all="ignore"):
            mean, worst = np.nanmean(ex, axis=0), np.nanmax(ex, axis=0)
        print(f"  excess over the uninterrupted run, mean: {np.round(mean, 1).tolist()}  worst: "
              f"{np.round(worst, 1).tolist()}; uninterrupted flights (from 2 s) {np.mean(clean_rms):.2f}° mean, "
              f"{np.max(clean_rms):.2f}° worst", flush=True)
        result["modes"]["gnss" if gnss else "no_gnss"] = {
            "cases": cases, "excess_mean_deg": mean.tolist(), "excess_worst_deg": worst.tolist(),
            "uninterrupted_rms_deg": clean_rms,
        }
    if args.json:
        args.json.write_text(json.dumps(result, indent=1, default=lambda x: None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
