"""Numerical stability under stress: extreme parameters for every method, against references.

    python benchmarks/stress.py [--out benchmarks/results] [--lhs 100] [--timeout 20] [--quick]

Design (MODEL.md base point θ 0.3, σ 0.05, γ_s 1, ξ 0.05, gap 0.1, 5 modes):

* one-at-a-time extremes around the base point at γ_r 0.85 and 2.0, both couplings: θ 1e-3 and
  1e3, σ 1e-4 and 10, γ_s 0.1 and 10, ξ 0 and 0.5, gaps 0, 1e-9, 1e-3, 1e6, asymmetric gaps,
  modes 1 and 30; and γ_r 0.01 and 50 themselves;
* a Latin-hypercube sample of combinations (θ, σ, γ_s, γ_r log-uniform over those ranges, ξ
  uniform in 0…0.5, g1 log-uniform in 1e-4…1e2 with g2/g1 log-uniform in 1e-2…1e2, modes 1…30,
  coupling alternating), seed 7;
* a few runs of 10,000 periods (``early_stop`` off).

Every point runs through ``simulate_chunk`` for each method (``exponential`` default,
``event``, ``euler`` at its default steps), in a separate worker process with a wall budget
(``--timeout``), so a hang is recorded instead of stalling the sweep. Each record is checked:
no NaN/inf anywhere; either finite Γ, amplitude and θ_eff, or ``failed`` with a non-empty
reason. Periodic points are compared with a reference: the pinned closed form for g1 = g2 = 0,
the linear closed form for gaps >= 1e6 without impacts, otherwise ``event`` at tight settings
(256 sub-grid intervals per period, event tolerance 1e-13·T, periodicity tolerance 1e-10).

Outcome per run: ok-periodic (agrees), ok-irregular (the method or the reference found no
period, or their periods differ: no pointwise limit), ok-unchecked (periodic, reference failed),
failed-with-reason, disagreeing, non-finite-record, timeout, crashed.

Also: the modal convergence table (Γ against modes 1…30, ``event``) and ``euler`` near and
past its stability limit. Writes ``stress.md`` and ``stress.csv``.
"""

from __future__ import annotations

import argparse
import csv
import math
import multiprocessing as mp
import re
import time
import traceback
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, g1=0.1, g2=0.1, modes=5)
METHODS = ("exponential", "event", "euler")
# Stated accuracy of Γ (dB) at periodic points, per method and reference (docs/accuracy.md).
TOL = {
    "exponential": {"event": 1e-3, "linear": 1e-4, "pinned": 1e-3},
    "event": {"event": 1e-6, "linear": 1e-6, "pinned": 1e-5},
    "euler": {"event": 0.1, "linear": 0.1, "pinned": 0.1},
}
REF_SOLVER = dict(method="event", steps_per_period=256, periodicity_tol=1e-10)
REF_EVENT_TOL = 1e-13
LONG_PERIODS = 10_000
OUTCOMES = (
    "ok-periodic",
    "ok-irregular",
    "ok-unchecked",
    "failed-with-reason",
    "disagreeing",
    "non-finite-record",
    "timeout",
    "crashed",
)


# --------------------------------------------------------------------------- design


def oat_points() -> list[dict[str, Any]]:
    """One-at-a-time extremes around the base point."""
    changes: list[tuple[str, dict[str, Any]]] = [
        ("base", {}),
        ("theta=1e-3", {"theta": 1e-3}),
        ("theta=1e3", {"theta": 1e3}),
        ("sigma=1e-4", {"sigma": 1e-4}),
        ("sigma=10", {"sigma": 10.0}),
        ("gamma_s=0.1", {"gamma_s": 0.1}),
        ("gamma_s=10", {"gamma_s": 10.0}),
        ("xi=0", {"xi": 0.0}),
        ("xi=0.5", {"xi": 0.5}),
        ("gaps=0", {"g1": 0.0, "g2": 0.0}),
        ("gaps=1e-9", {"g1": 1e-9, "g2": 1e-9}),
        ("gaps=1e-3", {"g1": 1e-3, "g2": 1e-3}),
        ("gaps=1e6", {"g1": 1e6, "g2": 1e6}),
        ("gaps=0.1/1e6", {"g1": 0.1, "g2": 1e6}),
        ("gaps=1e-3/1", {"g1": 1e-3, "g2": 1.0}),
        ("gaps=0/0.1", {"g1": 0.0, "g2": 0.1}),
        ("modes=1", {"modes": 1}),
        ("modes=30", {"modes": 30}),
    ]
    pts = []
    for coupling in ("paper", "full"):
        for g in (0.85, 2.0):
            for label, ch in changes:
                pts.append(
                    {"label": f"oat {label} γr={g}", **BASE, "gamma_r": g, "coupling": coupling,
                     **ch}
                )  # fmt: skip
        for g in (0.01, 50.0):
            pts.append({"label": f"oat gamma_r={g}", **BASE, "gamma_r": g, "coupling": coupling})
    return pts


