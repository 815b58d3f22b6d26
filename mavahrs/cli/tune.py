"""``mavahrs tune``: Madgwick β, ζ and the gyro temperature model from a recording at rest."""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["register", "run"]

HELP = "fit beta, zeta and the gyro temperature-bias model from a stationary recording"

DESCRIPTION = """\
Fit, from a recording of the IMU at rest (ideally through a temperature
change, e.g. a warm-up after power-on):

  * per gyro axis, a linear zero drift vs temperature b(T) = b0 + k (T - t0)
    (RAW_IMU / SCALED_IMU carry the IMU temperature);
  * the measurement noise (what that line does not explain);
  * Madgwick's beta and zeta from the sensor-spec formulas (Madgwick 2010,
    eq. 50-51) and by the least-squares method of Selezneva & Kumarin
    (mu = tr(V'W) / tr(V'V)).

INPUT is a tlog (the daemon's scaling and timing) or a CSV with the columns in
docs/evaluation.md (time_s, gyro_*_rad_s, accel_*_m_s2, optional mag_*_ut and
temperature_c).  Writes a TOML file `mavahrs run --config` reads."""


def register(subparsers: Any) -> argparse.ArgumentParser:
    from mavahrs.cli.common import add_source_option

    p: argparse.ArgumentParser = subparsers.add_parser(
        "tune", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("input", metavar="STATIONARY", help="tlog or CSV recorded at rest")
    p.add_argument("--output", "-o", metavar="TOML", help="write the settings file here (default: print only)")
    p.add_argument("--gains", choices=("flight", "spec", "ls"), default="flight",
                   help="flight: write no gains (the default filter keeps its flight gains), only the gyro "
                   "temperature model; spec formulas or least squares: Madgwick's beta/zeta fitted at rest, "
                   "for a bench only (default flight)")
    p.add_argument("--imu", default="auto", metavar="N", help="tlog: IMU instance 0, 1, 2 or auto (default auto)")
    p.add_argument("--start", type=float, metavar="S", help="use the recording from S seconds")
    p.add_argument("--end", type=float, metavar="S", help="… up to S seconds")
    p.add_argument("--json", action="store_true", help="print the fitted figures as JSON")
    add_source_option(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import fail
    from mavahrs.errors import DataError, MavahrsError

    try:
        return _run(args)
    except (DataError, MavahrsError, OSError) as exc:
        return fail(f"tune: {exc}", 1)
    except ValueError as exc:
        return fail(f"tune: {exc}", 2)


def _run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from mavahrs.cli.common import prefer_small_pages, start_kernels
    from mavahrs.evaluation.loaders import load_one
    from mavahrs.evaluation.tlogdata import cut_recording
    from mavahrs.evaluation.tuning import tune

    prefer_small_pages()
    start_kernels()
    path = Path(args.input)
    if not path.is_file():
        raise FileNotFoundError(2, "no such file", str(path))
    if path.suffix.lower() == ".tlog":
        from mavahrs.evaluation.tlogdata import load_tlog_recording

        rec = load_tlog_recording(path, imu=args.imu, reference=False, source=args.source)
    else:
        rec = load_one(path)
    rec = cut_recording(rec, args.start, args.end)
    result = tune(rec)
    if args.json:
        print(json.dumps(result.to_dict(), indent=2, default=float))
    else:
        print(result.format())
    warning = result.flight_warning(args.gains)
    if warning is not None:
        import logging

        logging.getLogger("mavahrs").warning("%s", warning)
    if args.output:
        out = Path(args.output)
        out.write_text(result.to_toml(gains=args.gains), encoding="utf-8")
        temp = "the gyro temperature model" if result.temperature_model else "no temperature model (no spread)"
        if args.gains == "flight":
            what = f"{temp}; no gains: the filter keeps its flight gains"
        else:
            beta, zeta = result.gains(args.gains)
            fit = "NOT fit to fly with" if warning is not None else "fit to fly with"
            what = f"{temp}; Madgwick β = {beta:.3g} rad/s, ζ = {zeta:.3g} rad/s² ({args.gains}, {fit})"
        print(f"wrote {out}: {what}; use: mavahrs run --config {out}", file=sys.stderr)
    return 0
