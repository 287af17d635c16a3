"""The nightly regression suite: loading, comparison, baselines, reports and the CLI.

Most tests use a tiny suite written into a temporary folder and run serially (seconds). The
shipped suite runs against the shipped baselines in one ``slow`` test.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import xarray as xr

from service.cli import main
from service.regression.compare import compare
from service.regression.report import NightlyReport
from service.regression.run import (
    check_baseline_folder,
    evaluate,
    make_report,
    run_suite,
    tagged,
    write_baseline,
)
from service.regression.spec import DEFAULT_IRREGULAR, IrregularCheck, RegressionSpec
from service.regression.suite import SuiteError, load_suite, suite_folders
from service.studies.dataset import encoding, open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study
from service.studies.variables import outcome_attrs, outcome_codes, outcome_names
from tests.service.helpers import TINY, write_suite
from worker.cpu import FINGERPRINT_KEYS
from worker.simulate import SOLVER_VERSION
from worker.solvers.settings import OUTCOMES

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny suite and baselines made from it (once per module)."""
    root = tmp_path_factory.mktemp("nightly")
    write_suite(root / "suite")
    report = run_suite(
        root / "suite",
        root / "baselines",
        data_dir=root / "data",
        update_baseline=True,
        report_dir=root / "report",
        serial=True,
    )
    assert report.ok, report.to_markdown()
    assert [s.status for s in report.studies] == ["created", "created"]
    return root


@pytest.fixture
def suite(made: Path, tmp_path: Path) -> dict[str, Path]:
    """A private copy of the tiny suite and its baselines."""
    shutil.copytree(made / "suite", tmp_path / "suite")
    shutil.copytree(made / "baselines", tmp_path / "baselines")
    return {
        "suite": tmp_path / "suite",
        "baselines": tmp_path / "baselines",
        "data": tmp_path / "data",
        "report": tmp_path / "report",
    }


def _run(paths: dict[str, Path], **kw: Any) -> Any:
    return run_suite(
        paths["suite"],
        paths["baselines"],
        data_dir=paths["data"],
        report_dir=paths["report"],
        serial=True,
        **kw,
    )


def _cli(paths: dict[str, Path], *extra: str) -> int:
    return main(
        [
            "nightly",
            "--suite", str(paths["suite"]),
            "--baselines", str(paths["baselines"]),
            "--data-dir", str(paths["data"]),
            "--report", str(paths["report"]),
            "--serial", "--quiet",
            *extra,
        ]
    )  # fmt: skip


def _cli_url(paths: dict[str, Path], url: str, token: str) -> int:
    """``impactcell nightly --url``, its output checked for where the report went."""
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["nightly", "--url", url, "--token", token, "--suite", str(paths["suite"]),
                     "--baselines", str(paths["baselines"]), "--data-dir", str(paths["data"]),
                     "--quiet"])  # fmt: skip
    assert f"catalogued as {url}/regressions/" in out.getvalue(), out.getvalue()
    return code


def _perturb(path: Path) -> dict[str, Any]:
    """Move one Γ by 0.01 dB and change one response period, at two linear/periodic points."""
    ds = open_results(path)
    steady = np.argwhere(np.isin(outcome_names(ds["outcome"]), ("linear", "periodic")))
    (i, j), (k, m) = steady[0], steady[1]
    old_g = float(ds["transmittance_db"].values[i, j])
    ds["transmittance_db"].values[i, j] = old_g + 0.01
    ds["response_period"].values[k, m] = 2.0
    gamma_r, gap = ds["gamma_r"].values, ds["gap"].values
    ds.to_netcdf(path, engine="netcdf4")
    return {
        "gamma": {"gamma_r": float(gamma_r[j]), "gap": float(gap[i]), "new": old_g},
        "period": {"gamma_r": float(gamma_r[m]), "gap": float(gap[k])},
    }


# --------------------------------------------------------------------------- suite runs


def test_suite_passes_against_its_own_baselines(suite: dict[str, Path]) -> None:
    report = _run(suite)
    assert report.ok, report.to_markdown()
    assert [s.status for s in report.studies] == ["passed", "passed"]
    assert all(not s.changes for s in report.studies)
    data = json.loads((suite["report"] / "report.json").read_text())
    assert data["ok"] is True and len(data["studies"]) == 2
    md = (suite["report"] / "report.md").read_text()
    assert "# Nightly regression: PASSED" in md
    assert "| study | points | linear | periodic | irregular | unsettled | failed | status |" in md
    tiny = {s.study: s for s in report.studies}["tiny"]
    counts = tiny.counts["new"]
    assert counts["points"] == tiny.points == sum(counts[k] for k in OUTCOMES)
    assert f"| tiny | {tiny.points} | {counts['linear']} | {counts['periodic']} |" in md
    # Fresh results every run (never reused from an earlier run of the same study id).
    assert all("/nightly/" in s.results for s in report.studies)


