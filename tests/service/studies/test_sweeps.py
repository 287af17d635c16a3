"""Sweeps and initial states (issue 15): schema, work order, runner, datasets, ``responses``.

Work order is the runner's flat index (chunk files): every sweep line is contiguous there,
and assembling a dataset maps it onto the results' dimensions (``initial``, ``direction``,
then the grid's). These tests pin that mapping, that a sweep run equals ``simulate_line``
called line by line, and that a study without ``sweep``/``initial`` is what it always was.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr

from service.studies.chunks import StudyStore
from service.studies.coexistence import count_responses
from service.studies.dataset import open_results, results_from_records
from service.studies.runner import run_study
from service.studies.schema import StudyError, parse_study, study_from_canonical
from service.studies.variables import OUTCOMES, outcome_names
from tests.service.helpers import FAST_SOLVER, comparable
from worker.simulate import simulate_line

GRID = {
    "gamma_r": {"start": 0.5, "stop": 2.5, "num": 5},
    "gap": [0.05, 0.3],
    "theta": 0.3,
    "sigma": 0.05,
    "gamma_s": 1.0,
}
SOLVER = {**FAST_SOLVER, "steps_per_period": 256, "max_periods": 60}
SI = {"length_m": 0.15, "width_m": 0.01, "thickness_m": 0.0025, "density_kg_m3": 1250.0,
      "youngs_modulus_pa": 4.583e7, "outer_mass_kg": 0.01667, "spring_n_m": 350.0,
      "gap_m": 0.001}  # fmt: skip


def _def(name: str = "sweep", grid: dict[str, Any] | None = None, **extra: Any) -> dict[str, Any]:
    return {"name": name, "model": {"modes": 2}, "solver": SOLVER, "grid": grid or GRID, **extra}


def _study(**extra: Any) -> Any:
    return parse_study(_def(**extra))


def _problems(d: dict[str, Any], **kw: Any) -> dict[str, str]:
    with pytest.raises(StudyError) as info:
        parse_study(d, **kw)
    return dict(info.value.problems)


# --------------------------------------------------------------------------- schema


def test_without_sweep_or_initial_the_study_is_what_it_was() -> None:
    plain = _study()
    assert "sweep" not in plain.canonical() and "initial" not in plain.canonical()
    assert "coexistence_tol_db" not in plain.canonical()["outputs"]
    assert not plain.is_extended
    assert plain.size == plain.grid_size == 10 and plain.shape == plain.grid_shape == (2, 5)
    assert list(plain.result_dims()) == list(plain.dims()) == ["gap", "gamma_r"]
    assert np.array_equal(plain.result_index(0, plain.size), np.arange(plain.size))
    assert all("initial" not in p for p in plain.points(0, plain.size))
    assert plain.points(0, plain.size) == plain.points(0, plain.size, grid=True)
    # Every addition changes the id; the same definition read back keeps it.
    ids = {plain.id}
    for extra in ({"sweep": {"axis": "gamma_r"}}, {"initial": "rest"}, {"initial": "linear"},
                  {"outputs": {"coexistence_tol_db": 0.1}}):  # fmt: skip
        s = _study(**extra)
        assert study_from_canonical(s.canonical()).id == s.id
        ids.add(s.id)
    assert len(ids) == 5


def test_sweep_directions_default_to_up_and_down() -> None:
    s = _study(sweep={"axis": "gap"})
    assert s.canonical()["sweep"] == {"axis": "gap", "directions": ["up", "down"]}
    assert s.directions() == ["up", "down"] and s.line_length == 2
    assert s.size == 2 * 10 and s.shape == (2, 2, 5)
    assert list(s.result_dims()) == ["direction", "gap", "gamma_r"]


@pytest.mark.parametrize(
    ("extra", "path", "fragment"),
    [
        ({"sweep": {"axis": "theta"}}, "sweep.axis", "'theta' has one value"),
        ({"sweep": {"axis": "xi"}}, "sweep.axis", "one of its varying axes: gap, gamma_r"),
        ({"sweep": {"axis": "gamma_r", "directions": ["up", "up"]}}, "sweep.directions",
         "distinct"),
        ({"sweep": {"axis": "gamma_r", "directions": []}}, "sweep.directions", "at least 1"),
        ({"sweep": {"axis": "gamma_r", "directions": ["left"]}}, "sweep.directions[0]",
         "'up' or 'down'"),
        ({"sweep": {"axis": "gamma_r", "speed": 1}}, "sweep.speed", "unknown key"),
        ({"sweep": {"directions": ["up"]}}, "sweep.axis", "is required"),
        ({"initial": "hot"}, "initial", "unknown initial state 'hot'"),
        ({"initial": ["rest", "random-0"]}, "initial", "cannot be mixed"),
        ({"initial": ["rest", {"random": 2}]}, "initial", "cannot be mixed"),
        ({"initial": ["rest", "rest"]}, "initial", "distinct"),
        ({"initial": []}, "initial", "must not be empty"),
        ({"initial": {"random": 65}}, "initial", "random must be an integer in 1…64, got 65"),
        ({"initial": {"random": 0, "seed": 1}}, "initial", "1…64"),
        ({"initial": {"random": 2, "seed": -1}}, "initial", "seed must be an integer"),
        ({"initial": {"random": 2, "sed": 1}}, "initial", "sed: unknown key"),
        ({"initial": 3}, "initial", "give rest, linear"),
        ({"outputs": {"coexistence_tol_db": 0}}, "outputs.coexistence_tol_db", "greater than 0"),
    ],
)  # fmt: skip
def test_schema_errors_name_the_field(extra: dict[str, Any], path: str, fragment: str) -> None:
    problems = _problems(_def(**extra))
    assert path in problems, problems
    assert fragment in problems[path]


def test_sweep_problems_are_reported_with_other_problems() -> None:
    d = _def(sweep={"axis": "theta"})
    d["model"] = {"modes": 2, "bogus": 1}
    problems = _problems(d)
    assert set(problems) == {"model.bogus", "sweep.axis"}


def test_point_limit_counts_initial_states_and_directions() -> None:
    d = _def(sweep={"axis": "gamma_r"}, initial=["rest", "linear"])  # 2 × 2 × 10 = 40 points
    assert parse_study(d, max_points=40).size == 40
    problems = _problems(d, max_points=39)
    assert problems["grid"] == (
        "has 40 points, more than the limit of 39 (initial 2 × direction 2 × gap 2 × gamma_r 5)"
    )
    # Random states count too, without a sweep; the plain grid fits.
    r = _def(initial={"random": 64, "seed": 3})
    assert "initial 64" in _problems(r, max_points=639)["grid"]
    assert parse_study(r, max_points=640).size == 640
    assert parse_study(_def(), max_points=10).size == 10


# --------------------------------------------------------------------------- work order

WORK_CASES = [
    {"sweep": {"axis": "gamma_r"}},
    {"sweep": {"axis": "gap", "directions": ["down"]}},
    {"sweep": {"axis": "gamma_r", "directions": ["down", "up"]}, "initial": ["linear", "rest"]},
    {"sweep": {"axis": "theta"}, "initial": {"random": 3, "seed": 1},
     "grid": {**GRID, "theta": [0.5, 0.1, 0.3]}},  # an unsorted list: up is by value
    {"initial": ["rest", "linear"]},
    {"initial": "linear"},
]  # fmt: skip


@pytest.mark.parametrize("extra", WORK_CASES)
def test_work_order_is_a_bijection_with_contiguous_lines(extra: dict[str, Any]) -> None:
    s = _study(**extra)
    where = s.result_index(0, s.size)
    assert np.array_equal(np.sort(where), np.arange(s.size)), "not a bijection"
    assert s.size == int(np.prod(s.shape))
    # Pieces agree with the whole (chunks are computed piece by piece).
    i, d, idx = s.work_indices(0, s.size)
    for a, b in [(0, 3), (3, min(11, s.size)), (7, s.size)]:
        ia, da, ixa = s.work_indices(a, b)
        assert np.array_equal(ia, i[a:b]) and np.array_equal(da, d[a:b])
        assert all(np.array_equal(ixa[k], idx[k][a:b]) for k in idx)
        assert np.array_equal(s.result_index(a, b), where[a:b])
    labels = s.initial_labels()
    points = s.points(0, s.size)
    if s.initial is not None:
        assert [p["initial"]["index"] for p in points] == i.tolist()
        kinds = {p["initial"]["kind"] for p in points}
        assert kinds == {lab.split("-")[0] for lab in labels}
    if s.sweep is None:  # initial-major, then the grid's C order: the results' own order
        assert np.array_equal(where, np.arange(s.size))
        return
    axis, n = s.sweep.axis, s.line_length
    values = s.axes()[axis]
    coords = s.coords_at(0, s.size)
    for start in range(0, s.size, n):
        line = slice(start, start + n)
        assert len(set(i[line])) == len(set(d[line])) == 1
        for k in idx:
            if k != axis:
                assert len(set(idx[k][line])) == 1, k
        along = coords[axis][line]
        direction = s.directions()[d[start]]
        want = np.sort(values) if direction == "up" else np.sort(values)[::-1]
        assert np.array_equal(along, want), (direction, along)
        # The results' index of the line's points runs along the swept dimension.
        steps = np.diff(where[line])
        assert np.all(np.abs(steps) == abs(steps[0])) or axis == "theta"


def test_down_lines_are_the_up_lines_reversed() -> None:
    s = _study(sweep={"axis": "gamma_r"})
    n = s.line_length
    up, down = s.points(0, n), s.points(s.size // 2, s.size // 2 + n)
    assert [p["gamma_r"] for p in down] == [p["gamma_r"] for p in up][::-1]
    assert [p["gamma_r"] for p in up] == sorted(p["gamma_r"] for p in up)


# --------------------------------------------------------------------------- runs


def _line_reference(study: Any) -> dict[str, np.ndarray]:
    """Every line through ``simulate_line`` directly, placed at its results' index."""
    solver = study.solver.settings().__dict__
    n = study.line_length
    out: dict[str, np.ndarray] = {}
    where = study.result_index(0, study.size)
    for start in range(0, study.size, n):
        recs = simulate_line(study.points(start, start + n), solver)
        assert len(recs) == n
        for k in ("transmittance_db", "outcome", "started_from", "response_period"):
            col = out.setdefault(k, np.empty(study.size, dtype=object))
            col[where[start : start + n]] = [r[k] for r in recs]
    return out


