"""``app.py report`` from the result folder alone (issue 31 item 5).

The report used to re-read the scene (scene.yaml with the machine's absolute paths) and
recompile the model: a folder moved or mailed, or whose body file had moved, failed with
``.../limb.stl: cannot open``. The folder now carries what the report draws (the faces, the node
fields, the body near the garment, the scene in short) and its scene.yaml names files without
their paths. Checked here: a report from a moved folder whose body and tables are gone, its numbers
against the result's, the colour scale (its top tick reaches the maximum shown), levels.csv read
tolerantly, and bad input refused naming the file."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest

import clothsim
from clothsim.compression.report_figures import PMAX_PERCENTILE, colour_scale
from clothsim.config import load_scene

from conftest import ROOT, cli_main


@pytest.fixture(scope="module")
def limb_run(tmp_path_factory):
    """The class II sleeve on a faceted cylinder read from an STL file, its tables from CSV files,
    all in a source folder; run into a result folder (the files stay in place)."""
    import trimesh

    src = tmp_path_factory.mktemp("src")
    for name in ("compression_knit_course.csv", "compression_knit_wale.csv"):
        shutil.copy(ROOT / "static" / "materials" / name, src / name)
    trimesh.creation.cylinder(radius=0.035, height=0.3, sections=64).export(src / "limb.stl")
    text = (ROOT / "configs" / "class2_sleeve.yaml").read_text().replace("../static/materials/", "")
    text = re.sub(r"^mold: .*$", "mold: {path: limb.stl, surface: faceted}", text, flags=re.M)
    (src / "scene.yaml").write_text(text)
    out = tmp_path_factory.mktemp("run") / "run"
    clothsim.solve(load_scene(src / "scene.yaml")).save(out)
    return src, out


@pytest.mark.slow
def test_report_from_a_moved_folder_without_its_files(tmp_path, capsys, limb_run):
    """Moved to another folder, with the STL and the CSV tables deleted: the report is written
    from the folder alone (on main: 'limb.stl: cannot open'); no file of the folder names the
    machine's paths, scene.yaml names the files with their SHA-256."""
    src, out = limb_run
    moved = tmp_path / "mailed" / "stocking result"
    shutil.copytree(out, moved)
    gone = tmp_path / "gone"
    shutil.copytree(src, gone)
    for f in src.iterdir():
        f.rename(tmp_path / f"hidden-{f.name}")   # the body file and the tables are no longer there
    try:
        rc, err = cli_main(capsys, "report", str(moved))
    finally:
        for f in gone.iterdir():
            shutil.copy(f, src / f.name)
    assert rc == 0, err
    for name in ("scene.yaml", "summary.json", "probes.csv", "profiles.csv"):
        text = (moved / name).read_text()
        assert str(src) not in text and str(ROOT) not in text, name
    import hashlib

    scene_text = (moved / "scene.yaml").read_text()
    assert "path: limb.stl" in scene_text and "csv: compression_knit_course.csv" in scene_text
    digest = hashlib.sha256((gone / "limb.stl").read_bytes()).hexdigest()
    assert f"mold.path: limb.stl  sha256 {digest}" in scene_text
    page = (moved / "report.html").read_text()
    assert str(src) not in page and "alt=\"pressure map: front, side and top views\"" in page
    d = np.load(moved / "result.npz")
    assert len(d["body_faces"]) > 100     # the body near the garment is in the folder
    bv = d["body_vertices"]
    P = d["positions"].reshape(-1, 3)
    # cropped to the garment's box grown by 3 cm (and the triangles reaching into it): not the whole
    # 30 cm cylinder
    assert (bv.min(0) >= P.min(0) - 0.045).all() and (bv.max(0) <= P.max(0) + 0.045).all()
    assert bv[:, 2].min() < P[:, 2].min() - 0.02 and bv[:, 2].max() > P[:, 2].max() + 0.02
    # the folder's scene.yaml runs again with the same files put beside it
    for f in gone.iterdir():
        if f.name != "scene.yaml":
            shutil.copy(f, moved / f.name)
    again = clothsim.solve(load_scene(moved / "scene.yaml"))
    np.testing.assert_allclose(again.positions.reshape(-1, 3), P, atol=1e-9)


def _report_page(capsys, folder) -> str:
    """`report FOLDER` run in-process (exit status 0 asserted) and the page it wrote."""
    assert cli_main(capsys, "report", str(folder))[0] == 0
    return (folder / "report.html").read_text()


