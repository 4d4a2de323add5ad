"""What a result folder carries so that ``report`` needs nothing else (issue 31 item 5).

A result folder is moved and mailed: the report must not re-read the scene's files (the body mesh,
the material tables) nor recompile the model. :meth:`clothsim.results.Result.npz_bytes` adds to
``result.npz``:

- ``faces`` (F, 3): the sheet's display triangles (node ids in the order of ``positions``
  flattened to (N, 3));
- ``node_strain_warp``, ``node_strain_weft`` (N,): each node's mean warp / weft spring strain;
- ``body_vertices`` (V, 3) float32 [m], ``body_faces`` (F, 3) int32: the mold's surface near
  the garment (:func:`body_near`: its triangles within the garment's bounding box plus
  BODY_MARGIN_M, merged onto a coarser grid when more than BODY_MAX_FACES);
- ``scene_summary``: a short description of the scene as JSON text (:func:`scene_summary`: the
  garment, the body, the materials' curves, friction, stages, solver, the standards' class
  ranges and every file the scene read, by name and SHA-256, never by its path).

``scene.yaml`` is written by :func:`portable_scene_yaml`: the scene as run with every file
reference reduced to the file's name, and a header listing each file's SHA-256, so the folder
holds no path of the machine that ran it and the run can be repeated with the same files put
beside it (the hashes say whether they are the same files).
"""

from __future__ import annotations

import hashlib
import json
import os
from datetime import datetime, timezone
from pathlib import Path, PurePath

import numpy as np
import yaml

from ..model import SpringFamily
from ..version import __version__
from .standards import STANDARDS, standard

#: the body is kept this far [m] beyond the garment's bounding box (the pictures' context)
BODY_MARGIN_M = 0.03
#: the most body triangles kept (a dense scan's region is merged onto a coarser grid)
BODY_MAX_FACES = 20_000


