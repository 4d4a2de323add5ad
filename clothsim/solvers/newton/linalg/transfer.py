"""Between multigrid levels: the stride-2 grid transfers (parents, weights, spans), restriction,
prolongation and the Galerkin coarse operator P^T A P (its pattern, its values, its terms),
with the active-set projectors applied."""

from __future__ import annotations


import numpy as np
from numba import njit


from ....topology import Topology


@njit(cache=True)
def _coarse_row(c, cptr, cchild, indptr, indices, pidx, marker, stamp, rowbuf):
    """The distinct coarse columns of row c of P^T A P (the parents of the fine neighbours of
    c's children) into rowbuf, unsorted; returns how many. marker (nc,) remembers the stamp of
    the row that last listed each column (stamps must differ between calls)."""
    m = 0
    for qc in range(cptr[c], cptr[c + 1]):
        k = cchild[qc]
        for q in range(indptr[k], indptr[k + 1]):
            l = indices[q]
            for t in range(pidx.shape[1]):
                d = pidx[l, t]
                if d >= 0 and marker[d] != stamp:
                    marker[d] = stamp
                    rowbuf[m] = d
                    m += 1
    return m


@njit(cache=True)
def _galerkin_pattern(indptr, indices, pidx, cptr, cchild, nc):
    """The block pattern of the coarse operator P^T A P (see :func:`_galerkin_values`): (cip (nc+1,),
    cidx) with sorted rows. It depends on the fine pattern and the interpolation alone, so a
    hierarchy rebuilt on the same pattern computes it once (:class:`Multigrid`)."""
    marker = -np.ones(nc, np.int64)
    rowbuf = np.empty(nc, np.int64)
    # symbolic pass: count the coarse row lengths
    cip = np.zeros(nc + 1, np.int64)
    for c in range(nc):
        cip[c + 1] = cip[c] + _coarse_row(c, cptr, cchild, indptr, indices, pidx, marker, c, rowbuf)
    cidx = np.empty(cip[nc], np.int64)
    for c in range(nc):
        # collect and sort the row's columns (a second stamp, nc + c, on the same marker)
        m = _coarse_row(c, cptr, cchild, indptr, indices, pidx, marker, nc + c, rowbuf)
        # insertion sort in place (rows are short; np.sort allocates per row)
        for a in range(1, m):
            v = rowbuf[a]
            b = a - 1
            while b >= 0 and rowbuf[b] > v:
                rowbuf[b + 1] = rowbuf[b]
                b -= 1
            rowbuf[b + 1] = v
        base = cip[c]
        for t in range(m):
            cidx[base + t] = rowbuf[t]
    return cip, cidx


@njit(cache=True)
def _galerkin_values(indptr, indices, data, pidx, pw, cptr, cchild, cw, nc, Pi, use_pi, cip, cidx):
    """Coarse operator A_c = P^T A P for a node-level interpolation P (fine node k has parents
    pidx[k, :] with weights pw[k, :], -1 unused; coarse node c has children cchild[cptr[c]:...]
    with weights cw) acting blockwise as weight x I3: its blocks cdat (nb, 3, 3) on its pattern
    (cip, cidx) from :func:`_galerkin_pattern`. With ``use_pi`` the fine matrix is
    A = Pi K Pi + mu Pi + (I - Pi) and the prolongation is Pi P: then P^T Pi A Pi P equals
    P^T (A - (I - Pi)) P, so the (I - Pi) part is left out of the diagonal blocks."""
    cdat = np.zeros((cip[nc], 3, 3))
    slot = np.empty(nc, np.int64)  # coarse column -> its block in row c (set per row before use)
    blk = np.empty((3, 3))
    for c in range(nc):
        for t in range(cip[c], cip[c + 1]):
            slot[cidx[t]] = t
        for qc in range(cptr[c], cptr[c + 1]):
            k = cchild[qc]
            wk = cw[qc]
            for q in range(indptr[k], indptr[k + 1]):
                l = indices[q]
                # the block (less its (I - Pi) part on the diagonal), read once for its parents
                for r in range(3):
                    for cc in range(3):
                        v = data[q, r, cc]
                        if use_pi and l == k:
                            v -= (1.0 if r == cc else 0.0) - Pi[k, r, cc]
                        blk[r, cc] = v
                for t in range(pidx.shape[1]):
                    d = pidx[l, t]
                    if d < 0:
                        continue
                    w = wk * pw[l, t]
                    z = slot[d]
                    for r in range(3):
                        for cc in range(3):
                            cdat[z, r, cc] += w * blk[r, cc]
    return cdat


