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


class Processes:
    """Subprocesses with their output in files; all of them stopped (SIGINT/SIGTERM, then SIGKILL) at the end."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.env = dict(os.environ)
        self.env["PYTHONPATH"] = str(REPO) + os.pathsep + self.env.get("PYTHONPATH", "")

    def start(self, name: str, cmd: list[str]) -> subprocess.Popen[bytes]:
        out = open(self.workdir / f"{name}.out", "wb")  # noqa: SIM115 - closed with the process
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                cwd=self.workdir, env=self.env, start_new_session=True)  # fmt: skip
        out.close()
        self.procs[name] = proc
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
        return proc.returncode

    def stop_all(self) -> None:
        for name in list(self.procs):
            self.stop(name)


@pytest.fixture(scope="module")
def processes(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Processes]:
    p = Processes(tmp_path_factory.mktemp("e2e"))
    try:
        yield p
    finally:
        p.stop_all()
