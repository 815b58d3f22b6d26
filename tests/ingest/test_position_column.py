"""``IN_POS``: every reader puts the GNSS fix's position beside its velocity, NED metres from the first fix fed.

The selector (the live pipeline's and the tlog replay's), the tlog reader over arrays and the ULog
reader; the DataFlash reader's is in ``tests/logs/test_dataflash.py``.  Truth: the position the same
fixes' velocities integrate to, and the messages' own latitude and longitude.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mavahrs.filters.layout import IN_POS, IN_VEL, IN_VEL_AGE
from mavahrs.sensors.position import PositionOrigin
from mavahrs.sensors.velocity import VelocitySelector


class _Gpi:
    """A GLOBAL_POSITION_INT as pymavlink decodes it."""

    def __init__(self, t_ms: int, lat_e7: int, lon_e7: int, alt_mm: int) -> None:
        self.time_boot_ms, self.lat, self.lon, self.alt = t_ms, lat_e7, lon_e7, alt_mm
        self.vx = self.vy = self.vz = 0

    def get_type(self) -> str:
        return "GLOBAL_POSITION_INT"


def test_selector_gives_ned_metres_from_the_first_fix_in_the_velocity_frame() -> None:
    sel = VelocitySelector("global_position_int")
    lat0, lon0 = 436044999, 14370000  # Toulouse, degE7
    assert sel.offer(_Gpi(1000, lat0, lon0, 150_100), 1_000_000, None) is not None
    assert sel.position_ned == (0.0, 0.0, 0.0)
    # 1e-4 deg north (≈ 11.1 m), 1e-4 deg east (≈ 8.05 m at 43.6°), 2 m up
    assert sel.offer(_Gpi(1200, lat0 + 1000, lon0 + 1000, 152_100), 1_200_000, None) is not None
    n, e, d = sel.position_ned
    assert n == pytest.approx(11.12, abs=0.02) and e == pytest.approx(8.07, abs=0.02) and d == pytest.approx(-2.0)
    # in the magnetic frame (declination 10° east) as the velocity: rotated by −10° about down
    dec = math.radians(10.0)
    assert sel.offer(_Gpi(1400, lat0 + 1000, lon0 + 1000, 152_100), 1_400_000, dec) is not None
    nm, em, _ = sel.position_ned
    assert (nm, em) == pytest.approx((math.cos(dec) * n + math.sin(dec) * e, -math.sin(dec) * n + math.cos(dec) * e))
    sel.reset()  # an autopilot reboot: the next fix is the new origin
    sel.offer(_Gpi(500, lat0 + 1000, lon0 + 1000, 152_100), 2_000_000, None)
    assert sel.position_ned == (0.0, 0.0, 0.0)


def _integrated_position(rows: np.ndarray, t_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fixes' positions and the trapezoid integral of the same fixes' horizontal velocity (fix times)."""
    has = np.isfinite(rows[:, IN_POS]) & np.isfinite(rows[:, IN_VEL])
    t = (t_us[has] - rows[has, IN_VEL_AGE] * 1e6) * 1e-6
    v = rows[has, IN_VEL : IN_VEL + 2]
    p = np.vstack([np.zeros(2), np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], 0)])
    return rows[has, IN_POS : IN_POS + 2], p


def test_tlog_reader_fills_the_position(shared_data: Path) -> None:
    from mavahrs.evaluation.tlogdata import prepare_inputs, read_tlog_data
    from mavahrs.service.pipeline import PipelineSettings

    prep = prepare_inputs(read_tlog_data(shared_data / "sitl" / "arducopter_gentle.tlog"), PipelineSettings())
    pos, integ = _integrated_position(prep.rows, prep.t_us)
    assert pos.shape[0] > 100
    assert np.allclose(pos[0], 0.0)
    assert np.ptp(pos[:, 0]) + np.ptp(pos[:, 1]) > 20.0
    # the velocities integrate to the positions (GLOBAL_POSITION_INT: EKF3's own, consistent): within 2 % of the path
    path = np.sum(np.hypot(*np.diff(integ, axis=0).T))
    assert np.max(np.hypot(*(pos - integ).T)) < 0.02 * path + 1.0


def test_ulog_reader_fills_the_position(shared_data: Path) -> None:
    pytest.importorskip("pyulog")
    from mavahrs.logs.ulog import read_ulog

    path = shared_data / "px4_sitl" / "px4_aggressive.ulg"
    if not path.exists():
        pytest.skip(f"{path} not found")
    li = read_ulog(path)
    rows = li.inputs.rows
    pos, integ = _integrated_position(rows, li.inputs.t_us)
    assert pos.shape[0] > 100
    assert np.allclose(pos[0], 0.0)
    path_m = np.sum(np.hypot(*np.diff(integ, axis=0).T))
    assert path_m > 50.0
    assert np.max(np.hypot(*(pos - integ).T)) < 0.02 * path_m + 1.0
    # PositionOrigin agrees with itself over arrays and one by one
    o1, o2 = PositionOrigin(), PositionOrigin()
    lat, lon = np.array([43.6, 43.6001, 43.6]), np.array([1.4, 1.4, 1.4002])
    arr = o1.ned_arrays(lat, lon, np.array([150.0, 151.0, 149.0]), 0.1)
    one = [o2.ned(float(a), float(b), float(c), 0.1) for a, b, c in zip(lat, lon, [150.0, 151.0, 149.0], strict=True)]
    assert np.allclose(arr, np.array(one))
