"""The typed records of a run's results: ONE field list, each field with its unit, that summary.json,
sweeps (``outputs:`` and summary.csv), the HTML report's summary table, plot labels and the docs read.

A record is a frozen dataclass; each field's metadata gives its readable label, unit and meaning
(:func:`out`). :data:`SUMMARY_FIELDS` lists every output a run or a sweep can report, in the order
summary.json writes them:

- :class:`RunSummary`: the run (status, residual, timings, solver) — always present;
- :class:`Diagnostics`: numbers that make a degenerate result visible, the peak strains and
  pressures (clothsim.results, clothsim.pressure) — some only when they apply (:data:`ABSENT`:
  left out of summary.json, e.g. ``max_penetration_m`` without a mold);
- :class:`FrictionReport` (summary.json ``friction``: load steps, stick / slip counts, cone
  violation), read by a sweep as ``friction.KEY``;
- :class:`StageReport` (``friction.stages``: each stage of a staged scene), read as
  ``stage:NAME.KEY`` (``stage:press.iterations``, ``stage:press.friction.slip``);
- :class:`ProbeReading` (``probes``: each probe of a compression scene), read as
  ``probe:NAME_SUFFIX`` (``probe:ankle_mmhg``);
- :data:`WORKER_FIELDS` (a sweep worker's extras: the sheet's height, the run's time) and
  :data:`FIT_FIELDS` (a fitting sweep's fit:PATH, fit_converged, fit_solves).

Units: SI; ``-`` a dimensionless ratio, ``""`` a count, a flag or a text.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any


class _Absent:
    """The value of a field that does not apply to a run (left out of summary.json)."""

    _instance = None

    def __new__(cls):
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "ABSENT"

    def __bool__(self) -> bool:
        return False

    def __reduce__(self):
        return (_Absent, ())


#: a field that does not apply (no mold: no penetration; no seams: no seam gap): not written
ABSENT: Any = _Absent()


def out(label: str, unit: str, doc: str = "", *, default=dataclasses.MISSING, optional: bool = False,
        suffix: str | None = None):
    """A record field: its readable ``label``, ``unit`` ("-" dimensionless, "" a count, a flag or
    a text) and one-line ``doc``; ``optional`` fields default to ABSENT (left out of summary.json
    when they do not apply); ``suffix``: the name a sweep output gives the field of a probe
    (``probe:NAME_<suffix>``)."""
    meta = {"label": label, "unit": unit, "doc": doc or label, "suffix": suffix}
    if optional:
        return field(default=ABSENT, metadata=meta)
    return field(default=default, metadata=meta)


class Record:
    """Shared by the records: to_dict (ABSENT fields left out, field order kept)."""

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if getattr(self, f.name) is not ABSENT}

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))


# ----------------------------------------------------------------------------- the records


@dataclass(frozen=True, kw_only=True)
class RunSummary(Record):
    """The run: what stopped it, where it stopped, how long it took (summary.json's first keys)."""

    name: str = out("scene name", "")
    converged: bool = out("converged", "", "the residual reached the limit e")
    status: str = out("status", "", "converged, max_iterations, time_limit, stalled, diverged, stopped, error")
    message: str = out("message", "", "why the run stopped, in words")
    iterations: int = out("iterations", "", "solver iterations")
    residual: float = out("residual ||V||inf", "N", "largest net force on a free node at the end")
    relative_residual: float = out("relative residual", "-", "residual over the largest spring force")
    best_residual: float = out("best residual", "N", "the smallest residual the run reached")
    energy: float = out("energy", "J", "elastic and potential energy at the end")
    wall_time_s: float = out("relaxation time", "s", "wall time of the relaxation")
    startup_s: float = out("start-up time", "s", "mold loading, model building, kernel compilation")
    solver: str = out("solver", "", "the solver method that ran")
    C: float = out("step divisor C", "-", "the paper's step divisor (solver.C)")
    e: float = out("convergence limit e", "N", "the residual limit (solver.e)")
    contact_count: int = out("contact nodes", "", "nodes touching the mold")
    node_count: int = out("nodes", "", "nodes of the sheet")
    clothsim_version: str = out("clothsim version", "")


@dataclass(frozen=True, kw_only=True)
class Diagnostics(Record):
    """Numbers that make a degenerate result visible, the peak strains and pressures and the deepest
    penetration (clothsim.results.Result.diagnostics, clothsim.pressure)."""

    slack_springs: int = out("slack springs", "", "springs carrying no force")
    spring_count: int = out("springs", "")
    undetermined_nodes: int = out("undetermined nodes", "", "free nodes held only by slack springs, off the mold")
    min_weft_extent_ratio: float = out("narrowest weft extent / rest width", "-",
                                       "the narrowest deformed weft line over its rest length")
    gathered_rows: int = out("gathered rows", "", "rows or columns bunched along a direction nothing holds")
    gathered_rows_direction: str = out("gathered rows' direction", "", "warp, weft, warp and weft, or empty")
    gathered_rows_min_strain: float | None = out("gathered rows' lowest strain", "-")
    gathered_rows_max_pressure_mmhg: float | None = out("gathered rows' peak pressure", "mmHg", optional=True)
    max_sensor_pressure_pa: float | None = out("peak sensor pressure", "Pa",
                                               "largest reading of the peak sensor disc (clothsim.pressure)")
    max_sensor_pressure_mmhg: float | None = out("peak sensor pressure", "mmHg")
    sensor_radius_m: float = out("peak sensor radius", "m")
    max_strain_warp: float = out("peak warp strain", "-")
    max_strain_weft: float = out("peak weft strain", "-")
    max_contact_pressure_pa: float | None = out("peak node pressure", "Pa",
                                                "largest node pressure where it is defined (null: all gathered)")
    max_contact_pressure_mmhg: float | None = out("peak node pressure", "mmHg")
    gathered_contact_nodes: int = out("gathered contact nodes", "", "loaded nodes with no area left (line loads)")
    contact_pressure_note: str = out("contact pressure note", "", "why there is no contact pressure",
                                     optional=True)
    gathered_contact_force_n: float = out("gathered contact force", "N", optional=True)
    contact_line_load_n_per_m: float | None = out("peak contact line load", "N/m", optional=True)
    contact_line_load_mean_n_per_m: float | None = out("mean contact line load", "N/m", optional=True)
    max_seam_gap_m: float = out("largest seam gap", "m", optional=True)
    seams: list = out("seams", "", "per seam: a_length_m, b_length_m, ease_pct, max_gap_m", optional=True)
    max_penetration_m: float = out("deepest penetration", "m", "deepest node inside the mold", optional=True)
    mold_surface: str = out("mold contact surface", "", "faceted or smooth", optional=True)
    mold_surface_reason: str = out("mold surface reason", "", optional=True)


@dataclass(frozen=True, kw_only=True)
class FrictionReport(Record):
    """A run in load steps (friction with the mold, stages, solver.load_steps): summary.json
    ``friction`` (clothsim.solvers.friction.solve_steps, clothsim.friction.friction_report)."""

    mu: float = out("friction coefficient mu", "-", "mold.friction: the nodes outside friction regions")
    mu_max: float = out("largest friction coefficient", "-", "largest mu over the nodes (with friction regions)",
                        optional=True)
    load_steps: int = out("load steps", "")
    steps_solved: int = out("load steps solved", "")
    cuts: int = out("load steps cut in half", "")
    refreshes: int = out("friction refreshes", "")
    steps: list = out("load step log", "", "per step: its control and its solve")
    stick: int = out("sticking nodes", "", "pressed contact nodes that did not slide", optional=True)
    slip: int = out("slipping nodes", "", "pressed contact nodes that slid at least eps", optional=True)
    cone_violation: float = out("Coulomb cone violation", "-", "max (|f_t| - mu f_n)+ / f_n", optional=True)
    stages: list = out("stages", "", "each stage's report (StageReport)", optional=True)


@dataclass(frozen=True, kw_only=True)
class StageReport(Record):
    """One finished stage of a staged scene (summary.json ``friction.stages``)."""

    name: str = out("stage name", "")
    load_steps: int = out("load steps", "")
    rest_scale: list = out("rest scale at the stage's end", "-", optional=True)
    converged: bool = out("converged", "")
    iterations: int = out("iterations", "")
    residual: float = out("residual ||V||inf", "N")
    friction: dict = out("the stage's friction report", "", "FrictionReport")


@dataclass(frozen=True, kw_only=True)
class ProbeReading(Record):
    """One probe's reading (summary.json ``probes``; clothsim.compression.probes.read_probe)."""

    name: str = out("probe name", "")
    point: list = out("probe point", "m")
    radius_m: float = out("probe radius", "m", suffix="radius_m")
    center: list | None = out("disc centre on the mold", "m")
    offset_m: float = out("point to mold", "m", suffix="offset_m")
    force_n: float = out("force on the disc", "N", suffix="force_n")
    pressure_pa: float = out("pressure", "Pa", "force over pi radius^2", suffix="pa")
    pressure_mmhg: float = out("pressure", "mmHg", suffix="mmhg")
    contact_fraction: float = out("contact fraction", "-", "area in contact on the disc over pi radius^2",
                                  suffix="contact_fraction")
    on_contact: bool = out("on contact", "")
    note: str = out("note", "")
    classes: dict = out("classes", "", "standard -> class (the classified probe)", optional=True)


# ----------------------------------------------------------------------------- the field list


@dataclass(frozen=True)
class OutputField:
    """One output: its key (summary.json key; ``friction.KEY``; ``stage:*.KEY``; ``probe:*_SUFFIX``),
    readable label, unit, meaning, the record it belongs to and whether it is a number (plotted)."""

    key: str
    label: str
    unit: str
    doc: str
    record: str
    scalar: bool

    def axis_label(self) -> str:
        return self.label + (f" [{self.unit}]" if self.unit else "")


def _fields(cls, prefix: str = "", only_scalar: bool = False) -> list[OutputField]:
    out_ = []
    for f in dataclasses.fields(cls):
        scalar = f.type.split(" ")[0] in ("int", "float", "bool", "str")
        if only_scalar and not scalar:
            continue
        m = f.metadata
        out_.append(OutputField(prefix + f.name, m["label"], m["unit"], m["doc"], cls.__name__, scalar))
    return out_


#: worker extras: what the sweep worker measures beside the summary (sweep_run.json)
WORKER_FIELDS = (
    OutputField("max_z_m", "highest node z", "m", "highest node's z (a cap's apex height)", "worker", True),
    OutputField("min_z_m", "lowest node z", "m", "lowest node's z", "worker", True),
    OutputField("run_time_s", "run time", "s", "wall time of the whole run in the worker (start-up + relaxation "
                "+ files)", "worker", True),
)
#: a fitting sweep's own outputs (``fit:PATH`` is the fitted value of a varied field)
FIT_FIELDS = (
    OutputField("fit_converged", "fit converged", "", "the fit met every target within tol_mmhg", "fit", True),
    OutputField("fit_solves", "fit solves", "", "solves the fit spent", "fit", True),
)

#: every top-level summary.json field, in writing order (RunSummary, then Diagnostics)
SUMMARY_FIELDS: tuple[OutputField, ...] = tuple(_fields(RunSummary) + _fields(Diagnostics))
#: the friction report's numbers, as sweep outputs ``friction.KEY``
FRICTION_FIELDS: tuple[OutputField, ...] = tuple(_fields(FrictionReport, "friction.", only_scalar=True))
#: a stage's numbers, as sweep outputs ``stage:NAME.KEY`` (KEY: these keys, the stage's friction
#: numbers as ``friction.KEY``)
STAGE_FIELDS: tuple[OutputField, ...] = tuple([f for f in _fields(StageReport, only_scalar=True) if f.key != "name"]
                                              + _fields(FrictionReport, "friction.", only_scalar=True))
#: a probe's numbers, as sweep outputs ``probe:NAME_SUFFIX``: {suffix: ProbeReading key}
PROBE_SUFFIXES: dict[str, str] = {f.metadata["suffix"]: f.name for f in dataclasses.fields(ProbeReading)
                                  if f.metadata.get("suffix")}
#: every plain output name a sweep accepts (summary fields, friction.KEY, worker extras, fit)
OUTPUT_FIELDS: dict[str, OutputField] = {f.key: f for f in (*SUMMARY_FIELDS, *FRICTION_FIELDS, *WORKER_FIELDS,
                                                          *FIT_FIELDS)}
#: outputs that depend on timing; equal sweeps differ only in these
TIMING_KEYS = ("wall_time_s", "startup_s", "run_time_s")


def _probe_field(f: dataclasses.Field) -> OutputField:
    m = f.metadata
    return OutputField(f.name, m["label"], m["unit"], m["doc"], "ProbeReading", True)


def split_named(name: str) -> tuple[str, str, OutputField] | None:
    """A named output ``probe:NAME_SUFFIX`` or ``stage:NAME.KEY`` as (kind, NAME, its field), or
    None when ``name`` is neither (an unknown suffix or key included)."""
    if name.startswith("probe:"):
        body = name[len("probe:"):]
        for suffix in sorted(PROBE_SUFFIXES, key=len, reverse=True):
            if body.endswith("_" + suffix) and len(body) > len(suffix) + 1:
                f = next(x for x in dataclasses.fields(ProbeReading) if x.name == PROBE_SUFFIXES[suffix])
                return "probe", body[:-len(suffix) - 1], _probe_field(f)
        return None
    if name.startswith("stage:"):
        body = name[len("stage:"):]
        for f in sorted(STAGE_FIELDS, key=lambda x: len(x.key), reverse=True):
            if body.endswith("." + f.key) and len(body) > len(f.key) + 1:
                return "stage", body[:-len(f.key) - 1], f
        return None
    return None


def output_field(name: str) -> OutputField | None:
    """The field of a sweep output name (a plain one, ``probe:NAME_SUFFIX`` or ``stage:NAME.KEY``),
    or None (``fit:PATH`` is the fitted field's: clothsim.labels)."""
    if name in OUTPUT_FIELDS:
        return OUTPUT_FIELDS[name]
    named = split_named(name)
    return named[2] if named is not None else None


def _dig(d: Any, path: str):
    for part in path.split("."):
        if not isinstance(d, dict) or part not in d:
            return None
        d = d[part]
    return d


def flatten(summary: dict) -> dict[str, Any]:
    """The sweep outputs of one summary.json (parsed): every scalar summary field present, the
    friction numbers (``friction.KEY``), each stage's (``stage:NAME.KEY``) and each probe's
    (``probe:NAME_SUFFIX``). Values as written (None for null)."""
    row: dict[str, Any] = {}
    for f in SUMMARY_FIELDS:
        if f.key in summary:
            row[f.key] = summary[f.key]
    fr = summary.get("friction")
    if isinstance(fr, dict):
        for f in FRICTION_FIELDS:
            v = _dig(summary, f.key)
            if v is not None or f.key[len("friction."):] in fr:
                row[f.key] = v
        for st in fr.get("stages") or []:
            if isinstance(st, dict) and isinstance(st.get("name"), str):
                for f in STAGE_FIELDS:
                    v = _dig(st, f.key)
                    if v is not None:
                        row[f"stage:{st['name']}.{f.key}"] = v
    for p in summary.get("probes") or []:
        if isinstance(p, dict) and isinstance(p.get("name"), str):
            for suffix, key in PROBE_SUFFIXES.items():
                row[f"probe:{p['name']}_{suffix}"] = p.get(key)
    return row


def field_rows(summary: dict) -> list[tuple[OutputField, str, Any]]:
    """(field, output name, value) of every scalar output of a summary.json (parsed), in the field
    list's order: the rows of the report's summary table."""
    flat = flatten(summary)
    rows = []
    for name, v in flat.items():
        f = output_field(name)
        if f is not None and f.scalar:
            rows.append((f, name, v))
    return rows


def format_value(v: Any) -> str:
    """A summary value as the report shows it: numbers to 6 significant digits, null as n/a."""
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.6g}"
    return str(v)


def outputs_markdown() -> str:
    """The table of sweep outputs for docs/guide/sweeps.md (checked against the field list by the
    tests): output, unit, meaning."""
    lines = ["| output | unit | meaning |", "|---|---|---|"]

    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    for f in OUTPUT_FIELDS.values():
        lines.append(f"| `{f.key}` | {f.unit or ''} | {cell(f.doc)}{'' if f.scalar else ' (a list: JSON in summary.csv)'} |")
    for suffix, key in PROBE_SUFFIXES.items():
        f = _probe_field(next(x for x in dataclasses.fields(ProbeReading) if x.name == key))
        lines.append(f"| `probe:NAME_{suffix}` | {f.unit} | probe NAME's {cell(f.doc)} |")
    for f in STAGE_FIELDS:
        lines.append(f"| `stage:NAME.{f.key}` | {f.unit or ''} | stage NAME's {cell(f.doc)} |")
    lines.append("| `fit:PATH` | the field's | the fitted value of a varied field (with `fit:`) |")
    return "\n".join(lines) + "\n"
