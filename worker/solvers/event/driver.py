"""The event solver's run: preparation, reset from a full state, and its own failure reasons."""

from __future__ import annotations

import numpy as np

from worker.model import System
from worker.solvers import measure as ms
from worker.solvers.base import ExactMonodromy, KernelRun
from worker.solvers.event import kernel as ek
from worker.solvers.event import monodromy as mono
from worker.solvers.event import primitives as pm
from worker.solvers.event.regimes import MAX_COND, prepare_event
from worker.solvers.event.roots import STACK, STACK_COLS
from worker.solvers.settings import SolverSettings

DEFAULT_GRID = 64
DEFAULT_EVENT_TOL = 1e-12
DEFAULT_MAX_EVENTS_PER_PERIOD = 1000
# Event log rows per period of the exact monodromy matrix's run (an orbit with more events per
# period gets the finite differences instead)
LOG_ROWS_PER_PERIOD = 64


class EventRun(KernelRun):
    """A point integrated event by event (``docs/solvers.md``).

    ``steps_per_period`` is the sub-grid of event brackets (default 64; it sets the cost, not
    the answer). ``event_tol`` is the event-time tolerance relative to the period (Newton is
    stopped below it and polished once more). The setting ``max_events_per_period`` (default
    1000) ends a chattering run.
    """

    name = "event"

    @classmethod
    def compile_helpers(cls) -> None:
        """Compile the exact monodromy matrix's replay (reached only at a point's first
        orbit) into numba's cache if it is not there."""
        mono.compile_monodromy()

    @classmethod
    def check_options(cls, event_tol: float = DEFAULT_EVENT_TOL, **others: object) -> float:
        """Validated ``event_tol``; other options are refused (the event budget is the solver
        setting ``max_events_per_period``)."""
        super().check_options(**others)
        if (
            isinstance(event_tol, bool)
            or not isinstance(event_tol, (int, float))
            or not (0.0 < event_tol < 1e-2)
        ):
            raise ValueError(f"event_tol must be in (0, 0.01), got {event_tol!r}")
        return float(event_tol)

    def __init__(self, sys_: System, settings: SolverSettings, *args, **options) -> None:
        super().__init__(sys_, settings, *args)
        event_tol = self.check_options(**options)
        self.max_events = settings.max_events_per_period or DEFAULT_MAX_EVENTS_PER_PERIOD
        p = sys_.params
        N = sys_.ndof
        nzm = 2 * N + 2
        self.spp = settings.steps_per_period or DEFAULT_GRID
        ea = prepare_event(sys_, self.spp)
        if ea.cond > MAX_COND:
            raise ValueError(
                f"event solver: a regime's eigenvector matrix is too ill-conditioned "
                f"(cond {ea.cond:.3g} > {MAX_COND:.0e}; e.g. a defective, undamped system)"
            )
        self.ea = ea
        self.bilateral = p.g1 + p.g2 <= 0.0
        self.h = 2.0 * np.pi / p.gamma_r / self.spp
        self.y = np.zeros(nzm)
        self.evlog = np.zeros((0, ek.EV_COLS))
        self.minvx = np.ascontiguousarray(sys_.Minv @ sys_.X)  # the impulse's direction
        self.arrays = (
            ea.nzr, ea.nk, ea.eh, ea.sp, ea.lam, ea.V, ea.Vi, ea.R, ea.RV, ea.B4, ea.Pin, ea.Qout,
            *pm.measure_tables(ea.lam, ea.RV, ea.nk, p.gamma_r), ea.D, ea.fidx, ea.fcs, ea.cosg,
            ea.sing,
            self.minvx, sys_.G, p.g1, p.g2, self.bilateral, N,
            self.spp, p.gamma_r, self.f_scale, event_tol, self.max_events, p.e1, p.e2,
        )  # fmt: skip
        cplx = [np.zeros(nzm, dtype=complex) for _ in range(6)]  # al, ae, c1, c2, cw, Ew
        self.work = (
            np.zeros(nzm), *cplx, np.zeros(nzm), np.zeros((STACK, STACK_COLS)), np.zeros(nzm),
            np.zeros(nzm, dtype=complex),  # a0: a measured segment's start
        )  # fmt: skip

    def _reset(self) -> None:
        nx = self.nx
        self.y[:nx] = self.x
        self.y[nx] = self.f_scale
        self.y[nx + 1] = 0.0
        ea = self.ea
        _, _, a, _, _, cw, _, _, _, _, _ = self.work
        ek.start_state(self.y, self.kst, ea.R, ea.RV, ea.Vi, ea.lam, ea.nk, self.bilateral,
                       self.sys.ndof, self.sys.params.g1, self.sys.params.g2, self.h, a,
                       cw)  # fmt: skip

    def _save(self) -> object:
        return self.y.copy(), self.work[1].copy()  # the state and its modal coefficients

    def _restore(self, extra: object) -> None:
        y, al = extra  # type: ignore[misc]
        self.y[:] = y
        self.work[1][:] = al

    def keep_history(self, cap: int) -> None:
        super().keep_history(cap)
        self.evlog = np.zeros((cap, ek.EV_COLS))
        self.kst[ek.K_EVLOG] = 0.0

    def history_rows_per_period(self) -> int:
        return self.spp + 64

    def history(self, params, kappa: float) -> dict[str, np.ndarray]:
        out = super().history(params, kappa)
        count = int(self.kst[ek.K_EVLOG])
        cap = self.evlog.shape[0]
        order = np.r_[count % cap : cap, 0 : count % cap] if count > cap else np.arange(count)
        out["events"] = self.evlog[order]
        return out

    def _advance(self, n, measure, checks, rows, samples):
        return ek.event_kernel(
            self.y, self.x, self.kst, self.ring, n, measure, checks, rows, samples, self.hist,
            self.xh, self.evlog, *self.arrays, self.lin_L, self.lin_xp, self.lin_amp,
            self.lin_gate, self.div_limit, self.tol, *self.work,
        )  # fmt: skip

    def run_from(self, x0: np.ndarray, n: int, measure: bool, exact: bool, rows: np.ndarray,
                 samples: np.ndarray) -> tuple[ExactMonodromy | None, int, int]:  # fmt: skip
        """:meth:`KernelRun.run_from`; the exact monodromy matrix (``monodromy.py``) replays the
        run's event log through the regimes' propagators and the impacts' saltation matrices.
        An orbit that starts with the tip on a stop moving into it (an impact at τ = 0) gets
        the matrix at its first release instead (the same multipliers; the map is one-sided at
        τ = 0), if it is stuck there until then. None for one that starts leaving a stop, where
        a history is being recorded (left alone), the log overflows or the replay refuses."""
        self.reset(x0)
        # the replay's saltation matrices are those of plastic impacts
        exact = exact and self.hist.shape[0] == 0 and not self.sys.params.elastic
        from_stop = self.kst[ek.K_PENDING] > 0.0
        if self.kst[ek.K_PENDING] < 0.0 or self.kst[ek.K_SKIP_ON] != 0.0:
            exact = False
        kept = self.evlog
        if exact:
            self.evlog = np.zeros((LOG_ROWS_PER_PERIOD * n, ek.EV_COLS))
        try:
            done, code, _ = self.advance(n, measure, 0, rows, samples)
            count = int(self.kst[ek.K_EVLOG])
            if not exact or done < n or code != ms.END_NONE or count > self.evlog.shape[0]:
                return None, done, code
            ea = self.ea
            J = np.zeros((self.nx, self.nx))
            p = self.sys.params
            status = mono.monodromy(
                self.evlog, count, x0, self.x, self.f_scale, 2.0 * np.pi / p.gamma_r, n,
                int(self.kst[ek.K_REGIME]), ea.lam, ea.V, ea.Vi, ea.nk, ea.R, ea.Pin, ea.Qout,
                self.minvx, self.sys.G, p.g1, p.g2, self.sys.ndof, from_stop, J,
            )  # fmt: skip
            if status != mono.M_OK:
                return None, done, code
            return ExactMonodromy(J, bool(from_stop)), done, code
        finally:
            self.evlog = kept

    def failure_reason(self, code: int) -> str:
        period = int(self.kst[ms.K_PERIOD])
        if code == ms.END_CHATTER:
            return (
                f"event budget exceeded: more than {self.max_events} events in period {period} "
                f"(chattering; the solver setting max_events_per_period raises the budget)"
            )
        return super().failure_reason(code)
