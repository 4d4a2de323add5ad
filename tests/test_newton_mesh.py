"""Newton on triangle-mesh molds: edges, vertices, grooves (clothsim.solvers.newton)."""

import numpy as np

import clothsim
from clothsim.contact import max_penetration

from conftest import ROOT


def test_torso_band_held_converges_tightly():
    """The band held on the 27k-triangle torso converges to 1e-6 N (it used to stall near 5e-3 N:
    nodes at grooves' edges stepping into the face beside their active one)."""
    scene = clothsim.load_scene(ROOT / "configs" / "torso_band_held.yaml",
                                ["solver.method=newton", "solver.time_limit_s=60"])
    res = clothsim.solve(scene)
    assert res.solve.converged, res.solve.message
    assert res.solve.residual <= 1e-6
    assert max_penetration(res.state.positions, res.model.mold.kernel_args()) <= 1e-9


def test_node_pulled_over_a_box_edge_leaves_it():
    """A contact node on a convex box edge pulled outward and down slides off into free space;
    newton reaches the same equilibrium (energy) as the paper's relaxation."""
    import trimesh
    from clothsim.grid import State, build_model
    from clothsim.mold import mold_from_arrays
    from clothsim.solvers import solve as run_solver

    box = trimesh.creation.box(extents=[0.04, 0.04, 0.04])
    box.apply_translation([0.05, 0.05, -0.01])
    mold = mold_from_arrays(box.vertices, box.faces)
    energies = {}
    for method in ("newton", "paper"):
        scene = clothsim.scene_from_dict({
            "name": "box", "fabric": {"size": [0.1, 0.1], "divisions": [10, 10],
                                      "warp": {"strain": [0, 1], "tension": [0, 250]},
                                      "weft": {"strain": [0, 1], "tension": [0, 250]}},
            "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.1}],
            "solver": {"method": method, "e": 1e-8}})
        model = build_model(scene, mold)
        pos = model.rest_positions.copy()
        pos[model.fixed_axes] = model.prescribed_positions[model.fixed_axes]
        pos[:, 2] = np.where(model.fixed_axes[:, 2], pos[:, 2], 0.03)
        k = 3 * 11 + 5
        pos[k] = [0.03, 0.05, 0.01]  # exactly on the top face's edge x = 0.03
        contact = np.zeros(model.node_count, bool)
        contact[k] = True
        state = State(pos, contact, 0)
        res = run_solver(model, state, scene.solver, None)
        assert res.converged, res.message
        assert max_penetration(state.positions, mold.kernel_args()) <= 1e-9
        energies[method] = res.energy
    assert abs(energies["newton"] - energies["paper"]) <= 1e-9 * abs(energies["paper"])
