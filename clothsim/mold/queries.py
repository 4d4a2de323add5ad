"""Rigid molds the fabric nodes may not enter.

A :class:`Mold` is either a triangle mesh (any format trimesh reads, the paper's own
points/triangles text format, legacy ASCII VTK polydata, VRML 2.0 ``IndexedFaceSet``) or an
analytic primitive (sphere, finite capped cylinder, half-space, axis-aligned box). Loading and
validation are plain Python/numpy; the queries used inside solver loops are ``@njit(cache=True)``
pure functions of the tuple of arrays returned by :meth:`Mold.kernel_args` (called ``margs``).

Conventions (every kernel):

* **Signed distance** [m]: negative inside the mold (the forbidden region), zero on the surface,
  positive outside.
* ``out`` of :func:`mold_query` (float64, length >= 8): ``out[0:3]`` the exact closest point on the
  surface [m]; ``out[3:6]`` the unit outward contact normal; ``out[6]`` the feature code
  (``FEATURE_FACE = 0``, ``FEATURE_EDGE = 1``, ``FEATURE_VERTEX = 2``); ``out[7]`` the feature's
  index (face id, edge id or vertex id of the mesh; for primitives see :func:`mold_query`).
* The contact normal is the face normal on a face interior and the angle-weighted pseudo-normal on
  an edge or a vertex (Baerentzen & Aanaes 2005, "Signed distance computation using the angle
  weighted pseudonormal", IEEE TVCG 11(3)). With it, ``sign(dot(p - closest, normal))`` is the
  correct inside/outside sign everywhere on a closed, consistently oriented mesh, including convex
  and concave edges and vertices. Ties between features at the same distance are resolved towards
  the lower-dimensional feature (vertex over edge over face), which is where the pseudo-normal is
  needed.
* **Closed mesh**: inside is the enclosed volume (normals are made to point outward at load).
* **Open mesh** (e.g. only the top skin of a mold): the forbidden side is behind the surface (the
  side the triangle normals point away from). Precisely: a point is inside iff its closest feature is
  a face, an interior edge or an interior vertex and ``dot(p - closest, pseudo_normal) < 0``; or its
  closest feature is on the open boundary (a boundary edge or boundary vertex) and ``p - closest``
  is anti-parallel to the normal of one of the faces adjacent to that feature (to a relative
  tolerance of 1e-9), i.e. the point lies directly behind a face, with its foot exactly on the
  boundary. Every other point whose closest feature is on the boundary is outside, so the forbidden
  region of a skin is the slab of points whose foot on the skin lies in the skin's interior and the
  region beyond the rim is free.

References: C. Ericson, *Real-Time Collision Detection* (2005), 5.1.5 (closest point on triangle),
6.2 (bounding volume hierarchies); T. Moller & B. Trumbore (1997), "Fast, minimum storage
ray-triangle intersection"; J. A. Baerentzen & H. Aanaes (2005), see above.
"""

from __future__ import annotations

import io
import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numba import njit

__all__ = [
    "MoldError",
    "Mold",
    "MOLD_MESH",
    "MOLD_SPHERE",
    "MOLD_CYLINDER",
    "MOLD_PLANE",
    "MOLD_BOX",
    "FEATURE_FACE",
    "FEATURE_EDGE",
    "FEATURE_VERTEX",
    "QUERY_OUT_SIZE",
    "load_mold",
    "load_mold_bytes",
    "mold_from_arrays",
    "mold_primitive",
    "mold_query",
    "mold_feature_normals",
    "mold_contact_normals",
    "mold_segment_hit",
    "mold_query_many",
]

MOLD_MESH = 1
MOLD_SPHERE = 2
MOLD_CYLINDER = 3
MOLD_PLANE = 4
MOLD_BOX = 5

FEATURE_FACE = 0
FEATURE_EDGE = 1
FEATURE_VERTEX = 2

#: minimum length of the ``out`` array of :func:`mold_query`
QUERY_OUT_SIZE = 8

_KIND_NAMES = {MOLD_MESH: "mesh", MOLD_SPHERE: "sphere", MOLD_CYLINDER: "cylinder",
               MOLD_PLANE: "plane", MOLD_BOX: "box"}

_PAPER_EXTS = {".txt", ".pts", ".tri"}
_VTK_EXTS = {".vtk"}
_VRML_EXTS = {".wrl", ".vrml"}
_TRIMESH_EXTS = {".stl", ".obj", ".ply", ".off", ".glb", ".gltf"}

# relative tolerances used by the kernels
_BARY_EPS = 1e-9      # barycentric slack of a ray hit; hits closer to an edge are confirmed by a probe
_T_EPS = 1e-10        # segment-parameter slack at t = 0 and t = 1
_PROBE_REL = 1e-8     # probe step for edge/vertex hits, relative to the mesh bounding-box diagonal
_BEHIND_REL = 1e-9    # open boundary: "directly behind a face" tolerance (relative lateral offset)


class MoldError(ValueError):
    """A mold file or spec cannot be used. The message names the file (and line where known)."""


# --------------------------------------------------------------------------------------------
# the Mold record
# --------------------------------------------------------------------------------------------


