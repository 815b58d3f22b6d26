"""``.ci/run`` leaves no virtual environment behind (or keeps the one it is told to reuse).

The script's own steps (``python3 -m venv``, pip) are replaced by a stand-in
``python3`` on ``PATH`` that creates the environment directory and fails, so
these tests cost milliseconds and check what is left in the temporary
directory when the run ends (here: by a failure, the case a trap must cover).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

_FAKE_PYTHON3 = """#!/bin/sh
# stand-in for `python3 -m venv DIR`: create DIR (as venv does), then fail like a broken install
if [ "$1" = "-m" ] && [ "$2" = "venv" ]; then mkdir -p "$3/bin"; echo created > "$3/marker"; fi
exit 7
"""


def _run_ci(tmp_path: Path, **env: str) -> tuple[subprocess.CompletedProcess[str], Path]:
    bindir = tmp_path / "bin"
    bindir.mkdir()
    fake = bindir / "python3"
    fake.write_text(_FAKE_PYTHON3)
    fake.chmod(0o755)
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    proc = subprocess.run(
        ["bash", str(REPO / ".ci" / "run")],
        env={**os.environ, "PATH": f"{bindir}:{os.environ['PATH']}", "TMPDIR": str(tmpdir), **env},
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    return proc, tmpdir


def test_ci_run_removes_its_virtual_environment_on_exit(tmp_path: Path) -> None:
    proc, tmpdir = _run_ci(tmp_path)
    assert proc.returncode == 7, proc.stderr  # the stand-in's failure, passed on by `set -e`
    assert list(tmpdir.iterdir()) == []


def test_ci_run_keeps_a_named_environment(tmp_path: Path) -> None:
    named = tmp_path / "ci-venv"
    proc, tmpdir = _run_ci(tmp_path, MAVAHRS_CI_VENV=str(named))
    assert proc.returncode == 7, proc.stderr
    assert (named / "marker").read_text() == "created\n"
    assert list(tmpdir.iterdir()) == []
