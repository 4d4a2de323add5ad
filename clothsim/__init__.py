"""clothsim: stretch fabric wrapping rigid forms, the Garcia et al. (2007) spring-particle model.

Quick use::

    import clothsim
    scene = clothsim.load_scene("configs/uniaxial_strip.yaml", ["solver.C=3"])
    result = clothsim.solve(scene)            # -> clothsim.results.Result
    result.save("results/strip")
"""

__version__ = "0.1.0"

from .config import Scene, SceneError, load_scene, scene_from_dict  # noqa: E402
from .simulation import Simulation, solve  # noqa: E402

__all__ = ["Scene", "SceneError", "Simulation", "load_scene", "scene_from_dict", "solve", "__version__"]
