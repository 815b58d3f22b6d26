"""The suite's own scheduling (tests/conftest.py): the real-time files handed out first name files that exist.

A renamed or moved real-time test file would silently drop out of ``LIVE_TESTS`` and be handed out in
collection order again, beside the CPU-bound files instead of first (docs/reliability.md, "Suite time
(branch speed1)").
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def test_every_live_entry_names_an_existing_test_file_or_folder() -> None:
    spec = importlib.util.spec_from_file_location("_suite_conftest", REPO / "tests" / "conftest.py")
    assert spec is not None and spec.loader is not None
    conftest = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conftest)
    assert conftest.LIVE_TESTS
    for entry in conftest.LIVE_TESTS:
        path = REPO / entry
        if entry.endswith("/"):
            assert path.is_dir() and any(path.glob("test_*.py")), entry
        else:
            assert path.is_file() and path.name.startswith("test_"), entry
