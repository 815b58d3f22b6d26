r"""Earth-frame conversions (NED/ENU/NWU) and the 24 sensor-axis alignments.

Earth frames (all right-handed):

* NED — x north, y east, z down (MAVLink, ArduPilot, PX4; mavahrs internal);
* ENU — x east, y north, z up (BROAD, VQF's default);
* NWU — x north, y west, z up (the ``ahrs`` package, imufusion's NWU option).

An attitude ``q_body_to_X`` is converted to another earth frame Y by
left-multiplying the constant ``q_X_to_Y``; the body frame is untouched.

Sensor-axis remaps: a sensor mounted rotated on the vehicle reports vectors in
its own axes; ``remap`` turns them into body axes with one of the 24 proper
axis permutations (signed permutation matrices with determinant +1), named the
way autopilots name board orientations, e.g. ``"+x+y+z"`` (identity),
``"-x-y+z"`` (yaw 180°): body x is the first signed sensor axis, and so on.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.geometry.quaternion import multiply

__all__ = [
    "Q_NED_TO_ENU",
    "Q_ENU_TO_NED",
    "Q_NED_TO_NWU",
    "Q_NWU_TO_NED",
    "Q_NWU_TO_ENU",
    "convert_earth_frame",
    "AXIS_REMAPS",
    "remap",
    "remap_matrix",
]

Array = NDArray[np.float64]

_S = np.sqrt(0.5)
#: NED→ENU: swap x/y, flip z (180° about the (1,1,0)/√2 axis).
Q_NED_TO_ENU: Array = np.array([0.0, _S, _S, 0.0])
Q_ENU_TO_NED: Array = np.array([0.0, -_S, -_S, 0.0])  # same rotation (self-inverse)
#: NED→NWU: 180° about north.
Q_NED_TO_NWU: Array = np.array([0.0, 1.0, 0.0, 0.0])
Q_NWU_TO_NED: Array = np.array([0.0, -1.0, 0.0, 0.0])
#: NWU→ENU: +90° about up (what the BROAD example code applies).
Q_NWU_TO_ENU: Array = np.array([_S, 0.0, 0.0, _S])

_TO_NED = {"NED": np.array([1.0, 0, 0, 0]), "ENU": Q_ENU_TO_NED, "NWU": Q_NWU_TO_NED}


def convert_earth_frame(q_body_to_src: ArrayLike, src: str, dst: str) -> Array:
    """Express a body→``src`` attitude as body→``dst`` (frames: NED, ENU, NWU)."""
    try:
        to_ned = _TO_NED[src.upper()]
        ned_to_dst = _TO_NED[dst.upper()] * np.array([1.0, -1, -1, -1])
    except KeyError as exc:
        raise ValueError(f"unknown earth frame {exc.args[0]!r}; use NED, ENU or NWU") from None
    return multiply(multiply(ned_to_dst, to_ned), q_body_to_src)


def _build_remaps() -> dict[str, Array]:
    out: dict[str, Array] = {}
    names = "xyz"
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for row, (col, s) in enumerate(zip(perm, signs, strict=True)):
                m[row, col] = s
            if np.linalg.det(m) > 0:
                name = "".join(("+" if s > 0 else "-") + names[c] for c, s in zip(perm, signs, strict=True))
                m.setflags(write=False)
                out[name] = m
    return out


#: The 24 proper sensor→body axis remaps, keyed by name (``"+x+y+z"`` is identity).
AXIS_REMAPS: dict[str, Array] = _build_remaps()


def remap_matrix(name: str) -> Array:
    """The 3×3 matrix M with ``v_body = M @ v_sensor`` for a remap name."""
    try:
        return AXIS_REMAPS[name]
    except KeyError:
        raise ValueError(
            f"unknown axis remap {name!r}; expected one of {sorted(AXIS_REMAPS)}"
        ) from None


def remap(v_sensor: ArrayLike, name: str) -> Array:
    """Sensor-axis vectors (…, 3) to body axes with the named proper remap."""
    return np.asarray(v_sensor, dtype=np.float64) @ remap_matrix(name).T
