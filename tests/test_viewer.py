"""Server-level tests of the viser app (no browser): start/stop, a full run through the app's own
API, what the scene nodes received, validation of edits, upload limits, concurrent edits, and the
helpers (GLB writer, per-node fields) against independent references."""

from __future__ import annotations

import io
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")

from clothsim.config import scene_from_dict  # noqa: E402
from clothsim.records import OUTPUT_FIELDS  # noqa: E402
from clothsim.viewer import ViewerApp, parse_table_text  # noqa: E402
from clothsim.viewer.glb import GlbMeshWriter, colormap, read_glb_positions  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

from viewer_util import SMALL, free_port, settle, small_scene, wait_for  # noqa: E402,F401

@pytest.fixture
def app():
    a = ViewerApp(small_scene(), port=free_port())
    a.wait_idle(20)
    yield a
    a.close()


def test_starts_on_free_port_and_stops_cleanly():
    """A busy port is not an error: the app takes the next free one and reports it; it serves the
    page; close() stops the server, the update loop and the solver thread within seconds."""
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    try:
        a = ViewerApp(small_scene(), port=port)
        try:
            assert a.port != port
            assert a.url == f"http://127.0.0.1:{a.port}"
            with urllib.request.urlopen(a.url, timeout=10) as r:
                assert r.status == 200
                assert b"<html" in r.read().lower()
        finally:
            t0 = time.perf_counter()
            a.close()
            stop_s = time.perf_counter() - t0
        assert stop_s < 5
        assert not a._thread.is_alive()
        with pytest.raises(OSError):
            urllib.request.urlopen(a.url, timeout=2)
    finally:
        busy.close()


def test_full_run_converges_and_scene_gets_final_positions(app):
    """Start through the app's API on a 10 x 10 sphere cap: the solver converges (residual <= e),
    and the sheet node's GLB, the constrained-node point cloud, the status line and the plot all
    show the final state (the GLB positions are decoded and compared with the solver's)."""
    app.start(wait=True)
    assert app.sim.wait(300) == "converged"
    settle(app)
    sim = app.sim
    assert sim.residual <= sim.settings.e
    assert app.pushed_iteration == sim.state.iteration > 0
    shown = read_glb_positions(app.renderer.h_cloth.glb_data)
    np.testing.assert_allclose(shown, sim.state.positions, atol=1e-6)
    fixed = sim.model.fixed_axes.any(axis=1)
    np.testing.assert_allclose(app.renderer.h_fixed.points, sim.state.positions[fixed], atol=1e-6)
    # the status line and the plot follow the frame on the update loop's next pass (a loaded
    # machine may take a while to get there)
    t0 = time.time()
    while "converged" not in app.gui["status"].content and time.time() - t0 < 30:
        time.sleep(0.05)
    assert "converged" in app.gui["status"].content
    assert f"iteration {sim.state.iteration}" in app.gui["status"].content
    x, y, e = app.gui["plot"].data
    assert x[-1] == sim.state.iteration and y[-1] <= sim.settings.e and np.all(e == sim.settings.e)
    # the mold (a sphere) is shown
    assert app.renderer.h_mold is not None and app.renderer.h_mold.visible


def test_step_pause_reset(app):
    """Step advances one iteration; Reset returns to the initial deformation."""
    p0 = app.sim.state.positions.copy()
    app.step(wait=True)
    t0 = time.time()
    while app.sim.state.iteration < 1 and time.time() - t0 < 30:
        time.sleep(0.02)
    app.sim.wait(30)
    assert app.sim.state.iteration == 1 and app.sim.status == "paused"
    app.reset()
    settle(app)
    assert app.sim.state.iteration == 0
    np.testing.assert_allclose(app.sim.state.positions, p0)


def test_solver_edits_validated_and_live(app):
    """C and e reach the running relaxation's settings; an invalid C shows an error and changes
    nothing."""
    app.gui["C"].value = 0.5
    settle(app)
    assert app.sim.settings.C == 2.0
    assert "greater than 1" in app.errors["solver"]
    app.gui["C"].value = 3.0
    app.gui["e"].value = "2e-6"
    settle(app)
    assert app.sim.settings.C == 3.0 and app.sim.settings.e == 2e-6
    assert app.errors["solver"] == ""
    app.gui["e"].value = "abc"
    settle(app)
    assert app.sim.settings.e == 2e-6 and "not a number" in app.errors["solver"]


