"""The camera pose relative to the pivot, and the camera model's uncertainty as angle modes.

**Pose from the fiducials.**  Without ``rvec, tvec`` in ``camera.json`` the pose is found from the
protocol's lab-fixed fiducials (:func:`estimate_pose`).

**Camera modes.**  The per-frame covariance holds the localisation error only.  The camera
model's own uncertainty (the intrinsics covariance that ``gyrorig calibrate`` writes, the pose
found from the fiducials, or a ``pose_covariance`` in ``camera.json``) moves every frame's angles
together.  :func:`camera_modes` propagates it as independent one-sigma modes: for mode ``k`` each
frame's angle shift (the pose re-solved from the fiducials when the intrinsics move).  The fit
turns these into nuisance parameters with unit Gaussian priors.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import cv2
import numpy as np
import pandas as pd

from ..geometry import angles_from_tip, wrap_angle
from ..markers import MarkerSet, parse_markers
from ..protocols import Protocol
from ..tables import camera_mode_columns, camera_mode_prior_column
from ..camera import Camera
from .detect import find_blobs
from .errors import TrackingError
from .rays import tips_from_pixels
from .scatter import neighbour_positions
from .sources import as_source
from .spot import fit_spot

__all__ = ["estimate_pose", "camera_modes", "camera_modes_by_source", "add_camera_modes"]


def _median_image(source, fps: float, span_s: float, samples: int) -> np.ndarray:
    """The per-pixel median of ``samples`` frames spread over the first ``span_s`` seconds."""
    stack = []
    with source.open() as frames:
        fps = fps if math.isfinite(fps) else frames.fps
        n_span = max(int(span_s * fps), samples)
        for k, (frame, _) in enumerate(frames):
            if k >= n_span:
                break
            if k % max(n_span // samples, 1) == 0:
                stack.append(frame)
    if len(stack) < 3:
        raise TrackingError(f"{source}: too few frames to find the static fiducials")
    return np.median(np.stack(stack), axis=0).astype(stack[0].dtype)


def _static_spots(median: np.ndarray, camera: Camera) -> list[tuple[float, float, float, np.ndarray]]:
    """The brightest static spots (at most 8): ``(x, y, amplitude, covariance)``."""
    sample = median[::8, ::8]
    bg = float(np.median(sample))
    noise = max(float(np.std(sample[sample < bg + 20])), 0.5)
    spots = []
    for cx, cy, r, _ in find_blobs(median, 0, 0, median.shape[1], median.shape[0], bg + max(8 * noise, 4.0)):
        fit = fit_spot(median, cx, cy, r, camera)
        if fit is not None:
            spots.append((fit.x_px, fit.y_px, fit.amplitude_adu, fit.cov_xy))
    return sorted(spots, key=lambda s: -s[2])[:8]


def _solve_assignment(obj: np.ndarray, img: np.ndarray, camera: Camera, top_z: float):
    """Pose of one assignment of image points to fiducials, and its RMS reprojection error; None if impossible."""
    # SQPnP (globally optimal; IPPE picks the wrong one of its two planar solutions when the
    # fiducial plane faces the camera), then Levenberg-Marquardt refinement from it
    ok, rvec, tvec = cv2.solvePnP(obj, img, camera.camera_matrix, camera.dist_coeffs, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        return None
    ok, rvec, tvec = cv2.solvePnP(obj, img, camera.camera_matrix, camera.dist_coeffs, rvec, tvec,
                                  useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    rot = cv2.Rodrigues(rvec)[0]
    if np.any((obj @ rot.T + tvec.ravel())[:, 2] <= 0):
        return None
    # the fiducials face up from the cup base: a camera that sees them is above their plane
    # (this also rejects the mirror solution of a planar pose)
    if (-rot.T @ tvec.ravel())[2] <= top_z:
        return None
    proj = cv2.projectPoints(obj, rvec, tvec, camera.camera_matrix, camera.dist_coeffs)[0].reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1)))), rvec.ravel(), tvec.ravel()


def _best_assignment(spots, names: list[str], obj_all: np.ndarray, camera: Camera, max_rms_px: float):
    """The assignment of spots to fiducials with the smallest reprojection error, using the largest set
    of spots that some assignment fits (a stray static spot or a hidden fiducial only removes one point)."""
    best = None
    for n_use in range(min(len(spots), len(names)), 3, -1):
        for spot_set in itertools.combinations(range(len(spots)), n_use):
            img = np.array([[spots[i][0], spots[i][1]] for i in spot_set], dtype=np.float64)
            for perm in itertools.permutations(range(len(names)), n_use):
                obj = obj_all[list(perm)]
                solved = _solve_assignment(obj, img, camera, obj_all[:, 2].max())
                if solved is not None and (best is None or solved[0] < best[0]):
                    best = (*solved, [names[j] for j in perm], obj, img, [spots[i][3] for i in spot_set])
        if best is not None and best[0] <= max_rms_px:
            break
    return best


def estimate_pose(video, camera: Camera, protocol: Protocol, *, span_s: float = 2.0,
                  samples: int = 15, max_rms_px: float = 1.0, markers: MarkerSet | None = None
                  ) -> tuple[Camera, dict]:
    """Camera pose relative to the pivot from the protocol's lab-fixed fiducials.

    The per-pixel median of frames spread over the first ``span_s`` seconds keeps what
    does not move (the fiducials) and drops the moving markers.  Static spots are
    localised to sub-pixel precision, then matched to the fiducials by trying every
    assignment with ``cv2.solvePnP`` (SQPnP, refined by Levenberg-Marquardt): the
    assignment with the smallest reprojection error, the fiducials in front of the camera
    and the camera above their plane (they face up) wins; the largest set of spots that
    fits is used, so one stray static spot or one hidden fiducial does no harm.  Needs at
    least 4 fiducials visible; their layout must have no rotational symmetry (else the
    azimuth is ambiguous), which the bundled protocols' irregular circle satisfies.

    ``video`` is a path or a frame source (:mod:`gyrorig.tracking.sources`); ``markers``: the protocol's, parsed
    already.  Returns the camera with its pose and a summary (matched fiducials, RMS error in px).
    """
    markers = markers if markers is not None else parse_markers(protocol)
    fid = {m.name: np.asarray(m.position_m, dtype=float) for m in markers.fiducials()}
    if len(fid) < 4:
        raise TrackingError(f"the camera file has no pose and the protocol has {len(fid)} lab-fixed fiducial(s) "
                            "(body = 'lab'); at least 4 are needed to find the pose")
    source = as_source(video)
    spots = _static_spots(_median_image(source, camera.fps, span_s, samples), camera)
    if len(spots) < 4:
        raise TrackingError(f"{source}: found {len(spots)} static spots; at least 4 fiducials must be visible")
    names = list(fid)
    best = _best_assignment(spots, names, np.array([fid[n] for n in names]), camera, max_rms_px)
    if best is None or best[0] > max_rms_px:
        rms = "no solution" if best is None else f"{best[0]:.3g} px"
        raise TrackingError(f"{source}: no assignment of the {len(spots)} static spots to the fiducials "
                            f"fits (best reprojection error {rms}, limit {max_rms_px} px)")
    rms, rvec, tvec, matched, obj, img, covs = best
    pose_cov = pose_covariance_from_points(obj, img, covs, camera.camera_matrix, camera.dist_coeffs, rvec, tvec)
    posed = replace(camera, rvec=rvec, tvec=tvec, pose_covariance=pose_cov)
    return posed, {"fiducials_matched": matched, "pose_rms_px": rms, "static_spots": len(spots),
                   "object_points_m": obj.tolist(), "image_points_px": img.tolist(),
                   "pose_sigma": np.sqrt(np.diag(pose_cov)).tolist()}


def pose_covariance_from_points(obj, img, covs, camera_matrix, dist_coeffs, rvec, tvec) -> np.ndarray:
    """Covariance of the PnP pose (rvec, tvec) from its image points' localisation errors (intrinsics
    held fixed): ``covs`` is each point's 2 x 2 pixel covariance (the fiducials' spot fits, a board's
    corner scatter); scaled up by the reduced chi-square of the reprojection when it exceeds 1.
    """
    proj, jac = cv2.projectPoints(obj, rvec, tvec, camera_matrix, dist_coeffs)
    r = (img - proj.reshape(-1, 2)).ravel()
    Cinv = np.zeros((2 * len(obj), 2 * len(obj)))
    for i, c in enumerate(covs):
        Cinv[2 * i:2 * i + 2, 2 * i:2 * i + 2] = np.linalg.inv(c)
    J = jac[:, :6]
    dof = max(2 * len(obj) - 6, 1)
    chi2_red = float(r @ Cinv @ r) / dof
    return np.linalg.pinv(J.T @ Cinv @ J, hermitian=True) * max(1.0, chi2_red)


def _eigen_moves(cov: np.ndarray):
    """One-sigma moves along the eigenvectors of a covariance (those above 1e-12 of the largest)."""
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    for k in np.flatnonzero(lam > 1e-12 * max(lam.max(), 1e-300)):
        yield math.sqrt(lam[k]) * vec[:, k]


def camera_modes(xy_px: np.ndarray, cam: Camera, radius_m: float, fiducials: dict | None = None,
                 min_effect_rad: float = 0.0) -> np.ndarray:
    """Angle shifts of each frame for independent one-sigma moves of the camera model.

    Parameters
    ----------
    xy_px : (n, 2) array
        The tip's pixel positions (the measurements, held fixed).
    cam : Camera
        With ``intrinsics_covariance`` and/or ``pose_covariance``.
    radius_m : float
        The tip's distance from the pivot. [m]
    fiducials : dict, optional
        ``object_points_m``, ``image_points_px`` when the pose came from the fiducials: a
        move of the intrinsics then re-solves the pose from them, as the tracker would.
    min_effect_rad : float
        Modes whose largest shift is below this are dropped. [rad]

    Returns
    -------
    (m, n, 2) array: ``[k, i] = (dtheta, dphi)`` of frame ``i`` for mode ``k`` (central
    differences over +-1 sigma along each eigenvector of the covariance). [rad]
    """
    return camera_modes_by_source(xy_px, cam, radius_m, fiducials, min_effect_rad)[0]


def camera_modes_by_source(xy_px: np.ndarray, cam: Camera, radius_m: float, fiducials: dict | None = None,
                           min_effect_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`camera_modes`, and which of them are moves of the pose: ``(modes, is_pose)``, ``is_pose`` an
    (m,) bool array (the intrinsics' modes first, then the pose's)."""
    xy = np.asarray(xy_px, float).reshape(-1, 2)
    moves, kinds = [], []
    if cam.intrinsics_covariance is not None:
        for d in _eigen_moves(cam.intrinsics_covariance):
            moves.append([cam.with_intrinsics(cam.intrinsics_parameters, sign * d) for sign in (1.0, -1.0)])
            kinds.append(False)
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
        for d in _eigen_moves(cam.pose_covariance):
            moves.append([replace(cam, rvec=cam.rvec + sign * d[:3], tvec=cam.tvec + sign * d[3:])
                          for sign in (1.0, -1.0)])
            kinds.append(True)
    out, is_pose = [], []
    for (plus, minus), kind in zip(moves, kinds):
        tp, pp = angles_from_tip(tips_from_pixels(xy, plus, radius_m))
        tm, pm = angles_from_tip(tips_from_pixels(xy, minus, radius_m))
        dv = 0.5 * np.column_stack([tp - tm, wrap_angle(pp - pm)])
        dv = np.where(np.isfinite(dv), dv, 0.0)  # a ray that leaves the sphere under the move: no shift known
        if np.abs(dv).max(initial=0.0) > min_effect_rad:
            out.append(dv)
            is_pose.append(kind)
    return np.array(out).reshape(len(out), len(xy), 2), np.array(is_pose, bool)


