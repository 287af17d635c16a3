"""Work–precision of every solver against a tight event-driven reference ("fast and accurate").

    python benchmarks/work_precision.py [--quick] [--points N] [--out benchmarks/results]

Cases: three 60-point spectra, γ_r = 0.2 … 6 (as ``benchmarks/spectrum.py``), γ_s 1, ξ 0.05,
gaps 0.1, five modes: θ 0.3, σ 0.05 in both couplings, and θ 1, σ 0.1 (paper coupling).

Reference: ``event`` with a 256-interval sub-grid, ``event_tol`` 1e-13 and ``periodicity_tol``
1e-11 (1e-12 is below the event-time noise floor and never confirms some orbits). Its
self-consistency is the difference to a second tight setting (128 intervals, ``event_tol``
1e-11, ``periodicity_tol`` 1e-10).

Every point ends with an ``outcome`` (linear, periodic, irregular, unsettled, failed), recorded
per point. Errors: |ΔΓ| (dB) and |Δθ_eff| (harmonic θ_eff) at points that are ``periodic`` in
the reference and periodic (or linear) with the same period in the method, and separately |ΔΓ|
at points ``linear`` in the reference that the method reports with period 1. A ``linear`` point
reports the closed form exactly; a method's own accuracy on impact-free points is measured with
``linear_tail=False`` (an ablation row). Points where the classification differs (converged vs
not, or another period) are counted, not measured. Irregular points have no pointwise limit:
their Γ is a mean over windows with a standard error, so at points irregular in both the
difference is reported relative to the combined standard error,
``z = |ΔΓ| / sqrt(se_ref² + se²)`` (median, and the fraction with z <= 3).

Methods: ``event`` (the default: sub-grid 64, ``event_tol`` 1e-12) over its sub-grid and
``event_tol``; ``exponential`` over ``steps_per_period``; ``euler`` (numba, closed-form LCP)
over ``steps_per_period`` (the finest on a subset of points); ``euler`` with the compiled Lemke
solver at every step (``lcp="lemke"``, the scheme as published); ablations of the default
(``early_stop``, ``extrapolate``, ``linear_tail`` off) on case A; a plain Python/NumPy port of
the paper's scheme (Lemke's algorithm at every step, in pure Python) and
``scipy.integrate.solve_ivp`` (LSODA) with a penalty spring-dashpot at the stops, both on a few
points only.

Time per point is the wall time of the whole ``simulate_point`` call (assembly, matrix
exponentials and kernel), in one single-threaded process.

Writes ``work_precision.csv`` (one row per method setting), ``work_precision_points.csv`` (one
row per point and setting), ``work_precision.md`` and ``work_precision.png`` to the output
folder.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import platform
import statistics
import sys
import time
import types
from dataclasses import dataclass, field, replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402
from numba.core.dispatcher import Dispatcher  # noqa: E402

from worker.model import CellParams, assemble, linear_transmittance_db  # noqa: E402
from worker.simulate import PointResult, SolverSettings, simulate_point, warm_up  # noqa: E402
from worker.solvers.event.driver import DEFAULT_EVENT_TOL, DEFAULT_GRID  # noqa: E402
from worker.solvers.lcp import LEMKE_OK, lemke_nb, lemke_workspace, two_stop_matrix  # noqa: E402

GAMMAS = np.linspace(0.2, 6.0, 60)
CASES = {
    "A": dict(theta=0.3, sigma=0.05, coupling="paper"),
    "B": dict(theta=0.3, sigma=0.05, coupling="full"),
    "C": dict(theta=1.0, sigma=0.1, coupling="paper"),
}
CASE_TEXT = {
    "A": "θ 0.3, σ 0.05, paper coupling",
    "B": "θ 0.3, σ 0.05, full coupling",
    "C": "θ 1, σ 0.1, paper coupling",
}
REF_GRID, REF_TOL, REF_PTOL = 256, 1e-13, 1e-11
CHK_GRID, CHK_TOL, CHK_PTOL = 128, 1e-11, 1e-10
MAX_PERIODS = SolverSettings().max_periods
TARGET_DB = 1e-6
Z_OK = 3.0  # irregular points: |ΔΓ| within this many combined standard errors


def event_tag(grid: int, tol: float) -> str:
    default = (grid, tol) == (DEFAULT_GRID, DEFAULT_EVENT_TOL)
    return f"grid {grid}, tol {tol:.0e}" + (" (default)" if default else "")


DEFAULT = ("event", event_tag(DEFAULT_GRID, DEFAULT_EVENT_TOL))
FAMILIES = ("event", "exponential", "euler", "euler + Lemke")  # the method families compared
IVP_WALL_CAP = 60.0  # seconds per solve_ivp point; beyond it the point is reported unfinished
IVP_WALL_CAP_QUICK = 10.0
PORT_PERIODS_QUICK = 5  # --quick: periods of the Python port (a smoke run, not a measurement)


def cell(case: str, g: float) -> CellParams:
    return CellParams(gamma_s=1.0, gamma_r=float(g), xi=0.05, g1=0.1, g2=0.1, **CASES[case])


@dataclass
class Rec:
    """One point of one method setting."""

    case: str
    idx: int
    outcome: str  # linear, periodic, irregular, unsettled, failed
    db: float | None
    se: float | None
    theta_eff: float | None
    period: int  # response period (linear 1), 0 irregular/unsettled, -1 failed
    wall: float  # whole call, s
    steps: int = 0
    contact_steps: int = 0
    coarse_steps: int = 0
    periods: int = 0  # all periods integrated, side runs included
    steady_period: int = 0  # periods of the main trajectory
    n_sub: int = 1
    spp: int = 0
    note: str = ""
    reason: str = ""

    @property
    def converged(self) -> bool:
        return self.outcome in ("linear", "periodic")


def rec_of(case: str, idx: int, r: PointResult, wall: float, n_sub: int = 1) -> Rec:
    period = -1 if r.failed else (r.response_period if r.converged else 0)
    return Rec(case, idx, r.outcome, r.transmittance_db, r.transmittance_db_se, r.theta_eff,
               period, wall, r.steps, r.contact_steps, r.coarse_steps, r.periods,
               r.steady_period, n_sub, r.steps_per_period, reason=r.reason)  # fmt: skip


def run_numba(case: str, idx: int, settings: SolverSettings, **kw) -> Rec:
    p = cell(case, GAMMAS[idx])
    note = ""
    while True:
        t0 = time.perf_counter()
        try:
            r = simulate_point(p, settings, **kw)
        except ValueError as exc:
            # euler refuses unstable steps (long periods at low γ_r): double the resolution
            if settings.method == "euler" and "unstable" in str(exc):
                settings = replace(settings, steps_per_period=2 * settings.steps_per_period)
                note = "raised"
                continue
            r = PointResult.failure(settings.method, f"refused: {exc}")
        break
    wall = time.perf_counter() - t0
    n_sub = 1
    if settings.method == "exponential":
        spp = settings.steps_per_period or 2048
        n_sub = spp // min(settings.coarse_steps, spp)
    rec = rec_of(case, idx, r, wall, n_sub)
    rec.note = note
    return rec


@dataclass
class Row:
    family: str
    setting: str
    recs: list[Rec] = field(default_factory=list)
    subset: bool = False
    extra: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- the paper's scheme,
# written out in Python/NumPy (one step = the formulas of docs/model.md §5, Lemke at every step)


def pure_python(fn: Dispatcher) -> types.FunctionType:
    """The plain-Python body of a numba function, with the numba functions it calls replaced by
    their plain-Python bodies too (``fn.py_func`` alone would still call compiled helpers)."""
    f = fn.py_func
    glb = {k: (v.py_func if isinstance(v, Dispatcher) else v) for k, v in f.__globals__.items()}
    return types.FunctionType(f.__code__, glb, f.__name__, f.__defaults__, f.__closure__)


lemke_py = pure_python(lemke_nb)


def python_paper_scheme(p: CellParams, spp: int, periods: int, measure: int) -> tuple[float, float]:
    """Γ (dB) and wall time of the paper's scheme run for ``periods`` periods, measured over the
    last ``measure`` (amplitude from the step ends, no sub-step refinement)."""
    t0 = time.perf_counter()
    s = assemble(p)
    N = s.ndof
    Minv = s.Minv
    MX = Minv @ s.X
    W = s.W
    dt = 2.0 * math.pi / p.gamma_r / spp
    Mlcp = two_stop_matrix(s.G * dt)
    ws = lemke_workspace(2)
    es = np.zeros(N)
    es[-1] = 1.0
    u = np.zeros(N)
    q = np.zeros(N)
    smax, smin = -math.inf, math.inf
    start = (periods - measure) * spp
    for k in range(periods * spp):
        tau = k * dt
        h = -s.C @ q - s.K @ u + es * (s.f_sin * math.sin(p.gamma_r * tau)
                                       + s.f_cos * math.cos(p.gamma_r * tau))  # fmt: skip
        qf = q + Minv @ h * dt
        wpred = W @ (u + qf * dt)
        if lemke_py(Mlcp, np.array([p.g1 - wpred, p.g2 + wpred]), *ws, 50) != LEMKE_OK:
            raise RuntimeError(f"Lemke did not solve the two-stop LCP at step {k}")
        lam = ws[-1]
        q = qf + MX * (lam[1] - lam[0])
        u = u + q * dt
        if k >= start:
            smax = max(smax, u[-1])
            smin = min(smin, u[-1])
    wall = time.perf_counter() - t0
    return 20.0 * math.log10(0.5 * (smax - smin) / p.base_scale), wall


# --------------------------------------------------------------------------- solve_ivp, penalty


class _Timeout(Exception):
    pass


def ivp_penalty(p: CellParams, periods: int, measure: int, k_factor: float, rtol: float,
                cap: float):  # fmt: skip
    """Γ (dB), wall time and f-evaluations of LSODA on the penalty-regularised model.

    Each stop is a unilateral spring-dashpot, force ``max(0, k δ + c δ̇)`` while penetrated by
    δ, with ``k = k_factor · σβ_1⁴`` (the first beam mode's modal stiffness) and critical
    damping ``c = 2√(k/G)`` for the tip's effective mass ``1/G``, which makes the impacts
    nearly plastic. Amplitude from dense output at 4096 samples per period. Gives up (Γ None)
    after ``cap`` seconds.
    """
    from scipy.integrate import solve_ivp

    t0 = time.perf_counter()
    s = assemble(p)
    N = s.ndof
    A = s.state_matrix()
    MX = s.Minv @ s.X
    fs = s.Minv[:, -1]
    W = s.W
    k = k_factor * s.K[0, 0]
    c = 2.0 * math.sqrt(k / s.G)
    g = p.gamma_r
    KW = np.outer(MX, W)
    nfev = [0]

    def force(x):
        w = W @ x[:N]
        wd = W @ x[N:]
        if w > p.g1:
            return -max(0.0, k * (w - p.g1) + c * wd)
        if w < -p.g2:
            return max(0.0, k * (-p.g2 - w) - c * wd)
        return 0.0

    def f(t, x):
        nfev[0] += 1
        if nfev[0] % 2000 == 0 and time.perf_counter() - t0 > cap:
            raise _Timeout
        dx = A @ x
        dx[N:] += fs * (s.f_sin * math.sin(g * t) + s.f_cos * math.cos(g * t))
        P = force(x)
        if P:
            dx[N:] += MX * P
        return dx

    def jac(t, x):
        J = A.copy()
        if force(x) != 0.0:
            J[N:, :N] -= k * KW
            J[N:, N:] -= c * KW
        return J

    T = 2.0 * math.pi / g
    try:
        sol = solve_ivp(f, (0.0, periods * T), np.zeros(2 * N), method="LSODA", rtol=rtol,
                        atol=rtol * 1e-2, jac=jac, dense_output=True)  # fmt: skip
    except _Timeout:
        return None, time.perf_counter() - t0, nfev[0]
    tt = np.linspace((periods - measure) * T, periods * T, 4096 * measure + 1)
    sv = sol.sol(tt)[N - 1]
    wall = time.perf_counter() - t0
    return 20.0 * math.log10(0.5 * (sv.max() - sv.min()) / p.base_scale), wall, nfev[0]


# --------------------------------------------------------------------------- statistics


def _max(v: list[float]) -> float:
    return max(v) if v else math.nan


def _median(v: list[float]) -> float:
    return statistics.median(v) if v else math.nan


def z_score(r: Rec, f: Rec) -> float:
    """|ΔΓ| of two irregular points over their combined standard error."""
    d = abs(r.db - f.db)
    se = math.hypot(f.se or 0.0, r.se or 0.0)
    return d / se if se > 0.0 else (0.0 if d == 0.0 else math.inf)


def compare(row: Row, ref: dict) -> dict:
    """Error statistics of a row against the reference (keyed by (case, idx))."""
    d_db, d_th, d_lin, d_irr, z_irr = [], [], [], [], []
    mismatch = failed = per_miss = 0
    for r in row.recs:
        f = ref[(r.case, r.idx)]
        if f.outcome == "periodic" and not (r.converged and r.period == f.period):
            per_miss += 1  # a periodic reference point the method does not reproduce
        if r.period < 0 or r.db is None:
            failed += 1
            continue
        if f.period < 0:
            continue  # the reference failed: nothing to compare with
        if f.converged and r.converged and r.period == f.period:
            if f.outcome == "linear":
                d_lin.append(abs(r.db - f.db))
            else:
                d_db.append(abs(r.db - f.db))
                if r.theta_eff is not None and f.theta_eff is not None:
                    d_th.append(abs(r.theta_eff - f.theta_eff))
        elif f.outcome == "irregular" and r.outcome == "irregular":
            d_irr.append(abs(r.db - f.db))
            z_irr.append(z_score(r, f))
        elif f.converged or r.converged:
            mismatch += 1  # converged vs not, or another period
        # irregular vs unsettled (either way) or both unsettled: no limit to compare with
    walls = [r.wall for r in row.recs]
    conv = [r for r in row.recs if r.converged]
    stepped = [r for r in row.recs if r.period >= 0]
    outcomes = {o: sum(r.outcome == o for r in row.recs) for o in
                ("linear", "periodic", "irregular", "unsettled", "failed")}  # fmt: skip
    out = {
        "n_points": len(row.recs),
        "n_compared": len(d_db),
        "max_db": _max(d_db),
        "median_db": _median(d_db),
        "max_theta": _max(d_th),
        "median_theta": _median(d_th),
        "per_miss": per_miss,
        "n_linear_cmp": len(d_lin),
        "max_db_linear": _max(d_lin),
        "n_irr": len(d_irr),
        "irr_median_db": _median(d_irr),
        "irr_median_z": _median(z_irr),
        "irr_within_z": (sum(z <= Z_OK for z in z_irr) / len(z_irr)) if z_irr else math.nan,
        "mismatch": mismatch,
        "failed": failed,
        **{f"n_{o}": n for o, n in outcomes.items()},
        "t_median_ms": 1e3 * statistics.median(walls) if walls else math.nan,
        "t_mean_ms": 1e3 * statistics.fmean(walls) if walls else math.nan,
        "steps_mean": statistics.fmean(r.steps for r in stepped) if stepped else 0.0,
        "contact_mean": statistics.fmean(r.contact_steps for r in stepped) if stepped else 0.0,
        # periods saved by the early stop, over the budget of the converged points (all periods
        # integrated, side runs included)
        "saved_periods_pct": (
            100.0 * sum(MAX_PERIODS - r.periods for r in conv) / (MAX_PERIODS * len(conv))
            if conv and row.family not in ("python port", "solve_ivp")
            else math.nan
        ),
        "coarse_mean": statistics.fmean(r.coarse_steps for r in stepped) if stepped else 0.0,
        "fine_saved_mean": (
            statistics.fmean(r.coarse_steps * (r.n_sub - 1) for r in stepped) if stepped else 0.0
        ),
    }
    return out


def within_target(st: dict) -> bool:
    """Within TARGET_DB of the reference at every point periodic in both (as target 1)."""
    return st["n_compared"] > 0 and st["max_db"] <= TARGET_DB


def fmt(x: float | None, spec: str = ".2e") -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def loglog_at(xs: list[float], ys: list[float], y0: float) -> tuple[float, bool]:
    """x where the log–log line through (x, y) reaches y0: interpolated between bracketing
    points, else extrapolated from the two most accurate ones. Returns (x, extrapolated)."""
    pts = sorted(zip(ys, xs, strict=True), reverse=True)  # decreasing error
    for (ya, xa), (yb, xb) in zip(pts, pts[1:], strict=False):
        if yb <= y0 <= ya:
            if ya == yb:
                return xa, False
            s = (math.log(y0) - math.log(ya)) / (math.log(yb) - math.log(ya))
            return math.exp(math.log(xa) + s * (math.log(xb) - math.log(xa))), False
    (ya, xa), (yb, xb) = pts[-2], pts[-1]
    if y0 > pts[0][0]:
        (ya, xa), (yb, xb) = pts[0], pts[1]
    slope = (math.log(xb) - math.log(xa)) / (math.log(yb) - math.log(ya))
    return math.exp(math.log(xb) + slope * (math.log(y0) - math.log(yb))), True


def machine() -> str:
    """What the timings ran on."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    load = ""
    if hasattr(os, "getloadavg"):
        load = f", load average {os.getloadavg()[0]:.1f} at the end"
    return (
        f"{model}, {os.cpu_count()} logical cores ({usable} usable); one single-threaded "
        f"process (OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}), "
        f"Python {platform.python_version()}{load}"
    )


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="few settings and points (smoke run)")
    ap.add_argument("--points", type=int, default=None, help="points per spectrum (of 60)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    ap.add_argument("--no-plot", action="store_true")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    command = " ".join(["python benchmarks/work_precision.py", *argv])
    quick = args.quick
    npts = args.points or (4 if quick else 60)
    if not 1 <= npts <= 60:
        ap.error("--points must be in 1…60")
    idx_all = sorted({int(round(i)) for i in np.linspace(0, 59, npts)})
    # subsets for the expensive settings: every 3rd point (20 per spectrum), every 6th (10)
    idx_sub = idx_all if quick else idx_all[::3]
    idx_fine = idx_all if quick else idx_all[::6]  # 10 per spectrum
    ivp_cap = IVP_WALL_CAP_QUICK if quick else IVP_WALL_CAP
    args.out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    warm_up()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t_start:7.1f} s] {msg}", flush=True)

    def sweep(family, setting, settings, idx, subset=False, cases=CASES, **kw) -> Row:
        row = Row(family, setting, subset=subset)
        for case in cases:
            for i in idx:
                row.recs.append(run_numba(case, i, settings, **kw))
        log(f"{family} {setting}: {sum(r.wall for r in row.recs):.1f} s")
        return row

    # ---- reference and its self-consistency
    ref_set = SolverSettings(method="event", steps_per_period=REF_GRID, periodicity_tol=REF_PTOL)
    ref_row = sweep("reference", "event 256, tol 1e-13", ref_set, idx_all, event_tol=REF_TOL)
    ref = {(r.case, r.idx): r for r in ref_row.recs}
    chk_set = SolverSettings(method="event", steps_per_period=CHK_GRID, periodicity_tol=CHK_PTOL)
    chk_row = sweep("reference check", "event 128, tol 1e-11", chk_set, idx_all,
                    event_tol=CHK_TOL)  # fmt: skip
    chk = compare(chk_row, ref)

    rows: list[Row] = []
    # ---- event (the default first: the ablations and the targets refer to it)
    assert SolverSettings().method == DEFAULT[0], "the default method changed: update DEFAULT"
    default_row = sweep(*DEFAULT, SolverSettings(), idx_all)  # the defaults, as a user gets them
    ev_settings = [(16, 1e-12), (256, 1e-12), (64, 1e-9), (64, 1e-6)]
    if quick:
        ev_settings = [(64, 1e-6)]
    for grid, tol in ev_settings:
        rows.append(sweep("event", event_tag(grid, tol),
                          SolverSettings(method="event", steps_per_period=grid), idx_all,
                          event_tol=tol))  # fmt: skip
    # in grid order: 16, 64 (default), 256, then the looser tolerances
    rows.insert(sum(g < DEFAULT_GRID for g, _ in ev_settings), default_row)
    # ---- exponential
    exp_ladder = (512, 2048) if quick else (512, 2048, 8192, 16384)
    for n in exp_ladder:
        idx = idx_fine if n == 16384 else idx_all
        rows.append(sweep("exponential", str(n),
                          SolverSettings(method="exponential", steps_per_period=n), idx,
                          subset=idx is not idx_all))  # fmt: skip
    # ---- euler, closed-form LCP
    eul_ladder = (1024, 4096) if quick else (1024, 2048, 4096, 8192, 16384, 32768)
    for n in eul_ladder:
        idx = idx_all if n <= 2048 else (idx_sub if n <= 8192 else idx_fine)
        rows.append(sweep("euler", str(n), SolverSettings(method="euler", steps_per_period=n),
                          idx, subset=idx is not idx_all))  # fmt: skip
    # ---- euler with Lemke at every step (as published)
    for n in (1024,) if quick else (1024, 4096):
        row = sweep("euler + Lemke", str(n),
                    SolverSettings(method="euler", steps_per_period=n, lcp="lemke"), idx_fine,
                    subset=idx_fine is not idx_all)  # fmt: skip
        closed = {(r.case, r.idx): r for x in rows if x.family == "euler" and x.setting == str(n)
                  for r in x.recs}  # fmt: skip
        diffs = [abs(r.db - closed[(r.case, r.idx)].db) for r in row.recs
                 if r.db is not None and closed[(r.case, r.idx)].db is not None]  # fmt: skip
        ratio = [r.wall / closed[(r.case, r.idx)].wall for r in row.recs]
        row.extra = {"vs_closed_max_db": max(diffs) if diffs else math.nan,
                     "time_vs_closed": statistics.median(ratio)}  # fmt: skip
        rows.append(row)
    # ---- ablations of the default (case A, every 3rd point)
    dflt_by = {(r.case, r.idx): r for r in default_row.recs}
    for tag, kw in (("early_stop off", {"early_stop": False}),
                    ("extrapolate off", {"extrapolate": False}),
                    ("linear_tail off", {"linear_tail": False})):  # fmt: skip
        row = sweep("event (ablation)", f"default, {tag}", SolverSettings(**kw), idx_sub,
                    subset=True, cases=("A",))  # fmt: skip
        tb = [dflt_by[("A", i)].wall for i in idx_sub]
        ta = [r.wall for r in row.recs]
        dd = [abs(r.db - dflt_by[(r.case, r.idx)].db) for r in row.recs
              if r.db is not None and dflt_by[(r.case, r.idx)].db is not None]  # fmt: skip
        row.extra = {"time_vs_default": sum(ta) / sum(tb) if sum(tb) > 0 else math.nan,
                     "vs_default_max_db": max(dd) if dd else math.nan,
                     "ablation_case": "A"}  # fmt: skip
        rows.append(row)

    # ---- a few points: Python port of the paper's scheme, and solve_ivp with a penalty
    few = []
    for case in CASES:
        periodic = [i for i in idx_all if ref[(case, i)].outcome == "periodic"]
        cands = [i for i in periodic if i in idx_sub and ref[(case, i)].period == 1
                 and 0.7 <= GAMMAS[i] <= 2.0]  # fmt: skip
        cands = cands or periodic or [i for i in idx_all if ref[(case, i)].period > 0]
        if cands:
            few.append((case, cands[0]))
    few = few[:1] if quick else few
    port_steps = 1024
    port = Row("python port", f"{port_steps}", subset=True)
    eul_same = {(r.case, r.idx): r for x in rows if x.family == "euler"
                and x.setting == str(port_steps) for r in x.recs}  # fmt: skip
    port_vs = []
    for case, i in few:
        e = eul_same[(case, i)]
        p = cell(case, GAMMAS[i])
        n_per = max(e.steady_period, max(e.period, 1))
        measure = max(e.period, 1)
        if quick:
            n_per = min(n_per, max(PORT_PERIODS_QUICK, measure))
        db, wall = python_paper_scheme(p, e.spp, n_per, measure)
        outcome = e.outcome if e.outcome != "failed" else "unsettled"
        port.recs.append(Rec(case, i, outcome, db, None, None, e.period, wall, e.steps,
                             e.contact_steps, 0, n_per, n_per, spp=e.spp))  # fmt: skip
        # numba euler ran e.steady_period periods on its main trajectory (plus side runs)
        t_numba = e.wall * n_per / max(e.periods, 1)
        port_vs.append((abs(db - e.db) if e.db is not None else math.nan, wall / t_numba))
    if port_vs:
        port.extra = {"vs_numba_euler_max_db": max(d for d, _ in port_vs),
                      "time_vs_numba_euler": statistics.median(t for _, t in port_vs)}  # fmt: skip
    log(f"python port: {sum(r.wall for r in port.recs):.1f} s")
    rows.append(port)
    ivp_settings = [(1e4, 1e-6, 1)] if quick else [(1e4, 1e-6, 2), (1e6, 1e-8, 1)]
    for kf, rtol, npt in ivp_settings:
        row = Row("solve_ivp", f"LSODA, k_pen {kf:.0e}·k1, rtol {rtol:.0e}", subset=True)
        nf = []
        for case, i in few[:npt]:
            f = ref[(case, i)]
            n_per = max(f.steady_period, f.period, 1)
            db, wall, nfev = ivp_penalty(cell(case, GAMMAS[i]), n_per, f.period, kf, rtol,
                                         ivp_cap)  # fmt: skip
            done = db is not None
            row.recs.append(Rec(case, i, f.outcome if done else "failed", db, None, None,
                                f.period if done else -1, wall, periods=n_per,
                                note="" if done else f"not done in {ivp_cap:.0f} s"))  # fmt: skip
            nf.append(nfev)
        if nf:
            row.extra = {"nfev_mean": statistics.fmean(nf)}
        log(f"solve_ivp {row.setting}: {sum(r.wall for r in row.recs):.1f} s")
        rows.append(row)

    stats = [(row, compare(row, ref)) for row in rows]
    total = time.perf_counter() - t_start
    write_csv(args.out, ref_row, chk_row, chk, ref, stats)
    md = report(
        stats=stats, ref=ref, chk=chk, default_row=default_row, few=few, port=port,
        idx_all=idx_all, idx_sub=idx_sub, idx_fine=idx_fine, command=command, total=total,
    )  # fmt: skip
    (args.out / "work_precision.md").write_text(md)
    if not args.no_plot:
        plot(stats, args.out / "work_precision.png", len(idx_all))
    print(md)
    return 0


