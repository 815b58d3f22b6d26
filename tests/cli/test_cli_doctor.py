"""``mavahrs doctor`` against the simulated autopilot (``firmware_sim`` processes, real UDP sockets and a pty).

* ArduPilot, watching only: RAW_IMU at the default 1 Hz stream rate, and a
  recommendation naming SRn_RAW_SENS / MAVn_RAW_SENS and SET_MESSAGE_INTERVAL;
* ArduPilot, asking for 400 Hz: refused, 250 Hz accepted and measured within
  5 %, firmware 4.5.7, SCHED_LOOP_RATE ≥ 625 recommended;
* PX4: HIGHRES_IMU at 400 Hz within 5 %, nothing to recommend;
* ArduPilot over a 57600-baud serial line (pty): the rate falls short and a
  baud rate that carries 400 Hz RAW_IMU is recommended.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from mavahrs.cli import main

pytestmark = [pytest.mark.slow, pytest.mark.skipif(os.name != "posix", reason="subprocesses, ptys")]

REPO = Path(__file__).resolve().parents[2]
SIMS = {
    "ardupilot": ["--out", "udpin:127.0.0.1:0"],
    "px4": ["--out", "udpin:127.0.0.1:0", "--autopilot", "px4"],
    "serial57600": ["--out", "pty", "--baud", "57600"],
}


def _start(args: list[str]) -> subprocess.Popen[str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "-q", "--scenario", "hover", "--duration", "0", *args],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env, cwd=REPO,
    )  # fmt: skip


@pytest.fixture(scope="module")
def sims() -> Iterator[dict[str, str]]:
    """The three simulators, started together; name → link ("udpin:127.0.0.1:PORT" or "pty /dev/pts/N")."""
    procs = {name: _start(args) for name, args in SIMS.items()}
    links: dict[str, str] = {}

    def wait_link(name: str, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith("LINK "):
                links[name] = line[5:].strip()
                return

    threads = [threading.Thread(target=wait_link, args=item, daemon=True) for item in procs.items()]
    for t in threads:
        t.start()
    try:
        for t in threads:
            t.join(90)
        assert set(links) == set(SIMS), f"simulators did not start: {links}"
        yield links
    finally:
        for proc in procs.values():
            proc.terminate()
        for proc in procs.values():
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)


def _doctor(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    code = main(["doctor", *args])
    return code, capsys.readouterr().out


def _rate(text: str, message: str) -> float:
    m = re.search(rf"{message} \(primary\): ([0-9.]+) Hz", text)
    assert m, text
    return float(m.group(1))


def _udpout(link: str) -> str:
    return link.replace("udpin:", "udpout:")


def test_ardupilot_watch_then_request(sims: dict[str, str], capsys: pytest.CaptureFixture[str]) -> None:
    master = _udpout(sims["ardupilot"])
    # 6 s: a 1 Hz stream needs several messages after the autopilot is first heard (its 1 Hz HEARTBEAT,
    # later on a loaded machine) for a rate from its timestamps
    code, text = _doctor(capsys, "--master", master, "--duration", "6", "--no-request")
    assert code == 0, text
    assert "autopilot: ArduPilot, system 1 component 1, quadrotor (ArduCopter); firmware 4.5.7 official" in text
    assert _rate(text, "RAW_IMU") == pytest.approx(1.0, rel=0.05)  # SRn_RAW_SENS = 1 Hz, the simulator's default
    rec = next(line for line in text.splitlines() if "RAW_IMU arrives at 1.0 Hz" in line)
    assert "SRn_RAW_SENS" in rec and "MAVn_RAW_SENS" in rec and "SET_MESSAGE_INTERVAL" in rec

    code, text = _doctor(capsys, "--master", master, "--duration", "4", "--rate", "400")
    assert code == 0, text
    assert "asked 400 Hz, accepted 250 Hz" in text
    assert _rate(text, "RAW_IMU") == pytest.approx(250.0, rel=0.05)
    assert "Set SCHED_LOOP_RATE to at least 625 Hz" in text
    field = re.search(r"magnetometer: present: \|B\| RAW_IMU ([0-9.]+) µT", text)
    assert field, text
    assert float(field.group(1)) == pytest.approx(58.1, abs=0.5)  # the simulator's WMM2025 field at Canberra
    assert "(steps 2.5, 5 ms)" in text  # send-time stamps in the 400 Hz scheduler loop


def test_px4_highres_imu_at_the_requested_rate(sims: dict[str, str], capsys: pytest.CaptureFixture[str]) -> None:
    code, text = _doctor(capsys, "--master", _udpout(sims["px4"]), "--duration", "3.5", "--rate", "400")
    assert code == 0, text
    assert "autopilot: PX4, system 1 component 1, quadrotor; firmware 1.15.0 official" in text
    assert _rate(text, "HIGHRES_IMU") == pytest.approx(400.0, rel=0.05)
    assert "recommendations: none" in text


def test_a_57600_baud_serial_link_gets_a_baud_rate(sims: dict[str, str], capsys: pytest.CaptureFixture[str]) -> None:
    device = sims["serial57600"].split()[1]
    # 8 s: the time before the raised rate arrives (longer on a loaded machine) is a small share of the load
    code, text = _doctor(capsys, "--master", device, "--baud", "57600", "--duration", "8", "--rate", "400")
    assert code == 0, text
    assert _rate(text, "RAW_IMU") < 0.9 * 250.0, text  # what 5.76 kB/s leaves for RAW_IMU
    rec = next(line for line in text.splitlines() if "baud carries at most" in line)
    assert "57600 baud carries at most 5.8 kB/s" in rec and "400 Hz RAW_IMU alone needs 16.4 kB/s" in rec
    assert "use ≥ 460800 baud (set ArduPilot SERIALn_BAUD = 460 and mavahrs run --baud 460800)" in rec
    # the load line: what arrived against what the baud rate carries.  How full the link gets depends
    # on the simulator keeping up (on an idle machine 70–100 %, starved 40 %): checked is that the
    # share is the received rate over the capacity, and that the raised rate arrived (well above the
    # 1 Hz streams' few hundred bytes a second)
    load = re.search(r"link load: ([0-9.]+) kB/s received of 5\.8 kB/s that 57600 baud carries \((\d+) %\)", text)
    assert load, text
    kb_s, share = float(load.group(1)), int(load.group(2))
    assert kb_s >= 1.0 and abs(share - 100.0 * kb_s / 5.76) <= 3.0, text


def test_no_autopilot_is_exit_code_3(capsys: pytest.CaptureFixture[str]) -> None:
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    t0 = time.monotonic()
    code, text = _doctor(capsys, "--master", f"udpin:127.0.0.1:{port}", "--duration", "1")
    assert code == 3 and time.monotonic() - t0 < 10
    assert "autopilot: none heard" in text and "nothing received" in text


def test_doctor_help_states_the_exit_codes_once(capsys: pytest.CaptureFixture[str]) -> None:
    from mavahrs.cli import main

    assert main(["doctor", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert out.count("exit codes") == 1 and out.count("130") == 1
    assert out.endswith(
        "exit codes: 0 report printed (an autopilot answered), 1 runtime failure, 2 usage error, 3 the link "
        "cannot be opened or no autopilot HEARTBEAT arrived, 130 interrupted by Ctrl-C"
    )


def test_doctor_says_what_it_is_waiting_for(capsys: pytest.CaptureFixture[str]) -> None:
    """It was silent for its whole --duration (10 s by default) before the report."""
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    code = main(["doctor", "--master", f"udpin:127.0.0.1:{port}", "--duration", "3.5"])
    err = capsys.readouterr().err
    assert code == 3
    lines = err.splitlines()
    assert "listening" in lines[0] and str(port) in lines[0] and "3.5 s" in lines[0], err
    assert any("no autopilot" in ln.lower() and "3 s" in ln for ln in lines[1:]), err
