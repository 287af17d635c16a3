"""End-to-end throughput of a 10,000-point study on the embedded LocalCluster.

γ_r 0.2–6 (100 values) × 10 gaps × 10 θ, default solver settings, one worker process per core.
Reports the end-to-end wall time (cluster start, warm-up, all chunks, collation, NetCDF write)
and compares it with the ideal ``sum of per-point kernel times / cores``, where the per-point
kernel time is the ``wall_s`` each point reports (the numba time loop only) and, for a fuller
picture, the serial cost of ``simulate_chunk`` per point (kernel plus per-point set-up: matrix
assembly and exponentials).

Run: ``python benchmarks/study_throughput.py [--workers N] [--chunk-size N]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import worker  # noqa: F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np

from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from worker.simulate import simulate_chunk

STUDY = {
    "name": "throughput-10k",
    "description": "benchmark: gamma_r 0.2-6 x 10 gaps x 10 theta, default solver",
    "grid": {
        "gamma_r": {"start": 0.2, "stop": 6.0, "num": 100},
        "gap": {"start": 0.1, "stop": 1.0, "num": 10},
        "theta": {"start": 0.05, "stop": 0.5, "num": 10},
        "sigma": 0.05,
        "gamma_s": 1.0,
    },
}


def main() -> None:
    """Run the benchmark and print/save the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--chunk-size", type=int, default=None)
    ap.add_argument("--sample", type=int, default=300, help="points timed serially")
    args = ap.parse_args()

    study = parse_study(STUDY)
    cores = args.workers or os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        s = run_study(study, tmp, workers=cores, chunk_size=args.chunk_size)
        wall = time.perf_counter() - t0
        ds = open_results(s.path)
        kernel_sum = float(ds["wall_s"].sum())

    # Serial cost of whole points (set-up + kernel) on an even sample, in this process.
    rng = np.random.default_rng(0)
    idx = np.sort(rng.choice(study.size, size=min(args.sample, study.size), replace=False))
    pts = [study.points(int(i), int(i) + 1)[0] for i in idx]
    simulate_chunk(pts[:2], {})  # load the kernels
    t1 = time.perf_counter()
    rec = simulate_chunk(pts, {})
    per_point_full = (time.perf_counter() - t1) / len(pts)
    per_point_kernel = float(np.mean([r["wall_s"] for r in rec]))

    ideal_kernel = kernel_sum / cores
    ideal_full = per_point_full * study.size / cores
    out = {
        "points": s.points,
        "failed": s.failed,
        "irregular": s.irregular,
        "workers": cores,
        "chunk_size": s.chunk_size,
        "wall_s_end_to_end": round(wall, 3),
        "sum_kernel_s": round(kernel_sum, 3),
        "ideal_s_kernel_sum_over_cores": round(ideal_kernel, 3),
        "overhead_vs_kernel_ideal": round(wall / ideal_kernel - 1.0, 4),
        "serial_ms_per_point_full": round(per_point_full * 1e3, 3),
        "serial_ms_per_point_kernel": round(per_point_kernel * 1e3, 3),
        "ideal_s_full_points_over_cores": round(ideal_full, 3),
        "overhead_vs_full_ideal": round(wall / ideal_full - 1.0, 4),
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "python": platform.python_version(),
    }
    print(json.dumps(out, indent=1))
    dest = Path(__file__).parent / "results" / "study_throughput.json"
    dest.parent.mkdir(exist_ok=True)
    dest.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
