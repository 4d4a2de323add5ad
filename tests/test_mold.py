"""Tests of clothsim.mold: closest point, signed distance, segment hits, loaders, bundled molds.

References used: brute force over all triangles in numpy (closest point) written independently of
the kernels (plane projection + segment distances), the generalized winding number (solid angles,
van Oosterom & Strackee 1983) for inside/outside of closed meshes, analytic formulas for the
primitives, and hand-computed values for the segment hits and the loaders.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from clothsim.mold import (
    MOLD_BOX,
    MOLD_CYLINDER,
    MOLD_MESH,
    MOLD_PLANE,
    MOLD_SPHERE,
    Mold,
    MoldError,
    load_mold,
    load_mold_bytes,
    mold_contact_normals,
    mold_feature_normals,
    mold_from_arrays,
    mold_query,
    mold_query_many,
    mold_segment_hit,
)

ROOT = Path(__file__).resolve().parents[1]
MOLDS = ROOT / "static" / "molds"


# ---------------------------------------------------------------------------------------------
# independent references
# ---------------------------------------------------------------------------------------------


def _seg_dist(P, A, B):
    """Closest points on segments AB (arrays over triangles) to the point P."""
    d = B - A
    l2 = np.einsum("ij,ij->i", d, d)
    t = np.where(l2 > 0, np.einsum("ij,ij->i", P - A, d) / np.where(l2 > 0, l2, 1), 0.0)
    t = np.clip(t, 0, 1)
    return A + t[:, None] * d


def brute_closest(P, V, F):
    """Distance and closest point from each row of P to the triangle mesh, by brute force."""
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(B - A, C - A)
    n /= np.linalg.norm(n, axis=1)[:, None]
    dist = np.empty(len(P))
    cp = np.empty_like(P)
    for i, p in enumerate(P):
        h = np.einsum("ij,ij->i", p - A, n)
        q = p - h[:, None] * n
        ins = ((np.einsum("ij,ij->i", np.cross(B - A, q - A), n) >= 0)
               & (np.einsum("ij,ij->i", np.cross(C - B, q - B), n) >= 0)
               & (np.einsum("ij,ij->i", np.cross(A - C, q - C), n) >= 0))
        cands = [np.where(ins[:, None], q, np.inf)]
        cands += [_seg_dist(p, A, B), _seg_dist(p, B, C), _seg_dist(p, C, A)]
        best, bq = np.inf, None
        for c in cands:
            d = np.linalg.norm(c - p, axis=1)
            d[~np.isfinite(d)] = np.inf
            k = int(np.argmin(d))
            if d[k] < best:
                best, bq = d[k], c[k]
        dist[i], cp[i] = best, bq
    return dist, cp


def winding_number(P, V, F):
    """Generalized winding number of each point (1 inside a closed outward mesh, 0 outside)."""
    out = np.empty(len(P))
    for i, p in enumerate(P):
        a, b, c = V[F[:, 0]] - p, V[F[:, 1]] - p, V[F[:, 2]] - p
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        num = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la
               + np.einsum("ij,ij->i", c, a) * lb)
        out[i] = np.sum(2 * np.arctan2(num, den)) / (4 * np.pi)
    return out


def query_all(mold: Mold, P):
    P = np.ascontiguousarray(P, dtype=np.float64)
    n = len(P)
    sd, cp, nr = np.empty(n), np.empty((n, 3)), np.empty((n, 3))
    ft = np.empty((n, 2), dtype=np.int64)
    mold_query_many(mold.kernel_args(), P, sd, cp, nr, ft)
    return sd, cp, nr, ft


def check_closed_mesh(mold: Mold, P, tol=1e-12):
    """Distance and closest point vs brute force, sign vs winding number."""
    V, F = np.asarray(mold.vertices), np.asarray(mold.faces)
    sd, cp, nr, ft = query_all(mold, P)
    assert np.isfinite(sd).all() and np.isfinite(cp).all() and np.isfinite(nr).all()
    d_ref, _ = brute_closest(P, V, F)
    scale = np.linalg.norm(V.max(0) - V.min(0))
    np.testing.assert_allclose(np.abs(sd), d_ref, atol=tol * scale, rtol=0)
    np.testing.assert_allclose(np.linalg.norm(cp - P, axis=1), d_ref, atol=tol * scale, rtol=0)
    on_surface, _ = brute_closest(cp, V, F)
    assert on_surface.max() < tol * scale
    np.testing.assert_allclose(np.linalg.norm(nr, axis=1), 1.0, atol=1e-12)
    w = winding_number(P, V, F)
    clear = np.abs(sd) > 1e-9 * scale
    inside_ref = w > 0.5
    assert np.array_equal(sd[clear] < 0, inside_ref[clear]), "sign disagrees with winding number"
    return sd, ft


def surface_points(V, F):
    """Points exactly on vertices, edge midpoints and face centroids."""
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1),
                  axis=0)
    return V.copy(), 0.5 * (V[E[:, 0]] + V[E[:, 1]]), V[F].mean(axis=1)


def l_extrusion():
    """L-shaped prism: polygon (0,0),(2,0),(2,1),(1,1),(1,2),(0,2) in x-z, extruded y in [0,1].
    Concave edge along y at x = z = 1. Caps triangulated by hand; winding left to the loader."""
    poly = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    V = np.array([[x, y, z] for y in (0.0, 1.0) for x, z in poly])
    cap = [[0, 1, 2], [0, 2, 3], [0, 3, 5], [3, 4, 5]]
    F = [c for c in cap] + [[a + 6, b + 6, c + 6] for a, b, c in cap]
    for i in range(6):
        j = (i + 1) % 6
        F += [[i, j, j + 6], [i, j + 6, i + 6]]
    return V, np.array(F)


def in_l(P):
    x, y, z = P[:, 0], P[:, 1], P[:, 2]
    iny = (y > 0) & (y < 1)
    return iny & (((x > 0) & (x < 2) & (z > 0) & (z < 1)) | ((x > 0) & (x < 1) & (z > 0) & (z < 2)))


# ---------------------------------------------------------------------------------------------
# closest point and sign on meshes
# ---------------------------------------------------------------------------------------------


def test_icosphere_closest_and_sign_vs_brute_force():
    """Icosphere (subdiv 3): |sd|, closest point vs brute force; sign vs winding number; points
    exactly on vertices/edges/faces give distance 0 with finite normals; vertex points report the
    vertex feature."""
    m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    mold = mold_from_arrays(m.vertices, m.faces)
    assert mold.closed and mold.kind == MOLD_MESH
    rng = np.random.default_rng(1)
    P = rng.normal(size=(300, 3))
    P *= (rng.uniform(0.0, 1.6, 300) / np.linalg.norm(P, axis=1))[:, None]
    check_closed_mesh(mold, P)
    V, F = np.asarray(mold.vertices), np.asarray(mold.faces)
    verts, mids, cents = surface_points(V, F)
    for pts, code in ((verts, 2), (mids, 1), (cents, 0)):
        sd, cp, nr, ft = query_all(mold, pts)
        assert np.isfinite(nr).all()
        assert np.abs(sd).max() < 1e-15
        np.testing.assert_allclose(cp, pts, atol=1e-15)
        assert (ft[:, 0] == code).mean() > 0.99
    sd, _, _, ft = query_all(mold, verts)
    np.testing.assert_array_equal(ft[:, 1], np.arange(len(V)))


def test_box_mesh_edges_and_corners():
    """Box mesh (12 triangles): random points and points near its edges and corners, inside and
    outside, vs brute force and winding number; pseudo-normal at a corner is (1,1,1)/sqrt3."""
    m = trimesh.creation.box(extents=[1.0, 2.0, 0.5])
    mold = mold_from_arrays(m.vertices, m.faces)
    rng = np.random.default_rng(2)
    P = rng.uniform(-1.0, 1.0, size=(200, 3)) * [1.0, 1.5, 0.6]
    corners = np.asarray(m.vertices)
    near = corners[rng.integers(0, 8, 200)] + rng.normal(scale=0.02, size=(200, 3))
    check_closed_mesh(mold, np.vstack([P, near]))
    out = np.empty(8)
    d = mold_query(mold.kernel_args(), np.array([0.6, 1.1, 0.35]), out)
    assert d == pytest.approx(np.sqrt(3 * 0.1 ** 2), abs=1e-14)
    assert out[6] == 2
    np.testing.assert_allclose(out[3:6], np.ones(3) / np.sqrt(3), atol=1e-14)


def test_concave_edge_of_l_extrusion():
    """L-shaped prism: points around the concave edge (x = z = 1) and elsewhere are classified
    exactly as the L polygon test says; distances vs brute force."""
    V, F = l_extrusion()
    mold = mold_from_arrays(V, F)
    assert mold.closed
    rng = np.random.default_rng(3)
    edge = np.column_stack([np.ones(300), rng.uniform(0.05, 0.95, 300), np.ones(300)])
    P = np.vstack([edge + rng.normal(scale=0.05, size=(300, 3)),
                   rng.uniform(-0.3, 2.3, size=(200, 3)) * [1, 0.6, 1]])
    sd, ft = check_closed_mesh(mold, P)
    clear = np.abs(sd) > 1e-9
    assert np.array_equal(sd[clear] < 0, in_l(P)[clear])
    # deep in the groove: just outside the concave edge along the bisector -> outside, and the
    # reaction cone there holds both face normals
    out = np.empty(8)
    margs = mold.kernel_args()
    d = mold_query(margs, np.array([1.0 + 1e-3, 0.5, 1.0 + 1e-3]), out)
    assert d > 0
    d = mold_query(margs, np.array([1.0 - 1e-3, 0.5, 1.0 - 1e-3]), out)
    assert d == pytest.approx(-np.sqrt(2) * 1e-3, rel=1e-9)
    assert out[6] == 1
    nb = np.zeros((8, 3))
    k = mold_feature_normals(margs, out[6], out[7], nb)
    assert k == 2
    got = {tuple(np.round(r, 12)) for r in nb[:2]}
    assert got == {(1.0, 0.0, 0.0), (0.0, 0.0, 1.0)}


def heightfield(nx=12, ny=10):
    x = np.linspace(0, 1, nx)
    y = np.linspace(0, 1, ny)
    X, Y = np.meshgrid(x, y, indexing="ij")
    Z = 0.08 * np.sin(3 * X) * np.cos(4 * Y) + 0.05 * X * Y
    V = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return V, F


def height_at(V, F, xy):
    """Piecewise-linear height of the patch at (x, y) (reference for the open-surface sign)."""
    out = np.full(len(xy), np.nan)
    A, B, C = V[F[:, 0], :2], V[F[:, 1], :2], V[F[:, 2], :2]
    for i, q in enumerate(xy):
        den = (B[:, 1] - C[:, 1]) * (A[:, 0] - C[:, 0]) + (C[:, 0] - B[:, 0]) * (A[:, 1] - C[:, 1])
        l1 = ((B[:, 1] - C[:, 1]) * (q[0] - C[:, 0]) + (C[:, 0] - B[:, 0]) * (q[1] - C[:, 1])) / den
        l2 = ((C[:, 1] - A[:, 1]) * (q[0] - C[:, 0]) + (A[:, 0] - C[:, 0]) * (q[1] - C[:, 1])) / den
        l3 = 1 - l1 - l2
        k = np.flatnonzero((l1 >= -1e-12) & (l2 >= -1e-12) & (l3 >= -1e-12))[0]
        out[i] = l1[k] * V[F[k, 0], 2] + l2[k] * V[F[k, 1], 2] + l3[k] * V[F[k, 2], 2]
    return out


def test_open_heightfield_patch_sign_rule():
    """Open bumpy height-field skin (normals up): distances vs brute force; a point within the
    footprint close to the skin is inside iff below the piecewise-linear height; points beyond the
    rim (closest feature on the boundary, not directly behind a face) are outside; a point exactly
    below a boundary edge is inside."""
    V, F = heightfield()
    mold = mold_from_arrays(V, F)
    assert not mold.closed
    assert (np.asarray(mold.face_normals)[:, 2] > 0).all()
    rng = np.random.default_rng(4)
    xy = rng.uniform(0.15, 0.85, size=(250, 2))
    h = height_at(V, F, xy)
    P = np.column_stack([xy, h + rng.uniform(-0.04, 0.04, 250)])
    sd, cp, nr, ft = query_all(mold, P)
    d_ref, _ = brute_closest(P, V, F)
    np.testing.assert_allclose(np.abs(sd), d_ref, atol=1e-13)
    clear = np.abs(sd) > 1e-9
    assert np.array_equal(sd[clear] < 0, (P[:, 2] < h)[clear])
    # beyond the rim, above and below the skin's level: outside
    # (within +-0.03 of the rim's height at 0.05..0.3 beyond it: no face's normal prism reaches
    # there, as the slopes are below 0.6)
    yq = rng.uniform(0, 1, 50)
    rim = height_at(V, F, np.column_stack([np.full(50, 1.0 - 1e-12), yq]))
    Q = np.column_stack([rng.uniform(1.05, 1.3, 50), yq, rim + rng.uniform(-0.03, 0.03, 50)])
    sdq, _, _, ftq = query_all(mold, Q)
    assert (sdq > 0).all()
    assert (ftq[:, 0] >= 1).all()
    # directly behind the middle of a boundary edge (x = 1), along its face's normal: inside
    nx, ny = 12, 10
    i, j = nx - 2, 4
    f = i * (ny - 1) + j  # triangle (idx[i,j], idx[i+1,j], idx[i+1,j+1]); edge 1-2 on x = 1
    b, c = F[f, 1], F[f, 2]
    mid = 0.5 * (V[b] + V[c])
    n_face = np.cross(V[F[f, 1]] - V[F[f, 0]], V[F[f, 2]] - V[F[f, 0]])
    n_face /= np.linalg.norm(n_face)
    out = np.empty(8)
    margs = mold.kernel_args()
    d = mold_query(margs, mid - 1e-3 * n_face, out)
    assert d == pytest.approx(-1e-3, rel=1e-9)
    # ... and slightly beyond the rim at the same depth: outside
    d = mold_query(margs, mid - 1e-3 * n_face + [1e-4, 0, 0], out)
    assert d > 0 and out[6] == 1


def test_primitives_vs_formulas():
    """Sphere, capped cylinder, plane and box: signed distance and closest point vs the analytic
    formulas; closest point lies on the surface and no dense surface sample is closer."""
    rng = np.random.default_rng(5)
    P = rng.uniform(-2, 2, size=(400, 3))
    # sphere
    s = load_mold({"sphere": {"center": [0.1, -0.2, 0.3], "radius": 0.7}})
    sd, cp, nr, _ = query_all(s, P)
    c = np.array([0.1, -0.2, 0.3])
    r = np.linalg.norm(P - c, axis=1)
    np.testing.assert_allclose(sd, r - 0.7, atol=1e-14)
    np.testing.assert_allclose(cp, c + 0.7 * (P - c) / r[:, None], atol=1e-14)
    # plane
    pl = load_mold({"plane": {"point": [0, 0, 0.2], "normal": [0, 0, 2]}})
    sd, cp, nr, _ = query_all(pl, P)
    np.testing.assert_allclose(sd, P[:, 2] - 0.2, atol=1e-14)
    np.testing.assert_allclose(nr, np.tile([0, 0, 1.0], (len(P), 1)))
    # box: vs brute force on a box mesh and the inside test
    bx = load_mold({"box": {"min": [-0.5, -1, -0.25], "max": [0.5, 1, 0.25]}})
    sd, cp, nr, ft = query_all(bx, P)
    bm = trimesh.creation.box(extents=[1, 2, 0.5])
    d_ref, _ = brute_closest(P, np.asarray(bm.vertices), np.asarray(bm.faces))
    inside = (np.abs(P) < [0.5, 1, 0.25]).all(axis=1)
    np.testing.assert_allclose(sd, np.where(inside, -d_ref, d_ref), atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(cp - P, axis=1), d_ref, atol=1e-14)
    out = np.empty(8)
    d = mold_query(bx.kernel_args(), np.array([0.7, 1.3, 0.0]), out)
    assert d == pytest.approx(np.hypot(0.2, 0.3)) and out[6] == 1
    nb = np.zeros((4, 3))
    assert mold_feature_normals(bx.kernel_args(), out[6], out[7], nb) == 2
    np.testing.assert_allclose(nb[:2].sum(0), [1, 1, 0])
    d = mold_query(bx.kernel_args(), np.array([-0.6, -1.1, -0.3]), out)
    assert out[6] == 2 and mold_feature_normals(bx.kernel_args(), out[6], out[7], nb) == 3
    np.testing.assert_allclose(nb[:3].sum(0), [-1, -1, -1])
    # cylinder with a tilted axis
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    cc = np.array([0.2, 0.1, -0.1])
    cy = load_mold({"cylinder": {"center": cc.tolist(), "axis": (3 * axis).tolist(),
                                 "radius": 0.6, "length": 1.6}})
    assert cy.kind == MOLD_CYLINDER
    sd, cp, nr, ft = query_all(cy, P)
    w = P - cc
    sax = w @ axis
    rho = np.linalg.norm(w - sax[:, None] * axis, axis=1)
    dr, dz = rho - 0.6, np.abs(sax) - 0.8
    ref = np.where((dr <= 0) & (dz <= 0), np.maximum(dr, dz),
                   np.hypot(np.maximum(dr, 0), np.maximum(dz, 0)))
    np.testing.assert_allclose(sd, ref, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(cp - P, axis=1), np.abs(sd), atol=1e-14)
    # closest point on the surface, and no point of a dense surface sample is closer
    wc = cp - cc
    sc = wc @ axis
    rc = np.linalg.norm(wc - sc[:, None] * axis, axis=1)
    on_side = np.isclose(rc, 0.6, atol=1e-12) & (np.abs(sc) <= 0.8 + 1e-12)
    on_cap = np.isclose(np.abs(sc), 0.8, atol=1e-12) & (rc <= 0.6 + 1e-12)
    assert (on_side | on_cap).all()
    # exact samples of the true surface (side grid and cap discs)
    e1 = np.cross(axis, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    th = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    ring = np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2
    side = (0.6 * ring[:, None, :] + np.linspace(-0.8, 0.8, 81)[None, :, None] * axis).reshape(-1, 3)
    caps = np.concatenate([(rr * ring[:, None, :] + sgn * 0.8 * axis).reshape(-1, 3)
                           for sgn in (-1, 1) for rr in [np.linspace(0, 0.6, 31)[None, :, None]]])
    dense = np.vstack([side, caps]) + cc
    for k in range(60):
        assert np.min(np.linalg.norm(dense - P[k], axis=1)) >= abs(sd[k]) - 1e-12


def test_icosphere_within_chord_error_of_sphere():
    """Icosphere (subdiv 4, r = 0.04) signed distance agrees with the analytic sphere within the
    chord error r - (smallest distance from the centre to a facet plane)."""
    r = 0.04
    m = trimesh.creation.icosphere(subdivisions=4, radius=r)
    mold = mold_from_arrays(m.vertices, m.faces)
    V, F = np.asarray(mold.vertices), np.asarray(mold.faces)
    fn = np.asarray(mold.face_normals)
    chord = r - np.min(np.einsum("ij,ij->i", V[F[:, 0]], fn))
    assert 0 < chord < 2e-4
    rng = np.random.default_rng(6)
    P = rng.normal(size=(500, 3))
    P *= (rng.uniform(0.5 * r, 1.5 * r, 500) / np.linalg.norm(P, axis=1))[:, None]
    sd, *_ = query_all(mold, P)
    sd_sphere, *_ = query_all(load_mold({"sphere": {"center": [0, 0, 0], "radius": r}}), P)
    err = np.abs(sd - sd_sphere)
    assert err.max() <= chord + 1e-15
    assert err.max() > 0.2 * chord  # the test can see a facet


def test_contact_normals_cylinder_rim_and_sphere():
    """mold_contact_normals: sphere -> radial normal; cylinder rim -> cap normal and side normal;
    mesh face -> one face normal (vs face_normals)."""
    s = load_mold({"sphere": {"center": [0, 0, 0], "radius": 1}})
    nb = np.zeros((8, 3))
    assert mold_contact_normals(s.kernel_args(), np.array([0.0, 3.0, 4.0]), np.empty(8), nb) == 1
    np.testing.assert_allclose(nb[0], [0, 0.6, 0.8], atol=1e-15)
    cy = load_mold({"cylinder": {"center": [0, 0, 0], "axis": [0, 0, 1], "radius": 1, "length": 2}})
    assert mold_contact_normals(cy.kernel_args(), np.array([2.0, 0.0, 2.0]), np.empty(8), nb) == 2
    np.testing.assert_allclose(nb[:2], [[0, 0, 1], [1, 0, 0]], atol=1e-14)


# ---------------------------------------------------------------------------------------------
# segment hits
# ---------------------------------------------------------------------------------------------


def test_segment_hit_box_mesh():
    """Box mesh [-0.5, 0.5]^3: through a face interior (t = 0.75), exactly through the face's
    diagonal edge (0.75), through a convex edge entering (0.5), grazing that edge (-1), through a
    corner (0.5), grazing a corner (-1), starting on the surface inward (0) / outward (-1), within a
    face plane (-1), starting inside and exiting (-1), missing (-1)."""
    m = trimesh.creation.box(extents=[1, 1, 1])
    mold = mold_from_arrays(m.vertices, m.faces)
    a = mold.kernel_args()

    def hit(p0, p1):
        return mold_segment_hit(a, np.array(p0, float), np.array(p1, float))

    assert hit([0.1, 0.2, 2.0], [0.1, 0.2, 0.0]) == pytest.approx(0.75, abs=1e-14)
    # the top face's two triangles share a diagonal; both diagonals checked
    assert hit([0.2, 0.2, 2.0], [0.2, 0.2, 0.0]) == pytest.approx(0.75, abs=1e-14)
    assert hit([0.2, -0.2, 2.0], [0.2, -0.2, 0.0]) == pytest.approx(0.75, abs=1e-14)
    assert hit([-1.5, 0, 1.5], [0.5, 0, -0.5]) == pytest.approx(0.5, abs=1e-12)
    assert hit([-1.5, 0, -0.5], [0.5, 0, 1.5]) == -1.0
    assert hit([1.5, 1.5, 1.5], [-0.5, -0.5, -0.5]) == pytest.approx(0.5, abs=1e-12)
    assert hit([0.0, 1.0, 0.0], [1.0, 0.0, 1.0]) == -1.0  # touches corner (0.5, 0.5, 0.5)
    assert hit([0.1, 0.2, 0.5], [0.1, 0.2, 0.0]) == 0.0
    assert hit([0.1, 0.2, 0.5], [0.1, 0.2, 1.0]) == -1.0
    assert hit([-0.9, 0.2, 0.5], [0.9, 0.2, 0.5]) == -1.0
    assert hit([0.0, 0.0, 0.0], [0.0, 0.0, 3.0]) == -1.0
    assert hit([2.0, 2.0, 2.0], [3.0, 2.0, 2.0]) == -1.0
    # exits then re-enters: only the entry counts
    assert hit([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]) == -1.0


def test_segment_hit_icosphere_vertex_and_tangent():
    """Icosphere: a radial segment through a vertex enters at |p0 - v| / |p1 - p0|; a segment
    in the tangent plane at a vertex only touches (-1); agrees with the signed distance along the
    segment for random segments (first sign change)."""
    m = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    mold = mold_from_arrays(m.vertices, m.faces)
    a = mold.kernel_args()
    v = np.asarray(mold.vertices)[7]
    t_ = mold_segment_hit(a, 2 * v, -v)
    assert t_ == pytest.approx(1.0 / 3.0, abs=1e-12)
    tang = np.cross(v, [0.3, 0.1, 0.9])
    tang /= np.linalg.norm(tang)
    assert mold_segment_hit(a, v - tang, v + tang) == -1.0
    rng = np.random.default_rng(7)
    out = np.empty(8)
    ts = np.linspace(0, 1, 2001)
    for _ in range(40):
        p0 = rng.normal(size=3)
        p0 *= 1.5 / np.linalg.norm(p0)
        p1 = rng.uniform(-1.2, 1.2, 3)
        sd = np.array([mold_query(a, p0 + t * (p1 - p0), out) for t in ts])
        t_ = mold_segment_hit(a, p0, p1)
        first = np.flatnonzero(sd < 0)
        if len(first) == 0:
            assert t_ == -1.0
        else:
            assert ts[first[0] - 1] - 1e-9 <= t_ <= ts[first[0]] + 1e-9


def test_segment_hit_primitives():
    """Analytic entries: sphere (t = 0.25), sphere tangent (-1), sphere from its surface inward
    (0); cylinder side (0.25) and cap (0.25); box (0.5), box edge graze (-1); plane (0.4),
    plane parallel (-1)."""
    s = load_mold({"sphere": {"center": [0, 0, 0], "radius": 1}}).kernel_args()
    A = np.array
    assert mold_segment_hit(s, A([0.0, 0, 2]), A([0.0, 0, -2])) == pytest.approx(0.25)
    assert mold_segment_hit(s, A([-2.0, 1, 0]), A([2.0, 1, 0])) == -1.0
    assert mold_segment_hit(s, A([0.0, 0, 1]), A([0.0, 0, 0.5])) == 0.0
    assert mold_segment_hit(s, A([0.0, 0, 1]), A([0.0, 0, 1.5])) == -1.0
    c = load_mold({"cylinder": {"center": [0, 0, 0], "axis": [0, 0, 1], "radius": 1,
                                "length": 2}}).kernel_args()
    assert mold_segment_hit(c, A([3.0, 0, 0]), A([-5.0, 0, 0])) == pytest.approx(0.25)
    assert mold_segment_hit(c, A([0.5, 0, 3.0]), A([0.5, 0, -5.0])) == pytest.approx(0.25)
    assert mold_segment_hit(c, A([-2.0, 1.0, 0.0]), A([2.0, 1.0, 0.0])) == -1.0
    b = load_mold({"box": {"min": [0, 0, 0], "max": [1, 1, 1]}}).kernel_args()
    assert mold_segment_hit(b, A([0.5, 0.5, 2.0]), A([0.5, 0.5, 0.0])) == pytest.approx(0.5)
    assert mold_segment_hit(b, A([-1.0, 0.5, 0.0]), A([1.0, 0.5, 2.0])) == -1.0
    assert mold_segment_hit(b, A([0.2, 0.3, 1.0]), A([0.8, 0.3, 1.0])) == -1.0
    p = load_mold({"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}}).kernel_args()
    assert mold_segment_hit(p, A([0.0, 0, 0.4]), A([0.0, 0, -0.6])) == pytest.approx(0.4)
    assert mold_segment_hit(p, A([0.0, 0, 0.4]), A([1.0, 0, 0.4])) == -1.0


# ---------------------------------------------------------------------------------------------
# loaders
# ---------------------------------------------------------------------------------------------

TETRA_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
TETRA_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def paper_text(base: int, extra: str = "") -> str:
    pts = "\n".join(f"{i + base} {x} {y} {z}" for i, (x, y, z) in enumerate(TETRA_V))
    tris = "\n".join(" ".join(str(k + base) for k in f) for f in TETRA_F)
    return f"# tetra\n{pts}\n{tris}\n{extra}"


def test_loaders_round_trip(tmp_path):
    """STL (trimesh), paper text 0- and 1-based, VTK (quad fanned into 2 triangles), VRML (quads):
    triangle counts, closedness, volumes match the source geometry."""
    tm = trimesh.Trimesh(TETRA_V, TETRA_F)
    (tmp_path / "t.stl").write_bytes(tm.export(file_type="stl"))
    for name, text in (("t0.txt", paper_text(0)), ("t1.pts", paper_text(1))):
        (tmp_path / name).write_text(text)
    for name in ("t.stl", "t0.txt", "t1.pts"):
        m = load_mold({"path": name}, base_dir=tmp_path)
        assert len(m.faces) == 4 and m.closed
        assert trimesh.Trimesh(m.vertices, m.faces).volume == pytest.approx(1 / 6)
    vtk = ("# vtk DataFile Version 3.0\npyramid\nASCII\nDATASET POLYDATA\nPOINTS 5 float\n"
           "0 0 0 1 0 0 1 1 0\n0 1 0 0.5 0.5 1\nPOLYGONS 5 21\n4 0 3 2 1\n3 0 1 4\n3 1 2 4\n"
           "3 2 3 4\n3 3 0 4\n")
    (tmp_path / "p.vtk").write_text(vtk)
    m = load_mold({"path": str(tmp_path / "p.vtk")})
    assert len(m.faces) == 6 and m.closed
    assert trimesh.Trimesh(m.vertices, m.faces).volume == pytest.approx(1 / 3)
    wrl = """#VRML V2.0 utf8
