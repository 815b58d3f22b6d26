r"""Magnetometer hard- and soft-iron calibration: an ellipsoid fit with quality figures.

A magnetometer on a vehicle measures ``m_raw = S·m + o`` (+ noise): the
vehicle's permanent magnets add a constant *hard-iron* offset ``o`` and its
soft iron (and the sensor's own scale/cross-axis errors) distort the field by
a matrix ``S``.  Over many orientations the true field ``m`` (constant length
F) traces a sphere, so ``m_raw`` traces an ellipsoid.  Fitting the ellipsoid
gives the correction applied by :class:`mavahrs.sensors.calibration.MagCalibration`:

    m_cal = M·(m_raw − o),      M = S⁻¹ (symmetric, positive definite).

Only the symmetric part of ``S⁻¹`` is observable from field lengths; a
rotation of the sensor against the body cannot be seen without attitude
reference and is left to the axis remap.  ``M`` is scaled so the corrected
field has the expected strength F (World Magnetic Model or given), or, when
F is unknown, the ellipsoid's mean radius.

Method:

1. algebraic fit of the general quadric ``xᵀAx + 2bᵀx + c = 0`` to the
   normalised data (smallest singular vector; Li & Griffiths 2004 use a
   constrained variant, the unconstrained one is the usual starting point),
   giving centre ``o = −A⁻¹b`` and shape ``A/(oᵀAo − c)`` whose symmetric
   square root maps the ellipsoid onto the unit sphere;
2. refinement of (o, M) by non-linear least squares on the geometric-ish
   residual ``‖M(m_raw − o)‖ − F`` (Levenberg–Marquardt on the 9 unknowns,
   soft-L1 loss against outliers, analytic Jacobian).

Quality figures: residual RMS (µT and % of F), orientation coverage (the
fraction of 60 near-equal-area direction cells on the sphere that the
corrected field visits), the weakest/strongest spread ratio of those
directions, the conditioning of the fit, and how strong the soft-iron
distortion is.  A fit from a recording that does not cover the sphere is
refused (its soft iron is unobservable along the missing directions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.errors import DataError
from mavahrs.geometry.quaternion import rotate
from mavahrs.sensors.calibration import MagCalibration

__all__ = [
    "MagFitSettings",
    "MagCalibrationFit",
    "fit_ellipsoid",
    "orientation_coverage",
    "magnetic_heading_error_rad",
    "MagRecording",
    "load_mag_recording",
    "MagCalibrationReport",
    "calibrate_recording",
    "calibration_toml",
    "format_report",
    "write_calibration_toml",
]

Array = NDArray[np.float64]

_COVERAGE_CELLS = 60


@dataclass(frozen=True)
class MagFitSettings:
    """When a magnetometer calibration fit is accepted.

    Attributes:
        min_samples: fewer valid samples than this are refused.
        min_coverage: orientation coverage (fraction of direction cells
            visited, 0–1) below which the fit is refused: a recording turned
            only about one axis leaves the soft iron unobservable.
        warn_coverage: coverage below which the fit is accepted with a warning.
        max_residual_percent: residual RMS above this % of the field strength
            gives a warning (disturbances during the recording, or a fit that
            did not converge).
        max_axis_ratio: a soft-iron matrix whose largest/smallest eigenvalue
            ratio exceeds this gives a warning (a strong distortion; or a bad
            fit).
        min_cell_samples: samples a direction cell needs to count as covered.
        max_fit_condition: a refinement Jacobian with a larger condition
            number means some calibration parameters are not determined by
            the data: refused (a good full-sphere recording gives ~100).
    """

    min_samples: int = 100
    min_coverage: float = 0.35
    warn_coverage: float = 0.6
    max_residual_percent: float = 3.0
    max_axis_ratio: float = 1.5
    min_cell_samples: int = 2
    max_fit_condition: float = 1e4

    def __post_init__(self) -> None:
        if self.min_samples < 12:
            raise ValueError(f"min_samples must be ≥ 12 (9 unknowns), got {self.min_samples}")
        if not 0.0 <= self.min_coverage <= self.warn_coverage <= 1.0:
            raise ValueError(
                f"need 0 ≤ min_coverage ≤ warn_coverage ≤ 1, got {self.min_coverage}, {self.warn_coverage}"
            )
        if not (
            self.max_residual_percent > 0
            and self.max_axis_ratio >= 1.0
            and self.min_cell_samples >= 1
            and self.max_fit_condition > 1.0
        ):
            raise ValueError(
                "max_residual_percent must be > 0, max_axis_ratio ≥ 1, min_cell_samples ≥ 1, max_fit_condition > 1"
            )


@dataclass(frozen=True)
class MagCalibrationFit:
    """A fitted magnetometer calibration and how good it is.

    Attributes:
        offset_ut: hard-iron offset o, µT, sensor axes.
        matrix: soft-iron correction M (symmetric, 3×3 rows); m_cal = M·(m − o).
        field_strength_ut: the strength the corrected field is scaled to, µT.
        strength_source: where that strength came from (``"given"``,
            ``"WMM-2025"`` …, or ``"fit"`` = the ellipsoid's mean radius).
        samples: valid samples used.
        residual_rms_ut: RMS of ‖m_cal‖ − F over the samples, µT.
        residual_rms_percent: the same as % of F.
        raw_residual_rms_ut: RMS of ‖m_raw‖ − F before calibration, µT.
        coverage: fraction of direction cells visited (0–1).
        direction_spread: smallest/largest eigenvalue of the scatter of the
            corrected unit directions (1/3 each when uniform; 0 when the
            directions lie in a plane), as a ratio 0–1.
        fit_condition: condition number of the refinement's Jacobian (large:
            some parameters are poorly determined by the data).
        axis_ratio: largest/smallest eigenvalue of M (1 = no soft iron).
        warnings: human-readable problems found (empty = good).
    """

    offset_ut: tuple[float, float, float]
    matrix: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
    field_strength_ut: float
    strength_source: str
    samples: int
    residual_rms_ut: float
    residual_rms_percent: float
    raw_residual_rms_ut: float
    coverage: float
    direction_spread: float
    fit_condition: float
    axis_ratio: float
    warnings: tuple[str, ...] = field(default=())

    def apply(self, mag_ut: ArrayLike) -> Array:
        """Correct ``(3,)`` or ``(N, 3)`` raw readings."""
        m = np.asarray(mag_ut, dtype=np.float64)
        return (m - np.asarray(self.offset_ut)) @ np.asarray(self.matrix).T

    def to_calibration(self) -> MagCalibration:
        """The settings object the pipeline applies (``CalibrationSettings.mag``)."""
        return MagCalibration(offset_ut=self.offset_ut, matrix=self.matrix)


# --------------------------------------------------------------------------- coverage


def _fibonacci_cells(n: int) -> Array:
    """``n`` near-uniform unit vectors (Fibonacci lattice), the centres of the coverage cells."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - z * z)
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def orientation_coverage(directions: ArrayLike, *, cells: int = _COVERAGE_CELLS, min_cell_samples: int = 2) -> float:
    """Fraction of ``cells`` direction cells holding ≥ ``min_cell_samples`` of the (N, 3) vectors."""
    d = np.asarray(directions, dtype=np.float64)
    n = np.linalg.norm(d, axis=1)
    d = d[n > 0] / n[n > 0, None]
    if d.size == 0:
        return 0.0
    centres = _fibonacci_cells(cells)
    nearest = np.argmax(d @ centres.T, axis=1)
    counts = np.bincount(nearest, minlength=cells)
    return float(np.count_nonzero(counts >= min_cell_samples) / cells)


