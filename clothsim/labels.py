"""Readable names and units of sweep outputs and scene fields, for plot axes.

``axis_label("max_contact_pressure_mmhg")`` is "peak node pressure [mmHg]",
``axis_label("mold.cylinder.radius")`` "mold cylinder radius [m]",
``axis_label("fit:fabric.size.0")`` "fitted fabric size (warp) [m]". A dimensionless value shows
``[-]``, a count no unit; a field whose unit is not known shows its path alone.
"""

from __future__ import annotations

import dataclasses

from .records import OUTPUT_FIELDS, OutputField, split_named

#: summary.json keys (and the sweep worker's extras): (readable name, unit), from the one field
#: list (clothsim.records)
OUTPUTS = {k: (f.label, f.unit) for k, f in OUTPUT_FIELDS.items()}

#: a scene field's unit by its name (the last non-index part of its path; see clothsim.config)
FIELD_UNITS = {
    "size": "m", "radius": "m", "length": "m", "lift": "m", "perturb": "m", "thickness": "m",
    "spacing": "m", "clearance": "m", "smoothing": "m", "tolerance": "m", "displacement": "m",
    "center": "m", "origin": "m", "translate": "m", "point": "m", "min": "m", "max": "m",
    "heights": "m", "from": "m", "to": "m", "step": "m",
    "start_angle": "deg", "rotate": "deg",
    "stretch": "-", "scale": "-", "C": "-", "newton_kink": "-",
    "e": "N", "stiffness": "N/m", "tension": "N/m", "stress": "Pa",
    "areal_density": "kg/m^2", "g": "m/s^2", "time_limit_s": "s",
    "divisions": "", "max_iterations": "", "max_retries": "", "stall_iterations": "", "seed": "",
    "reduction": "%", "girth": "m", "hem": "m", "height": "m", "at": "m", "girth_cm": "cm", "length_cm": "cm",
}
#: the unit of a field under a given parent: a seam's stiffness is per length of seam
PARENT_UNITS = {("seams", "stiffness"): "N/m^2", ("garment", "width"): "-", ("garment", "length"): "-"}
#: how the index after a field reads: fabric.size.0 is the warp size, center.2 the z coordinate
INDEX_NAMES = {"size": ("warp", "weft"), "divisions": ("warp", "weft"), "stretch": ("warp", "weft"),
               **{k: ("x", "y", "z") for k in ("center", "origin", "translate", "point", "min", "max",
                                                 "displacement", "axis", "rotate")}}


def record_field(record, name: str) -> OutputField:
    """A field of one of clothsim.records' records (RunSummary, Diagnostics, ProbeReading, ...) with
    its readable label and unit: what a display (the viewer's status line, readouts and plot
    labels) writes beside the value, so it names a figure as summary.json, the report and the
    sweeps do. KeyError for a name the record does not have."""
    f = next((x for x in dataclasses.fields(record) if x.name == name), None)
    if f is None:
        raise KeyError(f"{record.__name__} has no field {name!r}")
    m = f.metadata
    scalar = str(f.type).split(" ")[0] in ("int", "float", "bool", "str")
    return OutputField(name, m["label"], m["unit"], m["doc"], record.__name__, scalar)


def _unit(unit: str) -> str:
    return f" [{unit}]" if unit else ""


def field_label(path: str) -> str:
    """A scene field path as an axis label: its words and unit (``fabric.warp.scale`` ->
    "fabric warp scale [-]"); the path itself when its unit is not known."""
    parts = path.split(".")
    words: list[str] = []
    name = None  # the last named (non-index) part
    for k, part in enumerate(parts):
        if part.isdigit() and name in INDEX_NAMES and int(part) < len(INDEX_NAMES[name]):
            words.append(f"({INDEX_NAMES[name][int(part)]})")
        elif part.isdigit():
            words.append(part)
        else:
            name = part
            words.append(part.replace("_", " "))
    if name is None or (name not in FIELD_UNITS and not any(n == name for _, n in PARENT_UNITS)):
        return path
    unit = next((u for (parent, n), u in PARENT_UNITS.items() if n == name and parts[0] == parent),
                FIELD_UNITS.get(name, ""))
    return " ".join(words) + _unit(unit)


def field_unit(path: str) -> str:
    """The unit of a scene field path ("m", "%", "-" for a ratio; "" when not known)."""
    parts = path.split(".")
    names = [p for p in parts if not p.isdigit()]
    if not names:
        return ""
    name = names[-1]
    return next((u for (parent, n), u in PARENT_UNITS.items() if n == name and parts[0] == parent),
                FIELD_UNITS.get(name, ""))


def axis_label(name: str) -> str:
    """An output (summary key, probe:NAME_key, fit:PATH) or a scene field as an axis label."""
    if name in OUTPUTS:
        text, unit = OUTPUTS[name]
        return text + _unit(unit)
    named = split_named(name)
    if named is not None:  # probe:NAME_SUFFIX, stage:NAME.KEY
        kind, who, f = named
        return f"{kind} {who} {f.label}" + _unit(f.unit)
    if name.startswith("fit:"):
        return "fitted " + field_label(name[4:])
    return field_label(name)
