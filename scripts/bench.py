#!/usr/bin/env python3
r"""mavahrs performance targets (issue 6), measured in one run on the same generated 400 Hz data.

One run generates (once; cached in ``--workdir``) a one-hour 400 Hz RAW_IMU
tlog with ``firmware_sim --fast --ideal`` (hover, one IMU with compass,
SIMSTATE truth at 10 Hz) and measures, on that file and the filter inputs
decoded from it:

1. **Replay** — whole process, wall clock: ``mavahrs replay FILE --filter
   madgwick --csv OUT`` on the full hour, against a plain pymavlink
   (``mavlink_connection`` + ``recv_match``) + imufusion per-sample loop and a
   pymavlink + ``ahrs`` Madgwick loop writing a CSV of time, quaternion and
   Euler angles (mavahrs's CSV has 18 columns: the references do less
   formatting).  The references run on the first ``--prefix`` seconds of the
   same file; their time is extrapolated to the whole file as start-up +
   loop time × (samples / prefix samples).  mavahrs's bytecode is written
   first (``compileall``), as ``pip install`` does: the references are
   installed packages with theirs.
2. **Batch filters** — µs per sample (thread CPU time, the fastest of many
   20 000-sample windows: the machine is shared) of every filter, MARG and
   IMU, against imufusion per sample from Python and VQF's ``updateBatch``.
3. **Gain sweep** — 1000 Madgwick β values over the first 10 minutes
   (240 million filter updates) with ``run_many`` (all cores), wall clock;
   each β is scored against the truth.
4. **Live** — ``scripts/bench_live.py`` for ``best`` and every filter:
   processing latency, round trip over a bare pymavlink echo, CPU per message
   (the sending script on one CPU, both servers on the others: see
   bench_live.py on CPU placement);
   twice per filter where this process may use real-time scheduling (root or
   CAP_SYS_NICE): both servers under normal scheduling (reported, not judged),
   then both under SCHED_FIFO priority ``--live-realtime`` (default 20; judged:
   the deployment ``contrib/mavahrs.service`` describes).  Without the
   permission, or with ``--live-realtime 0``, the normal run is judged.
5. **Start-up** — ``mavahrs --help`` in a subprocess, and a fresh process's
   first filter call with a warm on-disk cache (nothing may be compiled).

It prints a summary table (target, measured, PASS/FAIL) and exits 1 if a
target is missed (2 on a setup error).  ``--quick``: two minutes of data,
100 β values, the live check for ``best`` only — a smoke test whose sweep
figure is projected linearly and whose replay ratio is not judged (start-up
dominates a short file).  Needs the ``bench`` extra (imufusion, vqf, ahrs).

    python3 scripts/bench.py                 # full run, ~15 min (+6 min to generate the hour once)
    python3 scripts/bench.py --quick         # ~3 min
    python3 scripts/bench.py --json bench.json --skip live
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
os.environ.setdefault("MAVLINK20", "1")  # pymavlink: the dialect mavahrs decodes with
os.environ.setdefault("MAVLINK_DIALECT", "ardupilotmega")

G_M_S2 = 9.80665
RATE_HZ = 400
SECTIONS = ("replay", "batch", "sweep", "live", "startup")

# targets (issue 6; live ones from issue 4 via bench_live.TARGETS)
REPLAY_RATIO = 20.0
BATCH_MSPS = 5.0
BATCH_VQF_RATIO = 4.0
SWEEP_POINTS = 1000
SWEEP_S = 600.0
SWEEP_LIMIT_S = 60.0
HELP_LIMIT_S = 0.5


@dataclass
class Row:
    """One line of the summary table."""

    section: str
    target: str
    measured: str
    passed: bool | None  # None: information, not judged

    @property
    def verdict(self) -> str:
        return "-" if self.passed is None else ("PASS" if self.passed else "FAIL")


def say(text: str = "") -> None:
    print(text, flush=True)


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def timed_process(cmd: list[str], *, stdout: Any = subprocess.PIPE) -> tuple[float, float, str]:
    """Run ``cmd``; return (wall s, CPU s of the child (user + system), stdout)."""
    _child_cpu_delta()  # children reaped before this one (live section, generation) are not ours
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=_env(), stdout=stdout, stderr=subprocess.PIPE, text=True)
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    cpu = _child_cpu_delta()  # user + system of the child just reaped
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:4])} … exited with {proc.returncode}: {err[-1500:]}")
    return wall, cpu, out or ""


_LAST_CHILD_CPU = [0.0]


def _child_cpu_delta() -> float:
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = ru.ru_utime + ru.ru_stime
    delta = total - _LAST_CHILD_CPU[0]
    _LAST_CHILD_CPU[0] = total
    return delta


# --------------------------------------------------------------------------- data


def ensure_tlog(workdir: Path, seconds: int, seed: int) -> Path:
    """The generated 400 Hz tlog (firmware_sim --fast --ideal), made once per (duration, seed)."""
    path = workdir / f"hover_{seconds}s_seed{seed}_raw_imu400.tlog"
    if path.is_file():
        return path
    part = path.with_suffix(".part")
    cmd = [sys.executable, "-m", "firmware_sim", "--tlog", str(part), "--fast", "--ideal", "--scenario", "hover",
           "--duration", str(seconds), "--seed", str(seed), "--imus", "1", "--preset", "none",
           "--stream", "RAW_IMU=400", "--stream", "HEARTBEAT=1", "--stream", "SIMSTATE=10", "-q"]  # fmt: skip
    say(f"generating {path.name} ({seconds} s of 400 Hz RAW_IMU): {' '.join(cmd[1:])}")
    t0 = time.perf_counter()
    _child_cpu_delta()
    subprocess.run(cmd, env=_env(), check=True)
    _child_cpu_delta()
    part.rename(path)
    say(f"  generated in {time.perf_counter() - t0:.0f} s")
    return path


def prefix_tlog(src: Path, seconds: float) -> Path:
    """The first ``seconds`` of a tlog (cut at a record boundary)."""
    import numpy as np

    from mavahrs.protocol.fast_tlog import scan_tlog

    dst = src.with_name(f"{src.stem}_first{int(seconds)}s.tlog")
    if dst.is_file() and dst.stat().st_mtime >= src.stat().st_mtime:
        return dst
    data = np.fromfile(src, np.uint8)
    scan = scan_tlog(data, None)
    t = scan.t_us.astype(np.int64)
    j = int(np.searchsorted(t, t[0] + int(seconds * 1e6)))
    cut = int(scan.offset[j]) - 8 if j < len(scan) else data.shape[0]
    data[:cut].tofile(dst)
    return dst


# --------------------------------------------------------------------------- reference loops (subprocess)


def reference_loop(kind: str, tlog: str, csv_path: str) -> int:
    """pymavlink + imufusion / ahrs Madgwick, sample by sample, writing a CSV; JSON timing on stdout."""
    t_start = time.perf_counter()
    c_start = time.process_time()
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(tlog)
    if kind == "imufusion":
        import imufusion
        import numpy as np

        ahrs = imufusion.Ahrs()
        settings = imufusion.AhrsSettings()
        settings.convention = imufusion.CONVENTION_NED  # 1.3.3 ignores AhrsSettings(convention=...)
        settings.sample_rate = RATE_HZ
        ahrs.set_settings(settings)
        ahrs.set_sample_period(1.0 / RATE_HZ)
        to_euler = imufusion.quaternion_to_euler
    elif kind == "ahrs":
        import numpy as np
        from ahrs.filters import Madgwick

        mad = Madgwick(frequency=float(RATE_HZ))
        q = np.array([1.0, 0.0, 0.0, 0.0])
    else:
        raise ValueError(kind)
    deg = 180.0 / math.pi
    n = 0
    t_first = c_first = 0.0
    last_us = None
    with open(csv_path, "w") as f:
        f.write("time_s,qw,qx,qy,qz,roll_deg,pitch_deg,yaw_deg\n")
        while True:
            msg = conn.recv_match(type="RAW_IMU")
            if msg is None:
                break
            if n == 0:
                t_first, c_first = time.perf_counter(), time.process_time()
            t_us = msg.time_usec
            if kind == "imufusion":
                # ArduPilot RAW_IMU: mG, mrad/s, mGauss; FRD body, NED earth (specific force: level z = −1 g)
                gyro = np.array([msg.xgyro, msg.ygyro, msg.zgyro]) * (1e-3 * deg)
                accel = np.array([msg.xacc, msg.yacc, msg.zacc]) * 1e-3
                mag = np.array([msg.xmag, msg.ymag, msg.zmag]) * 0.1
                ahrs.update(gyro, accel, mag)
                w, x, y, z = ahrs.get_quaternion()
                roll, pitch, yaw = to_euler(np.array([w, x, y, z]))
            else:
                # ahrs: FLU body / NWU earth, accelerometer up-positive, magnetometer nT
                dt = 1.0 / RATE_HZ if last_us is None or t_us <= last_us else (t_us - last_us) * 1e-6
                gyro = np.array([msg.xgyro, -msg.ygyro, -msg.zgyro]) * 1e-3
                if not gyro.any():
                    gyro[2] = 1e-12  # ahrs skips the whole update (accelerometer too) on an exactly zero gyro
                accel = np.array([msg.xacc, -msg.yacc, -msg.zacc]) * (1e-3 * G_M_S2)
                mag = np.array([msg.xmag, -msg.ymag, -msg.zmag]) * 100.0
                q = mad.updateMARG(q, gyr=gyro, acc=accel, mag=mag, dt=dt)
                w, x, y, z = q[0], q[1], -q[2], -q[3]  # FLU→NWU rotation to FRD→NED
                roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)) * deg
                pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x)))) * deg
                yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)) * deg
            last_us = t_us
            f.write(f"{t_us * 1e-6:.6f},{w:.7f},{x:.7f},{y:.7f},{z:.7f},{roll:.3f},{pitch:.3f},{yaw:.3f}\n")
            n += 1
    print(json.dumps({
        "samples": n,
        "startup_wall_s": t_first - t_start, "loop_wall_s": time.perf_counter() - t_first,
        "startup_cpu_s": c_first - c_start, "loop_cpu_s": time.process_time() - c_first,
    }))  # fmt: skip
    return 0


# --------------------------------------------------------------------------- 1. replay


def bench_replay(full: Path, prefix: Path, workdir: Path, quick: bool, repeats: int) -> tuple[list[Row], dict[str, Any]]:
    import re

    rows: list[Row] = []
    res: dict[str, Any] = {"file": full.name, "prefix_file": prefix.name}
    out_csv = workdir / "replay_mavahrs.csv"
    cmd = [sys.executable, "-m", "mavahrs", "replay", str(full), "--filter", "madgwick", "--csv", str(out_csv),
           "--no-progress"]  # fmt: skip
    # the package's bytecode, as `pip install` writes it (a source checkout run with
    # PYTHONDONTWRITEBYTECODE=1 would otherwise recompile every module in every run)
    res["bytecode_compiled"] = _byte_compile_mavahrs()
    # warm-up on the prefix: loads (or, after an edit, compiles) the cached kernels, fills the page cache
    timed_process([*cmd[:4], str(prefix), *cmd[5:]])
    runs = []
    samples = 0
    for _ in range(repeats):
        wall, cpu, out = timed_process(cmd)
        m = re.search(r"(\d+) IMU samples", out)
        samples = int(m.group(1)) if m else 0
        runs.append((wall, cpu))
        say(f"  mavahrs replay: {samples} samples, wall {wall:.2f} s, CPU {cpu:.2f} s")
    wall, cpu = min(runs)
    res["mavahrs"] = {"command": " ".join(["mavahrs", *cmd[3:]]), "samples": samples, "runs": runs,
                      "wall_s": wall, "cpu_s": cpu}  # fmt: skip
    mav_rate = samples / wall
    for kind in ("imufusion", "ahrs"):
        ref_csv = workdir / f"replay_{kind}.csv"
        rwall, rcpu, out = timed_process([sys.executable, __file__, "--reference-loop", kind, str(prefix), str(ref_csv)])
        r = json.loads(out.strip().splitlines()[-1])
        k = samples / r["samples"]
        # the whole file: this process's start-up plus the loop scaled by the sample count
        est_wall = rwall + r["loop_wall_s"] * (k - 1.0)
        est_cpu = rcpu + r["loop_cpu_s"] * (k - 1.0)
        say(f"  pymavlink + {kind}: {r['samples']} samples (first {prefix.stem.rsplit('first', 1)[-1]}), wall "
            f"{rwall:.1f} s, CPU {rcpu:.1f} s, {r['loop_wall_s'] / r['samples'] * 1e6:.0f} µs/sample in the loop; "
            f"whole file (×{k:.1f}) ≈ {est_wall:.0f} s wall, {est_cpu:.0f} s CPU")  # fmt: skip
        res[kind] = {**r, "wall_s": rwall, "cpu_s": rcpu, "scale": k, "est_full_wall_s": est_wall,
                     "est_full_cpu_s": est_cpu}  # fmt: skip
        ratio = mav_rate / (samples / est_wall)
        ratio_cpu = est_cpu / cpu
        res[kind]["ratio_wall"] = ratio
        res[kind]["ratio_cpu"] = ratio_cpu
        judged = kind == "imufusion" and not quick
        rows.append(Row(
            "replay",
            f"tlog→CSV vs pymavlink+{kind}" + (f" ≥ {REPLAY_RATIO:g}×" if kind == "imufusion" else ""),
            f"{ratio:.1f}× wall ({mav_rate / 1e3:.0f} k vs {samples / est_wall / 1e3:.1f} k samples/s), "
            f"{ratio_cpu:.1f}× CPU",
            (ratio >= REPLAY_RATIO) if judged else None,
        ))  # fmt: skip
    res["sanity"] = _compare_csvs(out_csv, [workdir / f"replay_{k}.csv" for k in ("imufusion", "ahrs")])
    for name, d in res["sanity"].items():
        say(f"  attitude check over the prefix, mavahrs vs {name}: mean |Δroll| {d['roll_deg']:.2f}°, "
            f"|Δpitch| {d['pitch_deg']:.2f}°")
    return rows, res


def _byte_compile_mavahrs() -> bool:
    """Write the bytecode of the mavahrs package being measured (``compileall``, quietly); False if it cannot."""
    import compileall

    import mavahrs

    try:
        return bool(compileall.compile_dir(str(Path(mavahrs.__file__).parent), quiet=2))
    except OSError:
        return False


def _compare_csvs(mine: Path, others: list[Path]) -> dict[str, dict[str, float]]:
    """Mean |Δroll|, |Δpitch| between mavahrs's CSV and each reference over the reference's rows."""
    import numpy as np

    out: dict[str, dict[str, float]] = {}
    for p in others:
        ref = np.loadtxt(p, delimiter=",", skiprows=1, usecols=(0, 5, 6))
        m = np.loadtxt(mine, delimiter=",", skiprows=1, usecols=(0, 5, 6), max_rows=ref.shape[0])
        k = min(len(ref), len(m))
        skip = min(k // 10, 4000)  # after convergence (10 s)
        d = np.abs(ref[skip:k, 1:] - m[skip:k, 1:])
        out[p.stem.replace("replay_", "")] = {"roll_deg": float(np.nanmean(d[:, 0])),
                                              "pitch_deg": float(np.nanmean(d[:, 1]))}  # fmt: skip
    return out


# --------------------------------------------------------------------------- 2. batch filters


def _min_window(run: Callable[[int, int], None], n: int, window: int, budget_s: float, min_windows: int = 3) -> float:
    """Fastest thread-CPU time per sample over consecutive windows of the data (seconds)."""
    best = math.inf
    a = 0
    k = 0
    end = time.perf_counter() + budget_s
    while k < min_windows or time.perf_counter() < end:
        if a + window > n:
            a = 0
        t0 = time.thread_time()
        run(a, a + window)
        best = min(best, (time.thread_time() - t0) / window)
        a += window
        k += 1
    return best


def _report_settings() -> Any:
    """MadgwickSettings reduced to the 2010 report's filter: β, ζ, distortion compensation only."""
    from mavahrs.filters.gains import GainScheduleSettings
    from mavahrs.filters.madgwick import MadgwickSettings
    from mavahrs.filters.rest import RestBiasSettings

    off = GainScheduleSettings(startup_gain_factor=1.0, startup_s=0.0, accel_norm_tolerance=0.0, recovery_s=0.0,
                               rejection_timeout_s=0.0, mag_norm_tolerance=0.0, mag_dip_tolerance_rad=0.0,
                               mag_learn_s=0.0)  # fmt: skip
    return MadgwickSettings(beta_rad_s=0.041, zeta_rad_s=0.015, zeta_spin_limit_rad_s=0.0, bias_limit_rad_s=0.0,
                            rest=RestBiasSettings(bias_tau_s=0.0), schedule=off)  # fmt: skip


