"""Drawing a marker's expected electrons into the image, sub-exposure sample by sample (motion blur)."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erfc

__all__ = ["draw_sphere"]


def draw_sphere(acc: np.ndarray, px: np.ndarray, radius: np.ndarray, vis: np.ndarray, peak_e: float,
               sigma: float) -> tuple[int, int, int, int] | None:
    """Add the spot's expected electrons (sum over visible sub-samples) into ``acc``; return its window."""
    if not vis.any():
        return None
    p, r = px[vis], radius[vis]
    reach = float(r.max()) + 5.0 * sigma + 1.0
    h, w = acc.shape
    x0 = max(int(math.floor(p[:, 0].min() - reach)), 0)
    x1 = min(int(math.ceil(p[:, 0].max() + reach)) + 1, w)
    y0 = max(int(math.floor(p[:, 1].min() - reach)), 0)
    y1 = min(int(math.ceil(p[:, 1].max() + reach)) + 1, h)
    if x1 <= x0 or y1 <= y0:
        return None
    xs = np.arange(x0, x1, dtype=np.float64)
    ys = np.arange(y0, y1, dtype=np.float64)
    dist = np.sqrt((xs[None, None, :] - p[:, 0, None, None]) ** 2 + (ys[None, :, None] - p[:, 1, None, None]) ** 2)
    prof = 0.5 * erfc((dist - r[:, None, None]) / (math.sqrt(2.0) * sigma))
    acc[y0:y1, x0:x1] += (peak_e / len(vis)) * prof.sum(axis=0)
    return (y0, y1, x0, x1)
