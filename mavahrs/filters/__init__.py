"""Attitude filters: one module each, one interface (:class:`~mavahrs.filters.base.AttitudeFilter`).

``create(name, settings=None)`` returns a per-sample filter; ``NAMES`` lists
the filters; ``"best"`` is the configuration the project recommends (see
:mod:`mavahrs.filters.best`).  Modules are imported on first use so that the
command line starts fast.
"""

from __future__ import annotations

import importlib
from typing import Any

from mavahrs.filters.base import AttitudeFilter, FilterSettings

__all__ = ["NAMES", "ALIASES", "create", "filter_class", "AttitudeFilter", "FilterSettings"]

#: The filters, in the order they are documented.
NAMES: tuple[str, ...] = ("madgwick", "mahony", "complementary", "gyroplatform", "eskf")
#: Other accepted names.
ALIASES: tuple[str, ...] = ("best",)

_CLASSES: dict[str, tuple[str, str]] = {
    "madgwick": ("mavahrs.filters.madgwick", "Madgwick"),
    "mahony": ("mavahrs.filters.mahony", "Mahony"),
    "complementary": ("mavahrs.filters.complementary", "Complementary"),
    "gyroplatform": ("mavahrs.filters.gyroplatform", "GyroPlatform"),
    "eskf": ("mavahrs.filters.eskf", "Eskf"),
}


def filter_class(name: str) -> type[AttitudeFilter]:
    """The class registered under ``name`` (one of :data:`NAMES`)."""
    try:
        module, cls = _CLASSES[name]
    except KeyError:
        raise ValueError(
            f"unknown filter {name!r}; choose one of {', '.join(NAMES + ALIASES)}"
        ) from None
    return getattr(importlib.import_module(module), cls)  # type: ignore[no-any-return]


def create(name: str, settings: FilterSettings | None = None, **kwargs: Any) -> AttitudeFilter:
    """A new per-sample filter.  ``name="best"`` ignores ``settings`` unless given."""
    if name == "best":
        from mavahrs.filters.best import create_best

        return create_best(settings, **kwargs)
    return filter_class(name)(settings, **kwargs)
