"""The fleet and replay packages use each other's and evaluation's public names only, and the replay package
hands on exactly its engine's public names (one list, kept in the engine)."""

from __future__ import annotations

import ast
from pathlib import Path

import mavahrs

ROOT = Path(mavahrs.__file__).parent


def _private_imports(path: Path) -> list[str]:
    """``from mavahrs.X import _name`` in ``path`` where X is another module than the file's own."""
    own = ".".join(("mavahrs", *path.relative_to(ROOT).with_suffix("").parts))
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("mavahrs") and node.module != own:
            out += [f"{path.relative_to(ROOT)}: {node.module}.{a.name}" for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")]  # fmt: skip
    return out


def test_fleet_and_replay_import_no_private_name_of_another_module() -> None:
    files = sorted((ROOT / "fleet").glob("*.py")) + sorted((ROOT / "replay").glob("*.py"))
    assert files
    found = [hit for f in files for hit in _private_imports(f)]
    assert found == []


def test_replay_package_hands_on_exactly_the_engines_public_names() -> None:
    import mavahrs.replay as pkg
    from mavahrs.replay import engine

    assert list(pkg.__all__) == list(engine.__all__)
    assert len(set(engine.__all__)) == len(engine.__all__)
    for name in engine.__all__:
        assert getattr(pkg, name) is getattr(engine, name), name


def test_every_name_taken_from_the_replay_package_is_public() -> None:
    """What the package, the scripts and the tests import from ``mavahrs.replay`` is in its ``__all__``."""
    import mavahrs.replay as pkg

    used: set[str] = set()
    for base in (ROOT, ROOT.parent / "scripts", ROOT.parent / "tests"):
        for f in base.rglob("*.py"):
            try:
                tree = ast.parse(f.read_text(encoding="utf-8"))
            except (SyntaxError, UnicodeDecodeError):
                continue
            used |= {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module == "mavahrs.replay"
                     for a in n.names}  # fmt: skip
    assert used, "nothing imports mavahrs.replay: the scan found no file"
    assert sorted(used - set(pkg.__all__) - {"engine"}) == []  # (the module itself: `from mavahrs.replay import engine`)
