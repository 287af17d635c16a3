"""``service.local.run``: a study (file, shipped name, dict) run in this process, returned as
an xarray Dataset, with the data dir and point store of ``impactcell run``."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

from service.local import run
from service.studies.dataset import open_results
from service.studies.schema import StudyError
from service.studies.shipped import ShippedStudyError
from tests.service.helpers import comparable, tiny_study


@pytest.mark.slow  # runs a (small) study
def test_a_dict_runs_serially_into_the_data_dir_and_a_second_call_reads_it(
    tmp_path: Path,
) -> None:
    d = tiny_study(num=4)  # 8 points
    seen: list[tuple[int, int]] = []
    ds = run(d, data_dir=tmp_path / "data", serial=True, progress=lambda a, b: seen.append((a, b)))
    assert isinstance(ds, xr.Dataset)
    assert dict(ds.sizes) == {"gap": 2, "gamma_r": 4, "stop": 2}
    assert float(ds["theta"]) == 0.3 and not bool(ds["failed"].any())
    assert np.isfinite(ds["transmittance_db"].values).all()
    assert seen and seen[-1] == (8, 8)
    results = tmp_path / "data" / "studies" / ds.attrs["study_id"] / "results.nc"
    assert results.is_file()
    xr.testing.assert_identical(ds, open_results(results))
    # The same study from a file: the finished results file, nothing computed again.
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(d))
    stamp = results.stat().st_mtime_ns
    again = run(f, data_dir=tmp_path / "data", serial=True)
    assert results.stat().st_mtime_ns == stamp
    xr.testing.assert_identical(again, ds)


@pytest.mark.slow  # runs a (small) study
def test_the_data_dir_comes_from_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("IMPACTCELL_DATA_DIR", str(tmp_path / "env-data"))
    ds = run(tiny_study(num=2, gaps=(0.1,)), serial=True)
    assert (tmp_path / "env-data" / "studies" / ds.attrs["study_id"] / "results.nc").is_file()


def test_bad_studies_are_errors_naming_every_problem(tmp_path: Path) -> None:
    d = tiny_study()
    d["grid"]["gamma_r"]["num"] = 0
    d["colour"] = "blue"
    with pytest.raises(StudyError) as err:
        run(d, data_dir=tmp_path, serial=True)
    text = str(err.value)
    assert "grid.gamma_r.num" in text and "colour: unknown key" in text
    with pytest.raises(ShippedStudyError, match="quick"):  # the message lists the shipped ones
        run("no-such-study", data_dir=tmp_path, serial=True)
    with pytest.raises(ValueError, match="more than the limit of 5"):
        run(tiny_study(), data_dir=tmp_path, serial=True, max_points=5)
    assert not (tmp_path / "studies").exists()  # nothing ran


@pytest.mark.slow
def test_the_documented_call_runs_a_study_file_on_the_embedded_cluster(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The Python block of docs/studies.md "Without the service", as written, in a folder
    # holding mycell.yaml.
    text = (Path(__file__).resolve().parents[2] / "docs" / "studies.md").read_text()
    section = text.split("## Without the service", 1)[1].split("\n## ", 1)[0]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("IMPACTCELL_DATA_DIR", str(tmp_path / "cluster"))
    Path("mycell.yaml").write_text(yaml.safe_dump(tiny_study(num=6)))
    scope: dict[str, object] = {}
    exec(compile(code, "docs/studies.md", "exec"), scope)
    ds = scope["ds"]
    assert isinstance(ds, xr.Dataset)
    assert Path("effect.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ref = run("mycell.yaml", data_dir=tmp_path / "serial", serial=True)
    xr.testing.assert_identical(comparable(ds), comparable(ref))
    assert os.path.isfile(tmp_path / "cluster" / "studies" / ds.attrs["study_id"] / "results.nc")
