"""The results store (service.studies.chunks) and datasets (service.studies.dataset): chunk
files, atomic writes, collation, NetCDF round trip."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import netCDF4
import numpy as np
import pytest
import xarray as xr

from service.studies.chunks import StudyStore, atomic_write
from service.studies.dataset import (
    FILL_FLOAT,
    PENDING,
    open_results,
    results_from_records,
    summarize,
)
from service.studies.schema import parse_study
from service.studies.variables import outcome_names
from tests.service.helpers import TABLE1_CELL
from worker.simulate import simulate_chunk
from worker.solvers.settings import OUTCOMES, TRANSIENT_NOTE

SOLVER = {"steps_per_period": 256, "max_periods": 120, "window": 5}


def _study(**grid: Any) -> Any:
    g = {"gamma_r": [0.5, 1.0, 2.2], "gap": [0.1, 0.5], "theta": 0.3, "sigma": 0.05}
    g.update(grid)
    g.setdefault("gamma_s", 1.0)
    return parse_study({"name": "store", "solver": SOLVER, "grid": g})


def _records(study: Any) -> list[dict[str, Any]]:
    return simulate_chunk(study.points(0, study.size), study.solver.settings().__dict__)


def _fill(store: StudyStore, records: list[dict[str, Any]], size: int) -> None:
    for s in range(0, len(records), size):
        store.write_chunk(s, min(s + size, len(records)), records[s : s + size])


def _with_failure(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    from worker.simulate import SolverSettings, failed_result

    out = list(records)
    out[1] = failed_result(SolverSettings(**SOLVER), "test: point made to fail")
    return out


def test_netcdf_round_trip_with_failed_point(tmp_path: Path) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    records = _with_failure(_records(study))
    _fill(store, records, 4)
    ds = results_from_records(study, store.collect())
    path = store.write_results(ds)
    back = open_results(path)
    xr.testing.assert_identical(ds, back)

    # The failed point: flagged, with a reason, and its measured values missing.
    flat = back.stack(p=list(study.dims()))
    assert bool(flat["failed"].values[1]) and "made to fail" in str(flat["reason"].values[1])
    for v in ("transmittance_db", "theta_eff", "response_period", "amplitude"):
        assert np.isnan(flat[v].values[1])
    assert not flat["failed"].values[[0, 2, 3, 4, 5]].any()

    # On disk: no NaN anywhere, the fill value where missing, compression on.
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        t = nc["transmittance_db"][:]
        assert not np.isnan(t).any()
        assert t.ravel()[1] == FILL_FLOAT
        assert nc["response_period"][:].ravel()[1] == -1
        assert nc["transmittance_db"].filters()["zlib"]
        assert nc["failed"][:].ravel()[1] == 1


def test_outcome_flag_round_trips_with_its_cf_attributes(tmp_path: Path) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    records = _with_failure(_records(study))
    names = [r["outcome"] for r in records]
    # The grid covers a steady point, an irregular one and a failed one (else the test is moot).
    assert {"periodic", "irregular", "failed"} <= set(names), names
    _fill(store, records, 4)
    path = store.write_results(results_from_records(study, store.collect()))

    back = open_results(path)
    out = back["outcome"]
    assert out.dtype == np.int8 and out.dims == ("gap", "gamma_r")
    assert out.attrs["flag_meanings"] == " ".join(OUTCOMES)
    assert OUTCOMES == ("linear", "periodic", "irregular", "unsettled", "failed")
    np.testing.assert_array_equal(out.attrs["flag_values"], np.arange(5, dtype=np.int8))
    assert {"units", "long_name"} <= set(out.attrs)
    flat = back.stack(p=list(study.dims()))
    assert list(outcome_names(flat["outcome"])) == names
    # ``failed`` and the outcome agree; irregular counts as such, not as "period 0 and fine".
    np.testing.assert_array_equal(flat["failed"].values, np.array(names) == "failed")
    counts = summarize(back)
    assert counts["irregular"] == names.count("irregular") and counts["failed"] == 1
    assert sum(counts[k] for k in OUTCOMES) == study.size

    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        v = nc["outcome"]
        assert v.dtype == np.int8 and "_FillValue" not in v.ncattrs()  # never missing
        assert v.getncattr("flag_meanings") == "linear periodic irregular unsettled failed"
        np.testing.assert_array_equal(v.getncattr("flag_values"), [0, 1, 2, 3, 4])
        np.testing.assert_array_equal(v[:].ravel(), [OUTCOMES.index(n) for n in names])


def _flagged(records: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], int, int]:
    """``records`` with one irregular point flagged may_be_transient (constructed: which points
    a CPU ends irregular is not pinned) and one more irregular-looking record that lacks both
    fields but carries the engine's note, as a record written without them does."""
    out = [dict(r) for r in records]
    irregular = [i for i, r in enumerate(out) if r["outcome"] == "irregular"]
    assert irregular, "the grid must have an irregular point"
    i = irregular[0]
    note = f"the impact-free response (Γ = -20 dB) is admissible here too: {TRANSIENT_NOTE}"
    out[i].update(may_be_transient=True, impacting_periods=out[i]["steady_period"], reason=note)
    j = next(k for k, r in enumerate(out) if k != i and r["outcome"] != "failed")
    out[j].update(outcome="irregular", reason=note, steady_period=321)
    del out[j]["may_be_transient"], out[j]["impacting_periods"]
    return out, i, j


