"""Sweep lines (worker/simulate.py: simulate_line): the state carried from point to point, and
the coexisting responses near grazing that a line shows and a from-rest grid does not
(docs/solvers.md, "Initial states and sweep lines")."""

import pytest

from worker.model import CellParams, assemble, steady_state
from worker.simulate import (
    POINT_KEYS,
    SolverSettings,
    project_admissible,
    simulate_chunk,
    simulate_line,
    simulate_point,
)

# The coexistence example (paper coupling, 5 modes, event): above the mass resonance the
# linear tip amplitude falls with γ_r and equals the gap 0.3 at γ_r ≈ 1.76 (grazing). Beyond
# it the impact-free response is admissible, but an impacting period-1 orbit (two impacts on
# each stop per period) coexists with it: from rest the cell lands on the orbit, from the
# linear state it stays linear.
BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05)
GAP = 0.3
COEX = dict(BASE, gamma_r=1.8, g1=GAP, g2=GAP)
GAMMA_IMPACTING = -9.2147  # dB, from rest: periodic, p = 1
GAMMA_LINEAR = -6.8944  # dB, from the linear state: the closed form


def _same(a: dict, b: dict) -> bool:
    """Records equal in everything but the wall time (and a line's ``started_from``)."""
    drop = {"wall_s", "started_from"}
    return {k: v for k, v in a.items() if k not in drop} == {
        k: v for k, v in b.items() if k not in drop
    }


def _tip_amplitude(pt: dict) -> float:
    sys_ = assemble(CellParams(**{k: pt[k] for k in POINT_KEYS if k in pt}))
    return abs(sys_.W @ steady_state(sys_).U)


# --------------------------------------------------------------------------- coexistence


def test_rest_and_linear_starts_end_on_two_coexisting_responses():
    # the linear response is admissible (tip amplitude 0.279 < 0.3): grazing is just below
    assert 0.9 * GAP < _tip_amplitude(COEX) < GAP
    rest = simulate_chunk([COEX])[0]
    lin = simulate_chunk([dict(COEX, initial={"kind": "linear"})])[0]
    assert rest["outcome"] == "periodic" and rest["response_period"] == 1
    assert rest["impacts_per_period"] == [2.0, 2.0]
    assert rest["transmittance_db"] == pytest.approx(GAMMA_IMPACTING, abs=1e-3)
    assert 0.0 < rest["floquet_multiplier"] < 0.95  # a stable orbit, not a transient
    assert lin["outcome"] == "linear" and lin["periods"] == 0
    assert lin["transmittance_db"] == pytest.approx(GAMMA_LINEAR, abs=1e-3)
    assert lin["transmittance_db"] == rest["transmittance_linear_db"]
    # two responses 2.3 dB apart at the same parameters
    assert lin["transmittance_db"] - rest["transmittance_db"] > 2.0


def test_frequency_sweep_up_and_down_show_hysteresis():
    grid = [1.7, 1.75, 1.8, 1.85, 1.9, 1.95]
    line = [dict(BASE, gamma_r=g, g1=GAP, g2=GAP) for g in grid]
    # up: from the impacting orbit below grazing the orbit is carried through the window
    up = simulate_line(line)
    # down: from the linear state above the window the cell stays linear down to 1.85
    down = simulate_line([dict(pt, initial={"kind": "linear"}) for pt in line[::-1]])[::-1]
    assert [r["started_from"] for r in up] == ["initial"] + ["previous"] * 5
    assert all(r["outcome"] == "periodic" and r["response_period"] == 1 for r in up)
    assert [r["outcome"] for r in down] == ["periodic"] * 3 + ["linear"] * 3
    for g, u, d in zip(grid, up, down, strict=True):
        if g >= 1.85:  # the hysteresis window: both responses, ≥ 1.3 dB apart
            assert d["transmittance_db"] == d["transmittance_linear_db"]
            assert d["transmittance_db"] - u["transmittance_db"] > 1.3
        else:  # below it only the impacting orbit: both sweeps agree
            assert u["transmittance_db"] == pytest.approx(d["transmittance_db"], abs=1e-6)
    assert up[3]["transmittance_db"] == pytest.approx(-9.7633, abs=1e-3)  # γ_r 1.85
    assert down[3]["transmittance_db"] == pytest.approx(-7.5644, abs=1e-3)


