"""``mavahrs calibrate-mag``: fit the magnetometer's hard and soft iron from a recording."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

__all__ = ["register", "run"]

HELP = "fit magnetometer hard/soft-iron calibration from a recording (tlog or CSV)"

DESCRIPTION = """\
Fit a magnetometer calibration m_cal = matrix * (m - offset_ut) (hard-iron
offset, symmetric soft-iron matrix) to RECORDING: a tlog (the IMU message with
the most magnetometer samples, or --message; units from the autopilot's
scaling profile) or a CSV with columns mx, my, mz in uT.  Turn the vehicle
through as many attitudes as possible while recording (level turns alone are
refused: the soft iron is then unobservable).  The corrected field is scaled
to the World Magnetic Model's strength at the recording's GNSS position (or
--lat/--lon, or --field-ut; else the ellipsoid's mean radius).

Prints the fit's quality (residual RMS in uT and % of the field, orientation
coverage, conditioning, heading error against the autopilot's ATTITUDE when
the log has it) and the [pipeline.calibration.mag] table; --output writes the
table into a settings file for `mavahrs run --config` (replacing an earlier
one, keeping the rest of the file).  Warns when the autopilot already
calibrated the recording's magnetometer (ArduPilot RAW_IMU is): mavahrs never
corrects it twice.  Exit code 1 when the fit is refused."""


def register(subparsers: Any) -> argparse.ArgumentParser:
    p: argparse.ArgumentParser = subparsers.add_parser(
        "calibrate-mag", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("recording", metavar="RECORDING", help=".tlog file, or .csv with columns mx, my, mz (uT)")
    p.add_argument("--output", "-o", metavar="TOML", help="write [pipeline.calibration.mag] into this settings file")
    p.add_argument("--message", metavar="NAME", help="tlog: IMU message to read (RAW_IMU, SCALED_IMU2, HIGHRES_IMU, ...)")
    p.add_argument("--profile", default="auto", choices=("auto", "ardupilot", "px4", "generic"),
                   help="tlog: scaling profile (default auto = from the autopilot's HEARTBEAT)")  # fmt: skip
    p.add_argument("--field-ut", type=float, metavar="UT", help="expected field strength, uT (default: WMM)")
    p.add_argument("--lat", type=float, metavar="DEG", help="latitude for the WMM when the log has no GNSS fix")
    p.add_argument("--lon", type=float, metavar="DEG", help="longitude for the WMM, east positive")
    p.add_argument("--alt", type=float, default=0.0, metavar="M", help="altitude for the WMM, m (default 0)")
    p.add_argument("--year", type=float, metavar="YEAR", help="decimal year for the WMM (default: the log's date)")
    p.add_argument("--min-coverage", type=float, default=0.35, metavar="FRACTION",
                   help="refuse below this orientation coverage, 0-1 (default 0.35)")  # fmt: skip
    p.add_argument("--force", action="store_true", help="accept a fit with poor coverage (with a warning)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import announce_compiles
    from mavahrs.errors import ConfigError, DataError
    from mavahrs.evaluation.magcal import (
        MagFitSettings,
        calibrate_recording,
        calibration_toml,
        format_report,
        load_mag_recording,
        write_calibration_toml,
    )  # fmt: skip

    if (args.lat is None) != (args.lon is None):
        raise ConfigError("give both --lat and --lon")

    announce_compiles()
    if args.lat is not None and not (-90.0 <= args.lat <= 90.0 and -180.0 <= args.lon <= 360.0):
        raise ConfigError(f"--lat {args.lat} / --lon {args.lon}: latitude must be within ±90°, longitude ±180°")
    if args.field_ut is not None and not 1.0 <= args.field_ut <= 200.0:
        raise ConfigError(f"--field-ut {args.field_ut}: expected a field strength of 1-200 uT (Earth: 22-67)")
    try:
        settings = MagFitSettings(min_coverage=args.min_coverage, warn_coverage=max(0.6, args.min_coverage))
    except ValueError as exc:
        raise ConfigError(f"--min-coverage: {exc}") from None
    recording = load_mag_recording(args.recording, message=args.message, profile=args.profile)
    position = (args.lat, args.lon, args.alt) if args.lat is not None else None
    try:
        report = calibrate_recording(
            recording, strength_ut=args.field_ut, position=position, decimal_year=args.year,
            settings=settings, force=args.force,
        )  # fmt: skip
    except DataError:
        if recording.already_calibrated:  # worth knowing before recording again
            logging.getLogger("mavahrs").warning("%s: the autopilot already calibrates this magnetometer", recording.source)
        raise
    print(format_report(report))
    print()
    print(calibration_toml(report.fit), end="")
    if args.output:
        write_calibration_toml(args.output, report.fit)
        print(f"\nwritten to {args.output}", file=sys.stderr)
    return 0
