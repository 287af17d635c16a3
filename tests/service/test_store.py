"""The results store: chunk files, atomic writes, collation, NetCDF round trip."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import netCDF4
import numpy as np
import pytest
import xarray as xr

from service.store import (
    FILL_FLOAT,
    StudyStore,
    atomic_write,
    open_results,
    results_from_records,
)
from service.study import parse_study
from worker.simulate import simulate_chunk

SOLVER = {"steps_per_period": 256, "max_periods": 60, "window": 5}


def _study(**grid: Any) -> Any:
    g = {"gamma_r": [0.5, 1.0, 2.0], "gap": [0.1, 0.5], "theta": 0.3, "sigma": 0.05}
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
    assert "theta_eff" not in ds and "peak_impulse" in ds and "transmittance_db" in ds
    assert {"failed", "reason", "wall_s"} <= set(ds.data_vars)


def test_missing_ranges_and_bad_chunks(tmp_path: Path) -> None:
    study = _study()
    store = StudyStore(tmp_path, study)
    store.prepare()
    records = _records(study)
    store.write_chunk(0, 2, records[0:2])
    store.write_chunk(4, 5, records[4:5])
    assert store.missing_ranges() == [(2, 4), (5, 6)]
    # A chunk marked for retry and an unreadable one are dropped and computed again.
    store.write_chunk(2, 4, records[2:4], retry=True)
    (store.chunk_dir / "5-6.npz").write_bytes(b"not a zip")
    assert store.has_retry_chunks()
    assert store.missing_ranges() == [(2, 4), (5, 6)]
    assert not (store.chunk_dir / "5-6.npz").exists()
    with pytest.raises(ValueError, match="points have no results yet"):
        store.collect()


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
            "physical": {
                "length_m": 0.15,
                "width_m": 0.01,
                "thickness_m": 0.0025,
                "density_kg_m3": 1250.0,
                "youngs_modulus_pa": 4.583e7,
                "outer_mass_kg": 0.01667,
                "spring_n_m": 350.0,
                "damping_ratio": 0.03,
                "gap_m": 0.001,
            },  # fmt: skip
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
