"""Model parameters and the assembly of M, C, K, W, X (docs/model.md §2–4).

Pure numpy; nothing here runs inside the time loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cache

import numpy as np

MAX_MODES = 30
COUPLINGS = ("paper", "full")


# --------------------------------------------------------------------------- modal data


@cache
def _betas(n: int) -> tuple[float, ...]:
    """Roots of cos β cosh β = -1, solved as cos β + 1/cosh β = 0 (no overflow, no cancellation)."""
    out = []
    for i in range(1, n + 1):
        b = (i - 0.5) * math.pi
        for _ in range(100):
            ch = math.cosh(b)
            f = math.cos(b) + 1.0 / ch
            df = -math.sin(b) - math.sinh(b) / (ch * ch)
            step = f / df
            b -= step
            if abs(step) < 1e-15 * b:
                break
        out.append(b)
    return tuple(out)


def betas(n: int) -> np.ndarray:
    """First ``n`` clamped–free eigenvalues β_i (docs/model.md §2)."""
    _check_modes(n)
    return np.array(_betas(n))


def _sigma_i(b: float) -> float:
    # (sinh β - sin β)/(cosh β + cos β), divided through by cosh β so large β stays finite.
    ch = math.cosh(b)
    return (math.tanh(b) - math.sin(b) / ch) / (1.0 + math.cos(b) / ch)


def _one_minus_sigma_i(b: float) -> float:
    # 1 - σ_i without cancellation: (e^-β + cos β + sin β)/(cosh β + cos β).
    return (math.exp(-b) + math.cos(b) + math.sin(b)) / (math.cosh(b) + math.cos(b))


def tip_values(n: int) -> np.ndarray:
    """φ_i(1) = 2(-1)^(i+1)."""
    _check_modes(n)
    return np.array([2.0 * (-1.0) ** i for i in range(n)])


def mode_means(n: int) -> np.ndarray:
    """d_i = ∫₀¹ φ_i dx = 2σ_i/β_i."""
    return np.array([2.0 * _sigma_i(b) / b for b in betas(n)])


def mode_shape(i: int, x: np.ndarray | float, derivative: int = 0) -> np.ndarray:
    """Cancellation-free φ_i(x) (``derivative`` 0) or φ_i''(x) (``derivative`` 2).

    φ = (cosh βx - σ sinh βx) - cos βx + σ sin βx. The first bracket equals
    ½(1-σ)e^{βx} + ½(1+σ)e^{-βx}; with 1-σ computed without cancellation it is exact for
    every mode, where the textbook form loses all digits once βx ≳ 35.
    """
    _check_modes(i)
    if derivative not in (0, 2):
        raise ValueError(f"derivative must be 0 or 2, got {derivative}")
    b = _betas(i)[i - 1]
    s = _sigma_i(b)
    oms = _one_minus_sigma_i(b)
    x = np.asarray(x, dtype=float)
    hyper = 0.5 * oms * np.exp(b * x) + 0.5 * (1.0 + s) * np.exp(-b * x)
    if derivative == 0:
        return hyper - np.cos(b * x) + s * np.sin(b * x)
    return b * b * (hyper + np.cos(b * x) - s * np.sin(b * x))


def _check_modes(n: int) -> None:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_MODES:
        raise ValueError(f"modes must be an integer in 1…{MAX_MODES}, got {n!r}")


# --------------------------------------------------------------------------- parameters


def _finite(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    return v


def _positive(name: str, value: float) -> float:
    v = _finite(name, value)
    if v <= 0.0:
        raise ValueError(f"{name} must be > 0, got {v}")
    return v


def _nonnegative(name: str, value: float) -> float:
    v = _finite(name, value)
    if v < 0.0:
        raise ValueError(f"{name} must be >= 0, got {v}")
    return v


@dataclass(frozen=True)
class CellParams:
    """Non-dimensional parameters of one point (docs/model.md §3).

    Parameters
    ----------
    theta, sigma, gamma_s, gamma_r : float
        Mass ratio, beam stiffness parameter, inverse mass frequency, excitation frequency (> 0).
    xi : float
        Damping ratio of the mass's dashpot (>= 0); also the beam's Rayleigh ratio unless
        ``xi_b`` is given.
    g1, g2 : float
        Clearances to stop 1 and stop 2 (>= 0); zero gaps pin the tip.
    modes : int
        Number of beam modes, 1…30.
    coupling : {"paper", "full"}
        Eq. 29 as published, or the consistent Lagrangian coupling.
    xi_b : float or None
        Beam Rayleigh damping ratio; ``None`` means ``xi``.
    """

    theta: float
    sigma: float
    gamma_s: float
    gamma_r: float
    xi: float = 0.05
    g1: float = 0.1
    g2: float = 0.1
    modes: int = 5
    coupling: str = "paper"
    xi_b: float | None = None

    def __post_init__(self) -> None:
        for name in ("theta", "sigma", "gamma_s", "gamma_r"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        for name in ("xi", "g1", "g2"):
            object.__setattr__(self, name, _nonnegative(name, getattr(self, name)))
        if self.xi_b is not None:
            object.__setattr__(self, "xi_b", _nonnegative("xi_b", self.xi_b))
        _check_modes(self.modes)
        object.__setattr__(self, "modes", int(self.modes))
        if self.coupling not in COUPLINGS:
            raise ValueError(
                f"coupling must be one of {', '.join(COUPLINGS)}, got {self.coupling!r}"
            )

    @property
    def beam_xi(self) -> float:
        """The beam's Rayleigh damping ratio."""
        return self.xi if self.xi_b is None else self.xi_b

    @property
    def base_scale(self) -> float:
        """θγ_s: the base amplitude in units of B (Γ = 20 log10(A_s/θγ_s))."""
        return self.theta * self.gamma_s


