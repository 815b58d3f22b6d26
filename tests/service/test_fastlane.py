"""The daemon's fast lane answers exactly what the Python path answers, or stands aside.

Each datagram goes to the lane first and then through the real codec and
Pipeline; every answer the lane gives must equal, byte for byte, the
ATTITUDE_QUATERNION the pipeline builds for that datagram.  The daemon tests
send real datagrams over UDP sockets.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from typing import Any

import numpy as np
import pytest

from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.service.daemon import DaemonSettings, build_daemon
from mavahrs.service.fastlane import I_SEQ, FastLane
from mavahrs.service.pipeline import Pipeline, PipelineSettings

_AQ_ID = mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION


class Autopilot:
    """RAW_IMU of a vehicle turning slowly (with a second IMU if asked), plus HEARTBEAT and GNSS."""

    def __init__(self, seed: int = 1, second_imu: bool = False) -> None:
        self.codec = MavCodec(1, 1)
        self.rng = np.random.default_rng(seed)
        self.t_us = 1_000_000
        self.k = 0
        self.second_imu = second_imu

    def heartbeat(self) -> bytes:
        return self.codec.encode(self.codec.mav.heartbeat_encode(2, 3, 0, 0, 4))

    def raw_imu(self, imu: int = 0, **override: int) -> bytes:
        k = self.k
        g = (30 * math.sin(k / 80), 20 * math.cos(k / 50), 50)
        f = dict(
            xacc=int(self.rng.normal(0, 8)), yacc=int(self.rng.normal(0, 8)), zacc=-1000 + int(self.rng.normal(0, 8)),
            xgyro=int(g[0] + self.rng.normal(0, 2)), ygyro=int(g[1] + self.rng.normal(0, 2)),
            zgyro=int(g[2] + self.rng.normal(0, 2)),
            xmag=200 + int(self.rng.normal(0, 3)), ymag=int(self.rng.normal(0, 3)), zmag=400 + int(self.rng.normal(0, 3)),
        )  # fmt: skip
        f.update(override)
        m = self.codec.mav.raw_imu_encode(
            self.t_us, f["xacc"], f["yacc"], f["zacc"], f["xgyro"], f["ygyro"], f["zgyro"],
            f["xmag"], f["ymag"], f["zmag"], imu, 0,
        )  # fmt: skip
        return self.codec.encode(m)

    def step(self) -> None:
        self.t_us += 2500
        self.k += 1

    def stream(self, n: int) -> list[bytes]:
        """A HEARTBEAT, then ``n`` RAW_IMU datagrams 2.5 ms apart."""
        out = [self.heartbeat()]
        for _ in range(n):
            self.step()
            out.append(self.raw_imu())
        return out

    def gnss(self) -> bytes:
        m = self.codec.mav.global_position_int_encode(
            self.t_us // 1000, -353632620, 1491652370, 584000, 0, 120, -40, 5, 0
        )
        return self.codec.encode(m)


def _aq(outs: list[Any]) -> list[bytes]:
    return [o.frame for o in outs if o.frame[7] == _AQ_ID]


def _run(pipe: Pipeline, datagrams: list[bytes]) -> tuple[int, int, list[int], list[bool]]:
    """(lane answers, pipeline attitudes, indices where the lane stood aside but the pipeline answered,
    whether the lane answered each datagram); every answer is checked against the pipeline's frame."""
    lane = FastLane(pipe)
    assert lane.usable
    rx = MavCodec()
    answers = attitudes = 0
    aside = []
    answered = []
    for i, d in enumerate(datagrams):
        ans = lane.answer(d)
        outs: list[Any] = []
        for m in rx.receive_datagram(d):
            outs += pipe.handle(m, 2500 * i)
        aq = _aq(outs)
        attitudes += len(aq)
        if ans is not None:
            answers += 1
            assert aq and aq[0] == ans, f"datagram {i}: the lane answered {ans.hex()}, the pipeline {aq}"
        elif aq:
            aside.append(i)
        answered.append(ans is not None)
        lane.refresh()
    return answers, attitudes, aside, answered


