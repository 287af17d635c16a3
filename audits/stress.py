"""Numerical stability under stress: extreme parameters for every method, against references.

    python audits/stress.py [--out audits/results] [--lhs 100] [--timeout 20] [--quick]
    python audits/stress.py --random N [--seed S]      # N random cells only

Design (base point θ 0.3, σ 0.05, γ_s 1, ξ 0.05, gap 0.1, 5 modes):

* one-at-a-time extremes around the base point at γ_r 0.85 and 2.0, both couplings: θ 1e-3 and
  1e3, σ 1e-4 and 10, γ_s 0.1 and 10, ξ 0 and 0.5, gaps 0, 1e-9, 1e-3, 1e6, asymmetric gaps,
  modes 1 and 30; and γ_r 0.01 and 50 themselves;
* the named cases of issue 11, each with what it should give: non-impacting points (θ 1, ξ 0.02,
  gap 0.5, γ_r 5.6, 6.0, 3.3: ``linear``, equal to the closed form), transient chaos (θ 1,
  ξ 0.02, γ_r 5.25 gap 0.5 and γ_r 4.3 gap 0.3: ``linear``, or ``irregular``/``unsettled``
  labelled with a reason), divergence (paper coupling θ 500 at γ_r 0.85 and 2.0: ``failed``),
  an undamped resonance (ξ 0, gaps 1e6, γ_r 1: ``failed``), exponential's fine step at low
  frequency (σ 10, γ_r 0.01, 0.011, 0.012, gaps 0 and 1e-7: finite and agreeing with the
  references) and huge gaps (1e10, 1e12 at γ_r 0.85 and 2.0: ``linear``, the closed form);
* a Latin-hypercube sample of combinations (θ, σ, γ_s, γ_r log-uniform over those ranges, ξ
  uniform in 0…0.5, g1 log-uniform in 1e-4…1e2 with g2/g1 log-uniform in 1e-2…1e2, modes 1…30,
  coupling alternating), seed 7 (``--seed``);
* a few runs of 10,000 periods (``early_stop`` off).

Every point runs through ``simulate_chunk`` for each method (``event``, the default;
``exponential``; ``euler``; all at their default settings), in a separate worker process with a
wall budget (``--timeout``), so a hang is recorded instead of stalling the sweep. Each record is
checked: no NaN/inf anywhere; either finite Γ, amplitude and θ_eff, or ``failed`` with a
non-empty reason. Points are compared with a reference: the pinned closed form for g1 = g2 = 0,
the linear closed form where the method reports ``linear`` or the gaps are >= 1e6 without
impacts, otherwise ``event`` at tight settings (256 sub-grid intervals per period, event
tolerance 1e-13·T, periodicity tolerance 1e-11). Tolerances on |ΔΓ|: event 1e-6 dB against
every reference; exponential 1e-3 dB (event), 1e-4 dB (linear, pinned); euler 0.1 dB.

Classification of each run (from the point's ``outcome``): ok-periodic (``periodic`` or
``linear`` and agreeing with its reference), ok-irregular (``irregular`` or ``unsettled``, or
converged where the reference is not or has another period; an irregular run with an irregular
reference within 4 combined standard errors of it), irregular-apart (both irregular, farther
apart than that), ok-unchecked
(converged, no reference), failed-with-reason, disagreeing, silent-divergence (not failed, but Γ
above 200 dB or the reference diverged: a finite Γ from a diverged state; the goal is none),
non-finite-record, timeout, crashed.

Also: the modal convergence table (Γ against modes 1…30, ``event``) and ``euler`` near and
past its stability limit. Writes ``stress.md`` and ``stress.csv``.

``--random N`` runs only N Latin-hypercube cells of seed ``--seed`` (the same ranges, checks
and references; no extremes, named cases, long runs or tables), a fresh sample where the
sweep's own seed 7 has been looked at already, and writes ``stress_random<S>.md`` and ``.csv``.
"""

from __future__ import annotations

import argparse
import csv
import math
import multiprocessing as mp
import os
import platform
import re
import sys
import time
import traceback
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# The worker process imports ``worker`` from this checkout, not from wherever the package is
# installed: comparing two checkouts must run each one's code.
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from audits.common import RESULTS  # noqa: E402
from service.regression.spec import IrregularCheck  # noqa: E402

