"""The lattice Topology, node selection and the compile step: checked against the rectangle the
first version hard-coded (node numbering k = i (ny+1) + j, warp then weft springs), against hand
counts on a non-rectangular lattice, and the compile step against the scene it reads."""

import numpy as np
import pytest

from clothsim.compile import compile_model, compile_scene
from clothsim.config import scene_from_dict
from clothsim.grid import coarsen_model
from clothsim.selection import SelectionError, seam_pairs, select_nodes
from clothsim.topology import Topology


def test_rectangle_numbering_and_springs():
    """Node (i, j) is k = i (ny+1) + j; warp spring (i, j) joins k and k + ny+1, weft k and k+1."""
    nx, ny = 4, 3
    t = Topology.rectangle(nx, ny)
    assert t.is_grid and t.grid_shape == (5, 4) and t.node_count == 20
    i, j = t.node_ij.T
    np.testing.assert_array_equal(i * (ny + 1) + j, np.arange(20))
    assert t.warp_count == nx * (ny + 1) and t.weft_count == (nx + 1) * ny
    np.testing.assert_array_equal(t.warp[:, 1] - t.warp[:, 0], ny + 1)
    np.testing.assert_array_equal(t.weft[:, 1] - t.weft[:, 0], 1)
    assert t.node(2, 3) == 2 * 4 + 3 and t.node(5, 0) == -1
    # faces: two per cell, each cell's two triangles covering it
    assert t.faces.shape == (2 * nx * ny, 3)
    # boundary = perimeter
    assert t.boundary.sum() == 2 * (nx + 1) + 2 * (ny - 1)


def _l_shape():
    """An L: a 5 x 5 node grid without its top-right 2 x 2 nodes."""
    m = np.ones((5, 5), bool)
    m[3:, 3:] = False
    return Topology.from_masks([m], ["L"])


def test_non_rectangular_lattice_counts():
    """Counted by hand on the L: 21 nodes; warp springs where (i, j) and (i+1, j) exist."""
    t = _l_shape()
    assert not t.is_grid and t.node_count == 21
    # warp: rows j = 0..2 have 4 springs, rows j = 3, 4 have 2 (i = 0..2)
    assert t.warp_count == 3 * 4 + 2 * 2
    assert t.weft_count == t.warp_count  # symmetric L
    # cells: 16 in the 4 x 4 cell grid less the 4 that touch a missing node
    assert t.cells.shape[0] == 16 - 4
    with pytest.raises(ValueError, match="not one full rectangle"):
        _ = t.grid_shape
    g = t.to_grid(np.arange(21.0))
    assert g.shape == (5, 5) and np.isnan(g[4, 4]) and g[0, 0] == 0


def test_areas_and_widths_sum_to_the_lattice_area():
    """An L-shaped outline on the lattice lines: node areas sum to its area (12 cells of dx dy)
    and warp (weft) widths x lengths cover it once."""
    from clothsim.grid import lattice_springs
    from clothsim.panels import panel_geometry

    dx, dy = 0.02, 0.03
    g = panel_geometry("L", [[0, 0], [4 * dx, 0], [4 * dx, 2 * dy], [2 * dx, 2 * dy], [2 * dx, 4 * dy], [0, 4 * dy]],
                       spacing=(dx, dy))
    t = Topology.from_masks([g.mask])
    area = g.node_area()
    assert area.sum() == pytest.approx(12 * dx * dy, rel=1e-14)
    sp = lattice_springs(t, [g], [(0, 1)])
    nodes, rest, width, table, family = sp.arrays()
    warp = family == 0
    assert (rest[warp] * width[warp]).sum() == pytest.approx(12 * dx * dy, rel=1e-14)
    assert (rest[~warp] * width[~warp]).sum() == pytest.approx(12 * dx * dy, rel=1e-14)
    # deformed area of the flat lattice equals the rest area
    pos = np.c_[t.node_ij * [dx, dy], np.zeros(t.node_count)]
    np.testing.assert_allclose(t.deformed_node_area(pos), area, rtol=1e-13)


def test_spread_is_the_mean_of_adjacent_springs():
    t = Topology.rectangle(3, 2)
    v = np.arange(t.warp_count, dtype=float)
    s = t.spread(v, "warp")
    # node (1, 1): warp springs (0, 1) and (1, 1) -> indices 0*3+1 and 1*3+1
    assert s[t.node(1, 1)] == pytest.approx((1 + 4) / 2)
    # node (0, 1): only warp spring (0, 1)
    assert s[t.node(0, 1)] == 1


def test_coarsen_is_the_stride_two_lattice():
    t = Topology.rectangle(8, 4)
    c, sub = t.coarsen()
    assert c.grid_shape == (5, 3)
    np.testing.assert_array_equal(t.node_ij[sub], 2 * c.node_ij)
    lc, lsub = _l_shape().coarsen()
    np.testing.assert_array_equal(_l_shape().node_ij[lsub], 2 * lc.node_ij)


def test_selection_on_a_topology():
    t = Topology.rectangle(4, 3)
    m = select_nodes("left", t)
    np.testing.assert_array_equal(np.nonzero(m)[0], [t.node(0, j) for j in range(4)])
    assert select_nodes("perimeter", t).sum() == 14
    with pytest.raises(SelectionError, match="i range"):
        select_nodes(type("S", (), {"i": [0, 9], "j": None})(), t)
    seam = type("Seam", (), {"a": "left", "b": "right", "reverse": False})()
    a, b, share, dirs = seam_pairs(seam, t)
    np.testing.assert_array_equal(t.node_ij[a, 0], 0)
    np.testing.assert_array_equal(t.node_ij[b, 0], 4)
    assert share.tolist() == [0.5, 1, 1, 0.5] and dirs == ((0, 1), (0, 1))


def test_compile_scene_reads_the_scene_once():
    """compile_scene gives the model and the state; the model carries its lattice, and the coarse
    model of grid sequencing is the same builder on the stride-2 lattice (its widths and areas are
    the fine rules at twice the spacing)."""
    scene = scene_from_dict({
        "fabric": {"size": [0.08, 0.04], "divisions": [8, 4],
                   "warp": {"strain": [0, 1], "tension": [0, 100]}, "weft": {"strain": [0, 1], "tension": [0, 50]}},
        "constraints": [{"nodes": "left", "axes": "xyz"}, {"nodes": "right", "axes": "xyz", "displacement": [0.01, 0, 0]}],
        "shear": {"stiffness": 1.0}, "bending": {"stiffness": 1.0},
    })
    model, state = compile_scene(scene)
    assert model.topology.grid_shape == (9, 5)
    assert state.positions.shape == (45, 3)
    assert model.node_area.sum() == pytest.approx(0.08 * 0.04, rel=1e-14)
    coarse, sub = coarsen_model(model)
    assert coarse.topology.grid_shape == (5, 3)
    assert coarse.node_area.sum() == pytest.approx(0.08 * 0.04, rel=1e-14)
    fresh = compile_model(scene_from_dict({**scene.to_dict(), "fabric": {**scene.to_dict()["fabric"], "divisions": [4, 2]}}))
    for f in ("spring_nodes", "spring_rest_length", "spring_width", "spring_table", "spring_family", "node_area"):
        np.testing.assert_allclose(getattr(coarse, f), getattr(fresh, f), rtol=1e-15, err_msg=f)
