"""The exact propagator with Moreau impulses for chains of N cells
(``worker/solvers/chain_exponential.py``; docs/chains.md)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from worker.model import CellParams
from worker.model.chain import ChainParams, assemble_chain, chain_linear_transmittance_db
from worker.simulate import CHAIN_METHODS, SolverSettings, simulate_chain_point, simulate_point
from worker.solvers.chain_euler import chain_tail, engine_view
from worker.solvers.chain_exponential import (
    GS_MAX_SWEEPS,
    ChainExponentialRun,
    chain_impulses,
    lcp_matrix,
)
from worker.solvers.engine import config as engine_config
from worker.solvers.engine import run_point
from worker.solvers.lcp import lemke_workspace

# the cell of test_chain_euler: its chains of 2 and 3 cells are periodic (period 1) with every
# cell impacting both stops once a period
CELL = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.3, g1=0.1, g2=0.1, modes=2)
FAR = dataclasses.replace(CELL, g1=1e6, g2=1e6)


def expo(n: int | None = None, **kw) -> SolverSettings:
    return SolverSettings(method="exponential", steps_per_period=n, **kw)


def record(res) -> dict:
    out = res.as_dict()
    out.pop("wall_s")
    return out


def test_exponential_runs_chains():
    assert CHAIN_METHODS == ("euler", "exponential")


# --------------------------------------------------------------------------- the contact LCP


def _solve(Gf, c1, c2, use_lemke=False):
    N = len(c1)
    lam1, lam2 = np.zeros(N), np.zeros(N)
    coupled = bool(np.any(Gf - np.diag(np.diag(Gf))))
    ws = lemke_workspace(2 * N)
    status = chain_impulses(Gf, c1, c2, lam1, lam2, coupled, use_lemke, lcp_matrix(Gf),
                            np.zeros(2 * N), *ws)  # fmt: skip
    return lam1, lam2, status


def _complementarity(Gf, c1, c2, lam1, lam2) -> float:
    """The largest violation of Λ ≥ 0, end gaps ≥ 0, Λ·gap = 0, relative to the data's size."""
    P = lam2 - lam1
    gap1 = c1 - Gf @ P
    gap2 = c2 + Gf @ P
    scale = max(np.max(np.abs(c1)), np.max(np.abs(c2)))
    lam_scale = max(np.max(lam1), np.max(lam2), 1e-300)
    return max(
        -min(lam1.min(), lam2.min(), 0.0) / lam_scale,
        -min(gap1.min(), gap2.min(), 0.0) / scale,
        float(np.max(np.minimum(lam1 / lam_scale, np.abs(gap1) / scale))),
        float(np.max(np.minimum(lam2 / lam_scale, np.abs(gap2) / scale))),
    )


def _chain_gf(n_cells: int, spp: int, coupling: str = "paper") -> np.ndarray:
    cs = assemble_chain(ChainParams(cell=dataclasses.replace(CELL, coupling=coupling),
                                    n_cells=n_cells))  # fmt: skip
    run = ChainExponentialRun(cs, expo(spp), chain_tail(cs), True, 1e6)
    return run.Gf


@pytest.mark.parametrize("coupling", ["paper", "full"])
def test_the_fine_steps_contact_matrix_couples_neighbours_through_the_propagator(coupling):
    Gf = _chain_gf(4, 2048, coupling)
    cs = assemble_chain(ChainParams(cell=dataclasses.replace(CELL, coupling=coupling), n_cells=4))
    dtf = 2.0 * math.pi / CELL.gamma_r / 2048
    # diagonal: each cell's own gain, close to its short-step value G Δτ
    G = np.array([s.G for s in cs.cells])
    np.testing.assert_allclose(np.diag(Gf), G * dtf, rtol=1e-3)
    # the euler step's Delassus matrix is diagonal (M block-diagonal); the propagator's is not:
    # neighbours ~1e-6 of the diagonal at T/2048, farther cells much less (measured 3.0e-6,
    # 2.4e-10, 1.4e-14 in paper coupling)
    assert np.count_nonzero(cs.delassus - np.diag(np.diag(cs.delassus))) == 0
    ratio = np.abs(Gf) / np.diag(Gf)[:, None]
    for j in range(3):
        assert 1e-8 < ratio[j, j + 1] < 1e-4
        # reciprocity (M, C, K symmetric and X = W): Gf is symmetric, to round-off
        assert Gf[j, j + 1] == pytest.approx(Gf[j + 1, j], rel=1e-12)
    assert ratio[0, 2] < 1e-3 * ratio[0, 1] and ratio[0, 3] < 1e-3 * ratio[0, 2]


