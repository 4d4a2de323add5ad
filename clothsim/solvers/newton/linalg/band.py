"""The band solver: a reverse Cuthill-McKee-like band order of the nodes and the banded Cholesky
factorisation and solve of a (projected) Newton system, used on the coarsest multigrid level and
for small systems."""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from numba import njit




def band_order(n, spring_nodes):
    """A node order (reverse Cuthill-McKee on the spring graph) for the banded solve and its
    half-bandwidth in nodes: (perm (n,) new -> old node, inverse (n,) old -> new, bandwidth)."""
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    a, b = spring_nodes[:, 0], spring_nodes[:, 1]
    G = sp.coo_matrix((np.ones(2 * a.size), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n)).tocsr()
    perm = np.asarray(reverse_cuthill_mckee(G, symmetric_mode=True), np.int64)
    inv = np.empty(n, np.int64)
    inv[perm] = np.arange(n)
    bw = int(np.abs(inv[a] - inv[b]).max()) if a.size else 0
    return perm, inv, bw


@njit(cache=True, inline="always")
def _band_entry(L, j, k, k0, w):
    """L[j, k] (k < j) of ``_band_factor``: A[j, k] minus the sum over m = k0 .. k-1 of
    L[j, m] L[k, m] (in that order), over L[k, k]."""
    s = L[j, w - 1 - (j - k)]
    oj = w - 1 - j
    ok = w - 1 - k
    for m in range(k0, k):
        s -= L[j, oj + m] * L[k, ok + m]
    L[j, w - 1 - (j - k)] = s / L[k, w - 1]


@njit(cache=True)
def _band_factor(L):
    """In-place banded Cholesky factorisation of the lower band stored in L (3n, w) (row i holds
    A[i, i - w + 1 .. i], the diagonal last; see ``_band_cholesky_solve``). Returns False when a
    pivot is not positive.

    Each entry is computed by the same arithmetic, in the same order, as the row-by-row
    algorithm (s = A[j, k] - sum_{m} L[j, m] L[k, m], m increasing); four rows are computed side
    by side against the same earlier row k, so that the four sums' additions (a chain each)
    overlap in the processor's pipeline instead of waiting on one another."""
    n3 = L.shape[0]
    w = L.shape[1]
    j0 = 0
    while j0 < n3:
        R = n3 - j0
        if R > 4:
            R = 4
        k00 = max(j0 - (w - 1), 0)
        if R == 4:
            k01 = max(j0 + 1 - (w - 1), 0)
            k02 = max(j0 + 2 - (w - 1), 0)
            k03 = max(j0 + 3 - (w - 1), 0)
            oj0 = w - 1 - j0
            oj1 = oj0 - 1
            oj2 = oj0 - 2
            oj3 = oj0 - 3
            for k in range(k00, j0):
                if k < k03:
                    # not every row of the four has an entry in column k yet
                    _band_entry(L, j0, k, k00, w)
                    if k >= k01:
                        _band_entry(L, j0 + 1, k, k01, w)
                    if k >= k02:
                        _band_entry(L, j0 + 2, k, k02, w)
                    continue
                ok = w - 1 - k
                s0 = L[j0, oj0 + k]
                s1 = L[j0 + 1, oj1 + k]
                s2 = L[j0 + 2, oj2 + k]
                s3 = L[j0 + 3, oj3 + k]
                for m in range(k00, k03):
                    s0 -= L[j0, oj0 + m] * L[k, ok + m]
                for m in range(k01, k03):
                    s1 -= L[j0 + 1, oj1 + m] * L[k, ok + m]
                for m in range(k02, k03):
                    s2 -= L[j0 + 2, oj2 + m] * L[k, ok + m]
                for m in range(k03, k):
                    lk = L[k, ok + m]
                    s0 -= L[j0, oj0 + m] * lk
                    s1 -= L[j0 + 1, oj1 + m] * lk
                    s2 -= L[j0 + 2, oj2 + m] * lk
                    s3 -= L[j0 + 3, oj3 + m] * lk
                d = L[k, w - 1]
                L[j0, oj0 + k] = s0 / d
                L[j0 + 1, oj1 + k] = s1 / d
                L[j0 + 2, oj2 + k] = s2 / d
                L[j0 + 3, oj3 + k] = s3 / d
            kstart = j0
        else:
            kstart = -1
        # the rest of each row (row by row): its entries from column kstart on, then its diagonal
        for r in range(R):
            j = j0 + r
            k0 = max(j - (w - 1), 0)
            kb = k0 if kstart < 0 else max(kstart, k0)
            for k in range(kb, j):
                _band_entry(L, j, k, k0, w)
            s = L[j, w - 1]
            oj = w - 1 - j
            for m in range(k0, j):
                v = L[j, oj + m]
                s -= v * v
            if not (s > 0.0) or not math.isfinite(s):
                return False
            L[j, w - 1] = math.sqrt(s)
        j0 += R
    return True


