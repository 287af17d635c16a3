"""Damaged files are detected and healed (issue 63): chunk files carry the SHA-256 of their
arrays and the results file a SHA-256 beside it; a file that fails its check is set aside in
``damaged/`` and its points are computed again (or taken from the point store), so that a
study finishes with nothing lost and nothing computed twice."""

from __future__ import annotations

import hashlib
import shutil
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import netCDF4
import numpy as np
import pytest
import xarray as xr

from service.api.catalogue import Catalogue
from service.api.points import SqlPointStore
from service.studies.chunks import MissingPoints, StudyStore
from service.studies.dataset import open_results, results_from_records
from service.studies.runner import run_study
from service.studies.schema import Study, parse_study
from tests.service.helpers import comparable, tiny_study
from worker.simulate import simulate_chunk

DEFINITION = tiny_study(name="damaged", num=4)  # 4 × 2 = 8 points


@pytest.fixture(scope="module")
def study() -> Study:
    return parse_study(DEFINITION)


@pytest.fixture(scope="module")
def records(study: Study) -> list[dict[str, Any]]:
    return simulate_chunk(study.points(0, study.size), study.solver.settings().__dict__)


@pytest.fixture(scope="module")
def reference(study: Study, tmp_path_factory: pytest.TempPathFactory) -> xr.Dataset:
    """The study's results from one clean serial run."""
    root = tmp_path_factory.mktemp("reference")
    return comparable(open_results(run_study(study, root, serial=True).path))


@pytest.fixture
def point_store(tmp_path: Path) -> Iterator[SqlPointStore]:
    cat = Catalogue(f"sqlite:///{tmp_path / 'catalogue.sqlite'}")
    yield SqlPointStore(cat.engine)
    cat.close()


def _store(tmp_path: Path, study: Study, records: list[dict[str, Any]]) -> StudyStore:
    """A store holding the study's points in chunks 0-3, 3-6 and 6-8."""
    store = StudyStore(tmp_path, study)
    store.prepare()
    for a, b in ((0, 3), (3, 6), (6, 8)):
        store.write_chunk(a, b, records[a:b])
    return store


def _member(path: Path, name: str) -> tuple[int, int]:
    """Where the bytes of array ``name`` of an npz file start in the file, and how many."""
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(f"{name}.npy")
    with open(path, "rb") as fh:
        fh.seek(info.header_offset)
        head = fh.read(30)  # the zip local file header; then its name and extra field
    start = info.header_offset + 30 + int.from_bytes(head[26:28], "little")
    start += int.from_bytes(head[28:30], "little")
    return start, info.file_size


