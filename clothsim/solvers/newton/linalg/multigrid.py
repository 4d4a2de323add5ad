"""The multigrid preconditioners of the Newton step: the line-smoothed geometric multigrid on a
full grid (``Multigrid``), on any lattice embedded in a padded grid (``PaddedMultigrid``) and
PyAMG's algebraic multigrid (``AlgebraicMultigrid``); the layouts they share, cached per
topology."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from numba import njit

from ....topology import Topology
from ...tuning import NewtonTuning
from ..objcache import per_object
from .assembly import _bsr_residual
from .smoothers import (_NO_MAP, _Transposed, _gather_blocks, _i_lines, _line_gs, _line_slots,
                        _seam_smooth, seam_chains)
from .transfer import (_Transfer, _full_spans, _galerkin_pattern, _galerkin_sum, _galerkin_terms,
                       _galerkin_values, _prolong_add, _restrict, _trimmed_spans, coarse_pairs)


class _Level:
    __slots__ = ("indptr", "indices", "data", "lu", "n", "shape", "ds", "ps", "ns", "T", "tdata")


class Multigrid:
    """Galerkin geometric multigrid on the node grid, used as the CG preconditioner.

    Levels: the fine grid, then every second node (bilinear interpolation), down to at most
    ``tuning.coarsest_nodes`` nodes, factorised with a sparse LU. The fine level's prolongation is
    projected by the active-set projectors Pi, so the coarse spaces only move nodes where they
    may move. Galerkin products, restriction and prolongation are numba loops over the
    structured grid's parent/child lists."""

    def __init__(self, topology, tuning: NewtonTuning = NewtonTuning()):
        """topology: a full-rectangle Topology (``is_grid``): the lines the smoother relaxes
        and the stride-2 levels come from it; tuning: NewtonOptions.tuning."""
        shapes = [topology.grid_shape]
        transfers: list[_Transfer] = []
        nx1, ny1 = topology.grid_shape
        while nx1 * ny1 > tuning.coarsest_nodes and nx1 > 3 and ny1 > 3:
            tr = _Transfer(topology)
            transfers.append(tr)
            topology = tr.coarse
            nx1, ny1 = topology.grid_shape
            shapes.append((nx1, ny1))
        self._init_levels(shapes, transfers, [_full_spans(nx, ny) for nx, ny in shapes], [None] * len(shapes), None,
                          tuning)

    @classmethod
    def for_topology(cls, topology, seam_pairs=None, tuning: NewtonTuning = NewtonTuning()):
        """A multigrid on the full-rectangle ``topology`` whose levels, and the coarse patterns of
        its set-ups, are shared with every other one made here for the same topology
        (``_grid_layout``): a Newton level made for each solve of the same model then builds its
        transfers, Galerkin patterns, line slots and renumbered patterns once, as
        ``PaddedMultigrid`` does for cut lattices. Each keeps its own values. seam_pairs (m,2):
        the sewn node pairs of a panel sewn to itself (a tube), relaxed jointly on every level
        as ``PaddedMultigrid`` relaxes its seams (without it the line sweeps reduce a seam's
        gap by about 1/1000 per sweep: CG made no progress in 200 iterations on a 160 x 32
        tube, and Newton stalled at 2 N)."""
        lay = _grid_layout(topology, tuning)
        pairs = None
        if seam_pairs is not None and len(seam_pairs) and tuning.pair_smoothing:
            pairs = coarse_pairs(seam_pairs, lay.transfers)
        mg = cls.from_levels(lay.shapes, lay.transfers, lay.spans, lay.pad, pairs, tuning)
        mg._layout = lay
        return mg

    @classmethod
    def from_levels(cls, shapes, transfers, spans, pad, pairs=None, tuning: NewtonTuning = NewtonTuning()):
        """A multigrid on levels already built (shapes, transfers, smoother spans, padding masks
        and seam pairs of another instance's __init__; read, never changed), without a set-up."""
        mg = cls.__new__(cls)
        mg._init_levels(shapes, transfers, spans, pad, pairs, tuning)
        return mg

    def _init_levels(self, shapes, transfers, spans, pad, pairs=None, tuning: NewtonTuning = NewtonTuning()):
        self.tuning = tuning
        self.shapes = list(shapes)
        self.transfers: list[_Transfer] = list(transfers)
        self.levels: list[_Level] = []
        self.Pi = None
        # sewn node pairs (m,2) per level relaxed jointly by _chain_gs (along seam chains), or None (set by
        # PaddedMultigrid on sewn lattices, and by for_topology on a full rectangle sewn to itself)
        self.pairs = pairs
        self._pslots = None
        # per level, (span of the i lines, span of the j lines) for _line_gs, and the padding
        # nodes (bool (n_l,), or None), set by PaddedMultigrid; the full lines by default
        self.spans = list(spans)
        self.pad = list(pad)
        # (fine indptr, fine indices, coarse patterns, line slots, seam chains, renumbered
        # patterns) of the last set-up
        self._sym = None
        self._tbuf: dict = {}  # per level, the renumbered values (_Transposed) of the last set-up
        self._layout = None  # a _GridLayout shared with other multigrids of the topology (for_topology)

    def setup(self, indptr, indices, data, Pi, pad_scale=None):
        """Build the hierarchy for the projected fine matrix (BSR arrays). pad_scale: when given,
        a coarse node whose diagonal block the Galerkin product leaves zero (no lattice node
        among its children: padding) gets pad_scale x I3, decoupled (its right-hand sides are
        zero, so it stays at zero). The per-level patterns, slots and Galerkin terms that
        multigrids of one topology share are built lazily under ``_SHARED_LOCK``: two threads
        setting up on one topology (the viewer's warm-up beside its worker) never append a
        level's entry twice."""
        with _SHARED_LOCK:
            self._setup(indptr, indices, data, Pi, pad_scale)

    def _setup(self, indptr, indices, data, Pi, pad_scale):
        self.Pi = Pi
        levels = []
        L = _Level()
        L.indptr, L.indices, L.data = indptr, indices, data
        L.n = indptr.shape[0] - 1
        levels.append(L)
        # the coarse patterns, line slots and seam chains depend on the fine pattern alone: kept
        # from the last set-up while the fine pattern is the same arrays (a Newton level's set-ups
        # share it)
        same = self._sym is not None and self._sym[0] is indptr and self._sym[1] is indices
        lay = self._layout
        if not same:
            got = None if lay is None else lay.sym
            if (got is not None and np.array_equal(got[0], indptr) and np.array_equal(got[1], indices)):
                # the same fine pattern as an earlier multigrid's of this topology: its patterns
                self._sym = (indptr, indices) + got[2:]
            else:
                self._sym = (indptr, indices, [], [], [], [], [])
            if lay is not None:
                lay.sym = (indptr.copy(), indices.copy()) + self._sym[2:]
        pats, slots, chains, trans, terms = self._sym[2:7]
        for lv, tr in enumerate(self.transfers):
            F = levels[-1]
            if lv == len(pats):
                pats.append(_galerkin_pattern(F.indptr, F.indices, tr.pidx, tr.cptr, tr.cchild, tr.nc))
            cip, cidx = pats[lv]
            if self.tuning.galerkin_terms:
                if lv == len(terms):
                    terms.append(_galerkin_terms(F.indptr, F.indices, tr.pidx, tr.pw, tr.cptr, tr.cchild, tr.cw,
                                                 tr.nc, cip, cidx))
                cdat = _galerkin_sum(F.data, Pi, lv == 0, *terms[lv])
            else:
                cdat = _galerkin_values(F.indptr, F.indices, F.data, tr.pidx, tr.pw, tr.cptr, tr.cchild, tr.cw,
                                        tr.nc, Pi, lv == 0, cip, cidx)
            C = _Level()
            C.indptr, C.indices, C.data = cip, cidx, cdat
            C.n = tr.nc
            levels.append(C)
        if pad_scale is not None:
            # after all the products, so that a filled row does not reach the next level
            for C in levels[1:]:
                _fill_empty_diagonal(C.indptr, C.indices, C.data, pad_scale)
        for lv, L in enumerate(levels[:-1]):
            nx1, ny1 = self.shapes[lv]
            if lv == len(slots):
                slots.append(_line_slots(L.indptr, L.indices, nx1, ny1))
            L.ds, L.ps, L.ns = slots[lv]
            if lv == len(trans):
                trans.append(_Transposed(L.indptr, L.indices, nx1, ny1, L.ds, L.ps, L.ns)
                             if nx1 * ny1 >= self.tuning.transpose_nodes else None)
            L.T = trans[lv]
            if L.T is not None:
                # the renumbered values, in a buffer of this multigrid's kept between set-ups
                # (the last hierarchy is not used after a new set-up)
                buf = self._tbuf.get(lv)
                if buf is None or buf.shape != L.data.shape:
                    buf = self._tbuf[lv] = np.empty_like(L.data)
                _gather_blocks(L.data, L.T.gather, buf)
                L.tdata = buf
        if self.pairs is not None:
            # (kept with the pairs they were made for: multigrids sharing _sym share their layout's)
            if not chains or chains[0] is not self.pairs:
                chains[:] = [self.pairs, [None if pr is None else seam_chains(L.indptr, L.indices, pr)
                                          for L, pr in zip(levels, self.pairs)]]
            self._pslots = chains[1]
        last = levels[-1]
        n3 = 3 * last.n
        Alast = sp.bsr_matrix((last.data, last.indices, last.indptr), shape=(n3, n3)).tocsc()
        d = Alast.diagonal()
        scale = np.abs(d).max() if d.size else 1.0
        fix = np.where(np.abs(d) <= 1e-12 * max(scale, 1e-300), max(scale, 1.0), 0.0)
        last.lu = _coarse_solver(Alast, fix, scale)
        self.levels = levels

    def vcycle(self, b, lv=0):
        """One V-cycle for A x = b from x = 0 (symmetric: alternating line Gauss-Seidel before,
        its adjoint after)."""
        L = self.levels[lv]
        if lv == len(self.levels) - 1:
            return L.lu.solve(b)
        nx1, ny1 = self.shapes[lv]
        tr = self.transfers[lv]
        x = np.zeros_like(b)
        # on sewn lattices the seam chains are relaxed before, between and after the line sweeps
        pr = self.pairs[lv] if self.pairs is not None else None
        if pr is not None:
            _seam_smooth(L, pr, self._pslots[lv], b, x, False)
        sp0, sp1 = self.spans[lv]
        _i_lines(L, nx1, ny1, b, x, False, sp0)
        if pr is not None:
            _seam_smooth(L, pr, self._pslots[lv], b, x, False)
        _line_gs(L.indptr, L.indices, L.data, nx1, ny1, L.ds, L.ps, L.ns, b, x, 1, False, sp1, _NO_MAP)
        if pr is not None:
            _seam_smooth(L, pr, self._pslots[lv], b, x, False)
        r = np.empty_like(b)
        _bsr_residual(L.indptr, L.indices, L.data, x, b, r)
        rc = np.empty(3 * tr.nc)
        _restrict(r, tr.cptr, tr.cchild, tr.cw, self.Pi, lv == 0, rc)
        xc = self.vcycle(rc, lv + 1)
        _prolong_add(xc, tr.pidx, tr.pw, self.Pi, lv == 0, x)
        if self.pad[lv] is not None:
            # the padding the trimmed lines leave out: 0, as the full line solve would make it
            x.reshape(-1, 3)[self.pad[lv]] = 0.0
        if pr is not None:
            _seam_smooth(L, pr, self._pslots[lv], b, x, True)
        _line_gs(L.indptr, L.indices, L.data, nx1, ny1, L.ds, L.ps, L.ns, b, x, 1, True, sp1, _NO_MAP)
        if pr is not None:
            _seam_smooth(L, pr, self._pslots[lv], b, x, True)
        _i_lines(L, nx1, ny1, b, x, True, sp0)
        if pr is not None:
            _seam_smooth(L, pr, self._pslots[lv], b, x, True)
        return x


