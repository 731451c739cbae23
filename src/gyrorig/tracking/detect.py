"""Detection: spots brighter than their surroundings, as start points for the spot fits.

A real frame is bright, textured and unevenly lit, so a spot is judged by its **local contrast**, not
by its level: the image minus its grey-scale opening by a square larger than any marker (the opening
removes every bright structure that the square cannot fit inside, and keeps the background's slow
variations, edges and all).  The threshold is a number of robust standard deviations (1.4826 x the
median absolute deviation) of that contrast over the frame, so a textured background raises it only as
far as its texture reaches, and it never depends on the frame's brightness.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from numba import njit

__all__ = ["Detection", "Blob", "find_blobs", "stands_out", "detection_threshold", "local_contrast", "opening_size_px",
           "THRESHOLD_SIGMAS", "PEAK_FRACTION"]

#: a spot's local contrast must exceed the contrast's median by this many of its robust standard deviations
THRESHOLD_SIGMAS = 5.0
#: ... but at most this fraction of the frame's highest local contrast
PEAK_FRACTION = 0.5
#: a blob wider than the widest spot looked for (after its cut at half its peak, where made) is cut at this fraction of
#: its peak
SECOND_CUT = 0.75
#: what lies under a blob's cut is searched for spots of its own only this far [px] (or the widest spot looked for, if
#: less) from the parts the cut kept
NEAR_KEPT_PX = 12.0


@dataclass(frozen=True)
class Detection:
    """How spots are told from the background in a frame: ``threshold`` on the local contrast [ADU]
    (:func:`local_contrast` with an opening of side ``scale_px``), ``noise`` the contrast's robust SD [ADU]."""

    threshold: float
    noise: float
    scale_px: int


class Blob(NamedTuple):
    """A detected spot: centre and radius of its largest inscribed circle [px], its peak contrast [ADU]."""

    x: float
    y: float
    r: float
    peak: float


def opening_size_px(largest_radius_px: float, psf_sigma_px: float) -> int:
    """The opening's square side [px]: odd, wider than a spot of ``largest_radius_px`` with its blur."""
    return 2 * int(math.ceil(largest_radius_px + 2.0 * psf_sigma_px + 1.0)) + 1


#: images of up to this many pixels (the tracker's windows) are opened by the compiled :func:`_square_opening`, larger
#: ones (a whole frame) by OpenCV, whose window over wide rows is the faster there; the two give the same values
_COMPILED_UP_TO = 250_000


@njit(cache=True)
def _running_min(src: np.ndarray, size: int) -> np.ndarray:
    """The minimum of ``src`` (2-D float32) over ``size`` (odd) consecutive rows, in each column, the first and last
    rows repeated beyond the ends (a window reaching past an end is cut there): van Herk's and Gil and Werman's
    method, three comparisons a value whatever the size, each step over a whole row at once."""
    n, cols = src.shape
    h = size // 2
    m = ((n + 2 * h + size - 1) // size) * size
    ahead = np.empty((m, cols), np.float32)  # the minimum from each block's first row down to this row
    behind = np.empty((m, cols), np.float32)  # ... from this row down to its block's last row
    for j in range(m):
        row = src[min(max(j - h, 0), n - 1)]
        if j % size == 0:
            ahead[j] = row
        else:
            for c in range(cols):
                ahead[j, c] = min(ahead[j - 1, c], row[c])
    for j in range(m - 1, -1, -1):
        row = src[min(max(j - h, 0), n - 1)]
        if j % size == size - 1:
            behind[j] = row
        else:
            for c in range(cols):
                behind[j, c] = min(behind[j + 1, c], row[c])
    out = np.empty((n, cols), np.float32)
    for i in range(n):
        for c in range(cols):
            out[i, c] = min(behind[i, c], ahead[i + size - 1, c])
    return out


@njit(cache=True)
def _square_opening(image: np.ndarray, size: int) -> np.ndarray:
    """The grey-scale opening of ``image`` (2-D float32) by a ``size`` square (odd), the image's edge values repeated
    beyond it: erosion (the minimum over the square, down the columns then along the rows), then dilation of that
    (the maximum: the minimum of the values turned over, exact in floating point)."""
    turned_t = -_running_min(_running_min(image, size).T.copy(), size)  # the erosion turned over, transposed
    return -_running_min(_running_min(turned_t, size).T.copy(), size)


def local_contrast(image: np.ndarray, scale_px: int) -> np.ndarray:
    """``image`` minus its grey-scale opening by a ``scale_px`` square (``scale_px`` odd, as
    :func:`opening_size_px` gives; float32; 0 where nothing narrower than the square stands out), the image's edge
    values repeated beyond it."""
    if scale_px % 2 == 0:
        raise ValueError(f"scale_px must be odd, got {scale_px}")
    image = np.asarray(image)
    if image.size > _COMPILED_UP_TO:  # OpenCV's window over wide rows (SIMD) is the faster there
        img = image if image.dtype in (np.uint8, np.uint16, np.float32) else image.astype(np.float32)
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (scale_px, scale_px))
        opened = cv2.morphologyEx(img, cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_REPLICATE)
        return cv2.subtract(img, opened).astype(np.float32, copy=False)
    img = np.ascontiguousarray(image, dtype=np.float32)
    return img - _square_opening(img, int(scale_px))