def _plain_madgwick() -> Any:
    """Madgwick's MadgwickAHRSupdate (MadgwickAHRS.c, 2010/2011) in numba: the arithmetic-limit reference."""
    try:
        import numba
    except ImportError:  # pragma: no cover
        return None

    @numba.njit(error_model="numpy", _nrt=False)
    def run(q, g, a, m, dt, beta, out):  # type: ignore[no-untyped-def]
        q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
        for i in range(g.shape[0]):
            gx, gy, gz = g[i, 0], g[i, 1], g[i, 2]
            ax, ay, az = a[i, 0], a[i, 1], a[i, 2]
            mx, my, mz = m[i, 0], m[i, 1], m[i, 2]
            qd1 = 0.5 * (-q1 * gx - q2 * gy - q3 * gz)
            qd2 = 0.5 * (q0 * gx + q2 * gz - q3 * gy)
            qd3 = 0.5 * (q0 * gy - q1 * gz + q3 * gx)
            qd4 = 0.5 * (q0 * gz + q1 * gy - q2 * gx)
            r = 1.0 / math.sqrt(ax * ax + ay * ay + az * az)
            ax, ay, az = ax * r, ay * r, az * r
            r = 1.0 / math.sqrt(mx * mx + my * my + mz * mz)
            mx, my, mz = mx * r, my * r, mz * r
            _2q0mx, _2q0my, _2q0mz, _2q1mx = 2.0 * q0 * mx, 2.0 * q0 * my, 2.0 * q0 * mz, 2.0 * q1 * mx
            _2q0, _2q1, _2q2, _2q3 = 2.0 * q0, 2.0 * q1, 2.0 * q2, 2.0 * q3
            _2q0q2, _2q2q3 = 2.0 * q0 * q2, 2.0 * q2 * q3
            q0q0, q0q1, q0q2, q0q3 = q0 * q0, q0 * q1, q0 * q2, q0 * q3
            q1q1, q1q2, q1q3 = q1 * q1, q1 * q2, q1 * q3
            q2q2, q2q3, q3q3 = q2 * q2, q2 * q3, q3 * q3
            hx = mx * q0q0 - _2q0my * q3 + _2q0mz * q2 + mx * q1q1 + _2q1 * my * q2 + _2q1 * mz * q3 - mx * q2q2 - mx * q3q3
            hy = _2q0mx * q3 + my * q0q0 - _2q0mz * q1 + _2q1mx * q2 - my * q1q1 + my * q2q2 + _2q2 * mz * q3 - my * q3q3
            _2bx = math.sqrt(hx * hx + hy * hy)
            _2bz = -_2q0mx * q2 + _2q0my * q1 + mz * q0q0 + _2q1mx * q3 - mz * q1q1 + _2q2 * my * q3 - mz * q2q2 + mz * q3q3
            _4bx, _4bz = 2.0 * _2bx, 2.0 * _2bz
            f1 = 2.0 * q1q3 - _2q0q2 - ax
            f2 = 2.0 * q0q1 + _2q2q3 - ay
            f3 = 1.0 - 2.0 * q1q1 - 2.0 * q2q2 - az
            f4 = _2bx * (0.5 - q2q2 - q3q3) + _2bz * (q1q3 - q0q2) - mx
            f5 = _2bx * (q1q2 - q0q3) + _2bz * (q0q1 + q2q3) - my
            f6 = _2bx * (q0q2 + q1q3) + _2bz * (0.5 - q1q1 - q2q2) - mz
            s0 = -_2q2 * f1 + _2q1 * f2 - _2bz * q2 * f4 + (-_2bx * q3 + _2bz * q1) * f5 + _2bx * q2 * f6
            s1 = _2q3 * f1 + _2q0 * f2 - 4.0 * q1 * f3 + _2bz * q3 * f4 + (_2bx * q2 + _2bz * q0) * f5 \
                + (_2bx * q3 - _4bz * q1) * f6
            s2 = -_2q0 * f1 + _2q3 * f2 - 4.0 * q2 * f3 + (-_4bx * q2 - _2bz * q0) * f4 \
                + (_2bx * q1 + _2bz * q3) * f5 + (_2bx * q0 - _4bz * q2) * f6
            s3 = _2q1 * f1 + _2q2 * f2 + (-_4bx * q3 + _2bz * q1) * f4 + (-_2bx * q0 + _2bz * q2) * f5 + _2bx * q1 * f6
            r = 1.0 / math.sqrt(s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3)
            q0 += (qd1 - beta * s0 * r) * dt
            q1 += (qd2 - beta * s1 * r) * dt
            q2 += (qd3 - beta * s2 * r) * dt
            q3 += (qd4 - beta * s3 * r) * dt
            r = 1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            q0, q1, q2, q3 = q0 * r, q1 * r, q2 * r, q3 * r
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = q0, q1, q2, q3
        q[0], q[1], q[2], q[3] = q0, q1, q2, q3

    return run


