"""The core types of clothsim.model: every field says its shape, dtype or unit in a ``#:`` line,
and the spring families are named (the stored int8 codes unchanged)."""

import ast
import dataclasses
from pathlib import Path

import numpy as np

import clothsim.model as cm
from clothsim import scene_from_dict
from clothsim.compile import compile_model
from clothsim.model import SpringFamily
from clothsim.simulation import _tiny_scene

RECORDS = ("Placement", "Placements", "PanelBuild", "SeamInfo", "Model", "State")


def test_every_field_has_a_doc_line():
    src = Path(cm.__file__).read_text()
    lines = src.splitlines()
    tree = ast.parse(src)
    classes = {n.name: n for n in tree.body if isinstance(n, ast.ClassDef)}
    missing = []
    for name in RECORDS:
        fields = [n for n in classes[name].body if isinstance(n, ast.AnnAssign)]
        # the ast sees exactly the dataclass's fields
        assert [f.target.id for f in fields] == [f.name for f in dataclasses.fields(getattr(cm, name))]
        for f in fields:
            above = lines[f.lineno - 2].strip()
            if not above.startswith("#:"):
                missing.append(f"{name}.{f.target.id}")
    assert not missing, missing


def test_family_codes_are_the_stored_ones():
    assert [(f.name, int(f)) for f in SpringFamily] == [
        ("WARP", 0), ("WEFT", 1), ("SHEAR", 2), ("BEND_WARP", 3), ("BEND_WEFT", 4), ("SEAM", 5)]


def _scene(**extra):
    d = {"fabric": {"size": [0.1, 0.08], "divisions": [4, 4],
                    "warp": {"strain": [0.0, 0.5], "tension": [0.0, 100.0]},
                    "weft": {"strain": [0.0, 0.5], "tension": [0.0, 80.0]}},
         "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.05}]}
    d.update(extra)
    return scene_from_dict(d)


def test_families_by_name():
    """Warp first, then weft, then shear and bending; the warm-up's tiny scene keeps the model's
    optional families (simulation._tiny_scene asks the model by family name)."""
    plain = compile_model(_scene())
    assert plain.families() == {SpringFamily.WARP, SpringFamily.WEFT}
    tiny = _tiny_scene(plain)
    assert tiny.shear is None and tiny.bending is None

    m = compile_model(_scene(shear={"stiffness": 2.0}, bending={"stiffness": 1.0}))
    assert m.families() == {SpringFamily.WARP, SpringFamily.WEFT, SpringFamily.SHEAR,
                            SpringFamily.BEND_WARP, SpringFamily.BEND_WEFT}
    fam = m.spring_family
    assert fam.dtype == np.int8
    assert np.all(fam[:m.warp_count] == SpringFamily.WARP)
    assert np.all(fam[m.warp_count:m.warp_count + m.weft_count] == SpringFamily.WEFT)
    assert np.all(np.diff(fam) >= 0)  # stored family by family
    tiny = _tiny_scene(m)
    assert tiny.shear is not None and tiny.bending is not None
    assert compile_model(tiny).families() == m.families()
