"""The Newton solver's per-node face store (``active_set._node_query``, ``queries.mesh_query_near``):
answers read from the faces kept near a node must be the BVH's answers, bit for bit, wherever the
node goes (on faces, edges and vertices, inside, outside, far away), and must be read from the
store where the faces settle them."""

from __future__ import annotations

import numpy as np
import trimesh

from clothsim.mold import mold_query
from clothsim.mold.build import mold_from_arrays
from clothsim.mold.queries import mesh_gather, mesh_query_near
from clothsim.solvers.newton.active_set import _node_query, near_faces


def _mold():
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    V = np.asarray(m.vertices) * np.array([1.0, 0.8, 1.3])  # an ellipsoid: faces of many shapes
    return mold_from_arrays(V, np.asarray(m.faces), closed=True).kernel_args()


def test_near_answers_are_the_bvh_answers_bit_for_bit():
    margs = _mold()
    V = np.asarray(margs.vertices)
    F = np.asarray(margs.faces)
    rng = np.random.default_rng(3)
    n = 60
    # nodes on vertices, edge midpoints and face centres, then random walks of growing steps
    starts = np.concatenate([V[rng.integers(0, len(V), n // 3)],
                             0.5 * (V[F[:20, 0]] + V[F[:20, 1]]),
                             V[F[20:40]].mean(axis=1)])
    near = near_faces(n, 0.01)
    q_near = np.empty(8)
    q_bvh = np.empty(8)
    pos = starts.copy()
    served = 0
    for step in (0.0, 1e-9, 1e-6, 1e-4, 1e-3, 5e-3, 2e-2, 0.1):
        for _ in range(5):
            pos = pos + step * rng.standard_normal(pos.shape)
            for k in range(n):
                p = np.ascontiguousarray(pos[k])
                counts_before = near[1][k]
                centre = near[2][k].copy()
                sd, status = mesh_query_near(margs, p, q_bvh, near[0][k], counts_before, centre, near[3][0])
                served += status == 0
                sd_near = _node_query(margs, p, q_near, k, near)
                sd_bvh = mold_query(margs, p, q_bvh)
                assert sd_near == sd_bvh, (k, step)
                assert np.array_equal(q_near, q_bvh), (k, step)
    assert served > 100  # the store answered (not only the BVH)


def test_gather_finds_exactly_the_faces_within_the_radius():
    margs = _mold()
    V = np.asarray(margs.vertices)
    F = np.asarray(margs.faces)
    x = V[5] + np.array([0.002, -0.001, 0.003])
    out = np.empty(64, np.int64)
    nc = mesh_gather(margs, x[0], x[1], x[2], 0.02, out)
    assert nc > 0
    q = np.empty(8)
    within = set()
    for f in range(len(F)):
        sub = mold_from_arrays(V[F[f]], np.array([[0, 1, 2]]), closed=False).kernel_args()
        mold_query(sub, x, q)
        if np.linalg.norm(x - q[:3]) < 0.02:
            within.add(f)
    assert set(out[:nc].tolist()) == within
    assert mesh_gather(margs, x[0], x[1], x[2], 0.02, np.empty(2, np.int64)) == -1  # too small a store