# --------------------------------------------------------------------------- output

CSV_KEYS = [
    "n_points", "n_compared", "max_db", "median_db", "max_theta", "median_theta", "per_miss",
    "n_linear_cmp", "max_db_linear", "n_irr", "irr_median_db", "irr_median_z", "irr_within_z",
    "mismatch", "failed", "n_linear", "n_periodic", "n_irregular", "n_unsettled", "n_failed",
    "t_median_ms", "t_mean_ms", "steps_mean", "contact_mean", "coarse_mean", "fine_saved_mean",
    "saved_periods_pct",
]  # fmt: skip


def write_csv(out: Path, ref_row: Row, chk_row: Row, chk: dict, ref: dict, stats: list) -> None:
    all_rows = [(ref_row, compare(ref_row, ref)), (chk_row, chk), *stats]
    with open(out / "work_precision.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["family", "setting", "subset", *CSV_KEYS, "notes"])
        for row, st in all_rows:
            notes = [f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                     for k, v in row.extra.items()]  # fmt: skip
            raised = sum(r.note == "raised" for r in row.recs)
            if raised:
                notes.append(f"raised_unstable={raised}")
            notes += [r.note for r in row.recs if r.note and r.note != "raised"]
            w.writerow([row.family, row.setting, int(row.subset),
                        *[st[k] for k in CSV_KEYS], "; ".join(notes)])  # fmt: skip
    with open(out / "work_precision_points.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["family", "setting", "case", "gamma_r", "outcome", "response_period",
                    "transmittance_db", "transmittance_db_se", "theta_eff", "ref_outcome",
                    "ref_period", "ref_db", "ref_se", "wall_s", "periods", "steady_period",
                    "steps", "reason"])  # fmt: skip
        for row, _ in all_rows:
            for r in row.recs:
                f = ref[(r.case, r.idx)]
                w.writerow([row.family, row.setting, r.case, f"{GAMMAS[r.idx]:.6f}", r.outcome,
                            r.period, r.db, r.se, r.theta_eff, f.outcome, f.period, f.db, f.se,
                            f"{r.wall:.6f}", r.periods, r.steady_period, r.steps,
                            r.reason or r.note])  # fmt: skip


