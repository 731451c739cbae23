"""The tip's picture copied by the codec from an earlier picture.

An inter-coding codec (H.264, HEVC) copies a block from a picture it has already coded when the block's change is
below what its quantizer keeps (a skipped block): a faint tip moving slowly, or standing still, then shows the same
pixels in several frames while it moves.  Such a frame is not a measurement of where the tip is: its fit is the
earlier frame's, off by the motion since.  :class:`RecentPictures` keeps the last frames seen and tells whether the
pixels around a tip's fit are bit for bit those of one of them (a sensor's noise alone never repeats them).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

__all__ = ["RecentPictures", "COPY_FRAMES", "COPY_MARGIN_PX"]

#: how many frames back a copy is looked for (a codec's run of B pictures and the reference pictures around it)
COPY_FRAMES = 8
#: the pixels compared: the tip's disc and this much around it [px]
COPY_MARGIN_PX = 4


class RecentPictures:
    """The last :data:`COPY_FRAMES` frames seen, each with its angle table row (held, not copied: each decoded frame
    is an array of its own)."""

    def __init__(self) -> None:
        self._frames: deque[tuple[np.ndarray, int | None]] = deque(maxlen=COPY_FRAMES)

    def see(self, frame: np.ndarray, row: int | None, fit=None) -> set[int]:
        """Take the next frame (its tip's fit in angle table row ``row``; None: no fit) and return the rows whose
        frames hold the same pixels within the tip's radius plus :data:`COPY_MARGIN_PX` of the fit's centre as
        this one, with this one's row; empty when none does.  All of them go: a run of B pictures copies its
        block from a reference picture that may come after it, so which one the pixels belong to is unknown.  A
        frame sharing this one's memory (a source reusing its buffer) is not compared."""
        same: set[int] = set()
        if fit is not None:
            half = int(math.ceil(fit.radius_px)) + COPY_MARGIN_PX
            xi, yi = int(round(fit.x_px)), int(round(fit.y_px))
            box = (slice(max(yi - half, 0), yi + half + 1), slice(max(xi - half, 0), xi + half + 1))
            here = frame[box]
            same = {r for seen, r in self._frames if r is not None and here.size and
                    not np.may_share_memory(seen, frame) and np.array_equal(seen[box], here)}
        self._frames.append((frame, row))
        return same | {row} if same else same
