"""How much a point's numbers depend on the CPU target: the point-engine points under other targets.

    python audits/cpu_targets.py [--variants pinned,unpinned,blas-sandybridge,numba-generic]
                                     [--every 1] [--out audits/results] [--json]

Runs the 120 points of ``point_engine.py`` (three 40-point spectra, default solver) once per
variant, each in a fresh process whose environment sets the targets before numpy and numba
load (``worker/cpu.py``), and counts the points whose outcome, Γ or period differ from the
``pinned`` run in any digit, and those whose outcome or period differ. Variants:

* ``pinned``: what ``worker`` sets (``OPENBLAS_CORETYPE=Haswell``, ``NUMBA_CPU_NAME=haswell``,
  numpy's AVX-512 dispatch off) on an x86-64 CPU with AVX2 and FMA;
* ``unpinned``: the libraries' own choice for this CPU (all three set empty);
* ``blas-sandybridge``: OpenBLAS's AVX (Sandybridge) kernels, the rest pinned;
* ``numba-generic``: numba compiling for a generic x86-64 (no AVX, no FMA), the rest pinned.

Each variant compiles its kernels once into its own numba cache (``--cache``, default a folder
under the system's temporary directory): about a minute a variant the first time.
Writes ``cpu_targets.md`` to the output folder.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from worker.cpu import BLAS_CORE, BLAS_ENV, NUMBA_CPU, NUMBA_ENV, NUMPY_ENV, NUMPY_OFF  # noqa: E402

PINNED = {BLAS_ENV: BLAS_CORE, NUMBA_ENV: NUMBA_CPU, NUMPY_ENV: NUMPY_OFF}
VARIANTS = {
    "pinned": PINNED,
    "unpinned": {k: "" for k in PINNED},  # empty: each library chooses for this CPU
    "blas-sandybridge": {**PINNED, BLAS_ENV: "Sandybridge"},
    "numba-generic": {**PINNED, NUMBA_ENV: "generic"},
}

# Run in the child: every point's outcome, Γ (repr: every digit) and period, as JSON.
_CHILD = """
import json, sys
sys.path.insert(0, {bench!r})
import worker  # first: the targets come from the environment set by the parent
import numpy as np
from point_engine import SPECTRA, cell
from worker.cpu import compiled_for, kernels
from worker.simulate import SolverSettings, simulate_point, warm_up
warm_up("event", quiet=True)
s = SolverSettings()
out = {{}}
for case in SPECTRA:
    for i, g in enumerate(np.linspace(0.3, 6.0, 40)):
        if i % {every}:
            continue
        r = simulate_point(cell(case, g), s)
        out[f"{{case}}:{{g:.6f}}"] = [r.outcome, repr(r.transmittance_db), r.response_period]
print(json.dumps({{"blas": kernels(), "numba": compiled_for(), "points": out}}))
"""


def run_variant(name: str, every: int, cache: Path) -> dict:
    """The points of one variant, computed in a fresh process."""
    env = {**os.environ, **VARIANTS[name], "OPENBLAS_NUM_THREADS": "1",
           "NUMBA_CACHE_DIR": str(cache / name)}  # fmt: skip
    code = _CHILD.format(bench=str(ROOT / "benchmarks"), every=every)
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True,
        check=False,
    )  # fmt: skip
    if out.returncode != 0:
        raise SystemExit(f"cpu_targets: variant {name!r} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--every", type=int, default=1, help="every k-th γ_r of each spectrum")
    ap.add_argument("--out", type=Path, default=ROOT / "audits" / "results")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "cpu_targets")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    bad = [v for v in names if v not in VARIANTS]
    if bad or not names:
        ap.error(f"--variants: {bad or names!r} not allowed; choose from {', '.join(VARIANTS)}")
    if not 1 <= args.every <= 40:
        ap.error(f"--every: {args.every} not allowed; an integer in 1…40")
    if "pinned" not in names:
        names.insert(0, "pinned")
    runs = {name: run_variant(name, args.every, args.cache) for name in names}
    ref = runs["pinned"]["points"]
    rows = []
    for name in names:
        pts = runs[name]["points"]
        digits = sum(pts[k] != ref[k] for k in ref)
        ends = sum((pts[k][0], pts[k][2]) != (ref[k][0], ref[k][2]) for k in ref)
        rows.append({
            "variant": name, "blas": runs[name]["blas"], "numba": runs[name]["numba"],
            "points": len(ref), "differ": digits, "other_outcome_or_period": ends,
        })  # fmt: skip
    if args.json:
        print(json.dumps(rows))
    lines = [
        "Point-engine points (three 40-point spectra, default solver) under other CPU targets, "
        "each against the pinned run (`python audits/cpu_targets.py`).",
        "",
        "| variant | OpenBLAS kernels | numba target | points | differ in any digit | "
        "another outcome or period |",
        "|---|---|---|---|---|---|",
        *(f"| {r['variant']} | {r['blas']} | {r['numba']} | {r['points']} | {r['differ']} | "
          f"{r['other_outcome_or_period']} |" for r in rows),
    ]  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "cpu_targets.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    if not args.json:
        print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
