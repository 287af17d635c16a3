"""The command line: in process (``main(argv)``, fast), and once as a real subprocess."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from service.cli import main
from tests.service.helpers import run_cli as run
from worker.model import CellParams, linear_transmittance_db
from worker.simulate import kernels_cached
from worker.solvers.settings import METHODS, OUTCOMES

ROOT = Path(__file__).resolve().parents[3]
REQUIRED = {
    "outcome", "transmittance_db", "transmittance_db_se", "amplitude", "theta_eff",
    "theta_eff_slope", "response_period", "impacts_per_period", "floquet_multiplier",
    "periods", "steps", "contact_steps", "wall_s", "failed", "reason", "method",
}  # fmt: skip


def subprocess_run(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """The CLI as a user runs it: a new Python process."""
    return subprocess.run(
        [sys.executable, "-m", "service.cli", *args], capture_output=True, text=True, timeout=600,
        cwd=ROOT, env=env,
    )  # fmt: skip


def test_point_json_has_every_field_and_the_right_number():
    out = run("point", "--gamma-r", "1.3", "--gap", "1e6", "--coupling", "full", "--json")
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert set(d) >= REQUIRED
    assert not {"converged", "theta_eff_mean"} & set(d)  # gone with solver version 2
    p = CellParams(theta=0.3, sigma=0.05, gamma_s=1, gamma_r=1.3, g1=1e6, g2=1e6, coupling="full")
    assert abs(d["transmittance_db"] - linear_transmittance_db(p)) < 1e-4
    assert d["failed"] is False and d["outcome"] == "linear" and d["response_period"] == 1
    assert d["transmittance_db_se"] is None and 0 < d["floquet_multiplier"] < 1
    assert d["method"] == METHODS[0] == "event"  # the worker's default method


def test_point_summary_is_readable():
    out = run("point", "--gamma-r", "0.85", "--g1", "0.1", "--g2", "0.2", "--method", "euler")
    assert out.returncode == 0, out.stderr
    assert re.search(r"transmittance Γ\s+-?\d+\.\d+ dB", out.stdout)
    assert "impacts / period" in out.stdout and "(euler)" in out.stdout
    assert re.search(r"outcome\s+periodic \(period \d+\) after \d+ periods", out.stdout)
    assert re.search(r"Floquet multiplier\s+\|μ\| = 0\.\d+\n", out.stdout)
    assert "θ_ps, all harmonics" in out.stdout and "irregular" not in out.stdout
    assert re.search(r"θ_eff, 1st harmonic\s+-?\d", out.stdout)
    # a period-21 orbit (Figure 5's cell): its multiplier is over the orbit's 21 periods
    fig5 = ("--theta", "0.3", "--sigma", "0.05", "--gamma-s", "1", "--xi", "0.05", "--gap", "0.7")
    out = run("point", "--gamma-r", "0.98", *fig5)
    assert re.search(r"outcome\s+periodic \(period 21\)", out.stdout)
    assert re.search(r"Floquet multiplier\s+\|μ\| = 0\.1\d* over 21 periods\n", out.stdout)


def test_point_summary_of_an_irregular_point_gives_the_standard_error():
    # γ_r = 3, gap 0.1: inside the band of irregular response (studies/nightly/irregular.yaml).
    args = ("point", "--gamma-r", "3.0", "--gap", "0.1")
    d = json.loads(run(*args, "--json").stdout)
    assert d["outcome"] in ("irregular", "unsettled") and d["response_period"] == 0
    assert d["transmittance_db_se"] > 0 and d["floquet_multiplier"] is None
    out = run(*args)
    assert out.returncode == 0, out.stderr
    g, se = d["transmittance_db"], d["transmittance_db_se"]
    assert f"transmittance Γ     {g:.6f} ± {se:.2g} dB" in out.stdout
    # an irregular point beside an admissible impact-free response says so, with its duration
    tag = ""
    if d["may_be_transient"]:
        tag = rf", may be transient \(impacts for {d['impacting_periods']} periods\)"
    assert re.search(rf"outcome\s+{d['outcome']}{tag} after {d['periods']} periods", out.stdout)
    assert "Floquet" not in out.stdout and "period-" not in out.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--theta", "-1"], "error: --theta must be > 0, got -1.0"),
        (["--modes", "31"], "error: --modes must be an integer in 1…30, got 31"),
        (["--coupling", "x"], "error: --coupling must be one of paper, full"),
        (["--method", "rk4"], "--method must be one of event, exponential, euler, got 'rk4'"),
        (["--gap", "nan"], "error: --gap must be finite, got nan"),  # g1 is --gap's field
        (["--g1", "nan"], "error: --g1 must be finite, got nan"),
        (["--method", "euler", "--steps-per-period", "16"], "error: --steps-per-period gives"),
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
    lines = out.stdout.splitlines()
    assert lines[0].split() == [
        "gamma_r", "Gamma_dB", "se_dB", "theta_eff", "outcome", "period", "|mu|", "ms",
    ]  # fmt: skip
    rows = [line.split() for line in lines[1:]]
    assert [float(r[0]) for r in rows] == [0.5, 1.0, 1.5, 2.0]
    assert all(len(r) == 8 for r in rows)  # "-" where a value does not apply
    assert all(re.fullmatch(r"-?\d+\.\d{5}", r[1]) for r in rows)
    assert all(r[4] in OUTCOMES for r in rows)
    data = json.loads(
        run("spectrum", "--num", "4", "--gamma-r-start", "0.5", "--gamma-r-stop", "2",
            "--json").stdout
    )  # fmt: skip
    assert [r[4] for r in rows] == [d["outcome"] for d in data]
    assert [r[2] == "-" for r in rows] == [d["transmittance_db_se"] is None for d in data]


def test_warmup_loads_or_compiles_the_kernels(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["warmup", "--method", "euler", "event", "--method", "euler"]) == 0
    out = capsys.readouterr().out
    assert re.findall(r"^(\w+): ready in \d+\.\d s \(cached on disk\)$", out, re.M) == [
        "euler", "event"
    ]  # fmt: skip
    assert re.search(r"^2 methods ready in \d+\.\d s$", out, re.M)
    assert kernels_cached("euler") and kernels_cached("event")
    with pytest.raises(SystemExit) as exc:  # argparse: exit status 2, the choices named
        main(["warmup", "--method", "rk4"])
    assert exc.value.code == 2
    assert "invalid choice: 'rk4'" in capsys.readouterr().err


# A worker's process on a cache that a warmup filled: the numbers of compilations (numba's
# cache misses) of every compiled function of the simulator, after points of every outcome.
_WORKER_AFTER_WARMUP = r"""
import importlib, json, pkgutil
import worker
from numba.core.registry import CPUDispatcher
from worker.model import CellParams
from worker.simulate import SolverSettings, cache_ready, simulate_point, warm_up