def bench_batch(rec: Any, quick: bool) -> tuple[list[Row], dict[str, Any]]:
    import numpy as np

    from mavahrs.filters import NAMES, create
    from mavahrs.filters.layout import IN_MAG, OUT_WIDTH

    prep = rec.extra["prepared"]
    rows_marg = np.ascontiguousarray(prep.rows)
    rows_imu = rows_marg.copy()
    rows_imu[:, IN_MAG : IN_MAG + 3] = np.nan
    n = rows_marg.shape[0]
    window = min(20_000, n)
    budget = 0.4 if quick else 1.5
    res: dict[str, Any] = {"samples": n, "window": window, "ns_per_sample": {}}
    for name in (*NAMES, "best"):
        for mode, data in (("MARG", rows_marg), ("IMU", rows_imu)):
            f = create(name)
            out = np.empty((window, OUT_WIDTH))
            f.run(data[:100])  # load the compiled kernel
            f.reset()

            def run(a: int, b: int, f: Any = f, data: Any = data, out: Any = out) -> None:
                if a == 0:
                    f.reset()
                f.run(data[a:b], out)

            res["ns_per_sample"][f"{name} {mode}"] = _min_window(run, n, window, budget) * 1e9
    # the same kernel doing only the report's filter (no rest detection, no gain schedule)
    f = create("madgwick", _report_settings())
    out = np.empty((window, OUT_WIDTH))
    f.run(rows_marg[:100])

    def run_report(a: int, b: int) -> None:
        if a == 0:
            f.reset()
        f.run(rows_marg[a:b], out)

    res["ns_per_sample"]["madgwick MARG, report's filter only"] = _min_window(run_report, n, window, budget) * 1e9
    # the arithmetic limit: Madgwick's own C code (2010 report, MadgwickAHRS.c) transliterated, compiled
    plain = _plain_madgwick()
    if plain is not None:
        q = np.array([1.0, 0.0, 0.0, 0.0])
        acc_up = np.ascontiguousarray(-rec.accel_m_s2)  # the C code's convention: gravity reads +z
        plain_out = np.empty((n, 4))
        gyr = np.ascontiguousarray(rec.gyro_rad_s)
        mag_ok = np.ascontiguousarray(np.nan_to_num(rec.mag_ut)) if rec.mag_ut is not None else np.zeros_like(gyr)
        plain(q, gyr[:100], acc_up[:100], mag_ok[:100], 1.0 / RATE_HZ, 0.041, plain_out)

        def run_plain(a: int, b: int) -> None:
            plain(q, gyr[a:b], acc_up[a:b], mag_ok[a:b], 1.0 / RATE_HZ, 0.041, plain_out[a:b])

        res["ns_per_sample"]["Madgwick 2010 C code (numba)"] = _min_window(run_plain, n, window, budget) * 1e9
    # references on the same samples: imufusion (per sample from Python), VQF updateBatch
    gyro = np.ascontiguousarray(rec.gyro_rad_s)
    acc = np.ascontiguousarray(rec.accel_m_s2)
    mag = np.ascontiguousarray(np.nan_to_num(rec.mag_ut)) if rec.mag_ut is not None else np.zeros_like(gyro)
    flu = np.array([1.0, -1.0, -1.0])  # FRD → FLU: VQF wants an up-positive accelerometer (ENU earth)
    g_flu, a_flu, m_flu = (np.ascontiguousarray(v * flu) for v in (gyro, acc, mag))
    try:
        from vqf import VQF

        for mode, use_mag in (("MARG", True), ("IMU", False)):

            def run_vqf(a: int, b: int, use_mag: bool = use_mag) -> None:
                v = VQF(1.0 / RATE_HZ)
                if use_mag:
                    v.updateBatch(g_flu[a:b], a_flu[a:b], m_flu[a:b])
                else:
                    v.updateBatch(g_flu[a:b], a_flu[a:b])

            res["ns_per_sample"][f"VQF updateBatch {mode}"] = _min_window(run_vqf, n, window, budget) * 1e9
    except ImportError:
        say("  vqf not installed (bench extra): no VQF figures")
    try:
        import imufusion

        gyro_deg = np.degrees(gyro)
        acc_g = acc / G_M_S2
        w_imf = min(window, 10_000)
        for mode, use_mag in (("MARG", True), ("IMU", False)):
            ahrs = imufusion.Ahrs()
            s = imufusion.AhrsSettings()
            s.convention = imufusion.CONVENTION_NED
            ahrs.set_settings(s)
            ahrs.set_sample_period(1.0 / RATE_HZ)
            q = np.empty((n, 4))

            def run_imf(a: int, b: int, ahrs: Any = ahrs, use_mag: bool = use_mag, q: Any = q) -> None:
                for i in range(a, b):
                    if use_mag:
                        ahrs.update(gyro_deg[i], acc_g[i], mag[i])
                    else:
                        ahrs.update_no_magnetometer(gyro_deg[i], acc_g[i])
                    q[i] = ahrs.get_quaternion()

            res["ns_per_sample"][f"imufusion per sample {mode}"] = _min_window(
                run_imf, n, w_imf, 0.2 if quick else 0.5, min_windows=2) * 1e9  # fmt: skip
    except ImportError:
        say("  imufusion not installed (bench extra): no imufusion figures")
    ns = res["ns_per_sample"]
    say(f"  {'':30s}{'ns/sample':>10s}{'M samples/s':>13s}")
    for k, v in ns.items():
        say(f"  {k:30s}{v:10.0f}{1e3 / v:13.2f}")
    rows = []
    mad = ns["madgwick MARG"]
    rows.append(Row("batch", f"Madgwick MARG ≥ {BATCH_MSPS:g} M samples/s (one core)",
                    f"{1e3 / mad:.2f} M/s ({mad:.0f} ns/sample)", 1e3 / mad >= BATCH_MSPS))  # fmt: skip
    vqf = ns.get("VQF updateBatch MARG")
    if vqf is not None:
        rows.append(Row("batch", f"Madgwick MARG ≥ {BATCH_VQF_RATIO:g}× VQF updateBatch",
                        f"{vqf / mad:.1f}× ({vqf:.0f} ns VQF)", vqf / mad >= BATCH_VQF_RATIO))  # fmt: skip
    rep = ns["madgwick MARG, report's filter only"]
    rows.append(Row("batch", "Madgwick MARG, report's filter only (no rest detection, no gain schedule)",
                    f"{1e3 / rep:.2f} M/s ({rep:.0f} ns){f', {vqf / rep:.1f}× VQF' if vqf else ''}", None))  # fmt: skip
    c_ref = ns.get("Madgwick 2010 C code (numba)")
    if c_ref is not None:
        rows.append(Row("batch", "Madgwick's 2010 C code compiled (the arithmetic limit)",
                        f"{1e3 / c_ref:.2f} M/s ({c_ref:.0f} ns)", None))  # fmt: skip
    imf = ns.get("imufusion per sample MARG")
    if imf is not None:
        rows.append(Row("batch", "Madgwick MARG vs imufusion per sample (Python loop)", f"{imf / mad:.0f}×", None))
    for name in (*NAMES, "best"):
        if name != "madgwick":
            v = ns[f"{name} MARG"]
            rows.append(Row("batch", f"{name} MARG / IMU", f"{1e3 / v:.2f} / {1e3 / ns[f'{name} IMU']:.2f} M/s",
                            None))  # fmt: skip
    return rows, res


