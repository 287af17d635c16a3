"""Adaptive sampling of one line (issue 17): band edges to a tolerance and features to a
resolution, driven to the end on functions whose crossings and features are known."""

from __future__ import annotations

import math
import random
import re
from collections.abc import Callable

import numpy as np
import pytest

from service.studies.adaptive import BandEdgeLearner, Edge, FeatureLearner, Learner, Sample

Fn = Callable[[float], Sample]


def resonance(x: float | np.ndarray, omega: float, xi: float) -> np.ndarray:
    return np.abs(1 / (1 - x**2 / omega**2 + 2j * xi * x / omega))


def bands(x: float | np.ndarray) -> np.ndarray:
    """Three resonances, 16 dB down: three bands above 0 dB, six crossings in 0.2..6."""
    h = resonance(x, 1.0, 0.05) + resonance(x, 2.5, 0.02) + resonance(x, 4.2, 0.01)
    return 20 * np.log10(h) - 16.0


def exact(f: Callable[[float], float]) -> Fn:
    return lambda x: Sample(float(f(x)))


def crossings(f: Callable[[float], float], a: float, b: float) -> list[tuple[float, bool]]:
    """The crossings of f = 0 in [a, b]: a dense sign scan, then bisection to 1e-12."""
    x = np.linspace(a, b, 100_001)
    g = np.asarray(f(x))  # f is vectorised
    out = []
    for i in np.nonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0]:
        lo, hi = x[i], x[i + 1]
        while hi - lo > 1e-12:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.sign(f(mid)) == np.sign(g[i]) else (lo, mid)
        out.append((0.5 * (lo + hi), bool(g[i] < 0)))
    return out


def drive(learner: Learner, fn: Fn, *, order: str = "forward", seed: int = 0) -> list[list[float]]:
    """Run a learner to the end; check every batch; return the batches."""
    rng = random.Random(seed)
    asked: set[float] = set()
    batches = []
    while True:
        xs = learner.ask()
        if not xs:
            break
        assert xs == sorted(xs)
        assert all(isinstance(x, float) and learner.start <= x <= learner.stop for x in xs)
        assert not asked & set(xs), "a value was asked twice"
        asked |= set(xs)
        assert len(asked) <= learner.max_points
        batches.append(xs)
        told = list(xs)
        if order == "reverse":
            told.reverse()
        elif order == "shuffle":
            rng.shuffle(told)
        for x in told:
            learner.tell(x, fn(x))
    assert learner.done
    assert learner.n_points == len(asked) == learner.n_asked
    assert [x for x, _ in learner.samples()] == sorted(asked)
    return batches


def assert_found(edges: list[Edge], truth: list[tuple[float, bool]], tol: float) -> None:
    assert len(edges) == len(truth), (edges, truth)
    for edge, (x, rising) in zip(edges, truth, strict=True):
        assert edge.certain
        assert edge.hi - edge.lo <= 2 * tol
        assert edge.lo <= x <= edge.hi
        assert abs(edge.x - x) <= tol
        assert edge.rising is rising


# =============================================================================== band edges


def test_resonance_bands_every_edge_to_tol_in_few_points():
    truth = crossings(bands, 0.2, 6.0)
    assert len(truth) == 6
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3)
    batches = drive(learner, exact(bands))
    assert_found(learner.edges(), truth, 1e-3)
    # A uniform grid at tol needs ~5,800 points; the coarse pass is 65.
    assert learner.n_points < 110
    assert len(batches) <= 8  # brackets refine in parallel
    assert learner.unresolved() == []


@pytest.mark.parametrize("tol", [1e-2, 1e-4, 1e-6])
def test_tolerance_is_met_at_every_scale(tol):
    truth = crossings(bands, 0.2, 6.0)
    learner = BandEdgeLearner(0.2, 6.0, 3, tol=tol, max_points=200)
    drive(learner, exact(bands))
    assert_found(learner.edges(), truth, tol)
    # Each edge costs at most the bisection count from the coarse spacing, plus a pair.
    bisect = math.ceil(math.log2((5.8 / 64) / (2 * tol))) + 2
    assert learner.n_points - 65 <= len(truth) * bisect


def test_threshold_other_than_zero():
    truth = crossings(lambda x: bands(x) + 5.0, 0.2, 6.0)
    learner = BandEdgeLearner(0.2, 6.0, 2, threshold_db=-5.0, tol=1e-3)
    drive(learner, exact(bands))
    assert_found(learner.edges(), truth, 1e-3)


