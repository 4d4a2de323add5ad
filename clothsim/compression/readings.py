"""What a scene reads on its equilibrium, in one record: its probes (:mod:`.probes`), profiles,
classes (:mod:`.standards`) and measuring levels (:mod:`.levels`), taken from the scene when it is
compiled, so a Result reads and writes them without reading the scene."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..plottext import failure
from .levels import (LevelError, level_point, level_set, levels_csv, read_level, read_levels, sensor_radius,
                     wants_levels)
from .levelspec import Levels
from .probes import NO_READING, probes_csv, profile_png, profiles_csv, read_probe, read_profile
from .standards import classify_all

if TYPE_CHECKING:
    from ..model import Model
    from .spec import Classes, Probe, Profile


@dataclass(frozen=True)
class Readings:
    """What a scene asks to read on its equilibrium (its ``probes``, ``profiles``, ``classes`` and
    measuring ``levels``, and the mold spec a chart leg's levels come from), taken from the scene
    when it is compiled (``clothsim.compile.run_inputs``): a Result reads and writes them without
    reading the scene. Falsy when the scene asks for none."""

    probes: tuple[Probe, ...] = ()
    profiles: tuple[Profile, ...] = ()
    classes: Classes | None = None
    levels: Levels | None = None
    mold: object | None = None

    @classmethod
    def of(cls, scene) -> "Readings":
        return cls(tuple(scene.probes), tuple(scene.profiles), scene.classes, scene.levels, scene.mold)

    def __bool__(self) -> bool:
        return bool(self.probes or self.profiles or wants_levels(self))

    def evaluate(self, model: Model, positions: np.ndarray, in_contact: np.ndarray, pressure: np.ndarray,
                 strain_warp: np.ndarray | None = None) -> dict:
        """The probes, profiles and classes: {"probes": [...], "profiles": [...], "classes": {...}}
        (only the keys asked for), and the measuring levels' readings {"levels": ...} (:mod:`.levels`).
        positions (N, 3) [m], in_contact (N,) bool, pressure (N,) [Pa], strain_warp the warp
        springs' strains (for the course strain at each level)."""
        out: dict = {}
        lset, level_error = None, ""
        if wants_levels(self) or any(pr.point is None for pr in self.probes):
            try:
                lset = level_set(self, model.mold)
            except LevelError as e:
                level_error = str(e)
        if self.probes:
            out["probes"] = [_read_probe_or_level(model, positions, in_contact, pressure, pr, lset, level_error)
                             for pr in self.probes]
        if wants_levels(self):
            out["levels"] = ({"error": level_error} if lset is None else
                             read_levels(self, model, positions, in_contact, pressure, strain_warp, lset))
        if self.profiles:
            out["profiles"] = [read_profile(model, positions, in_contact, pressure, pf) for pf in self.profiles]
        classes = self.classes
        if classes is not None and self.probes:
            reading = next(r for r in out["probes"] if r["name"] == classes.probe)
            results = classify_all(reading["pressure_mmhg"], classes.standards, classes.extra)
            if not reading["contact_fraction"] > 0.0:
                # a probe off the contact (a garment that slid off, a point off the body) reads no
                # pressure: it has no class, not "below class I"
                for c in results:
                    c["class"] = NO_READING
            out["classes"] = {"probe": classes.probe, "pressure_mmhg": reading["pressure_mmhg"],
                              "results": results}
            for r in out["probes"]:
                if r["name"] == classes.probe:
                    r["classes"] = {c["standard"]: c["class"] for c in out["classes"]["results"]}
        return out

    def read(self, model: Model, positions: np.ndarray, in_contact: np.ndarray, pressure: np.ndarray,
             names) -> dict:
        """{name: mmHg or None}: the named readings alone, each by the code :meth:`evaluate` reads it
        with (the same numbers): a probe's pressure (a probe's name wins over a level's), else a
        measuring level's mean (:func:`.levels.read_level` without its side sensors and course
        strain; None: no contact round the level). What a fit reads on each solve, where the full
        readings (every probe, every level's four sensor discs, profiles) would cost more than
        the targets need. Raises LevelError for a name that is neither a probe nor a level the
        scene can place (the message says why)."""
        probes = {pr.name: pr for pr in self.probes}
        lset, level_error = None, ""
        if any(n not in probes or probes[n].point is None for n in names):
            try:
                lset = level_set(self, model.mold)
            except LevelError as e:
                level_error = str(e)
        out: dict = {}
        for n in names:
            if n in probes:
                out[n] = _read_probe_or_level(model, positions, in_contact, pressure, probes[n], lset,
                                              level_error)["pressure_mmhg"]
                continue
            lv = next((r for r in (lset or {}).get("levels", []) if r["name"] == n), None)
            if lv is None:
                raise LevelError(level_error or f"'{n}' is neither a probe nor a measuring level of the scene")
            out[n] = read_level(model, positions, in_contact, pressure, lv, sensor_radius(self), sides=False)["mean_mmhg"]
        return out

    def files(self, readings: dict, title: str) -> dict[str, bytes]:
        """probes.csv, levels.csv, profiles.csv and profiles.png of ``readings`` (:meth:`evaluate`).
        A plot that cannot be drawn is a warning and is left out: it never costs the numeric files."""
        out: dict[str, bytes] = {}
        if readings.get("probes"):
            out["probes.csv"] = probes_csv(readings["probes"]).encode()
        if readings.get("levels", {}).get("levels"):
            out["levels.csv"] = levels_csv(readings["levels"]).encode()
        if readings.get("profiles"):
            out["profiles.csv"] = profiles_csv(readings["profiles"]).encode()
            try:
                out["profiles.png"] = profile_png(readings["profiles"], title)
            except Exception as exc:  # noqa: BLE001 (any plotting failure: the numbers are written)
                warnings.warn(f"profiles.png not written ({failure(exc)}); the numbers are in profiles.csv",
                              stacklevel=3)
        return out


def _read_probe_or_level(model, positions, in_contact, pressure, probe, lset, level_error: str) -> dict:
    """read_probe of a probe at its point, or at its level's side (``.levels``); a level that
    cannot be placed reads nothing and says why."""
    if probe.point is not None:
        return read_probe(model, positions, in_contact, pressure, probe)
    try:
        if lset is None:
            raise LevelError(level_error or "no levels on this body")
        pt = level_point(lset, probe.level, probe.side)
    except LevelError as e:
        return {"name": probe.name, "point": [math.nan] * 3, "center": None, "radius_m": float(probe.radius),
                "offset_m": math.nan, "force_n": 0.0, "pressure_pa": 0.0, "pressure_mmhg": 0.0,
                "contact_fraction": 0.0, "on_contact": False, "level": probe.level, "side": probe.side,
                "note": str(e)}
    r = read_probe(model, positions, in_contact, pressure, probe.model_copy(update={"point": pt}))
    r.update(level=probe.level, side=probe.side)
    return r
