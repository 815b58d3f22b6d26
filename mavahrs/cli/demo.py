"""``mavahrs demo``: simulated autopilot → daemon → ground-station view, with a live status line and a score."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from mavahrs.cli.common import EXIT_CODES_HELP, EXIT_INTERRUPTED, EXIT_OK, announce_compiles

__all__ = ["register", "run"]

_DESCRIPTION = """\
Start a simulated ArduPilot (firmware_sim) and the mavahrs daemon on loopback
UDP, fly a scenario, and show what a ground station receives: the attitude
(roll, pitch, yaw), the input and output rates and the error against the
simulator's exact attitude.  At the end: the accuracy (inclination and heading
RMS, degrees), a tlog with everything in and out (SIMSTATE truth included) and
a PNG plot of truth, estimate and error per angle.  Ctrl-C stops early (the
part flown is still scored).

example:
  mavahrs demo                       # 20 s of 'aggressive', files in ./mavahrs-demo/
  mavahrs demo --scenario magnetic --duration 60 --filter mahony --outdir /tmp/demo
"""


def register(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "demo",
        help="try it: simulated autopilot + daemon on loopback, live attitude and accuracy",
        description=_DESCRIPTION,
        epilog=EXIT_CODES_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--duration", type=float, default=20.0, metavar="S", help="flight time, s (default: 20)")
    p.add_argument(
        "--scenario", default="aggressive", metavar="NAME",
        help="simulated flight: rest, hover, aggressive, flips, highg, magnetic, mag_anomaly, vibration, temperature "
        "(default: aggressive; `mavahrs-sim --list-scenarios` describes them)",
    )
    p.add_argument("--filter", default="best", metavar="NAME", help="attitude filter (default: best)")
    p.add_argument("--outdir", default="mavahrs-demo", metavar="DIR",
                   help="where the tlog and the plot go (default: ./mavahrs-demo)")
    p.add_argument("--seed", type=int, default=1, help="simulator seed: same seed, same flight (default: 1)")
    p.add_argument("--out-rate", type=float, default=50.0, metavar="HZ",
                   help="ATTITUDE_QUATERNION rate, Hz; 0 = every IMU sample (default: 50)")
    p.add_argument("--no-plot", action="store_true", help="do not draw the PNG (no matplotlib needed)")
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.demo import DemoSettings, format_summary, run_demo

    settings = DemoSettings(
        duration_s=args.duration, scenario=args.scenario, filter_name=args.filter, outdir=args.outdir,
        seed=args.seed, out_rate_hz=args.out_rate, plot=not args.no_plot,
    )  # fmt: skip

    def out(text: str) -> None:
        end = "" if text.startswith("\r") else "\n"
        sys.stdout.write(text + end)
        sys.stdout.flush()

    announce_compiles()
    result = run_demo(settings, out)
    if result.interrupted:
        out("interrupted: scoring what was flown")
    for line in format_summary(result, settings):
        out(line)
    for note in result.notes:
        out(f"note: {note}")
    return EXIT_INTERRUPTED if result.interrupted else EXIT_OK
