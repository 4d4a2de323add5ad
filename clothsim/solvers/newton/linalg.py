"""Active-set Newton on the strain energy, with a multigrid-preconditioned CG and grid sequencing.

The equilibrium the paper's relaxation seeks (eq. 6: every free node's resultant zero, contact
nodes' resultant inside the cone of their mold normals) is the constrained minimum of the total
potential energy E(x) = sum over springs of w l0 int_0^strain T(s) ds minus the external work.
E is C1 and piecewise quadratic in the strain, so Newton's method on it converges quickly once the
set of contact nodes and of taut/slack springs has settled. One iteration:

1. Active set: each contact node's resultant R (constrained axes removed) is projected onto the
   cone of its feature's face normals (contact.cone_distance's geometry). A node whose R points
   out of the mold (projection = origin, i.e. n.R > 0 on a face) is released; otherwise the
   normals carrying a positive multiplier become constraints. With the constrained axes they
   define a per-node projector Pi_k onto the directions the node may move in (3 for a free node,
   2 on a face: the tangent plane, 1 along a concave edge, 0 in a corner). A node pressed onto a
   convex edge or vertex of a mesh (R inside the cone of several normals) satisfies eq. 6 but is
   not at an energy minimum: it keeps only the face it slides down (``_ridge_face``).
   After the linear solve, a node on an edge or vertex whose step would leave the feature's
   tangent cone through an inactive face (into a groove's other face) gets that face's normal
   added and the system is solved again (``_block_infeasible``, blocking constraints): otherwise
   the projection back onto the surface bends the path at first order and no step length lowers
   the energy (the stall on the torso mesh).
2. Linear system: (Pi K Pi + mu Pi + (I - Pi)) dx = Pi f, where K = d^2E/dx^2 is assembled from
   ``kernels.spring_hessian_block`` (transverse term clamped >= 0 so K is positive semi-definite;
   at and below strain 0 the first segment's slope times ``newton_kink`` replaces the zero
   stiffness of a slack spring: this only shapes the direction, never the forces) and mu is a
   Levenberg shift (relative to the mean diagonal) raised when a step fails. Solved by conjugate
   gradients preconditioned with a geometric multigrid V-cycle: bilinear prolongation on the
   structured node grid (projected by Pi on the finest level), Galerkin coarse operators,
   symmetric 3x3-block Gauss-Seidel smoothing, a sparse LU (scipy ``splu``) on the coarsest grid.
   Small problems (<= ``DIRECT_DOFS`` unknowns) are factorised directly.
3. Line search on the energy along x + a dx with the paper's contact rules applied to every
   trial: a free node's move is clipped where it would enter the mold (``contact.stop_at_surface``) and
   it becomes a contact node; contact nodes are projected back onto the surface
   (``mold_query``); no node ever ends inside. A contact node carried past a convex edge or
   vertex into free space (its closest point is that edge or vertex and its resultant pulls it
   away from it) becomes free instead of being pulled back onto the ridge (a node pulled over a
   box's edge). On a mesh mold, when the straight trial fails, the same step with contact nodes
   stopped at their face's border (so a node whose equilibrium is on an edge lands on it) is
   tried too. Backtracking (Armijo, halving). When the energy
   difference is below float64 resolution (close to the solution) the step is accepted if it
   lowers the residual instead; when neither can be lowered even with a large Levenberg shift,
   the run stops with flag 3 (``stalled``), keeping the best state.
4. Grid sequencing (``newton_sequencing``): when the grid's divisions are even and large, the
   scene is first solved on the grid with every second node (recursively), and the result is
   interpolated bilinearly and projected onto the mold as the starting point. The coarse solves
   are one recorded iteration.

References:
- Nocedal J., Wright S., Numerical Optimization, 2nd ed., Springer 2006 (line search Newton,
  Armijo condition, Levenberg-Marquardt shift, inexact Newton forcing terms).
- Briggs W., Henson V. E., McCormick S., A Multigrid Tutorial, 2nd ed., SIAM 2000 (V-cycle,
  Galerkin coarse operators, nested iteration = grid sequencing).
- Hestenes M., Stiefel E., Methods of conjugate gradients for solving linear systems, J. Res.
  NBS 49, 1952 (preconditioned CG).
- Garcia M., Gomez M., Ruiz O., Boulanger P., "Spring-particle model for hyperelastic cloth",
  Dyna 74 (151), 2007 (the model, the residual eq. 6 and the contact rules reproduced here).

Limitations:
- The mold's curvature is not in the Hessian (contact nodes move in the tangent plane and are
  projected back), so on strongly curved molds convergence is fast-linear rather than quadratic.
- Slack regions have no unique equilibrium; Newton stops at one of them (see Result
  .undetermined_nodes()). Near springs that end exactly at strain 0 the residual can chatter;
  the residual-based acceptance keeps it converging but a few extra iterations may be needed.
- Multigrid assumes the structured warp/weft grid (it always is here); the coarse spaces ignore
  the mold, so the CG iteration count grows slowly on grids with many contact nodes.
- Grid sequencing needs even divisions; otherwise it starts directly on the fine grid.
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from numba import njit

from ...contact import MAX_FEATURE_NORMALS, cone_active, free_axis_normals, stop_at_surface
from ...contact import residual_from_forces as _residual_from_forces
from ...kernels import LENGTH_EPS, first_slope, forces_and_energy, spring_vector, table_eval
from ...mold import MOLD_MESH, mold_contact_normals, mold_query
from ..common import Driver, model_mold_args

# systems with at most this many unknowns are factorised directly (no multigrid)
DIRECT_DOFS = 6000
# multigrid: stop coarsening at this many nodes
COARSEST_NODES = 400
# after a projection onto the mold, a node may be inside by at most this [m]
PENETRATION_TOL = 1e-10
# Newton iterations without a 1 % gain in the best residual before the run counts as stalled
STALL_NEWTON = 100
# relative energy change below which the energy cannot tell two states apart
ENERGY_RESOLUTION = 1e-13
# seconds after which an iteration stops retrying with larger Levenberg shifts (flag 3)
ITERATE_BUDGET_S = 1.0
# a contact node moved farther than this [m] off the surface may leave it (see _trial_positions)
RELEASE_GAP = 1e-12


# ----------------------------------------------------------------------------------------------
# numba kernels
# ----------------------------------------------------------------------------------------------


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
        row = np.sort(cols[ptr[i]:ptr[i + 1]])
        last = -1
        for c in row:
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
    kink[s] [N/m] at and below strain 0 on tension-only springs."""
    data[:] = 0.0
    for s in range(spring_nodes.shape[0]):
        dx, dy, dz, length = spring_vector(pos, spring_nodes[s, 0], spring_nodes[s, 1])
        if length < LENGTH_EPS:
            continue
        l0 = rest[s]
        w = width[s]
        t = table[s]
        st = length / l0 - 1.0
        T, dT, W = table_eval(x, y, cum, start, comp, t, st)
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
def _project_system(indptr, indices, data, diag, Pi, mu_abs, out):
    """out = Pi K Pi + mu Pi + (I - Pi) blockwise (Pi (n,3,3) symmetric projectors)."""
    n = indptr.shape[0] - 1
    tmp = np.empty((3, 3))
    for i in range(n):
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
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
def _line_gs(indptr, indices, data, nx1, ny1, dslot, pslot, nslot, b, xv, direction, reverse):
    """Block line Gauss-Seidel: every grid line along ``direction`` (0: i varies at fixed j, the
    warp lines; 1: j varies at fixed i) is solved exactly as a 3x3-block tridiagonal system
    (block Thomas algorithm) with the other couplings taken from the current iterate. Lines
    are visited in reverse when ``reverse`` (the adjoint sweep, so that the V-cycle stays
    symmetric for CG).

    Why lines: the stiffness of a stretched membrane is anisotropic per component (axial spring
    stiffness along a yarn, only the transverse T/l across it), and point smoothers degrade
    with that ratio; exact line solves make the smoothing robust to it."""
    nlines = ny1 if direction == 0 else nx1
    length = nx1 if direction == 0 else ny1
    stride = ny1 if direction == 0 else 1
    Cm = np.empty((length, 9))
    rr = np.empty((length, 3))
    for ll in range(nlines):
        line = nlines - 1 - ll if reverse else ll
        first = line if direction == 0 else line * ny1
        # right-hand sides with the off-line couplings moved over
        for t in range(length):
            k = first + t * stride
            qp = pslot[k, direction]
            qn = nslot[k, direction]
            qd = dslot[k]
            r0 = b[3 * k]
            r1 = b[3 * k + 1]
            r2 = b[3 * k + 2]
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
        for t in range(length):
            k = first + t * stride
            qd = dslot[k]
            d00 = data[qd, 0, 0]; d01 = data[qd, 0, 1]; d02 = data[qd, 0, 2]
            d10 = data[qd, 1, 0]; d11 = data[qd, 1, 1]; d12 = data[qd, 1, 2]
            d20 = data[qd, 2, 0]; d21 = data[qd, 2, 1]; d22 = data[qd, 2, 2]
            r0 = rr[t, 0]
            r1 = rr[t, 1]
            r2 = rr[t, 2]
            ql = pslot[k, direction]
            if t > 0 and ql >= 0:
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
            if t < length - 1 and qu >= 0:
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
        for tt in range(length):
            t = length - 1 - tt
            if t < length - 1:
                C = Cm[t]
                n0 = rr[t + 1, 0]
                n1 = rr[t + 1, 1]
                n2 = rr[t + 1, 2]
                rr[t, 0] -= C[0] * n0 + C[1] * n1 + C[2] * n2
                rr[t, 1] -= C[3] * n0 + C[4] * n1 + C[5] * n2
                rr[t, 2] -= C[6] * n0 + C[7] * n1 + C[8] * n2
            k = first + t * stride
            xv[3 * k] = rr[t, 0]
            xv[3 * k + 1] = rr[t, 1]
            xv[3 * k + 2] = rr[t, 2]


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
def _ridge_face(x, R, normals, m, margs, probe, act, na):
    """A node pressed onto a convex edge or vertex (its resultant inside the cone of several face
    normals) satisfies eq. 6 but is not at a minimum of the energy: sliding down one of the
    faces lowers it (the springs cut the corner). Among the faces it presses on (R.n_i < 0), the
    one whose tangential pull R - (R.n_i) n_i is largest (ties to the first) and leads along the surface (a probe
    point a short way along it is not inside the mold: not a groove) becomes the only active
    constraint (act[0] = i, returns 1). Otherwise (groove, or no such face) returns na."""
    p = np.empty(3)
    q = np.empty(8)
    best = 0.0
    ib = -1
    for i in range(m):
        rn = R[0] * normals[i, 0] + R[1] * normals[i, 1] + R[2] * normals[i, 2]
        if not (rn < 0.0):
            continue
        t0 = R[0] - rn * normals[i, 0]
        t1 = R[1] - rn * normals[i, 1]
        t2 = R[2] - rn * normals[i, 2]
        tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        # near-ties (a node exactly on a symmetric peak) go to the first face in the feature's
        # order, so that rounding (a mold in other units) cannot pick a different equilibrium
        if not (tn > best * (1.0 + 1e-6)):
            continue
        p[0] = x[0] + probe * t0 / tn
        p[1] = x[1] + probe * t1 / tn
        p[2] = x[2] + probe * t2 / tn
        sd = mold_query(margs, p, q)
        if sd < -1e-3 * probe:
            continue
        best = tn
        ib = i
    if ib < 0:
        return na
    act[0] = ib
    return 1


