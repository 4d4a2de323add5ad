"""The multigrid's smoothers: block line Gauss-Seidel along the grid's i and j lines (on rows
renumbered so the i lines are contiguous, ``_Transposed``), and the seam chains' 6x6 block
sweeps.

Shapes: vectors are flat (3N,) in node-major order; blocks N/m, right-hand sides N,
unknowns m."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


from .assembly import _find_block


@njit(cache=True)
def _line_slots(indptr, indices, nx1, ny1):
    """Block slots used by the line smoother: (diag (n,), prev (n,2), next (n,2)) where prev[k, d]
    is the slot of the block coupling k to the previous node of its line along direction d
    (0: i, 1: j), -1 if none."""
    n = nx1 * ny1
    diag = -np.ones(n, np.int64)
    prv = -np.ones((n, 2), np.int64)
    nxt = -np.ones((n, 2), np.int64)
    for k in range(n):
        i = k // ny1
        j = k - i * ny1
        for q in range(indptr[k], indptr[k + 1]):
            c = indices[q]
            if c == k:
                diag[k] = q
            elif c == k - ny1 and i > 0:
                prv[k, 0] = q
            elif c == k + ny1 and i < nx1 - 1:
                nxt[k, 0] = q
            elif c == k - 1 and j > 0:
                prv[k, 1] = q
            elif c == k + 1 and j < ny1 - 1:
                nxt[k, 1] = q
    return diag, prv, nxt


@njit(cache=True)
def _inv3s(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    """Inverse of a 3x3 matrix as 9 scalars (row major); a nearly singular matrix is shifted
    (by a small multiple of its trace) until it is invertible, a zero one gives zero."""
    tr = abs(a00) + abs(a11) + abs(a22)
    shift = 0.0
    for attempt in range(4):
        b00 = a00 + shift
        b11 = a11 + shift
        b22 = a22 + shift
        c00 = b11 * b22 - a12 * a21
        c01 = a12 * a20 - a10 * b22
        c02 = a10 * a21 - b11 * a20
        det = b00 * c00 + a01 * c01 + a02 * c02
        sc = max(tr, 1e-300)
        if abs(det) > 1e-12 * sc * sc * sc and math.isfinite(det):
            inv = 1.0 / det
            return (c00 * inv, (a02 * a21 - a01 * b22) * inv, (a01 * a12 - a02 * b11) * inv,
                    c01 * inv, (b00 * b22 - a02 * a20) * inv, (a02 * a10 - b00 * a12) * inv,
                    c02 * inv, (a01 * a20 - b00 * a21) * inv, (b00 * b11 - a01 * a10) * inv)
        shift = (1e-8 if shift == 0.0 else shift * 1e3) * max(tr, 1e-300)
    return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True)
def _line_gs(indptr, indices, data, nx1, ny1, dslot, pslot, nslot, b, xv, direction, reverse, span, node):
    """Block line Gauss-Seidel: every grid line along ``direction`` (0: i varies at fixed j, the
    warp lines; 1: j varies at fixed i) is solved exactly as a 3x3-block tridiagonal system
    (block Thomas algorithm) with the other couplings taken from the current iterate. Lines
    are visited in reverse when ``reverse`` (the adjoint sweep, so that the V-cycle stays
    symmetric for CG).

    node (n,) int64: the unknown (of b and xv) that each matrix row is, or empty when row k is
    unknown k. The block columns (indices) always name unknowns. With the rows of the matrix
    renumbered line by line (``_Transposed``), the i lines are swept as j lines of the renumbered
    matrix: the same arithmetic in the same order, on blocks read contiguously instead of ny1
    rows apart.

    Why lines: the stiffness of a stretched membrane is anisotropic per component (axial spring
    stiffness along a yarn, only the transverse T/l across it), and point smoothers degrade
    with that ratio; exact line solves make the smoothing robust to it."""
    nlines = ny1 if direction == 0 else nx1
    length = nx1 if direction == 0 else ny1
    stride = ny1 if direction == 0 else 1
    Cm = np.empty((length, 9))
    rr = np.empty((length, 3))
    mapped = node.shape[0] > 0
    for ll in range(nlines):
        line = nlines - 1 - ll if reverse else ll
        first = line if direction == 0 else line * ny1
        t0 = span[line, 0]
        t1 = span[line, 1]
        if t1 <= t0:
            continue
        # right-hand sides with the off-line couplings moved over
        for t in range(t0, t1):
            k = first + t * stride
            qp = pslot[k, direction]
            qn = nslot[k, direction]
            qd = dslot[k]
            kv = node[k] if mapped else k
            r0 = b[3 * kv]
            r1 = b[3 * kv + 1]
            r2 = b[3 * kv + 2]
            for q in range(indptr[k], indptr[k + 1]):
                if q == qd or q == qp or q == qn:
                    continue
                j = indices[q]
                x0 = xv[3 * j]
                x1 = xv[3 * j + 1]
                x2 = xv[3 * j + 2]
                r0 -= data[q, 0, 0] * x0 + data[q, 0, 1] * x1 + data[q, 0, 2] * x2
                r1 -= data[q, 1, 0] * x0 + data[q, 1, 1] * x1 + data[q, 1, 2] * x2
                r2 -= data[q, 2, 0] * x0 + data[q, 2, 1] * x1 + data[q, 2, 2] * x2
            rr[t, 0] = r0
            rr[t, 1] = r1
            rr[t, 2] = r2
        # block Thomas: D'_t = D_t - L_t C_{t-1}, r'_t = D'^{-1}(r_t - L_t r'_{t-1}), C_t = D'^{-1} U_t
        for t in range(t0, t1):
            k = first + t * stride
            qd = dslot[k]
            d00 = data[qd, 0, 0]; d01 = data[qd, 0, 1]; d02 = data[qd, 0, 2]
            d10 = data[qd, 1, 0]; d11 = data[qd, 1, 1]; d12 = data[qd, 1, 2]
            d20 = data[qd, 2, 0]; d21 = data[qd, 2, 1]; d22 = data[qd, 2, 2]
            r0 = rr[t, 0]
            r1 = rr[t, 1]
            r2 = rr[t, 2]
            ql = pslot[k, direction]
            if t > t0 and ql >= 0:
                C = Cm[t - 1]
                l00 = data[ql, 0, 0]; l01 = data[ql, 0, 1]; l02 = data[ql, 0, 2]
                l10 = data[ql, 1, 0]; l11 = data[ql, 1, 1]; l12 = data[ql, 1, 2]
                l20 = data[ql, 2, 0]; l21 = data[ql, 2, 1]; l22 = data[ql, 2, 2]
                d00 -= l00 * C[0] + l01 * C[3] + l02 * C[6]
                d01 -= l00 * C[1] + l01 * C[4] + l02 * C[7]
                d02 -= l00 * C[2] + l01 * C[5] + l02 * C[8]
                d10 -= l10 * C[0] + l11 * C[3] + l12 * C[6]
                d11 -= l10 * C[1] + l11 * C[4] + l12 * C[7]
                d12 -= l10 * C[2] + l11 * C[5] + l12 * C[8]
                d20 -= l20 * C[0] + l21 * C[3] + l22 * C[6]
                d21 -= l20 * C[1] + l21 * C[4] + l22 * C[7]
                d22 -= l20 * C[2] + l21 * C[5] + l22 * C[8]
                p0 = rr[t - 1, 0]
                p1 = rr[t - 1, 1]
                p2 = rr[t - 1, 2]
                r0 -= l00 * p0 + l01 * p1 + l02 * p2
                r1 -= l10 * p0 + l11 * p1 + l12 * p2
                r2 -= l20 * p0 + l21 * p1 + l22 * p2
            i00, i01, i02, i10, i11, i12, i20, i21, i22 = _inv3s(d00, d01, d02, d10, d11, d12, d20, d21, d22)
            rr[t, 0] = i00 * r0 + i01 * r1 + i02 * r2
            rr[t, 1] = i10 * r0 + i11 * r1 + i12 * r2
            rr[t, 2] = i20 * r0 + i21 * r1 + i22 * r2
            qu = nslot[k, direction]
            C = Cm[t]
            if t < t1 - 1 and qu >= 0:
                u00 = data[qu, 0, 0]; u01 = data[qu, 0, 1]; u02 = data[qu, 0, 2]
                u10 = data[qu, 1, 0]; u11 = data[qu, 1, 1]; u12 = data[qu, 1, 2]
                u20 = data[qu, 2, 0]; u21 = data[qu, 2, 1]; u22 = data[qu, 2, 2]
                C[0] = i00 * u00 + i01 * u10 + i02 * u20
                C[1] = i00 * u01 + i01 * u11 + i02 * u21
                C[2] = i00 * u02 + i01 * u12 + i02 * u22
                C[3] = i10 * u00 + i11 * u10 + i12 * u20
                C[4] = i10 * u01 + i11 * u11 + i12 * u21
                C[5] = i10 * u02 + i11 * u12 + i12 * u22
                C[6] = i20 * u00 + i21 * u10 + i22 * u20
                C[7] = i20 * u01 + i21 * u11 + i22 * u21
                C[8] = i20 * u02 + i21 * u12 + i22 * u22
            else:
                for u in range(9):
                    C[u] = 0.0
        # back substitution
        for tt in range(t1 - t0):
            t = t1 - 1 - tt
            if t < t1 - 1:
                C = Cm[t]
                n0 = rr[t + 1, 0]
                n1 = rr[t + 1, 1]
                n2 = rr[t + 1, 2]
                rr[t, 0] -= C[0] * n0 + C[1] * n1 + C[2] * n2
                rr[t, 1] -= C[3] * n0 + C[4] * n1 + C[5] * n2
                rr[t, 2] -= C[6] * n0 + C[7] * n1 + C[8] * n2
            k = first + t * stride
            kv = node[k] if mapped else k
            xv[3 * kv] = rr[t, 0]
            xv[3 * kv + 1] = rr[t, 1]
            xv[3 * kv + 2] = rr[t, 2]


@njit(cache=True)
def _block6(indptr, indices, data, u, v, out):
    """out (6,6) = the blocks of the node pairs u (2,) x v (2,) (zero where not coupled)."""
    for h in range(2):
        for g in range(2):
            q = _find_block(indptr, indices, u[h], v[g])
            for r in range(3):
                for c in range(3):
                    out[3 * h + r, 3 * g + c] = data[q, r, c] if q >= 0 else 0.0


@njit(cache=True)
def _chain_gs(indptr, indices, data, pairs, cstart, b, xv, reverse):
    """Block line Gauss-Seidel along seams: each chain of sewn pairs (pairs[cstart[c]:cstart[c+1]],
    consecutive along the seam) is solved exactly as a 6x6-block tridiagonal system (the pair's
    two nodes together; block Thomas algorithm), every other coupling taken from the current
    iterate; chains visited in reverse when ``reverse`` (the adjoint sweep).

    Why: a seam is a penalty spring about 1000 times a lattice spring's stiffness. A smoother
    that relaxes one node or one grid line at a time pins each sewn node to its partner's
    current value, so the pair's common motion, which the panels' soft springs decide, moves by
    about 1/1000 of its error per sweep; solving the two sides of the seam together moves it at
    once, and along the seam's line as the line smoother does on the grid."""
    nch = cstart.shape[0] - 1
    longest = 0
    for c in range(nch):
        longest = max(longest, cstart[c + 1] - cstart[c])
    D = np.empty((6, 6))
    Lb = np.empty((6, 6))
    Cm = np.zeros((longest, 6, 6))
    y = np.zeros((longest, 6))
    rhs = np.empty((6, 7))
    for cc in range(nch):
        c = nch - 1 - cc if reverse else cc
        s0 = cstart[c]
        m = cstart[c + 1] - s0
        for t in range(m):
            p = s0 + t
            # right-hand side without the couplings inside the window t-1..t+1
            for h in range(2):
                k = pairs[p, h]
                r0 = b[3 * k]
                r1 = b[3 * k + 1]
                r2 = b[3 * k + 2]
                for q in range(indptr[k], indptr[k + 1]):
                    j = indices[q]
                    inwin = j == pairs[p, 0] or j == pairs[p, 1]
                    if t > 0:
                        inwin = inwin or j == pairs[p - 1, 0] or j == pairs[p - 1, 1]
                    if t < m - 1:
                        inwin = inwin or j == pairs[p + 1, 0] or j == pairs[p + 1, 1]
                    if inwin:
                        continue
                    x0 = xv[3 * j]
                    x1 = xv[3 * j + 1]
                    x2 = xv[3 * j + 2]
                    r0 -= data[q, 0, 0] * x0 + data[q, 0, 1] * x1 + data[q, 0, 2] * x2
                    r1 -= data[q, 1, 0] * x0 + data[q, 1, 1] * x1 + data[q, 1, 2] * x2
                    r2 -= data[q, 2, 0] * x0 + data[q, 2, 1] * x1 + data[q, 2, 2] * x2
                y[t, 3 * h] = r0
                y[t, 3 * h + 1] = r1
                y[t, 3 * h + 2] = r2
            _block6(indptr, indices, data, pairs[p], pairs[p], D)
            if t > 0:
                _block6(indptr, indices, data, pairs[p], pairs[p - 1], Lb)
                # D -= L C_{t-1}; y_t -= L y_{t-1}
                for r in range(6):
                    for q2 in range(6):
                        v = 0.0
                        for u in range(6):
                            v += Lb[r, u] * Cm[t - 1, u, q2]
                        D[r, q2] -= v
                    v = 0.0
                    for u in range(6):
                        v += Lb[r, u] * y[t - 1, u]
                    y[t, r] -= v
            # solve D [C_t | y_t] = [U_t | y_t]
            for r in range(6):
                for q2 in range(6):
                    rhs[r, q2] = 0.0
                rhs[r, 6] = y[t, r]
            if t < m - 1:
                _block6(indptr, indices, data, pairs[p], pairs[p + 1], Lb)
                for r in range(6):
                    for q2 in range(6):
                        rhs[r, q2] = Lb[r, q2]
            _solve6(D, rhs)
            for r in range(6):
                for q2 in range(6):
                    Cm[t, r, q2] = rhs[r, q2]
                y[t, r] = rhs[r, 6]
        for tt in range(m):
            t = m - 1 - tt
            if t < m - 1:
                for r in range(6):
                    v = 0.0
                    for u in range(6):
                        v += Cm[t, r, u] * y[t + 1, u]
                    y[t, r] -= v
            p = s0 + t
            for h in range(2):
                k = pairs[p, h]
                for r in range(3):
                    xv[3 * k + r] = y[t, 3 * h + r]


