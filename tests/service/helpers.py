"""Helpers of the service tests (imported explicitly; conftest.py holds only fixtures)."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import httpx
import xarray as xr

from service.api.server import free_port

__all__ = [
    "API_TOKEN",
    "AppTransport",
    "FAST_SOLVER",
    "SLOW_SOLVER",
    "Server",
    "run_cli",
    "TINY",
    "TINY_EULER",
    "comparable",
    "tiny_study",
    "write_suite",
]

#: The bearer token of the token-protected test app (conftest fixture ``token_client``).
API_TOKEN = "s3cret"
#: What a request that changes state and has no body declares (the service requires a type).
JSON_BODY = {"Content-Type": "application/json"}

# Headers that describe a body on the wire: the test client hands the body over decoded and
# whole, so they would describe another body.
_WIRE_HEADERS = ("content-encoding", "content-length", "transfer-encoding")


class AppTransport(httpx.BaseTransport):
    """``service.client.Client`` (httpx) talking to an app through Starlette's ``TestClient``.

    The test client's own transport cannot be handed to httpx: Starlette builds its test
    client on httpx2 when that is installed (httpx is deprecated there), and httpx rejects
    httpx2's responses. This transport passes each request on as a request of the test client
    and its answer back as an httpx response, whichever library the test client uses.
    """

    def __init__(self, tc: Any) -> None:
        self.tc = tc

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        skip = ("host", "content-length")  # the test client sets its own
        headers = [(k, v) for k, v in request.headers.multi_items() if k not in skip]
        r = self.tc.request(request.method, str(request.url), headers=headers,
                            content=request.read(), follow_redirects=False)  # fmt: skip
        out = [(k, v) for k, v in r.headers.multi_items() if k.lower() not in _WIRE_HEADERS]
        return httpx.Response(r.status_code, headers=out, content=r.content, request=request)


# A coarse, fast solver: these tests check the service, not the numbers (tests/worker do that).
FAST_SOLVER = {"steps_per_period": 256, "max_periods": 60, "periodicity_tol": 1e-5, "window": 5}
# Tests that act mid-study need a study that lasts seconds even on a fast, idle machine. With
# the default event method only the budget and the tolerance count (steps_per_period is for the
# stepping methods): 480 tiny-study points of it are ~10 s of serial kernel time. A test that
# must hold the cluster for longer uses Euler points (MEDIUM_SOLVER in api/test_jobs.py).
#: The Table-1 experiment's cell (docs/experiment.md), as a study's ``physical`` block.
TABLE1_CELL = {
    "length_m": 0.15, "width_m": 0.01, "thickness_m": 0.0025, "density_kg_m3": 1250.0,
    "youngs_modulus_pa": 4.583e7, "outer_mass_kg": 0.01667, "spring_n_m": 350.0,
    "damping_ratio": 0.03, "gap_m": 0.001,
}  # fmt: skip
SLOW_SOLVER = {"steps_per_period": 2048, "max_periods": 100, "periodicity_tol": 1e-13}


def tiny_study(name: str = "tiny", num: int = 8, gaps: tuple[float, ...] = (0.1, 0.5),
               **solver: Any) -> dict[str, Any]:  # fmt: skip
    """A small non-dimensional study definition (num × len(gaps) points)."""
    return {
        "name": name,
        "solver": {**FAST_SOLVER, **solver},
        "grid": {
            "gamma_r": {"start": 0.5, "stop": 3.0, "num": num},
            "gap": list(gaps),
            "theta": 0.3,
            "sigma": 0.05,
            "gamma_s": 1.0,
        },
    }


def comparable(ds: xr.Dataset) -> xr.Dataset:
    """A dataset without what differs between any two runs (``wall_s``, ``created``)."""
    out = ds.drop_vars("wall_s")
    out.attrs = {k: v for k, v in ds.attrs.items() if k != "created"}
    return out


# A tiny nightly suite (seconds, serial): one study with a regression block, one without.
TINY = """\
name: tiny
model: {coupling: paper, modes: 3, xi: 0.05}
solver: {steps_per_period: 512, max_periods: 200, periodicity_tol: 1.0e-6, window: 10}
grid:
  gamma_r: [0.5, 1.2, 2.0, 3.0, 3.6, 4.8]
  gap: [0.1, 0.5]
  theta: 0.3
  sigma: 0.05
  gamma_s: 1.0
regression:
  tolerances:
    theta_eff: {abs: 1.0e-3, rel: 1.0e-3}
"""

TINY_EULER = """\
name: tiny-euler
model: {coupling: full, modes: 3, xi: 0.05}
solver: {method: euler, steps_per_period: 256, max_periods: 300, window: 10}
grid:
  gamma_r: [1.0, 2.0, 3.0]
  g1: 0.1
  g2: 0.3
  theta: 0.3
  sigma: 0.05
  gamma_s: 1.0
"""


def write_suite(folder: Path) -> Path:
    """Write the tiny suite (``tiny.yaml``, ``tiny-euler.yaml``) into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "tiny.yaml").write_text(TINY, encoding="utf-8")
    (folder / "tiny-euler.yaml").write_text(TINY_EULER, encoding="utf-8")
    return folder


ROOT = Path(__file__).resolve().parents[2]  # the repository


class Server:
    """``python -m service.cli serve`` in a subprocess."""

    def __init__(self, data_dir: Path, scheduler: str, token: str | None = None,
                 env: dict[str, str] | None = None) -> None:  # fmt: skip
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        env = {**os.environ, "IMPACTCELL_API_TOKEN": token or "", **(env or {})}
        self.log = open(data_dir.parent / f"serve-{self.port}.log", "wb")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "serve", "--host", "127.0.0.1",
             "--port", str(self.port), "--data-dir", str(data_dir), "--scheduler", scheduler,
             "--log-level", "warning"],
            cwd=ROOT, env=env, stdout=self.log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        t0 = time.monotonic()
        while True:
            try:
                if httpx.get(f"{self.url}/health", timeout=1).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            if self.proc.poll() is not None or time.monotonic() - t0 > 60:
                self.stop(signal.SIGKILL)
                raise RuntimeError(f"server did not start: {self.logtext()}")
            time.sleep(0.1)

    def logtext(self) -> str:
        self.log.flush()
        return Path(self.log.name).read_text(errors="replace")[-3000:]

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(60)
        finally:
            self.log.close()


def run_cli(*args: str) -> SimpleNamespace:
    """The CLI in this process: exit status, stdout and stderr as a subprocess would give."""
    from service.cli import main  # here: the helpers load without the CLI otherwise

    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:  # argparse's own errors
            code = exc.code if isinstance(exc.code, int) else 2
    return SimpleNamespace(returncode=code or 0, stdout=out.getvalue(), stderr=err.getvalue())