# a unit cube
Shape { geometry IndexedFaceSet {
  coord Coordinate { point [ 0 0 0, 1 0 0, 1 1 0, 0 1 0,
                             0 0 1, 1 0 1, 1 1 1, 0 1 1 ] }
  coordIndex [ 0 3 2 1 -1, 4 5 6 7 -1, 0 1 5 4 -1,
               1 2 6 5 -1, 2 3 7 6 -1, 3 0 4 7 -1 ]
} }
"""
    (tmp_path / "c.wrl").write_text(wrl)
    m = load_mold({"path": str(tmp_path / "c.wrl")})
    assert len(m.faces) == 12 and m.closed
    assert trimesh.Trimesh(m.vertices, m.faces).volume == pytest.approx(1.0)
    m2 = load_mold_bytes(wrl.encode(), "upload.wrl", translate=[1, 0, 0])
    np.testing.assert_allclose(m2.bounds, [[1, 0, 0], [2, 1, 1]])


def test_transform_scale_rotate_translate(tmp_path):
    """A mold in millimetres with scale 0.001 has the metres mold's bounds; rotate [0, 0, 90]
    maps +x to +y; order is scale, rotate (x, then y, then z), translate."""
    box_m = trimesh.creation.box(extents=[0.02, 0.04, 0.01])
    box_m.apply_translation([0.05, 0.05, 0.0])
    box_mm = box_m.copy()
    box_mm.apply_scale(1000.0)
    (tmp_path / "m.stl").write_bytes(box_m.export(file_type="stl"))
    (tmp_path / "mm.stl").write_bytes(box_mm.export(file_type="stl"))
    a = load_mold({"path": "m.stl"}, tmp_path)
    b = load_mold({"path": "mm.stl", "scale": 0.001}, tmp_path)
    np.testing.assert_allclose(b.bounds, a.bounds, atol=1e-9)
    r = load_mold({"path": "m.stl", "rotate": [0, 0, 90], "translate": [1, 2, 3], "scale": 2},
                  tmp_path)
    # box x in [0.04, 0.06], y in [0.03, 0.07], z in [-0.005, 0.005]; scale 2, then Rz(90):
    # (x, y) -> (-y, x), then + (1, 2, 3). STL stores float32, hence atol 1e-8.
    np.testing.assert_allclose(r.bounds[:, 0], [1 - 0.14, 1 - 0.06], atol=1e-8)
    np.testing.assert_allclose(r.bounds[:, 1], [2.08, 2.12], atol=1e-8)
    np.testing.assert_allclose(r.bounds[:, 2], [2.99, 3.01], atol=1e-8)
    # x first, then y: Rx(90) (x, y, z) -> (x, -z, y), Ry(90) (x, y, z) -> (z, y, -x)
    # so (x, y, z) -> (y, -z, -x)
    q = load_mold({"path": "m.stl", "rotate": [90, 90, 0]}, tmp_path)
    np.testing.assert_allclose(q.bounds, [[0.03, -0.005, -0.06], [0.07, 0.005, -0.04]], atol=1e-8)


@pytest.mark.parametrize("name,content,needle", [
    ("nan.txt", "1 0 0 0\n2 1 0 0\n3 nan 1 0\n4 0 0 1\n1 2 3\n", "line 3"),
    ("range.txt", "1 0 0 0\n2 1 0 0\n3 0 1 0\n1 2 3\n1 2 7\n", "line 5"),
    ("zero_based_mismatch.tri", "1 0 0 0\n2 1 0 0\n3 0 1 0\n0 1 2\n", "line 4"),
    ("empty.stl", "", "empty"),
    ("blank.txt", "\n\n  \n", "empty"),
    ("points_only.txt", "1 0 0 0\n2 1 0 0\n", "no triangles"),
    ("garbage.txt", "hello world this is\nnot a mold\n", "line 1"),
    ("garbage.stl", "\x00\x01garbage bytes that are not an stl at all" * 3, "garbage.stl"),
    ("garbage.xyz1", "hello", "unknown"),
    ("bad.vtk", "# vtk DataFile Version 3.0\nx\nBINARY\nDATASET POLYDATA\n", "binary"),
    ("bad2.vtk", "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n"
                 "0 0 0 1 0 inf 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n", "line 6"),
    ("bad3.vtk", "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n"
                 "0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 9\n", "line 8"),
    ("bad.wrl", "#VRML V2.0 utf8\nShape { geometry IndexedFaceSet {\ncoord Coordinate { point "
                "[ 0 0 0, 1 0 0, 0 1 0 ] }\ncoordIndex [ 0 1 5 -1 ] } }\n", "line 4"),
])
def test_bad_files_raise_with_name_and_line(tmp_path, name, content, needle):
    """Each bad file raises MoldError whose message names the file and (where known) the line."""
    p = tmp_path / name
    p.write_bytes(content.encode("latin-1"))
    with pytest.raises(MoldError) as ei:
        load_mold({"path": str(p)})
    msg = str(ei.value)
    assert name in msg
    assert needle.lower() in msg.lower()


def test_missing_file_and_bad_spec(tmp_path):
    """Unreadable path and malformed specs raise MoldError naming the problem."""
    with pytest.raises(MoldError, match="nope.stl"):
        load_mold({"path": "nope.stl"}, tmp_path)
    with pytest.raises(MoldError, match="radius"):
        load_mold({"sphere": {"center": [0, 0, 0], "radius": -1}})
    with pytest.raises(MoldError, match="max"):
        load_mold({"box": {"min": [0, 0, 0], "max": [1, 0, 1]}})
    with pytest.raises(MoldError):
        load_mold({"sphere": {"center": [0, 0, 0], "radius": 1}, "path": "x.stl"})
    assert load_mold(None) is None


def test_degenerate_and_duplicate_triangles_dropped_with_count():
    """A tetra plus 2 zero-area triangles and 1 duplicate (reversed) loads as the tetra, with
    warnings that count 2 degenerate and 1 duplicate triangles."""
    V = np.vstack([TETRA_V, [[0.5, 0, 0]]])  # vertex 4 on edge 0-1
    F = np.vstack([TETRA_F, [[0, 1, 4], [2, 2, 3], TETRA_F[1][::-1]]])
    with pytest.warns(UserWarning) as rec:
        m = mold_from_arrays(V, F, source="dup.stl")
    msgs = " | ".join(str(r.message) for r in rec)
    assert "dropped 2 degenerate" in msgs and "dropped 1 duplicate" in msgs and "dup.stl" in msgs
    assert len(m.faces) == 4 and m.closed and len(m.vertices) == 4


def test_winding_repair_and_non_orientable():
    """Icosphere with 30 flipped faces is repaired (all normals outward); a reversed closed mesh
    is turned outward; a Moebius strip raises MoldError about the winding."""
    m = trimesh.creation.icosphere(subdivisions=2)
    F = np.asarray(m.faces).copy()
    F[::11] = F[::11, ::-1]
    mold = mold_from_arrays(m.vertices, F)
    V = np.asarray(mold.vertices)
    c = V[np.asarray(mold.faces)].mean(axis=1)
    assert (np.einsum("ij,ij->i", c, np.asarray(mold.face_normals)) > 0).all()
    inv = mold_from_arrays(m.vertices, np.asarray(m.faces)[:, ::-1])
    out = np.empty(8)
    assert mold_query(inv.kernel_args(), np.zeros(3), out) < 0
    # Moebius strip
    n = 24
    u = np.linspace(0, 2 * np.pi, n, endpoint=False)
    Vm = []
    for ui in u:
        for w in (-0.2, 0.2):
            Vm.append([(1 + w * np.cos(ui / 2)) * np.cos(ui), (1 + w * np.cos(ui / 2)) * np.sin(ui),
                       w * np.sin(ui / 2)])
    Fm = []
    for i in range(n):
        a, b = 2 * i, 2 * i + 1
        if i < n - 1:
            c, d = 2 * i + 2, 2 * i + 3
        else:
            c, d = 1, 0  # the half twist
        Fm += [[a, c, b], [b, c, d]]
    with pytest.raises(MoldError, match="winding"):
        mold_from_arrays(np.array(Vm), np.array(Fm), source="moebius")


def test_surface_mesh_and_bounds_of_primitives():
    """Tessellations of primitives lie on their surfaces (|sd| ~ 0 at the tessellation's
    vertices) and bounds match the formulas."""
    specs = [{"sphere": {"center": [0, 0, 1], "radius": 0.5}},
             {"cylinder": {"center": [0, 0, 0], "axis": [0, 1, 0], "radius": 0.3, "length": 1}},
             {"box": {"min": [0, 0, 0], "max": [1, 2, 3]}}]
    for spec in specs:
        m = load_mold(spec)
        V, F = m.surface_mesh(resolution=32)
        assert F.dtype == np.int64 and F.max() < len(V)
        sd, *_ = query_all(m, V)
        assert np.abs(sd).max() < 1e-9
    np.testing.assert_allclose(load_mold(specs[1]).bounds, [[-0.3, -0.5, -0.3], [0.3, 0.5, 0.3]])
    pl = load_mold({"plane": {"point": [0, 0, 2], "normal": [0, 0, 1]}})
    assert pl.bounds[1, 2] == 2 and np.isinf(pl.bounds[0]).all()
    assert pl.kind == MOLD_PLANE and load_mold(specs[0]).kind == MOLD_SPHERE
    assert load_mold(specs[2]).kind == MOLD_BOX


# ---------------------------------------------------------------------------------------------
# bundled molds
# ---------------------------------------------------------------------------------------------


def test_thermoform_mold_bundled():
    """thermoform_mold.stl: closed, watertight, positive volume, 5-20k triangles, inside
    x, y in [0.015, 0.085], top near z = 0.02, base below z = 0, boss about 0.06 m across, and
    non-convex (convex hull at least 3 % larger). Its BVH query agrees with brute force."""
    m = load_mold({"path": "static/molds/thermoform_mold.stl"}, ROOT)
    tm = trimesh.Trimesh(m.vertices, m.faces)
    assert m.closed and tm.is_watertight and tm.volume > 0
    assert 5000 <= len(m.faces) <= 20000
    lo, hi = m.bounds
    assert lo[0] >= 0.015 - 1e-9 and lo[1] >= 0.015 - 1e-9
    assert hi[0] <= 0.085 + 1e-9 and hi[1] <= 0.085 + 1e-9
    assert 0.018 <= hi[2] <= 0.025 and lo[2] < 0
    sec = tm.section(plane_origin=[0, 0, -0.004], plane_normal=[0, 0, 1])
    width = np.ptp(sec.vertices[:, 0])
    assert 0.05 <= width <= 0.065
    assert tm.convex_hull.volume > 1.03 * tm.volume
    rng = np.random.default_rng(8)
    P = rng.uniform([0.01, 0.01, -0.02], [0.09, 0.09, 0.03], size=(40, 3))
    sd, *_ = query_all(m, P)
    d_ref, _ = brute_closest(P, np.asarray(m.vertices), np.asarray(m.faces))
    np.testing.assert_allclose(np.abs(sd), d_ref, atol=1e-14)
    assert np.array_equal(sd < 0, winding_number(P, np.asarray(m.vertices), np.asarray(m.faces)) > 0.5)


def test_torso_bundled():
    """torso.stl: closed, outward, 10-30k triangles, z from 0 to 0.6, centred on the z axis;
    girths (section perimeters) hip 0.95, waist 0.70, bust 0.90 m within 2 cm."""
    m = load_mold({"path": str(MOLDS / "torso.stl")})
    tm = trimesh.Trimesh(m.vertices, m.faces)
    assert m.closed and tm.is_watertight and tm.volume > 0
    assert 10000 <= len(m.faces) <= 30000
    np.testing.assert_allclose(m.bounds[:, 2], [0.0, 0.6], atol=1e-9)
    assert np.abs(tm.centroid[:2]).max() < 0.02
    girth = {z: tm.section(plane_origin=[0, 0, z], plane_normal=[0, 0, 1]).length
             for z in np.linspace(0.02, 0.58, 57)}
    zs = np.array(list(girth))
    g = np.array(list(girth.values()))
    waist = g[(zs > 0.2) & (zs < 0.4)].min()
    hip = g[zs < 0.2].max()
    bust = g[(zs > 0.4) & (zs < 0.55)].max()
    assert waist == pytest.approx(0.70, abs=0.02)
    assert hip == pytest.approx(0.95, abs=0.02)
    assert bust == pytest.approx(0.90, abs=0.02)
    assert tm.convex_hull.volume > 1.05 * tm.volume


def test_bundled_text_and_vtk_examples():
    """The paper-format thermoform mold and the VTK pyramid load closed with positive volume;
    the pyramid's quad base is fanned (6 triangles, volume 0.04^2 * 0.03 / 3)."""
    t = load_mold({"path": "static/molds/thermoform_mold.txt"}, ROOT)
    tt = trimesh.Trimesh(t.vertices, t.faces)
    assert t.closed and tt.volume > 0 and len(t.faces) > 500
    p = load_mold({"path": "static/molds/pyramid.vtk"}, ROOT)
    assert len(p.faces) == 6 and p.closed
    assert trimesh.Trimesh(p.vertices, p.faces).volume == pytest.approx(0.04 ** 2 * 0.03 / 3)


