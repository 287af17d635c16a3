"""``impactcell point | spectrum | warmup``: single points and spectra, without a service."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import re
import sys
import time
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from service.cli.common import Failure, positive_int
from worker.solvers.settings import DEFAULT_METHOD, METHODS

__all__ = ["FIELD_FLAGS", "add_commands"]

T = TypeVar("T")

# The model's and solver's field names (in their error messages) -> the flag a user types. The
# one place that knows both: errors say ``--gap must be >= 0``, never ``g1 must be >= 0``.
FIELD_FLAGS: dict[str, str] = {
    "theta": "--theta",
    "sigma": "--sigma",
    "gamma_s": "--gamma-s",
    "gamma_r": "--gamma-r",
    "xi": "--xi",
    "xi_b": "--xi-b",
    "g1": "--g1",
    "g2": "--g2",
    "e1": "--e1",
    "e2": "--e2",
    "modes": "--modes",
    "coupling": "--coupling",
    "method": "--method",
    "steps_per_period": "--steps-per-period",
    "max_periods": "--max-periods",
}


def _cell_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--theta", type=float, default=0.3, help="mass ratio θ = ρAl/m_o")
    p.add_argument("--sigma", type=float, default=0.05, help="beam stiffness parameter σ")
    p.add_argument("--gamma-s", type=float, default=1.0, help="inverse mass frequency γ_s")
    p.add_argument("--xi", type=float, default=0.05, help="damping ratio ξ")
    p.add_argument("--xi-b", type=float, default=None, help="beam Rayleigh ratio (default ξ)")
    p.add_argument("--gap", type=float, default=0.1, help="both clearances g̃1 = g̃2")
    p.add_argument("--g1", type=float, default=None, help="clearance to stop 1 (default: --gap)")
    p.add_argument("--g2", type=float, default=None, help="clearance to stop 2 (default: --gap)")
    p.add_argument("--restitution", type=float, default=0.0,
                   help="coefficient of restitution e at both stops, 0 (plastic, the paper's) "
                   "to 1; e > 0 needs --method euler or exponential")  # fmt: skip
    p.add_argument("--e1", type=float, default=None, help="e at stop 1 (default: --restitution)")
    p.add_argument("--e2", type=float, default=None, help="e at stop 2 (default: --restitution)")
    p.add_argument("--modes", type=int, default=5, help="number of beam modes, 1…30")
    p.add_argument("--coupling", default="paper", help="paper (Eq. 29) or full")
    p.add_argument(
        "--method", default=None, help=f"{', '.join(METHODS)} (default {DEFAULT_METHOD})"
    )
    p.add_argument(
        "--steps-per-period",
        type=int,
        default=None,
        help="time steps per period (default: the method's)",
    )
    p.add_argument("--max-periods", type=int, default=None,
                   help="period budget (default: the solver's)")  # fmt: skip


def _flags(args: argparse.Namespace, **override: str) -> dict[str, str]:
    """:data:`FIELD_FLAGS` as this command line spelled them (``--gap`` sets g1 and g2)."""
    names = dict(FIELD_FLAGS)
    for g in ("g1", "g2"):
        if getattr(args, g) is None:
            names[g] = "--gap"
    for e in ("e1", "e2"):
        if getattr(args, e) is None:
            names[e] = "--restitution"
    return {**names, **override}


def in_flag_terms(message: str, names: Mapping[str, str]) -> str:
    """``message`` with the field it starts with, and any other snake_case or numbered field
    (``gamma_r``, ``g1``) it mentions, replaced by the flag a user types."""
    head = re.match(r"(\w+)\b", message)
    if head and head.group(1) in names:
        message = names[head.group(1)] + message[head.end() :]
    for field, flag in names.items():
        if "_" in field or any(ch.isdigit() for ch in field):
            message = re.sub(rf"(?<![\w-]){re.escape(field)}\b", flag, message)
    return message


def _flagged(names: Mapping[str, str], make: Callable[[], T]) -> T:
    """``make()``, its ValueError said in terms of the command line's flags."""
    try:
        return make()
    except ValueError as exc:
        raise ValueError(in_flag_terms(str(exc), names)) from None