def _direction_spread(directions: Array) -> float:
    u = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    ev = np.linalg.eigvalsh(u.T @ u / len(u))
    return float(ev[0] / ev[-1]) if ev[-1] > 0 else 0.0


# --------------------------------------------------------------------------- fit


def _algebraic_fit(m: Array) -> tuple[Array, Array]:
    """Quadric fit → (centre, shape W with ‖W(m − centre)‖ ≈ 1).  Raises DataError if not an ellipsoid."""
    mu = m.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((m - mu) ** 2, axis=1)))) or 1.0
    x, y, z = ((m - mu) / scale).T
    design = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z, np.ones_like(x)], axis=1)
    _, _, vt = np.linalg.svd(design, full_matrices=False)
    v = vt[-1]
    a = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    b = v[6:9]
    c = v[9]
    if np.linalg.det(a) < 0:  # the sign of a null vector is arbitrary
        a, b, c = -a, -b, -c
    try:
        centre = -np.linalg.solve(a, b)
    except np.linalg.LinAlgError:
        raise DataError("magnetometer data do not determine an ellipsoid (degenerate quadric)") from None
    r = float(centre @ a @ centre - c)
    shape = a / r if r != 0 else a
    ev, vec = np.linalg.eigh(shape)
    if not np.all(ev > 0):
        raise DataError(
            "magnetometer data do not fit an ellipsoid (the orientations cover too little of the sphere, "
            "or the field was disturbed): record again while turning the vehicle through all attitudes"
        )
    w = vec @ np.diag(np.sqrt(ev)) @ vec.T  # symmetric square root
    return mu + scale * centre, w / scale


