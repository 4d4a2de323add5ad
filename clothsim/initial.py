"""The initial deformation (paper 3.1): a state that keeps the sheet off the mold.

Constrained nodes start at their prescribed positions (stretch/displacement applied); the other
nodes at the flat sheet, then ``lift`` (a smooth dome), ``wrap`` (the sheet rolled on a cylinder),
``file`` (an earlier result) and ``perturb`` act on the free coordinates only.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import SceneError
from .grid import Model, State


def initial_state(model: Model, initial, file: Path | None = None) -> State:
    """Build the starting State from the scene's ``initial`` record (lift, interpolate, perturb,
    seed, auto_clearance, wrap) and ``file``, the resolved path of ``initial.file`` (or None).
    Refuses a start that touches or penetrates the mold unless ``initial.auto_clearance`` asks to
    lift it clear."""
    ini = initial
    fixed = model.fixed_axes
    topo = model.topology
    flat = model.rest_positions.copy()
    if ini.interpolate and file is None:
        flat[:, :2] += _spread_in_plane(model)
    if ini.lift:
        # the dome lifts along the sheet's normal (+z flat; outward when wrapped)
        dome = np.empty(model.node_count)
        for p in range(topo.panel_count):
            nx1, ny1 = topo.panel_shape(p)
            sel = topo.node_panel == p
            ii, jj = topo.node_ij[sel, 0], topo.node_ij[sel, 1]
            dome[sel] = np.sin(np.pi * ii / max(nx1 - 1, 1)) * np.sin(np.pi * jj / max(ny1 - 1, 1))
        flat[:, 2] += ini.lift * dome
    pos = model.placement.apply(flat)
    if file is not None:
        path = file
        want = topo.to_grid(np.zeros((model.node_count, 3))).shape if topo.is_grid else (model.node_count, 3)
        p = _read_positions(Path(path), want)
        if p.shape != want:
            raise SceneError(f"{path}: initial.file: positions have shape {p.shape}, the scene needs "
                             f"{want}")
        if not np.isfinite(p).all():
            raise SceneError(f"{path}: initial.file: positions are not all finite")
        pos = p.reshape(-1, 3).copy()
    if ini.perturb:
        rng = np.random.default_rng(ini.seed)
        pos += rng.uniform(-ini.perturb, ini.perturb, pos.shape)
    # a constrained node starts at its prescribed position (its free axes moved along with it,
    # unless the start comes from a file); the constrained coordinates are exact
    held = fixed.any(axis=1)
    if file is None:
        base = model.placement.apply(model.rest_positions)
        pos[held] += model.prescribed_positions[held] - base[held]
    pos[fixed] = model.prescribed_positions[fixed]
    state = State(np.ascontiguousarray(pos), np.zeros(model.node_count, bool), 0)
    if model.mold is not None:
        _check_clearance(ini, model, state)
    return state


def _read_positions(path, shape: tuple) -> np.ndarray:
    """The ``positions`` array [m] of an earlier result.npz; SceneError ``file: initial.file: why``
    for anything else (not a regular file, not an npz, a truncated or oversized member, a
    non-real dtype)."""
    import zipfile
    import zlib

    from .fileio import check_input_file, excerpt

    where = f"{path}: initial.file"
    try:
        # a regular file, not a link out of its folder (np.load opens it by name)
        try:
            check_input_file(path, SceneError, limit=2**40, what="positions file")
        except SceneError as exc:
            raise SceneError(str(exc).replace(f"{path}: ", f"{where}: ", 1)) from None
        with np.load(os.path.realpath(path), allow_pickle=False) as data:
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
        raise SceneError(f"{where}: cannot read ({type(exc).__name__}: {excerpt(exc, 120, quote=False)})") from None
    if p.dtype.kind not in "fiu":
        raise SceneError(f"{where}: positions must be real numbers (got dtype {p.dtype})")
    return np.asarray(p, float)


def _spread_in_plane(model: Model) -> np.ndarray:
    """In-plane displacement (N,2) [m] of every node in the sheet's own coordinates: the
    constrained nodes' stretch (and, on a flat sheet, their in-plane displacement) held, the rest
    harmonic (discrete Laplace on the grid), so a strip pulled at one end starts uniformly
    stretched and a wrapped band pulled round starts evenly pulled. Zero when nothing moves."""
    held = model.fixed_axes.any(axis=1)
    rest = model.rest_positions
    target = model.prescribed_positions if model.placement.identity else model.prescribed_flat
    u_held = (target[:, :2] - rest[:, :2])[held]
    if not held.any() or not np.any(np.abs(u_held) > 0) or held.all():
        return np.zeros((model.node_count, 2))
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    pairs = np.concatenate([model.topology.warp, model.topology.weft])
    a, b = pairs[:, 0], pairs[:, 1]
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


def _check_clearance(ini, model: Model, state: State) -> None:
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
    size = max(model.placement.size)
    if not ini.auto_clearance or fixed_bad.any():
        what = "touch or penetrate"
        extra = ("; some of them are constrained nodes, which auto_clearance cannot move"
                 if ini.auto_clearance else
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
