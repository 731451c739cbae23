"""The frame's own dots (e.g. a crossbar): the frame's rotation angle ``psi`` about the axis.

A dot fixed on the frame at ``(rho cos a, rho sin a, z)`` (frame coordinates, ``z`` along the
axis) sits, for the tip direction ``n`` and the frame angle ``psi``, at
``rho (cos(psi + a) e_a + sin(psi + a) e_b) + z n`` with ``e_a`` the line of nodes and
``e_b = n x e_a`` (Goldstein x-convention).  Seen at a pixel, its ray meets the sphere of the
dot's radius about the pivot; the intersection nearer the dot's height along the axis gives
``psi``.  With two dots symmetric about the axis, which is which cannot be told from the
images: ``psi`` is then known modulo pi, and is continuous within a record.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from ..geometry import ray_sphere_distances, wrap_angle
from ..markers import Marker
from ..camera import Camera
from .detect import Detection, find_blobs, stands_out
from .follow import CLEAR_RADII
from .rays import pixel_rays
from .scene_spot import fit_round_spot
from .spot import SpotFit

__all__ = ["DotTracker", "dot_angle", "dot_angles", "dot_circles", "CIRCLE_SAMPLES"]


def _axis_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line of nodes ``a`` and ``b = n x a`` for the tip direction ``n`` (Goldstein x-convention)."""
    phi = math.atan2(n[0], -n[1])
    c, s = math.cos(phi), math.sin(phi)
    return np.array([c, s, 0.0]), np.array([-n[2] * s, n[2] * c, n[0] * s - n[1] * c])


def _angle_on_frame(dot: Marker) -> float:
    return math.atan2(dot.position_m[1], dot.position_m[0])


def _dot_position(dot: Marker, n: np.ndarray, psi: float) -> np.ndarray:
    a, b = _axis_basis(n)
    ang = psi + _angle_on_frame(dot)
    return dot.off_axis_m * (math.cos(ang) * a + math.sin(ang) * b) + dot.position_m[2] * n


def dot_angles(xy_px: np.ndarray, dot: "Marker | Sequence[Marker]", n: np.ndarray, cam: Camera) -> np.ndarray:
    """The frame angles psi (k,) implied by ``dot`` (one for every pixel, or one per pixel) seen at pixels
    ``xy_px`` (k, 2), for the tip direction ``n``.

    Each ray meets the sphere ``|X| = |p|`` twice; the intersection whose height along the axis is nearer the
    dot's is taken, and rejected (NaN) if it is off the dot's circle by more than a quarter of its radius, or if
    the ray misses the sphere.
    """
    d = pixel_rays(np.asarray(xy_px, float).reshape(-1, 2), cam)
    dots = [dot] * len(d) if isinstance(dot, Marker) else list(dot)
    radius = np.array([float(np.dot(m.position_m, m.position_m)) ** 0.5 for m in dots])
    height = np.array([m.position_m[2] for m in dots], float)
    rho = np.array([m.off_axis_m for m in dots], float)
    c = cam.centre_m
    near, far = ray_sphere_distances(c, d, radius)
    both = c + np.stack([near, far], axis=1)[:, :, None] * d[:, None, :]  # (k, 2, 3)
    off = np.abs(both @ n - height[:, None])
    pick = np.argmin(np.where(np.isfinite(off), off, np.inf), axis=1)
    X = both[np.arange(len(d)), pick]
    off = off[np.arange(len(d)), pick]
    v = X - (X @ n)[:, None] * n
    a, b = _axis_basis(n)
    psi = np.arctan2(v @ b, v @ a) - np.array([_angle_on_frame(m) for m in dots])
    bad = ~np.isfinite(near) | (off > 0.25 * rho) | (np.abs(np.linalg.norm(v, axis=1) - rho) > 0.25 * rho)
    return np.where(bad, np.nan, psi)


def _project(X: np.ndarray, cam: Camera) -> np.ndarray:
    """Pixels (k, 2) of the lab points ``X`` (k, 3) through the camera."""
    return cv2.projectPoints(X.reshape(-1, 1, 3), cam.rvec, cam.tvec, cam.camera_matrix,
                             cam.dist_coeffs)[0].reshape(-1, 2)


def _image_radius_px(dot: Marker, cam: Camera) -> float:
    """The dot's image radius [px] at the pivot's distance from the camera."""
    return float(cam.camera_matrix[0, 0] * dot.radius_m / np.linalg.norm(cam.centre_m))


