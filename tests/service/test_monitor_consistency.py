"""Never cry wolf: on firmware_sim flights, whose SIMSTATE gives the truth, our filter's tilt σ holds its
tilt error once airborne, and no in-flight WARNING comes while the simulated autopilot is within 1° of
tilt and 3° of heading of the truth (issue 24).

The flights are the ones on which the monitor benchmark (``scripts/bench_monitor.py --sim 3``) found
false WARNINGs: the aggressive one right after take-off (our heading, 2.5° off from the magnetometer,
taken for 0.9° and put into our tilt by the GNSS velocity at the first bank: 2.1° of tilt error at a σ
of 0.73°), the magnetic one in flight (the autopilot 0.8–0.9° off, inside the tolerance, and ours
0.45° the other way), and an aggressive one of the held-out seeds with yaw spins (1–2 turns at 200–400°/s)
whose gyro's z scale is 0.35 % off: there our heading drifted 3–5° while the ESKF's heading σ stayed
≈ 0.6° until the ESKF modelled the gyro's scale-factor error (``EskfSettings.gyro_scale_sigma``), and the
monitor, taking our heading σ as a fixed 1°, warned falsely at 52.8 s and 74.1 s.  And two flips flights
(issue 24, round eight) whose first fast flip (600–930 °/s, at 32.5 s and 32.3 s) left our tilt 1–1.5° off for
a second or two — the gyro's scale-factor error (firmware_sim draws σ 0.2 % per axis) over a 360° turn —
while our tilt σ rose only 0.53 → 0.75°: the monitor warned falsely at 33.6 s and 33.0 s with the simulated
autopilot within 0.96° and 0.91°, until the ESKF gave the tilt the scale factor's coherent process noise
(``EskfSettings.gyro_scale_tilt_sigma``).  Each is cut to the part
that matters; firmware_sim's flight of a seed is the
same for any duration.  Times come from the flight itself (the phase the monitor classifies, the
warnings it raises), none are written in.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("firmware_sim", reason="firmware_sim (the simulator with known truth) is not importable")

#: (scenario, seed, simulated seconds)
FLIGHTS = [("aggressive", 11, 40.0), ("magnetic", 13, 45.0), ("aggressive", 3, 80.0), ("flips", 61, 40.0),
           ("flips", 72, 40.0), ("magnetic", 101, 40.0)]
TOLERANCE_TILT_DEG, TOLERANCE_HEADING_DEG = 1.0, 3.0  # issue 24: an autopilot this close is not warned about


#: flights judged for false WARNINGs only (issue 24).  firmware_sim magnetic 102 draws an accelerometer bias of
#: 0.17 m/s² horizontal (0.98° of tilt, 3.4 σ of the simulator's 0.05 m/s² per axis) that our filter, without bias
#: states on a vehicle's stream, cannot tell from tilt in its hover: our tilt error stands at 0.8–1.1° for the whole
#: flight at σ 0.5° (beyond 2σ 23 % of the time: our σ is short there, so the σ tests above are not run on it),
#: and at 123.0 s the autopilot's, 0.95°, stood the other way (docs/monitor.md round fifteen).  Magnetic 13: the
#: autopilot 0.98° off at 120.3 s, inside its tolerance, with ours the other way; warned of when the vehicle
#: stream's gyro noise was halved and our tilt σ, and the threshold with it, fell (docs/monitor.md rounds
#: eighteen and nineteen)
WARNING_FLIGHTS = [
    # magnetic 102: passes since the level CUSUM's reference is 0.75 (docs/monitor.md round twenty-two; a strict xfail
    # before, its WARNING at 123.0 s)
    pytest.param(("magnetic", 102, 125.0), id="magnetic-102"),
    pytest.param(("magnetic", 13, 125.0), id="magnetic-13"),
    # hover 32: a 0.13 m/s² horizontal bias (2.7 σ of the simulator's draw) our filter cannot tell from tilt in a
    # hover: our tilt 0.73° off at σ 0.51° (1.4σ), the autopilot 0.75° off the other way and moving; the change
    # test warns at 96.4 s.  Passes with the bias considered in our tilt σ
    # (``best.VEHICLE_ACCEL_BIAS_CONSIDER_SIGMA_M_S2`` 0.05: σ 0.65° there), which is off (docs/monitor.md round
    # twenty-one: it moves aggressive 11's correct WARNING from 101.0 to 104.8 s)
    # magnetic 91: the autopilot 0.84–0.95° off at 131.3 s, ours 0.6–0.7° (σ 0.63°); the divergence had stood at 0.5–
    # 0.8 × the level threshold for seconds (its heading part 0.5–0.77), which a CUSUM with its reference at 0.5 took
    # as evidence (the sum at its cap of 2 × the alarm level from 129.8 s), and one comparison at the threshold
    # completed it.  Passes with the reference at 0.75 (docs/monitor.md round twenty-two)
    pytest.param(("magnetic", 91, 135.0), id="magnetic-91"),
    # hover 32 (a strict xfail until round twenty-three) and magnetic 32: the change test's WARNINGs at 96.4 s and
    # 93.8 s, the autopilot 0.75° / 0.48° off.  Over the baseline's seconds the vehicle turned (hover 32 ≈ 110° at
    # 10 °/s, our error fixed in its axes turning with it; magnetic 32 71° in 3 s, the autopilot's own error fixed
    # in its body), so the standing divergence turned in the earth frame and read as a change of 1.4–1.7°.  Pass
    # since the baseline holds a part fixed in the vehicle's heading axes (MonitorSettings.change_baseline_turn,
    # docs/monitor.md round twenty-three)
    pytest.param(("hover", 32, 100.0), id="hover-32"),
    pytest.param(("magnetic", 32, 100.0), id="magnetic-32"),
]


def _fly(scenario: str, seed: int, duration: float, tmp_path_factory: pytest.TempPathFactory) -> dict:
    from mavahrs.fleet.audit import phase_events, replay_monitor
    from mavahrs.replay import ReplaySettings, replay
    from mavahrs.service.monitor import FlightPhase, MonitorSettings

    path = tmp_path_factory.mktemp("consistency") / f"{scenario}_{seed}.tlog"
    subprocess.run([sys.executable, "-m", "firmware_sim", "--fast", "--tlog", str(path), "--scenario", scenario,
                    "--duration", str(duration), "--seed", str(seed), "-q"],
                   check=True, cwd=Path(__file__).parents[2])  # fmt: skip
    res = replay(path, ReplaySettings())
    truth = next((k for k in res.references if k.endswith("truth")), None)
    assert truth is not None, f"no truth in the simulated flight: {sorted(res.references)}"
    events = phase_events(res.tlog, res.inputs, res.inputs.source)
    mon = MonitorSettings()
    series, _ = replay_monitor(res, mon, "autopilot ATTITUDE", events)
    # the phase as the monitor classifies it, at every event: when the vehicle is airborne
    ph, air = FlightPhase(mon), []
    for t, kind, v in events:
        ph.on_event(t, kind, v)
        air.append((t / 1000.0, ph.phase(t) not in ("disarmed", "ground", "unknown")))
    return {"res": res, "truth": truth, "series": series, "air": air, "settings": mon}


@pytest.fixture(scope="module", params=FLIGHTS, ids=lambda f: f"{f[0]}-{f[1]}")
def flight(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> dict:
    return _fly(*request.param, tmp_path_factory)


def _runs(t: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) times of the stretches where ``mask`` holds."""
    out, start = [], None
    for ti, m in zip(t, mask, strict=True):
        if m and start is None:
            start = ti
        elif not m and start is not None:
            out.append((start, ti))
            start = None
    if start is not None:
        out.append((start, float(t[-1])))
    return out


