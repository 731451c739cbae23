"""Drawing a marker's expected electrons into the image, sub-exposure sample by sample (motion blur)."""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.special import erfc

from ..camera import Camera

__all__ = ["draw_sphere", "draw_disc", "DISC_SUPERSAMPLING"]

#: sub-pixel rays per pixel side of a disc marker (16 per pixel)
DISC_SUPERSAMPLING = 4


def draw_sphere(acc: np.ndarray, px: np.ndarray, radius: np.ndarray, vis: np.ndarray, peak_e: float,
               sigma: float) -> tuple[int, int, int, int] | None:
    """A sphere's spot: the disc of radius ``f R / depth`` convolved with the Gaussian PSF, point-sampled at the
    pixel centres (``0.5 erfc((|p - c| - r) / (sqrt(2) sigma))``), summed over the visible sub-exposure
    samples into ``acc``; returns its window."""
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


def _disc_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane normal to each ``n`` (k, 3)."""
    helper = np.where(np.abs(n[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(n, u)


def draw_disc(acc: np.ndarray, cam: Camera, centres: np.ndarray, normals: np.ndarray, radius_m: float,
              vis: np.ndarray, peak_e: float, supersampling: int = DISC_SUPERSAMPLING
              ) -> tuple[int, int, int, int] | None:
    """A flat disc's spot by ray casting, independent of the tracker's spot model: ``supersampling^2`` rays
    per pixel from the camera centre through the distorted pixel grid (OpenCV's undistortion) meet the
    disc's plane at each sub-exposure sample; the fraction inside the disc is the pixel's coverage, which
    is then blurred by the Gaussian PSF.  Adds into ``acc`` and returns the window."""
    if not vis.any():
        return None
    c, n = centres[vis], normals[vis]
    u, v = _disc_basis(n)
    a = np.linspace(0, 2 * np.pi, 33)[:-1]
    rim = c[:, None, :] + radius_m * (np.cos(a)[None, :, None] * u[:, None, :] + np.sin(a)[None, :, None] * v[:, None, :])
    rim_px = cv2.projectPoints(rim.reshape(-1, 3), cam.rvec, cam.tvec, cam.camera_matrix,
                               cam.dist_coeffs)[0].reshape(-1, 2)
    reach = 4.0 * cam.psf_sigma_px + 2.0
    h, w = acc.shape
    x0, y0 = max(int(math.floor(rim_px[:, 0].min() - reach)), 0), max(int(math.floor(rim_px[:, 1].min() - reach)), 0)
    x1 = min(int(math.ceil(rim_px[:, 0].max() + reach)) + 1, w)
    y1 = min(int(math.ceil(rim_px[:, 1].max() + reach)) + 1, h)
    if x1 <= x0 or y1 <= y0:
        return None
    s = supersampling
    sub = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(x0, x1)[:, None] + sub[None, :]).ravel()
    ys = (np.arange(y0, y1)[:, None] + sub[None, :]).ravel()
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 1, 2)
    norm = cv2.undistortPoints(grid, cam.camera_matrix, cam.dist_coeffs).reshape(-1, 2)
    rays = np.column_stack([norm, np.ones(len(norm))]) @ cam.rotation
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    origin = cam.centre_m
    cover = np.zeros(len(rays))
    for cj, nj in zip(c, n):
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = ((cj - origin) @ nj) / (rays @ nj)
        hit = origin + dist[:, None] * rays - cj
        cover += (dist > 0) & (np.einsum("ij,ij->i", hit, hit) <= radius_m**2)
    cover = cover.reshape(y1 - y0, s, x1 - x0, s).mean(axis=(1, 3)) / len(vis)
    blurred = cv2.GaussianBlur(cover, (0, 0), cam.psf_sigma_px, borderType=cv2.BORDER_CONSTANT)
    acc[y0:y1, x0:x1] += peak_e * blurred
    return (y0, y1, x0, x1)
