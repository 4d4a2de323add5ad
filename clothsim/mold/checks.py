"""Sanity checks of a loaded mold against the scene (pure functions; the caller decides where
to show their warnings)."""

from __future__ import annotations

import math

import numpy as np

from .queries import mold_query_many
from .record import MESH_KINDS, MOLD_BOX, MOLD_CYLINDER, MOLD_LEG, MOLD_PLANE, MOLD_SPHERE, Mold

#: a mold this many times larger (or smaller) than the sheet gets a units warning: a file in
#: millimetres read as metres is 1000x too large, one in centimetres 100x
SCALE_WARNING_RATIO = 100.0


def mold_size(mold: Mold) -> float | None:
    """The mold's overall size [m]: the bounding-box diagonal of a mesh or a box, a sphere's
    diameter, the larger of a cylinder's diameter and length; None for a plane (unbounded)."""
    p = mold.params
    if mold.kind in MESH_KINDS:
        lo, hi = mold.bounds
        return float(np.linalg.norm(hi - lo))
    if mold.kind == MOLD_SPHERE:
        return 2.0 * float(p[3])
    if mold.kind == MOLD_CYLINDER:
        return max(2.0 * float(p[6]), float(p[7]))
    if mold.kind in (MOLD_BOX, MOLD_LEG):
        lo, hi = mold.bounds
        return float(np.linalg.norm(hi - lo))
    assert mold.kind == MOLD_PLANE
    return None


def mold_scale_warning(mold: Mold | None, sheet_size_m) -> str | None:
    """A warning when the mold is about 1000x larger or smaller than the sheet, else None.

    mold: a loaded Mold (None: no warning); sheet_size_m [m]: the sheet's size, one number or
    its sides (the larger is used). The warning fires at a ratio of ``SCALE_WARNING_RATIO``
    (100) or more either way: no real draping set-up has a mold a hundred times the sheet's size
    or a hundredth of it, while a file in millimetres read as metres is 1000x off (centimetres
    100x). The message names both sizes and asks "millimetres?"."""
    if mold is None:
        return None
    size = mold_size(mold)
    sheet = float(np.max(np.asarray(sheet_size_m, dtype=np.float64)))
    if size is None or not (math.isfinite(size) and size > 0 and math.isfinite(sheet) and sheet > 0):
        return None
    ratio = size / sheet
    if ratio >= SCALE_WARNING_RATIO:
        return (f"the mold is {ratio:.0f}x larger than the sheet ({size:.4g} m across against "
                f"{sheet:.4g} m): millimetres? A file in millimetres needs mold.scale: 0.001 "
                f"(everything is in metres)")
    if ratio <= 1.0 / SCALE_WARNING_RATIO:
        return (f"the mold is {1.0 / ratio:.0f}x smaller than the sheet ({size:.4g} m across "
                f"against {sheet:.4g} m): millimetres? fabric.size and the mold are both read in "
                f"metres; check fabric.size and mold.scale")
    return None


def mold_reach_warning(mold: Mold | None, points: np.ndarray, sheet_size_m) -> str | None:
    """A warning when no node of the sheet can reach the mold, else None.

    mold: a loaded Mold (None: no warning); points (n, 3) [m]: where the nodes start and where
    the constraints take them (both); sheet_size_m [m]: the sheet's size, one number or its sides
    (the larger is used). The mold is out of reach when every point is farther from it than the
    sheet's size: a node moves by less than that in any equilibrium short of stretching the
    sheet to twice its length (e.g. a sheet laid beside the mold with no constraint moving it
    there). When the distance or the mold's size is ``SCALE_WARNING_RATIO`` (100) or more times
    the sheet's size, units are the likely cause and the message also asks "millimetres?"."""
    if mold is None:
        return None
    P = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    sheet = float(np.max(np.asarray(sheet_size_m, dtype=np.float64)))
    if P.shape[0] == 0 or not (math.isfinite(sheet) and sheet > 0) or not np.isfinite(P).all():
        return None

    n = P.shape[0]
    sd = np.empty(n)
    mold_query_many(mold.kernel_args(), P, sd, np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 2), np.int64))
    dist = float(np.min(sd))  # signed: a point inside (or behind an open skin) is in reach
    if not (dist > sheet):
        return None
    msg = (f"no node of the sheet can reach the mold: every node starts and is held {dist:.4g} m "
           f"or more from it, more than the sheet's size ({sheet:.4g} m); move the mold or the "
           f"sheet (fabric.origin, initial.wrap, a constraint's displacement)")
    size = mold_size(mold)
    ratio = max(dist / sheet, (size / sheet) if size else 0.0, (sheet / size) if size else 0.0)
    if ratio >= SCALE_WARNING_RATIO:
        msg += (f"; millimetres? The mold is {dist / sheet:.0f} sheet sizes away"
                + (f" and {size / sheet:.3g}x the sheet's size" if size else "")
                + ": a file in millimetres needs mold.scale: 0.001")
    return msg
