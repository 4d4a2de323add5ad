"""Honest degenerate answers (issue 12 item 5): contact nodes that carry force but have no area
(the sheet gathered into a rope) have no pressure. The summary reports null with the reason and
the line load along the rope [N/m], never 0.0.

Known answer: a band whose weft lines are each collapsed to one point, lying as a polygonal ring
on a cylinder of radius r, every warp spring at the same strain. The total hoop tension is
T = t x (the band's width) [N] (t the table's tension [N/m]); each station (one collapsed weft
line) takes 2 T sin(a/2) (a the angle between stations; half that at the ends, as the normal part
of one spring) over its share of the rope, r sin(a/2) per neighbour: the line load is T / r
exactly, at every station.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from clothsim.compile import compile_model, run_inputs
from clothsim.config import scene_from_dict
from clothsim.grid import State
from clothsim.results import MMHG, Result, strict_json

R = 0.05        # cylinder radius [m]
K = 200.0       # table slope [N/m per unit strain]


def _ring(nx=20, ny=4, arc=math.pi, width=0.05):
    d = {
        "name": "ring",
        "fabric": {"size": [0.10, width], "divisions": [nx, ny],
                   "warp": {"strain": [0, 1], "tension": [0, K]},
                   "weft": {"strain": [0, 1], "tension": [0, K]}},
        "mold": {"cylinder": {"center": [0, 0, 0], "axis": [0, 0, 1], "radius": R, "length": 0.3}},
        "initial": {"lift": 0.0},
        "solver": {"method": "newton"},
    }
    scene = scene_from_dict(d)
    from clothsim.mold import mold_primitive

    mold = mold_primitive("cylinder", {"center": [0, 0, 0], "axis": [0, 0, 1], "radius": R, "length": 0.3})
    model = compile_model(scene, mold=mold)
    ij = model.topology.node_ij
    theta = ij[:, 0] * (arc / nx)
    pos = np.stack([R * np.cos(theta), R * np.sin(theta), np.zeros(len(theta))], 1)
    state = State(np.ascontiguousarray(pos), np.ones(model.node_count, bool), 0)
    chord = 2 * R * math.sin(arc / nx / 2)
    strain = chord / (0.10 / nx) - 1
    assert strain > 0
    hoop = K * strain * width            # total hoop tension [N]
    return scene, model, state, hoop


class _Solve:  # what Result.summary reads of a solve record
    converged, status, message, iterations = True, "converged", "", 0
    residual = relative_residual = best_residual = energy = wall_time_s = 0.0
    contact_count = 0
    method = "newton"
    friction = None


def test_gathered_ring_has_no_pressure_and_reports_its_line_load():
    scene, model, state, hoop = _ring()
    res = Result(scene, model, state, _Solve(), inputs=run_inputs(scene))
    cf = res.contact_force.ravel()
    assert (cf > 0).all()                              # every node carries force ...
    assert np.isinf(res.contact_pressure).all()        # ... on no area
    s = res.summary()
    assert s["max_contact_pressure_pa"] is None and s["max_contact_pressure_mmhg"] is None
    assert "gathered into a rope" in s["contact_pressure_note"]
    assert s["gathered_contact_nodes"] == model.node_count
    assert s["gathered_contact_force_n"] == pytest.approx(cf.sum(), rel=1e-12)
    assert s["contact_line_load_n_per_m"] == pytest.approx(hoop / R, rel=1e-9)
    assert s["contact_line_load_mean_n_per_m"] == pytest.approx(hoop / R, rel=1e-9)
    text = strict_json(s)                              # null in JSON, not 0
    assert json.loads(text)["max_contact_pressure_mmhg"] is None


def test_rope_along_either_direction():
    """The rope found along weft when the warp lines are the collapsed ones (the sheet turned)."""
    scene, model, state, hoop = _ring()
    # collapse the other way: every warp line (same j) to one point, the stations round along j
    ij = model.topology.node_ij
    ny = int(ij[:, 1].max())
    theta = ij[:, 1] * (math.pi / ny)
    state.positions[:] = np.stack([R * np.cos(theta), R * np.sin(theta), np.zeros(len(theta))], 1)
    from clothsim.results import gathered_line_load

    force = np.ones(model.node_count)
    out = gathered_line_load(model, state.positions, force, np.ones(model.node_count, bool))
    chord = 2 * R * math.sin(math.pi / ny / 2)
    assert out["rope_length_m"] == pytest.approx(ny * chord, rel=1e-12)
    # interior stations: nx + 1 nodes of force 1 over one chord
    assert out["max_line_load_n_per_m"] == pytest.approx((ij[:, 0].max() + 1) / chord * 2, rel=1e-12)


def test_a_partly_gathered_sheet_keeps_the_peak_of_its_defined_nodes():
    scene, model, state, hoop = _ring()
    # open the band's weft at the first half of the stations: those nodes get area back
    ij = model.topology.node_ij
    nx = int(ij[:, 0].max())
    half = ij[:, 0] < nx // 2
    state.positions[half, 2] = ij[half, 1] * 0.05 / 4
    res = Result(scene, model, state, _Solve(), inputs=run_inputs(scene))
    p = res.contact_pressure.ravel()
    s = res.summary()
    finite = p[np.isfinite(p) & (res.contact_force.ravel() > 0)]
    assert finite.size and np.isinf(p).any()
    assert s["max_contact_pressure_pa"] == pytest.approx(finite.max())
    assert s["max_contact_pressure_mmhg"] == pytest.approx(finite.max() / MMHG)
    assert "contact_pressure_note" not in s and s["contact_line_load_n_per_m"] > 0


def test_no_contact_is_a_true_zero():
    scene, model, state, hoop = _ring()
    state.positions[:, 0] *= 2.0     # off the cylinder
    state.in_contact[:] = False
    s = Result(scene, model, state, _Solve(), inputs=run_inputs(scene)).summary()
    assert s["max_contact_pressure_pa"] == 0.0 and "contact_pressure_note" not in s
    assert "contact_line_load_n_per_m" not in s
