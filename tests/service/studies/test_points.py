"""The point store (issue 16): point identity, reuse across studies, crash safety, queries,
housekeeping and solver versions, on a real catalogue database (SQLite; PostgreSQL in CI)."""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr

from service.api.catalogue import Catalogue
from service.api.points import PointQuery, SqlPointStore, points_csv, points_dataset
from service.studies import points as pts
from service.studies.points import point_key, study_keys
from service.studies.runner import run_study
from service.studies.schema import Study
from tests.service.helpers import FAST_SOLVER, tiny_study
from worker.simulate import SOLVER_VERSION, PointLimits, SolverSettings
from worker.solvers.settings import TRANSIENT_NOTE, PointResult


def study(definition: dict[str, Any]) -> Study:
    return Study.model_validate(definition)


@pytest.fixture
def store(catalogue_url: str) -> Any:
    cat = Catalogue(catalogue_url)
    yield SqlPointStore(cat.engine), cat
    cat.close()


def run(defn: dict[str, Any], root: Path, store: SqlPointStore, **kw: Any) -> Any:
    return run_study(study(defn), root, serial=True, points=store, **kw)


def gamma(defn: dict[str, Any]) -> dict[str, Any]:
    return defn["grid"]["gamma_r"]


# --------------------------------------------------------------------------- identity


def test_the_key_is_what_determines_the_point() -> None:
    a = study(tiny_study("a", num=4))
    renamed = tiny_study("renamed", num=4)
    renamed["description"] = "a new description changes the study id, not its points"
    b = study(renamed)
    assert a.id != b.id
    assert study_keys(a) == study_keys(b)
    assert len(set(study_keys(a))) == a.size  # every point its own key
    # defaults written out are the same point
    explicit = tiny_study("a", num=4)
    explicit["model"] = {"modes": 5, "coupling": "paper"}
    assert study_keys(study(explicit)) == study_keys(a)
    # what changes the numbers changes the key
    other_solver = study(tiny_study("a", num=4, max_periods=61))
    assert not set(study_keys(other_solver)) & set(study_keys(a))
    p = a.points(0, 1)[0]
    solver = pts.solver_document(a.solver.settings().__dict__)
    base = point_key(p, solver)
    assert point_key({**p, "theta": p["theta"] * (1 + 1e-12)}, solver) != base
    assert point_key({**p, "initial": {"kind": "linear"}}, solver) != base
    assert point_key(p, solver, after="0" * 32) != base
    assert point_key(p, solver, version=SOLVER_VERSION + "x") != base
    assert point_key(p, solver) == base and len(base) == pts.KEY_LENGTH


@pytest.mark.parametrize(
    ("name", "value"), [("max_events_per_period", 5000), ("transient_guard", 40)]
)
def test_a_setting_added_later_keeps_the_keys_stored_before_it(name: str, value: int) -> None:
    # max_events_per_period and transient_guard came after the store's first points: at their
    # default (None) they are left out of the hashed document, so the keys of every earlier
    # study stay valid; given, each is a setting like any other.
    a = study(tiny_study("a", num=4))
    doc = pts.solver_document(a.solver.settings().__dict__)
    assert name not in doc and "steps_per_period" in doc
    assert set(doc) == {f.name for f in dataclasses.fields(SolverSettings)} - {
        "max_events_per_period",
        "transient_guard",
    }
    given = tiny_study("a", num=4)
    given["solver"][name] = value
    b = study(given)
    assert b.id != a.id
    assert pts.solver_document(b.solver.settings().__dict__)[name] == value
    assert not set(study_keys(b)) & set(study_keys(a))


@pytest.mark.slow  # runs whole (small) studies
def test_a_studys_event_budget_reaches_its_points(tmp_path: Path) -> None:
    # One event a period: every point of this study impacts, so every point fails with the
    # budget it was given; without the setting none fails.
    defn = tiny_study("budget", num=3, gaps=(0.1,), max_events_per_period=1)
    summary = run_study(study(defn), tmp_path / "small", serial=True)
    with xr.open_dataset(summary.path) as ds:
        reasons = [str(r) for r in ds.reason.values.ravel()]
    assert summary.failed == len(reasons) == 3
    assert all(r.startswith("event budget exceeded: more than 1 events") for r in reasons)
    assert run_study(study(tiny_study("budget", num=3, gaps=(0.1,))), tmp_path / "default",
                     serial=True).failed == 0  # fmt: skip