# ---------------------------------------------------------------------------------------------
# bad mold input (issue 15): refused with file, line and reason, quickly and in bounded memory
# ---------------------------------------------------------------------------------------------

TRI_TXT = "0 0 0 0\n1 1 0 0\n2 0 1 0\n0 1 2\n"


@pytest.mark.parametrize("text, line", [
    ("0 0 0 0\n1 1 0 0\n99999999999999999999999 0 1 0\n0 1 2\n", 3),
    ("0 0 0 0\n1 1 0 0\n1e300 0 1 0\n0 1 1e300\n", 3),
    ("0 0 0 0\n1 1 0 0\n2 0 1 0\n0 1 99999999999999999999999\n", 4),
    ("0 0 0 0\n1 1 0 0\n2 0 1 0\n0 1 -1e300\n", 4),
])
def test_paper_text_huge_index_refused_with_line(tmp_path, text, line):
    """A paper-format index too large for an int64 (or 1e300) is a MoldError naming the file,
    the line and 'out of range' -- not a raw OverflowError from numpy (issue 15)."""
    p = tmp_path / "huge.txt"
    p.write_text(text)
    with pytest.raises(MoldError) as ei:
        load_mold({"path": str(p)})
    msg = str(ei.value)
    assert "huge.txt" in msg and f"line {line}" in msg and "out of range" in msg
    with pytest.raises(MoldError, match="out of range"):  # uploads take the same reader
        load_mold_bytes(text.encode(), "huge.txt")


