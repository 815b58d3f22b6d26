"""The first-compile notice and ``mavahrs warm-up``.

On an empty numba cache (``NUMBA_CACHE_DIR``), a small cold compile (the ``complementary`` filter's paths,
then ``mahony``'s): a replay compiles what it needs and says so once, with "still compiling" lines and the
time it took; the first ``mavahrs audit`` compiles what it needs beyond that and says so, with what the
start-up cost, and the next one says it loaded the kernels.

That ``warm-up`` compiles every kernel a command needs is checked by listing, not by a second cold compile
of everything (tests/conftest.py's warm-up already pays one on a fresh machine, 180 CPU-s): in the suite's
own kernel cache, each process records the kernels it takes from numba as called from Python (a cache load,
or a compilation), each with its signature.  ``warm-up`` on that cache compiles nothing (run once before:
it is complete), and every kernel each later command takes is one that ``warm-up`` took — so on any
machine, after ``warm-up``, that command loads everything and compiles nothing (checked too: no notice).
Kernels that numba compiles into their caller (non-inlined callees) are not listed: a loaded caller carries
them.  The parts that ``warm-up --jobs 2`` compiles at once take every kernel the whole warm-up takes (so
the whole warm-up after them compiles nothing more).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mavahrs.cli.common import COMPILE_NOTICE
from mavahrs.protocol.tlog import tlog_record
from mavahrs.warmup import PARTS, STEPS, synthetic_frames

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
DATA = REPO.parent / "shared" / "data"  # ../shared/data, as tests/conftest.py


def _mavahrs(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        # a cold compile: seconds to minutes with ten times more runnable processes than cores; the
        # deadline is for a hung compiler only
        [sys.executable, "-m", "mavahrs", *args], env=env, capture_output=True, text=True, timeout=1800
    )


def _notices(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.endswith(" INFO " + COMPILE_NOTICE)]


#: ``python -c _RECORD OUT ARGS…``: ``mavahrs ARGS…`` that writes to OUT (JSON) the kernels of mavahrs it took
#: from numba as called from Python — "module.qualname(signature)": compiled (True) or loaded (False).
#: numba adds a specialisation to a dispatcher (``add_overload``) when it loads one from the cache and when
#: it compiles one; a callee compiled or loaded inside its caller's compilation is not listed (the caller's
#: machine code holds it), nor are the uncached driver loops (compiled in every process by design).
_RECORD = r"""
import atexit, json, runpy, sys
from numba.core import dispatcher, event

out = sys.argv[1]
sys.argv = ["mavahrs", *sys.argv[2:]]
compiling = []
taken = {}

class _Compiles(event.Listener):
    def on_start(self, ev):
        compiling.append(ev.data["dispatcher"])

    def on_end(self, ev):
        compiling.pop()

event.register("numba:compile", _Compiles())
add_overload = dispatcher.Dispatcher.add_overload

def record(self, cres):
    py = self.py_func
    ours = str(getattr(py, "__module__", "")).startswith("mavahrs")
    cached = type(getattr(self, "_cache", None)).__name__ != "NullCache"
    outermost = not compiling or (len(compiling) == 1 and compiling[0] is self)
    if ours and cached and outermost:
        taken[f"{py.__module__}.{py.__qualname__}{tuple(str(a) for a in cres.signature.args)}"] = bool(compiling)
    add_overload(self, cres)

