"""Where the time of ``impactcell run STUDY`` goes: wall time, and the CPU of the command's own
process and of its worker processes.

    python benchmarks/run_command.py [STUDY] [--runs 3] [--chunk-size N] [--out DIR]

Runs the command (``impactcell run STUDY --json --no-progress``, through a wrapper that reads
``getrusage`` as it exits) ``--runs`` times, each on a fresh data directory and its own
catalogue (nothing reused) and on the embedded cluster (``IMPACTCELL_SCHEDULER`` and
``IMPACTCELL_DATABASE_URL`` are not passed on), and reports per run:

* wall: from starting the command to its exit (interpreter start and imports included);
* the run: the command's own ``time`` line (the study's run: finding what is known, the
  cluster's start, computing, collating);
* command CPU: the command's own process (``getrusage(RUSAGE_SELF)`` at its exit): imports, the
  embedded cluster's scheduler and nannies, storing chunks, collation;
* workers CPU: its worker processes, their kernels included (``RUSAGE_CHILDREN``: the
  cluster reaps them before the command exits; forked workers are the forkserver's children,
  still running then: its CPU and its reaped children's, read from ``/proc``);
* of it, points: the CPU of the workers' task threads, the threads that run the chunk tasks
  (points, kernels and all; the rest is each worker's imports and its event loop). Read from
  ``/proc`` every 0.1 s while the command runs (Linux; a worker's task thread is the one,
  other than its main thread, that used the most CPU; a thread's last 0.1 s is missed; a
  reading takes ~0.7 ms of the command's CPU, under 1 % of a core); ``–`` without ``/proc``;
* kernels: the points' ``wall_s`` summed (the numba time loops only). Wall time: a kernel
  that waits for a core (two workers and the command's process on two cores) counts here,
  not in the CPU figures, so this can exceed the points' CPU;
* CPU floor: (command + workers CPU) / cores. With every core busy the run cannot be shorter;
  a wall time near it says a shorter run needs less work, not better overlap.

Default STUDY: ``studies/paper-fig5-gaps.yaml`` (the issue's 15 s target). ``--chunk-size`` is
passed to the command (default: the runner's). Writes ``run_command.md`` to ``--out`` (default
``benchmarks/results``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_STUDY = "studies/paper-fig5-gaps.yaml"
_NOT_PASSED = ("IMPACTCELL_SCHEDULER", "IMPACTCELL_DATABASE_URL")

# Run inside the command's process: the command itself (service.cli.entry, with its quick
# exit), then, from an atexit handler (entry runs them after main returns and the cluster is
# closed), the CPU of the process and of its reaped children on stderr.
_WRAPPER = r"""
import atexit, json, os, resource, sys, threading, time

_threads = {}  # (worker pid, thread id) -> the most CPU seen (s)
_TICK = os.sysconf("SC_CLK_TCK")


def _children(pid):
    kids = set()
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as fh:
                kids.update(fh.read().split())
    except OSError:  # no /proc (or a thread that just ended)
        pass
    return kids


def _descendants():
    # the workers: the command's children (spawned), or the forkserver's (forked)
    todo, seen = [str(os.getpid())], set()
    while todo:
        for kid in _children(todo.pop()):
            if kid not in seen:
                seen.add(kid)
                todo.append(kid)
    return seen


def _stat(pid, tid):
    with open(f"/proc/{pid}/task/{tid}/stat" if tid else f"/proc/{pid}/stat") as fh:
        return fh.read().rsplit(")", 1)[1].split()


def _sample_once():
    for pid in _descendants():
        try:
            for tid in os.listdir(f"/proc/{pid}/task"):
                f = _stat(pid, tid)
                cpu = (int(f[11]) + int(f[12])) / _TICK  # utime + stime
                _threads[pid, tid] = max(_threads.get((pid, tid), 0.0), cpu)
        except OSError:  # the process or one of its threads just ended
            pass


def _sample():
    while True:
        _sample_once()
        time.sleep(0.1)  # a thread's last 0.1 s before its process ends is not seen


def _report():
    s = resource.getrusage(resource.RUSAGE_SELF)
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    # Descendants still running (a forkserver, which reaped the workers it forked) are not in
    # RUSAGE_CHILDREN: their CPU and that of the children they reaped.
    alive = 0.0
    for pid in _descendants():
        try:
            f = _stat(pid, None)
        except OSError:
            continue
        alive += sum(int(x) for x in f[11:15]) / _TICK  # utime stime cutime cstime
    tasks = {}
    for (pid, tid), cpu in list(_threads.items()):
        if tid != pid:
            tasks[pid] = max(tasks.get(pid, 0.0), cpu)
    sys.stderr.write("RUSAGE " + json.dumps({
        "self": s.ru_utime + s.ru_stime, "children": c.ru_utime + c.ru_stime + alive,
        "points": sum(tasks.values()) if tasks else None}) + "\n")
    sys.stderr.flush()


