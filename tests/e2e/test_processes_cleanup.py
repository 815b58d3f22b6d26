"""The end-to-end fixture's processes (MAVProxy, the simulator, the daemon) do not outlive an interrupted test
session: a test process ended by SIGKILL, SIGTERM or Ctrl-C never reaches the fixture's teardown, and the
programs, each in a session of its own, used to run on."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

psutil = pytest.importorskip("psutil")

CONFTEST = Path(__file__).with_name("conftest.py")

# a stand-in for MAVProxy: a program that starts a helper in its own process group, both sleeping
_PROGRAM = (
    "import subprocess, sys, time\n"
    "helper = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])\n"
    "print(helper.pid, flush=True)\n"
    "time.sleep(600)\n"
)

# the test process: the fixture's Processes start two programs, then the process ends by SIGNAL with no teardown
_SESSION = """
import importlib.util, os, signal, sys, time
from pathlib import Path
spec = importlib.util.spec_from_file_location("e2e_conftest", {conftest!r})
mod = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mod)
p = mod.Processes(Path({workdir!r}))
for name in ("router", "sim"):
    p.start(name, [sys.executable, "-c", {program!r}])
deadline = time.monotonic() + 120
while not all(p.output(n).strip() for n in ("router", "sim")) and time.monotonic() < deadline:
    time.sleep(0.05)
print(" ".join([str(q.pid) for q in p.procs.values()] + [p.output(n).strip() for n in ("router", "sim")]), flush=True)
os.kill(os.getpid(), {sig})
time.sleep(600)
"""


def _running(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
def test_programs_and_their_helpers_are_stopped_when_the_test_process_dies(tmp_path: Path, sig: int) -> None:
    code = _SESSION.format(conftest=str(CONFTEST), workdir=str(tmp_path), program=_PROGRAM, sig=int(sig))
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    proc.wait(60)
    pids = [int(x) for x in line.split()]
    assert len(pids) == 4, (line, proc.stderr.read() if proc.stderr else "")  # two programs, two helpers
    deadline = time.monotonic() + 60.0
    while any(_running(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [p for p in pids if _running(p)]
    for p in left:  # (what the old fixture left running: stopped here, not by the next session)
        psutil.Process(p).kill()
    assert left == [], f"still running after the test process died by {signal.Signals(sig).name}: {left}"
