"""The start of sewn and placed panels (clothsim.initial): panels sewn edge to edge spread and
dome as the one sheet they make, and a rigidly placed panel's displacement reaches its interior.

Known answers: a sheet held on its outline stretched by s about its centre starts uniformly
stretched (the harmonic spread of a linear field is that field), so four quarter panels sewn edge
to edge must start where the one sheet starts; a strip pulled at one end starts uniformly
stretched, whatever rigid placement turns it in space."""

import numpy as np
import pytest

from clothsim.config import scene_from_dict
from clothsim.grid import FAMILY_SEAM
from clothsim.initial import SEAM_SPREAD_WEIGHT
from clothsim.simulation import prepare
from clothsim.solvers.tuning import NewtonTuning

LIN = {"strain": [0, 1], "tension": [0, 250]}


def _four_panels(lift=0.0, d=10):
    """Four 0.05 m quarter panels (d x d divisions) sewn edge to edge into a 0.1 m sheet, the outer
    edges held on the sheet stretched 10 % about its centre (each panel's stretch acts about its
    own centre; a displacement moves it to the sheet's)."""
    quads = (("bl", 0.0, 0.0), ("br", 0.05, 0.0), ("tl", 0.0, 0.05), ("tr", 0.05, 0.05))
    panels, cons = [], []
    for name, tx, ty in quads:
        panels.append({"name": name, "outline": [[0, 0], [0.05, 0], [0.05, 0.05], [0, 0.05]], "divisions": [d, d],
                       "placement": {"transform": {"translate": [tx, ty, 0.0]}}})
        ox = 0 if tx == 0 else -1
        oy = 0 if ty == 0 else -1
        disp = [0.1 * (tx + 0.025 - 0.05), 0.1 * (ty + 0.025 - 0.05), 0.0]
        cons.append({"nodes": {"panel": name, "i": ox, "j": None}, "axes": "xyz", "stretch": 1.1,
                     "displacement": disp})
        cons.append({"nodes": {"panel": name, "i": [1, -1] if ox == 0 else [0, -2], "j": oy}, "axes": "xyz",
                     "stretch": 1.1, "displacement": disp})
    seams = [{"a": {"panel": "bl", "side": "right"}, "b": {"panel": "br", "side": "left"}},
             {"a": {"panel": "tl", "side": "right"}, "b": {"panel": "tr", "side": "left"}},
             {"a": {"panel": "bl", "side": "top"}, "b": {"panel": "tl", "side": "bottom"}},
             {"a": {"panel": "br", "side": "top"}, "b": {"panel": "tr", "side": "bottom"}}]
    scene = scene_from_dict({"name": "four", "fabric": {"warp": LIN, "weft": LIN}, "panels": panels,
                             "seams": seams, "constraints": cons, "initial": {"lift": lift}})
    model, state, _ = prepare(scene)
    return model, state


def test_four_sewn_panels_start_uniformly_stretched_like_one_sheet():
    """In plane, every node of the four sewn quarters starts at centre + 1.1 (rest - centre): the
    one sheet's uniformly stretched start, within the seam coupling's bound (the displacement
    across one link, 0.1 x 5 mm, over ``SEAM_SPREAD_WEIGHT``). Each
    panel spread alone, the start had the seams 1 cm open (each quarter shifted by its held
    edges' displacement only)."""
    model, state = _four_panels()
    placed = model.placement.apply(model.rest_positions)
    c = np.array([0.05, 0.05])
    want = c + 1.1 * (placed[:, :2] - c)
    bound = 0.1 * 0.005 / SEAM_SPREAD_WEIGHT
    np.testing.assert_allclose(state.positions[:, :2], want, atol=bound, rtol=0)
    sn = model.spring_nodes[model.spring_family == FAMILY_SEAM]
    gap = np.linalg.norm(state.positions[sn[:, 0]] - state.positions[sn[:, 1]], axis=1)
    assert gap.max() < bound


