#!/usr/bin/env python3
"""``best``'s BROAD heading per trial for whichever mavahrs is importable: this checkout or an old one.

Usage::

    python3 scripts/bench_broad_history.py                          # this checkout
    git worktree add --detach /tmp/old ec1fcd2~1                    # an old commit, then (its own kernel cache):
    cd /tmp/old && NUMBA_CACHE_DIR=/tmp/old-cache PYTHONPATH=/tmp/old python3 /path/to/scripts/bench_broad_history.py
    python3 scripts/bench_broad_history.py --unaided-filter madgwick   # BestSettings(unaided_filter=...) where it exists

Issue 23's "stationary magnet 1.33°" was measured at 99defd7 (docs/accuracy.md round seven, branch smag5, bisects
it).  BROAD's scoring (``summarize``: heading 2·atan|e_z/e_w| over the scored samples), ``create("best")`` over
``make_inputs`` as ``scripts/bench_accuracy.py`` runs it; only APIs that have not changed since 2026-11 are used, so
the script runs against old checkouts (it puts no path of its own on ``sys.path`` unless mavahrs is not importable).
Prints per trial total / heading / inclination RMS, then one JSON line: the heading means of all 16, the two magnet
groups, round five's choice / held halves (``scripts/bench_broad_compass.py``), and the mean inclination.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

try:
    import mavahrs  # noqa: F401
except ImportError:  # run from a checkout without installing or PYTHONPATH
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mavahrs.evaluation.datasets import find_broad_trials, load_broad_trial  # noqa: E402
from mavahrs.evaluation.metrics import summarize  # noqa: E402
from mavahrs.filters import create  # noqa: E402
from mavahrs.filters.base import make_inputs  # noqa: E402
from mavahrs.filters.layout import OUT_Q  # noqa: E402

DEFAULT_DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "broad"
CHOICE_TRIALS = ("01", "04", "08", "11", "15", "24", "28", "32")  # as scripts/bench_broad_compass.py
HELD_TRIALS = ("02", "06", "10", "14", "18", "26", "30", "34")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--data", type=Path, default=DEFAULT_DATA, help=f"BROAD .mat trials (default {DEFAULT_DATA})"
    )
    ap.add_argument(
        "--unaided-filter", help="BestSettings(unaided_filter=...), e.g. madgwick (where it exists)"
    )
    ap.add_argument("--label", default="", help="a name for the JSON line")
    args = ap.parse_args(argv)
    paths = find_broad_trials(args.data) if args.data.is_dir() else []
    if not paths:
        print(f"skipped: no BROAD trials at {args.data} (use --data DIR)", file=sys.stderr)
        return 0
    settings = None
    if args.unaided_filter:
        from mavahrs.filters.best import BestSettings

        settings = BestSettings(unaided_filter=args.unaided_filter)
    heading, incl = {}, []
    for p in paths:
        r = load_broad_trial(p)
        out = create("best", settings).run(make_inputs(r.gyro_rad_s, r.accel_m_s2, r.mag_ut, dt_s=r.dt_s))
        s = summarize(out[:, OUT_Q : OUT_Q + 4], r.q_ref_body_to_ned, r.scored)
        heading[p.name[:2]] = round(float(s.heading_rms_deg), 3)
        incl.append(float(s.inclination_rms_deg))
        print(
            f"{p.name[:40]:40s} {s.total_rms_deg:6.2f} {s.heading_rms_deg:6.2f} {s.inclination_rms_deg:6.2f}",
            flush=True,
        )

    def mean(keys: tuple[str, ...] | list[str]) -> float:
        return round(float(np.mean([heading[k] for k in keys if k in heading])), 3)

    print(
        json.dumps(
            {
                "label": args.label,
                "all": mean(list(heading)),
                "stationary_magnet": mean(("28", "30")),
                "attached_magnet": mean(("32", "34")),
                "choice": mean(CHOICE_TRIALS),
                "held": mean(HELD_TRIALS),
                "inclination": round(float(np.mean(incl)), 3),
                "heading": heading,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