def _airborne_aided(flight: dict) -> tuple:
    """Our track from take-off on while GNSS-aided: the track, its times (s), the selection and the truth there."""
    from mavahrs.filters.layout import FLAG_VELOCITY_AIDED, OUT_FLAGS
    from mavahrs.service.monitor import align_attitudes

    res = flight["res"]
    takeoff = next((t for t, a in flight["air"] if a), None)
    assert takeoff is not None, "the simulated flight never left the ground"
    track = next(iter(res.tracks.values()))
    t_s = res.inputs.t_us / 1e6
    aided = (track.out[:, OUT_FLAGS].astype(np.int64) & FLAG_VELOCITY_AIDED) != 0
    sel = (t_s >= takeoff) & aided
    assert sel.sum() > 1000, "our filter was not GNSS-aided in flight"
    t_tr, q_tr = res.references[flight["truth"]]
    q_true = align_attitudes(t_tr / 1e6, q_tr, t_s[sel], tolerance_ms=30.0)
    return track, t_s, sel, q_true


def test_our_tilt_sigma_holds_our_tilt_error_once_airborne(flight: dict) -> None:
    """From leaving the ground on (take-off included: the first bank is where a heading taken for certain
    turns into a tilt error), our tilt error never stays beyond the monitor's k·σ for as long as the
    monitor's trigger time: the monitor takes that σ as what our error can be."""
    from mavahrs.filters.layout import OUT_GAIN, OUT_Q
    from mavahrs.service.monitor import divergence_series

    s = flight["settings"]
    track, t_s, sel, q_true = _airborne_aided(flight)
    q = track.out[:, OUT_Q : OUT_Q + 4]  # the published attitude (the replay applies the declination)
    err_deg, _ = divergence_series(t_s[sel], q[sel], t_s[sel], q_true)
    sigma_deg = np.degrees(track.out[sel, OUT_GAIN])
    beyond = np.nan_to_num(err_deg, nan=0.0) > s.sigma_k * sigma_deg
    long = [(a, b) for a, b in _runs(t_s[sel], beyond) if b - a >= s.trigger_s]
    worst = float(np.nanmax(err_deg / sigma_deg))
    assert not long, f"our tilt error beyond {s.sigma_k:g}σ for ≥ {s.trigger_s:g} s at {long} (worst {worst:.1f}σ)"


