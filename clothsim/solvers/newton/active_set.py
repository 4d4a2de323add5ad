"""The active set of the Newton step: per-node projectors onto the directions a node may move in
(fixed axes, mold faces it presses on, the face a node slides down a ridge), blocking constraints
for steps that would leave an edge's or vertex's tangent cone, and the trial positions of the line
search (free nodes stopped at the mold surface, contact nodes projected back onto it).

Shapes: n nodes; positions/forces (n, 3) [m]/[N]; projectors Pi (n, 3, 3) (dimensionless);
flat step vectors (3n,) [m].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...contact import MAX_FEATURE_NORMALS, cone_active, cone_distance, cut_move, free_axis_normals, stop_at_surface
from ...mold import MOLD_MESH, MOLD_SMOOTH, mold_query, smooth_shape_operator
from ...mold.queries import contact_normals_at, is_primitive, primitive_query, query_at
from ...mold.segment import primitive_segment_hit, smooth_segment_hit_from
from ...mold.smooth import _smooth_query_flag
from ..tuning import NewtonTuning

# after a projection onto the mold, a node may be inside by at most this [m]
PENETRATION_TOL = 1e-10
# The contact rules' switches (release_gap, smooth_foot_trusted, fixed_projection_*, held_keep_gap,
# held_gap_min) are fields of ``tuning.NewtonTuning``; the kernels read them as plain values from
# the array ``contact_rules(tuning)`` makes.


def contact_rules(tuning: NewtonTuning = NewtonTuning()) -> np.ndarray:
    """(7,) float64: the tuning's contact-rule values as the kernels read them: held_keep_gap (1/0),
    held_gap_min [m], release_gap [m], smooth_foot_trusted (1/0), fixed_projection_steps,
    fixed_projection_everywhere (1/0), fixed_projection_tol [m]."""
    t = tuning
    return np.array([1.0 if t.held_keep_gap else 0.0, t.held_gap_min, t.release_gap,
                     1.0 if t.smooth_foot_trusted else 0.0, float(t.fixed_projection_steps),
                     1.0 if t.fixed_projection_everywhere else 0.0, t.fixed_projection_tol])


# the default tuning's rules (tests and tools that call a kernel by hand)
RULES = contact_rules()


@njit(cache=True)
def _ridge_face(x, R, normals, m, margs, probe, act, na):
    """A node pressed onto a convex edge or vertex (its resultant inside the cone of several face
    normals) satisfies eq. 6 but is not at a minimum of the energy: sliding down one of the
    faces lowers it (the springs cut the corner). Among the faces it presses on (R.n_i < 0), the
    one whose tangential pull R - (R.n_i) n_i is largest (ties to the first) and leads along the surface (a probe
    point a short way along it is not inside the mold: not a groove) becomes the only active
    constraint (act[0] = i, returns 1). Otherwise (groove, or no such face) returns na."""
    p = np.empty(3)
    q = np.empty(8)
    best = 0.0
    ib = -1
    for i in range(m):
        rn = R[0] * normals[i, 0] + R[1] * normals[i, 1] + R[2] * normals[i, 2]
        if not (rn < 0.0):
            continue
        t0 = R[0] - rn * normals[i, 0]
        t1 = R[1] - rn * normals[i, 1]
        t2 = R[2] - rn * normals[i, 2]
        tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        # near-ties (a node exactly on a symmetric peak) go to the first face in the feature's
        # order, so that rounding (a mold in other units) cannot pick a different equilibrium
        if not (tn > best * (1.0 + 1e-6)):
            continue
        p[0] = x[0] + probe * t0 / tn
        p[1] = x[1] + probe * t1 / tn
        p[2] = x[2] + probe * t2 / tn
        sd = mold_query(margs, p, q)
        if sd < -1e-3 * probe:
            continue
        best = tn
        ib = i
    if ib < 0:
        return na
    act[0] = ib
    return 1


@njit(cache=True)
def _query_nodes(pos, has_mold, margs, Q):
    """Q (n, 9): every node's ``mold_query`` answer at pos (n,3) [m] in Q[k, 0:8] and its signed
    distance [m] in Q[k, 8] (inf without a mold): one call for the whole sheet, read by the
    ``*_q`` kernels instead of querying the same points again. With a tenth column, Q[k, 9] is 1
    where the answer is the smooth surface's own (``_smooth_query_flag``; 0 where it fell back to
    the facets; 1 on other molds), read by the line search's segment hits
    (``_trial_positions_sd``)."""
    smooth = has_mold and margs[0][0] == MOLD_SMOOTH
    flag = Q.shape[1] > 9
    kind = margs.info[0]
    if has_mold and is_primitive(kind):
        # (a loop of its own: see queries.is_primitive)
        prm = margs.params
        for k in range(pos.shape[0]):
            Q[k, 8] = primitive_query(kind, prm, pos[k, 0], pos[k, 1], pos[k, 2], Q[k])
            if flag:
                Q[k, 9] = 1.0
        return
    for k in range(pos.shape[0]):
        if smooth:
            sd, ok = _smooth_query_flag(margs, pos[k, 0], pos[k, 1], pos[k, 2], Q[k])
            Q[k, 8] = sd
            if flag:
                Q[k, 9] = 1.0 if ok else 0.0
        elif has_mold:
            Q[k, 8] = mold_query(margs, pos[k], Q[k])
            if flag:
                Q[k, 9] = 1.0
        else:
            Q[k, 8] = np.inf
            if flag:
                Q[k, 9] = 1.0


@njit(cache=True)
def _complete_queries(pos, Qt, q_pos, has_mold, margs, Q):
    """Q (n, 10) for the positions pos (n,3) [m] (``_query_nodes``' answers) from what is known:
    a node's row of Qt (n, 11) where Qt[k, 10] = 1 (the trial pass's answers at pos,
    ``_trial_positions_sd``), its row of Q where it has not moved from q_pos (n,3) [m] (the
    positions Q was queried at, bit for bit), and a query otherwise. Returns how many nodes were
    queried."""
    count = 0
    for k in range(pos.shape[0]):
        if Qt[k, 10] != 0.0:
            for a in range(10):
                Q[k, a] = Qt[k, a]
        elif not (pos[k, 0] == q_pos[k, 0] and pos[k, 1] == q_pos[k, 1] and pos[k, 2] == q_pos[k, 2]):
            _query_nodes(pos[k:k + 1], has_mold, margs, Q[k:k + 1])
            count += 1
    return count


@njit(cache=True)
def _residual_q(F, fixed, in_contact, has_mold, margs, Q, V):
    """``contact.residual_from_forces`` (the same arithmetic) with the mold's answers at the nodes
    read from Q (``_query_nodes``) instead of queried: V (n,) filled with eq. (6)'s entries,
    returns ||V||_inf [N] (nan if any entry is not finite)."""
    R = np.empty(3)
    nbuf = np.empty((MAX_FEATURE_NORMALS, 3))
    vmax = 0.0
    kind = margs.info[0]
    prim = is_primitive(kind)
    prm = margs.params
    for k in range(F.shape[0]):
        r0 = 0.0 if fixed[k, 0] else F[k, 0]
        r1 = 0.0 if fixed[k, 1] else F[k, 1]
        r2 = 0.0 if fixed[k, 2] else F[k, 2]
        if in_contact[k] and has_mold:
            R[0] = r0
            R[1] = r1
            R[2] = r2
            m = contact_normals_at(prim, kind, prm, margs, Q[k], nbuf)
            free_axis_normals(fixed[k], nbuf, m)
            v = cone_distance(R, nbuf, m)
        else:
            v = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        V[k] = v
        if not (v <= vmax):
            if math.isnan(v):
                return math.nan
            vmax = v
    return vmax


@njit(cache=True)
def _projectors(pos, F, fixed, in_contact, has_mold, margs, Pi, probe=0.0):
    """Active set and per-node projectors Pi (n,3,3) onto the allowed directions.

    Releases contact nodes whose resultant points out of the mold (in_contact updated in place).
    With ``probe`` > 0 [m], a node pressed onto a convex edge or vertex keeps only the face it
    slides down (``_ridge_face``). Returns the number of released nodes."""
    Q = np.empty((pos.shape[0], 9))
    _query_nodes(pos, has_mold, margs, Q)
    return _projectors_q(pos, F, fixed, in_contact, has_mold, margs, Pi, probe, Q)


@njit(cache=True, inline="always")
def held_axis_rows(fixed, k, Q):
    """Node k's held axes (fixed (n, 3) bool) as unit rows at the front of Q (m >= 3, 3), in axis
    order; returns how many."""
    nq = 0
    for a in range(3):
        if fixed[k, a]:
            Q[nq, 0] = 0.0
            Q[nq, 1] = 0.0
            Q[nq, 2] = 0.0
            Q[nq, a] = 1.0
            nq += 1
    return nq


@njit(cache=True, inline="always")
def orthonormal_rows(Q, nq):
    """Gram-Schmidt on the first nq rows of Q (m, 3) in place: the rows that are independent (a
    remainder of norm 1e-6 or more) become orthonormal and move to the front; returns how many
    (at most 3)."""
    kept = 0
    for t in range(nq):
        v0, v1, v2 = Q[t, 0], Q[t, 1], Q[t, 2]
        for u in range(kept):
            d = v0 * Q[u, 0] + v1 * Q[u, 1] + v2 * Q[u, 2]
            v0 -= d * Q[u, 0]
            v1 -= d * Q[u, 1]
            v2 -= d * Q[u, 2]
        nv = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        if nv < 1e-6:
            continue
        Q[kept, 0] = v0 / nv
        Q[kept, 1] = v1 / nv
        Q[kept, 2] = v2 / nv
        kept += 1
        if kept == 3:
            break
    return kept


@njit(cache=True)
def _projectors_q(pos, F, fixed, in_contact, has_mold, margs, Pi, probe, QA):
    """``_projectors`` with the mold's answers at the nodes read from QA (n, 9) (``_query_nodes``)."""
    nbuf = np.empty((MAX_FEATURE_NORMALS, 3))
    act = np.empty(3, np.int64)
    R = np.empty(3)
    Q = np.empty((6, 3))
    released = 0
    kind = margs.info[0]
    prim = is_primitive(kind)
    prm = margs.params
    for k in range(pos.shape[0]):
        nq = held_axis_rows(fixed, k, Q)
        if in_contact[k] and has_mold and nq < 3:
            for a in range(3):
                R[a] = 0.0 if fixed[k, a] else F[k, a]
            m = contact_normals_at(prim, kind, prm, margs, QA[k], nbuf)
            free_axis_normals(fixed[k], nbuf, m)
            na = cone_active(R, nbuf, m, act)
            if na >= 2 and QA[k, 6] != 0.0 and probe > 0.0:
                na = _ridge_face(pos[k], R, nbuf, m, margs, probe, act, na)
            if na == 0:
                in_contact[k] = False
                released += 1
            else:
                for t in range(na):
                    Q[nq, 0] = nbuf[act[t], 0]
                    Q[nq, 1] = nbuf[act[t], 1]
                    Q[nq, 2] = nbuf[act[t], 2]
                    nq += 1
        # Gram-Schmidt on the constraint directions; Pi = I - sum q q^T
        for r in range(3):
            for c in range(3):
                Pi[k, r, c] = 1.0 if r == c else 0.0
        kept = orthonormal_rows(Q, nq)
        for u in range(kept):
            for r in range(3):
                for c in range(3):
                    Pi[k, r, c] -= Q[u, r] * Q[u, c]
    return released


