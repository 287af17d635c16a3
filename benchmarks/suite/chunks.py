"""One dask task's work without dask: a chunk of Figure 5's points through ``simulate_chunk``,
what a worker runs for each task."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
from service.studies.schema import load_study  # noqa: E402
from service.studies.shipped import resolve_study_file  # noqa: E402
from worker.simulate import simulate_chunk, warm_up  # noqa: E402

CHUNK = 96  # the runner's DEFAULT_CHUNK_SIZE


class Figure5Chunk:
    """The first chunk of ``paper-fig5-gaps`` (96 points) with the study's solver settings."""

    timeout = 600

    def setup(self) -> None:
        warm_up("event", quiet=True)
        study = load_study(resolve_study_file("paper-fig5-gaps"))
        self.points = study.points(0, CHUNK)
        self.solver = study.solver.settings().__dict__.copy()

    def time_chunk(self) -> None:
        simulate_chunk(self.points, self.solver)

    def track_periods(self) -> int:
        return sum(r["periods"] for r in simulate_chunk(self.points, self.solver))

    track_periods.unit = "periods"  # type: ignore[attr-defined]