#: the places a dot not followed can take are sampled at this many angles about the axis (:func:`dot_circles`)
CIRCLE_SAMPLES = 48


def dot_circles(dots: Sequence[Marker], n: np.ndarray, cam: Camera) -> tuple[tuple[float, float, float], ...]:
    """Where each of ``dots`` (not followed: its angle about the axis unknown) can appear for the tip direction
    ``n``: :data:`CIRCLE_SAMPLES` points of its circle about the axis, projected, each ``(x, y, r)`` [px] with ``r``
    its image radius plus half the largest gap between neighbouring points (every place on the circle lies within
    one of them)."""
    if not dots:
        return ()
    a, b = _axis_basis(np.asarray(n, float))
    q = np.linspace(0.0, 2 * np.pi, CIRCLE_SAMPLES, endpoint=False)
    out = []
    for dot in dots:
        xy = _project(dot.off_axis_m * (np.cos(q)[:, None] * a + np.sin(q)[:, None] * b) + dot.position_m[2] * n, cam)
        gap = float(np.max(np.hypot(*(xy - np.roll(xy, 1, axis=0)).T)))
        r = _image_radius_px(dot, cam) + gap / 2
        out.extend((float(x), float(y), r) for x, y in xy)
    return tuple(out)


def dot_angle(x_px: float, y_px: float, dot: Marker, n: np.ndarray, cam: Camera) -> float | None:
    """The frame angle psi implied by ``dot`` seen at a pixel (:func:`dot_angles`); None where it is rejected."""
    psi = float(dot_angles(np.array([[x_px, y_px]]), dot, n, cam)[0])
    return psi if math.isfinite(psi) else None