@njit(cache=True)
def _projectors(pos, F, fixed, in_contact, has_mold, margs, Pi, probe=0.0):
    """Active set and per-node projectors Pi (n,3,3) onto the allowed directions.

    Releases contact nodes whose resultant points out of the mold (in_contact updated in place).
    With ``probe`` > 0 [m], a node pressed onto a convex edge or vertex keeps only the face it
    slides down (``_ridge_face``). Returns the number of released nodes."""
    qbuf = np.empty(8)
    nbuf = np.empty((MAX_FEATURE_NORMALS, 3))
    act = np.empty(3, np.int64)
    R = np.empty(3)
    Q = np.empty((6, 3))
    released = 0
    for k in range(pos.shape[0]):
        nq = 0
        for a in range(3):
            if fixed[k, a]:
                Q[nq, 0] = 0.0
                Q[nq, 1] = 0.0
                Q[nq, 2] = 0.0
                Q[nq, a] = 1.0
                nq += 1
        if in_contact[k] and has_mold and nq < 3:
            for a in range(3):
                R[a] = 0.0 if fixed[k, a] else F[k, a]
            m = mold_contact_normals(margs, pos[k], qbuf, nbuf)
            free_axis_normals(fixed[k], nbuf, m)
            na = cone_active(R, nbuf, m, act)
            if na >= 2 and qbuf[6] != 0.0 and probe > 0.0:
                na = _ridge_face(pos[k], R, nbuf, m, margs, probe, act, na)
            if na == 0:
                in_contact[k] = False
                released += 1
            else:
                for t in range(na):
                    Q[nq, 0] = nbuf[act[t], 0]
                    Q[nq, 1] = nbuf[act[t], 1]
                    Q[nq, 2] = nbuf[act[t], 2]
                    nq += 1
        # Gram-Schmidt on the constraint directions; Pi = I - sum q q^T
        for r in range(3):
            for c in range(3):
                Pi[k, r, c] = 1.0 if r == c else 0.0
        kept = 0
        for t in range(nq):
            v0, v1, v2 = Q[t, 0], Q[t, 1], Q[t, 2]
            for u in range(kept):
                d = v0 * Q[u, 0] + v1 * Q[u, 1] + v2 * Q[u, 2]
                v0 -= d * Q[u, 0]
                v1 -= d * Q[u, 1]
                v2 -= d * Q[u, 2]
            nv = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            if nv < 1e-6:
                continue
            Q[kept, 0] = v0 / nv
            Q[kept, 1] = v1 / nv
            Q[kept, 2] = v2 / nv
            kept += 1
            if kept == 3:
                break
        for u in range(kept):
            for r in range(3):
                for c in range(3):
                    Pi[k, r, c] -= Q[u, r] * Q[u, c]
    return released


