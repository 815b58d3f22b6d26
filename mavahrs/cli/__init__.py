r"""The ``mavahrs`` command: argparse subcommands, logging, exit codes.

Each subcommand lives in ``mavahrs/cli/<name>.py`` and exposes
``register(subparsers) -> argparse.ArgumentParser`` and ``run(args) -> int``.
:data:`SUBCOMMANDS` lists the modules looked for; a module that does not exist
is skipped, any other import error is a bug and is raised.  Subcommand modules
must not import numpy, numba or pymavlink at import time (``mavahrs --help``
answers in well under half a second): import inside ``run``.

Errors reach the user as one line (``mavahrs: error: …``) and an exit code
(:mod:`mavahrs.cli.common`); a traceback only for internal errors with ``-v``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence
from typing import Any

from mavahrs.cli import common

__all__ = ["main", "console_main", "build_parser", "SUBCOMMANDS"]

#: Subcommand modules, in the order ``--help`` lists them.
SUBCOMMANDS: tuple[str, ...] = (
    "run",
    "demo",
    "doctor",
    "replay",
    "audit",
    "inject_fault",
    "evaluate",
    "tune",
    "plot",
    "calibrate_mag",
    "sim",
    "warm_up",
)


def _load(name: str) -> Any:
    module_name = f"{__name__}.{name}"
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name == module_name:
            return None  # not written (yet): no such subcommand
        raise


def build_parser() -> argparse.ArgumentParser:
    """The full parser, with every available subcommand registered."""
    from mavahrs import __version__

    parser = argparse.ArgumentParser(
        prog="mavahrs",
        description="Attitude estimation beside a MAVLink autopilot (ArduPilot, PX4).",
        epilog=common.EXIT_CODES_HELP + ". `mavahrs COMMAND --help` for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"mavahrs {__version__}")
    common.add_logging_options(parser)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        module = _load(name)
        if module is None:
            continue
        before = set(subparsers.choices)
        module.register(subparsers)
        for cmd in set(subparsers.choices) - before:
            sub = subparsers.choices[cmd]
            sub.set_defaults(_run=module.run)
            try:
                common.add_logging_options(sub, suppress=True)
            except argparse.ArgumentError:
                pass  # the subcommand defines its own -v/-q
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``mavahrs`` with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors (argparse already printed)
        return int(exc.code) if isinstance(exc.code, int) else common.EXIT_USAGE
    except KeyboardInterrupt:  # Ctrl-C / SIGTERM while the commands' modules load: before any logging is set up
        words = list(sys.argv[1:] if argv is None else argv)
        if "run" in words:  # `run` ends with 0 when stopped, also this early (see below)
            return common.EXIT_OK
        sys.stderr.write("interrupted\n")
        return common.EXIT_INTERRUPTED
    verbosity = int(getattr(args, "verbose", 0) or 0) - int(getattr(args, "quiet", 0) or 0)
    log = common.setup_logging(verbosity, getattr(args, "log_format", "text"))
    run = getattr(args, "_run", None)
    if run is None:
        parser.print_help(sys.stderr)
        return common.EXIT_USAGE
    try:
        return int(run(args))
    except KeyboardInterrupt:
        if getattr(args, "command", None) == "run":
            # `run` stops with 0 on SIGINT/SIGTERM, also while it is still loading its settings and modules
            # (before its own handlers): a service manager stopping it at boot is not a failure
            log.info("mavahrs stopped (interrupted) while starting")
            return common.EXIT_OK
        log.error("interrupted")
        return common.EXIT_INTERRUPTED
    except BrokenPipeError:  # `mavahrs … | head`
        return common.EXIT_OK
    except Exception as exc:  # noqa: BLE001 - the one place errors become exit codes
        from mavahrs.errors import MavahrsError

        code = common.exit_code_for(exc)
        if isinstance(exc, (MavahrsError, OSError)):
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if isinstance(exc, OSError) and not isinstance(exc, MavahrsError) and exc.filename:
                message = f"{exc.filename}: {exc.strerror or message}"
            log.error("%s", message)
            if log.isEnabledFor(logging.DEBUG):
                log.debug("details", exc_info=True)
        else:
            log.error(
                "internal error: %s: %s%s",
                type(exc).__name__,
                exc,
                "" if log.isEnabledFor(logging.DEBUG) else " (run with -v for the traceback)",
                exc_info=log.isEnabledFor(logging.DEBUG),
            )
        return code
    finally:
        common.stop_announcing()


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT) or SIGTERM while a command runs, raised as Python's own Ctrl-C is (every
    ``except KeyboardInterrupt`` handles it).

    A subclass, not KeyboardInterrupt itself: CPython remembers a bare KeyboardInterrupt that passed through
    code it runs from C (an extension module's import) and, at exit, kills the process with SIGINT whatever
    :func:`main` returned — a ``run`` stopped while starting ended as "killed by SIGINT" after logging its
    clean stop (3 of 30 SIGTERMs, and 3 of 40 SIGINTs, sent 0.6–1.0 s after start).
    """


