"""Where the markers are: the simulator's trajectory as spline paths, projected through the camera per sub-exposure sample."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

from ..camera import Camera, CameraSetup
from ..markers import Marker
from ..physics import simulate
from ..physics.rotations import euler_to_matrix
from ..protocols import Protocol

__all__ = ["MarkerPaths", "Samples", "marker_paths", "marker_samples", "project"]


@dataclass(frozen=True)
class MarkerPaths:
    """Lab positions of the markers (splines over time), the normals of the disc markers, and the top's axis."""

    t_s: np.ndarray
    splines: dict[str, CubicSpline | np.ndarray]
    axis: CubicSpline
    phi_reference_rad: float
    normals: dict[str, CubicSpline | np.ndarray] = field(default_factory=dict)

    def position(self, name: str, t: np.ndarray) -> np.ndarray:
        """Lab position of a marker at times ``t``; shape ``t.shape + (3,)``. [m]"""
        return self._evaluate(self.splines[name], t)

    def normal(self, name: str, t: np.ndarray) -> np.ndarray:
        """Unit lab normal of a disc marker at times ``t``; shape ``t.shape + (3,)``."""
        v = self._evaluate(self.normals[name], t)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    @staticmethod
    def _evaluate(s, t):
        if isinstance(s, np.ndarray):
            return np.broadcast_to(s, np.shape(t) + (3,))
        return s(t)

    def tip(self, t: np.ndarray) -> np.ndarray:
        """Unit axis direction at times ``t``."""
        v = self.axis(t)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _turns_with_rotor(m: Marker, protocol: Protocol) -> bool:
    """A marker on the rotor, or on the frame of a plain top (which has no separate frame)."""
    return m.body == "rotor" or (m.body == "frame" and protocol.rig.frame_axial_inertia_kg_m2 is None)


def _held_then_released(protocol: Protocol, t: np.ndarray, hold_s: float) -> pd.DataFrame:
    """The simulator's angles at times ``t`` of a top held still by its frame for ``hold_s`` (its rotor spinning at
    the launch's rate) and then released as the protocol launches it."""
    free = t >= hold_s
    t_free = t[free] - hold_s
    df = simulate(protocol, t_eval_s=np.r_[0.0, t_free] if not len(t_free) or t_free[0] > 0 else t_free)
    first = df.iloc[0]
    rows = df.iloc[len(df) - len(t_free):]
    n_held = int(np.count_nonzero(~free))
    out = {}
    for name in ("phi_rad", "theta_rad", "psi_rad", "psi_frame_rad", "tip_x", "tip_y", "tip_z"):
        if name in df:
            out[name] = np.r_[np.full(n_held, first[name]), rows[name].to_numpy()]
    out["psi_rad"][:n_held] += protocol.launch.spin_rate_rad_s * (t[:n_held] - hold_s)
    return pd.DataFrame(out)


def marker_paths(protocol: Protocol, setup: CameraSetup, duration_s: float, hold_s: float = 0.0) -> MarkerPaths:
    """Simulate the scene densely and build spline paths of every marker; ``hold_s``: the top held still before its
    release for so long (the record's first ``hold_s`` of ``duration_s``)."""
    rig = protocol.rig
    nut_hz = abs(rig.inertia_axial_kg_m2 * protocol.launch.spin_rate_rad_s) / rig.inertia_transverse_kg_m2 / (2 * np.pi)
    rate = max(2000.0, 40.0 * nut_hz, 4.0 * setup.camera.fps)
    if any(_turns_with_rotor(m, protocol) for m in setup.markers):
        rate = max(rate, 64.0 * abs(protocol.launch.spin_rate_rad_s) / (2 * np.pi))  # 64 samples per turn
    pad = 2.0 / setup.camera.fps  # rolling-shutter rows and the last exposure reach past the last frame start
    n = int(math.ceil((duration_s + pad) * rate)) + 1
    t = np.arange(n) / rate
    df = simulate(protocol, t_eval_s=t) if hold_s <= 0 else _held_then_released(protocol, t, hold_s)
    # a plain top has no separate frame: its "frame" markers turn with the rotor
    psi_frame = df["psi_frame_rad"] if "psi_frame_rad" in df else df["psi_rad"]
    rot = {"frame": euler_to_matrix(df.phi_rad.to_numpy(), df.theta_rad.to_numpy(), psi_frame.to_numpy()),
           "rotor": euler_to_matrix(df.phi_rad.to_numpy(), df.theta_rad.to_numpy(), df.psi_rad.to_numpy())}
    splines: dict[str, CubicSpline | np.ndarray] = {}
    normals: dict[str, CubicSpline | np.ndarray] = {}
    for m in setup.markers:
        if m.body == "lab":
            splines[m.name] = np.asarray(m.position_m, dtype=float)
            normals[m.name] = np.asarray(m.normal, dtype=float)
        else:
            splines[m.name] = CubicSpline(t, rot[m.body] @ np.asarray(m.position_m, dtype=float))
            normals[m.name] = CubicSpline(t, rot[m.body] @ np.asarray(m.normal, dtype=float))
    axis = CubicSpline(t, df[["tip_x", "tip_y", "tip_z"]].to_numpy())
    return MarkerPaths(t, splines, axis, protocol.launch.azimuth_rad, normals)


