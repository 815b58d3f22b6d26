#!/usr/bin/env python3
"""What limits the BROAD magnetometer: its timing, its calibration, and what each does to ``best``'s heading.

Usage::

    python3 scripts/bench_broad_compass.py                 # every trial in ../shared/data/broad
    python3 scripts/bench_broad_compass.py --data DIR      # another folder of BROAD .mat trials
    python3 scripts/bench_broad_compass.py --no-filter     # the compass alone (seconds), not ``best``'s runs
    python3 scripts/bench_broad_compass.py --only-eskf --eskf '{"mag_learn_tau_s": 20}'   # best's settings changed
    python3 scripts/bench_broad_compass.py --drop-above-deg-s 150 300   # also the reading dropped in fast turns
    python3 scripts/bench_broad_compass.py --tstick ../shared/data/repoimu_tstick --drop-above-deg-s 150 300
    python3 scripts/bench_broad_compass.py --trace 30 --trace-blank 32 61   # one trial per 5 s, best's error and compass
    python3 scripts/bench_broad_compass.py --motion        # a late reading's azimuth error in each trial's motion, the gyro's drift
    python3 scripts/bench_broad_compass.py --rests         # whose drift: the compass at each rest against the reference and the gyro
    python3 scripts/bench_broad_compass.py --gyro-models   # candidate causes of the gyro's drift, fitted on one half, tested on the other
    python3 scripts/bench_broad_compass.py --only-eskf --oracle-gyro   # best with a gyro that cannot drift (the reference's rotation)

Issue 23 (docs/accuracy.md "BROAD magnet trials, round four (branch smag)").  Every figure but the delay
regression uses the optical reference, so none of them is something a filter could do online; they bound
what an online calibration or delay estimate could give.

* *A perfect-attitude compass*: each reading rotated to NED with the reference's attitude ``shift`` samples
  later (negative: earlier) and its azimuth compared with the first valid second's field azimuth; RMS over
  the scored samples.  The shift that minimises it is the compass's delay behind the reference, in samples
  (285.7 Hz); the gyro's delay behind the reference is the shift that best matches the reference's own body
  rate (:func:`gyro_shift_samples`).
* *The delay without a reference* (:func:`compass_delay_s`): an earth-fixed field read in a turning body
  obeys ṁ = −ω × m; a reading L s late obeys ṁ + ω × m ≈ L·(ω̇ × m); L by least squares over the trial, from
  central differences over ±``half`` samples.  A body-fixed field (a magnet on the sensor) breaks it.
* *The calibration's upper bound* (:func:`truth_calibration`): m = A·(Cᵀ f) + b fitted by least squares with
  the reference's C over the scored samples (hard iron b, soft iron and misalignment A, and the earth field
  f: the most any calibration can learn, and more: A's rotation too), the reading mapped back with
  A⁻¹(m − b) and its azimuth compared with f's; "own" fits each trial on itself (in-sample), "01" applies
  trial 01's A, b to the others.  ``best``'s "own truth calibration" run keeps f = the rest's field (BROAD's
  north).
* *Windowed*: the largest |1 s mean| of the azimuth error, and of the 1 s mean less the previous 10 s mean
  (the disturbance test bmag2 measured with the filter's own attitude), scored samples only.
* *Repeats*: the share of samples whose reading equals the previous one (BROAD's magnetometer is read slower
  than the IMU and held; ``best`` fuses a reading when it changes, at most ``mag_rate_hz``).
* *``best``'s heading RMS* (BROAD's scoring, ``scripts/bench_accuracy.py``) with the compass input edited:
  as is; 0.001 µT of Gaussian noise added (seeds 1–3: nothing physical changes, but no reading repeats, so
  other readings are fused — the per-trial noise floor of any compass change); calibrated with the trial's
  own truth fit; the project's ellipsoid fit (:func:`mavahrs.evaluation.magcal.fit_ellipsoid`, no
  reference, its coverage test) on each trial's own readings, and trial 01's applied to all; the delay removed to first order,
  m − L·(ω × m), for a few L.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(REPO))

from mavahrs.errors import DataError  # noqa: E402
from mavahrs.evaluation.datasets import Recording, find_broad_trials, load_broad_trial  # noqa: E402
from mavahrs.evaluation.magcal import fit_ellipsoid  # noqa: E402
from mavahrs.evaluation.metrics import summarize  # noqa: E402
from mavahrs.filters import create  # noqa: E402
from mavahrs.filters.base import make_inputs  # noqa: E402
from mavahrs.filters.best import BestSettings  # noqa: E402
from mavahrs.filters.layout import OUT_Q  # noqa: E402
from mavahrs.geometry.quaternion import (  # noqa: E402
    conjugate,
    from_rotation_vector,
    multiply,
    rotate,
    to_rotation_vector,
)

DEFAULT_DATA = REPO.parent / "shared" / "data" / "broad"
Array = np.ndarray


# ------------------------------------------------------------------ the compass against the reference


def _reference(rec: Recording) -> tuple[Array, Array]:
    """(q_body_to_ned with invalid rows set to identity, valid mask)."""
    ok = np.all(np.isfinite(rec.q_ref_body_to_ned), axis=1)
    q = np.where(ok[:, None], rec.q_ref_body_to_ned, np.array([1.0, 0.0, 0.0, 0.0]))
    return q, ok


def azimuth_deg(v_ned: Array) -> Array:
    return np.degrees(np.arctan2(v_ned[..., 1], v_ned[..., 0]))


def wrap_deg(a: Array) -> Array:
    return (a + 180.0) % 360.0 - 180.0


def earth_field_ned(rec: Recording, mag_body_ut: Array) -> Array:
    """The mean of the first valid second's readings rotated to NED with the reference (BROAD's north)."""
    q, ok = _reference(rec)
    i0 = int(np.flatnonzero(ok)[0])
    sl = slice(i0, i0 + round(1.0 / float(rec.dt_s[0])))
    return np.asarray(rotate(q[sl], mag_body_ut[sl]).mean(axis=0))


def azimuth_error_deg(
    rec: Recording, mag_body_ut: Array, shift: int = 0, field_ned: Array | None = None
) -> tuple[Array, Array]:
    """Reading i against the reference's attitude at i + ``shift``: (error, scored mask), both over i; the error
    against ``field_ned``'s azimuth (default: the first valid second's reading rotated to NED)."""
    if field_ned is None:
        field_ned = earth_field_ned(rec, mag_body_ut)
    q, ok = _reference(rec)
    n = rec.n
    i = np.arange(max(0, -shift), min(n, n - shift))
    e = np.full(n, np.nan)
    e[i] = wrap_deg(azimuth_deg(rotate(q[i + shift], mag_body_ut[i])) - azimuth_deg(field_ned))
    mask = np.zeros(n, dtype=bool)
    mask[i] = rec.scored[i] & ok[i] & ok[i + shift]
    return e, mask


def rest_and_motion_norm_ut(rec: Recording) -> tuple[float, float]:
    """The field's mean norm over the first valid second (the rest the schedule takes its reference from) and
    over the scored movement."""
    _, ok = _reference(rec)
    i0 = int(np.flatnonzero(ok)[0])
    norm = np.linalg.norm(rec.mag_ut, axis=1)
    return float(norm[i0 : i0 + round(1.0 / float(rec.dt_s[0]))].mean()), float(norm[rec.scored].mean())


def rms(e: Array, mask: Array) -> float:
    return float(np.sqrt(np.mean(e[mask] ** 2)))


def gyro_shift_samples(rec: Recording, shifts: range = range(-4, 9)) -> int:
    """The k whose gyro sample i + k best matches the reference's body rate between i and i + 1."""
    q, ok = _reference(rec)
    rate = 1.0 / float(rec.dt_s[0])
    w_ref = to_rotation_vector(multiply(conjugate(q[:-1]), q[1:])) * rate
    good = ok[:-1] & ok[1:] & rec.scored[:-1]
    best_k, best = 0, np.inf
    for k in shifts:
        i = np.arange(max(0, -k), min(len(w_ref), rec.n - k))
        d = rec.gyro_rad_s[i + k] - w_ref[i]
        err = float(np.mean(np.sum(d[good[i]] ** 2, axis=1)))
        if err < best:
            best_k, best = k, err
    return best_k


