"""A break in the motion: the record is two motions, each the model's, joined at one moment.

A touch of the hand, a bump against a stop or a knock on the table changes the top's state in a moment: before and
after it the motion is the scene's, but no one set of the model's parameters holds across it, and a fit of the whole
record is a compromise that describes neither.  :func:`find_break` looks for that moment where the whole record's
residuals are too large for its errors: the model (the terms already chosen) is fitted to the frames before and after
each candidate moment on its own, the moment that leaves the least chi-square taken (a grid over the record, then
refined to the frame).  It is a break when

- splitting there lowers the chi-square beyond chance: the F statistic of the second set of parameters,
  ``((chi2_whole - chi2_split) / k) / (chi2_split / dof_split)``, above its ``1 - BREAK_P`` quantile;
- the split takes away at least :data:`EXCESS_SHARE` of the whole record's reduced chi-square's excess over 1 (errors
  correlated from frame to frame, a codec's, let any split lower the chi-square beyond what the F test expects of
  independent errors, but only by a little of the excess);
- both parts are fitted no worse than :data:`PART_CHI2_RED_FRACTION` of the whole record's reduced chi-square above
  the split's (each part, on its own, is the model's);
- the moment is sharp: a split :data:`SHARPNESS_SHARE` of the record earlier or later gives back at least
  :data:`SHARPNESS_RISE` of what the best split gained (a change spread over the record, a spin slowly lost, lowers
  the chi-square as much wherever the record is cut near its middle).

The fit then keeps the longer part (:func:`gyrorig.fit.fit_angles`) and says where the break was.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import f as f_dist

from .data import FitData, FitError
from .model import FitModel, Residuals
from .result import MotionBreak
from .solver import STATIONARY_STEP_SE, Solution, gauss_newton_polish, remaining_step_se

__all__ = ["find_break", "part_of", "MIN_PART_SHARE", "BREAK_P"]

#: each part holds at least this share of the record's frames (and three frames per parameter)
MIN_PART_SHARE = 0.05
#: the chance of a split lowering the chi-square as much with no break (the F test)
BREAK_P = 1e-6
#: candidate moments on the first, coarse pass
GRID = 24
#: the share of the whole record's excess reduced chi-square the split must take away
EXCESS_SHARE = 0.5
#: each part's reduced chi-square may exceed the pooled one by at most this share of what the split gained
PART_CHI2_RED_FRACTION = 0.25
#: the sharpness test: a split this share of the record away gives back at least this share of the gain
SHARPNESS_SHARE, SHARPNESS_RISE = 0.1, 0.1
#: Gauss-Newton steps from the whole record's parameters to each part's
PART_STEPS = 20
#: at most this many residual evaluations of the damped steps that follow where they did not
PART_LM_EVALUATIONS = 300


def part_of(data: FitData, keep: np.ndarray) -> FitData:
    """The fit's data at the frames ``keep`` (a bool mask or indices), the reference time kept."""
    def take(v):
        return None if v is None else v[keep]
    return replace(data, frame=data.frame[keep], t_s=data.t_s[keep], theta_rad=data.theta_rad[keep],
                   phi_rad=data.phi_rad[keep], cov=data.cov[keep], segment=data.segment[keep],
                   exposure_s=take(data.exposure_s), b_frame=take(data.b_frame), row_fraction=take(data.row_fraction),
                   camera_shift=None if data.camera_shift is None else data.camera_shift[:, keep], still=None)


def _part_chi2(spec, part: FitData, start: np.ndarray) -> tuple[float, int]:
    """Chi-square and degrees of freedom of the model fitted to ``part`` from ``start`` (the whole record's
    parameters): Gauss-Newton steps, then a few Levenberg-Marquardt ones where those did not settle; a part's least
    chi-square or above it (a split is judged conservatively)."""
    white = Residuals(FitModel(spec), part)
    dof = white.informative_size - white.free
    if dof <= 0:
        raise FitError("too few frames for the model")
    with np.errstate(over="ignore", invalid="ignore"):
        r0 = white(start)
    if not np.all(np.isfinite(r0)):
        raise FitError("the model is not finite on this part")
    x, r, J = gauss_newton_polish(white, start, r0, white.jac(start), max_steps=PART_STEPS)
    if remaining_step_se(J, r) >= STATIONARY_STEP_SE:  # far from the part's minimum: damped steps, a few
        with np.errstate(over="ignore", invalid="ignore"):
            res = least_squares(white, x, jac=white.jac, method="lm", x_scale="jac", max_nfev=PART_LM_EVALUATIONS)
        if np.all(np.isfinite(res.fun)) and res.fun @ res.fun < r @ r:
            r = res.fun
    return float(r @ r), dof


def _split_cost(sol: Solution, data: FitData, i: int) -> tuple[float, int, float, float]:
    """Chi-square and degrees of freedom of the two parts split before frame ``i``, and each part's reduced
    chi-square (inf where a part cannot be fitted)."""
    out = []
    for part in (part_of(data, slice(0, i)), part_of(data, slice(i, data.n))):
        try:
            out.append(_part_chi2(sol.spec, part, sol.x))
        except (FitError, np.linalg.LinAlgError):
            return math.inf, 1, math.inf, math.inf
    (ca, da), (cb, db) = out
    return ca + cb, da + db, ca / da, cb / db


def find_break(sol: Solution, data: FitData) -> MotionBreak | None:
    """The record's break (module docstring), or None."""
    k = len(sol.x)
    lo = max(int(math.ceil(MIN_PART_SHARE * data.n)), 3 * k)
    hi = data.n - lo
    if hi <= lo:
        return None
    costs: dict[int, tuple] = {}

    def cost(i: int):
        if i not in costs:
            costs[i] = _split_cost(sol, data, i)
        return costs[i]

    def pooled(i: int) -> float:
        c = cost(i)
        return c[0] / max(c[1], 1)

    grid = np.unique(np.linspace(lo, hi, GRID).round().astype(int))
    best = int(min(grid, key=pooled))
    step = int(grid[1] - grid[0]) if len(grid) > 1 else 1
    while step > 1:  # refined to the frame about the best moment
        step = max(1, step // 4)
        around = range(max(lo, best - 4 * step), min(hi, best + 4 * step) + 1, step)
        best = int(min(around, key=pooled))
    chi2_split, dof_split, before, after = cost(best)
    if not (math.isfinite(chi2_split) and chi2_split > 0):
        return None
    whole = sol.chi2 / max(sol.dof, 1)
    split = chi2_split / dof_split
    f_stat = ((sol.chi2 - chi2_split) / k) / (chi2_split / dof_split)
    if f_dist.sf(f_stat, k, dof_split) > BREAK_P:
        return None
    if whole - split < EXCESS_SHARE * (whole - 1.0):
        return None
    if max(before, after) > split + PART_CHI2_RED_FRACTION * (whole - split):
        return None
    reach = int(round(SHARPNESS_SHARE * data.n))
    for j in (best - reach, best + reach):
        if lo <= j <= hi and pooled(j) < split + SHARPNESS_RISE * (whole - split):
            return None
    return MotionBreak(float(data.t_s[best - 1]), float(data.t_s[best]), whole, before, after, float(f_stat))
