r"""Compile every filter kernel ahead of time (``mavahrs warm-up``), so nothing compiles in the air.

numba compiles the kernels on their first use and caches the machine code on
disk (the user's cache folder ``~/.cache/mavahrs/kernels``, or
``NUMBA_CACHE_DIR`` when set, e.g. the systemd unit's ``/var/cache/mavahrs``);
a full cold compile measured 40 s to 6 min on a 2-core PC (idle to heavily
loaded) and takes longer on a Raspberry Pi.  :func:`warm_up` runs every path a command
takes through compiled code once, on a short synthetic recording:

* the daemon's path for each filter (``mavahrs run``, ``demo``): the
  pipeline's per-sample step and the fast lane that answers a RAW_IMU
  datagram;
* the bulk path (``replay``, ``evaluate``, ``tune``, ``plot``,
  ``calibrate-mag``, ``audit``): the tlog decoder, the batch loops of every
  filter, the CSV writer, and the pipeline engine; the sample chain's loops
  for one and for two IMU instances and for PX4's HIGHRES_IMU, and the
  DataFlash reader's record walk (a first replay of a shared tlog, .BIN or
  PX4 tlog after a warm-up compiled these, 1–2 s with the compile notice);
* the gain sweeps (``evaluate --study``): the parallel many-filter loop.

With a warm cache each step only loads the cached code (about a second in
all).  The recording is written to a temporary directory and removed.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

__all__ = ["WarmUpStep", "warm_up", "warm_up_part", "synthetic_frames", "STEPS", "PARTS"]

#: what :func:`warm_up` compiles, in order (names shown by ``mavahrs warm-up``)
STEPS: tuple[str, ...] = ("daemon", "replay and evaluation", "gain sweeps")

_RATE_HZ = 200
_SECONDS = 2


@dataclass(frozen=True)
class WarmUpStep:
    """One finished step: its name (one of :data:`STEPS`) and how long it took, s."""

    name: str
    seconds: float


def synthetic_frames(seconds: float = _SECONDS, autopilot: str = "ardupilot") -> list[tuple[int, bytes]]:
    """A short recording at rest: (time µs, MAVLink 2 frame) pairs.

    A HEARTBEAT once a second, the IMU at 200 Hz (level, a slight gyro bias,
    the magnetometer pointing north-down), GLOBAL_POSITION_INT and ATTITUDE
    at 10 Hz: every message the daemon and replay read.  ``autopilot``
    ``"ardupilot"``: RAW_IMU; ``"ardupilot2"``: RAW_IMU and SCALED_IMU2 (two
    IMU instances, the selection's path); ``"px4"``: HIGHRES_IMU (SI floats) and SCALED_IMU at 50 Hz
    (the same IMU without EKF2's gyro bias: the autopilot-bias step) and PX4's compass calibration as PARAM_VALUE
    (the magnetometer-bias step).
    """
    from mavahrs.protocol.codec import MavCodec, mavlink

    ap = MavCodec(1, 1)
    px4 = autopilot == "px4"
    kind = mavlink.MAV_AUTOPILOT_PX4 if px4 else mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    t0 = 1_000_000
    out: list[tuple[int, bytes]] = []
    for k in range(int(seconds * _RATE_HZ)):
        t = t0 + k * 1_000_000 // _RATE_HZ
        if k % _RATE_HZ == 0:
            hb = ap.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, kind, 0, 0, 4)
            out.append((t, ap.encode(hb)))
        if px4 and k == 0:  # PX4's compass calibration (the identity), as PARAM_VALUE: the mag-bias step's kernels
            out += [(t, ap.encode(ap.mav.param_value_encode(n.encode(), v, ty, 0, 0))) for n, v, ty in _px4_cal_params()]
        if px4:  # m/s², rad/s, gauss; fields_updated: gyro, accel and magnetometer new
            imu = ap.mav.highres_imu_encode(t, 0.0, 0.0, -9.81, 0.001, -0.001, 0.0, 0.2, 0.03, 0.45,
                                            1013.0, 0.0, 0.0, 35.0, 0x1FF)  # fmt: skip
        else:
            imu = ap.mav.raw_imu_encode(t, 0, 0, -1000, 1, -1, 0, 200, 30, 450, 0, 3500)
        out.append((t, ap.encode(imu)))
        if px4 and k % 4 == 0:  # mG, mrad/s, mgauss; 1 mrad/s of "EKF2 bias" on x
            twin = ap.mav.scaled_imu_encode(t // 1000, 0, 0, -1000, 2, -1, 0, 200, 30, 450, 3500)
            out.append((t + 100, ap.encode(twin)))
        if autopilot == "ardupilot2":
            imu2 = ap.mav.scaled_imu2_encode(t // 1000, 0, 0, -1000, 1, -1, 0, 200, 30, 450, 3500)
            out.append((t, ap.encode(imu2)))
        if k % (_RATE_HZ // 10) == 0:
            gpi = ap.mav.global_position_int_encode(t // 1000, 473_977_000, 85_455_000, 500_000, 10_000, 0, 0, 0, 0)
            att = ap.mav.attitude_encode(t // 1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            out.append((t, ap.encode(gpi)))
            out.append((t, ap.encode(att)))
    return out


def _px4_cal_params() -> list[tuple[str, float, int]]:
    """(name, PARAM_VALUE float, MAV_PARAM_TYPE) of one internal compass calibrated to the identity (PX4 SIH's)."""
    import struct

    def i32(v: int) -> float:  # PX4 sends an integer's bytes in the float
        return float(struct.unpack("<f", struct.pack("<i", v))[0])

    out = [("CAL_MAG0_ID", i32(197388), 6), ("CAL_MAG0_ROT", i32(-1), 6), ("CAL_MAG_COMP_TYP", i32(0), 6),
           ("SENS_BOARD_ROT", i32(0), 6)]  # fmt: skip
    out += [(f"CAL_MAG{k}_ID", i32(0), 6) for k in (1, 2, 3)]
    out += [(f"SENS_BOARD_{a}_OFF", 0.0, 9) for a in "XYZ"]
    out += [(f"CAL_MAG0_{a}{f}", 1.0 if f == "SCALE" else 0.0, 9) for a in "XYZ" for f in ("OFF", "SCALE", "ODIAG")]
    return out


def _every_filter() -> tuple[str, ...]:
    from mavahrs.filters import ALIASES, NAMES

    return (*NAMES, *ALIASES)


def _daemon_path(names: tuple[str, ...] | None = None, px4: bool = True) -> None:
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.service.fastlane import FastLane
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    frames = synthetic_frames(1.0)
    for name in _every_filter() if names is None else names:
        pipeline = Pipeline(PipelineSettings(filter_name=name))
        lane = FastLane(pipeline)
        rx = MavCodec()
        for t_us, frame in frames:
            if lane.usable:
                lane.answer(frame)
            for msg in rx.receive_datagram(frame):
                pipeline.handle(msg, t_us)
            lane.refresh()
    if not px4:
        return
    # PX4: HIGHRES_IMU with SCALED_IMU, the autopilot-bias step's per-message kernels
    pipeline = Pipeline(PipelineSettings(filter_name="best"))
    rx = MavCodec()
    for t_us, frame in synthetic_frames(autopilot="px4"):
        for msg in rx.receive_datagram(frame):
            pipeline.handle(msg, t_us)


def _replay_path(tmp: Path, names: tuple[str, ...] | None = None, readers: bool = True, dataflash: bool = True) -> None:
    from mavahrs.protocol.tlog import tlog_record
    from mavahrs.replay import ReplaySettings, replay

    tlog = tmp / "warm-up.tlog"
    tlog.write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames()))
    every = _every_filter() if names is None else names
    replay(tlog, ReplaySettings(filters=every, engine="fast"), csv_path=tmp / "warm-up.csv")
    replay(tlog, ReplaySettings(filters=every, engine="pipeline"), csv_path=tmp / "warm-up-pipeline.csv")
    # the readers' other compiled steps: two IMU instances (the selection), PX4's HIGHRES_IMU (float scaling)
    for autopilot in ("ardupilot2", "px4") if readers else ():
        other = tmp / f"warm-up-{autopilot}.tlog"
        other.write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames(autopilot=autopilot)))
        replay(other, ReplaySettings(filters=("best",), engine="fast"))
    if dataflash:
        _dataflash_scan()


