"""What a result carries for its report beside the solve's fields, so that ``report`` reads the
folder alone: the body's surface near the garment (:func:`body_near`) and the scene in short with
what the run adds (:func:`scene_summary`: the version, the date, the node count, the material
tables). The scene part (files by name and SHA-256, garment, body, friction, stages) is taken at
compile time by clothsim.compression.folder.scene_brief."""

from __future__ import annotations

import json
from datetime import datetime, timezone

import numpy as np

from .model import SpringFamily
from .version import __version__

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
    # until they are short against the box: the crop then follows the box. A split is made only
    # while its four times as many triangles stay within max_faces (else the merging below would
    # undo it)
    target = float((hi - lo).max()) / 12.0
    for _ in range(8):
        if not len(F) or 4 * len(F) > max_faces:
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


def scene_summary(brief: dict, model) -> dict:
    """The scene in short (:func:`scene_brief`) with what the run adds: the version, the date,
    the node count and the material tables of ``model``."""
    return {"name": brief["name"], "clothsim_version": __version__,
            "written_utc": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "garment": brief["garment"], "node_count": int(model.node_count), "body": brief["body"],
            "materials": _materials(model),
            **{k: brief[k] for k in ("friction_mu", "stages", "constraints", "solver", "files", "standards")},
            "friction_regions": brief.get("friction_regions", [])}


def scene_summary_json(brief: dict, model) -> str:
    """scene_summary as JSON text (a value JSON has no type for written as its str: the summary
    never costs the run's files)."""
    return json.dumps(scene_summary(brief, model), default=str)
