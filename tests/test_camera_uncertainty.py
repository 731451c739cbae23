"""The camera model's uncertainty, from calibration to fitted error bars.

Pixels come from projecting the simulator's tip through the true camera; the angles are
then computed through a *wrong* camera drawn from the calibration covariance, as happens
with any real calibration.  Without the camera modes the fit sees a systematic error far
above its statistical errors; with them, the error bars cover it.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pandas as pd

from _stats import chi2_red_band, sd_band
from conftest import PROTOCOL_DIR
from gyrorig.camera import Camera, Sensor, camera_setup
from gyrorig.geometry import angles_from_tip
from gyrorig.fit import ErrorKind, NoteKind, fit_angles
from gyrorig.physics.simulate import simulate
from gyrorig.protocols import load_protocol
from gyrorig.tables import camera_mode_prior_column
from gyrorig.tracking import camera_modes, tips_from_pixels
from gyrorig.tracking.motion_pose import fit_pose_to_track
from gyrorig.tracking.scatter import neighbour_positions

# standard deviations of a 12-view calibration of the bundled camera (gyrorig calibrate):
# fx, fy, cx, cy [px], k1, k2, p1, p2
CAL_STD = np.array([1.0, 1.0, 1.4, 1.3, 1.7e-3, 2.9e-2, 1.6e-4, 1.8e-4])
PIXEL_SIGMA = 0.02


def _angles(tips):
    return angles_from_tip(tips)


def _tracked(seed: int):
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    cam = camera_setup(p).camera
    length = float(p.extra["markers"]["tip"]["position_m"][2])
    truth = simulate(p, duration_s=2.0, rate_hz=100.0)
    tips = length * np.column_stack([np.sin(truth.theta_rad) * np.sin(truth.phi_rad),
                                     -np.sin(truth.theta_rad) * np.cos(truth.phi_rad), np.cos(truth.theta_rad)])
    px = cv2.projectPoints(tips, cam.rvec, cam.tvec, cam.camera_matrix, cam.dist_coeffs)[0].reshape(-1, 2)
    rng = np.random.default_rng(seed)
    px = px + PIXEL_SIGMA * rng.normal(size=px.shape)
    cov = np.diag(CAL_STD**2)
    dist = np.zeros(5)
    dist[:4] = cam.dist_coeffs[:4]
    true_cam = Camera(cam.camera_matrix, dist, cam.rvec, cam.tvec, cam.width_px, cam.height_px, cam.fps,
                              cam.exposure_s, "global", 0.0, 1.0, Sensor(gain_e_per_adu=1.0), intrinsics_covariance=cov,
                      intrinsics_parameters=tuple("fx fy cx cy k1 k2 p1 p2".split()))
    # the calibration's error: one draw from its covariance
    delta = rng.multivariate_normal(np.zeros(8), cov)
    K = cam.camera_matrix.copy()
    K[0, 0] += delta[0]
    K[1, 1] += delta[1]
    K[:2, 2] += delta[2:4]
    wrong = replace(true_cam, camera_matrix=K, dist_coeffs=dist + np.r_[delta[4:], 0.0])
    return p, _angle_table(truth, px, wrong, length), truth


def _angle_table(truth, px, cam, length, mode_prior: float = 1.0, sigma_px: float = PIXEL_SIGMA,
                 mode_px=None) -> pd.DataFrame:
    """The angles of pixels ``px`` through ``cam``, with their errors and the camera's modes (evaluated at
    ``mode_px``, default ``px``; ``cam_k_prior`` set to ``mode_prior``)."""
    th, ph = _angles(tips_from_pixels(px, cam, length))
    # per-frame errors from the pixel noise (numerical Jacobian)
    jac = []
    for d in ((1e-3, 0.0), (0.0, 1e-3)):
        a1 = _angles(tips_from_pixels(px + d, cam, length))
        a0 = _angles(tips_from_pixels(px - d, cam, length))
        jac.append([(a1[0] - a0[0]) / 2e-3, (a1[1] - a0[1]) / 2e-3])
    sth = sigma_px * np.hypot(jac[0][0], jac[1][0])
    sph = sigma_px * np.hypot(jac[0][1], jac[1][1])
    corr = sigma_px**2 * (jac[0][0] * jac[0][1] + jac[1][0] * jac[1][1]) / (sth * sph)
    angles = pd.DataFrame({"frame": np.arange(len(th)), "t_s": truth.t_s, "theta_rad": th, "phi_rad": np.unwrap(ph),
                           "theta_sigma_rad": sth, "phi_sigma_rad": sph, "theta_phi_corr": corr})
    modes = camera_modes(px if mode_px is None else mode_px, cam, length)
    for k in range(len(modes)):
        angles[f"theta_cam_{k + 1}_rad"] = modes[k, :, 0]
        angles[f"phi_cam_{k + 1}_rad"] = modes[k, :, 1]
        angles[camera_mode_prior_column(k + 1)] = mode_prior
    return angles


def test_camera_modes_are_the_angle_shifts_of_a_one_sigma_camera_move():
    p, angles, _ = _tracked(0)
    assert sum(c.startswith("theta_cam_") for c in angles.columns) == 8
    # the modes are orthogonal moves of the camera: their summed squares are the variance of the
    # angle under the calibration covariance, here checked against a direct Monte Carlo
    cam = camera_setup(p).camera
    length = float(p.extra["markers"]["tip"]["position_m"][2])
    dist = np.zeros(5)
    dist[:4] = cam.dist_coeffs[:4]
    base = Camera(cam.camera_matrix, dist, cam.rvec, cam.tvec, cam.width_px, cam.height_px, cam.fps, 0.0,
                          "global", 0.0, 1.0, Sensor(gain_e_per_adu=1.0))
    px = np.array([[700.0, 400.0]])
    rng = np.random.default_rng(1)
    th0 = _angles(tips_from_pixels(px, base, length))[0]
    shifts = []
    for _ in range(400):
        d = rng.normal(size=8) * CAL_STD
        K = cam.camera_matrix.copy()
        K[0, 0] += d[0]
        K[1, 1] += d[1]
        K[:2, 2] += d[2:4]
        c = replace(base, camera_matrix=K, dist_coeffs=dist + np.r_[d[4:], 0.0])
        shifts.append(_angles(tips_from_pixels(px, c, length))[0] - th0)
    one = camera_modes(px, replace(base, intrinsics_covariance=np.diag(CAL_STD**2),
                                   intrinsics_parameters=tuple("fx fy cx cy k1 k2 p1 p2".split())), length)
    sd_modes = float(np.sqrt(np.sum(one[:, 0, 0] ** 2)))
    lo, hi = sd_band(len(shifts))
    assert lo < np.std(shifts, ddof=1) / sd_modes < hi


def test_fit_error_bars_cover_the_calibration_error_only_with_the_camera_modes():
    p, angles, truth = _tracked(3)
    plain = fit_angles(angles[[c for c in angles.columns if "_cam_" not in c]], p, truth=truth,
                       check_residuals=True, rng=np.random.default_rng(0))
    full = fit_angles(angles, p, truth=truth, rng=np.random.default_rng(0))
    # without the camera: the residuals are far above the noise (systematic), with it: consistent
    assert plain.chi2_red > 5
    lo, hi = chi2_red_band(full.dof)
    assert lo < full.chi2_red < hi and full.error_kind is ErrorKind.FORMAL
    for k in ("precession_rate_rad_s", "nutation_amplitude_rad", "cone_angle_rad"):
        q = full.quantities[k]
        assert q.camera_standard_error > 0.5 * q.standard_error, k  # the camera dominates here
        assert abs(q.pull) < 4, (k, q.pull)
    assert len(full.notes_of(NoteKind.CAMERA_MODES)) == 1



def test_a_pose_found_from_the_same_frames_gives_error_bars_that_cover_its_error(tmp_path):
    """The pose fitted to the tip's own pixels (``fit_pose_to_track``, a camera 15 degrees off the vertical),
    then the fit of the angles through it with the pose's modes marked as found from these frames
    (``cam_k_prior`` 0) and evaluated at the neighbours' positions (as the tracker does).  Over N = 48 noise
    draws the pulls of the precession rate, nutation frequency and amplitude have an RMS within
    1 +- 3 / sqrt(2 N) and a mean within 3 / sqrt(N).  Taking the pose's covariance as independent of the
    frames (``cam_k_prior`` 1) makes the error bars too small; modes evaluated at the measured positions
    carry each frame's noise into its own correction and bias the amplitude (docs/methods.md, Fit: camera modes)."""
    text = (PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
    text = text.replace("position_m = [0.0, 0.0, 0.75]", "position_m = [0.0, -0.2, 0.75]")
    (tmp_path / "oblique.toml").write_text(text.replace("up_hint = [0.0, 1.0, 0.0]", "up_hint = [0.0, 0.0, 1.0]"))
    p = load_protocol(tmp_path / "oblique.toml")
    cam = camera_setup(p).camera
    length = float(p.extra["markers"]["tip"]["position_m"][2])
    truth = simulate(p, duration_s=2.0, rate_hz=cam.fps)
    tips = length * np.column_stack([np.sin(truth.theta_rad) * np.sin(truth.phi_rad),
                                     -np.sin(truth.theta_rad) * np.cos(truth.phi_rad), np.cos(truth.theta_rad)])
    px0 = cv2.projectPoints(tips, cam.rvec, cam.tvec, cam.camera_matrix, cam.dist_coeffs)[0].reshape(-1, 2)
    dist = np.zeros(5)
    dist[:4] = cam.dist_coeffs[:4]
    base = Camera(cam.camera_matrix, dist, cam.rvec, cam.tvec, cam.width_px, cam.height_px, cam.fps, 0.0,
                          "global", 0.0, 1.0, Sensor(gain_e_per_adu=1.0))
    sigma_px = 0.2
    names = ("precession_rate_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad")
    pulls = []
    for seed in range(48):
        px = px0 + sigma_px * np.random.default_rng(seed).normal(size=px0.shape)
        start = replace(base, rvec=cam.rvec + 0.02, tvec=cam.tvec + 0.01)
        pose = fit_pose_to_track(truth.t_s.to_numpy(), px, np.full(px.shape, sigma_px), start, length)
        posed = replace(base, rvec=pose.rvec, tvec=pose.tvec, pose_covariance=pose.covariance)
        table = _angle_table(truth, px, posed, length, 0.0, sigma_px=sigma_px,
                             mode_px=neighbour_positions(truth.t_s.to_numpy(), np.arange(len(px)), px))
        fit = fit_angles(table, p, truth=truth, rng=np.random.default_rng(0))
        pulls.append([fit.quantities[k].pull for k in names])
    pulls = np.array(pulls)
    n = len(pulls)
    rms, mean = np.sqrt(np.mean(pulls**2, axis=0)), pulls.mean(axis=0)
    for k, r, m in zip(names, rms, mean):
        assert abs(r - 1) < 3 / np.sqrt(2 * n) and abs(m) < 3 / np.sqrt(n), (k, r, m)
