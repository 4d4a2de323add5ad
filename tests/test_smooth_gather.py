"""The smooth surface's gathered vertex lists (``smooth._gather``, ``smooth._blend_from``): the blend
summed over the vertices gathered near a point must be the BVH search's blend (``smooth._blend``)
bit for bit at every point within half the margin, and the foot iteration and shape operator
that use it must answer as before (same point, normal and curvature as the BVH-only sums)."""

from __future__ import annotations

import numpy as np
import trimesh

from clothsim.mold.build import mold_from_arrays
from clothsim.mold.smooth import _blend, _blend_from, _gather, _gather_face


def _smooth_margs():
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    V = np.asarray(m.vertices) * np.array([1.0, 0.8, 1.3])
    return mold_from_arrays(V, np.asarray(m.faces), closed=True, surface="smooth").kernel_args()


def test_gathered_blend_is_the_bvh_blend_bit_for_bit():
    margs = _smooth_margs()
    V = np.asarray(margs.vertices)
    rng = np.random.default_rng(5)
    stack = np.empty(128, np.int64)
    margin = 0.25 * margs.params[14]
    assert margin > 0.0
    g1 = np.empty(3)
    g2 = np.empty(3)
    compared = 0
    for x in V[rng.integers(0, len(V), 40)] + 0.002 * rng.standard_normal((40, 3)):
        cand, nc = _gather(margs, x[0], x[1], x[2], margin, stack, np.empty(4, np.int64))  # grows
        assert nc > 0
        for _ in range(10):
            d = rng.standard_normal(3)
            y = x + 0.5 * margin * rng.uniform() * d / np.linalg.norm(d)
            a = _blend(margs, y[0], y[1], y[2], 0.0, g1, stack)
            b = _blend_from(margs, y[0], y[1], y[2], cand, nc, g2)
            assert a == b and np.array_equal(g1, g2)
            compared += a[1] > 0.0
    assert compared > 300


def test_a_vertex_left_out_changes_the_blend():
    # the comparison above can fail: without one of the gathered vertices the sums differ
    margs = _smooth_margs()
    x = np.asarray(margs.vertices)[7] + 1e-3
    stack = np.empty(128, np.int64)
    cand, nc = _gather(margs, x[0], x[1], x[2], 0.25 * margs.params[14], stack, np.empty(64, np.int64))
    g1 = np.empty(3)
    g2 = np.empty(3)
    a = _blend(margs, x[0], x[1], x[2], 0.0, g1, stack)
    V = np.asarray(margs.vertices)
    J = np.asarray(margs.vertex_jets)
    inside = [i for i in range(nc) if np.linalg.norm(x - V[cand[i]]) < J[cand[i], 15]]
    assert inside
    i = inside[0]
    fewer = np.concatenate([cand[:i], cand[i + 1:nc]])
    b = _blend_from(margs, x[0], x[1], x[2], fewer, nc - 1, g2)
    assert a != b


def test_face_lists_gather_what_the_bvh_gathers_at_every_point_of_the_face():
    # a query starts on the faceted closest point's face and gathers from that face's list
    # (``_gather_face``): the same vertices in the same order as the BVH search, at the face's
    # corners, on its edges and inside it
    margs = _smooth_margs()
    V = np.asarray(margs.vertices)
    F = np.asarray(margs.faces)
    ptr = np.asarray(margs.face_vertex_ptr)
    assert ptr.shape == (len(F) + 1,) and ptr[-1] == len(margs.face_vertex_idx)
    rng = np.random.default_rng(3)
    stack = np.empty(128, np.int64)
    margin = 0.25 * margs.params[14]
    checked = 0
    for f in rng.choice(len(F), 120, replace=False):
        a, b, c = V[F[f]]
        for w in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (0.5, 0.5, 0), (0, 0.3, 0.7)] + [tuple(rng.dirichlet((1, 1, 1)))
                                                                                      for _ in range(5)]:
            x = w[0] * a + w[1] * b + w[2] * c
            c1, n1 = _gather(margs, x[0], x[1], x[2], margin, stack, np.empty(64, np.int64))
            c2, n2 = _gather_face(margs, f, x[0], x[1], x[2], margin, np.empty(4, np.int64))  # grows
            assert n1 > 0 and n1 == n2 and np.array_equal(c1[:n1], c2[:n2])
            checked += 1
        # the list holds more than what one point gathers (it serves the whole face), and no
        # vertex twice
        lst = np.asarray(margs.face_vertex_idx[ptr[f]:ptr[f + 1]])
        assert len(np.unique(lst)) == len(lst)
    assert checked == 1200


