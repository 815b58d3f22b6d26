"""``mavahrs inject-fault``: a copy of a log (.tlog, .BIN, .ulg) with a known error in the autopilot's attitude or an IMU."""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["register", "run"]

HELP = "copy a log (.tlog, .BIN, .ulg) with a step, ramp or intermittent error added to the autopilot's attitude or an IMU"

DESCRIPTION = """\
Write OUT, a copy of the log IN in which the autopilot's own attitude or one
IMU's gyro / accelerometer is off by a known amount from a known time, to test
the second-opinion monitor (mavahrs replay / audit / run) or your own settings
for it.  Everything else is copied byte for byte.

IN is chosen by its content, as replay chooses:
  telemetry log (.tlog)   ATTITUDE and ATTITUDE_QUATERNION (the same offsets in
                          both); --imu names a message (RAW_IMU, SCALED_IMU2 …)
  ArduPilot .BIN          rewritten in place: XKQ/NKQ and XKF1/NKF1 (every EKF
                          core), ATT, AHR2, DCM; --imu N: the IMU/GYR/ACC records
                          of instance N (0 = the first IMU)
  PX4 .ulg                rewritten in place: vehicle_attitude (and
                          estimator_attitude) q; --imu N: vehicle_imu[N],
                          sensor_gyro[N], sensor_accel[N], and sensor_combined
                          when N is the voted IMU
(docs/monitor.md, "Trying it on your own logs", lists every field.)

Times are the autopilot's boot clock (time_boot_ms; a .BIN's TimeUS, a .ulg's
timestamp_sample), as replay and audit report them.
Shapes: step (the full offset at --at), ramp (from 0 at --at to the full
offset --ramp-s later, then held), intermittent (the full offset for --on-s of
every --period-s).  --duration limits any of them (default: to the end).

examples:
  mavahrs inject-fault flight.tlog roll2.tlog --at 100 --roll 2
  mavahrs inject-fault flight.tlog tilt2.tlog --at 100 --tilt 2 --tilt-azimuth 90
  mavahrs inject-fault flight.tlog drift.tlog --at 100 --roll 10 --shape ramp --ramp-s 50   # 0.2 deg/s
  mavahrs inject-fault flight.tlog yaw6.tlog --at 100 --yaw 6 --shape intermittent --on-s 2 --period-s 5
  mavahrs inject-fault flight.tlog gyro.tlog --at 100 --imu SCALED_IMU2 --gyro-bias 0,0,3
  mavahrs inject-fault 00000042.BIN tilt2.BIN --at 100 --tilt 2
  mavahrs inject-fault 00000042.BIN gyro1.BIN --at 100 --imu 1 --gyro-bias 0,0,3
  mavahrs inject-fault log_7.ulg tilt2.ulg --at 100 --tilt 2
  mavahrs audit roll2.tlog drift.tlog tilt2.BIN tilt2.ulg"""


def _triple(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z, got {text!r}")
    try:
        x, y, z = (float(p) for p in parts)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}") from exc
    return x, y, z


def _imu(text: str) -> str | int:
    """--imu: a MAVLink IMU message's name, or an instance number."""
    if text.isdigit():
        return int(text)
    if text not in _IMU_MESSAGES:
        raise argparse.ArgumentTypeError(f"expected an IMU message ({', '.join(_IMU_MESSAGES)}) or an instance "
                                         f"number (0, 1, …), got {text!r}")  # fmt: skip
    return text


#: mavahrs.evaluation.faults.IMU_FAULT_MESSAGES, named here so that ``--help`` imports no numpy
#: (tests/evaluation/test_faults.py keeps the two equal)
_IMU_MESSAGES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")


