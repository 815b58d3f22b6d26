"""Optional compilation of filter kernels with numba.

Every filter's mathematics is written once, as a plain-Python function on
scalars and flat ``float64`` arrays (the *kernel*).  Run by the interpreter it
is the readable reference; compiled by numba (cached on disk, so only the first
run on a machine pays for compilation) the same source is the fast path for
batch replay and for the live daemon.  Without numba everything still works,
only slower.

Cache freshness: numba re-uses a cached compilation while the *function's own
file* is unchanged, but kernels bake in module-level constants of other files
(the row layouts, ``P_FILTER`` = length of the gain-schedule block, …).  For
kernels in this package the cache stamp therefore covers every ``.py`` file
of ``mavahrs/filters`` — a hash of their contents, not their times, so that
reinstalling the same sources keeps the kernels: editing one invalidates
all, instead of silently running code compiled against an old layout.  The
cache lives in ``NUMBA_CACHE_DIR`` when set (the systemd unit's
``/var/cache/mavahrs``), else in the user's cache folder
(``~/.cache/mavahrs/kernels``, :func:`user_cache_dir`) — outside the
installation, which ``pip install ".[extra]"`` replaces with everything in
it — else (no writable home) in ``mavahrs/filters/__pycache__``.  In the user's
cache folder a kernel's place is named by its sources' contents, not by where
they are installed (:func:`cache_subpath`): a second virtual environment with
the same version loads what the first compiled, and installs into temporary
folders leave nothing behind there; the folders of versions unused for a day
beyond the four most recently used are removed (:data:`CACHE_KEEP_VERSIONS`).  A kernel elsewhere in the
package that calls a kernel of another of its files (an import) is compiled with that kernel in it, and
numba's stamp (its own file) would keep it after the other file changed: its stamp and its folder cover
the files of every kernel its module imports, and theirs in turn (:func:`kernel_dependencies`).  ``mavahrs warm-up``
(:mod:`mavahrs.warmup`) fills it ahead of time; :func:`on_first_compile` tells
the command line when a process is about to compile (a cold cache).

Speed (``docs/performance.md``): kernels of ``mavahrs/filters`` work on
arrays their caller owns and never allocate, so they are compiled without
numba's reference counting (``_nrt=False``): with it, every array argument,
row view and slice costs an atomic increment/decrement pair, which took more
than half of a Madgwick step.  Helpers that LLVM will not inline by itself
(too large) but that run on every sample are marked ``@kernel(inline=True)``
and inlined by numba into each filter's step; doing that for *every* kernel
triples the first compilation for little further gain.  Neither changes a
result: the same operations run in the same order.
"""

from __future__ import annotations

import os
import sys
import types
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = [
    "kernel",
    "loop_kernel",
    "bound_loop",
    "pure_python",
    "prange",
    "quick_start",
    "on_first_compile",
    "cache_location",
    "user_cache_dir",
    "cache_subpath",
    "kernel_dependencies",
    "HAVE_NUMBA",
]

F = TypeVar("F", bound=Callable[..., Any])

#: code objects of the cached kernels compiled without reference counting: loading one from the
#: cache needs no numba runtime (:func:`quick_start`)
_NO_RUNTIME: set[types.CodeType] = set()


def _import_numba() -> Any:
    """``import numba`` without the two optional imports it makes on the way that mavahrs never uses.

    numba imports PyYAML to read a ``.numba_config.yaml`` in the working directory (skipped only when
    there is none) and SciPy to check its version (skipped when SciPy is not already loaded; it
    imports as usual later): a tenth of numba's import, on every command's start.  Both are restored
    in ``sys.modules`` right after.
    """
    hidden = []
    if not os.path.isfile(".numba_config.yaml") and "yaml" not in sys.modules:
        hidden.append("yaml")
    if "scipy" not in sys.modules:
        hidden.append("scipy")
    for name in hidden:
        sys.modules[name] = None  # type: ignore[assignment]  # import name → ImportError
    try:
        import numba
    finally:
        for name in hidden:
            if name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]
    return numba


try:  # numba is a core dependency, but the package must still run without it
    _numba = _import_numba()

    HAVE_NUMBA = True
    prange = _numba.prange
