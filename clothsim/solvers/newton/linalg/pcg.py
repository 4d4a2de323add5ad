"""Preconditioned conjugate gradients (``_pcg``) with its vector operations as numba loops."""

from __future__ import annotations

import math

import numpy as np
from numba import njit




@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True)
def _cg_update(x, r, p, Ap, alpha):
    """x += alpha p; r -= alpha Ap; returns |r|^2."""
    s = 0.0
    for i in range(x.shape[0]):
        x[i] += alpha * p[i]
        r[i] -= alpha * Ap[i]
        s += r[i] * r[i]
    return s


@njit(cache=True)
def _cg_direction(p, z, beta):
    for i in range(p.shape[0]):
        p[i] = z[i] + beta * p[i]


def _pcg(matvec, prec, b, tol, maxiter, x0=None):
    """Preconditioned conjugate gradients from x = x0 (None: 0); returns (x, iterations, relative
    residual), the residual relative to |b|.

    Vector operations are numba loops: BLAS calls on short vectors are slow when its threads
    compete for a loaded machine."""
    bn = math.sqrt(_dot(b, b))
    if x0 is None:
        x = np.zeros_like(b)
        r = b.copy()
    else:
        x = x0.copy()
        r = np.empty_like(b)
        matvec(x, r)
        np.subtract(b, r, out=r)
        if bn > 0.0 and math.sqrt(_dot(r, r)) <= tol * bn:
            return x, 0, math.sqrt(_dot(r, r)) / bn
    if bn == 0.0:
        return x, 0, 0.0
    z = prec(r)
    p = z.copy()
    rz = _dot(r, z)
    it = 0
    rel = 1.0
    Ap = np.empty_like(b)
    for it in range(1, maxiter + 1):
        matvec(p, Ap)
        pAp = _dot(p, Ap)
        if not (pAp > 0.0):
            break
        rr = _cg_update(x, r, p, Ap, rz / pAp)
        rel = math.sqrt(rr) / bn
        if rel <= tol:
            break
        z = prec(r)
        rz_new = _dot(r, z)
        _cg_direction(p, z, rz_new / rz)
        rz = rz_new
    return x, it, rel
