"""One grid's Newton iteration (``NewtonLevel``): forces and energy, the projected Levenberg-shifted
linear system, its solve (direct LU or multigrid-preconditioned CG), the line search on the
energy with the contact rules applied to every trial, and the step's acceptance.

Shapes: n nodes; positions/forces (n, 3) [m]/[N]; residuals ||V||_inf [N]; energies [J].
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from numba import njit

from ...contact import friction_assemble
from ...contact import residual_from_forces as _residual_from_forces
from ...kernels import first_slope, forces_and_energy, seam_assemble, seam_slots
from ...model import SpringFamily
from ...mold import MOLD_MESH, MOLD_SMOOTH
from ..common import blowup_limit, model_mold_args
from ..base import StepStatus
from ..options import NewtonOptions
from ..tuning import Curvature, NewtonTuning
from .active_set import (PENETRATION_TOL, _add_curvature, _apply_pi, _block_entering,
                         _block_infeasible_q, _curvature_blocks, _curvature_terms, _gap_closure, _contact_faces_q, _free_distances_q, _projectors_q, _query_nodes, _residual_q,
                         _trial_positions_sd, _complete_queries, _NO_MEMO, _NO_QT, contact_rules)
from .linalg import (AlgebraicMultigrid, Multigrid, PaddedMultigrid, _assemble, _band_cholesky_solve, _band_factored_solve,
                     _bsr_matvec, _bsr_pattern, _dot, _pcg, _project_system, band_order)

# The switches and constants this module reads are the fields of ``tuning.NewtonTuning``
# (``NewtonLevel.tuning``); their measurements are documented there.


class NewtonLevel:
    """Newton iterations for one Model (the fine grid, or a coarse grid of the sequencing)."""

    def __init__(self, model, *, kink: float = NewtonOptions.kink, use_multigrid: bool | None = None,
                 preconditioner: str = "geometric", tuning: NewtonTuning = NewtonTuning()):
        """kink: NewtonOptions.kink; tuning: NewtonOptions.tuning; use_multigrid: None = by size
        (``tuning.direct_dofs``);
        preconditioner on lattices other than one full rectangle: "geometric" (the line-smoothed
        multigrid on the panels' padded rectangle, PaddedMultigrid) or "amg" (PyAMG's smoothed
        aggregation, AlgebraicMultigrid; slower here, kept for comparison in the benchmark)."""
        self.model = model
        self.tuning = tu = tuning
        self.rules = contact_rules(tu)  # the contact rules' values for the kernels
        self.has_mold, self.margs = model_mold_args(model)
        self.sargs = model.spring_args()
        n = model.node_count
        self.n = n
        self.indptr, self.indices, self.slot, self.diag = _bsr_pattern(n, _coupled_pairs(model))
        if model.seam_count:
            # the seam elements' node pairs follow the springs'
            self.slot = np.ascontiguousarray(self.slot[:model.spring_count])
            self.seam_slot = seam_slots(self.indptr, self.indices, model.seam_nodes)
        nb = self.indices.shape[0]
        self.K = np.zeros((nb, 3, 3))
        self.A = np.zeros((nb, 3, 3))
        # the array the multigrid hierarchy was built on and reads in its V-cycles (or None), and
        # a second buffer: while the hierarchy holds A, the next projected system is written to
        # the other one (_solve_linear) instead of giving the hierarchy a copy of A
        self._mg_A = None
        self._A_spare = None
        t = model.tables
        self.kink = np.array([kink * first_slope(t.x, t.y, t.start, int(tb)) for tb in
                              range(len(t.start) - 1)])[model.spring_table] if kink > 0 else np.zeros(
            model.spring_count)
        self.kink = np.ascontiguousarray(self.kink, float)
        self._kink_full = self.kink.copy()
        self._kink_scale = 1.0
        self.Pi = np.zeros((n, 3, 3))
        self.F = np.zeros((n, 3))
        self._Fr = np.zeros((n, 3))
        self.V = np.zeros(n)
        self.trial = np.zeros((n, 3))
        self.trial_contact = np.zeros(n, bool)
        self.direct = (use_multigrid is False) or (use_multigrid is None and 3 * n <= tu.direct_dofs)
        # line-smoothed geometric multigrid on one full rectangle, algebraic multigrid elsewhere
        self._band = None
        if self.direct:
            self.mg = None
            # on a triangle-mesh mold (scans, CAD; faceted or smooth), narrow bands (a band or strip of fabric) are
            # factorised by a banded Cholesky in a reverse Cuthill-McKee node order: a third of
            # the sparse LU's time on the torso band. Elsewhere the sparse LU stays: its rounding
            # is what the recorded equilibria of the analytic molds were computed with
            kind = self.margs[0][0] if self.has_mold else -1
            if kind == MOLD_MESH or (kind == MOLD_SMOOTH and tu.band_on_smooth):
                _, inv, bw = band_order(n, model.spring_nodes)
                w = 3 * bw + 3
                if 3 * n * w * w <= tu.band_work:
                    self._band = (inv, bw, np.empty((3 * n, w)))
        elif model.topology.is_grid:
            self.mg = Multigrid.for_topology(model.topology, _seam_pairs(model), tu)
        elif preconditioner == "amg":
            self.mg = AlgebraicMultigrid()
        else:
            self.mg = PaddedMultigrid(model.topology, _seam_pairs(model), tu)
        self.lm = 1e-10  # Levenberg shift relative to the mean diagonal stiffness
        # exactly singular factorisations in the current iteration, and why the last iteration
        # that found no step failed when they caused it ("" otherwise)
        self.singular = 0
        self.failure = ""
        kind = self.margs[0][0] if self.has_mold else -1
        rules = kind == MOLD_SMOOTH or (kind == MOLD_MESH and tu.scan_rules_on_facets)
        self._kink_decay = tu.kink_decay if rules else 1.0
        self._hold_share = tu.hold_share if (rules or tu.hold_share_everywhere) else 1.0
        self.blowup = blowup_limit(model)
        # step probed for leaving an edge's or vertex's tangent cone [m] (_block_infeasible)
        self.probe = 1e-6 * float(min(model.spacing))
        # difference step of the smooth surface's shape operator [m] (_curvature_blocks)
        self.fd_step = 1e-4 * float(min(model.spacing))
        self.spacing = float(min(model.spacing))
        self._refactor = None  # the last direct solve's factor: rhs (3n,) -> A^-1 rhs
        self._cache = None
        self._curv_full = False  # the Hessian holds all of the curvature term (Curvature.FULL_WHILE_DEFINITE)
        self._curv_test = False  # CG's level: test the system with all of the term at the next solve
        self._eig_x = None  # the last test's eigenvector estimate (3n,), the next test's start
        self._eig_rng = np.random.default_rng(0)  # the first test's start
        self._curv_M = np.zeros((n, 3, 3))  # -lam S per node [N/m] (_curvature_terms)
        # the mold's answers at the nodes (_query_nodes) and the positions they are for: the
        # accepted step's residual queries them, and the next iteration's active set, distances,
        # blocking rules and face clips read them instead of querying the same points again
        self.Q = np.zeros((n, 10))
        self._q_pos = None
        self.sd0 = np.full(n, np.inf)
        self.gap = np.zeros(3 * n)  # the step's prescribed gap closure [m] (_gap_closure)
        self._sd_trial = np.zeros(n)  # the trial positions' signed distances [m] (_trial_positions_sd)
        # on the smooth surface: the line search's segment traces, and the mold's answers at the
        # trial positions (_trial_positions_sd's memo and Qt; _accept completes Q from them)
        smooth = self.has_mold and self.margs[0][0] == MOLD_SMOOTH and tu.line_search_records
        self._memo = np.zeros((n, 6)) if smooth else _NO_MEMO
        self._Qt = np.zeros((n, 11)) if smooth else _NO_QT
        self._qt_for = None  # the trial positions Qt is for (None: none)
        self._face0 = -np.ones(n, np.int64)
        self.ls_alpha = 0.0
        self._mg_pi = None
        self._mg_mu = None
        self._mg_age = 0
        self._last_cg = 0
        self.v_prev = None  # the residual [N] the last iteration started from (forcing terms)

    def reset(self):
        """Forget what earlier iterations left (Levenberg shift, kink scale, cached forces, mold
        answers and multigrid hierarchy): the level then iterates as a newly built one would."""
        self.lm = 1e-10
        self._set_kink(1.0)
        self._cache = None
        self._q_pos = None
        self.sd0[:] = np.inf
        self._face0[:] = -1
        self.ls_alpha = 0.0
        self._mg_pi = None
        self._mg_mu = None
        self._mg_age = 0
        self._last_cg = 0
        self.v_prev = None
        self._eig_x = None
        self._eig_rng = np.random.default_rng(0)

    # -- helpers ---------------------------------------------------------------------------
    def energy_forces(self, pos, F):
        e = forces_and_energy(pos, *self.sargs, self.model.external_force, F)
        if self.model.seam_count:
            e += self.model.add_seam_forces(pos, F)
        if self.model.friction is not None:
            e += self.model.add_friction_forces(pos, F)
        return e

    def residual(self, pos, contact, F=None):
        """||V||_inf (eq. 6) at pos; F: the forces at pos when already known."""
        if F is None:
            F = self._Fr
            self.energy_forces(pos, F)
        if not self.has_mold:
            return _residual_from_forces(pos, F, self.model.fixed_axes, contact, self.has_mold, self.margs,
                                         self.V)
        return _residual_q(F, self.model.fixed_axes, contact, self.has_mold, self.margs, self.queries(pos), self.V)

    def queries(self, pos):
        """The mold's answers at the nodes at pos (n,3) [m] (``_query_nodes``: Q (n, 10)), queried
        once per set of positions."""
        if self._q_pos is None or not _same(self._q_pos, pos):
            _query_nodes(pos, self.has_mold, self.margs, self.Q)
            if self._q_pos is None:
                self._q_pos = pos.copy()
            else:
                self._q_pos[:] = pos
        return self.Q

    def _set_kink(self, scale):
        """The slack springs' kink stiffness at ``scale`` times NewtonOptions.kink's."""
        if scale != self._kink_scale:
            self._kink_scale = scale
            np.multiply(self._kink_full, scale, out=self.kink)

    def _solve_linear(self, rhs, mu_abs, tol, x0=None, reuse=False):
        """The projected system's solution for ``rhs`` (3n,) [N] with the shift mu_abs [N/m], to
        the relative residual tol (multigrid-preconditioned CG; direct below ``tuning.direct_dofs``):
        (x (3n,) [m], CG iterations). x0: CG's start (None: 0); reuse: keep the multigrid
        hierarchy even if the projectors changed since it was built (it is rebuilt when CG then
        does not reach tol)."""
        if self.A is self._mg_A:
            if self._A_spare is None:
                self._A_spare = np.empty_like(self.A)
            self.A, self._A_spare = self._A_spare, self.A
        _project_system(self.indptr, self.indices, self.K, self.diag, self.Pi, mu_abs, self.A)
        n3 = 3 * self.n
        if self.direct:
            if self._band is not None:
                inv, bw, work = self._band
                x = np.empty(n3)
                if _band_cholesky_solve(self.indptr, self.indices, self.A, inv, bw, rhs, work, x):
                    self._refactor = self._band_again
                    return x, 1
                if self._curv_full:
                    # not positive definite with all of the curvature term: its positive part
                    self._curvature_fallback()
                    return self._solve_linear(rhs, mu_abs, tol, x0, reuse)
            M = sp.bsr_matrix((self.A, self.indices, self.indptr), shape=(n3, n3)).tocsc()
            # (with all of the curvature term, pivots on the diagonal only: stable if the matrix
            # is positive definite, and then the pivots' signs are the test; with threshold
            # pivoting a positive definite but badly scaled matrix may take an off-diagonal one)
            try:
                lu = sla.splu(M, permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True),
                              diag_pivot_thresh=0.0 if self._curv_full else 1e-3)
            except RuntimeError:
                # "Factor is exactly singular": a pivot column vanished (a direction without
                # stiffness whose Levenberg shift is below the other pivots' rounding). With all
                # of the curvature term the system is not positive definite: its positive part.
                # Otherwise no step: a non-finite one, which iterate answers with a larger shift,
                # and after its attempts with NO_PROGRESS (the run stalls, keeping its state)
                self.singular += 1
                if self._curv_full:
                    self._curvature_fallback()
                    return self._solve_linear(rhs, mu_abs, tol, x0, reuse)
                return np.full(n3, np.nan), 1
            if self._curv_full and not _lu_positive_definite(lu):
                self._curvature_fallback()
                return self._solve_linear(rhs, mu_abs, tol, x0, reuse)
            x = lu.solve(rhs)
            self._refactor = lu.solve
            return x, 1
        if x0 is not None:
            # a start that already meets tol needs no hierarchy (and no rebuild)
            r0 = np.empty(n3)
            _bsr_matvec(self.indptr, self.indices, self.A, x0, r0)
            np.subtract(rhs, r0, out=r0)
            if math.sqrt(_dot(r0, r0)) <= tol * math.sqrt(_dot(rhs, rhs)):
                return x0.copy(), 0
        if not (reuse and self._mg_pi is not None and self._mg_mu == mu_abs) and self._mg_stale(mu_abs):
            # (a preconditioner that keeps the matrix keeps A itself: the next systems are
            # written to the other buffer while it holds it; the padded multigrid copies it into
            # its rectangle, PyAMG into its CSR). Recorded only once the set-up has succeeded: a
            # set-up that raises leaves the last hierarchy, and its buffer, as they were
            self._mg_pi = None
            Pi = self.Pi.copy()
            self.mg.setup(self.indptr, self.indices, self.A, Pi)
            self._mg_pi = Pi
            self._mg_A = None if getattr(self.mg, "copies_matrix", False) else self.A
            self._mg_age = 0
        self._mg_age += 1
        if self._curv_test:
            self._curv_test = False
            self._curvature_cg_test()
        indptr, indices, A = self.indptr, self.indices, self.A

        def mv(v, out):
            _bsr_matvec(indptr, indices, A, v, out)

        x, it, rel = _pcg(mv, self.mg.vcycle, rhs, tol, 200, x0)
        self._last_cg = it
        if rel > tol and self._mg_age > 1:
            # the reused preconditioner no longer fits: rebuild and solve again
            self._mg_pi = None
            return self._solve_linear(rhs, mu_abs, tol)
        return x, it

    def _curvature_cg_test(self):
        """On a CG level whose projected system A (the positive part of the curvature term; its
        multigrid hierarchy built) is about to be solved: A and the Hessian K with all of the term
        instead (``_curv_full``) when ``_smallest_eigenpair``'s estimate theta of the smallest
        eigenvalue of the system with it, on the free dofs, exceeds its residual's norm. Returns
        whether it took all of the term."""
        Kf = self._Kd + self._curv_M  # the diagonal blocks with all of -lam S [N/m]
        N = Kf - self.K[self.diag]  # ... minus those with its positive part: its negative part
        if not N.any():
            return False
        Pi = self.Pi
        Af = self.A.copy()
        Af[self.diag] += np.einsum("kab,kbc,kcd->kad", Pi, N, Pi)
        # (preconditioned by the V-cycle on the free dofs; a held dof's row of A is the identity's)
        est = self._free_eigenpair(Af, self.mg.vcycle, self.tuning.curvature_cg_test)
        if est is None:
            return False
        theta, r, _ = est
        if not (theta > r):
            return False
        self.A = Af  # (the multigrid keeps the array it was built on)
        self.K[self.diag] = Kf
        self._curv_full = True
        return True

    def _negative_curvature(self, mu_abs):
        """On a direct level whose system with all of the curvature term was found indefinite
        (the last solve, with its positive part, left its factor in ``_refactor``): LOBPCG's
        unit eigenvector v (3n,) of the smallest eigenvalue theta [N/m] of the projected system
        with all of the term (shift mu_abs [N/m]) on the free dofs, when theta < -|A v - theta v|
        (a converged negative eigenvalue), else None. Starts from the last estimate's vector
        (``_eig_x``)."""
        Kf = self.K.copy()
        Kf[self.diag] = self._Kd + self._curv_M
        Af = np.empty_like(Kf)
        _project_system(self.indptr, self.indices, Kf, self.diag, self.Pi, mu_abs, Af)
        est = self._free_eigenpair(Af, self._refactor, self.tuning.neg_curv_iters)
        if est is None:
            return None
        theta, r, x = est
        if not (theta < -r):
            return None
        v = np.empty(3 * self.n)
        _apply_pi(self.Pi, x, v)  # (in the free space up to rounding: exactly there)
        return v

    def _free_eigenpair(self, Af, inner, iters):
        """LOBPCG's estimate (``_smallest_eigenpair``, ``iters`` iterations) of the smallest
        eigenpair of the projected system Af (nb, 3, 3) [N/m] (this level's BSR pattern) on the
        free dofs, preconditioned by inner (rhs (3n,) -> (3n,)) between projections by Pi, from
        the last estimate's vector (``_eig_x``; at first a random one): (theta [N/m],
        |Af x - theta x|, x (3n,) unit), or None when the start projects to 0."""
        n3 = 3 * self.n
        indptr, indices, Pi = self.indptr, self.indices, self.Pi

        def mv(v):
            y = np.empty(n3)
            _bsr_matvec(indptr, indices, Af, v, y)
            return y

        def pc(v):
            w = np.empty(n3)
            _apply_pi(Pi, v, w)
            z = inner(w)
            _apply_pi(Pi, z, w)
            return w

        x0 = self._eig_x if self._eig_x is not None else self._eig_rng.standard_normal(n3)
        p0 = np.empty(n3)
        _apply_pi(Pi, x0, p0)
        if not (_dot(p0, p0) > 0.0):
            return None
        theta, r, x = _smallest_eigenpair(mv, pc, p0, iters)
        self._eig_x = x
        return theta, r, x

    def _band_again(self, rhs):
        """A^-1 rhs (3n,) with the banded Cholesky factor the last solve left in the work array."""
        inv, _, work = self._band
        x = np.empty(3 * self.n)
        _band_factored_solve(work, inv, rhs, x)
        return x

    def _curvature_fallback(self):
        """The Hessian K with the positive part of the curvature term (``Curvature.POSITIVE``) instead of
        all of it, for the rest of the iteration."""
        self.K[self.diag] = self._Kd
        _add_curvature(self._curv_M, 1, self.diag, self.K)
        self._curv_full = False

    def _mg_stale(self, mu_abs):
        """Rebuild the multigrid hierarchy when the active set changed, the shift changed, or
        the last solve needed many iterations; otherwise the previous one (a slightly older
        Hessian) still preconditions well and saves the Galerkin products."""
        if self._mg_pi is None or self._mg_mu != mu_abs or self._last_cg > 12 or self._mg_age >= 6:
            self._mg_mu = mu_abs
            return True
        if not np.array_equal(self._mg_pi, self.Pi):
            return True
        return False

    # -- one iteration -----------------------------------------------------------------------
    def iterate(self, state, vinf_now, forcing=1e-3):
        """One Newton iteration on state (in place). Returns (residual, energy, status), status a
        StepStatus: OK, DIVERGED (a non-finite residual) or NO_PROGRESS (no step lowers the energy
        or the residual; state unchanged)."""
        m = self.model
        pos = state.positions
        F = self.F
        self.v_prev = vinf_now
        if self._cache is not None and self._cache[0] is pos and _same(self._cache[1], pos):
            E0 = self._cache[2]
            F[:] = self._cache[3]
        else:
            E0 = self.energy_forces(pos, F)
        self._cache = None
        self.singular = 0
        self.failure = ""
        contact = state.in_contact
        contact_before = contact.copy()
        Q = self.queries(pos)
        _projectors_q(pos, F, m.fixed_axes, contact, self.has_mold, self.margs, self.Pi, self.probe, Q)
        # distances of the nodes not in contact (after the releases; contact nodes are on the surface,
        # but for a gap the step is to close, tuning.held_keep_gap)
        _free_distances_q(contact, self.has_mold, Q, m.fixed_axes, self.sd0, self.rules)
        v_base = self.residual(pos, contact, F) if not _same(contact, contact_before) else vinf_now
        f = F.reshape(-1)
        rhs = np.empty(3 * self.n)
        _apply_pi(self.Pi, f, rhs)
        _assemble(pos, *self.sargs, self.kink, self.slot, self.K)
        if m.seam_count:
            seam_assemble(*m.seam_args(), self.seam_slot, self.K)
        if m.friction is not None:
            fr = m.friction
            friction_assemble(pos, fr.nodes, fr.anchor, fr.normal, fr.weight, fr.eps, self.diag, self.K)
        self._curv_full = False
        self._curv_test = False
        curv_had = False  # a direct level with the curvature term (and so its definiteness test)
        tu = self.tuning
        if tu.curvature != Curvature.OFF and self.has_mold:
            if tu.curvature == Curvature.FULL_WHILE_DEFINITE and self.margs[0][0] == MOLD_SMOOTH \
                    and (self.direct or tu.curvature_cg_test):
                # direct levels: all of -lam S while the direct solve finds the system positive
                # definite (the banded Cholesky's pivots, the sparse LU's), else its positive part
                # (_solve_linear, _curvature_fallback). CG's levels: its positive part, and all of
                # it when the first solve's LOBPCG estimate finds the system with it positive
                # definite (_curvature_cg_test). CG alone is no test: it can reach its tolerance
                # on an indefinite system without meeting a direction of non-positive curvature
                # (the band at 1.24 m with CG: 0.468 J, the saddle, against 0.3315 J)
                self._curv_M[:] = 0.0
                if _curvature_terms(pos, F, contact, self.has_mold, self.margs, self.fd_step, self._curv_M):
                    self._Kd = self.K[self.diag].copy()
                    _add_curvature(self._curv_M, 2 if self.direct else 1, self.diag, self.K)
                    self._curv_full = self.direct
                    self._curv_test = not self.direct
                    curv_had = self.direct
            else:
                _curvature_blocks(pos, F, contact, self.has_mold, self.margs, self.fd_step,
                                  1 if tu.curvature == Curvature.FULL_WHILE_DEFINITE else int(tu.curvature), self.diag, self.K)
        tr = _diag_traces(self.K, self.diag)
        free = ~m.fixed_axes.all(axis=1)
        dsum = tr[free].sum()
        dcount = 3 * int(free.sum())
        dmean = dsum / dcount if dcount else 1.0
        if not (dmean > 0.0):
            dmean = 1.0
        cg_spent = 0
        for attempt in range(8):
            if attempt and cg_spent > tu.iterate_budget_cg:
                # failed attempts near float64's floor can each cost hundreds of CG iterations:
                # keep one iteration (and so the driver's batches) short
                break
            mu_abs = self.lm * dmean
            tol = min(tu.forcing_max, max(forcing, 1e-12))
            dx, cg_it = self._solve_linear(rhs, mu_abs, tol)
            cg_spent += cg_it
            for _ in range(3):
                if not (self.has_mold and _all_finite(dx)):
                    break
                blocked = _block_infeasible_q(pos, dx, contact, self.has_mold, self.margs, self.probe, self.Pi,
                                              self.queries(pos))
                if tu.hold_entering:
                    blocked += _block_entering(pos, dx, contact, self.sd0, self.has_mold, self.margs, self.Pi,
                                               PENETRATION_TOL, rhs, self._hold_share)
                if blocked == 0:
                    break
                _apply_pi(self.Pi, f, rhs)
                if tu.blocked_warm_start and not self.direct:
                    # the step solved before, projected onto the new active set: it differs from
                    # the new solution only about the few nodes just held (a local correction)
                    x0 = np.empty_like(dx)
                    _apply_pi(self.Pi, dx, x0)
                    dx, _ = self._solve_linear(rhs, mu_abs, tol, x0, tu.blocked_reuse_mg)
                else:
                    dx, _ = self._solve_linear(rhs, mu_abs, tol)
            if not _all_finite(dx):
                self.lm = max(self.lm * 100.0, 1e-8)
                continue
            slope = -_dot(rhs, dx)  # directional derivative of E (negative for a descent direction)
            if tu.held_keep_gap and self.has_mold and _gap_closure(contact, m.fixed_axes, self.sd0, Q, self.gap,
                                                                     tu.held_gap_min):
                # contact nodes still off the surface (held by _block_entering a little off it, or
                # left there by a step cut short): the step closes their gaps g, a prescribed move
                # the others' step answers (A y = Pi (f - K g), the step y + g)
                Kg = np.empty(3 * self.n)
                _bsr_matvec(self.indptr, self.indices, self.K, self.gap, Kg)
                PKg = np.empty(3 * self.n)
                _apply_pi(self.Pi, Kg, PKg)
                full = self._curv_full
                dy, cg_it = self._solve_linear(rhs - PKg, mu_abs, tol, None if self.direct else dx)
                if full and not self._curv_full:
                    # the solve fell back to the curvature term's positive part: K g again with it
                    _bsr_matvec(self.indptr, self.indices, self.K, self.gap, Kg)
                    _apply_pi(self.Pi, Kg, PKg)
                    dy, cg_it2 = self._solve_linear(rhs - PKg, mu_abs, tol, None if self.direct else dx)
                    cg_it += cg_it2
                cg_spent += cg_it
                if not _all_finite(dy):
                    self.lm = max(self.lm * 100.0, 1e-8)
                    continue
                dx = dy + self.gap
                slope = -_dot(rhs, dy) - _dot(f, self.gap)
            if tu.neg_curv_move > 0.0 and curv_had and not self._curv_full and slope < 0.0:
                # indefinite with all of the curvature term: a step along its negative
                # curvature too (tuning.neg_curv_move)
                v = self._negative_curvature(mu_abs)
                big = np.abs(v).max() if v is not None else 0.0
                if big > 0.0:
                    gv = _dot(rhs, v)
                    if gv < 0.0:
                        v = -v
                        gv = -gv
                    tau = tu.neg_curv_move * self.spacing / big
                    dx = dx + tau * v
                    slope -= tau * gv
            if not (slope < 0.0):
                self.lm = max(self.lm * 100.0, 1e-8)
                continue
            accepted = self._line_search(state, dx, E0, slope, v_base)
            if accepted is not None:
                # Levenberg-Marquardt shift as a trust region: a step the line search had to cut
                # hard means the quadratic model is poor at that length (slack springs leave
                # directions nearly free; contact nodes leave their faces), so shift more
                if self.ls_alpha < tu.lm_alpha_low:
                    self.lm = min(max(self.lm * 10.0, 1e-8), tu.lm_max)
                    self._set_kink(1.0)
                elif self.ls_alpha >= tu.lm_alpha_high:
                    self.lm = max(self.lm / 10.0, 1e-12)
                    if self._kink_decay > 1.0 and _same(contact_before, state.in_contact):
                        self._set_kink(max(self._kink_scale / self._kink_decay, tu.kink_floor))
                return accepted
            self.lm = max(self.lm * 100.0, 1e-6)
        if self.singular:
            self.failure = (f"the Newton system was exactly singular in {self.singular} factorisation(s) "
                            f"up to a Levenberg shift of {self.lm:.0e} x the mean diagonal")
        return v_base, E0, StepStatus.NO_PROGRESS

    def _line_search(self, state, dx, E0, slope, v_base):
        pos = state.positions
        contact = state.in_contact
        m = self.model
        alpha = 1.0
        # do not let any node move by more than the sheet's size in one step
        big = np.abs(dx).max()
        if big > 0 and alpha * big > 0.5 * self.blowup:
            alpha = 0.5 * self.blowup / big
        Ft = np.empty_like(self.F)
        mesh = self.has_mold and self.margs[0][0] == MOLD_MESH and contact.any()
        face0 = self._face0
        faces_known = False
        # the smooth surface's segment hits start from the nodes' answers at pos (Q0); other
        # molds do not read them (and the trial passes' residuals would query pos again)
        smooth = self.has_mold and self.margs[0][0] == MOLD_SMOOTH
        if self._memo.shape[0]:
            self._memo[:, 0] = 0.0  # no segment traced yet in this line search
        for _ in range(40):
            self.ls_alpha = alpha
            # the straight step (contact nodes projected back onto the surface); on a mesh mold,
            # when it fails, the same step with contact nodes stopped at their face's border
            for clip in ((False, True) if mesh else (False,)):
                if clip and not faces_known:
                    _contact_faces_q(contact, self.has_mold, self.margs, self.queries(pos), face0)
                    faces_known = True
                # the clipped pass re-queries only the nodes the clip stops (the others' answers
                # from the pass just before, at the same alpha, stand)
                pen = _trial_positions_sd(pos, contact, self.sd0, dx, alpha, m.fixed_axes, self.has_mold, self.margs,
                                          clip, face0, self.F, self.trial, self.trial_contact, self._sd_trial, clip,
                                          self.queries(pos) if smooth else _NO_Q, self._memo, self._Qt, self.rules)
                self._qt_for = self.trial if self._Qt.shape[0] else None
                if not (pen <= PENETRATION_TOL):
                    continue
                E1 = self.energy_forces(self.trial, Ft)
                if not math.isfinite(E1):
                    continue
                resolution = self.tuning.energy_resolution * max(abs(E0), abs(E1), 1e-300) + 1e-300
                if E1 <= E0 + 1e-4 * alpha * slope and E1 < E0 - resolution:
                    return self._accept(state, E1, F=Ft)
                if abs(E1 - E0) <= 10 * resolution:
                    # below the energy's resolution: judge by the residual
                    v1 = self.residual(self.trial, self.trial_contact, Ft)
                    if v1 < v_base:
                        return self._accept(state, E1, v1, Ft)
                    if self.tuning.trapezoid_energy:
                        # the energy change by the trapezoid rule, which does not cancel: the
                        # Armijo rule decides below the energy's resolution
                        dE = _trapezoid_change(pos, self.trial, self.F, Ft)
                        if dE <= 1e-4 * alpha * slope:
                            return self._accept(state, E1, v1, Ft)
            alpha *= 0.5
            if alpha * np.abs(dx).max() < 1e-17:
                break
        return None

    def _accept(self, state, E1, v1=None, F=None):
        if self._qt_for is self.trial and self._q_pos is not None and not _same(self._q_pos, self.trial):
            # the mold's answers at the accepted positions: the trial pass's where it knows them,
            # the last ones for nodes that did not move, a query for the rest
            _complete_queries(self.trial, self._Qt, self._q_pos, self.has_mold, self.margs, self.Q)
            self._q_pos[:] = self.trial
        self._qt_for = None
        state.positions[:] = self.trial
        state.in_contact[:] = self.trial_contact
        if v1 is None:
            v1 = self.residual(state.positions, state.in_contact, F)
        if F is not None:
            # forces and energy at the accepted state: the next iteration starts from them
            self._cache = (state.positions, state.positions.copy(), E1, F)
        if not math.isfinite(v1):
            return v1, E1, StepStatus.DIVERGED
        return v1, E1, StepStatus.OK


# no answers at the step's start for _trial_positions_sd (other molds than the smooth surface)
_NO_Q = np.empty((0, 10))


def _lu_positive_definite(lu) -> bool:
    """Whether the symmetric matrix that scipy's ``splu`` factorised (symmetric mode) is positive
    definite: its pivots were all taken on the diagonal (the same row and column permutation),
    so P A P^T = L U = L D L^T with D = diag(U), and all of them are positive (Sylvester)."""
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return False
    return bool(np.all(lu.U.diagonal() > 0.0))


def _smallest_eigenpair(matvec, prec, x0, iters):
    """LOBPCG's estimate (block size 1, ``iters`` iterations from x0) of the smallest eigenvalue of
    a symmetric operator A: (theta, |A x - theta x|, x) with x (m,) its unit eigenvector estimate.
    matvec(v) -> A v and prec(v) -> M v (M symmetric positive definite: the preconditioner) on
    vectors (m,). theta is a Rayleigh quotient, so it is at least the smallest eigenvalue; the
    caller takes A as positive definite only when theta exceeds the residual's norm.

    Reference: Knyazev A. V., Toward the optimal preconditioned eigensolver: locally optimal block
    preconditioned conjugate gradient method, SIAM J. Sci. Comput. 23 (2001)."""
    m = x0.shape[0]

    def mm(X):
        X = np.asarray(X).reshape(m, -1)
        return np.column_stack([matvec(np.ascontiguousarray(X[:, c])) for c in range(X.shape[1])])

    def pm(X):
        X = np.asarray(X).reshape(m, -1)
        return np.column_stack([prec(np.ascontiguousarray(X[:, c])) for c in range(X.shape[1])])

    A = sla.LinearOperator((m, m), matvec=mm, matmat=mm, dtype=float)
    M = sla.LinearOperator((m, m), matvec=pm, matmat=pm, dtype=float)
    with warnings.catch_warnings():
        # (LOBPCG warns when it stops at maxiter before its tolerance: the usual case here)
        warnings.simplefilter("ignore")
        _, V = sla.lobpcg(A, x0.reshape(m, 1), M=M, tol=1e-30, maxiter=iters, largest=False)
    x = np.ascontiguousarray(V[:, 0])
    x /= math.sqrt(_dot(x, x))
    Ax = matvec(x)
    theta = _dot(x, Ax)
    res = Ax - theta * x
    return theta, math.sqrt(_dot(res, res)), x


@njit(cache=True)
def _trapezoid_change(x0, x1, F0, F1):
    """-1/2 sum (F0 + F1) . (x1 - x0) [J]: the energy change from x0 to x1 (n, 3) [m] by the
    trapezoid rule with the forces F0, F1 (n, 3) [N] at both ends."""
    s = 0.0
    for k in range(x0.shape[0]):
        for a in range(3):
            s += (F0[k, a] + F1[k, a]) * (x1[k, a] - x0[k, a])
    return -0.5 * s


@njit(cache=True)
def _diag_traces(K, diag):
    """Traces (n,) [N/m] of the diagonal blocks K[diag] (the Levenberg shift's scale; summed by
    numpy afterwards, in the order the recorded equilibria were computed with)."""
    out = np.empty(diag.shape[0])
    for k in range(diag.shape[0]):
        q = diag[k]
        out[k] = 0.0 + K[q, 0, 0] + K[q, 1, 1] + K[q, 2, 2]
    return out


@njit(cache=True)
def _same(a, b):
    """np.array_equal(a, b) for two arrays of the same shape (1-d or 2-d; nan differs from
    everything), without numpy's temporaries: the per-call cost of the cached-answer checks."""
    if a.shape != b.shape:
        return False
    x = a.ravel()
    y = b.ravel()
    for i in range(x.shape[0]):
        if not (x[i] == y[i]):
            return False
    return True


