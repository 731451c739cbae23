"""A small square linear system solved inside compiled code (numba): a spot fit's Gauss-Newton step and its edge's
harmonics, a few unknowns each, where a LAPACK call would cost more than the elimination."""

from __future__ import annotations

import math

from numba import njit

__all__ = ["lu_solve"]


@njit(cache=True)
def lu_solve(a, b):
    """``a x = b`` for a small square matrix by Gaussian elimination with partial pivoting; ``(x, ok)``, ``ok``
    False when a pivot vanishes or the result is not finite."""
    n = b.size
    m = a.copy()
    x = b.copy()
    for k in range(n):
        piv = k
        for i in range(k + 1, n):
            if abs(m[i, k]) > abs(m[piv, k]):
                piv = i
        if m[piv, k] == 0.0:
            return x, False
        if piv != k:
            for j in range(n):
                m[k, j], m[piv, j] = m[piv, j], m[k, j]
            x[k], x[piv] = x[piv], x[k]
        for i in range(k + 1, n):
            f = m[i, k] / m[k, k]
            for j in range(k, n):
                m[i, j] -= f * m[k, j]
            x[i] -= f * x[k]
    for k in range(n - 1, -1, -1):
        acc = x[k]
        for j in range(k + 1, n):
            acc -= m[k, j] * x[j]
        x[k] = acc / m[k, k]
    for k in range(n):
        if not math.isfinite(x[k]):
            return x, False
    return x, True
