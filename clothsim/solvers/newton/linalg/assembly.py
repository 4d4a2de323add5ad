"""The Newton matrix as 3x3-block sparse rows (BSR): its pattern from the springs (and seam
pairs), its assembly, the active-set projection of the system, block lookup, products and
residuals.

Shapes: n nodes, S springs, nb stored 3x3 blocks; vectors are flat (3n,) in node-major order
(x0, y0, z0, x1, ...). Units: stiffness blocks N/m, forces N, displacements m."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ....kernels import LENGTH_EPS, spring_vector



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
def _bsr_residual(indptr, indices, data, xv, b, out):
    """out = b - A x."""
    _bsr_matvec(indptr, indices, data, xv, out)
    for i in range(out.shape[0]):
        out[i] = b[i] - out[i]


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
