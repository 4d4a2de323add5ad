"""The viewer's compression tools and scene files, server-level (no browser): a click's ray finds
the node under it and its readout equals the Result's fields; the scene's probes are read and drawn
with their values; the Files tab's report, scene zip (an uploaded mold beside the scene, rerunnable)
and scene switcher (validated, errors shown, nothing changed by a bad file); the camera re-frames
when a stretch takes the sheet beyond its view; the default sheet lets the mold show."""

from __future__ import annotations

import io
import time
import zipfile

import numpy as np
import pytest
import yaml

pytest.importorskip("viser")

import clothsim  # noqa: E402
from clothsim.compression import MMHG  # noqa: E402
from clothsim.config import load_scene, scene_from_dict  # noqa: E402
from clothsim.viewer import ViewerApp  # noqa: E402
from clothsim.viewer.draft import open_scene_upload, scene_zip_bytes  # noqa: E402
from clothsim.viewer.pick import ray_hit, ring  # noqa: E402
from clothsim.viewer.render import DEFAULT_SHEET_OPACITY, ViewSettings, needs_reframe  # noqa: E402

from conftest import ROOT  # noqa: E402
from viewer_util import SMALL, free_port, settle  # noqa: E402

CLASS2 = ROOT / "configs" / "class2_sleeve.yaml"


class FakeClient:
    def __init__(self):
        self.sent = {}

    def send_file_download(self, name, content, save_immediately=False):
        self.sent[name] = content


class Event:
    def __init__(self, client):
        self.client = client


def _poll(fn, timeout=60.0):
    t0 = time.time()
    while time.time() - t0 < timeout:
        v = fn()
        if v:
            return v
        time.sleep(0.05)
    return fn()


# ----------------------------------------------------------------------------- picking


def test_ray_hit_finds_the_node_under_a_click():
    """A flat 10 x 10 grid (1 cm cells) in z = 0: a ray down onto (3.4, 6.6) cm hits at t = 1 and
    picks node (3, 7); from below too (both sides); a ray beside the sheet or away from it misses."""
    xs = np.arange(11) * 0.01
    P = np.array([[x, y, 0.0] for x in xs for y in xs])
    idx = np.arange(121).reshape(11, 11)
    F = np.concatenate([np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:]], -1).reshape(-1, 3),
                        np.stack([idx[:-1, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 3)])
    node, t, hit = ray_hit(P, F, (0.034, 0.066, 1.0), (0, 0, -2.0))
    assert node == 3 * 11 + 7 and t == pytest.approx(1.0) and hit == pytest.approx([0.034, 0.066, 0.0])
    assert ray_hit(P, F, (0.034, 0.066, -0.5), (0, 0, 1))[0] == 3 * 11 + 7
    assert ray_hit(P, F, (0.2, 0.05, 1.0), (0, 0, -1)) is None
    assert ray_hit(P, F, (0.05, 0.05, 1.0), (0, 0, 1)) is None  # pointing away
    seg = ring((0, 0, 0), (0, 0, 1), 0.01)
    assert seg.shape == (48, 2, 3) and np.allclose(np.linalg.norm(seg[:, 0], axis=1), 0.01, rtol=1e-6)


@pytest.fixture(scope="module")
def sleeve_app():
    a = ViewerApp(load_scene(CLASS2, ["solver.method=newton", "solver.e=1e-9"]), port=free_port())
    a.start(wait=True)
    assert a.sim.wait(180) == "converged"
    settle(a)
    yield a
    a.close()


def test_probes_read_and_drawn_and_click_readout(sleeve_app):
    """The class II sleeve: the Probes tab's readings equal the Result's (summary) probes, each is
    drawn as a ring with a label 'ankle 25.0 mmHg'; a click from outside the limb towards the ankle
    probe picks a node on it whose pressure, strains and tensions equal the Result's fields."""
    app = sleeve_app
    res = app.sim.result()
    want = {r["name"]: r for r in res.compression()["probes"]}
    pp = app.panels["probes"]
    assert _poll(lambda: pp.read_at == app.sim.state.iteration > 0 and len(pp.readings) == 2)
    for r in pp.readings:
        assert r["pressure_mmhg"] == pytest.approx(want[r["name"]]["pressure_mmhg"], rel=1e-9)
    ankle = next(r for r in pp.readings if r["name"] == "ankle")
    assert 23 <= ankle["pressure_mmhg"] <= 32
    labels = [h for h in pp._nodes if type(h).__name__ == "LabelHandle"]
    assert any(h.text == f"ankle {ankle['pressure_mmhg']:.1f} mmHg" for h in labels), [h.text for h in labels]
    assert "| ankle |" in app.gui["probes_table"].content and "RAL-GZ 387" in app.gui["probes_table"].content
    # a click: the ray from outside the limb through the probe's point, towards the axis
    pp.pick_ray((0.2, 0.0, 0.001), (-1.0, 0.0, 0.0))
    assert _poll(lambda: pp.readout is not None)
    n = pp.readout["node"]
    pos = app.sim.state.positions
    assert pos[n][0] > 0.03 and abs(pos[n][1]) < 0.01 and abs(pos[n][2]) < 0.005
    nx1, ny1 = res.model.grid_shape
    i, j = divmod(n, ny1)
    assert pp.readout["ij"] == (i, j)
    assert pp.readout["pressure_mmhg"] == pytest.approx(res.contact_pressure[i, j] / MMHG, rel=1e-9)
    assert pp.readout["pressure_mmhg"] == pytest.approx(ankle["pressure_mmhg"], rel=5e-3)
    # node values: the mean of the node's springs (warp springs i-1..i, weft j-1..j)
    sw, sf = res.strain_warp, res.strain_weft
    assert pp.readout["strain_warp"] == pytest.approx(np.mean(sw[max(i - 1, 0):i + 1, j]), rel=1e-9)
    assert pp.readout["strain_weft"] == pytest.approx(np.mean(sf[i, max(j - 1, 0):j + 1]), rel=1e-9)
    assert pp.readout["tension_warp"] > 0
    text = app.gui["readout"].content
    assert f"node {n}" in text and f"{pp.readout['pressure_mmhg']:.2f} mmHg" in text
    assert pp._pick_node is not None and np.allclose(pp._pick_node.position, pos[n], atol=1e-6)
    # a click that misses the sheet keeps the readout
    pp.pick_ray((0.2, 0.0, 0.5), (1.0, 0.0, 0.0))
    settle(app)
    assert pp.readout["node"] == n


