"""The fast CSV formatter writes what Python's formatting writes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.csvout import CsvSink, format_rows


def test_matches_python_formatting(rng: np.random.Generator) -> None:
    v = rng.normal(size=(500, 5)) * np.array([1.0, 100.0, 1e4, 0.01, 3.0])
    dec = [7, 3, 0, 6, 2]
    got = format_rows(v, dec).decode().splitlines()
    want = [",".join(f"{x:.{d}f}" for x, d in zip(row, dec, strict=True)) for row in v]
    # Python rounds half to even on exact binary ties and writes "-0.000"; compare numerically there
    for g, w in zip(got, want, strict=True):
        if g != w:
            np.testing.assert_allclose([float(x) for x in g.split(",")], [float(x) for x in w.split(",")],
                                       atol=10.0 ** -min(dec))  # fmt: skip
    assert sum(g == w for g, w in zip(got, want, strict=True)) > 490


def test_specials_and_huge_values() -> None:
    v = np.array([[np.nan, np.inf, -np.inf, 1e30, 2.5]])
    assert format_rows(v, [2, 2, 2, 2, 0]) == b"nan,inf,-inf,1e+30,3\n"


def test_sink_flushes_every_block(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    sink = CsvSink(p, ["a", "b"], [1, 2])
    sink.write(np.array([[1.0, 2.0]]))
    assert p.read_text() == "a,b\n1.0,2.00\n"  # visible before close: an interrupted run keeps it
    sink.write(np.array([[3.0, 4.0], [5.0, 6.0]]))
    sink.close()
    assert p.read_text().splitlines()[-1] == "5.0,6.00" and sink.rows == 3


def test_digit_counts_and_rounding_across_powers_of_ten() -> None:
    """Every length from 1 to 15 digits, values that round up to the next power of ten, signs and zeros."""
    vals = [0.0, -0.0, 0.4, 0.5, -0.0004, 9.9996, 99.96, -999.9996, 123456789012.34, 1e14 - 1]
    vals += [10.0**e * m for e in range(-3, 14) for m in (1.0, 1.5, -7.25)]
    v = np.array(vals)[:, None] * np.ones((1, 3))
    dec = [3, 0, 1]
    got = format_rows(v, dec).decode().splitlines()
    for g, row in zip(got, v, strict=True):
        want = [f"{x:.{d}f}" for x, d in zip(row, dec, strict=True)]
        cells = g.split(",")
        for c, w, x, d in zip(cells, want, row, dec, strict=True):
            # Python writes "-0.000" for tiny negatives where this writes "0.000"; ties may round apart
            assert c == w or (float(c) == float(w) == 0.0) or abs(float(c) - x) <= 0.5 * 10.0**-d + 1e-9, (c, w)


def test_one_row_per_call_takes_the_compiled_path() -> None:
    """A block of one row must fit the compiled formatter's buffer (no fall-back to the slow path)."""
    from mavahrs.evaluation import csvout

    v = np.array([[-123456789012.5, 1.0]])
    buf = np.empty(v.shape[1] * 24 + 2, np.uint8)
    used = int(csvout._format(v, np.array([3, 12], np.int64), buf))
    assert used > 0 and bytes(buf[:used]) == b"-123456789012.500,1.000000000000\n"


def test_write_behind_keeps_order_and_every_block(tmp_path: Path, rng: np.random.Generator) -> None:
    blocks = [rng.normal(size=(n, 3)) for n in (1, 500, 7, 2000)]
    a, b = tmp_path / "sync.csv", tmp_path / "behind.csv"
    with CsvSink(a, ["x", "y", "z"], [3, 4, 5]) as sync:
        for blk in blocks:
            sync.write(blk)
    behind = CsvSink(b, ["x", "y", "z"], [3, 4, 5])
    for blk in blocks:
        behind.write_behind(blk)
    behind.sync_behind()  # queued behind the last block
    behind.close()  # waits for both
    assert b.read_bytes() == a.read_bytes() and behind.rows == sum(len(x) for x in blocks)


def test_write_behind_reports_a_failed_block(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    sink = CsvSink(p, ["a", "b"], [1, 1])
    sink.write_behind(np.array([[1.0, 2.0]]))
    sink.write_behind(np.zeros((2, 3)))  # wrong width: fails in the worker
    with pytest.raises(ValueError, match="2 columns"):
        sink.close()
    assert p.read_text() == "a,b\n1.0,2.0\n"  # what was written before stays, the file is closed
    with pytest.raises(ValueError, match="closed"):
        sink.write(np.array([[1.0, 2.0]]))
