"""Node selection and seam pairing: pure functions of a selector and a :class:`Topology`.

A selector is a name (``left``, ``right``, ``bottom``, ``top``, ``perimeter``, ``corners``,
``bottom_left``, ``bottom_right``, ``top_left``, ``top_right``, ``all``, ``outline``: the nodes on
a panel's cut outline, the perimeter of a rectangle) or an object with ``i``
and ``j`` (an index, an inclusive ``[a, b]`` range with negatives counting from the end, a share
of the way across ``"50%"``, or None for the whole range), read on a panel's (i, j) grid. These functions read plain attributes only:
they import nothing from the scene layer, so the scene's validators can call them.
"""

from __future__ import annotations

import math

import numpy as np

from .topology import Topology

SIDE_NAMES = ("left", "right", "bottom", "top", "perimeter", "corners", "bottom_left", "bottom_right",
              "top_left", "top_right", "all", "outline")


class SelectionError(ValueError):
    """A selector that selects nothing valid; the message starts with the field it names."""


def lattice_index(x, n: int) -> int:
    """The node index an index field names on an axis with nodes 0..n: an int as given (negative:
    from the end, -1 = n), a share ``"p%"`` the node nearest p % of the way from 0 to n (a half
    rounds up: "50%" of 15 divisions is 8)."""
    if isinstance(x, str):
        return int(math.floor(float(x.rstrip("%")) * n / 100.0 + 0.5))
    return x + n + 1 if x < 0 else x


def index_range(r, n: int, name: str, what: str = "constraints") -> tuple[int, int]:
    """(first, last) node index of a selector's inclusive range r (None: all; an int or a share
    "p%": one; see :func:`lattice_index`) on an axis with nodes 0..n; SelectionError ``what: name
    range [a, b] outside 0..n`` when it does not fit."""
    if r is None:
        return 0, n
    one = isinstance(r, (int, str))
    a, b = (r, r) if one else r
    a, b = lattice_index(a, n), lattice_index(b, n)
    if not (0 <= a <= b <= n):
        given = r if one else list(r)
        raise SelectionError(f"{what}: {name} range {given} outside 0..{n}")
    return a, b


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

    ia, ib = index_range(sel.i, nx, "i", what)
    ja, jb = index_range(sel.j, ny, "j", what)
    m[ia:ib + 1, ja:jb + 1] = True
    return m


def _panels_of(sel, topology: Topology) -> list[int]:
    name = getattr(sel, "panel", None)
    if name is None:
        return list(range(topology.panel_count))
    try:
        return [topology.panel_index(name)]
    except ValueError as exc:
        raise SelectionError(f"panel: {exc}") from None


def _grid_selector(sel):
    """The part of a selector read on a panel's (i, j) grid: a name, or an object with i and j."""
    if isinstance(sel, str):
        return sel
    side = getattr(sel, "side", None)
    return side if side is not None else sel


def edge_nodes(topology: Topology, panel: int, edge, what: str = "edge") -> np.ndarray:
    """The lattice nodes along a panel's outline from vertex edge[0] to vertex edge[1]
    (counter-clockwise), ordered along it: the panel's boundary nodes whose closest outline point
    lies on that chain of edges (distances in lattice units; a corner node belongs to both edges
    that meet there)."""
    import shapely

    outline = topology.outlines[panel] if panel < len(topology.outlines) else None
    if outline is None:
        raise SelectionError(f"{what}: panel '{topology.names[panel]}' has no outline to follow")
    k = len(outline)
    v0, v1 = edge
    if not (-k <= v0 < k and -k <= v1 < k):
        raise SelectionError(f"{what}: vertex index outside 0..{k - 1} (the outline has {k} vertices)")
    v0, v1 = v0 % k, v1 % k
    if v0 == v1:
        raise SelectionError(f"{what}: the two vertices must differ")
    chain_idx = [(v0 + t) % k for t in range(((v1 - v0) % k) + 1)]
    chain = shapely.LineString(outline[chain_idx])
    ring = shapely.LinearRing(outline)
    nodes = topology.panel_nodes(panel)
    nodes = nodes[topology.boundary[nodes]]
    pts = shapely.points(topology.node_ij[nodes].astype(float))
    d_chain = shapely.distance(chain, pts)
    d_all = shapely.distance(ring, pts)
    keep = (d_chain <= d_all + 1e-9) & (d_chain <= 1.0)
    nodes, pts = nodes[keep], pts[keep]
    if nodes.size == 0:
        raise SelectionError(f"{what}: no lattice node lies along outline vertices {v0}..{v1}")
    order = np.argsort(shapely.line_locate_point(chain, pts), kind="stable")
    return nodes[order].astype(np.int64)


