#!/usr/bin/env python3
"""ArduPilot's 400 Hz IMU stream as it really is: re-sent messages and steady-state repeats (issue 16, item 5).

Usage::

    python3 scripts/bench_duplicates.py                       # the SITL log in ../shared + a firmware_sim flight
    python3 scripts/bench_duplicates.py --log F.tlog --sim-seeds 1 5 --duration 120 --json out.json
    python3 scripts/bench_duplicates.py --no-sim               # the shared SITL log only

Acceptance measured: "a 400 Hz stream with its duplicates and steady-state repeats gives no IMU fail-over
and no worse accuracy than the same flight with the duplicates removed".

For each flight, two tlogs are replayed with :func:`mavahrs.replay.replay` (the daemon's own decoding,
IMU selection with fail-over, timeline and filters; every filter at its defaults):

* **as sent** — the log itself;
* **stripped** — a copy without the exact duplicates: every RAW_IMU / SCALED_IMU* record whose message
  repeats the previous one of its type (same stamp, same values, same instance) is left out; found here with numpy on the raw fields, independently of the
  pipeline's own re-send step (:mod:`mavahrs.ingest.resend`). Genuine repeats (new stamp, same values) stay.

Fail-overs: a :class:`~mavahrs.service.pipeline.Pipeline` is fed every message of the log (message by
message, as the daemon) and its ``imu_switches`` counter read, with ``exact_duplicates`` (what it
dropped as re-sends). Accuracy: each filter's attitude (as sent: true north) slerped onto the
simulator's truth (SIMSTATE / SIM_STATE, :func:`mavahrs.replay.attitude_at_reference`), inclination
and heading RMS (BROAD's definitions) from ``--skip`` seconds (10) after the first IMU sample.

Flights:

* ``../shared/data/sitl/arducopter_400hz_gps.tlog`` (ArduCopter SITL, SCHED_LOOP_RATE 800, 400 Hz asked:
  about one RAW_IMU and SCALED_IMU2 in four sent twice; noiseless IMUs repeating values in steady states);
* firmware_sim's ArduPilot mode in the same conditions, in process (``--loop-rate 800 --noiseless``,
  RAW_IMU and SCALED_IMU2 at 400 Hz: 2 ms kept, re-sent by the 400 Hz telemetry task; SIMSTATE at 50 Hz;
  GLOBAL_POSITION_INT at 10 Hz), scenario ``--sim-scenario`` (aggressive), seeds ``--sim-seeds``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(REPO))

from mavahrs.evaluation.metrics import summarize  # noqa: E402
from mavahrs.evaluation.tlogdata import read_tlog_data  # noqa: E402
from mavahrs.filters import NAMES  # noqa: E402
from mavahrs.protocol.codec import MavCodec  # noqa: E402
from mavahrs.protocol.fast_tlog import scan_tlog  # noqa: E402
from mavahrs.protocol.tlog import tlog_record  # noqa: E402
from mavahrs.replay import ReplaySettings, attitude_at_reference, replay  # noqa: E402
from mavahrs.service.pipeline import Pipeline, PipelineSettings  # noqa: E402

SITL_LOG = REPO.parent / "shared" / "data" / "sitl" / "arducopter_400hz_gps.tlog"
#: message type → (stamp field or None, value fields, instance field or None)
_RESENDABLE: dict[str, tuple[str | None, tuple[str, ...], str | None]] = {
    "RAW_IMU": ("time_usec", ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag"), "id"),
    **{n: ("time_boot_ms", ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag"), None)
       for n in ("SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")},
}  # fmt: skip
# (SIMSTATE carries no stamp: a re-send cannot be told from a still vehicle's truth, so it is never stripped)
#: the simulator's command line for the firmware_sim flights (after --tlog F --fast --scenario --duration --seed)
SIM_ARGS = ("--loop-rate", "800", "--noiseless", "--preset", "none", "--stream", "HEARTBEAT=1",
            "--stream", "RAW_IMU=400", "--stream", "SCALED_IMU2=400", "--stream", "SIMSTATE=50",
            "--stream", "ATTITUDE=50", "--stream", "GLOBAL_POSITION_INT=10", "--stream", "SYSTEM_TIME=1", "-q")  # fmt: skip


# ------------------------------------------------------------------ flights


def exact_duplicates(td: object) -> dict[str, np.ndarray]:
    """Per message type, which of its messages repeat the previous one exactly (stamp, values, instance)."""
    out: dict[str, np.ndarray] = {}
    for name, (stamp, fields, inst) in _RESENDABLE.items():
        a = td.arrays.get(name)  # type: ignore[attr-defined]
        if a is None or a.shape[0] < 2:
            continue
        cols = [a[f].astype(np.float64) for f in ((stamp,) if stamp else ()) + fields + ((inst,) if inst else ())]
        cols += [a["sysid"].astype(np.float64), a["compid"].astype(np.float64)]
        v = np.stack(cols, axis=1)
        dup = np.zeros(a.shape[0], bool)
        if inst is None:
            dup[1:] = np.all((v[1:] == v[:-1]) | (np.isnan(v[1:]) & np.isnan(v[:-1])), axis=1)
        else:  # the previous message of the same instance
            for i in np.unique(a[inst]).tolist():
                idx = np.flatnonzero(a[inst] == i)
                w = v[idx]
                dup[idx[1:]] = np.all((w[1:] == w[:-1]) | (np.isnan(w[1:]) & np.isnan(w[:-1])), axis=1)
        out[name] = dup
    return out


def write_stripped(path: Path, out: Path) -> dict[str, int]:
    """A copy of the tlog without the exact duplicates; returns how many were left out per type."""
    td = read_tlog_data(path)
    dups = exact_duplicates(td)
    drop: set[tuple[int, bool]] = set()
    for name, dup in dups.items():
        pos = td.pos[name][dup]
        drop.update(zip(td.scan.offset[pos].tolist(), td.scan.in_side[pos].tolist(), strict=True))
    full = scan_tlog(np.fromfile(path, np.uint8), None, mode="mmap")
    with open(out, "wb") as f:
        buf: list[bytes] = []
        for j in range(len(full)):
            if (int(full.offset[j]), bool(full.in_side[j])) in drop:
                continue
            buf.append(tlog_record(int(full.t_us[j]), full.frame(j)))
            if len(buf) >= 8192:
                f.write(b"".join(buf))
                buf.clear()
        f.write(b"".join(buf))
    return {name: int(d.sum()) for name, d in dups.items() if d.any()}


def write_sim_flight(path: Path, scenario: str, seed: int, duration_s: float) -> None:
    """firmware_sim's ArduPilot at SCHED_LOOP_RATE 800 with noiseless sensors, in process, into a tlog."""
    from firmware_sim.__main__ import build_parser, settings_from_args
    from firmware_sim.endpoint import Endpoint
    from firmware_sim.simulation import Simulation
    from firmware_sim.streamer import write_tlog

    ns = build_parser().parse_args(["--tlog", str(path), "--fast", "--scenario", scenario,
                                    "--duration", str(duration_s), "--seed", str(seed), *SIM_ARGS])  # fmt: skip
    sim_settings, ep_settings = settings_from_args(ns)
    write_tlog(Endpoint(Simulation(sim_settings), ep_settings), path, duration_s)


