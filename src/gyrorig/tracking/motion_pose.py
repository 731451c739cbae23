"""The camera pose from the rig's own motion (``gyrorig pose --video``): no fiducials, no board.

The tip moves on a sphere of known radius ``L`` about the pivot.  Its image track alone does not
fix the pose (any pivot whose sphere every ray meets explains each frame), so the pose is fitted
jointly with a model of the motion, in pixels:

    tip(t) = L (sin theta sin phi, -sin theta cos phi, cos theta)   (the paper's x-convention)
    theta(t) = theta_0 [+ theta_1 t]                 + sum_k c_k cos(k w t) + s_k sin(k w t)
    phi(t)   = Omega t [+ Omega_1 t^2]               + sum_k d_k cos(k w t) + e_k sin(k w t)

with ``t`` from the first tracked frame of the motion (the record's still ends, a top held before its release, are
left out: :mod:`gyrorig.stillness`), ``w`` the nutation frequency and ``K`` harmonics.  What
this assumes, and what it fixes:

- **the vertical** is the axis about which the slow motion is a steady precession: true for a
  top on a fixed pivot without damping (``theta``'s slow part constant).  With damping the slow
  tilt may drift (the ``theta_1``, ``Omega_1`` terms, on by default for a damped scene) and the
  vertical is less well fixed; an accelerated pivot tilts the apparent vertical by the
  acceleration's angle (not modelled: refused).
- **the depth scale** comes from the nutation: the tip's nodding moves it along the sphere's
  meridian, whose direction in the image depends on the distance; a pure precession (no
  nutation), or a camera on the vertical (the nod runs along the line of sight), leaves it
  nearly free: the tilt and the distance then trade off along a flat valley that the linearised
  covariance does not see, so the distance's sd is also read from the fit's profile (the
  distance held 5 % either side, the rest refitted), and a distance known worse than
  :data:`MAX_DEPTH_SCALE_SD_REL` is refused (the first pass, tracked from the rough placement, only
  starts the second, and is held to :data:`FIRST_PASS_DEPTH_SCALE_SD_REL`).
- **the azimuth origin** is free: ``phi``'s slow part is 0 at the first tracked frame (the fit
  has no constant in ``phi``).

The pose's covariance is the joint fit's (pixels weighted by their tracked covariance), scaled by
the reduced chi-square when above 1, marginalised over the motion parameters.  The starting
pose (the protocol's nominal camera placement) only picks the solution; a tip track from it
gives the pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lombscargle

from ..geometry import angles_from_tip, same_rotation_near
from ..protocols import Protocol
from ..stillness import still_ends
from ..camera import Camera
from .errors import TrackingError
from .rays import pixel_rays, tips_from_pixels
from .sources import as_source, fingerprint

__all__ = ["MotionPose", "AzimuthMark", "pose_from_motion", "fit_pose_to_track", "fix_azimuth", "MIN_FRAMES",
           "MAX_DEPTH_SCALE_SD_REL", "FIRST_PASS_DEPTH_SCALE_SD_REL"]

#: tracked frames needed (the joint fit has about 25 parameters)
MIN_FRAMES = 100
#: nutation harmonics in the motion model
HARMONICS = 6
#: the largest relative sd of the camera's distance accepted: beyond it the fit's valley is too flat for its
#: linearised covariance (a camera straight above the pivot: 3.5 % sd, the error 4 of them)
MAX_DEPTH_SCALE_SD_REL = 0.01
#: the first pass tracks from the rough placement, and its pose only starts the second: it is refused beyond this
#: (the motion then says nothing of the distance), the final pose beyond :data:`MAX_DEPTH_SCALE_SD_REL`
FIRST_PASS_DEPTH_SCALE_SD_REL = 0.05
#: above this reduced chi-square of the joint fit a refusal says the motion model did not follow the track
MISFIT_CHI2_RED = 3.0
#: the distance's profile is taken this far (relative) either side of the fitted one
PROFILE_STEP = 0.05
#: the focal length's starting scales tried, in its stated sds, where the stated one's rays mostly miss the tip's
#: sphere; the first at which this fraction of them meet it is taken; none below the least scale
START_SCALE_SDS = (0.0, -0.5, 0.5, -1.0, 1.0, -1.5, 1.5, -2.0, 2.0, -2.5, 2.5, -3.0, 3.0)
START_HIT_FRACTION = 0.9
MIN_START_SCALE = 0.2


@dataclass(frozen=True)
class MotionPose:
    """The pose found from the motion, with the fit that found it."""

    rvec: np.ndarray
    tvec: np.ndarray
    covariance: np.ndarray
    chi2_red: float
    frames: int
    nutation_frequency_rad_s: float
    slow_terms: bool
    #: sd of the depth scale relative to the pivot's distance (the weakest direction; large: no nutation)
    depth_scale_sd_rel: float
    #: the recording's fingerprint (:func:`gyrorig.tracking.sources.fingerprint`; None: frames in memory)
    video_fingerprint: str | None = None
    #: how the azimuth origin was fixed by a lab mark (:func:`fix_azimuth`); None: phi's slow part 0 at the first frame
    azimuth_mark: dict | None = None
    #: the focal length fitted with the pose, relative to the starting one (f = f0 (1 + scale)), and its sd; sd 0:
    #: the focal length was held (a calibration, or no uncertainty stated)
    focal_scale: float = 0.0
    focal_scale_sd: float = 0.0
    #: with the focal length fitted: the camera matrix and the intrinsics' covariance it gives (else None)
    camera_matrix: np.ndarray | None = None
    intrinsics: tuple[tuple[str, ...], np.ndarray] | None = None
    #: frames of the record's still ends (the top held before its release, caught at the end:
    #: :mod:`gyrorig.stillness`) left out of the fit
    still_frames: int = 0
    #: a rolling shutter whose readout camera.json leaves unknown: the readout fitted with the pose [s] and its sd
    #: (NaN: none fitted).  camera.json's readout stays unknown: the analysis's fit finds it again, with the rest
    readout_time_s: float = math.nan
    readout_time_sd_s: float = math.nan

    def camera_fields(self, video: str) -> dict:
        """The keys this pose adds to ``camera.json`` (no ``pose_points``: moving the intrinsics holds this pose).

        ``pose_source.video_fingerprint`` lets the tracker recognise the recording: its angles then mark the
        pose's modes as found from their own frames (``cam_k_prior`` 0), and the fit keeps of the pose's
        covariance only what the frames do not hold themselves (the same tip positions gave it; see
        :func:`gyrorig.fit.uncertainty.shared_pose_prior_root`)."""
        sd = np.sqrt(np.diag(self.covariance))
        focal, readout, intrinsics = {}, {}, {}
        if self.focal_scale_sd > 0:
            focal = {"focal_scale": self.focal_scale, "focal_scale_sd": self.focal_scale_sd}
        if math.isfinite(self.readout_time_s):
            readout = {"readout_fitted_s": self.readout_time_s, "readout_fitted_sd_s": self.readout_time_sd_s}
        if self.camera_matrix is not None and self.intrinsics is not None:
            intrinsics = {"camera_matrix": self.camera_matrix.tolist(),
                          "intrinsics_parameters": list(self.intrinsics[0]),
                          "intrinsics_covariance": self.intrinsics[1].tolist()}
        return {**intrinsics, "rvec": self.rvec.tolist(), "tvec": self.tvec.tolist(),
                "pose_covariance": self.covariance.tolist(),
                "pose_source": {
                    "method": "the tip's motion", "video": video, "frames": self.frames,
                    "still_frames": self.still_frames, "chi2_red": self.chi2_red,
                    "sigma_rvec_rad": sd[:3].tolist(), "sigma_tvec_m": sd[3:].tolist(),
                    "depth_scale_sd_rel": self.depth_scale_sd_rel,
                    "nutation_frequency_rad_s": self.nutation_frequency_rad_s,
                    "azimuth_origin": (self.azimuth_mark["origin"] if self.azimuth_mark else
                                       "phi's slow (precession) part is 0 at the first tracked frame of the motion"),
                    **({"azimuth_mark": self.azimuth_mark} if self.azimuth_mark else {}),
                    **({"video_fingerprint": self.video_fingerprint} if self.video_fingerprint else {}),
                    **focal, **readout,
                    "assumes": "a fixed pivot; the slow motion a precession about the vertical at a steady rate "
                               + ("with tilt and rate drifting linearly (damped scene)" if self.slow_terms
                                  else "and a constant slow tilt (undamped scene)")}}


class _Model:
    """Pixels of the tip for the pose and motion parameters (see the module's notes)."""

    def __init__(self, t_s: np.ndarray, camera: Camera, length_m: float, slow_terms: bool, harmonics: int,
                 focal: bool = False, rows: np.ndarray | None = None):
        self.t = t_s - t_s[0]
        self.cam = camera
        self.length_m = length_m
        self.slow = slow_terms
        self.k = harmonics
        #: the last parameter scales the focal length (f = f0 (1 + p[-1]))
        self.focal = focal
        #: a rolling shutter of unknown readout: each frame's row fraction about their mean, its time moved by that
        #: times the readout (the parameter before the focal length's, or the last); a delay alike for every frame
        #: would only shift the clock
        self.rows = None if rows is None else rows - np.mean(rows)

    def readout(self, p: np.ndarray) -> float:
        """The rolling shutter's readout time in ``p`` [s] (0 without one)."""
        return float(p[-2 if self.focal else -1]) if self.rows is not None else 0.0

    def split(self, p: np.ndarray):
        rvec, tvec = p[:3], p[3:6]
        n_slow = 2 if self.slow else 1
        i = 6
        th_slow = p[i:i + n_slow]
        i += n_slow
        ph_slow = p[i:i + n_slow]
        i += n_slow
        w = p[i]
        i += 1
        th_h = p[i:i + 2 * self.k]
        ph_h = p[i + 2 * self.k:i + 4 * self.k]
        return rvec, tvec, th_slow, ph_slow, w, th_h, ph_h

    def angles(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        _, _, th_slow, ph_slow, w, th_h, ph_h = self.split(p)
        t = self.t if self.rows is None else self.t + self.rows * self.readout(p)
        theta = th_slow[0] + (th_slow[1] * t if self.slow else 0.0)
        phi = ph_slow[0] * t + (ph_slow[1] * t * t if self.slow else 0.0)
        for k in range(self.k):
            c, s = np.cos((k + 1) * w * t), np.sin((k + 1) * w * t)
            theta = theta + th_h[2 * k] * c + th_h[2 * k + 1] * s
            phi = phi + ph_h[2 * k] * c + ph_h[2 * k + 1] * s
        return theta, phi

    def pixels(self, p: np.ndarray) -> np.ndarray:
        theta, phi = self.angles(p)
        st = np.sin(theta)
        tip = self.length_m * np.column_stack([st * np.sin(phi), -st * np.cos(phi), np.cos(theta)])
        k = self.cam.camera_matrix
        if self.focal:
            k = k.copy()
            k[0, 0] *= 1.0 + p[-1]
            k[1, 1] *= 1.0 + p[-1]
        return cv2.projectPoints(tip, p[:3], p[3:6], k, self.cam.dist_coeffs)[0].reshape(-1, 2)


def nutation_frequency(t_s: np.ndarray, xy_px: np.ndarray) -> float:
    """The strongest oscillation of the tip's image acceleration [rad/s]: the nutation (differentiating
    twice weighs each frequency by its square, so the slow precession's large arc drops out).  Frames may
    be missing: the Lomb-Scargle periodogram takes uneven sampling."""
    tt = t_s - t_s[0]
    ws = 2 * np.pi * np.linspace(2.0 / tt[-1], 0.5 / np.median(np.diff(tt)), 4000)
    power = np.zeros(len(ws))
    for j in range(2):
        acc = np.gradient(np.gradient(xy_px[:, j], tt), tt)
        power += lombscargle(tt, acc - acc.mean(), ws)
    return float(ws[np.argmax(power)])


def _harmonic_columns(tt: np.ndarray, w: float, harmonics: int) -> list[np.ndarray]:
    """``cos(k w t), sin(k w t)`` for k = 1 .. ``harmonics``, in the motion model's order."""
    return [f((k + 1) * w * tt) for k in range(harmonics) for f in (np.cos, np.sin)]


def _start_frequency(t: np.ndarray, theta: np.ndarray, phi: np.ndarray, w_image: float, slow: bool,
                     harmonics: int) -> float:
    """The nutation frequency to start the joint fit from: the one whose motion model, fitted linearly to the angles
    from the starting pose, leaves the least residual, over frequencies within twice the precession rate and two
    Fourier steps (``2 pi / T``) of ``w_image`` (the image's strongest oscillation).  The image shows the nod
    modulated by the precession (lines at ``w +- Omega``), so ``w_image`` may be off by the precession rate, and
    over a record of many nutations a start that far off leaves the fit in a local minimum of the phase."""
    tt = t - t[0]
    span = max(float(tt[-1]), 1e-9)
    ph = np.unwrap(phi) - phi[0]
    omega = abs(float(np.polyfit(tt, ph, 1)[0]))
    half = 2.0 * omega + 2.0 * (2.0 * np.pi / span)
    step = 0.05 * (2.0 * np.pi / span)  # a twentieth of a Fourier step: the phase off by 0.16 rad at the end at most
    candidates = np.arange(max(w_image - half, 0.5 * w_image), w_image + half + step, step)
    weight = max(float(np.median(np.sin(theta))), 1e-3)  # phi's residuals as arc
    n = len(tt)
    base_t = np.column_stack([np.ones(n)] + ([tt] if slow else []))
    base_p = np.column_stack([np.ones(n), tt] + ([tt * tt] if slow else []))
    best, best_w = math.inf, w_image
    for w in candidates:
        harm = np.column_stack(_harmonic_columns(tt, w, harmonics))
        rss = 0.0
        for base, y, scale in ((base_t, theta, 1.0), (base_p, ph, weight)):
            a = np.column_stack([base, harm])
            r = y - a @ np.linalg.lstsq(a, y, rcond=None)[0]
            rss += scale * scale * float(r @ r)
        if rss < best:
            best, best_w = rss, float(w)
    return best_w


def _start_motion(t: np.ndarray, theta: np.ndarray, phi: np.ndarray, w: float, slow: bool, harmonics: int):
    """Motion parameters fitted linearly to angles from the starting pose, at nutation frequency ``w``."""
    tt = t - t[0]
    phi = np.unwrap(phi) - phi[0]
    n = len(tt)
    cols_t = [np.ones(n)] + ([tt] if slow else [])
    cols_p = [tt] + ([tt * tt] if slow else [])
    harm = _harmonic_columns(tt, w, harmonics)
    a_t = np.linalg.lstsq(np.column_stack(cols_t + harm), theta, rcond=None)[0]
    # phi's constant is taken out by the gauge (0 at the first frame): fit it, then drop it
    a_p = np.linalg.lstsq(np.column_stack([np.ones(n)] + cols_p + harm), phi, rcond=None)[0]
    n_slow = len(cols_t)
    return np.concatenate([a_t[:n_slow], a_p[1:1 + n_slow], [w], a_t[n_slow:], a_p[1 + n_slow:]]), float(a_p[0])


def fit_pose_to_track(t_s: np.ndarray, xy_px: np.ndarray, sigma_px: np.ndarray, start: Camera,
                      length_m: float, *, slow_terms: bool = False, harmonics: int = HARMONICS,
                      focal_sd_rel: float = 0.0) -> MotionPose:
    """The pose fitted jointly with the motion model to the tip's pixels (see the module's notes).

    ``sigma_px``: (n, 2) per-frame standard deviations of x and y.  ``start`` holds the intrinsics and
    a starting pose.  ``focal_sd_rel`` > 0: the focal length is fitted too, with a Gaussian prior of that relative
    sd about the starting one (a data sheet's).  Raises :class:`TrackingError` when fewer than :data:`MIN_FRAMES`
    frames are given, the rays from the starting pose miss the tip's sphere, or the fit does not converge."""
    t = np.asarray(t_s, float)
    xy = np.asarray(xy_px, float).reshape(-1, 2)
    sig = np.asarray(sigma_px, float).reshape(-1, 2)
    good = np.all(np.isfinite(xy), axis=1) & np.all(sig > 0, axis=1) & np.isfinite(t)
    t, xy, sig = t[good], xy[good], sig[good]
    # the record's still ends (the top held before its release, caught at the end) are not the motion's
    moving = still_ends(t, xy, np.hypot(sig[:, 0], sig[:, 1])).keep
    t, xy, sig = t[moving], xy[moving], sig[moving]
    if len(t) < MIN_FRAMES:
        raise TrackingError(f"the tip was tracked in {len(t)} frames; the pose from the motion needs {MIN_FRAMES}")
    scale, theta, phi = _start_angles(xy, start, length_m, focal_sd_rel)
    hit = np.isfinite(theta)
    w_image = nutation_frequency(t, xy)
    # the start searched with the harmonics the frame rate resolves (above the Nyquist frequency a harmonic's
    # columns alias onto the other terms' frequencies and the search's least residual falls on a false frequency)
    resolved = min(harmonics, max(1, math.ceil(math.pi / (w_image * float(np.median(np.diff(t))))) - 1))
    w0 = _start_frequency(t[hit], theta[hit], phi[hit], w_image, slow_terms, resolved)
    motion, phi0 = _start_motion(t[hit], theta[hit], phi[hit], w0, slow_terms, harmonics)
    # the gauge: turn the starting pose about the vertical so that phi's slow part starts at 0
    rot = cv2.Rodrigues(start.rvec)[0] @ _rot_z(phi0)
    focal = focal_sd_rel > 0
    p0 = np.concatenate([cv2.Rodrigues(rot)[0].ravel(), start.tvec, motion] + ([[scale - 1.0]] if focal else []))
    model = _Model(t, start, length_m, slow_terms, harmonics, focal)

    def resid(p):
        r = ((model.pixels(p) - xy) / sig).ravel()
        return np.append(r, p[-1] / focal_sd_rel) if focal else r

    sol = least_squares(resid, p0, method="lm", x_scale="jac", max_nfev=4000)
    rolling = start.readout_unknown and sol.success
    if rolling:
        # the rows' delay fitted from the pose and motion found without it (from the start, the nod not yet fitted,
        # a readout far beyond any shutter's can warp the motion model into the nod)
        model = _Model(t, start, length_m, slow_terms, harmonics, focal, rows=xy[:, 1] / start.height_px)
        sol = least_squares(resid, np.insert(sol.x, len(sol.x) - int(focal), 0.0), method="lm", x_scale="jac",
                            max_nfev=4000)
    if not sol.success or not np.all(np.isfinite(sol.x)):
        raise TrackingError(f"the pose from the motion did not converge ({sol.message})")
    if not np.linalg.norm(sol.x[3:6]) > 1.5 * length_m or sol.x[5] <= 0:
        raise TrackingError(f"the pose from the motion put the camera {np.linalg.norm(sol.x[3:6]) * 1e3:.4g} mm from the "
                            f"pivot (the tip is {length_m * 1e3:.4g} mm from it): not a pose of this rig; the motion does "
                            "not fix the pose (use a board at a known place or lab fiducials)")
    dof = max(2 * len(t) - len(sol.x) + (1 if focal else 0), 1)
    chi2 = float(sol.fun @ sol.fun)
    chi2_red = chi2 / dof
    cov = np.linalg.pinv(sol.jac.T @ sol.jac, hermitian=True) * max(1.0, chi2_red)
    cov_pose = 0.5 * (cov[:6, :6] + cov[:6, :6].T)
    dist = float(np.linalg.norm(sol.x[3:6]))
    depth_sd = float(np.sqrt(sol.x[3:6] @ cov_pose[3:, 3:] @ sol.x[3:6])) / dist / dist
    depth_sd = max(depth_sd, _profile_depth_sd(resid, sol.x, chi2, max(1.0, chi2_red)))
    return MotionPose(sol.x[:3].copy(), sol.x[3:6].copy(), cov_pose, chi2_red, len(t),
                      float(abs(model.split(sol.x)[4])), slow_terms, depth_sd,
                      focal_scale=float(sol.x[-1]) if focal else 0.0,
                      focal_scale_sd=float(np.sqrt(max(cov[-1, -1], 0.0))) if focal else 0.0,
                      still_frames=int(np.count_nonzero(~moving)),
                      readout_time_s=model.readout(sol.x) if rolling else math.nan,
                      readout_time_sd_s=float(np.sqrt(max(cov[-1 - focal, -1 - focal], 0.0))) if rolling else math.nan)


def _start_angles(xy: np.ndarray, start: Camera, length_m: float, focal_sd_rel: float
                  ) -> tuple[float, np.ndarray, np.ndarray]:
    """The focal length's starting scale (relative to ``start``'s) and the tip's angles from the starting pose at it.

    The nearest of :data:`START_SCALE_SDS` (in the focal length's stated sds; the stated focal length alone when it is
    not fitted) at which :data:`START_HIT_FRACTION` of the tip's rays meet its sphere, or the one at which most do (a
    focal length known to 15 % may be 30 % off: the path then looks too large for the sphere seen from the rough
    placement, and every ray beyond the sphere's outline misses it).  Raises :class:`TrackingError` when none has
    half of them meeting it."""
    best = (0.0, 1.0, None, None)
    for z in START_SCALE_SDS if focal_sd_rel > 0 else (0.0,):
        scale = 1.0 + z * focal_sd_rel
        if scale < MIN_START_SCALE:
            continue
        cam = start.with_intrinsics(("fx", "fy"), (scale - 1.0) * np.diag(start.camera_matrix)[:2])
        theta, phi = angles_from_tip(tips_from_pixels(xy, cam, length_m))
        hit = float(np.isfinite(theta).mean())
        if hit > best[0]:
            best = (hit, scale, theta, phi)
        if hit >= START_HIT_FRACTION:
            return scale, theta, phi
    if best[0] < 0.5:
        raise TrackingError("from the starting pose (the protocol's camera placement) most of the tip's rays miss its "
                            "sphere: give a closer starting placement")
    return best[1], best[2], best[3]


def _profile_depth_sd(resid, x: np.ndarray, chi2: float, scale: float) -> float:
    """The camera distance's relative sd from the fit's profile: the distance held at ``1 +- PROFILE_STEP`` of the
    fitted one (the pivot's position in the camera scaled), everything else refitted; the chi-square's rise
    (over ``scale``, the reduced chi-square when above 1) on the flatter side read as a parabola.  Where the tilt and the distance
    trade off (a camera near the vertical: the precession's circle looks the same from nearer at a smaller tilt)
    the rise is small and this sd large, whatever the linearised covariance says; inf when a profile fit fails."""
    rises = []
    for f in (1.0 - PROFILE_STEP, 1.0 + PROFILE_STEP):
        tvec = f * x[3:6]

        def held(q, tvec=tvec):
            return resid(np.concatenate([q[:3], tvec, q[3:]]))

        sol = least_squares(held, np.delete(x, [3, 4, 5]), method="lm", x_scale="jac", max_nfev=2000)
        if not np.all(np.isfinite(sol.fun)):
            return math.inf
        rises.append(max(float(sol.fun @ sol.fun) - chi2, 0.0) / scale)
    return PROFILE_STEP / math.sqrt(max(min(rises), 1e-12))  # the flatter side: a valley may end in a wall


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose_from_motion(video, start: Camera, protocol: Protocol, *, progress=None) -> MotionPose:
    """Track the tip with the starting pose, then fit the pose to its pixels (:func:`fit_pose_to_track`).

    ``start``: the camera's intrinsics with a rough pose (the protocol's nominal placement).  Refuses an
    accelerated pivot (its apparent vertical is not the lab's), and a distance known worse than
    :data:`MAX_DEPTH_SCALE_SD_REL`."""
    from .tracker import track, tip_marker

    if protocol.pivot.acceleration is not None:
        raise TrackingError("the pose from the motion assumes a fixed pivot; this protocol accelerates it (the apparent "
                            "vertical tilts with the acceleration): use a board at a known place or lab fiducials")
    tip = tip_marker(protocol)
    video = as_source(video)
    camera = replace(start, pose_covariance=None, pose_points=None, pose_recording=None)
    focal_sd_rel = start.focal_sd_rel
    for final in (False, True):  # the second pass tracks with the pose found: frames the rough pose lost come back
        # the rough placement puts the lab fiducials where they are not: the camera's motion is followed on them only
        # once the pose is the motion's
        result = track(video, camera, protocol, progress=progress, frame_dots=False, watch_camera=final)
        m = result.markers
        rows = m[(m.marker == tip.name) & m.frame.isin(result.angles.frame[result.angles.theta_rad.notna()])]
        # the focal length's prior is the starting camera's (a data sheet's), whatever the tracking pass used
        fit_start = replace(result.camera, camera_matrix=start.camera_matrix)
        pose = fit_pose_to_track(rows.t_s.to_numpy(), rows[["x_px", "y_px"]].to_numpy(),
                                 rows[["sigma_x_px", "sigma_y_px"]].to_numpy(), fit_start, float(tip.position_m[2]),
                                 slow_terms=protocol.is_damped, focal_sd_rel=focal_sd_rel)
        limit = MAX_DEPTH_SCALE_SD_REL if final else FIRST_PASS_DEPTH_SCALE_SD_REL
        if pose.depth_scale_sd_rel > limit:  # before tracking again with a pose that may be far off
            misfit = (f"; the motion model leaves a reduced chi-square of {pose.chi2_red:.3g}: it does not follow the "
                      "track (a frame rate too low for the nod, the top touched during the record, or the fit in a "
                      "false minimum)" if pose.chi2_red > MISFIT_CHI2_RED else "")
            raise TrackingError(
                f"the tip's motion fixes the camera's distance only to {pose.depth_scale_sd_rel:.1%} (limit "
                f"{limit:.0%}): a camera looking along the vertical sees the nutation's nod end-on, or "
                "the nutation is too small; view the rig from 15 degrees or more off the vertical, or use a board at a "
                f"known place or lab fiducials{misfit}")
        camera = replace(camera, rvec=pose.rvec, tvec=pose.tvec)
        if focal_sd_rel > 0:  # the next pass tracks at the focal length found
            camera = replace(camera, camera_matrix=start.camera_matrix).with_intrinsics(
                ("fx", "fy"), pose.focal_scale * np.diag(start.camera_matrix)[:2])
            pose = _with_fitted_intrinsics(pose, camera, start)
    return replace(pose, video_fingerprint=fingerprint(video))


def _with_fitted_intrinsics(pose: MotionPose, camera: Camera, start: Camera) -> MotionPose:
    """The pose with the camera matrix at the fitted focal length and the intrinsics' covariance with the focal
    length's posterior sd (fx and fy one focal length; the other intrinsics' rows as they were)."""
    names = start.intrinsics_parameters
    cov = np.array(start.intrinsics_covariance, float)
    f = float(camera.camera_matrix[0, 0])
    sd = f * pose.focal_scale_sd
    fi = [names.index(n) for n in ("fx", "fy") if n in names]
    for a in fi:
        cov[a, :] = 0.0
        cov[:, a] = 0.0
    for a in fi:
        for b in fi:
            cov[a, b] = sd * sd
    return replace(pose, camera_matrix=camera.camera_matrix, intrinsics=(tuple(names), cov))


@dataclass(frozen=True)
class AzimuthMark:
    """A mark at a known place in the lab, seen in the image: it fixes the azimuth origin of a motion-found pose."""

    #: where the mark is in the image [px]
    pixel_px: tuple[float, float]
    #: where it is in the lab, relative to the pivot (x, y, z) [m]; its horizontal direction sets the azimuth
    position_m: tuple[float, float, float]
    pixel_sd_px: float = 1.0
    position_sd_m: float = 0.001


def _mark_point(rvec, tvec, cam: Camera, mark_px, height_m: float) -> np.ndarray:
    """Where the ray through ``mark_px`` meets the horizontal plane ``z = height_m`` (lab, pivot at 0); NaN where
    it does not (a ray parallel to the plane, or the plane behind the camera)."""
    posed = replace(cam, rvec=np.asarray(rvec, float), tvec=np.asarray(tvec, float))
    d = pixel_rays(np.asarray(mark_px, float), posed)[0]
    c = posed.centre_m
    if abs(d[2]) < 1e-9 or (height_m - c[2]) / d[2] <= 0:
        return np.full(3, np.nan)
    return c + (height_m - c[2]) / d[2] * d


def _turned(p6: np.ndarray, m5: np.ndarray, cam: Camera) -> np.ndarray:
    """The pose ``p6`` turned about the vertical so that the mark (pixel ``m5[:2]``, lab position ``m5[2:]``)
    lies at its stated azimuth; NaN when its ray does not reach the mark's height."""
    x = _mark_point(p6[:3], p6[3:], cam, m5[:2], m5[4])
    turn = math.atan2(m5[3], m5[2]) - math.atan2(x[1], x[0])
    rot = cv2.Rodrigues(p6[:3])[0] @ _rot_z(turn).T
    return np.concatenate([same_rotation_near(cv2.Rodrigues(rot)[0].ravel(), p6[:3]), p6[3:]])


def fix_azimuth(pose: MotionPose, camera: Camera, mark: AzimuthMark) -> MotionPose:
    """The pose turned about the vertical so that a lab mark lies at its stated azimuth (the pivot stays).

    The mark's ray is met with the horizontal plane at the mark's stated height; the azimuth of that
    point is set to the stated one.  The covariance takes the pose's (its own azimuth origin, "phi 0
    at the first frame", drops out) and the mark's pixel and position errors through central
    differences.  The mark's distance from the vertical as the pose places it, against the stated
    one, is reported in ``azimuth_mark`` (a check of the pose).  Raises :class:`TrackingError` for a mark
    on the vertical (no azimuth) or one whose ray does not reach its height."""
    pos = np.asarray(mark.position_m, float)
    r_stated = float(math.hypot(pos[0], pos[1]))
    if r_stated < 10 * mark.position_sd_m:
        raise TrackingError(f"the azimuth mark lies {r_stated * 1e3:.3g} mm from the vertical through the pivot, "
                            f"within 10 of its position sd ({mark.position_sd_m * 1e3:.3g} mm): it has no azimuth; "
                            "use a mark farther out")
    p6 = np.concatenate([pose.rvec, pose.tvec])
    m5 = np.concatenate([np.asarray(mark.pixel_px, float), pos])
    x = _mark_point(pose.rvec, pose.tvec, camera, m5[:2], pos[2])
    if not np.all(np.isfinite(x)):
        raise TrackingError(f"the ray through the azimuth mark at {tuple(mark.pixel_px)} px does not reach the mark's "
                            f"height z = {pos[2] * 1e3:.4g} mm in this pose: check the pixel and --mark-position-mm")
    turned = _turned(p6, m5, camera)
    jp, jm = np.zeros((6, 6)), np.zeros((6, 5))
    for j, h in enumerate([1e-6] * 6):
        e = np.zeros(6)
        e[j] = h
        jp[:, j] = (_turned(p6 + e, m5, camera) - _turned(p6 - e, m5, camera)) / (2 * h)
    for j, h in enumerate([1e-3, 1e-3, 1e-6, 1e-6, 1e-6]):
        e = np.zeros(5)
        e[j] = h
        jm[:, j] = (_turned(p6, m5 + e, camera) - _turned(p6, m5 - e, camera)) / (2 * h)
    sd_m = np.array([mark.pixel_sd_px] * 2 + [mark.position_sd_m] * 3)
    cov = jp @ pose.covariance @ jp.T + (jm * sd_m**2) @ jm.T
    turn = float(math.atan2(pos[1], pos[0]) - math.atan2(x[1], x[0]))
    info = {"origin": f"the lab mark at {tuple(round(float(v) * 1e3, 3) for v in pos)} mm (pixel "
                      f"{tuple(round(float(v), 2) for v in mark.pixel_px)}) lies at its stated azimuth",
            "pixel_px": [float(v) for v in mark.pixel_px], "position_m": pos.tolist(),
            "pixel_sd_px": mark.pixel_sd_px, "position_sd_m": mark.position_sd_m,
            "turn_rad": math.remainder(turn, 2 * math.pi),
            "distance_from_vertical_m": {"stated": r_stated, "as_posed": float(math.hypot(x[0], x[1]))}}
    return replace(pose, rvec=turned[:3], tvec=turned[3:], covariance=0.5 * (cov + cov.T), azimuth_mark=info)
