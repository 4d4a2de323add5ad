"""The benchmark's scan campaign (clothsim.bench): its scenes and its report. The campaign's runs
and timings are in the benchmark itself, not here."""

import numpy as np
import pytest

from clothsim import bench

from conftest import ROOT


def test_missing_bodies_are_skipped_with_a_message(tmp_path, monkeypatch):
    monkeypatch.setattr(bench, "SCAN_DIRS", (tmp_path / "nowhere",))
    said = []
    rows = bench.run(out=tmp_path, log=said.append, scans="only")
    assert rows == []
    assert any("smpl_man.stl not found" in s and "skipped" in s for s in said)
    assert "No body file found" in (tmp_path / "benchmarks_scans.md").read_text()


def test_scan_band_scene_is_the_papers_band_on_the_upright_body():
    """The band is the paper's (41 x 11 nodes, ends held in x and y), the Y-up scan is turned
    Z-up (its top at the body's height, 1.79 m) with its front towards +y, and the band starts
    clear of it round the given height, centred on the front."""
    from clothsim.config import load_scene
    from clothsim.simulation import prepare

    path = bench.scan_body_path("smpl_man")
    if path is None:
        pytest.skip("smpl_man.stl not found (bench.SCAN_DIRS)")
    scene = load_scene(ROOT / "configs" / "torso_band.yaml", bench.scan_band_overrides(path, 1.10))
    model, state, _ = prepare(scene)  # refuses a start that touches the mold
    assert model.node_count == 41 * 11
    assert model.fixed_axes.any(axis=1).sum() == 22
    V = model.mold.vertices
    assert abs(V[:, 2].max() - 1.791) < 2e-3 and abs(V[:, 2].min()) < 1e-9
    # the front (the belly, SMPL's +z) is +y: the body is deeper in front of its axis than behind
    slab = np.abs(V[:, 2] - 1.10) < 0.02
    assert V[slab, 1].max() > -V[slab, 1].min()
    mid = state.positions[model.node_count // 2]
    assert abs(mid[2] - 1.10) < 1e-9 and mid[1] > 0 and abs(mid[0]) < 0.05
    assert not state.in_contact.any()


def test_scan_table_counts_and_flags():
    rows = [{"body": "b", "height": 1.0 + 0.02 * i, "surface": "faceted", "nodes": 451,
             "status": "converged" if i else "stalled", "iterations": 40 + i, "residual": 1e-10,
             "wall_s": 1.0, "wu": 1e4, "ms_per_iteration": 5.0, "contact": 300} for i in range(3)]
    text = "\n".join(bench.scan_table(rows))
    assert "Converged 2 of 3; iterations 41-42" in text
    assert text.count("| b | faceted |") == 3 and "| stalled |" in text
    # a garment's row (bench.SCAN_GARMENTS) has no height
    text = "\n".join(bench.scan_table([{**rows[1], "body": "stocking 14 x 30", "height": None}]))
    assert "| stocking 14 x 30 | faceted | - | 451 | converged |" in text


def test_every_scan_garment_compiles():
    """Each garment of the campaign (bench.SCAN_GARMENTS) builds: the refined stocking's overrides
    double the ankle's single-node seams and the held column with its divisions (with the panels'
    divisions alone it was refused, "seams.2.b: selects no nodes")."""
    from clothsim.compile import compile_model
    from clothsim.config import load_scene

    counts = []
    for name, stem, config, overrides, surface in bench.SCAN_GARMENTS:
        model = compile_model(load_scene(ROOT / config, list(overrides)))
        counts.append(model.node_count)
    assert counts[1] > 3 * counts[0]
