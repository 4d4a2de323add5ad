"""Grid sequencing on cut and multi-panel lattices: the stride-2 prolongation, the coarse model
(Topology.coarsen + clothsim.lattice._coarsen_lattice), and the same equilibrium with sequencing as
without it on the circle and on the four-panel garment of the benchmark."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from clothsim.bench import Case, _load, four_panel_cap_overrides
from clothsim.grid import FAMILY_WARP, FAMILY_WEFT, coarsen_model
from clothsim.solvers import solve
from clothsim.solvers.newton import NewtonSolver, sequencing_chain
from clothsim.solvers.options import newton_options
from clothsim.solvers.tuning import NewtonTuning
from clothsim.topology import Topology


def _newton(model, state, settings, tuning):
    """``solve`` with Newton under ``tuning`` (the scene's other options as they are)."""
    return NewtonSolver(model, replace(newton_options(settings), tuning=tuning)).solve(state, settings)

ROOT = Path(__file__).resolve().parents[1]


def test_lattice_prolongation_equals_the_grid_one_on_a_rectangle():
    t = Topology.rectangle(8, 6)
    c, sub = t.coarsen()
    P = t.lattice_prolongation(c, sub)
    _, Q = t.grid_prolongation()
    assert abs(P - Q).max() == 0.0


def test_lattice_prolongation_on_a_cut_lattice():
    m = np.ones((9, 9), bool)
    m[:3, :3] = False
    m[7:, 6:] = False
    t = Topology.from_masks([m, np.ones((5, 5), bool)])
    c, sub = t.coarsen()
    P = t.lattice_prolongation(c, sub)
    assert np.allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0)  # partition of unity
    assert abs(P[sub] - sp.eye(c.node_count)).max() == 0.0  # coarse nodes keep their value
    # linear functions of (i, j) are reproduced on the full panel (all corners exist)
    f = t.node_ij[:, 0] * 2.0 + t.node_ij[:, 1] * 3.0
    full = t.node_panel == 1
    assert np.allclose((P @ f[sub])[full], f[full])


def _case(name):
    if name == "circle":
        return Case("circle", "configs/garments/circle_cap.yaml", ["panels.0.divisions=[60,60]"])
    return Case("four", "configs/garments/circle_cap.yaml", four_panel_cap_overrides(20))


def test_coarse_circle_keeps_area_and_band_widths():
    model, _, _ = _load(_case("circle"), "newton", 1e-7, None)
    coarse, sub = coarsen_model(model)
    assert coarse is not None and coarse.node_count == sub.size
    assert np.isclose(coarse.node_area.sum(), model.node_area.sum(), rtol=1e-12)
    for f in (FAMILY_WARP, FAMILY_WEFT):
        k, kc = model.spring_family == f, coarse.spring_family == f
        band = (model.spring_width[k] * model.spring_rest_length[k]).sum()
        bandc = (coarse.spring_width[kc] * coarse.spring_rest_length[kc]).sum()
        assert abs(bandc / band - 1) < 0.05  # the outline's half cells are what differ
    assert len(sequencing_chain(model, min_nodes=100)) >= 2


def test_full_rectangle_path_unchanged():
    # a one-panel full rectangle still goes through the closed-form coarse grid
    model, _, _ = _load(Case("sq", "configs/sphere_cap.yaml", []), "newton", 1e-7, None)
    coarse, _ = coarsen_model(model)
    k = coarse.spring_family == FAMILY_WARP
    assert np.allclose(coarse.spring_width[k].max(), 2 * model.spacing[1])


def _solve(name, seq):
    model, state, settings = _load(_case(name), "newton", 1e-9, 60.0)
    assert len(sequencing_chain(model)) >= 2  # the sequencing does run on this lattice
    res = solve(model, state, settings.model_copy(update={"newton_sequencing": seq}))
    return state.positions, res


def test_sequencing_gives_the_same_equilibrium_on_panels():
    for name in ("circle", "four"):
        p_seq, r_seq = _solve(name, True)
        p_off, r_off = _solve(name, False)
        assert r_seq.status == "converged" and r_off.status == "converged", name
        assert np.abs(p_seq - p_off).max() < 1e-7, name
        assert abs(r_seq.energy - r_off.energy) <= 1e-9 * abs(r_off.energy), name


def test_garment_bench_cases_and_report(tmp_path):
    from clothsim.bench import garment_cases, write_garment_report

    names = [c.name for c in garment_cases()]
    assert names[0] == "sphere cap 201^2" and len(names) == 3
    rows = [{"case": n, "nodes": 40000, "status": "converged", "iterations": 4,
             "times": {"1e-07": 1.0, "1e-09": 1.2}, "times_wu": {"1e-07": wu, "1e-09": wu * 1.1},
             "error_final": 1e-9} for n, wu in zip(names, (1000.0, 1500.0, 3000.0))]
    write_garment_report(rows, tmp_path, 1.0)
    text = (tmp_path / "benchmarks_garments.md").read_text()
    assert "| 1.50 |" in text and "| 3.00 |" in text


