"""Public loaders: a mold from a spec (file or primitive) or from uploaded bytes, with the
scale/rotate/translate transform."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .build import _build_mesh_mold, _vec, mold_primitive
from .readers import _read_any
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


def _apply_transform(V: np.ndarray, name: str, scale=1.0, translate=None, rotate=None):
    """Scale (a positive number or three), then rotate (degrees about x, y, z), then translate."""
    src = f"{name}: transform"
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
                    closed: bool | None = None) -> Mold:
    """Mold from file contents (an upload). ``filename`` only selects the format and names the
    mold in messages; nothing is written to disk."""
    name = str(filename)
    V, F = _read_any(bytes(data), name)
    V = _apply_transform(V, name, scale, translate, rotate)
    return _build_mesh_mold(V, F, closed, name)


def _spec_to_dict(spec: Any) -> dict:
    if hasattr(spec, "model_dump"):
        spec = spec.model_dump(exclude_none=True)
    if not isinstance(spec, Mapping):
        raise MoldError(f"mold spec must be a mapping, got {type(spec).__name__}")
    return {k: v for k, v in spec.items() if v is not None}


def load_mold(spec: Mapping | None, base_dir: Path | None = None) -> Mold | None:
    """Mold from a spec: ``None``; ``{"path": ..., "scale": s, "translate": [..], "rotate": [..],
    "closed": bool}`` (relative paths resolve against ``base_dir``); or one primitive
    ``{"sphere": {...}}``, ``{"cylinder": {...}}``, ``{"plane": {...}}``, ``{"box": {...}}``."""
    if spec is None:
        return None
    d = _spec_to_dict(spec)
    prims = [k for k in ("sphere", "cylinder", "plane", "box") if k in d]
    if "path" in d:
        extra = set(d) - {"path", "scale", "translate", "rotate", "closed"}
        if extra or prims:
            raise MoldError(f"mold spec for {d['path']}: unknown key(s) {sorted(extra | set(prims))}")
        path = Path(d["path"]).expanduser()
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        try:
            data = path.read_bytes()
        except OSError as e:
            raise MoldError(f"{path}: cannot read mold file: {e.strerror or e}") from None
        return load_mold_bytes(data, str(path), scale=d.get("scale", 1.0),
                               translate=d.get("translate"), rotate=d.get("rotate"),
                               closed=d.get("closed"))
    if len(prims) != 1 or len(d) != 1:
        raise MoldError(f"mold spec must have 'path' or exactly one of sphere/cylinder/plane/box, "
                        f"got keys {sorted(d)}")
    return mold_primitive(prims[0], d[prims[0]])
