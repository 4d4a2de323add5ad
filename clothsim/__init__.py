"""clothsim: stretch fabric wrapping rigid forms, the Garcia et al. (2007) spring-particle model.

Quick use::

    import clothsim
    scene = clothsim.load_scene("configs/uniaxial_strip.yaml", ["solver.C=3"])
    result = clothsim.solve(scene)            # -> clothsim.results.Result
    result.save("results/strip")
"""

import hashlib
import os
import tempfile
from pathlib import Path

from .version import __version__


def _numba_cache_dir() -> None:
    """Point numba's on-disk cache at a directory keyed by a hash of this package's sources.

    numba invalidates a cached kernel only when *its own* file changes; a kernel that calls one in
    another module (every solver calls contact.py and kernels.py) would otherwise keep running the
    old callee after an update. Keying the directory by all sources makes any change start a fresh
    cache. Base: $NUMBA_CACHE_DIR if set, else ~/.cache/clothsim/numba (XDG_CACHE_HOME honoured); if
    that cannot be written, the system's temporary folder; if neither, numba's own default."""
    here = Path(__file__).resolve().parent
    h = hashlib.sha1(__version__.encode())
    for f in sorted(here.rglob("*.py")):
        h.update(str(f.relative_to(here)).encode())
        h.update(f.read_bytes())
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "clothsim", "numba")
    from numba import config  # (not at the top: ``config`` would shadow clothsim.config here)

    for root in (base, os.path.join(tempfile.gettempdir(), f"clothsim-numba-{os.getuid() if hasattr(os, 'getuid') else 0}")):
        path = os.path.join(root, h.hexdigest()[:16])
        try:  # numba refuses to compile a cache=True kernel whose cache folder it cannot write
            os.makedirs(path, exist_ok=True)
            with tempfile.NamedTemporaryFile(dir=path):
                pass
        except OSError:
            continue
        config.CACHE_DIR = path
        return


_numba_cache_dir()


def kernels_cached() -> bool:
    """Whether numba's on-disk cache for these sources (see _numba_cache_dir) holds compiled
    kernels (index files, ``*.nbi``): False on the first start after an install or an update,
    when the kernels are compiled (about a minute), True once a run has cached them."""
    from numba import config

    root = getattr(config, "CACHE_DIR", None)
    if not root or not os.path.isdir(root):
        return False
    for _dir, _subdirs, files in os.walk(root):
        if any(f.endswith(".nbi") for f in files):
            return True
    return False

from .config import Scene, SceneError, load_scene, scene_from_dict  # noqa: E402
from .simulation import Simulation, solve  # noqa: E402

__all__ = ["Scene", "SceneError", "Simulation", "load_scene", "scene_from_dict", "solve", "__version__"]
