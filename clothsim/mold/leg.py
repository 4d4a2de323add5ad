"""A limb from a size chart (mold kind ``MOLD_LEG``): a smooth surface through the girths a
chart gives at its measuring levels, with exact closest-point queries (``@njit(cache=True)``
pure functions of the mold's parameter array, like the sphere's and the cylinder's).

The surface. The limb's axis is vertical (clothsim's +z) through ``center`` (x, y); a point of
the surface at height z and polar angle t about the axis lies at radius

    r(z, t) = a_0(z) + sum_{k=1..M} (a_k(z) cos k t + b_k(z) sin k t)

Each level's cross-section (a circle, or an ellipse of the given ``aspect`` with an optional
flatter medial side and a tibial crest, see :func:`section_shape`) is sampled, cut to its first
M harmonics (M = ``harmonics``, default 16), then scaled so that its girth as a tape measures
it (the perimeter of its convex hull: its own perimeter when it is convex) is exactly the
chart's. Each coefficient a_k, b_k is a
natural cubic spline in z through the levels (C2; two levels, or levels on a straight line,
give exactly a straight line: a cone). Beyond the lowest and the highest level each coefficient
goes on as c(z) = c_end + c'_end L tanh((z - z_end) / L) (L = ``extend`` [m], default 0.05): its
value, slope and (zero) curvature match the spline's, so the surface stays C2, and the limb
tends to a fixed section a few L beyond its ends (no caps, no edges). The surface is smooth by
construction: an analytic function of (z, t).

The closest point c of a point p is the minimiser of |p - S(z, t)|^2 over (z, t), found by a
damped Newton iteration on its gradient (exact second derivatives of S), started from p's own
height and polar angle: converged when the step is below 1e-14 m (or the gradient vanishes to
rounding); then p - c is along the normal. The start lies in the basin of the nearest point
for every point closer to the surface than its smallest radius of curvature, which covers
every contact (a 2 cm calf and 5 mm of clearance, say); the inside/outside sign comes from
comparing p's distance from the axis with r(z_p, t_p) (exact for a star-shaped section).

Parameter array (float64), read by the kernels: [0:2] the axis point (x, y) [m]; [2] n, the
number of levels; [3] M; [4] L [m]; [5] the largest radius [m]; [6] the lowest level's z [m];
[7] the highest's; [16:16+n] the levels' z [m]; then per coefficient j = 0..2M (a_0, a_1, b_1,
..., a_M, b_M) n values [m] and n spline second derivatives [1/m].
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

HEADER = 16
#: default number of harmonics of a section
DEFAULT_HARMONICS = 16
#: default length [m] over which the limb tends to a fixed section beyond its end levels
DEFAULT_EXTEND = 0.05
_NEWTON_ITERS = 60
_STEP_TOL = 1e-14   # [m]
_SEG_SAMPLES_PER_M = 500.0   # segment hits: sign samples per metre of segment (every 2 mm)


# --------------------------------------------------------------------------------------------
# numba kernels
# --------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _where(prm, z):
    """Where height z [m] falls: (mode, i, A, B, h, u) with mode 0 between levels i and i + 1
    (A, B the spline's weights, h the interval), -1 below the lowest, +1 above the highest
    (u = (z - z_end) / L)."""
    n = int(prm[2])
    Z = HEADER
    if z <= prm[Z]:
        return -1, 0, 0.0, 0.0, prm[Z + 1] - prm[Z], (z - prm[Z]) / prm[4]
    if z >= prm[Z + n - 1]:
        return 1, n - 2, 0.0, 0.0, prm[Z + n - 1] - prm[Z + n - 2], (z - prm[Z + n - 1]) / prm[4]
    i = 0
    while i < n - 2 and z > prm[Z + i + 1]:
        i += 1
    h = prm[Z + i + 1] - prm[Z + i]
    A = (prm[Z + i + 1] - z) / h
    return 0, i, A, 1.0 - A, h, 0.0


@njit(cache=True, inline="always")
def _coef(prm, j, mode, i, A, B, h, u):
    """Coefficient j's value, first and second derivative in z at the height ``_where`` placed:
    the natural spline between the levels; beyond the end levels c_end + c'_end L tanh(u)."""
    n = int(prm[2])
    base = HEADER + n + 2 * n * j
    y0 = prm[base + i]
    y1 = prm[base + i + 1]
    m0 = prm[base + n + i]
    m1 = prm[base + n + i + 1]
    if mode == 0:
        y = A * y0 + B * y1 + ((A * A * A - A) * m0 + (B * B * B - B) * m1) * h * h / 6.0
        dy = (y1 - y0) / h - (3.0 * A * A - 1.0) * h * m0 / 6.0 + (3.0 * B * B - 1.0) * h * m1 / 6.0
        return y, dy, A * m0 + B * m1
    L = prm[4]
    if mode < 0:
        s = (y1 - y0) / h - h * (2.0 * m0 + m1) / 6.0   # the natural spline's end slope
        ye = y0
    else:
        s = (y1 - y0) / h + h * (m0 + 2.0 * m1) / 6.0
        ye = y1
    th = math.tanh(u)
    sech2 = 1.0 - th * th
    return ye + s * L * th, s * sech2, -2.0 * s * th * sech2 / L


@njit(cache=True)
def leg_radius(prm, z, t):
    """(r, r_z, r_t, r_zz, r_zt, r_tt) of the limb's surface at height z [m], polar angle t
    [rad] (r [m]; derivatives in m and rad)."""
    M = int(prm[3])
    mode, i, A, B, h, u = _where(prm, z)
    r, rz, rzz = _coef(prm, 0, mode, i, A, B, h, u)
    rt = 0.0
    rzt = 0.0
    rtt = 0.0
    c1 = math.cos(t)
    s1 = math.sin(t)
    c = 1.0
    s = 0.0
    for k in range(1, M + 1):
        # cos k t, sin k t by the angle-addition recurrence
        c, s = c * c1 - s * s1, s * c1 + c * s1
        ya, dya, ddya = _coef(prm, 2 * k - 1, mode, i, A, B, h, u)
        yb, dyb, ddyb = _coef(prm, 2 * k, mode, i, A, B, h, u)
        r += ya * c + yb * s
        rz += dya * c + dyb * s
        rzz += ddya * c + ddyb * s
        rt += k * (-ya * s + yb * c)
        rzt += k * (-dya * s + dyb * c)
        rtt -= k * k * (ya * c + yb * s)
    return r, rz, rt, rzz, rzt, rtt


@njit(cache=True)
def leg_r(prm, z, t):
    """r(z, t) [m] alone: :func:`leg_radius`'s first value, the same sums in the same order
    (the same bits), without the derivatives (the line search and the inside test)."""
    M = int(prm[3])
    mode, i, A, B, h, u = _where(prm, z)
    r, _, _ = _coef(prm, 0, mode, i, A, B, h, u)
    c1 = math.cos(t)
    s1 = math.sin(t)
    c = 1.0
    s = 0.0
    for k in range(1, M + 1):
        c, s = c * c1 - s * s1, s * c1 + c * s1
        ya, _, _ = _coef(prm, 2 * k - 1, mode, i, A, B, h, u)
        yb, _, _ = _coef(prm, 2 * k, mode, i, A, B, h, u)
        r += ya * c + yb * s
    return r


@njit(cache=True)
def _frame(prm, z, t):
    """The surface point S, S_z, S_t and the second derivatives at (z, t): 15 numbers."""
    r, rz, rt, rzz, rzt, rtt = leg_radius(prm, z, t)
    c = math.cos(t)
    s = math.sin(t)
    return (prm[0] + r * c, prm[1] + r * s, z,
            rz * c, rz * s,                                  # S_z = (.., .., 1)
            rt * c - r * s, rt * s + r * c,                  # S_t = (.., .., 0)
            rzz * c, rzz * s,                                # S_zz
            rzt * c - rz * s, rzt * s + rz * c,              # S_zt
            (rtt - r) * c - 2.0 * rt * s, (rtt - r) * s + 2.0 * rt * c,   # S_tt
            r, rt)


@njit(cache=True)
def _dist2(prm, px, py, pz, z, t):
    r = leg_r(prm, z, t)
    dx = px - prm[0] - r * math.cos(t)
    dy = py - prm[1] - r * math.sin(t)
    dz = pz - z
    return dx * dx + dy * dy + dz * dz


@njit(cache=True)
def leg_inside(prm, px, py, pz):
    """(rho - r(z_p, t_p)) [m]: negative inside the limb (p's distance from the axis below the
    surface's radius at p's own height and angle; exact for star-shaped sections)."""
    dx = px - prm[0]
    dy = py - prm[1]
    rho = math.sqrt(dx * dx + dy * dy)
    t = math.atan2(dy, dx) if rho > 0.0 else 0.0
    return rho - leg_r(prm, pz, t)


@njit(cache=True)
def leg_foot(prm, px, py, pz):
    """The closest point's parameters (z, t) and whether the iteration converged."""
    dx = px - prm[0]
    dy = py - prm[1]
    rho = math.sqrt(dx * dx + dy * dy)
    t = math.atan2(dy, dx) if rho > 0.0 else 0.0
    z = pz
    f = _dist2(prm, px, py, pz, z, t)
    for _ in range(_NEWTON_ITERS):
        (sx, sy, sz, zx, zy, tx, ty, zzx, zzy, ztx, zty, ttx, tty, r, rt) = _frame(prm, z, t)
        wx = px - sx
        wy = py - sy
        wz = pz - sz
        gz = -(wx * zx + wy * zy + wz)
        gt = -(wx * tx + wy * ty)
        SzSz = zx * zx + zy * zy + 1.0
        StSt = tx * tx + ty * ty
        Hzz = SzSz - (wx * zzx + wy * zzy)
        Hzt = zx * tx + zy * ty - (wx * ztx + wy * zty)
        Htt = StSt - (wx * ttx + wy * tty)
        det = Hzz * Htt - Hzt * Hzt
        newton = Hzz > 0.0 and det > 1e-12 * Hzz * Htt
        if newton:
            dz = -(Htt * gz - Hzt * gt) / det
            dt = -(Hzz * gt - Hzt * gz) / det
        else:
            dz = -gz / SzSz
            dt = -gt / StSt
        # limit a step to a fraction of the limb's size
        lim = 0.5 * max(r, 1e-6)
        if abs(dz) > lim:
            sc = lim / abs(dz)
            dz *= sc
            dt *= sc
        if abs(dt) > 0.5:
            sc = 0.5 / abs(dt)
            dz *= sc
            dt *= sc
        step = math.sqrt(dz * dz + r * r * dt * dt)
        if step <= _STEP_TOL:
            return z, t, True
        if newton and step < 1e-5 * max(r, 1e-6):
            # the quadratic phase: the full step (|p - S|^2 cannot resolve its decrease here,
            # it is below rounding of the squared distance)
            z += dz
            t += dt
            f = _dist2(prm, px, py, pz, z, t)
            continue
        lam = 1.0
        moved = False
        for _ in range(40):
            fn = _dist2(prm, px, py, pz, z + lam * dz, t + lam * dt)
            if fn <= f:
                moved = True
                break
            lam *= 0.5
        if not moved:
            # no decrease to rounding: the gradient vanishes within it
            return z, t, True
        z += lam * dz
        t += lam * dt
        f = fn
        if lam * step <= _STEP_TOL:
            return z, t, True
    return z, t, False


@njit(cache=True)
def leg_query(prm, px, py, pz, out):
    """Signed distance [m] from p to the limb (negative inside); fills out[0:8] as every mold
    query does: the closest point [m], the unit outward normal there, feature code 0 (a face)
    and index 0."""
    z, t, _ = leg_foot(prm, px, py, pz)
    (sx, sy, sz, zx, zy, tx, ty, _, _, _, _, _, _, _, _) = _frame(prm, z, t)
    # n = S_t x S_z
    nx = ty
    ny = -tx
    nz = tx * zy - ty * zx
    nl = math.sqrt(nx * nx + ny * ny + nz * nz)
    nx /= nl
    ny /= nl
    nz /= nl
    out[0] = sx
    out[1] = sy
    out[2] = sz
    out[3] = nx
    out[4] = ny
    out[5] = nz
    out[6] = 0.0
    out[7] = 0.0
    d = math.sqrt((px - sx) ** 2 + (py - sy) ** 2 + (pz - sz) ** 2)
    return -d if leg_inside(prm, px, py, pz) < 0.0 else d


@njit(cache=True)
def leg_segment_hit(prm, p0, p1):
    """The share t in [0, 1] where the segment p0 -> p1 first enters the limb (from outside or
    from the surface), or -1.0: the sign of ``leg_inside`` sampled every 2 mm, the crossing then
    bisected to 1e-12 m."""
    dx = p1[0] - p0[0]
    dy = p1[1] - p0[1]
    dz = p1[2] - p0[2]
    L = math.sqrt(dx * dx + dy * dy + dz * dz)
    if L == 0.0:
        return -1.0
    n = max(8, min(100000, int(math.ceil(L * _SEG_SAMPLES_PER_M))))
    g0 = leg_inside(prm, p0[0], p0[1], p0[2])
    prev_t = 0.0
    prev_out = g0 >= 0.0
    for k in range(1, n + 1):
        tk = k / n
        g = leg_inside(prm, p0[0] + tk * dx, p0[1] + tk * dy, p0[2] + tk * dz)
        if g < 0.0 and prev_out:
            lo = prev_t
            hi = tk
            for _ in range(200):
                if (hi - lo) * L <= 1e-12:
                    break
                tm = 0.5 * (lo + hi)
                if leg_inside(prm, p0[0] + tm * dx, p0[1] + tm * dy, p0[2] + tm * dz) < 0.0:
                    hi = tm
                else:
                    lo = tm
            return lo
        prev_out = g >= 0.0
        prev_t = tk
    return -1.0


@njit(cache=True)
def leg_points(prm, Z, T, out):
    """The surface points S(Z[i], T[i]) [m] into out (n, 3); Z [m], T [rad] (n,)."""
    for i in range(Z.shape[0]):
        r, _, _, _, _, _ = leg_radius(prm, Z[i], T[i])
        out[i, 0] = prm[0] + r * math.cos(T[i])
        out[i, 1] = prm[1] + r * math.sin(T[i])
        out[i, 2] = Z[i]


# --------------------------------------------------------------------------------------------
# construction (plain numpy)
# --------------------------------------------------------------------------------------------


def _von_mises(phi, kappa):
    return np.exp(kappa * (np.cos(phi) - 1.0))


def section_shape(phi: np.ndarray, aspect: float = 1.0, medial_flat: float = 0.0,
                  crest: float = 0.0) -> np.ndarray:
    """A section's radius (unscaled) at the local angle phi [rad] (0 medial, pi/2 anterior, pi
    lateral, 3 pi/2 posterior): an ellipse with medio-lateral over antero-posterior axis ratio
    ``aspect``, its medial side flattened by the share ``medial_flat`` (the radius there cut by
    that share, over about +-40 degrees) and a tibial crest standing out anteriorly by the share
    ``crest`` (over about +-20 degrees)."""
    a_ml, a_ap = float(aspect), 1.0
    r = a_ml * a_ap / np.sqrt((a_ap * np.cos(phi)) ** 2 + (a_ml * np.sin(phi)) ** 2)
    r = r * (1.0 - medial_flat * _von_mises(phi, 4.0))
    return r * (1.0 + crest * _von_mises(phi - 0.5 * np.pi, 16.0))


def _fourier(r: np.ndarray, M: int) -> np.ndarray:
    """(2M+1,) coefficients a_0, a_1, b_1, ..., a_M, b_M of samples r at t = 2 pi k / N."""
    N = len(r)
    F = np.fft.rfft(r) / N
    c = np.empty(2 * M + 1)
    c[0] = F[0].real
    for k in range(1, M + 1):
        c[2 * k - 1] = 2.0 * F[k].real
        c[2 * k] = -2.0 * F[k].imag
    return c


def _series(c: np.ndarray, t: np.ndarray, deriv: int = 0) -> np.ndarray:
    M = (len(c) - 1) // 2
    out = np.full_like(t, c[0] if deriv == 0 else 0.0, dtype=float)
    for k in range(1, M + 1):
        a, b = c[2 * k - 1], c[2 * k]
        if deriv == 0:
            out += a * np.cos(k * t) + b * np.sin(k * t)
        else:
            out += k * (-a * np.sin(k * t) + b * np.cos(k * t))
    return out


def series_perimeter(c: np.ndarray, n: int = 4096) -> float:
    """The perimeter [m] of the closed polar curve r(t) of Fourier coefficients c (trapezoid
    rule on the periodic integrand sqrt(r^2 + r_t^2): spectrally accurate)."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    r = _series(c, t)
    rt = _series(c, t, 1)
    return float(np.sqrt(r * r + rt * rt).mean() * 2.0 * np.pi)


def _natural_spline_m(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Second derivatives of the natural cubic spline through (x, y) (zero at both ends)."""
    n = len(x)
    m = np.zeros(n)
    if n < 3:
        return m
    h = np.diff(x)
    A = np.zeros((n - 2, n - 2))
    rhs = np.zeros(n - 2)
    for i in range(1, n - 1):
        A[i - 1, i - 1] = (h[i - 1] + h[i]) / 3.0
        if i > 1:
            A[i - 1, i - 2] = h[i - 1] / 6.0
        if i < n - 2:
            A[i - 1, i] = h[i] / 6.0
        rhs[i - 1] = (y[i + 1] - y[i]) / h[i] - (y[i] - y[i - 1]) / h[i - 1]
    m[1:-1] = np.linalg.solve(A, rhs)
    return m


def leg_params(center, heights, girths, shapes=None, anterior=(0.0, -1.0), medial=(1.0, 0.0),
               harmonics: int = DEFAULT_HARMONICS, extend: float = DEFAULT_EXTEND, floor: float = 0.0,
               samples: int = 512) -> np.ndarray:
    """The parameter array of a limb (see the module docstring). center (x, y) [m] the axis;
    heights [m] the levels' heights above ``floor`` [m] (strictly rising), girths [m] their
    girths; shapes: per level a dict of :func:`section_shape`'s keywords (aspect, medial_flat,
    crest) or None (a circle); anterior, medial: unit directions (x, y) of the front and of the
    inner side. Raises ValueError on a bad input."""
    z = float(floor) + np.asarray(heights, float)
    g = np.asarray(girths, float)
    n = len(z)
    if n < 2 or len(g) != n:
        raise ValueError("a limb needs at least two levels, each with a height and a girth")
    if not (np.all(np.isfinite(z)) and np.all(np.diff(z) > 0)):
        raise ValueError(f"the levels' heights must rise strictly (got {np.round(z - floor, 4).tolist()} m)")
    if not np.all(np.isfinite(g) & (g > 0)):
        raise ValueError("every girth must be positive")
    a = np.asarray(anterior, float)
    m = np.asarray(medial, float)
    a, m = a / np.linalg.norm(a), m / np.linalg.norm(m)
    if abs(float(a @ m)) > 1e-6:
        raise ValueError("anterior and medial must be perpendicular directions")
    M = int(harmonics)
    t = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    t4 = np.linspace(0.0, 2.0 * np.pi, 4096, endpoint=False)   # leg_girth's grid
    d = np.column_stack([np.cos(t), np.sin(t)])
    phi = np.arctan2(d @ a, d @ m)        # local angle: 0 medial, pi/2 anterior
    C = np.empty((2 * M + 1, n))
    for i in range(n):
        sh = (shapes[i] if shapes is not None else None) or {}
        rho = section_shape(phi, **sh)
        c = _fourier(rho, M)
        if _series(c, t).min() <= 0:
            raise ValueError(f"level {i}: the section's shape has no positive radius everywhere")
        # the girth a tape measures: the convex hull's perimeter (the outline's own on a convex
        # section; the hull's share is scale-free, so one scaling makes it exact)
        C[:, i] = c * (g[i] / (series_perimeter(c) * _hull_share(_series(c, t4), t4)))
    prm = np.zeros(HEADER + n + 2 * n * (2 * M + 1))
    prm[0:2] = center
    prm[2] = n
    prm[3] = M
    prm[4] = float(extend)
    prm[6] = z[0]
    prm[7] = z[-1]
    prm[HEADER:HEADER + n] = z
    for j in range(2 * M + 1):
        base = HEADER + n + 2 * n * j
        prm[base:base + n] = C[j]
        prm[base + n:base + 2 * n] = _natural_spline_m(z, C[j])
    # the largest radius, over the levels, between them and beyond (the tanh tails)
    zs = np.linspace(z[0] - 4 * extend, z[-1] + 4 * extend, 200)
    rmax = 0.0
    for zz in zs:
        rr = _section(prm, float(zz), t[::8])[0]
        if rr.min() <= 0:
            raise ValueError(f"the limb's radius is not positive at z = {zz:.3f} m (levels too far apart "
                             f"for their girths, or extend too long)")
        rmax = max(rmax, float(rr.max()))
    prm[5] = rmax
    return prm


def _hull_share(r: np.ndarray, t: np.ndarray) -> float:
    """The convex hull's perimeter over the polygon's own, of the polar polygon r(t); exactly 1
    for a section convex to 1e-9 (the hull's rounding does not move a convex section's scale:
    a friction equilibrium can be that sensitive)."""
    from shapely.geometry import MultiPoint

    xy = np.column_stack([r * np.cos(t), r * np.sin(t)])
    own = float(np.linalg.norm(np.diff(np.vstack([xy, xy[:1]]), axis=0), axis=1).sum())
    share = MultiPoint([tuple(p) for p in xy]).convex_hull.length / own
    return 1.0 if share > 1.0 - 1e-9 else share


def leg_loop_length(prm: np.ndarray, z: float, n: int = 4096) -> float:
    """The length [m] of the section's own outline at height z [m] (the series' perimeter)."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    r, rt = _section(prm, float(z), t)
    return float(np.sqrt(r * r + rt * rt).mean() * 2.0 * np.pi)


def leg_girth(prm: np.ndarray, z: float, n: int = 4096) -> float:
    """The girth [m] of the limb's section at height z [m] as a tape measures it: the perimeter
    of the section's convex hull (its own perimeter on a convex section; less where a flat
    medial side or a crest makes it concave: the tape bridges the hollow)."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    r, rt = _section(prm, float(z), t)
    return float(np.sqrt(r * r + rt * rt).mean() * 2.0 * np.pi) * _hull_share(r, t)


