"""The edge of a disc fitted in front of a scene (:mod:`gyrorig.tracking.scene_spot`), in the ring's angular bins: where
it lies along each bin's ray (:func:`_edge_radii`) and what its departures from a circle say of the centre
(:func:`_edge_roughness`); and the ring's bins where part of it lies beyond the image (:func:`fill_empty_bins`,
:func:`on_image_bins`)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .small_solve import lu_solve

__all__ = ["ANGLE_BINS", "RING_WIDTH_PX", "fill_empty_bins", "on_image_bins"]

#: angular bins of the ring that gives the scene behind the disc's edge
ANGLE_BINS = 32
#: the ring's radial width [px]
RING_WIDTH_PX = 2.0
#: the edge's departures from a circle are read from its harmonics up to this order (:func:`_edge_roughness`)
EDGE_HARMONICS = 5
#: ... where at least this fraction of the bins has an edge point
MIN_ARC_FRACTION = 0.5


@njit(cache=True)
def _bin_of(dx, dy):
    """The angular bin of the direction ``(dx, dy)`` (bins of :data:`ANGLE_BINS` from ``-pi``)."""
    return int((math.atan2(dy, dx) + math.pi) / (2 * math.pi) * ANGLE_BINS) % ANGLE_BINS


_BIN_ANGLES = -math.pi + (np.arange(ANGLE_BINS) + 0.5) * (2 * math.pi / ANGLE_BINS)


@njit(cache=True)
def _bilinear(win, x, y):
    """The window's value at ``(x, y)`` (its own pixel coordinates), bilinear, the edge pixels repeated beyond it."""
    h, w = win.shape
    x = min(max(x, 0.0), w - 1.0)
    y = min(max(y, 0.0), h - 1.0)
    ix, iy = min(int(x), w - 2), min(int(y), h - 2)
    fx, fy = x - ix, y - iy
    return ((1 - fy) * ((1 - fx) * win[iy, ix] + fx * win[iy, ix + 1])
            + fy * ((1 - fx) * win[iy + 1, ix] + fx * win[iy + 1, ix + 1]))


@njit(cache=True)
def _edge_radii(win, cx, cy, r, blur, marker_level, bins, gap_sigmas):
    """Where the edge lies in each angular bin: along the ray from the window's point ``(cx, cy)`` through the
    bin's centre angle, the first radius at which the image falls below half-way between the marker's level and
    that bin's ring (bilinear samples 0.25 px apart, from ``r - 4 sigma`` out to the ring's outer edge, ``gap_sigmas``
    sigmas and :data:`RING_WIDTH_PX` beyond the edge; linear
    between samples).  ``+inf`` where it never falls that far (light beyond the disc), ``-inf`` where it starts
    below (something in front of the disc)."""
    start = max(r - 4.0 * blur, 0.3 * r)
    n = int(math.ceil((r + gap_sigmas * blur + RING_WIDTH_PX - start) / 0.25))
    out = np.full(ANGLE_BINS, np.inf)
    for b in range(ANGLE_BINS):
        c, s = math.cos(_BIN_ANGLES[b]), math.sin(_BIN_ANGLES[b])
        level = 0.5 * (marker_level + bins[b])
        before = _bilinear(win, cx + c * start, cy + s * start)
        if before < level:
            out[b] = -np.inf
            continue
        for j in range(1, n):
            rad = start + 0.25 * j
            v = _bilinear(win, cx + c * rad, cy + s * rad)
            if v < level:
                out[b] = rad - 0.25 + 0.25 * (before - level) / max(before - v, 1e-12)
                break
            before = v
    return out


#: the harmonic basis of :func:`_edge_roughness` at the bins' angles: 1, cos(n a), sin(n a) for n = 1..EDGE_HARMONICS
_HARMONICS = np.column_stack([np.ones(ANGLE_BINS)] + [f(n * _BIN_ANGLES) for n in range(1, EDGE_HARMONICS + 1)
                                                      for f in (np.cos, np.sin)])


