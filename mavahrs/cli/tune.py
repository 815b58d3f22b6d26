"""``mavahrs tune``: Madgwick β, ζ and the gyro temperature model from a recording at rest."""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["register", "run"]

HELP = "from a recording at rest: the gyro temperature-bias model (and bench-only beta, zeta: --gains)"

DESCRIPTION = """\
Fit, from a recording of the IMU at rest (ideally through a temperature
change, e.g. a warm-up after power-on):

  * per gyro axis, a linear zero drift vs temperature b(T) = b0 + k (T - t0)
    (RAW_IMU / SCALED_IMU carry the IMU temperature);
  * the measurement noise (what that line does not explain);
  * Madgwick's beta and zeta from the sensor-spec formulas (Madgwick 2010,
    eq. 50-51) and by the least-squares method of Selezneva & Kumarin
    (mu = tr(V'W) / tr(V'V)).

INPUT is a flight log, chosen by content: a tlog, an ArduPilot DataFlash .BIN
or a PX4 ULog .ulg (the daemon's scaling and timing), or a CSV with the columns in
docs/evaluation.md (time_s, gyro_*_rad_s, accel_*_m_s2, optional mag_*_ut and
temperature_c).  Writes a TOML file `mavahrs run --config` reads: by default
(--gains flight) the temperature model only, no gains (beta and zeta fitted at
rest measure the gyro's noise only; they are printed, and written as comments);
--gains spec or ls writes them too, for bench tests.

Several INPUTs (e.g. an airframe's last hundred flights with the simulator's
or a reference's rates, or its pre-flight rests) give one set of gains over
all of them: the least-squares terms tr(V'W) and tr(V'V) of every recording
are summed before the ratio, the noise figures averaged by samples; no
temperature model is combined (the gyro bias differs per power-up).  With
--dask (or --scheduler) each recording is one Dask task: the fleet extra,
pip install 'mavahrs[fleet]'."""


def register(subparsers: Any) -> argparse.ArgumentParser:
    from mavahrs.cli.common import add_source_option

    p: argparse.ArgumentParser = subparsers.add_parser(
        "tune", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "inputs", nargs="+", metavar="STATIONARY", help="flight log (.tlog, .BIN, .ulg) or CSV recorded at rest (one or more)"
    )
    p.add_argument(
        "--output", "-o", metavar="TOML", help="write the settings file here (default: print only)"
    )
    p.add_argument(
        "--gains",
        choices=("flight", "spec", "ls"),
        default="flight",
        help="flight: write no gains (the default filter keeps its flight gains), only the gyro "
        "temperature model; spec formulas or least squares: Madgwick's beta/zeta fitted at rest, "
        "for a bench only (default flight)",
    )
    p.add_argument(
        "--imu", default="auto", metavar="N", help="flight log: IMU instance 0, 1, 2 or auto (default auto)"
    )
    p.add_argument("--start", type=float, metavar="S", help="use the recording from S seconds")
    p.add_argument("--end", type=float, metavar="S", help="… up to S seconds")
    p.add_argument("--json", action="store_true", help="print the fitted figures as JSON")
    add_source_option(p)
    p.add_argument(
        "--dask", action="store_true", help="several inputs: one Dask task each on a local cluster"
    )
    p.add_argument(
        "--scheduler", metavar="ADDRESS", help="… or on an existing Dask cluster (tcp://HOST:8786)"
    )
    p.add_argument(
        "--workers", type=int, metavar="N", help="local cluster: worker processes (default: one per core)"
    )
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import report_errors

    return report_errors("tune", _run, args)


def _run(args: argparse.Namespace) -> int:
    import functools
    import json
    from pathlib import Path

    from mavahrs.cli.common import prefer_small_pages, start_kernels
    from mavahrs.errors import DataError
    from mavahrs.evaluation.tuning import combine

    prefer_small_pages()
    start_kernels()
    paths = [Path(p) for p in args.inputs]
    for path in paths:
        if path.is_dir():
            raise DataError(f"{path} is a directory: tune takes log files (for a folder: {path}/*.tlog, {path}/*.BIN …)")
        if not path.is_file():
            raise DataError(f"{path}: no such file")
    if len(paths) > 1 and not getattr(args, "verbose", 0):  # per-log INFO lines (magnetic model …) are noise
        import logging  # over several recordings, as in `audit`: its own progress and a compile's notice stay

        from mavahrs.cli.common import KERNELS_LOGGER

        logging.getLogger("mavahrs").setLevel(logging.WARNING)
        if not getattr(args, "quiet", 0):
            logging.getLogger("mavahrs.fleet").setLevel(logging.INFO)
            logging.getLogger(KERNELS_LOGGER).setLevel(logging.INFO)
    fn = functools.partial(_tune_one, imu=args.imu, start_s=args.start, end_s=args.end, source=args.source)
    if len(paths) > 1 and (args.dask or args.scheduler):
        from mavahrs.fleet.dask_engine import DaskEngine, available

        if not available():
            raise ValueError("--dask needs Dask: pip install 'mavahrs[fleet]'")
        with DaskEngine(args.scheduler, args.workers) as eng:
            done = dict(eng.map(fn, paths))
        results = [done[i] for i in range(len(paths))]
    else:
        results = [fn(p) for p in paths]
    failed = [r for r in results if isinstance(r, Exception)]
    if failed:  # raised here, not in a worker: one line, no worker traceback on the console
        raise failed[0]
    result = combine(results, name=paths[0].name if len(paths) == 1 else f"{len(paths)} recordings")
    if args.json:
        print(json.dumps(result.to_dict(), indent=2, default=float))
    else:
        print(result.format())
    warning = result.flight_warning(args.gains)
    if warning is not None:
        import logging

        logging.getLogger("mavahrs").warning("%s", warning)
    if args.output:
        unusable = result.unusable(args.gains)
        if unusable is not None:
            raise DataError(f"{result.name}: {unusable} (no {args.output} written)")
        out = Path(args.output)
        out.write_text(result.to_toml(gains=args.gains), encoding="utf-8")
        temp = (
            "the gyro temperature model" if result.temperature_model
            else "no temperature model (per recording: tune each alone)" if result.recordings > 1
            else "no temperature model (no spread)"
        )
        if args.gains == "flight":
            what = f"{temp}; no gains: the filter keeps its flight gains"
        else:
            beta, zeta = result.gains(args.gains)
            fit = "NOT fit to fly with" if warning is not None else "fit to fly with"
            what = f"{temp}; Madgwick β = {beta:.3g} rad/s, ζ = {zeta:.3g} rad/s² ({args.gains}, {fit})"
        print(f"wrote {out}: {what}; use: mavahrs run --config {out}", file=sys.stderr)
    return 0


def _tune_one(path: Any, **kw: Any) -> Any:
    """:func:`~mavahrs.evaluation.tuning.tune_file`, or the error it raised (a Dask task then does not fail:
    its worker would log the traceback on the console)."""
    from mavahrs.errors import MavahrsError
    from mavahrs.evaluation.tuning import tune_file

    try:
        return tune_file(path, **kw)
    except (MavahrsError, OSError, ValueError) as exc:
        return exc
