"""Every solver against analytic cases (no mold): uniaxial strips reproduce the input table,
a uniformly pre-stretched sheet relaxes to the uniform grid, symmetry and origin independence,
the half-area rule on free borders, and the run-control contract (bounds, stop, divergence)."""

import math

import numpy as np
import pytest

import clothsim
from clothsim.compile import compile_model, compile_state

from clothsim.solvers import solve as run_solver

from conftest import ROOT, make_scene, solver_methods

METHODS = solver_methods()
WARP_T = np.array([0, 0.1, 0.3, 0.6, 1.0]), np.array([0, 5.0e4, 2.0e5, 8.0e5, 3.0e6]) * 0.0005
WEFT_T = np.array([0, 0.1, 0.3, 0.6, 1.0]), np.array([0, 12, 55, 140, 300.0])


def _prepare(scene):
    model = compile_model(scene)
    return model, compile_state(scene, model)


def _T(table, s):
    x, y = table
    return np.interp(s, x, y) if s <= x[-1] else y[-1] + (y[-1] - y[-2]) / (x[-1] - x[-2]) * (s - x[-1])


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("strain", [0.05, 0.3, 0.8])
def test_uniaxial_warp_strip_reproduces_table(method, strain):
    """A strip pulled along warp to strain s: every warp spring at s, the reaction per width (sum
    of the warp forces across any column / width) equals T_warp(s) within 1e-6 relative; the weft
    springs stay at zero strain (no Poisson effect in this model)."""
    scene = make_scene(**{"constraints.1.displacement": [0.1 * strain, 0, 0], "solver.method": method,
                          "solver.e": 1e-9})
    res = clothsim.solve(scene)
    assert res.converged, res.solve.message
    per_width = res.tension_warp.sum(axis=1) / 0.02
    np.testing.assert_allclose(per_width, _T(WARP_T, strain), rtol=1e-6)
    np.testing.assert_allclose(res.strain_warp, strain, atol=1e-6)
    assert np.abs(res.strain_weft).max() < 1e-6


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("strain", [0.2, 0.7])
def test_uniaxial_weft_strip_reproduces_table(method, strain):
    """The same along weft: a 20 x 100 mm strip pulled at its top edge; T_weft(s) per width."""
    scene = make_scene(**{
        "fabric.size": [0.02, 0.10], "fabric.divisions": [2, 10],
        "constraints": [{"nodes": "bottom", "axes": "xyz"},
                        {"nodes": "top", "axes": "xyz", "displacement": [0, 0.1 * strain, 0]}],
        "solver.method": method, "solver.e": 1e-9})
    res = clothsim.solve(scene)
    assert res.converged, res.solve.message
    per_width = res.tension_weft.sum(axis=0) / 0.02
    np.testing.assert_allclose(per_width, _T(WEFT_T, strain), rtol=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_half_area_border_springs_on_free_edges(method):
    """On a strip with free top and bottom rows, border warp springs carry half the force of the
    interior ones (half tributary width, paper Fig. 3)."""
    scene = make_scene(**{"solver.method": method, "solver.e": 1e-9})
    res = clothsim.solve(scene)
    Tw = res.tension_warp
    np.testing.assert_allclose(Tw[:, 0], 0.5 * Tw[:, 1], rtol=1e-6)
    np.testing.assert_allclose(Tw[:, -1], 0.5 * Tw[:, 1], rtol=1e-6)


PRE = {
    "fabric.size": [0.06, 0.04], "fabric.divisions": [6, 4],
    "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": [1.2, 1.1]}],
    "initial": {"perturb": 0.002, "seed": 5},
}


@pytest.mark.parametrize("method", METHODS)
def test_prestretched_sheet_relaxes_to_uniform_grid(method):
    """Perimeter stretched 20 % (warp) and 10 % (weft) about the centre, interior perturbed by
    2 mm (also out of plane): the equilibrium is the uniformly stretched grid."""
    scene = make_scene(**PRE, **{"solver.method": method, "solver.e": 1e-10})
    res = clothsim.solve(scene)
    assert res.converged, res.solve.message
    model = res.model
    c = np.array([0.03, 0.02, 0.0])
    exact = c + (model.rest_positions - c) * np.array([1.2, 1.1, 1.0])
    # stiffness ~ T'(s) * width / l0 ~ 1e3 N/m: 1e-10 N residual -> ~1e-13 m
    np.testing.assert_allclose(res.state.positions, exact, atol=1e-9)
    np.testing.assert_allclose(res.strain_warp, 0.2, atol=1e-8)
    np.testing.assert_allclose(res.strain_weft, 0.1, atol=1e-8)


@pytest.mark.parametrize("method", METHODS)
def test_symmetric_scene_gives_symmetric_result_and_origin_does_not_matter(method):
    """A sheet pinned at its corners, perimeter stretched, loaded by gravity: the result is
    mirror-symmetric in x and y, and moving the sheet's origin moves the result rigidly."""
    changes = {
        "fabric.size": [0.06, 0.06], "fabric.divisions": [6, 6],
        "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.05}],
        "initial": {},
        "gravity": {"areal_density": 0.5},
        "solver.method": method, "solver.e": 1e-10,
    }
    res = clothsim.solve(make_scene(**changes))
    assert res.converged, res.solve.message
    p = res.positions
    c = 0.03
    np.testing.assert_allclose(p[::-1, :, 0], 2 * c - p[:, :, 0], atol=1e-9)
    np.testing.assert_allclose(p[:, ::-1, 1], 2 * c - p[:, :, 1], atol=1e-9)
    np.testing.assert_allclose(p[::-1, :, 2], p[:, :, 2], atol=1e-9)
    assert p[3, 3, 2] < -1e-5  # it sags under gravity
    shift = np.array([1.5, -2.0, 0.7])
    res2 = clothsim.solve(make_scene(**changes, **{"fabric.origin": shift.tolist()}))
    np.testing.assert_allclose(res2.positions - shift, p, atol=1e-8)