def _cells(page: str, table: str, cls: str) -> list[str]:
    body = page.split(f"<table id='{table}'>", 1)[1].split("</table>", 1)[0]
    return re.findall(rf"<td class='[^']*\b{cls}\b[^']*'>([^<]*)</td>", body)


@pytest.mark.slow
def test_the_reports_numbers_are_the_results(tmp_path, capsys, limb_run):
    _, out = limb_run
    d = tmp_path / "run"
    shutil.copytree(out, d)
    assert cli_main(capsys, "report", str(d))[0] == 0
    page = (d / "report.html").read_text()
    s = json.loads((d / "summary.json").read_text())
    assert _cells(page, "probes", "mmhg") == [f"{p['pressure_mmhg']:.2f}" for p in s["probes"]]
    on = [x for x in s["profiles"][0]["slices"] if x["mean_mmhg"] is not None]
    assert _cells(page, "levels", "mean") == [f"{x['mean_mmhg']:.1f}" for x in on]
    b = min(on, key=lambda x: abs(x["height_m"] - s["probes"][0]["center"][2]))   # B: the classed probe's level
    assert f"<span id='girth-mean-b'>{b['mean_mmhg']:.1f}</span>" in page
    assert f"<span id='peak'>{s['max_contact_pressure_mmhg']:.2f}</span>" in page
    assert f"<span id='class-reading'>{s['classes']['pressure_mmhg']:.1f}</span>" in page
    # the pressure map's scale: its top tick is its maximum and at least the 95th percentile
    p = np.load(d / "result.npz")["contact_pressure"].reshape(-1) / 133.322387415
    c = np.load(d / "result.npz")["in_contact"].reshape(-1)
    m = re.search(r"id='map-pressure' data-lo='([^']*)' data-hi='([^']*)' data-top-tick='([^']*)'", page)
    lo, hi, top = map(float, m.groups())
    assert top == hi >= np.percentile(p[c], PMAX_PERCENTILE) and lo == 0.0 and PMAX_PERCENTILE == 95.0
    # the body girth of the table: the cylinder's 64-gon perimeter (2 * 64 * r * sin(pi / 64))
    girths = re.findall(r"<tr><td>leg [^<]*</td><td class='n'>[^<]*</td><td class='n'>([^<]*)</td>", page)
    assert girths and all(float(g) == pytest.approx(100 * 2 * 64 * 0.035 * np.sin(np.pi / 64), abs=0.05)
                          for g in girths)
    # --pmax: the scale the user chose, stated
    assert cli_main(capsys, "report", str(d), "--pmax", "40")[0] == 0
    page = (d / "report.html").read_text()
    assert "data-lo='0' data-hi='40' data-top-tick='40'" in page and "(chosen with --pmax)" in page
    rc, err = cli_main(capsys, "report", str(d), "--pmax", "-3")
    assert rc == 2 and "--pmax" in err


def test_colour_scale_reaches_the_maximum_shown():
    """The stocking's case: most nodes 10-35 mmHg, one at 85. The default scale tops at the 95th
    percentile rounded up (not the single node), says how many nodes exceed it, and its top tick
    is the scale's maximum (the bar used to end at a 60 tick under an 85 top)."""
    rng = np.random.default_rng(1)
    p = np.r_[rng.uniform(10, 35, 700), 85.0, np.zeros(100)]
    contact = p > 0
    sc = colour_scale(p, contact=contact)
    assert sc["ticks"][0] == sc["lo"] == 0.0 and sc["ticks"][-1] == sc["hi"]
    assert np.percentile(p[contact], 95) <= sc["hi"] <= 40 and sc["above"] >= 1 and sc["peak"] == 85.0
    assert len(sc["ticks"]) >= 4
    for pmax in (85.0, 33.3, 7.0):
        sc = colour_scale(p, pmax, contact=contact)
        assert sc["hi"] == sc["ticks"][-1] == pmax and sc["ticks"][0] == 0.0
        assert np.all(np.diff(sc["ticks"]) > 0.3 * (sc["ticks"][1] - sc["ticks"][0]))
    sc = colour_scale(np.r_[-0.2, 0.1, 0.37], percentile=None)   # a strain field: below zero too
    assert sc["lo"] <= -0.2 and sc["hi"] >= 0.37 and sc["ticks"][-1] == sc["hi"] and sc["ticks"][0] == sc["lo"]


