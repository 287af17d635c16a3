"""``impactcell point --cells N``: chains of N cells on the command line (docs/chains.md)."""

from __future__ import annotations

import json
import math

import pytest

from tests.service.cli.test_errors import one_error_line
from tests.service.helpers import run_cli as run
from worker.model import CellParams
from worker.model.chain import ChainParams, chain_linear_transmittance_db, stop_bands


def _without_wall_time(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if not line.startswith("wall time"))


def test_one_cell_prints_what_point_prints() -> None:
    args = ("point", "--gamma-r", "0.85", "--gap", "0.2")
    plain, one = run(*args), run(*args, "--cells", "1")
    assert plain.returncode == one.returncode == 0, one.stderr
    assert _without_wall_time(one.stdout) == _without_wall_time(plain.stdout)
    plain, one = run(*args, "--json"), run(*args, "--cells", "1", "--json")
    d_plain, d_one = json.loads(plain.stdout), json.loads(one.stdout)
    d_plain.pop("wall_s"), d_one.pop("wall_s")
    assert d_one == d_plain and "cells" not in d_one


def test_a_chain_reports_every_cells_linear_transmittance() -> None:
    out = run("point", "--cells", "3", "--gaps", "0.1,0.2,0.3", "--coupling", "full", "--json")
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d["cells"] == 3 and d["method"] == "euler" and not d["failed"]
    assert "method: euler (the method that runs chains of N > 1 cells)" in out.stderr
    assert math.isfinite(d["transmittance_db"])
    cell = CellParams(theta=0.3, sigma=0.05, gamma_s=1.0, gamma_r=1.0, xi=0.05, g1=0.1, g2=0.1,
                      coupling="full")  # fmt: skip
    chain = ChainParams(cell, 3, g1=(0.1, 0.2, 0.3), g2=(0.1, 0.2, 0.3))
    assert d["cell_transmittance_linear_db"] == list(chain_linear_transmittance_db(chain))
    assert d["transmittance_linear_db"] == pytest.approx(d["cell_transmittance_linear_db"][-1])
    bands = stop_bands(cell)
    assert len(d["stop_bands"]) == len(bands) and d["stop_bands"][-1][1] is None  # inf: null
    assert d["stop_bands"][0] == list(bands[0])


def test_a_chain_summary_names_the_method_it_chose() -> None:
    out = run("point", "--cells", "2", "--sigmas", "0.05,0.1")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "method: euler (the method that runs chains of N > 1 cells)"
    assert lines[1].startswith("cells               2")
    assert "Γ_j,lin by cell" in out.stdout and "(euler)" in out.stdout
    assert "stop bands (γ_r)    n/a" in out.stdout  # a graded chain: no single lattice
    out = run("point", "--cells", "2", "--method", "euler")
    assert out.returncode == 0 and "method: euler" not in out.stdout  # asked for, not chosen
    assert "stop bands (γ_r)    [2, ∞)" in out.stdout  # paper coupling: a mass-spring chain


def test_a_method_that_runs_no_chains_is_a_usage_error() -> None:
    out = run("point", "--cells", "3", "--method", "event")
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert line.startswith("impactcell: error: --method 'event' does not run chains")
    assert "euler" in line


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--gaps", "0.1,0.2"], "--gaps must have one value per cell (--cells 3), got 2 values"),
        (["--sigmas", "1,2,3,4"], "--sigmas must have one value per cell (--cells 3), got 4"),
        (["--gaps", "0.1,wide,0.3"], "argument --gaps: must be numbers separated by commas"),
        (["--sigmas", "0.05,,0.05"], "argument --sigmas: must be numbers separated by commas"),
        (["--gaps", "0.1,-0.2,0.3"], "--gaps value 2 (cell 2) must be >= 0, got -0.2"),
        (["--sigmas", "0.05,0.05,0"], "--sigmas value 3 (cell 3) must be > 0, got 0.0"),
        (["--gaps", "0.1,0.1,0.1", "--g1", "0.2"], "--gaps sets both stops of every cell"),
    ],
)
def test_bad_chain_input_is_a_usage_error_naming_the_option(args: list[str], expected: str) -> None:
    out = run("point", "--cells", "3", *args)
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert expected in line
    assert not {"g1[", "sigma[", "n_cells"} & {w for w in line.split() if "[" in w or "_" in w}


@pytest.mark.parametrize(
    ("cells", "expected"),
    [("0", "argument --cells: must be >= 1, got 0"), ("two", "argument --cells: must be an "
     "integer, got 'two'"), ("1001", "--cells must be an integer in 1…1000, got 1001")],
)  # fmt: skip
def test_a_bad_number_of_cells_is_a_usage_error(cells: str, expected: str) -> None:
    out = run("point", "--cells", cells)
    assert out.returncode == 2 and expected in one_error_line(out.stderr)


def test_a_chain_spectrum_is_its_points() -> None:
    args = ("--cells", "2", "--gap", "0.1", "--modes", "2", "--json")
    out = run("spectrum", "--gamma-r-start", "1.5", "--gamma-r-stop", "2.5", "--num", "2", *args)
    assert out.returncode == 0, out.stderr
    rows = json.loads(out.stdout)
    assert [r["gamma_r"] for r in rows] == [1.5, 2.5]
    assert "method: euler" in out.stderr
    for r in rows:
        one = run("point", "--gamma-r", str(r["gamma_r"]), *args)
        assert one.returncode == 0, one.stderr
        d = json.loads(one.stdout)
        assert r["cells"] == d["cells"] == 2
        for k in ("transmittance_db", "outcome", "cell_transmittance_db",
                  "cell_transmittance_linear_db"):  # fmt: skip
            assert r[k] == d[k]
    bad = run("spectrum", "--cells", "2", "--gaps", "0.1", "--num", "2")
    assert bad.returncode == 2 and "--gaps" in one_error_line(bad.stderr)