BASE = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, g1=0.1, g2=0.1, modes=5)
METHODS = ("event", "exponential", "euler")  # the default first
# Stated accuracy of Γ (dB) at converged points, per method and reference (docs/accuracy.md).
TOL = {
    "event": {"event": 1e-6, "linear": 1e-6, "pinned": 1e-6},
    "exponential": {"event": 1e-3, "linear": 1e-4, "pinned": 1e-4},
    "euler": {"event": 0.1, "linear": 0.1, "pinned": 0.1},
}
REF_SOLVER = dict(method="event", steps_per_period=256, periodicity_tol=1e-11)
REF_EVENT_TOL = 1e-13
LONG_PERIODS = 10_000
SILENT_DB = 200.0  # a Γ above this is a diverged state reported as a number
# failure reasons of a reference that mean the state diverged (or grows without bound)
DIVERGED = re.compile(r"diverg|finite|without bound|undamped resonance|secular growth")
OUTCOMES = (
    "ok-periodic",
    "ok-irregular",
    "irregular-apart",
    "ok-unchecked",
    "failed-with-reason",
    "disagreeing",
    "silent-divergence",
    "non-finite-record",
    "timeout",
    "crashed",
)
# Irregular runs and their irregular references agree within this many combined standard
# errors: the nightly suite's default (``IrregularCheck.error_bars``)
ERROR_BARS = float(IrregularCheck().error_bars or 4.0)
POINT_FIELDS = ("theta", "sigma", "gamma_s", "gamma_r", "xi", "g1", "g2", "modes", "coupling")


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


# What a named case should give (``as_expected``).
EXPECT_TEXT = {
    "linear": "linear = closed form",
    "transient": "linear, or irregular/unsettled with a reason",
    "failed": "failed with a reason",
    "agree": "finite, agreeing with the references",
}


def named_points() -> list[dict[str, Any]]:
    """The explicit cases of issue 11 (base point and paper coupling unless stated)."""
    soft = dict(theta=1.0, xi=0.02)
    cases: list[tuple[str, dict[str, Any], str]] = []
    for g in (5.6, 6.0, 3.3):
        cases.append((f"non-impacting θ 1 ξ 0.02 gap 0.5 γr={g}",
                      {**soft, "g1": 0.5, "g2": 0.5, "gamma_r": g}, "linear"))  # fmt: skip
    cases.append(("transient chaos θ 1 ξ 0.02 gap 0.5 γr=5.25",
                  {**soft, "g1": 0.5, "g2": 0.5, "gamma_r": 5.25}, "transient"))  # fmt: skip
    cases.append(("transient chaos θ 1 ξ 0.02 gap 0.3 γr=4.3",
                  {**soft, "g1": 0.3, "g2": 0.3, "gamma_r": 4.3}, "transient"))  # fmt: skip
    for g in (0.85, 2.0):
        cases.append((f"paper coupling θ 500 γr={g}", {"theta": 500.0, "gamma_r": g}, "failed"))
    cases.append(("undamped resonance ξ 0 gaps 1e6 γr=1",
                  {"xi": 0.0, "g1": 1e6, "g2": 1e6, "gamma_r": 1.0}, "failed"))  # fmt: skip
    for g in (0.01, 0.011, 0.012):
        for gap in (0.0, 1e-7):
            ch = {"sigma": 10.0, "g1": gap, "g2": gap, "gamma_r": g}
            cases.append((f"σ 10 gaps {gap:g} γr={g}", ch, "agree"))
    for gap in (1e10, 1e12):
        for g in (0.85, 2.0):
            cases.append((f"gaps {gap:.0e} γr={g}", {"g1": gap, "g2": gap, "gamma_r": g}, "linear"))
    return [{"label": f"case {label}", "expect": expect, **BASE, "coupling": "paper", **ch}
            for label, ch, expect in cases]  # fmt: skip


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
    from worker.model import CellParams
    from worker.simulate import POINT_KEYS, SolverSettings, simulate_chunk, simulate_point, warm_up

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
                    r = simulate_point(p, SolverSettings(**solver), event_tol=REF_EVENT_TOL)
                    out = r.as_dict()
                except ValueError as exc:
                    out = {"failed": True, "outcome": "failed", "reason": str(exc)}
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


