"""The command line as a user runs it (real subprocesses)."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from worker.model import CellParams, linear_transmittance_db

ROOT = Path(__file__).resolve().parents[2]
REQUIRED = {
    "transmittance_db", "amplitude", "theta_eff", "theta_eff_mean", "response_period",
    "impacts_per_period", "converged", "periods", "steps", "contact_steps", "wall_s",
    "failed", "reason",
}  # fmt: skip


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "service.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_point_json_has_every_field_and_the_right_number():
    out = run("point", "--gamma-r", "1.3", "--gap", "1e6", "--coupling", "full", "--json")
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert set(d) >= REQUIRED
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=1, gamma_r=1.3, g1=1e6, g2=1e6, coupling="full")
    assert abs(d["transmittance_db"] - linear_transmittance_db(p)) < 1e-4
    assert d["failed"] is False and d["converged"] is True


def test_point_summary_is_readable():
    out = run("point", "--gamma-r", "0.85", "--g1", "0.1", "--g2", "0.2", "--method", "euler")
    assert out.returncode == 0, out.stderr
    assert re.search(r"transmittance Γ\s+-?\d+\.\d+ dB", out.stdout)
    assert "impacts / period" in out.stdout and "(euler)" in out.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--theta", "-1"], "theta must be > 0, got -1.0"),
        (["--modes", "31"], "modes must be an integer in 1…30, got 31"),
        (["--coupling", "x"], "coupling must be one of paper, full"),
        (["--method", "rk4"], "method must be one of exponential, euler"),
        (["--gap", "nan"], "g1 must be finite, got nan"),
        (["--method", "euler", "--steps-per-period", "16"], "largest stable step"),
    ],
)
def test_bad_input_exits_2_with_the_message(args, message):
    out = run("point", *args)
    assert out.returncode == 2
    assert message in out.stderr
    assert out.stdout == ""


def test_spectrum_prints_one_row_per_frequency():
    out = run("spectrum", "--num", "4", "--gamma-r-start", "0.5", "--gamma-r-stop", "2")
    assert out.returncode == 0, out.stderr
    rows = [line.split() for line in out.stdout.splitlines()[1:]]
    assert [float(r[0]) for r in rows] == [0.5, 1.0, 1.5, 2.0]
    assert all(re.fullmatch(r"-?\d+\.\d{5}", r[1]) for r in rows)


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    cmd = re.search(r"# run the tests\n(.+)\n", readme).group(1).strip()
    assert cmd in ci
