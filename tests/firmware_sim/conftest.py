"""Helpers for the simulator's tests: run ``python -m firmware_sim`` as a real process."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def sim_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@contextmanager
def running_sim(*args: str, startup_timeout_s: float = 60.0) -> Iterator[tuple[subprocess.Popen[str], dict[str, str]]]:
    """Start the simulator; yields (process, {"LINK": ..., "PTY": ...}) once it printed its link.

    The process is terminated (then killed) on exit, whatever happens.
    """
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "-q", *args],
        cwd=str(REPO), env=sim_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    info: dict[str, str] = {}
    try:
        deadline = time.monotonic() + startup_timeout_s
        while "LINK" not in info:
            line = proc.stdout.readline() if proc.stdout else ""
            if not line:
                if proc.poll() is not None or time.monotonic() > deadline:
                    err = proc.stderr.read() if proc.stderr else ""
                    pytest.fail(f"simulator did not start (rc={proc.poll()}): {err[-2000:]}")
                continue
            key, _, value = line.strip().partition(" ")
            info[key] = value
        yield proc, info
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        for stream in (proc.stdout, proc.stderr):
            if stream:
                stream.close()


@pytest.fixture
def run_sim():  # type: ignore[no-untyped-def]
    """``with run_sim("--out", "udpin:127.0.0.1:0") as (proc, info): ...`` — see :func:`running_sim`."""
    return running_sim


@pytest.fixture
def sim_env_vars() -> dict[str, str]:
    """Environment for running ``python -m firmware_sim`` from the checkout."""
    return sim_env()


@pytest.fixture
def repo_root() -> Path:
    return REPO
