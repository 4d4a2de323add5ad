"""Shared by the measuring levels' known-answer tests (a tube on a chart leg, a sleeve on an arm):
Laplace's pressure at a level from its course strain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clothsim.compression import MMHG
from clothsim.mold.leg import leg_radius


def wale_strain(res, z: float) -> float:
    """The wale (weft) springs' strain at height z [m]: hat weights over the median row spacing."""
    topo = res.model.topology
    X = res.state.positions
    F = np.asarray(topo.weft)
    strain = res._f()[0][topo.warp_count:topo.warp_count + topo.weft_count]
    zm = 0.5 * (X[F[:, 0], 2] + X[F[:, 1], 2])
    row = float(np.median(np.abs(X[F[:, 0], 2] - X[F[:, 1], 2])))
    w = np.clip(1 - np.abs(zm - z) / row, 0, None)
    return float((w * strain).sum() / w.sum())


def level_laplace_pa(res, r: dict) -> float:
    """Laplace's T cos(alpha) / r [Pa] at the level reading ``r`` (a row of
    ``compression()["levels"]["levels"]``) on a chart limb: T = the course table's tension at the
    level's course strain over (1 + the wale strain there) [N/m], r = girth / 2 pi, alpha the
    meridian's slope (from the surface)."""
    table = res.model.table_list[0]
    z = r["z_m"]
    T = float(np.interp(r["course_strain"], table.strain, table.tension)) / (1 + wale_strain(res, z))
    rz = leg_radius(res.model.mold.params, z, 0.0)[1]
    return T / math.sqrt(1 + rz * rz) / (r["girth_m"] / (2 * math.pi))


def assert_level_reads_laplace(res, r: dict, rest: float) -> None:
    """The level reading ``r`` of a uniform tube of cut width ``rest`` [m] on a circular chart
    limb: its course strain is the girth over the cut width (3 %), its girth mean Laplace's
    (:func:`level_laplace_pa`, 2 %) and its four sides the mean (3 %: uniform round a circle)."""
    assert r["course_strain"] == pytest.approx(r["girth_m"] / rest - 1, rel=0.03), r["level"]
    assert r["mean_mmhg"] * MMHG == pytest.approx(level_laplace_pa(res, r), rel=0.02), r["level"]
    for side, p in r["sides"].items():
        assert p == pytest.approx(r["mean_mmhg"], rel=0.03), (r["level"], side)