@njit(cache=True)
def _solve6(D, R):
    """R (6,7) <- D^{-1} R by Gaussian elimination with partial pivoting (D (6,6) is
    overwritten); a zero pivot column gives zero rows."""
    for c in range(6):
        piv = c
        big = abs(D[c, c])
        for r in range(c + 1, 6):
            if abs(D[r, c]) > big:
                big = abs(D[r, c])
                piv = r
        if not (big > 0.0):
            for t in range(7):
                R[c, t] = 0.0
            D[c, c] = 1.0
            continue
        if piv != c:
            for t in range(6):
                tmp = D[c, t]
                D[c, t] = D[piv, t]
                D[piv, t] = tmp
            for t in range(7):
                tmp = R[c, t]
                R[c, t] = R[piv, t]
                R[piv, t] = tmp
        for r in range(c + 1, 6):
            f = D[r, c] / D[c, c]
            if f != 0.0:
                for t in range(c, 6):
                    D[r, t] -= f * D[c, t]
                for t in range(7):
                    R[r, t] -= f * R[c, t]
    for c in range(5, -1, -1):
        for t in range(7):
            v = R[c, t]
            for u in range(c + 1, 6):
                v -= D[c, u] * R[u, t]
            R[c, t] = v / D[c, c]


class _Transposed:
    """The BSR pattern of an nx1 x ny1 grid level (node k = i ny1 + j) with its rows renumbered
    j-major (row r = j nx1 + i is node ``node[r]``), each row's blocks in their original order:
    the i lines of the grid are then contiguous rows. ``gather`` (nb,): the original block of
    each renumbered one; ds (N,), ps, ns (N, 2): ``_line_slots``' slots of the renumbered rows
    with the i-line neighbours in column 1 (as _line_gs reads direction 1); indices: the original
    block columns (unknowns)."""

    def __init__(self, indptr, indices, nx1, ny1, ds, ps, ns):
        (self.node, self.indptr, self.gather, self.indices, self.ds, self.ps,
         self.ns) = _transposed_pattern(indptr, indices, nx1, ny1, ds, ps, ns)


