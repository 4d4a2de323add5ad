"""The line smoother's i lines swept on the renumbered rows (``linalg._Transposed``) give the
same iterate, bit for bit, as the sweep over the original rows; the multigrid uses them on the
levels of at least ``NewtonTuning.transpose_nodes`` nodes and its V-cycle is unchanged."""

import numpy as np
import pytest

from clothsim.solvers.newton import linalg as L
from clothsim.solvers.tuning import NewtonTuning
from clothsim.topology import Topology


def _grid_system(nx1, ny1, seed, nine_point=False):
    """A random symmetric BSR matrix with 3x3 blocks on an nx1 x ny1 grid (node k = i ny1 + j),
    diagonally dominant; the 5-point pattern, or 9-point (as a Galerkin coarse level's)."""
    rng = np.random.default_rng(seed)
    n = nx1 * ny1
    offs = [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)]
    if nine_point:
        offs += [(-1, -1), (-1, 1), (1, -1), (1, 1)]
    rows = [[] for _ in range(n)]
    blocks = {}
    for k in range(n):
        i, j = divmod(k, ny1)
        for di, dj in offs:
            a, c = i + di, j + dj
            if 0 <= a < nx1 and 0 <= c < ny1:
                m = a * ny1 + c
                rows[k].append(m)
                if (m, k) in blocks:
                    blocks[(k, m)] = blocks[(m, k)].T
                elif m != k:
                    blocks[(k, m)] = -rng.uniform(0.0, 1.0, (3, 3))
    for k in range(n):
        off = sum(np.abs(blocks[(k, m)]).sum(axis=1) for m in rows[k] if m != k)
        B = rng.uniform(-0.1, 0.1, (3, 3))
        blocks[(k, k)] = np.diag(off + 1.0) + 0.5 * (B + B.T)
    indptr = np.zeros(n + 1, np.int64)
    indices, data = [], []
    for k in range(n):
        cols = sorted(rows[k])
        indptr[k + 1] = indptr[k] + len(cols)
        indices += cols
        data += [blocks[(k, m)] for m in cols]
    return indptr, np.array(indices, np.int64), np.ascontiguousarray(np.array(data))


@pytest.mark.parametrize("nine_point", [False, True])
@pytest.mark.parametrize("reverse", [False, True])
def test_renumbered_i_lines_equal_the_plain_sweep(nine_point, reverse):
    nx1, ny1 = 9, 7
    indptr, indices, data = _grid_system(nx1, ny1, 5, nine_point)
    ds, ps, ns = L._line_slots(indptr, indices, nx1, ny1)
    T = L._Transposed(indptr, indices, nx1, ny1, ds, ps, ns)
    tdata = np.empty_like(data)
    L._gather_blocks(data, T.gather, tdata)
    rng = np.random.default_rng(1)
    b = rng.normal(size=3 * nx1 * ny1)
    pad = np.zeros(nx1 * ny1, bool)
    pad[[0, 1, ny1, 2 * ny1 - 1, nx1 * ny1 - 1]] = True  # lines trimmed at their ends
    for spans in (L._full_spans(nx1, ny1), L._trimmed_spans(pad, nx1, ny1)):
        x0 = rng.normal(size=b.size)
        plain, renum = x0.copy(), x0.copy()
        L._line_gs(indptr, indices, data, nx1, ny1, ds, ps, ns, b, plain, 0, reverse, spans[0], L._NO_MAP)
        L._line_gs(T.indptr, T.indices, tdata, ny1, nx1, T.ds, T.ps, T.ns, b, renum, 1, reverse, spans[0], T.node)
        assert np.array_equal(plain, renum)
        assert not np.array_equal(plain, x0)
    # the i-line sweep is what the renumbering changes: a j-line sweep on it differs
    other = x0.copy()
    L._line_gs(indptr, indices, data, nx1, ny1, ds, ps, ns, b, other, 1, reverse, spans[1], L._NO_MAP)
    assert not np.array_equal(other, renum)


