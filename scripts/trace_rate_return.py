#!/usr/bin/env python3
"""The ESKF inside ``best`` after a ground station's slow IMU stream returns to full rate (issue 22/24).

The daemon's :class:`~mavahrs.service.pipeline.Pipeline` runs in-process on firmware_sim's ArduPilot (as
``tests/service/test_monitor_slow_imu.py::_fly``): RAW_IMU at ``--slow-hz`` until ``--fast-from`` s, when a ground
station's ``MAV_CMD_SET_MESSAGE_INTERVAL`` asks for 250 Hz and the autopilot obeys; ATTITUDE 10 Hz, GNSS 5 Hz.  Our
estimate (the filter's output row after each sample) is scored against the simulator's truth at the sample's tick.

Per flight: inclination / heading error (RMS and worst case) over the first 2 s after the rate returned, over 2–20 s
and over the whole rest of the flight.  ``--trace A:B`` prints the ESKF's state every 0.25 s over that stretch of
sim time (its attitude σ, the clocks of its last velocity fix and of its rejections) and every sample whose
correction (the attitude's change beyond the gyro's) exceeds ``--jump-deg``.

    python scripts/trace_rate_return.py --flights aggressive:3 --slow-hz 4 --trace 31:45
    python scripts/trace_rate_return.py --flights aggressive:1-4,hover:1,flips:1,magnetic:1 --slow-hz 4 10 25
    python scripts/trace_rate_return.py ... --vehicle-bound 0     (main's unbounded update on the vehicle stream)
    python scripts/trace_rate_return.py ... --set max_attitude_step_window_s=5   (an EskfSettings field: a variant)
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mavahrs.evaluation.metrics import attitude_errors_rad  # noqa: E402
from mavahrs.filters import eskf as _e  # noqa: E402
from mavahrs.filters.base import S_BIAS, S_FILTER, S_Q  # noqa: E402
from mavahrs.filters.best import _SE as _BEST_ESKF  # noqa: E402
from mavahrs.filters.best import Best, BestSettings  # noqa: E402
from mavahrs.filters.eskf import EskfSettings  # noqa: E402
from mavahrs.filters.layout import IN_DT, IN_GYRO, IN_VEL, OUT_Q  # noqa: E402
from mavahrs.protocol.codec import MavCodec, mavlink  # noqa: E402
from mavahrs.sensors.geomag import apply_declination_wxyz  # noqa: E402

N = _e.N
FULL_HZ = 250.0


def parse_flights(spec: str) -> list[tuple[str, int]]:
    """``aggressive:1-4,hover:1`` → [(scenario, seed), …]."""
    out: list[tuple[str, int]] = []
    for part in spec.split(","):
        name, _, seeds = part.partition(":")
        for rng in (seeds or "1").split("+"):
            a, _, b = rng.partition("-")
            out += [(name, s) for s in range(int(a), int(b or a) + 1)]
    return out


def parse_set(items: list[str]) -> dict[str, Any]:
    """``name=value`` pairs of EskfSettings fields (floats, ints or booleans)."""
    known = {f.name for f in fields(EskfSettings)}
    out: dict[str, Any] = {}
    for it in items:
        k, _, v = it.partition("=")
        if k not in known:
            raise SystemExit(f"--set: EskfSettings has no field {k!r}")
        out[k] = {"true": True, "false": False}.get(v.lower(), None)
        if out[k] is None:
            out[k] = float(v)
    return out


def _correction_deg(prev_q: np.ndarray, prev_b: np.ndarray, row: np.ndarray, q: np.ndarray) -> float:
    """The attitude's change over one sample beyond the gyro's propagation (the updates' correction), degrees."""
    dt = row[IN_DT]
    if not (dt > 0.0 and dt < 1.0):
        return 0.0
    w = (row[IN_GYRO : IN_GYRO + 3] - prev_b) * dt
    a = float(np.linalg.norm(w))
    dq = np.array([math.cos(a / 2), *(w / a * math.sin(a / 2))]) if a > 0 else np.array([1.0, 0, 0, 0])
    p0, p1, p2, p3 = prev_q
    d0, d1, d2, d3 = dq
    qp = np.array([p0 * d0 - p1 * d1 - p2 * d2 - p3 * d3, p0 * d1 + p1 * d0 + p2 * d3 - p3 * d2,
                   p0 * d2 - p1 * d3 + p2 * d0 + p3 * d1, p0 * d3 + p1 * d2 - p2 * d1 + p3 * d0])  # fmt: skip
    c = abs(float(np.dot(qp, q)))
    return math.degrees(2.0 * math.acos(min(c, 1.0)))


def fly(scenario: str, seed: int, slow_hz: float, fast_from_s: float, seconds: float,
        eskf_set: dict[str, Any] | None = None, trace: bool = False,
        inspect: Any = None) -> dict[str, Any]:  # fmt: skip
    """One flight; returns the per-sample arrays (and, with ``trace``, the ESKF's internals per sample).
    ``inspect(t_s, filter, state_before, row)`` is called after every sample (a debugging aid)."""
    import firmware_sim as fs
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    ss = fs.SimSettings(scenario=scenario, seed=seed)
    ep = fs.Endpoint(fs.Simulation(ss), fs.EndpointSettings(preset="none", block_ticks=400, streams_hz=(
        ("HEARTBEAT", 1.0), ("RAW_IMU", slow_hz), ("ATTITUDE", 10.0), ("GLOBAL_POSITION_INT", 5.0),
        ("SYSTEM_TIME", 1.0))))  # fmt: skip
    bs = BestSettings()
    if eskf_set:
        bs = replace(bs, eskf=replace(bs.eskf, **eskf_set))
    filt = Best(bs)
    pipe = Pipeline(PipelineSettings(), filter=filt)
    rx, gcs = MavCodec(255, 190), MavCodec(255, 190)
    tick_t: list[int] = []
    tick_q: list[list[float]] = []
    t_s: list[float] = []
    q_out: list[np.ndarray] = []
    tr: list[tuple[float, ...]] = []
    prev: list[np.ndarray] = []
    before: list[np.ndarray] = []

    def hook(name: str, t: int, row: np.ndarray, out: np.ndarray) -> None:
        t_s.append(t * 1e-6)
        q = out[OUT_Q : OUT_Q + 4]
        d = pipe.declination.declination_rad  # true north, as the pipeline publishes it
        q_out.append(np.array(apply_declination_wxyz(*q.tolist(), d) if d else q))
        if inspect is not None:
            if before:
                inspect(t * 1e-6, filt, before[0], row)
            before[:] = [filt._state.copy()]
        if not trace:
            return
        st = filt._state
        e = st[_BEST_ESKF : _BEST_ESKF + S_FILTER + _e._N_STATE]
        k = S_FILTER
        kp = k + _e._P
        clk = e[k + _e._CLK]
        jump = _correction_deg(prev[0], prev[1], row, e[S_Q : S_Q + 4]) if prev else 0.0
        vfix = 1.0 if math.isfinite(row[IN_VEL]) else 0.0
        tr.append((
            t * 1e-6, clk, math.degrees(math.sqrt(max(e[kp], 0) + max(e[kp + N + 1], 0))),
            math.degrees(math.sqrt(max(e[kp + 2 * N + 2], 0))),
            clk - e[k + _e._LAST_FIX] if e[k + _e._LAST_FIX] >= 0 else -1.0, e[k + _e._VREJ],
            clk - e[k + _e._GREJ] if e[k + _e._GREJ] >= 0 else -1.0, jump, vfix,
            math.degrees(float(np.linalg.norm(e[S_BIAS : S_BIAS + 3]))),
        ))  # fmt: skip
        prev[:] = [e[S_Q : S_Q + 4].copy(), e[S_BIAS : S_BIAS + 3].copy()]

    pipe.sample_hook = hook
    asked = False
    for kk in range(int(seconds * ss.loop_rate_hz)):
        for t_us, frame in ep.step():
            for msg in rx.receive_datagram(frame):
                pipe.handle(msg, t_us)
        w = ep._block
        tick_t.append(ep.now_us)
        tick_q.append(w.true_q[ep._k - 1 - w.k0])
        if kk % 20 == 0:
            pipe.tick(ep.now_us)
        if not asked and ep.now_us >= fast_from_s * 1e6:
            asked = True
            ask = gcs.mav.command_long_encode(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                              mavlink.MAVLINK_MSG_ID_RAW_IMU, int(1e6 / FULL_HZ), 0, 0, 0, 0, 0)  # fmt: skip
            ep.receive(gcs.encode(ask), datagram=True)
    ts = np.asarray(t_s)
    tt = np.asarray(tick_t) * 1e-6
    idx = np.clip(np.searchsorted(tt, ts + 1e-7, side="right") - 1, 0, len(tt) - 1)
    q_true = np.asarray(tick_q)[idx]
    _, head, incl = attitude_errors_rad(np.asarray(q_out), q_true)
    return {"t": ts, "incl_deg": np.degrees(incl), "head_deg": np.degrees(head), "trace": np.asarray(tr)}


def rate_returned_s(t: np.ndarray, after_s: float) -> float:
    """The first sample after ``after_s`` whose interval is within 1.25 / 50 Hz (the rate is back)."""
    d = np.diff(t)
    ok = np.nonzero((t[1:] >= after_s) & (d <= 1.25 / 50.0))[0]
    return float(t[ok[0] + 1]) if ok.size else float("nan")


def summarise(r: dict[str, Any], t_ret: float) -> dict[str, float]:
    t, inc, hd = r["t"], r["incl_deg"], r["head_deg"]
    res: dict[str, float] = {"t_return_s": t_ret}
    for name, a, b in (("0-2", 0.0, 2.0), ("2-20", 2.0, 20.0), ("after", 0.0, 1e9)):
        m = (t >= t_ret + a) & (t < t_ret + b)
        for key, e in (("incl", inc), ("head", hd)):
            v = e[m]
            v = v[np.isfinite(v)]
            res[f"{key}_rms_{name}"] = float(np.sqrt(np.mean(v**2))) if v.size else float("nan")
            res[f"{key}_max_{name}"] = float(np.max(v)) if v.size else float("nan")
    return res


def print_trace(r: dict[str, Any], a: float, b: float, jump_deg: float) -> None:
    tr = r["trace"]
    inc, hd = r["incl_deg"], r["head_deg"]
    print("  t s     incl°   head°   tiltσ°  headσ°  since fix s  vrej s  rej-streak s  corr°  |b| °/s")
    nxt = a
    for i in range(len(tr)):
        t = tr[i, 0]
        if t < a or t > b:
            continue
        if t >= nxt or tr[i, 7] >= jump_deg:
            mark = " *" if tr[i, 7] >= jump_deg else ""
            print(f"  {t:6.2f}  {inc[i]:6.1f}  {hd[i]:6.1f}  {tr[i, 2]:6.1f}  {tr[i, 3]:6.1f}  {tr[i, 4]:10.2f}  "
                  f"{tr[i, 5]:6.2f}  {tr[i, 6]:11.2f}  {tr[i, 7]:6.2f}  {tr[i, 9]:6.2f}"
                  f"{' fix' if tr[i, 8] else ''}{mark}")  # fmt: skip
            if t >= nxt:
                nxt = math.floor(t / 0.25) * 0.25 + 0.25


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--flights", default="aggressive:3", help="scenario:seeds, e.g. aggressive:1-4,hover:1")
    ap.add_argument("--slow-hz", type=float, nargs="+", default=[4.0], help="the ground station's RAW_IMU rate(s)")
    ap.add_argument("--fast-from", type=float, default=30.0, help="s: when the 250 Hz request is sent")
    ap.add_argument("--duration", type=float, default=60.0, help="s of flight")
    ap.add_argument("--set", action="append", default=[], help="EskfSettings field=value (a variant)")
    ap.add_argument("--vehicle-bound", type=float, default=None,
                    help="rad: best.VEHICLE_MAX_ATTITUDE_STEP_RAD for this run (0: main's unbounded update)")
    ap.add_argument("--vehicle-window", type=float, default=None,
                    help="s: best.VEHICLE_MAX_ATTITUDE_STEP_WINDOW_S with --vehicle-bound (0: at every update)")
    ap.add_argument("--trace", default="", help="A:B: print the ESKF's state over sim time A–B s")
    ap.add_argument("--jump-deg", type=float, default=5.0, help="print every sample correcting more than this")
    ap.add_argument("--json", default="", help="write the per-flight summaries here")
    a = ap.parse_args()
    eskf_set = parse_set(a.set)
    import mavahrs.filters.best as best_mod

    if a.vehicle_bound is not None:
        best_mod.VEHICLE_MAX_ATTITUDE_STEP_RAD = a.vehicle_bound
        eskf_set["vehicle_bound"] = a.vehicle_bound  # (for the JSON and the header only)
    if a.vehicle_window is not None:
        best_mod.VEHICLE_MAX_ATTITUDE_STEP_WINDOW_S = a.vehicle_window
        eskf_set["vehicle_window"] = a.vehicle_window
    rows = []
    print(f"variant: {eskf_set or 'this tree as it is'}")
    print("flight, slow Hz   return s  | incl / head RMS 0–2 s | 2–20 s | after: RMS; worst")
    for hz in a.slow_hz:
        for sc, seed in parse_flights(a.flights):
            t0 = time.time()
            r = fly(sc, seed, hz, a.fast_from, a.duration, {k: v for k, v in eskf_set.items() if not k.startswith("vehicle_")},
                    trace=bool(a.trace))
            s = summarise(r, rate_returned_s(r["t"], a.fast_from))
            s.update({"scenario": sc, "seed": seed, "slow_hz": hz})
            rows.append(s)
            print(f"{sc} {seed}, {hz:g} Hz  {s['t_return_s']:6.2f}  | {s['incl_rms_0-2']:5.1f} / {s['head_rms_0-2']:5.1f} "
                  f"| {s['incl_rms_2-20']:5.1f} / {s['head_rms_2-20']:5.1f} | {s['incl_rms_after']:5.1f} / "
                  f"{s['head_rms_after']:5.1f}; {s['incl_max_after']:5.1f} / {s['head_max_after']:5.1f}"
                  f"   ({time.time() - t0:.0f} s)", flush=True)  # fmt: skip
            if a.trace:
                lo, _, hi = a.trace.partition(":")
                print_trace(r, float(lo), float(hi), a.jump_deg)
    if a.json:
        Path(a.json).write_text(json.dumps({"variant": eskf_set, "flights": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
