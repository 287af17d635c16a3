"""The exact monodromy matrix of an event-solver orbit (worker/solvers/event/monodromy.py)."""

from __future__ import annotations

import numpy as np
import pytest

from worker.model import CellParams, assemble
from worker.simulate import SolverSettings, simulate_point
from worker.solvers import measure as ms
from worker.solvers.event import kernel as ek
from worker.solvers.event import monodromy as mono
from worker.solvers.event.driver import EventRun
from worker.solvers.linear import linear_tail

FIG5 = dict(sigma=0.05, gamma_s=1.0, xi=0.05, modes=5)


def cell(**kw) -> CellParams:
    return CellParams(**{**FIG5, **kw})


def event_run(p: CellParams) -> EventRun:
    s = assemble(p)
    tail = linear_tail(s, True)
    return EventRun(s, SolverSettings(), tail, True, 1e6 * max(tail.scale, p.g1, p.g2))


def period_map(run: EventRun, x: np.ndarray, n: int) -> np.ndarray:
    rows = np.zeros((n, ms.ROW))
    samples = np.zeros((n, run.nx))
    run.reset(x)
    run.advance(n, False, 0, rows, samples)
    return samples[-1].copy()


def central_jacobian(run: EventRun, x: np.ndarray, n: int, rel: float) -> np.ndarray:
    """The n-period map's Jacobian at x by central differences of whole kernel runs."""
    h = rel * np.max(np.abs(x))
    J = np.empty((x.size, x.size))
    for i in range(x.size):
        e = np.zeros(x.size)
        e[i] = h
        J[:, i] = (period_map(run, x + e, n) - period_map(run, x - e, n)) / (2.0 * h)
    return J


def exact(run: EventRun, x: np.ndarray, n: int, shifted: bool = False) -> np.ndarray | None:
    """The exact matrix of the n-period map at x (None without one); ``shifted``: taken at the
    orbit's first release (it starts stuck on a stop), else at x."""
    got = run.run_from(x, n, False, True, np.zeros((n, ms.ROW)), np.zeros((n, run.nx)))[0]
    if got is None:
        return None
    assert got.shifted == shifted
    return got.matrix


# Figure 5's cells and the full coupling (contact force along M⁻¹X ≠ Wᵀ): period-1 orbits that
# stick on and are released from both stops (8 events a period), one with impacts only, a
# period-3 orbit with 42 events, and Figure 5's period-33 orbit (a multiplier of 0.0015)
ORBITS = [
    dict(theta=0.1, g1=0.1, g2=0.1, gamma_r=0.6),
    dict(theta=0.1, g1=0.1, g2=0.1, gamma_r=0.9),
    dict(theta=0.1, g1=0.7, g2=0.7, gamma_r=1.16),
    dict(theta=0.1, g1=0.1, g2=0.1, gamma_r=1.3, coupling="full"),
    dict(theta=0.1, g1=0.1, g2=0.1, gamma_r=0.7, coupling="full"),
    dict(theta=0.1, g1=1.0, g2=1.0, gamma_r=0.86),
]


@pytest.mark.parametrize("kw", ORBITS, ids=lambda kw: f"g{kw['g1']}-γ{kw['gamma_r']}")
def test_the_exact_monodromy_matrix_is_the_period_maps_jacobian(kw):
    p = cell(**kw)
    r = simulate_point(p)
    assert r.outcome == "periodic"
    x, n = np.asarray(r.final_state), r.response_period
    run = event_run(p)
    J = exact(run, x, n)
    assert J is not None
    # central differences converge to it as their step shrinks (truncation ∝ step², round-off
    # ∝ 1/step): within 1e-5 of its size at a relative step of 1e-6 on every orbit here
    Jc = central_jacobian(run, x, n, 1e-6)
    size = np.max(np.abs(J))
    assert np.max(np.abs(J - Jc)) <= 1e-5 * size
    # a matrix off by 1 % of its size in one entry is told apart
    wrong = J.copy()
    wrong[0, 0] += 0.01 * size
    assert np.max(np.abs(wrong - Jc)) > 1e-5 * size
    # the engine reports its spectral radius as the Floquet multiplier
    assert r.floquet_multiplier == pytest.approx(np.max(np.abs(np.linalg.eigvals(J))), rel=1e-12)


