"""``pipeline.out_identity`` (``mavahrs run --out-identity``): how the attitude presents itself.

QGroundControl before 4.2 draws any component's ATTITUDE_QUATERNION of the vehicle's system on
its HUD (docs/ecosystem.md#qgroundcontrol): there the default (component 191 of the vehicle)
would replace the autopilot's attitude.  ``separate-vehicle`` sends as a vehicle of its own,
``none`` sends nothing.  The daemon runs with the real Pipeline over real UDP sockets; what the
ground station and the autopilot receive is decoded from the bytes on the wire.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from mavahrs.protocol.codec import MavCodec
from mavahrs.protocol.tlog import read_tlog_messages
from mavahrs.service.daemon import DaemonSettings, build_daemon
from mavahrs.service.pipeline import Pipeline, PipelineSettings

FIXED_WING = 1  # MAV_TYPE_FIXED_WING: the autopilot's vehicle type, copied into a separate vehicle's HEARTBEAT
ARDUPILOT, GENERIC, INVALID = 3, 0, 8  # MAV_AUTOPILOT_*
ONBOARD_CONTROLLER = 18


class Autopilot:
    """A UDP socket playing an ArduPilot plane (system 1, component 1) sending to the daemon's udpin."""

    def __init__(self, port: int) -> None:
        self.codec = MavCodec(1, 1)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(0.05)
        self.addr = ("127.0.0.1", port)
        self.t_us = 1_000_000

    def send(self, msg: Any) -> None:
        self.sock.sendto(self.codec.encode(msg), self.addr)

    def fly(self, seconds: float) -> None:
        """HEARTBEAT at 1 Hz and RAW_IMU at 400 Hz of sample time (level, still), in 20 ms bursts."""
        mav = self.codec.mav
        end = time.monotonic() + seconds
        next_hb = 0.0
        while time.monotonic() < end:
            if time.monotonic() >= next_hb:
                self.send(mav.heartbeat_encode(FIXED_WING, ARDUPILOT, 0, 0, 4))
                next_hb = time.monotonic() + 1.0
            for _ in range(8):
                self.t_us += 2500
                self.send(mav.raw_imu_encode(self.t_us, 0, 0, -1000, 0, 0, 0, 200, 0, 400, 0, 0))
            time.sleep(0.02)

    def received(self) -> list[Any]:
        return _decode_all(self.sock)

    def close(self) -> None:
        self.sock.close()


def _decode_all(sock: socket.socket) -> list[Any]:
    dec = MavCodec()
    out: list[Any] = []
    while True:
        try:
            out += dec.receive_datagram(sock.recv(65536))
        except TimeoutError:
            return out


@pytest.fixture
def gcs():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(0.05)
    yield s
    s.close()


def _fly(gcs: socket.socket, pipeline: PipelineSettings, log: Path | None = None) -> tuple[Any, list[Any], list[Any]]:
    """Run the daemon for 1.5 s of flight: (daemon, messages at the ground station, messages at the autopilot)."""
    d = build_daemon(DaemonSettings(
        master="udpin:127.0.0.1:0", outputs=(f"udpout:127.0.0.1:{gcs.getsockname()[1]}",), status_interval_s=0.0,
        log_path=str(log) if log else None,
    ), pipeline)  # fmt: skip
    ap = Autopilot(d.master.local_address[1])
    box: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: box.setdefault("result", d.run()), daemon=True)
    thread.start()
    at_gcs: list[Any] = []
    try:
        ap.fly(1.5)
        time.sleep(0.2)
        at_gcs = _decode_all(gcs)
        at_ap = ap.received()
    finally:
        d.stop()
        thread.join(5)
        ap.close()
    assert box["result"].reason == "stopped"
    return d, at_gcs, at_ap


def _senders(msgs: list[Any], kind: str) -> set[tuple[int, int]]:
    return {(m.get_srcSystem(), m.get_srcComponent()) for m in msgs if m.get_type() == kind}


def test_default_is_component_191_of_the_vehicle(gcs: socket.socket) -> None:
    d, at_gcs, at_ap = _fly(gcs, PipelineSettings(filter_name="mahony"))
    assert _senders(at_gcs, "ATTITUDE_QUATERNION") == {(1, 191)}
    assert _senders(at_ap, "ATTITUDE_QUATERNION") == {(1, 191)}  # routed on by the autopilot
    (hb,) = {(m.type, m.autopilot) for m in at_gcs if m.get_type() == "HEARTBEAT"}
    assert hb == (ONBOARD_CONTROLLER, INVALID)


