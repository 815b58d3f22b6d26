"""``mavahrs doctor``: connect to an autopilot link, measure what arrives, say what to change.

The talking happens here (the imperative shell); the analysis is the pure
:mod:`mavahrs.service.doctor`.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from mavahrs.cli.common import EXIT_CONNECTION, EXIT_OK

__all__ = ["register", "run", "probe"]

_DESCRIPTION = """\
Connect to the autopilot (--master, the same connection strings as `mavahrs
run`), ask it for the IMU stream at --rate as `mavahrs run` would (unless
--no-request), listen for --duration seconds and report: the autopilot and its
firmware version, which IMU messages arrive and at what rate (on the
autopilot's own clock), their timestamp intervals and arrival jitter, the
magnetometer, MAVLink 2 signing, link errors and load; then what to change
(parameters, baud rate, stream commands) to get the rate wanted.

The rate asked for stays in force until the autopilot reboots or something
else changes it, as after `mavahrs run`.  The doctor identifies itself as
component 194 (MAV_COMP_ID_ONBOARD_COMPUTER4), so it can run beside mavahrs
(191).

examples:
  mavahrs doctor --master /dev/ttyACM0 --baud 921600
  mavahrs doctor --master udpin:0.0.0.0:14550 --duration 20 --rate 200
  mavahrs doctor --master tcp:127.0.0.1:5760 --no-request     # only watch
"""

_COMPONENT = 194  # MAV_COMP_ID_ONBOARD_COMPUTER4
_MAV_CMD_REQUEST_MESSAGE = 512
_MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
_MSG_ID_AUTOPILOT_VERSION = 148


def register(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "doctor",
        help="check an autopilot link: IMU messages and rates, firmware, magnetometer, what to change",
        description=_DESCRIPTION,
        epilog="exit codes: 0 report printed (an autopilot answered), 1 runtime failure, 2 usage error, "
        "3 the link cannot be opened or no autopilot HEARTBEAT arrived, 130 interrupted by Ctrl-C",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--master", default="udpin:0.0.0.0:14550", metavar="URL",
                   help="autopilot link, as for mavahrs run (default: udpin:0.0.0.0:14550)")
    p.add_argument("--baud", type=int, default=115200, metavar="N",
                   help="serial baud rate, bit/s, unless URL ends in ,BAUD (default: 115200)")
    p.add_argument("--duration", type=float, default=10.0, metavar="S", help="how long to listen, s (default: 10)")
    p.add_argument("--rate", type=float, default=400.0, metavar="HZ",
                   help="IMU rate wanted (what mavahrs run --rate asks for), Hz (default: 400)")
    p.add_argument("--no-request", action="store_true",
                   help="do not ask for streams: report what the autopilot sends on its own")
    return p


def run(args: argparse.Namespace) -> int:
    from mavahrs.service.doctor import DoctorSettings, diagnose

    settings = DoctorSettings(rate_hz=args.rate, request_streams=not args.no_request)
    observer, facts = probe(args.master, args.baud, args.duration, settings)
    report = diagnose(observer, facts, settings)
    for line in report.lines():
        print(line, flush=True)
    return EXIT_OK if report.autopilot is not None else EXIT_CONNECTION


def _say(message: str) -> None:
    """A progress line on standard error (the log's format), while the report itself goes to standard output."""
    import logging

    logging.getLogger("mavahrs").info("%s", message)


def probe(master: str, baud: int, duration_s: float, settings: Any) -> tuple[Any, Any]:
    """Listen on ``master`` for ``duration_s``, asking for the IMU stream; returns (observer, link facts)."""
    from mavahrs.protocol.codec import MavCodec, mavlink
    from mavahrs.service.doctor import LinkFacts, LinkObserver
    from mavahrs.service.stream_requests import RequestDataStream, StreamRequester, StreamRequestSettings
    from mavahrs.transports import open_transport, parse_connection_string

    endpoint = parse_connection_string(master, baud)
    link = open_transport(endpoint)
    _say(f"doctor: listening on {link.describe()} for {duration_s:g} s"
         + (f", asking for the IMU stream at {settings.rate_hz:g} Hz once the autopilot is found" if settings.request_streams
            else " (not asking for streams)") + " …")  # fmt: skip
    rx = MavCodec()
    tx = MavCodec(system_id=1, component_id=_COMPONENT)
    decode = rx.receive_datagram if link.datagram else rx.receive_stream
    obs = LinkObserver()
    # ask once and watch: no quick re-requests, which would hide a stream-rate reset the report should name
    requester = StreamRequester(StreamRequestSettings(interval_s=max(duration_s, 10.0), rerequest_on_drop=False))
    target: tuple[int, int] | None = None
    version_tries = 0
    next_version_us = 0
    next_hb_us = 0
    start = time.monotonic()
    next_wait_s = 3.0
    heartbeat = tx.mav.heartbeat_encode(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                        mavlink.MAV_STATE_ACTIVE)  # fmt: skip

    def command(cmd: int, *params: float) -> None:
        assert target is not None
        p = list(params) + [0.0] * (7 - len(params))
        link.write(tx.encode(tx.mav.command_long_encode(target[0], target[1], cmd, 0, *p)))

    try:
        while True:
            now_s = time.monotonic()
            if now_s - start >= duration_s:
                break
            if target is None and now_s - start >= next_wait_s:  # still nothing: say so, not a silent wait
                _say(f"doctor: no autopilot HEARTBEAT yet after {now_s - start:.0f} s "
                     f"({link.counters.bytes_in} bytes received) …")  # fmt: skip
                next_wait_s += 3.0
            now_us = int(now_s * 1e6)
            if now_us >= next_hb_us:  # lets udpout/tcp peers learn where we are; harmless otherwise
                link.write(tx.encode(heartbeat))
                next_hb_us = now_us + 1_000_000
            data = link.read(0.02)
            link.maintain(now_s)
            for msg in decode(data) if data else ():
                now_us = int(time.monotonic() * 1e6)
                obs.on_message(msg, now_us)
                kind = msg.get_type()
                if target is None and obs.autopilot is not None:
                    target = obs.autopilot
                    tx.system_id = target[0]
                    _say(f"doctor: autopilot found after {time.monotonic() - start:.1f} s: system {target[0]}, "
                         f"component {target[1]}; measuring until {duration_s:g} s …")  # fmt: skip
                    if settings.request_streams:
                        name = "HIGHRES_IMU" if int(obs.heartbeat.autopilot) == mavlink.MAV_AUTOPILOT_PX4 else "RAW_IMU"
                        requester.want(name, getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), settings.rate_hz)
                        requester.start()
                if target is None or msg.get_srcSystem() != target[0] or msg.get_srcComponent() != target[1]:
                    continue
                if kind == "COMMAND_ACK":
                    if int(msg.command) == 511:
                        requester.on_command_ack(int(msg.command), int(msg.result), now_us)
                    elif int(msg.command) == _MAV_CMD_REQUEST_MESSAGE and int(msg.result) in (3, 4):
                        command(_MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1.0)  # older firmware
                elif kind == "STATUSTEXT":
                    requester.on_statustext(obs.statustext[-1] if obs.statustext else "", now_us)
            if target is None:
                continue
            now_us = int(time.monotonic() * 1e6)
            if obs.version is None and version_tries < 3 and now_us >= next_version_us:
                command(_MAV_CMD_REQUEST_MESSAGE, float(_MSG_ID_AUTOPILOT_VERSION))
                version_tries += 1
                next_version_us = now_us + 1_500_000
            for req in requester.poll(now_us):
                if isinstance(req, RequestDataStream):
                    link.write(tx.encode(tx.mav.request_data_stream_encode(target[0], target[1], req.stream_id,
                                                                           req.rate_hz, 1)))  # fmt: skip
                    obs.on_data_stream_request(now_us)
                else:
                    command(511, float(req.message_id), float(req.interval_us))
                    obs.on_request(req.message, 1e6 / req.interval_us, now_us)
    finally:
        elapsed = time.monotonic() - start
        counters = link.counters
        desc = link.describe()
        link.close()
    cc = rx.counters
    facts = LinkFacts(
        description=desc,
        kind=endpoint.kind,
        baud=int(endpoint.baud) if endpoint.kind == "serial" and getattr(endpoint, "baud", None) else None,
        bytes_in=int(counters.bytes_in),
        duration_s=elapsed,
        crc_errors=int(cc.crc_errors),
        bad_data=int(cc.bad_data),
        seq_gaps=int(cc.seq_gaps),
        seq_gaps_by_source={k: v.seq_gaps for k, v in cc.sources.items()},
    )
    return obs, facts
