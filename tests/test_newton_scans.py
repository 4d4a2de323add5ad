"""Projected Newton on scanned bodies (issue 12): held-axis contact nodes projected onto a curved
surface, no penetration after any iteration, and iteration counts the campaign's traces fixed."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import ROOT

import clothsim
from clothsim import bench
from clothsim.contact import max_penetration
from clothsim.mold import mold_primitive, mold_query
from clothsim.solvers.newton import PENETRATION_TOL, NewtonSolver
from clothsim.solvers.newton.active_set import _trial_positions_sd
from clothsim.solvers.newton import active_set
from clothsim.solvers.base import StepStatus
from clothsim.solvers.options import newton_options
from clothsim.solvers.tuning import Curvature, NewtonTuning


def _sphere_trial(steps):
    R, z0 = 0.1, 0.05
    rho0 = math.sqrt(R * R - z0 * z0)
    margs = mold_primitive("sphere", {"center": [0, 0, 0], "radius": R}).kernel_args()
    pos = np.array([[rho0, 0.0, z0]])
    step = np.array([-0.01, 0.02, 0.0])   # into the sphere and along it
    fixed = np.array([[False, False, True]])
    out = np.empty((1, 3))
    cout = np.empty(1, bool)
    # the rule runs on the smooth surface of meshes; on the sphere (everywhere) the answer is
    # known in closed form
    rules = active_set.contact_rules(NewtonTuning(fixed_projection_steps=steps, fixed_projection_everywhere=True))
    pen = _trial_positions_sd(pos, np.array([True]), np.zeros(1), step, 1.0, fixed, True, margs, False,
                              -np.ones(1, np.int64), np.zeros((1, 3)), out, cout, np.zeros(1), False,
                              np.empty((0, 10)), active_set._NO_MEMO, active_set._NO_QT, rules)
    return pen, out[0], cout[0], rho0, z0, margs


def test_held_axis_contact_node_lands_on_a_curved_surface():
    """A contact node held in z, stepped partly into a sphere (R = 0.1 m) at z0 = 0.05 m: the
    projection along its free axes ends on the sphere's circle at z0 (radius sqrt(R^2 - z0^2)),
    in the direction of its trial point in the xy plane, z untouched. Moving it onto the foot
    point along x and y only (the solver before) leaves it inside, and the line search then
    rejects long steps (the smooth stocking's 420 iterations)."""
    pen, p, c, rho0, z0, margs = _sphere_trial(NewtonTuning().fixed_projection_steps)
    assert c and pen <= 1e-12
    assert p[2] == z0
    trial_xy = np.array([rho0 - 0.01, 0.02])
    expect = rho0 * trial_xy / np.linalg.norm(trial_xy)
    assert np.allclose(p[:2], expect, atol=1e-12)
    q = np.empty(8)
    assert abs(mold_query(margs, p, q)) <= 1e-12
    # without the Newton steps along the free normal the node stays inside by far more than the
    # line search's tolerance
    pen0, *_ = _sphere_trial(0)
    assert pen0 > 1e3 * PENETRATION_TOL


def _run(model, state, settings, max_iterations, tuning=NewtonTuning()):
    """Newton iterations on state (with ``tuning``); returns (iterations, status, deepest
    penetration [m] after any iteration)."""
    s = NewtonSolver(model, replace(newton_options(settings), tuning=tuning))
    margs = model.mold.kernel_args()
    worst = 0.0
    for it in range(max_iterations):
        rep = s.step(state, 1, e=settings.e)
        worst = max(worst, max_penetration(state.positions, margs))
        if rep.status != "ok":
            return it + 1, str(rep.status), worst
    return max_iterations, "max_iterations", worst


def test_smooth_stocking_converges_without_penetrating():
    """The stocking on the leg's smooth surface: ~420 iterations before (a held column creeping
    at alpha = 0.25, then nodes churning in and out of contact), then 77, then 43, now 23; no node is inside
    the leg by more than 1e-9 m after any iteration."""
    scene = clothsim.load_scene(ROOT / "configs" / "garments" / "stocking.yaml", ["mold.surface=smooth"])
    from clothsim.simulation import prepare

    model, state, _ = prepare(scene)
    its, status, worst = _run(model, state, scene.solver, 150)
    assert status == "converged", (its, status)
    assert its <= 60
    assert worst <= 1e-9


def test_torso_band_on_the_smooth_scan_converges_in_60_iterations():
    """A campaign case on smpl_man's smooth surface (y = 1.08 m: 74 iterations before) converges
    to 1e-9 N within 60 iterations, never inside the body."""
    surface = "smooth"
    case = bench.Case("t", "configs/torso_band.yaml",
                      bench.scan_band_overrides(bench.scan_body_path("smpl_man"), 1.08, surface), ("newton",))
    model, state, settings = bench._load(case, "newton", 1e-9, None)
    its, status, worst = _run(model, state, settings, 100)
    assert status == "converged", (its, status)
    assert its <= 60
    assert worst <= 1e-9


@pytest.mark.parametrize("height, energy", [(1.24, 0.3315099495), (1.06, 0.9820114560)])
def test_torso_band_ends_at_the_minimum_not_the_saddle(height, energy):
    """smpl_man's smooth surface at y = 1.24 m (75 iterations with the positive part of the
    contact's curvature term alone, ``Curvature.POSITIVE``: a linear tail, the residual
    x0.42 per full step): with all of the term while the system stays positive definite
    (``Curvature.FULL_WHILE_DEFINITE``) it converges within 60 iterations to the same minimum (0.33151 J), not to
    the saddle all of the term everywhere (2) converges to (0.468 J). At y = 1.06 m the path
    passes a saddle (3.9e-3 N at 1.458 J by its 9th iteration); without the step along the
    negative curvature (``NewtonTuning.neg_curv_move`` 0) it crept away from it for 62 iterations, with it
    48 (52 with the line search's records, ``NewtonTuning.line_search_records``; on an Intel Xeon)."""
    from clothsim.solvers.newton import iteration

    assert NewtonTuning().curvature == Curvature.FULL_WHILE_DEFINITE
    case = bench.Case("t", "configs/torso_band.yaml",
                      bench.scan_band_overrides(bench.scan_body_path("smpl_man"), height, "smooth"), ("newton",))
    model, state, settings = bench._load(case, "newton", 1e-9, None)
    its, status, worst = _run(model, state, settings, 100)
    assert status == "converged", (its, status)
    assert its <= 60
    assert worst <= 1e-9
    E = iteration.NewtonLevel(model).energy_forces(state.positions, np.zeros((model.node_count, 3)))
    assert abs(E - energy) < 1e-8, E


def test_negative_curvature_direction_is_the_smallest_eigenvector(monkeypatch):
    """``NewtonLevel._negative_curvature`` on the smooth band at y = 1.06 m, at each of its first
    three calls (the system with all of the curvature term indefinite): v lies in the free space
    (Pi v = v), and its Rayleigh quotient on the projected system with all of the term is
    negative and equals that system's smallest eigenvalue on the free dofs, from a dense
    eigensolver, to 1e-3 of that eigenvalue."""
    from clothsim.solvers.newton import iteration
    from clothsim.solvers.newton.linalg import _project_system

    checked = []
    orig = iteration.NewtonLevel._negative_curvature

    def spy(self, mu_abs):
        v = orig(self, mu_abs)
        if v is None or len(checked) >= 3:
            return v
        Kf = self.K.copy()
        Kf[self.diag] = self._Kd + self._curv_M
        Af = np.empty_like(Kf)
        _project_system(self.indptr, self.indices, Kf, self.diag, self.Pi, mu_abs, Af)
        n3 = 3 * self.n
        import scipy.sparse as sp
        A = sp.bsr_matrix((Af, self.indices, self.indptr), shape=(n3, n3)).toarray()
        # an orthonormal basis of the free space: the projectors' unit eigenvectors
        B = []
        for k in range(self.n):
            w, U = np.linalg.eigh(self.Pi[k])
            for a in range(3):
                if w[a] > 0.5:
                    e = np.zeros(n3)
                    e[3 * k:3 * k + 3] = U[:, a]
                    B.append(e)
        B = np.array(B).T
        lam = np.linalg.eigvalsh(B.T @ A @ B)
        Pv = np.einsum("kab,kb->ka", self.Pi, v.reshape(-1, 3)).ravel()
        checked.append((lam[0], v @ A @ v / (v @ v), np.abs(Pv - v).max() / np.abs(v).max(),
                        np.abs(lam).max()))
        return v

    monkeypatch.setattr(iteration.NewtonLevel, "_negative_curvature", spy)
    case = bench.Case("t", "configs/torso_band.yaml",
                      bench.scan_band_overrides(bench.scan_body_path("smpl_man"), 1.06, "smooth"), ("newton",))
    model, state, settings = bench._load(case, "newton", 1e-9, None)
    _run(model, state, settings, 30)
    assert len(checked) == 3
    for lam0, rq, off, scale in checked:
        assert lam0 < 0.0 and rq < 0.0
        assert off <= 1e-12
        assert abs(rq - lam0) <= 1e-3 * abs(lam0), (rq, lam0, scale)


def test_lu_positive_definite_known_answers():
    """The sparse LU's test of positive definiteness (``Curvature.FULL_WHILE_DEFINITE`` on systems without the
    banded Cholesky): a diagonally dominant matrix is; the same with one diagonal entry lowered
    below the others' pull, or a symmetric matrix with a zero diagonal, is not."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla
    from clothsim.solvers.newton.iteration import _lu_positive_definite

    n = 200
    A = sp.random(n, n, 0.03, random_state=1)
    A = A + A.T
    D = sp.diags(np.abs(A).sum(1).A1 + 0.1)
    # (and a positive definite one badly scaled, rows and columns by 10^+-2: threshold pivoting
    # may take an off-diagonal pivot there; NewtonLevel factorises with diagonal pivots only when
    # it tests, diag_pivot_thresh 0)
    S = sp.diags(10.0 ** np.random.default_rng(4).uniform(-2, 2, n))
    cases = ((A + D, True), (A + D - sp.diags(np.r_[np.zeros(n - 1), 1e3]), False), (A, False),
             (S @ (A + D) @ S, True))
    for M, pd in cases:
        assert (np.linalg.eigvalsh(M.toarray()).min() > 0) == pd
        lu = sla.splu(sp.csc_matrix(M), permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True),
                      diag_pivot_thresh=0.0)
        assert _lu_positive_definite(lu) == pd


@pytest.mark.parametrize("height, energy, before", [(1.24, 0.3315099495, 68), (1.06, 0.9820114560, 64)])
def test_torso_band_on_cg_levels_ends_at_the_minimum(height, energy, before):
    """The bands at 1.06 and 1.24 m solved by CG (``NewtonTuning.direct_dofs`` 0) instead of a direct
    factorisation: CG is no test of positive definiteness (with all of the curvature term it
    reached its tolerance on the indefinite system and Newton converged to the saddle, 0.468 J at
    1.24 m), so CG's levels take all of the term only when LOBPCG's estimate of the smallest
    eigenvalue says the system with it is positive definite (``NewtonTuning.curvature_cg_test``), else its
    positive part: they end at the minima (0.33151 and 0.98201 J), and in fewer iterations than
    with the positive part alone (68 and 64; 52 and 58 measured)."""
    from clothsim.solvers.newton import iteration

    assert NewtonTuning().curvature_cg_test > 0
    case = bench.Case("t", "configs/torso_band.yaml",
                      bench.scan_band_overrides(bench.scan_body_path("smpl_man"), height, "smooth"), ("newton",))
    model, state, settings = bench._load(case, "newton", 1e-9, None)
    its, status, worst = _run(model, state, settings, 200, NewtonTuning(direct_dofs=0))
    assert status == "converged", (its, status)
    assert its < before
    assert worst <= 1e-9
    E = iteration.NewtonLevel(model).energy_forces(state.positions, np.zeros((model.node_count, 3)))
    assert abs(E - energy) < 1e-8, E


def test_smallest_eigenpair_known_answers():
    """LOBPCG's estimate (``iteration._smallest_eigenpair``, the test of ``NewtonTuning.curvature_cg_test``) on
    the 1-d Laplacian tridiag(-1, 2, -1) of m = 600 unknowns plus s I, whose smallest eigenvalue is
    2 - 2 cos(pi / (m + 1)) + s (2.7e-5 + s), 5 iterations from a random start. Preconditioned by
    the inverse of the Laplacian plus 1e-4 I (a good preconditioner, like the V-cycle): theta is
    the smallest eigenvalue to 1e-11 and s = 1e-3 and 0 are told positive definite (theta above its
    residual's norm), s = -1e-3 (one negative eigenvalue among 600) is not. With a poor one (plus
    1e-2 I) the estimate has not converged (theta 7e-5 too high, its residual 1.2e-3): no case is
    told positive definite."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as sla
    from clothsim.solvers.newton.iteration import _smallest_eigenpair

    m = 600
    L = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1]).tocsc()
    lam1 = 2 - 2 * math.cos(math.pi / (m + 1))
    x0 = np.random.default_rng(3).standard_normal(m)
    for c, good in ((1e-4, True), (1e-2, False)):
        lu = sla.splu((L + c * sp.identity(m)).tocsc())
        for s in (1e-3, -1e-3, 0.0):
            A = (L + s * sp.identity(m)).tocsr()
            theta, r, x = _smallest_eigenpair(lambda v: A @ v, lu.solve, x0, 5)
            assert abs(np.linalg.norm(x) - 1) < 1e-12
            assert theta >= lam1 + s - 1e-15  # a Rayleigh quotient
            if good:
                assert abs(theta - (lam1 + s)) < 1e-11, (s, theta, lam1 + s)
                assert (theta > r) == (s >= 0), (s, theta, r)
            else:
                assert not (theta > r), (s, theta, r)


