"""What a result folder carries so that ``report`` needs nothing else (issue 31 item 5).

A result folder is moved and mailed: the report must not re-read the scene's files (the body mesh,
the material tables) nor recompile the model. :meth:`clothsim.results.Result.npz_bytes` adds to
``result.npz``:

- ``faces`` (F, 3): the sheet's display triangles (node ids in the order of ``positions``
  flattened to (N, 3));
- ``node_strain_warp``, ``node_strain_weft`` (N,): each node's mean warp / weft spring strain;
- ``body_vertices`` (V, 3) float32 [m], ``body_faces`` (F, 3) int32: the mold's surface near
  the garment (:func:`clothsim.reportdata.body_near`: its triangles within the garment's bounding
  box plus BODY_MARGIN_M, merged onto a coarser grid when more than BODY_MAX_FACES);
- ``scene_summary``: a short description of the scene as JSON text (:func:`scene_brief` taken at
  compile time, completed by :func:`clothsim.reportdata.scene_summary`: the
  garment, the body, the materials' curves, friction, stages, solver, the standards' class
  ranges and every file the scene read, by name and SHA-256, never by its path).

``scene.yaml`` is written by :func:`portable_scene_yaml`: the scene as run with every file
reference reduced to the file's name, and a header listing each file's SHA-256, so the folder
holds no path of the machine that ran it and the run can be repeated with the same files put
beside it (the hashes say whether they are the same files). ``fit``'s ``fitted.yaml`` is written
the same way by :func:`runnable_scene`, with the files themselves copied beside it: the fit's
folder runs (``run fitted.yaml``) wherever it is moved.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path, PurePath

import yaml

from ..config.load import stage_scenes
from .standards import STANDARDS, standard


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


def _portable(scene, reserved=()) -> tuple[dict, list[dict], dict[str, Path]]:
    """(the scene dict with its file references by name, [{field, file, sha256, bytes}], {name:
    the file it names}). Two different files of one name (a course.csv from two folders), or a
    name in ``reserved``, get distinct names (``course-2.csv``)."""
    d = scene.to_dict()
    files, paths = [], {}
    for holder, key, field in _refs(d):
        path = scene.resolve(holder[key])
        name = PurePath(str(holder[key]).replace("\\", "/")).name
        stem, suffix, k = PurePath(name).stem, PurePath(name).suffix, 1
        while name in reserved or paths.get(name, path) != path:
            k += 1
            name = f"{stem}-{k}{suffix}"
        paths[name] = path
        digest, size = _sha256(path)
        holder[key] = name
        files.append({"field": field, "file": name, "sha256": digest, "bytes": size})
    return d, files, paths


def portable_scene(scene) -> tuple[dict, list[dict]]:
    """(the scene as a dict with every file reference reduced to the file's name, [{field,
    file, sha256, bytes}] of those references; sha256 None when the file cannot be read)."""
    d, files, _ = _portable(scene)
    return d, files


def portable_scene_yaml(scene, portable: tuple[dict, list[dict]] | None = None) -> str:
    """``scene.yaml`` of a result folder: a header naming each file the scene read with its
    SHA-256, then the scene with those references by name only (see the module docstring).
    ``portable``: :func:`portable_scene` of ``scene`` if already taken (its files are read once)."""
    d, files = portable if portable is not None else portable_scene(scene)
    head = ["# The scene as run. File references are by name only (no path of the machine that ran it):",
            "# to run it again, put these files beside this scene.yaml (the SHA-256 says whether a file is",
            "# the one used) or edit the paths."]
    head += [f"#   {f['field']}: {f['file']}  sha256 {f['sha256'] or 'unreadable'}" for f in files]
    return "\n".join(head) + "\n" + yaml.safe_dump(d, sort_keys=False)


def runnable_scene(scene, what: str, reserved=()) -> tuple[str, dict[str, Path]]:
    """A scene that runs from its folder wherever the folder is moved (``fitted.yaml``): (its
    YAML, {name: file to copy beside it}). As :func:`portable_scene_yaml`, every file reference
    is by name only (no path of the machine that ran it); the caller copies each file under that
    name into the folder. ``what`` names the scene in the header; ``reserved``: names the folder's
    other files take (a file of such a name is copied under another)."""
    d, files, paths = _portable(scene, reserved)
    head = [f"# {what}. The files it reads are copied beside it and referenced by name (no path of the",
            "# machine that ran it), so the folder runs wherever it is moved:"]
    head += [f"#   {f['field']}: {f['file']}  sha256 {f['sha256'] or 'unreadable'}" for f in files]
    return "\n".join(head) + "\n" + yaml.safe_dump(d, sort_keys=False), paths


# ----------------------------------------------------------------------------- the scene in short


def _fmt(v) -> str:
    return format(v, ".4g") if isinstance(v, float) else str(v)


def _last_scene(scene):
    """The scene the loading path ends with: its last stage's (whatever path its stages set
    fields by), or the scene itself without stages."""
    stages = stage_scenes(scene)
    return stages[-1][1] if stages else scene


def _friction(last) -> float:
    """The Coulomb coefficient of ``last``, the scene the loading path ends with (0 without)."""
    return float(last.mold.friction or 0.0) if last.mold is not None else 0.0


def _selector_text(sel) -> str:
    """A node selector in words: a set's name, or its panel, side, edge and i/j ranges."""
    if isinstance(sel, str):
        return sel
    d = sel if isinstance(sel, dict) else sel.model_dump(exclude_none=True)
    bits = []
    for k in ("panel", "side", "edge", "i", "j"):
        v = d.get(k)
        if v is None:
            continue
        if isinstance(v, (list, tuple)):
            v = f"{v[0]} to {v[1]}" if k != "edge" else f"vertices {v[0]} to {v[1]}"
        bits.append(f"{k} {v}")
    return ", ".join(bits) or "all"


def _friction_regions(last) -> list[dict]:
    """The friction regions of ``last``, the scene the loading path ends with: [{"nodes": the
    selector in words, "friction": mu}]."""
    regions = last.mold.regions if last.mold is not None else []
    return [{"nodes": _selector_text(r.nodes), "friction": float(r.friction)} for r in regions]


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
    return ", ".join(f"{k} {v}" for k, v in m.items() if k not in ("friction", "friction_regions"))


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


def scene_brief(scene, portable: tuple[dict, list[dict]] | None = None) -> dict:
    """The scene in short, as the report shows it (no path, no YAML dump; see the module
    docstring): what the scene alone says, taken when the scene is compiled. ``portable``: as
    for :func:`portable_scene_yaml`."""
    d, files = portable if portable is not None else portable_scene(scene)
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
    last = _last_scene(scene)   # the stages validated once, for both friction fields
    return {
        "name": scene.name,
        "garment": garment,
        "body": _mold_text(d, files),
        "friction_mu": _friction(last),
        "friction_regions": _friction_regions(last),
        "stages": [_stage_text(st) for st in scene.stages],
        "constraints": len(d.get("constraints") or []),
        "solver": f"{solver.get('method', 'auto')}, residual tolerance e = {_fmt(solver.get('e'))} N",
        "files": files,
        "standards": _standards(scene),
    }