def test_non_regular_files_refused_quickly(tmp_path):
    """/dev/zero (an endless stream), a named pipe and a folder are refused before any read,
    with a clear message (the old loader read /dev/zero until memory ran out and blocked forever
    on a pipe)."""
    import os
    import time

    cases = [tmp_path]
    if Path("/dev/zero").exists():
        cases.append(Path("/dev/zero"))
    if hasattr(os, "mkfifo"):
        fifo = tmp_path / "pipe.stl"
        os.mkfifo(fifo)
        cases.append(fifo)
    for path in cases:
        t0 = time.perf_counter()
        with pytest.raises(MoldError, match="not a regular file"):
            load_mold({"path": str(path)})
        assert time.perf_counter() - t0 < 2.0


def test_mold_file_size_capped(tmp_path):
    """A file over the size limit is refused by its size, and the read itself never takes more
    than the limit plus one byte (a file that grows after the check cannot make it unbounded)."""
    from clothsim.mold import readers

    p = tmp_path / "m.txt"
    p.write_text(TRI_TXT * 50)
    with pytest.raises(MoldError, match="over the mold file limit"):
        readers.read_mold_file(p, max_bytes=100)
    old = readers.MAX_MOLD_FILE_BYTES
    readers.MAX_MOLD_FILE_BYTES = 100
    try:
        with pytest.raises(MoldError, match="over the mold file limit"):
            load_mold({"path": str(p)})
    finally:
        readers.MAX_MOLD_FILE_BYTES = old