def _sphere_fit(m: Array) -> tuple[Array, Array]:
    """Least-squares sphere → (centre, I / radius): the starting point when the general quadric is no ellipsoid.

    A nearly calibrated magnetometer (soft iron ≈ I) turned through half the sphere or so, with noise of
    ~1 % of the field, can give a quadric whose smallest singular vector is a hyperboloid (firmware_sim's
    `flips`: coverage 50 %, |B| 57.0–59.3 µT).  A sphere, ‖m‖² = 2 m·c + k (linear in c and k), always
    exists; :func:`_refine` then fits the full ellipsoid from it.  Raises DataError when it is degenerate.
    """
    design = np.column_stack([2.0 * m, np.ones(len(m))])
    sol, *_ = np.linalg.lstsq(design, np.sum(m * m, axis=1), rcond=None)
    centre = sol[:3]
    r2 = float(sol[3] + centre @ centre)
    if not (math.isfinite(r2) and r2 > 0.0):
        raise DataError(
            "magnetometer data do not fit an ellipsoid (the orientations cover too little of the sphere, "
            "or the field was disturbed): record again while turning the vehicle through all attitudes"
        )
    return centre, np.eye(3) / math.sqrt(r2)


def _sym(p: Array) -> Array:
    return np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])


def _residuals_jacobian(m: Array, p: Array, strength: float) -> tuple[Array, Array]:
    """r = ‖M d‖ − F with d = m − o, and ∂r/∂p (p = o, M₀₀, M₁₁, M₂₂, M₀₁, M₀₂, M₁₂).

    With u = M d/‖M d‖: ∂r/∂o = −uᵀM, ∂r/∂M_jk = u_j d_k (+ u_k d_j off the diagonal).
    """
    d = m - p[:3]
    mat = _sym(p[3:])
    md = d @ mat.T
    n = np.linalg.norm(md, axis=1)
    u = md / np.maximum(n, 1e-12)[:, None]
    j = np.empty((len(m), 9))
    j[:, 0:3] = -(u @ mat)
    j[:, 3:6] = u * d
    j[:, 6] = u[:, 0] * d[:, 1] + u[:, 1] * d[:, 0]
    j[:, 7] = u[:, 0] * d[:, 2] + u[:, 2] * d[:, 0]
    j[:, 8] = u[:, 1] * d[:, 2] + u[:, 2] * d[:, 1]
    return n - strength, j


def _refine(m: Array, p0: Array, strength: float, max_iter: int = 60) -> tuple[Array, Array]:
    """Levenberg–Marquardt with a soft-L1 robust loss (IRLS weights); returns (p, JᵀWJ at p).

    ρ(r) = 2f²(√(1 + (r/f)²) − 1) with f = 5 % of F: quadratic for small
    residuals, linear for outliers (a moment near a magnet).  9 unknowns, so
    the normal equations are solved directly (Marquardt's diagonal damping).
    """
    f2 = (0.05 * strength) ** 2

    def cost_of(r: Array) -> float:
        return float(np.sum(np.sqrt(1.0 + r * r / f2) - 1.0))

    p = p0.copy()
    r, j = _residuals_jacobian(m, p, strength)
    cost = cost_of(r)
    lam = 1e-3
    normal = np.eye(9)
    for _ in range(max_iter):
        w = 1.0 / np.sqrt(1.0 + r * r / f2)  # IRLS weight of the soft-L1 loss
        jw = j * w[:, None]
        normal = jw.T @ j
        grad = jw.T @ r
        diag = np.diag(np.diag(normal)) + 1e-12 * np.eye(9)
        improved = False
        for _ in range(10):
            try:
                step = -np.linalg.solve(normal + lam * diag, grad)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            r_new, j_new = _residuals_jacobian(m, p + step, strength)
            c_new = cost_of(r_new)
            if c_new < cost:
                p, r, j, improved = p + step, r_new, j_new, True
                lam = max(lam / 3.0, 1e-9)
                break
            lam *= 10.0
        if not improved:
            break
        done = c_new > cost * (1.0 - 1e-10) or np.linalg.norm(step) < 1e-9 * (1.0 + np.linalg.norm(p))
        cost = c_new
        if done:
            break
    w = 1.0 / np.sqrt(1.0 + r * r / f2)
    return p, (j * w[:, None]).T @ j