def test_material_constraint_fabric_edits(app):
    """An invalid material table is refused with the table checker's message and leaves the draft
    as it was; valid edits of materials, constraints and divisions wait in the draft until Apply,
    which rebuilds the model."""
    before = app.draft["fabric"]["warp"]
    app.gui["warp_text"].value = "0, 0\n0.5, 10\n0.3, 20"
    settle(app)
    assert "strictly increasing" in app.errors["warp_table"]  # on the table's own line
    assert app.draft["fabric"]["warp"] == before and not app.pending
    app.gui["warp_text"].value = "0, 0\n0.2, 40\n1.0, 400"
    settle(app)
    assert app.errors["warp_table"] == "" and app.errors["material"] == "" and app.draft["fabric"]["warp"]["tension"] == [0, 40, 400]
    app.gui["weft_unit"].value = "Pa (stress)"  # no thickness: refused
    settle(app)
    assert "thickness" in app.errors["material"]
    app.gui["weft_unit"].value = "N/m (tension)"
    app.gui["preset"].value = "powernet_est"
    settle(app)
    assert app.draft["fabric"]["warp"] == {"preset": "powernet_est"}
    # constraints: add corners fixed in z only
    app.gui["c_select"].value = "+ new constraint"
    settle(app)
    app.gui["c_nodes"].value = "corners"
    app.gui["c_axes"].value = "z"
    app.post(app.panels["constraints"].save, "constraints")
    app.gui["nx"].value = 12
    settle(app)
    assert app.draft["constraints"][-1] == {"nodes": "corners", "axes": "z"}
    assert app.draft["fabric"]["divisions"] == [12, 10]
    app.gui["nx"].value = 0
    settle(app)
    assert "at least 1" in app.errors["fabric"] and app.draft["fabric"]["divisions"] == [12, 10]
    assert app.sim.model.grid_shape == (11, 11)
    app.apply()
    settle(app)
    assert app.errors["run"] == "", app.errors
    assert app.sim.model.grid_shape == (13, 11) and not app.pending
    assert len(read_glb_positions(app.renderer.h_cloth.glb_data)) == 13 * 11


def test_mold_upload_limits_and_formats(tmp_path):
    """A valid STL upload becomes the draft's mold (stored in the app's private temp folder under
    its own name); an unknown format is refused with the loader's message; an upload over the
    limit is refused when announced (its transfer state dropped) and again on arrival."""
    import trimesh
    from viser import _messages

    a = ViewerApp(small_scene(), port=free_port(), upload_limit_mb=0.05)
    try:
        a.wait_idle(20)
        box = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
        box.apply_translation((0.05, 0.05, -0.011))
        data = box.export(file_type="stl")
        a.post(lambda: a.panels["fabric"].mold_uploaded("../../evil name.stl", data), "mold")
        settle(a)
        assert a.errors["mold"] == ""
        path = Path(a.draft["mold"]["path"])
        assert path.parent == a.upload_dir and path.name == "mold_upload_1.stl"
        assert oct(a.upload_dir.stat().st_mode & 0o777) == "0o700"
        assert a.gui["mold"].value.startswith("upload: ")
        assert a.renderer.h_mold is not None  # the pending mold is previewed
        a.apply(wait=True)
        settle(a)
        assert a.sim.model.mold.kind_name == "mesh"
        # unknown format
        a.post(lambda: a.panels["fabric"].mold_uploaded("notes.xyz", b"\x00\x01garbage" * 10), "mold")
        settle(a)
        assert "unknown mold format" in a.errors["mold"]
        assert Path(a.draft["mold"]["path"]) == path
        # over the limit, announced by the browser
        a.server.gui._current_file_upload_states["t1"] = {"parts": {}}
        msg = _messages.FileTransferStartUpload(
            source_component_uuid=a.gui["mold_upload"]._impl.uuid, transfer_uuid="t1", filename="big.stl",
            mime_type="model/stl", size_bytes=10 * 2**20, part_count=10)
        a.upload_guard.on_start("no-such-client", msg)
        settle(a)
        assert "t1" not in a.server.gui._current_file_upload_states
        assert "over the upload limit" in a.errors["mold"]
        # over the limit on arrival (a client that lied about its size)
        from viser import UploadedFile

        a.gui["mold_upload"]._impl.value = UploadedFile("big.stl", b"x" * (a.upload_limit + 1))
        a.upload_callback(a.gui["mold_upload"], a.panels["fabric"].mold_uploaded, "mold")(None)
        settle(a)
        assert "over the upload limit" in a.errors["mold"]
        tmp = a.upload_dir
    finally:
        a.close()
    assert not tmp.exists()


