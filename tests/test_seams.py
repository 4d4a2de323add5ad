"""Seams (eq. 1, F_seams): sewing springs between two node lines of the sheet.

Checked: scene validation with file, line and field; the pairs and per-pair stiffness; forces
and Hessian blocks against finite differences of the energy; the sewn sleeve on a cylinder
against the exact polygon solution (uniform hoop strain, seam gap from the force balance,
Laplace pressure); the paper's relaxation reaching Newton's equilibrium; grid sequencing
carrying the seams to the coarse grids."""

import math

import numpy as np
import pytest

import clothsim
from clothsim.config import SceneError, load_scene, scene_from_dict
from clothsim.compile import compile_model
from clothsim.grid import FAMILY_SEAM
from clothsim.kernels import forces_and_energy, spring_hessian_block

from conftest import ROOT

SLEEVE = ROOT / "configs" / "sewn_sleeve.yaml"


def _panel(**extra):
    d = {"name": "panel",
         "fabric": {"size": [0.25, 0.08], "divisions": [10, 4],
                    "warp": {"strain": [0, 0.5], "tension": [0, 100]},
                    "weft": {"strain": [0, 0.2, 1.0], "tension": [0, 40, 400]}}}
    d.update(extra)
    return d


def _bad(tmp_path, seams_yaml):
    text = ("name: panel\n"
            "fabric:\n"
            "  size: [0.25, 0.08]\n"
            "  divisions: [10, 4]\n"
            "  warp: {preset: isotropic_paper}\n"
            "  weft: {preset: isotropic_paper}\n"
            "seams:\n" + seams_yaml)
    p = tmp_path / "scene.yaml"
    p.write_text(text)
    with pytest.raises(SceneError) as exc:
        load_scene(p)
    return str(exc.value)


def test_seam_errors_name_file_line_and_field(tmp_path):
    # (sides of unequal node counts are sewn along arc length: tests/test_seam_elements.py)
    msg = _bad(tmp_path, "  - {a: {i: 0, j: 0}, b: top}\n")
    assert msg == (f"{tmp_path / 'scene.yaml'}:8: seams.0.a: selects one node but b selects 11; "
                   "a seam of unequal node counts needs at least two nodes on each side")
    msg = _bad(tmp_path, "  - {a: left, b: right}\n  - {a: left, b: all}\n")
    assert msg.startswith(f"{tmp_path / 'scene.yaml'}:9: seams.1.b: must select one line of nodes")
    msg = _bad(tmp_path, "  - {a: right, b: right}\n")
    assert msg.endswith("seams.0.b: selects the same nodes as a (nothing to sew)")
    msg = _bad(tmp_path, "  - {a: {i: 12}, b: right}\n")
    assert msg.endswith("seams.0.a: i range 12 outside 0..10")
    msg = _bad(tmp_path, "  - {a: left, b: rigth}\n")
    assert ":8: seams.0.b: unknown node set 'rigth'" in msg
    msg = _bad(tmp_path, "  - {a: left, b: right, stiffness: -1}\n")
    assert msg.endswith("seams.0.stiffness: must be positive and finite (got -1.0)")


def test_seam_pairs_and_stiffness():
    """left-right pairs (0, j)-(10, j); reverse pairs the first with the last; each pair's
    stiffness is the seam stiffness times its share of the seam (half at the ends); the default
    is 1000 x the stiffest table slope / the smaller spacing; no seam, no seam springs."""
    m = compile_model(scene_from_dict(_panel(seams=[{"a": "left", "b": "right", "stiffness": 1e6}])))
    f = m.spring_family == FAMILY_SEAM
    ny1 = 5
    assert m.spring_nodes[f].tolist() == [[j, 10 * ny1 + j] for j in range(5)]
    k = m.spring_width[f] / m.spring_rest_length[f]
    dy = 0.02
    np.testing.assert_allclose(k, 1e6 * dy * np.array([0.5, 1, 1, 1, 0.5]), rtol=1e-12)
    m = compile_model(scene_from_dict(_panel(seams=[{"a": {"i": [0, 3], "j": 0}, "b": {"i": [5, 8], "j": 0},
                                                   "reverse": True}])))
    f = m.spring_family == FAMILY_SEAM
    assert m.spring_nodes[f].tolist() == [[0, 8 * ny1], [ny1, 7 * ny1], [2 * ny1, 6 * ny1], [3 * ny1, 5 * ny1]]
    k = m.spring_width[f] / m.spring_rest_length[f]
    dx = 0.025
    k_line = 1000 * max(100 / 0.5, (400 - 40) / 0.8) / min(dx, dy)
    np.testing.assert_allclose(k, k_line * dx * np.array([0.5, 1, 1, 0.5]), rtol=1e-12)
    assert not (compile_model(scene_from_dict(_panel())).spring_family == FAMILY_SEAM).any()


