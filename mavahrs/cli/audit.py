"""``mavahrs audit``: replay a fleet's logs as the daemon would, one summary row per flight."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Any

__all__ = ["register", "run"]

HELP = "replay many flight logs (.tlog, .BIN, .ulg: files, folders, globs) and summarise each flight in one row"

DESCRIPTION = """\
Replay every log with the daemon's own decoding, scaling, IMU selection and
filter (exactly as `mavahrs replay`), and summarise each flight in one row:
vehicle (system id, autopilot, type), start time, duration, IMU message and
rate, GNSS, mavahrs vs the log's own ATTITUDE (or AHRS2) -- RMS and maximum
of the inclination and heading divergence, the second-opinion monitor's
WARNINGs and their times (autopilot boot clock) --, gyro/accelerometer
clipping, vibration, replay notes (reboots, gaps, low rate), and an error for a
log that cannot be read (one bad log never stops the batch).  Prints the
worst flights first.

LOGS are files, folders and globs (quote them; ** is recursive) of telemetry
logs (.tlog), ArduPilot DataFlash logs (.BIN) and PX4 ULogs (.ulg), mixed
freely; the format is chosen by content, and a folder is searched recursively
for *.tlog, *.BIN, *.ulg and any other file that is a log by its content.
Other files (tables, plots, notes: `fleet/*` expanded by the shell) are
skipped, said in one line.

Exit codes: 0 every log summarised; 1 one or more logs could not be read
(their rows carry the error, the table and summary are written all the
same), or no log found; 2 a bad option; 130 interrupted (the table keeps what
was summarised).

Engine: Dask (the fleet extra, pip install 'mavahrs[fleet]'): by default a
local cluster, one worker process per core; --scheduler tcp://HOST:8786 (or
DASK_SCHEDULER_ADDRESS) sends the same tasks, one per log, to an existing
cluster whose workers can import mavahrs and read the paths.  Without Dask
(or with --serial) the logs are replayed one after the other.

--output fleet.parquet (or .csv; repeatable) is resumable: logs already in it
with the same path, size and modification time are not replayed again unless
--force.  The table is replaced atomically every few seconds and at the end,
so Ctrl-C loses nothing already summarised.

