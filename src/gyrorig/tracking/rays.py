"""From pixels to directions: undistorted rays from the camera centre meeting spheres about the pivot."""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry import angles_from_tip, ray_sphere_distances
from ..camera import Camera

__all__ = ["pixel_rays", "tips_from_pixels", "tip_from_pixel", "sphere_box", "angles_with_covariance",
           "angle_covariances", "limb_margins_rad", "near_limb", "limb_flags", "LIMB_MARGIN_RAD"]

#: a tip nearer than this to the limb of its sphere as the camera sees it may be read on the wrong side of it [rad]
LIMB_MARGIN_RAD = 0.1


def pixel_rays(xy_px: np.ndarray, cam: Camera) -> np.ndarray:
    """Unit directions in the lab (n, 3) of the rays through pixels (n, 2) (distortion removed)."""
    xy = np.asarray(xy_px, dtype=np.float64).reshape(-1, 1, 2)
    if len(xy) == 0:
        return np.empty((0, 3))
    n = cv2.undistortPoints(xy, cam.camera_matrix, cam.dist_coeffs).reshape(-1, 2)
    d = np.column_stack([n, np.ones(len(n))]) @ cam.rotation
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def tips_from_pixels(xy_px: np.ndarray, cam: Camera, radius_m: float) -> np.ndarray:
    """Unit tip directions (n, 3) for pixel positions (n, 2): each ray meets the sphere ``|X| = radius_m``
    about the pivot (the nearer point); NaN where the ray misses the sphere."""
    d = pixel_rays(xy_px, cam)
    c = cam.centre_m
    s, _ = ray_sphere_distances(c, d, radius_m)
    return (c + s[:, None] * d) / radius_m


def tip_from_pixel(x_px: float, y_px: float, cam: Camera, radius_m: float) -> np.ndarray | None:
    """Unit tip direction of one pixel (see :func:`tips_from_pixels`); None where the ray misses the sphere."""
    tip = tips_from_pixels(np.array([[x_px, y_px]]), cam, radius_m)[0]
    return None if not np.all(np.isfinite(tip)) else tip


def sphere_box(cam: Camera, radius_m: float, step_px: int = 8) -> tuple[int, int, int, int] | None:
    """The part of the image ``(x0, y0, x1, y1)`` [px] (half-open) holding every pixel whose ray meets the sphere
    ``|X| = radius_m`` about the pivot (:func:`tip_from_pixel` is not None there), tested on a grid of ``step_px``
    and widened by one step; None when no pixel's ray meets it."""
    w, h = int(cam.width_px), int(cam.height_px)
    xs = np.unique(np.r_[np.arange(0, w, step_px), w - 1])
    ys = np.unique(np.r_[np.arange(0, h, step_px), h - 1])
    gx, gy = np.meshgrid(xs, ys)
    pts = np.column_stack([gx.ravel(), gy.ravel()]).astype(float)
    meets = np.isfinite(tips_from_pixels(pts, cam, radius_m)[:, 0])
    if not meets.any():
        return None
    x, y = pts[meets].T
    return (max(int(x.min()) - step_px, 0), max(int(y.min()) - step_px, 0), min(int(x.max()) + step_px + 1, w),
            min(int(y.max()) + step_px + 1, h))


def angles_with_covariance(x: float, y: float, cov_xy: np.ndarray, cam: Camera, radius_m: float
                           ) -> tuple[float, float, np.ndarray, np.ndarray] | None:
    """``theta, phi``, the unit tip and the 2x2 covariance of ``(theta, phi)`` of a spot at ``(x, y)``
    with pixel covariance ``cov_xy`` (:func:`angle_covariances` for one spot).  None when the ray (or a
    neighbouring one) misses the tip's sphere."""
    th, ph, tip, cov = angle_covariances(np.array([[x, y]]), np.asarray(cov_xy, float)[None], cam, radius_m)
    if not np.isfinite(th[0]):
        return None
    return float(th[0]), float(ph[0]), tip[0], cov[0]