def test_symlink_out_of_folder_not_followed(tmp_path):
    """A mold path that is a symbolic link to a file outside the folder it names is refused,
    and the message quotes nothing of the target; a link to a file in the same folder loads."""
    secret = tmp_path / "secret"
    secret.write_text("root:*:19000:0:99999:7:::\n")
    folder = tmp_path / "molds"
    folder.mkdir()
    (folder / "shadow.txt").symlink_to(secret)
    with pytest.raises(MoldError) as ei:
        load_mold({"path": "shadow.txt"}, folder)
    assert "outside its folder" in str(ei.value) and "19000" not in str(ei.value)
    (folder / "real.txt").write_text(TRI_TXT)
    (folder / "alias.txt").symlink_to(folder / "real.txt")
    assert len(load_mold({"path": "alias.txt"}, folder).faces) == 1


@pytest.mark.parametrize("name, content", [
    ("long.txt", "0 0 0 0\nroot:*:19000:0:99999:7:::secretsecretsecret 1 2 3\n0 1 2\n"),
    ("ctrl.txt", "0 0 0 0\n1 1 0 0\n\x1b[31mredredredredredredredredred\x07 0 1 0\n0 1 2\n"),
    ("many.txt", "0 0 0 0\n" + " ".join(["secretword"] * 30) + "\n"),
    ("kw.vtk", "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\n"
               "root:*:19000:0:99999:7:::secretsecretsecret\n"),
    ("hdr.vtk", "# vtk DataFile Version 3.0\nx\nroot:*:19000:0:99999:7:::secretsecretsecret\n"),
])
def test_error_messages_quote_short_printable_excerpt(tmp_path, name, content):
    """Messages about a bad file quote at most a short, printable excerpt of its content: no
    control characters and never a whole long line (issue 15: a link to /etc/shadow named
    .txt echoed its content)."""
    p = tmp_path / name
    p.write_bytes(content.encode("latin-1"))
    with pytest.raises(MoldError) as ei:
        load_mold({"path": str(p)})
    msg = str(ei.value).replace(str(p), "")
    assert "secretsecretsecret" not in msg and "redredredredredredredredred" not in msg
    assert msg.count("secretword") <= 3
    assert all(" " <= c <= "~" for c in msg), repr(msg)


