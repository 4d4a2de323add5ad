"""An index given as a share of the way across ("50%"): the nearest node, so a held middle column
keeps its place when a garment's divisions change (the scan stocking held wale 7, the middle
one only with 14 divisions; a lattice study had to move it by hand)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import clothsim
from clothsim.compile import compile_model
from clothsim.config import SceneError, scene_from_dict
from clothsim.selection import SelectionError, index_range, lattice_index

ROOT = Path(__file__).resolve().parents[1]
STOCKING = ROOT / "configs" / "garments" / "stocking.yaml"


@pytest.mark.parametrize("share,n,node", [("50%", 14, 7), ("50%", 15, 8), ("50%", 28, 14), ("0%", 9, 0),
                                          ("100%", 9, 9), ("35%", 10, 4), ("20%", 14, 3), ("80%", 28, 22),
                                          (-1, 9, 9), (3, 9, 3)])
def test_a_share_is_the_nearest_node_and_a_half_rounds_up(share, n, node):
    assert lattice_index(share, n) == node


def test_ranges_of_shares_and_their_errors():
    assert index_range(["25%", "75%"], 20, "i") == (5, 15)
    assert index_range("50%", 20, "i") == (10, 10)
    with pytest.raises(SelectionError, match=r"i range \['75%', '25%'\] outside 0..20"):
        index_range(["75%", "25%"], 20, "i")


def _sheet(i):
    return {"fabric": {"size": [1.0, 0.5], "divisions": [10, 4],
                       "warp": {"preset": "isotropic_paper"}, "weft": {"preset": "isotropic_paper"}},
            "constraints": [{"nodes": {"i": i}, "axes": "x"}]}


@pytest.mark.parametrize("given,kept", [("50%", "50%"), (" 50 %", "50%"), ("12.5%", "12.5%"),
                                        ("50.0%", "50%"), ("33.33333333%", "33.33333333%"),
                                        ("12.4999999%", "12.4999999%")])
def test_the_schema_keeps_a_share_as_its_text(given, kept):
    assert scene_from_dict(_sheet(given)).constraints[0].nodes.i == kept


@pytest.mark.parametrize("bad", ["150%", "-5%", "x%", "50", "half"])
def test_a_bad_share_is_refused_naming_the_field(bad):
    with pytest.raises(SceneError, match=r"constraints\.0\.nodes\.i: must be an integer or a share of the way "
                                         r"across from 0% to 100%"):
        scene_from_dict(_sheet(bad))


def test_a_bad_share_in_a_range_is_one_error_line():
    with pytest.raises(SceneError) as exc:
        scene_from_dict(_sheet([0, "150%"]))
    lines = str(exc.value).splitlines()
    assert len(lines) == 1 and lines[0].startswith("<scene>: constraints.0.nodes.i.1: must be an integer or a share"), lines


def _held_x(scene):
    model = compile_model(scene)
    return np.flatnonzero(model.fixed_axes[:, 0]), model


def test_the_stocking_holds_the_same_wale_as_before_on_its_lattice():
    """On its 14 divisions "50%" is wale 7, the wale the stocking held before: same nodes."""
    share, _ = _held_x(clothsim.load_scene(STOCKING))
    seven, _ = _held_x(clothsim.load_scene(STOCKING, ["constraints.2.nodes.i=7"]))
    assert share.size == 31 and np.array_equal(share, seven)


def test_the_stocking_holds_its_middle_wale_on_a_doubled_lattice():
    """Doubled (28 x 60 per panel), only the bottom seams' columns need moving: the held wale is
    the front's wale 14, the middle one (it was wale 7, a quarter of the way across)."""
    over = ["panels.0.divisions=[28,60]", "panels.1.divisions=[28,60]", "seams.2.a.i=22", "seams.2.b.i=6",
            "seams.3.a.i=22", "seams.3.b.i=6"]
    held, model = _held_x(clothsim.load_scene(STOCKING, over))
    fourteen, _ = _held_x(clothsim.load_scene(STOCKING, over + ["constraints.2.nodes.i=14"]))
    assert held.size == 61 and np.array_equal(held, fourteen)
    front = model.topology.panel_index("front")
    ij = model.topology.node_ij[held]
    assert set(model.topology.node_panel[held]) == {front} and set(ij[:, 0]) == {14}