@dataclass(frozen=True)
class ClosedForms:
    """The references a point has in closed form (``None`` where there is none)."""

    kind: str  # "pinned" (g1 = g2 = 0), "linear" (gaps >= 1e6) or "event"
    pinned_db: float | None
    linear_db: float | None  # the impact-free steady state (None: undamped resonance)


def closed_forms(point: dict[str, Any]) -> ClosedForms:
    from worker.model import CellParams, linear_transmittance_db, pinned_transmittance_db
    from worker.simulate import POINT_KEYS

    p = CellParams(**{k: point[k] for k in POINT_KEYS if k in point})
    try:
        lin = linear_transmittance_db(p)
    except (ValueError, np.linalg.LinAlgError):
        lin = None
    if p.g1 == 0.0 and p.g2 == 0.0:
        try:
            pinned = pinned_transmittance_db(p)
        except (ValueError, np.linalg.LinAlgError):
            pinned = None
        return ClosedForms("pinned", pinned, lin)
    return ClosedForms("linear" if min(p.g1, p.g2) >= 1e6 else "event", None, lin)


def _ref_state(ref_rec: dict | None) -> str:
    """'none' (no reference run), 'diverged', 'failed', or the reference's outcome."""
    if not ref_rec:
        return "none"
    if ref_rec.get("failed", True):
        return "diverged" if DIVERGED.search(ref_rec.get("reason") or "") else "failed"
    return ref_rec["outcome"]


def _against(method: str, kind: str, db: float, ref_db: float) -> tuple[str, str]:
    d = abs(db - ref_db)
    return ("ok-periodic" if d <= TOL[method][kind] else "disagreeing"), f"{kind} |ΔΓ|={d:.3g}"


def _irregular_pair(rec, ref_rec) -> tuple[str, str]:
    """A run that did not settle: where it and its reference are both irregular with error
    bars, their Γ must agree within ``ERROR_BARS`` combined standard errors, as the nightly
    suite asks of irregular points (``irregular-apart`` where not)."""
    se, ref_se = rec.get("transmittance_db_se"), (ref_rec or {}).get("transmittance_db_se")
    if rec["outcome"] != "irregular" or _ref_state(ref_rec) != "irregular" or not se or not ref_se:
        return "ok-irregular", f"method {rec['outcome']}"
    d = abs(rec["transmittance_db"] - ref_rec["transmittance_db"])
    z = d / math.hypot(se, ref_se)
    note = f"irregular |ΔΓ|={d:.3g} dB = {z:.2g} combined SE"
    return ("ok-irregular" if z <= ERROR_BARS else "irregular-apart"), note


def classify(method: str, status: str, rec, cf: ClosedForms, ref_rec) -> tuple[str, str]:
    """Classification and a note for one run (see the module docstring)."""
    if status in ("timeout", "crashed"):
        return status, "" if status == "timeout" else str(rec).strip().splitlines()[-1]
    bad = non_finite_fields(rec)
    if bad:
        return "non-finite-record", ",".join(bad)
    if rec["failed"]:
        return ("failed-with-reason", rec["reason"]) if rec["reason"] else ("crashed", "no reason")
    db = rec["transmittance_db"]
    ref = _ref_state(ref_rec)
    if isinstance(db, float) and db > SILENT_DB:
        return "silent-divergence", f"{rec['outcome']} with Γ = {db:.4g} dB"
    if ref == "diverged":
        return "silent-divergence", (
            f"{rec['outcome']} Γ = {db:.4g} dB where the reference diverged: "
            f"{ref_rec['reason'][:80]}"
        )
    vals = [db, rec["amplitude"], rec["theta_eff"]]
    if not all(isinstance(v, float) and math.isfinite(v) for v in vals):
        return "non-finite-record", "missing value"
    if rec["outcome"] not in ("linear", "periodic"):
        return _irregular_pair(rec, ref_rec)
    impacts = sum(rec["impacts_per_period"] or (0.0, 0.0))
    if cf.kind == "pinned" and cf.pinned_db is not None:
        return _against(method, "pinned", db, cf.pinned_db)
    ref_impacts = sum((ref_rec or {}).get("impacts_per_period") or (0.0, 0.0))
    if rec["outcome"] == "linear" or (cf.kind == "linear" and impacts == 0):
        if ref == "periodic" and ref_impacts > 0:
            return "ok-irregular", (
                f"linear vs reference periodic p={ref_rec['response_period']} with impacts"
            )
        if cf.linear_db is None:
            return "ok-unchecked", "no closed form"
        return _against(method, "linear", db, cf.linear_db)
    if ref in ("none", "failed"):
        return "ok-unchecked", "reference failed" if ref == "failed" else "no reference"
    if ref in ("irregular", "unsettled"):
        return "ok-irregular", f"reference {ref}"
    if ref_rec["response_period"] != rec["response_period"]:
        return "ok-irregular", (
            f"period {rec['response_period']} vs reference {ref_rec['response_period']}"
        )
    if ref == "linear" and impacts > 0:
        return "ok-irregular", "periodic with impacts vs reference linear"
    return _against(method, "event", db, ref_rec["transmittance_db"])


