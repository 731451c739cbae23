"""Synthetic videos of the rigs: the simulator's trajectory seen through a real camera model.

Pipeline per video:

1. simulate the scene on a dense grid (>= 2 kHz, >= 40 samples per nutation period) and
   interpolate every marker's lab position with a cubic spline (error < 1e-12 m);
2. for each frame and marker, the sub-exposure sample times (global shutter: the same for
   the whole frame; rolling shutter: shifted by the marker's row, ``t = t_frame + (y/H)
   readout``), positions projected with ``cv2.projectPoints`` (pinhole + distortion);
3. each sample drawn as a sphere's disc of radius ``f R / depth`` convolved with the
   Gaussian PSF (``0.5 erfc((|p - c| - r) / (sqrt(2) sigma))``), only in a window around the
   marker; samples hidden behind an occluder (the rotor can) or outside the image are
   skipped; the sum over samples is the motion blur;
4. sensor: electrons = Poisson(expected) + Normal(0, read noise), clipped at the full
   well; ADU = round(electrons / gain), clipped at ``2^bits - 1``.  Near the markers this
   is drawn directly; elsewhere every pixel has the same distribution, computed exactly
   once (:func:`background_distribution`) and sampled through a 2^16-entry inverse-CDF
   table (probabilities resolved to 1.5e-5; 5x faster than drawing the noise);
5. frames go to ``video.mkv`` (FFV1, lossless; 16-bit grey for 10/12-bit sensors) or
   ``video.mp4`` (mp4v, 8-bit, lossy) under a temporary name, renamed when complete.

Truth is written beside: ``truth.csv`` (per frame and marker) and ``camera.json``.
Nothing here is read by the tracker.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline
from scipy.special import erfc
from scipy.stats import norm, poisson

from . import _io
from .camera import Camera, CameraSetup, Marker, camera_setup
from .physics import simulate
from .physics.rotations import euler_to_matrix, unwrapped_angles_from_tip
from .protocols import Protocol, ProtocolError

logger = logging.getLogger(__name__)

__all__ = ["MarkerPaths", "marker_paths", "render_frames", "render_video", "render_calibration_images",
           "TRUTH_COLUMNS", "background_distribution", "open_writer"]

TRUTH_COLUMNS = ("frame", "t_s", "marker", "x_px", "y_px", "visible", "theta_rad", "phi_rad", "t_marker_s",
                 "in_view")
#: background pixels are drawn by inverse CDF from a table of this many equiprobable values
BACKGROUND_TABLE_SIZE = 1 << 16


@dataclass(frozen=True)
class MarkerPaths:
    """Lab positions of the markers (splines over time) and the top's axis."""

    t_s: np.ndarray
    splines: dict[str, CubicSpline | np.ndarray]
    axis: CubicSpline
    phi_reference_rad: float

    def position(self, name: str, t: np.ndarray) -> np.ndarray:
        """Lab position of a marker at times ``t``; shape ``t.shape + (3,)``. [m]"""
        s = self.splines[name]
        if isinstance(s, np.ndarray):
            return np.broadcast_to(s, np.shape(t) + (3,))
        return s(t)

    def tip(self, t: np.ndarray) -> np.ndarray:
        """Unit axis direction at times ``t``."""
        v = self.axis(t)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def marker_paths(protocol: Protocol, setup: CameraSetup, duration_s: float) -> MarkerPaths:
    """Simulate the scene densely and build spline paths of every marker."""
    rig = protocol.rig
    nut_hz = abs(rig.inertia_axial_kg_m2 * protocol.launch.spin_rate_rad_s) / rig.inertia_transverse_kg_m2 / (2 * np.pi)
    rate = max(2000.0, 40.0 * nut_hz, 4.0 * setup.camera.fps)
    pad = 2.0 / setup.camera.fps  # rolling-shutter rows and the last exposure reach past the last frame start
    n = int(math.ceil((duration_s + pad) * rate)) + 1
    t = np.arange(n) / rate
    df = simulate(protocol, t_eval_s=t)
    psi = df["psi_frame_rad"] if "psi_frame_rad" in df else df["psi_rad"]
    rot = euler_to_matrix(df.phi_rad.to_numpy(), df.theta_rad.to_numpy(), psi.to_numpy())
    splines: dict[str, CubicSpline | np.ndarray] = {}
    for m in setup.markers:
        if m.body == "lab":
            splines[m.name] = np.asarray(m.position_m, dtype=float)
        else:
            splines[m.name] = CubicSpline(t, rot @ np.asarray(m.position_m, dtype=float))
    axis = CubicSpline(t, df[["tip_x", "tip_y", "tip_z"]].to_numpy())
    return MarkerPaths(t, splines, axis, protocol.launch.azimuth_rad)


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


