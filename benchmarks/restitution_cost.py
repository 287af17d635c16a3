"""Time and accuracy at a coefficient of restitution e = 0.5 (docs/model.md §5).

    python benchmarks/restitution_cost.py [--points 20] [--e 0.5] [--out benchmarks/results]

The three benchmark spectra (``benchmarks.suite.cases.SPECTRA``: A paper θ 0.3, gap 0.1; B
paper θ 1, gap 0.5; C full θ 0.3, gap 0.3), ``--points`` each over γ_r 0.3 … 6, with both
stops at e. The reference is the default method (``event``: rebounds located exactly, rebound
sequences passed to their accumulation points), timed like the others. ``euler`` and
``exponential`` run at a ladder of steps per period; for each setting: the time per point (the
whole ``simulate_point`` call, one core), how the points ended, and |ΔΓ| against the reference
where both have a Γ, with ``z = |ΔΓ| / sqrt(se² + se_ref²)`` where both are window means. The
default's time at e = 0 on the same points is the yardstick. Writes ``restitution_cost.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from benchmarks.suite.cases import SPECTRA, cell  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402

LADDER = (("euler", 1024), ("euler", 4096), ("euler", 16384), ("exponential", 512),
          ("exponential", 2048), ("exponential", 8192))  # fmt: skip
OUTCOMES = ("linear", "periodic", "irregular", "unsettled", "failed")


def points(n: int, e: float) -> list:
    """The cells of the three spectra at restitution e."""
    out = []
    for case in SPECTRA:
        for g in np.linspace(0.3, 6.0, n):
            out.append(dataclasses.replace(cell(case, float(g)), e1=e, e2=e))
    return out


def run(cells: list, settings: SolverSettings) -> tuple[list, list[float]]:
    """Every point's result and wall time (seconds)."""
    res, wall = [], []
    for p in cells:
        t = time.perf_counter()
        res.append(simulate_point(p, settings))
        wall.append(time.perf_counter() - t)
    return res, wall


def errors(res: list, ref: list) -> tuple[list[float], list[float]]:
    """|ΔΓ| where both have a Γ and the reference impacts (linear points are the closed form
    for every method), and z where both are window means."""
    d, z = [], []
    for r, f in zip(res, ref, strict=True):
        if r.transmittance_db is None or f.transmittance_db is None or f.outcome == "linear":
            continue
        diff = abs(r.transmittance_db - f.transmittance_db)
        d.append(diff)
        if r.transmittance_db_se and f.transmittance_db_se:
            z.append(diff / math.hypot(r.transmittance_db_se, f.transmittance_db_se))
    return d, z


def table(n: int, e: float) -> list[str]:
    """The markdown report."""
    cells = points(n, e)
    for m in ("event", "euler", "exponential"):
        warm_up(m)
    base, base_wall = run([dataclasses.replace(p, e1=0.0, e2=0.0) for p in cells], SolverSettings())
    ref, ref_wall = run(cells, SolverSettings())
    lines = [
        f"# Time and accuracy at e = {e:g}",
        "",
        f"`python benchmarks/restitution_cost.py --points {n} --e {e:g}`; three spectra × {n} "
        f"points; reference the default (`event`) at e = {e:g}, "
        f"{statistics.mean(ref_wall) * 1e3:.1f} ms a point, "
        f"{statistics.mean(ref_wall) / statistics.mean(base_wall):.1f} × its time at e = 0 on "
        f"the same points ({statistics.mean(base_wall) * 1e3:.2f} ms a point, the yardstick).",
        "",
        "| method | steps / period | mean ms | × default at e = 0 | outcomes "
        "(lin/per/irr/uns/fail) | median / max \\|ΔΓ\\| dB at impacting points "
        "| median z, share z ≤ 3 |",
        "|---|---|---|---|---|---|---|",
    ]
    for method, spp in LADDER:
        res, wall = run(cells, SolverSettings(method=method, steps_per_period=spp))
        d, z = errors(res, ref)
        counts = "/".join(str(sum(r.outcome == o for r in res)) for o in OUTCOMES)
        zs = (f"{statistics.median(z):.2f}, {sum(v <= 3 for v in z) / len(z):.0%}" if z
              else "–")  # fmt: skip
        ds = f"{statistics.median(d):.2e} / {max(d):.2e}" if d else "–"
        lines.append(
            f"| {method} | {spp} | {statistics.mean(wall) * 1e3:.1f} | "
            f"{statistics.mean(wall) / statistics.mean(base_wall):.1f} | {counts} | {ds} | {zs} |"
        )
    counts = "/".join(str(sum(r.outcome == o for r in ref)) for o in OUTCOMES)
    lines += ["", f"The reference's outcomes: {counts}."]
    return lines


def main(argv: list[str] | None = None) -> int:
    """Run the comparison and write its table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=20, help="points per spectrum")
    ap.add_argument("--e", type=float, default=0.5, help="coefficient of restitution")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args(argv)
    lines = table(args.points, args.e)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "restitution_cost.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
