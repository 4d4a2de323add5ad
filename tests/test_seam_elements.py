"""Seams of unequal node counts (clothsim.selection.arc_elements, clothsim.kernels.seam_*).

Checked: the dual-mortar weights (shares sum to 1, gaps invariant to translation, a straight
line reproduced exactly, a uniform line load reaching each node of both sides in proportion to
its share: the patch test); forces against finite differences of the energy and the assembled
Newton Hessian against finite differences of the forces, and the paper's per-node resultant
against the whole-sheet force; no seams (or equal counts) build no seam elements and leave the
Newton pattern as it was; the two-panel sleeve sewn 27 nodes to 20 equals the equal-count sleeve
(hoop strain and T / r pressure); an eased seam gathers its longer side to the shorter one's
length; the summary reports ease and widest gap per seam; the paper's relaxation reaches
Newton's equilibrium on a seam of unequal counts."""

import numpy as np
import pytest
import scipy.sparse as sp

import clothsim
from clothsim.compile import compile_model
from clothsim.config import load_scene
from clothsim.grid import FAMILY_SEAM, seam_adjacency
from clothsim.kernels import node_force, seam_node_force
from clothsim.selection import arc_elements

from conftest import ROOT

TWO = ROOT / "configs" / "garments" / "sleeve_two_panel.yaml"
UNEQUAL = ROOT / "configs" / "garments" / "sleeve_unequal.yaml"
EASED = ROOT / "configs" / "garments" / "eased_seam.yaml"


def _line(s, length=1.0, origin=(0.0, 0.0), direction=(1.0, 0.0)):
    s = np.asarray(s, float)
    return np.asarray(origin) + length * s[:, None] * np.asarray(direction)[None, :]


@pytest.mark.parametrize("na, nb", [(5, 7), (20, 27), (27, 20), (3, 11)])
def test_dual_mortar_weights(na, nb):
    """Shares sum to 1; each gap's weights sum to 0 (translation invariant) with 1 on its own
    node; two sides on the same straight line close exactly (also with uneven spacing); a
    uniform line load puts on every node of both sides exactly its share of the seam."""
    rng = np.random.default_rng(na * nb)
    sa = np.sort(np.concatenate([[0, 1], rng.uniform(0.02, 0.98, na - 2)]))
    sb = np.linspace(0, 1, nb)
    pa, pb = _line(sa, 0.3), _line(sb, 0.3)
    slave_is_a, nodes, weight, share, la, lb = arc_elements(pa, pb)
    assert slave_is_a == (na > nb)
    ns = max(na, nb)
    assert nodes.shape[0] == ns and share.sum() == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(weight.sum(axis=1), 0.0, atol=1e-14)
    np.testing.assert_array_equal(nodes[:, 0], np.arange(ns))
    assert (weight[:, 0] == 1.0).all()
    both = np.concatenate([pa, pb] if slave_is_a else [pb, pa])
    gaps = (weight[:, :, None] * both[nodes]).sum(axis=1)
    np.testing.assert_allclose(gaps, 0.0, atol=1e-15)
    # patch test: the load sum_i share_i w_ij on node j is its own share (trapezoid of its side)
    load = np.zeros(both.shape[0])
    np.add.at(load, nodes.ravel(), (share[:, None] * weight).ravel())
    sm = sb if slave_is_a else sa
    trap = np.zeros(sm.size)
    trap[:-1] += np.diff(sm) / 2
    trap[1:] += np.diff(sm) / 2
    np.testing.assert_allclose(load[:ns], share, atol=1e-15)
    np.testing.assert_allclose(load[ns:], -trap, atol=1e-15)
    assert la == pytest.approx(0.3) and lb == pytest.approx(0.3)


def _small_unequal():
    return compile_model(load_scene(TWO, ["panels.0.divisions=[4,3]", "panels.1.divisions=[4,5]",
                                          "seams.0.stiffness=1e3", "seams.1.stiffness=1e3"]))


