"""Elliptical spots: flat disc markers seen obliquely, and blobs of unknown appearance.

A flat disc's image is (up to the lens's distortion) an ellipse: the model is a uniform ellipse
convolved with the camera's Gaussian PSF on a flat background,
``mu = b + A * erfc(s / (sqrt(2) sigma)) / 2`` with ``s`` the signed distance to the ellipse's
boundary (to first order, ``(rho - 1) / |grad rho|`` for ``rho^2 = d^T M^-1 d``, ``M`` the ellipse's
shape matrix: its eigenvalues are the squared semi-axes).  The model is point-symmetric, so its
fitted centre is the ellipse's centre whatever the first-order edge model leaves in the residuals.

The centre of a disc's ellipse is not the image of the disc's centre (perspective moves it by a
few 0.01 px for a marker of a few millimetres): :func:`disc_image` gives both from the camera and
the disc's 3-D pose, and :class:`DiscGeometry` turns a fitted ellipse centre into the image of the
disc's centre and says which ellipse the disc must make there (the detection gate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from ..camera import Camera
from .rays import tip_from_pixel
from .spot import SpotFit, pixel_variance, spot_window

__all__ = ["ellipse_model", "fit_ellipse_spot", "disc_image", "DiscImage", "DiscGeometry"]

#: rim points used to project a disc (the projected area's centroid converges as 1/n^2)
RIM_POINTS = 96


@njit(cache=True)
def _edge_distance(p0, p1, p2, p3, p4, x, y):
    """The signed distance ``s`` of pixel ``(x, y)`` to the ellipse's boundary (first order, module docstring)."""
    det = p2 * p4 - p3 * p3
    q11, q12, q22 = p4 / det, -p3 / det, p2 / det  # M^-1
    dx, dy = x - p0, y - p1
    gx, gy = q11 * dx + q12 * dy, q12 * dx + q22 * dy
    rho = math.sqrt(max(dx * gx + dy * gy, 0.0)) + 1e-12
    grad = math.sqrt(gx * gx + gy * gy) / rho + 1e-12  # |grad rho|
    return (rho - 1.0) / grad


@njit(cache=True)
def _model_jacobian(p, xx, yy, sigma, jacobian):
    """The model over the window and, with ``jacobian``, its derivatives (h, w, 7): in the centre and the shape
    through the edge distance (``d mu / d s`` exact, ``d s / d p`` by central differences, steps ``1e-3`` px and
    ``1e-3`` of the shape's terms), exact ones in amplitude and background."""
    h, w = xx.shape
    k = 1.0 / (math.sqrt(2.0) * sigma)
    mu = np.empty((h, w))
    jac = np.empty((h, w, 7) if jacobian else (0, 0, 7))
    steps = np.array([1e-3, 1e-3, 1e-3 * p[2], 1e-3 * math.sqrt(p[2] * p[4]), 1e-3 * p[4]])
    up = p.copy()
    dn = p.copy()
    slope = -p[5] * k / math.sqrt(math.pi)
    for iy in range(h):
        for ix in range(w):
            x, y = xx[iy, ix], yy[iy, ix]
            ks = k * _edge_distance(p[0], p[1], p[2], p[3], p[4], x, y)
            e = 0.5 * math.erfc(ks)
            mu[iy, ix] = p[6] + p[5] * e
            if jacobian:
                dmu_ds = slope * math.exp(-ks * ks)
                for i in range(5):
                    up[i] = p[i] + steps[i]
                    dn[i] = p[i] - steps[i]
                    ds = (_edge_distance(up[0], up[1], up[2], up[3], up[4], x, y)
                          - _edge_distance(dn[0], dn[1], dn[2], dn[3], dn[4], x, y))
                    jac[iy, ix, i] = dmu_ds * ds / (2 * steps[i])
                    up[i] = p[i]
                    dn[i] = p[i]
                jac[iy, ix, 5] = e
                jac[iy, ix, 6] = 1.0
    return mu, jac