def as_expected(expect: str, row: dict[str, Any], cf: ClosedForms) -> str:
    """'yes', 'no' or 'unchecked': does a named case give what it should?"""
    if row["outcome"] in ("timeout", "crashed", "non-finite-record", "silent-divergence"):
        return "no"
    out, db, reason = row.get("point_outcome"), row.get("transmittance_db"), row.get("reason")
    closed = (out == "linear" and db is not None and cf.linear_db is not None
              and abs(db - cf.linear_db) <= 1e-6)  # fmt: skip
    if expect == "linear":
        return "yes" if closed else "no"
    if expect == "transient":
        return "yes" if closed or (out in ("irregular", "unsettled") and reason) else "no"
    if expect == "failed":
        return "yes" if out == "failed" and reason else "no"
    if row["outcome"] == "ok-periodic":
        return "yes"
    unchecked = ("ok-irregular", "irregular-apart", "ok-unchecked")
    return "unchecked" if row["outcome"] in unchecked else "no"


def esc(text: str) -> str:
    """Text for a markdown table cell (a bare | would split it)."""
    return str(text).replace("|", "\\|")


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
        "|Γ(n) − Γ(30)| in dB (p = response period at n = 30, or its outcome when not "
        "converged; * marks a period different from n = 30, or a point not converged).",
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
            if ref.failed:
                lines.append(f"| {c} | {g} | failed: {esc(ref.reason)} | | | "
                             + "| " * (len(modes) - 1))  # fmt: skip
                continue
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
                                     response_period=r.response_period,
                                     point_outcome=r.outcome))  # fmt: skip
            lines.append(
                f"| {c} | {g} | {ref.transmittance_db:.6f} | {ref.response_period or ref.outcome}"
                f" | {sum(ref.impacts_per_period):g} | " + " | ".join(cells) + " |"
            )
    lines.append("")


def min_stable_steps(sys_) -> int:
    """Smallest steps_per_period the euler scheme accepts for this system."""
    from worker.solvers.euler import check_stable

    T = 2.0 * math.pi / sys_.params.gamma_r
    n = max(4, math.ceil(T * sys_.omega_max() / 2.0) - 2)
    while True:
        try:
            check_stable(sys_, T / n)
            return n
        except ValueError:
            n += 1