def add_camera_modes(angles: pd.DataFrame, tip_px: dict, camera: Camera, length_m: float,
                      pose: dict | None, pose_from_these_frames: bool) -> list[float]:
    """Add the camera-model modes' columns (the pose's without a prior when ``pose_from_these_frames``);
    returns their RMS effect on (theta, phi) [rad] (NaN without)."""
    rows = np.array(sorted(tip_px))
    min_effect = 1e-3 * float(np.nanmedian(angles.theta_sigma_rad))
    xy = np.array([tip_px[r] for r in rows], float).reshape(-1, 2)
    if len(rows) > 1:  # the shifts at the neighbours' prediction: free of the frame's own noise
        xy = neighbour_positions(angles.t_s.to_numpy(float)[rows], angles.frame.to_numpy()[rows], xy)
    modes, is_pose = camera_modes_by_source(xy, camera, length_m, pose, min_effect)
    for mode in range(len(modes)):
        for j, col in enumerate(camera_mode_columns(mode + 1)):
            v = np.full(len(angles), np.nan)
            v[rows] = modes[mode, :, j]
            angles[col] = v
        angles[camera_mode_prior_column(mode + 1)] = 0.0 if (is_pose[mode] and pose_from_these_frames) else 1.0
    if len(modes):
        return np.sqrt(np.mean(np.sum(modes**2, axis=0), axis=0)).tolist()
    return [float("nan"), float("nan")]
