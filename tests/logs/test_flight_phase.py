"""The flight's phase from an onboard log (.BIN: ARM / EV; .ulg: vehicle_status / vehicle_land_detected), for the
second-opinion monitor of ``replay`` and ``audit``: a disagreement on the ground, at take-off or touchdown is a
NOTICE naming the phase, in flight a WARNING. Until user6 onboard logs gave the monitor no phase: every
disagreement was judged as in flight and printed with the phase ``unknown``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavahrs.fleet.audit import onboard_phase_events
from mavahrs.logs import read_log
from mavahrs.service.monitor import FlightPhase


def _phase_at(events: list[tuple[float, str, float]], t_s: float) -> str:
    ph = FlightPhase()
    for e in events:
        if e[0] <= t_s * 1000.0:
            ph.on_event(*e)
    return ph.phase(t_s * 1000.0)


@pytest.mark.parametrize(("rel", "expected"), [
    # ArduCopter SITL: ARM 42.77 s, EV NOT_LANDED 46.05 s, LAND_COMPLETE 249.68 s, ARM (disarmed) 250.19 s
    ("sitl/arducopter_onboard.BIN", {30.0: "disarmed", 44.0: "ground", 47.0: "takeoff", 100.0: "air",
                                     249.9: "touchdown", 251.0: "disarmed"}),
    # PX4 SIH: armed 24.64 s, landed false 26.49 s, landed 257.08 s, disarmed 259.10 s; the WARNING at 36.6 s
    ("px4_sitl/px4_aggressive.ulg", {10.0: "disarmed", 25.0: "ground", 27.0: "takeoff", 36.6: "air",
                                     257.5: "touchdown", 259.5: "disarmed"}),
])  # fmt: skip
def test_the_phase_of_an_onboard_log_is_the_autopilots(shared_data: Path, rel: str, expected: dict[float, str]) -> None:
    path = shared_data / rel
    if not path.is_file():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data beside the checkout)")
    li = read_log(path)
    events = onboard_phase_events(li)
    assert {t: _phase_at(events, t) for t in expected} == expected
    assert any(line.startswith("flight phase: armed from ") for line in li.found), li.found


def test_events_alone_give_the_phase_and_the_state_before_the_first_one() -> None:
    """A DataFlash log without ARM records (older ArduPilot): EV ARMED / DISARMED and LAND_COMPLETE / NOT_LANDED;
    a log that starts in flight (its first events DISARMED after LAND_COMPLETE) is flying until then."""
    from mavahrs.logs.dataflash import _flight_state

    ev = {"TimeUS": np.array([5_000_000, 9_000_000, 12_000_000], np.uint64), "Id": np.array([25, 18, 11], np.uint8)}
    state = _flight_state(None, ev)
    events = onboard_phase_events(type("Log", (), {"series": state})())
    assert [_phase_at(events, t) for t in (1.0, 9.5, 20.0)] == ["air", "touchdown", "disarmed"]
    ev = {"TimeUS": np.array([3_000_000, 4_000_000], np.uint64), "Id": np.array([10, 28], np.uint8)}
    events = onboard_phase_events(type("Log", (), {"series": _flight_state(None, ev)})())
    assert [_phase_at(events, t) for t in (1.0, 3.5, 4.5, 30.0)] == ["disarmed", "ground", "takeoff", "air"]
    assert onboard_phase_events(type("Log", (), {"series": {}})()) == []  # nothing logged: no phase