def test_may_be_transient_round_trips_as_a_cf_flag_and_records_without_it_stay_readable(
    tmp_path: Path,
) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    records, i, j = _flagged(_with_failure(_records(study)))
    _fill(store, records, 4)
    path = store.write_results(results_from_records(study, store.collect()))
    back = open_results(path)
    flat = back.stack(p=list(study.dims()))
    flag = flat["may_be_transient"].values
    assert flag.dtype == bool and set(np.flatnonzero(flag)) == {i, j}
    lasted = flat["impacting_periods"].values
    assert lasted[i] == records[i]["steady_period"] and lasted[j] == 321
    assert np.isnan(np.delete(lasted, [i, j])).all()  # only where flagged
    assert np.isfinite(flat["transmittance_linear_db"].values[[i, j]]).all()
    with netCDF4.Dataset(path) as nc:
        v = nc["may_be_transient"]
        assert v.dtype == np.int8 and v.getncattr("flag_meanings") == (
            "not_flagged may_be_transient"
        )
        np.testing.assert_array_equal(v.getncattr("flag_values"), [0, 1])
        assert nc["impacting_periods"].dtype == np.int32

    # a chunk file without the two columns (nor a SHA-256, as chunk files of then): read from
    # the reason's note and steady_period
    old = ("may_be_transient", "impacting_periods", "_sha256")
    for _, _, chunk in store.chunks():
        with np.load(chunk) as z:
            cols = {k: z[k] for k in z.files if k not in old}
        with open(chunk, "wb") as fh:
            np.savez(fh, **cols)
    again = StudyStore(tmp_path, study).collect()
    np.testing.assert_array_equal(again["may_be_transient"], flag)
    assert list(np.flatnonzero(again["impacting_periods"] >= 0)) == sorted((i, j))


def test_standard_error_is_a_fill_value_where_it_does_not_apply(tmp_path: Path) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    records = _with_failure(_records(study))
    se = [r["transmittance_db_se"] for r in records]
    assert any(x is None for x in se) and any(x is not None for x in se), se
    for r in records:  # the worker's contract: a standard error only where Γ is a mean
        assert (r["transmittance_db_se"] is not None) == (r["outcome"] in ("irregular",
                                                                         "unsettled"))  # fmt: skip
    _fill(store, records, 4)
    path = store.write_results(results_from_records(study, store.collect()))
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        for var in ("transmittance_db_se", "floquet_multiplier", "theta_eff_slope"):
            disk = nc[var][:].ravel()
            assert not np.isnan(disk).any(), var  # fill values on disk, never NaN
            want = [r[var] for r in records]
            for got, w in zip(disk, want, strict=True):
                assert got == FILL_FLOAT if w is None else got == pytest.approx(w, rel=1e-15)
        assert nc["transmittance_db_se"].units == "dB"
    flat = open_results(path).stack(p=list(study.dims()))
    np.testing.assert_array_equal(np.isnan(flat["transmittance_db_se"].values),
                                  [x is None for x in se])  # fmt: skip


