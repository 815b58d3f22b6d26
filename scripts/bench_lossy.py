#!/usr/bin/env python3
r"""Attitude accuracy over lossy links: the live daemon behind a UDP relay that drops datagrams, and replays
with GNSS messages removed (issue 16's "lossy links" targets).

Usage::

    python3 scripts/bench_lossy.py                  # live 3 seeds x 40 s x 2 runs (~4.5 min) + 18 replays (~40 s)
    python3 scripts/bench_lossy.py --live-seeds 1 2 3 4 5 6 --live-duration 60
    python3 scripts/bench_lossy.py --no-replay      # live part only (or --no-live)
    python3 scripts/bench_lossy.py --no-live --replay-source gps_raw_int
    python3 scripts/bench_lossy.py --filter madgwick --keep DIR --json out.json

**Live** (real time, every process real, all on loopback)::

    firmware_sim (ArduPilot, --loop-rate 800, SIMSTATE 400 Hz, --tlog sim.tlog)
        └─udp─▶ UdpFaultRelay (loss both ways) ─udp─▶ mavahrs run --out-rate 0 --log daemon.tlog

The simulator flies ``--live-scenario`` (default ``aggressive``) for
``--live-duration`` seconds per seed and streams what the daemon asks for:
RAW_IMU at 400 Hz, GLOBAL_POSITION_INT and GPS_RAW_INT at 10 Hz (the
daemon's defaults, ``velocity_source = auto``); the daemon runs with its
defaults (filter ``best``; ``--filter``) and answers every sample.  Each seed flies twice:
through the relay with no faults (the clean run) and with ``--loss`` (default
10 %) of all datagrams dropped at random in both directions (the simulator's
telemetry, and the daemon's heartbeats, stream requests and attitudes back to
the autopilot; ``UdpFaultRelay(reply_faults=…)``).  Scored: every
ATTITUDE_QUATERNION the daemon sent (its tlog; stamped with the sample's
``time_boot_ms``, mapped back to the sample's µs stamp), slerped onto the
SIMSTATE truth of the simulator's own tlog (complete whatever the link lost),
after ``--skip`` seconds (default 10), with
``bench_sim_accuracy.score``: inclination and heading (true north) RMS.  The
simulator's tlog is also replayed with the same filter (``mavahrs.replay``, no link):
the "replay" column, the same flight offline.  Target: the lossy run's
inclination within ``--live-target`` (0.3°) of the clean run's, every seed.

**Replay**: firmware_sim flights (``--replay-scenarios``, default
``aggressive highg flips``, seeds 1–6, ``--replay-duration`` 60 s) written
with ``--fast`` exactly as ``scripts/bench_sim_accuracy.py`` writes them
(``write_flight``: 400 Hz RAW_IMU, GLOBAL_POSITION_INT 10 Hz, SIMSTATE), and a
copy with ``--gnss-drop`` (30 %) of the GNSS messages (GLOBAL_POSITION_INT,
GPS_RAW_INT, GPS2_RAW) removed at random (seeded per flight); both replayed
through the daemon's pipeline with the filter and scored the same way (declination
0 in simulator and pipeline, as bench_sim_accuracy).  Target: inclination
within ``--replay-target`` (0.2°) of the complete log's, every flight.
``--replay-source gps_raw_int`` flies the same flights with the receiver's
GPS_RAW_INT (10 Hz) instead of GLOBAL_POSITION_INT.

Results and their reading: docs/reliability.md, "Lossy links".

Exit code 1 when a target is missed, 2 on a setup error (the daemon or the
simulator did not start or died).
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
for p in (REPO, REPO / "scripts"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import bench_sim_accuracy as bsa  # noqa: E402  (write_flight, truth, score: the same flights and scoring)
from bench_live import _env, _free_port  # noqa: E402  (how the live benchmark starts the daemon)

from mavahrs.filters.layout import FLAG_NOT_INITIALISED, OUT_FLAGS, OUT_Q  # noqa: E402
from mavahrs.protocol.tlog import iter_tlog, read_tlog_messages, tlog_record  # noqa: E402
from mavahrs.replay import ReplayResult, ReplaySettings, replay  # noqa: E402
from mavahrs.sensors.geomag import MagneticFieldSettings  # noqa: E402
from mavahrs.service.pipeline import PipelineSettings  # noqa: E402
from mavahrs.transports.relay import FaultSettings, UdpFaultRelay  # noqa: E402

#: MAVLink ids of the GNSS velocity messages the pipeline reads
GNSS_MSG_IDS = {33: "GLOBAL_POSITION_INT", 24: "GPS_RAW_INT", 124: "GPS2_RAW"}
#: the daemon's pipeline counters kept per live run (from ``--stats-json``: ``pipeline.counters``)
SHOWN_COUNTERS = ("lost_samples", "gaps", "filter_reinitialised")


def _score_track(res: ReplayResult, name: str, skip_s: float) -> tuple[float, float]:
    """(inclination, heading) RMS, degrees, of a replayed filter against the log's truth."""
    t_ref, q_ref = bsa.truth(res)
    tr = res.tracks[name]
    init = (tr.out[:, OUT_FLAGS].astype(np.int64) & FLAG_NOT_INITIALISED) == 0
    t = res.inputs.t_us.astype(np.float64)
    return bsa.score(t[init], tr.out[init, OUT_Q : OUT_Q + 4], t_ref, q_ref, skip_s)


