#!/usr/bin/env python3
"""`best` in every condition: with and without GNSS, a raw biased IMU, PX4 — beside VQF and the autopilot's EKF.

Usage::

    python3 scripts/bench_estimator.py                          # every data set (≈ 10 min on one core)
    python3 scripts/bench_estimator.py --sets sitl-nognss broad-raw
    python3 scripts/bench_estimator.py --filters best eskf madgwick mahony --json out.json
    python3 scripts/bench_estimator.py --cache /tmp/mavahrs-bench   # keep the decoded logs between runs

Data sets (all from ``../shared/data``; one setting per filter for all of them):

* ``sitl`` — the ArduCopter SITL tlogs as recorded (GNSS velocity from
  GLOBAL_POSITION_INT), beside the autopilot's EKF3 (ATTITUDE);
* ``sitl-nognss`` — the same flights with every GNSS message removed (as
  ``scripts/bench_sitl.py --variants no-gnss``); the EKF3 row is the autopilot's
  own estimate *with* its GNSS, for scale;
* ``sitl-raw`` — the no-GNSS flights made into a raw IMU: no magnetometer, a
  constant gyro bias of 1–5 °/s per axis (random sign, a different draw per
  flight, seed 22), the IMU mounted with its x axis up (rotated 90° about its
  y axis), and the first 20 s of the log cut so that the filters start in
  flight without a rest period;
* ``sitl-vib`` — the raw set as a real multirotor's IMU fed through the Python API,
  the way a research rig's log reaches ``create("best")``: decimated to 200 Hz,
  rotor vibration added (per axis an aliased rotor tone that wanders over
  20–90 Hz plus white noise: accelerometer ≈ 1.5 m/s² RMS, gyro ≈ 2 °/s RMS;
  seeded by the flight's name) and *not* declared a multirotor (no
  ``set_multirotor()``): the conditions of real indoor flights with a raw
  MEMS IMU, which the SITL simulator (no sensor noise) does not have (a row
  ``best, set_multirotor()`` beside it: the same user declaring the multirotor);
* ``broad`` — the 16 BROAD trials, 9-axis (inclination and heading) and
  6-axis (inclination);
* ``broad-raw`` — BROAD 6-axis with a constant gyro bias as above (a draw per
  trial), the IMU rotated as above and each trial cut to start 1 s before its
  first scored movement (no initial rest to learn the bias from);
* ``px4`` — the PX4 SITL (SIH) flight, GNSS, beside PX4's EKF2 (ATTITUDE),
  truth HIL_STATE_QUATERNION.

Every filter is fed the input rows the daemon builds (:func:`mavahrs.replay.replay`'s
decoding, scaling and timeline; the sensor delay and, for an autopilot's
stream, ``best``'s vehicle mode and, for a multirotor, the rotor-drag model
are set as the pipeline sets them; the raw-IMU sets stand for a sensor fed
through the Python API, without the first two: a user who knows the IMU flies
on a multirotor calls ``set_multirotor()``, which ``sitl-raw`` does and
``broad-raw`` does not) and scored against the truth as ``scripts/bench_sitl.py``
does (estimates slerped onto the truth's times, the first 10 s of each log
left out; BROAD: its own scoring, movement phases).  VQF 2.x (``vqf.VQF``,
defaults, sample by sample at the log's mean rate; 9-axis where a magnetometer
is fed, else 6-axis) runs on the same rows in the same run.  Figures:
inclination / heading RMS, degrees (heading only where it means something).
"""

from __future__ import annotations

import argparse
import json
import math
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(REPO))

from mavahrs.evaluation.datasets import find_broad_trials, load_broad_trial  # noqa: E402
from mavahrs.evaluation.metrics import summarize  # noqa: E402
from mavahrs.evaluation.tlogdata import interpolate_attitude  # noqa: E402
from mavahrs.filters import create  # noqa: E402
from mavahrs.filters.base import make_inputs  # noqa: E402
from mavahrs.filters.layout import (  # noqa: E402
    FLAG_NOT_INITIALISED,
    IN_ACCEL,
    IN_GYRO,
    IN_MAG,
    OUT_FLAGS,
    OUT_Q,
)
from mavahrs.geometry.frames import convert_earth_frame  # noqa: E402
from mavahrs.geometry.quaternion import multiply  # noqa: E402
from mavahrs.replay import ReplaySettings, replay  # noqa: E402
from mavahrs.sensors.profiles import get_profile  # noqa: E402