except ImportError:  # pragma: no cover - exercised only where numba is absent
    _numba = None
    HAVE_NUMBA = False
    prange = range

_FILTERS_DIR = os.path.dirname(os.path.abspath(__file__))
_PACKAGE_DIR = os.path.dirname(_FILTERS_DIR)


def _filters_files() -> tuple[tuple[str, int, int], ...]:
    out = []
    for name in sorted(os.listdir(_FILTERS_DIR)):
        if name.endswith(".py"):
            st = os.stat(os.path.join(_FILTERS_DIR, name))
            out.append((name, st.st_mtime_ns, st.st_size))
    return tuple(out)


_STAMPS: dict[tuple[tuple[str, int, int], ...], str] = {}


def _filters_source_stamp() -> str:
    """A hash of the *contents* of every ``.py`` file of ``mavahrs/filters`` (names included).

    Not their modification times: reinstalling the same version (``pip install ".[http]"`` after
    ``pip install .``) writes the same files anew, and the compiled kernels stay valid.  Hashed
    again only when a file's time or size changes.
    """
    import hashlib

    files = _filters_files()
    stamp = _STAMPS.get(files)
    if stamp is None:
        h = hashlib.sha256()
        for name, _t, _n in files:
            h.update(name.encode() + b"\0")
            with open(os.path.join(_FILTERS_DIR, name), "rb") as f:
                h.update(f.read())
            h.update(b"\0")
        stamp = _STAMPS[files] = h.hexdigest()
    return stamp


_JIT_STAMP: list[str] = []


def _jit_module_stamp() -> str:
    """A hash of this module's source (the compile options of every kernel of the package are set here)."""
    if not _JIT_STAMP:
        import hashlib

        with open(os.path.abspath(__file__), "rb") as f:
            _JIT_STAMP.append(hashlib.sha256(f.read()).hexdigest())
    return _JIT_STAMP[0]


#: versions kept per kernel file in the user's cache folder: the most recently used ones; older ones are removed
#: when a new version is compiled there, once unused for :data:`CACHE_PRUNE_AFTER_S` (a process still running
#: an old version may compile a new signature into its folder)
CACHE_KEEP_VERSIONS = 4
CACHE_PRUNE_AFTER_S = 86400.0

_CONTENT_HASHES: dict[tuple[str, int, int], str] = {}
_USED_PATHS: set[str] = set()


def cache_subpath(py_file: str, depends: tuple[str, ...] = ()) -> str:
    """The folder, inside the user's cache folder, of the kernels of ``py_file`` (a module of this package).

    ``GROUP_VERSION``: GROUP names the module (``filters`` for every module of ``mavahrs/filters``, whose
    kernels share one stamp; else its dotted path in the package, e.g. ``protocol.tlog``) and VERSION is a
    hash of the sources the kernels are compiled from (all of ``mavahrs/filters``; else the module's own
    file, the files ``depends`` of the kernels it calls (:func:`kernel_dependencies`) and this one, which
    decides the compile options).  numba's own choice, a hash of the folder the
    file is installed in, gave every virtual environment and every temporary install a cold compile of
    its own (2–5 minutes on two cores) and a folder that nothing removed.
    """
    import hashlib

    path = os.path.abspath(py_file)
    if os.path.dirname(path) == _FILTERS_DIR:
        return "filters_" + _filters_source_stamp()[:40]
    rel = os.path.relpath(path, _PACKAGE_DIR)
    group = os.path.splitext(rel)[0].replace(os.sep, ".")
    digest = _file_digest(path)
    if depends:
        h = hashlib.sha256(digest.encode())
        for dep in depends:
            h.update(b"\0" + _file_digest(dep).encode())
        digest = h.hexdigest()[:40]
    return f"{group}_{digest}"


def _file_digest(path: str) -> str:
    """A hash of this module's source and the contents of ``path`` (hashed again only when its time or size changes)."""
    import hashlib

    st = os.stat(path)
    key = (path, st.st_mtime_ns, st.st_size)
    digest = _CONTENT_HASHES.get(key)
    if digest is None:
        h = hashlib.sha256(_jit_module_stamp().encode() + b"\0")
        with open(path, "rb") as f:
            h.update(f.read())
        digest = _CONTENT_HASHES[key] = h.hexdigest()[:40]
    return digest