@pytest.mark.slow
def test_concurrent_edits_cannot_crash(app):
    """Eight threads (like eight tabs) hammer the app with valid and invalid edits and controls
    while it runs; afterwards the app, its update loop and the solver are alive and a final run
    still converges."""
    stop = time.time() + 2.0
    errors = []

    def worker(seed):
        rng = np.random.default_rng(seed)
        try:
            while time.time() < stop:
                k = rng.integers(8)
                if k == 0:
                    app.gui["C"].value = float(rng.choice([0.5, 1.5, 2.0, 3.0]))
                elif k == 1:
                    app.gui["e"].value = str(rng.choice(["1e-6", "x", "-1", "2e-6"]))
                elif k == 2:
                    app.gui["warp_text"].value = str(rng.choice(["0,0\n1,250", "0,0\n1,-3", "bad"]))
                elif k == 3:
                    app.gui["field"].value = str(rng.choice(list(app.gui["field"].options)))
                elif k == 4:
                    [app.start, app.pause, app.step][int(rng.integers(3))]()
                elif k == 5:
                    app.gui["nx"].value = int(rng.choice([0, 8, 10]))
                elif k == 6:
                    app.apply()
                else:
                    app.reset()
                time.sleep(float(rng.uniform(0, 0.01)))
        except Exception as exc:  # pragma: no cover - the assertion below reports it
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(s,)) for s in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    settle(app, 0.3)
    app.sim.pause(wait=True)
    assert app._thread.is_alive()
    app.gui["C"].value = 2.0
    app.gui["e"].value = "1e-6"
    app.gui["warp_text"].value = "0,0\n1,250"
    app.gui["nx"].value = 10
    settle(app)
    app.reset()
    settle(app)
    app.start(wait=True)
    assert app.sim.wait(300) == "converged", app.sim.message


def test_scene_yaml_download_roundtrip(app):
    """The downloaded YAML loads back into the same scene (paths made absolute)."""
    import yaml

    text = app.scene_yaml()
    again = scene_from_dict(yaml.safe_load(text))
    assert again.to_dict() == scene_from_dict(app.draft).to_dict()


def test_node_fields_match_result(app):
    """The viewer's whole-array per-node fields equal results.Result's (strain, pressure)."""
    from clothsim.results import MMHG
    from clothsim.viewer.fields import node_field

    app.start(wait=True)
    assert app.sim.wait(300) == "converged"
    r = app.sim.result()
    m, s = app.sim.model, app.sim.state
    p = node_field(m, s.positions, s.in_contact, "pressure")
    np.testing.assert_allclose(p, r.contact_pressure.ravel() / MMHG, rtol=1e-9, atol=1e-12)
    assert p.max() > 0
    w = node_field(m, s.positions, s.in_contact, "strain_warp").reshape(m.grid_shape)
    np.testing.assert_allclose(w[1:-1], 0.5 * (r.strain_warp[1:] + r.strain_warp[:-1]), rtol=1e-12)
    np.testing.assert_allclose(np.maximum(w, node_field(m, s.positions, s.in_contact, "strain_weft")
                                          .reshape(m.grid_shape)), r.node_strain(), rtol=1e-12)


def test_glb_writer_reads_back_in_trimesh():
    """The hand-written GLB is valid glTF: trimesh loads it with the same vertices and faces."""
    import trimesh

    from clothsim.topology import Topology

    rng = np.random.default_rng(0)
    P = rng.random((12, 3))
    F = Topology.rectangle(2, 3).faces
    w = GlbMeshWriter(F)
    glb = w.build(P, colormap(P[:, 0], 0, 1), None, opacity=0.5)
    assert len(glb) % 4 == 0
    np.testing.assert_allclose(read_glb_positions(glb), P, rtol=1e-6)
    m = trimesh.load(io.BytesIO(glb), file_type="glb", force="mesh", process=False)
    assert len(m.vertices) == 12 and len(m.faces) == len(F)


