"""Two versions of the code on the same points, interleaved: what a change does to run time.

    python benchmarks/interleaved.py OTHER [--study studies/paper-fig5-gaps.yaml] [--every 4]
                                     [--reps 3] [--out DIR]

OTHER is another checkout of this repository (for the code before a change:
``git worktree add /tmp/before <commit>``, then ``python -m service.cli warmup`` in it). One
server process per checkout runs the study's every ``--every``-th point with its solver
settings (``simulate_point``, one core each), and the parent hands each point to both in turn,
alternating which goes first, ``--reps`` times; a point's time is the fastest of its reps.
The machine's speed drifts by tens of percent over minutes, which separate runs of the two
versions cannot tell from the change; interleaving gives both the same drift. Reports the
time by outcome (the outcome of this checkout), the ratio OTHER / this, and how many points
differ in outcome, Γ or Floquet multiplier. Writes ``interleaved.md`` to the output folder
(default ``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Run in each server process, from the checkout it times (sys.argv: root, study, every).
_SERVER = r"""
import json, os, sys, time
root, study, every = sys.argv[1], sys.argv[2], int(sys.argv[3])
sys.path.insert(0, root)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import worker  # first: pins the CPU target
assert os.path.realpath(worker.__file__).startswith(os.path.realpath(root)), worker.__file__
from service.studies.schema import load_study
from worker.model import CellParams
from worker.simulate import SolverSettings, simulate_point, warm_up
st = load_study(study)
solver = {k: v for k, v in st.solver.model_dump().items() if v is not None}
settings = SolverSettings(**solver)
warm_up(settings.method, quiet=True)
points = [CellParams(**st.points(i, i + 1)[0]) for i in range(0, st.size, every)]
print(json.dumps({"ready": len(points)}), flush=True)
for line in sys.stdin:
    i = int(line)
    t = time.perf_counter()
    r = simulate_point(points[i], settings)
    dt = time.perf_counter() - t
    print(json.dumps([dt, r.outcome, r.transmittance_db, r.floquet_multiplier]), flush=True)
"""


def _start(root: Path, study: Path, every: int) -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen(
        [sys.executable, "-c", _SERVER, str(root), str(study), str(every)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=str(root),
    )  # fmt: skip
    line = proc.stdout.readline()
    if not line:
        raise SystemExit(f"interleaved: the server for {root} did not start")
    return proc, int(json.loads(line)["ready"])


def _ask(proc: subprocess.Popen, i: int) -> list:
    proc.stdin.write(f"{i}\n")
    proc.stdin.flush()
    return json.loads(proc.stdout.readline())


def run(other: Path, study: Path, every: int, reps: int) -> dict:
    """Time every ``every``-th point of ``study`` in OTHER and in this checkout, interleaved;
    per point the fastest of ``reps`` and the last result of each."""
    started = [_start(root, study, every) for root in (other, ROOT)]
    procs = [s[0] for s in started]
    sizes = [s[1] for s in started]
    if sizes[0] != sizes[1]:
        raise SystemExit(f"interleaved: the checkouts read {sizes[0]} and {sizes[1]} points")
    n = sizes[0]
    best = [[float("inf")] * n for _ in procs]
    res: list[list] = [[None] * n for _ in procs]
    try:
        for rep in range(reps):
            for i in range(n):
                for k in (0, 1) if (i + rep) % 2 == 0 else (1, 0):
                    dt, *out = _ask(procs[k], i)
                    best[k][i] = min(best[k][i], dt)
                    res[k][i] = out
    finally:
        for p in procs:
            p.stdin.close()
            p.wait()
    return {"n": n, "best": best, "res": res}


def report(got: dict, other: Path, argv: list[str]) -> str:
    n, best, res = got["n"], got["best"], got["res"]
    by = collections.defaultdict(lambda: [0, 0.0, 0.0])
    for i in range(n):
        b = by[res[1][i][0]]
        b[0] += 1
        b[1] += best[0][i]
        b[2] += best[1][i]
    lines = [
        f"# Interleaved: {other} (OTHER) against this checkout", "",
        f"{n} points, the fastest of each point's runs; ratio = OTHER / this (above 1: this "
        "checkout is faster).", "",
        "| outcome (this checkout) | points | OTHER s | this s | ratio |", "|---|---|---|---|---|",
    ]  # fmt: skip
    for o, (c, a, b) in sorted(by.items()):
        lines.append(f"| {o} | {c} | {a:.3f} | {b:.3f} | {a / b:.3f} |")
    ta, tb = sum(best[0]), sum(best[1])
    lines.append(f"| all | {n} | {ta:.3f} | {tb:.3f} | {ta / tb:.3f} |")
    outcome = sum(res[0][i][0] != res[1][i][0] for i in range(n))
    gamma = sum(res[0][i][1] != res[1][i][1] for i in range(n))
    mult = sum(res[0][i][2] != res[1][i][2] for i in range(n))
    lines += [
        "", f"Points that differ: outcome {outcome}, Γ {gamma}, Floquet multiplier {mult} "
        "(to the bit).", "",
        f"Generated by `python benchmarks/interleaved.py {' '.join(argv)}`.",
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path, help="another checkout of this repository")
    ap.add_argument("--study", type=Path, default=ROOT / "studies" / "paper-fig5-gaps.yaml")
    ap.add_argument("--every", type=int, default=4, help="every k-th point (default 4)")
    ap.add_argument("--reps", type=int, default=3, help="runs per point (default 3)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    a = ap.parse_args(argv)
    if not (a.other / "worker" / "__init__.py").is_file():
        ap.error(f"other: {a.other} is not a checkout of this repository (no worker/)")
    if a.every < 1 or a.reps < 1:
        ap.error(f"--every and --reps must be at least 1, got {a.every} and {a.reps}")
    got = run(a.other.resolve(), a.study.resolve(), a.every, a.reps)
    md = report(got, a.other, argv)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "interleaved.md").write_text(md, encoding="utf-8")
    print(md)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    raise SystemExit(main())
