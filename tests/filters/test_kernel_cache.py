"""Where the compiled kernels are kept in the user's cache folder: by the contents of their sources, not by the
folder they are installed in, and old versions removed (``mavahrs.filters.jit``)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mavahrs.filters import jit

DAY_S = 86400.0


def _version(parent: Path, name: str, used_s: float) -> Path:
    d = parent / name
    d.mkdir()
    (d / "k-1.py312.nbi").write_bytes(b"x")
    os.utime(d, (used_s, used_s))
    return d


def test_versions_beyond_the_most_recent_are_removed_once_unused_for_a_day(tmp_path: Path) -> None:
    now = 1.0e9
    keep = jit.CACHE_KEEP_VERSIONS
    # the most recently used first: keep of them, then two used recently, then two old ones
    recent = [_version(tmp_path, f"filters_{k:040x}", now - 60.0 * k) for k in range(keep + 2)]
    old = [_version(tmp_path, f"filters_{k:040x}", now - 3 * DAY_S - k) for k in range(100, 102)]
    other = _version(tmp_path, "protocol.tlog_" + "a" * 40, now - 30 * DAY_S)  # another group: not counted
    underscored = [_version(tmp_path, f"service.fast_lane_{k:040x}", now - 30 * DAY_S - k) for k in range(keep + 1)]

    legacy_old = _version(tmp_path, "protocol_" + "b" * 40, now - 2 * DAY_S)  # numba's naming: by install folder
    legacy_recent = _version(tmp_path, "replay_" + "c" * 40, now - 60.0)

    removed = jit._prune_versions(str(tmp_path), "filters", now=now)
    assert sorted(removed) == sorted(str(p) for p in [*old, legacy_old])
    assert legacy_recent.is_dir()
    assert all(p.is_dir() for p in recent) and other.is_dir()  # used within the day: kept even beyond the four
    assert not any(p.exists() for p in old)
    assert all(p.is_dir() for p in underscored)

    # a group whose name holds underscores is told apart by the last one
    assert jit._prune_versions(str(tmp_path), "service.fast_lane", now=now) == [str(underscored[-1])]


@pytest.mark.skipif(not jit.HAVE_NUMBA, reason="numba absent: nothing is cached")
def test_one_folder_for_the_filters_one_per_other_module() -> None:
    import mavahrs

    package = Path(mavahrs.__file__).parent
    filters = jit.cache_subpath(str(package / "filters" / "madgwick.py"))
    assert filters == jit.cache_subpath(str(package / "filters" / "eskf.py"))  # one stamp for all of filters/
    assert filters.startswith("filters_")
    tlog = jit.cache_subpath(str(package / "protocol" / "tlog.py"))
    assert tlog.startswith("protocol.tlog_") and tlog != filters


_RUN = """
import sys
from pathlib import Path

import mavahrs.filters.jit as jit

root = Path(sys.argv[1])
jit._PACKAGE_DIR = str(root / "mavahrs_probe")  # its two files stand for two modules of the package
jit.user_cache_dir = lambda: str(root / "cache")
compiled = []
jit.on_first_compile(compiled.append)
sys.path.insert(0, str(root))
from mavahrs_probe.caller import twice_plus

print(twice_plus(1.0), bool(compiled))
"""


def _run_probe(root: Path, env: dict[str, str]) -> tuple[float, bool]:
    """The probe package's kernel run in a fresh process: its value, and whether it was compiled (not loaded)."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _RUN, str(root)], capture_output=True, text=True,
                          timeout=300, env=env, cwd=root)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    value, compiled = proc.stdout.split()
    return float(value), compiled == "True"


