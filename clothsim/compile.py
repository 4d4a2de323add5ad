"""One compile step: Scene -> (Model, State), the only reader of a Scene below Simulation.

Like MuJoCo's ``mj_compile``, everything a run needs that does not change while it runs is
computed once here: the lattice (:class:`~clothsim.topology.Topology`), the material tables
(CSV files and presets resolved), the mold (loaded, or taken from the cache of loaded molds),
the springs, constraint masks and prescribed positions (:func:`clothsim.grid.build_model`), and
the initial state (:func:`clothsim.initial.initial_state`). Everything below this module takes
plain records and arrays, never the Scene.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from pathlib import Path

import numpy as np

from . import patterns
from .compression.folder import portable_scene, portable_scene_yaml, scene_brief
from .compression.readings import Readings
from .config import Scene
from .errors import SceneError
from .grid import build_model, rotation_matrix
from .hullwrap import hull_wrap
from .initial import initial_state
from .model import Model, PanelBuild, Placement, RunInputs, State
from .mold import load_mold, mold_reach_warning, mold_scale_warning
from .panels import PanelError, panel_geometry, rectangle_geometry
from .patterns import DEFAULT_TOLERANCE, PatternError
from .selection import SelectionError, select_nodes
from .sizing import sized, sized_spacing

_NO_MOLD = object()


def scene_panels(scene: Scene, mold=None) -> list[PanelBuild]:
    """The scene's panels as the builder takes them: the ``fabric`` rectangle (one panel named
    ``fabric``), or each of ``panels`` cut to its outline (clothsim.panels). ``mold`` (a loaded
    Mold or None) is what ``wrap_hull`` placements wrap round."""
    fab = scene.fabric
    # the outlines sized by the scene's garment field (clothsim.sizing): before any lattice is cut
    design, outlines, grains = sized(scene, *design_outlines(scene), mold)
    if not scene.panels:
        nx, ny = fab.divisions
        lx, ly = (float(x) for x in np.ptp(outlines[0], axis=0))
        warp, weft = scene.tables()
        geom = rectangle_geometry("fabric", nx, ny, lx / nx, ly / ny, origin=fab.origin[:2])
        hull = None
        if scene.initial.wrap_hull is not None:
            box = np.array([[0.0, 0.0], [lx, 0.0], [lx, ly], [0.0, ly]])
            hull = hull_wrap(scene.initial.wrap_hull, mold, box, ly / ny, "initial.wrap_hull")
        return [PanelBuild(geom, warp, weft, Placement(tuple(fab.origin), (lx, ly), scene.initial.wrap,
                                                       hull=hull),
                           z=fab.origin[2])]
    for key in ("wrap", "wrap_hull"):
        if getattr(scene.initial, key) is not None:
            raise SceneError(f"initial.{key}: with panels, give each panel its placement (panels.N.placement.{key})")
    out = []
    default = {}
    for n, panel in enumerate(scene.panels):
        outline, grain = outlines[n], grains[n]
        spacing = panel.spacing if outline is design[n] else sized_spacing(panel.spacing, design[n], outline, grain)
        try:
            geom = panel_geometry(panel.name, outline, grain, spacing, panel.divisions, panel.row_ends)
        except PanelError as exc:
            raise SceneError(f"panels.{n}: {exc}") from None
        thick = panel.thickness if panel.thickness is not None else fab.thickness
        tables = []
        for name in ("warp", "weft"):
            spec = getattr(panel, name)
            if spec is None and panel.thickness is None:
                if name not in default:
                    default[name] = scene.material_table(getattr(fab, name), fab.thickness, f"fabric.{name}")
                tables.append(default[name])  # the same Table object: one table id for all panels
            else:
                spec = spec if spec is not None else getattr(fab, name)
                tables.append(scene.material_table(spec, thick, f"panels.{n}.{name}"))
        g = geom.grain
        uv = geom.outline @ np.stack([g, [-g[1], g[0]]], 1)
        size = tuple(float(x) for x in uv.max(axis=0) - uv.min(axis=0))
        origin = (float(geom.origin[0]), float(geom.origin[1]), 0.0)
        pl = panel.placement
        if pl.wrap_hull is not None:
            uv = (geom.outline - geom.origin) @ np.stack([g, [-g[1], g[0]]], 1)
            hull = hull_wrap(pl.wrap_hull, mold, uv, geom.spacing[1], f"panels.{n}.placement.wrap_hull")
            placement = Placement(origin, size, None, grain=tuple(g), hull=hull)
        elif pl.wrap is not None:
            placement = Placement(origin, size, pl.wrap, grain=tuple(g))
        elif pl.transform is not None:
            placement = Placement(origin, size, None, grain=tuple(g), rotation=rotation_matrix(pl.transform.rotate),
                                  translation=np.asarray(pl.transform.translate, float))
        else:
            placement = Placement(origin, size, None, grain=tuple(g))
        out.append(PanelBuild(geom, tables[0], tables[1], placement, z=0.0))
    return out


def design_outlines(scene: Scene) -> tuple[list, list]:
    """(outlines, grains) of the scene's design pattern, before clothsim.sizing sizes it: each
    panel's outline (a pattern file's piece read) and grain, or the ``fabric`` sheet's rectangle."""
    if not scene.panels:
        lx, ly = scene.fabric.size
        return [np.array([[0.0, 0.0], [lx, 0.0], [lx, ly], [0.0, ly]])], [(1.0, 0.0)]
    outlines, grains = [], []
    for n, panel in enumerate(scene.panels):
        outline, grain = panel.outline, panel.grain
        if panel.pattern is not None:
            piece = _pattern_piece(scene, n)
            outline = piece.outline
            if grain is None and piece.grain is not None:
                grain = tuple(piece.grain)
        outlines.append(np.asarray(outline, float))
        grains.append(grain if grain is not None else (1.0, 0.0))
    return outlines, grains


