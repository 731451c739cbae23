"""Tolerances that follow from statistics, for the tests' checks of estimates against truth.

Every band is ``Z`` standard errors wide (two-sided, a false alarm in 1.6e4 checks for a Gaussian
statistic), with the standard error of the statistic for the sample at hand:

* a mean of ``n`` unit-variance pulls: ``1 / sqrt(n)``;
* a standard deviation of ``n`` Gaussian values, relative: ``1 / sqrt(2 (n - 1))``;
* a reduced chi-square with ``dof`` degrees of freedom: ``sqrt(2 / dof)``;
* the largest of ``n`` |pulls|: below the ``1e-4 / n`` two-sided Gaussian tail.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2, norm

#: standard errors in every band
Z = 4.0
#: the tail probability the bands leave out (two-sided, Gaussian)
TAIL = 2 * float(norm.sf(Z))


def sd_band(n: int, z: float = Z) -> tuple[float, float]:
    """Where the SD of ``n`` unit-variance Gaussian values lies (relative standard error ``1/sqrt(2(n-1))``)."""
    half = z / math.sqrt(2 * (n - 1))
    return 1 - half, 1 + half


def sd_ratio_band(n: int, tail: float = TAIL) -> tuple[float, float]:
    """Where the SD of ``n`` Gaussian values over the true SD lies: the chi distribution's quantiles
    (exact for small ``n``, where the normal approximation of :func:`sd_band` is poor)."""
    dof = n - 1
    return math.sqrt(chi2.ppf(tail / 2, dof) / dof), math.sqrt(chi2.isf(tail / 2, dof) / dof)


def chi2_red_band(dof: int, z: float = Z) -> tuple[float, float]:
    """Where a reduced chi-square with ``dof`` degrees of freedom lies (standard error ``sqrt(2/dof)``)."""
    half = z * math.sqrt(2 / dof)
    return 1 - half, 1 + half


def max_abs_pull(n: int, tail: float = 1e-4) -> float:
    """The bound the largest of ``n`` |unit Gaussian| values stays below but for a ``tail`` chance."""
    return float(norm.isf(tail / (2 * n)))


def check_pulls(pulls, label: str = "") -> None:
    """Pulls (estimate - truth) / sigma of ``n`` independent estimates: mean 0, SD 1, no outlier (bands above)."""
    p = np.asarray(pulls, float)
    n = len(p)
    lo, hi = sd_band(n)
    assert abs(p.mean()) < Z / math.sqrt(n), (label, "mean", p.mean(), Z / math.sqrt(n))
    assert lo < p.std(ddof=1) < hi, (label, "sd", p.std(ddof=1), (lo, hi))
    assert np.abs(p).max() < max_abs_pull(n), (label, "max", np.abs(p).max(), max_abs_pull(n))
