r"""Score filters against a reference the way the papers do, and print the tables.

For each recording and filter:

* the filter runs over the **whole** recording (batch path, the same kernel as
  the daemon), 9-axis when the recording has a magnetometer (``use_mag``);
* the reference is aligned as the dataset requires
  (:mod:`mavahrs.evaluation.alignment`; ``"auto"``: nothing for a
  north-referenced reference scored 9-axis, a fitted heading offset otherwise);
* on the scored samples with a reference: BROAD's total / heading /
  inclination RMS (:func:`~mavahrs.evaluation.metrics.summarize`); per-angle
  roll / pitch / yaw RMS at rest (< 5°/s) and in motion (≥ 5°/s) (Madgwick
  2010, Table 1); per-angle mean and SD (Ermakov & Gogolev 2022, Table 2).

Several recordings (a BROAD folder) are combined as BROAD does: the plain
mean over recordings of each per-recording figure.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.evaluation.alignment import ALIGNMENTS, Alignment, fit_alignment
from mavahrs.evaluation.datasets import Recording
from mavahrs.evaluation.metrics import (
    AngleStats,
    angle_stats,
    euler_errors_rad,
    motion_mask,
    summarize,
)
from mavahrs.filters.base import FilterSettings, make_inputs
from mavahrs.filters.layout import IN_CURRENT, IN_POS, OUT_Q, OUT_WIDTH

__all__ = [
    "FilterScore",
    "RecordingReport",
    "EvaluationReport",
    "resolve_filter_names",
    "run_filter",
    "choose_alignment",
    "score_estimate",
    "evaluate_recording",
    "evaluate_recordings",
    "format_report",
]

Array = NDArray[np.float64]
ANGLES = ("roll", "pitch", "yaw")


def resolve_filter_names(names: list[str] | tuple[str, ...] | None) -> list[str]:
    """Expand ``all`` (every registered filter plus ``best``) and check the names."""
    from mavahrs.filters import ALIASES, NAMES, filter_class

    if not names:
        return ["best"] if _has_best() else [NAMES[0]]
    out: list[str] = []
    for name in names:
        if name == "all":
            extra = [n for n in NAMES if _importable(n)]
            if _has_best():
                extra.append("best")
            out += [n for n in extra if n not in out]
        elif name in NAMES or name in ALIASES:
            if name in NAMES:
                filter_class(name)  # raises a clear error if the module is missing
            if name not in out:
                out.append(name)
        else:
            raise ValueError(f"unknown filter {name!r}; choose from {', '.join(NAMES + ALIASES)} or all")
    return out


def _importable(name: str) -> bool:
    from mavahrs.filters import filter_class

    try:
        filter_class(name)
    except (ImportError, AttributeError):
        return False
    return True


def _has_best() -> bool:
    import importlib.util

    return importlib.util.find_spec("mavahrs.filters.best") is not None


def run_filter(
    rec: Recording,
    name: str,
    settings: FilterSettings | None = None,
    *,
    use_mag: bool = True,
) -> Array:
    """Run one filter over a whole recording; the (N, OUT_WIDTH) output rows."""
    from mavahrs.filters import create

    mag = rec.mag_ut if use_mag else None
    vel = rec.extra.get("velocity_ned_m_s")
    inputs = make_inputs(
        rec.gyro_rad_s, rec.accel_m_s2, mag, dt_s=rec.dt_s, velocity_ned_m_s=vel,
        velocity_age_s=rec.extra.get("velocity_age_s") if vel is not None else None,
    )  # fmt: skip
    for key, col, width in (("current_a", IN_CURRENT, 1), ("position_ned_m", IN_POS, 3)):
        values = rec.extra.get(key)  # a flight log's other chain columns, as replay feeds them
        if values is not None and len(values) == inputs.shape[0]:
            inputs[:, col : col + width] = np.asarray(values, dtype=np.float64).reshape(inputs.shape[0], width)
    f = create(name, settings)
    if "sensor_delay_s" in rec.extra:  # a flight log: the filter is told what the daemon's pipeline tells it
        from mavahrs.ingest.arrays import configure_filter

        configure_filter(f, float(rec.extra["sensor_delay_s"]), bool(rec.extra.get("vehicle_stream")),  # type: ignore[arg-type]
                         bool(rec.extra.get("multirotor")))  # fmt: skip
    elif rec.extra.get("multirotor") and hasattr(f, "set_multirotor"):  # a raw recording declared a multirotor
        f.set_multirotor()
    events = rec.extra.get("mag_reference_events") or ()
    # a flight log in which the autopilot rebooted: the filter starts again at each boot, as the daemon's
    # pipeline restarts it (until user7 it ran on through the reboot: 132° on the second boot of two
    # firmware_sim flights written one after the other)
    boots = [int(i) for i in (rec.extra.get("boot_starts") or ())]
    if not events and not boots:
        return f.run(inputs)
    # a tlog: seed the magnetometer rejection where the daemon's pipeline would (WMM field known)
    out = np.empty((inputs.shape[0], OUT_WIDTH))
    cuts = sorted({0, inputs.shape[0], *boots, *(min(max(int(i), 0), inputs.shape[0]) for i, _, _ in events)})
    for lo, hi in itertools.pairwise(cuts):
        if lo in boots:
            f.reset()
        for i, norm, dip in events:
            if max(int(i), 0) == lo:
                f.set_mag_reference(norm, dip)
        f.run(inputs[lo:hi], out[lo:hi])
    return out


def choose_alignment(rec: Recording, use_mag: bool, requested: str = "auto") -> str:
    """The alignment mode for ``auto``: none when the reference is north-referenced and
    the filter uses the magnetometer, else a fitted heading offset."""
    if requested != "auto":
        if requested not in ALIGNMENTS:
            raise ValueError(f"unknown alignment {requested!r}; choose auto or one of {', '.join(ALIGNMENTS)}")
        return requested
    if rec.heading_referenced and use_mag and rec.mag_ut is not None:
        return "none"
    return "heading"


def _tuple3(x: tuple[float, float, float]) -> list[float | None]:
    return [None if not math.isfinite(v) else round(v, 6) for v in x]


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else round(float(x), 6)


@dataclass(frozen=True)
class FilterScore:
    """One filter's figures on one recording (degrees).

    Attributes:
        filter: filter name.
        axes: 9 with magnetometer, 6 without.
        alignment: the constant rotations applied to the reference.
        total_rms_deg, heading_rms_deg, inclination_rms_deg: BROAD's definitions.
        rest, motion, overall: per-angle statistics at rest (< 5°/s), in
            motion (≥ 5°/s) and over all scored samples.
    """

    filter: str
    axes: int
    alignment: Alignment
    total_rms_deg: float
    heading_rms_deg: float
    inclination_rms_deg: float
    rest: AngleStats
    motion: AngleStats
    overall: AngleStats
    samples: int

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "axes": self.axes,
            "alignment": self.alignment.mode,
            "heading_offset_deg": _num(self.alignment.heading_offset_deg),
            "body_misalignment_deg": _num(self.alignment.body_misalignment_deg),
            "total_rms_deg": _num(self.total_rms_deg),
            "heading_rms_deg": _num(self.heading_rms_deg),
            "inclination_rms_deg": _num(self.inclination_rms_deg),
            "samples": self.samples,
            "rest_samples": self.rest.samples,
            "motion_samples": self.motion.samples,
        }
        for i, angle in enumerate(ANGLES):
            d[f"{angle}_rms_rest_deg"] = _num(self.rest.rms_deg[i])
            d[f"{angle}_rms_motion_deg"] = _num(self.motion.rms_deg[i])
            d[f"{angle}_rms_deg"] = _num(self.overall.rms_deg[i])
            d[f"{angle}_mean_deg"] = _num(self.overall.mean_deg[i])
            d[f"{angle}_sd_deg"] = _num(self.overall.sd_deg[i])
            d[f"{angle}_max_abs_deg"] = _num(self.overall.max_abs_deg[i])
        return d


@dataclass
class RecordingReport:
    """All filters' scores on one recording, plus notes for the reader."""

    name: str
    scores: dict[str, FilterScore] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    scored_seconds: float = 0.0
    #: a robustness case (e.g. gyro clipping): reported, but left out of the mean
    robustness_only: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            "notes": self.notes,
            "in_mean": not self.robustness_only,
            "scored_s": round(self.scored_seconds, 3),
            "filters": {n: s.to_dict() for n, s in self.scores.items()},
        }