def report(*, stats, ref, chk, default_row, few, port, idx_all, idx_sub, idx_fine, command,
           total) -> str:  # fmt: skip
    n_ref = {o: sum(r.outcome == o for r in ref.values())
             for o in ("linear", "periodic", "irregular", "unsettled", "failed")}  # fmt: skip
    L = [
        "# Work–precision: every solver against a tight event-driven reference",
        "",
        f"Generated by `{command}` in {total / 60:.1f} min on {machine()}. Points run one after "
        "another; time per point = the whole `simulate_point` call.",
        "",
        "Cases (γ_s 1, ξ 0.05, gaps 0.1, 5 modes, γ_r = 0.2 … 6): "
        + "; ".join(f"**{c}** {t}" for c, t in CASE_TEXT.items())
        + f". {len(idx_all)} points per spectrum, {len(ref)} in all. The reference reports "
        + ", ".join(f"{n} {o}" for o, n in n_ref.items())
        + ".",
        "",
        f"**Reference**: `event`, sub-grid {REF_GRID}, event_tol {REF_TOL:g}, periodicity_tol "
        f"{REF_PTOL:g}. **Self-consistency** against `event` {CHK_GRID}, event_tol "
        f"{CHK_TOL:g}, periodicity_tol {CHK_PTOL:g}: max |ΔΓ| {fmt(chk['max_db'])} dB, "
        f"median {fmt(chk['median_db'])} dB, max |Δθ_eff| {fmt(chk['max_theta'])} over "
        f"{chk['n_compared']} periodic points; {chk['mismatch']} classification differences, "
        f"{chk['failed']} failed; irregular in both: {chk['n_irr']}, median z "
        f"{fmt(chk['irr_median_z'], '.2f')}.",
        "",
        "Columns: `n` = points periodic in the reference and periodic with the same period in "
        "the method / points run (`*` = subset of points, see notes); ΔΓ and Δθ_eff over those; "
        "`lin. max` = max |ΔΓ| over points linear in the reference that the method reports with "
        "period 1 (0 when both report the closed form); `class ≠`: points classified "
        "differently (converged vs not, or another period) + failed; `irr. n`, `irr. z`, "
        f"`z≤{Z_OK:g}`: points irregular in both, the median of |ΔΓ| / √(se_ref² + se²) and the "
        "fraction within 3 standard errors; `unsettled` = points the method left unsettled; "
        "`contact` = mean steps per point that needed a contact solve (event: impacts); `fine "
        "saved` = mean fine steps per point skipped by whole coarse steps far from the stops "
        "(exponential); `saved` = periods saved by the early stop, % of the "
        f"{MAX_PERIODS}-period budget of converged points (all periods integrated, side runs "
        "included).",
        "",
        "| method | setting | n | max abs ΔΓ dB | median abs ΔΓ dB | max abs Δθ_eff | "
        "median abs Δθ_eff | lin. max dB | class ≠ | irr. n | irr. z | z≤3 | unsettled | "
        "median ms/pt | mean ms/pt | steps/pt | contact/pt | fine saved/pt | saved % |",
        "|" + "---|" * 19,
    ]
    for row, st in stats:
        star = "*" if row.subset else ""
        L.append(
            f"| {row.family} | {row.setting} | {st['n_compared']}/{st['n_points']}{star} | "
            f"{fmt(st['max_db'])} | {fmt(st['median_db'])} | {fmt(st['max_theta'])} | "
            f"{fmt(st['median_theta'])} | {fmt(st['max_db_linear'])} | "
            f"{st['mismatch']}+{st['failed']} | {st['n_irr']} | "
            f"{fmt(st['irr_median_z'], '.2f')} | {fmt(st['irr_within_z'], '.0%')} | "
            f"{st['n_unsettled']} | {fmt(st['t_median_ms'], '.1f')} | "
            f"{fmt(st['t_mean_ms'], '.1f')} | {st['steps_mean']:.0f} | "
            f"{st['contact_mean']:.0f} | {st['fine_saved_mean']:.0f} | "
            f"{fmt(st['saved_periods_pct'], '.1f')} |"
        )
    L += ["", "Notes per row:", ""]
    for row, _st in stats:
        if row.extra or any(r.note for r in row.recs):
            bits = [f"{k} = {v:.3g}" if isinstance(v, float) else f"{k} = {v}"
                    for k, v in row.extra.items()]  # fmt: skip
            raised = sum(r.note == "raised" for r in row.recs)
            if raised:
                bits.append(
                    f"{raised} points refused as unstable at this step and run at the "
                    "smallest stable doubling"
                )
            bits += [r.note for r in row.recs if r.note and r.note != "raised"]
            L.append(f"- {row.family} {row.setting}: " + ", ".join(bits))
    L += [
        f"- Subsets (`*`): euler 4096 and 8192 on every 3rd point ({len(idx_sub)} per spectrum); "
        f"exponential 16384, euler 16384/32768 and euler + Lemke on every 6th "
        f"({len(idx_fine)} per spectrum); ablations of the default on case A's every 3rd point "
        "(`time_vs_default` = their total time over the default's on the same points, "
        "`vs_default_max_db` = max |ΔΓ| to the default there); python port and solve_ivp on "
        "the points "
        + (", ".join(f"{c} γ_r = {GAMMAS[i]:.3f}" for c, i in few) or "(none)")
        + " (the port runs as many periods as numba euler's main trajectory did there and "
        "measures the last p, its time compared with numba euler's per period; solve_ivp runs "
        "as many periods as the reference's main trajectory and measures the last p).",
    ]
    L += ablation_section(stats)
    L += irregular_section(stats, ref)
    L += targets_section(stats, ref, default_row, port, idx_fine)
    return "\n".join(L) + "\n"


