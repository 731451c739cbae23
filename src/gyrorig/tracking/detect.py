"""Detection: bright blobs in a window, as start points for the spot fits."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["find_blobs", "detection_threshold"]


def detection_threshold(image: np.ndarray) -> tuple[float, float]:
    """Background level and noise of a frame (from every 8th pixel), and the blob threshold above them.

    Returns ``(threshold, noise_sigma)`` [ADU]: the threshold is 8 noise sigmas (at least 4 ADU)
    above the median.
    """
    sample = image[::8, ::8]
    bg_level = float(np.median(sample))
    noise_sigma = max(float(np.std(sample[sample < bg_level + 20])), 0.5)
    return bg_level + max(8.0 * noise_sigma, 4.0), noise_sigma


def find_blobs(image: np.ndarray, x0: int, y0: int, x1: int, y1: int, threshold: float
               ) -> list[tuple[float, float, float]]:
    """Bright blobs in the window ``[x0, x1) x [y0, y1)``: ``(cx, cy, radius)`` of each blob's largest
    inscribed circle [px].

    The maximum of the distance transform finds the centre of the largest disc in a blob,
    so a spot merged with a smaller neighbour still starts the fit at the right place.
    Blobs of fewer than 3 pixels are ignored.
    """
    sub = image[y0:y1, x0:x1]
    mask = (sub > threshold).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    out = []
    for i in range(1, n):
        if stats[i, cv2.CC_STAT_AREA] < 3:
            continue
        bx, by = stats[i, cv2.CC_STAT_LEFT], stats[i, cv2.CC_STAT_TOP]
        bw, bh = stats[i, cv2.CC_STAT_WIDTH], stats[i, cv2.CC_STAT_HEIGHT]
        blob = np.pad((labels[by:by + bh, bx:bx + bw] == i).astype(np.uint8), 1)
        dist = cv2.distanceTransform(blob, cv2.DIST_L2, 5)
        iy, ix = np.unravel_index(int(np.argmax(dist)), dist.shape)
        out.append((float(bx + ix - 1 + x0), float(by + iy - 1 + y0), float(dist[iy, ix]) + 0.5))
    return out
