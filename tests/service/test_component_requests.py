"""Requests addressed to our component (191) over real UDP sockets: answered as a component without the service.

A ground station on an ``--out`` output (or behind the autopilot, on the master link) that asks
component 191 for a command or an FTP file gets COMMAND_ACK(MAV_RESULT_UNSUPPORTED) or an FTP NAK at
once; parameter requests stay unanswered, as the parameter protocol says of a component without
parameters; broadcasts and requests to other components are left to them. The daemon runs with a
small stand-in pipeline (tests/conftest.py's ``heartbeat_only_pipeline``; its codec is the real one: our
ids 1/191). Each test waits for the answers themselves; what must stay unanswered is checked against a
last targeted command sent after it (UDP on loopback keeps the order, and the daemon answers in order).
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from typing import Any

import pytest

from mavahrs.protocol.codec import MavCodec
from mavahrs.service.component import FTP_ERR_UNKNOWN_COMMAND, FTP_OP_NAK, ComponentResponder
from mavahrs.service.daemon import Daemon, DaemonSettings
from mavahrs.transports import open_transport

GCS = (255, 190)
MAV_CMD_REQUEST_MESSAGE, MAV_CMD_GET_HOME_POSITION, MAV_CMD_DO_SET_MODE = 512, 410, 176
MAV_RESULT_UNSUPPORTED = 3
FTP_OPEN_FILE_RO, FTP_TERMINATE_SESSION = 4, 1
FENCE_CMD = 31000  # MAV_CMD_USER_1: the last request of each test, its answer ends the wait


def _ftp(seq: int, opcode: int, data: bytes = b"", session: int = 0) -> list[int]:
    head = struct.pack("<HBBBBBBI", seq, session, opcode, len(data), 0, 0, 0, 0)
    return list((head + data).ljust(251, b"\0"))


def _requests(gcs: MavCodec) -> list[bytes]:
    """Every kind of request, targeted at us, broadcast, or at the autopilot; the fence last."""
    m = gcs.mav
    return [gcs.encode(x) for x in (
        m.command_long_encode(1, 191, MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0),  # answered
        m.command_int_encode(1, 191, 0, MAV_CMD_DO_SET_MODE, 0, 0, 1, 4, 0, 0, 0, 0, 0),  # answered
        m.file_transfer_protocol_encode(0, 1, 191, _ftp(41, FTP_OPEN_FILE_RO, b"@PARAM/param.pck")),  # answered
        m.param_request_list_encode(1, 191),  # ignored: no parameters
        m.param_request_read_encode(1, 191, b"SYSID_THISMAV", -1),  # ignored
        m.command_long_encode(0, 0, MAV_CMD_GET_HOME_POSITION, 0, 0, 0, 0, 0, 0, 0, 0),  # broadcast: not ours
        m.command_long_encode(1, 0, MAV_CMD_GET_HOME_POSITION, 0, 0, 0, 0, 0, 0, 0, 0),  # every component of 1
        m.file_transfer_protocol_encode(0, 0, 0, _ftp(7, FTP_OPEN_FILE_RO, b"@PARAM/param.pck")),  # broadcast
        m.file_transfer_protocol_encode(0, 1, 1, _ftp(8, FTP_OPEN_FILE_RO, b"@PARAM/param.pck")),  # the autopilot's
        m.command_long_encode(1, 1, MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0),  # the autopilot's
        m.command_long_encode(1, 191, FENCE_CMD, 0, 0, 0, 0, 0, 0, 0, 0),
    )]  # fmt: skip


def _answers_until_fence(sock: socket.socket, deadline_s: float = 20.0) -> list[Any]:
    dec = MavCodec()
    out: list[Any] = []
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        try:
            out += dec.receive_datagram(sock.recv(4096))
        except TimeoutError:
            continue
        if any(m.get_type() == "COMMAND_ACK" and m.command == FENCE_CMD for m in out):
            return [m for m in out if m.get_type() != "HEARTBEAT"]
    raise AssertionError(f"no answer to the last command within {deadline_s} s; got {[m.get_type() for m in out]}")


def _run(d: Daemon) -> threading.Thread:
    t = threading.Thread(target=d.run, daemon=True)
    t.start()
    return t


def _check(answers: list[Any]) -> None:
    acks = [(m.command, m.result, m.target_system, m.target_component) for m in answers if m.get_type() == "COMMAND_ACK"]
    assert acks == [(MAV_CMD_REQUEST_MESSAGE, MAV_RESULT_UNSUPPORTED, *GCS), (MAV_CMD_DO_SET_MODE, MAV_RESULT_UNSUPPORTED, *GCS),
                    (FENCE_CMD, MAV_RESULT_UNSUPPORTED, *GCS)]  # fmt: skip
    (nak,) = [m for m in answers if m.get_type() == "FILE_TRANSFER_PROTOCOL"]
    assert (nak.target_network, nak.target_system, nak.target_component) == (0, *GCS)
    seq, session, opcode, size, req_opcode = struct.unpack_from("<HBBBB", bytes(nak.payload))
    assert (seq, session, opcode, size, req_opcode) == (42, 0, FTP_OP_NAK, 1, FTP_OPEN_FILE_RO)
    assert nak.payload[12] == FTP_ERR_UNKNOWN_COMMAND
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in answers} == {(1, 191)}
    assert len(answers) == 4  # nothing for parameters, broadcasts or the autopilot's requests


def test_a_ground_station_on_an_output_gets_its_answers_there(caplog: pytest.LogCaptureFixture,
                                                             heartbeat_only_pipeline: Any) -> None:
    """MAVProxy/QGroundControl on ``--out udpin:…`` (they send first; the daemon answers to the last sender)."""
    settings = DaemonSettings(master="udpin:127.0.0.1:0", outputs=("udpin:127.0.0.1:0",), status_interval_s=0.0)
    d = Daemon(settings, heartbeat_only_pipeline(), open_transport(settings.master), [open_transport(settings.outputs[0])])
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.settimeout(0.1)
    thread = _run(d)
    try:
        with caplog.at_level(logging.INFO, logger="mavahrs.daemon"):
            codec = MavCodec(*GCS)
            for frame in _requests(codec):
                gcs.sendto(frame, d.outputs[0].local_address)
            answers = _answers_until_fence(gcs)
            # a second PARAM_REQUEST_LIST: said once only
            gcs.sendto(codec.encode(codec.mav.param_request_list_encode(1, 191)), d.outputs[0].local_address)
            gcs.sendto(codec.encode(codec.mav.command_long_encode(1, 191, FENCE_CMD, 0, 0, 0, 0, 0, 0, 0, 0)),
                       d.outputs[0].local_address)  # fmt: skip
            _answers_until_fence(gcs)
    finally:
        d.stop()
        thread.join(10)
        gcs.close()
    _check(answers)
    assert d.responder is not None and d.responder.counters.param_requests_ignored == 3
    said = [r.getMessage() for r in caplog.records if "parameters" in r.getMessage()]
    assert said == [
        "PARAM_REQUEST_LIST (system 255, component 190) asked this component for its parameters: mavahrs has no "
        "MAVLink parameters (its settings are --config/--set), and, as the parameter protocol says, does not answer "
        "(a ground station may keep asking: MAVProxy does every second or two; harmless)"
    ]
    assert d.counters.requests_answered == 5


def test_requests_routed_by_the_autopilot_are_answered_on_the_master_link(tmp_path: Any, heartbeat_only_pipeline: Any) -> None:
    """A ground station behind the autopilot (it routes messages for component 191 to the link it heard us on)."""
    from mavahrs.service.sinks import TlogSink

    settings = DaemonSettings(master="udpin:127.0.0.1:0", status_interval_s=0.0)
    sink = TlogSink(str(tmp_path / "run.tlog"), 0.1)
    d = Daemon(settings, heartbeat_only_pipeline(), open_transport(settings.master), [], sink=sink)
    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap.settimeout(0.1)
    thread = _run(d)
    try:
        autopilot = MavCodec(1, 1)
        ap.sendto(autopilot.encode(autopilot.mav.heartbeat_encode(2, 3, 0, 0, 4)), d.master.local_address)
        for frame in _requests(MavCodec(*GCS)):  # relayed as they are: the ground station's ids
            ap.sendto(frame, d.master.local_address)
        answers = _answers_until_fence(ap)
    finally:
        d.stop()
        thread.join(10)
        ap.close()
    _check(answers)
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(tmp_path / "run.tlog"))
    recorded = []
    while (m := log.recv_match(type=["COMMAND_ACK", "FILE_TRANSFER_PROTOCOL"])) is not None:
        recorded.append((m.get_type(), m.get_srcComponent()))
    log.close()
    assert recorded.count(("COMMAND_ACK", 191)) == 3 and recorded.count(("FILE_TRANSFER_PROTOCOL", 191)) == 1


def test_ftp_replies_and_short_payloads_are_not_answered() -> None:
    codec = MavCodec(1, 191)
    responder = ComponentResponder(codec)
    assert responder.ftp_nak(bytes(_ftp(3, FTP_OP_NAK))) is None  # someone's NAK
    assert responder.ftp_nak(b"\x01\x00") is None
    nak = responder.ftp_nak(bytes(_ftp(0xFFFF, FTP_TERMINATE_SESSION, session=5)))
    assert nak is not None and struct.unpack_from("<HBBBB", nak) == (0, 5, FTP_OP_NAK, 1, FTP_TERMINATE_SESSION)


class _FailingCodec(MavCodec):
    """Our codec, failing to encode the answer to one command (as a broken signing key or a full buffer
    might): the daemon must count it and go on."""

    BAD_CMD = 31001

    def encode(self, msg: Any) -> bytes:
        if getattr(msg, "command", None) == self.BAD_CMD:
            raise ValueError("cannot encode")
        return super().encode(msg)


def test_a_request_that_cannot_be_answered_is_counted_and_the_daemon_goes_on(caplog: pytest.LogCaptureFixture,
                                                                            heartbeat_only_pipeline: Any) -> None:
    pipeline = heartbeat_only_pipeline()
    pipeline.codec = _FailingCodec(1, 191)
    settings = DaemonSettings(master="udpin:127.0.0.1:0", status_interval_s=0.0)
    d = Daemon(settings, pipeline, open_transport(settings.master), [])
    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap.settimeout(0.1)
    thread = _run(d)
    try:
        with caplog.at_level(logging.WARNING, logger="mavahrs.daemon"):
            gcs = MavCodec(*GCS)
            for cmd in (_FailingCodec.BAD_CMD, FENCE_CMD):
                ap.sendto(gcs.encode(gcs.mav.command_long_encode(1, 191, cmd, 0, 0, 0, 0, 0, 0, 0, 0)),
                          d.master.local_address)  # fmt: skip
            answers = _answers_until_fence(ap)
    finally:
        d.stop()
        thread.join(10)
        ap.close()
    assert not thread.is_alive()
    assert [m.command for m in answers if m.get_type() == "COMMAND_ACK"] == [FENCE_CMD]
    assert d.counters.pipeline_errors == 1 and d.counters.requests_answered == 1
    assert any("could not answer COMMAND_LONG: cannot encode" in r.getMessage() for r in caplog.records), caplog.text