@dataclass
class EvaluationReport:
    """Scores over one or more recordings; ``mean`` is BROAD's plain mean over recordings."""

    input: str
    recordings: list[RecordingReport] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def filter_names(self) -> list[str]:
        names: list[str] = []
        for r in self.recordings:
            names += [n for n in r.scores if n not in names]
        return names

    def averaged(self) -> list[RecordingReport]:
        """The recordings in the mean: all scored ones except robustness cases (if any others)."""
        scored = [r for r in self.recordings if r.scores]
        kept = [r for r in scored if not r.robustness_only]
        return kept or scored

    def mean(self) -> dict[str, dict[str, Any]]:
        """Per filter: the mean over recordings of every numeric figure (NaN ignored)."""
        out: dict[str, dict[str, Any]] = {}
        for name in self.filter_names():
            dicts = [r.scores[name].to_dict() for r in self.averaged() if name in r.scores]
            if not dicts:
                continue
            merged: dict[str, Any] = {"recordings": len(dicts)}
            for key, value in dicts[0].items():
                if key in ("alignment",):
                    modes = sorted({d[key] for d in dicts})
                    merged[key] = modes[0] if len(modes) == 1 else modes
                elif isinstance(value, (int, float)) or value is None:
                    vals = [d[key] for d in dicts if d[key] is not None]
                    if key.endswith("samples"):
                        merged[key] = int(sum(vals))
                    elif key == "axes":
                        merged[key] = value
                    else:
                        merged[key] = round(float(np.mean(vals)), 6) if vals else None
            out[name] = merged
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "input": self.input,
            "recordings": len(self.recordings),
            "notes": self.notes,
            "filters": self.mean(),
            "per_recording": {r.name: r.to_dict() for r in self.recordings},
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False)


