"""The IMU source allow-list through the real daemon: another node on the link cannot inject an IMU stream.

By default the first autopilot HEARTBEAT fixes the source (system and
component); ``pipeline.source_system``/``source_component`` fix it in
advance, so even an intruder that speaks first is not believed.  The
intruder's frames are valid MAVLink (no signing here): only the allow-list
stands between them and the filter.  Checked: the fake samples are counted
(``foreign_source`` / ``no_autopilot_yet`` drops, ``other_autopilot_heartbeats``),
not one reaches the filter (samples in = the genuine count; every attitude
belongs to a genuine sample; the attitude stays on the genuine motion).
"""

from __future__ import annotations

import time

import pytest

STEP_US = 2500


def _run(rt, pipeline: dict, intruder_first: bool) -> dict:
    gcs = rt.Collector()
    d = rt.InProcessDaemon(gcs.port, pipeline=pipeline)
    genuine = rt.CraftedAutopilot(d.port, system_id=1, component_id=1)
    other_system = rt.CraftedAutopilot(d.port, system_id=2, component_id=1)
    other_component = rt.CraftedAutopilot(d.port, system_id=1, component_id=2)
    intruders = (other_system, other_component)
    n, fakes = 1200, 0
    try:
        early = 0
        if intruder_first:
            for ap in intruders:
                ap.heartbeat()
                for k in range(20):  # before any genuine heartbeat
                    ap.raw_imu(ap.boot_us - 100_000 + k * STEP_US, override={"xgyro": 3000})
                    early += 1
            time.sleep(0.1)
        genuine.heartbeat()
        for ap in intruders:
            ap.heartbeat()  # claims to be an ArduPilot too
        genuine_ms = []
        for k in range(n):
            t = genuine.boot_us + k * STEP_US
            genuine.raw_imu(t)
            genuine_ms.append(t // 1000)
            if k % 3 == 0:  # a fake stream interleaved, one ms apart, spinning wildly
                for ap in intruders:
                    ap.raw_imu(t + 1000, override={"xgyro": 3000, "zgyro": 3000, "zacc": 0})
                fakes += 2
            if k % 16 == 15:
                time.sleep(0.015)
        received = gcs.wait_quiet(0.5)
    finally:
        d.stop()
        gcs.close()
        for ap in (genuine, *intruders):
            ap.close()
    st = d.pipeline.status()
    return {"status": st, "pipe": d.pipeline, "received": received, "genuine_ms": genuine_ms, "n": n,
            "fakes": fakes, "early": early, "genuine": genuine}


def _check(rt, r: dict) -> None:
    st, pipe = r["status"], r["pipe"]
    answered = rt.attitude_map(r["received"])
    assert st.vehicle == (1, 1)
    assert pipe.samples_in == r["n"]  # not one fake sample accepted
    assert set(answered) <= set(r["genuine_ms"]) and len(answered) >= 0.99 * r["n"]
    keys = sorted(k for k in answered if k >= r["genuine_ms"][0] + 500)
    err = rt.tilt_errors_deg(answered, rt.motion_truth(r["genuine"], keys), keys)
    # 3 rad/s of fake rotation would be tens of degrees; a quadrotor's HEARTBEAT: best's rotor-drag model reads
    # this tilted-at-rest motion's horizontal specific force as drag (it models no wind): 1.8° at worst
    assert err.max() < 3.0, err.max()


@pytest.mark.slow
def test_first_autopilot_heartbeat_fixes_the_source_and_fakes_are_counted(rt) -> None:
    r = _run(rt, {}, intruder_first=False)
    st = r["status"]
    print(f"\nallow-list (default): drops {dict(st.drops)} counters {dict(st.counters)}")
    _check(rt, r)
    assert st.drops.get("foreign_source") == r["fakes"]
    assert st.counters.get("other_autopilot_heartbeats") == 2
    # the status line says the drops are the other systems' (a user seeing "drops" grow would hunt for a fault)
    assert f"({r['fakes']} from other systems)" in st.line(), st.line()


@pytest.mark.slow
def test_configured_source_holds_even_when_an_intruder_speaks_first(rt) -> None:
    r = _run(rt, {"source_system": 1, "source_component": 1}, intruder_first=True)
    st = r["status"]
    print(f"\nallow-list (configured): drops {dict(st.drops)} counters {dict(st.counters)}")
    _check(rt, r)
    # before the genuine heartbeat nothing is accepted; after it, the intruders' samples are foreign
    assert st.drops.get("no_autopilot_yet", 0) + st.drops.get("foreign_source", 0) == r["fakes"] + r["early"]
    assert st.drops.get("foreign_source") == r["fakes"]
    early = st.drops.get("no_autopilot_yet", 0)
    assert f"({early} before the autopilot's HEARTBEAT, {r['fakes']} from other systems)" in st.line(), st.line()
