"""The default monitor on a real autopilot's flight (ArduCopter SITL) with faults injected in its attitude,
through ``mavahrs audit``'s path; and the flight-phase classification."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from mavahrs.evaluation.faults import AttitudeFault, FaultShape, inject_faults
from mavahrs.service.monitor import FlightPhase, MonitorSettings

FLIGHT = "sitl/arducopter_gentle.tlog"  # airborne from about 76 to 126 s boot time
ONSET_S = 100.0


def _alarms(row) -> list[float]:  # type: ignore[no-untyped-def]
    assert row.ok, row.error
    return [float(x) for x in row.alarm_times_s.split(";") if x]


@pytest.fixture(scope="module")
def audited(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    from mavahrs.fleet.audit import summarise_log

    src = shared_data / FLIGHT
    tmp = tmp_path_factory.mktemp("monitor_flights")
    faults = {
        "clean": None,
        "tilt2": AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0, tilt_azimuth_deg=135.0),
        "hdg6": AttitudeFault(FaultShape("step", ONSET_S), heading_deg=-6.0),
        "ramp": AttitudeFault(FaultShape("ramp", ONSET_S, ramp_s=50.0), tilt_deg=10.0),  # 0.2°/s
        "blink": AttitudeFault(FaultShape("intermittent", ONSET_S, period_s=4.0, on_s=1.0), tilt_deg=2.0),
    }
    rows = {}
    for name, fault in faults.items():
        path = src
        if fault is not None:
            path = tmp / f"{name}.tlog"
            inject_faults(src, path, [fault])
        rows[name] = summarise_log(path)
        if fault is not None:
            path.unlink()
    return rows


def test_unfaulted_flight_has_no_in_flight_warning(audited: dict) -> None:
    row = audited["clean"]
    assert _alarms(row) == [] and row.inclination_max_deg < 1.0
    assert row.compared_s > 40.0


@pytest.mark.parametrize(("fault", "limit_s"), [("tilt2", 2.0), ("hdg6", 3.0)])
def test_a_step_is_warned_in_flight_in_time(audited: dict, fault: str, limit_s: float) -> None:
    times = _alarms(audited[fault])
    assert times, "no in-flight WARNING"
    assert ONSET_S < times[0] <= ONSET_S + limit_s, times  # nothing before the fault, and in time after it
    # a sequential test, not a single sample over a line: the change test's CUSUM at three times its threshold
    # needs (1 − 0.8)·1.5 s / (3 − 0.8) = 0.14 s (the 2° step here: 0.22 s since the timing term's tilt part is
    # the turn's horizontal one)
    assert 0.13 < times[0] - ONSET_S


def test_a_slow_tilt_drift_is_warned_before_it_reaches_3_deg(audited: dict) -> None:
    times = _alarms(audited["ramp"])
    assert times and ONSET_S + 3.0 < times[0] < ONSET_S + 15.0, times  # 0.6°: too early to be the drift; 3°


def test_a_ramp_warned_of_is_one_warning_as_it_grows(audited: dict) -> None:
    # the ramp warned of grows on along the line the warning stood on: the warning already on, not a new fault
    # (MonitorSettings.change_drift_slope_s; without it the drift test said it again once it had grown by the
    # change threshold: 106.2 s and 113.7 s on this flight)
    times = _alarms(audited["ramp"])
    assert len(times) == 1, times


# ---------------------------------------------------------------------------- phase


def test_phase_from_heartbeat_and_motion() -> None:
    """ArduPilot's stream: HEARTBEAT (armed flag) and GLOBAL_POSITION_INT, no EXTENDED_SYS_STATE."""
    ph = FlightPhase(MonitorSettings())
    assert ph.phase(0.0) == "unknown"
    ph.on_heartbeat(0, 1000.0)
    assert ph.phase(1000.0) == "disarmed"
    ph.on_heartbeat(128 | 1, 2000.0)  # armed
    ph.on_position(2000.0, 0.1, 0.0)
    assert ph.phase(2000.0) == "ground"
    ph.on_position(5000.0, 1.5, 1.0)  # leaving the ground: not yet decided
    assert ph.phase(5000.0) == "ground"
    ph.on_position(6000.0, 2.5, 1.5)
    assert ph.phase(6000.0) == "takeoff" and ph.phase(10_900.0) == "takeoff"
    assert ph.phase(11_100.0) == "air"
    ph.on_position(60_000.0, 0.5, 0.1)  # hovering low and still: that is on the ground
    assert ph.phase(60_000.0) == "touchdown" and ph.phase(64_900.0) == "touchdown"
    assert ph.phase(65_100.0) == "ground"
    ph.on_heartbeat(0, 70_000.0)
    assert ph.phase(70_000.0) == "disarmed"


