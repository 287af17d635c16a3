"""The results routes over damaged files (issue 63), in process (no runner): a damaged chunk
is a pending part of a partial dataset, never a 500; a finished study's results file that is
missing or fails its SHA-256 is never served (503, the study queued to write it again); no
response shows a server path."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import netCDF4
import pytest

from service.studies.dataset import results_from_records
from tests.service.api.test_results import QUICK, Served, record
from tests.service.studies.test_damaged_files import _flip_value, _truncate

ROUTES = ("/dataset", "/data", "/bandgap", "/plots/bandgap.png")


def _no_path(served: Served, body: bytes) -> None:
    root = str(served.settings.data_dir.resolve()).encode()
    for part in (root, b"/tmp/", b"results.nc", b".npz", b"damaged/"):
        assert part not in body, part


@pytest.mark.parametrize("damage", [_truncate, _flip_value], ids=["truncated", "byte-flipped"])
def test_a_damaged_chunk_is_pending_in_the_partial_dataset(
    served: Served, damage: Callable[[Path], None]
) -> None:
    for a in range(0, 36, 6):
        served.write(a, a + 6)
    damage(served.store.chunk_dir / "12-18.npz")
    for route in ROUTES:
        r = served.get(route)
        assert r.status_code == 200, (route, r.text[:300])
        _no_path(served, r.content)
    ds = served.client.dataset(served.id)
    assert int(ds.attrs["points_done"]) == 30
    pending = ds["pending"].transpose("gap", "theta", "gamma_r").values.ravel()
    assert list(pending.nonzero()[0]) == list(range(12, 18))
    assert served.get("/data").json()["partial"] is True
    assert not (served.store.chunk_dir / "12-18.npz").exists()
    assert [p.name.split(".npz.")[0] for p in (served.store.folder / "damaged").iterdir()] == [
        "12-18"
    ]


def _finish(served: Served) -> None:
    for a in range(0, 36, 6):
        served.write(a, a + 6)
    served.store.write_results(
        results_from_records(served.study, served.store.collect_partial()[0])
    )
    cat = served.tc.app.state.catalogue
    assert cat.set_status_if(served.id, ("queued",), "finished")


def _overwrite_coordinate(path: Path) -> None:
    with netCDF4.Dataset(path, "r+") as nc:
        nc["gamma_r"][1] = 42.0


DAMAGE = {
    "coordinate-overwritten": _overwrite_coordinate,
    "zero-bytes": lambda p: p.write_bytes(b""),
    "truncated": _truncate,
    "missing": lambda p: p.unlink(),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
@pytest.mark.parametrize("route", ROUTES)
def test_a_damaged_results_file_is_never_served_and_the_study_is_queued_to_rebuild_it(
    served: Served, damage: str, route: str
) -> None:
    _finish(served)
    good = served.get("/dataset")
    assert good.status_code == 200 and good.headers["x-impactcell-partial"] == "0"
    assert good.content == served.store.results_path.read_bytes()
    DAMAGE[damage](served.store.results_path)
    r = served.get(route)
    assert r.status_code == 503, r.text[:300]
    assert r.headers["retry-after"] == "5"
    detail = r.json()["detail"]
    why = "is missing" if damage == "missing" else "failed its SHA-256 check"
    assert f"the results file of study {served.id} {why}" in detail
    assert "queued to write it again" in detail
    _no_path(served, r.content)
    assert served.client.get(served.id)["status"] == "queued"
    if damage != "missing":
        aside = sorted(
            p.name.rsplit(".", 1)[0] for p in (served.store.folder / "damaged").iterdir()
        )
        assert aside == ["results.nc", "results.nc.sha256"]
    # Queued again: its data is the partial dataset of its chunks until a run writes the file.
    again = served.get("/dataset")
    assert again.status_code == 200 and again.headers["x-impactcell-partial"] == "1"
    assert int(served.client.dataset(served.id).attrs["points_done"]) == 36


def test_a_study_whose_chunks_are_found_damaged_at_collation_is_queued_again(
    tmp_path: Path,
) -> None:
    from service.api.catalogue import Catalogue
    from service.api.jobs import JobManager, _Active, lease_name
    from service.api.settings import Settings
    from service.studies.chunks import MissingPoints
    from service.studies.runner import StudyRun
    from service.studies.schema import parse_study

    settings = Settings(data_dir=tmp_path / "data")
    settings.data_dir.mkdir()
    cat = Catalogue(settings.catalogue_url())
    try:
        study = parse_study(QUICK)
        cat.add_study(study.id, study.name, study.canonical_json(), study.size)
        assert cat.set_status_if(study.id, ("queued",), "running")
        jobs = JobManager(settings, cat)  # not started: its runner thread's step done here
        run = StudyRun(study, settings.data_dir)
        for a in range(0, study.size, 6):
            run.store.write_chunk(a, a + 6, [record(i) for i in range(a, a + 6)])
        _truncate(run.store.chunk_dir / "6-12.npz")
        with pytest.raises(MissingPoints):  # what the runner thread meets
            run.store.collect()
        token = cat.acquire_fenced(lease_name(study.id), jobs.instance, 60.0)
        assert token is not None  # the runner holds the study's lease, as when it runs it
        jobs._hold(study.id, token)
        act = _Active(study, run, 0.0, jobs._fence(study.id, token))
        jobs._active[study.id] = act
        jobs._finish(study.id)  # the results file is written off the runner thread ...
        assert act.collating is not None
        with pytest.raises(MissingPoints):
            act.collating.result(timeout=60)
        jobs._retry_finishing()  # ... and looked at again by the runner's next step
        rec = cat.get_study(study.id)
        assert rec is not None and rec["status"] == "queued" and rec["error"] is None
        assert jobs._queue.get_nowait() == study.id  # the runner takes it up again
        assert not run.store.results_path.exists()
    finally:
        cat.close()
