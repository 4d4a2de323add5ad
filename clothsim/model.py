"""The core types: :class:`Model` (a scene's constant arrays), :class:`State` (what a solver
changes), the spring families, the panel placements and the other plain records between the
builder and the solvers (MuJoCo's model/data split).

The builder (:mod:`clothsim.grid`, with :mod:`clothsim.lattice` for the spring arrays and the
stride-2 coarse model) makes these; solvers, results and the viewer read them. This module reads
no scene and imports no builder or solver: solvers import their types from here. Every field
says its shape, dtype and unit (N nodes, S springs, P panels, Q seam elements of K nodes each).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import TYPE_CHECKING, Protocol

import numpy as np

from .contact import friction_forces_energy
from .kernels import seam_forces_and_energy, seam_gaps
from .material import Table, TablePack
from .topology import Topology

if TYPE_CHECKING:
    from .friction import FrictionLag
    from .hullwrap import HullWrap
    from .compression.readings import Readings
    from .mold.record import Mold
    from .panels import PanelGeometry


class SpringFamily(IntEnum):
    """What a spring is (``Model.spring_family``, stored as int8). Springs are stored warp
    first, then weft (in the topology's order), then shear, bending and seams."""

    #: along the warp (grain, the lattice's i direction)
    WARP = 0
    #: along the weft (across the grain, j)
    WEFT = 1
    #: a cell's diagonals (the scene's ``shear:``)
    SHEAR = 2
    #: skip-one springs (i, j)-(i+2, j) along the warp (the scene's ``bending:``)
    BEND_WARP = 3
    #: skip-one springs (i, j)-(i, j+2) along the weft
    BEND_WEFT = 4
    #: zero-length seam springs (sides of equal node counts)
    SEAM = 5


#: the lattice's own springs (warp and weft)
LATTICE_FAMILIES = (SpringFamily.WARP, SpringFamily.WEFT)
#: the bending springs
BENDING_FAMILIES = (SpringFamily.BEND_WARP, SpringFamily.BEND_WEFT)


class CylinderWrap(Protocol):
    """A cylinder a panel starts rolled onto (the scene's ``wrap`` record): warp round the axis,
    weft along it, centred on ``center``."""

    #: (3,) [m] a point of the axis, where the panel's centre line goes
    center: tuple[float, float, float]
    #: (3,) the cylinder's axis (need not be unit)
    axis: tuple[float, float, float]
    #: [m] the cylinder's radius
    radius: float
    #: [deg] where the panel's left edge sits round the axis
    start_angle: float


@dataclass(frozen=True)
class Placement:
    """Where one panel's flat lattice goes in space at the start: rolled onto a cylinder
    (``wrap``), laid round the hull of a mold's slab (``hull``), moved rigidly (``rotation``,
    ``translation``) or left where it is."""

    #: (3,) [m] the panel's reference corner in its plane (the ``fabric`` sheet's origin)
    origin: tuple = (0.0, 0.0, 0.0)
    #: (2,) [m] the panel's extent along and across the grain
    size: tuple = (0.0, 0.0)
    #: the cylinder the panel is rolled onto (warp round the axis, weft along it), or None
    wrap: CylinderWrap | None = None
    #: (2,) unit vector: the panel's warp direction in its plane (None: x)
    grain: tuple | None = None
    #: (3, 3) float64 rigid rotation (used when wrap is None; None: the identity)
    rotation: np.ndarray | None = None
    #: (3,) float64 [m] rigid translation after the rotation (None with rotation None)
    translation: np.ndarray | None = None
    #: the panel laid round the hull of a mold's slab, or None
    hull: HullWrap | None = None

    def apply(self, flat: np.ndarray) -> np.ndarray:
        """Points of the flat panel (N, 3) [m] -> their placement in space (N, 3) [m]."""
        if self.hull is not None:
            g = np.asarray(self.grain if self.grain is not None else (1.0, 0.0), float)
            d = flat[:, :2] - np.asarray(self.origin[:2])
            return self.hull.place(d @ g, d @ np.array([-g[1], g[0]]), flat[:, 2] - self.origin[2])
        w = self.wrap
        if w is None:
            if self.rotation is None:
                return flat.copy()
            return flat @ np.asarray(self.rotation).T + np.asarray(self.translation)
        a = np.asarray(w.axis, float)
        a = a / np.linalg.norm(a)
        t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = t - a * (t @ a)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        if self.grain is None:
            u = flat[:, 0] - self.origin[0]
            v = flat[:, 1] - self.origin[1] - self.size[1] / 2
        else:
            g = np.asarray(self.grain, float)
            d = flat[:, :2] - np.asarray(self.origin[:2])
            u = d @ g
            v = d @ np.array([-g[1], g[0]]) - self.size[1] / 2
        r = w.radius + (flat[:, 2] - self.origin[2])
        theta = math.radians(w.start_angle) + u / w.radius
        c = np.asarray(w.center, float)
        return c + r[:, None] * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2) + v[:, None] * a


