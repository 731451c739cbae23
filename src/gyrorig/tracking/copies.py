"""The tip's picture copied by the codec from another picture.

An inter-coding codec (H.264, HEVC) copies a block from a picture it has already coded when the block's change is
below what its quantizer keeps (a skipped block): a faint tip moving slowly then shows the same pixels in several
frames while it moves.  Such a frame's fit is the other frame's, off by the tip's motion between the two; which of
the frames alike holds the tip's own picture is unknown (a run of B pictures copies from a reference picture that
comes after it).  :class:`RecentPictures` keeps the last frames seen and tells whether the pixels around a tip's fit
are bit for bit those of one of them (a sensor's noise alone never repeats them); :func:`copy_groups` joins such
frames into groups, and :func:`path_extent_px` says how far the tip moved over a group's frames, from the tracked
frames around it: that motion is added to each copy's error.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from .appearance import decoded_pixels

__all__ = ["RepeatedFrames", "RecentPictures", "copy_groups", "path_extent_px", "copy_extents", "COPY_FRAMES",
           "COPY_MARGIN_PX", "PATH_FRAMES", "REPEAT_SAMPLE_STEP"]

#: how many frames back a copy is looked for (a codec's run of B pictures and the reference pictures around it)
COPY_FRAMES = 8
#: the pixels compared: the tip's disc and this much around it [px]
COPY_MARGIN_PX = 4
#: tracked frames on each side of a group of copies that the tip's path over the group is drawn through
PATH_FRAMES = 3


#: the frame's pixels compared first with the frame before's: every this many rows and columns (most frames differ
#: there; only those that do not are compared whole)
REPEAT_SAMPLE_STEP = (16, 7)


class RepeatedFrames:
    """Tells a decoded frame identical to the one before it (a repeated picture, as a rate conversion writes)."""

    def __init__(self) -> None:
        self._before: np.ndarray | None = None
        self._sample = b""

    def repeats(self, frame: np.ndarray) -> bool:
        """Whether ``frame`` (decoded) holds exactly the pixels of the frame seen before it; it becomes that frame.
        A sample of its pixels (:data:`REPEAT_SAMPLE_STEP`) is compared first and the whole frame where they agree;
        a frame sharing the one before's memory (a source reusing its buffer) by the sample alone."""
        rows, cols = REPEAT_SAMPLE_STEP
        sample, before = frame[::rows, ::cols].tobytes(), self._before
        same = (before is not None and sample == self._sample and before.shape == frame.shape
                and (np.may_share_memory(before, frame) or np.array_equal(before, frame)))
        self._before, self._sample = frame, sample
        return same


class RecentPictures:
    """The last :data:`COPY_FRAMES` frames seen, each with its angle table row (held, not copied: each decoded frame
    is an array of its own)."""

    def __init__(self) -> None:
        self._frames: deque[tuple[np.ndarray, int | None]] = deque(maxlen=COPY_FRAMES)

    def see(self, frame: np.ndarray, row: int | None, fit=None) -> set[int]:
        """Take the next frame (the tracker's image or the decoded frame: the decoded pixels are compared; its tip's
        fit in angle table row ``row``; None: no fit) and return the rows whose frames hold the same pixels within the
        tip's radius plus :data:`COPY_MARGIN_PX` of the fit's centre as this one, with this one's row; empty when none
        does.  A frame sharing this one's memory (a source reusing its buffer) is not compared."""
        same: set[int] = set()
        frame = decoded_pixels(frame)
        if fit is not None:
            half = int(math.ceil(fit.radius_px)) + COPY_MARGIN_PX
            xi, yi = int(round(fit.x_px)), int(round(fit.y_px))
            box = (slice(max(yi - half, 0), yi + half + 1), slice(max(xi - half, 0), xi + half + 1))
            here = frame[box]
            same = {r for seen, r in self._frames if r is not None and here.size and
                    not np.may_share_memory(seen, frame) and np.array_equal(seen[box], here)}
        self._frames.append((frame, row))
        return same | {row} if same else same


def copy_groups(found: list[set[int]]) -> list[list[int]]:
    """The rows of frames alike (each set one frame's :meth:`RecentPictures.see`), overlapping sets joined: one
    sorted list of rows per group."""
    merged: list[set[int]] = []
    for g in filter(None, found):
        joined = [m for m in merged if m & g]
        merged = [m for m in merged if not m & g] + [set(g).union(*joined)]
    return sorted(sorted(m) for m in merged)


def path_extent_px(frames: np.ndarray, xy_px: np.ndarray, group_frames: np.ndarray) -> np.ndarray | None:
    """How far the tip moved along x and y over a group of copies' frames [px] (2,): the range of a path through
    the :data:`PATH_FRAMES` nearest tracked frames on each side (``frames`` (n,) with their positions ``xy_px``
    (n, 2), the copies not among them) within :data:`COPY_FRAMES` of the group, quadratic in the frame number
    (straight with frames on one side only), taken at each frame from the group's first to its last.  None when
    fewer than three frames are there to draw it through: the motion is then unknown."""
    first, last = int(np.min(group_frames)), int(np.max(group_frames))
    before = np.flatnonzero((frames < first) & (frames >= first - COPY_FRAMES))[-PATH_FRAMES:]
    after = np.flatnonzero((frames > last) & (frames <= last + COPY_FRAMES))[:PATH_FRAMES]
    near = np.concatenate([before, after])
    if len(near) < 3:
        return None
    degree = 2 if len(before) and len(after) else 1
    f = frames[near].astype(float) - first
    span = np.arange(0, last - first + 1, dtype=float)
    path = np.array([np.polyval(np.polyfit(f, xy_px[near, axis], degree), span) for axis in range(2)])
    return np.ptp(path, axis=1)


def copy_extents(groups: list[list[int]], frames: np.ndarray, tip_px: dict) -> tuple[list[int], np.ndarray, list[int]]:
    """The tip's motion over each group of copies (:func:`copy_groups`; angle table rows, ``frames`` the rows' frame
    numbers, ``tip_px`` row -> the tip's position of the rows that have one): ``(rows, extents, unknown)``, the rows
    of the groups whose motion is known with their group's :func:`path_extent_px` (n, 2) [px], and the rows of the
    groups whose motion is unknown (too few tracked frames around them)."""
    alike = set().union(*groups) if groups else set()
    tracked = np.array(sorted(r for r in tip_px if r not in alike), int)
    xy = np.array([tip_px[r] for r in tracked], float).reshape(-1, 2)
    rows, extents, unknown = [], [], []
    for group in groups:
        group = [r for r in group if r in tip_px]
        if len(group) < 2:
            continue
        extent = path_extent_px(frames[tracked], xy, frames[group])
        if extent is None:
            unknown += group
        else:
            rows += group
            extents += [extent] * len(group)
    return rows, np.array(extents, float).reshape(-1, 2), unknown
