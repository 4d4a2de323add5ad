"""The smooth surface's gathered vertex lists (``smooth._gather``, ``smooth._blend_from``): the blend
summed over the vertices gathered near a point must be the BVH search's blend (``smooth._blend``)
bit for bit at every point within half the margin, and the foot iteration and shape operator
that use it must answer as before (same point, normal and curvature as the BVH-only sums)."""

from __future__ import annotations

import numpy as np
import trimesh

from clothsim.mold.build import mold_from_arrays
from clothsim.mold.smooth import _blend, _blend_from, _gather


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