def test_seam_elements_forces_and_hessian_match_finite_differences():
    """A seam pairing 4 nodes with 6: F = -dE/dx (central differences of the energy) and the
    Newton level's assembled Hessian = -dF/dx (central differences of the forces) over every
    coordinate; the paper's per-node resultant (node_force + seam_node_force) is the whole force."""
    from clothsim.solvers.newton.iteration import NewtonLevel
    from clothsim.solvers.newton.linalg import _assemble
    from clothsim.kernels import seam_assemble

    m = _small_unequal()
    assert m.seam_count == 2 * 6 and not (m.spring_family == FAMILY_SEAM).any()
    rng = np.random.default_rng(0)
    pos = m.rest_positions * 1.1 + rng.normal(0, 1e-3, m.rest_positions.shape)
    lvl = NewtonLevel(m, kink=0.0, use_multigrid=False)

    def ef(p):
        F = np.empty_like(p)
        return lvl.energy_forces(p, F), F

    E, F = ef(pos)
    sF = np.zeros_like(pos)
    sE = m.add_seam_forces(pos, sF)
    assert sE > 0 and np.abs(sF).max() > 0.1 * np.abs(F).max()  # the seams carry real force here
    h = 1e-7
    n = m.node_count
    fd = np.empty_like(pos)
    H = np.empty((3 * n, 3 * n))
    for k in range(n):
        for a in range(3):
            p = pos.copy(); p[k, a] += h
            q = pos.copy(); q[k, a] -= h
            (Ep, Fp), (Eq, Fq) = ef(p), ef(q)
            fd[k, a] = -(Ep - Eq) / (2 * h)
            H[:, 3 * k + a] = -(Fp - Fq).ravel() / (2 * h)
    np.testing.assert_allclose(F, fd, rtol=0, atol=1e-8 * np.abs(F).max())
    _assemble(pos, *m.spring_args(), lvl.kink, lvl.slot, lvl.K)
    seam_assemble(*m.seam_args(), lvl.seam_slot, lvl.K)
    K = sp.bsr_matrix((lvl.K, lvl.indices, lvl.indptr), shape=(3 * n, 3 * n)).toarray()
    np.testing.assert_allclose(K, H, rtol=0, atol=1e-8 * np.abs(K).max())
    np.testing.assert_allclose(K, K.T, rtol=0, atol=1e-15 * np.abs(K).max())
    # the seam part alone is k w w^T (x) I: positive semi-definite
    Ks = np.zeros_like(lvl.K)
    seam_assemble(*m.seam_args(), lvl.seam_slot, Ks)
    Ks = sp.bsr_matrix((Ks, lvl.indices, lvl.indptr), shape=(3 * n, 3 * n)).toarray()
    assert np.linalg.eigvalsh(Ks).min() > -1e-9 * np.abs(Ks).max()
    # the paper's per-node resultant
    ptr, elem = seam_adjacency(n, m.seam_nodes)
    R = np.empty(3)
    for k in range(n):
        node_force(k, pos, *m.adjacency_args(), m.external_force, R)
        if ptr[k + 1] > ptr[k]:
            seam_node_force(k, pos, ptr, elem, *m.seam_args(), R)
        np.testing.assert_allclose(R, F[k], rtol=0, atol=1e-9 * np.abs(F).max())


def test_no_seam_elements_unless_counts_differ():
    """Without seams, and with seams of equal counts, no seam element exists and the Newton
    level's pattern and slots are the springs' alone (a scene pays only for what it uses); the
    equal-count seams are today's springs."""
    from clothsim.solvers.newton.iteration import NewtonLevel
    from clothsim.solvers.newton.linalg import _bsr_pattern

    for over in ([], ["seams=[]"]):
        m = compile_model(load_scene(TWO, over))
        assert m.seam_count == 0
        lvl = NewtonLevel(m)
        ip, ind, slot, diag = _bsr_pattern(m.node_count, m.spring_nodes)
        np.testing.assert_array_equal(lvl.indices, ind)
        np.testing.assert_array_equal(lvl.slot, slot)
        assert not hasattr(lvl, "seam_slot")
    m = compile_model(load_scene(TWO))
    assert (m.spring_family == FAMILY_SEAM).sum() == 2 * 17
    assert [len(s.springs) for s in m.seams] == [17, 17] and m.seams[0].ease == 0.0


def _tube(path, over, k):
    res = clothsim.solve(load_scene(path, ["solver.e=1e-9", "solver.method=newton"] + over
                                    + [f"seams.{n}.stiffness={k}" for n in range(2 if path != ROOT / "configs/sewn_sleeve.yaml" else 1)]))
    assert res.converged, res.solve.message
    z = res.state.positions[:, 2]
    ring = np.abs(z - np.median(z)) < 1e-3
    return res, float(res.strain_warp.mean()), float(np.ptp(res.strain_warp)), res._f()[3][ring]


def test_two_panel_tube_with_unequal_counts_equals_equal_counts():
    """configs/garments/sleeve_unequal.yaml (27 nodes sewn to 20 on both seams) against the
    equal-count two-panel sleeve (17 to 17) at the same seam stiffness: hoop strain uniform and
    equal within 1e-7 relative (measured 2e-9), the mid-height ring's pressure T / r equal within
    1e-7 (measured 2e-8). Against the one-panel sleeve the figures are 4e-6: the second seam's
    opening (T / k), which both two-panel sleeves share: the hoop strains differ by the one-panel
    seam's gap over the sleeve's length (within 1 %; measured 0.1 %). Every seam node sits on
    the limb."""
    k = 4e8
    two, e2, ptp2, p2 = _tube(TWO, [], k)
    une, eu, ptpu, pu = _tube(UNEQUAL, [], k)
    one, e1, _, p1 = _tube(ROOT / "configs/sewn_sleeve.yaml", [], k)
    assert une.model.seam_count == 2 * 27
    assert ptpu < 1e-6 * eu  # uniform hoop strain
    assert eu == pytest.approx(e2, rel=1e-7)
    assert pu.mean() == pytest.approx(p2.mean(), rel=1e-7)
    assert np.ptp(pu) < 1e-4 * pu.mean()
    assert eu == pytest.approx(e1, rel=1e-5) and pu.mean() == pytest.approx(p1.mean(), rel=1e-5)
    # ... and that difference is one more seam opening: L (1 + e) + n g = 2 pi R round the limb
    g1 = one.summary()["max_seam_gap_m"]
    assert e1 - eu == pytest.approx(g1 / 0.25, rel=0.01)
    r = np.hypot(*une.state.positions[une.model.seam_nodes.ravel(), :2].T)
    np.testing.assert_allclose(r, 0.05, atol=1e-12)
    s = une.summary()
    assert [row["ease_pct"] for row in s["seams"]] == [pytest.approx(0.0, abs=1e-9)] * 2
    assert s["max_seam_gap_m"] < 1e-6


