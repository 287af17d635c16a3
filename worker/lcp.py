"""Linear complementarity problems for the contact step (MODEL.md §5).

The paper's time-stepping scheme computes the contact impulses of each step from an LCP:

    find z >= 0  such that  w = M z + q >= 0  and  z . w = 0.

For the unit cell there are exactly two stops and the LCP has the special form
``M = G dt [[1, -1], [-1, 1]]``, ``q = [c1, c2]`` with ``c1 + c2 >= 0``, which has a closed form
(:func:`two_stop_closed_form`) that the simulator uses in its hot loop. The general solver
(:func:`lemke`) exists as the independent reference the paper names, so that the closed form can
be checked against it and so that benchmarks can compare the two.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "LCPError",
    "LEMKE_BUDGET",
    "LEMKE_OK",
    "LEMKE_RAY",
    "TWO_STOP_RTOL",
    "lemke",
    "lemke_nb",
    "lemke_workspace",
    "two_stop_closed_form",
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


class LCPError(RuntimeError):
    """Lemke's algorithm stopped without finding a solution.

    Raised on ray termination (the problem is infeasible, or the matrix is outside the class
    for which Lemke's method is guaranteed to work) and when the pivot budget runs out.
    """


def _as_float_array(value: object, name: str, ndim: int) -> np.ndarray:
    """Convert ``value`` to a finite float array of the given rank, or raise ValueError.

    Parameters
    ----------
    value : array_like
        The user's input.
    name : str
        Argument name, used in the error message.
    ndim : int
        Required number of dimensions.

    Returns
    -------
    numpy.ndarray
        A new float64 array (a copy, so the caller's data is never modified by pivoting).

    Raises
    ------
    ValueError
        If ``value`` is not numeric, has the wrong rank, or contains NaN or infinity.
    """
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} must be a real numeric array, got {type(value).__name__}: {value!r}"
        ) from exc
    if arr.ndim != ndim:
        kind = "a 1-D vector" if ndim == 1 else "a 2-D square matrix"
        raise ValueError(f"{name} must be {kind}, got an array of shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must contain only finite values (no NaN or inf), got {arr!r}")
    return arr


def _validate_positive(value: float, name: str) -> float:
    """Return ``value`` as a float if it is finite and strictly positive, else raise ValueError.

    Parameters
    ----------
    value : float
        The value to check.
    name : str
        Argument name, used in the error message.

    Returns
    -------
    float
        ``value`` converted to float.

    Raises
    ------
    ValueError
        If ``value`` is not a real number, not finite, or not strictly positive.
    """
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real number > 0, got {value!r}") from exc
    if not np.isfinite(x) or x <= 0.0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return x


def _validate_finite(value: float, name: str) -> float:
    """Return ``value`` as a float if it is finite, else raise ValueError.

    Parameters
    ----------
    value : float
        The value to check.
    name : str
        Argument name, used in the error message.

    Returns
    -------
    float
        ``value`` converted to float.

    Raises
    ------
    ValueError
        If ``value`` is not a finite real number.
    """
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a finite real number, got {value!r}") from exc
    if not np.isfinite(x):
        raise ValueError(f"{name} must be a finite real number, got {value!r}")
    return x


def _lexicographic_argmin(rows: np.ndarray) -> int:
    """Index of the lexicographically smallest row, treating near-equal entries as ties.

    Parameters
    ----------
    rows : numpy.ndarray
        2-D array, one candidate per row. Column 0 is the ordinary minimum ratio; the following
        columns are the tie-breakers.

    Returns
    -------
    int
        Row index of the lexicographic minimum. If rounding leaves several rows tied on every
        column (impossible in exact arithmetic, since the tie-break columns come from a
        nonsingular matrix), the first of them is returned.
    """
    candidates = np.arange(rows.shape[0])
    for col in range(rows.shape[1]):
        values = rows[candidates, col]
        best = values.min()
        # Ties are judged relative to the size of the column's entries, because ratios of
        # different magnitude carry rounding errors of different absolute size.
        scale = max(1.0, float(np.abs(values).max()))
        candidates = candidates[values <= best + _TIE_RTOL * scale]
        if candidates.size == 1:
            break
    return int(candidates[0])


def lemke(M: np.ndarray, q: np.ndarray, max_pivots: int | None = None) -> np.ndarray:
    """Solve the linear complementarity problem LCP(M, q) by Lemke's complementary pivoting.

    Finds ``z >= 0`` with ``w = M z + q >= 0`` and ``z . w = 0``.

    The method augments the problem with an artificial variable ``z0`` and the covering vector
    of ones, ``w = M z + q + e z0``, starts from the almost-complementary basis obtained by
    letting ``z0`` enter at ``-min(q)``, and then repeatedly lets the complement of the
    variable that just left the basis enter, until ``z0`` leaves (a solution) or the entering
    column has no blocking row (ray termination). The minimum-ratio test breaks ties
    lexicographically with the rows of the current basis inverse, which is the standard
    perturbation argument that rules out cycling on degenerate problems. When the artificial
    variable is among the tied rows it is chosen, since that finishes the algorithm at once.

    Parameters
    ----------
    M : numpy.ndarray
        Square matrix of shape ``(n, n)`` with finite entries.
    q : numpy.ndarray
        Vector of shape ``(n,)`` with finite entries.
    max_pivots : int or None, optional
        Maximum number of pivots, counting the initial one. ``None`` (the default) allows
        ``max(1000, 50 * n)``, far more than the handful of pivots practical problems need,
        yet still a guard against runaway loops.

    Returns
    -------
    numpy.ndarray
        The solution ``z``, shape ``(n,)``, float64. Rounding-level negative components are
        clipped to zero.

    Raises
    ------
    ValueError
        If ``M`` is not square, ``q`` does not match it, either contains NaN or infinity, or
        ``max_pivots`` is not a positive integer.
    LCPError
        On ray termination (no solution found: for copositive-plus matrices, such as the
        positive semi-definite ones, this proves the LCP infeasible) or when the pivot budget
        is exhausted.

    Notes
    -----
    Lemke's method is guaranteed to terminate with a solution for P-matrices (every principal
    minor positive, which includes positive-definite matrices), and for copositive-plus
    matrices whenever the LCP is feasible. For other matrices a ray termination does not prove
    that no solution exists.

    Examples
    --------
    >>> import numpy as np
    >>> z = lemke(np.array([[2.0, 1.0], [1.0, 2.0]]), np.array([-5.0, -6.0]))
    >>> np.round(z, 12)
    array([1.33333333, 2.33333333])
    """
    M_arr = _as_float_array(M, "M", 2)
    if M_arr.shape[0] != M_arr.shape[1]:
        raise ValueError(f"M must be a square matrix, got shape {M_arr.shape}")
    n = M_arr.shape[0]
    q_arr = _as_float_array(q, "q", 1)
    if q_arr.shape != (n,):
        raise ValueError(
            f"q must have shape ({n},) to match M of shape {M_arr.shape}, got shape {q_arr.shape}"
        )
    if max_pivots is None:
        budget = max(1000, 50 * n)
    else:
        # bool is an int subclass; True as a pivot budget is surely a mistake.
        if isinstance(max_pivots, bool) or not isinstance(max_pivots, int | np.integer):
            raise ValueError(f"max_pivots must be a positive integer or None, got {max_pivots!r}")
        if max_pivots < 1:
            raise ValueError(f"max_pivots must be a positive integer or None, got {max_pivots}")
        budget = int(max_pivots)

    # z = 0 gives w = q; if that is already feasible it is complementary, and no pivoting is
    # needed. This is also the common "no contact" case in the time stepper.
    if np.all(q_arr >= 0.0):
        return np.zeros(n)

    # Variable numbering: w_i -> i, z_i -> n + i, the artificial z0 -> 2n.
    # Tableau columns: [ w (identity) | z (-M) | z0 (-e) | rhs q ] for  I w - M z - e z0 = q.
    # Keeping the identity block means its current contents are the basis inverse, which is
    # exactly what the lexicographic tie-break needs.
    z0 = 2 * n
    rhs = 2 * n + 1
    tableau = np.zeros((n, 2 * n + 2))
    tableau[:, :n] = np.eye(n)
    tableau[:, n : 2 * n] = -M_arr
    tableau[:, z0] = -1.0
    tableau[:, rhs] = q_arr
    basis = np.arange(n)  # basis[row] = variable that is basic in that row

    # Pivot entries are compared with the size of the data, so that the test does not depend
    # on the units of M.
    pivot_tol = _PIVOT_RTOL * max(1.0, float(np.abs(M_arr).max()))

    def pivot(row: int, col: int) -> None:
        """Gauss-Jordan pivot of the tableau on (row, col); updates the basis in place."""
        tableau[row] /= tableau[row, col]
        column = tableau[:, col].copy()
        column[row] = 0.0
        tableau[:] -= np.outer(column, tableau[row])
        # Force the pivot column to an exact unit vector; the elimination leaves rounding
        # residue there that would otherwise leak into later ratio tests.
        tableau[:, col] = 0.0
        tableau[row, col] = 1.0
        basis[row] = col

    # Initial pivot: z0 enters at the level that makes every w_i >= 0, i.e. -min(q). The column
    # of z0 is -e, so every row "blocks" with ratio q_i / -1; the lexicographic minimum of
    # [q_i, (B^-1)_i] over the rows picks the most negative q_i and breaks ties consistently
    # with the perturbed problem q + (eps, eps^2, ...).
    lex_rows = np.column_stack([tableau[:, rhs], tableau[:, :n]])
    row = _lexicographic_argmin(lex_rows)
    leaving = int(basis[row])
    pivot(row, z0)
    pivots = 1

    while True:
        # Complementary rule: the complement of the variable that just left enters.
        entering = leaving + n if leaving < n else leaving - n
        column = tableau[:, entering]
        blocking = np.flatnonzero(column > pivot_tol)
        if blocking.size == 0:
            raise LCPError(
                "Lemke's algorithm ended on a secondary ray after "
                f"{pivots} pivots: no solution was found (the LCP is infeasible, or M is "
                "not in a class, such as P-matrices or copositive-plus matrices, for which the "
                "method is guaranteed to succeed)"
            )
        if pivots >= budget:
            raise LCPError(
                f"Lemke's algorithm exhausted its pivot budget of {budget} pivots without "
                "reaching a solution; pass a larger max_pivots if the problem is large or "
                "badly degenerate"
            )

        ratios = tableau[blocking, rhs] / column[blocking]
        min_ratio = ratios.min()
        # If z0 can leave at the minimum ratio, let it: the next basis is complementary, i.e. a
        # solution, and there is nothing to gain from breaking the tie any other way.
        z0_rows = blocking[basis[blocking] == z0]
        tie = _TIE_RTOL * max(1.0, float(np.abs(ratios).max()))
        if z0_rows.size and tableau[z0_rows[0], rhs] / column[z0_rows[0]] <= min_ratio + tie:
            row = int(z0_rows[0])
        else:
            lex_rows = np.column_stack([tableau[blocking, rhs], tableau[blocking, :n]])
            lex_rows /= column[blocking, None]
            row = int(blocking[_lexicographic_argmin(lex_rows)])
        leaving = int(basis[row])
        pivot(row, entering)
        pivots += 1
        if leaving == z0:
            break

    # Read z off the final tableau, then refine it by re-solving the final basis with the
    # original data: many Gauss-Jordan pivots accumulate rounding, whereas one solve with the
    # original columns gives a result as accurate as the basis' conditioning allows.
    x_basic = tableau[:, rhs].copy()
    basis_matrix = np.zeros((n, n))
    for r, var in enumerate(basis):
        if var < n:
            basis_matrix[var, r] = 1.0
        else:
            basis_matrix[:, r] = -M_arr[:, var - n]
    try:
        refined = np.linalg.solve(basis_matrix, q_arr)
    except np.linalg.LinAlgError:
        refined = None
    if refined is not None and np.all(np.isfinite(refined)):
        x_basic = refined

    z = np.zeros(n)
    is_z = basis >= n
    z[basis[is_z] - n] = x_basic[is_z]
    # The basic values are >= 0 in exact arithmetic; what is left below zero is rounding.
    return np.maximum(z, 0.0)


def two_stop_matrix(G_dt: float) -> np.ndarray:
    """LCP matrix of the two-stop contact problem, ``G dt [[1, -1], [-1, 1]]`` (MODEL.md §5).

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
    g = _validate_positive(G_dt, "G_dt")
    return g * np.array([[1.0, -1.0], [-1.0, 1.0]])


def two_stop_closed_form(G_dt: float, c1: float, c2: float) -> tuple[float, float]:
    """Closed-form impulses of the two-stop LCP of MODEL.md §5.

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
    g = _validate_positive(G_dt, "G_dt")
    a = _validate_finite(c1, "c1")
    b = _validate_finite(c2, "c2")
    total = a + b
    if total < -TWO_STOP_RTOL * max(1.0, abs(a), abs(b)):
        raise ValueError(
            f"c1 + c2 must be >= 0 (the stops' clearances cannot sum to a negative value), got "
            f"c1={a!r}, c2={b!r}, c1 + c2={total!r}"
        )
    return max(0.0, -a) / g, max(0.0, -b) / g


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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def lemke_nb(M, q, T, basis, cand, Bm, xb, z, max_pivots):
    """Compiled Lemke: the algorithm of :func:`lemke` (same pivots, ties and refinement).

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