# --------------------------------------------------------------------------- 3. sweep


def bench_sweep(rec: Any, quick: bool) -> tuple[list[Row], dict[str, Any]]:
    import numba
    import numpy as np

    from mavahrs.evaluation.metrics import attitude_errors_rad
    from mavahrs.filters.base import run_many
    from mavahrs.filters.madgwick import Madgwick, MadgwickSettings

    points = 100 if quick else SWEEP_POINTS
    n = min(int(SWEEP_S * RATE_HZ), rec.extra["prepared"].rows.shape[0])
    rows_in = np.ascontiguousarray(rec.extra["prepared"].rows[:n])
    stride = RATE_HZ // 10  # keep 10 attitudes per second for scoring
    betas = np.geomspace(0.005, 0.5, points)
    filters = [Madgwick(MadgwickSettings(beta_rad_s=float(b))) for b in betas]
    run_many(filters[:2], rows_in[:10])  # load the cached parallel loop
    for f in filters[:2]:
        f.reset()
    c0 = time.process_time()
    t0 = time.perf_counter()
    q = run_many(filters, rows_in, stride=stride)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    updates = points * n
    q_ref = rec.q_ref_body_to_ned[:n:stride]
    keep = np.isfinite(q_ref).all(axis=1)
    keep[: 30 * 10] = False  # after the 3 s start-up boost and convergence (30 s)
    incl = np.empty(points)
    for m in range(points):
        _, _, e = attitude_errors_rad(q[m][keep], q_ref[keep])
        incl[m] = math.degrees(math.sqrt(float(np.mean(e * e))))
    best = int(np.argmin(incl))
    scale = (SWEEP_POINTS * SWEEP_S * RATE_HZ) / updates
    projected = wall * scale
    say(f"  {points} β values × {n} samples = {updates / 1e6:.0f} M updates: wall {wall:.1f} s, CPU {cpu:.1f} s "
        f"({numba.get_num_threads()} threads, {updates / wall / 1e6:.1f} M updates/s); best β {betas[best]:.4f} "
        f"(inclination RMS {incl[best]:.2f}° vs truth; β 0.041: {incl[np.argmin(abs(betas - 0.041))]:.2f}°)")
    res = {"points": points, "samples": n, "updates": updates, "wall_s": wall, "cpu_s": cpu,
           "threads": numba.get_num_threads(), "best_beta": float(betas[best]),
           "best_inclination_rms_deg": float(incl[best]), "projected_1000x10min_s": projected}  # fmt: skip
    measured = (f"{wall:.1f} s for {updates / 1e6:.0f} M updates" if scale == 1.0 else
                f"{projected:.0f} s projected (×{scale:.0f} of {wall:.1f} s for {updates / 1e6:.1f} M)")  # fmt: skip
    return [Row("sweep", f"1000-β sweep over 10 min at 400 Hz < {SWEEP_LIMIT_S:g} s", measured,
                projected < SWEEP_LIMIT_S)], res  # fmt: skip