def test_our_heading_sigma_holds_our_heading_error_once_airborne(flight: dict) -> None:
    """The same for the heading, which the monitor takes from the ESKF's own covariance
    (``OUT_HEADING_SIGMA``): through fast yaw (spins up to 400°/s, where the gyro's scale-factor error turns
    into heading error) our heading error never stays beyond k·σ for the trigger time."""
    from mavahrs.filters.layout import IN_GYRO, OUT_HEADING_SIGMA, OUT_Q
    from mavahrs.service.monitor import divergence_series

    res, s = flight["res"], flight["settings"]
    track, t_s, sel, q_true = _airborne_aided(flight)
    sigma_deg = np.degrees(track.out[sel, OUT_HEADING_SIGMA])
    assert np.isfinite(sigma_deg).all() and (sigma_deg > 0).all(), "the ESKF gave no heading σ while aided"
    _, hdg_err_deg = divergence_series(t_s[sel], track.out[sel, OUT_Q : OUT_Q + 4], t_s[sel], q_true)
    beyond = np.abs(np.nan_to_num(hdg_err_deg, nan=0.0)) > s.sigma_k * sigma_deg
    long = [(a, b) for a, b in _runs(t_s[sel], beyond) if b - a >= s.trigger_s]
    worst = float(np.nanmax(np.abs(hdg_err_deg) / sigma_deg))
    yaw_rate = float(np.degrees(np.nanmax(np.abs(res.inputs.rows[sel, IN_GYRO + 2]))))
    assert not long, (f"our heading error beyond {s.sigma_k:g}σ for ≥ {s.trigger_s:g} s at {long} "
                      f"(worst {worst:.1f}σ; fastest yaw {yaw_rate:.0f}°/s)")


def test_no_in_flight_warning_while_the_autopilot_is_within_tolerance(flight: dict) -> None:
    """Every in-flight WARNING must come with the (simulated) autopilot beyond 1° of tilt or 3° of heading
    of the truth at some moment of the 2 s before it; the monitor's own events, judged against the truth."""
    _assert_no_false_warning(flight)


