"""What the checks of a study's files cost: chunk digests (written and checked) and the results
file's SHA-256.

    python benchmarks/file_checks.py [--study studies/paper-fig5-gaps.yaml] [--chunk 96]
                                     [--repeat 5]

The study's points (synthetic records: the cost depends on the arrays' sizes, not their
values) are written as chunks of ``--chunk`` points, then read back by a fresh store (as a
resumed run or the API does) and collated into a results file. Each step is timed with the
check and with it switched off (the digest and the check replaced by no-ops), medians of
``--repeat`` rounds; the results file's first check (hashing it) and a repeated one (unchanged
file: its stamp only). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from service.studies import chunks  # noqa: E402
from service.studies.chunks import StudyStore, iter_chunk_ranges  # noqa: E402
from service.studies.dataset import results_from_records  # noqa: E402
from service.studies.schema import load_study  # noqa: E402


def record(i: int) -> dict[str, Any]:
    """A synthetic point record with every field a chunk keeps."""
    return {"outcome": "periodic", "transmittance_db": -3.0 - i % 7, "transmittance_db_se": None,
            "amplitude": 0.5, "theta_eff": 0.3, "theta_eff_slope": 0.2, "response_period": 1,
            "impacts_per_period": [1.0, 1.0], "peak_impulse": 0.1, "floquet_multiplier": 0.5,
            "periods": 40, "steps": 1000, "contact_steps": 10, "coarse_steps": 0,
            "steady_period": 20, "wall_s": 0.004, "reason": "", "failed": False}  # fmt: skip


def median_s(fn: Callable[[], Any], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--study", default=str(ROOT / "studies" / "paper-fig5-gaps.yaml"))
    ap.add_argument("--chunk", type=int, default=96)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    study = load_study(args.study)
    records = [record(i) for i in range(study.size)]
    ranges = iter_chunk_ranges([(0, study.size)], args.chunk)
    off = (
        mock.patch.object(chunks, "chunk_digest", lambda _arrays: ""),
        mock.patch.object(StudyStore, "_chunk_problem", lambda *_a: None),
    )
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)

        def write() -> None:
            store = StudyStore(root, study)
            store.prepare()
            for a, b in ranges:
                store.write_chunk(a, b, records[a:b])

        def read() -> None:
            StudyStore(root, study).collect()  # a fresh store reads every file

        for name, fn in (("write the chunks", write), ("read them back", read)):
            with off[0], off[1]:
                plain = median_s(fn, args.repeat)
            on = median_s(fn, args.repeat)  # last: the files written hold their digests
            rows.append((name, plain, on))
        store = StudyStore(root, study)
        store.write_results(results_from_records(study, store.collect()))
        size = store.results_path.stat().st_size

        def first() -> None:
            chunks._VERIFIED.clear()
            assert store.results_status() == "ok"

        hashed = median_s(first, args.repeat)
        again = median_s(lambda: store.results_status(), args.repeat)
    print(f"{study.name}: {study.size:,} points, {len(ranges)} chunks of {args.chunk}; "
          f"median of {args.repeat}\n")  # fmt: skip
    print("| step | without checks | with checks |\n|---|---|---|")
    for name, plain, on in rows:
        print(f"| {name} | {plain * 1e3:.1f} ms | {on * 1e3:.1f} ms |")
    print(f"| check the results file ({size / 1e6:.2f} MB): first / unchanged | – | "
          f"{hashed * 1e3:.2f} ms / {again * 1e3:.3f} ms |")  # fmt: skip


if __name__ == "__main__":
    main()