def fit_ellipsoid(
    mag_ut: ArrayLike,
    expected_strength_ut: float | None = None,
    *,
    settings: MagFitSettings | None = None,
    strength_source: str = "given",
    force: bool = False,
) -> MagCalibrationFit:
    """Fit hard- and soft-iron calibration to raw magnetometer readings.

    Args:
        mag_ut: (N, 3) raw readings, µT, sensor axes; non-finite and all-zero
            rows are ignored.
        expected_strength_ut: the local field strength F (World Magnetic Model
            or measured); None = scale to the ellipsoid's mean radius.
        settings: acceptance thresholds.
        strength_source: label for ``expected_strength_ut`` in the report.
        force: return a fit even when the orientation coverage is too poor
            (with a warning) instead of raising.

    Raises:
        DataError: too few samples; coverage below ``min_coverage`` or an
            ill-conditioned fit (unless ``force``); data that do not describe
            an ellipsoid.
    """
    s = settings if settings is not None else MagFitSettings()
    m = np.asarray(mag_ut, dtype=np.float64).reshape(-1, 3)
    keep = np.all(np.isfinite(m), axis=1) & np.any(m != 0.0, axis=1)
    m = m[keep]
    if len(m) < s.min_samples:
        raise DataError(f"only {len(m)} valid magnetometer samples; need at least {s.min_samples}")
    if expected_strength_ut is not None and not (math.isfinite(expected_strength_ut) and expected_strength_ut > 0):
        raise ValueError(f"expected_strength_ut must be a positive number of µT, got {expected_strength_ut!r}")

    try:
        centre0, w0 = _algebraic_fit(m)
    except DataError:
        centre0, w0 = _sphere_fit(m)  # the refinement below fits the soft iron and judges the coverage
    if expected_strength_ut is None:
        ev = np.linalg.eigvalsh(w0)
        strength = float(np.prod(1.0 / ev) ** (1.0 / 3.0))  # geometric mean semi-axis
        source = "fit"
    else:
        strength = float(expected_strength_ut)
        source = strength_source
    mat0 = strength * w0

    p0 = np.concatenate([centre0, [mat0[0, 0], mat0[1, 1], mat0[2, 2], mat0[0, 1], mat0[0, 2], mat0[1, 2]]])
    p, normal = _refine(m, p0, strength)
    offset = p[:3]
    matrix = _sym(p[3:])
    ev = np.linalg.eigvalsh(matrix)
    if not np.all(ev > 0):
        raise DataError("the magnetometer fit did not converge to a valid (positive definite) soft-iron matrix")

    corrected = (m - offset) @ matrix.T
    res = np.linalg.norm(corrected, axis=1) - strength
    rms = float(np.sqrt(np.mean(res**2)))
    raw_rms = float(np.sqrt(np.mean((np.linalg.norm(m, axis=1) - strength) ** 2)))
    coverage = orientation_coverage(corrected, min_cell_samples=s.min_cell_samples)
    spread = _direction_spread(corrected)
    eig_n = np.linalg.eigvalsh(normal)  # of Jᵀ W J: squares of the weighted Jacobian's singular values
    fit_condition = float(math.sqrt(eig_n[-1] / eig_n[0])) if eig_n[0] > 0 else math.inf
    axis_ratio = float(ev[-1] / ev[0])

    # Judged on the *fitted* directions: a fit that failed for lack of coverage
    # collapses them (and its Jacobian becomes singular).
    poorly_determined = coverage < s.min_coverage or fit_condition > s.max_fit_condition
    if poorly_determined and not force:
        raise DataError(
            f"orientation coverage {coverage:.0%} (need {s.min_coverage:.0%}), fit condition {fit_condition:.3g} "
            f"(limit {s.max_fit_condition:.3g}): the recording turned the vehicle through too few attitudes "
            "to calibrate the magnetometer — turn it through all of them (nose up and down, on each side, "
            "upside down) or force the fit"
        )
    warnings: list[str] = []
    if poorly_determined:
        warnings.append(
            f"orientation coverage {coverage:.0%}, fit condition {fit_condition:.3g}: fit forced, do not trust it"
        )
    elif coverage < s.warn_coverage:
        warnings.append(
            f"orientation coverage {coverage:.0%} is below {s.warn_coverage:.0%}: "
            "the soft-iron part is poorly determined; record more attitudes"
        )
    pct = 100.0 * rms / strength
    if pct > s.max_residual_percent:
        warnings.append(
            f"residual {rms:.2f} µT ({pct:.1f}% of the field) exceeds {s.max_residual_percent:g}%: "
            "magnetic disturbances during the recording, or a wrong expected field strength"
        )
    if axis_ratio > s.max_axis_ratio:
        warnings.append(f"strong soft-iron distortion (axis ratio {axis_ratio:.2f}): check the sensor's mounting")
    if float(np.linalg.norm(offset)) > 3.0 * strength:
        warnings.append(f"hard-iron offset {np.linalg.norm(offset):.0f} µT is very large: a magnet close to the sensor?")

    return MagCalibrationFit(
        offset_ut=(float(offset[0]), float(offset[1]), float(offset[2])),
        matrix=tuple(tuple(float(v) for v in row) for row in matrix),  # type: ignore[arg-type]
        field_strength_ut=strength,
        strength_source=source,
        samples=int(len(m)),
        residual_rms_ut=rms,
        residual_rms_percent=pct,
        raw_residual_rms_ut=raw_rms,
        coverage=coverage,
        direction_spread=spread,
        fit_condition=fit_condition,
        axis_ratio=axis_ratio,
        warnings=tuple(warnings),
    )


