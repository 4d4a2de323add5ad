"""Contact and residual kernels shared by every solver (numba, pure functions of arrays).

The residual is the paper's eq. (6): V_k = |R_k| for a free node and |R*_k| for a contact node,
with constrained axes removed. For a contact node we use the general form of "tangential part":
the distance from R to the cone of admissible reactions' opposites, ``-cone(n_1..n_m)``, where
n_i are the outward normals of the faces at the contact feature (one on a face interior: then the
distance is |R - (R.n) n| when R pushes into the mold and |R| when it pulls away; two at an edge;
the ring at a vertex). A node in a groove can so rest with its reaction anywhere in the cone of
the adjacent face normals, and a node on a face behaves exactly as the paper says.

``margs`` everywhere is the mold's :class:`clothsim.mold.MoldArgs` (``Mold.kernel_args()``), a
named tuple of arrays read by field name; ``has_mold`` False means it is a stand-in never queried.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .mold import mold_contact_normals, mold_query, mold_segment_hit
from .mold.queries import is_primitive, primitive_contact_normals, primitive_query

MAX_FEATURE_NORMALS = 64


@njit(cache=True)
def _norm3(a0, a1, a2):
    return math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)


@njit(cache=True)
def _wedge(R, normals, i, j):
    """Least-squares coefficients (la, lb) of R on the generators -n_i, -n_j, and the Gram
    determinant (<= 1e-14: the two normals are parallel)."""
    a0, a1, a2 = -normals[i, 0], -normals[i, 1], -normals[i, 2]
    b0, b1, b2 = -normals[j, 0], -normals[j, 1], -normals[j, 2]
    aa = a0 * a0 + a1 * a1 + a2 * a2
    bb = b0 * b0 + b1 * b1 + b2 * b2
    ab = a0 * b0 + a1 * b1 + a2 * b2
    ar = a0 * R[0] + a1 * R[1] + a2 * R[2]
    br = b0 * R[0] + b1 * R[1] + b2 * R[2]
    det = aa * bb - ab * ab
    if det <= 1e-14:
        return 0.0, 0.0, det
    return (bb * ar - ab * br) / det, (aa * br - ab * ar) / det, det


@njit(cache=True)
def cone_active(R, normals, m, act):
    """Active generators of the projection of R onto the cone {-sum l_i n_i, l_i >= 0}.

    Writes their indices into act and returns how many (0: R points out of the mold, release;
    1: a ray; 2: a wedge face; 3: R is inside the cone of three normals)."""
    best = math.sqrt(R[0] * R[0] + R[1] * R[1] + R[2] * R[2])
    cnt = 0
    for i in range(m):
        t = -(R[0] * normals[i, 0] + R[1] * normals[i, 1] + R[2] * normals[i, 2])
        if t > 0.0:
            d0 = R[0] + t * normals[i, 0]
            d1 = R[1] + t * normals[i, 1]
            d2 = R[2] + t * normals[i, 2]
            d = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if d < best:
                best = d
                cnt = 1
                act[0] = i
    for i in range(m):
        for j in range(i + 1, m):
            la, lb, det = _wedge(R, normals, i, j)
            if det <= 1e-14:
                continue
            if la > 0.0 and lb > 0.0:
                d0 = R[0] + la * normals[i, 0] + lb * normals[j, 0]
                d1 = R[1] + la * normals[i, 1] + lb * normals[j, 1]
                d2 = R[2] + la * normals[i, 2] + lb * normals[j, 2]
                d = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                if d < best * (1.0 - 1e-12):
                    best = d
                    cnt = 2
                    act[0] = i
                    act[1] = j
    if m >= 3 and best > 0.0:
        for i in range(m):
            for j in range(i + 1, m):
                for k in range(j + 1, m):
                    a0, a1, a2 = -normals[i, 0], -normals[i, 1], -normals[i, 2]
                    b0, b1, b2 = -normals[j, 0], -normals[j, 1], -normals[j, 2]
                    c0, c1, c2 = -normals[k, 0], -normals[k, 1], -normals[k, 2]
                    det = a0 * (b1 * c2 - b2 * c1) - b0 * (a1 * c2 - a2 * c1) + c0 * (a1 * b2 - a2 * b1)
                    if abs(det) < 1e-12:
                        continue
                    r0, r1, r2 = R[0], R[1], R[2]
                    l1 = (r0 * (b1 * c2 - b2 * c1) - b0 * (r1 * c2 - r2 * c1) + c0 * (r1 * b2 - r2 * b1)) / det
                    l2 = (a0 * (r1 * c2 - r2 * c1) - r0 * (a1 * c2 - a2 * c1) + c0 * (a1 * r2 - a2 * r1)) / det
                    l3 = (a0 * (b1 * r2 - b2 * r1) - b0 * (a1 * r2 - a2 * r1) + r0 * (a1 * b2 - a2 * b1)) / det
                    if l1 >= 0.0 and l2 >= 0.0 and l3 >= 0.0:
                        act[0] = i
                        act[1] = j
                        act[2] = k
                        return 3
    return cnt


@njit(cache=True)
def cone_distance(R, normals, m):
    """Distance from the vector R (3,) to the cone {-sum(l_i n_i), l_i >= 0} of the first m rows of
    normals (unit vectors): the contact residual of eq. (6) generalised to edges and vertices. The
    projection onto a polyhedral cone in 3-D lies on the origin, a ray or a 2-D face spanned by two
    generators, or R is inside (then 0); :func:`cone_active` says which."""
    act = np.empty(3, np.int64)
    cnt = cone_active(R, normals, m, act)
    if cnt == 0:
        return _norm3(R[0], R[1], R[2])
    if cnt == 3:
        return 0.0
    # least-squares residual of R + sum l_i n_i over the active generators
    if cnt == 1:
        i = act[0]
        t = -(R[0] * normals[i, 0] + R[1] * normals[i, 1] + R[2] * normals[i, 2])
        return _norm3(R[0] + t * normals[i, 0], R[1] + t * normals[i, 1], R[2] + t * normals[i, 2])
    i, j = act[0], act[1]
    la, lb, det = _wedge(R, normals, i, j)
    return _norm3(R[0] + la * normals[i, 0] + lb * normals[j, 0], R[1] + la * normals[i, 1] + lb * normals[j, 1],
                  R[2] + la * normals[i, 2] + lb * normals[j, 2])


@njit(cache=True)
def stop_at_surface(margs, p0, p, fixed_row):
    """Cut the move p0 -> p (p (3,) in place, free axes only) where it first enters the mold
    (paper 3.2.2: a free node's move that would cross the surface stops on it). Returns True
    when it does."""
    return cut_move(p0, p, fixed_row, mold_segment_hit(margs, p0, p))


@njit(cache=True)
def cut_move(p0, p, fixed_row, t):
    """Cut the move p0 -> p (p (3,) [m] in place, free axes only) at the share t of it where it
    first enters the mold (t < 0: it does not, p is left alone). Returns True when it is cut."""
    if t < 0.0:
        return False
    for a in range(3):
        if not fixed_row[a]:
            p[a] = p0[a] + t * (p[a] - p0[a])
    return True


@njit(cache=True)
def free_axis_normals(fixed_row, nbuf, m):
    """Restrict the first m contact normals to a node's free axes, in place: a constrained axis
    takes any reaction along it, so only the normals' free components (renormalised) bound the
    reaction the mold adds there. A normal lying along constrained axes only becomes 0 (it then
    takes part in no cone). The cone's generators change length, not the cone itself."""
    if not (fixed_row[0] or fixed_row[1] or fixed_row[2]):
        return
    for i in range(m):
        for a in range(3):
            if fixed_row[a]:
                nbuf[i, a] = 0.0
        nn = _norm3(nbuf[i, 0], nbuf[i, 1], nbuf[i, 2])
        for a in range(3):
            nbuf[i, a] = nbuf[i, a] / nn if nn > 1e-12 else 0.0


@njit(cache=True)
def node_residual(R, fixed_row, contact, p, has_mold, margs, qbuf, nbuf):
    """V_k (eq. 6) for one node with resultant R (3,) (modified: constrained axes zeroed): |R| on
    a free node; on a contact node the distance from R to the reactions the mold and the
    constraints can supply together (the cone of the contact normals plus any force along the
    constrained axes)."""
    for a in range(3):
        if fixed_row[a]:
            R[a] = 0.0
    if not contact or not has_mold:
        return _norm3(R[0], R[1], R[2])
    m = mold_contact_normals(margs, p, qbuf, nbuf)
    free_axis_normals(fixed_row, nbuf, m)
    return cone_distance(R, nbuf, m)


@njit(cache=True)
def residual_from_forces(pos, F, fixed, in_contact, has_mold, margs, V):
    """Fill V (N,) with eq. (6)'s entries from the nodal resultants F (N,3): constrained axes
    removed, the cone distance at contact nodes. Returns ||V||_inf (nan if any entry is not
    finite)."""
    R = np.empty(3)
    qbuf = np.empty(8)
    nbuf = np.empty((MAX_FEATURE_NORMALS, 3))
    vmax = 0.0
    kind = margs.info[0]
    prim = is_primitive(kind)
    prm = margs.params
    for k in range(pos.shape[0]):
        if in_contact[k] and has_mold:
            R[0] = F[k, 0]
            R[1] = F[k, 1]
            R[2] = F[k, 2]
            if prim:
                # node_residual's contact case from (kind, prm) (see queries.is_primitive): the
                # same steps; change both together (tests/test_contact.py compares them)
                for a in range(3):
                    if fixed[k, a]:
                        R[a] = 0.0
                primitive_query(kind, prm, pos[k, 0], pos[k, 1], pos[k, 2], qbuf)
                m = primitive_contact_normals(kind, prm, qbuf, nbuf)
                free_axis_normals(fixed[k], nbuf, m)
                v = cone_distance(R, nbuf, m)
            else:
                v = node_residual(R, fixed[k], True, pos[k], has_mold, margs, qbuf, nbuf)
        else:
            # a free node: |R| over its free axes (node_residual's first case, without the
            # array views that cost a reference count each)
            r0 = 0.0 if fixed[k, 0] else F[k, 0]
            r1 = 0.0 if fixed[k, 1] else F[k, 1]
            r2 = 0.0 if fixed[k, 2] else F[k, 2]
            v = _norm3(r0, r1, r2)
        V[k] = v
        if not (v <= vmax):
            if math.isnan(v):
                return math.nan
            vmax = v
    return vmax


@njit(cache=True)
def max_penetration(pos, margs):
    """Deepest penetration [m] of any node into the mold (0 if none)."""
    q = np.empty(8)
    worst = 0.0
    for k in range(pos.shape[0]):
        sd = mold_query(margs, pos[k], q)
        if -sd > worst:
            worst = -sd
    return worst


# ----------------------------------------------------------------------------- friction
# Coulomb friction as a lagged, smoothed dissipation potential per load step (Incremental
# Potential Contact's form): node k slides u = P_k (x_k - a_k) from its anchor a_k (its position
# at the previous load step's equilibrium) in the tangent plane P_k = I - n_k n_k^T of a frozen
# normal n_k, and carries D_k = w_k f0(|u|) with w_k = mu lam_k (lam_k the frozen normal force
# [N]); f0 is |u| above the slip eps and the C1 cubic -y^3/(3 eps^2) + y^2/eps + eps/3 below it,
# so the force -w_k f1(|u|) u/|u| has magnitude mu lam_k once the node slips (|u| >= eps) and less
# while it sticks. D is convex in x (Li M. et al., Incremental Potential Contact, ACM Trans.
# Graph. 39 (4), 2020, section 5).


@njit(cache=True)
def _friction_u(pos, k, anchor, normal, i):
    """(u0, u1, u2, |u|): the tangential slide of node k (friction row i) from its anchor [m]."""
    d0 = pos[k, 0] - anchor[i, 0]
    d1 = pos[k, 1] - anchor[i, 1]
    d2 = pos[k, 2] - anchor[i, 2]
    dn = d0 * normal[i, 0] + d1 * normal[i, 1] + d2 * normal[i, 2]
    u0 = d0 - dn * normal[i, 0]
    u1 = d1 - dn * normal[i, 1]
    u2 = d2 - dn * normal[i, 2]
    return u0, u1, u2, _norm3(u0, u1, u2)


@njit(cache=True)
def friction_forces_energy(pos, nodes, anchor, normal, weight, eps, out):
    """Add the friction forces [N] of the nodes ``nodes`` (m,) to out (N, 3) and return their
    dissipation potential [J]. anchor (m, 3) [m], normal (m, 3) unit, weight (m,) = mu lam [N],
    eps the slip below which a node sticks [m] (see the section's comment)."""
    e = 0.0
    for i in range(nodes.shape[0]):
        w = weight[i]
        if w == 0.0:
            continue
        k = nodes[i]
        u0, u1, u2, y = _friction_u(pos, k, anchor, normal, i)
        if y < eps:
            f0 = -y * y * y / (3.0 * eps * eps) + y * y / eps + eps / 3.0
            c = 2.0 / eps - y / (eps * eps)
        else:
            f0 = y
            c = 1.0 / y
        e += w * f0
        out[k, 0] -= w * c * u0
        out[k, 1] -= w * c * u1
        out[k, 2] -= w * c * u2
    return e


@njit(cache=True)
def friction_hessian_block(u0, u1, u2, y, n, w, eps, H):
    """The 3x3 Hessian H [N/m] of one node's w f0(|u|), u = (I - n n^T)(x - a) with |u| = y:
    w ((f1/y) P + (f1' - f1/y)/y^2 u u^T), positive semi-definite."""
    if y < eps:
        c = 2.0 / eps - y / (eps * eps)
        b = -1.0 / (eps * eps * y) if y > 0.0 else 0.0
    else:
        c = 1.0 / y
        b = -1.0 / (y * y * y)
    u = (u0, u1, u2)
    for a in range(3):
        for bb in range(3):
            p = (1.0 if a == bb else 0.0) - n[a] * n[bb]
            H[a, bb] = w * (c * p + b * u[a] * u[bb])


@njit(cache=True)
def friction_assemble(pos, nodes, anchor, normal, weight, eps, diag, K):
    """Add each friction node's Hessian block to its diagonal block K[diag[k]] (BSR blocks)."""
    H = np.empty((3, 3))
    for i in range(nodes.shape[0]):
        w = weight[i]
        if w == 0.0:
            continue
        k = nodes[i]
        u0, u1, u2, y = _friction_u(pos, k, anchor, normal, i)
        friction_hessian_block(u0, u1, u2, y, normal[i], w, eps, H)
        q = diag[k]
        for a in range(3):
            for b in range(3):
                K[q, a, b] += H[a, b]