@pytest.mark.parametrize("name", ["best", "madgwick", "mahony", "complementary", "gyroplatform"])
@pytest.mark.parametrize("out_rate", [0.0, 50.0])
def test_every_answer_is_the_pipelines_frame(name: str, out_rate: float) -> None:
    ap = Autopilot()
    dgrams = ap.stream(1600)
    pipe = Pipeline(PipelineSettings(filter_name=name, out_rate_hz=out_rate))
    answers, attitudes, aside, _ = _run(pipe, dgrams)
    assert attitudes > (1000 if out_rate == 0 else 150)
    assert answers >= attitudes - 3, f"the lane stood aside on {aside}"  # all but the start


def test_the_battery_current_in_the_pipelines_rows_is_the_lanes_too() -> None:
    # ``best`` on an autopilot's stream runs the magnetometer model, whose motor field scales with the
    # battery current (SYS_STATUS) the pipeline puts in every sample's row: the lane's rows carry the
    # same current while it is fresh, and no current once it has gone stale (5 s without SYS_STATUS)
    from mavahrs.filters.layout import IN_CURRENT

    ap = Autopilot()
    dgrams = []
    for i, d in enumerate(ap.stream(3200)):
        dgrams.append(d)
        if i % 40 == 1 and i < 1200:  # 10 Hz for the first 3 s, then none
            msg = ap.codec.mav.sys_status_encode(0, 0, 0, 500, 11100, 1500 + (i % 400), 80, 0, 0, 0, 0, 0, 0)
            dgrams.append(ap.codec.encode(msg))
    pipe = Pipeline(PipelineSettings(filter_name="best"))
    answers, attitudes, aside, _ = _run(pipe, dgrams)
    assert answers >= attitudes - 200, f"the lane stood aside on {len(aside)} samples"
    assert pipe._row[IN_CURRENT] != pipe._row[IN_CURRENT]  # stale at the end: NaN in the pipeline's row …
    lane = FastLane(pipe)
    lane.refresh()
    assert math.isnan(lane._row[IN_CURRENT])  # … and in the lane's
    fresh = Pipeline(PipelineSettings(filter_name="best"))
    _run(fresh, dgrams[:1100])  # 2.7 s in: SYS_STATUS at 10 Hz
    lane = FastLane(fresh)
    lane.refresh()
    assert 15.0 <= fresh._row[IN_CURRENT] <= 19.0 and lane._row[IN_CURRENT] == fresh._row[IN_CURRENT]


