"""Rigid molds the fabric nodes may not enter.

A :class:`Mold` is either a triangle mesh (any format trimesh reads, the paper's own
points/triangles text format, legacy ASCII VTK polydata, VRML 2.0 ``IndexedFaceSet``) or an
analytic primitive (sphere, finite capped cylinder, half-space, axis-aligned box). Loading and
validation are plain Python/numpy; the queries used inside solver loops are ``@njit(cache=True)``
pure functions of the named tuple of arrays (:class:`MoldArgs`) returned by
:meth:`Mold.kernel_args` (called ``margs``).

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

**Smooth mesh** (``MOLD_SMOOTH``, ``surface: smooth`` in a mesh spec): the same mesh, but contact
is on a smooth (G1) surface blended from its face planes (:mod:`clothsim.mold.smooth`); every
query answers code 0 (a face) with a point-dependent normal, as on the analytic sphere. Drawing,
exports and sizes use the mesh itself.

Modules, by job: ``record`` (the :class:`Mold` and its codes), ``closest`` (closest point on a
triangle, the BVH traversal, each primitive; numba), ``queries`` (the query of a mold, inside
test and contact normals, dispatched on its kind; numba), ``segment`` (segment hits; numba), ``build`` (mesh cleaning, BVH,
pseudo-normals, primitives), ``readers`` (file formats, safe file reading), ``load`` (specs,
transforms, loaders, the cache of loaded molds), ``checks`` (sanity warnings against the scene),
``smooth`` (the smooth surface of a mesh; numba).
Mold specs are typed in :mod:`clothsim.config` (``MoldSpec``).
"""

from .build import median_edge_length, mold_from_arrays, mold_primitive, with_surface
from .checks import SCALE_WARNING_RATIO, mold_reach_warning, mold_scale_warning, mold_size
from .load import (MOLD_CACHE_SIZE, cache_mold, check_mold, clear_mold_cache, load_mold, load_mold_bytes,
                   mold_cache_info, mold_cached)
from .readers import MAX_MOLD_FILE_BYTES
from .queries import contact_normals_from_query, mold_contact_normals, mold_feature_normals, mold_query, mold_query_many
from .record import (FEATURE_EDGE, FEATURE_FACE, FEATURE_VERTEX, MESH_KINDS, MOLD_BOX, MOLD_CYLINDER,
                     MOLD_MESH, MOLD_PLANE, MOLD_SMOOTH, MOLD_SPHERE, QUERY_OUT_SIZE, Mold, MoldArgs,
                     MoldError)
from .segment import mold_segment_hit
from .smooth import smooth_phi, smooth_shape_operator

__all__ = [
    "MoldError",
    "Mold",
    "MoldArgs",
    "MOLD_MESH",
    "MOLD_SMOOTH",
    "MESH_KINDS",
    "MOLD_SPHERE",
    "MOLD_CYLINDER",
    "MOLD_PLANE",
    "MOLD_BOX",
    "FEATURE_FACE",
    "FEATURE_EDGE",
    "FEATURE_VERTEX",
    "QUERY_OUT_SIZE",
    "load_mold",
    "check_mold",
    "cache_mold",
    "mold_cached",
    "load_mold_bytes",
    "clear_mold_cache",
    "mold_cache_info",
    "MOLD_CACHE_SIZE",
    "MAX_MOLD_FILE_BYTES",
    "mold_reach_warning",
    "mold_scale_warning",
    "mold_size",
    "SCALE_WARNING_RATIO",
    "mold_from_arrays",
    "mold_primitive",
    "mold_query",
    "mold_feature_normals",
    "mold_contact_normals",
    "contact_normals_from_query",
    "mold_segment_hit",
    "mold_query_many",
    "with_surface",
    "median_edge_length",
    "smooth_phi",
    "smooth_shape_operator",
]
