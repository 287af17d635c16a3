"""Newton's impact law with a coefficient of restitution e (``CellParams.e1``, ``e2``;
docs/model.md §5) in the time-stepping methods: e = 0 is today's model, an impact turns the
tip's approach velocity v into −e v, elastic impacts conserve energy without damping, and
what cannot honour e > 0 refuses it naming the field."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from worker.model import CellParams, assemble
from worker.model.chain import ChainParams
from worker.simulate import SolverSettings, simulate_chain_point, simulate_point
from worker.solvers import measure as ms
from worker.solvers.euler import EulerRun
from worker.solvers.exponential import ExponentialRun
from worker.solvers.linear import linear_tail

CELL = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.3, g1=0.1, g2=0.1, modes=3)
RUNS = {"euler": EulerRun, "exponential": ExponentialRun}


def free_run(method: str, spp: int, periods: int, **cell) -> tuple:
    """An unforced, undamped cell (full coupling: M symmetric, X = W) whose tip starts at 3
    towards stop 1: its history (every step's state and impulses) and its system."""
    p = dataclasses.replace(CELL, xi=0.0, gamma_r=1.0, coupling="full", **cell)
    sys_ = assemble(p)
    run = RUNS[method](sys_, SolverSettings(method=method, steps_per_period=spp),
                       linear_tail(sys_, False), False, 1e9)  # fmt: skip
    N = sys_.ndof
    x0 = np.zeros(2 * N)
    x0[N:] = np.linalg.lstsq(sys_.W[None, :], [3.0], rcond=None)[0]
    run.reset(x0)
    run.keep_history(periods * (spp + 8) * 2)
    run.advance(periods, False, 0, np.zeros((periods, ms.ROW)), np.zeros((periods, run.nx)))
    return run.history(p, sys_.kappa), sys_, x0


def energy(sys_, states: np.ndarray) -> np.ndarray:
    N = sys_.ndof
    return np.array([0.5 * x[N:] @ sys_.M @ x[N:] + 0.5 * x[:N] @ sys_.K @ x[:N] for x in states])


@pytest.mark.parametrize("method", ["euler", "exponential", "event"])
def test_zero_restitution_is_todays_model(method):
    s = SolverSettings(method=method)
    a = simulate_point(CELL, s).as_dict()
    b = simulate_point(dataclasses.replace(CELL, e1=0.0, e2=0.0), s).as_dict()
    a.pop("wall_s"), b.pop("wall_s")
    assert a == b and sum(a["impacts_per_period"]) > 0


@pytest.mark.parametrize("e", [0.3, 0.6, 1.0])
@pytest.mark.parametrize("method", ["euler", "exponential"])
def test_an_impact_turns_the_approach_velocity_v_into_minus_e_v(method, e):
    h, sys_, x0 = free_run(method, 1024, 1, e1=e, e2=e)
    N = sys_.ndof
    k = int(np.argmax(h["impulse1"] > 0))  # the first impact, at stop 1
    assert h["impulse1"][k] > 0 and h["impulse2"][: k + 1].max() == 0
    before = sys_.W @ (h["state"][k - 1] if k else x0)[N:]
    assert before > 2.5  # approaching stop 1
    if method == "euler":  # the step's end velocity: −e times the approach
        after = sys_.W @ h["state"][k][N:]
        assert after == pytest.approx(-e * before, rel=1e-12)
    else:  # at the step's start, at once: Newton's impulse (1 + e) v / G
        assert h["impulse1"][k] * sys_.G == pytest.approx((1 + e) * before, rel=1e-12)


def test_elastic_impacts_conserve_energy_without_damping():
    # exponential: exact free flight and Newton's instantaneous impulse: to round-off
    h, sys_, _ = free_run("exponential", 1024, 10, e1=1.0, e2=1.0)
    E = energy(sys_, h["state"])
    assert (h["impulse1"] > 0).sum() > 100 and (h["impulse2"] > 0).sum() > 100
    assert np.max(np.abs(E - E[0])) < 1e-9 * E[0]
    # euler: a first-order scheme, its energy error falls as Δτ
    drift = []
    for spp in (4096, 16384):
        h, sys_, _ = free_run("euler", spp, 10, e1=1.0, e2=1.0)
        E = energy(sys_, h["state"])
        drift.append(np.max(np.abs(E - E[0])) / E[0])
    assert drift[0] < 1e-2 and 2.5 < drift[0] / drift[1] < 8.0  # 4x smaller step: ~4x


@pytest.mark.parametrize("method", ["euler", "exponential"])
def test_a_rebounding_cell_ends_with_a_result_and_more_impacts(method):
    s = SolverSettings(method=method)
    plastic = simulate_point(CELL, s)
    bouncy = simulate_point(dataclasses.replace(CELL, e1=0.6, e2=0.6), s)
    assert not bouncy.failed and np.isfinite(bouncy.transmittance_db)
    assert sum(bouncy.impacts_per_period) > sum(plastic.impacts_per_period)


def test_what_cannot_honour_restitution_refuses_it_naming_the_field():
    with pytest.raises(ValueError, match=r"e1 must be <= 1, got 1.5"):
        dataclasses.replace(CELL, e1=1.5)
    with pytest.raises(ValueError, match=r"e2 must be >= 0"):
        dataclasses.replace(CELL, e2=-0.1)
    chain = ChainParams(dataclasses.replace(CELL, e2=0.5), 2)
    with pytest.raises(ValueError, match=r"cells \[1, 2\] have e1 or e2 > 0"):
        simulate_chain_point(chain, SolverSettings(method="euler"))


# --------------------------------------------------------------------------- a known orbit


def _oscillator(sys_, ss):
    """The reduced cell: one beam mode, θ = 1e-6, so the outer mass moves as in the closed form
    whatever the tip does (paper coupling: its row has no beam term; an impulse moves it by
    1e-6 of the tip's share). The tip w = W₀q is then a damped oscillator ẅ + cẇ + kw driven by
    the mass: its impact-free response w_p is the closed form's, and the homogeneous part has
    the transition matrix Φ(t) of a damped oscillator."""
    g = ss.params.gamma_r
    k = sys_.K[0, 0] / sys_.M[0, 0]
    c = sys_.C[0, 0] / sys_.M[0, 0]
    Wq = sys_.W[0] * ss.U[0]
    wd, a = np.sqrt(k - c * c / 4), c / 2

    def wp(t):
        return (Wq * np.exp(1j * g * t)).real, (1j * g * Wq * np.exp(1j * g * t)).real

    def phi(t):
        E, C, S = np.exp(-a * t), np.cos(wd * t), np.sin(wd * t)
        return np.array(
            [[E * (C + a / wd * S), E * S / wd], [-E * k * S / wd, E * (C - a / wd * S)]]
        )

    return wp, phi


def period_one_orbit(p: CellParams):
    """The period-1 orbit with one impact a period at stop 1 (e = p.e1): impact phase t₀ and
    approach velocity v, from w(t₀) = w(t₀ + T) = g̃1, ẇ(t₀⁺) = −e v, ẇ(t₀ + T⁻) = v with the
    closed-form flight between (Φ(T) and w_p), v eliminated, t₀ a root of one scalar equation;
    and the whole cell's state on it at τ = 0."""
    from scipy.optimize import brentq

    sys_ = assemble(p)
    ss = linear_tail(sys_, True).steady
    wp, phi = _oscillator(sys_, ss)
    T, e, gap = 2 * np.pi / p.gamma_r, p.e1, p.g1
    P = phi(T)

    def v_of(t0):
        w, wd = wp(t0)
        return ((P[0, 0] - 1) * (gap - w) - P[0, 1] * wd) / (e * P[0, 1])

    def residual(t0):
        w, wd = wp(t0)
        v = v_of(t0)
        return P[1, 0] * (gap - w) + P[1, 1] * (-e * v - wd) - v + wd

    ts = np.linspace(0, T, 2001)
    rs = [residual(t) for t in ts]
    for lo, hi, rlo, rhi in zip(ts[:-1], ts[1:], rs[:-1], rs[1:], strict=True):
        if rlo * rhi < 0:
            t0 = brentq(residual, lo, hi, xtol=1e-15)
            v = v_of(t0)
            h0 = np.array([gap - wp(t0)[0], -e * v - wp(t0)[1]])
            between = [wp(t0 + t)[0] + (phi(t) @ h0)[0] for t in np.linspace(0, T, 2001)[1:-1]]
            if v > 0 and max(between) < gap:  # approaching, and clear of the stop between
                h = phi(T - t0) @ h0  # τ = T ≡ 0 lies in (t₀, t₀ + T)
                N = sys_.ndof
                x0 = np.zeros(2 * N)
                x0[0], x0[N] = (wp(T)[0] + h[0]) / sys_.W[0], (wp(T)[1] + h[1]) / sys_.W[0]
                x0[N - 1] = ss.U[-1].real
                x0[2 * N - 1] = (1j * p.gamma_r * ss.U[-1]).real
                return t0, v, x0, sys_
    raise AssertionError("no period-1 orbit")


@pytest.mark.parametrize("method", ["euler", "exponential"])
def test_the_impact_oscillators_period_one_orbit_in_closed_form(method):
    base = CellParams(theta=1e-6, sigma=0.05, gamma_s=1.0, gamma_r=1.3, g1=1.0, g2=1e6, modes=1)
    amp = abs(assemble(base).W[0] * linear_tail(assemble(base), True).steady.U[0])
    p = dataclasses.replace(base, g1=0.5 * amp, e1=0.5, e2=0.5)  # the tip's free swing halved
    t0, v, x0, sys_ = period_one_orbit(p)
    T, spp, n = 2 * np.pi / p.gamma_r, 16384, 20
    run = RUNS[method](sys_, SolverSettings(method=method, steps_per_period=spp),
                       linear_tail(sys_, True), True, 1e9)  # fmt: skip
    run.reset(x0)
    run.keep_history(n * (spp + 8))
    run.advance(n, False, 0, np.zeros((n, ms.ROW)), np.zeros((n, run.nx)))
    h = run.history(p, sys_.kappa)
    N = sys_.ndof
    for k in range(n - 5, n):  # held on the orbit: one impact a period, where it belongs
        hit = np.nonzero((h["impulse1"] > 0) & (h["tau"] > k * T) & (h["tau"] <= (k + 1) * T))[0]
        assert len(hit) == 1
        i = hit[0]
        # the impulse goes in at the start of the step in which the tip would reach the stop
        assert 0.0 <= (h["tau"][i] - k * T - t0) / (T / spp) <= 1.0
        approach = sys_.W @ h["state"][i - 1][N:]
        assert approach == pytest.approx(v, rel=1e-3)  # e off by 10 % moves it by 2 %
