"""Grid sequencing: the scene on coarser grids (every second node, recursively), each solved by
Newton from the previous one's interpolated solution, gives the fine grid's starting state.

The coarse models come from the lattice builder at stride 2 (clothsim.lattice.coarsen_model) and
the interpolation from the Topology (``grid_prolongation``); positions (n, 3) [m].
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp
from numba import njit

from ...mold import mold_query_many
from .active_set import PENETRATION_TOL
from ..base import StepStatus
from ..tuning import NewtonTuning
from .iteration import NewtonLevel, _forcing
from .linalg import _grid_transfer
from .objcache import per_object
from .rim import outline_band, settle_outline
from .settle import settle_start


from ...lattice import coarsen_model  # noqa: E402  (the spring builder at stride 2)
from ...model import SpringFamily, State  # noqa: E402



# A cut lattice's coarse grids hold the free fine nodes beside the held outline (the "guessed
# holds", grid._coarsen_lattice) at a flat guess: the held fine node's place plus their rest
# offset. Where the sheet leaves the outline at a slope that guess is off by about slope x offset
# (0.1-0.3 mm on the benchmark's circle), and a boundary offset moves the whole free sheet: the
# fine start then needed a third Newton iteration. The guesses are therefore placed where the
# sheet puts them (``_HoldFit``): on each level from the sheet interpolated from the coarser one,
# on the coarsest again after a first solve (hold_refit_coarsest times), and on the last coarse
# level, once solved, at their fine nodes' places when its solution is interpolated onto the fine
# lattice and the outline band settled there against the true held outline; that level is then
# solved again (hold_band). On the 225-across circle: fine start 5.3e-3 -> 1.2e-3 N, fine Newton
# iterations 3 -> 2 (docs/benchmarks/benchmarks.md, "Sixth round"). hold_fit False: the flat guesses, as before.
# The switches read here are fields of ``tuning.NewtonTuning`` (``_Hierarchy.tuning``). A placed hold
# that would be inside the mold falls back to its flat guess (``_HoldFit.outside``).


class _HoldFit:
    """The guessed holds of one coarse level of a cut lattice, and where to put them.

    g (m,): the level's nodes held there but free on the fine model; axes (m, 3) bool: their held
    axes; fine (m,): their indices in the fine model; xo (m, 3) [m]: the prescribed position of
    each one's anchor o (m,) (the nearest node of the same panel held on the fine model, by rest
    position); nb (m, K): its K (``tuning.hold_fit_neighbours``) nearest free nodes on the level (same
    panel) and w (m, K) the weights of the affine extrapolation through them,
    x_g = x_o + sum_k w_k (x_nb_k - x_o): the least-squares linear map of the rest offsets from the
    anchor, evaluated at g's rest offset; ok (m,) where it is defined."""

    def __init__(self, level_model, fine_model, fine_idx, tuning: NewtonTuning = NewtonTuning()):
        from scipy.spatial import cKDTree

        fine_held = fine_model.fixed_axes.any(axis=1)
        held = level_model.fixed_axes.any(axis=1)
        g = np.nonzero(held & ~fine_held[fine_idx])[0]
        m = g.size
        K = tuning.hold_fit_neighbours
        self.g, self.axes, self.fine = g, level_model.fixed_axes[g], fine_idx[g]
        self.o = np.zeros(m, np.int64)
        self.xo = np.zeros((m, 3))
        self.nb = np.zeros((m, K), np.int64)
        self.w = np.zeros((m, K))
        self.ok = np.zeros(m, bool)
        r, rf = level_model.rest_positions, fine_model.rest_positions
        pan, pan_f = level_model.topology.node_panel, fine_model.topology.node_panel
        free = np.nonzero(~held)[0]
        o = self.o
        # the anchor is held on (at least) g's axes and the neighbours are near: within
        # tuning.hold_fit_reach level spacings (a notch or slit wider than that is not reached across)
        h = float(max(level_model.spacing))
        reach = tuning.hold_fit_reach * h
        for p in np.unique(pan[g]):
            fp = free[pan[free] == p]
            if fp.size < K:
                continue
            tree_f = cKDTree(r[fp])
            for ax in np.unique(self.axes[pan[g] == p], axis=0):
                kg = np.nonzero((pan[g] == p) & (self.axes == ax).all(axis=1))[0]
                hp = np.nonzero((fine_model.fixed_axes[:, ax].all(axis=1)) & (pan_f == p))[0]
                if hp.size == 0:
                    continue
                da, ia = cKDTree(rf[hp]).query(r[g[kg]])
                dn_, inb = tree_f.query(r[g[kg]], k=K)
                o[kg] = hp[ia]
                self.nb[kg] = fp[inb]
                self.ok[kg] = (da <= reach) & (dn_.max(axis=1) <= reach)
        if not self.ok.any():
            return
        dn = r[self.nb] - rf[o][:, None, :]  # (m, K, 3) rest offsets of the neighbours
        dg = r[g] - rf[o]
        A = np.einsum("mki,mkj->mij", dn, dn)
        # rest positions lie in the panel's plane: a relative ridge keeps the Gram matrix regular
        A += (1e-12 * np.einsum("mii->m", A) + 1e-300)[:, None, None] * np.eye(3)
        c = np.linalg.solve(A, dg[:, :, None])[:, :, 0]
        self.w = np.einsum("mki,mi->mk", dn, c)
        self.xo = fine_model.prescribed_positions[o].copy()
        self.ok &= np.isfinite(self.w).all(axis=1) & (np.abs(self.w).sum(axis=1) < 10.0)

    def place(self, src, dst):
        """dst[g] (their held axes) = the affine extrapolation through src (n, 3) [m] (src may be dst)."""
        k = self.ok
        if not k.any():
            return
        g, xo = self.g[k], self.xo[k]
        x = xo + np.einsum("mk,mkj->mj", self.w[k], src[self.nb[k]] - xo[:, None, :])
        dst[g] = np.where(self.axes[k], x, dst[g])

    def take(self, fine_pos, dst):
        """dst[g] (their held axes) = their fine nodes' places in fine_pos (N, 3) [m]."""
        dst[self.g] = np.where(self.axes, fine_pos[self.fine], dst[self.g])

    def outside(self, level_model, dst):
        """Put back at their flat guesses (the level's prescribed positions) the placed holds of
        dst (n, 3) [m] that are inside the level's mold (a held node is never moved onto it)."""
        if level_model.mold is None or self.g.size == 0:
            return

        g = self.g
        pts = np.ascontiguousarray(dst[g])
        m = g.size
        sd = np.empty(m)
        mold_query_many(level_model.mold.kernel_args(), pts, sd, np.empty((m, 3)), np.empty((m, 3)),
                        np.empty((m, 2), np.int64))
        bad = sd < 0.0
        if bad.any():
            gb = g[bad]
            dst[gb] = np.where(self.axes[bad], level_model.prescribed_positions[gb], dst[gb])