# ------------------------------------------------------------------ live


class SetupError(RuntimeError):
    pass


def _wait_for_text(path: Path, text: str, proc: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text(errors="replace"):
            return
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    tail = path.read_text(errors="replace")[-2000:] if path.exists() else ""
    raise SetupError(f"mavahrs run never said {text!r}; its log ({path}):\n{tail}")


def daemon_outputs(tlog: Path) -> tuple[np.ndarray, np.ndarray]:
    """(time_boot_ms, q) of every ATTITUDE_QUATERNION the daemon sent (its component 191), first of each stamp."""
    seen: dict[int, tuple[float, ...]] = {}
    for _, m in read_tlog_messages(tlog, ["ATTITUDE_QUATERNION"]):
        if m.get_srcComponent() == 191 and m.time_boot_ms not in seen:
            seen[m.time_boot_ms] = (m.q1, m.q2, m.q3, m.q4)
    ms = np.array(sorted(seen), dtype=np.int64)
    return ms, np.array([seen[k] for k in ms], dtype=np.float64).reshape(-1, 4)


def live_run(
    workdir: Path, scenario: str, seed: int, duration_s: float, loss: float, skip_s: float, filter_name: str,
    verbose: bool,
) -> dict[str, Any]:  # fmt: skip
    """One flight through the relay (``loss`` both ways) into ``mavahrs run``, scored against the truth."""
    workdir.mkdir(parents=True, exist_ok=True)
    d_port = _free_port()
    daemon_log = workdir / "daemon.log"
    with open(daemon_log, "w") as err:
        daemon = subprocess.Popen(
            [sys.executable, "-m", "mavahrs", "run", "--master", f"udpin:127.0.0.1:{d_port}", "--out-rate", "0",
             "--log", "daemon.tlog", "--stats-json", "daemon.json", "--heartbeat-timeout", "60",
             "--status-interval", "10", "--filter", filter_name],
            stdout=subprocess.DEVNULL, stderr=err, env=_env(), cwd=workdir,
        )  # fmt: skip
    faults = FaultSettings(loss=loss)
    relay = None
    sim = None
    try:
        _wait_for_text(daemon_log, "mavahrs running", daemon, 180.0)
        relay = UdpFaultRelay([(("127.0.0.1", d_port), faults, True)], seed=1000 + seed, record=False,
                              reply_faults=[faults])  # fmt: skip
        host, port = relay.address
        sim = subprocess.Popen(
            [sys.executable, "-m", "firmware_sim", "--out", f"udpout:{host}:{port}", "--scenario", scenario,
             "--duration", f"{duration_s:g}", "--seed", str(seed), "--loop-rate", "800",
             "--stream", "SIMSTATE=400", "--tlog", "sim.tlog", "--stats-json", "sim.json", "-q"],
            stdout=subprocess.DEVNULL, stderr=None if verbose else subprocess.DEVNULL, env=_env(), cwd=workdir,
        )  # fmt: skip
        if sim.wait(duration_s + 120) != 0:
            raise SetupError(f"firmware_sim exited with code {sim.returncode}")
        time.sleep(0.5)  # the last answers
        forward, back = relay.counters(0), relay.reply_counters(0)
    finally:
        if sim is not None and sim.poll() is None:
            sim.kill()
            sim.wait()
        if relay is not None:
            relay.close()
        if daemon.poll() is None:
            daemon.send_signal(signal.SIGTERM)
        try:
            rc = daemon.wait(60)
        except subprocess.TimeoutExpired:
            daemon.kill()
            rc = daemon.wait()
    if rc != 0:
        raise SetupError(f"mavahrs run exited with code {rc}; its log ({daemon_log}):\n"
                         f"{daemon_log.read_text(errors='replace')[-2000:]}")  # fmt: skip
    # the truth and the sample stamps: the simulator's own tlog, replayed (which also gives the offline figure)
    settings = ReplaySettings(filters=(filter_name,), pipeline=PipelineSettings(out_rate_hz=0.0))
    res = replay(workdir / "sim.tlog", settings)
    t_ref, q_ref = bsa.truth(res)
    sample_us = np.unique(res.inputs.t_us.astype(np.int64))
    ms, q = daemon_outputs(workdir / "daemon.tlog")
    # an answer carries its sample's time_boot_ms: back to the sample's µs stamp (400 Hz: one sample per ms)
    idx = np.searchsorted(sample_us // 1000, ms)
    idx = np.clip(idx, 0, sample_us.size - 1)
    found = sample_us[idx] // 1000 == ms
    incl, head = bsa.score(sample_us[idx[found]].astype(np.float64), q[found], t_ref, q_ref, skip_s)
    off_incl, off_head = _score_track(res, filter_name, skip_s)
    pipe = json.loads((workdir / "daemon.json").read_text())["pipeline"]
    return {
        "scenario": scenario, "seed": seed, "duration_s": duration_s, "loss": loss,
        "inclination_deg": incl, "heading_deg": head,
        "replay_inclination_deg": off_incl, "replay_heading_deg": off_head,
        "answered": int(found.sum()), "samples": int(sample_us.size),
        "lost_forward": forward.lost, "datagrams_forward": forward.datagrams,
        "lost_back": back.lost, "datagrams_back": back.datagrams,
        "filter": pipe["filter_name"], "counters": {k: pipe["counters"].get(k, 0) for k in SHOWN_COUNTERS},
        "drops": pipe["drops"], "velocity_fixes": pipe["velocity_fixes"],
    }  # fmt: skip


def format_live(rows: list[dict[str, Any]], target: float) -> str:
    lines = [
        f"Live: mavahrs run (filter {rows[0]['filter']}) behind a UDP relay, firmware_sim "
        f"{rows[0]['scenario']} {rows[0]['duration_s']:g} s; RMS vs SIMSTATE truth, degrees "
        "(inclination / heading); replay = the same flight's simulator tlog replayed with the same filter, no link; "
        "answered = samples answered / samples the simulator sent; lost = datagrams dropped / relayed; "
        "GNSS = velocity fixes the filter used; gaps, reinit = the daemon's counters",
        f"{'seed':>4} {'loss':>5} {'incl':>6} {'head':>6} {'replay':>13} {'answered':>13} {'lost fwd':>13} "
        f"{'lost back':>11} {'GNSS':>5} {'gaps':>5} {'reinit':>6} {'Δincl':>6} {'Δhead':>6}",
    ]
    clean = {r["seed"]: r for r in rows if r["loss"] == 0}
    for r in rows:
        c = clean.get(r["seed"])
        d = "" if r["loss"] == 0 or c is None else (
            f"{r['inclination_deg'] - c['inclination_deg']:+6.2f} {r['heading_deg'] - c['heading_deg']:+6.2f}"
        )
        lines.append(
            f"{r['seed']:>4} {r['loss']:>5.0%} {r['inclination_deg']:6.2f} {r['heading_deg']:6.2f} "
            f"{r['replay_inclination_deg']:6.2f}/{r['replay_heading_deg']:6.2f} "
            f"{r['answered']:>6}/{r['samples']:<6} {r['lost_forward']:>6}/{r['datagrams_forward']:<6} "
            f"{r['lost_back']:>5}/{r['datagrams_back']:<5} {sum(r['velocity_fixes'].values()):>5} "
            f"{r['counters']['gaps']:>5} "
            f"{r['counters']['filter_reinitialised']:>6} {d}"
        )
    diffs = [r["inclination_deg"] - clean[r["seed"]]["inclination_deg"] for r in rows if r["loss"] > 0]
    if diffs:
        lines.append(f"lossy − clean inclination: mean {np.mean(diffs):+.2f}°, worst {max(diffs):+.2f}° "
                     f"(target ≤ {target:g}°: {'met' if max(diffs) <= target else 'MISSED'})")  # fmt: skip
    return "\n".join(lines)


# ------------------------------------------------------------------ replay


def thin_gnss(src: Path, dst: Path, fraction: float, seed: int) -> dict[str, tuple[int, int]]:
    """Copy a tlog without a random ``fraction`` of its GNSS messages; name → (removed, total)."""
    rng = np.random.default_rng(seed)
    counts: dict[str, list[int]] = {}
    with open(dst, "wb") as out:
        for t_us, frame in iter_tlog(src):
            name = GNSS_MSG_IDS.get(bsa._msgid(frame))
            if name is not None:
                c = counts.setdefault(name, [0, 0])
                c[1] += 1
                if rng.random() < fraction:
                    c[0] += 1
                    continue
            out.write(tlog_record(t_us, frame))
    return {k: (v[0], v[1]) for k, v in counts.items()}


def receiver_flight(folder: Path, scenario: str, seed: int, duration_s: float) -> Path:
    """bench_sim_accuracy's flight with the receiver's GPS_RAW_INT (10 Hz) instead of GLOBAL_POSITION_INT."""
    path = folder / f"{scenario}_s{seed}_{duration_s:g}s_gpsraw.tlog"
    if not path.exists():
        subprocess.run(
            [sys.executable, "-m", "firmware_sim", "--tlog", str(path), "--fast", "--scenario", scenario,
             "--duration", f"{duration_s:g}", "--seed", str(seed), *bsa.SIM_ARGS,
             "--stream", "GLOBAL_POSITION_INT=0", "--stream", "GPS_RAW_INT=10"],
            check=True, env=_env(), stdout=subprocess.DEVNULL,
        )  # fmt: skip
    return path


def replay_flight(
    folder: Path, scenario: str, seed: int, duration_s: float, drop: float, skip_s: float, filter_name: str,
    source: str,
) -> dict[str, Any]:  # fmt: skip
    if source == "gps_raw_int":
        full = receiver_flight(folder, scenario, seed, duration_s)
    else:
        full, _ = bsa.write_flight(folder, scenario, seed, duration_s)
    thinned = folder / f"{full.stem}_gnss-{drop * 100:g}pct.tlog"
    # each flight its own draw of removed messages
    removed = thin_gnss(full, thinned, drop, 1000 * bsa.SCENARIOS.index(scenario) + seed)
    ps = PipelineSettings(out_rate_hz=0.0, magnetic=MagneticFieldSettings(declination_deg=0.0))
    out: dict[str, Any] = {"scenario": scenario, "seed": seed, "duration_s": duration_s, "drop": drop,
                           "removed": removed, "filter": filter_name, "source": source}  # fmt: skip
    for key, path in (("complete", full), ("thinned", thinned)):
        res = replay(path, ReplaySettings(filters=(filter_name,), pipeline=ps))
        incl_head = _score_track(res, filter_name, skip_s)
        out[key] = dict(zip(("inclination_deg", "heading_deg"), incl_head, strict=True))
    out["d_inclination_deg"] = out["thinned"]["inclination_deg"] - out["complete"]["inclination_deg"]
    out["d_heading_deg"] = out["thinned"]["heading_deg"] - out["complete"]["heading_deg"]
    return out


def format_replay(rows: list[dict[str, Any]], target: float) -> str:
    drop = rows[0]["drop"]
    lines = [
        f"Replay: {rows[0]['filter']} on firmware_sim tlogs ({rows[0]['duration_s']:g} s, velocity from "
        f"{rows[0]['source'].upper()} at 10 Hz), complete vs {drop:.0%} of the GNSS messages removed; "
        "RMS vs SIMSTATE truth, degrees",
        f"{'scenario':<11} {'seed':>4} {'complete incl/head':>19} {'thinned incl/head':>18} {'Δincl':>6} "
        f"{'Δhead':>6}  removed",
    ]
    for r in rows:
        c, t = r["complete"], r["thinned"]
        rem = ", ".join(f"{k} {a}/{n}" for k, (a, n) in r["removed"].items())
        lines.append(
            f"{r['scenario']:<11} {r['seed']:>4} {c['inclination_deg']:9.2f}/{c['heading_deg']:<9.2f} "
            f"{t['inclination_deg']:8.2f}/{t['heading_deg']:<9.2f} {r['d_inclination_deg']:+6.2f} "
            f"{r['d_heading_deg']:+6.2f}  {rem}"
        )
    d = [r["d_inclination_deg"] for r in rows]
    lines.append(f"thinned − complete inclination: mean {np.mean(d):+.2f}°, worst {max(d):+.2f}° "
                 f"(target ≤ {target:g}°: {'met' if max(d) <= target else 'MISSED'})")  # fmt: skip
    return "\n".join(lines)


# ------------------------------------------------------------------ main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    live = ap.add_argument_group("live (real time)")
    live.add_argument("--no-live", dest="live", action="store_false", help="skip the live part")
    live.add_argument("--live-scenario", default="aggressive", help="firmware_sim scenario (default aggressive)")
    live.add_argument("--live-seeds", nargs="+", type=int, default=[1, 2, 3], help="seeds (default 1 2 3)")
    live.add_argument("--live-duration", type=float, default=40.0, help="seconds per run (default 40)")
    live.add_argument("--loss", type=float, default=0.10, help="datagrams dropped, each direction (default 0.10)")
    live.add_argument("--live-target", type=float, default=0.3, help="max lossy − clean inclination, deg (0.3)")
    rep = ap.add_argument_group("replay")
    rep.add_argument("--no-replay", dest="replay", action="store_false", help="skip the replay part")
    rep.add_argument("--replay-scenarios", nargs="+", default=["aggressive", "highg", "flips"],
                     choices=bsa.SCENARIOS, help="firmware_sim scenarios (default aggressive highg flips)")
    rep.add_argument("--replay-seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5, 6],
                     help="seeds (default 1–6)")
    rep.add_argument("--replay-duration", type=float, default=60.0,
                     help="simulated seconds per flight (default 60)")
    rep.add_argument("--replay-source", default="global_position_int",
                     choices=("global_position_int", "gps_raw_int"),
                     help="the flights' velocity message: GLOBAL_POSITION_INT as bench_sim_accuracy writes them "
                     "(default), or the receiver's GPS_RAW_INT alone")
    rep.add_argument("--gnss-drop", type=float, default=0.30, help="GNSS messages removed (default 0.30)")
    rep.add_argument("--replay-target", type=float, default=0.2,
                     help="max thinned − complete inclination, deg (0.2)")
    ap.add_argument("--filter", default="best", help="the daemon's filter (default best)")
    ap.add_argument("--skip", type=float, default=10.0,
                    help="score from this many seconds after the first sample (10)")
    ap.add_argument("--keep", type=Path, help="keep the logs in this folder (replay flights re-used when present)")
    ap.add_argument("--json", type=Path, help="write every run's figures as JSON")
    ap.add_argument("-v", "--verbose", action="store_true", help="show the simulator's log")
    args = ap.parse_args(argv)
    if not 0.0 <= args.loss < 1.0 or not 0.0 <= args.gnss_drop < 1.0:
        ap.error("--loss and --gnss-drop are fractions 0…1")

    tmp = None
    folder = args.keep
    if folder is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench_lossy_")
        folder = Path(tmp.name)
    folder.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"live": [], "replay": []}
    missed: list[str] = []
    t0 = time.perf_counter()
    try:
        if args.live:
            for seed in args.live_seeds:
                for loss in (0.0, args.loss):
                    wd = folder / f"live_{args.live_scenario}_s{seed}_loss{loss * 100:g}"
                    try:
                        r = live_run(wd, args.live_scenario, seed, args.live_duration, loss, args.skip,
                                     args.filter, args.verbose)
                    except SetupError as exc:
                        print(f"bench_lossy: {exc}", file=sys.stderr)
                        return 2
                    result["live"].append(r)
                    print(f"  live seed {seed} loss {loss:.0%}: inclination {r['inclination_deg']:.2f}° "
                          f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)  # fmt: skip
            print(format_live(result["live"], args.live_target), flush=True)
            clean = {r["seed"]: r["inclination_deg"] for r in result["live"] if r["loss"] == 0}
            missed += [f"live seed {r['seed']}" for r in result["live"] if r["loss"] > 0
                       and r["inclination_deg"] - clean[r["seed"]] > args.live_target]  # fmt: skip
        if args.replay:
            for sc in args.replay_scenarios:
                for seed in args.replay_seeds:
                    r = replay_flight(folder, sc, seed, args.replay_duration, args.gnss_drop, args.skip,
                                      args.filter, args.replay_source)
                    result["replay"].append(r)
                    print(f"  replay {sc} seed {seed}: Δ {r['d_inclination_deg']:+.2f}° "
                          f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)  # fmt: skip
            if args.live:
                print()
            print(format_replay(result["replay"], args.replay_target), flush=True)
            missed += [f"replay {r['scenario']} seed {r['seed']}" for r in result["replay"]
                       if r["d_inclination_deg"] > args.replay_target]  # fmt: skip
    finally:
        if tmp is not None:
            tmp.cleanup()
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    if missed:
        print("targets missed: " + ", ".join(missed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