def _flip(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _flip_value(path: Path) -> None:
    start, size = _member(path, "transmittance_db")
    _flip(path, start + size - 3)  # inside the last float: the zip CRC no longer matches


def _flip_directory(path: Path) -> None:
    _flip(path, path.stat().st_size - 30)  # in the zip's central directory


def _rewritten(path: Path) -> None:
    """A valid npz again (good CRCs), one value changed, the old digest kept."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["transmittance_db"] = arrays["transmittance_db"] + 1.0
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def _other_range(path: Path) -> None:
    shutil.copyfile(path.with_name("0-3.npz"), path)  # 0-3's points under 3-6's name


DAMAGE: dict[str, Callable[[Path], None]] = {
    "truncated": _truncate,
    "zero-bytes": lambda p: p.write_bytes(b""),
    "value-byte-flipped": _flip_value,
    "directory-byte-flipped": _flip_directory,
    "rewritten-with-a-changed-value": _rewritten,
    "another-range": _other_range,
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_chunk_is_set_aside_and_its_points_count_as_missing(
    tmp_path: Path, study: Study, records: list[dict[str, Any]], damage: str
) -> None:
    store = _store(tmp_path, study, records)
    chunk = store.chunk_dir / "3-6.npz"
    DAMAGE[damage](chunk)
    # every reader: a fresh store (another run, or the API) and the store that wrote it
    for reader in (StudyStore(tmp_path, study), store):
        cols, filled = reader.collect_partial()
        np.testing.assert_array_equal(filled, [1, 1, 1, 0, 0, 0, 1, 1])
        assert list(cols["reason"][3:6]) == [cols["reason"][3]] * 3  # pending
        assert "pending" in str(cols["reason"][3])
        np.testing.assert_array_equal(
            cols["transmittance_db"][:3], [r["transmittance_db"] for r in records[:3]]
        )
    assert not chunk.exists()
    aside = list((store.folder / "damaged").iterdir())
    assert [p.name.split(".npz.")[0] for p in aside] == ["3-6"]  # kept for inspection
    assert StudyStore(tmp_path, study).missing_ranges() == [(3, 6)]
    with pytest.raises(MissingPoints, match="3 of 8 points have no results yet"):
        StudyStore(tmp_path, study).collect()


def test_chunk_files_hold_the_digest_of_their_arrays(
    tmp_path: Path, study: Study, records: list[dict[str, Any]]
) -> None:
    from service.studies.chunks import chunk_digest

    store = _store(tmp_path, study, records)
    with np.load(store.chunk_dir / "3-6.npz") as z:
        arrays = {k: z[k] for k in z.files}
    digest = str(arrays.pop("_sha256"))
    assert len(digest) == 64 and digest == chunk_digest(arrays)
    # a chunk file written before digests (none in it) is still read: its shape is checked
    with open(store.chunk_dir / "3-6.npz", "wb") as fh:
        np.savez(fh, **arrays)
    assert StudyStore(tmp_path, study).missing_ranges() == []


def test_a_damaged_retry_flag_never_counts_as_done(
    tmp_path: Path, study: Study, records: list[dict[str, Any]]
) -> None:
    store = _store(tmp_path, study, records)
    _truncate(store.chunk_dir / "6-8.npz")
    assert StudyStore(tmp_path, study).has_retry_chunks()  # computed again, never trusted


# --------------------------------------------------------------------------- results file


def _flip_coordinate(path: Path) -> None:
    """Overwrite one coordinate value: the file stays a valid NetCDF file."""
    with netCDF4.Dataset(path, "r+") as nc:
        nc["gamma_r"][0] = 0.123
    assert float(open_results(path)["gamma_r"][0]) == 0.123


RESULTS_DAMAGE: dict[str, Callable[[Path], None]] = {
    "coordinate-overwritten": _flip_coordinate,
    "zero-bytes": lambda p: p.write_bytes(b""),
    "truncated": _truncate,
    "byte-flipped": lambda p: _flip(p, p.stat().st_size // 2),
}


def _results(tmp_path: Path, study: Study, records: list[dict[str, Any]]) -> StudyStore:
    store = _store(tmp_path, study, records)
    store.write_results(results_from_records(study, store.collect()))
    return store


def test_the_results_file_has_its_sha256_beside_it(
    tmp_path: Path, study: Study, records: list[dict[str, Any]]
) -> None:
    store = _results(tmp_path, study, records)
    digest = hashlib.sha256(store.results_path.read_bytes()).hexdigest()
    assert store.results_sum_path.read_text() == f"{digest}  results.nc\n"  # sha256sum -c
    assert store.results_status() == "ok"
    assert StudyStore(tmp_path, study).results_status() == "ok"


@pytest.mark.parametrize("damage", list(RESULTS_DAMAGE))
def test_a_damaged_results_file_is_set_aside(
    tmp_path: Path, study: Study, records: list[dict[str, Any]], damage: str
) -> None:
    store = _results(tmp_path, study, records)
    assert store.results_status() == "ok"  # checked once; the check is kept while unchanged
    RESULTS_DAMAGE[damage](store.results_path)
    assert store.results_status() == "damaged"
    assert not store.results_path.exists() and not store.results_sum_path.exists()
    aside = sorted(p.name.rsplit(".", 1)[0] for p in (store.folder / "damaged").iterdir())
    assert aside == ["results.nc", "results.nc.sha256"]
    assert store.results_status() == "missing"


def test_a_results_file_without_a_sum_is_taken_only_if_it_is_the_studys(
    tmp_path: Path, study: Study, records: list[dict[str, Any]]
) -> None:
    store = _results(tmp_path, study, records)
    text = store.results_sum_path.read_text()
    store.results_sum_path.unlink()  # a results file written before sums were kept
    assert StudyStore(tmp_path, study).results_status() == "ok"
    assert store.results_sum_path.read_text() == text  # its sum written then
    # another study's results file under this study's name, without a sum: not taken
    other = parse_study(tiny_study(name="other", num=3))
    other_store = StudyStore(tmp_path / "other", other)
    other_store.write_results(results_from_records(other, other_store._empty_partial().cols))
    shutil.copyfile(other_store.results_path, store.results_path)
    store.results_sum_path.unlink()
    assert StudyStore(tmp_path, study).results_status() == "damaged"


# --------------------------------------------------------------------------- runs heal


def test_a_damaged_results_file_is_rebuilt_from_the_point_store(
    tmp_path: Path, study: Study, reference: xr.Dataset, point_store: SqlPointStore
) -> None:
    first = run_study(study, tmp_path, serial=True, points=point_store)
    assert first.computed == 8 and not list(StudyStore(tmp_path, study).chunks())
    _flip_coordinate(first.path)
    again = run_study(study, tmp_path, serial=True, points=point_store)
    assert not again.cached and again.computed == 0 and again.reused == 8  # nothing computed
    xr.testing.assert_identical(comparable(open_results(again.path)), reference)
    assert StudyStore(tmp_path, study).results_status() == "ok"
    cached = run_study(study, tmp_path, serial=True, points=point_store)
    assert cached.cached and cached.computed == 0


def test_without_a_point_store_a_damaged_results_file_is_computed_again(
    tmp_path: Path, study: Study, reference: xr.Dataset
) -> None:
    first = run_study(study, tmp_path, serial=True)
    first.path.write_bytes(b"")
    again = run_study(study, tmp_path, serial=True)
    assert not again.cached and again.computed == 8
    xr.testing.assert_identical(comparable(open_results(again.path)), reference)


def _cancel_after(chunks: int, ranges: list[tuple[int, int]]) -> Callable[[], bool]:
    return lambda: len(ranges) >= chunks


@pytest.mark.parametrize("with_store", [False, True], ids=["no-point-store", "point-store"])
def test_a_resume_computes_only_the_damaged_chunks_points(
    tmp_path: Path, study: Study, reference: xr.Dataset, with_store: bool,
    point_store: SqlPointStore,
) -> None:  # fmt: skip
    points = point_store if with_store else None
    ranges: list[tuple[int, int]] = []
    on_chunk = lambda a, b, _r: ranges.append((a, b))  # noqa: E731
    cut = run_study(study, tmp_path, serial=True, chunk_size=2, points=points,
                    cancel=_cancel_after(2, ranges), on_chunk=on_chunk)  # fmt: skip
    assert cut.cancelled and ranges == [(0, 2), (2, 4)]
    store = StudyStore(tmp_path, study)
    _truncate(store.chunk_dir / "0-2.npz")
    ranges.clear()
    done = run_study(study, tmp_path, serial=True, chunk_size=2, points=points,
                     on_chunk=on_chunk)  # fmt: skip
    if with_store:  # the damaged chunk's points come from the store: only new points computed
        assert done.computed == 4 and done.reused == 4
        assert ranges == [(4, 6), (6, 8)]
    else:  # the damaged chunk's points and the new ones; the intact chunk's are not
        assert done.computed == 6 and done.reused == 2
        assert ranges == [(0, 2), (4, 6), (6, 8)]
    xr.testing.assert_identical(comparable(open_results(done.path)), reference)
    assert [p.name.split(".npz.")[0] for p in (store.folder / "damaged").iterdir()] == ["0-2"]


def test_a_chunk_damaged_during_the_run_is_computed_again_before_collation(
    tmp_path: Path, study: Study, reference: xr.Dataset
) -> None:
    ranges: list[tuple[int, int]] = []
    store = StudyStore(tmp_path, study)

    def on_chunk(a: int, b: int, _records: list[dict[str, Any]]) -> None:
        ranges.append((a, b))
        if (a, b) == (6, 8) and ranges.count((6, 8)) == 1:  # the last chunk, the first time
            _truncate(store.chunk_dir / "2-4.npz")  # written (and held) by this run

    summary = run_study(study, tmp_path, serial=True, chunk_size=2, on_chunk=on_chunk)
    assert ranges == [(0, 2), (2, 4), (4, 6), (6, 8), (2, 4)]  # 2-4 once more, nothing else
    xr.testing.assert_identical(comparable(open_results(summary.path)), reference)
