"""The benchmark's scenes: the speed-against-error cases (square, sphere cap, panels, optional terms),
the panel scenes of the garment comparison, and the scan campaign's bodies, heights, garments
and limits."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np



ROOT = Path(__file__).resolve().parents[2]  # the repository (this file is clothsim/bench/cases.py)


LEVELS = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9]


TARGET_E = 1e-9


REFERENCE_E = 1e-12


@dataclass
class Case:
    """One benchmark scene: a config with overrides, and per-solver time limits [s]."""

    name: str
    config: str
    overrides: list[str] = field(default_factory=list)
    solvers: tuple[str, ...] = ("newton", "paper")
    time_limit: dict = field(default_factory=dict)  # solver -> s
    group: str = "main"


def garment_cases() -> list[Case]:
    """The panel scenes of issue 11's target (``app.py bench --garments``), newton alone, beside
    the 201^2 square they are measured against: the circle cut from the lattice on the sphere cap
    (225 divisions across: 39,877 nodes) and the four-panel garment (four 101^2 quarter panels sewn
    edge to edge: 40,804 nodes)."""
    return [
        Case("sphere cap 201^2", "configs/sphere_cap.yaml", ["fabric.divisions=[200,200]"], ("newton",),
             {"newton": 60}, group="garments"),
        Case("circle cap 40k", "configs/garments/circle_cap.yaml", ["panels.0.divisions=[224,224]"], ("newton",),
             {"newton": 120}, group="garments"),
        Case("four panels cap 40k", "configs/garments/circle_cap.yaml", four_panel_cap_overrides(100), ("newton",),
             {"newton": 120}, group="garments"),
    ]


def cases(quick: bool, garments: bool = False) -> list[Case]:
    """The benchmark scenes (quick: small grids and short caps, under a minute in all; garments:
    the panel scenes of :func:`garment_cases` alone)."""
    if garments:
        return garment_cases()
    sc = "configs/sphere_cap.yaml"
    hard = sorted((ROOT / "configs" / "hard").glob("*.yaml"))
    if quick:
        out = [
            Case("sphere cap 41^2", sc, [], time_limit={"paper": 3, "newton": 20}),
            Case("sphere cap 101^2", sc, ["fabric.divisions=[100,100]"], ("newton",), {"newton": 20}),
        ]
        if (ROOT / "configs" / "thermoform.yaml").exists():
            out.append(Case("thermoform 41^2", "configs/thermoform.yaml", [], time_limit={"paper": 3, "newton": 20}))
        for label, ov in _optional_terms()[::2]:
            out.append(Case(f"sphere cap 21^2 {label}", sc, ["fabric.divisions=[20,20]", *ov], ("newton",),
                            {"newton": 10}, group="terms"))
        return out
    out = [
        Case("sphere cap 41^2", sc, [], time_limit={"paper": 120, "newton": 60}),
        Case("sphere cap 201^2", sc, ["fabric.divisions=[200,200]"], time_limit={"paper": 60, "newton": 60}),
        Case("sphere cap 501^2", sc, ["fabric.divisions=[500,500]"], time_limit={"paper": 30, "newton": 120}),
    ]
    for cfg, label in (("thermoform.yaml", "thermoform 41^2"), ("torso_band.yaml", "torso band 41x11"),
                       ("torso_band_held.yaml", "torso band held 41x11"),
                       ("sewn_sleeve.yaml", "sewn sleeve 51x17")):
        if (ROOT / "configs" / cfg).exists():
            out.append(Case(label, f"configs/{cfg}", [], time_limit={"paper": 60 if "sewn" in cfg else 120,
                                                                     "newton": 60}))
    for h in hard:
        out.append(Case(f"hard: {h.stem}", str(h.relative_to(ROOT)), [], time_limit={"paper": 60, "newton": 60},
                        group="hard"))
    for label, ov in _optional_terms():
        out.append(Case(f"sphere cap 41^2 {label}", sc, ov, time_limit={"paper": 60, "newton": 60}, group="terms"))
    return out


def four_panel_cap_overrides(divisions: int = 100) -> list[str]:
    """Overrides that turn ``configs/sphere_cap.yaml`` into a four-panel garment: the 0.1 m
    sheet cut into four 0.05 m quarter panels (``divisions`` x ``divisions`` each; 100 gives
    40,804 nodes, as many as the 201^2 square), sewn edge to edge by four seams, the outer
    edges held on the square stretched 10 % about the sheet's centre (each panel's stretch acts
    about its own centre, so a displacement of 0.1 (c - 0.05) m moves it to the sheet's)."""
    d = int(divisions)
    quads = (("bl", 0.0, 0.0), ("br", 0.05, 0.0), ("tl", 0.0, 0.05), ("tr", 0.05, 0.05))
    panels, cons = [], []
    for name, tx, ty in quads:
        panels.append(f"{{name: {name}, outline: [[0, 0], [0.05, 0], [0.05, 0.05], [0, 0.05]], "
                      f"divisions: [{d}, {d}], placement: {{transform: {{translate: [{tx}, {ty}, 0.0]}}}}}}")
        ox = 0 if tx == 0 else -1  # the outer column (i) and row (j) of this quarter
        oy = 0 if ty == 0 else -1
        rng = "[1, -1]" if ox == 0 else "[0, -2]"  # the row without the corner the column has
        disp = f"[{0.1 * (tx + 0.025 - 0.05):.4f}, {0.1 * (ty + 0.025 - 0.05):.4f}, 0.0]"
        cons.append(f"{{nodes: {{panel: {name}, i: {ox}, j: null}}, axes: xyz, stretch: 1.1, displacement: {disp}}}")
        cons.append(f"{{nodes: {{panel: {name}, i: {rng}, j: {oy}}}, axes: xyz, stretch: 1.1, displacement: {disp}}}")
    seams = ["{a: {panel: bl, side: right}, b: {panel: br, side: left}}",
             "{a: {panel: tl, side: right}, b: {panel: tr, side: left}}",
             "{a: {panel: bl, side: top}, b: {panel: tl, side: bottom}}",
             "{a: {panel: br, side: top}, b: {panel: tr, side: bottom}}"]
    # each panel's dome leaves the seams on the sheet's plane: lifted clear of the sphere
    return ["panels=[" + ", ".join(panels) + "]", "seams=[" + ", ".join(seams) + "]",
            "constraints=[" + ", ".join(cons) + "]", "initial.auto_clearance=true"]


