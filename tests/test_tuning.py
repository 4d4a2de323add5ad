"""Issue 29 item 3: Newton's behaviour explicit. Its switches are the fields of one frozen record
(``NewtonTuning``) carried by ``NewtonOptions.tuning``, no Newton module keeps a switch of its own,
``NewtonLevel.iterate`` returns a ``StepStatus``, and the solver defaults are the scene's."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from clothsim.bench import Case, _load
from clothsim.config import SolverSettings
from clothsim.solvers import NewtonOptions, PaperOptions, RunLimits, StepStatus
from clothsim.solvers.newton import NewtonLevel, NewtonSolver
from clothsim.solvers.tuning import Curvature, NewtonTuning

NEWTON = Path(__file__).resolve().parents[1] / "clothsim" / "solvers" / "newton"
# module-level upper-case names that are no switches: the contact tolerance the paper's solver
# shares, the driver's stall window, the default contact rules' array, the caches' sizes, the
# fixed ladder of shifts a singular coarsest-grid factorisation is retried with (a safeguard)
NOT_SWITCHES = {"PENETRATION_TOL", "STALL_NEWTON", "RULES", "HIERARCHY_CACHE", "LAYOUT_CACHE", "COARSE_SHIFTS"}


def test_no_newton_module_keeps_a_switch_of_its_own():
    found = []
    for path in sorted(NEWTON.rglob("*.py")):
        for node in ast.parse(path.read_text()).body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
                node, ast.AnnAssign) else []
            for t in targets:
                if isinstance(t, ast.Name) and t.id.isupper() and not t.id.startswith("_") and t.id not in NOT_SWITCHES:
                    found.append(f"{path.name}:{t.id}")
    assert not found, found


def test_every_tuning_field_is_documented_and_the_record_is_frozen():
    src = (NEWTON.parent / "tuning.py").read_text()
    cls = next(n for n in ast.parse(src).body if isinstance(n, ast.ClassDef) and n.name == "NewtonTuning")
    body = cls.body
    documented = {a.target.id for a, d in zip(body, body[1:]) if isinstance(a, ast.AnnAssign)
                  and isinstance(d, ast.Expr) and isinstance(d.value, ast.Constant) and isinstance(d.value.value, str)}
    fields = {f.name for f in dataclasses.fields(NewtonTuning)}
    assert len(fields) >= 50 and fields == documented, fields - documented
    t = NewtonTuning()
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.hold_fit = False  # type: ignore[misc]
    assert NewtonOptions().tuning == t and hash(t) == hash(NewtonTuning())
    assert t.curvature is Curvature.FULL_WHILE_DEFINITE and NewtonTuning(curvature=1).curvature is Curvature.POSITIVE
    with pytest.raises(ValueError):
        NewtonOptions(tuning={"hold_fit": False})


def test_a_tuning_record_reaches_the_levels_and_iterate_returns_a_step_status():
    model, state, settings = _load(Case("sq", "configs/sphere_cap.yaml", ["fabric.divisions=[16,16]"]),
                                   "newton", 1e-7, None)
    assert NewtonSolver(model).fine.direct  # 289 nodes: factorised directly by default
    solver = NewtonSolver(model, NewtonOptions(tuning=NewtonTuning(direct_dofs=0)))
    assert not solver.fine.direct and solver.fine.tuning.direct_dofs == 0
    lvl = NewtonLevel(model, tuning=NewtonTuning(direct_dofs=0))
    st = state.copy()
    v, E, status = lvl.iterate(st, lvl.residual(st.positions, st.in_contact))
    assert status is StepStatus.OK and np.isfinite(v)
    # multigrid-preconditioned and direct: the same solve to the tolerance
    a, b = state.copy(), state.copy()
    NewtonSolver(model).solve(a, settings)
    solver.solve(b, settings)
    assert np.abs(a.positions - b.positions).max() < 1e-6


def test_solver_defaults_are_the_scenes():
    s = SolverSettings()
    r = RunLimits()
    assert (r.e, r.max_iterations, r.time_limit_s, r.stall_iterations) == (
        s.e, s.max_iterations, s.time_limit_s, s.stall_iterations)
    assert (PaperOptions().C, PaperOptions().max_retries) == (s.C, s.max_retries)
    assert (NewtonOptions().kink, NewtonOptions().sequencing) == (s.newton_kink, s.newton_sequencing)
