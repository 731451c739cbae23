"""How the work after the tracking loop grows with the record's length: ``gyrorig bench length``.

A phone's default 30 frames/s record of a nodding top is checked against a path of sinusoids over the whole record
(:mod:`gyrorig.tracking.harmonic`), then smoothed and fitted.  Each stage should take time in proportion to the
frames (or a little more), so that a record of minutes costs minutes at most.  The records are pixel tracks of the
simulated tip (the protocol's camera, white noise of ``noise_px``, frame times jittered by 5 % of an interval, 2 %
of the frames dropped) taken through :func:`gyrorig.tracking.angles_from_pixel_track` (the tracker's record checks
on a track), :func:`gyrorig.pipeline.smooth_and_fit` (the smoother's noise levels by maximum likelihood, the fit).
The figures: seconds per stage, microseconds per frame, and the growth exponent from the record before (1: time in
proportion to the frames; 2: to their square).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
import pandas as pd

from ..camera import camera_setup
from ..physics import simulate
from ..protocols import BUNDLED_PROTOCOL_DIR, load_protocol
from ..render.paths import project
from ..tracking.tracker import tip_marker

__all__ = ["record_length_benchmark", "DEFAULT_FRAMES"]

DEFAULT_FRAMES = (1000, 4000, 16000)


def _pixel_track(protocol, fps: float, frames: int, noise_px: float, rng: np.random.Generator):
    """The simulated tip's pixel track (``frame, t_s, x_px, y_px, sigma_px``: the noise stated), the camera at
    ``fps``."""
    camera = replace(camera_setup(protocol).camera, fps=fps)
    number = np.sort(rng.choice(int(frames * 1.02), frames, replace=False))
    t = (number + rng.uniform(-0.05, 0.05, frames)) / fps
    t = t - t.min()
    mid = t + camera.exposure_s / 2
    protocol = replace(protocol, scene=replace(protocol.scene, duration_s=float(mid.max()) + 1.0 / fps))
    df = simulate(protocol, t_eval_s=mid)
    theta, phi = df.theta_rad.to_numpy(), df.phi_rad.to_numpy()
    length = float(tip_marker(protocol).position_m[2])
    tip = length * np.stack([np.sin(theta) * np.sin(phi), -np.sin(theta) * np.cos(phi), np.cos(theta)], axis=1)
    xy = project(camera, tip)[0] + rng.normal(0.0, noise_px, (frames, 2))
    track = pd.DataFrame({"frame": number, "t_s": t, "x_px": xy[:, 0], "y_px": xy[:, 1], "sigma_px": noise_px})
    return track, camera


def record_length_benchmark(protocol: str = "air-cushion-heavy-top", frames=DEFAULT_FRAMES, fps: float = 30.0,
                            noise_px: float = 0.1, seed: int = 0, progress=None) -> pd.DataFrame:
    """One row per record length: ``frames``, ``record_s``, and per stage (``check``: the pixel track to angles with
    its errors checked; ``smooth``; ``fit``) its seconds and microseconds per frame, the growth exponent from the
    row before (``*_exponent``), the check's ``path`` (``sinusoids``, ``neighbours`` or ``unchecked``) and its
    ``factor`` (the errors' scale against ``noise_px``: about 1 where checked)."""
    from ..pipeline import smooth_and_fit
    from ..tracking.imported import angles_from_pixel_track

    base = load_protocol(BUNDLED_PROTOCOL_DIR / f"{protocol}.toml")
    rows = []
    for n in frames:
        rng = np.random.default_rng(seed)
        track, camera = _pixel_track(base, fps, int(n), noise_px, rng)
        t0 = time.perf_counter()
        angles, summary = angles_from_pixel_track(track, camera, base)
        t1 = time.perf_counter()
        fitted = smooth_and_fit(angles, base, rng=rng, stage=lambda _message: None)
        check = summary["sigma_check"]
        row = {"frames": int(n), "record_s": float(np.ptp(track.t_s)), "check_s": t1 - t0,
               "smooth_s": fitted.time_s["smooth"], "fit_s": fitted.time_s["fit"],
               "path": summary["checked_by"], "factor": float(check.get("factor", math.nan))}
        rows.append(row)
        if progress:
            progress(row)
    out = pd.DataFrame(rows)
    for stage in ("check", "smooth", "fit"):
        out[f"{stage}_us_per_frame"] = out[f"{stage}_s"] / out.frames * 1e6
        growth = np.log(out[f"{stage}_s"] / out[f"{stage}_s"].shift()) / np.log(out.frames / out.frames.shift())
        out[f"{stage}_exponent"] = growth
    return out
