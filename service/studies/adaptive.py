"""Adaptive sampling of one line of a study (issue 17): band edges and features of Γ along an axis.

A *line* is one axis (e.g. ``gamma_r``) with every other axis fixed. A learner decides where on
``[start, stop]`` the line is computed: :meth:`Learner.ask` returns a batch of axis values that
can be computed in parallel, :meth:`Learner.tell` takes the result of one of them (in any
order), and the learner is :attr:`~Learner.done` when it has nothing more to ask and nothing
outstanding. python-adaptive's ``Learner1D`` is the reference design; this module is written for
our targets (crossings to a tolerance, with standard errors and failed points) and depends on
the standard library and numpy only.

* :class:`BandEdgeLearner` locates every crossing of Γ = ``threshold_db`` to ``tol``: a uniform
  coarse pass brackets the crossings, a safeguarded regula falsi (ITP) refines every bracket in
  parallel. :meth:`BandEdgeLearner.edges` returns them as :class:`Edge`.
* :class:`FeatureLearner` refines where Γ jumps or bends sharply, to ``resolution``.

The learners are deterministic: the same told values give the same asks, whatever the order
of the tells. A killed line resumes by replaying: drive a new learner and answer its asks from
the points already computed (they are the same values), computing only the rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "COARSE_INTERVALS",
    "BandEdgeLearner",
    "Edge",
    "FeatureLearner",
    "Learner",
    "Sample",
    "default_min_width",
]


@dataclass(frozen=True)
class Sample:
    """What one computed point tells a learner.

    Parameters
    ----------
    value : float or None
        Γ in dB; ``None`` (or NaN) when the point failed and has no value.
    se : float or None
        Standard error of ``value`` (irregular responses); ``None`` or 0 when exact.
    """

    value: float | None
    se: float | None = None


@dataclass(frozen=True)
class Edge:
    """One crossing of the threshold along the line.

    Parameters
    ----------
    x : float
        Best estimate of the crossing: the midpoint of ``[lo, hi]``.
    lo, hi : float
        The crossing is proven to lie in ``[lo, hi]`` (by samples on either side whose sides
        are known, or an exact hit where ``lo == hi``).
    rising : bool
        Γ goes from below to above the threshold with increasing x.
    certain : bool
        ``hi - lo <= 2 tol``. False: the crossing is only known to lie in ``[lo, hi]``, e.g.
        where Γ's confidence band straddles the threshold, failed points hide it, or the point
        budget ran out; ``x`` is then no precise number.
    """

    x: float
    lo: float
    hi: float
    rising: bool
    certain: bool


def _check_real(name: str, value: float, *, positive: bool = False) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {name}={value!r}") from None
    if isinstance(value, bool) or not math.isfinite(out):
        raise ValueError(f"{name} must be a finite number, got {name}={value!r}")
    if positive and out <= 0:
        raise ValueError(f"{name} must be positive, got {name}={value!r}")
    return out


def _check_int(name: str, value: int, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValueError(f"{name} must be an integer, got {name}={value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be at least {minimum}, got {name}={value!r}")
    return int(value)


#: The default coarse pass divides the range into this many intervals (``min_width``).
COARSE_INTERVALS = 64


def default_min_width(start: float, stop: float) -> float:
    """The default coarse spacing: the range over :data:`COARSE_INTERVALS`."""
    return (stop - start) / COARSE_INTERVALS


def _grid(start: float, stop: float, num: int, min_width: float | None) -> list[float]:
    """``num`` evenly spaced values (both ends), each gap subdivided evenly to <= min_width."""
    # Computed as start + span*i/n (not by repeated addition) so the ends are exact.
    initial = [start + (stop - start) * i / (num - 1) for i in range(num)]
    initial[-1] = stop
    out = [initial[0]]
    for a, b in zip(initial[:-1], initial[1:], strict=True):
        # The slack keeps a ratio that is an integer but for rounding from adding a subdivision.
        m = 1 if min_width is None else max(1, math.ceil((b - a) / min_width * (1 - 1e-12)))
        out.extend(a + (b - a) * k / m for k in range(1, m))
        out.append(b)
    return out


class Learner:
    """Base of the learners: bookkeeping of asked, outstanding and told values.

    Subclasses implement :meth:`_propose` (the values to ask now, a pure function of the
    learner's state) and may record what they asked in :meth:`_commit`.
    """

    def __init__(self, start: float, stop: float, num: int, max_points: int) -> None:
        self.start = _check_real("start", start)
        self.stop = _check_real("stop", stop)
        if not self.start < self.stop:
            raise ValueError(f"start must be less than stop, got start={start!r}, stop={stop!r}")
        self.num = _check_int("num", num, 2)
        self.max_points = _check_int("max_points", max_points, 1)
        if self.max_points < self.num:
            raise ValueError(
                f"max_points must be at least num={self.num}, got max_points={max_points!r}"
            )
        self._data: dict[float, Sample] = {}
        self._pending: set[float] = set()

    # ----------------------------------------------------------------------- protocol

    def ask(self) -> list[float]:
        """Axis values to compute now, increasing; ``[]`` while waiting or when done.

        The values of one call can be computed in parallel. No value is asked twice, and no
        more than ``max_points`` values are asked in all.
        """
        room = self.max_points - self.n_asked
        xs = [x for x in self._propose() if x not in self._data and x not in self._pending]
        xs = sorted(set(xs))[: max(room, 0)]
        self._pending.update(xs)
        self._commit(xs)
        return xs

    def tell(self, x: float, sample: Sample) -> None:
        """The result of an asked value ``x`` (tells may come in any order)."""
        x = float(x)
        if x not in self._pending:
            told = "was already told" if x in self._data else "was never asked"
            raise ValueError(f"x={x!r} {told}")
        if sample.se is not None and not (math.isfinite(sample.se) and sample.se >= 0):
            raise ValueError(f"se must be a finite number >= 0 or None, got se={sample.se!r}")
        self._pending.discard(x)
        self._data[x] = sample

    @property
    def done(self) -> bool:
        """Nothing more to ask and nothing outstanding."""
        if self._pending:
            return False
        if self.n_asked >= self.max_points:
            return True
        return not any(x not in self._data for x in self._propose())

    @property
    def n_points(self) -> int:
        """Values told so far."""
        return len(self._data)

    @property
    def n_asked(self) -> int:
        """Values asked so far (told or outstanding)."""
        return len(self._data) + len(self._pending)

    @property
    def pending(self) -> list[float]:
        """Values asked and not yet told, increasing."""
        return sorted(self._pending)

    def samples(self) -> list[tuple[float, Sample]]:
        """The told values and their samples, sorted by x."""
        return sorted(self._data.items())

    # ----------------------------------------------------------------------- subclass hooks

    def _propose(self) -> list[float]:
        raise NotImplementedError

    def _commit(self, xs: list[float]) -> None:  # noqa: B027 (an optional hook)
        """Record the values just asked (their order is increasing)."""


# =============================================================================== band edges

# ITP (Oliveira & Takahashi 2020): truncation κ1 = _ITP_K1 / initial width, κ2 = 2, and n0 = 1
# steps of slack over bisection; so a bracket takes at most ceil(log2(w0 / 2 tol)) + 1 probes
# (pairs counted as one), and superlinearly fewer on smooth crossings.
_ITP_K1 = 0.2
_ITP_N0 = 1
# The probe pair that closes a bracket in one batch sits at estimate ± _PAIR * tol, so the
# bracket it leaves is narrower than 2 tol, with room for rounding.
_PAIR = 0.95
# A pair is probed when the interpolation estimate moved by at most this many tol since the
# last step: the estimates converge superlinearly, so the error is then well below tol.
_PAIR_TRUST = 4.0


@dataclass
class _Bracket:
    """A crossing being located: the values at lo and hi are on known, opposite sides."""

    lo: float
    hi: float
    rising: bool
    # Told samples strictly inside with an unknown side (straddling or failed).
    unknown: tuple[float, ...] = ()
    exact: bool = False  # lo..hi are exact hits of the threshold: nothing left to do
    # ITP state: the width when the current run of clean steps started, and the steps since.
    w0: float = 0.0
    steps: int = 0
    misses: int = 0  # probes of this crossing that came back with an unknown side
    estimate: float | None = None  # the interpolation estimate of the last step
    probes: tuple[float, ...] = field(default=())  # asked, maybe not told yet


class BandEdgeLearner(Learner):
    """Locate every crossing of Γ = ``threshold_db`` along ``[start, stop]`` to ``tol``.

    Bracketing: the first :meth:`ask` returns the ``num`` starting values (evenly spaced, both
    ends) and, in the same batch, a uniform coarse pass that subdivides every gap between them
    evenly to a spacing <= ``min_width``. So no band (a run of x where Γ is below, or above,
    the threshold) of width >= ``min_width`` is missed where the samples' sides are known; a
    narrower band may be. A crossing is a change of side between consecutive samples of known
    side; a touch of the threshold without a change of side is none.

    Refinement: each bracket is refined by ITP (regula falsi with truncation towards the
    midpoint and projection onto a shrinking bisection radius), so a bracket of width w takes
    at most ``ceil(log2(w / 2 tol)) + 1`` steps, and a few on smooth crossings. When two
    successive estimates agree to a few tol, the step probes estimate ± 0.95 tol instead, which
    closes the bracket in one batch. Brackets refine in parallel: one batch holds the next
    step of every open bracket. A probe exactly at the threshold is the edge (``lo == hi``).

    Sides: a sample is below or above the threshold, on it (exact, no ``se``), or *unknown*:
    failed (``value`` None or NaN) or straddling (``|value - threshold| <= z se``). A bracket
    whose inside holds unknown samples probes the midpoints of the gaps between its known ends
    and the unknown samples (the straddling region lies there: this narrows the proven
    interval from outside), until those gaps are <= max(tol / 2, a quarter of the unknown
    region's width) or ``max_unknown`` probes of it came back unknown; then it stops and the
    edge is reported with the nearest samples of known side as ``[lo, hi]``. Unknown samples
    between two samples on the same side (a possible band narrower than the spacing hidden in
    noise or failures) create no edge and cost no points; :meth:`unresolved` lists them.

    Budget: no more than ``max_points`` values are asked; when they run out, brackets still
    open are reported as they are. An edge is ``certain`` exactly when ``hi - lo <= 2 tol``.

    Parameters
    ----------
    start, stop : float
        The range of the axis, ``start < stop``.
    num : int
        Starting samples, >= 2.
    threshold_db : float
        The threshold of Γ (dB).
    tol : float
        Wanted accuracy of every edge: ``hi - lo <= 2 tol``, so ``|x - edge| <= tol``.
    min_width : float, optional
        The coarse spacing; default ``(stop - start) / 64``.
    max_points : int
        Most values asked in all; at least the coarse pass.
    z : float
        Width of the confidence band in standard errors.
    max_unknown : int
        Probes that may come back unknown per crossing before it is left uncertain.
    """

    def __init__(
        self,
        start: float,
        stop: float,
        num: int,
        *,
        threshold_db: float = 0.0,
        tol: float = 1e-3,
        min_width: float | None = None,
        max_points: int = 150,
        z: float = 2.0,
        max_unknown: int = 4,
    ) -> None:
        super().__init__(start, stop, num, max_points)
        self.threshold_db = _check_real("threshold_db", threshold_db)
        self.tol = _check_real("tol", tol, positive=True)
        if min_width is None:
            self.min_width = default_min_width(self.start, self.stop)
        else:
            self.min_width = _check_real("min_width", min_width, positive=True)
        self.z = _check_real("z", z, positive=True)
        self.max_unknown = _check_int("max_unknown", max_unknown, 1)
        self._coarse = _grid(self.start, self.stop, self.num, self.min_width)
        if len(self._coarse) > self.max_points:
            raise ValueError(
                f"max_points must hold the {len(self._coarse)} points of the coarse pass "
                f"(min_width={self.min_width!r}), got max_points={max_points!r}"
            )
        self._brackets: list[_Bracket] = []
        self._from_coarse: set[tuple[float, float]] = set()

    # ----------------------------------------------------------------------- results

    def edges(self) -> list[Edge]:
        """Every crossing located so far, increasing x (final once :attr:`done`)."""
        self._update()
        return [
            Edge(
                x=0.5 * (b.lo + b.hi),
                lo=b.lo,
                hi=b.hi,
                rising=b.rising,
                certain=b.hi - b.lo <= 2 * self.tol,
            )
            for b in sorted(self._brackets, key=lambda b: b.lo)
        ]

    def unresolved(self) -> list[tuple[float, float]]:
        """Runs of unknown samples between samples on the same side (or an end of the range).

        A band may hide there; no edge is reported for them. Each interval spans the run and
        reaches to the nearest samples of known side.
        """
        out = []
        told = sorted(self._data)
        sides = [self._side(x) for x in told]
        i = 0
        while i < len(told):
            if sides[i] is not None:
                i += 1
                continue
            j = i
            while j + 1 < len(told) and sides[j + 1] is None:
                j += 1
            left = sides[i - 1] if i > 0 else None
            right = sides[j + 1] if j + 1 < len(told) else None
            if left is None or right is None or left == right:
                out.append((told[max(i - 1, 0)], told[min(j + 1, len(told) - 1)]))
            i = j + 1
        return out

    # ----------------------------------------------------------------------- sides

    def _side(self, x: float) -> int | None:
        """-1 below, +1 above, 0 exactly at the threshold, None unknown (failed, straddling)."""
        s = self._data[x]
        if s.value is None or not math.isfinite(s.value):
            return None
        g = s.value - self.threshold_db
        if s.se and abs(g) <= self.z * s.se:
            return None
        return (g > 0) - (g < 0)

    def _g(self, x: float) -> float:
        value = self._data[x].value
        assert value is not None
        return value - self.threshold_db

    # ----------------------------------------------------------------------- state

    def _update(self) -> None:
        """Bracket newly complete coarse gaps, and split brackets whose probes are all told."""
        last: tuple[float, int] | None = None
        between: list[float] = []
        for x in self._coarse:
            if x not in self._data:
                # Outstanding: the side here is not known, so nothing pairs across it yet.
                last, between = None, []
                continue
            side = self._side(x)
            if side is None or side == 0:
                between.append(x)
                continue
            if last is not None and last[1] != side and (last[0], x) not in self._from_coarse:
                self._from_coarse.add((last[0], x))
                b = _Bracket(last[0], x, rising=last[1] < 0, w0=x - last[0])
                self._brackets.extend(self._split(b, [last[0], *between, x], fresh=True))
            last, between = (x, side), []

        brackets = []
        for b in self._brackets:
            if b.probes and all(p in self._data for p in b.probes):
                xs = sorted({b.lo, b.hi, *b.unknown, *b.probes})
                brackets.extend(self._split(b, xs, fresh=False))
            else:
                brackets.append(b)
        self._brackets = brackets

    def _split(self, parent: _Bracket, xs: list[float], *, fresh: bool) -> list[_Bracket]:
        """The brackets in ``parent`` given its told samples ``xs`` (sorted, ends included)."""
        misses = parent.misses + sum(self._side(p) is None for p in parent.probes)
        out = []
        last: float | None = None
        inner: list[float] = []
        for x in xs:
            side = self._side(x)
            if side is None or side == 0:
                inner.append(x)
                continue
            if last is not None and self._side(last) != side:
                zeros = [u for u in inner if self._side(u) == 0]
                unknown = tuple(u for u in inner if self._side(u) is None)
                child = _Bracket(last, x, rising=self._side(last) < 0, misses=misses)
                if zeros:
                    # Γ is at the threshold there: that is the crossing, exactly.
                    child.lo, child.hi, child.unknown, child.exact = zeros[0], zeros[-1], (), True
                elif unknown:
                    child.unknown = unknown
                elif fresh or parent.unknown:
                    child.w0 = x - last  # a clean run of ITP steps starts here
                else:
                    child.w0, child.steps = parent.w0, parent.steps + 1
                    child.estimate = parent.estimate
                out.append(child)
            last, inner = x, []
        return out

    # ----------------------------------------------------------------------- asking

    def _propose(self) -> list[float]:
        coarse = [x for x in self._coarse if x not in self._data and x not in self._pending]
        if coarse:
            return coarse
        self._update()
        room = self.max_points - self.n_asked
        plans = [(b, self._step(b)) for b in self._brackets if not b.probes]
        plans = [(b, p) for b, p in plans if p[0]]
        # Short of points, the widest brackets get their first probe first, then second ones.
        plans.sort(key=lambda bp: (-(bp[0].hi - bp[0].lo), bp[0].lo))
        chosen: dict[int, list[float]] = {}
        for b, (_, single) in plans:
            if room > 0:
                chosen[id(b)] = [single]
                room -= 1
        for b, (probes, _) in plans:
            # Second probes (a closing pair, or both gaps around unknown samples) cost one more.
            if room > 0 and len(probes) > 1 and id(b) in chosen:
                chosen[id(b)] = probes
                room -= 1
        return sorted(x for xs in chosen.values() for x in xs)

    def _commit(self, xs: list[float]) -> None:
        asked = set(xs)
        for b in self._brackets:
            if b.probes:
                continue
            probes, single = self._step(b)
            if probes and asked.issuperset(probes):
                mine = tuple(probes)
            else:
                mine = (single,) if single in asked else ()
            if mine:
                b.probes = mine
                if not b.unknown:
                    b.estimate = self._estimate(b)

    def _estimate(self, b: _Bracket) -> float:
        """Regula falsi: where the chord between the bracket's ends crosses the threshold."""
        ga, gb = self._g(b.lo), self._g(b.hi)
        return (gb * b.lo - ga * b.hi) / (gb - ga)

    def _step(self, b: _Bracket) -> tuple[list[float], float]:
        """The next probes of a bracket (``[]`` when it is finished) and the one to use alone.

        A pure function of the bracket and the samples, so :attr:`done` can ask it freely.
        """
        lo, hi = b.lo, b.hi
        width = hi - lo
        if b.exact or width <= 2 * self.tol:
            return [], math.nan
        inside = [x for x in self._data if lo < x < hi]
        if b.unknown:
            if b.misses >= self.max_unknown:
                return [], math.nan
            u0, u1 = min(b.unknown), max(b.unknown)
            # Gaps of tol / 2 let a lone unknown sample end certain (hi - lo <= 2 tol); a wide
            # unknown region needs its bounds no finer than a quarter of its width.
            enough = max(0.5 * self.tol, (u1 - u0) / 4)
            gaps = sorted(((u0 - lo, lo, u0), (hi - u1, u1, hi)), key=lambda g: (-g[0], g[1]))
            probes = [0.5 * (a + c) for w, a, c in gaps if w > enough]
            probes = [p for p in probes if lo < p < hi and p not in inside]
            return probes, probes[0] if probes else math.nan

        # ITP step on a clean bracket.
        xf = self._estimate(b)
        xh = 0.5 * (lo + hi)
        sigma = 1.0 if xh >= xf else -1.0
        delta = _ITP_K1 / b.w0 * width**2
        xt = xf + sigma * delta if delta <= abs(xh - xf) else xh
        n_max = max(math.ceil(math.log2(b.w0 / (2 * self.tol))), 0) + _ITP_N0
        radius = max(self.tol * 2.0 ** (n_max - b.steps) - 0.5 * width, 0.0)
        x = xt if abs(xt - xh) <= radius else xh - sigma * radius
        if not lo < x < hi:
            x = xh
        probes = [x]
        d = _PAIR * self.tol
        if (
            width > 4 * self.tol
            and b.estimate is not None
            and abs(xf - b.estimate) <= _PAIR_TRUST * self.tol
            and lo < x - d
            and x + d < hi
        ):
            # Either the crossing lies between the pair (done), or the bracket shrinks to one
            # side of it, which is no worse than probing x alone: the ITP bound still holds.
            probes = [x - d, x + d]
        probes = [p for p in probes if lo < p < hi and p not in inside]
        return probes, x if lo < x < hi else (probes[0] if probes else math.nan)


# =============================================================================== features


class FeatureLearner(Learner):
    """Refine where Γ jumps or bends sharply, to ``resolution``.

    Starting from ``num`` evenly spaced samples (each gap subdivided to <= ``min_width`` when
    given), every round splits at its midpoint each interval of width > ``resolution`` that
    qualifies, widest first, as one batch (:meth:`ask` returns ``[]`` while a batch is out).
    An interval between consecutive valid samples qualifies when

    * **jump**: its change of Γ differs from the change its neighbouring intervals' slopes
      predict by more than ``jump_db`` (the better of the two neighbours; with none, the change
      itself). A jump keeps this at every width; a steep smooth slope does not;
    * **bend**: an end sample lies more than ``jump_db`` from the chord through its two
      neighbours (a curvature criterion: large where the slope changes sharply relative to the
      neighbouring intervals);
    * **peak**: an end sample is a strict local extremum with a prominence > ``jump_db`` (the
      drop to the lower of the two minima towards higher samples or the ends); such intervals
      are split down to ``resolution / 2`` so the merged peak interval is <= ``resolution``.

    Bends and peaks at a sample next to a jump are not counted: the jump explains them.

    Failed samples (``value`` None or NaN) are skipped by the criteria; an interval is split in
    the widest gap between its failed samples, and not at all once it holds two. Standard
    errors are not used. Refinement stops when no interval qualifies or ``max_points`` values
    were asked. :meth:`features` returns the qualifying intervals, merged.

    Parameters
    ----------
    start, stop : float
        The range of the axis, ``start < stop``.
    num : int
        Starting samples, >= 2.
    resolution : float
        Width to which features are located.
    jump_db : float
        Size (dB) of a jump or bend that counts as a feature.
    max_points : int
        Most values asked in all; at least the starting samples.
    min_width : float, optional
        Spacing of a uniform starting pass (none by default: only the ``num`` samples).
    """

    def __init__(
        self,
        start: float,
        stop: float,
        num: int,
        *,
        resolution: float = 1e-3,
        jump_db: float = 1.0,
        max_points: int = 150,
        min_width: float | None = None,
    ) -> None:
        super().__init__(start, stop, num, max_points)
        self.resolution = _check_real("resolution", resolution, positive=True)
        self.jump_db = _check_real("jump_db", jump_db, positive=True)
        if min_width is not None:
            min_width = _check_real("min_width", min_width, positive=True)
        self.min_width = min_width
        self._initial = _grid(self.start, self.stop, self.num, min_width)
        if len(self._initial) > self.max_points:
            raise ValueError(
                f"max_points must hold the {len(self._initial)} starting points "
                f"(min_width={min_width!r}), got max_points={max_points!r}"
            )

    def features(self) -> list[tuple[float, float]]:
        """Intervals ``(a, b)`` where Γ jumps or bends sharply, merged, increasing."""
        merged: list[list[float]] = []
        for a, b in sorted(self._qualifying()):
            if merged and a <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        return [(a, b) for a, b in merged]

    def _valid(self) -> tuple[np.ndarray, np.ndarray]:
        xs = sorted(
            x for x, s in self._data.items() if s.value is not None and math.isfinite(s.value)
        )
        return np.array(xs, dtype=float), np.array([self._data[x].value for x in xs], dtype=float)

    def _qualifying(self) -> dict[tuple[float, float], float]:
        """Qualifying intervals and the width below which each is no longer split."""
        x, f = self._valid()
        n = len(x)
        if n < 2:
            return {}
        h = np.diff(x)
        df = np.diff(f)
        slope = df / h
        out: dict[tuple[float, float], float] = {}

        jump = np.zeros(n - 1, dtype=bool)
        for i in range(n - 1):
            predicted = [slope[k] * h[i] for k in (i - 1, i + 1) if 0 <= k < n - 1]
            dev = min((abs(df[i] - p) for p in predicted), default=abs(df[i]))
            jump[i] = dev > self.jump_db
            if jump[i]:
                out[(x[i], x[i + 1])] = self.resolution

        for k in range(1, n - 1):
            if jump[k - 1] or jump[k]:
                continue  # the jump explains a bend or an extremum at its ends
            chord = f[k - 1] + (f[k + 1] - f[k - 1]) * (x[k] - x[k - 1]) / (x[k + 1] - x[k - 1])
            if abs(f[k] - chord) > self.jump_db:
                for i in (k - 1, k):
                    out.setdefault((x[i], x[i + 1]), self.resolution)
            if self._prominence(f, k) > self.jump_db:
                for i in (k - 1, k):
                    out[(x[i], x[i + 1])] = 0.5 * self.resolution  # the finest of the criteria
        return {(float(a), float(b)): w for (a, b), w in out.items()}

    @staticmethod
    def _prominence(f: np.ndarray, k: int) -> float:
        """Prominence of sample k if it is a strict local extremum, else 0."""
        if f[k] > f[k - 1] and f[k] > f[k + 1]:
            g = f
        elif f[k] < f[k - 1] and f[k] < f[k + 1]:
            g = -f
        else:
            return 0.0
        drops = []
        for step in (-1, 1):
            low, j = g[k], k + step
            while 0 <= j < len(g) and g[j] <= g[k]:
                low = min(low, g[j])
                j += step
            drops.append(g[k] - low)
        return float(min(drops))

    def _propose(self) -> list[float]:
        initial = [x for x in self._initial if x not in self._data]
        if initial or self._pending:
            return [] if self._pending else initial
        failed = sorted(
            x for x, s in self._data.items() if s.value is None or not math.isfinite(s.value)
        )
        splits = []
        for (a, b), finest in self._qualifying().items():
            if b - a <= finest:
                continue
            holes = [u for u in failed if a < u < b]
            if len(holes) >= 2:
                continue
            cuts = [a, *holes, b]
            gap = max(zip(cuts[:-1], cuts[1:], strict=True), key=lambda g: (g[1] - g[0], -g[0]))
            mid = 0.5 * (gap[0] + gap[1])
            if gap[1] - gap[0] > 0.5 * finest and gap[0] < mid < gap[1]:
                splits.append((b - a, mid))
        room = self.max_points - self.n_asked
        splits.sort(key=lambda s: (-s[0], s[1]))
        return sorted(mid for _, mid in splits[: max(room, 0)])
