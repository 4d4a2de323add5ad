"""Simulation: owns a scene's Model and State and runs a solver, blocking or in a background thread.

This is the one code path the viewer, the headless CLI and the sweep runner all use; none of them
contains physics. GUI callbacks only *record* edits (:meth:`Simulation.edit`); the simulation
thread applies them between solver batches. An edit of C or e reaches a running relaxation at
once; one that changes the Model (materials, constraints, fabric, mold) rebuilds it on
:meth:`reset`-like application and keeps the current positions as a warm start when the grid is
unchanged.
"""

from __future__ import annotations

import dataclasses
import math
import re
import threading
import time
import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .config import Scene, SceneError, scene_from_dict, stage_scenes
from .compile import compile_model, compile_state, run_inputs
from .material import MaterialWarning
from .model import Model, SpringFamily, State
from .mold import mold_query_many
from .records import StageReport
from .results import Result
from .solvers import History, SolveResult, load_steps, make_solver, pick_method
from .solvers import solve as run_solver
from .solvers.base import Status
from .solvers.common import energy as energy_fn, residual as residual_fn
from .solvers.friction import solve_steps


def prepare(scene: Scene, on_stage: Callable[[str], None] | None = None) -> tuple[Model, State, float]:
    """Load the mold, build the model and the initial state. Returns (model, state, seconds).
    ``on_stage(text)``, when given, is told when each of the two is done (start-up progress)."""
    t0 = time.perf_counter()
    # compile_scene's two steps, with a word after each
    model = compile_model(scene)
    if on_stage is not None:
        on_stage(f"model built ({model.node_count:,} nodes)")
    state = compile_state(scene, model)
    if on_stage is not None:
        on_stage("initial state set")
    return model, state, time.perf_counter() - t0


def warm_up(model: Model, state: State, settings) -> float:
    """Compile (or load from numba's disk cache) every kernel the solve will call, so that no
    compilation falls inside a timed run; returns the seconds spent.

    One iteration on a copy of the state covers the first step; a few on a 4 x 4 sheet with the same mold, tables and optional terms cover the rest (same array
    types, so the same compiled code) at no cost worth counting."""
    t0 = time.perf_counter()
    # one fine-grid iteration without the grid sequencing (its coarse solves run the same kernels
    # and would be thrown away); prolong_state's mold query is warmed on its own
    s = settings.model_copy(update={"max_iterations": 1, "time_limit_s": None, "newton_sequencing": False})
    run_solver(model, state.copy(), s, None)
    if model.mold is not None:
        p = np.ascontiguousarray(state.positions[:1])
        mold_query_many(model.mold.kernel_args(), p, np.empty(1), np.empty((1, 3)), np.empty((1, 3)),
                        np.empty((1, 2), np.int64))
    if pick_method(model, settings) == "newton":
        try:  # best effort: a warm-up problem must never stop the real run
            small = compile_model(_tiny_scene(model), model.mold)
            tiny = State(small.rest_positions.copy(), np.zeros(small.node_count, bool), 0)
            tiny.positions[:, 2] += 1e-3 * np.sin(np.arange(small.node_count))
            run_solver(small, tiny, s.model_copy(update={"max_iterations": 3, "newton_sequencing": False}), None)
        except Exception:  # noqa: BLE001
            pass
    return time.perf_counter() - t0


def _tiny_scene(model: Model):
    """A 4 x 4 sheet with the model's tables and terms (for warm_up), far from any mold."""
    t = model.table_list
    d = {
        "fabric": {"size": [0.01, 0.01], "divisions": [4, 4], "origin": [1e6, 1e6, 1e6],
                   "warp": {"strain": t[0].strain.tolist(), "tension": t[0].tension.tolist()},
                   "weft": {"strain": t[1].strain.tolist(), "tension": t[1].tension.tolist()}},
        "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.05}],
    }
    fam = model.families()
    if SpringFamily.SHEAR in fam:
        d["shear"] = {"stiffness": 1.0}
    if fam & {SpringFamily.BEND_WARP, SpringFamily.BEND_WEFT}:
        d["bending"] = {"stiffness": 1.0}
    if model.external_force.any():
        d["gravity"] = {"areal_density": 0.1}
    with warnings.catch_warnings():  # the model's tables warned when its scene was read
        warnings.simplefilter("ignore", MaterialWarning)
        return scene_from_dict(d)


