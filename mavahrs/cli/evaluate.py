"""``mavahrs evaluate``: score filters against ground truth, or run one of the papers' studies."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

__all__ = ["register", "run"]

HELP = "score filters against ground truth (BROAD .mat, RepoIMU/CSV, simulator logs: .tlog, DataFlash .BIN, ULog .ulg)"

DESCRIPTION = """\
Run filters over recordings with a reference attitude and print the papers'
accuracy table per filter: BROAD's total / heading / inclination RMS on the
scored samples, RMS of roll, pitch and yaw at rest (< 5 deg/s) and in motion
(>= 5 deg/s) (Madgwick 2010 Table 1), and the mean and SD per angle
(Ermakov & Gogolev 2022 Table 2).  All figures in degrees.

INPUT is a BROAD .mat trial, a RepoIMU T-stick CSV, a CSV with the columns
documented in docs/evaluation.md, a simulator's flight log with its truth (chosen
by content: a tlog with SIMSTATE or HIL_STATE_QUATERNION, an ArduPilot DataFlash
.BIN with SIM, a PX4 ULog .ulg with vehicle_attitude_groundtruth), or a folder of
them (the mean over recordings is BROAD's plain mean of per-trial figures).

--study runs one of the papers' studies on INPUT instead, prints its table and,
with --plot, draws it:  beta (error vs beta 0..0.5, Fig. 10), rate (error vs
sample rate 1..512 Hz by decimation, Fig. 11), bias (tracking an injected
gyro drift, Fig. 12), compare (Mahony, Madgwick, complementary side by side,
2022 Table 2 / Fig. 8-13)."""


def register(subparsers: Any) -> argparse.ArgumentParser:
    from mavahrs.cli.common import (
        FilterNames,
        LazyDefaultsFormatter,
        add_source_option,
        add_velocity_source_option,
    )

    p: argparse.ArgumentParser = subparsers.add_parser(
        "evaluate", help=HELP, description=DESCRIPTION, formatter_class=LazyDefaultsFormatter
    )
    p.add_argument("input", metavar="INPUT", help=".mat, .csv, .tlog, .BIN, .ulg file or a folder of them")
    p.add_argument(
        "--filter", "-f", dest="filters", action=FilterNames, metavar="NAME",
        help="filter to run (repeatable, or comma-separated): {filters}, or all (default: best; studies: their own defaults)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the results as JSON instead of tables")
    add_velocity_source_option(p, default_text="auto; flight logs only")
    p.add_argument("--no-mag", action="store_true", help="6-axis: do not give the filters the magnetometer")
    p.add_argument(
        "--multirotor", action="store_true",
        help="the recording's IMU flew on a multirotor: filters that model one (best, eskf) use the rotor-drag "
        "measurement, as the daemon does on a multirotor's HEARTBEAT (a flight log's own HEARTBEAT decides "
        "without it)",
    )  # fmt: skip
    p.add_argument(
        "--align", default="auto", choices=("auto", "none", "heading", "heading+body"),
        help="reference alignment: auto = none for a north-referenced reference scored 9-axis, "
        "else a fitted heading offset; heading+body also fits a constant body misalignment "
        "(default: auto)",
    )  # fmt: skip
    p.add_argument("--skip", type=float, default=0.0, metavar="S",
                   help="CSV recordings / flight logs: do not score the first S seconds (convergence), s (default 0; "
                   "BROAD trials are scored over their own movement phase)")
    p.add_argument("--per-recording", action="store_true", help="print every recording's table, not only the mean")
    p.add_argument("--study", choices=("beta", "rate", "bias", "compare"), help="run a study instead (see above)")
    p.add_argument("--decimation", default="average", choices=("average", "pick"),
                   help="rate study: gyro averaged over each block, or every signal picked (default average)")
    p.add_argument("--duration", type=float, metavar="S", help="bias study: use only the first S seconds")
    p.add_argument("--plot", metavar="PNG", help="write a plot (evaluation: the first recording with a reference, named on stderr; study: its figure)")
    add_source_option(p)
    p.set_defaults(func=run)
    return p


def _error(msg: str, code: int) -> int:
    from mavahrs.cli.common import fail

    return fail(f"evaluate: {msg}", code)  # one log line, as every command's errors


def run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import report_errors

    return report_errors("evaluate", _run, args)  # DataError, OSError → 1; ValueError (a bad option) → 2


def _run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import prefer_small_pages, start_kernels
    from mavahrs.evaluation.loaders import load_any
    from mavahrs.evaluation.report import evaluate_recordings, format_report, resolve_filter_names

    prefer_small_pages()
    start_kernels()

    import logging

    geomag = logging.getLogger("mavahrs.sensors.geomag")
    level = geomag.level
    if Path(args.input).is_dir() and not getattr(args, "verbose", 0):
        geomag.setLevel(logging.WARNING)  # one "magnetic field from WMM at …" line per flight log, none saying which
    try:
        recordings = load_any(args.input, skip_s=args.skip, velocity_source=args.velocity_source or "auto",
                              source=args.source)
    finally:
        geomag.setLevel(level)
    if Path(args.input).is_dir():
        _say_what_the_folder_holds(Path(args.input))
    if args.multirotor:
        for rec in recordings:
            rec.extra["multirotor"] = True
    if args.study:
        return _study(args, recordings)
    filters = resolve_filter_names(args.filters)
    report = evaluate_recordings(
        recordings, filters, input_name=str(args.input), use_mag=not args.no_mag, alignment=args.align,
        progress=sys.stderr.isatty(),
    )  # fmt: skip
    if args.json:
        print(report.to_json())
    else:
        print(format_report(report, per_recording=True if args.per_recording else None))
    if args.plot:
        with_ref = [r for r in recordings if r.extra.get("has_reference", True)] or recordings
        _plot_first(args, _one_of(with_ref, "--plot draws"), filters)
    if not any(r.scores for r in report.recordings):
        return _error("nothing was scored (no usable reference attitude in the input; see the notes above)", 1)
    return 0


def _say_what_the_folder_holds(folder: Path) -> None:
    """The files a folder's evaluation skipped, and a mean over different kinds of recording, said as log lines
    (both were silent: a mean of BROAD trials and flight logs reads as one figure of one kind)."""
    import logging

    from mavahrs.evaluation.loaders import folder_files

    log = logging.getLogger("mavahrs")

    taken, skipped = folder_files(folder)
    if skipped:
        n = len(skipped)
        what = f"{n} files that are not recordings or logs" if n != 1 else "1 file that is not a recording or log"
        names = ", ".join(f.name for f in skipped[:5]) + (f" and {n - 5} more" if n > 5 else "")
        log.info("skipped %s (.mat, .csv, .tlog, .BIN, .ulg by name or content): %s", what, names)
    kinds: dict[str, int] = {}
    for f in taken:
        kind = {".mat": "BROAD trial", ".csv": "recording CSV"}.get(f.suffix.lower(), "flight log")
        kinds[kind] = kinds.get(kind, 0) + 1
    if len(kinds) > 1:
        held = ", ".join(f"{n} {k}{'s' if n != 1 else ''}" for k, n in kinds.items())
        log.warning("this folder holds different kinds of recording (%s): the mean over them mixes kinds; "
                    "evaluate a folder of one kind for a figure of that kind", held)


def _one_of(recordings: list[Any], what: str) -> Any:
    """The first of ``recordings``; says so when there are more (a folder): the command draws or studies one."""
    if len(recordings) > 1:
        import logging

        logging.getLogger("mavahrs.cli").info(
            "%s one recording: %s, the first of %d with a reference; give its file to choose another",
            what, recordings[0].name, len(recordings))  # fmt: skip
    return recordings[0]


def _plot_first(args: argparse.Namespace, rec: Any, filters: list[str]) -> None:
    import numpy as np

    from mavahrs.evaluation.plots import plot_attitude
    from mavahrs.evaluation.report import run_filter

    t = np.cumsum(np.nan_to_num(rec.dt_s)) - np.nan_to_num(rec.dt_s[0])
    outs = {n: run_filter(rec, n, use_mag=not args.no_mag) for n in filters}
    path = plot_attitude(args.plot, t, outs, reference_q=rec.q_ref_body_to_ned, title=rec.name)
    print(f"wrote {path}", file=sys.stderr)


def _study(args: argparse.Namespace, recordings: list[Any]) -> int:
    import json

    from mavahrs.evaluation import studies

    with_ref = [r for r in recordings if r.extra.get("has_reference", True)]
    if not with_ref:
        return _error("no recording with a reference attitude", 1)
    filters = args.filters or []
    progress = sys.stderr.isatty()
    if args.study == "beta":
        result = studies.beta_study(with_ref, filter_name=filters[0] if filters else "madgwick", progress=progress)
    elif args.study == "rate":
        result = studies.rate_study(
            with_ref, filter_name=filters[0] if filters else "madgwick", method=args.decimation, progress=progress
        )
    elif args.study == "bias":
        result = studies.bias_study(
            _one_of(with_ref, "--study bias runs on"), filter_name=filters[0] if filters else "madgwick", duration_s=args.duration,
            use_mag=not args.no_mag,
        )  # fmt: skip
    else:
        names = filters or ["mahony", "madgwick", "complementary"]
        result = studies.compare_study(_one_of(with_ref, "--study compare runs on"), filters=names,
                                       use_mag=not args.no_mag)  # fmt: skip
    print(json.dumps(result.to_dict(), indent=2) if args.json else result.format())
    if args.plot:
        from mavahrs.evaluation.plots import plot_study

        print(f"wrote {plot_study(result, Path(args.plot))}", file=sys.stderr)
    return 0
