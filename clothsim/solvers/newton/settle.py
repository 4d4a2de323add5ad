"""Contact-rim settlement of an interpolated start (grid sequencing): node-wise projected Newton
(nonlinear Gauss-Seidel) on the nodes near the contact rim, so that the fine grid's first Newton
iteration starts from nearly the contact set of its solution.

Why: the interpolation of a coarse solution marks as contact every fine node whose coarse parents
are all in contact, or that the interpolation puts inside the mold. At the rim some of those are
free at the fine solution. The active set releases a contact node when its resultant points out
of the mold, but a node whose outer neighbour is still held has its resultant pointing in: the
rim then peels one ring of nodes per Newton iteration (on the 201^2 sphere cap, 64 -> 16 -> 0
wrong nodes in the first two fine iterations, each ~110 work units). Here each rim node in turn
is moved to the minimum of the energy with its neighbours held (one 3x3 Newton step), released
when its resultant points out of the mold (the active set's own rule), and stopped on the
surface (becoming a contact node) when its move would enter it. A few sweeps over a band a few
nodes wide around the rim settle it at a cost of a few per cent of one force pass per sweep.

Shapes: n nodes, S springs; positions (n, 3) [m]; forces [N]; stiffnesses [N/m].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...contact import MAX_FEATURE_NORMALS, cone_active, cut_move, free_axis_normals, stop_at_surface
from ...kernels import LENGTH_EPS, first_slope
from ...mold.queries import contact_normals_at, is_primitive, query_at
from ...mold.segment import primitive_segment_hit
from ..common import model_mold_args
from .active_set import held_axis_rows, orthonormal_rows

from ..tuning import NewtonTuning

# band half-width around the rim and the sweeps over it: NewtonTuning.settle_width, .settle_sweeps


@njit(cache=True)
def contact_rim_band(contact, ptr, oth, width):
    """Nodes within ``width`` spring hops of the contact rim (a contact node with a free
    neighbour, or a free node with a contact neighbour), in node order; int64 (m,)."""
    n = contact.shape[0]
    dist = np.full(n, width + 1, np.int64)
    front = np.empty(n, np.int64)
    nf = 0
    for k in range(n):
        for e in range(ptr[k], ptr[k + 1]):
            if contact[oth[e]] != contact[k]:
                dist[k] = 0
                front[nf] = k
                nf += 1
                break
    nxt = np.empty(n, np.int64)
    for d in range(1, width + 1):
        nn = 0
        for t in range(nf):
            k = front[t]
            for e in range(ptr[k], ptr[k + 1]):
                j = oth[e]
                if dist[j] > d:
                    dist[j] = d
                    nxt[nn] = j
                    nn += 1
        front[:nn] = nxt[:nn]
        nf = nn
    m = 0
    for k in range(n):
        if dist[k] <= width:
            m += 1
    out = np.empty(m, np.int64)
    m = 0
    for k in range(n):
        if dist[k] <= width:
            out[m] = k
            m += 1
    return out


@njit(cache=True)
def _solve3(H, f, out):
    """out = H^{-1} f for a symmetric 3x3 H (Cramer); False when singular."""
    a, b, c = H[0, 0], H[0, 1], H[0, 2]
    d, e, g = H[1, 1], H[1, 2], H[2, 2]
    c00 = d * g - e * e
    c01 = c * e - b * g
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    tr = a + d + g
    if not (abs(det) > 1e-14 * tr * tr * tr) or not math.isfinite(det):
        return False
    c11 = a * g - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    out[0] = (c00 * f[0] + c01 * f[1] + c02 * f[2]) / det
    out[1] = (c01 * f[0] + c11 * f[1] + c12 * f[2]) / det
    out[2] = (c02 * f[0] + c12 * f[1] + c22 * f[2]) / det
    return True


@njit(cache=True, error_model="numpy")
def node_spring_block(k, pos, ptr, sp, oth, rest, width, table, x, y, cum, start, comp, kink, ext, f, H):
    """Node k's resultant f (3,) [N] (its springs' forces plus ext[k]) and the sum H (3, 3) [N/m]
    of its springs' stiffness blocks (``kernels.spring_hessian_block``; a slack tension-only
    spring at its kink stiffness kink (S,) [N/m], as the Newton matrix has it), its neighbours
    held; both written in place. ptr, oth, sp: the node adjacency (``Model.adj_ptr``,
    ``adj_node``, ``adj_spring``); the spring and table arrays as in ``kernels.forces_and_energy``.
    Returns the shortest rest length [m] of its springs.

    The table lookup is ``kernels.table_eval``'s, inline and without the energy (a call per
    spring was a third of this kernel's time), and each length is divided once (its reciprocal
    multiplied): 355 -> 203 ns a node update of the circle's outline band (four springs)."""
    f0 = ext[k, 0]
    f1 = ext[k, 1]
    f2 = ext[k, 2]
    h00 = 0.0
    h11 = 0.0
    h22 = 0.0
    h01 = 0.0
    h02 = 0.0
    h12 = 0.0
    p0 = pos[k, 0]
    p1 = pos[k, 1]
    p2 = pos[k, 2]
    lmin = 1e300
    for e in range(ptr[k], ptr[k + 1]):
        s = sp[e]
        j = oth[e]
        d0 = pos[j, 0] - p0
        d1 = pos[j, 1] - p1
        d2 = pos[j, 2] - p2
        l0 = rest[s]
        if l0 < lmin:
            lmin = l0
        length = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if length < LENGTH_EPS:
            continue
        w = width[s]
        tb = table[s]
        st = length / l0 - 1.0
        a = start[tb]
        if st <= 0.0:
            if comp[tb] == 0:
                T = 0.0
                dT = kink[s] if kink[s] > 0.0 else 0.0
            else:
                dT = (y[a + 1] - y[a]) / (x[a + 1] - x[a])
                T = y[a] + dT * st
        else:
            m = a
            b = start[tb + 1]
            while m < b - 2 and st >= x[m + 1]:
                m += 1
            dT = (y[m + 1] - y[m]) / (x[m + 1] - x[m])
            T = y[m] + dT * (st - x[m])
        inv = 1.0 / length
        kt = w * T * inv
        f0 += kt * d0
        f1 += kt * d1
        f2 += kt * d2
        u0 = d0 * inv
        u1 = d1 * inv
        u2 = d2 * inv
        ka = w / l0 * dT
        if kt < 0.0:
            kt = 0.0
        kd = ka - kt
        h00 += kd * u0 * u0 + kt
        h11 += kd * u1 * u1 + kt
        h22 += kd * u2 * u2 + kt
        h01 += kd * u0 * u1
        h02 += kd * u0 * u2
        h12 += kd * u1 * u2
    f[0] = f0
    f[1] = f1
    f[2] = f2
    H[0, 0] = h00
    H[1, 1] = h11
    H[2, 2] = h22
    H[0, 1] = h01
    H[0, 2] = h02
    H[1, 2] = h12
    H[1, 0] = h01
    H[2, 0] = h02
    H[2, 1] = h12
    return lmin


