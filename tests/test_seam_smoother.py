"""The seam-aware smoother of the padded multigrid (sewn lattices): the 6x6-block line
Gauss-Seidel along seam chains, the pairs carried to the coarse levels, PCG with it on a small
sewn garment, and the grid sequencing's fringe relaxation leaving seams closed."""

import numpy as np
import scipy.sparse as sp

from clothsim.bench import Case, _load, four_panel_cap_overrides
from clothsim.grid import FAMILY_SEAM
from clothsim.solvers.newton.iteration import NewtonLevel
from clothsim.solvers.newton.linalg import (PaddedMultigrid, _assemble, _bsr_matvec, _bsr_pattern, _chain_gs,
                                             _fill_empty_diagonal, _pcg, _project_system, coarse_pairs, seam_chains)
from clothsim.solvers.newton.sequencing import prolong_state, sequencing_chain
from clothsim.solvers.tuning import NewtonTuning


def _chain_system(m, rng):
    """A random SPD BSR system on 2m nodes whose couplings stay inside the chain's window: pair
    t = (t, m + t), pair t coupled to pairs t-1 and t+1 only."""
    n = 2 * m
    pairs = np.stack([np.arange(m), m + np.arange(m)], axis=1).astype(np.int64)
    links = [(t, m + t) for t in range(m)]
    for t in range(m - 1):
        links += [(t, t + 1), (m + t, m + t + 1), (t, m + t + 1)]
    dense = np.zeros((3 * n, 3 * n))
    for a, b in links:
        B = rng.normal(size=(3, 3))
        dense[3 * a:3 * a + 3, 3 * b:3 * b + 3] = B
        dense[3 * b:3 * b + 3, 3 * a:3 * a + 3] = B.T
    dense = dense + dense.T + np.diag(np.abs(dense).sum(axis=1) + 1.0)  # symmetric, diagonally dominant
    indptr, indices, _, _ = _bsr_pattern(n, np.array(links, np.int64))
    data = np.zeros((indices.shape[0], 3, 3))
    for i in range(n):
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            data[q] = dense[3 * i:3 * i + 3, 3 * j:3 * j + 3]
    return indptr, indices, data, pairs, dense


def test_one_chain_sweep_solves_a_system_that_lives_on_the_chain():
    rng = np.random.default_rng(3)
    indptr, indices, data, pairs, dense = _chain_system(7, rng)
    starts = seam_chains(indptr, indices, pairs)
    assert starts.tolist() == [0, 7]  # consecutive pairs are coupled: one chain
    b = rng.normal(size=dense.shape[0])
    x = np.zeros_like(b)
    _chain_gs(indptr, indices, data, pairs, starts, b, x, False)
    assert np.abs(x - np.linalg.solve(dense, b)).max() < 1e-10
    y = np.zeros_like(b)
    _chain_gs(indptr, indices, data, pairs, starts, b, y, True)
    assert np.abs(y - x).max() < 1e-10


def test_chains_split_where_pairs_are_not_coupled():
    rng = np.random.default_rng(4)
    indptr, indices, data, pairs, _ = _chain_system(4, rng)
    # the pairs of two chains, the second reversed: pair 2 (node 0 side) is not coupled to pair 1
    pr = np.concatenate([pairs[:2], pairs[2:][::-1]])
    assert seam_chains(indptr, indices, pr).tolist() == [0, 2, 4]


class _Tr:
    """A stand-in transfer: fine nodes 0..5, coarse nodes 0..2; even fine nodes are injected."""
    pidx = np.array([[0, -1], [0, 1], [1, -1], [1, 2], [2, -1], [2, -1]])
    pw = np.array([[1.0, 0], [0.5, 0.5], [1.0, 0], [0.5, 0.5], [1.0, 0], [0.7, 0]])


def test_coarse_pairs_keep_pairs_of_injected_nodes():
    out = coarse_pairs(np.array([[0, 2], [1, 4], [2, 4], [0, 5]]), [_Tr()])
    assert out[0].tolist() == [[0, 2], [1, 4], [2, 4], [0, 5]]
    assert out[1].tolist() == [[0, 1], [1, 2]]  # (1, 4): 1 interpolated; (0, 5): weight 0.7


