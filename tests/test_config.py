"""Scene files: validation messages name the file, the line and the field; overrides; presets."""

import textwrap

import pytest

from clothsim.config import SceneError, load_scene, scene_from_dict

from conftest import scene_dict

GOOD = textwrap.dedent("""\
    name: t
    fabric:
      size: [0.10, 0.02]
      divisions: [20, 4]
      thickness: 0.0005
      warp: {strain: [0, 0.1, 0.3], stress: [0, 5.0e4, 2.0e5]}
      weft: {strain: [0, 0.1], tension: [0, 12]}
    constraints:
      - {nodes: left, axes: xyz}
    solver: {method: paper, C: 2.0, e: 1.0e-6}
    """)


def _err(tmp_path, text, overrides=None):
    p = tmp_path / "x.yaml"
    p.write_text(text)
    with pytest.raises(SceneError) as exc:
        load_scene(p, overrides)
    return str(exc.value).replace(str(p), "x.yaml")


def test_good_scene_loads(tmp_path):
    p = tmp_path / "x.yaml"
    p.write_text(GOOD)
    s = load_scene(p)
    assert s.fabric.divisions == (20, 4)
    warp, weft = s.tables()
    # stress [Pa] x thickness -> tension [N/m]
    assert warp.tension[2] == pytest.approx(2.0e5 * 0.0005)
    assert weft.tension[1] == 12


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("warp: {strain: [0, 0.1, 0.3]", "warp: {strain: [0, 0.3, 0.3]",
         "x.yaml:6: fabric.warp.strain: must be strictly increasing (0.3 after 0.3)"),
        ("warp: {strain: [0, 0.1, 0.3]", "warp: {strain: [0.1, 0.2, 0.3]",
         "x.yaml:6: fabric.warp.strain: must start at 0 (got 0.1)"),
        ("stress: [0, 5.0e4, 2.0e5]", "stress: [0, 5.0e4, .nan]",
         "x.yaml:6: fabric.warp.stress: must be finite (got nan)"),
        ("stress: [0, 5.0e4, 2.0e5]", "stress: [0, -5.0e4, 2.0e5]",
         "x.yaml:6: fabric.warp.stress: must be non-negative (got -50000.0)"),
        ("stress: [0, 5.0e4, 2.0e5]", "stress: [0, 5.0e4, 1.0e4]",
         "x.yaml:6: fabric.warp.stress: must be non-decreasing (10000.0 after 50000.0)"),
        ("stress: [0, 5.0e4, 2.0e5]", "stress: [0, 5.0e4]",
         "x.yaml:6: fabric.warp: strain and stress have different lengths (3 and 2)"),
        ("weft: {strain: [0, 0.1], tension: [0, 12]}", "weft: {strain: [0], tension: [0]}",
         "x.yaml:7: fabric.weft: needs at least 2 points (got 1)"),
        ("weft: {strain: [0, 0.1], tension: [0, 12]}", "weft: {strain: [0, 0.1], tension: [0, 12], stress: [0, 1]}",
         "x.yaml:7: fabric.weft: give exactly one of stress, tension, csv or preset (got stress, tension)"),
        ("weft: {strain: [0, 0.1], tension: [0, 12]}", "weft: {preset: nope}",
         "x.yaml:7: fabric.weft.preset: unknown 'nope' (known: compression_knit_est, elastic_woven_est, isotropic_paper, powernet_est, swimwear_knit_est)"),
        ("  thickness: 0.0005\n", "",
         "x.yaml:2: fabric.thickness: needed because warp is given as stress [Pa]"),
        ("divisions: [20, 4]", "divisions: [0, 4]", "x.yaml:4: fabric.divisions: must be at least 1 (got 0)"),
        ("size: [0.10, 0.02]", "size: [0.10, -0.02]", "x.yaml:3: fabric.size: must be positive and finite (got -0.02)"),
        ("{nodes: left, axes: xyz}", "{nodes: lefty, axes: xyz}",
         "x.yaml:9: constraints.0.nodes: unknown node set 'lefty' (known: perimeter, left, right, bottom, top, "
         "bottom_left, bottom_right, top_left, top_right, corners, all, outline; or give {i: [a, b], j: [c, d]})"),
        ("{nodes: left, axes: xyz}", "{nodes: left, axes: xw}",
         "x.yaml:9: constraints.0.axes: must be a non-empty subset of 'xyz' (got 'xw')"),
        ("{nodes: left, axes: xyz}", "{nodes: left, axes: xyz, stretch: 0}",
         "x.yaml:9: constraints.0.stretch: must be positive (got 0.0)"),
        ("C: 2.0", "C: 1.0", "x.yaml:10: solver.C: must be greater than 1 (got 1.0)"),
        ("e: 1.0e-6", "e: 0", "x.yaml:10: solver.e: must be positive (got 0.0)"),
        ("method: paper", "method: magic",
         "x.yaml:10: solver.method: Input should be 'auto', 'paper' or 'newton'"),
        ("name: t", "name: t\ncolour: red", "x.yaml:2: colour: unknown field"),
    ],
)
def test_validation_messages_name_file_line_and_field(tmp_path, old, new, message):
    """Each rule rejects a bad scene with the exact message file:line: field: what."""
    assert old in GOOD
    msg = _err(tmp_path, GOOD.replace(old, new))
    if "solver.method" in message:
        assert msg.startswith(message)
    else:
        assert msg == message


