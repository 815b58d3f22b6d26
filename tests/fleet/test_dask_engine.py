"""The Dask engine: a task whose worker process dies gives its own error result; the other tasks go on."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
for _module in ("distributed", "pyarrow"):
    pytest.importorskip(_module, reason="the fleet extra is not installed: pip install '.[fleet]'")


def _double_or_die(x: int) -> int:
    if x == 3:
        os._exit(13)  # the worker process dies, as on a crash in compiled code
    return 2 * x


def test_a_dead_worker_costs_one_task_not_the_batch(tmp_path: Path) -> None:
    import cloudpickle
    import dask

    from mavahrs.fleet.audit import lost_row
    from mavahrs.fleet.dask_engine import DaskEngine

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import this test module
    # a task whose worker died is given up (KilledWorker) after allowed-failures retries; with one task per
    # worker at a time (saturation 1) no other task is on the dying worker
    cfg = {"distributed.scheduler.allowed-failures": 0, "distributed.scheduler.worker-saturation": 1.0}
    with dask.config.set(cfg), DaskEngine(workers=2) as eng:
        out = dict(eng.map(_double_or_die, range(8), on_error=lambda item, exc: f"{item}: {type(exc).__name__}"))
        assert out == {i: "3: KilledWorker" if i == 3 else 2 * i for i in range(8)}
        with pytest.raises(ZeroDivisionError):  # without on_error the task's exception is raised
            list(eng.map(lambda x: 1 // x, [1, 0]))
    log = tmp_path / "a.tlog"
    log.write_bytes(b"x" * 10)
    row = lost_row(log, RuntimeError("worker gone"))
    assert (row.path, row.size_bytes, row.error) == (str(log), 10, "the task replaying this log failed: RuntimeError: worker gone")


def _numba_threads() -> str | None:
    return os.environ.get("NUMBA_NUM_THREADS")


def test_local_workers_run_one_numba_thread_and_this_process_is_left_alone() -> None:
    """One log per worker process is the parallelism: each local worker gets NUMBA_NUM_THREADS=1 (its own
    thread pool would compete with the other workers for the cores), and the calling process keeps its
    environment (numba refuses another thread count once its pool runs, so a leak breaks later sweeps)."""
    from mavahrs.fleet.dask_engine import DaskEngine

    before = os.environ.get("NUMBA_NUM_THREADS")
    with DaskEngine(workers=2) as eng:
        assert set(eng._client.run(_numba_threads).values()) == {"1"}
    assert os.environ.get("NUMBA_NUM_THREADS") == before


def test_a_local_cluster_leaves_nothing_in_the_temporary_directory(tmp_path: Path) -> None:
    """Dask's workers keep a scratch space (by default ``dask-scratch-space`` in the system's temporary
    directory, left behind); the engine gives them a folder of its own and removes it.  Run in a process
    of its own whose temporary directory is this test's (tests run in parallel)."""
    import subprocess

    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    code = (
        "from mavahrs.fleet.dask_engine import DaskEngine\n"
        "with DaskEngine(workers=1) as eng:\n"
        "    print(sorted(r for _, r in eng.map(abs, [-1, -2])))\n"
    )
    repo = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "TMPDIR": str(tmpdir), "PYTHONPATH": os.pathsep.join([repo, os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert run.returncode == 0 and run.stdout.strip() == "[1, 2]", run.stdout + run.stderr
    assert sorted(p.name for p in tmpdir.iterdir()) == []


def test_a_loopback_cluster_leaves_nothing_in_the_temporary_directory(tmp_path: Path) -> None:
    """``loopback_cluster`` (tests, bench_fleet): the ``dask scheduler`` and ``dask worker`` processes left
    ``dask-scratch-space`` with empty ``global.lock`` / ``purge.lock`` in the system's temporary directory; their
    scratch space is now inside the cluster's own work folder.  Processes of their own whose temporary
    directory is this test's."""
    import subprocess

    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    work = tmp_path / "cluster"
    code = (
        "from mavahrs.fleet.dask_engine import DaskEngine, loopback_cluster\n"
        f"with loopback_cluster({str(work)!r}, 1) as address, DaskEngine(scheduler=address) as eng:\n"
        "    print(sorted(r for _, r in eng.map(abs, [-1, -2])))\n"
    )
    repo = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "TMPDIR": str(tmpdir), "PYTHONPATH": os.pathsep.join([repo, os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert run.returncode == 0 and run.stdout.strip() == "[1, 2]", run.stdout + run.stderr
    assert sorted(p.name for p in tmpdir.iterdir()) == []
    assert (work / "scratch").is_dir()  # where it went instead (removed with the work folder)


def test_no_scheduler_at_the_address_fails_at_once_with_the_reason(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """`audit --scheduler tcp://127.0.0.1:PORT` with nothing listening waited silently for 60 s, then failed."""
    import socket
    import time

    from mavahrs.cli import main

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    log = tmp_path / "one.tlog"
    log.write_bytes(b"")
    t0 = time.monotonic()
    code = main(["audit", str(log), "--scheduler", f"tcp://127.0.0.1:{port}", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 3, err
    assert time.monotonic() - t0 < 30  # the client's own time-out was 60 s
    assert "scheduler" in err and f"127.0.0.1:{port}" in err and "refused" in err, err