def test_no_outline_band_where_every_panel_is_a_full_rectangle(monkeypatch):
    """Sewn full-rectangle panels (their coarse lattices hold every outline exactly, as the
    square's do) get no outline band or rim relaxation in the sequencing, a cut lattice does.
    Forced back on the four panels, the band changes neither the Newton iterations nor the
    equilibrium (beyond 1e-9 m)."""
    from clothsim.solvers.newton import sequencing as S

    assert Topology.rectangle(4, 3).panels_full
    assert Topology.from_masks([np.ones((5, 5), bool), np.ones((3, 4), bool)]).panels_full
    cut = np.ones((5, 5), bool)
    cut[0, 0] = False
    assert not Topology.from_masks([np.ones((5, 5), bool), cut]).panels_full

    four, _, _ = _load(_case("four"), "newton", 1e-7, None)
    circle, _, _ = _load(_case("circle"), "newton", 1e-7, None)
    assert four.topology.panels_full and not circle.topology.panels_full
    hf = S._Hierarchy(four, 1e-3)
    assert all(b is None for b in hf.bands) and all(r is None for r in hf.rim_ops)
    hc = S._Hierarchy(circle, 1e-3)
    assert all(b is not None and b.size for b in hc.bands)

    # the four panels with the band and the rim relaxation forced back: the same Newton
    # iterations and equilibrium (the fine steps take what the settling would have done)
    four, fstate, settings = _load(_case("four"), "newton", 1e-9, 60.0)
    same = NewtonTuning(cut_coarsest_nodes=400)  # (the same chain both ways)
    runs = []
    for forced in (False, True):
        if forced:
            # the lattice taken for a cut one: the hierarchy gets its bands and rim operators
            monkeypatch.setattr(Topology, "panels_full", property(lambda self: False))
        S._HIERARCHIES.clear()
        h = S._hierarchy(four, settings.newton_kink, same)
        assert (h.bands[-1] is not None and h.bands[-1].size > 0) == forced
        st = fstate.copy()
        res = _newton(four, st, settings, same)
        runs.append((res.iterations, st.positions))
    S._HIERARCHIES.clear()
    assert runs[0][0] == runs[1][0]
    assert 0 < np.abs(runs[0][1] - runs[1][1]).max() < 1e-9  # (not the same path: the band did run)


def test_cut_lattice_sequences_down_to_a_smaller_coarsest_grid():
    """A cut lattice's sequencing goes down to NewtonTuning.cut_coarsest_nodes (its coarsest grid carries the
    guessed holds' refit), a full one's stops at 400 nodes: the 161-across circle then reaches
    1e-7 N in two fine Newton steps instead of three, at the same equilibrium."""
    from clothsim.solvers.newton import sequencing as S

    circle, _, _ = _load(_case("circle"), "newton", 1e-7, None)
    chain = S._Hierarchy(circle, 1e-3).chain
    assert NewtonTuning().cut_coarsest_nodes <= chain[0][0].node_count < 400
    square, _, _ = _load(Case("sq", "configs/sphere_cap.yaml", ["fabric.divisions=[40,40]"]), "newton", 1e-7, None)
    assert S._Hierarchy(square, 1e-3).chain[0][0].node_count >= 400

    case = Case("c161", "configs/garments/circle_cap.yaml", ["panels.0.divisions=[160,160]"])
    runs = []
    for nodes in (400, NewtonTuning().cut_coarsest_nodes):
        model, state, settings = _load(case, "newton", 1e-7, 60.0)
        res = _newton(model, state, settings, NewtonTuning(cut_coarsest_nodes=nodes))
        assert res.status == "converged"
        runs.append((res.iterations, state.positions))
    S._HIERARCHIES.clear()
    assert (runs[0][0], runs[1][0]) == (4, 3)
    assert np.abs(runs[0][1] - runs[1][1]).max() < 1e-7


def test_middle_levels_take_one_newton_iteration(monkeypatch):
    """The levels between the coarsest and the last coarse one take NewtonTuning.mid_level_iterations (1)
    Newton iteration: on the 113-across circle its 625-node level took 2 uncapped; capped, the
    fine lattice starts as well (the same fine iterations) and reaches the same equilibrium."""
    from clothsim.solvers.newton import iteration as I
    from clothsim.solvers.newton import sequencing as S

    counts: dict = {}
    orig = I.NewtonLevel.iterate

    def counted(self, *a, **k):
        counts[self.n] = counts.get(self.n, 0) + 1
        return orig(self, *a, **k)

    monkeypatch.setattr(I.NewtonLevel, "iterate", counted)
    case = Case("c113", "configs/garments/circle_cap.yaml", ["panels.0.divisions=[112,112]"])
    runs = []
    for cap in (None, 1):
        model, state, settings = _load(case, "newton", 1e-7, 600.0)
        chain = S._Hierarchy(model, 1e-3).chain
        assert len(chain) >= 4
        counts.clear()
        res = _newton(model, state, settings, NewtonTuning(mid_level_iterations=cap))
        assert res.status == "converged"
        mids = [counts.get(m.node_count, 0) for m, _ in chain[1:-2]]
        runs.append((mids, res.iterations, state.positions))
    S._HIERARCHIES.clear()
    assert max(runs[0][0]) >= 2 and max(runs[1][0]) == 1
    assert runs[0][1] == runs[1][1]
    assert np.abs(runs[0][2] - runs[1][2]).max() < 1e-7