@njit(cache=True)
def _pad_copy(src, data, value, out, lattice_only):
    """out[q] = data[src[q]] where src[q] >= 0, else value x I3 (out (nq,3,3)); lattice_only:
    the blocks with src[q] < 0 are left as they are (written by an earlier call with the same
    value)."""
    for q in range(src.shape[0]):
        k = src[q]
        if k >= 0:
            for r in range(3):
                for c in range(3):
                    out[q, r, c] = data[k, r, c]
        elif not lattice_only:
            for r in range(3):
                for c in range(3):
                    out[q, r, c] = value if r == c else 0.0


@njit(cache=True)
def _fill_empty_diagonal(indptr, indices, data, value):
    """Rows of a BSR matrix whose blocks are all zero get value x I3 on their diagonal block
    (data (nb,3,3) edited in place; every row must hold its diagonal block). Returns how many."""
    n = indptr.shape[0] - 1
    cnt = 0
    for i in range(n):
        empty = True
        d = -1
        for q in range(indptr[i], indptr[i + 1]):
            if indices[q] == i:
                d = q
            for r in range(3):
                for c in range(3):
                    if data[q, r, c] != 0.0:
                        empty = False
        if empty and d >= 0:
            for r in range(3):
                data[d, r, r] = value
            cnt += 1
    return cnt