# ---------------------------------------------------------------------------------------------
# typed specs and the cache of loaded molds
# ---------------------------------------------------------------------------------------------


def test_load_mold_accepts_typed_spec_and_checks_dicts_with_it(tmp_path):
    """load_mold takes the typed spec a scene holds and a plain dict (checked by the same
    model, so a bad dict names the field as a scene file would)."""
    from clothsim.config import MeshMoldSpec, SphereMoldSpec, validate_mold_spec

    p = tmp_path / "t.txt"
    p.write_text(TRI_TXT)
    typed = validate_mold_spec({"path": str(p), "scale": 2})
    assert isinstance(typed, MeshMoldSpec)
    np.testing.assert_allclose(load_mold(typed).bounds, [[0, 0, 0], [2, 2, 0]])
    sph = validate_mold_spec({"sphere": {"center": [0, 0, 0], "radius": 1}})
    assert isinstance(sph, SphereMoldSpec) and load_mold(sph).kind == MOLD_SPHERE
    with pytest.raises(MoldError, match=r"mold\.scale: must be a positive number"):
        load_mold({"path": str(p), "scale": "abc"})
    with pytest.raises(MoldError, match=r"mold\.closed"):
        load_mold({"path": str(p), "closed": "maybe"})
    with pytest.raises(MoldError, match=r"mold\.path"):
        load_mold({"path": 5})