def test_parse_table_text():
    assert parse_table_text("# strain, N/m\n0, 0\n0.5;10\n1 30  # end\n") == ([0, 0.5, 1], [0, 10, 30])
    with pytest.raises(ValueError, match="line 2"):
        parse_table_text("0,0\n0.5\n")


def test_core_does_not_import_viser():
    """Only the clothsim/viewer/ package may import viser, and within it neither the scene draft
    nor the field, GLB and plot helpers (testable without a server)."""
    pure = {"draft.py", "fields.py", "glb.py", "plot.py"}
    for p in (ROOT / "clothsim").rglob("*.py"):
        rel = p.relative_to(ROOT / "clothsim")
        if rel.parts[0] == "viewer" and rel.name not in pure:
            continue
        assert not re.search(r"^\s*(import|from)\s+viser\b", p.read_text(), re.M), p


def _sigint_ignored() -> bool:
    """Whether this process ignores SIGINT at the kernel's level (/proc/self/status SigIgn; the
    signal module only sees handlers set through it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("SigIgn:"):
                return bool(int(line.split()[1], 16) & (1 << (signal.SIGINT - 1)))
    except OSError:
        pass
    return False


def test_cli_view_prints_url_and_warns_off_loopback():
    """``python app.py view scene --host 0.0.0.0 --no-browser`` prints the real URL and a warning
    that others on the network can drive it; Ctrl+C stops it with status 0."""
    if _sigint_ignored():
        # a test run started as a shell's background job (`pytest &` without job control) ignores
        # SIGINT, and the viewer inherits that: Ctrl+C's default action cannot be tested (two such
        # local runs saw the viewer's SigIgn 0x1001006, SIGINT and SIGQUIT ignored, and no stop)
        pytest.skip("this test process ignores SIGINT (started in the background): Ctrl+C cannot be tested")
    port = free_port()
    cfg = ROOT / "configs" / "sphere_cap.yaml"
    proc = subprocess.Popen([sys.executable, str(ROOT / "app.py"), "view", str(cfg), "--host", "0.0.0.0",
                             "--port", str(port), "--no-browser"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        line = ""
        t0 = time.time()
        while "clothsim viewer:" not in line and time.time() - t0 < 60:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                break
        assert f"http://127.0.0.1:{port}" in line, line + proc.stderr.read()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}", timeout=10) as r:
            assert r.status == 200
    finally:
        proc.send_signal(signal.SIGINT)
        state = ""
        try:
            out, err = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            # why it did not stop: its signal masks (blocked, ignored, pending) and threads
            try:
                state = "".join(ln for ln in Path(f"/proc/{proc.pid}/status").read_text().splitlines(True)
                                if ln.startswith(("Sig", "Shd", "Threads", "State")))
            except OSError:
                pass
            proc.kill()
            out, err = proc.communicate()
    assert "warning: binding 0.0.0.0" in err
    assert proc.returncode == 0, err + state


def test_downloads_build_valid_files(app):
    """Save scene / export npz, ply, csv: each reaches the asking tab's send_file_download and is a
    valid file of its kind (loaded back with yaml, numpy, trimesh)."""
    import trimesh
    import yaml

    sent = {}

    class FakeClient:
        def send_file_download(self, name, content, save_immediately=False):
            sent[name] = content

    class Event:
        client = FakeClient()

    app.start(wait=True)
    assert app.sim.wait(300) == "converged"
    for kind in ("yaml", "npz", "ply", "csv"):
        app.panels["files"].download(Event(), kind)
    settle(app)
    assert set(sent) == {"small-cap.yaml", "result.npz", "sheet.ply", "history.csv"}, app.errors
    assert scene_from_dict(yaml.safe_load(sent["small-cap.yaml"])).fabric.divisions == (10, 10)
    z = np.load(io.BytesIO(sent["result.npz"]))
    np.testing.assert_allclose(z["positions"].reshape(-1, 3), app.sim.state.positions)
    assert len(trimesh.load(io.BytesIO(sent["sheet.ply"]), file_type="ply").vertices) == 121
    assert sent["history.csv"].decode().startswith("iteration,residual_N")


def test_status_shows_a_gathering_sheet_and_slack_springs():
    """A strip whose free edges are pulled together by nothing but slack weft springs is shown as
    such: after a run the status line reports the slack springs, the undetermined nodes and the
    narrowest weft extent, with a warning when the sheet has gathered below half its width."""
    d = {"name": "slack", "fabric": {"size": [0.1, 0.1], "divisions": [6, 6],
                                     "warp": {"strain": [0, 1], "tension": [0, 250]},
                                     "weft": {"strain": [0, 1], "tension": [0, 250]}},
         "constraints": [{"nodes": "left", "axes": "xyz"},
                         {"nodes": "right", "axes": "xyz", "displacement": [0.01, 0, 0], "stretch": [1.0, 0.3]}],
         "solver": {"method": "paper", "e": 1e-6}}
    a = ViewerApp(scene_from_dict(d), port=free_port())
    try:
        a.wait_idle(20)
        a.start(wait=True)
        assert a.sim.wait(300) in ("converged", "stalled")
        settle(a, 0.5)
        text = a.gui["status"].content
        # named as the field list names them (clothsim.records.Diagnostics)
        m = re.search(r"(\d+) slack springs of (\d+) springs · (\d+) undetermined nodes · "
                      + re.escape(OUTPUT_FIELDS["min_weft_extent_ratio"].label) + r" (\d+)%", text)
        assert m, repr(text)
        assert int(m.group(1)) > 0 and int(m.group(4)) < 50
        assert "the sheet gathers" in text
    finally:
        a.close()


def test_seams_are_drawn_and_close():
    """A scene with a seam shows one orange thread per sewn node pair; after the run the threads
    end at the solver's positions, and they have closed to (almost) nothing."""
    from clothsim.config import load_scene

    scene = load_scene(ROOT / "configs" / "sewn_sleeve.yaml", ["fabric.divisions=[20,4]",
                                                               "constraints.2.nodes={i: 10}"])
    a = ViewerApp(scene, port=free_port())
    try:
        a.wait_idle(20)
        pts0 = np.array(a.renderer.h_seams.points)
        assert pts0.shape == (5, 2, 3)
        assert np.linalg.norm(pts0[:, 0] - pts0[:, 1], axis=1).min() > 0.01  # the seam starts open
        a.start(wait=True)
        assert a.sim.wait(300) == "converged"
        settle(a)
        pos = a.sim.state.positions
        pts = np.array(a.renderer.h_seams.points)
        np.testing.assert_allclose(pts[:, 0], pos[a.renderer.seam_ab[:, 0]], atol=1e-6)
        np.testing.assert_allclose(pts[:, 1], pos[a.renderer.seam_ab[:, 1]], atol=1e-6)
        assert np.linalg.norm(pts[:, 0] - pts[:, 1], axis=1).max() < 1e-5
    finally:
        a.close()