atexit.register(_report)
threading.Thread(target=_sample, daemon=True).start()
sys.argv = ["impactcell", "--traceback", "run", *sys.argv[1:]]  # a failure shows where it was
from service.cli import entry

entry()
"""


def run_once(study: str, data_dir: Path, chunk_size: int | None = None) -> dict[str, Any]:
    """One ``impactcell run`` on ``data_dir``: its figures (see the module docstring)."""
    cmd = [sys.executable, "-c", _WRAPPER, study, "--out", str(data_dir), "--json",
           "--no-progress"]  # fmt: skip
    if chunk_size is not None:
        cmd += ["--chunk-size", str(chunk_size)]
    # the embedded cluster (its workers are this command's children) and a fresh catalogue
    env = {k: v for k, v in os.environ.items() if k not in _NOT_PASSED}
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=3600)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"impactcell run {study} failed ({done.returncode}):\n{done.stderr}")
    usage = next(
        json.loads(ln[len("RUSAGE ") :])
        for ln in reversed(done.stderr.splitlines())
        if ln.startswith("RUSAGE ")
    )
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    if summary["computed"] != summary["points"]:
        raise SystemExit(f"expected every point computed, got {summary['computed']} of "
                         f"{summary['points']} (a data directory that was not fresh?)")  # fmt: skip
    return {
        "points": summary["points"],
        "workers": summary["workers"],
        "wall": wall,
        "run": summary["wall_s"],
        "self": usage["self"],
        "children": usage["children"],
        "points_cpu": usage["points"],
        "kernels": summary["kernel_s"],
    }


def table(rows: list[dict[str, Any]], cores: int) -> list[str]:
    """The markdown rows: one per run, then the medians."""
    out = [
        "| run | wall s | of it the run s | command CPU s | workers CPU s | of it points s "
        "| kernels s | CPU floor s | wall − floor s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]

    def line(name: str, r: dict[str, Any]) -> str:
        floor = (r["self"] + r["children"]) / cores
        pts = "–" if r["points_cpu"] is None else f"{r['points_cpu']:.2f}"
        return (f"| {name} | {r['wall']:.2f} | {r['run']:.2f} | {r['self']:.2f} | "
                f"{r['children']:.2f} | {pts} | {r['kernels']:.2f} | {floor:.2f} | "
                f"{r['wall'] - floor:.2f} |")  # fmt: skip

    for i, r in enumerate(rows, 1):
        out.append(line(str(i), r))
    med: dict[str, Any] = {
        k: statistics.median(r[k] for r in rows)
        for k in ("wall", "run", "self", "children", "kernels")
    }
    known = [r["points_cpu"] for r in rows if r["points_cpu"] is not None]
    med["points_cpu"] = statistics.median(known) if len(known) == len(rows) else None
    out.append(line("median", med))
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print/save the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", nargs="?", default=DEFAULT_STUDY, help="a study file")
    ap.add_argument("--runs", type=int, default=3, help="runs (default 3)")
    ap.add_argument("--chunk-size", type=int, default=None,
                    help="points per task, passed on (default: the runner's)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error(f"--runs must be at least 1, got {args.runs}")
    if args.chunk_size is not None and args.chunk_size < 1:
        ap.error(f"--chunk-size must be at least 1, got {args.chunk_size}")
    cores = os.cpu_count() or 1
    rows = []
    for _ in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="impactcell-run-") as tmp:
            rows.append(run_once(args.study, Path(tmp), args.chunk_size))
    first = rows[0]
    lines = [
        f"`impactcell run {args.study}` end to end: {first['points']:,} points, "
        f"{first['workers']} worker processes on {cores} cores "
        f"({platform.machine()}, Python {platform.python_version()}); "
        f"each run on a fresh data directory.",
        "",
        *table(rows, cores),
        "",
        "The run: the command's `time` line. "
        "Command CPU: the `impactcell` process (imports, scheduler and nannies, chunk storage, "
        "collation); workers CPU: its worker processes (and the forkserver they are forked "
        "from); of it points: their task threads "
        "(the points; the rest is the workers' imports and event loops); kernels: the points' "
        "`wall_s` summed (wall time: it includes waiting for a core); CPU floor: (command + "
        "workers CPU) / cores.",
        "",
        f"Generated by `python benchmarks/run_command.py {args.study} --runs {args.runs}"
        + (f" --chunk-size {args.chunk_size}" if args.chunk_size is not None else "")
        + "`.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "run_command.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
