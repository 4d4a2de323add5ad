"""The initial deformation (paper 3.1): a state that keeps the sheet off the mold.

Constrained nodes start at their prescribed positions (stretch/displacement applied); the other
nodes at the flat sheet, then ``lift`` (a smooth dome), ``wrap`` (the sheet rolled on a cylinder),
``file`` (an earlier result) and ``perturb`` act on the free coordinates only.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .errors import SceneError
from .fileio import check_input_file, excerpt
from .model import Model, SpringFamily, State
from .mold import mold_query_many


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
        dome = _joined_dome(model)
        if dome is None:
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
        _check_clearance(ini, model, state, from_file=file is not None)
    return state


def _read_positions(path, shape: tuple) -> np.ndarray:
    """The ``positions`` array [m] of an earlier result.npz; SceneError ``file: initial.file: why``
    for anything else (not a regular file, not an npz, a truncated or oversized member, a
    non-real dtype)."""
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
    constrained nodes' stretch (and their in-plane displacement, on a flat sheet or a rigidly
    placed panel) held, the rest harmonic (discrete Laplace on the lattice), so a strip pulled at
    one end starts uniformly stretched and a wrapped band pulled round starts evenly pulled. The
    two sides of a seam that already meet where the panels are placed (``_closed_seam_rows``)
    move together (a stiff coupling of weight ``SEAM_SPREAD_WEIGHT``), so panels sewn edge to
    edge spread as the one sheet they make. Zero when nothing moves."""
    held = model.fixed_axes.any(axis=1)
    rest = model.rest_positions
    target = model.prescribed_positions if model.placement.identity else _held_flat_target(model)
    u_held = (target[:, :2] - rest[:, :2])[held]
    if not held.any() or not np.any(np.abs(u_held) > 0) or held.all():
        return np.zeros((model.node_count, 2))
    import scipy.sparse.linalg as spla

    n = model.node_count
    L, _ = _lattice_laplacian(model)
    B = _closed_seam_rows(model)
    if B is not None:
        L = (L + SEAM_SPREAD_WEIGHT * (B.T @ B)).tocsr()
    free = ~held
    Lff = L[free][:, free].tocsc()
    Lfh = L[free][:, held]
    u = np.zeros((n, 2))
    u[held] = u_held
    solve = spla.factorized(Lff)
    for c in range(2):
        u[free, c] = solve(-(Lfh @ u_held[:, c]))
    return u


#: weight of a closed seam's coupling in the start's spread, relative to a lattice link's 1: the
#: two sides move together to about 1 / SEAM_SPREAD_WEIGHT of the displacement across one link
SEAM_SPREAD_WEIGHT = 1e6


def _lattice_laplacian(model: Model):
    """(L (N, N) scipy CSR, deg (N,)): the graph Laplacian of the warp and weft links (each of
    weight 1) and each node's number of links."""
    import scipy.sparse as sp

    pairs = np.concatenate([model.topology.warp, model.topology.weft])
    a, b = pairs[:, 0], pairs[:, 1]
    n = model.node_count
    W = sp.coo_matrix((np.ones(2 * a.size), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n)).tocsr()
    deg = np.asarray(W.sum(axis=1)).ravel()
    return (sp.diags(deg) - W).tocsr(), deg


def _held_flat_target(model: Model) -> np.ndarray:
    """(N,3) [m]: the constrained nodes' targets in their panels' own (flat) coordinates: the
    stretch (``Model.prescribed_flat``), plus on a rigidly placed panel the displacement in space
    turned back into the panel's plane (a wrapped or hull-laid panel: the stretch only)."""
    flat = np.array(model.prescribed_flat, float)
    pl = model.placement
    parts = getattr(pl, "parts", None) or ((0, model.node_count, pl),)
    for a, b, p in parts:
        if p.wrap is not None or p.hull is not None:
            continue
        shift = model.prescribed_positions[a:b] - p.apply(flat[a:b])
        R = np.eye(3) if p.rotation is None else np.asarray(p.rotation, float)
        flat[a:b] += shift @ R  # R^T shift, row-wise
    return flat


def _joined_dome(model: Model):
    """(N,) the ``lift`` dome's shape over panels sewn edge to edge where they are placed (a
    seam closed in the placement, ``_closed_seam_rows``): the discrete Poisson bubble -L z = 1
    on the lattice with the closed seams' sides moving together, zero on the joined sheet's
    outline (nodes with fewer than four warp/weft neighbours that are not sewn there), scaled to
    a largest value of 1; so the sewn panels start as one dome, as the one-panel sheet does,
    instead of a dome each with their seams left on the mold. None for a single panel or
    without closed seams (each panel then gets its own sine dome)."""
    import scipy.sparse.linalg as spla

    if model.topology.panel_count < 2:
        return None
    B = _closed_seam_rows(model)
    if B is None:
        return None
    n = model.node_count
    L, deg = _lattice_laplacian(model)
    sewn = np.asarray(abs(B).sum(axis=0)).ravel() > 0
    edge = (deg < 4) & ~sewn
    if edge.all() or not edge.any():
        return None
    L = (L + SEAM_SPREAD_WEIGHT * (B.T @ B)).tocsr()
    inner = ~edge
    z = np.zeros(n)
    z[inner] = spla.spsolve(L[inner][:, inner].tocsc(), np.ones(int(inner.sum())))
    top = z.max()
    return z / top if top > 0 else None


