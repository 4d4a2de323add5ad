"""Solve every example scene and record or compare its equilibrium (positions [m], energy [J]).

    python scripts/equilibria.py record tests/data/equilibria     # after a change meant to move results
    python scripts/equilibria.py compare tests/data/equilibria    # did a refactor change any result?

A refactor must leave every equilibrium where it was: within 1e-9 m and 1e-9 relative energy on
analytic and flat scenes, within 2e-5 m on faceted meshes (their many nearby equilibria), and,
on scenes with slack regions (nodes held by nothing, so no unique position), the energy only.
tests/test_equilibria.py runs the comparison in the test suite.
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
    faceted = s.mold is not None and getattr(s.mold, "path", None) is not None
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
    if dx > tol or (not faceted and de > 1e-9):
        return f"{scene}: positions differ by {dx:.2e} m (tolerance {tol:g}), energy by {de:.2e} relative"
    return None


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("record", "compare"):
        print(__doc__)
        return 2
    folder = Path(argv[1])
    folder.mkdir(parents=True, exist_ok=True)
    bad = 0
    for scene in scenes():
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