def select_nodes(sel, topology: Topology, panel: int | None = None, what: str = "constraints") -> np.ndarray:
    """(N,) bool: the lattice nodes a selector picks (on ``panel``, on the panel the selector
    names, or on every panel)."""
    out = np.zeros(topology.node_count, bool)
    panels = [panel] if panel is not None else _panels_of(sel, topology)
    if not isinstance(sel, str) and getattr(sel, "edge", None) is not None:
        for p in panels:
            out[edge_nodes(topology, p, sel.edge, what)] = True
        return out
    g = _grid_selector(sel)
    for p in panels:
        if g == "outline":
            out |= topology.boundary & (topology.node_panel == p)
            continue
        m = select_grid(g, topology.panel_shape(p), what)
        idx = topology.index[p][m]
        out[idx[idx >= 0]] = True
    return out


def seam_line(sel, topology: Topology, name: str):
    """Node numbers of one seam side in order, and how it runs: (panel, 0) along i, (panel, 1)
    along j (also for a single node), or the node array itself for a side along an outline edge.
    A side must lie on one panel."""
    panels = _panels_of(sel, topology)
    if len(panels) > 1:
        raise SelectionError(f"{name}: name the panel (the scene has {len(panels)}: {', '.join(topology.names)})")
    p = panels[0]
    if not isinstance(sel, str) and getattr(sel, "edge", None) is not None:
        nodes = edge_nodes(topology, p, sel.edge, name)
        return nodes, nodes
    if _grid_selector(sel) == "outline":
        raise SelectionError(f"{name}: a seam side must be one line of nodes or an outline edge, not the whole outline")
    m = select_grid(_grid_selector(sel), topology.panel_shape(p), name)
    ii, jj = np.nonzero(m)
    nodes = topology.index[p][ii, jj]
    keep = nodes >= 0
    ii, jj, nodes = ii[keep], jj[keep], nodes[keep]
    if ii.size == 0:
        raise SelectionError(f"{name}: selects no nodes")
    if ii.size > 1 and not ((ii == ii[0]).all() or (jj == jj[0]).all()):
        raise SelectionError(f"{name}: must select one line of nodes (a single i or a single j); it selects "
                             f"{ii.size} nodes over i {ii.min()}..{ii.max()}, j {jj.min()}..{jj.max()}")
    direction = 0 if ii.size > 1 and (jj == jj[0]).all() else 1
    return nodes.astype(np.int64), (p, direction)


def seam_sides(seam, topology: Topology):
    """The two sides of a seam (``a``, ``b``, ``reverse``) in sewing order: (a (Na,), b (Nb,),
    (how a runs, how b runs)) (see :func:`seam_line`), b reversed when ``reverse``. The counts
    may differ (then the seam is sewn along arc length, :func:`arc_elements`). Raises
    SelectionError naming the side ("a: ..." or "b: ...")."""
    a, da = seam_line(seam.a, topology, "a")
    b, db = seam_line(seam.b, topology, "b")
    if seam.reverse:
        b = b[::-1]
        if not isinstance(db, tuple):
            db = b
    if a.size != b.size and min(a.size, b.size) < 2:
        short, long_ = ("a", "b") if a.size < b.size else ("b", "a")
        raise SelectionError(f"{short}: selects one node but {long_} selects {max(a.size, b.size)}; "
                             "a seam of unequal node counts needs at least two nodes on each side")
    if np.array_equal(np.sort(a), np.sort(b)):
        raise SelectionError("b: selects the same nodes as a (nothing to sew)")
    return a, b, (da, db)


def seam_pairs(seam, topology: Topology):
    """The node pairs a seam (``a``, ``b``, ``reverse``) of equal node counts sews: (a (P,),
    b (P,), share (P,), (how a runs, how b runs)) (see :func:`seam_line`), where the share of a
    pair is its part of the seam in node spacings along each side (1 inside, 1/2 at the ends).
    Pairs of a node with itself (the tip of a dart) are dropped. Raises SelectionError naming
    the side ("a: ..." or "b: ..."), also when the counts differ (see :func:`arc_elements`)."""
    a, b, (da, db) = seam_sides(seam, topology)
    if a.size != b.size:
        raise SelectionError(f"b: selects {b.size} nodes but a selects {a.size}; sew them along arc length "
                             "(clothsim.selection.arc_elements)")
    share = np.ones(a.size)
    if a.size > 1:
        share[0] = share[-1] = 0.5
    keep = a != b
    if not keep.any():
        raise SelectionError("b: selects the same nodes as a (nothing to sew)")
    return a[keep], b[keep], share[keep], (da, db)


def _arc_fractions(p: np.ndarray, name: str) -> tuple[np.ndarray, float]:
    """Normalised arc length (N,) along the points p (N, d) [m] (0 at the first, exactly 1 at the
    last) and the total length [m]."""
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if not (seg > 0).all():
        raise SelectionError(f"{name}: two consecutive nodes of the side coincide (no arc length between them)")
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = float(s[-1])
    s /= total
    s[-1] = 1.0
    return s, total