@njit(cache=True, inline="always")
def _remove_direction(Pi, k, n0, n1, n2, min_norm):
    """Constrains node k along the unit vector Pi_k n / |Pi_k n| (Pi (n,3,3) updated in place:
    Pi_k -= a a^T); returns False, leaving Pi unchanged, when |Pi_k n| < min_norm (n already
    blocked)."""
    a0 = Pi[k, 0, 0] * n0 + Pi[k, 0, 1] * n1 + Pi[k, 0, 2] * n2
    a1 = Pi[k, 1, 0] * n0 + Pi[k, 1, 1] * n1 + Pi[k, 1, 2] * n2
    a2 = Pi[k, 2, 0] * n0 + Pi[k, 2, 1] * n1 + Pi[k, 2, 2] * n2
    an = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if an < min_norm:
        return False
    a0 /= an
    a1 /= an
    a2 /= an
    Pi[k, 0, 0] -= a0 * a0
    Pi[k, 0, 1] -= a0 * a1
    Pi[k, 0, 2] -= a0 * a2
    Pi[k, 1, 0] -= a1 * a0
    Pi[k, 1, 1] -= a1 * a1
    Pi[k, 1, 2] -= a1 * a2
    Pi[k, 2, 0] -= a2 * a0
    Pi[k, 2, 1] -= a2 * a1
    Pi[k, 2, 2] -= a2 * a2
    return True


