"""The :class:`Mold` record: constant arrays describing a rigid mold, the kind and feature codes,
and :class:`MoldError`. Plain Python/numpy; the kernels that query it live in ``queries`` and
``segment``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .leg import leg_mesh

MOLD_MESH = 1
MOLD_SPHERE = 2
MOLD_CYLINDER = 3
MOLD_PLANE = 4
MOLD_BOX = 5
#: a triangle mesh queried through its smooth (G1) blended surface (see :mod:`clothsim.mold.smooth`)
MOLD_SMOOTH = 6
#: a limb from a size chart's girths (see :mod:`clothsim.mold.leg`): an analytic surface
MOLD_LEG = 7

FEATURE_FACE = 0
FEATURE_EDGE = 1
FEATURE_VERTEX = 2

#: minimum length of the ``out`` array of :func:`mold_query`
QUERY_OUT_SIZE = 8

_KIND_NAMES = {MOLD_MESH: "mesh", MOLD_SPHERE: "sphere", MOLD_CYLINDER: "cylinder",
               MOLD_PLANE: "plane", MOLD_BOX: "box", MOLD_SMOOTH: "smooth mesh", MOLD_LEG: "leg"}
#: the kinds that carry a triangle mesh (drawn, exported and sized as that mesh)
MESH_KINDS = (MOLD_MESH, MOLD_SMOOTH)


_NO_JETS = np.zeros((0, 20))
_NO_JETS.setflags(write=False)
_NO_REACH = np.zeros(0)
_NO_REACH.setflags(write=False)
_NO_LIST = np.zeros(0, dtype=np.int64)
_NO_LIST.setflags(write=False)


class MoldError(ValueError):
    """A mold file or spec cannot be used. The message names the file (and line where known)."""


# --------------------------------------------------------------------------------------------
# the Mold record
# --------------------------------------------------------------------------------------------


class MoldArgs(NamedTuple):
    """A mold's arrays as the njit kernels take them (numba passes a named tuple of arrays at no
    cost, and fields are read by name). Same numba type for every mold: primitives carry empty
    mesh arrays. Field order is the historical positional order (``margs[9]`` is ``edge_faces``),
    so callers indexing by position keep working."""

    info: np.ndarray
    """int64 (2,): [kind, closed] (kind a ``MOLD_*`` code; closed 1 or 0)."""
    params: np.ndarray
    """float64 (16,): see :attr:`Mold.params`."""
    vertices: np.ndarray
    """float64 (V, 3) [m]."""
    faces: np.ndarray
    """int64 (F, 3)."""
    face_normals: np.ndarray
    """float64 (F, 3), unit."""
    vertex_normals: np.ndarray
    """float64 (V, 3), unit pseudo-normals."""
    edges: np.ndarray
    """int64 (E, 2)."""
    edge_normals: np.ndarray
    """float64 (E, 3), unit pseudo-normals."""
    face_edges: np.ndarray
    """int64 (F, 3)."""
    edge_faces: np.ndarray
    """int64 (E, 2); -1 marks a boundary edge."""
    vertex_face_ptr: np.ndarray
    """int64 (V+1,): CSR offsets."""
    vertex_face_idx: np.ndarray
    """int64 (sum of valences,)."""
    vertex_boundary: np.ndarray
    """int64 (V,): 1 on the open boundary."""
    bvh_min: np.ndarray
    """float64 (N, 3) [m]."""
    bvh_max: np.ndarray
    """float64 (N, 3) [m]."""
    bvh_child: np.ndarray
    """int64 (N, 2); -1 on leaves."""
    bvh_range: np.ndarray
    """int64 (N, 2): (start, count) in ``bvh_faces``."""
    bvh_faces: np.ndarray
    """int64 (F,)."""
    vertex_jets: np.ndarray
    """float64 (V, 20) on a smooth mesh, else (0, 20): see :attr:`Mold.vertex_jets`."""
    bvh_reach: np.ndarray
    """float64 (N,) on a smooth mesh, else (0,): see :attr:`Mold.bvh_reach`."""
    face_vertex_ptr: np.ndarray
    """int64 (F+1,) on a smooth mesh, else (0,): see :attr:`Mold.face_vertex_ptr`."""
    face_vertex_idx: np.ndarray
    """int64 (M,) on a smooth mesh, else (0,): see :attr:`Mold.face_vertex_ptr`."""


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
    """``MOLD_MESH``, ``MOLD_SMOOTH`` (the same mesh, contact on its smooth blended surface),
    ``MOLD_SPHERE``, ``MOLD_CYLINDER``, ``MOLD_PLANE`` or ``MOLD_BOX``."""
    params: np.ndarray
    """float64 (16,): primitive parameters [m] (unit vectors dimensionless).
    sphere: center[0:3], radius[3]; cylinder: center[0:3], unit axis[3:6], radius[6], length[7]
    (the cylinder spans center +- axis*length/2); plane: point[0:3], unit outward normal[3:6]
    (the mold is the half-space below); box: min corner[0:3], max corner[3:6];
    leg: see :mod:`clothsim.mold.leg` (longer than 16);
    mesh: params[15] = bounding-box diagonal [m]; smooth mesh: also params[14] = the median
    smoothing radius [m], params[13] = the largest blending radius [m] (points farther from the
    mesh get the faceted answer), params[12] = the smoothing asked for (0: adaptive)
    (see :mod:`clothsim.mold.smooth`)."""
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
    vertex_jets: np.ndarray = None  # type: ignore[assignment]
    """float64 (V, 20) on a smooth mesh (``MOLD_SMOOTH``), (0, 20) otherwise: per vertex its
    local frame t1[0:3], t2[3:6] (with the vertex normal, a right-handed frame), the fitted
    osculating jet's coefficients a, b, c, d, e, f, g, k, l [6:15] (height over the tangent plane
    h = a x1 + b x2 + c x1^2/2 + d x1 x2 + e x2^2/2 + f x1^3/6 + g x1^2 x2/2 + k x1 x2^2/2
    + l x2^3/6, x in m), its blending radius r_v [m] at [15], its weight factor (r / r_v)^4 at
    [16] and its base smoothing radius r [m] at [17] (see :mod:`clothsim.mold.smooth`)."""
    bvh_reach: np.ndarray = None  # type: ignore[assignment]
    """float64 (N,) on a smooth mesh, (0,) otherwise: per BVH node the largest blending radius
    [m] of the vertices owned by its faces (a vertex is owned by the first face of its ring), so
    the smooth surface's vertex search prunes each node by its own reach."""
    face_vertex_ptr: np.ndarray = None  # type: ignore[assignment]
    """int64 (F+1,) on a smooth mesh, (0,) otherwise: CSR offsets into ``face_vertex_idx``, per
    face the vertices whose support reaches within the foot iteration's gathering margin of some
    point of the face (|x - v| < r_v + margin for some x on it), in the order the BVH search
    visits them (``smooth.face_vertex_lists``): a query started on the face gathers its vertices
    from this list instead of searching the tree (the same vertices in the same order)."""
    face_vertex_idx: np.ndarray = None  # type: ignore[assignment]
    """int64 (M,) on a smooth mesh, (0,) otherwise: see ``face_vertex_ptr``."""
    surface_note: str = ""
    """A mesh mold whose spec left the surface to the default: which surface
    :func:`clothsim.mold.build.auto_surface` chose and why, in words; empty otherwise."""

    def __post_init__(self):
        if self.vertex_jets is None:
            object.__setattr__(self, "vertex_jets", _NO_JETS)
        if self.bvh_reach is None:
            object.__setattr__(self, "bvh_reach", _NO_REACH)
        if self.face_vertex_ptr is None:
            object.__setattr__(self, "face_vertex_ptr", _NO_LIST)
        if self.face_vertex_idx is None:
            object.__setattr__(self, "face_vertex_idx", _NO_LIST)

    # ---- API -----------------------------------------------------------------------------
    @property
    def kind_name(self) -> str:
        return _KIND_NAMES[self.kind]

    @property
    def surface(self) -> str | None:
        """'faceted' or 'smooth' for a mesh mold, None for a primitive."""
        return {MOLD_MESH: "faceted", MOLD_SMOOTH: "smooth"}.get(self.kind)

    @property
    def smoothing(self) -> float | None:
        """The (median) smoothing radius r [m] of a smooth mesh mold, else None."""
        return float(self.params[14]) if self.kind == MOLD_SMOOTH else None

    @property
    def bounds(self) -> np.ndarray:
        """float64 (2, 3) [m]: [min corner, max corner]. A plane is unbounded: +-inf on every
        axis except, for an axis-aligned normal, the upper (or lower) bound along that axis."""
        p = self.params
        if self.kind in MESH_KINDS:
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
        if self.kind == MOLD_LEG:
            # the drawn extent: one ``extend`` beyond the end levels (the surface goes on)
            return np.array([[p[0] - p[5], p[1] - p[5], p[6] - p[4]], [p[0] + p[5], p[1] + p[5], p[7] + p[4]]])
        b = np.array([[-np.inf] * 3, [np.inf] * 3])
        n = p[3:6]
        for ax in range(3):
            if abs(abs(n[ax]) - 1.0) < 1e-15:
                if n[ax] > 0:
                    b[1, ax] = p[ax]
                else:
                    b[0, ax] = p[ax]
        return b

    def kernel_args(self) -> "MoldArgs":
        """The :class:`MoldArgs` named tuple every kernel takes first (called ``margs``): plain,
        read-only numpy arrays, read by field name inside the kernels."""
        info = np.array([self.kind, 1 if self.closed else 0], dtype=np.int64)
        info.setflags(write=False)
        return MoldArgs(info, self.params, self.vertices, self.faces, self.face_normals,
                        self.vertex_normals, self.edges, self.edge_normals, self.face_edges,
                        self.edge_faces, self.vertex_face_ptr, self.vertex_face_idx,
                        self.vertex_boundary, self.bvh_min, self.bvh_max, self.bvh_child,
                        self.bvh_range, self.bvh_faces, self.vertex_jets,
                        self.bvh_reach, self.face_vertex_ptr, self.face_vertex_idx)

    def surface_mesh(self, resolution: int = 48, extent: float = 1.0):
        """A triangle mesh for display: ``(vertices float64 (V,3) [m], faces int64 (F,3))``.

        A mesh mold returns (copies of) itself; a primitive is tessellated with about
        ``resolution`` segments around; a plane becomes a square of side ``extent`` [m] centred on
        its point.
        """
        import trimesh

        p = self.params
        res = max(int(resolution), 8)
        if self.kind in MESH_KINDS:
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
        if self.kind == MOLD_LEG:

            return leg_mesh(p, res)
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
        if self.kind == MOLD_SMOOTH:
            return (f"Mold(smooth mesh, {len(self.faces)} triangles, closed={self.closed}, "
                    f"smoothing={self.params[14]:.4g} m, source={self.source!r})")
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
