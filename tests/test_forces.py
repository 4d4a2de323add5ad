"""Every force is minus the gradient of its energy (central finite differences).

Checked on small grids whose springs sit in tension, exactly around the slack boundary and across
table breakpoints, for warp and weft (different tables), and for the optional terms of eq. (1):
gravity, shear and bending springs."""

import numpy as np
import pytest

from clothsim.compile import compile_model, compile_state
from clothsim.kernels import forces_and_energy, spring_eval, spring_hessian_block

from conftest import make_scene


def _energy(model, pos):
    out = np.empty_like(pos)
    return forces_and_energy(pos, *model.spring_args(), model.external_force, out)


def _forces(model, pos):
    out = np.empty_like(pos)
    forces_and_energy(pos, *model.spring_args(), model.external_force, out)
    return out


def _fd_check(model, pos, h=1e-8, rtol=1e-5):
    F = _forces(model, pos)
    fd = np.zeros_like(pos)
    for k in range(pos.shape[0]):
        for a in range(3):
            p = pos.copy(); p[k, a] += h
            em = pos.copy(); em[k, a] -= h
            fd[k, a] = -(_energy(model, p) - _energy(model, em)) / (2 * h)
    scale = np.abs(F).max()
    assert scale > 0
    np.testing.assert_allclose(F, fd, rtol=0, atol=rtol * scale)
    return F


@pytest.mark.parametrize("stretch", [1.05, 1.3, 1.8])
def test_forces_are_minus_energy_gradient_in_tension(stretch):
    """Random stretched 4x3 grid with distinct warp/weft tables: F = -dE/dx."""
    scene = make_scene(**{"fabric.divisions": [4, 3]})
    model = compile_model(scene)
    rng = np.random.default_rng(0)
    pos = model.rest_positions * np.array([stretch, stretch * 0.97, 1.0]) + rng.normal(0, 2e-4, model.rest_positions.shape)
    _fd_check(model, pos)


def test_forces_at_slack_boundary_and_breakpoints():
    """Springs placed at strains just around 0 (slack kink) and just around table breakpoints
    (0.1, 0.3, 0.6): the C1 energy still gives F = -dE/dx there."""
    scene = make_scene(**{"fabric.divisions": [1, 1]})
    model = compile_model(scene)
    l0 = model.spring_rest_length[0]
    for s in (-1e-6, 1e-6, 0.1 - 1e-6, 0.1 + 1e-6, 0.3, 0.6 + 1e-7, 1.2):
        pos = model.rest_positions.copy()
        # stretch the warp springs to strain s and tilt a node out of plane
        pos[2:, 0] = pos[:2, 0] + l0 * (1 + s)
        pos[3, 2] += 1e-4
        F = _forces(model, pos)
        fd = np.zeros_like(pos)
        h = 1e-10
        for k in range(4):
            for a in range(3):
                p = pos.copy(); p[k, a] += h
                m = pos.copy(); m[k, a] -= h
                fd[k, a] = -(_energy(model, p) - _energy(model, m)) / (2 * h)
        np.testing.assert_allclose(F, fd, atol=1e-5 * max(np.abs(F).max(), 1e-3))


def test_optional_terms_forces_are_energy_gradients():
    """Gravity (constant force, energy -f.x), shear diagonals and bending skip-one springs (both
    resisting compression): F = -dE/dx, in tension and in compression."""
    scene = make_scene(**{"fabric.divisions": [4, 3], "gravity": {"areal_density": 0.2},
                          "shear": {"stiffness": 20.0}, "bending": {"stiffness": 1.0}})
    model = compile_model(scene)
    fam = set(model.spring_family.tolist())
    assert fam == {0, 1, 2, 3, 4}
    assert np.abs(model.external_force[:, 2]).sum() == pytest.approx(0.2 * 9.80665 * 0.1 * 0.02)
    rng = np.random.default_rng(3)
    for stretch in (0.9, 1.2):
        pos = model.rest_positions * stretch + rng.normal(0, 3e-4, model.rest_positions.shape)
        _fd_check(model, pos)


def test_unused_terms_add_no_springs():
    """A scene that does not ask for shear/bending/gravity builds only warp and weft springs and a
    zero external force (an unused term costs nothing)."""
    model = compile_model(make_scene(**{"fabric.divisions": [5, 4]}))
    assert model.spring_count == 5 * 5 + 6 * 4
    assert set(model.spring_family.tolist()) == {0, 1}
    assert not model.external_force.any()


