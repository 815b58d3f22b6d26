"""Helpers for end-to-end tests with third-party programs (MAVProxy): processes bounded in time, loopback ports."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


@pytest.fixture(scope="session")
def free_udp_port() -> Callable[[], int]:
    """A function returning a free loopback UDP port."""
    return _free_udp_port


def _script(name: str) -> str | None:
    """A console script of the running interpreter's environment (its bin/ first, then PATH)."""
    here = Path(sys.executable).parent / name
    if here.is_file():
        return str(here)
    return shutil.which(name)


@pytest.fixture(scope="session")
def mavproxy() -> str:
    """Path of ``mavproxy.py``; the tests skip (saying why) only when MAVProxy is not installed."""
    pytest.importorskip(
        "MAVProxy",
        reason="MAVProxy is not installed: .ci/run installs it with "
        "`pip install --no-deps MAVProxy==1.8.75` (see docs/ecosystem.md)",
    )
    path = _script("mavproxy.py")
    if path is None:
        pytest.fail("MAVProxy is importable but mavproxy.py is not on PATH nor beside the interpreter")
    return path


@pytest.fixture(scope="session")
def mavlogdump() -> str:
    path = _script("mavlogdump.py")
    if path is None:
        pytest.fail("mavlogdump.py (installed with pymavlink) not found beside the interpreter nor on PATH")
    return path


#: The reaper: reads "+PGID" / "-PGID" lines (a process group started / stopped) until its stdin closes —
#: at the end of the fixture, or when the test process dies in any way (Ctrl-C, SIGTERM, SIGKILL, a killed
#: xdist worker), which no ``finally`` covers —, then stops every group still listed: SIGTERM, SIGKILL after 5 s.
_REAPER = """
import os, signal, sys, time
groups = set()
for line in sys.stdin:
    line = line.strip()
    if line[:1] == "+":
        groups.add(int(line[1:]))
    elif line[:1] == "-":
        groups.discard(int(line[1:]))
def alive(g):
    try:
        os.killpg(g, 0)
        return True
    except OSError:
        return False
for sig in (signal.SIGTERM, signal.SIGKILL):
    for g in [g for g in groups if alive(g)]:
        try:
            os.killpg(g, sig)
        except OSError:
            pass
    deadline = time.monotonic() + 5.0
    while any(alive(g) for g in groups) and time.monotonic() < deadline:
        time.sleep(0.05)
"""


class Processes:
    """Subprocesses with their output in files; all of them stopped (SIGINT/SIGTERM, then SIGKILL) at the end,
    and by a reaper process of their own when the test process ends without reaching its teardown."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.env = dict(os.environ)
        self.env["PYTHONPATH"] = str(REPO) + os.pathsep + self.env.get("PYTHONPATH", "")
        # its own session: a Ctrl-C at the terminal reaches pytest, not the reaper, which then does its work
        self.reaper = subprocess.Popen([sys.executable, "-c", _REAPER], stdin=subprocess.PIPE,
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip

    def _tell_reaper(self, line: str) -> None:
        if self.reaper.stdin is not None and not self.reaper.stdin.closed:
            self.reaper.stdin.write(line.encode() + b"\n")
            self.reaper.stdin.flush()

    def start(self, name: str, cmd: list[str]) -> subprocess.Popen[bytes]:
        out = open(self.workdir / f"{name}.out", "wb")  # noqa: SIM115 - closed with the process
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                cwd=self.workdir, env=self.env, start_new_session=True)  # fmt: skip
        out.close()
        self.procs[name] = proc
        self._tell_reaper(f"+{proc.pid}")  # start_new_session: its process group is its pid
        return proc

    def output(self, name: str) -> str:
        return (self.workdir / f"{name}.out").read_text(errors="replace")

    def stop(self, name: str, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> int | None:
        proc = self.procs[name]
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, sig)  # MAVProxy starts helper processes: stop its whole group
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait(timeout_s)
        self._reap_group(proc.pid)
        return proc.returncode

    def _reap_group(self, pgid: int) -> None:
        """The leader has exited; what it left in its group (MAVProxy's helpers) goes too."""
        try:
            os.killpg(pgid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        self._tell_reaper(f"-{pgid}")

    def stop_all(self) -> None:
        try:
            for name in list(self.procs):
                self.stop(name)
        finally:
            if self.reaper.stdin is not None:
                self.reaper.stdin.close()  # nothing listed is left: the reaper exits at once
            self.reaper.wait(30)


@pytest.fixture(scope="module")
def processes(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Processes]:
    p = Processes(tmp_path_factory.mktemp("e2e"))
    try:
        yield p
    finally:
        p.stop_all()
