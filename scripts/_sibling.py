"""Another script of this folder loaded as a module: the benchmarks share their runners (VQF, the SITL variants, …)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType


def load_script(stem: str, module_name: str | None = None) -> ModuleType:
    """``scripts/<stem>.py`` run as the module ``module_name`` (default ``stem``), registered in ``sys.modules``
    first (its dataclasses, and pickles of them in a benchmark cache, look their module up there)."""
    name = module_name or stem
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(f"{stem}.py"))
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