def test_it_stands_aside_where_the_steady_state_ends() -> None:
    """Saturation, a gap, a duplicate, MAVLink 1, a bad CRC, a foreign source, GNSS velocity, declination."""
    ap = Autopilot(seed=2)
    special: dict[int, str] = {}
    dgrams = [ap.heartbeat()]
    for k in range(2400):
        ap.step()
        i = len(dgrams)
        if k == 300:
            dgrams.append(ap.raw_imu(xgyro=32767))
            special[i] = "saturated"
        elif k == 400:
            ap.t_us += 800_000  # 0.8 s: beyond the timeline's gap limit (0.5 s)
            dgrams.append(ap.raw_imu())
            special[i] = "gap"
        elif k == 500:
            dgrams.append(dgrams[-1])
            special[i] = "duplicate"
        elif k == 600:
            bad = bytearray(ap.raw_imu())
            bad[-1] ^= 0xFF
            dgrams.append(bytes(bad))
            special[i] = "bad CRC"
        elif k == 700:
            other = MavCodec(7, 1)
            dgrams.append(
                other.encode(other.mav.raw_imu_encode(ap.t_us, 0, 0, -1000, 0, 0, 0, 200, 0, 400, 0, 0))
            )
            special[i] = "foreign"
        elif k == 800:
            dgrams.append(ap.gnss())  # the next row carries the velocity: the Python path's
            special[i + 1] = "velocity"
            ap.step()
            dgrams.append(ap.raw_imu())
        elif k == 1000:
            m = ap.codec.mav.raw_imu_encode(ap.t_us, 0, 0, -1000, 1, 2, 3, 200, 0, 400)
            dgrams.append(ap.codec.encode(m, force_mavlink1=True))
            special[i] = "MAVLink 1"
        elif k == 900:
            dgrams.append(bytes(ap.raw_imu(zacc=0, xacc=0, yacc=0, xgyro=0, ygyro=0, zgyro=0)))
            special[i] = "all zero"
        elif k == 1100:  # a bundle led by another message: the Python path's
            dgrams.append(ap.heartbeat() + ap.raw_imu())
            special[i] = "bundle led by a HEARTBEAT"
        elif k == 1200:  # a bundle led by the sample: the lane's (checked equal like every answer)
            dgrams.append(ap.raw_imu() + ap.heartbeat())
            bundle_led_by_imu = i
        else:
            dgrams.append(ap.raw_imu())
    pipe = Pipeline(PipelineSettings(filter_name="best", out_rate_hz=0.0), decimal_year=2026.9)
    _, _, _, answered = _run(pipe, dgrams)
    for i, why in special.items():
        assert not answered[i], f"the lane answered a {why} sample ({i})"
    assert answered[bundle_led_by_imu]
    # after each special case it comes back
    assert sum(answered) > 2000
    # the position gave a declination: answered frames after it carry it too (checked equal above)
    assert pipe.declination.declination_rad != 0.0
    assert any(answered[i] for i in range(max(special) + 10, len(dgrams)))


def test_two_imu_instances_only_between_the_selectors_evaluations() -> None:
    """With a second IMU the selector may switch at each evaluation (every 20 ms): those samples are the pipeline's."""
    ap = Autopilot(seed=3)
    dgrams = [ap.heartbeat()]
    for _ in range(1200):
        ap.step()
        dgrams.append(ap.raw_imu(0))
        dgrams.append(ap.raw_imu(1))
    pipe = Pipeline(PipelineSettings(filter_name="madgwick", out_rate_hz=0.0))
    answers, attitudes, _, _ = _run(pipe, dgrams)
    assert attitudes > 1000
    assert 0.7 * attitudes < answers < attitudes  # most, not all


def _run_queued(pipe: Pipeline, datagrams: list[bytes], seed: int = 0) -> tuple[int, int, list[bool]]:
    """As :func:`_run`, but the datagrams arrive in bursts of 1–15, handled as the daemon handles its
    inbox: while two or more wait, ``answer_queue`` answers a chain of them; the others one by one.

    Returns (answers, pipeline attitudes, whether each datagram was answered)."""
    lane = FastLane(pipe)
    rx = MavCodec()
    rng = np.random.default_rng(seed)
    answers = attitudes = 0
    answered = [False] * len(datagrams)
    chained = 0
    i = 0
    while i < len(datagrams):
        inbox = list(range(i, min(i + int(rng.integers(1, 16)), len(datagrams))))
        i = inbox[-1] + 1
        chain: list[bytes | None] = []
        while inbox:
            if not chain and len(inbox) > 1:
                chain = lane.answer_queue(datagrams[k] for k in inbox)
                assert len(chain) <= len(inbox)
                chained += sum(a is not None for a in chain)
            k = inbox.pop(0)
            if chain:
                ans = chain.pop(0)
                in_chain = True
            else:
                ans = lane.answer(datagrams[k])
                in_chain = False
            outs: list[Any] = []
            for m in rx.receive_datagram(datagrams[k]):
                outs += pipe.handle(m, 2500 * k)
            aq = _aq(outs)
            attitudes += len(aq)
            if ans is not None:
                answers += 1
                answered[k] = True
                assert aq and aq[0] == ans, f"datagram {k} differs (chained: {in_chain})"
            elif in_chain:  # the filter stepped in the chain, no output was due
                assert not aq, f"datagram {k}: the chain saw no output due, the pipeline sent one"
            lane.refresh()
    assert chained > 0.5 * answers  # most answers came from chains
    return answers, attitudes, answered


