"""Optional compilation of filter kernels with numba.

Every filter's mathematics is written once, as a plain-Python function on
scalars and flat ``float64`` arrays (the *kernel*).  Run by the interpreter it
is the readable reference; compiled by numba (cached on disk, so only the first
run on a machine pays for compilation) the same source is the fast path for
batch replay and for the live daemon.  Without numba everything still works,
only slower.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["kernel", "HAVE_NUMBA"]

F = TypeVar("F", bound=Callable[..., Any])

try:  # numba is a core dependency, but the package must still run without it
    import numba as _numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only where numba is absent
    _numba = None
    HAVE_NUMBA = False


class _Interpreted:
    """Stand-in for a numba dispatcher: exposes ``py_func`` like numba does."""

    def __init__(self, func: Callable[..., Any]) -> None:
        self.py_func = func
        self.__wrapped__ = func
        self.__doc__ = func.__doc__
        self.__name__ = func.__name__

    def __call__(self, *args: Any) -> Any:
        return self.py_func(*args)


def kernel(func: F) -> F:
    """Compile ``func`` lazily with numba (``cache=True``), keeping ``.py_func``.

    No ``fastmath``: the compiled and the interpreted kernels must agree to
    rounding (tested to 1e-9).
    """
    if HAVE_NUMBA:
        return _numba.njit(cache=True, error_model="numpy")(func)  # type: ignore[no-any-return]
    return _Interpreted(func)  # type: ignore[return-value]