# --------------------------------------------------------------------------- 4. live


def _live_context(r: dict[str, Any]) -> str:
    """What else was true in a live run: the bare echo's own receipt → sendto p99 and the VM's steal time."""
    parts = []
    ep = r.get("echo_processing_us")
    if ep and ep.get("n"):
        parts.append(f"bare echo's own p99 {ep['p99']:.0f} µs")
    if r.get("steal_pct") is not None:
        parts.append(f"VM steal {r['steal_pct']:.0f} %")
    return f" ({'; '.join(parts)})" if parts else ""


def _may_use_sched_fifo() -> bool:
    probe = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return hasattr(os, "sched_setscheduler") and subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, timeout=60
    ).returncode == 0


def bench_live(quick: bool, verbose: bool, realtime_priority: int = 20) -> tuple[list[Row], dict[str, Any]]:
    from _sibling import load_script

    from mavahrs.filters import NAMES

    live = load_script("bench_live")
    names = ["best"] if quick else ["best", *NAMES]
    warmup, duration = (2.0, 6.0) if quick else (3.0, 20.0)
    rows: list[Row] = []
    res: dict[str, Any] = {}
    t = live.TARGETS
    rt = realtime_priority if realtime_priority and _may_use_sched_fifo() else 0
    if realtime_priority and not rt:
        say("  real-time scheduling is not permitted here (root or CAP_SYS_NICE): normal scheduling only, judged")
    runs = [0, rt] if rt else [0]
    for name in names:
        for prio in runs:
            r = live.bench_one(name, float(RATE_HZ), warmup, duration, verbose, prio)
            res[name if prio == rt else f"{name} (normal scheduling)"] = r
            say(live._report(r))
            p, o, c = r["processing_us"], r["e2e_overhead_us"], r["checks"]
            judged = prio == rt  # the real-time run where there is one, else the normal one
            verdict = (lambda ok: ok) if judged else (lambda ok: None)
            label = f"{name}{f' SCHED_FIFO {prio}' if prio else (' normal sched.' if rt else '')}"

            rows += [
                Row("live", f"{label}: processing p50 ≤ {t['processing_p50_us']:.0f} µs, p99 ≤ "
                    f"{t['processing_p99_us']:.0f} µs", f"p50 {p['p50']:.0f} µs, p99 {p['p99']:.0f} µs, max {p['max']:.0f} µs" + _live_context(r),
                    verdict(c["processing_p50_us"] and c["processing_p99_us"])),
                Row("live", f"{label}: e2e p50 overhead over bare echo ≤ {t['e2e_p50_overhead_us']:.0f} µs",
                    f"{o['p50']:.0f} µs (p99 {o['p99']:.0f} µs)", verdict(c["e2e_p50_overhead_us"])),
                Row("live", f"{label}: CPU/msg ≤ {t['cpu_ratio']:g}× bare echo",
                    f"{r['cpu_ratio']:.2f}× ({r['cpu_us_per_msg']['mavahrs']:.0f} vs "
                    f"{r['cpu_us_per_msg']['echo']:.0f} µs)", verdict(c["cpu_ratio"])),
                Row("live", f"{label}: ≥ 99 % of samples answered",
                    f"{r['answered']['mavahrs']}/{r['samples_sent']}", verdict(c["answered_99pct"])),
            ]  # fmt: skip
    return rows, res