@njit(cache=True)
def _block_infeasible(pos, dx, contact, has_mold, margs, probe, Pi):
    """Blocking constraints at edges and vertices. The active set (``_projectors``) keeps the
    normals that carry a positive multiplier; the Newton step of a node on an edge or vertex can
    still leave the feature's tangent cone through another face (in a groove: into the face
    beside the active one), and the projection back onto the surface then bends the path at
    first order, so no step length lowers the energy. A node whose step direction enters the
    mold within ``probe`` [m] gets the face normal it violates most added to its constraints
    (Pi updated in place). Returns how many nodes were blocked."""
    if not has_mold:
        return 0
    q = np.empty(8)
    p = np.empty(3)
    nbuf = np.empty((MAX_FEATURE_NORMALS, 3))
    blocked = 0
    for k in range(pos.shape[0]):
        if not contact[k]:
            continue
        d0 = dx[3 * k]
        d1 = dx[3 * k + 1]
        d2 = dx[3 * k + 2]
        dn = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if dn == 0.0:
            continue
        mold_query(margs, pos[k], q)
        if q[6] == 0.0:
            continue
        p[0] = pos[k, 0] + probe * d0 / dn
        p[1] = pos[k, 1] + probe * d1 / dn
        p[2] = pos[k, 2] + probe * d2 / dn
        sd = mold_query(margs, p, q)
        if not (sd < -1e-3 * probe):
            continue
        m = mold_contact_normals(margs, pos[k], q, nbuf)
        best = 0.0
        jb = -1
        for j in range(m):
            # the normal's part in the still-allowed directions
            a0 = Pi[k, 0, 0] * nbuf[j, 0] + Pi[k, 0, 1] * nbuf[j, 1] + Pi[k, 0, 2] * nbuf[j, 2]
            a1 = Pi[k, 1, 0] * nbuf[j, 0] + Pi[k, 1, 1] * nbuf[j, 1] + Pi[k, 1, 2] * nbuf[j, 2]
            a2 = Pi[k, 2, 0] * nbuf[j, 0] + Pi[k, 2, 1] * nbuf[j, 1] + Pi[k, 2, 2] * nbuf[j, 2]
            if math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) < 1e-6:
                continue
            dd = (d0 * nbuf[j, 0] + d1 * nbuf[j, 1] + d2 * nbuf[j, 2]) / dn
            if dd < best:
                best = dd
                jb = j
        if jb < 0:
            continue
        a0 = Pi[k, 0, 0] * nbuf[jb, 0] + Pi[k, 0, 1] * nbuf[jb, 1] + Pi[k, 0, 2] * nbuf[jb, 2]
        a1 = Pi[k, 1, 0] * nbuf[jb, 0] + Pi[k, 1, 1] * nbuf[jb, 1] + Pi[k, 1, 2] * nbuf[jb, 2]
        a2 = Pi[k, 2, 0] * nbuf[jb, 0] + Pi[k, 2, 1] * nbuf[jb, 1] + Pi[k, 2, 2] * nbuf[jb, 2]
        an = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        a0 /= an
        a1 /= an
        a2 /= an
        Pi[k, 0, 0] -= a0 * a0
        Pi[k, 0, 1] -= a0 * a1
        Pi[k, 0, 2] -= a0 * a2
        Pi[k, 1, 0] -= a1 * a0
        Pi[k, 1, 1] -= a1 * a1
        Pi[k, 1, 2] -= a1 * a2
        Pi[k, 2, 0] -= a2 * a0
        Pi[k, 2, 1] -= a2 * a1
        Pi[k, 2, 2] -= a2 * a2
        blocked += 1
    return blocked


@njit(cache=True)
def _apply_pi(Pi, v, out):
    for k in range(Pi.shape[0]):
        a0 = v[3 * k]
        a1 = v[3 * k + 1]
        a2 = v[3 * k + 2]
        for r in range(3):
            out[3 * k + r] = Pi[k, r, 0] * a0 + Pi[k, r, 1] * a1 + Pi[k, r, 2] * a2


@njit(cache=True)
def _mold_distances(pos, has_mold, margs, out):
    """Signed distance [m] of every node to the mold (inf without a mold)."""
    q = np.empty(8)
    for k in range(pos.shape[0]):
        out[k] = mold_query(margs, pos[k], q) if has_mold else np.inf


@njit(cache=True)
def _face_exit(margs, f, p0, d):
    """Largest t in [0, 1] such that p0 + t d stays inside triangle f (barycentric coordinates
    of the point's projection onto the face plane all >= 0)."""
    V = margs[2]
    F = margs[3]
    a = F[f, 0]
    b = F[f, 1]
    c = F[f, 2]
    e1x = V[b, 0] - V[a, 0]; e1y = V[b, 1] - V[a, 1]; e1z = V[b, 2] - V[a, 2]
    e2x = V[c, 0] - V[a, 0]; e2y = V[c, 1] - V[a, 1]; e2z = V[c, 2] - V[a, 2]
    d11 = e1x * e1x + e1y * e1y + e1z * e1z
    d12 = e1x * e2x + e1y * e2y + e1z * e2z
    d22 = e2x * e2x + e2y * e2y + e2z * e2z
    den = d11 * d22 - d12 * d12
    if not (den > 0.0):
        return 1.0
    wx = p0[0] - V[a, 0]; wy = p0[1] - V[a, 1]; wz = p0[2] - V[a, 2]
    w1 = wx * e1x + wy * e1y + wz * e1z
    w2 = wx * e2x + wy * e2y + wz * e2z
    u0 = (d22 * w1 - d12 * w2) / den
    v0 = (d11 * w2 - d12 * w1) / den
    q1 = d[0] * e1x + d[1] * e1y + d[2] * e1z
    q2 = d[0] * e2x + d[1] * e2y + d[2] * e2z
    du = (d22 * q1 - d12 * q2) / den
    dv = (d11 * q2 - d12 * q1) / den
    lam = (u0, v0, 1.0 - u0 - v0)
    dl = (du, dv, -du - dv)
    t = 1.0
    for i in range(3):
        if dl[i] < 0.0:
            ti = -max(lam[i], 0.0) / dl[i]
            if ti < t:
                t = ti
    return max(t, 0.0)


