"""The start-up line of ``mavahrs audit``: whether the kernels compiled or loaded, and what that cost.

A cold first audit on a machine (an empty kernel cache) is run in tests/cli/test_cli_warm_up.py, inside the
suite's one cold compile.

Before, audit kept the ``mavahrs`` loggers at WARNING, so the compile notice never showed: a cold first run was
silent for minutes after "starting a local Dask cluster", and its summary gave only the replay time and rate.
"""

from __future__ import annotations

from mavahrs.fleet.audit import format_startup


def test_startup_line_says_compiled_or_loaded_and_what_it_cost() -> None:
    cold = format_startup(95.4, 3.1, 95.0, 93.2, local=True)
    assert cold.startswith("start-up before the first log 95.4 s, not in the figures above: ")
    assert "starting the local cluster 3.1 s" in cold and "compiled once in this process in 93 s" in cold
    assert "first run of this version" in cold and "mavahrs warm-up" in cold
    warm = format_startup(2.9, 2.9, 0.7, None, local=True)
    assert warm.endswith("starting the local cluster 2.9 s; meanwhile the filter kernels loaded from the cache in 0.7 s")
    remote = format_startup(0.4, 0.4, None, None, local=False)
    assert remote.endswith("connecting to the cluster 0.4 s")
    assert format_startup(None, None, None, None) == ""  # serial, warm: nothing before the first log
    assert "compiling the filter kernels" in format_startup(None, None, None, 41.0)  # serial, cold
