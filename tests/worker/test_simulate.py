"""The public door (worker/simulate.py): records, histories, settings, refusals, warm-up."""

import math
import threading
import time

import numpy as np
import pytest

import worker.simulate as simulate
from worker import numba_cache
from worker.model import CellParams, assemble, linear_transmittance_db
from worker.simulate import PointResult, SolverSettings, simulate_chunk, simulate_point
from worker.solvers import measure as ms
from worker.solvers.dispatch import RUNS
from worker.solvers.linear import linear_tail
from worker.solvers.settings import OUTCOMES

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05)


def cell(**kw) -> CellParams:
    return CellParams(**{**BASE, **kw})


def test_every_method_reports_the_same_record():
    keys = None
    for method in ("event", "exponential", "euler"):
        r = simulate_point(cell(gamma_r=0.85), SolverSettings(method=method))
        assert isinstance(r, PointResult) and r.method == method and r.outcome in OUTCOMES
        d = r.as_dict()
        assert keys is None or d.keys() == keys
        keys = d.keys()
    assert {"outcome", "transmittance_db_se", "theta_eff_slope", "floquet_multiplier"} <= keys
    assert not {"converged", "theta_eff_mean"} & keys


@pytest.mark.parametrize("method", ["exponential", "euler"])
def test_a_contact_held_over_a_period_end_carries_into_the_next_batch(method):
    # θ 0.3, gap 0.1, γ_r 1: the period-1 orbit is held on stop 1 at every period end. The
    # episode goes on into the next period, and the next batch (the kernels store a period's
    # row and its contact state apart: a first version of the shared row writer dropped the
    # latter, and 18 of 92 stepping records moved), and is not a new impact there: the
    # time-stepping kernels count what the event solver counts, one impact a stop a period.
    p = cell(gamma_r=1.0, g1=0.1, g2=0.1)
    s = SolverSettings(method=method)
    sys_ = assemble(p)
    run = RUNS[method](sys_, s, linear_tail(sys_), True, 1e6)
    run.reset(np.zeros(run.nx))
    rows, samples = np.zeros((40, ms.ROW)), np.zeros((40, run.nx))
    assert run.advance(40, False, 0, rows, samples)[0] == 40
    assert np.all(rows[20:, ms.M_REGIME] == 1.0)  # held on stop 1 at the period ends
    assert run.kst[ms.K_CONTACT] == 1.0  # and so at the next batch's start
    ref = simulate_point(p, SolverSettings())
    r = simulate_point(p, s)
    assert ref.outcome == r.outcome == "periodic" and ref.response_period == r.response_period
    assert r.impacts_per_period == ref.impacts_per_period == (1.0, 1.0)


def test_amplitude_is_refined_between_samples():
    # 16 steps per period, no early linear proof: the largest sample misses the peak by up to
    # 20log10(cos(π/16)), the refined extremum does not
    p = cell(gamma_r=0.7, g1=1e6, g2=1e6)
    s = SolverSettings(method="exponential", steps_per_period=16, coarse_steps=16,
                       early_stop=False, max_periods=300, window=1)  # fmt: skip
    r = simulate_point(p, s, history_periods=1)
    exact = linear_transmittance_db(p)
    sampled = 20 * math.log10(0.5 * np.ptp(r.history["s"]) / p.base_scale)
    assert abs(r.transmittance_db - exact) < 2e-3
    assert abs(sampled - exact) > 5 * abs(r.transmittance_db - exact)


def test_adaptive_coarse_steps_change_nothing_but_cost():
    p = cell(gamma_r=1.5)
    kw = dict(method="exponential", steps_per_period=1024)
    a = simulate_point(p, SolverSettings(**kw))
    b = simulate_point(p, SolverSettings(**kw, adaptive=False))
    assert a.transmittance_db == pytest.approx(b.transmittance_db, abs=1e-9)
    assert a.coarse_steps > 0 and b.coarse_steps == 0 and a.steps < b.steps


def test_exponential_refines_a_fine_step_that_does_not_resolve_the_tip():
    # σ 10 at γ_r 0.01: T/2048 is longer than a third of the first mode's period
    p = cell(sigma=10.0, gamma_r=0.01, g1=0.0, g2=0.0)
    r = simulate_point(p, SolverSettings(method="exponential"))
    ev = simulate_point(p)
    assert r.steps_per_period > 2048 and r.outcome == ev.outcome == "periodic"
    assert r.transmittance_db == pytest.approx(ev.transmittance_db, abs=1e-6)
    with pytest.raises(ValueError, match="does not resolve the tip's modes"):
        simulate_point(
            cell(sigma=1e5, gamma_r=1e-4, g1=0.0, g2=0.0), SolverSettings(method="exponential")
        )