@functools.lru_cache(maxsize=16)
def _near_kept_kernel(reach_px: float) -> np.ndarray:
    """The disc (OpenCV's ellipse of odd size ``2 ceil(reach_px) + 1``) within which a part below a cut belongs to the
    part kept above it (:func:`_components`)."""
    size = 2 * int(math.ceil(reach_px)) + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def _components(sub: np.ndarray, mask: np.ndarray, x0: int, y0: int, min_radius_px: float, out: list,
                split_above: float | None, max_radius_px: float = math.inf, cut: float = 0.5) -> None:
    """The blobs of ``mask`` (in window coordinates offset by ``x0, y0``), appended to ``out``.  A large blob
    whose peak contrast exceeds ``split_above`` is cut again at half its peak (a bright spot joined to a
    texture's faint network, a mortar line or a rim, by a low threshold stands apart at half its height), and what
    lies below the cut is searched again in the same way (a fainter spot joined to it stands apart there); a blob
    wider than ``max_radius_px`` (its inscribed circle; after that cut, where made) is cut once more at
    :data:`SECOND_CUT` of its peak (a spot joined to a bright patch of the scene that stands out half as much)."""
    min_area = max(3.0, math.pi * min_radius_px * min_radius_px)
    binary = np.ascontiguousarray(mask).view(np.uint8) if mask.dtype == np.bool_ else mask.astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    for i in range(1, n):
        bx, by = stats[i, cv2.CC_STAT_LEFT], stats[i, cv2.CC_STAT_TOP]
        bw, bh = stats[i, cv2.CC_STAT_WIDTH], stats[i, cv2.CC_STAT_HEIGHT]
        if stats[i, cv2.CC_STAT_AREA] < min_area or min(bw, bh) < 2.0 * min_radius_px - 1.0:
            continue
        own = labels[by:by + bh, bx:bx + bw] == i
        values = sub[by:by + bh, bx:bx + bw]
        peak = float(values[own].max())
        if split_above is not None and peak > split_above and stats[i, cv2.CC_STAT_AREA] > 4 * min_area + 50:
            above = values > cut * peak
            kept = own & above
            _components(values, kept, x0 + bx, y0 + by, min_radius_px, out, None, max_radius_px, cut)
            # what the cut left, away from what it kept, may hold a fainter spot of its own (a white tip on a white
            # table joined to a crossbar dot on a dark rotor): searched in the same way, each part cut at half its own
            # peak; beside a kept part (its halo, or a spot merged with it) it is that part's (no blob of the
            # smallest area fits in what lies below the cut: nothing to search)
            if np.count_nonzero(own) - np.count_nonzero(kept) < min_area:
                continue
            near = cv2.dilate(above.view(np.uint8), _near_kept_kernel(min(max_radius_px, NEAR_KEPT_PX)))
            _components(values, own & (near == 0), x0 + bx, y0 + by, min_radius_px, out, split_above, max_radius_px,
                        cut)
            continue
        blob = cv2.copyMakeBorder(own.astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
        dist = cv2.distanceTransform(blob, cv2.DIST_L2, 5)
        iy, ix = np.unravel_index(int(np.argmax(dist)), dist.shape)
        radius = float(dist[iy, ix]) + 0.5
        if radius > max_radius_px and cut < SECOND_CUT:
            _components(values, own & (values > SECOND_CUT * peak), x0 + bx, y0 + by, min_radius_px, out, None,
                        max_radius_px, SECOND_CUT)
            continue
        out.append(Blob(float(bx + ix - 1 + x0), float(by + iy - 1 + y0), radius, peak))


def detection_threshold(image: np.ndarray, scale_px: int, *, floor: float = 4.0) -> Detection:
    """The frame's :class:`Detection`: :data:`THRESHOLD_SIGMAS` robust SDs of the local contrast above its
    median (at least ``floor`` ADU), but never above :data:`PEAK_FRACTION` of the frame's highest contrast (a
    texture as rough as the marker is bright, e.g. sunlit gravel, would hide it otherwise; the follower then
    tells the marker by its size, shape and motion).  The contrast is taken over every 2nd pixel."""
    contrast = local_contrast(image, scale_px)[::2, ::2]
    med = float(np.median(contrast))
    noise = max(1.4826 * float(np.median(np.abs(contrast - med))), 0.5)
    level = min(med + max(THRESHOLD_SIGMAS * noise, floor), PEAK_FRACTION * float(contrast.max()))
    return Detection(max(level, floor), noise, scale_px)


def find_blobs(image: np.ndarray, x0: int, y0: int, x1: int, y1: int, threshold: Detection | float, *,
               min_radius_px: float = 0.0, max_radius_px: float = math.inf) -> list[Blob]:
    """Spots in the window ``[x0, x1) x [y0, y1)``, brightest first: each blob's largest inscribed circle and
    its peak contrast.

    With a :class:`Detection` the local contrast is thresholded (the window is widened by the opening's
    size so that the contrast at its edges is the frame's); with a number, the pixel values themselves
    (for a static image of known flat background).  The maximum of the distance transform finds the centre
    of the largest disc in a blob, so a spot merged with a smaller neighbour still starts the fit at the
    right place.  Blobs of fewer than 3 pixels are ignored, and those too small to hold a disc of
    ``min_radius_px`` (by area or by extent: a texture's specks and lines).  A large contrast blob whose peak
    is more than twice the threshold is cut again at half its peak, and one still wider than ``max_radius_px`` once
    more higher up (:func:`_components`).
    """
    h, w = image.shape
    if isinstance(threshold, Detection):
        m = threshold.scale_px
        ax0, ay0, ax1, ay1 = max(x0 - m, 0), max(y0 - m, 0), min(x1 + m, w), min(y1 + m, h)
        if ax1 - ax0 < 3 or ay1 - ay0 < 3:
            return []
        sub = local_contrast(image[ay0:ay1, ax0:ax1], m)[y0 - ay0:y1 - ay0, x0 - ax0:x1 - ax0]
        level = threshold.threshold
    else:
        sub = image[y0:y1, x0:x1]
        level = float(threshold)
    if sub.size == 0:
        return []
    out: list[Blob] = []
    # contrast blobs twice the threshold are split at half their peak; raw levels are not (a background under them)
    _components(sub, sub > level, x0, y0, min_radius_px, out, 2.0 * level if isinstance(threshold, Detection) else None,
                max_radius_px)
    out.sort(key=lambda b: -b.peak)
    return out


def stands_out(fit, threshold: Detection | float) -> bool:
    """Whether a fitted spot (:class:`~gyrorig.tracking.spot.SpotFit`) would be detected: its contrast above the
    background beyond a :class:`Detection`'s threshold, or its level beyond a raw level (:func:`find_blobs`)."""
    if isinstance(threshold, Detection):
        return fit.amplitude_adu > threshold.threshold
    return fit.amplitude_adu + fit.background_adu > float(threshold)