def test_baseline_files_are_small_and_record_provenance(made: Path) -> None:
    with xr.open_dataset(made / "baselines" / "tiny.nc") as ds:
        assert set(ds.data_vars) == {
            "transmittance_db", "transmittance_db_se", "theta_eff", "outcome", "response_period",
            "floquet_multiplier", "failed", "reason",
        }  # fmt: skip
        assert ds["outcome"].attrs["flag_meanings"] == "linear periodic irregular unsettled failed"
        assert ds.attrs["solver_version"] == SOLVER_VERSION
        for key in (
            "impactcell_version", "git_commit", "solver_version", "solver_settings", "study",
            "study_id", "baseline_created", *FINGERPRINT_KEYS,
        ):  # fmt: skip
            assert ds.attrs.get(key), key
        assert ds["transmittance_db"].encoding.get("zlib") is True
        assert "stop" not in ds.coords
        assert set(ds["transmittance_db"].dims) == {"gap", "gamma_r"}


def test_perturbed_baseline_is_caught_and_reported_precisely(suite: dict[str, Path]) -> None:
    moved = _perturb(suite["baselines"] / "tiny.nc")
    report = _run(suite)
    assert not report.ok
    tiny = {s.study: s for s in report.studies}["tiny"]
    assert tiny.status == "failed"
    assert {s.study: s.status for s in report.studies}["tiny-euler"] == "passed"
    regs = tiny.regressions
    assert len(regs) == 2, [r.to_json() for r in regs]
    by_var = {r.variable: r for r in regs}

    g = by_var["transmittance_db"]
    assert g.kind == "moved"
    assert g.coords["gamma_r"] == moved["gamma"]["gamma_r"]
    assert g.coords["gap"] == moved["gamma"]["gap"]
    assert g.new == pytest.approx(moved["gamma"]["new"], abs=1e-12)
    assert g.old == pytest.approx(moved["gamma"]["new"] + 0.01, abs=1e-12)
    assert g.delta == pytest.approx(0.01, abs=1e-9)
    assert g.tolerance == "abs 0.001"

    p = by_var["response_period"]
    assert p.kind == "moved" and p.old == 2 and p.new == 1 and p.tolerance == "exact"
    assert p.coords["gamma_r"] == moved["period"]["gamma_r"]
    assert p.coords["gap"] == moved["period"]["gap"]

    md = (suite["report"] / "report.md").read_text()
    assert "# Nightly regression: FAILED" in md
    row = next(line for line in md.splitlines() if "| transmittance_db | moved" in line)
    assert f"gamma_r={moved['gamma']['gamma_r']:.8g}" in row
    assert f"gap={moved['gamma']['gap']:.8g}" in row
    assert f"{g.old:.9g}" in row and f"{g.new:.9g}" in row and "abs 0.001" in row
    data = json.loads((suite["report"] / "report.json").read_text())
    tj = next(s for s in data["studies"] if s["study"] == "tiny")
    assert tj["status"] == "failed" and tj["regressions"] == 2
    assert {c["variable"] for c in tj["changes"]} == {"transmittance_db", "response_period"}
    assert _cli(suite) == 1


def test_update_baseline_rewrites_and_reports_what_changed(suite: dict[str, Path]) -> None:
    _perturb(suite["baselines"] / "tiny.nc")
    before = open_results(suite["baselines"] / "tiny.nc").attrs["baseline_created"]
    report = _run(suite, update_baseline=True)
    assert report.ok
    tiny = {s.study: s for s in report.studies}["tiny"]
    assert tiny.status == "updated"
    assert {c.variable for c in tiny.changes} == {"transmittance_db", "response_period"}
    md = (suite["report"] / "report.md").read_text()
    assert "BASELINES UPDATED" in md and "Changes written to the baselines" in md
    after = open_results(suite["baselines"] / "tiny.nc")
    assert after.attrs["baseline_created"] >= before
    # The rewritten baselines pass.
    again = _run(suite)
    assert again.ok and [s.status for s in again.studies] == ["passed", "passed"]


def test_the_suite_computes_on_the_runners_client_with_every_methods_kernels(
    suite: dict[str, Path], monkeypatch
) -> None:
    # One place makes the cluster (one BLAS thread per worker, kernels loaded as the workers
    # start); the suite's studies use all three methods.
    import service.studies.runner as runner

    asked: list[tuple[Any, ...]] = []

    def make_client(scheduler: Any, workers: Any, *, method: Any = "event") -> Any:
        asked.append((scheduler, workers, method))
        raise RuntimeError("no cluster in this test")

    monkeypatch.setattr(runner, "make_client", make_client)
    for scheduler in (None, "tcp://127.0.0.1:8786"):
        with pytest.raises(RuntimeError, match="no cluster"):
            run_suite(suite["suite"], suite["baselines"], data_dir=suite["data"],
                      report_dir=suite["report"], scheduler=scheduler, workers=3)  # fmt: skip
    assert asked == [(None, 3, None), ("tcp://127.0.0.1:8786", 3, None)]


