"""``mavahrs run``: the companion daemon (live IMU in, ATTITUDE_QUATERNION out)."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import threading
from typing import Any

from mavahrs.cli.common import (
    EXIT_CODES_HELP,
    EXIT_OK,
    SIGNALS_RECEIVED,
    LazyDefaultsFormatter,
    add_velocity_source_option,
    gc_paused,
    parse_source,
    start_kernels,
)

__all__ = ["register", "run"]

_DESCRIPTION = """\
Connect to the autopilot (--master), request its IMU stream, estimate the
attitude sample by sample and send ATTITUDE_QUATERNION (component 191) to
every --out, plus HEARTBEAT at 1 Hz.  Settings come from defaults, then
--config FILE (TOML), then these flags and --set.

connection strings (as pymavlink/MAVProxy): udpin:HOST:PORT (listen; replies
to the last sender), udp:HOST:PORT (= udpin), udpout:HOST:PORT,
udpbcast:HOST:PORT, tcp:HOST:PORT (client, reconnects), tcpin:HOST:PORT
(server), /dev/ttyACM0 or /dev/ttyUSB0,921600 or COM3 (serial).

examples:
  mavahrs run --master /dev/ttyACM0 --baud 921600 --out udpout:127.0.0.1:14551
  mavahrs run --master udpin:0.0.0.0:14550 --out udpout:192.168.1.10:14550 --log flight.tlog
  mavahrs run --master tcp:127.0.0.1:5760 --filter madgwick --out-rate 0
  mavahrs run --master udpin:0.0.0.0:14550 --http 8088   # then open http://127.0.0.1:8088/