def _project(cam: Camera, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates and camera depth of lab points; shapes (..., 2) and (...)."""
    flat = pts.reshape(-1, 3).astype(np.float64)
    px = cv2.projectPoints(flat, cam.rvec, cam.tvec, cam.camera_matrix, cam.distortion)[0].reshape(-1, 2)
    depth = flat @ cam.rotation[2] + cam.tvec[2]
    return px.reshape(pts.shape[:-1] + (2,)), depth.reshape(pts.shape[:-1])


def _marker_samples(cam: Camera, setup: CameraSetup, paths: MarkerPaths, m: Marker, frames: np.ndarray):
    """Per frame: sub-sample pixel positions, radii, visibility; and the truth at mid-exposure."""
    times = _sample_times(cam, frames)
    if cam.shutter == "rolling":
        # the marker's rows start exposing (y / H) * readout later; two fixed-point passes
        shift = np.zeros(len(frames))
        for _ in range(2):
            mid = frames / cam.fps + shift + cam.exposure_s / 2
            y = _project(cam, paths.position(m.name, mid))[0][:, 1]
            shift = np.clip(y, 0, cam.height_px - 1) / cam.height_px * cam.readout_time_s
        times = times + shift[:, None]
    else:
        shift = np.zeros(len(frames))
    pts = paths.position(m.name, times)
    px, depth = _project(cam, pts)
    radius = cam.camera_matrix[0, 0] * m.radius_m / np.maximum(depth, 1e-9)
    in_view = (depth > 0) & (px[..., 0] > -radius) & (px[..., 0] < cam.width_px - 1 + radius) & \
        (px[..., 1] > -radius) & (px[..., 1] < cam.height_px - 1 + radius)
    visible = in_view.copy()
    if setup.occluders:
        visible &= ~_occluded(cam.position_m, pts, paths.tip(times), setup.occluders)
    t_mid = frames / cam.fps + shift + cam.exposure_s / 2
    truth_px, _ = _project(cam, paths.position(m.name, t_mid))
    return px, radius, visible, truth_px, t_mid, in_view.mean(axis=1) >= 0.5


def _draw_spot(acc: np.ndarray, px: np.ndarray, radius: np.ndarray, vis: np.ndarray, peak_e: float,
               sigma: float) -> tuple[int, int, int, int] | None:
    """Add the spot's expected electrons (sum over visible sub-samples) into ``acc``; return its window."""
    if not vis.any():
        return None
    p, r = px[vis], radius[vis]
    reach = float(r.max()) + 5.0 * sigma + 1.0
    h, w = acc.shape
    x0 = max(int(math.floor(p[:, 0].min() - reach)), 0)
    x1 = min(int(math.ceil(p[:, 0].max() + reach)) + 1, w)
    y0 = max(int(math.floor(p[:, 1].min() - reach)), 0)
    y1 = min(int(math.ceil(p[:, 1].max() + reach)) + 1, h)
    if x1 <= x0 or y1 <= y0:
        return None
    xs = np.arange(x0, x1, dtype=np.float64)
    ys = np.arange(y0, y1, dtype=np.float64)
    dist = np.sqrt((xs[None, None, :] - p[:, 0, None, None]) ** 2 + (ys[None, :, None] - p[:, 1, None, None]) ** 2)
    prof = 0.5 * erfc((dist - r[:, None, None]) / (math.sqrt(2.0) * sigma))
    acc[y0:y1, x0:x1] += (peak_e / len(vis)) * prof.sum(axis=0)
    return (y0, y1, x0, x1)


def background_distribution(background_e: float, sensor) -> np.ndarray:
    """Exact distribution of a background pixel's value: P(ADU = k), k = 0 .. 2^bits - 1.

    electrons = Poisson(background) + Normal(0, read noise), clipped to [0, full well];
    ADU = min(round(electrons / gain), 2^bits - 1).
    """
    s = sensor
    spread = 12.0 * math.sqrt(background_e) + 10.0
    n = np.arange(max(0, int(background_e - spread)), int(background_e + spread) + 1)
    pn = poisson.pmf(n, background_e)
    top = min(s.max_adu, int(math.floor(s.full_well_e / s.gain_e_per_adu + 0.5)))
    edges = (np.arange(top) + 0.5) * s.gain_e_per_adu  # ADU <= k  <=>  electrons < (k + 0.5) gain
    if s.read_noise_e > 0:
        cdf = (pn[None, :] * norm.cdf((edges[:, None] - n[None, :]) / s.read_noise_e)).sum(axis=1)
    else:
        cdf = (pn[None, :] * (n[None, :] < edges[:, None])).sum(axis=1)
    cdf = np.append(np.clip(cdf, 0.0, 1.0), 1.0)
    pmf = np.zeros(s.max_adu + 1)
    pmf[: top + 1] = np.diff(np.concatenate([[0.0], cdf]))
    return pmf / pmf.sum()


def _background_table(background_e: float, sensor) -> np.ndarray:
    """Inverse-CDF lookup table: a uniform 16-bit integer -> a background pixel value."""
    pmf = background_distribution(background_e, sensor)
    u = (np.arange(BACKGROUND_TABLE_SIZE) + 0.5) / BACKGROUND_TABLE_SIZE
    values = np.searchsorted(np.cumsum(pmf), u, side="left").clip(0, sensor.max_adu)
    return values.astype(np.uint8 if sensor.bit_depth == 8 else np.uint16)


def _sensor(expected: np.ndarray, windows, cam: Camera, rng: np.random.Generator, background_e: float,
            table: np.ndarray) -> np.ndarray:
    """Pixel values: background from its exact distribution, exact shot + read noise near markers."""
    s = cam.sensor
    h, w = expected.shape
    idx = np.frombuffer(rng.bytes(2 * h * w), dtype=np.uint16).reshape(h, w)
    image = np.take(table, idx)
    for (y0, y1, x0, x1) in windows:
        lam = expected[y0:y1, x0:x1] + background_e
        e = rng.poisson(lam) + rng.standard_normal(lam.shape) * s.read_noise_e
        adu = np.floor(np.clip(e, 0.0, s.full_well_e) / s.gain_e_per_adu + 0.5)
        image[y0:y1, x0:x1] = np.clip(adu, 0, s.max_adu)
    return image


def render_frames(protocol: Protocol, *, seed: int = 0, duration_s: float | None = None,
                  setup: CameraSetup | None = None, noise: bool = True, chunk: int = 64,
                  paths: MarkerPaths | None = None) -> Iterator[tuple[np.ndarray, pd.DataFrame]]:
    """Yield ``(frame image, truth rows)`` chunk by chunk (see :data:`TRUTH_COLUMNS`).

    Parameters
    ----------
    protocol : Protocol
        With ``[camera]`` and ``[markers]`` sections.
    seed : int
        Seed of the noise generator: same seed, same frames.
    duration_s : float, optional
        Overrides the scene duration. [s]
    noise : bool
        ``False`` gives the expected image (no shot or read noise, no quantisation), as float32.
    """
    setup = setup or camera_setup(protocol)
    cam = setup.camera
    duration = protocol.scene.duration_s if duration_s is None else float(duration_s)
    n_frames = int(math.floor(duration * cam.fps + 1e-9))
    if n_frames < 1:
        raise ProtocolError(f"scene.duration_s = {duration:g} gives no frame at {cam.fps:g} fps")
    paths = paths or marker_paths(protocol, setup, duration)
    rng = np.random.default_rng(seed)
    bg = cam.sensor.background_e_per_s * cam.exposure_s
    table = _background_table(bg, cam.sensor) if noise else None
    # expected spot electrons; only the windows around markers are ever touched (and reset)
    acc = np.zeros((cam.height_px, cam.width_px), dtype=np.float64)
    for start in range(0, n_frames, chunk):
        frames = np.arange(start, min(start + chunk, n_frames))
        per_marker = {m.name: _marker_samples(cam, setup, paths, m, frames) for m in setup.markers}
        t_mid = frames / cam.fps + cam.exposure_s / 2
        th, ph = unwrapped_angles_from_tip(paths.tip(t_mid), phi_at_pole_rad=paths.phi_reference_rad)
        for i, f in enumerate(frames):
            windows = []
            rows = []
            for m in setup.markers:
                px, rad, vis, truth_px, tm, inview = per_marker[m.name]
                win = _draw_spot(acc, px[i], rad[i], vis[i], m.brightness_e_per_s * cam.exposure_s, cam.psf_sigma_px)
                if win is not None:
                    windows.append(win)
                rows.append((int(f), float(t_mid[i]), m.name, float(truth_px[i, 0]), float(truth_px[i, 1]),
                             bool(vis[i].mean() >= 0.5), float(th[i]), float(ph[i]), float(tm[i]), bool(inview[i])))
            truth = pd.DataFrame(rows, columns=list(TRUTH_COLUMNS))
            if noise:
                image = _sensor(acc, windows, cam, rng, bg, table)
            else:
                image = (acc + bg).astype(np.float32)
            for (y0, y1, x0, x1) in windows:
                acc[y0:y1, x0:x1] = 0.0
            yield image, truth


#: ``lossless``: FFV1 in Matroska (8 or 16 bit); ``raw``: uncompressed 8-bit AVI (large, decodes
#: at memory speed); ``mp4``: lossy MPEG-4 (small; the noise model no longer holds)
VIDEO_CODECS = ("lossless", "raw", "mp4")


def open_writer(path: Path, cam: Camera, codec: str) -> cv2.VideoWriter:
    sixteen = codec == "lossless" and cam.sensor.bit_depth > 8
    # raw: uncompressed frames, as machine-vision cameras record them (decoding costs nothing)
    fourcc = 0 if codec == "raw" else cv2.VideoWriter_fourcc(*("FFV1" if codec == "lossless" else "mp4v"))
    params = [cv2.VIDEOWRITER_PROP_IS_COLOR, 0, cv2.VIDEOWRITER_PROP_DEPTH, cv2.CV_16U if sixteen else cv2.CV_8U]
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, fourcc, float(cam.fps), (cam.width_px, cam.height_px), params)
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV could not open a {codec} video writer for {path}")
    return writer