def ablation_section(stats: list) -> list[str]:
    abl = [(row, st) for row, st in stats if row.family.endswith("(ablation)")]
    if not abl:
        return []
    L = [
        "",
        "## Ablations of the default",
        "",
        "Case A, every 3rd point. `early_stop` off runs the whole budget and classifies at "
        "its end; `extrapolate` off confirms only orbits the trajectory reaches by itself; "
        "`linear_tail` off integrates impact-free tails instead of proving them (the "
        "solver's own accuracy at points linear in the reference: `lin. max`).",
        "",
        "| setting | time vs default | max abs ΔΓ vs default dB | max abs ΔΓ vs ref (periodic) "
        "dB | lin. max vs ref dB | class ≠ | median ms/pt |",
        "|---|---|---|---|---|---|---|",
    ]
    for row, st in abl:
        x = row.extra
        L.append(
            f"| {row.setting} | {fmt(x.get('time_vs_default'), '.2f')}× | "
            f"{fmt(x.get('vs_default_max_db'))} | {fmt(st['max_db'])} | "
            f"{fmt(st['max_db_linear'])} | {st['mismatch']}+{st['failed']} | "
            f"{fmt(st['t_median_ms'], '.1f')} |"
        )
    return L


def irregular_section(stats: list, ref: dict) -> list[str]:
    drow = next(row for row, _ in stats if (row.family, row.setting) == DEFAULT)
    L = [
        "",
        "## Irregular points: agreement within the standard errors",
        "",
        "An irregular point's Γ is the mean over measurement windows with a standard error "
        "(the statistics stop when it is at most `stat_tol_db`, after at least 8 windows and a "
        "quarter of the budget); `unsettled` points ran out of budget first. Where both the "
        "reference and the default are irregular, z = |ΔΓ| / √(se_ref² + se²).",
        "",
        "| case | ref irregular | ref unsettled | default irregular | default unsettled | "
        "irregular in both | median abs ΔΓ dB | median z | z ≤ 3 | median se_ref dB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for case in CASES:
        recs = [r for r in drow.recs if r.case == case]
        refs = [ref[(r.case, r.idx)] for r in recs]
        both = [(r, f) for r, f in zip(recs, refs, strict=True)
                if r.outcome == "irregular" and f.outcome == "irregular"]  # fmt: skip
        dd = [abs(r.db - f.db) for r, f in both]
        zz = [z_score(r, f) for r, f in both]
        ses = [f.se for f in refs if f.outcome == "irregular" and f.se is not None]
        L.append(
            f"| {case} | {sum(f.outcome == 'irregular' for f in refs)} | "
            f"{sum(f.outcome == 'unsettled' for f in refs)} | "
            f"{sum(r.outcome == 'irregular' for r in recs)} | "
            f"{sum(r.outcome == 'unsettled' for r in recs)} | {len(both)} | "
            f"{fmt(_median(dd))} | {fmt(_median(zz), '.2f')} | "
            f"{fmt(sum(z <= Z_OK for z in zz) / len(zz) if zz else math.nan, '.0%')} | "
            f"{fmt(_median(ses))} |"
        )
    return L


def targets_section(stats: list, ref: dict, default_row: Row, port: Row, idx_fine) -> list[str]:
    dflt = next(st for row, st in stats if (row.family, row.setting) == DEFAULT)
    L = ["", "## Targets", ""]
    # (a) periodic points
    ok_a = dflt["max_db"] <= TARGET_DB
    verdict_a = "met" if ok_a else "NOT met"
    if dflt["n_compared"] == 0:
        verdict_a = "not checked (no point periodic in both)"
    L.append(
        f"1. **Default within {TARGET_DB:g} dB of the reference at every point periodic in "
        f"both: {verdict_a}.** Max |ΔΓ| {fmt(dflt['max_db'])} dB (median "
        f"{fmt(dflt['median_db'])}) over {dflt['n_compared']} points periodic in both; "
        f"{dflt['per_miss']} periodic reference points not reproduced with the same period, "
        f"{dflt['mismatch']} classification differences in all, {dflt['failed']} failed."
    )
    # (b) linear points
    lin = [r for r in default_row.recs if ref[(r.case, r.idx)].outcome == "linear"]
    as_linear = [r for r in lin if r.outcome == "linear"]
    closed = {
        (r.case, r.idx): linear_transmittance_db(cell(r.case, GAMMAS[r.idx])) for r in as_linear
    }
    d_cf = [abs(r.db - closed[(r.case, r.idx)]) for r in as_linear]
    n_ok = sum(d <= TARGET_DB for d in d_cf)
    ok_b = n_ok == len(lin)
    extra_lin = [r for r in default_row.recs
                 if r.outcome == "linear" and ref[(r.case, r.idx)].outcome != "linear"]  # fmt: skip
    bad = [r for r in lin if r.outcome != "linear"]
    L += [
        "",
        f"2. **Non-impacting points are `linear` and equal the closed form within "
        f"{TARGET_DB:g} dB: {'met' if ok_b else 'NOT met'}.** Of {len(lin)} points the "
        f"reference reports linear, the default reports {len(as_linear)} linear, {n_ok} of them "
        f"within {TARGET_DB:g} dB of `linear_transmittance_db` (max |ΔΓ| {fmt(_max(d_cf))} "
        f"dB). The default also reports {len(extra_lin)} points linear that the reference "
        "does not."
        + (
            " Not linear in the default: "
            + ", ".join(f"{r.case} γ_r = {GAMMAS[r.idx]:.3f} ({r.outcome})" for r in bad[:10])
            + ("…" if len(bad) > 10 else "")
            + "."
            if bad
            else ""
        ),
    ]
    # (c) cheapest setting per family within the target at every periodic point
    drow_by = {(r.case, r.idx): r for r in default_row.recs}
    L += [
        "",
        f"3. **The default method is the fastest within {TARGET_DB:g} dB at every periodic "
        "point.** Per family, the cheapest setting (median time) within "
        f"{TARGET_DB:g} dB of the reference at every point periodic in both (as in 1); `not "
        "reproduced` = periodic reference points where the setting found another period, no "
        "orbit, or failed; `default there` = the default's times on the same points:",
        "",
        "   | family | cheapest setting within target | max abs ΔΓ dB | not reproduced | "
        "median ms/pt | mean ms/pt | default there: median / mean ms |",
        "   |---|---|---|---|---|---|---|",
    ]
    ratios = []
    default_qualifies = within_target(dflt)
    for fam in FAMILIES:
        good = [(row, st) for row, st in stats if row.family == fam and within_target(st)]
        if not good:
            L.append(f"   | {fam} | none | | | | | |")
            continue
        row, st = min(good, key=lambda x: x[1]["t_median_ms"])
        walls = [drow_by[(r.case, r.idx)].wall for r in row.recs]
        dm, dmean = 1e3 * statistics.median(walls), 1e3 * statistics.fmean(walls)
        if fam != DEFAULT[0]:  # other settings of the default's method are the same method
            ratios.append((fam, row.setting, st["t_median_ms"] / dm if dm > 0 else math.inf))
        L.append(
            f"   | {fam} | {row.setting}{'*' if row.subset else ''} | {fmt(st['max_db'])} | "
            f"{st['per_miss']} | {st['t_median_ms']:.1f} | {st['t_mean_ms']:.1f} | "
            f"{dm:.1f} / {dmean:.1f} |"
        )
    # the target is about methods: the default's method must be the fastest family within it
    fastest = default_qualifies and all(r >= 1.0 for _, _, r in ratios)
    L.append("")
    if dflt["n_compared"] == 0:
        L.append("   **Not checked**: no point periodic in both.")
    elif not default_qualifies:
        L.append("   **NOT met**: the default itself is not within the target (see 1).")
    else:
        others = "; ".join(f"{fam} {s}: {r:.2f}× the default's median time"
                           for fam, s, r in ratios)  # fmt: skip
        L.append(f"   **{'Met' if fastest else 'NOT met'}**" + (
            f" ({others})." if others else
            f": no other method reaches the target (settings of `{DEFAULT[0]}` other than the "
            "default are the same method; see their rows above)."))  # fmt: skip
    # (d) the paper's scheme at equal accuracy (information)
    L += paper_scheme_section(stats, ref, default_row, port, idx_fine)
    return L


def paper_scheme_section(stats, ref, default_row, port, idx_fine) -> list[str]:
    sub_keys = {(c, i) for c in CASES for i in idx_fine}

    def on_subset(row: Row) -> dict:
        r2 = Row(row.family, row.setting, [r for r in row.recs if (r.case, r.idx) in sub_keys])
        return compare(r2, ref)

    d_sub = on_subset(default_row)
    eul_rows = [row for row, _ in stats if row.family == "euler"
                and sub_keys <= {(r.case, r.idx) for r in row.recs}]  # fmt: skip
    e_sub = [(row.setting, on_subset(row)) for row in eul_rows]
    L = [
        "",
        "4. **At equal accuracy against the paper's scheme (information).** Compared on the "
        f"{len(sub_keys)} points where every euler setting ran (default there: max "
        f"{fmt(d_sub['max_db'])} dB, median {fmt(d_sub['median_db'])} dB over "
        f"{d_sub['n_compared']} periodic points, median {fmt(d_sub['t_median_ms'], '.1f')} "
        f"ms/point, mean {fmt(d_sub['t_mean_ms'], '.1f')}):",
        "",
        "   | euler steps/period | max abs ΔΓ dB | median abs ΔΓ dB | median ms/pt | mean ms/pt |",
        "   |---|---|---|---|---|",
    ]
    for name, st in e_sub:
        L.append(f"   | {name} | {fmt(st['max_db'])} | {fmt(st['median_db'])} | "
                 f"{fmt(st['t_median_ms'], '.1f')} | {fmt(st['t_mean_ms'], '.1f')} |")  # fmt: skip
    L.append("")
    verdicts = []
    for stat, tkey in (("max_db", "t_median_ms"), ("median_db", "t_median_ms"),
                       ("max_db", "t_mean_ms")):  # fmt: skip
        pts = [(st[tkey], st[stat]) for _, st in e_sub if st[stat] > 0 and st[tkey] > 0]
        y0, t0 = d_sub[stat], d_sub[tkey]
        label = f"{stat.replace('_db', '')} error, {tkey.replace('t_', '').replace('_ms', '')} time"
        if len(pts) < 2 or not (y0 > 0 and t0 > 0):
            L.append(f"   - {label}: not computable here (fewer than two euler settings with a "
                     "positive error, or no periodic point for the default).")  # fmt: skip
            verdicts.append(math.nan)
            continue
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        t_eq, extrap = loglog_at(xs, ys, y0)
        ratio = t_eq / t0
        verdicts.append(ratio)
        how = "interpolated between its settings"
        if extrap:
            slope = (math.log(ys[-1]) - math.log(ys[-2])) / (math.log(xs[-1]) - math.log(xs[-2]))
            decades = math.log10(min(ys) / y0) if y0 < min(ys) else 0.0
            how = (
                "extrapolated along the log–log line through its two finest settings, "
                f"d log error / d log time = {slope:.2f}"
                + (f"; {decades:.1f} decades of error beyond the finest: indicative only"
                   if decades >= 1.0 else "")
            )  # fmt: skip
        L.append(
            f"   - {label}: euler needs ≈ {t_eq:.3g} ms/point for {fmt(y0)} dB ({how}), "
            f"{ratio:.3g}× the default."
        )
    lem = next((st for row, st in stats if row.family == "euler + Lemke"), None)
    lem_row = next((row for row, _ in stats if row.family == "euler + Lemke"), None)
    prt = port.extra.get("time_vs_numba_euler", math.nan)
    v0 = verdicts[0]
    bits = [f"   - Against numba euler with the closed-form LCP (max-error criterion, median "
            f"time): ≈ {fmt(v0, '.3g')}× the default's time."]  # fmt: skip
    if lem is not None and lem_row is not None and "time_vs_closed" in lem_row.extra:
        tvc = lem_row.extra["time_vs_closed"]
        bits.append(f" With Lemke at every step (as published, compiled) euler is a further "
                    f"{tvc:.2f}× slower, i.e. ≈ {fmt(v0 * tvc, '.3g')}×.")  # fmt: skip
    if not math.isnan(prt):
        bits.append(f" The plain Python/NumPy port is {prt:.0f}× slower than numba euler per "
                    f"period at the same setting, i.e. ≈ {fmt(v0 * prt, '.3g')}× the default at "
                    "equal accuracy.")  # fmt: skip
    L.append("".join(bits))
    return L


def plot(stats: list, path: Path, npts: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fams = {}
    for row, st in stats:
        if row.family.endswith("(ablation)"):
            continue
        fam = row.family
        if row.family == "event":
            grid = "tol 1e-12" in row.setting
            fam = "event (tol 1e-12, grid)" if grid else "event (grid 64, tol)"
        fams.setdefault(fam, []).append((st["t_median_ms"], st["max_db"], st["median_db"],
                                         row.setting))  # fmt: skip
    fams["event (grid 64, tol)"] = fams.get("event (grid 64, tol)", []) + [
        p for p in fams.get("event (tol 1e-12, grid)", []) if p[3].startswith("grid 64")
    ]
    fig, ax = plt.subplots(figsize=(8, 5.5))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (fam, pts) in enumerate(fams.items()):
        pts = sorted(p for p in pts if p[1] > 0 and not math.isnan(p[1]))
        if not pts:
            continue
        c = colors[k % len(colors)]
        t = [p[0] for p in pts]
        ax.loglog(t, [p[1] for p in pts], "o-", color=c, label=f"{fam}: max")
        ax.loglog(t, [max(p[2], 1e-14) for p in pts], "s--", color=c, alpha=0.6,
                  label=f"{fam}: median")  # fmt: skip
    for row, st in stats:
        if (row.family, row.setting) == DEFAULT and st["max_db"] > 0:
            ax.loglog([st["t_median_ms"]], [st["max_db"]], "k*", ms=14, label="default")
    ax.axhline(1e-3, color="grey", lw=0.8, ls=":")
    ax.axhline(TARGET_DB, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("median wall time per point (ms, one core)")
    ax.set_ylabel("|ΔΓ| against the reference (dB), periodic points")
    ax.set_title(f"Work–precision, three {npts}-point spectra")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
