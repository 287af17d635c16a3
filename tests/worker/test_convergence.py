"""Convergence of the time-stepping methods to the event-driven solution, in the style of
scikit-fem's ``tests/test_convergence.py``: one class per method with its expected order; each
checks the fitted rate *and* a bound on the finest error.

The reference is the event solver at tight settings (256 sub-grid intervals, events to 1e-13
of a period). Points are periodic impacting orbits of both couplings.
"""

import numpy as np
import pytest

from worker.model import CellParams
from worker.simulate import SolverSettings, simulate_point

POINTS = {
    "paper-0.85": dict(gamma_r=0.85, coupling="paper"),
    "full-2.0": dict(gamma_r=2.0, coupling="full"),
}


def cell(name: str) -> CellParams:
    return CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, g1=0.1, g2=0.1, **POINTS[name])


@pytest.fixture(scope="module")
def reference():
    out = {}
    for name in POINTS:
        r = simulate_point(cell(name), SolverSettings(steps_per_period=256, periodicity_tol=1e-11),
                           event_tol=1e-13)  # fmt: skip
        assert r.outcome == "periodic" and sum(r.impacts_per_period) > 0
        out[name] = r
    return out


class ConvergenceEuler:
    """The paper's scheme: first order in Δτ."""

    method = "euler"
    steps = (2048, 4096, 8192, 16384)
    rate = 1.0
    rate_tol = 0.2  # the fitted rate is rate ± rate_tol (None: at least rate)
    finest = 2e-3  # dB

    def errors(self, name, reference):
        out = []
        for n in self.steps:
            r = simulate_point(cell(name), SolverSettings(method=self.method, steps_per_period=n))
            assert r.outcome == "periodic"
            assert r.response_period == reference[name].response_period
            out.append(abs(r.transmittance_db - reference[name].transmittance_db))
        return np.array(out)

    @pytest.mark.parametrize("name", list(POINTS))
    def test_convergence(self, name, reference):
        err = self.errors(name, reference)
        h = 1.0 / np.array(self.steps)
        fitted = np.polyfit(np.log(h), np.log(err), 1)[0]
        if self.rate_tol is None:
            assert fitted >= self.rate
        else:
            assert fitted == pytest.approx(self.rate, abs=self.rate_tol)
        assert err[-1] < self.finest


class TestConvergenceEuler(ConvergenceEuler):
    pass


class TestConvergenceEulerLemke(ConvergenceEuler):
    """The same scheme with Lemke's algorithm at every step: the same trajectory."""

    steps = (2048, 4096)
    rate_tol = 0.3

    def errors(self, name, reference):
        out = []
        for n in self.steps:
            kw = dict(method="euler", steps_per_period=n)
            a = simulate_point(cell(name), SolverSettings(**kw, lcp="lemke"))
            b = simulate_point(cell(name), SolverSettings(**kw))
            assert a.transmittance_db == pytest.approx(b.transmittance_db, abs=1e-9)
            out.append(abs(a.transmittance_db - reference[name].transmittance_db))
        return np.array(out)

    @pytest.mark.parametrize("name", list(POINTS))
    def test_convergence(self, name, reference):
        err = self.errors(name, reference)
        assert err[1] < err[0]


class TestConvergenceExponential(ConvergenceEuler):
    """Exact free flight; impact timing is first order in the fine step at worst (observed
    1.5–2.5 on these orbits, with the ups and downs of where impacts fall in a step)."""

    method = "exponential"
    steps = (256, 1024, 4096, 16384)
    rate_tol = None
    finest = 1e-5


class TestEventSubGrid:
    """The event solver's sub-grid sets the cost, not the answer: no convergence, agreement."""

    @pytest.mark.parametrize("name", list(POINTS))
    def test_every_sub_grid_gives_the_reference(self, name, reference):
        for n in (8, 16, 64, 128):
            r = simulate_point(cell(name), SolverSettings(steps_per_period=n))
            assert r.response_period == reference[name].response_period
            assert r.transmittance_db == pytest.approx(reference[name].transmittance_db, abs=1e-8)