def test_the_coupled_lcp_is_solved_to_complementarity():
    rng = np.random.default_rng(67)
    for n_cells, spp in ((3, 2048), (6, 64)):
        Gf = _chain_gf(n_cells, spp)
        for _ in range(200):
            w = rng.normal(0.0, 0.15, n_cells)  # predicted end tips, some past a stop
            c1, c2 = 0.1 - w, 0.1 + w
            lam1, lam2, status = _solve(Gf, c1, c2)
            assert status >= 0  # the sweeps converged (no Lemke needed)
            assert status <= 4  # in a few sweeps: the off-diagonal ratio is < 1e-3
            assert _complementarity(Gf, c1, c2, lam1, lam2) < 1e-13
            # and Lemke's algorithm on the 2N × 2N LCP finds the same impulses
            l1, l2, st = _solve(Gf, c1, c2, use_lemke=True)
            assert st in (0, -1)
            np.testing.assert_allclose(l2 - l1, lam2 - lam1, rtol=1e-12, atol=1e-15)


def test_an_lcp_the_sweeps_cannot_finish_goes_to_lemke():
    # strongly coupled (not a chain's fine step; symmetric positive definite, smallest
    # eigenvalue 0.015): the sweeps contract too slowly for their budget
    Gf = np.array([[1.0, 0.9, 0.0], [0.9, 1.0, 0.4], [0.0, 0.4, 1.0]])
    c1 = np.array([-0.3, 0.2, -0.1])
    c2 = np.array([0.5, 0.1, 0.4])
    lam1, lam2, status = _solve(Gf, c1, c2)
    assert status == -1
    assert _complementarity(Gf, c1, c2, lam1, lam2) < 1e-13
    assert GS_MAX_SWEEPS == 100


def test_no_impulse_needed_alone_means_none_at_all():
    Gf = _chain_gf(3, 2048)
    lam1, lam2, status = _solve(Gf, np.array([0.1, 0.0, 0.05]), np.array([0.1, 0.2, 0.15]))
    assert status == 0 and not lam1.any() and not lam2.any()


# --------------------------------------------------------------------------- whole points


@pytest.mark.parametrize("coupling", ["paper", "full"])
def test_the_chain_kernel_at_one_cell_is_the_unit_cells_method_bit_for_bit(coupling):
    # straight through the engine (simulate_chain_point hands N = 1 to simulate_point)
    cell = dataclasses.replace(CELL, coupling=coupling)
    s = expo()
    cs = assemble_chain(ChainParams(cell=cell, n_cells=1))
    tail = chain_tail(cs)
    bound = engine_config.DIVERGENCE_FACTOR * max(tail.scale, 0.1)
    a = run_point(lambda: ChainExponentialRun(cs, s, tail, True, bound), engine_view(cs), tail,
                  s, np.zeros(2 * cs.ndof))  # fmt: skip
    b = simulate_point(cell, s)
    assert sum(b.impacts_per_period) > 0
    assert record(a) == record(b)


def test_one_cell_is_the_unit_cell():
    s = expo()
    a = simulate_chain_point(ChainParams(cell=CELL, n_cells=1), s)
    assert record(a) == record(simulate_point(CELL, s))


