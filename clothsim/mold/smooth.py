"""The smooth contact surface of a triangle mesh (mold kind ``MOLD_SMOOTH``): ``@njit(cache=True)``
pure functions of the mold's kernel arguments ``margs``.

A membrane pressed onto a polyhedron carries line loads on its ridges, so the contact pressure on
a faceted scan does not converge under lattice refinement. A scanned body is smooth and its
triangles are only a sampling of it; this kind replaces the polyhedron, for contact, by a smooth
(G1, continuous-normal) surface through the mesh's vertices: the zero set of a partition-of-unity
blend of per-vertex osculating jets (an implicit surface in the family of Shen, O'Brien &
Shewchuk 2004, "Interpolating and approximating implicit surfaces from polygon soup", SIGGRAPH,
and of Ohtake et al. 2003, "Multi-level partition of unity implicits", SIGGRAPH)::

    phi(x) = sum_v w_v(x) s_v(x) / sum_v w_v(x),     w_v(x) = psi(|x - v| / r_v)
    s_v(x) = (x - v) . n_v - h_v(x1, x2),             x1 = (x - v) . t1_v,  x2 = (x - v) . t2_v
    h_v = a x1 + b x2 + c x1^2/2 + d x1 x2 + e x2^2/2 + f x1^3/6 + g x1^2 x2/2 + k x1 x2^2/2 + l x2^3/6

n_v the vertex's angle-weighted pseudo-normal, (t1_v, t2_v) its tangent frame, h_v the cubic
height function through v fitted to its 2-ring of neighbours (quadratic for vertices with fewer
than 12 neighbours; ``Mold.vertex_jets``, built by ``build._vertex_jets``), psi(t) = (1 - t)^4
(4 t + 1) for t < 1 (Wendland C2; 0 beyond; psi'(0) = 0). r_v [m] is the vertex's blending
radius: its base radius b_v (default 1.5 times its mean edge length, so a scan's dense hands and
face are not blended over the body's coarse scale; ``smoothing`` sets one for all; at most 3
median bases) raised to 1.25 x its longest edge, at most 3 b_v and 3 median bases (every point
of a face but the inside of triangles larger than about twice that lies in some vertex's
support; the inside of such a big triangle, flat on CAD molds, is answered by the faceted
query). Each weight carries the factor (median base / r_v)^4 (stored in the jet), so fine
vertices decide the surface wherever they overlap wide ones. Each BVH node is pruned by the
largest r_v of the vertices its faces own (``bvh_reach``).

phi is C1 with an analytic gradient. A cubic jet's height is exact to third order and its
curvature to second, so the surface converges to the sampled smooth body at about fourth order in
the edge length (the facets at second), and so do its normal and curvature: no facet stripes in
the pressure. Coplanar neighbourhoods give their plane exactly. (The lead's first design blended
the faces' planes instead. Measured on icospheres it undulates at the mesh's own wavelength with
about half the facets' sagitta, an O(1) curvature error; quadratic jets left a +-25 % curvature
ripple on the thermoform mold: see docs/method/smooth_surface.md.)

Queries (the conventions of :mod:`clothsim.mold`): the closest point c on {phi = 0} is found from
the faceted closest point by repeated projection of p onto the linearisation of phi at c (a
Newton step onto phi = 0 and a tangential fixed-point correction in one) until the step is below
1e-13 m, so that phi(c) = 0 and p - c is parallel to grad phi(c);
the signed distance is (p - c) . n(c), n = grad phi / |grad phi|, and the feature is code 0 (a
face, as on the analytic sphere) with the point-dependent normal n(c); ``out[7]`` is the nearest
mesh face. The faceted answer (still code 0, ``out[3:6]`` the faceted pseudo-normal) goes to
points farther than the largest r_v from the mesh (far outside or deep inside: never in contact),
to points whose foot iteration does not converge in 30 steps, and, on an open mesh, to points the
faceted open-mesh rule puts outside beyond the rim.

Thin parts thinner than about r (both sides' vertices within each other's supports) are blended
into one another: use a smaller ``smoothing`` or ``surface: faceted`` there.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .closest import _box_d2, _mesh_query, _tri_closest

_FOOT_TOL = 1e-13      # [m] tangential residual |p - c - ((p - c).n) n| of a converged foot point
_FOOT_ITERS = 30
# the foot iteration's and the shape operator's vertices are gathered once within this many
# median smoothing radii of the start point (``_gather``); steps within half of it reuse them
_GATHER_MARGIN = 0.25


@njit(cache=True, inline="always")
def _reaches(V, J, v, x, y, z, margin):
    """Whether vertex v's support (radius J[v, 15] [m]) plus margin [m] reaches the point
    (x, y, z) [m] (strictly; as the gathering loops tested it); V (nv, 3) [m] the vertices, J
    the jets."""
    dx = x - V[v, 0]
    dy = y - V[v, 1]
    dz = z - V[v, 2]
    rv = J[v, 15] + margin
    return not (dx * dx + dy * dy + dz * dz >= rv * rv)


@njit(cache=True, inline="always")
def _push(cand, nc, v):
    """cand[nc] = v, cand (K,) int64 doubled when full: (cand, nc + 1)."""
    if nc == cand.shape[0]:
        bigger = np.empty(2 * cand.shape[0], np.int64)
        bigger[:nc] = cand[:nc]
        cand = bigger
    cand[nc] = v
    return cand, nc + 1


@njit(cache=True)
def _gather(margs, x, y, z, margin, stack, cand):
    """The vertices whose support reaches within ``margin`` [m] of x (|x - v| < r_v + margin), in
    the order the BVH visits them (the order ``_blend`` sums them in), written to cand (int64,
    grown when full: the possibly new array is returned with the count). Points within
    ``margin`` of x have every vertex their blend sums among them, in the same order, so
    ``_blend_from`` gives the same bits as ``_blend`` there. stack: int64 scratch (>= 128)."""
    V = margs.vertices
    F = margs.faces
    J = margs.vertex_jets
    owner_ptr = margs.vertex_face_ptr
    owner_idx = margs.vertex_face_idx
    bmin = margs.bvh_min
    bmax = margs.bvh_max
    child = margs.bvh_child
    rng = margs.bvh_range
    order = margs.bvh_faces
    reach = margs.bvh_reach
    nc = 0
    if bmin.shape[0] == 0 or J.shape[0] != V.shape[0] or reach.shape[0] != bmin.shape[0]:
        return cand, -1
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack[sp]
        rr = reach[n] + margin
        if _box_d2(bmin, bmax, n, x, y, z) >= rr * rr:
            continue
        if child[n, 0] >= 0:
            if sp + 2 > stack.shape[0]:
                return cand, -1  # cannot happen for the median-split trees built here
            stack[sp] = child[n, 0]
            stack[sp + 1] = child[n, 1]
            sp += 2
            continue
        start = rng[n, 0]
        for k in range(start, start + rng[n, 1]):
            f = order[k]
            for j in range(3):
                v = F[f, j]
                if owner_idx[owner_ptr[v]] != f:
                    continue  # each vertex is visited once: from the first face of its ring
                if _reaches(V, J, v, x, y, z, margin):
                    cand, nc = _push(cand, nc, v)
    return cand, nc


# the face lists' slack [m] per metre of the mesh's bounding-box diagonal: the faceted closest
# point a query starts from lies on its face up to rounding
_FACE_LIST_SLACK = 1e-9


@njit(cache=True)
def face_vertex_lists(margs, max_entries):
    """Per face f of a smooth mesh, the vertices v whose support reaches within the foot
    iteration's gathering margin (``_GATHER_MARGIN`` median smoothing radii) of some point of f
    (distance from v to the triangle < r_v + margin, with a slack of 1e-9 bounding-box diagonals),
    in the order the BVH search visits them. Returns (ptr int64 (F+1,), idx int64 (M,)): the
    CSR lists (``Mold.face_vertex_ptr``). A point x on f then has, among f's list, every vertex
    ``_gather`` finds at x, in the same order (``_gather_face``). Empty lists (the queries then
    search the BVH, the same answers) when they would hold more than ``max_entries`` vertex
    numbers in all (``FACE_LIST_MAX_ENTRIES``: about 33 a face on the 13.8k-face scan at the
    default smoothing, 69 at smoothing 0.03 m; memory 8 bytes each)."""
    F = margs.faces
    V = margs.vertices
    J = margs.vertex_jets
    nf = F.shape[0]
    ptr = np.zeros(nf + 1, np.int64)
    idx = np.empty(16 * nf + 16, np.int64)
    margin = _GATHER_MARGIN * margs.params[14]
    slack = _FACE_LIST_SLACK * margs.params[15]
    stack = np.empty(128, np.int64)
    cand = np.empty(64, np.int64)
    m = 0
    for f in range(nf):
        a = F[f, 0]
        b = F[f, 1]
        c = F[f, 2]
        gx = (V[a, 0] + V[b, 0] + V[c, 0]) / 3.0
        gy = (V[a, 1] + V[b, 1] + V[c, 1]) / 3.0
        gz = (V[a, 2] + V[b, 2] + V[c, 2]) / 3.0
        rf = 0.0
        for j in range(3):
            v = F[f, j]
            rf = max(rf, math.sqrt((V[v, 0] - gx) ** 2 + (V[v, 1] - gy) ** 2 + (V[v, 2] - gz) ** 2))
        # every point of f is within rf of its centroid: a superset, in the BVH's order
        cand, nc = _gather(margs, gx, gy, gz, margin + rf + 2.0 * slack, stack, cand)
        if nc < 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        for i in range(nc):
            v = cand[i]
            qx, qy, qz, _ = _tri_closest(V[v, 0], V[v, 1], V[v, 2], V[a, 0], V[a, 1], V[a, 2],
                                         V[b, 0], V[b, 1], V[b, 2], V[c, 0], V[c, 1], V[c, 2])
            d = math.sqrt((V[v, 0] - qx) ** 2 + (V[v, 1] - qy) ** 2 + (V[v, 2] - qz) ** 2)
            if not (d < J[v, 15] + margin + slack):
                continue
            if m >= max_entries:
                return np.zeros(0, np.int64), np.zeros(0, np.int64)
            if m == idx.shape[0]:
                bigger = np.empty(min(2 * idx.shape[0], max_entries), np.int64)
                bigger[:m] = idx[:m]
                idx = bigger
            idx[m] = v
            m += 1
        ptr[f + 1] = m
    return ptr, idx[:m].copy()


#: the largest total length of the face lists (``face_vertex_lists``) a smooth mold keeps (128 MB);
#: a bigger scan or smoothing radius keeps none and its queries search the BVH
FACE_LIST_MAX_ENTRIES = 16_000_000


@njit(cache=True)
def _gather_face(margs, f, x, y, z, margin, cand):
    """``_gather`` at a point (x, y, z) [m] on face f (its faceted closest point) from f's list
    (``face_vertex_lists``, built for this margin [m]) instead of the BVH: the same vertices in
    the same order. cand (K,) int64: a buffer, grown when full. Returns (cand, count), count -1
    when the mesh has no lists."""
    ptr = margs.face_vertex_ptr
    if not (0 <= f < ptr.shape[0] - 1):
        return cand, -1
    V = margs.vertices
    J = margs.vertex_jets
    lst = margs.face_vertex_idx
    nc = 0
    for i in range(ptr[f], ptr[f + 1]):
        v = lst[i]
        if _reaches(V, J, v, x, y, z, margin):
            cand, nc = _push(cand, nc, v)
    return cand, nc


@njit(cache=True, inline="always")
def _blend_vertex(margs, v, x, y, z):
    """Vertex v's terms of the blend at x: (inside its support, w, w s, grad w (3), w grad s +
    s grad w (3)), the weight w and jet s of the module docstring."""
    V = margs.vertices
    VN = margs.vertex_normals
    J = margs.vertex_jets
    dx = x - V[v, 0]
    dy = y - V[v, 1]
    dz = z - V[v, 2]
    d2 = dx * dx + dy * dy + dz * dz
    rv = J[v, 15]
    if d2 >= rv * rv:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    t = math.sqrt(d2) / rv
    om = 1.0 - t
    om3 = om * om * om
    k4 = J[v, 16]
    w = k4 * om3 * om * (4.0 * t + 1.0)
    # grad w = k4 psi'(t)/rv * (x - v)/|x - v| = -20 k4 (1 - t)^3 (x - v) / rv^2
    a = -20.0 * k4 * om3 / (rv * rv)
    wx = a * dx
    wy = a * dy
    wz = a * dz
    # the vertex's jet: s = (x - v).n - h(x1, x2), x1, x2 its tangent coordinates
    nx = VN[v, 0]
    ny = VN[v, 1]
    nz = VN[v, 2]
    x1 = dx * J[v, 0] + dy * J[v, 1] + dz * J[v, 2]
    x2 = dx * J[v, 3] + dy * J[v, 4] + dz * J[v, 5]
    ca = J[v, 6]
    cb = J[v, 7]
    cc = J[v, 8]
    cd = J[v, 9]
    ce = J[v, 10]
    cf = J[v, 11]
    cg = J[v, 12]
    ck = J[v, 13]
    cl = J[v, 14]
    q11 = x1 * x1
    q12 = x1 * x2
    q22 = x2 * x2
    hv = (ca * x1 + cb * x2 + 0.5 * cc * q11 + cd * q12 + 0.5 * ce * q22
          + cf * q11 * x1 / 6.0 + 0.5 * cg * q11 * x2 + 0.5 * ck * x1 * q22
          + cl * q22 * x2 / 6.0)
    s = dx * nx + dy * ny + dz * nz - hv
    h1 = ca + cc * x1 + cd * x2 + 0.5 * cf * q11 + cg * q12 + 0.5 * ck * q22
    h2 = cb + cd * x1 + ce * x2 + 0.5 * cg * q11 + ck * q12 + 0.5 * cl * q22
    sx = nx - h1 * J[v, 0] - h2 * J[v, 3]
    sy = ny - h1 * J[v, 1] - h2 * J[v, 4]
    sz = nz - h1 * J[v, 2] - h2 * J[v, 5]
    return True, w, w * s, wx, wy, wz, w * sx + s * wx, w * sy + s * wy, w * sz + s * wz


@njit(cache=True, inline="always")
def _blend_add(margs, v, x, y, z, W, S, gw0, gw1, gw2, gs0, gs1, gs2):
    """The blend's eight running sums (W, S, grad W, grad S) with vertex v's terms at x added
    (``_blend_vertex``; unchanged when x is outside its support)."""
    ok, w, ws, wx, wy, wz, t0, t1, t2 = _blend_vertex(margs, v, x, y, z)
    if not ok:
        return W, S, gw0, gw1, gw2, gs0, gs1, gs2
    return W + w, S + ws, gw0 + wx, gw1 + wy, gw2 + wz, gs0 + t0, gs1 + t1, gs2 + t2


@njit(cache=True, inline="always")
def _blend_finish(W, S, gw0, gw1, gw2, gs0, gs1, gs2, g):
    """(phi, W) from the blend's sums, and its gradient into g (3,); (0, 0) and g = 0 where no
    vertex reaches."""
    g[0] = 0.0
    g[1] = 0.0
    g[2] = 0.0
    if not (W > 0.0):
        return 0.0, 0.0
    phi = S / W
    g[0] = (gs0 - phi * gw0) / W
    g[1] = (gs1 - phi * gw1) / W
    g[2] = (gs2 - phi * gw2) / W
    return phi, W


@njit(cache=True)
def _blend_from(margs, x, y, z, cand, nc, g):
    """``_blend`` at x summing over the candidates cand[:nc] of a ``_gather`` made within its
    margin of x (the same vertices in the same order: the same bits)."""
    W = 0.0
    S = 0.0
    gw0 = 0.0
    gw1 = 0.0
    gw2 = 0.0
    gs0 = 0.0
    gs1 = 0.0
    gs2 = 0.0
    for i in range(nc):
        W, S, gw0, gw1, gw2, gs0, gs1, gs2 = _blend_add(margs, cand[i], x, y, z, W, S, gw0, gw1, gw2, gs0, gs1,
                                                        gs2)
    return _blend_finish(W, S, gw0, gw1, gw2, gs0, gs1, gs2, g)


@njit(cache=True)
def _blend(margs, x, y, z, r, g, stack):
    """phi(x) [m] and its gradient g (3,) (filled); returns (phi, W), W = sum of the weights
    (0: no vertex's support reaches x; then phi = 0 and g = 0). r: unused (the vertices' own
    radii apply; kept for the call signature). stack: int64 scratch (>= 128)."""
    V = margs.vertices
    F = margs.faces
    J = margs.vertex_jets
    owner_ptr = margs.vertex_face_ptr
    owner_idx = margs.vertex_face_idx
    bmin = margs.bvh_min
    bmax = margs.bvh_max
    child = margs.bvh_child
    rng = margs.bvh_range
    order = margs.bvh_faces
    reach = margs.bvh_reach
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
    if bmin.shape[0] == 0 or J.shape[0] != V.shape[0] or reach.shape[0] != bmin.shape[0]:
        return 0.0, 0.0
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack[sp]
        if _box_d2(bmin, bmax, n, x, y, z) >= reach[n] * reach[n]:
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
            for j in range(3):
                v = F[f, j]
                if owner_idx[owner_ptr[v]] != f:
                    continue  # each vertex is visited once: from the first face of its ring
                W, S, gw0, gw1, gw2, gs0, gs1, gs2 = _blend_add(margs, v, x, y, z, W, S, gw0, gw1, gw2, gs0, gs1,
                                                                gs2)
    return _blend_finish(W, S, gw0, gw1, gw2, gs0, gs1, gs2, g)


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
def _smooth_foot(margs, px, py, pz, cx, cy, cz, g, stack, face=-1):
    """Closest point c on {phi = 0} to p, started from c; returns (cx, cy, cz, nx, ny, nz, sd,
    ok): the unit normal n(c) and sd = (p - c).n(c) [m].

    Each step projects p onto the linearisation of phi at the current c (one evaluation of phi
    and its gradient): c' = p - ((phi(c) + g.(p - c)) / |g|^2) g. Its fixed point is the foot
    (phi(c) = 0, p - c parallel to g); it converges quadratically onto the surface and, along it,
    linearly with the factor |sd| x curvature (fast for the near-surface points of contact).
    Stops when the step is below 1e-13 m (then |phi(c)| / |g| and the tangential residual are
    too); a growing step is halved; no convergence in 30 steps: ok False.

    The vertices near the start are gathered once (``_gather``, within ``_GATHER_MARGIN``
    median smoothing radii) and the steps within half that of it sum over them alone, instead
    of searching the BVH at every step: the same vertices in the same order, the same bits.
    face >= 0: c lies on that face (the faceted closest point), and they are gathered from its
    list (``_gather_face``), again the same."""
    prev = np.inf
    damp = 1.0
    margin = _GATHER_MARGIN * margs.params[14]
    cand = np.empty(64, np.int64)
    nc = -1
    if face >= 0:
        cand, nc = _gather_face(margs, face, cx, cy, cz, margin, cand)
    if nc < 0:
        cand, nc = _gather(margs, cx, cy, cz, margin, stack, cand)
    x0 = cx
    y0 = cy
    z0 = cz
    lim = 0.25 * margin * margin
    for _ in range(_FOOT_ITERS):
        ex = cx - x0
        ey = cy - y0
        ez = cz - z0
        if nc >= 0 and ex * ex + ey * ey + ez * ez <= lim:
            phi, W = _blend_from(margs, cx, cy, cz, cand, nc, g)
        else:
            phi, W = _blend(margs, cx, cy, cz, 0.0, g, stack)
        if not (W > 0.0):
            break
        gg = g[0] * g[0] + g[1] * g[1] + g[2] * g[2]
        if not (gg > 0.0):
            break
        wx = px - cx
        wy = py - cy
        wz = pz - cz
        lam = (phi + g[0] * wx + g[1] * wy + g[2] * wz) / gg
        dx = wx - lam * g[0]
        dy = wy - lam * g[1]
        dz = wz - lam * g[2]
        step = math.sqrt(dx * dx + dy * dy + dz * dz)
        if step <= _FOOT_TOL:
            gl = math.sqrt(gg)
            nx = g[0] / gl
            ny = g[1] / gl
            nz = g[2] / gl
            return cx, cy, cz, nx, ny, nz, wx * nx + wy * ny + wz * nz, True
        if step >= prev:
            damp *= 0.5
            if damp < 1e-3:
                break
        prev = step
        cx += damp * dx
        cy += damp * dy
        cz += damp * dz
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
    if not (abs(sdf) < margs.params[13]):
        return sdf, False
    if margs.info[1] == 0 and sdf > 0.0:
        # open mesh: a point whose foot is on the rim and which is not directly behind a face is
        # outside (the faceted open-mesh rule), so the region beyond the rim stays free
        if (code == 1 and margs.edge_faces[idx, 1] < 0) or (code == 2 and margs.vertex_boundary[idx] != 0):
            return sdf, False
    g = np.empty(3)
    stack = np.empty(128, dtype=np.int64)
    cx, cy, cz, nx, ny, nz, sd, ok = _smooth_foot(margs, px, py, pz, out[0], out[1], out[2], g,
                                                  stack, int(out[7]))
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


@njit(cache=True)
def smooth_shape_operator(margs, px, py, pz, h, n_out, S_out):
    """The smooth surface's unit normal n (3,) (filled into n_out) and its shape operator
    S = d n / d x restricted to the tangent plane (3,3) [1/m] (filled into S_out, symmetric,
    S n = 0; positive on convex parts: a sphere of radius R gives (I - n n^T) / R) at a point
    p [m] on the surface, from forward differences of grad phi over h [m] along two tangents
    (three evaluations of phi, no foot iteration). Returns False (S = 0) where phi is not
    defined (no vertex's support reaches p)."""
    g0 = np.empty(3)
    g1 = np.empty(3)
    g2 = np.empty(3)
    stack = np.empty(128, dtype=np.int64)
    for a in range(3):
        for b in range(3):
            S_out[a, b] = 0.0
    # the three points are within h of p: one gather serves them (the same bits as _blend).
    # From the list of p's nearest face f (``face_vertex_lists``) when p is within the list's
    # margin of f less 4 h: a vertex whose support reaches within 4 h of p is then within
    # r_v + margin of f, so it is on the list, in the BVH's order (extra vertices, outside every
    # support, add nothing: the same bits)
    margin = max(_GATHER_MARGIN * margs.params[14], 4.0 * h)
    cand = np.empty(64, np.int64)
    nc = -1
    if margs.face_vertex_ptr.shape[0] > 0 and h > 0.0:
        q = np.empty(8)
        sdf = _mesh_query(margs, px, py, pz, q)
        code = int(q[6])
        if code >= 0 and abs(sdf) + 4.0 * h <= _GATHER_MARGIN * margs.params[14]:
            margin = 4.0 * h
            cand, nc = _gather_face(margs, _nearest_face(margs, code, int(q[7])), px, py, pz, margin, cand)
    if nc < 0:
        margin = max(_GATHER_MARGIN * margs.params[14], 4.0 * h)
        cand, nc = _gather(margs, px, py, pz, margin, stack, cand)
    if nc < 0 or not (h <= 0.5 * margin):
        nc = -1  # a variable, not a literal -1 in the call: that compiled this and two callees twice
    return _shape_operator_blend(margs, px, py, pz, h, n_out, S_out, g0, g1, g2, stack, cand, nc)


@njit(cache=True)
def _blend_at(margs, x, y, z, g, stack, cand, nc):
    """``_blend`` at x, over the gathered candidates when nc >= 0."""
    if nc >= 0:
        return _blend_from(margs, x, y, z, cand, nc, g)
    return _blend(margs, x, y, z, 0.0, g, stack)


@njit(cache=True)
def _shape_operator_blend(margs, px, py, pz, h, n_out, S_out, g0, g1, g2, stack, cand, nc):
    """The body of ``smooth_shape_operator`` (cand[:nc]: the vertices gathered at p, nc < 0: none)."""
    _, W = _blend_at(margs, px, py, pz, g0, stack, cand, nc)
    gl = math.sqrt(g0[0] * g0[0] + g0[1] * g0[1] + g0[2] * g0[2])
    if not (W > 0.0 and gl > 0.0):
        return False
    nx = g0[0] / gl
    ny = g0[1] / gl
    nz = g0[2] / gl
    n_out[0] = nx
    n_out[1] = ny
    n_out[2] = nz
    # tangent frame
    if abs(nx) < 0.9:
        ax, ay, az = 1.0, 0.0, 0.0
    else:
        ax, ay, az = 0.0, 1.0, 0.0
    d = ax * nx + ay * ny + az * nz
    t1x = ax - d * nx
    t1y = ay - d * ny
    t1z = az - d * nz
    tl = math.sqrt(t1x * t1x + t1y * t1y + t1z * t1z)
    t1x /= tl
    t1y /= tl
    t1z /= tl
    t2x = ny * t1z - nz * t1y
    t2y = nz * t1x - nx * t1z
    t2z = nx * t1y - ny * t1x
    _, W1 = _blend_at(margs, px + h * t1x, py + h * t1y, pz + h * t1z, g1, stack, cand, nc)
    _, W2 = _blend_at(margs, px + h * t2x, py + h * t2y, pz + h * t2z, g2, stack, cand, nc)
    if not (W1 > 0.0 and W2 > 0.0):
        return False
    s = 1.0 / (h * gl)
    # S_ab = t_a . (g(p + h t_b) - g(p)) / (h |g|), symmetrised
    s11 = ((g1[0] - g0[0]) * t1x + (g1[1] - g0[1]) * t1y + (g1[2] - g0[2]) * t1z) * s
    s22 = ((g2[0] - g0[0]) * t2x + (g2[1] - g0[1]) * t2y + (g2[2] - g0[2]) * t2z) * s
    s12 = 0.5 * s * ((g2[0] - g0[0]) * t1x + (g2[1] - g0[1]) * t1y + (g2[2] - g0[2]) * t1z
                     + (g1[0] - g0[0]) * t2x + (g1[1] - g0[1]) * t2y + (g1[2] - g0[2]) * t2z)
    t1 = (t1x, t1y, t1z)
    t2 = (t2x, t2y, t2z)
    for a in range(3):
        for b in range(3):
            S_out[a, b] = s11 * t1[a] * t1[b] + s22 * t2[a] * t2[b] + s12 * (t1[a] * t2[b] + t2[a] * t1[b])
    return True