def test_sweep_points_are_chained_to_their_line() -> None:
    grid = tiny_study("s", num=4)
    grid["sweep"] = {"axis": "gamma_r", "directions": ["up"]}
    sweep = study(grid)
    plain = study(tiny_study("s", num=4))
    ks = study_keys(sweep)
    assert len(set(ks)) == sweep.size
    n = sweep.line_length
    # the first point of each line starts where a grid point does; the others after their
    # predecessor, so they are other points
    firsts = {ks[i] for i in range(0, len(ks), n)}
    assert firsts <= set(study_keys(plain))
    assert not (set(ks) - firsts) & set(study_keys(plain))
    with pytest.raises(ValueError, match="line's first point"):
        study_keys(sweep, 1, 2)


def test_a_run_keys_its_points_once_and_as_they_are(store: Any, tmp_path: Path) -> None:
    # The keys made at the start (what the store knows) are the ones its chunks go out with.
    from service.studies.runner import StudyRun

    point_store, _ = store
    for sweep in (None, {"axis": "gamma_r", "directions": ["up", "down"]}):
        grid = tiny_study("k", num=6)
        if sweep:
            grid["sweep"] = sweep
        s = study(grid)
        r = StudyRun(s, tmp_path / f"kept-{bool(sweep)}", points=point_store)
        assert sorted(r._kept_keys) == list(range(s.size))  # nothing known: all to compute
        n = s.line_length if sweep else 1
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr("service.studies.runner.study_keys", _no_keys_made)
            got = [r.keys(a, min(a + 2 * n, s.size)) for a in range(0, s.size, 2 * n)]
        assert got == [
            pts.study_keys(s, a, min(a + 2 * n, s.size), solver=r._solver_doc)
            for a in range(0, s.size, 2 * n)
        ]


def _no_keys_made(*_: Any, **__: Any) -> list[str]:
    raise AssertionError("keys made again")


def test_only_the_points_own_results_are_storable() -> None:
    assert pts.is_storable({"failed": False, "reason": ""})
    assert pts.is_storable({"failed": True, "reason": "diverged: |x| grew beyond ..."})
    assert not pts.is_storable({"failed": True, "reason": "time limit of 1 s per point ..."})
    assert not pts.is_storable({"failed": True, "reason": "step budget of 10 steps per ..."})
    assert not pts.is_storable({"failed": True, "reason": "task failed after 2 retries: X"})


# --------------------------------------------------------------------------- reuse


def _values(path: Path) -> dict[str, np.ndarray]:
    with xr.open_dataset(path) as ds:
        return {
            k: ds[k].values.copy()
            for k in ("transmittance_db", "outcome", "amplitude", "periods")
            if k in ds
        }


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.mark.slow  # runs whole (small) studies
def test_renamed_extended_and_rerun_studies_compute_only_new_points(
    store: Any, tmp_path: Path
) -> None:
    st, _ = store
    first = tiny_study("first", num=6)
    s1 = run(first, tmp_path, st)
    assert (s1.computed, s1.reused) == (12, 0)
    assert st.count() == 12

    renamed = copy.deepcopy(first)
    renamed["name"] = "renamed"
    s2 = run(renamed, tmp_path, st)
    assert (s2.computed, s2.reused, s2.cached) == (0, 12, False)
    _same(_values(s1.path), _values(s2.path))

    wider = copy.deepcopy(first)
    wider["name"] = "one more gap"
    wider["grid"]["gap"] = [0.1, 0.5, 0.3]
    s3 = run(wider, tmp_path, st)
    assert (s3.computed, s3.reused) == (6, 12)
    assert st.count() == 18
    with xr.open_dataset(s3.path) as ds, xr.open_dataset(s1.path) as ref:
        np.testing.assert_array_equal(
            ds.transmittance_db.sel(gap=[0.1, 0.5]).values, ref.transmittance_db.values
        )

    again = run(first, tmp_path, st)  # the results file exists: nothing to do at all
    assert (again.computed, again.reused, again.cached) == (0, 12, True)

    tagged = copy.deepcopy(first)
    tagged["tag"] = "fresh-run"  # a tag is a fresh run: computes every point itself
    s4 = run(tagged, tmp_path, st)
    assert (s4.computed, s4.reused) == (12, 0)
    _same(_values(s1.path), _values(s4.path))  # and finds the same numbers