def test_euler_beyond_its_stability_limit_is_refused_with_the_largest_step():
    p = cell(gamma_r=0.3)
    T = 2 * math.pi / 0.3
    wmax = assemble(p).omega_max()
    n_unstable = math.floor(T * wmax / 2) - 1  # Δτ·ω̃_max > 2
    with pytest.raises(ValueError, match=r"largest stable step is Δτ < 0\.0447"):
        simulate_point(p, SolverSettings(method="euler", steps_per_period=n_unstable))
    # Explicit damping of the stiff modes makes the real limit tighter than 2/ω̃_max.
    with pytest.raises(
        ValueError, match=r"with this damping; the largest stable step is Δτ ≈ 0\.0425"
    ):
        simulate_point(p, SolverSettings(method="euler", steps_per_period=n_unstable + 3))
    r = simulate_point(p, SolverSettings(method="euler", steps_per_period=math.ceil(T / 0.042)))
    assert not r.failed and math.isfinite(r.transmittance_db)


@pytest.mark.parametrize("method", ["event", "exponential", "euler"])
def test_history_is_the_reported_response(method):
    r = simulate_point(cell(gamma_r=0.85), SolverSettings(method=method), history_periods=2)
    h = r.history
    keys = {"tau", "s", "w_tip", "s_b", "s_dot", "s_b_dot", "theta_eff", "impulse1", "impulse2",
            "kind", "state"}  # fmt: skip
    assert keys <= set(h)
    n = len(h["tau"])
    assert n > 0 and all(len(h[k]) == n for k in keys)
    assert np.all(np.diff(h["tau"]) >= 0) and h["tau"][-1] == pytest.approx(
        2 * 2 * math.pi / 0.85, rel=1e-9
    )
    assert np.max(h["w_tip"]) <= 0.1 * (1 + 1e-9) and np.min(h["w_tip"]) >= -0.1 * (1 + 1e-9)
    # the history is the orbit: its range is the reported amplitude
    amp = 0.5 * (h["s"].max() - h["s"].min())
    assert amp == pytest.approx(r.amplitude, rel=2e-3)  # samples at sub-steps miss the peak
    assert simulate_point(cell(gamma_r=0.85)).history is None


def test_the_history_of_an_orbit_with_many_events_a_period_is_whole():
    # a random cell of orbit_audit (--random 3000 --seed 5): 10 modes, gaps 0.0016, an orbit
    # with more events a period than the history buffer's 64: its oldest rows dropped out, and
    # the history began 1.1 periods into the orbit. The orbit is period 3 but nearly period 1
    # (its states one period apart differ by ~5e-4 of the state's size), so which it is may
    # depend on the CPU's rounding: the test reads the period from the result.
    p = CellParams(theta=0.044887161146510715, sigma=0.584553291097932,
                   gamma_s=2.894713468440343, xi=0.013697696577168397,
                   g1=0.0015904847533030346, g2=0.0015904847533030346,
                   gamma_r=0.6677594811720176, coupling="full", modes=10)  # fmt: skip
    probe = simulate_point(p)
    assert probe.outcome == "periodic"
    n = probe.response_period
    r = simulate_point(p, history_periods=n)
    assert (r.outcome, r.response_period) == ("periodic", n)
    h = r.history
    T = 2 * math.pi / p.gamma_r
    assert len(h["events"]) > n * 64  # the case: more events than the buffer holds
    # from one sub-grid interval into the orbit to its end, and the states at its period ends:
    # back at the orbit's start after n periods, and not before (n is the smallest period:
    # every earlier period end is farther from the start than the periodicity tolerance)
    assert h["tau"][0] <= T / 32 and h["tau"][-1] == pytest.approx(n * T, rel=1e-9)
    ends = [h["state"][np.flatnonzero(np.isclose(h["tau"], k * T, rtol=0, atol=1e-9 * T))[-1]]
            for k in range(1, n + 1)]  # fmt: skip
    scale = np.max(np.abs(r.final_state))
    assert np.max(np.abs(ends[-1] - r.final_state)) <= 1e-8 * scale
    tol = SolverSettings().periodicity_tol
    assert all(np.max(np.abs(e - r.final_state)) > 10 * tol * scale for e in ends[:-1])
    # early stop off: the run's last n periods, whole too
    # (on the run's own clock, as where nothing overflows)
    off = simulate_point(p, SolverSettings(early_stop=False, max_periods=600), history_periods=n)
    end = 600 * T  # the budget: early stop off runs it all
    assert off.history["tau"][0] - (end - n * T) <= T / 32
    assert off.history["tau"][-1] == pytest.approx(end, rel=1e-9)
    # and a history longer than the samples the engine keeps (319 periods): its first period
    # end is reached again from the start, not from where the kept samples begin
    long = simulate_point(p, SolverSettings(early_stop=False, max_periods=600),
                          history_periods=400)  # fmt: skip
    h = long.history
    assert h["tau"][0] - (end - 400 * T) <= T / 32
    assert h["tau"][-1] == pytest.approx(end, rel=1e-9)
    # the same trajectory: it ends where the short history does (to round-off: the runs are
    # split into other batches)
    scale = np.max(np.abs(off.history["state"][-1]))
    np.testing.assert_allclose(h["state"][-1], off.history["state"][-1], rtol=0,
                               atol=1e-12 * scale)  # fmt: skip