def compiled():
    out = {}
    for info in pkgutil.walk_packages(worker.__path__, "worker."):
        mod = importlib.import_module(info.name)
        for name, obj in vars(mod).items():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == mod.__name__:
                out[f"{mod.__name__}.{name}"] = sum(obj.stats.cache_misses.values())
    return out

ready = cache_ready("event")
warm_up("event", quiet=True)
cell = dict(theta=0.3, sigma=0.05, gamma_s=1.0, xi=0.05, g1=0.1, g2=0.1)
seen = set()
# linear after a transient, orbits found by extrapolation, an irregular response
for g in (3.37, 1.03, 0.45, 2.35):
    seen.add(simulate_point(CellParams(gamma_r=g, **cell), SolverSettings()).outcome)
seen.add(simulate_point(CellParams(gamma_r=0.85, **cell),
                        SolverSettings(max_periods=200, window=10)).outcome)
print(json.dumps([ready, sorted(seen), sorted(k for k, n in compiled().items() if n)]))
"""


@pytest.mark.slow
def test_warmup_compiles_an_empty_cache_then_no_point_compiles_anything(tmp_path: Path) -> None:
    # On a fresh cache the first warmup compiles (and says so) what points need: the kernels,
    # and the engine's helpers that only extrapolated orbits reach (before, every worker
    # compiled those at its first periodic point, ~12 s, all workers at once). A new process
    # then compiles nothing, through points of every outcome; a second warmup only loads.
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    first = subprocess_run("warmup", "--method", "event", env=env)
    assert first.returncode == 0, first.stderr
    assert "event: compiling (once per machine) ..." in first.stdout
    assert "event: ready in" in first.stdout and "(cached on disk)" in first.stdout
    assert list((tmp_path / "numba").rglob("*.nbi")), "no numba cache index written"
    script = [sys.executable, "-c", _WORKER_AFTER_WARMUP]
    out = subprocess.run(script, cwd=ROOT, env=env, capture_output=True, text=True, check=True,
                         timeout=600).stdout  # fmt: skip
    ready, seen, compiled = json.loads(out.strip().splitlines()[-1])
    # the finished warm-up is recorded in the cache (workers then load the kernels as they start)
    assert ready is True
    assert {"linear", "periodic", "irregular"} <= set(seen), seen
    assert compiled == [], f"compiled after the warmup: {compiled}"
    again = subprocess_run("warmup", "--method", "event", env=env)
    assert again.returncode == 0, again.stderr
    assert "event: loading from numba's cache ..." in again.stdout


@pytest.mark.slow
def test_the_console_command_runs_in_a_new_process():
    out = subprocess_run("point", "--gamma-r", "1.3", "--gap", "1e6", "--json")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["outcome"] == "linear"
    bad = subprocess_run("point", "--theta", "-1")
    assert bad.returncode == 2 and "--theta must be > 0, got -1.0" in bad.stderr


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    cmd = re.search(r"# run the tests\n(.+)\n", readme).group(1).strip()
    assert cmd in ci


def test_point_prints_the_linear_reference_and_the_impact_effect():
    out = run("point", "--gamma-r", "2.05", "--gap", "0.1")
    d = json.loads(run("point", "--gamma-r", "2.05", "--gap", "0.1", "--json").stdout)
    assert out.returncode == 0 and d["outcome"] == "periodic"
    line = next(t for t in out.stdout.splitlines() if t.startswith("without stops"))
    assert f"{d['transmittance_linear_db']:.6f} dB" in line
    assert f"{d['impact_effect_db']:+.6f} dB" in line
    assert d["impact_effect_db"] == pytest.approx(
        d["transmittance_db"] - d["transmittance_linear_db"], abs=1e-12
    )
