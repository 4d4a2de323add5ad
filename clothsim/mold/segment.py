"""Segment hits: where a straight move p0 -> p1 first enters the mold (``@njit(cache=True)``
pure functions of the mold's kernel arguments ``margs``). Solvers use it to stop a node at the
surface instead of letting a step tunnel through a thin part of the mold.

Reference: T. Moller & B. Trumbore (1997), "Fast, minimum storage ray-triangle intersection",
Journal of Graphics Tools 2(1).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .closest import _mesh_query
from .leg import leg_segment_hit
from .record import MOLD_CYLINDER, MOLD_LEG, MOLD_MESH, MOLD_PLANE, MOLD_SMOOTH, MOLD_SPHERE
from .smooth import _smooth_query_flag

_BARY_EPS = 1e-9      # barycentric slack of a ray hit; hits closer to an edge are confirmed by a probe
_T_EPS = 1e-10        # segment-parameter slack at t = 0 and t = 1
_PROBE_REL = 1e-8     # probe step for edge/vertex hits, relative to the mesh bounding-box diagonal


@njit(cache=True)
def _interval_hit(lo, hi):
    """Entry parameter of the open inside-interval (lo, hi) if it starts within [0, 1], else -1."""
    if not (hi - lo > 1e-12):
        return -1.0
    if lo < -_T_EPS or lo > 1.0 + _T_EPS:
        return -1.0
    return min(max(lo, 0.0), 1.0)


@njit(cache=True)
def _quadratic_interval(A, B, C):
    """Open interval where A t^2 + B t + C < 0 (A > 0); (1, 0) if empty (or tangent)."""
    disc = B * B - 4.0 * A * C
    if not (disc > 1e-14 * (B * B + abs(4.0 * A * C))):
        return 1.0, 0.0
    sq = math.sqrt(disc)
    q = -0.5 * (B - sq) if B < 0.0 else -0.5 * (B + sq)
    t1 = q / A
    t2 = C / q if q != 0.0 else -t1
    if t1 > t2:
        t1, t2 = t2, t1
    return t1, t2


@njit(cache=True)
def _slab(p0, d, lo, hi, tlo, thi, closed=False):
    """Clip the running interval (tlo, thi) by the open slab lo < p0 + t d < hi (closed: with
    the bounds, lo <= p0 + t d <= hi, the BVH box test)."""
    if d == 0.0:
        if (lo <= p0 <= hi) if closed else (lo < p0 < hi):
            return tlo, thi
        return 1.0, 0.0
    a = (lo - p0) / d
    b = (hi - p0) / d
    if a > b:
        a, b = b, a
    return max(tlo, a), min(thi, b)


@njit(cache=True)
def _mesh_segment_hit(margs, p0, p1):
    V = margs.vertices
    F = margs.faces
    FN = margs.face_normals
    bmin = margs.bvh_min
    bmax = margs.bvh_max
    child = margs.bvh_child
    rng = margs.bvh_range
    order = margs.bvh_faces
    dx = p1[0] - p0[0]
    dy = p1[1] - p0[1]
    dz = p1[2] - p0[2]
    dd = dx * dx + dy * dy + dz * dz
    if dd == 0.0 or bmin.shape[0] == 0:
        return -1.0
    dl = math.sqrt(dd)
    probe = _PROBE_REL * margs.params[15]
    best = 2.0
    qout = np.empty(8)
    q = np.empty(3)
    stack = np.empty(128, dtype=np.int64)
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack[sp]
        tlo = -_T_EPS
        thi = min(best, 1.0) + _T_EPS
        for k in range(3):
            tlo, thi = _slab(p0[k], (dx, dy, dz)[k], bmin[n, k], bmax[n, k], tlo, thi, True)
        if tlo > thi:
            continue
        if child[n, 0] >= 0:
            if sp + 2 > stack.shape[0]:
                bigger = np.empty(stack.shape[0] * 2, dtype=np.int64)
                bigger[:sp] = stack[:sp]
                stack = bigger
            stack[sp] = child[n, 0]
            stack[sp + 1] = child[n, 1]
            sp += 2
            continue
        start = rng[n, 0]
        for kk in range(start, start + rng[n, 1]):
            f = order[kk]
            ia = F[f, 0]
            ib = F[f, 1]
            ic = F[f, 2]
            e1x = V[ib, 0] - V[ia, 0]
            e1y = V[ib, 1] - V[ia, 1]
            e1z = V[ib, 2] - V[ia, 2]
            e2x = V[ic, 0] - V[ia, 0]
            e2y = V[ic, 1] - V[ia, 1]
            e2z = V[ic, 2] - V[ia, 2]
            # entering means d . n < 0; with n ~ e1 x e2 this is det = e1 . (d x e2) > 0
            pvx = dy * e2z - dz * e2y
            pvy = dz * e2x - dx * e2z
            pvz = dx * e2y - dy * e2x
            det = e1x * pvx + e1y * pvy + e1z * pvz
            e11 = e1x * e1x + e1y * e1y + e1z * e1z
            e22 = e2x * e2x + e2y * e2y + e2z * e2z
            if not (det * det > 1e-24 * e11 * e22 * dd) or det <= 0.0:
                continue
            if FN[f, 0] * dx + FN[f, 1] * dy + FN[f, 2] * dz >= 0.0:
                continue
            inv = 1.0 / det
            tx = p0[0] - V[ia, 0]
            ty = p0[1] - V[ia, 1]
            tz = p0[2] - V[ia, 2]
            u = (tx * pvx + ty * pvy + tz * pvz) * inv
            if u < -_BARY_EPS or u > 1.0 + _BARY_EPS:
                continue
            qx = ty * e1z - tz * e1y
            qy = tz * e1x - tx * e1z
            qz = tx * e1y - ty * e1x
            v = (dx * qx + dy * qy + dz * qz) * inv
            if v < -_BARY_EPS or u + v > 1.0 + _BARY_EPS:
                continue
            t = (e2x * qx + e2y * qy + e2z * qz) * inv
            if t < -_T_EPS or t > 1.0 + _T_EPS or t >= best:
                continue
            t = min(max(t, 0.0), 1.0)
            if u < _BARY_EPS or v < _BARY_EPS or u + v > 1.0 - _BARY_EPS:
                # on (or within rounding of) an edge or vertex: the segment may only graze the
                # surface there; confirm that just past the hit point it is inside
                q[0] = p0[0] + t * dx + probe * dx / dl
                q[1] = p0[1] + t * dy + probe * dy / dl
                q[2] = p0[2] + t * dz + probe * dz / dl
                if not (_mesh_query(margs, q[0], q[1], q[2], qout) < 0.0):
                    continue
            best = t
    return best if best <= 1.0 else -1.0


_HIT_TOL = 1e-12      # [m] a smooth-surface hit point lies within this of the surface
_TRACE_STEPS = 64


@njit(cache=True)
def _smooth_sd(margs, p0, dx, dy, dz, t, out):
    """Signed distance [m] to the smooth surface at p0 + t d and a step [m] along the segment
    that does not reach it: the distance itself, or where the query fell back to the facets
    (far from the mesh, where the offset between the two surfaces is well below a tenth of the
    smoothing radius; thin features, where the facets are the surface) the faceted distance less
    that margin, at least half of it; out[3:6] the normal."""
    sd, smooth = _smooth_query_flag(margs, p0[0] + t * dx, p0[1] + t * dy, p0[2] + t * dz, out)
    safe = abs(sd)
    if not smooth:
        safe = max(safe - 0.1 * margs.params[14], 0.5 * safe)
    return sd, safe


@njit(cache=True)
def _smooth_bracket(margs, p0, dx, dy, dz, ta, fa, tb, fb, out):
    """First crossing in [ta, tb] (fa > 0 > fb): regula falsi (Illinois) safeguarded by
    bisection, until the point is within _HIT_TOL of the surface; returns its parameter (on the
    outer side when the bracket collapses first)."""
    side = 0
    for _ in range(200):
        if tb - ta <= 1e-17:
            break
        t = (ta * fb - tb * fa) / (fb - fa)
        if not (ta < t < tb):
            t = 0.5 * (ta + tb)
        f, _ = _smooth_sd(margs, p0, dx, dy, dz, t, out)
        if abs(f) <= _HIT_TOL:
            return t
        if f > 0.0:
            ta = t
            fa = f
            if side == 1:
                fb *= 0.5
            side = 1
        else:
            tb = t
            fb = f
            if side == -1:
                fa *= 0.5
            side = -1
    return ta


@njit(cache=True, inline="always")
def _segment(p0, p1):
    """The segment p0 -> p1 ((3,) [m] each): its vector's components and its length [m]."""
    dx = p1[0] - p0[0]
    dy = p1[1] - p0[1]
    dz = p1[2] - p0[2]
    return dx, dy, dz, math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def _smooth_segment_hit(margs, p0, p1):
    """mold_segment_hit on the smooth surface: sphere tracing with the signed distance (a
    distance never overshoots the first crossing) from t = 0, each step tried first with a Newton
    step on the distance along the segment (a point inside brackets a crossing); if it stalls (a segment grazing the
    surface), a point inside is sought at t = 1, at the faceted hit and at the minimum of the
    distance along the segment (where its derivative n . d changes sign), and the first crossing
    before it is bracketed and refined to 1e-12 m."""
    dx, dy, dz, L = _segment(p0, p1)
    if L == 0.0:
        return -1.0
    out = np.empty(8)
    f, safe = _smooth_sd(margs, p0, dx, dy, dz, 0.0, out)
    return _smooth_trace(margs, p0, p1, f, safe, out)


