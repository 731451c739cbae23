"""The record a rig and camera will give, before anyone films it: the simulated tip angles at the
camera's frame times with the per-frame covariance the tracker will reach, and the fit terms
planned on it.

The motion comes from the simulator (never from the formulas being tested); the per-frame error
is the tip marker's localisation bound (:func:`gyrorig.tracking.spot.spot_crb_px`, the exact
Fisher matrix of the rendered spot model) propagated through the camera model:
``(J^T J)^-1 sigma_px^2`` with ``J = d(pixel)/d(theta, phi)``.  Used by the plan
(:mod:`gyrorig.plan`) and by the Monte Carlo of the full chain (:mod:`gyrorig.montecarlo`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import cv2
import numpy as np
import pandas as pd

from .camera import CameraSetup, camera_setup
from .fit import FitTerms, fit_data_from_angles, model_for_scene, plan_terms
from .geometry import tip_from_angles
from .markers import Marker
from .physics import simulate
from .prediction import Prediction
from .protocols import Protocol, ProtocolError
from .theory import predict
from .tracking.spot import spot_crb_px

__all__ = ["ExpectedRecord", "expected_record", "tip_setup", "pixel_bound", "project", "plan_fit_terms"]


def tip_setup(protocol: Protocol) -> tuple[CameraSetup, Marker]:
    """The protocol's camera setup and its tip marker (:class:`ProtocolError` when there is none)."""
    setup = camera_setup(protocol)
    tips = [m for m in setup.markers if m.name == "tip"] or [m for m in setup.markers if m.body == "frame"]
    if not tips:
        raise ProtocolError("[markers]: the plan needs a marker on the top (named 'tip' or with body = 'frame')")
    return setup, tips[0]


def pixel_bound(setup: CameraSetup, marker: Marker, depth_m: float) -> dict:
    """Spot size, signal and the localisation bound of the marker at a given depth.

    Returns ``radius_px, signal_adu, background_adu, saturates, sigma_px`` (the bound per axis)
    and ``px_per_m`` (the image scale at that depth).
    """
    cam, sensor = setup.camera, setup.camera.sensor
    f_px = float(cam.camera_matrix[0, 0])
    radius_px = marker.radius_m * f_px / depth_m
    amp_e = marker.brightness_e_per_s * cam.exposure_s
    bg_e = sensor.background_e_per_s * cam.exposure_s
    amp, bg = amp_e / sensor.gain_e_per_adu, bg_e / sensor.gain_e_per_adu
    sat = amp + bg >= sensor.max_adu
    spot_cam = SimpleNamespace(psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=sensor.gain_e_per_adu,
                               read_noise_e=sensor.read_noise_e)
    sigma = spot_crb_px(0.3, 0.2, radius_px, min(amp, sensor.max_adu - bg), bg, spot_cam)
    return {"radius_px": radius_px, "signal_adu": amp, "background_adu": bg, "saturates": bool(sat),
            "sigma_px": sigma, "px_per_m": f_px / depth_m}


def project(setup: CameraSetup, pts: np.ndarray) -> np.ndarray:
    """Pixel positions (n, 2) of lab points (n, 3) through the protocol's camera."""
    cam = setup.camera
    return cv2.projectPoints(pts.reshape(-1, 1, 3), cam.rvec, cam.tvec, cam.camera_matrix,
                             cam.dist_coeffs)[0].reshape(-1, 2)


def _angle_covariance(setup: CameraSetup, lever_m: float, theta: np.ndarray, phi: np.ndarray,
                      sigma_px: float) -> np.ndarray:
    """Per-frame covariance of (theta, phi) from an isotropic pixel error, through the camera; NaN in a frame
    whose azimuth's error would exceed :data:`AZIMUTH_SIGMA_LIMIT_RAD` (the tip within about its pixel error of the
    vertical, where the azimuth barely moves the image, or exactly on it, where it does not move it at all)."""
    h = 1e-6
    p0 = project(setup, lever_m * tip_from_angles(theta, phi))
    jt = (project(setup, lever_m * tip_from_angles(theta + h, phi)) - p0) / h
    jp = (project(setup, lever_m * tip_from_angles(theta, phi + h)) - p0) / h
    J = np.stack([jt, jp], axis=-1)  # (n, 2 px, 2 angles)
    JTJ = np.einsum("nki,nkj->nij", J, J)
    still = JTJ[:, 1, 1] <= 1e-12 * JTJ[:, 0, 0]
    JTJ[still] = np.eye(2)
    cov = np.linalg.inv(JTJ) * sigma_px**2
    cov[still | (cov[:, 1, 1] > AZIMUTH_SIGMA_LIMIT_RAD**2)] = np.nan
    return cov