def _rim_operator(model):
    """``_relax_rim``'s averaging operator, which depends on the model alone: (rim (m,) the free
    nodes beside a held or missing lattice node, not sewn; A (m, n) CSR their warp and weft
    neighbours; d (m,) how many), or None when there are none."""
    n = model.node_count
    fam = model.spring_family
    lat = (fam == SpringFamily.WARP) | (fam == SpringFamily.WEFT)
    a, b = model.spring_nodes[lat, 0], model.spring_nodes[lat, 1]
    deg = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
    free = ~model.fixed_axes.any(axis=1)
    held_nb = np.zeros(n, bool)
    held = model.fixed_axes.any(axis=1)
    held_nb[a[held[b]]] = True
    held_nb[b[held[a]]] = True
    # a sewn node's missing neighbours are across its seam (its partner's panel): it is not on
    # the fringe, and the mean of its own panel's neighbours would open the seam
    sewn = np.zeros(n, bool)
    sewn[model.spring_nodes[fam == SpringFamily.SEAM].ravel()] = True
    rim = np.nonzero(free & ((deg < 4) | held_nb) & ~sewn)[0]
    if rim.size == 0:
        return None
    A = sp.csr_matrix((np.ones(2 * a.size), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n))
    A = A[rim]
    d = np.asarray(A.sum(axis=1)).ravel()
    return rim, A, d


