"""Adaptive studies (issue 17): the study block and its refusals, the run (serial here, the
cluster and the service in the slow tests), the dataset, resuming from the point store, and
bandgap maps from the located edges. The learners themselves: test_adaptive_learners.py."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr

from service.analysis.bands import bandgap_json, bandgap_map
from service.api.catalogue import Catalogue
from service.api.points import SqlPointStore
from service.studies.adaptive_run import NOT_SAMPLED
from service.studies.runner import run_study
from service.studies.schema import StudyError, parse_study
from tests.service.helpers import FAST_SOLVER

TOL = 1e-3


def adaptive_study(name: str = "edges", **adaptive: Any) -> dict[str, Any]:
    """Γ = 0 dB edges along γ_r 0.5–3 for two gaps (FAST_SOLVER)."""
    return {
        "name": name,
        "solver": dict(FAST_SOLVER),
        "adaptive": {
            "axis": "gamma_r",
            "tol": TOL,
            "min_width": 0.25,
            "max_points": 60,
            **adaptive,
        },  # fmt: skip
        "grid": {
            "gamma_r": {"start": 0.5, "stop": 3.0, "num": 2},
            "gap": [0.1, 0.5],
            "theta": 0.3,
            "sigma": 0.05,
            "gamma_s": 1.0,
        },
    }


@pytest.fixture
def store(tmp_path: Path) -> Any:
    cat = Catalogue(f"sqlite:///{tmp_path / 'cat.sqlite'}")
    yield SqlPointStore(cat.engine)
    cat.close()


def run(defn: dict[str, Any], root: Path, store: Any, **kw: Any) -> Any:
    return run_study(parse_study(defn), root, serial=True, points=store, **kw)


# --------------------------------------------------------------------------- the study block


@pytest.mark.parametrize(
    ("change", "path", "says"),
    [
        ({"sweep": {"axis": "gamma_r"}}, "adaptive", "give one of them"),
        ({"initial": ["rest", "linear"]}, "adaptive", "drop initial"),
        ({"adaptive": {"axis": "theta"}}, "grid.theta", "must be a range"),
        ({"adaptive": {"axis": "zeta"}}, "adaptive.axis", "'zeta' is not an axis"),
        ({"adaptive": {"axis": "gamma_r", "max_points": 1}}, "adaptive.max_points", "2…10000"),
        ({"adaptive": {"axis": "gamma_r", "tol": 5}}, "adaptive.tol", "below the axis's span"),
        ({"adaptive": {"axis": "gamma_r", "target": "peaks"}}, "adaptive.target", "band_edges"),
    ],
)
def test_refused_adaptive_studies_say_why(change: dict, path: str, says: str) -> None:
    defn = {**adaptive_study(), **change}
    with pytest.raises(StudyError) as err:
        parse_study(defn)
    problems = dict(err.value.problems)
    assert path in problems, problems
    assert says in problems[path]


def test_an_adaptive_study_keeps_grid_ids_and_bounds_its_size() -> None:
    s = parse_study(adaptive_study())
    assert s.is_adaptive and s.size == 2 * 60  # lines × max_points: the most it may compute
    plain = adaptive_study()
    plain.pop("adaptive")
    assert parse_study(plain).id != s.id and not parse_study(plain).is_adaptive


# --------------------------------------------------------------------------- the run


@pytest.mark.slow  # runs whole (small) studies
def test_edges_are_located_to_tol_and_the_dataset_holds_the_samples(
    tmp_path: Path, store: Any
) -> None:
    s = run(adaptive_study(), tmp_path, store)
    ds = xr.open_dataset(s.path).load()
    assert s.points == int(ds.sampled.sum()) == int(ds.line_points.sum()) == s.computed
    assert int(ds.line_points.max()) <= 60
    g = ds.gamma_r.values
    assert np.all(np.diff(g) > 0) and g[0] == 0.5 and g[-1] == 3.0
    # where a line did not sample: missing, with the reason saying so
    gamma = ds.transmittance_db.values
    assert np.all(np.isnan(gamma[~ds.sampled.values]))
    assert set(ds.reason.values[~ds.sampled.values].ravel()) == {NOT_SAMPLED}
    found = 0
    for gap in ds.gap.values:
        line = ds.sel(gap=gap)
        edges = line.band_edges.values
        n = int(np.isfinite(edges).sum())
        assert np.all(np.isfinite(edges[:n])) and np.all(np.isnan(edges[n:]))  # fill-padded
        assert np.all(np.diff(edges[:n]) > 0)
        for k in range(n):
            lo, hi = float(line.band_edge_lo[k]), float(line.band_edge_hi[k])
            assert lo <= edges[k] <= hi
            if line.band_edge_certain[k] != 1:
                continue
            found += 1
            assert hi - lo <= 2 * TOL + 1e-12
            # the known answer: the sampled points at both ends lie on either side of 0 dB
            g_lo = float(line.transmittance_db.sel(gamma_r=lo))
            g_hi = float(line.transmittance_db.sel(gamma_r=hi))
            rising = line.band_edge_rising[k] == 1
            assert (g_lo < 0 <= g_hi) if rising else (g_hi < 0 <= g_lo), (lo, hi, g_lo, g_hi)
    assert found >= 2  # both lines cross 0 dB above the resonance


@pytest.mark.slow  # runs whole (small) studies
def test_features_are_refined_where_the_transmittance_bends(tmp_path: Path, store: Any) -> None:
    s = run(adaptive_study("features", target="features", resolution=0.01, jump_db=3.0),
            tmp_path, store)  # fmt: skip
    ds = xr.open_dataset(s.path).load()
    assert "feature_lo" in ds and "band_edges" not in ds
    lo, hi = ds.feature_lo.values, ds.feature_hi.values
    ok = np.isfinite(lo)
    assert ok.any() and np.all(hi[ok] - lo[ok] <= 0.01 + 1e-12)
    # the resonance peak (γ_r ≈ 1) is one of them
    assert np.any((lo[ok] <= 1.1) & (hi[ok] >= 0.9))


@pytest.mark.slow  # runs whole (small) studies
def test_a_renamed_or_killed_adaptive_study_takes_its_points_from_the_store(
    tmp_path: Path, store: Any
) -> None:
    first = run(adaptive_study(), tmp_path, store)
    again = run(adaptive_study("renamed"), tmp_path, store)
    assert (again.computed, again.reused) == (0, first.points)
    a = xr.open_dataset(first.path).load()
    b = xr.open_dataset(again.path).load()
    np.testing.assert_array_equal(a.band_edges.values, b.band_edges.values)
    np.testing.assert_array_equal(a.transmittance_db.values, b.transmittance_db.values)

    # killed after three batches, then run again: the learners ask for the same points, the
    # store answers those it has (other solver settings: nothing shared with the runs above)
    other = adaptive_study("killed")
    other["solver"]["max_periods"] = 61
    chunks: list[int] = []
    killed = run(other, tmp_path, store, cancel=lambda: len(chunks) >= 3,
                 on_chunk=lambda *a: chunks.append(1))  # fmt: skip
    assert killed.cancelled and killed.computed >= 3
    resumed = run(other, tmp_path, store)
    assert resumed.reused == killed.computed
    full = run({**other, "name": "not killed"}, tmp_path, store)
    assert full.computed == 0 and full.points == resumed.points


@pytest.mark.slow  # runs whole (small) studies
def test_the_bandgap_map_uses_the_located_edges(tmp_path: Path, store: Any) -> None:
    s = run(adaptive_study(), tmp_path, store)
    ds = xr.open_dataset(s.path).load()
    m = bandgap_map(ds, "gamma_r", "gap")
    doc = bandgap_json(m)
    for row in doc["edges"]:
        line = ds.sel(gap=row["y"])
        located = {float(v) for v in line.band_edges.values if np.isfinite(v)}
        for (start, stop), kinds, iv in zip(row["bands"], row["kinds"], row["intervals"],
                                            strict=True):  # fmt: skip
            for x, kind, (lo, hi) in ((start, kinds[0], iv[0]), (stop, kinds[1], iv[1])):
                assert kind in ("located", "uncertain", "grid_end")
                if kind != "grid_end":
                    assert x in located and lo <= x <= hi
    # another threshold is not what the study located: interpolated as for any grid
    other = bandgap_json(bandgap_map(ds, "gamma_r", "gap", threshold_db=-5.0))
    assert all("intervals" not in row for row in other["edges"])


@pytest.mark.slow
def test_an_adaptive_study_runs_on_the_cluster_like_serially(
    tmp_path: Path, dask_address: str
) -> None:
    defn = adaptive_study("on the cluster")
    serial = run_study(parse_study(defn), tmp_path / "serial", serial=True)
    cat = Catalogue(f"sqlite:///{tmp_path / 'c2.sqlite'}")
    try:
        from dask.distributed import Client as DaskClient

        with DaskClient(dask_address) as client:
            dist = run_study(parse_study(copy.deepcopy(defn)), tmp_path / "dist", client=client,
                             points=SqlPointStore(cat.engine))  # fmt: skip
    finally:
        cat.close()
    a = xr.open_dataset(serial.path).load()
    b = xr.open_dataset(dist.path).load()
    np.testing.assert_array_equal(a.gamma_r.values, b.gamma_r.values)
    np.testing.assert_array_equal(a.band_edges.values, b.band_edges.values)
    assert dist.computed == serial.computed
