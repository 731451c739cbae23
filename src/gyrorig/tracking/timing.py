"""Frame times: numbering a recording's frames on the camera's rate, slow motion, and the rate checked against the
frames' own times (a variable rate, dropped frames, times in milliseconds)."""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

from ..camera import Camera
from .errors import BadInputError

__all__ = ["FrameClock", "settle_timing", "check_frame_rate", "frame_interval_stats", "checked_frame_times", "TIME_SNAP_FRAMES",
           "MIN_PLAUSIBLE_FPS", "RATE_CHECK_FRAMES", "RATE_MISMATCH_SHARE", "FPS_TOLERANCE", "VARIABLE_RATE_JITTER"]

logger = logging.getLogger(__name__)

#: a container time within this many frame intervals of a frame's nominal time is that frame's (rounded)
TIME_SNAP_FRAMES = 0.3
#: frames slower than this (a frame rate from the frames' own times) are taken as times in ms and warned of [1/s]
MIN_PLAUSIBLE_FPS = 1.0
#: the frame rate is checked against camera.json's after this many frames (and again at the end)
RATE_CHECK_FRAMES = 30
#: a record whose intervals are this many grid steps or more (all but :data:`RATE_MISMATCH_SHARE` of them) is stored
#: at a lower rate than camera.json's fps, not missing frames
RATE_MISMATCH_SHARE = 0.9


class FrameClock:
    """Frame numbers and times from the source's times: scaled to real time (slow motion), numbered on the camera's
    rate (a frame that would repeat the last number, a variable rate's jitter, takes the next one and keeps its own
    time), snapped to its number's time when within :data:`TIME_SNAP_FRAMES` (a container's rounding), the rate
    checked after :data:`RATE_CHECK_FRAMES` frames (``check_rate``: not when the same file is read again)."""

    def __init__(self, fps: float, time_scale: float, source, *, check_rate: bool = True):
        self.fps, self.time_scale, self.source, self.check_rate = fps, time_scale, source, check_rate
        self.times: list[float] = []  # every frame's time as read (scaled) [s]
        self.last = -1
        self.renumbered = 0

    def number(self, t_s: float, k: int) -> tuple[int, float]:
        """The ``k``-th decoded frame's number and time [s] (its time NaN: counted at the camera's rate)."""
        t = t_s * self.time_scale if math.isfinite(t_s) else k / self.fps
        self.times.append(t)
        index = int(round(t * self.fps))
        if index <= self.last:
            self.renumbered += 1
            index = self.last + 1
        self.last = index
        if self.check_rate and len(self.times) == RATE_CHECK_FRAMES:
            check_frame_rate(np.asarray(self.times), self.fps, self.source)
        if abs(t - index / self.fps) <= TIME_SNAP_FRAMES / self.fps:
            t = index / self.fps
        return index, t


def settle_timing(camera: Camera, frames, source) -> tuple[Camera, float]:
    """The camera with its frame rate settled, and the factor from the file's times to real times: a capture rate
    stated apart from the file's (slow motion) scales the file's times so that their interval (the slope of the
    times against their grid numbers) is one capture interval."""
    if math.isfinite(camera.capture_fps):
        interval = source.frame_interval_s() if hasattr(source, "frame_interval_s") else math.nan
        if not (math.isfinite(interval) and interval > 0):
            raise BadInputError(f"{source}: a capture rate of {camera.capture_fps:g} fps is given, but the file has no "
                                "frame times to scale")
        return replace(camera, fps=camera.capture_fps), 1.0 / (camera.capture_fps * interval)
    if not math.isfinite(camera.fps):
        fps = frames.fps
        if not (math.isfinite(fps) and fps > 0):
            interval = source.frame_interval_s() if hasattr(source, "frame_interval_s") else math.nan
            if not (math.isfinite(interval) and interval > 0):
                raise BadInputError(f"{source}: no frame rate: the frames carry no times and camera.json gives no "
                                    "fps (add fps to camera.json, or a timestamps.csv with frame, t_s)")
            fps = 1.0 / interval
        if fps < MIN_PLAUSIBLE_FPS:
            logger.warning("%s: the frames are %.4g s apart (%.3g fps): frame times in milliseconds where seconds "
                           "are meant?", source, 1.0 / fps, fps)
        return replace(camera, fps=fps), 1.0
    return camera, 1.0