def _occluded(cam_pos: np.ndarray, points: np.ndarray, axis: np.ndarray, occluders) -> np.ndarray:
    """True where the segment camera -> point passes through an occluding cylinder about ``axis``."""
    hidden = np.zeros(points.shape[:-1], dtype=bool)
    if not occluders:
        return hidden
    c = cam_pos
    d = points - c
    for occ in occluders:
        zc = c @ axis.T if axis.ndim == 1 else np.einsum("j,...j->...", c, axis)
        zd = np.einsum("...j,...j->...", d, axis)
        # axial coordinate z(s) = zc + s zd; radial^2 r2(s) = |c + s d|^2 - z(s)^2 = a s^2 + b s + k
        a = np.einsum("...j,...j->...", d, d) - zd**2
        b = 2 * (np.einsum("j,...j->...", c, d) - zc * zd)
        k = c @ c - zc**2
        with np.errstate(divide="ignore", invalid="ignore"):
            s1 = np.where(zd != 0, (occ.z_min_m - zc) / zd, -np.inf)
            s2 = np.where(zd != 0, (occ.z_max_m - zc) / zd, np.inf)
        lo = np.maximum(np.minimum(s1, s2), 0.0)
        hi = np.minimum(np.maximum(s1, s2), 1.0 - 1e-9)
        inside_slab = np.where(zd == 0, (zc >= occ.z_min_m) & (zc <= occ.z_max_m), True)
        with np.errstate(divide="ignore", invalid="ignore"):
            s_min = np.clip(np.where(a > 0, -b / (2 * a), lo), lo, hi)
        r2 = a * s_min**2 + b * s_min + k
        hidden |= inside_slab & (lo <= hi) & (r2 <= occ.radius_m**2)
    return hidden


def _sample_times(cam: Camera, frames: np.ndarray) -> np.ndarray:
    """Sub-exposure sample offsets (midpoint rule) for each frame; shape (n_frames, N). [s]"""
    n = cam.motion_blur_samples
    offsets = (np.arange(n) + 0.5) / n * cam.exposure_s
    return frames[:, None] / cam.fps + offsets[None, :]


def project(cam: Camera, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates and camera depth of lab points; shapes (..., 2) and (...)."""
    flat = pts.reshape(-1, 3).astype(np.float64)
    px = cv2.projectPoints(flat, cam.rvec, cam.tvec, cam.camera_matrix, cam.dist_coeffs)[0].reshape(-1, 2)
    depth = flat @ cam.rotation[2] + cam.tvec[2]
    return px.reshape(pts.shape[:-1] + (2,)), depth.reshape(pts.shape[:-1])


@dataclass(frozen=True)
class Samples:
    """One marker over a chunk of frames: per frame and sub-exposure sample (``[frame, sample]``) its lab
    position, pixel position, the radius a sphere of its size would have [px], its normal (discs) and
    whether it is visible; per frame its truth at mid-exposure."""

    pts: np.ndarray
    px: np.ndarray
    radius: np.ndarray
    normals: np.ndarray | None
    visible: np.ndarray
    truth_px: np.ndarray
    t_mid: np.ndarray
    in_view: np.ndarray


def marker_samples(cam: Camera, setup: CameraSetup, paths: MarkerPaths, m: Marker, frames: np.ndarray) -> Samples:
    """The marker's sub-exposure samples in a chunk of frames (rolling shutter: at its own row's time).

    Visible: in the image, not behind an occluder, and for a disc facing the camera."""
    times = _sample_times(cam, frames)
    if cam.shutter == "rolling":
        # the marker's rows start exposing (y / H) * readout later; two fixed-point passes
        shift = np.zeros(len(frames))
        for _ in range(2):
            mid = frames / cam.fps + shift + cam.exposure_s / 2
            y = project(cam, paths.position(m.name, mid))[0][:, 1]
            shift = np.clip(y, 0, cam.height_px - 1) / cam.height_px * cam.readout_time_s
        times = times + shift[:, None]
    else:
        shift = np.zeros(len(frames))
    pts = paths.position(m.name, times)
    px, depth = project(cam, pts)
    radius = cam.camera_matrix[0, 0] * m.radius_m / np.maximum(depth, 1e-9)
    in_view = (depth > 0) & (px[..., 0] > -radius) & (px[..., 0] < cam.width_px - 1 + radius) & \
        (px[..., 1] > -radius) & (px[..., 1] < cam.height_px - 1 + radius)
    visible = in_view.copy()
    if setup.occluders:
        visible &= ~_occluded(cam.centre_m, pts, paths.tip(times), setup.occluders)
    normals = None
    if m.shape == "disc":
        normals = paths.normal(m.name, times)
        visible &= np.einsum("...j,...j->...", normals, cam.centre_m - pts) > 0
    t_mid = frames / cam.fps + shift + cam.exposure_s / 2
    truth_px, _ = project(cam, paths.position(m.name, t_mid))
    return Samples(pts, px, radius, normals, visible, truth_px, t_mid, in_view.mean(axis=1) >= 0.5)