@njit(cache=True)
def smooth_segment_hit_from(margs, p0, p1, q0, sd0, smooth0):
    """``mold_segment_hit`` on the smooth surface with the query at p0 already made: p0, p1 (3,)
    [m] the segment's ends; q0 (>= 8,) its answer (``_smooth_query_flag`` at p0), sd0 [m] its
    signed distance, smooth0 its flag (False: the faceted answer). Returns the share t in [0, 1]
    of the segment where it first enters the surface, or -1.0 when it does not. The same steps
    as without q0, so the same bits, one query fewer."""
    dx, dy, dz, L = _segment(p0, p1)
    if L == 0.0:
        return -1.0
    out = np.empty(8)
    for a in range(8):
        out[a] = q0[a]
    safe = abs(sd0)
    if not smooth0:
        safe = max(safe - 0.1 * margs.params[14], 0.5 * safe)
    return _smooth_trace(margs, p0, p1, sd0, safe, out)


@njit(cache=True)
def _smooth_trace(margs, p0, p1, f, safe, out):
    """The body of ``_smooth_segment_hit`` after the query at t = 0 (f, safe: its
    ``_smooth_sd``; out: its answer)."""
    dx = p1[0] - p0[0]
    dy = p1[1] - p0[1]
    dz = p1[2] - p0[2]
    L = math.sqrt(dx * dx + dy * dy + dz * dz)
    t = 0.0
    steps = _TRACE_STEPS
    if abs(f) <= _HIT_TOL:
        if out[3] * dx + out[4] * dy + out[5] * dz < 0.0:
            return 0.0
        steps = 0  # starts on the surface moving off it: straight to the search for a re-entry
    was_outside = f > _HIT_TOL
    if steps > 0 and f > _HIT_TOL:
        # both ends outside and farther from the surface, together, than the segment is long:
        # no point of it can reach the surface (the distance is 1-Lipschitz)
        n0 = out[3]
        n1 = out[4]
        n2 = out[5]
        f1, safe1 = _smooth_sd(margs, p0, dx, dy, dz, 1.0, out)
        if f1 > _HIT_TOL and safe + safe1 > L:
            return -1.0
        out[3] = n0
        out[4] = n1
        out[5] = n2
    for _ in range(steps):
        if abs(f) <= _HIT_TOL and was_outside and t > 0.0:
            return t
        if f > _HIT_TOL:
            was_outside = True
            # Newton on the distance along the segment (its derivative is n . d): a point found
            # inside brackets the crossing; the distance is unchanged by the trial otherwise
            fd = out[3] * dx + out[4] * dy + out[5] * dz
            if fd < 0.0:
                tn = t - f / fd
                if tn <= 1.0:
                    fn, _ = _smooth_sd(margs, p0, dx, dy, dz, tn, out)
                    if abs(fn) <= _HIT_TOL:
                        return tn
                    if fn < 0.0:
                        return _smooth_bracket(margs, p0, dx, dy, dz, t, f, tn, fn, out)
        t += max(safe, _HIT_TOL) / L
        if t >= 1.0:
            return -1.0
        fa = f
        f, safe = _smooth_sd(margs, p0, dx, dy, dz, t, out)
        if f < -_HIT_TOL and fa > _HIT_TOL:
            # cannot happen for an exact distance (the step was at most the distance)
            return _smooth_bracket(margs, p0, dx, dy, dz, t - max(fa, _HIT_TOL) / L, fa, t, f, out)
    # stalled: look for a point inside beyond t
    if not (f > -_HIT_TOL):
        # stalled inside or on the surface (a long walk out of a deep start): no entry found
        return -1.0
    ta = t
    fa = f
    f1, _ = _smooth_sd(margs, p0, dx, dy, dz, 1.0, out)
    if f1 < 0.0:
        return _smooth_bracket(margs, p0, dx, dy, dz, ta, fa, 1.0, f1, out)
    tf = _mesh_segment_hit(margs, p0, p1)
    if tf > ta:
        ff, _ = _smooth_sd(margs, p0, dx, dy, dz, tf, out)
        if ff < 0.0:
            return _smooth_bracket(margs, p0, dx, dy, dz, ta, fa, tf, ff, out)
    # the minimum of the distance along [ta, 1]: bisection on the sign of its derivative n . d
    f, _ = _smooth_sd(margs, p0, dx, dy, dz, ta, out)
    if out[3] * dx + out[4] * dy + out[5] * dz >= 0.0:
        return -1.0
    lo = ta
    hi = 1.0
    for _ in range(60):
        tm = 0.5 * (lo + hi)
        fm, _ = _smooth_sd(margs, p0, dx, dy, dz, tm, out)
        if fm < 0.0:
            return _smooth_bracket(margs, p0, dx, dy, dz, ta, fa, tm, fm, out)
        if out[3] * dx + out[4] * dy + out[5] * dz < 0.0:
            lo = tm
        else:
            hi = tm
        if (hi - lo) * L <= _HIT_TOL:
            break
    return -1.0