@pytest.mark.parametrize("n_cells", [2, 3])
def test_without_stops_the_chain_ends_linear_at_the_closed_form(n_cells):
    chain = ChainParams(cell=FAR, n_cells=n_cells)
    lin = chain_linear_transmittance_db(chain)
    r = simulate_chain_point(chain, expo())
    assert r.outcome == "linear"
    assert abs(r.transmittance_db - lin[-1]) <= 1e-6
    assert r.transmittance_db == r.transmittance_linear_db == lin[-1]
    # without the proof, the method's own impact-free orbit: the propagator is exact, Γ_N is
    # read from the range of s_N (cubic Hermite between the T/64 coarse steps), measured
    # 2.0e-6 dB off
    r = simulate_chain_point(chain, expo(linear_tail=False))
    assert r.outcome == "periodic" and r.impacts_per_period == (0.0, 0.0)
    assert r.contact_steps == 0 and r.coarse_steps > 0
    assert abs(r.transmittance_db - lin[-1]) < 1e-5


@pytest.mark.parametrize(
    ("n_cells", "per_dt"),
    # euler's error, measured (dB per unit of Δτ): 1.39 (N = 2), 2.43 (N = 3), first order
    [(2, 1.39), (3, 2.43)],
)
def test_euler_converges_to_the_exponential_result_at_first_order(n_cells, per_dt):
    chain = ChainParams(cell=CELL, n_cells=n_cells)
    ref = simulate_chain_point(chain, expo(4096))
    assert ref.outcome == "periodic" and ref.response_period == 1
    assert ref.impacts_per_period == (float(n_cells), float(n_cells))
    # the exponential result is converged far below euler's error: measured 2.4e-6 (N = 2) and
    # 4.3e-6 dB (N = 3) between T/2048 and T/4096, where euler is 1.6e-3 and 2.9e-3 dB off
    coarse = simulate_chain_point(chain, expo(2048))
    assert abs(coarse.transmittance_db - ref.transmittance_db) < 2e-5
    errors = []
    for n in (1024, 2048, 4096):
        r = simulate_chain_point(chain, SolverSettings(method="euler", steps_per_period=n))
        assert r.outcome == "periodic" and r.response_period == 1
        assert r.impacts_per_period == ref.impacts_per_period
        dt = 2.0 * math.pi / CELL.gamma_r / n
        err = abs(r.transmittance_db - ref.transmittance_db)
        # within 25 % of euler's measured first-order error constant
        assert err == pytest.approx(per_dt * dt, rel=0.25)
        errors.append(err)
    # measured orders 1.00, 1.00 (N = 2) and 1.01, 1.00 (N = 3)
    for coarse_err, fine_err in zip(errors[:-1], errors[1:], strict=True):
        assert 0.8 <= math.log2(coarse_err / fine_err) <= 1.2


def test_a_graded_chain_of_identical_cells_is_the_uniform_chain_bit_for_bit():
    uniform = ChainParams(cell=CELL, n_cells=3)
    graded = ChainParams(cell=CELL, n_cells=3, sigma=(CELL.sigma,) * 3, g1=(0.1,) * 3,
                         g2=(0.1,) * 3)  # fmt: skip
    a = simulate_chain_point(uniform, expo())
    b = simulate_chain_point(graded, expo())
    assert sum(a.impacts_per_period) > 0
    assert record(a) == record(b)
    np.testing.assert_array_equal(a.final_state, b.final_state)


def test_every_cell_impacts_on_its_own_stops():
    both = simulate_chain_point(ChainParams(cell=CELL, n_cells=2), expo())
    assert both.impacts_per_period == (2.0, 2.0)
    for g in ((0.1, 1e6), (1e6, 0.1)):
        one = simulate_chain_point(ChainParams(cell=CELL, n_cells=2, g1=g, g2=g), expo())
        assert one.outcome == "periodic" and sum(one.impacts_per_period) > 0
        assert sum(one.impacts_per_period) < sum(both.impacts_per_period)


