"""Linear complementarity problems for the contact step (docs/model.md §5).

The paper's time-stepping scheme computes the contact impulses of each step from an LCP:

    find z >= 0  such that  w = M z + q >= 0  and  z . w = 0.

For the unit cell there are exactly two stops and the LCP has the special form
``M = G dt [[1, -1], [-1, 1]]``, ``q = [c1, c2]`` with ``c1 + c2 >= 0``, which has a closed form
(:func:`two_stop_closed_form`) that the simulator uses in its hot loop. Lemke's complementary
pivoting (:func:`lemke_nb`, compiled) is the general solver the paper names: ``euler`` with
``lcp="lemke"`` runs it at every step as published, and it is what more contacts will need.
Its tests compare it with a brute-force enumeration of complementary bases.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.checks import finite, positive

__all__ = [
    "LEMKE_BUDGET",
    "LEMKE_OK",
    "LEMKE_RAY",
    "TWO_STOP_RTOL",
    "lemke_nb",
    "lemke_workspace",
    "two_stop_closed_form",
    "two_stop_impulses",
    "two_stop_matrix",
]

#: Relative tolerance on ``c1 + c2 >= 0`` in :func:`two_stop_closed_form`. The two predicted
#: gaps are computed as ``g1 - x`` and ``g2 + x`` from the same tip displacement ``x``, so their
#: sum equals ``g1 + g2 >= 0`` only up to rounding of order ``eps * |x|``; a pinned tip
#: (``g1 = g2 = 0``) would otherwise be rejected at random.
TWO_STOP_RTOL: float = 1e-12

# Relative tolerance for deciding that a pivot-column entry is positive, i.e. that a basic
# variable really blocks the entering one. Entries below it are rounding noise from earlier
# pivots, and pivoting on them would blow up the tableau.
_PIVOT_RTOL: float = 1e-12

# Relative tolerance for calling two ratios equal in the lexicographic ratio test. Exact ties are
# what lexicographic ordering resolves; after floating-point pivots, "exact" ties differ in the
# last few bits, so they have to be recognised as ties rather than broken by noise.
_TIE_RTOL: float = 1e-11


def two_stop_matrix(G_dt: float) -> np.ndarray:
    """LCP matrix of the two-stop contact problem, ``G dt [[1, -1], [-1, 1]]`` (docs/model.md §5).

    Parameters
    ----------
    G_dt : float
        The product ``G * dt`` of the tip's inverse effective mass ``G = W^T M^-1 X`` and the
        time step; must be finite and positive.

    Returns
    -------
    numpy.ndarray
        The 2x2 float64 matrix. It is symmetric positive semi-definite (singular), which is
        why the LCP's ``z`` is not unique when both stops are closed.

    Raises
    ------
    ValueError
        If ``G_dt`` is not a finite positive number.
    """
    g = positive("G_dt", G_dt)
    return g * np.array([[1.0, -1.0], [-1.0, 1.0]])


def two_stop_closed_form(G_dt: float, c1: float, c2: float) -> tuple[float, float]:
    """Closed-form impulses of the two-stop LCP of docs/model.md §5.

    Solves ``w = G dt [[1, -1], [-1, 1]] [L1, L2] + [c1, c2]``, ``L >= 0``, ``w >= 0``,
    ``L . w = 0``, where ``c1``, ``c2`` are the predicted gaps at the two stops. Because the
    stops face each other, ``c1 + c2 = g1 + g2 >= 0``, so at most one predicted gap is
    negative and the impulse at that stop alone closes it:
    ``L1 = max(0, -c1) / (G dt)``, ``L2 = max(0, -c2) / (G dt)``.

    If ``c1 + c2 == 0`` (both clearances zero, a pinned tip) and one ``c`` is negative, the
    formula closes that gap and the other post-impulse gap ``w = c1 + c2`` is zero as well, so
    the result is still a solution; it is the one with the smaller total impulse.

    Parameters
    ----------
    G_dt : float
        ``G * dt``; must be finite and positive.
    c1 : float
        Predicted gap at stop 1 (negative means penetration).
    c2 : float
        Predicted gap at stop 2.

    Returns
    -------
    tuple of float
        ``(L1, L2)``, the non-negative impulses at stops 1 and 2; at most one is nonzero.

    Raises
    ------
    ValueError
        If ``G_dt`` is not finite and positive, ``c1`` or ``c2`` is not finite, or
        ``c1 + c2 < 0`` beyond rounding (relative tolerance :data:`TWO_STOP_RTOL`), in which
        case both stops would be penetrated and the problem is infeasible.
    """
    g = positive("G_dt", G_dt)
    a = finite("c1", c1)
    b = finite("c2", c2)
    total = a + b
    if total < -TWO_STOP_RTOL * max(1.0, abs(a), abs(b)):
        raise ValueError(
            f"c1 + c2 must be >= 0 (the stops' clearances cannot sum to a negative value), got "
            f"c1={a!r}, c2={b!r}, c1 + c2={total!r}"
        )
    return two_stop_impulses(g, a, b)


@njit(cache=True, nogil=True)
def two_stop_impulses(g_dt, c1, c2):
    """The closed form of :func:`two_stop_closed_form` without validation, for the kernels."""
    return max(0.0, -c1) / g_dt, max(0.0, -c2) / g_dt


# ---------------------------------------------------------------------------------------------
# Compiled Lemke (numba), for use inside the time loop
# ---------------------------------------------------------------------------------------------

#: Status codes of :func:`lemke_nb`.
LEMKE_OK = 0
LEMKE_RAY = 1
LEMKE_BUDGET = 2


def lemke_workspace(n: int) -> tuple[np.ndarray, ...]:
    """Preallocated arrays for :func:`lemke_nb` on an ``n``-square LCP.

    Returns ``(tableau, basis, cand, Bm, xb, z)``, to be passed after ``M, q`` (and ``z`` read
    back as the solution). Allocated once, so the solver allocates nothing per call.
    """
    return (
        np.zeros((n, 2 * n + 2)),
        np.zeros(n, dtype=np.int64),
        np.zeros(n, dtype=np.int64),
        np.zeros((n, n)),
        np.zeros(n),
        np.zeros(n),
    )


@njit(cache=True, nogil=True)
def _lex_pick_nb(T, n, cand, m, col, divide):
    """Row among ``cand[:m]`` with the lexicographically smallest [rhs, B⁻¹ row] (÷ pivot column).

    Same rule as :func:`_lexicographic_argmin`: near-equal entries (relative ``_TIE_RTOL``) tie.
    ``cand`` is reordered in place.
    """
    rhs = 2 * n + 1
    for k in range(n + 1):
        src = rhs if k == 0 else k - 1
        best = np.inf
        big = 0.0
        for a in range(m):
            r = cand[a]
            v = T[r, src] / T[r, col] if divide else T[r, src]
            best = min(best, v)
            big = max(big, abs(v))
        lim = best + _TIE_RTOL * max(1.0, big)
        keep = 0
        for a in range(m):
            r = cand[a]
            v = T[r, src] / T[r, col] if divide else T[r, src]
            if v <= lim:
                cand[keep] = r
                keep += 1
        m = keep
        if m == 1:
            break
    return cand[0]


@njit(cache=True, nogil=True)
def _pivot_nb(T, basis, row, col):
    p = T[row, col]
    ncol = T.shape[1]
    for j in range(ncol):
        T[row, j] /= p
    for r in range(T.shape[0]):
        if r == row:
            continue
        f = T[r, col]
        if f != 0.0:
            for j in range(ncol):
                T[r, j] -= f * T[row, j]
        T[r, col] = 0.0
    T[row, col] = 1.0
    basis[row] = col


@njit(cache=True, nogil=True)
def lemke_nb(M, q, T, basis, cand, Bm, xb, z, max_pivots):
    """Lemke's algorithm for LCP(M, q): find ``z >= 0`` with ``w = M z + q >= 0``, ``z·w = 0``.

    The problem is augmented with an artificial variable ``z0`` and the covering vector of ones;
    from the almost-complementary basis where ``z0`` enters at ``-min(q)``, the complement of
    the variable that just left enters next, until ``z0`` leaves (a solution) or the entering
    column has no blocking row (ray termination). Ratio-test ties are broken
    lexicographically by the rows of the basis inverse (no cycling on degenerate problems); the
    artificial variable is preferred when tied. The final basis is re-solved with the original
    data (partial pivoting) to remove the tableau's rounding.

    No input validation and no allocation: ``M`` (n × n) and ``q`` (n) must be finite, the
    workspace comes from :func:`lemke_workspace`. The solution is written to ``z``.

    Returns
    -------
    int
        :data:`LEMKE_OK`, :data:`LEMKE_RAY` (ray termination) or :data:`LEMKE_BUDGET`
        (``max_pivots`` reached); ``z`` is zero unless the status is ``LEMKE_OK``.
    """
    n = q.shape[0]
    for i in range(n):
        z[i] = 0.0
    feasible = True
    for i in range(n):
        if q[i] < 0.0:
            feasible = False
            break
    if feasible:
        return LEMKE_OK
    z0 = 2 * n
    rhs = 2 * n + 1
    big = 1.0
    for i in range(n):
        for j in range(n):
            T[i, j] = 1.0 if i == j else 0.0
            T[i, n + j] = -M[i, j]
            big = max(big, abs(M[i, j]))
        T[i, z0] = -1.0
        T[i, rhs] = q[i]
        basis[i] = i
    pivot_tol = _PIVOT_RTOL * big
    for i in range(n):
        cand[i] = i
    row = _lex_pick_nb(T, n, cand, n, z0, False)
    leaving = basis[row]
    _pivot_nb(T, basis, row, z0)
    pivots = 1
    while True:
        entering = leaving + n if leaving < n else leaving - n
        m = 0
        min_ratio = np.inf
        max_abs = 0.0
        z0_row = -1
        for r in range(n):
            if T[r, entering] > pivot_tol:
                cand[m] = r
                m += 1
                ratio = T[r, rhs] / T[r, entering]
                min_ratio = min(min_ratio, ratio)
                max_abs = max(max_abs, abs(ratio))
                if basis[r] == z0 and z0_row < 0:
                    z0_row = r
        if m == 0:
            return LEMKE_RAY
        if pivots >= max_pivots:
            return LEMKE_BUDGET
        tie = _TIE_RTOL * max(1.0, max_abs)
        if z0_row >= 0 and T[z0_row, rhs] / T[z0_row, entering] <= min_ratio + tie:
            row = z0_row
        else:
            row = _lex_pick_nb(T, n, cand, m, entering, True)
        leaving = basis[row]
        _pivot_nb(T, basis, row, entering)
        pivots += 1
        if leaving == z0:
            break
    # Refine: re-solve the final basis with the original data (Gaussian elimination with
    # partial pivoting on the workspace; kept as read off the tableau if singular).
    for r in range(n):
        xb[r] = q[r]
        var = basis[r]
        for i in range(n):
            if var < n:
                Bm[i, r] = 1.0 if i == var else 0.0
            else:
                Bm[i, r] = -M[i, var - n]
    ok = True
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(Bm[i, k]) > abs(Bm[p, k]):
                p = i
        if abs(Bm[p, k]) < 1e-300:
            ok = False
            break
        if p != k:
            for j in range(n):
                tmp = Bm[k, j]
                Bm[k, j] = Bm[p, j]
                Bm[p, j] = tmp
            tmp = xb[k]
            xb[k] = xb[p]
            xb[p] = tmp
        for i in range(k + 1, n):
            f = Bm[i, k] / Bm[k, k]
            if f != 0.0:
                for j in range(k, n):
                    Bm[i, j] -= f * Bm[k, j]
                xb[i] -= f * xb[k]
    if ok:
        for k in range(n - 1, -1, -1):
            acc = xb[k]
            for j in range(k + 1, n):
                acc -= Bm[k, j] * xb[j]
            xb[k] = acc / Bm[k, k]
        for r in range(n):
            if not math.isfinite(xb[r]):
                ok = False
    for r in range(n):
        var = basis[r]
        if var >= n and var < z0:
            v = xb[r] if ok else T[r, rhs]
            z[var - n] = max(v, 0.0)
    return LEMKE_OK
