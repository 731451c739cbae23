"""Tracking: from a video to the tip direction theta(t), phi(t) with honest error bars.

Works on any video OpenCV decodes; it reads only the video, ``camera.json`` and the
protocol's marker geometry; never the simulator or a renderer's ``truth.csv``
(this module imports neither).

Per frame:

1. **find** the tip spot: threshold and connected components in a window around the
   position predicted from the previous frames; a full-frame search only to acquire or
   reacquire.  Candidates must have the tip's expected size (from the camera and the
   marker radius) and lie on the tip's sphere; a spurious bright spot fails one of these.
2. **localise** it by weighted least squares of the rendered-spot model (a disc of
   radius ``r`` convolved with the camera's Gaussian PSF, on a flat background), with
   pixel variances from the sensor model ``mu / gain + (read noise / gain)^2 + 1/12``
   [ADU^2]; saturated pixels are left out.  The covariance is the inverse Fisher matrix,
   scaled up by the reduced chi-square when the model fits worse than the noise (motion
   blur).
3. **3D**: the undistorted ray through the spot centre meets the sphere of the tip's
   radius about the pivot (the nearer intersection); ``theta, phi`` follow, with their
   covariance propagated through the numerical Jacobian.

4. **camera model** (after the loop): the per-frame covariance holds the localisation
   error only.  The camera model's own uncertainty (the intrinsics covariance that
   ``gyrorig calibrate`` writes, the pose found from the fiducials, or a
   ``pose_covariance`` in ``camera.json``) moves every frame's angles together.  It is
   propagated as independent one-sigma *modes*: for mode ``k`` the columns
   ``theta_cam_k_rad, phi_cam_k_rad`` give each frame's angle shift (the pose re-solved
   from the fiducials when the intrinsics move).  The fit turns these into nuisance
   parameters with unit Gaussian priors.  An exact camera (the renderer's) has none.

Outputs (``track_video``): ``angles.csv`` (``frame, t_s, theta_rad, phi_rad,
theta_sigma_rad, phi_sigma_rad, theta_phi_corr, tip_x, tip_y, tip_z, quality``, then
``exposure_s`` (the camera's exposure; ``t_s`` is its middle, and the angles are those of the
spot's centroid, i.e. averaged over it: the fit models that average), and
``theta_cam_k_rad, phi_cam_k_rad`` for each camera mode) and ``markers.csv`` (raw
detections: ``frame, t_s, marker, x_px, y_px, sigma_x_px, sigma_y_px, radius_px,
amplitude_adu, background_adu, chi2_red, quality``).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from numba import njit
from scipy.special import erfc

from . import _io
from .protocols import Protocol, ProtocolError

logger = logging.getLogger(__name__)

__all__ = ["TrackingCamera", "load_camera", "estimate_pose", "SpotFit", "fit_spot", "tip_from_pixel",
           "tips_from_pixels", "camera_modes", "track_video", "TrackingError", "ANGLE_COLUMNS", "MARKER_COLUMNS",
           "INTRINSIC_PARAMETERS"]

#: intrinsics an ``intrinsics_covariance`` in ``camera.json`` may refer to (``gyrorig calibrate`` writes the
#: first eight); a pose covariance is over ``(rvec, tvec)``
INTRINSIC_PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")

ANGLE_COLUMNS = ("frame", "t_s", "theta_rad", "phi_rad", "theta_sigma_rad", "phi_sigma_rad", "theta_phi_corr",
                 "tip_x", "tip_y", "tip_z", "quality")
MARKER_COLUMNS = ("frame", "t_s", "marker", "x_px", "y_px", "sigma_x_px", "sigma_y_px", "radius_px",
                  "amplitude_adu", "background_adu", "chi2_red", "quality")


class TrackingError(RuntimeError):
    """The video cannot be tracked (unreadable, camera mismatch, marker never found)."""


@dataclass(frozen=True)
class TrackingCamera:
    """What the tracker needs from ``camera.json`` (OpenCV conventions)."""

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    width_px: int
    height_px: int
    fps: float
    exposure_s: float
    shutter: str
    readout_time_s: float
    psf_sigma_px: float
    gain_e_per_adu: float
    read_noise_e: float
    max_adu: int
    #: covariance of the intrinsics named in ``intrinsics_parameters`` (None: exact)
    intrinsics_covariance: np.ndarray | None = None
    intrinsics_parameters: tuple[str, ...] = ()
    #: covariance of ``(rvec, tvec)`` (None: exact, or found from the fiducials)
    pose_covariance: np.ndarray | None = None

    @property
    def has_pose(self) -> bool:
        """True when the pose relative to the pivot is known."""
        return bool(np.all(np.isfinite(self.rvec)) and np.all(np.isfinite(self.tvec)))

    @cached_property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation matrix ``R(rvec)`` (computed once per camera)."""
        return cv2.Rodrigues(self.rvec)[0]

    @cached_property
    def centre_m(self) -> np.ndarray:
        """Camera centre in the lab (pivot frame). [m]"""
        return -self.rotation.T @ self.tvec


