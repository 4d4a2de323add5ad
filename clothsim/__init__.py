"""clothsim: stretch fabric wrapping rigid forms, the Garcia et al. (2007) spring-particle model.

Quick use::

    import clothsim
    scene = clothsim.load_scene("configs/uniaxial_strip.yaml", ["solver.C=3"])
    result = clothsim.solve(scene)            # -> clothsim.results.Result
    result.save("results/strip")
"""

__version__ = "0.1.0"


def _numba_cache_dir() -> None:
    """Point numba's on-disk cache at a directory keyed by a hash of this package's sources.

    numba invalidates a cached kernel only when *its own* file changes; a kernel that calls one in
    another module (every solver calls contact.py and kernels.py) would otherwise keep running the
    old callee after an update. Keying the directory by all sources makes any change start a fresh
    cache. Base: $NUMBA_CACHE_DIR if set, else ~/.cache/clothsim/numba (XDG_CACHE_HOME honoured)."""
    import hashlib
    import os
    from pathlib import Path

    here = Path(__file__).resolve().parent
    h = hashlib.sha1(__version__.encode())
    for f in sorted(here.rglob("*.py")):
        h.update(str(f.relative_to(here)).encode())
        h.update(f.read_bytes())
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "clothsim", "numba")
    from numba import config

    config.CACHE_DIR = os.path.join(base, h.hexdigest()[:16])


_numba_cache_dir()

from .config import Scene, SceneError, load_scene, scene_from_dict  # noqa: E402
from .simulation import Simulation, solve  # noqa: E402

__all__ = ["Scene", "SceneError", "Simulation", "load_scene", "scene_from_dict", "solve", "__version__"]
