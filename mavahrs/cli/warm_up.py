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
loaded); expect longer on a Raspberry Pi.  Run it once after installing or
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
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.filters.jit import HAVE_NUMBA, cache_location, quick_start
    from mavahrs.warmup import warm_up

    if not HAVE_NUMBA:
        print("warm-up: numba is not installed: the filters run interpreted (slowly); nothing to compile")
        return EXIT_OK
    quick_start()
    print(f"warm-up: compiling every filter kernel for this version, cached in {cache_location()} "
          "(about a minute the first time, up to 8 minutes on a busy or slow machine, with a line every 30 s; "
          "a few seconds when already cached) …", flush=True)

    def done(step: Any) -> None:
        print(f"  {step.name}: {step.seconds:.1f} s", flush=True)

    from mavahrs.cli.common import CompileProgress, compile_progress_s

    progress = CompileProgress(compile_progress_s())  # a line every 30 s while compiling: a step can take minutes on a busy machine
    try:
        steps = warm_up(done)
    finally:
        progress.close()
    total = sum(s.seconds for s in steps)
    print(f"warm-up: done in {total:.1f} s; later commands start without compiling")
    return EXIT_OK