def _params(args: argparse.Namespace, gamma_r: float) -> Any:
    from worker.model import CellParams

    g1 = args.gap if args.g1 is None else args.g1
    g2 = args.gap if args.g2 is None else args.g2
    e1 = args.restitution if args.e1 is None else args.e1
    e2 = args.restitution if args.e2 is None else args.e2
    return CellParams(
        theta=args.theta, sigma=args.sigma, gamma_s=args.gamma_s, gamma_r=gamma_r, xi=args.xi,
        g1=g1, g2=g2, modes=args.modes, coupling=args.coupling, xi_b=args.xi_b, e1=e1, e2=e2,
    )  # fmt: skip


def _settings(args: argparse.Namespace) -> Any:
    from worker.simulate import SolverSettings

    given = {"method": args.method, "steps_per_period": args.steps_per_period,
             "max_periods": args.max_periods}  # fmt: skip
    return SolverSettings(**{k: v for k, v in given.items() if v is not None})


def _outcome_text(r: Any) -> str:
    """``linear``, ``periodic (period 2)``, ``irregular``, ``irregular, may be transient`` or
    ``unsettled``."""
    if r.outcome == "periodic":
        return f"periodic (period {r.response_period})"
    if r.may_be_transient:
        return f"{r.outcome}, may be transient (impacts for {r.impacting_periods} periods)"
    return r.outcome


def _cmd_point(args: argparse.Namespace) -> int:
    from worker.simulate import simulate_point

    if args.cells > 1 or args.gaps is not None or args.sigmas is not None:
        return _cmd_chain_point(args)
    names = _flags(args)
    params = _flagged(names, lambda: _params(args, args.gamma_r))
    settings = _flagged(names, lambda: _settings(args))
    result = _flagged(names, lambda: simulate_point(params, settings))
    d = result.as_dict()
    if args.json:
        print(json.dumps(d))  # the record of a failed point too; the exit status says it failed
    if result.failed:
        raise Failure(f"the point failed: {result.reason}")
    if args.json:
        return 0
    _print_point(result)
    return 0


def _plus_minus(ses: Any, scale: float = 1.0) -> tuple[str, str]:
    """Each stop's standard error as ' ± SE' (blank where there is none)."""
    if ses is None:
        return "", ""
    a, b = ("" if v is None else f" ± {scale * v:.2g}" for v in ses)
    return a, b


def _print_point(result: Any) -> None:
    """The summary of one point (a unit cell's, or a chain's last cell's) as ``point`` prints
    it."""
    se = result.transmittance_db_se
    print(f"transmittance Γ     {result.transmittance_db:.6f}"
          + (f" ± {se:.2g}" if se is not None else "") + " dB")  # fmt: skip
    lin, eff = result.transmittance_linear_db, result.impact_effect_db
    if lin is not None:  # the same cell without stops, and what the impacts change
        print(f"without stops Γ_lin {lin:.6f} dB (impact effect Γ − Γ_lin "
              f"{'n/a' if eff is None else f'{eff:+.6f}'} dB)")  # fmt: skip
    print(f"amplitude A_s       {result.amplitude:.6g}")
    print(f"θ_eff, 1st harmonic {result.theta_eff:.6g}  (the effective mass)")
    ts = result.theta_eff_slope
    print(f"θ_ps, all harmonics {'n/a' if ts is None else f'{ts:.6g}'}  (phase-portrait ratio)")
    print(f"outcome             {_outcome_text(result)} after {result.periods} periods")
    if result.reason:
        print(f"reason              {result.reason}")
    if result.floquet_multiplier is not None:
        # the monodromy matrix's spectral radius (finite differences), or exact: never a guess
        span = f"over {result.response_period} periods" if result.response_period > 1 else ""
        print(f"Floquet multiplier  |μ| = {result.floquet_multiplier:.4g} {span}".rstrip())
    i1, i2 = result.impacts_per_period
    pm = _plus_minus(result.impacts_per_period_se)
    print(f"impacts / period    stop 1: {i1:g}{pm[0]}, stop 2: {i2:g}{pm[1]}")
    if result.contact_fraction is not None:
        c1, c2 = result.contact_fraction
        pm = _plus_minus(result.contact_fraction_se, 100.0)
        print(f"time on the stops   stop 1: {100 * c1:.3g}{pm[0]} %, stop 2: {100 * c2:.3g}{pm[1]} "
              "% of the period")  # fmt: skip
    if result.impact_velocity is not None and any(v is not None for v in result.impact_velocity):
        v1, v2 = ("-" if v is None else f"{v:.4g}" for v in result.impact_velocity)
        pm = _plus_minus(result.impact_velocity_se)
        print(f"impact velocity     stop 1: {v1}{pm[0]}, stop 2: {v2}{pm[1]} (mean approach, "
              "B per τ)")  # fmt: skip
    if result.impact_energy is not None:
        e1, e2 = result.impact_energy
        pm = _plus_minus(result.impact_energy_se)
        share = result.impact_energy_share
        of = "" if share is None else f" ({100 * share:.3g} % of all dissipated)"
        print(f"impact energy       stop 1: {e1:.4g}{pm[0]}, stop 2: {e2:.4g}{pm[1]} per period"
              + of)  # fmt: skip
    if result.peak_impulse is not None and result.peak_impulse > 0:
        print(f"largest impulse     {result.peak_impulse:.4g}")
    print(f"steps               {result.steps} ({result.contact_steps} with contact)")
    print(f"wall time           {result.wall_s * 1e3:.2f} ms ({result.method})")