@pytest.mark.parametrize("name", ["best", "madgwick", "mahony"])
@pytest.mark.parametrize("out_rate", [0.0, 50.0])
def test_chained_answers_over_queued_datagrams_are_the_pipelines_frames(name: str, out_rate: float) -> None:
    """Datagrams that queued up are answered one after the other from the lane's own state: each
    answer, including its sequence number and the output-rate rule, equals the pipeline's frame."""
    ap = Autopilot(seed=5)
    dgrams = ap.stream(1600)
    pipe = Pipeline(PipelineSettings(filter_name=name, out_rate_hz=out_rate))
    answers, attitudes, _ = _run_queued(pipe, dgrams)
    assert attitudes > (1000 if out_rate == 0 else 150)
    assert answers >= attitudes - 3


def test_a_chain_ends_where_the_steady_state_ends() -> None:
    """Bursts holding a gap, a bad CRC, a GNSS fix, a bundle: the chain stops before (or, for a
    bundle led by the sample, after) them, never answering what the pipeline answers otherwise."""
    ap = Autopilot(seed=6)
    special: dict[int, str] = {}
    dgrams = [ap.heartbeat()]
    for k in range(2000):
        ap.step()
        i = len(dgrams)
        if k % 250 == 100:
            ap.t_us += 800_000
            dgrams.append(ap.raw_imu())
            special[i] = "gap"
        elif k % 250 == 150:
            bad = bytearray(ap.raw_imu())
            bad[20] ^= 0x55
            dgrams.append(bytes(bad))
            special[i] = "bad CRC"
        elif k % 250 == 200:
            dgrams.append(ap.raw_imu() + ap.gnss())  # answered; the next row carries the velocity
            ap.step()
            dgrams.append(ap.raw_imu())
            special[i + 1] = "velocity"
        else:
            dgrams.append(ap.raw_imu())
    pipe = Pipeline(PipelineSettings(filter_name="best", out_rate_hz=0.0))
    answers, attitudes, answered = _run_queued(pipe, dgrams, seed=1)
    for i, why in special.items():
        assert not answered[i], f"the chain answered a {why} sample ({i})"
    assert answers > 0.9 * attitudes


