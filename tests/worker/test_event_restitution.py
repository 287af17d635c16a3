"""Newton's impact law in the event method (docs/model.md §5, docs/solvers.md "Restitution"):
rebounds, the accumulation point of a rebound sequence against its closed form, the impact
oscillator's period-1 orbit, energy across elastic impacts, and the time-stepping methods
converging to the event method at e = 0.5."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tests.worker.test_restitution import _oscillator, period_one_orbit
from worker.model import CellParams, assemble
from worker.simulate import SolverSettings, simulate_point
from worker.solvers import measure as ms
from worker.solvers.event.driver import EventRun
from worker.solvers.event.kernel import time_to_accumulation
from worker.solvers.linear import linear_tail

CELL = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.3, g1=0.1, g2=0.1, modes=3)


def oscillator_cell(gamma_r: float, e: float) -> CellParams:
    """The impact oscillator (one beam mode, θ = 1e-6, one stop) with the tip's free swing
    halved by stop 1."""
    base = CellParams(theta=1e-6, sigma=0.05, gamma_s=1.0, gamma_r=gamma_r, g1=1.0, g2=1e6,
                      modes=1)  # fmt: skip
    amp = abs(assemble(base).W[0] * linear_tail(assemble(base), True).steady.U[0])
    return dataclasses.replace(base, g1=0.5 * amp, e1=e, e2=e)


def test_the_geometric_limit_is_exact_for_a_bouncing_ball():
    """Under a constant acceleration a towards the stop the impacts are v_k = eᵏv₀ at
    t_k = t₀ + Σ 2eᵏv₀/a, and accumulate at t₀ + 2ev₀/(a(1 − e)): the limit from any two
    consecutive impacts is that point, to round-off."""
    a, v0, e = 9.81, 2.0, 0.7
    t_inf = 2 * e * v0 / (a * (1 - e))
    t, v = 0.0, v0
    for _ in range(6):
        flight, v_next = 2 * e * v / a, e * v
        left = time_to_accumulation(v, v_next, flight, e)
        assert t + flight + left == pytest.approx(t_inf, rel=1e-14)
        t, v = t + flight, v_next
    # not one geometric sequence (v not e times the last), elastic, or plastic: no limit
    assert time_to_accumulation(1.0, 0.6, 0.1, 0.5) == -1.0
    assert time_to_accumulation(1.0, 1.0, 0.1, 1.0) == -1.0
    assert time_to_accumulation(1.0, 0.0, 0.1, 0.0) == -1.0


def test_a_rebound_sequence_accumulates_where_the_closed_form_says():
    """A slowly driven impact oscillator (γ_r = 0.3) chatters on its stop once a period: its
    rebounds, each flight in closed form (the oscillator's transition matrix and the mass's
    closed-form drive), accumulate at a time the event method reports (event kind 3) within
    2e-6 of the sequence's length; the run neither stalls nor spends its event budget on it."""
    from scipy.optimize import brentq

    p = oscillator_cell(0.3, 0.5)
    sys_ = assemble(p)
    wp, phi = _oscillator(sys_, linear_tail(sys_, True).steady)
    r = simulate_point(p, SolverSettings(method="event"), history_periods=1)
    assert r.outcome == "periodic" and r.response_period == 1
    ev = r.history["events"]
    acc = np.nonzero(ev[:, 1] == 3)[0]
    assert len(acc) == 1
    first = acc[0]
    while first > 0 and ev[first - 1, 1] == 1 and ev[first - 1, 2] == 1:
        first -= 1
    assert acc[0] - first >= 10  # a sequence of rebounds, not a single impact
    t, e, gap, G = ev[first, 0], p.e1, p.g1, sys_.G
    v = ev[first, 4] * G / (1 + e)  # the first impact's approach velocity, from its impulse
    v1, t1 = v, t
    n = 0
    while v > 1e-6 * v1:  # far above the round-off of the flights' roots
        h0 = np.array([gap - wp(t)[0], -e * v - wp(t)[1]])  # leaving the stop at −e v

        def gap_at(s, t=t, h0=h0):
            return gap - (wp(s)[0] + (phi(s - t) @ h0)[0])

        def rate(s, t=t, h0=h0):
            return wp(s)[1] + (phi(s - t) @ h0)[1]

        accel = abs(rate(t + 1e-6) - rate(t)) / 1e-6
        grid = t + 2 * e * v / accel * np.linspace(1e-3, 3.0, 3001)  # the flight ≈ 2ev/a
        g = np.array([gap_at(s) for s in grid])
        k = int(np.argmax(g < 0))
        assert k > 0, "the tip returns to the stop"
        t_next = brentq(gap_at, grid[k - 1], grid[k], xtol=1e-16, rtol=1e-15)
        state = phi(t_next - t) @ h0
        v_next = wp(t_next)[1] + state[1]
        flight = t_next - t
        t, v_prev, v = t_next, v, v_next
        n += 1
    tail = time_to_accumulation(v_prev, v, flight, e)
    reference = t + tail
    assert n >= 15
    # θ = 1e-6: the impulses move the mass, and so the tip's drive, by ~1e-6
    assert ev[acc[0], 0] == pytest.approx(reference, abs=2e-6 * (reference - t1))