# --------------------------------------------------------------------------- chains of N cells

# A chain's per-cell fields (in ChainParams' messages) -> the flag a user types.
CHAIN_FLAGS: dict[str, str] = {"n_cells": "--cells", "sigma": "--sigmas", "g1": "--gaps",
                               "g2": "--gaps"}  # fmt: skip


def number_list(text: str) -> list[float]:
    """An argparse type: numbers separated by commas (``0.1,0.2,0.3``), one per cell."""
    items = text.split(",")
    try:
        return [float(v) for v in items]
    except ValueError:
        bad = next(v for v in items if not _is_float(v))
        raise argparse.ArgumentTypeError(
            f"must be numbers separated by commas, one per cell (e.g. 0.1,0.2,0.3), got "
            f"{text!r} ({bad.strip()!r} is not a number)"
        ) from None


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _chain_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cells", type=positive_int, default=1,
                   help="N, cells in series (docs/chains.md); N > 1 runs method euler unless "
                   "--method exponential")  # fmt: skip
    p.add_argument("--gaps", type=number_list, default=None, metavar="G1,…,GN",
                   help="per-cell clearances, both stops of cell j at g_j (default: --gap, "
                   "--g1, --g2 in every cell)")  # fmt: skip
    p.add_argument("--sigmas", type=number_list, default=None, metavar="S1,…,SN",
                   help="per-cell beam stiffness σ_j (default: --sigma in every cell)")  # fmt: skip


_INDEXED = re.compile(r"\b(g1|g2|sigma)\[(\d+)\]")


def _chain_terms(message: str, args: argparse.Namespace, names: Mapping[str, str]) -> str:
    """A ``ChainParams`` message in the command line's terms: ``g1[2] must be >= 0, got -1.0``
    becomes ``--gaps value 3 (cell 3) must be >= 0, got -1.0 (--gaps 0.1,0.2,-1)``."""
    typed = {"--gaps": args.gaps, "--sigmas": args.sigmas}
    head = re.match(r"(g1|g2|sigma)\b", message)
    if head is None:  # n_cells, or a cell field given once for every cell
        return in_flag_terms(message, {**names, "n_cells": "--cells"})
    flag = CHAIN_FLAGS[head.group(1)]
    values = typed[flag]
    if values is None:
        return in_flag_terms(message, names)
    message = _INDEXED.sub(lambda m: f"{flag} value {int(m.group(2)) + 1} (cell "
                           f"{int(m.group(2)) + 1})", message)  # fmt: skip
    message = flag + message[head.end() :] if message.startswith(head.group(1)) else message
    message = message.replace("(n_cells = ", "(--cells ")
    if "values:" in message:  # the wrong length: the message shows the list already
        return message
    return f"{message} ({flag} {','.join(f'{v:g}' for v in values)})"


def _chain(args: argparse.Namespace, names: Mapping[str, str]) -> Any:
    """The ``ChainParams`` of the command line, its errors in the command line's terms."""
    from worker.model.chain import ChainParams

    if args.gaps is not None and (args.g1 is not None or args.g2 is not None):
        raise ValueError("--gaps sets both stops of every cell: give it without --g1 and --g2")
    cell = _flagged(names, lambda: _params(args, args.gamma_r))
    gaps = None if args.gaps is None else tuple(args.gaps)
    sigmas = None if args.sigmas is None else tuple(args.sigmas)
    try:
        return ChainParams(cell, args.cells, sigma=sigmas, g1=gaps, g2=gaps)
    except ValueError as exc:
        raise ValueError(_chain_terms(str(exc), args, names)) from None


