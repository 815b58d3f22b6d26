"""Ctrl-C after a command finished, while the interpreter shuts down (exit handlers, threads being joined).

`audit` once ended by the signal right after "wrote fi.parquet", without its "interrupted" line.  A
non-daemon thread that outlives the command (as Dask's and numba's helpers can) holds the shutdown here:
the signal then arrives exactly in that window, every time.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(os.name != "posix", reason="SIGINT")

REPO = Path(__file__).resolve().parents[2]
_LINGER = '''
import sys, threading, time
def _linger():
    threading.main_thread().join()
    sys.stderr.write("SHUTTING DOWN\\n")
    sys.stderr.flush()
    time.sleep(60)
threading.Thread(target=_linger, daemon=False).start()
'''


def test_ctrl_c_while_shutting_down_after_audit_wrote_its_table(tmp_path: Path) -> None:
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(_LINGER)
    log = tmp_path / "empty.tlog"
    log.write_bytes(b"")
    table = tmp_path / "fi.csv"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), str(REPO)]))
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavahrs", "audit", str(log), "--serial", "--no-progress", "-o", str(table)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
    )  # fmt: skip
    assert proc.stderr is not None
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if "SHUTTING DOWN" in line:
            break
    assert any(f"wrote {table}" in x for x in seen), seen
    proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    assert proc.returncode == 130, (proc.returncode, err)
    assert "interrupted" in err and "Traceback" not in err, err
    assert table.exists() and table.stat().st_size > 0


#: The same thread, but the Ctrl-C reaches it rather than the main thread (the kernel hands a
#: process's signal to any thread that does not block it; under load the lingering one got it).
_LINGER_TAKES_THE_SIGNAL = """
import signal, sys, threading, time
def _linger():
    threading.main_thread().join()
    sys.stderr.write("SHUTTING DOWN\\n")
    sys.stderr.flush()
    signal.pthread_kill(threading.get_ident(), signal.SIGINT)
    time.sleep(60)
threading.Thread(target=_linger, daemon=False).start()
"""


def test_ctrl_c_that_reaches_another_thread_while_shutting_down_still_ends_it(tmp_path: Path) -> None:
    """The main thread is blocked joining the lingering thread: the signal must still end the process."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(_LINGER_TAKES_THE_SIGNAL)
    log = tmp_path / "empty.tlog"
    log.write_bytes(b"")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), str(REPO)]))
    proc = subprocess.run(
        [sys.executable, "-m", "mavahrs", "audit", str(log), "--serial", "--no-progress", "-o", str(tmp_path / "t.csv")],
        env=env, capture_output=True, text=True, cwd=tmp_path, timeout=45,
    )  # fmt: skip
    assert "SHUTTING DOWN" in proc.stderr, proc.stderr
    assert proc.returncode == 130, (proc.returncode, proc.stderr)
    assert "interrupted while shutting down" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr

