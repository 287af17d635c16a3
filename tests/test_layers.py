"""The house's layering as a checked contract (import-linter, configured in pyproject.toml) and
what import-linter cannot say directly: the client's whole import list, the one module that may
import matplotlib, and no import circles anywhere.

Imports inside functions count: grimp reads every import statement, not only the top-level ones.
"""

import sys
from pathlib import Path

import grimp
import pytest
from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("worker", "service")


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph(*PACKAGES, include_external_packages=True, cache_dir=None)


def internal(module: str) -> bool:
    return module.split(".")[0] in PACKAGES


def test_import_linter_contracts_hold(monkeypatch):
    monkeypatch.chdir(ROOT)
    assert lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True) == 0


def test_the_client_imports_only_httpx_xarray_numpy_and_the_standard_library(graph):
    allowed = {"httpx", "xarray", "numpy"} | set(sys.stdlib_module_names)
    imported = graph.find_modules_directly_imported_by("service.client")
    assert imported, "the graph lost the client"
    bad = sorted(m for m in imported if m.split(".")[0] not in allowed)
    assert not bad, f"service.client imports {bad}"


def test_only_the_plots_module_imports_matplotlib(graph):
    importers = graph.find_modules_that_directly_import("matplotlib")
    assert importers == {"service.analysis.plots"}


def _cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    nodes = sorted(m for m in graph.modules if internal(m))
    edges = {
        m: sorted(n for n in graph.find_modules_directly_imported_by(m) if internal(n))
        for m in nodes
    }
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(edges[root]))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(edges[w])))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_no_import_circles(graph):
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_a_cycle():
    g = grimp.ImportGraph()
    for m in ("worker.a", "worker.b", "worker.c", "service.d"):
        g.add_module(m)
    g.add_import(importer="worker.a", imported="worker.b")
    g.add_import(importer="worker.b", imported="worker.c")
    g.add_import(importer="worker.c", imported="worker.a")
    g.add_import(importer="service.d", imported="worker.a")
    assert _cycles(g) == [["worker.a", "worker.b", "worker.c"]]


def test_importing_the_client_loads_no_simulator():
    # What a process that only talks to a service pays: the client, httpx, xarray, numpy, and
    # the CPU pin (``worker/__init__`` and ``worker/cpu``, standard library only, so a process
    # that goes on to compute is pinned), never numba or the simulator's modules.
    import subprocess

    code = (
        "import sys, service.client; "
        "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in "
        "('numba', 'llvmlite', 'scipy', 'worker', 'dask', 'matplotlib'))))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert set(out.stdout.split()) == {"worker", "worker.cpu"}, out.stdout