# --------------------------------------------------------------------------- heading


def magnetic_heading_error_rad(
    mag_body_ut: ArrayLike, q_body_to_ned: ArrayLike, declination_rad: float = 0.0
) -> Array:
    """Heading error a magnetometer-only heading would have, given the true attitude.

    The body-frame field is rotated into NED with the reference attitude; its
    horizontal direction should point at magnetic north, i.e. azimuth
    ``declination_rad`` in a true-north frame (0 when the reference frame is
    magnetic).  Returns the signed angle (−π, π] by which it does not.
    """
    m_ned = rotate(q_body_to_ned, mag_body_ut)
    az = np.arctan2(m_ned[..., 1], m_ned[..., 0]) - declination_rad
    return np.angle(np.exp(1j * az))


# --------------------------------------------------------------------------- recordings (calibrate-mag)


@dataclass(frozen=True)
class MagRecording:
    """Magnetometer samples read from a recording, with what is known about them.

    Attributes:
        mag_ut: (N, 3) field, µT, sensor (= body) axes; rows of NaN where absent.
        t_ms: (N,) sample times, ms of the autopilot's boot clock (NaN for CSV).
        source: what was read, e.g. ``"RAW_IMU (ardupilot profile)"`` or ``"CSV"``.
        already_calibrated: the autopilot had already applied its own
            hard/soft-iron calibration (from the scaling profile).
        position: (lat°, lon°, alt m) of the first GNSS fix, or None.
        decimal_year: date of the recording (SYSTEM_TIME, else the tlog's
            own timestamps), or None.
        attitude_t_ms: times of the autopilot's ATTITUDE messages, ms.
        attitude_q: (M, 4) the autopilot's attitude (true north), for a
            heading check; empty when absent.
    """

    mag_ut: Array
    t_ms: Array
    source: str
    already_calibrated: bool = False
    position: tuple[float, float, float] | None = None
    decimal_year: float | None = None
    attitude_t_ms: Array = field(default_factory=lambda: np.zeros(0))
    attitude_q: Array = field(default_factory=lambda: np.zeros((0, 4)))


_MAG_MESSAGES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
_MAV_AUTOPILOT_INVALID = 8


class _Row:
    """A structured-array record seen as a pymavlink-like message (attribute access, get_type)."""

    __slots__ = ("_rec", "_type")

    def __init__(self, rec: Any, kind: str) -> None:
        self._rec = rec
        self._type = kind

    def get_type(self) -> str:
        return self._type

    def __getattr__(self, name: str) -> Any:
        try:
            return self._rec[name].item()
        except (KeyError, ValueError):
            raise AttributeError(name) from None


def _read_csv(path: str) -> MagRecording:
    import csv

    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise DataError(f"{path}: empty CSV file")
    header = [h.strip().lower() for h in rows[0]]
    try:
        cols = [header.index(c) for c in ("mx", "my", "mz")]
    except ValueError:
        raise DataError(f"{path}: CSV needs a header with columns mx, my, mz (µT); found {', '.join(header)}") from None
    try:
        mag = np.array([[float(r[c]) for c in cols] for r in rows[1:] if r], dtype=np.float64).reshape(-1, 3)
    except (ValueError, IndexError) as exc:
        raise DataError(f"{path}: unreadable number in the mx, my, mz columns ({exc})") from None
    return MagRecording(mag, np.full(len(mag), np.nan), "CSV (mx, my, mz µT)")