def test_pattern_panel_scene_opens_lists_its_panels_and_converges():
    """A scene of pattern panels (configs/garments/sleeve_two_panel.yaml) opens in the viewer:
    the Fabric tab lists the panels (nodes and outline area) instead of a size, the sheet's faces
    come from the lattice, and a run converges."""
    import clothsim

    root = Path(__file__).resolve().parents[1]
    a = ViewerApp(clothsim.load_scene(root / "configs/garments/sleeve_two_panel.yaml"), port=free_port())
    try:
        a.wait_idle(20)
        table = a.panels["fabric"].gui["panels"].content
        assert "| front | 442 | 100.00 | 25 x 16 |" in table and "| back | 442 |" in table
        assert not a.panels["fabric"].gui["size"].visible
        assert len(a.renderer.glb.faces) == len(a.sim.model.topology.faces)
        a.sim.start()
        assert a.sim.wait(300) == "converged"
    finally:
        a.close()


def test_unequal_seam_threads_and_widest_gap_list():
    """A seam of unequal node counts (configs/garments/eased_seam.yaml: 23 nodes sewn to an edge
    of 21) draws one thread per sewn node, to the point of the other side it is sewn to; after the run
    the threads end at the solver's positions and have closed, and the status lists the seam's
    widest gap and its ease."""
    from clothsim.config import load_scene

    a = ViewerApp(load_scene(ROOT / "configs" / "garments" / "eased_seam.yaml"), port=free_port())
    try:
        a.wait_idle(20)
        pts0 = np.array(a.renderer.h_seams.points)
        assert pts0.shape == (23, 2, 3)
        assert np.linalg.norm(pts0[:, 0] - pts0[:, 1], axis=1).max() > 1e-4  # the eased side starts longer
        a.start(wait=True)
        assert a.sim.wait(300) == "converged"
        settle(a, 0.5)
        pos = a.sim.state.positions
        pts = np.array(a.renderer.h_seams.points)
        m = a.sim.model
        np.testing.assert_allclose(pts[:, 0], pos[m.seam_nodes[:, 0]], atol=1e-6)
        assert np.linalg.norm(pts[:, 0] - pts[:, 1], axis=1).max() < 1e-5
        text = a.gui["status"].content
        found = re.search(r"seam 0: widest gap ([0-9.e+-]+) m \(ease 10\.0 %\)", text)
        assert found, repr(text)
        assert float(found.group(1)) < 1e-5
    finally:
        a.close()