@pytest.mark.slow  # runs whole (small) studies
def test_a_sweep_reuses_whole_lines_only(store: Any, tmp_path: Path) -> None:
    st, _ = store
    defn = tiny_study("sweep", num=5, gaps=(0.1,))
    defn["sweep"] = {"axis": "gamma_r", "directions": ["up"]}
    s1 = run(defn, tmp_path, st)
    assert s1.computed == 5
    renamed = {**copy.deepcopy(defn), "name": "sweep again"}
    s2 = run(renamed, tmp_path, st)
    assert (s2.computed, s2.reused) == (0, 5)
    _same(_values(s1.path), _values(s2.path))
    # a longer line: its later points start from states that were never stored, so the
    # whole line is computed again (the shared prefix gives the same numbers)
    longer = copy.deepcopy(defn)
    longer["name"] = "longer"
    gamma(longer).update(stop=3.0 + 2.5 / 4, num=6)
    s3 = run(longer, tmp_path, st)
    assert (s3.computed, s3.reused) == (6, 0)
    with xr.open_dataset(s3.path) as ds, xr.open_dataset(s1.path) as ref:
        np.testing.assert_array_equal(
            ds.transmittance_db.values.ravel()[:5], ref.transmittance_db.values.ravel()
        )


@pytest.mark.slow  # runs whole (small) studies
def test_budget_failures_are_not_stored(store: Any, tmp_path: Path) -> None:
    st, _ = store
    defn = tiny_study("budget", num=3, gaps=(0.1,))
    s1 = run(defn, tmp_path, st, limits=PointLimits(steps=5))
    assert s1.failed == 3 and st.count() == 0
    s2 = run({**defn, "name": "budget again"}, tmp_path, st)
    assert (s2.computed, s2.failed) == (3, 0)
    assert st.count() == 3


@pytest.mark.slow  # runs whole (small) studies
def test_a_killed_run_keeps_its_finished_chunks_in_the_store(store: Any, tmp_path: Path) -> None:
    st, _ = store
    defn = tiny_study("killed", num=8)
    chunks = []

    def stop_after_two() -> bool:
        return len(chunks) >= 2

    s1 = run(defn, tmp_path, st, chunk_size=3, cancel=stop_after_two,
             on_chunk=lambda a, b, r: chunks.append((a, b)))  # fmt: skip
    assert s1.cancelled and st.count() == 6
    # another study with the same points (the killed one's chunk files are its own)
    s2 = run({**defn, "name": "after the kill"}, tmp_path, st)
    assert (s2.computed, s2.reused) == (10, 6)


# --------------------------------------------------------------------------- queries


@pytest.fixture
def filled(store: Any, tmp_path: Path) -> Any:
    st, cat = store
    a = run(tiny_study("a", num=6), tmp_path, st)
    defn = tiny_study("b", num=4, gaps=(0.5, 0.3))
    defn["grid"]["theta"] = [0.3, 1.0]
    b = run(defn, tmp_path, st)
    return st, cat, a, b


