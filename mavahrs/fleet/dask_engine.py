r"""The fleet tasks on Dask: one task per log, results gathered as they complete.

Imported only by ``mavahrs audit`` and ``mavahrs tune`` when they run on Dask
(the optional ``fleet`` extra: ``pip install 'mavahrs[fleet]'``).

* no address: a :class:`distributed.LocalCluster` of ``workers`` processes
  (default: one per core) with one thread each — the filters are compiled
  numba kernels holding the GIL, so processes, not threads, scale;
* ``scheduler="tcp://HOST:8786"`` (or ``DASK_SCHEDULER_ADDRESS``, read by the
  CLI): an existing cluster; its workers must be able to import mavahrs and
  read the logs' paths.

Each worker process loads the filter kernels from numba's on-disk cache (or
compiles them once, 20–30 s); the connection time-outs are raised so that a
worker busy compiling is not taken for a dead one.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any

__all__ = ["available", "DaskEngine"]

#: Connection/heartbeat time-outs while a worker may be compiling kernels.
_TIMEOUTS = {
    "distributed.comm.timeouts.connect": "120s",
    "distributed.comm.timeouts.tcp": "300s",
    "distributed.scheduler.worker-ttl": "600s",
}


def available() -> bool:
    """Dask's distributed scheduler can be imported."""
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        return False
    return True


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

    def __enter__(self) -> DaskEngine:
        import dask
        from dask.distributed import Client, LocalCluster

        self._config = dask.config.set(_TIMEOUTS)
        self._config.__enter__()
        if self.scheduler:
            self._client = Client(self.scheduler, timeout="60s")
        else:
            self._cluster = LocalCluster(
                n_workers=self.workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                silence_logs=logging.ERROR,
            )  # fmt: skip
            self._client = Client(self._cluster)
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

    def describe(self) -> str:
        n = len(self._client.scheduler_info().get("workers", {})) if self._client is not None else 0
        where = f"the cluster at {self.scheduler}" if self.scheduler else "a local Dask cluster"
        return f"{where} ({n} worker{'s' if n != 1 else ''})"

    def on_every_worker(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` once in every worker process (e.g. load the filter kernels before timing)."""
        self._client.run(fn, *args)

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        """(index, fn(item)) as each task completes; a task's exception is raised here."""
        from dask.distributed import as_completed

        futures = self._client.map(fn, list(items), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures):
                yield index[fut.key], fut.result()
                fut.release()
        finally:
            self._client.cancel(futures)