@pytest.mark.slow
def test_levels_csv_read_tolerantly_and_refused_when_not_numbers(tmp_path, capsys, limb_run):
    """levels.csv (the leg's measuring levels) in any column order and unit spelling becomes the
    table; a cell that is not a number is refused with file, line and column; names are escaped."""
    _, out = limb_run
    d = tmp_path / "run"
    shutil.copytree(out, d)
    (d / "levels.csv").write_text(
        "# written by the leg\n"
        "Level,Height [m],Girth_cm,Reduction (%),Mean mmHg,Anterior,Posterior,Medial,Lateral,notes\n"
        "B,0.12,22.8,30,24.5,26,23,20,28,x\n"
        "C,0.35,37.6,28,17.2,,18,15,19,y\n"
        "<b id=inj>D</b>,0.42,35,n/a,14.0,14,14,13,15,z\n")
    page = _report_page(capsys, d)
    assert "<b id=inj>" not in page and "&lt;b id=inj&gt;D&lt;/b&gt;" in page
    assert _cells(page, "levels", "mean") == ["24.5", "17.2", "14.0"]
    row_c = page.split("<td>C</td>", 1)[1].split("</tr>", 1)[0]
    assert re.findall(r"<td class='n'>([^<]*)</td>", row_c)[:8] == ["0.350", "37.6", "28.0", "n/a", "18.0", "15.0",
                                                                      "19.0", "70"]
    assert "RAL-GZ 387: class II" in page.split("<td>B</td>", 1)[1].split("</tr>", 1)[0]   # 24.5 at B
    # the columns the leg's measuring levels write (clothsim.compression.levels.LEVELS_COLUMNS)
    (d / "levels.csv").write_text(
        "level,height_cm,z_m,girth_cm,loop_cm,how,course_strain,reduction_pct,mean_mmHg,anterior_mmHg,"
        "posterior_mmHg,medial_mmHg,lateral_mmHg,percent_of_B,required_percent_of_B,gradient_ok\n"
        "B,12.00,0.12000,22.80,23.10,found,0.3012,23.15,28.100,39.600,25.000,20.100,27.000,100.0,100-100,1\n"
        "C,35.00,0.35000,37.60,38.00,found,0.2500,20.00,14.300,15.000,14.000,13.000,15.500,50.9,50-80,1\n")
    page = _report_page(capsys, d)
    assert _cells(page, "levels", "mean") == ["28.1", "14.3"]
    row_b = page.split("<td>B</td>", 1)[1].split("</tr>", 1)[0]
    assert re.findall(r"<td class='n'>([^<]*)</td>", row_b) == ["0.120", "22.8", "23.1", "39.6", "25.0", "20.1",
                                                                "27.0", "100"]
    assert "RAL-GZ 387: class II" in row_b and "<span id='girth-mean-b'>28.1</span>" in page
    (d / "levels.csv").write_text("level,height,girth,mean,anterior\nB,0.12,0.228,<i>24</i>,25\n")
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'levels.csv'}:2: mean is not a number" in err, err
    (d / "levels.csv").write_text("height,girth\n0.1,0.2\n")
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'levels.csv'}:1: no 'level' column" in err, err


@pytest.mark.slow
def test_an_old_folder_or_a_damaged_scene_summary_refused(tmp_path, capsys, limb_run):
    _, out = limb_run
    d = tmp_path / "old"
    shutil.copytree(out, d)
    with np.load(d / "result.npz") as z:
        arrays = {k: z[k] for k in z.files if k not in ("faces", "scene_summary")}
    np.savez_compressed(d / "result.npz", **arrays)
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'result.npz'}: no faces: written by a clothsim older" in err, err
    with np.load(out / "result.npz") as z:
        arrays = {k: z[k] for k in z.files}
    scene = json.loads(str(arrays["scene_summary"]))
    scene["materials"][0]["strain"][1] = "<script>alert(1)</script>"
    arrays["scene_summary"] = np.array(json.dumps(scene))
    np.savez_compressed(d / "result.npz", **arrays)
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and "scene_summary: materials[0].strain[1]: not a number" in err, err
    arrays["faces"] = arrays["faces"] + 10_000
    arrays["scene_summary"] = np.array(json.dumps({**scene, "materials": []}))
    np.savez_compressed(d / "result.npz", **arrays)
    rc, err = cli_main(capsys, "report", str(d))
    assert rc == 2 and f"{d / 'result.npz'}: faces names a node outside" in err, err
    assert not (d / "report.html").exists()


