"""Where a point's time goes, down to the compiled helpers: ``perf`` with numba's symbols.

    python benchmarks/profile_kernels.py [--points A:2.2,B:1.030769] [--seconds 8] [--top 30]

Runs the given points of the point-engine benchmark (``case:gamma_r``, cases A, B, C of
``point_engine.py``) once each, then over and over for ``--seconds`` with ``perf record``
attached (imports, compilation and the first runs are not sampled), and prints the share of
samples per part of the process and per function. Numba's compiled code has no symbols perf
can see, so the process writes ``/tmp/perf-<pid>.map`` (perf's map of JIT code) before perf
stops: the address of every function numba's JIT engine holds, each up to the next one.
Helpers LLVM inlined are counted in their caller. ``libm``'s ``__sincos``/``exp`` rows are the
exponentials the kernels evaluate (``roots.cexp``). Needs ``perf`` (linux-tools); without it
the script says so and exits 2.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_POINTS = "A:2.2,B:1.030769,B:4.830769,A:1.176923,C:0.884615"


def _points(spec: str) -> list[tuple[str, float]]:
    out = []
    for item in spec.split(","):
        case, _, g = item.partition(":")
        try:
            gamma_r = float(g)
        except ValueError:
            gamma_r = math.nan
        if case not in ("A", "B", "C") or not gamma_r > 0.0 or math.isinf(gamma_r):
            raise SystemExit(
                f"--points: expected case:gamma_r with case A, B or C and gamma_r a positive "
                f"number, got {item!r}"
            )
        out.append((case, gamma_r))
    return out


def _demangle(name: str) -> str:
    """``module.function`` from numba's mangled name (length-prefixed parts after ``_ZN``)."""
    body = name[3:] if name.startswith("_ZN") else name
    parts = []
    i = 0
    while i < len(body) and body[i].isdigit():
        j = i
        while j < len(body) and body[j].isdigit():
            j += 1
        n = int(body[i:j])
        parts.append(body[j : j + n])
        i = j + n
    return ".".join(parts[-2:]) if parts else name[:80]


def write_perf_map(path: Path) -> int:
    """Write perf's map of the JIT code loaded in this process to ``path`` (perf reads
    ``/tmp/perf-<pid>.map``): one line ``start size name`` per compiled function, each up to
    the next one. Returns the number of functions (0 before the event kernel is loaded)."""
    from worker.solvers.event import kernel

    engine = None
    for cres in kernel.event_kernel.overloads.values():
        engine = cres.library._codegen._engine  # one JIT engine holds every function
    if engine is None:
        return 0
    addrs = []
    for name in engine._defined_symbols:
        try:
            a = engine.get_function_address(name)
        except Exception:  # noqa: BLE001 - a data symbol, not a function
            continue
        if a:
            addrs.append((a, name))
    addrs = sorted(set(addrs))
    with open(path, "w") as fh:
        for i, (a, name) in enumerate(addrs):
            size = addrs[i + 1][0] - a if i + 1 < len(addrs) else 4096
            fh.write(f"{a:x} {min(size, 1 << 20):x} {_demangle(name)}\n")
    return len(addrs)


def run_profiled(points: list[tuple[str, float]], seconds: float, perf: str,
                 data: Path) -> int:  # fmt: skip
    """Load the kernels and run each point once (not sampled), then run the points over and
    over for ``seconds`` with ``perf record`` attached to this process, and write the perf map
    before perf stops. Returns perf's exit status."""
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from point_engine import cell

    from worker.simulate import SolverSettings, simulate_point

    settings = SolverSettings()
    cells = [cell(c, g) for c, g in points]
    for p in cells:  # compiling, loading and imports are not what is measured
        simulate_point(p, settings)
    rec = subprocess.Popen([perf, "record", "-q", "-p", str(os.getpid()), "-o", str(data)])
    time.sleep(0.5)  # perf attaches
    t0 = time.perf_counter()
    runs = 0
    while time.perf_counter() - t0 < seconds:
        for p in cells:
            simulate_point(p, settings)
        runs += 1
    n = write_perf_map(Path(f"/tmp/perf-{os.getpid()}.map"))  # removed by main after the report
    rec.send_signal(signal.SIGINT)
    code = rec.wait()
    print(f"{runs} passes over {len(cells)} points sampled; {n} compiled functions mapped")
    return code


def _group(line: str) -> str:
    """Which part of the process a perf report line belongs to."""
    for key, name in (("[JIT]", "compiled (numba)"), ("libm.", "libm (exp, sincos)"),
                      ("libpython", "Python interpreter"), ("multiarray", "numpy"),
                      ("openblas", "BLAS/LAPACK")):  # fmt: skip
        if key in line:
            return name
    return "other"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", default=DEFAULT_POINTS, help="case:gamma_r, comma separated")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args(argv)
    if not 0.0 < args.seconds < math.inf:
        ap.error(f"--seconds must be a positive number, got {args.seconds}")
    if args.top < 1:
        ap.error(f"--top must be at least 1, got {args.top}")
    points = _points(args.points)
    perf = shutil.which("perf")
    if perf is None:
        print("profile_kernels: perf is not installed (linux-tools)", file=sys.stderr)
        return 2
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy loads its BLAS (tiny matrices)
    perf_map = Path(f"/tmp/perf-{os.getpid()}.map")  # where perf looks for it
    try:
        with tempfile.TemporaryDirectory() as tmp:
            data = Path(tmp) / "perf.data"
            if run_profiled(points, args.seconds, perf, data) not in (0, -signal.SIGINT):
                print("profile_kernels: perf record failed", file=sys.stderr)
                return 2
            rep = subprocess.run(
                [perf, "report", "-i", str(data), "--no-children", "--sort", "dso,symbol",
                 "--stdio"], capture_output=True, text=True,
            )  # fmt: skip
    finally:
        perf_map.unlink(missing_ok=True)
    rows = [ln for ln in rep.stdout.splitlines() if re.match(r"\s+\d+\.\d+%", ln)]
    groups: dict[str, float] = {}
    for ln in rows:
        pct, _, rest = ln.strip().partition("%")
        part = _group(rest)
        groups[part] = groups.get(part, 0.0) + float(pct)
    print("share of samples by part: " + ", ".join(
        f"{k} {v:.1f} %" for k, v in sorted(groups.items(), key=lambda kv: -kv[1])))  # fmt: skip
    print(f"share of samples, top {args.top} ([JIT] = compiled by numba):")
    for ln in rows[: args.top]:
        head, _, sym = ln.partition("[.]")
        pct, _, dso = head.strip().partition(" ")
        dso = "[JIT]" if "[JIT]" in dso else Path(dso.strip()).name
        sym = re.sub(r"(\s+-)+\s*$", "", sym).strip()  # empty columns of a -p recording
        print(f"{pct:>8}  {dso[:24]:24}  {sym[:70]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