def lhs_points(n: int, seed: int = 7) -> list[dict[str, Any]]:
    """Latin-hypercube sample of combinations over the extreme ranges."""
    rng = np.random.default_rng(seed)
    dims = 8
    u = (rng.permuted(np.tile(np.arange(n), (dims, 1)), axis=1).T + rng.random((n, dims))) / n
    lg = lambda x, lo, hi: 10 ** (math.log10(lo) + x * (math.log10(hi) - math.log10(lo)))  # noqa: E731
    pts = []
    for i, r in enumerate(u):
        g1 = lg(r[5], 1e-4, 1e2)
        pts.append(
            {
                "label": f"lhs {i}",
                "theta": lg(r[0], 1e-3, 1e3),
                "sigma": lg(r[1], 1e-4, 10.0),
                "gamma_s": lg(r[2], 0.1, 10.0),
                "gamma_r": lg(r[3], 0.01, 50.0),
                "xi": 0.5 * r[4],
                "g1": g1,
                "g2": g1 * lg(r[6], 1e-2, 1e2),
                "modes": 1 + min(29, int(r[7] * 30)),
                "coupling": ("paper", "full")[i % 2],
            }
        )
    return pts


def long_points() -> list[dict[str, Any]]:
    """Runs of the whole 10,000-period budget (early stop off)."""
    return [
        {"label": "long base γr=0.85", **BASE, "gamma_r": 0.85, "coupling": "paper"},
        {"label": "long full γr=2.0", **BASE, "gamma_r": 2.0, "coupling": "full"},
        {"label": "long irregular γr=5.0", **BASE, "gamma_r": 5.0, "coupling": "paper"},
    ]


# --------------------------------------------------------------------------- worker process


def _serve(conn) -> None:
    """Worker loop: run tasks sent over ``conn`` until ``None``."""
    from worker.event import simulate_event
    from worker.model import CellParams
    from worker.simulate import POINT_KEYS, SolverSettings, simulate_chunk, warm_up

    warm_up()
    conn.send(("ready", None, 0.0))
    while True:
        task = conn.recv()
        if task is None:
            return
        kind, point, solver = task
        t0 = time.perf_counter()
        try:
            if kind == "chunk":
                out = simulate_chunk([point], solver)[0]
            else:  # tight event reference; a refusal is a failed reference
                try:
                    p = CellParams(**{k: point[k] for k in POINT_KEYS if k in point})
                    r = simulate_event(p, SolverSettings(**solver), event_tol=REF_EVENT_TOL)
                    out = r.as_dict()
                except ValueError as exc:
                    out = {"failed": True, "reason": str(exc)}
            conn.send(("ok", out, time.perf_counter() - t0))
        except Exception:  # noqa: BLE001 - anything else is a crash, reported
            conn.send(("crashed", traceback.format_exc(), time.perf_counter() - t0))


class Runner:
    """One worker process with a wall budget per task; restarted after a timeout or crash."""

    def __init__(self, timeout: float):
        self.timeout = timeout
        self.ctx = mp.get_context("spawn")
        self.proc = None
        self.conn = None

    def _start(self) -> None:
        self.conn, child = self.ctx.Pipe()
        self.proc = self.ctx.Process(target=_serve, args=(child,), daemon=True)
        self.proc.start()
        self.conn.recv()  # ready (compiled / loaded from numba's cache)

    def run(self, kind: str, point: dict[str, Any], solver: dict[str, Any]):
        if self.proc is None or not self.proc.is_alive():
            self._start()
        t0 = time.perf_counter()
        self.conn.send((kind, point, solver))
        if not self.conn.poll(self.timeout):
            self.close(kill=True)
            return "timeout", None, time.perf_counter() - t0
        try:
            status, out, _ = self.conn.recv()
        except EOFError:
            self.close(kill=True)
            return "crashed", "worker process died", time.perf_counter() - t0
        return status, out, time.perf_counter() - t0

    def close(self, kill: bool = False) -> None:
        if self.proc is None:
            return
        if kill:
            self.proc.kill()
        else:
            self.conn.send(None)
        self.proc.join(5)
        self.proc = None


