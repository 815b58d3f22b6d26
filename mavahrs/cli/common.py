r"""What every ``mavahrs`` subcommand shares: exit codes, logging set-up, error reporting, help formatting.

Kept free of heavy imports (no numpy, numba, pymavlink): ``mavahrs --help``
imports this module and every subcommand's ``register``.

Exit codes (documented in docs/daemon.md and ``mavahrs --help``):

====  ======================================================================
0     success (also ``run`` stopped by SIGINT/SIGTERM or ``--duration``)
1     runtime failure (an unexpected error; ``-v`` shows the traceback)
2     usage or configuration error (bad option, config file, connection string)
3     connection failure: a link cannot be opened (port busy, permission
      denied, no such device, address in use) or no autopilot heartbeat
130   interrupted: Ctrl-C (or SIGTERM) before the command finished (``demo`` still
      scores the part flown, and exits 130); ``run`` is meant to run until
      stopped, so SIGINT/SIGTERM end it with 0
====  ======================================================================
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import logging
import re
import sys
from collections.abc import Iterator
from typing import Any

__all__ = [
    "EXIT_OK",
    "EXIT_FAILURE",
    "EXIT_USAGE",
    "EXIT_CONNECTION",
    "EXIT_INTERRUPTED",
    "EXIT_CODES_HELP",
    "exit_code_for",
    "FilterNames",
    "setup_logging",
    "JsonFormatter",
    "LazyDefaultsFormatter",
    "add_logging_options",
    "fail",
    "report_errors",
    "prefer_small_pages",
    "start_kernels",
    "COMPILE_NOTICE",
    "announce_compiles",
    "CompileProgress",
    "compile_progress_s",
    "COMPILE_PROGRESS_S",
    "stop_announcing",
    "add_source_option",
    "parse_source",
]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_CONNECTION = 3
EXIT_INTERRUPTED = 130

#: the stop signals (SIGINT/SIGTERM) the command line's own handler received, in order (``console_main``
#: records each before raising it: a raise that lands in a callback run from C is dropped, the record stays)
SIGNALS_RECEIVED: list[int] = []

EXIT_CODES_HELP = (
    "exit codes: 0 ok, 1 runtime failure, 2 usage/config error, "
    "3 connection failure or no heartbeat, 130 interrupted by Ctrl-C before finishing "
    "(`run` exits 0 when SIGINT or SIGTERM stops it: that is how a service ends)"
)

_LOGGER_NAME = "mavahrs"


def exit_code_for(exc: BaseException) -> int:
    """The documented exit code for an exception reaching the command line."""
    from mavahrs.errors import ConfigError, TransportError

    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    if isinstance(exc, ConfigError):
        return EXIT_USAGE
    if isinstance(exc, TransportError):
        return EXIT_CONNECTION
    return EXIT_FAILURE


def fail(message: str, code: int = EXIT_FAILURE) -> int:
    """Log ``message`` as one error line and return ``code`` (for ``return fail(...)`` in ``run``)."""
    logging.getLogger(_LOGGER_NAME).error("%s", message)
    return code


def report_errors(command: str, run: Any, args: argparse.Namespace) -> int:
    """``run(args)`` with its errors as one line and the documented exit code.

    ConfigError and ValueError (bad options, settings) → 2; TransportError (a link or a
    scheduler that cannot be reached) → 3; DataError, any other MavahrsError and OSError (unreadable input, missing file) → 1; a
    broken pipe (``mavahrs … | head``) is left to ``main``, which exits quietly.
    """
    from mavahrs.errors import ConfigError, MavahrsError, TransportError

    try:
        return int(run(args))
    except BrokenPipeError:
        raise
    except ConfigError as exc:
        return fail(f"{command}: {exc}", EXIT_USAGE)
    except TransportError as exc:  # a link or server that cannot be reached: the documented connection code
        return fail(f"{command}: {exc}", EXIT_CONNECTION)
    except MavahrsError as exc:
        return fail(f"{command}: {exc}", EXIT_FAILURE)
    except OSError as exc:  # the file and the reason, not Python's "[Errno 2] …" form
        what = f"{exc.filename}: {exc.strerror}" if exc.filename and exc.strerror else (exc.strerror or str(exc))
        return fail(f"{command}: {what}", EXIT_FAILURE)
    except ValueError as exc:
        return fail(f"{command}: {exc}", EXIT_USAGE)


def prefer_small_pages() -> None:
    """Stop numpy asking the kernel for transparent huge pages for its large arrays (bulk commands).

    numpy calls ``madvise(MADV_HUGEPAGE)`` on every array of 4 MB or more. Where the
    kernel's THP ``defrag`` setting is ``madvise`` (a common default), each 2 MB
    fault in such an array may then compact memory synchronously. Replay and
    evaluation allocate a few hundred MB once and stream over it, so they
    gain nothing from huge pages and pay for every fault. On the one-hour
    ``bench.py`` replay this was 0.8 s of 4.4 s (system time 1.7 → 0.9 s).
    A user's own ``NUMPY_MADVISE_HUGEPAGE`` setting is left as it is.
    """
    import os

    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return
    import numpy as np

    core = getattr(np, "_core", None) or getattr(np, "core", None)
    setter = getattr(getattr(core, "multiarray", None), "_set_madvise_hugepage", None)
    if setter is not None:
        setter(False)


#: allocations between two collections of the youngest generation while a command starts (Python's
#: default is 700): a start-up's ~120 000 lasting objects never reach it, while a long replay still
#: collects its cycles — the garbage it may hold is bounded
STARTUP_GC_THRESHOLD = 500_000


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Let Python's cyclic garbage collector rest while a command starts, then freeze what it built.

    A command's start imports a few hundred modules (numba's most of all) and loads its filter
    kernels from the disk cache: ~120 000 objects that live as long as the process.  With the
    default thresholds every 700 allocations start a collection that walks the young ones again,
    and the older generations are walked over and over as they grow: 35–45 ms of a 0.5 s
    ``mavahrs replay`` of a 5-second log (``scripts/bench_startup.py``).  Here the youngest
    generation is collected only every :data:`STARTUP_GC_THRESHOLD` allocations instead —
    reference counting still frees every object outside a cycle, and a long replay inside the
    block still collects its cycles now and then.  On leaving (an exception included) the
    thresholds are restored and what exists is moved to the permanent generation
    (:func:`gc.freeze`): the modules, functions and kernels are not walked by later collections
    (a full collection of them took 20 ms, a stall in the daemon's 400 Hz loop), at the price of
    keeping the few hundred cyclic leftovers of the start itself.
    """
    import gc

    thresholds = gc.get_threshold()
    gc.set_threshold(max(STARTUP_GC_THRESHOLD, thresholds[0]), *thresholds[1:])
    try:
        yield
    finally:
        gc.set_threshold(*thresholds)
        gc.freeze()


