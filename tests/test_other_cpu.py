"""The tests that meet chaotic, grazing or transient points, run as another CPU would run them.

Every x86-64 machine with AVX2 computes the same bits (``worker/cpu.py``), so a machine in CI
cannot meet another's rounding by itself. This runs those tests in a fresh process whose
libraries take other code paths on any x86-64 CPU: numba compiling for a ``generic`` x86-64,
OpenBLAS's ``Sandybridge`` kernels, numpy's dispatch held to its baseline. A test that pinned
the bit-level outcome of such a point would fail here; an invariant holds.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from worker import cpu

ROOT = Path(__file__).resolve().parents[1]

# The tests whose points end where the last bits take them (issue: they failed on AVX-512).
SENSITIVE = [
    "tests/worker/test_engine.py::test_an_orbit_is_reported_only_where_the_trajectory_reaches_it",
    "tests/worker/test_engine.py::"
    "test_a_transient_guard_waits_where_chaos_may_die_out_and_moves_no_other_claim",
    "tests/worker/test_engine.py::"
    "test_chaos_beside_an_admissible_linear_response_is_labelled_as_possibly_transient",
    "tests/worker/test_simulate.py::test_the_history_of_an_orbit_with_many_events_a_period_is_whole",
    "tests/test_benchmarks.py::"
    "test_irregular_budget_reruns_only_the_noted_claims_with_a_transient_guard",
]

OTHER_CPU = {
    cpu.NUMBA_ENV: "generic",
    cpu.FEATURES_ENV: "",
    cpu.BLAS_ENV: "Sandybridge",
    cpu.NUMPY_ENV: "X86_V3 X86_V4 AVX512_ICL AVX512_SPR",
}


@pytest.mark.slow  # a new pytest process compiling the kernels for another target (~2 min)
@pytest.mark.skipif(not cpu.pinnable(), reason="the other targets are x86-64 ones")
def test_the_sensitive_tests_hold_with_another_cpus_rounding(tmp_path: Path) -> None:
    env = {**os.environ, **OTHER_CPU, "NUMBA_CACHE_DIR": str(tmp_path)}
    env.pop("PYTEST_XDIST_WORKER", None)
    probe = (
        "import worker, numpy; from worker.cpu import fingerprint; f = fingerprint(); "
        "print(f['numba_cpu'], f['blas_kernels'], f['numpy_simd'])"
    )
    seen = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert seen.returncode == 0, seen.stderr
    # the other code paths are taken: not the pinned ones
    assert seen.stdout.split() == ["generic", "Sandybridge", "baseline"], seen.stdout
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *SENSITIVE],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=1500,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert f"{len(SENSITIVE)} passed" in out.stdout