# --------------------------------------------------------------------------- checks


def non_finite_fields(rec: dict[str, Any]) -> list[str]:
    """Fields holding NaN or inf (lists included)."""
    bad = []
    for k, v in rec.items():
        vals = v if isinstance(v, (list, tuple)) else [v]
        if any(isinstance(x, float) and not math.isfinite(x) for x in vals):
            bad.append(k)
    return bad


def closed_form(point: dict[str, Any]) -> tuple[str, float | None]:
    """('pinned' | 'linear' | 'event', Γ or None)."""
    from worker.model import CellParams, linear_transmittance_db, pinned_transmittance_db
    from worker.simulate import POINT_KEYS

    p = CellParams(**{k: point[k] for k in POINT_KEYS if k in point})
    if p.g1 == 0.0 and p.g2 == 0.0:
        return "pinned", pinned_transmittance_db(p)
    if min(p.g1, p.g2) >= 1e6:
        return "linear", linear_transmittance_db(p)
    return "event", None


def classify(method: str, status: str, rec, ref_kind: str, ref_db, ref_rec) -> tuple[str, str]:
    """Outcome and a note for one run."""
    if status in ("timeout", "crashed"):
        return status, "" if status == "timeout" else str(rec).strip().splitlines()[-1]
    bad = non_finite_fields(rec)
    if bad:
        return "non-finite-record", ",".join(bad)
    if rec["failed"]:
        return ("failed-with-reason", rec["reason"]) if rec["reason"] else ("crashed", "no reason")
    vals = [rec["transmittance_db"], rec["amplitude"], rec["theta_eff"]]
    if not all(isinstance(v, float) and math.isfinite(v) for v in vals):
        return "non-finite-record", "missing value"
    if not rec["converged"]:
        return "ok-irregular", "method irregular"
    if ref_kind == "linear" and sum(rec["impacts_per_period"]) > 0:
        ref_kind = "event"  # the closed form needs an impact-free response
    if ref_kind in ("linear", "pinned"):
        d = abs(rec["transmittance_db"] - ref_db)
        ok = d <= TOL[method][ref_kind]
        return ("ok-periodic" if ok else "disagreeing"), f"{ref_kind} |ΔΓ|={d:.3g}"
    if ref_rec is None or ref_rec.get("failed", True):
        return "ok-unchecked", "reference failed"
    if not ref_rec["converged"]:
        return "ok-irregular", "reference irregular"
    if ref_rec["response_period"] != rec["response_period"]:
        return "ok-irregular", (
            f"period {rec['response_period']} vs reference {ref_rec['response_period']}"
        )
    d = abs(rec["transmittance_db"] - ref_rec["transmittance_db"])
    ok = d <= TOL[method]["event"]
    return ("ok-periodic" if ok else "disagreeing"), f"event |ΔΓ|={d:.3g}"


def reason_group(reason: str) -> str:
    """A failure reason with its numbers replaced, to group like reasons."""
    return re.sub(r"[-+]?\d[\d.]*(e[-+]?\d+)?", "#", reason)[:110]


# --------------------------------------------------------------------------- sections