def test_no_chain_while_the_monitor_holds_an_autopilot_attitude() -> None:
    """The monitor's STATUSTEXT would take a sequence number the chain cannot foresee."""
    ap = Autopilot(seed=7)
    pipe = Pipeline(PipelineSettings(filter_name="madgwick", out_rate_hz=0.0))
    lane = FastLane(pipe)
    rx = MavCodec()
    for d in ap.stream(5):
        for m in rx.receive_datagram(d):
            pipe.handle(m, 0)
        lane.refresh()
    burst = []
    for _ in range(4):
        ap.step()
        burst.append(ap.raw_imu())
    assert len(lane.answer_queue(burst)) == 4
    att = ap.codec.encode(ap.codec.mav.attitude_encode(ap.t_us // 1000 + 50, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0))
    for m in rx.receive_datagram(att):
        pipe.handle(m, 0)
    lane.refresh()
    assert pipe._monitor._pending
    assert lane.answer_queue(burst) == []
    assert lane.answer(burst[0]) is not None  # one at a time it still answers (the mirror is exact)


# --------------------------------------------------------------------------- the daemon, over UDP


def _daemon_run(
    fast_lane: bool, n: int, sabotage: bool = False, stall: bool = False, sabotage_chain: bool = False
) -> tuple[list[Any], Any, Any]:
    """Run a daemon in a thread against ``n`` RAW_IMU datagrams sent 1 ms apart over UDP.

    ``sabotage``: the lane's mirror gets a wrong sequence number after every refresh from the 200th on;
    ``stall``: the daemon sleeps 40 ms there (as if not scheduled), so datagrams queue up;
    ``sabotage_chain``: the first chain of five or more datagrams that the lane answers starts from a wrong
    sequence number."""
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.05)
    d = build_daemon(DaemonSettings(
        master="udpin:127.0.0.1:0", outputs=(f"udpout:127.0.0.1:{gcs.getsockname()[1]}",), status_interval_s=0.0,
        fast_lane=fast_lane,
    ), PipelineSettings(filter_name="madgwick", out_rate_hz=0.0))  # fmt: skip
    if sabotage or stall:
        lane = d._lane
        real = lane.refresh
        calls = [0]

        def refresh() -> None:
            real()
            calls[0] += 1
            if calls[0] == 200 and stall:
                time.sleep(0.04)
            if calls[0] >= 200 and sabotage:
                # the lane's next frame is wrong (again after every refresh, the timer's too, until
                # the daemon has caught it and switched the lane off)
                lane.icfg[I_SEQ] = (lane.icfg[I_SEQ] + 1) % 256

        lane.refresh = refresh
    if sabotage_chain:
        chain_lane = d._lane
        real_queue = chain_lane.answer_queue
        done = [False]
        sabotaged: list[int] = []  # answers in the sabotaged chain

        def answer_queue(datas: Any) -> list[bytes | None]:
            datas = list(datas)
            if len(datas) < 5 or done[0]:
                return real_queue(datas)
            seq = chain_lane.icfg[I_SEQ]
            chain_lane.icfg[I_SEQ] = (seq + 1) % 256  # (refresh() mends it)
            taken = real_queue(datas)
            answered = sum(a is not None for a in taken)
            if answered == 0:
                # no chain went out (the lane not on yet on a loaded machine, a HEARTBEAT first):
                # nothing sabotaged; the next queue of five is
                chain_lane.icfg[I_SEQ] = seq
                return taken
            done[0] = True
            sabotaged.append(answered)
            return taken

        chain_lane.answer_queue = answer_queue
    ap = Autopilot(seed=4)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    addr = ("127.0.0.1", d.master.local_address[1])
    box: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: box.update(result=d.run()), daemon=True)
    thread.start()
    got: list[Any] = []
    rx = MavCodec()
    try:
        sock.sendto(ap.heartbeat(), addr)
        time.sleep(0.05)
        for _ in range(n):
            ap.step()
            sock.sendto(ap.raw_imu(), addr)
            time.sleep(0.001)
            gcs.setblocking(False)  # the sender keeps its pace while the daemon stalls
            try:
                while True:
                    got += rx.receive_datagram(gcs.recv(4096))
            except BlockingIOError:
                pass
            gcs.settimeout(0.05)
        # what the daemon still has to answer: until no attitude came for 1.5 s (a loaded machine may hold the
        # daemon's thread back for a while; the cap only a stuck daemon reaches; its 1 Hz HEARTBEAT goes on)
        quiet_until, cap = time.monotonic() + 1.5, time.monotonic() + 60.0
        while time.monotonic() < min(quiet_until, cap):
            try:
                new = rx.receive_datagram(gcs.recv(4096))
            except TimeoutError:
                continue
            got += new
            if any(m.get_type() == "ATTITUDE_QUATERNION" for m in new):
                quiet_until = time.monotonic() + 1.5
    finally:
        d.stop()
        thread.join(10)
        sock.close()
        gcs.close()
    if sabotage_chain:
        d.counters.sabotaged_chain = sabotaged[0] if sabotaged else 0  # type: ignore[attr-defined]
    return [m for m in got if m.get_type() == "ATTITUDE_QUATERNION"], d.counters, box.get("result")


