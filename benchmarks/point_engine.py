"""How a point ends: the default solver against the paper's scheme on three spectra.

    python benchmarks/point_engine.py [--points 40] [--repeat 3] [--out benchmarks/results] [--json]
                                      [--set KEY=VALUE ...]

Three 40-point spectra, γ_r = 0.3 … 6, σ 0.05, γ_s 1, five modes:

* A: paper coupling, θ 0.3, ξ 0.05, gaps 0.1;
* B: paper coupling, θ 1, ξ 0.02, gaps 0.5;
* C: full coupling, θ 0.3, ξ 0.05, gaps 0.3.

Each point is run twice in the same process, one after the other: with the default
``SolverSettings()`` and with the paper's scheme as published (semi-implicit Euler with Lemke's
LCP at every step, Δτ = 1e-3, a fixed 150 periods, measured over the last 20). Time per point is
the wall time of the whole ``simulate_point`` call (assembly, matrix exponentials, kernel), one
core, the fastest of ``--repeat`` passes over all the points (the machine's speed drifts by
tens of percent over seconds; a point's runs spread over the whole benchmark rarely all fall in
a slow spell, and the minimum is the cost of the work itself). Reports mean, median and worst
time per point for both, their ratios, and how the default's points ended; then the time,
periods and cost per period by outcome, and the ceiling of the mean ratio (what it would be if
only the irregular and unsettled points cost anything: their periods are set by the window
statistics and the quarter-budget guard against transient chaos, not by the kernel's speed).
Both methods' kernels are compiled with the same numba options (``measure.KERNEL_JIT``).

``--set KEY=VALUE`` (repeatable) runs a variant of the default in its place, for example
``--set steps_per_period=32`` (the event solver's sub-grid) or ``--set extrapolate=false``
(plain iteration to orbits): any ``SolverSettings`` field, the value read as JSON (``true``,
``32``, ``1e-12``) or else as text.

Each point's time is also split: the compiled time loops (every ``KernelRun.advance`` call the
point makes, side runs included; the benchmark wraps that method while it runs) and the rest
(assembly, closed forms, the engine's Python: batches, extrapolation, proofs). From the loops'
time alone come the ratios the default would have if everything but its time loops cost
nothing: what a compiled engine at most could give, with the kernels as they are.

For every point that ends ``linear`` after simulating, the benchmark also finds the last period
in which its tip met a stop (``last_impact``: the same start and settings without early stop,
from the run's time history): how long the point's transient really impacts, against the
period at which its linear tail was proven. Their difference is all a sharper proof could
save; the rest is the transient itself, which no proof may skip (the impact-free response being
admissible does not make it the one reached: an impacting orbit may coexist).

Writes ``point_engine.md`` and ``point_engine.csv`` to the output folder (a variant:
``point_engine_<KEY>-<VALUE>….md`` and ``.csv``, so the default's stay).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import json
import math
import os
import re
import statistics
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: threads only cost

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import worker  # noqa: E402, F401  # first: pins the CPU target (worker/cpu.py)

# isort: split
import numpy as np  # noqa: E402

from benchmarks.suite.cases import (  # noqa: E402
    SPECTRA,
    cell,
    paper_settings,
)
from worker.model import CellParams  # noqa: E402
from worker.simulate import SolverSettings, simulate_point, warm_up  # noqa: E402
from worker.solvers.base import KernelRun  # noqa: E402


def variant(items: list[str]) -> tuple[SolverSettings, dict[str, Any]]:
    """``SolverSettings`` with the ``KEY=VALUE`` items over the defaults, and those items
    (values read as JSON, else as text). A bad item raises ``ValueError`` naming it."""
    names = [f.name for f in dataclasses.fields(SolverSettings)]
    given: dict[str, Any] = {}
    for item in items:
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq or key not in names:
            raise ValueError(
                f"--set {item!r}: expected KEY=VALUE with KEY a solver setting ({', '.join(names)})"
            )
        try:
            given[key] = json.loads(text)
        except ValueError:
            given[key] = text
    try:
        return SolverSettings(**given), given
    except (TypeError, ValueError) as e:
        raise ValueError(f"--set: {e}") from None


def _text(value: Any) -> str:
    """A setting's value as it was given (``false``, ``32``, ``event``)."""
    return value if isinstance(value, str) else json.dumps(value)