def _locate(s: np.ndarray, x: np.ndarray):
    """Segment (k, k+1) of the increasing breakpoints s holding each x, and x's place t in [0, 1]
    on it."""
    k = np.clip(np.searchsorted(s, x, side="right") - 1, 0, s.size - 2)
    return k, np.clip((x - s[k]) / (s[k + 1] - s[k]), 0.0, 1.0)


def arc_elements(pa: np.ndarray, pb: np.ndarray):
    """Sew two node lines of unequal counts along arc length (a dual mortar seam in penalty form).

    pa (Na, d), pb (Nb, d): the rest positions [m] of the two sides' nodes in sewing order (each
    side on its own panel's plane), Na != Nb, both >= 2. Both sides are parametrised by their
    fraction of arc length sigma in [0, 1] (points at the same sigma are sewn together) and
    interpolated linearly between their nodes. The denser side is the *slave*: each of its nodes
    i is sewn to a point of the other (master) side, a weighted mean of the master's line
    x_m(sigma) under node i's dual function psi_i (on each slave segment with hats N1, N2:
    psi1 = 2 N1 - N2, psi2 = 2 N2 - N1; int psi_i N_k dsigma = delta_ik int N_i dsigma):

        g_i = x_i - int psi_i x_m dsigma / int N_i dsigma,

    integrated exactly over the merged breakpoints of both sides. Its energy is k L_i |g_i|^2 / 2
    with L_i = int N_i dsigma times the seam length (the law of the zero-length seam springs).
    Why this form (Wohlmuth's dual mortar): a straight master line is reproduced exactly (the
    slave's nodes close on it, ends included); a uniform pull across the seam reaches every node
    of both sides in proportion to its share of the seam (each master node j receives int N_j
    lambda dsigma of the line load lambda), so a seam of unequal counts carries a uniform
    membrane state exactly; and one gap per slave node, on that node, cannot lock a curved
    seam. (Sewing each slave node to the master point at its own sigma passes neither test
    exactly: it shifts load between rows.)

    Returns (slave_is_a, nodes (Ns, K) indices into the concatenation [slave side, master side],
    the slave node first, weight (Ns, K) the gap's coefficients (1 on the slave node, summing to
    0 per element; padding has weight 0 and repeats the element's first node), share (Ns,)
    int N_i dsigma (summing to 1), La, Lb [m] the sides' rest arc lengths). The point node i is
    sewn to is x_i - g_i: sum over the master nodes of -weight x."""
    sa, La = _arc_fractions(pa, "a")
    sb, Lb = _arc_fractions(pb, "b")
    slave_is_a = sa.size > sb.size
    ss, sm = (sa, sb) if slave_is_a else (sb, sa)
    ns = ss.size
    # exact integrals of products of hat functions: both are linear between merged breakpoints,
    # so two-point Gauss quadrature on each merged interval is exact
    br = np.unique(np.concatenate([ss, sm]))
    lo, hi = br[:-1], br[1:]
    keep = hi - lo > 0
    lo, hi = lo[keep], hi[keep]
    g = np.array([0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0)])
    x = (lo[:, None] + (hi - lo)[:, None] * g[None, :]).ravel()
    w = np.repeat((hi - lo) / 2, 2)
    ks, ts = _locate(ss, x)
    km, tm = _locate(sm, x)
    # per quadrature point: the slave's dual functions on its segment ks (psi of node ks:
    # 2 (1 - ts) - ts, of node ks + 1: 2 ts - (1 - ts)) against the master's hats
    rows = {i: {i: 0.0} for i in range(ns)}  # the slave node itself: weight 1 (set below)
    for q in range(x.size):
        for i, psi in ((ks[q], 2.0 - 3.0 * ts[q]), (ks[q] + 1, 3.0 * ts[q] - 1.0)):
            r = rows[int(i)]
            for j, nj in ((km[q], 1.0 - tm[q]), (km[q] + 1, tm[q])):
                if nj != 0.0:
                    r[ns + int(j)] = r.get(ns + int(j), 0.0) - w[q] * psi * nj
    share = np.diff(ss)
    share = (np.concatenate([share, [0.0]]) + np.concatenate([[0.0], share])) / 2
    K = max(len(r) for r in rows.values())
    nodes = np.empty((ns, K), np.int64)
    weight = np.zeros((ns, K))
    for i in range(ns):
        cols = sorted(rows[i])
        nodes[i, :] = cols[0]
        nodes[i, :len(cols)] = cols
        weight[i, :len(cols)] = [1.0 if c == i else rows[i][c] / share[i] for c in cols]
    return slave_is_a, nodes, weight, share, La, Lb