def test_serial_sweep_equals_simulate_line_per_line(tmp_path: Path) -> None:
    study = _study(sweep={"axis": "gamma_r"}, initial=["rest", "linear"])
    s = run_study(study, tmp_path, serial=True)
    assert s.points == s.computed == study.size == 40 and s.chunk_size == study.line_length
    ds = open_results(s.path)
    assert tuple(ds["outcome"].dims) == ("initial", "direction", "gap", "gamma_r")
    assert list(ds["initial"].values) == ["rest", "linear"]
    assert list(ds["direction"].values) == ["up", "down"]
    ref = _line_reference(study)
    shape = study.shape
    got = ds["transmittance_db"].values
    want = np.array([np.nan if v is None else v for v in ref["transmittance_db"]], dtype=float)
    np.testing.assert_array_equal(got, want.reshape(shape))
    assert (outcome_names(ds["outcome"]) == ref["outcome"].astype(str).reshape(shape)).all()
    assert (ds["started_from"].values == ref["started_from"].astype(str).reshape(shape)).all()
    # Up lines start at the smallest γ_r, down lines at the largest; the rest carry the state.
    sf = ds["started_from"]
    assert (sf.sel(direction="up").isel(gamma_r=0) == "initial").all()
    assert (sf.sel(direction="down").isel(gamma_r=-1) == "initial").all()
    assert int((sf == "previous").sum()) == study.size - 2 * 2 * 2
    assert ds.attrs["sweep_axis"] == "gamma_r" and ds.attrs["initial_states"] == "rest linear"
    # responses: over the grid only, between 1 and the computations a grid point had.
    r = ds["responses"]
    assert r.dims == ("gap", "gamma_r") and r.dtype.kind == "i"
    assert ((r >= 1) & (r <= 4)).all()
    assert r.attrs["coexistence_tol_db"] == ds.attrs["coexistence_tol_db"] == 0.05
    np.testing.assert_array_equal(r.values, count_responses(ds, 0.05).values)


