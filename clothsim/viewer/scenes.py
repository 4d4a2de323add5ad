"""Which files a scene opened in the viewer may read, and the scenes that come with clothsim. No
viser import.

- An **uploaded** scene may name only files uploaded with it (:func:`check_references`), and its
  files are read (:func:`check_scene_files`) before it replaces the viewer's scene; messages
  never show the private upload folder (:func:`scrub`).
- The **bundled** scenes are ``configs/**/*.yaml`` but the sweeps (:func:`bundled_scenes`); one
  opens from its own folder, its references resolved beside it (:func:`open_bundled`).
"""

from __future__ import annotations

import re
from pathlib import Path

from ..config import Scene, SceneError, load_scene
from ..material import MaterialError
from ..mold import MoldError, check_mold

ROOT = Path(__file__).resolve().parent.parent.parent


def scrub(msg: str, path: Path, dest: Path, label: str) -> str:
    """``msg`` with the private folder of an upload replaced by the uploaded file's name (the
    scene) or left out (its other files)."""
    for d in {str(dest), str(Path(dest).resolve())}:
        msg = msg.replace(str(Path(d) / Path(path).name), label).replace(d + "/", "").replace(d, "(upload)")
    return msg


def file_references(scene: Scene) -> list[tuple[str, str]]:
    """(field path, file name as written) of every file a scene reads: the mold mesh, CSV
    tables (the fabric's and each panel's), pattern files and the initial positions."""
    d = scene.to_dict()
    refs: list[tuple[str, str]] = []
    if (d.get("mold") or {}).get("path"):
        refs.append(("mold.path", d["mold"]["path"]))
    for key in ("warp", "weft"):
        if (d["fabric"].get(key) or {}).get("csv"):
            refs.append((f"fabric.{key}.csv", d["fabric"][key]["csv"]))
    for n, panel in enumerate(d.get("panels", [])):
        if (panel.get("pattern") or {}).get("file"):
            refs.append((f"panels.{n}.pattern.file", panel["pattern"]["file"]))
        for key in ("warp", "weft"):
            if (panel.get(key) or {}).get("csv"):
                refs.append((f"panels.{n}.{key}.csv", panel[key]["csv"]))
    if (d.get("initial") or {}).get("file"):
        refs.append(("initial.file", d["initial"]["file"]))
    return refs


def check_references(scene: Scene, folder: Path) -> None:
    """An uploaded scene may read only files uploaded with it: every reference must be a
    relative name (no absolute path, no ``..``) that resolves inside ``folder``, the upload's own
    folder. Raises SceneError naming the line and field, before any file is read."""
    root = Path(folder).resolve()
    for field, ref in file_references(scene):
        p = Path(str(ref).replace("\\", "/"))
        bad = p.is_absolute() or ".." in p.parts or re.match(r"^[A-Za-z]:", str(ref)) is not None
        if not bad:
            try:
                bad = not (scene.base_dir / p).resolve().is_relative_to(root)
            except (OSError, RuntimeError):
                bad = True
        if bad:
            raise SceneError(scene.locate(
                f"{field}: '{str(ref)[:80]}' is not a file of this upload: an uploaded scene may only "
                f"name files uploaded with it, by a relative name without '..' (upload a .zip from "
                f"'Save scene + files', or pick a bundled scene from the list)"))


def check_scene_files(scene: Scene) -> None:
    """Read the files a scene names (mold mesh, CSV tables) as a run would, before it replaces
    the viewer's scene; errors name the file's line and field (``file:line: field: ...``)."""
    if scene.mold is not None:
        spec = scene.to_dict().get("mold") or {}
        try:
            check_mold(scene.mold, scene.base_dir)
        except MoldError as exc:
            field = "mold.path" if spec.get("path") else "mold"
            raise MoldError(scene.locate(f"{field}: {exc}")) from None
    holders = [("fabric", scene.fabric, scene.fabric.thickness)]
    holders += [(f"panels.{n}", p, p.thickness if getattr(p, "thickness", None) is not None
                 else scene.fabric.thickness) for n, p in enumerate(scene.panels)]
    for where, holder, thickness in holders:
        for key in ("warp", "weft"):
            spec = getattr(holder, key, None)
            if spec is None or spec.csv is None:
                continue
            try:
                scene.material_table(spec, thickness, f"{where}.{key}")
            except (MaterialError, SceneError) as exc:
                msg = str(exc)
                if not msg.startswith(f"{where}.{key}"):
                    msg = f"{where}.{key}.csv: {msg}"
                raise type(exc)(scene.locate(msg)) from None


CONFIG_DIR = ROOT / "configs"


def bundled_scenes() -> dict[str, Path]:
    """The scenes that come with clothsim: label (the path under ``configs/``) -> file, every
    ``configs/**/*.yaml`` but the sweep definitions (``configs/sweeps``)."""
    if not CONFIG_DIR.is_dir():
        return {}
    out = {}
    for f in sorted(CONFIG_DIR.rglob("*.yaml")):
        rel = f.relative_to(CONFIG_DIR)
        if rel.parts[0] != "sweeps":
            out[rel.as_posix()] = f
    return out


def bundled_match(data: bytes) -> Path | None:
    """The bundled scene file whose bytes are ``data`` (an upload of a file from configs/), or
    None."""
    for f in bundled_scenes().values():
        try:
            if f.stat().st_size == len(data) and f.read_bytes() == data:
                return f
        except OSError:
            continue
    return None


def open_bundled(path: Path) -> Scene:
    """A bundled scene (:func:`bundled_scenes`), its references resolved against its own folder
    (``../../static/bodies/smpl_man.stl``) and its files read as a run would; errors name
    ``configs/...:line: field``."""
    path = Path(path)
    rel = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else path.name
    try:
        scene = load_scene(path)
        check_scene_files(scene)
    except (SceneError, MoldError, MaterialError) as exc:
        raise type(exc)(str(exc).replace(str(path), rel).replace(str(ROOT) + "/", "")) from None
    return scene