def start_kernels() -> None:
    """Load numba's compiler without its BLAS probe (:func:`mavahrs.filters.jit.quick_start`; 0.15 s sooner),
    and announce a first compilation (:func:`announce_compiles`)."""
    from mavahrs.filters.jit import quick_start

    quick_start()
    announce_compiles()


#: printed once, just before the first compilation of the filter kernels in a process (a cold cache)
COMPILE_NOTICE = (  # CPU time and busy figure: a cold `mavahrs run`, docs/daemon.md (first start)
    "compiling the filter kernels this command needs, once for this version of mavahrs: up to 1½ min "
    "of CPU time (`mavahrs run`), 6–7 min measured on a busy 2-core machine; a line every 30 s says it is still "
    "at it, later runs load them in a second, and `mavahrs warm-up` does it ahead of time …"
)

#: seconds between two "still compiling" lines while a first compilation goes on (:class:`CompileProgress`;
#: ``MAVAHRS_COMPILE_PROGRESS_S`` overrides it)
COMPILE_PROGRESS_S = 30.0


def announce_compiles() -> None:
    """Log :data:`COMPILE_NOTICE` when this process starts compiling a filter kernel (never on a warm cache).

    Called by every subcommand that runs filters, before it does (numba gets
    imported here).  Detection is numba's own
    (:func:`mavahrs.filters.jit.on_first_compile`): it compiles only what its
    disk cache cannot supply.  Idempotent; :func:`stop_announcing` (called by
    ``main`` when the command ends) removes the listener.
    """
    if _ANNOUNCER:
        return
    from mavahrs.filters.jit import on_first_compile

    def announce(_kernel: str) -> None:
        logging.getLogger(KERNELS_LOGGER).info("%s", COMPILE_NOTICE)

    import time

    _ANNOUNCER.append(on_first_compile(announce, clock=time.monotonic))
    _ANNOUNCER.append(CompileProgress(compile_progress_s()).close)