def render_video(protocol: Protocol, out_dir: str | Path, *, seed: int = 0, codec: str = "lossless",
                 duration_s: float | None = None, calibration_views: int = 12,
                 progress: Callable[[int, int], None] | None = None) -> dict:
    """Render the protocol's scene to ``out_dir``: video, ``truth.csv``, ``camera.json``, ``calibration/``.

    Returns a summary (paths, frame count, timings).  The video is written under a
    temporary name and renamed only when complete; on any error nothing is left
    under the final names.
    """
    if codec not in VIDEO_CODECS:
        raise ValueError(f"codec = {codec!r}: allowed {', '.join(map(repr, VIDEO_CODECS))}")
    setup = camera_setup(protocol)
    cam = setup.camera
    if codec == "raw" and cam.sensor.bit_depth > 8:
        raise ValueError(f"codec = 'raw' writes 8-bit AVI; camera.bit_depth = {cam.sensor.bit_depth}: use 'lossless' "
                         "(FFV1 keeps 16 bits)")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    duration = protocol.scene.duration_s if duration_s is None else float(duration_s)
    n_frames = int(math.floor(duration * cam.fps + 1e-9))
    start = time.perf_counter()
    paths = marker_paths(protocol, setup, duration)
    t_sim = time.perf_counter() - start
    name = {"lossless": "video.mkv", "mp4": "video.mp4", "raw": "video.avi"}[codec]
    tmp = out / f".{name}.partial{Path(name).suffix}"
    writer = open_writer(tmp, cam, codec)
    truths = []
    t_render = t_encode = 0.0
    try:
        t0 = time.perf_counter()
        for k, (image, truth) in enumerate(render_frames(protocol, seed=seed, duration_s=duration, setup=setup,
                                                         paths=paths)):
            t1 = time.perf_counter()
            t_render += t1 - t0
            if codec == "mp4" and image.dtype == np.uint16:
                image = (image >> (cam.sensor.bit_depth - 8)).astype(np.uint8)
            writer.write(image)
            t0 = time.perf_counter()
            t_encode += t0 - t1
            truths.append(truth)
            if progress and (k % 50 == 0 or k == n_frames - 1):
                progress(k + 1, n_frames)
        writer.release()
        truth = pd.concat(truths, ignore_index=True)
        # a marker never in the field of view is a misconfigured camera or marker; one hidden
        # behind the rig for the whole clip is not (it is marked visible = False)
        never = [m.name for m in setup.markers if not truth[truth.marker == m.name].in_view.any()]
        if never:
            raise ProtocolError(f"markers.{never[0]}: never in the camera's field of view in the {n_frames} "
                                "frames (check camera.position_m, look_at_m and the marker position)")
        os.chmod(tmp, 0o644)
        os.replace(tmp, out / name)
    finally:
        writer.release()
        if tmp.exists():
            tmp.unlink()
    _io.write_csv(truth, out / "truth.csv")
    _io.write_json(cam.to_json(), out / "camera.json")
    calib = render_calibration_images(cam, out / "calibration", seed=seed, n_views=calibration_views) \
        if calibration_views else None
    return {"video": str(out / name), "frames": n_frames, "simulate_s": t_sim, "render_s": t_render,
            "encode_s": t_encode, "calibration": calib}