@njit(cache=True)
def mold_segment_hit(margs, p0, p1):
    """Smallest t in [0, 1] where p0 + t (p1 - p0) crosses the surface from outside to inside.

    Returns -1.0 if the segment does not enter the mold. A segment that starts on the surface
    and moves inward returns 0.0; one that only touches the surface (tangent, grazing a convex
    edge or vertex, sliding within a face) returns -1.0. The start point's own state is not a
    crossing: a segment starting strictly inside reports only a later re-entry (callers should
    project penetrating nodes first). Mesh: BVH + Moller-Trumbore on faces whose normal opposes
    the motion; hits within 1e-9 (barycentric) of an edge or vertex are confirmed by probing the
    signed distance 1e-8 x (bounding-box diagonal) beyond the hit. Smooth mesh: the first
    crossing of its smooth surface, within 1e-12 m of it (see ``_smooth_segment_hit``).
    Primitives: analytic.
    """
    kind = margs.info[0]
    if kind == MOLD_MESH:
        return _mesh_segment_hit(margs, p0, p1)
    if kind == MOLD_SMOOTH:
        return _smooth_segment_hit(margs, p0, p1)
    return primitive_segment_hit(kind, margs.params, p0, p1)


@njit(cache=True)
def primitive_segment_hit(kind, prm, p0, p1):
    """:func:`mold_segment_hit` on an analytic mold (``queries.is_primitive``; prm: margs.params),
    from (kind, prm) alone: p0, p1 (3,) [m] the segment's ends; returns the share t in [0, 1]
    where it first enters the mold, or -1.0."""
    dx = p1[0] - p0[0]
    dy = p1[1] - p0[1]
    dz = p1[2] - p0[2]
    if dx == 0.0 and dy == 0.0 and dz == 0.0:
        return -1.0
    if kind == MOLD_LEG:
        return leg_segment_hit(prm, p0, p1)
    if kind == MOLD_PLANE:
        nx, ny, nz = prm[3], prm[4], prm[5]
        s0 = (p0[0] - prm[0]) * nx + (p0[1] - prm[1]) * ny + (p0[2] - prm[2]) * nz
        dn = dx * nx + dy * ny + dz * nz
        if not (dn < 0.0):
            return -1.0
        t = -s0 / dn
        if t < -_T_EPS or t > 1.0 + _T_EPS:
            return -1.0
        return min(max(t, 0.0), 1.0)
    if kind == MOLD_SPHERE:
        wx = p0[0] - prm[0]
        wy = p0[1] - prm[1]
        wz = p0[2] - prm[2]
        A = dx * dx + dy * dy + dz * dz
        B = 2.0 * (dx * wx + dy * wy + dz * wz)
        C = wx * wx + wy * wy + wz * wz - prm[3] * prm[3]
        lo, hi = _quadratic_interval(A, B, C)
        return _interval_hit(lo, hi)
    if kind == MOLD_CYLINDER:
        ax, ay, az = prm[3], prm[4], prm[5]
        wx = p0[0] - prm[0]
        wy = p0[1] - prm[1]
        wz = p0[2] - prm[2]
        da = dx * ax + dy * ay + dz * az
        wa = wx * ax + wy * ay + wz * az
        dpx = dx - da * ax
        dpy = dy - da * ay
        dpz = dz - da * az
        wpx = wx - wa * ax
        wpy = wy - wa * ay
        wpz = wz - wa * az
        A = dpx * dpx + dpy * dpy + dpz * dpz
        C = wpx * wpx + wpy * wpy + wpz * wpz - prm[6] * prm[6]
        if A <= 1e-30 * (dx * dx + dy * dy + dz * dz):
            if C < 0.0:
                lo, hi = -np.inf, np.inf
            else:
                return -1.0
        else:
            B = 2.0 * (dpx * wpx + dpy * wpy + dpz * wpz)
            lo, hi = _quadratic_interval(A, B, C)
        h = 0.5 * prm[7]
        lo, hi = _slab(wa, da, -h, h, lo, hi)
        return _interval_hit(lo, hi)
    # box
    lo = -np.inf
    hi = np.inf
    lo, hi = _slab(p0[0], dx, prm[0], prm[3], lo, hi)
    lo, hi = _slab(p0[1], dy, prm[1], prm[4], lo, hi)
    lo, hi = _slab(p0[2], dz, prm[2], prm[5], lo, hi)
    return _interval_hit(lo, hi)
