"""Chains of N cells in series, without stops (docs/model.md §11): the assembled linear chain,
its closed-form steady state at every cell, and the infinite lattice (transfer matrix, Bloch
exponent, stop bands).

Cell 1's outer mass is tied to the base by the cell's spring and dashpot, cell j's to cell
j − 1's by the same spring and dashpot, the last cell is free. Every cell is the unit cell of
§4 (its modes, coupling and stops); σ and the gaps may differ from cell to cell.
"""

from __future__ import annotations

import cmath
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from worker.checks import check_field, integer, shown
from worker.model.params import CellParams
from worker.model.references import unit_response
from worker.model.system import System, assemble

__all__ = [
    "MAX_ASSEMBLED",
    "MAX_CELLS",
    "ChainParams",
    "ChainSteadyState",
    "ChainSystem",
    "assemble_chain",
    "bloch_exponent",
    "chain_linear_transmittance_db",
    "chain_steady_state",
    "chain_transfer_transmittance_db",
    "effective_mass",
    "stop_bands",
    "transfer_matrix",
]

# A finite chain of up to 1000 cells; longer chains are what the infinite lattice (stop bands,
# Bloch exponent) describes.
MAX_CELLS = 1000
# The assembled chain is dense, as the unit cell is (so N = 1 is the unit cell to the bit):
# 2048 unknowns are 34 MB a matrix, its complex H 67 MB. Longer chains take the transfer
# recursion, O(N) in time and memory.
MAX_ASSEMBLED = 2048
_PER_CELL = ("sigma", "g1", "g2")
_CELL_FIELDS = {f.name: dict(f.metadata) for f in dataclasses.fields(CellParams)}


@dataclass(frozen=True)
class ChainParams:
    """N unit cells in series (docs/model.md §11).

    Parameters
    ----------
    cell : CellParams
        The cell: θ, γ_s, γ_r, ξ, ξ_b, modes and coupling are those of every cell; its σ, g1
        and g2 are every cell's unless given per cell.
    n_cells : int
        N, in 1 … 1000.
    sigma, g1, g2 : sequence of float, optional
        One value per cell (cell 1 first), each in the range of the ``CellParams`` field: a
        graded chain. The gaps are kept for the impacting chain; the linear chain ignores them.

    Raises
    ------
    ValueError
        N out of range, a per-cell list of the wrong length or a value out of range, naming
        the field, the value and what is allowed.
    """

    cell: CellParams
    n_cells: int
    sigma: tuple[float, ...] | None = None
    g1: tuple[float, ...] | None = None
    g2: tuple[float, ...] | None = None
    cells: tuple[CellParams, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.cell, CellParams):
            raise ValueError(f"cell must be a CellParams, got {shown(self.cell)}")
        n = integer("n_cells", self.n_cells, 1, MAX_CELLS)
        object.__setattr__(self, "n_cells", n)
        for name in _PER_CELL:
            values = getattr(self, name)
            if values is not None:
                object.__setattr__(self, name, _per_cell(name, values, n))
        cells = tuple(
            dataclasses.replace(
                self.cell,
                **{k: getattr(self, k)[j] for k in _PER_CELL if getattr(self, k) is not None},
            )
            for j in range(n)
        )
        object.__setattr__(self, "cells", cells)


def _per_cell(name: str, values: Any, n: int) -> tuple[float, ...]:
    """A per-cell list checked: one value per cell, each in the ``CellParams`` field's range."""
    if isinstance(values, str | bytes) or not isinstance(values, Sequence | np.ndarray):
        raise ValueError(
            f"{name} must be a list of one value per cell (n_cells = {n}), got {shown(values)}"
        )
    if len(values) != n:
        raise ValueError(
            f"{name} must have one value per cell (n_cells = {n}), got {len(values)} values: "
            f"{shown(list(values))}"
        )
    return tuple(check_field(f"{name}[{j}]", v, _CELL_FIELDS[name]) for j, v in enumerate(values))


