"""Running an adaptive study: its lines sampled by learners, points in batches on dask.

An adaptive study (``adaptive:`` in the study, docs/adaptive.md) samples one axis of each line
(each combination of the other axes) where its target needs it: a learner per line
(``service.studies.adaptive``) asks for axis values, the runner computes them in batches on the
cluster (the same :class:`~service.studies.runner.ChunkPool` as grid studies, so several studies
share it), and tells each learner its values as they come back; the learners then ask again.

Points are numbered in the order they are first asked for (the "sample index": chunks are
ranges of it). Every computed point goes to the point store as it finishes, so a killed run
resumes by asking again: the learners are deterministic, so they ask for the same points, which
the store now answers at once. Without a point store a killed adaptive run starts over.

The dataset holds the sampled points over the union of every line's sampled axis values
(``sampled`` false and values missing where a line was not sampled there), the located edges
(``band_edges`` over an ``edge`` dimension, with the interval each is proven to lie in and a
flag for the uncertain ones) or features, and the points each line took (``line_points``).
"""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from service.studies.adaptive import (
    BandEdgeLearner,
    FeatureLearner,
    Sample,
    default_min_width,
)
from service.studies.chunks import StudyStore, record_columns
from service.studies.dataset import open_results, results_from_records
from service.studies.fence import Fence
from service.studies.points import PointStore, point_key, save_chunk, solver_document
from service.studies.schema import Study
from service.studies.summary import Cancelled, RunSummary
from service.studies.variables import OUTCOMES, outcome_names
from worker.simulate import PointLimits, SolverSettings, failed_result, simulate_chunk

__all__ = ["NOT_SAMPLED", "AdaptiveRun", "adaptive_dataset"]

#: Reason of the fill records where a line was not sampled (``sampled`` is false there).
NOT_SAMPLED = "not sampled: an adaptive line took no point at this value"
ADAPTIVE_CHUNK = 4  # points per task: a round of a few lines' probes spreads over the workers