@njit(cache=True)
def _galerkin_terms(indptr, indices, pidx, pw, cptr, cchild, cw, nc, cip, cidx):
    """The terms of :func:`_galerkin_values`' sums, grouped by the coarse block they add to:
    coarse block z (of the pattern cip, cidx) is the sum over e = eptr[z] .. eptr[z+1]-1, in
    that order, of ew[e] x (fine block esrc[e]; for esrc[e] < 0 the diagonal block of fine row
    -esrc[e]-1, whose slot is fdiag[that row]), in the order _galerkin_values adds them. Returns
    (eptr (nzc+1,), esrc (ne,) int64, ew (ne,), fdiag (n,)); ew[e] = cw x pw, the same product.
    The terms depend on the patterns and the interpolation alone."""
    n = indptr.shape[0] - 1
    nzc = cip[nc]
    slot = np.empty(nc, np.int64)
    eptr = np.zeros(nzc + 1, np.int64)
    # count the terms of every coarse block
    for c in range(nc):
        for t in range(cip[c], cip[c + 1]):
            slot[cidx[t]] = t
        for qc in range(cptr[c], cptr[c + 1]):
            k = cchild[qc]
            for q in range(indptr[k], indptr[k + 1]):
                l = indices[q]
                for t in range(pidx.shape[1]):
                    d = pidx[l, t]
                    if d >= 0:
                        eptr[slot[d] + 1] += 1
    for z in range(nzc):
        eptr[z + 1] += eptr[z]
    fill = eptr[:-1].copy()
    esrc = np.empty(eptr[nzc], np.int64)
    ew = np.empty(eptr[nzc])
    fdiag = -np.ones(n, np.int64)
    for c in range(nc):
        for t in range(cip[c], cip[c + 1]):
            slot[cidx[t]] = t
        for qc in range(cptr[c], cptr[c + 1]):
            k = cchild[qc]
            wk = cw[qc]
            for q in range(indptr[k], indptr[k + 1]):
                l = indices[q]
                if l == k:
                    fdiag[k] = q
                for t in range(pidx.shape[1]):
                    d = pidx[l, t]
                    if d < 0:
                        continue
                    z = slot[d]
                    e = fill[z]
                    esrc[e] = -(k + 1) if l == k else q
                    ew[e] = wk * pw[l, t]
                    fill[z] = e + 1
    return eptr, esrc, ew, fdiag


@njit(cache=True)
def _galerkin_sum(data, Pi, use_pi, eptr, esrc, ew, fdiag):
    """:func:`_galerkin_values` from its terms (:func:`_galerkin_terms`): the same blocks, bit
    for bit (each coarse block's terms added in the same order, from 0), summed in registers
    one coarse block at a time instead of by read-modify-writes of the coarse blocks. data
    (nzf, 3, 3) the fine BSR values [N/m], Pi (n, 3, 3) the fine projectors (applied when
    use_pi), eptr/esrc/ew/fdiag the terms. Returns cdat (nzc, 3, 3) [N/m]."""
    nzc = eptr.shape[0] - 1
    n = fdiag.shape[0]
    # the fine diagonal blocks, less their (I - Pi) part with use_pi
    dg = np.empty((n, 3, 3))
    for k in range(n):
        q = fdiag[k]
        if q < 0:
            continue
        for r in range(3):
            for cc in range(3):
                v = data[q, r, cc]
                if use_pi:
                    v -= (1.0 if r == cc else 0.0) - Pi[k, r, cc]
                dg[k, r, cc] = v
    cdat = np.empty((nzc, 3, 3))
    for z in range(nzc):
        a00 = 0.0; a01 = 0.0; a02 = 0.0
        a10 = 0.0; a11 = 0.0; a12 = 0.0
        a20 = 0.0; a21 = 0.0; a22 = 0.0
        for e in range(eptr[z], eptr[z + 1]):
            s = esrc[e]
            w = ew[e]
            if s >= 0:
                B = data[s]
            else:
                B = dg[-s - 1]
            a00 += w * B[0, 0]; a01 += w * B[0, 1]; a02 += w * B[0, 2]
            a10 += w * B[1, 0]; a11 += w * B[1, 1]; a12 += w * B[1, 2]
            a20 += w * B[2, 0]; a21 += w * B[2, 1]; a22 += w * B[2, 2]
        cdat[z, 0, 0] = a00; cdat[z, 0, 1] = a01; cdat[z, 0, 2] = a02
        cdat[z, 1, 0] = a10; cdat[z, 1, 1] = a11; cdat[z, 1, 2] = a12
        cdat[z, 2, 0] = a20; cdat[z, 2, 1] = a21; cdat[z, 2, 2] = a22
    return cdat