def modal_table(lines: list[str], rows_out: list[dict]) -> None:
    from worker.model import CellParams
    from worker.simulate import SolverSettings, simulate_point

    modes = (1, 2, 3, 5, 8, 12, 20, 30)
    lines += [
        "## Modal convergence",
        "",
        "`event` (default settings), θ 0.3, σ 0.05, γ_s 1, ξ 0.05, gap 0.1. Γ(30) in dB, then "
        "|Γ(n) − Γ(30)| in dB (p = response period at n; * marks a period different from n = 30 "
        "or irregular).",
        "",
        "| coupling | γ_r | Γ(30) dB | p | impacts/period | "
        + " | ".join(f"n={n}" for n in modes[:-1])
        + " |",
        "|---|---|---|---|---|" + "---|" * (len(modes) - 1),
    ]
    for c in ("paper", "full"):
        for g in (0.85, 1.5, 2.0, 3.5):
            res = {}
            for n in modes:
                p = CellParams(**{**BASE, "gamma_r": g, "modes": n, "coupling": c})
                res[n] = simulate_point(p, SolverSettings(method="event"))
            ref = res[30]
            cells = []
            for n in modes[:-1]:
                r = res[n]
                mark = "" if r.converged and r.response_period == ref.response_period else "*"
                if r.transmittance_db is None:
                    cells.append("failed")
                    continue
                d = abs(r.transmittance_db - ref.transmittance_db)
                cells.append(f"{d:.2e}{mark}")
                rows_out.append(dict(section="modal", coupling=c, gamma_r=g, modes=n,
                                     transmittance_db=r.transmittance_db, diff_db=d,
                                     response_period=r.response_period))  # fmt: skip
            lines.append(
                f"| {c} | {g} | {ref.transmittance_db:.6f} | {ref.response_period} | "
                f"{sum(ref.impacts_per_period):g} | " + " | ".join(cells) + " |"
            )
    lines.append("")


def min_stable_steps(sys_) -> int:
    """Smallest steps_per_period the euler scheme accepts for this system."""
    from worker.simulate import _euler_check

    T = 2.0 * math.pi / sys_.params.gamma_r
    n = max(4, math.ceil(T * sys_.omega_max() / 2.0) - 2)
    while True:
        try:
            _euler_check(sys_, T / n)
            return n
        except ValueError:
            n += 1


def euler_table(lines: list[str], rows_out: list[dict]) -> None:
    from worker.event import simulate_event
    from worker.model import CellParams, assemble
    from worker.simulate import SolverSettings, euler_default_steps, simulate_point

    cases = [
        ("base γ_r 0.85 paper", {**BASE, "gamma_r": 0.85}),
        ("γ_r 2.0 full", {**BASE, "gamma_r": 2.0, "coupling": "full"}),
        ("ξ 0.5, σ 1, 8 modes, γ_r 0.85", {**BASE, "gamma_r": 0.85, "xi": 0.5, "sigma": 1.0,
                                            "modes": 8}),
    ]  # fmt: skip
    lines += [
        "## `euler` near and past its stability limit",
        "",
        "n_min is the smallest `steps_per_period` the scheme accepts (Δτ·ω̃_max < 2 and spectral "
        "radius of its free-flight step <= 1). Reference: `event` at tight settings. "
        "Below n_min the point is refused with a `ValueError` (via `simulate_chunk`: failed "
        "with that reason).",
        "",
    ]
    for label, kw in cases:
        p = CellParams(**kw)
        sys_ = assemble(p)
        T = 2.0 * math.pi / p.gamma_r
        wmax = sys_.omega_max()
        nmin = min_stable_steps(sys_)
        ref = simulate_event(p, SolverSettings(**REF_SOLVER), event_tol=REF_EVENT_TOL)
        lines += [
            f"**{label}**: ω̃_max = {wmax:.4g}, n_min = {nmin} (Δτ·ω̃_max = "
            f"{T / nmin * wmax:.4f}), default {euler_default_steps(sys_)}; reference Γ = "
            f"{ref.transmittance_db:.6f} dB (p = {ref.response_period}).",
            "",
        ]
        try:
            simulate_point(p, SolverSettings(method="euler", steps_per_period=nmin - 1))
            lines.append(f"- {nmin - 1} steps: NOT refused (problem)")
        except ValueError as exc:
            lines.append(f"- {nmin - 1} steps (n_min − 1): refused — “{exc}”")
        lines += [
            "",
            "| steps/period | × n_min | Δτ·ω̃_max | Γ dB | |ΔΓ| dB | p | ms |",
            "|---|---|---|---|---|---|---|",
        ]
        for f in (1.0, 1.05, 1.5, 2.0, 4.0, 16.0, 64.0):
            n = math.ceil(f * nmin)
            t0 = time.perf_counter()
            r = simulate_point(p, SolverSettings(method="euler", steps_per_period=n))
            ms = 1e3 * (time.perf_counter() - t0)
            if r.failed:
                lines.append(f"| {n} | {f} | {T / n * wmax:.3f} | failed: {r.reason} | | | |")
                continue
            d = abs(r.transmittance_db - ref.transmittance_db)
            lines.append(
                f"| {n} | {f} | {T / n * wmax:.3f} | {r.transmittance_db:.6f} | {d:.2e} | "
                f"{r.response_period} | {ms:.0f} |"
            )
            rows_out.append(dict(section="euler", label=label, steps_per_period=n, factor=f,
                                 transmittance_db=r.transmittance_db, diff_db=d,
                                 response_period=r.response_period))  # fmt: skip
        lines.append("")


