"""The exact monodromy matrix of an event-solver orbit, from the orbit's own event log.

The p-period map's Jacobian at an orbit's start ``x0`` is a product along the orbit
(docs/solvers.md, "Floquet multiplier"):

* inside a regime, its exact propagator ``e^{At} = Re V diag(e^{λt}) V⁻¹`` over the time to the
  next event (the regime's modal form, ``regimes.py``);
* at an impact on stop k at time t*, the saltation matrix of the plastic impact
  ``S = R + (f⁺ − R f⁻) ∇hᵀ / (∇h · f⁻)``: ``R`` the impact map (the impulse along ``M⁻¹X`` that
  zeroes the tip's velocity, ``z⁺ = z⁻ − [0; M⁻¹X; 0]·(W q⁻)/G``), ``f⁻`` and ``f⁺`` the vector
  fields before (free) and after (stuck, or free when the tip leaves at once), ``h`` the stop's
  gap (``∇h · f⁻``: minus the speed of approach). When the tip sticks, ``y = Pin z`` restricts
  the perturbation to the constraint;
* at a release the contact force is zero, so the free and stuck fields agree there and the
  saltation matrix is the identity: ``z = Qout y``.

The orbit's own measuring run, with an event log, replaces the ``nx`` finite-difference side
runs (``nx`` = 12 for 5 modes), and the matrix is exact to round-off where the differences carried a
truncation error (forward differences with a relative step of 1e-7: up to 9.5e-3 in the largest
multiplier at Figure 5's orbits; central differences converge to this matrix).

An orbit that starts with the tip stuck on a stop (at τ = 0 the map is one-sided: no state
may move into the stop) gets the matrix at its first release instead, where the motion is free;
it has the same multipliers (``monodromy``'s ``from_stop``). Central differences along the
constraint at τ = 0 converge to its spectral radius.

The replay refuses (and the caller falls back on finite differences) where the p-period map has
no such Jacobian or this replay does not cover it: an orbit that starts leaving a stop or on a
stop it does not stay stuck on until a release, an impact without a speed of approach (grazing,
or the repeated impact of a tip that neither sticks nor leaves), an event log that does not
match the regimes, or a replay whose end state differs from the run's.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.numba_cache import on_disk
from worker.solvers.event.regimes import R_W, R_WD

__all__ = ["M_OK", "compile_monodromy", "monodromy"]

# what the replay returns: a matrix, or why there is none
M_OK = 0
M_STUCK_IMPACT = 1  # an impact logged while the tip was stuck
M_GRAZING = 2  # an impact without a speed of approach
M_RELEASE = 3  # a release from a stop the tip was not stuck on
M_END_REGIME = 4  # the replay ends in another regime than the run
M_END_STATE = 5  # the replay's end state differs from the run's
M_NOT_FINITE = 6  # the matrix is not finite
M_FROM_STOP = 7  # the orbit starts on a stop but not stuck there until a release

# An impact whose speed of approach is below this fraction of the velocities' size is taken as
# grazing: the saltation matrix divides by that speed.
MIN_APPROACH = 1e-9
# The replay's end state must equal the run's to this, relative to the state's size (they agree
# to ~1e-13: the same propagators, other summation orders).
END_TOL = 1e-8


@njit(cache=True, nogil=True)
def _propagator(lam, V, Vi, r, nk, nz, t, e, out):
    """out = Re V diag(e^{λt}) V⁻¹ (regime r, its nk kept modes, nz states)."""
    for k in range(nk):
        e[k] = np.exp(lam[r, k] * t)
    for i in range(nz):
        for j in range(nz):
            acc = 0.0
            for k in range(nk):
                acc += (V[r, i, k] * e[k] * Vi[r, k, j]).real
            out[i, j] = acc


@njit(cache=True, nogil=True)
def _field(lam, V, Vi, r, nk, nz, y, a, out):
    """out = A y, the regime's vector field, as Re V diag(λ) V⁻¹ y (a: scratch)."""
    for k in range(nk):
        acc = 0j
        for j in range(nz):
            acc += Vi[r, k, j] * y[j]
        a[k] = acc * lam[r, k]
    for i in range(nz):
        acc = 0.0
        for k in range(nk):
            acc += (V[r, i, k] * a[k]).real
        out[i] = acc


@njit(cache=True, nogil=True)
def _mat_vec(A, v, rows, cols, out):
    for i in range(rows):
        acc = 0.0
        for j in range(cols):
            acc += A[i, j] * v[j]
        out[i] = acc