@njit(cache=True)
def _residual_sum(radii, good, m):
    """The residual sum of squares of the finite ``radii`` (``good``) about their least-squares fit on the first
    ``m`` columns of :data:`_HARMONICS` (by its normal equations); NaN when that cannot be solved."""
    a = np.zeros((m, m))
    rhs = np.zeros(m)
    for b in range(ANGLE_BINS):
        if good[b]:
            for i in range(m):
                rhs[i] += _HARMONICS[b, i] * radii[b]
                for j in range(m):
                    a[i, j] += _HARMONICS[b, i] * _HARMONICS[b, j]
    coef, ok = lu_solve(a, rhs)
    if not ok:
        return math.nan
    total = 0.0
    for b in range(ANGLE_BINS):
        if good[b]:
            model = 0.0
            for i in range(m):
                model += _HARMONICS[b, i] * coef[i]
            total += (radii[b] - model) ** 2
    return total


@njit(cache=True)
def _harmonic_power(radii):
    """The mean power per coefficient of harmonics 2 to :data:`EDGE_HARMONICS` of the finite ``radii``: twice the
    sum of squares they explain beyond the circle (harmonics 0 and 1), per coefficient and per bin.  On the whole
    circle of bins this is the mean of their squared coefficients; on an arc (bins without an edge point) the
    harmonics are not orthogonal and their coefficients would take up the noise many times over, while what they
    explain stays what the edge departs from a circle by.  NaN when fewer than :data:`MIN_ARC_FRACTION` of the bins
    are finite."""
    good = np.isfinite(radii)
    n = np.count_nonzero(good)
    if n < MIN_ARC_FRACTION * ANGLE_BINS:
        return math.nan
    m = _HARMONICS.shape[1]
    explained = _residual_sum(radii, good, 3) - _residual_sum(radii, good, m)
    return 2.0 * max(explained, 0.0) / ((m - 3) * n)


@njit(cache=True)
def _edge_roughness(win, cx, cy, p, bins, kept, top, gap_sigmas):
    """The variance [px^2] per axis of the centre (at the window's point ``(cx, cy)``) that the edge's own departures
    from a circle imply: the edge points (:func:`_edge_radii`) as a Fourier series in angle, whose first harmonic is a
    shift of the centre and is therefore absorbed by the fit; its unseen power is taken as the mean power per
    coefficient of harmonics 2 to :data:`EDGE_HARMONICS`.  Noise independent from bin to bin gives ``2 var / bins``
    (what the pixels' own covariance already holds); a bump of another spot's light merged with the edge, a bulge of
    texture under it or something in front of the disc spread over neighbouring harmonics and give what they shift the
    centre by.  NaN when fewer than half the bins have an edge point.

    Only the ``kept`` bins have an edge point (a dark object's edge, whose sectors are left out of the fit, would
    bend it; another spot's light merged with the edge is what this looks for).  A saturated marker's edge is where
    the image falls half-way from full scale ``top``, its level as far as it is seen."""
    radii = _edge_radii(win, cx, cy, p[2], p[4], min(p[3], top), bins, gap_sigmas)
    for b in range(ANGLE_BINS):
        if not kept[b]:
            radii[b] = np.nan
    return _harmonic_power(radii)


@njit(cache=True)
def fill_empty_bins(bins, counts):
    """The ring's bins without a pixel (``counts`` 0: beyond the image) set, in place, to the line in angle between
    the nearest bins with pixels on either side."""
    n = bins.size
    for b in range(n):
        if counts[b] > 0:
            continue
        lo, hi = 1, 1
        while counts[(b - lo) % n] == 0:
            lo += 1
        while counts[(b + hi) % n] == 0:
            hi += 1
        bins[b] = (hi * bins[(b - lo) % n] + lo * bins[(b + hi) % n]) / (lo + hi)


def on_image_bins(shape: tuple[int, int], x_first: float, y_first: float, cx: float, cy: float,
                  r_out: float) -> np.ndarray:
    """Which of the ring's bins about ``(cx, cy)`` (from ``r_out``) have the middle of their arc inside the window of
    ``shape`` whose first column and row are at ``x_first, y_first``."""
    rad = r_out + RING_WIDTH_PX / 2
    x = cx + rad * np.cos(_BIN_ANGLES) - x_first
    y = cy + rad * np.sin(_BIN_ANGLES) - y_first
    return (x >= 0) & (x <= shape[1] - 1) & (y >= 0) & (y <= shape[0] - 1)
