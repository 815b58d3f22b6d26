#!/usr/bin/env python3
"""Heading under magnetic disturbance: ``best`` as configured (the learnt magnetometer model on) and with it off, beside the autopilot's EKF.

Usage::

    python3 scripts/bench_mag.py                                   # the shared magnetic SITL flight + 2 firmware_sim flights
    python3 scripts/bench_mag.py FLIGHT.tlog ...                   # other flights (SIMSTATE / HIL_STATE_QUATERNION truth)
    python3 scripts/bench_mag.py --sim-seeds 3 11 --variants as-is # firmware_sim ``mag_anomaly`` flights only
    python3 scripts/bench_mag.py --json out.json

Every flight is replayed with :func:`mavahrs.replay.replay` (the daemon's
decoding, scaling, timeline, declination; ``IN_CURRENT`` from SYS_STATUS /
BATTERY_STATUS) twice: ``best`` as configured (the magnetometer model,
:mod:`mavahrs.filters.magfield`, on by default since 2026-12-06) and ``best``
with ``eskf.mag_model.enabled = False`` (the heading update gated by the
schedule's norm and dip only).  Scored as ``scripts/bench_sitl.py`` scores
(estimates slerped onto the truth's times, the first ``--skip`` s left out,
heading against true north), beside the autopilot's own estimate in the same
log (ATTITUDE: EKF3 / EKF2; on firmware_sim flights the simulated
autopilot's).  Variants: ``as-is``, and ``receiver-only`` (GLOBAL_POSITION_INT
removed; logs with GPS_RAW_INT only).

firmware_sim flights (``--sim-seeds``): scenario ``mag_anomaly`` with
ArduPilot-like magnitudes — a ground anomaly of (12, −8, 15) µT NED decaying
to 1/8 at 3 m, motor interference (−0.4, 0.2, 0.5) µT/A at 28 A in hover
(``arducopter_magnetic``'s SIM_MAG_MOT) — 200 s, written to a temporary
folder and deleted.  Also printed per flight: how long and until when the
status said "heading unknown: compass disturbed" (the replay header's note,
model on).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from _sibling import load_script  # noqa: E402

from mavahrs.evaluation.tlogdata import interpolate_attitude  # noqa: E402
from mavahrs.filters.best import BestSettings  # noqa: E402
from mavahrs.filters.eskf import EskfSettings  # noqa: E402
from mavahrs.filters.magfield import HEADING_UNKNOWN_TEXT, MagFieldSettings  # noqa: E402
from mavahrs.replay import ReplaySettings, attitude_at_reference, replay  # noqa: E402

_sitl = load_script("bench_sitl")

SHARED = REPO.parent / "shared" / "data" / "sitl" / "arducopter_magnetic.tlog"
VARIANTS = ("as-is", "receiver-only")
SIM_ARGS = ("--scenario", "mag_anomaly", "--duration", "200", "--mag-anomaly-ut", "12,-8,15",
            "--mag-anomaly-height-m", "3", "--mag-motor-ut-per-a=-0.4,0.2,0.5", "--hover-current-a", "28")  # fmt: skip
OFF = BestSettings(eskf=EskfSettings(mag_model=MagFieldSettings(enabled=False)))


def _score(res, name: str, skip_s: float) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    truth = next(k for k in res.references if "truth" in k)
    t_ref, q_ref = res.references[truth]
    start = float(res.inputs.t_us[0]) + skip_s * 1e6
    if name.startswith("autopilot"):
        t_a, q_a = res.references[name]
        q = interpolate_attitude(t_a, q_a, t_ref, max_gap_s=0.5)
    else:
        q = attitude_at_reference(res, name, truth)
    inc, head, _ = _sitl.score(t_ref, q, t_ref, q_ref, start)
    return inc, head


def run(path: Path, skip_s: float) -> dict[str, object]:
    on = replay(path, ReplaySettings(filters=("best",)))
    off = replay(path, ReplaySettings(filters=("best",), filter_settings={"best": OFF}))
    out: dict[str, object] = {
        "best (default, model on)": _score(on, "best", skip_s),
        "best, model off": _score(off, "best", skip_s),
    }
    if "autopilot ATTITUDE" in on.references:
        out["autopilot ATTITUDE"] = _score(on, "autopilot ATTITUDE", skip_s)
    unknown = [n for n in on.notes if n.startswith("best: ") and HEADING_UNKNOWN_TEXT in n]
    out["heading unknown"] = unknown[0].split("for ", 1)[1] if unknown else "never"
    cur = on.inputs.rows[:, 14]
    out["current"] = "yes" if np.isfinite(cur).any() else "none"
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--sim-seeds", nargs="*", type=int, default=[3, 11])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--skip", type=float, default=10.0)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    results: dict[str, dict[str, object]] = {}
    with tempfile.TemporaryDirectory(prefix="mavahrs-mag-") as tmp:
        logs = list(args.logs) or ([SHARED] if SHARED.exists() else [])
        for seed in args.sim_seeds:
            p = Path(tmp) / f"mag_anomaly_seed{seed}.tlog"
            subprocess.run([sys.executable, "-m", "firmware_sim", *SIM_ARGS, "--seed", str(seed), "--tlog", str(p),
                            "--fast"], check=True, cwd=REPO, stdout=subprocess.DEVNULL)  # fmt: skip
            logs.append(p)
        for variant in args.variants:
            for log in logs:
                path = _sitl.write_variant(log, variant, Path(tmp))
                if path is None:
                    continue
                key = f"{log.stem} [{variant}]"
                results[key] = run(path, args.skip)
                r = results[key]
                cells = " | ".join(
                    f"{n}: {v[0]:.2f} / {v[1]:.2f}" for n, v in r.items() if isinstance(v, tuple)
                )
                print(f"{key} (current: {r['current']}) | {cells} | heading unknown: {r['heading unknown']}", flush=True)
                if path != log:
                    path.unlink()
    print("\n(inclination / heading RMS, degrees; truth SIMSTATE / HIL_STATE_QUATERNION; first "
          f"{args.skip:g} s left out)")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