@njit(cache=True)
def _trial_positions(pos0, contact0, sd0, step, alpha, fixed, has_mold, margs, clip_faces, F0, out, contact_out):
    """Positions after the step alpha*step with the contact rules (paper 3.2.2): a free node's
    move is clipped where it would enter the mold and it becomes a contact node; contact nodes
    are projected onto the surface. sd0 (N,) [m]: the nodes' signed distances before the step
    (a free node whose move is shorter than its distance cannot reach the mold and needs no
    query). Returns the deepest remaining penetration [m] (0 when none)."""
    q = np.empty(8)
    p = np.empty(3)
    dd = np.empty(3)
    worst = 0.0
    for k in range(pos0.shape[0]):
        moved = False
        d2 = 0.0
        for a in range(3):
            v = pos0[k, a]
            if not fixed[k, a]:
                d = alpha * step[3 * k + a]
                if d != 0.0:
                    moved = True
                    d2 += d * d
                v += d
            p[a] = v
        c = contact0[k]
        if has_mold and moved and (c or not (sd0[k] > math.sqrt(d2) * (1.0 + 1e-9) + 1e-15)):
            hit = False
            if c:
                hit = True
                if clip_faces and margs[0][0] == MOLD_MESH:
                    # a contact node on a face slides at most to the face's border: the contact
                    # feature changes there (edge or vertex), and the next active set decides
                    # whether it stays on it or moves on to the next face
                    mold_query(margs, pos0[k], q)
                    if q[6] == 0.0:
                        for a in range(3):
                            dd[a] = p[a] - pos0[k, a]
                        t = _face_exit(margs, int(q[7]), pos0[k], dd)
                        if t < 1.0:
                            for a in range(3):
                                if not fixed[k, a]:
                                    p[a] = pos0[k, a] + t * dd[a]
            else:
                hit = stop_at_surface(margs, pos0[k], p, fixed[k])
            sd = mold_query(margs, p, q)
            if c and sd > RELEASE_GAP and q[6] != 0.0:
                # a contact node whose move took it off the surface past a convex edge or vertex
                # (the closest point is on that edge or vertex): it is put back there only if its
                # resultant pulls it there (R . (p - q) < 0); otherwise it has slid off the
                # feature into free space (a node pulled over a box's edge) and is free. (Past a
                # face's curvature it is always projected back: a face keeps its nodes.)
                dot = 0.0
                for a in range(3):
                    if not fixed[k, a]:
                        dot += F0[k, a] * (p[a] - q[a])
                if dot > 0.0:
                    hit = False
                    c = False
            if hit or sd < 0.0:
                for a in range(3):
                    if not fixed[k, a]:
                        p[a] = q[a]
                c = True
                sd = mold_query(margs, p, q)
            if -sd > worst:
                worst = -sd
        out[k, 0] = p[0]
        out[k, 1] = p[1]
        out[k, 2] = p[2]
        contact_out[k] = c
    return worst


# ----------------------------------------------------------------------------------------------
# multigrid
# ----------------------------------------------------------------------------------------------


def _interp_1d(n: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """Linear interpolation from the coarse node set (every second node, plus the last) of a
    line of n nodes. Returns (P (n, nc), coarse node indices)."""
    coarse = list(range(0, n, 2))
    if coarse[-1] != n - 1:
        coarse.append(n - 1)
    coarse = np.asarray(coarse)
    pos = {c: q for q, c in enumerate(coarse)}
    rows, cols, vals = [], [], []
    for i in range(n):
        if i in pos:
            rows.append(i); cols.append(pos[i]); vals.append(1.0)
        else:
            lo, hi = i - 1, i + 1
            rows += [i, i]; cols += [pos[lo], pos[hi]]; vals += [0.5, 0.5]
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, len(coarse))), coarse


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
def _galerkin(indptr, indices, data, pidx, pw, cptr, cchild, cw, nc, Pi, use_pi):
    """Coarse operator A_c = P^T A P for a node-level interpolation P (fine node k has parents
    pidx[k, :] with weights pw[k, :], -1 unused; coarse node c has children cchild[cptr[c]:...]
    with weights cw) acting blockwise as weight x I3. With ``use_pi`` the fine matrix is
    A = Pi K Pi + mu Pi + (I - Pi) and the prolongation is Pi P: then P^T Pi A Pi P equals
    P^T (A - (I - Pi)) P, so the (I - Pi) part is left out of the diagonal blocks.
    Returns the coarse BSR arrays (indptr, indices, data (nb,3,3)) with sorted rows."""
    marker = -np.ones(nc, np.int64)
    rowbuf = np.empty(nc, np.int64)
    # symbolic pass: count the coarse row lengths
    cip = np.zeros(nc + 1, np.int64)
    for c in range(nc):
        cip[c + 1] = cip[c] + _coarse_row(c, cptr, cchild, indptr, indices, pidx, marker, c, rowbuf)
    cidx = np.empty(cip[nc], np.int64)
    cdat = np.zeros((cip[nc], 3, 3))
    slot = np.empty(nc, np.int64)  # coarse column -> its block in row c (set per row before use)
    for c in range(nc):
        # collect and sort the row's columns (a second stamp, nc + c, on the same marker)
        m = _coarse_row(c, cptr, cchild, indptr, indices, pidx, marker, nc + c, rowbuf)
        row = np.sort(rowbuf[:m])
        base = cip[c]
        for t in range(m):
            cidx[base + t] = row[t]
            slot[row[t]] = base + t
        for qc in range(cptr[c], cptr[c + 1]):
            k = cchild[qc]
            wk = cw[qc]
            for q in range(indptr[k], indptr[k + 1]):
                l = indices[q]
                for t in range(pidx.shape[1]):
                    d = pidx[l, t]
                    if d < 0:
                        continue
                    w = wk * pw[l, t]
                    z = slot[d]
                    for r in range(3):
                        for cc in range(3):
                            v = data[q, r, cc]
                            if use_pi and l == k:
                                v -= (1.0 if r == cc else 0.0) - Pi[k, r, cc]
                            cdat[z, r, cc] += w * v
    return cip, cidx, cdat


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
    __slots__ = ("indptr", "indices", "data", "lu", "n", "shape", "ds", "ps", "ns")