def euler_table(lines: list[str], rows_out: list[dict]) -> None:
    from worker.model import CellParams, assemble
    from worker.simulate import SolverSettings, simulate_point
    from worker.solvers.euler import default_steps

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
        "with that reason). The euler runs here have `linear_tail` off, so the scheme "
        "integrates impact-free tails too (otherwise a point proven linear from rest reports "
        "the closed form without ever building, or checking, the scheme).",
        "",
    ]
    for label, kw in cases:
        p = CellParams(**kw)
        sys_ = assemble(p)
        T = 2.0 * math.pi / p.gamma_r
        wmax = sys_.omega_max()
        nmin = min_stable_steps(sys_)
        ref = simulate_point(p, SolverSettings(**REF_SOLVER), event_tol=REF_EVENT_TOL)
        ref_db = ref.transmittance_db
        lines += [
            f"**{label}**: ω̃_max = {wmax:.4g}, n_min = {nmin} (Δτ·ω̃_max = "
            f"{T / nmin * wmax:.4f}), default {default_steps(sys_)}; reference: {ref.outcome}, "
            + (f"Γ = {ref_db:.6f} dB (p = {ref.response_period})." if ref_db is not None
               else f"{ref.reason}.")
            + ("" if ref.converged else " (|ΔΓ| below is not a pointwise error.)"),
            "",
        ]  # fmt: skip
        try:
            simulate_point(p, SolverSettings(method="euler", steps_per_period=nmin - 1,
                                             linear_tail=False))  # fmt: skip
            lines.append(f"- {nmin - 1} steps: NOT refused (problem)")
        except ValueError as exc:
            lines.append(f"- {nmin - 1} steps (n_min − 1): refused — “{exc}”")
        lines += [
            "",
            "| steps/period | × n_min | Δτ·ω̃_max | Γ dB | abs ΔΓ dB | p | ms |",
            "|---|---|---|---|---|---|---|",
        ]
        for f in (1.0, 1.05, 1.5, 2.0, 4.0, 16.0, 64.0):
            n = math.ceil(f * nmin)
            t0 = time.perf_counter()
            r = simulate_point(p, SolverSettings(method="euler", steps_per_period=n,
                                                 linear_tail=False))  # fmt: skip
            ms = 1e3 * (time.perf_counter() - t0)
            if r.failed:
                lines.append(f"| {n} | {f} | {T / n * wmax:.3f} | failed: {esc(r.reason)} | | | |")
                continue
            d = abs(r.transmittance_db - ref_db) if ref_db is not None else math.nan
            lines.append(
                f"| {n} | {f} | {T / n * wmax:.3f} | {r.transmittance_db:.6f} | {d:.2e} | "
                f"{r.response_period or r.outcome} | {ms:.0f} |"
            )
            rows_out.append(dict(section="euler", label=label, steps_per_period=n, factor=f,
                                 transmittance_db=r.transmittance_db, diff_db=d,
                                 response_period=r.response_period,
                                 point_outcome=r.outcome))  # fmt: skip
        lines.append("")


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--lhs", type=int, default=100, help="Latin-hypercube points")
    ap.add_argument("--timeout", type=float, default=20.0, help="wall budget per run, s")
    ap.add_argument("--quick", action="store_true", help="10 LHS points, no long runs")
    ap.add_argument(
        "--random", type=int, default=0, help="only this many Latin-hypercube cells of --seed"
    )
    ap.add_argument("--seed", type=int, default=7, help="the Latin-hypercube sample's seed")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    command = " ".join(["python audits/stress.py", *argv])
    args.out.mkdir(parents=True, exist_ok=True)
    n_lhs = 10 if args.quick else args.lhs
    t_start = time.perf_counter()

    name = f"stress_random{args.seed}" if args.random else "stress"
    if args.random:
        design = [("lhs", p) for p in lhs_points(args.random, seed=args.seed)]
    else:
        design = [("oat", p) for p in oat_points()] + [("case", p) for p in named_points()]
        design += [("lhs", p) for p in lhs_points(n_lhs, seed=args.seed)]
        if not args.quick:
            design += [("long", p) for p in long_points()]
    runner = Runner(args.timeout)
    rows = []
    for i, (kind, pt) in enumerate(design):
        point = {k: v for k, v in pt.items() if k not in ("label", "expect")}
        cf = closed_forms(point)
        solver_extra = {"max_periods": LONG_PERIODS, "early_stop": False} if kind == "long" else {}
        ref_status, ref_rec, ref_wall = runner.run("ref", point, {**REF_SOLVER, **solver_extra})
        if ref_status != "ok":
            ref_rec = None
        for method in METHODS:
            status, rec, wall = runner.run("chunk", point, {"method": method, **solver_extra})
            outcome, note = classify(method, status, rec, cf, ref_rec)
            row = dict(design=kind, label=pt["label"], method=method, outcome=outcome,
                       note=note, wall_s=wall, ref_status=ref_status, ref_wall_s=ref_wall,
                       **point)  # fmt: skip
            if status == "ok":
                row["point_outcome"] = rec.get("outcome")
                for k in ("transmittance_db", "transmittance_db_se", "theta_eff",
                          "response_period", "periods", "steady_period", "steps",
                          "steps_per_period", "reason"):  # fmt: skip
                    row[k] = rec.get(k)
                if kind == "long" and not rec["failed"] and rec["steady_period"] != LONG_PERIODS:
                    row["outcome"], row["note"] = "crashed", f"ran {rec['steady_period']} periods"
            if ref_rec:
                row["ref_outcome"] = ref_rec.get("outcome")
                row["ref_reason"] = ref_rec.get("reason")
                if not ref_rec.get("failed", True):
                    row["ref_db"] = ref_rec["transmittance_db"]
                    row["ref_period"] = ref_rec["response_period"]
            row["closed_form_db"] = cf.pinned_db if cf.kind == "pinned" else cf.linear_db
            row["kind"] = cf.kind
            if kind == "case":
                row["expect"] = pt["expect"]
                row["as_expected"] = as_expected(pt["expect"], row, cf)
            rows.append(row)
        done = ", ".join(f"{r['method']} {r['outcome']}" for r in rows[-len(METHODS) :])
        print(f"{i + 1}/{len(design)} {pt['label']}: {done}", flush=True)
    runner.close()
    sweep_s = time.perf_counter() - t_start

    fields = [
        "design", "label", "method", "outcome", "note", "point_outcome", "expect", "as_expected",
        "wall_s", *POINT_FIELDS, "transmittance_db", "transmittance_db_se", "ref_outcome",
        "ref_db", "closed_form_db", "theta_eff", "response_period", "ref_period", "periods",
        "steady_period", "steps", "steps_per_period", "reason", "ref_reason", "ref_status",
        "ref_wall_s",
    ]  # fmt: skip
    with open(args.out / f"{name}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)

    lines = report(rows, design, args, sweep_s, command)
    if not args.random:
        extra_rows: list[dict] = []
        modal_table(lines, extra_rows)
        euler_table(lines, extra_rows)
    lines.append(f"Total run time {time.perf_counter() - t_start:.0f} s.")
    (args.out / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def machine() -> str:
    """What the sweep ran on."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} logical cores, Python {platform.python_version()}"


def point_text(r: dict[str, Any]) -> str:
    return ", ".join(f"{k}={r[k]:.3g}" if isinstance(r[k], float) else f"{k}={r[k]}"
                     for k in POINT_FIELDS)  # fmt: skip


def report(rows, design, args, sweep_s, command) -> list[str]:
    count = Counter(k for k, _ in design)
    what = (
        f"{count['lhs']} Latin-hypercube cells of seed {args.seed} only"
        if args.random
        else f"{count['oat']} one-at-a-time extremes, {count['case']} named cases, "
        f"{count['lhs']} Latin-hypercube points (seed {args.seed}), {count['long']} runs of "
        f"{LONG_PERIODS} periods"
    )
    lines = [
        "# Stress sweep" + (f": random cells, seed {args.seed}" if args.random else ""),
        "",
        f"`{command}` — {what}; each through `simulate_chunk`, one worker process (the sweep's "
        f"only one), wall budget {args.timeout:.0f} s per run. Sweep {sweep_s:.0f} s on "
        f"{machine()}.",
        "",
        "Reference: pinned closed form (g1 = g2 = 0), linear closed form (the method reports "
        "`linear`, or gaps >= 1e6 and no impacts), else `event` at tight settings (256 "
        "intervals/period, event tol 1e-13·T, periodicity tol 1e-11). Tolerance on |ΔΓ| at "
        "converged points (same period as the reference): "
        + "; ".join(
            f"{m} " + ", ".join(f"{k} {v:g} dB" for k, v in TOL[m].items()) for m in METHODS
        )
        + f". `silent-divergence`: a record that is not failed but has Γ > {SILENT_DB:g} dB or "
        "comes from a point whose reference diverged.",
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
    lines += ["", "How the points ended (the records' `outcome`):", ""]
    kinds = ("linear", "periodic", "irregular", "unsettled", "failed")
    lines += ["| method | " + " | ".join(kinds) + " | no record |", "|---|" + "---|" * 6]
    for m in METHODS:
        c = Counter(r.get("point_outcome") for r in rows if r["method"] == m)
        lines.append(f"| {m} | " + " | ".join(str(c.get(k, 0)) for k in kinds)
                     + f" | {c.get(None, 0)} |")  # fmt: skip
    lines.append("")
    lines += named_section(rows)
    silent = [r for r in rows if r["outcome"] == "silent-divergence"]
    lines += ["## Silent divergence (finite Γ from a diverged state; goal: none)", ""]
    if not silent:
        lines.append("None.")
    else:
        lines += ["| method | point | note |", "|---|---|---|"]
        for r in silent:
            lines.append(f"| {r['method']} | {r['label']}: {point_text(r)} | {esc(r['note'])} |")
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
            lines.append(f"| {m} | {n} | {esc(reason)} |")
    lines.append("")
    within = f"both irregular, within {ERROR_BARS:g} combined SE"
    irr = Counter(
        (r["method"], within if r["note"].startswith("irregular |ΔΓ|") else r["note"])
        for r in rows
        if r["outcome"] == "ok-irregular"
    )
    lines += ["## Irregular or classified differently", ""]
    lines += ["| method | note | count |", "|---|---|---|"]
    for (m, note), n in sorted(irr.items()):
        lines.append(f"| {m} | {esc(reason_group(note))} | {n} |")
    lines.append("")
    problems = [
        r
        for r in rows
        if r["outcome"]
        in ("disagreeing", "irregular-apart", "non-finite-record", "timeout", "crashed")
    ]
    lines += ["## Problems (disagreeing, irregular apart, non-finite, timeout, crashed)", ""]
    if not problems:
        lines.append("None.")
    else:
        lines += ["| method | outcome | point | note | wall s |", "|---|---|---|---|---|"]
        for r in problems:
            lines.append(
                f"| {r['method']} | {r['outcome']} | {r['label']}: {point_text(r)} | "
                f"{esc(r['note'])} | {r['wall_s']:.1f} |"
            )
    lines.append("")
    longs = [r for r in rows if r["design"] == "long"]
    if longs:
        lines += [
            f"## Runs of {LONG_PERIODS} periods (early stop off)",
            "",
            "| point | method | outcome | point outcome | periods | Γ dB | wall s |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in longs:
            db = r.get("transmittance_db")
            lines.append(
                f"| {r['label']} | {r['method']} | {r['outcome']} | {r.get('point_outcome')} | "
                f"{r.get('steady_period')} | {'' if db is None else f'{db:.6f}'} | "
                f"{r['wall_s']:.1f} |"
            )
        lines.append("")
    return lines


def named_section(rows: list[dict[str, Any]]) -> list[str]:
    """What each method says at the named cases of issue 11, and whether that is as expected."""
    named = [r for r in rows if r["design"] == "case"]
    if not named:
        return []
    c = Counter(r["as_expected"] for r in named)
    lines = [
        "## Named cases (issue 11)",
        "",
        "Base point (θ 0.3, σ 0.05, γ_s 1, ξ 0.05, gaps 0.1, 5 modes, paper coupling) unless "
        "the case says otherwise. Expected: "
        + "; ".join(f"**{k}** {v}" for k, v in EXPECT_TEXT.items())
        + f". As expected: {c.get('yes', 0)} of {len(named)} runs"
        + (f", {c['unchecked']} unchecked (no pointwise reference)" if c.get("unchecked") else "")
        + (f", **{c['no']} not**" if c.get("no") else "")
        + ".",
        "",
        "| case | expected | method | outcome | Γ dB | closed form dB (linear or pinned) | "
        "reason | check | as expected |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in named:
        db, cf = r.get("transmittance_db"), r.get("closed_form_db")
        reason = r.get("reason") or ""
        if len(reason) > 140:
            reason = reason[:137] + "…"
        # the check: the note unless it only repeats the reason
        check = r["outcome"] if r["outcome"] == "failed-with-reason" else (
            f"{r['outcome']}: {r['note']}")  # fmt: skip
        if not (r["expect"] in ("linear", "transient") or r.get("point_outcome") == "linear"
                or r.get("kind") == "pinned"):  # fmt: skip
            cf = None  # the impact-free closed form says nothing here
        lines.append(
            f"| {r['label'].removeprefix('case ')} | {r['expect']} | {r['method']} | "
            f"{r.get('point_outcome') or r['outcome']} | {'' if db is None else f'{db:.6g}'} | "
            f"{'' if cf is None else f'{cf:.6g}'} | {esc(reason)} | {esc(check)} | "
            f"{r['as_expected']} |"
        )
    lines.append("")
    return lines


if __name__ == "__main__":
    main()