def test_rest_slice_equals_the_study_without_initial(tmp_path: Path) -> None:
    both = _study(initial=["linear", "rest"])
    plain = _study()
    a = open_results(run_study(both, tmp_path / "a", serial=True).path)
    b = open_results(run_study(plain, tmp_path / "b", serial=True).path)
    assert a["outcome"].dims == ("initial", "gap", "gamma_r") and "started_from" not in a
    assert "responses" in a and "responses" not in b and "initial" not in b.coords
    rest = a.sel(initial="rest").drop_vars(["initial", "responses"])
    xr.testing.assert_equal(rest.drop_vars("wall_s"), b.drop_vars("wall_s"))
    # One explicit initial state: a scalar coordinate, no dimension, no responses.
    one = open_results(run_study(_study(initial="rest"), tmp_path / "c", serial=True).path)
    assert one["initial"].ndim == 0 and str(one["initial"].values) == "rest"
    assert "responses" not in one
    xr.testing.assert_equal(one.drop_vars(["initial", "wall_s"]), b.drop_vars("wall_s"))


def test_a_sweep_started_from_rest_slice_equals_the_sweep_without_initial(
    tmp_path: Path,
) -> None:
    with_initial = _study(sweep={"axis": "gap", "directions": ["down"]}, initial=["rest", "linear"])
    plain = _study(sweep={"axis": "gap", "directions": ["down"]})
    a = open_results(run_study(with_initial, tmp_path / "a", serial=True).path)
    b = open_results(run_study(plain, tmp_path / "b", serial=True).path)
    assert b["outcome"].dims == ("direction", "gap", "gamma_r") and b.sizes["direction"] == 1
    rest = a.sel(initial="rest").drop_vars(["initial", "responses"])
    xr.testing.assert_equal(rest.drop_vars("wall_s"), b.drop_vars(["wall_s", "responses"]))


