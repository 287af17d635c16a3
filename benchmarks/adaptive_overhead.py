"""Point-selection overhead: python-adaptive's Learner1D against our BandEdgeLearner.

    pip install adaptive   # not a dependency of impactcell: only for this measurement
    python benchmarks/adaptive_overhead.py

Both learners are driven on a resonance-like Γ(γ_r) (dB) over 0.2–6 that costs microseconds,
so the time per point is the learner's own ask/tell work: Learner1D with ``ask(4)`` batches to
150 and 1000 points, BandEdgeLearner to ``tol`` 1e-3 with ``min_width`` 0.1. Compare with a
point's cost (1–20 ms, benchmarks/point_engine.py).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from service.studies.adaptive import BandEdgeLearner, Sample  # noqa: E402


def gamma(x: float) -> float:
    """A one-degree-of-freedom resonance at 1.3 in dB: a band above ≈ 1.84."""
    return 20 * math.log10(abs(1 / complex(1 - (x / 1.3) ** 2, 0.1 * x / 1.3)))


def learner1d(n: int) -> float:
    """ms per point of Learner1D, ``n`` points."""
    import adaptive

    learner = adaptive.Learner1D(gamma, bounds=(0.2, 6.0))
    t0 = time.perf_counter()
    told = 0
    while told < n:
        xs, _ = learner.ask(4)
        for x in xs:
            learner.tell(x, gamma(x))
            told += 1
    return 1e3 * (time.perf_counter() - t0) / told


def ours() -> tuple[float, int]:
    """ms per point of BandEdgeLearner, and the points it took."""
    learner = BandEdgeLearner(0.2, 6.0, 2, tol=1e-3, min_width=0.1, max_points=150)
    t0 = time.perf_counter()
    told = 0
    while not learner.done:
        xs = learner.ask()
        if not xs:
            break
        for x in xs:
            learner.tell(x, Sample(gamma(x)))
            told += 1
    return 1e3 * (time.perf_counter() - t0) / told, told


def main() -> None:
    """Print the overheads."""
    try:
        for n in (150, 1000):
            print(f"Learner1D, {n} points: {learner1d(n):.3f} ms per point")
    except ImportError:
        print("python-adaptive is not installed (pip install adaptive): Learner1D skipped")
    ms, n = ours()
    print(f"BandEdgeLearner, tol 1e-3 ({n} points): {ms:.3f} ms per point")


if __name__ == "__main__":
    main()
