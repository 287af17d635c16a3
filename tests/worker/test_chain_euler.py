"""The paper's scheme for chains of N cells (``worker/solvers/chain_euler.py``,
``simulate_chain_point``; docs/model.md §11)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from worker.model import CellParams
from worker.model.chain import ChainParams, assemble_chain, chain_linear_transmittance_db
from worker.simulate import SolverSettings, simulate_chain_point, simulate_point
from worker.solvers.chain_euler import ChainEulerRun, chain_tail, engine_view
from worker.solvers.engine import config as engine_config
from worker.solvers.engine import run_point

# A cell whose unit cell impacts both stops once a period (euler, 512 steps: periodic, Γ 0.52 dB)
CELL = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.3, g1=0.1, g2=0.1, modes=2)
FAR = dataclasses.replace(CELL, g1=1e6, g2=1e6)


def euler(n: int, **kw) -> SolverSettings:
    return SolverSettings(method="euler", steps_per_period=n, **kw)


def record(res) -> dict:
    out = res.as_dict()
    out.pop("wall_s")
    return out


@pytest.mark.parametrize("method", ["euler", "event"])
def test_one_cell_is_the_unit_cell_bit_for_bit(method):
    s = SolverSettings(method=method, steps_per_period=256 if method == "euler" else None)
    a = simulate_chain_point(ChainParams(cell=CELL, n_cells=1), s)
    b = simulate_point(CELL, s)
    assert sum(b.impacts_per_period) > 0
    assert record(a) == record(b)
    np.testing.assert_array_equal(a.final_state, b.final_state)


@pytest.mark.parametrize("lcp", ["closed", "lemke"])
@pytest.mark.parametrize("coupling", ["paper", "full"])
def test_the_chain_kernel_at_one_cell_is_the_unit_cells_scheme_bit_for_bit(coupling, lcp):
    # run straight through the engine (simulate_chain_point hands N = 1 to simulate_point)
    cell = dataclasses.replace(CELL, coupling=coupling)
    s = euler(512, lcp=lcp)
    cs = assemble_chain(ChainParams(cell=cell, n_cells=1))
    tail = chain_tail(cs)
    bound = engine_config.DIVERGENCE_FACTOR * max(tail.scale, 0.1)
    a = run_point(lambda: ChainEulerRun(cs, s, tail, True, bound), engine_view(cs), tail, s,
                  np.zeros(2 * cs.ndof))  # fmt: skip
    b = simulate_point(cell, s)
    assert sum(b.impacts_per_period) > 0
    assert record(a) == record(b)


def test_without_stops_gamma_n_converges_at_first_order_to_the_closed_form():
    chain = ChainParams(cell=FAR, n_cells=2)
    ref = chain_linear_transmittance_db(chain)[-1]
    errors = []
    for n in (256, 512, 1024):
        # no linear early stop: the scheme's own periodic orbit (the proof would report the
        # closed form itself)
        r = simulate_chain_point(chain, euler(n, linear_tail=False))
        assert r.outcome == "periodic" and r.response_period == 1
        assert r.impacts_per_period == (0.0, 0.0)
        assert r.transmittance_linear_db == ref
        dt = 2.0 * math.pi / CELL.gamma_r / n
        # first order: measured 0.0165, 0.0084, 0.0042 dB, i.e. 0.87 dB per unit of Δτ
        assert abs(r.transmittance_db - ref) < 2.0 * dt
        errors.append(abs(r.transmittance_db - ref))
    for coarse, fine in zip(errors[:-1], errors[1:], strict=True):
        assert coarse / fine == pytest.approx(2.0, rel=0.3)


def test_without_stops_the_proof_reports_the_chains_closed_form():
    chain = ChainParams(cell=FAR, n_cells=3)
    r = simulate_chain_point(chain, euler(256))
    lin = chain_linear_transmittance_db(chain)
    assert r.outcome == "linear" and r.periods == 0
    assert r.transmittance_db == r.transmittance_linear_db == lin[-1]
    assert r.impact_effect_db == 0.0


def test_an_impacting_two_cell_chain_converges_at_first_order():
    chain = ChainParams(cell=CELL, n_cells=2)
    gammas = []
    for n in (512, 1024, 2048):
        r = simulate_chain_point(chain, euler(n))
        assert r.outcome == "periodic" and r.response_period == 1
        assert sum(r.impacts_per_period) > 0
        gammas.append(r.transmittance_db)
    d = np.diff(gammas)
    # measured: differences 6.8e-3, 3.3e-3 dB, observed order 1.04
    order = math.log2(d[0] / d[1])
    assert 0.7 <= order <= 1.3
    assert r.transmittance_linear_db == chain_linear_transmittance_db(chain)[-1]


def test_every_cell_impacts_on_its_own_stops():
    s = euler(512)
    unit = simulate_point(CELL, s)
    assert sum(unit.impacts_per_period) > 0
    both = simulate_chain_point(ChainParams(cell=CELL, n_cells=2), s)
    assert sum(both.impacts_per_period) > 0
    # one cell's stops moved out of reach at a time: the other cell's impacts remain
    for g in ((0.1, 1e6), (1e6, 0.1)):
        one = simulate_chain_point(ChainParams(cell=CELL, n_cells=2, g1=g, g2=g), s)
        assert one.outcome == "periodic" and sum(one.impacts_per_period) > 0
    # counted over the cells: the chain's total is the sum of the cells' own
    assert sum(both.impacts_per_period) > max(sum(unit.impacts_per_period), 1.0)


def test_lemke_on_the_block_diagonal_lcp_gives_the_closed_forms_trajectory():
    chain = ChainParams(cell=CELL, n_cells=3)
    kw = dict(max_periods=40, window=5, early_stop=False)
    a = simulate_chain_point(chain, euler(512, **kw))
    b = simulate_chain_point(chain, euler(512, lcp="lemke", **kw))
    assert not b.failed
    assert b.contact_steps == a.contact_steps > 0
    assert b.transmittance_db == pytest.approx(a.transmittance_db, abs=1e-9)


def test_impacts_that_die_out_end_in_the_proven_linear_tail():
    # gaps the steady state clears, a start that hits them: impacts, then the proof
    cell = dataclasses.replace(CELL, g1=3.0, g2=3.0)
    chain = ChainParams(cell=cell, n_cells=2)
    x0 = np.zeros(2 * 2 * (cell.modes + 1))
    x0[6 + 0] = 4.0  # cell 1's first modal velocity
    r = simulate_chain_point(chain, euler(256), initial_state=x0)
    assert r.outcome == "linear" and r.periods > 0
    assert r.transmittance_db == chain_linear_transmittance_db(chain)[-1]


def test_the_tail_proof_holds_per_cell():
    chain = ChainParams(cell=dataclasses.replace(CELL, g1=3.0, g2=3.0), n_cells=2)
    tail = chain_tail(assemble_chain(chain))
    assert tail.usable and tail.damped and tail.amp < tail.gate
    assert tail.proves(tail.xp0, 100.0)
    x = tail.xp0.copy()
    x[6 + 3] += 100.0  # cell 2's beam thrown far past its stops
    assert not tail.proves(x, 100.0)


def test_history_is_the_last_cells_channels_and_the_chains_state():
    chain = ChainParams(cell=CELL, n_cells=2)
    r = simulate_chain_point(chain, euler(256), history_periods=2)
    h = r.history
    assert len(h["tau"]) == 512 and h["state"].shape == (512, 12)
    np.testing.assert_array_equal(h["s"], h["state"][:, 5])
    np.testing.assert_array_equal(h["s_dot"], h["state"][:, 11])


def test_other_methods_refuse_chains():
    with pytest.raises(ValueError, match="method 'event'") as err:
        simulate_chain_point(ChainParams(cell=CELL, n_cells=2), SolverSettings(method="event"))
    assert "for chains method must be one of euler, exponential" in str(err.value)


def test_bad_chain_points_are_refused():
    with pytest.raises(ValueError, match="pinned tip"):
        simulate_chain_point(ChainParams(cell=CELL, n_cells=2, g1=(0.1, 0.0), g2=(0.1, 0.0)),
                             euler(256))  # fmt: skip
    with pytest.raises(ValueError, match="initial_state must be 12 finite numbers"):
        simulate_chain_point(ChainParams(cell=CELL, n_cells=2), euler(256),
                             initial_state=np.zeros(6))  # fmt: skip
    with pytest.raises(ValueError, match="unstable"):
        simulate_chain_point(ChainParams(cell=dataclasses.replace(CELL, sigma=50.0), n_cells=2),
                             euler(16))  # fmt: skip
    with pytest.raises(ValueError, match="chain must be a ChainParams"):
        simulate_chain_point(CELL, euler(256))  # type: ignore[arg-type]


def test_every_cells_gamma_is_proven_or_absent():
    # periodic: Γ_j from the orbit run again; the last is the point's Γ_N
    cp = ChainParams(cell=CELL, n_cells=3)
    r = simulate_chain_point(cp, euler(512))
    assert r.outcome == "periodic" and r.cells == 3
    assert len(r.cell_transmittance_db) == 3
    assert r.cell_transmittance_db[-1] == pytest.approx(r.transmittance_db, abs=1e-9)
    assert len(set(np.round(r.cell_transmittance_db, 6))) == 3  # each cell its own
    np.testing.assert_array_equal(r.cell_transmittance_linear_db,
                                  chain_linear_transmittance_db(cp))  # fmt: skip
    # linear: the closed form at every cell
    far = ChainParams(cell=FAR, n_cells=3)
    r = simulate_chain_point(far, euler(512))
    assert r.outcome == "linear"
    np.testing.assert_array_equal(r.cell_transmittance_db, chain_linear_transmittance_db(far))
    # an unproven point has no per-cell Γ; the record names N either way
    r = simulate_chain_point(cp, euler(512, max_periods=30, window=10))
    assert r.outcome == "unsettled" and r.cell_transmittance_db is None
    assert r.as_dict()["cells"] == 3 and "cell_transmittance_db" in r.as_dict()
    # a unit cell's record is what it always was
    assert "cells" not in simulate_point(CELL, euler(512)).as_dict()


def test_a_chain_point_of_a_study_runs_or_fails_with_its_chain_fields():
    from worker.simulate import simulate_chunk

    base = {k: getattr(CELL, k) for k in ("theta", "sigma", "gamma_s", "gamma_r", "xi",
                                          "g1", "g2", "modes", "coupling")}  # fmt: skip
    pts = [
        {**base, "cells": 2},
        {**base, "cells": 2, "cell_g1": [0.1, 0.1], "cell_g2": [0.1, 0.1]},
        {**base, "cells": 2, "cell_g1": [0.1]},
        {**base, "cells": 2, "initial": {"kind": "linear"}},
    ]
    uniform, graded, short, started = simulate_chunk(
        pts, {"method": "euler", "steps_per_period": 512}
    )
    # a graded chain of identical cells is the uniform chain
    uniform.pop("wall_s"), graded.pop("wall_s")
    assert uniform == graded and uniform["cells"] == 2
    assert short["failed"] and "g1 must have one value per cell" in short["reason"]
    assert short["cells"] == 2 and short["cell_transmittance_linear_db"] is None  # no chain
    assert started["failed"] and "starts from rest" in started["reason"]
    # a valid chain that cannot be run keeps its closed form
    assert started["cell_transmittance_linear_db"] == uniform["cell_transmittance_linear_db"]
    assert started["transmittance_linear_db"] == uniform["transmittance_linear_db"]
