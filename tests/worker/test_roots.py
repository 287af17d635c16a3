"""The event solver's root finder against a slow, obviously correct reference.

``f(t) = off + Re Σ_k c_k e^{λ_k t}`` with random coefficients and decaying or oscillating
exponents; the reference samples f densely and bisects the first sign change.
"""

from __future__ import annotations

import cmath
import math

import numpy as np
import pytest

from worker.solvers.event.roots import (
    SPLITS,
    STACK,
    STACK_COLS,
    _decayed_clear,
    cabs,
    cexp,
    clear_sums,
    clear_test,
    clear_whole,
    first_root,
    first_root_end,
    first_root_whole,
    phi1,
    refine,
    skip_start,
    split_points,
    split_table,
)
from worker.solvers.measure import cubic_above, cubic_inside, cubic_minmax, hermite_hull


def f_ref(c: np.ndarray, lam: np.ndarray, off: float, t: np.ndarray) -> np.ndarray:
    """The sum, evaluated the obvious way."""
    return off + np.real(np.exp(np.outer(t, lam)) @ c)


def first_root_ref(c, lam, off, t0, t1, samples=200_001) -> tuple[float | None, float]:
    """First sign change on a dense grid, refined by bisection; (root or None, min f)."""
    t = np.linspace(t0, t1, samples)
    f = f_ref(c, lam, off, t)
    bad = np.flatnonzero(f <= 0.0)
    if bad.size == 0:
        return None, float(f.min())
    i = int(bad[0])
    if i == 0:
        return t0, float(f.min())
    a, b = t[i - 1], t[i]
    for _ in range(80):
        m = 0.5 * (a + b)
        if f_ref(c, lam, off, np.array([m]))[0] > 0.0:
            a = m
        else:
            b = m
    return 0.5 * (a + b), float(f.min())


