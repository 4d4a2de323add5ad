"""Contact pressure and its sensors: the per-node normal reaction and pressure, the sensor disc
and its readings, the line load where the sheet gathered into a rope.

Everything that turns an equilibrium into a pressure lives here; ``clothsim.results`` (the run's
summary), ``clothsim.compression`` (probes, profiles, classes, fit, report) and the viewer read it.

**One sensor disc** (:class:`SensorDisc`): a pressure sensor is a disc of radius r laid between
the sheet and the body; it reads the normal contact force on the disc over an area. Two readings
of the disc are used, with two radii, each for its job (the numbers of every existing output are
those they always were):

- the run summary's peak (``max_sensor_pressure_*``, :data:`PEAK_SENSOR`, r = 5 mm, about a
  thin-film interface-pressure sensor's 9.5 mm sensing disc): the disc is moved over the sheet to
  where it reads most (:func:`max_sensor_pressure`), and reads the force over the part of the disc
  the sheet covers (:func:`sensor_pressure`), a value that converges under refinement where the
  node peak does only at first order (docs/method/pressure_convergence.md);
- a probe (``probes:`` in a scene, ``clothsim.compression.probes``, default radius
  :data:`PROBE_SENSOR` r = 1 cm, a clinical probe's size, the user may give any): the disc sits
  at a named point on the mold and reads the force over the whole disc area pi r^2
  (:meth:`SensorDisc.on_mold`), so a disc the sheet half covers reads half (its
  ``contact_fraction`` says so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .kernels import forces_and_energy
from .model import SpringFamily
from .mold import mold_query_many
from .units import MMHG  # noqa: F401 (Pa per mmHg; defined once, in clothsim.units)

#: a contact node whose deformed tributary area is below this fraction of its rest area has
#: gathered: its pressure is reported as inf (see contact_reaction)
GATHERED_AREA_RATIO = 1e-2
#: a node of a cut panel whose rest area is below this fraction of its lattice share (the quarter
#: cells round it) is a sliver of the outline: its pressure is read over its patch (see
#: contact_reaction)
SLIVER_FRACTION = 0.5


def pressure_area(model, positions: np.ndarray) -> np.ndarray:
    """Each node's tributary area [m^2] (N,) on the deformed sheet, the area its contact reaction
    is spread over: a quarter of each adjacent cell; on a cut panel the node's rest area
    (model.node_area) times the areal stretch of the cells round it. positions (N, 3) [m]."""
    topo = model.topology
    area = topo.deformed_node_area(positions)
    if not topo.is_grid:
        # a cut panel's node carries only its share of the cells the outline crosses: its rest
        # area (model.node_area) times the areal stretch of the cells round it
        rest = topo.deformed_node_area(model.rest_positions)
        area = model.node_area * np.divide(area, rest, out=np.ones_like(area), where=rest > 0)
    return area


def contact_reaction(model, positions: np.ndarray, in_contact: np.ndarray):
    """Per-node normal contact reaction [N] and contact pressure [Pa], both (N,): the reaction is
    max(0, -R . n), R the resultant of the node's springs and external force, n the mold's outward
    (pseudo-)normal at the closest point; the pressure divides it by the node's tributary area on
    the deformed sheet. Zero off contact; inf where a loaded node's area has shrunk below
    GATHERED_AREA_RATIO of its rest area (the sheet gathered into a rope: a line load).
    Whole-array kernels (the viewer calls it 25 times a second)."""
    n = model.node_count
    force = np.zeros(n)
    pressure = np.zeros(n)
    if model.mold is None or not in_contact.any():
        return force, pressure

    F = np.empty((n, 3))
    forces_and_energy(positions, *model.spring_args(), model.external_force, F)
    model.add_seam_forces(positions, F)
    k = np.nonzero(in_contact)[0]
    m = len(k)
    sd, cp, nrm = np.empty(m), np.empty((m, 3)), np.empty((m, 3))
    mold_query_many(model.mold.kernel_args(), np.ascontiguousarray(positions[k]), sd, cp, nrm,
                    np.empty((m, 2), np.int64))
    force[k] = np.maximum(0.0, -np.einsum("ij,ij->i", F[k], nrm))
    area = pressure_area(model, positions)
    np.divide(force, area, out=pressure, where=area > 0)
    _sliver_pressure(model, in_contact, force, area, pressure)
    # where the sheet has gathered (a band pulled into a rope) its area is gone and the reaction
    # is a line load: the pressure there is unbounded (inf), not a huge finite number
    pressure[(force > 0.0) & (area < GATHERED_AREA_RATIO * model.node_area)] = np.inf
    return force, pressure


def _sliver_pressure(model, in_contact, force, area, pressure) -> None:
    """Where the outline cuts a sliver off a lattice cell, the node there carries a tiny rest area
    (down to 1e-6 of a full node's) and a reaction that the springs' geometry, not that area,
    decides: reaction / area then reads thousands of mmHg (49,000 mmHg on the refined stocking,
    from 3e-4 N on 4e-11 m^2). A contact node of a cut panel whose rest area is below
    SLIVER_FRACTION of its lattice share reads its patch instead: the reactions of the node and its
    warp, weft and seam neighbours in contact over their deformed areas (exact for a uniform
    pressure, like the sensor reading). force, area, pressure (N,) [N], [m^2], [Pa]; pressure updated in place."""
    topo = model.topology
    if topo.is_grid:
        return
    share = topo.deformed_node_area(model.rest_positions)
    sliver = in_contact & (model.node_area < SLIVER_FRACTION * share)
    if not sliver.any():
        return
    fam = model.spring_family
    pairs = model.spring_nodes[(fam == SpringFamily.WARP) | (fam == SpringFamily.WEFT) | (fam == SpringFamily.SEAM)]
    a, b = pairs[:, 0], pairs[:, 1]
    # the neighbours in contact only (a neighbour off the mold carries no reaction, and its area
    # is not pressed)
    fc = np.where(in_contact, force, 0.0)
    ac = np.where(in_contact, area, 0.0)
    fsum, asum = fc.copy(), ac.copy()
    np.add.at(fsum, a, fc[b])
    np.add.at(fsum, b, fc[a])
    np.add.at(asum, a, ac[b])
    np.add.at(asum, b, ac[a])
    k = np.nonzero(sliver & (asum > 0))[0]
    pressure[k] = np.where(np.isinf(pressure[k]), pressure[k], fsum[k] / asum[k])


@dataclass(frozen=True)
class SensorDisc:
    """A pressure sensor: a disc of radius ``radius_m`` [m] between the sheet and the body (see the
    module docstring for its two readings and their radii)."""

    #: the disc's radius [m]
    radius_m: float

    @property
    def area_m2(self) -> float:
        """The disc's area pi r^2 [m^2]."""
        return math.pi * self.radius_m * self.radius_m

    def on_sheet(self, positions: np.ndarray, force: np.ndarray, area: np.ndarray,
                 centers: np.ndarray) -> np.ndarray:
        """The covered-area reading [Pa] centred on nodes ``centers`` (:func:`sensor_pressure`)."""
        return sensor_pressure(positions, force, area, centers, self.radius_m)

    def peak_on_sheet(self, positions: np.ndarray, force: np.ndarray, area: np.ndarray, centers: np.ndarray,
                      cells: np.ndarray) -> float:
        """The largest covered-area reading [Pa] anywhere on the contact (:func:`max_sensor_pressure`)."""
        return max_sensor_pressure(positions, force, area, centers, cells, self.radius_m)

    def on_mold(self, model, positions: np.ndarray, in_contact: np.ndarray, pressure: np.ndarray,
                centre: np.ndarray) -> tuple[float, float]:
        """The disc centred on the mold point ``centre`` (3,) [m]: (the normal force on it [N], the
        sheet's area in contact on it [m^2]), see :func:`disc_force_on_mold`; the reading is the
        force over :attr:`area_m2`."""
        return disc_force_on_mold(model, positions, in_contact, pressure, centre, self.radius_m)


#: the disc of the run summary's peak sensor pressure (``max_sensor_pressure_*``,
#: ``sensor_radius_m``): 5 mm, about a thin-film interface-pressure sensor's 9.5 mm sensing disc
PEAK_SENSOR = SensorDisc(0.005)
#: a probe's disc when the scene gives no radius (``probes: [{radius: ...}]``; its default in
#: ``clothsim.compression.spec.DEFAULT_PROBE_RADIUS``, which imports nothing from clothsim and is
#: checked equal to this one by the tests): 1 cm, a clinical interface-pressure probe
PROBE_SENSOR = SensorDisc(0.01)
#: radius [m] of the peak sensor disc (PEAK_SENSOR.radius_m; the name summary.json's
#: ``sensor_radius_m`` and scripts read)
SENSOR_RADIUS_M = PEAK_SENSOR.radius_m


def mold_closest(mold, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(closest points (M, 3) [m], signed distances (M,) [m]) of points P (M, 3) on the mold."""

    P = np.ascontiguousarray(P, dtype=float).reshape(-1, 3)
    m = len(P)
    sd, cp, nrm = np.empty(m), np.empty((m, 3)), np.empty((m, 3))
    if m:
        mold_query_many(mold.kernel_args(), P, sd, cp, nrm, np.empty((m, 2), np.int64))
    return cp, sd


def finite_pressure(pressure: np.ndarray) -> tuple[np.ndarray, int]:
    """Pressure [Pa] with gathered nodes (inf: a line load) set to 0, and how many there were."""
    bad = ~np.isfinite(pressure)
    return np.where(bad, 0.0, pressure), int(bad.sum())


def _subdivision(k: int) -> tuple[np.ndarray, float]:
    """Barycentric centroids (k^2, 3) of the k^2 equal sub-triangles of a triangle; each has
    1/k^2 of its area."""
    out = []
    for a in range(k):
        for b in range(k - a):
            out.append(((a + 1 / 3) / k, (b + 1 / 3) / k))        # upward sub-triangle
            if a + b < k - 1:
                out.append(((a + 2 / 3) / k, (b + 2 / 3) / k))    # downward one
    uv = np.array(out)
    return np.column_stack([1 - uv.sum(1), uv[:, 0], uv[:, 1]]), 1.0 / k ** 2


def disc_force_on_mold(model, positions: np.ndarray, in_contact: np.ndarray, pressure: np.ndarray,
                       centre: np.ndarray, radius: float) -> tuple[float, float]:
    """The disc of mold points within ``radius`` [m] (straight, chord distance) of the mold point
    ``centre`` (3,) [m]: (the integral of the node pressure over the sheet inside it [N], the
    integral of the contact flag there [m^2]). A point of the sheet is inside when its closest mold
    point is. p and c are interpolated linearly over the deformed sheet's display triangles
    (``model.topology.faces``), the triangles near the disc each split into k^2 sub-triangles (k
    so that a sub-triangle is about radius / 60 wide): the disc's outline is resolved well below
    the node spacing. positions (N, 3) [m], in_contact (N,) bool, pressure (N,) [Pa] (gathered
    nodes, inf, count 0)."""
    r = float(radius)
    p, _ = finite_pressure(np.asarray(pressure, float))
    faces = model.topology.faces
    X = np.asarray(positions, float)
    tri = X[faces]                                                  # (F, 3, 3)
    edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    # triangles that can reach the disc: a vertex's mold point within radius + the triangle size
    vcp, _ = mold_closest(model.mold, X)
    vd = np.linalg.norm(vcp - centre, axis=1)
    near = np.nonzero(vd[faces].min(axis=1) <= r + 2.0 * edge)[0]
    if not near.size:
        return 0.0, 0.0
    k = int(min(64, max(4, math.ceil(60.0 * float(edge[near].max()) / r))))
    bary, share = _subdivision(k)
    t = tri[near]                                                   # (M, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    S = np.einsum("sv,mvc->msc", bary, t).reshape(-1, 3)            # sample points
    a = np.repeat(area * share, len(bary))
    ps = (bary @ p[faces[near]].T).T.reshape(-1)
    cs = (bary @ in_contact[faces[near]].astype(float).T).T.reshape(-1)
    scp, _ = mold_closest(model.mold, S)
    inside = np.linalg.norm(scp - centre, axis=1) <= r
    return float((ps * a)[inside].sum()), float((cs * a)[inside].sum())


def _lens_fraction(d: np.ndarray, r: float, rho: np.ndarray) -> np.ndarray:
    """Fraction [-] of a disc of radius rho [m] (a node's tributary area as a disc) that lies
    inside a disc of radius r [m] whose centre is d [m] away; d, rho (M,), result (M,). The
    exact area of the two circles' intersection (a lens) over pi rho^2: 1 inside, 0 apart,
    continuous and smooth in d in between."""
    d = np.maximum(d, 1e-300)
    out = (d <= r - rho).astype(float)
    part = (d > np.abs(r - rho)) & (d < r + rho)
    dd, q = d[part], rho[part]
    lens = (q * q * np.arccos(np.clip((dd * dd + q * q - r * r) / (2 * dd * q), -1, 1))
            + r * r * np.arccos(np.clip((dd * dd + r * r - q * q) / (2 * dd * r), -1, 1))
            - 0.5 * np.sqrt(np.maximum((-dd + q + r) * (dd + q - r) * (dd - q + r) * (dd + q + r), 0.0)))
    out[part] = lens / (np.pi * q * q)
    out[(d <= rho - r)] = (r * r) / (rho[(d <= rho - r)] ** 2)   # the sensor inside the node's disc
    return out


def sensor_pressure(positions: np.ndarray, force: np.ndarray, area: np.ndarray, centers: np.ndarray,
                    radius: float = SENSOR_RADIUS_M) -> np.ndarray:
    """Contact pressure [Pa] a sensor disc of ``radius`` [m] centred on each of ``centers`` reads:
    the normal contact force on the disc over the sheet's area on it,

        S(c) = sum_k F_k f_k(c) / sum_k A_k f_k(c),

    F_k [N] the nodes' normal contact reactions, A_k [m^2] their deformed tributary areas and
    f_k(c) the fraction of node k's tributary area (taken as a disc of area A_k round the node)
    within 3-D distance ``radius`` of c (:func:`_lens_fraction`). positions (N, 3) [m]; force,
    area (N,); centers (M,) node numbers; returns (M,).

    Why: the node pressure F_k / A_k is a point value. Where the sheet leaves the mold along a
    lift-off line the pressure drops from its largest value to 0 across one lattice cell, and the
    node values there sample that drop at a distance from the line that depends on where the line
    crosses the lattice; their peak converges only at first order under refinement. The force is
    right in aggregate (the total contact force converges to 4 digits), so an average over a
    sensor-sized disc converges (docs/method/pressure_convergence.md). Under a uniform pressure it
    reads that pressure exactly (Laplace's T / r on a cylinder or sphere). Unlike a probe
    (force over pi r^2), a disc only partly under the sheet reads the covered part's mean."""
    X = np.asarray(positions, float)
    centers = np.asarray(centers, np.int64)
    return sensor_pressure_at(X, force, area, X[centers], radius)


def sensor_pressure_at(positions: np.ndarray, force: np.ndarray, area: np.ndarray, points: np.ndarray,
                       radius: float = SENSOR_RADIUS_M) -> np.ndarray:
    """:func:`sensor_pressure` for sensor discs centred on any points (M, 3) [m] on the sheet
    (not only its nodes); positions (N, 3) [m], force, area (N,); returns (M,) [Pa] (0 where no
    node's area reaches the disc)."""
    from scipy.spatial import cKDTree

    X = np.asarray(positions, float)
    F = np.asarray(force, float)
    A = np.asarray(area, float)
    P = np.asarray(points, float).reshape(-1, 3)
    out = np.zeros(P.shape[0])
    if P.shape[0] == 0:
        return out
    rho = np.sqrt(np.maximum(A, 0.0) / np.pi)
    tree = cKDTree(X)
    reach = radius + float(rho.max())
    for s in range(0, P.shape[0], 2048):   # chunks: bounded memory on big lattices
        c = P[s:s + 2048]
        pairs = cKDTree(c).sparse_distance_matrix(tree, reach, output_type="ndarray")
        row, k = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)
        f = _lens_fraction(pairs["v"], radius, rho[k])
        num = np.bincount(row, F[k] * f, c.shape[0])
        den = np.bincount(row, A[k] * f, c.shape[0])
        np.divide(num, den, out=out[s:s + 2048], where=den > 0)
    return out


#: the peak sensor reading is searched between the nodes too: on a SENSOR_SUBDIVISIONS x
#: SENSOR_SUBDIVISIONS grid of points in each lattice cell that has a corner reading at least
#: SENSOR_SEARCH_SHARE of the node-centred peak (the calf band's 5 mm sensor peak at 80
#: divisions round the leg: 25.60 mmHg on the nodes, 25.73 between them; 26.37 / 26.40 at 160)
SENSOR_SUBDIVISIONS = 4
SENSOR_SEARCH_SHARE = 0.9


def max_sensor_pressure(positions: np.ndarray, force: np.ndarray, area: np.ndarray, centers: np.ndarray,
                        cells: np.ndarray, radius: float = SENSOR_RADIUS_M) -> float:
    """The largest reading [Pa] of a sensor disc of ``radius`` [m] (:func:`sensor_pressure`)
    centred anywhere on the contact ``centers`` (M,) (node numbers; loaded contact nodes): on
    each of them, and on the bilinear points (i/s, j/s), s = ``SENSOR_SUBDIVISIONS``, of every
    lattice cell of ``cells`` (C, 4) (``Topology.cells``) whose four corners are all centres and
    one of which reads at least ``SENSOR_SEARCH_SHARE`` of the node-centred peak. A sensor is
    placed where the reading is largest, not where the lattice has a node: on a coarse lattice
    the node-centred peak misses a crest between nodes (by 0.5 % on the calf band at 3.6 mm
    cells, its change from 80 to 160 divisions 3.04 % -> 2.6 %). positions (N, 3) [m]; force,
    area (N,). 0.0 when there are no centres."""
    X = np.asarray(positions, float)
    centers = np.asarray(centers, np.int64)
    if centers.size == 0:
        return 0.0
    S = sensor_pressure(X, force, area, centers, radius)
    peak = float(S.max())
    cells = np.asarray(cells, np.int64).reshape(-1, 4)
    if not (peak > 0.0) or cells.shape[0] == 0:
        return peak
    n = X.shape[0]
    is_c = np.zeros(n, bool)
    is_c[centers] = True
    near = np.zeros(n, bool)
    near[centers[S >= SENSOR_SEARCH_SHARE * peak]] = True
    pick = is_c[cells].all(axis=1) & near[cells].any(axis=1)
    if not pick.any():
        return peak
    c = cells[pick]
    t = np.arange(SENSOR_SUBDIVISIONS + 1) / SENSOR_SUBDIVISIONS
    u, v = (a.ravel() for a in np.meshgrid(t, t, indexing="ij"))
    w = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], 1)   # corners 0..3 of a cell
    pts = np.einsum("qc,mcd->mqd", w, X[c]).reshape(-1, 3)
    return max(peak, float(sensor_pressure_at(X, force, area, pts, radius).max()))


def gathered_line_load(model, positions: np.ndarray, force: np.ndarray, gathered: np.ndarray) -> dict:
    """The line load [N/m] along a rope the sheet has gathered into (contact nodes with no area
    left, see contact_reaction), where a pressure is meaningless.

    positions (N, 3) [m]; force (N,) [N] each node's normal contact reaction; gathered (N,)
    bool. The rope runs along warp or weft: the gathered nodes of one lattice line across it (one
    station: same panel, same i for a rope along warp) sit together, so the stations' centroids
    trace the rope. Both directions are tried and the longer trace is the rope. A station's line
    load is its total reaction over its share of the rope's length (half of each segment to its
    neighbouring stations). On a ring of total hoop tension T [N] round a cylinder of radius r
    this is T / r at every station (tested). Returns {"gathered_contact_force_n",
    "rope_length_m", "max_line_load_n_per_m", "mean_line_load_n_per_m"} (the last three None when
    the gathered nodes make no rope: one station only)."""
    k = np.nonzero(gathered)[0]
    out = {"gathered_contact_force_n": float(force[k].sum()), "rope_length_m": None,
           "max_line_load_n_per_m": None, "mean_line_load_n_per_m": None}
    if k.size == 0:
        return out
    topo = model.topology
    best = None
    for d in (0, 1):
        key = topo.node_panel[k].astype(np.int64) * (1 << 32) + topo.node_ij[k, d]
        st, inv = np.unique(key, return_inverse=True)
        cnt = np.bincount(inv)
        cen = np.stack([np.bincount(inv, positions[k, c]) for c in range(3)], 1) / cnt[:, None]
        f = np.bincount(inv, force[k])
        # segments between consecutive stations of the same panel
        nb = (np.diff(st) == 1)
        seg = np.where(nb, np.linalg.norm(np.diff(cen, axis=0), axis=1), 0.0)
        length = float(seg.sum())
        trib = np.zeros(st.size)
        trib[:-1] += 0.5 * seg
        trib[1:] += 0.5 * seg
        if best is None or length > best[0]:
            best = (length, f, trib)
    length, f, trib = best
    if length > 0:
        ok = trib > 0
        out.update(rope_length_m=length, max_line_load_n_per_m=float((f[ok] / trib[ok]).max()),
                   mean_line_load_n_per_m=float(f.sum() / length))
    return out


def pressure_peaks(model, positions: np.ndarray, force: np.ndarray, pressure: np.ndarray) -> dict:
    """The run summary's pressure figures (fields of clothsim.records.Diagnostics): the peak node
    pressure and the peak sensor reading (:data:`PEAK_SENSOR`) over the nodes whose pressure is
    defined, in Pa and mmHg, the sensor's radius, the gathered contact nodes and, where the sheet
    gathered into a rope, its line load. positions (N, 3) [m], force (N,) [N] normal contact
    reactions, pressure (N,) [Pa] (:func:`contact_reaction`).

    When every loaded contact node has gathered there is no pressure to report: None (null) with
    the reason (``contact_pressure_note``) and the line load, never a 0 that would read as "no
    pressure"; with no loaded contact node both peaks are 0.0."""
    cf, p = force, pressure
    gathered = np.isinf(p)
    defined = np.isfinite(p) & (cf > 0.0)
    out: dict = {}
    note = None
    if defined.any():
        pmax = float(p[defined].max())
    elif gathered.any():
        pmax = None
        note = (f"no contact pressure: all {int(gathered.sum())} loaded contact nodes sit where the sheet "
                f"has gathered into a rope (no area under them); their load is a line load "
                f"(contact_line_load_n_per_m)")
    else:
        pmax = 0.0  # no loaded contact node: truly no pressure
    sensor = pmax  # None (all gathered) or 0.0 (no loaded contact node) as the node peak
    if defined.any():
        # the peak a sensor-sized disc reads (sensor_pressure): converges under refinement
        # where the node peak, sitting on a lift-off line, does so only at first order
        sensor = PEAK_SENSOR.peak_on_sheet(positions, np.where(np.isfinite(cf), cf, 0.0),
                                           pressure_area(model, positions), np.nonzero(defined)[0],
                                           model.topology.cells)
    out.update({
        "max_sensor_pressure_pa": sensor,
        "max_sensor_pressure_mmhg": None if sensor is None else sensor / MMHG,
        "sensor_radius_m": PEAK_SENSOR.radius_m,
        "max_contact_pressure_pa": pmax,
        "max_contact_pressure_mmhg": None if pmax is None else pmax / MMHG,
        "gathered_contact_nodes": int(gathered.sum()),
    })
    if note is not None:
        out["contact_pressure_note"] = note
    if gathered.any():
        rope = gathered_line_load(model, positions, cf, gathered)
        out["gathered_contact_force_n"] = rope["gathered_contact_force_n"]
        out["contact_line_load_n_per_m"] = rope["max_line_load_n_per_m"]
        out["contact_line_load_mean_n_per_m"] = rope["mean_line_load_n_per_m"]
    return out
