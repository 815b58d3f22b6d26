"""The demo's live status line: the error against the simulator's truth is shown whatever the stream phases."""

from __future__ import annotations

import math

from mavahrs.demo import TruthTap, _Live
from mavahrs.geometry.rotation import from_euler_rad


class _Gcs:
    def __init__(self) -> None:
        self.t_ms: list[int] = []
        self.q: list[tuple[float, float, float, float]] = []


class _Pipeline:
    def handle(self, msg: object, now_us: int) -> list[object]:
        return []


def _tap_with_truth(truth_ms: list[int], rpy: tuple[float, float, float]) -> TruthTap:
    """A tap fed RAW_IMU + SIMSTATE in one datagram on each tick of ``truth_ms``, RAW_IMU alone between."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    tap = TruthTap(_Pipeline())
    for k, t in enumerate(truth_ms):
        now_us = 10_000_000 + 10 * k
        tap.handle(
            mavlink.MAVLink_raw_imu_message(t * 1000, 0, 0, -1000, 0, 0, 0, 200, 30, 450, 0, 3500), now_us
        )
        tap.handle(mavlink.MAVLink_simstate_message(*rpy, 0, 0, -9.8, 0, 0, 0, 0, 0), now_us)
        tap.handle(mavlink.MAVLink_raw_imu_message(t * 1000 + 2500, 0, 0, -1000, 0, 0, 0, 200, 30, 450, 0, 3500),
                   now_us + 5)  # fmt: skip
    assert sorted(tap.truth_by_ms) == sorted(truth_ms)
    return tap


def test_error_shown_when_the_nearest_truth_is_a_tick_not_yet_received() -> None:
    # The pattern of a failed CI run: RAW_IMU and SIMSTATE both at 250 Hz on a 400 Hz loop,
    # in phase only on some ticks; attitudes at 50 Hz fall 5 ms before a truth tick and 7 ms
    # after the previous one.  At the moment of the status line the newest attitude's truth
    # (5 ms later) has not arrived.
    rpy = (math.radians(10.0), math.radians(-5.0), math.radians(100.0))
    truth_ms = [t for t in range(1000, 2040) if t % 20 in (5, 12)]  # ticks with SIMSTATE, up to 2032
    gcs = _Gcs()
    tilt = from_euler_rad(rpy[0] + math.radians(2.0), rpy[1], rpy[2])  # 2° off in roll
    for t in range(1007, 2048, 20):  # attitudes at …, 2027, 2047
        gcs.t_ms.append(t)
        gcs.q.append(tuple(float(x) for x in tilt))
    line = _Live(_tap_with_truth(truth_ms, rpy), gcs).line(4.0)  # type: ignore[arg-type]
    assert "error vs truth" in line, line
    assert "tilt  2.0°" in line, line


def test_no_error_without_any_truth_near_the_attitudes() -> None:
    gcs = _Gcs()
    gcs.t_ms.append(5000)
    gcs.q.append((1.0, 0.0, 0.0, 0.0))
    line = _Live(_tap_with_truth([1000], (0.0, 0.0, 0.0)), gcs).line(4.0)  # type: ignore[arg-type]
    assert "error vs truth" not in line
    assert "roll" in line


def test_the_input_rate_is_counted_over_a_window_not_between_two_lines(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A 250 Hz stream delivered in bursts (100 then 150 messages between lines 0.5 s apart, as on a
    busy machine) reads 250 Hz once the window is full; between two lines it read 200 and 300 Hz."""
    import re
    import types

    import mavahrs.demo as demo

    clock = [100.0]
    monkeypatch.setattr(demo, "time", types.SimpleNamespace(monotonic=lambda: clock[0]))
    tap = types.SimpleNamespace(imu_messages=0, truth_by_ms={})
    live = _Live(tap, _Gcs())  # type: ignore[arg-type]
    shown: list[float] = []
    for k in range(16):  # 8 s of lines every 0.5 s
        clock[0] += 0.5
        tap.imu_messages += 100 if k % 2 == 0 else 150
        m = re.search(r"\| in +([0-9]+) Hz", live.line(0.5 * (k + 1)))
        assert m, k
        shown.append(float(m.group(1)))
    assert all(240 <= hz <= 260 for hz in shown[3:]), shown  # from a full 2 s window on