class _CancelMidLine:
    """A cancel callback that turns true a few polls into the line after ``lines`` lines
    were stored (``on_chunk``): the run stops inside a line."""

    def __init__(self, lines: int, polls: int = 3) -> None:
        self.lines, self.polls, self.stored = lines, polls, 0

    def on_chunk(self, start: int, stop: int, records: list[dict[str, Any]]) -> None:
        self.stored += 1

    def __call__(self) -> bool:
        if self.stored >= self.lines:
            self.polls -= 1
        return self.polls < 0


@pytest.mark.slow  # runs whole (small) studies
def test_resume_after_cancel_equals_an_uninterrupted_run(tmp_path: Path) -> None:
    study = _study(sweep={"axis": "gamma_r"}, initial=["rest", "linear"])
    n = study.line_length
    cancel = _CancelMidLine(3)
    first = run_study(study, tmp_path / "r", serial=True, cancel=cancel, on_chunk=cancel.on_chunk)
    assert first.cancelled and first.computed == 3 * n  # the fourth line was cut short
    store = StudyStore(tmp_path / "r", study)
    chunks = store.chunks()
    assert chunks and all(a % n == 0 and b - a == n for a, b, _ in chunks)  # whole lines
    # The partial dataset of an interrupted sweep: pending where no line has finished.
    cols, filled = store.collect_partial()
    part = results_from_records(study, cols, computed=filled)
    assert int(part["pending"].sum()) == study.size - first.computed
    assert part.attrs["points_done"] == first.computed
    assert (part["started_from"].where(part["pending"], "") == "").all()
    rest = run_study(study, tmp_path / "r", serial=True)
    assert rest.computed == study.size - first.computed
    whole = run_study(study, tmp_path / "w", serial=True)
    a, b = open_results(rest.path), open_results(whole.path)
    xr.testing.assert_identical(comparable(a), comparable(b))
    done = part.where(~part["pending"])
    np.testing.assert_array_equal(
        done["transmittance_db"].values, b["transmittance_db"].where(~part["pending"]).values
    )


