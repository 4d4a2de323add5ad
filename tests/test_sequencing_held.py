"""Grid sequencing on a cut lattice: the nodes held on the fine grid are held at their prescribed
positions on every coarse level; the nodes held only on a coarse grid (free fine nodes beside the
held outline, the "guessed holds") are placed where the sheet puts them (sequencing._HoldFit)."""

import copy
from dataclasses import replace
import time

import numpy as np

from clothsim.bench import Case, _load
from clothsim.solvers.newton import NewtonSolver, sequencing as S
from clothsim.solvers.options import newton_options
from clothsim.solvers.tuning import NewtonTuning


def _circle(div):
    case = Case("ci", "configs/garments/circle_cap.yaml", [f"panels.0.divisions=[{div},{div}]"], ("newton",))
    return _load(case, "newton", 1e-7, 60.0)


def test_coarse_levels_hold_the_fine_held_nodes_at_their_prescribed_positions(monkeypatch):
    model, state, _ = _circle(64)
    hier = S._hierarchy(model, 1e-3)
    seen = []
    orig = S._solve_level

    def spy(level, st, e, max_iter, deadline, *rest):
        m = level.model
        li = [lv.model for lv in hier.levels].index(m)
        held = m.fixed_axes.copy()
        fit = hier.fits[li]
        if fit is not None:
            held[fit.g] = False  # the guessed holds: placed, not prescribed
        seen.append(float(np.abs(st.positions[held] - m.prescribed_positions[held]).max()))
        return orig(level, st, e, max_iter, deadline, *rest)

    monkeypatch.setattr(S, "_solve_level", spy)
    trial = S.grid_sequence(model, state, 1e-7, 1e-3, time.perf_counter() + 60)
    assert trial is not None and len(seen) >= 1
    assert all(err < 1e-12 for err in seen), seen
    held = model.fixed_axes
    assert np.abs(trial.positions[held] - state.positions[held]).max() < 1e-12


def test_the_hold_fit_reproduces_an_affine_sheet_exactly():
    # the extrapolation from the anchor through the nearest free nodes is exact for a sheet that is
    # an affine map of its rest state (whatever map: a stretch, a shear, a tilt out of the plane)
    model, state, _ = _circle(64)
    hier = S._hierarchy(model, 1e-3)
    li = next(i for i, f in enumerate(hier.fits) if f is not None)
    fit, m = copy.copy(hier.fits[li]), hier.levels[li].model  # (the cached hierarchy's fit left alone)
    assert fit.g.size > 20 and fit.ok.all()
    A = np.array([[1.1, 0.05, 0.0], [-0.02, 0.95, 0.0], [0.3, -0.4, 1.0]])
    t = np.array([0.01, -0.02, 0.005])
    src = m.rest_positions @ A.T + t
    fit.xo = model.rest_positions[fit.o] @ A.T + t
    dst = np.zeros_like(src)
    fit.place(src, dst)
    assert np.abs(dst[fit.g] - src[fit.g]).max() < 1e-12


def test_a_hold_placed_inside_the_mold_falls_back_to_its_flat_guess():
    model, state, _ = _circle(64)
    hier = S._hierarchy(model, 1e-3)
    li = next(i for i, f in enumerate(hier.fits) if f is not None)
    fit, m = hier.fits[li], hier.levels[li].model
    pos = m.prescribed_positions.copy()
    pos[fit.g] += [0.0, 0.0, 0.002]  # placed 2 mm above the flat guess: outside the sphere
    inside = fit.g[:5]
    pos[inside] = [0.05, 0.05, -0.02]  # the sphere's centre
    fit.outside(m, pos)
    assert np.array_equal(pos[inside], m.prescribed_positions[inside])
    rest = fit.g[5:]
    assert np.array_equal(pos[rest], m.prescribed_positions[rest] + [0.0, 0.0, 0.002])


def test_guessed_holds_end_near_the_fine_solution(monkeypatch):
    # on the last coarse level, as it is solved, the guessed holds are within 0.3 of the flat
    # guess's distance from where the converged fine sheet has those nodes (measured: 0.21)
    model, state, settings = _circle(112)
    final = state.copy()
    res = NewtonSolver(model, newton_options(settings)).solve(final, settings.model_copy(update={"e": 1e-9}))
    assert res.status == "converged"
    hier = S._hierarchy(model, 1e-3)
    last = len(hier.levels) - 1
    fit, m = hier.fits[last], hier.levels[last].model
    seen = {}
    orig = S._solve_level

    def spy(level, st, *args):
        if level is hier.levels[last]:
            seen["pos"] = st.positions.copy()
        return orig(level, st, *args)

    monkeypatch.setattr(S, "_solve_level", spy)
    S.grid_sequence(model, state, 1e-7, 1e-3, time.perf_counter() + 60)
    want = final.positions[fit.fine]
    flat = np.abs(m.prescribed_positions[fit.g] - want).max()
    placed = np.abs(seen["pos"][fit.g] - want).max()
    assert flat > 1e-4 and placed < 0.3 * flat, (placed, flat)


def test_placed_holds_save_a_fine_newton_iteration_on_the_circle():
    model, state, settings = _circle(112)

    def run(on):
        st = state.copy()
        options = replace(newton_options(settings), tuning=NewtonTuning(hold_fit=on))
        res = NewtonSolver(model, options).solve(st, settings.model_copy(update={"e": 1e-7}))
        assert res.status == "converged"
        return res.iterations, st

    (k_on, a), (k_off, b) = run(True), run(False)
    assert k_on == 3 and k_off == 4, (k_on, k_off)  # the sequencing and 2 fine iterations, not 3
    assert np.abs(a.positions - b.positions).max() < 1e-6  # the same equilibrium (to e's scale)
