"""The engine's tuning constants live in one place (worker/solvers/engine/config.py), each with
what it trades and the tests that pin it (checked by ``audits/config_pins.py``)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from audits.config_pins import CONFIG, comment_blocks, constants, variants
from worker.model import CellParams
from worker.simulate import SolverSettings, simulate_point
from worker.solvers.engine import config as cfg
from worker.solvers.engine import loop

ROOT = Path(__file__).resolve().parents[2]
ENGINE = CONFIG.parent


def test_every_constant_says_what_it_trades_and_names_existing_pins() -> None:
    blocks = {name: "\n".join(block) for name, (_, block) in comment_blocks().items()}
    numbers = constants()
    assert len(numbers) >= 30  # the parser sees them all (a broken parser would pass below)
    for name, (_, pins) in numbers.items():
        assert "Trades:" in blocks[name], f"{name}: no 'Trades:' line"
        assert pins, f"{name}: no 'Pinned by:' line"
        for pin in pins:
            path, _, test = pin.partition("::")
            file = ROOT / path  # tests/worker/<module>.py
            assert file.is_file(), f"{name}: pin {pin}: no such file"
            assert re.search(rf"^def {re.escape(test)}\(", file.read_text(), re.M), (
                f"{name}: pin {pin}: no such test"
            )


def test_the_engine_defines_no_tuning_constant_outside_config() -> None:
    """One place: no other engine module assigns a module-level number in CAPITALS."""
    for path in ENGINE.glob("*.py"):
        if path == CONFIG:
            continue
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
                names = [getattr(t, "id", "") for t in node.targets]
                numeric = isinstance(node.value.value, (int, float))
                bad = [n for n in names if n.isupper() and numeric]
                assert not bad, f"{path.name}: {bad} belongs in config.py"


def test_history_holds_every_shrinking_test() -> None:
    from worker.solvers import measure as ms

    assert cfg.HISTORY == (cfg.SHRINK_RETURNS + 2) * ms.MAX_PERIOD
    assert cfg.RECENT <= cfg.HISTORY


@pytest.mark.parametrize(("value", "expected"), [(4, [2, 8]), (1, [2]), (0.25, [0.125, 0.5])])
def test_audit_variants_always_move_the_value(value: float, expected: list[float]) -> None:
    assert variants(value) == expected


# --------------------------------------------------------------------------- rules' own pins
# Rules no older test holds, each with a point where turning it off changes what the engine
# does (found with ``audits/config_pins.py --off`` and 3,000 random cells, seed 5).

FIG5 = dict(sigma=0.05, gamma_s=1.0, xi=0.05)


def test_an_unstable_orbit_reached_is_not_measured_again_while_near() -> None:
    # Figure 5 at θ 0.3, gap 0.7, γ_r 1.18 with periodicity_tol 1e-6: the samples repeat near
    # an unstable period-3 orbit. Held back UNSTABLE_HOLD returns after each measurement, the
    # engine measures it 12 times; measured at every batch end it would be 176 times, and the
    # point would run 14,000 periods instead of 2,000.
    calls: list[int] = []
    measure = loop._Engine._measure_orbit

    def counted(self, *args):  # noqa: ANN001, ANN202
        calls.append(self.period)
        return measure(self, *args)

    p = CellParams(theta=0.3, gamma_r=1.18, g1=0.7, g2=0.7, **FIG5)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(loop._Engine, "_measure_orbit", counted)
        r = simulate_point(p, SolverSettings(periodicity_tol=1e-6))
    assert r.outcome == "unsettled" and "near an unstable period-3 orbit" in r.reason
    assert len(calls) <= 20 and r.periods <= 3_000


def test_a_slowly_attracting_pending_orbit_is_reached_within_the_budget() -> None:
    # A lightly damped random cell (7 modes, paper coupling): its period-1 orbit attracts at
    # 0.992 a period, too slowly for its returns to come within periodicity_tol of it in the
    # budget. Reached once the trajectory has come REACH_SHRINK times closer at REACH_HOLD
    # returns in a row, it is reported; without that rule the point is unsettled.
    p = CellParams(theta=0.23116053852985946, sigma=0.0037653668033563693,
                   gamma_s=1.3333362810639198, xi=0.003042440793045525,
                   g1=0.026244847284715135, g2=0.026244847284715135,
                   gamma_r=1.014281029212554, coupling="paper", modes=7)  # fmt: skip
    r = simulate_point(p)
    assert r.outcome == "periodic" and r.response_period == 1
    assert 0.98 < r.floquet_multiplier < 1.0


def test_a_drifting_record_is_not_claimed_irregular() -> None:
    # A lightly damped random cell (one mode): its per-period amplitudes drift for hundreds of
    # periods as it approaches a period-1 orbit (multiplier 0.997). The trend test (|t| above
    # MAX_TREND) holds the irregular claim back until the orbit is found; without it the
    # point is claimed irregular at period 600.
    p = CellParams(theta=1.4160297946191949, sigma=0.26183776207595805,
                   gamma_s=2.9657888321921715, xi=0.0014165482210838473,
                   g1=0.008573199480914727, g2=0.007081375187767407,
                   gamma_r=0.5053240828792093, coupling="paper", modes=1)  # fmt: skip
    r = simulate_point(p)
    assert r.outcome == "periodic" and r.response_period == 1
    assert r.periods > 600


def test_the_finite_difference_multiplier_is_the_exact_one() -> None:
    # `exponential` has no exact monodromy matrix: its multiplier is the spectral radius of
    # finite differences of its p-period map (relative step FD_STEP). At an orbit where the
    # map is smooth it matches `event`'s exact matrix to the two methods' own difference.
    p = CellParams(theta=0.3, gamma_r=0.86, g1=0.3, g2=0.3, **FIG5)
    exact = simulate_point(p)
    fd = simulate_point(p, SolverSettings(method="exponential"))
    assert exact.outcome == fd.outcome == "periodic"
    assert exact.response_period == fd.response_period == 1
    assert fd.floquet_multiplier == pytest.approx(exact.floquet_multiplier, abs=1e-3)


def test_a_slowly_approached_orbit_is_fitted_over_all_returns() -> None:
    # A lightly damped random cell (2 modes, full coupling): its pending period-1 orbit attracts
    # so slowly that MAX_RRE returns show too little of the approach; fitted also over all the
    # returns the buffer holds (the map brings deviations less than SLOW_SHRINK closer over
    # MAX_RRE returns), it is reached in the budget. Fitted over MAX_RRE returns only, the point
    # is unsettled.
    p = CellParams(theta=8.180259733498044, sigma=0.029805397331306285,
                   gamma_s=0.9853627459216457, xi=0.0037362875708830635,
                   g1=0.7313964819092309, g2=0.7313964819092309,
                   gamma_r=1.0367115995518963, coupling="full", modes=2)  # fmt: skip
    r = simulate_point(p)
    assert r.outcome == "periodic" and r.response_period == 1
    assert r.floquet_multiplier is not None and r.floquet_multiplier < 1.0
