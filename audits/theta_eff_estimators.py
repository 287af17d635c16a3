"""Where the effective mass θ_eff and the phase-portrait ratio θ_ps disagree: a study's points.

    python audits/theta_eff_estimators.py [--study paper-fig6-theta-sweep ...] [--out DIR]

Every point of the shipped grid studies named (default: both of the paper's Figure 6 studies)
is run with the study's settings, one core. θ_eff (``theta_eff``: first harmonic at γ_r, Eq. 35)
and θ_ps (``theta_eff_slope``: the least-squares slope of the velocity phase portrait) are
compared at the impacting points (every outcome but ``linear`` and ``failed``): how many have
opposite signs, the largest and median |θ_eff − θ_ps|, and for linear points the largest
difference (none: the closed form gives both as Re(Ŝ_b/Ŝ)). At the points whose signs differ,
a history of the reported response (its orbit's p periods, or 40 periods of an irregular one)
splits θ_ps by harmonic: r = ⟨ṡ_b ṡ⟩/⟨ṡ²⟩ = Σ_k w_k r_k, with w_k the k-th harmonic's share of
⟨ṡ²⟩ and r_k = Re(V̂_b,k / V̂_k); the fundamental's share w_1 and the ratio r_1 (θ_eff's) show
how much of θ_ps the harmonics that the impacts excite decide. Writes
``theta_eff_estimators.md`` and ``.csv`` (docs/accuracy.md, "Effective mass at impacting
points").
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from audits.common import (  # noqa: E402
    RESULTS,  # noqa: E402
    random_points,
    spectra_points,
    study_points,
    write_results,  # noqa: E402
)
from worker.model import CellParams  # noqa: E402
from worker.simulate import SolverSettings, simulate_point  # noqa: E402

STUDIES = ("paper-fig6-theta-sweep", "paper-fig6-effective-mass")
IRREGULAR_HISTORY = 40  # periods of history split by harmonic at an irregular point
HARMONICS = 60  # harmonics of γ_r summed (the rest is counted as such)


def by_harmonic(p: CellParams, settings: SolverSettings, periods: int) -> dict[str, float]:
    """The fundamental's share of ⟨ṡ²⟩ (w1), its ratio r1 = Re(V̂_b,1/V̂_1) and the slope r
    over ``periods`` periods of the reported response (trapezoid rule on the history's
    samples, which hold every event)."""
    r = simulate_point(p, settings, history_periods=periods)
    h = r.history
    assert h is not None
    tau, v, vb = h["tau"], h["s_dot"], h["s_b_dot"]
    span = tau[-1] - tau[0]
    vv = np.trapezoid(v * v, tau) / span
    vbv = np.trapezoid(vb * v, tau) / span
    w, r1 = [], 0.0
    for k in range(1, HARMONICS + 1):
        e = np.exp(-1j * k * p.gamma_r * tau)
        vk = 2.0 * np.trapezoid(v * e, tau) / span
        vbk = 2.0 * np.trapezoid(vb * e, tau) / span
        w.append(0.5 * abs(vk) ** 2 / vv)
        if k == 1:
            r1 = float((vbk / vk).real)
    return {"w1": w[0], "w_first10": float(sum(w[:10])), "r1": r1, "r": float(vbv / vv)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", nargs="+", default=list(STUDIES), help="shipped grid studies")
    ap.add_argument("--spectra", type=int, default=0, metavar="N",
                    help="also point_engine.py's three spectra, N points each")  # fmt: skip
    ap.add_argument(
        "--random",
        type=int,
        default=0,
        metavar="N",
        help="also N random cells (irregular_budget.py's), default settings",
    )
    ap.add_argument("--seed", type=int, default=11, help="seed of the random cells")  # fmt: skip
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = []
    seen: set[tuple] = set()
    sets = [(name, *study_points(name)) for name in args.study]
    if args.spectra:
        sets.append(("spectra", *spectra_points(args.spectra)))
    if args.random:
        cells = random_points(args.random, args.seed)  # named by their index, not their JSON
        pts = [(f"#{i}", g, c) for i, (_, g, c) in enumerate(cells)]
        sets.append((f"random{args.seed}", pts, SolverSettings()))
    for name, pts, settings in sets:
        for case, g, p in pts:
            key = (p, settings)
            if key in seen:  # the two Figure 6 studies share their θ = 1 points
                continue
            seen.add(key)
            r = simulate_point(p, settings)
            if r.failed:
                continue
            rows.append({"study": name, "coupling": p.coupling, "theta": p.theta,
                         "gamma_r": g, "case": case,
                         "outcome": r.outcome, "period": r.response_period,
                         "theta_eff": r.theta_eff, "theta_ps": r.theta_eff_slope,
                         "p": p, "settings": settings})  # fmt: skip
    imp = [r for r in rows if r["outcome"] != "linear" and r["theta_ps"] is not None]
    lin = [r for r in rows if r["outcome"] == "linear"]
    opposite = [r for r in imp if r["theta_eff"] * r["theta_ps"] < 0]
    diffs = [abs(r["theta_eff"] - r["theta_ps"]) for r in imp]
    lin_max = max((abs(r["theta_eff"] - r["theta_ps"]) for r in lin), default=0.0)
    for r in opposite:
        periods = r["period"] if r["outcome"] == "periodic" else IRREGULAR_HISTORY
        r.update(by_harmonic(r["p"], r["settings"], periods))
    cmd = (
        "python audits/theta_eff_estimators.py"
        + ("" if args.study == list(STUDIES) else " --study " + " ".join(args.study))
        + (f" --spectra {args.spectra}" if args.spectra else "")
        + (f" --random {args.random} --seed {args.seed}" if args.random else "")
    )
    lines = [
        "# θ_eff (first harmonic) against θ_ps (phase-portrait slope)",
        "",
        f"`{cmd}` ({(time.perf_counter() - t0) / 60:.1f} min, one core). Studies: "
        f"{', '.join(f'`{s}`' for s in args.study)}"
        + (
            f", point_engine.py's three spectra ({args.spectra} points each)"
            if args.spectra
            else ""
        )
        + (f", {args.random} random cells (seed {args.seed})" if args.random else "")  # fmt: skip
        + f"; {len(rows)} distinct points, "
        f"{len(lin)} linear, {len(imp)} impacting (periodic, irregular or unsettled).",
        "",
        f"- Impacting points where the two have opposite signs: **{len(opposite)} of {len(imp)}**"
        + "".join(
            f"; {c}: {sum(r['coupling'] == c for r in opposite)} of "
            f"{sum(r['coupling'] == c for r in imp)}"
            for c in ("paper", "full")
        )
        + ".",
        f"- |θ_eff − θ_ps| at impacting points: median {statistics.median(diffs):.3g}, "
        f"largest {max(diffs):.3g}."
        if diffs
        else "- No impacting points.",
        "- Impacting points where they differ by more than 0.1: "
        + "; ".join(
            f"{c}: {sum(r['coupling'] == c and d > 0.1 for r, d in zip(imp, diffs, strict=True))}"
            f" of {sum(r['coupling'] == c for r in imp)}"
            for c in ("paper", "full")
        )
        + ".",
        f"- Linear points: largest |θ_eff − θ_ps| {lin_max:.2g} (the closed form gives both as "
        "Re(Ŝ_b/Ŝ)).",
        "",
        "Opposite signs, with the fundamental's share w1 of ⟨ṡ²⟩ and of the first ten harmonics, "
        "r1 = Re(V̂_b,1/V̂_1) (θ_eff's ratio) and r = ⟨ṡ_b ṡ⟩/⟨ṡ²⟩ (θ_ps's), over the reported "
        f"response's history (an orbit's p periods; {IRREGULAR_HISTORY} periods of an irregular "
        "one, whose θ_eff and θ_ps are window means: its r1 and r are of these periods only):",
        "",
        "| points | coupling | θ | γ_r | outcome | θ_eff | θ_ps | w1 | w1..10 | r1 | r |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in opposite:
        out = r["outcome"] + (f" p = {r['period']}" if r["outcome"] == "periodic" else "")
        lines.append(
            f"| {r['study']} {r['case']} | {r['coupling']} | {r['theta']:.3g} | "
            f"{r['gamma_r']:.4g} | {out} | {r['theta_eff']:+.3f} | "
            f"{r['theta_ps']:+.3f} | {r['w1']:.2f} | {r['w_first10']:.2f} | {r['r1']:+.3f} | "
            f"{r['r']:+.3f} |"
        )
    table = [{k: v for k, v in r.items() if k not in ("p", "settings")} for r in rows]
    keys = list(dict.fromkeys(k for r in table for k in r))
    table = [{k: r.get(k, "") for k in keys} for r in table]
    write_results(args.out, "theta_eff_estimators", lines, table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
