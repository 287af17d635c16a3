"""``impactcell plot``: the service's figures from a results file or a study id, no service.

The study's results file is written from synthetic points (no point is simulated); the service's
app, opened on the same data dir (no job runner), draws its ``/plots`` from that file, so the
two can be compared byte for byte (SVG output is reproducible).
"""

from __future__ import annotations

import inspect
import json
import typing
from collections.abc import Iterator
from pathlib import Path

import pytest

from service.analysis.figures import KINDS
from service.api.routes import results as results_route
from service.cli.study import PLOT_KINDS
from service.studies.dataset import results_from_records
from tests.service.api.test_hysteresis import finish, sweep_results
from tests.service.api.test_results import QUICK, Served, impact_record
from tests.service.helpers import run_cli


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    """A finished gamma_r × gap × theta study (36 points: every third impacts, 2.5 dB more
    attenuation than without stops), served by the app without its job runner."""
    app = Served(tmp_path_factory.mktemp("plot"), QUICK)
    try:
        app.store.write_chunk(0, 36, [impact_record(i) for i in range(36)])
        finish(app, results_from_records(app.study, app.store.collect_partial()[0]))
        app.file = app.store.results_path  # type: ignore[attr-defined]
        app.data = app.settings.data_dir  # type: ignore[attr-defined]
        yield app
    finally:
        app.close()


def test_the_kinds_are_those_of_the_figures_and_of_the_route() -> None:
    assert set(PLOT_KINDS) == set(KINDS)
    # the route's signature as FastAPI reads it (admission's wrapper resolves the annotations)
    kind = inspect.signature(results_route.plot).parameters["kind"].annotation
    route_kinds = typing.get_args(kind)
    assert set(route_kinds) == set(KINDS)


@pytest.mark.parametrize(
    ("kind", "options", "query"),
    [
        ("bandgap", [], {}),
        ("transmittance", ["--sel", "theta=0.3"], {"theta": "0.3"}),
        ("impact-effect", [], {}),
        ("effective-mass", ["--x", "gamma_r", "--sel", "gap=0.5"], {"x": "gamma_r", "gap": "0.5"}),
        ("bandgap", ["--variable", "transmittance_linear_db", "--threshold-db", "-3"],
         {"variable": "transmittance_linear_db", "threshold_db": "-3"}),
    ],
)  # fmt: skip
def test_the_same_figure_as_the_service_by_file_or_by_id(
    study: Served, tmp_path: Path, kind: str, options: list[str], query: dict[str, str]
) -> None:
    served = study.tc.get(f"/studies/{study.id}/plots/{kind}.svg", params=query)
    assert served.status_code == 200, served.text
    by_file = tmp_path / "file.svg"
    out = run_cli("plot", str(study.file), "--kind", kind, "--out", str(by_file), *options)
    assert out.returncode == 0, out.stderr
    assert by_file.read_bytes() == served.content
    by_id = tmp_path / "id.svg"
    out = run_cli("plot", study.id, "--data-dir", str(study.data), "--kind", kind,
                  "--out", str(by_id), *options)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert by_id.read_bytes() == served.content
    # stdout names what the service's header says was fixed by default
    fixed = json.loads(served.headers["x-impactcell-fixed"])
    assert out.stdout.startswith(f"{by_id}  {kind} over {fixed['x']}")
    for name, value in fixed["fixed"].items():
        assert f"{name} = {value}" in out.stdout


