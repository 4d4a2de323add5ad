"""The ``Scene`` (everything one run needs, validated as a whole: panels against constraints and
seams, friction against the method, the compression names) and the ``Stage``s of a loading
path."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import ConfigDict, Field, field_validator, model_validator

from ..compression.levelspec import Levels
from ..compression.spec import Classes, Probe, Profile, check_compression
from ..sizingspec import GarmentSpec
from ..errors import SceneError
from ..fileio import fmt_beyond
from ..material import TENSION_MAX, Table, read_table_csv
from ..presets import PRESETS
from ..selection import SelectionError, index_range, seam_pairs, seam_sides
from ..strict import Strict as _Strict
from ..topology import Topology
from .fields import Int
from .molds import MoldSpec
from .sourcelines import _blamed, _yaml_line
from .schema import (Constraint, Fabric, Gravity, Initial, MaterialSpec, NodeRange, Panel, Seam,
                     SolverSettings, SpringTerm)


# the scene fields a stage may change (the lattice, seams and start are the scene's own)
STAGE_FIELDS = ("constraints", "mold", "gravity", "solver")
# a stage's rest_scale: the garment from half to twice its design size along each direction
REST_SCALE_RANGE = (0.5, 2.0)


class Stage(_Strict):
    """One stage of a loading path (``stages:``): name; steps, its load steps (>= 1); set, scene
    fields (dotted paths as in ``--set``, under constraints, mold, gravity or solver) and the
    values they take from this stage on. The constraints' prescribed coordinates and the loads
    (gravity's force on the nodes) go linearly from where the previous stage left them (the first
    stage: from the scene's own) to this stage's values over its steps; the other changes
    (mold.friction, a mold, solver fields) apply from the stage's first step."""

    name: str = ""
    steps: Int = 1
    set: dict[str, Any] = Field(default_factory=dict)
    # the garment's size relative to its design (every panel's rest lengths), one number or
    # [warp, weft]; ramped from the previous stage's (1 before the first) over the steps;
    # absent: the previous stage's
    rest_scale: Any = None

    @field_validator("rest_scale", mode="before")
    @classmethod
    def _rest_scale(cls, v):
        if v is None:
            return v
        vals = [v] if isinstance(v, (int, float)) else list(v) if isinstance(v, (list, tuple)) else [None]
        if len(vals) not in (1, 2) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and
                                              math.isfinite(x) and
                                              REST_SCALE_RANGE[0] <= x <= REST_SCALE_RANGE[1] for x in vals):
            raise ValueError(f"must be a number or [warp, weft], each from {REST_SCALE_RANGE[0]} to "
                             f"{REST_SCALE_RANGE[1]} (the garment's size over its design; got {v!r})")
        return [float(x) for x in vals] if isinstance(v, (list, tuple)) else float(v)

    def scale(self, previous: tuple) -> tuple:
        """(s_warp, s_weft) this stage ramps to, from the previous stage's ``previous``."""
        if self.rest_scale is None:
            return tuple(previous)
        v = self.rest_scale
        return (float(v), float(v)) if isinstance(v, (int, float)) else (float(v[0]), float(v[-1]))

    @field_validator("steps")
    @classmethod
    def _steps(cls, v):
        if not 1 <= v <= 100_000:
            raise ValueError(f"must be from 1 to 100000 (got {v})")
        return v

    @field_validator("set")
    @classmethod
    def _paths(cls, v):
        for k in v:
            if str(k).split(".")[0] not in STAGE_FIELDS:
                raise ValueError(f"'{k}': a stage may change {', '.join(STAGE_FIELDS)} only")
        return v