@njit(cache=True)
def _restrict(r, cptr, cchild, cw, Pi, use_pi, out):
    """out = (Pi P)^T r blockwise (Pi only when use_pi)."""
    nc = cptr.shape[0] - 1
    for c in range(nc):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for q in range(cptr[c], cptr[c + 1]):
            k = cchild[q]
            w = cw[q]
            r0 = r[3 * k]
            r1 = r[3 * k + 1]
            r2 = r[3 * k + 2]
            if use_pi:
                a0 += w * (Pi[k, 0, 0] * r0 + Pi[k, 0, 1] * r1 + Pi[k, 0, 2] * r2)
                a1 += w * (Pi[k, 1, 0] * r0 + Pi[k, 1, 1] * r1 + Pi[k, 1, 2] * r2)
                a2 += w * (Pi[k, 2, 0] * r0 + Pi[k, 2, 1] * r1 + Pi[k, 2, 2] * r2)
            else:
                a0 += w * r0
                a1 += w * r1
                a2 += w * r2
        out[3 * c] = a0
        out[3 * c + 1] = a1
        out[3 * c + 2] = a2


@njit(cache=True)
def _prolong_add(xc, pidx, pw, Pi, use_pi, x):
    """x += (Pi P) xc blockwise."""
    for k in range(pidx.shape[0]):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for t in range(pidx.shape[1]):
            d = pidx[k, t]
            if d < 0:
                continue
            w = pw[k, t]
            a0 += w * xc[3 * d]
            a1 += w * xc[3 * d + 1]
            a2 += w * xc[3 * d + 2]
        if use_pi:
            x[3 * k] += Pi[k, 0, 0] * a0 + Pi[k, 0, 1] * a1 + Pi[k, 0, 2] * a2
            x[3 * k + 1] += Pi[k, 1, 0] * a0 + Pi[k, 1, 1] * a1 + Pi[k, 1, 2] * a2
            x[3 * k + 2] += Pi[k, 2, 0] * a0 + Pi[k, 2, 1] * a1 + Pi[k, 2, 2] * a2
        else:
            x[3 * k] += a0
            x[3 * k + 1] += a1
            x[3 * k + 2] += a2


class _Transfer:
    """Node-level bilinear interpolation between a grid and its every-second-node coarse grid."""

    def __init__(self, topology):
        nx1, ny1 = topology.grid_shape
        self.pidx, self.pw, self.cptr, self.cchild, self.cw, nxc, nyc = _grid_transfer(nx1, ny1)
        # the coarse grid of Topology.grid_prolongation (every second node of each line and its last)
        self.coarse = Topology.rectangle(nxc - 1, nyc - 1, topology.names[0])
        self.nc = nxc * nyc


@njit(cache=True)
def _line_parents(n):
    """A line of n nodes and its coarse line (every second node and the last): (nc, parent index
    (n, 2), weight (n, 2)) with -1 / 0 for an unused second parent, parents in increasing order
    (the 1-d factor of Topology.grid_prolongation's P)."""
    nc = (n + 1) // 2
    if (n - 1) % 2 == 1:
        nc += 1
    par = -np.ones((n, 2), np.int64)
    w = np.zeros((n, 2))
    for i in range(n):
        if i % 2 == 0:
            par[i, 0] = i // 2
            w[i, 0] = 1.0
        elif i == n - 1:
            # the last node (odd index) is a coarse node of its own
            par[i, 0] = nc - 1
            w[i, 0] = 1.0
        else:
            par[i, 0] = (i - 1) // 2
            par[i, 1] = (i + 1) // 2
            w[i, 0] = 0.5
            w[i, 1] = 0.5
    return nc, par, w