def test_multigrid_uses_renumbered_lines_with_the_same_vcycle():
    nx1, ny1 = 33, 29
    indptr, indices, data = _grid_system(nx1, ny1, 2)
    Pi = np.tile(np.eye(3), (nx1 * ny1, 1, 1))
    b = np.random.default_rng(3).normal(size=3 * nx1 * ny1)
    out = []
    for limit in (10 ** 9, 100):
        mg = L.Multigrid(Topology.rectangle(nx1 - 1, ny1 - 1), NewtonTuning(transpose_nodes=limit))
        mg.setup(indptr, indices, data, Pi)
        used = [lv.T is not None for lv in mg.levels[:-1]]
        assert used[0] == (limit == 100)
        out.append(mg.vcycle(b))
        # a second set-up on new values refills the kept buffers
        mg.setup(indptr, indices, 2.0 * data, Pi)
        out.append(mg.vcycle(b))
    assert np.array_equal(out[0], out[2]) and np.array_equal(out[1], out[3])
    assert np.allclose(out[1], 0.5 * out[0])


def test_multigrids_of_one_topology_share_their_patterns_not_their_values():
    """``Multigrid.for_topology``: a second multigrid of the same grid (a Newton level of the next
    solve of the same model) takes the first one's levels and coarse patterns when its fine
    pattern is equal (new arrays with the same content), keeps its own values, and gives the
    V-cycle of a multigrid built afresh, bit for bit."""
    tu = NewtonTuning(transpose_nodes=100)
    nx1, ny1 = 33, 29
    indptr, indices, data = _grid_system(nx1, ny1, 2)
    topo = Topology.rectangle(nx1 - 1, ny1 - 1)
    Pi = np.tile(np.eye(3), (nx1 * ny1, 1, 1))
    b = np.random.default_rng(3).normal(size=3 * nx1 * ny1)
    fresh = L.Multigrid(topo, tu)
    fresh.setup(indptr, indices, 3.0 * data, Pi)
    first = L.Multigrid.for_topology(topo, tuning=tu)
    first.setup(indptr, indices, data, Pi)
    second = L.Multigrid.for_topology(topo, tuning=tu)
    assert all(a is b for a, b in zip(second.transfers, first.transfers))
    second.setup(indptr.copy(), indices.copy(), 3.0 * data, Pi)
    assert second._sym[2] is first._sym[2] and second._sym[5] is first._sym[5]   # patterns shared
    assert second._sym[6] is first._sym[6] and len(first._sym[6]) == len(first.transfers)  # Galerkin terms
    assert second.levels[1].data is not first.levels[1].data                     # values not
    assert np.array_equal(second.vcycle(b), fresh.vcycle(b))
    assert np.allclose(first.vcycle(b), 3.0 * second.vcycle(b))
    # a different fine pattern (one coupling dropped) gets patterns of its own
    ip2, ix2, d2 = _grid_system(nx1, ny1, 2, nine_point=True)
    third = L.Multigrid.for_topology(topo, tuning=tu)
    third.setup(ip2, ix2, d2, Pi)
    assert third._sym[2] is not first._sym[2]
    ref = L.Multigrid(topo, tu)
    ref.setup(ip2, ix2, d2, Pi)
    assert np.array_equal(third.vcycle(b), ref.vcycle(b))


def _projectors(n, seed):
    """Random node projectors (n, 3, 3) and their kinds (n,): 0 identity (free), 1 zero (held),
    2 a plane's (I - v v^T, a contact node)."""
    rng = np.random.default_rng(seed)
    Pi = np.tile(np.eye(3), (n, 1, 1))
    kinds = rng.integers(0, 3, n)
    Pi[kinds == 1] = 0.0
    for k in np.nonzero(kinds == 2)[0]:
        v = rng.normal(size=3)
        v /= np.linalg.norm(v)
        Pi[k] = np.eye(3) - np.outer(v, v)
    return Pi, kinds


