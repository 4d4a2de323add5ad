"""Tests of the newton solver (clothsim.solvers.newton).

References: the analytic uniaxial strip (reaction = tension table x width, no Poisson effect),
the uniform grid of a perimeter-stretched sheet, the paper solver's equilibrium on the sphere
cap, finite differences of the forces (Hessian blocks) and of the energy (forces), and the
mold's own signed distance (no penetration after every iteration).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clothsim.config import load_scene
from clothsim.contact import max_penetration
from clothsim.kernels import forces_and_energy, spring_hessian_block
from clothsim.simulation import prepare
from clothsim.solvers import pick_method, solve
from clothsim.solvers import newton as nw
from clothsim.solvers.tuning import NewtonTuning

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"


def _setup(name, *overrides, **solver):
    scene = load_scene(CONFIGS / name, list(overrides))
    model, state, _ = prepare(scene)
    settings = scene.solver.model_copy(update={"method": "newton", **solver})
    return scene, model, state, settings


def test_auto_picks_newton():
    """``auto`` runs newton (the fastest method on every measured scene)."""
    scene, model, state, settings = _setup("sphere_cap.yaml")
    assert pick_method(model, settings.model_copy(update={"method": "auto"})) == "newton"


def test_uniaxial_strip_reproduces_table():
    """Strip pulled 30 %: every warp spring at 30 % strain, the reaction at the pulled edge equals
    sigma(0.3) x thickness x width (2e5 Pa x 0.5 mm x 20 mm = 2 N) within 1e-6 relative."""
    scene, model, state, settings = _setup("uniaxial_strip.yaml", e=1e-10)
    res = solve(model, state, settings)
    assert res.converged, res.message
    F = np.empty_like(state.positions)
    forces_and_energy(state.positions, *model.spring_args(), model.external_force, F)
    nx1, ny1 = model.grid_shape
    right = np.arange(ny1) + (nx1 - 1) * ny1
    reaction = -F[right, 0].sum()
    expected = 2.0e5 * 0.0005 * 0.02
    assert abs(reaction - expected) <= 1e-6 * expected
    fam = model.spring_family
    p = state.positions
    l = np.linalg.norm(p[model.spring_nodes[:, 1]] - p[model.spring_nodes[:, 0]], axis=1)
    strain = l / model.spring_rest_length - 1
    assert np.allclose(strain[fam == 0], 0.3, atol=1e-9)


def test_pretensioned_sheet_relaxes_to_uniform_grid():
    """Perimeter stretched 10 %, perturbed start: the exact equilibrium is the uniform grid."""
    scene, model, state, settings = _setup("pretensioned_sheet.yaml", e=1e-10)
    res = solve(model, state, settings)
    assert res.converged, res.message
    nx1, ny1 = model.grid_shape
    c = model.rest_positions.reshape(nx1, ny1, 3)[..., :2].mean(axis=(0, 1))
    exact = c + (model.rest_positions[:, :2] - c) * 1.1
    assert np.abs(state.positions[:, :2] - exact).max() < 1e-9
    assert np.abs(state.positions[:, 2]).max() < 1e-9


@pytest.mark.slow
def test_sphere_cap_same_equilibrium_as_paper():
    """Sphere cap at 21 x 21 nodes: newton and paper (both to 1e-8 N) give the same positions
    (within 1e-6 m, what a 1e-8 N residual with ~100 N/m stiffness implies, with margin) and
    the same energy."""
    scene, model, state, settings = _setup("sphere_cap.yaml", "fabric.divisions=[20,20]", e=1e-8)
    sn = state.copy()
    rn = solve(model, sn, settings)
    sp = state.copy()
    rp = solve(model, sp, settings.model_copy(update={"method": "paper", "time_limit_s": 60}))
    assert rn.converged and rp.converged, (rn.message, rp.message)
    assert np.abs(sn.positions - sp.positions).max() < 1e-6
    assert abs(rn.energy - rp.energy) <= 1e-9 * abs(rn.energy) + 1e-15


@pytest.mark.parametrize("strain", [-0.05, 0.0, 0.05, 0.1, 0.3, 0.65])
def test_hessian_blocks_match_force_differences(strain):
    """Assembled Hessian (away from the strain-0 kink: kink 0) equals -d(force)/d(position) by
    central finite differences, in tension, at strain 0, across table breakpoints and slack;
    and the scalar assembly equals kernels.spring_hessian_block."""
    scene, model, state, settings = _setup("uniaxial_strip.yaml")
    rng = np.random.default_rng(3)
    pos = model.rest_positions.copy()
    pos[:, 0] = model.rest_positions[:, 0] * (1 + strain)
    pos += rng.normal(0, 2e-4, pos.shape)
    lvl = nw.NewtonLevel(model, kink=0.0)
    nw._assemble(pos, *model.spring_args(), lvl.kink, lvl.slot, lvl.K)
    n = model.node_count
    import scipy.sparse as sp

    K = sp.bsr_matrix((lvl.K, lvl.indices, lvl.indptr), shape=(3 * n, 3 * n)).toarray()
    h = 1e-8
    F1 = np.empty_like(pos)
    F2 = np.empty_like(pos)
    for k in (0, 7, 33, 50):
        for a in range(3):
            p1 = pos.copy(); p1[k, a] += h
            p2 = pos.copy(); p2[k, a] -= h
            forces_and_energy(p1, *model.spring_args(), model.external_force, F1)
            forces_and_energy(p2, *model.spring_args(), model.external_force, F2)
            col = -(F1 - F2).reshape(-1) / (2 * h)
            scale = np.abs(K).max()
            # the transverse term is clamped at >= 0 on compressed springs: compare only where
            # no spring at this node is compressed
            assert np.abs(K[:, 3 * k + a] - col).max() <= 1e-5 * scale or strain < 0
    # scalar assembly vs the shared kernel (one spring: its diagonal and coupling blocks)
    blk = np.empty((3, 3))
    t = model.tables
    one = nw.NewtonLevel(model, kink=0.0)
    sub = model.spring_nodes[:1]
    ip, ind, slot, diag = nw._bsr_pattern(n, sub)
    data = np.zeros((ind.shape[0], 3, 3))
    nw._assemble(pos, sub, model.spring_rest_length[:1], model.spring_width[:1], model.spring_table[:1],
                 t.x, t.y, t.cum, t.start, t.compression, one.kink[:1], slot, data)
    a, b = sub[0]
    spring_hessian_block(pos[a], pos[b], model.spring_rest_length[0], model.spring_width[0], t.x, t.y, t.cum,
                         t.start, t.compression, model.spring_table[0], 0.0, blk)
    assert np.allclose(data[slot[0, 0]], blk, rtol=1e-12, atol=1e-12)
    assert np.allclose(data[slot[0, 2]], -blk, rtol=1e-12, atol=1e-12)


def test_fast_forces_and_residual_match_per_spring_and_per_node_kernels():
    """The scalar-indexed whole-sheet kernels every solver uses (forces_and_energy, and the
    residual from those forces) agree with the per-spring function (spring_eval, summed here in
    Python) and with the per-node resultants of the paper's relaxation (node_force) to
    rounding, with gravity, shear and bending on."""
    from clothsim.kernels import node_force, spring_eval
    from clothsim.solvers.common import residual

    scene, model, state, settings = _setup("sphere_cap.yaml", "fabric.divisions=[20,20]", "gravity={areal_density: 0.2}",
                                           "shear={stiffness: 20}", "bending={stiffness: 1}")
    solve(model, state, settings.model_copy(update={"max_iterations": 3}))
    pos = state.positions
    F1 = np.empty_like(pos)
    e1 = forces_and_energy(pos, *model.spring_args(), model.external_force, F1)
    t = model.tables
    F2 = model.external_force.copy()
    e2 = -float((model.external_force * pos).sum())
    for s, (a, b) in enumerate(model.spring_nodes):
        fx, fy, fz, e, *_ = spring_eval(pos[a], pos[b], model.spring_rest_length[s], model.spring_width[s],
                                        t.x, t.y, t.cum, t.start, t.compression, model.spring_table[s])
        F2[a] += (fx, fy, fz)
        F2[b] -= (fx, fy, fz)
        e2 += e
    assert abs(e1 - e2) <= 1e-12 * abs(e1)
    assert np.allclose(F1, F2, rtol=0, atol=1e-13)
    R = np.empty(3)
    for k in range(0, model.node_count, 7):
        node_force(k, pos, *model.adjacency_args(), model.external_force, R)
        assert np.allclose(R, F1[k], rtol=0, atol=1e-13)
    lvl = nw.NewtonLevel(model)
    v_shared, _ = residual(model, state)
    assert abs(lvl.residual(state.positions, state.in_contact) - v_shared) <= 1e-13


def test_no_penetration_every_iteration():
    """Thermoforming mold (non-convex mesh): after every newton iteration the deepest penetration
    is at most 1e-9 m (checked through the callback with contact.max_penetration)."""
    name = "thermoform.yaml" if (CONFIGS / "thermoform.yaml").exists() else "sphere_cap.yaml"
    scene, model, state, settings = _setup(name, e=1e-9)
    margs = model.mold.kernel_args()
    worst = []

    def cb(prog):
        worst.append(max_penetration(prog.state.positions, margs))
        return False

    res = solve(model, state, settings, callback=cb)
    assert res.converged, res.message
    assert len(worst) >= res.iterations
    assert max(worst) <= 1e-9


def test_grid_sequencing_and_multigrid_path():
    """A 101 x 101 sphere cap goes through grid sequencing and the multigrid-preconditioned CG
    and converges to 1e-9 N; without sequencing it reaches the same equilibrium."""
    scene, model, state, settings = _setup("sphere_cap.yaml", "fabric.divisions=[100,100]", e=1e-9)
    assert 3 * model.node_count > NewtonTuning().direct_dofs
    s1 = state.copy()
    r1 = solve(model, s1, settings)
    s2 = state.copy()
    r2 = solve(model, s2, settings.model_copy(update={"newton_sequencing": False}))
    assert r1.converged and r2.converged, (r1.message, r2.message)
    assert np.abs(s1.positions - s2.positions).max() < 1e-7


def test_multigrid_vcycle_is_symmetric_and_contracting():
    """The V-cycle used as CG preconditioner is a symmetric operator (x.M y = y.M x) and reduces
    the error of A x = b by a factor < 0.5 per cycle on a stretched sheet."""
    scene, model, state, settings = _setup("sphere_cap.yaml", "fabric.divisions=[60,60]")
    lvl = nw.NewtonLevel(model, use_multigrid=True)
    pos = state.positions
    forces_and_energy(pos, *model.spring_args(), model.external_force, lvl.F)
    nw._projectors(pos, lvl.F, model.fixed_axes, state.in_contact, lvl.has_mold, lvl.margs, lvl.Pi)
    nw._assemble(pos, *model.spring_args(), lvl.kink, lvl.slot, lvl.K)
    nw._project_system(lvl.indptr, lvl.indices, lvl.K, lvl.diag, lvl.Pi, 0.0, lvl.A)
    lvl.mg.setup(lvl.indptr, lvl.indices, lvl.A, lvl.Pi)
    rng = np.random.default_rng(0)
    x = rng.normal(size=3 * lvl.n)
    y = rng.normal(size=3 * lvl.n)
    assert abs(x @ lvl.mg.vcycle(y) - y @ lvl.mg.vcycle(x)) <= 1e-8 * abs(x @ lvl.mg.vcycle(x))
    b = rng.normal(size=3 * lvl.n)
    xs = np.zeros_like(b)
    out = np.empty_like(b)
    norms = []
    for _ in range(4):
        nw._bsr_matvec(lvl.indptr, lvl.indices, lvl.A, xs, out)
        r = b - out
        norms.append(np.linalg.norm(r))
        xs += lvl.mg.vcycle(r)
    assert norms[-1] < 0.5 ** 3 * norms[0]


def test_band_cholesky_solve_matches_sparse_lu():
    """The banded Cholesky (reverse Cuthill-McKee order) used for direct solves on mesh molds
    solves the projected Newton system of a stretched band to rounding, like the sparse LU; a
    matrix that is not positive definite is refused (the caller falls back to the LU)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla

    from clothsim.solvers.newton import linalg as la

    scene, model, state, settings = _setup("sphere_cap.yaml", "fabric.divisions=[24,6]")
    lvl = nw.NewtonLevel(model, use_multigrid=False)
    nw._assemble(state.positions, *model.spring_args(), lvl.kink, lvl.slot, lvl.K)
    lvl.Pi[:] = np.eye(3)
    lvl.Pi[::4] = np.diag([1.0, 0.0, 1.0])
    mu = 1e-3 * np.einsum("kii->k", lvl.K[lvl.diag]).mean()  # a flat sheet: shifted, well conditioned
    nw._project_system(lvl.indptr, lvl.indices, lvl.K, lvl.diag, lvl.Pi, mu, lvl.A)
    perm, inv, bw = la.band_order(lvl.n, model.spring_nodes)
    assert bw <= 8  # the short side, not the long one
    n3 = 3 * lvl.n
    b = np.random.default_rng(3).normal(size=n3)
    x = np.empty(n3)
    L = np.empty((n3, 3 * bw + 3))
    assert la._band_cholesky_solve(lvl.indptr, lvl.indices, lvl.A, inv, bw, b, L, x)
    M = sp.bsr_matrix((lvl.A, lvl.indices, lvl.indptr), shape=(n3, n3)).tocsc()
    ref = sla.spsolve(M, b)
    assert np.abs(x - ref).max() <= 1e-9 * np.abs(ref).max()
    # the factor it leaves solves again, bit for bit (the negative-curvature search's
    # preconditioner), for another right-hand side too
    x2 = np.empty(n3)
    la._band_factored_solve(L, inv, b, x2)
    assert np.array_equal(x2, x)
    b2 = np.random.default_rng(4).normal(size=n3)
    la._band_factored_solve(L, inv, b2, x2)
    assert np.abs(x2 - sla.spsolve(M, b2)).max() <= 1e-9 * np.abs(x2).max()
    bad = -lvl.A
    assert not la._band_cholesky_solve(lvl.indptr, lvl.indices, bad, inv, bw, b, np.empty((n3, 3 * bw + 3)), x)


