#!/usr/bin/env python3
"""Benchmark DataFlash (.BIN) replay against a plain pymavlink DFReader loop over the same file, same run.

    python3 scripts/bench_dataflash.py                    # ~10 min built from the shared SITL .BIN
    python3 scripts/bench_dataflash.py --minutes 3 --bin flight.BIN
    python3 scripts/bench_dataflash.py --filter all       # replay every filter

The file: ``../shared/data/sitl/arducopter_onboard.BIN`` (ArduCopter SITL, IMU at 400 Hz for two
IMUs, 248 s) repeated end to end until it spans ``--minutes`` of log time, each copy's ``TimeUS``
shifted to follow the last (every record whose first column is the ``Q`` TimeUS), the last copy
cut at the span; written to a temporary directory, removed afterwards.

Timed on that one file, one after the other (wall and CPU seconds; CPU is the figure to trust on a
shared machine):

* ``reader``: :func:`mavahrs.logs.dataflash.read_dataflash`, the log's FMT records walked once and
  each message type decoded with numpy, up to the filter's input rows;
* ``replay``: :func:`mavahrs.replay.replay` of the file with ``--filter`` (default ``best``):
  reading, IMU selection, timeline, calibration, the filters over every 400 Hz sample and the
  comparison with the log's references;
* ``DFReader``: pymavlink's ``DFReader_binary`` + ``recv_match(type=...)`` over the message types
  replay reads (IMU, MAG, GPS, PARM, XKQ, ATT, AHR2, SIM), each field taken into a list: reading
  alone, no filtering.

The numba kernels are compiled (or loaded from their cache) on a short slice first; that start-up
is not in the figures.  The goal is ``replay`` ≥ 10× the DFReader loop's speed; exit status 1 if not.
"""

from __future__ import annotations

import argparse
import math
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

SHARED_BIN = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "sitl" / "arducopter_onboard.BIN"
TYPES = ("IMU", "MAG", "GPS", "PARM", "XKQ", "ATT", "AHR2", "SIM")
GOAL = 10.0


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def build_long(src: Path, minutes: float, out: Path) -> tuple[float, int]:
    """``src`` repeated, time-shifted, to span ``minutes`` of log time; (span s, IMU records) written."""
    from mavahrs.logs.dataflash import scan

    sc = scan(src)
    stamped = np.zeros(256, bool)  # types whose first column is the uint64 TimeUS
    for t, (_name, _length, fmt, cols) in sc.formats.items():
        stamped[t] = bool(fmt) and fmt[0] == "Q" and bool(cols) and cols[0] == "TimeUS"
    whole = sc.offsets
    ends = np.empty_like(whole)
    ends[:-1] = whole[1:]
    ends[-1] = sc.data.size - sc.tail_bytes  # drop an incomplete last record
    has_t = stamped[sc.ids]
    tus = np.zeros(whole.size, np.int64)
    pos = whole[has_t]
    tus[has_t] = sc.data[(pos + 3)[:, None] + np.arange(8)].copy().view("<u8").reshape(-1).astype(np.int64)
    t_first, t_last = int(tus[has_t].min()), int(tus[has_t].max())
    period = t_last - t_first + 2500  # the next copy starts one 400 Hz period after the last record
    span_us = int(minutes * 60e6)
    body = sc.data[: int(ends[-1])]
    imu_type = sc.types["IMU"]
    imu_n = 0
    with out.open("wb") as fh:
        for copy in range(math.ceil(span_us / period)):
            shift = copy * period
            chunk = body.copy()
            if shift:
                p = (pos + 3)[:, None] + np.arange(8)
                chunk[p] = (tus[has_t] + shift).astype("<u8").view(np.uint8).reshape(-1, 8)
            limit = t_first + span_us - shift
            keep = ~has_t | (tus <= limit)  # untimed records (FMT) always, timed ones inside the span
            if keep.all():
                fh.write(chunk.tobytes())
                imu_n += int(np.count_nonzero(sc.ids == imu_type))
                continue
            last = int(np.flatnonzero(keep & has_t)[-1])
            fh.write(chunk[: int(ends[last])].tobytes())
            imu_n += int(np.count_nonzero(sc.ids[: last + 1] == imu_type))
            break
    return min(span_us, math.ceil(span_us / period) * period) / 1e6, imu_n


def dfreader_loop(path: Path) -> int:
    """pymavlink's DFReader over ``TYPES``, every field into a list (what a reader built on it must do)."""
    from pymavlink import DFReader

    r = DFReader.DFReader_binary(str(path), zero_time_base=False)
    cols: dict[str, list[list[object]]] = {}
    n = 0
    while (m := r.recv_match(type=list(TYPES))) is not None:
        cols.setdefault(m.get_type(), []).append([getattr(m, f) for f in m.get_fieldnames()])
        n += 1
    return n


def timed(fn, *args, **kwargs):  # type: ignore[no-untyped-def]
    w0, c0 = time.perf_counter(), _cpu_s()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - w0, _cpu_s() - c0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", type=Path, default=SHARED_BIN, help="source DataFlash log (default: the shared SITL one)")
    ap.add_argument("--minutes", type=float, default=10.0, help="log time to build from it, min (default 10)")
    ap.add_argument("--filter", default="best", help="filters to replay (default best; 'all' for every one)")
    a = ap.parse_args(argv)
    if not a.bin.exists():
        print(f"no DataFlash log at {a.bin} (expected ../shared/data beside the checkout)", file=sys.stderr)
        return 2
    from mavahrs.filters import NAMES
    from mavahrs.logs.dataflash import read_dataflash
    from mavahrs.replay import ReplaySettings, replay

    filters = list(NAMES) if a.filter == "all" else [f.strip() for f in a.filter.split(",") if f.strip()]
    settings = ReplaySettings(filters=tuple(filters), engine="fast")
    tmp = Path(tempfile.mkdtemp(prefix="bench_dataflash_"))
    try:
        long_bin = tmp / "long.BIN"
        span_s, imu_n = build_long(a.bin, a.minutes, long_bin)
        size_mb = long_bin.stat().st_size / 1e6
        print(f"file: {a.bin.name} repeated to {span_s:.0f} s ({span_s / 60:.1f} min) of log time, "
              f"{size_mb:.0f} MB, {imu_n} IMU records (every instance)")  # fmt: skip
        short = ReplaySettings(filters=settings.filters, engine="fast", end_s=3.0)
        replay(a.bin, short)  # compile or load the kernels first
        li, rw, rc = timed(read_dataflash, long_bin)
        fed = li.inputs.t_us.size
        res, pw, pc = timed(replay, long_bin, settings)
        assert res.inputs.t_us.size == fed
        n, dw, dc = timed(dfreader_loop, long_bin)
        print(f"{'':<10}{'wall s':>9}{'CPU s':>9}{'IMU samples/s (CPU)':>22}{'× DFReader (CPU)':>18}")
        for name, w, c in (("reader", rw, rc), (f"replay {a.filter}", pw, pc), ("DFReader", dw, dc)):
            print(f"{name:<10}{w:9.2f}{c:9.2f}{fed / c:22,.0f}{dc / c:18.1f}")
        print(f"DFReader loop: {n} messages of {', '.join(TYPES)}; replay fed {fed} IMU samples "
              f"({fed / span_s:.0f} Hz) through {', '.join(settings.filters)}")  # fmt: skip
        ratio = dc / pc
        print(f"replay is {ratio:.1f}× a plain DFReader loop over the same file (CPU time; goal ≥ {GOAL:g}×)")
        return 0 if ratio >= GOAL else 1
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
