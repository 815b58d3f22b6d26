"""The first ``mavahrs audit`` on a machine (an empty kernel cache: ``NUMBA_CACHE_DIR`` of its own) says that it
compiles and what that cost, beside the replay time; the next one says it loaded the kernels.

Before, audit kept the ``mavahrs`` loggers at WARNING, so the compile notice never showed: a cold first run was
silent for minutes after "starting a local Dask cluster", and its summary gave only the replay time and rate.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mavahrs.cli.common import COMPILE_NOTICE
from mavahrs.fleet.audit import format_startup
from mavahrs.protocol.tlog import tlog_record
from mavahrs.warmup import synthetic_frames

REPO = Path(__file__).resolve().parents[2]


def test_startup_line_says_compiled_or_loaded_and_what_it_cost() -> None:
    cold = format_startup(95.4, 3.1, 95.0, 93.2, local=True)
    assert cold.startswith("start-up before the first log 95.4 s, not in the figures above: ")
    assert "starting the local cluster 3.1 s" in cold and "compiled once in this process in 93 s" in cold
    assert "first run on this machine and version" in cold and "mavahrs warm-up" in cold
    warm = format_startup(2.9, 2.9, 0.7, None, local=True)
    assert warm.endswith("starting the local cluster 2.9 s; meanwhile the filter kernels loaded from the cache in 0.7 s")
    remote = format_startup(0.4, 0.4, None, None, local=False)
    assert remote.endswith("connecting to the cluster 0.4 s")
    assert format_startup(None, None, None, None) == ""  # serial, warm: nothing before the first log
    assert "compiling the filter kernels" in format_startup(None, None, None, 41.0)  # serial, cold


@pytest.mark.slow
def test_a_cold_first_audit_says_it_compiles_and_what_the_start_up_cost(tmp_path: Path) -> None:
    for module in ("distributed", "pyarrow"):
        pytest.importorskip(module, reason="the fleet extra is not installed: pip install '.[fleet]'")
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache),
           "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}  # fmt: skip
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    logs = tmp_path / "logs"
    logs.mkdir()
    for k in range(2):
        (logs / f"flight{k}.tlog").write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames(3.0 + k)))

    def audit() -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "mavahrs", "audit", str(logs), "--workers", "1", "--no-progress"],
                              env=env, capture_output=True, text=True, timeout=900, cwd=tmp_path)  # fmt: skip

    cold = audit()
    assert cold.returncode == 0, cold.stderr
    assert [x for x in cold.stderr.splitlines() if x.endswith(" INFO " + COMPILE_NOTICE)], cold.stderr
    lines = cold.stdout.splitlines()
    assert lines[0].startswith("audited 2 logs (2 replayed, 0 already in the table) in "), cold.stdout
    m = re.fullmatch(r"start-up before the first log (\d+\.\d) s, not in the figures above: starting the local "
                     r"cluster \d+\.\d s; meanwhile the filter kernels compiled once in this process in (\d+) s, .*"
                     r"first run on this machine and version.*", lines[1])  # fmt: skip
    assert m is not None, cold.stdout
    assert float(m.group(2)) <= float(m.group(1)) + 1.0  # the compile is part of the start-up
    assert any(cache.iterdir())

    warm = audit()
    assert warm.returncode == 0, warm.stderr
    assert not [x for x in warm.stderr.splitlines() if x.endswith(" INFO " + COMPILE_NOTICE)], warm.stderr
    assert re.fullmatch(r"start-up before the first log \d+\.\d s, not in the figures above: starting the local "
                        r"cluster \d+\.\d s; meanwhile the filter kernels loaded from the cache in \d+\.\d s",
                        warm.stdout.splitlines()[1]), warm.stdout  # fmt: skip
