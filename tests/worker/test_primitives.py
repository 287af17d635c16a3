"""The event solver's measurement by primitives against slow, obviously correct quadrature.

A segment of one regime from modal coefficients ``α₀`` and forcing phase ``θ₀``, of length L:
the kernel's integrals (the primitive's difference at the two ends plus the directly
integrated terms) against composite 16-point Gauss-Legendre quadrature of the observables
``s, s_b, ṡ, ṡ_b = Re Σ RV_k α₀_k e^{λ_k t}`` evaluated the obvious way.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from worker.model import CellParams, assemble
from worker.simulate import RUNS, SolverSettings, linear_tail
from worker.solvers import measure as ms
from worker.solvers.engine.config import DIVERGENCE_FACTOR
from worker.solvers.event import primitives as pm
from worker.solvers.event.regimes import R_S, R_SB, R_SBD, R_SD, prepare_event

NODES, WEIGHTS = np.polynomial.legendre.leggauss(16)


def cell(**kw) -> CellParams:
    base = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, g1=0.1, g2=0.1, modes=5)
    return CellParams(**{**base, **kw})


def quadrature(RV, lam, a0, gamma, th0, L, pieces=400):
    """(∫ s e^{-iθ}, ∫ s_b e^{-iθ}, ∫ ṡ², ∫ ṡ_b ṡ) over [0, L] by composite Gauss-Legendre."""
    edges = np.linspace(0.0, L, pieces + 1)
    mid = 0.5 * (edges[1:] + edges[:-1])
    half = 0.5 * (edges[1:] - edges[:-1])
    t = (mid[:, None] + half[:, None] * NODES[None, :]).ravel()
    w = (half[:, None] * WEIGHTS[None, :]).ravel()
    E = np.exp(np.outer(t, lam)) * a0  # (nt, nk): α(t)
    s, sb, sd, sbd = (np.real(E @ RV[row]) for row in (R_S, R_SB, R_SD, R_SBD))
    rot = np.exp(-1j * (th0 + gamma * t))
    return (w @ (s * rot), w @ (sb * rot), w @ (sd * sd), w @ (sbd * sd))


def kernel_way(r, RV, lam, nk, a0, gamma, th0, L, tables):
    H, C, dint, dcm, nd = tables
    a1 = a0 * np.exp(lam * L)
    pad = np.zeros(RV.shape[-1], dtype=complex)
    A0, A1 = pad.copy(), pad.copy()
    A0[:nk], A1[:nk] = a0, a1
    th1 = th0 + gamma * L
    p0 = pm.primitive(r, A0, nk, H, C, math.cos(th0), -math.sin(th0))
    p1 = pm.primitive(r, A1, nk, H, C, math.cos(th1), -math.sin(th1))
    d = pm.direct(r, A0, L, math.cos(th0), -math.sin(th0), dint, dcm, nd)
    v = [b - a + c for a, b, c in zip(p0, p1, d, strict=True)]
    return complex(v[0], v[1]), complex(v[2], v[3]), v[4], v[5]


def near_resonant_cell() -> CellParams:
    """Forcing on the lightly damped cell's first natural frequency: the harmonic term of that
    mode has a rate of ~1e-6 and must be integrated directly."""
    p = cell(xi=1e-6, gamma_r=1.0)
    lam = np.linalg.eigvals(assemble(p).state_matrix())
    w = float(np.min(np.abs(lam.imag[lam.imag > 1e-9])))
    return cell(xi=1e-6, gamma_r=w)


CELLS = {
    "paper, long period": cell(gamma_r=0.45),
    "full coupling": cell(gamma_r=1.5, coupling="full"),
    "undamped": cell(gamma_r=1.7, xi=0.0),
    "near resonance": near_resonant_cell(),
}


@pytest.mark.parametrize("name", list(CELLS))
def test_segment_integrals_are_exact(name):
    p = CELLS[name]
    ea = prepare_event(assemble(p), 64)
    tables = pm.measure_tables(ea.lam, ea.RV, ea.nk, p.gamma_r)
    T = 2.0 * math.pi / p.gamma_r
    rng = np.random.default_rng(7)
    for r in (0, 1, 2):
        nk = int(ea.nk[r])
        lam, RV = ea.lam[r, :nk], ea.RV[r][:, :nk]
        for _ in range(4):
            a0 = rng.standard_normal(nk) + 1j * rng.standard_normal(nk)
            # a segment anywhere in the period, from a sliver to a whole period
            L = T * float(rng.choice([1e-7, 0.013, 0.4, 1.0]))
            th0 = float(rng.uniform(0.0, 2.0 * math.pi))
            ref = quadrature(RV, lam, a0, p.gamma_r, th0, L)
            got = kernel_way(r, ea.RV[r], lam, nk, a0, p.gamma_r, th0, L, tables)
            # round-off of a period's worth of the integrand (a segment's primitives are of
            # that size; a wrong term would be off by its own size × L, 1e-7 T at least)
            size = np.sum(np.abs(RV[[R_S, R_SB, R_SD, R_SBD]] * a0), axis=1)
            scale = [T * size[0], T * size[1], T * size[2] ** 2, T * size[3] * size[2]]
            for g, f, sc in zip(got, ref, scale, strict=True):
                assert abs(g - f) <= 1e-13 * sc, (name, r, L / T, g, f)


def test_every_kind_of_slow_term_is_integrated_exactly():
    # synthetic modes with every rate that needs the direct integral: +iγ (harmonic α term),
    # -iγ (harmonic ᾱ term; with +iγ an α_kα_l pair of rate 0), λ = 0 (α_k² of rate 0), a
    # mode a hair off resonance, and a fast decaying one
    gamma = 1.3
    lam1 = np.array([1j * gamma, -1j * gamma, 0.0, -1e-7 + 1j * gamma, -0.4 + 5.0j])
    nk = lam1.size
    rng = np.random.default_rng(3)
    lam = np.zeros((3, 8), dtype=complex)
    RV = np.zeros((3, 8, 8), dtype=complex)
    lam[:, :nk] = lam1
    RV[:, :, :nk] = rng.standard_normal((8, nk)) + 1j * rng.standard_normal((8, nk))
    tables = pm.measure_tables(lam, RV, np.full(3, nk), gamma)
    dint = tables[2]
    kinds = {int(k) for k in dint[0, : tables[4][0], 2]}
    assert kinds == {pm.T_A, pm.T_AC, pm.T_AA, pm.T_AAC}
    T = 2.0 * math.pi / gamma
    for L in (1e-6 * T, 0.3 * T, T):
        a0 = rng.standard_normal(nk) + 1j * rng.standard_normal(nk)
        ref = quadrature(RV[0][:, :nk], lam1, a0, gamma, 0.7, L)
        got = kernel_way(0, RV[0], lam1, nk, a0, gamma, 0.7, L, tables)
        for g, f in zip(got, ref, strict=True):
            assert abs(g - f) <= 1e-11 * T, (L / T, g, f)


def test_slow_terms_are_listed_for_direct_integration():
    # the forcing mode's harmonic term has rate 0 in every regime; an undamped mode's |α|²
    # term too; near resonance the resonant mode's harmonic term
    counts = {}
    for name, p in CELLS.items():
        ea = prepare_event(assemble(p), 64)
        H, C, dint, dcm, nd = pm.measure_tables(ea.lam, ea.RV, ea.nk, p.gamma_r)
        T = 2.0 * math.pi / p.gamma_r
        for r in range(3):
            assert np.all(np.abs(dcm[r, : nd[r], 1]) * T < pm.DIRECT_MU_T)
        counts[name] = int(nd[0])
        kinds = {(int(k), int(o)) for k, o in dint[0, : nd[0], 2:4]}
        assert (pm.T_A, pm.OUT_HS) in kinds and (pm.T_A, pm.OUT_HSB) in kinds
    assert counts["undamped"] > counts["paper, long period"]
    assert counts["near resonance"] > counts["paper, long period"]


def test_measured_impact_free_periods_are_the_closed_form():
    # Started on the impact-free steady state with stops it never reaches, every measured
    # period's harmonics and phase-portrait integrals are the closed form's: Ŝ T/2,
    # γ²|Ŝ|² T/2 and γ² Re(Ŝ_b conj Ŝ) T/2.
    for p in (cell(gamma_r=0.45, g1=50.0, g2=50.0), cell(gamma_r=2.3, g1=9.0, g2=9.0,
                                                        coupling="full")):  # fmt: skip
        sys_ = assemble(p)
        tail = linear_tail(sys_)
        run = RUNS["event"](sys_, SolverSettings(), tail, True, DIVERGENCE_FACTOR * 100.0)
        run.reset(tail.xp0)
        n = 3
        rows = np.zeros((n, ms.ROW))
        samples = np.zeros((n, run.nx))
        done, code, _ = run.advance(n, True, 0, rows, samples)
        assert done == n and code == ms.END_NONE
        S = tail.steady.U[-1]
        Sb = tail.steady.d @ tail.steady.U[:-1]
        g = p.gamma_r
        T = 2.0 * math.pi / g
        for row in rows:
            assert row[ms.M_S_RE] + 1j * row[ms.M_S_IM] == pytest.approx(S * T / 2, rel=1e-11)
            assert row[ms.M_SB_RE] + 1j * row[ms.M_SB_IM] == pytest.approx(Sb * T / 2, rel=1e-11)
            assert row[ms.M_VV] == pytest.approx(g * g * abs(S) ** 2 * T / 2, rel=1e-11)
            assert row[ms.M_VB] == pytest.approx(
                g * g * (Sb * S.conjugate()).real * T / 2, rel=1e-10, abs=1e-12 * row[ms.M_VV]
            )
