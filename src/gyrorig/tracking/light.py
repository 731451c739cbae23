"""The light at the tip's rows, followed from frame to frame; how the scene moved between two frames.

The tip's level is compared in the light of its frame: lamps rippling on the mains (an LED lamp's light, by up to
its whole level at twice the mains frequency; in bands across the picture under a rolling shutter) change it from
frame to frame.  :class:`RowLight` follows that light where the tip is: at the rows either side of it, each frame's
level over the frame before's, column by column, and the median of those changes (an object that comes into a few
columns, a hand beside the tip, is not the light).  :func:`scene_shift` registers two frames (a candidate for the
tip must move unlike the scene).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["RowLight", "scene_shift", "LIGHT_ROWS", "LIGHT_STEP", "LIGHT_LIT", "LIGHT_KEPT"]

#: the rows either side of the tip whose level is followed, and every this many-th column of them
LIGHT_ROWS = 24
LIGHT_STEP = 8
#: the rows either side of the tip kept for the next frame's comparison (the tip moves less than this between frames)
LIGHT_KEPT = 4 * LIGHT_ROWS
#: columns darker than this share of the rows' mean level do not count in the light's change (their ratio is noise)
LIGHT_LIT = 0.25


class RowLight:
    """The light at the tip's rows relative to the first frame's (:attr:`index`), from the changes between
    consecutive frames (:meth:`see`)."""

    def __init__(self) -> None:
        self.index = 1.0
        #: the last frame's every LIGHT_STEP-th column over the rows kept (LIGHT_KEPT either side of the tip, or all),
        #: and the first of those rows
        self._before: np.ndarray | None = None
        self._first = 0

    def see(self, frame: np.ndarray, row: float | None) -> None:
        """Take the next frame, the tip at about ``row`` [px] (None: not known; the index is then kept)."""
        h = frame.shape[0]
        y = None if row is None else min(max(int(round(row)), 0), h - 1)
        if self._before is not None and y is not None:
            top, end = max(y - LIGHT_ROWS, self._first), min(y + LIGHT_ROWS + 1, self._first + len(self._before))
            if end > top:
                before = self._before[top - self._first:end - self._first].mean(axis=0)
                after = np.asarray(frame[top:end, ::LIGHT_STEP], np.float32).mean(axis=0)
                lit = before > LIGHT_LIT * float(np.mean(before))
                if lit.any():
                    change = float(np.median(after[lit] / before[lit]))
                    if change > 0.0:
                        self.index *= change
        # the rows the next frame's tip can be compared at; a copy: a source may reuse its frame buffer
        self._first = 0 if y is None else max(y - LIGHT_KEPT, 0)
        end = h if y is None else min(y + LIGHT_KEPT + 1, h)
        self._before = np.array(frame[self._first:end, ::LIGHT_STEP], np.float32)


#: the scene is registered between frames at most this wide (downsampled), and its shift believed when the phase
#: correlation's peak holds at least this much of the response
REGISTER_WIDTH_PX = 480
REGISTER_MIN_RESPONSE = 0.08


def scene_shift(before: np.ndarray | None, after: np.ndarray) -> np.ndarray | None:
    """How the scene moved between two frames [px] (phase correlation of the frames downsampled to at most
    :data:`REGISTER_WIDTH_PX`, Hann-windowed), or None when there is no frame before or the scene has too little
    texture to say (a weak correlation peak, :data:`REGISTER_MIN_RESPONSE`)."""
    if before is None or before.shape != after.shape:
        return None
    f = max(1, int(math.ceil(after.shape[1] / REGISTER_WIDTH_PX)))
    a = cv2.resize(np.asarray(before, np.float32), None, fx=1 / f, fy=1 / f, interpolation=cv2.INTER_AREA)
    b = cv2.resize(np.asarray(after, np.float32), None, fx=1 / f, fy=1 / f, interpolation=cv2.INTER_AREA)
    window = cv2.createHanningWindow((a.shape[1], a.shape[0]), cv2.CV_32F)
    (dx, dy), response = cv2.phaseCorrelate(a, b, window)
    if not response >= REGISTER_MIN_RESPONSE:
        return None
    return np.array([dx * f, dy * f])