@pytest.mark.slow  # runs whole (small) studies
def test_queries_by_value_and_range_page_through_everything(filled: Any) -> None:
    st, _, a, b = filled
    total = st.count()
    # b shares θ 0.3, gap 0.5 at γ_r 0.5 and 3 (both grids' ends) with a
    assert (b.computed, b.reused) == (14, 2) and total == 12 + 14
    rows, nxt = st.query(PointQuery(values={"gap": 0.1}, ranges={"gamma_r": (1.0, 2.0)}))
    assert nxt is None and rows
    assert all(r["g1"] == r["g2"] == 0.1 and 1.0 <= r["gamma_r"] <= 2.0 for r in rows)
    with xr.open_dataset(a.path) as ds:
        want = ds.transmittance_db.sel(gap=0.1).to_series()
    want = want[(want.index >= 1.0) & (want.index <= 2.0)]
    got = sorted((r["gamma_r"], r["transmittance_db"]) for r in rows)
    np.testing.assert_array_equal([g for g, _ in got], want.index.values)
    np.testing.assert_array_equal([v for _, v in got], want.values)
    # a computed value matches within a relative 1e-9 (0.1 + 0.2 is not 0.3)
    assert st.query(PointQuery(values={"gap": 0.1 + 0.2}))[0]
    # paging: every point exactly once, in key order
    seen: list[str] = []
    after = None
    while True:
        page, after = st.query(PointQuery(limit=5, after=after))
        seen += [r["key"] for r in page]
        if after is None:
            break
    assert len(seen) == total and seen == sorted(set(seen))
    # a study's own points
    only_b = list(st.iter_query(PointQuery(study=b.study_id)))
    assert len(only_b) == 16 and {r["theta"] for r in only_b} == {0.3, 1.0}
    with pytest.raises(ValueError, match="unknown parameter 'bogus'"):
        st.query(PointQuery(values={"bogus": 1.0}))
    with pytest.raises(ValueError, match="limit must be"):
        st.query(PointQuery(limit=0))


@pytest.mark.slow  # runs whole (small) studies
def test_exports_keep_parameters_and_results(filled: Any, tmp_path: Path) -> None:
    st, *_ = filled
    rows = list(st.iter_query(PointQuery(values={"theta": 1.0})))
    assert len(rows) == 8
    ds = points_dataset(rows)
    assert ds.sizes["point"] == 8 and set(ds.theta.values) == {1.0}
    assert "flag_meanings" in ds.outcome.attrs
    path = tmp_path / "q.nc"
    ds.to_netcdf(path, engine="netcdf4")
    with xr.open_dataset(path) as back:
        np.testing.assert_array_equal(
            back.transmittance_db.values,
            [np.nan if r["transmittance_db"] is None else r["transmittance_db"] for r in rows],
        )
    text = points_csv(rows).splitlines()
    assert len(text) == 9 and text[0].startswith("key,version,method,start,theta")
    empty = points_dataset([])
    assert empty.sizes["point"] == 0


def irregular_record(flagged: bool | None, steady_period: int = 400) -> dict[str, Any]:
    """A constructed irregular record (``flagged`` None: one without the two fields, its
    reason carrying the engine's note)."""
    res = PointResult(
        outcome="irregular", transmittance_db=3.0, transmittance_db_se=0.05, amplitude=1.4,
        theta_eff=0.4, theta_eff_slope=-0.2, response_period=0, impacts_per_period=(1.0, 0.5),
        peak_impulse=0.1, floquet_multiplier=None, periods=steady_period + 30,
        steps=10_000, contact_steps=500, coarse_steps=0, steady_period=steady_period,
        wall_s=0.01, reason=f"… admissible here too: {TRANSIENT_NOTE}" if flagged is not False
        else "", method="event", steps_per_period=64, transmittance_linear_db=-20.0,
        impact_effect_db=23.0, may_be_transient=bool(flagged),
        impacting_periods=steady_period if flagged else None,
    )  # fmt: skip
    rec = res.as_dict()
    if flagged is None:
        del rec["may_be_transient"], rec["impacting_periods"]
    return rec


def test_the_transient_flag_comes_back_from_the_store_also_for_records_without_it(
    store: Any,
) -> None:
    st, _ = store
    solver = dataclasses.asdict(SolverSettings())
    made = {True: irregular_record(True, 300), None: irregular_record(None, 500),
            False: irregular_record(False)}  # fmt: skip
    rows = [(f"{k:032x}", {"theta": 0.3, "sigma": 0.05, "gamma_s": 1.0, "gamma_r": 1.0 + k}, rec)
            for k, rec in enumerate(made.values())]  # fmt: skip
    st.save(rows, solver)
    got = sorted(st.iter_query(PointQuery()), key=lambda r: r["key"])
    assert [(r["may_be_transient"], r["impacting_periods"]) for r in got] == [
        (True, 300),
        (True, 500),
        (False, None),
    ]
    ds = points_dataset(got)
    assert ds.may_be_transient.dtype == bool
    assert ds.may_be_transient.attrs["flag_meanings"] == "not_flagged may_be_transient"
    np.testing.assert_array_equal(ds.impacting_periods.values, [300, 500, np.nan])