def load_camera(path: str | Path, *, require_pose: bool = True) -> TrackingCamera:
    """Read ``camera.json`` (as written by ``gyrorig render``, or by ``gyrorig calibrate``).

    Without a pose (``rvec``, ``tvec``) the camera is returned with NaN pose when
    ``require_pose=False``; :func:`estimate_pose` then finds it from the fiducials.
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise TrackingError(f"cannot read camera file {path}: {exc}") from exc
    missing = [k for k in ("camera_matrix", "dist_coeffs", "image_size") if k not in d]
    if missing:
        raise TrackingError(f"{path}: missing key(s) {', '.join(missing)}")
    if ("rvec" not in d or "tvec" not in d) and require_pose:
        raise TrackingError(f"{path}: no camera pose (rvec, tvec) relative to the pivot; "
                            "the tracker needs it to turn pixels into directions")
    sensor = d.get("sensor", {})
    bits = int(sensor.get("bit_depth", 8))
    cov_i = names = cov_p = None
    if "intrinsics_covariance" in d:
        names = tuple(d.get("intrinsics_parameters", INTRINSIC_PARAMETERS[:8]))
        unknown = [n for n in names if n not in INTRINSIC_PARAMETERS]
        cov_i = np.asarray(d["intrinsics_covariance"], dtype=float)
        if unknown or cov_i.shape != (len(names), len(names)):
            raise TrackingError(f"{path}: intrinsics_covariance must be a {len(names)} x {len(names)} matrix over "
                                f"intrinsics_parameters (any of {', '.join(INTRINSIC_PARAMETERS)}); unknown: {unknown}")
    if "pose_covariance" in d:
        cov_p = np.asarray(d["pose_covariance"], dtype=float)
        if cov_p.shape != (6, 6):
            raise TrackingError(f"{path}: pose_covariance must be 6 x 6 over (rvec, tvec), not {cov_p.shape}")
    for key, c in (("intrinsics_covariance", cov_i), ("pose_covariance", cov_p)):
        if c is not None and (not np.all(np.isfinite(c)) or np.linalg.eigvalsh(0.5 * (c + c.T)).min()
                              < -1e-9 * max(np.abs(c).max(), 1e-300)):
            raise TrackingError(f"{path}: {key} must be finite, symmetric and positive semi-definite")
    return TrackingCamera(
        np.asarray(d["camera_matrix"], dtype=float), np.asarray(d["dist_coeffs"], dtype=float).ravel(),
        np.asarray(d.get("rvec", [np.nan] * 3), dtype=float).ravel(),
        np.asarray(d.get("tvec", [np.nan] * 3), dtype=float).ravel(),
        int(d["image_size"][0]), int(d["image_size"][1]), float(d.get("fps", np.nan)), float(d.get("exposure_s", 0.0)),
        d.get("shutter", "global"), float(d.get("readout_time_s", 0.0)), float(d.get("psf_sigma_px", 1.0)),
        float(sensor.get("gain_e_per_adu", np.nan)), float(sensor.get("read_noise_e", 0.0)), (1 << bits) - 1,
        cov_i, names or (), cov_p)


# --------------------------------------------------------------------------------------
# spot localisation


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


def _model(params, xx, yy, sigma):
    """K discs (each x, y, r, amplitude) on one background; returns (mu, jacobian (..., 4K + 1))."""
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


def _variance(mu, cam, background_var):
    """Pixel variance [ADU^2]: the sensor model, or the measured background variance if it is unknown."""
    if math.isfinite(cam.gain_e_per_adu):
        return np.maximum(mu, 0.0) / cam.gain_e_per_adu + (cam.read_noise_e / cam.gain_e_per_adu) ** 2 + 1.0 / 12.0
    return np.full(mu.shape, background_var)


@njit(cache=True, error_model="numpy")
def _normal_equations(win, x_first, y_first, use, p, sigma, gain, read_var, background_var, mu_out):
    """Compiled pass over a window: ``J^T W J``, ``J^T W r``, chi-square, and the model in ``mu_out``.

    The same model and weights as :func:`_model` and :func:`_variance` (which stay the
    readable reference and are tested against this), without the window-sized temporaries
    of the numpy form: one spot fit costs tens of microseconds instead of milliseconds.
    ``gain`` NaN means an unknown sensor: every pixel then has ``background_var``.
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
    """Compile the spot-fit kernel now (numba; cached on disk after the first run), not in the first frame."""
    _normal_equations(np.zeros((3, 3)), 0.0, 0.0, np.ones((3, 3), bool), np.array([1.0, 1.0, 1.0, 1.0, 0.0]), 1.0,
                      float("nan"), 0.0, 1.0, np.empty((3, 3)))