def spring_kinks(model, kink: float) -> np.ndarray:
    """(S,) [N/m]: each spring's kink stiffness, ``kink`` (NewtonOptions.kink) times its table's
    first slope, as NewtonLevel has them (zeros when kink is 0)."""
    if not kink > 0:
        return np.zeros(model.spring_count)
    t = model.tables
    slopes = np.array([kink * first_slope(t.x, t.y, t.start, int(tb)) for tb in range(len(t.start) - 1)])
    return np.ascontiguousarray(slopes[model.spring_table], float)


@njit(cache=True)
def settle_contact_rim(pos, contact, fixed, ext, band, ptr, sp, oth, rest, width, table, x, y, cum, start, comp, kink,
               margs, sweeps):
    """``sweeps`` Gauss-Seidel sweeps over the nodes ``band`` (int64 (m,)): each node's 3x3
    Newton step for its springs' energy with its neighbours held (slack tension-only springs at
    the kink stiffness kink (S,) [N/m], as the Newton matrix has them); a contact node is
    released when its resultant points out of the mold (``cone_active``), else it moves in the
    tangent space of its active normals and is put back on the surface; a free node's move stops
    on the surface, where it becomes a contact node. pos, contact changed in place. Returns the
    number of contact changes in the last sweep."""
    f = np.empty(3)
    R = np.empty(3)
    H = np.empty((3, 3))
    A = np.empty((3, 3))
    dx = np.empty(3)
    p = np.empty(3)
    q = np.empty(8)
    nbuf = np.empty((MAX_FEATURE_NORMALS, 3))
    act = np.empty(3, np.int64)
    Q = np.empty((3, 3))
    Hp = np.empty((3, 3))
    changes = 0
    kind = margs.info[0]
    prim = is_primitive(kind)
    prm = margs.params
    for sweep in range(sweeps):
        changes = 0
        for t in range(band.shape[0]):
            k = band[t]
            if fixed[k, 0] and fixed[k, 1] and fixed[k, 2]:
                continue
            node_spring_block(k, pos, ptr, sp, oth, rest, width, table, x, y, cum, start, comp, kink, ext, f, H)
            # constraint directions: held axes, then the active contact normals
            nq = held_axis_rows(fixed, k, Q)
            if contact[k]:
                query_at(prim, kind, prm, margs, pos[k], q)
                for a in range(3):
                    R[a] = 0.0 if fixed[k, a] else f[a]
                m = contact_normals_at(prim, kind, prm, margs, q, nbuf)
                free_axis_normals(fixed[k], nbuf, m)
                na = cone_active(R, nbuf, m, act)
                if na == 0:
                    contact[k] = False
                    changes += 1
                else:
                    for u in range(na):
                        if nq < 3:
                            Q[nq, 0] = nbuf[act[u], 0]
                            Q[nq, 1] = nbuf[act[u], 1]
                            Q[nq, 2] = nbuf[act[u], 2]
                            nq += 1
            # orthonormalise; the step solves (P H P + (I - P)) dx = P f with P = I - sum q q^T
            kept = orthonormal_rows(Q, nq)
            if kept == 3:
                continue
            for r in range(3):
                for c in range(3):
                    P = 1.0 if r == c else 0.0
                    for z in range(kept):
                        P -= Q[z, r] * Q[z, c]
                    A[r, c] = P
            # R = P f, H' = P H P + (I - P)
            for r in range(3):
                R[r] = A[r, 0] * f[0] + A[r, 1] * f[1] + A[r, 2] * f[2]
            for r in range(3):
                for c in range(3):
                    v = 0.0
                    for a in range(3):
                        for b in range(3):
                            v += A[r, a] * H[a, b] * A[b, c]
                    Hp[r, c] = v + (1.0 if r == c else 0.0) - A[r, c]
            if not _solve3(Hp, R, dx):
                continue
            for a in range(3):
                p[a] = pos[k, a] + (0.0 if fixed[k, a] else dx[a])
            if contact[k]:
                # back onto the surface (the closest point), held axes kept
                query_at(prim, kind, prm, margs, p, q)
                for a in range(3):
                    if not fixed[k, a]:
                        pos[k, a] = q[a]
            else:
                hit = (cut_move(pos[k], p, fixed[k], primitive_segment_hit(kind, prm, pos[k], p)) if prim else
                       stop_at_surface(margs, pos[k], p, fixed[k]))
                if hit:
                    contact[k] = True
                    changes += 1
                for a in range(3):
                    pos[k, a] = p[a]
        if changes == 0:
            break
    return changes