dispatcher.Dispatcher.add_overload = record
atexit.register(lambda: open(out, "w").write(json.dumps(taken)))
runpy.run_module("mavahrs", run_name="__main__")
"""


def _recorded(env: dict[str, str], out: Path, *args: str) -> tuple[subprocess.CompletedProcess[str], dict[str, bool]]:
    """``mavahrs ARGS`` and the kernels it took (:data:`_RECORD`)."""
    env = {**env, "PYTHONPATH": os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", _RECORD, str(out), *args], env=env, capture_output=True,
                          text=True, timeout=1800, cwd=out.parent)  # fmt: skip
    taken = json.loads(out.read_text()) if out.exists() else {}
    return proc, taken


def test_compile_notice_on_a_cold_cache_only(tmp_path: Path) -> None:
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    # "still compiling" every second (30 s by default): the cold replay takes longer than that even when idle
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "MAVAHRS_COMPILE_PROGRESS_S": "1"}
    tlog = tmp_path / "rest.tlog"
    tlog.write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames(3.0)))

    cold = _mavahrs(env, "replay", str(tlog), "--filter", "complementary")
    assert cold.returncode == 0, cold.stderr
    assert len(_notices(cold.stderr)) == 1, cold.stderr
    assert "compiling" in COMPILE_NOTICE and "warm-up" in COMPILE_NOTICE
    assert re.search(r"INFO compiling the filters took \d+ s; kept in ", cold.stderr), cold.stderr  # measured
    assert cold.stderr.splitlines()[0].endswith(COMPILE_NOTICE), cold.stderr  # before anything else
    # progress while it compiles (a cold `mavahrs run` took 5-6 min on a busy VM with nothing said): after the
    # notice, before the measured time
    progress = [i for i, x in enumerate(cold.stderr.splitlines()) if " INFO still compiling the filter kernels: " in x]
    took = next(i for i, x in enumerate(cold.stderr.splitlines()) if "compiling the filters took" in x)
    assert progress and 0 < progress[0] and progress[-1] < took, cold.stderr
    assert any(cache.iterdir()), "the kernels were cached in NUMBA_CACHE_DIR"

    again = _mavahrs(env, "replay", str(tlog), "--filter", "complementary")
    assert again.returncode == 0, again.stderr
    assert _notices(again.stderr) == [] and "still compiling" not in again.stderr, again.stderr

    _first_audit_says_it_compiles(env, tmp_path)  # compiles `mahony`, not compiled by the replay above


@pytest.fixture(scope="module")
def warm_up_takes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bool]:
    """What ``mavahrs warm-up`` takes from the suite's kernel cache once that is complete (a first warm-up
    before, in case nothing filled it yet — tests/conftest.py's warm-up does, under xdist)."""
    tmp = tmp_path_factory.mktemp("warm-up-takes")
    first = _mavahrs(dict(os.environ), "warm-up")
    assert first.returncode == 0, first.stderr
    warm, taken = _recorded(dict(os.environ), tmp / "warm-up.json", "warm-up")
    assert warm.returncode == 0, warm.stderr
    lines = warm.stdout.splitlines()
    assert lines[0].startswith("warm-up: compiling every filter kernel for this version, cached in "), warm.stdout
    steps = [re.sub(r"\d+\.\d s$", "N s", x) for x in lines[1:-1]]
    assert steps in ([f"  {s}: N s" for s in STEPS], ["  2 processes at once: N s", *(f"  {s}: N s" for s in STEPS)])
    assert re.fullmatch(r"warm-up: done in \d+\.\d s; later commands start without compiling", lines[-1])
    assert _notices(warm.stderr) == [] and "still compiling" not in warm.stderr, warm.stderr
    assert taken and not any(taken.values()), {k for k, v in taken.items() if v}  # complete: compiles nothing
    # the ESKF's step and the daemon's fast lane: what a `mavahrs run` with `best` starts with
    assert any(k.startswith("mavahrs.filters.eskf.step(") for k in taken), sorted(taken)
    assert any(k.startswith("mavahrs.service.fastlane.") for k in taken), sorted(taken)
    return taken


def test_warm_up_takes_every_kernel_a_later_command_takes(tmp_path: Path, warm_up_takes: dict[str, bool]) -> None:
    tlog = tmp_path / "rest.tlog"
    tlog.write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames(3.0)))
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "flight.tlog").write_bytes(tlog.read_bytes())
    # the shared logs' other paths: two IMU instances (a SITL tlog), PX4's HIGHRES_IMU, a DataFlash .BIN (absent
    # data: those cases are left out)
    shared = [DATA / "sitl/arducopter_gentle.tlog", DATA / "px4_sitl/px4_aggressive.tlog",
              DATA / "sitl/arducopter_onboard.BIN"]  # fmt: skip
    commands = [
        ("replay", str(tlog), "--filter", "all", "--csv", str(tmp_path / "out.csv")),
        ("replay", str(tlog), "--filter", "all", "--engine", "pipeline"),
        ("tune", str(tlog)),
        ("audit", str(logs), "--serial", "--no-progress", "-o", str(tmp_path / "fleet.parquet")),
        *(("replay", str(p), "--no-progress") for p in shared if p.exists()),
    ]
    for k, args in enumerate(commands):
        proc, taken = _recorded(dict(os.environ), tmp_path / f"command{k}.json", *args)
        # the synthetic log is noiseless: tune refuses it (a gyro axis that never changes), after its kernels ran
        refused = args[0] == "tune" and proc.returncode == 1 and "not enough rest data" in proc.stderr
        assert proc.returncode == 0 or refused, proc.stderr
        assert taken, (args, "took no kernel: the listing is broken")
        assert set(taken) <= set(warm_up_takes), (args, sorted(set(taken) - set(warm_up_takes)))
        assert not any(taken.values()), (args, "compiled", {k for k, v in taken.items() if v})
        assert _notices(proc.stderr) == [] and "still compiling" not in proc.stderr, (args, proc.stderr)


def test_the_parts_compiled_at_once_take_everything_the_warm_up_takes(
    tmp_path: Path, warm_up_takes: dict[str, bool]
) -> None:
    """``warm-up --jobs 2`` compiles :data:`~mavahrs.warmup.PARTS` in processes of their own, then the whole
    warm-up in its own: that last one must find everything cached (on a cold cache it would otherwise compile
    the rest alone, on one core)."""
    union: dict[str, bool] = {}
    for part in PARTS:
        proc, taken = _recorded(dict(os.environ), tmp_path / f"{part}.json", "warm-up", "--part", part)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout == "" and _notices(proc.stderr) == [], (proc.stdout, proc.stderr)
        union.update(taken)
    assert set(warm_up_takes) <= set(union), sorted(set(warm_up_takes) - set(union))


