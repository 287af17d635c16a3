"""A small per-process cache of what is computed from a cell's matrices alone.

A spectrum varies γ_r over one cell: the eigen-decomposition of the free system and the
constrained (stuck) system's projections do not depend on γ_r, yet cost ~0.2 ms a point. They are
cached here, keyed by the exact bytes of the arrays they are computed from, so a hit returns
what the computation would have returned, bit for bit, and a different cell can never hit.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

__all__ = ["ArrayMemo"]

T = TypeVar("T")


class ArrayMemo:
    """Least-recently-used values by their input arrays (``size`` kept per process)."""

    def __init__(self, size: int = 16) -> None:
        self.size = size
        self._items: OrderedDict[tuple, object] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def get(self, arrays: Sequence[np.ndarray], compute: Callable[[], T]) -> T:
        """``compute()``'s value for these input arrays, computed on the first call only.

        Callers must not modify what they get (copy what goes on to be changed)."""
        key = tuple((a.shape, a.dtype.str, a.tobytes()) for a in arrays)
        if key in self._items:
            self._items.move_to_end(key)
            self.hits += 1
            return self._items[key]  # type: ignore[return-value]
        value = compute()
        self.misses += 1
        self._items[key] = value
        if len(self._items) > self.size:
            self._items.popitem(last=False)
        return value
