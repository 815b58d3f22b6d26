"""``mavahrs replay``: run the filters over a flight log as the daemon would, compare, write, stream."""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["register", "run", "settings_from_args", "add_pipeline_options"]

HELP = "replay a flight log (.tlog, DataFlash .BIN, ULog .ulg) through the filters (CSV, tlog, plot, QGC stream)"

DESCRIPTION = """\
Read the IMU messages (RAW_IMU, SCALED_IMU*, HIGHRES_IMU) and the GNSS velocity
(GLOBAL_POSITION_INT, GPS_RAW_INT, GPS2_RAW: --velocity-source) of a tlog with the daemon's own scaling, IMU selection and timing, run the
filters, and compare them with the attitude the log already holds (the
autopilot's ATTITUDE and AHRS2; in simulator logs, the SIMSTATE/SIM_STATE/HIL_STATE_QUATERNION truth).
An onboard log is read the same way, the format chosen by its content: an
ArduPilot DataFlash log (.BIN: IMU at the loop rate, MAG, GPS; compared with
EKF3's XKQ, ATT, AHR2 and in SITL the SIM truth) or a PX4 ULog (.ulg).

  --output   the input tlog with ATTITUDE_QUATERNION inserted after each IMU
             message, exactly as `mavahrs run` would have sent it (vehicle
             system id, component 191, then 192... for further filters,
             time_boot_ms of the IMU sample); opens in MAVExplorer and QGC.
  --csv      one row per IMU sample: time, then per filter the quaternion,
             Euler angles (deg), gain, accelerometer/magnetometer trust and
             rejection, gyro bias; flushed as it goes (Ctrl-C keeps every row
             computed, and --output gets the log up to the last of them).
  --plot     truth/estimate/error per angle, gain and rejection underneath;
             beside it OUT_second_opinion.png, the second-opinion monitor's
             chart against the log's autopilot attitude (when it has one).
             The second opinion judges our attitude at the daemon's output
             rate (50 Hz, or the --config file's out_rate_hz), as `mavahrs
             run` and `mavahrs audit` do, whatever --out-rate says.
  --stream   after replaying, present the first filter's attitude to a ground
             station as a vehicle of its own (its own system id, component 1,
             HEARTBEAT as a quadrotor), paced in real time (x --speed), so
             QGroundControl's HUD shows the filter flying."""


