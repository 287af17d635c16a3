"""The distribution: every package listed, and the shipped studies installed as package data.

The ``slow`` test builds the wheel (no build isolation: the test extra holds the build backend,
so no package index is reached), installs it into a folder of its own and runs the commands
that read the shipped files from elsewhere than the repository (the folder comes first on the
path, so the editable install of this checkout is not what answers).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
CONFIG = PYPROJECT["tool"]["setuptools"]


def test_every_package_folder_is_listed() -> None:
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("worker", "service")
        for p in (ROOT / top).rglob("__init__.py")
    }
    listed = set(CONFIG["packages"])
    assert found <= listed, f"add to [tool.setuptools] packages: {sorted(found - listed)}"
    assert listed - found == {"service.shipped"}
    assert CONFIG["package-dir"] == {"service.shipped": "studies"}
    assert (ROOT / "studies" / "__init__.py").is_file()


def _shipped_files() -> set[str]:
    root = ROOT / "studies"
    globs = CONFIG["package-data"]["service.shipped"]
    return {str(p.relative_to(root)) for g in globs for p in root.glob(g)}


def test_the_test_extra_carries_the_build_backend() -> None:
    """The wheel test builds without isolation, with what the test extra installed."""
    test = map(Requirement, PYPROJECT["project"]["optional-dependencies"]["test"])
    extra = {r.name: r for r in test}
    for r in map(Requirement, PYPROJECT["build-system"]["requires"]):
        assert r.name in extra and extra[r.name].specifier == r.specifier, r


def _wheel(dist: Path) -> Path:
    """This checkout's wheel, built into ``dist``. No build isolation and no index: pip would
    fetch the build backend from the package index, and no test reaches the internet; the
    test extra installs it (checked above)."""
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
         "-q", "-w", str(dist), str(ROOT)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert build.returncode == 0, build.stderr
    (wheel,) = dist.glob("impactcell-*.whl")
    return wheel


def _install(wheel: Path, site: Path) -> None:
    """Install ``wheel`` alone (no dependencies) into the folder ``site``."""
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "-q", "--target",
         str(site), str(wheel)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert install.returncode == 0, install.stderr


@pytest.mark.slow
def test_the_wheel_carries_the_shipped_studies_and_finds_them(tmp_path: Path) -> None:
    wheel = _wheel(tmp_path / "dist")
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = _shipped_files()
    assert {"quick.yaml", "nightly/table1.yaml", "baselines/table1.nc"} <= shipped
    assert {f"service/shipped/{f}" for f in shipped} <= names
    assert not any(n.startswith("studies/") for n in names)

    site = tmp_path / "site"
    _install(wheel, site)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site), "IMPACTCELL_DATA_DIR": str(tmp_path / "data")}

    def cli(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "service.cli", *args], capture_output=True, text=True,
            cwd=elsewhere, env=env, timeout=600,
        )  # fmt: skip

    where = subprocess.run(
        [sys.executable, "-c", "from service.studies import shipped; import json; print(json.dumps("
         "[str(shipped.shipped_root()), shipped.in_source_checkout()]))"],
        capture_output=True, text=True, cwd=elsewhere, env=env, timeout=120,
    )  # fmt: skip
    assert where.returncode == 0, where.stderr
    root, checkout = json.loads(where.stdout)
    assert Path(root) == site / "service" / "shipped" and checkout is False

    listed = cli("studies")
    assert listed.returncode == 0, listed.stderr
    assert [line.split()[0] for line in listed.stdout.splitlines()] == sorted(
        Path(f).stem for f in shipped if "/" not in f and f.endswith(".yaml")
    )
    ran = cli("run", "paper-fig6-theta-sweep", "--serial", "--no-progress", "--json")
    assert ran.returncode == 0, ran.stderr
    assert json.loads(ran.stdout)["points"] == 30
    # The installed baselines are never written; an explicit folder is asked for.
    refused = cli("nightly", "--update-baseline", "--quiet")
    assert refused.returncode == 2 and "--baselines DIR" in refused.stderr


def _pins() -> dict[str, str]:
    """constraints.txt as {normalized name: version}."""
    pins: dict[str, str] = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        req = Requirement(line)
        (spec,) = req.specifier  # one exact pin per line
        assert spec.operator == "==", line
        pins[_normalized(req.name)] = spec.version
    return pins


def _normalized(name: str) -> str:
    return name.lower().replace("_", "-").replace(".", "-")


def test_the_constraints_pin_every_dependency_within_pyproject() -> None:
    pins = _pins()
    project = PYPROJECT["project"]
    deps = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        deps += extra
    deps += PYPROJECT["build-system"]["requires"]
    for text in deps:
        req = Requirement(text)
        name = _normalized(req.name)
        assert name in pins, f"{req.name} is not pinned in constraints.txt"
        assert req.specifier.contains(pins[name], prereleases=True), (
            f"constraints.txt pins {req.name}=={pins[name]}, outside pyproject's {req.specifier}"
        )


def _closure(names: list[str]) -> set[str]:
    """The installed distributions ``names`` need, themselves included (markers evaluated,
    no extras): what ``pip install NAMES`` brings."""
    from importlib import metadata

    seen: set[str] = set()
    todo = list(names)
    while todo:
        name = _normalized(todo.pop())
        if name in seen:
            continue
        seen.add(name)
        for text in metadata.requires(name) or []:
            req = Requirement(text)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(req.name)
    return seen


@pytest.mark.slow
def test_the_client_runs_with_httpx_xarray_and_numpy_alone(tmp_path: Path) -> None:
    """docs/service.md's client install: the package without its dependencies, plus httpx,
    xarray and numpy (and what they need). Built from this machine's installed files, no index:
    a site folder holding only those distributions, and the package's wheel."""
    from importlib import metadata

    site = tmp_path / "site"
    site.mkdir()
    light = _closure(["httpx", "xarray", "numpy"])
    assert not light & {"numba", "scipy", "fastapi", "dask", "sqlalchemy", "matplotlib"}
    for name in light:
        dist = metadata.distribution(name)
        for f in dist.files or []:
            top = Path(str(f)).parts[0]
            src = Path(str(dist.locate_file(top)))
            if src.exists() and not (site / top).exists():
                (site / top).symlink_to(src)
    _install(_wheel(tmp_path / "dist"), site)
    script = (
        "import importlib.util, json, sys\n"
        "import httpx\n"
        "from service.client import Client\n"
        "def answer(request):\n"
        "    return httpx.Response(200, json={'items': [], 'total': 0, 'limit': 50, 'offset': 0})\n"
        "c = Client('http://127.0.0.1:9', transport=httpx.MockTransport(answer))\n"
        "page = c.list()\n"
        "missing = [m for m in ('numba', 'scipy', 'fastapi', 'dask')\n"
        "           if importlib.util.find_spec(m) is None]\n"
        "print(json.dumps({'total': page.total, 'missing': missing}))\n"
    )
    # -I: isolated (no user site, no PYTHONPATH, no cwd); -S: no site-packages of this venv.
    head = f"import sys; sys.path[:0] = [{str(site)!r}]\n"
    run = subprocess.run(
        [sys.executable, "-I", "-S", "-c", head + script],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out == {"total": 0, "missing": ["numba", "scipy", "fastapi", "dask"]}