def test_physical_frequency_sweep(tmp_path: Path) -> None:
    d = {
        "name": "table1-sweep",
        "model": {"modes": 2},
        "solver": SOLVER,
        "physical": {**SI, "damping_ratio": 0.03,
                     "base_amplitude_per_frequency_m": [2.0e-3, 1.0e-3, 4.0e-4]},
        "grid": {"damping_ratio": [0.01, 0.05], "frequency_hz": [12.0, 23.0, 42.0]},
        "sweep": {"axis": "frequency_hz"},
    }  # fmt: skip
    study = parse_study(d)
    assert study.size == 12 and study.line_length == 3
    up = study.points(0, 3)
    assert [p["gamma_r"] for p in up] == sorted(p["gamma_r"] for p in up)
    ds = open_results(run_study(study, tmp_path, serial=True).path)
    assert ds["outcome"].dims == ("direction", "damping_ratio", "frequency_hz")
    # Model parameters and metres are the grid's, whatever the direction.
    assert ds["gamma_r"].dims == ("frequency_hz",)
    scale = (ds["amplitude_m"] / ds["amplitude"]).values
    np.testing.assert_allclose(scale[0], scale[1])
    ref = _line_reference(study)
    want = np.array([np.nan if v is None else v for v in ref["transmittance_db"]], dtype=float)
    np.testing.assert_array_equal(ds["transmittance_db"].values, want.reshape(study.shape))
    sf = ds["started_from"]
    assert (sf.sel(direction="down", frequency_hz=42.0) == "initial").all()
    assert (sf.sel(direction="up", frequency_hz=42.0) == "previous").all()


@pytest.mark.slow
def test_cluster_sweep_cancel_and_resume_equals_serial(tmp_path: Path) -> None:
    from dask.distributed import Client, LocalCluster

    study = _study(sweep={"axis": "gamma_r"}, initial={"random": 2, "seed": 5},
                   solver={**SOLVER, "steps_per_period": 1024, "max_periods": 150})  # fmt: skip
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=40)  # fmt: skip
    client = Client(cluster)
    try:
        stored: list[tuple[int, int]] = []
        first = run_study(study, tmp_path / "d", client=client, chunk_size=1,
                          on_chunk=lambda a, b, r: stored.append((a, b)),
                          cancel=lambda: bool(stored))  # fmt: skip
        assert first.cancelled and stored
        n = study.line_length
        chunks = StudyStore(tmp_path / "d", study).chunks()
        assert all(a % n == 0 and b - a == n for a, b, _ in chunks)
        dist = run_study(study, tmp_path / "d", client=client, chunk_size=1)
        assert dist.computed == study.size - first.computed and dist.chunk_size == n
    finally:
        client.close()
        cluster.close()
    serial = run_study(study, tmp_path / "s", serial=True)
    xr.testing.assert_identical(
        comparable(open_results(dist.path)), comparable(open_results(serial.path))
    )


# --------------------------------------------------------------------------- responses


