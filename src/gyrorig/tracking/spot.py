"""The marker spot: its image model, weighted least-squares localisation and its Cramér-Rao bound.

A spot is a disc of radius ``r`` convolved with the camera's Gaussian PSF on a flat background:
``mu(x, y) = b + A * erfc((rho - r) / (sqrt(2) sigma)) / 2``, ``rho`` the distance from the
centre.  Pixel variances come from the sensor model ``mu / gain + (read noise / gain)^2 + 1/12``
[ADU^2] (or, when the gain is unknown, the measured background variance).  Saturated pixels
are left out of the fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit
from scipy.special import erfc

from ..camera import Camera

__all__ = ["SpotFit", "fit_spot", "spot_model", "pixel_variance", "normal_equations", "spot_crb_px", "warm_up"]


@dataclass(frozen=True)
class SpotFit:
    """A fitted spot: centre, radius, amplitude, background, covariance of the centre."""

    x_px: float
    y_px: float
    radius_px: float
    amplitude_adu: float
    background_adu: float
    cov_xy: np.ndarray
    chi2_red: float
    saturated: bool
    converged: bool
    blended: bool = False
    #: semi-axes of an elliptical fit (:mod:`gyrorig.tracking.ellipse`; NaN for the sphere model) [px]
    major_px: float = math.nan
    minor_px: float = math.nan
    #: direction of the major axis from the x axis (elliptical fits only) [rad]
    angle_rad: float = math.nan
    #: reduced chi-square over the spot's own pixels (its edge + 3 PSF sigmas; for a blended spot, those
    #: nearer to it than to its neighbour): how well the spot itself is fitted
    chi2_own: float = math.nan


def spot_model(params, xx, yy, sigma):
    """K discs (each x, y, r, amplitude) on one background; returns (mu, jacobian (..., 4K + 1)).

    The readable reference of the compiled :func:`normal_equations` (tested against it).
    """
    k = (len(params) - 1) // 4
    mu = np.full(xx.shape, params[-1], dtype=np.float64)
    jac = np.empty(xx.shape + (len(params),))
    jac[..., -1] = 1.0
    for i in range(k):
        x0, y0, r, amp = params[4 * i:4 * i + 4]
        dx, dy = xx - x0, yy - y0
        rho = np.sqrt(dx * dx + dy * dy) + 1e-12
        arg = (rho - r) / (math.sqrt(2.0) * sigma)
        prof = 0.5 * erfc(arg)
        dprof = -np.exp(-arg * arg) / (math.sqrt(2.0 * math.pi) * sigma)  # d prof / d rho
        mu += amp * prof
        jac[..., 4 * i] = amp * dprof * (-dx / rho)
        jac[..., 4 * i + 1] = amp * dprof * (-dy / rho)
        jac[..., 4 * i + 2] = -amp * dprof
        jac[..., 4 * i + 3] = prof
    return mu, jac


def pixel_variance(mu, cam: Camera, background_var):
    """Pixel variance [ADU^2]: the sensor model, or the measured background variance if it is unknown."""
    if cam.sensor_known:
        return np.maximum(mu, 0.0) / cam.gain_e_per_adu + (cam.read_noise_e / cam.gain_e_per_adu) ** 2 + 1.0 / 12.0
    return np.full(mu.shape, background_var)


@njit(cache=True, error_model="numpy")
def normal_equations(win, x_first, y_first, use, p, sigma, gain, read_var, background_var, mu_out):
    """Compiled pass over a window: ``J^T W J``, ``J^T W r``, chi-square, and the model in ``mu_out``.

    The same model and weights as :func:`spot_model` and :func:`pixel_variance`, without the
    window-sized temporaries of the numpy form.  ``gain`` NaN means an unknown sensor: every
    pixel then has ``background_var``.
    """
    n = p.size
    k = (n - 1) // 4
    A = np.zeros((n, n))
    g = np.zeros(n)
    chi2 = 0.0
    j = np.empty(n)
    s2 = math.sqrt(2.0) * sigma
    c = 1.0 / (math.sqrt(2.0 * math.pi) * sigma)
    h, w = win.shape
    for iy in range(h):
        y = y_first + iy
        for ix in range(w):
            x = x_first + ix
            mu = p[n - 1]
            j[n - 1] = 1.0
            for i in range(k):
                dx = x - p[4 * i]
                dy = y - p[4 * i + 1]
                rho = math.sqrt(dx * dx + dy * dy) + 1e-12
                arg = (rho - p[4 * i + 2]) / s2
                amp = p[4 * i + 3]
                if arg > 5.0:  # erfc(5) = 1.5e-12 of the amplitude: outside the disc's edge
                    prof, dprof = 0.0, 0.0
                elif arg < -5.0:  # inside it
                    prof, dprof = 1.0, 0.0
                else:
                    prof = 0.5 * math.erfc(arg)
                    dprof = -math.exp(-arg * arg) * c
                mu += amp * prof
                j[4 * i] = -amp * dprof * dx / rho
                j[4 * i + 1] = -amp * dprof * dy / rho
                j[4 * i + 2] = -amp * dprof
                j[4 * i + 3] = prof
            mu_out[iy, ix] = mu
            if not use[iy, ix]:
                continue
            if gain > 0:
                var = max(mu, 0.0) / gain + read_var + 1.0 / 12.0
            else:
                var = background_var
            r = win[iy, ix] - mu
            chi2 += r * r / var
            for a in range(n):
                ja = j[a] / var
                g[a] += ja * r
                for b in range(a, n):
                    A[a, b] += ja * j[b]
    for a in range(n):
        for b in range(a):
            A[a, b] = A[b, a]
    return A, g, chi2


def warm_up() -> None:
    """Compile the spot-fit kernels now (numba; cached on disk after the first run), not in the first frame."""
    normal_equations(np.zeros((3, 3)), 0.0, 0.0, np.ones((3, 3), bool), np.array([1.0, 1.0, 1.0, 1.0, 0.0]), 1.0,
                     float("nan"), 0.0, 1.0, np.empty((3, 3)))
    _levels(np.zeros(4), np.zeros((3, 3)))


def _sensor_terms(cam: Camera) -> tuple[float, float]:
    if cam.sensor_known:
        return cam.gain_e_per_adu, (cam.read_noise_e / cam.gain_e_per_adu) ** 2
    return float("nan"), 0.0


def _gauss_newton(win, x_first, y_first, use, p, cam, iterations, background_var=1.0):
    """Damped Gauss-Newton; returns ``(p, converged, (fisher, chi2, mu))``.

    The last triple is evaluated at the start of the final step; on convergence that step
    moved the centre by < 1e-4 px, so it stands for the solution (saves a pass).
    """
    gain, read_var = _sensor_terms(cam)
    mu = np.empty_like(win)
    converged = False
    A = chi2_sum = None
    for _ in range(iterations):
        A, g, chi2_sum = normal_equations(win, x_first, y_first, use, p, cam.psf_sigma_px, gain, read_var,
                                          background_var, mu)
        try:
            step = np.linalg.solve(A, g)
        except np.linalg.LinAlgError:
            return None, False, (None, None, None)
        # halve the step until radii and amplitudes stay positive (a damped Gauss-Newton step)
        for _ in range(20):
            trial = p + step
            if np.all(np.isfinite(trial)) and np.all(trial[2:-1:4] > 0) and np.all(trial[3:-1:4] > 0):
                break
            step = step / 2
        else:
            return None, False, (None, None, None)
        p = trial
        if abs(step[0]) < 1e-4 and abs(step[1]) < 1e-4:  # 5 % of a typical 0.002 px sigma
            converged = True
            break
    if not converged:
        A, _, chi2_sum = normal_equations(win, x_first, y_first, use, p, cam.psf_sigma_px, gain, read_var,
                                          background_var, mu)
    return p, converged, (A, chi2_sum, mu)


def _neighbour_start(win, xx, yy, p, foreign) -> np.ndarray:
    """Start values of a joint fit with the neighbouring spot whose light makes up ``foreign``."""
    n_lbl, labels, stats, _ = cv2.connectedComponentsWithStats(foreign.astype(np.uint8), connectivity=8)
    big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    blob = cv2.copyMakeBorder((labels == big).astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    dist = cv2.distanceTransform(blob, cv2.DIST_L2, 5)
    iy, ix = np.unravel_index(int(np.argmax(dist)), dist.shape)
    # the neighbour's visible part is a cap; start it a little beyond its inscribed circle
    nx, ny, nr = xx[0, 0] + ix - 1, yy[0, 0] + iy - 1, float(dist[iy, ix]) + 0.5
    namp = float(np.percentile(win[labels == big], 90)) - p[4]
    return np.array([*p[:4], nx, ny, nr, max(namp, 1.0), p[4]])


def spot_window(image: np.ndarray, x0: float, y0: float, half: int, cam: Camera):
    """The square window of half-width ``half`` around ``(x0, y0)`` as float64, its pixel coordinates, the
    saturated pixels, the border pixels, the background (their median) and the amplitude (99th percentile above
    it): ``(win, xx, yy, saturated, border, background, amplitude)``; None when the window leaves the image or
    holds no light above the background."""
    window = window_levels(image, x0, y0, half)
    if window is None:
        return None
    win, x_first, y_first, border, bg, amp = window
    yy, xx = np.mgrid[y_first:y_first + win.shape[0], x_first:x_first + win.shape[1]].astype(np.float64)
    return win, xx, yy, win >= cam.max_adu, border, bg, amp


def window_levels(image: np.ndarray, x0: float, y0: float, half: int, min_margin: float | None = None):
    """:func:`spot_window` without the pixel coordinates and saturated pixels: ``(win, x_first, y_first, border,
    background, amplitude)``, ``x_first, y_first`` the window's first column and row; None as there.  With
    ``min_margin`` a window that leaves the image is cut at its edges, where ``(x0, y0)`` is at least that far [px]
    inside them (else None)."""
    xi, yi = int(round(x0)), int(round(y0))
    h, w = image.shape
    if xi - half < 0 or yi - half < 0 or xi + half >= w or yi + half >= h:
        if min_margin is None or min(x0, y0, w - 1 - x0, h - 1 - y0) < min_margin:
            return None
    x_first, y_first = max(xi - half, 0), max(yi - half, 0)
    win = image[y_first:min(yi + half + 1, h), x_first:min(xi + half + 1, w)].astype(np.float64)
    border = np.concatenate([win[0], win[-1], win[:, 0], win[:, -1]])
    bg, top = _levels(border, win)
    amp = top - bg
    if amp <= 0:
        return None
    return win, x_first, y_first, border, bg, amp


@njit(cache=True)
def _levels(border, win):
    """The border's median and the window's 99th percentile."""
    return np.median(border), np.percentile(win, 99.0)


def fit_spot(image: np.ndarray, x0: float, y0: float, r0: float, cam: Camera, *,
             iterations: int = 10, neighbour: str = "joint") -> SpotFit | None:
    """Weighted least-squares fit of the disc-spot model in a window around ``(x0, y0)``.

    Light from a neighbouring spot inside the window (pixels beyond ``r + 3 sigma`` from the
    fitted centre that are brighter than the model by more than 5 standard deviations)
    triggers a joint fit of both discs (``neighbour="joint"``), or a fit of this spot alone with the
    neighbour's light masked out (``"mask"``: for a neighbour that is not a disc, e.g. a streak);
    ``SpotFit.blended`` says so.  Saturated pixels are left out.  The centre's covariance is the inverse Fisher matrix; with a known sensor it is
    scaled up by the reduced chi-square only when the fit is worse than the noise (and not for
    a blended spot, whose neighbour's imperfect model leaves residuals near the tip that do not
    move it); with an unknown sensor it is scaled to the residuals.  Returns ``None`` when the
    window leaves the image or the fit diverges.
    """
    sigma = cam.psf_sigma_px
    half = int(math.ceil(r0 + 4 * sigma + 4))
    window = spot_window(image, x0, y0, half, cam)
    if window is None:
        return None
    win, xx, yy, sat, border, bg, amp = window
    xf, yf = float(xx[0, 0]), float(yy[0, 0])
    use = ~sat
    bvar = max(float(np.var(border)), 1.0 / 12.0)
    p, converged, (fisher, chi2_sum, mu) = _gauss_newton(win, xf, yf, use, np.array([x0, y0, r0, amp, bg]), cam,
                                                         iterations, bvar)
    if p is None:
        return None
    excess = (win - mu) / np.sqrt(pixel_variance(mu, cam, bvar))
    foreign = (np.hypot(xx - p[0], yy - p[1]) > p[2] + 3 * sigma) & (excess > 5.0)
    blended = bool(foreign.sum() >= 3)
    if blended and neighbour == "mask":
        grown = cv2.dilate(foreign.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        use = use & ~grown
        p, converged, (fisher, chi2_sum, mu) = _gauss_newton(win, xf, yf, use, p, cam, iterations, bvar)
        if p is None:
            return None
    elif blended:
        p, converged, (fisher, chi2_sum, mu) = _gauss_newton(win, xf, yf, use, _neighbour_start(win, xx, yy, p, foreign),
                                                             cam, 2 * iterations, bvar)
        if p is None:
            return None
    if abs(p[0] - x0) > half or abs(p[1] - y0) > half:
        return None
    dof = max(int(use.sum()) - len(p), 1)
    chi2_red = float(chi2_sum / dof)
    near = use & (np.hypot(xx - p[0], yy - p[1]) <= p[2] + 3 * sigma)
    if blended and neighbour == "joint":
        near &= np.hypot(xx - p[0], yy - p[1]) <= np.hypot(xx - p[4], yy - p[5])
    n_near = int(near.sum())
    chi2_own = (float(((win - mu)[near] ** 2 / pixel_variance(mu[near], cam, bvar)).sum() / max(n_near - 5, 1))
                if n_near > 10 else chi2_red)
    # a blended spot is judged where its own light is
    scale_chi2 = chi2_own if blended else chi2_red
    try:
        finv = np.linalg.inv(fisher)
        if blended and cam.sensor_known:
            cov = finv[:2, :2]
        else:
            cov = finv[:2, :2] * (max(1.0, scale_chi2) if cam.sensor_known else scale_chi2)
    except np.linalg.LinAlgError:
        return None
    return SpotFit(float(p[0]), float(p[1]), float(p[2]), float(p[3]), float(p[-1]), cov, chi2_red,
                   bool(sat.any()), converged, blended, chi2_own=chi2_own)


def spot_crb_px(x: float, y: float, radius_px: float, amplitude_adu: float, background_adu: float, cam) -> float:
    """Cramér-Rao bound (standard deviation per axis, px) of the disc-spot centre.

    Exact Fisher matrix of :func:`spot_model` for pixel variances ``mu / gain + (read noise /
    gain)^2 + 1/12`` [ADU^2], all five parameters free.  ``cam`` needs ``psf_sigma_px``,
    ``gain_e_per_adu`` and ``read_noise_e``.
    """
    half = int(math.ceil(radius_px + 6 * cam.psf_sigma_px + 4))
    xi, yi = int(round(x)), int(round(y))
    yy, xx = np.mgrid[yi - half:yi + half + 1, xi - half:xi + half + 1].astype(np.float64)
    mu, jac = spot_model(np.array([x, y, radius_px, amplitude_adu, background_adu]), xx, yy, cam.psf_sigma_px)
    var = mu / cam.gain_e_per_adu + (cam.read_noise_e / cam.gain_e_per_adu) ** 2 + 1.0 / 12.0
    jf = jac.reshape(-1, 5)
    fisher = (jf / var.reshape(-1, 1)).T @ jf
    cov = np.linalg.inv(fisher)
    return float(math.sqrt(0.5 * (cov[0, 0] + cov[1, 1])))
