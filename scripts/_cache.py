"""The benchmarks' ``--cache``: a cached item is named by the code that made it, so a changed decoder is never
read from a stale pickle (a cache keyed by the log's name alone kept PX4's rows from before a change to the
sample chain, and the benchmark reported the old figures)."""

from __future__ import annotations

import hashlib
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def code_stamp(*paths: str, exclude: tuple[str, ...] = ()) -> str:
    """12 hex digits of SHA-256 over the ``.py`` files under ``paths`` (relative to the repo), minus ``exclude``."""
    h = hashlib.sha256()
    for rel in paths:
        root = REPO / rel
        files = [root] if root.is_file() else sorted(root.rglob("*.py"))
        for f in files:
            name = f.relative_to(REPO).as_posix()
            if any(name.startswith(x) for x in exclude):
                continue
            h.update(name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:12]


def file_stamp(path: Path) -> str:
    """The input file's size and modification time, so a replaced log is decoded again."""
    st = path.stat()
    return f"{st.st_size:x}-{st.st_mtime_ns:x}"
