"""A stage's garment-level rest scale (issue 30 item 2): the garment drawn on wider than its
design and relaxed back (docs/method/friction.md, Stages). Known answers: a uniaxial strip at rest scale
s carries the table's tension at strain L / (s L0) - 1; a sleeve started loose (s > 1) and relaxed
to its design size reaches the frictionless sleeve's equilibrium and Laplace's T / r; bad values
are refused with the scene file's line."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROOT

import clothsim
from clothsim.config import load_scene
from clothsim.errors import SceneError
from clothsim.solvers.control import Control, load_steps, scale_rest

SLEEVE = ROOT / "configs" / "sewn_sleeve.yaml"
SMALL = ["fabric.divisions=[20,8]", "constraints.2.nodes={i: 10}", "solver.method=newton", "solver.e=1e-9"]


def _staged(path, tmp_path, stages, over=()):
    text = path.read_text().replace("../static/", str(ROOT / "static") + "/")
    p = tmp_path / "s.yaml"
    p.write_text(text + "stages:\n" + "".join(f"  - {s}\n" for s in stages))
    return load_scene(p, list(over))


def test_strip_at_a_rest_scale_carries_the_tables_tension_at_the_scaled_strain(tmp_path):
    """configs/uniaxial_strip.yaml (clamped, pulled 30 mm to 130 mm) with its courses 1.1 times
    their cut length: every warp spring sits at 0.13 / (1.1 x 0.10) - 1 = 18.2 % (not 30 %) and
    pulls the table's tension there times its width; the ramp's last step is the stage's value."""
    sc = _staged(ROOT / "configs" / "uniaxial_strip.yaml", tmp_path,
                 ["{name: wide, steps: 3, rest_scale: [1.1, 1.0]}"], ["solver.method=newton", "solver.e=1e-9"])
    r = clothsim.solve(sc)
    assert r.solve.converged, r.solve.message
    m = r.model
    warp = m.spring_family == 0
    eps = 0.13 / (1.1 * 0.10) - 1
    np.testing.assert_allclose(r.strain_warp, eps, atol=1e-9)
    tab = m.table_list[0]
    t = float(np.interp(eps, tab.strain, tab.tension))
    np.testing.assert_allclose(m.spring_rest_length[warp], 1.1 * 0.005, rtol=1e-12)
    np.testing.assert_allclose(r.tension_warp, t * m.spring_width[warp].reshape(r.tension_warp.shape), rtol=1e-7)
    # the strip's design strain, 30 %, would read far more:
    assert abs(t - float(np.interp(0.3, tab.strain, tab.tension))) > 0.2 * t
    st = r.summary()["friction"]["stages"][0]
    assert st["rest_scale"] == [1.1, 1.0]
    assert [s["rest_scale"][0] for s in r.summary()["friction"]["steps"]] == pytest.approx([1 + 0.1 / 3, 1 + 0.2 / 3, 1.1])


def test_loose_sleeve_relaxed_to_its_design_reaches_the_frictionless_sleeve_and_laplace(tmp_path):
    """configs/sewn_sleeve.yaml (20 x 8) put on 1.1 times its cut size (frictionless), then
    relaxed to 1.0 in 4 load steps with mold.friction 0: the equilibrium is the one-step
    frictionless sleeve's (positions within 1e-7 m) and its pressure is Laplace's T / r. With
    mu = 0.4 every node sticks as the hoop tightens and the pressure stays within 3 % of T / r."""
    ref = clothsim.solve(load_scene(SLEEVE, SMALL))
    assert ref.solve.converged
    sc = _staged(SLEEVE, tmp_path, ["{name: loose, steps: 1, rest_scale: 1.1}",
                                    "{name: relax, steps: 4, rest_scale: 1.0, set: {mold.friction: 0.0}}"], SMALL)
    r = clothsim.solve(sc)
    assert r.solve.converged, r.solve.message
    stages = r.summary()["friction"]["stages"]
    assert [s["rest_scale"] for s in stages] == [[1.1, 1.1], [1.0, 1.0]]
    assert np.abs(r.state.positions - ref.state.positions).max() < 1e-7
    np.testing.assert_array_equal(r.model.spring_rest_length, ref.model.spring_rest_length)
    m = r.model
    e = float(np.median(r.strain_warp))
    t_course = float(np.interp(e, m.table_list[0].strain, m.table_list[0].tension))
    T = t_course / (1 + float(np.median(r.strain_weft)))
    np.testing.assert_allclose(r.contact_pressure[1:-1, 1:-1], T / 0.05, rtol=1e-5)
    fr = _staged(SLEEVE, tmp_path, ["{name: loose, steps: 1, rest_scale: 1.1}",
                                    "{name: relax, steps: 4, rest_scale: 1.0, set: {mold.friction: 0.4}}"], SMALL)
    rf = clothsim.solve(fr)
    assert rf.solve.converged, rf.solve.message
    f = rf.summary()["friction"]
    # the hoop tightens round the cylinder without sliding: every node sticks, the cone holds,
    # and friction keeps some of the loose stage's unevenness (0.7 mm, pressure within 3 %)
    assert rf.state.in_contact.all() and f["slip"] == 0 and f["stick"] == 21 * 9 - 2 * 21 - 7  # all but the held rows and column
    assert f["cone_violation"] <= 1e-6
    np.testing.assert_allclose(rf.contact_pressure[1:-1, 1:-1], T / 0.05, rtol=0.03)