def test_jump_discontinuity_located_to_tol():
    edge = 2.3456789

    def f(x: float) -> float:
        return 0.3 * x + (4.0 if x >= edge else -6.0)

    learner = BandEdgeLearner(0.0, 5.0, 2, tol=1e-4)
    drive(learner, exact(f))
    assert_found(learner.edges(), [(edge, True)], 1e-4)
    assert learner.n_points - 65 <= math.ceil(math.log2((5 / 64) / 2e-4)) + 2


def test_band_just_wider_than_min_width_is_found_anywhere():
    for offset in np.linspace(0.0, 1.0, 7):
        a = 1.0 + offset * 0.05
        b = a + 1.05 * 0.05
        learner = BandEdgeLearner(0.0, 3.2, 2, min_width=0.05, tol=1e-4, max_points=200)
        drive(learner, exact(lambda x, a=a, b=b: 1.0 if a <= x <= b else -1.0))
        assert_found(learner.edges(), [(a, True), (b, False)], 1e-4)


def test_band_narrower_than_min_width_may_be_missed():
    # Documented: only bands >= min_width are guaranteed. This one falls between samples.
    learner = BandEdgeLearner(0.0, 3.2, 2, min_width=0.05)
    drive(learner, exact(lambda x: 1.0 if 1.01 <= x <= 1.04 else -1.0))
    assert learner.edges() == []


def test_exact_hit_is_the_edge_and_a_touch_is_none():
    # The coarse pass of 0..2 with min_width 0.25 has 1.0 exactly.
    learner = BandEdgeLearner(0.0, 2.0, 3, min_width=0.25)
    drive(learner, exact(lambda x: x - 1.0))
    assert learner.edges() == [Edge(1.0, 1.0, 1.0, rising=True, certain=True)]
    assert learner.n_points == 9
    touch = BandEdgeLearner(0.0, 2.0, 3, min_width=0.25)
    drive(touch, exact(lambda x: -((x - 1.0) ** 2)))
    assert touch.edges() == []


def test_falling_edge_starting_on_the_side_above():
    learner = BandEdgeLearner(-1.0, 1.0, 2, tol=1e-5)
    drive(learner, exact(lambda x: -math.sinh(3 * (x - 0.123))))
    assert_found(learner.edges(), [(0.123, False)], 1e-5)


# ----------------------------------------------------------------------- statistics


def noisy(edge: float, half_width: float, se: float) -> Fn:
    """Γ = 10 (x - edge) dB; irregular (with se) within half_width of the edge."""

    def fn(x: float) -> Sample:
        value = 10.0 * (x - edge)
        return Sample(value, se if abs(x - edge) < half_width else None)

    return fn


def test_noisy_crossing_is_an_uncertain_interval_and_costs_few_points():
    # z se = 2 dB: the band straddles 0 dB for |x - 3| <= 0.2.
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3, z=2.0)
    drive(learner, noisy(3.0, 0.5, 1.0))
    [edge] = learner.edges()
    assert not edge.certain
    assert edge.rising
    assert edge.lo <= 3.0 <= edge.hi
    # The interval is the straddling region, closed in from the known sides to a quarter of it.
    assert 2.7 <= edge.lo <= 2.8 <= 3.2 <= edge.hi <= 3.3
    assert learner.n_points - 65 <= 8
    assert learner.unresolved() == []


def test_noise_far_from_the_threshold_changes_nothing():
    # Irregular points whose band clears the threshold have known sides.
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3)
    drive(learner, lambda x: Sample(10.0 * (x - 3.0), 0.001))
    assert_found(learner.edges(), [(3.0, True)], 1e-3)


def test_a_single_straddling_probe_near_a_steep_edge_is_resolved():
    # Only the band |x - e| <= 2e-4 straddles: refinement resolves around it to tol.
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3)
    drive(learner, lambda x: Sample(100.0 * (x - 3.01), 0.01))
    [edge] = learner.edges()
    assert edge.certain and edge.lo <= 3.01 <= edge.hi and edge.hi - edge.lo <= 2e-3


def test_straddling_between_same_sides_is_unresolved_not_an_edge():
    # A dip to the threshold within the noise, never below it.
    def fn(x: float) -> Sample:
        value = 0.5 + 40 * (x - 2.0) ** 2
        return Sample(value, 1.0 if abs(x - 2.0) < 0.2 else None)

    learner = BandEdgeLearner(0.2, 6.0, 2)
    drive(learner, fn)
    assert learner.edges() == []
    assert learner.n_points == 65  # no points spent on it
    [(lo, hi)] = learner.unresolved()
    assert lo < 2.0 < hi


# ----------------------------------------------------------------------- failed points


def failing(f: Callable[[float], float], holes: list[tuple[float, float]]) -> Fn:
    def fn(x: float) -> Sample:
        if any(a <= x <= b for a, b in holes):
            return Sample(None)
        return Sample(float(f(x)))

    return fn