@dataclass
class Snapshot:
    """A consistent copy of what the viewer shows."""

    positions: np.ndarray
    in_contact: np.ndarray
    iteration: int
    residual: float
    energy: float
    status: str
    iterations_per_s: float
    history_iteration: np.ndarray
    history_residual: np.ndarray
    version: int
    message: str = ""


@dataclass
class StageEnd:
    """The state a staged run reached at a stage's end (or, named "start", where it began): what
    the viewer replays. positions [m] (N, 3), in_contact (N,), the iteration, the Model then (its
    ``friction`` the friction refreshed at that equilibrium, anchored at the step before: the
    stick/slip state) and the stage's report (None for the start)."""

    name: str
    positions: np.ndarray
    in_contact: np.ndarray
    iteration: int
    model: Model
    report: dict | None = None


class Simulation:
    """A scene being solved. Thread-safe controls: start, pause, step, reset, stop, edit.

    ``status``: idle, running, paused, converged, stalled, diverged, stopped, max_iterations,
    time_limit, error."""

    def __init__(self, scene: Scene, on_progress: Callable | None = None, callback: Callable | None = None,
                 on_stage: Callable[[str], None] | None = None):
        """on_progress(sim) is told after each batch (the viewer); callback(progress) may return
        True to stop the run (scripts); on_stage(text) is told as the start-up's stages end."""
        self._lock = threading.RLock()
        self.user_callback = callback
        self._wake = threading.Condition(self._lock)
        self.on_progress = on_progress
        self._edits: list[Callable[[], None]] = []
        self._thread: threading.Thread | None = None
        self._command: str | None = None
        self._closing = False
        self._pause_requested = False
        self.version = 0
        self._load(scene, on_stage=on_stage)

    # ------------------------------------------------------------------ setup
    def _load(self, scene: Scene, keep_positions: np.ndarray | None = None,
              on_stage: Callable[[str], None] | None = None) -> None:
        model, state, t = prepare(scene, on_stage)
        if keep_positions is not None and keep_positions.shape == state.positions.shape:
            free = ~model.fixed_axes
            state.positions[free] = keep_positions[free]
        self.scene = scene
        self.model = model
        self.state = state
        self.settings = scene.solver.model_copy()
        self.prepare_s = t
        self.status = "idle"
        self.message = ""
        self.last_result: SolveResult | None = None
        # the one run record: every run of this scene (start/pause segments, steps) appends to it
        self.history = History()
        self.residual = math.nan
        self.energy = math.nan
        self.ips = 0.0
        # the load path of a staged scene (stages, friction, solver.load_steps): the stages to
        # do, the current one's load steps and how many are done, the finished stages' reports
        self._plan = None
        self._controls = None
        self._stage_model = None
        self._steps_done = 0
        self._stage_reports = []
        # what a staged run went through: [(iteration, name)] where each stage began, the state at
        # the start and at each finished stage's end (StageEnd), and whether the run pauses at the
        # current stage's end (run_stage)
        self.stage_marks: list[tuple[int, str]] = []
        self.stage_ends: list[StageEnd] = []
        self._stage_once = False
        self.version += 1

    @property
    def hist_it(self) -> np.ndarray:
        """Iteration numbers of the cumulative history."""
        return self.history["iteration"]

    @property
    def hist_res(self) -> np.ndarray:
        """||V||_inf [N] after each iteration of the cumulative history."""
        return self.history["residual"]

    @property
    def hist_en(self) -> np.ndarray:
        """Energy [J] after each iteration of the cumulative history."""
        return self.history["energy"]

    @property
    def hist_t(self) -> np.ndarray:
        """Time [s] of each iteration of the cumulative history (solver time only)."""
        return self.history["time"]

    @property
    def total_time(self) -> float:
        """Solver wall time [s] summed over this scene's runs."""
        return self.history.elapsed_s

    @property
    def method(self) -> str:
        return pick_method(self.model, self.settings)

    # ------------------------------------------------------------------ edits
    def edit(self, fn: Callable[[], None]) -> None:
        """Record an edit; it runs in the simulation thread between batches (or now if idle)."""
        with self._lock:
            if self._thread is not None and self._thread.is_alive() and self.status == "running":
                self._edits.append(fn)
            else:
                fn()

    def set_solver(self, **kw) -> None:
        """Change solver settings (validated); C, e, max_iterations apply to a running solve."""
        new = self.settings.model_validate({**self.settings.model_dump(), **kw})

        def apply():
            for k, v in new.model_dump().items():
                setattr(self.settings, k, v)
            self.scene = self.scene.model_copy(update={"solver": new})

        self.edit(apply)

    def replace_scene(self, scene: Scene, warm_start: bool = True) -> None:
        """Rebuild the model from a new scene (stops a running solve first)."""
        self.pause(wait=True)
        with self._lock:
            keep = self.state.positions.copy() if warm_start else None
            self._load(scene, keep)

    # ------------------------------------------------------------------ running
    def _callback(self, prog) -> bool:
        with self._lock:
            for fn in self._edits:
                fn()
            self._edits.clear()
            self.residual = prog.residual
            self.energy = prog.energy
            self.ips = prog.iterations_per_s
            stop = self._pause_requested or self._closing
        if self.on_progress is not None:
            self.on_progress(self)
        if self.user_callback is not None and self.user_callback(prog):
            stop = True
        return stop

    def run(self, max_iterations: int | None = None) -> SolveResult:
        """Solve in the calling thread (headless runs and sweeps), continuing from the current
        state; returns the SolveResult and keeps the cumulative history."""
        settings = self.settings
        if max_iterations is not None:
            settings = settings.model_copy(update={"max_iterations": max_iterations})
        with self._lock:
            self.status = "running"
            self._pause_requested = False
        try:
            if self._staged():
                res = self._run_steps(settings)
            else:
                res = run_solver(self.model, self.state, settings, self._callback, self.history)
        except Exception as exc:  # keep the state, report the failure
            with self._lock:
                self.status = "error"
                self.message = f"{type(exc).__name__}: {exc}"
            if self.on_progress is not None:
                try:
                    self.on_progress(self)  # (the viewer shows the error at once)
                except Exception:  # noqa: BLE001 - the solver's error is the one to report
                    pass
            raise
        with self._lock:
            self.residual = res.residual
            self.energy = res.energy
            self.last_result = res
            if res.status == "stopped" and self._pause_requested and not self._closing:
                self.status = "paused"
            elif res.status == "max_iterations" and max_iterations is not None:
                self.status = "paused"
            else:
                self.status = res.status
            self.message = res.message
            self.version += 1
        if self.on_progress is not None:
            self.on_progress(self)
        return res

    def _staged(self) -> bool:
        """Whether the scene is solved in load steps: stages, friction with the mold, or
        ``solver.load_steps`` > 1 (a scene without any pays nothing for them)."""
        return bool(self.scene.stages) or self.model.has_friction or self.settings.load_steps > 1

    def solved_along_a_path(self) -> bool:
        """Whether the run follows a loading path from the scene's start (stages, friction,
        ``solver.load_steps`` > 1): its answer is that path's, so a run started elsewhere (a fit's
        warm start) would follow another path and may end elsewhere."""
        return self._staged()

    def _stages(self) -> list:
        """[[name, Model, steps, solver, scales, forces]]: the scene's stages
        (config.stage_scenes), or the scene itself as one stage of ``solver.load_steps`` steps
        from the placed sheet. ``scales`` and ``forces``: (from, to) of the rest scale and of the
        external force [N] (N, 3) ramped over the stage's steps, or None where they do not change
        (each stage's from the previous one's; the first stage's from the scene's own, the scene
        without stages its gravity from zero)."""
        if not self.scene.stages:
            steps = int(self.settings.load_steps)
            f = self.model.external_force
            # load steps ramp the loads as they ramp the displacements: gravity from zero
            forces = (np.zeros_like(f), f) if steps > 1 and f.any() else None
            return [["", self.model, steps, None, None, forces]]
        out = []
        scale = (1.0, 1.0)
        force = self.model.external_force
        for n, (st, sc) in enumerate(stage_scenes(self.scene)):
            try:
                m = compile_model(sc)
            except SceneError as exc:  # a selector the stage set that the lattice refuses: named
                # where the stage is, not where the scene's own field would be
                why = re.sub(rf"^{re.escape(str(sc._label))}(:\d+)?: ", "", str(exc)) if sc._label else str(exc)
                raise SceneError(self.scene.locate(f"stages.{n}.set: {why}")) from None
            if m.node_count != self.model.node_count:
                raise SceneError(self.scene.locate(f"stages.{n}.set: changes the lattice"))
            new = st.scale(scale)
            # the garment's rest scale ramped over the stage (None: the design all along)
            scales = None if scale == new == (1.0, 1.0) else (scale, new)
            # the loads ramped from the previous stage's (None: unchanged, the stage's own)
            forces = None if np.array_equal(force, m.external_force) else (force, m.external_force)
            out.append([st.name or f"stage {n + 1}", m, int(st.steps), sc.solver, scales, forces])
            scale, force = new, m.external_force
        return out

    def _run_steps(self, settings) -> SolveResult:
        """The load steps still to do, stage by stage (clothsim.solvers.friction.solve_steps):
        each stage's prescribed coordinates, rest scale and external force from where the last
        one left them (the scene without stages: from the placed sheet and no load) to its values
        in its steps; a paused run goes on with the step it was in. The result's ``friction``
        holds the last stage's report and ``stages`` every stage's."""
        if self._plan is None:
            self._plan = self._stages()
            self._stage_reports = []
            self.stage_ends = [StageEnd("start", self.state.positions.copy(), self.state.in_contact.copy(),
                                        self.state.iteration, self.model)]
            self.stage_marks = []
        res = None
        while self._plan:
            name, model, steps, stage_solver, scales, forces = self._plan[0]
            if self._controls is None:
                if self.scene.stages:
                    start = self.state.positions.copy()
                else:
                    start = model.placement.apply(model.rest_positions) if steps > 1 else model.prescribed_positions
                start = np.where(model.fixed_axes, start, model.prescribed_positions)
                self._controls = load_steps(start, model.prescribed_positions, steps, scales, forces)
                self._stage_model = dataclasses.replace(model, prescribed_positions=start)
                self._steps_done = 0
                self.stage_marks = self.stage_marks + [(int(self.state.iteration), name)]
            todo = self._controls[self._steps_done:]
            # a stage's own solver fields (its set may change e), the run's limits otherwise
            s = settings if stage_solver is None else stage_solver.model_copy(
                update={"max_iterations": settings.max_iterations})
            done = self._steps_done
            from_scale = (1.0, 1.0) if scales is None else \
                (scales[0] if done == 0 else self._controls[done - 1].rest_scale)
            from_force = None if forces is None else \
                (forces[0] if done == 0 else self._controls[done - 1].external_force)
            m, res = solve_steps(self._stage_model, self.state, todo, s, self._callback, self.history,
                                 lambda mm: make_solver(mm, s), model_scale=from_scale, model_force=from_force)
            self._steps_done += int(res.friction["steps_solved"])
            self.model = m
            # the stage's design rest lengths and loads stay with it: each control sets them anew
            self._stage_model = dataclasses.replace(m, spring_rest_length=model.spring_rest_length,
                                                    spring_width=model.spring_width,
                                                    external_force=model.external_force)
            if not res.converged:
                break
            self._stage_reports.append(StageReport(
                name=name, load_steps=len(self._controls),
                **({} if scales is None else {"rest_scale": list(scales[1])}),
                converged=True, iterations=int(res.iterations), residual=float(res.residual),
                friction=res.friction).to_dict())
            # a new list, so that a reader in another thread holds a consistent one
            self.stage_ends = self.stage_ends + [StageEnd(name, self.state.positions.copy(),
                                                          self.state.in_contact.copy(), int(self.state.iteration),
                                                          m, self._stage_reports[-1])]
            self._plan.pop(0)
            self._controls = None
            if self._plan and self._stage_once:  # run_stage: pause here, between two stages
                self._stage_once = False
                with self._lock:
                    self._pause_requested = True
                nxt = self._plan[0][0]
                res = dataclasses.replace(res, converged=False, status=Status.STOPPED,
                                          message=f"stage '{name}' done; Start goes on with '{nxt}'")
                break
        if self.scene.stages and res is not None:
            rep = dict(res.friction or {})
            rep["stages"] = list(self._stage_reports)
            res = dataclasses.replace(res, friction=rep)
        return res

    def result(self, startup_s: float = 0.0) -> Result:
        """The current state as a Result (cumulative history across start/pause segments)."""
        with self._lock:
            r = self.last_result
            if r is None:
                v, _ = residual_fn(self.model, self.state)
                r = SolveResult(False, "idle", "not run", 0, v, math.nan, energy_fn(self.model, self.state),
                                int(self.state.in_contact.sum()), 0.0, self.method)
            hist = self.history.copy()
            solve = SolveResult(r.converged, r.status, r.message, self.state.iteration, r.residual,
                                r.relative_residual, r.energy, r.contact_count, self.total_time, r.method,
                                hist, r.best_residual, r.friction)
            return Result(self.scene, self.model, self.state.copy(), solve, startup_s or self.prepare_s,
                          inputs=run_inputs(self.scene))

    # background thread -------------------------------------------------
    def _worker(self) -> None:
        while True:
            with self._lock:
                while self._command is None and not self._closing:
                    self._wake.wait()
                if self._closing:
                    return
                cmd, self._command = self._command, None
            try:
                self.run(1 if cmd == "step" else None)
            except Exception:
                pass  # status/message already record the failure

    def _ensure_thread(self) -> None:
        if self._thread is None or not self._thread.is_alive():
            self._thread = threading.Thread(target=self._worker, name="clothsim-solver", daemon=True)
            self._thread.start()

    def start(self, stage_once: bool = False) -> None:
        """Start (or resume) relaxing in the background thread (``stage_once``: see run_stage)."""
        with self._lock:
            self._ensure_thread()
            if self.status != "running":
                self._stage_once = stage_once
                self._pause_requested = False
                self._command = "run"
                self.status = "running"
                self._wake.notify_all()

    def run_stage(self) -> None:
        """Run (in the background thread) until the current stage of a staged scene ends, then
        pause (the last stage: until the run ends). A scene without stages runs as start() does."""
        self.start(stage_once=True)

    def stage_list(self) -> list[dict]:
        """The loading path as the viewer lists it: per stage, name, steps, the changes it makes
        (``set`` and ``rest_scale`` as text), its state ("done", "current" or "to do") and, when
        done, its report (iterations, residual, friction). A scene without stages that is solved
        in load steps (friction, ``solver.load_steps``) is one stage; otherwise empty."""
        if not self.scene.stages and not self._staged():
            return []
        if self.scene.stages:
            rows = [{"name": st.name or f"stage {n + 1}", "steps": int(st.steps),
                     "changes": "; ".join([f"{k} = {v}" for k, v in (st.set or {}).items()]
                                          + ([f"rest_scale = {st.rest_scale}"] if st.rest_scale is not None else []))}
                    for n, st in enumerate(self.scene.stages)]
        else:
            rows = [{"name": "load steps", "steps": int(self.settings.load_steps), "changes": ""}]
        done = len(self._stage_reports)
        for n, row in enumerate(rows):
            row["state"] = "done" if n < done else "current" if n == done and self._plan is not None else "to do"
            row["report"] = self._stage_reports[n] if n < done else None
        return rows

    def step(self) -> None:
        """One iteration in the background thread (when not running)."""
        with self._lock:
            self._ensure_thread()
            if self.status != "running":
                self._command = "step"
                self.status = "running"
                self._wake.notify_all()

    def pause(self, wait: bool = False, timeout: float = 30.0) -> None:
        with self._lock:
            if self.status == "running":
                self._pause_requested = True
        if wait:
            t0 = time.perf_counter()
            while self.status == "running" and time.perf_counter() - t0 < timeout:
                time.sleep(0.005)

    def reset(self) -> None:
        """Back to the initial deformation (keeps the edited scene)."""
        self.pause(wait=True)
        with self._lock:
            self._load(self.scene)

    def close(self) -> None:
        with self._lock:
            self._closing = True
            self._pause_requested = True
            self._wake.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=10)

    def wait(self, timeout: float | None = None) -> str:
        """Block until the background run leaves 'running'; returns the status."""
        t0 = time.perf_counter()
        while self.status == "running":
            if timeout is not None and time.perf_counter() - t0 > timeout:
                break
            time.sleep(0.01)
        return self.status

    def current_residual(self) -> float:
        """||V||_inf [N] of the current state, evaluated now (under the lock, so a consistent
        state): what the viewer shows before a run has reported one."""
        with self._lock:
            return float(residual_fn(self.model, self.state)[0])

    def snapshot(self) -> Snapshot:
        with self._lock:
            return Snapshot(self.state.positions.copy(), self.state.in_contact.copy(), self.state.iteration,
                            self.residual, self.energy, self.status, self.ips,
                            *self.history.columns("iteration", "residual"), self.version,
                            self.message)


