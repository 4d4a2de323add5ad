"""The one driver every solver runs under, and the run history it keeps.

``run(solver, state, limits, callback)`` calls ``solver.step`` in batches until the residual is at
most ``e`` or a limit ends the run, and owns everything around the iterations: the iteration and
time limits, stall detection, divergence, the progress callback (which may return True to stop,
scipy.optimize style), the history and the final residual check. ``limits`` is re-read between
batches, so a GUI edit of ``e`` or ``max_iterations`` reaches a running solve.

Stall detection (one detector, here): the run stalls when the best residual has not improved by
1 % within the stall window — the run's ``stall_iterations``, or the solver's ``stall_window`` when
that is smaller (Newton: 100 iterations, each of which should gain; the paper's sweeps gain little
each and use the run's window). The residual is sampled at batch ends (every iteration for Newton,
which runs one per batch). Until this refactor Newton also ran the same 1 %-gain rule with its
own 100-iteration window inside its iteration loop, beside the driver's; the driver's rule with
the window min(stall_iterations, 100) stops such a run at the same iteration, and keeps one
message and one place for the rule. A solver that cannot move at all reports NO_PROGRESS from its
step (status ``stalled`` at once; the solver's ``failure`` text, when it has one, e.g. Newton's
exactly singular system, ends the message).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping

import numpy as np

from .status import Status, StepStatus
from .common import Progress, SolveResult, energy, force_scale, residual


class History(Mapping):
    """The run record: one row per iteration — ``iteration`` (int), ``residual`` [N] (||V||_inf
    after it), ``energy`` [J], ``time`` [s] (wall-clock since the first run that appended to this
    history, counting only the runs' own time).

    Read as a mapping of those four names to arrays (copies). One record is kept per run or per
    ``Simulation`` (its start/pause segments and a composite's phases append to the same one);
    ``elapsed_s`` [s] is the summed wall time of the runs that appended. One writer (the driver);
    a reader in another thread sees a consistent prefix (rows are written before the count)."""

    KEYS = ("iteration", "residual", "energy", "time")

    def __init__(self):
        self._cols = {"iteration": np.zeros(0, np.int64), "residual": np.zeros(0),
                      "energy": np.zeros(0), "time": np.zeros(0)}
        self._n = 0
        self.elapsed_s = 0.0

    def append(self, iterations, residuals, energies, times) -> None:
        """Append k rows (each argument has length k)."""
        k = len(residuals)
        if k == 0:
            return
        n = self._n
        cols = self._cols
        cap = cols["residual"].shape[0]
        if n + k > cap:
            new = max(2 * cap, n + k, 64)
            grown = {}
            for key, a in cols.items():
                b = np.zeros(new, a.dtype)
                b[:n] = a[:n]
                grown[key] = b
            self._cols = cols = grown
        cols["iteration"][n:n + k] = iterations
        cols["residual"][n:n + k] = residuals
        cols["energy"][n:n + k] = energies
        cols["time"][n:n + k] = times
        self._n = n + k

    @property
    def size(self) -> int:
        """Number of rows (iterations recorded)."""
        return self._n

    def last_time(self) -> float:
        """[s] time of the last row (``elapsed_s`` when empty)."""
        n = self._n
        return float(self._cols["time"][n - 1]) if n else self.elapsed_s

    def copy(self) -> "History":
        h = History()
        n = self._n
        h._cols = {k: v[:n].copy() for k, v in self._cols.items()}
        h._n = n
        h.elapsed_s = self.elapsed_s
        return h

    def columns(self, *keys: str) -> tuple[np.ndarray, ...]:
        """Copies of several columns, all of the same length (one read of the row count)."""
        n = self._n
        cols = self._cols
        return tuple(cols[k][:n].copy() for k in keys)

    def __getitem__(self, key: str) -> np.ndarray:
        n = self._n  # the count first: rows below it are written in whichever arrays follow
        return self._cols[key][:n].copy()

    def __iter__(self):
        return iter(self.KEYS)

    def __len__(self) -> int:
        return len(self.KEYS)

    def __repr__(self) -> str:
        return f"History({self._n} rows, {self.elapsed_s:.3f} s)"


_STEP_STATUS = {StepStatus.CONVERGED: Status.CONVERGED, StepStatus.DIVERGED: Status.DIVERGED,
                StepStatus.NO_PROGRESS: Status.STALLED}


def run(solver, state, limits, callback=None, history: History | None = None, before_batch=None,
        initial_batch: int | None = None, target_batch_s: float = 0.05) -> SolveResult:
    """Relax ``state`` in place with ``solver`` until converged or a limit ends the run.

    limits: ``SolverSettings`` or ``RunLimits`` (e [N], max_iterations, time_limit_s [s] or None,
    stall_iterations), re-read between batches. callback(progress: Progress) after each batch and
    once at the end; True stops the run. history: the History to append to (a new one if None;
    ``SolveResult.history`` is it). before_batch(solver): called before each batch (the settings
    wrappers use it so that a GUI edit of the paper's C reaches a running relaxation).
    Batches start at ``initial_batch`` iterations (the solver's) and are sized to about
    ``target_batch_s`` [s]."""
    model = solver.model
    s = limits
    st = state
    hist = history if history is not None else History()
    t0 = time.perf_counter()
    t_base = hist.elapsed_s
    t_prev = t_base
    start_iter = st.iteration
    batch = max(1, solver.initial_batch if initial_batch is None else initial_batch)
    status, message = None, ""
    # residual at the start: a state that is already converged needs no iteration
    r0, _ = residual(model, st)
    if not math.isfinite(r0):
        status, message = Status.DIVERGED, "the initial state has a non-finite force"
    elif r0 <= s.e:
        status, message = Status.CONVERGED, f"already converged at the start (||V||_inf = {r0:.3e} N)"
    cur, cur_en = r0, math.nan
    best = stall_ref = r0
    stall_ref_iter = st.iteration
    while status is None:
        if before_batch is not None:
            before_batch(solver)
        done_before = st.iteration - start_iter
        n = min(batch, s.max_iterations - done_before)
        if solver.max_batch is not None:
            n = min(n, solver.max_batch)
        if n <= 0:
            status, message = Status.MAX_ITERATIONS, f"stopped after {s.max_iterations} iterations without converging"
            break
        tb = time.perf_counter()
        left = None if s.time_limit_s is None else s.time_limit_s - (tb - t0)
        it_before = st.iteration
        rep = solver.step(st, n, e=s.e, time_left_s=left)
        now = time.perf_counter()
        dt = now - tb
        k = rep.iterations
        if k:
            times = np.linspace(t_prev, t_base + (now - t0), k + 1)[1:]
            hist.append(np.arange(it_before + 1, it_before + 1 + k), rep.residuals[:k], rep.energies[:k], times)
            t_prev = float(times[-1])
            cur, cur_en = float(rep.residuals[k - 1]), float(rep.energies[k - 1])
        if k and dt < target_batch_s / 2:
            batch = min(batch * 2, 1 << 20)
        elif dt > target_batch_s * 2 and batch > 1:
            batch = max(1, batch // 2)
        if cur < best:
            best = cur
        if rep.status == StepStatus.DIVERGED:
            status = Status.DIVERGED
            message = (f"diverged at iteration {st.iteration} (non-finite or blown-up positions); "
                       f"kept the last finite state")
            break
        if rep.status == StepStatus.CONVERGED or cur <= s.e:
            status, message = Status.CONVERGED, f"||V||_inf = {cur:.3e} N <= e = {s.e:.3e} N"
            break
        if rep.status == StepStatus.NO_PROGRESS:
            status = Status.STALLED
            message = (f"no further progress possible at ||V||_inf = {cur:.3e} N (e = {s.e:.3e} N); "
                       f"smallest residual reached {best:.3e} N")
            if solver.failure:
                message += f"; {solver.failure}"
            break
        # stall: the best residual has not improved by 1 % within the stall window
        window = s.stall_iterations if solver.stall_window is None else min(s.stall_iterations, solver.stall_window)
        if best < 0.99 * stall_ref:
            stall_ref = best
            stall_ref_iter = st.iteration
        elif st.iteration - stall_ref_iter >= window:
            status = Status.STALLED
            message = (f"no progress over {window} iterations at ||V||_inf = {cur:.3e} N "
                       f"(e = {s.e:.3e} N); smallest residual reached {best:.3e} N")
            break
        elapsed = time.perf_counter() - t0
        if s.time_limit_s is not None and elapsed >= s.time_limit_s:
            status, message = Status.TIME_LIMIT, f"time limit {s.time_limit_s} s reached at ||V||_inf = {cur:.3e} N"
            break
        if callback is not None:
            it_done = st.iteration - start_iter
            prog = Progress(st.iteration, cur, cur_en, elapsed, it_done / elapsed if elapsed > 0 else 0.0,
                            int(st.in_contact.sum()), st, solver.name)
            if callback(prog):
                status, message = Status.STOPPED, f"stopped by request at iteration {st.iteration}"
                break
    wall = time.perf_counter() - t0
    hist.elapsed_s = t_base + wall
    # (solver.model: a frictional solve refreshes its model's friction as it goes)
    model = solver.model
    r, _ = residual(model, st)
    en = energy(model, st)
    fs = force_scale(model, st)
    if status == Status.CONVERGED and not (r <= s.e):
        # the solver's own bookkeeping said converged but the shared residual disagrees
        status, message = Status.STALLED, f"residual check failed: ||V||_inf = {r:.3e} N > e"
    res = SolveResult(
        converged=status == Status.CONVERGED,
        status=status,
        message=message,
        iterations=st.iteration - start_iter,
        residual=float(r),
        relative_residual=float(r / fs) if fs > 0 else float(r),
        energy=float(en),
        contact_count=int(st.in_contact.sum()),
        wall_time_s=wall,
        method=solver.name,
        history=hist,
        best_residual=float(min(best, r)),
    )
    if callback is not None:
        callback(Progress(st.iteration, r, en, wall, 0.0, res.contact_count, st, solver.name))
    return res