class _Transfer:
    """Node-level bilinear interpolation between a grid and its every-second-node coarse grid."""

    def __init__(self, nx1, ny1):
        px, _ = _interp_1d(nx1)
        py, _ = _interp_1d(ny1)
        P = sp.kron(px, py, format="csr")
        P.sort_indices()
        n, nc = P.shape
        self.coarse_shape = (px.shape[1], py.shape[1])
        self.pidx = -np.ones((n, 4), np.int64)
        self.pw = np.zeros((n, 4))
        cnt = np.diff(P.indptr)
        pos_in_row = np.arange(P.indices.shape[0]) - np.repeat(P.indptr[:-1], cnt)
        rows = np.repeat(np.arange(n), cnt)
        self.pidx[rows, pos_in_row] = P.indices
        self.pw[rows, pos_in_row] = P.data
        PT = P.T.tocsr()
        PT.sort_indices()
        self.cptr = PT.indptr.astype(np.int64)
        self.cchild = PT.indices.astype(np.int64)
        self.cw = PT.data.astype(float)
        self.nc = nc


class Multigrid:
    """Galerkin geometric multigrid on the node grid, used as the CG preconditioner.

    Levels: the fine grid, then every second node (bilinear interpolation), down to at most
    ``COARSEST_NODES`` nodes, factorised with a sparse LU. The fine level's prolongation is
    projected by the active-set projectors Pi, so the coarse spaces only move nodes where they
    may move. Galerkin products, restriction and prolongation are numba loops over the
    structured grid's parent/child lists."""

    def __init__(self, grid_shape):
        self.shapes = [tuple(grid_shape)]
        self.transfers: list[_Transfer] = []
        nx1, ny1 = grid_shape
        while nx1 * ny1 > COARSEST_NODES and nx1 > 3 and ny1 > 3:
            tr = _Transfer(nx1, ny1)
            self.transfers.append(tr)
            nx1, ny1 = tr.coarse_shape
            self.shapes.append((nx1, ny1))
        self.levels: list[_Level] = []
        self.Pi = None

    def setup(self, indptr, indices, data, Pi):
        """Build the hierarchy for the projected fine matrix (BSR arrays)."""
        self.Pi = Pi
        levels = []
        L = _Level()
        L.indptr, L.indices, L.data = indptr, indices, data
        L.n = indptr.shape[0] - 1
        levels.append(L)
        for lv, tr in enumerate(self.transfers):
            F = levels[-1]
            cip, cidx, cdat = _galerkin(F.indptr, F.indices, F.data, tr.pidx, tr.pw, tr.cptr, tr.cchild,
                                        tr.cw, tr.nc, Pi, lv == 0)
            C = _Level()
            C.indptr, C.indices, C.data = cip, cidx, cdat
            C.n = tr.nc
            levels.append(C)
        for lv, L in enumerate(levels[:-1]):
            nx1, ny1 = self.shapes[lv]
            L.ds, L.ps, L.ns = _line_slots(L.indptr, L.indices, nx1, ny1)
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
        _line_gs(L.indptr, L.indices, L.data, nx1, ny1, L.ds, L.ps, L.ns, b, x, 0, False)
        _line_gs(L.indptr, L.indices, L.data, nx1, ny1, L.ds, L.ps, L.ns, b, x, 1, False)
        r = np.empty_like(b)
        _bsr_residual(L.indptr, L.indices, L.data, x, b, r)
        rc = np.empty(3 * tr.nc)
        _restrict(r, tr.cptr, tr.cchild, tr.cw, self.Pi, lv == 0, rc)
        xc = self.vcycle(rc, lv + 1)
        _prolong_add(xc, tr.pidx, tr.pw, self.Pi, lv == 0, x)
        _line_gs(L.indptr, L.indices, L.data, nx1, ny1, L.ds, L.ps, L.ns, b, x, 1, True)
        _line_gs(L.indptr, L.indices, L.data, nx1, ny1, L.ds, L.ps, L.ns, b, x, 0, True)
        return x


def _pcg(matvec, prec, b, tol, maxiter):
    """Preconditioned conjugate gradients from x = 0; returns (x, iterations, relative residual).

    Vector operations are numba loops: BLAS calls on short vectors are slow when its threads
    compete for a loaded machine."""
    x = np.zeros_like(b)
    r = b.copy()
    bn = math.sqrt(_dot(b, b))
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


# ----------------------------------------------------------------------------------------------
# the Newton iteration on one grid
# ----------------------------------------------------------------------------------------------


LM_ALPHA_LOW = 0.1
LM_MAX = 1e4