def test_node_held_off_the_surface_closes_its_gap():
    """A contact node a little off the surface (sd0 = 2e-11 m above the plane z = 0: held by
    ``_block_entering`` while still off it) closes its gap in the step (``_gap_closure``: the
    prescribed move -sd0 n), and the trial at step length alpha keeps (1 - alpha) of it instead of
    projecting it onto the plane (a move along the normal in no step: next to a seam's zero-length
    spring it raised the faceted calf band's residual from 6e-7 to 5e-5 N for every step length).
    A node on the surface (sd0 = 0) has nothing to close and is projected as before."""
    from clothsim.solvers.newton.active_set import _gap_closure, _query_nodes

    margs = mold_primitive("plane", {"point": [0, 0, 0], "normal": [0, 0, 1]}).kernel_args()
    gap = 2e-11
    pos = np.array([[0.01, 0.02, gap], [0.03, 0.0, 0.0]])
    contact = np.array([True, True])
    fixed = np.zeros((2, 3), bool)
    Q = np.empty((2, 9))
    _query_nodes(pos, True, margs, Q)
    sd0 = np.array([gap, 0.0])
    g = np.empty(6)
    assert _gap_closure(contact, fixed, sd0, Q, g, NewtonTuning().held_gap_min) == 1
    assert np.array_equal(g, [0, 0, -gap, 0, 0, 0])
    step = np.array([1e-9, -2e-9, 0.0, 1e-9, 1e-9, 0.0]) + g
    out = np.empty((2, 3))
    cout = np.empty(2, bool)
    for alpha in (1.0, 0.5):
        pen = _trial_positions_sd.py_func(pos, contact, sd0, step, alpha, fixed, True, margs, False,
                                          -np.ones(2, np.int64), np.zeros((2, 3)), out, cout, np.zeros(2), False,
                                          np.empty((0, 10)), active_set._NO_MEMO, active_set._NO_QT,
                                          active_set.RULES)
        assert pen == 0.0 and cout.all()
        assert out[0, 2] == pytest.approx((1 - alpha) * gap, rel=0, abs=1e-20)
        assert np.allclose(out[0, :2], pos[0, :2] + alpha * step[:2], rtol=0, atol=1e-15)
        assert abs(out[1, 2]) <= 1e-15
    # a node with a held axis is left to the held-axis projection (no gap to close)
    fixed[0, 2] = True
    assert _gap_closure(contact, fixed, sd0, Q, g, NewtonTuning().held_gap_min) == 0 and not g.any()