def _ro(a: np.ndarray, dtype) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=dtype)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Mold:
    """A rigid mold: constant arrays queried by the njit kernels through :meth:`kernel_args`.

    For primitives the mesh arrays are empty (with their proper dtype and number of dimensions)
    so that every mold has the same numba type and the kernels compile once.
    """

    kind: int
    """``MOLD_MESH``, ``MOLD_SPHERE``, ``MOLD_CYLINDER``, ``MOLD_PLANE`` or ``MOLD_BOX``."""
    params: np.ndarray
    """float64 (16,): primitive parameters [m] (unit vectors dimensionless).
    sphere: center[0:3], radius[3]; cylinder: center[0:3], unit axis[3:6], radius[6], length[7]
    (the cylinder spans center +- axis*length/2); plane: point[0:3], unit outward normal[3:6]
    (the mold is the half-space below); box: min corner[0:3], max corner[3:6];
    mesh: params[15] = bounding-box diagonal [m]."""
    vertices: np.ndarray
    """float64 (V, 3) [m]: mesh vertices (exact duplicates merged, unreferenced removed)."""
    faces: np.ndarray
    """int64 (F, 3): vertex ids of each triangle, counter-clockwise seen from outside."""
    closed: bool
    """True: watertight mesh (inside = enclosed volume), or any primitive. False: open skin."""
    source: str
    """Where the mold came from (file path, upload name or a description)."""
    face_normals: np.ndarray
    """float64 (F, 3): unit outward face normals."""
    vertex_normals: np.ndarray
    """float64 (V, 3): unit angle-weighted vertex pseudo-normals."""
    edges: np.ndarray
    """int64 (E, 2): vertex ids of each unique edge (sorted pair)."""
    edge_normals: np.ndarray
    """float64 (E, 3): unit edge pseudo-normals (normalised sum of the adjacent face normals)."""
    face_edges: np.ndarray
    """int64 (F, 3): edge id of the edge (faces[f,k], faces[f,(k+1)%3]) for k = 0, 1, 2."""
    edge_faces: np.ndarray
    """int64 (E, 2): the one or two faces adjacent to each edge; -1 marks a boundary edge."""
    vertex_face_ptr: np.ndarray
    """int64 (V+1,): CSR offsets into ``vertex_face_idx`` (the faces around each vertex)."""
    vertex_face_idx: np.ndarray
    """int64 (sum of valences,): face ids around each vertex."""
    vertex_boundary: np.ndarray
    """int64 (V,): 1 if the vertex lies on a boundary edge of an open mesh, else 0."""
    bvh_min: np.ndarray
    """float64 (N, 3) [m]: lower corner of each BVH node's box (slightly padded)."""
    bvh_max: np.ndarray
    """float64 (N, 3) [m]: upper corner of each BVH node's box (slightly padded)."""
    bvh_child: np.ndarray
    """int64 (N, 2): the two children of each BVH node; -1 on leaves. Node 0 is the root."""
    bvh_range: np.ndarray
    """int64 (N, 2): (start, count) of each node's faces in ``bvh_faces``."""
    bvh_faces: np.ndarray
    """int64 (F,): face ids ordered so that every node's faces are contiguous."""
    max_feature_normals: int
    """Rows ``normals_out`` of :func:`mold_feature_normals` needs (max vertex valence, >= 3)."""

    # ---- API -----------------------------------------------------------------------------
    @property
    def kind_name(self) -> str:
        return _KIND_NAMES[self.kind]

    @property
    def bounds(self) -> np.ndarray:
        """float64 (2, 3) [m]: [min corner, max corner]. A plane is unbounded: +-inf on every
        axis except, for an axis-aligned normal, the upper (or lower) bound along that axis."""
        p = self.params
        if self.kind == MOLD_MESH:
            return np.array([self.vertices.min(0), self.vertices.max(0)])
        if self.kind == MOLD_SPHERE:
            c, r = p[0:3], p[3]
            return np.array([c - r, c + r])
        if self.kind == MOLD_CYLINDER:
            c, a, r, h = p[0:3], p[3:6], p[6], 0.5 * p[7]
            ext = h * np.abs(a) + r * np.sqrt(np.clip(1.0 - a * a, 0.0, None))
            return np.array([c - ext, c + ext])
        if self.kind == MOLD_BOX:
            return np.array([p[0:3], p[3:6]])
        b = np.array([[-np.inf] * 3, [np.inf] * 3])
        n = p[3:6]
        for ax in range(3):
            if abs(abs(n[ax]) - 1.0) < 1e-15:
                if n[ax] > 0:
                    b[1, ax] = p[ax]
                else:
                    b[0, ax] = p[ax]
        return b

    def kernel_args(self) -> tuple:
        """The tuple ``margs`` every kernel takes first (plain, read-only numpy arrays):

        ``(info int64 (2,) = [kind, closed], params, vertices, faces, face_normals,
        vertex_normals, edges, edge_normals, face_edges, edge_faces, vertex_face_ptr,
        vertex_face_idx, vertex_boundary, bvh_min, bvh_max, bvh_child, bvh_range, bvh_faces)``.
        """
        info = np.array([self.kind, 1 if self.closed else 0], dtype=np.int64)
        info.setflags(write=False)
        return (info, self.params, self.vertices, self.faces, self.face_normals,
                self.vertex_normals, self.edges, self.edge_normals, self.face_edges,
                self.edge_faces, self.vertex_face_ptr, self.vertex_face_idx,
                self.vertex_boundary, self.bvh_min, self.bvh_max, self.bvh_child,
                self.bvh_range, self.bvh_faces)

    def surface_mesh(self, resolution: int = 48, extent: float = 1.0):
        """A triangle mesh for display: ``(vertices float64 (V,3) [m], faces int64 (F,3))``.

        A mesh mold returns (copies of) itself; a primitive is tessellated with about
        ``resolution`` segments around; a plane becomes a square of side ``extent`` [m] centred on
        its point.
        """
        import trimesh

        p = self.params
        res = max(int(resolution), 8)
        if self.kind == MOLD_MESH:
            return self.vertices.copy(), self.faces.copy()
        if self.kind == MOLD_SPHERE:
            sub = int(np.clip(round(math.log2(max(res, 8) / 5.0)), 1, 6))
            m = trimesh.creation.icosphere(subdivisions=sub, radius=p[3])
            return np.asarray(m.vertices) + p[0:3], np.asarray(m.faces, dtype=np.int64)
        if self.kind == MOLD_CYLINDER:
            T = np.eye(4)
            T[:3, :3] = _frame_from_z(p[3:6])
            T[:3, 3] = p[0:3]
            m = trimesh.creation.cylinder(radius=p[6], height=p[7], sections=res, transform=T)
            return np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64)
        if self.kind == MOLD_BOX:
            T = np.eye(4)
            T[:3, 3] = 0.5 * (p[0:3] + p[3:6])
            m = trimesh.creation.box(extents=p[3:6] - p[0:3], transform=T)
            return np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64)
        R = _frame_from_z(p[3:6])
        h = 0.5 * float(extent)
        corners = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
        return corners @ R.T + p[0:3], np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)

    def __repr__(self) -> str:
        if self.kind == MOLD_MESH:
            return (f"Mold(mesh, {len(self.faces)} triangles, closed={self.closed}, "
                    f"source={self.source!r})")
        return f"Mold({self.kind_name}, params={self.params[:8].tolist()}, source={self.source!r})"


def _frame_from_z(axis) -> np.ndarray:
    """Rotation matrix whose third column is the unit vector ``axis``."""
    z = np.asarray(axis, float)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


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
    """BVH search for the closest point: returns (cx, cy, cz, feature_code, feature_id, d2)."""
    V = margs[2]
    F = margs[3]
    face_edges = margs[8]
    bmin = margs[13]
    bmax = margs[14]
    child = margs[15]
    rng = margs[16]
    order = margs[17]
    best = np.inf
    bx = 0.0
    by = 0.0
    bz = 0.0
    bcode = -1
    bidx = -1
    if bmin.shape[0] == 0:
        return bx, by, bz, bcode, bidx, best
    stack = np.empty(128, dtype=np.int64)
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack[sp]
        if _box_d2(bmin, bmax, n, px, py, pz) > best * (1.0 + 1e-12):
            continue
        if child[n, 0] < 0:
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
        else:
            l = child[n, 0]
            r = child[n, 1]
            dl = _box_d2(bmin, bmax, l, px, py, pz)
            dr = _box_d2(bmin, bmax, r, px, py, pz)
            if sp + 2 > stack.shape[0]:
                # cannot happen for the median-split trees built here (depth ~ log2 F)
                bigger = np.empty(stack.shape[0] * 2, dtype=np.int64)
                bigger[:sp] = stack[:sp]
                stack = bigger
            if dl <= dr:  # push the farther child first so the nearer one is searched first
                stack[sp] = r
                stack[sp + 1] = l
            else:
                stack[sp] = l
                stack[sp + 1] = r
            sp += 2
    return bx, by, bz, bcode, bidx, best