def register(subparsers: Any) -> argparse.ArgumentParser:
    from mavahrs.cli.common import FilterNames, LazyDefaultsFormatter

    p: argparse.ArgumentParser = subparsers.add_parser(
        "replay", help=HELP, description=DESCRIPTION, formatter_class=LazyDefaultsFormatter
    )
    p.add_argument("tlog", metavar="LOG", help="flight log: telemetry .tlog (MAVProxy, QGC, Mission Planner, mavahrs), "
                   "ArduPilot DataFlash .BIN or PX4 ULog .ulg (chosen by content)")
    p.add_argument("--filter", "-f", dest="filters", action=FilterNames, metavar="NAME",
                   help="filter (repeatable, or comma-separated): {filters}, or all (default: best)")
    p.add_argument("--output", "-o", metavar="OUT.tlog", help="write the log with the filters' ATTITUDE_QUATERNION "
                   "(of an onboard log: a tlog of those frames alone)")
    p.add_argument("--csv", metavar="OUT.csv", help="write one row per IMU sample")
    p.add_argument("--plot", metavar="OUT.png", help="write a plot (needs the plot extra: matplotlib); also OUT_second_opinion.png")
    p.add_argument("--out-rate", type=float, default=0.0, metavar="HZ",
                   help="ATTITUDE_QUATERNION rate in the output tlog, Hz of log time; 0 = every sample (default 0)")
    p.add_argument("--start", type=float, metavar="S", help="replay from S seconds after the log's start")
    p.add_argument("--end", type=float, metavar="S", help="… up to S seconds after the log's start")
    p.add_argument("--skip", type=float, default=0.0, metavar="S",
                   help="compare from S seconds after the first replayed sample: leaves the filters' convergence "
                   "out of the RMS table, as the README's tables do with 10 (the filters still start at the first "
                   "sample; --start moves that) (default 0: every sample)")
    add_pipeline_options(p)
    p.add_argument("--engine", default="auto", choices=("auto", "fast", "pipeline"),
                   help="fast: bulk decode + batch filters; pipeline: the daemon's per-message path; "
                   "auto: fast when it can mirror the log (default)")
    p.add_argument("--stream", metavar="URL", help="then stream to a ground station, e.g. udpout:127.0.0.1:14550")
    p.add_argument("--speed", type=float, default=1.0, help="stream speed, 1 = real time (default 1)")
    p.add_argument("--stream-sysid", type=int, default=42, metavar="ID",
                   help="system id of the streamed pretend vehicle (default 42)")
    p.add_argument("--stream-rate", type=float, default=50.0, metavar="HZ", help="stream rate, Hz (default 50)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import report_errors

    return report_errors("replay", _run, args)


def add_pipeline_options(p: argparse.ArgumentParser) -> None:
    """--imu, --velocity-source, --profile, --source and --config: how the daemon's pipeline reads the log
    (replay and audit)."""
    from mavahrs.cli.common import add_source_option, add_velocity_source_option

    p.add_argument("--imu", default=None, metavar="N", help="IMU instance: auto, 0, 1 or 2 (default auto)")
    add_velocity_source_option(p, default_text="auto, or the --config file's")
    p.add_argument("--profile", default=None, choices=("auto", "ardupilot", "px4", "generic"),
                   help="scaling profile (default: from the autopilot's HEARTBEAT)")
    add_source_option(p)
    p.add_argument("--config", metavar="TOML", action="append",
                   help="daemon settings file (pipeline, monitor and filter settings); repeatable, layered in "
                   "order as `mavahrs run --config` does")  # fmt: skip


def settings_from_args(args: argparse.Namespace) -> Any:
    """ReplaySettings from the options replay and audit share (--filter, --config, --imu, --profile,
    --velocity-source, --source, and where present --out-rate, --start, --end, --engine)."""
    import dataclasses

    from mavahrs.evaluation.report import resolve_filter_names
    from mavahrs.replay import ReplaySettings
    from mavahrs.service.pipeline import PipelineSettings

    filters = resolve_filter_names(args.filters)
    filter_settings: dict[str, Any] = {}
    if args.config:
        from mavahrs.config import load_run_config

        cfg = load_run_config(args.config)
        ps = cfg.pipeline
        if cfg.filter is not None:
            filter_settings[ps.filter_name] = cfg.filter
        if not args.filters:
            filters = [ps.filter_name]
    else:
        ps = PipelineSettings()
    # the second opinion judges what the daemon with these settings publishes, whatever the output tlog's rate
    monitor_rate_hz = float(ps.out_rate_hz)
    changes: dict[str, Any] = {}
    if getattr(args, "out_rate", None) is not None:
        changes["out_rate_hz"] = args.out_rate
    if args.imu is not None:
        changes["imu"] = args.imu
    if args.profile is not None:
        changes["autopilot_profile"] = args.profile
    if args.velocity_source is not None:
        changes["velocity_source"] = args.velocity_source
    if args.source is not None:
        changes["source_system"], changes["source_component"] = args.source
    ps = dataclasses.replace(ps, **changes)
    return ReplaySettings(
        filters=tuple(filters), pipeline=ps, filter_settings=filter_settings,
        start_s=getattr(args, "start", None), end_s=getattr(args, "end", None),
        engine=getattr(args, "engine", "auto"), monitor_rate_hz=monitor_rate_hz,
    )  # fmt: skip


def _run(args: argparse.Namespace) -> int:
    from contextlib import ExitStack

    from mavahrs.cli.common import gc_paused

    # the collector rests while the command starts and computes the replay (imports, kernels: 40 ms
    # of a short log's 0.5 s); it resumes before the output is printed, written, plotted or streamed
    with ExitStack() as starting:
        starting.enter_context(gc_paused())
        try:
            rp, settings = _start(args)
        except KeyboardInterrupt:  # Ctrl-C while the command started (imports, kernels): before the log was read
            return _interrupted(args, None, starting=True)
        return _replay_started(args, rp, settings, computed=starting.close)


def _start(args: argparse.Namespace) -> tuple[Any, Any]:
    """Imports, filter kernels, checks of the input and the settings: (the replay module, its settings)."""
    from pathlib import Path

    from mavahrs import replay as rp
    from mavahrs.cli.common import prefer_small_pages, start_kernels
    from mavahrs.errors import DataError

    prefer_small_pages()
    start_kernels()

    # the same exit code (1, a runtime failure, as for an unreadable log) for both, a clear message
    if Path(args.tlog).is_dir():
        raise DataError(f"{args.tlog} is a directory: replay takes one log file; for a folder of logs "
                        "use `mavahrs audit FOLDER` (one row per flight)")  # fmt: skip
    if not Path(args.tlog).is_file():
        raise DataError(f"{args.tlog}: no such file")
    # an output whose folder does not exist is said before the log is read and replayed, not after
    for option, out in (("--output", args.output), ("--csv", args.csv), ("--plot", args.plot)):
        if out and not Path(out).parent.is_dir():
            raise DataError(f"{option} {out}: no such folder {Path(out).parent}")
    return rp, settings_from_args(args)


def _replay_started(args: argparse.Namespace, rp: Any, settings: Any, computed: Any = None) -> int:
    progress = not args.no_progress and sys.stderr.isatty()
    try:
        result = rp.replay(args.tlog, settings, csv_path=args.csv, progress=progress)
    except rp.ReplayInterrupted as stop:
        return _interrupted(args, stop)
    except KeyboardInterrupt:
        return _interrupted(args, None)
    if computed is not None:
        computed()
    wrote: dict[str, int] = {}  # the outputs written so far (a Ctrl-C while reporting keeps the rest)
    try:
        _report(args, rp, result, wrote)
    except KeyboardInterrupt:
        return _interrupted_reporting(args, rp, result, wrote)
    return _streamed(args, rp, result)


def _report(args: argparse.Namespace, rp: Any, result: Any, wrote: dict[str, int]) -> None:
    """The replay's header, comparison and second opinion (printed), then its outputs: the tlog and plot."""
    from pathlib import Path

    inp = result.inputs
    dur = inp.duration_s()
    print(f"{Path(args.tlog).name}: {inp.n} IMU samples of {inp.message} (instance {inp.instance}) "
          f"from system {inp.source[0]}/{inp.source[1]} ({inp.profile} scaling), {dur:.1f} s at "
          f"{inp.rate_hz():.1f} Hz; engine {result.engine}")  # fmt: skip
    if result.log is not None:
        from mavahrs.logs import FORMATS

        print(f"format: {FORMATS[result.log.format]}")
        for line in result.log.found:
            print(line)
    print(rp.format_velocity(inp))
    for note in result.notes:
        print(f"note: {note}")
    print(rp.format_comparison(rp.compare(result, skip_s=args.skip), skip_s=args.skip, result=result))
    so = rp.format_second_opinion(result)  # what the daemon's monitor would have said
    if so:
        print(so)
    wrote["compared"] = 1
    if args.csv:
        print(f"wrote {args.csv} ({inp.n} rows)", file=sys.stderr)
    if args.output:
        k = rp.write_tlog(result, args.output)
        wrote["output"] = k
        comps = ", ".join(f"{t.name} → component {t.component_id}" for t in result.tracks.values())
        print(f"wrote {args.output} ({k} frames inserted, system {result.system_id}: {comps})", file=sys.stderr)
    if args.plot:
        print(f"wrote {rp.plot_replay(result, args.plot)}", file=sys.stderr)
        wrote["plot"] = 1
        so = rp.plot_second_opinion(result, args.plot)  # the monitor's chart beside it, where there is one
        if so is not None:
            print(f"wrote {so}", file=sys.stderr)


def _interrupted_reporting(args: argparse.Namespace, rp: Any, result: Any, wrote: dict[str, int]) -> int:
    """Ctrl-C after every sample was filtered, while comparing, writing or plotting: the CSV is complete, the
    --output tlog is written if it was not yet (it said "interrupted" and lost it), exit 130."""
    import logging

    from mavahrs.cli.common import EXIT_INTERRUPTED

    kept: list[str] = []
    if args.csv:
        kept.append(f"{result.inputs.n} CSV rows in {args.csv} (complete)")
    if args.output:
        if "output" not in wrote:
            logging.getLogger("mavahrs").info("interrupted: writing %s with every filtered sample first", args.output)
        k = wrote["output"] if "output" in wrote else rp.write_tlog(result, args.output)
        kept.append(f"{k} frames in {args.output} (complete)")
    left = ([] if "compared" in wrote else ["the comparison (printed)"]) + ([f"the plot ({args.plot})"] if args.plot and "plot" not in wrote else [])
    logging.getLogger("mavahrs").error(
        "replay interrupted after every sample was filtered — %s%s",
        "kept " + ", ".join(kept) if kept else "nothing to keep",
        "; not made: " + ", ".join(left) if left else "",
    )
    return EXIT_INTERRUPTED


def _streamed(args: argparse.Namespace, rp: Any, result: Any) -> int:
    """--stream: the first filter's attitude to a ground station, paced in real time."""
    if args.stream:
        name = next(iter(result.tracks))
        ss = rp.StreamSettings(url=args.stream, system_id=args.stream_sysid, speed=args.speed,
                               rate_hz=args.stream_rate)  # fmt: skip
        print(f"streaming {name} to {args.stream} as system {ss.system_id}, component 1 (a quadrotor) at "
              f"{ss.speed:g}× speed; Ctrl-C stops", file=sys.stderr)  # fmt: skip
        n = rp.stream(result, name, ss)
        print(f"streamed {n} attitudes", file=sys.stderr)
    return 0


def _interrupted(args: argparse.Namespace, stop: Any, starting: bool = False) -> int:
    """Ctrl-C during the replay: write what was computed and say what was kept (exit 130)."""
    import logging

    from mavahrs.cli.common import EXIT_INTERRUPTED

    kept: list[str] = []
    if starting:
        at = "while starting (loading the filters), before the log was read"
    elif stop is None:
        at = "while reading the log, before any sample was filtered"
    else:
        at = f"at {100.0 * stop.fraction:.0f} % of the samples"
    if args.csv:
        kept.append(f"no CSV ({args.csv} not written)" if stop is None or stop.csv_path is None
                    else f"{stop.csv_rows} CSV rows in {args.csv}")  # fmt: skip
    if args.output:
        part = None if stop is None else stop.result
        if part is not None and part.inputs.n:
            from mavahrs import replay as rp

            k = rp.write_tlog(part, args.output, until_tlog_us=int(part.inputs.tlog_us[-1]))
            kept.append(f"{k} frames in {args.output} (the log up to the last filtered sample)")
        elif part is None and stop is not None:
            kept.append(f"no tlog ({args.output}: the pipeline engine writes it only at the end)")
        else:
            kept.append(f"no tlog ({args.output} not written)")
    logging.getLogger("mavahrs").error(
        "replay interrupted %s — %s", at, "kept " + ", ".join(kept) if kept else "nothing to keep"
    )
    return EXIT_INTERRUPTED