def _synthetic(rows: list[list[tuple[str, float, float, float]]]) -> xr.Dataset:
    """A dataset of grid points ``x`` × computations (``direction`` × ``initial``): each
    computation is (outcome, Γ, period, se)."""
    n, m = len(rows), len(rows[0])
    shape = (2, m // 2, n)  # (initial, direction, x)

    def col(k: int) -> np.ndarray:
        a = np.array([[c[k] for c in row] for row in rows], dtype=object).T  # (m, n)
        return a.reshape(shape)

    codes = np.vectorize(OUTCOMES.index)(col(0)).astype(np.int8)
    dims = ("initial", "direction", "x")
    return xr.Dataset(
        {
            "outcome": (dims, codes),
            "transmittance_db": (dims, col(1).astype(float)),
            "response_period": (dims, col(2).astype(float)),
            "transmittance_db_se": (dims, col(3).astype(float)),
            "failed": (dims, codes == OUTCOMES.index("failed")),
        },
        coords={"x": np.arange(n, dtype=float), "initial": ["rest", "linear"],
                "direction": ["up", "down"][: m // 2]},
    )  # fmt: skip


NAN = float("nan")
P = ("periodic", -10.0, 1.0, NAN)


def test_responses_counts_distinct_responses() -> None:
    def per(g: float, p: float = 1.0) -> tuple[str, float, float, float]:
        return ("periodic", g, p, NAN)

    def irr(g: float, se: float) -> tuple[str, float, float, float]:
        return ("irregular", g, 0.0, se)

    rows = [
        [P, P, P, P],  # one response four times
        [per(-10), per(-10.04), per(-10.08), per(-10.12)],  # a chain of steps within 0.05: one
        [per(-10), per(-10.1), per(-10), per(-10.1)],  # 0.1 dB apart: two
        [per(-10), per(-10, 2.0), per(-10), per(-10)],  # another period: two
        [per(-10), irr(-10, 0.1), per(-10), irr(-10.2, 0.1)],  # irregular ≠ periodic; 0.2 < 3·0.14
        [irr(-10, 0.1), irr(-11, 0.1), irr(-10, 0.1), irr(-10, 0.1)],  # 1 dB: two
        [("linear", -3.0, 1.0, NAN), per(-3.0), P, P],  # linear ≠ periodic at the same Γ
        [("failed", NAN, NAN, NAN), ("unsettled", -5.0, 0.0, 0.3), P, P],  # not counted
        [("failed", NAN, NAN, NAN)] * 4,  # nothing found
    ]
    ds = _synthetic(rows)
    r = count_responses(ds, 0.05)
    assert r.dims == ("x",) and r.name == "responses" and r.attrs["coexistence_tol_db"] == 0.05
    assert r.values.tolist() == [1, 1, 2, 2, 2, 2, 3, 1, 0]
    # A wider tolerance merges the periodic ones 0.1 dB apart.
    assert count_responses(ds, 0.2).values.tolist()[:3] == [1, 1, 1]
    # The order of the computations does not matter.
    flipped = ds.isel(initial=[1, 0], direction=[1, 0])
    assert count_responses(flipped, 0.05).values.tolist() == r.values.tolist()
    with pytest.raises(ValueError, match="tol_db"):
        count_responses(ds, 0.0)
    with pytest.raises(ValueError, match="outcome"):
        count_responses(ds.drop_vars("outcome"), 0.05)


def test_responses_uses_the_study_tolerance(tmp_path: Path) -> None:
    study = _study(initial=["rest", "linear"], outputs={"coexistence_tol_db": 0.5})
    cols = {}
    from service.studies.chunks import record_columns

    recs = []
    for p in study.points(0, study.size):
        recs.append({"outcome": "periodic", "transmittance_db": -10.0 - 0.3 * p["initial"]["index"],
                     "response_period": 1, "failed": False, "wall_s": 0.0, "periods": 1,
                     "steps": 1})  # fmt: skip
    cols = record_columns(recs)
    ds = results_from_records(study, cols)
    assert ds.attrs["coexistence_tol_db"] == 0.5 and (ds["responses"] == 1).all()
    strict = study.model_copy(update={"outputs": study.outputs.model_copy(
        update={"coexistence_tol_db": 0.1})})  # fmt: skip
    assert (results_from_records(strict, cols)["responses"] == 2).all()
    assert json.loads(ds.attrs["study"])["outputs"]["coexistence_tol_db"] == 0.5