def _pattern_piece(scene: Scene, n: int):
    """The piece panels.n.pattern names, read from its file (clothsim.patterns)."""
    ref = scene.panels[n].pattern
    where = f"panels.{n}.pattern"
    try:
        # only the piece the scene uses must be valid (another one, broken, is left out with a warning)
        pieces = patterns.read_pattern(scene.resolve(ref.file), units=ref.units, piece=ref.piece,
                              tolerance=ref.tolerance if ref.tolerance is not None else DEFAULT_TOLERANCE)
    except PatternError as exc:
        raise SceneError(f"{where}: {exc}") from None
    names = [p.name for p in pieces]
    if ref.piece is None:
        if len(pieces) == 1:
            return pieces[0]
        raise SceneError(f"{where}.piece: the file has {len(pieces)} pieces ({', '.join(names)}): name one")
    for p in pieces:
        if p.name == ref.piece:
            return p
    raise SceneError(f"{where}.piece: no piece '{ref.piece}' in {ref.file} (pieces: {', '.join(names)})")


def load_scene_mold(scene: Scene):
    """The scene's mold (clothsim.mold.Mold, loaded once per spec and cached) or None."""
    if scene.mold is None:
        return None

    return load_mold(scene.mold, scene.base_dir)


#: memory a run needs per lattice node [bytes], measured: 501^2 nodes (251k) peaked at 999 MB
#: RSS in the Newton benchmark, about 200 MB of it the interpreter, numba and the libraries
#: (3.2 kB a node); the line smoother's renumbered copy of the matrix (newton.linalg._Transposed)
#: adds about 0.56 kB a node since, still within this
BYTES_PER_NODE = 4000
BASE_BYTES = 250e6


