"""Study definitions: one pydantic model, validation and the content-hash id.

A study file (YAML or JSON) names a cell model, solver settings, the outputs to store and a grid;
the study is the Cartesian product of the grid's axes (:mod:`service.studies.grid`). The
blocks themselves are derived from the worker's types (:mod:`service.studies.specs`).
Non-dimensional studies vary the parameters of docs/model.md §3; physical studies
(docs/model.md §8) give a ``physical:`` block in SI units and vary ``frequency_hz`` and any
physical field; their base amplitude may be given per frequency (a list aligned with
``frequency_hz``, or a table whose frequencies are the grid's; docs/experiment.md), and each
point then maps with its own frequency's amplitude.

Validation reports every problem it can find in one go, each with its path in the file
(``grid.gamma_r.num: ...``), as a :class:`StudyError` (a ``ValueError``). Grid sizes are
arithmetic (:meth:`Study.sizes`): the point limit is checked, and ``size``/``shape`` are
known, without building any axis; a physical grid's model parameters are checked at its
corners.

A study may also name initial states (``initial:``) and a sweep along one grid axis
(``sweep:``); both are absent by default, so a study without them keeps its id and results.
Then :attr:`Study.size` counts every computation (initial states × directions × grid points),
the results get ``initial``/``direction`` dimensions before the grid's (:meth:`Study.result_dims`),
and the runner's flat index is "work order" (:meth:`Study.work_indices`), in which each sweep
line is contiguous; :meth:`Study.result_index` maps it onto the results.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field, PrivateAttr, StrictBool, ValidationError

from service.studies.files import nul_paths, read_study_file
from service.studies.grid import AXIS_TAGS, Range, Real, StrictModel, axis_size, axis_values
from service.studies.limits import DEFAULT_MAX_POINTS
from service.studies.specs import (
    MAX_STEPS_PER_POINT,
    PER_FREQUENCY_FIELDS,
    AdaptiveSpec,
    AmplitudeTable,
    Grid,
    InitialSpec,
    ModelSpec,
    PhysicalSpec,
    SolverSpec,
    SweepSpec,
    initial_labels,
    initial_states,
)
from service.studies.variables import MODEL_AXES, PHYSICAL_AXES, PHYSICAL_FIELDS
from worker.model import CellParams
from worker.physical import CELL_FIELDS, PhysicalCell
from worker.simulate import CHAIN_METHODS, SOLVER_VERSION

__all__ = [
    "DEFAULT_COEXISTENCE_TOL_DB",
    "DEFAULT_MAX_POINTS",
    "Grid",
    "ModelSpec",
    "Outputs",
    "PhysicalSpec",
    "SolverSpec",
    "Study",
    "SweepSpec",
    "StudyError",
    "load_study",
    "parse_study",
    "study_from_canonical",
    "validation_problems",
]

# The grid-size limit when none is given (``Settings.max_points``, ``--max-points``).
#: Two responses at one grid point whose Γ differ by less than this (dB) are the same one
#: (``outputs.coexistence_tol_db``; irregular ones: within 3 combined standard errors).
DEFAULT_COEXISTENCE_TOL_DB = 0.05

# --------------------------------------------------------------------------- the study


class Outputs(StrictModel):
    """Which result groups are stored (failed, reason and wall_s always are).

    transmittance: ``transmittance_db``, ``transmittance_db_se``, ``amplitude``;
    effective_mass: ``theta_eff`` (the effective mass), ``theta_eff_slope`` (the phase-portrait
    ratio θ_ps); response: ``outcome``, ``may_be_transient``, ``impacting_periods``,
    ``response_period``, ``impacts_per_period``, ``contact_fraction``, ``impact_velocity``,
    ``impact_energy`` (each with its standard error), ``impact_energy_share``,
    ``peak_impulse``, ``floquet_multiplier``, ``periods``, ``steps``; contact (off by default:
    diagnostics that cost storage, not insight): ``contact_steps``, ``coarse_steps``,
    ``steady_period``.
    """

    # Strict: "yes", "true" or 1 are not booleans (JSON and YAML have true and false).
    transmittance: StrictBool = True
    effective_mass: StrictBool = True
    response: StrictBool = True
    contact: StrictBool = False
    # Absent by default (None: ``DEFAULT_COEXISTENCE_TOL_DB``), so existing ids are unchanged.
    coexistence_tol_db: Real | None = Field(
        None,
        gt=0,
        le=100,
        description=(
            "Responses at one grid point whose transmittance differs by less than this (dB) "
            "are counted as one in `responses` (default 0.05); studies with several initial "
            "states or sweep directions."
        ),
    )

    def tol_db(self) -> float:
        """The coexistence tolerance in dB (the default when not given)."""
        tol = self.coexistence_tol_db
        return DEFAULT_COEXISTENCE_TOL_DB if tol is None else float(tol)


class Study(StrictModel):
    """A parameter study: the Cartesian product of ``grid``'s axes."""

    name: str = Field(min_length=1, max_length=200)
    description: str = Field("", max_length=10_000)
    # A run tag: part of the id (a new tag is a fresh run of the same definition); absent by
    # default, so untagged studies keep their ids. The nightly suite sets ``nightly-<time>``.
    tag: str | None = Field(None, min_length=1, max_length=100)
    model: ModelSpec = ModelSpec()
    solver: SolverSpec = SolverSpec()
    outputs: Outputs = Outputs()
    physical: PhysicalSpec | None = None
    grid: Grid
    # Absent by default, so existing ids are unchanged (docs: README "Study files").
    sweep: SweepSpec | None = None
    adaptive: AdaptiveSpec | None = None
    initial: InitialSpec | None = None
    _axes: dict[str, np.ndarray] | None = PrivateAttr(None)
    _amplitudes: np.ndarray | None = PrivateAttr(None)

    # ---------------------------------------------------------------- identity

    def canonical(self) -> dict[str, Any]:
        """The definition with every default filled in, as plain JSON data."""
        return self.model_dump(mode="json", exclude_none=True)

    def canonical_json(self) -> str:
        """Canonical JSON text: sorted keys, no whitespace."""
        return json.dumps(self.canonical(), sort_keys=True, separators=(",", ":"))

    @property
    def id(self) -> str:
        """Content hash of the canonical definition plus the solver version."""
        text = f"{self.canonical_json()}\nsolver={SOLVER_VERSION}"
        return hashlib.sha256(text.encode()).hexdigest()[:20]

    # ---------------------------------------------------------------- grid

    @property
    def is_physical(self) -> bool:
        """Whether this is a physical (SI) study."""
        return self.physical is not None

    def axes(self) -> dict[str, np.ndarray]:
        """Every grid axis in canonical order, name -> values (built once per study object:
        every chunk's ``points`` reads them)."""
        if self._axes is None:
            order = PHYSICAL_AXES if self.is_physical else MODEL_AXES
            given = self.grid.given()
            axes = {k: axis_values(given[k]) for k in order if k in given}
            for v in axes.values():
                v.flags.writeable = False  # shared by every caller
            self._axes = axes
        return dict(self._axes)

    def dims(self) -> dict[str, np.ndarray]:
        """The varying axes (more than one value): the dataset's dimensions."""
        return {k: v for k, v in self.axes().items() if v.size > 1}

    def scalars(self) -> dict[str, float]:
        """The axes with a single value: the dataset's scalar coordinates."""
        return {k: float(v[0]) for k, v in self.axes().items() if v.size == 1}

    def sizes(self) -> dict[str, int]:
        """Every grid axis's number of values in canonical order (arithmetic: nothing built)."""
        order = PHYSICAL_AXES if self.is_physical else MODEL_AXES
        given = self.grid.given()
        return {k: axis_size(given[k]) for k in order if k in given}

    @property
    def grid_shape(self) -> tuple[int, ...]:
        """Shape of the grid (one entry per varying axis)."""
        return tuple(n for n in self.sizes().values() if n > 1)

    @property
    def grid_size(self) -> int:
        """Number of grid points."""
        return math.prod(self.sizes().values())

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of the results: ``initial`` (several initial states), ``direction`` (a
        sweep), then one entry per varying grid axis."""
        return (*self._lead_shape(), *self.grid_shape) if self.is_extended else self.grid_shape

    @property
    def size(self) -> int:
        """Number of points to compute (initial states × directions × grid points); for an
        adaptive study the most it may compute (lines × ``max_points``)."""
        if self.adaptive is not None:
            n = self.sizes()
            return math.prod(v for k, v in n.items() if k != self.adaptive.axis) * int(
                self.adaptive.max_points
            )
        return self.n_initial * self.n_directions * self.grid_size

    # ---------------------------------------------------------------- initial states, sweeps

    @property
    def is_extended(self) -> bool:
        """Whether the study names initial states or a sweep (results beyond the grid)."""
        return self.sweep is not None or self.initial is not None

    def initial_labels(self) -> list[str]:
        """Labels of the initial states (``["rest"]`` when none is given)."""
        return initial_labels(self.initial)

    @property
    def n_initial(self) -> int:
        """How many initial states each grid point (or sweep line) starts from."""
        return len(self.initial_labels())

    def directions(self) -> list[str]:
        """The sweep's directions in order (empty without a sweep)."""
        return [] if self.sweep is None else list(self.sweep.directions)

    @property
    def n_directions(self) -> int:
        """How many sweep directions (1 without a sweep)."""
        return max(1, len(self.directions()))

    @property
    def line_length(self) -> int:
        """Points of one sweep line (the swept axis's size); 1 without a sweep."""
        return 1 if self.sweep is None else self.sizes()[self.sweep.axis]

    def _lead_shape(self) -> tuple[int, ...]:
        lead = (self.n_initial,) if self.n_initial > 1 else ()
        return (*lead, self.n_directions) if self.sweep is not None else lead

    def result_dims(self) -> dict[str, np.ndarray]:
        """The dataset's dimensions in order, name -> values: ``initial`` (labels, when more
        than one), ``direction`` (a sweep's, ``up``/``down``), then :meth:`dims`."""
        out: dict[str, np.ndarray] = {}
        if self.n_initial > 1:
            out["initial"] = np.array(self.initial_labels())
        if self.sweep is not None:
            out["direction"] = np.array(self.directions())
        return {**out, **self.dims()}

    def _sweep_orders(self) -> np.ndarray:
        """Grid value index of each step of a line, one row per direction (up: increasing
        values of the swept axis, down: decreasing)."""
        assert self.sweep is not None
        up = np.argsort(self.axes()[self.sweep.axis], kind="stable")
        rows = {"up": up, "down": up[::-1]}
        return np.stack([rows[d] for d in self.directions()])

    def work_indices(
        self, start: int, stop: int
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Initial-state index, direction index and each grid axis's value index of points
        ``start:stop`` in work order.

        Work order is the runner's flat index (chunk files): initial-major, then direction,
        then the grid's C order, except that in a sweep the swept axis varies fastest and in
        sweep order, so every line (one initial state × one direction × one combination of
        the other axes) is contiguous. Without a sweep or initial states it is the grid's C
        order.
        """
        w = np.arange(start, stop, dtype=np.int64)
        sizes = self.sizes()
        names = list(sizes)
        ni, nd = self.n_initial, self.n_directions
        if self.sweep is None:
            parts = np.unravel_index(w, (ni, nd, *sizes.values()))
            idx = dict(zip(names, parts[2:], strict=True))
        else:
            axis = self.sweep.axis
            others = [n for n in names if n != axis]
            shape = (ni, nd, *(sizes[n] for n in others), sizes[axis])
            parts = np.unravel_index(w, shape)
            found = dict(zip(others, parts[2:-1], strict=True))
            found[axis] = self._sweep_orders()[parts[1], parts[-1]]
            idx = {n: found[n] for n in names}
        return parts[0], parts[1], idx

    def result_index(self, start: int, stop: int) -> np.ndarray:
        """Flat C-order index in the results' shape (:attr:`shape`) of work points
        ``start:stop``; over the whole study a bijection."""
        i, d, idx = self.work_indices(start, stop)
        full = (self.n_initial, self.n_directions, *self.sizes().values())
        return np.ravel_multi_index((i, d, *idx.values()), full)

    def _indices(self, start: int, stop: int, grid: bool = False) -> dict[str, np.ndarray]:
        """Each axis's value index of points ``start:stop`` (work order, or with ``grid`` the
        grid's flat C order)."""
        if grid or not self.is_extended:
            axes = self.axes()
            shape = tuple(v.size for v in axes.values())
            idx = np.unravel_index(np.arange(start, stop), shape)
            return dict(zip(axes, idx, strict=True))
        return self.work_indices(start, stop)[2]

    def coords_at(self, start: int, stop: int, *, grid: bool = False) -> dict[str, np.ndarray]:
        """Grid-axis values of points ``start:stop`` (work order, or with ``grid`` the
        grid's flat C order), name -> array."""
        axes = self.axes()
        return {k: axes[k][i] for k, i in self._indices(start, stop, grid).items()}

    def base_amplitudes_m(self) -> np.ndarray | None:
        """A physical study's base amplitude at each value of ``frequency_hz`` (in the axis's
        order) when it is given per frequency, else None."""
        p = self.physical
        if p is None or all(getattr(p, k) is None for k in PER_FREQUENCY_FIELDS):
            return None
        if self._amplitudes is None:
            freqs = self.axes()["frequency_hz"]
            if p.base_amplitude_table is not None:
                amps, problems = _aligned(freqs, p.base_amplitude_table)
                if amps is None:  # parse_study refuses this; a hand-built Study may not
                    raise StudyError(problems)
            else:
                amps = np.asarray(p.base_amplitude_per_frequency_m, dtype=np.float64)
            amps.flags.writeable = False
            self._amplitudes = amps
        return self._amplitudes

    def cells(
        self, start: int, stop: int, *, grid: bool = False
    ) -> list[tuple[PhysicalCell, float]]:
        """A physical study's points ``start:stop`` (work order, or with ``grid`` the grid's
        C order) as (SI cell, frequency in Hz) pairs."""
        assert self.physical is not None, "cells() is for physical studies"
        cols = self.coords_at(start, stop, grid=grid)
        base = self.physical.cell_fields()
        amps = self.base_amplitudes_m()
        # Per-frequency amplitudes: each point takes its frequency's value as U_g.
        at_f = None if amps is None else amps[self._indices(start, stop, grid)["frequency_hz"]]
        out = []
        for i in range(stop - start):
            fields = {**base, **{k: float(v[i]) for k, v in cols.items()}}
            if at_f is not None:
                fields["base_amplitude_m"] = float(at_f[i])
            f = fields.pop("frequency_hz")
            out.append((PhysicalCell(**fields), f))
        return out

    def points(self, start: int, stop: int, *, grid: bool = False) -> list[dict[str, Any]]:
        """``CellParams`` keyword dicts of points ``start:stop`` in work order (with ``grid``:
        grid points in the grid's C order). When the study names initial states, each work
        point also carries its ``initial`` (``kind``, ``seed``, ``index``: the worker's)."""
        out: list[dict[str, Any]] = []
        if self.is_physical:
            common = self._common()
            out = [{**c.to_model(f), **common} for c, f in self.cells(start, stop, grid=grid)]
        else:
            cols = self.coords_at(start, stop, grid=grid)
            for i in range(stop - start):
                out.append(self.model_point({k: float(v[i]) for k, v in cols.items()}))
        if self.initial is not None and not grid:
            states = initial_states(self.initial)
            for p, k in zip(out, self.work_indices(start, stop)[0], strict=True):
                p["initial"] = dict(states[int(k)])
        return out

    def _common(self) -> dict[str, Any]:
        m = self.model
        common: dict[str, Any] = {"modes": m.modes, "coupling": m.coupling}
        if m.xi_b is not None:
            common["xi_b"] = m.xi_b
        return common

    def model_point(self, values: Mapping[str, float]) -> dict[str, Any]:
        """The ``CellParams`` keyword dict of a non-dimensional point from its grid axes'
        values (``gap`` sets both stops; ``xi`` from the model block unless an axis).

        A chain of N > 1 cells adds ``cells`` and, for a graded chain, ``cell_g1``,
        ``cell_g2`` and ``cell_sigma`` (the worker's ``CHAIN_POINT_KEYS``); its own g1, g2 and
        σ are cell 1's. A point of N = 1 is the unit cell's dict, whatever the study says."""
        row = dict(values)
        m = self.model
        n = int(row.pop("cells", m.cells or 1))
        if "gap" in row:
            g = row.pop("gap")
            row["g1"] = row["g2"] = g
        if "restitution" in row:
            e = row.pop("restitution")
            row["e1"] = row["e2"] = e
        row.setdefault("xi", m.xi)
        if m.gaps is not None:
            row["g1"] = row["g2"] = float(m.gaps[0])
            if n > 1:
                row["cell_g1"] = row["cell_g2"] = [float(v) for v in m.gaps]
        if m.sigmas is not None:
            row["sigma"] = float(m.sigmas[0])
            if n > 1:
                row["cell_sigma"] = [float(v) for v in m.sigmas]
        if n > 1:
            row["cells"] = n
        return {**row, **self._common()}

    def max_cells(self) -> int:
        """The longest chain of the study (1: unit cells only)."""
        if self.model.cells is not None:
            return int(self.model.cells)
        if self.grid.cells is not None:
            return int(axis_values(self.grid.cells).max())
        return 1

    def cell_points(self) -> int:
        """What the study's points cost in cells: each point counts N (arithmetic)."""
        sizes = self.sizes()
        if self.grid.cells is not None:
            rest = math.prod(v for k, v in sizes.items() if k != "cells")
            per = float(axis_values(self.grid.cells).sum())
        else:
            rest, per = math.prod(sizes.values()), float(self.model.cells or 1)
        return int(per * rest * self.n_initial * self.n_directions)

    # ---------------------------------------------------------------- adaptive lines

    @property
    def is_adaptive(self) -> bool:
        """Whether one axis is sampled adaptively (``adaptive:``)."""
        return self.adaptive is not None

    def line_axes(self) -> dict[str, np.ndarray]:
        """An adaptive study's other axes (every axis but the sampled one), canonical order."""
        assert self.adaptive is not None
        return {k: v for k, v in self.axes().items() if k != self.adaptive.axis}

    def lines(self) -> list[dict[str, float]]:
        """An adaptive study's lines: each combination of the other axes' values, C order."""
        axes = self.line_axes()
        return [
            dict(zip(axes, (float(x) for x in combo), strict=True))
            for combo in itertools.product(*axes.values())
        ]

    def iter_points(self, chunk: int = 4096) -> Iterator[dict[str, Any]]:
        """Every point in order (for serial reference runs and tests)."""
        for s in range(0, self.size, chunk):
            yield from self.points(s, min(s + chunk, self.size))

    # ---------------------------------------------------------------- semantic checks

    def problems(self, max_points: int | None = None) -> list[tuple[str, str]]:
        """Cross-field problems: (path, message) pairs; empty when the study is sound."""
        out = _grid_problems(
            self.grid,
            self.physical,
            explicit_xi="xi" in self.model.model_fields_set,
            max_points=max_points,
            lead=self._lead_sizes(),
            # a chain's per-cell lists give what these axes would
            supplied={a for name, a in (("gaps", "gap"), ("sigmas", "sigma"))
                      if getattr(self.model, name) is not None},
        )  # fmt: skip
        if self.sweep is not None:
            out += _sweep_problems(self.sweep, self.grid)
        if self.adaptive is not None:
            out += _adaptive_problems(self)
        return _chain_problems(self, out, max_points) + _restitution_problems(self)

    def _lead_sizes(self) -> dict[str, int]:
        """Sizes of the dimensions before the grid's (initial states, directions)."""
        lead: dict[str, int] = {}
        if self.n_initial > 1:
            lead["initial"] = self.n_initial
        if self.sweep is not None and self.n_directions > 1:
            lead["direction"] = self.n_directions
        return lead


def _restitution_problems(study: Study) -> list[tuple[str, str]]:
    """Rebounding stops (an e axis above 0) need one cell (chains run plastic impacts)."""
    given = study.grid.given()
    axes = [a for a in ("restitution", "e1", "e2") if a in given]
    if not axes or max(_ends(given[a])[1] for a in axes) <= 0.0:
        return []
    out = []
    if study.max_cells() > 1:
        out.append((f"grid.{axes[0]}", "chains of N > 1 cells run plastic impacts only (e = 0)"))
    return out


#: What a chain's per-cell lists replace on the grid.
_PER_CELL_AXES = {"gaps": ("gap", "g1", "g2"), "sigmas": ("sigma",)}


def _chain_problems(
    study: Study, found: list[tuple[str, str]], max_points: int | None
) -> list[tuple[str, str]]:
    """``found`` with a chain's rules: per-cell lists in place of their grid axes, N in one
    place, what chains of N > 1 cells run with, and the point budget counted in cells."""
    m, given = study.model, study.grid.given()
    out = list(found)
    for name, axes in _PER_CELL_AXES.items():
        if getattr(m, name) is None:
            continue
        for a in axes:
            if a in given:
                out.append((f"grid.{a}", f"is given per cell by model.{name}; give it in one "
                            "place"))  # fmt: skip
    if m.cells is not None and "cells" in given:
        out.append(("grid.cells", "is also given as model.cells; give it in one place"))
    if "cells" in given and (m.gaps is not None or m.sigmas is not None):
        out.append(("grid.cells", "per-cell lists (model.gaps, model.sigmas) need one chain "
                    "length: give model.cells instead"))  # fmt: skip
    if out or study.max_cells() == 1:
        return out
    why = "chains of N > 1 cells"
    method = study.solver.method
    if method not in CHAIN_METHODS:
        out.append(("solver.method", f"{method!r} does not run {why} yet; give method: "
                    f"{' or '.join(CHAIN_METHODS)} (docs/chains.md)"))  # fmt: skip
    if study.physical is not None:
        out.append(("physical", f"{why} are non-dimensional studies (model.cells, grid.cells "
                    "with a model grid)"))  # fmt: skip
    if study.sweep is not None:
        out.append(("sweep", f"is not available for {why} yet"))
    if study.adaptive is not None:
        out.append(("adaptive", f"is not available for {why} yet"))
    if study.initial is not None and study.initial_labels() != ["rest"]:
        out.append(("initial", f"{why} start from rest (initial: rest)"))
    spp = study.solver.steps_per_period
    n = study.max_cells()
    if spp is not None and study.solver.max_periods * spp * n > MAX_STEPS_PER_POINT:
        out.append(("solver.steps_per_period", (
            f"max_periods × steps_per_period × cells must be <= {MAX_STEPS_PER_POINT:.0e} "
            f"(one point's step budget, a chain's steps counted per cell), got "
            f"{study.solver.max_periods} × {spp} × {n}")))  # fmt: skip
    limit = DEFAULT_MAX_POINTS if max_points is None else max_points
    cost = study.cell_points()
    if cost > limit:
        out.append(("grid", f"has {cost:,} cell-points (each point counts its N cells), more "
                    f"than the limit of {limit:,}"))  # fmt: skip
    return out


def _adaptive_problems(study: Study) -> list[tuple[str, str]]:
    """An adaptive study samples a range axis of a non-dimensional grid, point by point."""
    spec = study.adaptive
    assert spec is not None
    given = study.grid.given()
    out: list[tuple[str, str]] = []
    if study.is_physical:
        out.append(("adaptive", "adaptive sampling needs a non-dimensional grid (no physical "
                    "block); sample gamma_r instead of frequency_hz"))  # fmt: skip
        return out
    if study.sweep is not None:
        out.append(("adaptive", "a sweep's points start from each other in order along "
                    "the swept axis, an adaptive study samples out of order: give one of "
                    "them"))  # fmt: skip
    if study.initial is not None:
        out.append(("adaptive", "adaptive lines start from rest; drop initial (or run a grid "
                    "study for several initial states)"))  # fmt: skip
    axis = given.get(spec.axis)
    if axis is None:
        hint = f"grid.{spec.axis}: {{start: 0.2, stop: 6, num: 2}}"
        return [*out, ("adaptive.axis", f"{spec.axis!r} is not an axis of the grid; give it "
                       f"as a range, e.g. {hint}")]  # fmt: skip
    if not isinstance(axis, Range) or axis.num is None or axis.scale != "linear":
        return [*out, (f"grid.{spec.axis}", "the adaptive axis must be a range {start, stop, "
                       "num} (the interval searched and its starting samples)")]  # fmt: skip
    if axis.num < 2:
        out.append((f"grid.{spec.axis}.num", f"the adaptive axis needs num >= 2 starting "
                    f"samples, got {axis.num}"))  # fmt: skip
    if spec.max_points < axis.num:
        out.append(("adaptive.max_points", f"must be at least the starting samples "
                    f"(grid.{spec.axis}.num = {axis.num}), got {spec.max_points}"))  # fmt: skip
    span = float(axis.stop) - float(axis.start)
    if span <= 0:
        out.append((f"grid.{spec.axis}", f"the adaptive axis needs stop > start, got "
                    f"start={axis.start}, stop={axis.stop}"))  # fmt: skip
    elif spec.tol >= span:
        out.append(("adaptive.tol", f"must be below the axis's span ({span:g}), got {spec.tol}"))
    return out


def _sweep_problems(sweep: SweepSpec, grid: Grid) -> list[tuple[str, str]]:
    """A sweep's axis must be a varying axis of the grid."""
    sizes = {k: axis_size(v) for k, v in grid.given().items()}
    varying = [k for k, n in sizes.items() if n > 1]
    choices = (
        f"sweep along one of its varying axes: {', '.join(varying)}"
        if varying
        else "the grid has no varying axis to sweep along"
    )
    if sweep.axis not in sizes:
        return [("sweep.axis", f"{sweep.axis!r} is not an axis of the grid; {choices}")]
    if sizes[sweep.axis] < 2:
        return [("sweep.axis", f"{sweep.axis!r} has one value, so there is nothing to sweep; "
                 f"{choices}")]  # fmt: skip
    return []


def _presence_problems(given: set[str]) -> list[tuple[str, str]]:
    """Required axes of a non-dimensional study, from the keys alone."""
    out: list[tuple[str, str]] = []
    for k in ("gamma_r", "theta", "sigma", "gamma_s"):
        if k not in given:
            out.append((f"grid.{k}", "is required (a number, a list or a range)"))
    if "restitution" in given and ("e1" in given or "e2" in given):
        out.append(("grid.restitution", "give either restitution (both stops) or e1 and e2, "
                    "not both"))  # fmt: skip
    if "gap" in given and ("g1" in given or "g2" in given):
        out.append(("grid.gap", "give either gap (both stops) or g1 and g2, not both"))
    elif "gap" not in given and ("g1" in given) != ("g2" in given):
        missing = "g2" if "g1" in given else "g1"
        out.append((f"grid.{missing}", "is required with the other stop's gap"))
    elif "gap" not in given and "g1" not in given:
        out.append(("grid.gap", "is required (or g1 and g2)"))
    return out


#: The PhysicalCell fields that drive the base (exactly one of them, or of PER_FREQUENCY_FIELDS).
_EXCITATION_FIELDS = ("base_amplitude_m", "base_acceleration_m_s2")


def _grid_problems(
    grid: Grid,
    physical: PhysicalSpec | None,
    *,
    explicit_xi: bool,
    max_points: int | None,
    lead: Mapping[str, int] | None = None,
    supplied: set[str] | None = None,
) -> list[tuple[str, str]]:
    """Problems of the grid: its axes for the kind of study, the required ones (``supplied``:
    axes another block gives), the physical block, the point limit."""
    limit = DEFAULT_MAX_POINTS if max_points is None else max_points
    out: list[tuple[str, str]] = []
    given = grid.given()
    if physical is None:
        for k in given:
            if k not in MODEL_AXES:
                out.append(
                    (f"grid.{k}", "is a physical axis; give a physical: block or use "
                     f"one of {', '.join(MODEL_AXES)}")
                )  # fmt: skip
        out += _presence_problems(set(given) | (supplied or set()))
        if explicit_xi and "xi" in given:
            out.append(("grid.xi", "is also given as model.xi; give it in one place"))
    else:
        for k in given:
            if k not in PHYSICAL_AXES:
                out.append(
                    (f"grid.{k}", "is a non-dimensional axis; a physical study varies "
                     f"frequency_hz and the physical fields ({', '.join(PHYSICAL_FIELDS)})")
                )  # fmt: skip
        if "frequency_hz" not in given:
            out.append(("grid.frequency_hz", "is required in a physical study"))
        if explicit_xi:
            out.append(("model.xi", "a physical study takes physical.damping_ratio instead"))
        base = physical.cell_fields()
        for k in CELL_FIELDS:
            if k not in base and k not in given:
                out.append((f"physical.{k}", "is required (in physical: or as a grid axis)"))
        if not any(k in base or k in given for k in ("gap_m", "gap1_m")) or not any(
            k in base or k in given for k in ("gap_m", "gap2_m")
        ):
            out.append(("physical.gap_m", "is required (or gap1_m and gap2_m)"))
        per_frequency = [k for k in PER_FREQUENCY_FIELDS if getattr(physical, k) is not None]
        excitation = [k for k in _EXCITATION_FIELDS if k in base or k in given] + per_frequency
        if len(excitation) != 1:
            # The message lists the new per-frequency fields only to a study that uses one,
            # so that the long-standing message of a scalar study stays as it was.
            choices = "base_amplitude_m and base_acceleration_m_s2"
            if per_frequency:
                choices = "base_amplitude_m, base_acceleration_m_s2, " + ", ".join(
                    PER_FREQUENCY_FIELDS
                )
            out.append(
                ("physical.base_amplitude_m", f"give exactly one of {choices}, got "
                 f"{', '.join(excitation) or 'neither'}")
            )  # fmt: skip
        amplitudes: np.ndarray | None = None
        if len(excitation) == 1 and per_frequency and "frequency_hz" in given:
            amplitudes, found = _per_frequency_problems(physical, given, limit)
            out += found
        if not out:
            first = {k: _ends(v)[0] for k, v in given.items()}
            first.pop("frequency_hz", None)
            if amplitudes is not None:
                first["base_amplitude_m"] = float(amplitudes[0])
            try:
                PhysicalCell(**{**base, **first})
            except (TypeError, ValueError) as exc:
                out.append(("physical", str(exc)))
            else:
                out += _model_range_problems(base, given, amplitudes)
    # Sizes, not values: a grid of 10⁹ points is refused without building an axis.
    sizes = {k: axis_size(v) for k, v in given.items()}
    size = math.prod(sizes.values()) if given else 0
    if lead:  # initial states × directions × grid points: what the runner computes
        size *= math.prod(lead.values())
        sizes = {**lead, **sizes}
    if size > limit:
        axes = " × ".join(f"{k} {n:,}" for k, n in sizes.items() if n > 1)
        out.append(("grid", f"has {size:,} points, more than the limit of {limit:,} ({axes})"))
    return out


def _ends(axis: Any) -> tuple[float, float]:
    """An axis's smallest and largest values, without building it."""
    if isinstance(axis, Range):
        return (min(axis.start, axis.last), max(axis.start, axis.last))
    if isinstance(axis, list):
        return (float(min(axis)), float(max(axis)))
    return (float(axis), float(axis))


#: Relative tolerance of matching a table's frequencies to the grid's (grid coordinates keep
#: 12 significant digits; a table read from a file keeps what it wrote).
_FREQUENCY_RTOL = 1e-9


def _listed(values: Sequence[float], most: int = 5) -> str:
    shown = ", ".join(f"{v:g}" for v in values[:most])
    return shown + (f" and {len(values) - most} more" if len(values) > most else "")


def _aligned(freqs: np.ndarray, table: AmplitudeTable) -> tuple[np.ndarray | None, list[str]]:
    """A table's amplitudes in the order of the grid's frequencies ``freqs``, or None and
    what does not match: grid frequencies without a row, rows off the grid."""
    tf = np.asarray(table.frequency_hz, dtype=np.float64)
    ta = np.asarray(table.base_amplitude_m, dtype=np.float64)
    order = np.argsort(tf)
    sorted_f = tf[order]
    # Each grid frequency's nearest table frequency (the table's are distinct).
    pos = np.clip(np.searchsorted(sorted_f, freqs), 1, max(sorted_f.size - 1, 1))
    lo = np.clip(pos - 1, 0, sorted_f.size - 1)
    hi = np.clip(pos, 0, sorted_f.size - 1)
    near = np.where(np.abs(sorted_f[lo] - freqs) <= np.abs(sorted_f[hi] - freqs), lo, hi)
    hit = np.abs(sorted_f[near] - freqs) <= _FREQUENCY_RTOL * np.abs(freqs)
    problems = []
    if not np.all(hit):
        missing = freqs[~hit].tolist()
        problems.append(
            f"grid.frequency_hz has {_listed(missing)} Hz, which the table has no row for; "
            "the table must have one row for every frequency of the grid, and only those "
            f"(its {tf.size} rows span {tf.min():g} … {tf.max():g} Hz)"
        )
    used = np.zeros(tf.size, dtype=bool)
    used[order[near[hit]]] = True
    if not np.all(used):
        extra = np.flatnonzero(~used)
        rows = [f"frequency_hz[{i}] = {tf[i]:g}" for i in extra[:5]]
        more = f" and {extra.size - 5} more" if extra.size > 5 else ""
        problems.append(
            f"table rows {', '.join(rows)}{more} Hz are not on grid.frequency_hz; the table "
            "and the grid must have the same frequencies (add them to the grid or drop the rows)"
        )
    if problems:
        return None, problems
    return ta[order[near]], []


def _per_frequency_problems(
    physical: PhysicalSpec, given: dict[str, Any], limit: int
) -> tuple[np.ndarray | None, list[tuple[str, str]]]:
    """Per-frequency amplitudes against ``grid.frequency_hz``: one per frequency, or a table
    with the grid's frequencies. Returns the amplitudes in the axis's order when they fit."""
    axis = given["frequency_hz"]
    n = axis_size(axis)
    values = physical.base_amplitude_per_frequency_m
    if values is not None:
        if len(values) != n:
            return None, [(
                "physical.base_amplitude_per_frequency_m",
                f"has {len(values)} values, but grid.frequency_hz has {n:,}; give one "
                "amplitude per frequency, in the order of grid.frequency_hz",
            )]  # fmt: skip
        return np.asarray(values, dtype=np.float64), []
    table = physical.base_amplitude_table
    assert table is not None
    if n > limit:  # the point limit is reported below; do not build a huge axis to match it
        return None, []
    amps, problems = _aligned(axis_values(axis), table)
    source = f" (file {table.file})" if table.file else ""
    return amps, [("physical.base_amplitude_table", m + source) for m in problems]


#: The most varying physical axes whose corners (2**n) are checked before a study runs.
_MAX_CORNER_AXES = 12


def _model_range_problems(
    base: dict[str, Any], given: dict[str, Any], amplitudes: np.ndarray | None = None
) -> list[tuple[str, str]]:
    """The model parameters a physical grid maps to, checked against the model's ranges.

    Every model parameter is a product of powers of the physical fields (θ = ρbhL/m_o,
    σ = Eh²m_o/(12ρL⁴k), γ_r = 2πf/√(k/m_o), g̃ = gθ/U_g), so over a box of physical values
    it is largest and smallest at the box's corners: checking the corners checks every point.
    Amplitudes given per frequency are paired with their frequency, but no model parameter
    depends on both (γ_r on f alone, g̃ on U_g alone), so treating their ends as one more axis
    of the box gives the same extremes.
    """
    ends = {k: _ends(v) for k, v in given.items()}
    if amplitudes is not None:
        ends["base_amplitude_m"] = (float(amplitudes.min()), float(amplitudes.max()))
    varying = [k for k, (lo, hi) in ends.items() if lo != hi]
    if len(varying) > _MAX_CORNER_AXES:  # too many corners; points are checked as they run
        return []
    fixed = {k: lo for k, (lo, hi) in ends.items() if lo == hi}
    for corner in itertools.product(*(ends[k] for k in varying)):
        at = {**fixed, **dict(zip(varying, corner, strict=True))}
        fields = {**base, **at}
        f = fields.pop("frequency_hz")
        try:
            CellParams(**PhysicalCell(**fields).to_model(f))
        except ValueError as exc:
            where = ", ".join(f"{k}={v:g}" for k, v in at.items() if k in varying) or "every point"
            return [("physical", f"at {where} the model's {exc}")]
    return []


# --------------------------------------------------------------------------- errors, loading


class StudyError(ValueError):
    """Every problem with a study definition, each with its path in the file."""

    def __init__(self, problems: Sequence[tuple[str, str]], source: str = "study") -> None:
        self.problems = list(problems)
        lines = "\n".join(f"  {p}: {m}" if p else f"  {m}" for p, m in self.problems)
        n = len(self.problems)
        super().__init__(f"{source}: {n} problem{'s' if n != 1 else ''}\n{lines}")


def _path(loc: Sequence[Any]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in AXIS_TAGS:
            # Union tags (which shape of axis was tried) are not part of the file's path.
            continue
        else:
            out += f".{part}" if out else str(part)
    return out


def _message(err: Mapping[str, Any]) -> str:
    kind = err["type"]
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "missing":
        return "is required"
    msg = str(err["msg"])
    return msg.removeprefix("Value error, ")


def validation_problems(exc: ValidationError) -> list[tuple[str, str]]:
    """A pydantic error of a study-file block as (path in the block, message) pairs."""
    return [(_path(e["loc"]), _message(e)) for e in exc.errors()]


def parse_study(data: Any, *, max_points: int | None = None, source: str = "study") -> Study:
    """Validate a study definition (already parsed from YAML/JSON).

    ``max_points`` limits the grid size (default :data:`DEFAULT_MAX_POINTS`).

    Raises
    ------
    StudyError
        Listing every problem found, each with its path.
    """
    nul = nul_paths(data)
    if nul:  # never part of a name or value; databases refuse it
        raise StudyError([(p, "must not contain a NUL character") for p in nul], source)
    problems: list[tuple[str, str]] = []
    try:
        study = Study.model_validate(data)
    except ValidationError as exc:
        problems += validation_problems(exc)
        # Check the grid on its own too, so a bad key elsewhere does not hide grid problems.
        if isinstance(data, Mapping) and isinstance(data.get("grid"), Mapping):
            grid_ok = not any(p == "grid" or p.startswith("grid.") for p, _ in problems)
            if grid_ok:
                physical = None
                bad: set[str] = set()
                if isinstance(data.get("physical"), Mapping):
                    # The valid keys of the block (its bad ones are listed already), so that
                    # the presence rules of a physical study are still checked.
                    bad = {p.split(".")[1] for p, _ in problems if p.startswith("physical.")}
                    known = set(PhysicalSpec.model_fields) - bad
                    good = {k: v for k, v in data["physical"].items() if k in known}
                    try:
                        physical = PhysicalSpec.model_validate(good)
                    except ValidationError:
                        physical = PhysicalSpec.model_construct()
                try:
                    grid = Grid.model_validate(data["grid"])
                except ValidationError:
                    pass
                else:
                    explicit_xi = isinstance(data.get("model"), Mapping) and "xi" in data["model"]
                    seen = {p for p, _ in problems}
                    if bad & {*_EXCITATION_FIELDS, *PER_FREQUENCY_FIELDS}:
                        # a bad excitation field is not also "neither given"
                        seen.add("physical.base_amplitude_m")
                    problems += [
                        pr
                        for pr in _grid_problems(
                            grid, physical, explicit_xi=explicit_xi, max_points=max_points
                        )
                        # a field already reported is not reported again ("physical": the
                        # cell could not be built, which its bad fields already say)
                        if pr[0] not in seen and not (pr[0] == "physical" and bad)
                    ]
                    sweep = data.get("sweep")
                    if isinstance(sweep, Mapping) and not any(
                        p == "sweep" or p.startswith("sweep.") for p, _ in problems
                    ):
                        problems += _sweep_problems(SweepSpec.model_validate(sweep), grid)
            elif "physical" not in data:
                problems += _presence_problems(set(data["grid"]))
        raise StudyError(problems, source) from None
    problems = study.problems(max_points)
    if problems:
        raise StudyError(problems, source)
    return study


def study_from_canonical(data: Any, *, source: str = "canonical definition") -> Study:
    """A study from its canonical definition (:meth:`Study.canonical`, as the catalogue and
    results files store it), checked against the model but not by the rules for user input.

    :func:`parse_study` can refuse a canonical definition: it has every default filled in, so
    ``model.xi`` reads as given twice when ``xi`` is a grid axis, or as given in a physical
    study. The id is that of the study the definition was made from.

    Raises
    ------
    StudyError
        The definition does not fit the model (e.g. it was written by another version).
    """
    try:
        return Study.model_validate(data)
    except ValidationError as exc:
        raise StudyError(validation_problems(exc), source) from None


def load_study(path: str | os.PathLike[str], *, max_points: int | None = None) -> Study:
    """Read and validate a study file (``.yaml``, ``.yml`` or ``.json``)."""
    source = str(Path(path))
    data = read_study_file(path)
    if not isinstance(data, Mapping):
        raise StudyError([("", "a study file must be a mapping of keys to values")], source)
    return parse_study(data, max_points=max_points, source=source)