@dataclass(frozen=True)
class ChainSystem:
    """Assembled ``M ü + C u̇ + K u = F(τ) + Σ_j X_j(−λ1_j + λ2_j)`` of a chain.

    ``u = [η^(1); s_1; …; η^(N); s_N]``; ``F(τ) = e_{s_1}(f_sin sin γ_r τ + f_cos cos γ_r τ)``
    (the base drives cell 1 only). Row j of ``W`` gives cell j's tip, ``w_tip_j = W[j] @ u``;
    row j of ``X`` is the direction of cell j's contact force.
    """

    params: ChainParams
    cells: tuple[System, ...] = field(repr=False)
    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    W: np.ndarray
    X: np.ndarray
    s_index: np.ndarray  # positions of s_1 … s_N in u
    f_sin: float
    f_cos: float
    Minv: np.ndarray = field(repr=False)

    @property
    def ndof(self) -> int:
        """Number of generalised coordinates, N(n + 1)."""
        return self.M.shape[0]

    @property
    def delassus(self) -> np.ndarray:
        """``W M⁻¹ Xᵀ`` (N × N): diagonal, the unit cells' G, since M is block-diagonal (an
        impact in one cell moves no other cell's velocities)."""
        return self.W @ self.Minv @ self.X.T


def assemble_chain(cp: ChainParams) -> ChainSystem:
    """Build the chain's M, C, K, W, X (docs/model.md §11) from its cells' unit-cell systems.

    Each cell's block is its unit cell's (whose s entries already hold the spring and dashpot
    towards the previous mass, or the base); the spring and dashpot towards the next mass add
    ``k``, ``c`` to ``s_j``'s diagonal and ``−k``, ``−c`` between ``s_j`` and ``s_{j+1}``. For
    N = 1 nothing is added: the unit cell's matrices, bit for bit.
    """
    N = cp.n_cells
    b = cp.cell.modes + 1
    ndof = N * b
    if ndof > MAX_ASSEMBLED:
        raise ValueError(
            f"n_cells × (modes + 1) must be <= {MAX_ASSEMBLED} to assemble the chain, got {ndof} "
            f"(n_cells {N}, modes {cp.cell.modes}); chain_linear_transmittance_db and "
            "chain_transfer_transmittance_db take any n_cells"
        )
    systems = tuple(assemble(p) for p in cp.cells)
    M = np.zeros((ndof, ndof))
    C = np.zeros((ndof, ndof))
    K = np.zeros((ndof, ndof))
    Minv = np.zeros((ndof, ndof))
    W = np.zeros((N, ndof))
    X = np.zeros((N, ndof))
    for j, sys_ in enumerate(systems):
        block = slice(j * b, (j + 1) * b)
        M[block, block] = sys_.M
        C[block, block] = sys_.C
        K[block, block] = sys_.K
        Minv[block, block] = sys_.Minv
        W[j, block] = sys_.W
        X[j, block] = sys_.X
    s_index = np.arange(1, N + 1) * b - 1
    k, c = _spring(systems[0])
    for j in range(N - 1):
        a, z = s_index[j], s_index[j + 1]
        K[a, a] += k
        K[a, z] = K[z, a] = -k
        C[a, a] += c
        C[a, z] = C[z, a] = -c
    first = systems[0]
    return ChainSystem(
        params=cp,
        cells=systems,
        M=M,
        C=C,
        K=K,
        W=W,
        X=X,
        s_index=s_index,
        f_sin=first.f_sin,
        f_cos=first.f_cos,
        Minv=Minv,
    )


def _spring(sys_: System) -> tuple[float, float]:
    """The spring k = 1/(θγ_s²) and dashpot c = 2ξ/(θγ_s) between neighbouring masses: the
    unit cell's s entries of K and C (which tie its mass to the base)."""
    return float(sys_.K[-1, -1]), float(sys_.C[-1, -1])


# --------------------------------------------------------------------------- finite chain


@dataclass(frozen=True)
class ChainSteadyState:
    """The chain's impact-free steady state ``u(τ) = Re(U e^{iγ_r τ})`` (docs/model.md §11)."""

    params: ChainParams
    U: np.ndarray  # complex amplitudes of u = [η^(1); s_1; …; η^(N); s_N]
    s_index: np.ndarray
    W: np.ndarray

    @property
    def amplitudes(self) -> np.ndarray:
        """A_s of every cell, ``|U_{s_j}|``, cell 1 first."""
        return np.array([float(abs(self.U[i])) for i in self.s_index])

    @property
    def transmittance_db(self) -> np.ndarray:
        """Γ_j = 20 log10(A_{s_j}/θγ_s) of every cell; the last is Γ_N."""
        # math.log10 one by one, as the unit cell computes it: N = 1 gives its Γ to the bit
        scale = self.params.cell.base_scale
        return np.array([20.0 * math.log10(a / scale) for a in self.amplitudes])

    @property
    def tip_amplitudes(self) -> np.ndarray:
        """|Ŵ_j| of every cell: the largest |w_tip| of cell j over the orbit."""
        # one dot product per cell, as the unit cell computes it (a matrix product may round
        # otherwise)
        return np.array([float(abs(w @ self.U)) for w in self.W])


