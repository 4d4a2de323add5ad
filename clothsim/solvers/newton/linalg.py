"""Linear algebra of the Newton step: the 3x3-block sparse (BSR) Hessian's pattern and assembly,
the active-set projection of the system, the line-smoothed geometric multigrid V-cycle and the
preconditioned conjugate gradients it preconditions.

Shapes: n nodes, S springs, nb stored 3x3 blocks; vectors are flat (3n,) in node-major order
(x0, y0, z0, x1, ...). Units: stiffness blocks N/m, forces N, displacements m.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from numba import njit

from ...kernels import LENGTH_EPS, spring_vector
from .objcache import per_object

from ..tuning import NewtonTuning

# The switches read here (coarsest_nodes, band_work, transpose_nodes, galerkin_terms,
# trim_padding, panel_align, pad_identity, pair_smoothing) are fields of ``tuning.NewtonTuning``.


@njit(cache=True)
def _bsr_pattern(n, spring_nodes):
    """Block-sparse pattern (one 3x3 block per node pair coupled by a spring, plus the diagonal).

    Returns (indptr (n+1,), indices (nb,), spring_slot (S,4): the block slots of (a,a), (b,b),
    (a,b), (b,a) for every spring, diag_slot (n,))."""
    s_count = spring_nodes.shape[0]
    deg = np.ones(n, np.int64)
    for s in range(s_count):
        deg[spring_nodes[s, 0]] += 1
        deg[spring_nodes[s, 1]] += 1
    cols = np.empty(deg.sum(), np.int64)
    ptr = np.zeros(n + 1, np.int64)
    for i in range(n):
        ptr[i + 1] = ptr[i] + deg[i]
    fill = ptr[:-1].copy()
    for i in range(n):
        cols[fill[i]] = i
        fill[i] += 1
    for s in range(s_count):
        a = spring_nodes[s, 0]
        b = spring_nodes[s, 1]
        cols[fill[a]] = b
        fill[a] += 1
        cols[fill[b]] = a
        fill[b] += 1
    # sort and deduplicate each row
    indptr = np.zeros(n + 1, np.int64)
    out = np.empty(cols.shape[0], np.int64)
    m = 0
    for i in range(n):
        # insertion sort in place (rows are short; np.sort allocates per row)
        for a in range(ptr[i] + 1, ptr[i + 1]):
            c = cols[a]
            b = a - 1
            while b >= ptr[i] and cols[b] > c:
                cols[b + 1] = cols[b]
                b -= 1
            cols[b + 1] = c
        last = -1
        for a in range(ptr[i], ptr[i + 1]):
            c = cols[a]
            if c != last:
                out[m] = c
                m += 1
                last = c
        indptr[i + 1] = m
    indices = out[:m].copy()

    slot = np.empty((s_count, 4), np.int64)
    for s in range(s_count):
        a = spring_nodes[s, 0]
        b = spring_nodes[s, 1]
        slot[s, 0] = _find_block(indptr, indices, a, a)
        slot[s, 1] = _find_block(indptr, indices, b, b)
        slot[s, 2] = _find_block(indptr, indices, a, b)
        slot[s, 3] = _find_block(indptr, indices, b, a)
    diag = np.empty(n, np.int64)
    for i in range(n):
        diag[i] = _find_block(indptr, indices, i, i)
    return indptr, indices, slot, diag


@njit(cache=True)
def _assemble(pos, spring_nodes, rest, width, table, x, y, cum, start, comp, kink, slot, data):
    """Hessian blocks of the spring energy into data (nb,3,3) (zeroed first).

    Per spring the block of ``kernels.spring_hessian_block`` (the same formula, written with
    scalars): K = (w/l0) T'(s) u u^T + max(w T / l, 0) (I - u u^T), with T' replaced by
    kink[s] [N/m] at and below strain 0 on tension-only springs.

    The table lookup is ``table_eval``'s (T and dT) written out in the loop, the same operations
    in the same order (see ``kernels.forces_and_energy``: a call that takes the table's arrays
    costs numba a reference count on each of them per spring, about half this loop's time)."""
    data[:] = 0.0
    for s in range(spring_nodes.shape[0]):
        dx, dy, dz, length = spring_vector(pos, spring_nodes[s, 0], spring_nodes[s, 1])
        if length < LENGTH_EPS:
            continue
        l0 = rest[s]
        w = width[s]
        t = table[s]
        st = length / l0 - 1.0
        m = start[t]
        if st <= 0.0:
            if comp[t] == 0:
                T = 0.0
                dT = 0.0
            else:
                dT = (y[m + 1] - y[m]) / (x[m + 1] - x[m])
                T = y[m] + dT * st
        else:
            end = start[t + 1] - 2
            while m < end and st >= x[m + 1]:
                m += 1
            dT = (y[m + 1] - y[m]) / (x[m + 1] - x[m])
            T = y[m] + dT * (st - x[m])
        if st <= 0.0 and comp[t] == 0 and kink[s] > 0.0:
            dT = kink[s]
        u0 = dx / length
        u1 = dy / length
        u2 = dz / length
        ka = w / l0 * dT
        kt = w * T / length
        if kt < 0.0:
            kt = 0.0
        kd = ka - kt
        b00 = kd * u0 * u0 + kt
        b11 = kd * u1 * u1 + kt
        b22 = kd * u2 * u2 + kt
        b01 = kd * u0 * u1
        b02 = kd * u0 * u2
        b12 = kd * u1 * u2
        for q, sg in ((slot[s, 0], 1.0), (slot[s, 1], 1.0), (slot[s, 2], -1.0), (slot[s, 3], -1.0)):
            data[q, 0, 0] += sg * b00
            data[q, 1, 1] += sg * b11
            data[q, 2, 2] += sg * b22
            data[q, 0, 1] += sg * b01
            data[q, 1, 0] += sg * b01
            data[q, 0, 2] += sg * b02
            data[q, 2, 0] += sg * b02
            data[q, 1, 2] += sg * b12
            data[q, 2, 1] += sg * b12


@njit(cache=True)
def _projector_kinds(Pi):
    """Per node (n,) int8: 1 where Pi[k] is exactly the identity, 2 where it is exactly zero, 3
    another finite projector, 0 one with a non-finite entry."""
    n = Pi.shape[0]
    kind = np.empty(n, np.int8)
    for k in range(n):
        ident = True
        zero = True
        finite = True
        for r in range(3):
            for c in range(3):
                v = Pi[k, r, c]
                if v != (1.0 if r == c else 0.0):
                    ident = False
                if v != 0.0:
                    zero = False
                if not math.isfinite(v):
                    finite = False
        kind[k] = 1 if ident else (2 if zero else (3 if finite else 0))
    return kind


@njit(cache=True)
def _project_system(indptr, indices, data, diag, Pi, mu_abs, out):
    """out = Pi K Pi + mu Pi + (I - Pi) blockwise (Pi (n,3,3) symmetric projectors).

    A finite block K_ij is copied (+ 0.0) where Pi_i and Pi_j are the identity, and is 0 where
    Pi_j is zero (Pi_i finite) or Pi_i is zero and Pi_j the identity: the products' exact
    results, bit for bit (each sum starts from 0.0, so a -0.0 entry becomes 0.0 either way), at
    the cost of a copy: on a sheet most nodes are free (identity) and a held node's is zero."""
    n = indptr.shape[0] - 1
    tmp = np.empty((3, 3))
    kind = _projector_kinds(Pi)
    for i in range(n):
        ki = kind[i]
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            kj = kind[j]
            if (kj == 2 and ki != 0) or (ki == 2 and kj == 1) or (ki == 1 and kj == 1):
                finite = True
                for r in range(3):
                    for c in range(3):
                        if not math.isfinite(data[q, r, c]):
                            finite = False
                if finite:
                    if ki == 1 and kj == 1:
                        for r in range(3):
                            for c in range(3):
                                out[q, r, c] = data[q, r, c] + 0.0
                    else:
                        for r in range(3):
                            for c in range(3):
                                out[q, r, c] = 0.0
                    continue
            # tmp = K_ij Pi_j
            for r in range(3):
                for c in range(3):
                    v = 0.0
                    for t in range(3):
                        v += data[q, r, t] * Pi[j, t, c]
                    tmp[r, c] = v
            for r in range(3):
                for c in range(3):
                    v = 0.0
                    for t in range(3):
                        v += Pi[i, r, t] * tmp[t, c]
                    out[q, r, c] = v
        d = diag[i]
        for r in range(3):
            for c in range(3):
                idm = 1.0 if r == c else 0.0
                out[d, r, c] += mu_abs * Pi[i, r, c] + (idm - Pi[i, r, c])


@njit(cache=True)
def _find_block(indptr, indices, i, j):
    lo = indptr[i]
    hi = indptr[i + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if indices[mid] < j:
            lo = mid + 1
        else:
            hi = mid
    if lo < indptr[i + 1] and indices[lo] == j:
        return lo
    return -1


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




def band_order(n, spring_nodes):
    """A node order (reverse Cuthill-McKee on the spring graph) for the banded solve and its
    half-bandwidth in nodes: (perm (n,) new -> old node, inverse (n,) old -> new, bandwidth)."""
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    a, b = spring_nodes[:, 0], spring_nodes[:, 1]
    G = sp.coo_matrix((np.ones(2 * a.size), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n)).tocsr()
    perm = np.asarray(reverse_cuthill_mckee(G, symmetric_mode=True), np.int64)
    inv = np.empty(n, np.int64)
    inv[perm] = np.arange(n)
    bw = int(np.abs(inv[a] - inv[b]).max()) if a.size else 0
    return perm, inv, bw


@njit(cache=True, inline="always")
def _band_entry(L, j, k, k0, w):
    """L[j, k] (k < j) of ``_band_factor``: A[j, k] minus the sum over m = k0 .. k-1 of
    L[j, m] L[k, m] (in that order), over L[k, k]."""
    s = L[j, w - 1 - (j - k)]
    oj = w - 1 - j
    ok = w - 1 - k
    for m in range(k0, k):
        s -= L[j, oj + m] * L[k, ok + m]
    L[j, w - 1 - (j - k)] = s / L[k, w - 1]


@njit(cache=True)
def _band_factor(L):
    """In-place banded Cholesky factorisation of the lower band stored in L (3n, w) (row i holds
    A[i, i - w + 1 .. i], the diagonal last; see ``_band_cholesky_solve``). Returns False when a
    pivot is not positive.

    Each entry is computed by the same arithmetic, in the same order, as the row-by-row
    algorithm (s = A[j, k] - sum_{m} L[j, m] L[k, m], m increasing); four rows are computed side
    by side against the same earlier row k, so that the four sums' additions (a chain each)
    overlap in the processor's pipeline instead of waiting on one another."""
    n3 = L.shape[0]
    w = L.shape[1]
    j0 = 0
    while j0 < n3:
        R = n3 - j0
        if R > 4:
            R = 4
        k00 = max(j0 - (w - 1), 0)
        if R == 4:
            k01 = max(j0 + 1 - (w - 1), 0)
            k02 = max(j0 + 2 - (w - 1), 0)
            k03 = max(j0 + 3 - (w - 1), 0)
            oj0 = w - 1 - j0
            oj1 = oj0 - 1
            oj2 = oj0 - 2
            oj3 = oj0 - 3
            for k in range(k00, j0):
                if k < k03:
                    # not every row of the four has an entry in column k yet
                    _band_entry(L, j0, k, k00, w)
                    if k >= k01:
                        _band_entry(L, j0 + 1, k, k01, w)
                    if k >= k02:
                        _band_entry(L, j0 + 2, k, k02, w)
                    continue
                ok = w - 1 - k
                s0 = L[j0, oj0 + k]
                s1 = L[j0 + 1, oj1 + k]
                s2 = L[j0 + 2, oj2 + k]
                s3 = L[j0 + 3, oj3 + k]
                for m in range(k00, k03):
                    s0 -= L[j0, oj0 + m] * L[k, ok + m]
                for m in range(k01, k03):
                    s1 -= L[j0 + 1, oj1 + m] * L[k, ok + m]
                for m in range(k02, k03):
                    s2 -= L[j0 + 2, oj2 + m] * L[k, ok + m]
                for m in range(k03, k):
                    lk = L[k, ok + m]
                    s0 -= L[j0, oj0 + m] * lk
                    s1 -= L[j0 + 1, oj1 + m] * lk
                    s2 -= L[j0 + 2, oj2 + m] * lk
                    s3 -= L[j0 + 3, oj3 + m] * lk
                d = L[k, w - 1]
                L[j0, oj0 + k] = s0 / d
                L[j0 + 1, oj1 + k] = s1 / d
                L[j0 + 2, oj2 + k] = s2 / d
                L[j0 + 3, oj3 + k] = s3 / d
            kstart = j0
        else:
            kstart = -1
        # the rest of each row (row by row): its entries from column kstart on, then its diagonal
        for r in range(R):
            j = j0 + r
            k0 = max(j - (w - 1), 0)
            kb = k0 if kstart < 0 else max(kstart, k0)
            for k in range(kb, j):
                _band_entry(L, j, k, k0, w)
            s = L[j, w - 1]
            oj = w - 1 - j
            for m in range(k0, j):
                v = L[j, oj + m]
                s -= v * v
            if not (s > 0.0) or not math.isfinite(s):
                return False
            L[j, w - 1] = math.sqrt(s)
        j0 += R
    return True


@njit(cache=True)
def _band_cholesky_solve(indptr, indices, data, inv, bw, rhs, L, x):
    """Solve A x = rhs for the symmetric positive definite BSR matrix A (3x3 blocks) by a banded
    Cholesky factorisation in the node order ``inv`` (old -> new node; half-bandwidth bw nodes).
    L (3n, 3 bw + 3) is work space: row i holds L[i, i - w + 1 .. i] (w = 3 bw + 3 columns, the
    diagonal last), so the inner products run over contiguous memory; on success it holds the
    factor (``_band_factored_solve`` solves with it again). Returns False (x undefined) when a
    pivot is not positive: the caller falls back to the sparse LU."""
    if not _band_scatter_factor(indptr, indices, data, inv, L):
        return False
    _band_factored_solve(L, inv, rhs, x)
    return True


@njit(cache=True)
def _band_scatter_factor(indptr, indices, data, inv, L):
    """L (3n, w): the banded Cholesky factor of the BSR matrix (indptr, indices, data (nb, 3, 3))
    in the node order ``inv`` (see ``_band_cholesky_solve``). Returns False when a pivot is not
    positive."""
    n = indptr.shape[0] - 1
    n3 = 3 * n
    w = L.shape[1]
    for i in range(n3):
        for c in range(w):
            L[i, c] = 0.0
    # scatter the lower triangle (new numbering): A[r, c] with c <= r -> L[r, w - 1 - (r - c)]
    for k in range(n):
        kn = inv[k]
        for q in range(indptr[k], indptr[k + 1]):
            jn = inv[indices[q]]
            if jn > kn:
                continue
            for a in range(3):
                r = 3 * kn + a
                for b in range(3):
                    c = 3 * jn + b
                    if c <= r:
                        L[r, w - 1 - (r - c)] = data[q, a, b]
    return _band_factor(L)


@njit(cache=True)
def _band_factored_solve(L, inv, rhs, x):
    """x (3n,) = A^-1 rhs (3n,) with A's banded Cholesky factor L (3n, w) in the node order inv
    (``_band_scatter_factor``)."""
    n3 = L.shape[0]
    n = n3 // 3
    w = L.shape[1]
    # forward: L y = P rhs
    y = np.empty(n3)
    for k in range(n):
        kn = inv[k]
        for a in range(3):
            y[3 * kn + a] = rhs[3 * k + a]
    for j in range(n3):
        s = y[j]
        k0 = j - (w - 1)
        if k0 < 0:
            k0 = 0
        oj = w - 1 - j
        for m in range(k0, j):
            s -= L[j, oj + m] * y[m]
        y[j] = s / L[j, w - 1]
    # backward: L^T z = y
    for jj in range(n3):
        j = n3 - 1 - jj
        y[j] /= L[j, w - 1]
        v = y[j]
        k0 = j - (w - 1)
        if k0 < 0:
            k0 = 0
        oj = w - 1 - j
        for m in range(k0, j):
            y[m] -= L[j, oj + m] * v
    for k in range(n):
        kn = inv[k]
        for a in range(3):
            x[3 * k + a] = y[3 * kn + a]


@njit(cache=True)
def _bsr_residual(indptr, indices, data, xv, b, out):
    """out = b - A x."""
    _bsr_matvec(indptr, indices, data, xv, out)
    for i in range(out.shape[0]):
        out[i] = b[i] - out[i]


@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True)
def _cg_update(x, r, p, Ap, alpha):
    """x += alpha p; r -= alpha Ap; returns |r|^2."""
    s = 0.0
    for i in range(x.shape[0]):
        x[i] += alpha * p[i]
        r[i] -= alpha * Ap[i]
        s += r[i] * r[i]
    return s


@njit(cache=True)
def _cg_direction(p, z, beta):
    for i in range(p.shape[0]):
        p[i] = z[i] + beta * p[i]


@njit(cache=True)
def _bsr_matvec(indptr, indices, data, xv, out):
    n = indptr.shape[0] - 1
    for i in range(n):
        r0 = 0.0
        r1 = 0.0
        r2 = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            x0 = xv[3 * j]
            x1 = xv[3 * j + 1]
            x2 = xv[3 * j + 2]
            r0 += data[q, 0, 0] * x0 + data[q, 0, 1] * x1 + data[q, 0, 2] * x2
            r1 += data[q, 1, 0] * x0 + data[q, 1, 1] * x1 + data[q, 1, 2] * x2
            r2 += data[q, 2, 0] * x0 + data[q, 2, 1] * x1 + data[q, 2, 2] * x2
        out[3 * i] = r0
        out[3 * i + 1] = r1
        out[3 * i + 2] = r2


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


class _Level:
    __slots__ = ("indptr", "indices", "data", "lu", "n", "shape", "ds", "ps", "ns", "T", "tdata")




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


class _Transfer:
    """Node-level bilinear interpolation between a grid and its every-second-node coarse grid."""

    def __init__(self, topology):
        nx1, ny1 = topology.grid_shape
        from ...topology import Topology

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
        Alast = (Alast + sp.diags(fix + 1e-12 * max(scale, 1e-300))).tocsc()
        last.lu = sla.splu(Alast, permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True),
                           diag_pivot_thresh=1e-3)
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
        from ...topology import Topology

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