# --------------------------------------------------------------------------- main


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    ap.add_argument("--lhs", type=int, default=100, help="Latin-hypercube points")
    ap.add_argument("--timeout", type=float, default=20.0, help="wall budget per run, s")
    ap.add_argument("--quick", action="store_true", help="10 LHS points, no long runs")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    n_lhs = 10 if args.quick else args.lhs
    t_start = time.perf_counter()

    design = [("oat", p) for p in oat_points()] + [("lhs", p) for p in lhs_points(n_lhs)]
    if not args.quick:
        design += [("long", p) for p in long_points()]
    runner = Runner(args.timeout)
    rows = []
    for i, (kind, pt) in enumerate(design):
        point = {k: v for k, v in pt.items() if k != "label"}
        ref_kind, ref_db = closed_form(point)
        solver_extra = {"max_periods": LONG_PERIODS, "early_stop": False} if kind == "long" else {}
        ref_status, ref_rec, ref_wall = runner.run("ref", point, {**REF_SOLVER, **solver_extra})
        if ref_status != "ok":
            ref_rec = None
        for method in METHODS:
            status, rec, wall = runner.run("chunk", point, {"method": method, **solver_extra})
            outcome, note = classify(method, status, rec, ref_kind, ref_db, ref_rec)
            row = dict(design=kind, label=pt["label"], method=method, outcome=outcome,
                       note=note, wall_s=wall, ref_status=ref_status, ref_wall_s=ref_wall,
                       **point)  # fmt: skip
            if status == "ok":
                for k in ("transmittance_db", "theta_eff", "response_period", "converged",
                          "periods", "steps", "steps_per_period", "reason"):  # fmt: skip
                    row[k] = rec.get(k)
                if kind == "long" and not rec["failed"] and rec["periods"] != LONG_PERIODS:
                    row["outcome"], row["note"] = "crashed", f"ran {rec['periods']} periods"
            if ref_rec and not ref_rec.get("failed", True):
                row["ref_db"] = ref_rec["transmittance_db"]
                row["ref_period"] = ref_rec["response_period"]
            if ref_db is not None:
                row["closed_form_db"] = ref_db
            rows.append(row)
        done = ", ".join(f"{r['method']} {r['outcome']}" for r in rows[-3:])
        print(f"{i + 1}/{len(design)} {pt['label']}: {done}", flush=True)
    runner.close()
    sweep_s = time.perf_counter() - t_start

    fields = [
        "design", "label", "method", "outcome", "note", "wall_s", "theta", "sigma", "gamma_s",
        "gamma_r", "xi", "g1", "g2", "modes", "coupling", "transmittance_db", "ref_db",
        "closed_form_db", "theta_eff", "response_period", "ref_period", "converged", "periods",
        "steps", "steps_per_period", "reason", "ref_status", "ref_wall_s",
    ]  # fmt: skip
    with open(args.out / "stress.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)

    lines = report(rows, design, args, sweep_s)
    extra_rows: list[dict] = []
    modal_table(lines, extra_rows)
    euler_table(lines, extra_rows)
    lines.append(f"Total run time {time.perf_counter() - t_start:.0f} s.")
    (args.out / "stress.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def report(rows, design, args, sweep_s) -> list[str]:
    n_oat = sum(1 for k, _ in design if k == "oat")
    n_lhs = sum(1 for k, _ in design if k == "lhs")
    n_long = sum(1 for k, _ in design if k == "long")
    lines = [
        "# Stress sweep",
        "",
        f"`python benchmarks/stress.py` — {n_oat} one-at-a-time extremes, {n_lhs} Latin-"
        f"hypercube points, {n_long} runs of {LONG_PERIODS} periods; each through "
        f"`simulate_chunk`, one worker process, wall budget {args.timeout:.0f} s per run. "
        f"Sweep {sweep_s:.0f} s on a shared 2-core machine.",
        "",
        "Reference: pinned closed form (g1 = g2 = 0), linear closed form (gaps >= 1e6, no "
        "impacts), else `event` at tight settings (256 intervals/period, event tol 1e-13·T, "
        "periodicity tol 1e-10). Tolerance on |ΔΓ| at periodic points (same period as the "
        "reference): "
        + "; ".join(
            f"{m} " + ", ".join(f"{k} {v:g} dB" for k, v in TOL[m].items()) for m in METHODS
        )
        + ".",
        "",
        "## Outcomes per method",
        "",
        "| method | " + " | ".join(OUTCOMES) + " | max wall s | median wall s |",
        "|---|" + "---|" * (len(OUTCOMES) + 2),
    ]
    for m in METHODS:
        rs = [r for r in rows if r["method"] == m]
        c = Counter(r["outcome"] for r in rs)
        walls = [r["wall_s"] for r in rs]
        lines.append(
            f"| {m} | "
            + " | ".join(str(c.get(o, 0)) for o in OUTCOMES)
            + f" | {max(walls):.2f} | {np.median(walls):.3f} |"
        )
    lines.append("")
    lines += ["## |ΔΓ| at agreeing periodic points", ""]
    lines += ["| method | reference | n | max dB | median dB |", "|---|---|---|---|---|"]
    for m in METHODS:
        by = defaultdict(list)
        for r in rows:
            if r["method"] == m and r["outcome"] in ("ok-periodic", "disagreeing"):
                kind, val = r["note"].split(" |ΔΓ|=")
                by[kind].append(float(val))
        for kind, v in sorted(by.items()):
            lines.append(f"| {m} | {kind} | {len(v)} | {max(v):.2e} | {np.median(v):.2e} |")
    lines.append("")
    lines += ["## Failure reasons (numbers replaced by #)", ""]
    lines += ["| method | count | reason |", "|---|---|---|"]
    for m in METHODS:
        c = Counter(
            reason_group(r["note"])
            for r in rows
            if r["method"] == m and r["outcome"] == "failed-with-reason"
        )
        for reason, n in c.most_common():
            lines.append(f"| {m} | {n} | {reason} |")
    lines.append("")
    irr = Counter((r["method"], r["note"]) for r in rows if r["outcome"] == "ok-irregular")
    lines += ["## Irregular or classified differently", ""]
    lines += ["| method | note | count |", "|---|---|---|"]
    for (m, note), n in sorted(irr.items()):
        lines.append(f"| {m} | {reason_group(note)} | {n} |")
    lines.append("")
    problems = [
        r
        for r in rows
        if r["outcome"] in ("disagreeing", "non-finite-record", "timeout", "crashed")
    ]
    lines += ["## Problems (disagreeing, non-finite, timeout, crashed)", ""]
    if not problems:
        lines.append("None.")
    else:
        lines += ["| method | outcome | point | note | wall s |", "|---|---|---|---|---|"]
        for r in problems:
            pt = ", ".join(
                f"{k}={r[k]:.3g}" if isinstance(r[k], float) else f"{k}={r[k]}"
                for k in (
                    "theta",
                    "sigma",
                    "gamma_s",
                    "gamma_r",
                    "xi",
                    "g1",
                    "g2",
                    "modes",
                    "coupling",
                )  # fmt: skip
            )
            lines.append(
                f"| {r['method']} | {r['outcome']} | {r['label']}: {pt} | {r['note']} | "
                f"{r['wall_s']:.1f} |"
            )
    lines.append("")
    longs = [r for r in rows if r["design"] == "long"]
    if longs:
        lines += [
            f"## Runs of {LONG_PERIODS} periods (early stop off)",
            "",
            "| point | method | outcome | periods | Γ dB | wall s |",
            "|---|---|---|---|---|---|",
        ]
        for r in longs:
            db = r.get("transmittance_db")
            lines.append(
                f"| {r['label']} | {r['method']} | {r['outcome']} | {r.get('periods')} | "
                f"{'' if db is None else f'{db:.6f}'} | {r['wall_s']:.1f} |"
            )
        lines.append("")
    return lines


if __name__ == "__main__":
    main()
