"""How fast a study over the point limit is refused, and whether ``/health`` keeps answering.

A real server (uvicorn on 127.0.0.1, no runner) gets ``gamma_r: {start: 0.1, stop: 6, num: N}``
while a thread polls ``/health``; prints the answer, its time and the slowest poll.

Run: ``python benchmarks/huge_grid.py [N ...]`` (default 10,000,000 and 1,000,000,000). Run it
from another checkout (``PYTHONPATH=<checkout>``) for before/after figures.
"""

from __future__ import annotations

import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import uvicorn

from service.api.app import create_app
from service.api.server import free_port
from service.api.settings import Settings


def measure(url: str, num: int) -> str:
    times: list[float] = []
    stop = threading.Event()

    def poll() -> None:
        with httpx.Client(base_url=url, timeout=300) as c:
            while not stop.is_set():
                t0 = time.monotonic()
                c.get("/health")
                times.append(time.monotonic() - t0)
                time.sleep(0.05)

    t = threading.Thread(target=poll)
    t.start()
    time.sleep(0.5)
    body = {"name": "big", "grid": {"gamma_r": {"start": 0.1, "stop": 6, "num": num},
            "gap": 0.1, "theta": 0.3, "sigma": 0.05, "gamma_s": 1.0}}  # fmt: skip
    t0 = time.monotonic()
    r = httpx.post(url + "/studies", json=body, timeout=600)
    dt = time.monotonic() - t0
    time.sleep(0.5)
    stop.set()
    t.join()
    return (f"num={num:,}: HTTP {r.status_code} in {dt:.3f} s; slowest of {len(times)} "
            f"/health polls {max(times):.3f} s; {r.text[:160]}")  # fmt: skip


def main() -> None:
    nums = [int(a) for a in sys.argv[1:]] or [10_000_000, 1_000_000_000]
    app = create_app(Settings(data_dir=Path(tempfile.mkdtemp()) / "data"), run_jobs=False)
    port = free_port()
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error"))
    threading.Thread(target=srv.run, daemon=True).start()
    while not srv.started:
        time.sleep(0.05)
    try:
        for num in nums:
            print(measure(f"http://127.0.0.1:{port}", num), flush=True)
    finally:
        srv.should_exit = True


if __name__ == "__main__":
    main()