def results_name(given: dict[str, Any]) -> str:
    """The results files' name: ``point_engine``, or a variant's ``point_engine_<k>-<v>…``."""
    parts = [f"{k}-{_text(v)}" for k, v in given.items()]
    tail = re.sub(r"[^A-Za-z0-9_.+-]+", "", "_".join(parts))
    return "point_engine" + (f"_{tail}" if tail else "")


def outcome_of(r) -> str:
    """The point's outcome (``outcome`` where the result has it)."""
    out = getattr(r, "outcome", None)
    if out:
        return str(out)
    if r.failed:
        return "failed"
    return "periodic" if r.converged else "irregular"


@contextlib.contextmanager
def kernel_clock() -> Iterator[list[float]]:
    """While inside: every ``KernelRun.advance`` call (a method's compiled time loop, all
    methods) adds its wall time to the one-element list yielded. The method is restored on
    leaving."""
    spent = [0.0]
    plain = KernelRun.advance

    def advance(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return plain(self, *args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - t0

    KernelRun.advance = advance  # type: ignore[method-assign]
    try:
        yield spent
    finally:
        KernelRun.advance = plain  # type: ignore[method-assign]


def timed(params: CellParams, settings: SolverSettings, repeat: int = 1):
    """The result, the fastest wall time of ``repeat`` runs and the fastest time of the
    runs' compiled time loops (:func:`kernel_clock`)."""
    best = loops = math.inf
    for _ in range(repeat):
        with kernel_clock() as spent:
            t0 = time.perf_counter()
            r = simulate_point(params, settings)
            best = min(best, time.perf_counter() - t0)
        loops = min(loops, spent[0])
    return r, best, loops


def last_impact(params: CellParams, settings: SolverSettings, periods: int) -> int:
    """The last period from rest in which the tip met a stop (1 for the first; 0 if none did)
    in a run of ``periods`` periods (at least 2) without early stop or the linear tail, from its
    time history (``kind`` 1 and 2 are impacts)."""
    if periods < 1:
        return 0
    n = max(periods, 2)  # the smallest budget the settings allow
    # the window (statistics only) must fit in the budget; the trajectory does not depend on it
    # (and without the linear tail the run ends unsettled: its history is the run's own)
    plain = dataclasses.replace(
        settings, early_stop=False, linear_tail=False, max_periods=n, window=1
    )
    r = simulate_point(params, plain, history_periods=n)
    kind, tau = r.history["kind"], r.history["tau"]
    hits = tau[(kind == 1) | (kind == 2)]
    if hits.size == 0:
        return 0
    period = 2.0 * math.pi / params.gamma_r
    # not capped at ``periods``: an impact after a linear point's proof would be a broken proof
    return int(hits.max() // period) + 1


def linear_transients(rows: list[dict]) -> dict[str, Any]:
    """The linear points' transients: how many were proven at the start, how many after
    simulating (the rows with ``last_impact`` set), their periods, the periods up to their last
    impacts, and the lags from the last impact (or the start) to the proof."""
    simulated = [r for r in rows if r.get("last_impact") is not None]
    hit = [r["last_impact"] for r in simulated if r["last_impact"] > 0]
    lags = [r["periods"] - r["last_impact"] for r in simulated]
    return dict(
        linear_at_start=sum(r["outcome"] == "linear" for r in rows) - len(simulated),
        linear_simulated=len(simulated),
        linear_periods=sum(r["periods"] for r in simulated),
        impacting_periods=sum(hit),
        last_impacts=(min(hit), max(hit)) if hit else None,
        impacted=len(hit),
        proof_lags=(min(lags), max(lags)) if lags else None,
        proof_lag_median=statistics.median(lags) if lags else None,
    )


def by_outcome(rows: list[dict]) -> dict[str, dict[str, float]]:
    """Per outcome of the default: points, its time, the time of its time loops and its
    periods in all, the paper's scheme's time at the same points."""
    out: dict[str, dict[str, float]] = {}
    for r in rows:
        o = out.setdefault(
            r["outcome"], dict(points=0, ms=0.0, kernel_ms=0.0, periods=0, paper_ms=0.0)
        )
        o["points"] += 1
        for key in ("ms", "kernel_ms", "periods", "paper_ms"):
            o[key] += r[key]
    return dict(sorted(out.items()))


def loops_only(rows: list[dict]) -> tuple[float, float]:
    """The mean and median ratios to the paper's scheme if the default's points cost only
    their time loops (``kernel_ms``): the most a compiled engine could give with the kernels
    as they are (inf where the loops took no time)."""
    t_pap = [r["paper_ms"] for r in rows]
    loops = [r["kernel_ms"] for r in rows]
    mean = statistics.fmean(loops)
    median = statistics.median(loops)
    return (
        statistics.fmean(t_pap) / mean if mean > 0 else math.inf,
        statistics.median(t_pap) / median if median > 0 else math.inf,
    )


def ceiling(rows: list[dict], costly: tuple[str, ...] = ("irregular", "unsettled")) -> float:
    """The mean ratio the default could reach if every point not in ``costly`` cost nothing:
    the paper's scheme's total time over the costly points' default time (inf: none)."""
    spent = sum(r["ms"] for r in rows if r["outcome"] in costly)
    return sum(r["paper_ms"] for r in rows) / spent if spent > 0 else math.inf


def linear_lines(lin: dict[str, Any]) -> list[str]:
    """The paragraph on the linear points (:func:`linear_transients`)."""
    head = (
        f"Linear points: {lin['linear_at_start']} proven at the start (no period "
        f"simulated), {lin['linear_simulated']} after simulating"
    )
    if not lin["linear_simulated"]:
        return [head + "."]
    met = (
        "{} of these met a stop, last in period {}–{}".format(lin["impacted"], *lin["last_impacts"])
        if lin["impacted"]
        else "none of these met a stop"
    )
    periods, impacting = lin["linear_periods"], lin["impacting_periods"]
    return [
        "{}: {}; the linear tail was proven {}–{} periods after the last impact (or the "
        "start; median {:g}). Of their {:,} periods, {:,} ({:.0f} %) are the transient up to "
        "its last impact, which no proof may skip; a sharper proof could save at most the "
        "other {:,}.".format(
            head, met, *lin["proof_lags"], lin["proof_lag_median"], periods, impacting,
            100 * impacting / periods, periods - impacting,
        )
    ]  # fmt: skip


def write_results(out: Path, name: str, lines: list[str], rows: list[dict]) -> None:
    """Write ``<name>.md`` (the lines) and ``<name>.csv`` (the rows) to ``out``; print the
    table. Without rows no CSV is written, and one an earlier run left is removed (it would
    pass for this run's)."""
    text = "\n".join(lines) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.md").write_text(text)
    table = out / f"{name}.csv"
    if rows:
        with open(table, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    else:
        table.unlink(missing_ok=True)
    print(text)


def main(argv: list[str] | None = None) -> None:
    """Run the benchmark and write its tables."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=40)
    ap.add_argument(
        "--repeat", type=int, default=3, help="passes over the points (the fastest run counts)"
    )
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    ap.add_argument("--json", action="store_true", help="print a JSON summary line")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a solver setting of the variant run in place of the default "
                         "(repeatable)")  # fmt: skip
    args = ap.parse_args(argv)
    if args.points < 1 or args.repeat < 1:
        ap.error(f"--points and --repeat must be at least 1, got {args.points}, {args.repeat}")
    try:
        default, given = variant(args.set)
    except ValueError as e:
        ap.error(str(e))
    label = (
        f"{default.method}, " + ", ".join(f"{k}={_text(v)}" for k, v in given.items())
        if given
        else f"default ({default.method})"
    )
    who = "variant" if given else "default"
    gammas = np.linspace(0.3, 6.0, args.points)
    warm_up(default.method)
    warm_up("euler")
    # compile the Lemke path before timing
    warm_lemke = dataclasses.replace(paper_settings(6.0), max_periods=3, window=1)
    simulate_point(cell("A", 1.0), warm_lemke)

    points = [(case, float(g)) for case in SPECTRA for g in gammas]
    rows: list[dict] = []
    # Repeats are passes over all the points, not runs back to back: this machine's speed
    # drifts by tens of percent over seconds, and a point's repeats spread over the whole run
    # are rarely all in a slow spell (back to back, the mean moved by up to 60 % between runs
    # of the same code; as passes, by 6 %).
    for rep in range(args.repeat):
        for i, (case, g) in enumerate(points):
            p = cell(case, g)
            r, t, tk = timed(p, default)
            rp, tp, _ = timed(p, paper_settings(g))
            if rep:
                rows[i]["ms"] = min(rows[i]["ms"], t * 1e3)
                rows[i]["kernel_ms"] = min(rows[i]["kernel_ms"], tk * 1e3)
                rows[i]["paper_ms"] = min(rows[i]["paper_ms"], tp * 1e3)
                continue
            rows.append(
                dict(
                    case=case, gamma_r=g, outcome=outcome_of(r),
                    db=r.transmittance_db, ms=t * 1e3, kernel_ms=tk * 1e3, periods=r.periods,
                    paper_db=rp.transmittance_db, paper_ms=tp * 1e3,
                    paper_outcome=outcome_of(rp), reason=r.reason,
                    last_impact=(
                        last_impact(p, default, r.periods)
                        if r.outcome == "linear" and r.periods > 0 else None
                    ),
                )
            )  # fmt: skip
    t_def = [r["ms"] for r in rows]
    t_pap = [r["paper_ms"] for r in rows]
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    summary = dict(
        method=default.method,
        settings=given,
        points=len(rows),
        default_mean_ms=statistics.fmean(t_def),
        default_median_ms=statistics.median(t_def),
        default_max_ms=max(t_def),
        paper_mean_ms=statistics.fmean(t_pap),
        paper_median_ms=statistics.median(t_pap),
        mean_ratio=statistics.fmean(t_pap) / statistics.fmean(t_def),
        median_ratio=statistics.median(t_pap) / statistics.median(t_def),
        # the other reading of "the median point": the median of each point's own speed-up
        median_point_ratio=statistics.median(p / d for p, d in zip(t_pap, t_def, strict=True)),
        outcomes=counts,
        mean_ratio_ceiling=ceiling(rows),
    )
    summary["kernel_mean_ms"] = statistics.fmean(r["kernel_ms"] for r in rows)
    summary["kernel_median_ms"] = statistics.median(r["kernel_ms"] for r in rows)
    summary["mean_ratio_loops_only"], summary["median_ratio_loops_only"] = loops_only(rows)
    groups = by_outcome(rows)
    summary.update(linear_transients(rows))
    lines = [
        f"Three {args.points}-point spectra (γ_r 0.3–6; A paper θ 0.3 ξ 0.05 gap 0.1, B paper "
        "θ 1 ξ 0.02 gap 0.5, C full θ 0.3 ξ 0.05 gap 0.3), one core, whole `simulate_point` "
        f"call per point, fastest of {args.repeat} passes over all the points.",
        "",
        "| solver | mean ms/point | median ms/point | worst ms |",
        "|---|---|---|---|",
        f"| {label} | {summary['default_mean_ms']:.2f} | "
        f"{summary['default_median_ms']:.2f} | {summary['default_max_ms']:.1f} |",
        f"| paper's scheme (euler + Lemke, Δτ 1e-3, 150 periods) | "
        f"{summary['paper_mean_ms']:.1f} | {summary['paper_median_ms']:.1f} | {max(t_pap):.0f} |",
        "",
        f"Paper's scheme / {who}: mean {summary['mean_ratio']:.1f}×, "
        f"median {summary['median_ratio']:.1f}× (ratio of the medians; the median of the "
        f"points' own ratios is {summary['median_point_ratio']:.1f}×).",
        "",
        f"Outcomes of the {who}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())),
        "",
        f"Where the time goes, by the {who}'s outcome:",
        "",
        f"| outcome | points | {who} ms | of it time loops ms | periods | µs per period | "
        "paper's scheme ms |",
        "|---|---|---|---|---|---|---|",
        *(
            f"| {k} | {g['points']} | {g['ms']:.0f} | {g['kernel_ms']:.0f} | {g['periods']:,} "
            f"| {1e3 * g['ms'] / max(g['periods'], 1):.0f} | {g['paper_ms']:.0f} |"
            for k, g in groups.items()
        ),
        "",
        f"Time loops only: the {who}'s compiled time loops took {summary['kernel_mean_ms']:.2f} "
        f"ms a point on average (median {summary['kernel_median_ms']:.2f} ms) of "
        f"{summary['default_mean_ms']:.2f} ({summary['default_median_ms']:.2f}). If everything "
        f"else cost nothing (a compiled engine at best, the kernels as they are), the ratios "
        f"would be {summary['mean_ratio_loops_only']:.1f}× (mean) and "
        f"{summary['median_ratio_loops_only']:.1f}× (median).",
        "",
        f"Ceiling of the mean ratio: if every point but the irregular and unsettled ones cost "
        f"nothing, {summary['mean_ratio_ceiling']:.1f}× (the paper's scheme's total over their "
        f"time). A median ratio of 100× needs the median point within "
        f"{summary['paper_median_ms'] / 100:.2f} ms.",
        "",
        *linear_lines(summary),
    ]
    write_results(args.out, results_name(given), lines, rows)
    if args.json:
        print(json.dumps(summary))


if __name__ == "__main__":
    main()