class DotTracker:
    """Follows the frame's dots from frame to frame; gives the frame angle psi and its sigma."""

    LOST_AFTER = 5  # frames without any dot before a fresh acquisition

    def __init__(self, dots: tuple[Marker, ...], cam: Camera):
        self.dots = dots
        self.cam = cam
        self.r_px = {d.name: _image_radius_px(d, cam) for d in dots}
        self.psi = None
        self.rate = 0.0
        self.t = None
        self.misses = 0
        self.last_r = dict(self.r_px)

    def _project(self, X: np.ndarray) -> np.ndarray:
        return _project(X, self.cam)

    def _acquire(self, image, n, tip_xy, r_tip, threshold):
        dot = self.dots[0]
        circle = self._project(np.array([_dot_position(dot, n, q) for q in np.linspace(0, 2 * np.pi, 25)[:-1]]))
        r = self.r_px[dot.name]
        h, w = image.shape
        x0, y0 = circle.min(axis=0) - 3 * r - 5
        x1, y1 = circle.max(axis=0) + 3 * r + 5
        cand = find_blobs(image, max(int(x0), 0), max(int(y0), 0), min(int(x1), w), min(int(y1), h), threshold)
        for cx, cy, cr, _ in sorted(cand, key=lambda c: -c.r):
            if not 0.5 * r <= cr <= 1.6 * r or math.hypot(cx - tip_xy[0], cy - tip_xy[1]) < 1.2 * r_tip:
                continue
            fit = fit_round_spot(image, cx, cy, cr, self.cam)
            if fit is not None:
                psi = dot_angle(fit.x_px, fit.y_px, dot, n, self.cam)
                if psi is not None:
                    return psi
        return None

    def _fit_dot(self, image, dot: Marker, at, tip_xy, r_tip, threshold, near=()) -> SpotFit | None:
        """The dot near its predicted place ``at`` (x, y) [px].  Followed, and clear of the tip and of ``near``
        (the other dots' predictions, ``(x, y, r)`` [px]) by :data:`~gyrorig.tracking.follow.CLEAR_RADII` of its
        radii plus theirs, the fit starts at the prediction and is taken when it stays there; otherwise the
        candidates around the prediction are searched."""
        r = self.r_px[dot.name]
        h, w = image.shape
        px, py = float(at[0]), float(at[1])
        spots = ((tip_xy[0], tip_xy[1], r_tip), *near)
        if self.misses == 0 and all(math.hypot(x - px, y - py) > CLEAR_RADII * r + rr for x, y, rr in spots):
            fit = fit_round_spot(image, px, py, self.last_r[dot.name], self.cam)
            if (fit is not None and not fit.blended and stands_out(fit, threshold)
                    and math.hypot(fit.x_px - px, fit.y_px - py) < max(2.0, 0.3 * fit.radius_px)
                    and 0.5 * r <= fit.radius_px <= 1.6 * r):
                return fit
        reach = int(3 * r + 10)
        cand = find_blobs(image, max(int(px) - reach, 0), max(int(py) - reach, 0), min(int(px) + reach, w),
                          min(int(py) + reach, h), threshold)
        cand = [c for c in cand if 0.5 * r <= c[2] <= 1.6 * r
                and math.hypot(c[0] - tip_xy[0], c[1] - tip_xy[1]) >= 1.2 * r_tip]
        if not cand:
            return None
        cx, cy, cr, _ = min(cand, key=lambda c: (c.x - px) ** 2 + (c.y - py) ** 2)
        if self.misses == 0 and math.hypot(cx - px, cy - py) < max(2.0, 0.3 * cr):
            cx, cy, cr = px, py, self.last_r[dot.name]  # sub-pixel prediction: fewer iterations
        return fit_round_spot(image, cx, cy, cr, self.cam)

    def _psis_with_variance(self, fitted: list, n) -> list[tuple[float | None, float | None]]:
        """psi of each fitted dot (``fitted``: ``(Marker, SpotFit)`` pairs) and its variance from the spot
        covariance through the pixel -> angle map (central differences over +-0.05 px), all in one ray call;
        ``(None, None)`` for a dot rejected, the variance None when a neighbouring pixel is."""
        if not fitted:
            return []
        eps = 0.05
        offsets = np.array([[0.0, 0.0], [eps, 0.0], [-eps, 0.0], [0.0, eps], [0.0, -eps]])
        xy = np.concatenate([np.array([fit.x_px, fit.y_px]) + offsets for _, fit in fitted])
        psis = dot_angles(xy, [dot for dot, _ in fitted for _ in offsets], n, self.cam).reshape(-1, len(offsets))
        out = []
        for (_, fit), psi in zip(fitted, psis):
            if not math.isfinite(psi[0]):
                out.append((None, None))
            elif not np.all(np.isfinite(psi)):
                out.append((float(psi[0]), None))
            else:
                jac = np.array([wrap_angle(psi[1] - psi[2]), wrap_angle(psi[3] - psi[4])]) / (2 * eps)
                var = float(jac @ fit.cov_xy @ jac)
                out.append((float(psi[0]), var if var > 0 else None))
        return out

    def step(self, image, t_s: float, n: np.ndarray, tip_xy, r_tip: float, threshold: Detection):
        """Fit the dots in one frame; returns ``(psi, psi_sigma, [(name, SpotFit), ...])``."""
        if self.psi is None:
            self.psi = self._acquire(image, n, tip_xy, r_tip, threshold)
            self.rate, self.t = 0.0, t_s
            if self.psi is None:
                return float("nan"), float("nan"), []
        psi_pred = self.psi + self.rate * (t_s - self.t)
        found, est = [], []
        predicted = self._project(np.array([_dot_position(d, n, psi_pred) for d in self.dots]))
        places = [(float(x), float(y), self.r_px[d.name]) for (x, y), d in zip(predicted, self.dots)]
        fitted = []
        for k, dot in enumerate(self.dots):
            fit = self._fit_dot(image, dot, predicted[k], tip_xy, r_tip, threshold, places[:k] + places[k + 1:])
            if fit is not None:
                self.last_r[dot.name] = fit.radius_px
                fitted.append((dot, fit))
        for (dot, fit), (psi_m, var) in zip(fitted, self._psis_with_variance(fitted, n)):
            if psi_m is None:
                continue
            psi_m = psi_pred + wrap_angle(psi_m - psi_pred)
            if var is not None:
                est.append((psi_m, var))
            found.append((dot.name, fit))
        if not est:
            self.misses += 1
            if self.misses >= self.LOST_AFTER:
                self.psi = None
            return float("nan"), float("nan"), found
        wts = np.array([1 / v for _, v in est])
        psi = float(np.sum(wts * np.array([p for p, _ in est])) / wts.sum())
        if self.t is not None and t_s > self.t:
            self.rate = (psi - self.psi) / (t_s - self.t)
        self.psi, self.t, self.misses = psi, t_s, 0
        return psi, float(1 / math.sqrt(wts.sum())), found