def score_estimate(
    q_est: Array,
    rec: Recording,
    *,
    filter_name: str = "estimate",
    axes: int = 9,
    alignment: str = "none",
    moving: NDArray[np.bool_] | None = None,
) -> FilterScore:
    """Score an (N, 4) estimate against the recording's reference over its scored samples."""
    ref = rec.q_ref_body_to_ned
    scored = np.asarray(rec.scored, dtype=bool) & np.all(np.isfinite(ref), axis=1)
    align = fit_alignment(q_est, ref, scored, mode=alignment)
    ref_aligned = align.apply(ref) if align.mode != "none" else ref
    summary = summarize(q_est, ref_aligned, scored)
    euler = euler_errors_rad(q_est, ref_aligned)
    if moving is None:
        moving = motion_mask(rec.gyro_rad_s, rec.dt_s)
    return FilterScore(
        filter=filter_name,
        axes=axes,
        alignment=align,
        total_rms_deg=summary.total_rms_deg,
        heading_rms_deg=summary.heading_rms_deg,
        inclination_rms_deg=summary.inclination_rms_deg,
        rest=angle_stats(euler, scored & ~moving),
        motion=angle_stats(euler, scored & moving),
        overall=angle_stats(euler, scored),
        samples=summary.samples,
    )


def evaluate_recording(
    rec: Recording,
    filters: list[str],
    *,
    use_mag: bool = True,
    alignment: str = "auto",
    settings: dict[str, FilterSettings] | None = None,
) -> RecordingReport:
    """Run and score each filter on one recording."""
    report = RecordingReport(name=rec.name)
    has_ref = bool(np.all(np.isfinite(rec.q_ref_body_to_ned), axis=1).any())
    if not has_ref:
        report.notes += [str(n) for n in rec.extra.get("notes", ())]  # type: ignore[attr-defined]  # (why: the loader's)
        if not any("nothing is scored" in n for n in report.notes):  # the loader said why already
            report.notes.append("no reference attitude in this recording: nothing to score")
        return report
    clipped = int(rec.extra.get("gyro_clipped_samples", 0) or 0)  # type: ignore[call-overload]
    if clipped:
        report.robustness_only = True
        report.notes.append(
            f"gyro clipping: {clipped} samples at the sensor's range limit — a robustness case, "
            "not an accuracy case (left out of the mean)"
        )
    for note in rec.extra.get("notes", ()):  # type: ignore[attr-defined]
        report.notes.append(str(note))
    mag = use_mag and rec.mag_ut is not None
    mode = choose_alignment(rec, mag, alignment)
    moving = motion_mask(rec.gyro_rad_s, rec.dt_s)
    scored = np.asarray(rec.scored, dtype=bool)
    report.scored_seconds = float(np.nansum(np.where(scored, rec.dt_s, 0.0)))
    for name in filters:
        s = (settings or {}).get(name)
        out = run_filter(rec, name, s, use_mag=mag)
        report.scores[name] = score_estimate(
            out[:, OUT_Q : OUT_Q + 4], rec, filter_name=name, axes=9 if mag else 6,
            alignment=mode, moving=moving,
        )  # fmt: skip
    return report


def evaluate_recordings(
    recordings: list[Recording],
    filters: list[str],
    *,
    input_name: str = "",
    use_mag: bool = True,
    alignment: str = "auto",
    settings: dict[str, FilterSettings] | None = None,
    progress: bool = False,
) -> EvaluationReport:
    """Evaluate every filter on every recording."""
    report = EvaluationReport(input=input_name)
    it: Any = recordings
    if progress and len(recordings) > 1:
        from tqdm import tqdm

        it = tqdm(recordings, desc="evaluating", unit="rec", leave=False)
    for rec in it:
        report.recordings.append(
            evaluate_recording(rec, filters, use_mag=use_mag, alignment=alignment, settings=settings)
        )
    return report


