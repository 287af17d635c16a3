"""Chains of N cells without stops (docs/model.md §11): assembly, closed-form steady state,
transfer matrices and the infinite lattice. No simulator: everything here is linear algebra."""

import dataclasses
import math

import numpy as np
import pytest

from worker.model import CellParams, assemble, linear_transmittance_db, steady_state
from worker.model.chain import (
    MAX_ASSEMBLED,
    MAX_CELLS,
    ChainParams,
    assemble_chain,
    bloch_exponent,
    chain_linear_transmittance_db,
    chain_steady_state,
    chain_transfer_transmittance_db,
    effective_mass,
    stop_bands,
    transfer_matrix,
)

NEPER_DB = 20.0 / math.log(10.0)  # dB in a neper


def cell(**kw) -> CellParams:
    return CellParams(**{"theta": 0.3, "sigma": 0.05, "gamma_s": 1.0, "gamma_r": 1.3, **kw})


# Cells of both couplings: near the mass resonance, in the isolation range, at the first beam
# mode, with ξ_b apart from ξ, one mode and thirty, light and heavy frames.
CELLS = [
    dict(coupling="paper"),
    dict(coupling="full"),
    dict(coupling="paper", gamma_r=0.9, xi=0.05, theta=1.0, modes=1),
    dict(coupling="full", gamma_r=0.8, xi=0.01, xi_b=0.002),
    dict(coupling="full", gamma_r=4.0, sigma=0.1, modes=30, gamma_s=2.0),
    dict(coupling="paper", gamma_r=2.5, sigma=3.0, theta=20.0, xi=0.3),
    dict(coupling="full", gamma_r=0.05, theta=1e-3, sigma=1e-4, xi=0.5, modes=3),
]
IDS = [f"{kw['coupling']}-{kw.get('gamma_r', 1.3)}" for kw in CELLS]


# ------------------------------------------------------------------------------ N = 1


@pytest.mark.parametrize("kw", CELLS, ids=IDS)
def test_one_cell_is_the_unit_cell_to_the_bit(kw):
    p = cell(**kw)
    unit = assemble(p)
    cs = assemble_chain(ChainParams(p, 1))
    for name in ("M", "C", "K", "Minv"):
        assert np.array_equal(getattr(cs, name), getattr(unit, name)), name
    assert np.array_equal(cs.W[0], unit.W) and np.array_equal(cs.X[0], unit.X)
    assert (cs.f_sin, cs.f_cos) == (unit.f_sin, unit.f_cos)
    ss, ref = chain_steady_state(cs), steady_state(unit)
    assert np.array_equal(ss.U, ref.U)
    assert ss.transmittance_db[0] == ref.transmittance_db == linear_transmittance_db(p)
    assert chain_linear_transmittance_db(ChainParams(p, 1))[0] == linear_transmittance_db(p)
    assert ss.amplitudes[0] == ref.amplitude and ss.tip_amplitudes[0] == ref.tip_amplitude


def test_an_undamped_resonance_has_no_steady_state_as_for_the_unit_cell():
    p = cell(coupling="paper", xi=0.0, xi_b=0.0, gamma_r=1.0)  # the mass's own frequency
    assert steady_state(assemble(p)) is None
    assert chain_steady_state(assemble_chain(ChainParams(p, 1))) is None
    for solve in (chain_linear_transmittance_db, chain_transfer_transmittance_db):
        with pytest.raises(ValueError, match="undamped resonance at gamma_r = 1.0"):
            solve(ChainParams(p, 1))


def test_a_long_chain_deep_in_a_stop_band_keeps_finite_numbers():
    # Γ_1000 near −8.7 dB × 1000 Re q: no float holds |S_0/S_N| = e^{4000}
    p = cell(coupling="full", gamma_r=20.0, xi=0.02)
    gammas = chain_linear_transmittance_db(ChainParams(p, MAX_CELLS))
    assert np.all(np.isfinite(gammas)) and gammas[-1] < -40000.0
    mu = bloch_exponent(p).real
    np.testing.assert_allclose(-np.diff(gammas)[:900] / NEPER_DB, mu, rtol=1e-9)


# ------------------------------------------------------------------------------ assembly


