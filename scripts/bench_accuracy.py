#!/usr/bin/env python3
"""Accuracy of every mavahrs filter, ``best`` and the reference libraries on the BROAD trials.

Usage::

    python3 scripts/bench_accuracy.py                 # all filters, all references found
    python3 scripts/bench_accuracy.py --data DIR      # another folder of BROAD .mat trials
    python3 scripts/bench_accuracy.py --json out.json # also write the figures for machines
    python3 scripts/bench_accuracy.py --references vqf imufusion   # skip the slow ``ahrs``

Scoring is BROAD's (Laidig et al. 2021, ``../shared/data/README.md``): the
error quaternion e = q_est ⊗ q_ref*, total 2·acos|w|, heading 2·atan|z/w|,
inclination 2·acos√(w²+z²); per trial the RMS over the scored movement phase
(``movement == 1``, valid reference), then plain means over trials and groups.
One setting per filter for all trials, its defaults (``best``: the project's
recommendation).  9-axis heading is comparable directly (the reference's north
is the magnetometer's); for 6-axis only the inclination is reported.

Reference libraries (the ``bench`` extra; each skipped with a note when not
importable), all causal and at their defaults:

* VQF — ``vqf.VQF(Ts).updateBatch`` (not ``offlineVQF``); ENU earth frame;
* imufusion — ``imufusion.Ahrs()`` per sample (gyro °/s, accelerometer g);
  left at its default NWU convention (imufusion 1.3.3 ignores
  ``AhrsSettings(convention=...)``) and converted;
* ahrs — ``ahrs.filters.Madgwick`` (default gains 0.041 MARG / 0.033 IMU);
  NWU.  It skips the whole update when the gyro is exactly zero, so such
  samples get a 1e-12 rad/s gyro (counted in the output).  Slow (pure Python,
  ≈ 4 min for all trials).

All quaternions are converted to NED with
:func:`mavahrs.geometry.frames.convert_earth_frame` before scoring; the body
frame stays the IMU's (no FRD remap), as the dataset's README prescribes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(REPO))

from mavahrs.evaluation.datasets import Recording, find_broad_trials, load_broad_trial  # noqa: E402
from mavahrs.evaluation.metrics import summarize  # noqa: E402
from mavahrs.filters import NAMES, create  # noqa: E402
from mavahrs.filters.base import make_inputs  # noqa: E402
from mavahrs.filters.layout import OUT_Q  # noqa: E402
from mavahrs.geometry.frames import convert_earth_frame  # noqa: E402

DEFAULT_DATA = REPO.parent / "shared" / "data" / "broad"
G_M_S2 = 9.80665

#: (column title, group tag) of the per-group columns; "all" = every trial
GROUPS: tuple[tuple[str, str], ...] = (
    ("all", "all"),
    ("undisturbed", "undisturbed"),
    ("disturbed", "disturbed"),
    ("rotation", "rotation"),
    ("translation", "translation"),
    ("stat.magnet", "stationary_magnet"),
    ("att.magnet", "attached_magnet"),
)

Estimator = Callable[[Recording, bool], np.ndarray]  # (recording, use_mag) -> q_body_to_ned (N, 4)
Describe = Callable[[], str]  # a note on how the estimator was run (read after the runs)


@dataclass
class Result:
    """Per-trial RMS errors (deg) of one estimator: {trial: (total, heading, inclination)}."""

    name: str
    nine: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    six: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    seconds: float = 0.0
    note: str = ""


# ------------------------------------------------------------------ estimators


def mavahrs_estimator(name: str) -> Estimator:
    def run(rec: Recording, use_mag: bool) -> np.ndarray:
        inputs = make_inputs(rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut if use_mag else None, dt_s=rec.dt_s)
        return create(name).run(inputs)[:, OUT_Q : OUT_Q + 4]

    return run


def vqf_estimator() -> tuple[Estimator, Describe]:
    from vqf import VQF  # bench extra

    cache: dict[str, dict[str, np.ndarray]] = {}

    def run(rec: Recording, use_mag: bool) -> np.ndarray:
        if rec.name not in cache:  # one causal run gives both: quat6D never uses the magnetometer
            v = VQF(float(rec.dt_s[0]))
            cache.clear()
            cache[rec.name] = v.updateBatch(
                np.ascontiguousarray(rec.gyro_rad_s),
                np.ascontiguousarray(rec.accel_m_s2),
                np.ascontiguousarray(rec.mag_ut),
            )
        q_enu = cache[rec.name]["quat9D" if use_mag else "quat6D"]
        return convert_earth_frame(q_enu, "ENU", "NED")

    return run, lambda: "VQF(Ts).updateBatch, defaults, ENU→NED"


def imufusion_estimator() -> tuple[Estimator, Describe]:
    import imufusion  # bench extra

    def run(rec: Recording, use_mag: bool) -> np.ndarray:
        ahrs = imufusion.Ahrs()  # defaults; convention NWU (the default, left alone)
        ahrs.set_sample_period(float(rec.dt_s[0]))
        gyro_deg_s = np.degrees(rec.gyro_rad_s)
        accel_g = rec.accel_m_s2 / G_M_S2
        q = np.empty((rec.n, 4))
        if use_mag:
            for i in range(rec.n):
                ahrs.update(gyro_deg_s[i], accel_g[i], rec.mag_ut[i])
                q[i] = ahrs.get_quaternion()
        else:
            for i in range(rec.n):
                ahrs.update_no_magnetometer(gyro_deg_s[i], accel_g[i])
                q[i] = ahrs.get_quaternion()
        return convert_earth_frame(q, "NWU", "NED")

    return run, lambda: "imufusion.Ahrs() defaults, NWU→NED"


def ahrs_estimator() -> tuple[Estimator, Describe]:
    from ahrs.filters import Madgwick  # bench extra

    zero_rows = {"n": 0}

    def run(rec: Recording, use_mag: bool) -> np.ndarray:
        gyro = rec.gyro_rad_s.copy()
        zero = ~np.any(gyro != 0.0, axis=1)
        zero_rows["n"] += int(zero.sum())
        gyro[zero] = 1e-12  # ahrs skips the whole update (accelerometer too) on an exactly zero gyro
        f = 1.0 / float(rec.dt_s[0])
        m = Madgwick(gyr=gyro, acc=rec.accel_m_s2, mag=rec.mag_ut, frequency=f) if use_mag else Madgwick(
            gyr=gyro, acc=rec.accel_m_s2, frequency=f
        )
        return convert_earth_frame(m.Q, "NWU", "NED")

    return run, lambda: f"ahrs.filters.Madgwick defaults, NWU→NED; exactly-zero gyro rows patched: {zero_rows['n']}"


REFERENCES: dict[str, Callable[[], tuple[Estimator, Describe]]] = {
    "vqf": vqf_estimator,
    "imufusion": imufusion_estimator,
    "ahrs": ahrs_estimator,
}


# ------------------------------------------------------------------ scoring and tables


def score(name: str, est: Estimator, recs: list[Recording], note: str = "", six_axis: bool = True) -> Result:
    res = Result(name, note=note)
    t0 = time.perf_counter()
    for rec in recs:
        for use_mag, table in ((True, res.nine), (False, res.six)):
            if not use_mag and not six_axis:
                continue
            q = est(rec, use_mag)
            s = summarize(q, rec.q_ref_body_to_ned, rec.scored)
            table[rec.name] = (s.total_rms_deg, s.heading_rms_deg, s.inclination_rms_deg)
        print(f"  {name:14s} {rec.name}", file=sys.stderr, flush=True)
    res.seconds = time.perf_counter() - t0
    return res


def group_means(per_trial: dict[str, tuple[float, float, float]], recs: list[Recording]) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    for title, tag in GROUPS:
        rows = [per_trial[r.name] for r in recs if r.name in per_trial and (tag == "all" or tag in r.groups)]
        if rows:
            out[title] = [float(x) for x in np.mean(np.array(rows), axis=0)]
    return out


def format_tables(results: list[Result], recs: list[Recording]) -> str:
    lines = []
    titles = [t for t, _ in GROUPS]
    counts = {t: sum(1 for r in recs if tag == "all" or tag in r.groups) for t, tag in GROUPS}
    head = f"{'filter':14s} " + " ".join(f"{t + f' ({counts[t]})':>17s}" for t in titles)
    lines.append("9-axis, mean over trials of the per-trial RMS error, degrees: total / heading / inclination")
    lines.append(head)
    lines.append("-" * len(head))
    for r in results:
        g = group_means(r.nine, recs)
        cells = [f"{g[t][0]:5.2f}/{g[t][1]:5.2f}/{g[t][2]:4.2f}" if t in g else "-" for t in titles]
        lines.append(f"{r.name:14s} " + " ".join(f"{c:>17s}" for c in cells))
    lines.append("")
    lines.append("6-axis (no magnetometer), inclination only, degrees")
    head6 = f"{'filter':14s} " + " ".join(f"{t:>12s}" for t in titles)
    lines.append(head6)
    lines.append("-" * len(head6))
    for r in results:
        if not r.six:
            continue
        g = group_means(r.six, recs)
        lines.append(f"{r.name:14s} " + " ".join(f"{g[t][2]:12.2f}" if t in g else f"{'-':>12s}" for t in titles))
    lines.append("")
    lines.append("per trial, 9-axis total / heading / inclination, degrees")
    names = [r.name for r in results]
    lines.append(f"{'trial':46s} " + " ".join(f"{n[:14]:>16s}" for n in names))
    for rec in recs:
        cells = []
        for r in results:
            v = r.nine.get(rec.name)
            cells.append(f"{v[0]:4.1f}/{v[1]:4.1f}/{v[2]:3.1f}" if v else "-")
        lines.append(f"{rec.name[:46]:46s} " + " ".join(f"{c:>16s}" for c in cells))
    notes = [f"  {r.name}: {r.note} ({r.seconds:.1f} s)" for r in results]
    lines.append("")
    lines.append("runs:")
    lines.extend(notes)
    return "\n".join(lines)


def to_json(results: list[Result], recs: list[Recording], data_dir: Path) -> dict[str, object]:
    return {
        "data": str(data_dir),
        "metric": "BROAD: mean over trials of per-trial RMS (deg) over movement==1 with valid reference",
        "trials": {r.name: list(r.groups) for r in recs},
        "results": {
            r.name: {
                "note": r.note,
                "seconds": r.seconds,
                "9axis": {"per_trial": r.nine, "groups": group_means(r.nine, recs)},
                "6axis": {"per_trial": r.six, "groups": group_means(r.six, recs)},
            }
            for r in results
        },
    }


# ------------------------------------------------------------------ main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help=f"folder of BROAD .mat trials (default {DEFAULT_DATA})")
    ap.add_argument("--json", type=Path, help="also write the results as JSON to this file ('-' = stdout)")
    ap.add_argument("--filters", nargs="*", default=[*NAMES, "best"], help="mavahrs filters to run (default: all and best)")
    ap.add_argument(
        "--references", nargs="*", default=list(REFERENCES), choices=list(REFERENCES),
        help="reference libraries to run when importable (default: all)",
    )  # fmt: skip
    args = ap.parse_args(argv)

    paths = find_broad_trials(args.data) if args.data.is_dir() else []
    if not paths:
        print(
            f"skipped: no BROAD trials at {args.data} (expected ../shared/data/broad beside the checkout; "
            f"use --data DIR)",
            file=sys.stderr,
        )
        return 0
    recs = [load_broad_trial(p) for p in paths]

    results: list[Result] = []
    for name in args.filters:
        results.append(score(name, mavahrs_estimator(name), recs, note=f"mavahrs {name!r}, default settings"))
    for ref in args.references:
        try:
            est, describe = REFERENCES[ref]()
        except ImportError as exc:
            print(f"note: {ref} not importable ({exc}); install the bench extra: pip install '.[bench]'", file=sys.stderr)
            continue
        res = score(ref, est, recs)
        res.note = describe()
        results.append(res)

    text = format_tables(results, recs)
    print(f"BROAD trials: {len(recs)} in {args.data}")
    print(text)
    if args.json:
        payload = json.dumps(to_json(results, recs, args.data), indent=1)
        if str(args.json) == "-":
            print(payload)
        else:
            args.json.write_text(payload)
    return 0


if __name__ == "__main__":
    sys.exit(main())