sys.path.insert(0, str(REPO / "scripts"))
from _cache import code_stamp, file_stamp  # noqa: E402
from _sibling import load_script  # noqa: E402

_sitl = load_script("bench_sitl")  # write_variant (GNSS removal)

DATA = REPO.parent / "shared" / "data"
SETS = ("sitl", "sitl-nognss", "sitl-raw", "sitl-vib", "broad", "broad-raw", "px4")
SKIP_S = 10.0
RAW_CUT_S = 20.0
#: body (x up) → IMU: the raw IMU is mounted rotated 90° about the vehicle's y axis
Q_MOUNT = np.array([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])
REFS = ("vqf",)


# ------------------------------------------------------------------ raw-IMU construction


def draw_bias_rad_s(name: str) -> np.ndarray:
    """A constant gyro bias, 1–5 °/s per axis with a random sign, drawn from the name (seed 22)."""
    seed = 22 + sum(ord(c) * (i + 1) for i, c in enumerate(name))
    rng = np.random.default_rng(seed)
    return np.radians(rng.uniform(1.0, 5.0, 3) * rng.choice([-1.0, 1.0], 3))


def rotate_vectors(v: np.ndarray, q: np.ndarray) -> np.ndarray:
    """v expressed in the frame that q maps to the original one: R(q)ᵀ v (rows)."""
    w, x, y, z = q
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    return v @ r  # (R^T v^T)^T = v R