# --------------------------------------------------------------------------- 5. start-up

_FIRST_CALL = r"""
import json, sys, time
t0 = time.perf_counter()
import numpy as np
from mavahrs.filters import create
from mavahrs.filters.base import _batch_loops
from mavahrs.filters.layout import IN_WIDTH
name = sys.argv[1]
row = np.full((1000, IN_WIDTH), np.nan); row[:, 0] = 0.0025; row[:, 1:4] = 0.01; row[:, 4:7] = [0.0, 0.0, -9.8]
row[:, 7:10] = [20.0, 1.0, 45.0]
t1 = time.perf_counter()
f = create(name)
f.update_row(row[0])
t2 = time.perf_counter()
f.run(row)
t3 = time.perf_counter()
step = f._step
misses = sum(sum(d.stats.cache_misses.values()) for d in (step, _batch_loops(step)[0]))
hits = sum(sum(d.stats.cache_hits.values()) for d in (step, _batch_loops(step)[0]))
print(json.dumps({"import_s": t1 - t0, "first_update_s": t2 - t1, "first_run_s": t3 - t2,
                  "total_s": t3 - t0, "compiled": misses, "loaded": hits}))
"""


def bench_startup(quick: bool) -> tuple[list[Row], dict[str, Any]]:
    from mavahrs.filters import NAMES

    rows: list[Row] = []
    res: dict[str, Any] = {}
    walls = []
    for _ in range(3 if quick else 7):
        wall, _, _ = timed_process([sys.executable, "-m", "mavahrs", "--help"])
        walls.append(wall)
    walls.sort()
    res["help_wall_s"] = walls
    say(f"  mavahrs --help: best {walls[0] * 1e3:.0f} ms, median {walls[len(walls) // 2] * 1e3:.0f} ms")
    rows.append(Row("startup", f"mavahrs --help < {HELP_LIMIT_S:g} s (subprocess)",
                    f"{walls[0] * 1e3:.0f} ms (median {walls[len(walls) // 2] * 1e3:.0f} ms)",
                    walls[0] < HELP_LIMIT_S))  # fmt: skip
    for name in ("best", *NAMES):
        timed_process([sys.executable, "-c", _FIRST_CALL, name])  # warm the cache (compiles after an edit)
        wall, _, out = timed_process([sys.executable, "-c", _FIRST_CALL, name])
        r = json.loads(out.strip().splitlines()[-1])
        r["process_wall_s"] = wall
        res[name] = r
        say(f"  {name}: fresh process, warm cache: import {r['import_s']:.2f} s, first update {r['first_update_s']:.2f} s, "
            f"first batch run {r['first_run_s']:.2f} s (process {wall:.2f} s); kernels loaded {r['loaded']}, "
            f"compiled {r['compiled']}")  # fmt: skip
        rows.append(Row("startup", f"{name}: 2nd process loads its kernels from disk (compiles nothing)",
                        f"compiled {r['compiled']}, first call {r['first_update_s'] + r['first_run_s']:.2f} s",
                        r["compiled"] == 0))  # fmt: skip
    return rows, res