def _relax_rim(model, pos, cont, op=None, sweeps: int = NewtonTuning.rim_sweeps):
    """On a cut lattice, the free nodes beside a held or missing lattice node (the outline's
    fringe, where the interpolation lost corners) are moved, in ``sweeps`` Jacobi sweeps, to
    the mean of their warp and weft neighbours: the membrane's equilibrium there to first order.
    Sewn nodes (ends of seam springs) are left alone. op: ``_rim_operator(model)`` when known.
    pos (N, 3) [m] is changed in place; contact nodes stay."""
    if op is None:
        op = _rim_operator(model)
    if op is None:
        return
    rim, A, d = op
    keep = ~cont[rim]
    if not keep.any():
        return
    rk = rim[keep]
    for _ in range(sweeps):
        pos[rk] = ((A @ pos) / d[:, None])[keep]


def _prolongation(fine_topology, coarse_topology):
    """P (N, Nc): the full grid's bilinear interpolation, or on a cut or multi-panel lattice the
    Topology's ``lattice_prolongation`` from its stride-2 coarsening (``coarse_topology``)."""
    if fine_topology.is_grid:
        return fine_topology.grid_prolongation()[1]
    ctopo, sub = fine_topology.coarsen()
    return fine_topology.lattice_prolongation(ctopo, sub)


@njit(cache=True)
def _interpolate(pidx, pw, xc, cc, out, cout):
    """out (n, 3) = P xc and cout (n,) = P cc (cc bool (nc,) as 0/1) for the interpolation P
    whose row k has weights pw[k, t] at coarse nodes pidx[k, t] (-1: none), summed from 0 in
    that order (as scipy's sparse product sums a row)."""
    for k in range(pidx.shape[0]):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        c = 0.0
        for t in range(pidx.shape[1]):
            d = pidx[k, t]
            if d < 0:
                continue
            w = pw[k, t]
            a0 += w * xc[d, 0]
            a1 += w * xc[d, 1]
            a2 += w * xc[d, 2]
            c += w * (1.0 if cc[d] else 0.0)
        out[k, 0] = a0
        out[k, 1] = a1
        out[k, 2] = a2
        cout[k] = c


def _interpolated(coarse_model, coarse_state, fine_model, fine_state, P=None, kink=None, band=None, rim_op=None,
                  tuning: NewtonTuning = NewtonTuning()):
    """The interpolation of ``prolong_state`` without its mold query: (pos (n, 3) [m], cont (n,)
    bool: interpolated contact) with the fine held coordinates kept and, on a cut lattice (or on
    full panels given a ``band``), the outline's fringe relaxed and its band settled (nodes may be
    left inside the mold)."""
    if fine_model.topology.is_grid:
        # P's rows as the multigrid's transfer holds them (the same weights in the same order as
        # grid_prolongation's P, so the same sums, without building P)
        pidx, pw = _grid_transfer(*fine_model.topology.grid_shape)[:2]
        pos = np.empty((fine_model.node_count, 3))
        cw = np.empty(fine_model.node_count)
        _interpolate(pidx, pw, coarse_state.positions, coarse_state.in_contact, pos, cw)
        cont = cw > 1.0 - 1e-9
    else:
        if P is None:
            P = _prolongation(fine_model.topology, coarse_model.topology)
        pos = P @ coarse_state.positions
        cont = (P @ coarse_state.in_contact.astype(float)) > 1.0 - 1e-9
    fixed = fine_model.fixed_axes
    pos[fixed] = fine_state.positions[fixed]
    if not fine_model.topology.is_grid and (band is not None or not fine_model.topology.panels_full):
        # (full rectangular panels held on their coarse nodes: the coarse lattices hold their
        # outlines exactly, as the square's do, and neither step saves a Newton step, so the
        # sequencing passes no band; four 101^2 panels: the same Newton residuals to 5 digits,
        # 44 ms of settling saved)
        _relax_rim(fine_model, pos, cont, rim_op, tuning.rim_sweeps)
        if kink is not None and tuning.settle_rim:
            settle_outline(fine_model, pos, cont, kink, band, tuning.rim_gs_sweeps)
    return pos, cont