def settle_start(model, state, kink, width=None, sweeps=None):
    """``settle_contact_rim`` on the nodes within ``width`` (default NewtonTuning.settle_width) spring hops of
    ``state``'s contact rim, ``sweeps`` (default NewtonTuning.settle_sweeps) sweeps at most; state's
    positions (n, 3) [m] and in_contact (n,) are changed in place. kink: NewtonOptions.kink
    (times each table's first slope, as in NewtonLevel). Nodes of seam elements are left out.
    Returns the contact changes of the last sweep (0: settled), or -1 without a mold."""
    has_mold, margs = model_mold_args(model)
    if not has_mold:
        return -1
    width = NewtonTuning.settle_width if width is None else width
    sweeps = NewtonTuning.settle_sweeps if sweeps is None else sweeps
    n = model.node_count
    ptr, oth, sp = model.adj_ptr, model.adj_node, model.adj_spring
    band = contact_rim_band(state.in_contact, ptr, oth, width)
    if model.seam_count:
        # a seam element's forces are not the springs': its nodes are left to Newton
        keep = np.ones(n, bool)
        keep[model.seam_nodes.ravel()] = False
        band = np.ascontiguousarray(band[keep[band]])
    t = model.tables
    kk = spring_kinks(model, kink)
    return settle_contact_rim(state.positions, state.in_contact, model.fixed_axes, model.external_force, band, ptr, sp, oth,
                      model.spring_rest_length, model.spring_width, model.spring_table, t.x, t.y, t.cum, t.start,
                      t.compression, kk, margs, sweeps)