def test_the_daemon_answers_from_the_lane_and_sends_each_attitude_once() -> None:
    fast, fc, _ = _daemon_run(True, 600)
    slow, sc, _ = _daemon_run(False, 600)
    assert fc.fast_lane_answers >= 0.95 * fc.attitudes_out and fc.fast_lane_mismatches == 0
    assert sc.fast_lane_answers == 0
    # the same attitudes, each once, as the Python path alone sends them
    times = [m.time_boot_ms for m in fast]
    assert len(times) == len(set(times)) >= 590
    a = {m.time_boot_ms: (m.q1, m.q2, m.q3, m.q4, m.rollspeed) for m in fast}
    b = {m.time_boot_ms: (m.q1, m.q2, m.q3, m.q4, m.rollspeed) for m in slow}
    assert a == b


def test_an_unconfirmed_answer_is_logged_counted_and_switches_the_lane_off(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with caplog.at_level(logging.WARNING, logger="mavahrs"):
        att, c, _ = _daemon_run(True, 500, sabotage=True)
    # one (or, had datagrams queued up just then, each of a chain's answers) caught, said once
    assert c.fast_lane_mismatches >= 1
    assert 150 < c.fast_lane_answers < 250  # answered until the sabotage, then off
    warnings = [
        r for r in caplog.records if "fast lane" in r.getMessage() and "not confirmed" in r.getMessage()
    ]
    assert len(warnings) == 1
    # the pipeline's frame went out too: every sample still has its (correct) attitude
    assert len({m.time_boot_ms for m in att}) >= 490


def test_after_a_stall_the_queued_datagrams_are_answered_in_a_chain() -> None:
    fast, fc, _ = _daemon_run(True, 600, stall=True)
    slow, _, _ = _daemon_run(False, 600, stall=False)
    assert fc.fast_lane_chained >= 10 and fc.fast_lane_mismatches == 0
    assert fc.fast_lane_answers >= 0.95 * fc.attitudes_out
    a = {m.time_boot_ms: (m.q1, m.q2, m.q3, m.q4, m.rollspeed) for m in fast}
    b = {m.time_boot_ms: (m.q1, m.q2, m.q3, m.q4, m.rollspeed) for m in slow}
    assert len(fast) == len(a) >= 590 and a == b  # each once, the same as the Python path's


def test_a_chain_gone_wrong_is_caught_and_every_sample_still_gets_its_attitude(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with caplog.at_level(logging.WARNING, logger="mavahrs"):
        att, c, _ = _daemon_run(True, 500, stall=True, sabotage_chain=True)
    assert c.sabotaged_chain >= 5  # the wrong chain went out …
    assert c.fast_lane_mismatches == c.sabotaged_chain  # … and each of its frames was caught
    warnings = [r for r in caplog.records if "not confirmed" in r.getMessage()]
    assert len(warnings) == 1
    assert len({m.time_boot_ms for m in att}) >= 490


def test_a_failing_lane_is_switched_off_and_the_daemon_goes_on(caplog: pytest.LogCaptureFixture) -> None:
    """An exception inside the lane (never expected) costs the lane, not the daemon or the attitude."""
    original, original_queue = FastLane.answer, FastLane.answer_queue
    calls = [0]  # datagrams the lane was given, one at a time or queued

    def count(data: bytes) -> bytes:
        calls[0] += 1
        if calls[0] == 100:
            raise RuntimeError("lane broke")
        return data

    def answer(self: FastLane, data: bytes) -> bytes | None:
        return original(self, count(data))

    def answer_queue(self: FastLane, datas: Any) -> list[bytes | None]:
        return original_queue(self, (count(d) for d in datas))

    FastLane.answer, FastLane.answer_queue = answer, answer_queue  # type: ignore[method-assign]
    try:
        with caplog.at_level(logging.WARNING, logger="mavahrs"):
            att, c, result = _daemon_run(True, 300)
    finally:
        FastLane.answer, FastLane.answer_queue = original, original_queue  # type: ignore[method-assign]
    assert result is not None and c.fast_lane_mismatches == 0
    assert 50 <= c.fast_lane_answers < 100  # (a chain the failure hit sent nothing: up to its length fewer)
    assert any("fast lane failed" in r.getMessage() for r in caplog.records)
    assert len({m.time_boot_ms for m in att}) >= 295  # the Python path answered the rest