def test_a_missing_baseline_is_bad_usage_found_before_anything_runs(
    suite: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    (suite["baselines"] / "tiny-euler.nc").unlink()
    with pytest.raises(SuiteError, match=r"no baseline in .* for tiny-euler\.nc"):
        _run(suite)
    assert _cli(suite) == 2
    err = capsys.readouterr().err
    assert "tiny-euler.nc" in err and "--update-baseline" in err and "Traceback" not in err
    assert not suite["report"].exists() and not suite["data"].exists()  # nothing ran
    assert _cli(suite, "--update-baseline") == 0  # creating it is what --update-baseline does
    assert (suite["baselines"] / "tiny-euler.nc").is_file()
    assert _cli(suite) == 0


def test_a_baseline_folder_that_does_not_exist_is_bad_usage(
    suite: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    nowhere = tmp_path / "nonexistent"
    assert _cli({**suite, "baselines": nowhere}) == 2
    err = capsys.readouterr().err
    assert f"baseline folder {nowhere} does not exist" in err
    assert len(err.strip().splitlines()) == 1
    assert not suite["report"].exists() and not suite["data"].exists()  # nothing ran


def test_a_baseline_that_vanishes_mid_run_is_reported_not_raised(
    suite: dict[str, Path],
) -> None:
    entry = {e.stem: e for e in load_suite(suite["suite"])}["tiny-euler"]
    ds = open_results(suite["baselines"] / "tiny-euler.nc")
    (suite["baselines"] / "tiny-euler.nc").unlink()
    cmp = evaluate(entry, ds, "here", suite["baselines"])
    assert cmp.status == "missing-baseline" and "--update-baseline" in (cmp.error or "")


def test_an_unreachable_service_is_bad_usage_found_before_anything_runs(
    suite: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from service.api.server import free_port

    url = f"http://127.0.0.1:{free_port()}"  # nobody listens there
    paths = {**suite}
    argv = ["nightly", "--url", url, "--suite", str(paths["suite"]), "--baselines",
            str(paths["baselines"]), "--data-dir", str(paths["data"]), "--report",
            str(paths["report"]), "--quiet"]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"cannot reach the impactcell service at {url}" in err and "Traceback" not in err
    assert not suite["report"].exists() and not suite["data"].exists()  # nothing ran
    argv[2] = "notaurl"
    assert main(argv) == 2
    assert "--url 'notaurl' is not an http(s) URL" in capsys.readouterr().err


def test_the_markdown_report_shows_no_absolute_paths(suite: dict[str, Path]) -> None:
    _perturb(suite["baselines"] / "tiny.nc")
    entries = load_suite(suite["suite"])
    results = []
    for e in entries:
        ds = open_results(run_study(e.study, suite["data"], serial=True).path)
        if e.stem == "tiny-euler":  # gone after the check: an error that names its path
            (suite["baselines"] / "tiny-euler.nc").unlink()
        results.append(evaluate(e, ds, str(suite["report"] / "runs" / "x.nc"), suite["baselines"]))
    report = make_report(
        entries, results, suite["suite"], suite["baselines"], mode="embedded", update=False,
        started="2026-01-01T00:00:00+00:00", wall_s=1.0, report_dir=suite["report"],
    )  # fmt: skip
    md = (suite["report"] / "report.md").read_text()
    assert md == report.to_markdown()
    root = str(suite["suite"].parent)
    assert root not in md, md
    assert "Suite `suite`, baselines `baselines`" in md
    assert "no baseline baselines/tiny-euler.nc" in md
    # The JSON keeps the paths as they are (tools read it on the machine that ran it).
    data = json.loads((suite["report"] / "report.json").read_text())
    assert data["suite"] == str(suite["suite"]) and data["baselines"] == str(suite["baselines"])


def test_changed_definition_needs_an_update(suite: dict[str, Path]) -> None:
    text = TINY.replace("max_periods: 200", "max_periods: 150")
    (suite["suite"] / "tiny.yaml").write_text(text, encoding="utf-8")
    report = _run(suite)
    tiny = {s.study: s for s in report.studies}["tiny"]
    assert tiny.status == "error" and "different study definition" in (tiny.error or "")
    assert "solver.max_periods" in (tiny.error or "")


def _make_old(path: Path) -> None:
    """Rewrite a baseline as solver version 1 wrote it: no ``outcome``, version "1"."""
    ds = open_results(path).drop_vars("outcome")
    ds.attrs["solver_version"] = "1"
    ds.to_netcdf(path, engine="netcdf4", encoding=encoding(ds))


@pytest.mark.slow  # runs whole (small) studies
def test_baseline_of_an_older_solver_says_to_recut_it(
    suite: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    _make_old(suite["baselines"] / "tiny.nc")
    report = _run(suite)
    assert not report.ok
    tiny = {s.study: s for s in report.studies}["tiny"]
    assert tiny.status == "error" and not tiny.regressions
    assert "predates solver version " + SOLVER_VERSION in (tiny.error or "")
    assert "solver version 1" in (tiny.error or "")
    assert "impactcell nightly --update-baseline" in (tiny.error or "")
    assert {s.study: s.status for s in report.studies}["tiny-euler"] == "passed"
    # The old baseline's outcome is read from response_period: the counts are still there.
    assert tiny.counts["baseline"]["points"] == tiny.points
    md = (suite["report"] / "report.md").read_text()
    assert "predates solver version" in md and "--update-baseline" in md
    assert _cli(suite) == 1
    assert "predates solver version" in capsys.readouterr().out
    # Re-cut deliberately: written, and then it passes.
    assert _cli(suite, "--update-baseline") == 0
    with xr.open_dataset(suite["baselines"] / "tiny.nc") as ds:
        assert "outcome" in ds and ds.attrs["solver_version"] == SOLVER_VERSION
    assert _cli(suite) == 0


def test_url_mode_runs_fresh_through_a_real_service(
    suite: dict[str, Path], dask_address: str
) -> None:
    """URL mode against a real server on 127.0.0.1: passes, and every run is a fresh study."""
    from service.api.server import ServerThread
    from service.api.settings import Settings
    from service.client import Client

    s = Settings(host="127.0.0.1", port=0, data_dir=suite["data"] / "server",
                 scheduler=dask_address, api_token="t0k")  # fmt: skip
    server = ServerThread(s).start()
    try:
        with pytest.raises(SuiteError, match="refused the request: HTTP 401"):
            _run(suite, url=server.url, token="wrong")  # found before anything runs
        assert not suite["report"].exists()
        report = _run(suite, url=server.url, token="t0k")
        assert report.ok, report.to_markdown()
        assert report.mode == server.url
        assert "summary" in report.to_json() and "no regressions" in report.summary()
        again = _run(suite, url=server.url, token="t0k")  # at once: the same second, maybe
        assert again.ok
        with Client(server.url, token="t0k") as c:
            studies = c.list(full=True)
            # Two suite runs of two studies: four studies, none served from an earlier run;
            # each run's tag is in the definition, the description is the file's.
            assert len(studies) == 4 and all(r["status"] == "finished" for r in studies)
            tags = {r["definition"]["tag"] for r in studies}
            assert len(tags) == 2 and all(t.startswith("nightly-") for t in tags)
            assert all(r["definition"]["description"] == "" for r in studies)
            # A user's untagged submission of the same definition is a study of its own, and
            # submitting it again returns that one (cached, no second run).
            entry = load_suite(suite["suite"])[0]
            first = c.submit(entry.study.canonical())
            assert first["id"] == entry.study.id and first["id"] not in {r["id"] for r in studies}
            c.wait(first["id"], progress=False)
            assert c.submit(entry.study.canonical())["id"] == first["id"]
            assert len(c.list()) == 5
            # Both runs are catalogued on the service, beside its own nightly runs.
            regs = c.regressions()
            assert [r["trigger"] for r in regs] == ["client", "client"]
            assert all(r["ok"] is True and r["finished_at"] for r in regs)
            assert again.catalogued == f"{server.url}/regressions/{regs[0]['id']}"
            assert report.catalogued == f"{server.url}/regressions/{regs[1]['id']}"
            stored = c.regression(regs[0]["id"])
            assert stored["report"]["summary"] == again.summary()
            assert stored["started_at"][:19] == again.started[:19]
            assert "# Nightly regression: PASSED" in stored["markdown"]
            assert str(suite["suite"].parent) not in stored["markdown"]
        # The command line says where it catalogued the report.
        assert _cli_url(suite, server.url, "t0k") == 0
        with Client(server.url, token="t0k") as c:
            newest = c.regressions()[0]
        assert newest["trigger"] == "client" and newest["ok"] is True
    finally:
        server.stop()


def test_a_tagged_run_is_compared_with_untagged_baselines(
    suite: dict[str, Path], tmp_path: Path
) -> None:
    entry = {e.stem: e for e in load_suite(suite["suite"])}["tiny"]
    study = tagged(entry.study, "nightly-20260101T020000Z")
    assert study.tag == "nightly-20260101T020000Z" and study.id != entry.study.id
    assert {**study.canonical(), "tag": None} == {**entry.study.canonical(), "tag": None}
    ds = open_results(run_study(study, suite["data"], serial=True).path)
    cmp = evaluate(entry, ds, "here", suite["baselines"])
    assert cmp.status == "passed", cmp.to_json()
    assert not any("tag" in n for n in cmp.notes)  # a label, like name and description
    # A baseline cut from a tagged run records the untagged definition and id.
    write_baseline(ds, tmp_path / "b.nc", entry.spec)
    with xr.open_dataset(tmp_path / "b.nc") as b:
        assert json.loads(b.attrs["study"]) == entry.study.canonical()
        assert b.attrs["study_id"] == entry.study.id


def test_suite_folders_default_to_the_shipped_suite(tmp_path: Path) -> None:
    assert suite_folders() == (ROOT / "studies" / "nightly", ROOT / "studies" / "baselines")
    assert suite_folders(tmp_path / "s") == (tmp_path / "s", tmp_path / "baselines")
    assert suite_folders(tmp_path / "s", tmp_path / "b") == (tmp_path / "s", tmp_path / "b")
    assert suite_folders(None, tmp_path / "b") == (ROOT / "studies" / "nightly", tmp_path / "b")


def test_an_installed_package_never_writes_its_shipped_baselines(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import service.regression.run as run_module

    monkeypatch.setattr(run_module, "in_source_checkout", lambda: False)
    args = ["nightly", "--update-baseline", "--data-dir", str(tmp_path / "d"), "--quiet"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "installed package's copy of the shipped baselines" in err
    assert "--baselines DIR" in err and str(ROOT / "studies" / "baselines") in err
    assert not (tmp_path / "d").exists()  # refused before anything ran
    check_baseline_folder(tmp_path / "b", update=True)  # an explicit folder is fine
    check_baseline_folder(ROOT / "studies" / "baselines", update=False)  # reading is fine


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("block", "expected"),
    [
        (
            "  tolerances:\n    transmittance_db: {absolute: 1.0e-3}\n",
            "regression.tolerances.transmittance_db.absolute: unknown key",
        ),
        ("  tolerances:\n    gamma: {abs: 1.0e-3}\n", "unknown variable 'gamma'"),
        (
            "  tolerances:\n    theta_eff_mean: {abs: 1.0e-3}\n",
            "unknown variable 'theta_eff_mean' (replaced by theta_eff_slope in solver version 2)",
        ),
        ("  tolerances:\n    outcome: {exact: true}\n", "unknown variable 'outcome'"),
        (
            "  tolerances:\n    response_period: {exact: true, abs: 1}\n",
            "regression.tolerances.response_period: give exact: true or abs/rel, not both",
        ),
        ("  tolerances:\n    theta_eff: {}\n", "give abs and/or rel, or exact: true"),
        ("  irregular:\n    transmittance_db: {median: 1}\n", "median: unknown key"),
        ("  irregular:\n    response_period: {median_shift: 1}\n", "unknown variable"),
        ("  thresholds: {}\n", "regression.thresholds: unknown key"),
        (
            "  irregular:\n    transmittance_db: {quantile_shift: 1, quantiles: [1.5]}\n",
            "quantiles must be in [0, 1]",
        ),
    ],
)
def test_bad_regression_block_names_the_field(tmp_path: Path, block: str, expected: str) -> None:
    folder = tmp_path / "suite"
    folder.mkdir()
    (folder / "bad.yaml").write_text(TINY.split("regression:")[0] + "regression:\n" + block)
    with pytest.raises(SuiteError) as err:
        load_suite(folder)
    assert expected in str(err.value)
    assert "bad.yaml" in str(err.value)


def test_bad_suite_exits_2_with_a_message(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "suite"
    folder.mkdir()
    bad = TINY.replace("{abs: 1.0e-3, rel", "{absolute: 1.0e-3, rel")
    (folder / "bad.yaml").write_text(bad)
    (folder / "worse.yaml").write_text(TINY.replace("gap: [0.1, 0.5]", "gap: [0.1, -1]"))
    paths = {"suite": folder, "baselines": tmp_path / "b", "data": tmp_path / "d",
             "report": tmp_path / "r"}  # fmt: skip
    assert _cli(paths) == 2
    msg = capsys.readouterr().err
    assert "regression.tolerances.theta_eff.absolute: unknown key" in msg
    assert re.search(r"worse\.yaml: grid\.gap: .*must be .*-1", msg)
    assert not (tmp_path / "r").exists()  # nothing ran
    assert _cli({**paths, "suite": tmp_path / "nowhere"}) == 2
    assert "does not exist" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert _cli({**paths, "suite": empty}) == 2
    assert "no study files" in capsys.readouterr().err


def test_regression_block_does_not_change_the_study_id(tmp_path: Path) -> None:
    folder = write_suite(tmp_path / "suite")
    entry = {e.stem: e for e in load_suite(folder)}["tiny"]
    import yaml

    plain = yaml.safe_load(TINY)
    del plain["regression"]
    assert entry.study.id == parse_study(plain).id
    # What URL mode submits parses back to the same study.
    assert parse_study(entry.study.canonical()).id == entry.study.id
    assert set(entry.spec.effective_tolerances()) == {
        "transmittance_db", "response_period", "floquet_multiplier", "theta_eff",
    }  # fmt: skip
    assert entry.spec.effective_irregular() == DEFAULT_IRREGULAR


# --------------------------------------------------------------------------- compare()


def _synthetic(
    gamma: np.ndarray,
    period: np.ndarray,
    failed: np.ndarray | None = None,
    outcome: list[str] | None = None,
    **attrs: Any,
) -> xr.Dataset:
    """A results-like dataset; the outcome defaults to failed / periodic (period > 0) /
    irregular (period 0)."""
    n = gamma.size
    failed = np.zeros(n, dtype=bool) if failed is None else failed
    if outcome is None:
        outcome = [
            "failed" if f else ("periodic" if p > 0 else "irregular")
            for f, p in zip(failed, period, strict=True)
        ]
    g = np.where(failed, np.nan, gamma)
    rp = np.where(failed, np.nan, period).astype(float)
    fm = np.where(np.asarray(period) > 0, 0.5, np.nan)  # an orbit's multiplier, unchanged
    return xr.Dataset(
        {
            "transmittance_db": ("gamma_r", g),
            "outcome": ("gamma_r", outcome_codes(outcome), outcome_attrs()),
            "response_period": ("gamma_r", rp),
            "floquet_multiplier": ("gamma_r", fm),
            "failed": ("gamma_r", failed),
        },
        coords={"gamma_r": np.linspace(4.0, 5.0, n), "gap": 0.1},
        attrs=attrs,
    )


def test_irregular_distribution_check_catches_a_shift() -> None:
    rng = np.random.default_rng(6)
    n = 40
    base = rng.uniform(-25.0, -18.0, n)
    irregular = np.zeros(n)
    old = _synthetic(base, irregular)
    # Unshifted: every point moves by up to ±1.5 dB (a chaotic response), the median not at all.
    noise = rng.uniform(-1.5, 1.5, n)
    noise -= np.median(noise)
    same = compare(_synthetic(base + noise, irregular), old)
    assert same.status == "passed", [d.to_json() for d in same.distribution]
    assert {d.check for d in same.distribution} == {"median_shift", "quantile_shift"}
    assert all(d.n_paired == n for d in same.distribution)
    # Shifted by 1.5 dB: caught by both checks, and no pointwise change is reported.
    shifted = compare(_synthetic(base + noise + 1.5, irregular), old)
    assert shifted.status == "failed"
    assert {d.check for d in shifted.failed_checks} == {"median_shift", "quantile_shift"}
    assert not shifted.changes
    med = next(d for d in shifted.distribution if d.check == "median_shift")
    assert med.value == pytest.approx(1.5)
    # A two-sample KS test on request.
    spec = RegressionSpec(irregular={"transmittance_db": IrregularCheck(ks_pvalue=0.01)})
    assert compare(_synthetic(base + noise, irregular), old, spec).status == "passed"
    far = compare(_synthetic(base + 8.0, irregular), old, spec)
    assert {d.check for d in far.failed_checks} == {"ks_pvalue"}


def test_irregular_check_skips_too_few_points() -> None:
    g = np.array([-20.0, -21.0, -22.0, -23.0])
    rp = np.array([1, 0, 0, 1])
    out = compare(_synthetic(g + [0, 3, 3, 0], rp), _synthetic(g, rp))
    assert out.status == "passed"
    assert all(d.skipped and d.value is None for d in out.distribution)


def test_outcome_class_changes_are_regressions() -> None:
    g = np.array([-10.0, -11.0, -12.0, -13.0, -14.0, -15.0, -16.0, -17.0])
    rp = np.array([1, 1, 2, 1, 1, 1, 0, 0])
    old = _synthetic(
        g, rp, failed=np.array([0, 0, 0, 0, 1, 0, 0, 0], dtype=bool),
        outcome=["periodic", "periodic", "periodic", "periodic", "failed", "linear", "irregular",
                 "unsettled"],
    )  # fmt: skip
    new = _synthetic(
        g + [0.0005, 3, 0, 0, 0, 0, 0, 5],  # within 1e-3 dB; the rest are not compared
        np.array([1, 0, 2, 1, 3, 1, 0, 0]),
        failed=np.array([0, 0, 0, 1, 0, 0, 0, 0], dtype=bool),
        outcome=["linear", "irregular", "periodic", "failed", "periodic", "periodic",
                 "unsettled", "unsettled"],
    )  # fmt: skip
    new["reason"] = ("gamma_r", np.array(["", "", "", "euler scheme is unstable", "", "",
                                          "the budget ran out", ""], object))  # fmt: skip
    out = compare(new, old, study="synthetic")
    # Linear <-> periodic is one class (compared pointwise): points 0 and 5 did not move.
    moved = {round(c.coords["gamma_r"], 6): c for c in out.changes}
    step = 1.0 / 7
    assert sorted(moved) == [round(4.0 + k * step, 6) for k in (1, 3, 4, 6)]
    assert all(c.kind == "outcome" and c.variable == "outcome" for c in out.changes)
    assert all(c.regression for c in out.changes)
    pairs = [(c.old, c.new) for c in out.changes]
    assert pairs == [
        ("periodic", "irregular"), ("periodic", "failed"), ("failed", "periodic"),
        ("irregular", "unsettled"),
    ]  # fmt: skip
    assert out.changes[1].note == "euler scheme is unstable"
    assert out.changes[3].note == "the budget ran out"
    assert out.status == "failed" and len(out.regressions) == 4
    assert any("1 points unsettled in both runs" in n for n in out.notes)
    md = NightlyReport([out], "s", "b", "embedded", False, "now").to_markdown()
    assert "| synthetic | gamma_r=4.1428571 | outcome | outcome | periodic | irregular | - |" in md

    # Missing values: missing == missing, missing vs value is a change.
    g2 = g.copy()
    spec = RegressionSpec.model_validate({"tolerances": {"transmittance_db": {"abs": 1e-3}}})
    a, b = _synthetic(g, rp), _synthetic(g2, rp)
    a["transmittance_db"].values[0] = np.nan
    b["transmittance_db"].values[0] = np.nan
    assert compare(b, a, spec).status == "passed"
    b["transmittance_db"].values[0] = -10.0
    moved_pts = compare(b, a, spec).regressions
    assert len(moved_pts) == 1 and moved_pts[0].old is None and moved_pts[0].new == -10.0


def test_an_old_baseline_is_read_not_crashed_on() -> None:
    g = np.array([-10.0, -11.0, -12.0])
    rp = np.array([1, 0, 1])
    new = _synthetic(g, rp, solver_version=SOLVER_VERSION)
    old = _synthetic(g + [0.0, 0.0, 0.5], rp, solver_version="1").drop_vars("outcome")
    out = compare(new, old, study="old")
    assert out.status == "error" and "predates solver version" in (out.error or "")
    assert "--update-baseline" in (out.error or "")
    # What differs is listed for information only (period 0 read as irregular: same class).
    assert [(c.kind, c.variable) for c in out.changes] == [("moved", "transmittance_db")]
    assert not out.regressions and not out.distribution
    assert out.counts["baseline"]["irregular"] == 1 and out.counts["baseline"]["periodic"] == 2
    # Same version on both sides but no outcome in the baseline: still not comparable.
    out = compare(new, old.assign_attrs(solver_version=SOLVER_VERSION))
    assert out.status == "error" and "has no outcome variable" in (out.error or "")


def test_relative_tolerance() -> None:
    g = np.array([-10.0, -100.0])
    rp = np.array([1, 1])
    spec = RegressionSpec.model_validate({"tolerances": {"transmittance_db": {"rel": 1e-3}}})
    new = _synthetic(g * (1 + 5e-4) + [0, 0], rp)
    assert compare(new, _synthetic(g, rp), spec).status == "passed"
    new = _synthetic(g * (1 + 2e-3), rp)
    assert len(compare(new, _synthetic(g, rp), spec).regressions) == 2


def test_a_moved_or_new_floquet_multiplier_is_a_change() -> None:
    # A multiplier moves with how its matrix is computed (finite differences against the exact
    # monodromy matrix: up to ~1e-2), and one that appears or goes is a change too.
    g, rp = np.array([-10.0, -11.0, -12.0]), np.array([1, 1, 1])
    base = _synthetic(g, rp)
    same = _synthetic(g, rp)
    same["floquet_multiplier"].values[0] += 5e-7
    assert compare(same, base).status == "passed"
    moved = _synthetic(g, rp)
    moved["floquet_multiplier"].values[1] += 1e-5
    moved["floquet_multiplier"].values[2] = np.nan  # a multiplier that is no longer computed
    out = compare(moved, base)
    assert out.status == "failed"
    assert sorted((c.variable, c.kind) for c in out.regressions) == [
        ("floquet_multiplier", "moved"), ("floquet_multiplier", "moved"),
    ]  # fmt: skip


def test_definition_check_tolerates_new_default_keys() -> None:
    g, rp = np.array([-10.0, -11.0]), np.array([1, 1])
    base = {"name": "a", "solver": {"max_periods": 200}}
    old = _synthetic(g, rp, study=json.dumps(base))
    added = {"name": "b", "solver": {"max_periods": 200, "new_option": True}}
    out = compare(_synthetic(g, rp, study=json.dumps(added)), old)
    assert out.status == "passed" and any("solver.new_option" in n for n in out.notes)
    changed = {"name": "a", "solver": {"max_periods": 300}}
    out = compare(_synthetic(g, rp, study=json.dumps(changed)), old)
    assert out.status == "error" and "solver.max_periods" in (out.error or "")


def test_grid_mismatch_is_an_error() -> None:
    g = np.array([-10.0, -11.0, -12.0])
    old = _synthetic(g, np.ones(3))
    new = _synthetic(np.r_[g, -13.0], np.ones(4))
    out = compare(new, old)
    assert out.status == "error" and "gamma_r" in (out.error or "")


# --------------------------------------------------------------------------- the shipped suite


def test_shipped_suite_covers_what_it_claims() -> None:
    entries = load_suite(ROOT / "studies" / "nightly")
    studies = [e.study for e in entries]
    assert {s.model.coupling for s in studies} == {"paper", "full"}
    # Both time-stepping solvers set explicitly; table1 runs on the default (event).
    assert {s.solver.method for s in studies} == {"event", "exponential", "euler"}
    assert any(s.is_physical for s in studies)
    axes = [s.axes() for s in studies]
    assert any("g1" in a and set(a["g1"]) != set(a["g2"]) for a in axes)  # asymmetric gaps
    zero = [np.any(a.get("gap", a.get("g1", np.ones(1))) == 0) for a in axes]
    assert any(zero)
    total = sum(s.size for s in studies)
    assert 1000 <= total <= 5000
    for e in entries:  # every study has a baseline made from its current definition
        path = ROOT / "studies" / "baselines" / f"{e.stem}.nc"
        assert path.is_file(), path
        with xr.open_dataset(path) as ds:
            assert ds.attrs["solver_version"] == SOLVER_VERSION, (
                f"{path.name} predates solver version {SOLVER_VERSION}: re-cut the baselines "
                "with `impactcell nightly --update-baseline`"
            )
            assert json.loads(ds.attrs["study"]) == e.study.canonical()


@pytest.mark.slow
def test_shipped_suite_passes_against_shipped_baselines(tmp_path: Path) -> None:
    # The defaults: the shipped suite and baselines, through the package-data accessor.
    report = run_suite(
        data_dir=tmp_path / "data",
        report_dir=tmp_path / "report",
        workers=2,
    )
    assert report.ok, report.to_markdown()
    assert report.suite == str(ROOT / "studies" / "nightly")
    assert report.baselines == str(ROOT / "studies" / "baselines")


def test_a_moved_point_of_a_sweep_baseline_is_named_by_its_direction_and_start() -> None:
    """The shipped sweep baseline: labels (direction, initial) compare as labels, and a moved
    point is reported with them."""
    from service.studies.shipped import baselines_dir

    base = open_results(baselines_dir() / "sweep.nc")
    assert compare(base, base, study="sweep").status == "passed"
    moved = base.copy(deep=True)
    periodic = (moved["response_period"] > 0) & ~moved["failed"].astype(bool)
    where = np.argwhere(periodic.transpose("initial", "direction", "gamma_r").values)[0]
    i, d, g = (int(k) for k in where)
    moved["transmittance_db"][i, d, g] += 0.01
    cmp = compare(moved, base, study="sweep")
    assert cmp.status == "failed" and len(cmp.changes) == 1
    c = cmp.changes[0]
    assert c.variable == "transmittance_db"
    assert c.coords["direction"] == str(base["direction"].values[d])
    assert c.coords["initial"] == str(base["initial"].values[i])
    assert c.coords["gamma_r"] == pytest.approx(float(base["gamma_r"].values[g]))


def test_outcome_changes_at_sensitive_points_are_listed_not_counted() -> None:
    from service.regression.compare import SENSITIVE_MULTIPLIER
    from worker.solvers.engine import TRANSIENT_NOTE

    g = np.array([-10.0, -11.0, -12.0, -13.0])
    old = _synthetic(g, np.array([1, 1, 1, 1]), outcome=["linear", "periodic", "periodic",
                                                          "periodic"])  # fmt: skip
    old["floquet_multiplier"].values[:] = [np.nan, 0.5, SENSITIVE_MULTIPLIER + 0.005, 0.5]
    new = _synthetic(g, np.array([0, 0, 0, 1]), outcome=["irregular", "irregular", "irregular",
                                                          "periodic"])  # fmt: skip
    new["reason"] = ("gamma_r", np.array([f"impact-free response admissible too: {TRANSIENT_NOTE}",
                                          "", "", ""], object))  # fmt: skip
    out = compare(new, old, study="synthetic")
    by = {c.old + ">" + c.new + str(i): c for i, c in enumerate(out.changes)}
    assert len(out.changes) == 3
    # Transient chaos that may die out, and an orbit next to a bifurcation: listed, said why.
    assert not by["linear>irregular0"].regression
    assert by["linear>irregular0"].note.startswith("sensitive: may be transient chaos")
    assert not by["periodic>irregular2"].regression
    assert "Floquet multiplier near 1" in by["periodic>irregular2"].note
    # A well-attracting orbit that became irregular is a regression.
    assert by["periodic>irregular1"].regression
    assert len(out.regressions) == 1 and out.status == "failed"
    assert any("2 outcome changes at sensitive points" in n for n in out.notes)
    md = NightlyReport([out], "s", "b", "embedded", False, "now").to_markdown()
    assert "outcome (sensitive, not a regression)" in md


def test_irregular_points_are_compared_within_their_combined_error_bars() -> None:
    n = 6
    g = np.linspace(-25.0, -20.0, n)
    irregular = np.zeros(n)
    old, new = _synthetic(g, irregular), _synthetic(g.copy(), irregular)
    se = np.full(n, 0.1)
    old["transmittance_db_se"] = ("gamma_r", se)
    new["transmittance_db_se"] = ("gamma_r", se)
    # 4 combined standard errors are 0.566 dB: 0.5 dB is within, 0.6 dB is not.
    new["transmittance_db"].values[[1, 4]] += [0.5, -0.6]
    out = compare(new, old, study="synthetic")
    assert [(c.kind, round(c.coords["gamma_r"], 6)) for c in out.regressions] == [
        ("moved", round(float(old["gamma_r"][4]), 6))
    ]
    assert out.regressions[0].tolerance.startswith("within 4 combined standard errors")
    # A wider error bar on the new run: within again.
    new["transmittance_db_se"].values[4] = 0.2
    assert not compare(new, old).regressions
    # A baseline without error bars: said, not compared point by point.
    out = compare(new, old.drop_vars("transmittance_db_se"))
    assert not out.regressions
    assert any("transmittance_db_se not in both" in note for note in out.notes)
    # The baseline keeps the error bar and the reason the comparison reads.
    assert {"transmittance_db_se", "reason"} <= set(RegressionSpec().variables())