def load_mag_recording(path: str, *, message: str | None = None, profile: str = "auto") -> MagRecording:
    """Read magnetometer samples from a tlog or a CSV (columns ``mx, my, mz`` in µT).

    For a tlog the scaling profile (``auto`` = from the autopilot's
    HEARTBEAT) converts the wire units and says whether the autopilot already
    calibrated the magnetometer; ``message`` picks the IMU message (default:
    the one with the most magnetometer samples, the profile's primary message
    on a tie).  The first GNSS fix, the date and the autopilot's ATTITUDE are
    read too (expected field strength, heading check).

    Raises:
        DataError: unreadable file or no magnetometer data in it.
    """
    import os

    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    if os.path.isdir(path):
        raise DataError(f"{path} is a directory: calibrate-mag takes one .tlog or .csv file")
    if path.lower().endswith(".csv"):
        return _read_csv(path)
    from mavahrs.logs import a_format, sniff

    kind = sniff(path)
    if kind in ("dataflash", "ulog"):  # read as a tlog it said "no magnetometer samples in RAW_IMU"
        raise DataError(f"{path} is {a_format(kind)}: calibrate-mag reads a telemetry log (.tlog) or a CSV with "
                        "columns mx, my, mz in µT; record a tlog of the vehicle turning through many attitudes "
                        "(e.g. with MAVProxy or mavahrs run --log)")

    from mavahrs.geometry.rotation import from_euler_rad
    from mavahrs.protocol.fast_tlog import read_tlog_arrays
    from mavahrs.sensors.geomag import decimal_year_from_unix_s
    from mavahrs.sensors.profiles import get_profile, profile_for_autopilot
    from mavahrs.sensors.scaling import Scaler

    types = (*_MAG_MESSAGES, "HEARTBEAT", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "SYSTEM_TIME", "ATTITUDE")
    try:
        arrays = read_tlog_arrays(path, types)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read as a tlog ({exc})") from None
    if all(len(a) == 0 for a in arrays.values()):  # say what the file is before what it lacks
        from mavahrs.protocol.fast_tlog import scan_tlog

        if os.path.getsize(path) == 0:
            raise DataError(f"{path}: the file is empty: expected a telemetry log (.tlog) or a CSV")
        if scan_tlog(path, None).msgid.shape[0] == 0:
            raise DataError(f"{path}: no MAVLink messages in this file: expected a telemetry log (.tlog, "
                            "as MAVProxy, QGroundControl, Mission Planner and mavahrs write them) or a CSV")  # fmt: skip
    if profile == "auto":
        hb = arrays["HEARTBEAT"]
        hb = hb[hb["autopilot"] != _MAV_AUTOPILOT_INVALID]
        prof = profile_for_autopilot(int(hb["autopilot"][0])) if len(hb) else get_profile("generic")
    else:
        prof = get_profile(profile)
    counts = {
        name: int(np.count_nonzero((arrays[name]["xmag"] != 0) | (arrays[name]["ymag"] != 0) | (arrays[name]["zmag"] != 0)))
        for name in _MAG_MESSAGES
        if prof.scale_for(name) is not None
    }
    if message is None:  # the profile's primary message unless another has clearly more samples
        best = max(counts.values(), default=0)
        primary = prof.primary_message
        message = primary if counts.get(primary, 0) >= 0.9 * best > 0 else max(counts, key=counts.__getitem__)
    message = message.upper()
    if counts.get(message, 0) == 0:
        found = ", ".join(f"{k} {v}" for k, v in counts.items() if v) or "none"
        raise DataError(f"{path}: no magnetometer samples in {message} (samples per message: {found})")
    scaler = Scaler(prof)
    rows = arrays[message]
    mag = np.full((len(rows), 3), np.nan)
    t_ms = np.full(len(rows), np.nan)
    for k in range(len(rows)):
        v = scaler.scale(_Row(rows[k], message))
        if v is None:
            continue
        mag[k] = v[8:11]
        t_ms[k] = v[1] / 1000.0
    position = None
    gpi = arrays["GLOBAL_POSITION_INT"]
    gpi = gpi[(gpi["lat"] != 0) | (gpi["lon"] != 0)]
    gps = arrays["GPS_RAW_INT"]
    gps = gps[gps["fix_type"] >= 2]
    if len(gpi):
        position = (gpi["lat"][0] * 1e-7, gpi["lon"][0] * 1e-7, gpi["alt"][0] * 1e-3)
    elif len(gps):
        position = (gps["lat"][0] * 1e-7, gps["lon"][0] * 1e-7, gps["alt"][0] * 1e-3)
    year = None
    st = arrays["SYSTEM_TIME"]
    st = st[st["time_unix_usec"] > 1262304000 * 10**6]
    if len(st):
        year = decimal_year_from_unix_s(st["time_unix_usec"][0] * 1e-6)
    elif len(rows) and rows["t_us"][0] > 1262304000 * 10**6:
        year = decimal_year_from_unix_s(rows["t_us"][0] * 1e-6)  # the tlog's own (logging) clock
    att = arrays["ATTITUDE"]
    q_att = from_euler_rad(att["roll"], att["pitch"], att["yaw"]) if len(att) else np.zeros((0, 4))
    scale = prof.scale_for(message)
    return MagRecording(
        mag_ut=mag,
        t_ms=t_ms,
        source=f"{message} ({prof.name} profile)",
        already_calibrated=bool(scale is not None and scale.mag_calibrated),
        position=position,
        decimal_year=year,
        attitude_t_ms=att["time_boot_ms"].astype(np.float64) if len(att) else np.zeros(0),
        attitude_q=q_att,
    )