def estimated_nodes(scene: Scene) -> int:
    """Lattice nodes of a scene, before anything is built (an upper bound for cut panels: their
    bounding lattices)."""
    if not scene.panels:
        nx, ny = scene.fabric.divisions
        return (nx + 1) * (ny + 1)
    total = 0
    for p in scene.panels:
        if p.divisions is not None:
            total += (p.divisions[0] + 1) * (p.divisions[1] + 1)
        elif p.outline is not None:
            pts = np.asarray(p.outline, float)
            ext = np.ptp(pts, axis=0)
            dx, dy = (p.spacing, p.spacing) if np.isscalar(p.spacing) else p.spacing
            total += int((ext.max() / dx + 2) * (ext.max() / dy + 2))
    return total


def _cgroup_paths() -> dict[str, str]:
    """The process's cgroup paths from /proc/self/cgroup: {"": v2 path, "memory": v1 path}."""
    out = {}
    try:
        for line in Path("/proc/self/cgroup").read_text().splitlines():
            _, ctrl, path = line.split(":", 2)
            if ctrl == "" or "memory" in ctrl.split(","):
                out["" if ctrl == "" else "memory"] = path.strip("/")
    except (OSError, ValueError):
        pass
    return out


def _cgroup_headroom() -> float | None:
    """Bytes the process's memory cgroup still allows (its limit minus its current use, less the
    page cache it can reclaim), or None when there is no limit: cgroup v2 ``memory.max`` /
    ``memory.current`` (``inactive_file`` of ``memory.stat`` reclaimable), else cgroup v1
    ``memory.limit_in_bytes`` / ``memory.usage_in_bytes`` (``total_inactive_file``). The
    process's own cgroup (/proc/self/cgroup) is read where it is mounted, else the mount's root."""
    own = _cgroup_paths()
    for root, key, lim, cur, cache in (("/sys/fs/cgroup", "", "memory.max", "memory.current", "inactive_file"),
                                       ("/sys/fs/cgroup/memory", "memory", "memory.limit_in_bytes",
                                        "memory.usage_in_bytes", "total_inactive_file")):
        for base in dict.fromkeys(([str(Path(root) / own[key])] if own.get(key) else []) + [root]):
            try:
                text = (Path(base) / lim).read_text().strip()
            except OSError:
                continue
            if text == "max" or not text.isdigit() or int(text) >= 1 << 60:  # v1's "no limit" is ~2^63
                return None
            try:
                used = int((Path(base) / cur).read_text().strip())
            except (OSError, ValueError):
                used = 0
            try:
                for line in (Path(base) / "memory.stat").read_text().splitlines():
                    name, _, value = line.partition(" ")
                    if name == cache:
                        used = max(used - int(value), 0)
                        break
            except (OSError, ValueError):
                pass
            return float(int(text) - used)
    return None


def _rlimit_headroom() -> float | None:
    """Bytes of address space ``ulimit -v`` (RLIMIT_AS) still allows the process (the limit
    minus its current virtual size), or None when unlimited."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY:
            return None
        import psutil

        return float(soft - psutil.Process().memory_info().vms)
    except Exception:  # noqa: BLE001  (no estimate possible)
        return None


def memory_budget() -> tuple[float, str] | None:
    """The memory [bytes] a new model may use and what bounds it: the smallest of the machine's
    available memory (psutil), the address space ``ulimit -v`` still allows and the memory
    cgroup's headroom. None when none of them can be read."""
    budgets = []
    try:
        import psutil

        budgets.append((float(psutil.virtual_memory().available), "available on the machine"))
    except Exception:  # noqa: BLE001
        pass
    rl = _rlimit_headroom()
    if rl is not None:
        budgets.append((max(rl, 0.0), "left under the address-space limit (ulimit -v)"))
    cg = _cgroup_headroom()
    if cg is not None:
        budgets.append((max(cg, 0.0), "left under the memory cgroup's limit"))
    return min(budgets) if budgets else None