def test_face_lists_against_brute_force_distance_to_the_triangle():
    # f's list = the vertices within r_v + margin of the triangle (up to the 1e-9 diagonal slack),
    # by brute force over all vertices and a dense sampling of the triangle
    margs = _smooth_margs()
    V = np.asarray(margs.vertices)
    F = np.asarray(margs.faces)
    J = np.asarray(margs.vertex_jets)
    ptr = np.asarray(margs.face_vertex_ptr)
    margin = 0.25 * margs.params[14]
    u, v = np.meshgrid(np.linspace(0, 1, 41), np.linspace(0, 1, 41))
    keep = u + v <= 1.0
    W = np.stack([1 - u[keep] - v[keep], u[keep], v[keep]], 1)
    for f in range(0, len(F), 37):
        S = W @ V[F[f]]
        d = np.sqrt(((V[:, None, :] - S[None]) ** 2).sum(-1)).min(1)
        lst = set(np.asarray(margs.face_vertex_idx[ptr[f]:ptr[f + 1]]).tolist())
        sure_in = set(np.nonzero(d < J[:, 15] + margin - 5e-4)[0].tolist())  # sampling error < 3e-4 m
        sure_out = set(np.nonzero(d > J[:, 15] + margin + 1e-9)[0].tolist())
        assert sure_in <= lst and not (lst & sure_out)


def test_smooth_query_answers_as_with_the_bvh_gather():
    # the query with the face lists against the same mold without them (the BVH gather): the
    # same bits
    from clothsim.mold import mold_query_many
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    V = np.asarray(m.vertices) * np.array([1.0, 0.8, 1.3])
    mold = mold_from_arrays(V, np.asarray(m.faces), closed=True, surface="smooth")
    import dataclasses
    bare = dataclasses.replace(mold, face_vertex_ptr=None, face_vertex_idx=None)
    assert len(bare.kernel_args().face_vertex_ptr) == 0
    rng = np.random.default_rng(11)
    P = V[rng.integers(0, len(V), 500)] + 0.004 * rng.standard_normal((500, 3))
    res = []
    for mm in (mold, bare):
        sd, cp, nr, ft = np.empty(500), np.empty((500, 3)), np.empty((500, 3)), np.empty((500, 2), np.int64)
        mold_query_many(mm.kernel_args(), P, sd, cp, nr, ft)
        res.append((sd, cp, nr, ft))
    for a, b in zip(*res):
        assert np.array_equal(a, b)


def _mold_and_bare():
    import dataclasses
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    V = np.asarray(m.vertices) * np.array([1.0, 0.8, 1.3])
    mold = mold_from_arrays(V, np.asarray(m.faces), closed=True, surface="smooth")
    return mold, dataclasses.replace(mold, face_vertex_ptr=None, face_vertex_idx=None), V


def test_shape_operator_with_face_lists_is_the_bvh_ones_bit_for_bit():
    from clothsim.mold import smooth_shape_operator
    mold, bare, V = _mold_and_bare()
    rng = np.random.default_rng(2)
    P = V[rng.integers(0, len(V), 200)] + 0.003 * rng.standard_normal((200, 3))
    cp = np.empty((200, 3))
    from clothsim.mold import mold_query_many
    mold_query_many(mold.kernel_args(), P, np.empty(200), cp, np.empty((200, 3)), np.empty((200, 2), np.int64))
    for h in (1e-6, 1e-4, 0.01):  # the last: 4 h beyond the list's margin, the BVH gather
        for p in cp:
            res = []
            for mm in (mold, bare):
                n = np.empty(3)
                S = np.empty((3, 3))
                ok = smooth_shape_operator(mm.kernel_args(), p[0], p[1], p[2], h, n, S)
                res.append((ok, n.copy(), S.copy()))
            assert res[0][0] and res[1][0]
            assert np.array_equal(res[0][1], res[1][1]) and np.array_equal(res[0][2], res[1][2])