def solve(scene: Scene, callback: Callable | None = None,
          on_stage: Callable[[str, float], None] | None = None) -> Result:
    """Headless: build, relax and return a Result (the same path the viewer uses).

    ``callback(progress)`` receives clothsim.solvers.Progress after each batch; returning True
    stops the run. ``on_stage(text, seconds)`` is told as each start-up stage ends (the model
    built, the initial state set, the kernels compiled or loaded from numba's cache and tried on
    one step), with the seconds since the start.

    ``solver.time_limit_s`` bounds the start-up's first stage too: when the time since the start
    has passed it once the model and the initial state are built (the stage that grows with the
    lattice: an 800 x 800 sheet's initial spread is a sparse solve of some 20 s), the run ends
    there with status ``time_limit`` (no relaxation; the Result holds the initial state, its
    residual and energy NaN: evaluating them could compile kernels, seconds). The stage itself
    is not interrupted. The warm-up (compiling or loading the numba kernels, a minute when the
    cache is cold whatever the scene, and one trial step) is not counted. The relaxation then
    has the full time_limit_s of its own."""
    t0 = time.perf_counter()
    limit = scene.solver.time_limit_s
    stage = None if on_stage is None else (lambda text: on_stage(text, time.perf_counter() - t0))
    sim = Simulation(scene, callback=callback, on_stage=stage)
    if _startup_over(sim, limit, t0, "the model and initial state"):
        return sim.result(time.perf_counter() - t0)
    warm_up(sim.model, sim.state, sim.settings)
    if stage is not None:
        stage("kernels compiled or loaded, one step tried")
    startup = time.perf_counter() - t0
    sim.run()
    return sim.result(startup)


def _startup_over(sim: Simulation, limit: float | None, t0: float, what: str) -> bool:
    """True (and sim's last result set to status time_limit, not relaxed) when the start-up since
    t0 [s, perf_counter] has passed ``limit`` [s]."""
    took = time.perf_counter() - t0
    if limit is None or took <= limit:
        return False

    msg = (f"time limit {limit:g} s reached during start-up ({what} took {took:.1f} s); "
           f"not relaxed")
    with sim._lock:  # residual and energy not evaluated: that could compile kernels (seconds)
        sim.last_result = SolveResult(False, Status.TIME_LIMIT, msg, 0, math.nan, math.nan, math.nan,
                                      int(sim.state.in_contact.sum()), 0.0, sim.method)
        sim.status, sim.message = Status.TIME_LIMIT, msg
    return True