def compass_delay_s(gyro_rad_s: Array, mag_ut: Array, dt_s: float, half: int = 6) -> float:
    """The compass's delay behind the gyro, s, from the two alone: ṁ + ω × m ≈ L·(ω̇ × m) for an earth-fixed field."""
    n = len(mag_ut)
    i = np.arange(half, n - half)
    span = 2 * half * dt_s
    m_dot = (mag_ut[i + half] - mag_ut[i - half]) / span
    w_dot = (gyro_rad_s[i + half] - gyro_rad_s[i - half]) / span
    m_c = 0.5 * (mag_ut[i + half] + mag_ut[i - half])
    w_c = 0.5 * (gyro_rad_s[i + half] + gyro_rad_s[i - half])
    r = m_dot + np.cross(w_c, m_c)
    g = np.cross(w_dot, m_c)
    return float(np.sum(r * g) / np.sum(g * g))


def fit_calibration_with_truth(mag_body_ut: Array, field_body_ut: Array) -> tuple[Array, Array]:
    """Least-squares (A, b) of m = A·f + b over the rows given (m the reading, f the true field in the body)."""
    x = np.column_stack([field_body_ut, np.ones(len(field_body_ut))])
    coef, *_ = np.linalg.lstsq(x, mag_body_ut, rcond=None)
    return coef[:3].T, coef[3]


def apply_calibration(mag_body_ut: Array, a: Array, b: Array) -> Array:
    return np.linalg.solve(a, (mag_body_ut - b).T).T


def truth_calibration(rec: Recording, shift: int, fit_field: bool = False) -> tuple[Array, Array, Array]:
    """(A, b, f) of m = A·(Cᵀ f) + b over the trial's scored samples, each reading against the reference ``shift``
    samples later.  f is the first valid second's field rotated to NED (BROAD's north: the calibrated reading keeps
    it), or with ``fit_field`` fitted too (alternating least squares, ‖f‖ kept): at a rest the reading carries
    the distortion at that one orientation, which no body-fixed A can take out at the others."""
    q, ok = _reference(rec)
    n = rec.n
    i = np.arange(max(0, -shift), min(n, n - shift))
    use = rec.scored[i] & ok[i] & ok[i + shift]
    m = rec.mag_ut[i][use]
    q_ned_to_body = conjugate(q[i + shift][use])
    me = earth_field_ned(rec, rec.mag_ut)
    f = me.copy()
    # Cᵀ as (N, 3, 3): its columns are the NED axes in the body
    ct = np.stack([rotate(q_ned_to_body, np.broadcast_to(e, (len(m), 3))) for e in np.eye(3)], axis=2)
    for _ in range(30 if fit_field else 1):
        a, b = fit_calibration_with_truth(m, ct @ f)
        if not fit_field:
            break
        mi = a @ ct  # (N, 3, 3): m − b = Mᵢ f
        f = np.linalg.solve(np.einsum("nji,njk->ik", mi, mi), np.einsum("nji,nj->i", mi, m - b))
        f *= np.linalg.norm(me) / np.linalg.norm(f)
    return a, b, f


def ellipsoid_report(rec: Recording) -> str:
    """:func:`mavahrs.evaluation.magcal.fit_ellipsoid`'s figures on the trial's scored readings (forced when refused)."""
    try:
        fit = fit_ellipsoid(rec.mag_ut[rec.scored], None)
        state = "fit"
    except DataError:
        fit = fit_ellipsoid(rec.mag_ut[rec.scored], None, force=True)
        state = "refused"
    m = np.array(fit.matrix)
    soft = float(np.max(np.abs(m / np.mean(np.diag(m)) - np.eye(3)))) * 100.0
    return (
        f"{state:7s} coverage {fit.coverage:.2f}  offset {np.linalg.norm(fit.offset_ut):4.1f} µT  soft iron ≤ {soft:3.1f} %  "
        f"axis ratio {fit.axis_ratio:.3f}  residual {fit.residual_rms_ut:.2f} µT ({fit.residual_rms_percent:.1f} %), raw "
        f"{fit.raw_residual_rms_ut:.2f} µT"
    )