def test_report_download_is_the_report_of_the_shown_state(sleeve_app):
    """Files > Report (.html): the same report as 'app.py report' of the current result (its probe
    value in the table), sent to the asking tab."""
    app = sleeve_app
    c = FakeClient()
    app.panels["files"].download(Event(c), "html")
    name = _poll(lambda: next(iter(c.sent), None), timeout=120)
    assert name == "class2-sleeve-report.html", app.errors
    text = c.sent[name].decode()
    ankle = app.sim.result().compression()["probes"][0]
    assert text.startswith("<!DOCTYPE html>") and "data:image/png;base64," in text
    assert f"{ankle['pressure_mmhg']:.2f}" in text


# ----------------------------------------------------------------------------- scene files


def test_scene_zip_keeps_an_uploaded_mold_and_reruns(tmp_path):
    """A scene whose mold was uploaded to the viewer: its zip holds scene.yaml with the mold path
    rewritten to files/mold.stl (relative), the mold and the CSV tables; unzipped elsewhere it
    loads and solves to the same equilibrium as the viewer's scene."""
    import trimesh

    app = ViewerApp(scene_from_dict(SMALL), port=free_port())
    try:
        sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
        sphere.apply_translation((0.05, 0.05, -0.02))
        app.panels["fabric"].mold_uploaded("ball.stl", sphere.export(file_type="stl"))
        settle(app)
        assert app.draft["mold"]["path"].startswith(str(app.upload_dir)), app.errors
        assert "Save scene + files" in app.scene_yaml()  # the YAML's note points at the zip
        c = FakeClient()
        app.panels["files"].download(Event(c), "zip")
        settle(app)
        data = c.sent["small-cap.zip"]
        z = zipfile.ZipFile(io.BytesIO(data))
        assert set(z.namelist()) == {"scene.yaml", "files/mold.stl"}
        d = yaml.safe_load(z.read("scene.yaml"))
        assert d["mold"]["path"] == "files/mold.stl"
        z.extractall(tmp_path / "copy")
        app.apply(wait=True)
        settle(app)
        ref = clothsim.solve(app.sim.scene)
    finally:
        app.close()
    assert not app.upload_dir.exists()  # the viewer's copy is gone; the zip's stays
    again = clothsim.solve(load_scene(tmp_path / "copy" / "scene.yaml"))
    assert again.solve.converged and ref.solve.converged
    np.testing.assert_allclose(again.state.positions, ref.state.positions, atol=1e-12)
    # CSV tables travel too
    data = scene_zip_bytes(load_scene(CLASS2))
    names = set(zipfile.ZipFile(io.BytesIO(data)).namelist())
    assert names == {"scene.yaml", "files/compression_knit_course.csv", "files/compression_knit_wale.csv"}


def _zip(members: dict) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for k, v in members.items():
            z.writestr(k, v)
    return buf.getvalue()