class Scene(_Strict):
    """A complete, validated scene. ``source`` (not part of the file) is where it was read from;
    relative paths inside resolve against its folder."""

    name: str = "scene"
    fabric: Fabric
    constraints: list[Constraint] = Field(default_factory=list)
    initial: Initial = Field(default_factory=Initial)
    mold: MoldSpec | None = None
    gravity: Gravity | None = None
    shear: SpringTerm | None = None
    bending: SpringTerm | None = None
    seams: list[Seam] = Field(default_factory=list)
    panels: list[Panel] = Field(default_factory=list)
    solver: SolverSettings = Field(default_factory=SolverSettings)
    # compression engineering (clothsim.compression.spec): sensors, slices along a limb, classes
    probes: list[Probe] = Field(default_factory=list)
    profiles: list[Profile] = Field(default_factory=list)
    classes: Classes | None = None
    levels: Levels | None = None   # the measuring levels read on the body (compression/levelspec.py)
    # a loading path in stages (empty: one stage, the scene as it is)
    stages: list[Stage] = Field(default_factory=list)
    # sizing the garment: panel scale, reduction at measuring levels, grading (clothsim.sizing)
    garment: GarmentSpec | None = None

    model_config = ConfigDict(extra="forbid")
    _source: Path | None = None
    # where the scene came from, for errors found after validation (``locate``): the file's label
    # as given, its YAML node tree and the --set overrides' labels by field path
    _label: str | None = None
    _yaml_root: Any = None
    _blame: dict | None = None

    def locate(self, message: str) -> str:
        """``message`` (``field.path: why``, as the model and the start-up raise them) prefixed
        with where that field was set: ``file:line`` of the scene file, or the ``--set`` that
        set it (as validation errors are). A message that names no field of the scene is
        returned as it is."""
        m = re.match(r"([A-Za-z_]\w*(?:\.\w+)*): ", message)
        if not m or m.group(1).split(".")[0] not in type(self).model_fields:
            return message
        loc = tuple(int(p) if p.isdigit() else p for p in m.group(1).split("."))
        culprit = _blamed(loc, self._blame, self._yaml_root)
        if culprit:
            return f"{culprit}: {message}"
        if self._label is None:
            return message
        line = _yaml_line(self._yaml_root, loc) if self._yaml_root is not None else None
        return f"{self._label}:{line}: {message}" if line else f"{self._label}: {message}"

    @model_validator(mode="after")
    def _panels_fit(self):
        """The fabric rectangle or panels; panel names are unique and every selector names an
        existing panel."""
        if not self.panels:
            for k in ("size", "divisions"):
                if getattr(self.fabric, k) is None:
                    raise ValueError(f"fabric.{k}: missing (the sheet needs it unless panels are given)")
        else:
            for k in ("size", "divisions"):
                if getattr(self.fabric, k) is not None:
                    raise ValueError(f"fabric.{k}: not used with panels (each panel has its outline and lattice)")
        names = [p.name for p in self.panels]
        for n, name in enumerate(names):
            if name in names[:n]:
                raise ValueError(f"panels.{n}.name: '{name}' is used twice")
        sels = [(f"constraints.{n}.nodes", c.nodes) for n, c in enumerate(self.constraints)]
        sels += [(f"seams.{n}.{k}", getattr(s, k)) for n, s in enumerate(self.seams) for k in ("a", "b")]
        sels += [(f"mold.friction_regions.{n}.nodes", r.nodes) for n, r in enumerate(self._regions())]
        for where, sel in sels:
            if isinstance(sel, NodeRange) and sel.panel is not None and sel.panel not in names:
                known = ", ".join(names) if names else "none: the scene has no panels"
                raise ValueError(f"{where}.panel: unknown panel '{sel.panel}' (known: {known})")
        return self

    @model_validator(mode="after")
    def _ranges_fit(self):
        """On the ``fabric`` sheet, each constraint's i/j ranges lie on its lattice (checked here,
        so a sweep refuses such a run before any runs; panel lattices are checked when built)."""
        if self.panels or self.fabric.divisions is None:
            return self
        nx, ny = self.fabric.divisions
        sels = [(f"constraints.{n}.nodes", "constraints", c.nodes) for n, c in enumerate(self.constraints)]
        sels += [(f"mold.friction_regions.{n}.nodes", "friction_regions", r.nodes)
                 for n, r in enumerate(self._regions())]
        for where, what, sel in sels:
            if isinstance(sel, NodeRange) and sel.side is None and sel.edge is None:
                try:
                    index_range(sel.i, nx, "i", what)
                    index_range(sel.j, ny, "j", what)
                except SelectionError as exc:
                    raise ValueError(f"{where}: {exc}") from None
        return self

    def _regions(self) -> list:
        """The mold's friction regions (none without a mold)."""
        return self.mold.regions if self.mold is not None else []

    @model_validator(mode="after")
    def _friction_method(self):
        """The paper's relaxation is frictionless: a scene with friction asks for Newton."""
        if self.mold is None or self.solver.method != "paper":
            return self
        mu = self.mold.friction
        if mu:
            raise ValueError(f"solver.method: 'paper' is frictionless (the paper's relaxation has no "
                             f"friction) but mold.friction is {mu:g}: use method newton or auto, or "
                             f"mold.friction: 0")
        for n, r in enumerate(self.mold.regions):
            if r.friction > 0:
                raise ValueError(f"solver.method: 'paper' is frictionless (the paper's relaxation has no "
                                 f"friction) but mold.friction_regions.{n}.friction is {r.friction:g}: use "
                                 f"method newton or auto, or mold.friction_regions.{n}.friction: 0")
        return self

    @model_validator(mode="after")
    def _compression_names(self):
        check_compression(self.probes, self.profiles, self.classes)
        return self

    @model_validator(mode="after")
    def _seams_fit(self):
        """Each seam joins two node lines that are not the same (checked here for the ``fabric``
        sheet; panel seams are checked when the panels' lattices are built)."""
        if not self.seams or self.panels:
            return self
        topology = Topology.rectangle(*self.fabric.divisions)
        for n, seam in enumerate(self.seams):
            try:
                a, b, _ = seam_sides(seam, topology)
                if a.size == b.size:
                    seam_pairs(seam, topology)
            except SelectionError as exc:
                raise ValueError(f"seams.{n}.{exc}") from None
        return self

    @property
    def base_dir(self) -> Path:
        return self._source.parent if self._source is not None else Path.cwd()

    @property
    def source(self) -> Path | None:
        return self._source

    def resolve(self, p: str | Path) -> Path:
        p = Path(p)
        return p if p.is_absolute() else self.base_dir / p

    def tables(self) -> tuple[Table, Table]:
        """(warp, weft) tension tables [N/m], CSV files and presets resolved."""
        return tuple(self._table(name) for name in ("warp", "weft"))  # type: ignore[return-value]

    def _table(self, name: str) -> Table:
        return self.material_table(getattr(self.fabric, name), self.fabric.thickness, name)

    def material_table(self, m: MaterialSpec, thickness: float | None, name: str) -> Table:
        """The tension table [N/m] of a material spec (CSV resolved against the scene's folder,
        stress times ``thickness``); ``name`` is the field named in errors."""
        if m.preset is not None:
            p = PRESETS[m.preset]
            which = "warp" if name.endswith("warp") else "weft"
            return Table(np.asarray(p.strain, float), np.asarray(getattr(p, which), float) * (m.scale or 1.0))
        if m.csv is not None:
            path = self.resolve(m.csv)
            strain, value, kind = read_table_csv(path)
        else:
            strain = np.asarray(m.strain, float)
            kind = "stress" if m.stress is not None else "tension"
            value = np.asarray(m.stress if m.stress is not None else m.tension, float)
        if kind == "stress":
            if thickness is None:
                raise SceneError(f"fabric.thickness: needed because {name} is given as stress [Pa]")
            value = value * thickness
        value = value * (m.scale or 1.0)
        if value.size and value.max() > TENSION_MAX:
            field = name if "." in name else f"fabric.{name}"
            raise SceneError(f"{field}: tension reaches {fmt_beyond(value.max(), TENSION_MAX)} N/m (after thickness and scale); "
                             f"at most {TENSION_MAX:.0e} N/m")
        return Table(strain, value)

    def to_dict(self) -> dict:
        d = self.model_dump(mode="json", exclude_none=True)
        for key in ("probes", "profiles", "stages"):  # optional sections: absent unless used
            if not d.get(key):
                d.pop(key, None)
        return d

    def resolved(self) -> "Scene":
        """A copy whose file references (CSV tables, initial file, mold path) are absolute, so the
        scene can be written anywhere and repeated exactly."""
        d = self.to_dict()
        for panel in d.get("panels", []):
            if panel.get("pattern"):
                panel["pattern"]["file"] = str(self.resolve(panel["pattern"]["file"]))
        for holder in [d["fabric"]] + d.get("panels", []):
            for name in ("warp", "weft"):
                if (holder.get(name) or {}).get("csv"):
                    holder[name]["csv"] = str(self.resolve(holder[name]["csv"]))
        if d.get("initial", {}).get("file"):
            d["initial"]["file"] = str(self.resolve(d["initial"]["file"]))
        if d.get("mold") and d["mold"].get("path"):
            d["mold"]["path"] = str(self.resolve(d["mold"]["path"]))
        out = Scene.model_validate(d)
        out._source = self._source
        out._label, out._yaml_root, out._blame = self._label, self._yaml_root, self._blame
        return out

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

