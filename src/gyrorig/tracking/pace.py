"""A slow-motion record whose ends run at another pace: a phone gallery's copy of a slow-motion video.

A phone's slow-motion video, shared or exported from its gallery, is stored again at one container rate with its
first and last part at normal speed: there every ``r``-th captured frame is kept (``r`` the capture rate over the
container rate, 8 for 240 frames/s stored at 30), between them the speed ramps down to the slowed middle, where
every captured frame is kept.  Nothing in the file says where the speed changes, so numbered on the capture rate
the ends' frames are ``r`` times too close in time.  The tip then moves ``r`` times farther per frame there than in
the middle, or (a motion too fast for the ends' pace to sample) is lost or off its path in most of their frames.

:func:`off_pace_ends` finds such ends on the tracked tip's direction: the record's steps (between frames tracked
one or two frames apart) are *fast* when the tip's direction turns more than ``sqrt(r)`` times the middle half's
median step per frame; a prefix (or suffix) of the record in which fast steps and frames without a position
(``missing``, ``outlier``) together outnumber the steps that are not fast, by :data:`MIN_EXCESS` or more and with at
least :data:`MIN_PLACED` frames with a position, is off pace.  Within the slowed middle a step is fast only where the
tip's speed exceeds ``sqrt(r)`` times its median (a nutation's peak speed is about 1.4-1.6 times its median), so the
check runs from ``r`` = :data:`MIN_RATIO` on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["OffPace", "off_pace_ends", "off_pace_rows", "MIN_RATIO", "MIN_EXCESS", "MIN_PLACED"]

#: the least ratio of capture rate to container rate the check runs at
MIN_RATIO = 3.0
#: an end is off pace when its fast steps and lost frames outnumber its other steps by this many, and it holds this
#: many frames with a position
MIN_EXCESS = 3
MIN_PLACED = 2
#: steps between frames farther apart than this are not used (a chord across a gap understates the speed)
MAX_STEP_FRAMES = 2


@dataclass(frozen=True)
class OffPace:
    """The ends :func:`off_pace_ends` found: how many of the record's rows (from its start, and from its end) are
    off pace, each end's median speed over the middle's (NaN: no such end), and the middle's median speed
    [rad per frame]."""

    head_rows: int
    tail_rows: int
    head_speed_ratio: float
    tail_speed_ratio: float
    middle_speed_rad: float

    @property
    def found(self) -> bool:
        return self.head_rows > 0 or self.tail_rows > 0


def _steps(frames: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The steps between consecutive tracked rows at most :data:`MAX_STEP_FRAMES` frames apart: the later row's
    position and the tip's turn per frame [rad]."""
    tracked = np.flatnonzero(np.all(np.isfinite(xyz), axis=1))
    if len(tracked) < 2:
        return np.empty(0, int), np.empty(0)
    a, b = tracked[:-1], tracked[1:]
    gap = frames[b] - frames[a]
    near = (gap >= 1) & (gap <= MAX_STEP_FRAMES)
    a, b, gap = a[near], b[near], gap[near]
    chord = np.linalg.norm(xyz[b] - xyz[a], axis=1)
    return b, 2.0 * np.arcsin(np.minimum(chord / 2.0, 1.0)) / gap


def _end_rows(score: np.ndarray, placed: np.ndarray, margin: int) -> int:
    """How many rows from the start form an off-pace end: the prefix of the largest summed ``score`` (+1 per fast
    step or lost frame, -1 per other step) and ``margin`` rows more, if that sum reaches :data:`MIN_EXCESS` and the
    prefix holds :data:`MIN_PLACED` rows with a position (``placed``: a tip lost for a run of frames, as one leaving
    the view, is no pace at all); else 0."""
    if not len(score):
        return 0
    total = np.cumsum(score)
    end = int(np.argmax(total))
    if total[end] < MIN_EXCESS or int(np.sum(placed[:end + 1])) < MIN_PLACED:
        return 0
    return min(end + 1 + margin, len(score))


def off_pace_ends(frames, xyz, lost, ratio: float) -> OffPace:
    """The record's ends that run faster than its middle (module docstring).

    ``frames`` (n,) the rows' frame numbers (increasing), ``xyz`` (n, 3) the tip's unit direction (NaN where the
    row has none), ``lost`` (n,) rows whose tip was lost or left out as off its path (a position that was never
    there counts as no evidence: a duplicate, a damaged picture), ``ratio`` the capture rate over the container
    rate.  Below :data:`MIN_RATIO`, or with too few steps in the middle half to know its pace, nothing is found."""
    frames, xyz, lost = np.asarray(frames, int), np.asarray(xyz, float), np.asarray(lost, bool)
    n = len(frames)
    none = OffPace(0, 0, math.nan, math.nan, math.nan)
    if not ratio >= MIN_RATIO or n < 20:
        return none
    at, speed = _steps(frames, xyz)
    middle = (at >= n // 4) & (at < n - n // 4)
    if np.sum(middle) < 10:
        return none
    pace = float(np.median(speed[middle]))
    if not pace > 0:
        return none
    score = lost.astype(float)
    score[at] = np.where(speed > math.sqrt(ratio) * pace, 1.0, -1.0)
    margin = math.ceil(math.sqrt(ratio))  # the ramp's last steps, shorter than sqrt(ratio) frames
    placed = np.all(np.isfinite(xyz), axis=1)
    head = _end_rows(score[: n // 2], placed[: n // 2], margin)
    tail = _end_rows(score[::-1][: n // 2], placed[::-1][: n // 2], margin)

    def ratio_of(rows: np.ndarray) -> float:
        inside = np.isin(at, rows)
        return float(np.median(speed[inside]) / pace) if inside.any() else math.nan

    return OffPace(head, tail, ratio_of(np.arange(head)) if head else math.nan,
                   ratio_of(np.arange(n - tail, n)) if tail else math.nan, pace)


def off_pace_rows(angles, ratio: float) -> tuple[np.ndarray, str]:
    """The rows of a track's angle table (:mod:`gyrorig.tables`) in off-pace ends (:func:`off_pace_ends`) that
    still have a position (those the tracker leaves out), and what to tell the user ("" when none)."""
    quality = angles.quality.astype(str)
    lost = quality.str.contains("missing|outlier").to_numpy()
    found = off_pace_ends(angles.frame.to_numpy(), angles[["tip_x", "tip_y", "tip_z"]].to_numpy(float), lost, ratio)
    n = len(angles)
    ends = np.r_[np.arange(found.head_rows), np.arange(n - found.tail_rows, n)].astype(int)
    rows = ends[np.isfinite(angles.theta_rad.to_numpy()[ends])]
    if not len(rows):
        return rows, ""
    said = [f"the {where} {k} frames ({int(np.sum(lost[part]))} without the tip{speed})" for where, k, part, speed in (
        ("first", found.head_rows, ends[:found.head_rows], _faster(found.head_speed_ratio)),
        ("last", found.tail_rows, ends[found.head_rows:], _faster(found.tail_speed_ratio))) if k]
    return rows, (f"{' and '.join(said)} do not move at the pace of the rest (captured at {ratio:.3g} times the "
                  "file's rate): a slow-motion video shared or exported from a phone's gallery plays its ends at "
                  f"normal speed and their frame times are not known; their {len(rows)} frames with a position are "
                  "left out (quality off-pace).  Track the original file, or give --start/--end inside the slowed "
                  "part")


def _faster(ratio: float) -> str:
    return f"; the tip moves {ratio:.2g} times as far per frame" if math.isfinite(ratio) and ratio > 1.5 else ""