@dataclass(frozen=True)
class System:
    """Assembled matrices of ``M ü + C u̇ + K u = F(τ) + X(-λ1 + λ2)``.

    ``u = [η_1 … η_n, s]``. ``F(τ) = e_s (f_sin sin γ_r τ + f_cos cos γ_r τ)``.
    """

    params: CellParams
    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    W: np.ndarray  # gap gradient: w_tip = Wᵀu
    X: np.ndarray  # contact force direction
    d: np.ndarray  # mode means: s_b = dᵀη
    f_sin: float
    f_cos: float
    Minv: np.ndarray = field(repr=False)

    @property
    def ndof(self) -> int:
        """Number of generalised coordinates (modes + 1)."""
        return self.M.shape[0]

    @property
    def G(self) -> float:
        """Wᵀ M⁻¹ X > 0: the tip's inverse effective mass for a contact impulse."""
        return float(self.W @ self.Minv @ self.X)

    @property
    def kappa(self) -> float:
        """Rigid-body momentum factor of the effective mass (1 paper, 1 + θ full)."""
        return 1.0 if self.params.coupling == "paper" else 1.0 + self.params.theta

    def omega_max(self) -> float:
        """Largest undamped natural frequency of the free system, sqrt(max eig M⁻¹K)."""
        ev = np.linalg.eigvals(self.Minv @ self.K)
        return float(np.sqrt(np.max(np.abs(ev))))

    def state_matrix(self) -> np.ndarray:
        """First-order matrix A of ``ẋ = A x`` with ``x = [u; q]``."""
        n = self.ndof
        A = np.zeros((2 * n, 2 * n))
        A[:n, n:] = np.eye(n)
        A[n:, :n] = -self.Minv @ self.K
        A[n:, n:] = -self.Minv @ self.C
        return A

    def augmented_matrix(self) -> np.ndarray:
        """``ż = A_aug z`` with ``z = [u; q; cos γ_r τ; sin γ_r τ]``: the harmonic forcing
        carried in the state, so free flight is one linear system (no particular solution
        needed, exact even at an undamped resonance)."""
        n = self.ndof
        g = self.params.gamma_r
        A = np.zeros((2 * n + 2, 2 * n + 2))
        A[: 2 * n, : 2 * n] = self.state_matrix()
        fs = self.Minv[:, -1]  # M⁻¹ e_s
        A[n : 2 * n, 2 * n] = fs * self.f_cos
        A[n : 2 * n, 2 * n + 1] = fs * self.f_sin
        A[2 * n, 2 * n + 1] = -g
        A[2 * n + 1, 2 * n] = g
        return A


def rayleigh_constants(omegas: np.ndarray, xi_b: float) -> tuple[float, float]:
    """Rayleigh α_R, β_R fixed at modes 1 and min(5, n) (docs/model.md §4)."""
    if len(omegas) == 1:
        return 2.0 * xi_b * omegas[0], 0.0
    wa, wb = omegas[0], omegas[min(5, len(omegas)) - 1]
    return 2.0 * xi_b * wa * wb / (wa + wb), 2.0 * xi_b / (wa + wb)


def assemble(p: CellParams) -> System:
    """Build M, C, K, W, X for ``p`` (docs/model.md §4)."""
    n = p.modes
    b = betas(n)
    d = mode_means(n)
    tip = tip_values(n)
    N = n + 1

    M = np.zeros((N, N))
    M[:n, :n] = np.eye(n)
    M[:n, n] = -d
    if p.coupling == "paper":
        M[n, n] = 1.0 / p.theta
    else:
        M[n, :n] = -d
        M[n, n] = 1.0 / p.theta + 1.0

    k_beam = p.sigma * b**4
    K = np.diag(np.append(k_beam, 1.0 / (p.theta * p.gamma_s**2)))

    omegas = b**2 * math.sqrt(p.sigma)
    alpha_r, beta_r = rayleigh_constants(omegas, p.beam_xi)
    C = np.zeros((N, N))
    C[:n, :n] = np.diag(alpha_r + beta_r * k_beam)
    C[n, n] = 2.0 * p.xi / (p.theta * p.gamma_s)

    W = np.append(tip, 0.0)
    X = np.append(tip, 1.0) if p.coupling == "paper" else W.copy()

    # M is block-triangular (paper) or symmetric positive definite (full); a dense inverse of a
    # (n+1)-square matrix is exact enough and is computed once per point.
    Minv = np.linalg.inv(M)
    return System(
        params=p,
        M=M,
        C=C,
        K=K,
        W=W,
        X=X,
        d=d,
        f_sin=1.0 / p.gamma_s,
        f_cos=2.0 * p.xi * p.gamma_r,
        Minv=Minv,
    )


