"""Issue 23: ``best``'s heading where GNSS cannot observe it, on the PX4 SITL flight in ../shared.

``px4_sitl/px4_aggressive.tlog`` ends in a hover (220–250 s on the fed samples' clock: the GNSS
horizontal speed below 1 m/s).  There the heading is the magnetometer's alone, and mavahrs's own
complementary filter follows the truth (HIL_STATE_QUATERNION) within 0.2–0.5° per 10 s window, while
``best`` carries +1.2…+2.1° built up in the manoeuvre before it (hover RMS 1.61°, 1.31° with the compass noise learnt,
measured 2026-12-06; docs/accuracy.md,
"PX4 calm-segment heading").  Target of issue 23: ``best`` within 0.1° of the best mavahrs filter on
every flight, so here within 0.1° of the complementary filter in the hover.  Met since round six
(px4h6): PX4's HIGHRES_IMU has EKF2's gyro bias subtracted, and the ``px4`` profile now recovers it
from the tlog's own SCALED_IMU and adds it back (``mavahrs.ingest.autopilot_bias``): ``best`` 1.07 →
0.75°, and the complementary filter's 0.38° turned out to be EKF2's correction (1.02° without it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.loaders import load_any
from mavahrs.evaluation.metrics import attitude_errors_rad
from mavahrs.evaluation.report import run_filter
from mavahrs.evaluation.tlogdata import load_tlog_recording
from mavahrs.ingest.autopilot_bias import AutopilotBiasSettings
from mavahrs.service.pipeline import PipelineSettings

HOVER_S = (220.0, 250.0)


@pytest.fixture(scope="module")
def px4_recording(shared_data: Path):
    path = shared_data / "px4_sitl" / "px4_aggressive.tlog"
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data/px4_sitl beside the checkout)")
    return load_any(path)[0]


@pytest.fixture(scope="module")
def px4_recording_as_sent(shared_data: Path):
    """The same tlog with HIGHRES_IMU as PX4 sends it (EKF2's gyro bias subtracted, not added back)."""
    path = shared_data / "px4_sitl" / "px4_aggressive.tlog"
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data/px4_sitl beside the checkout)")
    return load_tlog_recording(path, settings=PipelineSettings(autopilot_bias=AutopilotBiasSettings(enabled=False)))


def _hover_heading_rms_deg(rec, name: str) -> float:
    t_s = np.cumsum(rec.dt_s)
    window = (t_s >= HOVER_S[0]) & (t_s < HOVER_S[1])
    out = run_filter(rec, name)
    heading_rad = attitude_errors_rad(out[:, :4], rec.q_ref_body_to_ned)[1]
    return float(np.degrees(np.sqrt(np.nanmean(heading_rad[window] ** 2))))


def test_hover_window_is_calm(px4_recording) -> None:
    """The window is a hover by the GNSS velocity the filters are fed, not by assumption."""
    t_s = np.cumsum(px4_recording.dt_s)
    v = px4_recording.extra["velocity_ned_m_s"]
    window = (t_s >= HOVER_S[0]) & (t_s < HOVER_S[1]) & np.isfinite(v[:, 0])
    assert window.sum() > 100
    assert np.max(np.hypot(v[window, 0], v[window, 1])) < 1.0


def test_complementary_follows_the_truth_in_the_hover_only_with_ekf2s_gyro_bias(px4_recording_as_sent,
                                                                                px4_recording) -> None:
    """On HIGHRES_IMU as sent (EKF2's bias subtracted) the complementary filter holds the hover within 0.8°
    (0.38°); with EKF2's bias added back from SCALED_IMU it does not (1.02°): its 0.38° was EKF2's
    correction (round three), which is why the independent estimate is judged without it."""
    assert _hover_heading_rms_deg(px4_recording_as_sent, "complementary") < 0.8
    assert _hover_heading_rms_deg(px4_recording, "complementary") > 0.8


def test_best_heading_in_the_hover_within_0_1_deg_of_complementary(px4_recording, px4_recording_as_sent) -> None:
    """Issue 23's target on the tlog, with EKF2's gyro bias added back (best 0.75 vs complementary 1.02°; it
    failed as a strict xfail through round five: best 1.07 vs 0.38 on HIGHRES_IMU as sent); ``best`` also beats
    its own figure on the messages as sent (1.07°), so the gain is the bias's, not the yardstick's."""
    best = _hover_heading_rms_deg(px4_recording, "best")
    complementary = _hover_heading_rms_deg(px4_recording, "complementary")
    assert best <= complementary + 0.1, (best, complementary)
    assert best < _hover_heading_rms_deg(px4_recording_as_sent, "best") - 0.2, best


def test_on_the_sensors_own_rates_best_holds_the_hover_heading_at_or_below_complementary(shared_data: Path) -> None:
    """The same flight's ULog: ``sensor_combined`` (no EKF2 bias subtracted), ``vehicle_magnetometer`` and, as the
    daemon takes it on PX4, the receiver's velocity.  There the issue's target holds: ``best`` within 0.1° of the
    complementary filter in the hover (0.91 vs 1.60°, round five; 1.19 with EKF2's velocity fed before)."""
    path = shared_data / "px4_sitl" / "px4_aggressive.ulg"
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data/px4_sitl beside the checkout)")
    rec = load_any(path)[0]
    best = _hover_heading_rms_deg(rec, "best")
    complementary = _hover_heading_rms_deg(rec, "complementary")
    assert best <= complementary + 0.1, (best, complementary)
    assert best < 1.1, best  # the receiver's velocity keeps the learnt declination on the field (EKF2's: 1.19°)