def test_hessian_block_matches_force_derivative():
    """spring_hessian_block is d(f_b)/d(x_b) of the spring force (finite differences) in tension."""
    scene = make_scene()
    model = compile_model(scene)
    t = model.tables
    pa = np.array([0.0, 0.0, 0.0])
    pb = np.array([0.0061, 0.0012, -0.0009])  # length 6.28 mm: strain 0.256 on l0 = 5 mm
    l0, w = 0.005, 0.004
    K = np.empty((3, 3))
    spring_hessian_block(pa, pb, l0, w, t.x, t.y, t.cum, t.start, t.compression, 0, 0.0, K)
    h = 1e-9
    fd = np.zeros((3, 3))
    for a in range(3):
        p = pb.copy(); p[a] += h
        m = pb.copy(); m[a] -= h
        fp = -np.array(spring_eval(pa, p, l0, w, t.x, t.y, t.cum, t.start, t.compression, 0)[:3])
        fm = -np.array(spring_eval(pa, m, l0, w, t.x, t.y, t.cum, t.start, t.compression, 0)[:3])
        fd[:, a] = -(fp - fm) / (2 * h)
    np.testing.assert_allclose(K, fd, rtol=1e-5, atol=1e-6 * np.abs(K).max())
    assert np.linalg.eigvalsh(0.5 * (K + K.T)).min() >= -1e-9


def test_zero_length_spring_is_finite():
    """Two nodes projected onto the same point: the spring is slack and gives no NaN."""
    scene = make_scene(**{"fabric.divisions": [1, 1]})
    model = compile_model(scene)
    pos = model.rest_positions.copy()
    pos[2] = pos[0]
    F = _forces(model, pos)
    assert np.isfinite(F).all()


@pytest.mark.parametrize("slide", [0.3, 0.9, 1.0, 1.7, 40.0])
def test_friction_force_and_hessian_are_derivatives_of_its_potential(slide):
    """Coulomb friction's lagged potential (clothsim.contact.friction_*): the force is minus its
    gradient and the Hessian block the force's derivative (central differences), for slides
    below the slip eps (the C1 mollifier: sticking), at it and beyond it (slipping, |f| = mu lam),
    with a tilted frozen normal and the normal component of the move ignored."""
    from clothsim.contact import friction_assemble, friction_forces_energy

    eps = 1e-4
    n = np.array([[0.3, -0.2, 0.9]])
    n /= np.linalg.norm(n)
    anchor = np.array([[0.01, 0.02, -0.03]])
    t = np.cross(n[0], [1.0, 0.0, 0.0])
    t /= np.linalg.norm(t)
    pos = anchor + slide * eps * t + 2e-3 * n  # a slide in the tangent plane, plus a normal offset
    pos = np.vstack([pos, [[5.0, 5.0, 5.0]]])  # a node without friction
    nodes = np.array([0], np.int64)
    weight = np.array([0.7])

    def energy(p):
        return friction_forces_energy(p, nodes, anchor, n, weight, eps, np.zeros_like(p))

    def force(p):
        out = np.zeros_like(p)
        friction_forces_energy(p, nodes, anchor, n, weight, eps, out)
        return out

    F = force(pos)
    h = 1e-9
    fd = np.zeros_like(pos)
    H_fd = np.zeros((3, 3))
    for a in range(3):
        p, m = pos.copy(), pos.copy()
        p[0, a] += h
        m[0, a] -= h
        fd[0, a] = -(energy(p) - energy(m)) / (2 * h)
        H_fd[:, a] = -(force(p)[0] - force(m)[0]) / (2 * h)
    np.testing.assert_allclose(F, fd, rtol=0, atol=1e-6 * weight[0])
    assert abs(F[0] @ n[0]) < 1e-12 * weight[0]  # tangential only
    assert np.linalg.norm(F[0]) <= weight[0] * (1 + 1e-12)  # never beyond mu lam
    if slide >= 1.0:
        assert np.linalg.norm(F[0]) == pytest.approx(weight[0], rel=1e-12)
    K = np.zeros((1, 3, 3))
    friction_assemble(pos, nodes, anchor, n, weight, eps, np.array([0, 0], np.int64), K)
    scale = np.abs(K[0]).max()
    assert scale > 0
    np.testing.assert_allclose(K[0], H_fd, rtol=0, atol=2e-5 * scale)
    assert np.linalg.eigvalsh(K[0]).min() >= -1e-9 * scale  # convex
