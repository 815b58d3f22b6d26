"""Tests touch loopback only: the check in tests/conftest.py catches a test that reaches beyond it.

Each test process runs in a network namespace whose only interface is ``lo``; the kernel counts every
send or connect towards another address (it finds no route), and a test during which that count grows
fails.  Here: that the namespace is what it should be, that a subprocess connecting a UDP socket to a
documentation address (203.0.113.1, TEST-NET-3) is counted, and that a test doing so in a pytest run
with this suite's conftest is reported failed while its loopback-only neighbour passes.  Also: every
place that starts Chromium does it through the one helper with the networking flags.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
TESTS = REPO / "tests"

_CONNECT_OUT = (
    "import socket\n"
    "s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n"
    "try:\n"
    "    s.connect(('203.0.113.1', 9))\n"
    "    s.send(b'x')\n"
    "    print('sent')\n"
    "except OSError as exc:\n"
    "    print('refused:', exc.errno)\n"
)


def test_the_only_interface_is_loopback(off_loopback_attempts: Callable[[], int]) -> None:
    interfaces = sorted(name for _, name in socket.if_nameindex())
    assert interfaces == ["lo"], interfaces
    # loopback itself works, both families where IPv6 is on
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(30)
        tx.sendto(b"ping", rx.getsockname())
        assert rx.recv(16) == b"ping"


@pytest.mark.reaches_off_loopback
def test_a_subprocess_connecting_beyond_loopback_is_counted(off_loopback_attempts: Callable[[], int]) -> None:
    before = off_loopback_attempts()
    out = subprocess.run([sys.executable, "-c", _CONNECT_OUT], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "refused: 101", out  # ENETUNREACH: nothing left the machine
    assert off_loopback_attempts() - before >= 1
    # a loopback datagram is not counted
    before = off_loopback_attempts()
    subprocess.run([sys.executable, "-c", _CONNECT_OUT.replace("203.0.113.1", "127.0.0.1")], check=True,
                   capture_output=True, timeout=60)  # fmt: skip
    assert off_loopback_attempts() == before


@pytest.mark.reaches_off_loopback
def test_a_test_reaching_beyond_loopback_fails_the_run(off_loopback_attempts: Callable[[], int], tmp_path: Path) -> None:
    (tmp_path / "test_inner.py").write_text(
        "import subprocess, sys\n"
        f"CODE = {_CONNECT_OUT!r}\n"
        "def test_stays_on_loopback():\n"
        "    subprocess.run([sys.executable, '-c', CODE.replace('203.0.113.1', '127.0.0.1')], check=True)\n"
        "def test_reaches_out():\n"
        "    subprocess.run([sys.executable, '-c', CODE], check=True)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS"}
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), str(REPO), env.get("PYTHONPATH", "")])
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "conftest", "-p", "no:cacheprovider", "-p", "no:xdist", "-q",
         "--rootdir", str(tmp_path), "--basetemp", str(tmp_path / "base"), str(tmp_path / "test_inner.py")],
        capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env,
    )  # fmt: skip
    text = run.stdout + run.stderr
    assert run.returncode == 1, text
    # the loopback test passes; the other's call passes too, and its teardown reports the attempt
    assert re.search(r"^2 passed, 1 error in ", text, re.M), text
    assert "ERROR test_inner.py::test_stays_on_loopback" not in text, text
    assert "ERROR test_inner.py::test_reaches_out" in text, text
    assert "attempt(s) to reach an address beyond loopback" in text, text


def test_every_chromium_is_started_through_the_helper_with_networking_off() -> None:
    from mavahrs.evaluation.browser import CHROMIUM_FLAGS

    for flag in ("--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-default-apps", "--no-first-run"):
        assert flag in CHROMIUM_FLAGS
    assert any(f.startswith("--headless") for f in CHROMIUM_FLAGS)
    helper = REPO / "mavahrs" / "evaluation" / "browser.py"
    starters = []
    for path in [*REPO.glob("mavahrs/**/*.py"), *REPO.glob("scripts/*"), *REPO.glob("tests/**/*.py")]:
        if path == helper or path == Path(__file__) or not path.is_file():
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        if re.search(r"webdriver\.Chrom|ChromeOptions|[\"']chromium[\"'][,)]", text):
            starters.append(path.relative_to(REPO).as_posix())
    assert starters == [], f"start Chromium with mavahrs.evaluation.browser.start_chromium: {starters}"
    for user in ("tests/service/test_http_live.py", "scripts/bench_live.py"):
        assert "start_chromium(" in (REPO / user).read_text(encoding="utf-8")
