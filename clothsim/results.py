"""Result: what users read and export (positions, contact, strains, tensions, contact pressure).

Files written by :meth:`Result.save` (each written to a temporary name, then renamed, so an
interrupted run never leaves a half-written file; summary.json is removed first and written last,
so a folder is complete exactly when it holds summary.json):

- ``result.npz``: positions (nx+1, ny+1, 3) [m]; in_contact (nx+1, ny+1) bool; strain_warp
  (nx, ny+1); strain_weft (nx+1, ny); tension_warp / tension_weft [N per spring]; contact_force
  (nx+1, ny+1) [N] (normal reaction); contact_pressure (nx+1, ny+1) [Pa]; residual_history [N];
  energy_history [J]; and what ``report`` draws (faces, node strains, the body near the garment,
  the scene in short: clothsim.compression.folder).
- ``summary.json``: converged, status, message, iterations, residual [N], relative_residual,
  energy [J], wall_time_s (the relaxation), startup_s (mold loading, model building, JIT
  compilation), solver, contact_count, diagnostics, clothsim version. Strict JSON: a
  non-finite number (a diverged run's NaN residual) is written as null.
- ``history.csv``: iteration, residual [N], energy [J], elapsed [s].
- ``sheet.ply``: the deformed grid as triangles with per-vertex colours (strain or pressure).
- ``scene.yaml``: the scene as run, its file references by name with their SHA-256 (no machine
  paths: clothsim.compression.folder.portable_scene_yaml).
- ``probes.csv``, ``profiles.csv``, ``profiles.png``: when the scene has ``probes`` / ``profiles``
  (clothsim.compression.probes); summary.json then holds ``probes``, ``profiles`` and ``classes``.
  A plot that cannot be drawn is a warning and is left out; the numeric files are written.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .kernels import spring_strains_tensions
from .fileio import atomic_write_bytes  # noqa: F401  (re-exported: sweeps and the viewer use it)
from .model import Model, SpringFamily, State

if TYPE_CHECKING:
    from .config import Scene
    from .solvers import SolveResult

FAMILY_SEAM = SpringFamily.SEAM  # (the name Result.summary reads)

MMHG = 133.322387415  # Pa per mmHg

#: every file :meth:`Result.save` may write (summary.json first: it is removed first). A save
#: removes those of them it does not write this time, so an earlier result's files (a scene with
#: probes, then one without) never sit beside a newer result.
RESULT_FILES = ("summary.json", "result.npz", "history.csv", "sheet.ply", "scene.yaml",
                "probes.csv", "profiles.csv", "profiles.png")


def strict_json(obj) -> str:
    """JSON text in which every non-finite float (NaN, inf) is null, as strict JSON parsers
    require (a diverged run's residual is NaN)."""
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(obj), indent=2, allow_nan=False)


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
    from .kernels import forces_and_energy
    from .mold import mold_query_many

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


#: radius [m] of the sensor disc over which :func:`sensor_pressure` averages: 5 mm, about the
#: size of a thin-film interface-pressure sensor (a 9.5 mm sensing disc)
SENSOR_RADIUS_M = 0.005


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


def seam_report(model, positions) -> dict:
    """Per seam (scene order) its sides' rest arc lengths [m], its ease (how much longer the
    longer side is [%]: the longer side gathers onto the shorter) and its widest gap [m] at
    positions (N,3) (the longest seam spring, or the farthest sewn node from the point of the
    other side it is sewn to): {"seams": [...], "max_seam_gap_m": the widest over all seams}."""
    gaps = model.seam_gaps(positions)
    rows = [{"a_length_m": info.a_length, "b_length_m": info.b_length, "ease_pct": info.ease,
             "max_gap_m": float(g.max()) if g.size else 0.0} for info, g in zip(model.seams, gaps)]
    return {"seams": rows, "max_seam_gap_m": max(r["max_gap_m"] for r in rows)}


def node_fields(model, state):
    """Per-spring strain and force, per-node contact force and pressure."""
    S = model.spring_count
    strain = np.empty(S)
    force = np.empty(S)
    spring_strains_tensions(state.positions, *model.spring_args(), strain, force)
    contact_force, pressure = contact_reaction(model, state.positions, state.in_contact)
    return strain, force, contact_force, pressure


