"""The lattice builder: a scene's panels, constraints, seams and loads -> a :class:`Model`.

A :class:`~clothsim.topology.Topology` says which nodes exist and which warp and weft springs
join them; :func:`clothsim.lattice.lattice_springs` gives them their rest lengths, tables and
tributary widths and adds the optional shear and bending families (built only when a scene asks
for them: an unused term costs nothing); this module adds the seams and the constraint masks and
places the panels. Springs are stored warp first, then weft (in the topology's order), then
shear, bending and seams. A seam of unequal node counts is not a spring: it is a set of seam
elements (``Model.seam_nodes``, built by :func:`clothsim.selection.arc_elements`; none when no
seam needs them). Grid sequencing's coarse models come from the same spring builder on the
stride-2 lattice (:func:`clothsim.lattice.coarsen_model`).

The types it builds (Model, State, the placements, the spring families) live in
:mod:`clothsim.model`; they are imported here under their old names for code outside the package.
The only reader of the scene file above this module is :mod:`clothsim.compile`.
"""

from __future__ import annotations

import math

import numpy as np

from .lattice import _adjacency, coarsen_model, lattice_springs, seam_adjacency  # noqa: F401
from .material import Table, TablePack
from .model import Model, PanelBuild, Placement, Placements, SeamInfo, SpringFamily, State  # noqa: F401
from .selection import SelectionError, arc_elements, seam_pairs, seam_sides, select_nodes
from .topology import Topology

# the spring families by their former names, for code outside the package (inside it:
# clothsim.model.SpringFamily)
FAMILY_WARP, FAMILY_WEFT, FAMILY_SHEAR = SpringFamily.WARP, SpringFamily.WEFT, SpringFamily.SHEAR
FAMILY_BEND_WARP, FAMILY_BEND_WEFT, FAMILY_SEAM = SpringFamily.BEND_WARP, SpringFamily.BEND_WEFT, SpringFamily.SEAM

#: rest length of a seam spring, relative to the smaller grid spacing. A seam is a zero-length
#: linear spring (force k * gap); the kernels' spring model (force = T(l/l0 - 1) * w) represents it
#: exactly with the table T(s) = 1 + s [N/m] (compression allowed) and width w = k * l0, since
#: then force = k * l and energy = k (l^2 - l0^2) / 2. l0 only has to be positive; keeping it
#: tiny makes the paper's "elongation" l - l0 of a seam its gap.
SEAM_REST_RATIO = 1e-6


def rotation_matrix(degrees) -> np.ndarray:
    """(3, 3): rotate about x, then y, then z by the given angles [deg]."""
    ax, ay, az = (math.radians(float(d)) for d in degrees)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx



