#!/usr/bin/env python3
"""Microseconds per IMU message through ``Pipeline.handle`` (with pymavlink decode and encode).

Builds a 400 Hz ArduPilot-style RAW_IMU stream (heartbeat, then a vehicle
turning and rocking) with :class:`MavCodec`, decodes each frame as the daemon
does and passes it to the pipeline, timing decode and ``handle`` separately
with ``perf_counter_ns``.  Prints p50/p90/p99/max per configuration.

    nice python3 scripts/profile_pipeline.py [--seconds 30] [--filter best]

The daemon budget (issue 4) is p50 ≤ 200 µs per message including decode and
encode; other processes on the machine inflate p99 and max.
"""

from __future__ import annotations

import argparse
import gc
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mavahrs.protocol.codec import MavCodec  # noqa: E402
from mavahrs.service.pipeline import Pipeline, PipelineSettings  # noqa: E402

G = 9.80665


def stream(seconds: float, rate_hz: float = 400.0) -> list[bytes]:
    ap = MavCodec(1, 1)
    frames = [ap.encode(ap.mav.heartbeat_encode(2, 3, 0, 0, 4))]
    n = int(seconds * rate_hz)
    for k in range(n):
        t = k / rate_hz
        roll = 0.3 * math.sin(2 * math.pi * 0.3 * t)
        yaw_rate = 0.5
        p = 0.3 * 2 * math.pi * 0.3 * math.cos(2 * math.pi * 0.3 * t)
        # level-ish body: gravity mostly on z, tilted by roll
        acc = (0, round(-math.sin(roll) * -1000), round(-math.cos(roll) * 1000))
        yaw = yaw_rate * t
        mag = (round(200 * math.cos(yaw)), round(-200 * math.sin(yaw)), 450)
        gyro = (round(p * 1000), 0, round(yaw_rate * 1000))
        frames.append(ap.encode(ap.mav.raw_imu_encode(1_000_000 + round(t * 1e6), *acc, *gyro, *mag, 0, 3500)))
        if k % int(rate_hz) == 0:
            frames.append(ap.encode(ap.mav.heartbeat_encode(2, 3, 0, 0, 4)))
    return frames


def run(frames: list[bytes], settings: PipelineSettings) -> tuple[np.ndarray, np.ndarray, int]:
    pipe = Pipeline(settings)
    rx = MavCodec(0, 0)
    dec_ns, handle_ns = [], []
    now_us = 0
    outputs = 0
    gc.collect()
    gc.freeze()
    for i, data in enumerate(frames):
        now_us += 2500
        a = time.perf_counter_ns()
        msgs = rx.receive_datagram(data)
        b = time.perf_counter_ns()
        for m in msgs:
            outputs += len(pipe.handle(m, now_us))
        c = time.perf_counter_ns()
        if i % 20 == 0:
            pipe.tick(now_us)
        if msgs and msgs[0].get_type() == "RAW_IMU" and i > 2000:  # after warm-up (numba, caches)
            dec_ns.append(b - a)
            handle_ns.append(c - b)
    gc.unfreeze()
    return np.array(dec_ns) / 1000.0, np.array(handle_ns) / 1000.0, outputs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--filter", default="best")
    args = ap.parse_args()
    frames = stream(args.seconds)
    print(f"{len(frames)} frames, filter {args.filter}")
    print(f"{'configuration':34s} {'part':16s} {'p50':>7s} {'p90':>7s} {'p99':>7s} {'max':>8s}  µs")
    for label, s in (
        ("out_rate 0 (every sample)", PipelineSettings(filter_name=args.filter, out_rate_hz=0.0)),
        ("out_rate 50 Hz", PipelineSettings(filter_name=args.filter, out_rate_hz=50.0)),
        ("out_rate 0 + ATTITUDE", PipelineSettings(filter_name=args.filter, out_rate_hz=0.0, send_attitude_euler=True)),
    ):
        dec, han, outs = run(frames, s)
        tot = dec + han
        for part, x in (("decode", dec), ("handle", han), ("decode+handle", tot)):
            q = np.percentile(x, [50, 90, 99])
            print(f"{label:34s} {part:16s} {q[0]:7.1f} {q[1]:7.1f} {q[2]:7.1f} {x.max():8.1f}")
        print(f"{'':34s} outputs: {outs}")


if __name__ == "__main__":
    main()
