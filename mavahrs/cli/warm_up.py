"""``mavahrs warm-up``: compile every filter kernel now, so no later command (or flight) waits for it."""

from __future__ import annotations

import argparse
from typing import Any

from mavahrs.cli.common import EXIT_CODES_HELP, EXIT_OK

__all__ = ["register", "run"]

_DESCRIPTION = """\
Compile every filter kernel for this version and cache the result on disk
(numba; in the user's cache folder, ~/.cache/mavahrs/kernels, or in
NUMBA_CACHE_DIR when set).  The cache outlives reinstalling the same version
(e.g. adding an extra) and serves every installation of it (another virtual
environment, another source folder) from any working directory; upgrading
mavahrs compiles again.  Without it, each
command that runs a filter compiles what it needs the first time and says so.
A full warm-up measured 40 s to 6 min on a 2-core PC (idle to heavily
loaded); expect longer on a Raspberry Pi.  Where two CPUs are free it compiles
on two processes at once (the ESKF's filters in one, the others in the other;
--jobs 1: one process).  Run it once after installing or
upgrading mavahrs, before a flight, or from a systemd unit's ExecStartPre=
(contrib/mavahrs.service).  With a warm cache it only loads the cached code
and returns in a few seconds.

example:
  mavahrs warm-up
  NUMBA_CACHE_DIR=/var/cache/mavahrs mavahrs warm-up   # the cache the systemd unit uses
"""


def register(subparsers: Any) -> argparse.ArgumentParser:
    p: argparse.ArgumentParser = subparsers.add_parser(
        "warm-up",
        help="compile every filter kernel ahead of time (once per version)",
        description=_DESCRIPTION,
        epilog=EXIT_CODES_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--jobs", type=_jobs, default=None, metavar="N",
                   help="processes that compile at once (default: 2 where 2 or more CPUs are available, else 1; "
                        "more than 2 gains nothing)")  # fmt: skip
    p.add_argument("--part", choices=_parts(), help=argparse.SUPPRESS)  # one process's share under --jobs
    return p


def _parts() -> tuple[str, ...]:
    from mavahrs.warmup import PARTS

    return PARTS


def _jobs(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole number, got {text!r}")
    return value


def default_jobs() -> int:
    """2 where the process may run on 2 or more CPUs, else 1: the warm-up's parts (:data:`mavahrs.warmup.PARTS`)."""
    import os

    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        cpus = os.cpu_count() or 1
    return min(cpus, len(_parts()))


def _compile_parts(jobs: int) -> float:
    """:data:`mavahrs.warmup.PARTS` in ``jobs`` processes at once (``mavahrs warm-up --part NAME``); their
    "still compiling" lines go to this process's standard error.  Returns the seconds it took.  A part that
    fails is said, and left to the whole warm-up that follows (it compiles what is missing)."""
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path

    import mavahrs

    env = dict(os.environ)  # the children import this mavahrs, whatever the working directory
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(Path(mavahrs.__file__).resolve().parent.parent),
                                                     env.get("PYTHONPATH", "")) if p)  # fmt: skip
    t0 = time.monotonic()
    todo = list(_parts())
    running: list[tuple[str, subprocess.Popen[bytes]]] = []
    try:
        while todo or running:
            while todo and len(running) < jobs:
                part = todo.pop(0)
                cmd = [sys.executable, "-m", "mavahrs", "warm-up", "--part", part]
                running.append((part, subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL)))
            part, proc = running.pop(0)
            if proc.wait() != 0:
                print(f"warm-up: the part {part!r} exited {proc.returncode}; the steps below compile what it left",
                      file=sys.stderr, flush=True)  # fmt: skip
    finally:
        for _part, proc in running:  # interrupted: do not leave compilers behind
            proc.terminate()
            proc.wait()
    return time.monotonic() - t0


def run(args: argparse.Namespace) -> int:
    from mavahrs.filters.jit import HAVE_NUMBA, cache_location, quick_start
    from mavahrs.warmup import warm_up

    if not HAVE_NUMBA:
        print("warm-up: numba is not installed: the filters run interpreted (slowly); nothing to compile")
        return EXIT_OK
    quick_start()
    if args.part is not None:  # one share of a parallel warm-up (_compile_parts), in a process of its own
        from mavahrs.cli.common import CompileProgress, compile_progress_s
        from mavahrs.warmup import warm_up_part

        progress = CompileProgress(compile_progress_s())
        try:
            warm_up_part(args.part)
        finally:
            progress.close()
        return EXIT_OK
    jobs = default_jobs() if args.jobs is None else min(args.jobs, len(_parts()))
    print(f"warm-up: compiling every filter kernel for this version, cached in {cache_location()} "
          "(about a minute the first time, up to 8 minutes on a busy or slow machine, with a line every 30 s; "
          "a few seconds when already cached) …", flush=True)

    def done(step: Any) -> None:
        print(f"  {step.name}: {step.seconds:.1f} s", flush=True)

    from mavahrs.cli.common import CompileProgress, compile_progress_s

    progress = CompileProgress(compile_progress_s())  # a line every 30 s while compiling: a step can take minutes on a busy machine
    parallel_s = 0.0
    try:
        if jobs > 1:  # the parts at once, then the whole warm-up below loads them and compiles what is left
            parallel_s = _compile_parts(jobs)
            print(f"  {jobs} processes at once: {parallel_s:.1f} s", flush=True)
        steps = warm_up(done)
    finally:
        progress.close()
    total = parallel_s + sum(s.seconds for s in steps)
    print(f"warm-up: done in {total:.1f} s; later commands start without compiling")
    return EXIT_OK
