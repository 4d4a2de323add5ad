"""One compile step: Scene -> (Model, State), the only reader of a Scene below Simulation.

Like MuJoCo's ``mj_compile``, everything a run needs that does not change while it runs is
computed once here: the lattice (:class:`~clothsim.topology.Topology`), the material tables
(CSV files and presets resolved), the mold (loaded, or taken from the cache of loaded molds),
the springs, constraint masks and prescribed positions (:func:`clothsim.grid.build_model`), and
the initial state (:func:`clothsim.initial.initial_state`). Everything below this module takes
plain records and arrays, never the Scene.
"""

from __future__ import annotations

from .config import Scene
from .grid import Model, Placement, State, build_model
from .initial import initial_state
from .topology import Topology

_NO_MOLD = object()


def scene_topology(scene: Scene) -> Topology:
    """The scene's lattice: today the ``fabric`` rectangle, one panel."""
    nx, ny = scene.fabric.divisions
    return Topology.rectangle(nx, ny, name="fabric")


def load_scene_mold(scene: Scene):
    """The scene's mold (clothsim.mold.Mold, loaded once per spec and cached) or None."""
    if scene.mold is None:
        return None
    from .mold import load_mold

    return load_mold(scene.mold, scene.base_dir)


def compile_model(scene: Scene, mold=_NO_MOLD) -> Model:
    """The constant Model of a scene; ``mold`` (a loaded Mold or None) replaces the scene's own
    mold when given (tests and the viewer's mold preview use it)."""
    fab = scene.fabric
    nx, ny = fab.divisions
    lx, ly = fab.size
    if mold is _NO_MOLD:
        mold = load_scene_mold(scene)
    return build_model(
        topology=scene_topology(scene),
        spacing=(lx / nx, ly / ny),
        origin=tuple(fab.origin),
        tables=list(scene.tables()),
        constraints=scene.constraints,
        placement=Placement(tuple(fab.origin), tuple(fab.size), scene.initial.wrap),
        shear_stiffness=None if scene.shear is None else scene.shear.stiffness,
        bending_stiffness=None if scene.bending is None else scene.bending.stiffness,
        gravity=scene.gravity,
        seams=scene.seams,
        mold=mold,
    )


def compile_state(scene: Scene, model: Model) -> State:
    """The initial State of a compiled scene (paper 3.1; see clothsim.initial)."""
    ini = scene.initial
    return initial_state(model, ini, None if ini.file is None else scene.resolve(ini.file))


def compile_scene(scene: Scene, mold=_NO_MOLD) -> tuple[Model, State]:
    """(Model, State) of a scene: the one compile step (see the module docstring)."""
    model = compile_model(scene, mold)
    return model, compile_state(scene, model)
