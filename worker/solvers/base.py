"""What every method provides to the point engine: a kernel run over whole periods.

A method (``euler``, ``exponential``, ``event``) prepares its matrices once per point and
returns a :class:`KernelRun`. The engine drives it: ``reset`` to a state at forcing phase 0,
``advance`` a batch of periods (each filling one measurement row and one stroboscopic sample,
``measure.py``), ``save``/``restore`` around a side trip (confirming an extrapolated orbit),
``keep_history`` for time histories.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from worker.model import System
from worker.observables import theta_eff_instantaneous
from worker.solvers import measure as ms
from worker.solvers.linear import LinearTail
from worker.solvers.settings import SolverSettings

__all__ = ["ExactMonodromy", "KernelRun"]


class ExactMonodromy(NamedTuple):
    """A method's exact monodromy matrix of an orbit (``KernelRun.run_from``)."""

    matrix: np.ndarray  # nx × nx
    # the section was moved from τ = 0 to the orbit's first release: it starts stuck on a stop,
    # where the map at τ = 0 is one-sided (the same multipliers)
    shifted: bool


class KernelRun:
    """Base of every method's run: the state and arrays the kernels share.

    Subclasses set ``name`` and ``spp`` and implement ``_advance`` (one call of the method's
    compiled kernel) and, where the method keeps more state than ``x``, ``_reset``,
    ``_save`` and ``_restore``.
    """

    name = ""

    def __init__(self, sys_: System, settings: SolverSettings, tail: LinearTail,
                 forcing: bool, div_limit: float) -> None:  # fmt: skip
        self.sys = sys_
        self.settings = settings
        self.nx = 2 * sys_.ndof
        self.x = np.zeros(self.nx)
        self.kst = np.zeros(ms.KST_SIZE)
        self.ring = np.zeros((ms.RING, self.nx))
        self.f_scale = 1.0 if forcing else 0.0
        self.hist = np.zeros((0, ms.H_COLS))
        self.xh = np.zeros((0, self.nx))
        if tail.usable:
            self.lin_L, self.lin_xp = tail.L, tail.xp0
            self.lin_amp, self.lin_gate = tail.amp, tail.gate
        else:
            self.lin_L = np.zeros((0, self.nx), dtype=complex)
            self.lin_xp = np.zeros(self.nx)
            self.lin_amp, self.lin_gate = 0.0, -1.0
        self.div_limit = float(div_limit)
        self.tol = settings.periodicity_tol
        self.spp = 0

    @classmethod
    def check_options(cls, **options: object) -> None:
        """Validate method options before anything runs (the base method takes none)."""
        if options:
            raise ValueError(f"method {cls.name} takes no option {', '.join(sorted(options))}")

    @classmethod
    def check_point(cls, sys_: System, settings: SolverSettings) -> None:
        """Refuse settings this method cannot run for this point (before anything runs, so a
        refusal does not depend on whether the point needs simulating at all)."""

    # ------------------------------------------------------------------ state

    def reset(self, x0: np.ndarray) -> None:
        """Start from the full state ``x0`` at forcing phase 0 (period count and ring cleared)."""
        self.x[:] = x0
        self.kst[:] = 0.0
        w = float(self.sys.W @ x0[: self.sys.ndof])
        p = self.sys.params
        # On a stop already: its contact episode is in progress (no new impact is counted).
        if p.g1 - w <= ms.OPEN_FRAC * p.g1:
            self.kst[ms.K_CONTACT] = 1.0
        elif p.g2 + w <= ms.OPEN_FRAC * p.g2:
            self.kst[ms.K_CONTACT] = 2.0
        self._reset()

    def _reset(self) -> None:
        """Method-specific state from ``self.x``."""

    def save(self) -> tuple:
        """A snapshot of everything ``advance`` changes."""
        return (self.x.copy(), self.kst.copy(), self.ring.copy(), self._save())

    def restore(self, saved: tuple) -> None:
        """Return to a snapshot taken by :meth:`save`."""
        x, kst, ring, extra = saved
        self.x[:] = x
        self.kst[:] = kst
        self.ring[:] = ring
        self._restore(extra)

    def _save(self) -> object:
        return None

    def _restore(self, extra: object) -> None:
        pass

    def keep_history(self, cap: int) -> None:
        """Record the last ``cap`` history samples from now on (0: none)."""
        self.hist = np.zeros((cap, ms.H_COLS))
        self.xh = np.zeros((cap, self.nx))
        self.kst[ms.K_HIST] = 0.0

    def history_rows_per_period(self) -> int:
        """History samples one period may write (steps, plus events for ``event``)."""
        return max(self.spp, 1) + 8

    def history(self, params, kappa: float) -> dict[str, np.ndarray]:
        """The recorded history, oldest first (see ``simulate_point``)."""
        count = int(self.kst[ms.K_HIST])
        cap = self.hist.shape[0]
        order = np.r_[count % cap : cap, 0 : count % cap] if count > cap else np.arange(count)
        h = self.hist[order]
        sdot, sbdot = h[:, 4], h[:, 5]
        return {
            "tau": h[:, 0], "s": h[:, 1], "w_tip": h[:, 2], "s_b": h[:, 3], "s_dot": sdot,
            "s_b_dot": sbdot,
            # NaN marks where Eq. 36 is singular (ṡ ≈ 0); histories only, never a point result
            "theta_eff": theta_eff_instantaneous(sdot, sbdot, kappa, params.theta),
            "impulse1": h[:, 6], "impulse2": h[:, 7], "kind": h[:, 8].astype(np.int64),
            "state": self.xh[order],
        }  # fmt: skip

    # ------------------------------------------------------------------ stepping

    def advance(self, n: int, measure: bool, checks: int, rows: np.ndarray,
                samples: np.ndarray) -> tuple[int, int, int]:  # fmt: skip
        """Run up to ``n`` periods; returns (periods done, ``END_*`` code, period found)."""
        done, code, p = self._advance(int(n), bool(measure), int(checks), rows, samples)
        return int(done), int(code), int(p)

    def _advance(self, n: int, measure: bool, checks: int, rows: np.ndarray,
                 samples: np.ndarray) -> tuple[int, int, int]:  # fmt: skip
        raise NotImplementedError

    @classmethod
    def compile_helpers(cls) -> None:
        """Compile what the method's points reach only late (``simulate.warm_up``)."""

    def run_from(self, x0: np.ndarray, n: int, measure: bool, exact: bool, rows: np.ndarray,
                 samples: np.ndarray) -> tuple[ExactMonodromy | None, int, int]:  # fmt: skip
        """Run up to n periods from the state ``x0`` (period count cleared; the caller
        saves/restores the run) and, with ``exact``, the n-period map's exact Jacobian at
        ``x0`` where the method has one; returns (the matrix or None, periods done, ``END_*``
        code). Methods without one: None, and the engine differences the map."""
        self.reset(x0)
        done, code, _ = self.advance(n, measure, 0, rows, samples)
        return None, done, code

    def failure_reason(self, code: int) -> str:
        """Why a batch that ended with ``code`` failed (methods add their own codes)."""
        period = int(self.kst[ms.K_PERIOD])
        if code == ms.END_NONFINITE:
            return f"state stopped being finite in period {period}"
        if code == ms.END_DIVERGED:
            return (
                f"diverged: |state| exceeded {self.div_limit:.3g} (10^6 times the scale of the "
                f"linear response and the gaps) in period {period}"
            )
        return f"kernel stopped with code {code} in period {period}"
