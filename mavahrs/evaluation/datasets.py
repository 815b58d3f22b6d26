r"""Loaders for reference datasets; frame conversion happens once, here.

Every loader returns a :class:`Recording`: sensor arrays in SI units in the
sensor's own axes, and a reference attitude ``q_ref_body_to_ned`` (NaN rows
where there is none).  Where the dataset's earth frame is not NED it is
converted here (``../shared/data/README.md`` documents each dataset's frames).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import DataError
from mavahrs.geometry.frames import convert_earth_frame

__all__ = [
    "Recording",
    "load_broad_trial",
    "broad_trial_groups",
    "find_broad_trials",
    "load_repoimu_csv",
    "REPOIMU_GYRO_LIMIT_RAD_S",
    "load_csv",
    "CSV_COLUMNS",
    "write_csv_recording",
]

Array = NDArray[np.float64]


@dataclass
class Recording:
    """A recording with a reference attitude.

    Attributes:
        name: trial or file name.
        dt_s: (N,) sample intervals, s (first = nominal interval).
        gyro_rad_s, accel_m_s2: (N, 3) in the sensor's axes.
        mag_ut: (N, 3) or None.
        q_ref_body_to_ned: (N, 4) reference attitude, NaN rows where missing.
        scored: (N,) bool, the samples a benchmark scores.
        groups: dataset group tags (e.g. BROAD's ``undisturbed``, ``rotation``).
        heading_referenced: True when the reference's north is the
            magnetometer's north, so 9-axis heading is comparable directly.
    """

    name: str
    dt_s: Array
    gyro_rad_s: Array
    accel_m_s2: Array
    mag_ut: Array | None
    q_ref_body_to_ned: Array
    scored: NDArray[np.bool_]
    groups: tuple[str, ...] = ()
    heading_referenced: bool = True
    extra: dict[str, object] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.gyro_rad_s.shape[0])


def broad_trial_groups(broad_dir: Path) -> dict[str, tuple[str, ...]]:
    """Trial name → group tags from BROAD's ``trials.json`` (empty if absent)."""
    path = Path(broad_dir) / "trials.json"
    if not path.exists():
        return {}
    data = json.loads(path.read_text())
    out: dict[str, tuple[str, ...]] = {}
    for name, trial in data.get("trials", {}).items():
        out[name] = tuple(trial.get("groups", ()))
    return out


def load_broad_trial(path: str | Path) -> Recording:
    """Load one BROAD ``.mat`` trial; the ENU reference is converted to NED.

    BROAD's IMU axes are kept as they are (the body frame is the sensor's); the
    accelerometer reads specific force (+9.8 on the up axis at rest) as
    mavahrs expects; north is the magnetometer's north.
    """
    try:
        from scipy.io import loadmat
    except ImportError as exc:  # pragma: no cover
        raise DataError("reading BROAD .mat files needs scipy (pip install scipy)") from exc
    path = Path(path)
    try:
        d = loadmat(str(path))
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: not a readable MATLAB file ({exc})") from exc
    for key in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate"):
        if key not in d:
            raise DataError(f"{path}: missing variable {key!r}; is this a BROAD trial?")
    rate = float(np.asarray(d["sampling_rate"]).ravel()[0])
    if abs(rate - 2000.0 / 7.0) < 0.01:
        rate = 2000.0 / 7.0  # exact, see the dataset README
    n = d["imu_gyr"].shape[0]
    q_enu = np.asarray(d["opt_quat"], dtype=np.float64)
    q_ned = convert_earth_frame(q_enu, "ENU", "NED")
    name = path.stem
    groups = broad_trial_groups(path.parent).get(name, ())
    return Recording(
        name=name,
        dt_s=np.full(n, 1.0 / rate),
        gyro_rad_s=np.ascontiguousarray(d["imu_gyr"], dtype=np.float64),
        accel_m_s2=np.ascontiguousarray(d["imu_acc"], dtype=np.float64),
        mag_ut=np.ascontiguousarray(d["imu_mag"], dtype=np.float64),
        q_ref_body_to_ned=q_ned,
        scored=np.asarray(d["movement"]).ravel().astype(bool),
        groups=groups,
        heading_referenced=True,
    )


def find_broad_trials(broad_dir: str | Path) -> list[Path]:
    """The ``.mat`` trials in a folder, sorted by name."""
    return sorted(Path(broad_dir).glob("*.mat"))


# --------------------------------------------------------------------------- RepoIMU

#: The T-stick Xsens gyro saturates at about ±7.36 rad/s (``../shared/data/README.md``); a
#: sample within 5 % of that (≥ 7.0 rad/s on any axis) is counted as clipped.
REPOIMU_GYRO_LIMIT_RAD_S = 7.0


def load_repoimu_csv(path: str | Path, *, skip_s: float = 0.0) -> Recording:
    """Load one RepoIMU T-stick CSV (';'-separated, two header lines).

    Columns: time (s); Vicon quaternion W X Y Z (IMU body → a z-up reference
    frame that is the stick's initial pose, **not** north-referenced);
    acceleration (m/s²); gyro (rad/s); magnetometer (normalised, |m| ≈ 1 — kept
    as it is: the filters only use its direction and learn its norm).

    The z-up reference frame is turned into a z-down one with the ENU → NED
    conversion; its heading remains arbitrary (``heading_referenced=False``):
    fit the heading offset before scoring heading.  Every sample from
    ``skip_s`` on is scored (the dataset has no rest/motion flag).  Gyro
    clipping (|ω_k| ≥ 7.0 rad/s, near the ±7.36 rad/s saturation) is counted in ``extra["gyro_clipped_samples"]``;
    a trial whose reference is all zero (``Test01_Static``) gets NaN references.
    """
    path = Path(path)
    try:
        raw = np.genfromtxt(path, delimiter=";", skip_header=2, dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: not a readable RepoIMU CSV ({exc})") from exc
    raw = np.atleast_2d(raw)
    if raw.ndim != 2 or raw.shape[1] < 14:
        raise DataError(f"{path}: expected 14 ';'-separated columns (RepoIMU T-stick), got {raw.shape}")
    raw = raw[:, :14]
    raw = raw[np.isfinite(raw[:, 0])]
    if raw.shape[0] < 2:
        raise DataError(f"{path}: fewer than two samples")
    t = raw[:, 0]
    dt = np.diff(t, prepend=t[0] - np.median(np.diff(t)))
    q_ref = raw[:, 1:5].copy()
    norm = np.linalg.norm(q_ref, axis=1)
    q_ref[~(norm > 0.5)] = np.nan  # all-zero Vicon rows: no reference
    with np.errstate(invalid="ignore"):
        q_ref = q_ref / np.linalg.norm(q_ref, axis=1, keepdims=True)
    q_ned = convert_earth_frame(q_ref, "ENU", "NED")  # any z-up frame → z-down; heading stays arbitrary
    gyro = np.ascontiguousarray(raw[:, 8:11])
    clipped = int(np.sum(np.any(np.abs(gyro) >= REPOIMU_GYRO_LIMIT_RAD_S, axis=1)))
    scored = (t - t[0]) >= skip_s
    return Recording(
        name=path.stem,
        dt_s=dt,
        gyro_rad_s=gyro,
        accel_m_s2=np.ascontiguousarray(raw[:, 5:8]),
        mag_ut=np.ascontiguousarray(raw[:, 11:14]),
        q_ref_body_to_ned=q_ned,
        scored=scored,
        groups=("repoimu", "clipped") if clipped else ("repoimu",),
        heading_referenced=False,
        extra={
            "gyro_clipped_samples": clipped,
            "has_reference": bool(np.isfinite(q_ned).all(axis=1).any()),
            "time_s": t,
            "skip_s": skip_s,
        },
    )


# --------------------------------------------------------------------------- generic CSV

#: The columns :func:`load_csv` understands (comma-separated, one header line;
#: names are matched case-insensitively; extra columns are ignored).
CSV_COLUMNS: dict[str, str] = {
    "time_s": "sample time, s (required unless dt_s is given)",
    "dt_s": "time since the previous sample, s (alternative to time_s)",
    "gyro_x_rad_s, gyro_y_rad_s, gyro_z_rad_s": "angular rate, sensor axes, rad/s (required)",
    "accel_x_m_s2, accel_y_m_s2, accel_z_m_s2": "specific force, sensor axes, m/s² (required; "
    "a level FRD sensor at rest reads about 0, 0, −9.81)",
    "mag_x_ut, mag_y_ut, mag_z_ut": "magnetic field, sensor axes, µT (optional)",
    "vel_n_m_s, vel_e_m_s, vel_d_m_s": "GNSS velocity, NED, m/s (optional, empty = no fix)",
    "temperature_c": "sensor temperature, °C (optional; used by `mavahrs tune`)",
    "q_w, q_x, q_y, q_z": "reference attitude, body → earth, scalar first (optional)",
    "r11 … r33": "reference as a (possibly noisy) rotation matrix, row-major, body → earth "
    "(optional; converted with Bar-Itzhack's method)",
    "roll_deg, pitch_deg, yaw_deg": "reference as aerospace Z-Y-X Euler angles (optional)",
    "scored": "1 = score this sample, 0 = skip (optional, default all)",
}

_VEC = {
    "gyro": ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"),
    "accel": ("accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"),
    "mag": ("mag_x_ut", "mag_y_ut", "mag_z_ut"),
    "vel": ("vel_n_m_s", "vel_e_m_s", "vel_d_m_s"),
    "quat": ("q_w", "q_x", "q_y", "q_z"),
    "euler": ("roll_deg", "pitch_deg", "yaw_deg"),
    "matrix": tuple(f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)),
}


def load_csv(
    path: str | Path,
    *,
    earth_frame: str = "NED",
    heading_referenced: bool = True,
    skip_s: float = 0.0,
) -> Recording:
    """Load a recording from a CSV with the documented columns (:data:`CSV_COLUMNS`).

    Args:
        earth_frame: the reference's earth frame (NED, ENU or NWU); converted to NED.
        heading_referenced: False if the reference's heading is arbitrary
            (then fit the heading offset before scoring heading).
        skip_s: do not score the first ``skip_s`` seconds (the filter's convergence), s; combined
            with the ``scored`` column where there is one.

    The temperature column, when present, is in ``extra["temperature_c"]``
    and the times in ``extra["time_s"]``.
    """
    path = Path(path)
    try:
        with path.open("r", encoding="utf-8") as f:
            header = f.readline()
        names = [h.strip().lower() for h in header.strip().split(",")]
        with warnings.catch_warnings():  # a header without rows: said below as one error line, not a warning
            warnings.filterwarnings("ignore", message="genfromtxt: Empty input file", category=UserWarning)
            data = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=np.float64, ndmin=2)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: not a readable CSV ({exc})") from exc
    if data.size == 0:
        raise DataError(f"{path}: no data rows")
    if data.shape[1] != len(names):
        raise DataError(f"{path}: the header names {len(names)} columns but rows have {data.shape[1]}")
    col = {n: i for i, n in enumerate(names)}

    def vec(kind: str, required: bool = False) -> Array | None:
        keys = _VEC[kind]
        present = [k in col for k in keys]
        if not any(present):
            if required:
                raise DataError(f"{path}: missing columns {', '.join(keys)} (see CSV_COLUMNS)")
            return None
        if not all(present):
            missing = [k for k, p in zip(keys, present, strict=True) if not p]
            raise DataError(f"{path}: incomplete column group, missing {', '.join(missing)}")
        return np.ascontiguousarray(data[:, [col[k] for k in keys]])

    gyro = vec("gyro", required=True)
    accel = vec("accel", required=True)
    assert gyro is not None and accel is not None
    n = gyro.shape[0]
    if "time_s" in col:
        t = data[:, col["time_s"]]
        steps = np.diff(t)
        nominal = float(np.median(steps)) if steps.size else 0.01
        dt = np.diff(t, prepend=t[0] - nominal)
    elif "dt_s" in col:
        dt = data[:, col["dt_s"]].copy()
        t = np.cumsum(np.nan_to_num(dt))
    else:
        raise DataError(f"{path}: needs a time_s or dt_s column")
    quat = vec("quat")
    matrix = vec("matrix")
    euler = vec("euler")
    if quat is not None:
        q_ref = quat
    elif matrix is not None:
        from mavahrs.geometry.rotation import from_matrix_bar_itzhack

        m = matrix.reshape(n, 3, 3)
        ok = np.all(np.isfinite(matrix), axis=1)
        q_ref = np.full((n, 4), np.nan)
        if ok.any():
            q_ref[ok] = from_matrix_bar_itzhack(m[ok])
    elif euler is not None:
        from mavahrs.geometry.rotation import from_euler_rad

        r = np.radians(euler)
        q_ref = from_euler_rad(r[:, 0], r[:, 1], r[:, 2])
    else:
        q_ref = np.full((n, 4), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        q_ref = q_ref / np.linalg.norm(q_ref, axis=1, keepdims=True)
    q_ned = convert_earth_frame(q_ref, earth_frame, "NED")
    scored = np.ones(n, dtype=bool)
    if "scored" in col:
        scored = np.nan_to_num(data[:, col["scored"]]) > 0.5
    if skip_s > 0.0:
        scored &= (t - t[0]) >= skip_s
    extra: dict[str, object] = {"time_s": t, "has_reference": bool(np.isfinite(q_ned).all(axis=1).any())}
    if "temperature_c" in col:
        extra["temperature_c"] = data[:, col["temperature_c"]].copy()
    vel = vec("vel")
    if vel is not None:
        extra["velocity_ned_m_s"] = vel
    return Recording(
        name=path.stem,
        dt_s=dt,
        gyro_rad_s=gyro,
        accel_m_s2=accel,
        mag_ut=vec("mag"),
        q_ref_body_to_ned=q_ned,
        scored=scored,
        groups=(),
        heading_referenced=heading_referenced,
        extra=extra,
    )


def write_csv_recording(path: str | Path, rec: Recording) -> None:
    """Write a :class:`Recording` in the :func:`load_csv` format (reference as q_w … q_z, NED)."""
    t = rec.extra.get("time_s")
    if t is None:
        t = np.cumsum(rec.dt_s) - rec.dt_s[0]
    cols = [np.asarray(t, dtype=np.float64)[:, None], rec.gyro_rad_s, rec.accel_m_s2]
    names = ["time_s", *_VEC["gyro"], *_VEC["accel"]]
    if rec.mag_ut is not None:
        cols.append(rec.mag_ut)
        names += list(_VEC["mag"])
    temp = rec.extra.get("temperature_c")
    if temp is not None:
        cols.append(np.asarray(temp, dtype=np.float64)[:, None])
        names.append("temperature_c")
    cols += [rec.q_ref_body_to_ned, rec.scored.astype(np.float64)[:, None]]
    names += [*_VEC["quat"], "scored"]
    np.savetxt(path, np.hstack(cols), delimiter=",", header=",".join(names), comments="", fmt="%.9g")