def _undetermined(model, force, in_contact) -> np.ndarray:
    taut = force > 0.0
    node_taut = np.zeros(model.node_count, bool)
    node_taut[model.spring_nodes[taut, 0]] = True
    node_taut[model.spring_nodes[taut, 1]] = True
    return ~model.fixed_axes.all(axis=1) & ~node_taut & ~in_contact


#: a warp or weft spring compressed below -GATHER_STRAIN (and so slack) along a direction no
#: constraint holds has gathered (see gathered_rows)
GATHER_STRAIN = 0.2
#: ... and a line between two rows (or columns) of the lattice has gathered when at least this
#: share of the springs across it has
GATHER_LINE_SHARE = 0.5


def gathered_rows(model, positions, strain, force) -> tuple[int, float | None, np.ndarray, str]:
    """Rows (or columns) of the lattice that have gathered along a free direction: contact nodes
    are counted as determined by ``undetermined_nodes``, but a row of a tube with free ends can
    slide along the limb's axis wherever the weft springs on both sides stay slack, and rows
    bunched together (strain -86 % seen on a 80 x 32 tube) read a contact pressure many times
    Laplace's T / r (the same load on a fraction of the area) that depends on where the solver
    left them. A warp or weft spring has gathered when its strain is below -GATHER_STRAIN, it
    carries no force, and one of its nodes is free along it (its direction has a part of at
    least 0.5 on the node's unconstrained axes: a spring held at its length by its two nodes is
    determined). A line between two neighbouring rows (weft springs) or columns (warp springs)
    of a panel has gathered when GATHER_LINE_SHARE of its springs have; the rows or columns on
    both sides of it have gathered.

    positions (N, 3) [m]; strain, force (S,) per spring (``spring_strains_tensions``). Returns
    (the number of gathered rows and columns, the lowest strain among their gathered springs
    or None, a node mask (N,) of their nodes, "weft", "warp", "warp and weft" or "")."""
    topo = model.topology
    fixed = model.fixed_axes
    mask = np.zeros(model.node_count, bool)
    count, low, dirs = 0, None, []
    wc = topo.warp_count
    for name, pairs, first, axis in (("warp", topo.warp, 0, 0), ("weft", topo.weft, wc, 1)):
        if not pairs.shape[0]:
            continue
        sl = slice(first, first + pairs.shape[0])
        st, fo = strain[sl], force[sl]
        a, b = pairs[:, 0], pairs[:, 1]
        u = positions[b] - positions[a]
        u /= np.maximum(np.linalg.norm(u, axis=1), 1e-300)[:, None]
        free_a = np.linalg.norm(np.where(fixed[a], 0.0, u), axis=1) >= 0.5
        free_b = np.linalg.norm(np.where(fixed[b], 0.0, u), axis=1) >= 0.5
        g = (st < -GATHER_STRAIN) & (fo <= 0.0) & (free_a | free_b)
        if not g.any():
            continue
        # the line each spring crosses: (panel, its first node's index along the spring's axis)
        key = topo.node_panel[a] * (1 + int(topo.node_ij[:, axis].max())) + topo.node_ij[a, axis]
        keys, line = np.unique(key, return_inverse=True)
        share = np.bincount(line, g) / np.bincount(line)
        hit = share >= GATHER_LINE_SHARE
        if not hit.any():
            continue
        on = hit[line]
        # the rows (columns) on both sides of the gathered lines, each counted once
        rows = np.unique(np.concatenate([key[on], key[on] + 1]))
        count += int(rows.size)
        s_min = float(st[on & g].min())
        low = s_min if low is None else min(low, s_min)
        mask[a[on]] = True
        mask[b[on]] = True
        dirs.append(name)
    return count, low, mask, " and ".join(dirs)


def gathered_rows_warning(summary: dict) -> str | None:
    """The run's warning line for rows that gathered along a free direction (summary keys
    ``gathered_rows``, ``gathered_rows_direction``, ``gathered_rows_min_strain``,
    ``gathered_rows_max_pressure_mmhg``), or None."""
    n = summary.get("gathered_rows") or 0
    if not n:
        return None
    p = summary.get("gathered_rows_max_pressure_mmhg")
    return (f"  warning: {n} rows of the sheet have gathered along {summary.get('gathered_rows_direction')} "
            f"(springs across them compressed to {summary['gathered_rows_min_strain']:.0%}, slack) and no "
            f"constraint holds them along it: their position is not unique"
            + (f" and their contact pressure (up to {p:.3g} mmHg) reads where they bunched, not the fabric"
               if p else "")
            + "; hold the ends (constraints) or stretch the sheet along that direction")


