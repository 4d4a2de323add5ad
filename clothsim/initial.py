"""The initial deformation (paper 3.1): a state that keeps the sheet off the mold.

Constrained nodes start at their prescribed positions (stretch/displacement applied); the other
nodes at the flat sheet, then ``lift`` (a smooth dome), ``wrap`` (the sheet rolled on a cylinder),
``file`` (an earlier result) and ``perturb`` act on the free coordinates only.
"""

from __future__ import annotations

import numpy as np

from .config import Scene, SceneError
from .grid import Model, State, place_sheet


def initial_state(scene: Scene, model: Model) -> State:
    """Build the starting State; refuses a start that touches or penetrates the mold unless
    ``initial.auto_clearance`` asks to lift it clear."""
    ini = scene.initial
    fixed = model.fixed_axes
    nx1, ny1 = model.grid_shape
    flat = model.rest_positions.copy()
    if ini.interpolate and ini.file is None:
        flat[:, :2] += _spread_in_plane(scene, model)
    if ini.lift:
        # the dome lifts along the sheet's normal (+z flat; outward when wrapped)
        ii, jj = np.meshgrid(np.arange(nx1), np.arange(ny1), indexing="ij")
        dome = np.sin(np.pi * ii / max(nx1 - 1, 1)) * np.sin(np.pi * jj / max(ny1 - 1, 1))
        flat[:, 2] += ini.lift * dome.ravel()
    pos = place_sheet(scene, flat)
    if ini.file is not None:
        path = scene.resolve(ini.file)
        p = _read_positions(path, (nx1, ny1, 3))
        if p.shape != (nx1, ny1, 3):
            raise SceneError(f"{path}: initial.file: positions have shape {p.shape}, the scene needs "
                             f"{(nx1, ny1, 3)}")
        if not np.isfinite(p).all():
            raise SceneError(f"{path}: initial.file: positions are not all finite")
        pos = p.reshape(-1, 3).copy()
    if ini.perturb:
        rng = np.random.default_rng(ini.seed)
        pos += rng.uniform(-ini.perturb, ini.perturb, pos.shape)
    # a constrained node starts at its prescribed position (its free axes moved along with it,
    # unless the start comes from a file); the constrained coordinates are exact
    held = fixed.any(axis=1)
    if ini.file is None:
        base = place_sheet(scene, model.rest_positions)
        pos[held] += model.prescribed_positions[held] - base[held]
    pos[fixed] = model.prescribed_positions[fixed]
    state = State(np.ascontiguousarray(pos), np.zeros(model.node_count, bool), 0)
    if model.mold is not None:
        _check_clearance(scene, model, state)
    return state


def _read_positions(path, shape: tuple) -> np.ndarray:
    """The ``positions`` array [m] of an earlier result.npz; SceneError ``file: initial.file: why``
    for anything else (not a regular file, not an npz, a truncated or oversized member, a
    non-real dtype)."""
    import stat
    import zipfile
    import zlib

    where = f"{path}: initial.file"
    try:
        if not stat.S_ISREG(path.stat().st_mode):
            raise SceneError(f"{where}: not a regular file")
        with np.load(path, allow_pickle=False) as data:
            if not hasattr(data, "files"):
                raise SceneError(f"{where}: not an .npz archive (an earlier run's result.npz)")
            if "positions" not in data.files:
                raise SceneError(f"{where}: no 'positions' array")
            info = data.zip.getinfo("positions.npy")
            if info.file_size > 8 * int(np.prod(shape)) + 4096:  # refuse before inflating
                raise SceneError(f"{where}: 'positions' is larger than the scene's {shape}")
            p = data["positions"]
    except SceneError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        raise SceneError(f"{where}: cannot read ({type(exc).__name__}: {str(exc)[:120]})") from None
    if p.dtype.kind not in "fiu":
        raise SceneError(f"{where}: positions must be real numbers (got dtype {p.dtype})")
    return np.asarray(p, float)


def _spread_in_plane(scene: Scene, model: Model) -> np.ndarray:
    """In-plane displacement (N,2) [m] of every node in the sheet's own coordinates: the
    constrained nodes' stretch (and, on a flat sheet, their in-plane displacement) held, the rest
    harmonic (discrete Laplace on the grid), so a strip pulled at one end starts uniformly
    stretched and a wrapped band pulled round starts evenly pulled. Zero when nothing moves."""
    held = model.fixed_axes.any(axis=1)
    rest = model.rest_positions
    target = model.prescribed_positions if scene.initial.wrap is None else model.prescribed_flat
    u_held = (target[:, :2] - rest[:, :2])[held]
    if not held.any() or not np.any(np.abs(u_held) > 0) or held.all():
        return np.zeros((model.node_count, 2))
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    nx1, ny1 = model.grid_shape
    idx = np.arange(model.node_count).reshape(nx1, ny1)
    a = np.concatenate([idx[:-1, :].ravel(), idx[:, :-1].ravel()])
    b = np.concatenate([idx[1:, :].ravel(), idx[:, 1:].ravel()])
    n = model.node_count
    W = sp.coo_matrix((np.ones(2 * a.size), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n)).tocsr()
    L = sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W
    free = ~held
    Lff = L[free][:, free].tocsc()
    Lfh = L[free][:, held]
    u = np.zeros((n, 2))
    u[held] = u_held
    solve = spla.factorized(Lff)
    for c in range(2):
        u[free, c] = solve(-(Lfh @ u_held[:, c]))
    return u


def _check_clearance(scene: Scene, model: Model, state: State) -> None:
    from .mold import mold_query_many

    margs = model.mold.kernel_args()
    n = model.node_count
    sd = np.empty(n)
    cp = np.empty((n, 3))
    nrm = np.empty((n, 3))
    feat = np.empty((n, 2), np.int64)
    mold_query_many(margs, state.positions, sd, cp, nrm, feat)
    bad = sd <= 0.0
    if not bad.any():
        return
    fixed_bad = bad & model.fixed_axes.any(axis=1)
    size = max(scene.fabric.size)
    if not scene.initial.auto_clearance or fixed_bad.any():
        what = "touch or penetrate"
        extra = ("; some of them are constrained nodes, which auto_clearance cannot move"
                 if scene.initial.auto_clearance else
                 "; raise initial.lift, move the mold or set initial.auto_clearance: true")
        raise SceneError(
            f"initial: {int(bad.sum())} nodes {what} the mold at the start (deepest {-sd.min() * 1e3:.3g} mm)"
            + extra)
    # lift the offending nodes just clear: to the surface plus a small margin along its normal
    margin = 1e-3 * size
    k = np.nonzero(bad)[0]
    state.positions[k] = cp[k] + margin * nrm[k]
    mold_query_many(margs, state.positions, sd, cp, nrm, feat)
    if (sd <= 0).any():
        raise SceneError(f"initial: auto_clearance could not lift {int((sd <= 0).sum())} nodes clear of the mold")
