"""What every solver shares: the result record, the progress record, the residual, and the
driver loop (time/iteration bounds, stall and divergence detection, history, callback).

A solver is ``solve(model, state, settings, callback=None) -> SolveResult``; it advances
``state`` in place. It never prints; it reports through ``callback(progress)``, which may return
True to stop the run (scipy.optimize style). The driver re-reads ``settings.C`` and ``settings.e``
between batches, so a GUI edit reaches a running relaxation.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from ..contact import residual_from_forces
from ..kernels import forces_and_energy

STATUSES = ("converged", "max_iterations", "time_limit", "stalled", "diverged", "stopped")


@dataclass
class Progress:
    """Reported to the callback after each batch of iterations."""

    iteration: int
    residual: float  # N, ||V||_inf
    energy: float  # J
    elapsed_s: float
    iterations_per_s: float
    contact_count: int
    state: object  # the live State (read only, between batches)
    method: str = ""


@dataclass
class SolveResult:
    """converged, status (one of STATUSES), message, iterations, residual [N] (||V||_inf, eq. 6),
    relative_residual (residual / largest spring force), energy [J], contact_count, wall_time_s,
    history: dict of arrays iteration, residual [N], energy [J], time [s]."""

    converged: bool
    status: str
    message: str
    iterations: int
    residual: float
    relative_residual: float
    energy: float
    contact_count: int
    wall_time_s: float
    method: str
    history: dict = field(default_factory=dict)
    best_residual: float = math.nan


@functools.lru_cache(maxsize=1)
def _dummy_mold_args():
    from ..mold import load_mold

    return load_mold({"plane": {"point": [0.0, 0.0, -1e9], "normal": [0.0, 0.0, 1.0]}}).kernel_args()


def model_mold_args(model):
    """(has_mold, margs): the mold's kernel arguments, or a far-away plane's (same numba type, so
    a scene without a mold compiles nothing extra and never queries it: has_mold is False)."""
    if model.mold is None:
        return False, _dummy_mold_args()
    return True, model.mold.kernel_args()


def residual(model, state, V: Optional[np.ndarray] = None) -> tuple[float, np.ndarray]:
    """(||V||_inf [N], V (N,)) at the current state."""
    has_mold, margs = model_mold_args(model)
    if V is None:
        V = np.empty(model.node_count)
    F = np.empty_like(state.positions)
    forces_and_energy(state.positions, *model.spring_args(), model.external_force, F)
    vinf = residual_from_forces(state.positions, F, model.fixed_axes, state.in_contact, has_mold, margs, V)
    return vinf, V


def energy(model, state) -> float:
    """Total potential energy [J] (springs minus external work)."""
    out = np.empty_like(state.positions)
    return forces_and_energy(state.positions, *model.spring_args(), model.external_force, out)


def force_scale(model, state) -> float:
    """Largest spring force [N] (for the relative residual)."""
    from ..kernels import spring_strains_tensions

    s = np.empty(model.spring_count)
    f = np.empty(model.spring_count)
    spring_strains_tensions(state.positions, *model.spring_args(), s, f)
    fmax = float(np.max(np.abs(f))) if f.size else 0.0
    gmax = float(np.max(np.linalg.norm(model.external_force, axis=1))) if model.node_count else 0.0
    return max(fmax, gmax)


class Driver:
    """Runs ``advance(n) -> (n_done, flag)`` batches until converged/stopped; records history.

    ``advance`` performs at most n iterations on the state, appends per-iteration residual and
    energy to the driver's buffers via ``record`` and returns a flag: 0 ok, 1 converged in batch,
    2 diverged (state restored to the last finite iterate by the solver), 3 no progress possible."""

    def __init__(self, model, state, settings, callback, method: str):
        self.model = model
        self.state = state
        self.settings = settings
        self.callback = callback
        self.method = method
        self.res: list[float] = []
        self.en: list[float] = []
        self.t: list[float] = []
        self.t0 = time.perf_counter()
        self.best = math.inf
        self.best_iter = 0
        self.stall_ref = math.inf
        self.stall_ref_iter = 0

    def record(self, residuals: np.ndarray, energies: np.ndarray) -> None:
        now = time.perf_counter() - self.t0
        n = len(residuals)
        if n == 0:
            return
        prev = self.t[-1] if self.t else 0.0
        self.t.extend(np.linspace(prev, now, n + 1)[1:].tolist())
        self.res.extend(np.asarray(residuals, float).tolist())
        self.en.extend(np.asarray(energies, float).tolist())

    def run(self, advance: Callable[[int], tuple[int, int]], initial_batch: int = 1,
            target_batch_s: float = 0.05) -> SolveResult:
        s = self.settings
        st = self.state
        start_iter = st.iteration
        batch = max(1, initial_batch)
        status, message = None, ""
        # residual at the start: a state that is already converged needs no iteration
        r0, _ = residual(self.model, st)
        if not math.isfinite(r0):
            status, message = "diverged", "the initial state has a non-finite force"
        elif r0 <= s.e:
            status, message = "converged", f"already converged at the start (||V||_inf = {r0:.3e} N)"
        self.best = r0
        self.stall_ref = r0
        self.stall_ref_iter = st.iteration
        last_report = 0.0
        while status is None:
            done_before = st.iteration - start_iter
            n = min(batch, s.max_iterations - done_before)
            if n <= 0:
                status, message = "max_iterations", f"stopped after {s.max_iterations} iterations without converging"
                break
            tb = time.perf_counter()
            n_done, flag = advance(n)
            dt = time.perf_counter() - tb
            st.iteration += n_done
            if n_done and dt < target_batch_s / 2:
                batch = min(batch * 2, 1 << 20)
            elif dt > target_batch_s * 2 and batch > 1:
                batch = max(1, batch // 2)
            cur = self.res[-1] if self.res else r0
            if cur < self.best:
                self.best = cur
                self.best_iter = st.iteration
            if flag == 2:
                status = "diverged"
                message = (f"diverged at iteration {st.iteration} (non-finite or blown-up positions); "
                           f"kept the last finite state")
                break
            if flag == 1 or cur <= s.e:
                status, message = "converged", f"||V||_inf = {cur:.3e} N <= e = {s.e:.3e} N"
                break
            if flag == 3:
                status = "stalled"
                message = (f"no further progress possible at ||V||_inf = {cur:.3e} N (e = {s.e:.3e} N); "
                           f"smallest residual reached {self.best:.3e} N")
                break
            # stall: the best residual has not improved by 1 % within stall_iterations
            if self.best < 0.99 * self.stall_ref:
                self.stall_ref = self.best
                self.stall_ref_iter = st.iteration
            elif st.iteration - self.stall_ref_iter >= s.stall_iterations:
                status = "stalled"
                message = (f"no progress over {s.stall_iterations} iterations at ||V||_inf = {cur:.3e} N "
                           f"(e = {s.e:.3e} N); smallest residual reached {self.best:.3e} N")
                break
            elapsed = time.perf_counter() - self.t0
            if s.time_limit_s is not None and elapsed >= s.time_limit_s:
                status, message = "time_limit", f"time limit {s.time_limit_s} s reached at ||V||_inf = {cur:.3e} N"
                break
            if self.callback is not None:
                it_done = st.iteration - start_iter
                prog = Progress(st.iteration, cur, self.en[-1] if self.en else math.nan, elapsed,
                                it_done / elapsed if elapsed > 0 else 0.0, int(st.in_contact.sum()), st,
                                self.method)
                if self.callback(prog):
                    status, message = "stopped", f"stopped by request at iteration {st.iteration}"
                    break
        wall = time.perf_counter() - self.t0
        r, _ = residual(self.model, st)
        en = energy(self.model, st)
        fs = force_scale(self.model, st)
        if status == "converged" and not (r <= s.e):
            # the solver's own bookkeeping said converged but the shared residual disagrees
            status, message = "stalled", f"residual check failed: ||V||_inf = {r:.3e} N > e"
        res = SolveResult(
            converged=status == "converged",
            status=status,
            message=message,
            iterations=st.iteration - start_iter,
            residual=float(r),
            relative_residual=float(r / fs) if fs > 0 else float(r),
            energy=float(en),
            contact_count=int(st.in_contact.sum()),
            wall_time_s=wall,
            method=self.method,
            history={
                "iteration": np.arange(start_iter + 1, start_iter + 1 + len(self.res)),
                "residual": np.asarray(self.res),
                "energy": np.asarray(self.en),
                "time": np.asarray(self.t),
            },
            best_residual=float(min(self.best, r)),
        )
        if self.callback is not None:
            prog = Progress(st.iteration, r, en, wall, 0.0, res.contact_count, st, self.method)
            self.callback(prog)
        return res
