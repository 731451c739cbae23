"""Error bars checked against a path of sinusoids over the whole record, where the local path cannot follow.

At a low frame rate for the motion (a phone's 30 frames/s for a top nodding at 5-10 turns per second) the tip
moves too far between frames for a path through a frame's six neighbours to predict it (module scatter), and
the record's check of the errors has nothing to go on.  The tip's path is still a sum of few sinusoids: a
precession, a nod and their combinations, their amplitudes changing slowly (damping).  Sampled at any rate a
sinusoid stays one (at its alias, or above the Nyquist frequency where the frame times scatter), so the whole record can be followed by a cubic and sinusoids whose amplitudes
change linearly along it, their frequencies found one by one from the residuals' Lomb-Scargle periodogram (both
axes; its peak refined to the least scatter) while each new one takes off more than noise would (an F test at
:data:`ADD_P`).  The residuals, each over
its error and the fit's share of it (``1 - h``, the hat matrix), then hold the errors' scatter: their RMS is the
factor by which the reported errors are off, as in module scatter.  The fit is trusted only where the search ended
because a further sinusoid took off no more than noise (not at :data:`MAX_FREQUENCIES` or
:data:`MAX_PARAMETER_SHARE` of the coordinates: a record too short for its motion) and its residuals are
uncorrelated from frame to frame (:data:`MAX_ACF` at lags 1-3, noise gives about 0): otherwise part of the motion
is left in them.  Frames off the path by more than :data:`~gyrorig.tracking.scatter.OUTLIER_Z` of the
scaled errors are outliers, left out of the fit and the factor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.signal import lombscargle
from scipy.stats import f as f_dist

from .scatter import OUTLIER_Z

__all__ = ["HarmonicCheck", "harmonic_check", "MAX_FREQUENCIES", "ADD_P", "MAX_ACF"]

#: the most sinusoids in the path
MAX_FREQUENCIES = 16
#: a sinusoid is added while the scatter it takes off would come from noise alone with at most this probability
ADD_P = 1e-3
#: the largest correlation of neighbouring frames' residuals (lags 1-3) with which the path is said to follow
MAX_ACF = 0.25
#: the path's parameters are at most this share of the coordinates
MAX_PARAMETER_SHARE = 0.3
#: the frequency grid's step, in turns over the record
GRID_STEP_TURNS = 0.1
#: the frequency grid's top, in Nyquist frequencies of the median frame interval: frames whose times scatter do not
#: alias a sinusoid above it onto one below (a nod's second harmonic at 30 frames/s)
GRID_TOP_NYQUIST = 2.0


@dataclass(frozen=True)
class HarmonicCheck:
    """The outcome of :func:`harmonic_check`: ``factor`` (RMS of the normalised residuals) and its standard error,
    the ``coordinates`` that entered, the ``outliers`` (indices), the sinusoids' angular frequencies [rad/s], the
    residuals' correlations at lags 1-3, whether the path ``follows`` the record (module docstring), and the same
    factor per class of frame ``{class: (factor, factor_se, coordinates)}``."""

    factor: float
    factor_se: float
    coordinates: int
    outliers: tuple[int, ...]
    omegas_rad_s: tuple[float, ...]
    residual_acf: tuple[float, ...]
    follows: bool
    by_class: dict
    #: whether the search for sinusoids ended on one that took off no more than noise (not on the limits)
    converged: bool = True


def _design(tau: np.ndarray, omegas) -> np.ndarray:
    """A cubic in ``tau`` (scaled to +-1) and per frequency a cosine and a sine whose amplitudes change linearly."""
    u = tau / max(float(np.abs(tau).max()), 1e-12)
    cols = [u**k for k in range(4)]
    for w in omegas:
        c, s = np.cos(w * tau), np.sin(w * tau)
        cols += [c, s, u * c, u * s]
    return np.stack(cols, axis=1)


def _fit(tau, xy, sd, omegas):
    """Weighted least squares of both axes on :func:`_design`: residuals, leverages (n, 2) and the weighted sum of
    squares."""
    a = _design(tau, omegas)
    res, lev = np.empty_like(xy), np.empty_like(xy)
    for k in range(2):
        aw = a / sd[:, k, None]
        q, _ = np.linalg.qr(aw)
        bw = xy[:, k] / sd[:, k]
        res[:, k] = (bw - q @ (q.T @ bw)) * sd[:, k]
        lev[:, k] = np.sum(q * q, axis=1)
    return res, lev, float(np.sum((res / sd) ** 2)), a.shape[1]


def _acf(z: np.ndarray, frames: np.ndarray, lags=(1, 2, 3)) -> tuple[float, ...]:
    """Correlations of ``z`` (n, 2) between frames ``lag`` apart (both axes pooled)."""
    out = []
    pos = {int(f): i for i, f in enumerate(frames)}
    for lag in lags:
        pairs = np.array([(i, pos[int(f) + lag]) for i, f in enumerate(frames) if int(f) + lag in pos], int)
        if len(pairs) < 10:
            out.append(math.nan)
            continue
        a, b = z[pairs[:, 0]].ravel(), z[pairs[:, 1]].ravel()
        out.append(float(np.sum(a * b) / math.sqrt(np.sum(a * a) * np.sum(b * b))))
    return tuple(out)


def harmonic_check(t_s, frames, xy, var, classes=None) -> HarmonicCheck | None:
    """Check the errors ``var`` (n, 2) [px^2] of the positions ``xy`` (n, 2) at ``t_s`` (frame numbers ``frames``)
    against a path of sinusoids over the whole record (module docstring), overall and per label of ``classes``
    (n,).  None with too few frames for it."""
    t_s, frames = np.asarray(t_s, float), np.asarray(frames, int)
    xy, sd = np.asarray(xy, float), np.sqrt(np.asarray(var, float))
    n = len(t_s)
    if n < 40:
        return None
    tau = t_s - t_s.mean()
    span = float(np.ptp(tau))
    dt = float(np.median(np.diff(np.sort(t_s))))
    if not (span > 0 and dt > 0):
        return None
    grid = np.arange(GRID_STEP_TURNS, GRID_TOP_NYQUIST * span / (2 * dt), GRID_STEP_TURNS) * 2 * math.pi / span
    keep = np.ones(n, bool)
    omegas: list[float] = []
    for attempt in range(2):  # once with every frame, once without the outliers the first pass found
        omegas = []
        res, lev, rss, p = _fit(tau[keep], xy[keep], sd[keep], omegas)
        converged = False  # True once a further sinusoid takes off no more than noise would
        while len(omegas) < MAX_FREQUENCIES and p + 4 <= MAX_PARAMETER_SHARE * keep.sum():
            power = sum(lombscargle(tau[keep], res[:, k] / sd[keep, k], grid, floating_mean=True) for k in range(2))
            peak, step = float(grid[int(np.argmax(power))]), float(grid[1] - grid[0])
            best = minimize_scalar(lambda w: _fit(tau[keep], xy[keep], sd[keep], omegas + [w])[2],
                                   bounds=(peak - step, peak + step), method="bounded", options={"xatol": step / 100})
            trial = omegas + [float(best.x)]
            res_t, lev_t, rss_t, p_t = _fit(tau[keep], xy[keep], sd[keep], trial)
            dof = 2 * (keep.sum() - p_t)
            gain = (rss - rss_t) / (2 * (p_t - p)) / (rss_t / dof)
            if not f_dist.sf(gain, 2 * (p_t - p), dof) < ADD_P:
                converged = True
                break
            omegas, res, lev, rss, p = trial, res_t, lev_t, rss_t, p_t
        z = res / (sd[keep] * np.sqrt(np.clip(1.0 - lev, 1e-3, None)))
        off = np.abs(z).max(axis=1) > OUTLIER_Z * 1.4826 * float(np.median(np.abs(z)))
        if attempt or not off.any():
            break
        keep[np.flatnonzero(keep)[off]] = False
    labels = np.asarray(classes if classes is not None else np.zeros(n, int))[keep]
    by_class = {}
    for label in np.unique(labels):
        zc = z[labels == label]
        f = float(np.sqrt(np.mean(zc * zc)))
        by_class[label.item()] = (f, f / math.sqrt(2 * zc.size), int(zc.size))
    factor = float(np.sqrt(np.mean(z * z)))
    m = int(z.size)
    acf = _acf(z, frames[keep])
    follows = converged and bool(all(math.isfinite(a) and abs(a) <= MAX_ACF for a in acf))
    return HarmonicCheck(factor, factor / math.sqrt(2 * m), m, tuple(int(i) for i in np.flatnonzero(~keep)),
                         tuple(omegas), acf, follows, by_class if classes is not None else {}, converged)