def test_faceted_calf_band_step_from_its_stall_makes_progress():
    """The faceted calf band at 80 x 20 (the file's lattice) stalled at 6.3e-7 N (e = 1e-7 N),
    "no further progress possible": tests/data/calf_band_faceted_80_stall.npz holds that state.
    Its step releases node 1695 (a seam node 2.3e-11 m off the surface) and holds it again
    (``_block_entering``); projecting it onto the surface in every trial cost 5e-5 N of residual
    at its stiff zero-length seam spring, so no step length was accepted. With its gap closed by
    the step (the seam's partner answering it in the Newton system), two iterations from that
    state reach 1.1e-10 N (the first step cut to 1/128, the second a full one that closes the gap;
    on main the first iteration found no progress possible)."""
    from clothsim.simulation import prepare
    from clothsim.solvers.newton import NewtonLevel
    from clothsim.solvers.newton.iteration import _forcing

    scene = clothsim.load_scene(ROOT / "configs" / "garments" / "calf_band.yaml", ["mold.surface=faceted"])
    model, state, _ = prepare(scene)
    d = np.load(ROOT / "tests" / "data" / "calf_band_faceted_80_stall.npz")
    state.positions[:] = d["positions"]
    state.in_contact[:] = d["in_contact"]
    lev = NewtonLevel(model)
    lev.lm = 1e-12
    v0 = lev.residual(state.positions, state.in_contact)
    assert 6e-7 < v0 < 7e-7
    v = v0
    for _ in range(2):
        v, _, flag = lev.iterate(state, v, forcing=_forcing(v, 1e-9))
        assert flag == StepStatus.OK
    assert v < 1e-9
    assert max_penetration(state.positions, model.mold.kernel_args()) <= PENETRATION_TOL


