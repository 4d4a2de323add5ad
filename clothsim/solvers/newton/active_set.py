"""The active set of the Newton step: per-node projectors onto the directions a node may move in
(fixed axes, mold faces it presses on, the face a node slides down a ridge), blocking constraints
for steps that would leave an edge's or vertex's tangent cone, and the contact's curvature terms.
The line search's trial positions are in :mod:`.trial` (re-exported here).

Shapes: n nodes; positions/forces (n, 3) [m]/[N]; projectors Pi (n, 3, 3) (dimensionless);
flat step vectors (3n,) [m].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...contact import MAX_FEATURE_NORMALS, cone_active, cone_distance, free_axis_normals
from ...mold import MOLD_MESH, MOLD_SMOOTH, mold_query, smooth_shape_operator
from ...mold.queries import contact_normals_at, is_primitive, primitive_query, query_at
from ...mold.smooth import _smooth_query_flag
from ..tuning import NewtonTuning
from .trial import _NO_MEMO, _NO_QT, _face_exit, _trial_positions, _trial_positions_sd  # noqa: F401  (re-exported)

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
