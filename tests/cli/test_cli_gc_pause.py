"""The cyclic collector rests while a command starts (``common.gc_paused``) and always resumes."""

from __future__ import annotations

import gc
import weakref

import pytest

from mavahrs.cli.common import STARTUP_GC_THRESHOLD, gc_paused


@pytest.fixture(autouse=True)
def _collector_restored():
    thresholds = gc.get_threshold()
    yield
    gc.unfreeze()
    gc.set_threshold(*thresholds)


class _Node:
    other: object = None


def _cycle() -> weakref.ref:
    a, b = _Node(), _Node()
    a.other, b.other = b, a
    return weakref.ref(a)


def test_rests_inside_resumes_after_with_the_start_up_frozen() -> None:
    before = gc.get_threshold()
    with gc_paused():
        assert gc.get_threshold()[0] == STARTUP_GC_THRESHOLD
        built = [[i] for i in range(1000)]  # what a start-up leaves behind: lives on, not walked again
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() >= len(built)


def test_an_exception_while_starting_restores_the_thresholds() -> None:
    before = gc.get_threshold()
    with pytest.raises(KeyboardInterrupt), gc_paused():
        raise KeyboardInterrupt
    assert gc.get_threshold() == before


def test_a_long_block_still_collects_its_cycles() -> None:
    """Resting is not switching off: past the threshold a replay's cycles are collected, not hoarded."""
    with gc_paused():
        first = _cycle()
        assert first() is not None  # a start-up's few allocations: no collection yet
        junk = [[] for _ in range(2 * STARTUP_GC_THRESHOLD)]  # a long replay's allocations
        del junk
        for _ in range(3 * STARTUP_GC_THRESHOLD // 1000):
            _cycle()
        assert first() is None


def test_cycles_left_at_the_start_are_kept_frozen_not_collected() -> None:
    """The price of freezing: what is cyclic garbage when the start ends stays until unfrozen."""
    gc.collect()
    with gc_paused():
        ref = _cycle()
    gc.collect()
    assert ref() is not None
    gc.unfreeze()
    gc.collect()
    assert ref() is None