def _closed_seam_rows(model: Model):
    """B (Q, N) scipy CSR: one row per seam spring or seam element whose two sides meet where the
    panels are placed (their placed rest positions within 1e-9 of the sheet's size, and the
    placement turning both sides' planes alike): the gap's coefficients (1 and -1 for a seam
    spring, ``Model.seam_weight`` for a seam element). None when there is none. A seam that is
    open in the placement (a flat sheet whose edges are sewn round a limb) is left out: its
    sides are far apart in the panel's plane."""
    import scipy.sparse as sp

    n = model.node_count
    sel = model.spring_family == SpringFamily.SEAM
    if not sel.any() and not model.seam_count:
        return None
    rest = model.rest_positions
    size = float(np.ptp(rest, axis=0).max()) or 1.0
    place = model.placement.apply
    step = 1e-3 * size
    moved = [place(rest)] + [place(rest + d) for d in (np.array([step, 0.0, 0.0]), np.array([0.0, step, 0.0]))]

    def meet(q, w):
        """(Q,) bool: the combination sum_k w[:, k] x[q[:, k]] vanishes for the placed rest
        positions and for their in-plane derivatives."""
        ok = np.ones(q.shape[0], bool)
        for t, pts in enumerate(moved):
            g = (w[:, :, None] * (pts[q] if t == 0 else pts[q] - moved[0][q])).sum(axis=1)
            ok &= np.linalg.norm(g, axis=1) <= (1e-9 * size if t == 0 else 1e-6 * step)
        return ok

    rows = []
    sn = model.spring_nodes[sel]
    if sn.size:
        w = np.tile([1.0, -1.0], (sn.shape[0], 1))
        ok = meet(sn, w)
        rows.append((sn[ok], w[ok]))
    if model.seam_count:
        q, w = model.seam_nodes, model.seam_weight
        ok = meet(q, w)
        rows.append((q[ok], w[ok]))
    rows = [(q, w) for q, w in rows if q.shape[0]]
    if not rows:
        return None
    mats = []
    for q, w in rows:
        r = np.repeat(np.arange(q.shape[0]), q.shape[1])
        mats.append(sp.csr_matrix((w.ravel(), (r, q.ravel())), shape=(q.shape[0], n)))
    return sp.vstack(mats).tocsr()


#: a start read from a file (an earlier result) may have nodes on the mold's surface: those
#: within this many metres per metre of the sheet's size of it, on either side, start in contact
FILE_CONTACT_TOL = 1e-9


def _check_clearance(ini, model: Model, state: State, from_file: bool = False) -> None:
    """Refuse (SceneError) or, with ``initial.auto_clearance``, lift a start that touches or
    penetrates the mold. from_file: the start is an earlier result's positions, whose contact
    nodes lie on the surface: nodes within FILE_CONTACT_TOL x the sheet's size of it start in
    contact (state.in_contact) instead of being refused."""
    margs = model.mold.kernel_args()
    n = model.node_count
    sd = np.empty(n)
    cp = np.empty((n, 3))
    nrm = np.empty((n, 3))
    feat = np.empty((n, 2), np.int64)
    mold_query_many(margs, state.positions, sd, cp, nrm, feat)
    size = max(model.placement.size)
    bad = sd <= 0.0
    if from_file:
        on = np.abs(sd) <= FILE_CONTACT_TOL * size
        state.in_contact[:] = on
        bad &= ~on
    if not bad.any():
        return
    fixed_bad = bad & model.fixed_axes.any(axis=1)
    if not ini.auto_clearance or fixed_bad.any():
        what = "touch or penetrate"
        extra = ("; some of them are constrained nodes, which auto_clearance cannot move"
                 if ini.auto_clearance else
                 "; raise initial.lift, move the mold or set initial.auto_clearance: true")
        raise SceneError(
            f"initial: {int(bad.sum())} nodes {what} the mold at the start (deepest {max(-sd[bad].min(), 0.0) * 1e3:.3g} mm)"
            + extra)
    # lift the offending nodes just clear: to the surface plus a small margin along its normal
    margin = 1e-3 * size
    k = np.nonzero(bad)[0]
    state.positions[k] = cp[k] + margin * nrm[k]
    mold_query_many(margs, state.positions, sd, cp, nrm, feat)
    if (sd <= 0).any():
        raise SceneError(f"initial: auto_clearance could not lift {int((sd <= 0).sum())} nodes clear of the mold")