def test_failed_points_around_an_edge_give_an_uncertain_edge_spanning_them():
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3, max_unknown=4)
    drive(learner, failing(lambda x: x - 3.0, [(2.95, 3.08)]))
    [edge] = learner.edges()
    assert not edge.certain and edge.rising
    assert edge.lo < 2.95 and edge.hi > 3.08
    assert edge.hi - edge.lo < 0.13 + 2 * 0.04  # closed in from outside
    failed = [x for x, s in learner.samples() if s.value is None]
    assert all(edge.lo < x < edge.hi for x in failed)
    assert sum(2.95 <= x <= 3.08 for x in failed) <= 4 + 2  # max_unknown probes + coarse


def test_an_isolated_failure_in_a_bracket_is_stepped_around():
    # Only the coarse point nearest the edge fails: its neighbours resolve the edge to tol.
    coarse = BandEdgeLearner(0.2, 6.0, 2)._coarse
    near = min(coarse, key=lambda x: abs(x - 3.01))
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3)
    drive(learner, failing(lambda x: x - 3.01, [(near, near)]))
    assert_found(learner.edges(), [(3.01, True)], 1e-3)


def test_failed_points_away_from_edges_create_no_edges():
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3)
    drive(learner, failing(lambda x: x - 3.0, [(0.2, 0.3), (1.0, 1.2), (5.0, 5.05)]))
    assert_found(learner.edges(), [(3.0, True)], 1e-3)
    unresolved = learner.unresolved()
    assert len(unresolved) == 3
    assert unresolved[0][0] == 0.2  # a run at the end of the range


def test_all_points_failing_is_done_with_no_edges():
    learner = BandEdgeLearner(0.2, 6.0, 2)
    drive(learner, lambda x: Sample(None))
    assert learner.edges() == [] and learner.n_points == 65
    assert learner.unresolved() == [(0.2, 6.0)]


def test_nan_is_a_failed_point():
    learner = BandEdgeLearner(0.0, 1.0, 2, min_width=0.5)
    drive(learner, lambda x: Sample(math.nan if x == 0.5 else x - 0.5))
    [edge] = learner.edges()
    # Closed in around the failed point to tol / 2 on either side: known to tol after all.
    assert edge.lo < 0.5 < edge.hi and edge.hi - edge.lo <= 2e-3 and edge.certain
    assert [x for x, s in learner.samples() if s.value is None or math.isnan(s.value)] == [0.5]


# ----------------------------------------------------------------------- budget


@pytest.mark.parametrize("max_points", [65, 66, 72, 80])
def test_max_points_stops_and_reports_open_brackets_as_they_are(max_points):
    truth = crossings(bands, 0.2, 6.0)
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-6, max_points=max_points)
    drive(learner, exact(bands))
    assert learner.n_points == max_points
    edges = learner.edges()
    assert len(edges) == len(truth)
    for edge, (x, rising) in zip(edges, truth, strict=True):
        assert edge.lo <= x <= edge.hi and edge.rising is rising
        assert edge.certain is (edge.hi - edge.lo <= 2e-6)
    assert not all(e.certain for e in edges)


def test_coarse_pass_must_fit_the_budget():
    with pytest.raises(ValueError, match=r"max_points=64\b"):
        BandEdgeLearner(0.2, 6.0, 2, max_points=64)


# ----------------------------------------------------------------------- protocol


def test_deterministic_whatever_the_order_of_tells():
    runs = []
    for order, seed in (("forward", 0), ("reverse", 0), ("shuffle", 1), ("shuffle", 2)):
        learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-4)
        batches = drive(learner, exact(bands), order=order, seed=seed)
        runs.append((batches, learner.edges()))
    assert all(run == runs[0] for run in runs[1:])