def check_frame_rate(t_s: np.ndarray, fps: float, source) -> None:
    """Refuse frame times that camera.json's ``fps`` cannot number (bad input, :class:`BadInputError`): frames
    closer than 3/4 of a grid step (the file's rate is higher), or all but a few of them whole grid steps apart
    (:data:`RATE_MISMATCH_SHARE`: a slow-motion file stored at a lower rate than it was captured at; dropped
    frames leave only some such gaps).  A variable rate and dropped frames pass (they keep their own times)."""
    dt = np.diff(np.asarray(t_s, float))
    dt = dt[np.isfinite(dt)]
    if len(dt) < 3:
        return
    steps = dt * fps
    med = float(np.median(steps))
    if med < 0.75:
        raise BadInputError(f"{source}: the frames are {float(np.median(dt)) * 1e3:.4g} ms apart (median), "
                            f"{1.0 / float(np.median(dt)):.5g} fps, but camera.json says {fps:g} fps: two frames would "
                            "share one number; give camera.json the video's frame rate")
    if abs(med / 1000.0 - 1.0) < 0.05:
        raise BadInputError(f"{source}: the frames are {float(np.median(dt)):.4g} s apart (median), 1000 times "
                            f"camera.json's frame interval ({1.0 / fps:.4g} s at {fps:g} fps): frame times in "
                            "milliseconds where seconds are meant (t_s)?")
    wide = steps >= 1.5
    if len(dt) >= 10 and np.mean(wide) >= RATE_MISMATCH_SHARE:
        whole = np.abs(steps - np.round(steps)) < 0.2
        what = (f"{source}: all but {np.sum(~wide)} of {len(dt)} frame intervals are {med:.3g} frame intervals of "
                f"camera.json's {fps:g} fps ({1.0 / float(np.median(dt)):.5g} fps in the file)")
        if np.mean(whole[wide]) >= RATE_MISMATCH_SHARE:
            raise BadInputError(what + ": a slow-motion file stored at a lower rate than it was captured at? Give the "
                                "capture rate (--capture-fps or capture_fps in camera.json), or give camera.json's fps "
                                "the file's rate")
        raise BadInputError(what + ": camera.json's fps does not match the video")


#: the median frame interval may differ from 1 / camera.json's fps by this fraction before a warning
FPS_TOLERANCE = 0.005
#: intervals scattering by more than this fraction of the interval (SD, dropped frames left out): a variable rate
VARIABLE_RATE_JITTER = 0.05


def frame_interval_stats(t_s: np.ndarray, fps: float) -> dict:
    """The measured frame intervals (the container's own times) against camera.json's ``fps``.

    ``median_interval_s``, ``min_interval_s``, ``max_interval_s``, ``jitter_rel`` (SD of the intervals
    without the dropped-frame gaps, over the median), ``dropped_frames`` (gaps of 1.5 intervals or more,
    counted in frames), ``measured_fps`` (1 / median), ``agrees_with_camera`` and a ``warning`` when not:
    a median off by more than :data:`FPS_TOLERANCE` or a variable frame rate (jitter above
    :data:`VARIABLE_RATE_JITTER`, phone video); the frames keep their own times either way.
    """
    dt = np.diff(np.asarray(t_s, float))
    if len(dt) < 2 or not np.all(np.isfinite(dt)):
        return {}
    med = float(np.median(dt))
    gaps = dt >= 1.5 * med
    regular = dt[~gaps]
    jitter = float(np.std(regular) / med) if len(regular) > 1 and med > 0 else 0.0
    out = {"median_interval_s": med, "min_interval_s": float(dt.min()), "max_interval_s": float(dt.max()),
           "jitter_rel": jitter, "dropped_frames": int(np.sum(np.round(dt[gaps] / med) - 1)),
           "measured_fps": 1.0 / med if med > 0 else math.inf, "camera_fps": fps}
    t = np.asarray(t_s, float)
    off = t - np.round(t * fps) / fps
    out["max_offset_from_grid_frames"] = float(np.max(np.abs(off)) * fps)
    problems = []
    if out["max_offset_from_grid_frames"] <= TIME_SNAP_FRAMES:
        # every frame within a rounding of camera.json's grid (Matroska stores ms: 240 fps alternates 4 and 5 ms)
        out["agrees_with_camera"] = True
        return out
    if med > 0 and abs(med * fps - 1.0) > FPS_TOLERANCE:
        problems.append(f"the frames are {med * 1e3:.4g} ms apart (median), {1.0 / med:.5g} fps, but camera.json "
                        f"says {fps:g} fps")
    if jitter > VARIABLE_RATE_JITTER:
        problems.append(f"the frame intervals scatter by {jitter:.1%} of the interval (a variable frame rate): each "
                        "frame keeps its own time")
    out["agrees_with_camera"] = not problems
    if problems:
        out["warning"] = "; ".join(problems)
    return out


def checked_frame_times(clock: FrameClock, camera: Camera, time_scale: float, source, fields: str | None = None
                        ) -> dict:
    """The frame intervals measured against the camera's rate (:func:`frame_interval_stats`, with the time scale,
    the renumbering and, for an interlaced video read field by field, its field order); a warning when they
    disagree."""
    times = frame_interval_stats(np.asarray(clock.times), camera.fps)
    if times:
        times.update(time_scale=time_scale, renumbered_frames=clock.renumbered,
                     capture_fps=camera.capture_fps if math.isfinite(camera.capture_fps) else None, fields=fields)
    if not times.get("agrees_with_camera", True):
        logger.warning("%s: %s", source, times["warning"])
    return times