class NewtonLevel:
    """Newton iterations for one Model (the fine grid, or a coarse grid of the sequencing)."""

    def __init__(self, model, *, kink: float = 1.0, use_multigrid: bool | None = None):
        self.model = model
        self.has_mold, self.margs = model_mold_args(model)
        self.sargs = model.spring_args()
        n = model.node_count
        self.n = n
        self.indptr, self.indices, self.slot, self.diag = _bsr_pattern(n, model.spring_nodes)
        nb = self.indices.shape[0]
        self.K = np.zeros((nb, 3, 3))
        self.A = np.zeros((nb, 3, 3))
        t = model.tables
        self.kink = np.array([kink * first_slope(t.x, t.y, t.start, int(tb)) for tb in
                              range(len(t.start) - 1)])[model.spring_table] if kink > 0 else np.zeros(
            model.spring_count)
        self.kink = np.ascontiguousarray(self.kink, float)
        self.Pi = np.zeros((n, 3, 3))
        self.F = np.zeros((n, 3))
        self._Fr = np.zeros((n, 3))
        self.V = np.zeros(n)
        self.trial = np.zeros((n, 3))
        self.trial_contact = np.zeros(n, bool)
        self.direct = (use_multigrid is False) or (use_multigrid is None and 3 * n <= DIRECT_DOFS)
        self.mg = None if self.direct else Multigrid(model.grid_shape)
        self.lm = 1e-10  # Levenberg shift relative to the mean diagonal stiffness
        ext = np.ptp(model.rest_positions, axis=0).max()
        self.blowup = float(np.abs(model.rest_positions).max() + 1e3 * max(ext, 1e-9))
        # step probed for leaving an edge's or vertex's tangent cone [m] (_block_infeasible)
        self.probe = 1e-6 * float(min(model.spacing))
        self._cache = None
        self.sd0 = np.full(n, np.inf)
        self.ls_alpha = 0.0
        self._mg_pi = None
        self._mg_mu = None
        self._mg_age = 0
        self._last_cg = 0

    # -- helpers ---------------------------------------------------------------------------
    def energy_forces(self, pos, F):
        return forces_and_energy(pos, *self.sargs, self.model.external_force, F)

    def residual(self, pos, contact, F=None):
        """||V||_inf (eq. 6) at pos; F: the forces at pos when already known."""
        if F is None:
            F = self._Fr
            forces_and_energy(pos, *self.sargs, self.model.external_force, F)
        return _residual_from_forces(pos, F, self.model.fixed_axes, contact, self.has_mold, self.margs,
                                     self.V)

    def _solve_linear(self, rhs, mu_abs, tol):
        _project_system(self.indptr, self.indices, self.K, self.diag, self.Pi, mu_abs, self.A)
        n3 = 3 * self.n
        if self.direct:
            M = sp.bsr_matrix((self.A, self.indices, self.indptr), shape=(n3, n3)).tocsc()
            lu = sla.splu(M, permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True),
                          diag_pivot_thresh=1e-3)
            x = lu.solve(rhs)
            return x, 1
        if self._mg_stale(mu_abs):
            self._mg_pi = self.Pi.copy()
            self.mg.setup(self.indptr, self.indices, self.A.copy(), self._mg_pi)
            self._mg_age = 0
        self._mg_age += 1
        indptr, indices, A = self.indptr, self.indices, self.A

        def mv(v, out):
            _bsr_matvec(indptr, indices, A, v, out)

        x, it, rel = _pcg(mv, self.mg.vcycle, rhs, tol, 200)
        self._last_cg = it
        if rel > tol and self._mg_age > 1:
            # the reused preconditioner no longer fits: rebuild and solve again
            self._mg_pi = None
            return self._solve_linear(rhs, mu_abs, tol)
        return x, it

    def _mg_stale(self, mu_abs):
        """Rebuild the multigrid hierarchy when the active set changed, the shift changed, or
        the last solve needed many iterations; otherwise the previous one (a slightly older
        Hessian) still preconditions well and saves the Galerkin products."""
        if self._mg_pi is None or self._mg_mu != mu_abs or self._last_cg > 12 or self._mg_age >= 6:
            self._mg_mu = mu_abs
            return True
        if not np.array_equal(self._mg_pi, self.Pi):
            return True
        return False

    # -- one iteration -----------------------------------------------------------------------
    def iterate(self, state, vinf_now, forcing=1e-3):
        """One Newton iteration on state (in place). Returns (residual, energy, flag) with flag
        0 ok, 2 diverged (state unchanged), 3 no progress possible (state unchanged)."""
        m = self.model
        pos = state.positions
        F = self.F
        if self._cache is not None and self._cache[0] is pos and np.array_equal(self._cache[1], pos):
            E0 = self._cache[2]
            F[:] = self._cache[3]
        else:
            E0 = self.energy_forces(pos, F)
        self._cache = None
        _mold_distances(pos, self.has_mold, self.margs, self.sd0)
        contact = state.in_contact
        contact_before = contact.copy()
        _projectors(pos, F, m.fixed_axes, contact, self.has_mold, self.margs, self.Pi, self.probe)
        v_base = self.residual(pos, contact, F) if not np.array_equal(contact, contact_before) else vinf_now
        f = F.reshape(-1)
        rhs = np.empty(3 * self.n)
        _apply_pi(self.Pi, f, rhs)
        gnorm = np.linalg.norm(rhs)
        _assemble(pos, *self.sargs, self.kink, self.slot, self.K)
        dsum = 0.0
        dcount = 0
        dg = self.K[self.diag]
        tr = np.einsum("nii->n", dg)
        free = ~m.fixed_axes.all(axis=1)
        if free.any():
            dsum = tr[free].sum()
            dcount = 3 * free.sum()
        dmean = dsum / dcount if dcount else 1.0
        if not (dmean > 0.0):
            dmean = 1.0
        t_start = time.perf_counter()
        for attempt in range(8):
            if attempt and time.perf_counter() - t_start > ITERATE_BUDGET_S:
                # failed attempts near float64's floor can each cost hundreds of CG iterations:
                # keep one iteration (and so the driver's batches) short
                break
            mu_abs = self.lm * dmean
            tol = min(1e-2, max(forcing, 1e-12))
            dx, _ = self._solve_linear(rhs, mu_abs, tol)
            for _ in range(3):
                if not (self.has_mold and np.all(np.isfinite(dx))):
                    break
                if _block_infeasible(pos, dx, contact, self.has_mold, self.margs, self.probe, self.Pi) == 0:
                    break
                _apply_pi(self.Pi, f, rhs)
                dx, _ = self._solve_linear(rhs, mu_abs, tol)
            if not np.all(np.isfinite(dx)):
                self.lm = max(self.lm * 100.0, 1e-8)
                continue
            slope = -(rhs @ dx)  # directional derivative of E (negative for a descent direction)
            if not (slope < 0.0):
                self.lm = max(self.lm * 100.0, 1e-8)
                continue
            accepted = self._line_search(state, dx, E0, slope, v_base)
            if accepted is not None:
                # Levenberg-Marquardt shift as a trust region: a step the line search had to cut
                # hard means the quadratic model is poor at that length (slack springs leave
                # directions nearly free; contact nodes leave their faces), so shift more
                if self.ls_alpha < LM_ALPHA_LOW:
                    self.lm = min(max(self.lm * 10.0, 1e-8), LM_MAX)
                elif self.ls_alpha >= 1.0:
                    self.lm = max(self.lm / 10.0, 1e-12)
                return accepted
            self.lm = max(self.lm * 100.0, 1e-6)
        return v_base, E0, 3

    def _line_search(self, state, dx, E0, slope, v_base):
        pos = state.positions
        contact = state.in_contact
        m = self.model
        alpha = 1.0
        # do not let any node move by more than the sheet's size in one step
        big = np.abs(dx).max()
        if big > 0 and alpha * big > 0.5 * self.blowup:
            alpha = 0.5 * self.blowup / big
        Ft = np.empty_like(self.F)
        mesh = self.has_mold and self.margs[0][0] == MOLD_MESH and contact.any()
        for _ in range(40):
            self.ls_alpha = alpha
            # the straight step (contact nodes projected back onto the surface); on a mesh mold,
            # when it fails, the same step with contact nodes stopped at their face's border
            for clip in ((False, True) if mesh else (False,)):
                pen = _trial_positions(pos, contact, self.sd0, dx, alpha, m.fixed_axes, self.has_mold, self.margs,
                                       clip, self.F, self.trial, self.trial_contact)
                if not (pen <= PENETRATION_TOL):
                    continue
                E1 = self.energy_forces(self.trial, Ft)
                if not math.isfinite(E1):
                    continue
                resolution = ENERGY_RESOLUTION * max(abs(E0), abs(E1), 1e-300) + 1e-300
                if E1 <= E0 + 1e-4 * alpha * slope and E1 < E0 - resolution:
                    return self._accept(state, E1, F=Ft)
                if abs(E1 - E0) <= 10 * resolution:
                    # below the energy's resolution: judge by the residual
                    v1 = self.residual(self.trial, self.trial_contact, Ft)
                    if v1 < v_base:
                        return self._accept(state, E1, v1, Ft)
            alpha *= 0.5
            if alpha * np.abs(dx).max() < 1e-17:
                break
        return None

    def _accept(self, state, E1, v1=None, F=None):
        state.positions[:] = self.trial
        state.in_contact[:] = self.trial_contact
        if v1 is None:
            v1 = self.residual(state.positions, state.in_contact, F)
        if F is not None:
            # forces and energy at the accepted state: the next iteration starts from them
            self._cache = (state.positions, state.positions.copy(), E1, F)
        if not math.isfinite(v1):
            return v1, E1, 2
        return v1, E1, 0