def test_yaml_syntax_error_names_line(tmp_path):
    msg = _err(tmp_path, GOOD.replace("divisions: [20, 4]", "divisions: [20, 4"))
    assert msg.startswith("x.yaml:") and "not valid YAML" in msg


def test_set_overrides(tmp_path):
    """--set field.path=value parses YAML values and reaches nested fields and list items."""
    p = tmp_path / "x.yaml"
    p.write_text(GOOD)
    s = load_scene(p, ["solver.C=3", "fabric.divisions=[80, 80]", "constraints.0.axes=xz"])
    assert s.solver.C == 3 and s.fabric.divisions == (80, 80) and s.constraints[0].axes == "xz"
    with pytest.raises(SceneError, match=r"--set constraints.5.axes: index 5 out of range \(list has 1 items\)"):
        load_scene(p, ["constraints.5.axes=x"])
    # a bad value given by --set is blamed on the --set argument, not a line of the file (issue 15.23)
    msg = _err(tmp_path, GOOD, ["solver.C=0.5"])
    assert msg == "--set solver.C=0.5: solver.C: must be greater than 1 (got 0.5)"


def test_relative_paths_resolve_against_scene_folder(tmp_path):
    """A CSV table named relative to the scene file is read from the scene's folder."""
    (tmp_path / "tables").mkdir()
    (tmp_path / "tables" / "w.csv").write_text("strain,tension\n0,0\n0.5,100\n")
    p = tmp_path / "x.yaml"
    p.write_text(GOOD.replace("weft: {strain: [0, 0.1], tension: [0, 12]}", "weft: {csv: tables/w.csv}"))
    s = load_scene(p)
    assert s.tables()[1].tension[1] == 100
    assert str(tmp_path) in s.resolved().fabric.weft.csv


def test_every_bundled_config_validates(root):
    """All example scenes load (their molds are checked by the mold/contact tests)."""
    files = sorted((root / "configs").glob("*.yaml"))
    assert len(files) >= 6
    for f in files:
        load_scene(f)


MOLD_GOOD = GOOD + "mold: {path: m.stl, scale: 0.001}\n"


@pytest.mark.parametrize(
    "overrides, text, message",
    [
        (["mold.scale=abc"], MOLD_GOOD,
         "--set mold.scale=abc: mold.scale: must be a positive number or three positive numbers (got 'abc')"),
        (["mold.scale={a: 1}"], MOLD_GOOD,
         "--set mold.scale={a: 1}: mold.scale: must be a positive number or three positive numbers (got {'a': 1})"),
        (["mold.scale=[1, 2]"], MOLD_GOOD,
         "--set mold.scale=[1, 2]: mold.scale: must be a positive number or three positive numbers (got [1, 2])"),
        (["mold.path=5"], MOLD_GOOD, "--set mold.path=5: mold.path: Input should be a valid string"),
        (["mold.closed=maybe"], MOLD_GOOD, "--set mold.closed=maybe: mold.closed: Input should be a valid boolean"),
        (None, MOLD_GOOD.replace("scale: 0.001}", "closed: 1}"), "x.yaml:11: mold.closed: Input should be a valid boolean"),
        (None, MOLD_GOOD.replace("scale: 0.001}", "rotate: [0, 90]}"), "x.yaml:11: mold.rotate.2: missing"),
        (None, MOLD_GOOD.replace("scale: 0.001}", "colour: red}"), "x.yaml:11: mold.colour: unknown field"),
        (None, GOOD + "mold: {sphere: {center: [0, 0, 0], radius: -1}}\n",
         "x.yaml:11: mold.sphere.radius: must be positive and finite (got -1.0)"),
        (None, GOOD + "mold:\n  cylinder: {center: [0, 0, 0], axis: [0, 0, 0], radius: 1, length: 1}\n",
         "x.yaml:12: mold.cylinder.axis: must be a non-zero finite vector (got [0.0, 0.0, 0.0])"),
        (None, GOOD + "mold: {box: {min: [0, 0, 0], max: [1, 0, 1]}}\n",
         "x.yaml:11: mold.box.max: must exceed min on every axis (got min [0.0, 0.0, 0.0], max [1.0, 0.0, 1.0])"),
        (None, GOOD + "mold: {sphere: {center: [0, 0, 0], radius: 1}, path: m.stl}\n",
         "x.yaml:11: mold: must be a mapping with exactly one of 'path' (a mesh file), sphere, cylinder, plane, box, leg"),
        (None, GOOD + "mold: {sphere: {center: [0, 0, 0], radius: 1}, box: {min: [0, 0, 0], max: [1, 1, 1]}}\n",
         "x.yaml:11: mold: must be a mapping with exactly one of 'path' (a mesh file), sphere, cylinder, plane, box, leg"),
        (None, GOOD + "mold: {sphere: {center: [1.0e+7, 0, 0], radius: 1}}\n",
         "x.yaml:11: mold.sphere.center: |x| must be at most 1e+06 m (got 1e+07)"),
        (None, GOOD + "mold: {sphere: {center: [0, 0, 0], radius: 1.0e+300}}\n",
         "x.yaml:11: mold.sphere.radius: at most 1e+06 m (got 1e+300)"),
        (["mold.translate=[1e7, 0, 0]"], MOLD_GOOD,
         "--set mold.translate=[1e7, 0, 0]: mold.translate: |x| must be at most 1e+06 m (got 1e+07)"),
        (None, GOOD + "mold: {scale: 2}\n",
         "x.yaml:11: mold: must be a mapping with exactly one of 'path' (a mesh file), sphere, cylinder, plane, box, leg"),
        (None, GOOD + "mold: m.stl\n",
         "x.yaml:11: mold: must be a mapping with exactly one of 'path' (a mesh file), sphere, cylinder, plane, box, leg"),
    ],
)
def test_mold_spec_typed_with_file_line(tmp_path, overrides, text, message):
    """The mold spec is a typed union (mesh file or one primitive): every bad key or value is
    reported like any other scene field, file:line: mold.field: what, or blamed on the --set
    argument that gave it (issue 15: --set mold.scale=abc, mold.path=5 and a non-bool
    mold.closed gave tracebacks or passed)."""
    assert _err(tmp_path, text, overrides) == message


