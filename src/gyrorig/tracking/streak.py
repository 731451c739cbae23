"""Where a marker moving during a long exposure has drawn a streak instead of a round spot: the start of the
streak fit of :func:`gyrorig.tracking.scene_spot.fit_scene_spot` (the disc's coverage averaged along its path during
the exposure)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..camera import Camera
from .spot import spot_window

__all__ = ["streak_start", "STREAK_ELONGATION", "MAX_STREAK_RADII"]

#: a bright region longer than this times its width is fitted as a streak
STREAK_ELONGATION = 1.3
#: streaks up to this many tip radii long are looked for
MAX_STREAK_RADII = 6.0


def streak_start(image: np.ndarray, x0: float, y0: float, r0: float, cam: Camera, blur_max_px: float) -> tuple | None:
    """Where a streak lies: ``(x, y, vx, vy)`` from the moments of the bright region about ``(x0, y0)`` (above
    half-way from the window's border median to its 99th percentile, the part holding the pixel nearest
    ``(x0, y0)``): its centroid, and its long axis with the length a segment of that spread has beside the
    short axis' (``sqrt(12 (l1 - l2))``).  None when the region is not longer than :data:`STREAK_ELONGATION`
    times its width (a round spot), reaches the window's edge (spots up to :data:`MAX_STREAK_RADII` tip radii
    long and ``blur_max_px`` of blur are looked for) or is not there."""
    half = int(math.ceil(r0 * (1.3 + 0.5 * MAX_STREAK_RADII) + 3.0 * blur_max_px + 4))
    window = spot_window(image, x0, y0, half, cam)
    if window is None:
        return None
    win, xx, yy, _, _, background, amplitude = window
    mask = (win > background + 0.5 * amplitude).astype(np.uint8)
    count, labels = cv2.connectedComponents(mask, connectivity=8)
    if count < 2:
        return None
    on = np.argwhere(labels > 0)
    near = on[np.argmin((on[:, 0] - (y0 - yy[0, 0])) ** 2 + (on[:, 1] - (x0 - xx[0, 0])) ** 2)]
    part = labels == labels[near[0], near[1]]
    if part[0].any() or part[-1].any() or part[:, 0].any() or part[:, -1].any() or part.sum() < 5:
        return None
    px, py = xx[part], yy[part]
    (l2, l1), vectors = np.linalg.eigh(np.cov(np.vstack([px, py])))
    if not l1 > STREAK_ELONGATION ** 2 * max(l2, 1e-12):
        return None
    length = math.sqrt(12.0 * (l1 - l2))
    return float(px.mean()), float(py.mean()), float(length * vectors[0, 1]), float(length * vectors[1, 1])