def prolong_state(coarse_model, coarse_state, fine_model, fine_state, P=None, kink=None, band=None, rim_op=None,
                  tuning: NewtonTuning = NewtonTuning()):
    """Interpolate a coarse solution onto the fine grid (bilinear in the node indices), keep
    the fine constrained coordinates, and put nodes that would be inside the mold (or between
    two contact nodes) onto its surface as contact nodes. On a cut lattice (some panel not a full
    rectangle; on full panels only when a ``band`` is given) the outline's fringe is relaxed
    (``_relax_rim``) and, when ``kink`` (NewtonOptions.kink) is given, its band of nodes settled by
    nonlinear Gauss-Seidel (``rim.settle_outline``; ``band``: ``rim.outline_band(fine_model)`` when
    known). P: the interpolation (``_prolongation``) and rim_op:
    ``_rim_operator(fine_model)``, when known; tuning: NewtonOptions.tuning."""
    pos, cont = _interpolated(coarse_model, coarse_state, fine_model, fine_state, P, kink, band, rim_op, tuning)
    fixed = fine_model.fixed_axes
    if fine_model.mold is not None:
        margs = fine_model.mold.kernel_args()
        n = fine_model.node_count
        sd = np.empty(n); cp = np.empty((n, 3)); nrm = np.empty((n, 3)); feat = np.empty((n, 2), np.int64)
        mold_query_many(margs, pos, sd, cp, nrm, feat)
        put = (sd < 0) | cont
        put &= ~fixed.all(axis=1)
        k = np.nonzero(put)[0]
        for a in range(3):
            sel = k[~fixed[k, a]]
            pos[sel, a] = cp[sel, a]
        # only the nodes put on the surface moved: the others' distances stand
        pk = np.ascontiguousarray(pos[k])
        sdk = np.empty(k.size)
        mold_query_many(margs, pk, sdk, np.empty((k.size, 3)), np.empty((k.size, 3)), np.empty((k.size, 2), np.int64))
        sd[k] = sdk
        inside = sd < -PENETRATION_TOL
        if inside.any():
            return False
        cont = put
    else:
        cont = np.zeros(fine_model.node_count, bool)
    fine_state.positions[:] = pos
    fine_state.in_contact[:] = cont
    return True


def _solve_level(level: NewtonLevel, state, e, max_iter, deadline, e_settled=None):
    """Newton iterations on a coarse level until its residual is below e (or no progress), or
    below e_settled [N] (when given) after an iteration that left the contact set as it was."""
    v = level.residual(state.positions, state.in_contact)
    settled = False
    for _ in range(max_iter):
        if v <= e or (settled and e_settled is not None and v <= e_settled) or time.perf_counter() > deadline:
            break
        before = state.in_contact.copy()
        v, E, flag = level.iterate(state, v, forcing=_forcing(v, e, level.v_prev, level.tuning.forcing_max))
        settled = np.array_equal(before, state.in_contact)
        if flag != StepStatus.OK:
            break
    return v


def sequencing_chain(model, min_nodes: int = 400):
    """[(model, sub), ...] from the coarsest grid to the given one; each coarser grid has half
    the divisions of the next, and ``sub`` (for all but the last) indexes the next grid's nodes
    that it keeps."""
    chain = [(model, None)]
    m = model
    while True:
        c, sub = coarsen_model(m)
        if c is None or c.node_count < min_nodes:
            break
        chain.append((c, sub))  # sub: the nodes of m (the next finer grid) that c keeps
        m = c
    return chain[::-1]