@dataclass(frozen=True)
class Placements:
    """The placement of every panel over its node range (a panel's nodes are consecutive)."""

    #: ((start, stop, Placement), ...): one per panel, in node order
    parts: tuple[tuple[int, int, Placement], ...] = ()

    def apply(self, flat: np.ndarray) -> np.ndarray:
        """Flat lattice points (N, 3) [m] -> their placement in space (N, 3) [m]."""
        if len(self.parts) == 1:
            return self.parts[0][2].apply(flat)
        out = np.empty_like(flat)
        for a, b, pl in self.parts:
            out[a:b] = pl.apply(flat[a:b])
        return out

    @property
    def identity(self) -> bool:
        """True when every panel stays where its flat lattice is (no wrap, no rigid motion)."""
        return all(pl.wrap is None and pl.rotation is None and pl.hull is None for _, _, pl in self.parts)

    @property
    def size(self) -> tuple:
        """The largest panel extent (2,) [m]."""
        return tuple(np.max([pl.size for _, _, pl in self.parts], axis=0)) if self.parts else (0.0, 0.0)


@dataclass(frozen=True)
class PanelBuild:
    """One panel as the builder (:func:`clothsim.grid.build_model`) takes it."""

    #: the panel's lattice: mask, spacing, band and cell fractions, outline
    geometry: PanelGeometry
    #: the warp springs' tension table [N/m] against engineering strain
    warp_table: Table
    #: the weft springs' tension table [N/m] against engineering strain
    weft_table: Table
    #: where its flat lattice goes in space at the start
    placement: Placement
    #: [m] the height of its flat lattice
    z: float = 0.0


@dataclass(frozen=True)
class SeamInfo:
    """One seam of a model, for reports."""

    #: [m] the rest arc length of side a
    a_length: float
    #: [m] the rest arc length of side b
    b_length: float
    #: (s,) int64 indices of its zero-length springs (sides of equal node counts) into the springs
    springs: np.ndarray
    #: (q,) int64 indices of its seam elements (unequal counts) into ``Model.seam_nodes``
    elements: np.ndarray

    @property
    def ease(self) -> float:
        """How much longer the longer side is than the shorter [%]."""
        lo, hi = sorted((self.a_length, self.b_length))
        return 100.0 * (hi - lo) / lo if lo > 0 else math.inf


@dataclass(frozen=True)
class RunInputs:
    """What a run's :class:`~clothsim.results.Result` reports of its scene, taken from the scene by
    ``clothsim.compile.run_inputs`` (a Result never reads the scene itself)."""

    #: the scene's name (summary.json ``name``)
    name: str
    #: the paper's step divisor C [-] (solver.C)
    C: float
    #: the residual limit e [N] (solver.e)
    e: float
    #: the scene as YAML text with its files named without their paths, each file's SHA-256 in
    #: a header (the result folder's scene.yaml; clothsim.compression.folder.portable_scene_yaml)
    scene_yaml: str
    #: the probes, profiles and classes to read on the equilibrium (empty: none)
    readings: Readings
    #: the scene in short for the report (clothsim.compression.folder.scene_brief: garment, body,
    #: friction, stages, solver, files by name and SHA-256, standards)
    scene_brief: dict


def _empty(shape, dtype=float):
    return field(default_factory=lambda: np.zeros(shape, dtype))


