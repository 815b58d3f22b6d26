"""The status page's pieces that need no live stream: addresses, health rule, metrics text, BlueOS metadata.

The server itself, the page in a browser and ``/healthz`` following a real
link are in ``test_http_live.py``.
"""

from __future__ import annotations

import math
import sys

import pytest

from mavahrs.errors import ConfigError
from mavahrs.service.daemon import DaemonSettings
from mavahrs.service.http import (
    MISSING_EXTRA_TEXT,
    LiveSample,
    StatusBoard,
    StatusServer,
    attitude_fields,
    health,
    is_loopback,
    metric_families,
    parse_http_address,
    register_service_info,
)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("8088", ("127.0.0.1", 8088)),
        (8088, ("127.0.0.1", 8088)),
        ("0.0.0.0:8088", ("0.0.0.0", 8088)),
        (":9000", ("127.0.0.1", 9000)),
        ("[::1]:8088", ("::1", 8088)),
        ("pi.local:80", ("pi.local", 80)),
        ("0", ("127.0.0.1", 0)),
    ],
)
def test_http_addresses(text: str, expected: tuple[str, int]) -> None:
    assert parse_http_address(text) == expected


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("web", "--http 'web': the port must be a number 0…65535 (e.g. 8088 or 0.0.0.0:8088)"),
        ("1.2.3.4:70000", "--http '1.2.3.4:70000': the port must be a number 0…65535 (e.g. 8088 or 0.0.0.0:8088)"),
        ("::1:8088", "--http '::1:8088': write an IPv6 address in brackets, e.g. [::1]:8088"),
        ("[::1]8088", "--http '[::1]8088': expected [HOST:]PORT, e.g. 8088 or 0.0.0.0:8088 or [::1]:8088"),
    ],
)
def test_bad_http_addresses_are_config_errors(text: str, message: str) -> None:
    with pytest.raises(ConfigError) as exc:
        parse_http_address(text)
    assert str(exc.value) == message
    with pytest.raises(ConfigError):  # the setting is checked when the settings are made
        DaemonSettings(http=text)


def test_loopback() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("127.1.2.3") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("::") and not is_loopback("192.168.1.5")
    assert not is_loopback("pi.local")


def test_health_rule() -> None:
    t = 100.0
    live = LiveSample(t, 0.0, t - 0.2, t - 0.2, 1000, (1.0, 0.0, 0.0, 0.0), None, 0.0)
    assert health(None, t, 1.0) == (False, "starting")
    assert health(live, t + 0.5, 1.0) == (True, "ok")
    assert health(live._replace(last_input_s=None), t, 1.0) == (False, "nothing received from the autopilot yet")
    assert health(live._replace(last_input_s=t - 1.5), t, 1.0) == (
        False, "nothing received from the autopilot for 1.5 s")
    assert health(live._replace(last_attitude_s=None), t, 1.0) == (False, "no attitude sent yet")
    assert health(live._replace(last_attitude_s=t - 3.0), t, 1.0) == (False, "no attitude sent for 3.0 s")
    # the loop stopped publishing: whatever the last sample said
    assert health(live, t + 2.0, 1.0) == (False, "the daemon's loop has not published for 2.0 s")


def test_attitude_fields_from_a_sample() -> None:
    """Euler angles of both attitudes and their difference, worked out from what the loop published."""
    from mavahrs.geometry.rotation import from_euler_rad
    from mavahrs.protocol.codec import mavlink

    ours = tuple(from_euler_rad(math.radians(20.0), math.radians(-5.0), math.radians(350.0)).tolist())
    ap = mavlink.MAVLink_attitude_message(4950, math.radians(18.0), math.radians(-5.0), math.radians(-8.0), 0, 0, 0)
    live = LiveSample(12.0, 2.0, 11.99, 11.99, 5000, ours, ap, 11.9)
    f = attitude_fields(live)
    assert f["uptime_s"] == 10.0 and f["time_boot_ms"] == 5000
    assert (f["roll_deg"], f["pitch_deg"], f["yaw_deg"]) == pytest.approx((20.0, -5.0, 350.0))
    a = f["autopilot"]
    assert a["time_boot_ms"] == 4950 and a["age_s"] == pytest.approx(0.1)
    assert (a["roll_deg"], a["pitch_deg"], a["yaw_deg"]) == pytest.approx((18.0, -5.0, 352.0))
    assert f["difference"]["heading_deg"] == pytest.approx(-2.0, abs=0.2)
    assert 1.5 < f["difference"]["tilt_deg"] < 2.5
    # q and −q are one rotation; published with the scalar part ≥ 0 whichever the filter holds (seen live: w < 0)
    w_positive = [c if ours[0] >= 0.0 else -c for c in ours]
    for q in (ours, tuple(-c for c in ours)):
        g = attitude_fields(live._replace(q_body_to_ned=q))
        assert g["q"] == pytest.approx(w_positive) and g["q"][0] > 0.0 and g["roll_deg"] == pytest.approx(20.0)
    assert a["q"][0] > 0.0
    none = attitude_fields(live._replace(q_body_to_ned=None, autopilot_msg=None))
    assert none["q"] is None and none["autopilot"] is None and none["difference"] is None and "roll_deg" not in none