@njit(cache=True)
def _feature_normal(margs, code, idx):
    if code == 0:
        N = margs[4]
    elif code == 1:
        N = margs[7]
    else:
        N = margs[5]
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
    if margs[0][1] == 0:  # open surface: the boundary rule
        boundary = False
        if code == 1:
            boundary = margs[9][idx, 1] < 0
        elif code == 2:
            boundary = margs[12][idx] != 0
        if boundary:
            inside = False
            FN = margs[4]
            if code == 1:
                inside = _behind_face(FN, margs[9][idx, 0], wx, wy, wz, dist)
            else:
                ptr = margs[10]
                ring = margs[11]
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
    kind = margs[0][0]
    px = p[0]
    py = p[1]
    pz = p[2]
    if kind == MOLD_MESH:
        return _mesh_query(margs, px, py, pz, out)
    prm = margs[1]
    if kind == MOLD_SPHERE:
        return _sphere_query(prm, px, py, pz, out)
    if kind == MOLD_CYLINDER:
        return _cylinder_query(prm, px, py, pz, out)
    if kind == MOLD_PLANE:
        return _plane_query(prm, px, py, pz, out)
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
    Primitives: plane 1; box 1 / 2 / 3 on a face / edge / corner; sphere and cylinder side or rim
    return 0 because their normals depend on the point: use :func:`mold_contact_normals`
    (cylinder caps return their single normal).
    """
    kind = margs[0][0]
    code = int(feature_code)
    idx = int(feature_index)
    prm = margs[1]
    if kind == MOLD_MESH:
        FN = margs[4]
        if code == 0:
            return _put(normals_out, 0, FN[idx, 0], FN[idx, 1], FN[idx, 2])
        if code == 1:
            ef = margs[9]
            k = 0
            for j in range(2):
                f = ef[idx, j]
                if f >= 0:
                    k = _put(normals_out, k, FN[f, 0], FN[f, 1], FN[f, 2])
            return k
        ptr = margs[10]
        ring = margs[11]
        k = 0
        for j in range(ptr[idx], ptr[idx + 1]):
            f = ring[j]
            k = _put(normals_out, k, FN[f, 0], FN[f, 1], FN[f, 2])
        return k
    if kind == MOLD_PLANE:
        return _put(normals_out, 0, prm[3], prm[4], prm[5])
    if kind == MOLD_SPHERE:
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
    kind = margs[0][0]
    k = mold_feature_normals(margs, out[6], out[7], normals_out)
    if k > 0:
        return k
    if kind == MOLD_CYLINDER and out[6] == 1.0:
        prm = margs[1]
        sg = 1.0 if out[7] == 0.0 else -1.0
        q = math.sqrt(2.0)
        # pseudo-normal = (u + sg a)/sqrt2  =>  u = sqrt2 n - sg a
        ux = q * out[3] - sg * prm[3]
        uy = q * out[4] - sg * prm[4]
        uz = q * out[5] - sg * prm[5]
        k = _put(normals_out, 0, sg * prm[3], sg * prm[4], sg * prm[5])
        return _put(normals_out, k, ux, uy, uz)
    return _put(normals_out, 0, out[3], out[4], out[5])


@njit(cache=True)
def _interval_hit(lo, hi):
    """Entry parameter of the open inside-interval (lo, hi) if it starts within [0, 1], else -1."""
    if not (hi - lo > 1e-12):
        return -1.0
    if lo < -_T_EPS or lo > 1.0 + _T_EPS:
        return -1.0
    return min(max(lo, 0.0), 1.0)


@njit(cache=True)
def _quadratic_interval(A, B, C):
    """Open interval where A t^2 + B t + C < 0 (A > 0); (1, 0) if empty (or tangent)."""
    disc = B * B - 4.0 * A * C
    if not (disc > 1e-14 * (B * B + abs(4.0 * A * C))):
        return 1.0, 0.0
    sq = math.sqrt(disc)
    q = -0.5 * (B - sq) if B < 0.0 else -0.5 * (B + sq)
    t1 = q / A
    t2 = C / q if q != 0.0 else -t1
    if t1 > t2:
        t1, t2 = t2, t1
    return t1, t2


@njit(cache=True)
def _slab(p0, d, lo, hi, tlo, thi, closed=False):
    """Clip the running interval (tlo, thi) by the open slab lo < p0 + t d < hi (closed: with
    the bounds, lo <= p0 + t d <= hi, the BVH box test)."""
    if d == 0.0:
        if (lo <= p0 <= hi) if closed else (lo < p0 < hi):
            return tlo, thi
        return 1.0, 0.0
    a = (lo - p0) / d
    b = (hi - p0) / d
    if a > b:
        a, b = b, a
    return max(tlo, a), min(thi, b)


@njit(cache=True)
def _mesh_segment_hit(margs, p0, p1):
    V = margs[2]
    F = margs[3]
    FN = margs[4]
    bmin = margs[13]
    bmax = margs[14]
    child = margs[15]
    rng = margs[16]
    order = margs[17]
    dx = p1[0] - p0[0]
    dy = p1[1] - p0[1]
    dz = p1[2] - p0[2]
    dd = dx * dx + dy * dy + dz * dz
    if dd == 0.0 or bmin.shape[0] == 0:
        return -1.0
    dl = math.sqrt(dd)
    probe = _PROBE_REL * margs[1][15]
    best = 2.0
    qout = np.empty(8)
    q = np.empty(3)
    stack = np.empty(128, dtype=np.int64)
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack[sp]
        tlo = -_T_EPS
        thi = min(best, 1.0) + _T_EPS
        for k in range(3):
            tlo, thi = _slab(p0[k], (dx, dy, dz)[k], bmin[n, k], bmax[n, k], tlo, thi, True)
        if tlo > thi:
            continue
        if child[n, 0] >= 0:
            if sp + 2 > stack.shape[0]:
                bigger = np.empty(stack.shape[0] * 2, dtype=np.int64)
                bigger[:sp] = stack[:sp]
                stack = bigger
            stack[sp] = child[n, 0]
            stack[sp + 1] = child[n, 1]
            sp += 2
            continue
        start = rng[n, 0]
        for kk in range(start, start + rng[n, 1]):
            f = order[kk]
            ia = F[f, 0]
            ib = F[f, 1]
            ic = F[f, 2]
            e1x = V[ib, 0] - V[ia, 0]
            e1y = V[ib, 1] - V[ia, 1]
            e1z = V[ib, 2] - V[ia, 2]
            e2x = V[ic, 0] - V[ia, 0]
            e2y = V[ic, 1] - V[ia, 1]
            e2z = V[ic, 2] - V[ia, 2]
            # entering means d . n < 0; with n ~ e1 x e2 this is det = e1 . (d x e2) > 0
            pvx = dy * e2z - dz * e2y
            pvy = dz * e2x - dx * e2z
            pvz = dx * e2y - dy * e2x
            det = e1x * pvx + e1y * pvy + e1z * pvz
            e11 = e1x * e1x + e1y * e1y + e1z * e1z
            e22 = e2x * e2x + e2y * e2y + e2z * e2z
            if not (det * det > 1e-24 * e11 * e22 * dd) or det <= 0.0:
                continue
            if FN[f, 0] * dx + FN[f, 1] * dy + FN[f, 2] * dz >= 0.0:
                continue
            inv = 1.0 / det
            tx = p0[0] - V[ia, 0]
            ty = p0[1] - V[ia, 1]
            tz = p0[2] - V[ia, 2]
            u = (tx * pvx + ty * pvy + tz * pvz) * inv
            if u < -_BARY_EPS or u > 1.0 + _BARY_EPS:
                continue
            qx = ty * e1z - tz * e1y
            qy = tz * e1x - tx * e1z
            qz = tx * e1y - ty * e1x
            v = (dx * qx + dy * qy + dz * qz) * inv
            if v < -_BARY_EPS or u + v > 1.0 + _BARY_EPS:
                continue
            t = (e2x * qx + e2y * qy + e2z * qz) * inv
            if t < -_T_EPS or t > 1.0 + _T_EPS or t >= best:
                continue
            t = min(max(t, 0.0), 1.0)
            if u < _BARY_EPS or v < _BARY_EPS or u + v > 1.0 - _BARY_EPS:
                # on (or within rounding of) an edge or vertex: the segment may only graze the
                # surface there; confirm that just past the hit point it is inside
                q[0] = p0[0] + t * dx + probe * dx / dl
                q[1] = p0[1] + t * dy + probe * dy / dl
                q[2] = p0[2] + t * dz + probe * dz / dl
                if not (_mesh_query(margs, q[0], q[1], q[2], qout) < 0.0):
                    continue
            best = t
    return best if best <= 1.0 else -1.0


@njit(cache=True)
def mold_segment_hit(margs, p0, p1):
    """Smallest t in [0, 1] where p0 + t (p1 - p0) crosses the surface from outside to inside.

    Returns -1.0 if the segment does not enter the mold. A segment that starts on the surface
    and moves inward returns 0.0; one that only touches the surface (tangent, grazing a convex
    edge or vertex, sliding within a face) returns -1.0. The start point's own state is not a
    crossing: a segment starting strictly inside reports only a later re-entry (callers should
    project penetrating nodes first). Mesh: BVH + Moller-Trumbore on faces whose normal opposes
    the motion; hits within 1e-9 (barycentric) of an edge or vertex are confirmed by probing the
    signed distance 1e-8 x (bounding-box diagonal) beyond the hit. Primitives: analytic.
    """
    kind = margs[0][0]
    if kind == MOLD_MESH:
        return _mesh_segment_hit(margs, p0, p1)
    prm = margs[1]
    dx = p1[0] - p0[0]
    dy = p1[1] - p0[1]
    dz = p1[2] - p0[2]
    if dx == 0.0 and dy == 0.0 and dz == 0.0:
        return -1.0
    if kind == MOLD_PLANE:
        nx, ny, nz = prm[3], prm[4], prm[5]
        s0 = (p0[0] - prm[0]) * nx + (p0[1] - prm[1]) * ny + (p0[2] - prm[2]) * nz
        dn = dx * nx + dy * ny + dz * nz
        if not (dn < 0.0):
            return -1.0
        t = -s0 / dn
        if t < -_T_EPS or t > 1.0 + _T_EPS:
            return -1.0
        return min(max(t, 0.0), 1.0)
    if kind == MOLD_SPHERE:
        wx = p0[0] - prm[0]
        wy = p0[1] - prm[1]
        wz = p0[2] - prm[2]
        A = dx * dx + dy * dy + dz * dz
        B = 2.0 * (dx * wx + dy * wy + dz * wz)
        C = wx * wx + wy * wy + wz * wz - prm[3] * prm[3]
        lo, hi = _quadratic_interval(A, B, C)
        return _interval_hit(lo, hi)
    if kind == MOLD_CYLINDER:
        ax, ay, az = prm[3], prm[4], prm[5]
        wx = p0[0] - prm[0]
        wy = p0[1] - prm[1]
        wz = p0[2] - prm[2]
        da = dx * ax + dy * ay + dz * az
        wa = wx * ax + wy * ay + wz * az
        dpx = dx - da * ax
        dpy = dy - da * ay
        dpz = dz - da * az
        wpx = wx - wa * ax
        wpy = wy - wa * ay
        wpz = wz - wa * az
        A = dpx * dpx + dpy * dpy + dpz * dpz
        C = wpx * wpx + wpy * wpy + wpz * wpz - prm[6] * prm[6]
        if A <= 1e-30 * (dx * dx + dy * dy + dz * dz):
            if C < 0.0:
                lo, hi = -np.inf, np.inf
            else:
                return -1.0
        else:
            B = 2.0 * (dpx * wpx + dpy * wpy + dpz * wpz)
            lo, hi = _quadratic_interval(A, B, C)
        h = 0.5 * prm[7]
        lo, hi = _slab(wa, da, -h, h, lo, hi)
        return _interval_hit(lo, hi)
    # box
    lo = -np.inf
    hi = np.inf
    lo, hi = _slab(p0[0], dx, prm[0], prm[3], lo, hi)
    lo, hi = _slab(p0[1], dy, prm[1], prm[4], lo, hi)
    lo, hi = _slab(p0[2], dz, prm[2], prm[5], lo, hi)
    return _interval_hit(lo, hi)


@njit(cache=True)
def mold_query_many(margs, P, signed_dist_out, closest_out, normal_out, feature_out):
    """:func:`mold_query` over the rows of P (float64 (N, 3) [m]).

    Fills signed_dist_out (N,) [m], closest_out (N, 3) [m], normal_out (N, 3) and
    feature_out int64 (N, 2) = (feature code, feature index).
    """
    out = np.empty(8)
    p = np.empty(3)
    for i in range(P.shape[0]):
        p[0] = P[i, 0]
        p[1] = P[i, 1]
        p[2] = P[i, 2]
        signed_dist_out[i] = mold_query(margs, p, out)
        for k in range(3):
            closest_out[i, k] = out[k]
            normal_out[i, k] = out[3 + k]
        feature_out[i, 0] = int(out[6])
        feature_out[i, 1] = int(out[7])


# --------------------------------------------------------------------------------------------
# building a mesh mold (plain numpy)
# --------------------------------------------------------------------------------------------

_E3 = np.zeros((0, 3))
_I3 = np.zeros((0, 3), dtype=np.int64)
_I2 = np.zeros((0, 2), dtype=np.int64)
_I1 = np.zeros(0, dtype=np.int64)


def _unit_rows(a: np.ndarray, fallback=(0.0, 0.0, 1.0)) -> np.ndarray:
    n = np.linalg.norm(a, axis=1)
    ok = n > 0
    out = np.empty_like(a)
    out[ok] = a[ok] / n[ok, None]
    out[~ok] = fallback
    return out


def _build_bvh(V: np.ndarray, F: np.ndarray, leaf_size: int = 4):
    """Median-split AABB tree over triangle centroids (flat arrays, node 0 the root)."""
    nF = len(F)
    tri = V[F]
    fmin = tri.min(axis=1)
    fmax = tri.max(axis=1)
    cen = tri.mean(axis=1)
    cap = max(2 * nF, 1)
    bmin = np.empty((cap, 3))
    bmax = np.empty((cap, 3))
    child = -np.ones((cap, 2), dtype=np.int64)
    rng = np.zeros((cap, 2), dtype=np.int64)
    order = np.arange(nF, dtype=np.int64)
    count = 1
    stack = [(0, 0, nF)]
    while stack:
        node, s, e = stack.pop()
        idx = order[s:e]
        bmin[node] = fmin[idx].min(axis=0)
        bmax[node] = fmax[idx].max(axis=0)
        rng[node] = (s, e - s)
        if e - s <= leaf_size:
            continue
        c = cen[idx]
        ax = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        mid = (e - s) // 2
        part = np.argpartition(c[:, ax], mid)
        order[s:e] = idx[part]
        left, right = count, count + 1
        count += 2
        child[node] = (left, right)
        stack.append((right, s + mid, e))
        stack.append((left, s, s + mid))
    diag = float(np.linalg.norm(V.max(0) - V.min(0))) if len(V) else 0.0
    pad = 1e-9 * diag + 1e-300
    return (bmin[:count] - pad, bmax[:count] + pad, child[:count], rng[:count], order)


def _clean_mesh(V, F, source: str):
    """Merge exact duplicate vertices, drop degenerate and duplicate triangles (with warnings)."""
    V = np.asarray(V, dtype=np.float64).reshape(-1, 3) + 0.0  # +0.0 turns -0.0 into 0.0
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    if len(F) == 0:
        raise MoldError(f"{source}: no triangles")
    if len(V) == 0:
        raise MoldError(f"{source}: no vertices")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise MoldError(f"{source}: non-finite coordinates at vertex {i}: {V[i].tolist()}")
    if F.min() < 0 or F.max() >= len(V):
        f = int(np.flatnonzero((F < 0).any(1) | (F >= len(V)).any(1))[0])
        raise MoldError(f"{source}: triangle {f} has a vertex index out of range "
                        f"{F[f].tolist()} (there are {len(V)} vertices)")
    uniq, inv = np.unique(V, axis=0, return_inverse=True)
    F = inv.reshape(-1)[F]
    V = uniq
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    # degenerate: repeated vertex or zero area (relative to the mesh size)
    cr = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    area2 = np.linalg.norm(cr, axis=1)
    degenerate = ((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
                  | ~(area2 > 1e-14 * diag * diag))
    nd = int(degenerate.sum())
    F = F[~degenerate]
    nu = 0
    if len(F):
        key = np.sort(F, axis=1)
        _, first = np.unique(key, axis=0, return_index=True)
        keep = np.zeros(len(F), dtype=bool)
        keep[first] = True
        nu = int(len(F) - keep.sum())
        F = F[np.sort(first)]
    if nd:
        warnings.warn(f"{source}: dropped {nd} degenerate (zero-area) triangle(s)", stacklevel=3)
    if nu:
        warnings.warn(f"{source}: dropped {nu} duplicate triangle(s)", stacklevel=3)
    if len(F) == 0:
        raise MoldError(f"{source}: no triangles left after dropping degenerate/duplicate ones")
    used = np.unique(F)
    remap = -np.ones(len(V), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def _orient(V, F, closed: bool | None, source: str):
    """Make the winding consistent (trimesh); closed meshes outward, open ones keep the
    majority (area-weighted) orientation of the input."""
    import trimesh

    m = trimesh.Trimesh(vertices=V, faces=F, process=False, validate=False)
    edges_sorted = np.sort(m.edges, axis=1)
    _, counts = np.unique(edges_sorted, axis=0, return_counts=True)
    if counts.max() > 2:
        raise MoldError(f"{source}: non-manifold mesh ({int((counts > 2).sum())} edge(s) shared "
                        f"by more than two triangles)")
    watertight = bool((counts == 2).all())
    if closed is None:
        closed = watertight
    elif closed and not watertight:
        raise MoldError(f"{source}: declared closed but has {int((counts == 1).sum())} "
                        f"boundary edge(s)")
    before = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    if not m.is_winding_consistent:
        trimesh.repair.fix_winding(m)
        m = trimesh.Trimesh(vertices=V, faces=np.asarray(m.faces), process=False, validate=False)
        if not m.is_winding_consistent:
            raise MoldError(f"{source}: inconsistent triangle winding that could not be repaired "
                            f"(non-orientable surface?)")
    F2 = np.asarray(m.faces, dtype=np.int64).copy()
    if closed:
        trimesh.repair.fix_inversion(m, multibody=True)
        F2 = np.asarray(m.faces, dtype=np.int64).copy()
        vol = trimesh.Trimesh(vertices=V, faces=F2, process=False).volume
        if vol < 0:
            F2 = F2[:, ::-1].copy()
    else:
        after = np.cross(V[F2[:, 1]] - V[F2[:, 0]], V[F2[:, 2]] - V[F2[:, 0]])
        if np.sum(np.einsum("ij,ij->i", before, after)) < 0:
            F2 = F2[:, ::-1].copy()
    return F2, bool(closed)


def _build_mesh_mold(V, F, closed: bool | None, source: str) -> Mold:
    V, F = _clean_mesh(V, F, source)
    F, closed = _orient(V, F, closed, source)
    nV, nF = len(V), len(F)
    e0, e1, e2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    fn = _unit_rows(np.cross(e1 - e0, e2 - e0))
    # edges
    he = np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2)  # (3F, 2): (f,k)
    key = np.sort(he, axis=1)
    edges, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    face_edges = inv.reshape(nF, 3)
    nE = len(edges)
    edge_faces = -np.ones((nE, 2), dtype=np.int64)
    face_of_he = np.repeat(np.arange(nF), 3)
    o = np.argsort(inv, kind="stable")
    inv_s = inv[o]
    first = np.r_[True, inv_s[1:] != inv_s[:-1]]
    edge_faces[inv_s[first], 0] = face_of_he[o][first]
    second = ~first
    edge_faces[inv_s[second], 1] = face_of_he[o][second]
    en = fn[edge_faces[:, 0]].copy()
    two = edge_faces[:, 1] >= 0
    en[two] += fn[edge_faces[two, 1]]
    en = _unit_rows(en)
    bad = np.linalg.norm(en, axis=1) == 0
    en[bad] = fn[edge_faces[bad, 0]]
    # angle-weighted vertex pseudo-normals
    vn = np.zeros((nV, 3))
    tri = V[F]
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        ang = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
        np.add.at(vn, F[:, k], ang[:, None] * fn)
    zero = np.linalg.norm(vn, axis=1) == 0
    if zero.any():
        alt = np.zeros((nV, 3))
        for k in range(3):
            np.add.at(alt, F[:, k], fn)
        vn[zero] = alt[zero]
    vn = _unit_rows(vn)
    # vertex -> faces (CSR)
    flat_v = F.reshape(-1)
    flat_f = np.repeat(np.arange(nF, dtype=np.int64), 3)
    o = np.argsort(flat_v, kind="stable")
    vf_idx = flat_f[o]
    vf_ptr = np.zeros(nV + 1, dtype=np.int64)
    np.cumsum(np.bincount(flat_v, minlength=nV), out=vf_ptr[1:])
    vb = np.zeros(nV, dtype=np.int64)
    vb[edges[edge_faces[:, 1] < 0].reshape(-1)] = 1
    bmin, bmax, child, rng, order = _build_bvh(V, F)
    params = np.zeros(16)
    params[15] = float(np.linalg.norm(V.max(0) - V.min(0)))
    maxval = int(np.diff(vf_ptr).max()) if nV else 3
    return Mold(
        kind=MOLD_MESH, params=_ro(params, np.float64), vertices=_ro(V, np.float64),
        faces=_ro(F, np.int64), closed=closed, source=source,
        face_normals=_ro(fn, np.float64), vertex_normals=_ro(vn, np.float64),
        edges=_ro(edges, np.int64), edge_normals=_ro(en, np.float64),
        face_edges=_ro(face_edges, np.int64), edge_faces=_ro(edge_faces, np.int64),
        vertex_face_ptr=_ro(vf_ptr, np.int64), vertex_face_idx=_ro(vf_idx, np.int64),
        vertex_boundary=_ro(vb, np.int64), bvh_min=_ro(bmin, np.float64),
        bvh_max=_ro(bmax, np.float64), bvh_child=_ro(child, np.int64),
        bvh_range=_ro(rng, np.int64), bvh_faces=_ro(order, np.int64),
        max_feature_normals=max(maxval, 3),
    )


def mold_from_arrays(vertices, faces, closed: bool | None = None, source: str = "") -> Mold:
    """Mesh mold from arrays: vertices (V,3) [m], faces (F,3) vertex ids.

    ``closed=None`` detects watertightness; ``closed=True`` on a mesh with boundary edges is an
    error; ``closed=False`` treats even a watertight mesh as an open skin (winding kept).
    Exact duplicate vertices are merged; degenerate and duplicate triangles are dropped with a
    warning; inconsistent winding is repaired or reported.
    """
    return _build_mesh_mold(vertices, faces, closed, source or "<arrays>")


def _primitive(kind: int, params, source: str) -> Mold:
    prm = np.zeros(16)
    prm[: len(params)] = params
    return Mold(
        kind=kind, params=_ro(prm, np.float64), vertices=_ro(_E3, np.float64),
        faces=_ro(_I3, np.int64), closed=True, source=source,
        face_normals=_ro(_E3, np.float64), vertex_normals=_ro(_E3, np.float64),
        edges=_ro(_I2, np.int64), edge_normals=_ro(_E3, np.float64),
        face_edges=_ro(_I3, np.int64), edge_faces=_ro(_I2, np.int64),
        vertex_face_ptr=_ro(np.zeros(1, np.int64), np.int64), vertex_face_idx=_ro(_I1, np.int64),
        vertex_boundary=_ro(_I1, np.int64), bvh_min=_ro(_E3, np.float64),
        bvh_max=_ro(_E3, np.float64), bvh_child=_ro(_I2, np.int64), bvh_range=_ro(_I2, np.int64),
        bvh_faces=_ro(_I1, np.int64), max_feature_normals=3,
    )


def _vec(d: Mapping, key: str, src: str, n: int = 3) -> np.ndarray:
    if key not in d:
        raise MoldError(f"{src}: missing '{key}'")
    try:
        v = np.asarray(d[key], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as e:
        raise MoldError(f"{src}: '{key}' must be {n} numbers ({e})") from None
    if v.shape != (n,) or not np.isfinite(v).all():
        raise MoldError(f"{src}: '{key}' must be {n} finite numbers, got {d[key]!r}")
    return v


def _pos(d: Mapping, key: str, src: str) -> float:
    v = float(_vec(d, key, src, 1)[0])
    if not v > 0:
        raise MoldError(f"{src}: '{key}' must be positive, got {v}")
    return v


def _unit(v: np.ndarray, key: str, src: str) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if not n > 0:
        raise MoldError(f"{src}: '{key}' must be a non-zero vector")
    return v / n


def mold_primitive(kind: str, spec: Mapping) -> Mold:
    """Analytic mold: kind 'sphere' {center, radius}, 'cylinder' {center, axis, radius, length},
    'plane' {point, normal} (the mold is the half-space behind the normal), 'box' {min, max}."""
    src = f"{kind} mold"
    if not isinstance(spec, Mapping):
        raise MoldError(f"{src}: expected a mapping of parameters, got {spec!r}")
    allowed = {"sphere": {"center", "radius"}, "cylinder": {"center", "axis", "radius", "length"},
               "plane": {"point", "normal"}, "box": {"min", "max"}}
    if kind not in allowed:
        raise MoldError(f"unknown mold primitive {kind!r}")
    extra = set(spec) - allowed[kind]
    if extra:
        raise MoldError(f"{src}: unknown key(s) {sorted(extra)}")
    if kind == "sphere":
        c = _vec(spec, "center", src)
        return _primitive(MOLD_SPHERE, [*c, _pos(spec, "radius", src)],
                          f"sphere(center={c.tolist()}, radius={float(spec['radius'])})")
    if kind == "cylinder":
        c = _vec(spec, "center", src)
        a = _unit(_vec(spec, "axis", src), "axis", src)
        r, L = _pos(spec, "radius", src), _pos(spec, "length", src)
        return _primitive(MOLD_CYLINDER, [*c, *a, r, L],
                          f"cylinder(center={c.tolist()}, axis={a.tolist()}, radius={r}, "
                          f"length={L})")
    if kind == "plane":
        p = _vec(spec, "point", src)
        n = _unit(_vec(spec, "normal", src), "normal", src)
        return _primitive(MOLD_PLANE, [*p, *n], f"plane(point={p.tolist()}, normal={n.tolist()})")
    lo, hi = _vec(spec, "min", src), _vec(spec, "max", src)
    if not (hi > lo).all():
        raise MoldError(f"{src}: 'max' must exceed 'min' on every axis, got {lo} / {hi}")
    return _primitive(MOLD_BOX, [*lo, *hi], f"box(min={lo.tolist()}, max={hi.tolist()})")


# --------------------------------------------------------------------------------------------
# file readers: each returns (V float64 (V,3), F int64 (F,3)) and raises MoldError
# --------------------------------------------------------------------------------------------

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?|[-+]?(?:nan|inf|infinity)"


def _float(tok: str, name: str, lineno: int, what: str) -> float:
    try:
        v = float(tok.replace("D", "e").replace("d", "e"))
    except ValueError:
        raise MoldError(f"{name}: line {lineno}: {what}: {tok!r} is not a number") from None
    if not math.isfinite(v):
        raise MoldError(f"{name}: line {lineno}: {what}: non-finite coordinate {tok!r}")
    return v


def _int(tok: str, name: str, lineno: int, what: str) -> int:
    try:
        return int(tok)
    except ValueError:
        try:
            f = float(tok)
        except ValueError:
            f = math.nan
        if math.isfinite(f) and f == int(f):
            return int(f)
        raise MoldError(f"{name}: line {lineno}: {what}: {tok!r} is not an integer") from None


def _read_paper_text(text: str, name: str):
    """The paper's text format: point lines ``index x y z`` then triangle lines ``n1 n2 n3``.

    Triangles refer to the point indices as written (so 0- and 1-based files, and any other
    numbering, work); '#' starts a comment; commas/semicolons count as blanks; a line holding one
    or two integers only (a count header) is skipped.
    """
    labels, coords, label_lines = [], [], []
    tris, tri_lines = [], []
    in_tris = False
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].replace(",", " ").replace(";", " ").strip()
        if not line:
            continue
        toks = line.split()
        if len(toks) in (1, 2) and all(re.fullmatch(r"[+]?\d+", t) for t in toks):
            continue
        if len(toks) == 4:
            if in_tris:
                raise MoldError(f"{name}: line {lineno}: point line 'index x y z' after the "
                                f"triangle lines")
            labels.append(_int(toks[0], name, lineno, "point index"))
            coords.append([_float(t, name, lineno, "point") for t in toks[1:]])
            label_lines.append(lineno)
        elif len(toks) == 3:
            in_tris = True
            tris.append([_int(t, name, lineno, "triangle") for t in toks])
            tri_lines.append(lineno)
        else:
            raise MoldError(f"{name}: line {lineno}: expected 'index x y z' or 'n1 n2 n3', got "
                            f"{len(toks)} fields: {raw.strip()[:60]!r}")
    if not labels and not tris:
        raise MoldError(f"{name}: empty file (no points, no triangles)")
    if not labels:
        raise MoldError(f"{name}: no point lines 'index x y z'")
    if not tris:
        raise MoldError(f"{name}: no triangles")
    lab = np.asarray(labels, dtype=np.int64)
    order = np.argsort(lab, kind="stable")
    sl = lab[order]
    dup = np.flatnonzero(sl[1:] == sl[:-1])
    if len(dup):
        j = order[dup[0] + 1]
        raise MoldError(f"{name}: line {label_lines[j]}: duplicate point index {labels[j]}")
    T = np.asarray(tris, dtype=np.int64)
    pos = np.searchsorted(sl, T)
    pos_c = np.clip(pos, 0, len(sl) - 1)
    ok = sl[pos_c] == T
    if not ok.all():
        r = int(np.flatnonzero(~ok.all(axis=1))[0])
        bad = int(T[r][~ok[r]][0])
        raise MoldError(f"{name}: line {tri_lines[r]}: triangle index {bad} out of range "
                        f"(points are numbered {int(sl[0])}..{int(sl[-1])})")
    return np.asarray(coords, dtype=np.float64)[order], pos_c


def _read_vtk(data: bytes, name: str):
    """Legacy ASCII VTK, DATASET POLYDATA: POINTS and POLYGONS (fanned) / TRIANGLE_STRIPS."""
    text = data.decode("latin-1")
    lines = text.splitlines()
    if not lines or not lines[0].lstrip().lower().startswith("# vtk"):
        raise MoldError(f"{name}: line 1: not a legacy VTK file (expected '# vtk DataFile')")
    if len(lines) < 3:
        raise MoldError(f"{name}: truncated VTK header")
    fmt = lines[2].strip().upper()
    if fmt == "BINARY":
        raise MoldError(f"{name}: line 3: binary VTK is not supported; save it as ASCII "
                        f"(e.g. ParaView 'File > Save Data', Data Mode ASCII) or as STL/PLY")
    if fmt != "ASCII":
        raise MoldError(f"{name}: line 3: expected ASCII or BINARY, got {lines[2].strip()!r}")
    toks: list[tuple[str, int]] = []
    for i, ln in enumerate(lines[3:], 4):
        for t in ln.split():
            toks.append((t, i))
    pos = 0

    def take(what):
        nonlocal pos
        if pos >= len(toks):
            raise MoldError(f"{name}: unexpected end of file while reading {what}")
        pos += 1
        return toks[pos - 1]

    V = None
    polys: list[list[int]] = []
    poly_lines: list[int] = []
    dataset_seen = False
    while pos < len(toks):
        kw, ln = take("a keyword")
        K = kw.upper()
        if K == "DATASET":
            typ, ln2 = take("the dataset type")
            if typ.upper() != "POLYDATA":
                raise MoldError(f"{name}: line {ln2}: only 'DATASET POLYDATA' is supported, got "
                                f"{typ!r}")
            dataset_seen = True
        elif K == "POINTS":
            n = _int(take("POINTS count")[0], name, ln, "POINTS count")
            take("POINTS data type")
            vals = []
            for _ in range(3 * n):
                t, l3 = take("point coordinates")
                vals.append(_float(t, name, l3, "point"))
            V = np.asarray(vals, dtype=np.float64).reshape(-1, 3)
        elif K in ("POLYGONS", "TRIANGLE_STRIPS", "VERTICES", "LINES"):
            n = _int(take(f"{K} count")[0], name, ln, f"{K} count")
            size = _int(take(f"{K} size")[0], name, ln, f"{K} size")
            if pos < len(toks) and toks[pos][0].upper() == "OFFSETS":  # VTK >= 5.1 layout
                take("OFFSETS")
                take("OFFSETS type")
                offs = [_int(take("offsets")[0], name, ln, "offset") for _ in range(n)]
                t, l4 = take("CONNECTIVITY")
                if t.upper() != "CONNECTIVITY":
                    raise MoldError(f"{name}: line {l4}: expected CONNECTIVITY, got {t!r}")
                take("CONNECTIVITY type")
                conn, conn_lines = [], []
                for _ in range(size):
                    t, l5 = take("connectivity")
                    conn.append(_int(t, name, l5, "connectivity"))
                    conn_lines.append(l5)
                cells = [(conn[offs[i]:offs[i + 1]], conn_lines[offs[i]] if offs[i] < size else ln)
                         for i in range(n - 1)]
            else:
                cells = []
                for _ in range(n):
                    t, l4 = take(f"{K} cells")
                    k = _int(t, name, l4, f"{K} cell size")
                    ids = [_int(take(f"{K} cells")[0], name, l4, f"{K} cell") for _ in range(k)]
                    cells.append((ids, l4))
            if K == "POLYGONS":
                for ids, l4 in cells:
                    for j in range(1, len(ids) - 1):
                        polys.append([ids[0], ids[j], ids[j + 1]])
                        poly_lines.append(l4)
            elif K == "TRIANGLE_STRIPS":
                for ids, l4 in cells:
                    for j in range(len(ids) - 2):
                        tri = [ids[j], ids[j + 1], ids[j + 2]]
                        if j % 2:
                            tri = [tri[1], tri[0], tri[2]]
                        polys.append(tri)
                        poly_lines.append(l4)
        elif K in ("POINT_DATA", "CELL_DATA", "FIELD", "METADATA"):
            break
        else:
            raise MoldError(f"{name}: line {ln}: unexpected keyword {kw!r}")
    if not dataset_seen:
        raise MoldError(f"{name}: no 'DATASET POLYDATA' section")
    if V is None or len(V) == 0:
        raise MoldError(f"{name}: no POINTS")
    if not polys:
        raise MoldError(f"{name}: no triangles (no POLYGONS or TRIANGLE_STRIPS cells)")
    F = np.asarray(polys, dtype=np.int64)
    bad = (F < 0).any(1) | (F >= len(V)).any(1)
    if bad.any():
        r = int(np.flatnonzero(bad)[0])
        raise MoldError(f"{name}: line {poly_lines[r]}: polygon index out of range "
                        f"{F[r].tolist()} (there are {len(V)} points)")
    return V, F


def _match_bracket(text: str, start: int, open_ch: str, close_ch: str) -> int:
    depth = 0
    for i in range(start, len(text)):
        c = text[i]
        if c == open_ch:
            depth += 1
        elif c == close_ch:
            depth -= 1
            if depth == 0:
                return i
    return -1


def _read_vrml(data: bytes, name: str):
    """VRML 2.0: every IndexedFaceSet with ``coord Coordinate { point [...] }`` and
    ``coordIndex [...]`` (polygons fanned); Transform nodes are not applied."""
    text = data.decode("utf-8", errors="replace")
    head = text.lstrip()[:20]
    if not head.startswith("#VRML"):
        raise MoldError(f"{name}: line 1: not a VRML file (expected '#VRML V2.0 utf8')")
    if not head.startswith("#VRML V2.0"):
        raise MoldError(f"{name}: line 1: only VRML 2.0 is supported, got {head.splitlines()[0]!r}")
    # blank comments but keep offsets (so line numbers stay right)
    text = re.sub(r"#[^\n]*", lambda m: " " * len(m.group(0)), text)

    def line_of(off: int) -> int:
        return text.count("\n", 0, off) + 1

    Vs, Fs, nv = [], [], 0
    for m in re.finditer(r"\bIndexedFaceSet\b", text):
        b0 = text.find("{", m.end())
        b1 = _match_bracket(text, b0, "{", "}") if b0 >= 0 else -1
        if b1 < 0:
            raise MoldError(f"{name}: line {line_of(m.start())}: unterminated IndexedFaceSet")
        block_start = b0
        block = text[b0:b1]
        pm = re.search(r"\bcoord\s+(?:DEF\s+\S+\s+)?Coordinate\s*\{\s*point\s*\[", block)
        im = re.search(r"\bcoordIndex\s*\[", block)
        if pm is None or im is None:
            raise MoldError(f"{name}: line {line_of(m.start())}: IndexedFaceSet without "
                            f"'coord Coordinate {{ point [...] }}' and 'coordIndex [...]' "
                            f"(USE references are not supported)")
        p_end = block.find("]", pm.end())
        i_end = block.find("]", im.end())
        if p_end < 0 or i_end < 0:
            raise MoldError(f"{name}: line {line_of(m.start())}: unterminated '[' list")
        vals = []
        for tm in re.finditer(r"[^\s,]+", block[pm.end():p_end]):
            vals.append(_float(tm.group(0), name, line_of(block_start + pm.end() + tm.start()),
                               "point"))
        if len(vals) % 3:
            raise MoldError(f"{name}: line {line_of(block_start + pm.end())}: point list length "
                            f"{len(vals)} is not a multiple of 3")
        V = np.asarray(vals, dtype=np.float64).reshape(-1, 3)
        poly: list[int] = []
        poly_line = 0
        tris, lines_ = [], []
        toks = list(re.finditer(r"[^\s,]+", block[im.end():i_end])) + [None]
        for tm in toks:
            if tm is None:
                k = -1
            else:
                ln = line_of(block_start + im.end() + tm.start())
                k = _int(tm.group(0), name, ln, "coordIndex")
                if k >= 0 and not poly:
                    poly_line = ln
            if k < 0:
                for j in range(1, len(poly) - 1):
                    tris.append([poly[0], poly[j], poly[j + 1]])
                    lines_.append(poly_line)
                poly = []
            else:
                if k >= len(V):
                    raise MoldError(f"{name}: line {ln}: coordIndex {k} out of range "
                                    f"(there are {len(V)} points)")
                poly.append(k)
        if tris:
            Vs.append(V)
            Fs.append(np.asarray(tris, dtype=np.int64) + nv)
            nv += len(V)
    if not Fs:
        raise MoldError(f"{name}: no triangles (no IndexedFaceSet with faces)")
    return np.concatenate(Vs), np.concatenate(Fs)


def _read_trimesh(data: bytes, name: str, ext: str):
    import trimesh

    try:
        m = trimesh.load(io.BytesIO(data), file_type=ext.lstrip("."), force="mesh", process=False)
    except Exception as e:  # trimesh raises many kinds of errors on bad input
        raise MoldError(f"{name}: cannot parse as {ext.lstrip('.').upper()}: "
                        f"{type(e).__name__}: {e}") from None
    if isinstance(m, (list, tuple)):
        m = trimesh.util.concatenate(list(m))
    if not isinstance(m, trimesh.Trimesh):
        raise MoldError(f"{name}: no triangle mesh found (got {type(m).__name__})")
    V = np.asarray(m.vertices, dtype=np.float64)
    F = np.asarray(m.faces, dtype=np.int64)
    if len(F) == 0:
        raise MoldError(f"{name}: no triangles")
    return V, F


def _sniff(data: bytes) -> str | None:
    head = data[:512].lstrip()
    low = head.lower()
    if low.startswith(b"# vtk"):
        return ".vtk"
    if head.startswith(b"#VRML"):
        return ".wrl"
    if low.startswith(b"solid") or low.startswith(b"ply") or low.startswith(b"off"):
        return {b"s": ".stl", b"p": ".ply", b"o": ".off"}[low[:1]]
    if head.startswith(b"glTF"):
        return ".glb"
    try:
        txt = data[:4096].decode("ascii")
    except UnicodeDecodeError:
        return None
    for raw in txt.splitlines():
        line = raw.split("#", 1)[0].replace(",", " ").strip()
        if not line:
            continue
        toks = line.split()
        if len(toks) in (1, 2, 4) and all(re.fullmatch(_NUM, t, re.I) for t in toks):
            if len(toks) == 4:
                return ".txt"
            continue
        if toks[0] in ("v", "f", "vn", "o", "g", "mtllib", "usemtl"):
            return ".obj"
        return None
    return None


def _read_any(data: bytes, name: str):
    if len(data.strip()) == 0:
        raise MoldError(f"{name}: empty file")
    ext = Path(name).suffix.lower()
    if ext not in _PAPER_EXTS | _VTK_EXTS | _VRML_EXTS | _TRIMESH_EXTS:
        sniffed = _sniff(data)
        if sniffed is None:
            raise MoldError(f"{name}: unknown mold format {ext or '(no extension)'!r}; supported: "
                            f"STL, OBJ, PLY, OFF, GLB/glTF, the paper's .txt/.pts/.tri, "
                            f"legacy ASCII .vtk, VRML 2.0 .wrl")
        ext = sniffed
    if ext in _PAPER_EXTS:
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise MoldError(f"{name}: not a text file (expected the points/triangles text "
                            f"format)") from None
        return _read_paper_text(text, name)
    if ext in _VTK_EXTS:
        return _read_vtk(data, name)
    if ext in _VRML_EXTS:
        return _read_vrml(data, name)
    return _read_trimesh(data, name, ext)


# --------------------------------------------------------------------------------------------
# transforms and public loaders
# --------------------------------------------------------------------------------------------


def _rotation_xyz(deg) -> np.ndarray:
    """Rotation about x, then y, then z (angles in degrees): R = Rz @ Ry @ Rx."""
    rx, ry, rz = np.radians(np.asarray(deg, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _apply_transform(V: np.ndarray, name: str, scale=1.0, translate=None, rotate=None):
    """Scale (a positive number or three), then rotate (degrees about x, y, z), then translate."""
    src = f"{name}: transform"
    s = np.asarray(1.0 if scale is None else scale, dtype=np.float64).reshape(-1)
    if s.size not in (1, 3) or not np.isfinite(s).all() or not (s > 0).all():
        raise MoldError(f"{src}: 'scale' must be a positive number (or three), got {scale!r}")
    V = V * s
    if rotate is not None:
        V = V @ _rotation_xyz(_vec({"rotate": rotate}, "rotate", src)).T
    if translate is not None:
        V = V + _vec({"translate": translate}, "translate", src)
    return V


def load_mold_bytes(data: bytes, filename: str, *, scale=1.0, translate=None, rotate=None,
                    closed: bool | None = None) -> Mold:
    """Mold from file contents (an upload). ``filename`` only selects the format and names the
    mold in messages; nothing is written to disk."""
    name = str(filename)
    V, F = _read_any(bytes(data), name)
    V = _apply_transform(V, name, scale, translate, rotate)
    return _build_mesh_mold(V, F, closed, name)


def _spec_to_dict(spec: Any) -> dict:
    if hasattr(spec, "model_dump"):
        spec = spec.model_dump(exclude_none=True)
    if not isinstance(spec, Mapping):
        raise MoldError(f"mold spec must be a mapping, got {type(spec).__name__}")
    return {k: v for k, v in spec.items() if v is not None}


def load_mold(spec: Mapping | None, base_dir: Path | None = None) -> Mold | None:
    """Mold from a spec: ``None``; ``{"path": ..., "scale": s, "translate": [..], "rotate": [..],
    "closed": bool}`` (relative paths resolve against ``base_dir``); or one primitive
    ``{"sphere": {...}}``, ``{"cylinder": {...}}``, ``{"plane": {...}}``, ``{"box": {...}}``."""
    if spec is None:
        return None
    d = _spec_to_dict(spec)
    prims = [k for k in ("sphere", "cylinder", "plane", "box") if k in d]
    if "path" in d:
        extra = set(d) - {"path", "scale", "translate", "rotate", "closed"}
        if extra or prims:
            raise MoldError(f"mold spec for {d['path']}: unknown key(s) {sorted(extra | set(prims))}")
        path = Path(d["path"]).expanduser()
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        try:
            data = path.read_bytes()
        except OSError as e:
            raise MoldError(f"{path}: cannot read mold file: {e.strerror or e}") from None
        return load_mold_bytes(data, str(path), scale=d.get("scale", 1.0),
                               translate=d.get("translate"), rotate=d.get("rotate"),
                               closed=d.get("closed"))
    if len(prims) != 1 or len(d) != 1:
        raise MoldError(f"mold spec must have 'path' or exactly one of sphere/cylinder/plane/box, "
                        f"got keys {sorted(d)}")
    return mold_primitive(prims[0], d[prims[0]])