def test_phase_from_extended_sys_state_wins() -> None:
    ph = FlightPhase(MonitorSettings())
    ph.on_heartbeat(128, 0.0)
    ph.on_landed_state(1, 0.0)
    ph.on_position(0.0, 30.0, 5.0)  # a baro step on the ground: the autopilot's landed state decides
    assert ph.phase(1000.0) == "ground"
    ph.on_landed_state(3, 2000.0)
    assert ph.phase(2000.0) == "takeoff"
    ph.on_landed_state(2, 4000.0)
    assert ph.phase(4000.0) == "takeoff" and ph.phase(9100.0) == "air"
    ph.on_landed_state(4, 50_000.0)
    assert ph.phase(50_000.0) == "touchdown"
    ph.on_landed_state(1, 52_000.0)
    assert ph.phase(52_000.0) == "touchdown" and ph.phase(57_100.0) == "ground"
    ph.on_landed_state(0, 60_000.0)  # undefined: changes nothing
    assert ph.phase(60_000.0) == "ground"


def test_a_disagreement_on_the_ground_is_a_notice_and_warns_again_once_airborne() -> None:
    from mavahrs.protocol.codec import mavlink
    from mavahrs.service.monitor import AttitudeMonitor

    mon = AttitudeMonitor(MonitorSettings(startup_grace_s=0.0))
    mon.heading_valid = False
    mon.phase.on_heartbeat(128, 0.0)
    mon.phase.on_position(0.0, 0.0, 0.0)
    off = (math.cos(math.radians(2.5)), math.sin(math.radians(2.5)), 0.0, 0.0)  # 5° of roll
    out = []
    for k in range(0, 30_000, 20):
        t = float(k)
        if t == 10_000.0:
            mon.phase.on_position(t, 10.0, 3.0)
        out += [(t, m.severity, m.text) for m in mon.add_estimate(t, (1.0, 0.0, 0.0, 0.0), math.radians(0.5))]
        out += [(t, m.severity, m.text) for m in mon.add_autopilot(t, off)]
    assert [(s, text.split(":")[0]) for _, s, text in out] == [
        (mavlink.MAV_SEVERITY_NOTICE, "mavahrs on ground"),
        (mavlink.MAV_SEVERITY_WARNING, "mavahrs"),
    ], out
    assert out[0][0] < 1000.0 and 15_000.0 <= out[1][0] < 15_100.0  # once the take-off phase is over
    assert all(len(text.encode()) <= 50 for _, _, text in out)
    assert mon.status.episodes == 2 and mon.status.ground_episodes == 1


def test_an_intermittent_fault_is_one_warning(audited: dict) -> None:
    # 2° of tilt for 1 s in every 4 s: warned at its first second, then the same disagreement coming and going
    # is the warning already on — not a new step within it (MonitorSettings.change_in_warning_s: a WARNING
    # every 4–8 s when the step within a warning was judged against the warning's mean alone)
    times = _alarms(audited["blink"])
    assert times and ONSET_S < times[0] <= ONSET_S + 2.0, times
    assert len(times) == 1, times
