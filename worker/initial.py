"""Initial states of a point: rest, the linear steady state, seeded random states, and their
projection onto the admissible set (docs/solvers.md, "Initial states and sweep lines").

A point's mapping may carry ``"initial": {"kind": "rest"|"linear"|"random", "seed": int | None,
"index": int}``. ``rest`` is the zero state (also what an absent key means). ``linear`` is the
closed-form steady state of the cell without stops at τ = 0 (forcing phase 0). ``random`` is
the linear state plus Gaussian perturbations, deterministic from ``(seed, index)`` only.
Every state is projected onto the admissible set (:func:`project_admissible`) before it is used.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from worker.checks import integer
from worker.model import CellParams, System, assemble, steady_state

__all__ = ["INITIAL_KINDS", "initial_state", "parse_initial", "project_admissible"]

INITIAL_KINDS = ("rest", "linear", "random")
MAX_SEED = 2**63 - 1  # numpy's SeedSequence takes any non-negative int; keep it an int64
# A tip within this fraction of |W|·|u| of a stop is on it (round-off of Wᵀu); likewise a
# tip velocity within it of |W|·|q| is zero.
AT_STOP_RTOL = 1e-12


def parse_initial(initial: Mapping[str, Any] | str | None) -> tuple[str, int, int]:
    """``(kind, seed, index)`` of an ``"initial"`` entry (``None``: rest; a bare kind name is
    accepted too). A ``None`` seed is 0, so a random state is always reproducible."""
    if initial is None:
        return "rest", 0, 0
    if isinstance(initial, str):
        initial = {"kind": initial}
    if not isinstance(initial, Mapping):
        raise ValueError(f"initial must be a mapping with a 'kind', got {initial!r}")
    unknown = set(initial) - {"kind", "seed", "index"}
    if unknown:
        raise ValueError(f"initial has unknown keys {sorted(unknown)} (kind, seed, index)")
    kind = initial.get("kind", "rest")
    if kind not in INITIAL_KINDS:
        raise ValueError(f"initial kind must be one of {', '.join(INITIAL_KINDS)}, got {kind!r}")
    seed = initial.get("seed")
    seed = 0 if seed is None else integer("initial seed", seed, 0, MAX_SEED)
    index = integer("initial index", initial.get("index", 0), 0, MAX_SEED)
    return str(kind), seed, index


def project_admissible(sys_: System, x: np.ndarray) -> np.ndarray:
    """``x`` (``[u; q]``) moved onto the admissible set of ``sys_``'s stops (a new array).

    A tip beyond a stop (``w_tip = Wᵀu > g̃1`` or ``< −g̃2``) is put on that stop by the
    smallest change of the modal displacements ``η`` in the mass-normalised metric: the modes
    are mass-normalised (``∫φ_iφ_j dx = δ_ij``, the beam block of M is I in both couplings), so
    ``|Δη|`` is the L² norm of the change of the beam's deflection shape and the minimiser is
    ``Δη = φ(1)(w* − w_tip)/|φ(1)|²``; ``s`` is untouched (the gaps do not depend on it). A tip
    on a stop that moves into it (``Wᵀq > 0`` on stop 1, ``< 0`` on stop 2; either sign when
    both gaps are zero) loses that velocity the same way: ``Δη̇ = −φ(1) Wᵀq/|φ(1)|²``. An
    admissible state is returned unchanged; "beyond", "on" and "into" allow for the round-off
    of ``Wᵀu`` and ``Wᵀq`` (``AT_STOP_RTOL``), so projecting twice changes nothing.
    """
    N = sys_.ndof
    out = np.array(x, dtype=float)
    if out.shape != (2 * N,) or not np.all(np.isfinite(out)):
        raise ValueError(f"a state must be {2 * N} finite numbers, got shape {out.shape}")
    p = sys_.params
    W = sys_.W
    ww = float(W @ W)
    u, q = out[:N], out[N:]  # views: corrections land in out
    # Round-off of Wᵀu itself: a tip within it of a stop is on the stop (the kernels agree),
    # and a state projected once is left unchanged by a second projection.
    tol = AT_STOP_RTOL * max(p.g1, p.g2, float(np.abs(W) @ np.abs(u)))
    w = float(W @ u)
    if w - p.g1 > tol:
        u += W * ((p.g1 - w) / ww)
    elif -p.g2 - w > tol:
        u += W * ((-p.g2 - w) / ww)
    w = float(W @ u)
    wd = float(W @ q)
    tol_v = AT_STOP_RTOL * float(np.abs(W) @ np.abs(q))
    if (p.g1 - w <= tol and wd > tol_v) or (p.g2 + w <= tol and wd < -tol_v):
        q -= W * (wd / ww)
    return out


def initial_state(
    params: CellParams, initial: Mapping[str, Any] | str | None, forcing: bool = True
) -> np.ndarray:
    """The state ``[u; q]`` at τ = 0 that ``initial`` names, projected onto the admissible set.

    ``rest``: zeros. ``linear``: the closed-form steady state without stops at forcing phase 0
    (``LinearTail.xp0``; zeros with ``forcing`` off). ``random``: the linear state ``x_lin``
    plus ``S·z`` on the displacements and ``S·γ_r·z`` on the velocities, ``z`` standard normal
    from ``numpy.random.default_rng([seed, index])`` and ``S = max(|u_lin|∞, |q_lin|∞/γ_r, g̃1,
    g̃2)`` (the size of the linear motion or of the clearances, whichever is larger, so the
    draws reach the stops). Raises ``ValueError`` for a bad entry, or ``linear``/``random`` at
    an undamped resonance (no linear steady state).
    """
    kind, seed, index = parse_initial(initial)
    sys_ = assemble(params)
    N = sys_.ndof
    if kind == "rest":
        return np.zeros(2 * N)
    ss = steady_state(sys_, forcing=forcing)
    if ss is None:
        raise ValueError(
            f"initial {kind!r}: no linear steady state (γ_r = {params.gamma_r:g} is an undamped "
            "resonance)"
        )
    x = ss.state_at_phase_zero()
    if kind == "random":
        g = params.gamma_r
        scale = max(
            float(np.max(np.abs(x[:N]))), float(np.max(np.abs(x[N:]))) / g, params.g1, params.g2
        )
        z = np.random.default_rng([seed, index]).standard_normal(2 * N)
        x = x + scale * np.concatenate([z[:N], g * z[N:]])
    return project_admissible(sys_, x)