@dataclass(frozen=True)
class Model:
    """Constant arrays of a scene (MuJoCo's model/data split: the State changes, this does not).

    Spring force = tension [N/m] (the spring's table at its engineering strain l/l0 - 1) x its
    tributary width [m]. Seam elements join seams of unequal node counts (clothsim.kernels
    ``seam_forces_and_energy``): each element's first node is the node it sews (weight 1), its
    gap a fixed linear combination of node positions, energy k |gap|^2 / 2."""

    #: N, the number of nodes
    node_count: int
    #: the lattice: nodes, warp/weft pairs, cells, faces (:class:`~clothsim.topology.Topology`)
    topology: Topology
    #: (N, 3) float64 [m] node positions in the flat sheet (before placement)
    rest_positions: np.ndarray
    #: (S, 2) int64 the two nodes of each spring
    spring_nodes: np.ndarray
    #: (S,) float64 [m] rest lengths
    spring_rest_length: np.ndarray
    #: (S,) float64 [m] tributary widths (force = tension x width)
    spring_width: np.ndarray
    #: (S,) int64 each spring's index into ``tables``
    spring_table: np.ndarray
    #: (S,) int8 each spring's :class:`SpringFamily`
    spring_family: np.ndarray
    #: the tension tables [N/m] packed for the kernels (x, y, cum, start, compression)
    tables: TablePack
    #: the same tables as :class:`~clothsim.material.Table` records, in id order
    table_list: tuple[Table, ...]
    #: (N, 3) bool the constrained coordinates
    fixed_axes: np.ndarray
    #: (N, 3) float64 [m] the constrained coordinates' values (others unused)
    prescribed_positions: np.ndarray
    #: (N, 3) float64 [N] constant external force (gravity; zeros when off)
    external_force: np.ndarray
    #: (N,) float64 [m^2] each node's tributary area (a quarter of each adjacent cell)
    node_area: np.ndarray
    #: (N + 1,) int64 node adjacency in CSR form: node k's entries are [adj_ptr[k], adj_ptr[k+1])
    adj_ptr: np.ndarray
    #: (2S,) int64 the neighbour node of each adjacency entry
    adj_node: np.ndarray
    #: (2S,) int64 the spring of each adjacency entry
    adj_spring: np.ndarray
    #: the rigid mold the sheet rests on, or None
    mold: Mold | None = None
    #: (dx, dy) [m] the lattice spacing (the smallest over panels)
    spacing: tuple[float, float] = (0.0, 0.0)
    #: (N, 3) float64 [m] the prescribed positions in the flat sheet's own coordinates, before
    #: placement and displacement (stretch only; used to build the initial guess), or None
    prescribed_flat: np.ndarray | None = None
    #: where each panel's flat lattice starts in space
    placement: Placements = Placements()
    #: (P, 2) float64 [m] each panel's spacing (dx, dy), or None
    panel_spacing: np.ndarray | None = None
    #: (Q, K) int64 the nodes of each seam element (Q = 0 when the scene has none)
    seam_nodes: np.ndarray = _empty((0, 1), np.int64)
    #: (Q, K) float64 the gap's coefficients of those nodes
    seam_weight: np.ndarray = _empty((0, 1))
    #: (Q,) float64 [N/m] each seam element's stiffness
    seam_stiffness: np.ndarray = _empty(0)
    #: one :class:`SeamInfo` per scene seam, in scene order
    seams: tuple[SeamInfo, ...] = ()
    #: the scene's Coulomb coefficient between fabric and mold (``mold.friction``; 0: frictionless);
    #: with ``friction_mu_nodes`` set it is only the summary's ``mu`` (replace both to change the
    #: model's friction)
    friction_mu: float = 0.0
    #: (N,) float64 [-] each node's Coulomb coefficient when the garment has friction regions
    #: (``mold.friction_regions``: a grip band); None: every node has ``friction_mu``
    friction_mu_nodes: np.ndarray | None = None
    #: the frozen friction of the load step being solved (set by the frictional load steps;
    #: None: no friction force)
    friction: FrictionLag | None = None

    @property
    def has_friction(self) -> bool:
        """Whether the fabric has friction against the mold at some node (and there is a mold)."""
        if self.mold is None:
            return False
        if self.friction_mu_nodes is not None:
            return bool((self.friction_mu_nodes > 0).any())
        return self.friction_mu > 0

    def friction_mu_of(self, nodes: np.ndarray) -> np.ndarray:
        """(m,) float64 [-]: the Coulomb coefficients of ``nodes`` (m,) (node numbers)."""
        if self.friction_mu_nodes is None:
            return np.full(len(nodes), float(self.friction_mu))
        return np.ascontiguousarray(self.friction_mu_nodes[nodes], float)

    @property
    def seam_count(self) -> int:
        """Q: seam elements (0 unless a seam joins sides of unequal node counts)."""
        return int(self.seam_nodes.shape[0])

    def seam_args(self) -> tuple:
        """The seam element arrays in the order the kernels take them."""
        return self.seam_nodes, self.seam_weight, self.seam_stiffness

    def add_seam_forces(self, pos: np.ndarray, out: np.ndarray) -> float:
        """Adds the seam elements' forces [N] into out (N,3); returns their energy [J] (0 and
        nothing done when there are none)."""
        if not self.seam_nodes.shape[0]:
            return 0.0

        return seam_forces_and_energy(pos, self.seam_nodes, self.seam_weight, self.seam_stiffness, out)

    def add_friction_forces(self, pos: np.ndarray, out: np.ndarray) -> float:
        """Adds the frozen friction's forces [N] into out (N,3); returns its dissipation
        potential [J] (0 and nothing done without friction)."""
        f = self.friction
        if f is None:
            return 0.0

        return friction_forces_energy(pos, f.nodes, f.anchor, f.normal, f.weight, f.eps, out)

    def seam_gaps(self, pos: np.ndarray) -> list:
        """Per seam (in scene order) its gaps [m] at positions pos (N,3): the zero-length
        springs' lengths, and for a seam of unequal counts each element's |g| (the distance from
        its node to the point of the other side it is sewn to)."""
        g = np.empty(self.seam_count)
        if g.size:
            seam_gaps(pos, self.seam_nodes, self.seam_weight, g)
        out = []
        for info in self.seams:
            ab = self.spring_nodes[info.springs]
            out.append(np.concatenate([np.linalg.norm(pos[ab[:, 1]] - pos[ab[:, 0]], axis=1), g[info.elements]]))
        return out

    def seam_points(self, pos: np.ndarray) -> np.ndarray:
        """(P, 2, 3) [m]: the two ends of every seam spring, and every seam element's node and
        the point of the other side it is sewn to (x - g), for drawing."""
        ab = self.spring_nodes[self.spring_family == SpringFamily.SEAM]
        a = [pos[ab[:, 0]]]
        b = [pos[ab[:, 1]]]
        if self.seam_count:
            x = pos[self.seam_nodes[:, 0]]
            a.append(x)
            b.append(x - (self.seam_weight[:, :, None] * pos[self.seam_nodes]).sum(axis=1))
        return np.stack([np.concatenate(a), np.concatenate(b)], axis=1)

    def families(self) -> set[SpringFamily]:
        """The spring families the model has."""
        return {SpringFamily(f) for f in np.unique(self.spring_family).tolist()}

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(nx+1, ny+1) of a one-panel full rectangle (see Topology.grid_shape)."""
        return self.topology.grid_shape

    @property
    def warp_count(self) -> int:
        """Warp springs, stored first."""
        return self.topology.warp_count

    @property
    def weft_count(self) -> int:
        """Weft springs, stored after the warp springs."""
        return self.topology.weft_count

    @property
    def spring_count(self) -> int:
        return int(self.spring_nodes.shape[0])

    def spring_args(self) -> tuple:
        """The spring arrays in the order the kernels take them."""
        t = self.tables
        return (self.spring_nodes, self.spring_rest_length, self.spring_width, self.spring_table,
                t.x, t.y, t.cum, t.start, t.compression)

    def adjacency_args(self) -> tuple:
        t = self.tables
        return (self.adj_ptr, self.adj_node, self.adj_spring, self.spring_rest_length,
                self.spring_width, self.spring_table, t.x, t.y, t.cum, t.start, t.compression)


@dataclass
class State:
    """What a solver changes."""

    #: (N, 3) float64 [m] node positions
    positions: np.ndarray
    #: (N,) bool the nodes in contact with the mold
    in_contact: np.ndarray
    #: iterations done so far
    iteration: int = 0

    def copy(self) -> State:
        return State(self.positions.copy(), self.in_contact.copy(), self.iteration)
