"""The service under load: a real ``impactcell serve`` on 127.0.0.1 and a 2-worker dask cluster.

Measures what a user feels (issue 13):

- ``fair``: a 4-point study submitted while a 2,000-point study runs: seconds until it is
  finished, and how far the large study got meanwhile (strict FIFO: after the large one);
- ``cancel``: two points of a minute or more each are cancelled 3 s after they start: seconds
  until a 4-point study submitted right after the cancel is finished (the cluster is free), and
  whether the cancelled study wrote anything after the cancel;
- ``timeseries``: a ``/timeseries`` recomputation of such a point: the slowest ``/health`` and
  ``GET /studies`` answer while it runs, and how the request ends;
- ``plots``: 50 concurrent plot requests (PNG and SVG, transmittance and bandgap) of a finished
  96-point study: the slowest and the median ``/health`` answer meanwhile, the plots' statuses
  (200, or 503 with ``Retry-After`` from the heavy-read pool) and the slowest plot.

Run: ``python benchmarks/service_under_load.py [--repo PATH] [--out FILE] [--only NAME ...]``.
``--repo`` runs the server of another checkout (e.g. a ``git worktree`` of an older commit) for
before/after figures; the client side speaks both APIs (``POST /studies/{id}/cancel`` or the
older ``DELETE``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parents[1]
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

# first: pins the CPU target (worker/cpu.py) before dask loads numpy, so that the cluster's
# workers compute as the service expects
import worker  # noqa: E402, F401

# isort: split
import httpx  # noqa: E402

FAST = {"steps_per_period": 256, "max_periods": 60, "periodicity_tol": 1e-5, "window": 5}
SLOW = {"steps_per_period": 2048, "max_periods": 100, "periodicity_tol": 1e-13}
HEAVY = {"method": "euler", "steps_per_period": 65_536, "max_periods": 10_000,
         "early_stop": False, "window": 10}  # fmt: skip


def study(name: str, num: int, gaps: list[float], solver: dict[str, Any]) -> dict[str, Any]:
    return {"name": name, "solver": solver,
            "grid": {"gamma_r": {"start": 0.5, "stop": 3.0, "num": num}, "gap": gaps,
                     "theta": 0.3, "sigma": 0.05, "gamma_s": 1.0}}  # fmt: skip


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    def __init__(self, repo: Path, data: Path, scheduler: str, env: dict[str, str]) -> None:
        self.url = f"http://127.0.0.1:{(port := free_port())}"
        self.log = open(data.parent / f"serve-{port}.log", "wb")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service.cli", "serve", "--host", "127.0.0.1", "--port",
             str(port), "--data-dir", str(data), "--scheduler", scheduler],
            cwd=repo, env={**os.environ, "PYTHONPATH": str(repo), **env},
            stdout=self.log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120:
            try:
                if httpx.get(f"{self.url}/health", timeout=1).status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.2)
        raise RuntimeError("server did not start")

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.log.close()


def wait(url: str, sid: str, until: Any, timeout: float = 900) -> dict[str, Any]:
    t0 = time.monotonic()
    while True:
        rec = httpx.get(f"{url}/studies/{sid}", timeout=120).json()
        if until(rec) or time.monotonic() - t0 > timeout:
            return rec
        time.sleep(0.1)


JSON_BODY = {"Content-Type": "application/json"}  # every state change declares a body type


def cancel(url: str, sid: str) -> None:
    r = httpx.post(f"{url}/studies/{sid}/cancel", headers=JSON_BODY, timeout=120)
    if r.status_code in (404, 405):  # the older API cancelled with DELETE
        httpx.delete(f"{url}/studies/{sid}", headers=JSON_BODY, timeout=120)


def chunks(data: Path, sid: str) -> int:
    d = data / "studies" / sid / "chunks"
    return len(list(d.glob("*.npz"))) if d.is_dir() else 0


def fair(url: str) -> dict[str, Any]:
    big = httpx.post(f"{url}/studies", json=study("big", 500, [0.1, 0.3, 0.5, 0.7], SLOW)).json()
    wait(url, big["id"], lambda r: r["points_done"] > 0)
    t0 = time.monotonic()
    small = httpx.post(f"{url}/studies", json=study("small", 4, [0.1], FAST)).json()
    rec = wait(url, small["id"], lambda r: r["status"] == "finished")
    out = {"small_study_s": round(time.monotonic() - t0, 1)}
    b = httpx.get(f"{url}/studies/{big['id']}").json()
    out["big_points_done_then"] = b["points_done"]
    out["big_points"] = b["points_total"]
    out["small_status"] = rec["status"]
    out["big_eta_s"] = b.get("eta_s")
    cancel(url, big["id"])
    return out


def cancelled(url: str, data: Path) -> dict[str, Any]:
    heavy = httpx.post(f"{url}/studies", json=study("heavy", 2, [0.1], HEAVY)).json()
    wait(url, heavy["id"], lambda r: r["status"] == "running")
    time.sleep(3.0)
    cancel(url, heavy["id"])
    t0 = time.monotonic()
    after = httpx.post(f"{url}/studies", json=study("after", 4, [0.2], FAST)).json()
    rec = wait(url, after["id"], lambda r: r["status"] == "finished")
    freed = time.monotonic() - t0
    time.sleep(5.0)
    return {"cluster_free_after_cancel_s": round(freed, 1), "after_status": rec["status"],
            "chunks_written_after_cancel": chunks(data, heavy["id"])}  # fmt: skip


def timeseries(url: str) -> dict[str, Any]:
    heavy = httpx.post(f"{url}/studies", json=study("ts", 2, [0.3], HEAVY)).json()
    cancel(url, heavy["id"])  # only its definition is used
    out: dict[str, Any] = {}

    def ask() -> None:
        t0 = time.monotonic()
        try:
            r = httpx.get(f"{url}/studies/{heavy['id']}/timeseries",
                          params={"gamma_r": 0.5, "periods": 2}, timeout=400)  # fmt: skip
            out["status"] = r.status_code
            out["detail"] = r.json().get("detail", "")[:120] if r.status_code >= 400 else ""
        except httpx.HTTPError as exc:
            out["status"] = f"{type(exc).__name__}"
        out["timeseries_s"] = round(time.monotonic() - t0, 1)

    t = threading.Thread(target=ask)
    t.start()
    slowest = 0.0
    while t.is_alive():
        t0 = time.monotonic()
        try:
            httpx.get(f"{url}/health", timeout=60)
            httpx.get(f"{url}/studies", timeout=60)
            slowest = max(slowest, time.monotonic() - t0)
        except httpx.HTTPError:
            slowest = max(slowest, 60.0)
        time.sleep(0.2)
    t.join()
    return {"slowest_health_and_list_s": round(slowest, 2), **out}


def plots(url: str, n: int = 50) -> dict[str, Any]:
    done = httpx.post(f"{url}/studies", json=study("plots", 32, [0.1, 0.3, 0.5], FAST)).json()
    wait(url, done["id"], lambda r: r["status"] == "finished")
    kinds = [("transmittance", "png"), ("bandgap", "png"), ("transmittance", "svg"),
             ("bandgap", "svg")]  # fmt: skip
    answers: list[tuple[int, bool, float]] = []
    lock = threading.Lock()
    start = threading.Barrier(n + 1)
    # Clients made before the burst: httpx.get makes one per call, with an SSL context whose
    # set-up holds this process's GIL, and 50 at once would slow the prober here, not the
    # service. The prober has a client of its own.
    many = httpx.Client(limits=httpx.Limits(max_connections=n), timeout=600)
    probe = httpx.Client(timeout=120)

    def plot(i: int) -> None:
        kind, fmt = kinds[i % len(kinds)]
        start.wait()
        t0 = time.monotonic()
        try:
            r = many.get(f"{url}/studies/{done['id']}/plots/{kind}.{fmt}")
            got = (r.status_code, "retry-after" in r.headers, time.monotonic() - t0)
        except httpx.HTTPError:
            got = (0, False, time.monotonic() - t0)
        with lock:
            answers.append(got)

    threads = [threading.Thread(target=plot, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    start.wait()
    began = time.monotonic()
    health: list[float] = []
    worst = (0.0, 0.0)  # the slowest /health answer, and when it was asked (s after the start)
    while any(t.is_alive() for t in threads):
        t0 = time.monotonic()
        try:
            probe.get(f"{url}/health")
            health.append(time.monotonic() - t0)
        except httpx.HTTPError:
            health.append(120.0)
        worst = max(worst, (health[-1], t0 - began))
        time.sleep(0.1)
    for t in threads:
        t.join()
    many.close()
    probe.close()
    codes: dict[str, int] = {}
    for code, _, _ in answers:
        codes[str(code)] = codes.get(str(code), 0) + 1
    health.sort()
    return {
        "plot_requests": n,
        "statuses": codes,
        "503_with_retry_after": sum(1 for c, ra, _ in answers if c == 503 and ra),
        "slowest_plot_s": round(max(s for *_, s in answers), 2),
        "slowest_health_s": round(health[-1], 3) if health else None,
        "slowest_health_asked_at_s": round(worst[1], 2),
        "median_health_s": round(health[len(health) // 2], 3) if health else None,
        "health_samples": len(health),
    }


SCENARIOS = ("fair", "cancel", "timeseries", "plots")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repo", type=Path, default=HERE, help="checkout whose server runs")
    ap.add_argument("--out", type=Path, default=HERE / "benchmarks/results/service_under_load.json")
    ap.add_argument("--only", nargs="+", choices=SCENARIOS, default=list(SCENARIOS),
                    help="the scenarios to run (default: all)")  # fmt: skip
    args = ap.parse_args()
    from dask.distributed import LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0",
                           silence_logs=40)  # fmt: skip
    tmp = Path(tempfile.mkdtemp(prefix="impactcell-load-"))
    data = tmp / "data"
    srv = Server(args.repo.resolve(), data, cluster.scheduler_address,
                 {"IMPACTCELL_TIMESERIES_TIME_LIMIT_S": "20"})  # fmt: skip
    try:
        git = ["git", "rev-parse", "--short", "HEAD"]
        rev = subprocess.run(git, cwd=args.repo, capture_output=True, text=True).stdout.strip()
        rev = rev or "unknown"
        res: dict[str, Any] = {
            "commit": rev,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        }
        runs = {
            "fair": lambda: fair(srv.url),
            "cancel": lambda: cancelled(srv.url, data),
            "timeseries": lambda: timeseries(srv.url),
            "plots": lambda: plots(srv.url),
        }
        for name in args.only:
            res[name] = runs[name]()
    finally:
        srv.stop()
        cluster.close()
    print(json.dumps(res, indent=2))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