class AdaptiveRun:
    """One adaptive study's side of a run: the same surface as ``StudyRun`` for the pool
    (``pieces``, ``points_of``, ``keys``, ``finished``, ``complete``, ``collate``)."""

    lines = False  # its chunks are independent points, never sweep lines

    def __init__(
        self,
        study: Study,
        root: str | Path | None,
        *,
        chunk_size: int | None = None,
        workers: int = 1,
        progress: Callable[[int, int], None] | None = None,
        on_chunk: Callable[[int, int, list[dict[str, Any]]], None] | None = None,
        points: PointStore | None = None,
        fence: Fence | None = None,
    ) -> None:
        assert study.adaptive is not None
        self.t0 = time.perf_counter()
        self.study = study
        self.spec = study.adaptive
        self.store = StudyStore(root, study, fence=fence)
        self.points = points
        self.reuse = points is not None and study.tag is None
        self.solver = study.solver.settings().__dict__.copy()
        self._solver_doc = solver_document(self.solver)
        self.progress = progress
        self.on_chunk = on_chunk
        self.kernel_s = 0.0
        self.in_flight = 0
        self.shared = 0
        self.shared_pool = False
        self.submitted = 0
        self.chunk = chunk_size or ADAPTIVE_CHUNK
        self.line_values = study.lines()
        axis = study.grid.given()[self.spec.axis]
        self.learners = [self._learner(float(axis.start), float(axis.stop), int(axis.num))
                         for _ in self.line_values]  # fmt: skip
        self.samples: list[tuple[int, float]] = []  # sample index → (line, axis value)
        self.records: list[dict[str, Any] | None] = []
        self.pieces: deque[tuple[int, int]] = deque()
        self.computed = 0  # points computed by this run
        self.reused = 0  # points the store answered
        self.cached = self.store.results_status() == "ok"  # a damaged file: set aside, rebuilt
        if not self.cached:
            self.store.prepare()
            self._refill()
        self._report()

    # ------------------------------------------------------------------ learners

    def _learner(self, start: float, stop: float, num: int) -> Any:
        s = self.spec
        if s.target == "band_edges":
            return BandEdgeLearner(
                start, stop, num, threshold_db=float(s.threshold_db), tol=float(s.tol),
                min_width=None if s.min_width is None else float(s.min_width),
                max_points=int(s.max_points),
            )  # fmt: skip
        # A coarse pass as for edges, so no peak hides between two starting samples.
        width = default_min_width(start, stop) if s.min_width is None else float(s.min_width)
        return FeatureLearner(
            start, stop, num,
            resolution=float(s.tol if s.resolution is None else s.resolution),
            jump_db=float(s.jump_db), max_points=int(s.max_points), min_width=width,
        )  # fmt: skip

    def _sample(self, record: dict[str, Any]) -> Sample:
        """What a point tells its learner: the value, and how sure it is."""
        if record.get("failed"):
            return Sample(None)
        value = record.get(self.spec.variable)
        if value is None:
            return Sample(None)
        se = None
        if self.spec.variable != "transmittance_linear_db":  # Γ_lin is the closed form
            se = record.get("transmittance_db_se")
            if se is None and record.get("outcome") == "unsettled":
                se = float("inf")  # no converged statistics: its side is not known
        return Sample(float(value), None if se is None else float(se))

    def _tell(self, i: int, record: dict[str, Any]) -> None:
        self.records[i] = record
        li, x = self.samples[i]
        self.learners[li].tell(x, self._sample(record))

    def _refill(self) -> None:
        """Ask every learner; answer what the store knows at once, queue the rest."""
        while True:
            new: list[int] = []
            for li, learner in enumerate(self.learners):
                if learner.done:
                    continue
                for x in learner.ask():
                    self.samples.append((li, float(x)))
                    self.records.append(None)
                    new.append(len(self.samples) - 1)
            if not new:
                return
            todo = new
            if self.reuse:
                assert self.points is not None
                keys = [self.key(i) for i in new]
                known = self.points.lookup(keys)
                if known:
                    self.points.link(
                        self.study.id, [(i, k) for i, k in zip(new, keys, strict=True)
                                        if k in known],
                    )  # fmt: skip
                    todo = []
                    for i, k in zip(new, keys, strict=True):
                        if k in known:
                            self._tell(i, known[k])
                            self.reused += 1
                        else:
                            todo.append(i)
            self._queue(todo)
            if len(todo) == len(new):
                return  # nothing answered: the learners wait for these

    def _queue(self, indices: list[int]) -> None:
        run: list[int] = []
        for i in [*indices, -1]:
            if run and (i != run[-1] + 1 or len(run) == self.chunk):
                self.pieces.append((run[0], run[-1] + 1))
                run = []
            if i >= 0:
                run.append(i)

    # ------------------------------------------------------------------ the pool's surface

    @property
    def total(self) -> int:
        """The most points the run may take (finished lines count what they took)."""
        return sum(
            lr.n_points if lr.done else max(lr.n_points, int(self.spec.max_points))
            for lr in self.learners
        )

    @property
    def done(self) -> int:
        """Points with a record (``computed`` counts every chunk's points, ``shared`` those of
        them another study's task computed: ``ChunkPool``)."""
        return self.computed + self.reused

    @property
    def n_missing(self) -> int:
        return len(self.pieces)

    def point(self, i: int) -> dict[str, Any]:
        """The ``CellParams`` keyword dict of sample ``i``."""
        li, x = self.samples[i]
        return self.study.model_point({**self.line_values[li], self.spec.axis: x})

    def points_of(self, start: int, stop: int) -> list[dict[str, Any]]:
        """The points of samples ``start:stop``."""
        return [self.point(i) for i in range(start, stop)]

    def coords_of(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Axis values of samples ``start:stop`` (failed points' coordinates)."""
        rows = [{**self.line_values[li], self.spec.axis: x}
                for li, x in self.samples[start:stop]]  # fmt: skip
        return {k: np.array([r[k] for r in rows]) for k in rows[0]} if rows else {}

    def keys(self, start: int, stop: int) -> list[str]:
        """Point keys of samples ``start:stop``."""
        return [point_key(p, self._solver_doc) for p in self.points_of(start, stop)]

    def key(self, i: int) -> str:
        return point_key(self.point(i), self._solver_doc)

    def plan(self, workers: int) -> None:
        """Nothing to plan: batches are what the learners ask for."""

    @property
    def complete(self) -> bool:
        """Every line done (nothing queued, nothing in flight)."""
        return not self.pieces and self.in_flight == 0

    def finished(
        self,
        start: int,
        stop: int,
        records: list[dict[str, Any]],
        retry: bool,
        keys: list[str] | None = None,
    ) -> None:
        """Store a chunk's records, tell their learners, queue what they ask next."""
        if self.points is not None and not retry:
            keys = keys or self.keys(start, stop)
            save_chunk(self.points, self.study.id, self._solver_doc, start, keys,
                       self.points_of(start, stop), records)  # fmt: skip
        self.kernel_s += sum(float(r.get("wall_s") or 0.0) for r in records)
        for i, rec in zip(range(start, stop), records, strict=True):
            self._tell(i, rec)
        self.computed += stop - start
        if self.on_chunk:
            self.on_chunk(start, stop, records)
        self._refill()
        self._report()

    def _report(self) -> None:
        if self.progress and not self.cached:
            self.progress(self.done, self.total)

    def run_serial(self, cancel: Callable[[], bool], limits: PointLimits) -> None:
        """Compute every batch in this process (reference runs, tests)."""
        while self.pieces:
            if cancel():
                raise Cancelled
            start, stop = self.pieces.popleft()
            records = simulate_chunk(self.points_of(start, stop), self.solver, asdict(limits),
                                     cancel)  # fmt: skip
            if len(records) < stop - start:
                raise Cancelled
            self.finished(start, stop, records, False)

    # ------------------------------------------------------------------ results

    def collate(self, workers: int) -> RunSummary:
        """The dataset (``adaptive_dataset``) written to the results file; the summary."""
        if self.cached:
            ds = open_results(self.store.results_path)
            return self._summary(ds, int(ds["sampled"].sum()), 0, 0, cached=True)
        ds = adaptive_dataset(self)
        self.store.write_results(ds)
        self.store.remove_chunks()
        n = sum(r is not None for r in self.records)
        return self._summary(ds, n, self.computed - self.shared, workers, cached=False)

    def _summary(self, ds: xr.Dataset, n: int, computed: int, workers: int,
                 cached: bool) -> RunSummary:  # fmt: skip
        """Counts over the sampled points of an adaptive dataset."""
        took = ds["sampled"].values.astype(bool)
        names = outcome_names(ds["outcome"])[took]
        counts = {k: int(np.sum(names == k)) for k in OUTCOMES}
        return RunSummary(
            study_id=self.study.id, path=self.store.results_path, points=n, computed=computed,
            reused=n - computed, failed=counts["failed"], irregular=counts["irregular"],
            unsettled=counts["unsettled"], wall_s=time.perf_counter() - self.t0,
            kernel_s=self.kernel_s, workers=workers, chunk_size=0 if cached else self.chunk,
            cached=cached, outcomes=counts,
        )  # fmt: skip

    def cancelled_summary(self, workers: int) -> RunSummary:
        """The summary of a run stopped on request (its points are in the store)."""
        return RunSummary(
            study_id=self.study.id, path=self.store.results_path, points=self.total,
            computed=self.computed - self.shared, reused=self.reused + self.shared, failed=0,
            irregular=0, unsettled=0,
            wall_s=time.perf_counter() - self.t0, kernel_s=self.kernel_s, workers=workers,
            chunk_size=self.chunk, cancelled=True,
        )  # fmt: skip


def adaptive_dataset(run: AdaptiveRun) -> xr.Dataset:
    """The results of a finished adaptive run over the union of its sampled axis values."""
    study, spec = run.study, run.spec
    assert spec is not None
    axis = spec.axis
    xs = np.unique(np.array([x for _, x in run.samples], dtype=np.float64))
    definition = study.canonical()
    definition.pop("adaptive")
    definition["grid"][axis] = [float(x) for x in xs]
    union = Study.model_validate(definition)
    where = {
        (li, x): rec
        for (li, x), rec in zip(run.samples, run.records, strict=True)
        if rec is not None
    }
    line_index = {_line_key(v): li for li, v in enumerate(run.line_values)}
    cols = union.coords_at(0, union.size, grid=True)
    fill = failed_result(SolverSettings(**run.solver), NOT_SAMPLED)
    records: list[dict[str, Any]] = []
    sampled = np.zeros(union.size, dtype=bool)
    for i in range(union.size):
        row = {k: float(v[i]) for k, v in cols.items()}
        x = row.pop(axis)
        rec = where.get((line_index[_line_key(row)], x))
        sampled[i] = rec is not None
        records.append(dict(rec) if rec is not None else dict(fill))
    ds = results_from_records(union, record_columns(records))
    dims = tuple(union.dims())
    took = {"units": "1", "long_name": "the adaptive line took a point here"}
    ds["sampled"] = (dims, sampled.reshape(union.shape), took)
    ds.attrs.update(
        study_name=study.name, study_id=study.id, study=study.canonical_json(),
        title=f"impactcell study {study.name}", adaptive=json.dumps(spec.model_dump(mode="json")),
        comment=ds.attrs.get("comment", "") + "; adaptive study: sampled = 0 marks values "
        "a line did not take (their variables are missing)",
    )  # fmt: skip
    line_dims = tuple(d for d in dims if d != axis)
    line_shape = tuple(ds.sizes[d] for d in line_dims)
    # Lines in C order of the other varying axes: study.lines() runs over every other axis
    # (single-valued ones included), in the same canonical order.
    ds["line_points"] = (
        line_dims,
        np.array([lr.n_points for lr in run.learners], dtype=np.int32).reshape(line_shape),
        {"units": "1", "long_name": "points the adaptive line took"},
    )
    if spec.target == "band_edges":
        _edges_vars(ds, run, line_dims, line_shape)
    else:
        _feature_vars(ds, run, line_dims, line_shape)
    return ds


def _line_key(values: dict[str, float]) -> tuple[tuple[str, float], ...]:
    return tuple(sorted(values.items()))


def _edges_vars(ds: xr.Dataset, run: AdaptiveRun, dims: tuple[str, ...],
                shape: tuple[int, ...]) -> None:  # fmt: skip
    edges = [lr.edges() for lr in run.learners]
    n = max([len(e) for e in edges] + [1])
    arr = {k: np.full((len(edges), n), np.nan) for k in ("x", "lo", "hi")}
    rising = np.full((len(edges), n), np.nan)  # 1/0 flags, missing past the last edge
    certain = np.full((len(edges), n), np.nan)
    for li, es in enumerate(edges):
        for j, e in enumerate(es):
            arr["x"][li, j], arr["lo"][li, j], arr["hi"][li, j] = e.x, e.lo, e.hi
            rising[li, j] = float(e.rising)
            certain[li, j] = float(e.certain)
    spec = run.spec
    assert spec is not None
    units = ds[spec.axis].attrs.get("units", "1")
    what = f"{spec.variable} = {float(spec.threshold_db):g} dB"
    full = (*dims, "edge")
    sh = (*shape, n)
    ds["band_edges"] = (full, arr["x"].reshape(sh), {
        "units": units, "long_name": f"band edges along {spec.axis}: crossings of {what}, "
        f"increasing, located to {float(spec.tol):g} (missing past the last)"})  # fmt: skip
    ds["band_edge_lo"] = (
        full,
        arr["lo"].reshape(sh),
        {"units": units, "long_name": "lower end of the interval the edge is proven to lie in"},
    )
    ds["band_edge_hi"] = (
        full,
        arr["hi"].reshape(sh),
        {"units": units, "long_name": "upper end of the interval the edge is proven to lie in"},
    )
    ds["band_edge_rising"] = (full, rising.reshape(sh), {
        "units": "1", "long_name": f"1: the variable rises through the threshold with {spec.axis}"
        ", 0: it falls"})  # fmt: skip
    ds["band_edge_certain"] = (full, certain.reshape(sh), {
        "units": "1", "long_name": "1: located to tol; 0: only the interval is known (the "
        "confidence band of irregular points straddles the threshold there, or failed points "
        "hide the crossing)"})  # fmt: skip


def _feature_vars(ds: xr.Dataset, run: AdaptiveRun, dims: tuple[str, ...],
                  shape: tuple[int, ...]) -> None:  # fmt: skip
    feats = [lr.features() for lr in run.learners]
    n = max([len(f) for f in feats] + [1])
    lo = np.full((len(feats), n), np.nan)
    hi = np.full((len(feats), n), np.nan)
    for li, fs in enumerate(feats):
        for j, (a, b) in enumerate(fs):
            lo[li, j], hi[li, j] = a, b
    spec = run.spec
    assert spec is not None
    units = ds[spec.axis].attrs.get("units", "1")
    full = (*dims, "feature")
    ds["feature_lo"] = (full, lo.reshape(*shape, n), {
        "units": units, "long_name": f"start of an interval of {spec.axis} where "
        f"{spec.variable} jumps or bends (missing past the last)"})  # fmt: skip
    ds["feature_hi"] = (
        full,
        hi.reshape(*shape, n),
        {"units": units, "long_name": "end of that interval"},
    )
