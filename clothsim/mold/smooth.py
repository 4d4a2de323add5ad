"""The smooth contact surface of a triangle mesh (mold kind ``MOLD_SMOOTH``): ``@njit(cache=True)``
pure functions of the mold's kernel arguments ``margs``.

A membrane pressed onto a polyhedron carries line loads on its ridges, so the contact pressure on
a faceted scan does not converge under lattice refinement. A scanned body is smooth and its
triangles are only a sampling of it; this kind replaces the polyhedron, for contact, by a smooth
(G1, continuous-normal) surface through the mesh: the zero set of the face-blended implicit
function (a simplified form of C. Shen, J. F. O'Brien & J. R. Shewchuk 2004, "Interpolating and
approximating implicit surfaces from polygon soup", ACM SIGGRAPH)::

    phi(x) = sum_f w_f(x) n_f . (x - a_f) / sum_f w_f(x),   w_f(x) = psi(d_f(x) / r)

with n_f the unit outward normal of face f, a_f one of its vertices, d_f(x) [m] the unsigned
distance from x to the triangle f, psi(t) = (1 - t)^4 (4 t + 1) for t < 1 (Wendland C2; 0 beyond)
and r [m] the smoothing radius (``params[14]``; default the mesh's median edge length).
psi'(0) = 0 makes w_f (hence phi) C1 across face planes; the gradient is analytic.
Coplanar faces give their plane exactly (flat CAD regions stay flat); creases are rounded over
about r; on a convex sampled surface the zero set lies just outside the polyhedron, within the
sampling error.

Queries (the conventions of :mod:`clothsim.mold`): the closest point c on {phi = 0} is found from
the faceted closest point by Newton steps onto phi = 0 (x <- x - phi grad / |grad|^2) alternated
with a tangential fixed-point correction until p - c is parallel to grad phi(c) (to 1e-13 m);
the signed distance is (p - c) . n(c), n = grad phi / |grad phi|, and the feature is code 0 (a
face, as on the analytic sphere) with the point-dependent normal n(c); ``out[7]`` is the nearest
mesh face. Points with no face within r (far outside or deep inside: never in contact), points
whose foot iteration does not converge, and, on an open mesh, points the faceted open-mesh rule
puts outside beyond the rim get the faceted answer (still code 0, ``out[3:6]`` the faceted
pseudo-normal).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .queries import _box_d2, _mesh_query, _tri_closest

_FOOT_TOL = 1e-13      # [m] tangential residual |p - c - ((p - c).n) n| of a converged foot point
_FOOT_ITERS = 60
_NEWTON_ITERS = 16


@njit(cache=True)
def _blend(margs, x, y, z, r, g, stack):
    """phi(x) [m] and its gradient g (3,) (filled); returns (phi, W), W = sum of the weights
    (0: no face within r of x; then phi = 0 and g = 0). stack: int64 scratch (>= 128)."""
    V = margs.vertices
    F = margs.faces
    FN = margs.face_normals
    bmin = margs.bvh_min
    bmax = margs.bvh_max
    child = margs.bvh_child
    rng = margs.bvh_range
    order = margs.bvh_faces
    r2 = r * r
    c20 = -20.0 / r2
    W = 0.0
    S = 0.0
    gw0 = 0.0
    gw1 = 0.0
    gw2 = 0.0
    gs0 = 0.0
    gs1 = 0.0
    gs2 = 0.0
    g[0] = 0.0
    g[1] = 0.0
    g[2] = 0.0
    if bmin.shape[0] == 0:
        return 0.0, 0.0
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack[sp]
        if _box_d2(bmin, bmax, n, x, y, z) >= r2:
            continue
        if child[n, 0] >= 0:
            if sp + 2 > stack.shape[0]:
                return 0.0, -1.0  # cannot happen for the median-split trees built here
            stack[sp] = child[n, 0]
            stack[sp + 1] = child[n, 1]
            sp += 2
            continue
        start = rng[n, 0]
        for k in range(start, start + rng[n, 1]):
            f = order[k]
            ia = F[f, 0]
            ib = F[f, 1]
            ic = F[f, 2]
            qx, qy, qz, reg = _tri_closest(x, y, z, V[ia, 0], V[ia, 1], V[ia, 2],
                                           V[ib, 0], V[ib, 1], V[ib, 2],
                                           V[ic, 0], V[ic, 1], V[ic, 2])
            dx = x - qx
            dy = y - qy
            dz = z - qz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 >= r2:
                continue
            t = math.sqrt(d2) / r
            om = 1.0 - t
            om3 = om * om * om
            w = om3 * om * (4.0 * t + 1.0)
            # grad w = psi'(t)/r * (x - q)/d = -20 (1 - t)^3 (x - q) / r^2  (smooth at d = 0)
            a = c20 * om3
            wx = a * dx
            wy = a * dy
            wz = a * dz
            nx = FN[f, 0]
            ny = FN[f, 1]
            nz = FN[f, 2]
            s = nx * (x - V[ia, 0]) + ny * (y - V[ia, 1]) + nz * (z - V[ia, 2])
            W += w
            S += w * s
            gw0 += wx
            gw1 += wy
            gw2 += wz
            gs0 += w * nx + s * wx
            gs1 += w * ny + s * wy
            gs2 += w * nz + s * wz
    if not (W > 0.0):
        return 0.0, 0.0
    phi = S / W
    g[0] = (gs0 - phi * gw0) / W
    g[1] = (gs1 - phi * gw1) / W
    g[2] = (gs2 - phi * gw2) / W
    return phi, W


@njit(cache=True)
def smooth_phi(margs, P, phi_out, grad_out, weight_out):
    """phi [m], grad phi (N,3) and the weight sum W over the rows of P (float64 (N,3) [m]).
    W = 0 marks points with no face within the smoothing radius (phi and grad 0 there)."""
    g = np.empty(3)
    stack = np.empty(128, dtype=np.int64)
    r = margs.params[14]
    for i in range(P.shape[0]):
        phi, W = _blend(margs, P[i, 0], P[i, 1], P[i, 2], r, g, stack)
        phi_out[i] = phi
        weight_out[i] = W
        grad_out[i, 0] = g[0]
        grad_out[i, 1] = g[1]
        grad_out[i, 2] = g[2]


@njit(cache=True)
def _onto(margs, r, cx, cy, cz, g, stack, tol):
    """Newton steps onto phi = 0 from c; returns (cx, cy, cz, ok) with g the gradient at the
    returned point (|phi| / |g| <= tol there when ok)."""
    prev = np.inf
    for _ in range(_NEWTON_ITERS):
        phi, W = _blend(margs, cx, cy, cz, r, g, stack)
        if not (W > 0.0):
            return cx, cy, cz, False
        gg = g[0] * g[0] + g[1] * g[1] + g[2] * g[2]
        if not (gg > 0.0):
            return cx, cy, cz, False
        step = abs(phi) / math.sqrt(gg)
        if step <= tol:
            return cx, cy, cz, True
        if not (step < prev):  # roundoff floor reached
            return cx, cy, cz, step <= 1e3 * tol
        prev = step
        a = phi / gg
        cx -= a * g[0]
        cy -= a * g[1]
        cz -= a * g[2]
    return cx, cy, cz, False


@njit(cache=True)
def _smooth_foot(margs, px, py, pz, cx, cy, cz, g, stack):
    """Closest point c on {phi = 0} to p, started from c; returns (cx, cy, cz, nx, ny, nz, sd,
    ok): the unit normal n(c) and sd = (p - c).n(c) [m]."""
    r = margs.params[14]
    tol = 1e-15 * margs.params[15] + 1e-300
    prev = np.inf
    damp = 1.0
    for _ in range(_FOOT_ITERS):
        cx, cy, cz, ok = _onto(margs, r, cx, cy, cz, g, stack, tol)
        if not ok:
            break
        gl = math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
        nx = g[0] / gl
        ny = g[1] / gl
        nz = g[2] / gl
        wx = px - cx
        wy = py - cy
        wz = pz - cz
        s = wx * nx + wy * ny + wz * nz
        tx = wx - s * nx
        ty = wy - s * ny
        tz = wz - s * nz
        tl = math.sqrt(tx * tx + ty * ty + tz * tz)
        if tl <= _FOOT_TOL:
            return cx, cy, cz, nx, ny, nz, s, True
        if tl >= prev:
            damp *= 0.5
            if damp < 1e-3:
                break
        prev = tl
        cx += damp * tx
        cy += damp * ty
        cz += damp * tz
    return cx, cy, cz, 0.0, 0.0, 1.0, 0.0, False


@njit(cache=True)
def _nearest_face(margs, code, idx):
    if code == 0:
        return idx
    if code == 1:
        return margs.edge_faces[idx, 0]
    return margs.vertex_face_idx[margs.vertex_face_ptr[idx]]


@njit(cache=True)
def _smooth_query_flag(margs, px, py, pz, out):
    """Signed distance [m] to the smooth surface; fills out[0:8] (see the module docstring).
    Returns (sd, smooth): smooth False when the faceted answer was used."""
    sdf = _mesh_query(margs, px, py, pz, out)
    code = int(out[6])
    if code < 0:
        return sdf, False
    idx = int(out[7])
    out[6] = 0.0
    out[7] = _nearest_face(margs, code, idx)
    if not (abs(sdf) < margs.params[14]):
        return sdf, False
    if margs.info[1] == 0 and sdf > 0.0:
        # open mesh: a point whose foot is on the rim and which is not directly behind a face is
        # outside (the faceted open-mesh rule), so the region beyond the rim stays free
        if (code == 1 and margs.edge_faces[idx, 1] < 0) or (code == 2 and margs.vertex_boundary[idx] != 0):
            return sdf, False
    g = np.empty(3)
    stack = np.empty(128, dtype=np.int64)
    cx, cy, cz, nx, ny, nz, sd, ok = _smooth_foot(margs, px, py, pz, out[0], out[1], out[2], g,
                                                  stack)
    if not ok:
        return sdf, False
    out[0] = cx
    out[1] = cy
    out[2] = cz
    out[3] = nx
    out[4] = ny
    out[5] = nz
    return sd, True


@njit(cache=True)
def _smooth_query(margs, px, py, pz, out):
    """Signed distance [m] to the smooth surface of a ``MOLD_SMOOTH`` mold; fills out[0:8]."""
    sd, _ = _smooth_query_flag(margs, px, py, pz, out)
    return sd
