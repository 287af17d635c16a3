"""The default solver against a fair yardstick: the paper's scheme run as the default is.

The paper's scheme (semi-implicit Euler with Lemke's algorithm, a step fixed in time) is run
with the default's stopping rules (the same steady-state tests and proofs, no reference
needed) instead of a fixed 150-period budget, and each irregular point until its standard
error is the one the default reached there. Beside every ratio the yardstick's own error is
printed, by the reference's outcome class, against a tight ``event`` reference (sub-grid 256,
event_tol 1e-13, periodicity_tol 1e-11). The old protocol (a fixed 150 periods) is a row of its
own, for history::

    python benchmarks/fair_yardstick.py [--points 40] [--dt 1e-3] [--out benchmarks/results]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import sys
import time
from pathlib import Path

# The checkout's own code, whatever is installed.
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from benchmarks.point_engine import kernel_clock  # noqa: E402
from benchmarks.suite.cases import SPECTRA, cell, paper_settings  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402

REF = dict(steps_per_period=256, periodicity_tol=1e-11)
REF_TOL = 1e-13


def yardstick(gamma_r: float, dt: float, stat_tol_db: float | None) -> SolverSettings:
    """The paper's scheme at step ``dt`` with the default's stopping rules."""
    base = dataclasses.replace(paper_settings(gamma_r), early_stop=True, max_periods=1000,
                               window=SolverSettings().window)  # fmt: skip
    spp = max(4, round(2.0 * math.pi / gamma_r / dt))
    base = dataclasses.replace(base, steps_per_period=spp)
    if stat_tol_db is not None:
        base = dataclasses.replace(base, stat_tol_db=stat_tol_db)
    return base


def timed(params, settings, **options):  # noqa: ANN001, ANN201 - a benchmark's helper
    """The result, the call's wall time and its compiled time loops' (``kernel_clock``)."""
    with kernel_clock() as loops:
        t0 = time.perf_counter()
        r = simulate_point(params, settings, **options)
        t = time.perf_counter() - t0
    return r, t, loops[0]


def main(argv: list[str] | None = None) -> None:
    """Run the three spectra with the default, the fair yardstick, the old protocol and a
    tight reference; print and write the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=40, help="points per spectrum (%(default)s)")
    ap.add_argument("--dt", type=float, default=1e-3, help="the yardstick's step (%(default)s)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args(argv)
    for m in ("event", "euler"):
        warm_up(m, quiet=True)
    rows = []
    for case in SPECTRA:
        for g in np.linspace(0.3, 6.0, args.points):
            p = cell(case, float(g))
            ref = simulate_point(p, SolverSettings(**REF), event_tol=REF_TOL)
            d, td, tk = timed(p, SolverSettings())
            se = d.transmittance_db_se if d.outcome == "irregular" else None
            y, ty, _ = timed(p, yardstick(float(g), args.dt, se))
            o, to, _ = timed(p, paper_settings(float(g)))
            rows.append(dict(case=case, g=float(g), ref=ref, d=d, y=y, o=o, td=td * 1e3,
                             tk=tk * 1e3, ty=ty * 1e3, to=to * 1e3))  # fmt: skip
            print(f"{case} γ_r {g:.3f}: {ref.outcome:10s} default {td * 1e3:8.1f} ms, "
                  f"yardstick {ty * 1e3:8.1f} ms ({y.outcome})", flush=True)  # fmt: skip

    def ratio(key: str, f, sel: list[dict] | None = None, base: str = "td") -> float:  # noqa: ANN001
        sel = rows if sel is None else sel
        return f([r[key] for r in sel]) / f([r[base] for r in sel])

    settled = [r for r in rows if r["ref"].outcome in ("linear", "periodic")]
    mean, median = statistics.fmean, statistics.median

    def err_lines(key: str) -> list[str]:
        out = []
        for cls in ("linear", "periodic", "irregular"):
            sel = [r for r in rows if r["ref"].outcome == cls]
            if not sel:
                continue
            e = [abs(r[key].transmittance_db - r["ref"].transmittance_db) for r in sel]
            e = [x for x in e if math.isfinite(x)]
            over = sum(x > 0.1 for x in e)
            out.append(f"{cls} ({len(sel)}): median {statistics.median(e):.2e} dB, max "
                       f"{max(e):.2e} dB, {over} beyond 0.1 dB")  # fmt: skip
        return out

    lines = [
        "# The default against a fair yardstick",
        "",
        f"`python benchmarks/fair_yardstick.py --points {args.points} --dt {args.dt:g}`: three "
        f"{args.points}-point spectra (γ_r 0.3–6; the cells of `benchmarks/suite/cases.py`), one "
        "process, one pass per point (whole `simulate_point` calls).",
        "",
        "| solver | mean ms | median ms | ratio to the default: mean / median |",
        "|---|---|---|---|",
        f"| default (`event`) | {statistics.fmean(r['td'] for r in rows):.2f} | "
        f"{statistics.median(r['td'] for r in rows):.2f} | 1 / 1 |",
        f"| fair yardstick: euler + Lemke, Δτ {args.dt:g}, the default's stopping rules and "
        f"standard errors | {statistics.fmean(r['ty'] for r in rows):.1f} | "
        f"{statistics.median(r['ty'] for r in rows):.1f} | "
        f"{ratio('ty', statistics.fmean):.1f}× / {ratio('ty', statistics.median):.1f}× |",
        f"| old protocol (history): euler + Lemke, Δτ 1e-3, a fixed 150 periods | "
        f"{statistics.fmean(r['to'] for r in rows):.1f} | "
        f"{statistics.median(r['to'] for r in rows):.1f} | "
        f"{ratio('to', statistics.fmean):.1f}× / {ratio('to', statistics.median):.1f}× |",
        "",
        f"At the {len(settled)} linear and periodic points (by the reference's outcome), the "
        f"yardstick over the default: mean {ratio('ty', mean, settled):.1f}×, median "
        f"{ratio('ty', median, settled):.1f}×.",
        "",
        f"The default's compiled time loops alone (every `KernelRun.advance`, side runs "
        f"included): {mean(r['tk'] for r in rows):.2f} ms mean, "
        f"{median(r['tk'] for r in rows):.2f} ms median of its "
        f"{mean(r['td'] for r in rows):.2f} / {median(r['td'] for r in rows):.2f}. If "
        f"everything else cost nothing (a compiled engine at best, the kernels as they are), "
        f"the ratios would be {ratio('ty', mean, base='tk'):.1f}× mean and "
        f"{ratio('ty', median, base='tk'):.1f}× median; at the linear and periodic points "
        f"{ratio('ty', mean, settled, 'tk'):.1f}× / {ratio('ty', median, settled, 'tk'):.1f}×.",
        "",
        "Errors against the tight `event` reference, by the reference's outcome:",
        "",
        "- default: " + "; ".join(err_lines("d")),
        "- fair yardstick: " + "; ".join(err_lines("y")),
        "- old protocol: " + "; ".join(err_lines("o")),
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "fair_yardstick.md").write_text(text, encoding="utf-8")


if __name__ == "__main__":
    main()