@pytest.mark.parametrize("method", METHODS)
def test_max_iterations_is_exact_and_time_limit_is_honoured(method):
    """A run stops after exactly max_iterations, or at the time limit, with that status."""
    scene = make_scene(**PRE, **{"solver.method": method, "solver.e": 1e-300, "solver.max_iterations": 3})
    res = clothsim.solve(scene)
    assert res.status == "max_iterations" and res.solve.iterations == 3
    big = make_scene(**{"fabric.divisions": [60, 60], "fabric.size": [0.1, 0.1],
                        "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.1}],
                        "initial": {"perturb": 0.003}, "solver.method": method, "solver.e": 1e-300,
                        "solver.time_limit_s": 0.5, "solver.stall_iterations": 10**9})
    res = clothsim.solve(big)
    assert res.status in ("time_limit", "stalled", "converged")
    assert res.solve.wall_time_s < 0.5 + 5.0


@pytest.mark.parametrize("method", METHODS)
def test_callback_can_stop(method):
    """The progress callback returning True stops the run with status 'stopped'."""
    scene = make_scene(**PRE, **{"solver.method": method, "solver.e": 1e-300})
    calls = []

    def cb(prog):
        calls.append(prog.iteration)
        return True

    res = clothsim.solve(scene, callback=cb)
    assert res.status == "stopped" and calls


def test_non_finite_start_is_reported_as_diverged(monkeypatch):
    """A table whose extrapolation overflows to inf makes the start non-finite: status diverged,
    the state kept finite where it was. (Scene validation now refuses such a table, issue 15.17;
    its bound is lifted here to reach the solver's own safety net behind it.)"""
    import math

    import clothsim.config.scene
    import clothsim.material

    monkeypatch.setattr(clothsim.material, "VALUE_MAX", {})
    monkeypatch.setattr(clothsim.config.scene, "TENSION_MAX", math.inf)
    scene = make_scene(**{"fabric.warp": {"strain": [0, 1], "tension": [0, 1e308]},
                          "constraints.1.displacement": [0.5, 0, 0]})
    res = clothsim.solve(scene)
    assert res.status == "diverged" and "non-finite" in res.solve.message
    assert np.isfinite(res.state.positions).all()


def test_unreachable_tolerance_ends_stalled():
    """e below what float64 can reach ends 'stalled' with the smallest residual, not a loop."""
    scene = make_scene(**PRE, **{"solver.method": "paper", "solver.e": 1e-30, "solver.stall_iterations": 200})
    res = clothsim.solve(scene)
    assert res.status == "stalled"
    assert res.solve.best_residual < 1e-9
    assert "smallest residual" in res.solve.message


def test_initial_file_restarts_from_an_earlier_result(tmp_path):
    """initial.file takes the free coordinates from an earlier result.npz: restarting from a
    converged result needs no iteration; a wrong shape is refused naming the file."""
    scene = make_scene(**PRE, **{"solver.e": 1e-9})
    res = clothsim.solve(scene)
    res.save(tmp_path / "a")
    again = clothsim.solve(make_scene(**{**PRE, "solver.e": 1e-9, "initial": {"file": str(tmp_path / "a" / "result.npz")}}))
    assert again.converged and again.solve.iterations == 0
    np.testing.assert_array_equal(again.positions, res.positions)
    bad = make_scene(**{**PRE, "fabric.divisions": [3, 3], "initial": {"file": str(tmp_path / "a" / "result.npz")}})
    with pytest.raises(clothsim.SceneError, match=r"result.npz: initial.file: positions have shape \(7, 5, 3\), the scene needs \(4, 4, 3\)"):
        clothsim.solve(bad)


def test_auto_hands_a_stalled_newton_run_to_the_paper_relaxation(monkeypatch):
    """When newton stalls, auto continues with the paper's relaxation from the same state within
    the remaining budget: the run converges, says so (method newton+paper) and its history covers
    both phases with contiguous iteration numbers."""
    from clothsim.solvers import NewtonSolver, PaperSolver

    def stalled(self, state, limits, callback=None, history=None, before_batch=None):
        r = PaperSolver(self.model).solve(state, limits.model_copy(update={"max_iterations": 3}), callback, history)
        r.status, r.converged, r.method = "stalled", False, "newton"
        return r

    monkeypatch.setattr(NewtonSolver, "solve", stalled)
    res = clothsim.solve(make_scene(**PRE, **{"solver.method": "auto", "solver.e": 1e-9}))
    assert res.converged and res.solve.method == "newton+paper"
    assert "newton stalled" in res.solve.message
    it = res.solve.history["iteration"]
    np.testing.assert_array_equal(it, np.arange(1, len(it) + 1))
    assert res.solve.iterations == len(it) > 3
    assert np.all(np.diff(res.solve.history["time"]) >= 0)


@pytest.mark.parametrize("method", ["newton", "paper"])
def test_a_strip_stretched_far_beyond_its_size_is_not_a_blow_up(method):
    """A strip 0.1 m long whose end is prescribed 300 m away (strain 3000, within the documented
    coordinate range) converges to the uniform strain: the blow-up limit counts the prescribed
    positions, not only the rest ones (it reported "diverged at iteration 0": a hostile pass)."""
    scene = clothsim.load_scene(ROOT / "configs" / "uniaxial_strip.yaml",
                                ["constraints.1.displacement=[300,0,0]", f"solver.method={method}"])
    res = clothsim.solve(scene)
    assert res.converged, res.solve.message
    assert res.summary()["max_strain_warp"] == pytest.approx(3000.0, rel=1e-9)
