"""Grid sequencing on a cut lattice: every coarse level starts (and ends) with its held nodes at
their prescribed positions, including the nodes held only on the coarse grid (free fine nodes
beside the held outline)."""

import time

import numpy as np

from clothsim.bench import Case, _load
from clothsim.solvers.newton import sequencing as S


def test_coarse_levels_hold_their_nodes_at_the_prescribed_positions(monkeypatch):
    case = Case("ci", "configs/garments/circle_cap.yaml", ["panels.0.divisions=[64,64]"], ("newton",))
    model, state, _ = _load(case, "newton", 1e-7, 60.0)
    seen = []
    orig = S._solve_level

    def spy(level, st, e, max_iter, deadline, *rest):
        m = level.model
        held = m.fixed_axes
        seen.append((m.node_count, float(np.abs(st.positions[held] - m.prescribed_positions[held]).max())))
        return orig(level, st, e, max_iter, deadline, *rest)

    monkeypatch.setattr(S, "_solve_level", spy)
    trial = S.grid_sequence(model, state, 1e-7, 1e-3, time.perf_counter() + 60)
    assert trial is not None and len(seen) >= 1
    assert all(err < 1e-12 for _, err in seen), seen
    held = model.fixed_axes
    assert np.abs(trial.positions[held] - state.positions[held]).max() < 1e-12
