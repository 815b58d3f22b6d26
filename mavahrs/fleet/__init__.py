r"""A fleet's logs: every flight replayed as the daemon would and summarised in one row.

* :mod:`mavahrs.fleet.audit` — :class:`~mavahrs.fleet.audit.FleetRow` (the row
  schema, fields and units documented), :func:`~mavahrs.fleet.audit.summarise_log`
  (a pure function of a path and the settings: :func:`mavahrs.replay.replay`, the
  second-opinion monitor's :func:`~mavahrs.service.monitor.monitor_series`, the
  clipping and vibration figures), the resumable Parquet/CSV table and the
  printed summary;
* :mod:`mavahrs.fleet.dask_engine` — the same tasks on Dask (a local cluster on
  all cores, or an existing scheduler); imported only when used, Dask being the
  optional ``fleet`` extra.

Beside :mod:`mavahrs.replay` in the layers: it uses replay, the CLI uses it.
"""

from __future__ import annotations