# --------------------------------------------------------------------------- linear references


@dataclass(frozen=True)
class SteadyState:
    """The impact-free steady state in closed form: ``u(τ) = Re(U e^{iγ_r τ})`` (docs/model.md §7).

    It is the response of the cell without stops (gaps → ∞), and the steady state of any point
    whose tip provably never reaches a stop again.
    """

    params: CellParams
    U: np.ndarray  # complex amplitudes of u = [η_1 … η_n, s]
    kappa: float
    d: np.ndarray
    W: np.ndarray

    @property
    def amplitude(self) -> float:
        """A_s = |U_s|."""
        return float(abs(self.U[-1]))

    @property
    def transmittance_db(self) -> float:
        """Γ = 20 log10(A_s / θγ_s) (Eq. 32)."""
        return 20.0 * math.log10(self.amplitude / self.params.base_scale)

    @property
    def theta_eff(self) -> float:
        """θ_eff from the first harmonics (Eq. 35); for a harmonic motion the phase-portrait
        slope ⟨ṡ_b ṡ⟩/⟨ṡ²⟩ is Re(Ŝ_b/Ŝ) too, so both estimators equal this value."""
        ratio = (self.d @ self.U[:-1]) / self.U[-1]
        theta = self.params.theta
        return float((self.kappa - theta * ratio.real) / (1.0 + theta))

    @property
    def tip_amplitude(self) -> float:
        """|Ŵ|: the largest |w_tip| over the orbit."""
        return float(abs(self.W @ self.U))

    def state_at_phase_zero(self) -> np.ndarray:
        """``[u; q]`` at forcing phase 0 (τ a whole number of periods)."""
        g = self.params.gamma_r
        return np.concatenate([self.U.real, (1j * g * self.U).real])


def steady_state(sys_: System, forcing: bool = True) -> SteadyState | None:
    """The closed-form impact-free steady state, or ``None`` at an undamped resonance (the
    forcing frequency on a natural frequency of an undamped system: no steady state)."""
    p = sys_.params
    g = p.gamma_r
    H = sys_.K - g * g * sys_.M + 1j * g * sys_.C
    e_s = np.zeros(sys_.ndof)
    e_s[-1] = 1.0
    try:
        h = np.linalg.solve(H, e_s)
    except np.linalg.LinAlgError:
        return None
    # |H⁻¹| >= |H⁻¹ e_s|: a response 1e13 times the size of what H maps it to is a singular H
    if not np.all(np.isfinite(h)) or np.max(np.abs(h)) * np.max(np.abs(H)) > 1e13:
        return None
    # F(τ) = e_s (f_sin sin γτ + f_cos cos γτ) = Re(e_s (f_cos - i f_sin) e^{iγτ})
    f = complex(sys_.f_cos, -sys_.f_sin) if forcing else 0j
    return SteadyState(params=p, U=h * f, kappa=sys_.kappa, d=sys_.d, W=sys_.W)


def linear_transmittance_db(p: CellParams) -> float:
    """Γ of the impact-free system (gaps → ∞): the closed-form frequency response (model.md §7)."""
    ss = steady_state(assemble(p))
    if ss is None:
        raise ValueError(f"no steady state: undamped resonance at gamma_r = {p.gamma_r}")
    return ss.transmittance_db


def pinned_transmittance_db(p: CellParams) -> float:
    """Γ with the tip pinned (g̃1 = g̃2 = 0): linear response of the system constrained to Wᵀu = 0.

    The constraint is eliminated with a null-space basis Z of Wᵀ (u = Z v), which is the exact
    constrained linear system.
    """
    sys_ = assemble(p)
    g = p.gamma_r
    # Null space of Wᵀ (1 × N), orthonormal.
    _, _, vt = np.linalg.svd(sys_.W[None, :])
    Z = vt[1:].T
    # Constraint force direction X must be eliminated with the same test space when M, X
    # are not symmetric: project with a left null space of Xᵀ.
    _, _, vtx = np.linalg.svd(sys_.X[None, :])
    Y = vtx[1:].T
    H = Y.T @ (sys_.K - g * g * sys_.M + 1j * g * sys_.C) @ Z
    e_s = np.zeros(sys_.ndof)
    e_s[-1] = 1.0
    v = np.linalg.solve(H, Y.T @ e_s)
    s_amp = abs((Z @ v)[-1]) * abs(1.0 / p.gamma_s + 2j * p.xi * g)
    return 20.0 * math.log10(s_amp / p.base_scale)