def _small_garment(d=16):
    case = Case("fp", "configs/garments/circle_cap.yaml", four_panel_cap_overrides(d), ("newton",))
    model, state, _ = _load(case, "newton", 1e-7, 60.0)
    return model, state


def test_pcg_with_the_seam_smoother_solves_a_sewn_system():
    model, state = _small_garment(16)
    lv = NewtonLevel(model, use_multigrid=True)
    assert isinstance(lv.mg, PaddedMultigrid) and lv.mg.mg.pairs is not None
    assert len(lv.mg.mg.pairs[0]) == 4 * 17
    # the Hessian at the flat placed sheet stretched 5 % (every spring in tension), the seams'
    # penalty blocks, the held nodes projected out
    free = _projected_system(model, lv)
    lv.mg.setup(lv.indptr, lv.indices, lv.A.copy(), lv.Pi)
    rng = np.random.default_rng(0)
    rhs = rng.normal(size=3 * model.node_count) * np.repeat(free, 3)

    def mv(v, out):
        _bsr_matvec(lv.indptr, lv.indices, lv.A, v, out)

    x, it, rel = _pcg(mv, lv.mg.vcycle, rhs, 1e-8, 200)
    n3 = 3 * model.node_count
    A = sp.bsr_matrix((lv.A, lv.indices, lv.indptr), shape=(n3, n3)).tocsr()
    assert rel <= 1e-8
    assert np.abs(A @ x - rhs).max() <= 1e-7 * np.abs(rhs).max()
    # the seam chains are what makes it converge fast: without them PCG needs several times as many
    lv.mg.mg.pairs = None
    lv.mg.setup(lv.indptr, lv.indices, lv.A.copy(), lv.Pi)
    _, it_lines, _ = _pcg(mv, lv.mg.vcycle, rhs, 1e-8, 400)
    assert it_lines > 2 * it


def _projected_system(model, lv):
    """The Hessian at the flat placed sheet stretched 5 %, the seams' penalty blocks, the held
    nodes projected out, into lv.A; returns the free-node mask."""
    from clothsim.kernels import seam_assemble

    pos = model.rest_positions * 1.05
    _assemble(pos, *lv.sargs, lv.kink, lv.slot, lv.K)
    if model.seam_count:
        seam_assemble(*model.seam_args(), lv.seam_slot, lv.K)
    free = ~model.fixed_axes.any(axis=1)
    lv.Pi[:] = 0.0
    lv.Pi[free] = np.eye(3)
    dmean = np.einsum("nii->n", lv.K[lv.diag])[free].mean() / 3
    _project_system(lv.indptr, lv.indices, lv.K, lv.diag, lv.Pi, 1e-8 * dmean, lv.A)
    return free


def _transfer_matrix(tr):
    n = tr.pidx.shape[0]
    rows = np.repeat(np.arange(n), tr.pidx.shape[1]).reshape(n, -1)
    keep = tr.pidx >= 0
    return sp.csr_matrix((tr.pw[keep], (rows[keep], tr.pidx[keep])), shape=(n, tr.nc))


def test_fill_empty_diagonal_sets_only_all_zero_rows():
    indptr = np.array([0, 2, 4, 5])
    indices = np.array([0, 1, 0, 1, 2])
    data = np.zeros((5, 3, 3))
    data[0] = np.eye(3)
    data[1, 0, 2] = 0.5  # row 0: a diagonal and an off-diagonal block
    data[2, 2, 0] = 0.5  # row 1 holds a non-zero off-diagonal block: not empty
    assert _fill_empty_diagonal(indptr, indices, data, 7.0) == 1
    assert np.array_equal(data[4], 7.0 * np.eye(3))
    assert np.array_equal(data[3], np.zeros((3, 3))) and np.array_equal(data[0], np.eye(3))