def test_segment_hit_from_a_known_start_query_is_the_segment_hit():
    # the line search's free nodes start their segment hit from the node's answer already
    # queried (``_query_nodes`` with its smooth-surface flag): the same t, bit for bit, for
    # segments that hit, miss and graze, starting near and far (faceted fallback) from the surface
    from clothsim.mold import mold_segment_hit
    from clothsim.mold.segment import smooth_segment_hit_from
    from clothsim.solvers.newton.active_set import _query_nodes
    mold, _, V = _mold_and_bare()
    margs = mold.kernel_args()
    rng = np.random.default_rng(9)
    n = 400
    c = V[rng.integers(0, len(V), n)]
    out = c * (1.0 + rng.choice([0.02, 0.1, 0.8, 1.5], n)[:, None])  # near, and beyond the supports
    P1 = c * (1.0 - 0.05 * rng.uniform(-1, 1, n)[:, None]) + 0.01 * rng.standard_normal((n, 3))
    Q = np.empty((n, 10))
    _query_nodes(out, True, margs, Q)
    assert 0 < Q[:, 9].sum() < n  # both the smooth answers and the faceted fallback
    hits = 0
    for k in range(n):
        t0 = mold_segment_hit(margs, out[k], P1[k])
        t1 = smooth_segment_hit_from(margs, out[k], P1[k], Q[k], Q[k, 8], Q[k, 9] != 0.0)
        assert t0 == t1
        hits += t0 >= 0.0
    assert 0 < hits < n


def test_slanted_segment_hits_are_the_first_crossing_by_bisection():
    # slanted segments from outside into the surface (a line-search trial's free node reaching
    # the body) hit where bisection on the smooth signed distance finds the first crossing
    # (sampled densely along the segment), to within the hit tolerance over the slope
    from clothsim.mold import mold_query, mold_segment_hit
    mold, _, V = _mold_and_bare()
    margs = mold.kernel_args()
    rng = np.random.default_rng(4)
    q = np.empty(8)

    def sd(x):
        return mold_query(margs, x, q)

    checked = 0
    for k in rng.integers(0, len(V), 60):
        c = np.asarray(margs.vertices[k])
        n = np.asarray(margs.vertex_normals[k])
        t1 = np.cross(n, rng.standard_normal(3))
        t1 /= np.linalg.norm(t1)
        p0 = c + 0.01 * n - 0.02 * t1
        p1 = c - 0.006 * n + 0.01 * t1  # slanted: about 30 degrees to the surface
        t = mold_segment_hit(margs, p0, p1)
        ts = np.linspace(0.0, 1.0, 401)
        f = np.array([sd(p0 + s * (p1 - p0)) for s in ts])
        i = np.nonzero(f < 0.0)[0]
        assert len(i) and i[0] > 0
        lo, hi = ts[i[0] - 1], ts[i[0]]
        for _ in range(60):
            m = 0.5 * (lo + hi)
            lo, hi = (m, hi) if sd(p0 + m * (p1 - p0)) > 0.0 else (lo, m)
        L = np.linalg.norm(p1 - p0)
        assert abs(sd(p0 + t * (p1 - p0))) <= 1e-12
        assert abs(t - lo) * L <= 1e-10
        checked += 1
    assert checked == 60


def test_face_lists_are_dropped_above_their_memory_cap():
    """Lists longer in all than ``max_entries`` are not kept (the queries search the BVH, which
    the test above shows gives the same answers); under the cap they are the full lists."""
    from clothsim.mold.smooth import FACE_LIST_MAX_ENTRIES, face_vertex_lists

    mold, _, _ = _mold_and_bare()
    ptr, idx = face_vertex_lists(mold.kernel_args(), FACE_LIST_MAX_ENTRIES)
    assert np.array_equal(ptr, mold.face_vertex_ptr) and np.array_equal(idx, mold.face_vertex_idx)
    assert 0 < idx.size < FACE_LIST_MAX_ENTRIES
    p2, i2 = face_vertex_lists(mold.kernel_args(), idx.size)
    assert np.array_equal(i2, idx)                       # exactly at the cap: kept
    p3, i3 = face_vertex_lists(mold.kernel_args(), idx.size - 1)
    assert p3.size == 0 and i3.size == 0