def _sensor_terms(cam: TrackingCamera) -> tuple[float, float]:
    if math.isfinite(cam.gain_e_per_adu):
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
        A, g, chi2_sum = _normal_equations(win, x_first, y_first, use, p, cam.psf_sigma_px, gain, read_var,
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
        A, _, chi2_sum = _normal_equations(win, x_first, y_first, use, p, cam.psf_sigma_px, gain, read_var,
                                           background_var, mu)
    return p, converged, (A, chi2_sum, mu)


def fit_spot(image: np.ndarray, x0: float, y0: float, r0: float, cam: TrackingCamera, *,
             iterations: int = 10) -> SpotFit | None:
    """Weighted least-squares fit of the disc-spot model in a window around ``(x0, y0)``.

    Light from a neighbouring spot inside the window (pixels beyond ``r + 3 sigma`` from the
    fitted centre that are brighter than the model by more than 5 standard deviations)
    triggers a joint fit of both discs; ``SpotFit.blended`` says so.  Saturated
    pixels are left out.  Returns ``None`` when the window leaves the image or the fit
    diverges.
    """
    sigma = cam.psf_sigma_px
    half = int(math.ceil(r0 + 4 * sigma + 4))
    xi, yi = int(round(x0)), int(round(y0))
    h, w = image.shape
    if xi - half < 0 or yi - half < 0 or xi + half >= w or yi + half >= h:
        return None
    win = image[yi - half:yi + half + 1, xi - half:xi + half + 1].astype(np.float64)
    yy, xx = np.mgrid[yi - half:yi + half + 1, xi - half:xi + half + 1].astype(np.float64)
    xf, yf = float(xi - half), float(yi - half)
    sat = win >= cam.max_adu
    use = ~sat
    border = np.concatenate([win[0], win[-1], win[:, 0], win[:, -1]])
    bg = float(np.median(border))
    amp = float(np.percentile(win, 99)) - bg
    if amp <= 0:
        return None
    known = math.isfinite(cam.gain_e_per_adu)
    bvar = max(float(np.var(border)), 1.0 / 12.0)
    p, converged, (fisher, chi2_sum, mu) = _gauss_newton(win, xf, yf, use, np.array([x0, y0, r0, amp, bg]), cam,
                                                         iterations, bvar)
    if p is None:
        return None
    excess = (win - mu) / np.sqrt(_variance(mu, cam, bvar))
    foreign = (np.hypot(xx - p[0], yy - p[1]) > p[2] + 3 * sigma) & (excess > 5.0)
    blended = bool(foreign.sum() >= 3)
    if blended:
        # a neighbouring spot reaches into the window: fit both discs jointly
        n_lbl, labels, stats, _ = cv2.connectedComponentsWithStats(foreign.astype(np.uint8), connectivity=8)
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        blob = np.pad((labels == big).astype(np.uint8), 1)
        dist = cv2.distanceTransform(blob, cv2.DIST_L2, 5)
        iy, ix = np.unravel_index(int(np.argmax(dist)), dist.shape)
        # the neighbour's visible part is a cap; start it a little beyond its inscribed circle
        nx, ny, nr = xx[0, 0] + ix - 1, yy[0, 0] + iy - 1, float(dist[iy, ix]) + 0.5
        namp = float(np.percentile(win[labels == big], 90)) - p[4]
        p2 = np.array([*p[:4], nx, ny, nr, max(namp, 1.0), p[4]])
        p2, converged, (fisher, chi2_sum, mu) = _gauss_newton(win, xf, yf, use, p2, cam, 2 * iterations, bvar)
        if p2 is None:
            return None
        p = p2
    if abs(p[0] - x0) > half or abs(p[1] - y0) > half:
        return None
    dof = max(int(use.sum()) - len(p), 1)
    chi2_red = float(chi2_sum / dof)
    scale_chi2 = chi2_red
    if blended:
        # judge the fit where the tip's own light is: a neighbour's imperfect model elsewhere
        # in the window says nothing about the tip's position error
        near = use & (np.hypot(xx - p[0], yy - p[1]) <= p[2] + 3 * sigma)
        n_near = int(near.sum())
        if n_near > 10:
            scale_chi2 = float(((win - mu)[near] ** 2 / _variance(mu[near], cam, bvar)).sum() / max(n_near - 5, 1))
    try:
        finv = np.linalg.inv(fisher)
        if blended and known:
            # the neighbour's imperfect model leaves residuals near the tip (often a reduced
            # chi-square above 4 there) that do not move it: scaled by their chi-square, blended
            # frames' errors were 0.87 of their sigma (B2 at 640x480, 718 frames in 6 records; 0.91
            # with a sandwich estimate, 0.91 scaling only above 4), with the bound alone 0.95-0.96,
            # as in frames without a neighbour (0.95-1.00).  The smoother's innovation gate
            # catches a blend that does move the tip.
            cov = finv[:2, :2]
        else:
            # a known noise model: inflate only when the fit is worse than the noise; else scale to the residuals
            cov = finv[:2, :2] * (max(1.0, scale_chi2) if known else scale_chi2)
    except np.linalg.LinAlgError:
        return None
    return SpotFit(float(p[0]), float(p[1]), float(p[2]), float(p[3]), float(p[-1]), cov, chi2_red,
                   bool(sat.any()), converged, blended)


# --------------------------------------------------------------------------------------
# geometry


def tips_from_pixels(xy_px: np.ndarray, cam: TrackingCamera, radius_m: float) -> np.ndarray:
    """Unit tip directions (n, 3) for pixel positions (n, 2); NaN where the ray misses the sphere."""
    xy = np.asarray(xy_px, dtype=np.float64).reshape(-1, 1, 2)
    n = cv2.undistortPoints(xy, cam.camera_matrix, cam.dist_coeffs).reshape(-1, 2)
    d = np.column_stack([n, np.ones(len(n))]) @ cam.rotation
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = cam.centre_m
    b = d @ c
    disc = b * b - (c @ c - radius_m**2)
    with np.errstate(invalid="ignore"):
        s = -b - np.sqrt(np.where(disc >= 0, disc, np.nan))
    return (c + s[:, None] * d) / radius_m


def tip_from_pixel(x_px: float, y_px: float, cam: TrackingCamera, radius_m: float) -> np.ndarray | None:
    """Unit tip direction: the ray through the pixel meets the sphere ``|X| = radius_m`` (nearer point)."""
    n = cv2.undistortPoints(np.array([[[x_px, y_px]]], dtype=np.float64), cam.camera_matrix, cam.dist_coeffs).reshape(2)
    d = cam.rotation.T @ np.array([n[0], n[1], 1.0])
    d /= np.linalg.norm(d)
    c = cam.centre_m
    b = c @ d
    disc = b * b - (c @ c - radius_m**2)
    if disc < 0:
        return None
    s = -b - math.sqrt(disc)
    return (c + s * d) / radius_m


def _angles(tip: np.ndarray) -> tuple[float, float]:
    return math.atan2(math.hypot(tip[0], tip[1]), tip[2]), math.atan2(tip[0], -tip[1])


def _angle_covariance(x: float, y: float, cov: np.ndarray, cam: TrackingCamera, radius_m: float):
    """theta, phi, tip and their 2x2 covariance (numerical Jacobian of pixel -> angles)."""
    tip = tip_from_pixel(x, y, cam, radius_m)
    if tip is None:
        return None
    th, ph = _angles(tip)
    jac = np.zeros((2, 2))
    eps = 0.05
    for k, (dx, dy) in enumerate([(eps, 0.0), (0.0, eps)]):
        tp, tm = tip_from_pixel(x + dx, y + dy, cam, radius_m), tip_from_pixel(x - dx, y - dy, cam, radius_m)
        if tp is None or tm is None:
            return None
        (a1, b1), (a2, b2) = _angles(tp), _angles(tm)
        jac[0, k] = (a1 - a2) / (2 * eps)
        jac[1, k] = math.remainder(b1 - b2, 2 * math.pi) / (2 * eps)
    return th, ph, tip, jac @ cov @ jac.T


# --------------------------------------------------------------------------------------
# camera pose from the lab-fixed fiducials


def _fiducials(protocol: Protocol) -> dict[str, np.ndarray]:
    markers = protocol.extra.get("markers") or {}
    return {name: np.asarray(m["position_m"], dtype=float) for name, m in markers.items()
            if isinstance(m, dict) and m.get("body") == "lab" and m.get("kind", "dot") == "dot"}


def estimate_pose(video: str | Path, camera: TrackingCamera, protocol: Protocol, *, span_s: float = 2.0,
                  samples: int = 15, max_rms_px: float = 1.0) -> tuple[TrackingCamera, dict]:
    """Camera pose relative to the pivot from the protocol's lab-fixed fiducials.

    The per-pixel median of frames spread over the first ``span_s`` seconds keeps what
    does not move (the fiducials) and drops the moving markers.  Static spots are
    localised to sub-pixel precision, then matched to the fiducials by trying every
    assignment with ``cv2.solvePnP`` (SQPnP, refined by Levenberg-Marquardt): the
    assignment with the smallest reprojection error, the fiducials in front of the camera
    and the camera above their plane (they face up) wins; the largest set of spots that
    fits is used, so one stray static spot or one hidden fiducial does no harm.  Needs at least 4 fiducials visible; their layout must have no
    rotational symmetry (else the azimuth is ambiguous), which the bundled protocols'
    irregular circle satisfies.

    Returns the camera with its pose and a summary (matched fiducials, RMS error in px).
    """
    import itertools

    fid = _fiducials(protocol)
    if len(fid) < 4:
        raise TrackingError(f"the camera file has no pose and the protocol has {len(fid)} lab-fixed fiducial(s) "
                            "(body = 'lab'); at least 4 are needed to find the pose")
    cap = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise TrackingError(f"cannot open video {video}")
    cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    fps = camera.fps if math.isfinite(camera.fps) else float(cap.get(cv2.CAP_PROP_FPS))
    n_span = max(int(span_s * fps), samples)
    stack = []
    for k in range(n_span):
        ok, frame = cap.read()
        if not ok:
            break
        if k % max(n_span // samples, 1) == 0:
            stack.append(frame[:, :, 0] if frame.ndim == 3 else frame)
    cap.release()
    if len(stack) < 3:
        raise TrackingError(f"{video}: too few frames to find the static fiducials")
    median = np.median(np.stack(stack), axis=0).astype(stack[0].dtype)
    sample = median[::8, ::8]
    bg = float(np.median(sample))
    noise = max(float(np.std(sample[sample < bg + 20])), 0.5)
    spots = []
    for cx, cy, r in _candidates(median, 0, 0, median.shape[1], median.shape[0], bg + max(8 * noise, 4.0)):
        fit = fit_spot(median, cx, cy, r, camera)
        if fit is not None:
            spots.append((fit.x_px, fit.y_px, fit.amplitude_adu, fit.cov_xy))
    spots = sorted(spots, key=lambda s: -s[2])[:8]
    if len(spots) < 4:
        raise TrackingError(f"{video}: found {len(spots)} static spots; at least 4 fiducials must be visible")
    names = list(fid)
    obj_all = np.array([fid[n] for n in names])
    best = None
    # the largest set of spots that some assignment fits (a stray static spot or a hidden
    # fiducial only removes one point)
    for n_use in range(min(len(spots), len(names)), 3, -1):
        for spot_set in itertools.combinations(range(len(spots)), n_use):
            img = np.array([[spots[i][0], spots[i][1]] for i in spot_set], dtype=np.float64)
            for perm in itertools.permutations(range(len(names)), n_use):
                obj = obj_all[list(perm)]
                # SQPnP (globally optimal; IPPE picks the wrong one of its two planar solutions when the
                # fiducial plane faces the camera), then Levenberg-Marquardt refinement from it
                ok, rvec, tvec = cv2.solvePnP(obj, img, camera.camera_matrix, camera.dist_coeffs,
                                              flags=cv2.SOLVEPNP_SQPNP)
                if not ok:
                    continue
                ok, rvec, tvec = cv2.solvePnP(obj, img, camera.camera_matrix, camera.dist_coeffs, rvec, tvec,
                                              useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
                if not ok:
                    continue
                rot = cv2.Rodrigues(rvec)[0]
                if np.any((obj @ rot.T + tvec.ravel())[:, 2] <= 0):
                    continue
                # the fiducials face up from the cup base: a camera that sees them is above their plane
                # (this also rejects the mirror solution of a planar pose)
                if (-rot.T @ tvec.ravel())[2] <= obj_all[:, 2].max():
                    continue
                proj = cv2.projectPoints(obj, rvec, tvec, camera.camera_matrix, camera.dist_coeffs)[0].reshape(-1, 2)
                rms = float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))
                if best is None or rms < best[0]:
                    best = (rms, rvec.ravel(), tvec.ravel(), [names[j] for j in perm], obj, img,
                            [spots[i][3] for i in spot_set])
        if best is not None and best[0] <= max_rms_px:
            break
    if best is None or best[0] > max_rms_px:
        rms = "no solution" if best is None else f"{best[0]:.3g} px"
        raise TrackingError(f"{video}: no assignment of the {len(spots)} static spots to the fiducials "
                            f"fits (best reprojection error {rms}, limit {max_rms_px} px)")
    from dataclasses import replace

    rms, rvec, tvec, matched, obj, img, covs = best
    pose_cov = _pose_covariance(obj, img, covs, camera, rvec, tvec)
    posed = replace(camera, rvec=rvec, tvec=tvec, pose_covariance=pose_cov)
    return posed, {"fiducials_matched": matched, "pose_rms_px": rms, "static_spots": len(spots),
                   "object_points_m": obj.tolist(), "image_points_px": img.tolist(),
                   "pose_sigma": np.sqrt(np.diag(pose_cov)).tolist()}


def _pose_covariance(obj, img, covs, camera: TrackingCamera, rvec, tvec) -> np.ndarray:
    """Covariance of (rvec, tvec) from the fiducials' localisation errors (intrinsics held fixed).

    Weighted by each fiducial's covariance from the spot fit on the median image, and
    scaled up by the reduced chi-square of the reprojection when it exceeds 1.
    """
    proj, jac = cv2.projectPoints(obj, rvec, tvec, camera.camera_matrix, camera.dist_coeffs)
    r = (img - proj.reshape(-1, 2)).ravel()
    Cinv = np.zeros((2 * len(obj), 2 * len(obj)))
    for i, c in enumerate(covs):
        Cinv[2 * i:2 * i + 2, 2 * i:2 * i + 2] = np.linalg.inv(c)
    J = jac[:, :6]
    dof = max(2 * len(obj) - 6, 1)
    chi2_red = float(r @ Cinv @ r) / dof
    return np.linalg.pinv(J.T @ Cinv @ J, hermitian=True) * max(1.0, chi2_red)


def _with_intrinsics(cam: TrackingCamera, names: tuple[str, ...], delta: np.ndarray) -> TrackingCamera:
    from dataclasses import replace

    K = cam.camera_matrix.copy()
    dist = np.zeros(max(5, cam.dist_coeffs.size))
    dist[:cam.dist_coeffs.size] = cam.dist_coeffs
    where = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
    for name, d in zip(names, delta):
        if name in where:
            K[where[name]] += d
        else:
            dist[("k1", "k2", "p1", "p2", "k3").index(name)] += d
    return replace(cam, camera_matrix=K, dist_coeffs=dist)


def _angles_of(tips: np.ndarray) -> np.ndarray:
    """(n, 2) theta, phi of unit tip directions (n, 3)."""
    return np.column_stack([np.arctan2(np.hypot(tips[:, 0], tips[:, 1]), tips[:, 2]),
                            np.arctan2(tips[:, 0], -tips[:, 1])])


def camera_modes(xy_px: np.ndarray, cam: TrackingCamera, radius_m: float, fiducials: dict | None = None,
                 min_effect_rad: float = 0.0) -> np.ndarray:
    """Angle shifts of each frame for independent one-sigma moves of the camera model.

    Parameters
    ----------
    xy_px : (n, 2) array
        The tip's pixel positions (the measurements, held fixed).
    cam : TrackingCamera
        With ``intrinsics_covariance`` and/or ``pose_covariance``.
    fiducials : dict, optional
        ``object_points_m``, ``image_points_px`` when the pose came from the fiducials: a
        move of the intrinsics then re-solves the pose from them, as the tracker would.
    min_effect_rad : float
        Modes whose largest shift is below this are dropped.

    Returns
    -------
    (m, n, 2) array: ``[k, i] = (dtheta, dphi)`` of frame ``i`` for mode ``k`` (central
    differences over +-1 sigma along each eigenvector of the covariance).
    """
    from dataclasses import replace

    xy = np.asarray(xy_px, float).reshape(-1, 2)
    moves = []
    if cam.intrinsics_covariance is not None:
        lam, vec = np.linalg.eigh(0.5 * (cam.intrinsics_covariance + cam.intrinsics_covariance.T))
        for k in np.flatnonzero(lam > 1e-12 * max(lam.max(), 1e-300)):
            d = math.sqrt(lam[k]) * vec[:, k]
            moves.append([_with_intrinsics(cam, cam.intrinsics_parameters, sign * d) for sign in (1.0, -1.0)])
    if fiducials is not None and moves:
        obj = np.asarray(fiducials["object_points_m"], float)
        img = np.asarray(fiducials["image_points_px"], float)
        for pair in moves:
            for j, c in enumerate(pair):
                ok, rv, tv = cv2.solvePnP(obj, img, c.camera_matrix, c.dist_coeffs, cam.rvec.copy(), cam.tvec.copy(),
                                          useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
                if ok:
                    pair[j] = replace(c, rvec=rv.ravel(), tvec=tv.ravel())
    if cam.pose_covariance is not None:
        lam, vec = np.linalg.eigh(0.5 * (cam.pose_covariance + cam.pose_covariance.T))
        for k in np.flatnonzero(lam > 1e-12 * max(lam.max(), 1e-300)):
            d = math.sqrt(lam[k]) * vec[:, k]
            moves.append([replace(cam, rvec=cam.rvec + sign * d[:3], tvec=cam.tvec + sign * d[3:])
                          for sign in (1.0, -1.0)])
    out = []
    for plus, minus in moves:
        ap, am = _angles_of(tips_from_pixels(xy, plus, radius_m)), _angles_of(tips_from_pixels(xy, minus, radius_m))
        dv = 0.5 * np.column_stack([ap[:, 0] - am[:, 0], np.remainder(ap[:, 1] - am[:, 1] + np.pi, 2 * np.pi) - np.pi])
        dv = np.where(np.isfinite(dv), dv, 0.0)  # a ray that leaves the sphere under the move: no shift known
        if np.abs(dv).max(initial=0.0) > min_effect_rad:
            out.append(dv)
    return np.array(out).reshape(len(out), len(xy), 2)


# --------------------------------------------------------------------------------------
# the frame's own dots (crossbar): the frame's rotation angle about the axis


@dataclass(frozen=True)
class _DotSpec:
    name: str
    body_m: np.ndarray  # position on the frame (axis along z)
    radius_m: float

    @property
    def angle_rad(self) -> float:
        return math.atan2(self.body_m[1], self.body_m[0])

    @property
    def rho_m(self) -> float:
        return math.hypot(self.body_m[0], self.body_m[1])


def _dot_specs(protocol: Protocol) -> list[_DotSpec]:
    """Frame-fixed dots off the axis (e.g. the crossbar): they give the frame's angle about the axis."""
    out = []
    for name, m in (protocol.extra.get("markers") or {}).items():
        if (name != "tip" and isinstance(m, dict) and m.get("body") == "frame" and m.get("kind", "dot") == "dot"
                and math.hypot(*m["position_m"][:2]) > 1e-6):
            out.append(_DotSpec(name, np.asarray(m["position_m"], float), float(m["radius_m"])))
    return out


def _axis_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line of nodes ``a`` and ``b = n x a`` for the tip direction ``n`` (Goldstein x-convention)."""
    phi = math.atan2(n[0], -n[1])
    c, s = math.cos(phi), math.sin(phi)
    return np.array([c, s, 0.0]), np.array([-n[2] * s, n[2] * c, n[0] * s - n[1] * c])


def _dot_position(spec: _DotSpec, n: np.ndarray, psi: float) -> np.ndarray:
    a, b = _axis_basis(n)
    ang = psi + spec.angle_rad
    return spec.rho_m * (math.cos(ang) * a + math.sin(ang) * b) + spec.body_m[2] * n


def _dot_angle(x_px: float, y_px: float, spec: _DotSpec, n: np.ndarray, cam: TrackingCamera) -> float | None:
    """The frame angle psi implied by a dot seen at a pixel (None if the ray cannot meet its circle).

    The ray meets the sphere ``|X| = |p|`` twice; the intersection whose height along the
    axis is nearer the dot's is taken, and rejected if it is off the dot's circle by more
    than a quarter of its radius.
    """
    und = cv2.undistortPoints(np.array([[[x_px, y_px]]], np.float64), cam.camera_matrix, cam.dist_coeffs).reshape(2)
    d = cam.rotation.T @ np.array([und[0], und[1], 1.0])
    d /= np.linalg.norm(d)
    c = cam.centre_m
    b_ = c @ d
    disc = b_ * b_ - (c @ c - float(spec.body_m @ spec.body_m))
    if disc < 0:
        return None
    best = None
    for s in (-b_ - math.sqrt(disc), -b_ + math.sqrt(disc)):
        X = c + s * d
        off = abs(X @ n - spec.body_m[2])
        if best is None or off < best[0]:
            best = (off, X)
    off, X = best
    v = X - (X @ n) * n
    if off > 0.25 * spec.rho_m or abs(np.linalg.norm(v) - spec.rho_m) > 0.25 * spec.rho_m:
        return None
    a, b = _axis_basis(n)
    return math.atan2(v @ b, v @ a) - spec.angle_rad


class _DotTracker:
    """Follows the frame's dots from frame to frame; gives the frame angle psi and its sigma.

    With two dots symmetric about the axis (the bundled crossbar) which is which cannot be
    told from the images: psi is then known modulo pi, and is continuous within a record.
    """

    LOST_AFTER = 5  # frames without any dot before a fresh acquisition

    def __init__(self, specs: list[_DotSpec], cam: TrackingCamera):
        self.specs = specs
        self.cam = cam
        depth = float(np.linalg.norm(cam.centre_m))
        self.r_px = {s.name: cam.camera_matrix[0, 0] * s.radius_m / depth for s in specs}
        self.psi = None
        self.rate = 0.0
        self.t = None
        self.misses = 0
        self.last_r = dict(self.r_px)

    def _project(self, X: np.ndarray) -> np.ndarray:
        return cv2.projectPoints(X.reshape(-1, 1, 3), self.cam.rvec, self.cam.tvec, self.cam.camera_matrix,
                                 self.cam.dist_coeffs)[0].reshape(-1, 2)

    def _acquire(self, image, n, tip_xy, r_tip, threshold):
        spec = self.specs[0]
        circle = self._project(np.array([_dot_position(spec, n, q) for q in np.linspace(0, 2 * np.pi, 25)[:-1]]))
        r = self.r_px[spec.name]
        h, w = image.shape
        x0, y0 = circle.min(axis=0) - 3 * r - 5
        x1, y1 = circle.max(axis=0) + 3 * r + 5
        cand = _candidates(image, max(int(x0), 0), max(int(y0), 0), min(int(x1), w), min(int(y1), h), threshold)
        for cx, cy, cr in sorted(cand, key=lambda c: -c[2]):
            if not 0.5 * r <= cr <= 1.6 * r or math.hypot(cx - tip_xy[0], cy - tip_xy[1]) < 1.2 * r_tip:
                continue
            fit = fit_spot(image, cx, cy, cr, self.cam)
            if fit is not None:
                psi = _dot_angle(fit.x_px, fit.y_px, spec, n, self.cam)
                if psi is not None:
                    return psi
        return None

    def step(self, image, t_s: float, n: np.ndarray, tip_xy, r_tip: float, threshold: float):
        """Fit the dots in one frame; returns ``(psi, psi_sigma, [(name, SpotFit), ...])``."""
        if self.psi is None:
            self.psi = self._acquire(image, n, tip_xy, r_tip, threshold)
            self.rate, self.t = 0.0, t_s
            if self.psi is None:
                return float("nan"), float("nan"), []
        psi_pred = self.psi + self.rate * (t_s - self.t)
        h, w = image.shape
        found, est = [], []
        for spec in self.specs:
            r = self.r_px[spec.name]
            px, py = self._project(_dot_position(spec, n, psi_pred))[0]
            reach = int(3 * r + 10)
            cand = _candidates(image, max(int(px) - reach, 0), max(int(py) - reach, 0), min(int(px) + reach, w),
                               min(int(py) + reach, h), threshold)
            cand = [c for c in cand if 0.5 * r <= c[2] <= 1.6 * r
                    and math.hypot(c[0] - tip_xy[0], c[1] - tip_xy[1]) >= 1.2 * r_tip]
            if not cand:
                continue
            cx, cy, cr = min(cand, key=lambda c: (c[0] - px) ** 2 + (c[1] - py) ** 2)
            if self.misses == 0 and math.hypot(cx - px, cy - py) < max(2.0, 0.3 * cr):
                cx, cy, cr = float(px), float(py), self.last_r[spec.name]  # sub-pixel prediction: fewer iterations
            fit = fit_spot(image, cx, cy, cr, self.cam)
            if fit is None:
                continue
            self.last_r[spec.name] = fit.radius_px
            psi_m = _dot_angle(fit.x_px, fit.y_px, spec, n, self.cam)
            if psi_m is None:
                continue
            psi_m = psi_pred + math.remainder(psi_m - psi_pred, 2 * math.pi)
            # sigma from the spot covariance through the pixel -> angle map
            jac = np.zeros(2)
            for i, (dx, dy) in enumerate(((0.05, 0.0), (0.0, 0.05))):
                p1 = _dot_angle(fit.x_px + dx, fit.y_px + dy, spec, n, self.cam)
                p0 = _dot_angle(fit.x_px - dx, fit.y_px - dy, spec, n, self.cam)
                if p1 is None or p0 is None:
                    break
                jac[i] = math.remainder(p1 - p0, 2 * math.pi) / 0.1
            else:
                var = float(jac @ fit.cov_xy @ jac)
                if var > 0:
                    est.append((psi_m, var))
            found.append((spec.name, fit))
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


# --------------------------------------------------------------------------------------
# the tracking loop


@dataclass(frozen=True)
class _TipSpec:
    name: str
    length_m: float
    radius_m: float


def _tip_spec(protocol: Protocol) -> _TipSpec:
    markers = protocol.extra.get("markers")
    if not markers:
        raise ProtocolError(f"{protocol.name}: tracking needs a [markers] section with the tip marker")
    tip = markers.get("tip")
    if not isinstance(tip, dict) or tip.get("body") != "frame":
        raise ProtocolError("markers.tip: tracking needs a marker named 'tip' on the frame (body = 'frame')")
    pos = tip.get("position_m", [0, 0, 0])
    if abs(pos[0]) > 1e-9 or abs(pos[1]) > 1e-9 or pos[2] <= 0:
        raise ProtocolError(f"markers.tip.position_m = {pos!r}: the tip must be on the axis, above the pivot "
                            "([0, 0, L] with L > 0)")
    return _TipSpec("tip", float(pos[2]), float(tip["radius_m"]))


def _candidates(image: np.ndarray, x0: int, y0: int, x1: int, y1: int, threshold: float):
    """Bright blobs in a window: (cx, cy, radius) of each blob's largest inscribed circle.

    The maximum of the distance transform finds the centre of the largest disc in a blob,
    so a spot merged with a smaller neighbour still starts the fit at the right place.
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


def track_video(video: str | Path, camera: TrackingCamera, protocol: Protocol, out_dir: str | Path, *,
                progress: Callable[[int, int], None] | None = None, frame_dots: bool = True) -> dict:
    """Track the tip marker through a video; write ``angles.csv`` and ``markers.csv``.

    With ``frame_dots`` (and frame-fixed dots off the axis in the protocol, like the
    crossbar) these are tracked too: their detections go to ``markers.csv`` and the
    frame's angle about the axis to ``angles.csv`` (``psi_rad, psi_sigma_rad``; modulo pi
    for a symmetric pair).

    Returns a summary (frames, tracked fraction, timings).  Raises
    :class:`TrackingError` for an unreadable video, a camera that does not match the
    video, or a tip that is never found; nothing is written then.
    """
    spec = _tip_spec(protocol)
    pose_info = None
    if not camera.has_pose:
        camera, pose_info = estimate_pose(video, camera, protocol)
    cap = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise TrackingError(f"cannot open video {video}")
    cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    if not math.isfinite(camera.fps):
        from dataclasses import replace

        camera = replace(camera, fps=float(cap.get(cv2.CAP_PROP_FPS)))
    if (w, h) != (camera.width_px, camera.height_px):
        raise TrackingError(f"camera file says {camera.width_px} x {camera.height_px}, the video is {w} x {h}")
    n_total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    # expected tip radius in pixels (tip upright) and the spot-size gate
    depth = float(np.linalg.norm(camera.centre_m - np.array([0, 0, spec.length_m])))
    r_expected = camera.camera_matrix[0, 0] * spec.radius_m / depth
    rows_a, rows_m = [], []
    tip_px: dict[int, tuple[float, float]] = {}  # angle row -> tip pixel position
    last = []  # recent (x, y) of the tip
    last_r = r_expected  # its latest fitted radius [px]
    dot_specs = _dot_specs(protocol) if frame_dots else []
    dots = _DotTracker(dot_specs, camera) if dot_specs else None
    psi_rows: dict[int, tuple[float, float]] = {}
    prev_hash = None
    k = 0
    t_decode = t_track = 0.0  # t_decode: time spent waiting for decoded frames
    noise_sigma = None
    frames = _decoded_frames(cap)
    while True:
        t0 = time.perf_counter()
        item = next(frames, None)
        t1 = time.perf_counter()
        t_decode += t1 - t0
        if item is None:
            break
        frame, pos_ms = item
        if frame.ndim == 3:
            frame = frame[:, :, 0]
        t_frame = pos_ms / 1000.0 if pos_ms >= 0 else k / camera.fps
        index = int(round(t_frame * camera.fps))
        quality = "ok"
        digest = hash(frame[::7, ::7].tobytes())
        if digest == prev_hash:
            rows_a.append(_empty_angle_row(index, t_frame + camera.exposure_s / 2, "duplicate"))
            k += 1
            continue
        prev_hash = digest
        if noise_sigma is None or k % 100 == 0:
            # background level and noise, refreshed every 100 frames (slow illumination drift)
            sample = frame[::8, ::8]
            bg_level = float(np.median(sample))
            noise_sigma = max(float(np.std(sample[sample < bg_level + 20])), 0.5)
        threshold = bg_level + max(8.0 * noise_sigma, 4.0)
        cand = []
        predicted = None
        if last:
            predicted = np.array(last[-1]) if len(last) < 2 else 2 * np.array(last[-1]) - np.array(last[-2])
            reach = int(4 * r_expected + 20)
            x0, y0 = max(int(predicted[0]) - reach, 0), max(int(predicted[1]) - reach, 0)
            cand = _candidates(frame, x0, y0, min(int(predicted[0]) + reach, w), min(int(predicted[1]) + reach, h),
                               threshold)
        sized = [c for c in cand if 0.5 * r_expected <= c[2] <= 1.6 * r_expected]
        if not sized:
            if last:
                quality = "reacquired"
            cand = _candidates(frame, 0, 0, w, h, threshold)
            sized = [c for c in cand if 0.5 * r_expected <= c[2] <= 1.6 * r_expected]
        # candidates must lie on the tip's sphere
        sized = [c for c in sized if tip_from_pixel(c[0], c[1], camera, spec.length_m) is not None]
        if predicted is not None and len(sized) > 1:
            sized.sort(key=lambda c: (c[0] - predicted[0]) ** 2 + (c[1] - predicted[1]) ** 2)
        elif len(sized) > 1:
            sized.sort(key=lambda c: -c[2])  # no history: the largest spot of the tip's size
        fit = None
        if sized:
            x0, y0, r0 = sized[0]
            if predicted is not None and math.hypot(x0 - predicted[0], y0 - predicted[1]) < max(2.0, 0.3 * r0):
                # the motion prediction is sub-pixel; the blob's inscribed centre is not: fewer iterations
                x0, y0, r0 = float(predicted[0]), float(predicted[1]), last_r
            fit = fit_spot(frame, x0, y0, r0, camera)
        t_mid = t_frame + camera.exposure_s / 2
        if fit is None:
            rows_a.append(_empty_angle_row(index, t_mid, "missing"))
            last = []
        else:
            t_mid += (fit.y_px / camera.height_px) * camera.readout_time_s if camera.shutter == "rolling" else 0.0
            for flag, on in (("saturated", fit.saturated), ("blended", fit.blended)):
                if on:
                    quality = flag if quality == "ok" else quality + "," + flag
            geo = _angle_covariance(fit.x_px, fit.y_px, fit.cov_xy, camera, spec.length_m)
            if geo is None:
                rows_a.append(_empty_angle_row(index, t_mid, "off-sphere"))
                last = []
            else:
                th, ph, tip, cov = geo
                sth, sph = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
                rows_a.append((index, t_mid, th, ph, sth, sph, cov[0, 1] / (sth * sph), tip[0], tip[1], tip[2],
                               quality))
                tip_px[len(rows_a) - 1] = (fit.x_px, fit.y_px)
                last = (last + [(fit.x_px, fit.y_px)])[-2:]
                last_r = fit.radius_px
                if dots is not None:
                    psi, psi_sigma, found = dots.step(frame, t_mid, tip, (fit.x_px, fit.y_px), fit.radius_px,
                                                      threshold)
                    psi_rows[len(rows_a) - 1] = (psi, psi_sigma)
                    for name, dfit in found:
                        t_dot = t_frame + camera.exposure_s / 2 + ((dfit.y_px / camera.height_px) * camera.readout_time_s
                                                                   if camera.shutter == "rolling" else 0.0)
                        rows_m.append((index, t_dot, name, dfit.x_px, dfit.y_px, math.sqrt(dfit.cov_xy[0, 0]),
                                       math.sqrt(dfit.cov_xy[1, 1]), dfit.radius_px, dfit.amplitude_adu,
                                       dfit.background_adu, dfit.chi2_red, "blended" if dfit.blended else "ok"))
            rows_m.append((index, t_mid, spec.name, fit.x_px, fit.y_px, math.sqrt(fit.cov_xy[0, 0]),
                           math.sqrt(fit.cov_xy[1, 1]), fit.radius_px, fit.amplitude_adu, fit.background_adu,
                           fit.chi2_red, quality))
        t_track += time.perf_counter() - t1
        k += 1
        if progress and (k % 50 == 0):
            progress(k, n_total)
    cap.release()
    if k == 0:
        raise TrackingError(f"{video}: no frame could be decoded (unreadable or truncated video)")
    angles = pd.DataFrame(rows_a, columns=list(ANGLE_COLUMNS))
    if not angles.theta_rad.notna().any():
        raise TrackingError(f"{video}: the tip marker was never found in {k} frames")
    angles["phi_rad"] = _unwrap_nan(angles.phi_rad.to_numpy())
    markers = pd.DataFrame(rows_m, columns=list(MARKER_COLUMNS))
    if dots is not None:
        psi_col = np.full((len(angles), 2), np.nan)
        for r_, v_ in psi_rows.items():
            psi_col[r_] = v_
        angles["psi_rad"], angles["psi_sigma_rad"] = psi_col[:, 0], psi_col[:, 1]
    angles["exposure_s"] = float(camera.exposure_s)
    rows = np.array(sorted(tip_px))
    min_effect = 1e-3 * float(np.nanmedian(angles.theta_sigma_rad))
    modes = camera_modes(np.array([tip_px[r] for r in rows]), camera, spec.length_m, pose_info, min_effect)
    camera_sigma = [float("nan"), float("nan")]
    for mode in range(len(modes)):
        for j, col in enumerate((f"theta_cam_{mode + 1}_rad", f"phi_cam_{mode + 1}_rad")):
            v = np.full(len(angles), np.nan)
            v[rows] = modes[mode, :, j]
            angles[col] = v
    if len(modes):
        camera_sigma = np.sqrt(np.mean(np.sum(modes**2, axis=0), axis=0)).tolist()
    out = Path(out_dir)
    _io.write_csv(angles, out / "angles.csv")
    _io.write_csv(markers, out / "markers.csv")
    if progress:
        progress(k, k)
    tracked = float(angles.theta_rad.notna().mean())
    return {"frames": k, "tracked_fraction": tracked, "decode_s": t_decode, "track_s": t_track,
            "angles": str(out / "angles.csv"), "markers": str(out / "markers.csv"), "pose": pose_info,
            "camera_modes": len(modes), "camera_sigma_rad": camera_sigma,
            "rvec": camera.rvec.tolist(), "tvec": camera.tvec.tolist()}


def _decoded_frames(cap: cv2.VideoCapture, depth: int = 8):
    """Yield ``(frame, container time in ms)``, decoding in a background thread.

    OpenCV releases the GIL while decoding, so decoding the next frames overlaps with
    tracking this one (two cores: throughput is the slower of the two, not their sum).
    """
    import queue
    import threading

    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            ok, frame = cap.read()
            q.put((frame, cap.get(cv2.CAP_PROP_POS_MSEC)) if ok else None)
            if not ok:
                return

    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is None:
                return
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # unblock a reader waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                pass
            thread.join(timeout=0.05)


def _empty_angle_row(index: int, t_s: float, quality: str) -> tuple:
    nan = float("nan")
    return (index, t_s, nan, nan, nan, nan, nan, nan, nan, nan, quality)


def _unwrap_nan(phi: np.ndarray) -> np.ndarray:
    """Unwrap the azimuth across the tracked frames, leaving gaps as NaN."""
    ok = np.isfinite(phi)
    out = phi.copy()
    if ok.any():
        out[ok] = np.unwrap(phi[ok])
    return out
