"""Heading without a magnetometer: from GNSS velocity alone once the vehicle moves (firmware_sim, no compass).

firmware_sim's ``hover`` flight with ``--mags 0``: on the ground the heading is unknown (no compass;
the filter starts tens of degrees off), the take-off and the slow turns and drifts of the hover make it
observable through the velocity fixes (δv̇ = −[C f]× δθ: a horizontal acceleration turns a heading error
into a velocity residual).  Measured (seed 7, ``docs/accuracy.md``): first horizontal motion > 1 m/s at
11 s, heading within 10° from 28 s and within 5° from 36 s on; bound here: within 10° over 45–60 s.
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.__main__ import main as sim_main
from mavahrs.geometry.quaternion import conjugate, multiply
from mavahrs.replay import ReplaySettings, attitude_at_reference, replay


@pytest.fixture(scope="module")
def nomag(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("nomag") / "hover_nomag.tlog"
    args = ["--tlog", str(path), "--fast", "-q", "--scenario", "hover", "--mags", "0", "--seed", "7", "--duration", "60"]
    assert sim_main(args) == 0
    res = replay(path, ReplaySettings(filters=("best",)))
    path.unlink()
    return res


def test_heading_converges_from_gnss_after_take_off(nomag) -> None:  # type: ignore[no-untyped-def]
    res = nomag
    truth = next(k for k in res.references if "truth" in k)
    t_ref, q_ref = res.references[truth]
    e = multiply(attitude_at_reference(res, "best", truth), conjugate(q_ref))
    err = np.abs((np.degrees(2 * np.arctan2(e[:, 3], e[:, 0])) + 180.0) % 360.0 - 180.0)
    ts = (t_ref - res.inputs.t_us[0]) / 1e6
    assert np.nanmax(err[(ts > 2.0) & (ts < 8.0)]) > 20.0  # before moving the heading is not known
    late = (ts > 45.0) & np.isfinite(err)
    assert late.sum() > 100
    assert np.max(err[late]) < 10.0