def chain_steady_state(cs: ChainSystem) -> ChainSteadyState | None:
    """The chain's closed-form impact-free steady state, or ``None`` at an undamped resonance.

    ``U = H⁻¹ e_{s_1}(f_cos − i f_sin)`` with ``H = K − γ_r² M + iγ_r C``, the same arithmetic
    as the unit cell's ``steady_state`` (so N = 1 reproduces it bit for bit).
    """
    h = unit_response(cs.K, cs.M, cs.C, cs.params.cell.gamma_r, int(cs.s_index[0]))
    if h is None:
        return None
    f = complex(cs.f_cos, -cs.f_sin)
    return ChainSteadyState(params=cs.params, U=h * f, s_index=cs.s_index, W=cs.W)


def chain_linear_transmittance_db(cp: ChainParams) -> np.ndarray:
    """Γ_j,lin of every cell of the chain without stops (the closed form; the last is Γ_N,lin).

    The assembled solve up to ``MAX_ASSEMBLED`` unknowns (N = 1: the unit cell's Γ to the bit),
    the transfer recursion beyond (the two agree within 1e-9 dB).
    """
    if cp.n_cells * (cp.cell.modes + 1) > MAX_ASSEMBLED:
        return chain_transfer_transmittance_db(cp)
    ss = chain_steady_state(assemble_chain(cp))
    if ss is None:
        raise ValueError(f"no steady state: undamped resonance at gamma_r = {cp.cell.gamma_r}")
    return ss.transmittance_db


def chain_transfer_transmittance_db(cp: ChainParams) -> np.ndarray:
    """Γ_j,lin of every cell by transfer matrices from the free end (docs/model.md §11).

    Starting at the last mass (``S_N = 1``, no force beyond it) and stepping towards the base
    with ``T_j⁻¹``: O(N) work for any N, and stable inside stop bands, where the response grows
    in that direction. Independent of :func:`chain_steady_state` (condensed cells, no assembly).
    """
    g = cp.cell.gamma_r
    systems = [assemble(p) for p in cp.cells]
    k, c = _spring(systems[0])
    z = complex(k, g * c)
    # ln|S_j| kept apart from a unit-modulus S_j: in a stop band |S_0/S_N| reaches e^{5000}
    # at N = 1000, far beyond a float
    log_s = np.empty(cp.n_cells + 1)
    log_s[cp.n_cells] = 0.0
    s, f = 1.0 + 0j, 0j  # S_j and F_{j+1} (the force of the spring beyond mass j), over |S_j|
    for j in range(cp.n_cells, 0, -1):
        # mass j: −γ² m_j S_j = F_j − F_{j+1}; spring j: F_j = z (S_{j−1} − S_j)
        f = f - g * g * _condensed_mass(systems[j - 1], g) * s
        s = s + f / z
        size = abs(s)
        if not (size > 0.0 and math.isfinite(size)):
            raise ValueError(f"no steady state: undamped resonance at gamma_r = {g}")
        log_s[j - 1] = log_s[j] + math.log(size)
        s, f = s / size, f / size
    # S_0 is the base, |U_g| = θγ_s: Γ_j = 20 log10 |S_j/S_0|
    return (log_s[1:] - log_s[0]) * (20.0 / math.log(10.0))


# --------------------------------------------------------------------------- infinite lattice


def _condensed_mass(sys_: System, gamma_r: float, damped: bool = True) -> complex:
    """m(γ) = M_ss + γ² M_sη D⁻¹ M_ηs, ``D = K_ηη − γ² M_ηη + iγ C_ηη``: the cell's mass once its
    beam's modes are eliminated at frequency γ (units of ρAl)."""
    x = gamma_r * gamma_r
    D = sys_.K[:-1, :-1] - x * sys_.M[:-1, :-1]
    if damped:
        D = D + 1j * gamma_r * sys_.C[:-1, :-1]
    # paper coupling has M_sη = 0: the mass alone, whatever the beam does
    coupling = sys_.M[-1, :-1] @ np.linalg.solve(D, sys_.M[:-1, -1])
    return complex(sys_.M[-1, -1] + x * coupling)


