"""From pixels to directions: undistorted rays from the camera centre meeting spheres about the pivot."""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..geometry import angles_from_tip, ray_sphere_distances
from .camera_file import TrackingCamera

__all__ = ["pixel_rays", "tips_from_pixels", "tip_from_pixel", "angles_with_covariance"]


def pixel_rays(xy_px: np.ndarray, cam: TrackingCamera) -> np.ndarray:
    """Unit directions in the lab (n, 3) of the rays through pixels (n, 2) (distortion removed)."""
    xy = np.asarray(xy_px, dtype=np.float64).reshape(-1, 1, 2)
    n = cv2.undistortPoints(xy, cam.camera_matrix, cam.dist_coeffs).reshape(-1, 2)
    d = np.column_stack([n, np.ones(len(n))]) @ cam.rotation
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def tips_from_pixels(xy_px: np.ndarray, cam: TrackingCamera, radius_m: float) -> np.ndarray:
    """Unit tip directions (n, 3) for pixel positions (n, 2): each ray meets the sphere ``|X| = radius_m``
    about the pivot (the nearer point); NaN where the ray misses the sphere."""
    d = pixel_rays(xy_px, cam)
    c = cam.centre_m
    s, _ = ray_sphere_distances(c, d, radius_m)
    return (c + s[:, None] * d) / radius_m


def tip_from_pixel(x_px: float, y_px: float, cam: TrackingCamera, radius_m: float) -> np.ndarray | None:
    """Unit tip direction of one pixel (see :func:`tips_from_pixels`); None where the ray misses the sphere."""
    tip = tips_from_pixels(np.array([[x_px, y_px]]), cam, radius_m)[0]
    return None if not np.all(np.isfinite(tip)) else tip


def angles_with_covariance(x: float, y: float, cov_xy: np.ndarray, cam: TrackingCamera, radius_m: float
                           ) -> tuple[float, float, np.ndarray, np.ndarray] | None:
    """``theta, phi``, the unit tip and the 2x2 covariance of ``(theta, phi)`` of a spot at ``(x, y)``
    with pixel covariance ``cov_xy``.

    The tip vector is smooth in the pixel position everywhere, the angles are not (at the poles ``phi`` is
    undefined and ``theta`` has a cone): so the pixel covariance goes to the tip vector first (numerical
    Jacobian over +-0.05 px), then onto the angles' local directions, ``d theta = e_theta . dn`` and
    ``d phi = e_phi . dn / sin(theta)``.  Near a pole ``theta``'s error stays the tip's angular error and
    ``phi``'s grows as ``1 / sin(theta)``: a sleeping top's azimuth is honestly unknown.

    None when the ray (or a neighbouring one) misses the tip's sphere.
    """
    eps = 0.05
    xy = np.array([[x, y], [x + eps, y], [x - eps, y], [x, y + eps], [x, y - eps]])
    tips = tips_from_pixels(xy, cam, radius_m)
    if not np.all(np.isfinite(tips)):
        return None
    jac_n = np.column_stack([(tips[1] - tips[2]) / (2 * eps), (tips[3] - tips[4]) / (2 * eps)])  # 3 x 2
    cov_n = jac_n @ cov_xy @ jac_n.T
    th, ph = angles_from_tip(tips[:1])
    th, ph = float(th[0]), float(ph[0])
    e_theta = np.array([math.cos(th) * math.sin(ph), -math.cos(th) * math.cos(ph), -math.sin(th)])
    e_phi = np.array([math.cos(ph), math.sin(ph), 0.0])
    proj = np.vstack([e_theta, e_phi / max(math.sin(th), 1e-12)])
    return th, ph, tips[0], proj @ cov_n @ proj.T
