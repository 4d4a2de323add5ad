"""Friction regions (``mold.friction_regions``): parts of the garment with their own Coulomb
coefficient against the mold (a silicone grip band). Checked against the capstan over part of
the arc (the frictionless part carries one tension; the frictional part multiplies it by
e^(mu phi) over the angle it turns through), against ``mold.friction`` when a region covers
every node, by finite differences of the friction's potential with a coefficient per node, and
for the scene's refusals."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from clothsim.bench.friction import column_tensions, turn_angle  # (T, d) of warp columns; wrap angle
from clothsim.compile import compile_model, compile_state
from clothsim.config import SceneError, load_scene
from clothsim.friction import lag_friction, normal_forces
from clothsim.solvers import Control, load_steps, solve
from clothsim.solvers.friction import solve_steps

ROOT = Path(__file__).resolve().parent.parent
WRAP = ROOT / "configs" / "cylinder_wrap.yaml"


def _pulled(nx, overrides, pull=0.06, steps=20):
    """The capstan strip (configs/cylinder_wrap.yaml, nx divisions) solved frictionless, then its
    right end pulled down ``pull`` [m] in ``steps`` load steps with the scene's friction:
    (the last step's model, with its friction, positions, the steps' result)."""
    sc = load_scene(WRAP, [f"fabric.divisions=[{nx},2]", "solver.method=newton", "solver.e=1e-7", *overrides])
    model = compile_model(sc)
    state = compile_state(sc, model)
    frictionless = dataclasses.replace(model, friction_mu=0.0, friction_mu_nodes=None)
    assert solve(frictionless, state, sc.solver).converged
    target = model.prescribed_positions.copy()
    right = model.fixed_axes[:, 2] & (model.rest_positions[:, 0] > 0.1)
    target[right, 2] -= pull
    last, res = solve_steps(model, state, load_steps(model.prescribed_positions, target, steps), sc.solver)
    return last, state.positions, res


def test_capstan_over_part_of_the_arc_is_e_to_mu_phi_over_that_part():
    """mu = 0.6 from 40 % of the strip to its pulled end, frictionless before: past slip the
    frictionless part carries one tension (T_split = T_left), and the frictional part multiplies
    it by e^(mu phi2), phi2 the angle the strip turns through from the region's first spring to
    its straight end. Measured: T_split / T_left - 1 = 3.9e-4, T_right / T_split against
    e^(0.6 phi2) -1.1e-4 at 40 divisions (-6.6e-5 at 80); the whole strip at 0.6 would give
    e^(0.6 phi) = 3.44 against the 2.88 read."""
    mu = 0.6
    model, pos, res = _pulled(40, [f"mold.friction_regions=[{{nodes: {{i: ['40%', '100%']}}, friction: {mu}}}]"])
    assert res.converged and res.residual <= 1e-7, res.message
    fr = res.friction
    assert fr["mu"] == 0.0 and fr["mu_max"] == mu and fr["slip"] > 0 and fr["cone_violation"] < 1e-5
    # only the band's nodes carry friction: the stick and slip counts are theirs
    in_band = model.friction_mu_nodes > 0
    lag = model.friction
    assert lag is not None and (model.friction_mu_nodes[lag.nodes] == mu).all()
    assert fr["stick"] + fr["slip"] == int((lag.lam > 0).sum())
    first = model.rest_positions[in_band, 0].min()
    assert first == pytest.approx(0.08)   # node 16 of 40
    h = 0.2 / 40
    (tl, dl), (tr, dr), (ts, ds) = column_tensions(model, pos, (h / 2, 0.2 - h / 2, first - h / 2))
    phi2, phi = turn_angle(ds, dr), turn_angle(dl, dr)
    assert 1.5 < phi2 < phi < 2.2
    assert ts / tl == pytest.approx(1.0, abs=2e-3)
    assert tr / ts == pytest.approx(math.exp(mu * phi2), rel=1e-3)
    assert tr / tl < 0.9 * math.exp(mu * phi)


def _grip_on_cone(mu_band, mu_rest):
    """The knit tube on the faceted leg cone (tan(alpha) = 0.05; tests/test_friction.py) solved
    frictionless with its cuffs held along the leg, then released with mu_rest on the tube and
    mu_band on its top quarter (rows from 75 %: a grip band): (the band's slip threshold from the
    frictionless normal forces, mean move along the leg [m], contact nodes before, after)."""
    sc = load_scene(ROOT / "configs" / "tube_on_leg_cone.yaml",
                    ["constraints.1.displacement=[0,0,0]", "fabric.divisions=[34,16]", "solver.e=3e-6",
                     "solver.time_limit_s=300", f"mold.friction={mu_rest}",
                     f"mold.friction_regions=[{{nodes: {{j: ['75%', '100%']}}, friction: {mu_band}}}]"])
    model = compile_model(sc)
    state = compile_state(sc, model)
    assert solve(dataclasses.replace(model, friction_mu=0.0, friction_mu_nodes=None), state, sc.solver).converged
    nodes, _, lam = normal_forces(model, state)
    band = model.friction_mu_nodes[nodes] == mu_band
    # along the leg the cone's reaction pushes the tube down by tan(alpha) per newton pressed; the
    # tube holds while its friction can take that: mu_band N_band + mu_rest N_rest >= tan(alpha) N
    threshold = (0.05 * lam.sum() - mu_rest * lam[~band].sum()) / lam[band].sum()
    z0, c0 = state.positions[:, 2].copy(), int(state.in_contact.sum())
    fixed = model.fixed_axes.copy()
    fixed[:, 2] = False  # the cuffs let go along the leg
    m = dataclasses.replace(model, fixed_axes=fixed)
    _, res = solve_steps(m, state, [Control(m.prescribed_positions)], sc.solver)
    assert res.converged, res.message
    return threshold, float(np.mean(state.positions[:, 2] - z0)), c0, int(state.in_contact.sum())


def test_a_grip_band_holds_a_tube_that_slides_without_it():
    """A tube whose knit slides on the cone (mu 0.03 < tan(alpha) = 0.05) is held by a grip band
    on its top quarter when the band's friction carries the rest: mu_band above the threshold
    (0.05 N - 0.03 N_rest) / N_band (0.087 here; the band presses 35 % of N). Measured: 1.3 and 1.2 times
    the threshold move the tube under 2 mm and 1.0 mm, 0.7 times lets it slide 8 cm, off the
    narrow end."""
    threshold, dz, c0, c1 = _grip_on_cone(0.087 * 1.3, 0.03)
    assert threshold == pytest.approx(0.087, rel=0.05)
    assert abs(dz) < 2e-3 and c1 == c0
    _, dz, c0, c1 = _grip_on_cone(0.087 * 0.7, 0.03)
    assert dz < -0.02 and c1 < 0.8 * c0


def test_a_region_over_every_node_is_mold_friction():
    """friction_regions [{nodes: all, friction: 0.3}] on a frictionless mold gives the positions
    mold.friction: 0.3 gives, to round-off."""
    m1, p1, r1 = _pulled(20, ["mold.friction=0.3"], steps=5)
    m2, p2, r2 = _pulled(20, ["mold.friction_regions=[{nodes: all, friction: 0.3}]"], steps=5)
    assert m1.friction_mu_nodes is None and m2.friction_mu == 0.0 and (m2.friction_mu_nodes == 0.3).all()
    assert r1.converged and r2.converged
    assert np.abs(p1 - p2).max() < 1e-12
    assert r2.friction["mu_max"] == 0.3 and "mu_max" not in r1.friction


def test_a_region_with_the_mold_coefficient_costs_nothing():
    sc = load_scene(WRAP, ["solver.method=newton", "mold.friction=0.3",
                           "mold.friction_regions=[{nodes: {i: [0, 10]}, friction: 0.3}]"])
    assert compile_model(sc).friction_mu_nodes is None
    sc = load_scene(WRAP, ["solver.method=newton", "mold.friction_regions=[{nodes: all, friction: 0}]"])
    m = compile_model(sc)
    assert m.friction_mu_nodes is None and not m.has_friction


def test_friction_with_a_coefficient_per_node_is_the_derivative_of_its_potential():
    """The lagged friction of a model whose regions give its contact nodes different mu: its
    force is minus the central difference of its potential, node by node, and each node's weight
    is its own mu times its normal force."""
    model, pos, _ = _pulled(20, ["mold.friction=0.2", "mold.friction_regions=[{nodes: {i: ['50%', '100%']}, friction: 0.7}]"],
                            steps=3)
    state = compile_state(load_scene(WRAP, ["fabric.divisions=[20,2]"]), model)
    state.positions[:] = pos
    state.in_contact[:] = model.mold is not None
    from clothsim.mold import mold_query_many
    d = np.empty(model.node_count)
    mold_query_many(model.mold.kernel_args(), np.ascontiguousarray(pos), d, np.empty((model.node_count, 3)),
                    np.empty((model.node_count, 3)), np.empty((model.node_count, 2), np.int64))
    state.in_contact[:] = d < 1e-6
    anchor = pos.copy()
    anchor[:, 0] -= 3e-5   # a slide along the strip: some nodes stick (below eps), none at rest
    lag = lag_friction(model, state, anchor)
    # each node's weight is its region's mu (read off its lattice column: from 50 % of 20
    # divisions, 0.7) times its normal force
    col = model.topology.node_ij[lag.nodes, 0]
    assert set(col < 10) == {True, False}
    assert np.array_equal(lag.weight, np.where(col >= 10, 0.7, 0.2) * lag.lam)
    m = dataclasses.replace(model, friction=lag)
    F = np.zeros_like(pos)
    m.add_friction_forces(pos, F)
    h = 1e-9
    for k in lag.nodes[:: max(1, len(lag.nodes) // 6)]:
        for a in range(3):
            p, q = pos.copy(), pos.copy()
            p[k, a] += h
            q[k, a] -= h
            fd = -(m.add_friction_forces(p, np.zeros_like(p)) - m.add_friction_forces(q, np.zeros_like(q))) / (2 * h)
            assert fd == pytest.approx(F[k, a], rel=1e-5, abs=1e-9 * max(1.0, np.abs(F).max()))


def _write(tmp_path, text):
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return p


HEAD = ("fabric: {size: [0.1, 0.02], divisions: [10, 2], warp: {preset: powernet_est}, "
        "weft: {preset: powernet_est}}\n"
        "mold:\n  cylinder: {center: [0, 0, -0.1], axis: [0, 1, 0], radius: 0.05, length: 0.2}\n")


@pytest.mark.parametrize("region,msg", [
    ("{nodes: all, friction: -1}", r"s\.yaml:5: mold\.friction_regions\.0\.friction: must be a number from 0 to 10"),
    ("{nodes: everywhere, friction: 1}", r"s\.yaml:5: mold\.friction_regions\.0\.nodes: unknown node set 'everywhere'"),
    ("{nodes: {i: [0, 12]}, friction: 1}", r"s\.yaml:5: mold\.friction_regions\.0\.nodes: friction_regions: i range "
                                           r"\[0, 12\] outside 0\.\.10"),
    ("{nodes: {panel: front}, friction: 1}", r"mold\.friction_regions\.0\.nodes\.panel: unknown panel 'front'"),
    ("{nodes: all}", r"s\.yaml:5: mold\.friction_regions\.0\.friction: missing"),
])
def test_bad_regions_are_refused_with_file_line_and_field(tmp_path, region, msg):
    p = _write(tmp_path, HEAD + f"  friction_regions:\n    - {region}\n")
    with pytest.raises(SceneError, match=msg):
        load_scene(p)


def test_the_paper_method_refuses_a_frictional_region(tmp_path):
    p = _write(tmp_path, HEAD + "  friction_regions: [{nodes: left, friction: 0.5}]\nsolver: {method: paper}\n")
    with pytest.raises(SceneError, match=r"solver\.method: 'paper' is frictionless .* "
                                         r"mold\.friction_regions\.0\.friction is 0\.5"):
        load_scene(p)
    load_scene(p, ["mold.friction_regions.0.friction=0"])


def test_a_region_on_a_panel_that_selects_no_node_is_refused():
    sc = load_scene(ROOT / "configs" / "garments" / "stocking_friction.yaml",
                    ["mold.friction_regions=[{nodes: {panel: front, i: 0, j: 0}, friction: 1.0}]"])
    with pytest.raises(SceneError, match=r"mold\.friction_regions\.0\.nodes: selects no nodes"):
        compile_model(sc)


def test_the_report_names_each_region_and_checks_them_when_read():
    """The scene in short (result.npz's scene_summary) carries the regions at the end of the
    loading path; the report's assumptions and scene table name them; a summary whose region is
    not a number or not text is refused naming the key."""
    import json

    from clothsim.compression.folder import scene_brief
    from clothsim.compression.report import ReportError, check_scene_summary
    from clothsim.compression.report_html import _assumptions, _scene_summary

    from clothsim.reportdata import scene_summary

    sc = load_scene(ROOT / "configs" / "garments" / "stocking_friction.yaml",
                    ["stages.1.set={mold.friction: 0.4, mold.friction_regions: "
                     "[{nodes: {panel: front, j: [90%, 100%]}, friction: 1.2}]}"])
    # as result.npz holds it: the brief with what the run adds
    brief = json.loads(json.dumps(scene_summary(scene_brief(sc), compile_model(sc))))
    assert brief["friction_regions"] == [{"nodes": "panel front, j 90% to 100%", "friction": 1.2}]
    assert "mu = 0.4 between garment and skin; mu = 1.2 on panel front, j 90% to 100%" in _assumptions(brief, {})
    assert "Coulomb, mu = 0.4; mu = 1.2 on panel front, j 90% to 100%" in _scene_summary(brief)
    assert check_scene_summary(np.array(json.dumps(brief)), "r.npz")["friction_regions"][0]["friction"] == 1.2
    for bad, key in ((dict(brief, friction_regions=[{"nodes": "all", "friction": "x"}]), r"friction_regions\[0\]\.friction"),
                     (dict(brief, friction_regions=[{"nodes": 3, "friction": 1.0}]), r"friction_regions\[0\]\.nodes"),
                     (dict(brief, friction_regions={"a": 1}), "friction_regions: not a list")):
        with pytest.raises(ReportError, match=key):
            check_scene_summary(np.array(json.dumps(bad)), "r.npz")
    # without regions (and from a folder written before them) the text is the one it was
    old = {k: v for k, v in brief.items() if k != "friction_regions"}
    assert "mu = 0.4 between garment and skin, on the loading path" in _assumptions(old, {})
    # a stage that sets one region's mu by its path: the brief has the end of the path's
    sc = load_scene(ROOT / "configs" / "garments" / "stocking_friction.yaml",
                    ["mold.friction_regions=[{nodes: {j: [90%, 100%]}, friction: 1.2}]",
                     "stages.1.set={mold.friction: 0.4, mold.friction_regions.0.friction: 1.5}"])
    brief = json.loads(json.dumps(scene_summary(scene_brief(sc), compile_model(sc))))
    assert brief["friction_mu"] == 0.4 and brief["friction_regions"] == [{"nodes": "j 90% to 100%", "friction": 1.5}]
    # friction only in a band: the report says friction, in both places, and the body line
    # does not list the regions
    sc = load_scene(WRAP, ["solver.method=newton", "mold.friction_regions=[{nodes: {i: [50%, 100%]}, friction: 1.2}]"])
    brief = json.loads(json.dumps(scene_summary(scene_brief(sc), compile_model(sc))))
    assert "Friction: Coulomb, mu = 0 between garment and skin; mu = 1.2 on i 50% to 100%" in _assumptions(brief, {})
    assert "Coulomb, mu = 0; mu = 1.2 on i 50% to 100%" in _scene_summary(brief)
    assert "friction_regions" not in (brief["body"] or "")
    sc = load_scene(WRAP, ["solver.method=newton", "mold.friction_regions=[{nodes: left, friction: 0}]"])
    brief = json.loads(json.dumps(scene_summary(scene_brief(sc), compile_model(sc))))
    assert "No friction" in _assumptions(brief, {}) and "none (frictionless)" in _scene_summary(brief)


def test_a_stage_region_the_lattice_refuses_names_the_stage():
    import clothsim

    # on a sheet the range is checked when the scene is read
    with pytest.raises(SceneError, match=r"stages\.1\.set: mold\.friction_regions\.0\.nodes: friction_regions: "
                                         r"i range \[0, 500\] outside 0\.\.80"):
        load_scene(WRAP, ["solver.method=newton", "stages=[{name: drape}, {name: pull, set: "
                          "{mold.friction_regions: [{nodes: {i: [0, 500]}, friction: 0.5}]}}]"])
    # on panels when the stages' models are built, before anything is solved
    sc = load_scene(ROOT / "configs" / "garments" / "stocking_friction.yaml",
                    ["stages.1.set={mold.friction: 0.4, mold.friction_regions: "
                     "[{nodes: {panel: front, i: 0, j: 0}, friction: 1.2}]}"])
    sim = clothsim.Simulation(sc)
    with pytest.raises(SceneError, match=r"^--set stages\.1\.set=\{.*\}: stages\.1\.set: "
                                         r"mold\.friction_regions\.0\.nodes: selects no nodes$"):
        sim.run()
    assert sim.state.iteration == 0


def test_the_viewer_keeps_the_regions_with_a_new_mold():
    from clothsim.viewer.draft import SceneDraft

    sc = load_scene(WRAP, ["solver.method=newton", "mold.friction=0.3",
                           "mold.friction_regions=[{nodes: left, friction: 0.9}]"])
    d = SceneDraft(sc)
    d.set_mold({"sphere": {"center": [0.1, 0.01, -0.1], "radius": 0.05}})
    assert d.data["mold"]["friction"] == 0.3 and d.data["mold"]["friction_regions"] == [{"nodes": "left", "friction": 0.9}]