def _pcg(matvec, prec, b, tol, maxiter, x0=None):
    """Preconditioned conjugate gradients from x = x0 (None: 0); returns (x, iterations, relative
    residual), the residual relative to |b|.

    Vector operations are numba loops: BLAS calls on short vectors are slow when its threads
    compete for a loaded machine."""
    bn = math.sqrt(_dot(b, b))
    if x0 is None:
        x = np.zeros_like(b)
        r = b.copy()
    else:
        x = x0.copy()
        r = np.empty_like(b)
        matvec(x, r)
        np.subtract(b, r, out=r)
        if bn > 0.0 and math.sqrt(_dot(r, r)) <= tol * bn:
            return x, 0, math.sqrt(_dot(r, r)) / bn
    if bn == 0.0:
        return x, 0, 0.0
    z = prec(r)
    p = z.copy()
    rz = _dot(r, z)
    it = 0
    rel = 1.0
    Ap = np.empty_like(b)
    for it in range(1, maxiter + 1):
        matvec(p, Ap)
        pAp = _dot(p, Ap)
        if not (pAp > 0.0):
            break
        rr = _cg_update(x, r, p, Ap, rz / pAp)
        rel = math.sqrt(rr) / bn
        if rel <= tol:
            break
        z = prec(r)
        rz_new = _dot(r, z)
        _cg_direction(p, z, rz_new / rz)
        rz = rz_new
    return x, it, rel
