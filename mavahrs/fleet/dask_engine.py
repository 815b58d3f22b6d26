r"""The fleet tasks on Dask: one task per log, results gathered as they complete.

Imported only by ``mavahrs audit`` and ``mavahrs tune`` when they run on Dask
(the optional ``fleet`` extra: ``pip install 'mavahrs[fleet]'``).

* no address: a :class:`distributed.LocalCluster` of ``workers`` processes
  (default: one per core) with one thread each — the filters are compiled
  numba kernels holding the GIL, so processes, not threads, scale;
* ``scheduler="tcp://HOST:8786"`` (or ``DASK_SCHEDULER_ADDRESS``, read by the
  CLI): an existing cluster; its workers must be able to import mavahrs and
  read the logs' paths.

Each worker process loads the filter kernels from numba's on-disk cache (on a
cold cache ``mavahrs audit`` compiles them once in its own process while a local
cluster starts; a remote worker compiles them itself); the connection time-outs
are raised so that a worker busy compiling is not taken for a dead one.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["available", "DaskEngine", "loopback_cluster"]

#: Connection/heartbeat time-outs while a worker may be compiling kernels.
_TIMEOUTS = {
    "distributed.comm.timeouts.connect": "120s",
    "distributed.comm.timeouts.tcp": "300s",
    "distributed.scheduler.worker-ttl": "600s",
}
#: set in each local worker process (not in this one: Dask's "pre-spawn-environ" would set it here too, where
#: numba then refuses other thread counts): one log per worker process is the parallelism, and numba's own
#: thread pool (started when a batch path loads its parallel sweep loop) only competes with the other workers
#: for the cores (measured: 2 local workers on 2 cores 1.2x one worker with it, 1.9x without); Dask already
#: gives its workers OMP_NUM_THREADS=1 for the same reason
_WORKER_ENV = {"NUMBA_NUM_THREADS": "1"}


def available() -> bool:
    """Dask's distributed scheduler can be imported."""
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        return False
    return True


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail at once, with a clear reason, when nothing accepts connections at a ``tcp://HOST:PORT`` scheduler
    address (Dask's client would retry a refused connection silently for its whole 60 s time-out)."""
    import socket
    from urllib.parse import urlsplit

    from mavahrs.errors import TransportError

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme not in ("tcp", "tls") or not parts.hostname:
        return  # another transport (inproc, ucx, ws): Dask's client decides
    port = parts.port or 8786
    try:
        socket.create_connection((parts.hostname, port), timeout=timeout_s).close()
    except OSError as exc:
        reason = "connection refused" if isinstance(exc, ConnectionRefusedError) else (exc.strerror or str(exc))
        raise TransportError(
            f"no Dask scheduler at {address} ({reason}): start one there (`dask scheduler`) with workers "
            "(`dask worker ADDRESS`), or leave out --scheduler (and DASK_SCHEDULER_ADDRESS) for a local cluster"
        ) from None


class DaskEngine:
    """A Dask client, local or remote, mapping a function over items (one task each).

    Use as a context manager; :meth:`map` yields ``(index, result)`` in completion order.
    """

    def __init__(self, scheduler: str | None = None, workers: int | None = None) -> None:
        self.scheduler = scheduler
        self.workers = workers if workers is not None else (os.cpu_count() or 1)
        self._client: Any = None
        self._cluster: Any = None
        self._config: Any = None
        self._scratch: str | None = None

    def __enter__(self) -> DaskEngine:
        import dask
        from dask.distributed import Client, LocalCluster

        settings: dict[str, object] = dict(_TIMEOUTS)
        if not self.scheduler:
            # the local workers' scratch space (spilled data, locks; Dask's default: dask-scratch-space in
            # the system's temporary directory, left there) goes to a folder of its own, removed on exit
            self._scratch = tempfile.mkdtemp(prefix="mavahrs-dask-")
            settings["temporary-directory"] = self._scratch
        self._config = dask.config.set(settings)
        self._config.__enter__()
        log = logging.getLogger("mavahrs.fleet")  # audit keeps this one at INFO (the per-log lines: WARNING)
        if self.scheduler:
            try:
                _check_reachable(self.scheduler)
            except BaseException:
                self.__exit__(None, None, None)
                raise
            log.info("connecting to the Dask scheduler at %s …", self.scheduler)
            self._client = Client(self.scheduler, timeout="60s")
        else:
            log.info("starting a local Dask cluster of %d worker process%s …", self.workers,
                        "es" if self.workers != 1 else "")  # fmt: skip
            try:
                self._cluster = LocalCluster(
                    n_workers=self.workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                    silence_logs=logging.ERROR, env=_WORKER_ENV, local_directory=self._scratch,
                )  # fmt: skip
                self._client = Client(self._cluster)
            except BaseException:
                self.__exit__(None, None, None)
                raise
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            if self._client is not None:
                self._client.close()
            if self._cluster is not None:
                self._cluster.close()
        finally:
            if self._config is not None:
                self._config.__exit__(None, None, None)
                self._config = None
            if self._scratch is not None:
                shutil.rmtree(self._scratch, ignore_errors=True)
                self._scratch = None

    def describe(self) -> str:
        n = len(self._client.scheduler_info().get("workers", {})) if self._client is not None else 0
        where = f"the cluster at {self.scheduler}" if self.scheduler else "a local Dask cluster"
        return f"{where} ({n} worker{'s' if n != 1 else ''})"

    def on_every_worker(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` once in every worker process (e.g. load the filter kernels before timing)."""
        self._client.run(fn, *args)

    def map(
        self, fn: Callable[[Any], Any], items: Sequence[Any], *,
        on_error: Callable[[Any, BaseException], Any] | None = None,
    ) -> Iterator[tuple[int, Any]]:  # fmt: skip
        """(index, fn(item)) as each task completes.

        A task that failed — ``fn`` raised, or its worker died more often than
        Dask's ``allowed-failures`` (KilledWorker) — gives ``on_error(item,
        exception)`` instead, or raises here without ``on_error``.
        """
        from dask.distributed import as_completed

        items = list(items)
        futures = self._client.map(fn, items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures):
                i = index[fut.key]
                try:
                    result = fut.result()
                except Exception as exc:  # noqa: BLE001 - handed to on_error: one task never stops the rest
                    if on_error is None:
                        raise
                    result = on_error(items[i], exc)
                yield i, result
                fut.release()
        finally:
            self._client.cancel(futures)



@contextmanager
def loopback_cluster(
    workdir: str | Path, workers: int = 2, *, env: Mapping[str, str] | None = None, timeout_s: float = 120.0
) -> Iterator[str]:
    """A Dask scheduler and ``workers`` worker processes (one thread each) on 127.0.0.1, started with the
    ``dask`` command as one would on a cluster; yields the scheduler's address, stops them all on exit.

    For trying ``--scheduler`` on one machine, the tests and ``scripts/bench_fleet.py``.  ``env`` is the
    processes' environment (their PYTHONPATH must find mavahrs); their output goes to ``workdir/*.log``.
    """
    import json

    from dask.distributed import Client

    work = Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    sched_file = work / "scheduler.json"
    sched_file.unlink(missing_ok=True)
    procs: list[subprocess.Popen[bytes]] = []

    # one numba thread per worker process (see _WORKER_ENV): what a real cluster's workers should be given too;
    # the processes' scratch space (Dask's default: dask-scratch-space with its lock files in the system's
    # temporary directory, left there by the scheduler and the workers' nannies) inside workdir
    penv = {**(env if env is not None else os.environ), **_WORKER_ENV,
            "DASK_TEMPORARY_DIRECTORY": str(work / "scratch")}  # fmt: skip

    def start(name: str, *args: str) -> None:
        with open(work / f"{name}.log", "wb") as log:
            procs.append(subprocess.Popen([sys.executable, "-m", "dask", *args], stdout=log, stderr=subprocess.STDOUT,
                                          env=penv, cwd=work))  # fmt: skip

    try:
        start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--scheduler-file", str(sched_file))  # fmt: skip
        deadline = time.monotonic() + timeout_s
        while not sched_file.exists():
            if procs[0].poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the Dask scheduler did not start: {(work / 'scheduler.log').read_text()[-2000:]}")
            time.sleep(0.1)
        address = str(json.loads(sched_file.read_text())["address"])
        for k in range(workers):
            start(f"worker{k}", "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
                  "--local-directory", str(work / f"worker{k}"), "--name", f"worker{k}")  # fmt: skip
        with Client(address, timeout=f"{timeout_s:g}s") as client:
            client.wait_for_workers(workers, timeout=timeout_s)
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)