def ellipse_model(params: np.ndarray, xx: np.ndarray, yy: np.ndarray, sigma: float) -> np.ndarray:
    """The spot of a uniform ellipse: ``params = (x, y, m11, m12, m22, amplitude, background)``, ``M`` the
    shape matrix [px^2] (a circle of radius r: ``M = r^2 I``)."""
    xx, yy = np.broadcast_arrays(np.asarray(xx, np.float64), np.asarray(yy, np.float64))
    shape = xx.shape
    mu, _ = _model_jacobian(np.asarray(params, np.float64), np.ascontiguousarray(xx.reshape(1, -1)),
                            np.ascontiguousarray(yy.reshape(1, -1)), float(sigma), False)
    return mu.reshape(shape)


def warm_up() -> None:
    """Compile the ellipse model now (numba; cached on disk after the first run), not in the first frame."""
    yy, xx = np.mgrid[0:5, 0:5].astype(np.float64)
    _model_jacobian(np.array([2.0, 2.0, 4.0, 0.0, 4.0, 10.0, 1.0]), xx, yy, 1.0, True)


def _valid(p) -> bool:
    """Finite parameters of a bounded (a diverged step's are not), positive-definite ellipse of positive amplitude."""
    return bool(np.all(np.abs(p) < 1e100) and p[2] > 0.04 and p[4] > 0.04 and p[2] * p[4] - p[3] ** 2 > 1e-3
                and p[5] > 0)


def _solve(win, xx, yy, use, p, cam, bvar, iterations):
    """Damped Gauss-Newton over the pixels in ``use``; returns ``(p, converged, fisher, chi2, mu)``."""
    sigma = cam.psf_sigma_px
    converged = False
    for it in range(iterations + 1):
        mu, jac = _model_jacobian(p, xx, yy, sigma, True)
        var = pixel_variance(mu, cam, bvar)
        jac = jac[use]
        wj = jac / var[use][:, None]
        fisher = wj.T @ jac
        r = (win - mu)[use]
        chi2 = float((r * r / var[use]).sum())
        if converged or it == iterations:
            return p, converged, fisher, chi2, mu
        try:
            step = np.linalg.solve(fisher + 1e-9 * np.diag(np.diag(fisher)), wj.T @ r)
        except np.linalg.LinAlgError:
            return None, False, None, None, None
        for _ in range(20):
            trial = p + step
            if _valid(trial):
                break
            step = step / 2
        else:
            return None, False, None, None, None
        p = trial
        converged = abs(step[0]) < 1e-4 and abs(step[1]) < 1e-4
    return p, converged, fisher, chi2, mu  # not reached


