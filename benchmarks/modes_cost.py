"""What more beam modes cost the default solver: time per point against the number of modes.

    python benchmarks/modes_cost.py [--points 12] [--modes 5 10 20 30] [--repeat 3] [--out DIR]

Spectrum A of ``point_engine.py`` (paper coupling, θ 0.3, ξ 0.05, gaps 0.1, σ 0.05, γ_s 1,
γ_r 0.3 … 6) with 5, 10, 20 and 30 modes, default settings. Higher modes are stiff (|λ|·h in the
hundreds over one sub-grid interval) and strongly damped, so they cost through the event
search's bounds, not through the number of impacts. Time per point is the whole
``simulate_point`` call, one core, the fastest of ``--repeat`` runs. Also reports each mode
count's outcomes and a digest of (outcome, Γ) over its points, so two runs (two versions of the
code) can be checked to compute the same numbers.

Writes ``modes_cost.md`` and ``modes_cost.csv`` to the output folder.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
from collections import Counter
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from benchmarks.point_engine import SPECTRA, timed, write_results  # noqa: E402
from worker.model import CellParams  # noqa: E402
from worker.simulate import SolverSettings, warm_up  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=12, help="points of the spectrum")
    ap.add_argument("--modes", type=int, nargs="+", default=[5, 10, 20, 30])
    ap.add_argument("--repeat", type=int, default=3, help="runs per point (the fastest counts)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args(argv)
    settings = SolverSettings()
    warm_up(settings.method)
    rows = []
    for modes in args.modes:
        for g in np.linspace(0.3, 6.0, args.points):
            params = CellParams(sigma=0.05, gamma_s=1.0, gamma_r=float(g), modes=modes,
                                **SPECTRA["A"])  # fmt: skip
            r, dt, _ = timed(params, settings, args.repeat)
            rows.append(dict(modes=modes, gamma_r=float(g), outcome=r.outcome,
                             db=r.transmittance_db, periods=r.periods, ms=1e3 * dt))  # fmt: skip
    lines = [
        "# Cost against the number of modes (default solver)",
        "",
        f"`python benchmarks/modes_cost.py --points {args.points}` — spectrum A of "
        "`point_engine.py` (paper coupling, θ 0.3, ξ 0.05, gaps 0.1), one core, fastest of "
        f"{args.repeat} runs per point.",
        "",
        "| modes | mean ms per point | median ms | periods per point | outcomes "
        "| digest of (outcome, Γ) |",
        "|---|---|---|---|---|---|",
    ]
    for modes in args.modes:
        sel = [r for r in rows if r["modes"] == modes]
        ms = [r["ms"] for r in sel]
        outcomes = ", ".join(
            f"{k} {v}" for k, v in sorted(Counter(r["outcome"] for r in sel).items())
        )
        digest = hashlib.sha256(repr([(r["outcome"], r["db"]) for r in sel]).encode()).hexdigest()
        lines.append(
            f"| {modes} | {np.mean(ms):.1f} | {np.median(ms):.1f} | "
            f"{np.mean([r['periods'] for r in sel]):.0f} | {outcomes} | `{digest[:12]}` |"
        )
    write_results(args.out, "modes_cost", lines, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