@njit(cache=True, nogil=True)
def _mat_mat(A, B, n, m, q, out):
    """out[:n, :q] = A[:n, :m] B[:m, :q]."""
    for i in range(n):
        for j in range(q):
            acc = 0.0
            for k in range(m):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@njit(cache=True, nogil=True)
def _impact_map(R, MinvX, G, N, nzm, z):
    """z ← R z: the plastic impact's impulse along M⁻¹X that zeroes the tip's velocity W q
    (a state, or a vector field at the impact)."""
    v = 0.0
    for j in range(nzm):
        v += R[0, R_WD, j] * z[j]
    for j in range(N):
        z[N + j] -= MinvX[j] * v / G


@njit(cache=True, nogil=True)
def monodromy(ev, n_ev, x0, x_end, f_scale, T, p, reg_end, lam, V, Vi, nk, R, Pin, Qout, MinvX,
              G, g1, g2, N, from_stop, out):  # fmt: skip
    """Replay the ``n_ev`` logged events ``ev`` (rows τ, kind, stop, …) of a run of ``p``
    periods of length ``T`` from the free state ``x0`` at τ = 0, which ended at ``x_end`` in
    regime ``reg_end``: the p-period map's Jacobian into ``out`` (nx × nx). Returns ``M_OK`` or
    the code of why there is none (``M_*``).

    ``from_stop``: the orbit starts with the tip stuck on a stop (the run's first event is its
    impact at τ = 0, without a speed of approach), where the map at τ = 0 is one-sided. The
    section is then moved to the first release t_r: the Jacobian is that of the map from
    t_r to t_r + pT, where the motion is free and the map smooth. The two maps are the
    products of the same two pieces in the other order (``BA`` and ``AB``), so they have the
    same nonzero eigenvalues: the same Floquet multipliers."""
    nx = 2 * N
    nzm = nx + 2
    ny = nzm - 1
    z = np.zeros(nzm)
    y = np.zeros(ny)
    zt = np.zeros(nzm)
    fm = np.zeros(nzm)
    fp = np.zeros(nzm)
    yt = np.zeros(ny)
    g = np.zeros(nzm)
    a = np.zeros(nzm, dtype=np.complex128)
    e = np.zeros(nzm, dtype=np.complex128)
    P = np.zeros((nzm, nzm))
    J = np.zeros((nzm, nzm))  # d z / d z0 while free
    Jy = np.zeros((ny, nzm))  # d y / d z0 while stuck
    Jt = np.zeros((nzm, nzm))
    for i in range(nx):
        z[i] = x0[i]
    z[nx] = f_scale
    for i in range(nzm):
        J[i, i] = 1.0
    reg = 0
    t_prev = 0.0
    first = 0
    t_end = p * T
    z_start = np.zeros(nzm)
    if from_stop:
        k = int(ev[0, 2])
        # stuck from τ = 0 to a release of that stop, and stuck there again at the end
        if n_ev < 2 or ev[0, 0] != 0.0 or int(ev[0, 1]) != 1:
            return M_FROM_STOP
        if int(ev[1, 1]) != 2 or int(ev[1, 2]) != k:
            return M_FROM_STOP
        if reg_end != k:
            return M_FROM_STOP
        # the state at the first release: stuck from τ = 0 (the impact map there zeroes a
        # velocity that is already zero), propagated in the stuck regime
        _impact_map(R, MinvX, G, N, nzm, z)
        _mat_vec(Pin[k - 1], z, ny, nzm, y)
        y[ny - 1] = g1 if k == 1 else -g2
        _propagator(lam, V, Vi, k, nk[k], ny, ev[1, 0], e, P)
        _mat_vec(P, y, ny, ny, yt)
        _mat_vec(Qout[k - 1], yt, nzm, ny, z)
        z_start[:] = z
        t_prev = ev[1, 0]
        first = 2
        t_end = p * T + t_prev
    for i in range(first, n_ev + 1):
        last = i == n_ev
        tau = t_end if last else ev[i, 0]
        dt = tau - t_prev
        t_prev = tau
        # the regime's exact propagator up to the event
        if reg == 0:
            _propagator(lam, V, Vi, 0, nk[0], nzm, dt, e, P)
            _mat_vec(P, z, nzm, nzm, zt)
            z[:] = zt
            _mat_mat(P, J, nzm, nzm, nzm, Jt)
            J[:, :] = Jt
        else:
            _propagator(lam, V, Vi, reg, nk[reg], ny, dt, e, P)
            _mat_vec(P, y, ny, ny, yt)
            y[:] = yt
            _mat_mat(P, Jy, ny, ny, nzm, Jt)
            Jy[:, :] = Jt[:ny, :]
        if last:
            break
        kind = int(ev[i, 1])
        stop = int(ev[i, 2])
        if kind == 2:
            # a release: the fields agree where the contact force is zero (S = I)
            if reg != stop:
                return M_RELEASE
            _mat_vec(Qout[stop - 1], y, nzm, ny, z)
            _mat_mat(Qout[stop - 1], Jy, nzm, ny, nzm, J)
            reg = 0
            continue
        if reg != 0:
            return M_STUCK_IMPACT
        # an impact: v = W q⁻ (the tip's velocity), ∇h·f⁻ = -v on stop 1, +v on stop 2
        v = 0.0
        vscale = 0.0
        for j in range(nzm):
            v += R[0, R_WD, j] * z[j]
            vscale += abs(R[0, R_WD, j] * z[j])
        den = -v if stop == 1 else v
        if not den < -MIN_APPROACH * vscale:
            return M_GRAZING
        sgn = -1.0 if stop == 1 else 1.0
        # the tip sticks when the next event is its release from this stop (or, the last
        # event, the run ends stuck there)
        stuck = (int(ev[i + 1, 1]) == 2 and int(ev[i + 1, 2]) == stop) if i + 1 < n_ev else (
            reg_end == stop)  # fmt: skip
        _field(lam, V, Vi, 0, nk[0], nzm, z, a, fm)
        # z⁺ = R z⁻ (R f⁻ likewise): the impulse along M⁻¹X that zeroes W q
        for j in range(N):
            z[N + j] -= MinvX[j] * v / G
        _impact_map(R, MinvX, G, N, nzm, fm)
        if stuck:
            _mat_vec(Pin[stop - 1], z, ny, nzm, y)
            y[ny - 1] = g1 if stop == 1 else -g2  # the stop's position w*
            _field(lam, V, Vi, stop, nk[stop], ny, y, a, yt)
            _mat_vec(Qout[stop - 1], yt, nzm, ny, fp)
        else:
            _field(lam, V, Vi, 0, nk[0], nzm, z, a, fp)
        # S J = R J + (f⁺ - R f⁻)(∇hᵀ J)/(∇h·f⁻), ∇h = ∓ W over u
        for c in range(nzm):
            acc = 0.0
            wq = 0.0
            for j in range(nzm):
                acc += R[0, R_W, j] * J[j, c]
                wq += R[0, R_WD, j] * J[j, c]
            g[c] = sgn * acc / den
            for j in range(N):
                J[N + j, c] -= MinvX[j] * wq / G
        for j in range(nzm):
            d = fp[j] - fm[j]
            for c in range(nzm):
                J[j, c] += d * g[c]
        if stuck:
            _mat_mat(Pin[stop - 1], J, ny, nzm, nzm, Jy)
            reg = stop
    if reg != reg_end:
        return M_END_REGIME
    if reg != 0:
        _mat_vec(Qout[reg - 1], y, nzm, ny, z)
        _mat_mat(Qout[reg - 1], Jy, nzm, ny, nzm, J)
    size = 0.0
    diff = 0.0
    for i in range(nx):
        # from a stop, the replay ends p periods after the first release: at its start again
        want = z_start[i] if from_stop else x_end[i]
        size = max(size, abs(want))
        diff = max(diff, abs(z[i] - want))
    if not diff <= END_TOL * size:
        return M_END_STATE
    for i in range(nx):
        for j in range(nx):
            if not math.isfinite(J[i, j]):
                return M_NOT_FINITE
            out[i, j] = J[i, j]
    return M_OK


def compile_monodromy() -> None:
    """Compile :func:`monodromy` into numba's on-disk cache if it is not there (a point reaches
    it only at its first orbit; ``simulate.warm_up`` calls this so that no worker compiles it):
    a one-mode replay of one impact-free period, with the argument types the driver passes."""
    if on_disk(monodromy):
        return
    N, nzm = 1, 4
    lam = np.zeros((3, nzm), dtype=np.complex128)
    V = np.zeros((3, nzm, nzm), dtype=np.complex128)
    for r in range(3):
        V[r] = np.eye(nzm)
    monodromy(np.zeros((1, 5)), 0, np.zeros(2), np.zeros(2), 1.0, 1.0, 1, 0, lam, V, V.copy(),
              np.full(3, nzm - 1, dtype=np.int64), np.zeros((3, 8, nzm)),
              np.zeros((2, nzm - 1, nzm)), np.zeros((2, nzm, nzm - 1)), np.zeros(N), 1.0, 1.0,
              1.0, N, False, np.zeros((2, 2)))  # fmt: skip
