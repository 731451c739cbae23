"""The light at the tip's rows, followed from frame to frame.

The tip's level is compared in the light of its frame: lamps rippling on the mains (an LED lamp's light, by up to
its whole level at twice the mains frequency; in bands across the picture under a rolling shutter) change it from
frame to frame.  :class:`RowLight` follows that light where the tip is: at the rows either side of it, each frame's
level over the frame before's, column by column, and the median of those changes (an object that comes into a few
columns, a hand beside the tip, is not the light).
"""

from __future__ import annotations

import numpy as np

__all__ = ["RowLight", "LIGHT_ROWS", "LIGHT_STEP", "LIGHT_LIT"]

#: the rows either side of the tip whose level is followed, and every this many-th column of them
LIGHT_ROWS = 24
LIGHT_STEP = 8
#: columns darker than this share of the rows' mean level do not count in the light's change (their ratio is noise)
LIGHT_LIT = 0.25


class RowLight:
    """The light at the tip's rows relative to the first frame's (:attr:`index`), from the changes between
    consecutive frames (:meth:`see`)."""

    def __init__(self) -> None:
        self.index = 1.0
        self._before: np.ndarray | None = None  # the last frame's every LIGHT_STEP-th column

    def see(self, frame: np.ndarray, row: float | None) -> None:
        """Take the next frame, the tip at about ``row`` [px] (None: not known; the index is then kept)."""
        now = np.array(frame[:, ::LIGHT_STEP], np.float32)  # a copy: a source may reuse its frame buffer
        if self._before is not None and row is not None:
            y = min(max(int(round(row)), 0), len(now) - 1)
            rows = slice(max(y - LIGHT_ROWS, 0), y + LIGHT_ROWS + 1)
            before, after = self._before[rows].mean(axis=0), now[rows].mean(axis=0)
            lit = before > LIGHT_LIT * float(np.mean(before))
            if lit.any():
                change = float(np.median(after[lit] / before[lit]))
                if change > 0.0:
                    self.index *= change
        self._before = now
