"""What the compiled time loops cost per period and per impact, over the three spectra.

    python benchmarks/kernel_cost.py [--points 40] [--method event] [--repeat 3] [--out DIR]

Runs the points of the three spectra (``benchmarks/suite/cases.py``) with the default
settings (``--method`` another method's) and records, for every call of a method's compiled time
loop (``KernelRun.advance``: main batches and side runs), its wall time, the periods it ran and
the impacts in them (read from the period rows it filled). The fastest of ``--repeat`` passes
per point counts. A non-negative least-squares fit over the points of each spectrum (its cell
sets the cost of a period: modes, coupling) and over all of them,

    loop time = a · periods + b · impacts,

gives the cost of an impact-free period (a) and of each impact beyond it (b); the calls
(entering and leaving compiled code, a few µs each) are too few and too much in step with the
periods to be told apart. Writes ``kernel_cost.md`` to ``--out`` (default
``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from benchmarks.suite.cases import SPECTRA, cell  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402
from worker.solvers import measure as ms  # noqa: E402
from worker.solvers.base import KernelRun  # noqa: E402


@contextlib.contextmanager
def loop_counter() -> Iterator[list[float]]:
    """While inside: [seconds, periods, impacts, calls] of every ``KernelRun.advance`` call."""
    tally = [0.0, 0.0, 0.0, 0.0]
    plain = KernelRun.advance

    def advance(self, n, measure, checks, rows, samples):  # noqa: ANN001, ANN202
        t0 = time.perf_counter()
        done, code, p = plain(self, n, measure, checks, rows, samples)
        tally[0] += time.perf_counter() - t0
        tally[1] += done
        tally[2] += float(rows[:done, ms.M_IMP1].sum() + rows[:done, ms.M_IMP2].sum())
        tally[3] += 1
        return done, code, p

    KernelRun.advance = advance  # type: ignore[method-assign]
    try:
        yield tally
    finally:
        KernelRun.advance = plain  # type: ignore[method-assign]


def fit(rows: list[list[float]]) -> tuple[float, float]:
    """Non-negative least-squares (a, b) of seconds = a·periods + b·impacts."""
    from scipy.optimize import nnls

    A = np.array([[r[1], r[2]] for r in rows])
    y = np.array([r[0] for r in rows])
    coef, _ = nnls(A, y)
    return float(coef[0]), float(coef[1])


def main(argv: list[str] | None = None) -> int:
    """Measure, fit and write the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=40, help="points per spectrum (%(default)s)")
    ap.add_argument("--method", default="event")
    ap.add_argument("--repeat", type=int, default=3, help="passes (the fastest counts)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args(argv)
    if args.points < 1 or args.repeat < 1:
        ap.error(f"--points and --repeat must be at least 1, got {args.points}, {args.repeat}")
    settings = SolverSettings(method=args.method)
    warm_up(args.method, quiet=True)
    cases = [c for c in SPECTRA for _ in range(args.points)]
    cells = [cell(c, float(g)) for c in SPECTRA for g in np.linspace(0.3, 6.0, args.points)]
    best: list[list[float]] = [[math.inf, 0.0, 0.0, 0.0] for _ in cells]
    for _ in range(args.repeat):
        for i, p in enumerate(cells):
            with loop_counter() as tally:
                simulate_point(p, settings)
            if tally[0] < best[i][0]:
                best[i] = list(tally)
    used = [r for r in best if r[3] > 0]
    a, b = fit(used)
    periods = sum(r[1] for r in used)
    impacts = sum(r[2] for r in used)
    seconds = sum(r[0] for r in used)
    lines = [
        f"# Cost of the `{args.method}` time loops",
        "",
        f"`python benchmarks/kernel_cost.py --points {args.points} --method {args.method}`: "
        f"{len(used)} of {len(cells)} points simulate (the rest are proven at their start); "
        f"{periods:,.0f} periods, {impacts:,.0f} impacts, {sum(r[3] for r in used):,.0f} calls, "
        f"{seconds * 1e3:.1f} ms in the loops (fastest of {args.repeat} passes per point).",
        "",
        "| points | per impact-free period | per impact | mean per period | impacts per period |",
        "|---|---|---|---|---|",
    ]
    for case in SPECTRA:
        sel = [r for r, c in zip(best, cases, strict=True) if c == case and r[3] > 0]
        if len(sel) >= 2:
            ca, cb = fit(sel)
            per = sum(r[0] for r in sel) / sum(r[1] for r in sel)
            imp = sum(r[2] for r in sel) / sum(r[1] for r in sel)
            lines.append(f"| spectrum {case} | {ca * 1e6:.2f} µs | {cb * 1e6:.2f} µs | "
                         f"{per * 1e6:.2f} µs | {imp:.2f} |")  # fmt: skip
    lines.append(f"| all | {a * 1e6:.2f} µs | {b * 1e6:.2f} µs | "
                 f"{seconds / periods * 1e6:.2f} µs | {impacts / periods:.2f} |")  # fmt: skip
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "kernel_cost.md").write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
