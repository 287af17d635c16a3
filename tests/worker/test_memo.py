"""The per-process cache of what a cell's matrices alone determine (``worker.memo``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from worker.memo import ArrayMemo
from worker.model import CellParams, assemble
from worker.solvers.event.regimes import _STUCK, prepare_event, stuck_matrices
from worker.solvers.linear import _FREE, _free_modes, linear_tail


def test_values_are_keyed_by_the_exact_bytes_and_evicted_least_recently_used():
    memo = ArrayMemo(size=2)
    calls = []

    def value(tag):
        def compute():
            calls.append(tag)
            return tag

        return compute

    a = np.array([1.0, 2.0])
    assert memo.get((a,), value("a")) == "a"
    assert memo.get((a.copy(),), value("again")) == "a"  # equal bytes: a hit
    assert memo.get((np.nextafter(a, 3.0),), value("b")) == "b"  # one ulp apart: a miss
    assert memo.get((a.reshape(2, 1),), value("c")) == "c"  # same bytes, other shape: a miss
    assert memo.get((a,), value("a2")) == "a2"  # "a" was the least recent: evicted
    assert calls == ["a", "b", "c", "a2"] and (memo.hits, memo.misses) == (1, 4)


def test_a_spectrum_shares_the_free_modes_and_gets_the_uncached_values_bit_for_bit():
    base = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0, modes=5, g1=0.1, g2=0.1)
    hits = _FREE.hits
    for g in (0.8, 1.3, 2.9):
        sys_ = assemble(dataclasses.replace(base, gamma_r=g))
        tail = linear_tail(sys_)
        lam, L, max_re, _, damped = _free_modes(sys_.state_matrix(), sys_.W, sys_.ndof)
        assert np.array_equal(tail.lam, lam) and np.array_equal(tail.L, L)
        assert (tail.max_re, tail.damped) == (max_re, damped)
        tail.L[:] = 0.0  # a caller's copy: the next point must not see this
    assert _FREE.hits >= hits + 2
    assert np.any(linear_tail(assemble(base)).L != 0.0)


def test_stuck_matrices_from_the_cache_equal_a_fresh_computation():
    a = assemble(CellParams(theta=1.0, sigma=0.05, gamma_s=1.0, gamma_r=2.0, modes=4))
    b = assemble(CellParams(theta=1.0, sigma=0.05, gamma_s=1.0, gamma_r=3.5, modes=4))
    _STUCK._items.clear()
    fresh = stuck_matrices(a)  # computed
    cached = stuck_matrices(a)  # from the cache
    assert all(np.array_equal(x, y) for x, y in zip(fresh, cached, strict=True))
    cached[1][:] = 0.0  # Pin and Qout are the caller's copies
    cached[2][:] = 0.0
    again, other = stuck_matrices(a), stuck_matrices(b)
    assert np.array_equal(again[1], fresh[1]) and np.array_equal(again[2], fresh[2])
    # the γ_r-dependent parts differ between the points, the rest is shared
    assert not np.array_equal(again[0], other[0]) and not np.array_equal(again[3], other[3])
    assert np.array_equal(again[2], other[2])
    ea, eb = prepare_event(a, 64), prepare_event(a, 64)
    for f in dataclasses.fields(ea):
        assert np.array_equal(getattr(ea, f.name), getattr(eb, f.name)), f.name
