"""Throughput and precision of the video stages: ``gyrorig bench render``, ``bench track``, ``bench smooth``.

These print figures; they are not timed unit tests.  Compare ratios measured in one run (the
machines are shared and noisy).
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from ..camera import camera_setup
from ..geometry import wrap_angle
from ..physics import simulate
from ..protocols import BUNDLED_PROTOCOL_DIR, load_protocol
from ..render import open_writer, marker_paths, render_frames, render_video
from ..smooth import estimate_noise, kalman_smooth, prepare_measurements
from ..tracking import load_camera, spot_crb_px, track_video, warm_up

__all__ = ["render_throughput", "track_benchmark", "smooth_benchmark"]


# --------------------------------------------------------------------------------------
# rendering throughput (gyrorig bench render)


def render_throughput(n_frames: int = 100) -> pd.DataFrame:
    """Frames per second of rendering (no encoding) and of OpenCV's FFV1 encoder, same frames.

    Sizes 640x480 and 1440x1080, with motion blur (8 sub-exposure samples) and without (1),
    on the air-cushion protocol's markers and sensor.  The target is rendering at least as
    fast as encoding, so that the disk encoder is the limit.
    """
    base = load_protocol(BUNDLED_PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    rows = []
    for (w, h) in [(640, 480), (1440, 1080)]:
        for nsub in (1, 8):
            cam_t = dict(base.extra["camera"])
            scale = w / 1440
            cam_t.update(width_px=w, height_px=h, pixel_size_um=3.45 / scale, motion_blur_samples=nsub)
            p = replace(base, extra={**base.extra, "camera": cam_t})
            setup = camera_setup(p)
            duration = n_frames / setup.camera.fps
            paths = marker_paths(p, setup, duration)
            start = time.perf_counter()
            frames = [img for img, _ in render_frames(p, duration_s=duration, setup=setup, paths=paths)]
            t_render = time.perf_counter() - start
            with tempfile.TemporaryDirectory() as tmp:
                writer = open_writer(Path(tmp) / "v.mkv", setup.camera, "lossless")
                start = time.perf_counter()
                for f in frames:
                    writer.write(f)
                writer.release()
                t_encode = time.perf_counter() - start
            rows.append(dict(width_px=w, height_px=h, motion_blur_samples=nsub, frames=len(frames),
                             render_fps=len(frames) / t_render, ffv1_encode_fps=len(frames) / t_encode,
                             render_over_encode=t_encode / t_render,
                             encoding_share=t_encode / (t_encode + t_render)))
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------------------
# tracking precision and speed (gyrorig bench track)


def track_benchmark(*, duration_s: float = 1.0, sizes=((1440, 1080), (640, 480)), seed: int = 0) -> pd.DataFrame:
    """Render the air-cushion rig, track it, and compare with the truth and the bound.

    For each image size: FFV1 with motion blur off (the bound's model is exact) and on, and
    uncompressed video (blur off), which shows the tracker's own speed when decoding is free, tracking
    the tip alone and with the frame's dots:
    RMS position error of the tip against the truth, the Cramer-Rao bound, their ratio,
    the standard deviation of the normalised errors of x, y, theta and phi, and the
    tracking speed with and without video decoding.
    """
    warm_up()
    base = load_protocol(BUNDLED_PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    rows = []
    for (w, h) in sizes:
        for codec, nsub, dots in (("lossless", 1, False), ("lossless", 8, False), ("raw", 1, False), ("raw", 1, True)):
            cam_t = dict(base.extra["camera"])
            cam_t.update(width_px=w, height_px=h, pixel_size_um=3.45 * 1440 / w, motion_blur_samples=nsub)
            p = replace(base, extra={**base.extra, "camera": cam_t})
            with tempfile.TemporaryDirectory() as tmp:
                video = render_video(p, f"{tmp}/v", seed=seed, duration_s=duration_s, calibration_views=0,
                                     codec=codec)["video"]
                cam = load_camera(f"{tmp}/v/camera.json")
                start = time.perf_counter()
                cap = cv2.VideoCapture(video, cv2.CAP_FFMPEG)
                cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
                while cap.read()[0]:
                    pass
                cap.release()
                decode_only = time.perf_counter() - start
                start = time.perf_counter()
                summary = track_video(video, cam, p, f"{tmp}/t", frame_dots=dots)
                wall = time.perf_counter() - start
                mk = pd.read_csv(f"{tmp}/t/markers.csv")
                mk = mk[mk.marker == "tip"]
                angles = pd.read_csv(f"{tmp}/t/angles.csv").dropna(subset=["theta_rad"])
                truth = pd.read_csv(f"{tmp}/v/truth.csv")
            truth = truth[truth.marker == "tip"]
            m = mk.merge(truth, on="frame", suffixes=("", "_true"))
            setup = camera_setup(p)
            c = setup.camera
            tip = next(x for x in setup.markers if x.name == "tip")
            amp = tip.brightness_e_per_s * c.exposure_s / cam.gain_e_per_adu
            bg = c.sensor.background_e_per_s * c.exposure_s / cam.gain_e_per_adu
            crb = np.array([spot_crb_px(r.x_px_true, r.y_px_true, r.radius_px, amp, bg, cam) for r in m.itertuples()])
            err = np.hypot(m.x_px - m.x_px_true, m.y_px - m.y_px_true) / math.sqrt(2)
            sim = simulate(p, t_eval_s=angles.t_s.to_numpy())
            e_th = (angles.theta_rad.to_numpy() - sim.theta_rad.to_numpy()) / angles.theta_sigma_rad.to_numpy()
            e_ph = wrap_angle(angles.phi_rad.to_numpy() - sim.phi_rad.to_numpy()) / \
                angles.phi_sigma_rad.to_numpy()
            n = summary["frames"]
            rows.append(dict(
                width_px=w, height_px=h, codec=codec, motion_blur_samples=nsub, frame_dots=dots, frames=n,
                tracked_fraction=summary["tracked_fraction"],
                rms_error_px=float(np.sqrt(np.mean(err**2))), crb_px=float(np.sqrt(np.mean(crb**2))),
                error_over_crb=float(np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(crb**2))),
                pull_std_x=float(np.std((m.x_px - m.x_px_true) / m.sigma_x_px)),
                pull_std_y=float(np.std((m.y_px - m.y_px_true) / m.sigma_y_px)),
                pull_std_theta=float(np.std(e_th)), pull_std_phi=float(np.std(e_ph)),
                track_fps=n / summary["track_s"], decode_only_fps=n / decode_only, end_to_end_fps=n / wall))
    return pd.DataFrame(rows)


# ------------------------------------------------------------------------------------- smoother speed
def smooth_benchmark(n_frames: int = 100_000, n_filterpy: int = 20_000, seed: int = 0) -> dict:
    """Speed of the compiled smoother against filterpy on the same model, and their agreement.

    Synthetic tracked angles (a nutating, precessing tip with white noise, 200 fps, 2 %
    of frames missing, uneven frame times).  filterpy runs on the first ``n_filterpy``
    frames (it takes ~90 us per frame); both engines are compared there.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / 200.0 + rng.uniform(0, 1e-3, n_frames)
    theta = 0.79 + 0.02 * np.cos(59.5 * t)
    phi = 1.72 * t + 0.028 * np.sin(59.5 * t)
    th = theta + 2e-5 * rng.normal(size=n_frames)
    ph = phi + 3e-5 * rng.normal(size=n_frames)
    gone = rng.uniform(size=n_frames) < 0.02
    th[gone] = ph[gone] = np.nan
    df = pd.DataFrame({"frame": np.arange(n_frames), "t_s": t, "theta_rad": th,
                       "phi_rad": wrap_angle(ph), "theta_sigma_rad": 2e-5, "phi_sigma_rad": 3e-5,
                       "theta_phi_corr": 0.1})
    m = prepare_measurements(df)
    kalman_smooth(m, 1.0, 1.0)  # compile (cached on disk after the first run)
    times = []
    for _ in range(3):
        start = time.perf_counter()
        kalman_smooth(m, 10.0, 10.0)
        times.append(time.perf_counter() - start)
    start = time.perf_counter()
    qt, qp, _, info = estimate_noise(m)
    ml_s = time.perf_counter() - start
    sub = prepare_measurements(df.iloc[:n_filterpy])
    start = time.perf_counter()
    ref = kalman_smooth(sub, qt, qp, engine="filterpy")
    fp_s = time.perf_counter() - start
    fast = kalman_smooth(sub, qt, qp)
    sd = np.sqrt(np.einsum("nii->ni", ref[2]))
    dx = float(np.max(np.abs(fast[1] - ref[1]) / sd))
    dP = np.abs(fast[2] - ref[2]) / (sd[:, :, None] * sd[:, None, :])
    return {"frames": n_frames, "fast_s": float(np.median(times)), "fast_us_per_frame": float(np.median(times)) / n_frames * 1e6,
            "ml_noise_s": ml_s, "ml_evaluations": info["ml_evaluations"], "q_theta": qt, "q_phi": qp,
            "filterpy_frames": n_filterpy, "filterpy_s": fp_s, "filterpy_us_per_frame": fp_s / n_filterpy * 1e6,
            "speedup": (fp_s / n_filterpy) / (float(np.median(times)) / n_frames),
            "max_state_diff_in_sigma": dx, "max_cov_diff_rel_after_first": float(np.max(dP[1:])),
            "max_cov_diff_rel_first": float(np.max(dP[0])), "same_gating": bool(np.array_equal(fast[4], ref[4]))}