def kernel_dependencies(py_func: Any) -> tuple[str, ...]:
    """The source files, other than its own, that ``py_func``'s compiled code depends on, sorted.

    Those are the files of the package's compiled kernels bound in its module's globals (imported at
    the top: a kernel calls no other), and theirs in turn; and the package's modules each of those
    modules imports from at its top, whose constants (``IN_GYRO``, a layout's offsets) are compiled into
    the kernels as literals.  numba compiles a called kernel into its caller and stamps the caller's cache
    with the caller's file alone, so a change to the called kernel's file or to an imported constant would
    otherwise leave the caller's old machine code in use (mavahrs/ingest's shared running mean, the fast
    lane's parser, the scaling kernels' column offsets).  Read when the kernel is decorated: its module's
    imports are there.  Files of ``mavahrs/filters`` count like any other (their own kernels are stamped
    with all of them).
    """
    own = os.path.abspath(py_func.__code__.co_filename)
    files: set[str] = set(_imported_package_files(own))
    seen: set[str] = set()
    todo = [py_func.__globals__]
    while todo:
        glb = todo.pop()
        for value in list(glb.values()):
            py = getattr(value, "py_func", None)
            code = getattr(py, "__code__", None)
            if code is None or not isinstance(py, types.FunctionType):
                continue
            path = os.path.abspath(code.co_filename)
            if path == own or not path.startswith(_PACKAGE_DIR + os.sep) or path in seen:
                continue
            seen.add(path)
            files.add(path)
            files.update(_imported_package_files(path))
            todo.append(py.__globals__)
    files.discard(own)
    return tuple(sorted(files))


_IMPORTS: dict[str, tuple[str, ...]] = {}


def _imported_package_files(path: str) -> tuple[str, ...]:
    """The files of the package's modules that the module at ``path`` imports from at its top level
    (``from mavahrs.x import NAME`` and ``import mavahrs.x``; a name that is itself a module counts as
    its file); read once per file."""
    import ast

    done = _IMPORTS.get(path)
    if done is not None:
        return done
    try:
        with open(path, "rb") as f:
            tree = ast.parse(f.read(), path)
    except (OSError, SyntaxError, ValueError):
        _IMPORTS[path] = ()
        return ()
    names: list[str] = []
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and not node.level and node.module:
            names.append(node.module)
            names.extend(f"{node.module}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            names.extend(alias.name for alias in node.names)
    found: set[str] = set()
    package = os.path.basename(_PACKAGE_DIR)
    for name in names:
        parts = name.split(".")
        if parts[0] != package:
            continue
        base = os.path.join(_PACKAGE_DIR, *parts[1:])
        for candidate in (base + ".py", os.path.join(base, "__init__.py")):
            if os.path.isfile(candidate):
                found.add(os.path.abspath(candidate))
                break
    found.discard(os.path.abspath(path))
    _IMPORTS[path] = done = tuple(sorted(found))
    return done


def _use_cache_path(path: str) -> None:
    """Create ``path`` (a version's folder in the user's cache), mark it used now (its folder time), and when
    it is new remove the same group's versions beyond :data:`CACHE_KEEP_VERSIONS` unused for a day."""
    if path in _USED_PATHS:
        return
    new = not os.path.isdir(path)
    os.makedirs(path, exist_ok=True)
    try:
        os.utime(path)
    except OSError:
        pass  # another user's folder: numba's own check decides whether it is usable
    _USED_PATHS.add(path)
    if new:  # "now" as the file system tells it: the new folder's time
        _prune_versions(os.path.dirname(path), os.path.basename(path).rsplit("_", 1)[0], os.stat(path).st_mtime)


def _prune_versions(parent: str, group: str, now: float) -> list[str]:
    """Remove ``group``'s version folders in ``parent`` beyond the :data:`CACHE_KEEP_VERSIONS` most recently
    used, and the folders of numba's own naming (``protocol_<hash of the install folder>``, the package's
    cache until 2026-12-06), if unused for :data:`CACHE_PRUNE_AFTER_S` before ``now`` (s, the folder times'
    clock); returns the removed folders."""
    import shutil

    found, legacy = [], []
    try:
        with os.scandir(parent) as it:
            for e in it:
                if not e.is_dir(follow_symlinks=False):
                    continue
                name = e.name.rsplit("_", 1)[0]
                if name == group:
                    found.append((e.stat(follow_symlinks=False).st_mtime, e.path))
                elif name != "filters" and "." not in name:  # numba's own naming, before 2026-12-06: a
                    legacy.append((e.stat(follow_symlinks=False).st_mtime, e.path))  # folder per install place
    except OSError:
        return []
    found.sort(reverse=True)
    removed = []
    for used_s, folder in found[CACHE_KEEP_VERSIONS:] + legacy:
        if now - used_s >= CACHE_PRUNE_AFTER_S:
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


def user_cache_dir() -> str:
    """The kernels' cache outside the installation: ``$XDG_CACHE_HOME/mavahrs/kernels`` (``~/.cache/…``;
    the platform's user cache folder elsewhere), so that reinstalling the package keeps it."""
    try:
        from numba.misc.appdirs import AppDirs

        base = AppDirs(appname="mavahrs", appauthor=False).user_cache_dir
    except Exception:  # noqa: BLE001 - numba's helper moved or absent: the XDG default
        base = os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "mavahrs")
    return os.path.join(base, "kernels")