def _optional_terms():
    return [
        ("(stretch only)", []),
        ("+ gravity", ["gravity={areal_density: 0.2}"]),
        ("+ shear", ["shear={stiffness: 20}"]),
        ("+ bending", ["bending={stiffness: 1}"]),
        ("+ all three", ["gravity={areal_density: 0.2}", "shear={stiffness: 20}", "bending={stiffness: 1}"]),
    ]


# ------------------------------------------------------------------------------------------------
# the scan campaign: the paper's torso band on two scanned bodies at many heights, newton alone
# ------------------------------------------------------------------------------------------------


#: the scanned bodies of the campaign (file stem, heights [m] of the band's centre line in the
#: body's own Y-up frame: waist to lower chest, below the arms)
SCAN_BODIES = (
    ("smpl_man", tuple(round(1.02 + 0.02 * i, 2) for i in range(12))),
    ("smpl_neutral", tuple(round(0.96 + 0.02 * i, 2) for i in range(12))),
)


SCAN_MAX_ITERATIONS = 400


SCAN_TIME_LIMIT = 120.0


#: ... for a garment of the campaign [s] (wall clock: the 28 x 60 stocking took 43-53 s of CPU and
#: up to 117 s of wall time on the loaded 2-core machine)
SCAN_GARMENT_TIME_LIMIT = 600.0


#: the garments of the campaign (issue 12 names the garment issue's stocking): (row name, body
#: file stem (its file from SCAN_DIRS is the mold), config, overrides, contact surface; None: the
#: campaign's), newton alone to TARGET_E like the bands
SCAN_GARMENTS = (
    ("stocking 14 x 30", "smpl_man", "configs/garments/stocking.yaml", (), None),
    # the ankle's single-node seams name the bottom row's end columns: doubled with the divisions
    # (the held middle column is i: 50%, the middle on any lattice)
    ("stocking 28 x 60", "smpl_man", "configs/garments/stocking.yaml",
     ("panels.0.divisions=[28,60]", "panels.1.divisions=[28,60]", "seams.2.a.i=22", "seams.2.b.i=6",
      "seams.3.a.i=22", "seams.3.b.i=6"), "smooth"),
)


def scan_band_overrides(path: Path, height: float, surface: str = "faceted") -> list[str]:
    """Overrides that put configs/torso_band.yaml (the paper's 0.5 x 0.2 m band, 40 x 10
    divisions, ends pulled round to the back with stretch 1.75 and held in x and y, free along
    the body axis) onto a Y-up scan in metres at ``height`` [m]: the mold is rotated to Z-up with
    the front towards +y (``rotate: [90, 0, 180]``); the band starts on a cylinder round the body
    axis through the middle of the body's slab [height - 0.1, height + 0.1] (arms excluded:
    |x| < 0.3 m), 2 cm clear of its farthest vertex, centred on the front. ``surface``: the mesh
    mold's contact surface ("faceted" or "smooth"; always stated: a scan's default is smooth)."""
    import trimesh

    V = np.asarray(trimesh.load(str(path), force="mesh").vertices)
    sel = (np.abs(V[:, 1] - height) < 0.1) & (np.abs(V[:, 0]) < 0.3)
    z0 = 0.5 * float(V[sel, 2].min() + V[sel, 2].max())
    r = float(np.hypot(V[sel, 0], V[sel, 2] - z0).max()) + 0.02
    start = 90.0 - math.degrees(0.25 / r)
    mold = f"path: {path}, rotate: [90, 0, 180], surface: {surface}"
    return [f"mold={{{mold}}}",
            f"initial.wrap={{center: [0.0, {z0:.6f}, {height:.4f}], axis: [0, 0, 1], radius: {r:.6f}, "
            f"start_angle: {start:.6f}}}"]


#: rounds of fresh processes in ``bench --garments`` (each round runs every scene once; the best
#: and the paired medians are reported): a process's reference pass moves by up to 1.6x from one
#: process to the next on the 2-core machine (memory placement), and with it a single run's work
#: units; the machine's load drifts over minutes
GARMENT_REPEAT = 5


#: solves of each scene in one process of ``run_pair`` (in the order base, scene, scene, base,
#: base, scene, ...: each pair of neighbouring solves is one ratio)
PAIR_SOLVES = 4