def sheet_health(model, positions, in_contact, force=None, strain=None) -> dict:
    """Diagnostics that make a degenerate equilibrium visible instead of hiding it.

    slack_springs: springs carrying no force; undetermined_nodes: free nodes held only by slack
    springs and not touching the mold (their position is not unique); min_weft_extent_ratio: the
    narrowest length of the sheet along weft (over all warp positions i) over its rest width — a
    band that gathers into a rope (tension-only weft springs resist no compression) shows here;
    gathered_rows, gathered_rows_direction, gathered_rows_min_strain: rows (or columns) bunched
    along a direction nothing holds, touching the mold or not (:func:`gathered_rows`)."""
    if force is None or strain is None:
        S = model.spring_count
        strain = np.empty(S)
        force = np.empty(S)
        spring_strains_tensions(positions, *model.spring_args(), strain, force)
    topo = model.topology
    weft = topo.weft
    ratio = math.nan
    if weft.shape[0]:
        # one weft line per (panel, i): its deformed length over its rest length
        line = topo.node_panel[weft[:, 0]] * (1 + int(topo.node_ij[:, 0].max())) + topo.node_ij[weft[:, 0], 0]
        _, line = np.unique(line, return_inverse=True)
        length = np.linalg.norm(positions[weft[:, 1]] - positions[weft[:, 0]], axis=1)
        weft_len = np.bincount(line, length)
        wc = topo.warp_count
        rest_w = np.bincount(line, model.spring_rest_length[wc:wc + weft.shape[0]])
        ratio = float((weft_len / rest_w).min()) if (rest_w > 0).all() else math.nan
    rows, low, _, direction = gathered_rows(model, positions, strain, force)
    return {
        "slack_springs": int((force <= 0.0).sum()),
        "spring_count": int(model.spring_count),
        "undetermined_nodes": int(_undetermined(model, force, in_contact).sum()),
        "min_weft_extent_ratio": ratio,
        "gathered_rows": rows,
        "gathered_rows_direction": direction,
        "gathered_rows_min_strain": low,
    }


def surface_report(mold) -> dict:
    """The contact surface of a mesh mold: {"mold_surface": "faceted" | "smooth"} and, when the
    scene left it to the default, "mold_surface_reason" (why :func:`clothsim.mold.build.auto_surface`
    chose it); {} for a primitive mold."""
    from .mold import MOLD_MESH, MOLD_SMOOTH

    if mold.kind not in (MOLD_MESH, MOLD_SMOOTH):
        return {}
    out = {"mold_surface": "smooth" if mold.kind == MOLD_SMOOTH else "faceted"}
    if mold.surface_note:
        out["mold_surface_reason"] = "default: " + mold.surface_note
    return out


