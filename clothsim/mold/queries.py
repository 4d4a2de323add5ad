"""Closest-point and inside/outside queries of a mold: ``@njit(cache=True)`` pure functions of
the mold's kernel arguments ``margs`` (see :meth:`clothsim.mold.Mold.kernel_args`).

Conventions (signed distance, the ``out`` array, pseudo-normals, the open-mesh rule) are those
of the package docstring (:mod:`clothsim.mold`).

References: C. Ericson, *Real-Time Collision Detection* (2005), 5.1.5 (closest point on triangle),
6.2 (bounding volume hierarchies); J. A. Baerentzen & H. Aanaes (2005), "Signed distance
computation using the angle weighted pseudonormal", IEEE TVCG 11(3).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .leg import leg_query
from .record import MOLD_CYLINDER, MOLD_LEG, MOLD_MESH, MOLD_PLANE, MOLD_SMOOTH, MOLD_SPHERE

_BEHIND_REL = 1e-9    # open boundary: "directly behind a face" tolerance (relative lateral offset)


# --------------------------------------------------------------------------------------------
# numba kernels: geometry helpers
# --------------------------------------------------------------------------------------------


@njit(cache=True)
def _seg_closest(px, py, pz, ax, ay, az, bx, by, bz):
    """Closest point on segment ab to p and its parameter t in [0, 1]."""
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    l2 = dx * dx + dy * dy + dz * dz
    t = 0.0
    if l2 > 0.0:
        t = ((px - ax) * dx + (py - ay) * dy + (pz - az) * dz) / l2
        t = min(max(t, 0.0), 1.0)
    return ax + t * dx, ay + t * dy, az + t * dz, t


@njit(cache=True)
def _tri_closest(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Exact closest point on triangle abc to p (Ericson 5.1.5) and its Voronoi region.

    Region: 0 face interior, 1/2/3 vertex a/b/c, 4 edge ab, 5 edge bc, 6 edge ca.
    Boundary cases go to the lower-dimensional feature; degenerate triangles fall back to their
    edges, so no division by zero can occur.
    """
    abx = bx - ax
    aby = by - ay
    abz = bz - az
    acx = cx - ax
    acy = cy - ay
    acz = cz - az
    apx = px - ax
    apy = py - ay
    apz = pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az, 1
    bpx = px - bx
    bpy = py - by
    bpz = pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz, 2
    ab2 = abx * abx + aby * aby + abz * abz
    ac2 = acx * acx + acy * acy + acz * acz
    tol = 1e-12 * ab2 * ac2
    vc = d1 * d4 - d3 * d2
    if vc <= tol and d1 >= 0.0 and d3 <= 0.0:
        den = d1 - d3
        v = d1 / den if den > 0.0 else 0.0
        v = min(max(v, 0.0), 1.0)
        return ax + v * abx, ay + v * aby, az + v * abz, 4
    cpx = px - cx
    cpy = py - cy
    cpz = pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz, 3
    vb = d5 * d2 - d1 * d6
    if vb <= tol and d2 >= 0.0 and d6 <= 0.0:
        den = d2 - d6
        w = d2 / den if den > 0.0 else 0.0
        w = min(max(w, 0.0), 1.0)
        return ax + w * acx, ay + w * acy, az + w * acz, 6
    va = d3 * d6 - d5 * d4
    e1 = d4 - d3
    e2 = d5 - d6
    if va <= tol and e1 >= 0.0 and e2 >= 0.0:
        den = e1 + e2
        w = e1 / den if den > 0.0 else 0.0
        w = min(max(w, 0.0), 1.0)
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz), 5
    s = va + vb + vc
    if not (s > tol):
        # degenerate (needle/zero-area) triangle: closest point on its three edges
        best = np.inf
        rx = ax
        ry = ay
        rz = az
        reg = 1
        for k in range(3):
            if k == 0:
                qx, qy, qz, t = _seg_closest(px, py, pz, ax, ay, az, bx, by, bz)
                r = 1 if t <= 0.0 else (2 if t >= 1.0 else 4)
            elif k == 1:
                qx, qy, qz, t = _seg_closest(px, py, pz, bx, by, bz, cx, cy, cz)
                r = 2 if t <= 0.0 else (3 if t >= 1.0 else 5)
            else:
                qx, qy, qz, t = _seg_closest(px, py, pz, cx, cy, cz, ax, ay, az)
                r = 3 if t <= 0.0 else (1 if t >= 1.0 else 6)
            d = (px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2
            if d < best:
                best = d
                rx = qx
                ry = qy
                rz = qz
                reg = r
        return rx, ry, rz, reg
    v = vb / s
    w = vc / s
    return ax + v * abx + w * acx, ay + v * aby + w * acy, az + v * abz + w * acz, 0


@njit(cache=True)
def _box_d2(bmin, bmax, n, px, py, pz):
    """Squared distance from p to the axis-aligned box of BVH node n."""
    d = 0.0
    for a in range(3):
        c = px if a == 0 else (py if a == 1 else pz)
        v = bmin[n, a] - c
        if v <= 0.0:
            v = c - bmax[n, a]
        if v > 0.0:
            d += v * v
    return d


@njit(cache=True)
def _mesh_closest(margs, px, py, pz):
    """BVH search for the closest point: returns (cx, cy, cz, feature_code, feature_id, d2).

    Depth first, the nearer child first; a node's box distance is computed once (kept on the
    stack beside it) and a child already farther than the best answer so far is not pushed
    (the best only decreases, so it would be skipped when popped): the leaves are visited in
    the same order as by testing every node when popped, and the answer is the same."""
    V = margs.vertices
    F = margs.faces
    face_edges = margs.face_edges
    bmin = margs.bvh_min
    bmax = margs.bvh_max
    child = margs.bvh_child
    rng = margs.bvh_range
    order = margs.bvh_faces
    best = np.inf
    bx = 0.0
    by = 0.0
    bz = 0.0
    bcode = -1
    bidx = -1
    if bmin.shape[0] == 0:
        return bx, by, bz, bcode, bidx, best
    stack = np.empty(64, dtype=np.int64)
    sd2 = np.empty(64)
    stack[0] = 0
    sd2[0] = _box_d2(bmin, bmax, 0, px, py, pz)
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack[sp]
        if sd2[sp] > best * (1.0 + 1e-12):
            continue
        # descend to a leaf along the nearer children, pushing the farther ones
        while child[n, 0] >= 0:
            l = child[n, 0]
            r = child[n, 1]
            dl = _box_d2(bmin, bmax, l, px, py, pz)
            dr = _box_d2(bmin, bmax, r, px, py, pz)
            lim = best * (1.0 + 1e-12)
            if dl <= dr:
                near = l
                far = r
                dn = dl
                dfar = dr
            else:
                near = r
                far = l
                dn = dr
                dfar = dl
            if dfar <= lim:
                if sp >= stack.shape[0]:
                    # cannot happen for the median-split trees built here (depth ~ log2 F)
                    bigger = np.empty(2 * stack.shape[0], dtype=np.int64)
                    bigger[:sp] = stack[:sp]
                    stack = bigger
                    bigger2 = np.empty(stack.shape[0])
                    bigger2[:sp] = sd2[:sp]
                    sd2 = bigger2
                stack[sp] = far
                sd2[sp] = dfar
                sp += 1
            if dn > lim:
                n = -1
                break
            n = near
        if n < 0:
            continue
        start = rng[n, 0]
        for k in range(start, start + rng[n, 1]):
            f = order[k]
            ia = F[f, 0]
            ib = F[f, 1]
            ic = F[f, 2]
            cx, cy, cz, reg = _tri_closest(px, py, pz, V[ia, 0], V[ia, 1], V[ia, 2],
                                           V[ib, 0], V[ib, 1], V[ib, 2],
                                           V[ic, 0], V[ic, 1], V[ic, 2])
            d2 = (px - cx) ** 2 + (py - cy) ** 2 + (pz - cz) ** 2
            if reg == 0:
                code = 0
            elif reg <= 3:
                code = 2
            else:
                code = 1
            if d2 < best * (1.0 - 1e-12) or (d2 <= best * (1.0 + 1e-12) and code > bcode):
                best = d2
                bx = cx
                by = cy
                bz = cz
                bcode = code
                if reg == 0:
                    bidx = f
                elif reg <= 3:
                    bidx = F[f, reg - 1]
                else:
                    bidx = face_edges[f, reg - 4]
    return bx, by, bz, bcode, bidx, best


@njit(cache=True)
def _feature_normal(margs, code, idx):
    if code == 0:
        N = margs.face_normals
    elif code == 1:
        N = margs.edge_normals
    else:
        N = margs.vertex_normals
    return N[idx, 0], N[idx, 1], N[idx, 2]


@njit(cache=True)
def _mesh_query(margs, px, py, pz, out):
    """Signed distance to a mesh mold; fills out[0:8] (see mold_query)."""
    cx, cy, cz, code, idx, d2 = _mesh_closest(margs, px, py, pz)
    if code < 0:
        out[:] = 0.0
        out[5] = 1.0
        out[6] = -1.0
        out[7] = -1.0
        return np.inf
    nx, ny, nz = _feature_normal(margs, code, idx)
    wx = px - cx
    wy = py - cy
    wz = pz - cz
    dist = math.sqrt(d2)
    s = wx * nx + wy * ny + wz * nz
    inside = s < 0.0
    if margs.info[1] == 0:  # open surface: the boundary rule
        boundary = False
        if code == 1:
            boundary = margs.edge_faces[idx, 1] < 0
        elif code == 2:
            boundary = margs.vertex_boundary[idx] != 0
        if boundary:
            inside = False
            FN = margs.face_normals
            if code == 1:
                inside = _behind_face(FN, margs.edge_faces[idx, 0], wx, wy, wz, dist)
            else:
                ptr = margs.vertex_face_ptr
                ring = margs.vertex_face_idx
                for k in range(ptr[idx], ptr[idx + 1]):
                    if _behind_face(FN, ring[k], wx, wy, wz, dist):
                        inside = True
                        break
    out[0] = cx
    out[1] = cy
    out[2] = cz
    out[3] = nx
    out[4] = ny
    out[5] = nz
    out[6] = code
    out[7] = idx
    if dist == 0.0:
        return 0.0
    return -dist if inside else dist


@njit(cache=True)
def _behind_face(FN, f, wx, wy, wz, dist):
    """True if w = p - closest is anti-parallel to the normal of face f (p directly behind f)."""
    s = wx * FN[f, 0] + wy * FN[f, 1] + wz * FN[f, 2]
    if s >= 0.0:
        return False
    lx = wx - s * FN[f, 0]
    ly = wy - s * FN[f, 1]
    lz = wz - s * FN[f, 2]
    return math.sqrt(lx * lx + ly * ly + lz * lz) <= _BEHIND_REL * dist


@njit(cache=True)
def _any_perp(ax, ay, az):
    """A unit vector perpendicular to the unit vector a."""
    if abs(ax) < 0.9:
        hx, hy, hz = 1.0, 0.0, 0.0
    else:
        hx, hy, hz = 0.0, 1.0, 0.0
    ux = hy * az - hz * ay
    uy = hz * ax - hx * az
    uz = hx * ay - hy * ax
    l = math.sqrt(ux * ux + uy * uy + uz * uz)
    return ux / l, uy / l, uz / l


# --------------------------------------------------------------------------------------------
# primitives
# --------------------------------------------------------------------------------------------


@njit(cache=True)
def _sphere_query(prm, px, py, pz, out):
    wx = px - prm[0]
    wy = py - prm[1]
    wz = pz - prm[2]
    r = prm[3]
    l = math.sqrt(wx * wx + wy * wy + wz * wz)
    if l > 0.0:
        nx = wx / l
        ny = wy / l
        nz = wz / l
    else:
        nx, ny, nz = 0.0, 0.0, 1.0
    out[0] = prm[0] + r * nx
    out[1] = prm[1] + r * ny
    out[2] = prm[2] + r * nz
    out[3] = nx
    out[4] = ny
    out[5] = nz
    out[6] = 0.0
    out[7] = 0.0
    return l - r


@njit(cache=True)
def _cylinder_query(prm, px, py, pz, out):
    """Finite capped cylinder. Features: face 0 side, face 1 cap at +axis, face 2 cap at -axis;
    edge 0 rim at +axis, edge 1 rim at -axis."""
    cx, cy, cz = prm[0], prm[1], prm[2]
    ax, ay, az = prm[3], prm[4], prm[5]
    R = prm[6]
    h = 0.5 * prm[7]
    wx = px - cx
    wy = py - cy
    wz = pz - cz
    s = wx * ax + wy * ay + wz * az
    rx = wx - s * ax
    ry = wy - s * ay
    rz = wz - s * az
    rho = math.sqrt(rx * rx + ry * ry + rz * rz)
    if rho > 0.0:
        ux = rx / rho
        uy = ry / rho
        uz = rz / rho
    else:
        ux, uy, uz = _any_perp(ax, ay, az)
    sg = 1.0 if s >= 0.0 else -1.0
    dr = rho - R
    dz = abs(s) - h
    # 0 side, 1 cap, 2 rim
    if dr > 0.0 and dz > 0.0:
        feat = 2
        sd = math.sqrt(dr * dr + dz * dz)
    elif dr > 0.0:
        feat = 2 if dz == 0.0 else 0
        sd = dr
    elif dz > 0.0:
        feat = 2 if dr == 0.0 else 1
        sd = dz
    else:
        if dr == 0.0 and dz == 0.0:
            feat = 2
            sd = 0.0
        elif dr >= dz:
            feat = 0
            sd = dr
        else:
            feat = 1
            sd = dz
    if feat == 0:
        out[0] = cx + s * ax + R * ux
        out[1] = cy + s * ay + R * uy
        out[2] = cz + s * az + R * uz
        out[3] = ux
        out[4] = uy
        out[5] = uz
        out[6] = 0.0
        out[7] = 0.0
    elif feat == 1:
        out[0] = cx + sg * h * ax + rx
        out[1] = cy + sg * h * ay + ry
        out[2] = cz + sg * h * az + rz
        out[3] = sg * ax
        out[4] = sg * ay
        out[5] = sg * az
        out[6] = 0.0
        out[7] = 1.0 if sg > 0.0 else 2.0
    else:
        out[0] = cx + sg * h * ax + R * ux
        out[1] = cy + sg * h * ay + R * uy
        out[2] = cz + sg * h * az + R * uz
        q = 1.0 / math.sqrt(2.0)
        out[3] = q * (ux + sg * ax)
        out[4] = q * (uy + sg * ay)
        out[5] = q * (uz + sg * az)
        out[6] = 1.0
        out[7] = 0.0 if sg > 0.0 else 1.0
    return sd


@njit(cache=True)
def _plane_query(prm, px, py, pz, out):
    nx, ny, nz = prm[3], prm[4], prm[5]
    sd = (px - prm[0]) * nx + (py - prm[1]) * ny + (pz - prm[2]) * nz
    out[0] = px - sd * nx
    out[1] = py - sd * ny
    out[2] = pz - sd * nz
    out[3] = nx
    out[4] = ny
    out[5] = nz
    out[6] = 0.0
    out[7] = 0.0
    return sd


@njit(cache=True)
def _box_feature(prm, side, at_bound, out):
    """Fill normal, code and index of a box feature from the per-axis boundary flags.

    Faces: index 2*axis + side (side 0 = min, 1 = max). Edges: index 4*a + 2*s_b + s_c where a is
    the edge's free axis and b < c the two bounded axes. Vertices: s_x + 2 s_y + 4 s_z.
    """
    m = 0
    for k in range(3):
        if at_bound[k]:
            m += 1
    nx = 0.0
    ny = 0.0
    nz = 0.0
    for k in range(3):
        if at_bound[k]:
            v = 1.0 if side[k] == 1 else -1.0
            if k == 0:
                nx = v
            elif k == 1:
                ny = v
            else:
                nz = v
    l = math.sqrt(nx * nx + ny * ny + nz * nz)
    if l == 0.0:
        l = 1.0
        nz = 1.0
    out[3] = nx / l
    out[4] = ny / l
    out[5] = nz / l
    if m <= 1:
        idx = 0
        for k in range(3):
            if at_bound[k]:
                idx = 2 * k + side[k]
        out[6] = 0.0
        out[7] = idx
    elif m == 2:
        a = 0
        for k in range(3):
            if not at_bound[k]:
                a = k
        b = (a + 1) % 3
        c = (a + 2) % 3
        if b > c:
            b, c = c, b
        out[6] = 1.0
        out[7] = 4 * a + 2 * side[b] + side[c]
    else:
        out[6] = 2.0
        out[7] = side[0] + 2 * side[1] + 4 * side[2]


@njit(cache=True)
def _box_query(prm, px, py, pz, out):
    p = (px, py, pz)
    side = np.zeros(3, dtype=np.int64)
    at_bound = np.zeros(3, dtype=np.bool_)
    c = np.empty(3)
    outside = False
    for k in range(3):
        lo = prm[k]
        hi = prm[3 + k]
        v = p[k]
        if v < lo:
            c[k] = lo
            outside = True
        elif v > hi:
            c[k] = hi
            outside = True
        else:
            c[k] = v
    if outside:
        for k in range(3):
            if c[k] == prm[k]:
                at_bound[k] = True
                side[k] = 0
            elif c[k] == prm[3 + k]:
                at_bound[k] = True
                side[k] = 1
        d2 = (px - c[0]) ** 2 + (py - c[1]) ** 2 + (pz - c[2]) ** 2
        sd = math.sqrt(d2)
    else:
        best = np.inf
        bk = 0
        bs = 0
        for k in range(3):
            dlo = p[k] - prm[k]
            dhi = prm[3 + k] - p[k]
            if dlo < best:
                best = dlo
                bk = k
                bs = 0
            if dhi < best:
                best = dhi
                bk = k
                bs = 1
        if best == 0.0:
            for k in range(3):
                if p[k] == prm[k]:
                    at_bound[k] = True
                    side[k] = 0
                elif p[k] == prm[3 + k]:
                    at_bound[k] = True
                    side[k] = 1
        else:
            at_bound[bk] = True
            side[bk] = bs
            c[bk] = prm[3 * bs + bk]
        sd = -best
    out[0] = c[0]
    out[1] = c[1]
    out[2] = c[2]
    _box_feature(prm, side, at_bound, out)
    return sd


# --------------------------------------------------------------------------------------------
# public kernels
# --------------------------------------------------------------------------------------------


@njit(cache=True)
def mold_query(margs, p, out):
    """Signed distance [m] from point p (float64 (3,) [m]) to the mold (negative inside).

    Fills ``out`` (float64, len >= 8): closest surface point [m] in out[0:3], unit outward contact
    normal in out[3:6] (face normal on a face interior, angle-weighted pseudo-normal on an edge or
    vertex), feature code in out[6] (0 face, 1 edge, 2 vertex), feature index in out[7].

    Primitive feature ids: sphere face 0; plane face 0; cylinder faces 0 side / 1 cap at +axis /
    2 cap at -axis and edges (rims) 0 at +axis / 1 at -axis; box see ``_box_feature``
    (faces 2*axis+side, edges 4*axis+2*s_b+s_c, vertices s_x+2*s_y+4*s_z).
    """
    kind = margs.info[0]
    px = p[0]
    py = p[1]
    pz = p[2]
    if kind == MOLD_MESH:
        return _mesh_query(margs, px, py, pz, out)
    if kind == MOLD_SMOOTH:
        return _smooth_query(margs, px, py, pz, out)
    return primitive_query(kind, margs.params, px, py, pz, out)


@njit(cache=True)
def is_primitive(kind):
    """Whether the mold kind (margs.info[0]) is an analytic one (sphere, cylinder, plane, box),
    whose kernels read margs.params alone.

    Why the ``primitive_*`` kernels: a call that takes margs, a tuple of 22 arrays, costs numba a
    reference count increment and decrement on each of them (about 190 ns, 25 times a sphere's
    query), so the loops over every node call them with (kind, margs.params) on these molds."""
    return kind != MOLD_MESH and kind != MOLD_SMOOTH


@njit(cache=True, inline="always")
def primitive_query(kind, prm, px, py, pz, out):
    """:func:`mold_query` at the point (px, py, pz) [m] on an analytic mold (``is_primitive``;
    prm: margs.params): the same answer, from (kind, prm) alone."""
    if kind == MOLD_SPHERE:
        return _sphere_query(prm, px, py, pz, out)
    if kind == MOLD_CYLINDER:
        return _cylinder_query(prm, px, py, pz, out)
    if kind == MOLD_PLANE:
        return _plane_query(prm, px, py, pz, out)
    if kind == MOLD_LEG:
        return leg_query(prm, px, py, pz, out)
    return _box_query(prm, px, py, pz, out)


@njit(cache=True)
def _put(normals_out, k, x, y, z):
    if k < normals_out.shape[0]:
        normals_out[k, 0] = x
        normals_out[k, 1] = y
        normals_out[k, 2] = z
        return k + 1
    return k


@njit(cache=True)
def mold_feature_normals(margs, feature_code, feature_index, normals_out):
    """Outward normals of the faces adjacent to a feature; returns how many were written.

    ``normals_out`` float64 (K, 3); K >= ``Mold.max_feature_normals`` guarantees room (extra
    normals are dropped silently otherwise). Mesh: 1 for a face, 2 for an interior edge (1 for a
    boundary edge), the ring of faces around a vertex. A node in a groove can be in equilibrium
    with a reaction anywhere in the cone of these normals.
    Primitives: plane 1; box 1 / 2 / 3 on a face / edge / corner; a smooth mesh, sphere and
    cylinder side or rim return 0 because their normals depend on the point: use :func:`mold_contact_normals`
    (cylinder caps return their single normal).
    """
    kind = margs.info[0]
    code = int(feature_code)
    idx = int(feature_index)
    if kind == MOLD_SMOOTH:
        return 0  # point-dependent normal, like the sphere
    if kind == MOLD_MESH:
        FN = margs.face_normals
        if code == 0:
            return _put(normals_out, 0, FN[idx, 0], FN[idx, 1], FN[idx, 2])
        if code == 1:
            ef = margs.edge_faces
            k = 0
            for j in range(2):
                f = ef[idx, j]
                if f >= 0:
                    k = _put(normals_out, k, FN[f, 0], FN[f, 1], FN[f, 2])
            return k
        ptr = margs.vertex_face_ptr
        ring = margs.vertex_face_idx
        k = 0
        for j in range(ptr[idx], ptr[idx + 1]):
            f = ring[j]
            k = _put(normals_out, k, FN[f, 0], FN[f, 1], FN[f, 2])
        return k
    return primitive_feature_normals(kind, margs.params, code, idx, normals_out)


@njit(cache=True)
def primitive_feature_normals(kind, prm, code, idx, normals_out):
    """:func:`mold_feature_normals` of feature (code, idx) (int) on an analytic mold
    (``is_primitive``; prm: margs.params)."""
    if kind == MOLD_PLANE:
        return _put(normals_out, 0, prm[3], prm[4], prm[5])
    if kind == MOLD_SPHERE or kind == MOLD_LEG:
        return 0
    if kind == MOLD_CYLINDER:
        if code == 0 and idx == 1:
            return _put(normals_out, 0, prm[3], prm[4], prm[5])
        if code == 0 and idx == 2:
            return _put(normals_out, 0, -prm[3], -prm[4], -prm[5])
        return 0
    # box
    k = 0
    if code == 0:
        ax = idx // 2
        v = 1.0 if idx % 2 == 1 else -1.0
        return _put(normals_out, 0, v if ax == 0 else 0.0, v if ax == 1 else 0.0,
                    v if ax == 2 else 0.0)
    if code == 1:
        a = idx // 4
        b = (a + 1) % 3
        c = (a + 2) % 3
        if b > c:
            b, c = c, b
        sb = (idx // 2) % 2
        sc = idx % 2
        for ax, s in ((b, sb), (c, sc)):
            v = 1.0 if s == 1 else -1.0
            k = _put(normals_out, k, v if ax == 0 else 0.0, v if ax == 1 else 0.0,
                     v if ax == 2 else 0.0)
        return k
    for ax in range(3):
        s = (idx >> ax) & 1
        v = 1.0 if s == 1 else -1.0
        k = _put(normals_out, k, v if ax == 0 else 0.0, v if ax == 1 else 0.0,
                 v if ax == 2 else 0.0)
    return k


@njit(cache=True)
def mold_contact_normals(margs, p, out, normals_out):
    """The cone of contact normals at the closest feature of point p; returns the count (>= 1).

    Like :func:`mold_feature_normals` after :func:`mold_query`, but also covers point-dependent
    primitive normals (sphere; cylinder side; cylinder rim gives the cap normal and the side
    normal at p). out (8,): filled by that one query (closest point, pseudo-normal, feature), so
    a caller needs no second query for them.
    """
    mold_query(margs, p, out)
    return contact_normals_from_query(margs, out, normals_out)


@njit(cache=True)
def contact_normals_from_query(margs, out, normals_out):
    """:func:`mold_contact_normals` from the answer ``out`` (>= 8) of a :func:`mold_query` already
    made at the point (no query): the same normals, written into normals_out; returns the count."""
    kind = margs.info[0]
    if is_primitive(kind):
        return primitive_contact_normals(kind, margs.params, out, normals_out)
    k = mold_feature_normals(margs, out[6], out[7], normals_out)
    if k > 0:
        return k
    return _put(normals_out, 0, out[3], out[4], out[5])


@njit(cache=True)
def primitive_contact_normals(kind, prm, out, normals_out):
    """:func:`contact_normals_from_query` on an analytic mold (``is_primitive``; prm:
    margs.params): out (>= 8,) a query's answer, normals_out (K, 3) filled with the contact
    cone's unit normals; returns their number."""
    k = primitive_feature_normals(kind, prm, int(out[6]), int(out[7]), normals_out)
    if k > 0:
        return k
    if kind == MOLD_CYLINDER and out[6] == 1.0:
        sg = 1.0 if out[7] == 0.0 else -1.0
        q = math.sqrt(2.0)
        # pseudo-normal = (u + sg a)/sqrt2  =>  u = sqrt2 n - sg a
        ux = q * out[3] - sg * prm[3]
        uy = q * out[4] - sg * prm[4]
        uz = q * out[5] - sg * prm[5]
        k = _put(normals_out, 0, sg * prm[3], sg * prm[4], sg * prm[5])
        return _put(normals_out, k, ux, uy, uz)
    return _put(normals_out, 0, out[3], out[4], out[5])


@njit(cache=True, inline="always")
def query_at(prim, kind, prm, margs, p, out):
    """:func:`mold_query` (margs, p, out) at p (3,) [m]; on an analytic mold (prim =
    ``is_primitive(kind)``, prm = margs.params) through :func:`primitive_query`, the same answer
    without passing margs to a call (inlined: a loop over nodes pays no reference counts)."""
    if prim:
        return primitive_query(kind, prm, p[0], p[1], p[2], out)
    return mold_query(margs, p, out)


@njit(cache=True, inline="always")
def contact_normals_at(prim, kind, prm, margs, out, normals_out):
    """:func:`contact_normals_from_query` (margs, out, normals_out), through
    :func:`primitive_contact_normals` on an analytic mold (see :func:`query_at`)."""
    if prim:
        return primitive_contact_normals(kind, prm, out, normals_out)
    return contact_normals_from_query(margs, out, normals_out)


@njit(cache=True)
def mold_query_many(margs, P, signed_dist_out, closest_out, normal_out, feature_out):
    """:func:`mold_query` over the rows of P (float64 (N, 3) [m]).

    Fills signed_dist_out (N,) [m], closest_out (N, 3) [m], normal_out (N, 3) and
    feature_out int64 (N, 2) = (feature code, feature index).
    """
    out = np.empty(8)
    p = np.empty(3)
    kind = margs.info[0]
    prim = is_primitive(kind)
    prm = margs.params
    for i in range(P.shape[0]):
        p[0] = P[i, 0]
        p[1] = P[i, 1]
        p[2] = P[i, 2]
        signed_dist_out[i] = query_at(prim, kind, prm, margs, p, out)
        for k in range(3):
            closest_out[i, k] = out[k]
            normal_out[i, k] = out[3 + k]
        feature_out[i, 0] = int(out[6])
        feature_out[i, 1] = int(out[7])


# the smooth surface's kernels build on the helpers above (imported last: smooth imports them)
from .smooth import _smooth_query  # noqa: E402