# --------------------------------------------------------------------------- housekeeping


@pytest.mark.slow  # runs whole (small) studies
def test_delete_keeps_shared_points_and_gc_removes_the_rest(filled: Any, tmp_path: Path) -> None:
    st, cat, a, b = filled
    for s in (a, b):
        cat.add_study(s.study_id, "x", "{}", s.points)
    before = st.count()
    shared_a = {r["key"] for r in st.iter_query(PointQuery(study=a.study_id))}
    shared_b = {r["key"] for r in st.iter_query(PointQuery(study=b.study_id))}
    common = shared_a & shared_b
    cat.delete_study(a.study_id)
    assert st.count() == before  # deleting a study keeps its points until gc
    dry = st.gc(tmp_path / "elsewhere", dry_run=True)
    assert dry == {"points": len(shared_a - common), "links": 0, "studies": 0}
    assert st.count() == before
    assert st.gc(tmp_path / "elsewhere") == dry
    assert st.count() == before - len(shared_a - common)
    assert {r["key"] for r in st.iter_query(PointQuery())} == shared_b
    # a study run from the command line is not in the catalogue: its folder keeps it
    c = run(tiny_study("cli", num=3, gaps=(0.7,)), tmp_path, st)
    assert st.gc(tmp_path)["points"] == 0
    gone = st.gc(tmp_path / "elsewhere")
    assert gone == {"points": c.computed, "links": c.points, "studies": 1}


@pytest.mark.slow  # runs whole (small) studies
def test_a_solver_version_bump_hides_old_points_from_new_studies(
    store: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    st, _ = store
    defn = tiny_study("versions", num=3, gaps=(0.1,))
    run(defn, tmp_path, st)
    import service.api.points as api_points

    new = "999"
    monkeypatch.setattr(pts, "SOLVER_VERSION", new)
    monkeypatch.setattr(api_points, "SOLVER_VERSION", new)
    s = run({**defn, "name": "after the bump"}, tmp_path, st)
    assert (s.computed, s.reused) == (3, 0)
    assert len(st.query(PointQuery(version=SOLVER_VERSION))[0]) == 3
    assert len(st.query(PointQuery(version=new))[0]) == 3
    assert len(st.query(PointQuery(version="all"))[0]) == 6


@pytest.mark.slow  # runs whole (small) studies
def test_solver_settings_are_stored_once(filled: Any) -> None:
    st, *_ = filled
    from sqlalchemy import func, select

    from service.api.catalogue import SolverRow

    with st.engine.connect() as conn:
        assert conn.execute(select(func.count()).select_from(SolverRow)).scalar_one() == 1
    row = st.query(PointQuery(limit=1))[0][0]
    assert row["solver"]["max_periods"] == FAST_SOLVER["max_periods"]


def test_points_of_an_unpinned_cpu_are_keyed_apart(monkeypatch: pytest.MonkeyPatch) -> None:
    # A process off the pinned targets (aarch64, x86-64 without AVX2) computes other last bits:
    # its points get other keys, so neither side reuses the other's as equal.
    from service.studies import points
    from worker import cpu

    cell = {"theta": 0.3, "sigma": 0.05, "gamma_s": 1.0, "gamma_r": 1.2, "gap": 0.1}
    doc = points.solver_document({})
    if cpu.pinnable():
        assert points.key_version() == points.SOLVER_VERSION
    pinned = points.point_key(cell, doc, version=points.SOLVER_VERSION)
    monkeypatch.setattr(points, "on_pinned_target", lambda: False)
    monkeypatch.setattr(points, "target_label", lambda: "aarch64/neoverse-n1/NEOVERSEN1/ASIMD")
    points._off_pin.cache_clear()
    try:
        assert (
            points.key_version() == f"{points.SOLVER_VERSION}@aarch64/neoverse-n1/NEOVERSEN1/ASIMD"
        )
        assert points.point_key(cell, doc) != pinned
    finally:
        points._off_pin.cache_clear()
