"""The trial positions of Newton's line search: free nodes moved along the step and stopped at the
mold surface, contact nodes projected back onto it (on a mesh, along their face until they leave
it), with the records the smooth surface's trials keep. Pure numba functions of arrays.

Shapes: n nodes; positions/forces (n, 3) [m]/[N]; flat step vectors (3n,) [m].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...contact import cut_move, stop_at_surface
from ...mold import MOLD_MESH, MOLD_SMOOTH
from ...mold.queries import is_primitive, query_at
from ...mold.segment import primitive_segment_hit, smooth_segment_hit_from
from ...mold.smooth import _smooth_query_flag


@njit(cache=True)
def _face_exit(margs, f, p0, d):
    """Largest t in [0, 1] such that p0 + t d stays inside triangle f (barycentric coordinates
    of the point's projection onto the face plane all >= 0)."""
    V = margs[2]
    F = margs[3]
    a = F[f, 0]
    b = F[f, 1]
    c = F[f, 2]
    e1x = V[b, 0] - V[a, 0]; e1y = V[b, 1] - V[a, 1]; e1z = V[b, 2] - V[a, 2]
    e2x = V[c, 0] - V[a, 0]; e2y = V[c, 1] - V[a, 1]; e2z = V[c, 2] - V[a, 2]
    d11 = e1x * e1x + e1y * e1y + e1z * e1z
    d12 = e1x * e2x + e1y * e2y + e1z * e2z
    d22 = e2x * e2x + e2y * e2y + e2z * e2z
    den = d11 * d22 - d12 * d12
    if not (den > 0.0):
        return 1.0
    wx = p0[0] - V[a, 0]; wy = p0[1] - V[a, 1]; wz = p0[2] - V[a, 2]
    w1 = wx * e1x + wy * e1y + wz * e1z
    w2 = wx * e2x + wy * e2y + wz * e2z
    u0 = (d22 * w1 - d12 * w2) / den
    v0 = (d11 * w2 - d12 * w1) / den
    q1 = d[0] * e1x + d[1] * e1y + d[2] * e1z
    q2 = d[0] * e2x + d[1] * e2y + d[2] * e2z
    du = (d22 * q1 - d12 * q2) / den
    dv = (d11 * q2 - d12 * q1) / den
    lam = (u0, v0, 1.0 - u0 - v0)
    dl = (du, dv, -du - dv)
    t = 1.0
    for i in range(3):
        if dl[i] < 0.0:
            ti = -max(lam[i], 0.0) / dl[i]
            if ti < t:
                t = ti
    return max(t, 0.0)


# no records for _trial_positions_sd (molds other than the smooth surface; callers without them)
_NO_MEMO = np.zeros((0, 6))
_NO_QT = np.zeros((0, 11))


@njit(cache=True)
def _trial_positions(pos0, contact0, sd0, step, alpha, fixed, has_mold, margs, clip_faces, face0, F0, out,
                     contact_out, rules):
    """``_trial_positions_sd`` without the per-node distances and the reuse of an earlier pass."""
    sd_out = np.empty(pos0.shape[0])
    return _trial_positions_sd(pos0, contact0, sd0, step, alpha, fixed, has_mold, margs, clip_faces, face0, F0,
                               out, contact_out, sd_out, False, np.empty((0, 10)), _NO_MEMO, _NO_QT, rules)


@njit(cache=True)
def _trial_positions_sd(pos0, contact0, sd0, step, alpha, fixed, has_mold, margs, clip_faces, face0, F0, out,
                        contact_out, sd_out, reuse, Q0, memo, Qt, rules):
    """Positions after the step alpha*step with the contact rules (paper 3.2.2): a free node's
    move is clipped where it would enter the mold and it becomes a contact node; contact nodes
    are projected onto the surface. sd0 (N,) [m]: the signed distances of the nodes not in
    contact before the step (a free node whose move is shorter than its distance cannot reach the
    mold and needs no query). clip_faces: on a mesh mold, contact nodes stop at their face's
    border; face0 (N,) int64: that face (``_contact_faces_q``; -1: not on a face). Returns the
    deepest remaining penetration [m] (0 when none). sd_out (N,) [m]: each node's signed
    distance after its move (0 for a node not queried). reuse (with clip_faces): out,
    contact_out and sd_out hold the pass without the clip at the same pos0, step and alpha, and
    the nodes that the clip does not stop (their position is the same) keep that pass's answers
    instead of being queried again: the same result, bit for bit. Q0 (n, 10): the mold's answers
    at pos0 with their smooth-surface flags (``_query_nodes``; (0, 10): none): on the smooth
    surface a free node's segment hit starts from its answer instead of querying pos0 again (the
    same bits).

    On the smooth surface (with Q0), two records that make a line search's shorter steps cheap:
    memo (n, 6) (``(0, 6)``: none), the free nodes' segment traces of this line search (the
    caller zeroes column 0 when a line search starts): memo[k, 0] the alpha of node k's trace
    (0: none yet), memo[k, 1] the share of that segment where it first enters the surface (-1:
    nowhere), memo[k, 2:5] [m] and memo[k, 5] [m] the node's position and signed distance after
    the hit. A shorter step's segment is a prefix of the traced one (the same start and
    direction), so its first entry is the same point, or none when the prefix ends before it:
    each free node is traced once per line search (a grazing segment takes up to 64 queries).
    The same point up to the trace's tolerance: where a segment starts on the surface and grazes
    it, a fresh trace of the shorter segment may find a re-entry a little away (1.75e-8 m seen on
    the smooth stocking; the same contact set).
    Qt (n, 11) (``(0, 11)``: none): each node's mold answer at its trial position where this pass
    knows it (Qt[k, 0:10] as ``_query_nodes``' Q row, Qt[k, 10] = 1; 0 where it does not): the
    query of a point left where it was queried, and for a node put on the surface its foot
    point's answer (the foot, the normal there, distance 0: a converged foot point is on the
    surface to 1e-13 m); ``NewtonLevel._accept`` reads it instead of querying them again.
    rules (7,): the tuning's contact rules (``contact_rules``)."""
    keep_gap = rules[0] != 0.0
    gap_min = rules[1]
    release_gap = rules[2]
    foot_trusted = rules[3] != 0.0
    proj_steps = int(rules[4])
    proj_everywhere = rules[5] != 0.0
    proj_tol = rules[6]
    q = np.empty(8)
    q0_known = Q0.shape[0] == pos0.shape[0] and Q0.shape[1] > 9 and margs[0][0] == MOLD_SMOOTH
    use_memo = q0_known and memo.shape[0] == pos0.shape[0]
    use_qt = q0_known and Qt.shape[0] == pos0.shape[0]
    p = np.empty(3)
    dd = np.empty(3)
    worst = 0.0
    kind = margs.info[0]
    prim = is_primitive(kind)
    prm = margs.params
    for k in range(pos0.shape[0]):
        if use_qt:
            Qt[k, 10] = 0.0
        traced = False
        moved = False
        d2 = 0.0
        for a in range(3):
            v = pos0[k, a]
            if not fixed[k, a]:
                d = alpha * step[3 * k + a]
                if d != 0.0:
                    moved = True
                    d2 += d * d
                v += d
            p[a] = v
        c = contact0[k]
        # a contact node off the surface by a gap to close (held_keep_gap): its step closes it
        # (``_gap_closure``), the trial keeps the part (1 - alpha) not yet closed
        gap = 0.0
        if c and keep_gap and sd0[k] > gap_min and not (fixed[k, 0] or fixed[k, 1] or fixed[k, 2]):
            gap = sd0[k]
        frac = alpha
        sdk = 0.0
        if has_mold and moved and (c or not (sd0[k] > math.sqrt(d2) * (1.0 + 1e-9) + 1e-15)):
            hit = False
            if c:
                hit = True
                if clip_faces and margs[0][0] == MOLD_MESH:
                    # a contact node on a face slides at most to the face's border: the contact
                    # feature changes there (edge or vertex), and the next active set decides
                    # whether it stays on it or moves on to the next face
                    clipped = False
                    if face0[k] >= 0:
                        for a in range(3):
                            dd[a] = p[a] - pos0[k, a]
                        t = _face_exit(margs, face0[k], pos0[k], dd)
                        if t < 1.0:
                            clipped = True
                            frac = alpha * t
                            for a in range(3):
                                if not fixed[k, a]:
                                    p[a] = pos0[k, a] + t * dd[a]
                    if reuse and not clipped:
                        # the same position as in the pass without the clip: its answers stand
                        if -sd_out[k] > worst:
                            worst = -sd_out[k]
                        continue
            elif reuse:
                if -sd_out[k] > worst:
                    worst = -sd_out[k]
                continue
            elif use_memo and memo[k, 0] > 0.0:
                # traced on a longer step of this line search: the hit, if this step reaches it
                if memo[k, 1] >= 0.0 and alpha >= memo[k, 0] * memo[k, 1]:
                    for a in range(3):
                        out[k, a] = memo[k, 2 + a]
                    contact_out[k] = True
                    sd_out[k] = memo[k, 5]
                    if -memo[k, 5] > worst:
                        worst = -memo[k, 5]
                    continue
                hit = False
            elif q0_known:
                # stop_at_surface with the query at pos0 read from Q0
                t_hit = smooth_segment_hit_from(margs, pos0[k], p, Q0[k], Q0[k, 8], Q0[k, 9] != 0.0)
                hit = cut_move(pos0[k], p, fixed[k], t_hit)
                if use_memo:
                    memo[k, 0] = alpha
                    memo[k, 1] = t_hit
                    traced = hit
            elif prim:
                hit = cut_move(pos0[k], p, fixed[k], primitive_segment_hit(kind, prm, pos0[k], p))
            else:
                hit = stop_at_surface(margs, pos0[k], p, fixed[k])
            on_foot = False
            if margs[0][0] == MOLD_SMOOTH:
                sd, on_foot = _smooth_query_flag(margs, p[0], p[1], p[2], q)
                if use_qt:
                    # the answer at p, where the node stays unless it is put on the surface
                    for a in range(8):
                        Qt[k, a] = q[a]
                    Qt[k, 8] = sd
                    Qt[k, 9] = 1.0 if on_foot else 0.0
                    Qt[k, 10] = 1.0
            else:
                sd = query_at(prim, kind, prm, margs, p, q)
            if gap > 0.0:
                gap = (1.0 - frac) * gap if frac < 1.0 else 0.0
            if c and sd > gap + release_gap and q[6] != 0.0:
                # a contact node whose move took it off the surface past a convex edge or vertex
                # (the closest point is on that edge or vertex): it is put back there only if its
                # resultant pulls it there (R . (p - q) < 0); otherwise it has slid off the
                # feature into free space (a node pulled over a box's edge) and is free. (Past a
                # face's curvature it is always projected back: a face keeps its nodes.)
                dot = 0.0
                for a in range(3):
                    if not fixed[k, a]:
                        dot += F0[k, a] * (p[a] - q[a])
                if dot > 0.0:
                    hit = False
                    c = False
            if hit or sd < 0.0:
                for a in range(3):
                    if not fixed[k, a]:
                        p[a] = q[a] + gap * q[3 + a]
                c = True
                if (margs[0][0] == MOLD_MESH or (on_foot and foot_trusted)) and not fixed[k, 0] and \
                        not fixed[k, 1] and not fixed[k, 2]:
                    # the closest point of a triangle mesh is on the mesh, and a converged foot
                    # point of the smooth surface is on it to its 1e-13 m tolerance (far below
                    # PENETRATION_TOL): no query needed to know that it is not inside
                    sd = 0.0
                    if use_qt:
                        if gap == 0.0:
                            # at the foot point: itself, the same normal, distance 0
                            Qt[k, 8] = 0.0
                        else:
                            Qt[k, 10] = 0.0
                else:
                    if use_qt:
                        Qt[k, 10] = 0.0
                    sd = query_at(prim, kind, prm, margs, p, q)
                    # a node with constrained axes moved onto the foot point along its free axes
                    # only is still inside where the surface curves (by about its constrained
                    # offset times the curvature): the line search then rejects any step longer
                    # than the curvature allows, and the run creeps (the stocking's held column on
                    # the smooth leg: alpha = 0.25 for 400 iterations). Newton along the normal's
                    # free part n_f: p -= sd n_f / |n_f|^2 puts it on the surface to first order;
                    # started only for a node inside, repeated while it is off the surface
                    for t in range(proj_steps if (proj_everywhere or margs[0][0] == MOLD_SMOOTH) else 0):
                        if not (sd < 0.0 or (t > 0 and sd > proj_tol)):
                            break
                        nf2 = 0.0
                        for a in range(3):
                            if not fixed[k, a]:
                                nf2 += q[3 + a] * q[3 + a]
                        if not (nf2 > 1e-12):
                            break
                        for a in range(3):
                            if not fixed[k, a]:
                                p[a] -= sd * q[3 + a] / nf2
                        sd = query_at(prim, kind, prm, margs, p, q)
            sdk = sd
            if -sd > worst:
                worst = -sd
            if traced:
                for a in range(3):
                    memo[k, 2 + a] = p[a]
                memo[k, 5] = sd
        elif reuse:
            # not moved, or a free node that cannot reach the mold: as in the earlier pass
            continue
        out[k, 0] = p[0]
        out[k, 1] = p[1]
        out[k, 2] = p[2]
        contact_out[k] = c
        sd_out[k] = sdk
    return worst