def random_sum(
    rng: np.random.Generator, m: int, stiff: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """A real sum: conjugate pairs kept once with a doubled coefficient (the reduced form);
    ``stiff`` adds a small, fast mode (24-40 cycles per unit of time)."""
    lam = -rng.uniform(0.0, 0.5, m) + 1j * rng.uniform(0.2, 8.0, m)
    c = 2.0 * (rng.normal(size=m) + 1j * rng.normal(size=m)) * np.exp(-rng.uniform(0, 3, m))
    off = float(rng.uniform(0.2, 2.5))
    if stiff:
        c = np.append(c, 2e-3 * (rng.normal() + 1j * rng.normal()))
        lam = np.append(lam, -rng.uniform(0.0, 2.0) + 1j * rng.uniform(150.0, 250.0))
    return np.ascontiguousarray(c), np.ascontiguousarray(lam), off


def call_first_root(c, lam, off, t0, t1, tol=1e-13):
    stack = np.zeros((STACK, STACK_COLS))
    w4 = np.zeros(len(c))
    return first_root(c, lam, len(c), off, t0, t1, tol, stack, w4)


# The dense reference costs ~20 ms a case: a sample in the fast tier, the full count in CI.
CASES = [60, pytest.param(300, marks=pytest.mark.slow)]
STIFF_CASES = [15, pytest.param(60, marks=pytest.mark.slow)]


@pytest.mark.parametrize("n", CASES)
def test_first_root_agrees_with_dense_sampling_on_random_sums(n):
    rng = np.random.default_rng(20261122 + n)
    decided = with_root = 0
    for _ in range(n):
        c, lam, off = random_sum(rng, int(rng.integers(1, 6)))
        t1 = float(rng.uniform(0.5, 6.0))
        ref, fmin = first_root_ref(c, lam, off, 0.0, t1)
        got = call_first_root(c, lam, off, 0.0, t1)
        scale = off + np.abs(c).sum()
        if ref is None and fmin > 1e-6 * scale:
            assert got < 0.0, (c, lam, off, t1)
            decided += 1
        elif ref is not None:
            # a root the dense grid sees: the finder returns the first one (or an earlier touch
            # between samples, never a later root)
            assert got >= 0.0 and got <= ref + 1e-9, (got, ref)
            assert f_ref(c, lam, off, np.array([got]))[0] <= 1e-9 * scale
            if abs(got - ref) > 1e-9:  # an earlier touch the grid missed: f must reach 0 there
                assert got < ref
            decided += 1
            with_root += 1
    # nearly every case decided, and both kinds (root, no root) were really exercised
    assert decided >= n * 29 // 30 and n // 5 <= with_root <= n * 4 // 5


def test_reduced_and_full_conjugate_forms_give_the_same_roots():
    rng = np.random.default_rng(5)
    for _ in range(50):
        c, lam, off = random_sum(rng, 3)
        full_c = np.concatenate([c / 2, np.conj(c) / 2])
        full_lam = np.concatenate([lam, np.conj(lam)])
        a = call_first_root(c, lam, off, 0.0, 4.0)
        b = call_first_root(full_c, full_lam, off, 0.0, 4.0)
        assert a == pytest.approx(b, abs=1e-11)


def test_grazing_dip_between_coarse_samples_is_found():
    # f = off + cos t dips to off - 1 at t = π: with off = 1 - 1e-10 it is negative only in a
    # window of width ~3e-5 around π, invisible to the endpoint values of [0, 5]
    off = 1.0 - 1e-10
    c = np.array([1.0 + 0j])
    lam = np.array([1j])
    t = call_first_root(c, lam, off, 0.0, 5.0)
    assert t == pytest.approx(math.pi - math.sqrt(2e-10), abs=1e-9)
    # just clear of zero: proven clear
    assert call_first_root(c, lam, 1.0 + 1e-6, 0.0, 5.0) < 0.0


def test_refine_reaches_the_root_to_the_tolerance():
    rng = np.random.default_rng(11)
    for _ in range(100):
        c, lam, off = random_sum(rng, 2)
        ref, _ = first_root_ref(c, lam, off, 0.0, 3.0, samples=20_001)
        if ref is None or ref == 0.0:
            continue
        lo, hi = ref - 1e-3, ref + 1e-3
        flo = f_ref(c, lam, off, np.array([lo]))[0]
        fhi = f_ref(c, lam, off, np.array([hi]))[0]
        if not (flo > 0.0 >= fhi):
            continue
        t = refine(c, lam, len(c), off, lo, hi, flo, fhi, 1e-14)
        assert t == pytest.approx(ref, abs=1e-11)


def test_clear_whole_never_claims_a_piece_with_a_root():
    rng = np.random.default_rng(3)
    claimed = 0
    for _ in range(400):
        c, lam, off = random_sum(rng, 3)
        ln = float(rng.uniform(0.01, 0.5))
        E = np.exp(lam * ln)
        if clear_whole(c, lam, E, len(c), off, ln):
            claimed += 1
            assert f_ref(c, lam, off, np.linspace(0.0, ln, 2001)).min() > 0.0
    assert claimed > 100


def test_skip_start_finds_where_the_gap_opens():
    # f = 1 - cos t >= t²/2 - t⁴/24 rises over all of (0, 1]: no exponential needed, the search
    # may start at the interval's end
    c = np.array([-1.0 + 0j])
    lam = np.array([1j])
    t = skip_start(c, lam, 1, 1.0, 1.0, True)
    assert t == 1.0 and (1.0 - math.cos(t)) > 2e-12
    # over (0, 8] it comes back to zero at 2π: the start stays before that
    t = skip_start(c, lam, 1, 1.0, 8.0, True)
    assert 0.0 < t < 2.0 * math.pi and (1.0 - math.cos(t)) > 2e-12


def departures(rng: np.random.Generator, n: int):
    """Sums that leave zero with f = f' = 0 (a departure) or f = f' = f'' = 0 (a release),
    rising: a random sum S minus 1 - e^{-t} and 1 - e^{-2t} terms fixing the derivatives."""
    while n:
        c, lam, _ = random_sum(rng, int(rng.integers(1, 5)))
        s0 = float(np.real(c.sum()))
        s1, s2, s3 = (float(np.real(np.sum(c * lam**k))) for k in (1, 2, 3))
        release = bool(rng.integers(0, 2))
        beta = -(s1 + s2) / 2.0 if release else 0.0
        alpha = (2.0 * s1 + s2) if release else s1
        d2 = s2 + alpha + 4.0 * beta
        d3 = s3 - alpha - 8.0 * beta
        if (release and d3 <= 0.0) or (not release and d2 <= 0.0):
            continue
        cc = np.concatenate([c, [alpha + 0j, beta + 0j]])
        ll = np.concatenate([lam, [-1.0 + 0j, -2.0 + 0j]])
        # f = S - S(0) - α(1 - e^{-t}) - β(1 - e^{-2t}): the offset is -S(0) - α - β
        yield cc, ll, -s0 - alpha - beta
        n -= 1


def test_skip_start_never_skips_a_root_beyond_the_round_off():
    # After a departure f is round-off, then clearly positive: the search may start anywhere
    # before f's first real root, never after it; and (the point of it) well after the
    # round-off stretch, so the search does not crawl up from there.
    rng = np.random.default_rng(5)
    fractions = []
    for c, lam, off in departures(rng, 300):
        h = float(rng.uniform(0.05, 2.0))
        assert abs(f_ref(c, lam, off, np.array([0.0]))[0]) < 1e-12
        t = skip_start(c, lam, len(c), off, h, True)
        assert 0.0 < t <= h
        scale = abs(off) + np.abs(c).sum()
        grid = np.linspace(0.0, t, 20_001)[1:]
        vals = f_ref(c, lam, off, grid)
        assert vals[-1] > 1e-12 * scale
        clear = np.flatnonzero(vals > 1e-9 * scale)  # beyond any round-off
        assert not clear.size or np.all(vals[clear[0] :] > 0.0)
        fractions.append(t / h)
    assert np.median(fractions) > 1e-2


def entries(rng: np.random.Generator, n: int, stiff: bool = False):
    """Sums that leave zero with f = f' = 0 and f'' < 0: the tip held against a stop by the
    forcing, let go (a reset or a departure that is not one). f dips below zero at once, and
    on some of them comes back above it within the interval."""
    while n:
        c, lam, _ = random_sum(rng, int(rng.integers(1, 5)), stiff=stiff)
        s0 = float(np.real(c.sum()))
        s1, s2 = (float(np.real(np.sum(c * lam**k))) for k in (1, 2))
        # f = S - S(0) - s1 (1 - e^{-t}): f(0) = f'(0) = 0, f''(0) = s2 + s1
        if s2 + s1 >= -1e-3:
            continue
        cc = np.concatenate([c, [s1 + 0j]])
        ll = np.concatenate([lam, [-1.0 + 0j]])
        yield cc, ll, -s0 - s1
        n -= 1


@pytest.mark.parametrize("stiff", [False, True])
def test_skip_start_never_skips_a_contact_that_starts_at_once(stiff):
    # A gap that closes at once (f'' < 0) is a contact, not a departure: no start may be
    # returned beyond a stretch where f is below zero by more than round-off, even where f is
    # above zero again at the interval's end: a start past the dip lets the tip fly through
    # the stop for a sub-grid interval (at a run from a state held on a stop, up to a tenth of
    # the clearance deep), and the answer then depends on the sub-grid.
    rng = np.random.default_rng(11)
    back_out = 0
    for c, lam, off in entries(rng, 200, stiff=stiff):
        h = float(rng.uniform(0.5, 8.0))
        scale = abs(off) + np.abs(c).sum()
        grid = np.linspace(0.0, h, 40_001)[1:]
        vals = f_ref(c, lam, off, grid)
        back_out += bool(vals[-1] > 1e-9 * scale)
        t = skip_start(c, lam, len(c), off, h, True)
        if t < 0.0:
            continue
        assert t <= h
        assert vals[grid <= t].min() > -1e-9 * scale
    assert back_out > 20  # the case that matters is in the sample


def test_skip_start_of_a_contact_force_may_skip_its_tensile_start():
    # f = -1e-6 + (1 - e^{-t}): below zero by far more than round-off, then rising. As a gap it
    # closes first (a contact: -1); as the contact force of a stick tried where leaving the
    # stop failed, its start is skipped to where it is clearly positive.
    c = np.array([-1.0 + 0j])
    lam = np.array([-1.0 + 0j])
    off = 1.0 - 1e-6
    assert skip_start(c, lam, 1, off, 0.5, True) == -1.0
    t = skip_start(c, lam, 1, off, 0.5, False)
    assert 0.0 < t <= 0.5 and f_ref(c, lam, off, np.array([t]))[0] > 0.0


@pytest.mark.parametrize("x", [0.0, 1e-9, 1e-4 + 2e-4j, 0.5 - 3j, -7.0])
def test_phi1_is_the_integral_of_the_exponential(x):
    ln = 0.7
    t = np.linspace(0.0, ln, 200_001)
    integrand = np.exp(x * t)
    ref = np.sum((integrand[1:] + integrand[:-1]) / 2) * (t[1] - t[0])
    assert phi1(complex(x), ln) == pytest.approx(ref, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("n", STIFF_CASES)
def test_stiff_modes_are_bounded_by_their_size_and_roots_still_found(n):
    # a slow sum plus one mode turning ~100 cycles over the interval: the Hermite bound of the
    # whole sum is useless, the split search still proves clear pieces and finds the roots
    rng = np.random.default_rng(17 + n)
    decided = with_root = 0
    for _ in range(n):
        c, lam, off = random_sum(rng, 2, stiff=True)
        t1 = float(rng.uniform(2.0, 4.0))
        ref, fmin = first_root_ref(c, lam, off, 0.0, t1, samples=400_001)
        got = call_first_root(c, lam, off, 0.0, t1)
        scale = off + np.abs(c).sum()
        if ref is None and fmin > 1e-6 * scale:
            assert got < 0.0
            decided += 1
        elif ref is not None:
            assert 0.0 <= got <= ref + 1e-9
            assert f_ref(c, lam, off, np.array([got]))[0] <= 1e-9 * scale
            decided += 1
            with_root += 1
    assert decided >= n * 11 // 12 and max(1, n // 12) <= with_root <= n * 11 // 12


def _piece_inputs(c, lam, off, total, lo, hi):
    """What the split search hands ``_decayed_clear`` for the piece [lo, hi] of [0, total]:
    the marked weights, the slow modes' bound weight, and f, ḟ at both ends of the whole sum
    and of its slow modes."""
    m2 = np.abs(lam) ** 2
    fast = m2 > (4.43 / total) ** 2
    w4 = np.abs(c) * m2 * m2
    slow = float(w4[~fast].sum())  # the caller's factor for decaying slow modes is 1
    w4 = np.where(fast, -w4, w4)

    def ends(sel):
        e = np.exp(np.outer([lo, hi], lam[sel])) * c[sel]
        f = off + e.real.sum(axis=1)
        d = (e * lam[sel]).real.sum(axis=1)
        return f[0], d[0], f[1], d[1]

    return w4, slow, ends(np.ones(len(c), bool)), ends(~fast)


def test_decayed_bound_of_fast_modes_never_clears_a_piece_with_a_root():
    # Stiff, strongly damped modes of an impact (|λ| 1e2…1e5) over a slow sum: on pieces that
    # start after t = 0 the fast modes are bounded by their size where the piece starts. On
    # every piece the test clears, the dense samples of f stay positive; it clears pieces the
    # bounds at t = 0 cannot, and pieces with a root are never cleared.
    rng = np.random.default_rng(4)
    cleared = beyond = refused_roots = 0
    for _ in range(400):
        c, lam, off = random_sum(rng, 2)
        k = int(rng.integers(1, 4))
        mag = 10.0 ** rng.uniform(2.0, 5.0, k)
        xi = rng.uniform(0.05, 1.0, k)
        c = np.append(c, rng.normal(scale=1.0, size=k) * (1 + 1j))
        lam = np.append(lam, mag * (-xi + 1j * np.sqrt(np.maximum(1.0 - xi * xi, 0.0))))
        total = 0.06
        lo = float(rng.uniform(0.0, 0.9)) * total
        hi = lo + float(rng.uniform(0.01, 0.3)) * total
        w4, slow, (f0, d0, f1, d1), (s0, e0, s1, e1) = _piece_inputs(c, lam, off, total, lo, hi)
        ln = hi - lo
        l4 = ln**4 / 384.0
        got = _decayed_clear(c, lam, len(c), w4, lo, hi, ln, l4, slow, f0, d0, f1, d1, s0, e0,
                             s1, e1)  # fmt: skip
        fmin = float(f_ref(c, lam, off, np.linspace(lo, hi, 20_001)).min())
        if got:
            cleared += 1
            assert fmin > 0.0, (c, lam, off, lo, hi)
            bfast0 = float(np.abs(c[w4 < 0.0]).sum())
            if not (cubic_above(f0, d0, f1, d1, ln, float(np.abs(w4).sum()) * l4, 0.0)
                    or cubic_above(s0, e0, s1, e1, ln, slow * l4, bfast0)):  # fmt: skip
                beyond += 1
        elif fmin <= 0.0:
            refused_roots += 1
    assert cleared >= 250 and beyond >= 150 and refused_roots >= 40


def test_cexp_is_cmath_exp_and_cabs_is_abs_to_an_ulp():
    rng = np.random.default_rng(23)
    zs = [complex(x, y) for x, y in rng.normal(scale=30.0, size=(2000, 2))]
    zs += [0j, 1e-300j, complex(-700.0, 3.0), complex(700.0, -1e5)]
    for z in zs:  # equal here; an ulp allowed for another libm
        assert cexp(z) == pytest.approx(cmath.exp(z), rel=4.5e-16, abs=0.0)
    for z in zs + [complex(1e-200, -3e-201), complex(3e180, 1e180), complex(1e150, 1e150)]:
        assert cabs(z) == pytest.approx(abs(z), rel=2.3e-16, abs=0.0)


def test_shared_clear_sums_prove_both_signs_as_clear_whole_does():
    # one set of sums of w serves both stops (g1 - w and g2 + w)
    rng = np.random.default_rng(29)
    for _ in range(300):
        c, lam, off = random_sum(rng, 3)
        ln = float(rng.uniform(0.01, 0.5))
        E = np.exp(lam * ln)
        sums = clear_sums(c, lam, E, len(c), ln)
        for sgn in (1.0, -1.0):
            want = clear_whole(sgn * c, lam, E, len(c), off, ln)
            assert clear_test(sums, off, sgn, ln) == want


@pytest.mark.parametrize("stiff", [False, True])
def test_first_root_whole_is_first_root_with_the_end_exponentials_given(stiff):
    rng = np.random.default_rng(31 + stiff)
    for _ in range(200):
        c, lam, off = random_sum(rng, 3, stiff)
        ln = float(rng.uniform(0.05, 4.0))
        E = np.array([cexp(complex(x)) for x in lam * ln])
        want = call_first_root(c, lam, off, 0.0, ln)
        stack = np.zeros((STACK, STACK_COLS))
        got = first_root_whole(c, lam, E, len(c), off, ln, 1e-13, stack, np.zeros(len(c)))
        assert got == pytest.approx(want, abs=1e-12 * ln)


def test_split_points_are_the_first_two_splits_of_the_interval():
    for h in (1.0, 0.1, 2.0 * math.pi / 0.37 / 64):
        pts = np.empty(SPLITS)
        split_points(h, pts)
        quarters = pts[:3] / h * 4.0
        sixteenths = pts[3:].reshape(4, 3) / h * 16.0
        assert np.allclose(quarters, [1, 2, 3], rtol=0, atol=1e-12)
        assert np.allclose(sixteenths, [[4 * i + j for j in (1, 2, 3)] for i in range(4)],
                           rtol=0, atol=1e-12)  # fmt: skip


@pytest.mark.parametrize("stiff", [False, True])
def test_a_whole_interval_search_with_its_split_table_is_the_same_to_the_bit(stiff):
    # The event kernel hands a search over a whole sub-grid interval [0, h] the exponentials
    # of the first two splits' points, computed ahead: the root (or -1) must be the one the
    # search finds evaluating them itself, bit for bit, or the trajectories would move.
    rng = np.random.default_rng(43 + stiff)
    roots = differs = 0
    for _ in range(400):
        c, lam, off = random_sum(rng, 3, stiff)
        h = float(rng.uniform(0.05, 4.0))
        n = len(c)
        E = np.array([cexp(complex(x) * h) for x in lam])
        P = np.zeros((1, SPLITS, n), dtype=complex)
        split_table(lam[None, :], np.array([n]), h, P)
        stack = np.zeros((STACK, STACK_COLS))
        w4 = np.zeros(n)
        want = first_root_whole(c, lam, E, n, off, h, 1e-13, stack, w4)
        got = first_root_whole(c, lam, E, n, off, h, 1e-13, stack, w4, P[0])
        assert got == want
        roots += want >= 0.0
        # and the table is what the search reads: a wrong one moves some answers
        wrong = first_root_whole(c, lam, E, n, off, h, 1e-13, stack, w4, 1.01 * P[0])
        differs += wrong != want
    assert roots > 100
    assert differs > 20 or stiff  # the stiff search bounds the fast mode its own way


def test_cexp_on_the_axes_is_the_general_formula_bit_for_bit():
    # the forcing mode (λ = iγ) and a stuck regime's λ = 0 skip the exponential or the sine
    # and cosine; the value must be what e^{Re z}·(cos Im z, sin Im z) gives, signed zeros too
    rng = np.random.default_rng(37)
    zs = [complex(0.0, y) for y in rng.normal(scale=30.0, size=500)]
    zs += [complex(x, 0.0) for x in rng.normal(scale=30.0, size=500)]
    zs += [complex(x, -0.0) for x in rng.normal(scale=3.0, size=50)]
    zs += [complex(-0.0, y) for y in rng.normal(scale=3.0, size=50)]
    zs += [0j, complex(-0.0, -0.0), complex(0.0, -0.0), complex(-0.0, 0.0)]
    for z in zs:
        r = math.exp(z.real)
        want = complex(r * math.cos(z.imag), r * math.sin(z.imag))
        got = cexp(z)
        assert got == want
        assert math.copysign(1.0, got.imag) == math.copysign(1.0, want.imag)


def test_skip_start_with_curvature_and_a_constant_mode():
    # f = 0.5 + 0.5 - cos t (a λ = 0 mode, as in a stuck regime): f(0) = ḟ(0) = 0, f̈(0) = 1,
    # rising over all of (0, 0.5]
    c = np.array([-1.0 + 0j, 0.5 + 0j])
    lam = np.array([1j, 0j])
    assert skip_start(c, lam, 2, 0.5, 0.5, False) == 0.5


@pytest.mark.parametrize("stiff", [False, True])
def test_first_root_end_is_first_root_bit_for_bit(stiff):
    # the search from a late start t0 to the interval's end, with e^{λ·t1} given as cexp gives
    # it: the same answer to the last bit (the end's f and ḟ are the same sums)
    rng = np.random.default_rng(41 + stiff)
    found = 0
    for _ in range(300):
        c, lam, off = random_sum(rng, 3, stiff)
        t1 = float(rng.uniform(0.05, 4.0))
        t0 = float(rng.uniform(0.0, 0.5)) * t1
        E = np.array([cexp(complex(x) * t1) for x in lam])
        want = call_first_root(c, lam, off, t0, t1)
        stack = np.zeros((STACK, STACK_COLS))
        got = first_root_end(c, lam, E, len(c), off, t0, t1, 1e-13, stack, np.zeros(len(c)))
        assert got == want
        found += want >= 0.0
    assert 0 < found < 300


def test_hermite_hull_holds_the_cubics_rounded_extrema():
    # a test passed on the hull must pass on the cubic: its computed min and max lie inside,
    # also where an extremum sits at an end or the slopes nearly vanish
    rng = np.random.default_rng(43)
    for _ in range(20_000):
        f0, f1 = rng.normal(size=2) * 10.0 ** rng.uniform(-3, 3)
        d0, d1 = rng.normal(size=2) * 10.0 ** rng.uniform(-6, 3, size=2)
        if rng.uniform() < 0.2:
            d0 *= 1e-16
        if rng.uniform() < 0.2:
            f1 = f0 * (1.0 + 1e-16 * rng.normal())
        ln = 10.0 ** rng.uniform(-6, 1)
        fmin, _, fmax, _ = cubic_minmax(f0, d0, f1, d1, ln)
        lo, hi = hermite_hull(f0, d0, f1, d1, ln)
        assert lo <= fmin and fmax <= hi


def test_cubic_tests_decide_as_the_exact_cubic_extrema_do():
    # the hull is only a shortcut: every decision is the one cubic_minmax gives
    rng = np.random.default_rng(47)
    for _ in range(5_000):
        f0, f1 = rng.normal(size=2)
        d0, d1 = rng.normal(size=2) * 10.0 ** rng.uniform(-2, 2, size=2)
        ln = 10.0 ** rng.uniform(-2, 0.5)
        a, b, lo, hi = rng.normal(size=4) * 0.5
        fmin, _, fmax, _ = cubic_minmax(f0, d0, f1, d1, ln)
        assert cubic_above(f0, d0, f1, d1, ln, a, b) == (fmin - a - b > 0.0)
        pad = abs(a)
        want = fmax + pad < hi + 1.5 and fmin - pad > lo - 1.5
        assert cubic_inside(f0, d0, f1, d1, ln, lo - 1.5, hi + 1.5, pad) == want
