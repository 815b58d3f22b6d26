"""The doctor's analysis on synthetic links: what it measures and what it recommends.

Messages are real MAVLink frames (encoded and decoded again, as on a link);
arrival times are given, so every figure has a known true value.
"""

from __future__ import annotations

import numpy as np
import pytest

from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.service.doctor import (
    DoctorSettings,
    LinkFacts,
    LinkObserver,
    ardupilot_min_loop_rate_hz,
    diagnose,
    frame_bytes,
    min_baud_for,
)

AP, PX4 = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink.MAV_AUTOPILOT_PX4
T0 = 10_000_000  # the observer's clock at the first message, µs


class Link:
    """A simulated autopilot feeding an observer: frames encoded, decoded, stamped with arrival times."""

    def __init__(self, autopilot: int = AP, signing_key: bytes | None = None) -> None:
        self.tx = MavCodec(1, 1)
        if signing_key is not None:
            self.tx.enable_signing(signing_key, initial_timestamp_10us=1)
        self.rx = MavCodec()
        self.obs = LinkObserver()
        self.autopilot = autopilot
        self.bytes = 0

    def send(self, msg, rx_us: int) -> None:  # type: ignore[no-untyped-def]
        frame = self.tx.encode(msg)
        self.bytes += len(frame)
        for m in self.rx.receive_datagram(frame):
            self.obs.on_message(m, rx_us)

    def heartbeat(self, rx_us: int = T0) -> None:
        self.send(self.tx.mav.heartbeat_encode(2, self.autopilot, 0, 0, 4), rx_us)

    def raw_imu(self, t_us: int, rx_us: int, mag_mgauss=(200, 30, 550), acc_mg=(0, 0, -1000)) -> None:  # type: ignore[no-untyped-def]
        self.send(self.tx.mav.raw_imu_encode(t_us, *acc_mg, 1, -2, 3, *mag_mgauss, 0, 3500), rx_us)

    def highres(self, t_us: int, rx_us: int) -> None:
        self.send(
            self.tx.mav.highres_imu_encode(t_us, 0.0, 0.0, -9.8, 0.01, 0.0, 0.0, 0.2, 0.03, 0.55, 1013.0, 0.0, 10.0, 20.0,
                                           0x1FF, 0),
            rx_us,
        )  # fmt: skip

    def stream(self, kind: str, rate_hz: float, start_s: float, end_s: float, *, grid_us: int = 0, delay_us: int = 500,
               **kw) -> None:  # type: ignore[no-untyped-def]
        """Messages at ``rate_hz`` between the times (s after T0); ``grid_us`` snaps send stamps to a scheduler loop."""
        n = int(round((end_s - start_s) * rate_hz))
        for k in range(n):
            t = int(start_s * 1e6 + k * 1e6 / rate_hz)
            if grid_us:
                t = -(-t // grid_us) * grid_us  # the first loop tick at or after the due time
            getattr(self, kind)(1_000_000 + t, T0 + t + delay_us + (k * 37 % 300), **kw)

    def ack(self, rate_hz: float, result: int, at_s: float, message: str = "RAW_IMU") -> None:
        self.obs.on_request(message, rate_hz, T0 + int(at_s * 1e6) - 1000)
        self.send(self.tx.mav.command_ack_encode(511, result, 0, 0, 1, 194), T0 + int(at_s * 1e6))

    def facts(self, duration_s: float, baud: int | None = None, **kw) -> LinkFacts:  # type: ignore[no-untyped-def]
        cc = self.rx.counters
        return LinkFacts("test link", "serial" if baud else "udpin", baud, kw.pop("bytes_in", self.bytes), duration_s,
                         crc_errors=cc.crc_errors, bad_data=cc.bad_data, seq_gaps=cc.seq_gaps, **kw)  # fmt: skip


def test_wire_arithmetic() -> None:
    assert frame_bytes("RAW_IMU") == 41  # 10 header + 29 payload (with extensions) + 2 CRC
    assert frame_bytes("RAW_IMU", signed=True) == 54
    assert frame_bytes("HIGHRES_IMU") == 75
    # 400 Hz × 41 B = 16.4 kB/s: 230400 baud (23.04 kB/s) carries it with little room; with 50 % headroom 460800
    assert min_baud_for(400 * 41) == 460800
    assert min_baud_for(50 * 41) == 57600
    # ArduPilot: interval_ms·800 ≥ loop period (µs); 400 Hz = 2 ms intervals → loop period ≤ 1600 µs
    assert ardupilot_min_loop_rate_hz(400) == pytest.approx(625.0)
    assert ardupilot_min_loop_rate_hz(250) <= 400.0 < ardupilot_min_loop_rate_hz(300)


def test_denied_rate_measured_on_the_autopilot_clock_and_the_loop_rate_named() -> None:
    link = Link()
    link.heartbeat()
    link.stream("raw_imu", 4.0, 0.0, 1.0, grid_us=2500)
    link.send(link.tx.mav.statustext_encode(4, b"Requested rate too fast. Increase SCHED_LOOP_RATE"), T0 + 1_000_000)
    link.ack(400.0, mavlink.MAV_RESULT_DENIED, 1.0)
    link.ack(250.0, mavlink.MAV_RESULT_ACCEPTED, 1.01)
    link.stream("raw_imu", 250.0, 1.02, 6.0, grid_us=2500)  # send stamps in a 400 Hz loop: 2.5 / 5 ms steps
    report = diagnose(link.obs, link.facts(6.0))
    assert report.autopilot is not None and report.autopilot.name == "ArduPilot"
    assert report.autopilot.vehicle == "quadrotor (ArduCopter)"
    raw = report.stream("RAW_IMU")
    assert raw is not None and report.primary == "RAW_IMU"
    assert raw.rate_hz == pytest.approx(250.0, rel=0.01)  # the 4 Hz before the change is not averaged in
    assert (raw.requested_hz, raw.accepted_hz) == (400.0, 250.0)
    assert raw.interval_steps_ms == (2.5, 5.0)
    assert raw.interval_ms[0] == pytest.approx(5.0)
    assert raw.mag_ut == pytest.approx(np.linalg.norm([20.0, 3.0, 55.0]), rel=1e-3)
    assert raw.accel_g == pytest.approx(1.0)
    text = "\n".join(report.lines())
    assert "SCHED_LOOP_RATE to at least 625 Hz" in text and "until then it streams 250 Hz" in text
    assert "no signed frames" in report.signing


def test_low_rate_without_requests_names_the_stream_parameters() -> None:
    link = Link()
    link.heartbeat()
    link.stream("raw_imu", 4.0, 0.0, 8.0)
    report = diagnose(link.obs, link.facts(8.0), DoctorSettings(rate_hz=400, request_streams=False))
    assert report.stream("RAW_IMU").rate_hz == pytest.approx(4.0, rel=0.02)
    (rec,) = [r for r in report.recommendations if "RAW_IMU arrives at 4.0 Hz" in r]
    assert "SRn_RAW_SENS" in rec and "MAVn_RAW_SENS" in rec and "SET_MESSAGE_INTERVAL" in rec


def test_px4_low_rate_gives_the_mavlink_stream_command() -> None:
    link = Link(PX4)
    link.heartbeat()
    link.stream("highres", 50.0, 0.0, 5.0)
    report = diagnose(link.obs, link.facts(5.0), DoctorSettings(rate_hz=400, request_streams=False))
    assert report.autopilot.name == "PX4" and report.autopilot.vehicle == "quadrotor"
    assert report.primary == "HIGHRES_IMU" and report.stream("HIGHRES_IMU").rate_hz == pytest.approx(50.0, rel=0.02)
    assert any("mavlink stream -d /dev/ttyS2 -s HIGHRES_IMU -r 400" in r for r in report.recommendations)
    assert report.stream("HIGHRES_IMU").mag_ut == pytest.approx(np.linalg.norm([20.0, 3.0, 55.0]), rel=1e-3)


def test_a_serial_link_too_slow_for_the_rate_gets_a_baud_rate() -> None:
    link = Link()
    link.heartbeat()
    link.ack(250.0, mavlink.MAV_RESULT_ACCEPTED, 0.1)
    link.stream("raw_imu", 130.0, 0.2, 5.0)  # what fits through 57600 baud beside the rest
    facts = link.facts(5.0, baud=57600, bytes_in=int(5760 * 5.0))
    report = diagnose(link.obs, facts)
    (rec,) = [r for r in report.recommendations if "baud" in r]
    assert "57600 baud carries at most 5.8 kB/s" in rec and "400 Hz RAW_IMU alone needs 16.4 kB/s" in rec
    assert "≥ 460800 baud" in rec and "SERIALn_BAUD = 460" in rec
    assert "(100 %)" in report.load


def test_a_stream_rate_reset_by_another_ground_station_is_named() -> None:
    link = Link()
    link.heartbeat()
    link.ack(250.0, mavlink.MAV_RESULT_ACCEPTED, 0.1)
    link.stream("raw_imu", 250.0, 0.2, 4.0)
    link.stream("raw_imu", 4.0, 4.0, 9.0)  # MAVProxy's REQUEST_DATA_STREAM(ALL, 4 Hz)
    report = diagnose(link.obs, link.facts(9.0), DoctorSettings(rate_hz=250))
    (rec,) = [r for r in report.recommendations if "reset the stream rates" in r]
    assert "--streamrate=-1" in rec and "fell to about 4 Hz" in rec


def test_magnetometer_absent_or_implausible() -> None:
    link = Link()
    link.heartbeat()
    link.stream("raw_imu", 50.0, 0.0, 2.0, mag_mgauss=(0, 0, 0))
    report = diagnose(link.obs, link.facts(2.0), DoctorSettings(rate_hz=50, request_streams=False))
    assert report.magnetometer.startswith("absent")
    assert any("heading (yaw) will drift" in r and "COMPASS_USE" in r for r in report.recommendations)

    link = Link()
    link.heartbeat()
    link.stream("raw_imu", 50.0, 0.0, 2.0, mag_mgauss=(20000, 3000, 5500))  # 10× too strong
    report = diagnose(link.obs, link.facts(2.0), DoctorSettings(rate_hz=50, request_streams=False))
    assert any("more than any place on Earth" in r and "milligauss" in r for r in report.recommendations)


def test_signed_frames_are_reported() -> None:
    link = Link(signing_key=bytes(range(32)))
    link.heartbeat()
    link.stream("raw_imu", 50.0, 0.0, 1.0)
    report = diagnose(link.obs, link.facts(1.0), DoctorSettings(rate_hz=50, request_streams=False))
    assert report.signing.startswith("all 51 frames signed")
    assert any("signing_key_path" in r for r in report.recommendations)


def test_absent_second_imu_and_firmware_version() -> None:
    link = Link()
    link.heartbeat()
    link.send(link.tx.mav.autopilot_version_encode(0, (4 << 24) | (6 << 16) | (2 << 8) | 255, 0, 0, 0, [0] * 8,
                                                   [0] * 8, [0] * 8, 0x1209, 0x5741, 7), T0)  # fmt: skip
    link.stream("raw_imu", 50.0, 0.0, 1.0)
    for k in range(10):  # a board with a second compass but no second IMU: SCALED_IMU2 accel/gyro all zero
        link.send(link.tx.mav.scaled_imu2_encode(1000 + 100 * k, 0, 0, 0, 0, 0, 0, 200, 30, 550, 0), T0 + 100_000 * k)
    report = diagnose(link.obs, link.facts(1.0), DoctorSettings(rate_hz=50, request_streams=False))
    assert report.autopilot.firmware == "firmware 4.6.2 official"
    assert report.autopilot.board == "USB 1209:5741, uid 0000000000000007"
    assert report.stream("SCALED_IMU2").present is False
    assert any("no such IMU on this board" in line for line in report.lines())


def test_no_autopilot_heard() -> None:
    link = Link(autopilot=mavlink.MAV_AUTOPILOT_INVALID)  # a ground station's heartbeat only
    link.send(link.tx.mav.heartbeat_encode(6, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4), T0)
    report = diagnose(link.obs, link.facts(3.0))
    assert report.autopilot is None
    assert any("no autopilot HEARTBEAT" in r for r in report.recommendations)
    report = diagnose(LinkObserver(), LinkFacts("/dev/ttyUSB0", "serial", 57600, 0, 3.0))
    assert any("nothing received on the serial port" in r for r in report.recommendations)


QGC_NOTE = (
    "a ground station is on this link (system 255 component 190); its HEARTBEAT does not say which program or "
    "version it is. QGroundControl 4.1 and older draws any component's ATTITUDE_QUATERNION of the vehicle on its "
    "HUD: there mavahrs run's attitude (component 191 of the vehicle) would replace the autopilot's. For such a "
    "ground station run mavahrs with --out-identity separate-vehicle (a vehicle of its own, system 42) or "
    "--out-identity none (QGroundControl 4.2 and later draws only the autopilot's attitude)"
)


def test_a_ground_station_on_the_link_gets_the_hud_note() -> None:
    link = Link()
    link.heartbeat()
    link.stream("raw_imu", 50.0, 0.0, 1.0)
    quiet = diagnose(link.obs, link.facts(1.0), DoctorSettings(rate_hz=50, request_streams=False))
    assert not any("ground station is on this link" in n for n in quiet.notes)
    qgc = MavCodec(255, 190)  # QGroundControl's ids and HEARTBEAT (MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID)
    for m in link.rx.receive_datagram(qgc.encode(qgc.mav.heartbeat_encode(6, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4))):
        link.obs.on_message(m, T0 + 500_000)
    report = diagnose(link.obs, link.facts(1.0), DoctorSettings(rate_hz=50, request_streams=False))
    assert QGC_NOTE in report.notes
    assert f"note: {QGC_NOTE}" in report.lines()
    assert "also heard: system 255 component 190: ground station" in report.lines()


def test_nothing_received_says_so_and_nothing_about_the_compass() -> None:
    report = diagnose(LinkObserver(), LinkFacts("udpin:0.0.0.0:14550", "udpin", None, 0, 10.0))
    lines = report.lines()
    assert "magnetometer: unknown: no IMU data received" in lines
    assert not any("magnetometer" in r or "compass" in r for r in report.recommendations)
    assert report.recommendations == [
        "nothing received in 10 s: check that the autopilot, mavlink-router or MAVProxy sends to this address and "
        "port (udpin:0.0.0.0:14550; e.g. MAVProxy --out udp:THIS_IP:PORT, mavlink-router [UdpEndpoint] Mode = "
        "Normal), that no firewall drops it, and that no other program already listens on the port"
    ]