def test_faceted_calf_band_converges_with_newton_alone():
    """Issue 12 item 2: the calf band on the faceted scan (80 x 20, the file's lattice) converges
    to 1e-9 N with ``newton`` alone (19 iterations, 2.4e-10 N; main stalled at 6.3e-7 N: a seam
    node held 2.3e-11 m off a face and projected onto it in every line-search trial)."""
    res = clothsim.solve(clothsim.load_scene(ROOT / "configs" / "garments" / "calf_band.yaml",
                                             ["mold.surface=faceted", "solver.method=newton", "solver.e=1e-9"]))
    s = res.summary()
    assert s["status"] == "converged", s["status"]
    assert s["iterations"] <= 30 and s["residual"] <= 1e-9
    assert max_penetration(res.state.positions, res.model.mold.kernel_args()) <= PENETRATION_TOL


def test_line_search_records_give_the_fresh_answers(monkeypatch):
    """On the smooth surface the line search traces each free node's segment once
    (``_trial_positions_sd``'s memo) and the accepted step's mold answers come from its trial pass
    (Qt, ``_complete_queries``). In the first 12 iterations of smpl_man's band at y = 1.06 m,
    every trial pass equals the same pass without the records (positions within 1e-9 m, the same
    contact set and depth), and every completed set of answers equals ``_query_nodes``' at the
    accepted positions (foot points and distances within 1e-12 m, normals within 1e-9)."""
    from clothsim.solvers.newton import active_set, iteration

    passes = []
    accepts = []
    orig_tp = iteration._trial_positions_sd

    def tp(*args):
        a = list(args)
        out, cout = a[11], a[12]
        memo, alpha = args[16], float(args[4])
        # free nodes traced on a longer step of this line search: this pass reads their traces
        read = int(((memo[:, 0] > 0.0) & (memo[:, 0] > alpha)).sum()) if memo.shape[0] else 0
        pen = orig_tp(*args)
        if a[16].shape[0] == 0:
            return pen
        ref, rc, rsd = np.empty_like(out), np.empty_like(cout), np.empty(out.shape[0])
        a[11], a[12], a[13], a[16], a[17] = ref, rc, rsd, active_set._NO_MEMO, active_set._NO_QT
        pen_ref = orig_tp(*a)
        passes.append((np.abs(out - ref).max(), int((cout != rc).sum()), abs(pen - pen_ref), read))
        return pen

    orig_cq = iteration._complete_queries

    def cq(pos, Qt, q_pos, has_mold, margs, Q):
        n = orig_cq(pos, Qt, q_pos, has_mold, margs, Q)
        F = np.empty_like(Q)
        active_set._query_nodes(pos, has_mold, margs, F)
        accepts.append((np.abs(Q[:, :3] - F[:, :3]).max(), np.abs(Q[:, 3:6] - F[:, 3:6]).max(),
                        np.abs(Q[:, 8] - F[:, 8]).max(), bool(np.array_equal(Q[:, 9], F[:, 9])),
                        int(Qt[:, 10].sum()), n))
        return n

    monkeypatch.setattr(iteration, "_trial_positions_sd", tp)
    monkeypatch.setattr(iteration, "_complete_queries", cq)
    case = bench.Case("t", "configs/torso_band.yaml",
                      bench.scan_band_overrides(bench.scan_body_path("smpl_man"), 1.06, "smooth"), ("newton",))
    model, state, settings = bench._load(case, "newton", 1e-9, None)
    _run(model, state, settings, 12)
    assert len(passes) >= 12 and len(accepts) >= 6
    for dpos, dcontact, dpen, read in passes:
        # (a re-entry after a start on the surface may differ by more: 1.75e-8 m on the stocking)
        assert dpos <= 1e-9 and dcontact == 0 and dpen <= 1e-12, (dpos, dcontact, dpen)
    # the records were used: shorter steps read traces, accepted steps took the trial's answers
    assert sum(p[3] for p in passes) > 0
    for dfoot, dnormal, dsd, flags, known, queried in accepts:
        assert dfoot <= 1e-12 and dsd <= 1e-12 and dnormal <= 1e-9 and flags, (dfoot, dsd, dnormal, flags)
        assert known > queried