def make_raw(rows: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """rows → a raw IMU's rows (bias added, frame rotated, no magnetometer, no velocity); also the bias."""
    out = rows.copy()
    bias = draw_bias_rad_s(name)
    out[:, IN_GYRO : IN_GYRO + 3] = rotate_vectors(rows[:, IN_GYRO : IN_GYRO + 3], Q_MOUNT) + bias
    out[:, IN_ACCEL : IN_ACCEL + 3] = rotate_vectors(rows[:, IN_ACCEL : IN_ACCEL + 3], Q_MOUNT)
    out[:, IN_MAG:] = np.nan  # no magnetometer, no velocity (IN_VEL, IN_VEL_AGE follow IN_MAG)
    return out, bias


VIB_RATE_HZ = 200.0
#: RMS of the added vibration: accelerometer m/s², gyro rad/s (tone and white noise share it equally)
VIB_ACCEL_M_S2 = 1.5
VIB_GYRO_RAD_S = math.radians(2.0)


def make_vibrating(rows: np.ndarray, t_us: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Raw rows → a vibrating 200 Hz IMU's rows and which rows were kept: decimated, tone + white noise added."""
    keep = np.zeros(len(t_us), bool)
    last = -np.inf
    period_us = 1e6 / VIB_RATE_HZ * 0.9
    for i, t in enumerate(t_us):  # the first sample at least a (nearly) whole period after the last kept
        if t - last >= period_us:
            keep[i] = True
            last = t
    t = t_us[keep]
    out = rows[keep].copy()
    out[1:, 0] = np.diff(t) * 1e-6  # IN_DT: the interval before each kept sample
    rng = np.random.default_rng(7 + sum(ord(c) * (i + 1) for i, c in enumerate(name)))
    ts = (t - t[0]) * 1e-6
    n = len(t)
    for base, rms in ((IN_ACCEL, VIB_ACCEL_M_S2), (IN_GYRO, VIB_GYRO_RAD_S)):
        for c in range(3):
            # an aliased rotor tone whose frequency wanders with the throttle (20–90 Hz), then white noise
            f_hz = 55.0 + 35.0 * np.sin(2 * np.pi * ts / rng.uniform(8.0, 20.0) + rng.uniform(0, 2 * np.pi))
            phase = 2 * np.pi * np.cumsum(f_hz * np.r_[0.0, np.diff(ts)]) + rng.uniform(0, 2 * np.pi)
            out[:, base + c] += rms * np.sin(phase) + rms / math.sqrt(2.0) * rng.standard_normal(n)
    return out, keep


# ------------------------------------------------------------------ logs


def load_log(path: Path, variant: str, cache: Path | None) -> dict[str, object]:
    """The input rows the daemon builds from a log (variant: as-is / no-gnss), its truth and autopilot estimates."""
    # named by the log and the code that decodes it (mavahrs outside the filters, which only run on the rows)
    key = (cache / f"{path.stem}.{variant}.{file_stamp(path)}.{code_stamp('mavahrs', exclude=('mavahrs/filters',))}.pkl"
           if cache else None)  # fmt: skip
    if key is not None and key.exists():
        return pickle.loads(key.read_bytes())
    with tempfile.TemporaryDirectory(prefix="mavahrs-est-") as tmp:
        src = _sitl.write_variant(path, variant, Path(tmp))
        assert src is not None
        res = replay(src, ReplaySettings(filters=("madgwick",)))
    truth = next(k for k in res.references if "truth" in k)
    profile = get_profile(res.inputs.profile)
    ms = profile.scale_for(res.inputs.message)
    d: dict[str, object] = {
        "rows": res.inputs.rows,
        "t_us": res.inputs.t_us.astype(np.float64),
        "decl": res.inputs.declination_rad,
        "truth": res.references[truth],
        "autopilot": res.references.get("autopilot ATTITUDE"),
        "delay_s": 0.0 if ms is None else ms.delay_s,
    }
    if key is not None:
        key.parent.mkdir(parents=True, exist_ok=True)
        key.write_bytes(pickle.dumps(d))
    return d


def _declinate(q: np.ndarray, decl: np.ndarray) -> np.ndarray:
    h = 0.5 * decl
    return multiply(np.stack([np.cos(h), 0 * h, 0 * h, np.sin(h)], axis=1), q)


def run_filter(name: str, rows: np.ndarray, delay_s: float = 0.0, vehicle: bool = False,
               multirotor: bool = False) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``name`` on ``rows``; ``delay_s``, ``vehicle`` (an autopilot's stream) and ``multirotor`` (its
    HEARTBEAT's type, or a Python API user's ``set_multirotor()``) set as the pipeline sets them."""
    f = create(name)
    set_multirotor = getattr(f, "set_multirotor", None)
    if set_multirotor is not None and multirotor:
        set_multirotor()
    set_delay = getattr(f, "set_sensor_delay", None)
    if set_delay is not None and delay_s > 0.0:
        set_delay(delay_s)
    set_vehicle = getattr(f, "set_vehicle_stream", None)
    if set_vehicle is not None and vehicle:
        set_vehicle()
    out = f.run(rows)
    init = (out[:, OUT_FLAGS].astype(np.int64) & FLAG_NOT_INITIALISED) == 0
    return out[:, OUT_Q : OUT_Q + 4], init


def run_vqf(rows: np.ndarray, rate_hz: float, use_mag: bool) -> np.ndarray:
    from vqf import VQF  # bench extra

    v = VQF(1.0 / rate_hz)
    gyr = np.ascontiguousarray(rows[:, IN_GYRO : IN_GYRO + 3])
    acc = np.ascontiguousarray(rows[:, IN_ACCEL : IN_ACCEL + 3])
    if use_mag:
        mag = rows[:, IN_MAG : IN_MAG + 3].copy()
        have = np.all(np.isfinite(mag), axis=1)
        idx = np.maximum.accumulate(np.where(have, np.arange(len(mag)), int(np.argmax(have))))
        mag = np.ascontiguousarray(np.where(have[:, None], mag, mag[idx]))
        q = v.updateBatch(gyr, acc, mag)["quat9D"]
    else:
        q = v.updateBatch(gyr, acc)["quat6D"]
    return convert_earth_frame(q, "ENU", "NED")


def score_log(t: np.ndarray, q: np.ndarray, ok: np.ndarray, t_ref: np.ndarray, q_ref: np.ndarray,
              start_us: float) -> tuple[float, float]:  # fmt: skip
    qi = interpolate_attitude(t[ok], q[ok], t_ref, max_gap_s=0.5)
    keep = (t_ref >= start_us) & np.all(np.isfinite(qi), axis=1) & np.all(np.isfinite(q_ref), axis=1)
    s = summarize(qi[keep], q_ref[keep])
    return s.inclination_rms_deg, s.heading_rms_deg


def bench_logs(kind: str, filters: list[str], refs: list[str], cache: Path | None) -> dict[str, dict[str, tuple[float, float]]]:
    if kind == "px4":
        logs = sorted((DATA / "px4_sitl").glob("*.tlog"))
    else:
        logs = sorted((DATA / "sitl").glob("*.tlog"))
    variant = "as-is" if kind in ("sitl", "px4") else "no-gnss"
    raw = kind in ("sitl-raw", "sitl-vib")
    results: dict[str, dict[str, tuple[float, float]]] = {}
    for log in logs:
        d = load_log(log, variant, cache)
        rows, t = d["rows"], d["t_us"]
        t_ref, q_ref = d["truth"]
        assert isinstance(rows, np.ndarray) and isinstance(t, np.ndarray)
        decl = np.asarray(d["decl"])
        start = float(t[0]) + SKIP_S * 1e6
        delay = float(d["delay_s"])  # type: ignore[arg-type]
        if raw:
            rows, _bias = make_raw(rows, log.stem)
            cut = t >= t[0] + RAW_CUT_S * 1e6
            rows, t, decl = rows[cut], t[cut], decl[cut]
            if kind == "sitl-vib":
                rows, keep = make_vibrating(rows, t, log.stem)
                t, decl = t[keep], decl[keep]
            start = float(t[0]) + SKIP_S * 1e6
            q_ref = multiply(q_ref, np.broadcast_to(Q_MOUNT, q_ref.shape).copy())
            delay = 0.0  # a raw IMU: no autopilot low-pass
        r: dict[str, tuple[float, float]] = {}
        for name in filters:
            # every log is a quadrotor's: as the pipeline knows from its HEARTBEAT, or as an API user who
            # calls set_multirotor() (sitl-raw); sitl-vib is the plain API
            q, ok = run_filter(name, rows, delay, vehicle=not raw, multirotor=kind != "sitl-vib")
            r[name] = score_log(t, _declinate(q, decl), ok, t_ref, q_ref, start)
        if kind == "sitl-vib" and "best" in filters:  # beside it: the API user who declares the multirotor
            q, ok = run_filter("best", rows, delay, multirotor=True)
            r["best, set_multirotor()"] = score_log(t, _declinate(q, decl), ok, t_ref, q_ref, start)
        rate = 1e6 * (len(t) - 1) / float(t[-1] - t[0])
        for ref in refs:
            try:
                q = run_vqf(rows, rate, use_mag=not raw)
            except ImportError as exc:
                print(f"  {ref}: not importable ({exc}); pip install '.[bench]'", file=sys.stderr)
                continue
            ok = np.all(np.isfinite(q), axis=1)
            r["VQF" + (" 6D" if raw else " 9D")] = score_log(t, _declinate(q, decl), ok, t_ref, q_ref, start)
        ap = d["autopilot"]
        if ap is not None and not raw:
            t_a, q_a = ap  # type: ignore[misc]
            label = "EKF2 (ATTITUDE)" if kind == "px4" else "EKF3 (ATTITUDE" + (", with GNSS)" if variant != "as-is" else ")")
            r[label] = score_log(np.asarray(t_a), np.asarray(q_a), np.ones(len(t_a), bool), t_ref, q_ref, start)
        results[log.stem] = r
        print(f"  {kind} {log.stem}: " + ", ".join(f"{k} {v[0]:.2f}" for k, v in r.items()), file=sys.stderr, flush=True)
    return results


def bench_broad(kind: str, filters: list[str], refs: list[str]) -> dict[str, dict[str, tuple[float, float]]]:
    paths = find_broad_trials(DATA / "broad")
    results: dict[str, dict[str, tuple[float, float]]] = {}
    for p in paths:
        rec = load_broad_trial(p)
        r: dict[str, tuple[float, float]] = {}
        q_ref, scored = rec.q_ref_body_to_ned, rec.scored
        if kind == "broad":
            variants = [("9D", make_inputs(rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut, dt_s=rec.dt_s)),
                        ("6D", make_inputs(rec.gyro_rad_s, rec.accel_m_s2, None, dt_s=rec.dt_s))]  # fmt: skip
        else:
            first = int(np.argmax(scored))
            begin = max(0, first - int(round(1.0 / float(rec.dt_s[0]))))
            rows, _bias = make_raw(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, None, dt_s=rec.dt_s), rec.name)
            rows = rows[begin:]
            q_ref = multiply(q_ref[begin:], np.broadcast_to(Q_MOUNT, q_ref[begin:].shape).copy())
            scored = scored[begin:]
            variants = [("6D", rows)]
        for tag, rows in variants:
            for name in filters:
                q, _ok = run_filter(name, rows)
                s = summarize(q, q_ref, scored)
                r[f"{name} {tag}"] = (s.inclination_rms_deg, s.heading_rms_deg)
            for _ref in refs:
                try:
                    q = run_vqf(rows, 1.0 / float(rec.dt_s[0]), use_mag=tag == "9D")
                except ImportError:
                    continue
                s = summarize(q, q_ref, scored)
                r[f"VQF {tag}"] = (s.inclination_rms_deg, s.heading_rms_deg)
        results[rec.name] = r
        print(f"  {kind} {rec.name}: " + ", ".join(f"{k} {v[0]:.2f}" for k, v in r.items()), file=sys.stderr, flush=True)
    return results


# ------------------------------------------------------------------ tables


def table(kind: str, results: dict[str, dict[str, tuple[float, float]]], heading: bool) -> str:
    names: list[str] = []
    for r in results.values():
        names += [n for n in r if n not in names]
    many = len(results) > 6
    cols = ["mean", "worst"] if many else [*results, "mean"]
    lines = [f"| {kind} | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for n in names:
        vals = np.array([r[n] for r in results.values() if n in r])
        cells = []
        if many:
            cells = [f"{vals[:, 0].mean():.2f}" + (f" / {vals[:, 1].mean():.2f}" if heading else ""),
                     f"{vals[:, 0].max():.2f}"]  # fmt: skip
        else:
            for log in results:
                v = results[log].get(n)
                cells.append("–" if v is None else f"{v[0]:.2f}" + (f" / {v[1]:.2f}" if heading else ""))
            cells.append(f"{vals[:, 0].mean():.2f}" + (f" / {vals[:, 1].mean():.2f}" if heading else ""))
        lines.append(f"| {'**' + n + '**' if n.startswith('best') else n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", nargs="+", default=list(SETS), choices=SETS)
    ap.add_argument("--filters", nargs="+", default=["best", "eskf", "madgwick"])
    ap.add_argument("--references", nargs="*", default=list(REFS), choices=list(REFS))
    ap.add_argument("--cache", type=Path, help="keep the decoded logs here between runs")
    ap.add_argument("--json", type=Path, help="also write the figures as JSON")
    args = ap.parse_args(argv)
    out: dict[str, object] = {}
    for kind in args.sets:
        t0 = time.perf_counter()
        if kind.startswith("broad"):
            if not (DATA / "broad").is_dir():
                print(f"{kind}: skipped, {DATA / 'broad'} absent", file=sys.stderr)
                continue
            res = bench_broad(kind, args.filters, args.references)
        else:
            res = bench_logs(kind, args.filters, args.references, args.cache)
        out[kind] = res
        heading = kind in ("sitl", "px4") or kind == "broad"
        what = "inclination / heading" if heading else "inclination"
        print(f"\n### {kind}: {what} RMS, degrees ({time.perf_counter() - t0:.0f} s)\n")
        print(table(kind, res, heading), flush=True)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