def test_four_sewn_panels_are_lifted_as_one_dome():
    """With ``lift``, the sewn quarters start as one dome over the joined sheet: highest (= lift)
    at the sheet's centre, where the seams cross, the seams' sides at equal heights, zero on the
    held outline, and symmetric under the sheet's mirror x -> 0.1 - x."""
    lift = 0.03
    model, state = _four_panels(lift=lift)
    z = state.positions[:, 2]
    placed = model.placement.apply(model.rest_positions)
    centre = np.nonzero(np.linalg.norm(placed[:, :2] - 0.05, axis=1) < 1e-12)[0]
    assert centre.size == 4  # the corner of each quarter
    assert z[centre] == pytest.approx(np.full(4, lift), abs=1e-12)
    assert z.max() == pytest.approx(lift, abs=1e-12)
    held = model.fixed_axes.all(axis=1)
    assert np.abs(z[held]).max() == 0.0
    sn = model.spring_nodes[model.spring_family == FAMILY_SEAM]
    assert np.abs(z[sn[:, 0]] - z[sn[:, 1]]).max() < 1e-6 * lift
    # the mirror image of each node (x -> 0.1 - x) starts at the same height
    key = {tuple(np.round(p[:2], 9)): k for k, p in enumerate(placed)}
    mirror = np.array([key[(round(0.1 - p[0], 9), round(p[1], 9))] for p in placed])
    np.testing.assert_allclose(z, z[mirror], atol=1e-6 * lift)


def test_a_rotated_panel_pulled_at_one_end_starts_uniformly_stretched():
    """A strip panel turned 90 degrees about z and moved, held at its left end and pulled 30 %
    along its grain at the right end by a displacement given in space: every warp spring starts
    at the same length (the stretch 1.3, within 1e-12 relative). Before the displacement was
    turned back into the panel's plane, the interior started unstretched and the last spring
    carried the whole pull."""
    scene = scene_from_dict({
        "name": "turned", "fabric": {"warp": LIN, "weft": LIN},
        "panels": [{"name": "s", "outline": [[0, 0], [0.1, 0], [0.1, 0.02], [0, 0.02]], "divisions": [10, 2],
                    "placement": {"transform": {"rotate": [0, 0, 90], "translate": [0.3, 0.2, 0.1]}}}],
        "constraints": [{"nodes": {"panel": "s", "i": 0, "j": None}, "axes": "xyz"},
                        {"nodes": {"panel": "s", "i": -1, "j": None}, "axes": "xyz", "displacement": [0.0, 0.03, 0.0]}]})
    model, state, _ = prepare(scene)
    warp = model.spring_family == 0
    a, b = model.spring_nodes[warp].T
    length = np.linalg.norm(state.positions[b] - state.positions[a], axis=1)
    np.testing.assert_allclose(length, 1.3 * 0.01, rtol=1e-12)


def test_outline_band_of_sewn_panels_follows_the_outline_not_the_seams():
    """The outline band the sequencing settles (``rim.outline_band``) starts at held nodes and at
    unsewn nodes short of lattice neighbours: on four quarters sewn edge to edge and held on their
    outer edges it is the rows along the held edges, none along the seams (a sewn node's missing
    neighbours are across its seam). Each band node is within NewtonTuning.rim_band lattice steps of a held
    node of its panel, and the band holds every free unsewn node that is."""
    from clothsim.solvers.newton import rim

    model, _ = _four_panels(d=20)
    band = rim.outline_band(model)
    topo = model.topology
    held = np.nonzero(model.fixed_axes.any(axis=1))[0]
    sewn = np.zeros(model.node_count, bool)
    sewn[model.spring_nodes[model.spring_family == FAMILY_SEAM].ravel()] = True
    ij = topo.node_ij
    near = np.zeros(model.node_count, bool)
    for k in range(model.node_count):
        same = held[topo.node_panel[held] == topo.node_panel[k]]
        near[k] = np.abs(ij[same] - ij[k]).sum(axis=1).min() <= NewtonTuning().rim_band
    want = np.nonzero(near & ~model.fixed_axes.any(axis=1) & ~sewn)[0]
    np.testing.assert_array_equal(np.sort(band), want)
