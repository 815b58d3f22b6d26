#!/usr/bin/env python3
"""Benchmark the MAVLink layer: bulk tlog reading vs pymavlink, and the live codec's µs per message.

    python3 scripts/bench_tlog.py                       # generated 300 s, 400 Hz RAW_IMU tlog + the real logs
    python3 scripts/bench_tlog.py --seconds 3600        # a one-hour log (1.44 M RAW_IMU)
    python3 scripts/bench_tlog.py --tlog sim.tlog       # any tlog, e.g. from `python -m firmware_sim --tlog sim.tlog --fast`

For each file: mavahrs's ``read_tlog_arrays`` (best of ``--repeat`` runs, after a
first call that loads or compiles the numba kernels) and pymavlink's
``mavlink_connection(path)`` + ``recv_match(type=types)`` over the same types,
with wall and CPU time (the CPU figure is the one to trust on a shared
machine), messages per second and the ratio; the two must return the same
number of messages.  Then the live path: ``MavCodec.receive_datagram`` per
RAW_IMU datagram and ``receive_stream`` in 64-byte reads, against pymavlink's
own ``parse_buffer`` on the same frames.

Exit status 1 if the fast reader stays under 1 million messages/s (CPU time)
on the generated log.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")  # pymavlink: same dialect module as mavahrs
os.environ.setdefault("MAVLINK_DIALECT", "ardupilotmega")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mavahrs.protocol.codec import MavCodec  # noqa: E402
from mavahrs.protocol.fast_tlog import DEFAULT_TYPES, read_tlog_arrays  # noqa: E402
from mavahrs.protocol.tlog import TlogWriter  # noqa: E402

REAL_LOGS = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "mavlink_logs"
TARGET_MSGS_PER_S = 1e6


def generate(seconds: float, rate_hz: int = 400) -> bytes:
    """A MAVProxy-like log of an ArduPilot streaming RAW_IMU at ``rate_hz`` (plus ATTITUDE, GPS, …)."""
    ap = MavCodec(1, 1)
    m = ap.mav
    f = io.BytesIO()
    w = TlogWriter(f, flush_interval_s=1.0)
    step = 1_000_000 // rate_hz
    t0 = 1_700_000_000_000_000
    for i in range(int(seconds * rate_hz)):
        tb = i * step
        now = t0 + tb
        w.write(now, ap.encode(m.raw_imu_encode(tb, 3 + i % 5, -7, -1000 + i % 3, 11, -2, i % 9, 230, -40, 410, 0, 3500)), tb * 1e-6)
        if i % (rate_hz // 50) == 0:
            w.write(now + 1, ap.encode(m.attitude_encode(tb // 1000, 0.01, -0.02, 1.5, 0.001, 0.0, -0.002)), tb * 1e-6)
        if i % (rate_hz // 10) == 0:
            w.write(now + 2, ap.encode(m.scaled_imu2_encode(tb // 1000, 2, -6, -1001, 10, -1, 7, 231, -41, 409, 3400)), tb * 1e-6)
            w.write(now + 3, ap.encode(m.ahrs2_encode(0.01, -0.02, 1.5, 100.0, 473977000, 85455000)), tb * 1e-6)
        if i % (rate_hz // 5) == 0:
            w.write(now + 4, ap.encode(m.global_position_int_encode(tb // 1000, 473977000, 85455000, 500000, 100000, 120, -30, 5, 9000)), tb * 1e-6)
            w.write(now + 5, ap.encode(m.gps_raw_int_encode(tb, 3, 473977000, 85455000, 500000, 90, 120, 123, 9000, 14)), tb * 1e-6)
        if i % rate_hz == 0:
            w.write(now + 6, ap.encode(m.heartbeat_encode(2, 3, 209, 4, 4)), tb * 1e-6)
            w.write(now + 7, ap.encode(m.system_time_encode(now, tb // 1000)), tb * 1e-6)
            w.write(now + 8, ap.encode(m.sys_status_encode(1, 1, 1, 500, 12000, 20, 80, 0, 0, 0, 0, 0, 0)), tb * 1e-6)
    w.close()
    return f.getvalue()


def timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def pymavlink_read(path: str, types: list[str]) -> int:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(path)
    n = 0
    while conn.recv_match(type=types) is not None:
        n += 1
    conn.close()
    return n


def bench_file(path: str, types: list[str], repeat: int, with_pymavlink: bool) -> tuple[float, float] | None:
    size = os.path.getsize(path)
    arrays, first_w, first_c = timed(lambda: read_tlog_arrays(path, types))
    n = sum(len(a) for a in arrays.values())
    best_w = best_c = float("inf")
    for _ in range(repeat):
        _, w, c = timed(lambda: read_tlog_arrays(path, types))
        best_w, best_c = min(best_w, w), min(best_c, c)
    print(f"\n{path}  ({size / 1e6:.1f} MB, {n} messages of {len(types)} types; RAW_IMU {len(arrays.get('RAW_IMU', []))})")
    print(f"  mavahrs read_tlog_arrays : wall {best_w * 1e3:8.1f} ms  cpu {best_c * 1e3:8.1f} ms  "
          f"-> {n / best_w / 1e6:5.2f} M msg/s wall, {n / best_c / 1e6:5.2f} M msg/s cpu "
          f"(first call {first_w:.2f} s wall: numba cache load or compile)")  # fmt: skip
    if with_pymavlink:
        n_ref, w, c = timed(lambda: pymavlink_read(path, types))
        status = "same count" if n_ref == n else f"COUNT DIFFERS: pymavlink {n_ref}"
        print(f"  pymavlink recv_match     : wall {w * 1e3:8.1f} ms  cpu {c * 1e3:8.1f} ms  "
              f"-> {n_ref / w / 1e3:6.1f} k msg/s wall ({status})")  # fmt: skip
        print(f"  speed-up                 : {w / best_w:6.0f}x wall, {c / best_c:6.0f}x cpu")
    return (n / best_c) if n else None


def bench_live(n: int = 20_000) -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    src = MavCodec(1, 1)
    frames = [src.encode(src.mav.raw_imu_encode(2500 * i, i % 50, -3, -1000, 4, -5, 6, 230, -40, 410)) for i in range(n)]
    codec = MavCodec()
    _, w, c = timed(lambda: [codec.receive_datagram(f) for f in frames])
    assert codec.counters.packets == n
    print(f"\nlive path, {n} RAW_IMU frames ({len(frames[0])} bytes)")
    print(f"  MavCodec.receive_datagram: {w / n * 1e6:6.1f} µs/msg wall, {c / n * 1e6:6.1f} µs/msg cpu")
    blob = b"".join(frames)
    codec = MavCodec()
    chunks = [blob[k : k + 64] for k in range(0, len(blob), 64)]
    _, w, c = timed(lambda: [codec.receive_stream(ch) for ch in chunks])
    assert codec.counters.packets == n
    print(f"  MavCodec.receive_stream  : {w / n * 1e6:6.1f} µs/msg wall, {c / n * 1e6:6.1f} µs/msg cpu (64-byte reads)")
    ref = mavlink.MAVLink(None)
    ref.robust_parsing = True
    _, w, c = timed(lambda: [ref.parse_buffer(f) for f in frames])
    print(f"  pymavlink parse_buffer   : {w / n * 1e6:6.1f} µs/msg wall, {c / n * 1e6:6.1f} µs/msg cpu")
    enc = MavCodec(1, 191)
    msg = enc.mav.attitude_quaternion_encode(1, 1.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3, [0, 0, 0, 0])
    _, w, c = timed(lambda: [enc.encode(msg) for _ in range(n)])
    print(f"  MavCodec.encode (ATTITUDE_QUATERNION): {w / n * 1e6:6.1f} µs/msg wall, {c / n * 1e6:6.1f} µs/msg cpu")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=300.0, help="length of the generated 400 Hz log, s (default 300)")
    ap.add_argument("--tlog", action="append", default=[], help="also benchmark this tlog (repeatable)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of the fast reader per file (best is shown)")
    ap.add_argument("--no-pymavlink", action="store_true", help="skip the (slow) pymavlink reference runs")
    ap.add_argument("--no-real", action="store_true", help="skip the real logs in ../shared/data/mavlink_logs")
    args = ap.parse_args(argv)
    types = list(DEFAULT_TYPES)
    print(f"generating a {args.seconds:.0f} s log with 400 Hz RAW_IMU ...", flush=True)
    data, w, _ = timed(lambda: generate(args.seconds))
    with tempfile.TemporaryDirectory() as d:
        gen = os.path.join(d, "generated.tlog")
        Path(gen).write_bytes(data)
        del data
        rate = bench_file(gen, types, args.repeat, not args.no_pymavlink)
        for p in args.tlog:
            bench_file(p, types, args.repeat, not args.no_pymavlink)
        if not args.no_real and REAL_LOGS.is_dir():
            for p in sorted(REAL_LOGS.glob("*/*.tlog")):
                bench_file(str(p), types, args.repeat, not args.no_pymavlink)
    bench_live()
    ok = rate is not None and rate >= TARGET_MSGS_PER_S
    print(f"\ntarget: fast reader >= {TARGET_MSGS_PER_S / 1e6:.0f} M msg/s (cpu) on the generated log: "
          f"{'met' if ok else 'MISSED'} ({(rate or 0) / 1e6:.2f} M msg/s)")  # fmt: skip
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