# ------------------------------------------------------------------ measuring


def fail_overs(path: Path) -> dict[str, int]:
    """Feed every message through the daemon's pipeline; its IMU switches and dropped re-sends."""
    td = read_tlog_data(path)
    pipe = Pipeline(PipelineSettings(filter_name="mahony", out_rate_hz=0.0))
    codec = MavCodec()
    for j in range(td.frames):
        msg = codec.decode_frame(td.scan.frame(j))
        if msg is not None:
            pipe.handle(msg, int(td.t_us[j]))
    c = pipe.status().counters
    return {k: int(c.get(k, 0)) for k in ("imu_switches", "exact_duplicates", "same_stamp_changed")}


def accuracy(path: Path, filters: list[str], skip_s: float) -> tuple[dict[str, tuple[float, float, float]], str, int]:
    """{filter: (inclination, heading, total) RMS °} against the simulator's truth; the engine; samples fed."""
    res = replay(path, ReplaySettings(filters=tuple(filters), pipeline=PipelineSettings(out_rate_hz=0.0)))
    ref = next((k for k in res.references if k.endswith("truth")), None)
    if ref is None:
        raise SystemExit(f"{path}: no SIMSTATE/SIM_STATE truth in the log")
    t_ref, q_ref = res.references[ref]
    keep = t_ref >= res.inputs.t_us[0] + skip_s * 1e6
    out = {}
    for name in filters:
        q = attitude_at_reference(res, name, ref)[keep]
        ok = np.all(np.isfinite(q), axis=1)
        s = summarize(q[ok], q_ref[keep][ok])
        out[name] = (s.inclination_rms_deg, s.heading_rms_deg, s.total_rms_deg)
    return out, res.engine, res.inputs.n