def _dataflash_scan() -> None:
    """A DataFlash .BIN's record walk (its samples then take the replay's steps); a ULog compiles nothing of its own."""
    import numpy as np

    from mavahrs.logs.dataflash import scan

    scan(np.zeros(8, np.uint8))  # a writable array, as np.fromfile gives (bytes: a read-only one, another signature)


def _sweeps(names: tuple[str, ...] | None = None) -> None:
    import numpy as np

    from mavahrs.filters import NAMES, create
    from mavahrs.filters.base import make_inputs, run_many

    n = 50
    gyro = np.zeros((n, 3))
    accel = np.tile([0.0, 0.0, -9.80665], (n, 1))
    mag = np.tile([20.0, 0.0, 40.0], (n, 1))
    inputs = make_inputs(gyro, accel, mag, dt_s=np.full(n, 1.0 / _RATE_HZ))
    for name in NAMES if names is None else names:
        run_many([create(name), create(name)], inputs)


#: The parts of a warm-up that ``mavahrs warm-up`` compiles in processes of their own (``--jobs``), before
#: the whole warm-up runs in its own process and finds them cached: the ESKF's filters (``eskf``, ``best``:
#: one large kernel, about half of a cold compile, measured in docs/reliability.md) and everything else.
PARTS: tuple[str, ...] = ("eskf", "others")
_ESKF_FILTERS = ("eskf", "best")