def test_padded_coarse_operators_are_the_lattice_galerkin_products():
    """The padded rectangle's coarse operators are (E P)^T (Pi A Pi) (E P) for the lattice alone
    (E: the lattice's rows of the rectangle, P: the rectangle's bilinear prolongation), level by
    level: the padding adds nothing to the coarse nodes next to it (the seams' edges), and a
    coarse node without a lattice child gets a decoupled scaled identity."""
    model, state = _small_garment(16)
    # three coarse levels on the small garment
    lv = NewtonLevel(model, use_multigrid=True, tuning=NewtonTuning(coarsest_nodes=40))
    pm = lv.mg
    assert isinstance(pm, PaddedMultigrid) and len(pm.mg.transfers) >= 3
    free = _projected_system(model, lv)
    pm.setup(lv.indptr, lv.indices, lv.A.copy(), lv.Pi)
    n, n3 = model.node_count, 3 * model.node_count
    A = sp.bsr_matrix((lv.A, lv.indices, lv.indptr), shape=(n3, n3)).tocsr()
    # Pi A Pi = A - (I - Pi) for the projected system
    PAP = (A - sp.diags(np.repeat(~free, 3).astype(float))).tocsr()
    E = sp.csr_matrix((np.ones(n), (np.arange(n), pm.emb)), shape=(n, pm.N))
    # the projector on the fine level (Pi P), plain P below
    R = sp.kron(sp.diags(free.astype(float)) @ E, sp.identity(3)).tocsr()
    cur = R.T @ PAP @ R
    for lvl, tr in enumerate(pm.mg.transfers):
        P3 = sp.kron(_transfer_matrix(tr), sp.identity(3)).tocsr()
        cur = (P3.T @ cur @ P3).tocsr()
        C = pm.mg.levels[lvl + 1]
        got = sp.bsr_matrix((C.data, C.indices, C.indptr), shape=(3 * C.n, 3 * C.n)).toarray()
        want = cur.toarray()
        empty = ~np.abs(want).reshape(C.n, 3, -1).any(axis=(1, 2))
        scale = np.abs(got).max()
        for c in np.nonzero(empty)[0]:
            want[3 * c:3 * c + 3, 3 * c:3 * c + 3] = got[3 * c, 3 * c] * np.eye(3)
            assert got[3 * c, 3 * c] > 0
        assert np.abs(got - want).max() <= 1e-12 * scale


def test_a_second_setup_on_the_same_pattern_equals_a_fresh_one():
    """Multigrid.setup keeps the coarse patterns and line slots of its last set-up while the fine
    pattern is the same arrays: a set-up on new values then builds, bit for bit, the hierarchy a
    new multigrid builds (values, patterns, line slots, the coarsest LU's solution)."""
    model, state = _small_garment(16)
    lv = NewtonLevel(model, use_multigrid=True)
    _projected_system(model, lv)
    first = lv.A.copy()
    reused = lv.mg
    reused.setup(lv.indptr, lv.indices, first, lv.Pi)
    second = first * 1.3 + 0.01 * np.eye(3)  # other values on the same pattern
    reused.setup(lv.indptr, lv.indices, second, lv.Pi)
    assert reused.mg._sym is not None and len(reused.mg._sym[2]) == len(reused.mg.transfers)
    fresh = NewtonLevel(model, use_multigrid=True).mg
    fresh.setup(lv.indptr, lv.indices, second.copy(), lv.Pi)
    for a, b in zip(reused.mg.levels, fresh.mg.levels):
        assert np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
        assert np.array_equal(a.data, b.data)
        if hasattr(a, "ds"):
            assert np.array_equal(a.ds, b.ds) and np.array_equal(a.ps, b.ps) and np.array_equal(a.ns, b.ns)
    b = np.random.default_rng(0).normal(size=3 * model.node_count)
    assert np.array_equal(reused.vcycle(b), fresh.vcycle(b))