@pytest.mark.parametrize("spec", WARNING_FLIGHTS)
def test_no_in_flight_warning_over_our_standing_tilt_error(spec: tuple, tmp_path_factory: pytest.TempPathFactory) -> None:
    """Our tilt error standing for the whole flight (an accelerometer bias the filter cannot see in a hover) or
    for seconds, and the autopilot's at its 1° tolerance the other way: the divergence, up to 1.9°, is within
    what the two allow, not a fault of the autopilot's.  Magnetic 102 and magnetic 91 failed with the level
    CUSUM's reference at 0.5 (WARNINGs at 123.0 s and 131.3 s: docs/monitor.md round twenty-two);
    magnetic 13 fails with the vehicle stream's gyro noise halved (0.0015 rad/s/√Hz) and the monitor as it is
    (a WARNING at 120.3 s, docs/monitor.md round nineteen)."""
    _assert_no_false_warning(_fly(*spec, tmp_path_factory))


def _assert_no_false_warning(flight: dict) -> None:
    from mavahrs.protocol.codec import mavlink
    from mavahrs.service.monitor import FLIGHT_PHASES, align_attitudes, divergence_series

    res = flight["res"]
    warnings = [e for e in flight["series"].events
                if e.severity == mavlink.MAV_SEVERITY_WARNING and not e.update and e.phase in FLIGHT_PHASES]
    t_ap, q_ap = res.references["autopilot ATTITUDE"]
    t_tr, q_tr = res.references[flight["truth"]]
    q_true = align_attitudes(t_tr / 1e6, q_tr, t_ap / 1e6, tolerance_ms=30.0)
    tilt, hdg = divergence_series(t_ap / 1e6, q_ap, t_ap / 1e6, q_true)
    assert np.isfinite(tilt).mean() > 0.9, "the autopilot's attitude could not be judged against the truth"
    t_ap_s = t_ap / 1e6
    false = []
    for e in warnings:
        t = e.t_ms / 1000.0
        m = (t_ap_s > t - 2.0) & (t_ap_s <= t)
        if np.nanmax(tilt[m]) < TOLERANCE_TILT_DEG and np.nanmax(np.abs(hdg[m])) < TOLERANCE_HEADING_DEG:
            false.append((round(t, 2), e.text, f"AP off {np.nanmax(tilt[m]):.2f}° / {np.nanmax(np.abs(hdg[m])):.2f}°"))
    assert not false, f"in-flight WARNINGs with the autopilot within {TOLERANCE_TILT_DEG:g}°/{TOLERANCE_HEADING_DEG:g}°: {false}"


def test_an_autopilot_standing_beyond_its_heading_tolerance_is_warned(tmp_path_factory: pytest.TempPathFactory) -> None:
    """firmware_sim hover 12: the simulated autopilot's heading runs 3.3–3.8° off for a second or more (past its
    3° tolerance) with ours −0.85° at σ 1.16°, which has stood for a minute: a WARNING comes during that stretch
    or within 2 s of its end (``MonitorSettings.change_heading_sigma_growth``: the change test's heading cap
    with our σ as it stood, 3.80°, let a change of 3.9–4.1° pass for 1.2 s; none was raised)."""
    from mavahrs.protocol.codec import mavlink
    from mavahrs.service.monitor import FLIGHT_PHASES, align_attitudes, divergence_series

    flight = _fly("hover", 12, 150.0, tmp_path_factory)
    res = flight["res"]
    t_ap, q_ap = res.references["autopilot ATTITUDE"]
    t_tr, q_tr = res.references[flight["truth"]]
    t_s = t_ap / 1e6
    _, hdg = divergence_series(t_s, q_ap, t_s, align_attitudes(t_tr / 1e6, q_tr, t_s, tolerance_ms=30.0))
    airborne = [t for t, a in flight["air"] if a]
    beyond = np.abs(np.nan_to_num(hdg, nan=0.0)) > 1.1 * TOLERANCE_HEADING_DEG
    stretches = [(a, b) for a, b in _runs(t_s, beyond) if b - a >= 1.0 and airborne and a > airborne[0]]
    assert stretches, "the simulated autopilot never stood past its heading tolerance: not the flight it was"
    warned = [e.t_ms / 1000.0 for e in flight["series"].events
              if e.severity == mavlink.MAV_SEVERITY_WARNING and not e.update and e.phase in FLIGHT_PHASES]
    missed = [(round(a, 1), round(b, 1)) for a, b in stretches if not any(a <= t <= b + 2.0 for t in warned)]
    assert not missed, f"the autopilot past its heading tolerance at {missed}, WARNINGs at {warned}"