def test_eased_seam_gathers_the_longer_side():
    """configs/garments/eased_seam.yaml: an 11 cm edge (23 nodes) sewn to a 10 cm edge (21
    nodes) held at its length: the summary reports both lengths and 10 % ease; the longer edge
    gathers to the shorter one's length (0.100 m within 1e-6 m: measured 0.1000004 m), its
    springs slack, and the seam closes."""
    res = clothsim.solve(load_scene(EASED))
    assert res.converged, res.solve.message
    m = res.model
    s = res.summary()
    (row,) = s["seams"]
    assert row["a_length_m"] == pytest.approx(0.10) and row["b_length_m"] == pytest.approx(0.11)
    assert row["ease_pct"] == pytest.approx(10.0)
    assert row["max_gap_m"] == s["max_seam_gap_m"] < 1e-6
    from clothsim.selection import seam_sides

    a, b, _ = seam_sides(load_scene(EASED).seams[0], m.topology)
    p = res.state.positions

    def length(x):
        return float(np.linalg.norm(np.diff(p[x], axis=0), axis=1).sum())

    assert length(a) == pytest.approx(0.10, abs=1e-6)
    assert length(b) == pytest.approx(length(a), abs=1e-6)  # gathered from 0.11 m
    # the gathered edge's warp springs are compressed (slack): the fabric gathers
    topo = m.topology
    on_b = np.isin(topo.warp, b).all(axis=1)
    assert (res.strain_warp.ravel()[:topo.warp_count][on_b] < -0.05).all()


def test_paper_relaxation_sews_unequal_counts():
    """A coarse eased seam (10 mm spacing on the lower panel, 7.5 mm on the upper: 11 to 16
    nodes) with a soft seam: the paper's relaxation reaches Newton's equilibrium."""
    over = ["panels.0.spacing=0.01", "panels.1.spacing=0.0075", "seams.0.stiffness=1e4", "solver.e=1e-7"]
    ref = clothsim.solve(load_scene(EASED, over + ["solver.e=1e-11"]))
    assert ref.converged and ref.model.seam_count == 16
    res = clothsim.solve(load_scene(EASED, over + ["solver.method=paper", "solver.time_limit_s=60"]))
    assert res.converged, res.solve.message
    assert np.abs(res.state.positions - ref.state.positions).max() < 1e-5


def test_edges_named_by_pattern_notches():
    """An edge of a panel read from a pattern file may name its vertices by the file's notches:
    configs/garments/sleeve_dxf.yaml's FRONT piece has notch1 at vertex 2 (half-way up its right
    side), so ``edge: [notch1, 3]`` is the upper half of that side (9 nodes, 0.04 m) and sews to
    back's whole left side (17 nodes, 0.08 m) with 100 % ease; an unknown name, or a name on a
    panel without a pattern, is refused naming the field."""
    from clothsim.config import SceneError

    dxf = ROOT / "configs" / "garments" / "sleeve_dxf.yaml"
    m = compile_model(load_scene(dxf, ["seams.0.a={panel: front, edge: [notch1, 3]}"]))
    by_index = compile_model(load_scene(dxf, ["seams.0.a={panel: front, edge: [2, 3]}"]))
    info = m.seams[0]
    assert (info.a_length, info.b_length) == (pytest.approx(0.04), pytest.approx(0.08))
    assert info.ease == pytest.approx(100.0) and info.elements.size == 17
    np.testing.assert_array_equal(m.seam_nodes, by_index.seam_nodes)
    with pytest.raises(SceneError, match=r"seams\.0\.a\.edge: no vertex 'notch9' on panel 'front'; "
                                         r"its named vertices: notch1, notch2"):
        compile_model(load_scene(dxf, ["seams.0.a={panel: front, edge: [notch9, 3]}"]))
    with pytest.raises(SceneError, match=r"constraints\.0\.nodes\.edge: no vertex 'notch1' on panel 'front'; "
                                         r"it has no named vertices"):
        compile_model(load_scene(TWO, ["constraints.0.nodes={panel: front, edge: [notch1, 3]}"]))
