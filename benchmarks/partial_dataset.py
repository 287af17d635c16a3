"""Time GET /studies/{id}/dataset of a 200k-point study in progress (chunks written directly).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/partial_dataset.py [CHUNK]`` from a checkout.
"""

import sys
import tempfile
import time
from pathlib import Path

from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.settings import Settings
from service.studies.chunks import StudyStore
from service.studies.runner import DEFAULT_CHUNK_SIZE
from service.studies.schema import parse_study

DEF = {
    "name": "bench-partial",
    "grid": {
        "gamma_r": {"start": 0.2, "stop": 6.0, "num": 2000},
        "gap": [0.1 * i for i in range(1, 11)],
        "theta": [0.1 * i for i in range(1, 11)],
        "sigma": 0.05,
        "gamma_s": 1.0,
    },
}
CHUNK = int(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_CHUNK_SIZE


def record(i: int) -> dict:
    return {
        "outcome": "linear",
        "transmittance_db": -1.0 - i % 7,
        "transmittance_db_se": None,
        "amplitude": 0.5,
        "theta_eff": 0.3,
        "theta_eff_slope": 0.2,
        "response_period": 1,
        "impacts_per_period": [0.0, 0.0],
        "peak_impulse": 0.0,
        "floquet_multiplier": 0.1,
        "periods": 3,
        "steps": 10,
        "contact_steps": 0,
        "coarse_steps": 0,
        "steady_period": 2,
        "wall_s": 0.001,
        "reason": "",
        "failed": False,
    }


def main() -> None:
    root = Path(tempfile.mkdtemp(prefix="bench-partial-"))
    s = Settings(data_dir=root / "data", max_points=10**6)
    with TestClient(create_app(s, run_jobs=False)) as tc:
        sid = tc.post("/studies", json=DEF).json()["id"]
        study = parse_study(DEF)
        store = StudyStore(s.data_dir, study)
        store.prepare()
        n = study.size
        starts = list(range(0, n, CHUNK))
        t0 = time.perf_counter()
        for a in starts[: int(0.8 * len(starts))]:  # 80 % done
            store.write_chunk(
                a, min(a + CHUNK, n), [record(i) for i in range(a, min(a + CHUNK, n))]
            )
        print(
            f"{n} points, {len(store.chunks())} chunk files written in "
            f"{time.perf_counter() - t0:.1f} s"
        )

        def get(label: str) -> None:
            t = time.perf_counter()
            r = tc.get(f"/studies/{sid}/dataset")
            dt = time.perf_counter() - t
            assert r.status_code == 200, r.text
            print(
                f"{label}: {dt:.2f} s, {len(r.content) / 1e6:.1f} MB, partial "
                f"{r.headers.get('x-impactcell-partial')}"
            )

        get("first /dataset")
        get("second /dataset (no new chunk)")
        a = starts[int(0.8 * len(starts))]
        store.write_chunk(a, a + CHUNK, [record(i) for i in range(a, a + CHUNK)])
        get("third /dataset (one new chunk)")
        t = time.perf_counter()
        r = tc.get(f"/studies/{sid}/data", params={"gap": 0.1, "theta": 0.1})
        print(f"/data one spectrum: {time.perf_counter() - t:.2f} s, status {r.status_code}")
        t = time.perf_counter()
        r = tc.get(f"/studies/{sid}/data")
        print(
            f"/data no selection: {time.perf_counter() - t:.2f} s, status {r.status_code}, "
            f"{len(r.content) / 1e6:.1f} MB"
        )


if __name__ == "__main__":
    sys.exit(main())