# --------------------------------------------------------------------------- issue 28, items 10, 16
def _scene_zip(weft_csv: str) -> bytes:
    """A scene upload as a zip: scene.yaml naming files/weft.csv, and that table."""
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("scene.yaml", _scene_yaml(weft={"csv": "files/weft.csv"}))
        z.writestr("files/weft.csv", weft_csv)
    return buf.getvalue()


def _scene_yaml(**fabric) -> str:
    import yaml

    d = {**SMALL, "name": "uploaded", "fabric": {**SMALL["fabric"], **fabric}}
    return yaml.safe_dump(d, sort_keys=False)


def test_uploaded_scene_reads_only_its_own_files(app, tmp_path):
    """Issue 28, item 10: a scene uploaded to the viewer naming a weft table elsewhere on the
    server (absolute, or ``../``) used to open, and 'Save scene + files (.zip)' sent that file
    back; an error quoted the server file's first cell and showed the private upload path.
    Now it is refused before any file is read, naming the line and field; no message shows the
    upload folder; a zip's own table opens and is the only file saved with it."""
    import zipfile

    secret = tmp_path / "secret.csv"
    secret.write_text("TOPSECRET,cell\n1,2\n")
    fp = app.panels["files"]
    for ref in (str(secret), "../../" + secret.name, "files/../../x.csv"):
        text = _scene_yaml(weft={"csv": ref})
        app.post(lambda t=text: fp.open_scene("evil.yaml", t.encode()), "files")
        settle(app)
        err = app.errors["files"]
        assert re.search(r"evil\.yaml:\d+: fabric\.weft\.csv: .*not a file of this upload", err), err
        assert "TOPSECRET" not in err and str(app.upload_dir) not in err and "clothsim-uploads" not in err
        assert app.sim.scene.name == "small-cap"
    # a zip with its own table: a bad one is reported by its name in the zip, never the folder
    app.post(lambda: fp.open_scene("bad.zip", _scene_zip("strain,tension\n0,0\nzero,5\n")), "files")
    settle(app)
    err = app.errors["files"]
    assert "fabric.weft.csv" in err and "files/weft.csv" in err and "clothsim-uploads" not in err, err
    assert app.sim.scene.name == "small-cap"
    app.post(lambda: fp.open_scene("good.zip", _scene_zip("strain,tension\n0,0\n1,300\n")), "files")
    settle(app)
    assert app.errors["files"] == "" and app.sim.scene.name == "uploaded", app.errors
    saved = zipfile.ZipFile(io.BytesIO(app.scene_draft.scene_zip()))
    assert sorted(saved.namelist()) == ["files/weft.csv", "scene.yaml"]
    assert saved.read("files/weft.csv").decode().endswith("1,300\n")