@njit(cache=True)
def _band_cholesky_solve(indptr, indices, data, inv, bw, rhs, L, x):
    """Solve A x = rhs for the symmetric positive definite BSR matrix A (3x3 blocks) by a banded
    Cholesky factorisation in the node order ``inv`` (old -> new node; half-bandwidth bw nodes).
    L (3n, 3 bw + 3) is work space: row i holds L[i, i - w + 1 .. i] (w = 3 bw + 3 columns, the
    diagonal last), so the inner products run over contiguous memory; on success it holds the
    factor (``_band_factored_solve`` solves with it again). Returns False (x undefined) when a
    pivot is not positive: the caller falls back to the sparse LU."""
    if not _band_scatter_factor(indptr, indices, data, inv, L):
        return False
    _band_factored_solve(L, inv, rhs, x)
    return True


@njit(cache=True)
def _band_scatter_factor(indptr, indices, data, inv, L):
    """L (3n, w): the banded Cholesky factor of the BSR matrix (indptr, indices, data (nb, 3, 3))
    in the node order ``inv`` (see ``_band_cholesky_solve``). Returns False when a pivot is not
    positive."""
    n = indptr.shape[0] - 1
    n3 = 3 * n
    w = L.shape[1]
    for i in range(n3):
        for c in range(w):
            L[i, c] = 0.0
    # scatter the lower triangle (new numbering): A[r, c] with c <= r -> L[r, w - 1 - (r - c)]
    for k in range(n):
        kn = inv[k]
        for q in range(indptr[k], indptr[k + 1]):
            jn = inv[indices[q]]
            if jn > kn:
                continue
            for a in range(3):
                r = 3 * kn + a
                for b in range(3):
                    c = 3 * jn + b
                    if c <= r:
                        L[r, w - 1 - (r - c)] = data[q, a, b]
    return _band_factor(L)


@njit(cache=True)
def _band_factored_solve(L, inv, rhs, x):
    """x (3n,) = A^-1 rhs (3n,) with A's banded Cholesky factor L (3n, w) in the node order inv
    (``_band_scatter_factor``)."""
    n3 = L.shape[0]
    n = n3 // 3
    w = L.shape[1]
    # forward: L y = P rhs
    y = np.empty(n3)
    for k in range(n):
        kn = inv[k]
        for a in range(3):
            y[3 * kn + a] = rhs[3 * k + a]
    for j in range(n3):
        s = y[j]
        k0 = j - (w - 1)
        if k0 < 0:
            k0 = 0
        oj = w - 1 - j
        for m in range(k0, j):
            s -= L[j, oj + m] * y[m]
        y[j] = s / L[j, w - 1]
    # backward: L^T z = y
    for jj in range(n3):
        j = n3 - 1 - jj
        y[j] /= L[j, w - 1]
        v = y[j]
        k0 = j - (w - 1)
        if k0 < 0:
            k0 = 0
        oj = w - 1 - j
        for m in range(k0, j):
            y[m] -= L[j, oj + m] * v
    for k in range(n):
        kn = inv[k]
        for a in range(3):
            x[3 * k + a] = y[3 * kn + a]
