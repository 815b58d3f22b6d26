r"""Fast, crash-tolerant CSV output of numeric tables (replay writes a row per IMU sample).

``np.savetxt`` formats each number through Python (a few µs per value); a
one-hour 400 Hz replay has 1.4 million rows of a dozen columns or more.
:func:`format_rows` formats fixed-point decimals in one compiled pass instead
(numba, cached): each value is rounded to its column's number of decimals
(half away from zero, like ``"%.{d}f"`` for values exactly representable) and
written as ASCII; NaN is written as ``nan``, ±inf as ``inf``/``-inf``;
values whose scaled magnitude does not fit 15 significant digits fall back
to Python's ``repr``.

:class:`CsvSink` appends such blocks to a file and flushes after every
block, so an interrupted replay leaves every row written so far.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.filters.jit import kernel

__all__ = ["format_rows", "CsvSink"]

_LIMIT = 1e15  # scaled values beyond this use the slow path


#: "00", "01", … "99" as ASCII: two digits per table lookup
_PAIRS = np.frombuffer(b"".join(b"%02d" % i for i in range(100)), np.uint8).copy()
_POW10 = np.array([10**i for i in range(20)], np.uint64)


@kernel(nogil=True, allocates=True)
def _format(values, decimals, out):  # type: ignore[no-untyped-def]
    """Write rows of ``values`` (n, c) into ``out`` (uint8); return bytes used or < 0 if a value is too large.

    Each number is written right to left, two digits at a time from a
    "00".."99" table, after counting its digits against powers of ten.
    """
    n, c = values.shape
    scales = np.empty(c)
    for j in range(c):
        scales[j] = 10.0 ** decimals[j]
    pairs = _PAIRS
    pow10 = _POW10
    p = 0
    cap = out.shape[0]
    h = np.uint64(100)
    ten = np.uint64(10)
    for i in range(n):
        if p + 19 * c + 1 > cap:  # a value takes ≤ 19 bytes with its comma ("-" + 16 digits + "."), "\n"
            return -1
        for j in range(c):
            if j > 0:
                out[p] = 44  # ','
                p += 1
            v = values[i, j]
            d = decimals[j]
            if v != v:
                out[p] = 110  # nan
                out[p + 1] = 97
                out[p + 2] = 110
                p += 3
                continue
            if v == np.inf or v == -np.inf:
                if v < 0:
                    out[p] = 45
                    p += 1
                out[p] = 105  # inf
                out[p + 1] = 110
                out[p + 2] = 102
                p += 3
                continue
            s = abs(v) * scales[j]
            if s >= 1e15:
                return -2 - (i * c + j)  # caller formats this block in Python
            k = np.uint64(s + 0.5)  # s ≥ 0: truncation = floor
            if v < 0 and k != 0:
                out[p] = 45  # '-'
                p += 1
            nd = d + 1  # digits to write: at least one before the point (k < 1e16)
            while nd < 16 and k >= pow10[nd]:
                nd += 1
            end = p + nd + (1 if d > 0 else 0)
            # The decimals, then the integer part, two digits per step.  The two loops are the same on
            # purpose: as one shared inlined helper the formatter ran 1.8x slower (measured).
            q = end - 1
            x = k
            r = d
            while r >= 2:
                t = x // h
                u = 2 * (x - t * h)
                out[q] = pairs[u + 1]
                out[q - 1] = pairs[u]
                q -= 2
                x = t
                r -= 2
            if r == 1:
                t = x // ten
                out[q] = np.uint8(48 + (x - t * ten))
                q -= 1
                x = t
            if d > 0:
                out[q] = 46  # '.'
                q -= 1
            r = nd - d
            while r >= 2:
                t = x // h
                u = 2 * (x - t * h)
                out[q] = pairs[u + 1]
                out[q - 1] = pairs[u]
                q -= 2
                x = t
                r -= 2
            if r == 1:
                out[q] = np.uint8(48 + x)
            p = end
        out[p] = 10  # '\n'
        p += 1
    return p


def format_rows(values: NDArray[np.float64], decimals: Sequence[int] | NDArray[np.int64]) -> bytes:
    """CSV text (no header) of a 2-D float array, column ``j`` with ``decimals[j]`` decimals."""
    return b"".join(bytes(part) for part in _formatted_parts(values, decimals))


def _formatted_parts(
    values: NDArray[np.float64], decimals: Sequence[int] | NDArray[np.int64]
) -> Iterator[bytes | memoryview]:
    """The CSV text of ``values`` in consecutive parts of about 4 MB.

    A part may be a view of a buffer the next part overwrites: use each
    before asking for the next (write it, copy it).
    """
    v = np.ascontiguousarray(values, dtype=np.float64)
    if v.ndim != 2:
        raise ValueError(f"values must be 2-D, got shape {v.shape}")
    d = np.ascontiguousarray(decimals, dtype=np.int64)
    if d.shape != (v.shape[1],) or (d < 0).any() or (d > 12).any():
        raise ValueError("decimals must give 0…12 per column")
    if v.shape[0] == 0:
        return
    width = int(v.shape[1] * 24 + 2)
    block = max(1, (1 << 22) // width)  # ~4 MB of text per pass: no huge temporary buffer
    buf = np.empty(min(block, v.shape[0]) * width, np.uint8)
    for start in range(0, v.shape[0], block):
        part = v[start : start + block]
        used = int(_format(part, d, buf))
        yield memoryview(buf)[:used] if used >= 0 else _format_slow(part, d)


def _format_slow(v: NDArray[np.float64], d: NDArray[np.int64]) -> bytes:
    """The plain way, for a block holding a value too large for the fixed-point path."""
    lines = []
    for row in v:
        cells = []
        for x, dj in zip(row, d, strict=True):
            if math.isnan(x):
                cells.append("nan")
            elif math.isinf(x):
                cells.append("inf" if x > 0 else "-inf")
            elif abs(x) * 10.0**dj >= _LIMIT:
                cells.append(repr(float(x)))
            else:  # the same rounding as the compiled path
                one = np.empty(64, np.uint8)
                used = int(_format(np.array([[x]]), np.array([dj], np.int64), one))
                cells.append(one[: used - 1].tobytes().decode())
        lines.append(",".join(cells))
    return ("\n".join(lines) + "\n").encode()


class CsvSink:
    """Append numeric rows to a CSV file; every :meth:`write` is flushed to the OS.

    :meth:`write_behind` formats and writes a block in a worker thread while
    the caller computes the next one (the formatter releases the GIL): the
    bulk replay's CSV then costs little more than the filters.  One block at
    most is in flight; :meth:`close` (also on an exception or Ctrl-C in the
    caller) waits for it, so every block handed over reaches the file;
    :meth:`sync_behind` queues the final flush and fsync behind it.

    Args:
        path: file to create (truncated if it exists).
        columns: header names.
        decimals: decimals per column.
    """

    def __init__(self, path: str | os.PathLike[str], columns: Sequence[str], decimals: Sequence[int]) -> None:
        if len(columns) != len(decimals):
            raise ValueError("one decimals entry per column")
        self.path = os.fspath(path)
        self.columns = list(columns)
        self._decimals = np.asarray(decimals, dtype=np.int64)
        self._file: IO[bytes] | None = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._file.write((",".join(self.columns) + "\n").encode())
        self._file.flush()
        self.rows = 0
        self._pool: ThreadPoolExecutor | None = None
        self._pending: list[Future[None]] = []
        self._synced_rows = -1  # rows on disk at the last fsync (-1: never)

    def write(self, values: NDArray[np.float64]) -> None:
        """Append rows (n, len(columns)) and flush."""
        if self._file is None:
            raise ValueError(f"CSV file {self.path} is closed")
        if values.shape[0] == 0:
            return
        if values.ndim != 2 or values.shape[1] != len(self.columns):
            raise ValueError(f"expected rows of {len(self.columns)} columns, got shape {values.shape}")
        for part in _formatted_parts(values, self._decimals):
            self._file.write(part)
        self._file.flush()
        self.rows += int(values.shape[0])

    def write_behind(self, values: NDArray[np.float64]) -> None:
        """:meth:`write` in the worker thread; first waits for what was handed over before (raising its error).

        ``values`` must not be changed afterwards.
        """
        self._wait()
        self._submit(self.write, values)

    def sync_behind(self) -> None:
        """Flush and fsync in the worker, after the blocks handed over so far; the caller goes on."""
        if self._file is not None:
            self._submit(self._sync)

    def _submit(self, fn: Any, *args: Any) -> None:
        if self._file is None:
            raise ValueError(f"CSV file {self.path} is closed")
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mavahrs-csv")
        self._pending.append(self._pool.submit(fn, *args))  # one worker: done in order

    def write_now(self, values: NDArray[np.float64]) -> None:
        """:meth:`write` in the caller's thread, after what was handed over before (rows stay in order)."""
        self._wait()
        self.write(values)

    def _wait(self) -> None:
        # One at a time, each forgotten only once done: a Ctrl-C while waiting leaves the rest
        # pending, so whatever comes next (close, write_now) still waits for it.
        errors = []
        while self._pending:
            exc = self._pending[0].exception()
            self._pending.pop(0)
            if exc is not None:
                errors.append(exc)
        if errors:
            raise errors[0]

    def _sync(self) -> None:
        assert self._file is not None
        self._file.flush()
        try:
            os.fsync(self._file.fileno())
        except OSError:
            pass
        self._synced_rows = self.rows

    def close(self) -> None:
        """Wait for what is still being written, flush, fsync and close (idempotent)."""
        try:
            self._wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None
            if self._file is not None:
                if self._synced_rows != self.rows:
                    self._sync()
                self._file.close()
                self._file = None

    def __enter__(self) -> CsvSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