def test_open_scene_upload_validates_and_refuses(tmp_path):
    """A zip written by 'Save scene + files' opens again; bad files are refused with the uploaded
    file's name: a path out of the folder, no scene, two scenes, an invalid field, a wrong type,
    too much once unpacked."""
    good = scene_zip_bytes(load_scene(CLASS2))
    scene = open_scene_upload("chart.zip", good, tmp_path / "a", 10**8)
    assert scene.name == "class2-sleeve" and scene.mold is not None
    cases = [
        ("evil.zip", _zip({"scene.yaml": "name: x", "../escape.csv": "0,0"}), "not a plain relative path"),
        ("none.zip", _zip({"files/a.csv": "0,0"}), "one scene .yaml"),
        ("two.zip", _zip({"a.yaml": "name: a", "b.yaml": "name: b"}), "one scene .yaml"),
        ("bad.yaml", (CLASS2.read_text().replace("divisions: [34, 16]", "divisions: [0, 16]")).encode(),
         "bad.yaml:"),
        ("notes.txt", b"hello", "a .yaml file or a .zip"),
        ("junk.zip", b"PK\x03\x04 not really", "not a readable zip"),
        ("big.zip", _zip({"scene.yaml": "x" * 5000}), "more than the upload limit"),
    ]
    for k, (name, data, msg) in enumerate(cases):
        with pytest.raises(Exception, match=msg.replace(".", r"\.")) as exc:
            open_scene_upload(name, data, tmp_path / f"c{k}", 4000)
        assert str(tmp_path) not in str(exc.value)
    assert not (tmp_path / "escape.csv").exists()


def test_scene_switcher_replaces_the_scene_or_changes_nothing():
    """Files > Open scene: an invalid upload shows its error and leaves the scene; a valid zip
    becomes the simulation's scene (title, model, draft, widgets) and converges."""
    app = ViewerApp(scene_from_dict(SMALL), port=free_port())
    try:
        model = app.sim.model
        bad = (CLASS2.read_text().replace("divisions: [34, 16]", "divisions: [0, 16]")).encode()
        fp = app.panels["files"]
        app.post(lambda: fp.open_scene("sleeve.yaml", bad), "files")
        settle(app)
        assert "sleeve.yaml" in app.errors["files"] and "divisions" in app.errors["files"], app.errors
        assert app.sim.model is model and app.sim.scene.name == "small-cap"
        app.post(lambda: fp.open_scene("c2.zip", scene_zip_bytes(load_scene(CLASS2))), "files")
        settle(app)
        assert app.errors["files"] == "", app.errors
        assert app.sim.scene.name == "class2-sleeve" and app.sim.model.grid_shape == (35, 17)
        assert "class2-sleeve" in app.gui["title"].content and app.draft["name"] == "class2-sleeve"
        assert app.gui["nx"].value == 34 and not app.pending
        app.start(wait=True)
        assert app.sim.wait(180) == "converged"
    finally:
        app.close()


# ----------------------------------------------------------------------------- camera, mold


def test_reframe_rule():
    box = (np.zeros(3), np.ones(3))
    assert needs_reframe(None, box)
    assert not needs_reframe(box, (np.zeros(3), np.full(3, 1.4)))  # within a quarter diagonal
    assert needs_reframe(box, (np.zeros(3), np.array([2.0, 1.0, 1.0])))
    assert needs_reframe(box, (np.array([-0.5, 0, 0]), np.ones(3)))


def test_camera_reframes_after_a_stretch():
    """A strip pulled to three times its length runs beyond the framed view: the update loop points
    every tab's camera at the stretched sheet (framed_box follows it); a small change does not."""
    strip = {"name": "strip", "fabric": {"size": [0.1, 0.02], "divisions": [10, 2],
                                         "warp": {"strain": [0, 1], "tension": [0, 100]},
                                         "weft": {"strain": [0, 1], "tension": [0, 100]}},
             "constraints": [{"nodes": "left", "axes": "xyz"},
                             {"nodes": "right", "axes": "xyz", "displacement": [0.001, 0, 0]}],
             "solver": {"method": "newton", "e": 1e-8}}
    app = ViewerApp(scene_from_dict(strip), port=free_port())
    try:
        settle(app)
        n0 = app.reframes
        box0 = app.framed_box
        assert box0 is not None and box0[1][0] == pytest.approx(0.1, abs=2e-3)
        app.start(wait=True)
        assert app.sim.wait(60) == "converged"
        settle(app)
        assert app.reframes == n0  # 1 mm: no re-framing
        app.scene_draft.edit("constraints", lambda d: d["constraints"][1].__setitem__("displacement", [0.2, 0, 0]))
        app.start(wait=True)
        assert app.sim.wait(60) == "converged"
        settle(app)
        assert app.reframes > n0
        assert app.framed_box[1][0] == pytest.approx(0.3, abs=1e-3)
    finally:
        app.close()


def test_default_sheet_lets_the_mold_show():
    """The default scene's mold lay hidden under an opaque sheet: the sheet is see-through by
    default (a blended GLB material)."""
    from clothsim.viewer.glb import GlbMeshWriter

    assert ViewSettings().sheet_opacity == DEFAULT_SHEET_OPACITY < 1.0
    app = ViewerApp(load_scene(ROOT / "configs" / "thermoform.yaml"), port=free_port())
    try:
        settle(app)
        assert app.panels["view"].settings().sheet_opacity == DEFAULT_SHEET_OPACITY
        glb = app.renderer.h_cloth.glb_data
        assert b'"alphaMode":"BLEND"' in glb.replace(b" ", b"")
        assert app.renderer.h_mold is not None and app.renderer.h_mold.visible
    finally:
        app.close()
