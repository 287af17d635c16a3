"""Work–precision of every solver against a tight event-driven reference ("fast and accurate").

    python benchmarks/work_precision.py [--quick] [--points N] [--out benchmarks/results]

Cases: three 60-point spectra, γ_r = 0.2 … 6 (as ``benchmarks/spectrum.py``), γ_s 1, ξ 0.05,
gaps 0.1, five modes: θ 0.3, σ 0.05 in both couplings, and θ 1, σ 0.1 (paper coupling).

Reference: ``event`` with a 256-interval sub-grid, ``event_tol`` 1e-13 and ``periodicity_tol``
1e-11. Its self-consistency is the difference to a second tight setting (128 intervals,
``event_tol`` 1e-11, ``periodicity_tol`` 1e-10).

Errors: |ΔΓ| (dB) and |Δθ_eff| (harmonic θ_eff) at points that are periodic with the same
period in the reference and in the method. Points where the classification differs (periodic
vs irregular, or another period) are counted, not measured. Irregular points have no pointwise
limit; there the reference's own spread between successive measurement windows (the last 20
periods of a 1000-period run against periods 960–980, i.e. a run with ``max_periods`` 980) is
reported, next to each method's median |ΔΓ| there.

Methods: ``exponential`` over ``steps_per_period``; ``euler`` (numba, closed-form LCP) over
``steps_per_period`` (the finest on a subset of points); ``euler`` with the compiled Lemke
solver at every step (``lcp="lemke"``, the scheme as published); ``event`` over its sub-grid
and ``event_tol``; a plain Python/NumPy port of the paper's scheme (``worker.lcp.lemke`` at
every step) and ``scipy.integrate.solve_ivp`` (LSODA) with a penalty spring-dashpot at the
stops, both on a few points only.

Time per point is the wall time of the whole ``simulate_point`` call (assembly, matrix
exponentials and kernel), on one core of a shared machine.

Writes ``work_precision.csv`` (one row per method setting), ``work_precision.md`` and
``work_precision.png`` to the output folder.
"""

from __future__ import annotations

import argparse
import csv
import math
import statistics
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from worker.event import simulate_event  # noqa: E402
from worker.lcp import lemke, two_stop_matrix  # noqa: E402
from worker.model import CellParams, assemble  # noqa: E402
from worker.simulate import PointResult, SolverSettings, simulate_point, warm_up  # noqa: E402

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
MAX_PERIODS, WINDOW = 1000, 20
DEFAULT = ("exponential", "2048 (default)")
IVP_WALL_CAP = 60.0  # seconds per solve_ivp point; beyond it the point is reported unfinished


def cell(case: str, g: float) -> CellParams:
    return CellParams(gamma_s=1.0, gamma_r=float(g), xi=0.05, g1=0.1, g2=0.1, **CASES[case])


@dataclass
class Rec:
    """One point of one method setting."""

    case: str
    idx: int
    db: float | None
    theta_eff: float | None
    period: int  # 0 irregular, -1 failed
    wall: float  # whole call, s
    steps: int = 0
    contact_steps: int = 0
    coarse_steps: int = 0
    periods: int = 0
    n_sub: int = 1
    spp: int = 0
    note: str = ""


def rec_of(case: str, idx: int, r: PointResult, wall: float, n_sub: int = 1) -> Rec:
    period = -1 if r.failed else (r.response_period if r.converged else 0)
    return Rec(case, idx, r.transmittance_db, r.theta_eff, period, wall, r.steps,
               r.contact_steps, r.coarse_steps, r.periods, n_sub)  # fmt: skip