def test_project_system_fast_blocks_are_the_products():
    """_project_system copies the blocks between two identity projectors and zeroes those next to
    a zero one: the same numbers as Pi K Pi + mu Pi + (I - Pi) computed in full."""
    nx1, ny1 = 7, 6
    indptr, indices, data = _grid_system(nx1, ny1, 4, nine_point=True)
    n = nx1 * ny1
    Pi, kinds = _projectors(n, 0)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    between = np.nonzero((kinds[rows] == 0) & (kinds[indices] == 0) & (rows != indices))[0]
    qz, qi = between[0], between[1]
    data[qz, 0, 1] = -0.0     # a copied block: -0.0 + 0.0 is +0.0, as the full product gives
    data[qi, 1, 1] = np.inf   # not finite: the full product (0 x inf is NaN off its row)
    diag = np.array([L._find_block(indptr, indices, k, k) for k in range(n)], np.int64)
    out = np.empty_like(data)
    mu = 0.3
    L._project_system(indptr, indices, data, diag, Pi, mu, out)
    with np.errstate(invalid="ignore"):
        ref = np.einsum("qab,qbc,qcd->qad", Pi[rows], data, Pi[indices])
    ref[diag] += mu * Pi + (np.eye(3) - Pi)
    assert out[qz, 0, 1] == 0.0 and not np.signbit(out[qz, 0, 1])
    assert np.array_equal(np.isnan(out[qi]), np.isnan(ref[qi])) and np.isnan(out[qi]).any()
    assert out[qi, 1, 1] == np.inf
    fin = np.ones(len(out), bool)
    fin[qi] = False
    np.testing.assert_allclose(out[fin], ref[fin], rtol=1e-13, atol=1e-13 * np.abs(ref[fin]).max())
    both = (kinds[rows] == 0) & (kinds[indices] == 0) & (rows != indices)
    both[qi] = False
    assert both.any() and np.array_equal(out[both], data[both] + 0.0)
    zero = (kinds[indices] == 1) & (rows != indices)
    assert zero.any() and not out[zero].any() and not np.signbit(out[zero]).any()


@pytest.mark.parametrize("use_pi", [False, True])
def test_galerkin_sum_equals_galerkin_values(use_pi):
    """The Galerkin product from its terms grouped by coarse block (``_galerkin_terms``,
    ``_galerkin_sum``) equals the direct product (``_galerkin_values``) bit for bit, on every
    level of a grid with general, zero and identity projectors and non-finite and -0.0 entries."""
    nx1, ny1 = 17, 13
    topo = Topology.rectangle(nx1 - 1, ny1 - 1)
    mg = L.Multigrid(topo)
    indptr, indices, data = _grid_system(nx1, ny1, 7, nine_point=True)
    n = nx1 * ny1
    Pi, _ = _projectors(n, 1)
    data[5, 0, 0] = -0.0
    data[9, 2, 1] = np.inf
    data[14, 1, 0] = np.nan
    data[20, 0, 2] = 1e308
    fip, fix, fdat = indptr, indices, data
    for lv, tr in enumerate(mg.transfers):
        cip, cidx = L._galerkin_pattern(fip, fix, tr.pidx, tr.cptr, tr.cchild, tr.nc)
        first = use_pi and lv == 0
        with np.errstate(all="ignore"):
            direct = L._galerkin_values(fip, fix, fdat, tr.pidx, tr.pw, tr.cptr, tr.cchild, tr.cw, tr.nc, Pi,
                                        first, cip, cidx)
            terms = L._galerkin_terms(fip, fix, tr.pidx, tr.pw, tr.cptr, tr.cchild, tr.cw, tr.nc, cip, cidx)
            summed = L._galerkin_sum(fdat, Pi, first, *terms)
        assert direct.shape == summed.shape
        assert np.array_equal(direct.view(np.int64), summed.view(np.int64)), lv  # the same bits
        if lv == 0:
            assert np.isnan(direct).any() and np.isfinite(direct).any()
        fip, fix, fdat = cip, cidx, np.nan_to_num(direct)