@njit(cache=True)
def _all_finite(x):
    """np.isfinite(x).all() for a flat array, without the temporary."""
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


def _coupled_pairs(model):
    """(P,2) node pairs whose Hessian blocks couple: the springs', then every pair of nodes of
    each seam element (only the springs' without seam elements)."""
    if not model.seam_count:
        return model.spring_nodes
    q = model.seam_nodes
    i, j = np.triu_indices(q.shape[1], 1)
    pairs = np.stack([q[:, i].ravel(), q[:, j].ravel()], 1)
    return np.ascontiguousarray(np.concatenate([model.spring_nodes, pairs]))




def _forcing(v, e, v_prev=None, forcing_max=NewtonTuning.forcing_max):
    """Inexact-Newton forcing term (relative linear residual) at residual v [N] for the limit e
    [N]: Eisenstat and Walker's choice 2, 0.9 (v / v_prev)^2 (v_prev: the residual one
    iteration before, None: unknown), capped at forcing_max (``NewtonTuning.forcing_max``), and at least 0.5 e / v (Kelley's
    safeguard: the last iteration does not solve beyond what reaching e needs).

    References: Eisenstat S. C., Walker H. F., Choosing the forcing terms in an inexact Newton
    method, SIAM J. Sci. Comput. 17 (1996); Kelley C. T., Iterative Methods for Linear and
    Nonlinear Equations, SIAM 1995, section 6.3."""
    if not math.isfinite(v) or v <= 0:
        return forcing_max
    eta = forcing_max
    if v_prev is not None and math.isfinite(v_prev) and v_prev > 0:
        eta = min(eta, 0.9 * (v / v_prev) ** 2)
    return float(min(forcing_max, max(eta, 0.5 * max(e, 0.0) / v, 1e-10)))


def _seam_pairs(model):
    """(m,2) int64: the model's sewn node pairs (its zero-length seam springs), or None."""
    sel = model.spring_family == SpringFamily.SEAM
    if not sel.any():
        return None
    return np.ascontiguousarray(model.spring_nodes[sel], np.int64)
