#!/usr/bin/env python3
"""Regenerate the evaluation figures in docs/img/ and print the tables of docs/evaluation.md.

    python3 scripts/make_report_plots.py [--out docs/img] [--quick] [--only sitl_flight sim_flight ...]

Needs the reference data in ../shared/data (BROAD, RepoIMU, mavlink_logs),
``firmware_sim`` and matplotlib.  ``--quick`` uses two BROAD trials and a
coarse β grid (a few minutes less).  Writes:

* ``broad_trial.png``   — a BROAD trial, filters vs optical truth (per angle, gain, trust);
* ``sim_flight.png``    — a simulator ``aggressive`` flight replayed from its tlog vs SIM_STATE truth;
* ``sitl_flight.png``   — the ArduCopter SITL ``aggressive`` flight (ArduPilot's own firmware)
  vs SIMSTATE truth, beside the autopilot's EKF3 (ATTITUDE) and DCM (AHRS2);
* ``replay_vtol.png``   — the SITL QuadPlane tlog (4 Hz RAW_IMU) vs SIMSTATE and the autopilot;
* ``beta_sweep.png``    — error vs β (Madgwick 2010 Fig. 10) over the BROAD trials;
* ``rate_sweep.png``    — error vs sample rate (Fig. 11) over the BROAD trials;
* ``bias_tracking.png`` — injected gyro drift tracking (Fig. 12);
* ``compare_2022.png``  — Mahony, Madgwick, complementary side by side on RepoIMU (2022 Fig. 8–13).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
DATA = REPO.parent / "shared" / "data"


PARTS = ("tables", "broad_trial", "sim_flight", "sitl_flight", "replay_vtol", "studies")
SHOW = ("madgwick", "mahony", "best")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(REPO / "docs" / "img"))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--only", nargs="+", choices=PARTS, default=list(PARTS), help="what to make (default: all)"
    )
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.time()
    broad: list = []
    if {"tables", "studies"} & set(args.only):
        from mavahrs.evaluation.datasets import find_broad_trials, load_broad_trial

        trials = find_broad_trials(DATA / "broad")
        broad = [load_broad_trial(p) for p in (trials[:2] if args.quick else trials)]
    for part in PARTS:
        if part in args.only:
            globals()[f"make_{part}"](out, broad, args.quick)
    print(f"\nwrote the figures to {out} in {time.time() - t_start:.0f} s", file=sys.stderr)
    return 0


def make_tables(out: Path, broad: list, quick: bool) -> None:
    from mavahrs.evaluation.loaders import load_any
    from mavahrs.evaluation.report import evaluate_recordings, format_report, resolve_filter_names

    names = resolve_filter_names(["all"])
    print("## BROAD, 9-axis, per filter (mean over trials)\n")
    print(format_report(evaluate_recordings(broad, names, input_name="broad"), per_recording=False))
    print("\n## BROAD, 6-axis (heading offset fitted)\n")
    print(
        format_report(
            evaluate_recordings(broad, names, input_name="broad", use_mag=False), per_recording=False
        )
    )
    repo_recs = load_any(DATA / "repoimu_tstick")
    print("\n## RepoIMU T-stick, 9-axis, heading offset fitted\n")
    print(format_report(evaluate_recordings(repo_recs, names, input_name="repoimu"), per_recording=False))
    print("\n## RepoIMU T-stick, 9-axis, heading offset + body misalignment fitted\n")
    print(format_report(evaluate_recordings(repo_recs, names, alignment="heading+body"), per_recording=False))


def make_broad_trial(out: Path, broad: list, quick: bool) -> None:
    import numpy as np

    from mavahrs.evaluation.datasets import load_broad_trial
    from mavahrs.evaluation.plots import plot_attitude
    from mavahrs.evaluation.report import run_filter
    from mavahrs.evaluation.tlogdata import cut_recording

    rec = cut_recording(load_broad_trial(DATA / "broad" / "06_undisturbed_fast_rotation_A.mat"), 30.0, 110.0)
    outs = {n: run_filter(rec, n) for n in SHOW}
    t = np.cumsum(rec.dt_s) - rec.dt_s[0] + 30.0
    plot_attitude(out / "broad_trial.png", t, outs, reference_q=rec.q_ref_body_to_ned,
                  reference_label="optical (BROAD)", title=f"BROAD {rec.name}, 30–110 s, 9-axis")  # fmt: skip


def make_sim_flight(out: Path, broad: list, quick: bool) -> None:
    from firmware_sim.__main__ import main as sim_main
    from mavahrs import replay as rp

    with tempfile.TemporaryDirectory() as tmp:
        tlog = Path(tmp) / "aggressive.tlog"
        sim_main(["--tlog", str(tlog), "--fast", "-q", "--scenario", "aggressive", "--duration", "40",
                  "--seed", "2", "--imus", "1"])  # fmt: skip
        res = rp.replay(tlog, rp.ReplaySettings(filters=SHOW))
        print("\n## Simulator 'aggressive' flight, replayed from its tlog\n")
        print(rp.format_comparison(rp.compare(res)))
        rp.plot_replay(res, out / "sim_flight.png")


def make_sitl_flight(out: Path, broad: list, quick: bool) -> None:
    from mavahrs import replay as rp

    res = rp.replay(
        DATA / "sitl" / "arducopter_aggressive.tlog",
        rp.ReplaySettings(filters=SHOW),
    )
    print("\n## ArduCopter SITL 'aggressive' flight\n")
    print(rp.format_comparison(rp.compare(res)))
    rp.plot_replay(res, out / "sitl_flight.png")


def make_replay_vtol(out: Path, broad: list, quick: bool) -> None:
    from mavahrs import replay as rp

    res = rp.replay(
        DATA / "mavlink_logs" / "UAVLogViewer" / "vtol.tlog",
        rp.ReplaySettings(filters=("madgwick", "mahony")),
    )
    print("\n## SITL QuadPlane tlog (RAW_IMU at 4 Hz)\n")
    for n in res.notes:
        print("note:", n)
    print(rp.format_comparison(rp.compare(res)))
    rp.plot_replay(res, out / "replay_vtol.png")


def make_studies(out: Path, broad: list, quick: bool) -> None:
    from mavahrs.evaluation import studies
    from mavahrs.evaluation.datasets import load_broad_trial
    from mavahrs.evaluation.loaders import load_any
    from mavahrs.evaluation.plots import plot_study

    betas = studies.DEFAULT_BETAS if not quick else (0.0, 0.02, 0.05, 0.1, 0.2, 0.5)
    betas = tuple(b for i, b in enumerate(betas) if i % 2 == 0) if not quick else betas
    r = studies.beta_study(broad, values=betas)
    print("\n" + r.format())
    plot_study(r, out / "beta_sweep.png")
    r = studies.rate_study(broad)
    print("\n" + r.format())
    plot_study(r, out / "rate_sweep.png")
    r = studies.bias_study(load_broad_trial(DATA / "broad" / "02_undisturbed_slow_rotation_B.mat"))
    print("\n" + r.format())
    plot_study(r, out / "bias_tracking.png")
    r = studies.compare_study(load_any(DATA / "repoimu_tstick" / "TStick_Test02_Trial1.csv")[0])
    print("\n" + r.format())
    plot_study(r, out / "compare_2022.png")


if __name__ == "__main__":
    raise SystemExit(main())
