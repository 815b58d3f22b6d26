"""The "still compiling" lines of a first compilation (:class:`mavahrs.cli.common.CompileProgress`).

A cold compile of ``mavahrs run`` took 5–6 minutes on the busy 2-core VM with nothing said after the
notice: the user took it for a hang. Here numba's own compile events are played to the listener (a
kernel of the package, a cached one) with a short interval; the lines are awaited, not timed. The whole
path on an empty cache (a real compilation, the notice, these lines, none on a warm cache) is in
test_cli_warm_up.py.
"""

from __future__ import annotations

import logging
import re
import time
from types import SimpleNamespace
from typing import Any

import pytest

from mavahrs.cli.common import KERNELS_LOGGER, CompileProgress, compile_progress_s

numba_event = pytest.importorskip("numba.core.event", reason="numba is not installed: nothing compiles")


def _event(module: str, cache: str = "FunctionCache") -> Any:
    py = SimpleNamespace(__module__=module, __qualname__="step")
    dispatcher = SimpleNamespace(py_func=py, _cache=type(cache, (), {})())
    return SimpleNamespace(data={"dispatcher": dispatcher})


def _lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith("still compiling")]


def _wait_for(caplog: pytest.LogCaptureFixture, n: int, deadline_s: float = 20.0) -> list[str]:
    end = time.monotonic() + deadline_s
    while len(_lines(caplog)) < n and time.monotonic() < end:
        time.sleep(0.01)
    return _lines(caplog)


def test_a_line_per_interval_while_compiling_and_none_once_done(caplog: pytest.LogCaptureFixture) -> None:
    progress = CompileProgress(0.2)
    listener = progress._listener  # noqa: SLF001 - the numba listener it registered
    try:
        with caplog.at_level(logging.INFO, logger=KERNELS_LOGGER):
            listener.on_start(_event("numpy.core"))  # not ours: no thread, nothing said
            listener.on_start(_event("mavahrs.service.fastlane", cache="NullCache"))  # an uncached driver loop
            assert progress.started == 0
            listener.on_start(_event("mavahrs.filters.eskf"))
            listener.on_start(_event("mavahrs.filters.kinematics"))  # nested in the first
            listener.on_end(_event("mavahrs.filters.kinematics"))
            lines = _wait_for(caplog, 2)
            assert len(lines) >= 2, lines
            assert re.fullmatch(r"still compiling the filter kernels: \d+ s so far, 1 compiled \(once for this "
                                r"version\) …", lines[0]), lines  # fmt: skip
            listener.on_end(_event("mavahrs.filters.eskf"))  # done: at most the line of the interval it ended in
            time.sleep(0.05)
            done = len(_wait_for(caplog, len(lines) + 1, deadline_s=0.5))
            time.sleep(1.0)  # five quiet intervals
            assert len(_lines(caplog)) == done
            assert progress.ended == 2
    finally:
        progress.close()
    assert progress._listener is None  # noqa: SLF001 - unregistered


def test_the_interval_can_be_set_for_tests(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MAVAHRS_COMPILE_PROGRESS_S", "2.5")
    assert compile_progress_s() == 2.5
    for bad in ("0", "-1", "soon"):
        monkeypatch.setenv("MAVAHRS_COMPILE_PROGRESS_S", bad)
        assert compile_progress_s() == 30.0