def ellipsoid_calibration(rec: Recording) -> tuple[Array, Array] | None:
    """(A, b) from :func:`mavahrs.evaluation.magcal.fit_ellipsoid` over the trial's own scored readings (no
    reference; its coverage and conditioning tests), A = M⁻¹, b = the offset; None when it refuses the fit."""
    try:
        fit = fit_ellipsoid(rec.mag_ut[rec.scored], None)
    except DataError:
        return None
    return np.linalg.inv(np.array(fit.matrix)), np.array(fit.offset_ut)


def window_maxima(e: Array, mask: Array, rate_hz: float) -> tuple[float, float]:
    """(max |1 s mean|, max |1 s mean − previous 10 s mean|) of e over the masked samples, windows ≥ 80 % full."""
    v = np.where(mask, e, 0.0)
    c = np.concatenate([[0.0], np.cumsum(v)])
    cn = np.concatenate([[0], np.cumsum(mask)])
    n1, n10 = round(rate_hz), round(10 * rate_hz)
    idx = np.arange(n1 + n10, len(e), max(n1 // 4, 1))

    def mean(a: Array, b: Array) -> tuple[Array, Array]:
        cnt = cn[b] - cn[a]
        return (c[b] - c[a]) / np.maximum(cnt, 1), cnt

    m1, k1 = mean(idx - n1, idx)
    m10, k10 = mean(idx - n1 - n10, idx - n1)
    ok1 = k1 > 0.8 * n1
    ok10 = ok1 & (k10 > 0.8 * n10)
    a = float(np.max(np.abs(m1[ok1]))) if ok1.any() else float("nan")
    s = float(np.max(np.abs(m1 - m10)[ok10])) if ok10.any() else float("nan")
    return a, s


# ------------------------------------------------------------------ what the motion does to a late reading and to the gyro


def late_azimuth_rate_rad_s(q_body_to_ned: Array, gyro_rad_s: Array, mag_ut: Array) -> Array:
    """Per sample, how fast a reading's azimuth runs ahead as the body turns, rad/s: read L s late and rotated to
    NED with the attitude of now, its azimuth is off by L × this (to first order).

    With ω and h the body rate and the reading in NED, the late reading is h + L·(ω × h), whose azimuth is off by
    L·(ω_D − (h_D/h_H)·(ω_N h_N + ω_E h_E)/h_H): the yaw rate, and the turn about the field's horizontal direction
    times tan(dip) (≈ 2.7 at BROAD's 70°).  The ESKF's delay correction (``mag_delay_s``, ``mag_learn_tau_s``)
    has the yaw rate alone."""
    w = rotate(q_body_to_ned, gyro_rad_s)
    h = rotate(q_body_to_ned, mag_ut)
    hh2 = h[:, 0] ** 2 + h[:, 1] ** 2
    return np.asarray(w[:, 2] - h[:, 2] * (w[:, 0] * h[:, 0] + w[:, 1] * h[:, 1]) / hh2)


def late_azimuth_bias_deg(rec: Recording, lag_samples: int) -> tuple[float, float]:
    """(mean, RMS) over the scored samples of the azimuth of reading i rotated with the reference at i less that
    rotated with the reference at i − ``lag_samples``: what a reading that many samples late is off by when it is
    rotated with the attitude of now, as the filter does."""
    q, ok = _reference(rec)
    i = np.arange(lag_samples, rec.n)
    d = wrap_deg(
        azimuth_deg(rotate(q[i], rec.mag_ut[i])) - azimuth_deg(rotate(q[i - lag_samples], rec.mag_ut[i]))
    )
    s = ok[i] & ok[i - lag_samples] & rec.scored[i]
    return float(np.mean(d[s])), float(np.sqrt(np.mean(d[s] ** 2)))


def gyro_heading_drift_deg_s(
    rec: Recording, bias_rad_s: Array, window_s: float = 10.0, gyro_shift: int = 2
) -> Array:
    """The gyro's heading drift against the reference, °/s, per window of ``window_s``: the gyro less
    ``bias_rad_s`` ((3,) or (N, 3)) integrated from the reference's attitude at the window's start (the gyro
    ``gyro_shift`` samples behind the reference, :func:`gyro_shift_samples`), its heading against the
    reference's at the end, over the window's length; windows with an invalid end or less than half scored are
    left out."""
    q, ok = _reference(rec)
    dt = float(rec.dt_s[0])
    g = rec.gyro_rad_s - np.broadcast_to(bias_rad_s, rec.gyro_rad_s.shape)
    steps = from_rotation_vector(g * dt)
    per = round(window_s / dt)
    out = []
    for i0 in range(gyro_shift, rec.n - per, per):
        i1 = i0 + per
        a, b = i0 - gyro_shift, i1 - gyro_shift
        if not (ok[a] and ok[b] and rec.scored[i0:i1].mean() > 0.5):
            continue
        qq = q[a]
        for r in steps[i0:i1]:
            qq = multiply(qq, r)
        e = multiply(qq / np.linalg.norm(qq), conjugate(q[b]))
        out.append(np.degrees(2.0 * np.arctan(e[3] / e[0])) / window_s)
    return np.asarray(out)


def motion_report(recs: list[Recording]) -> None:
    """Per trial: the compass's delay (regression), the mean rates in NED (reference), what a reading late by
    that delay is off by in azimuth (measured: reference at i against i − 3; predicted: L × the mean of
    :func:`late_azimuth_rate_rad_s`; and the yaw-rate term alone), the gyro's heading drift against the
    reference (``best``'s own bias; mean and RMS of the 10 s windows) and ``best``'s heading RMS."""
    from mavahrs.filters.layout import OUT_BIAS

    print(
        "\nA late reading in this motion, and the gyro's heading drift (rates and azimuths from the reference)"
    )
    print(
        f"{'trial':32s} {'L ms':>5s} {'mean rate N/E/D deg/s':>22s} {'late az: 3 samples':>18s} "
        f"{'L·rate':>6s} {'L·w_D':>6s} {'drift deg/s':>12s} {'best hdg':>8s}"
    )
    for rec in recs:
        dt = float(rec.dt_s[0])
        q, ok = _reference(rec)
        s = ok & rec.scored
        lag_s = compass_delay_s(rec.gyro_rad_s, rec.mag_ut, dt)
        w = np.degrees(rotate(q[s], rec.gyro_rad_s[s])).mean(axis=0)
        meas, _ = late_azimuth_bias_deg(rec, 3)
        rate = late_azimuth_rate_rad_s(q[s], rec.gyro_rad_s[s], rec.mag_ut[s])
        out = create("best").run(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut, dt_s=rec.dt_s))
        drift = gyro_heading_drift_deg_s(rec, out[:, OUT_BIAS : OUT_BIAS + 3])
        h = summarize(out[:, OUT_Q : OUT_Q + 4], rec.q_ref_body_to_ned, rec.scored).heading_rms_deg
        print(
            f"{rec.name[:32]:32s} {lag_s * 1e3:5.1f} {w[0]:+7.0f}{w[1]:+7.0f}{w[2]:+7.0f}  {meas:+17.2f} "
            f"{np.degrees(lag_s * rate.mean()):+6.2f} {lag_s * w[2]:+6.2f} {drift.mean():+6.2f}/{np.sqrt(np.mean(drift**2)):5.2f} "
            f"{h:8.2f}"
        )


# ------------------------------------------------------------------ whose drift: the gyro's or the reference's


def still_rests(
    rec: Recording, min_s: float = 2.0, still_deg_s: float = 3.0, trim_s: float = 0.3
) -> list[tuple[int, int]]:
    """BROAD's rests: unscored stretches with a valid reference where the gyro turns slower than ``still_deg_s``,
    at least ``min_s`` long after ``trim_s`` is cut from each end; (first, end) sample indices."""
    _, ok = _reference(rec)
    still = (~rec.scored) & ok & (np.degrees(np.linalg.norm(rec.gyro_rad_s, axis=1)) < still_deg_s)
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    trim = round(trim_s / float(rec.dt_s[0]))
    out = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        a, b = int(a) + trim, int(b) - trim
        if (b - a) * float(rec.dt_s[0]) >= min_s:
            out.append((a, b))
    return out


def _qmul(a: tuple[float, ...], b: Array) -> tuple[float, float, float, float]:
    w0, x0, y0, z0 = a
    w1, x1, y1, z1 = b
    return (
        w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
        w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
        w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
        w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1,
    )


def _heading_error_deg(q_est: Array, q_ref: Array) -> float:
    e = multiply(np.asarray(q_est) / np.linalg.norm(q_est), conjugate(q_ref))
    return float(np.degrees(2.0 * np.arctan(e[3] / e[0])))


def rest_to_rest(rec: Recording, gyro_shift: int = 2) -> list[dict[str, float]]:
    """Per rest (:func:`still_rests`): its times; the field's azimuth read there with the reference, less the
    first rest's (the compass at rest is an earth-fixed direction and its delay plays no part, so a reference
    that drifted in the motion before would show here); the gyro (less the mean of every rest's rate, ``gyro_shift``
    samples behind the reference) integrated from the previous rest's middle with the reference's attitude there,
    its heading against the reference's at this rest's middle; and the motion's length between the two."""
    q, _ = _reference(rec)
    dt = float(rec.dt_s[0])
    rests = still_rests(rec)
    if not rests:
        return []
    idx = np.concatenate([np.arange(a, b) for a, b in rests])
    bias = rec.gyro_rad_s[idx].mean(axis=0)
    steps = from_rotation_vector((rec.gyro_rad_s - bias) * dt)
    az = [float(np.mean(azimuth_deg(rotate(q[a:b], rec.mag_ut[a:b])))) for a, b in rests]
    out = []
    for k, (a, b) in enumerate(rests):
        row = {"t0_s": a * dt, "t1_s": b * dt, "field_azimuth_deg": float(wrap_deg(az[k] - az[0]))}
        row["gyro_heading_error_deg"], row["motion_s"] = 0.0, 0.0
        if k:
            m0, m1 = (rests[k - 1][0] + rests[k - 1][1]) // 2, (a + b) // 2
            qq = tuple(q[m0])
            for i in range(m0, min(m1, rec.n - gyro_shift)):
                qq = _qmul(qq, steps[i + gyro_shift])
            row["gyro_heading_error_deg"] = _heading_error_deg(np.array(qq), q[m1])
            row["motion_s"] = (a - rests[k - 1][1]) * dt
        out.append(row)
    return out


def _rotation_matrices(q: Array) -> Array:
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        1,
    )