@njit(cache=True)
def _block_infeasible(pos, dx, contact, has_mold, margs, probe, Pi):
    """``_block_infeasible_q`` querying the nodes itself."""
    if not has_mold or margs[0][0] == MOLD_SMOOTH:
        return 0
    Q = np.empty((pos.shape[0], 9))
    _query_nodes(pos, has_mold, margs, Q)
    return _block_infeasible_q(pos, dx, contact, has_mold, margs, probe, Pi, Q)


@njit(cache=True)
def _block_infeasible_q(pos, dx, contact, has_mold, margs, probe, Pi, Q):
    """Blocking constraints at edges and vertices. The active set (``_projectors``) keeps the
    normals that carry a positive multiplier; the Newton step of a node on an edge or vertex can
    still leave the feature's tangent cone through another face (in a groove: into the face
    beside the active one), and the projection back onto the surface then bends the path at
    first order, so no step length lowers the energy. A node whose step direction enters the
    mold within ``probe`` [m] gets the face normal it violates most added to its constraints
    (Pi updated in place). Returns how many nodes were blocked. On the smooth surface of a mesh
    every answer is a face (code 0, one normal): nothing to block, no query. Q (n, 9): the mold's
    answers at pos (``_query_nodes``)."""
    if not has_mold or margs[0][0] == MOLD_SMOOTH:
        return 0
    q = np.empty(8)
    p = np.empty(3)
    nbuf = np.empty((MAX_FEATURE_NORMALS, 3))
    blocked = 0
    kind = margs.info[0]
    prim = is_primitive(kind)
    prm = margs.params
    for k in range(pos.shape[0]):
        if not contact[k]:
            continue
        d0 = dx[3 * k]
        d1 = dx[3 * k + 1]
        d2 = dx[3 * k + 2]
        dn = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if dn == 0.0:
            continue
        if Q[k, 6] == 0.0:
            continue
        p[0] = pos[k, 0] + probe * d0 / dn
        p[1] = pos[k, 1] + probe * d1 / dn
        p[2] = pos[k, 2] + probe * d2 / dn
        sd = query_at(prim, kind, prm, margs, p, q)
        if not (sd < -1e-3 * probe):
            continue
        m = contact_normals_at(prim, kind, prm, margs, Q[k], nbuf)
        best = 0.0
        jb = -1
        for j in range(m):
            # the normal's part in the still-allowed directions
            a0 = Pi[k, 0, 0] * nbuf[j, 0] + Pi[k, 0, 1] * nbuf[j, 1] + Pi[k, 0, 2] * nbuf[j, 2]
            a1 = Pi[k, 1, 0] * nbuf[j, 0] + Pi[k, 1, 1] * nbuf[j, 1] + Pi[k, 1, 2] * nbuf[j, 2]
            a2 = Pi[k, 2, 0] * nbuf[j, 0] + Pi[k, 2, 1] * nbuf[j, 1] + Pi[k, 2, 2] * nbuf[j, 2]
            if math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) < 1e-6:
                continue
            dd = (d0 * nbuf[j, 0] + d1 * nbuf[j, 1] + d2 * nbuf[j, 2]) / dn
            if dd < best:
                best = dd
                jb = j
        if jb < 0:
            continue
        _remove_direction(Pi, k, nbuf[jb, 0], nbuf[jb, 1], nbuf[jb, 2], -1.0)
        blocked += 1
    return blocked