"""

# CLI option -> dotted setting (value conversions happen in mavahrs.config).
_OVERRIDES = {
    "master": "daemon.master",
    "baud": "daemon.baud",
    "outputs": "daemon.outputs",
    "log": "daemon.log_path",
    "heartbeat_timeout": "daemon.heartbeat_timeout_s",
    "duration": "daemon.duration_s",
    "status_interval": "daemon.status_interval_s",
    "stats_json": "daemon.stats_path",
    "filter": "pipeline.filter_name",
    "imu": "pipeline.imu",
    "velocity_source": "pipeline.velocity_source",
    "out_rate": "pipeline.out_rate_hz",
    "rate": "pipeline.stream_rate_hz",
    "sysid": "pipeline.system_id",
    "compid": "pipeline.component_id",
    "out_identity": "pipeline.out_identity",
    "euler": "pipeline.send_attitude_euler",
    "request_streams": "pipeline.request_streams",
    "signing_key": "daemon.signing_key_path",
    "require_signing": "daemon.require_signing",
    "signing_link_id": "daemon.signing_link_id",
    "realtime_priority": "daemon.realtime_priority",
    "fast_lane": "daemon.fast_lane",
    "http": "daemon.http",
    "http_token": "daemon.http_token",
}


def register(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "run",
        help="run the companion daemon: live IMU in, ATTITUDE_QUATERNION out",
        description=_DESCRIPTION,
        epilog=EXIT_CODES_HELP + ".  SIGINT/SIGTERM stop cleanly with exit code 0.",
        formatter_class=LazyDefaultsFormatter,
    )
    links = p.add_argument_group("links")
    links.add_argument("--master", metavar="URL", help="autopilot link (default: {daemon.master})")
    links.add_argument(
        "--baud", type=int, metavar="N", help="serial baud rate, bit/s, unless URL ends in ,BAUD (default: {daemon.baud})"
    )
    links.add_argument(
        "--out", dest="outputs", action="append", metavar="URL",
        help="send the attitude here; repeat for more outputs (default: none)",
    )
    links.add_argument(
        "--heartbeat-timeout", type=float, metavar="S",
        help="exit with code 3 if no autopilot HEARTBEAT arrives within S seconds of start; 0 = wait for ever "
        "(default: {daemon.heartbeat_timeout_s} s)",
    )
    est = p.add_argument_group("estimation")
    est.add_argument("--filter", metavar="NAME", help="attitude filter: {filters} (default: {pipeline.filter_name})")
    est.add_argument(
        "--imu", metavar="0|1|2|auto",
        help="IMU instance to use; auto picks one and fails over when it goes stale (default: {pipeline.imu})",
    )
    add_velocity_source_option(est, default_text="{pipeline.velocity_source}")
    est.add_argument(
        "--source", type=parse_source, metavar="SYSID[:COMPID]",
        help="take the IMU data from this autopilot only, e.g. 1 or 1:1 (several autopilots on one link); "
        "sets pipeline.source_system and pipeline.source_component (default: the first autopilot HEARTBEAT's)",
    )
    est.add_argument(
        "--rate", type=float, metavar="HZ",
        help="IMU message rate requested from the autopilot, Hz (default: {pipeline.stream_rate_hz} Hz)",
    )
    est.add_argument(
        "--no-stream-requests", dest="request_streams", action="store_const", const=False,
        help="do not ask the autopilot for streams (it is configured to send them already)",
    )
    out = p.add_argument_group("output")
    out.add_argument(
        "--out-rate", type=float, metavar="HZ",
        help="ATTITUDE_QUATERNION rate, Hz; 0 = one per IMU sample (default: {pipeline.out_rate_hz} Hz)",
    )
    out.add_argument(
        "--sysid", type=int, metavar="N",
        help="system id of our messages; none = the autopilot's (default: {pipeline.system_id})",
    )
    out.add_argument(
        "--compid", type=int, metavar="N",
        help="component id of our messages; 191 = MAV_COMP_ID_ONBOARD_COMPUTER (default: {pipeline.component_id})",
    )
    out.add_argument(
        "--out-identity", choices=("component", "separate-vehicle", "none"),
        help="how the attitude presents itself: component = component --compid of the vehicle; "
        "separate-vehicle = a vehicle of its own (--sysid, default 42, component 1), for QGroundControl "
        "before 4.2, which would draw our attitude on the autopilot's HUD; none = send no attitude "
        "(status line and --log only) (default: {pipeline.out_identity})",
    )
    out.add_argument(
        "--euler", action="store_const", const=True,
        help="also send ATTITUDE (roll/pitch/yaw) (default: {pipeline.send_attitude_euler})",
    )
    sec = p.add_argument_group("security (MAVLink 2 signing)")
    sec.add_argument(
        "--signing-key", metavar="FILE",
        help="sign everything we send and verify signed input with the key in FILE: 64 hex characters, or a "
        "passphrase (key = SHA-256 of it, as MAVProxy's 'signing setup'); FILE must not be readable by "
        "other users (chmod 600) (default: no signing)",
    )
    sec.add_argument(
        "--require-signing", action="store_const", const=True,
        help="drop unsigned input too (wrongly signed and replayed input is always dropped); needs "
        "--signing-key (default: off)",
    )
    sec.add_argument(
        "--signing-link-id", type=int, metavar="N",
        help="link id 0-255 written into our signatures (default: {daemon.signing_link_id})",
    )
    web = p.add_argument_group("status page (pip install 'mavahrs[http]'; docs/status-page.md)")
    web.add_argument(
        "--http", metavar="[HOST:]PORT",
        help="serve a read-only status page (attitude, link and filter health), /status.json, /metrics, "
        "/healthz and /register_service on PORT; HOST defaults to 127.0.0.1 (default: off)",
    )
    web.add_argument(
        "--http-token", metavar="TOKEN",
        help="require TOKEN on every request (query token=TOKEN or header 'Authorization: Bearer TOKEN'; not on /healthz "
        "and /register_service); without it a non-loopback HOST is served with a warning. Visible in the "
        "process list: prefer daemon.http_token in --config (default: none)",
    )
    ops = p.add_argument_group("operation")
    ops.add_argument(
        "--config", metavar="FILE", action="append",
        help="TOML settings file (see contrib/mavahrs.example.toml); repeatable: a later file's settings "
        "over an earlier one's (e.g. --config /etc/mavahrs.toml --config gains.toml from `mavahrs tune`)",
    )
    ops.add_argument(
        "--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
        help="any setting, e.g. pipeline.out_rate_hz=100, daemon.input_queue=512, filter.max_gap_s=0.5 "
        "(repeatable; wins over --config)",
    )
    ops.add_argument("--log", metavar="FILE.tlog", help="record everything in and out (flushed every second)")
    ops.add_argument(
        "--duration", type=float, metavar="S", help="stop after S seconds (default: run until SIGINT/SIGTERM)"
    )
    ops.add_argument(
        "--status-interval", type=float, metavar="S",
        help="seconds between status lines; 0 = none (default: {daemon.status_interval_s} s)",
    )
    ops.add_argument("--stats-json", metavar="FILE", help="write counters and latency percentiles here at exit")
    ops.add_argument(
        "--realtime-priority", type=int, metavar="N",
        help="run under real-time scheduling, SCHED_FIFO priority 1-99 (needs root or CAP_SYS_NICE; "
        "systemd: CPUSchedulingPolicy=fifo); 0 = normal (default: {daemon.realtime_priority})",
    )
    ops.add_argument(
        "--no-fast-lane", dest="fast_lane", action="store_const", const=False,
        help="answer every datagram through the Python path only (default: steady-state RAW_IMU on a UDP "
        "link is answered by the compiled fast lane and confirmed byte for byte by the Python path)",
    )
    ops.add_argument(
        "--print-config", action="store_true", help="print the effective configuration as TOML and exit"
    )
    return p


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The dotted settings the command line sets (``--set`` first, explicit flags win)."""
    from mavahrs.config import parse_override

    out: dict[str, Any] = {}
    for text in getattr(args, "settings", None) or []:
        path, value = parse_override(text)
        out[".".join(path)] = value
    for attr, dotted in _OVERRIDES.items():
        value = getattr(args, attr, None)
        if value is None:
            continue
        if attr == "imu":
            value = str(value)
        out[dotted] = list(value) if isinstance(value, list) else value
    source = getattr(args, "source", None)
    if source is not None:
        out["pipeline.source_system"] = source[0]
        if source[1] is not None:
            out["pipeline.source_component"] = source[1]
    return out