# --------------------------------------------------------------------------- main


def machine_notes() -> dict[str, Any]:
    import platform

    try:
        load = os.getloadavg()
    except OSError:
        load = (math.nan, math.nan, math.nan)
    cpu = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import numba
    import numpy

    return {"cpus": os.cpu_count(), "cpu": cpu, "loadavg": load, "python": platform.python_version(),
            "numpy": numpy.__version__, "numba": numba.__version__}  # fmt: skip


def print_table(rows: list[Row]) -> None:
    w1 = max(len(r.target) for r in rows) + 2
    w2 = max(len(r.measured) for r in rows) + 2
    say(f"\n{'section':9s}{'target':{w1}s}{'measured':{w2}s}result")
    say("─" * (9 + w1 + w2 + 6))
    for r in rows:
        say(f"{r.section:9s}{r.target:{w1}s}{r.measured:{w2}s}{r.verdict}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--quick", action="store_true", help="2 minutes of data, 100 β, live check of best only")
    ap.add_argument("--json", metavar="FILE", help="write every figure as JSON")
    ap.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "mavahrs-bench",
                    help="where the generated tlogs and CSVs go (kept between runs; default %(default)s)")
    ap.add_argument("--prefix", type=float, default=None, metavar="S",
                    help="seconds of the file the pymavlink loops run on (default 300, quick 60)")
    ap.add_argument("--repeat", type=int, default=None, help="mavahrs replay runs, the fastest counts (default 2)")
    ap.add_argument("--skip", action="append", default=[], choices=SECTIONS, help="leave a section out")
    ap.add_argument("--seed", type=int, default=1, help="firmware_sim seed (default 1)")
    ap.add_argument("-v", "--verbose", action="store_true", help="show the daemon's log in the live section")
    ap.add_argument("--live-realtime", type=int, default=20, metavar="N",
                    help="SCHED_FIFO priority of the judged live run (where permitted; 0 = judge normal scheduling; "
                    "default 20)")
    ap.add_argument("--reference-loop", nargs=3, metavar=("KIND", "TLOG", "CSV"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.reference_loop:
        return reference_loop(*args.reference_loop)
    args.workdir.mkdir(parents=True, exist_ok=True)
    seconds = 120 if args.quick else 3600
    prefix_s = args.prefix if args.prefix is not None else (60.0 if args.quick else 300.0)
    repeats = args.repeat if args.repeat is not None else (1 if args.quick else 2)
    results: dict[str, Any] = {"quick": args.quick, "machine": machine_notes()}
    say(f"mavahrs bench{' --quick' if args.quick else ''}: {results['machine']['cpus']} CPUs "
        f"({results['machine']['cpu']}), load average {results['machine']['loadavg'][0]:.1f} at start")
    rows: list[Row] = []
    try:
        full = ensure_tlog(args.workdir, seconds, args.seed)
        prefix = prefix_tlog(full, prefix_s)
        rec = None
        if {"batch", "sweep"} - set(args.skip):
            from mavahrs.evaluation.tlogdata import load_tlog_recording

            rec = load_tlog_recording(full)
            say(f"filter inputs: {rec.n} samples of {full.name} ({rec.extra['imu']})")
        steps: list[tuple[str, Callable[[], tuple[list[Row], dict[str, Any]]]]] = [
            ("replay", lambda: bench_replay(full, prefix, args.workdir, args.quick, repeats)),
            ("batch", lambda: bench_batch(rec, args.quick)),
            ("sweep", lambda: bench_sweep(rec, args.quick)),
            ("live", lambda: bench_live(args.quick, args.verbose, args.live_realtime)),
            ("startup", lambda: bench_startup(args.quick)),
        ]
        for name, fn in steps:
            if name in args.skip:
                continue
            say(f"\n== {name}")
            t0 = time.perf_counter()
            r, res = fn()
            res["section_wall_s"] = time.perf_counter() - t0
            rows += r
            results[name] = res
    except (RuntimeError, subprocess.CalledProcessError, FileNotFoundError) as exc:
        print(f"bench: setup error: {exc}", file=sys.stderr)
        return 2
    results["machine"]["loadavg_end"] = machine_notes()["loadavg"]
    print_table(rows)
    results["table"] = [asdict(r) | {"result": r.verdict} for r in rows]
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2, default=float))
    missed = [r for r in rows if r.passed is False]
    say(f"\nload average at the end {results['machine']['loadavg_end'][0]:.1f}; "
        + (f"{len(missed)} target(s) missed" if missed else "all targets met"))
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
