"""Solve every example scene and record or compare its equilibrium (positions [m], energy [J]).

    python scripts/equilibria.py record tests/data/equilibria     # after a change meant to move results
    python scripts/equilibria.py record tests/data/equilibria configs/x.yaml   # a new example alone
    python scripts/equilibria.py compare tests/data/equilibria    # did a refactor change any result?

A refactor must leave every equilibrium where it was: within 1e-9 m and 1e-9 relative energy on
analytic and flat scenes, within 2e-5 m on faceted meshes (their many nearby equilibria), and,
on scenes with slack regions (nodes held by nothing, so no unique position), the energy only.
tests/test_equilibria.py runs the comparison in the test suite.

Another machine: numba compiles the kernels for the host CPU (its vector width, fused
multiply-adds), so rounding differs from one CPU to another, and a solve stopped at ||V||_inf <= e
is only determined to about e over the scene's softest stiffness. Measured from the Intel Xeon
that recorded the references to an AMD EPYC: analytic and flat scenes within 1e-12 m, the sewn
sleeves 0.4-3.4e-8 m (e = 1e-7 N; energy within 3e-12), the faceted tube on the leg cone 3.7e-5 m
and the stocking's 12 slack nodes up to 3.3 mm (energy within 6e-8). So where the positions
differ by more than the tolerance, the comparison checks what a change of the model would break
and a change of rounding would not: the recorded positions must still be an equilibrium of the
code (||V||_inf <= e at them, with the nodes on the mold's surface in contact), and the energy of
the new solve must equal the recorded one (1e-9 relative; 1e-6 on faceted meshes).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: scenes whose slack nodes have no unique position: only the energy is compared [J, absolute]
SLACK = {"configs/hard/slack_sheet.yaml"}


def scenes() -> list[str]:
    """The example scenes, as paths relative to the repository."""
    return sorted(str(p.relative_to(ROOT)) for p in (ROOT / "configs").rglob("*.yaml")
                  if "sweeps" not in p.parts)


def reference_name(scene: str) -> str:
    return scene.replace("/", "__").removesuffix(".yaml") + ".npz"


def solve(scene: str):
    """(positions (N, 3) [m], energy [J], faceted mold?) of a scene's equilibrium."""
    import clothsim

    s = clothsim.load_scene(ROOT / scene, ["solver.time_limit_s=120"])
    r = clothsim.solve(s)
    if not r.converged:
        raise RuntimeError(f"{scene}: {r.status}: {r.solve.message}")
    faceted = r.model.mold is not None and r.model.mold.kind_name == "mesh"  # not the smooth surface
    return np.asarray(r.state.positions), float(r.solve.energy), faceted


def compare(scene: str, folder: Path) -> str | None:
    """None when the scene's equilibrium matches its reference, else what differs."""
    ref = np.load(folder / reference_name(scene))
    pos, energy, faceted = solve(scene)
    e0 = float(ref["energy"])
    if scene in SLACK:
        return None if abs(energy - e0) <= 1e-12 else f"{scene}: energy {energy:.6e} J, reference {e0:.6e} J"
    if pos.shape != ref["positions"].shape:
        return f"{scene}: {pos.shape[0]} nodes, reference {ref['positions'].shape[0]}"
    dx = float(np.abs(pos - ref["positions"]).max())
    de = abs(energy - e0) / max(abs(e0), 1e-300)
    tol = 2e-5 if faceted else 1e-9
    etol = 1e-6 if faceted else 1e-9
    if de > etol:
        return f"{scene}: positions differ by {dx:.2e} m (tolerance {tol:g}), energy by {de:.2e} relative"
    if dx > tol:
        v, e = reference_residual(scene, ref["positions"])
        if not (v <= e):
            return (f"{scene}: positions differ by {dx:.2e} m (tolerance {tol:g}) and the recorded "
                    f"positions are no equilibrium of the code: ||V||_inf = {v:.2e} N > e = {e:.1e} N")
    return None


def reference_residual(scene: str, positions: np.ndarray) -> tuple[float, float]:
    """(||V||_inf [N] of the code at the recorded positions (N, 3) [m], the scene's e [N]). The
    nodes within 1e-9 m of the mold's surface count as in contact (a converged solve leaves its
    contact nodes on the surface, its free nodes off it or touching it without force). A staged
    scene is judged by its last stage's model (its friction, gravity, mold and rest scale); with
    friction the residual is the full one, friction included (``clothsim.solvers.friction.coulomb_residual``:
    each contact node's tangential force up to mu times its normal force is the mold's, as at any
    frictional equilibrium; the frictionless residual would count it as out of balance)."""
    import clothsim
    from clothsim.compile import compile_scene
    from clothsim.config import stage_scenes
    from clothsim.solvers.friction import coulomb_residual
    from clothsim.mold import mold_query
    from clothsim.solvers.control import scale_rest

    s = clothsim.load_scene(ROOT / scene)
    final, scale = s, (1.0, 1.0)
    for st, sc in stage_scenes(s):
        final, scale = sc, st.scale(scale)
    model, state = compile_scene(final)
    model = scale_rest(model, scale)
    state.positions[:] = positions
    state.in_contact[:] = False
    if model.mold is not None:
        margs, q = model.mold.kernel_args(), np.empty(8)
        state.in_contact[:] = [mold_query(margs, p, q) <= 1e-9 for p in state.positions]
    return coulomb_residual(model, state), float(final.solver.e)


def main(argv: list[str]) -> int:
    if len(argv) < 2 or argv[0] not in ("record", "compare"):
        print(__doc__)
        return 2
    folder = Path(argv[1])
    folder.mkdir(parents=True, exist_ok=True)
    chosen = scenes()
    if len(argv) > 2:  # the named scenes alone (e.g. a new example), as paths relative to the repository
        unknown = [a for a in argv[2:] if a not in chosen]
        if unknown:
            print(f"not an example scene: {', '.join(unknown)} (expected paths like configs/sphere_cap.yaml)")
            return 2
        chosen = argv[2:]
    bad = 0
    for scene in chosen:
        if argv[0] == "record":
            pos, energy, _ = solve(scene)
            np.savez_compressed(folder / reference_name(scene), positions=pos, energy=energy)
            print(f"recorded {scene}")
        else:
            msg = compare(scene, folder)
            bad += msg is not None
            print(msg or f"same     {scene}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