class _StopRequested(Exception):
    """SIGINT/SIGTERM while the daemon is still starting (links opening, filter compiling)."""


class _StartupSignals:
    """SIGINT/SIGTERM while the daemon starts: remembered, acted on where the start-up can stop cleanly.

    Never raised from the handler: an exception raised wherever the signal lands was dropped inside numba's
    ctypes callbacks to LLVM (the stop lost, the daemon running on — forever with ``--heartbeat-timeout 0`` —
    or the kernel cache handing LLVM garbage: a segmentation fault) and turned into a ``RuntimeError`` inside a
    class's creation (exit 1).  :meth:`checkpoint` raises :class:`_StopRequested` between the steps; once the
    daemon is built it is stopped as its own handler would.  A second signal ends the process at once (a cold
    compilation of the kernels takes minutes; numba writes its cache files whole).
    """

    def __init__(self, log: logging.Logger) -> None:
        self.received: list[int] = []
        self._log = log
        self._daemon: Any = None

    def install(self) -> dict[Any, Any]:
        """Become the SIGINT/SIGTERM handler (main thread only); the handlers replaced, to restore."""
        if threading.current_thread() is not threading.main_thread():
            return {}
        old = {s: signal.signal(s, self) for s in (signal.SIGINT, signal.SIGTERM)}
        self.received.extend(SIGNALS_RECEIVED)  # the command line's handler's, whose raise was dropped
        return old

    def __call__(self, signum: int, frame: Any) -> None:
        self.received.append(signum)
        name = signal.Signals(signum).name
        if self._daemon is not None:
            self._daemon.stop_on_signal(signum)
        elif len(self.received) == 1:
            self._log.info("%s: stopping as soon as the start-up allows (again to stop at once)", name)
        else:
            self._log.info("mavahrs stopped (%s) while starting, at once", name)
            logging.shutdown()
            os._exit(EXIT_OK)

    def checkpoint(self) -> None:
        """Raise :class:`_StopRequested` if a stop was asked for."""
        if self.received:
            raise _StopRequested(signal.Signals(self.received[0]).name)

    def attach(self, daemon: Any) -> None:
        """From now on a signal stops ``daemon`` (as its own handler, which replaces this one, does); one
        received before stops it at once."""
        self._daemon = daemon
        if self.received:
            daemon.stop_on_signal(self.received[0])


def _restore_signals(old: dict[Any, Any]) -> None:
    for sig, handler in old.items():
        signal.signal(sig, handler)


def run(args: argparse.Namespace) -> int:
    stopping = logging.getLogger("mavahrs.daemon")
    # A stop request during start-up is a clean stop too (exit code 0), not a traceback or 130; the
    # daemon installs its own handlers for the loop and restores these afterwards.
    startup = _StartupSignals(stopping)
    old = startup.install()
    daemon = None
    try:
        startup.checkpoint()
        from mavahrs.config import load_run_config
        from mavahrs.service.daemon import build_daemon

        # the collector rests while the daemon starts (settings, imports, kernels: see gc_paused) and
        # resumes before it serves
        with gc_paused():
            config = load_run_config(args.config, overrides_from_args(args))
            if args.print_config:
                print(config.to_toml(), end="")
                return EXIT_OK
            start_kernels()  # cached kernels load without numba's compiler registries; announces a first compile
            startup.checkpoint()
            daemon = build_daemon(config.daemon, config.pipeline, config.filter)
        startup.attach(daemon)
        daemon.run()
    except _StopRequested as exc:
        if daemon is not None:
            daemon.close()
        stopping.info("mavahrs stopped (%s) while starting", exc)
    finally:
        _restore_signals(old)
    return EXIT_OK
