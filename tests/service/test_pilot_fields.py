"""The status page's pilot fields (mavahrs.service.pilot) from real MAVLink bytes: armed and mode, battery,
altitude and ground speed, GNSS fix and satellites, field strength, the --log file, latency in context."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.service.pilot import PilotInfo, latency_context, pilot_fields


def _decoded(codec: MavCodec, rx: MavCodec, msg: object) -> object:
    (out,) = rx.receive_datagram(codec.encode(msg))  # real bytes there and back
    return out


def test_pilot_fields_from_an_armed_ardupilot_in_loiter(tmp_path: Path) -> None:
    ap, gcs, rx = MavCodec(1, 1), MavCodec(255, 190), MavCodec()
    info = PilotInfo()
    m = ap.mav
    for msg in (
        gcs.mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0),  # not the vehicle
        m.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                           mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5, 4),
        m.sys_status_encode(0, 0, 0, 500, 15_870, 1_234, 76, 0, 0, 0, 0, 0, 0),
        m.global_position_int_encode(10_000, -353_632_600, 1_491_652_300, 612_340, 27_500, 300, -400, 0, 9000),
        m.gps_raw_int_encode(10_000_000, 3, -353_632_600, 1_491_652_300, 612_340, 80, 120, 500, 9000, 14),
        m.raw_imu_encode(10_000_000, 0, 0, -1000, 1, -1, 0, 200, 30, 450, 0, 0),
    ):
        info.observe(_decoded(ap, rx, msg))
    log = tmp_path / "flight.tlog"
    log.write_bytes(b"x" * 2048)
    daemon = SimpleNamespace(pilot=info, settings=SimpleNamespace(log_path=str(log)),
                             pipeline=SimpleNamespace(declination=SimpleNamespace(field=SimpleNamespace(strength_ut=58.1))))
    f = pilot_fields(daemon, {"latency_p50_us": 120.0, "latency_p99_us": 5000.0, "filter_hz": 250.0, "out_hz": 50.0})
    assert f["armed"] is True and f["mode"] == "LOITER"
    assert f["battery"] == {"voltage_v": pytest.approx(15.87), "current_a": pytest.approx(12.34), "remaining_pct": 76}
    assert f["altitude_rel_m"] == pytest.approx(27.5) and f["altitude_msl_m"] == pytest.approx(612.34)
    assert f["ground_speed_m_s"] == pytest.approx(5.0)
    assert f["gnss"] == {"fix": "3D fix", "fix_type": 3, "satellites": 14}
    assert f["mag_field_ut"] == pytest.approx(math.sqrt(200**2 + 30**2 + 450**2) / 10.0)
    assert f["mag_field_expected_ut"] == 58.1
    assert f["log"] == {"recording": True, "path": str(log), "bytes": 2048}
    lat = f["latency"]
    assert lat["sample_period_us"] == pytest.approx(4000.0) and lat["within_sample_period"] is False
    assert lat["output_period_us"] == pytest.approx(20_000.0)


def test_nothing_heard_yet_is_none_not_zero() -> None:
    f = pilot_fields(SimpleNamespace(pilot=PilotInfo(), settings=SimpleNamespace(log_path=None)), {})
    assert f["armed"] is None and f["mode"] is None and f["gnss"]["fix"] is None and f["altitude_rel_m"] is None
    assert f["log"]["recording"] is False and f["mag_field_ut"] is None
    assert latency_context(100.0, 300.0, 400.0, None)["within_sample_period"] is True