def _cluster(V: np.ndarray, F: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: vertices in one grid cell of side ``cell`` [m] merge into their mean;
    triangles that collapse are dropped, duplicates kept once."""
    key = np.floor((V - V.min(0)) / cell).astype(np.int64)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    n = int(inv.max()) + 1 if inv.size else 0
    W = np.zeros((n, 3))
    np.add.at(W, inv, V)
    W /= np.maximum(np.bincount(inv, minlength=n), 1)[:, None]
    G = inv[F]
    ok = (G[:, 0] != G[:, 1]) & (G[:, 1] != G[:, 2]) & (G[:, 0] != G[:, 2])
    G = G[ok]
    if len(G):
        G = G[np.unique(np.sort(G, axis=1), axis=0, return_index=True)[1]]
    return W, G


def _overlaps(V, F, lo, hi) -> np.ndarray:
    """(F,) bool: the triangle's bounding box meets the box [lo, hi]."""
    T = V[F]
    return ((T.min(1) <= hi) & (T.max(1) >= lo)).all(axis=1)


def _split4(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle split in four at its edges' midpoints (shared midpoints merged)."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    key, inv = np.unique(np.sort(E, axis=1), axis=0, return_inverse=True)
    mid = len(V) + inv.reshape(3, -1).T            # (F, 3): the midpoints of edges 01, 12, 20
    V = np.concatenate([V, 0.5 * (V[key[:, 0]] + V[key[:, 1]])])
    a, b, c = F.T
    m01, m12, m20 = mid.T
    F = np.concatenate([np.c_[a, m01, m20], np.c_[m01, b, m12], np.c_[m20, m12, c], np.c_[m01, m12, m20]])
    return V, F


def body_near(mold, positions: np.ndarray, margin: float = BODY_MARGIN_M,
              max_faces: int = BODY_MAX_FACES) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float32 [m], faces (F, 3) int32): the mold's display surface
    (``Mold.surface_mesh``: a mesh mold's own triangles, a primitive tessellated) where a
    triangle has a corner within the garment's bounding box grown by ``margin``; more than
    ``max_faces`` triangles are merged onto a grid (vertex clustering) until they fit. No mold:
    empty arrays."""
    empty = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
    if mold is None:
        return empty
    P = np.asarray(positions, float).reshape(-1, 3)
    P = P[np.isfinite(P).all(axis=1)]
    if not len(P):
        return empty
    lo, hi = P.min(0) - margin, P.max(0) + margin
    V, F = mold.surface_mesh(resolution=96, extent=float(2.0 * (hi - lo).max()))
    V, F = np.asarray(V, float), np.asarray(F, np.int64)
    F = F[_overlaps(V, F, lo, hi)]
    # a primitive's long triangles (a cylinder's sides run its whole length) are split in four
    # until they are short against the box: the crop then follows the box
    target = float((hi - lo).max()) / 12.0
    for _ in range(8):
        if not len(F) or 4 * len(F) > 4 * max_faces:
            break
        T = V[F]
        if np.linalg.norm(T - np.roll(T, 1, axis=1), axis=2).max() <= target:
            break
        V, F = _split4(V, F)
        F = F[_overlaps(V, F, lo, hi)]
    inside = ((V >= lo) & (V <= hi)).all(axis=1)
    F = F[inside[F].any(axis=1)]
    if not len(F):
        return empty
    used, F = np.unique(F, return_inverse=True)
    V, F = V[used], F.reshape(-1, 3)
    cell = float((hi - lo).max()) / 400.0
    while len(F) > max_faces:
        V, F = _cluster(V, F, cell)
        cell *= 1.5
    return V.astype(np.float32), F.astype(np.int32)


# ----------------------------------------------------------------------------- file references


def _refs(d: dict):
    """(holder dict, key, field name) of every file reference in a scene dict (to_dict)."""
    for holder, where in [(d.get("fabric") or {}, "fabric")] + [
            (p, f"panels.{k}") for k, p in enumerate(d.get("panels") or [])]:
        for name in ("warp", "weft"):
            m = holder.get(name) or {}
            if m.get("csv"):
                yield m, "csv", f"{where}.{name}.csv"
    for k, p in enumerate(d.get("panels") or []):
        if (p.get("pattern") or {}).get("file"):
            yield p["pattern"], "file", f"panels.{k}.pattern.file"
    if (d.get("initial") or {}).get("file"):
        yield d["initial"], "file", "initial.file"
    if (d.get("mold") or {}).get("path"):
        yield d["mold"], "path", "mold.path"
    for k, st in enumerate(d.get("stages") or []):
        for key, v in list((st.get("set") or {}).items()):
            if isinstance(v, str) and key.rsplit(".", 1)[-1] in ("path", "file", "csv"):
                yield st["set"], key, f"stages.{k}.set.{key}"


def _sha256(path: Path) -> tuple[str | None, int | None]:
    try:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        return h.hexdigest(), os.path.getsize(path)
    except OSError:
        return None, None


def portable_scene(scene) -> tuple[dict, list[dict]]:
    """(the scene as a dict with every file reference reduced to the file's name, [{field,
    file, sha256, bytes}] of those references; sha256 None when the file cannot be read)."""
    d = scene.to_dict()
    files = []
    for holder, key, field in _refs(d):
        path = scene.resolve(holder[key])
        name = PurePath(str(holder[key]).replace("\\", "/")).name
        digest, size = _sha256(path)
        holder[key] = name
        files.append({"field": field, "file": name, "sha256": digest, "bytes": size})
    return d, files


def portable_scene_yaml(scene) -> str:
    """``scene.yaml`` of a result folder: a header naming each file the scene read with its
    SHA-256, then the scene with those references by name only (see the module docstring)."""
    d, files = portable_scene(scene)
    head = ["# The scene as run. File references are by name only (no path of the machine that ran it):",
            "# to run it again, put these files beside this scene.yaml (the SHA-256 says whether a file is",
            "# the one used) or edit the paths."]
    head += [f"#   {f['field']}: {f['file']}  sha256 {f['sha256'] or 'unreadable'}" for f in files]
    return "\n".join(head) + "\n" + yaml.safe_dump(d, sort_keys=False)


# ----------------------------------------------------------------------------- the scene in short


def _fmt(v) -> str:
    return format(v, ".4g") if isinstance(v, float) else str(v)


def _materials(model) -> list[dict]:
    """[{direction, strain [], tension_n_per_m []}]: the tension tables of the warp and weft
    springs (one entry per distinct table, in table order)."""
    out = []
    for fam, name in ((SpringFamily.WARP, "warp"), (SpringFamily.WEFT, "weft")):
        ids = np.unique(model.spring_table[model.spring_family == fam])
        for k, t in enumerate(ids):
            tab = model.table_list[int(t)]
            out.append({"direction": name if len(ids) == 1 else f"{name} {k + 1}",
                        "strain": [float(x) for x in tab.strain], "tension_n_per_m": [float(y) for y in tab.tension]})
    return out


def _friction(scene) -> float:
    """The Coulomb coefficient at the end of the loading path (the last stage that sets
    mold.friction, else the mold's; 0 without)."""
    mu = 0.0
    mold = scene.mold
    if mold is not None and mold.friction:
        mu = float(mold.friction)
    for st in scene.stages:
        if "mold.friction" in (st.set or {}):
            mu = float(st.set["mold.friction"] or 0.0)
    return mu


def _mold_text(d: dict, files: list[dict]) -> str | None:
    m = d.get("mold")
    if not m:
        return None
    if m.get("path"):
        bits = [f"mesh {m['path']}"]
        if m.get("surface"):
            bits.append(f"{m['surface']} surface")
        if m.get("up"):
            bits.append(f"up {m['up']}")
        if m.get("scale") not in (None, 1, 1.0):
            bits.append(f"scale {m['scale']}")
        return ", ".join(bits)
    for kind in ("cylinder", "sphere", "plane", "box"):
        if m.get(kind):
            return f"{kind} " + ", ".join(f"{k} {v}" for k, v in m[kind].items())
    return ", ".join(f"{k} {v}" for k, v in m.items() if k != "friction")


def _stage_text(st) -> str:
    bits = [f"{st.steps} step{'s' if st.steps != 1 else ''}"]
    if st.rest_scale is not None:
        bits.append(f"garment at {st.rest_scale} x its cut size")
    bits += [f"{k} = {v}" for k, v in (st.set or {}).items()]
    return f"{st.name or 'stage'}: " + ", ".join(bits)


def _standards(scene) -> list[dict]:
    """The class tables the scene's classes use (every built-in one, its extra ones)."""
    cl = getattr(scene, "classes", None)
    if cl is None:
        return []
    extra = list(cl.extra or [])
    chosen = [standard(n, extra) for n in cl.standards] if cl.standards else list(STANDARDS)
    chosen += [s for s in extra if s not in chosen]
    return [{"name": s.name, "site": s.site, "source": s.source,
             "classes": [{"name": c.name, "min": c.min, "max": c.max} for c in s.classes]} for s in chosen]


def scene_brief(scene) -> dict:
    """The scene in short, as the report shows it (no path, no YAML dump; see the module
    docstring): what the scene alone says, taken when the scene is compiled."""
    d, files = portable_scene(scene)
    panels = d.get("panels") or []
    if panels:
        names = ", ".join(str(p.get("name")) for p in panels)
        garment = f"{len(panels)} panel{'s' if len(panels) != 1 else ''} ({names})"
        if d.get("seams"):
            garment += f", {len(d['seams'])} seam{'s' if len(d['seams']) != 1 else ''}"
    else:
        f = d.get("fabric") or {}
        garment = f"a rectangle {f.get('size')} m, {f.get('divisions')} divisions"
    solver = d.get("solver") or {}
    return {
        "name": scene.name,
        "garment": garment,
        "body": _mold_text(d, files),
        "friction_mu": _friction(scene),
        "stages": [_stage_text(st) for st in scene.stages],
        "constraints": len(d.get("constraints") or []),
        "solver": f"{solver.get('method', 'auto')}, residual tolerance e = {_fmt(solver.get('e'))} N",
        "files": files,
        "standards": _standards(scene),
    }


def scene_summary(brief: dict, model) -> dict:
    """The scene in short (:func:`scene_brief`) with what the run adds: the version, the date,
    the node count and the material tables of ``model``."""
    return {"name": brief["name"], "clothsim_version": __version__,
            "written_utc": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "garment": brief["garment"], "node_count": int(model.node_count), "body": brief["body"],
            "materials": _materials(model),
            **{k: brief[k] for k in ("friction_mu", "stages", "constraints", "solver", "files", "standards")}}


def scene_summary_json(brief: dict, model) -> str:
    """scene_summary as JSON text (a value JSON has no type for written as its str: the summary
    never costs the run's files)."""
    return json.dumps(scene_summary(brief, model), default=str)