def run_numba(case: str, idx: int, settings: SolverSettings, **kw) -> Rec:
    p = cell(case, GAMMAS[idx])
    note = ""
    while True:
        t0 = time.perf_counter()
        try:
            if settings.method == "event":
                r = simulate_event(p, settings, **kw)
            else:
                r = simulate_point(p, settings)
        except ValueError as exc:
            # euler refuses unstable steps (long periods at low γ_r): double the resolution
            if settings.method != "euler" or "unstable" not in str(exc):
                raise
            settings = replace(settings, steps_per_period=2 * settings.steps_per_period)
            note = "raised"
            continue
        break
    wall = time.perf_counter() - t0
    n_sub = 1
    if settings.method == "exponential":
        spp = settings.steps_per_period or 2048
        n_sub = spp // min(settings.coarse_steps, spp)
    rec = rec_of(case, idx, r, wall, n_sub)
    rec.note = note
    rec.spp = r.steps_per_period
    return rec


@dataclass
class Row:
    family: str
    setting: str
    recs: list[Rec] = field(default_factory=list)
    subset: bool = False
    extra: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- the paper's scheme,
# written out in Python/NumPy (one step = the formulas of MODEL.md §5, Lemke at every step)


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
        lam = lemke(Mlcp, np.array([p.g1 - wpred, p.g2 + wpred]))
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