def test_loaded_mesh_molds_cached_by_spec(tmp_path, monkeypatch):
    """Loading the same spec twice returns the same Mold without reading the file or building
    the BVH again; another scale, another closed flag, or a changed file (size/mtime) builds a
    new one; the cache keeps MOLD_CACHE_SIZE molds, least recently used dropped first; the
    build's warnings are raised again on a hit."""
    import os

    from clothsim.mold import MOLD_CACHE_SIZE, build, clear_mold_cache, mold_cache_info

    builds = []
    real = build._build_bvh
    monkeypatch.setattr(build, "_build_bvh", lambda V, F: builds.append(1) or real(V, F))
    clear_mold_cache()
    p = tmp_path / "m.stl"
    trimesh.creation.box(extents=(1, 1, 1)).export(p)
    a = load_mold({"path": "m.stl"}, tmp_path)
    b = load_mold({"path": str(p)})
    assert b is a and len(builds) == 1 and mold_cache_info()["hits"] == 1
    c = load_mold({"path": str(p), "scale": 0.5})
    assert c is not a and len(builds) == 2
    assert load_mold({"path": str(p), "closed": True}) is not a and len(builds) == 3
    st = p.stat()
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # same bytes, newer file
    d = load_mold({"path": str(p)})
    assert d is not a and len(builds) == 4
    assert load_mold({"path": str(p)}) is d and len(builds) == 4
    # LRU: fill the cache with other scales; the oldest entry drops out
    for k in range(MOLD_CACHE_SIZE):
        load_mold({"path": str(p), "scale": 2.0 + k})
    assert mold_cache_info()["entries"] == MOLD_CACHE_SIZE
    n = len(builds)
    assert load_mold({"path": str(p)}) is not d and len(builds) == n + 1
    # warnings of the build come again on a hit
    q = tmp_path / "dup.txt"
    q.write_text("0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n0 1 2\n0 1 2\n0 1 3\n0 3 2\n1 2 3\n")
    for _ in range(2):
        with pytest.warns(UserWarning, match="duplicate"):
            load_mold({"path": str(q)})
    clear_mold_cache()


def test_mold_scale_warning_millimetres():
    """mold_scale_warning: None at a plausible size; 'millimetres?' when the mold is about 1000x
    larger (a file in mm read as m) or 1000x smaller than the sheet; None for a plane."""
    from clothsim.mold import mold_scale_warning

    tm = load_mold({"path": str(MOLDS / "thermoform_mold.stl")})
    assert mold_scale_warning(tm, (0.10, 0.10)) is None
    assert mold_scale_warning(tm, 0.6) is None
    V, F = tm.vertices, tm.faces
    mm = mold_from_arrays(V * 1000.0, F)
    w = mold_scale_warning(mm, (0.10, 0.10))
    assert w is not None and "millimetres?" in w and "larger" in w and "mold.scale: 0.001" in w
    w = mold_scale_warning(tm, 100.0)
    assert w is not None and "millimetres?" in w and "smaller" in w
    s = load_mold({"sphere": {"center": [0, 0, 0], "radius": 50.0}})
    assert "millimetres?" in mold_scale_warning(s, [0.1, 0.05])
    assert mold_scale_warning(load_mold({"plane": {"point": [0, 0, 0], "normal": [0, 0, 1]}}), 0.1) is None
    assert mold_scale_warning(None, 0.1) is None