def build_model(*, panels: list, constraints=(), shear_stiffness: float | None = None,
                bending_stiffness: float | None = None, gravity=None, seams=(), mold=None) -> Model:
    """The constant arrays of a lattice of panels (see the module docstring).

    panels: PanelBuild records (geometry, tables, placement, z), one per panel, in order;
    constraints: objects with ``nodes`` (a selector), ``axes``, ``stretch`` and ``displacement``
    [m]; shear_stiffness / bending_stiffness [N/m] or None; gravity: an object with
    ``areal_density`` [kg/m^2], ``g`` [m/s^2] and ``direction``, or None; seams: objects with
    ``a``, ``b``, ``reverse`` and ``stiffness`` [N/m^2] (None = the default); mold: a loaded Mold
    or None. A selector that selects nothing valid raises SelectionError naming its field
    (``constraints.N.nodes: ...``, ``seams.N.a: ...``)."""
    geoms = [p.geometry for p in panels]
    topology = Topology.from_masks([g.mask for g in geoms], [g.name for g in geoms],
                                   outlines=[g.outline_lattice for g in geoms])
    n = topology.node_count
    rest = np.empty((n, 3))
    tables: list = []
    table_ids = []

    def table_id(t):
        for k, u in enumerate(tables):
            if u is t:
                return k
        tables.append(t)
        return len(tables) - 1

    starts = np.searchsorted(topology.node_panel, np.arange(len(panels) + 1))
    for p, pb in enumerate(panels):
        g = pb.geometry
        # each node at its material point (the lattice point, or a row end on the outline)
        rest[starts[p]:starts[p + 1], :2] = g.to_plane(g.material_ij(topology.node_ij[starts[p]:starts[p + 1]]))
        rest[starts[p]:starts[p + 1], 2] = pb.z
        table_ids.append((table_id(pb.warp_table), table_id(pb.weft_table)))
    shear_tid = bend_tid = None
    if shear_stiffness is not None:
        tables.append(Table.linear(shear_stiffness, compression=True))
        shear_tid = len(tables) - 1
    if bending_stiffness is not None:
        tables.append(Table.linear(bending_stiffness, compression=True))
        bend_tid = len(tables) - 1
    sp = lattice_springs(topology, geoms, table_ids, shear_table=shear_tid, bend_table=bend_tid)

    seam_infos = []
    el_nodes, el_weight, el_k = [], [], []
    if seams:
        tables.append(Table(np.array([0.0, 1.0]), np.array([1.0, 2.0]), compression=True))
        tid = len(tables) - 1
        h_min = min(min(g.spacing) for g in geoms)
        l0 = SEAM_REST_RATIO * h_min
        slope = max(float(np.max(np.diff(t.tension) / np.diff(t.strain)))
                    for pb in panels for t in (pb.warp_table, pb.weft_table))
        n_springs = sum(x.shape[0] for x in sp.nodes)
        n_elements = 0
        for n_seam, seam in enumerate(seams):
            k_line = seam.stiffness if seam.stiffness is not None else 1000.0 * max(slope, 1e-300) / h_min
            try:
                a_all, b_all, _ = seam_sides(seam, topology)
                if a_all.size != b_all.size:
                    dense_is_a, enodes, eweight, share, la, lb = arc_elements(rest[a_all], rest[b_all])
                else:
                    a, b, share, (sa, sb) = seam_pairs(seam, topology)
            except SelectionError as exc:
                raise SelectionError(f"seams.{n_seam}.{exc}") from None
            arc = [float(np.linalg.norm(np.diff(rest[x], axis=0), axis=1).sum()) for x in (a_all, b_all)]
            if a_all.size != b_all.size:
                # one element per node of the denser side (selection.arc_elements)
                both = np.concatenate([a_all, b_all] if dense_is_a else [b_all, a_all])
                el_nodes.append(both[enodes])
                el_weight.append(eweight)
                el_k.append(k_line * share * 0.5 * (la + lb))  # [N/m] per element
                seam_infos.append(SeamInfo(arc[0], arc[1], np.zeros(0, np.int64),
                                           np.arange(n_elements, n_elements + share.size)))
                n_elements += share.size
                continue
            side = [sa, sb]
            for k, (nodes, s) in enumerate(((a, sa), (b, sb))):
                if isinstance(s, tuple):  # (panel, direction 0/1): the lattice spacing
                    side[k] = geoms[s[0]].spacing[s[1]]
                else:  # along an outline edge: the mean distance between its nodes
                    d = np.linalg.norm(np.diff(rest[s], axis=0), axis=1)
                    side[k] = float(d.mean()) if d.size else h_min
            # the pair's share of the seam length [m], averaged over the two sides
            length = share * 0.5 * (side[0] + side[1])
            k = k_line * length  # [N/m] per pair
            sp.add(a, b, l0, k * l0, tid, SpringFamily.SEAM)
            seam_infos.append(SeamInfo(arc[0], arc[1], np.arange(n_springs, n_springs + a.size), np.zeros(0, np.int64)))
            n_springs += a.size
    seam_extra = {}
    if el_nodes:
        # rows padded to the widest element (repeating the first node, weight 0)
        K = max(x.shape[1] for x in el_nodes)
        el_nodes = [np.concatenate([x, np.repeat(x[:, :1], K - x.shape[1], 1)], 1) for x in el_nodes]
        el_weight = [np.concatenate([x, np.zeros((x.shape[0], K - x.shape[1]))], 1) for x in el_weight]
        seam_extra = dict(seam_nodes=np.ascontiguousarray(np.concatenate(el_nodes), np.int64),
                          seam_weight=np.ascontiguousarray(np.concatenate(el_weight)),
                          seam_stiffness=np.ascontiguousarray(np.concatenate(el_k)))

    spring_nodes, rest_len, width, table, family = sp.arrays()
    ptr, adj_node, adj_spring = _adjacency(n, spring_nodes)
    node_area = np.concatenate([g.node_frac[g.mask] * (g.spacing[0] * g.spacing[1]) for g in geoms])

    ext = np.zeros((n, 3))
    if gravity is not None:
        d = np.asarray(gravity.direction, float)
        d = d / np.linalg.norm(d)
        ext[:] = (gravity.areal_density * gravity.g * node_area)[:, None] * d[None, :]

    fixed = np.zeros((n, 3), bool)
    flat = rest.copy()
    shift = np.zeros((n, 3))
    # stretch is about each panel's centre, along its grain and across it
    centre = np.empty((n, 2))
    grain = np.empty((n, 2))
    for p, pb in enumerate(panels):
        pl, g = pb.placement, pb.geometry
        gr = np.asarray(g.grain, float)
        c = np.array([pl.origin[0], pl.origin[1]]) + pl.size[0] / 2 * gr + pl.size[1] / 2 * np.array([-gr[1], gr[0]])
        centre[starts[p]:starts[p + 1]] = c
        grain[starts[p]:starts[p + 1]] = gr
    for n_c, c in enumerate(constraints):
        try:
            m = select_nodes(c.nodes, topology)
        except SelectionError as exc:
            raise SelectionError(f"constraints.{n_c}.nodes: {exc}") from None
        for ax in c.axes:
            fixed[m, "xyz".index(ax)] = True
        if c.stretch is not None:
            s = np.array([c.stretch, c.stretch] if isinstance(c.stretch, (int, float)) else c.stretch, float)
            # scaled along the grain and across it (on an x grain: (flat - centre) * s, exactly)
            d = flat[m, :2] - centre[m]
            g = grain[m]
            gp = np.stack([-g[:, 1], g[:, 0]], 1)
            u = (d * g).sum(1) * s[0]
            v = (d * gp).sum(1) * s[1]
            flat[m, :2] = centre[m] + u[:, None] * g + v[:, None] * gp
        if c.displacement is not None:
            shift[m] += np.asarray(c.displacement, float)
    # stretch acts in the panels' own planes, then each panel is placed (flat, rigidly moved or
    # wrapped), then displacements act in space
    placement = Placements(tuple((int(starts[p]), int(starts[p + 1]), pb.placement) for p, pb in enumerate(panels)))
    prescribed = placement.apply(flat) + shift
    spacing = np.array([g.spacing for g in geoms], float)

    return Model(
        node_count=n,
        topology=topology,
        rest_positions=rest,
        spring_nodes=spring_nodes,
        spring_rest_length=rest_len,
        spring_width=width,
        spring_table=table,
        spring_family=family,
        tables=TablePack.from_tables(tables),
        table_list=tuple(tables),
        fixed_axes=fixed,
        prescribed_positions=np.ascontiguousarray(prescribed),
        prescribed_flat=flat,
        external_force=ext,
        node_area=node_area,
        adj_ptr=ptr,
        adj_node=adj_node,
        adj_spring=adj_spring,
        mold=mold,
        spacing=(float(spacing[:, 0].min()), float(spacing[:, 1].min())),
        placement=placement,
        panel_spacing=spacing,
        seams=tuple(seam_infos),
        **seam_extra,
    )