def test_the_hysteresis_of_a_sweep_is_the_services(tmp_path: Path) -> None:
    app = Served(tmp_path, {**QUICK, "grid": {**QUICK["grid"], "theta": 0.1}})
    try:
        finish(app, sweep_results())
        served = app.get("/plots/hysteresis.svg", tol_db=0.01, gap=0.5)
    finally:
        app.close()
    assert served.status_code == 200, served.text
    results = str(app.store.results_path)
    out = run_cli("plot", results, "--kind", "hysteresis", "--tol-db", "0.01", "--sel", "gap=0.5",
                  "--out", str(tmp_path / "h.svg"))  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "h.svg").read_bytes() == served.content
    assert out.stdout.startswith(f"{tmp_path / 'h.svg'}  hysteresis over gamma_r")
    bad = run_cli("plot", results, "--kind", "hysteresis", "--jump-db", "0",
                  "--out", str(tmp_path / "j.svg"))  # fmt: skip
    assert bad.returncode == 2 and "--jump-db 0.0 must be positive" in bad.stderr


def test_impact_effect_is_the_bandgap_map_of_the_impact_effect(
    study: Served, tmp_path: Path
) -> None:
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    assert (
        run_cli("plot", str(study.file), "--kind", "impact-effect", "--out", str(a)).returncode == 0
    )
    assert run_cli("plot", str(study.file), "--variable", "impact_effect_db",
                   "--out", str(b)).returncode == 0  # fmt: skip
    assert a.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert a.read_bytes() == b.read_bytes()
    served = study.tc.get(f"/studies/{study.id}/plots/impact-effect.png")
    assert served.status_code == 200 and served.headers["content-type"] == "image/png"


def test_a_map_prints_the_band_edges_the_service_finds(study: Served, tmp_path: Path) -> None:
    from service.cli.service import _spans

    out = run_cli("plot", str(study.file), "--kind", "impact-effect", "--sel", "theta=0.3",
                  "--out", str(tmp_path / "e.png"))  # fmt: skip
    assert out.returncode == 0, out.stderr
    doc = study.tc.get(
        f"/studies/{study.id}/bandgap", params={"variable": "impact_effect_db", "theta": 0.3}
    ).json()
    lines = out.stdout.splitlines()
    assert lines[1] == f"bands: {doc['threshold']['meaning']}"
    assert lines[2:] == [
        f"  gap {row['y']:g}: gamma_r in {_spans(row['bands'])}" for row in doc["edges"]
    ]
    assert len(lines[2:]) == 3  # one line per gap
    assert all(" in none" not in line for line in lines[2:])  # every gap has its bands


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--out", "x.jpg"], "--out x.jpg: the file name must end in .png or .svg"),
        (["--sel", "theta"], "--sel 'theta' is not NAME=VALUE"),
        (["--sel", "theta=0.4"], "theta=0.4 is not a coordinate value; values are 0.1, 0.3 "
         "(use --nearest)"),
        (["--variable", "nope"], "--variable 'nope' cannot be mapped"),
        (["--kind", "hysteresis"], "no hysteresis"),
        (["--x", "sigma"], "sigma"),
        (["--threshold-db", "inf"], "argument --threshold-db: must be a finite number"),
    ],
)  # fmt: skip
def test_bad_options_exit_2_naming_the_flag_and_write_nothing(
    study: Served, tmp_path: Path, args: list[str], message: str
) -> None:
    target = [] if args[0] == "--out" else ["--out", str(tmp_path / "f.png")]
    out = run_cli("plot", str(study.file), *args, *target)
    assert out.returncode == 2
    assert message in out.stderr and out.stderr.count("error:") == 1, out.stderr
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "f.png").exists()


def test_a_study_id_without_results_or_a_file_that_is_not_results(
    study: Served, tmp_path: Path
) -> None:
    out = run_cli("plot", "0123456789abcdef0123", "--data-dir", str(study.data))
    assert out.returncode == 2
    assert "study 0123456789abcdef0123 has no results file in" in out.stderr
    other = tmp_path / "other.nc"
    import xarray as xr

    xr.Dataset({"a": ("x", [1.0, 2.0])}).to_netcdf(other)
    out = run_cli("plot", str(other))
    assert out.returncode == 2 and "is not an impactcell results file" in out.stderr
    out = run_cli("plot", str(tmp_path / "missing.nc"))
    assert out.returncode == 2 and "no such results file" in out.stderr
