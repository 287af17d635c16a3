"""What the audits share: the points they run (the benchmark spectra, a shipped or nightly
study, random cells over wide ranges), the command-line options that choose them, and the
results files' names and writer."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from benchmarks.point_engine import SPECTRA, cell, write_results  # noqa: E402
from worker.model import CellParams  # noqa: E402
from worker.simulate import SolverSettings  # noqa: E402

__all__ = [
    "RESULTS",
    "SPECTRA",
    "cell",
    "chosen_points",
    "random_points",
    "results_name",
    "selection",
    "selection_options",
    "spectra_points",
    "study_points",
    "write_results",
]

#: Where an audit writes its tables by default (not committed but for the ones the docs cite).
RESULTS = Path(__file__).resolve().parent / "results"


def spectra_points(n: int) -> tuple[list[tuple[str, float, CellParams]], SolverSettings]:
    """The three spectra's points (case, γ_r, cell), n per spectrum, and the default settings."""
    pts = [(case, float(g), cell(case, g)) for case in SPECTRA for g in np.linspace(0.3, 6.0, n)]
    return pts, SolverSettings()


def study_points(name: str) -> tuple[list[tuple[str, float, CellParams]], SolverSettings]:
    """Every point of a shipped grid study (its coordinates but γ_r as the case) and its
    settings; ``nightly/NAME`` names a study of the nightly suite."""
    from service.regression.suite import load_suite
    from service.studies.schema import load_study
    from service.studies.shipped import resolve_study_file

    if name.startswith("nightly/"):
        entries = {e.stem: e for e in load_suite()}
        stem = name.removeprefix("nightly/")
        if stem not in entries:
            raise SystemExit(f"--study {name}: the nightly suite has {', '.join(entries)}")
        study = entries[stem].study
    else:
        study = load_study(resolve_study_file(name))
    grid = study.points(0, study.size, grid=True)
    # the case: the coordinates other than γ_r that vary over the study
    varying = [k for k in grid[0] if k != "gamma_r" and len({str(kw[k]) for kw in grid}) > 1]
    pts = []
    for kw in grid:
        where = ", ".join(f"{k} {kw[k]:g}" for k in varying)
        pts.append((where, float(kw["gamma_r"]), CellParams(**kw)))
    return pts, study.solver.settings()


def random_points(n: int, seed: int) -> list[tuple[str, float, CellParams]]:
    """n random cells (case: their parameters as JSON): θ 0.01–10, σ 0.003–1, γ_s 0.2–5,
    ξ 0.001–0.3, g1 0.001–5 (log-uniform; g2 = g1, or for 30 % g1 times 0.3–3), γ_r 0.2–6,
    1–10 modes, either coupling."""
    rng = np.random.default_rng(seed)

    def log_uniform(a: float, b: float) -> float:
        return float(np.exp(rng.uniform(np.log(a), np.log(b))))

    pts = []
    for _ in range(n):
        g1 = log_uniform(0.001, 5.0)
        g2 = g1 * (log_uniform(0.3, 3.0) if rng.random() < 0.3 else 1.0)
        kw = dict(theta=log_uniform(0.01, 10.0), sigma=log_uniform(0.003, 1.0),
                  gamma_s=log_uniform(0.2, 5.0), xi=log_uniform(0.001, 0.3), g1=g1, g2=g2,
                  gamma_r=log_uniform(0.2, 6.0), coupling=str(rng.choice(["paper", "full"])),
                  modes=int(rng.integers(1, 11)))  # fmt: skip
        pts.append((json.dumps(kw), kw["gamma_r"], CellParams(**kw)))
    return pts


def selection_options(ap: argparse.ArgumentParser) -> None:
    """The options :func:`chosen_points` reads: ``--study``, ``--points``, ``--random``,
    ``--seed`` (the benchmarks that take a study's, the spectra's or random points)."""
    ap.add_argument("--study", help="a shipped grid study instead of the three spectra")
    ap.add_argument("--points", type=int, default=40, help="points per spectrum (no --study)")
    ap.add_argument("--random", type=int, default=0, help="N random cells instead (--seed)")
    ap.add_argument("--seed", type=int, default=4, help="the random cells' seed")


def chosen_points(
    ap: argparse.ArgumentParser, args: argparse.Namespace
) -> tuple[list[tuple[str, float, CellParams]], SolverSettings]:
    """The points ``--random``/``--seed``, ``--study`` or else ``--points`` name, and their
    settings (``ap.error`` for ``--random`` below 0 or with ``--study``)."""
    if args.random < 0 or (args.random and args.study):
        ap.error(f"--random must be 0 (off) or more, and not with --study; got {args.random}")
    if args.random:
        return random_points(args.random, args.seed), SolverSettings()
    if args.study:
        return study_points(args.study)
    return spectra_points(args.points)


def selection(args: argparse.Namespace) -> tuple[str, str]:
    """What the points are (``points of `paper-fig5-gaps```) and the options that chose them."""
    if args.random:
        return f"random cells (seed {args.seed})", f"--random {args.random} --seed {args.seed}"
    if args.study:
        return f"points of `{args.study}`", f"--study {args.study}"
    return "points of the three spectra", f"--points {args.points}"


def results_name(prefix: str, args: argparse.Namespace) -> str:
    """The results files' name: ``prefix``, and ``_random<seed>`` or ``_<study>``."""
    name = prefix + (f"_random{args.seed}" if args.random else "")
    if args.study:
        name += "_" + args.study.replace("/", "-")
    return name