def test_history_of_a_linear_point_is_the_closed_form_orbit():
    p = cell(gamma_r=4.5, g1=1e6, g2=1e6)
    r = simulate_point(p, history_periods=1)
    assert r.outcome == "linear" and r.periods == 0
    amp = 0.5 * (r.history["s"].max() - r.history["s"].min())
    assert amp == pytest.approx(r.amplitude, rel=2e-3)


def test_asymmetric_gaps_hit_only_the_near_stop():
    r = simulate_point(cell(gamma_r=0.85, g1=0.1, g2=1e6), history_periods=1)
    assert r.impacts_per_period[0] >= 1 and r.impacts_per_period[1] == 0
    assert np.min(r.history["w_tip"]) < -0.1  # it swings past where stop 2 would be


def test_non_finite_start_marks_the_point_failed_without_nan():
    sys_ = assemble(cell(gamma_r=1.0))
    x0 = np.full(2 * sys_.ndof, 1e300)
    r = simulate_point(cell(gamma_r=1.0), initial_state=x0)
    assert r.failed and r.transmittance_db is None and r.reason
    with pytest.raises(ValueError, match="initial_state must be 12 finite numbers"):
        simulate_point(cell(gamma_r=1.0), initial_state=np.zeros(3))


def test_chunk_reports_bad_points_instead_of_raising():
    pts = [dict(BASE, gamma_r=1.0, g1=1e6, g2=1e6), dict(BASE, gamma_r=-1.0, g1=0.1, g2=0.1)]
    out = simulate_chunk(pts, {"max_periods": 200})
    assert len(out) == 2
    assert out[0]["outcome"] == "linear" and out[0]["transmittance_db"] is not None
    assert out[1]["failed"] and out[1]["outcome"] == "failed"
    assert "gamma_r must be > 0, got -1.0" in out[1]["reason"]
    assert out[1]["transmittance_db"] is None and out[0].keys() == out[1].keys()


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"method": "rk4"}, "method must be one of event, exponential, euler, got 'rk4'"),
        ({"steps_per_period": 2}, "steps_per_period must be an integer in 4"),
        ({"max_periods": 10, "window": 10}, "window must be < max_periods"),
        ({"periodicity_tol": 0.0}, r"periodicity_tol must be > 0, got 0.0; allowed range \(0, "),
        ({"stat_tol_db": float("nan")}, "stat_tol_db must be finite, got nan"),
        ({"extrapolate": "yes"}, "extrapolate must be true or false"),
        ({"lcp": "pgs"}, "lcp must be one of closed, lemke"),
        ({"max_events_per_period": 0}, "max_events_per_period must be an integer in 1"),
        (
            {"method": "euler", "max_events_per_period": 10},
            "max_events_per_period applies to method 'event' only, got method 'euler'",
        ),
        ({"transient_guard": -1}, "transient_guard must be an integer in 0"),
        (
            {"max_periods": 400, "transient_guard": 401},
            r"transient_guard must be <= max_periods \(400\).*got 401",
        ),
    ],
)
def test_bad_solver_settings(kw, message):
    with pytest.raises(ValueError, match=message):
        SolverSettings(**kw)


def test_defaults():
    s = SolverSettings()
    assert s.method == "event" and s.early_stop and s.extrapolate
    assert s.periodicity_tol == 1e-9 and s.stat_tol_db == 0.1


def test_first_compilation_says_what_it_does(monkeypatch, capsys):
    monkeypatch.setattr(simulate, "_warm", set())
    monkeypatch.setattr(simulate, "kernels_cached", lambda method: False)
    simulate.warm_up("euler")
    err = capsys.readouterr().err
    assert "compiling the numba kernels of method 'euler'" in err and "usually" in err
    assert "kernels ready in" in err
    monkeypatch.setattr(simulate, "_warm", set())
    monkeypatch.setattr(simulate, "kernels_cached", lambda method: True)
    simulate.warm_up("euler")
    assert capsys.readouterr().err == ""


def test_warm_up_waits_for_another_process_compiling_the_method(monkeypatch, capsys):
    # the lock held here stands for a second process compiling euler into the same cache
    monkeypatch.setattr(simulate, "_warm", set())
    monkeypatch.setattr(simulate, "cache_ready", lambda method=None: False)
    said = []
    say = simulate._say_waiting
    monkeypatch.setattr(simulate, "_say_waiting", lambda m: (say(m), said.append(m)))
    with numba_cache.exclusive("warm-euler"):
        t = threading.Thread(target=simulate.warm_up, args=("euler",), daemon=True)
        t.start()
        deadline = time.monotonic() + 30  # a loaded machine may start the thread late
        while not said and time.monotonic() < deadline:
            time.sleep(0.01)
        assert t.is_alive() and "euler" in simulate._warm
    t.join(120)
    assert not t.is_alive()
    err = capsys.readouterr().err
    assert "another process is compiling method 'euler' into the same cache" in err


def test_kernels_are_in_the_on_disk_cache_after_warm_up():
    simulate.warm_up()
    assert all(simulate.kernels_cached(m) for m in ("event", "exponential", "euler"))