def test_gap_sweep_up_and_down_show_hysteresis():
    gaps = [0.25, 0.3, 0.35, 0.4]
    line = [dict(BASE, gamma_r=1.8, g1=g, g2=g) for g in gaps]
    up = simulate_line(line)  # opening the gap: the orbit is kept past grazing (0.279)
    down = simulate_line([dict(pt, initial={"kind": "linear"}) for pt in line[::-1]])[::-1]
    assert all(r["outcome"] == "periodic" for r in up)
    assert [r["outcome"] for r in down] == ["periodic", "linear", "linear", "linear"]
    assert up[0]["transmittance_db"] == pytest.approx(down[0]["transmittance_db"], abs=1e-6)
    for u, d in zip(up[1:], down[1:], strict=True):
        assert d["transmittance_db"] - u["transmittance_db"] > 1.5
    assert up[1]["transmittance_db"] == pytest.approx(GAMMA_IMPACTING, abs=1e-3)
    assert down[1]["transmittance_db"] == pytest.approx(GAMMA_LINEAR, abs=1e-3)


# --------------------------------------------------------------------------- the hand-over


@pytest.mark.parametrize("direction", [1, -1])
def test_a_line_equals_point_by_point_runs_from_the_predecessors(direction):
    pts = [dict(BASE, gamma_r=g, g1=GAP, g2=GAP) for g in (1.75, 1.85, 1.95, 2.1)][::direction]
    line = simulate_line(pts)
    prev = None
    for pt, rec in zip(pts, line, strict=True):
        p = CellParams(**{k: pt[k] for k in POINT_KEYS if k in pt})
        x0 = None if prev is None else project_admissible(assemble(p), prev)
        res = simulate_point(p, initial_state=x0)
        assert _same(rec, res.as_dict())
        assert rec["started_from"] == ("initial" if prev is None else "previous")
        prev = res.final_state
    # the two directions see different responses at γ_r 1.85 and 1.95
    assert len({r["outcome"] for r in line}) == 2


def test_a_lines_first_point_equals_simulate_chunk():
    for pt in (COEX, dict(COEX, initial={"kind": "linear"}),
               dict(COEX, initial={"kind": "random", "seed": 2, "index": 5})):  # fmt: skip
        first = simulate_line([pt, dict(pt, gamma_r=1.85)])[0]
        assert first["started_from"] == "initial"
        assert _same(first, simulate_chunk([pt])[0])
    assert "started_from" not in simulate_chunk([COEX])[0]


def test_gaps_that_shrink_along_a_line_project_the_handed_state():
    # the orbit at gap 0.3 puts the tip on the stops; at gap 0.1 that state is inadmissible
    pts = [dict(COEX), dict(COEX, g1=0.1, g2=0.1)]
    first = simulate_point(CellParams(**COEX))
    sys_ = assemble(CellParams(**pts[1]))
    N = sys_.ndof
    w = float(sys_.W @ first.final_state[:N])
    assert abs(w) > 0.1  # the handed-over tip is beyond the new stops
    line = simulate_line(pts)
    x0 = project_admissible(sys_, first.final_state)
    assert abs(float(sys_.W @ x0[:N])) == pytest.approx(0.1, abs=1e-14)
    direct = simulate_point(CellParams(**pts[1]), initial_state=x0)
    assert line[1]["started_from"] == "previous" and _same(line[1], direct.as_dict())
    assert line[1]["outcome"] == "periodic"