# --------------------------------------------------------------------------------------
# calibration images


def render_calibration_images(cam: Camera, out_dir: str | Path, *, seed: int = 0, n_views: int = 12,
                              cols: int = 9, rows: int = 6, square_m: float = 0.02) -> dict:
    """Checkerboard images through the same camera at varied poses, for ``gyrorig calibrate``.

    ``cols x rows`` inner corners (OpenCV's pattern size), squares of ``square_m``; boards
    near the pivot, tilted up to 35 deg.  Writes ``view_NN.png`` and ``board.json`` (the
    board and the true pose of each view, for tests).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([seed, 7919])
    h, w = cam.height_px, cam.width_px
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), axis=-1)
    norm = cv2.undistortPoints(grid.reshape(-1, 1, 2), cam.camera_matrix, cam.distortion).reshape(-1, 2)
    rays = np.column_stack([norm, np.ones(len(norm))])
    # local Jacobian of the normalised coordinates with respect to the pixel position
    grid_n = norm.reshape(h, w, 2)
    jac_x = np.zeros((h, w, 3))
    jac_y = np.zeros((h, w, 3))
    jac_x[:, :, :2] = np.gradient(grid_n, axis=1)
    jac_y[:, :, :2] = np.gradient(grid_n, axis=0)
    jac_x, jac_y = jac_x.reshape(-1, 3), jac_y.reshape(-1, 3)
    dist_to_pivot = float(np.linalg.norm(cam.tvec))
    s = cam.sensor
    white_e = 0.6 * s.full_well_e
    dark_e = 0.08 * s.full_well_e
    poses = []
    while len(poses) < n_views:
        angles = np.radians(rng.uniform(-35, 35, 2))
        rot_board = cv2.Rodrigues(np.array([angles[0], angles[1], rng.uniform(-np.pi, np.pi)]))[0]
        # board centre: ahead of the camera near the pivot's depth, within the central field
        centre = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), 1.0]) * \
            dist_to_pivot * rng.uniform(0.8, 1.05)
        rmat = rot_board  # board -> camera
        size = np.array([(cols + 1) * square_m, (rows + 1) * square_m])
        origin = centre - rmat @ np.array([size[0] / 2, size[1] / 2, 0.0])
        corners = np.array([[(i + 1) * square_m, (j + 1) * square_m, 0.0] for j in range(rows) for i in range(cols)])
        pts = (rmat @ corners.T).T + origin
        px = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.camera_matrix, cam.distortion)[0].reshape(-1, 2)
        margin = 20
        if not ((px[:, 0] > margin).all() and (px[:, 0] < w - margin).all() and (px[:, 1] > margin).all()
                and (px[:, 1] < h - margin).all()):
            continue
        nrm = rmat[:, 2]
        # each pixel integrates its area: 3 x 3 sub-samples, rays from the undistortion map and its Jacobian
        e = np.zeros(h * w)
        for dy in (-1 / 3, 0.0, 1 / 3):
            for dx in (-1 / 3, 0.0, 1 / 3):
                r = rays + dx * jac_x + dy * jac_y
                with np.errstate(divide="ignore", invalid="ignore"):
                    sdist = (nrm @ origin) / (r @ nrm)
                hit = r * sdist[:, None] - origin
                bx, by = hit @ rmat[:, 0], hit @ rmat[:, 1]
                # a white margin of one square around the (cols + 1) x (rows + 1) checker, as printed boards have
                on_board = (sdist > 0) & (bx >= -square_m) & (bx <= size[0] + square_m) & (by >= -square_m) & \
                    (by <= size[1] + square_m)
                in_checker = (bx >= 0) & (bx < size[0]) & (by >= 0) & (by < size[1])
                dark = in_checker & ((np.floor(bx / square_m) + np.floor(by / square_m)) % 2 == 0)
                e += np.where(on_board, np.where(dark, dark_e, white_e), s.background_e_per_s * cam.exposure_s)
        e /= 9.0
        img = cv2.GaussianBlur(e.reshape(h, w).astype(np.float32), (0, 0), cam.psf_sigma_px)
        noisy = rng.poisson(np.maximum(img, 0)).astype(np.float64) + rng.normal(0, s.read_noise_e, img.shape)
        adu = np.clip(np.floor(np.clip(noisy, 0, s.full_well_e) / s.gain_e_per_adu + 0.5), 0, s.max_adu)
        adu = adu.astype(np.uint8 if s.bit_depth == 8 else np.uint16)
        ok, png = cv2.imencode(".png", adu)
        with _io.atomic_path(out / f"view_{len(poses):02d}.png") as tmp:
            tmp.write_bytes(png.tobytes())
        # pose of the board in the camera frame with OpenCV's object points (corner grid from (0,0))
        obj_origin = origin + rmat @ np.array([square_m, square_m, 0.0])
        poses.append({"rvec": cv2.Rodrigues(rmat)[0].ravel().tolist(), "tvec": obj_origin.tolist()})
    board = {"cols": cols, "rows": rows, "square_m": square_m, "views": poses,
             "object_points": "corner (i, j) at (i * square_m, j * square_m, 0), i < cols fastest"}
    _io.write_json(board, out / "board.json")
    return {"dir": str(out), "views": n_views}