examples:
  mavahrs audit flights/ -o fleet.parquet --plot fleet.png
  mavahrs audit 'archive/**/2025-*.tlog' -o fleet.csv --scheduler tcp://dask-head:8786
  mavahrs audit one.tlog two.tlog --serial"""


def register(subparsers: Any) -> argparse.ArgumentParser:
    from mavahrs.cli.common import FilterNames
    from mavahrs.cli.replay import add_pipeline_options

    p: argparse.ArgumentParser = subparsers.add_parser(
        "audit", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("logs", nargs="+", metavar="LOGS", help="log files (.tlog, .BIN, .ulg), folders, globs")
    p.add_argument("--output", "-o", action="append", default=[], metavar="TABLE",
                   help="write the rows to TABLE.parquet or TABLE.csv (repeatable, or comma-separated); resumable")
    p.add_argument("--force", action="store_true", help="replay logs already summarised in --output")
    p.add_argument("--plot", metavar="PNG", help="draw the fleet overview (needs matplotlib)")
    p.add_argument("--top", type=int, default=10, metavar="N", help="flights listed in the summary (default 10)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://HOST:8786 (default: DASK_SCHEDULER_ADDRESS, "
                        "else a local cluster)")  # fmt: skip
    p.add_argument("--workers", type=int, metavar="N", help="local cluster: worker processes (default: one per core)")
    p.add_argument("--serial", action="store_true", help="no Dask: replay the logs one after the other here")
    p.add_argument("--filter", "-f", dest="filters", action=FilterNames, metavar="NAME",
                   help="filter compared with the autopilot (default best)")
    add_pipeline_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.cli.common import report_errors

    return report_errors("audit", _run, args)


def _run(args: argparse.Namespace) -> int:
    import functools
    import logging
    import os
    from contextlib import ExitStack

    from mavahrs.cli.common import prefer_small_pages, start_kernels
    from mavahrs.cli.replay import settings_from_args
    from mavahrs.fleet import audit as fa

    prefer_small_pages()
    start_kernels()
    from mavahrs.cli.common import KERNELS_LOGGER

    if not getattr(args, "verbose", 0):  # per-log INFO lines (magnetic model …) are noise over a fleet
        logging.getLogger("mavahrs").setLevel(logging.WARNING)
        if not getattr(args, "quiet", 0):
            logging.getLogger("mavahrs.fleet").setLevel(logging.INFO)  # the audit's own progress (cluster start …)
            logging.getLogger(KERNELS_LOGGER).setLevel(logging.INFO)  # and a first compile's notice and time
    if args.filters and len(args.filters) > 1:
        raise ValueError("audit compares one filter with the autopilot: give --filter once")
    for t in args.output:
        fa.read_table(t)  # a bad suffix or a missing pyarrow fails now, not after the replays
    selection = fa.select_logs(args.logs)
    logs = selection.logs
    if selection.skipped:  # a glob over a folder with tables, plots, notes: not failures of the fleet
        n = len(selection.skipped)
        what = f"{n} files that are not flight logs" if n != 1 else "1 file that is not a flight log"
        print(f"audit: skipped {what} (.tlog, .BIN, .ulg by name or content): "
              f"{fa.skipped_text(selection.skipped)}", file=sys.stderr)  # fmt: skip
    from pathlib import Path

    plots = str(Path(args.plot).with_suffix("")) + "_flights" if args.plot else ""  # one chart per flight
    settings = fa.AuditSettings(replay=settings_from_args(args), plot_dir=plots)
    fn = functools.partial(fa.summarise_log, settings=settings)
    scheduler = args.scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    plan = fa.plan_audit(logs, args.output, args.force)
    import time

    startup = ""
    with ExitStack() as stack:
        mapper: Any = fa.serial_map
        where = "one process, serially" if plan.todo else ""
        if not args.serial and plan.todo:  # (nothing to replay: no cluster to start)
            from mavahrs.fleet import dask_engine

            if dask_engine.available():
                loading = None
                t0 = time.monotonic()
                kernels_s: list[float] = []
                if not scheduler:  # meanwhile the cluster starts: on a warm cache this costs no time
                    import threading

                    warm = functools.partial(fa.summarise_log, settings=dataclasses.replace(settings, plot_dir=""))  # no chart
                    loading = threading.Thread(target=_load_kernels_here, args=(warm, kernels_s), name="mavahrs-kernels")
                    loading.start()
                try:
                    eng = stack.enter_context(dask_engine.DaskEngine(scheduler, args.workers))
                    cluster_s = time.monotonic() - t0
                finally:
                    if loading is not None:
                        loading.join()  # before the first task: the workers load the kernels, none compiles
                mapper, where = functools.partial(eng.map, on_error=fa.lost_row), eng.describe()
                startup = fa.format_startup(time.monotonic() - t0, cluster_s, kernels_s[0] if kernels_s else None,
                                            _compiled_s(), local=not scheduler)  # fmt: skip
            elif scheduler:
                raise ValueError("--scheduler needs Dask: pip install 'mavahrs[fleet]'")
            else:
                logging.getLogger("mavahrs.fleet").warning("%s", fa.SERIAL_HINT)  # a log line, as every message
        bar = None
        if not args.no_progress and sys.stderr.isatty():
            from tqdm import tqdm

            bar = stack.enter_context(tqdm(total=len(plan.todo), unit="log", desc="audit", leave=False))
        result = fa.run_audit(
            logs, fn, mapper, tables=args.output, plan=plan,
            on_row=(lambda _row: bar.update(1)) if bar is not None else None,
        )  # fmt: skip
    if where == "one process, serially" and _compiled_s() is not None:  # the first log's replay compiled them
        startup = fa.format_startup(None, None, None, _compiled_s(), local=True)
    print(fa.format_summary(result, top=args.top, engine=where, startup=startup))
    for t in args.output:
        print(f"wrote {t}", file=sys.stderr)
    if args.plot:
        from mavahrs.evaluation.plots import plot_fleet

        rows = [r.as_dict() for r in result.rows]
        monitor = settings.replay.pipeline_settings().monitor
        print(f"wrote {plot_fleet(args.plot, rows, monitor=monitor)} (each flight replayed: "
              f"{plots}/LOG_second_opinion.png)", file=sys.stderr)  # fmt: skip
    bad = sum(1 for r in result.rows if not r.ok)
    if bad:
        from mavahrs.cli.common import EXIT_FAILURE

        print(f"audit: {bad} of {len(result.rows)} logs could not be read (their rows carry the error)",
              file=sys.stderr)  # fmt: skip
        return EXIT_FAILURE
    return 0


def _compiled_s() -> float | None:
    from mavahrs.cli.common import compiled_s

    return compiled_s()


def _load_kernels_here(fn: Any, took_s: list[float]) -> None:
    """Run the audit's own task once, here, on a short synthetic log before the local workers start.

    On a cold kernel cache every local worker compiled the same kernels at the same time (two workers on two
    cores: each as slow as one compile on one core, and the first audit slower than replaying the logs one
    after the other); compiled here once, they are cached and the workers only load them.  Run while the
    cluster starts; on a warm cache it only loads them (2.6 s at a load average of 13 on 2 cores).
    """
    import tempfile
    import time
    from pathlib import Path

    from mavahrs.protocol.tlog import tlog_record
    from mavahrs.warmup import synthetic_frames

    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="mavahrs-audit-") as tmp:
        log = Path(tmp) / "kernels.tlog"
        log.write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames(2.0)))
        fn(str(log))
    took_s.append(time.monotonic() - t0)
