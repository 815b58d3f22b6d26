"""PX4's magnetometer calibration from its parameters (``CAL_MAGn_*``), for SCALED_IMU's raw field.

PX4 corrects a compass reading as ``R · S · (m + P·c − o)`` (``src/lib/sensor_calibration/Magnetometer.hpp``,
``Correct``): ``o`` = ``CAL_MAGn_XOFF…ZOFF`` (gauss), ``S`` the symmetric matrix of ``CAL_MAGn_XSCALE…ZSCALE`` on
its diagonal and ``CAL_MAGn_XODIAG`` (xy), ``YODIAG`` (xz), ``ZODIAG`` (yz) off it, ``c`` the power compensation
(``CAL_MAG_COMP_TYP``), ``R`` the rotation: ``CAL_MAGn_ROT`` for an external compass, the board's
(``SENS_BOARD_ROT``, ``SENS_BOARD_X/Y/Z_OFF``) for an internal one (``CAL_MAGn_ROT`` −1).

SCALED_IMU carries ``sensor_mag`` instance 0, and MAVLink does not say which slot ``n`` (matched by device ID)
is that compass's.  So a calibration is returned only where the slot does not matter: every configured slot
(``CAL_MAGn_ID`` ≠ 0) holds the same values.  Only what is modelled is returned: no power compensation, the
rotation the identity (an internal compass on an unrotated board, or ``CAL_MAGn_ROT`` 0).  Anything else gives
None and a reason; the caller then leaves HIGHRES_IMU's field as sent (docs/accuracy.md, "PX4 heading, round eight").
"""

from __future__ import annotations

import struct

import numpy as np
from numpy.typing import NDArray

__all__ = ["SLOTS", "GLOBAL_NAMES", "param_value", "relevant_name", "missing_names", "mag_calibration"]

SLOTS = 4
_SLOT_FIELDS = ("XOFF", "YOFF", "ZOFF", "XSCALE", "YSCALE", "ZSCALE", "XODIAG", "YODIAG", "ZODIAG", "ROT")
GLOBAL_NAMES = ("CAL_MAG_COMP_TYP", "SENS_BOARD_ROT", "SENS_BOARD_X_OFF", "SENS_BOARD_Y_OFF", "SENS_BOARD_Z_OFF")
_INT_TYPES = (1, 2, 3, 4, 5, 6)  # MAV_PARAM_TYPE_UINT8 … INT32: PX4 sends their bytes in the float
_BOARD_OFF_TOL_DEG = 0.01  # a board rotation below this is none (PX4 SIH: SENS_BOARD_X_OFF 1e-6)


def param_value(value: float, param_type: int) -> float:
    """A PARAM_VALUE's value: an integer type's bytes reinterpreted (PX4 encodes parameters byte-wise)."""
    if int(param_type) in _INT_TYPES:
        return float(struct.unpack("<i", struct.pack("<f", float(value)))[0])
    return float(value)


def relevant_name(name: str) -> bool:
    """Whether parameter ``name`` takes part in :func:`mag_calibration`."""
    return name.startswith("CAL_MAG") or name in GLOBAL_NAMES


def missing_names(params: dict[str, float]) -> list[str]:
    """The parameters still needed to decide the calibration (what to request from the autopilot)."""
    out = [n for n in GLOBAL_NAMES if n not in params]
    for k in range(SLOTS):
        idn = f"CAL_MAG{k}_ID"
        if idn not in params:
            out.append(idn)
        elif params[idn] != 0:
            out += [f"CAL_MAG{k}_{f}" for f in _SLOT_FIELDS if f"CAL_MAG{k}_{f}" not in params]
    return out


def mag_calibration(params: dict[str, float]) -> tuple[NDArray[np.float64] | None, str]:
    """``(calibration, reason)``: the offset (µT) and matrix, as :data:`~mavahrs.ingest.autopilot_mag_bias.CAL_LEN`
    values applied as ``M · (m − o)``, or None with why not."""
    if missing_names(params):
        return None, "CAL_MAG* parameters not all received"
    if params["CAL_MAG_COMP_TYP"] != 0:
        return None, f"power compensation on (CAL_MAG_COMP_TYP {params['CAL_MAG_COMP_TYP']:g}): not modelled"
    slots = [k for k in range(SLOTS) if params[f"CAL_MAG{k}_ID"] != 0]
    if not slots:
        return None, "no compass calibrated (every CAL_MAGn_ID 0)"
    values = {tuple(params[f"CAL_MAG{k}_{f}"] for f in _SLOT_FIELDS) for k in slots}
    if len(values) > 1:
        return None, "compasses calibrated differently: which is SCALED_IMU's is not known over MAVLink"
    xo, yo, zo, xs, ys, zs, xy, xz, yz, rot = values.pop()
    if rot == -1:  # internal: the board's rotation
        board = [params[n] for n in ("SENS_BOARD_X_OFF", "SENS_BOARD_Y_OFF", "SENS_BOARD_Z_OFF")]
        if params["SENS_BOARD_ROT"] != 0 or max(abs(b) for b in board) > _BOARD_OFF_TOL_DEG:
            return None, "board rotated (SENS_BOARD_ROT / SENS_BOARD_*_OFF): not modelled"
    elif rot != 0:
        return None, f"compass rotated (CAL_MAGn_ROT {rot:g}): not modelled"
    m = np.array([[xs, xy, xz], [xy, ys, yz], [xz, yz, zs]], np.float64)
    if not np.all(np.isfinite(m)) or not all(np.isfinite((xo, yo, zo))) or abs(np.linalg.det(m)) < 1e-3:
        return None, "calibration values not usable"
    return np.concatenate([np.array([xo, yo, zo]) * 100.0, m.ravel()]), "calibrated"
