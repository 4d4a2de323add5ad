"""Closest-point and inside/outside queries of a mold: ``@njit(cache=True)`` pure functions of
the mold's kernel arguments ``margs`` (see :meth:`clothsim.mold.Mold.kernel_args`), dispatched
on the mold's kind to the pieces' queries (:mod:`.closest`) or the smooth surface
(:mod:`.smooth`).

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

from .closest import _box_query, _cylinder_query, _mesh_query, _plane_query, _sphere_query
from .leg import leg_query
from .record import MOLD_CYLINDER, MOLD_LEG, MOLD_MESH, MOLD_PLANE, MOLD_SMOOTH, MOLD_SPHERE
from .smooth import _smooth_query


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

