"""The sensor: shot and read noise, full well, quantisation; the background drawn from its exact distribution."""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import norm, poisson

from ..camera import Camera

__all__ = ["background_distribution", "background_table", "BackgroundTables", "response_table", "expose",
           "BACKGROUND_TABLE_SIZE"]

#: background pixels are drawn by inverse CDF from a table of this many equiprobable values
BACKGROUND_TABLE_SIZE = 1 << 16


def background_distribution(background_e: float, sensor) -> np.ndarray:
    """Exact distribution of a background pixel's value: P(ADU = k), k = 0 .. 2^bits - 1.

    electrons = Poisson(background) + Normal(0, read noise), clipped to [0, full well];
    ADU = min(round(electrons / gain), 2^bits - 1).
    """
    s = sensor
    spread = 12.0 * math.sqrt(background_e) + 10.0
    n = np.arange(max(0, int(background_e - spread)), int(background_e + spread) + 1)
    pn = poisson.pmf(n, background_e)
    top = min(s.max_adu, int(math.floor(s.full_well_e / s.gain_e_per_adu + 0.5)))
    edges = (np.arange(top) + 0.5) * s.gain_e_per_adu  # ADU <= k  <=>  electrons < (k + 0.5) gain
    if s.read_noise_e > 0:
        cdf = (pn[None, :] * norm.cdf((edges[:, None] - n[None, :]) / s.read_noise_e)).sum(axis=1)
    else:
        cdf = (pn[None, :] * (n[None, :] < edges[:, None])).sum(axis=1)
    cdf = np.append(np.clip(cdf, 0.0, 1.0), 1.0)
    pmf = np.zeros(s.max_adu + 1)
    pmf[: top + 1] = np.diff(np.concatenate([[0.0], cdf]))
    return pmf / pmf.sum()


def background_table(background_e: float, sensor) -> np.ndarray:
    """Inverse-CDF lookup table: a uniform 16-bit integer -> a background pixel value."""
    pmf = background_distribution(background_e, sensor)
    u = (np.arange(BACKGROUND_TABLE_SIZE) + 0.5) / BACKGROUND_TABLE_SIZE
    values = np.searchsorted(np.cumsum(pmf), u, side="left").clip(0, sensor.max_adu)
    return values.astype(np.uint8 if sensor.bit_depth == 8 else np.uint16)


class BackgroundTables:
    """Background tables of a lighting level that drifts about ``nominal_e``: one per level, the level rounded
    to 0.1 % of the nominal one (each computed once)."""

    def __init__(self, sensor, nominal_e: float):
        self.sensor, self.nominal_e = sensor, nominal_e
        self._tables: dict[int, np.ndarray] = {}

    def __call__(self, factor: float) -> tuple[np.ndarray, float]:
        """The table for the lighting ``factor`` x nominal, and the background level it was made for. [e]"""
        key = int(round(factor * 1000.0))
        level = self.nominal_e if key == 1000 else self.nominal_e * key / 1000.0
        if key not in self._tables:
            self._tables[key] = background_table(level, self.sensor)
        return self._tables[key], level


def response_table(sensor) -> np.ndarray | None:
    """The recorded value of each linear value, ``round(max (v / max)^(1 / gamma))`` (None for a linear sensor)."""
    if sensor.gamma == 1.0:
        return None
    v = np.arange(sensor.max_adu + 1, dtype=np.float64)
    out = np.floor(sensor.max_adu * (v / sensor.max_adu) ** (1.0 / sensor.gamma) + 0.5)
    return out.astype(np.uint8 if sensor.bit_depth == 8 else np.uint16)


def expose(expected: np.ndarray, windows, cam: Camera, rng: np.random.Generator, background_e: float,
           table: np.ndarray, response: np.ndarray | None = None) -> np.ndarray:
    """Pixel values: background from its exact distribution, exact shot + read noise near markers; then the
    sensor's response (``response_table``) when it is not linear."""
    s = cam.sensor
    h, w = expected.shape
    idx = np.frombuffer(rng.bytes(2 * h * w), dtype=np.uint16).reshape(h, w)
    image = np.take(table, idx)
    for (y0, y1, x0, x1) in windows:
        lam = expected[y0:y1, x0:x1] + background_e
        e = rng.poisson(lam) + rng.standard_normal(lam.shape) * s.read_noise_e
        adu = np.floor(np.clip(e, 0.0, s.full_well_e) / s.gain_e_per_adu + 0.5)
        image[y0:y1, x0:x1] = np.clip(adu, 0, s.max_adu)
    return image if response is None else np.take(response, image)