def compile_progress_s() -> float:
    """Seconds between "still compiling" lines: ``MAVAHRS_COMPILE_PROGRESS_S`` when set to a positive number
    (the tests' short interval), else :data:`COMPILE_PROGRESS_S`."""
    import os

    try:
        value = float(os.environ.get("MAVAHRS_COMPILE_PROGRESS_S", ""))
    except ValueError:
        return COMPILE_PROGRESS_S
    return value if value > 0 else COMPILE_PROGRESS_S


class CompileProgress:
    """While mavahrs kernels compile, log every ``interval_s`` that it is still at it, with the time and count so far.

    A cold compile takes from a minute to several (a busy 2-core machine: 6 min for ``mavahrs run``),
    and the process is silent meanwhile: it looked hung.  Listens to numba's own compile events
    (kernels of the ``mavahrs`` package only; a warm cache compiles nothing, so nothing is said);
    a daemon thread, started at the first compilation, says *"still compiling the filter kernels:
    90 s so far, 57 compiled …"* at each interval during which a compilation ran, and nothing
    while the process does other work.  :meth:`close` stops it.
    """

    def __init__(self, interval_s: float = COMPILE_PROGRESS_S, logger: logging.Logger | None = None) -> None:
        import threading
        import time

        self.interval_s = float(interval_s)
        self.started = 0
        self.ended = 0
        self.lines = 0
        self._clock = time.monotonic
        self._first_s: float | None = None
        self._log = logger or logging.getLogger(KERNELS_LOGGER)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: Any = None
        try:
            from numba.core import event
        except ImportError:  # no numba: nothing compiles
            return
        owner = self

        class _Listener(event.Listener):  # type: ignore[misc, name-defined]
            def on_start(self, ev: Any) -> None:
                if _ours(ev):
                    owner._on_start()

            def on_end(self, ev: Any) -> None:
                if _ours(ev):
                    owner.ended += 1

        self._listener = _Listener()
        event.register("numba:compile", self._listener)

    def _on_start(self) -> None:
        import threading

        self.started += 1
        if self._first_s is None:
            self._first_s = self._clock()
            self._thread = threading.Thread(target=self._run, name="mavahrs-compile-progress", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        seen = 0  # compilations started by the previous tick
        while not self._stop.wait(self.interval_s):
            now = self._clock()
            busy = self.started > self.ended or self.started != seen  # compiling now, or some started since
            seen = self.started
            if busy and self._first_s is not None:
                self.lines += 1
                self._log.info(
                    "still compiling the filter kernels: %.0f s so far, %d compiled (once for this version) …",
                    now - self._first_s, self.ended,
                )  # fmt: skip

    def close(self) -> None:
        """Stop listening and end the thread (idempotent)."""
        self._stop.set()
        if self._listener is not None:
            from numba.core import event

            event.unregister("numba:compile", self._listener)
            self._listener = None
        if self._thread is not None:
            self._thread.join(1.0)


def _ours(ev: Any) -> bool:
    """A numba compile event of a cached kernel of the mavahrs package (not a driver loop compiled uncached in
    every process, ≈ 0.5 s, as :func:`mavahrs.filters.jit.on_first_compile` counts)."""
    data = ev.data if isinstance(getattr(ev, "data", None), dict) else {}
    dispatcher = data.get("dispatcher")
    py = getattr(dispatcher, "py_func", None)
    if not str(getattr(py, "__module__", "")).startswith("mavahrs"):
        return False
    cache = getattr(dispatcher, "_cache", None)
    return cache is not None and type(cache).__name__ != "NullCache"


def compiled_s() -> float | None:
    """How long this process has compiled filter kernels so far, s (None: nothing compiled, a warm cache)."""
    for remove in _ANNOUNCER:
        took = getattr(remove, "compiled_s", lambda: None)()
        if took is not None:
            return float(took)
    return None


def stop_announcing() -> None:
    """Undo :func:`announce_compiles` (no-op when it was not called); after a compilation, say how long it took
    and where the kernels are kept (the notice's figure is a range; this one is measured)."""
    while _ANNOUNCER:
        remove = _ANNOUNCER.pop()
        took = getattr(remove, "compiled_s", lambda: None)()
        remove()
        if took is not None:
            from mavahrs.filters.jit import cache_location

            logging.getLogger(KERNELS_LOGGER).info(
                "compiling the filters took %.0f s; kept in %s, later runs load them at once", took, cache_location()
            )


_ANNOUNCER: list[Any] = []
#: the compile notice's logger: a command that keeps ``mavahrs`` at WARNING over many logs (audit) keeps this
#: one at INFO, so that minutes of a first compile are never silent
KERNELS_LOGGER = "mavahrs.kernels"


# --------------------------------------------------------------------------- logging


class JsonFormatter(logging.Formatter):
    """One JSON object per line (journald, Loki, Elasticsearch…).

    Keys: ``time`` (ISO 8601, UTC), ``level``, ``logger``, ``message``; a
    record's ``status`` extra (the daemon's status fields) is included as an
    object; ``exception`` holds a traceback when there is one.
    """

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "time": datetime.datetime.fromtimestamp(record.created, datetime.timezone.utc).isoformat(
                timespec="milliseconds"
            ),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        status = getattr(record, "status", None)
        if status is not None:
            out["status"] = status
        if record.exc_info:
            out["exception"] = self.formatException(record.exc_info)
        return json.dumps(out, default=_json_default, allow_nan=False)


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


class _NanSafeJson(JsonFormatter):
    def format(self, record: logging.LogRecord) -> str:
        try:
            return super().format(record)
        except ValueError:  # NaN/inf in the status: JSON has none, write null
            status = getattr(record, "status", None)
            if isinstance(status, dict):
                record.status = {k: _finite_or_none(v) for k, v in status.items()}
            return super().format(record)


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float) and (value != value or value in (float("inf"), float("-inf"))):
        return None
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    return value