# --------------------------------------------------------------------------- the whole job


@dataclass(frozen=True)
class MagCalibrationReport:
    """What ``mavahrs calibrate-mag`` found: the fit, the recording and a heading check.

    Attributes:
        fit: the calibration and its quality figures.
        recording: the data it came from.
        declination_rad: declination used for the heading check (None: unknown).
        heading_rms_before_deg: RMS heading error of the raw magnetometer
            against the autopilot's attitude (NaN without ATTITUDE).
        heading_rms_after_deg: the same after the calibration.
        warnings: the fit's warnings plus the recording's (already calibrated …).
    """

    fit: MagCalibrationFit
    recording: MagRecording
    declination_rad: float | None
    heading_rms_before_deg: float
    heading_rms_after_deg: float
    warnings: tuple[str, ...]


def calibrate_recording(
    recording: MagRecording,
    *,
    strength_ut: float | None = None,
    position: tuple[float, float, float] | None = None,
    decimal_year: float | None = None,
    settings: MagFitSettings | None = None,
    force: bool = False,
) -> MagCalibrationReport:
    """Fit a recording; the field strength is ``strength_ut``, else the WMM at its position, else the fit's.

    ``position``/``decimal_year`` override what the recording says.
    """
    from mavahrs.sensors.geomag import expected_field

    pos = position if position is not None else recording.position
    year = decimal_year if decimal_year is not None else recording.decimal_year
    model = expected_field(*pos, year) if pos is not None and year is not None else None
    if strength_ut is not None:
        fit = fit_ellipsoid(recording.mag_ut, strength_ut, settings=settings, strength_source="given", force=force)
    elif model is not None:
        where = f"{model.source} at {pos[0]:.4f}, {pos[1]:.4f}"  # type: ignore[index]
        fit = fit_ellipsoid(recording.mag_ut, model.strength_ut, settings=settings, strength_source=where, force=force)
    else:
        fit = fit_ellipsoid(recording.mag_ut, None, settings=settings, force=force)
    warnings = list(fit.warnings)
    if recording.already_calibrated:
        warnings.insert(
            0,
            f"{recording.source}: the autopilot has already calibrated this magnetometer; mavahrs does not "
            "correct it twice (the result is applied only with pipeline.calibration.force_mag_calibration = "
            "true). Calibrate the compass in the autopilot, or read an uncalibrated message.",
        )
    before = after = math.nan
    decl = model.declination_rad if model is not None else None
    if len(recording.attitude_t_ms) and decl is not None and np.any(np.isfinite(recording.t_ms)):
        from mavahrs.service.monitor import align_attitudes

        q_ref = align_attitudes(recording.attitude_t_ms, recording.attitude_q, recording.t_ms, tolerance_ms=100.0)
        ok = np.all(np.isfinite(q_ref), axis=1) & np.all(np.isfinite(recording.mag_ut), axis=1)
        if np.count_nonzero(ok) >= 10:
            e0 = magnetic_heading_error_rad(recording.mag_ut[ok], q_ref[ok], decl)
            e1 = magnetic_heading_error_rad(fit.apply(recording.mag_ut[ok]), q_ref[ok], decl)
            before = float(np.degrees(np.sqrt(np.mean(e0**2))))
            after = float(np.degrees(np.sqrt(np.mean(e1**2))))
    return MagCalibrationReport(fit, recording, decl, before, after, tuple(warnings))


