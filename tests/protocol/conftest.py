"""Shared helpers for the protocol tests: generated tlogs, fuzz mutations, pymavlink as reference."""

from __future__ import annotations

import contextlib
import io
import os
import random
from collections.abc import Callable, Iterator
from types import SimpleNamespace
from typing import Any

import pytest

from mavahrs.protocol.codec import MavCodec
from mavahrs.protocol.tlog import TlogWriter

T0_US = 1_700_000_000_000_000
SIGNING_KEY = bytes(range(32))


def _make_tlog(seconds: float = 1.0, rate_hz: int = 400, seed: int = 0, signed: bool = True) -> bytes:
    """A tlog like a MAVProxy log of a fast-streaming ArduPilot: 400 Hz RAW_IMU and the rest.

    MAVLink 2 frames (zero-trimmed payloads: many fields are 0), MAVLink 1
    frames from a ground station (including PARAM_REQUEST_LIST, whose 2-byte
    payload trips pymavlink's sequential reader after a MAVLink 2 frame),
    signed frames from a companion, NaN floats, strings.
    """
    rng = random.Random(seed)
    ap, gcs, comp = MavCodec(1, 1), MavCodec(255, 190), MavCodec(1, 191)
    if signed:
        comp.enable_signing(SIGNING_KEY, link_id=3, initial_timestamp_10us=10**12)
    f = io.BytesIO()
    w = TlogWriter(f, flush_interval_s=0)
    n = int(seconds * rate_hz)
    step = 1_000_000 // rate_hz

    def r16() -> int:
        return rng.choice([0, 0, rng.randint(-32768, 32767)])

    def rf() -> float:
        return rng.choice([0.0, rng.uniform(-10, 10), float("nan") if rng.random() < 0.02 else 1.5])

    m = ap.mav
    for i in range(n):
        tb = i * step
        t = T0_US + tb
        fr = [ap.encode(m.raw_imu_encode(tb, *[r16() for _ in range(9)], rng.choice([0, 1]), r16()))]
        if i % 2 == 0:
            fr.append(ap.encode(m.scaled_imu2_encode(tb // 1000, *[r16() for _ in range(10)])))
        if i % 8 == 0:
            fr.append(ap.encode(m.highres_imu_encode(tb, *[rf() for _ in range(13)], rng.randint(0, 65535), 2)))
        if i % 8 == 4:
            fr.append(ap.encode(m.attitude_encode(tb // 1000, *[rf() for _ in range(6)])))
        if i % 40 == 1:
            fr.append(ap.encode(m.attitude_quaternion_encode(tb // 1000, *[rf() for _ in range(7)], [rf() for _ in range(4)])))
        if i % 40 == 2:
            fr.append(ap.encode(m.ahrs2_encode(*[rf() for _ in range(4)], rng.randint(-(2**31), 2**31 - 1), 5)))
        if i % 40 == 3:
            fr.append(ap.encode(m.simstate_encode(*[rf() for _ in range(9)], 1, 2)))
        if i % 40 == 5:
            fr.append(ap.encode(m.sim_state_encode(*[rf() for _ in range(21)], 7, 8)))
        if i % 80 == 6:
            fr.append(ap.encode(m.global_position_int_encode(tb // 1000, 1, 2, 3, 4, 5, -6, 7, 8)))
        if i % 80 == 7:
            fr.append(ap.encode(m.gps_raw_int_encode(tb, 3, 1, 2, 3, 4, 5, 6, 7, 8)))
        if i % 400 == 8:
            fr.append(ap.encode(m.heartbeat_encode(2, 3, 81, 4, 4)))
        if i % 400 == 9:
            fr.append(ap.encode(m.system_time_encode(t, tb // 1000)))
        if i % 400 == 10:
            fr.append(gcs.encode(gcs.mav.heartbeat_encode(6, 8, 0, 0, 0), force_mavlink1=True))
        if i % 400 == 11:
            fr.append(gcs.encode(gcs.mav.param_request_list_encode(1, 1), force_mavlink1=True))
        if i % 400 == 12:
            fr.append(ap.encode(m.param_value_encode(b"GYRO_X", 1.0, 9, 100, 3)))
        if i % 200 == 13:
            fr.append(ap.encode(m.statustext_encode(6, b"hello world")))
        if i % 50 == 14:
            fr.append(comp.encode(comp.mav.attitude_quaternion_encode(tb // 1000, 1, 0, 0, 0, 0.1, 0.2, 0.3, [0, 0, 0, 0])))
        if i % 100 == 15:
            fr.append(ap.encode(m.raw_imu_encode(tb, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0, 0), force_mavlink1=True))
        for k, frame in enumerate(fr):
            w.write(t + k, frame, 0.0)
    w.close()
    return f.getvalue()


def _mutate(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    """One random corruption of a tlog: bit flips, truncation, junk (with or without marker bytes), …"""
    b = bytearray(data)
    kind = rng.choice(["flip", "flips", "trunc", "junk", "junk_markers", "delete", "dup", "mixed"])

    def flip() -> None:
        p = rng.randrange(len(b))
        b[p] ^= 1 << rng.randrange(8)

    def junk(markers: bool) -> None:
        p = rng.randrange(len(b))
        n = rng.randint(1, 60)
        j = bytearray(rng.randrange(256) for _ in range(n))
        if markers:
            for _ in range(rng.randint(1, 4)):
                j[rng.randrange(n)] = rng.choice([0xFD, 0xFE])
        else:
            j = bytearray(x if x not in (0xFD, 0xFE) else 0 for x in j)
        b[p:p] = j

    if kind == "flip":
        flip()
    elif kind == "flips":
        for _ in range(rng.randint(2, 40)):
            flip()
    elif kind == "trunc":
        del b[rng.randrange(len(b)) :]
    elif kind == "junk":
        junk(False)
    elif kind == "junk_markers":
        junk(True)
    elif kind == "delete":
        p = rng.randrange(len(b))
        del b[p : p + rng.randint(1, 50)]
    elif kind == "dup":
        p = rng.randrange(len(b))
        n = rng.randint(1, 80)
        b[p:p] = b[p : p + n]
    else:
        for _ in range(rng.randint(2, 10)):
            rng.choice([flip, lambda: junk(True), lambda: junk(False)])()
        if rng.random() < 0.5:
            del b[rng.randrange(len(b)) :]
    return kind, bytes(b)


@pytest.fixture(scope="session")
def make_tlog() -> Callable[..., bytes]:
    """``make_tlog(seconds=1.0, rate_hz=400, seed=0, signed=True) -> bytes``."""
    return _make_tlog


@pytest.fixture(scope="session")
def mutate_tlog() -> Callable[[bytes, random.Random], tuple[str, bytes]]:
    """``mutate_tlog(data, rng) -> (kind, corrupted bytes)``."""
    return _mutate


@contextlib.contextmanager
def _pymavlink_readers() -> Iterator[Any]:
    """pymavlink's own tlog readers, set to the dialect mavahrs decodes with.

    pymavlink picks its dialect from environment variables at import and
    switches module state when it first sees MAVLink 2; here it is pinned to
    the MAVLink 2 ``ardupilotmega`` module and restored afterwards.

    ``mmap(path, types)`` = ``mavlink_connection(path)`` + ``recv_match(type=types)``
    until ``None``; ``seq(path)`` = ``mavlogfile(path)`` + ``recv_msg()`` until
    ``None`` (BAD_DATA left out).
    """
    from pymavlink import mavutil

    saved = (mavutil.mavlink, mavutil.current_dialect)
    mp = pytest.MonkeyPatch()
    mp.setenv("MAVLINK20", "1")
    mp.setenv("MAVLINK_DIALECT", "ardupilotmega")
    mavutil.set_dialect("ardupilotmega")

    def mmap(path: str | os.PathLike[str], types: Any = None) -> list[Any]:
        conn = mavutil.mavlink_connection(os.fspath(path))
        out = []
        try:
            while True:
                m = conn.recv_match(type=types)
                if m is None:
                    return out
                out.append(m)
        finally:
            conn.close()

    def seq(path: str | os.PathLike[str]) -> list[Any]:
        conn = mavutil.mavlogfile(os.fspath(path))
        out = []
        try:
            while True:
                m = conn.recv_msg()
                if m is None:
                    return out
                if m.get_type() != "BAD_DATA":
                    out.append(m)
        finally:
            conn.close()

    try:
        yield SimpleNamespace(mmap=mmap, seq=seq)
    finally:
        mp.undo()
        mavutil.mavlink, mavutil.current_dialect = saved


@pytest.fixture
def pymavlink_ref() -> Iterator[Any]:
    """pymavlink readers (see ``_pymavlink_readers``) for one test."""
    with _pymavlink_readers() as ref:
        yield ref


@pytest.fixture(scope="module")
def pymavlink_ref_module() -> Iterator[Any]:
    """The same, for a whole module (hypothesis tests cannot use function-scoped fixtures)."""
    with _pymavlink_readers() as ref:
        yield ref


@pytest.fixture(scope="session")
def arrays_match_messages() -> Callable[[dict[str, Any], list[Any], list[str]], str | None]:
    """``check(arrays, pymavlink_messages, types) -> None | first difference``.

    Same count per type, same order, timestamps (``t_us * 1e-6 == msg._timestamp``),
    source ids and every field of ``msg.to_dict()`` (NaN equal to NaN).
    """
    import numpy as np

    def check(arrays: dict[str, Any], msgs: list[Any], types: list[str]) -> str | None:
        by: dict[str, list[Any]] = {t: [] for t in types}
        for m in msgs:
            by.setdefault(m.get_type(), []).append(m)
        for t in types:
            a, r = arrays[t], by[t]
            if len(a) != len(r):
                return f"{t}: {len(a)} rows, pymavlink {len(r)}"
            for i, (row, msg) in enumerate(zip(a, r, strict=True)):
                if (int(row["t_us"]) % 2**64) * 1e-6 != msg._timestamp:
                    return f"{t}[{i}]: t_us {int(row['t_us'])} vs _timestamp {msg._timestamp!r}"
                if (row["sysid"], row["compid"]) != (msg.get_srcSystem(), msg.get_srcComponent()):
                    return f"{t}[{i}]: source ids differ"
                for f, v in msg.to_dict().items():
                    if f == "mavpackettype":
                        continue
                    mine = row[f]
                    if isinstance(v, (str, bytes)):
                        same = bytes(mine) == (v.encode() if isinstance(v, str) else v)
                    else:
                        same = np.array_equal(np.asarray(mine), np.asarray(v), equal_nan=True)
                    if not same:
                        return f"{t}[{i}].{f}: {mine!r} vs {v!r}"
        return None

    return check
