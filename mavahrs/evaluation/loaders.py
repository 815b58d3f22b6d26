r"""Pick the right loader for an input path (file or folder).

* ``*.mat`` — a BROAD trial (:func:`~mavahrs.evaluation.datasets.load_broad_trial`);
* ``*.csv`` — a RepoIMU T-stick file (recognised by its ``Time (s);`` header)
  or a CSV with the documented columns (:data:`~mavahrs.evaluation.datasets.CSV_COLUMNS`);
* ``*.tlog`` — a MAVLink telemetry log whose reference is SIMSTATE (or SIM_STATE, HIL_STATE_QUATERNION)
  (:func:`~mavahrs.evaluation.tlogdata.load_tlog_recording`);
* a folder — every such file inside it (not recursive), sorted by name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mavahrs.errors import DataError
from mavahrs.evaluation.datasets import Recording, load_broad_trial, load_csv, load_repoimu_csv

__all__ = ["load_any", "SUFFIXES"]

SUFFIXES = (".mat", ".csv", ".tlog")

#: where a user who has only the repository gets the BROAD trials the README evaluates
BROAD_SOURCE = (
    "BROAD is not shipped with mavahrs: get the .mat trials and trials.json from GitHub, dlaidig/broad, "
    "folder data_mat/ (CC BY 4.0; cite Laidig et al., Data 6(7):72, 2021), see README 'Data and credits'"
)


def _missing(p: Path, what: str) -> DataError:
    hint = f"; {BROAD_SOURCE}" if "broad" in p.name.lower() else ""
    return DataError(f"{p}: {what}{hint}")


def _is_repoimu(path: Path) -> bool:
    with path.open("r", encoding="utf-8", errors="replace") as f:
        first = f.readline()
    return first.lower().startswith("time (s);")


def load_one(path: Path, **kwargs: Any) -> Recording:
    suffix = path.suffix.lower()
    if suffix == ".mat":
        return load_broad_trial(path)
    if suffix == ".csv":
        if _is_repoimu(path):
            return load_repoimu_csv(path, skip_s=float(kwargs.get("skip_s", 0.0)))
        return load_csv(
            path,
            earth_frame=str(kwargs.get("earth_frame", "NED")),
            heading_referenced=bool(kwargs.get("heading_referenced", True)),
        )
    if suffix == ".tlog":
        from mavahrs.evaluation.tlogdata import load_tlog_recording

        return load_tlog_recording(
            path, **{k: v for k, v in kwargs.items() if k in ("imu", "skip_s", "velocity_source", "source")}
        )
    raise DataError(f"{path}: unknown input type {suffix!r}; use .mat (BROAD), .csv or .tlog")


def load_any(path: str | Path, **kwargs: Any) -> list[Recording]:
    """Load one file, or every recognised file in a folder."""
    p = Path(path)
    if not p.exists():
        raise _missing(p, "no such file or folder")
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.suffix.lower() in SUFFIXES and f.is_file())
        if not files:
            raise _missing(p, "no .mat, .csv or .tlog files in this folder")
        return [load_one(f, **kwargs) for f in files]
    return [load_one(p, **kwargs)]