def test_bundled_scenes_open_from_an_upload_and_from_the_picker(app):
    """Issue 28, item 16: 'Open scene' with a bundled example naming files beside it used to fail
    ("../../static/bodies/smpl_man.stl: cannot open", no line or field). A bundled scene's bytes
    now open it from configs/ (its files resolved beside it); a missing file names the line and
    field; the Files tab lists every bundled scene but the sweeps and opens one without a
    restart."""
    fp = app.panels["files"]
    calf = ROOT / "configs" / "garments" / "calf_band.yaml"
    app.post(lambda: fp.open_scene("calf_band.yaml", calf.read_bytes()), "files")
    settle(app)
    assert app.errors["files"] == "", app.errors
    assert app.sim.scene.name == "calf-band" and "mesh" in app.sim.model.mold.kind_name
    assert app.sim.scene.source == calf and "calf-band" in app.gui["title"].content
    import yaml

    d = yaml.safe_load(_scene_yaml())
    d["mold"] = {"path": "missing_leg.stl"}
    text = yaml.safe_dump(d, sort_keys=False)
    line = next(n for n, t in enumerate(text.splitlines(), 1) if "missing_leg" in t)
    app.post(lambda: fp.open_scene("mine.yaml", text.encode()), "files")
    settle(app)
    err = app.errors["files"]
    assert f"mine.yaml:{line}: mold.path: " in err and "missing_leg.stl" in err and "cannot open" in err, err
    assert "clothsim-uploads" not in err and app.sim.scene.name == "calf-band"
    options = app.gui["bundled"].options
    assert "garments/calf_band.yaml" in options and "thermoform.yaml" in options
    assert not any(o.startswith("sweeps/") for o in options)
    assert len(options) - 1 == len(list((ROOT / "configs").rglob("*.yaml"))) - len(list((ROOT / "configs" / "sweeps").glob("*.yaml")))
    app.gui["bundled"].value = "torso_band.yaml"
    app.post(lambda: fp.open_bundled(app.gui["bundled"].value), "files")
    settle(app)
    assert app.errors["files"] == "" and app.sim.scene.name == "torso-band", app.errors
    assert "mesh" in app.sim.model.mold.kind_name and app.draft["name"] == "torso-band"


@pytest.mark.slow
def test_frame_the_sheet_frames_the_garment_on_a_body():
    """Issue 28, item 15: on a body, 'Frame the sheet' framed the whole 1.8 m body whenever the
    mold was under 10x the sheet (the stocking: a 1.84 m box for a 0.3 m garment, the camera
    2.5 m away). It now frames the garment's box and the body only within 10 % of the garment's
    size around it, and the camera stands off that box with a margin; the button does it for
    the asking tab."""
    from types import SimpleNamespace

    from clothsim.config import load_scene

    app = ViewerApp(load_scene(ROOT / "configs" / "garments" / "stocking.yaml"), port=free_port())
    try:
        settle(app)
        p = app.pushed_positions
        lo, hi = (np.asarray(x) for x in app.framed_box)
        sheet = np.ptp(p, axis=0)
        body = np.ptp(np.asarray(app.sim.model.mold.bounds), axis=0)
        print(f"sheet {sheet.round(3)} m, body {body.round(3)} m, framed {(hi - lo).round(3)} m")
        assert body.max() > 1.5 and sheet.max() < 0.4
        assert (lo <= p.min(axis=0) + 1e-9).all() and (hi >= p.max(axis=0) - 1e-9).all()
        assert (hi - lo).max() <= sheet.max() * 1.2 + 1e-9
        cam = SimpleNamespace(camera=SimpleNamespace())
        app.post(lambda: app.frame(cam))  # what the button posts for its tab
        settle(app)
        look = np.asarray(cam.camera.look_at)
        dist = float(np.linalg.norm(np.asarray(cam.camera.position) - look))
        half = 0.5 * float(np.linalg.norm(hi - lo))
        print(f"camera {dist:.3f} m from the framed box's centre")
        np.testing.assert_allclose(look, 0.5 * (lo + hi))
        assert 1.6 * half * 1.1 < dist < 0.6, dist  # off the box with a margin, not the body's distance
    finally:
        app.close()


# --------------------------------------------------------------------------- issue 28, item 18
FLAT = {"name": "flat", "fabric": {"size": [0.1, 0.1], "divisions": [6, 6],
                                   "warp": {"strain": [0, 1], "tension": [0, 250]},
                                   "weft": {"strain": [0, 1], "tension": [0, 250]}},
        "constraints": [{"nodes": "left", "axes": "xyz"}, {"nodes": "right", "axes": "xyz"}],
        "solver": {"method": "paper", "e": 1e-6}}


def test_zero_field_legend_and_range_widgets_follow_the_bar(app):
    """Issue 28, item 18: an all-zero pressure field said "uniform (0.5)" on a 0-1 bar (the middle
    of the widened range, not the field); Range min/max kept showing 0/1 while the bar spanned
    0-85. Now: "0 everywhere"; with Auto range on the two widgets show the bar's range (and
    turning Auto range off keeps it)."""
    view = app.gui
    view["field"].value = "contact pressure"
    settle(app)
    assert "contact pressure" in app.panels["view"].legend
    assert "0 everywhere" in app.panels["view"].legend, app.panels["view"].legend  # flat sheet: no contact yet
    app.start(wait=True)
    assert app.sim.wait(300) == "converged"
    settle(app, 0.5)
    lo, hi = app.renderer.range
    print(f"pressure bar {lo:g}..{hi:g} mmHg; legend {app.panels['view'].legend}")
    assert hi > 5 and lo == 0.0
    assert view["range_min"].value == float(f"{lo:.4g}") and view["range_max"].value == float(f"{hi:.4g}")
    view["auto_range"].value = False
    settle(app, 0.5)
    assert app.renderer.range == pytest.approx((lo, hi), rel=1e-3)