# ----------------------------------------------------------------------------------------------
# grid sequencing
# ----------------------------------------------------------------------------------------------


def coarsen_model(model):
    """The same scene on the grid of every second node (needs even divisions), or None."""
    from ...grid import FAMILY_BEND_WARP, FAMILY_BEND_WEFT, FAMILY_SEAM, FAMILY_SHEAR, Model, _adjacency

    nx1, ny1 = model.grid_shape
    nx, ny = nx1 - 1, ny1 - 1
    if nx % 2 or ny % 2 or nx < 4 or ny < 4:
        return None, None
    cx, cy = nx // 2, ny // 2
    dx, dy = 2 * model.spacing[0], 2 * model.spacing[1]
    sub = np.arange(nx1 * ny1).reshape(nx1, ny1)[::2, ::2].ravel()
    n = (cx + 1) * (cy + 1)
    idx = np.arange(n).reshape(cx + 1, cy + 1)
    rest = model.rest_positions[sub].copy()
    fam = model.spring_family
    nodes, rest_len, width, table, family = [], [], [], [], []

    def add(a, b, l0, w, t, f):
        nodes.append(np.stack([a.ravel(), b.ravel()], 1)); rest_len.append(np.full(a.size, l0))
        width.append(np.broadcast_to(w, a.shape).ravel().astype(float))
        table.append(np.full(a.size, t, np.int64)); family.append(np.full(a.size, f, np.int8))

    t_warp = int(model.spring_table[fam == 0][0])
    t_weft = int(model.spring_table[fam == 1][0])
    w = np.full((cx, cy + 1), dy); w[:, 0] *= 0.5; w[:, cy] *= 0.5
    add(idx[:-1, :], idx[1:, :], dx, w, t_warp, 0)
    w = np.full((cx + 1, cy), dx); w[0, :] *= 0.5; w[cx, :] *= 0.5
    add(idx[:, :-1], idx[:, 1:], dy, w, t_weft, 1)
    if (fam == FAMILY_SHEAR).any():
        t = int(model.spring_table[fam == FAMILY_SHEAR][0])
        diag = math.hypot(dx, dy)
        wd = 0.5 * dx * dy / diag
        add(idx[:-1, :-1], idx[1:, 1:], diag, wd, t, FAMILY_SHEAR)
        add(idx[1:, :-1], idx[:-1, 1:], diag, wd, t, FAMILY_SHEAR)
    if (fam == FAMILY_BEND_WARP).any() and cx >= 2:
        t = int(model.spring_table[fam == FAMILY_BEND_WARP][0])
        w = np.full((cx - 1, cy + 1), dy); w[:, 0] *= 0.5; w[:, cy] *= 0.5
        add(idx[:-2, :], idx[2:, :], 2 * dx, w, t, FAMILY_BEND_WARP)
    if (fam == FAMILY_BEND_WEFT).any() and cy >= 2:
        t = int(model.spring_table[fam == FAMILY_BEND_WEFT][0])
        w = np.full((cx + 1, cy - 1), dx); w[0, :] *= 0.5; w[cx, :] *= 0.5
        add(idx[:, :-2], idx[:, 2:], 2 * dy, w, t, FAMILY_BEND_WEFT)
    seam = fam == FAMILY_SEAM
    if seam.any():
        # seams keep the pairs whose two nodes are both on the coarse grid; each carries the
        # seam length of two fine pairs (twice the stiffness)
        cmap = -np.ones(model.node_count, np.int64)
        cmap[sub] = np.arange(n)
        ca = cmap[model.spring_nodes[seam, 0]]
        cb = cmap[model.spring_nodes[seam, 1]]
        keep = (ca >= 0) & (cb >= 0)
        if keep.any():
            nodes.append(np.stack([ca[keep], cb[keep]], 1))
            rest_len.append(model.spring_rest_length[seam][keep])
            width.append(2.0 * model.spring_width[seam][keep])
            table.append(model.spring_table[seam][keep])
            family.append(np.full(int(keep.sum()), FAMILY_SEAM, np.int8))
    spring_nodes = np.ascontiguousarray(np.concatenate(nodes).astype(np.int64))
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)
    wx = np.full(cx + 1, dx); wx[0] *= 0.5; wx[-1] *= 0.5
    wy = np.full(cy + 1, dy); wy[0] *= 0.5; wy[-1] *= 0.5
    area = np.outer(wx, wy).ravel()
    fine_area = model.node_area[sub]
    ext = model.external_force[sub] * (area / np.where(fine_area > 0, fine_area, 1.0))[:, None]
    coarse = Model(
        node_count=n, grid_shape=(cx + 1, cy + 1), rest_positions=rest, spring_nodes=spring_nodes,
        spring_rest_length=np.ascontiguousarray(np.concatenate(rest_len), float),
        spring_width=np.ascontiguousarray(np.concatenate(width), float),
        spring_table=np.ascontiguousarray(np.concatenate(table)), spring_family=np.concatenate(family),
        tables=model.tables, table_list=model.table_list,
        fixed_axes=np.ascontiguousarray(model.fixed_axes[sub]),
        prescribed_positions=np.ascontiguousarray(model.prescribed_positions[sub]),
        external_force=np.ascontiguousarray(ext), node_area=area, adj_ptr=ptr, adj_node=adj_node,
        adj_spring=adj_spring, mold=model.mold, spacing=(dx, dy), warp_count=cx * (cy + 1),
        weft_count=(cx + 1) * cy)
    return coarse, sub