def test_chain_matrices_are_the_cells_tied_by_springs_and_dashpots():
    sig = (0.05, 0.2, 0.7)
    p = cell(coupling="full", xi=0.04, modes=2)
    cs = assemble_chain(ChainParams(p, 3, sigma=sig))
    k, c = 1.0 / (p.theta * p.gamma_s**2), 2.0 * p.xi / (p.theta * p.gamma_s)
    np.testing.assert_array_equal(cs.s_index, [2, 5, 8])
    for j, s in enumerate(sig):
        unit = assemble(dataclasses.replace(p, sigma=s))
        b = slice(3 * j, 3 * j + 3)
        np.testing.assert_array_equal(cs.M[b, b], unit.M)
        np.testing.assert_array_equal(cs.K[b, b][:2, :2], unit.K[:2, :2])  # σ_j's beam
        assert cs.K[b, b][2, 2] == (2 * k if j < 2 else k)  # the last mass has one spring
        assert cs.C[b, b][2, 2] == pytest.approx(2 * c if j < 2 else c, rel=1e-15)
    assert cs.K[2, 5] == cs.K[5, 2] == cs.K[5, 8] == -k and cs.C[5, 8] == -c
    assert cs.K[2, 8] == 0.0
    # nothing else couples the cells: the off-block entries are the two springs/dashpots only
    off = np.ones_like(cs.K, dtype=bool)
    for j in range(3):
        off[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = False
    assert np.count_nonzero(cs.K[off]) == 4 and np.count_nonzero(cs.M[off]) == 0


@pytest.mark.parametrize("coupling", ["paper", "full"])
def test_the_delassus_matrix_is_diagonal_with_the_unit_cells_g(coupling):
    cp = ChainParams(cell(coupling=coupling), 4, sigma=(0.05, 0.1, 0.2, 0.4))
    cs = assemble_chain(cp)
    G = cs.delassus
    np.testing.assert_array_equal(G, np.diag(np.diag(G)))
    np.testing.assert_allclose(np.diag(G), [assemble(p).G for p in cp.cells], rtol=1e-15)


def test_a_graded_chain_of_identical_cells_is_the_uniform_chain():
    p = cell(coupling="full", xi=0.02)
    uniform = chain_steady_state(assemble_chain(ChainParams(p, 6)))
    graded = chain_steady_state(
        assemble_chain(ChainParams(p, 6, sigma=[p.sigma] * 6, g1=np.full(6, 0.1)))
    )
    assert np.array_equal(uniform.U, graded.U)
    # the gaps are the impacting chain's: without stops they change nothing
    other_gaps = ChainParams(p, 6, g1=[0.0, 1, 2, 3, 4, 5], g2=[1e6] * 6)
    assert np.array_equal(chain_linear_transmittance_db(other_gaps), uniform.transmittance_db)
    assert other_gaps.cells[3].g1 == 3.0 and other_gaps.cells[3].g2 == 1e6


# ------------------------------------------------------------------------------ closed forms


POINTS = [(coupling, g) for coupling in ("paper", "full") for g in (0.3, 0.8, 1.3, 3.0, 20.0)]


@pytest.mark.parametrize(("coupling", "gamma_r"), POINTS)
def test_the_full_solve_equals_the_transfer_recursion_from_the_free_end(coupling, gamma_r):
    # graded σ; at γ_r = 3 and 20 (stop bands) Γ_10 reaches −180 … −500 dB
    for n in range(1, 11):
        cp = ChainParams(
            cell(coupling=coupling, gamma_r=gamma_r, xi=0.02),
            n,
            sigma=[0.05 * (1 + 0.07 * j) for j in range(n)],
        )
        solved = chain_linear_transmittance_db(cp)
        np.testing.assert_allclose(solved, chain_transfer_transmittance_db(cp), rtol=0, atol=1e-9)


def test_the_largest_assembled_chain_equals_the_transfer_recursion_and_longer_ones_take_it():
    p = cell(coupling="full", modes=5, xi=0.02)
    cp = ChainParams(p, MAX_ASSEMBLED // 6)  # 341 cells, 2046 unknowns
    solved = chain_steady_state(assemble_chain(cp)).transmittance_db
    np.testing.assert_allclose(solved, chain_transfer_transmittance_db(cp), rtol=0, atol=1e-9)
    longer = ChainParams(p, MAX_CELLS)
    with pytest.raises(ValueError, match=r"must be <= 2048 to assemble the chain, got 6000"):
        assemble_chain(longer)
    np.testing.assert_array_equal(
        chain_linear_transmittance_db(longer), chain_transfer_transmittance_db(longer)
    )


@pytest.mark.parametrize(("coupling", "gamma_r"), POINTS)
def test_the_base_power_equals_the_power_dissipated(coupling, gamma_r):
    """Time-averaged: what the base puts in (through the spring and dashpot of cell 1) is what
    the dashpots take out, and in `full` coupling the beams' damping too; in `paper` coupling
    the masses ignore the beams, so the dashpots alone balance it."""
    p = cell(coupling=coupling, gamma_r=gamma_r, xi=0.03, xi_b=0.01)
    cp = ChainParams(p, 5, sigma=(0.05, 0.08, 0.03, 0.2, 0.05))
    cs = assemble_chain(cp)
    U = chain_steady_state(cs).U
    V = 1j * gamma_r * U
    F = complex(cs.f_cos, -cs.f_sin)
    power_in = 0.5 * (np.conj(V[cs.s_index[0]]) * F).real
    s = cs.s_index
    dashpots = 0.5 * (np.conj(V[s]) @ cs.C[np.ix_(s, s)] @ V[s]).real
    total = 0.5 * (np.conj(V) @ cs.C @ V).real
    if coupling == "paper":
        assert dashpots == pytest.approx(power_in, rel=1e-10, abs=1e-300)
    else:
        assert total == pytest.approx(power_in, rel=1e-10, abs=1e-300)
        if gamma_r in (0.8, 1.3):  # near beam modes the beams take a share that matters
            assert total - dashpots > 1e-3 * total


# ------------------------------------------------------------------------------ infinite lattice


@pytest.mark.parametrize("kw", CELLS, ids=IDS)
def test_transfer_matrix_and_bloch_exponent(kw):
    p = cell(**kw)
    T = transfer_matrix(p)
    assert abs(np.linalg.det(T) - 1.0) < 1e-12 * max(1.0, np.abs(T).max() ** 2)
    q = bloch_exponent(p)
    assert q.real >= 0.0
    assert cmath_close(np.cosh(q), 0.5 * np.trace(T), 1e-12)
    # e^{∓q} are T's eigenvalues (the forward and the backward wave)
    lam = np.sort_complex(np.linalg.eigvals(T))
    np.testing.assert_allclose(np.sort_complex(np.array([np.exp(q), np.exp(-q)])), lam, rtol=1e-9)


def cmath_close(a: complex, b: complex, rel: float) -> bool:
    return abs(a - b) <= rel * max(1.0, abs(b))


def test_bloch_exponent_keeps_its_digits_at_low_frequency():
    # q ≈ iγ_r √(m/k) as γ_r → 0; acosh(1 − ε) would give only half the digits
    p = cell(coupling="paper", xi=0.0, xi_b=0.0)
    for g in (1e-3, 1e-5):
        q = bloch_exponent(p, g)
        exact = 2.0 * math.asin(0.5 * g * p.gamma_s)  # cosh q = 1 − (γ_r γ_s)²/2
        assert q.real == 0.0 and q.imag == pytest.approx(exact, rel=1e-14)


@pytest.mark.parametrize("kw", CELLS, ids=IDS)
def test_effective_mass_is_the_paper_momentum_mass_in_full_and_the_frame_in_paper(kw):
    p = cell(**kw)
    m = effective_mass(p)
    if p.coupling == "paper":
        assert m == 1.0 / p.theta  # Eq. 29: no clamp reaction on the mass
    else:
        # at a linear point θ_eff (Eq. 35, κ = 1 + θ) is Re m · θ/(1 + θ)
        theta_eff = steady_state(assemble(p)).theta_eff
        assert (m * p.theta / (1 + p.theta)).real == pytest.approx(theta_eff, rel=1e-11, abs=1e-12)
        assert effective_mass(p, 1e-6).real == pytest.approx(1 / p.theta + 1, rel=1e-9)


@pytest.mark.parametrize("gamma_s", [0.5, 1.0, 3.0])
@pytest.mark.parametrize("theta", [0.01, 1.0, 50.0])
def test_paper_lattice_is_the_monatomic_chain(gamma_s, theta):
    # the masses alone, m = 1/θ, k = 1/(θγ_s²): one band from γ_r = 2ω_m = 2/γ_s up
    bands = stop_bands(cell(coupling="paper", gamma_s=gamma_s, theta=theta, sigma=0.3))
    assert len(bands) == 1
    assert bands[0][0] == pytest.approx(2.0 / gamma_s, rel=1e-12) and bands[0][1] == math.inf


@pytest.mark.parametrize(
    "kw",
    [dict(), dict(sigma=0.5, modes=3), dict(theta=3.0, gamma_s=0.7, modes=8), dict(modes=1)],
)
def test_stop_bands_are_where_the_undamped_lattice_has_no_real_wavenumber(kw):
    p = cell(coupling="full", xi=0.05, **kw)  # the bands ignore the damping
    bands = stop_bands(p)
    undamped = dataclasses.replace(p, xi=0.0, xi_b=0.0)

    def cos_kappa(g: float) -> float:
        return 0.5 * np.trace(transfer_matrix(undamped, g)).real

    edges = [e for band in bands for e in band if 0.0 < e < math.inf]
    for e in edges:  # every edge is cos κ = ±1, exactly (an eigenvalue)
        assert abs(abs(cos_kappa(e)) - 1.0) < 1e-8
    top = 1.5 * max(edges)
    grid = np.geomspace(1e-3, top, 4000)
    inside = np.zeros(grid.size, dtype=bool)
    for lo, hi in bands:
        inside |= (grid > lo) & (grid < hi)
    near = np.zeros(grid.size, dtype=bool)
    for e in edges:
        near |= np.abs(grid - e) < 1e-9 * e
    stop = np.array([abs(cos_kappa(g)) > 1.0 for g in grid])
    np.testing.assert_array_equal(stop[~near], inside[~near])
    assert bands[-1][1] == math.inf  # finite modes: the lattice cuts off above the last edge
    # the first band holds the first clamped-beam mode, where the cell's mass changes sign
    w1 = math.sqrt(assemble(p).K[0, 0])
    assert bands[0][0] < w1 < bands[0][1]


@pytest.mark.parametrize(
    ("coupling", "gamma_r"), [("paper", 3.0), ("full", 0.8), ("full", 3.0), ("full", 8.0)]
)
def test_finite_chains_decay_per_cell_at_the_lattice_attenuation(coupling, gamma_r):
    """Inside a stop band S_N/U_g = 1/(T^N)_22, so the decay per added cell approaches Re q
    like e^{−2N Re q}; lightly damped, with the full solve."""
    p = cell(coupling=coupling, gamma_r=gamma_r, xi=1e-3, xi_b=1e-3)
    mu = bloch_exponent(p).real
    assert mu > 0.5  # inside a band: the check has room
    gammas = [chain_linear_transmittance_db(ChainParams(p, n))[-1] for n in range(1, 16)]
    rate = -np.diff(gammas) / NEPER_DB  # nepers lost per added cell
    errors = np.abs(rate - mu)
    assert errors[0] > 100 * 1e-9 * mu  # two cells are not yet a lattice: the bound means something
    assert errors[-1] < 1e-9 * mu
    # and at the rate the reflection from the free end dies out: e^{−2 Re q} per cell
    big = errors > 1e-11 * mu
    np.testing.assert_allclose(
        errors[1:][big[1:]] / errors[:-1][big[1:]], math.exp(-2 * mu), rtol=0.1
    )
    # inside one long chain too, away from its ends: Γ_{j+1} − Γ_j → −Re q·20/ln 10
    inner = chain_linear_transmittance_db(ChainParams(p, 30))
    np.testing.assert_allclose(-np.diff(inner)[:15] / NEPER_DB, mu, rtol=1e-9)


def test_pass_band_chains_do_not_decay_like_a_stop_band():
    p = cell(coupling="full", gamma_r=1.3, xi=1e-3, xi_b=1e-3)
    mu = bloch_exponent(p).real
    assert mu < 0.01  # a pass band: only the damping attenuates
    inner = chain_linear_transmittance_db(ChainParams(p, 30))
    assert np.max(np.abs(np.diff(inner))) > 100 * mu * NEPER_DB  # standing waves, not decay


# ------------------------------------------------------------------------------ bad input


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        (dict(n_cells=0), "n_cells must be an integer in 1…1000, got 0"),
        (dict(n_cells=MAX_CELLS + 1), "n_cells must be an integer in 1…1000, got 1001"),
        (dict(n_cells=2.0), "n_cells must be an integer in 1…1000, got 2.0"),
        (dict(n_cells=True), "n_cells must be an integer in 1…1000, got True"),
        (
            dict(n_cells=3, sigma=[0.1, 0.2]),
            r"sigma must have one value per cell \(n_cells = 3\), got 2 values: \[0.1, 0.2\]",
        ),
        (
            dict(n_cells=2, g1=[0.1, 0.2, 0.3]),
            r"g1 must have one value per cell \(n_cells = 2\), got 3 values",
        ),
        (
            dict(n_cells=2, g2=0.1),
            r"g2 must be a list of one value per cell \(n_cells = 2\), got 0.1",
        ),
        (dict(n_cells=2, sigma="ab"), "sigma must be a list of one value per cell"),
        (dict(n_cells=2, sigma=[0.1, -1.0]), r"sigma\[1\] must be > 0, got -1.0"),
        (dict(n_cells=2, g1=[0.1, math.nan]), r"g1\[1\] must be finite, got nan"),
        (dict(n_cells=1, g2=[2e12]), r"g2\[0\] must be <= 1e\+12, got 2000000000000.0; allowed"),
    ],
)
def test_bad_chains_are_refused_naming_field_value_and_range(kw, message):
    with pytest.raises(ValueError, match=message):
        ChainParams(cell(), **kw)


def test_the_cell_must_be_cell_params():
    with pytest.raises(ValueError, match="cell must be a CellParams, got"):
        ChainParams({"theta": 0.3}, 2)