#: a frame whose azimuth's error exceeds half a turn has no azimuth: the planned record leaves it out [rad]
AZIMUTH_SIGMA_LIMIT_RAD = math.pi


@dataclass(frozen=True)
class ExpectedRecord:
    """The simulated tip at the camera's frame times, with the tracker's per-frame covariance."""

    #: tilt and azimuth at the frame times [rad]
    theta: np.ndarray
    phi: np.ndarray
    #: the tip marker's lab position (n, 3) [m] and its median distance from the camera [m]
    pos: np.ndarray
    depth: float
    #: :func:`pixel_bound` at that depth
    spot: dict
    #: per-frame covariance of (theta, phi), (n, 2, 2) [rad^2]; NaN where the tip is on the vertical (no azimuth)
    cov: np.ndarray
    #: the same as an angle table (:mod:`gyrorig.tables`): what the fit is given (no angles on the vertical)
    angles: pd.DataFrame


def expected_record(protocol: Protocol, duration_s: float) -> ExpectedRecord:
    """The record of ``duration_s`` that the protocol's rig and camera will give, without noise."""
    setup, marker = tip_setup(protocol)
    cam = setup.camera
    lever = float(np.linalg.norm(marker.position_m))
    n = int(math.floor(duration_s * cam.fps)) + 1
    sim = simulate(protocol, t_eval_s=np.arange(n) / cam.fps)
    theta, phi = sim.theta_rad.to_numpy(), sim.phi_rad.to_numpy()
    pos = lever * tip_from_angles(theta, phi)
    depth = float(np.median(np.linalg.norm(pos - cam.centre_m, axis=1)))
    spot = pixel_bound(setup, marker, depth)
    cov = _angle_covariance(setup, lever, theta, phi, spot["sigma_px"])
    on_axis = np.isnan(cov[:, 1, 1])
    angles = pd.DataFrame({"frame": np.arange(len(sim)), "t_s": sim.t_s, "theta_rad": np.where(on_axis, np.nan, theta),
                           "phi_rad": np.where(on_axis, np.nan, phi),
                           "theta_sigma_rad": np.sqrt(cov[:, 0, 0]), "phi_sigma_rad": np.sqrt(cov[:, 1, 1]),
                           "theta_phi_corr": cov[:, 0, 1] / np.sqrt(cov[:, 0, 0] * cov[:, 1, 1])})
    return ExpectedRecord(theta, phi, pos, depth, spot, cov, angles)


def plan_fit_terms(protocol: Protocol, duration_s: float, *, prediction: Prediction | None = None) -> FitTerms:
    """The fit model's optional terms for records of ``duration_s`` through the protocol's camera.

    Chosen once, before any data, on the simulated motion with the per-frame errors the camera
    will give (:func:`gyrorig.fit.plan_terms`): every record of the scene is then fitted with
    the same model (``fit_angles(..., terms=...)``, ``gyrorig fit --terms plan.json``), rather
    than one chosen afresh by each record's chi-square tests, which switches terms on and off
    from record to record.
    """
    if "camera" not in protocol.extra:
        raise ProtocolError("planning the fit terms needs a [camera] section in the protocol")
    pred = prediction if prediction is not None else predict(protocol, simulate_damping=False)
    scene = model_for_scene(protocol, pred)
    data = fit_data_from_angles(expected_record(protocol, duration_s).angles, None, scene.precession_hint_rad_s)
    return plan_terms(data, scene, source=f"gyrorig plan of {protocol.name} for {duration_s:g} s records")