def check_memory(scene: Scene, available: float | None = None) -> None:
    """Refuse a scene whose lattice would not fit in the memory available (SceneError naming the
    estimate and the limit), before any of it is built: a 1999 x 1999 sheet needs about 16 GB.
    The budget is :func:`memory_budget` (``available`` [bytes] replaces it)."""
    n = estimated_nodes(scene)
    need = BASE_BYTES + BYTES_PER_NODE * n
    what = "available"
    if available is None:
        budget = memory_budget()
        if budget is None:  # no estimate possible: do not refuse
            return
        available, what = budget
    if need > available:
        field = "panels" if scene.panels else "fabric.divisions"
        raise SceneError(f"{field}: {n:,} nodes need about {need / 1e9:.1f} GB of memory; "
                         f"{available / 1e9:.1f} GB are {what} (use fewer divisions)")


def _located(fn):
    """Errors about a field that the start-up finds after validation (a seam side on a panel's
    lattice, a node range beyond it, a pattern's piece) name the file and line or the ``--set``
    that set the field, as validation's do (``Scene.locate``)."""
    @functools.wraps(fn)
    def located(scene, *args, **kwargs):
        try:
            return fn(scene, *args, **kwargs)
        except SceneError as exc:
            raise SceneError(scene.locate(str(exc))) from None

    return located


@_located
def compile_model(scene: Scene, mold=_NO_MOLD) -> Model:
    """The constant Model of a scene; ``mold`` (a loaded Mold or None) replaces the scene's own
    mold when given (tests and the viewer's mold preview use it)."""
    check_memory(scene)
    warn = mold is _NO_MOLD
    if warn:
        mold = load_scene_mold(scene)
    panels = scene_panels(scene, mold)
    if warn:
        _warn_scale(mold, panels)
    seams, constraints, regions = _named_vertices(scene)
    try:
        model = build_model(
            panels=panels,
            constraints=constraints,
            shear_stiffness=None if scene.shear is None else scene.shear.stiffness,
            bending_stiffness=None if scene.bending is None else scene.bending.stiffness,
            gravity=scene.gravity,
            seams=seams,
            mold=mold,
        )
    except SelectionError as exc:
        raise SceneError(str(exc)) from None
    mu = scene.mold.friction if scene.mold is not None else None
    if mu and mold is not None:
        # Coulomb friction with the mold (clothsim.friction): only a scene that asks pays for it
        model = dataclasses.replace(model, friction_mu=float(mu))
    if regions and mold is not None:
        model = dataclasses.replace(model, friction_mu_nodes=_region_mu(model, regions))
    return model


def _region_mu(model: Model, regions) -> np.ndarray | None:
    """(N,) each node's Coulomb coefficient: ``model.friction_mu``, then each friction region's
    on the nodes it selects (a later region over an earlier one); None when that is
    ``friction_mu`` everywhere (the scene then pays nothing for its regions)."""
    mu = np.full(model.node_count, float(model.friction_mu))
    for n, r in enumerate(regions):
        try:
            mask = select_nodes(r.nodes, model.topology, what="friction_regions")
        except SelectionError as exc:
            raise SceneError(f"mold.friction_regions.{n}.nodes: {exc}") from None
        if not mask.any():
            raise SceneError(f"mold.friction_regions.{n}.nodes: selects no nodes")
        mu[mask] = float(r.friction)
    return None if (mu == model.friction_mu).all() else mu