@dataclass
class Result:
    """A finished (or stopped) run: the scene, its model, the final state and the solve record."""

    scene: Scene
    model: Model
    state: State
    solve: SolveResult
    startup_s: float = 0.0
    _fields: tuple | None = field(default=None, repr=False)
    _compression: dict | None = field(default=None, repr=False)
    _diagnostics: dict | None = field(default=None, repr=False)

    def _f(self):
        if self._fields is None:
            self._fields = node_fields(self.model, self.state)
        return self._fields

    @property
    def converged(self) -> bool:
        return self.solve.converged

    @property
    def status(self) -> str:
        return self.solve.status

    @property
    def positions(self) -> np.ndarray:
        """(nx+1, ny+1, 3) [m]: the node positions on the lattice's grid (Topology.to_grid)."""
        return self._layout(self.state.positions)

    @property
    def in_contact(self) -> np.ndarray:
        return self._layout(self.state.in_contact)

    def _layout(self, values: np.ndarray) -> np.ndarray:
        """Per-node values on the (nx+1, ny+1) grid of a full rectangle; on any other lattice
        (panels) the flat per-node array (N, ...) in node order (``node_panel``, ``node_ij`` in
        result.npz say which node is which)."""
        topo = self.model.topology
        return topo.to_grid(values) if topo.is_grid else np.asarray(values)

    def _split(self, arr):
        """Warp (nx, ny+1) and weft (nx+1, ny) grids of per-spring values (warp then weft first)."""
        topo = self.model.topology
        wc, fc = topo.warp_count, topo.weft_count
        if not topo.is_grid:
            return arr[:wc], arr[wc:wc + fc]
        return (topo.springs_to_grid(arr[:wc], "warp"), topo.springs_to_grid(arr[wc:wc + fc], "weft"))

    @property
    def strain_warp(self):
        return self._split(self._f()[0])[0]

    @property
    def strain_weft(self):
        return self._split(self._f()[0])[1]

    @property
    def tension_warp(self):
        """Axial force of each warp spring [N]."""
        return self._split(self._f()[1])[0]

    @property
    def tension_weft(self):
        return self._split(self._f()[1])[1]

    @property
    def contact_force(self):
        """Normal contact reaction per node [N] (nx+1, ny+1)."""
        return self._layout(self._f()[2])

    @property
    def contact_pressure(self):
        """Contact pressure [Pa] = reaction / deformed tributary area, (nx+1, ny+1); inf where
        the sheet has gathered into a rope (see contact_reaction)."""
        return self._layout(self._f()[3])

    def _node_strain(self) -> np.ndarray:
        """(N,): the larger of the mean adjacent warp and weft strains at each node."""
        topo = self.model.topology
        wc, fc = topo.warp_count, topo.weft_count
        strain = self._f()[0]
        return np.maximum(topo.spread(strain[:wc], "warp"), topo.spread(strain[wc:wc + fc], "weft"))

    def node_strain(self) -> np.ndarray:
        """Per-node strain for colouring on the lattice's grid (nx+1, ny+1): the larger of the
        mean adjacent warp and weft strains."""
        return self._layout(self._node_strain())

    def diagnostics(self) -> dict:
        """Numbers that make a degenerate result visible (see :func:`sheet_health`), the peak
        strains and pressures, and the deepest penetration into the mold. Worked out once per
        Result (the sensor peak takes seconds on a big sheet, and summary() and save() both need
        it); a copy is returned."""
        if self._diagnostics is None:
            self._diagnostics = self._work_out_diagnostics()
        return copy.deepcopy(self._diagnostics)

    def _work_out_diagnostics(self) -> dict:
        out = sheet_health(self.model, self.state.positions, self.state.in_contact,
                           force=self._f()[1], strain=self._f()[0])
        cf, p = self._f()[2], self._f()[3]
        if out["gathered_rows"]:
            _, _, rows, _ = gathered_rows(self.model, self.state.positions, self._f()[0], self._f()[1])
            pr = p[rows & np.isfinite(p) & (cf > 0.0)]
            out["gathered_rows_max_pressure_mmhg"] = float(pr.max()) / MMHG if pr.size else None
        gathered = np.isinf(p)
        # the peak over nodes whose pressure is defined (gathered nodes are counted apart); when
        # every loaded contact node has gathered there is no pressure to report: None (null)
        # with the reason and the line load, never a 0 that would read as "no pressure"
        defined = np.isfinite(p) & (cf > 0.0)
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
            pos = self.state.positions
            sensor = max_sensor_pressure(pos, np.where(np.isfinite(cf), cf, 0.0), pressure_area(self.model, pos),
                                         np.nonzero(defined)[0], self.model.topology.cells)
        out.update({
            "max_sensor_pressure_pa": sensor,
            "max_sensor_pressure_mmhg": None if sensor is None else sensor / MMHG,
            "sensor_radius_m": SENSOR_RADIUS_M,
            "max_strain_warp": float(self.strain_warp.max()) if self.strain_warp.size else 0.0,
            "max_strain_weft": float(self.strain_weft.max()) if self.strain_weft.size else 0.0,
            "max_contact_pressure_pa": pmax,
            "max_contact_pressure_mmhg": None if pmax is None else pmax / MMHG,
            "gathered_contact_nodes": int(gathered.sum()),
        })
        if note is not None:
            out["contact_pressure_note"] = note
        if gathered.any():
            rope = gathered_line_load(self.model, self.state.positions, cf, gathered)
            out["gathered_contact_force_n"] = rope["gathered_contact_force_n"]
            out["contact_line_load_n_per_m"] = rope["max_line_load_n_per_m"]
            out["contact_line_load_mean_n_per_m"] = rope["mean_line_load_n_per_m"]
        seam = self.model.spring_family == FAMILY_SEAM
        if seam.any():
            ab = self.model.spring_nodes[seam]
            pos = self.state.positions
            out["max_seam_gap_m"] = float(np.linalg.norm(pos[ab[:, 1]] - pos[ab[:, 0]], axis=1).max())
        if self.model.seams:
            out.update(seam_report(self.model, self.state.positions))
        if self.model.mold is not None:
            from .contact import max_penetration

            out["max_penetration_m"] = float(max_penetration(self.state.positions, self.model.mold.kernel_args()))
            out.update(surface_report(self.model.mold))
        return out

    def undetermined_nodes(self) -> np.ndarray:
        """(i, j) indices of free nodes held only by slack springs (no unique equilibrium)."""
        und = _undetermined(self.model, self._f()[1], self.state.in_contact)
        return self.model.topology.node_ij[und]

    def summary(self) -> dict:
        from . import __version__
        from .solvers import pick_method

        s = self.solve
        d = {
            "name": self.scene.name,
            "converged": bool(s.converged),
            "status": s.status,
            "message": s.message,
            "iterations": int(s.iterations),
            "residual": float(s.residual),
            "relative_residual": float(s.relative_residual),
            "best_residual": float(s.best_residual),
            "energy": float(s.energy),
            "wall_time_s": float(s.wall_time_s),
            "startup_s": float(self.startup_s),
            "solver": s.method,
            "C": float(self.scene.solver.C),
            "e": float(self.scene.solver.e),
            "contact_count": int(s.contact_count),
            "node_count": int(self.model.node_count),
            "clothsim_version": __version__,
        }
        if getattr(s, "friction", None):
            # the load steps and the Coulomb state at the last one (stick, slip, cone violation)
            d["friction"] = {k: v for k, v in s.friction.items()}
        d.update(self.diagnostics())
        d.update(self.compression())
        return d

    def compression(self) -> dict:
        """The scene's probes, profiles and classes (clothsim.compression.probes.evaluate):
        {"probes": [...], "profiles": [...], "classes": {...}}, only the keys the scene asks for."""
        if not (getattr(self.scene, "probes", None) or getattr(self.scene, "profiles", None)):
            return {}
        if getattr(self, "_compression", None) is None:
            from .compression.probes import evaluate

            self._compression = evaluate(self.scene, self.model, self.state.positions, self.state.in_contact,
                                         self._f()[3])
        return self._compression

    def colored_mesh(self, field: str = "strain"):
        """A trimesh.Trimesh of the deformed sheet with per-vertex colours (viridis) of field
        ('strain' or 'pressure')."""
        import trimesh
        from matplotlib import colormaps

        values = self._f()[3] / MMHG if field == "pressure" else self._node_strain()
        finite = values[np.isfinite(values)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        t = (values - lo) / (hi - lo) if hi > lo else np.where(np.isposinf(values), 1.0, 0.0)
        # gathered nodes (pressure inf) take the top colour
        t = np.clip(np.nan_to_num(t, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
        colors = (colormaps["viridis"](t) * 255).astype(np.uint8)
        return trimesh.Trimesh(self.state.positions.copy(), self.model.topology.faces, vertex_colors=colors,
                               process=False)

    def history_csv(self) -> str:
        h = self.solve.history
        lines = ["iteration,residual_N,energy_J,elapsed_s"]
        for it, r, e, t in zip(h["iteration"], h["residual"], h["energy"], h["time"]):
            lines.append(f"{int(it)},{r:.10e},{e:.10e},{t:.6f}")
        return "\n".join(lines) + "\n"

    def npz_bytes(self) -> bytes:
        import io

        buf = io.BytesIO()
        np.savez_compressed(
            buf,
            positions=self.positions,
            in_contact=self.in_contact,
            strain_warp=self.strain_warp,
            strain_weft=self.strain_weft,
            tension_warp=self.tension_warp,
            tension_weft=self.tension_weft,
            contact_force=self.contact_force,
            contact_pressure=self.contact_pressure,
            residual_history=self.solve.history.get("residual", np.zeros(0)),
            energy_history=self.solve.history.get("energy", np.zeros(0)),
            **self._report_arrays(),
            **({} if self.model.topology.is_grid else {
                "node_panel": self.model.topology.node_panel, "node_ij": self.model.topology.node_ij,
                "panel_names": np.array(self.model.topology.names)}),
        )
        return buf.getvalue()

    def _report_arrays(self) -> dict:
        """What ``report`` draws, so that it reads the folder alone (clothsim.compression.folder):
        the sheet's faces, each node's warp and weft strain, the body near the garment and the
        scene in short."""
        from .compression.folder import body_near, scene_summary_json

        topo = self.model.topology
        wc, fc = topo.warp_count, topo.weft_count
        strain = self._f()[0]
        body_v, body_f = body_near(self.model.mold, self.state.positions)
        return {"faces": np.asarray(topo.faces, np.int64), "node_strain_warp": topo.spread(strain[:wc], "warp"),
                "node_strain_weft": topo.spread(strain[wc:wc + fc], "weft"), "body_vertices": body_v,
                "body_faces": body_f, "scene_summary": np.array(scene_summary_json(self.scene, self.model))}

    def files(self, ply_field: str = "strain") -> dict[str, bytes]:
        """Every output file's name and bytes, in writing order (summary.json last)."""
        from .compression.folder import portable_scene_yaml

        return {
            "result.npz": self.npz_bytes(),
            "history.csv": self.history_csv().encode(),
            "sheet.ply": self.colored_mesh(ply_field).export(file_type="ply"),
            "scene.yaml": portable_scene_yaml(self.scene).encode(),
            **self._compression_files(),
            "summary.json": strict_json(self.summary()).encode(),
        }

    def _compression_files(self) -> dict[str, bytes]:
        """probes.csv, profiles.csv and profiles.png when the scene asks for probes or profiles.
        A plot that cannot be drawn is a warning and is left out: it never costs the numeric files."""
        comp = self.compression()
        out: dict[str, bytes] = {}
        if comp:
            from .compression.probes import probes_csv, profile_png, profiles_csv

            if comp.get("probes"):
                out["probes.csv"] = probes_csv(comp["probes"]).encode()
            if comp.get("profiles"):
                out["profiles.csv"] = profiles_csv(comp["profiles"]).encode()
                try:
                    out["profiles.png"] = profile_png(comp["profiles"], self.scene.name)
                except Exception as exc:  # noqa: BLE001 (any plotting failure: the numbers are written)
                    import warnings

                    from .plottext import failure

                    warnings.warn(f"profiles.png not written ({failure(exc)}); the numbers are in profiles.csv",
                                  stacklevel=2)
        return out

    def save(self, out_dir: str | Path, ply_field: str = "strain") -> Path:
        """Write every output file into out_dir (created); returns out_dir.

        The set is replaced as a whole: summary.json (whose presence marks a complete run folder)
        is removed first and written last, so a folder holding an earlier result never looks
        complete with a mix of old and new files. Free space is checked before the first write;
        on any failure (a full disk included) no temporary file is left behind and
        :class:`clothsim.fileio.OutputError` or the OSError is raised."""
        from .fileio import check_free_space, check_out_dir

        out = check_out_dir(out_dir)
        files = self.files(ply_field)
        check_free_space(out, sum(len(b) for b in files.values()))
        write_result_files(out, files, known=RESULT_FILES)
        return out


def write_result_files(out: Path, files: dict[str, bytes], finished: str = "summary.json",
                       known: tuple[str, ...] = ()) -> None:
    """Write files into out, each atomically: ``finished`` removed first, then stale temporary
    files and, when the folder holds an earlier result (its ``finished`` file or one of the first
    two names of ``known``: summary.json, result.npz for a run), every name of ``known`` that ``files`` does not hold (that result's files this one
    does not write; in a folder without a result, a file of the same name is the user's and
    stays); ``finished`` written last."""
    out = Path(out)
    earlier = any((out / n).is_file() for n in (finished, *known[:2]))
    (out / finished).unlink(missing_ok=True)
    for name in known if earlier else ():
        if name not in files:
            (out / name).unlink(missing_ok=True)
    for tmp in out.glob(".*.tmp*"):  # left by a write that was killed half-way
        tmp.unlink(missing_ok=True)
    for name, data in files.items():
        if name != finished:
            atomic_write_bytes(out / name, data)
    if finished in files:
        atomic_write_bytes(out / finished, files[finished])
