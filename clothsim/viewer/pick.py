"""Reading the sheet where the user clicks, and the probes' markers. No viser import: the update
loop calls these with the shown frame; everything here is tested without a browser.

- :func:`ray_hit` finds the sheet triangle a click's ray meets first and the node nearest to the
  hit point;
- :func:`node_readout` gives that node's contact pressure [mmHg], warp and weft strain and warp
  and weft tension [N/m] (the same whole-array helpers as the colour fields);
- :func:`probe_readings` reads the scene's probes (:mod:`clothsim.compression.probes`) on a frame;
- :func:`ring` is the outline of a probe's sensor disc, drawn on the mold.
"""

from __future__ import annotations

import math

import numpy as np

from ..compression.readings import Readings
from ..kernels import spring_strains_tensions
from ..labels import record_field
from ..pressure import MMHG, contact_reaction, mold_closest
from ..records import Diagnostics, ProbeReading

#: the units of a node's pressure and a probe's reading, as the field list gives them
NODE_MMHG, NODE_PA = (record_field(Diagnostics, k) for k in ("max_contact_pressure_mmhg", "max_contact_pressure_pa"))
PROBE_MMHG = record_field(ProbeReading, "pressure_mmhg")


def ray_hit(positions: np.ndarray, faces: np.ndarray, origin, direction) -> tuple[int, float, np.ndarray] | None:
    """The first sheet triangle the ray ``origin + t direction`` (t > 0) meets: (nearest node of
    that triangle to the hit point, t, hit point [m] (3,)), or None if the ray misses the sheet.
    positions (N, 3) [m], faces (F, 3) node indices (Moller-Trumbore, both sides)."""
    o = np.asarray(origin, float)
    d = np.asarray(direction, float)
    n = np.linalg.norm(d)
    if not (np.isfinite(o).all() and np.isfinite(d).all() and n > 0) or len(faces) == 0:
        return None
    d = d / n
    X = np.asarray(positions, float)
    a, b, c = X[faces[:, 0]], X[faces[:, 1]], X[faces[:, 2]]
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    tol = 1e-9
    hit = ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t > 0)
    if not hit.any():
        return None
    k = int(np.argmin(np.where(hit, t, np.inf)))
    point = o + t[k] * d
    corners = faces[k]
    node = int(corners[np.argmin(np.linalg.norm(X[corners] - point, axis=1))])
    return node, float(t[k]), point


def node_readout(model, positions: np.ndarray, in_contact: np.ndarray, node: int) -> dict:
    """One node's values: node, panel, (i, j), position [m], in_contact, pressure_mmhg (contact
    pressure; inf for a gathered node carrying a line load), strain_warp, strain_weft
    (engineering strain, mean of the node's springs of that family), tension_warp, tension_weft
    [N/m] (spring force over its width, mean of the node's springs)."""
    topo = model.topology
    pressure = contact_reaction(model, positions, in_contact)[1]
    wc, fc = model.warp_count, model.weft_count
    S = wc + fc
    strain = np.empty(S)
    force = np.empty(S)
    nodes, rest, width, table, *tabs = model.spring_args()
    spring_strains_tensions(positions, nodes[:S], rest[:S], width[:S], table[:S], *tabs, strain, force)
    t = np.divide(force, width[:S], out=np.zeros(S), where=width[:S] > 0)
    panel = int(topo.node_panel[node]) if getattr(topo, "node_panel", None) is not None else 0
    i, j = (int(x) for x in topo.node_ij[node])
    return {
        "node": int(node), "panel": topo.names[panel] if getattr(topo, "names", None) else str(panel),
        "ij": (i, j), "position": [float(x) for x in positions[node]],
        "in_contact": bool(in_contact[node]),
        "pressure_mmhg": float(pressure[node]) / MMHG,
        "strain_warp": float(topo.spread(strain[:wc], "warp")[node]),
        "strain_weft": float(topo.spread(strain[wc:S], "weft")[node]),
        "tension_warp": float(topo.spread(t[:wc], "warp")[node]),
        "tension_weft": float(topo.spread(t[wc:S], "weft")[node]),
    }


def readout_text(r: dict | None) -> str:
    """The markdown of a node's readout (None: how to get one)."""
    if r is None:
        return "<small>Click the sheet to read a node's pressure, strains and tensions.</small>"
    p = r["pressure_mmhg"]
    pt = "line load (gathered)" if not math.isfinite(p) else f"{p:.2f} {NODE_MMHG.unit} ({p * MMHG:.4g} {NODE_PA.unit})"
    x, y, z = r["position"]
    return (f"**node {r['node']}** ({r['panel']}, i {r['ij'][0]}, j {r['ij'][1]}) at "
            f"({x:.4g}, {y:.4g}, {z:.4g}) m · {'in contact' if r['in_contact'] else 'free'}  \n"
            f"pressure **{pt if r['in_contact'] or p else '0 (free)'}**  \n"
            f"strain warp {r['strain_warp']:+.4f}, weft {r['strain_weft']:+.4f} · "
            f"tension warp {r['tension_warp']:.4g} N/m, weft {r['tension_weft']:.4g} N/m")


def probe_readings(scene, model, positions: np.ndarray, in_contact: np.ndarray) -> list[dict]:
    """The scene's probes read on a frame (clothsim.compression.readings.Readings), with their
    classes and each disc's mold normal (unit (3,), for drawing); [] without probes."""
    if not scene.probes:
        return []

    pressure = contact_reaction(model, positions, in_contact)[1]
    out = Readings.of(scene).evaluate(model, positions, in_contact, pressure).get("probes", [])
    for r in out:
        c = np.asarray(r["center"] if r.get("center") is not None else r["point"], float)
        nrm = np.asarray(r["point"], float) - c
        if model.mold is not None and np.linalg.norm(nrm) < 1e-9:
            cp, _ = mold_closest(model.mold, (c + 1e-4 * np.array([0.0, 0.0, 1.0]))[None])
            nrm = c + 1e-4 * np.array([0.0, 0.0, 1.0]) - cp[0]
        n = np.linalg.norm(nrm)
        r["normal"] = [float(x) for x in (nrm / n if n > 0 else np.array([0.0, 0.0, 1.0]))]
    return out


def probe_label(r: dict) -> str:
    """'ankle 21.3 mmHg' (plus 'off contact' or the contact fraction when partly covered)."""
    if not r["on_contact"]:
        return f"{r['name']}: off contact"
    txt = f"{r['name']} {r['pressure_mmhg']:.1f} {PROBE_MMHG.unit}"
    if r["contact_fraction"] < 0.999:
        txt += f" ({r['contact_fraction']:.0%} covered)"
    return txt


def ring(center, normal, radius: float, n: int = 48) -> np.ndarray:
    """(n, 2, 3) float32 line segments of the circle of ``radius`` [m] round ``center`` in the
    plane normal to ``normal`` (a probe's sensor disc)."""
    c = np.asarray(center, float)
    nz = np.asarray(normal, float)
    nz = nz / max(np.linalg.norm(nz), 1e-300)
    ref = np.array([1.0, 0.0, 0.0]) if abs(nz[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(nz, ref)
    u /= np.linalg.norm(u)
    v = np.cross(nz, u)
    a = np.linspace(0.0, 2 * math.pi, n + 1)
    P = c + radius * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
    return np.stack([P[:-1], P[1:]], axis=1).astype(np.float32)