def setup_logging(verbosity: int = 0, log_format: str = "text", stream: Any = None) -> logging.Logger:
    """Configure the ``mavahrs`` logger (library code only uses ``logging.getLogger``).

    Args:
        verbosity: −2 errors only, −1 warnings, 0 info (status lines), ≥ 1 debug.
        log_format: ``"text"`` (time, level, message) or ``"json"`` (one object per line).
        stream: where to write (default: standard error).
    """
    level = {-2: logging.ERROR, -1: logging.WARNING, 0: logging.INFO}.get(
        max(-2, min(0, verbosity)), logging.INFO
    )
    if verbosity >= 1:
        level = logging.DEBUG
    logger = logging.getLogger(_LOGGER_NAME)
    for h in list(logger.handlers):
        if getattr(h, "_mavahrs_cli", False):
            logger.removeHandler(h)
    handler = logging.StreamHandler(stream if stream is not None else sys.stderr)
    handler._mavahrs_cli = True  # type: ignore[attr-defined]
    if log_format == "json":
        handler.setFormatter(_NanSafeJson())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s.%(msecs)03d %(levelname)s %(message)s", "%H:%M:%S"))
    logger.addHandler(handler)
    logger.setLevel(level)
    logger.propagate = False
    return logger


def add_logging_options(parser: argparse.ArgumentParser, *, suppress: bool = False) -> None:
    """``-v``, ``-q``, ``--log-format`` (``suppress``: for subcommands, so the top-level value stays)."""
    default: Any = argparse.SUPPRESS if suppress else 0
    parser.add_argument("-v", "--verbose", action="count", default=default, help="more output (debug messages)")
    parser.add_argument("-q", "--quiet", action="count", default=default, help="less output (-q warnings, -qq errors)")
    parser.add_argument(
        "--log-format",
        choices=("text", "json"),
        default=argparse.SUPPRESS if suppress else "text",
        help="log line format: text, or json (one object per line, for journald and log collectors); "
        "default text",
    )