def test_ask_while_points_are_outstanding_gives_only_independent_work():
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3)
    first = learner.ask()
    assert len(first) == 65 and first[0] == 0.2 and first[-1] == 6.0
    assert learner.ask() == [] and not learner.done
    # Tell only the lower half: only brackets there can be refined.
    for x in first[:33]:
        learner.tell(x, exact(bands)(x))
    more = learner.ask()
    assert more and all(x < first[32] for x in more)
    assert learner.ask() == []  # those probes are outstanding
    assert learner.pending == sorted(set(first[33:]) | set(more))
    # Finish in a scrambled order; the edges are the same as in an orderly run.
    rng = random.Random(3)
    while not learner.done:
        todo = learner.pending
        rng.shuffle(todo)
        for x in todo[: max(1, len(todo) // 3)]:
            learner.tell(x, exact(bands)(x))
        learner.ask()
    reference = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3)
    drive(reference, exact(bands))
    assert learner.edges() == reference.edges()


def test_tell_refuses_unasked_and_repeated_values_and_bad_se():
    learner = BandEdgeLearner(0.0, 1.0, 2, min_width=0.5)
    with pytest.raises(ValueError, match="x=0.25 was never asked"):
        learner.tell(0.25, Sample(1.0))
    learner.ask()
    learner.tell(0.5, Sample(1.0))
    with pytest.raises(ValueError, match="x=0.5 was already told"):
        learner.tell(0.5, Sample(1.0))
    with pytest.raises(ValueError, match="se=-1.0"):
        learner.tell(0.0, Sample(1.0, -1.0))


# =============================================================================== features


def test_features_locate_a_peak_and_a_jump_to_resolution():
    peak, jump = 2.0, 4.1234

    def f(x: float) -> float:
        return float(20 * np.log10(resonance(x, peak, 0.01))) + (5.0 if x >= jump else 0.0)

    learner = FeatureLearner(0.2, 6.0, 2, resolution=1e-3, min_width=5.8 / 32)
    drive(learner, exact(f))
    features = learner.features()
    top = peak * math.sqrt(1 - 2 * 0.01**2)  # the maximum of |H|
    assert any(a <= top <= b and b - a <= 1e-3 for a, b in features), features
    assert any(a <= jump <= b and b - a <= 1e-3 for a, b in features), features
    assert all(b - a <= 1e-3 for a, b in features)
    assert learner.n_points < 150


def test_features_find_a_jump_from_two_starting_samples():
    learner = FeatureLearner(0.0, 1.0, 2, resolution=1e-4)
    drive(learner, exact(lambda x: 2.0 * x + (3.0 if x > 0.3 else 0.0)))
    [(a, b)] = learner.features()
    assert a < 0.3 <= b and b - a <= 1e-4
    assert learner.n_points <= 2 + 2 * math.ceil(math.log2(1e4))


def test_features_of_a_linear_function_need_no_refinement():
    learner = FeatureLearner(0.2, 6.0, 5)
    drive(learner, exact(lambda x: 30.0 * x - 40.0))  # steep, but no feature
    assert learner.n_points == 5 and learner.features() == []


def test_features_stop_at_max_points_with_wide_intervals():
    learner = FeatureLearner(0.0, 1.0, 2, resolution=1e-9, max_points=12)
    drive(learner, exact(lambda x: 3.0 if x > 0.3 else 0.0))
    assert learner.n_points == 12
    [(a, b)] = learner.features()
    assert a < 0.3 <= b and b - a > 1e-9


def test_features_skip_failed_points():
    learner = FeatureLearner(0.0, 1.0, 2, resolution=1e-3)
    drive(learner, failing(lambda x: 3.0 if x > 0.3 else 0.0, [(0.5, 0.5)]))
    [(a, b)] = learner.features()
    assert a < 0.3 <= b and b - a <= 1e-3


# =============================================================================== arguments


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"start": 1.0, "stop": 1.0}, "start=1.0, stop=1.0"),
        ({"start": 2.0, "stop": 1.0}, "start=2.0, stop=1.0"),
        ({"start": math.nan}, "start=nan"),
        ({"stop": "x"}, "stop='x'"),
        ({"num": 1}, "num=1"),
        ({"num": 2.0}, "num=2.0"),
        ({"num": True}, "num=True"),
        ({"tol": 0.0}, "tol=0.0"),
        ({"tol": -1e-3}, "tol=-0.001"),
        ({"max_points": 1, "num": 2}, "max_points=1"),
        ({"max_points": 10, "num": 20}, "max_points=10"),
        ({"min_width": 0.0}, "min_width=0.0"),
        ({"z": -1.0}, "z=-1.0"),
        ({"threshold_db": math.inf}, "threshold_db=inf"),
        ({"max_unknown": 0}, "max_unknown=0"),
    ],
)
def test_band_edge_bad_arguments(kwargs, message):
    args = {"start": 0.2, "stop": 6.0, "num": 2} | kwargs
    with pytest.raises(ValueError, match=re.escape(message)):
        BandEdgeLearner(args.pop("start"), args.pop("stop"), args.pop("num"), **args)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"resolution": 0.0}, "resolution=0.0"),
        ({"jump_db": -1.0}, "jump_db=-1.0"),
        ({"max_points": 3, "num": 4}, "max_points=3"),
        ({"min_width": -0.1}, "min_width=-0.1"),
        ({"start": 3.0, "stop": 2.0}, "start=3.0, stop=2.0"),
    ],
)
def test_feature_bad_arguments(kwargs, message):
    args = {"start": 0.2, "stop": 6.0, "num": 2} | kwargs
    with pytest.raises(ValueError, match=re.escape(message)):
        FeatureLearner(args.pop("start"), args.pop("stop"), args.pop("num"), **args)