def calibration_toml(fit: MagCalibrationFit) -> str:
    """The ``[pipeline.calibration.mag]`` table for a settings file."""

    def num(v: float) -> str:
        return f"{v:.6g}" if "e" not in f"{v:.6g}" else repr(v)

    o = ", ".join(num(v) for v in fit.offset_ut)
    rows = ",\n    ".join("[" + ", ".join(num(v) for v in row) + "]" for row in fit.matrix)
    return (
        f"# magnetometer calibration: m_cal = matrix · (m − offset_ut); fitted by mavahrs calibrate-mag,\n"
        f"# residual {fit.residual_rms_ut:.2f} µT ({fit.residual_rms_percent:.1f} %), coverage {fit.coverage:.0%}, "
        f"field {fit.field_strength_ut:.2f} µT ({fit.strength_source})\n"
        f"[pipeline.calibration.mag]\n"
        f"offset_ut = [{o}]\n"
        f"matrix = [\n    {rows},\n]\n"
    )


def format_report(report: MagCalibrationReport) -> str:
    """Human-readable summary (what ``calibrate-mag`` prints before the TOML)."""
    fit = report.fit
    rec = report.recording
    ev = np.linalg.eigvalsh(np.asarray(fit.matrix))
    lines = [
        f"recording: {rec.source}, {fit.samples} magnetometer samples"
        + (f", position {rec.position[0]:.5f}, {rec.position[1]:.5f}" if rec.position else ""),
        f"field strength: {fit.field_strength_ut:.2f} µT ({fit.strength_source})",
        f"hard iron (offset): {fit.offset_ut[0]:+.2f} {fit.offset_ut[1]:+.2f} {fit.offset_ut[2]:+.2f} µT "
        f"(|o| = {np.linalg.norm(fit.offset_ut):.2f} µT)",
        f"soft iron: matrix eigenvalues {ev[0]:.3f} {ev[1]:.3f} {ev[2]:.3f} (axis ratio {fit.axis_ratio:.3f})",
        f"fit residual: {fit.residual_rms_ut:.2f} µT RMS = {fit.residual_rms_percent:.2f} % of the field "
        f"(raw: {fit.raw_residual_rms_ut:.2f} µT)",
        f"orientation coverage: {fit.coverage:.0%} of directions, spread {fit.direction_spread:.2f}, "
        f"fit condition {fit.fit_condition:.3g}",
    ]
    if math.isfinite(report.heading_rms_before_deg):
        lines.append(
            f"heading vs the autopilot's attitude: {report.heading_rms_before_deg:.1f}° RMS raw → "
            f"{report.heading_rms_after_deg:.1f}° RMS calibrated"
        )
    lines += [f"WARNING: {w}" for w in report.warnings]
    return "\n".join(lines)


_TABLE_RE = r"^\s*\[pipeline\.calibration\.mag\]\s*(#.*)?$"
# a table header (``[a.b]``, ``[[a]]``), not an array row of numbers inside a multi-line value
_ANY_TABLE_RE = r"^\s*\[\[?\s*[A-Za-z_\"'][^\]]*\]\]?\s*(#.*)?$"


def write_calibration_toml(path: str, fit: MagCalibrationFit) -> None:
    """Put the calibration into settings file ``path`` (created if missing).

    An existing ``[pipeline.calibration.mag]`` table (and the comment lines
    just above it) is replaced; the rest of the file is kept as it is.  The
    result is parsed before it replaces the file.

    Raises:
        ConfigError: the existing file is not valid TOML, or the result is not.
    """
    import os
    import re

    from mavahrs.config import load_toml
    from mavahrs.errors import ConfigError

    old = ""
    if os.path.exists(path):
        load_toml(path)  # refuse to edit a file that is already broken
        with open(path, encoding="utf-8") as f:
            old = f.read()
    lines = old.splitlines()
    start = next((i for i, ln in enumerate(lines) if re.match(_TABLE_RE, ln)), None)
    if start is not None:
        end = start + 1
        while end < len(lines) and not re.match(_ANY_TABLE_RE, lines[end]):
            end += 1
        while end > start + 1 and (not lines[end - 1].strip() or lines[end - 1].lstrip().startswith("#")):
            end -= 1  # keep comments/blank lines that belong to the next table
        while start > 0 and lines[start - 1].lstrip().startswith(("# magnetometer calibration", "# residual")):
            start -= 1  # our own comment above the table
        lines = lines[:start] + lines[end:]
    body = "\n".join(lines).rstrip()
    text = (body + "\n\n" if body else "") + calibration_toml(fit)
    tmp = f"{path}.tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
    try:
        data = load_toml(tmp)
        mag = data["pipeline"]["calibration"]["mag"]
        MagCalibration(offset_ut=tuple(mag["offset_ut"]), matrix=tuple(tuple(r) for r in mag["matrix"]))
    except (ConfigError, KeyError, TypeError) as exc:
        os.unlink(tmp)
        raise ConfigError(f"{path}: could not add the calibration ({exc}); the file is unchanged") from None
    os.replace(tmp, path)
