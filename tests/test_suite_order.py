"""The suite's own scheduling (tests/conftest.py): the units handed out first name files that exist.

A renamed or moved long test file would silently drop out of ``LONG_TESTS`` and be handed out in
collection order again — the cold-compile test last, minutes after everything else (docs/reliability.md,
"Suite time (branch speed1)").
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _suite_conftest():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("_suite_conftest", REPO / "tests" / "conftest.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_long_unit_names_an_existing_test_file_or_folder() -> None:
    conftest = _suite_conftest()
    for entry in conftest.LONG_TESTS:
        path = REPO / entry.rstrip(":")
        assert path.exists(), entry
        if entry.endswith("/"):
            assert path.is_dir() and any(path.glob("test_*.py")), entry
        else:
            assert path.is_file() and path.name.startswith("test_"), entry


def test_units_and_ranks() -> None:
    conftest = _suite_conftest()
    cold = "tests/cli/test_cli_warm_up.py::test_compile_notice_on_a_cold_cache_only_and_warm_up_compiles_everything"
    assert conftest._unit(cold) == cold  # a unit of its own
    assert conftest._unit("tests/fleet/test_audit.py::test_every_row_of_the_fleet") == "tests/fleet/test_audit.py"
    assert conftest._long_rank(cold) == 0
    assert conftest._long_rank("tests/geometry/test_quaternion.py::test_x") == len(conftest.LONG_TESTS)