@njit(cache=True)
def _section(prm, z, t):
    """(r, r_t) (n,) of the section at height z [m] at the angles t [rad]."""
    r = np.empty(t.shape[0])
    rt = np.empty(t.shape[0])
    for i in range(t.shape[0]):
        a, _, b, _, _, _ = leg_radius(prm, z, t[i])
        r[i] = a
        rt[i] = b
    return r, rt


def leg_mesh(prm: np.ndarray, resolution: int = 48, rings: int | None = None):
    """A closed triangle mesh of the limb for display and sections: (V (n,3) [m], F (m,3)),
    from one ``extend`` below the lowest level to one above the highest, capped flat."""
    L = float(prm[4])
    z0, z1 = float(prm[6]) - L, float(prm[7]) + L
    res = max(int(resolution), 8)
    nz = rings or max(8, int(math.ceil((z1 - z0) / (2 * math.pi * prm[5] / res))))
    zs = np.linspace(z0, z1, nz + 1)
    ts = np.linspace(0.0, 2 * np.pi, res, endpoint=False)
    Zg, Tg = np.meshgrid(zs, ts, indexing="ij")
    P = np.empty((Zg.size, 3))
    leg_points(prm, Zg.ravel(), Tg.ravel(), P)
    V = np.vstack([P, [[prm[0], prm[1], z0], [prm[0], prm[1], z1]]])
    F = []
    for i in range(nz):
        for k in range(res):
            a, b = i * res + k, i * res + (k + 1) % res
            F += [[a, b, b + res], [a, b + res, a + res]]
    bot, top = len(V) - 2, len(V) - 1
    for k in range(res):
        F.append([bot, (k + 1) % res, k])
        F.append([top, nz * res + k, nz * res + (k + 1) % res])
    return np.array(V, float), np.array(F, np.int64)
