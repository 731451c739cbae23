"""The light at the tip's rows, followed from frame to frame.

The tip's level is compared in the light of its frame: lamps rippling on the mains (an LED lamp's light, by up to
its whole level at twice the mains frequency; in bands across the picture under a rolling shutter) change it from
frame to frame.  :class:`RowLight` follows that light where the tip is: at the rows either side of it, each frame's
level over the frame before's, column by column, and the median of those changes (an object that comes into a few
columns, a hand beside the tip, is not the light).
"""

from __future__ import annotations

import numpy as np

__all__ = ["RowLight", "LIGHT_ROWS", "LIGHT_STEP", "LIGHT_LIT", "LIGHT_KEPT"]

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