#: candidate causes of the gyro's error, each a set of body-frame terms (what the gyro reads beyond the true rate):
#: g-sensitivity G (f_j on axis a), a scale / cross-axis matrix M (ω_j on axis a), a time skew per axis T (−ω̇_a),
#: the pseudo-coning of a low-pass K ((ω × ω̇)_a), a scale error growing with the rate N (|ω|·ω_a)
GYRO_MODELS: dict[str, tuple[str, ...]] = {
    "g-sensitivity (9)": tuple(f"G{a}{j}" for a in range(3) for j in range(3)),
    "matrix (9)": tuple(f"M{a}{j}" for a in range(3) for j in range(3)),
    "axis time skew (3)": tuple(f"T{a}" for a in range(3)),
    "pseudo-coning (3)": tuple(f"K{a}" for a in range(3)),
    "scale ∝ |ω| (3)": tuple(f"N{a}" for a in range(3)),
}


def gyro_window_errors(
    rec: Recording, window_s: float = 5.0, gyro_shift: int = 2
) -> tuple[Array, dict[str, Array]]:
    """The gyro's error against the reference per window of ``window_s``, to first order in NED (rad, (n, 3)):
    Σ C_i (ω_g(i + shift) − b) dt − C_i φ_i, φ_i the reference's own step i → i + 1 in the body, b the mean rate of
    the rests; and each term of :data:`GYRO_MODELS` summed the same way, Σ C_i e_a x_i dt, so that the errors are
    linear in the terms' coefficients.  Windows with less than 95 % scored valid steps are left out."""
    q, ok = _reference(rec)
    dt = float(rec.dt_s[0])
    rests = still_rests(rec)
    idx = np.concatenate([np.arange(a, b) for a, b in rests]) if rests else np.arange(round(1.0 / dt))
    bias = rec.gyro_rad_s[idx].mean(axis=0)
    force_rest = rec.accel_m_s2[idx].mean(axis=0)
    i = np.arange(rec.n - gyro_shift - 1)
    c = _rotation_matrices(q[i])
    phi = to_rotation_vector(multiply(conjugate(q[i]), q[i + 1]))
    w = rec.gyro_rad_s[i + gyro_shift]
    wd = np.gradient(rec.gyro_rad_s, dt, axis=0)[i + gyro_shift]
    f = rec.accel_m_s2[i + gyro_shift] - force_rest
    cone = np.cross(w, wd)
    norm = np.linalg.norm(w, axis=1)
    res = np.einsum("nab,nb->na", c, (w - bias) * dt - phi)
    good = ok[i] & ok[i + 1] & rec.scored[i] & (np.linalg.norm(phi, axis=1) < 0.2)
    body: dict[str, tuple[int, Array]] = {}  # term: (the body axis it reads on, its value per sample)
    for a in range(3):
        for j in range(3):
            body[f"G{a}{j}"], body[f"M{a}{j}"] = (a, f[:, j]), (a, w[:, j])
        body[f"T{a}"], body[f"K{a}"], body[f"N{a}"] = (a, -wd[:, a]), (a, cone[:, a]), (a, norm * w[:, a])
    per = round(window_s / dt)
    errors: list[Array] = []
    regs: dict[str, list[Array]] = {k: [] for k in body}
    for s0 in range(0, len(i) - per, per):
        sl = slice(s0, s0 + per)
        m = good[sl]
        if m.mean() < 0.95:
            continue
        errors.append(res[sl][m].sum(axis=0))
        for k, (a, x) in body.items():
            regs[k].append(c[sl][m][:, :, a].T @ (x[sl][m] * dt))
    return np.array(errors).reshape(-1, 3), {k: np.array(v).reshape(-1, 3) for k, v in regs.items()}


