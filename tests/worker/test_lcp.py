"""Lemke's algorithm (compiled) and the two-stop closed form (docs/model.md, time stepping)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from worker.solvers.lcp import (
    LEMKE_BUDGET,
    LEMKE_OK,
    LEMKE_RAY,
    lemke_nb,
    lemke_workspace,
    two_stop_closed_form,
    two_stop_matrix,
)


class LCPError(RuntimeError):
    """Lemke stopped without a solution (ray termination or pivot budget)."""


def lemke(M, q, max_pivots: int = 1000) -> np.ndarray:
    """The compiled solver with a fresh workspace; raises on ray termination or budget."""
    M = np.ascontiguousarray(M, dtype=float)
    q = np.ascontiguousarray(q, dtype=float)
    ws = lemke_workspace(len(q))
    status = lemke_nb(M, q, *ws, max_pivots)
    if status == LEMKE_RAY:
        raise LCPError("ray termination")
    if status == LEMKE_BUDGET:
        raise LCPError("pivot budget exhausted")
    assert status == LEMKE_OK
    return ws[-1].copy()


# ---------------------------------------------------------------------------------------------
# Reference helpers
# ---------------------------------------------------------------------------------------------


def brute_force_lcp(M: np.ndarray, q: np.ndarray, tol: float = 1e-9) -> list[np.ndarray]:
    """All solutions of LCP(M, q) found by trying every complementary basis.

    The slow, obvious reference: for each subset S of indices, set z_i = 0 outside S and
    w_i = 0 inside S, solve M_SS z_S = -q_S, and keep the candidate if z >= 0 and w >= 0.
    """
    n = len(q)
    scale = 1.0 + float(np.abs(q).max())
    solutions: list[np.ndarray] = []
    for mask in itertools.product([False, True], repeat=n):
        S = np.flatnonzero(mask)
        z = np.zeros(n)
        if S.size:
            sub = M[np.ix_(S, S)]
            if abs(np.linalg.det(sub)) < 1e-14:
                continue
            z[S] = np.linalg.solve(sub, -q[S])
        w = M @ z + q
        if np.all(z >= -tol * scale) and np.all(w >= -tol * scale):
            solutions.append(z)
    return solutions


def principal_minors_positive(M: np.ndarray) -> bool:
    """True if every principal minor of M is positive (the definition of a P-matrix)."""
    n = M.shape[0]
    for k in range(1, n + 1):
        for idx in itertools.combinations(range(n), k):
            if np.linalg.det(M[np.ix_(idx, idx)]) <= 0.0:
                return False
    return True


def assert_solves_lcp(M: np.ndarray, q: np.ndarray, z: np.ndarray) -> None:
    """Assert z is a solution of LCP(M, q) to rounding accuracy."""
    w = M @ z + q
    assert z.shape == q.shape
    assert np.all(z >= -1e-10), z
    assert np.all(w >= -1e-10 * (1.0 + np.abs(q).max())), w
    scale = 1.0 + np.linalg.norm(z) * (np.abs(M).max() * np.linalg.norm(z) + np.abs(q).max())
    assert abs(z @ w) <= 1e-9 * scale, (z, w)
    # The sum can hide cancelling terms; complementarity must hold componentwise too.
    assert np.all(np.abs(z * w) <= 1e-9 * scale), (z, w)


def random_pd(rng: np.random.Generator, n: int) -> np.ndarray:
    """Symmetric positive-definite matrix A A^T + eps I."""
    A = rng.normal(size=(n, n))
    return A @ A.T + 0.1 * np.eye(n)


def random_p_matrix(rng: np.random.Generator, n: int, kind: int) -> np.ndarray:
    """A P-matrix that is in general neither symmetric nor positive definite.

    kind 0: positive-diagonal scalings D1 (S + K) D2 of a PD matrix S plus a skew part K
            (scaling by positive diagonals multiplies every principal minor by a positive
            number, so the P property survives while positive definiteness does not).
    kind 1: a permuted triangular matrix with positive diagonal and large off-diagonal
            entries (every principal minor is a product of diagonal entries).
    """
    if kind == 0:
        K = rng.normal(size=(n, n))
        K = K - K.T
        D1 = np.diag(rng.uniform(0.1, 10.0, size=n))
        D2 = np.diag(rng.uniform(0.1, 10.0, size=n))
        return D1 @ (random_pd(rng, n) + K) @ D2
    T = np.triu(rng.normal(scale=5.0, size=(n, n)), k=1) + np.diag(rng.uniform(0.5, 3.0, size=n))
    perm = rng.permutation(n)
    return T[np.ix_(perm, perm)]


def two_stop_w(G_dt: float, c1: float, c2: float, lam: np.ndarray) -> np.ndarray:
    """Post-impulse gaps w = M L + q of the two-stop LCP."""
    return two_stop_matrix(G_dt) @ lam + np.array([c1, c2])


def check_two_stop_agreement(G_dt: float, c1: float, c2: float) -> None:
    """Lemke and the closed form give the same post-impulse gaps and net impulse."""
    closed = np.array(two_stop_closed_form(G_dt, c1, c2))
    M = two_stop_matrix(G_dt)
    q = np.array([c1, c2])
    z = lemke(M, q)
    scale = max(1.0, abs(c1), abs(c2))

    # Both must be genuine solutions of the same LCP ...
    assert_solves_lcp(M, q, z)
    assert_solves_lcp(M, q, closed)
    # ... the closed form puts impulse on at most one stop ...
    assert closed.min() == 0.0
    # ... and since M is only semi-definite, z may differ, but w and L1 - L2 may not.
    w_lemke = M @ z + q
    w_closed = M @ closed + q
    np.testing.assert_allclose(w_lemke, w_closed, rtol=0.0, atol=1e-9 * scale)
    np.testing.assert_allclose(
        z[0] - z[1], closed[0] - closed[1], rtol=1e-9, atol=1e-9 * scale / G_dt
    )


# ---------------------------------------------------------------------------------------------
# Lemke on general LCPs
# ---------------------------------------------------------------------------------------------


def test_lemke_textbook_example() -> None:
    M = np.array([[2.0, 1.0], [1.0, 2.0]])
    q = np.array([-5.0, -6.0])
    z = lemke(M, q)
    np.testing.assert_allclose(z, [4.0 / 3.0, 7.0 / 3.0], rtol=1e-12)
    assert_solves_lcp(M, q, z)


def test_lemke_nonnegative_q_returns_zeros() -> None:
    M = np.array([[-1.0, 5.0], [2.0, -3.0]])  # any M: q >= 0 makes z = 0 a solution
    z = lemke(M, np.array([0.0, 2.0]))
    assert z.dtype == np.float64
    np.testing.assert_array_equal(z, [0.0, 0.0])


def test_lemke_does_not_modify_inputs() -> None:
    M = np.array([[2.0, 1.0], [1.0, 2.0]])
    q = np.array([-5.0, -6.0])
    M0, q0 = M.copy(), q.copy()
    lemke(M, q)
    np.testing.assert_array_equal(M, M0)
    np.testing.assert_array_equal(q, q0)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6])
def test_lemke_positive_definite_matches_brute_force(n: int) -> None:
    rng = np.random.default_rng(1000 + n)
    for _ in range(40):
        M = random_pd(rng, n)
        q = rng.normal(size=n) * rng.choice([0.01, 1.0, 100.0])
        z = lemke(M, q)
        assert_solves_lcp(M, q, z)
        # PD => P-matrix => the solution is unique, so the brute force must find exactly it.
        reference = brute_force_lcp(M, q)
        assert reference, "brute force found no solution of a PD LCP"
        for ref in reference:
            np.testing.assert_allclose(z, ref, rtol=1e-8, atol=1e-9 * (1 + np.abs(q).max()))


@pytest.mark.parametrize("kind", [0, 1])
@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_lemke_p_matrix_matches_brute_force(n: int, kind: int) -> None:
    rng = np.random.default_rng(2000 + 10 * n + kind)
    saw_indefinite = False
    for _ in range(25):
        M = random_p_matrix(rng, n, kind)
        assert principal_minors_positive(M)  # the generator must really produce P-matrices
        saw_indefinite |= bool(np.linalg.eigvalsh(M + M.T).min() < 0.0)
        q = rng.normal(size=n)
        z = lemke(M, q)
        assert_solves_lcp(M, q, z)
        reference = brute_force_lcp(M, q)
        assert reference
        for ref in reference:
            np.testing.assert_allclose(z, ref, rtol=1e-7, atol=1e-8)
    # Otherwise this test would only repeat the PD one.
    assert saw_indefinite


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_lemke_degenerate_problems_do_not_cycle(n: int) -> None:
    """Integer data with repeated and zero entries in q produce exact ratio ties."""
    rng = np.random.default_rng(3000 + n)
    for _ in range(40):
        A = rng.integers(-2, 3, size=(n, n)).astype(float)
        M = A @ A.T + np.eye(n)
        q = rng.choice([-2.0, -1.0, 0.0, 1.0], size=n)
        z = lemke(M, q, max_pivots=200)
        assert_solves_lcp(M, q, z)
        for ref in brute_force_lcp(M, q):
            np.testing.assert_allclose(z, ref, atol=1e-9)


def test_lemke_all_equal_negative_q() -> None:
    """Every row ties in the initial ratio test."""
    M = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    q = -np.ones(3)
    np.testing.assert_allclose(lemke(M, q), np.ones(3), rtol=1e-12)


def test_lemke_feasible_copositive_plus() -> None:
    """Singular PSD (+ skew) matrices are copositive-plus: feasible LCPs must be solved."""
    rng = np.random.default_rng(4)
    for _ in range(60):
        n = int(rng.integers(2, 7))
        A = rng.normal(size=(n, max(1, n - 2)))  # rank-deficient, so M is only semi-definite
        K = rng.normal(size=(n, n))
        M = A @ A.T + (K - K.T)
        x = np.maximum(rng.normal(size=n), 0.0)
        q = -M @ x + np.maximum(rng.normal(size=n), 0.0)  # x is feasible, so a solution exists
        z = lemke(M, q)
        assert_solves_lcp(M, q, z)


# ---------------------------------------------------------------------------------------------
# The two-stop problem
# ---------------------------------------------------------------------------------------------


def test_two_stop_matrix() -> None:
    np.testing.assert_array_equal(two_stop_matrix(2.5), [[2.5, -2.5], [-2.5, 2.5]])


@pytest.mark.parametrize(
    ("c1", "c2", "expected"),
    [
        pytest.param(0.3, 0.7, (0.0, 0.0), id="free"),
        pytest.param(-0.2, 0.5, (0.1, 0.0), id="stop1-active"),
        pytest.param(0.5, -0.2, (0.0, 0.1), id="stop2-active"),
        pytest.param(0.0, 0.4, (0.0, 0.0), id="grazing-stop1"),
        pytest.param(0.4, 0.0, (0.0, 0.0), id="grazing-stop2"),
        pytest.param(-0.3, 0.3, (0.15, 0.0), id="pinned-pushing-stop1"),
        pytest.param(0.3, -0.3, (0.0, 0.15), id="pinned-pushing-stop2"),
        pytest.param(0.0, 0.0, (0.0, 0.0), id="pinned-at-rest"),
    ],
)
def test_two_stop_contact_states(c1: float, c2: float, expected: tuple[float, float]) -> None:
    G_dt = 2.0
    lam = two_stop_closed_form(G_dt, c1, c2)
    assert isinstance(lam[0], float)
    assert isinstance(lam[1], float)
    np.testing.assert_allclose(lam, expected, rtol=1e-14, atol=0.0)
    # The active stop's gap is closed exactly and the other ends at c1 + c2 (the tip moved
    # across the whole clearance); with no contact both keep their predicted values.
    w = two_stop_w(G_dt, c1, c2, np.array(lam))
    np.testing.assert_allclose(w, [max(c1, 0.0) + min(c2, 0.0), max(c2, 0.0) + min(c1, 0.0)])
    check_two_stop_agreement(G_dt, c1, c2)


def test_two_stop_agrees_with_lemke_random() -> None:
    rng = np.random.default_rng(5)
    states = {"free": 0, "stop1": 0, "stop2": 0, "pinned": 0}
    for i in range(400):
        G_dt = float(10.0 ** rng.uniform(-4, 4))
        c1 = float(rng.normal() * 10.0 ** rng.uniform(-3, 3))
        if i % 4 == 0:
            c2 = -c1  # both clearances zero: the pinned tip
            states["pinned"] += 1
        else:
            c2 = float(-c1 + abs(rng.normal()) * 10.0 ** rng.uniform(-3, 3))
            if c1 < 0:
                states["stop1"] += 1
            elif c2 < 0:
                states["stop2"] += 1
            else:
                states["free"] += 1
        check_two_stop_agreement(G_dt, c1, c2)
    # The sampling must actually visit every contact state.
    assert min(states.values()) >= 20, states


gaps = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_subnormal=False)


@settings(max_examples=300, deadline=None)
@given(
    G_dt=st.floats(min_value=1e-4, max_value=1e4),
    c1=gaps,
    slack=st.one_of(st.just(0.0), st.floats(min_value=0.0, max_value=1e3, allow_subnormal=False)),
    swap=st.booleans(),
)
def test_two_stop_agrees_with_lemke_property(
    G_dt: float, c1: float, slack: float, swap: bool
) -> None:
    # c1 + c2 = slack >= 0 by construction (and fl(slack - c1) + c1 >= 0 in floating point).
    c2 = slack - c1
    if swap:
        c1, c2 = c2, c1
    check_two_stop_agreement(G_dt, c1, c2)


def test_two_stop_tolerates_rounding_in_sum() -> None:
    # g1 - x and g2 + x with g1 = g2 = 0 can sum to a rounding-level negative number.
    lam = two_stop_closed_form(1.0, -0.3, 0.3 - 1e-17)
    np.testing.assert_allclose(lam, (0.3, 0.0))


# ---------------------------------------------------------------------------------------------
# Error paths
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("G_dt", [0.0, -1.0, np.nan, np.inf])
def test_two_stop_rejects_bad_G_dt(G_dt: float) -> None:
    with pytest.raises(ValueError, match="G_dt"):
        two_stop_closed_form(G_dt, 0.1, 0.2)
    with pytest.raises(ValueError, match="G_dt"):
        two_stop_matrix(G_dt)


@pytest.mark.parametrize(("c1", "c2", "name"), [(np.nan, 0.1, "c1"), (0.1, np.inf, "c2")])
def test_two_stop_rejects_non_finite_gaps(c1: float, c2: float, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        two_stop_closed_form(1.0, c1, c2)


@pytest.mark.parametrize(("c1", "c2"), [(-0.2, 0.1), (0.1, -0.2), (-1e-3, -1e-3)])
def test_two_stop_rejects_negative_clearance(c1: float, c2: float) -> None:
    with pytest.raises(ValueError, match=r"c1 \+ c2") as info:
        two_stop_closed_form(1.0, c1, c2)
    assert repr(c1) in str(info.value)


@pytest.mark.parametrize(
    ("M", "q"),
    [
        pytest.param([[-1.0]], [-1.0], id="negative-1x1"),
        pytest.param([[0.0]], [-1.0], id="zero-1x1"),
        # w1 = z1 + z2 - 1 >= 0 and w2 = -z1 - z2 - 1 >= 0 cannot both hold.
        pytest.param([[1.0, 1.0], [-1.0, -1.0]], [-1.0, -1.0], id="infeasible-psd-plus-skew"),
    ],
)
def test_lemke_ray_termination(M: list[list[float]], q: list[float]) -> None:
    M_arr, q_arr = np.array(M), np.array(q)
    assert not brute_force_lcp(M_arr, q_arr)  # really no solution
    with pytest.raises(LCPError, match="ray"):
        lemke(M_arr, q_arr)


def test_lemke_pivot_budget() -> None:
    M = np.array([[2.0, 1.0], [1.0, 2.0]])
    q = np.array([-5.0, -6.0])  # needs more than one pivot
    with pytest.raises(LCPError, match="budget"):
        lemke(M, q, max_pivots=1)
    np.testing.assert_allclose(lemke(M, q), np.linalg.solve(M, -q), rtol=1e-12)


def test_ray_leaves_a_zero_solution() -> None:
    ws = lemke_workspace(2)
    status = lemke_nb(np.array([[1.0, 1.0], [-1.0, -1.0]]), np.array([-1.0, -1.0]), *ws, 100)
    assert status == LEMKE_RAY
    np.testing.assert_array_equal(ws[-1], 0.0)


def test_lemke_on_the_two_stop_problem_matches_the_closed_form() -> None:
    rng = np.random.default_rng(8)
    for i in range(300):
        G_dt = float(10.0 ** rng.uniform(-4, 4))
        c1 = float(rng.normal() * 10.0 ** rng.uniform(-3, 3))
        c2 = -c1 if i % 4 == 0 else float(-c1 + abs(rng.normal()) * 10.0 ** rng.uniform(-3, 3))
        M = two_stop_matrix(G_dt)
        q = np.array([c1, c2])
        z = lemke(M, q)
        closed = np.array(two_stop_closed_form(G_dt, c1, c2))
        scale = max(1.0, abs(c1), abs(c2))
        np.testing.assert_allclose(M @ z + q, M @ closed + q, rtol=0.0, atol=1e-9 * scale)


def test_euler_with_compiled_lemke_matches_closed_form() -> None:
    """``SolverSettings(method="euler", lcp="lemke")``: Lemke at every step, same trajectory."""
    from worker.model import CellParams
    from worker.simulate import SolverSettings, simulate_point

    for coupling, gaps in (("paper", 0.1), ("full", 0.1), ("paper", 0.0)):
        p = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.3, g1=gaps, g2=gaps,
                       coupling=coupling)  # fmt: skip
        kw = dict(method="euler", steps_per_period=1024, max_periods=40, window=5,
                  early_stop=False)  # fmt: skip
        a = simulate_point(p, SolverSettings(**kw))
        b = simulate_point(p, SolverSettings(**kw, lcp="lemke"))
        assert not b.failed
        assert b.contact_steps == a.contact_steps > 0
        np.testing.assert_allclose(b.transmittance_db, a.transmittance_db, rtol=0, atol=1e-9)


def test_lcp_setting_is_validated() -> None:
    from worker.simulate import SolverSettings

    assert SolverSettings().lcp == "closed"
    with pytest.raises(ValueError, match="lcp must be one of"):
        SolverSettings(method="euler", lcp="pgs")
