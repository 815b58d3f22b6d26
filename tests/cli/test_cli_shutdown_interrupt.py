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