def _energy_forces(model, pos):
    out = np.empty_like(pos)
    e = forces_and_energy(pos, *model.spring_args(), model.external_force, out)
    return e, out


def test_seam_force_is_minus_energy_gradient_and_linear():
    """The seam force is k x gap (a zero-length linear spring), exactly -dE/dx (central
    differences), and its Hessian block is k I (finite differences of the force)."""
    m = compile_model(scene_from_dict(_panel(seams=[{"a": "left", "b": "right", "stiffness": 2e3}])))
    rng = np.random.default_rng(1)
    pos = m.rest_positions * np.array([1.1, 1.05, 1.0]) + rng.normal(0, 1e-3, m.rest_positions.shape)
    E, F = _energy_forces(m, pos)
    h = 1e-7
    fd = np.zeros_like(pos)
    for k in range(pos.shape[0]):
        for a in range(3):
            p = pos.copy(); p[k, a] += h
            q = pos.copy(); q[k, a] -= h
            fd[k, a] = -(_energy_forces(m, p)[0] - _energy_forces(m, q)[0]) / (2 * h)
    np.testing.assert_allclose(F, fd, atol=1e-6 * np.abs(F).max())
    # the seam springs alone: force on a = k (x_b - x_a)
    f = m.spring_family == FAMILY_SEAM
    t = m.tables
    for s in np.nonzero(f)[0]:
        a, b = m.spring_nodes[s]
        k = m.spring_width[s] / m.spring_rest_length[s]
        K = np.empty((3, 3))
        spring_hessian_block(pos[a], pos[b], m.spring_rest_length[s], m.spring_width[s], t.x, t.y, t.cum,
                             t.start, t.compression, m.spring_table[s], 0.0, K)
        np.testing.assert_allclose(K, k * np.eye(3), rtol=1e-9, atol=1e-9 * k)
    sub = compile_model(scene_from_dict(_panel()))
    _, F0 = _energy_forces(sub, pos)
    for s in np.nonzero(f)[0]:
        a, b = m.spring_nodes[s]
        k = m.spring_width[s] / m.spring_rest_length[s]
        extra_a = F[a] - F0[a]
        # nodes a and b each sit on one seam pair only
        np.testing.assert_allclose(extra_a, k * (pos[b] - pos[a]), rtol=1e-9, atol=1e-12)


def _sleeve_checks(res, R=0.05, closed=True):
    """The sewn sleeve against the exact polygon solution (closed: the seam is stiff enough that
    its gap does not change the hoop strain beyond 1e-4)."""
    m = res.model
    nx1, ny1 = m.grid_shape
    nx = nx1 - 1
    p = res.state.positions.reshape(nx1, ny1, 3)
    r = np.hypot(p[..., 0], p[..., 1])
    np.testing.assert_allclose(r, R, atol=1e-12)  # every node on the limb
    eps = res.strain_warp
    assert np.ptp(eps) <= 1e-6 * eps.mean()  # uniform hoop strain
    e = float(eps.mean())
    h = m.spacing[0]
    phi_c = 2 * math.asin(h * (1 + e) / (2 * R))
    phi_g = 2 * math.pi - nx * phi_c
    g_geom = 2 * R * math.sin(phi_g / 2)
    gap = np.linalg.norm(p[0] - p[nx], axis=-1)
    np.testing.assert_allclose(gap, g_geom, rtol=1e-6, atol=1e-12)
    # tangential balance at the seam: chord force cos(phi_c/2) = seam force cos(phi_g/2)
    f = m.spring_family == FAMILY_SEAM
    k = (m.spring_width[f] / m.spring_rest_length[f]).reshape(-1)
    fw = res.tension_warp.reshape(nx, ny1)[0]  # force of the first warp spring of each row [N]
    np.testing.assert_allclose(k * gap * math.cos(phi_g / 2), fw * math.cos(phi_c / 2), rtol=1e-6)
    # the seam closes: the polygon of nx chords is the continuum sleeve up to the chord error
    L = h * nx
    e_poly = nx * 2 * R * math.sin(math.pi / nx) / L - 1
    if closed:
        assert abs(e - e_poly) < 1e-4
    return e