def register(subparsers: Any) -> argparse.ArgumentParser:

    p: argparse.ArgumentParser = subparsers.add_parser(
        "inject-fault", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("input", metavar="IN", help="the log to copy: .tlog, ArduPilot .BIN or PX4 .ulg (by content)")
    p.add_argument("output", metavar="OUT", help="the faulty copy (must differ from IN)")
    g = p.add_argument_group("when")
    g.add_argument("--at", type=float, required=True, metavar="S", help="boot time the fault begins, s")
    g.add_argument("--shape", choices=("step", "ramp", "intermittent"), default="step", help="default step")
    g.add_argument("--duration", type=float, default=float("inf"), metavar="S", help="how long it lasts (default: to the end)")
    g.add_argument("--ramp-s", type=float, default=10.0, metavar="S", help="ramp: time to the full offset (default 10)")
    g.add_argument("--period-s", type=float, default=4.0, metavar="S", help="intermittent: period (default 4)")
    g.add_argument("--on-s", type=float, default=1.0, metavar="S", help="intermittent: on time per period (default 1)")
    a = p.add_argument_group("the autopilot's attitude (degrees, added to its Euler angles)")
    a.add_argument("--roll", type=float, default=0.0, metavar="DEG")
    a.add_argument("--pitch", type=float, default=0.0, metavar="DEG")
    a.add_argument("--yaw", type=float, default=0.0, metavar="DEG")
    a.add_argument("--tilt", type=float, default=0.0, metavar="DEG",
                   help="an earth-frame tilt error: exactly DEG of inclination whatever the attitude")
    a.add_argument("--tilt-azimuth", type=float, default=0.0, metavar="DEG",
                   help="the tilt's rotation axis, from north (default 0: about north)")
    a.add_argument("--heading", type=float, default=0.0, metavar="DEG", help="an earth-frame heading error")
    i = p.add_argument_group("an IMU (body axes)")
    i.add_argument("--imu", type=_imu, metavar="MESSAGE|N",
                   help=f"the IMU to bias: in a tlog its message ({', '.join(_IMU_MESSAGES)}); in a .BIN or "
                        ".ulg its instance N (0 = the first IMU; a message name means the instance it carries: "
                        "RAW_IMU 0, SCALED_IMU2 1, SCALED_IMU3 2)")  # fmt: skip
    i.add_argument("--gyro-bias", type=_triple, metavar="X,Y,Z", help="gyro bias, deg/s")
    i.add_argument("--accel-bias", type=_triple, metavar="X,Y,Z", help="accelerometer bias, m/s²")
    p.add_argument("--system", type=int, metavar="ID", help="a tlog's: the autopilot's system id (default: from its HEARTBEAT)")
    p.add_argument("--component", type=int, default=1, metavar="ID", help="a tlog's: its component id (default 1)")
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import report_errors

    return report_errors("inject-fault", _run, args)  # one line naming the command, as replay's and audit's


def _run(args: argparse.Namespace) -> int:
    import logging
    from pathlib import Path

    from mavahrs.errors import ConfigError, DataError
    from mavahrs.evaluation.faults import AttitudeFault, FaultShape, ImuFault, inject_faults

    try:
        when = FaultShape(args.shape, args.at, args.duration, args.ramp_s, args.period_s, args.on_s)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
    faults: list[Any] = []
    if args.roll or args.pitch or args.yaw or args.tilt or args.heading:
        faults.append(AttitudeFault(when, args.roll, args.pitch, args.yaw, args.tilt, args.tilt_azimuth, args.heading))
    if args.imu is not None or args.gyro_bias or args.accel_bias:
        if args.imu is None or not (args.gyro_bias or args.accel_bias):
            raise ConfigError("an IMU fault needs --imu MESSAGE|N and --gyro-bias and/or --accel-bias")
        message, instance = (args.imu, None) if isinstance(args.imu, str) else ("RAW_IMU", args.imu)
        try:
            faults.append(ImuFault(message, when, args.gyro_bias or (0.0, 0.0, 0.0),
                                   args.accel_bias or (0.0, 0.0, 0.0), instance))  # fmt: skip
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
    if not faults:
        raise ConfigError("no fault given: --roll/--pitch/--yaw/--tilt/--heading for the attitude, "
                          "--imu with --gyro-bias/--accel-bias")
    src, dst = Path(args.input), Path(args.output)
    if src.is_dir():
        raise DataError(f"{src} is a directory: inject-fault copies one log (.tlog, .BIN or .ulg)")
    if not src.is_file():
        raise DataError(f"{src}: no such file")
    if not dst.parent.is_dir():  # before the whole log is read (the copy goes to a temporary file beside it)
        raise DataError(f"cannot write {dst}: no such folder {dst.parent}")
    try:
        report = inject_faults(src, dst, faults, system_id=args.system, component_id=args.component)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
    except OSError as exc:  # the copy is written to a hidden temporary file beside the output: name the output
        if exc.filename and Path(exc.filename).name.startswith(f".{dst.name}."):
            raise DataError(f"cannot write {dst}: {exc.strerror or exc}") from exc
        raise
    print(f"{args.output}: {report.text()}", file=sys.stdout)
    if not report.modified:
        import math

        what = "messages" if report.format == "tlog" else "records"
        span = (f"the {what} to rewrite span {report.seen_first_s:.3f}–{report.seen_last_s:.3f} s boot time"
                if math.isfinite(report.seen_first_s) else
                f"the log has none of them from system {report.source[0]} component {report.source[1]} "
                "(--system, --component)" if report.format == "tlog" else
                "the log has none of them (for an IMU: is --imu an instance it logged?)")  # fmt: skip
        logging.getLogger("mavahrs").warning("no %s was rewritten: is --at within the log's boot times? %s",
                                             what[:-1], span)  # fmt: skip
    elif report.first_s > args.at + 1.0:  # --at read as seconds into the log, or a log that starts later
        logging.getLogger("mavahrs").warning(
            "--at %g s is before the first message rewritten, at %.3f s boot time: the fault starts there (--at "
            "is the autopilot's boot clock, as audit and replay report times, not seconds into the log)",
            args.at, report.first_s)  # fmt: skip
    return 0