# --------------------------------------------------------------------------- text


def _f(x: float | None, width: int = 6) -> str:
    if x is None or not math.isfinite(x):
        return "—".rjust(width)
    return f"{x:{width}.2f}"


def _table(rows: dict[str, dict[str, Any]], title: str) -> list[str]:
    lines = [title]
    head = (
        f"{'filter':<14}{'axes':>5} {'total':>6} {'head':>6} {'incl':>6} │"
        f" {'rest RMS r/p/y':>20} │ {'motion RMS r/p/y':>20} │ {'mean r/p/y':>20} │ {'SD r/p/y':>20}"
    )
    lines.append(head)
    lines.append("─" * len(head))
    for name, d in rows.items():

        def three(kind: str, d: dict[str, Any] = d) -> str:
            return " ".join(_f(d.get(f"{a}_{kind}")) for a in ANGLES)

        lines.append(
            f"{name:<14}{d.get('axes', ''):>5} {_f(d.get('total_rms_deg'))} {_f(d.get('heading_rms_deg'))}"
            f" {_f(d.get('inclination_rms_deg'))} │ {three('rms_rest_deg')} │ {three('rms_motion_deg')} │"
            f" {three('mean_deg')} │ {three('sd_deg')}"
        )
    return lines


def format_report(report: EvaluationReport, *, per_recording: bool | None = None) -> str:
    """The papers' tables as text: per recording (if several, optional) and the mean."""
    lines: list[str] = []
    if per_recording is None:
        per_recording = len(report.recordings) <= 3
    multi = len(report.recordings) > 1
    if per_recording or not multi:
        for r in report.recordings:
            lines.append("")
            lines.append(f"== {r.name}  (scored {r.scored_seconds:.1f} s)")
            for note in r.notes:
                lines.append(f"   note: {note}")
            if r.scores:
                aligns = {s.alignment.describe() for s in r.scores.values()}
                if len(aligns) == 1:
                    lines.append(f"   alignment: {aligns.pop()}")
                else:
                    for s in r.scores.values():
                        lines.append(f"   alignment ({s.filter}): {s.alignment.describe()}")
                lines += ["   " + x for x in _table({n: s.to_dict() for n, s in r.scores.items()}, "")[1:]]
    if multi:
        lines.append("")
        n_mean = len(report.averaged())
        left_out = len(report.recordings) - n_mean
        lines.append(
            f"== mean over {n_mean} recordings (BROAD: plain mean of per-trial RMS)"
            + (f"; {left_out} left out (no reference or robustness case, marked *)" if left_out else "")
        )
        if not per_recording:
            lines.append("   per recording, total RMS (deg):")
            names = report.filter_names()
            lines.append("   " + f"{'recording':<46}" + "".join(f"{n:>14}" for n in names))
            in_mean = {id(r) for r in report.averaged()}
            for r in report.recordings:
                cells = "".join(
                    f"{_f(r.scores[n].total_rms_deg, 14) if n in r.scores else '—':>14}" for n in names
                )
                flag = " *" if id(r) not in in_mean else ""  # the mark the heading's "left out" count refers to
                lines.append("   " + f"{r.name[:46]:<46}" + cells + flag)
            if left_out:
                lines.append("   * left out of the mean: see its notes (--json or --per-recording)")
        modes = sorted({s.alignment.mode for r in report.recordings for s in r.scores.values()})
        lines.append(f"   alignment: {', '.join(modes)} (per recording and filter; see --json)")
        lines += ["   " + x for x in _table(report.mean(), "")[1:]]
    lines.append("")
    lines.append(
        "Degrees.  total/head/incl = BROAD's total, heading and inclination RMS on scored samples;"
    )
    lines.append(
        "rest/motion = per-angle RMS below/above 5°/s (Madgwick 2010 Table 1); mean/SD per angle "
        "(2022 Table 2); angles = Euler angles of the body-frame error q_ref*⊗q_est."
    )
    for note in report.notes:
        lines.append(f"note: {note}")
    return "\n".join(lines).lstrip("\n")


def load_inputs(path: str | Path, **kwargs: Any) -> list[Recording]:
    """Recordings from a BROAD ``.mat``, a RepoIMU or documented CSV, a tlog, or a folder of them."""
    from mavahrs.evaluation.loaders import load_any

    return load_any(path, **kwargs)