def fit_ellipse_spot(image: np.ndarray, x0: float, y0: float, r0: float, cam: Camera, *,
                     shape: tuple[float, float, float] | None = None, iterations: int = 12) -> SpotFit | None:
    """Weighted least-squares fit of the elliptical spot model around ``(x0, y0)``.

    ``r0``: a start radius (and the window's size: 2 r0 + 4 sigma + 4 px either side); ``shape``: the
    start shape matrix ``(m11, m12, m22)`` [px^2], default a circle of radius ``r0``.  Light of other
    spots is left out (``blended``): bright regions of the window apart from the one at the start
    point, grown by the PSF's reach; and, after a first fit, pixels beyond the ellipse's edge + 3
    sigma that exceed the model by 5 standard deviations (then the fit is repeated).  Saturated pixels are left out.  The
    centre's covariance is the inverse Fisher matrix, scaled by the reduced chi-square when that is
    above 1 (or always, for an unknown sensor).  The returned :class:`SpotFit` has the ellipse's centre,
    ``radius_px = sqrt(major * minor)``, ``major_px``, ``minor_px`` and ``angle_rad`` (the major axis's
    direction from the x axis).  None when the window leaves the image or the fit diverges.
    """
    sigma = cam.psf_sigma_px
    half = int(math.ceil(2 * r0 + 4 * sigma + 4))
    window = spot_window(image, x0, y0, half, cam)
    if window is None:
        return None
    win, xx, yy, sat, border, bg, amp = window
    use = ~sat
    noise = max(1.4826 * float(np.median(np.abs(border - bg))), math.sqrt(1.0 / 12.0))
    bvar = noise * noise
    others = _other_spots(win, bg + max(5.0 * noise, 0.1 * amp), x0 - xx[0, 0], y0 - yy[0, 0], sigma)
    use &= ~others
    m = shape if shape is not None else (r0 * r0, 0.0, r0 * r0)
    p, converged, fisher, chi2, mu = _solve(win, xx, yy, use, np.array([x0, y0, *m, amp, bg]), cam, bvar, iterations)
    if p is None:
        return None
    dx, dy = xx - p[0], yy - p[1]
    major = math.sqrt(max(np.linalg.eigvalsh([[p[2], p[3]], [p[3], p[4]]])[1], 0.0))
    excess = (win - mu) / np.sqrt(pixel_variance(mu, cam, bvar))
    foreign = (np.hypot(dx, dy) > major + 3 * sigma) & (excess > 5.0)
    blended = bool(foreign.sum() >= 3)
    if blended:
        use &= ~cv2.dilate(foreign.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        p, converged, fisher, chi2, mu = _solve(win, xx, yy, use, p, cam, bvar, iterations)
        if p is None:
            return None
    blended = blended or bool(others.any())
    if abs(p[0] - x0) > half or abs(p[1] - y0) > half:
        return None
    chi2_red = chi2 / max(int(use.sum()) - 7, 1)
    try:
        cov = np.linalg.inv(fisher)[:2, :2] * (max(1.0, chi2_red) if cam.sensor_known else chi2_red)
    except np.linalg.LinAlgError:
        return None
    evals, evecs = np.linalg.eigh(np.array([[p[2], p[3]], [p[3], p[4]]]))
    minor, major = math.sqrt(evals[0]), math.sqrt(evals[1])
    angle = math.atan2(evecs[1, 1], evecs[0, 1])
    near = use & (np.hypot(xx - p[0], yy - p[1]) <= major + 3 * sigma)
    n_near = int(near.sum())
    chi2_own = (float(((win - mu)[near] ** 2 / pixel_variance(mu[near], cam, bvar)).sum() / max(n_near - 7, 1))
                if n_near > 10 else chi2_red)
    return SpotFit(float(p[0]), float(p[1]), math.sqrt(major * minor), float(p[5]), float(p[6]), cov, chi2_red,
                   bool(sat.any()), converged, blended, major, minor, angle, chi2_own)


def _other_spots(win: np.ndarray, threshold: float, x: float, y: float, sigma: float) -> np.ndarray:
    """Pixels of the window's bright regions other than the one at (or nearest) ``(x, y)`` (window
    coordinates), grown by the PSF's reach: light of other markers, to be left out of the fit."""
    n, labels = cv2.connectedComponents((win > threshold).astype(np.uint8), connectivity=8)
    if n <= 2:
        return np.zeros(win.shape, bool)
    iy, ix = np.nonzero(labels)
    k = int(np.argmin((ix - x) ** 2 + (iy - y) ** 2))
    others = (labels > 0) & (labels != labels[iy[k], ix[k]])
    reach = 2 * int(math.ceil(2 * sigma)) + 3
    return cv2.dilate(others.astype(np.uint8), np.ones((reach, reach), np.uint8)).astype(bool)


@dataclass(frozen=True)
class DiscImage:
    """A disc's image: its centre's image, its ellipse's (area) centre, semi-axes and the major axis's
    direction from the x axis [px, rad]."""

    centre_px: np.ndarray
    ellipse_centre_px: np.ndarray
    major_px: float
    minor_px: float
    angle_rad: float


def disc_image(centre_m: np.ndarray, normal: np.ndarray, radius_m: float, cam: Camera) -> DiscImage:
    """Project a disc (lab centre, unit normal, radius) through the camera, lens included: its rim as a
    polygon of :data:`RIM_POINTS` points, whose area centroid and second moments give the ellipse."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    a = np.linspace(0.0, 2.0 * np.pi, RIM_POINTS, endpoint=False)
    pts = np.vstack([centre_m, centre_m + radius_m * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)])
    px = cv2.projectPoints(pts, cam.rvec, cam.tvec, cam.camera_matrix, cam.dist_coeffs)[0].reshape(-1, 2)
    centre_px, rim = px[0], px[1:]
    # polygon area moments (shoelace) relative to the centre's image, for accuracy
    x, y = rim[:, 0] - centre_px[0], rim[:, 1] - centre_px[1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2.0
    cx = ((x + xn) * cross).sum() / (6.0 * area)
    cy = ((y + yn) * cross).sum() / (6.0 * area)
    sxx = ((x * x + x * xn + xn * xn) * cross).sum() / (12.0 * area) - cx * cx
    syy = ((y * y + y * yn + yn * yn) * cross).sum() / (12.0 * area) - cy * cy
    sxy = ((x * yn + 2 * x * y + 2 * xn * yn + xn * y) * cross).sum() / (24.0 * area) - cx * cy
    evals, evecs = np.linalg.eigh(np.array([[sxx, sxy], [sxy, syy]]))
    # a uniform ellipse with semi-axes a, b has second moments a^2 / 4, b^2 / 4
    minor, major = 2.0 * math.sqrt(max(evals[0], 0.0)), 2.0 * math.sqrt(max(evals[1], 0.0))
    return DiscImage(centre_px, centre_px + np.array([cx, cy]), major, minor, math.atan2(evecs[1, 1], evecs[0, 1]))


class DiscGeometry:
    """The tip's disc marker on the stem axis, facing along it (or against it): where its centre's image is
    for a fitted ellipse centre, and the ellipse it must make there."""

    def __init__(self, cam: Camera, length_m: float, radius_m: float):
        self.cam, self.length_m, self.radius_m = cam, length_m, radius_m

    def at(self, x_px: float, y_px: float) -> DiscImage | None:
        """The disc's image when its ellipse's centre is at ``(x_px, y_px)`` (None: off the tip's sphere).

        Two fixed-point steps: the offset between the ellipse's centre and the centre's image varies by
        far less than a pixel over the offset itself."""
        target = np.array([x_px, y_px])
        guess = target.copy()
        img = None
        for _ in range(2):
            n = tip_from_pixel(float(guess[0]), float(guess[1]), self.cam, self.length_m)
            if n is None:
                return None
            img = disc_image(self.length_m * n, n, self.radius_m, self.cam)
            guess = target - (img.ellipse_centre_px - img.centre_px)
        return img

    def at_centre(self, x_px: float, y_px: float) -> DiscImage | None:
        """The disc's image when its centre's image is at ``(x_px, y_px)`` (None: off the tip's sphere)."""
        n = tip_from_pixel(x_px, y_px, self.cam, self.length_m)
        return None if n is None else disc_image(self.length_m * n, n, self.radius_m, self.cam)

    def centre_px(self, fit: SpotFit) -> tuple[float, float] | None:
        """The image of the disc's centre for an ellipse fitted at ``fit`` (None: off the sphere)."""
        img = self.at(fit.x_px, fit.y_px)
        if img is None:
            return None
        off = img.ellipse_centre_px - img.centre_px
        return float(fit.x_px - off[0]), float(fit.y_px - off[1])

    def looks_right(self, fit: SpotFit, img: DiscImage, *, size=(0.75, 1.33), slack_px: float = 1.0,
                    angle_tol_rad: float = math.radians(25.0)) -> bool:
        """Whether a fitted ellipse is the disc's: semi-axes within ``size`` (plus ``slack_px`` for the
        minor, which the PSF blurs most) of the predicted ones, and the major axis along the predicted one
        when the ellipse is elongated (predicted axis ratio above 1.3)."""
        lo, hi = size
        if not (lo * img.major_px <= fit.major_px <= hi * img.major_px):
            return False
        if not (lo * img.minor_px - slack_px <= fit.minor_px <= hi * img.minor_px + slack_px):
            return False
        if img.major_px > 1.3 * img.minor_px and math.isfinite(fit.angle_rad):
            d = abs(math.remainder(fit.angle_rad - img.angle_rad, math.pi))
            return d <= angle_tol_rad
        return True
