r"""Cyclic band systems of a closed curve's least-squares fit: band storage, a banded Cholesky.

A closed Catmull-Rom curve of ``n`` control points (:mod:`surface.catmull_rom`) fitted by least
squares with a third-difference fairness term has normal equations ``(AᵀA + λ DᵀD) P = Aᵀx`` whose
matrix is symmetric, positive definite and cyclically banded: entry ``(i, j)`` is non-zero only
for ``i`` and ``j`` cyclically at most 3 apart.  Stored as ``band[j, (i − j + 3) mod n]`` ``(n, 7)``
(:func:`normal_equations_band` accumulates ``AᵀA`` and ``Aᵀx`` in it, :func:`third_difference_band`
is ``DᵀD``), it is solved in O(n) by a banded Cholesky factorisation in the interleaved order
``0, n−1, 1, n−2, …`` (:func:`interleaved`: the cyclic half-band 3 becomes a plain band of 6;
:func:`cholesky_cyclic_band`, numba), with a sparse LU (:func:`solve_band`) where that is not
positive definite to rounding or ``n <= 6``.  Right-hand sides ``(n, 3) float64``.
"""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve

__all__ = ["THIRD_DIFFERENCE_STENCIL", "band_rows", "cholesky_cyclic_band", "cyclic_band",
           "interleaved", "normal_equations_band", "periodic_third_difference", "solve_band",
           "third_difference_band", "third_difference_gram"]


@lru_cache(maxsize=64)
def interleaved(n: int) -> np.ndarray:
    """The order ``0, n-1, 1, n-2, ...`` of n cyclic unknowns: cyclic neighbours up to 3
    apart end up at most 6 places apart, so a cyclic band of half-width 3 becomes a plain
    band of half-width 6 (no fill-in outside it)."""
    order = np.empty(n, np.int64)
    order[0::2] = np.arange((n + 1) // 2)
    order[1::2] = n - 1 - np.arange(n // 2)
    order.flags.writeable = False
    return order


@numba.njit(cache=True, nogil=True)
def cholesky_cyclic_band(system, rhs, order, out):  # pragma: no cover - compiled
    """Solve the symmetric positive definite cyclic band system of a closed curve's fit
    (n > 6; band storage ``system[j, (i − j + 3) mod n]`` = entry (i, j), right-hand sides
    ``rhs`` ``(n, 3)``) into ``out``; False (``out`` undefined) when it is not positive
    definite to rounding.

    A banded Cholesky factorisation in the interleaved order (:func:`interleaved`: the
    cyclic half-band 3 becomes a plain band of 6), O(n) work with no sparse-matrix set-up
    (SuperLU's was most of the GCV's time, 900 fits a real temple ring).
    """
    n = system.shape[0]
    half = 6
    low = np.zeros((n, half + 1))          # low[p, d] = L[p, p - d], interleaved order
    for p in range(n):
        for d in range(min(half, p), -1, -1):
            q = p - d
            i, j = order[p], order[q]
            diff = (i - j + 3) % n
            value = system[j, diff] if diff <= 6 else 0.0   # cyclically <= 3 apart (n > 6)
            for r in range(max(p - half, q - half, 0), q):
                value -= low[p, p - r] * low[q, q - r]
            if d == 0:
                if value <= 0.0:
                    return False
                low[p, 0] = np.sqrt(value)
            else:
                low[p, d] = value / low[q, 0]
    y = np.empty((n, 3))
    for p in range(n):
        for c in range(3):
            value = rhs[order[p], c]
            for r in range(max(p - half, 0), p):
                value -= low[p, p - r] * y[r, c]
            y[p, c] = value / low[p, 0]
    for p in range(n - 1, -1, -1):
        for c in range(3):
            value = y[p, c]
            for r in range(p + 1, min(p + half + 1, n)):
                value -= low[r, r - p] * y[r, c]
            y[p, c] = value / low[p, 0]
    for p in range(n):
        for c in range(3):
            out[order[p], c] = y[p, c]
    return True


@numba.njit(cache=True, nogil=True)
def normal_equations_band(cols, weights, pts, normal, rhs):  # pragma: no cover
    """Accumulate ``AᵀA`` (band storage ``(n, 7)``) and ``Aᵀx`` ``(n, 3)``, point by point.

    Row j of A holds ``weights[j]`` at ``cols[j]`` (four distinct columns, n > 6).
    """
    n = normal.shape[0]
    for k in range(cols.shape[0]):
        for a in range(4):
            i = cols[k, a]
            w = weights[k, a]
            for d in range(3):
                rhs[i, d] += w * pts[k, d]
            for b in range(4):
                j = cols[k, b]
                normal[j, (i - j + 3) % n] += w * weights[k, b]


@lru_cache(maxsize=64)
def third_difference_gram(n: int) -> np.ndarray:
    """Dense ``DᵀD`` ``(n, n)`` of :func:`periodic_third_difference` (integers, exact)."""
    fair = periodic_third_difference(n)
    gram = (fair.T @ fair).toarray()
    gram.flags.writeable = False
    return gram


#: One column of ``DᵀD`` about its diagonal (offsets −3..3): the autocorrelation of the
#: third difference's stencil (−1, 3, −3, 1), the same in every column of a ring of n > 6.
THIRD_DIFFERENCE_STENCIL = np.array([-1.0, 6.0, -15.0, 20.0, -15.0, 6.0, -1.0])


def third_difference_band(n: int) -> np.ndarray:
    """``DᵀD`` in band storage ``(n, 7)`` (n > 6): entry (i, j) at ``[j, (i − j + 3) mod n]``;
    circulant, so every column is :data:`THIRD_DIFFERENCE_STENCIL` (a test compares it
    with the sparse product ``DᵀD``)."""
    return np.broadcast_to(THIRD_DIFFERENCE_STENCIL, (n, 7))


@lru_cache(maxsize=64)
def band_rows(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``(n, 7)`` of band column j in ascending order, and their band slots (n > 6)."""
    rows = (np.arange(n)[:, None] + np.arange(-3, 4)[None, :]) % n
    order = np.argsort(rows, axis=1)
    return np.take_along_axis(rows, order, axis=1), order


@lru_cache(maxsize=64)
def cyclic_band(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Every (row, column) of a narrow ring (n <= 6): ``(n, n)`` each, rows ascending."""
    rows = np.broadcast_to(np.arange(n)[None, :], (n, n))
    return rows, rows.T


def solve_band(values: np.ndarray, rows: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve the cyclic band system whose column j holds ``values[j]`` at ``rows[j]``.

    Sparse LU (SuperLU) on the CSC matrix of the non-zeros; like scipy's sparse sums
    and products, exact zeros are not stored.
    """
    n = len(values)
    nonzero = values != 0
    indptr = np.concatenate([[0], np.cumsum(nonzero.sum(axis=1))])
    system = sparse.csc_matrix((values[nonzero], rows[nonzero], indptr), shape=(n, n))
    return np.asarray(spsolve(system, rhs)).reshape(n, 3)


def periodic_third_difference(n: int) -> sparse.csc_matrix:
    """``(n, n)`` matrix of ``−P_{j−1} + 3P_j − 3P_{j+1} + P_{j+2}`` with cyclic indices."""
    rows = np.repeat(np.arange(n), 4)
    cols = (rows + np.tile([-1, 0, 1, 2], n)) % n
    vals = np.tile([-1.0, 3.0, -3.0, 1.0], n)
    return sparse.csc_matrix((vals, (rows, cols)), shape=(n, n))
