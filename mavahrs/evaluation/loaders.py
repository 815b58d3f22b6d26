r"""Pick the right loader for an input path (file or folder).

* ``*.mat`` — a BROAD trial (:func:`~mavahrs.evaluation.datasets.load_broad_trial`);
* ``*.csv`` — a RepoIMU T-stick file (recognised by its ``Time (s);`` header)
  or a CSV with the documented columns (:data:`~mavahrs.evaluation.datasets.CSV_COLUMNS`);
* a flight log, recognised by its content whatever its name (:func:`mavahrs.logs.sniff`): a MAVLink
  telemetry log whose reference is SIMSTATE (or SIM_STATE, HIL_STATE_QUATERNION)
  (:func:`~mavahrs.evaluation.tlogdata.load_tlog_recording`), an ArduPilot DataFlash log (SIM truth)
  or a PX4 ULog (``vehicle_attitude_groundtruth``) (:func:`load_onboard_recording`);
* a folder — every such file inside it (not recursive), sorted by name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mavahrs.errors import DataError
from mavahrs.evaluation.datasets import Recording, load_broad_trial, load_csv, load_repoimu_csv

__all__ = ["load_any", "SUFFIXES"]

SUFFIXES = (".mat", ".csv", ".tlog", ".bin", ".ulg")

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


def load_onboard_recording(
    path: str | Path,
    *,
    imu: str = "auto",
    reference: bool = True,
    skip_s: float = 0.0,
    velocity_source: str = "auto",
    source: tuple[int, int | None] | None = None,  # noqa: ARG001 - an onboard log has one vehicle
) -> Recording:
    """A DataFlash or ULog log as an evaluation :class:`Recording`: its reader's filter inputs
    (:func:`mavahrs.logs.read_log`), the simulator's truth as the reference (SIM, ``vehicle_attitude_groundtruth``)."""
    from mavahrs.evaluation.tlogdata import recording_from_inputs
    from mavahrs.logs import read_log
    from mavahrs.service.pipeline import PipelineSettings

    li = read_log(path, PipelineSettings(imu=imu, velocity_source=velocity_source))
    return recording_from_inputs(
        Path(path).stem, li.inputs, li.references if reference else None, skip_s=skip_s, groups=(li.format,),
        no_truth="no simulator truth (DataFlash SIM, ULog vehicle_attitude_groundtruth) in this log: nothing to "
        "score against (an autopilot's own estimate is not ground truth)",
    )  # fmt: skip


def load_one(path: Path, **kwargs: Any) -> Recording:
    """One input, a flight log by its content (any name), else a .mat or .csv recording by its suffix."""
    from mavahrs.logs import FORMATS, sniff

    fmt = sniff(path)
    log_kw = {k: v for k, v in kwargs.items() if k in ("imu", "skip_s", "velocity_source", "source", "reference")}
    if fmt == "tlog":
        from mavahrs.evaluation.tlogdata import load_tlog_recording

        return load_tlog_recording(path, **log_kw)
    if fmt in ("dataflash", "ulog"):
        return load_onboard_recording(path, **log_kw)
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
            skip_s=float(kwargs.get("skip_s", 0.0)),
        )
    if suffix == ".tlog":
        from mavahrs.evaluation.tlogdata import load_tlog_recording

        return load_tlog_recording(path, **log_kw)  # its reader says what is wrong with it
    from mavahrs.logs import unsupported_message

    why = unsupported_message(path)
    raise DataError(f"{why}; or a recording with ground truth: .mat (BROAD), .csv (RepoIMU or documented columns)"
                    if why.endswith(", ".join(FORMATS.values())) else why)  # fmt: skip


def folder_files(folder: Path) -> tuple[list[Path], list[Path]]:
    """A folder's files that :func:`load_any` takes (by suffix, or a log by its content) and the ones it skips."""
    from mavahrs.logs import sniff

    taken, skipped = [], []
    for f in sorted(f for f in folder.iterdir() if f.is_file()):
        (taken if f.suffix.lower() in SUFFIXES or sniff(f) else skipped).append(f)
    return taken, skipped


def load_any(path: str | Path, **kwargs: Any) -> list[Recording]:
    """Load one file, or every recognised file in a folder."""
    p = Path(path)
    if not p.exists():
        raise _missing(p, "no such file or folder")
    if p.is_dir():
        files, _ = folder_files(p)
        if not files:
            raise _missing(p, "no .mat, .csv, .tlog, .BIN or .ulg files in this folder")
        recs = [load_one(f, **kwargs) for f in files]
        # one flight's .tlog and .BIN share a stem: name both by their file name, else the tables show it twice
        stems = [r.name for r in recs]
        for f, r in zip(files, recs, strict=True):
            if stems.count(r.name) > 1:
                r.name = f.name
        return recs
    return [load_one(p, **kwargs)]
