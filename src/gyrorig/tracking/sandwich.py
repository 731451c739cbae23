"""The covariance of a fit's parameters from its residuals themselves (:func:`sandwich_covariance`): what the
model lacks (the scene behind a spot's edge, a lossy codec's ringing, spatially correlated noise) reaches the
parameters through the residuals, where the inverse Fisher matrix alone would not see it."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["sandwich_covariance"]


#: the spatial kernel of :func:`sandwich_covariance`: Bartlett weights over a 5 x 5 neighbourhood (a positive-definite
#: kernel, so the estimate is positive semi-definite), reaching residuals correlated over a PSF, a texture's grain or
#: a codec's block edge
_BARTLETT_1D = np.array([1 / 3, 2 / 3, 1.0, 2 / 3, 1 / 3])


@njit(cache=True)
def _projected_meat(pick, shape, jac, weight, resid, proj):
    """``P M P^T`` of :func:`sandwich_covariance`'s ``M = sum_ij k(i - j) u_i u_j^T`` over the fitted pixels
    (flat indices ``pick`` into a window of ``shape``; the rows of ``jac``, ``weight``, ``resid`` theirs),
    with ``P = proj`` (rows of ``F^-1``: only the parameters asked for are carried through the sum)."""
    h, w = shape
    m, n = proj.shape
    grid = np.zeros((h, w, m))
    for k in range(pick.size):
        iy, ix = pick[k] // w, pick[k] % w
        wr = weight[k] * resid[k]
        for a in range(m):
            acc = 0.0
            for c in range(n):
                acc += proj[a, c] * jac[k, c]
            grid[iy, ix, a] = acc * wr
    meat = np.zeros((m, m))
    for k in range(pick.size):
        iy, ix = pick[k] // w, pick[k] % w
        for dy in range(-2, 3):
            jy = iy + dy
            if jy < 0 or jy >= h:
                continue
            for dx in range(-2, 3):
                jx = ix + dx
                if jx < 0 or jx >= w:
                    continue
                kern = _BARTLETT_1D[dy + 2] * _BARTLETT_1D[dx + 2]
                for a in range(m):
                    ua = kern * grid[iy, ix, a]
                    for c in range(m):
                        meat[a, c] += ua * grid[jy, jx, c]
    return 0.5 * (meat + meat.T)


def sandwich_covariance(pick: np.ndarray, shape: tuple[int, int], jac: np.ndarray, weight: np.ndarray,
                        resid: np.ndarray, fisher_inv: np.ndarray, parameters: int | None = None) -> np.ndarray:
    """The parameters' covariance from the residuals themselves: ``F^-1 M F^-1`` with
    ``M = sum_ij k(i - j) u_i u_j^T``, ``u_i = J_i w_i r_i`` over the fitted pixels and ``k`` a Bartlett kernel
    over neighbours up to 2 px apart.

    Where the noise model is right and the pixels independent, ``E M = F`` and this is ``F^-1``; where the
    residuals hold what the model lacks (the scene behind the spot's edge, a lossy codec's ringing,
    spatially correlated noise) it grows by what those do to the centre: a heteroscedasticity- and
    autocorrelation-consistent estimate (White; Newey-West, in two dimensions).  ``pick`` the fitted pixels'
    flat indices in a window of ``shape``; ``jac`` (n, parameters), ``weight, resid`` (n) theirs.  With
    ``parameters`` only the covariance of the first that many parameters is computed."""
    proj = np.ascontiguousarray(fisher_inv[:parameters], np.float64)
    return _projected_meat(np.asarray(pick, np.int64), shape, np.asarray(jac, np.float64),
                           np.asarray(weight, np.float64), np.asarray(resid, np.float64), proj)