@pytest.mark.skipif(not jit.HAVE_NUMBA, reason="numba absent: nothing is cached")
@pytest.mark.parametrize("numba_cache_dir", [False, True], ids=["user cache", "NUMBA_CACHE_DIR"])
def test_a_kernel_calling_another_files_kernel_is_compiled_again_when_that_file_changes(
    tmp_path: Path, numba_cache_dir: bool
) -> None:
    """numba stamps a cached kernel with its own file only; a kernel it calls from another file is compiled into
    it, so without the dependency in the stamp the caller kept the callee's old code after the callee changed."""

    pkg = tmp_path / "mavahrs_probe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    callee = pkg / "callee.py"
    callee.write_text("from mavahrs.filters.jit import kernel\n\n\n@kernel\ndef plus(x):\n    return x + 1.0\n")
    (pkg / "caller.py").write_text(
        "from mavahrs.filters.jit import kernel\nfrom mavahrs_probe.callee import plus\n\n\n"
        "@kernel\ndef twice_plus(x):\n    return 2.0 * plus(x)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    if numba_cache_dir:
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba")

    def run() -> tuple[float, bool]:
        return _run_probe(tmp_path, env)

    assert run() == (4.0, True)  # a cold cache: compiled
    assert run() == (4.0, False)  # nothing changed: loaded from the cache
    callee.write_text(callee.read_text().replace("x + 1.0", "x + 5.0"))
    assert run() == (12.0, True)  # the callee's file changed: the caller is compiled again with it
    assert run() == (12.0, False)


@pytest.mark.skipif(not jit.HAVE_NUMBA, reason="numba absent: nothing is cached")
def test_a_kernel_is_compiled_again_when_a_constant_it_imports_changes(tmp_path: Path) -> None:
    """An imported module-level constant (a layout's column offset) is compiled into the kernel as a literal:
    a change in the file it comes from must compile the kernel again, not load the old one."""

    pkg = tmp_path / "mavahrs_probe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "callee.py").write_text("from mavahrs.filters.jit import kernel\n\n\n@kernel\ndef plus(x):\n    return x\n")
    consts = pkg / "consts.py"
    consts.write_text("OFFSET = 1.0\n")
    (pkg / "caller.py").write_text(
        "from mavahrs.filters.jit import kernel\nfrom mavahrs_probe.callee import plus\n"
        "from mavahrs_probe.consts import OFFSET\n\n\n@kernel\ndef twice_plus(x):\n    return 2.0 * (plus(x) + OFFSET)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}

    def run() -> tuple[float, bool]:
        return _run_probe(tmp_path, env)

    assert run() == (4.0, True)
    assert run() == (4.0, False)
    consts.write_text("OFFSET = 3.0\n")
    assert run() == (8.0, True)  # the constant's file changed: compiled again with the new literal
    assert run() == (8.0, False)


@pytest.mark.skipif(not jit.HAVE_NUMBA, reason="numba absent: nothing is cached")
def test_the_files_of_the_kernels_a_module_calls_are_its_kernels_dependencies() -> None:
    import mavahrs
    from mavahrs.service import fastlane

    package = Path(mavahrs.__file__).parent
    deps = jit.kernel_dependencies(fastlane._parse.py_func)
    for called in ("protocol/fast_tlog.py", "sensors/scaling.py", "ingest/timeline.py"):
        assert str(package / called) in deps
    assert str(package / "service" / "fastlane.py") not in deps  # its own file is numba's stamp already
    scaling = jit.kernel_dependencies(__import__("mavahrs.sensors.scaling", fromlist=["x"]).scale_int_row.py_func)
    assert str(package / "filters" / "layout.py") in scaling  # its column offsets are compiled in
    assert jit.cache_subpath(fastlane.__file__, deps) != jit.cache_subpath(fastlane.__file__)


def _lock_waiters(inode: int) -> int:
    """Processes/threads blocked in ``flock`` on the file with ``inode`` (``/proc/locks``: ``N: -> FLOCK …``)."""
    with open("/proc/locks", encoding="ascii") as f:
        return sum(1 for line in f if " -> " in line and line.split()[6].rsplit(":", 1)[-1] == str(inode))


@pytest.mark.skipif(not jit.HAVE_NUMBA, reason="numba absent: nothing is cached")
@pytest.mark.skipif(not os.path.exists("/proc/locks"), reason="needs Linux's /proc/locks to see a waiting lock")
def test_processes_adding_kernels_to_one_cache_folder_take_turns(tmp_path: Path) -> None:
    """numba's save reads a kernel's index, picks the first free data file number and writes index and data,
    without a lock: two processes saving two signatures at once (``warm-up --jobs 2``, the test workers) could
    both pick ``.1.nbc``, and the index then named one signature's machine code for the other's.  Here
    another process is in the middle of its save (it holds the folder's lock, has read the index and writes
    its entry); a save meanwhile waits for it, then adds its own entry beside it."""
    import fcntl
    import threading
    import time

    from numba.core.caching import IndexDataCacheFile

    def index() -> IndexDataCacheFile:
        return IndexDataCacheFile(str(tmp_path), "probe.kernel-1.py311", "stamp")

    other, ours = index(), index()
    fd = os.open(tmp_path / jit.CACHE_LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o666)
    fcntl.flock(fd, fcntl.LOCK_EX)  # the other process's save has begun
    assert other._load_index() == {}
    saved = threading.Event()
    thread = threading.Thread(target=lambda: (ours.save(("sig", "ours"), b"ours"), saved.set()), daemon=True)
    thread.start()
    inode = os.fstat(fd).st_ino
    while not saved.is_set() and not _lock_waiters(inode):  # an event either way: it waits, or it saved
        time.sleep(0.005)
    try:
        assert not saved.is_set(), "saved while another process was in the middle of saving to the folder"
        other._save_data(other._data_name(1), b"other's")  # the other process's entry: data, then index
        other._save_index({("sig", "other"): other._data_name(1)})
    finally:
        os.close(fd)  # its save is done: the lock is free
    thread.join(timeout=60)
    assert saved.is_set()
    assert index().load(("sig", "other")) == b"other's"
    assert index().load(("sig", "ours")) == b"ours"  # its own data file, not the other's