def test_separate_vehicle_sends_as_its_own_system_with_the_autopilots_vehicle_type(gcs: socket.socket) -> None:
    d, at_gcs, at_ap = _fly(gcs, PipelineSettings(filter_name="mahony", out_identity="separate-vehicle"))
    n = sum(m.get_type() == "ATTITUDE_QUATERNION" for m in at_gcs)
    assert n >= 40  # 50 Hz for about a second and a half
    for msgs in (at_gcs, at_ap):
        assert _senders(msgs, "ATTITUDE_QUATERNION") == {(42, 1)}
        assert _senders(msgs, "HEARTBEAT") == {(42, 1)}
        # nothing claims to come from the autopilot's system: its HUD keeps the autopilot's attitude
        assert all(m.get_srcSystem() != 1 for m in msgs if m.get_type() != "COMMAND_LONG")
    hbs = {(m.type, m.autopilot) for m in at_gcs if m.get_type() == "HEARTBEAT"}
    assert hbs == {(FIXED_WING, GENERIC)}  # a vehicle to a ground station (not an onboard controller)
    requests = [m for m in at_ap if m.get_type() == "COMMAND_LONG"]
    assert requests and all((m.target_system, m.target_component) == (1, 1) for m in requests)


def test_separate_vehicle_with_a_chosen_system_id(gcs: socket.socket) -> None:
    d, at_gcs, _ = _fly(gcs, PipelineSettings(filter_name="mahony", out_identity="separate-vehicle", system_id=7))
    assert _senders(at_gcs, "ATTITUDE_QUATERNION") == {(7, 1)}


def test_none_sends_no_attitude_and_no_heartbeat_but_records_it(gcs: socket.socket, tmp_path: Path) -> None:
    log = tmp_path / "flight.tlog"
    d, at_gcs, at_ap = _fly(gcs, PipelineSettings(filter_name="mahony", out_identity="none"), log)
    assert at_gcs == []
    assert {m.get_type() for m in at_ap} == {"COMMAND_LONG"}  # the stream requests only
    assert d.counters.attitudes_out == 0 and d.counters.frames_to_outputs == 0
    assert d.pipeline.outputs_sent >= 40  # estimated all the same …
    recorded = list(read_tlog_messages(log, "ATTITUDE_QUATERNION"))
    assert len(recorded) == d.pipeline.outputs_sent  # … and in the recording


def test_the_option_is_checked() -> None:
    from mavahrs.errors import ConfigError

    with pytest.raises(ConfigError, match="^out_identity must be one of component, separate-vehicle, none, got 'qgc'$"):
        PipelineSettings(out_identity="qgc")


def _heartbeat(sysid: int, compid: int, mav_type: int, autopilot: int) -> Any:
    codec = MavCodec(sysid, compid)
    (msg,) = MavCodec().receive_datagram(codec.encode(codec.mav.heartbeat_encode(mav_type, autopilot, 0, 0, 4)))
    return msg


def test_a_separate_vehicle_never_uses_the_autopilots_system_id() -> None:
    p = Pipeline(PipelineSettings(filter_name="mahony", out_identity="separate-vehicle", system_id=1))
    assert p.handle(_heartbeat(1, 1, FIXED_WING, ARDUPILOT), 1_000_000) == []
    out = p.tick(1_100_000)
    assert out and all(not o.to_outputs and o.frame[7] == 76 for o in out)  # the stream requests (COMMAND_LONG) only
    warnings = [text for level, text in p.drain_notices() if level >= 30]
    assert warnings == [
        "out_identity separate-vehicle: system id 1 is the autopilot's own, so a ground station would take our "
        "attitude for the autopilot's; sending nothing (set pipeline.system_id, --sysid, to a free system id)"
    ]


def test_our_own_heartbeat_relayed_back_is_not_a_second_autopilot() -> None:
    p = Pipeline(PipelineSettings(filter_name="mahony", out_identity="separate-vehicle"))
    p.handle(_heartbeat(1, 1, FIXED_WING, ARDUPILOT), 1_000_000)
    (hb,) = [o for o in p.tick(1_100_000) if o.frame[7] == 0]  # msgid 0: our HEARTBEAT
    (echo,) = MavCodec().receive_datagram(hb.frame)
    assert (echo.get_srcSystem(), echo.get_srcComponent(), echo.autopilot) == (42, 1, GENERIC)
    p.handle(echo, 1_200_000)
    assert p.source == (1, 1)
    assert "other_autopilot_heartbeats" not in p.status(1_300_000).counters
    notices = [text for _, text in p.drain_notices()]
    assert "attitude sent as a separate vehicle: system 42, component 1 (the autopilot is system 1)" in notices
    assert not any("second autopilot" in text for text in notices)
