"""MkDocs hook: the reference pages are generated from the code at every build, so they cannot drift.

``reference/scene.md`` lists every scene field from the pydantic models of ``clothsim.config``
(type, default, bounds, the model's docstring); ``reference/cli.md`` prints every command's
``-h`` from ``clothsim.cli.build_parser``."""

from __future__ import annotations

import inspect
import re
import types
import typing

from pydantic import BaseModel

MARK_SCENE = "<!-- generated: scene fields -->"
MARK_CLI = "<!-- generated: cli help -->"


def _type_name(tp) -> str:
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        return " \\| ".join(repr(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        return " \\| ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is typing.Annotated:
        return _type_name(typing.get_args(tp)[0])
    if origin is not None:
        args = ", ".join(_type_name(a) for a in typing.get_args(tp))
        name = getattr(origin, "__name__", str(origin))
        return f"{name}[{args}]"
    if inspect.isclass(tp) and issubclass(tp, BaseModel):
        return f"[{tp.__name__}](#{tp.__name__.lower()})"
    if tp is type(None):
        return "null"
    return getattr(tp, "__name__", str(tp)).replace("|", "\\|")


def _models(tp, seen: dict):
    """Every pydantic model reachable from the annotation tp, in first-seen order."""
    if inspect.isclass(tp) and issubclass(tp, BaseModel):
        if tp.__name__ in seen:
            return
        seen[tp.__name__] = tp
        for f in tp.model_fields.values():
            _models(f.annotation, seen)
        return
    for a in typing.get_args(tp) or ():
        _models(a, seen)


def _bounds(field) -> str:
    out = []
    for m in field.metadata:
        for attr, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="),
                          ("min_length", "length >="), ("max_length", "length <=")):
            v = getattr(m, attr, None)
            if v is not None:
                out.append(f"{sym} {v:g}" if isinstance(v, float) else f"{sym} {v}")
    return ", ".join(out)


def _default(field) -> str:
    if field.is_required():
        return "**required**"
    if field.default_factory is not None:
        try:
            v = field.default_factory()
        except TypeError:
            return "(computed)"
        if isinstance(v, BaseModel):
            return "(its defaults)"
        return f"`{v!r}`"
    return f"`{field.default!r}`"


def scene_reference() -> str:
    from clothsim.config import Scene

    seen: dict = {}
    _models(Scene, seen)
    parts = []
    for name, model in seen.items():
        doc = inspect.cleandoc(model.__doc__ or "").strip()
        if doc.startswith("A base class") or doc.startswith("!!!"):
            doc = ""
        parts.append(f"## {name}\n")
        if doc:
            parts.append(doc + "\n")
        parts.append("| field | type | default | bounds |\n|---|---|---|---|")
        for fname, f in model.model_fields.items():
            key = f.alias or fname
            parts.append(f"| `{key}` | {_type_name(f.annotation)} | {_default(f)} | {_bounds(f)} |")
        parts.append("")
    return "\n".join(parts)


def cli_reference() -> str:
    import argparse

    from clothsim.cli import build_parser

    parser = build_parser()
    parts = ["## clothsim\n", "```text", parser.format_help().rstrip(), "```", ""]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                parts += [f"## clothsim {name}\n", "```text", sub.format_help().rstrip(), "```", ""]
    return "\n".join(parts)


def on_page_markdown(markdown: str, page, config, files):
    if MARK_SCENE in markdown:
        markdown = markdown.replace(MARK_SCENE, scene_reference())
    if MARK_CLI in markdown:
        markdown = markdown.replace(MARK_CLI, cli_reference())
    return markdown
