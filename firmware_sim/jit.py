"""Kernels that run interpreted by default and compiled with numba on request.

The simulator's sequential loops (vehicle dynamics, biquad filters) are
written once as scalar Python.  Interpreted they start instantly, which is
what a live simulator (and every test that launches one) wants; compiled by
numba (``cache=True``) they make a ``--fast`` tlog of minutes take a second.
numba is imported only when a compiled kernel is first asked for, so a live
run never pays its start-up (about 2 s).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

__all__ = ["LazyKernel", "lazy_kernel"]


class LazyKernel:
    """A scalar kernel: ``k(...)`` runs it interpreted, ``k.select(jit=True)(...)`` compiled."""

    def __init__(self, func: Callable[..., Any]) -> None:
        self.py_func = func
        self._compiled: Callable[..., Any] | None = None
        functools.update_wrapper(self, func)

    def __call__(self, *args: Any) -> Any:
        return self.py_func(*args)

    def compiled(self) -> Callable[..., Any]:
        """The numba-compiled kernel (compiled or loaded from cache on first use); the
        interpreted one if numba is not installed."""
        if self._compiled is None:
            try:
                import numba
            except ImportError:  # pragma: no cover - numba is a core dependency
                self._compiled = self.py_func
            else:
                self._compiled = numba.njit(cache=True, error_model="numpy")(self.py_func)
        return self._compiled

    def select(self, jit: bool) -> Callable[..., Any]:
        return self.compiled() if jit else self.py_func


def lazy_kernel(func: Callable[..., Any]) -> LazyKernel:
    """Decorator: see :class:`LazyKernel`.  Kernels call no other kernels (numba needs that)."""
    return LazyKernel(func)
