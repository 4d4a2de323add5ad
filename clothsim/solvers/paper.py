"""The seed paper's node-by-node relaxation, faithful (Garcia, Gomez, Ruiz, Boulanger 2007, sec. 3.2-3.3).

Each iteration is one sweep over the nodes in the paper's numbering order (left to right along
warp, rows from bottom to top). At node N_ij:

1. R = sum of the spring forces around it (eq. 3) plus the constant external force (gravity, when
   the scene has it); constrained axes are zeroed (3.2.3).
2. Step zeta = (sum of elongations d_k = l - l0 of its springs) / C (eq. 4), moved along R/|R|
   (eq. 5). When the move does not lower the node's residual V_k, zeta is divided by C and the
   move retried, at most ``max_retries`` times; if none helps the node stays where it was.
3. Contact (3.2.2): a node in contact whose R points out of the mold (n.R > 0) moves freely; else
   it moves along the tangential part R* = R - (R.n) n and is projected back onto the surface. A
   free node whose move would cross the surface stops on it and becomes a contact node.
4. Stop when ||V||_inf <= e (eq. 6).

Choices where the paper is silent (documented because users cite this method):
- Sign of d_k for slack springs: a slack spring carries no force, so its "elongation" must not
  shrink the step: zeta uses the sum of *positive* elongations. If that is 0 (all springs slack,
  the node moved only by gravity or the optional compression-resisting springs) the sum of |d_k|
  is used, and if that is 0 too, the mean rest length of its springs.
- "Force drops" is measured by V_k, the node's own residual entry (|R|, or |R*| on contact), so
  that the acceptance test and the stopping criterion agree.
- The retry limit (default 60) bounds the work per node; with C = 2 that allows steps down to
  1e-18 of the first, far below float64 resolution of a position.
- Residual V is evaluated after each full sweep with the same definition every solver uses.

References: Garcia M., Gomez M., Ruiz O., Boulanger P., "Spring-particle model for hyperelastic
cloth", Dyna 74 (151), 2007.

Limitations: it is a coordinate-wise descent on |R|, not on the energy; its iteration count grows
with the square of the grid's side (information crosses one node per sweep), and it converges
linearly at best. Use ``newton`` (or ``auto``) for large grids and tight tolerances.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..contact import MAX_FEATURE_NORMALS, node_residual, residual_from_forces, stop_at_surface
from ..kernels import forces_and_energy, node_force, seam_forces_and_energy, seam_node_force
from ..lattice import seam_adjacency
from ..mold import mold_query
from .base import Solver, StepReport, StepStatus
from .common import blowup_limit, model_mold_args
from .options import PaperOptions, live_options, paper_options

# After a projection onto the mold a node must not be inside by more than this [m].
PENETRATION_TOL = 1e-12


@njit(cache=True)
def _relax_node(k, pos, fixed, in_contact, adj_ptr, adj_node, adj_spring, rest, width, table,
                x, y, cum, start, comp, ext, C, max_retries, has_mold, margs, R, Rn, qbuf, nbuf, trial,
                sptr, selem, snodes, sweight, sk):
    """Relax node k (paper 3.2). Returns 1 if it moved. sptr, selem: the seam elements at each
    node (clothsim.lattice.seam_adjacency); snodes, sweight, sk: the seam element arrays (empty
    when the scene has none)."""
    dpos, dabs = node_force(k, pos, adj_ptr, adj_node, adj_spring, rest, width, table, x, y, cum,
                            start, comp, ext, R)
    if sptr[k + 1] > sptr[k]:
        d = seam_node_force(k, pos, sptr, selem, snodes, sweight, sk, R)
        dpos += d
        dabs += d
    p0 = pos[k, 0]
    p1 = pos[k, 1]
    p2 = pos[k, 2]
    contact0 = in_contact[k]
    v0 = node_residual(R, fixed[k], contact0, pos[k], has_mold, margs, qbuf, nbuf)  # zeroes fixed axes of R
    if v0 == 0.0:
        return 0
    tangent = False
    if contact0 and has_mold:
        mold_query(margs, pos[k], qbuf)
        n0, n1, n2 = qbuf[3], qbuf[4], qbuf[5]
        rn = R[0] * n0 + R[1] * n1 + R[2] * n2
        if rn <= 0.0:
            # move in the tangent plane: R* = R - (R.n) n
            tangent = True
            R[0] -= rn * n0
            R[1] -= rn * n1
            R[2] -= rn * n2
            for a in range(3):
                if fixed[k, a]:
                    R[a] = 0.0
    rlen = math.sqrt(R[0] * R[0] + R[1] * R[1] + R[2] * R[2])
    if rlen == 0.0:
        return 0
    if dpos > 0.0:
        zeta = dpos / C
    elif dabs > 0.0:
        zeta = dabs / C
    else:
        s = 0.0
        c = 0
        for q in range(adj_ptr[k], adj_ptr[k + 1]):
            s += rest[adj_spring[q]]
            c += 1
        zeta = (s / c if c > 0 else 1.0) / C
    d0 = R[0] / rlen
    d1 = R[1] / rlen
    d2 = R[2] / rlen
    for _ in range(max_retries):
        trial[0] = p0 + zeta * d0
        trial[1] = p1 + zeta * d1
        trial[2] = p2 + zeta * d2
        contact1 = False
        ok = True
        if has_mold:
            if tangent:
                sd = mold_query(margs, trial, qbuf)
                for a in range(3):
                    if not fixed[k, a]:
                        trial[a] = qbuf[a]
                contact1 = True
                if fixed[k, 0] or fixed[k, 1] or fixed[k, 2]:
                    sd = mold_query(margs, trial, qbuf)
                    if sd < -PENETRATION_TOL:
                        ok = False  # fixed axes keep the node inside: reject this move
            else:
                contact1 = stop_at_surface(margs, pos[k], trial, fixed[k])
                sd = mold_query(margs, trial, qbuf)
            if not tangent and (contact1 or sd < 0.0):
                # land exactly on the surface (the hit point is only accurate to rounding)
                for a in range(3):
                    if not fixed[k, a]:
                        trial[a] = qbuf[a]
                contact1 = True
                if fixed[k, 0] or fixed[k, 1] or fixed[k, 2]:
                    sd = mold_query(margs, trial, qbuf)
                    if sd < -PENETRATION_TOL:
                        ok = False  # fixed axes keep the node inside: reject this move
        if ok:
            pos[k, 0] = trial[0]
            pos[k, 1] = trial[1]
            pos[k, 2] = trial[2]
            in_contact[k] = contact1
            node_force(k, pos, adj_ptr, adj_node, adj_spring, rest, width, table, x, y, cum, start,
                       comp, ext, Rn)
            if sptr[k + 1] > sptr[k]:
                seam_node_force(k, pos, sptr, selem, snodes, sweight, sk, Rn)
            v1 = node_residual(Rn, fixed[k], contact1, pos[k], has_mold, margs, qbuf, nbuf)
            if v1 < v0:
                return 1
            pos[k, 0] = p0
            pos[k, 1] = p1
            pos[k, 2] = p2
            in_contact[k] = contact0
        zeta /= C
    return 0


@njit(cache=True, nogil=True)
def paper_sweeps(pos, fixed, in_contact, order, adj_ptr, adj_node, adj_spring, rest, width, table,
                 x, y, cum, start, comp, spring_nodes, ext, C, max_retries, has_mold, margs,
                 n_sweeps, e, blowup, res_out, en_out, prev, sptr, selem, snodes, sweight, sk):
    """Run up to n_sweeps sweeps. Returns (sweeps done, flag): flag 0 ok, 1 converged, 2 diverged
    (positions restored to the last finite sweep), 3 no node could move. The seam elements
    (sptr, selem, snodes, sweight, sk; see ``_relax_node``) add to every force."""
    R = np.empty(3)
    Rn = np.empty(3)
    qbuf = np.empty(8)
    nbuf = np.empty((MAX_FEATURE_NORMALS, 3))
    trial = np.empty(3)
    V = np.empty(pos.shape[0])
    F = np.empty_like(pos)
    prev_contact = in_contact.copy()
    for it in range(n_sweeps):
        prev[:] = pos
        prev_contact[:] = in_contact
        moved = 0
        for kk in range(order.shape[0]):
            moved += _relax_node(order[kk], pos, fixed, in_contact, adj_ptr, adj_node, adj_spring, rest,
                                 width, table, x, y, cum, start, comp, ext, C, max_retries, has_mold,
                                 margs, R, Rn, qbuf, nbuf, trial, sptr, selem, snodes, sweight, sk)
        # one force pass gives both the sweep's energy and its residual (eq. 6)
        en = forces_and_energy(pos, spring_nodes, rest, width, table, x, y, cum, start, comp, ext, F)
        if snodes.shape[0]:
            en += seam_forces_and_energy(pos, snodes, sweight, sk, F)
        vinf = residual_from_forces(pos, F, fixed, in_contact, has_mold, margs, V)
        big = 0.0
        for k in range(pos.shape[0]):
            for a in range(3):
                d = abs(pos[k, a])
                if not (d <= big):
                    big = d if not math.isnan(d) else math.inf
        if not math.isfinite(vinf) or big > blowup:
            pos[:] = prev
            in_contact[:] = prev_contact
            return it, 2
        res_out[it] = vinf
        en_out[it] = en
        if vinf <= e:
            return it + 1, 1
        if moved == 0:
            return it + 1, 3
    return n_sweeps, 0


def paper_order(model) -> np.ndarray:
    """Node visiting order: the paper numbers nodes left to right (i, along warp), rows bottom to
    top (j, along weft); panel after panel in a lattice of several."""
    topo = model.topology
    k = np.lexsort((topo.node_ij[:, 0], topo.node_ij[:, 1], topo.node_panel))
    free = ~model.fixed_axes.all(axis=1)
    return np.ascontiguousarray(k[free[k]].astype(np.int64))


class PaperSolver(Solver):
    """The paper's node relaxation as a solver object: ``PaperSolver(model, PaperOptions(C,
    max_retries))``; one iteration = one sweep over the nodes (see the module docstring).
    ``options`` may be replaced between steps (a GUI edit of C reaches a running relaxation)."""

    name = "paper"
    Options = PaperOptions

    def __init__(self, model, options: PaperOptions | None = None):
        super().__init__(model, options)
        self.has_mold, self.margs = model_mold_args(model)
        self.order = paper_order(model)
        self.adj = model.adjacency_args()
        self.seam = (*seam_adjacency(model.node_count, model.seam_nodes), *model.seam_args())
        self.limit = blowup_limit(model)
        self._prev = np.empty((model.node_count, 3))

    def step(self, state, n, *, e=0.0, time_left_s=None) -> StepReport:
        m = self.model
        res = np.empty(n)
        en = np.empty(n)
        o = self.options
        done, flag = paper_sweeps(state.positions, m.fixed_axes, state.in_contact, self.order, *self.adj,
                                  m.spring_nodes, m.external_force, float(o.C), int(o.max_retries),
                                  self.has_mold, self.margs, n, float(e), self.limit, res, en, self._prev,
                                  *self.seam)
        state.iteration += done
        return StepReport(done, res[:done], en[:done], _FLAG[flag])


_FLAG = {0: StepStatus.OK, 1: StepStatus.CONVERGED, 2: StepStatus.DIVERGED, 3: StepStatus.NO_PROGRESS}


def solve(model, state, settings, callback=None, history=None):
    """Relax ``state`` in place with the paper's method under ``settings`` (a SolverSettings:
    C and max_retries, re-read between batches, plus the driver's limits); returns a SolveResult."""
    solver = PaperSolver(model, paper_options(settings))
    return solver.solve(state, settings, callback, history, before_batch=live_options(settings))
