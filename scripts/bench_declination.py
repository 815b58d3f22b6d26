#!/usr/bin/env python3
"""The learnt declination (``EskfSettings.declination_sigma_rad``): ``best`` with it and with the WMM's taken as exact.

Usage::

    python3 scripts/bench_declination.py                      # the shared SITL (ArduPilot, PX4) flights
    python3 scripts/bench_declination.py FLIGHT.tlog|.BIN ... # other flights with a truth (SIMSTATE, …)
    python3 scripts/bench_declination.py --sigma-deg 1 2      # other prior σ
    python3 scripts/bench_declination.py --variants receiver-only no-gnss   # tlogs with messages removed

Each flight is replayed (:func:`mavahrs.replay.replay`) with ``best`` as
configured and with ``declination_sigma_rad = 0`` (the WMM's declination
exact, the behaviour before the state existed), scored as
``scripts/bench_mag.py`` scores (inclination / heading RMS against the truth,
first ``--skip`` s left out, heading against true north), beside the
autopilot's own estimate, with the mean heading error (signed, °: a
constant offset shows here).  ``--variants`` as ``scripts/bench_sitl.py``'s
(tlogs only; ``no-gnss``: the prior must hold, both rows alike).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from _sibling import load_script  # noqa: E402

from mavahrs.filters.best import BestSettings  # noqa: E402
from mavahrs.replay import ReplaySettings, attitude_at_reference, replay  # noqa: E402

_mag = load_script("bench_mag")

DATA = REPO.parent / "shared" / "data"
DEFAULT_LOGS = (
    *sorted((DATA / "sitl").glob("*.tlog")), DATA / "sitl" / "arducopter_onboard.BIN", DATA / "px4_sitl" / "px4_aggressive.tlog",
)  # fmt: skip


def _mean_heading_error(res, skip_s: float) -> float:  # type: ignore[no-untyped-def]
    """Signed mean heading error of ``best`` against the truth, degrees (yaw of q_est ⊗ q_ref*)."""
    truth = next(k for k in res.references if "truth" in k)
    t_ref, q_ref = res.references[truth]
    q = attitude_at_reference(res, "best", truth)
    keep = (t_ref >= float(res.inputs.t_us[0]) + skip_s * 1e6) & np.isfinite(q[:, 0])
    a, b = q[keep], q_ref[keep]
    # e = a ⊗ b*, heading 2·atan(e_z / e_w)
    w = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2] + a[:, 3] * b[:, 3]
    z = -a[:, 0] * b[:, 3] + a[:, 3] * b[:, 0] - a[:, 1] * b[:, 2] + a[:, 2] * b[:, 1]
    return math.degrees(float(np.mean(2.0 * np.arctan(z / w))))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--sigma-deg", nargs="+", type=float, default=[None], help="prior σ (default: best's own)")
    ap.add_argument("--skip", type=float, default=10.0)
    ap.add_argument("--variants", nargs="+", default=["as-is"], choices=_mag._sitl.VARIANTS)
    args = ap.parse_args(argv)
    logs = args.logs or [p for p in DEFAULT_LOGS if p.exists()]
    with tempfile.TemporaryDirectory(prefix="mavahrs-decl-") as tmp:
        for variant in args.variants:
            for src in logs:
                log = src if variant == "as-is" or src.suffix != ".tlog" else _mag._sitl.write_variant(src, variant, Path(tmp))
                if log is None or (variant != "as-is" and log == src):
                    continue
                _one(log, f"{src.parent.name}/{src.name} [{variant}]", args)
    print(f"\n(inclination / heading RMS, degrees, first {args.skip:g} s left out; mean: signed heading error; "
          "against the truth)")  # fmt: skip
    return 0


def _one(log: Path, label: str, args: argparse.Namespace) -> None:
    base = BestSettings()
    cells = []
    runs: list[tuple[str, float | None]] = [("WMM exact", 0.0)] + [
        (f"σ {'default' if s is None else f'{s:g}°'}", s) for s in args.sigma_deg
    ]
    auto = None
    for name, sigma in runs:
        eskf = base.eskf if sigma is None else dataclasses.replace(base.eskf, declination_sigma_rad=math.radians(sigma))
        res = replay(log, ReplaySettings(filters=("best",), filter_settings={"best": dataclasses.replace(base, eskf=eskf)}))
        inc, head = _mag._score(res, "best", args.skip)
        mean = _mean_heading_error(res, args.skip)
        cells.append(f"{name}: {inc:.2f} / {head:.2f} (mean {mean:+.2f})")
        if auto is None and "autopilot ATTITUDE" in res.references:
            auto = _mag._score(res, "autopilot ATTITUDE", args.skip)
    ap_cell = f" | autopilot {auto[0]:.2f} / {auto[1]:.2f}" if auto else ""
    print(f"{label} | " + " | ".join(cells) + ap_cell, flush=True)


if __name__ == "__main__":
    sys.exit(main())