def _stop_bands(chain: Any) -> list[tuple[float, float]] | None:
    """The stop bands of the infinite lattice of the chain's cell, or ``None`` for a graded
    chain (cells of different σ: no single lattice)."""
    from worker.model.chain import stop_bands

    if len({p.sigma for p in chain.cells}) > 1:
        return None
    return stop_bands(chain.cells[0])


#: What ``point`` and ``spectrum`` say when they pick the method of a chain of N > 1 cells.
_CHAIN_METHOD_NOTE = "euler (the method that runs chains of N > 1 cells)"


def _cmd_chain_point(args: argparse.Namespace) -> int:
    """``point --cells N``: an impacting chain's last cell (Γ_N), Γ_j,lin at every cell and the
    infinite lattice's stop bands."""
    from worker.model.chain import chain_linear_transmittance_db
    from worker.simulate import simulate_chain_point

    names = _flags(args)
    chain = _chain(args, names)
    chosen = args.method is None and chain.n_cells > 1
    if chosen:
        args = argparse.Namespace(**{**vars(args), "method": "euler"})
    settings = _flagged(names, lambda: _settings(args))
    result = _flagged({**names, "n_cells": "--cells"},
                      lambda: simulate_chain_point(chain, settings))  # fmt: skip
    if chain.n_cells == 1:  # the unit cell: what point prints without --cells
        if args.json:
            print(json.dumps(result.as_dict()))
        if result.failed:
            raise Failure(f"the point failed: {result.reason}")
        if not args.json:
            _print_point(result)
        return 0
    try:
        lin: list[float] | None = [float(v) for v in chain_linear_transmittance_db(chain)]
    except ValueError:  # undamped resonance: no steady state (the point fails too)
        lin = None
    bands = _stop_bands(chain)
    if args.json:
        d = {**result.as_dict(), "cells": chain.n_cells, "cell_transmittance_linear_db": lin,
             "stop_bands": None if bands is None else
             [[lo, hi if math.isfinite(hi) else None] for lo, hi in bands]}  # fmt: skip
        print(json.dumps(d))
        if chosen:
            print(f"method: {_CHAIN_METHOD_NOTE}", file=sys.stderr)
    if result.failed:
        raise Failure(f"the point failed: {result.reason}")
    if args.json:
        return 0
    if chosen:
        print(f"method: {_CHAIN_METHOD_NOTE}")
    print(f"cells               {chain.n_cells} (Γ below is the last cell's, Γ_N)")
    _print_point(result)
    if result.cell_transmittance_db is not None:
        cells = ", ".join(f"{v:.4f}" for v in result.cell_transmittance_db)
        print(f"Γ_j by cell         {cells} dB (cell 1 first)")
    if lin is not None:
        print(f"Γ_j,lin by cell     {', '.join(f'{v:.4f}' for v in lin)} dB (cell 1 first)")
    if bands is None:
        print("stop bands (γ_r)    n/a (cells of different σ: no single infinite lattice)")
    else:
        shown = ", ".join(f"[{lo:.4g}, {hi:.4g}]" if math.isfinite(hi) else f"[{lo:.4g}, ∞)"
                          for lo, hi in bands)  # fmt: skip
        print(f"stop bands (γ_r)    {shown or 'none'} (the infinite lattice, undamped)")
    return 0


def _cmd_spectrum(args: argparse.Namespace) -> int:
    from worker.simulate import simulate_chain_point, simulate_point

    names = _flags(args)
    chained = args.cells > 1 or args.gaps is not None or args.sigmas is not None
    chosen = chained and args.method is None and args.cells > 1
    if chosen:
        args = argparse.Namespace(**{**vars(args), "method": "euler"})
    settings = _flagged(names, lambda: _settings(args))
    # Both ends checked first, each named by its flag (the frequencies between are in range).
    for end in ("start", "stop"):
        value = getattr(args, f"gamma_r_{end}")
        _flagged(_flags(args, gamma_r=f"--gamma-r-{end}"), lambda v=value: _params(args, v))
    rows = []
    for g in np.linspace(args.gamma_r_start, args.gamma_r_stop, args.num):
        if chained:  # Γ_N of a chain (docs/chains.md), its cells' values in the JSON
            at = argparse.Namespace(**{**vars(args), "gamma_r": float(g)})
            chain = _chain(at, names)
            r = _flagged({**names, "n_cells": "--cells"},
                         lambda c=chain: simulate_chain_point(c, settings))  # fmt: skip
        else:
            params = _flagged(names, lambda g=g: _params(args, float(g)))
            r = _flagged(names, lambda p=params: simulate_point(p, settings))
        rows.append((float(g), r))
    if chosen:
        print(f"method: {_CHAIN_METHOD_NOTE}", file=sys.stderr if args.json else sys.stdout)
    if args.json:
        print(json.dumps([{"gamma_r": g, **r.as_dict()} for g, r in rows]))
        return 0
    head = ("gamma_r", "Gamma_dB", "se_dB", "theta_eff", "outcome", "period", "|mu|", "ms")
    print("{:>8}  {:>11}  {:>7}  {:>9}  {:<9}  {:>6}  {:>6}  {:>7}".format(*head))
    for g, r in rows:
        # "-" where a value does not apply, so every row has every column
        gam = "-" if r.transmittance_db is None else f"{r.transmittance_db:11.5f}"
        se = "-" if r.transmittance_db_se is None else f"{r.transmittance_db_se:7.3f}"
        th = "-" if r.theta_eff is None else f"{r.theta_eff:9.4f}"
        per = str(r.response_period) if r.response_period else "-"
        mu = "-" if r.floquet_multiplier is None else f"{r.floquet_multiplier:6.3f}"
        print(f"{g:8.4f}  {gam:>11}  {se:>7}  {th:>9}  {r.outcome:<9}  {per:>6}  {mu:>6}  "
              f"{r.wall_s * 1e3:7.2f}")  # fmt: skip
    return 0


