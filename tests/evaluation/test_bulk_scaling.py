"""The bulk scaling of replay (``tlogdata.scale_imu_messages``) equals the daemon's per-message ``Scaler``, edge cases included."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.tlogdata import read_tlog_data, scale_imu_messages
from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.sensors.profiles import get_profile
from mavahrs.sensors.scaling import Scaler, ScalingSettings

# (gyro mrad/s, accel mG, mag mgauss): int16 limits, just under/over full scale, absent and implausible mag
EDGES = [
    ((0, 0, 0), (0, 0, -1000), (200, 0, 400)),
    ((0, 0, 0), (0, 0, 0), (0, 0, 0)),
    ((32767, 0, 0), (0, 0, -1000), (200, 0, 400)),
    ((0, -32768, 5), (0, 0, -1000), (0, 0, 0)),
    ((1, 2, 3), (16000, 0, -1000), (200, 0, 400)),
    ((1, 2, 3), (15000, 0, -1000), (5, 0, 0)),
    ((1, 2, 3), (-32768, 32767, -1000), (32767, 32767, 32767)),
    ((30000, -100, 7), (10, -20, -30), (-250, 120, 420)),
    ((-1, 1, -1), (0, 0, 0), (1, 0, 0)),
    ((-32768, 0, 0), (0, 32767, 0), (200, 0, 400)),
    ((100, -200, 300), (123, -456, -789), (-32768, 0, 0)),
]


def _msg(name: str, k: int, g: tuple[int, ...], a: tuple[int, ...], m: tuple[int, ...]) -> object:
    if name == "RAW_IMU":
        return mavlink.MAVLink_raw_imu_message(1_000_000 + 2500 * k, *a, *g, *m, 0, 25 + k)
    cls = getattr(mavlink, f"MAVLink_{name.lower()}_message")
    return cls(1000 + k, *a, *g, *m, 2500 + k)


@pytest.mark.parametrize("profile", ["ardupilot", "px4", "generic"])
@pytest.mark.parametrize("name", ["RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"])
@pytest.mark.parametrize("settings", [ScalingSettings(), ScalingSettings(accel_range_g=8.0, gyro_range_deg_s=500.0)])
def test_bulk_scaling_equals_the_scaler(tmp_path: Path, name: str, profile: str, settings: ScalingSettings) -> None:
    ms = get_profile(profile).scale_for(name)
    if ms is None:
        pytest.skip(f"the {profile} profile does not scale {name}")
    codec = MavCodec(system_id=1, component_id=1)
    msgs = [_msg(name, k, *e) for k, e in enumerate(EDGES)]
    blob = b"".join(struct.pack(">Q", 1_790_000_000_000_000 + k) + codec.encode(m) for k, m in enumerate(msgs))
    path = tmp_path / "edges.tlog"
    path.write_bytes(blob)
    td = read_tlog_data(path)
    bulk = scale_imu_messages(name, td.arrays[name], ms, settings)
    scaler = Scaler(profile, settings)
    for k, m in enumerate(msgs):
        v = scaler.scale(m)
        assert v is not None
        want = list(v[2:11])
        got = [*bulk["gyro"][k], *bulk["accel"][k], *bulk["mag"][k]]
        for w, x in zip(want, got, strict=True):
            assert (math.isnan(w) and math.isnan(x)) or w == x, (k, want, got)
        assert (bulk["sat"][k], bulk["inv"][k]) == (v[12], v[13]), (k, EDGES[k])
        assert bulk["zero"][k] == all(w == 0 for w in want[:6])  # an absent instance sends zeros
        assert (bulk["imu"][k], bulk["t_us"][k]) == (v[0], v[1])
        t = bulk["temp"][k]
        assert (v[11] is None and math.isnan(t)) or t == v[11]
    # the edge cases do exercise every flag
    assert set(np.unique(bulk["sat"]).tolist()) >= {0, 1, 2, 3}
    assert 4 in bulk["inv"].tolist() and bulk["zero"].any() and not bulk["zero"].all()