if HAVE_NUMBA:
    from numba.core import caching as _caching

    class _FiltersStamp:
        """Cache-locator mixin for kernels in ``mavahrs/filters``: stamp = all its sources."""

        def get_source_stamp(self) -> Any:
            return _filters_source_stamp()

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if os.path.dirname(os.path.abspath(py_file)) != _FILTERS_DIR:
                return None  # not ours: numba's own locators decide
            return super().from_function(py_func, py_file)  # type: ignore[misc]

    class _FiltersUserCacheLocator(_FiltersStamp, _caching.UserProvidedCacheLocator):  # type: ignore[misc]
        """``NUMBA_CACHE_DIR`` set (e.g. the systemd unit's /var/cache/mavahrs): the cache goes there."""

    class _FiltersMavahrsCacheLocator(_FiltersStamp, _caching.UserWideCacheLocator):  # type: ignore[misc]
        """Otherwise the user's cache folder (:func:`user_cache_dir`), outside the installation: ``pip install``
        replaces ``mavahrs/filters`` (and its ``__pycache__``) whenever an extra is added, …  One folder per
        version of the sources (:func:`cache_subpath`), wherever they are installed."""

        def __init__(self, py_func: Any, py_file: str) -> None:
            super().__init__(py_func, py_file)
            self._cache_path = os.path.join(user_cache_dir(), cache_subpath(py_file))

        def ensure_cache_path(self) -> None:
            _use_cache_path(self._cache_path)
            super().ensure_cache_path()

    class _FiltersCacheLocator(_FiltersStamp, _caching.InTreeCacheLocator):  # type: ignore[misc]
        """… else (no writable home) ``mavahrs/filters/__pycache__``, numba's own default place."""

    class _DependsStamp:
        """Cache-locator mixin for the package's kernels outside ``mavahrs/filters``: numba's stamp (the
        file's time and size) with this module's contents and the contents of the files of the kernels the
        module imports (:func:`kernel_dependencies`; a change there must compile the callers again)."""

        _depends: tuple[str, ...] = ()

        def get_source_stamp(self) -> Any:
            return (super().get_source_stamp(), _jit_module_stamp(),  # type: ignore[misc]
                    tuple(_file_digest(p) for p in self._depends))  # fmt: skip

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            path = os.path.abspath(py_file)
            if not path.startswith(_PACKAGE_DIR + os.sep) or os.path.dirname(path) == _FILTERS_DIR:
                return None
            return super().from_function(py_func, py_file)  # type: ignore[misc]

    class _MavahrsUserCacheLocator(_DependsStamp, _caching.UserProvidedCacheLocator):  # type: ignore[misc]
        """``NUMBA_CACHE_DIR`` set: the package's other kernels go there, numba's folder naming, our stamp."""

        def __init__(self, py_func: Any, py_file: str) -> None:
            super().__init__(py_func, py_file)
            self._depends = kernel_dependencies(py_func)

    class _MavahrsCacheLocator(_DependsStamp, _caching.UserWideCacheLocator):  # type: ignore[misc]
        """The other kernels of the package (tlog decoder, replay, CSV, fast lane) go to the same user cache
        folder, unless ``NUMBA_CACHE_DIR`` is set.  Their stamp is numba's own (their file's time and size)
        with this module's contents: the options every kernel is compiled with (reference counting or
        not) are decided here, and numba's cache index does not tell them apart — a kernel cached with
        other options must be compiled again, not loaded; and with the files of the kernels they call."""

        def __init__(self, py_func: Any, py_file: str) -> None:
            super().__init__(py_func, py_file)
            self._depends = kernel_dependencies(py_func)
            self._cache_path = os.path.join(user_cache_dir(), cache_subpath(py_file, self._depends))

        def ensure_cache_path(self) -> None:
            _use_cache_path(self._cache_path)
            super().ensure_cache_path()

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if _numba.config.CACHE_DIR:
                return None
            return super().from_function(py_func, py_file)

    class _MavahrsInTreeCacheLocator(_DependsStamp, _caching.InTreeCacheLocator):  # type: ignore[misc]
        """… else (no writable home) the module's ``__pycache__``, numba's own default place, our stamp."""

        def __init__(self, py_func: Any, py_file: str) -> None:
            super().__init__(py_func, py_file)
            self._depends = kernel_dependencies(py_func)

    _locators = _caching.CacheImpl._locator_classes
    _locators[:] = [c for c in _locators if not getattr(c, "__name__", "").startswith(("_Filters", "_Mavahrs"))]
    _locators[0:0] = [_FiltersUserCacheLocator, _FiltersMavahrsCacheLocator, _FiltersCacheLocator,
                      _MavahrsUserCacheLocator, _MavahrsCacheLocator, _MavahrsInTreeCacheLocator]  # idempotent across re-imports

    #: the lock file, in each cache folder, that serialises the processes adding kernels to that folder
    CACHE_LOCK_NAME = ".mavahrs-save.lock"

    def _save_locked(self: Any, key: Any, data: Any) -> Any:
        """numba's ``IndexDataCacheFile.save``, made safe for several processes adding to one cache folder.

        numba reads the kernel's index, picks the first data file number the index does not use, writes the
        index and then the data file — without a lock.  Two processes saving two signatures of one kernel at
        once (``mavahrs warm-up`` compiling on several processes; the test workers; a daemon beside a replay)
        could both pick ``.1.nbc``: the index then names one signature while the file holds the other's
        machine code.  Here the read-modify-write holds an exclusive ``flock`` on :data:`CACHE_LOCK_NAME` in
        the folder, and the data file is written before the index that names it, so a process loading at
        the same time finds either the old index or the new one with its data.
        """
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: numba's own save
            return _numba_save(self, key, data)  # type: ignore[no-any-return]
        os.makedirs(self._cache_path, exist_ok=True)
        fd = os.open(os.path.join(self._cache_path, CACHE_LOCK_NAME), os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            overloads = self._load_index()
            data_name = overloads.get(key)
            if data_name is not None:  # the same signature again: its file is replaced, the index stays
                self._save_data(data_name, data)
                return
            existing = set(overloads.values())
            number = 1
            while self._data_name(number) in existing:
                number += 1
            data_name = self._data_name(number)
            self._save_data(data_name, data)
            overloads[key] = data_name
            self._save_index(overloads)
        finally:
            os.close(fd)  # releases the lock

    _numba_save = getattr(_caching.IndexDataCacheFile.save, "_numba_save", _caching.IndexDataCacheFile.save)
    _save_locked._numba_save = _numba_save  # type: ignore[attr-defined]  # idempotent across re-imports
    _caching.IndexDataCacheFile.save = _save_locked  # type: ignore[method-assign]


class _Interpreted:
    """Stand-in for a numba dispatcher: exposes ``py_func`` like numba does."""

    def __init__(self, func: Callable[..., Any]) -> None:
        self.py_func = func
        self.__wrapped__ = func
        self.__doc__ = func.__doc__
        self.__name__ = func.__name__

    def __call__(self, *args: Any) -> Any:
        return self.py_func(*args)


def _is_filter_kernel(func: Callable[..., Any]) -> bool:
    code = getattr(func, "__code__", None)
    return code is not None and os.path.dirname(os.path.abspath(code.co_filename)) == _FILTERS_DIR


def pure_python(func: Any) -> Callable[..., Any]:
    """The interpreted reference of a kernel: its source run by the interpreter, and every kernel it calls too.

    ``kernel.py_func`` alone would still call the *compiled* helpers (the
    names in its globals are numba dispatchers), and calling those from
    Python compiles a standalone copy of every helper that the compiled
    steps inline: seconds per helper on a cold cache, for a path that is
    meant to be the slow, readable reference.  Here each kernel of
    ``mavahrs/filters`` reached from ``func`` is replaced by its own
    pure-Python version (a copy of its function with those names rebound).
    Anything else is returned as its ``py_func`` (or itself).
    """
    return _pure(func, {})


def _pure(func: Any, memo: dict[int, Callable[..., Any]]) -> Callable[..., Any]:
    py = getattr(func, "py_func", func)
    if not isinstance(py, types.FunctionType) or not _is_filter_kernel(py):
        return py  # type: ignore[no-any-return]
    done = memo.get(id(py))
    if done is not None:
        return done
    glb = dict(py.__globals__)
    clone = types.FunctionType(py.__code__, glb, py.__name__, py.__defaults__, py.__closure__)
    clone.__qualname__, clone.__module__, clone.__doc__ = py.__qualname__, py.__module__, py.__doc__
    memo[id(py)] = clone
    for name in py.__code__.co_names:  # the globals this function refers to
        value = glb.get(name)
        if value is not None and hasattr(value, "py_func"):
            glb[name] = _pure(value, memo)
    return clone


def kernel(func: F | None = None, *, inline: bool = False, nogil: bool = False, allocates: bool = False) -> Any:
    """Compile ``func`` lazily with numba (``cache=True``), keeping ``.py_func``.

    No ``fastmath``: the compiled and the interpreted kernels must agree to
    rounding (tested to 1e-9).  Kernels are compiled without reference
    counting: they work in arrays their caller owns and must not allocate
    (numba then refuses to compile them), which also spares a command's
    start numba's runtime (:func:`quick_start`).  ``allocates=True`` (not for
    ``mavahrs/filters``) keeps reference counting for a kernel that creates
    arrays.  ``inline=True`` inlines the kernel into the
    compiled kernels that call it (numba IR inlining; for large helpers called
    on every sample).  ``nogil=True`` releases the GIL while the compiled
    kernel runs, so another thread can work meanwhile (replay's CSV writer).
    Usable as ``@kernel`` or ``@kernel(inline=True)``.
    """

    def wrap(f: F) -> F:
        if HAVE_NUMBA:
            options: dict[str, Any] = {"cache": True, "error_model": "numpy"}
            if allocates and _is_filter_kernel(f):
                raise ValueError(f"{f.__qualname__}: kernels of mavahrs/filters must not allocate")
            if not allocates:
                options["_nrt"] = False
                _NO_RUNTIME.add(f.__code__)
            if inline:
                options["inline"] = "always"
            if nogil:
                options["nogil"] = True
            return _numba.njit(**options)(f)  # type: ignore[no-any-return]
        return _Interpreted(f)  # type: ignore[return-value]

    return wrap if func is None else wrap(func)


def loop_kernel(func: F | None = None, *, parallel: bool = False) -> Any:
    """Compile a *driver* loop (one that receives a kernel as an argument) with numba, uncached.

    numba's on-disk cache index of a function typed on a first-class
    dispatcher argument refers to every kernel it was ever compiled for; when
    one of those is not loaded in the saving process the save fails
    ("underlying object has vanished").  Driver loops are small, so they are
    compiled once per process instead (≈ 0.5 s); the kernels they call stay
    cached.  ``parallel=True`` enables ``numba.prange``.  Like the filter
    kernels, driver loops must not allocate: they run without reference
    counting (a row view per sample would otherwise cost two atomic
    operations, and in a parallel loop make the threads fight over the input
    array's reference count).
    """

    def wrap(f: F) -> F:
        if HAVE_NUMBA:
            return _numba.njit(cache=False, parallel=parallel, error_model="numpy", _nrt=False)(f)  # type: ignore[no-any-return]
        return _Interpreted(f)  # type: ignore[return-value]

    return wrap if func is None else wrap(func)


def bound_loop(template: Callable[..., Any], qualname: str, *, parallel: bool = False, **bound: Any) -> Any:
    """A driver loop with its kernel bound as a *global*, compiled with numba and cached on disk.

    ``template`` calls its kernel through module-level names (e.g. ``_STEP``);
    this returns a copy of it whose globals bind those names to ``bound``
    (e.g. ``_STEP=Madgwick.step``), named ``qualname`` (the cache file name:
    unique per binding).  Unlike a :func:`loop_kernel` that receives the
    kernel as an argument, such a loop can be cached, so a new process loads
    it instead of compiling it (≈ 0.5 s).  Only for templates in
    ``mavahrs/filters`` binding kernels of ``mavahrs/filters`` (the cache
    stamp covers those sources); returns None for anything else, and without
    numba.
    """
    if not HAVE_NUMBA or not _is_filter_kernel(template):
        return None
    for value in bound.values():
        py = getattr(value, "py_func", None)
        if py is None or not _is_filter_kernel(py):
            return None
    glb = dict(template.__globals__)
    glb.update(bound)
    func = types.FunctionType(template.__code__, glb, qualname.rsplit(".", 1)[-1], template.__defaults__)
    func.__qualname__ = qualname
    func.__module__ = template.__module__
    func.__doc__ = template.__doc__
    # nogil: a batch run leaves the interpreter to other threads (replay's CSV writer formats meanwhile)
    _NO_RUNTIME.add(func.__code__)
    return _numba.njit(cache=True, parallel=parallel, error_model="numpy", _nrt=False, nogil=True)(func)


def quick_start() -> bool:
    """Let kernels load from the disk cache without numba's compiler registries (command-line processes).

    numba loads every lowering and typing registry (``BaseContext.refresh``: ~0.2 s, a third of
    a command's start on the development VM) before it even looks up a kernel in its on-disk
    cache, though re-creating a cached kernel needs none of them: they serve compilation only.
    Here a cache lookup goes straight to the cache; a kernel that is not there is compiled,
    and numba's compiler loads the registries itself then.  When they load, one of them probes
    for BLAS by importing ``scipy.linalg`` (0.14 s), which only code compiling ``np.dot``-like
    calls with numba needs; the kernels of mavahrs use none, so ``scipy.linalg`` is hidden for
    that moment (it imports as usual afterwards).  Kernels compiled without reference counting
    (every one but those declared ``allocates``) load without numba's runtime, which is set up
    (17 ms) only for one that calls into it.  None of this changes a result: the same machine
    code runs.  Not done when the library is imported: a user's own numba code in the same
    process may need BLAS.  Returns whether it was installed (False: numba absent, its
    registries already loaded, or numba's internals not as expected).
    """
    if not HAVE_NUMBA or "numba.np.arraymath" in sys.modules:
        return False
    try:
        from numba.core.cpu import CPUContext
        from numba.core.runtime import rtsys

        cache_cls = _caching.Cache
        load = cache_cls._load_overload
        guard = cache_cls._guard_against_spurious_io_errors
        registries = CPUContext.load_additional_registries
    except (ImportError, AttributeError):  # numba internals moved: it loads them itself on first use
        return False
    if getattr(cache_cls.load_overload, "_mavahrs_quick", False):
        return True

    def load_overload(self: Any, sig: Any, target_context: Any) -> Any:
        if getattr(getattr(self, "_py_func", None), "__code__", None) not in _NO_RUNTIME:
            # numba's runtime (kernels with reference counting call into it; 17 ms to set up)
            rtsys.initialize(target_context)
        with guard(self):
            return load(self, sig, target_context)
        return None  # (the guard swallowed an I/O error: compile, as numba does)

    def load_additional_registries(self: Any) -> None:
        hide = "scipy.linalg" not in sys.modules
        if hide:
            sys.modules["scipy.linalg"] = None  # type: ignore[assignment]  # import scipy.linalg → ImportError
        try:
            registries(self)
        finally:
            if hide and sys.modules.get("scipy.linalg", 0) is None:
                del sys.modules["scipy.linalg"]

    load_overload._mavahrs_quick = True  # type: ignore[attr-defined]
    cache_cls.load_overload = load_overload  # type: ignore[method-assign]
    CPUContext.load_additional_registries = load_additional_registries  # type: ignore[method-assign]
    return True


def on_first_compile(callback: Callable[[str], None], clock: Callable[[], float] | None = None) -> Callable[[], None]:
    """Call ``callback(kernel_name)`` once, when a cached kernel of mavahrs is first *compiled* in this process.

    numba announces a compilation only when the on-disk cache has no usable
    entry (a cold cache: first run on a machine, or sources changed); loading a
    cached kernel is silent.  So the callback runs, just before the first
    compilation starts, exactly when this process is about to spend the
    seconds to minutes of a cold compile, and never on a warm cache.  Driver loops that
    are compiled uncached in every process (:func:`loop_kernel`, ≈ 0.5 s) do
    not count.  Returns a function that removes the listener; with a ``clock``
    (seconds, e.g. ``time.monotonic``) its ``compiled_s()`` tells how long the
    compilations took (None if none).  Without numba: never called.
    """
    if not HAVE_NUMBA:
        return lambda: None
    from numba.core import event as _event

    listener = _FirstCompile(callback, _event.Listener, clock)
    _event.register("numba:compile", listener.numba_listener)

    def remove() -> None:
        _event.unregister("numba:compile", listener.numba_listener)

    remove.compiled_s = listener.compiled_s  # type: ignore[attr-defined]  # how long it compiled, s (None: it did not)
    return remove


class _FirstCompile:
    """The numba event listener behind :func:`on_first_compile` (fires once).

    numba announces compilations while holding its global compiler lock, so
    two threads never get here at the same time.
    """

    def __init__(self, callback: Callable[[str], None], base: type, clock: Callable[[], float] | None = None) -> None:
        self._callback = callback
        self._clock = clock
        self._fired = False
        self._first_s: float | None = None
        self._last_end_s: float | None = None
        owner = self

        class _Listener(base):  # type: ignore[misc, valid-type]
            def on_start(self, event: Any) -> None:
                owner.started(event.data.get("dispatcher") if isinstance(event.data, dict) else None)

            def on_end(self, event: Any) -> None:
                if owner._fired and owner._clock is not None:
                    owner._last_end_s = owner._clock()

        self.numba_listener = _Listener()

    def compiled_s(self) -> float | None:
        """From the first compilation's start to the last one's end, s (None before any)."""
        if self._first_s is None or self._last_end_s is None:
            return None
        return self._last_end_s - self._first_s

    def started(self, dispatcher: Any) -> None:
        py = getattr(dispatcher, "py_func", None)
        cache = getattr(dispatcher, "_cache", None)
        if py is None or not str(getattr(py, "__module__", "")).startswith("mavahrs"):
            return
        if cache is None or type(cache).__name__ == "NullCache":  # uncached driver loop
            return
        if self._fired:
            return
        self._fired = True
        self._first_s = self._clock() if self._clock is not None else None
        self._callback(getattr(py, "__qualname__", repr(py)))


def cache_location() -> str | None:
    """Where numba caches the filter kernels (``NUMBA_CACHE_DIR`` when set, else the user's cache folder, …);
    None without numba."""
    if not HAVE_NUMBA:
        return None
    if _numba.config.CACHE_DIR:
        return str(_numba.config.CACHE_DIR)
    from mavahrs.filters.kinematics import quat_multiply

    try:
        return str(quat_multiply._cache.cache_path)
    except AttributeError:  # pragma: no cover - numba internals moved
        return None