@njit(cache=True)
def _grid_transfer(nx1, ny1):
    """The bilinear transfer of an nx1 x ny1 node grid (node i * ny1 + j) to its every-second-node
    coarse grid, as ``_Transfer`` holds it: (pidx (n, 4), pw (n, 4), cptr (nc+1,), cchild,
    cw, nxc, nyc); the same arrays as built from Topology.grid_prolongation's P (its rows'
    columns in increasing order, each coarse node's children in increasing order)."""
    nxc, px, wx = _line_parents(nx1)
    nyc, py, wy = _line_parents(ny1)
    n = nx1 * ny1
    nc = nxc * nyc
    pidx = -np.ones((n, 4), np.int64)
    pw = np.zeros((n, 4))
    cnt = np.zeros(nc + 1, np.int64)
    for i in range(nx1):
        for j in range(ny1):
            k = i * ny1 + j
            t = 0
            for a in range(2):
                if px[i, a] < 0:
                    continue
                for b in range(2):
                    if py[j, b] < 0:
                        continue
                    c = px[i, a] * nyc + py[j, b]
                    pidx[k, t] = c
                    pw[k, t] = wx[i, a] * wy[j, b]
                    cnt[c + 1] += 1
                    t += 1
    for c in range(nc):
        cnt[c + 1] += cnt[c]
    cptr = cnt.copy()
    fill = cnt[:-1].copy()
    cchild = np.empty(cptr[nc], np.int64)
    cw = np.empty(cptr[nc])
    for k in range(n):
        for t in range(4):
            c = pidx[k, t]
            if c < 0:
                continue
            cchild[fill[c]] = k
            cw[fill[c]] = pw[k, t]
            fill[c] += 1
    return pidx, pw, cptr, cchild, cw, nxc, nyc


def _full_spans(nx1, ny1):
    """_line_gs's spans of whole lines on an nx1 x ny1 grid: (i lines (ny1, 2), j lines (nx1, 2))."""
    a = np.zeros((ny1, 2), np.int64)
    a[:, 1] = nx1
    b = np.zeros((nx1, 2), np.int64)
    b[:, 1] = ny1
    return a, b


def _trimmed_spans(pad, nx1, ny1):
    """_line_gs's spans on an nx1 x ny1 grid (node k = i ny1 + j) without the padding (pad (n,)
    bool) at each line's ends: (i lines (ny1, 2), j lines (nx1, 2)); an all-padding line gets
    an empty span."""
    live = ~pad.reshape(nx1, ny1)
    out = []
    for m in (live.T, live):  # i lines: rows of live.T (fixed j); j lines: rows of live (fixed i)
        sp_ = np.zeros((m.shape[0], 2), np.int64)
        anyl = m.any(axis=1)
        sp_[anyl, 0] = m[anyl].argmax(axis=1)
        sp_[anyl, 1] = m.shape[1] - m[anyl][:, ::-1].argmax(axis=1)
        out.append(sp_)
    return out[0], out[1]


def coarse_pairs(pairs, transfers):
    """The sewn node pairs (m,2) of each level: level 0's are ``pairs``; a pair goes on to the
    next level when both its nodes are coarse grid nodes (a prolongation row of one weight-1
    entry), as those coarse nodes. Returns a list, one (m_l,2) int64 array or None per level
    (len(transfers) + 1 levels)."""
    out = [np.ascontiguousarray(pairs, np.int64)]
    for tr in transfers:
        pr = out[-1]
        if pr is None or not len(pr):
            out.append(None)
            continue
        inj = (tr.pidx[:, 1] < 0) & (tr.pw[:, 0] == 1.0)
        a, b = pr[:, 0], pr[:, 1]
        keep = inj[a] & inj[b]
        nxt = np.stack([tr.pidx[a[keep], 0], tr.pidx[b[keep], 0]], axis=1)
        nxt = nxt[nxt[:, 0] != nxt[:, 1]]
        out.append(np.ascontiguousarray(nxt, np.int64) if len(nxt) else None)
    return out
