"""Numba kernels: pure functions of arrays (no pydantic objects, no globals that change).

Per-element math lives in small functions (a table lookup, one spring's force, energy and Hessian
block); the loop kernels call them. Every function is ``@njit(cache=True)`` so that a second run
starts without recompiling.

Spring model (paper eq. 1-3): a spring between nodes a and b with rest length l0 [m], tributary
width w [m] and tension table T(strain) [N/m] pulls both ends towards each other with the axial
force ``f = T(l/l0 - 1) * w`` [N]. Its energy is ``E = w * l0 * int_0^strain T(s) ds`` [J], so
that ``-dE/dx_a = f * (x_b - x_a)/l``: forces are exact gradients of the energy (tests check this
by finite differences).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# A spring shorter than this [m] has no defined direction: it carries no force (see
# docs/method/modelling.md: projection can put two nodes on the same mold vertex).
LENGTH_EPS = 1e-14


@njit(cache=True)
def table_eval(x, y, cum, start, comp, t, s):
    """Evaluate table t at strain s.

    Returns (T [N/m], dT/ds [N/m], W = int_0^s T ds [N/m]). Piecewise linear between points, the
    last segment extended beyond the table; for s <= 0 zero (tension only) unless comp[t], then
    the first segment is extended to negative strain.

    x, y, cum (P,) are the packed tables' strains, tensions [N/m] and integrals of T up to each
    point [N/m]; start (T+1,) their offsets; comp (T,) 1 where a table takes compression.
    ``forces_and_energy``, ``node_force``, ``solvers.newton.settle.node_spring_block`` and
    ``solvers.newton.linalg._assemble`` repeat this lookup inline (for speed: see there); a
    change here must be made there too
    (tests/test_kernel_lookup.py checks they agree).
    """
    a = start[t]
    b = start[t + 1]
    if s <= 0.0:
        if comp[t] == 0:
            return 0.0, 0.0, 0.0
        k0 = (y[a + 1] - y[a]) / (x[a + 1] - x[a])
        return y[a] + k0 * s, k0, y[a] * s + 0.5 * k0 * s * s
    # find segment m with x[m] <= s < x[m+1]; the last segment is extended beyond
    m = a
    while m < b - 2 and s >= x[m + 1]:
        m += 1
    k = (y[m + 1] - y[m]) / (x[m + 1] - x[m])
    ds = s - x[m]
    return y[m] + k * ds, k, cum[m] + y[m] * ds + 0.5 * k * ds * ds


@njit(cache=True)
def first_slope(x, y, start, t):
    """Slope of table t's first segment [N/m per unit strain] (the stiffness a Newton matrix uses
    at the strain-0 kink, where a tension-only spring's own tangent is 0)."""
    a = start[t]
    return (y[a + 1] - y[a]) / (x[a + 1] - x[a])