def warm_up_part(part: str) -> float:
    """Compile (or load) one of :data:`PARTS`' kernels in this process; returns the seconds it took.

    ``"eskf"``: the ESKF's per-sample kernels first (nothing else needed to compile them), then the daemon's,
    replay's and the readers' paths with those filters and their gain sweeps; ``"others"``: the same paths
    with every other filter, and the DataFlash reader.  Shared kernels (the sample chain, the decoder) are
    compiled by whichever part gets there first (the other loads them, or compiles them too when both get
    there at once: several processes may add to one cache, ``mavahrs.filters.jit``).  Together they compile
    what :func:`warm_up` does; :func:`warm_up` after them compiles only what neither did.
    """
    from mavahrs.filters import create

    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="mavahrs-warm-up-") as tmp:
        if part == "eskf":
            for name in _ESKF_FILTERS:
                create(name).warm_up()
            _daemon_path(_ESKF_FILTERS, px4=True)
            _replay_path(Path(tmp), _ESKF_FILTERS, readers=True, dataflash=False)
            _sweeps(("eskf",))
        elif part == "others":
            others = tuple(n for n in _every_filter() if n not in _ESKF_FILTERS)
            _daemon_path(others, px4=False)
            _replay_path(Path(tmp), others, readers=False, dataflash=True)
            _sweeps(others)
        else:
            raise ValueError(f"unknown warm-up part {part!r}; one of {', '.join(PARTS)}")
    return time.monotonic() - t0


def warm_up(done: Callable[[WarmUpStep], None] = lambda step: None) -> list[WarmUpStep]:
    """Compile (or load from the disk cache) every kernel a command can use; ``done`` is told after each step."""
    steps: list[WarmUpStep] = []
    with tempfile.TemporaryDirectory(prefix="mavahrs-warm-up-") as tmp:
        for name, work in zip(STEPS, (_daemon_path, lambda: _replay_path(Path(tmp)), _sweeps), strict=True):
            t0 = time.monotonic()
            work()
            step = WarmUpStep(name, time.monotonic() - t0)
            steps.append(step)
            done(step)
    return steps