def test_padded_multigrids_on_one_topology_share_its_layout_and_set_up_alike():
    """The padded rectangle's layout (embedding, levels, spans, seam pairs, BSR pattern, coarse
    patterns) is built once per topology: a second multigrid on it shares it, other seam pairs
    get their own, and a set-up on the shared layout (after one on other values, whose rectangle
    buffers it reuses) equals, bit for bit, one built afresh."""
    from clothsim.solvers.newton import linalg

    model, state = _small_garment(16)
    lv = NewtonLevel(model, use_multigrid=True)
    _projected_system(model, lv)
    pairs = lv.mg._layout.pairs
    assert pairs is not None
    lv.mg.setup(lv.indptr, lv.indices, lv.A.copy(), lv.Pi)
    again = NewtonLevel(model, use_multigrid=True).mg
    assert again._layout is lv.mg._layout and again.mg is not lv.mg.mg
    assert PaddedMultigrid(model.topology, None)._layout is not lv.mg._layout  # no seam pairs
    # a first set-up on other values (its rectangle's buffers are kept for the second one)
    rng = np.random.default_rng(2)
    other = lv.A.copy() * rng.uniform(0.5, 2.0, size=(lv.A.shape[0], 1, 1))
    other_pi = lv.Pi.copy()
    other_pi[::3] = 0.0
    again.setup(lv.indptr, lv.indices, other, other_pi)
    kept = again._fdat
    again.setup(lv.indptr, lv.indices, lv.A.copy(), lv.Pi)
    assert again._fdat is kept
    linalg._LAYOUTS.clear()
    fresh = NewtonLevel(model, use_multigrid=True).mg
    assert fresh._layout is not lv.mg._layout
    fresh.setup(lv.indptr, lv.indices, lv.A.copy(), lv.Pi)
    for a, b in zip(again.mg.levels, fresh.mg.levels):
        assert np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
        assert np.array_equal(a.data, b.data)
    b = np.random.default_rng(1).normal(size=3 * model.node_count)
    assert np.array_equal(again.vcycle(b), fresh.vcycle(b))


def test_padded_layout_starts_panels_on_aligned_columns():
    """Four 17 x 17 panels: each starts on a column that is a multiple of NewtonTuning.panel_align (4: columns
    0, 20, 40, 60), the rectangle ends at the last panel's last column (77 x 17); a node (i, j) of
    panel p is row (start_p + i) * 17 + j."""
    assert NewtonTuning().panel_align == 4
    model, _ = _small_garment(16)
    top = model.topology
    pm = PaddedMultigrid(top)
    assert pm.full.grid_shape == (77, 17) and pm.N == 77 * 17
    want = (20 * top.node_panel + top.node_ij[:, 0]) * 17 + top.node_ij[:, 1]
    assert np.array_equal(pm.emb, want)


def test_sequencing_keeps_the_seams_closed():
    from clothsim.grid import State

    model, state = _small_garment(24)
    chain = sequencing_chain(model)
    assert len(chain) == 2
    coarse, sub = chain[0]  # sub: the fine nodes the coarse grid keeps
    # a coarse state with every seam closed: the initial state's coarse nodes, each group of
    # sewn nodes moved to its mean
    from scipy.sparse.csgraph import connected_components

    pos = np.ascontiguousarray(state.positions[sub])
    ab = coarse.spring_nodes[coarse.spring_family == FAMILY_SEAM]
    nc = coarse.node_count
    _, comp = connected_components(sp.coo_matrix((np.ones(len(ab)), (ab[:, 0], ab[:, 1])), shape=(nc, nc)))
    cnt = np.bincount(comp)
    for a in range(3):
        pos[:, a] = (np.bincount(comp, pos[:, a]) / cnt)[comp]
    cs = State(pos, np.zeros(nc, bool), 0)
    assert len(ab) and np.abs(cs.positions[ab[:, 0]] - cs.positions[ab[:, 1]]).max() < 1e-12
    fine = state.copy()
    assert prolong_state(coarse, cs, model, fine)
    ab = model.spring_nodes[model.spring_family == FAMILY_SEAM]
    free = ~model.fixed_axes.any(axis=1)
    keep = free[ab[:, 0]] & free[ab[:, 1]]
    gap = np.linalg.norm(fine.positions[ab[keep, 0]] - fine.positions[ab[keep, 1]], axis=1)
    assert keep.sum() > 50 and gap.max() < 1e-12
