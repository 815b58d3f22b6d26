"""MAVProxy 1.8.75 asking our component (191) for its parameters, on loopback, as a ground station would.

MAVProxy targeting component 191 (``--target-component=191``, or ``set target_component 191``) downloads
parameters over MAVLink FTP first (``@PARAM/param.pck``), then with PARAM_REQUEST_LIST. Unanswered (this
test with the answers switched off), it sent 8 FTP OpenFileRO requests over 7 s and no PARAM_REQUEST_LIST
within 40 s (nor 120 s in a second run; docs/daemon.md). The daemon now NAKs the FTP request at once (mavahrs.service.component): MAVProxy's
first OpenFileRO is its only one, and its PARAM_REQUEST_LIST follows within its 1 s parameter period.
PARAM_REQUEST_LIST itself stays unanswered (a component without parameters ignores it, per the parameter
protocol). The daemon runs in-process with a stand-in pipeline (tests/conftest.py's ``heartbeat_only_pipeline``: our real codec and ids); the test waits
for MAVProxy's requests, not for fixed times.
"""

from __future__ import annotations

import struct
import sys
import threading
import time
from typing import Any

import pytest

from mavahrs.service.daemon import Daemon, DaemonSettings
from mavahrs.transports import open_transport

pytestmark = [pytest.mark.slow, pytest.mark.skipif(sys.platform == "win32", reason="process groups, signals")]

FTP_OPEN_FILE_RO = 4


@pytest.mark.reaches_off_loopback  # MAVProxy itself tries off-loopback connects (as in test_mavproxy.py; blocked by the namespace)
def test_mavproxy_falls_back_from_ftp_at_once_when_component_191_naks(processes: Any, mavproxy: str,
                                                                     heartbeat_only_pipeline: Any) -> None:
    settings = DaemonSettings(master="udpin:127.0.0.1:0", outputs=("udpin:127.0.0.1:0",), status_interval_s=0.0)
    d = Daemon(settings, heartbeat_only_pipeline(heartbeat_to_master=False), open_transport(settings.master),
               [open_transport(settings.outputs[0])])
    assert d.responder is not None
    seen: list[tuple[float, str, int | None]] = []  # (time s, type, FTP opcode) of requests addressed to 1/191
    answer = d.responder.answer

    def recording(msg: Any) -> list[bytes]:
        if (getattr(msg, "target_system", None), getattr(msg, "target_component", None)) == (1, 191):
            op = struct.unpack_from("<HBB", bytes(msg.payload))[2] if msg.get_type() == "FILE_TRANSFER_PROTOCOL" else None
            seen.append((time.monotonic(), msg.get_type(), op))
        return answer(msg)

    d.responder.answer = recording  # type: ignore[method-assign]
    thread = threading.Thread(target=d.run, daemon=True)
    thread.start()
    port = d.outputs[0].local_address[1]
    try:
        processes.start("gcs", [sys.executable, mavproxy, f"--master=udpout:127.0.0.1:{port}", "--daemon",
                                "--target-system=1", "--target-component=191", "--streamrate=-1",
                                f"--state-basedir={processes.workdir}", "--nodtr"])  # fmt: skip
        deadline = time.monotonic() + 120.0  # MAVProxy's start-up on a loaded machine included
        while time.monotonic() < deadline and not any(kind == "PARAM_REQUEST_LIST" for _, kind, _ in seen):
            if processes.procs["gcs"].poll() is not None:
                pytest.fail(f"MAVProxy exited: {processes.output('gcs')[-2000:]}")
            time.sleep(0.1)
    finally:
        processes.stop("gcs")
        d.stop()
        thread.join(10)
    opens = [t for t, kind, op in seen if kind == "FILE_TRANSFER_PROTOCOL" and op == FTP_OPEN_FILE_RO]
    lists = [t for t, kind, _ in seen if kind == "PARAM_REQUEST_LIST"]
    assert opens and lists, f"MAVProxy's requests to 1/191: {seen}"
    assert len(opens) == 1, f"MAVProxy resent OpenFileRO despite the NAK: {seen}"
    assert lists[0] - opens[0] < 3.0, f"fell back {lists[0] - opens[0]:.1f} s after the NAK: {seen}"
    assert d.responder.counters.ftp_naks >= 1