def test_unknown_outcome_is_refused_and_pending_points_read_as_failed(tmp_path: Path) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    records = _records(study)
    bad = [dict(r) for r in records[:2]]
    bad[1]["outcome"] = "chaotic"
    with pytest.raises(ValueError, match="outcome must be one of linear, .*got 'chaotic'"):
        store.write_chunk(0, 2, bad)
    store.write_chunk(0, 2, records[:2])
    cols, filled = store.collect_partial()
    ds = results_from_records(study, cols, computed=filled)
    flat = ds.stack(p=list(study.dims()))
    names = outcome_names(flat["outcome"])
    assert list(names[:2]) == [r["outcome"] for r in records[:2]]
    assert set(names[2:]) == {"failed"} and set(flat["reason"].values[2:]) == {PENDING}
    assert flat["pending"].values[2:].all() and not flat["pending"].values[:2].any()


def test_cf_attributes_and_provenance(tmp_path: Path) -> None:
    study = _study()
    ds = results_from_records(study, _collect(tmp_path, study))
    for name in list(ds.data_vars) + list(ds.coords):
        assert {"units", "long_name"} <= set(ds[name].attrs), name
    for key in ("study", "study_id", "impactcell_version", "solver_settings", "created"):
        assert key in ds.attrs
    assert ds.attrs["study_id"] == study.id
    assert ds["gamma_r"].dims == ("gamma_r",) and ds["theta"].dims == ()
    assert ds["impacts_per_period"].dims == ("gap", "gamma_r", "stop")


def _collect(tmp_path: Path, study: Any, size: int = 5) -> dict[str, np.ndarray]:
    store = StudyStore(tmp_path, study)
    store.prepare()
    _fill(store, _records(study), size)
    return store.collect()


def test_collation_independent_of_chunking(tmp_path: Path) -> None:
    study = _study()
    records = _records(study)
    out = []
    for i, size in enumerate((1, 4, 6)):
        store = StudyStore(tmp_path / str(i), study)
        store.prepare()
        _fill(store, records, size)
        out.append(results_from_records(study, store.collect(), created="x"))
    xr.testing.assert_identical(out[0], out[1])
    xr.testing.assert_identical(out[0], out[2])


def test_outputs_select_variables(tmp_path: Path) -> None:
    study = parse_study(
        {
            "name": "o",
            "solver": SOLVER,
            "outputs": {"effective_mass": False, "contact": True},
            "grid": {"gamma_r": [1.0, 2.0], "gap": 0.2, "theta": 0.3, "sigma": 0.05, "gamma_s": 1},
        }
    )
    ds = results_from_records(study, _collect(tmp_path, study))
    assert "theta_eff" not in ds and "theta_eff_slope" not in ds
    assert {"peak_impulse", "transmittance_db", "transmittance_db_se", "outcome"} <= set(ds)
    assert {"failed", "reason", "wall_s"} <= set(ds.data_vars)
    assert not {"converged", "theta_eff_mean"} & set(ds.data_vars)  # solver version 1 only


def test_missing_ranges_and_bad_chunks(tmp_path: Path) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    records = _records(study)
    store.write_chunk(0, 2, records[0:2])
    store.write_chunk(4, 5, records[4:5])
    assert store.missing_ranges() == [(2, 4), (5, 6)]
    assert not store.has_retry_chunks()
    (store.chunk_dir / "5-6.npz").write_bytes(b"not a zip")
    assert store.has_retry_chunks()  # an unreadable chunk is computed again too
    # A chunk marked for retry and an unreadable one are dropped and computed again.
    store.write_chunk(2, 4, records[2:4], retry=True)
    assert store.has_retry_chunks()
    assert store.missing_ranges() == [(2, 4), (5, 6)]
    assert not (store.chunk_dir / "5-6.npz").exists()
    with pytest.raises(ValueError, match="points have no results yet"):
        store.collect()