def fit_gyro_model(
    data: dict[str, tuple[Array, dict[str, Array]]], keys: tuple[str, ...], trials: tuple[str, ...]
) -> Array:
    """Least-squares coefficients of ``keys`` to the heading (down) component of the window errors of ``trials``."""
    a = np.concatenate([np.stack([data[t][1][k][:, 2] for k in keys], -1) for t in trials if t in data])
    y = np.concatenate([data[t][0][:, 2] for t in trials if t in data])
    return np.linalg.lstsq(a, y, rcond=None)[0]


def window_heading_drift_deg_s(
    data: dict[str, tuple[Array, dict[str, Array]]],
    trial: str,
    window_s: float,
    keys: tuple[str, ...] = (),
    coef: Array | None = None,
) -> Array:
    """The heading (down) component of a trial's window errors, °/s, less the model ``keys`` × ``coef``."""
    y = data[trial][0][:, 2].copy()
    if keys and coef is not None:
        y -= np.stack([data[trial][1][k][:, 2] for k in keys], -1) @ coef
    return np.degrees(y) / window_s


def gyro_models_report(recs: list[Recording], window_s: float) -> None:
    """Each candidate of :data:`GYRO_MODELS` fitted on CHOICE_TRIALS and tested on HELD_TRIALS, and the reverse:
    the window heading drift's RMS (mean over the trials of each half) and per trial mean / RMS, °/s."""
    data = {r.name[:2]: gyro_window_errors(r, window_s) for r in recs}
    names = list(data)

    def rms_mean(keys: tuple[str, ...], coef: Array | None, trials: tuple[str, ...]) -> float:
        d = [window_heading_drift_deg_s(data, t, window_s, keys, coef) for t in trials if t in data]
        return float(np.mean([np.sqrt(np.mean(x**2)) for x in d]))

    print(
        f"\nThe gyro's heading drift per {window_s:g} s window against the reference, °/s (first order), with each "
        "candidate cause fitted on one half and tested on the other; per trial mean / RMS with the choice fit"
    )
    print(
        f"{'model':22s} {'fit choice: choice / held':>26s} {'fit held: held / choice':>24s}  "
        + " ".join(f"{t:>10s}" for t in names)
    )
    for model, keys in {"none": (), **GYRO_MODELS}.items():
        c1 = fit_gyro_model(data, keys, CHOICE_TRIALS) if keys else None
        c2 = fit_gyro_model(data, keys, HELD_TRIALS) if keys else None
        cells = []
        for t in names:
            d = window_heading_drift_deg_s(data, t, window_s, keys, c1)
            cells.append(f"{d.mean():+.2f}/{np.sqrt(np.mean(d**2)):.2f}")
        print(
            f"{model:22s} {rms_mean(keys, c1, CHOICE_TRIALS):12.3f} / {rms_mean(keys, c1, HELD_TRIALS):.3f}   "
            f"{rms_mean(keys, c2, HELD_TRIALS):11.3f} / {rms_mean(keys, c2, CHOICE_TRIALS):.3f}   "
            + " ".join(f"{x:>10s}" for x in cells)
        )
        if model == "scale ∝ |ω| (3)" and c1 is not None:
            print(f"{'':22s} choice fit N = {', '.join(f'{x:+.2e}' for x in c1)} per rad/s")


def rate_scaled_gyro(gyro_rad_s: Array, n_per_rad_s: Array) -> Array:
    """The gyro with a scale error that grows with the rate taken out: ω − N_a·|ω|·ω_a (N per rad/s, per axis)."""
    return gyro_rad_s - n_per_rad_s * np.linalg.norm(gyro_rad_s, axis=1)[:, None] * gyro_rad_s


def rests_report(recs: list[Recording]) -> None:
    print(
        "\nAt each rest: the field's azimuth with the reference less the first rest's (the compass at rest: an earth-fixed "
        "direction), and the gyro integrated over the motion before it from the previous rest's reference attitude"
    )
    print(f"{'trial':32s} rests: t s | field az ° | gyro heading error ° over the motion's s")
    for rec in recs:
        rows = rest_to_rest(rec)
        cells = [
            f"{r['t0_s']:.0f}|{r['field_azimuth_deg']:+.2f}|{r['gyro_heading_error_deg']:+.2f}/{r['motion_s']:.0f}"
            for r in rows
        ]
        print(f"{rec.name[:32]:32s} " + "  ".join(cells))