def test_the_impact_oscillators_period_one_orbit_event_by_event():
    """The closed-form period-1 orbit (e = 0.5; tests/worker/test_restitution.py) is the event
    method's orbit: one rebound a period at its phase and approach velocity (θ = 1e-6 moves the
    mass by 1e-6 of the tip's share, the tolerance), confirmed periodic."""
    p = oscillator_cell(1.3, 0.5)
    t0, v, x0, sys_ = period_one_orbit(p)
    T, n = 2 * np.pi / p.gamma_r, 10
    run = EventRun(sys_, SolverSettings(method="event"), linear_tail(sys_, True), True, 1e9)
    run.reset(x0)
    run.keep_history(n * (run.history_rows_per_period() + 8))
    run.advance(n, False, 0, np.zeros((n, ms.ROW)), np.zeros((n, run.nx)))
    ev = run.history(p, sys_.kappa)["events"]
    assert list(ev[:, 1]) == [1.0] * n  # one rebound a period, nothing else
    assert ev[:, 0] - T * np.arange(n) == pytest.approx(np.full(n, t0), abs=1e-6 * T)
    assert ev[:, 4] * sys_.G / (1 + p.e1) == pytest.approx(np.full(n, v), rel=1e-5)
    r = simulate_point(p, SolverSettings(method="event"))
    assert r.outcome == "periodic" and r.response_period == 1
    assert r.impacts_per_period == (1.0, 0.0)


def test_an_event_rebound_turns_v_into_minus_e_v_and_elastic_ones_keep_the_energy():
    """Unforced, undamped, full coupling (M symmetric, X = W): at e = 1 the energy
    ½qᵀMq + ½uᵀKu is the same after hundreds of impacts to 1e-9; at e = 0.6 every rebound
    turns the approach velocity v into −0.6 v (to 1e-12)."""
    for e in (1.0, 0.6):
        p = dataclasses.replace(CELL, xi=0.0, gamma_r=1.0, coupling="full", e1=e, e2=e)
        sys_ = assemble(p)
        N = sys_.ndof
        run = EventRun(sys_, SolverSettings(method="event"), linear_tail(sys_, False), False,
                       1e9)  # fmt: skip
        x0 = np.zeros(2 * N)
        x0[N:] = np.linalg.lstsq(sys_.W[None, :], [3.0], rcond=None)[0]
        run.reset(x0)
        n = 10
        run.keep_history(n * (run.history_rows_per_period() + 400))
        run.advance(n, False, 0, np.zeros((n, ms.ROW)), np.zeros((n, run.nx)))
        h = run.history(p, sys_.kappa)
        states = h["state"]
        energy = np.array([0.5 * x[N:] @ sys_.M @ x[N:] + 0.5 * x[:N] @ sys_.K @ x[:N]
                           for x in states])  # fmt: skip
        hits = np.nonzero(h["events"][:, 1] == 1)[0]
        if e == 1.0:
            assert len(hits) > 100
            assert np.abs(energy / energy[0] - 1).max() < 1e-9
        else:
            # an impact's row (kind 1 or 2, the stop): its impulse, the state just after it.
            # A rebound leaves at −e v; an impact that ends a rebound sequence (its limit, an
            # event of kind 3, or a departure the search cannot prove) at 0
            rows = np.nonzero((h["kind"] == 1) | (h["kind"] == 2))[0]
            v_in = (h["impulse1"][rows] + h["impulse2"][rows]) * sys_.G
            v_out = np.abs(states[rows][:, N:] @ sys_.W)
            rebound = v_out > 1e-12 * v_in.max()
            assert rebound.sum() > 20
            assert v_out[rebound] == pytest.approx(e * v_in[rebound] / (1 + e), rel=1e-12)
            # every limit taken is one of them; a departure the search cannot prove adds
            # only a few
            limits = int((h["events"][:, 1] == 3).sum())
            assert 0 < limits <= (~rebound).sum() <= limits + 0.05 * len(rows)


@pytest.mark.parametrize("method", ["exponential", "euler"])
def test_time_stepping_converges_to_the_event_method_at_first_order(method):
    """At e = 0.5 (the paper-like cell of tests/worker/test_restitution.py, whose rebound
    sequences accumulate twice a period: a periodic orbit for the event method) the
    transmittance of the time-stepping methods approaches the event method's at first order
    (the error falls by ~4 from T/4096 to T/16384: measured 4.7 and 4.0), and the time on the
    stops at an order of ~0.8 (measured 2.9 and 3.0; a resting tip's last rebounds are
    resolved only down to the step)."""
    p = dataclasses.replace(CELL, e1=0.5, e2=0.5)
    ref = simulate_point(p, SolverSettings(method="event"))
    assert ref.outcome == "periodic"
    errs = []
    for spp in (4096, 16384):
        r = simulate_point(p, SolverSettings(method=method, steps_per_period=spp,
                                             max_periods=400))  # fmt: skip
        errs.append((abs(r.transmittance_db - ref.transmittance_db),
                     abs(r.contact_fraction[0] - ref.contact_fraction[0])))  # fmt: skip
    (g_coarse, c_coarse), (g_fine, c_fine) = errs
    assert 3.0 < g_coarse / g_fine < 6.0, errs
    assert 2.2 < c_coarse / c_fine < 6.0, errs