def test_difference_compares_at_the_autopilots_own_time(autopilot, trajectory) -> None:
    """``attitude.difference`` is ours at the autopilot attitude's own ``time_boot_ms`` against it.

    The synthetic autopilot's ATTITUDE is the exact truth, stamped with its own time but arriving 0.54 s
    late (seen live: −20° in a turn against our latest); the difference must be our filter's error only.
    """
    from types import SimpleNamespace

    from mavahrs.geometry import rotation
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.service.http import StatusPublisher
    from mavahrs.service.monitor import attitude_divergence_rad
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    delay_us = 540_000
    pipe = Pipeline(PipelineSettings(filter_name="mahony", out_rate_hz=0.0))
    daemon = SimpleNamespace(
        counters=SimpleNamespace(datagrams_in=1, attitudes_out=1, messages_in=1, input_dropped=0), pipeline=pipe, last_pipeline_status=None,
        status_fields=lambda now_s, window: {}, settings=SimpleNamespace(master="synthetic"),
    )
    board = StatusBoard()
    pub = StatusPublisher(board, 0.0)
    rx = MavCodec(0, 0)
    late: list[tuple[int, bytes]] = []  # (arrival µs, ATTITUDE frame)
    aligned, against_latest = [], []
    for k in range(len(trajectory.t_us)):
        t_us = int(trajectory.t_us[k])
        frames = [autopilot.heartbeat()] if k % 400 == 0 else []
        frames.append(autopilot.raw_imu_k(trajectory, k))
        if k % 40 == 0:  # ATTITUDE at 10 Hz: the truth at t_us
            roll, pitch, yaw = rotation.to_euler_rad(trajectory.q_body_to_ned[k])
            late.append((t_us + delay_us, autopilot.codec.encode(autopilot.codec.mav.attitude_encode(
                t_us // 1000, float(roll), float(pitch), float(yaw), 0.0, 0.0, 0.0))))
        while late and late[0][0] <= t_us:
            frames.append(late.pop(0)[1])
        for frame in frames:
            for msg in rx.receive_datagram(frame):
                pipe.handle(msg, t_us)
        if k % 20 == 0:  # the daemon's timer: 20 Hz
            pipe.tick(t_us)
            pub.tick(daemon, t_us * 1e-6)
            live = board.live
            f = attitude_fields(live)
            if f["difference"] is None or t_us < 6_000_000:
                continue
            ap_k = trajectory.index_of_ms(f["autopilot"]["time_boot_ms"])
            assert f["difference"]["time_boot_ms"] == f["autopilot"]["time_boot_ms"]
            assert live.time_boot_ms - f["autopilot"]["time_boot_ms"] >= 500  # 0.54 s behind ours
            aligned.append(math.hypot(f["difference"]["tilt_deg"], f["difference"]["heading_deg"]))
            tilt, hdg = attitude_divergence_rad(live.q_body_to_ned, trajectory.q_body_to_ned[ap_k])
            against_latest.append(math.degrees(math.hypot(tilt, hdg)))
    assert len(aligned) > 200
    assert max(against_latest) > 10.0  # the turns make the late ATTITUDE look far off "now"
    assert max(aligned) < 2.0  # at the same time: the filter's own error


def test_register_service_has_the_fields_blueos_reads() -> None:
    """BlueOS's ServiceMetadata: seven strings, and optional flags it understands."""
    info = register_service_info("1.2.3")
    for key in ("name", "description", "icon", "company", "version", "webpage", "api"):
        assert isinstance(info[key], str) and info[key], key
    assert info["version"] == "1.2.3"
    assert info["icon"].startswith("mdi-")  # BlueOS shows Material Design Icons by name
    optional = {"route": str, "new_page": bool, "sanitized_name": str, "extra_query": str,
                "avoid_iframes": bool, "works_in_relative_paths": bool, "extras": dict}
    for key in set(info) - {"name", "description", "icon", "company", "version", "webpage", "api"}:
        assert isinstance(info[key], optional[key]), key
    assert info["works_in_relative_paths"] is True  # the page uses relative URLs only


def test_metrics_text_parses_with_prometheus_parser() -> None:
    parser = pytest.importorskip("prometheus_client.parser")
    from prometheus_client import CollectorRegistry, generate_latest

    from mavahrs.service.http import _Families

    attitude = {"t_s": 5.0, "uptime_s": 12.5, "roll_deg": 10.0, "pitch_deg": -2.0, "yaw_deg": 350.0}
    status = {
        "datagrams_in": 4000, "messages_in": 4100, "attitudes_out": 500, "input_dropped": 2, "crc_errors": 3,
        "bad_data": 1, "seq_gaps": 7, "samples_in": 3990, "samples_filtered": 3980,
        "drops_by_reason": {"stale": 4, "duplicate": 1}, "link_drops": 2,
        "in_hz": 400.0, "filter_hz": 400.0, "out_hz": 50.0, "gain": 0.033, "accel_weight": 0.9,
        "mag_weight": 0.25, "accel_rejected": False, "mag_rejected": True, "accel_rejection_pct": 5.0,
        "mag_rejection_pct": 80.0, "bias_deg_s": [0.5, -0.25, 0.0], "gnss_velocity": "in use", "imu": 1,
        "second_opinion": {"tilt_deg": 1.5, "heading_deg": -3.0, "warning": False, "comparisons": 9, "episodes": 1},
        "latency_p50_us": 150.0, "latency_p99_us": 900.0, "latency_max_us": 2000.0, "filter": "best",
        "master": "udpin:0.0.0.0:14550",
    }
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Families(metric_families(attitude, status, True, "0.1.0")))
    text = generate_latest(registry).decode()
    samples = {}
    types = {}
    for fam in parser.text_string_to_metric_families(text):
        types[fam.name] = fam.type
        for s in fam.samples:
            samples[(s.name, tuple(sorted(s.labels.items())))] = s.value
    assert types["mavahrs_datagrams_received"] == "counter"
    assert samples[("mavahrs_datagrams_received_total", ())] == 4000
    assert samples[("mavahrs_crc_errors_total", ())] == 3
    assert samples[("mavahrs_samples_dropped_total", (("reason", "stale"),))] == 4
    assert samples[("mavahrs_samples_dropped_total", (("reason", "link"),))] == 2
    assert samples[("mavahrs_rate_hertz", (("stage", "input"),))] == 400
    assert samples[("mavahrs_sensor_trust_ratio", (("sensor", "magnetometer"),))] == 0.25
    assert samples[("mavahrs_sensor_rejected", (("sensor", "magnetometer"),))] == 1
    assert samples[("mavahrs_sensor_rejection_ratio", (("sensor", "magnetometer"),))] == pytest.approx(0.8)
    assert samples[("mavahrs_gyro_bias_radians_per_second", (("axis", "x"),))] == pytest.approx(math.radians(0.5))
    assert samples[("mavahrs_gnss_velocity_in_use", ())] == 1
    assert samples[("mavahrs_imu_in_use", ())] == 1
    assert samples[("mavahrs_attitude_degrees", (("angle", "yaw"),))] == 350
    assert samples[("mavahrs_autopilot_divergence_degrees", (("component", "heading"),))] == -3
    assert samples[("mavahrs_autopilot_divergence_episodes_total", ())] == 1
    assert samples[("mavahrs_processing_latency_seconds", (("quantile", "0.99"),))] == pytest.approx(900e-6)
    assert samples[("mavahrs_up", ())] == 1
    assert samples[("mavahrs_build_info", (("filter", "best"), ("master", "udpin:0.0.0.0:14550"),
                                           ("version", "0.1.0")))] == 1
    # before the first snapshot: the same names, no values yet (NaN), still parseable
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Families(metric_families(None, None, False, "0.1.0")))
    names = {f.name for f in parser.text_string_to_metric_families(generate_latest(registry).decode())}
    assert names == set(types)


def test_http_without_the_extra_is_a_config_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "aiohttp", None)  # what an interpreter without aiohttp does on import
    with pytest.raises(ConfigError) as exc:
        StatusServer(StatusBoard(), "127.0.0.1", 0)
    assert str(exc.value) == MISSING_EXTRA_TEXT.format(missing="aiohttp")
    assert str(exc.value) == "--http needs the optional web server: pip install 'mavahrs[http]' (missing: aiohttp)"


def test_run_http_without_the_extra_exits_2(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    from mavahrs.cli import main

    monkeypatch.setitem(sys.modules, "aiohttp", None)
    rc = main(["run", "--master", "udpin:127.0.0.1:0", "--http", "0", "--duration", "1"])
    assert rc == 2
    assert "--http needs the optional web server: pip install 'mavahrs[http]' (missing: aiohttp)" in (
        capsys.readouterr().err)
