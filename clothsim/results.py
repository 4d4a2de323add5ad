"""Result: what users read and export (positions, contact, strains, tensions, contact pressure).

Files written by :meth:`Result.save` (each written to a temporary name, then renamed, so an
interrupted run never leaves a half-written file; summary.json is removed first and written last,
so a folder is complete exactly when it holds summary.json):

- ``result.npz``: positions (nx+1, ny+1, 3) [m]; in_contact (nx+1, ny+1) bool; strain_warp
  (nx, ny+1); strain_weft (nx+1, ny); tension_warp / tension_weft [N per spring]; contact_force
  (nx+1, ny+1) [N] (normal reaction); contact_pressure (nx+1, ny+1) [Pa]; residual_history [N];
  energy_history [J]; and what ``report`` draws (faces, node strains, the body near the garment,
  the scene in short: clothsim.reportdata).
- ``summary.json``: converged, status, message, iterations, residual [N], relative_residual,
  energy [J], wall_time_s (the relaxation), startup_s (mold loading, model building, JIT
  compilation), solver, contact_count, diagnostics, clothsim version. Strict JSON: a
  non-finite number (a diverged run's NaN residual) is written as null.
- ``history.csv``: iteration, residual [N], energy [J], elapsed [s].
- ``sheet.ply``: the deformed grid as triangles with per-vertex colours (strain or pressure).
- ``scene.yaml``: the scene as run, its file references by name with their SHA-256 (no machine
  paths: clothsim.compression.folder.portable_scene_yaml).
- ``probes.csv``, ``profiles.csv``, ``profiles.png``: when the scene has ``probes`` / ``profiles``
  (clothsim.compression.probes); summary.json then holds ``probes``, ``profiles`` and ``classes``.
  A plot that cannot be drawn is a warning and is left out; the numeric files are written.
"""

from __future__ import annotations

import copy
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .contact import max_penetration
from .diagnostics import gathered_rows, seam_report, sheet_health, surface_report, undetermined_mask
from .fileio import atomic_write_bytes, check_free_space, check_out_dir
from .kernels import spring_strains_tensions
from .model import Model, SpringFamily, State
# the pressure analysis lives in clothsim.pressure (these names are re-exported for scripts and tests)
from .pressure import (GATHERED_AREA_RATIO, MMHG, PEAK_SENSOR, SENSOR_RADIUS_M, SENSOR_SEARCH_SHARE,  # noqa: F401
                       SENSOR_SUBDIVISIONS, SLIVER_FRACTION, contact_reaction, gathered_line_load,
                       max_sensor_pressure, pressure_area, sensor_pressure, sensor_pressure_at)
from .pressure import pressure_peaks
from .records import Diagnostics, RunSummary
from .reportdata import body_near, scene_summary_json
from .version import __version__

if TYPE_CHECKING:
    from .config import Scene
    from .model import RunInputs
    from .solvers import SolveResult

FAMILY_SEAM = SpringFamily.SEAM  # (the name Result.summary reads)

#: every file :meth:`Result.save` may write (summary.json first: it is removed first). A save
#: removes those of them it does not write this time, so an earlier result's files (a scene with
#: probes, then one without) never sit beside a newer result.
RESULT_FILES = ("summary.json", "result.npz", "history.csv", "sheet.ply", "scene.yaml",
                "probes.csv", "profiles.csv", "profiles.png", "levels.csv")


def strict_json(obj) -> str:
    """JSON text in which every non-finite float (NaN, inf) is null, as strict JSON parsers
    require (a diverged run's residual is NaN)."""
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(obj), indent=2, allow_nan=False)



def node_fields(model, state):
    """Per-spring strain and force, per-node contact force and pressure."""
    S = model.spring_count
    strain = np.empty(S)
    force = np.empty(S)
    spring_strains_tensions(state.positions, *model.spring_args(), strain, force)
    contact_force, pressure = contact_reaction(model, state.positions, state.in_contact)
    return strain, force, contact_force, pressure


