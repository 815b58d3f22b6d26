r"""Loaders for reference datasets; frame conversion happens once, here.

Every loader returns a :class:`Recording`: sensor arrays in SI units in the
sensor's own axes, and a reference attitude ``q_ref_body_to_ned`` (NaN rows
where there is none).  Where the dataset's earth frame is not NED it is
converted here (``../shared/data/README.md`` documents each dataset's frames).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import DataError
from mavahrs.geometry.frames import convert_earth_frame

__all__ = ["Recording", "load_broad_trial", "broad_trial_groups", "find_broad_trials"]

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