def angle_covariances(xy_px: np.ndarray, cov_xy: np.ndarray, cam: Camera, radius_m: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``theta, phi`` (n,), the unit tips (n, 3) and the covariances of ``(theta, phi)`` (n, 2, 2) of spots at
    ``xy_px`` (n, 2) with pixel covariances ``cov_xy`` (n, 2, 2).

    The tip vector is smooth in the pixel position everywhere, the angles are not (at the poles ``phi`` is
    undefined and ``theta`` has a cone): so the pixel covariance goes to the tip vector first (numerical
    Jacobian over +-0.05 px), then onto the angles' local directions, ``d theta = e_theta . dn`` and
    ``d phi = e_phi . dn / sin(theta)``.  Near a pole ``theta``'s error stays the tip's angular error and
    ``phi``'s grows as ``1 / sin(theta)``: a sleeping top's azimuth is honestly unknown.

    NaN where the ray (or a neighbouring one) misses the tip's sphere.
    """
    eps = 0.05
    xy = np.asarray(xy_px, float).reshape(-1, 2)
    n = len(xy)
    steps = np.array([[0, 0], [eps, 0], [-eps, 0], [0, eps], [0, -eps]])
    tips = tips_from_pixels((xy[:, None, :] + steps).reshape(-1, 2), cam, radius_m).reshape(n, 5, 3)
    jac_n = np.stack([(tips[:, 1] - tips[:, 2]) / (2 * eps), (tips[:, 3] - tips[:, 4]) / (2 * eps)], axis=2)
    th, ph = angles_from_tip(tips[:, 0])
    th, ph = np.asarray(th, float), np.asarray(ph, float)
    e_theta = np.stack([np.cos(th) * np.sin(ph), -np.cos(th) * np.cos(ph), -np.sin(th)], axis=1)
    e_phi = np.stack([np.cos(ph), np.sin(ph), np.zeros(n)], axis=1) / np.maximum(np.sin(th), 1e-12)[:, None]
    proj = np.stack([e_theta, e_phi], axis=1) @ jac_n  # (n, 2, 2): pixels -> angles
    cov = proj @ np.asarray(cov_xy, float).reshape(n, 2, 2) @ np.transpose(proj, (0, 2, 1))
    bad = ~np.all(np.isfinite(tips), axis=(1, 2))
    th[bad], ph[bad] = np.nan, np.nan
    cov[bad] = np.nan
    return th, ph, tips[:, 0], cov


def limb_margins_rad(tips: np.ndarray, cam: Camera, radius_m: float) -> np.ndarray:
    """Per unit tip (n, 3): its angle from the limb of the sphere ``|X| = radius_m`` as the camera sees it (the
    circle where the camera's rays graze the sphere), positive on the camera's side; NaN for a NaN tip.

    Every ray through the tip's image meets the sphere twice, and the tracker takes the nearer point: a tip beyond
    the limb is read as a point on the camera's side, at a tilt it does not have, with error bars that cannot show
    it (one picture cannot tell the two points apart; near the limb they meet)."""
    c = np.asarray(cam.centre_m, float).ravel()
    distance = float(np.linalg.norm(c))
    if distance <= radius_m:  # the camera inside the sphere sees no limb
        return np.full(len(tips), np.inf)
    limb = np.arccos(radius_m / distance)
    return limb - np.arccos(np.clip(np.asarray(tips, float) @ (c / distance), -1.0, 1.0))


def near_limb(tips: np.ndarray, cam: Camera, radius_m: float) -> np.ndarray:
    """Whether each tip (n, 3) lies within :data:`LIMB_MARGIN_RAD` of the limb or beyond it (:func:`limb_margins_rad`;
    False for a NaN tip)."""
    margins = limb_margins_rad(tips, cam, radius_m)
    return np.isfinite(margins) & (margins < LIMB_MARGIN_RAD)


def limb_flags(tips: np.ndarray, cam: Camera, radius_m: float) -> tuple[np.ndarray, str]:
    """The tracked tips (n, 3; NaN where untracked) to flag ``near-limb``, and what to say (empty when none is).

    Tracked tips are all on the camera's side; one within :data:`LIMB_MARGIN_RAD` of the limb may be the reading of
    a tip beyond it, and a path that reaches the limb may cross it: after that, and before it, either side may be the
    true one, which one view cannot tell.  So when any tracked tip is that near, every tracked frame is flagged."""
    margins = limb_margins_rad(tips, cam, radius_m)
    tracked = np.isfinite(margins)
    if not np.any(tracked & (margins < LIMB_MARGIN_RAD)):
        return np.zeros(len(margins), bool), ""
    limb_deg = np.degrees(np.arccos(radius_m / float(np.linalg.norm(cam.centre_m))))
    return tracked, (f"the tip came within {np.degrees(np.nanmin(margins)):.2g} deg of the limb of its sphere as this "
                     f"camera sees it ({limb_deg:.3g} deg from the camera's direction, seen from the pivot): every ray "
                     "through the tip meets the sphere twice and the nearer point is taken, so a tip beyond the limb "
                     "is read at a wrong tilt and azimuth with error bars that cannot show it, and one view cannot tell "
                     f"which frames are: all {int(tracked.sum())} tracked frames are flagged near-limb; film the top "
                     f"from above (the camera's direction within {limb_deg:.3g} deg less the top's largest tilt of the "
                     "vertical)")