def test_mold_spec_round_trip(tmp_path):
    """A typed mold spec dumps back to the keys it was given (no defaults added), and
    resolved() makes its path absolute."""
    p = tmp_path / "x.yaml"
    p.write_text(MOLD_GOOD)
    s = load_scene(p)
    assert s.mold.path == "m.stl" and s.mold.scale == 0.001 and s.mold.closed is None
    assert s.to_dict()["mold"] == {"path": "m.stl", "scale": 0.001}
    assert s.resolved().mold.path == str(tmp_path / "m.stl")
    p.write_text(GOOD + "mold: {cylinder: {center: [0, 0, 0], axis: [0, 0, 1], radius: 0.05, length: 0.3}}\n")
    d = load_scene(p).to_dict()["mold"]
    assert d == {"cylinder": {"center": [0, 0, 0], "axis": [0, 0, 1], "radius": 0.05, "length": 0.3}}


def test_a_union_reports_the_branch_the_input_is_not_every_branch(tmp_path):
    """A bad value inside one branch of a union is reported once, from that branch: a seam side
    {side: lft} was also reported as "Input should be 'perimeter', ..." for the side itself,
    and a sweep's {linspace: [1, 3, -2]} also as "Input should be a valid list" (a hostile pass)."""
    from clothsim import sweep as sw

    with pytest.raises(SceneError) as exc:
        scene_from_dict(scene_dict(seams=[{"a": "left", "b": {"side": "lft"}}]))
    lines = str(exc.value).splitlines()
    assert len(lines) == 1 and lines[0].startswith("<scene>: seams.0.b.side: Input should be 'perimeter'"), lines
    f = tmp_path / "s.yaml"
    f.write_text("base: x.yaml\nsweep: {parameters: {solver.C: {linspace: [1.5, 3, -2]}}}\noutputs: [iterations]\n")
    with pytest.raises(sw.SweepError) as exc:
        sw.load_sweep(f)
    assert str(exc.value) == f"{f}:2: sweep.parameters.solver.C.linspace: n must be at least 1 (got -2)"
    f.write_text("base: x.yaml\nsweep: {parameters: {solver.C: {linspace: [1.5, 3, 100000000]}}}\noutputs: [iterations]\n")
    with pytest.raises(sw.SweepError, match=r"linspace: n must be at most 100,000 \(got 100,000,000\)"):
        sw.load_sweep(f)
    f.write_text("base: x.yaml\nsweep: {parameters: {solver.C: {linspace: [1.5, 3, 1000]}, "
                 "solver.e: {logspace: [1.0e-8, 1.0e-4, 1000]}}}\noutputs: [iterations]\n")
    with pytest.raises(sw.SweepError, match=r"sweep\.parameters: 1,000,000 runs \(grid of solver\.C: 1,000, "
                                            r"solver\.e: 1,000\); a sweep runs at most 100,000"):
        sw.load_sweep(f)


def test_a_mistyped_key_with_brackets_keeps_its_name_and_line(tmp_path):
    """A key typed as ``size[0]`` is a field of the file, not one of pydantic's branch tags
    (``list[any]``): its error names it at its own line (a reviewer found it dropped)."""
    d = scene_dict()
    d["fabric"]["size[0]"] = 3
    with pytest.raises(SceneError, match=r"fabric\.size\[0\]: unknown field"):
        scene_from_dict(d)
