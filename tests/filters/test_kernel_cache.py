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