@njit(cache=True)
def _transposed_pattern(indptr, indices, nx1, ny1, ds, ps, ns):
    """``_Transposed``'s arrays: (node, indptr, gather, indices, ds, ps, ns)."""
    n = nx1 * ny1
    nb = indptr[n]
    node = np.empty(n, np.int64)
    tptr = np.zeros(n + 1, np.int64)
    for r in range(n):
        k = (r % nx1) * ny1 + r // nx1
        node[r] = k
        tptr[r + 1] = tptr[r] + indptr[k + 1] - indptr[k]
    gather = np.empty(nb, np.int64)
    tidx = np.empty(nb, indices.dtype)
    where = np.empty(nb, np.int64)
    for r in range(n):
        k = node[r]
        for u in range(indptr[k + 1] - indptr[k]):
            q = indptr[k] + u
            gather[tptr[r] + u] = q
            tidx[tptr[r] + u] = indices[q]
            where[q] = tptr[r] + u
    tds = np.empty(n, np.int64)
    tps = np.full((n, 2), -1, np.int64)
    tns = np.full((n, 2), -1, np.int64)
    for r in range(n):
        k = node[r]
        tds[r] = where[ds[k]] if ds[k] >= 0 else -1
        if ps[k, 0] >= 0:
            tps[r, 1] = where[ps[k, 0]]
        if ns[k, 0] >= 0:
            tns[r, 1] = where[ns[k, 0]]
    return node, tptr, gather, tidx, tds, tps, tns