# the sequencing hierarchies of the last few models (``_hierarchy``), by id(model)
_HIERARCHIES: OrderedDict = OrderedDict()
HIERARCHY_CACHE = 2


class _Hierarchy:
    """What grid sequencing builds for one model and reuses on every later solve of it: the chain
    of coarse models (``sequencing_chain``), the interpolation from each to the next finer one
    (``_prolongation``), a NewtonLevel per coarse model (reset before each use), each coarse
    level's guessed holds (``_HoldFit``; None on full grids) and each level's outline band
    (``rim.outline_band``) and rim operator (None where every panel is a full rectangle,
    ``Topology.panels_full``, and no level has guessed holds)."""

    def __init__(self, model, kink, tuning: NewtonTuning = NewtonTuning()):
        self.kink = kink
        self.tuning = tu = tuning
        chain = sequencing_chain(model) if model.topology.panels_full else sequencing_chain(model, tu.cut_coarsest_nodes)
        self.P = [None] + [_prolongation(chain[i][0].topology, chain[i - 1][0].topology)
                           for i in range(1, len(chain))]
        self.levels = [NewtonLevel(m, kink=kink, tuning=tu) for m, _ in chain[:-1]]
        # each coarse level's guessed holds (None: a full grid, or none)
        self.fits = []
        for li, (m, _) in enumerate(chain[:-1]):
            fit = None
            if tu.hold_fit and not m.topology.is_grid:
                idx = np.arange(m.node_count)
                for lj in range(li, len(chain) - 1):
                    idx = chain[lj][1][idx]
                fit = _HoldFit(m, model, idx, tu)
                fit = fit if fit.g.size else None
            self.fits.append(fit)
        # the outline band and rim relaxation where the coarse lattices hold the outline or the
        # holds only roughly: a panel cut by its outline, or guessed holds (held fine nodes that
        # no coarse node keeps); none on full rectangular panels held on their coarse nodes
        rough = not model.topology.panels_full or any(f is not None for f in self.fits)
        self.bands = [outline_band(m, tu.rim_band) if rough and not m.topology.is_grid else None for m, _ in chain]
        self.rim_ops = [_rim_operator(m) if rough and not m.topology.is_grid else None for m, _ in chain]
        # the given model itself is not kept (the cache must not keep it alive)
        self.chain = chain[:-1] + [(None, None)]


def _hierarchy(model, kink, tuning: NewtonTuning = NewtonTuning()):
    """The model's ``_Hierarchy``, built on its first solve and kept while the model lives (the
    model and its arrays are not changed in place: a Control makes a new Model). The
    ``HIERARCHY_CACHE`` most recently used models' are kept."""
    return per_object(_HIERARCHIES, model, (kink, tuning), lambda: _Hierarchy(model, kink, tuning), HIERARCHY_CACHE)


def _solve_coarse(level: NewtonLevel, state, coarsest: bool, e, deadline, rel=None, reset=True, max_iter=60):
    """Solve one level of the sequencing: the coarsest grid until its contact set is settled, the
    others only as far as their discretisation error matters for the next grid's start (level_rel:
    the fine start's residual is set by the interpolation, not by a tighter coarse solve); rel:
    to this share of the start residual instead; at most max_iter Newton iterations. reset: start
    the level afresh (False: keep its multigrid hierarchy, Levenberg shift and forcing history from
    the last solve)."""
    tu = level.tuning
    if reset:
        level.reset()
    v0 = level.residual(state.positions, state.in_contact)
    if rel is not None:
        _solve_level(level, state, max(e, rel * v0), max_iter, deadline)
    elif coarsest:
        _solve_level(level, state, max(e, 1e-8 * v0), max_iter, deadline, max(e, tu.coarsest_rel * v0))
    else:
        _solve_level(level, state, max(e, tu.level_rel * v0), max_iter, deadline)


