"""``mavahrs plot``: a picture of a replay, a recording with ground truth, or a replay CSV."""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["register", "run"]

HELP = "plot truth/estimate/error per angle with gain and rejection state (needs matplotlib)"

DESCRIPTION = """\
INPUT is a flight log, recognised by its content: a tlog, an ArduPilot
DataFlash .BIN or a PX4 ULog .ulg (replayed first, compared with the
simulator's truth or the autopilot's attitude), a recording with ground truth (BROAD .mat, RepoIMU or
documented CSV: the filters run over it), or a CSV written by `mavahrs replay
--csv` (drawn as it is).  Per angle: reference, estimates and error; underneath,
each filter's gain and accelerometer/magnetometer trust (0 = rejected)."""


def register(subparsers: Any) -> argparse.ArgumentParser:
    from mavahrs.cli.common import FilterNames, add_source_option

    p: argparse.ArgumentParser = subparsers.add_parser(
        "plot", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("input", metavar="INPUT", help=".tlog, .BIN, .ulg, .mat, .csv (recording or replay CSV)")
    p.add_argument("--output", "-o", metavar="PNG", required=True, help="image to write")
    p.add_argument("--filter", "-f", dest="filters", action=FilterNames, metavar="NAME",
                   help="filter(s) to run (repeatable or comma-separated; all = every filter); default best")
    p.add_argument("--no-mag", action="store_true", help="recordings (.mat, .csv): 6-axis (no magnetometer)")
    p.add_argument("--start", type=float, metavar="S", help="from S seconds after the start")
    p.add_argument("--end", type=float, metavar="S", help="up to S seconds after the start")
    add_source_option(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import fail
    from mavahrs.errors import DataError, MavahrsError

    try:
        return _run(args)
    except (DataError, MavahrsError, OSError) as exc:
        return fail(f"plot: {exc}", 1)
    except ValueError as exc:
        return fail(f"plot: {exc}", 2)


def _run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from mavahrs.cli.common import announce_compiles
    from mavahrs.errors import DataError

    announce_compiles()
    path = Path(args.input)
    if path.is_dir():
        raise DataError(f"{path} is a directory: plot takes one file (.tlog, .BIN, .ulg, .mat or .csv)")
    if not path.exists():
        raise DataError(f"{path}: no such file")
    from mavahrs.logs import sniff

    if sniff(path) is not None or path.suffix.lower() in (".tlog", ".bin", ".ulg"):  # a log, by content
        from mavahrs import replay as rp
        from mavahrs.evaluation.report import resolve_filter_names
        from mavahrs.service.pipeline import PipelineSettings

        ps = None
        if args.source is not None:
            ps = PipelineSettings(source_system=args.source[0], source_component=args.source[1])
        res = rp.replay(path, rp.ReplaySettings(filters=tuple(resolve_filter_names(args.filters)), pipeline=ps,
                                                start_s=args.start, end_s=args.end))  # fmt: skip
        out = rp.plot_replay(res, args.output)
        import logging

        if args.no_mag:
            _ignored("--no-mag", "a flight log is replayed as the daemon runs it, magnetometer included")
        for note in res.notes:  # what replay says of the log (truncated, gaps, reboots …) holds for its plot
            logging.getLogger("mavahrs.cli").info("%s: note: %s", path.name, note)
    elif path.suffix.lower() == ".csv" and _is_replay_csv(path):
        for flag, given in (("--filter", args.filters), ("--no-mag", args.no_mag), ("--source", args.source)):
            if given:
                _ignored(flag, "a replay CSV is drawn as it is, with the filters it holds")
        out = _plot_replay_csv(path, args.output, args.start, args.end)
    else:
        out = _plot_recording(path, args)
    print(f"wrote {out}", file=sys.stderr)
    return 0


def _is_replay_csv(path: Any) -> bool:
    with open(path, encoding="utf-8", errors="replace") as f:
        head = f.readline()
    return head.startswith("time_s,") and "_qw," in head and "_sent" in head


def _ignored(flag: str, why: str) -> None:
    import logging

    logging.getLogger("mavahrs.cli").warning("plot: %s has no effect here: %s", flag, why)


def _plot_replay_csv(path: Any, output: str, start_s: float | None = None, end_s: float | None = None) -> Any:
    """A ``replay --csv`` file drawn as it is, against its ``time_s`` (the autopilot's boot time, as ``replay
    --plot`` draws and the second opinion's times read; until user7 it counted from the first row); where the
    autopilot rebooted (``time_s`` goes back) each boot on its own clock, lines broken between them.
    ``start_s``/``end_s``: seconds after its first row (the time between boots not counted)."""
    import numpy as np

    from mavahrs.errors import DataError
    from mavahrs.evaluation.plots import plot_attitude
    from mavahrs.filters.layout import OUT_ACCEL_WEIGHT, OUT_FLAGS, OUT_GAIN, OUT_MAG_WEIGHT, OUT_Q, OUT_WIDTH

    with open(path, encoding="utf-8") as f:
        cols = f.readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)  # our own numeric CSV: 4× genfromtxt's speed
    col = {c: i for i, c in enumerate(cols)}
    names = [c[: -len("_qw")] for c in cols if c.endswith("_qw")]
    est = {}
    missing = [f"{n}_{q}" for n in names for q in ("qw", "qx", "qy", "qz") if f"{n}_{q}" not in col]
    if missing or "time_s" not in col:  # a replay CSV cut down by hand: say which, not "internal error: KeyError"
        raise DataError(f"{path}: a replay CSV without its column(s) {', '.join(missing or ['time_s'])}")
    for n in names:
        out = np.full((data.shape[0], OUT_WIDTH), np.nan)
        for k, q in enumerate(("qw", "qx", "qy", "qz")):
            out[:, OUT_Q + k] = data[:, col[f"{n}_{q}"]]
        for j, c in ((OUT_GAIN, "gain"), (OUT_ACCEL_WEIGHT, "accel_weight"), (OUT_MAG_WEIGHT, "mag_weight"),
                     (OUT_FLAGS, "flags")):  # fmt: skip
            if f"{n}_{c}" in col:  # optional: the trust panel is left empty without them
                out[:, j] = data[:, col[f"{n}_{c}"]]
        est[n] = out
    t = data[:, col["time_s"]]
    step = np.diff(t)
    t_s = np.concatenate(([0.0], np.cumsum(np.maximum(step, 0.0))))  # seconds after the first row
    keep = (t_s >= (start_s if start_s is not None else -np.inf)) & (t_s <= (end_s if end_s is not None else np.inf))
    if not keep.any():
        raise DataError(f"{path}: no rows between --start {start_s} and --end {end_s} s "
                        f"(the CSV covers 0–{t_s[-1]:.1f} s)")  # fmt: skip
    x, est = t[keep], {n: o[keep] for n, o in est.items()}
    back = np.flatnonzero(np.diff(x) < 0) + 1  # a reboot: a NaN row there breaks every line
    if back.size:
        x = np.insert(x, back, np.nan)
        est = {n: np.insert(o, back, np.nan, axis=0) for n, o in est.items()}
    label = "autopilot boot time" + (" (each boot's own clock)" if back.size else "") + ", s"
    return plot_attitude(output, x, est, title=f"{path.name} (replay CSV)", time_label=label)


def _plot_recording(path: Any, args: argparse.Namespace) -> Any:
    import numpy as np

    from mavahrs.evaluation.loaders import load_one
    from mavahrs.evaluation.plots import plot_attitude
    from mavahrs.evaluation.report import choose_alignment, resolve_filter_names, run_filter
    from mavahrs.evaluation.tlogdata import cut_recording
    from mavahrs.filters.layout import OUT_Q

    rec = cut_recording(load_one(path), args.start, args.end)
    use_mag = not args.no_mag and rec.mag_ut is not None
    outs = {n: run_filter(rec, n, use_mag=use_mag) for n in resolve_filter_names(args.filters)}
    ref = rec.q_ref_body_to_ned
    mode = choose_alignment(rec, use_mag)
    title = rec.name
    if mode != "none" and outs:
        from mavahrs.evaluation.alignment import fit_alignment

        first = next(iter(outs.values()))
        a = fit_alignment(first[:, OUT_Q : OUT_Q + 4], ref, rec.scored, mode=mode)
        ref = a.apply(ref)
        title += f" (reference: {a.describe()} to {next(iter(outs))})"
    t = np.cumsum(np.nan_to_num(rec.dt_s)) - np.nan_to_num(rec.dt_s[0])
    return plot_attitude(args.output, t, outs, reference_q=ref, title=title)