def oracle_gyro(rec: Recording, gyro_shift: int = 2) -> Array:
    """The reference's own rotation over each sample as the gyro (``gyro_shift`` samples behind it, as BROAD's gyro
    is), plus the rests' mean rate as its bias; the gyro as is where the reference is not valid: a gyro that cannot
    drift against the reference, to see what is left of ``best``'s heading error with the compass alone."""
    q, ok = _reference(rec)
    dt = float(rec.dt_s[0])
    rests = still_rests(rec)
    bias = rec.gyro_rad_s[np.concatenate([np.arange(a, b) for a, b in rests])].mean(axis=0) if rests else 0.0
    i = np.arange(rec.n - gyro_shift - 1)
    good = ok[i] & ok[i + 1]
    g = rec.gyro_rad_s.copy()
    g[i[good] + gyro_shift] = to_rotation_vector(multiply(conjugate(q[i[good]]), q[i[good] + 1])) / dt + bias
    return g


# ------------------------------------------------------------------ best with the compass edited


def best_settings_with(changes: dict[str, Any]) -> BestSettings:
    """``best``'s defaults with fields of its plain-path ESKF changed (``"schedule"``: a dict of gain-schedule fields)."""
    changes = dict(changes)
    s = BestSettings()
    schedule = replace(s.eskf.schedule, **changes.pop("schedule", {}))
    return replace(s, eskf=replace(s.eskf, schedule=schedule, **changes))


def best_heading_rms(rec: Recording, mag_ut: Array, settings: BestSettings | None = None) -> float:
    q = create("best", settings).run(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, mag_ut, dt_s=rec.dt_s))[
        :, OUT_Q : OUT_Q + 4
    ]
    return summarize(q, rec.q_ref_body_to_ned, rec.scored).heading_rms_deg


def delay_removed(rec: Recording, delay_s: float) -> Array:
    """The reading carried forward by ``delay_s`` of the gyro's turn, to first order: m − L·(ω × m)."""
    return rec.mag_ut - delay_s * np.cross(rec.gyro_rad_s, rec.mag_ut)


def dropped_above(mag_ut: Array, gyro_rad_s: Array, limit_deg_s: float) -> Array:
    """The readings taken while the gyro turns faster than ``limit_deg_s`` set to NaN (no magnetometer there)."""
    out = mag_ut.copy()
    out[np.degrees(np.linalg.norm(gyro_rad_s, axis=1)) > limit_deg_s] = np.nan
    return out


def tstick_check(folder: Path, limits_deg_s: list[float]) -> None:
    """RepoIMU T-stick (another sensor, Xsens MTi + Vicon, not north-referenced): the compass's delay by the same
    regression, and ``best``'s heading RMS after a fitted constant heading offset, as is and with the reading
    dropped above each limit.  Test05 is left out (its gyro clips for 15–20 % of the trial)."""
    from mavahrs.evaluation.datasets import load_repoimu_csv
    from mavahrs.evaluation.report import score_estimate

    paths = sorted(p for p in folder.glob("TStick_Test*_Trial1.csv") if "Test05" not in p.name)
    if not paths:
        print(f"skipped: no RepoIMU T-stick trials at {folder}", file=sys.stderr)
        return
    recs = {p.name.split("_")[1]: load_repoimu_csv(p) for p in paths}
    print("\nRepoIMU T-stick: compass delay behind the gyro (ms), share of samples turning > 300 deg/s")
    for key, rec in recs.items():
        d = compass_delay_s(rec.gyro_rad_s, rec.mag_ut, float(rec.dt_s[0]), half=2) * 1e3
        fast = float(np.mean(np.degrees(np.linalg.norm(rec.gyro_rad_s, axis=1)) > 300.0))
        print(f"  {key}: {d:6.2f} ms, {fast:.3f}")
    print("best's heading RMS after a fitted heading offset, degrees")
    variants: dict[str, Callable[[Recording], Array]] = {"as is": lambda r: r.mag_ut}
    for limit in limits_deg_s:
        variants[f"NaN > {limit:g} deg/s"] = lambda r, limit=limit: dropped_above(
            r.mag_ut, r.gyro_rad_s, limit
        )
    for name, make in variants.items():
        h = {}
        for key, rec in recs.items():
            q = create("best").run(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, make(rec), dt_s=rec.dt_s))
            h[key] = score_estimate(q[:, OUT_Q : OUT_Q + 4], rec, alignment="heading").heading_rms_deg
        print(
            f"  {name:20s} "
            + " ".join(f"{k[-2:]}:{v:.2f}" for k, v in h.items())
            + f"   mean {np.mean(list(h.values())):.3f}"
        )


def trace(
    rec: Recording, blank_s: tuple[float, float] | None, delay_ms: float, window_s: float = 5.0
) -> None:
    """Per window: ``best``'s signed heading error (mean), the share of samples whose compass weight is ≥ 0.5, and
    the true azimuth error (reading rotated with the reference 2 samples earlier, the gyro's time) of the new
    readings among those; for the compass as is, carried forward by ``delay_ms``, its own ellipsoid, and (with
    ``blank_s``) no compass over that span."""
    from mavahrs.filters.layout import OUT_MAG_WEIGHT

    q_ref, ok = _reference(rec)
    t = np.arange(rec.n) * float(rec.dt_s[0])
    field = earth_field_ned(rec, rec.mag_ut)
    variants: dict[str, Array] = {
        "as is": rec.mag_ut,
        f"L {delay_ms:g} ms": delay_removed(rec, delay_ms * 1e-3),
    }
    cal = ellipsoid_calibration(rec)
    if cal is not None:
        variants["own ellipsoid"] = apply_calibration(rec.mag_ut, *cal)
    if blank_s is not None:
        m = rec.mag_ut.copy()
        m[(t >= blank_s[0]) & (t < blank_s[1])] = np.nan
        variants[f"no compass {blank_s[0]:g}-{blank_s[1]:g} s"] = m
    for name, m in variants.items():
        out = create("best").run(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, m, dt_s=rec.dt_s))
        q = out[:, OUT_Q : OUT_Q + 4]
        e = multiply(q, conjugate(rec.q_ref_body_to_ned))
        heading = np.degrees(2.0 * np.arctan(e[:, 3] / e[:, 0]))
        h_rms = summarize(q, rec.q_ref_body_to_ned, rec.scored).heading_rms_deg
        passed = out[:, OUT_MAG_WEIGHT] >= 0.5
        new = np.r_[True, np.any(m[1:] != m[:-1], axis=1)] & np.all(np.isfinite(m), axis=1)
        idx = np.arange(rec.n)
        true_err = np.full(rec.n, np.nan)
        good = np.isfinite(m[:, 0])
        true_err[good] = wrap_deg(
            azimuth_deg(rotate(q_ref[np.maximum(idx[good] - 2, 0)], m[good])) - azimuth_deg(field)
        )
        print(
            f"{name} (heading RMS {h_rms:.2f}): window s: error / share passed / passed readings' true error"
        )
        cells = []
        for a in np.arange(0.0, t[-1], window_s):
            w = (t >= a) & (t < a + window_s) & ok
            if not (w & rec.scored).any():
                continue
            sel = w & passed & new
            te = f"{np.mean(true_err[sel]):+.1f}" if sel.any() else "-"
            cells.append(f"{a:.0f}: {np.nanmean(heading[w]):+.1f}/{np.mean(passed[w]):.2f}/{te}")
        print("  " + "  ".join(cells))