def grid_sequence(model, state, e, kink, deadline, tuning: NewtonTuning = NewtonTuning()):
    """Solve the scene on the coarser grids (coarsest first), each started from the previous
    one's solution, and return the interpolated starting state for ``model`` (or None when the
    grid cannot be coarsened or the interpolation fails). e [N]: the run's convergence limit (no
    level is solved tighter); kink: NewtonOptions.kink; tuning: NewtonOptions.tuning; deadline: a ``time.perf_counter`` value.
    The coarse models, transfers and levels are built once per model (``_hierarchy``)."""
    tu = tuning
    hier = _hierarchy(model, kink, tu)
    chain = hier.chain
    if len(chain) < 2:
        return None
    # restrict the current state down the chain (each level keeps every second node)
    starts = [None] * len(chain)
    starts[-1] = (state.positions, state.in_contact)
    for li in range(len(chain) - 1, 0, -1):
        p, c = starts[li]
        sub = chain[li - 1][1]
        starts[li - 1] = (p[sub].copy(), c[sub].copy())
    prev_model = prev_state = None
    for li, (mdl, _) in enumerate(chain[:-1]):
        p, c = starts[li]
        cst = State(np.ascontiguousarray(p), c.copy(), 0)
        if not mdl.topology.is_grid:
            # a cut lattice's coarse grid holds nodes that are free on the fine one (beside its
            # held outline): the restricted state has them where the fine start had those free
            # nodes (lifted), and Newton never moves a held coordinate, so put them in place
            held = mdl.fixed_axes
            cst.positions[held] = mdl.prescribed_positions[held]
        fit = hier.fits[li]
        if prev_state is not None:
            if fit is not None:
                # the guessed holds where the sheet interpolated from the coarser level puts them
                fit.place(hier.P[li] @ prev_state.positions, cst.positions)
                fit.outside(mdl, cst.positions)
            # the previous level's solution; when it cannot be interpolated (prolong_state then
            # leaves cst alone) this level starts from the restricted state
            if (prolong_state(prev_model, prev_state, mdl, cst, hier.P[li], kink, hier.bands[li], hier.rim_ops[li],
                              tu) and tu.settle_contact_rim):
                settle_start(mdl, cst, kink, tu.settle_width, tu.settle_sweeps)
        lvl = hier.levels[li]
        refits = tu.hold_refit_coarsest if li == 0 and fit is not None else 0
        mid = 0 < li < len(chain) - 2 and tu.mid_level_iterations is not None
        _solve_coarse(lvl, cst, li == 0, e, deadline, tu.hold_first_rel if refits else None,
                      max_iter=tu.mid_level_iterations if mid else 60)
        for _ in range(refits):
            # the guessed holds where the solved sheet puts them, and the level solved again
            fit.place(cst.positions, cst.positions)
            fit.outside(mdl, cst.positions)
            _solve_coarse(lvl, cst, True, e, deadline, tu.hold_refit_rel)
        if tu.hold_band and li == len(chain) - 2 and fit is not None:
            # the last coarse level's solution on the fine lattice, its outline band settled there
            # against the true held outline: the guessed holds take their fine nodes' places, and
            # the level is solved again (its multigrid kept while its active set is the same)
            fpos, _ = _interpolated(mdl, cst, model, state, hier.P[-1], kink, hier.bands[-1], hier.rim_ops[-1], tu)
            fit.take(fpos, cst.positions)
            fit.outside(mdl, cst.positions)
            _solve_coarse(lvl, cst, li == 0, e, deadline, reset=False)
        prev_model, prev_state = mdl, cst
    trial = state.copy()
    if not prolong_state(prev_model, prev_state, model, trial, hier.P[-1], kink, hier.bands[-1], hier.rim_ops[-1], tu):
        return None
    if tu.settle_contact_rim:
        settle_start(model, trial, kink, tu.settle_width, tu.settle_sweeps)
    return trial
