"""Pattern panels (clothsim.panels, scene ``panels``): the cut lattice's areas and widths against
the polygon's exact area, the one-panel shorthand against a rectangle given as a panel (bit for
bit), a trapezoid strip against its material table, the two-panel sleeve against the one-panel
sleeve, and the error messages."""

from pathlib import Path

import numpy as np
import pytest
import shapely

import clothsim
from clothsim.compile import compile_model
from clothsim.config import SceneError, scene_from_dict
from clothsim.panels import PanelError, check_outline, panel_geometry, rectangle_geometry

ROOT = Path(__file__).resolve().parents[1]
TABLE = {"strain": [0, 0.1, 0.3, 0.6, 1.0], "tension": [0, 12, 55, 140, 300]}


def _circle(r=0.05, n=720):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[r * np.cos(t), r * np.sin(t)]


@pytest.mark.parametrize("grain", [(1, 0), (1, 1), (2, -1)])
@pytest.mark.parametrize("h", [0.01, 0.005, 0.0025])
def test_node_areas_and_band_widths_sum_to_the_polygon(grain, h):
    """Node areas sum to the outline's area, and so do warp (weft) widths x rest lengths: the
    membrane carries the whole panel in each yarn direction, whatever the lattice's offset and
    the grain's angle (1e-12 relative, at every refinement)."""
    outline = _circle()
    area = shapely.Polygon(outline).area
    g = panel_geometry("c", outline, grain, spacing=h)
    cell = g.spacing[0] * g.spacing[1]
    assert g.node_area().sum() == pytest.approx(area, rel=1e-12)
    assert g.warp_frac.sum() * cell == pytest.approx(area, rel=1e-12)
    assert g.weft_frac.sum() * cell == pytest.approx(area, rel=1e-12)


def test_rectangle_outline_is_the_rectangle_rule():
    """A rectangle outline on lattice lines gives exactly the paper's rule (half widths on border
    springs, quarter cells at corners), even when size / spacing is not exact in floating point."""
    g = panel_geometry("r", [[0, 0], [0.157, 0], [0.157, 0.2], [0, 0.2]], divisions=(25, 8))
    q = rectangle_geometry("q", 25, 8, 0.157 / 25, 0.2 / 8)
    for f in ("mask", "node_frac", "warp_frac", "weft_frac", "cell_frac"):
        np.testing.assert_array_equal(getattr(g, f), getattr(q, f), err_msg=f)


def _strip(panel: bool):
    d = {"name": "strip", "fabric": {"warp": TABLE, "weft": TABLE},
         "constraints": [{"nodes": "left", "axes": "xyz"}, {"nodes": "right", "axes": "xyz", "displacement": [0.03, 0, 0]}],
         "shear": {"stiffness": 2.0}, "bending": {"stiffness": 1.0}, "gravity": {"areal_density": 0.2},
         "seams": [{"a": {"i": [0, 3], "j": 0}, "b": {"i": [5, 8], "j": 0}, "reverse": True}],
         "solver": {"e": 1e-9}}
    if panel:
        d["panels"] = [{"name": "fabric", "outline": [[0, 0], [0.1, 0], [0.1, 0.02], [0, 0.02]], "divisions": [20, 4]}]
    else:
        d["fabric"].update(size=[0.1, 0.02], divisions=[20, 4])
    return scene_from_dict(d)