def test_sewn_sleeve_matches_the_polygon_solution_and_laplace():
    """configs/sewn_sleeve.yaml (newton, e = 1e-9 N): the seam closes to the gap its force
    balance gives, the hoop strain is uniform, and the pressure on interior nodes is Laplace's
    T / r with T the course tension per current width."""
    scene = load_scene(SLEEVE, ["solver.method=newton", "solver.e=1e-9"])
    res = clothsim.solve(scene)
    assert res.solve.converged, res.solve.message
    e = _sleeve_checks(res)
    m = res.model
    nx1, ny1 = m.grid_shape
    t_course = float(np.interp(e, *(m.table_list[0].strain, m.table_list[0].tension)))
    eps_wale = float(np.median(res.strain_weft))
    T = t_course / (1 + eps_wale)  # per current width
    p = res.contact_pressure[1:-1, 1:-1]
    np.testing.assert_allclose(p, T / 0.05, rtol=1e-6)
    s = res.summary()
    assert s["max_seam_gap_m"] == pytest.approx(float(np.linalg.norm(
        res.state.positions.reshape(nx1, ny1, 3)[0] - res.state.positions.reshape(nx1, ny1, 3)[-1], axis=-1).max()))
    assert s["max_seam_gap_m"] < 1e-6


def test_paper_relaxation_sews_the_same_sleeve():
    """A 20 x 4 sleeve with a seam of moderate stiffness: the paper's relaxation converges to
    Newton's equilibrium (positions within the residual's tolerance) and passes the polygon
    checks."""
    over = ["fabric.divisions=[20,4]", "constraints.2.nodes={i: 10}", "seams.0.stiffness=1e5",
            "initial.wrap.start_angle=-40.2177", "solver.e=1e-8", "solver.time_limit_s=60"]
    ref = clothsim.solve(load_scene(SLEEVE, over + ["solver.method=newton", "solver.e=1e-11"]))
    assert ref.solve.converged, ref.solve.message
    res = clothsim.solve(load_scene(SLEEVE, over + ["solver.method=paper"]))
    assert res.solve.converged, res.solve.message
    assert np.abs(res.state.positions - ref.state.positions).max() < 1e-6
    _sleeve_checks(res, closed=False)


def test_grid_sequencing_keeps_the_seams():
    """On a 100 x 40 sleeve the coarse grid keeps every seam pair whose nodes it keeps, with twice
    the stiffness, and Newton with sequencing reaches the same equilibrium as without."""
    from clothsim.solvers.newton import coarsen_model

    over = ["fabric.divisions=[100,40]", "constraints.2.nodes={i: 50}", "solver.method=newton", "solver.e=1e-9"]
    scene = load_scene(SLEEVE, over)
    m = compile_model(scene, None)
    c, sub = coarsen_model(m)
    f, fc = m.spring_family == FAMILY_SEAM, c.spring_family == FAMILY_SEAM
    assert fc.sum() == 21
    assert c.spring_nodes[fc].tolist() == [[j, 50 * 21 + j] for j in range(21)]
    np.testing.assert_allclose(c.spring_width[fc][1:-1], 2 * m.spring_width[f][2:-2:2])
    a = clothsim.solve(scene)
    b = clothsim.solve(load_scene(SLEEVE, over + ["solver.newton_sequencing=false"]))
    assert a.solve.converged and b.solve.converged, (a.solve.message, b.solve.message)
    assert np.abs(a.state.positions - b.state.positions).max() < 1e-7
    _sleeve_checks(a)


def test_pinned_contact_nodes_reach_a_tight_residual():
    """The sleeve's pinned column (x held) off the top of the limb (start_angle -35 deg): its
    contact normal is not orthogonal to the held axis. The residual lets the constraint take any
    force along x (it stalled at 5.5e-6 N when the held component was only dropped from R):
    newton reaches 1e-9 N."""
    res = clothsim.solve(load_scene(SLEEVE, ["solver.method=newton", "solver.e=1e-9",
                                             "initial.wrap.start_angle=-35"]))
    assert res.solve.converged, res.solve.message
    m = res.model
    pinned = m.fixed_axes[:, 0] & ~m.fixed_axes[:, 2]
    x = res.state.positions[pinned, 0]
    assert np.abs(x).min() > 1e-3  # really off the top: the normal has an x component