def _named_vertices(scene: Scene):
    """The scene's seams, constraints and friction regions with every outline vertex given by
    name (a pattern piece's notch, ``edge: [notch1, notch2]``) replaced by its index in the
    panel's outline (clothsim.patterns.Piece.vertex_names). Nothing is read unless a selector
    names a vertex."""
    regions = scene.mold.regions if scene.mold is not None else []
    sels = [(f"seams.{n}.{k}", s, k) for n, s in enumerate(scene.seams) for k in ("a", "b")]
    sels += [(f"constraints.{n}.nodes", c, "nodes") for n, c in enumerate(scene.constraints)]
    sels += [(f"mold.friction_regions.{n}.nodes", r, "nodes") for n, r in enumerate(regions)]
    named = [(w, o, k) for w, o, k in sels
             if getattr(getattr(o, k), "edge", None) is not None and any(isinstance(v, str) for v in getattr(o, k).edge)]
    if not named:
        return scene.seams, scene.constraints, regions
    by_panel = {p.name: n for n, p in enumerate(scene.panels)}
    cache: dict = {}
    fixed: dict = {}
    for where, obj, key in named:
        sel = getattr(obj, key)
        n = by_panel.get(sel.panel)
        if n is None:
            continue  # the builder names the unknown panel
        if n not in cache:
            cache[n] = dict(_pattern_piece(scene, n).vertex_names) if scene.panels[n].pattern is not None else {}
        names = cache[n]
        edge = []
        for v in sel.edge:
            if isinstance(v, str):
                if v not in names:
                    known = (f"its named vertices: {', '.join(names)}" if names else
                             "it has no named vertices (names come from a pattern file's notches)")
                    raise SceneError(f"{where}.edge: no vertex '{v}' on panel '{sel.panel}'; {known}")
                v = names[v]
            edge.append(v)
        fixed[id(obj), key] = sel.model_copy(update={"edge": tuple(edge)})

    def resolved(obj, keys):
        upd = {k: fixed[id(obj), k] for k in keys if (id(obj), k) in fixed}
        return obj.model_copy(update=upd) if upd else obj

    return ([resolved(s, ("a", "b")) for s in scene.seams], [resolved(c, ("nodes",)) for c in scene.constraints],
            [resolved(r, ("nodes",)) for r in regions])


def _warn_scale(mold, panels) -> None:
    """Warn (``mold: ... millimetres?``) when the mold is 100x larger or smaller than the sheet."""
    if mold is None:
        return

    msg = mold_scale_warning(mold, max(max(p.placement.size) for p in panels))
    if msg:
        warnings.warn(f"mold: {msg}", UserWarning, stacklevel=3)


@_located
def compile_state(scene: Scene, model: Model) -> State:
    """The initial State of a compiled scene (paper 3.1; see clothsim.initial). Warns
    (``mold: no node of the sheet can reach the mold ...``) when the mold is out of the sheet's
    reach (clothsim.mold.mold_reach_warning)."""
    ini = scene.initial
    state = initial_state(model, ini, None if ini.file is None else scene.resolve(ini.file))
    _warn_reach(model, state)
    return state


def _warn_reach(model: Model, state: State) -> None:
    """Warn when no node, where it starts or where the constraints take it, is within the
    sheet's size of the mold."""
    if model.mold is None:
        return

    pts = np.concatenate([state.positions, model.prescribed_positions[model.fixed_axes.any(axis=1)]])
    # a strided sample of at most 20,000 points (lattice neighbours are consecutive, so it misses
    # the nearest point by a few spacings at most, far below the sheet's size)
    pts = pts[::max(1, -(-len(pts) // 20000))]
    msg = mold_reach_warning(model.mold, pts, max(model.placement.size))
    if msg:
        warnings.warn(f"mold: {msg}", UserWarning, stacklevel=3)


def compile_scene(scene: Scene, mold=_NO_MOLD) -> tuple[Model, State]:
    """(Model, State) of a scene: the one compile step (see the module docstring)."""
    model = compile_model(scene, mold)
    return model, compile_state(scene, model)


def run_inputs(scene: Scene) -> RunInputs:
    """What the run's Result reports of ``scene`` (its name, C and e, the resolved scene's YAML,
    the probes, profiles and classes to read): the Result reads these, never the scene. The
    scene's files are read and hashed once, for both the YAML and the brief."""

    portable = portable_scene(scene)
    return RunInputs(name=scene.name, C=float(scene.solver.C), e=float(scene.solver.e),
                     scene_yaml=portable_scene_yaml(scene, portable), readings=Readings.of(scene),
                     scene_brief=scene_brief(scene, portable))
