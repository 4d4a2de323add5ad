"""Loading a scene: a YAML file or a raw dict validated into a :class:`Scene` (errors with file,
line and field), overrides applied, the scenes of its stages, and a raw mold spec validated on
its own."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from ..errors import SceneError
from ..fileio import load_yaml, read_text
from .molds import (BoxMoldSpec, CylinderMoldSpec, LegMoldSpec, MeshMoldSpec, PlaneMoldSpec, SphereMoldSpec,
                    _MoldHolder)
from .overrides import _set_path, parse_overrides
from .scene import Scene, Stage
from .sourcelines import format_validation_error

def validate_mold_spec(spec: Any) -> Any:
    """A raw mold spec (dict) as its typed model; a typed one is returned as is. Raises
    ValueError with ``mold.field: message`` lines (the same checks as a scene file's)."""
    if isinstance(spec, (MeshMoldSpec, SphereMoldSpec, CylinderMoldSpec, PlaneMoldSpec, BoxMoldSpec, LegMoldSpec)):
        return spec
    try:
        return _MoldHolder.model_validate({"mold": spec}).mold
    except ValidationError as exc:
        raise ValueError(format_validation_error(exc, "", None).replace("\n: ", "\n").lstrip(": ")) from None




def scene_from_dict(data: dict, source: str | Path | None = None, root: yaml.Node | None = None,
                    blame: dict[str, str] | None = None) -> Scene:
    """Validate a raw dict into a Scene; errors become SceneError with file:line: field: message
    (or ``--set ...: field: message`` for a field an override set, see format_validation_error)."""
    label = str(source) if source is not None else "<scene>"
    if not isinstance(data, dict):
        raise SceneError(f"{label}: a scene must be a mapping (got {type(data).__name__})")
    try:
        scene = Scene.model_validate(data)
    except ValidationError as exc:
        raise SceneError(format_validation_error(exc, label, root, blame)) from None
    if source is not None:
        scene._source = Path(source).resolve()
        scene._label = label
    scene._yaml_root = root
    scene._blame = dict(blame) if blame else None
    if scene.stages:
        stage_scenes(scene)  # every stage's scene is valid before any work
    return scene


def read_yaml(path: str | Path, error: type[Exception] = SceneError) -> tuple[Any, yaml.Node | None]:
    """(data, node tree) of a YAML file; the tree gives line numbers for error messages. Failures
    raise ``error`` naming the file (and the line of a syntax error or of a byte that is not
    UTF-8). Refused before parsing: anything but a regular file, a file over 10 MB; before
    building any object: aliases expanding past a budget (a YAML bomb), see clothsim.fileio."""
    path = Path(path)
    return load_yaml(read_text(path, error), str(path), error)


def load_scene(path: str | Path, overrides: list[str] | dict[str, Any] | None = None) -> Scene:
    """Read and validate a scene YAML file, applying ``--set`` style overrides."""
    path = Path(path)
    data, root = read_yaml(path)
    if data is None:
        raise SceneError(f"{path}: empty scene file")
    items = parse_overrides(overrides)
    if items and not isinstance(data, dict):
        raise SceneError(f"{path}: a scene must be a mapping (got {type(data).__name__})")
    data = copy.deepcopy(data)
    for k, v, _ in items:
        _set_path(data, k, v)
    return scene_from_dict(data, path, root, {k: label for k, _, label in items})


def stage_scenes(scene: Scene) -> list[tuple[Stage, Scene]]:
    """Each stage of ``scene.stages`` with the scene it solves: the scene's fields with every
    stage's ``set`` up to it applied (empty without stages). A value a field refuses is reported
    as ``file:line: stages.N.set: field: message``."""
    if not scene.stages:
        return []
    data = scene.to_dict()
    data.pop("stages", None)
    out = []
    for n, st in enumerate(scene.stages):
        try:
            for k, v in st.set.items():
                _set_path(data, k, copy.deepcopy(v))
            s = Scene.model_validate(copy.deepcopy(data))
        except (SceneError, ValidationError) as exc:
            why = format_validation_error(exc, "", None).lstrip(": ") if isinstance(exc, ValidationError) \
                else str(exc).replace("--set ", "")
            raise SceneError(scene.locate(f"stages.{n}.set: {why}")) from None
        s._source, s._label = scene._source, scene._label
        out.append((st, s))
    return out


def dump_scene(scene: Scene, path: str | Path) -> None:
    Path(path).write_text(scene.to_yaml(), encoding="utf-8")