def test_lemke_and_the_sweeps_give_the_same_trajectory():
    chain = ChainParams(cell=CELL, n_cells=3)
    kw = dict(max_periods=30, window=5, early_stop=False)
    a = simulate_chain_point(chain, expo(**kw))
    b = simulate_chain_point(chain, expo(lcp="lemke", **kw))
    assert not b.failed
    assert b.contact_steps == a.contact_steps > 0
    assert b.transmittance_db == pytest.approx(a.transmittance_db, abs=1e-9)


def test_fine_steps_everywhere_give_the_same_orbit():
    chain = ChainParams(cell=CELL, n_cells=2)
    a = simulate_chain_point(chain, expo())
    b = simulate_chain_point(chain, expo(adaptive=False))
    assert a.coarse_steps > 0 and b.coarse_steps == 0
    assert b.outcome == a.outcome == "periodic"
    assert b.transmittance_db == pytest.approx(a.transmittance_db, abs=1e-6)


def test_history_is_the_last_cells_channels_and_the_chains_state():
    r = simulate_chain_point(ChainParams(cell=CELL, n_cells=2), expo(256), history_periods=2)
    h = r.history
    n = len(h["tau"])
    assert h["state"].shape == (n, 12) and n >= 2 * 4  # coarse and fine steps
    np.testing.assert_array_equal(h["s"], h["state"][:, 5])
    np.testing.assert_array_equal(h["s_dot"], h["state"][:, 11])
    assert np.all(np.diff(h["tau"]) > 0)


def test_a_fine_step_that_resolves_no_tip_is_refined():
    # 16 steps a period: the contact gain is too small (as for the unit cell), doubled until not
    cell = dataclasses.replace(CELL, sigma=5.0)
    cs = assemble_chain(ChainParams(cell=cell, n_cells=2))
    run = ChainExponentialRun(cs, expo(16), chain_tail(cs), True, 1e6)
    assert run.spp > 16
    dtf = 2.0 * math.pi / cell.gamma_r / run.spp
    assert np.all(np.diag(run.Gf) >= 0.5 * np.array([s.G for s in cs.cells]) * dtf)


def test_bad_chain_points_are_refused():
    with pytest.raises(ValueError, match=r"cells \[2\] have g1 = g2 = 0"):
        simulate_chain_point(ChainParams(cell=CELL, n_cells=2, g1=(0.1, 0.0), g2=(0.1, 0.0)),
                             expo())  # fmt: skip
    with pytest.raises(ValueError, match="initial_state must be 12 finite numbers"):
        simulate_chain_point(ChainParams(cell=CELL, n_cells=2), expo(),
                             initial_state=np.zeros(6))  # fmt: skip


def test_every_cells_gamma_is_measured_on_the_orbit():
    cp = ChainParams(cell=CELL, n_cells=3)
    r = simulate_chain_point(cp, expo())
    assert r.outcome == "periodic" and r.cells == 3
    # the last cell's is the rows' amplitude: the same steps and in-step extrema
    assert r.cell_transmittance_db[-1] == pytest.approx(r.transmittance_db, abs=1e-9)
    assert len(set(np.round(r.cell_transmittance_db, 6))) == 3
    # every cell as euler sees it at a fine step (euler's first-order error, measured 3.6e-3,
    # 0.9e-3 and 2.9e-3 dB at T/4096)
    e = simulate_chain_point(cp, SolverSettings(method="euler", steps_per_period=4096))
    np.testing.assert_allclose(e.cell_transmittance_db, r.cell_transmittance_db, atol=1e-2)
    far = ChainParams(cell=FAR, n_cells=3)
    r = simulate_chain_point(far, expo())
    assert r.outcome == "linear"
    np.testing.assert_array_equal(r.cell_transmittance_db, chain_linear_transmittance_db(far))
