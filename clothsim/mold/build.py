"""Building a mold (plain numpy): mesh cleaning and orientation, edges and angle-weighted
pseudo-normals, the BVH, and the analytic primitives with their parameter checks."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Mapping

import numpy as np

from .record import (MOLD_BOX, MOLD_CYLINDER, MOLD_LEG, MOLD_MESH, MOLD_PLANE, MOLD_SMOOTH, MOLD_SPHERE, Mold,
                     MoldError, _ro)
from ..legspec import LegParams
from .leg import leg_params
from .smooth import FACE_LIST_MAX_ENTRIES, face_vertex_lists, smooth_phi


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


def _build_bvh(V: np.ndarray, F: np.ndarray, leaf_size: int = 4, progress=None):
    """Median-split AABB tree over triangle centroids (flat arrays, node 0 the root).
    ``progress(fraction)`` (optional) is told the fraction of nodes built every few thousand
    nodes; it may raise to abandon the build."""
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
    built, expected = 0, max(2 * nF // leaf_size, 1)
    while stack:
        node, s, e = stack.pop()
        built += 1
        if progress is not None and built % 4096 == 0:
            progress(min(built / expected, 1.0))
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


#: share of a mesh mold's build time per stage (measured on a 327k-triangle sphere): cleaning,
#: orientation, edges and normals, the BVH
_STAGES = {"cleaning the mesh": (0.0, 0.12), "orienting the triangles": (0.12, 0.35),
           "edges and normals": (0.35, 0.5), "building the search tree": (0.5, 1.0)}


def _build_mesh_mold(V, F, closed: bool | None, source: str, progress=None) -> Mold:
    """A mesh Mold from vertices (V,3) [m] and triangles (F,3). ``progress(fraction, stage)``
    (optional) is told how far the build is (0..1, a rough share of the time) between stages and
    every few thousand BVH nodes; it may raise (a cancelled upload) to abandon the build."""

    def tell(stage: str, within: float = 0.0) -> None:
        if progress is not None:
            a, b = _STAGES[stage]
            progress(a + (b - a) * within, stage)

    tell("cleaning the mesh")
    V, F = _clean_mesh(V, F, source)
    tell("orienting the triangles")
    F, closed = _orient(V, F, closed, source)
    tell("edges and normals")
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
    tell("building the search tree")
    if progress is None:
        bmin, bmax, child, rng, order = _build_bvh(V, F)
    else:
        bmin, bmax, child, rng, order = _build_bvh(V, F, progress=lambda f: tell("building the search tree", f))
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


def median_edge_length(mold: Mold) -> float:
    """The median edge length [m] of a mesh mold (the default smoothing radius)."""
    V, E = mold.vertices, mold.edges
    return float(np.median(np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)))


#: the default surface of a mesh mold (``surface`` omitted, :func:`auto_surface`): a mesh whose
#: interior edges bend by between ``BEND_RANGE_DEG`` in more than this share samples a smooth
#: body at a scan's density (the bundled SMPL bodies 34 %, one Loop subdivision of them 16 %);
#: CAD exports are flat regions, fine tessellations of curved faces (bends below 10 degrees) and
#: creases (the bundled thermoform mold 0.5 %, torso and leg cone 0 %)
SCAN_BEND_SHARE = 0.10
#: the bends [deg] that sample a smooth body at a scan's density: more than a fine CAD
#: tessellation's, less than a crease
BEND_RANGE_DEG = (10.0, 45.0)


def bend_share(mold: Mold) -> float:
    """The share of a mesh mold's interior edges (two faces) whose faces' normals differ by an
    angle within ``BEND_RANGE_DEG``; 0 without interior edges."""
    ef = mold.edge_faces
    ef = ef[(ef[:, 0] >= 0) & (ef[:, 1] >= 0)]
    if len(ef) == 0:
        return 0.0
    N = mold.face_normals
    c = np.clip(np.einsum("ij,ij->i", N[ef[:, 0]], N[ef[:, 1]]), -1.0, 1.0)
    a = np.degrees(np.arccos(c))
    lo, hi = BEND_RANGE_DEG
    return float(np.mean((a > lo) & (a < hi)))


def auto_surface(mold: Mold, share: float | None = None) -> tuple[Mold, str]:
    """The default contact surface of a mesh mold (``surface`` omitted): its smooth surface for a
    mesh that samples a smooth body at a scan's density (more than ``SCAN_BEND_SHARE`` of its
    interior edges bend by 10 to 45 degrees) and that the smooth surface follows (it departs
    from at most ``SMOOTH_WARN_FRACTION`` of the face centres, see :func:`smooth_departure`: a
    coarse cylinder of long slivers does not qualify); the faceted polyhedron otherwise (a CAD
    mold). A scan refined until its edges bend by less than 10 degrees reads as CAD: state
    ``surface: smooth``. ``share``: ``bend_share(mold)`` if already known. Returns (the mold on
    that surface, the reason in words)."""
    if share is None:
        share = bend_share(mold)
    lo, hi = BEND_RANGE_DEG
    why = f"{100 * share:.1f} % of its edges bend by {lo:.0f}-{hi:.0f} degrees"
    if share > SCAN_BEND_SHARE:
        smooth = with_surface(mold, "smooth", warn=False)
        frac, _ = smooth_departure(smooth)
        if frac <= SMOOTH_WARN_FRACTION:
            note = f"smooth: {why}, a sampled smooth body (a scan); surface: faceted keeps the triangles"
            return dataclasses.replace(smooth, surface_note=note), note
        why += f" but the smooth surface departs from {100 * frac:.0f} % of its faces (coarse slivers)"
    note = f"faceted: {why} (a CAD mold); surface: smooth blends them"
    return dataclasses.replace(with_surface(mold, "faceted"), surface_note=note), note


#: default smoothing radius of a smooth mesh, in median edge lengths
SMOOTHING_EDGES = 1.5
#: every vertex's blending radius is at least this many times its longest edge (so every point of
#: every face lies well inside some vertex's support, also on big flat CAD triangles)
_COVER_EDGES = 1.25
#: ... but at most this many smoothing radii, and this many median smoothing radii (a wide vertex
#: is visited by every query within its reach; the inside of a triangle larger than that is
#: answered by the faceted query: its plane)
_MAX_REACH = 3.0


def _vertex_jets(V: np.ndarray, E: np.ndarray, vn: np.ndarray, r: float | None) -> np.ndarray:
    """Per-vertex osculating jets (float64 (V, 20), the layout of :attr:`Mold.vertex_jets`): a
    cubic height function over the vertex's tangent plane (normal: its pseudo-normal), through
    the vertex, fitted by weighted least squares to its 2-ring of neighbours (weights
    1 / (1 + (rho / h)^2), h the mean 1-ring edge length; a small ridge keeps the fit well posed;
    r [m]: the smoothing radius, None for the adaptive 1.5 h per vertex;
    vertices with fewer than 12 neighbours, e.g. on an open rim, get a quadratic jet). A cubic
    jet's curvature is exact to second order in the edge length (a quadratic one's to first
    only, which measured on the thermoform mold leaves a +-25 % curvature ripple at the mesh's
    wavelength). After F. Cazals & M. Pouget (2003), "Estimating differential quantities using
    polynomial fitting of osculating jets", SGP."""
    import scipy.sparse as sp

    nV = len(V)
    ii = np.r_[E[:, 0], E[:, 1]]
    jj = np.r_[E[:, 1], E[:, 0]]
    elen = np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)
    A = sp.csr_matrix((np.ones(len(ii)), (ii, jj)), shape=(nV, nV))
    deg = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1.0)
    h = np.bincount(ii, weights=np.r_[elen, elen], minlength=nV) / deg
    h[h <= 0] = 1.0
    longest = np.zeros(nV)
    np.maximum.at(longest, ii, np.r_[elen, elen])
    A2 = (A + A @ A).tocoo()
    keep = A2.row != A2.col
    i, j = A2.row[keep], A2.col[keep]
    n = vn
    helper = np.where(np.abs(n[:, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(n, t1)
    d = V[j] - V[i]
    x1 = np.einsum("ij,ij->i", d, t1[i]) / h[i]
    x2 = np.einsum("ij,ij->i", d, t2[i]) / h[i]
    z = np.einsum("ij,ij->i", d, n[i]) / h[i]
    w = 1.0 / (1.0 + x1 * x1 + x2 * x2)
    B = np.stack([x1, x2, 0.5 * x1 * x1, x1 * x2, 0.5 * x2 * x2, x1 ** 3 / 6, 0.5 * x1 * x1 * x2,
                  0.5 * x1 * x2 * x2, x2 ** 3 / 6], axis=1)
    count = np.bincount(i, minlength=nV)
    wsum = np.bincount(i, weights=w, minlength=nV)
    coef = np.zeros((nV, 9))
    for m, sel in ((5, count < 12), (9, count >= 12)):
        if not sel.any():
            continue
        Bm = B[:, :m]
        M = np.zeros((nV, m, m))
        np.add.at(M, i, w[:, None, None] * Bm[:, :, None] * Bm[:, None, :])
        rhs = np.zeros((nV, m))
        np.add.at(rhs, i, (w * z)[:, None] * Bm)
        M += (1e-6 * np.maximum(wsum, 1.0))[:, None, None] * np.eye(m)[None]
        coef[sel, :m] = np.linalg.solve(M[sel], rhs[sel][:, :, None])[:, :, 0]
    coef[:, 2:5] /= h[:, None]
    coef[:, 5:9] /= (h * h)[:, None]
    jets = np.zeros((nV, 20))
    jets[:, 0:3] = t1
    jets[:, 3:6] = t2
    jets[:, 6:15] = coef
    base = SMOOTHING_EDGES * h if r is None else np.full(nV, r)
    ref = float(np.median(base))
    base = np.minimum(base, _MAX_REACH * ref)
    jets[:, 15] = np.clip(_COVER_EDGES * longest, base, _MAX_REACH * np.minimum(base, ref))
    # a vertex's weight factor (r_ref / r_v)^4, r_ref the median base radius: where fine and
    # coarse vertices overlap (a scan's face next to its cheek, a fine dome next to a coarse
    # plate fitted across a crease) the fine ones decide the surface
    jets[:, 16] = (ref / jets[:, 15]) ** 4
    jets[:, 17] = base
    return jets


def _bvh_reach(mold: Mold, rv: np.ndarray) -> np.ndarray:
    """Per BVH node: the largest radius rv [m] of the vertices its faces own (see
    :attr:`Mold.bvh_reach`)."""
    owner = mold.vertex_face_idx[mold.vertex_face_ptr[:-1]]
    face_r = np.zeros(len(mold.faces))
    np.maximum.at(face_r, owner, rv)
    fr = face_r[mold.bvh_faces]
    rng = mold.bvh_range
    reach = np.empty(len(rng))
    for n in range(len(rng)):
        s, c = rng[n]
        reach[n] = fr[s:s + c].max() if c else 0.0
    return reach


def with_surface(mold: Mold, surface: str = "faceted", smoothing: float | None = None, warn: bool = True) -> Mold:
    """The same mesh mold with contact on its ``'faceted'`` polyhedron (``MOLD_MESH``) or on its
    ``'smooth'`` blended surface (``MOLD_SMOOTH``, see :mod:`clothsim.mold.smooth`) of smoothing
    radius ``smoothing`` [m] (default: adaptive, ``SMOOTHING_EDGES`` = 1.5 times each vertex's
    mean edge length, so dense parts of a scan, such as hands and face, are not blended over
    the body's coarse scale). The mesh
    arrays are shared; the smooth surface adds the vertices' fitted jets. ``warn``: warn when the
    smooth surface departs from the mesh (:func:`smooth_departure`)."""
    if mold.kind not in (MOLD_MESH, MOLD_SMOOTH):
        raise MoldError(f"{mold.source}: 'surface' applies to mesh molds only")
    if surface == "faceted":
        if smoothing is not None:
            raise MoldError(f"{mold.source}: 'smoothing' applies to surface: smooth only")
        if mold.kind == MOLD_MESH:
            return mold
        prm = np.array(mold.params)
        prm[13:15] = 0.0
        return dataclasses.replace(mold, kind=MOLD_MESH, params=_ro(prm, np.float64),
                                   vertex_jets=None, bvh_reach=None, face_vertex_ptr=None,
                                   face_vertex_idx=None)
    if surface != "smooth":
        raise MoldError(f"{mold.source}: surface must be 'smooth' or 'faceted', got {surface!r}")
    r = None if smoothing is None else float(smoothing)
    if r is not None and not (np.isfinite(r) and r > 0):
        raise MoldError(f"{mold.source}: 'smoothing' must be a positive length [m], got {smoothing!r}")
    if mold.kind == MOLD_SMOOTH and mold.params[12] == (0.0 if r is None else r):
        return mold
    jets = _vertex_jets(mold.vertices, mold.edges, mold.vertex_normals, r)
    prm = np.array(mold.params)
    prm[12] = 0.0 if r is None else r
    prm[14] = float(np.median(jets[:, 17]))
    prm[13] = float(jets[:, 15].max())
    out = dataclasses.replace(mold, kind=MOLD_SMOOTH, params=_ro(prm, np.float64),
                              vertex_jets=_ro(jets, np.float64),
                              bvh_reach=_ro(_bvh_reach(mold, jets[:, 15]), np.float64),
                              face_vertex_ptr=None, face_vertex_idx=None)
    # each face's gathering list for the queries started on it (``smooth.face_vertex_lists``)

    fptr, fidx = face_vertex_lists(out.kernel_args(), FACE_LIST_MAX_ENTRIES)
    out = dataclasses.replace(out, face_vertex_ptr=_ro(fptr, np.int64), face_vertex_idx=_ro(fidx, np.int64))
    if not warn:
        return out
    frac, dev = smooth_departure(out)
    if frac > SMOOTH_WARN_FRACTION:
        warnings.warn(f"{mold.source}: the smooth surface departs from {100 * frac:.0f} % of the "
                      f"mesh's face centres by more than a tenth of the face's longest edge (up to "
                      f"{dev * 1000:.3g} mm): the triangles are long slivers or too coarse for the "
                      f"shape (a CAD export?); use surface: faceted, or a finer, more even mesh",
                      stacklevel=3)
    return out


#: with_surface warns when more than this fraction of the faces' centres lie farther than a
#: tenth of the face's longest edge from the smooth surface (scans: 2 to 6 %, at their fine
#: thin features; a cone of long slivers: 75 %)
SMOOTH_WARN_FRACTION = 0.2


def smooth_departure(mold: Mold):
    """How far a smooth mold's surface departs from its mesh: the fraction of faces whose centre
    lies farther than a tenth of the face's longest edge from it (first order: |phi| / |grad
    phi|), and the largest such distance [m]. Faces beyond every vertex's reach (answered by the
    facets) count as on it."""
    T = mold.vertices[mold.faces]
    C = np.ascontiguousarray(T.mean(axis=1))
    L = np.linalg.norm(T - np.roll(T, 1, axis=1), axis=2).max(axis=1)
    phi, g, W = np.empty(len(C)), np.empty((len(C), 3)), np.empty(len(C))
    smooth_phi(mold.kernel_args(), C, phi, g, W)
    gl = np.linalg.norm(g, axis=1)
    d = np.where((W > 0) & (gl > 0), np.abs(phi) / np.where(gl > 0, gl, 1.0), 0.0)
    return float(np.mean(d > 0.1 * L)), float(d.max())


def mold_from_arrays(vertices, faces, closed: bool | None = None, source: str = "",
                     surface: str = "faceted", smoothing: float | None = None) -> Mold:
    """Mesh mold from arrays: vertices (V,3) [m], faces (F,3) vertex ids.

    ``closed=None`` detects watertightness; ``closed=True`` on a mesh with boundary edges is an
    error; ``closed=False`` treats even a watertight mesh as an open skin (winding kept).
    Exact duplicate vertices are merged; degenerate and duplicate triangles are dropped with a
    warning; inconsistent winding is repaired or reported. ``surface``: ``'faceted'`` (contact on
    the polyhedron) or ``'smooth'`` (on its smooth blended surface of radius ``smoothing`` [m],
    default the median edge length; see :func:`with_surface`).
    """
    mold = _build_mesh_mold(vertices, faces, closed, source or "<arrays>")
    return with_surface(mold, surface, smoothing)


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


def leg_mold(spec: Mapping) -> Mold:
    """A limb from a size chart (``MOLD_LEG``, :mod:`clothsim.mold.leg`) from the fields of
    :class:`clothsim.legspec.LegParams` (a dict; validated there)."""

    try:
        p = LegParams.model_validate(dict(spec))
    except Exception as e:  # pydantic's message, one line per field
        raise MoldError(f"leg mold: {e}") from None
    names = list(p.levels)
    lv = [p.levels[k] for k in names]
    try:
        prm = leg_params(p.center, [x.height_cm / 100 for x in lv], [x.girth_cm / 100 for x in lv],
                         [dict(aspect=x.aspect, medial_flat=x.medial_flat, crest=x.crest) for x in lv],
                         p.anterior, p.medial, p.harmonics, p.extend, p.floor)
    except ValueError as e:
        raise MoldError(f"leg mold: {e}") from None
    desc = ", ".join(f"{k} {x.girth_cm:g} cm at {x.height_cm:g} cm" for k, x in zip(names, lv))
    m = _primitive(MOLD_LEG, [], f"leg({desc})")
    return dataclasses.replace(m, params=_ro(prm, np.float64))


def mold_primitive(kind: str, spec: Mapping) -> Mold:
    """Analytic mold: kind 'sphere' {center, radius}, 'cylinder' {center, axis, radius, length},
    'plane' {point, normal} (the mold is the half-space behind the normal), 'box' {min, max}."""
    src = f"{kind} mold"
    if not isinstance(spec, Mapping):
        raise MoldError(f"{src}: expected a mapping of parameters, got {spec!r}")
    if kind == "leg":
        return leg_mold(spec)
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