def sticking_orbit() -> tuple[EventRun, np.ndarray, np.ndarray, np.ndarray]:
    """Figure 5's θ 0.1, gap 0.1, γ_r 0.6 orbit (period 1): its run, start, event log, end."""
    p = cell(theta=0.1, g1=0.1, g2=0.1, gamma_r=0.6)
    x = np.asarray(simulate_point(p).final_state)
    run = event_run(p)
    run.reset(x)
    run.evlog = np.zeros((64, ek.EV_COLS))
    run.advance(1, False, 0, np.zeros((1, ms.ROW)), np.zeros((1, run.nx)))
    return run, x, run.evlog[: int(run.kst[ek.K_EVLOG])].copy(), run.x.copy()


def test_the_replay_covers_sticking_and_releases():
    kinds = sticking_orbit()[2][:, 1]
    assert (kinds == 1).sum() >= 2 and (kinds == 2).sum() >= 2  # impacts, and releases


def test_an_orbit_that_starts_stuck_on_a_stop_gets_the_matrix_at_its_first_release():
    # Figure 5, θ 0.2, gap 0.1, γ_r 0.94: a period-21 orbit whose start has the tip stuck on a
    # stop. The map at τ = 0 is one-sided (no state may move into the stop), so the replay
    # moves the section to the first release. Its spectral radius is the orbit's: central
    # differences along the constraint at τ = 0 (the tip held on the stop, at rest) converge
    # to it. (Before, neither the replay nor the engine's finite differences gave one.)
    p = cell(theta=0.2, g1=0.1, g2=0.1, gamma_r=0.94)
    r = simulate_point(p)
    assert r.outcome == "periodic" and r.response_period == 21
    x, n = np.asarray(r.final_state), 21
    run = event_run(p)
    run.reset(x)
    assert run.kst[ek.K_PENDING] > 0.0 and run.kst[ek.K_SKIP_ON] == 0.0
    J = exact(run, x, n, shifted=True)
    assert J is not None
    rho = float(np.max(np.abs(np.linalg.eigvals(J))))
    s = assemble(p)
    N = s.ndof
    C = np.zeros((2, 2 * N))
    C[0, :N] = s.W
    C[1, N:] = s.W
    Z = np.linalg.svd(C)[2][2:].T  # the constraint's tangent space: W δu = W δq = 0
    errors = []
    for rel in (1e-5, 1e-6, 1e-7):
        h = rel * np.max(np.abs(x))
        D = np.column_stack([
            (period_map(run, x + h * z, n) - period_map(run, x - h * z, n)) / (2.0 * h) for z in Z.T
        ])  # fmt: skip
        assert np.max(np.abs(C @ D)) < 1e-6  # the orbit ends stuck: the image stays on it
        errors.append(abs(np.max(np.abs(np.linalg.eigvals(Z.T @ D))) - rho))
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-6 * rho
    assert r.floquet_multiplier == pytest.approx(rho, rel=1e-12)


def _replay(run: EventRun, x: np.ndarray, evlog: np.ndarray, x_end: np.ndarray,
            from_stop: bool = False) -> int:  # fmt: skip
    p = run.sys.params
    ea = run.ea
    out = np.zeros((run.nx, run.nx))
    return mono.monodromy(evlog, len(evlog), x, x_end, run.f_scale, 2 * np.pi / p.gamma_r, 1, 0,
                          ea.lam, ea.V, ea.Vi, ea.nk, ea.R, ea.Pin, ea.Qout, run.minvx,
                          run.sys.G, p.g1, p.g2, run.sys.ndof, from_stop, out)  # fmt: skip


def test_the_replay_refuses_a_log_it_cannot_account_for():
    run, x, log, end = sticking_orbit()
    assert _replay(run, x, log, end) == mono.M_OK
    # the run's end state moved: the replay does not reproduce it
    moved = end.copy()
    moved[0] += 1e-6 * np.max(np.abs(end))
    assert _replay(run, x, log, moved) == mono.M_END_STATE
    # a release from a stop the tip is not stuck on
    first_release = int(np.flatnonzero(log[:, 1] == 2)[0])
    assert _replay(run, x, log[first_release:], end) == mono.M_RELEASE
    # the first impact put on the other stop, which the tip is moving away from: no speed of
    # approach (the saltation matrix would divide by it)
    assert log[0, 1] == 1.0
    away = log.copy()
    away[0, 2] = 3.0 - away[0, 2]
    assert _replay(run, x, away, end) == mono.M_GRAZING
    # taken as starting stuck on a stop: its first impact is not at τ = 0
    assert log[0, 0] > 0.0
    assert _replay(run, x, log, end, from_stop=True) == mono.M_FROM_STOP