@njit(cache=True)
def _block_entering(pos, dx, contact, sd0, has_mold, margs, Pi, tol, rhs, share):
    """Released nodes whose step enters the mold. ``_projectors`` releases a contact node whose
    resultant points out of the mold, but the Newton step couples it to its neighbours, and the
    step of the whole sheet can still move it into the mold (its neighbours pull it in more than
    its own resultant lifts it). The line search then stops it at the surface for every step
    length: the path bends at first order, the step's predicted decrease is mostly that node's
    (unreachable) move, and no step length lowers the energy enough (the stall on scans). A
    node not in contact that lies on the surface (signed distance sd0 (n,) [m] <= tol [m]) and
    whose step points into the mold (along the query's outward normal, beyond rounding) is put
    back in contact (``contact`` updated in place) with that normal as a constraint (Pi updated
    in place), and the step is solved again (projected Newton: a variable at its bound whose step
    leaves the feasible set is held). This is done only when those nodes' moves carry more than
    ``share`` of the step's predicted energy decrease (rhs (3n,) [N]: the projected forces the
    step was solved for; the decrease is rhs . dx). With share = 1: only when the rest of the
    step, the part the line search can realise, does not lower the energy at first order; with
    share = 0 (the solver's setting, ``NewtonTuning.hold_share``): every entering node, the projected
    Newton rule (otherwise a node whose multiplier is about 0 at the solution churns in and out of
    contact, each entry cutting the step to a sliver).
    Returns how many nodes were put back."""
    if not has_mold:
        return 0
    q = np.empty(8)
    n = pos.shape[0]
    enter = np.zeros(n, np.bool_)
    nrm = np.empty((n, 3))
    total = 0.0
    part = 0.0
    kind = margs.info[0]
    prim = is_primitive(kind)
    prm = margs.params
    for k in range(n):
        dec = rhs[3 * k] * dx[3 * k] + rhs[3 * k + 1] * dx[3 * k + 1] + rhs[3 * k + 2] * dx[3 * k + 2]
        total += dec
        if contact[k] or not (sd0[k] <= tol):
            continue
        d0 = dx[3 * k]
        d1 = dx[3 * k + 1]
        d2 = dx[3 * k + 2]
        dn = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if dn == 0.0:
            continue
        if prim:
            primitive_query(kind, prm, pos[k, 0], pos[k, 1], pos[k, 2], q)
        else:
            mold_query(margs, pos[k], q)
        if not (d0 * q[3] + d1 * q[4] + d2 * q[5] < -1e-6 * dn):
            continue
        enter[k] = True
        nrm[k, 0] = q[3]
        nrm[k, 1] = q[4]
        nrm[k, 2] = q[5]
        part += dec
    if not (total > 0.0 and part > share * total):
        return 0
    held = 0
    for k in range(n):
        if not enter[k]:
            continue
        n0 = nrm[k, 0]
        n1 = nrm[k, 1]
        n2 = nrm[k, 2]
        if not _remove_direction(Pi, k, n0, n1, n2, 1e-6):
            continue
        contact[k] = True
        held += 1
    return held

