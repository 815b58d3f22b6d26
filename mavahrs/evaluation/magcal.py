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
   residual ``‖M(m_raw − o)‖ − F`` (``scipy.optimize.least_squares``,
   soft-L1 loss against outliers).

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


def _sym(p: Array) -> Array:
    return np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])


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
    from scipy.optimize import least_squares  # heavy import, only needed here

    s = settings if settings is not None else MagFitSettings()
    m = np.asarray(mag_ut, dtype=np.float64).reshape(-1, 3)
    keep = np.all(np.isfinite(m), axis=1) & np.any(m != 0.0, axis=1)
    m = m[keep]
    if len(m) < s.min_samples:
        raise DataError(f"only {len(m)} valid magnetometer samples; need at least {s.min_samples}")
    if expected_strength_ut is not None and not (math.isfinite(expected_strength_ut) and expected_strength_ut > 0):
        raise ValueError(f"expected_strength_ut must be a positive number of µT, got {expected_strength_ut!r}")

    centre0, w0 = _algebraic_fit(m)
    if expected_strength_ut is None:
        ev = np.linalg.eigvalsh(w0)
        strength = float(np.prod(1.0 / ev) ** (1.0 / 3.0))  # geometric mean semi-axis
        source = "fit"
    else:
        strength = float(expected_strength_ut)
        source = strength_source
    mat0 = strength * w0

    def residuals(p: Array) -> Array:
        corrected = (m - p[:3]) @ _sym(p[3:]).T
        return np.linalg.norm(corrected, axis=1) - strength

    def jacobian(p: Array) -> Array:
        # r = ‖M d‖ − F with d = m − o, u = M d/‖M d‖:  ∂r/∂o = −uᵀM,  ∂r/∂M_jk = u_j d_k (+ u_k d_j off-diagonal)
        d = m - p[:3]
        mat = _sym(p[3:])
        md = d @ mat.T
        u = md / np.linalg.norm(md, axis=1, keepdims=True)
        j = np.empty((len(m), 9))
        j[:, 0:3] = -(u @ mat)
        j[:, 3:6] = u * d
        j[:, 6] = u[:, 0] * d[:, 1] + u[:, 1] * d[:, 0]
        j[:, 7] = u[:, 0] * d[:, 2] + u[:, 2] * d[:, 0]
        j[:, 8] = u[:, 1] * d[:, 2] + u[:, 2] * d[:, 1]
        return j

    p0 = np.concatenate([centre0, [mat0[0, 0], mat0[1, 1], mat0[2, 2], mat0[0, 1], mat0[0, 2], mat0[1, 2]]])
    result = least_squares(
        residuals, p0, jac=jacobian, loss="soft_l1", f_scale=0.05 * strength, x_scale="jac",
        max_nfev=100,  # a well-posed fit converges in ~10; an ill-posed one wanders
    )  # fmt: skip
    p = result.x
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
    sv = np.linalg.svd(result.jac, compute_uv=False)
    fit_condition = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
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