def test_scale_rest_scales_a_pattern_and_one_is_the_design():
    sc = load_scene(SLEEVE, SMALL)
    from clothsim.compile import compile_model

    m = compile_model(sc)
    assert scale_rest(m, (1.0, 1.0)) is m
    s = scale_rest(m, (1.2, 0.9))
    warp, weft = m.spring_family == 0, m.spring_family == 1
    np.testing.assert_allclose(s.spring_rest_length[warp], 1.2 * m.spring_rest_length[warp])
    np.testing.assert_allclose(s.spring_width[warp], 0.9 * m.spring_width[warp])
    np.testing.assert_allclose(s.spring_rest_length[weft], 0.9 * m.spring_rest_length[weft])
    np.testing.assert_allclose(s.spring_width[weft], 1.2 * m.spring_width[weft])
    seam = m.spring_family == 5
    np.testing.assert_array_equal(s.spring_rest_length[seam], m.spring_rest_length[seam])
    c = load_steps(m.prescribed_positions, m.prescribed_positions, 4, ((1.2, 1.2), (1.0, 1.0)))
    assert [x.rest_scale for x in c] == [pytest.approx((1.15, 1.15)), pytest.approx((1.1, 1.1)),
                                         pytest.approx((1.05, 1.05)), (1.0, 1.0)]
    with pytest.raises(ValueError, match="rest_scale must be positive"):
        Control(m.prescribed_positions, (0.0, 1.0))


@pytest.mark.parametrize("value", ["0.3", "[1.1, 1.0, 1.0]", "abc", "2.5"])
def test_a_bad_rest_scale_is_refused_with_file_and_line(tmp_path, value):
    text = (ROOT / "tests" / "data" / "capstan_stages.yaml").read_text()
    p = tmp_path / "s.yaml"
    p.write_text(text.replace("{name: drape, steps: 1}", f"{{name: drape, steps: 1, rest_scale: {value}}}"))
    n = 1 + text.splitlines().index("  - {name: drape, steps: 1}")
    with pytest.raises(SceneError, match=rf"s\.yaml:{n}: stages\.0\.rest_scale: .*from 0\.5 to 2\.0"):
        load_scene(p)


def test_a_paused_staged_run_goes_on_at_the_scale_it_was_at(tmp_path):
    """The sleeve's loose-then-relax path run a few Newton iterations at a time (the viewer's
    pause / go on) reaches the one-go equilibrium: each resumed step scales the design rest
    lengths anew (not the already scaled ones) and ramps from where the pause left the scale."""
    from clothsim.simulation import Simulation

    stages = ["{name: loose, steps: 2, rest_scale: 1.1}",
              "{name: relax, steps: 3, rest_scale: 1.0, set: {mold.friction: 0.0}}"]
    once = clothsim.solve(_staged(SLEEVE, tmp_path, stages, SMALL))
    sim = Simulation(_staged(SLEEVE, tmp_path, stages, SMALL))
    mid_stage = 0
    for calls in range(1, 200):
        res = sim.run(max_iterations=2)
        mid_stage += sim._controls is not None and sim._steps_done > 0
        if res.converged and not sim._plan:
            break
    assert res.converged and not sim._plan
    assert calls > 5 and mid_stage > 0  # paused within the stages' load steps
    assert np.abs(sim.state.positions - once.state.positions).max() < 1e-7
    np.testing.assert_array_equal(sim.model.spring_rest_length, once.model.spring_rest_length)