#: round five's split (docs/accuracy.md, branch smag3), fixed before its variants were measured: settings are chosen
#: on CHOICE_TRIALS (one of each kind: slow / fast rotation, slow / fast translation, tapping, each magnet) and
#: confirmed on HELD_TRIALS
CHOICE_TRIALS = ("01", "04", "08", "11", "15", "24", "28", "32")
HELD_TRIALS = ("02", "06", "10", "14", "18", "26", "30", "34")


def _groups(values: dict[str, float]) -> str:
    def mean(keys: tuple[str, ...]) -> float:
        return float(np.mean([values[k] for k in keys if k in values]))

    clean = tuple(k for k in values if int(k[:2]) <= 18)
    return (
        f"all {np.mean(list(values.values())):.2f}  undisturbed(10) {mean(clean):.2f}  "
        f"stat.magnet {mean(('28', '30')):.2f}  att.magnet {mean(('32', '34')):.2f}  "
        f"choice {mean(CHOICE_TRIALS):.3f}  held {mean(HELD_TRIALS):.3f}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--data",
        type=Path,
        default=DEFAULT_DATA,
        help=f"folder of BROAD .mat trials (default {DEFAULT_DATA})",
    )
    ap.add_argument("--no-filter", action="store_true", help="the compass figures only, not best's runs")
    ap.add_argument(
        "--delays-ms", type=float, nargs="*", default=[5.0, 10.0], help="L for best with m − L·(ω × m)"
    )
    ap.add_argument(
        "--eskf", action="append", default=[], metavar="JSON",
        help='best with its plain-path ESKF settings changed, the compass as is, e.g. \'{"mag_learn_tau_s": 20}\' '
        'or \'{"schedule": {"mag_norm_tolerance": 0.12}}\' (repeatable; only these runs with --only-eskf)',
    )  # fmt: skip
    ap.add_argument(
        "--drop-above-deg-s", type=float, nargs="*", default=[],
        help="also best with the reading dropped (NaN) where the gyro turns faster than this, for L 0 and each --delays-ms",
    )  # fmt: skip
    ap.add_argument(
        "--tstick", type=Path, metavar="DIR",
        help="instead: the RepoIMU T-stick check (../shared/data/repoimu_tstick) with --drop-above-deg-s",
    )  # fmt: skip
    ap.add_argument(
        "--trace", metavar="TRIAL", help="instead: per-5-s trace of one trial (its two-digit number)"
    )
    ap.add_argument(
        "--trace-blank", type=float, nargs=2, metavar=("T0", "T1"), help="with --trace: no compass T0–T1 s"
    )
    ap.add_argument("--only-eskf", action="store_true", help="run only the --eskf variants (and best as is)")
    ap.add_argument(
        "--oracle-gyro", action="store_true",
        help="best's runs (and --trace) with the reference's own rotation as the gyro (plus the rests' bias): no gyro drift left",
    )  # fmt: skip
    ap.add_argument(
        "--gyro-rate-scale", type=float, nargs=3, metavar=("NX", "NY", "NZ"),
        help="the gyro read as ω − N_a·|ω|·ω_a first (a scale error growing with the rate, per rad/s; --gyro-models fits it)",
    )  # fmt: skip
    ap.add_argument(
        "--rests", action="store_true",
        help="instead: at each rest, the compass's azimuth with the reference and the gyro's heading error over the motion before",
    )  # fmt: skip
    ap.add_argument(
        "--gyro-models", type=float, nargs="?", const=5.0, metavar="WINDOW_S",
        help="instead: candidate causes of the gyro's heading drift fitted on one half of the trials, tested on the other",
    )  # fmt: skip
    ap.add_argument(
        "--motion", action="store_true",
        help="instead: per trial, what a late reading is off by in that motion and the gyro's heading drift",
    )  # fmt: skip
    args = ap.parse_args(argv)
    if args.tstick is not None:
        tstick_check(args.tstick, args.drop_above_deg_s)
        return 0
    paths = find_broad_trials(args.data) if args.data.is_dir() else []
    if not paths:
        print(f"skipped: no BROAD trials at {args.data} (use --data DIR)", file=sys.stderr)
        return 0
    if args.trace is not None:
        match = [p for p in paths if p.name.startswith(args.trace)]
        if not match:
            print(f"no trial {args.trace!r} in {args.data}", file=sys.stderr)
            return 2
        blank = tuple(args.trace_blank) if args.trace_blank else None
        rec = load_broad_trial(match[0])
        if args.oracle_gyro:
            rec.gyro_rad_s = oracle_gyro(rec)
        trace(rec, blank, args.delays_ms[-1] if args.delays_ms else 10.0)
        return 0
    recs = [load_broad_trial(p) for p in paths]
    if args.gyro_rate_scale is not None:
        for r in recs:
            r.gyro_rad_s = rate_scaled_gyro(r.gyro_rad_s, np.asarray(args.gyro_rate_scale))
    if args.motion:
        motion_report(recs)
        return 0
    if args.rests:
        rests_report(recs)
        return 0
    if args.gyro_models is not None:
        gyro_models_report(recs, args.gyro_models)
        return 0
    first = recs[0]
    shifts = (0, -2, -3, -4, -5, -6)

    print("A perfect-attitude compass (reading i against the reference at i + shift), azimuth RMS, degrees;")
    print(
        "gyro: best k with gyro[i + k] ≈ reference rate at i + ½; delay: ṁ + ω×m ≈ L·(ω̇×m), ms behind the gyro"
    )
    print(
        f"{'trial':32s} "
        + " ".join(f"{s:>6d}" for s in shifts)
        + "  best  gyro k  delay ms  repeats  ‖m‖ rest / moving µT"
    )
    for rec in recs:
        e = [rms(*azimuth_error_deg(rec, rec.mag_ut, s)) for s in shifts]
        k = gyro_shift_samples(rec)
        d = compass_delay_s(rec.gyro_rad_s, rec.mag_ut, float(rec.dt_s[0])) * 1e3
        rep = float(np.mean(np.all(rec.mag_ut[1:] == rec.mag_ut[:-1], axis=1)))
        n0, n1 = rest_and_motion_norm_ut(rec)
        print(
            f"{rec.name[:32]:32s} "
            + " ".join(f"{x:6.2f}" for x in e)
            + f"  {shifts[int(np.argmin(e))]:4d}  {k:+6d}  {d:8.2f}  {rep:7.3f}  {n0:5.1f} {n1:5.1f}"
        )

    shift = -4
    a01, b01, f01 = truth_calibration(first, shift, fit_field=True)
    print(
        f"\nCalibration upper bound at shift {shift} (azimuth RMS, deg; own: A, b and the field f fitted with the reference, "
        "error against f; 01: trial 01's A, b), and windows"
    )
    print(
        f"{'trial':32s} {'as is':>6s} {'own':>6s} {'01':>6s} | {'1s':>5s} {'shift':>5s} | own: {'1s':>5s} {'shift':>5s}"
    )
    rate = 1.0 / float(first.dt_s[0])
    for rec in recs:
        e0, m0 = azimuth_error_deg(rec, rec.mag_ut, shift)
        a, b, f = truth_calibration(rec, shift, fit_field=True)
        e1, m1 = azimuth_error_deg(rec, apply_calibration(rec.mag_ut, a, b), shift, f)
        e2, m2 = azimuth_error_deg(rec, apply_calibration(rec.mag_ut, a01, b01), shift)
        w0 = window_maxima(e0, m0, rate)
        w1 = window_maxima(e1, m1, rate)
        print(
            f"{rec.name[:32]:32s} {rms(e0, m0):6.2f} {rms(e1, m1):6.2f} {rms(e2, m2):6.2f} | "
            f"{w0[0]:5.1f} {w0[1]:5.1f} |      {w1[0]:5.1f} {w1[1]:5.1f}"
        )
    print(
        "\nmagcal.fit_ellipsoid on each trial's scored readings (no reference); the raw norm's spread (1 σ)"
    )
    for rec in recs:
        norm = np.linalg.norm(rec.mag_ut[rec.scored], axis=1)
        print(f"{rec.name[:32]:32s} {ellipsoid_report(rec)}  ‖m‖ σ {100 * norm.std() / norm.mean():.1f} %")
    if args.no_filter:
        return 0

    variants: dict[str, Callable[[Recording], Array]] = {"as is": lambda r: r.mag_ut}
    for seed in (1, 2, 3):
        variants[f"+0.001 uT noise, seed {seed}"] = lambda r, seed=seed: (
            r.mag_ut + 1e-3 * np.random.default_rng(seed).standard_normal(r.mag_ut.shape)
        )
    variants["own truth calibration"] = lambda r: apply_calibration(
        r.mag_ut, *truth_calibration(r, shift)[:2]
    )
    ellipsoids = {r.name: ellipsoid_calibration(r) for r in recs}
    print(
        "\nmagcal.fit_ellipsoid on each trial's own scored readings: "
        + " ".join(f"{r.name[:2]}:{'fit' if ellipsoids[r.name] is not None else 'refused'}" for r in recs)
    )

    def own_ellipsoid(r: Recording) -> Array:
        cal = ellipsoids[r.name]
        return r.mag_ut if cal is None else apply_calibration(r.mag_ut, *cal)

    variants["own ellipsoid (magcal)"] = own_ellipsoid
    cal01 = ellipsoids[first.name]
    if cal01 is not None:
        variants[f"{first.name[:2]}'s ellipsoid on all"] = lambda r: apply_calibration(r.mag_ut, *cal01)
    for ms in args.delays_ms:
        variants[f"m - L(w x m), L {ms:g} ms"] = lambda r, ms=ms: delay_removed(r, ms * 1e-3)
    for limit in args.drop_above_deg_s:
        for ms in (0.0, *args.delays_ms):
            variants[f"L {ms:g} ms, NaN > {limit:g} deg/s"] = lambda r, ms=ms, limit=limit: dropped_above(
                delay_removed(r, ms * 1e-3), r.gyro_rad_s, limit
            )
    if args.oracle_gyro:
        for r in recs:
            r.gyro_rad_s = oracle_gyro(r)
    print(
        "\nbest's heading RMS (BROAD scoring), degrees, with the compass input edited"
        + (" (the oracle gyro: the reference's rotation)" if args.oracle_gyro else "")
    )
    print(f"{'variant':28s} " + " ".join(f"{r.name[:2]:>5s}" for r in recs))
    runs: list[tuple[str, Callable[[Recording], Array], BestSettings | None]] = [
        (name, make, None) for name, make in variants.items() if not args.only_eskf or name == "as is"
    ]
    runs += [(f"eskf {text}", variants["as is"], best_settings_with(json.loads(text))) for text in args.eskf]
    for name, make, settings in runs:
        h = {r.name[:2]: best_heading_rms(r, make(r), settings) for r in recs}
        print(
            f"{name:28s} " + " ".join(f"{h[r.name[:2]]:5.2f}" for r in recs) + "   " + _groups(h), flush=True
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
