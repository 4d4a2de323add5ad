"""``--set field.path=value`` overrides: parsed as YAML and applied to a raw scene dict."""

from __future__ import annotations

import copy
from typing import Any


from ..errors import SceneError
from ..fileio import load_yaml

def _set_path(data: dict, path: str, value: Any) -> None:
    parts = path.split(".")
    node: Any = data
    for n, part in enumerate(parts):
        last = n == len(parts) - 1
        if isinstance(node, list):
            try:
                idx = int(part)
            except ValueError:
                raise SceneError(f"--set {path}: '{part}' is not a list index") from None
            if not -len(node) <= idx < len(node):
                raise SceneError(f"--set {path}: index {idx} out of range (list has {len(node)} items)")
            if last:
                node[idx] = value
            else:
                node = node[idx]
        else:
            if not isinstance(node, dict):
                raise SceneError(f"--set {path}: '{'.'.join(parts[:n])}' is not a mapping")
            if last:
                node[part] = value
            else:
                if node.get(part) is None:
                    node[part] = {}
                node = node[part]


def apply_overrides(data: dict, overrides: list[str] | dict[str, Any] | None) -> dict:
    """Return a copy of the raw scene dict with ``field.path=value`` overrides applied (values
    are parsed as YAML, so ``[80, 80]`` is a list and ``3`` a number)."""
    data = copy.deepcopy(data)
    for k, v, _ in parse_overrides(overrides):
        _set_path(data, k, v)
    return data


def parse_overrides(overrides: list[str] | dict[str, Any] | None) -> list[tuple[str, Any, str]]:
    """(field path, value, label) of each override; ``--set`` strings are parsed as YAML (aliases
    bounded as in scene files) and labelled ``--set path=value``."""
    if not overrides:
        return []
    if isinstance(overrides, dict):
        return [(k, v, f"{k}={v!r}") for k, v in overrides.items()]
    parsed = []
    for o in overrides:
        if "=" not in o:
            raise SceneError(f"--set {o}: expected field.path=value")
        k, v = o.split("=", 1)
        parsed.append((k.strip(), load_yaml(v, f"--set {o}", SceneError)[0], f"--set {o}"))
    return parsed