def console_main() -> None:
    """The ``mavahrs`` command (and ``python -m mavahrs``): :func:`main`, then an orderly exit.

    A Ctrl-C after ``main`` returned — while the interpreter shuts down: Dask's and numba's exit
    handlers, threads being joined — raised a KeyboardInterrupt nobody caught, and the process
    ended by the signal (exit −2 in a shell's terms) without a word, after the command had
    already written everything.  From here on a Ctrl-C says so and exits with 130 at once.
    """
    import os
    import signal

    def terminated(_signum: int, _frame: Any) -> None:
        # the batch commands (replay, audit, tune, evaluate …) stopped by `kill`, a job scheduler or a
        # container's stop: as Ctrl-C, so what was written is kept and said and worker processes are shut
        # down (it ended silently, with Dask's "leaked semaphore" warning); `run` installs its own handlers
        common.SIGNALS_RECEIVED.append(_signum)
        raise Interrupted

    try:
        if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
            signal.signal(signal.SIGTERM, terminated)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, terminated)
    except ValueError:  # not the main thread (embedded)
        pass
    code = main()
    try:  # the command is over (everything written): a SIGTERM from here on ends the process, as before
        if signal.getsignal(signal.SIGTERM) is terminated:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
    except ValueError:
        pass

    def at_shutdown(_signum: int, _frame: Any) -> None:
        try:
            sys.stdout.flush()
            import time

            now = time.time()
            stamp = time.strftime("%H:%M:%S", time.localtime(now)) + f".{int(now * 1000) % 1000:03d}"
            # the log's own format (logging itself may be shut down by now)
            sys.stderr.write(f"{stamp} ERROR interrupted while shutting down (everything was written before)\n")
            sys.stderr.flush()
        finally:
            os._exit(common.EXIT_INTERRUPTED)

    try:
        signal.signal(signal.SIGINT, at_shutdown)
        # The handler above runs only in the main thread, and only once the signal interrupts what it
        # waits on; a Ctrl-C delivered to another thread (one still running at shutdown) left the main
        # thread blocked in joining it.  The wakeup file descriptor gets the signal's number whichever
        # thread it reaches, and a daemon thread reading it acts at once.
        import threading

        r, w = os.pipe()
        os.set_blocking(w, False)
        signal.set_wakeup_fd(w, warn_on_full_buffer=False)

        def watch() -> None:
            while True:
                got = os.read(r, 64)
                if not got or signal.SIGINT in got:
                    break
            if got:
                at_shutdown(signal.SIGINT, None)

        threading.Thread(target=watch, name="mavahrs-shutdown-ctrl-c", daemon=True).start()
    except ValueError:  # not the main thread (embedded): nothing to do
        pass
    sys.exit(code)