def test_trapezoid_energy_change_below_the_energys_resolution():
    """``iteration._trapezoid_change`` (-1/2 (F0 + F1) . (x1 - x0)) is the energy change of a
    step too small for E1 - E0 to resolve (below NewtonTuning.energy_resolution of E): on the stretched
    uniaxial strip it equals the second-order expansion -F0 . d + 1/2 d K d to 1e-6 relative."""
    from clothsim.solvers.newton.iteration import _trapezoid_change
    import scipy.sparse as sp

    scene, model, state, settings = _setup("uniaxial_strip.yaml")
    pos = model.rest_positions.copy()
    pos[:, 0] *= 1.2
    d = np.random.default_rng(5).normal(0, 1e-15, pos.shape)
    F0 = np.empty_like(pos)
    F1 = np.empty_like(pos)
    E0 = forces_and_energy(pos, *model.spring_args(), model.external_force, F0)
    forces_and_energy(pos + d, *model.spring_args(), model.external_force, F1)
    lvl = nw.NewtonLevel(model, kink=0.0)
    nw._assemble(pos, *model.spring_args(), lvl.kink, lvl.slot, lvl.K)
    n = model.node_count
    K = sp.bsr_matrix((lvl.K, lvl.indices, lvl.indptr), shape=(3 * n, 3 * n))
    dv = d.reshape(-1)
    expect = -F0.reshape(-1) @ dv + 0.5 * dv @ (K @ dv)
    assert abs(expect) < NewtonTuning().energy_resolution * abs(E0)
    assert _trapezoid_change(pos, pos + d, F0, F1) == pytest.approx(expect, rel=1e-6)


def test_multigrid_keeps_its_matrix_while_the_next_system_is_written_elsewhere():
    """The multigrid hierarchy keeps the projected matrix it was set up on (no copy): the next
    system (here with a doubled Hessian, the hierarchy reused) is written to the Newton level's
    second buffer, so the hierarchy's fine values stay those it was built on."""
    from clothsim import bench
    from clothsim.solvers.newton.iteration import NewtonLevel

    case = bench.Case("t", "configs/sphere_cap.yaml", ["fabric.divisions=[20,20]"], ("newton",))
    model, state, _ = bench._load(case, "newton", 1e-9, None)
    lev = NewtonLevel(model, use_multigrid=True)
    lev.iterate(state, np.inf)
    fine = lev.mg.levels[0].data
    assert fine is lev._mg_A
    kept = fine.copy()
    lev.K *= 2.0
    rhs = np.random.default_rng(0).normal(size=3 * lev.n)
    _solve = lev._solve_linear(rhs, lev._mg_mu, 1e-8, None, True)
    assert lev.mg.levels[0].data is fine and np.array_equal(fine, kept)
    assert lev.A is not fine and not np.array_equal(lev.A, fine)
    assert np.all(np.isfinite(_solve[0]))
