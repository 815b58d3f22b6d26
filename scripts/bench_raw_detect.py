#!/usr/bin/env python3
"""Issue 22's raw multirotor through the plain API: ``create("best")`` with nothing declared, beside VQF.

Usage::

    python3 scripts/bench_raw_detect.py --scenarios aggressive hover --seeds 1 2 3 4 --cache /tmp/mvc
    python3 scripts/bench_raw_detect.py --broad            # BROAD raw and 6D/9D: the decision per trial

``firmware_sim`` flights as a research rig's raw IMU reaches the Python API (the raw preset: a
constant gyro bias of up to 5 °/s per axis; x axis up; started in flight; no GNSS, no
magnetometer; 200 Hz; 90 s, scored after 20 s: ``tests/filters/conftest.raw_imu_flight``).  Per
flight: inclination RMS of ``best`` through the plain API, of ``best`` declared a multirotor
(``set_multirotor()``) and of VQF 2.x 6D, and the plain path's decision
(:meth:`mavahrs.filters.best.Best.multirotor_detection`: seconds output as a multirotor, switches).
``--broad``: the 16 BROAD trials 9D / 6D and as a raw IMU (``scripts/bench_estimator.py``'s
``broad-raw``), the plain path's decision per trial (a hand-held sensor must never be taken for a
multirotor).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "filters"))

from mavahrs.evaluation.metrics import summarize  # noqa: E402
from mavahrs.filters import create  # noqa: E402
from mavahrs.filters.layout import OUT_Q  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _cache import code_stamp  # noqa: E402
from _sibling import load_script  # noqa: E402

RATE_HZ = 200
SCORE_AFTER_S = 20.0


def flight(scenario: str, seed: int, cache: Path | None) -> tuple[np.ndarray, np.ndarray]:
    stamp = code_stamp("firmware_sim", "tests/filters/conftest.py")  # the code that simulates the flight
    path = cache / f"raw-{scenario}-{seed}.{stamp}.pkl" if cache is not None else None
    if path is not None and path.exists():
        with path.open("rb") as fh:
            return pickle.load(fh)  # type: ignore[no-any-return]
    from conftest import raw_imu_flight  # tests/filters/conftest.py: the flight the tests use

    rows, q_ref, _bias = raw_imu_flight(scenario, seed)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as fh:
            pickle.dump((rows, q_ref), fh)
    return rows, q_ref


DETECT = True  # --no-detect: the plain path's single ESKF (as before the detection)


def run_best(rows: np.ndarray, declared: bool = False) -> tuple[np.ndarray, dict[str, float]]:
    if DETECT:
        f = create("best")
    else:
        from mavahrs.filters.best import BestSettings, MultirotorDetectSettings

        f = create("best", BestSettings(detect=MultirotorDetectSettings(enabled=False)))
    if declared:
        f.set_multirotor()  # type: ignore[attr-defined]
    out = f.run(rows)
    det = getattr(f, "multirotor_detection", None)
    return out[:, OUT_Q : OUT_Q + 4], (det() if det is not None else {})


def run_vqf(rows: np.ndarray, rate_hz: float) -> np.ndarray:
    mod = load_script("bench_estimator", "_bench_est")
    return mod.run_vqf(rows, rate_hz, use_mag=False)  # type: ignore[no-any-return]


def bench_sim(scenarios: list[str], seeds: list[int], cache: Path | None, declared: bool, vqf: bool) -> dict[str, dict[str, object]]:
    res: dict[str, dict[str, object]] = {}
    for sc in scenarios:
        for seed in seeds:
            rows, q_ref = flight(sc, seed, cache)
            scored = slice(int(RATE_HZ * SCORE_AFTER_S), None)
            r: dict[str, object] = {}
            q, det = run_best(rows)
            r["plain"] = summarize(q[scored], q_ref[scored]).inclination_rms_deg
            r["decision"] = det
            if declared:
                q, _ = run_best(rows, declared=True)
                r["declared"] = summarize(q[scored], q_ref[scored]).inclination_rms_deg
            if vqf:
                q = run_vqf(rows, RATE_HZ)
                r["VQF"] = summarize(q[scored], q_ref[scored]).inclination_rms_deg
            res[f"{sc} {seed}"] = r
            txt = ", ".join(f"{k} {v:.2f}" for k, v in r.items() if isinstance(v, float))
            print(f"{sc} {seed}: {txt}  decision {det}", flush=True)
    return res


def bench_broad() -> dict[str, dict[str, object]]:
    mod = load_script("bench_estimator", "_bench_est")
    from mavahrs.filters.base import make_inputs
    from mavahrs.geometry.quaternion import multiply

    res: dict[str, dict[str, object]] = {}
    for p in mod.find_broad_trials(mod.DATA / "broad"):
        rec = mod.load_broad_trial(p)
        first = int(np.argmax(rec.scored))
        begin = max(0, first - int(round(1.0 / float(rec.dt_s[0]))))
        raw, _ = mod.make_raw(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, None, dt_s=rec.dt_s), rec.name)
        q_raw = multiply(rec.q_ref_body_to_ned[begin:], np.broadcast_to(mod.Q_MOUNT, rec.q_ref_body_to_ned[begin:].shape).copy())
        variants = [
            ("9D", make_inputs(rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut, dt_s=rec.dt_s), rec.q_ref_body_to_ned, rec.scored),
            ("6D", make_inputs(rec.gyro_rad_s, rec.accel_m_s2, None, dt_s=rec.dt_s), rec.q_ref_body_to_ned, rec.scored),
            ("raw", raw[begin:], q_raw, rec.scored[begin:]),
        ]
        r: dict[str, object] = {}
        for tag, rows, q_ref, scored in variants:
            q, det = run_best(rows)
            s = summarize(q, q_ref, scored)
            r[tag] = (s.inclination_rms_deg, s.heading_rms_deg)
            r[f"{tag} decision"] = det
        res[rec.name] = r
        print(f"{rec.name}: " + ", ".join(f"{k} {v}" for k, v in r.items()), flush=True)
    return res


def bench_tstick() -> dict[str, dict[str, object]]:
    """RepoIMU TStick (hand-held, a check set): inclination 9D / 6D and the decision per recording."""
    from mavahrs.evaluation.loaders import load_any
    from mavahrs.filters.base import make_inputs

    res: dict[str, dict[str, object]] = {}
    data = Path(__file__).resolve().parents[2] / "shared" / "data" / "repoimu_tstick"
    for rec in load_any(data):
        r: dict[str, object] = {}
        for tag, mag in (("9D", rec.mag_ut), ("6D", None)):
            q, det = run_best(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, mag, dt_s=rec.dt_s))
            s = summarize(q, rec.q_ref_body_to_ned, rec.scored)
            r[tag] = (s.inclination_rms_deg, s.heading_rms_deg)
            r[f"{tag} decision"] = det
        res[rec.name] = r
        print(f"{rec.name}: " + ", ".join(f"{k} {v}" for k, v in r.items()), flush=True)
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=["aggressive", "hover", "flips", "highg", "vibration"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4])
    ap.add_argument("--cache", type=Path, default=None, help="keep the simulated flights here between runs")
    ap.add_argument("--declared", action="store_true", help="also best with set_multirotor()")
    ap.add_argument("--vqf", action="store_true", help="also VQF 2.x 6D")
    ap.add_argument("--broad", action="store_true", help="the BROAD trials instead (decision per trial)")
    ap.add_argument("--tstick", action="store_true", help="RepoIMU TStick instead (decision per recording)")
    ap.add_argument("--no-detect", action="store_true", help="the plain path without the multirotor hypothesis")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    global DETECT
    DETECT = not a.no_detect
    if a.broad:
        res = bench_broad()
    elif a.tstick:
        res = bench_tstick()
    else:
        res = bench_sim(a.scenarios, a.seeds, a.cache, a.declared, a.vqf)
        for sc in a.scenarios:
            for key in ("plain", "declared", "VQF"):
                v = [float(r[key]) for n, r in res.items() if n.split()[0] == sc and key in r]  # type: ignore[arg-type]
                if v:
                    print(f"{sc} {key}: mean {np.mean(v):.2f} ({' / '.join(f'{x:.2f}' for x in v)})")
    if a.json is not None:
        a.json.write_text(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