def prolong_state(coarse_model, coarse_state, fine_model, fine_state):
    """Interpolate a coarse solution onto the fine grid (bilinear in the node indices), keep
    the fine constrained coordinates, and put nodes that would be inside the mold (or between
    two contact nodes) onto its surface as contact nodes."""
    from ...mold import mold_query_many

    nx1, ny1 = fine_model.grid_shape
    cx1, cy1 = coarse_model.grid_shape
    px, _ = _interp_1d(nx1)
    py, _ = _interp_1d(ny1)
    P = sp.kron(px, py, format="csr")
    pos = P @ coarse_state.positions
    cont = (P @ coarse_state.in_contact.astype(float)) > 1.0 - 1e-9
    fixed = fine_model.fixed_axes
    pos[fixed] = fine_state.positions[fixed]
    if fine_model.mold is not None:
        margs = fine_model.mold.kernel_args()
        n = fine_model.node_count
        sd = np.empty(n); cp = np.empty((n, 3)); nrm = np.empty((n, 3)); feat = np.empty((n, 2), np.int64)
        mold_query_many(margs, pos, sd, cp, nrm, feat)
        put = (sd < 0) | cont
        put &= ~fixed.all(axis=1)
        k = np.nonzero(put)[0]
        for a in range(3):
            sel = k[~fixed[k, a]]
            pos[sel, a] = cp[sel, a]
        mold_query_many(margs, pos, sd, cp, nrm, feat)
        inside = sd < -PENETRATION_TOL
        if inside.any():
            return False
        cont = put
    else:
        cont = np.zeros(fine_model.node_count, bool)
    fine_state.positions[:] = pos
    fine_state.in_contact[:] = cont
    return True


def _solve_level(level: NewtonLevel, state, e, max_iter, deadline):
    """Newton iterations on a coarse level until its residual is below e (or no progress)."""
    v = level.residual(state.positions, state.in_contact)
    for _ in range(max_iter):
        if v <= e or time.perf_counter() > deadline:
            break
        v, E, flag = level.iterate(state, v, forcing=_forcing(v, e))
        if flag:
            break
    return v


def _forcing(v, e):
    """Inexact-Newton forcing term: loose far from the solution, tight close to it."""
    if not math.isfinite(v) or v <= 0:
        return 1e-2
    return float(min(1e-2, max(1e-10, 1e-2 * math.sqrt(max(e, 1e-300) / v))))


def sequencing_chain(model, min_nodes: int = 400):
    """[(model, sub), ...] from the coarsest grid to the given one; each coarser grid has half
    the divisions of the next, and ``sub`` (for all but the last) indexes the next grid's nodes
    that it keeps."""
    chain = [(model, None)]
    m = model
    while True:
        c, sub = coarsen_model(m)
        if c is None or c.node_count < min_nodes:
            break
        chain.append((c, sub))  # sub: the nodes of m (the next finer grid) that c keeps
        m = c
    return chain[::-1]


def grid_sequence(model, state, settings, kink, deadline):
    """Solve the scene on the coarser grids (coarsest first), each started from the previous
    one's solution, and return the interpolated starting state for ``model`` (or None when the
    grid cannot be coarsened or the interpolation fails)."""
    from ...grid import State

    chain = sequencing_chain(model)
    if len(chain) < 2:
        return None
    # restrict the current state down the chain (each level keeps every second node)
    starts = [None] * len(chain)
    starts[-1] = (state.positions, state.in_contact)
    for li in range(len(chain) - 1, 0, -1):
        p, c = starts[li]
        sub = chain[li - 1][1]
        starts[li - 1] = (p[sub].copy(), c[sub].copy())
    prev_model = prev_state = None
    for li, (mdl, _) in enumerate(chain[:-1]):
        p, c = starts[li]
        cst = State(np.ascontiguousarray(p), c.copy(), 0)
        if prev_state is not None:
            # the previous level's solution; when it cannot be interpolated (prolong_state then
            # leaves cst alone) this level starts from the restricted state
            prolong_state(prev_model, prev_state, mdl, cst)
        lvl = NewtonLevel(mdl, kink=kink)
        v0 = lvl.residual(cst.positions, cst.in_contact)
        # the coarsest grid is solved tightly (it fixes the contact set), the others only as far
        # as their discretisation error matters for the next grid's start
        rel = 1e-8 if li == 0 else 1e-4
        _solve_level(lvl, cst, max(settings.e, rel * v0), 60, deadline)
        prev_model, prev_state = mdl, cst
    trial = state.copy()
    if not prolong_state(prev_model, prev_state, model, trial):
        return None
    return trial


def solve(model, state, settings, callback=None):
    """Relax ``state`` in place with active-set Newton (see the module docstring).

    Options (``SolverSettings``): ``newton_kink`` (stiffness used at and below strain 0 on
    tension-only springs, as a fraction of the table's first slope; default 1),
    ``newton_sequencing`` (solve coarser grids first; default True), plus the common ``e``,
    ``max_iterations`` and ``time_limit_s``. One recorded iteration = one Newton step (the
    grid-sequencing stage counts as one)."""
    kink = float(getattr(settings, "newton_kink", 1e-3))
    seq = bool(getattr(settings, "newton_sequencing", True))
    fine = NewtonLevel(model, kink=kink)
    drv = Driver(model, state, settings, callback, "newton")
    holder = {"v": None, "seq_done": not seq, "best": math.inf, "since": 0}

    def advance(n):
        if not holder["seq_done"]:
            holder["seq_done"] = True
            t_lim = settings.time_limit_s
            deadline = time.perf_counter() + (0.5 * t_lim if t_lim else 1e30)
            trial = grid_sequence(model, state, settings, kink, deadline)
            if trial is not None:
                E_old = fine.energy_forces(state.positions, fine.F)
                E_new = fine.energy_forces(trial.positions, fine.F)
                v_new = fine.residual(trial.positions, trial.in_contact, fine.F)
                if math.isfinite(E_new) and math.isfinite(v_new) and E_new <= E_old:
                    state.positions[:] = trial.positions
                    state.in_contact[:] = trial.in_contact
                    holder["v"] = v_new
                    drv.record(np.array([v_new]), np.array([E_new]))
                    return 1, 1 if v_new <= settings.e else 0
        if holder["v"] is None:
            holder["v"] = fine.residual(state.positions, state.in_contact)
        v0 = holder["v"]
        prev_pos = state.positions.copy()
        prev_c = state.in_contact.copy()
        v, E, flag = fine.iterate(state, v0, forcing=_forcing(v0, settings.e))
        if flag == 2 or not math.isfinite(v) or not np.isfinite(state.positions).all() \
                or np.abs(state.positions).max() > fine.blowup:
            state.positions[:] = prev_pos
            state.in_contact[:] = prev_c
            return 0, 2
        if flag == 3:
            return 0, 3
        holder["v"] = v
        drv.record(np.array([v]), np.array([E]))
        if v <= settings.e:
            return 1, 1
        # stagnation: no 1 % gain in the best residual over STALL_NEWTON iterations (the
        # active set cycling on a faceted mold, or float64's floor): stop as stalled
        if v < 0.99 * holder["best"]:
            holder["best"] = v
            holder["since"] = 0
        else:
            holder["since"] += 1
            if holder["since"] >= STALL_NEWTON:
                return 1, 3
        return 1, 0

    return drv.run(advance)