def _cmd_warmup(args: argparse.Namespace) -> int:
    from worker.compile_progress import compile_progress
    from worker.simulate import kernels_cached, warm_up

    methods = list(dict.fromkeys(args.method or METHODS))  # given order, no repeats
    total = time.perf_counter()
    for m in methods:
        cached = kernels_cached(m)
        what = {True: "loading from numba's cache", False: "compiling (once per machine)"}.get(
            cached, "compiling or loading"
        )
        print(f"{m}: {what} ...", flush=True)
        t0 = time.perf_counter()
        with compile_progress(m) if cached is not True else contextlib.nullcontext():
            warm_up(m, quiet=True)
        now = kernels_cached(m)
        on_disk = {True: "cached on disk", False: "NOT cached on disk"}.get(now, "cache unknown")
        print(f"{m}: ready in {time.perf_counter() - t0:.1f} s ({on_disk})", flush=True)
    print(f"{len(methods)} method{'s' if len(methods) != 1 else ''} ready in "
          f"{time.perf_counter() - total:.1f} s")  # fmt: skip
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``point``, ``spectrum`` and ``warmup``."""
    p = sub.add_parser(
        "point",
        help="simulate one point",
        description="Simulate one point of the cell in this process and print its "
        "transmittance Γ, the same cell without stops (Γ_lin) and the impact effect, the "
        "effective mass, how it ended (linear, periodic, irregular, unsettled or failed) and "
        "its cost. Exit status 1 when the point failed.",
    )
    _cell_arguments(p)
    p.add_argument("--gamma-r", type=float, default=1.0, help="excitation frequency γ_r")
    _chain_arguments(p)
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.set_defaults(func=_cmd_point)

    p = sub.add_parser(
        "spectrum",
        help="transmittance over a γ_r range",
        description="Simulate the cell at evenly spaced frequencies γ_r in this process and "
        "print one row per frequency: Γ, its standard error, θ_eff, the outcome, the response "
        "period, the Floquet multiplier and the time. A study (`impactcell run`) does the same "
        "on a cluster, for grids of any axes.",
    )
    _cell_arguments(p)
    p.add_argument("--gamma-r-start", type=float, default=0.2, help="first γ_r")
    p.add_argument("--gamma-r-stop", type=float, default=6.0, help="last γ_r")
    p.add_argument("--num", type=positive_int, default=30, help="frequencies, evenly spaced")
    _chain_arguments(p)
    p.add_argument("--json", action="store_true", help="a JSON list on stdout")
    p.set_defaults(func=_cmd_spectrum)

    p = sub.add_parser(
        "warmup",
        help="compile the numba kernels ahead (or load them from numba's on-disk cache)",
        description="Compile the numba kernels of the given solver methods (default: every "
        "method), or load them from numba's on-disk cache when they are there, so that no "
        "point, study or dask worker pays for the compilation later.",
    )
    p.add_argument(
        "--method",
        nargs="+",
        action="extend",
        choices=METHODS,
        default=None,
        metavar="M",
        help=f"methods to warm up: {', '.join(METHODS)} (default all)",
    )
    p.set_defaults(func=_cmd_warmup)  # fmt: skip