@njit(cache=True)
def _apply_pi(Pi, v, out):
    for k in range(Pi.shape[0]):
        a0 = v[3 * k]
        a1 = v[3 * k + 1]
        a2 = v[3 * k + 2]
        for r in range(3):
            out[3 * k + r] = Pi[k, r, 0] * a0 + Pi[k, r, 1] * a1 + Pi[k, r, 2] * a2


@njit(cache=True)
def _mold_distances(pos, has_mold, margs, out):
    """Signed distance [m] of every node to the mold (inf without a mold)."""
    q = np.empty(8)
    for k in range(pos.shape[0]):
        out[k] = mold_query(margs, pos[k], q) if has_mold else np.inf


@njit(cache=True)
def _free_distances_q(contact, has_mold, Q, fixed, out, rules):
    """out (n,) [m]: the signed distance to the mold of each node not in contact (the only ones
    whose distance the step reads: ``_trial_positions``, ``_block_entering``), from the mold's
    answers at the nodes in Q (``_query_nodes``); contact nodes get 0 (they are on the surface),
    except a contact node without held axes still farther than held_gap_min off it (a gap kept
    by a step cut short, held_keep_gap; rules: ``contact_rules``): its distance, which the next
    step closes."""
    keep_gap = rules[0] != 0.0
    gap_min = rules[1]
    for k in range(contact.shape[0]):
        if not has_mold:
            out[k] = np.inf
        elif contact[k]:
            if keep_gap and Q[k, 8] > gap_min and not (fixed[k, 0] or fixed[k, 1] or fixed[k, 2]):
                out[k] = Q[k, 8]
            else:
                out[k] = 0.0
        else:
            out[k] = Q[k, 8]


