"""A mold that no node of the sheet can reach warns; when units are the likely cause the warning
says "millimetres?" (issue 12 item 4). Known answers: distances to a sphere are |c - p| - r."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import ROOT, scene_dict

from clothsim.config import scene_from_dict

SHEET = {
    "name": "beside",
    "fabric": {"size": [0.10, 0.10], "divisions": [10, 10],
               "warp": {"strain": [0, 1], "tension": [0, 250]},
               "weft": {"strain": [0, 1], "tension": [0, 250]}},
    "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.1}],
    "initial": {"lift": 0.03},
    "mold": {"sphere": {"center": [0.05, 0.05, -0.02], "radius": 0.04}},
    "solver": {"method": "newton", "e": 1e-6},
}


def _compile_warnings(d) -> list[str]:
    from clothsim.compile import compile_scene

    scene = scene_from_dict(d, ROOT / "configs" / "x.yaml")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        compile_scene(scene)
    return [str(w.message) for w in caught if "mold" in str(w.message)]


def test_a_mold_within_reach_does_not_warn():
    assert _compile_warnings(scene_dict(SHEET)) == []


def test_a_sheet_beside_the_mold_warns_without_blaming_units():
    # the sphere 0.5 m to the side: the nearest node is 0.5 - 0.05 x 1.1 - 0.04 m away, far more
    # than the sheet's 0.1 m
    got = _compile_warnings(scene_dict(SHEET, **{"mold.sphere.center": [0.60, 0.05, -0.02]}))
    assert len(got) == 1, got
    assert "no node of the sheet can reach the mold" in got[0]
    assert "millimetres?" not in got[0]


def test_a_constraint_that_takes_the_sheet_there_does_not_warn():
    d = scene_dict(SHEET, **{"mold.sphere.center": [0.60, 0.05, -0.02]})
    d["constraints"] = [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.1, "displacement": [0.55, 0, 0]}]
    d["initial"] = {"lift": 0.03, "interpolate": True}
    assert _compile_warnings(d) == []


def test_a_millimetre_mold_out_of_reach_says_millimetres():
    # the sphere cap's mold written in millimetres and read as metres: 1000x too big and far off
    d = scene_dict(SHEET, **{"mold.sphere.center": [50.0, 50.0, -60.0], "mold.sphere.radius": 40.0})
    got = _compile_warnings(d)
    reach = [w for w in got if "can reach" in w]
    assert len(reach) == 1 and "millimetres?" in reach[0] and "mold.scale: 0.001" in reach[0]


def test_reach_warning_direct():
    from clothsim.mold import mold_primitive, mold_reach_warning

    sphere = mold_primitive("sphere", {"center": [1.0, 0.0, 0.0], "radius": 0.25})
    pts = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    # nearest point 1 - 0.1 - 0.25 = 0.65 m from the surface
    assert mold_reach_warning(sphere, pts, 0.7) is None
    w = mold_reach_warning(sphere, pts, 0.6)
    assert w is not None and "0.65 m" in w and "millimetres?" not in w
    assert mold_reach_warning(None, pts, 0.6) is None
    # a point inside the mold is in reach whatever the sheet's size
    assert mold_reach_warning(sphere, np.array([[1.0, 0.0, 0.0]]), 1e-3) is None


def test_cli_shows_the_reach_warning(tmp_path):
    import subprocess
    import sys

    import yaml

    d = scene_dict(SHEET, **{"mold.sphere.center": [0.60, 0.05, -0.02]})
    d["solver"]["max_iterations"] = 3
    p = tmp_path / "beside.yaml"
    p.write_text(yaml.safe_dump(d))
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), "run", str(p)], capture_output=True, text=True,
                       cwd=ROOT, env={**__import__("os").environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert "warning: mold: no node of the sheet can reach the mold" in r.stderr, r.stderr
