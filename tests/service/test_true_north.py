"""True north and the second opinion, end to end: firmware_sim → Pipeline → (monitor hook).

The simulator plays an ArduPilot at ArduPilot SITL's home (Canberra, where the
declination is 12.7°) with GPS (GLOBAL_POSITION_INT, SYSTEM_TIME): RAW_IMU at
the fastest rate it accepts, its own estimate (ATTITUDE) and the truth
(SIMSTATE).  Frames are decoded as the daemon does and fed to the real
:class:`~mavahrs.service.pipeline.Pipeline`; its ATTITUDE_QUATERNION output is
scored against SIMSTATE.  The attitude monitor is then driven exactly as the
pipeline hook does it (our published attitudes + the autopilot's ATTITUDE +
``tick``), on a fault-free flight and on one with an injected estimator fault.
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass

import numpy as np
import pytest

from mavahrs.evaluation.metrics import attitude_errors_rad, rms_deg
from mavahrs.geometry.rotation import from_euler_rad
from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.sensors.geomag import apply_declination, expected_field
from mavahrs.service.monitor import AttitudeMonitor, MonitorSettings, align_attitudes
from mavahrs.service.pipeline import Pipeline, PipelineSettings

sim = pytest.importorskip("firmware_sim")

pytestmark = pytest.mark.slow

DURATION_S = 30.0
SKIP_S = 10.0  # convergence of the filter (start-up boost) before scoring
FAULT = dict(start_s=14.0, duration_s=8.0, roll_deg=15.0, ramp_s=1.0)  # clears at 22 s + clear_s
FILTER = "best" if importlib.util.find_spec("mavahrs.filters.best") else "mahony"


@dataclass
class Flight:
    out_t_ms: np.ndarray  # our ATTITUDE_QUATERNION time_boot_ms
    out_q: np.ndarray  # … and q (true north, as published)
    truth_t_ms: np.ndarray
    truth_q: np.ndarray  # SIMSTATE
    ap_msgs: list  # the autopilot's ATTITUDE messages (decoded), in order
    ap_recv_us: list  # when each arrived (autopilot time)
    pipeline: Pipeline


def _fly(scenario: str, *, fault: dict | None = None, seed: int = 3) -> Flight:
    settings = sim.SimSettings(
        scenario=scenario, seed=seed, attitude_fault=sim.AttitudeFault(**fault) if fault else None
    )
    endpoint = sim.Endpoint(
        sim.Simulation(settings),
        sim.EndpointSettings(
            preset="none", block_ticks=400,
            streams_hz=(("RAW_IMU", math.inf), ("SIMSTATE", 50.0), ("ATTITUDE", 25.0),
                        ("GLOBAL_POSITION_INT", 5.0), ("SYSTEM_TIME", 1.0)),
        ),
    )  # fmt: skip
    rx = MavCodec(system_id=255, component_id=190)
    ours = MavCodec(system_id=255, component_id=190)
    pipe = Pipeline(PipelineSettings(filter_name=FILTER, out_rate_hz=50.0))
    out_t, out_q, tr_t, tr_q, ap, ap_us = [], [], [], [], [], []
    for _ in range(int(DURATION_S * settings.loop_rate_hz)):
        for t_us, frame in endpoint.step():
            for msg in rx.receive_datagram(frame):
                kind = msg.get_type()
                if kind == "SIMSTATE":
                    tr_t.append(t_us / 1000.0)
                    tr_q.append(from_euler_rad(msg.roll, msg.pitch, msg.yaw))
                elif kind == "ATTITUDE":
                    ap.append(msg)
                    ap_us.append(t_us)
                for o in pipe.handle(msg, t_us):
                    for m in ours.receive_datagram(o.frame):
                        if m.get_type() == "ATTITUDE_QUATERNION":
                            out_t.append(m.time_boot_ms)
                            out_q.append((m.q1, m.q2, m.q3, m.q4))
        pipe.tick(endpoint.now_us)
    return Flight(np.array(out_t, float), np.array(out_q), np.array(tr_t), np.array(tr_q), ap, ap_us, pipe)


@pytest.fixture(scope="module")
def clean_flight() -> Flight:
    return _fly("aggressive")


@pytest.fixture(scope="module")
def faulty_flight() -> Flight:
    return _fly("hover", fault=FAULT)


def _heading_and_tilt_rms(f: Flight, q_out: np.ndarray) -> tuple[float, float]:
    q_ref = align_attitudes(f.truth_t_ms, f.truth_q, f.out_t_ms, tolerance_ms=20.0)
    scored = np.all(np.isfinite(q_ref), axis=1) & (f.out_t_ms > f.out_t_ms[0] + 1000.0 * SKIP_S)
    assert np.count_nonzero(scored) > 0.9 * 50.0 * (DURATION_S - SKIP_S - 1.0)
    _, heading, tilt = attitude_errors_rad(q_out[scored], q_ref[scored])
    return rms_deg(heading), rms_deg(tilt)


def test_heading_is_referenced_to_true_north(clean_flight: Flight) -> None:
    f = clean_flight
    home = sim.Home()
    wmm = expected_field(home.lat_deg, home.lon_deg, home.alt_m, 2025.42)
    decl = f.pipeline.declination
    assert decl.known and decl.field is not None and "WMM-2025" in decl.status()
    assert decl.declination_rad == pytest.approx(wmm.declination_rad, abs=math.radians(0.05))
    assert math.degrees(decl.declination_rad) > 12.0
    heading, tilt = _heading_and_tilt_rms(f, f.out_q)
    print(f"heading {heading:.2f}° RMS, tilt {tilt:.2f}° RMS against SIMSTATE ({FILTER})")
    assert heading <= 3.0, f"heading error {heading:.2f}° RMS against true north"
    assert tilt <= 3.0
    # Without the correction the same estimates would be off by the declination.
    uncorrected, _ = _heading_and_tilt_rms(f, apply_declination(f.out_q, -decl.declination_rad))
    print(f"without the declination: heading {uncorrected:.2f}° RMS")
    assert uncorrected > 10.0


def _monitor(f: Flight, settings: MonitorSettings) -> tuple[list[tuple[float, object]], AttitudeMonitor]:
    """The pipeline hook: published attitudes + the autopilot's ATTITUDE (+ tick) into the monitor."""
    mon = AttitudeMonitor(settings)
    events: list[tuple[float, object]] = []
    i = 0
    for msg, t_us in zip(f.ap_msgs, f.ap_recv_us, strict=True):
        while i < len(f.out_t_ms) and f.out_t_ms[i] <= t_us / 1000.0:
            events += [(f.out_t_ms[i], m) for m in mon.add_estimate(f.out_t_ms[i], f.out_q[i])]
            i += 1
        events += [(t_us / 1000.0, m) for m in mon.handle(msg, t_us)]
        mon.tick(t_us)
    return events, mon


