r"""Constant frame alignment between a reference and an estimate.

A motion-capture reference is measured in the camera's frame and on a marker
body; a filter estimates the sensor's attitude in a north-referenced earth
frame.  Madgwick 2010, eq. (58), relates them by two constant rotations:

    q_meas = q_earth ⊗ q_ref ⊗ q_body

* ``q_earth`` — the camera frame's heading relative to (magnetic) north, a
  rotation about the vertical (eq. (59)–(64) measure it with a pendulum and a
  compass; here it is fitted);
* ``q_body`` — the marker body's misalignment with the sensor axes (eq. (65)
  takes it from the average static error of a reference filter; here it is
  fitted over all scored samples).

Both are least-squares fits of the reference to an estimate, so they remove a
constant offset the filter could not know (a reference that is not
north-referenced, markers glued a few degrees off the IMU axes).  They also
hide any *constant* error the filter makes, so always say which alignment a
number was scored with.  Fitting rules:

* heading: maximise Σ (q_earth · e_i)² over rotations about z, with the
  earth-frame errors ``e_i = q_est ⊗ (q_ref ⊗ q_body)*`` — a 2×2 eigenproblem
  on (e_w, e_z) (the quaternion-averaging solution restricted to the vertical
  axis);
* body: the chordal mean of the body-frame errors
  ``b_i = (q_earth ⊗ q_ref)* ⊗ q_est``: average their rotation matrices and
  take the nearest rotation with Bar-Itzhack's method (Madgwick 2010,
  eq. (56)–(57)), which is exactly what it is for — a quaternion from a matrix
  that is not orthogonal;
* both: alternate the two until they stop changing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.geometry.quaternion import conjugate, multiply, normalize, to_rotation_vector
from mavahrs.geometry.rotation import from_matrix_bar_itzhack, to_matrix

__all__ = [
    "ALIGNMENTS",
    "Alignment",
    "fit_heading_offset",
    "fit_body_misalignment",
    "fit_alignment",
]

Array = NDArray[np.float64]

#: Accepted alignment modes: nothing, heading offset only, heading + body misalignment.
ALIGNMENTS: tuple[str, ...] = ("none", "heading", "heading+body")

_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True)
class Alignment:
    """Constant rotations applied to a reference: ``q_earth ⊗ q_ref ⊗ q_body``.

    Attributes:
        mode: one of :data:`ALIGNMENTS`.
        q_earth: rotation about the vertical (earth frame), scalar first.
        q_body: body-frame misalignment, scalar first.
    """

    mode: str = "none"
    q_earth: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    q_body: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    @property
    def heading_offset_deg(self) -> float:
        """Heading rotation of the reference, degrees, in (−180, 180] (positive about +z)."""
        w, _, _, z = self.q_earth
        return float(np.degrees(2.0 * np.arctan2(z, w) if w >= 0 else 2.0 * np.arctan2(-z, -w)))

    @property
    def body_misalignment_deg(self) -> float:
        """Angle of the body misalignment rotation, degrees."""
        return float(np.degrees(np.linalg.norm(to_rotation_vector(np.array(self.q_body)))))

    def apply(self, q_ref: ArrayLike) -> Array:
        """The aligned reference ``q_earth ⊗ q_ref ⊗ q_body`` (NaN rows stay NaN)."""
        q = np.asarray(q_ref, dtype=np.float64)
        return multiply(multiply(np.array(self.q_earth), q), np.array(self.q_body))

    def describe(self) -> str:
        if self.mode == "none":
            return "none (reference used as recorded)"
        text = f"heading offset {self.heading_offset_deg:+.2f}° fitted"
        if self.mode == "heading+body":
            text += f", body misalignment {self.body_misalignment_deg:.2f}° fitted"
        return text


def _valid_rows(q_est: Array, q_ref: Array, mask: ArrayLike | None) -> NDArray[np.bool_]:
    ok = np.all(np.isfinite(q_est), axis=1) & np.all(np.isfinite(q_ref), axis=1)
    ok &= np.linalg.norm(q_ref, axis=1) > 0.5
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool)
    return ok


def _heading_fit(q_est: Array, q_ref: Array) -> Array:
    e = multiply(q_est, conjugate(q_ref))
    ez = np.stack([e[:, 0], e[:, 3]], axis=1)
    m = ez.T @ ez  # Σ [e_w e_z]ᵀ [e_w e_z]
    _, vecs = np.linalg.eigh(m)
    c, s = vecs[:, -1]
    if c < 0:
        c, s = -c, -s
    return normalize(np.array([c, 0.0, 0.0, s]))


def _body_fit(q_est: Array, q_ref: Array) -> Array:
    b = multiply(conjugate(q_ref), q_est)
    mean_matrix = to_matrix(b).mean(axis=0)
    return np.asarray(from_matrix_bar_itzhack(mean_matrix), dtype=np.float64)


def fit_heading_offset(q_est: ArrayLike, q_ref: ArrayLike, mask: ArrayLike | None = None) -> Alignment:
    """Fit the constant heading rotation ``q_earth`` so that ``q_earth ⊗ q_ref ≈ q_est``."""
    return fit_alignment(q_est, q_ref, mask, mode="heading")


def fit_body_misalignment(q_est: ArrayLike, q_ref: ArrayLike, mask: ArrayLike | None = None) -> Array:
    """Fit only the constant body rotation ``q_body`` so that ``q_ref ⊗ q_body ≈ q_est``."""
    est, ref = _prepare(q_est, q_ref)
    ok = _valid_rows(est, ref, mask)
    if not ok.any():
        return _IDENTITY.copy()
    return _body_fit(est[ok], ref[ok])


def _prepare(q_est: ArrayLike, q_ref: ArrayLike) -> tuple[Array, Array]:
    est = np.atleast_2d(np.asarray(q_est, dtype=np.float64))
    ref = np.atleast_2d(np.asarray(q_ref, dtype=np.float64))
    if est.shape != ref.shape:
        raise ValueError(f"estimate {est.shape} and reference {ref.shape} must have the same shape")
    with np.errstate(invalid="ignore", divide="ignore"):
        ref = ref / np.linalg.norm(ref, axis=1, keepdims=True)
        est = est / np.linalg.norm(est, axis=1, keepdims=True)
    return est, ref


def fit_alignment(
    q_est: ArrayLike,
    q_ref: ArrayLike,
    mask: ArrayLike | None = None,
    *,
    mode: str = "heading",
    iterations: int = 20,
    tolerance_rad: float = 1e-9,
) -> Alignment:
    """Least-squares constant alignment of ``q_ref`` to ``q_est`` over ``mask``.

    Args:
        q_est, q_ref: (N, 4) attitudes, both body → the same earth frame
            (up to the rotations being fitted); NaN rows are ignored.
        mask: samples to fit over (e.g. the scored ones); all if None.
        mode: ``"none"``, ``"heading"`` or ``"heading+body"``.
    """
    if mode not in ALIGNMENTS:
        raise ValueError(f"unknown alignment {mode!r}; choose one of {', '.join(ALIGNMENTS)}")
    if mode == "none":
        return Alignment()
    est, ref = _prepare(q_est, q_ref)
    ok = _valid_rows(est, ref, mask)
    if not ok.any():
        return Alignment(mode=mode)
    est, ref = est[ok], ref[ok]
    q_body = _IDENTITY.copy()
    q_earth = _heading_fit(est, ref)
    if mode == "heading+body":
        for _ in range(iterations):
            q_body_new = _body_fit(est, multiply(q_earth, ref))
            q_earth_new = _heading_fit(est, multiply(ref, q_body_new))
            change = max(
                float(np.abs(np.dot(q_body_new, q_body))),
                0.0,
            )
            moved = 2.0 * np.arccos(min(1.0, change))
            q_body, q_earth = q_body_new, q_earth_new
            if moved < tolerance_rad:
                break
    return Alignment(
        mode=mode,
        q_earth=tuple(float(x) for x in q_earth),  # type: ignore[arg-type]
        q_body=tuple(float(x) for x in q_body),  # type: ignore[arg-type]
    )