class _GridLayout:
    """What ``Multigrid.for_topology`` builds from a full-rectangle topology alone: the levels'
    shapes, transfers, spans and padding masks (none), and, once set up, the coarse patterns of
    its fine BSR pattern (``sym``: Multigrid._sym with copies of the fine indptr and indices)."""

    def __init__(self, topology, tuning):
        mg = Multigrid(topology, tuning)
        self.shapes, self.transfers, self.spans, self.pad = mg.shapes, mg.transfers, mg.spans, mg.pad
        self.sym = None


# the full-grid layouts of the last few topologies (_grid_layout), by id(topology)
_GRID_LAYOUTS: OrderedDict = OrderedDict()


def _grid_layout(topology, tuning: NewtonTuning = NewtonTuning()) -> _GridLayout:
    """The full-rectangle topology's _GridLayout, built on first use and kept while the topology
    lives; the LAYOUT_CACHE most recently used are kept."""
    # (the switches the layout reads are part of its key)
    key = (tuning.transpose_nodes, tuning.coarsest_nodes, tuning.galerkin_terms)
    return per_object(_GRID_LAYOUTS, topology, key, lambda: _GridLayout(topology, tuning), LAYOUT_CACHE)


class _PaddedLayout:
    """What a PaddedMultigrid builds from its topology alone (see its docstring): full (the
    rectangle's Topology), emb (n,), N, the rectangle multigrid's shapes, transfers, spans, padding
    masks and seam pairs, and, once known, the BSR pattern (``pattern``: (lattice indptr, lattice
    indices, (fptr, fidx, src))) and the coarse patterns of a set-up on it (``sym``, Multigrid._sym)."""

    def __init__(self, topology, seam_pairs, tuning):
        shapes = [topology.panel_shape(p) for p in range(topology.panel_count)]
        height = max(s[1] for s in shapes)
        # each panel starts on a column that is a multiple of tuning.panel_align (at least one empty
        # column before it): its first column then stays a grid node on the first coarse levels
        # instead of being interpolated from the previous panel's last column
        al = tuning.panel_align
        offs = np.cumsum([0] + [-(-(s[0] + 1) // al) * al for s in shapes])
        width = int(offs[-2]) + shapes[-1][0]
        self.full = Topology.rectangle(width - 1, height - 1)
        I = offs[topology.node_panel] + topology.node_ij[:, 0]
        self.emb = (I * height + topology.node_ij[:, 1]).astype(np.int64)
        self.N = width * height
        mg = Multigrid(self.full, tuning)
        if tuning.trim_padding:
            # the padding on every level: a coarse node all of whose children are padding
            pad = np.ones(self.N, bool)
            pad[self.emb] = False
            for lv, (nx1, ny1) in enumerate(mg.shapes):
                mg.pad[lv] = pad
                mg.spans[lv] = _trimmed_spans(pad, nx1, ny1)
                if lv < len(mg.transfers):
                    tr = mg.transfers[lv]
                    live = np.zeros(tr.nc, bool)
                    ch = np.repeat(np.arange(tr.nc), np.diff(tr.cptr))
                    np.logical_or.at(live, ch, (~pad[tr.cchild]) & (tr.cw != 0.0))
                    pad = ~live
        if seam_pairs is not None and len(seam_pairs) and tuning.pair_smoothing:
            mg.pairs = coarse_pairs(self.emb[np.asarray(seam_pairs, np.int64)], mg.transfers)
        self.shapes, self.transfers, self.spans, self.pad, self.pairs = mg.shapes, mg.transfers, mg.spans, mg.pad, mg.pairs
        self.pattern = None
        self.sym = None


# the layouts of the last few topologies (_padded_layout, objcache.per_object): (weakref to the
# topology, seam pairs' bytes and switches, layout) by id(topology)
_LAYOUTS: OrderedDict = OrderedDict()


LAYOUT_CACHE = 4


def _padded_layout(topology, seam_pairs=None, tuning: NewtonTuning = NewtonTuning()) -> _PaddedLayout:
    """The topology's _PaddedLayout, built on first use and kept while the topology lives (a
    Topology is not changed in place); the LAYOUT_CACHE most recently used are kept."""
    # (the switches the layout reads are part of its key)
    sp_key = (None if seam_pairs is None else np.asarray(seam_pairs, np.int64).tobytes(), tuning.trim_padding,
              tuning.pair_smoothing, tuning.panel_align, tuning.coarsest_nodes, tuning.transpose_nodes,
              tuning.galerkin_terms)
    return per_object(_LAYOUTS, topology, sp_key, lambda: _PaddedLayout(topology, seam_pairs, tuning), LAYOUT_CACHE)


class PaddedMultigrid:
    """The line-smoothed geometric multigrid for any lattice: its panels laid side by side (one
    empty column between two) on one rectangle, the rectangle's nodes that are not lattice nodes
    given an identity block, decoupled, and a zero projector (so no coarse space moves them).
    Cut panels and several panels sewn together keep the smoother's lines and the Galerkin
    coarse grids; the seams' stiff pairs, off-line blocks for the lines, are relaxed by their own
    6x6-block line solves along each seam (``_chain_gs``) before, between and after the line
    sweeps, on every level both nodes of a pair reach (:func:`coarse_pairs`). Same interface as :class:`Multigrid`; ``prepare`` takes the lattice's BSR pattern once.

    Shapes: the lattice's n nodes map to rows ``emb`` (n,) of the rectangle's N nodes; the
    embedding is increasing, so every row keeps its sorted block columns."""

    # setup copies the lattice's blocks into the rectangle's and keeps no reference to them
    copies_matrix = True

    def __init__(self, topology, seam_pairs=None, tuning: NewtonTuning = NewtonTuning()):
        """tuning: NewtonOptions.tuning; seam_pairs (m,2): the lattice's sewn node pairs (zero-length seam springs), relaxed
        jointly on every level where both nodes are grid nodes (:func:`coarse_pairs`). The
        layout (rectangle, embedding, levels, spans, pairs, BSR pattern) depends on the topology
        alone and is built once per topology (:func:`_padded_layout`)."""
        lay = _padded_layout(topology, seam_pairs, tuning)
        self._layout = lay
        self.tuning = tuning
        self.full, self.emb, self.N = lay.full, lay.emb, lay.N
        self.mg = Multigrid.from_levels(lay.shapes, lay.transfers, lay.spans, lay.pad, lay.pairs, tuning)
        self._pattern = None
        self._fdat = self._fpi = self._pad_value = None  # the rectangle's matrix, projectors, padding value

    def prepare(self, indptr, indices):
        """The rectangle's BSR pattern and, per block, the lattice block it copies (-1: identity);
        kept in the layout for the next multigrid on the same lattice pattern."""
        self._fdat = None  # (setup's kept rectangle follows the pattern)
        got = self._layout.pattern
        if got is not None and np.array_equal(got[0], indptr) and np.array_equal(got[1], indices):
            self._pattern = got[2]
            return
        n = indptr.shape[0] - 1
        inv = -np.ones(self.N, np.int64)
        inv[self.emb] = np.arange(n)
        counts = np.ones(self.N, np.int64)
        counts[self.emb] = np.diff(indptr)
        fptr = np.zeros(self.N + 1, np.int64)
        np.cumsum(counts, out=fptr[1:])
        fidx = np.empty(fptr[-1], np.int64)
        src = -np.ones(fptr[-1], np.int64)
        miss = np.nonzero(inv < 0)[0]
        fidx[fptr[miss]] = miss
        q = np.arange(indptr[-1])
        k = np.repeat(np.arange(n), np.diff(indptr))  # the lattice row of every block
        dest = fptr[self.emb[k]] + (q - indptr[k])
        fidx[dest] = self.emb[indices]
        src[dest] = q
        self._pattern = (fptr, fidx, src)
        self._layout.pattern = (indptr.copy(), indices.copy(), self._pattern)
        self._layout.sym = None

    def setup(self, indptr, indices, data, Pi):
        if self._pattern is None:
            self.prepare(indptr, indices)
        fptr, fidx, src = self._pattern
        scale = float(np.abs(np.einsum("kii->k", data)).mean() / 3) if data.shape[0] else 1.0
        # the padding's blocks are the identity, like a held node's (I - Pi with Pi = 0): the
        # Galerkin products drop exactly that part, so the padding adds nothing to a coarse node
        # (a scaled identity there would pin the coarse nodes next to it: seam edges, outlines).
        # The rectangle's matrix and projectors are kept from one set-up to the next (the
        # last hierarchy is not used after a new set-up): the padding is written once, and the
        # 33 MB of a 225^2 rectangle are not allocated (and page-faulted) again each time
        value = 1.0 if self.tuning.pad_identity else max(scale, 1e-300)
        keep = self._fdat is not None and self._pad_value == value
        if not keep:
            self._fdat = np.empty((fidx.shape[0], 3, 3))
            self._fpi = np.zeros((self.N, 3, 3))
            self._pad_value = value
        fdat, fpi = self._fdat, self._fpi
        _pad_copy(src, data, value, fdat, keep)
        fpi[self.emb] = Pi
        if self.mg._sym is None:
            self.mg._sym = self._layout.sym  # the coarse patterns of an earlier multigrid, if any
        self.mg.setup(fptr, fidx, fdat, fpi, pad_scale=max(scale, 1e-300) if self.tuning.pad_identity else None)
        self._layout.sym = self.mg._sym

    def vcycle(self, b):
        bf = np.zeros((self.N, 3))
        bf[self.emb] = b.reshape(-1, 3)
        return self.mg.vcycle(bf.ravel()).reshape(-1, 3)[self.emb].ravel()


# guards the lazily built per-level lists that the multigrids of one topology share
# (``Multigrid.setup``)
_SHARED_LOCK = threading.RLock()


class AlgebraicMultigrid:
    """PyAMG's smoothed aggregation on the projected BSR matrix, used as the CG preconditioner
    where the lattice is not one full rectangle (cut panels, several panels), so the line
    smoother's grid lines do not exist. Same interface as :class:`Multigrid`.

    References: Vanek, Mandel, Brezina, *Algebraic multigrid by smoothed aggregation for second
    and fourth order elliptic problems*, Computing 56 (1996); PyAMG (Bell, Olson, Schroder).
    Limitations: set-up costs more than the geometric multigrid's Galerkin products on a grid."""

    # PyAMG builds its own CSR copy: the Newton level need not keep the matrix for it
    copies_matrix = True

    def __init__(self):
        self._M = None

    def setup(self, indptr, indices, data, Pi):
        import pyamg

        n3 = 3 * (indptr.shape[0] - 1)
        A = sp.bsr_matrix((data, indices, indptr), shape=(n3, n3)).tocsr()
        ml = pyamg.smoothed_aggregation_solver(A, symmetry="symmetric", max_coarse=300,
                                               strength=("symmetric", {"theta": 0.0}))
        self._M = ml.aspreconditioner(cycle="V")

    def vcycle(self, b):
        return self._M @ b


# the coarsest grid's diagonal shifts (relative to its largest diagonal entry) tried in turn
COARSE_SHIFTS = (1e-12, 1e-8, 1e-4)


class _DiagonalSolve:
    """A coarsest-grid solve by the inverse of the diagonal (|d|, its zeros by ``big``): the
    preconditioner's last resort when no shifted LU exists (CG still solves the true system)."""

    def __init__(self, d, big):
        a = np.abs(d)
        self.inv = 1.0 / np.where(a > 0.0, a, big)

    def solve(self, b):
        return self.inv * b


def _coarse_solver(Alast, fix, scale):
    """The coarsest grid's solver (``.solve(b)``): the sparse LU of Alast (CSC) with ``fix`` (its
    zero diagonal entries' stand-ins) plus a small shift added to the diagonal. A factorisation
    scipy finds exactly singular is tried again with the larger shifts of ``COARSE_SHIFTS``, then
    the diagonal stands in: a preconditioner only needs to be positive definite, and the V-cycle
    must never stop the run."""
    s = max(scale, 1e-300)
    for shift in COARSE_SHIFTS:
        try:
            return sla.splu((Alast + sp.diags(fix + shift * s)).tocsc(), permc_spec="MMD_AT_PLUS_A",
                            options=dict(SymmetricMode=True), diag_pivot_thresh=1e-3)
        except RuntimeError:
            continue
    return _DiagonalSolve(Alast.diagonal() + fix, max(scale, 1.0))