def test_monitor_quiet_on_a_fault_free_flight(clean_flight: Flight) -> None:
    events, mon = _monitor(clean_flight, MonitorSettings())
    assert events == []
    assert mon.status.comparisons > 0.9 * 25.0 * (DURATION_S - 1.0)
    assert mon.status.unmatched < 5


def test_monitor_warns_on_an_injected_autopilot_fault(faulty_flight: Flight) -> None:
    s = MonitorSettings(mode="fixed")  # the fixed 10° threshold's timing (uncertainty mode: test_monitor_flights.py)
    events, mon = _monitor(faulty_flight, s)
    texts = [(t / 1000.0, m.severity, m.text) for t, m in events]
    assert len(texts) == 2, texts
    (t_warn, sev_warn, text), (t_ok, sev_ok, _) = texts
    assert sev_warn == mavlink.MAV_SEVERITY_WARNING and "tilt 1" in text
    start = FAULT["start_s"]  # simulation time = autopilot boot time (boot_offset_s = 0)
    # Exceeds 10° once the 15° ramp passes 2/3 (0.67 s), then trigger_s: within ramp + trigger_s of the onset.
    assert start + s.trigger_s <= t_warn <= start + FAULT["ramp_s"] + s.trigger_s + 0.2
    end = start + FAULT["duration_s"]
    assert sev_ok == mavlink.MAV_SEVERITY_INFO and end + s.clear_s <= t_ok <= end + s.clear_s + 0.3
    assert mon.status.episodes == 1 and not mon.status.warning