#: ``velocity_source`` values (mavahrs.sensors.velocity.VELOCITY_SOURCES; spelled out so that ``--help``
#: needs no numpy import; a test keeps the two equal)
VELOCITY_SOURCE_CHOICES = ("auto", "global_position_int", "gps_raw_int", "gps2_raw", "none")


def add_velocity_source_option(parser: Any, *, default_text: str = "auto") -> None:
    """``--velocity-source``: which GNSS velocity aids the filter (run, replay, evaluate)."""
    parser.add_argument(
        "--velocity-source", choices=VELOCITY_SOURCE_CHOICES, metavar="SOURCE",
        help="GNSS velocity for the filter: auto (GLOBAL_POSITION_INT while it arrives, else GPS_RAW_INT, "
        "else GPS2_RAW), global_position_int, gps_raw_int, gps2_raw (the receiver's own: independent of "
        f"the autopilot's EKF; no vertical) or none (default: {default_text})",
    )  # fmt: skip


# --------------------------------------------------------------------------- options


class FilterNames(argparse.Action):
    """``--filter``: repeatable, and each value may list several names (``-f mahony,best``)."""

    def __call__(self, parser: Any, namespace: argparse.Namespace, values: Any, option_string: Any = None) -> None:
        names = [n.strip() for n in str(values).split(",") if n.strip()]
        if not names:
            parser.error(f"{option_string}: no filter name given")
        setattr(namespace, self.dest, [*(getattr(namespace, self.dest, None) or []), *names])


def parse_source(text: str) -> tuple[int, int | None]:
    """``SYSID`` or ``SYSID:COMPID`` (MAVLink ids 1–255) → (system, component or None)."""
    parts = text.split(":")
    try:
        if len(parts) > 2:
            raise ValueError
        ids = [int(x) for x in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SYSID or SYSID:COMPID, e.g. 1 or 1:1; got {text!r}") from None
    if not all(1 <= i <= 255 for i in ids):
        raise argparse.ArgumentTypeError(f"MAVLink system and component ids are 1–255; got {text!r}")
    return ids[0], (ids[1] if len(ids) == 2 else None)


def add_source_option(parser: Any) -> None:
    """``--source SYSID[:COMPID]``: whose IMU data to use (replay, evaluate, tune, plot, run)."""
    parser.add_argument(
        "--source", type=parse_source, metavar="SYSID[:COMPID]",
        help="use the IMU data of this system (and component) only, e.g. 1 or 1:1 (default: the first "
        "autopilot HEARTBEAT's; in a log without HEARTBEAT, the only sender of IMU data)",
    )  # fmt: skip


# --------------------------------------------------------------------------- help


class LazyDefaultsFormatter(argparse.RawDescriptionHelpFormatter):
    """Expands ``{daemon.KEY}`` / ``{pipeline.KEY}`` / ``{filters}`` in help texts when help is printed.

    Defaults live in the settings dataclasses, whose modules import numpy;
    reading them only when ``--help`` is actually shown keeps ``mavahrs
    --help`` fast and the help text true to the code.
    """

    _PLACEHOLDER = re.compile(r"\{(daemon|pipeline)\.([a-z0-9_]+)\}|\{filters\}")

    def _expand_help(self, action: argparse.Action) -> str:
        text = super()._expand_help(action)
        return self._PLACEHOLDER.sub(_default_text, text)


def _default_text(m: re.Match[str]) -> str:
    try:
        if m.group(0) == "{filters}":
            from mavahrs.filters import ALIASES, NAMES

            return ", ".join((*ALIASES, *NAMES))
        section, key = m.group(1), m.group(2)
        if section == "daemon":
            from mavahrs.service.daemon import DaemonSettings as cls
        else:
            from mavahrs.service.pipeline import PipelineSettings as cls
        value = getattr(cls(), key)
    except Exception:  # noqa: BLE001 - help must print even if a module is missing
        return "?"
    if value is None:
        return "none"
    if isinstance(value, float) and value.is_integer():
        return str(int(value)) if abs(value) < 1e15 else repr(value)
    if isinstance(value, (tuple, list)):
        return ", ".join(map(str, value)) or "none"
    return str(value)
