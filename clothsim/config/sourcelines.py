"""Where a problem is: the line of a field in the scene's YAML file, or the ``--set`` override
that set it; :func:`format_validation_error` turns pydantic's errors into ``file:line: field:
message`` lines."""

from __future__ import annotations

import re

import yaml
from pydantic import ValidationError

from .fields import _MOLD_TAGS

def _yaml_line(root: yaml.Node | None, loc: tuple) -> int | None:
    """Line (1-based) of the YAML node at path loc, or of the key of its deepest existing ancestor."""
    node = root
    line = root.start_mark.line + 1 if root is not None else None
    for key in loc:
        nxt = None
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if str(k.value) == str(key):
                    nxt = v
                    line = k.start_mark.line + 1
                    break
        elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
            nxt = node.value[key]
            line = nxt.start_mark.line + 1
        if nxt is None:
            break
        node = nxt
    return line


#: pydantic's branch tags of generic types (a key typed as ``size[0]`` is a field, not a tag)
_TAG = re.compile(r"(list|tuple|literal|dict|set|frozenset)\[")


def _is_tag(part) -> bool:
    """Whether a location part is pydantic's tag of a union's branch (``list[any]``,
    ``literal[...]``, ``function-after[_one(), Space]``, ``NodeRange``, a mold kind), not a field."""
    return isinstance(part, str) and (_TAG.match(part) is not None or part.startswith("function-")
                                      or part in ("NodeRange", "float", "int", "str") or part in _MOLD_TAGS)


def _clean_loc(loc: tuple) -> tuple:
    """Drop pydantic's union/literal branch tags from a location."""
    return tuple(p for p in loc if not _is_tag(p))


def _winning_branches(errors: list[dict]) -> list[dict]:
    """A union's errors without the branches the input plainly is not: an error at a branch's own
    level (a list expected, a literal string expected) is dropped when another branch of the same
    union got further (an error inside it, or its own validator's message), at every level of
    nested unions. ``{linspace: [1, 3, -2]}`` then reports the bad n alone, not also "Input should
    be a valid list"; ``i: [0, '150%']`` the bad share alone, not also "a valid integer"."""
    def levels(e):
        loc = tuple(e["loc"])
        # (the union's location, the branch, whether the error lies further than the branch's
        # own level: a field or index below it; a nested branch tag is still its own level)
        return [(loc[:i], p, any(not _is_tag(q) for q in loc[i + 1:]) or e["type"] == "value_error")
                for i, p in enumerate(loc) if _is_tag(p)]

    info = [levels(e) for e in errors]
    further = {(base, tag) for lv in info for base, tag, far in lv if far}
    keep = []
    for e, lv in zip(errors, info):
        if any(not far and any(b == base and t != tag for b, t in further) for base, tag, far in lv):
            continue
        keep.append(e)
    return keep


def format_validation_error(exc: ValidationError, source: str, root: yaml.Node | None,
                            blame: dict[str, str] | None = None) -> str:
    """One line per problem: ``file:line: field.path: message``. ``blame`` maps a field path
    (``solver.C``) to the label of what set it (``--set solver.C=0.5``): a problem at or under
    that path is reported against the label instead of a line of the file."""
    lines = []
    seen = set()
    for err in _winning_branches(exc.errors()):
        loc = _clean_loc(tuple(err["loc"]))
        msg = err["msg"]
        for prefix in ("Value error, ", "Assertion failed, "):
            if msg.startswith(prefix):
                msg = msg[len(prefix):]
        field = ".".join(str(p) for p in loc)
        # a model-level validator reports "sub: message" (sub may be a dotted path such as
        # seams.0.b): fold the sub-field into the path
        head = msg.split(": ", 1)[0] if ": " in msg else ""
        if head and " " not in head and all(p.replace("_", "").isalnum() for p in head.split(".")):
            sub, msg = msg.split(": ", 1)
            loc = loc + tuple(int(p) if p.isdigit() else p for p in sub.split("."))
            field = ".".join(str(p) for p in loc)
        if err["type"] == "extra_forbidden":
            msg = "unknown field"
        elif err["type"] == "missing":
            msg = "missing"
        culprit = _blamed(loc, blame, root)
        line = _yaml_line(root, loc) if root is not None and culprit is None else None
        where = culprit or (f"{source}:{line}" if line else source)
        text = f"{where}: {field}: {msg}" if field else f"{where}: {msg}"
        if (field, msg) in seen:
            continue
        seen.add((field, msg))
        lines.append(text)
    # union errors produce one entry per branch; keep the most specific ones
    return "\n".join(lines)


def _in_file(root: yaml.Node | None, parts) -> bool:
    """Whether the scene file itself has a node at the path ``parts`` (keys, list indices)."""
    node = root
    for key in parts:
        nxt = None
        if isinstance(node, yaml.MappingNode):
            nxt = next((v for k, v in node.value if str(k.value) == str(key)), None)
        elif isinstance(node, yaml.SequenceNode) and str(key).isdigit() and int(key) < len(node.value):
            nxt = node.value[int(key)]
        if nxt is None:
            return False
        node = nxt
    return node is not None


def _blamed(loc: tuple, blame: dict[str, str] | None, root: yaml.Node | None = None) -> str | None:
    """The label of the override that caused a problem at loc, if any: the longest override path
    that is a prefix of loc (``--set solver.C=0``: solver.C); else one under loc (``--set
    fabric.size.0=-1``: the check of fabric.size); else one that shares the start of loc where the
    file has no such node (``--set gravity.g=1`` made gravity: its missing areal_density;
    ``--set solvr.C=3``: the unknown solvr). Problems of the file's own nodes keep the file's
    line."""
    best = None
    for path, label in (blame or {}).items():
        parts = path.split(".")
        c = 0
        while c < min(len(parts), len(loc)) and str(loc[c]) == parts[c]:
            c += 1
        if c == 0:
            continue
        if c == len(parts):
            rank = (2, c)
        elif c == len(loc):
            rank = (1, c)
        elif not _in_file(root, parts[:c]):
            rank = (0, c)
        else:
            continue
        if best is None or rank > best[0]:
            best = (rank, label)
    return best[1] if best else None