@njit(cache=True, inline="always")
def spring_vector(pos, a, b):
    """(dx, dy, dz, l): the vector x_b - x_a of rows a and b of pos (N,3) and its length [m],
    with scalar indexing (the loop kernels' prologue; no array views, which cost a reference
    count each)."""
    dx = pos[b, 0] - pos[a, 0]
    dy = pos[b, 1] - pos[a, 1]
    dz = pos[b, 2] - pos[a, 2]
    return dx, dy, dz, math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def spring_eval(pa, pb, l0, w, x, y, cum, start, comp, t):
    """One spring: returns (fx, fy, fz, energy, T, dT, l) where f [N] is the force on node a
    (towards b when in tension), energy [J], T the tension [N/m], dT its strain derivative and
    l the current length [m]. (The per-spring reference; the loop kernels below write the same
    math out with scalars, which measured 2.5x faster than calling this per spring.)"""
    dx = pb[0] - pa[0]
    dy = pb[1] - pa[1]
    dz = pb[2] - pa[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    T, dT, W = table_eval(x, y, cum, start, comp, t, length / l0 - 1.0)
    energy = w * l0 * W
    if length < LENGTH_EPS:
        return 0.0, 0.0, 0.0, energy, T, dT, length
    f = T * w / length
    return f * dx, f * dy, f * dz, energy, T, dT, length


@njit(cache=True, error_model="numpy")
def forces_and_energy(pos, spring_nodes, rest, width, table, x, y, cum, start, comp, ext, out):
    """All spring forces plus the constant external force ext (N,3) [N] (gravity), into out (N,3).

    pos (N,3) [m]; spring_nodes (S,2) node indices; rest (S,) [m] and width (S,) [m] per spring;
    table (S,) the spring's table in the pack (x, y, cum, start, comp) that ``table_eval`` reads.
    Returns the total potential energy [J] (springs minus ext . pos).

    The table lookup is ``table_eval`` written out in the loop (same operations in the same
    order, so the same bits): a call to a function that takes arrays and branches costs numba
    reference-count operations on each array per spring, which it cannot prune across the
    branches, and made this loop 5-6x slower than the lookup itself. A slack tension-only spring
    (strain <= 0) adds no force and no energy and is skipped. ``error_model="numpy"`` drops the
    division-by-zero checks (no division here can be by zero: rest lengths and table steps are
    positive, lengths are tested against LENGTH_EPS)."""
    energy = 0.0
    for k in range(pos.shape[0]):
        out[k, 0] = ext[k, 0]
        out[k, 1] = ext[k, 1]
        out[k, 2] = ext[k, 2]
        energy -= ext[k, 0] * pos[k, 0] + ext[k, 1] * pos[k, 1] + ext[k, 2] * pos[k, 2]
    for s in range(spring_nodes.shape[0]):
        a = spring_nodes[s, 0]
        b = spring_nodes[s, 1]
        dx, dy, dz, length = spring_vector(pos, a, b)
        l0 = rest[s]
        strain = length / l0 - 1.0
        t = table[s]
        m = start[t]
        if strain <= 0.0:
            if comp[t] == 0:
                continue  # slack: T = W = 0
            k0 = (y[m + 1] - y[m]) / (x[m + 1] - x[m])
            T = y[m] + k0 * strain
            W = y[m] * strain + 0.5 * k0 * strain * strain
        else:
            end = start[t + 1] - 2
            while m < end and strain >= x[m + 1]:
                m += 1
            k1 = (y[m + 1] - y[m]) / (x[m + 1] - x[m])
            ds = strain - x[m]
            T = y[m] + k1 * ds
            W = cum[m] + y[m] * ds + 0.5 * k1 * ds * ds
        energy += width[s] * l0 * W
        if length < LENGTH_EPS:
            continue
        f = T * width[s] / length
        out[a, 0] += f * dx
        out[a, 1] += f * dy
        out[a, 2] += f * dz
        out[b, 0] -= f * dx
        out[b, 1] -= f * dy
        out[b, 2] -= f * dz
    return energy


@njit(cache=True)
def spring_strains_tensions(pos, spring_nodes, rest, width, table, x, y, cum, start, comp, strain_out, force_out):
    """Per-spring engineering strain and axial force [N] (tension positive, 0 when slack)."""
    for s in range(spring_nodes.shape[0]):
        length = spring_vector(pos, spring_nodes[s, 0], spring_nodes[s, 1])[3]
        strain = length / rest[s] - 1.0
        strain_out[s] = strain
        force_out[s] = table_eval(x, y, cum, start, comp, table[s], strain)[0] * width[s]


@njit(cache=True, error_model="numpy")
def node_force(k, pos, ptr, nbr, sid, rest, width, table, x, y, cum, start, comp, ext, out):
    """Resultant R (paper eq. 3) at node k from its own springs plus ext[k], into out (3,) [N].

    ptr (N+1,), nbr and sid: node k's neighbours nbr[ptr[k]:ptr[k+1]] through springs sid;
    the other arrays as in ``forces_and_energy``. Returns the sum of the elongations d = l - l0
    [m] of those springs, split as (sum of positive elongations, sum of |elongations|) for the
    paper's step (eq. 4). The table lookup is written out as in ``forces_and_energy`` (same
    bits as ``table_eval``, no per-spring reference counting)."""
    r0 = ext[k, 0]
    r1 = ext[k, 1]
    r2 = ext[k, 2]
    dpos = 0.0
    dabs = 0.0
    for q in range(ptr[k], ptr[k + 1]):
        s = sid[q]
        dx, dy, dz, length = spring_vector(pos, k, nbr[q])
        l0 = rest[s]
        strain = length / l0 - 1.0
        t = table[s]
        m = start[t]
        T = 0.0
        if strain <= 0.0:
            if comp[t] != 0:
                T = y[m] + (y[m + 1] - y[m]) / (x[m + 1] - x[m]) * strain
        else:
            end = start[t + 1] - 2
            while m < end and strain >= x[m + 1]:
                m += 1
            T = y[m] + (y[m + 1] - y[m]) / (x[m + 1] - x[m]) * (strain - x[m])
        if length >= LENGTH_EPS:
            f = T * width[s] / length
            r0 += f * dx
            r1 += f * dy
            r2 += f * dz
        d = length - l0
        if d > 0.0:
            dpos += d
        dabs += abs(d)
    out[0] = r0
    out[1] = r1
    out[2] = r2
    return dpos, dabs


@njit(cache=True)
def spring_hessian_block(pa, pb, l0, w, x, y, cum, start, comp, t, kink_stiffness, out):
    """3x3 stiffness block K = -d(f_b)/d(x_b) of one spring (positive semi-definite), f_b the
    force on node b.

    K = (w/l0) T'(s) u u^T + (w T / l) (I - u u^T). The transverse term is clamped at >= 0
    (compressed springs would make K indefinite); at and below strain 0 a tension-only spring has
    T' = 0, and ``kink_stiffness`` (>= 0, [N/m]) is used instead for s in (-inf, 0] when > 0 (this
    regularises the singular matrix at the undeformed state; it only changes the search direction,
    never the forces or the residual)."""
    dx = pb[0] - pa[0]
    dy = pb[1] - pa[1]
    dz = pb[2] - pa[2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    for i in range(3):
        for j in range(3):
            out[i, j] = 0.0
    if length < LENGTH_EPS:
        return
    s = length / l0 - 1.0
    T, dT, W = table_eval(x, y, cum, start, comp, t, s)
    if s <= 0.0 and comp[t] == 0 and kink_stiffness > 0.0:
        dT = kink_stiffness
    u0 = dx / length
    u1 = dy / length
    u2 = dz / length
    u = (u0, u1, u2)
    ka = w / l0 * dT
    kt = w * T / length
    if kt < 0.0:
        kt = 0.0
    for i in range(3):
        for j in range(3):
            out[i, j] = (ka - kt) * u[i] * u[j]
        out[i, i] += kt


# -- seam elements: seams of unequal node counts --------------------------------------------------
#
# A seam element q is a gap g_q = sum_i weight[q, i] x_{nodes[q, i]} [m], a fixed linear
# combination of K node positions whose weights sum to 0 (so a rigid translation leaves it
# unchanged), with energy E_q = k_q |g_q|^2 / 2 [J] (the law of the zero-length seam springs).
# The force on node nodes[q, i] is -k_q weight[q, i] g_q [N] and the Hessian block of the pair
# (i, j) is k_q weight[q, i] weight[q, j] I [N/m] (constant, positive semi-definite): both exact
# derivatives of E. clothsim.selection.arc_elements builds them (one per node of the denser
# side: its hat-weighted gap to the other side along arc length); unused columns of a row
# repeat its first node with weight 0.


@njit(cache=True, inline="always")
def _seam_gap(pos, nodes, weight, q):
    """The gap g_q = sum_i weight[q, i] pos[nodes[q, i]] [m] of seam element q, as (g0, g1, g2)."""
    g0 = 0.0
    g1 = 0.0
    g2 = 0.0
    for i in range(nodes.shape[1]):
        n = nodes[q, i]
        w = weight[q, i]
        g0 += w * pos[n, 0]
        g1 += w * pos[n, 1]
        g2 += w * pos[n, 2]
    return g0, g1, g2


@njit(cache=True, error_model="numpy")
def seam_forces_and_energy(pos, nodes, weight, k, out):
    """Adds every seam element's force into out (N,3) [N]; returns their energy [J].

    pos (N,3) [m]; nodes (Q,K) int64; weight (Q,K) the gap's coefficients; k (Q,) stiffness
    [N/m]. E_q = k_q |g_q|^2 / 2, g_q = sum_i weight[q, i] pos[nodes[q, i]]."""
    energy = 0.0
    for q in range(nodes.shape[0]):
        g0, g1, g2 = _seam_gap(pos, nodes, weight, q)
        kq = k[q]
        energy += 0.5 * kq * (g0 * g0 + g1 * g1 + g2 * g2)
        for i in range(nodes.shape[1]):
            n = nodes[q, i]
            c = kq * weight[q, i]
            out[n, 0] -= c * g0
            out[n, 1] -= c * g1
            out[n, 2] -= c * g2
    return energy


@njit(cache=True)
def seam_gaps(pos, nodes, weight, out):
    """|g_q| [m] of every seam element into out (Q,): how far its node is from the point of the
    other side it is sewn to (arrays as in ``seam_forces_and_energy``)."""
    for q in range(nodes.shape[0]):
        g0, g1, g2 = _seam_gap(pos, nodes, weight, q)
        out[q] = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)


@njit(cache=True, error_model="numpy")
def seam_node_force(k, pos, ptr, elem, nodes, weight, stiff, out):
    """Adds the seam elements' force on node k into out (3,) [N] (the paper's per-node resultant);
    ptr (N+1,), elem: the elements touching node k are elem[ptr[k]:ptr[k+1]] (see
    ``clothsim.lattice.seam_adjacency``). Returns the sum of |weight_k| |g| over them [m] (the
    node's 'elongation' in the paper's step, eq. 4)."""
    d = 0.0
    for p in range(ptr[k], ptr[k + 1]):
        q = elem[p]
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        wk = 0.0
        for i in range(nodes.shape[1]):
            n = nodes[q, i]
            w = weight[q, i]
            g0 += w * pos[n, 0]
            g1 += w * pos[n, 1]
            g2 += w * pos[n, 2]
            if n == k:
                wk += w
        c = stiff[q] * wk
        out[0] -= c * g0
        out[1] -= c * g1
        out[2] -= c * g2
        d += abs(wk) * math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    return d


@njit(cache=True)
def seam_assemble(nodes, weight, k, slot, data):
    """Adds the seam elements' Hessian blocks k_q w_i w_j I [N/m] into the BSR data (nb,3,3).

    slot (Q,K*K): the block slot of node pair (nodes[q, i], nodes[q, j]) at slot[q, K i + j]."""
    m = nodes.shape[1]
    for q in range(nodes.shape[0]):
        for i in range(m):
            for j in range(m):
                c = k[q] * weight[q, i] * weight[q, j]
                s = slot[q, m * i + j]
                data[s, 0, 0] += c
                data[s, 1, 1] += c
                data[s, 2, 2] += c


@njit(cache=True)
def seam_slots(indptr, indices, nodes):
    """(Q,K*K) int64: the BSR block slot of node pair (nodes[q, i], nodes[q, j]) at [q, K i + j]
    (for ``seam_assemble``); indptr (n+1,), indices (nb,) a pattern holding those pairs, with
    sorted columns per row. A missing block raises."""
    m = nodes.shape[1]
    out = np.empty((nodes.shape[0], m * m), np.int64)
    for q in range(nodes.shape[0]):
        for i in range(m):
            r = nodes[q, i]
            for j in range(m):
                c = nodes[q, j]
                lo = indptr[r]
                hi = indptr[r + 1]
                while lo < hi:
                    mid = (lo + hi) // 2
                    if indices[mid] < c:
                        lo = mid + 1
                    else:
                        hi = mid
                if lo >= indptr[r + 1] or indices[lo] != c:
                    raise ValueError("seam_slots: block missing from the pattern")
                out[q, m * i + j] = lo
    return out
