"""Public loaders: a mold from a spec (file or primitive) or from uploaded bytes, with the
scale/rotate/translate transform, and the small cache of loaded mesh molds."""

from __future__ import annotations

import os
import threading
import warnings
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from ..config import MeshMoldSpec, validate_mold_spec
from .build import SCAN_BEND_SHARE, _build_mesh_mold, _vec, auto_surface, bend_share, mold_primitive, with_surface
from .readers import _read_any, mold_file_status, read_mold_file
from .record import Mold, MoldError


# --------------------------------------------------------------------------------------------
# transforms and public loaders
# --------------------------------------------------------------------------------------------


def _rotation_xyz(deg) -> np.ndarray:
    """Rotation about x, then y, then z (angles in degrees): R = Rz @ Ry @ Rx."""
    rx, ry, rz = np.radians(np.asarray(deg, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


#: the file's up axis -> the rotation that makes it clothsim's +z (a Y-up file turned +90 degrees
#: about x: (x, y, z) -> (x, -z, y), the convention of Blender's glTF import)
UP_ROTATIONS = {"z": np.eye(3), "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])}


def _apply_transform(V: np.ndarray, name: str, scale=1.0, translate=None, rotate=None, up=None):
    """Up axis first (``up``: 'y' turns a Y-up file to Z-up; 'z' or None: unchanged), then scale
    (a positive number or three), then rotate (degrees about x, y, z), then translate.
    V (n, 3) [file units] -> (n, 3) [m]."""
    src = f"{name}: transform"
    if up not in (None, "z", "y"):
        raise MoldError(f"{src}: 'up' must be 'y' or 'z', got {str(up)[:20]!r}")
    if up == "y":
        V = V @ UP_ROTATIONS["y"].T
    s = np.asarray(1.0 if scale is None else scale, dtype=np.float64).reshape(-1)
    if s.size not in (1, 3) or not np.isfinite(s).all() or not (s > 0).all():
        raise MoldError(f"{src}: 'scale' must be a positive number (or three), got {scale!r}")
    V = V * s
    if rotate is not None:
        V = V @ _rotation_xyz(_vec({"rotate": rotate}, "rotate", src)).T
    if translate is not None:
        V = V + _vec({"translate": translate}, "translate", src)
    return V


def load_mold_bytes(data: bytes, filename: str, *, scale=1.0, translate=None, rotate=None,
                    closed: bool | None = None, up: str | None = None, max_triangles: int | None = None,
                    progress=None) -> Mold:
    """Mold from file contents (an upload). ``filename`` only selects the format and names the
    mold in messages; nothing is written to disk. ``up``: the file's up axis ('y' or 'z', see
    :func:`_apply_transform`).

    ``max_triangles``: refuse (MoldError) a mesh with more triangles, once read and before the
    costly build. ``progress(fraction, stage)``: told how far the parse is (0..1) between stages
    and during the build; it may raise to abandon the parse (the exception propagates)."""
    name = str(filename)
    if progress is not None:
        progress(0.0, "reading the file")
    V, F = _read_any(bytes(data) if not isinstance(data, bytes) else data, name)
    if max_triangles is not None and len(F) > max_triangles:
        raise MoldError(f"{name}: {len(F):,} triangles, over the limit of {max_triangles:,} for an "
                        f"upload (simplify the mesh, or name the file in the scene)")
    V = _apply_transform(V, name, scale, translate, rotate, up)
    return _build_mesh_mold(V, F, closed, name, progress)


def _cache_key(spec: MeshMoldSpec, base_dir: Path | None):
    """(resolved path, cache key) of a mesh mold spec (file checked by mold_file_status)."""
    path = Path(spec.path).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    st = mold_file_status(path)
    key = (os.path.realpath(path), st.st_size, st.st_mtime_ns, st.st_ino, st.st_dev,
           _freeze(spec.scale), _freeze(spec.translate), _freeze(spec.rotate), spec.closed, spec.up)
    return path, key


def cache_mold(spec: Any, mold: Mold, base_dir: Path | None = None) -> None:
    """Remember ``mold`` as what :func:`load_mold` of the mesh spec ``spec`` builds (the viewer
    parses an upload once, off its update loop, and stores the file: loading the stored file's
    spec then costs a cache look-up, not a second parse). The caller vouches that ``mold`` is
    the file's content with the spec's transform."""
    try:
        typed = validate_mold_spec(spec)
    except ValueError as e:
        raise MoldError(str(e)) from None
    if not isinstance(typed, MeshMoldSpec):
        return
    _path, key = _cache_key(typed, base_dir)
    with _cache_lock:
        _cache[key] = (mold, [])
        _cache.move_to_end(key)
        while len(_cache) > MOLD_CACHE_SIZE:
            _cache.popitem(last=False)


#: how many loaded mesh molds :func:`load_mold` keeps (least recently used dropped first)
MOLD_CACHE_SIZE = 4

_cache: OrderedDict = OrderedDict()   # key -> (Mold, warnings raised while building it)
_cache_lock = threading.Lock()
_cache_stats = {"hits": 0, "misses": 0}


# (id(cached mesh), surface asked for (None: the default), smoothing) -> (that mesh, the mold on
# that surface): the smooth surface of a mesh is built once per cached mesh, not once per load
_surfaces: OrderedDict = OrderedDict()
# _surface_key -> the lock held while that surface is built (``_on_surface``)
_building: dict = {}


def clear_mold_cache() -> None:
    """Forget every cached mold (and the hit/miss counts)."""
    with _cache_lock:
        _cache.clear()
        _surfaces.clear()
        _cache_stats.update(hits=0, misses=0)


def _surface_key(mesh: Mold, typed: MeshMoldSpec):
    return (id(mesh), typed.surface, typed.smoothing)


def _on_surface(mesh: Mold, typed: MeshMoldSpec) -> Mold:
    """The cached mesh on the spec's contact surface: faceted as it is; smooth, or the default
    (:func:`clothsim.mold.build.auto_surface`: smooth for a scan), built once per cached mesh and
    kept beside it (dropped when the mesh leaves the cache)."""
    if typed.surface == "faceted":
        return with_surface(mesh, "faceted")
    key = _surface_key(mesh, typed)
    with _cache_lock:
        build = _building.setdefault(key, threading.Lock())
    # one build per key: a second thread asking for the same surface meanwhile (the viewer's
    # worker beside a run) waits for the first's and takes it from the cache
    try:
        with build:
            with _cache_lock:
                hit = _surfaces.get(key)
                if hit is not None and hit[0] is mesh:
                    _surfaces.move_to_end(key)
                    return hit[1]
            if typed.surface is None:
                mold = auto_surface(mesh)[0]
            else:
                mold = with_surface(mesh, typed.surface, typed.smoothing)
            _remember(mesh, key, mold)
            return mold
    finally:
        with _cache_lock:
            if _building.get(key) is build:
                del _building[key]  # later loads find it in the cache (or build it again if it left)


def _remember(mesh: Mold, key, mold: Mold) -> None:
    """Keep ``mold`` (``mesh`` on a surface) beside the cached mesh, under ``key``; drop those
    whose mesh left the cache."""
    with _cache_lock:
        live = {id(h[0]): h[0] for h in _cache.values()}
        for k in [k for k, h in _surfaces.items() if live.get(k[0]) is not h[0]]:
            del _surfaces[k]  # its mesh left the cache
        if live.get(id(mesh)) is mesh:
            _surfaces[key] = (mesh, mold)


def mold_cache_info() -> dict:
    """``{"hits", "misses", "entries", "size"}`` of the loaded-mold cache."""
    with _cache_lock:
        return {**_cache_stats, "entries": len(_cache), "size": MOLD_CACHE_SIZE}


def _freeze(v: Any):
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    return tuple(float(x) for x in np.asarray(v, dtype=np.float64).reshape(-1))


def mold_cached(spec: Any, base_dir: Path | None = None) -> bool:
    """True if :func:`load_mold` of ``spec`` would cost nothing worth waiting for: a primitive, a
    mesh file already in the cache (with its smooth surface built too when the spec asks for it
    or, left out, when the mesh is a scan), or a spec that is refused at once (its error is left
    to :func:`load_mold`). For a cached mesh that is no scan, it keeps the default (faceted)
    surface's mold it decided on, for the load that follows."""
    try:
        typed = validate_mold_spec(spec)
        if not isinstance(typed, MeshMoldSpec):
            return True
        _path, key = _cache_key(typed, base_dir)
    except (ValueError, MoldError):
        return True
    with _cache_lock:
        hit = _cache.get(key)
        if hit is None:
            return False
        if typed.surface == "faceted":
            return True
        # the smooth surface (stated, or the default's for a scan) is built too: cached as well?
        got = _surfaces.get(_surface_key(hit[0], typed))
        if got is not None and got[0] is hit[0]:
            return True
        mesh = hit[0]
    if typed.surface is not None:
        return False
    # the default on a mesh that is no scan is its faceted self: only the bends to count (kept,
    # so that the load that follows does not count them again)
    share = bend_share(mesh)
    if share > SCAN_BEND_SHARE:
        return False
    _remember(mesh, _surface_key(mesh, typed), auto_surface(mesh, share)[0])
    return True


def check_mold(spec: Any, base_dir: Path | None = None) -> None:
    """Every check of :func:`load_mold` (the spec, the file, the mesh) without building the
    contact surface (a scan's smooth surface costs about a second): for validating a scene
    before it runs. Raises MoldError."""
    if spec is None:
        return
    try:
        typed = validate_mold_spec(spec)
    except ValueError as e:
        raise MoldError(str(e)) from None
    if isinstance(typed, MeshMoldSpec):
        _load_mesh_file(typed, base_dir)
    else:
        mold_primitive(typed.kind, getattr(typed, typed.kind).model_dump())


def _load_mesh_file(spec: MeshMoldSpec, base_dir: Path | None, progress=None) -> Mold:
    """A mesh mold from its file, through the cache: the same resolved file (same size,
    modification time and inode) with the same scale/transform/closed returns the Mold built
    before, without reading the file or rebuilding the BVH. The warnings its build raised are
    raised again on every load."""
    path, key = _cache_key(spec, base_dir)
    with _cache_lock:
        hit = _cache.get(key)
        if hit is not None:
            _cache.move_to_end(key)
            _cache_stats["hits"] += 1
    if hit is None:
        data = read_mold_file(path)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            mold = load_mold_bytes(data, str(path), scale=1.0 if spec.scale is None else spec.scale,
                                   translate=spec.translate, rotate=spec.rotate, closed=spec.closed,
                                   up=spec.up, progress=progress)
        hit = (mold, [(w.message, w.category) for w in caught])
        with _cache_lock:
            _cache_stats["misses"] += 1
            _cache[key] = hit
            _cache.move_to_end(key)
            while len(_cache) > MOLD_CACHE_SIZE:
                _cache.popitem(last=False)
    for message, category in hit[1]:
        warnings.warn(message, category, stacklevel=3)
    return hit[0]


def load_mold(spec: Any, base_dir: Path | None = None, progress=None) -> Mold | None:
    """Mold from a spec: ``None``; a typed :data:`clothsim.config.MoldSpec`; or the same as a
    plain mapping (checked by the same model): ``{"path": ..., "scale": s, "translate": [..],
    "rotate": [..], "closed": bool, "up": "y" | "z", "surface": "faceted" | "smooth" (omitted:
    :func:`clothsim.mold.build.auto_surface`, smooth for a scan), "smoothing": r}`` (relative
    paths resolve against ``base_dir``; the cached mesh is shared by both surfaces), or one
    primitive ``{"sphere": {...}}``, ``{"cylinder": {...}}``, ``{"plane": {...}}``,
    ``{"box": {...}}``. Mesh files are cached (see :func:`_load_mesh_file`); ``progress`` as in
    :func:`load_mold_bytes` (told only when a mesh file is parsed). Raises MoldError."""
    if spec is None:
        return None
    try:
        typed = validate_mold_spec(spec)
    except ValueError as e:
        raise MoldError(str(e)) from None
    if isinstance(typed, MeshMoldSpec):
        return _on_surface(_load_mesh_file(typed, base_dir, progress), typed)
    return mold_primitive(typed.kind, getattr(typed, typed.kind).model_dump())