def test_body_near_the_garment_is_cropped_and_decimated():
    """The body the folder carries: a sphere's triangles within the garment's box grown by the
    margin, merged onto a coarser grid when more than max_faces (vertices stay near the surface)."""
    import trimesh

    from clothsim.reportdata import body_near
    from clothsim.mold import mold_from_arrays

    s = trimesh.creation.icosphere(subdivisions=5, radius=0.1)
    mold = mold_from_arrays(s.vertices, s.faces)
    garment = np.array([[-0.05, -0.12, 0.0], [0.05, 0.12, 0.12]])
    v, f = body_near(mold, garment, margin=0.01)
    assert 1000 < len(f) < len(s.faces) and v.dtype == np.float32 and f.dtype == np.int32
    assert v[:, 0].min() > -0.08 and v[:, 2].min() > -0.03     # the far side of the box is cut away
    v, f = body_near(mold, garment, margin=0.01, max_faces=500)
    assert 50 < len(f) <= 500 and f.max() < len(v)
    assert np.abs(np.linalg.norm(v, axis=1) - 0.1).max() < 0.003
    assert body_near(None, garment)[1].shape == (0, 3)


class _Square:
    """A mold whose display surface is the unit square z = 0 in two triangles (edges of 1 and
    1.41 m: long against the box, so body_near splits them)."""

    def surface_mesh(self, resolution, extent):
        return np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]])


def test_body_near_splits_only_within_max_faces():
    """A split makes four triangles of one: it is made only when the four-fold count stays within
    max_faces (the guard read ``4 len(F) > 4 max_faces``, i.e. len(F) > max_faces, so a split could
    leave up to four times max_faces, merged back onto a grid). At the boundary: 2 triangles with
    max_faces 8 are split once (8, not 32: the next split would pass 8) and kept as split; with
    max_faces 7 they are kept as they are."""
    from clothsim.reportdata import body_near

    garment = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    v, f = body_near(_Square(), garment, margin=0.01, max_faces=8)
    assert len(f) == 8 and len(v) == 9                       # one split: the square's 3 x 3 grid
    assert sorted({(float(x), float(y)) for x, y, _ in v}) == [(x, y) for x in (0, 0.5, 1) for y in (0, 0.5, 1)]
    v, f = body_near(_Square(), garment, margin=0.01, max_faces=7)
    assert len(f) == 2 and len(v) == 4                       # no split: the two triangles as given
    assert sorted({(float(x), float(y)) for x, y, _ in v}) == [(0, 0), (0, 1), (1, 0), (1, 1)]


def test_run_inputs_reads_each_scene_file_once(monkeypatch):
    """run_inputs takes the portable scene once for scene.yaml and the scene in short: each file
    the stocking reads (two CSV tables, the body's STL) is hashed once (it was twice: 6 reads for 3
    files), and both are what each gives alone."""
    from clothsim.compile import run_inputs
    from clothsim.compression import folder

    scene = load_scene(ROOT / "configs" / "garments" / "stocking.yaml")
    hashed = []
    sha256 = folder._sha256
    monkeypatch.setattr(folder, "_sha256", lambda path: (hashed.append(path.name), sha256(path))[1])
    inputs = run_inputs(scene)
    assert sorted(hashed) == ["compression_knit_course.csv", "compression_knit_wale.csv", "smpl_man.stl"]
    monkeypatch.setattr(folder, "_sha256", sha256)
    assert inputs.scene_yaml == folder.portable_scene_yaml(scene)
    assert inputs.scene_brief == folder.scene_brief(scene)


def test_a_level_b_without_a_reading_is_not_taken_for_no_level_b():
    """levels.csv rows: with a B that has no reading (the garment starts above it) the page says
    so and gives no % of B, without calling the body B-less; without any B (an arm) it says there
    is no level B and gives the first level's girth mean; with a B, every level is a % of B."""
    from clothsim.compression.report_html import _headline, _levels, levels_table

    def rows(b_mean, names=("B", "C")):
        return [{"level": n, "height": 0.1 * (k + 1), "girth": 0.3, "reduction": 20.0,
                 "mean": b_mean if k == 0 else 15.0} for k, n in enumerate(names)]

    for given, says, head in [
            (rows(None), "B has no reading here", "girth-mean-b'>no reading"),
            (rows(None, ("cC", "cD")), "This body has no level B", "girth-mean-first'>15.0"),
            (rows(30.0), "every level is given as a percentage of B.", "girth-mean-b'>30.0")]:
        got, from_file = _levels({}, None, given)
        page = levels_table(got, from_file, []) + _headline({}, got, from_file)
        assert says in page and head in page, (given, page)
        assert ("This body has no level B" in page) == (given[0]["level"] != "B")
        assert ("<td class='n'>50</td>" in page) == (given[0]["mean"] == 30.0)   # C: 15 / 30