def _assert_same_columns(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for name in a:
        assert a[name].dtype == b[name].dtype, name
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def _record_loads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the files ``np.load`` opens from now on."""
    loads: list[str] = []
    real = np.load
    monkeypatch.setattr(
        np, "load", lambda path, **kw: loads.append(Path(path).name) or real(path, **kw)
    )
    return loads


def test_a_store_collates_the_chunks_it_wrote_without_reading_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    _fill(store, _with_failure(_records(study)), 4)
    from_disk = StudyStore(tmp_path, study).collect()  # a fresh store reads the files
    loads = _record_loads(monkeypatch)
    _assert_same_columns(store.collect(), from_disk)
    assert not store.has_retry_chunks()
    assert loads == []
    assert bool(from_disk["failed"][1]) and "made to fail" in from_disk["reason"][1]


def test_a_chunk_rewritten_by_another_run_is_read_from_its_file(tmp_path: Path) -> None:
    study = _study()
    records = _records(study)
    store = StudyStore(tmp_path, study)
    store.prepare()
    _fill(store, records, 3)
    other = StudyStore(tmp_path, study)  # another run of the study, writing the same chunk
    other.write_chunk(0, 3, _with_failure(records)[0:3], retry=True)
    cols = store.collect()
    assert bool(cols["failed"][1]) and "made to fail" in cols["reason"][1]
    assert store.has_retry_chunks()


def test_chunks_beyond_the_held_points_are_read_from_their_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import service.studies.chunks as chunks

    monkeypatch.setattr(chunks, "HOLD_POINTS", 4)
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    _fill(store, _records(study), 4)  # 0-4 is held, 4-6 is not
    loads = _record_loads(monkeypatch)
    cols = store.collect()
    assert loads == ["4-6.npz"]
    _assert_same_columns(cols, StudyStore(tmp_path, study).collect())
    store.remove_chunks()
    assert store._held == {} and store._held_points == 0


def test_atomic_write_leaves_nothing_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "f.bin"

    def boom(p: Path) -> None:
        p.write_bytes(b"half")
        raise RuntimeError("crash mid-write")

    with pytest.raises(RuntimeError):
        atomic_write(target, boom)
    assert list(tmp_path.iterdir()) == []
    atomic_write(target, lambda p: p.write_bytes(b"whole"))
    assert target.read_bytes() == b"whole" and [x.name for x in tmp_path.iterdir()] == ["f.bin"]


def test_paths_are_ids(tmp_path: Path) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    assert store.folder == tmp_path / "studies" / study.id
    store.prepare()
    assert store.definition_path.is_file()


def test_physical_results_carry_hz_and_gamma_r(tmp_path: Path) -> None:
    study = parse_study(
        {
            "name": "phys",
            "solver": SOLVER,
            "physical": TABLE1_CELL,
            "grid": {"frequency_hz": [20.0, 25.0], "base_amplitude_m": [0.0005, 0.001]},
        }
    )
    ds = results_from_records(study, _collect(tmp_path, study))
    assert ds["frequency_hz"].attrs["units"] == "Hz"
    assert ds["gamma_r"].dims == ("frequency_hz",)
    assert ds["g1"].dims == ("base_amplitude_m",)
    assert ds["theta"].dims == ()
    np.testing.assert_allclose(
        ds["gamma_r"].values, 2 * np.pi * np.array([20, 25]) / np.sqrt(350 / 0.01667)
    )


def test_update_partial_reads_only_new_chunks_and_rebuilds_when_one_vanishes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    records = _with_failure(_records(study))
    reads: list[str] = []
    load = StudyStore._load_chunk
    monkeypatch.setattr(StudyStore, "_load_chunk",
                        lambda self, p: reads.append(p.name) or load(self, p))  # fmt: skip
    store.write_chunk(0, 2, records[:2])
    state = store.update_partial(None)
    assert state.files_read == 1 and state.filled.tolist() == [True, True] + [False] * 4
    key = state.key
    assert store.update_partial(state) is state and state.files_read == 0 and state.key == key
    store.write_chunk(2, 4, records[2:4], retry=True)
    state = store.update_partial(state)
    assert reads == ["0-2.npz", "2-4.npz"] and state.has_retry and state.key != key
    cols, filled = store.collect_partial()
    for name in cols:  # incremental equals built at once
        np.testing.assert_array_equal(state.cols[name], cols[name])
    np.testing.assert_array_equal(state.filled, filled)
    (store.chunk_dir / "2-4.npz").unlink()  # a retry chunk removed to compute it again
    fresh = store.update_partial(state)
    assert fresh is not state and not fresh.has_retry and fresh.filled.sum() == 2
    assert fresh.cols["reason"][3] == PENDING and fresh.cols["failed"][3]
    store.write_chunk(0, 2, [records[2], records[3]])  # a chunk rewritten: read again
    again = store.update_partial(fresh)
    assert again is not fresh and reads[-1] == "0-2.npz"
    assert again.cols["transmittance_db"][0] == records[2]["transmittance_db"]