@njit(cache=True)
def _gather_blocks(data, gather, out):
    """out[q] = data[gather[q]] for (nb, 3, 3) blocks."""
    for q in range(gather.shape[0]):
        s = gather[q]
        for a in range(3):
            for c in range(3):
                out[q, a, c] = data[s, a, c]


_NO_MAP = np.zeros(0, np.int64)


def _i_lines(L, nx1, ny1, b, x, reverse, span):
    """The level's i-line sweep (``_line_gs`` direction 0) of x (3N,) [m] for b (3N,) [N] on the
    level L (N = nx1 ny1 nodes), in place, on its renumbered rows when it has them
    (``_Transposed``: the same result, read contiguously); span (ny1, 2): the i lines' spans."""
    T = L.T
    if T is None:
        _line_gs(L.indptr, L.indices, L.data, nx1, ny1, L.ds, L.ps, L.ns, b, x, 0, reverse, span, _NO_MAP)
    else:
        _line_gs(T.indptr, T.indices, L.tdata, ny1, nx1, T.ds, T.ps, T.ns, b, x, 1, reverse, span, T.node)


def _seam_smooth(L, pr, starts, b, x, reverse):
    _chain_gs(L.indptr, L.indices, L.data, pr, starts, b, x, reverse)


def seam_chains(indptr, indices, pairs):
    """Where the sewn pairs (m,2), in seam order, split into chains for ``_chain_gs``: (c+1,)
    int64 starts. Two consecutive pairs stay in one chain when a node of one is coupled to a
    node of the other (a block in the pattern) and the four nodes are distinct."""
    m = len(pairs)
    starts = [0]
    for p in range(1, m):
        a0, b0 = pairs[p - 1]
        a1, b1 = pairs[p]
        linked = len({a0, b0, a1, b1}) == 4 and any(
            _find_block(indptr, indices, u, v) >= 0 for u in (a0, b0) for v in (a1, b1))
        if not linked:
            starts.append(p)
    starts.append(m)
    return np.asarray(starts, np.int64)
