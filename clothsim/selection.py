"""Node selection and seam pairing: pure functions of a selector and a :class:`Topology`.

A selector is a name (``left``, ``right``, ``bottom``, ``top``, ``perimeter``, ``corners``,
``bottom_left``, ``bottom_right``, ``top_left``, ``top_right``, ``all``) or an object with ``i``
and ``j`` (an index, an inclusive ``[a, b]`` range with negatives counting from the end, or None
for the whole range), read on a panel's (i, j) grid. These functions read plain attributes only:
they import nothing from the scene layer, so the scene's validators can call them.
"""

from __future__ import annotations

import numpy as np

from .topology import Topology

SIDE_NAMES = ("left", "right", "bottom", "top", "perimeter", "corners", "bottom_left", "bottom_right",
              "top_left", "top_right", "all")


class SelectionError(ValueError):
    """A selector that selects nothing valid; the message starts with the field it names."""


def select_grid(sel, shape: tuple[int, int], what: str = "constraints") -> np.ndarray:
    """Boolean mask (nx+1, ny+1) of a selector on a grid of ``shape`` = (nx+1, ny+1); ``what``
    names the field in error messages."""
    nx, ny = shape[0] - 1, shape[1] - 1
    m = np.zeros(shape, bool)
    if isinstance(sel, str):
        if sel in ("left", "perimeter"):
            m[0, :] = True
        if sel in ("right", "perimeter"):
            m[nx, :] = True
        if sel in ("bottom", "perimeter"):
            m[:, 0] = True
        if sel in ("top", "perimeter"):
            m[:, ny] = True
        if sel in ("bottom_left", "corners"):
            m[0, 0] = True
        if sel in ("bottom_right", "corners"):
            m[nx, 0] = True
        if sel in ("top_left", "corners"):
            m[0, ny] = True
        if sel in ("top_right", "corners"):
            m[nx, ny] = True
        if sel == "all":
            m[:] = True
        return m

    def rng(r, n, name):
        if r is None:
            return 0, n
        a, b = (r, r) if isinstance(r, int) else r
        a = a + n + 1 if a < 0 else a
        b = b + n + 1 if b < 0 else b
        if not (0 <= a <= b <= n):
            raise SelectionError(f"{what}: {name} range {list(r) if not isinstance(r, int) else r} outside 0..{n}")
        return a, b

    ia, ib = rng(sel.i, nx, "i")
    ja, jb = rng(sel.j, ny, "j")
    m[ia:ib + 1, ja:jb + 1] = True
    return m


def select_nodes(sel, topology: Topology, panel: int = 0, what: str = "constraints") -> np.ndarray:
    """(N,) bool: the lattice nodes a selector picks on one panel."""
    m = select_grid(sel, topology.panel_shape(panel), what)
    idx = topology.index[panel][m]
    out = np.zeros(topology.node_count, bool)
    out[idx[idx >= 0]] = True
    return out


def seam_line(sel, topology: Topology, name: str, panel: int = 0) -> tuple[np.ndarray, int]:
    """Node numbers of one seam side in index order, and the lattice direction it runs along
    (0: i varies, 1: j varies; 1 for a single node)."""
    m = select_grid(sel, topology.panel_shape(panel), name)
    ii, jj = np.nonzero(m)
    nodes = topology.index[panel][ii, jj]
    keep = nodes >= 0
    ii, jj, nodes = ii[keep], jj[keep], nodes[keep]
    if ii.size == 0:
        raise SelectionError(f"{name}: selects no nodes")
    if ii.size > 1 and not ((ii == ii[0]).all() or (jj == jj[0]).all()):
        raise SelectionError(f"{name}: must select one line of nodes (a single i or a single j); it selects "
                             f"{ii.size} nodes over i {ii.min()}..{ii.max()}, j {jj.min()}..{jj.max()}")
    direction = 0 if ii.size > 1 and (jj == jj[0]).all() else 1
    return nodes.astype(np.int64), direction


def seam_pairs(seam, topology: Topology):
    """The node pairs a seam (``a``, ``b``, ``reverse``) sews: (a (P,), b (P,), share (P,),
    (direction of a, direction of b)), where the share of a pair is its part of the seam in
    lattice spacings along each side (1 inside, 1/2 at the ends). Pairs of a node with itself
    (the tip of a dart) are dropped. Raises SelectionError naming the side ("a: ..." or "b: ...")."""
    a, da = seam_line(seam.a, topology, "a")
    b, db = seam_line(seam.b, topology, "b")
    if a.size != b.size:
        raise SelectionError(f"b: selects {b.size} nodes but a selects {a.size}; a seam sews them one to one")
    if seam.reverse:
        b = b[::-1]
    share = np.ones(a.size)
    if a.size > 1:
        share[0] = share[-1] = 0.5
    keep = a != b
    if not keep.any():
        raise SelectionError("b: selects the same nodes as a (nothing to sew)")
    return a[keep], b[keep], share[keep], (da, db)