@njit(cache=True)
def _gap_closure(contact, fixed, sd0, Q, g, gap_min):
    """The prescribed part g (3n,) [m] of the Newton step (``NewtonTuning.held_keep_gap``): -sd0 n for
    every contact node without held axes whose signed distance sd0 (n,) [m] exceeds gap_min [m] (n
    the mold's outward normal at the node, Q from ``_query_nodes``), 0 elsewhere. Returns how
    many nodes have a gap to close."""
    count = 0
    for k in range(contact.shape[0]):
        d = sd0[k]
        if contact[k] and d > gap_min and not (fixed[k, 0] or fixed[k, 1] or fixed[k, 2]):
            for a in range(3):
                g[3 * k + a] = -d * Q[k, 3 + a]
            count += 1
        else:
            for a in range(3):
                g[3 * k + a] = 0.0
    return count


@njit(cache=True)
def _contact_faces_q(contact, has_mold, margs, Q, out):
    """out (n,) int64: for a contact node on a mesh mold whose closest feature is a face, that
    face; -1 otherwise (read by ``_trial_positions``' face-border clip), from the mold's answers at
    the nodes in Q (``_query_nodes``)."""
    for k in range(contact.shape[0]):
        out[k] = -1
        if has_mold and contact[k] and margs[0][0] == MOLD_MESH and Q[k, 6] == 0.0:
            out[k] = int(Q[k, 7])


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


@njit(cache=True)
def _curvature_blocks(pos, F, contact, has_mold, margs, h, mode, diag, K):
    """Adds the contact's curvature term to the diagonal Hessian blocks K[diag[k]] (3,3) [N/m] of
    the contact nodes on a smooth surface (``MOLD_SMOOTH``; other molds: nothing).

    A node held on a curved surface and pressed onto it by lam = -F.n [N] (F (n,3) [N] its
    resultant without the contact force, n the outward normal) has, along the surface, the
    energy Hessian K - lam S (S the shape operator, ``smooth_shape_operator``, from differences
    over h [m]): the tangent-plane model alone misses -lam S. mode 1: only its positive
    semi-definite part (the stiffening of concave parts; the Hessian stays positive definite);
    mode 2: all of it. Nodes pulled off (lam <= 0) get nothing. Returns the number of nodes."""
    if not has_mold or margs[0][0] != MOLD_SMOOTH:
        return 0
    M = np.zeros((pos.shape[0], 3, 3))
    count = _curvature_terms(pos, F, contact, has_mold, margs, h, M)
    if count:
        _add_curvature(M, mode, diag, K)
    return count


@njit(cache=True)
def _curvature_terms(pos, F, contact, has_mold, margs, h, M):
    """M (n, 3, 3) [N/m]: -lam S of every contact node on a smooth surface pressed onto it (see
    ``_curvature_blocks``), 0 elsewhere (M must come in as zeros). Returns how many nodes have
    one."""
    if not has_mold or margs[0][0] != MOLD_SMOOTH:
        return 0
    n = np.empty(3)
    S = np.empty((3, 3))
    count = 0
    for k in range(pos.shape[0]):
        if not contact[k]:
            continue
        if not smooth_shape_operator(margs, pos[k, 0], pos[k, 1], pos[k, 2], h, n, S):
            continue
        lam = -(F[k, 0] * n[0] + F[k, 1] * n[1] + F[k, 2] * n[2])
        if not (lam > 0.0):
            continue
        for a in range(3):
            for b in range(3):
                M[k, a, b] = -lam * S[a, b]
        count += 1
    return count


@njit(cache=True)
def _add_curvature(M, mode, diag, K):
    """K[diag[k]] += M[k] (mode 2) or its positive semi-definite part (mode 1) for every node k
    whose M[k] (``_curvature_terms``) is not 0. M (n, 3, 3) [N/m]; diag (n,) the slots of the
    diagonal blocks in K (nb, 3, 3) [N/m], the BSR Hessian's blocks."""
    P = np.empty((3, 3))
    for k in range(M.shape[0]):
        nz = False
        for a in range(3):
            for b in range(3):
                if M[k, a, b] != 0.0:
                    nz = True
        if not nz:
            continue
        for a in range(3):
            for b in range(3):
                P[a, b] = M[k, a, b]
        if mode == 1:
            w, v = np.linalg.eigh(P)
            for a in range(3):
                for b in range(3):
                    x = 0.0
                    for c in range(3):
                        if w[c] > 0.0:
                            x += w[c] * v[a, c] * v[b, c]
                    P[a, b] = x
        d = diag[k]
        for a in range(3):
            for b in range(3):
                K[d, a, b] += P[a, b]