def test_after_a_failed_point_the_next_starts_from_its_own_initial():
    # θ = 500 in the paper coupling diverges (docs/model.md §4); a bad start is refused
    pts = [
        COEX,
        dict(COEX, theta=500.0),
        dict(COEX, initial={"kind": "linear"}),
        dict(COEX, initial={"kind": "nonsense"}),
        COEX,
    ]
    line = simulate_line(pts)
    assert [r["outcome"] for r in line] == ["periodic", "failed", "linear", "failed", "periodic"]
    assert [r["started_from"] for r in line] == [
        "initial", "previous", "initial", "initial", "initial",
    ]  # fmt: skip
    assert "diverged" in line[1]["reason"] and "kind" in line[3]["reason"]
    assert _same(line[2], simulate_chunk([pts[2]])[0])
    assert _same(line[4], simulate_chunk([COEX])[0])


def test_a_change_of_modes_restarts_from_the_initial_state():
    pts = [COEX, dict(COEX, modes=3)]
    line = simulate_line(pts)
    assert [r["started_from"] for r in line] == ["initial", "initial"]
    assert _same(line[1], simulate_chunk([pts[1]])[0])


def test_a_point_over_its_budget_fails_and_the_next_restarts():
    line = simulate_line([COEX, COEX], limits={"steps": 50})
    assert [r["outcome"] for r in line] == ["failed", "failed"]
    assert "step budget" in line[0]["reason"]
    assert [r["started_from"] for r in line] == ["initial", "initial"]


def test_a_cancelled_line_returns_the_points_finished_so_far():
    pts = [dict(BASE, gamma_r=g, g1=GAP, g2=GAP) for g in (1.75, 1.8, 1.85)]
    assert simulate_line(pts, cancelled=lambda: True) == []
    # how often the first point polls (the check before it included)
    polls = {"n": 0}

    def count() -> bool:
        polls["n"] += 1
        return False

    first = simulate_line(pts[:1], cancelled=count)
    n1 = polls["n"]
    assert n1 >= 2  # the point polls between batches too
    # let the first point and the check before the second pass, cancel inside the second
    polls["n"] = 0

    def stop_in_second() -> bool:
        polls["n"] += 1
        return polls["n"] > n1 + 1

    out = simulate_line(pts, cancelled=stop_in_second)
    assert len(out) == 1 and _same(out[0], first[0])
    assert polls["n"] == n1 + 2  # stopped at the second point's first poll


@pytest.mark.parametrize("method", ["event", "exponential", "euler"])
def test_every_method_carries_the_state_and_shows_the_same_hysteresis(method):
    pts = [dict(BASE, gamma_r=g, g1=GAP, g2=GAP) for g in (1.75, 1.85, 1.95)]
    solver = {"method": method}
    up = simulate_line(pts, solver=solver)
    down = simulate_line([dict(pt, initial={"kind": "linear"}) for pt in pts[::-1]],
                         solver=solver)[::-1]  # fmt: skip
    assert [r["outcome"] for r in up] == ["periodic"] * 3
    assert [r["outcome"] for r in down] == ["periodic", "linear", "linear"]
    # the event solver's orbits (exact impacts); euler is first order: 0.015 dB off at 1024
    # steps per period
    for r, ref in zip(up, (-8.7414, -9.7633, -10.1419), strict=True):
        assert r["transmittance_db"] == pytest.approx(ref, abs=0.03)
    assert down[1]["transmittance_db"] == pytest.approx(-7.5644, abs=1e-3)
    # the hand-over is the method's own final state
    p = CellParams(**{k: v for k, v in pts[1].items() if k in POINT_KEYS})
    first = simulate_point(CellParams(**pts[0]), SolverSettings(**solver))
    x0 = project_admissible(assemble(p), first.final_state)
    assert _same(up[1], simulate_point(p, SolverSettings(**solver), initial_state=x0).as_dict())