def measure(label: str, path: Path, folder: Path, filters: list[str], skip_s: float) -> dict[str, object]:
    stripped = folder / f"{path.stem}_stripped.tlog"
    removed = write_stripped(path, stripped)
    row: dict[str, object] = {"flight": label, "stripped_per_type": removed}
    for variant, p in (("as sent", path), ("stripped", stripped)):
        acc, engine, fed = accuracy(p, filters, skip_s)
        row[variant] = {"pipeline": fail_overs(p), "engine": engine, "samples_fed": fed,
                        "rms_deg": {n: dict(zip(("inclination", "heading", "total"), v, strict=True))
                                    for n, v in acc.items()}}  # fmt: skip
    return row


def format_rows(rows: list[dict[str, object]], filters: list[str]) -> str:
    lines = []
    for r in rows:
        left = ", ".join(f"{n} {k}" for n, k in r["stripped_per_type"].items()) or "nothing"  # type: ignore[union-attr]
        lines += ["", f"{r['flight']}  (left out of the stripped copy: {left})"]
        head = f"{'':10s}{'fail-overs':>11s}{'re-sends dropped':>18s}{'samples fed':>13s}  " + "".join(
            f"{n:>22s}" for n in filters)
        lines += [head, f"{'':10s}{'':42s}  " + "".join(f"{'incl / head / total':>22s}" for _ in filters),
                  "-" * len(head)]  # fmt: skip
        for variant in ("as sent", "stripped"):
            v = r[variant]
            pc = v["pipeline"]  # type: ignore[index]
            cells = "".join(
                "{inclination:6.2f} /{heading:5.2f} /{total:5.2f}".format(**v["rms_deg"][n]).rjust(22)  # type: ignore[index]
                for n in filters
            )
            lines.append(f"{variant:10s}{pc['imu_switches']:>11d}{pc['exact_duplicates']:>18d}"
                         f"{v['samples_fed']:>13d}  {cells}")  # type: ignore[index]  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", type=Path, action="append",
                    help="SITL tlog(s) with SIMSTATE truth (repeatable; default: ../shared/data/sitl/arducopter_400hz_gps.tlog)")
    ap.add_argument("--no-sim", action="store_true", help="no firmware_sim flight")
    ap.add_argument("--sim-scenario", default="aggressive")
    ap.add_argument("--sim-seeds", nargs="+", type=int, default=[5])
    ap.add_argument("--duration", type=float, default=120.0, help="simulated seconds per firmware_sim flight")
    ap.add_argument("--filters", nargs="+", default=["best", *NAMES], help="mavahrs filters (default: best and all)")
    ap.add_argument("--skip", type=float, default=10.0, help="score from this many seconds after the first sample")
    ap.add_argument("--json", type=Path, help="also write the figures as JSON")
    args = ap.parse_args(argv)
    filters = list(dict.fromkeys(args.filters))
    logs = args.log if args.log else ([SITL_LOG] if SITL_LOG.exists() else [])
    if not args.log and not logs:
        print(f"note: {SITL_LOG} not found (../shared absent): SITL log skipped", file=sys.stderr)
    rows = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_dup_") as tmp:
        folder = Path(tmp)
        for p in logs:
            rows.append(measure(p.name, p, folder, filters, args.skip))
            print(f"  {p.name} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
        if not args.no_sim:
            try:
                import firmware_sim  # noqa: F401
            except ImportError:
                print("note: firmware_sim is not importable (run from the checkout): no simulated flight", file=sys.stderr)
            else:
                for seed in args.sim_seeds:
                    p = folder / f"fwsim_{args.sim_scenario}_s{seed}_{args.duration:g}s.tlog"
                    write_sim_flight(p, args.sim_scenario, seed, args.duration)
                    label = f"firmware_sim {args.sim_scenario} seed {seed}, {args.duration:g} s, " + " ".join(SIM_ARGS[:3])
                    rows.append(measure(label, p, folder, filters, args.skip))
                    print(f"  {label} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    print(f"Fail-overs and RMS error (°) vs the simulator's truth from {args.skip:g} s, each flight as sent and "
          "without its exact duplicates")  # fmt: skip
    print(format_rows(rows, filters))
    worse = max((r["as sent"]["rms_deg"][n][k] - r["stripped"]["rms_deg"][n][k]  # type: ignore[index]
                 for r in rows for n in filters for k in ("inclination", "heading")), default=0.0)  # fmt: skip
    switches = sum(r["as sent"]["pipeline"]["imu_switches"] for r in rows)  # type: ignore[index]
    print(f"\nacceptance: IMU fail-overs on the streams as sent: {switches}; as sent worse than stripped by at most "
          f"{worse:+.3f}° RMS — {'met' if switches == 0 and worse <= 0.005 else 'NOT met'}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
