"""Frames and videos: every marker drawn through the camera and the sensor, written with the truth beside."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from .. import _io
from ..camera import Camera, CameraSetup, camera_setup
from ..geometry import board_lab_rotation
from ..physics.rotations import unwrapped_angles_from_tip
from ..protocols import Protocol, ProtocolError
from .board import render_calibration_images, render_pose_board
from .draw import draw_disc, draw_sphere
from .paths import MarkerPaths, marker_paths, marker_samples
from .sensor import BackgroundTables, expose, response_table

__all__ = ["render_frames", "render_video", "open_writer", "TRUTH_COLUMNS", "VIDEO_CODECS"]

TRUTH_COLUMNS = ("frame", "t_s", "marker", "x_px", "y_px", "visible", "theta_rad", "phi_rad", "t_marker_s",
                 "in_view")


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
    tables = BackgroundTables(cam.sensor, cam.sensor.background_e_per_s * cam.exposure_s)
    response = response_table(cam.sensor)
    # expected spot electrons; only the windows around markers are ever touched (and reset)
    acc = np.zeros((cam.height_px, cam.width_px), dtype=np.float64)
    for start in range(0, n_frames, chunk):
        frames = np.arange(start, min(start + chunk, n_frames))
        per_marker = {m.name: marker_samples(cam, setup, paths, m, frames) for m in setup.markers}
        t_mid = frames / cam.fps + cam.exposure_s / 2
        # each marker's rows carry the tip's angles at that marker's own mid-exposure time (a rolling
        # shutter exposes its row later than the frame's start)
        by_times: dict[bytes, tuple] = {}  # with a global shutter every marker shares one time grid
        angles = {}
        for m in setup.markers:
            t_m = per_marker[m.name].t_mid
            key = t_m.tobytes()
            if key not in by_times:
                by_times[key] = unwrapped_angles_from_tip(paths.tip(t_m), phi_at_pole_rad=paths.phi_reference_rad)
            angles[m.name] = by_times[key]
        for i, f in enumerate(frames):
            light = float(cam.illumination(t_mid[i]))
            table, bg = tables(light)
            windows = []
            rows = []
            for m in setup.markers:
                sm = per_marker[m.name]
                peak = m.brightness_e_per_s * cam.exposure_s * light
                if m.shape == "disc":
                    win = draw_disc(acc, cam, sm.pts[i], sm.normals[i], m.radius_m, sm.visible[i], peak)
                else:
                    win = draw_sphere(acc, sm.px[i], sm.radius[i], sm.visible[i], peak, cam.psf_sigma_px)
                if win is not None:
                    windows.append(win)
                th, ph = angles[m.name]
                rows.append((int(f), float(t_mid[i]), m.name, float(sm.truth_px[i, 0]), float(sm.truth_px[i, 1]),
                             bool(sm.visible[i].mean() >= 0.5), float(th[i]), float(ph[i]), float(sm.t_mid[i]),
                             bool(sm.in_view[i])))
            truth = pd.DataFrame(rows, columns=list(TRUTH_COLUMNS))
            if noise:
                image = expose(acc, windows, cam, rng, bg, table, response)
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
                 progress: Callable[[int, int], None] | None = None, hold_s: float = 0.0) -> dict:
    """Render the protocol's scene to ``out_dir``: video, ``truth.csv``, ``camera.json``, ``calibration/``.

    ``hold_s``: the top held still by its frame (the rotor spinning) for so long before its release, as a phone
    records from before it: the video is ``hold_s`` longer than the scene's duration, its times from its first frame.

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
    if not (math.isfinite(hold_s) and hold_s >= 0):
        raise ValueError(f"hold_s = {hold_s!r}: the time the top is held before its release, allowed >= 0 s")
    duration = (protocol.scene.duration_s if duration_s is None else float(duration_s)) + hold_s
    n_frames = int(math.floor(duration * cam.fps + 1e-9))
    start = time.perf_counter()
    paths = marker_paths(protocol, setup, duration, hold_s)
    t_sim = time.perf_counter() - start
    name = {"lossless": "video.mkv", "mp4": "video.mp4", "raw": "video.avi"}[codec]
    tmp = out / f".{name}.partial{Path(name).suffix}"
    writer = open_writer(tmp, cam, codec)
    records = []  # the truth's rows as tuples: a small table kept per frame fragments the heap under the encoder's
    # frame buffers, which are then never given back
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
            records.extend(truth.itertuples(index=False, name=None))
            if progress and (k % 50 == 0 or k == n_frames - 1):
                progress(k + 1, n_frames)
        writer.release()
        truth = pd.DataFrame(records, columns=list(TRUTH_COLUMNS))
        # a marker never in the field of view is a misconfigured camera or marker; one hidden
        # behind the rig for the whole clip is not (it is marked visible = False)
        never = [m.name for m in setup.markers if not truth[truth.marker == m.name].in_view.any()]
        if never:
            raise ProtocolError(f"markers.{never[0]}: never in the camera's field of view in the {n_frames} "
                                "frames (check camera.centre_m, look_at_m and the marker position)")
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
    pose_board = _pose_board(cam, out / "pose_board", seed) if calibration_views else None
    return {"video": str(out / name), "frames": n_frames, "simulate_s": t_sim, "render_s": t_render,
            "encode_s": t_encode, "calibration": calib, "pose_board": pose_board}


#: the pose board's place in the renders (render_pose_board's default 9 x 6 inner corners of 20 mm): centred
#: under the pivot, this far below it, its x axis at this azimuth
POSE_BOARD_HEIGHT_M = -0.05
POSE_BOARD_YAW_RAD = math.radians(20.0)
_POSE_BOARD = {"cols": 9, "rows": 6, "square_m": 0.02}


def _pose_board(cam, out: Path, seed: int) -> dict | None:
    """A board lying at a known place (``pose_board/board.png``, ``placement.json``); None when it is not
    wholly in view."""
    b = _POSE_BOARD
    centre_from_origin = np.array([(b["cols"] - 1) / 2, (b["rows"] - 1) / 2, 0.0]) * b["square_m"]
    origin = -board_lab_rotation(POSE_BOARD_YAW_RAD) @ centre_from_origin + np.array([0.0, 0.0, POSE_BOARD_HEIGHT_M])
    try:
        return render_pose_board(cam, out, origin_m=origin, yaw_rad=POSE_BOARD_YAW_RAD, seed=seed, **b)
    except ValueError:
        return None