def test_invalid_table_keeps_the_typing_and_apply_resumes_a_run(app):
    """Issue 28, item 18: an invalid table edit threw the typing away and showed its error in the
    Material group's line below the uploads; Apply edits during a run left it paused. Now the
    text stays with the error on the table's own line (cleared by a valid edit) and a running
    relaxation goes on with the applied model."""
    before = dict(app.draft["fabric"]["warp"])
    bad = "0, 0\n0.5, 10\n0.3, 20"
    app.gui["warp_text"].value = bad  # as a tab's edit (not quiet): posted to the loop
    settle(app)
    assert app.gui["warp_text"].value == bad
    assert "strictly increasing" in app.errors["warp_table"] and app.errors["material"] == "", app.errors
    assert app.draft["fabric"]["warp"] == before and "material" not in app.pending
    app.gui["warp_text"].value = "0, 0\n1, 300"
    settle(app)
    assert app.errors["warp_table"] == "" and app.draft["fabric"]["warp"]["tension"] == [0, 300]
    big = ViewerApp(scene_from_dict({**SMALL, "fabric": {**SMALL["fabric"], "divisions": [60, 60]},
                                     "solver": {"method": "paper", "C": 2.0, "e": 1e-12}}), port=free_port())
    try:  # a run of minutes
        big.wait_idle(20)
        big.start(wait=True)
        assert wait_for(lambda: big.sim.state.iteration > 20, 30) and big.sim.status == "running"
        big.gui["lift"].value = 0.031  # an edit of the model, as a tab makes it
        settle(big)
        assert "fabric" in big.pending, big.errors
        big.apply(wait=True)
        assert big.errors["run"] == "" and not big.pending
        it = big.sim.state.iteration
        assert wait_for(lambda: big.sim.state.iteration > it + 5, 30), big.sim.status
        assert big.sim.status == "running"
        big.pause(wait=True)
    finally:
        big.close()


def test_probe_table_columns_and_undetermined_advice():
    """Issue 28, item 18: the probe table's five columns (the classes' long names among them)
    crowded the panel: now three (probe, mmHg to 0.1, covered) and the classes on a line below;
    "6 undetermined nodes" gave no advice: the status now says what it means and what to do."""
    from types import SimpleNamespace

    from clothsim.viewer.panels.probes import ProbesPanel

    fake = SimpleNamespace(gui={}, sim=SimpleNamespace(scene=SimpleNamespace(probes=[1, 2])))
    panel = ProbesPanel(fake)
    panel.readings = [
        {"name": "ankle", "pressure_mmhg": 21.3456, "pressure_pa": 2845.8, "contact_fraction": 0.97,
         "classes": {"RAL-GZ 387": "below I", "UK Drug Tariff": "2"}},
        {"name": "calf", "pressure_mmhg": 14.06, "pressure_pa": 1874.5, "contact_fraction": 1.0}]
    text = panel.table()
    rows = [ln for ln in text.splitlines() if ln.startswith("|")]
    assert rows[0] == "| probe | mmHg | covered |" and all(ln.count("|") == 4 for ln in rows), text
    assert "| ankle | 21.3 | 97% |" in rows and "| calf | 14.1 | 100% |" in rows
    assert "Class at *ankle*: RAL-GZ 387 **below I** · UK Drug Tariff **2**" in text
    a = ViewerApp(scene_from_dict(FLAT), port=free_port())
    try:
        a.start(wait=True)
        assert a.sim.wait(120) == "converged"
        settle(a, 0.5)
        text = a.gui["status"].content
        m = re.search(r"(\d+) undetermined nodes", text)
        assert m and int(m.group(1)) > 0, text
        assert "Hold the ends along the axis, add pre-tension" in text and "`shear:`/`bending:`" in text, text
    finally:
        a.close()
