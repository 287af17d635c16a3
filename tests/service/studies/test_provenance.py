"""service.studies.provenance: looked up once per process, written into every dataset."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest

from service.studies import provenance
from service.studies.chunks import StudyStore
from service.studies.dataset import results_from_records
from service.studies.schema import parse_study
from worker import cpu
from worker.simulate import SolverSettings, failed_result


def test_git_is_asked_once_per_process(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[list[str]] = []
    real = subprocess.run

    def counting(args: list[str], **kw: Any) -> Any:
        calls.append(list(args))
        return real(args, **kw)

    monkeypatch.setattr(subprocess, "run", counting)
    provenance.git_commit.cache_clear()
    provenance.git_dirty.cache_clear()
    first = provenance.provenance_attrs()
    for _ in range(5):
        assert provenance.provenance_attrs() == first
    assert [c[:2] for c in calls] == [["git", "rev-parse"], ["git", "status"]]
    assert first["git_dirty"] in ("yes", "no", "unknown")
    assert set(first) == {
        "impactcell_version", "git_commit", "git_dirty", "xarray_version", "dask_version",
        *cpu.FINGERPRINT_KEYS,
    }  # fmt: skip
    # Which OpenBLAS kernels and numba target compute the points: pinned where the CPU runs them.
    if cpu.pinnable():
        assert (first["blas_kernels"], first["numba_cpu"]) == (cpu.BLAS_CORE, cpu.NUMBA_CPU)


def test_datasets_carry_the_provenance(tmp_path: Path) -> None:
    study = parse_study({"name": "p", "grid": {"gamma_r": [1.0, 2.0], "gap": 0.1, "theta": 0.3,
                                               "sigma": 0.05, "gamma_s": 1.0}})  # fmt: skip
    store = StudyStore(tmp_path, study)
    store.prepare()
    rec = failed_result(SolverSettings(), "test")
    store.write_chunk(0, 2, [rec, rec])
    ds = results_from_records(study, store.collect())
    for key, value in provenance.provenance_attrs().items():
        assert ds.attrs[key] == value
