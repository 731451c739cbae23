"""Frame times: numbering a recording's frames on the camera's rate, slow motion, and the rate checked against the
frames' own times (a variable rate, dropped frames, times in milliseconds)."""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

from ..camera import Camera
from .errors import BadInputError
from .scatter import path_residuals

__all__ = ["FrameClock", "settle_timing", "check_frame_rate", "frame_interval_stats", "checked_frame_times", "capture_on_grid",
           "TIME_SNAP_FRAMES",
           "FILE_RATE_RANGE", "FILE_RATE_SIGMAS", "FILE_RATE_DRIFT_FRAMES",
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
        self.read: dict[int, float] = {}  # frame number -> its time as read (scaled) [s]

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
        self.read[index] = t
        return index, self.given(index)

    def given(self, index: int) -> float:
        """The time [s] :meth:`number` gives frame ``index``: its time as read, or its number's time when within
        :data:`TIME_SNAP_FRAMES` of it."""
        t = self.read[index]
        return index / self.fps if abs(t - index / self.fps) <= TIME_SNAP_FRAMES / self.fps else t


def settle_timing(camera: Camera, frames, source) -> tuple[Camera, float]:
    """The camera with its frame rate settled, and the factor from the file's times to real times: a capture rate
    stated apart from the file's (slow motion) scales the file's times so that their interval (the slope of the
    times against their grid numbers) is one capture interval; a rate stated a little off the file's own is
    replaced by it (:func:`_file_rate`)."""
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
    return _file_rate(camera, source), 1.0


#: a file whose frames' rate differs from camera.json's by at most this fraction is numbered and timed on its own rate
#: (a nominal 30 for NTSC's 30000/1001, 29.97) when the difference is beyond :data:`FILE_RATE_SIGMAS` standard errors
#: and moves the record's last frame by more than :data:`FILE_RATE_DRIFT_FRAMES` of an interval
FILE_RATE_RANGE = 0.02
FILE_RATE_SIGMAS = 4.0
FILE_RATE_DRIFT_FRAMES = 0.05


def _file_rate(camera: Camera, source):
    """The camera with the file's own frame rate where camera.json states one a little off it (:data:`FILE_RATE_RANGE`:
    a phone's NTSC rate stated as 30 or 60; the grid drifts from the frames, whose times are then snapped to the
    wrong numbers' times), with a warning; else as it is.  The file's rate is the slope of its times, or the stated
    rate's NTSC value (times 1000/1001) where that slope is within :data:`FILE_RATE_SIGMAS` of its errors of it."""
    interval, se, n = source.frame_grid() if hasattr(source, "frame_grid") else (math.nan, math.nan, 0)
    if not (math.isfinite(interval) and interval > 0 and math.isfinite(se)):
        return camera
    off = interval * camera.fps - 1.0  # the file's interval over camera.json's, less 1
    if not (abs(off) <= FILE_RATE_RANGE and abs(off) > FILE_RATE_SIGMAS * se * camera.fps
            and abs(off) * n > FILE_RATE_DRIFT_FRAMES):
        return camera
    fps = 1.0 / interval
    ntsc = camera.fps * 1000.0 / 1001.0  # a television rate's exact value, where the file's is within its error of it
    fps = ntsc if abs(fps - ntsc) <= FILE_RATE_SIGMAS * se * fps * fps else fps
    logger.warning("%s: camera.json says %g fps, but the file's frames are %.6g fps apart (%+.2g %%, %.2g intervals "
                   "over its %d frames): they are numbered and timed on the file's rate", source, camera.fps, fps,
                   100.0 * (fps / camera.fps - 1.0), abs(off) * n, n)
    return replace(camera, fps=fps)


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


def frame_interval_stats(t_s: np.ndarray, fps: float, on_grid: bool = False) -> dict:
    """The measured frame intervals (the container's own times) against camera.json's ``fps``.

    ``median_interval_s`` (without the dropped-frame gaps), ``min_interval_s``, ``max_interval_s``, ``jitter_rel``
    (SD of the intervals without the gaps, over the median), ``dropped_frames`` (gaps of 1.5 intervals or more,
    counted in frames), ``measured_fps`` (1 / median), ``agrees_with_camera`` and a ``warning`` when not:
    a median off by more than :data:`FPS_TOLERANCE` (or three of its standard errors, if more: a jittered clock's
    median wanders) or a variable frame rate (jitter above
    :data:`VARIABLE_RATE_JITTER`, phone video); the frames keep their own times either way, unless ``on_grid``
    (the tip's path says the capture was steady: :func:`capture_on_grid`).
    """
    dt = np.diff(np.asarray(t_s, float))
    if len(dt) < 2 or not np.all(np.isfinite(dt)):
        return {}
    gaps = dt >= 1.5 * float(np.median(dt))
    regular = dt[~gaps]
    med = float(np.median(regular)) if len(regular) else float(np.median(dt))
    jitter = float(np.std(regular) / med) if len(regular) > 1 and med > 0 else 0.0
    # the median's own standard error (1.25 SD / sqrt(n) for a normal scatter): a jittered clock's median wanders
    tolerance = max(FPS_TOLERANCE, 3.0 * 1.2533 * jitter / math.sqrt(max(len(regular), 1)))
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
    if med > 0 and abs(med * fps - 1.0) > tolerance:
        problems.append(f"the frames are {med * 1e3:.4g} ms apart (median), {1.0 / med:.5g} fps, but camera.json "
                        f"says {fps:g} fps")
    if jitter > VARIABLE_RATE_JITTER:
        problems.append(f"the frame intervals scatter by {jitter:.1%} of the interval" + (
            ": the tip's path says the capture was steady and the file's clock jitters about it; each frame takes "
            "its time on camera.json's grid" if on_grid else " (a variable frame rate): each frame keeps its own time"))
    out["agrees_with_camera"] = not problems
    if problems:
        out["warning"] = "; ".join(problems)
    return out


def checked_frame_times(clock: FrameClock, camera: Camera, time_scale: float, source, fields: str | None = None,
                        capture: dict | None = None) -> dict:
    """The frame intervals measured against the camera's rate (:func:`frame_interval_stats`, with the time scale,
    the renumbering, for an interlaced video read field by field its field order, and ``capture``, what
    :func:`capture_on_grid` found); a warning when they disagree."""
    capture = capture or {}
    times = frame_interval_stats(np.asarray(clock.times), camera.fps, capture.get("capture") == "grid")
    if times:
        times.update(time_scale=time_scale, renumbered_frames=clock.renumbered,
                     capture_fps=camera.capture_fps if math.isfinite(camera.capture_fps) else None, fields=fields,
                     **capture)
    if not times.get("agrees_with_camera", True):
        logger.warning("%s: %s", source, times["warning"])
    return times


#: a frame's squared residual counts up to this (in its error's units) in :func:`capture_on_grid`'s comparison: a
#: wrong spot far off the path weighs the same whichever times are taken
CAPTURE_Z2_CAP = 25.0
#: the file's times are on camera.json's grid when none is further from it than this many intervals (a float's
#: rounding), and :func:`capture_on_grid` has nothing to decide
ON_GRID_FRAMES = 1e-6
#: the frames' paired differences of squared residuals must average this many of their standard errors from zero
#: for :func:`capture_on_grid` to take one set of times
CAPTURE_Z = 3.0
#: ... and only where the path follows the tip: its residuals' robust SD within this many of their errors (errors
#: too small by as much as a codec makes them pass; a path that cannot follow a fast nod at 30 frames/s does not)
CAPTURE_MAX_SCALE = 3.0
#: ... the differences summed over blocks of this many frames (a path's stencil: a frame and its six neighbours)
CAPTURE_BLOCK = 7


def capture_on_grid(angles, markers, tip_px: dict, tip_cov: dict, clock: FrameClock) -> dict:
    """Whether the frames were captured at the file's times or on the camera's grid, as the tip's path says, and
    each frame's ``t_s`` in ``angles`` and ``markers`` (its time, the exposure's middle and its row's delay) moved
    to that time, in place.

    A phone's file may carry the sensor's true times of a capture whose pace varied, or the times of a clock that
    jitters about a steady capture (an encoder stamping frames as they arrive, a container's rounding).  The tip's
    positions tell: each frame's residual about the smooth path through its neighbours
    (:func:`~gyrorig.tracking.scatter.path_residuals`, in its error's units) is found with the file's times and with
    the grid's, and the times whose squared residuals (each capped at :data:`CAPTURE_Z2_CAP`) are lower, over blocks
    of :data:`CAPTURE_BLOCK` frames, by :data:`CAPTURE_Z` standard errors of the blocks' mean difference (``z``)
    are the capture's.

    Returns ``{}`` when every time is on the grid (:data:`ON_GRID_FRAMES`), else ``capture`` (``grid``, ``file``,
    or ``unknown`` when the path cannot tell them: a still tip, a path that cannot follow the motion
    (:data:`CAPTURE_MAX_SCALE`), fewer than 7 tracked frames; the frames then keep the clock's times,
    :data:`TIME_SNAP_FRAMES`), the two sums, ``z``, the residuals' robust SD (``residual_sd``, the better times')
    and the number of frames off the grid."""
    numbers = np.array(sorted(clock.read), int)
    read = np.array([clock.read[f] for f in numbers])
    off = np.abs(read - numbers / clock.fps) * clock.fps > ON_GRID_FRAMES
    if not off.any():
        return {}
    out = {"capture": "unknown", "off_grid_frames": int(off.sum()), "z2_file": math.nan, "z2_grid": math.nan,
           "z": math.nan}
    rows = np.array(sorted(tip_px), int)
    if len(rows) < 7:
        return out
    shifts = {"file": {f: clock.read[f] - clock.given(f) for f in clock.read},
              "grid": {f: f / clock.fps - clock.given(f) for f in clock.read}}
    frames = angles.frame.to_numpy()[rows]
    xy = np.array([tip_px[r] for r in rows], float).reshape(-1, 2)
    var = np.array([np.diag(tip_cov[r]) for r in rows], float).reshape(-1, 2)
    active = np.all(np.isfinite(xy), axis=1) & np.all(np.isfinite(var) & (var > 0), axis=1)
    z2, scale = {}, {}
    for name, shift in shifts.items():
        t = angles.t_s.to_numpy()[rows] + np.array([shift.get(int(f), 0.0) for f in frames])
        _, z = path_residuals(t, frames, xy, var, active)
        z2[name] = np.sum(np.minimum(z * z, CAPTURE_Z2_CAP), axis=1)
        out[f"z2_{name}"] = float(np.sum(z2[name]))
        scale[name] = math.sqrt(float(np.median(z * z)) / 0.4549) if z.size else math.inf  # robust SD of z
    out["residual_sd"] = min(scale.values())
    if out["residual_sd"] > CAPTURE_MAX_SCALE:  # the path does not follow the motion (a low frame rate)
        return out
    # the frames' paired differences, summed over blocks as long as a path's stencil (neighbouring frames' residuals
    # share frames, so theirs are correlated)
    d = z2["file"] - z2["grid"]
    blocks = np.add.reduceat(d, np.arange(0, len(d), CAPTURE_BLOCK))[: len(d) // CAPTURE_BLOCK]
    spread = float(np.std(blocks, ddof=1)) if len(blocks) > 2 else 0.0
    out["z"] = float(np.mean(blocks) / (spread / math.sqrt(len(blocks)))) if spread > 0 else 0.0
    if abs(out["z"]) <= CAPTURE_Z:  # the path cannot tell them (a still tip, a path that cannot follow the motion)
        return out
    out["capture"] = "grid" if out["z"] > 0 else "file"
    for table in (angles, markers):
        table["t_s"] = table.t_s + table.frame.map(lambda f: shifts[out["capture"]].get(int(f), 0.0)).to_numpy(float)
    return out
