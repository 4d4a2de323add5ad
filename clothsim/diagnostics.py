"""Diagnostics of a sheet's equilibrium that are not results themselves but make a degenerate one
visible: slack springs and undetermined nodes, rows that gathered along a direction nothing holds
(:func:`gathered_rows`), the narrowest weft extent (:func:`sheet_health`), each seam's ease and gap
(:func:`seam_report`) and the mold's contact surface (:func:`surface_report`). Read by
``clothsim.results.Result.diagnostics`` (the :class:`~clothsim.records.Diagnostics` record), the
CLI's warnings and the viewer's status line."""

from __future__ import annotations

import math

import numpy as np

from .kernels import spring_strains_tensions
from .mold import MOLD_MESH, MOLD_SMOOTH


def seam_report(model, positions) -> dict:
    """Per seam (scene order) its sides' rest arc lengths [m], its ease (how much longer the
    longer side is [%]: the longer side gathers onto the shorter) and its widest gap [m] at
    positions (N,3) (the longest seam spring, or the farthest sewn node from the point of the
    other side it is sewn to): {"seams": [...], "max_seam_gap_m": the widest over all seams}."""
    gaps = model.seam_gaps(positions)
    rows = [{"a_length_m": info.a_length, "b_length_m": info.b_length, "ease_pct": info.ease,
             "max_gap_m": float(g.max()) if g.size else 0.0} for info, g in zip(model.seams, gaps)]
    return {"seams": rows, "max_seam_gap_m": max(r["max_gap_m"] for r in rows)}


def undetermined_mask(model, force, in_contact) -> np.ndarray:
    """(N,) bool: free nodes (not fixed on every axis) held only by slack springs (force <= 0)
    and off the mold: their position is not unique."""
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
        "undetermined_nodes": int(undetermined_mask(model, force, in_contact).sum()),
        "min_weft_extent_ratio": ratio,
        "gathered_rows": rows,
        "gathered_rows_direction": direction,
        "gathered_rows_min_strain": low,
    }


def surface_report(mold) -> dict:
    """The contact surface of a mesh mold: {"mold_surface": "faceted" | "smooth"} and, when the
    scene left it to the default, "mold_surface_reason" (why :func:`clothsim.mold.build.auto_surface`
    chose it); {} for a primitive mold."""
    if mold.kind not in (MOLD_MESH, MOLD_SMOOTH):
        return {}
    out = {"mold_surface": "smooth" if mold.kind == MOLD_SMOOTH else "faceted"}
    if mold.surface_note:
        out["mold_surface_reason"] = "default: " + mold.surface_note
    return out