def _first_audit_says_it_compiles(env: dict[str, str], tmp_path: Path) -> None:
    """The first ``mavahrs audit`` on a machine (here a kernel cache without `mahony`) says that it compiles and
    what that cost, beside the replay time; the next one says it loaded the kernels.

    Before, audit kept the ``mavahrs`` loggers at WARNING, so the compile notice never showed: a cold first run
    was silent for minutes after "starting a local Dask cluster", and its summary gave only the replay time.
    (Here, in the cold-cache test, so that the suite compiles the kernels cold once instead of twice; with
    `mahony`, a small filter: which one is compiled is not the subject.)
    """
    try:
        import distributed  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError:
        # the fleet extra is not installed (pip install '.[fleet]'): audit's part left out — but not under CI,
        # which installs it (tests/conftest.py: such a skip there is a broken install)
        assert not os.environ.get("CI"), "the fleet extra is missing under CI (.ci/run installs it)"
        return
    env = {**env, "PYTHONPATH": os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])}
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    logs = tmp_path / "logs"
    logs.mkdir()
    for k in range(2):
        (logs / f"flight{k}.tlog").write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames(3.0 + k)))

    def audit() -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "mavahrs", "audit", str(logs), "--workers", "1", "--no-progress",
                               "--filter", "mahony"],
                              env=env, capture_output=True, text=True, timeout=1800, cwd=tmp_path)  # fmt: skip

    cold = audit()
    assert cold.returncode == 0, cold.stderr
    assert _notices(cold.stderr), cold.stderr
    lines = cold.stdout.splitlines()
    assert lines[0].startswith("audited 2 logs (2 replayed, 0 already in the table) in "), cold.stdout
    m = re.fullmatch(r"start-up before the first log (\d+\.\d) s, not in the figures above: starting the local "
                     r"cluster \d+\.\d s; meanwhile the filter kernels compiled once in this process in (\d+) s, .*"
                     r"first run of this version.*", lines[1])  # fmt: skip
    assert m is not None, cold.stdout
    assert float(m.group(2)) <= float(m.group(1)) + 1.0  # the compile is part of the start-up

    warm = audit()
    assert warm.returncode == 0, warm.stderr
    assert _notices(warm.stderr) == [], warm.stderr
    assert re.fullmatch(r"start-up before the first log \d+\.\d s, not in the figures above: starting the local "
                        r"cluster \d+\.\d s; meanwhile the filter kernels loaded from the cache in \d+\.\d s",
                        warm.stdout.splitlines()[1]), warm.stdout  # fmt: skip


def test_the_kernels_survive_reinstalling_the_same_sources(tmp_path: Path) -> None:
    """`pip install ".[http]"` after `pip install .` writes the package anew (new files, new times, its
    ``__pycache__`` gone), and the next command compiled everything again (`run` silent for 102 s).  The same
    version installed in another virtual environment compiled everything again too (numba names a kernel's
    cache folder after the folder its file is installed in)."""
    import shutil

    repo = Path(__file__).resolve().parents[2]
    site, other_site, home = tmp_path / "site-packages", tmp_path / "other-venv-site-packages", tmp_path / "home"

    def install(where: Path = site) -> None:  # as pip does: the old tree removed, every file written fresh
        shutil.rmtree(where / "mavahrs", ignore_errors=True)
        shutil.copytree(repo / "mavahrs", where / "mavahrs", copy_function=shutil.copyfile,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc"))  # fmt: skip

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(HOME=str(home), XDG_CACHE_HOME=str(home / ".cache"))
    tlog = tmp_path / "rest.tlog"
    tlog.write_bytes(b"".join(tlog_record(t, f) for t, f in synthetic_frames(2.0)))
    def replay(where: Path = site) -> subprocess.CompletedProcess[str]:  # the installed copy (cwd elsewhere)
        return subprocess.run(
            [sys.executable, "-m", "mavahrs", "replay", str(tlog), "--filter", "complementary", "--no-progress"],
            env={**env, "PYTHONPATH": str(where)}, capture_output=True, text=True, timeout=900, cwd=tmp_path,
        )  # fmt: skip

    install()
    first = replay()
    assert first.returncode == 0 and len(_notices(first.stderr)) == 1, first.stderr
    kernels = home / ".cache" / "mavahrs" / "kernels"
    assert any(kernels.iterdir()), "kept in the user's cache folder"
    folders = sorted(p.name for p in kernels.iterdir())
    install()
    again = replay()
    assert again.returncode == 0, again.stderr
    assert _notices(again.stderr) == [], again.stderr  # nothing compiled again
    install(other_site)
    elsewhere = replay(other_site)
    assert elsewhere.returncode == 0, elsewhere.stderr
    assert _notices(elsewhere.stderr) == [], elsewhere.stderr  # the same version in another environment
    assert sorted(p.name for p in kernels.iterdir()) == folders  # and no folder of its own
    assert not (site / "mavahrs" / "filters" / "__pycache__").exists() or not any(
        p.suffix in (".nbi", ".nbc") for p in (site / "mavahrs" / "filters" / "__pycache__").iterdir()
    )
