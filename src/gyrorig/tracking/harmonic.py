"""Error bars checked against a path of sinusoids over the whole record, where the local path cannot follow.

At a low frame rate for the motion (a phone's 30 frames/s for a top nodding at 5-10 turns per second) the tip
moves too far between frames for a path through a frame's six neighbours to predict it (module scatter), and
the record's check of the errors has nothing to go on.  The tip's path is still a sum of few sinusoids: a
precession, a nod and their combinations, their amplitudes changing slowly (damping).  Sampled at any rate a
sinusoid stays one (at its alias, or above the Nyquist frequency where the frame times scatter), so the whole record can be followed by a cubic and sinusoids whose amplitudes
change linearly along it, their frequencies found one by one from the residuals' Lomb-Scargle periodogram (both
axes, by FFT: :class:`Periodogram`; its peak refined to the least scatter) while each new one takes off more than noise would (an F test at
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
from scipy.fft import next_fast_len, rfft
from scipy.optimize import minimize_scalar
from scipy.stats import f as f_dist

from .scatter import OUTLIER_Z

__all__ = ["HarmonicCheck", "harmonic_check", "Periodogram", "MAX_FREQUENCIES", "ADD_P", "MAX_ACF"]

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
#: terms of the Taylor series that carries each frame time's offset from the FFT's time grid (at most pi/4 of a
#: turn of the highest frequency: the terms left out are below 1e-13 of the sums)
TAYLOR_TERMS = 14


def _trig_sums(t: np.ndarray, c: np.ndarray, d_omega: float, m: int) -> np.ndarray:
    """``sum_k c[k, q] exp(-i j d_omega t[k])`` for ``j = 0..m`` (rows) and each column ``q`` of ``c`` (n, q), in
    O(n + m log m): FFTs of ``c`` times powers of each time's offset from a grid of ``2 pi / (d_omega L)`` steps
    (``L >= 4 m``, so that ``j d_omega`` times an offset of at most half a step stays within pi/4)."""
    size = next_fast_len(4 * m + 4, real=True)
    u = t * (d_omega * size / (2 * math.pi))
    cell = np.rint(u)
    offset, index = u - cell, cell.astype(np.int64) % size  # exp(-2 pi i j cell / L) has period L in cell
    phase = -2j * math.pi * np.arange(m + 1) / size  # per unit of offset at frequency j
    sums = np.zeros((m + 1, c.shape[1]), complex)
    term, weight = c.astype(float), np.ones(m + 1, complex)
    for p in range(TAYLOR_TERMS):
        spread = np.stack([np.bincount(index, weights=term[:, q], minlength=size) for q in range(c.shape[1])], 1)
        sums += weight[:, None] * rfft(spread, axis=0)[: m + 1]
        term, weight = term * offset[:, None], weight * phase / (p + 1)
    return sums


class Periodogram:
    """The floating-mean Lomb-Scargle periodogram of values at times ``t_s`` at the angular frequencies ``(j + 1)
    d_omega``, ``j < m``: for each, the least-squares fit of a constant, a cosine and a sine, and the scatter it takes
    off beyond the constant's, in :func:`scipy.signal.lombscargle`'s units (``floating_mean=True``; ``n / 2`` times
    the mean square taken off).  Its sums over the frames come from :func:`_trig_sums`, those of the times alone
    (which every set of values shares) made once: O(n + m log m) a set of values, where the direct sums are O(n m)
    (a record of 10,000 frames: 100,000 frequencies)."""

    def __init__(self, t_s, d_omega: float, m: int):
        t = np.asarray(t_s, float)
        self.t, self.d_omega, self.m, self.n = t - t.min(), float(d_omega), int(m), len(t)
        ones = _trig_sums(self.t, np.ones((self.n, 1)), self.d_omega, 2 * self.m)[:, 0] / self.n
        one, two = ones[1 : self.m + 1], ones[2 : 2 * self.m + 1 : 2]
        self.c, self.s = one.real, -one.imag
        cc = (1 + two.real) / 2 - self.c**2
        ss = (1 - two.real) / 2 - self.s**2
        cs = -two.imag / 2 - self.c * self.s
        # turned by the angle that makes the cosine and sine columns uncorrelated (scipy's tau), as scipy does
        turn = 0.5 * np.arctan2(2 * cs, cc - ss)
        self.cos, self.sin = np.cos(turn), np.sin(turn)
        eps = np.finfo(float).epsneg
        self.cc = np.maximum(cc * self.cos**2 + 2 * cs * self.sin * self.cos + ss * self.sin**2, eps)
        self.ss = np.maximum(cc * self.sin**2 - 2 * cs * self.sin * self.cos + ss * self.cos**2, eps)

    def power(self, values) -> np.ndarray:
        """The periodogram (m,) of ``values`` (n,), or the sum of those of each column of ``values`` (n, q)."""
        y = np.asarray(values, float).reshape(self.n, -1)
        sums = _trig_sums(self.t, y, self.d_omega, self.m)[1:] / self.n
        mean = y.mean(axis=0)
        yc = sums.real - mean * self.c[:, None]
        ys = -sums.imag - mean * self.s[:, None]
        yc, ys = yc * self.cos[:, None] + ys * self.sin[:, None], ys * self.cos[:, None] - yc * self.sin[:, None]
        return self.n / 2 * np.sum(yc**2 / self.cc[:, None] + ys**2 / self.ss[:, None], axis=1)


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
    (n,); frames without a finite position are left out of it (and are no outliers).  None with too few frames for
    it."""
    t_s, frames = np.asarray(t_s, float), np.asarray(frames, int)
    xy, sd = np.asarray(xy, float), np.sqrt(np.asarray(var, float))
    n = len(t_s)
    usable = np.all(np.isfinite(xy), axis=1) & np.all(np.isfinite(sd), axis=1)
    if usable.sum() < 40:
        return None
    tau = t_s - t_s.mean()
    span = float(np.ptp(tau))
    dt = float(np.median(np.diff(np.sort(t_s))))
    if not (span > 0 and dt > 0):
        return None
    d_omega = GRID_STEP_TURNS * 2 * math.pi / span
    grid = np.arange(1, math.ceil(GRID_TOP_NYQUIST * span / (2 * dt) / GRID_STEP_TURNS)) * d_omega  # below the top
    keep = usable.copy()
    omegas: list[float] = []
    for attempt in range(2):  # once with every frame, once without the outliers the first pass found
        omegas = []
        res, lev, rss, p = _fit(tau[keep], xy[keep], sd[keep], omegas)
        converged = False  # True once a further sinusoid takes off no more than noise would
        periodogram = Periodogram(tau[keep], d_omega, len(grid))
        while len(omegas) < MAX_FREQUENCIES and p + 4 <= MAX_PARAMETER_SHARE * keep.sum():
            power = periodogram.power(res / sd[keep])
            peak, step = float(grid[int(np.argmax(power))]), d_omega
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
    return HarmonicCheck(factor, factor / math.sqrt(2 * m), m, tuple(int(i) for i in np.flatnonzero(usable & ~keep)),
                         tuple(omegas), acf, follows, by_class if classes is not None else {}, converged)