def test_rectangle_as_panels_is_bit_identical_to_fabric():
    """The ``fabric:`` rectangle is the one-panel shorthand: the same scene given as a panel
    builds the same arrays bit for bit (every optional term on) and solves to the same state."""
    a, b = compile_model(_strip(False)), compile_model(_strip(True))
    for f in ("rest_positions", "spring_nodes", "spring_rest_length", "spring_width", "spring_table", "spring_family",
              "fixed_axes", "prescribed_positions", "external_force", "node_area", "adj_ptr", "adj_node", "adj_spring"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    ra, rb = clothsim.solve(_strip(False)), clothsim.solve(_strip(True))
    np.testing.assert_array_equal(ra.state.positions, rb.state.positions)


def test_trapezoid_strip_reproduces_the_table():
    """A trapezoid strip (ends cut at an angle, long sides off the lattice lines: the top edge
    crosses its cells at 0.65 of a cell) pulled along the grain: in its middle every warp spring
    has the same strain, and the force across any column is T(strain) x the strip's width — the
    cut cells carry exactly their share."""
    W, L, u = 0.0213, 0.12, 0.01
    scene = scene_from_dict({
        "fabric": {"warp": TABLE, "weft": TABLE},
        "panels": [{"name": "strip", "outline": [[0, 0], [L, 0], [L - 0.01, W], [0.01, W]], "spacing": 0.002}],
        "constraints": [{"nodes": {"i": [0, 6]}, "axes": "xyz"},
                        {"nodes": {"i": [-7, -1]}, "axes": "xyz", "displacement": [u, 0, 0]}],
        "solver": {"method": "newton", "e": 1e-10},
    })
    r = clothsim.solve(scene)
    assert r.converged
    m = r.model
    topo = m.topology
    strain, force = r._f()[0], r._f()[1]
    warp = slice(0, topo.warp_count)
    i0 = topo.node_ij[topo.warp[:, 0], 0]
    middle = (i0 >= 6) & (i0 < 54)
    eps = u / (0.002 * 48)
    np.testing.assert_allclose(strain[warp][middle], eps, rtol=1e-9)
    T = np.interp(eps, TABLE["strain"], TABLE["tension"])
    for col in (10, 30, 50):
        f = force[warp][i0 == col].sum()
        assert f == pytest.approx(T * W, rel=1e-9)


def test_two_panel_sleeve_equals_one_panel_sleeve():
    """configs/garments/sleeve_two_panel.yaml (two halves sewn on both sides) against
    configs/sewn_sleeve.yaml (one panel sewn to itself): hoop strain and contact pressure within
    1e-6 relative. The seams are made stiff (1e10 N/m^2) so that the second seam's gap (T / k)
    is below that tolerance."""
    k = 1e10
    one = clothsim.solve(clothsim.load_scene(ROOT / "configs/sewn_sleeve.yaml",
                                             ["solver.method=newton", "solver.e=1e-9", f"seams.0.stiffness={k}"]))
    two = clothsim.solve(clothsim.load_scene(ROOT / "configs/garments/sleeve_two_panel.yaml",
                                             ["solver.e=1e-9", f"seams.0.stiffness={k}", f"seams.1.stiffness={k}"]))
    assert one.converged and two.converged
    s1, s2 = one.summary(), two.summary()
    assert s2["max_strain_warp"] == pytest.approx(s1["max_strain_warp"], rel=1e-6)
    assert s2["max_contact_pressure_pa"] == pytest.approx(s1["max_contact_pressure_pa"], rel=1e-6)
    # the mid-height ring's pressure, node by node, is the same T / r
    for r in (one, two):
        z = r.state.positions[:, 2]
        ring = np.abs(z - np.median(z)) < 1e-3
        p = r._f()[3][ring]
        assert p.min() == pytest.approx(s1["max_contact_pressure_pa"], rel=2e-6)


def test_outline_selector_and_edges():
    """``outline`` holds a cut panel's boundary; an ``edge`` follows outline vertices in order."""
    sq = [[0, 0], [0.04, 0], [0.04, 0.02], [0, 0.02]]
    scene = scene_from_dict({
        "fabric": {"warp": TABLE, "weft": TABLE},
        "panels": [{"name": "p", "outline": sq, "divisions": [4, 2]}],
        "constraints": [{"nodes": "outline", "axes": "z"}, {"nodes": {"panel": "p", "edge": [1, 2]}, "axes": "x"}],
    })
    m = compile_model(scene)
    ij = m.topology.node_ij
    on_outline = (ij[:, 0] == 0) | (ij[:, 0] == 4) | (ij[:, 1] == 0) | (ij[:, 1] == 2)
    np.testing.assert_array_equal(m.fixed_axes[:, 2], on_outline)
    np.testing.assert_array_equal(m.fixed_axes[:, 0], ij[:, 0] == 4)
    from clothsim.selection import edge_nodes

    e = edge_nodes(m.topology, 0, (1, 2))
    assert ij[e].tolist() == [[4, 0], [4, 1], [4, 2]]


@pytest.mark.parametrize("outline, msg", [
    ([[0, 0], [1, 0]], "at least 3 points"),
    ([[0, 0], [1, 0], [2, 0]], "not a simple polygon|zero area"),
    ([[0, 0], [1, 1], [1, 0], [0, 1]], "not a simple polygon"),
])
def test_bad_outlines_are_refused(outline, msg):
    with pytest.raises(PanelError, match=msg):
        check_outline(outline, "front")
    with pytest.raises(SceneError, match=r"panels\.0\.outline"):
        scene_from_dict({"fabric": {"warp": TABLE, "weft": TABLE},
                         "panels": [{"name": "front", "outline": outline, "spacing": 0.1}]}, "x.yaml")


def test_panel_scene_errors():
    base = {"fabric": {"warp": TABLE, "weft": TABLE},
            "panels": [{"name": "a", "outline": [[0, 0], [0.1, 0], [0.1, 0.1]], "spacing": 0.01}]}
    with pytest.raises(SceneError, match="unknown panel 'b'"):
        scene_from_dict({**base, "constraints": [{"nodes": {"panel": "b", "side": "left"}}]}, "x.yaml")
    with pytest.raises(SceneError, match="fabric.size: not used with panels"):
        scene_from_dict({**base, "fabric": {**base["fabric"], "size": [1, 1]}}, "x.yaml")
    with pytest.raises(SceneError, match="fabric.size: missing"):
        scene_from_dict({"fabric": {"warp": TABLE, "weft": TABLE, "divisions": [2, 2]}}, "x.yaml")
    with pytest.raises(SceneError, match="used twice"):
        scene_from_dict({**base, "panels": base["panels"] * 2}, "x.yaml")
    with pytest.raises(SceneError, match="spacing or divisions"):
        scene_from_dict({**base, "panels": [{"name": "a", "outline": [[0, 0], [1, 0], [1, 1]]}]}, "x.yaml")
    rect = {"name": "a", "outline": [[0, 0], [0.1, 0], [0.1, 0.05], [0, 0.05]], "spacing": 0.01}
    bad_seam = {**base, "panels": [rect],
                "seams": [{"a": {"panel": "a", "edge": [0, 1]}, "b": {"panel": "a", "edge": [1, 2]}}]}
    # edges of unequal node counts are sewn along arc length (tests/test_seam_elements.py) ...
    assert compile_model(scene_from_dict(bad_seam, "x.yaml")).seam_count == 11
    # ... but a single node cannot be
    bad_seam["seams"] = [{"a": {"panel": "a", "i": 0, "j": 0}, "b": {"panel": "a", "edge": [1, 2]}}]
    with pytest.raises(SceneError, match=r"seams\.0\.a: selects one node but b selects 6"):
        compile_model(scene_from_dict(bad_seam, "x.yaml"))


def test_circular_blank_converges_under_refinement():
    """configs/garments/circle_cap.yaml (a circular blank cut from the lattice, its outline held
    and stretched 10 %, pressed by a sphere) at 40, 80 and 160 divisions: the total contact force
    and the mean pressure over the apex (1 cm) settle — each refinement changes them at least
    twice less than the one before — and the hoop-ring strain agrees to 5e-4 relative."""
    out = []
    for n in (40, 80, 160):
        r = clothsim.solve(clothsim.load_scene(ROOT / "configs/garments/circle_cap.yaml",
                                               [f"panels.0.divisions=[{n},{n}]", "solver.e=1e-8",
                                                "solver.method=newton"]))
        assert r.converged
        p, pressure, area = r.state.positions, r._f()[3], r.model.node_area
        d = np.linalg.norm(p[:, :2] - [0.05, 0.05], axis=1)
        apex = d < 0.01
        ring = (d > 0.03) & (d < 0.035)
        out.append((r._f()[2].sum(), (pressure[apex] * area[apex]).sum() / area[apex].sum(),
                    r._node_strain()[ring].mean()))
    (f1, p1, s1), (f2, p2, s2), (f3, p3, s3) = out
    assert abs(f3 - f2) < 0.5 * abs(f2 - f1)
    assert abs(p3 - p2) < 0.5 * abs(p2 - p1)
    assert s3 == pytest.approx(s2, rel=5e-4) and s2 == pytest.approx(s1, rel=5e-4)


@pytest.mark.parametrize("preconditioner", ["geometric", "amg"])
def test_newton_preconditioners_on_a_cut_lattice(preconditioner):
    """Newton on a cut lattice, with multigrid forced on a small circle: the padded geometric
    multigrid and PyAMG's smoothed aggregation both precondition CG to the equilibrium the direct
    factorisation reaches (1e-9 m)."""
    from clothsim.compile import compile_scene
    from clothsim.solvers.newton import NewtonLevel

    scene = clothsim.load_scene(ROOT / "configs/garments/circle_cap.yaml", ["panels.0.divisions=[30,30]"])
    ends = []
    for kw in ({"use_multigrid": False}, {"use_multigrid": True, "preconditioner": preconditioner}):
        model, state = compile_scene(scene)
        lvl = NewtonLevel(model, **kw)
        assert (lvl.mg is None) == (not kw["use_multigrid"])
        v = lvl.residual(state.positions, state.in_contact)
        for _ in range(60):
            if v < 1e-10:
                break
            v, _, flag = lvl.iterate(state, v, forcing=1e-10)
        assert v < 1e-9
        ends.append(state.positions.copy())
    assert np.abs(ends[0] - ends[1]).max() < 1e-9


def test_a_scene_too_big_for_the_memory_is_refused_before_building(monkeypatch):
    """Issue 15 item 5: --set fabric.divisions=[1999,1999] reached 10 GB before failing; the
    compile step now estimates the memory first and refuses with the estimate (exit 2 in the
    CLI), here against a pretended 2 GB available."""
    from clothsim.compile import check_memory

    scene = clothsim.load_scene(ROOT / "configs/thermoform.yaml", ["fabric.divisions=[1999,1999]"])
    with pytest.raises(SceneError, match=r"fabric.divisions: 4,000,000 nodes need about 16.2 GB of memory; 2.0 GB"):
        check_memory(scene, available=2e9)
    check_memory(clothsim.load_scene(ROOT / "configs/thermoform.yaml"), available=2e9)
    import psutil

    monkeypatch.setattr(psutil, "virtual_memory", lambda: type("M", (), {"available": 1e9})())
    with pytest.raises(SceneError, match="GB of memory"):
        compile_model(scene)
