"""The contact-rim settlement of an interpolated start (solvers/newton/settle.py): an equilibrium
is a fixed point of it, and on the sphere cap it brings the interpolated start's contact set to
the fine solution's."""

import numpy as np

from clothsim.bench import Case, _load
from clothsim.solvers import solve
from clothsim.solvers.newton import sequencing as S
from clothsim.solvers.newton.settle import settle_start


def _cap(div):
    case = Case("cap", "configs/sphere_cap.yaml", [f"fabric.divisions=[{div},{div}]"], ("newton",))
    return _load(case, "newton", 1e-10, None)


def test_an_equilibrium_is_a_fixed_point():
    model, state, settings = _cap(40)
    res = solve(model, state, settings.model_copy(update={"newton_sequencing": False}))
    assert res.residual <= 1e-10
    st = state.copy()
    changes = settle_start(model, st, 1e-3)
    assert changes == 0
    assert np.array_equal(st.in_contact, state.in_contact)
    # each node's Newton step with its neighbours held is of the order of its residual over its
    # stiffness (~1e-10 N / 250 N/m): far below a micrometre
    assert np.abs(st.positions - state.positions).max() < 1e-9


def test_a_ring_put_in_contact_is_released():
    """The free nodes beside the rim of an equilibrium put on the sphere as contact nodes: the
    settlement releases them all (their resultants point out of the sphere once they are
    moved), and keeps every node of the equilibrium's contact set."""
    model, state, settings = _cap(40)
    solve(model, state, settings.model_copy(update={"newton_sequencing": False}))
    c = state.in_contact
    a, b = model.spring_nodes[:, 0], model.spring_nodes[:, 1]
    ring = np.zeros(model.node_count, bool)
    ring[a[c[b] & ~c[a]]] = True
    ring[b[c[a] & ~c[b]]] = True
    assert ring.sum() >= 8
    st = state.copy()
    center = np.array([0.05, 0.05, -0.02])
    d = st.positions[ring] - center
    st.positions[ring] = center + 0.04 * d / np.linalg.norm(d, axis=1)[:, None]
    st.in_contact[ring] = True
    settle_start(model, st, 1e-3)
    assert np.array_equal(st.in_contact, c)


def test_the_interpolated_cap_gets_the_solutions_contact_set():
    """80^2 cap: the coarse 41^2 solution interpolated marks at the rim nodes as contact that are
    free at the 81^2 solution (the rim would peel one ring per Newton iteration); settled, the
    start's contact set is within a few nodes of the solution's."""
    model, state, settings = _cap(80)
    fine = state.copy()
    solve(model, fine, settings.model_copy(update={"newton_sequencing": False, "e": 1e-9}))
    chain = S.sequencing_chain(model)
    coarse, sub = chain[-2]
    cs = state.copy()
    cs.positions = np.ascontiguousarray(state.positions[sub])
    cs.in_contact = state.in_contact[sub].copy()
    solve(coarse, cs, settings.model_copy(update={"newton_sequencing": False, "e": 1e-9}))
    start = state.copy()
    assert S.prolong_state(coarse, cs, model, start)
    wrong_before = int((start.in_contact != fine.in_contact).sum())
    settle_start(model, start, 1e-3)
    wrong_after = int((start.in_contact != fine.in_contact).sum())
    assert wrong_before >= 8, wrong_before
    assert wrong_after <= wrong_before // 3, (wrong_before, wrong_after)