def ivp_penalty(p: CellParams, periods: int, measure: int, k_factor: float, rtol: float):
    """Γ (dB), wall time and f-evaluations of LSODA on the penalty-regularised model.

    Each stop is a unilateral spring-dashpot, force ``max(0, k δ + c δ̇)`` while penetrated by
    δ, with ``k = k_factor · σβ_1⁴`` (the first beam mode's modal stiffness) and critical
    damping ``c = 2√(k/G)`` for the tip's effective mass ``1/G``, which makes the impacts
    nearly plastic. Amplitude from dense output at 4096 samples per period.
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
        if nfev[0] % 2000 == 0 and time.perf_counter() - t0 > IVP_WALL_CAP:
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


def compare(row: Row, ref: dict) -> dict:
    """Error statistics of a row against the reference (keyed by (case, idx))."""
    d_db, d_th, d_irr = [], [], []
    mismatch = failed = 0
    for r in row.recs:
        f = ref[(r.case, r.idx)]
        if r.period < 0 or r.db is None:
            failed += 1
            continue
        if f.period > 0 and r.period == f.period:
            d_db.append(abs(r.db - f.db))
            if r.theta_eff is not None and f.theta_eff is not None:
                d_th.append(abs(r.theta_eff - f.theta_eff))
        elif f.period == 0 and r.period == 0:
            d_irr.append(abs(r.db - f.db))
        else:
            mismatch += 1
    walls = [r.wall for r in row.recs]
    conv = [r for r in row.recs if r.period > 0]
    stepped = [r for r in row.recs if r.period >= 0]
    out = {
        "n_points": len(row.recs),
        "n_compared": len(d_db),
        "max_db": max(d_db) if d_db else math.nan,
        "median_db": statistics.median(d_db) if d_db else math.nan,
        "max_theta": max(d_th) if d_th else math.nan,
        "median_theta": statistics.median(d_th) if d_th else math.nan,
        "irr_median_db": statistics.median(d_irr) if d_irr else math.nan,
        "n_irr": len(d_irr),
        "mismatch": mismatch,
        "failed": failed,
        "t_median_ms": 1e3 * statistics.median(walls) if walls else math.nan,
        "t_mean_ms": 1e3 * statistics.fmean(walls) if walls else math.nan,
        "steps_mean": statistics.fmean(r.steps for r in stepped) if stepped else 0.0,
        "contact_mean": statistics.fmean(r.contact_steps for r in stepped) if stepped else 0.0,
        # periods saved by the early stop, over the budget of the converged points
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
    out.update(row.extra)
    return out


def fmt(x: float, spec: str = ".2e") -> str:
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


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="few settings and points (smoke run)")
    ap.add_argument("--points", type=int, default=None, help="points per spectrum (of 60)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    ap.add_argument("--no-plot", action="store_true")
    args = ap.parse_args(argv)
    quick = args.quick
    npts = args.points or (4 if quick else 60)
    if not 1 <= npts <= 60:
        ap.error("--points must be in 1…60")
    idx_all = sorted({int(round(i)) for i in np.linspace(0, 59, npts)})
    # subsets for the expensive settings: every 3rd point (20 per spectrum), every 6th (10)
    idx_sub = idx_all if quick else idx_all[::3]
    idx_fine = idx_all if quick else idx_all[::6]  # 10 per spectrum
    args.out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    warm_up()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t_start:7.1f} s] {msg}", flush=True)

    def sweep(family, setting, settings, idx, subset=False, **kw) -> Row:
        row = Row(family, setting, subset=subset)
        for case in CASES:
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
    # window-to-window spread of the reference at its irregular points
    irr_keys = [k for k, r in ref.items() if r.period == 0]
    spread = {}
    prev_set = SolverSettings(method="event", steps_per_period=REF_GRID,
                              periodicity_tol=REF_PTOL,
                              max_periods=MAX_PERIODS - WINDOW)  # fmt: skip
    for case, i in irr_keys:
        r2 = run_numba(case, i, prev_set, event_tol=REF_TOL)
        f = ref[(case, i)]
        if r2.db is not None and r2.period == 0:
            spread[(case, i)] = (abs(f.db - r2.db), abs(f.theta_eff - r2.theta_eff))
    log(f"irregular spread: {len(spread)} points")

    rows: list[Row] = []
    # ---- exponential
    exp_ladder = (512, 2048, 8192) if quick else (512, 2048, 8192, 16384)
    for n in exp_ladder:
        name = f"{n} (default)" if n == 2048 else str(n)
        idx = idx_fine if n == 16384 else idx_all
        rows.append(sweep("exponential", name, SolverSettings(steps_per_period=n), idx,
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
    # ---- event
    ev_settings = [(16, 1e-12), (64, 1e-12), (64, 1e-6), (64, 1e-9)]
    if quick:
        ev_settings = [(64, 1e-12), (64, 1e-6)]
    for grid, tol in ev_settings:
        tag = f"grid {grid}, tol {tol:.0e}" + (" (default)" if (grid, tol) == (64, 1e-12) else "")
        rows.append(sweep("event", tag, SolverSettings(method="event", steps_per_period=grid),
                          idx_all, event_tol=tol))  # fmt: skip
    # ---- early stop and adaptive stepping switched off (default exponential, case A subset)
    for tag, kw in (("2048, early_stop off", {"early_stop": False}),
                    ("2048, adaptive off", {"adaptive": False})):  # fmt: skip
        row = Row("exponential (ablation)", tag, subset=True)
        base = {(r.case, r.idx): r for r in rows[exp_ladder.index(2048)].recs}
        for i in idx_sub:
            row.recs.append(run_numba("A", i, SolverSettings(**kw)))
        tb = [base[("A", i)].wall for i in idx_sub]
        ta = [r.wall for r in row.recs]
        row.extra = {"time_vs_default": sum(ta) / sum(tb), "ablation_case": "A"}
        log(f"ablation {tag}: {sum(ta):.1f} s vs {sum(tb):.1f} s")
        rows.append(row)

    # ---- a few points: Python port of the paper's scheme, and solve_ivp with a penalty
    few = []
    for case in CASES:
        cands = [i for i in idx_sub if ref[(case, i)].period == 1 and 0.7 <= GAMMAS[i] <= 2.0]
        cands = cands or [i for i in idx_all if ref[(case, i)].period > 0]
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
        db, wall = python_paper_scheme(p, e.spp, e.periods, max(e.period, 1))
        port.recs.append(Rec(case, i, db, None, e.period, wall, e.steps, e.contact_steps, 0,
                             e.periods))  # fmt: skip
        port_vs.append((abs(db - e.db), wall / e.wall))
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
            db, wall, nfev = ivp_penalty(cell(case, GAMMAS[i]), f.periods, f.period, kf, rtol)
            per = f.period if db is not None else -1
            row.recs.append(
                Rec(
                    case,
                    i,
                    db,
                    None,
                    per,
                    wall,
                    periods=f.periods,
                    note="" if db is not None else f"not done in {IVP_WALL_CAP:.0f} s",
                )
            )
            nf.append(nfev)
        row.extra = {"nfev_mean": statistics.fmean(nf)}
        log(f"solve_ivp {row.setting}: {sum(r.wall for r in row.recs):.1f} s")
        rows.append(row)

    # ---------------------------------------------------------------- tables
    stats = [(row, compare(row, ref)) for row in rows]
    total = time.perf_counter() - t_start
    csv_path = args.out / "work_precision.csv"
    keys = ["n_points", "n_compared", "max_db", "median_db", "max_theta", "median_theta",
            "n_irr", "irr_median_db", "mismatch", "failed", "t_median_ms", "t_mean_ms",
            "steps_mean", "contact_mean", "coarse_mean", "fine_saved_mean",
            "saved_periods_pct"]  # fmt: skip
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["family", "setting", "subset", *keys, "notes"])
        for row, st in [(ref_row, compare(ref_row, ref)), (chk_row, chk), *stats]:
            notes = "; ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                              for k, v in row.extra.items())  # fmt: skip
            raised = sum(r.note == "raised" for r in row.recs)
            notes += f"; raised_unstable={raised}" if raised else ""
            notes += "; ".join(r.note for r in row.recs if r.note and r.note != "raised")
            w.writerow([row.family, row.setting, int(row.subset),
                        *[st[k] for k in keys], notes])  # fmt: skip

    n_per = sum(1 for r in ref.values() if r.period > 0)
    n_irr = sum(1 for r in ref.values() if r.period == 0)
    L = [
        "# Work–precision: every solver against a tight event-driven reference",
        "",
        f"Generated by `python benchmarks/work_precision.py{' --quick' if quick else ''}` "
        f"in {total / 60:.1f} min on one core of a shared 2-core machine.",
        "",
        "Cases (γ_s 1, ξ 0.05, gaps 0.1, 5 modes, γ_r = 0.2 … 6): "
        + "; ".join(f"**{c}** {t}" for c, t in CASE_TEXT.items())
        + f". {len(idx_all)} points per spectrum, {len(ref)} in all: {n_per} periodic and "
        f"{n_irr} irregular in the reference.",
        "",
        f"**Reference**: `event`, sub-grid {REF_GRID}, event_tol {REF_TOL:g}, periodicity_tol "
        f"{REF_PTOL:g}. **Self-consistency** against `event` {CHK_GRID}, event_tol "
        f"{CHK_TOL:g}, periodicity_tol {CHK_PTOL:g}: max |ΔΓ| {fmt(chk['max_db'])} dB, "
        f"median {fmt(chk['median_db'])} dB, max |Δθ_eff| {fmt(chk['max_theta'])} over "
        f"{chk['n_compared']} periodic points; {chk['mismatch']} classification differences.",
        "",
        "Columns: errors over points periodic with the same period in the reference and the "
        "method (`n` compared / points run; `*` = subset of points, see notes); `class ≠`: "
        "points classified differently (periodic vs irregular or another period) + failed; "
        "`irr. med` the median |ΔΓ| at points irregular in both (no pointwise limit there, "
        "compare with the reference's window spread below); time = whole `simulate_point` "
        "call; `contact` = mean steps per point that needed a contact solve (event: impacts); "
        "`fine saved` = mean fine steps per point skipped by whole coarse steps far from the "
        "stops (exponential; event: sub-grid intervals cleared by the cheap test); `saved` = "
        "periods saved by the early stop, % of the 1000-period budget of converged points.",
        "",
        "| method | setting | n | max abs ΔΓ dB | median abs ΔΓ dB | max abs Δθ_eff | "
        "median abs Δθ_eff | class ≠ | irr. med dB | median ms/pt | mean ms/pt | steps/pt | "
        "contact/pt | fine saved/pt | saved % |",
        "|" + "---|" * 15,
    ]
    for row, st in stats:
        star = "*" if row.subset else ""
        L.append(
            f"| {row.family} | {row.setting} | {st['n_compared']}/{st['n_points']}{star} | "
            f"{fmt(st['max_db'])} | {fmt(st['median_db'])} | {fmt(st['max_theta'])} | "
            f"{fmt(st['median_theta'])} | {st['mismatch']}+{st['failed']} | "
            f"{fmt(st['irr_median_db'])} | {fmt(st['t_median_ms'], '.1f')} | "
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
        f"({len(idx_fine)} per spectrum); ablations on case A's every 3rd point; "
        "python port and solve_ivp on the points "
        + ", ".join(f"{c} γ_r = {GAMMAS[i]:.3f}" for c, i in few)
        + " (the port runs as many periods as numba euler did there and measures the last "
        "p; solve_ivp runs as many periods as the reference and measures the last p).",
        "",
        "## Irregular points: the reference's window-to-window spread",
        "",
        "Γ over the last 20 of 1000 periods against the last 20 of 980 (periods 961–980).",
        "",
        "| case | irregular points | median spread dB | max spread dB | "
        "median spread θ_eff | default exponential median abs ΔΓ dB there |",
        "|---|---|---|---|---|---|",
    ]
    dflt = next(st for row, st in stats if (row.family, row.setting) == DEFAULT)
    drow = next(row for row, _ in stats if (row.family, row.setting) == DEFAULT)
    for case in CASES:
        sp = [v for (c, _), v in spread.items() if c == case]
        dd = [abs(r.db - ref[(r.case, r.idx)].db) for r in drow.recs
              if r.case == case and r.period == 0 and ref[(r.case, r.idx)].period == 0]  # fmt: skip
        L.append(
            f"| {case} | {len(sp)} | {fmt(statistics.median([a for a, _ in sp]) if sp else None)}"
            f" | {fmt(max([a for a, _ in sp]) if sp else None)} | "
            f"{fmt(statistics.median([b for _, b in sp]) if sp else None)} | "
            f"{fmt(statistics.median(dd) if dd else None)} |"
        )

    # ---------------------------------------------------------------- targets
    L += ["", "## Targets", ""]
    ok1 = dflt["max_db"] <= 1e-3
    L.append(
        f"1. **Default within 1e-3 dB at every periodic point: {'met' if ok1 else 'NOT met'}.** "
        f"Max |ΔΓ| {fmt(dflt['max_db'])} dB (median {fmt(dflt['median_db'])}) over "
        f"{dflt['n_compared']} points periodic in both; {dflt['mismatch']} classification "
        f"differences, {dflt['failed']} failed."
    )
    # 2: on the subset where the euler ladder is complete
    sub_keys = {(c, i) for c in CASES for i in idx_fine}

    def on_subset(row: Row) -> dict:
        r2 = Row(row.family, row.setting, [r for r in row.recs if (r.case, r.idx) in sub_keys])
        return compare(r2, ref)

    d_sub = on_subset(drow)
    eul_rows = [row for row, _ in stats if row.family == "euler"
                and sub_keys <= {(r.case, r.idx) for r in row.recs}]  # fmt: skip
    e_sub = [(row.setting, on_subset(row)) for row in eul_rows]
    L.append("")
    L.append(
        f"2. **Default ≥ 50× faster than the paper's scheme at equal accuracy.** Compared on the "
        f"{len(sub_keys)} points where every euler setting ran (default there: max "
        f"{fmt(d_sub['max_db'])} dB, median {fmt(d_sub['median_db'])} dB, median "
        f"{fmt(d_sub['t_median_ms'], '.1f')} ms/point, mean {fmt(d_sub['t_mean_ms'], '.1f')}):"
    )
    L.append("")
    L.append(
        "   | euler steps/period | max abs ΔΓ dB | median abs ΔΓ dB | median ms/pt | mean ms/pt |"
    )
    L.append("   |---|---|---|---|---|")
    for name, st in e_sub:
        L.append(f"   | {name} | {fmt(st['max_db'])} | {fmt(st['median_db'])} | "
                 f"{fmt(st['t_median_ms'], '.1f')} | {fmt(st['t_mean_ms'], '.1f')} |")  # fmt: skip
    L.append("")
    verdicts = []
    for stat, tkey in (("max_db", "t_median_ms"), ("median_db", "t_median_ms"),
                       ("max_db", "t_mean_ms")):  # fmt: skip
        xs = [st[tkey] for _, st in e_sub]
        ys = [st[stat] for _, st in e_sub]
        t_eq, extrap = loglog_at(xs, ys, d_sub[stat])
        ratio = t_eq / d_sub[tkey]
        verdicts.append(ratio)
        slope = (math.log(ys[-1]) - math.log(ys[-2])) / (math.log(xs[-1]) - math.log(xs[-2]))
        how = "interpolated between its settings"
        if extrap:
            how = (
                "extrapolated along the log–log line through its two finest settings, "
                f"d log error / d log time = {slope:.2f}"
            )
        L.append(
            f"   - {stat.replace('_db', '')} error, {tkey.replace('t_', '').replace('_ms', '')} "
            f"time: euler needs ≈ {t_eq:.0f} ms/point for {fmt(d_sub[stat])} dB "
            f"({how}), "
            f"{ratio:.0f}× the default."
        )
    lem = next((st for row, st in stats if row.family == "euler + Lemke"), None)
    prt = port.extra["time_vs_numba_euler"]
    ok2 = verdicts[0] >= 50
    L.append(
        f"   - **{'Met' if ok2 else 'NOT met'}** against numba euler with the closed-form LCP "
        f"(max-error criterion, median time: {verdicts[0]:.0f}×)."
        + (
            f" With Lemke at every step (as published, compiled) euler is a further "
            f"{lem['time_vs_closed']:.2f}× slower, i.e. "
            f"≈ {verdicts[0] * lem['time_vs_closed']:.0f}×."
            if lem
            else ""
        )  # fmt: skip
        + f" The plain Python/NumPy port is {prt:.0f}× slower than numba euler at the same "
        f"setting, i.e. ≈ {verdicts[0] * prt:.0f}× the default at equal accuracy."
    )
    # 3: event at 1e-6 dB
    ev = [(row.setting, st) for row, st in stats if row.family == "event"]
    good = [(n, st) for n, st in ev if st["max_db"] <= 1e-6 and st["mismatch"] == 0]
    L.append("")
    if good:
        n, st = min(good, key=lambda x: x[1]["t_median_ms"])
        ratio = st["t_median_ms"] / dflt["t_median_ms"]
        ratio_mean = st["t_mean_ms"] / dflt["t_mean_ms"]
        ok3 = ratio <= 2.0
        L.append(
            f"3. **event reaches 1e-6 dB in ≤ 2× the default's time: "
            f"{'met' if ok3 else 'NOT met'}.** Cheapest event setting within 1e-6 dB at every "
            f"periodic point: {n} (max {fmt(st['max_db'])} dB), median "
            f"{st['t_median_ms']:.1f} ms/point = {ratio:.2f}× the default's "
            f"{dflt['t_median_ms']:.1f} ms (mean: {ratio_mean:.2f}×). Note the reference is "
            "the same solver at tighter settings; its independent check is the agreement "
            "of all three families as the steps shrink."
        )
    else:
        L.append("3. **event reaches 1e-6 dB: no event setting did** (see the table).")
    md = "\n".join(L) + "\n"
    (args.out / "work_precision.md").write_text(md)
    if not args.no_plot:
        plot(stats, args.out / "work_precision.png")
    print(md)
    return 0


def plot(stats: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fams = {}
    for row, st in stats:
        if row.family.startswith("exponential (ablation)"):
            continue
        fam = row.family
        if row.family == "event":
            fam = (
                "event (tol 1e-12, grid)" if "tol 1e-12" in row.setting else "event (grid 64, tol)"
            )
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
        if (row.family, row.setting) == DEFAULT:
            ax.loglog([st["t_median_ms"]], [st["max_db"]], "k*", ms=14, label="default")
    ax.axhline(1e-3, color="grey", lw=0.8, ls=":")
    ax.axhline(1e-6, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("median wall time per point (ms, one core)")
    ax.set_ylabel("|ΔΓ| against the reference (dB), periodic points")
    ax.set_title("Work–precision, three 60-point spectra")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