@dataclass
class Result:
    """A finished (or stopped) run: the scene, its model, the final state and the solve record.

    The Result never reads the scene: what it reports of it (name, C, e, the resolved YAML, the
    probes and profiles to read) is ``inputs`` (``clothsim.compile.run_inputs``); ``scene`` is
    kept for callers that go on from the result (a fit, the viewer)."""

    #: the scene that ran (not read here)
    scene: Scene
    #: the scene's compiled constant arrays
    model: Model
    #: the final state (positions, contact flags)
    state: State
    #: the solve record (status, residual, history, friction report)
    solve: SolveResult
    #: [s] mold loading, model building, kernel compilation
    startup_s: float = 0.0
    #: what the result reports of its scene (clothsim.compile.run_inputs)
    inputs: RunInputs | None = None
    #: per-spring strain (S,) [-] and force (S,) [N], per-node contact force (N,) [N] and pressure (N,) [Pa]
    _fields: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    #: the probes', profiles' and classes' readings (Readings.evaluate)
    _compression: dict | None = field(default=None, repr=False)
    #: the diagnostics record, worked out once
    _diagnostics: Diagnostics | None = field(default=None, repr=False)

    def __post_init__(self):
        if self.inputs is None:
            raise TypeError("Result needs inputs=clothsim.compile.run_inputs(scene) (what it reports of the scene)")

    def _f(self):
        if self._fields is None:
            self._fields = node_fields(self.model, self.state)
        return self._fields

    @property
    def converged(self) -> bool:
        return self.solve.converged

    @property
    def status(self) -> str:
        return self.solve.status

    @property
    def positions(self) -> np.ndarray:
        """(nx+1, ny+1, 3) [m]: the node positions on the lattice's grid (Topology.to_grid)."""
        return self._layout(self.state.positions)

    @property
    def in_contact(self) -> np.ndarray:
        return self._layout(self.state.in_contact)

    def _layout(self, values: np.ndarray) -> np.ndarray:
        """Per-node values on the (nx+1, ny+1) grid of a full rectangle; on any other lattice
        (panels) the flat per-node array (N, ...) in node order (``node_panel``, ``node_ij`` in
        result.npz say which node is which)."""
        topo = self.model.topology
        return topo.to_grid(values) if topo.is_grid else np.asarray(values)

    def _split(self, arr):
        """Warp (nx, ny+1) and weft (nx+1, ny) grids of per-spring values (warp then weft first)."""
        topo = self.model.topology
        wc, fc = topo.warp_count, topo.weft_count
        if not topo.is_grid:
            return arr[:wc], arr[wc:wc + fc]
        return (topo.springs_to_grid(arr[:wc], "warp"), topo.springs_to_grid(arr[wc:wc + fc], "weft"))

    @property
    def strain_warp(self):
        return self._split(self._f()[0])[0]

    @property
    def strain_weft(self):
        return self._split(self._f()[0])[1]

    @property
    def tension_warp(self):
        """Axial force of each warp spring [N]."""
        return self._split(self._f()[1])[0]

    @property
    def tension_weft(self):
        return self._split(self._f()[1])[1]

    @property
    def contact_force(self):
        """Normal contact reaction per node [N] (nx+1, ny+1)."""
        return self._layout(self._f()[2])

    @property
    def contact_pressure(self):
        """Contact pressure [Pa] = reaction / deformed tributary area, (nx+1, ny+1); inf where
        the sheet has gathered into a rope (see contact_reaction)."""
        return self._layout(self._f()[3])

    def _node_strain(self) -> np.ndarray:
        """(N,): the larger of the mean adjacent warp and weft strains at each node."""
        topo = self.model.topology
        wc, fc = topo.warp_count, topo.weft_count
        strain = self._f()[0]
        return np.maximum(topo.spread(strain[:wc], "warp"), topo.spread(strain[wc:wc + fc], "weft"))

    def node_strain(self) -> np.ndarray:
        """Per-node strain for colouring on the lattice's grid (nx+1, ny+1): the larger of the
        mean adjacent warp and weft strains."""
        return self._layout(self._node_strain())

    def diagnostics(self) -> dict:
        """Numbers that make a degenerate result visible (see :func:`clothsim.diagnostics.sheet_health`), the peak
        strains and pressures, and the deepest penetration into the mold (the
        :class:`~clothsim.records.Diagnostics` record's fields that apply, as a dict). Worked out
        once per Result (the sensor peak takes seconds on a big sheet, and summary() and save()
        both need it); a fresh dict is returned."""
        return copy.deepcopy(self.diagnostics_record().to_dict())

    def diagnostics_record(self) -> Diagnostics:
        """The :class:`~clothsim.records.Diagnostics` record (worked out once)."""
        if self._diagnostics is None:
            self._diagnostics = self._work_out_diagnostics()
        return self._diagnostics

    def _work_out_diagnostics(self) -> Diagnostics:
        pos = self.state.positions
        strain, force, cf, p = self._f()
        out = sheet_health(self.model, pos, self.state.in_contact, force=force, strain=strain)
        if out["gathered_rows"]:
            _, _, rows, _ = gathered_rows(self.model, pos, strain, force)
            pr = p[rows & np.isfinite(p) & (cf > 0.0)]
            out["gathered_rows_max_pressure_mmhg"] = float(pr.max()) / MMHG if pr.size else None
        out.update(pressure_peaks(self.model, pos, cf, p))
        out["max_strain_warp"] = float(self.strain_warp.max()) if self.strain_warp.size else 0.0
        out["max_strain_weft"] = float(self.strain_weft.max()) if self.strain_weft.size else 0.0
        seam = self.model.spring_family == FAMILY_SEAM
        if seam.any():
            ab = self.model.spring_nodes[seam]
            out["max_seam_gap_m"] = float(np.linalg.norm(pos[ab[:, 1]] - pos[ab[:, 0]], axis=1).max())
        if self.model.seams:
            out.update(seam_report(self.model, pos))
        if self.model.mold is not None:
            out["max_penetration_m"] = float(max_penetration(pos, self.model.mold.kernel_args()))
            out.update(surface_report(self.model.mold))
        return Diagnostics(**out)

    def undetermined_nodes(self) -> np.ndarray:
        """(i, j) indices of free nodes held only by slack springs (no unique equilibrium)."""
        und = undetermined_mask(self.model, self._f()[1], self.state.in_contact)
        return self.model.topology.node_ij[und]

    def summary_record(self) -> RunSummary:
        """The run's :class:`~clothsim.records.RunSummary` record."""
        s, inp = self.solve, self.inputs
        return RunSummary(
            name=inp.name, converged=bool(s.converged), status=s.status, message=s.message,
            iterations=int(s.iterations), residual=float(s.residual), relative_residual=float(s.relative_residual),
            best_residual=float(s.best_residual), energy=float(s.energy), wall_time_s=float(s.wall_time_s),
            startup_s=float(self.startup_s), solver=s.method, C=float(inp.C), e=float(inp.e),
            contact_count=int(s.contact_count), node_count=int(self.model.node_count), clothsim_version=__version__)

    def summary(self) -> dict:
        """summary.json's content: the :class:`~clothsim.records.RunSummary` fields, ``friction``
        (a :class:`~clothsim.records.FrictionReport`) when the run went in load steps, the
        :class:`~clothsim.records.Diagnostics` fields that apply, and the compression readings
        (``probes``, ``profiles``, ``classes``) when the scene asks for them."""
        d = self.summary_record().to_dict()
        if self.solve.friction:
            # the load steps and the Coulomb state at the last one (stick, slip, cone violation)
            d["friction"] = dict(self.solve.friction)
        d.update(self.diagnostics())
        d.update(self.compression())
        return d

    def compression(self) -> dict:
        """The scene's probes, profiles and classes (clothsim.compression.readings.Readings):
        {"probes": [...], "profiles": [...], "classes": {...}}, only the keys the scene asks for."""
        readings = self.inputs.readings
        if not readings:
            return {}
        if self._compression is None:
            self._compression = readings.evaluate(self.model, self.state.positions, self.state.in_contact,
                                                  self._f()[3], self._f()[0][:self.model.topology.warp_count])
        return self._compression

    def read(self, names) -> dict:
        """{name: mmHg or None} of the named probes and measuring levels alone
        (clothsim.compression.readings.Readings.read: the numbers :meth:`compression` gives them,
        without its other readings); LevelError for a name the scene cannot read."""
        return self.inputs.readings.read(self.model, self.state.positions, self.state.in_contact, self._f()[3],
                                         list(names))

    def colored_mesh(self, field: str = "strain"):
        """A trimesh.Trimesh of the deformed sheet with per-vertex colours (viridis) of field
        ('strain' or 'pressure')."""
        import trimesh
        from matplotlib import colormaps

        values = self._f()[3] / MMHG if field == "pressure" else self._node_strain()
        finite = values[np.isfinite(values)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        t = (values - lo) / (hi - lo) if hi > lo else np.where(np.isposinf(values), 1.0, 0.0)
        # gathered nodes (pressure inf) take the top colour
        t = np.clip(np.nan_to_num(t, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
        colors = (colormaps["viridis"](t) * 255).astype(np.uint8)
        return trimesh.Trimesh(self.state.positions.copy(), self.model.topology.faces, vertex_colors=colors,
                               process=False)

    def history_csv(self) -> str:
        h = self.solve.history
        lines = ["iteration,residual_N,energy_J,elapsed_s"]
        for it, r, e, t in zip(h["iteration"], h["residual"], h["energy"], h["time"]):
            lines.append(f"{int(it)},{r:.10e},{e:.10e},{t:.6f}")
        return "\n".join(lines) + "\n"

    def npz_bytes(self) -> bytes:
        buf = io.BytesIO()
        np.savez_compressed(
            buf,
            positions=self.positions,
            in_contact=self.in_contact,
            strain_warp=self.strain_warp,
            strain_weft=self.strain_weft,
            tension_warp=self.tension_warp,
            tension_weft=self.tension_weft,
            contact_force=self.contact_force,
            contact_pressure=self.contact_pressure,
            residual_history=self.solve.history.get("residual", np.zeros(0)),
            energy_history=self.solve.history.get("energy", np.zeros(0)),
            **self._report_arrays(),
            **({} if self.model.topology.is_grid else {
                "node_panel": self.model.topology.node_panel, "node_ij": self.model.topology.node_ij,
                "panel_names": np.array(self.model.topology.names)}),
        )
        return buf.getvalue()

    def _report_arrays(self) -> dict:
        """What ``report`` draws, so that it reads the folder alone (clothsim.reportdata):
        the sheet's faces, each node's warp and weft strain, the body near the garment and the
        scene in short."""
        topo = self.model.topology
        wc, fc = topo.warp_count, topo.weft_count
        strain = self._f()[0]
        body_v, body_f = body_near(self.model.mold, self.state.positions)
        return {"faces": np.asarray(topo.faces, np.int64), "node_strain_warp": topo.spread(strain[:wc], "warp"),
                "node_strain_weft": topo.spread(strain[wc:wc + fc], "weft"), "body_vertices": body_v,
                "body_faces": body_f, "scene_summary": np.array(scene_summary_json(self.inputs.scene_brief, self.model))}

    def files(self, ply_field: str = "strain") -> dict[str, bytes]:
        """Every output file's name and bytes, in writing order (summary.json last)."""
        return {
            "result.npz": self.npz_bytes(),
            "history.csv": self.history_csv().encode(),
            "sheet.ply": self.colored_mesh(ply_field).export(file_type="ply"),
            "scene.yaml": self.inputs.scene_yaml.encode(),
            **self._compression_files(),
            "summary.json": strict_json(self.summary()).encode(),
        }

    def _compression_files(self) -> dict[str, bytes]:
        """probes.csv, profiles.csv and profiles.png when the scene asks for probes or profiles
        (a plot that cannot be drawn is a warning and is left out: Readings.files)."""
        comp = self.compression()
        return self.inputs.readings.files(comp, self.inputs.name) if comp else {}

    def save(self, out_dir: str | Path, ply_field: str = "strain") -> Path:
        """Write every output file into out_dir (created); returns out_dir.

        The set is replaced as a whole: summary.json (whose presence marks a complete run folder)
        is removed first and written last, so a folder holding an earlier result never looks
        complete with a mix of old and new files. Free space is checked before the first write;
        on any failure (a full disk included) no temporary file is left behind and
        :class:`clothsim.fileio.OutputError` or the OSError is raised."""
        out = check_out_dir(out_dir)
        files = self.files(ply_field)
        check_free_space(out, sum(len(b) for b in files.values()))
        write_result_files(out, files, known=RESULT_FILES)
        return out


def write_result_files(out: Path, files: dict[str, bytes], finished: str = "summary.json",
                       known: tuple[str, ...] = ()) -> None:
    """Write files into out, each atomically: ``finished`` removed first, then stale temporary
    files and, when the folder holds an earlier result (its ``finished`` file or one of the first
    two names of ``known``: summary.json, result.npz for a run), every name of ``known`` that ``files`` does not hold (that result's files this one
    does not write; in a folder without a result, a file of the same name is the user's and
    stays); ``finished`` written last."""
    out = Path(out)
    earlier = any((out / n).is_file() for n in (finished, *known[:2]))
    (out / finished).unlink(missing_ok=True)
    for name in known if earlier else ():
        if name not in files:
            (out / name).unlink(missing_ok=True)
    for tmp in out.glob(".*.tmp*"):  # left by a write that was killed half-way
        tmp.unlink(missing_ok=True)
    for name, data in files.items():
        if name != finished:
            atomic_write_bytes(out / name, data)
    if finished in files:
        atomic_write_bytes(out / finished, files[finished])