def effective_mass(p: CellParams, gamma_r: float | None = None) -> complex:
    """The cell's dynamic effective mass m(γ_r) in units of ρAl (docs/model.md §11): the force
    the springs and dashpots pass on to the cell over its outer mass's acceleration.

    ``full``: ``1/θ + 1 + γ² Σ d_i²/(σβ_i⁴ − γ² + iγ c_i)``, which is ``M_eff/ρAl`` of Eq. 35
    (κ = 1 + θ) at a linear point. ``paper``: ``1/θ``, the outer mass alone (Eq. 29 has no clamp
    reaction). ``gamma_r`` defaults to the cell's.
    """
    return _condensed_mass(assemble(p), p.gamma_r if gamma_r is None else gamma_r)


def transfer_matrix(p: CellParams, gamma_r: float | None = None) -> np.ndarray:
    """The cell's 2 × 2 transfer matrix: ``[S_j; F_{j+1}] = T [S_{j−1}; F_j]``.

    S_j is mass j's complex amplitude, F_j = z(S_{j−1} − S_j) the force of the spring and
    dashpot between masses j − 1 and j on mass j, z = k + iγc.
    ``T = [[1, −1/z], [γ²m, 1 − γ²m/z]]``, det T = 1. ``gamma_r`` defaults to the cell's.
    """
    g = p.gamma_r if gamma_r is None else gamma_r
    sys_ = assemble(p)
    k, c = _spring(sys_)
    z = complex(k, g * c)
    xm = g * g * _condensed_mass(sys_, g)
    return np.array([[1.0, -1.0 / z], [xm, 1.0 - xm / z]], dtype=complex)


def bloch_exponent(p: CellParams, gamma_r: float | None = None) -> complex:
    """The Bloch exponent q of the infinite lattice of this cell: ``S_{j+1} = e^{−q} S_j``,
    ``cosh q = 1 − γ²m/(2z)``, with ``Re q ≥ 0``.

    Re q is the attenuation per cell (nepers; 20/ln 10 = 8.686 dB a neper), Im q the phase per
    cell (π: neighbours in antiphase). Computed as ``q = 2 asinh √(−γ²m/(4z))``, which keeps its
    digits near q = 0 where ``acosh`` of a number near 1 loses half of them.
    """
    g = p.gamma_r if gamma_r is None else gamma_r
    sys_ = assemble(p)
    k, c = _spring(sys_)
    y = -g * g * _condensed_mass(sys_, g) / (4.0 * complex(k, g * c))
    q = 2.0 * cmath.asinh(cmath.sqrt(y))
    if q.real < 0.0 or (q.real == 0.0 and q.imag < 0.0):
        q = -q  # cosh is even: the wave that decays away from the base
    return q


def stop_bands(p: CellParams) -> list[tuple[float, float]]:
    """The stop bands of the undamped infinite lattice of cell ``p``: the intervals of γ_r where
    ``|cos κ| = |1 − γ²m/(2k)| > 1`` (no real Bloch wavenumber κ), ξ and ξ_b set to 0.

    Each band edge is an exact eigenvalue: ``γ²m(γ) = 0`` (the free cell) or ``= 4k`` (the cell
    on a spring 4k, the antiphase wave); the poles of m (the clamped beam's frequencies, in
    ``full`` coupling) lie inside bands. The last band may extend to ``inf``.
    """
    sys_ = assemble(dataclasses.replace(p, xi=0.0, xi_b=0.0))
    k, _ = _spring(sys_)
    edges = [0.0]
    for stiffness in (0.0, 4.0 * k):
        K = sys_.K.copy()
        K[-1, -1] = stiffness
        # M is invertible in both couplings (det M = 1/θ in paper; SPD in full)
        x = np.linalg.eigvals(sys_.Minv @ K).real
        edges += [math.sqrt(v) for v in x if v > 0.0]
    edges += [math.sqrt(v) for v in np.diag(sys_.K)[:-1]]  # poles of m (spurious in paper)
    edges = sorted(set(edges))

    def stop(g: float) -> bool:
        return abs(1.0 - g * g * _condensed_mass(sys_, g, damped=False).real / (2.0 * k)) > 1.0

    bands: list[tuple[float, float]] = []
    bounds = [*edges, math.inf]
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        mid = 0.5 * (lo + hi) if math.isfinite(hi) else 2.0 * lo + 1.0
        if not stop(mid):
            continue
        if bands and bands[-1][1] == lo:  # a pole splits no band
            bands[-1] = (bands[-1][0], hi)
        else:
            bands.append((lo, hi))
    return bands
