"""Following the tip back through the frames it was not taken in.

At a frame rate low for the motion (a heavy top's nod at 25-30 frames/s moves the tip by several of its radii
between frames) the tip is taken only where the nod turns and lost at the next step, until it has been seen to move
that fast (:class:`~gyrorig.tracking.follow.TipFollower`).  The frames before are not lost for good: each keeps the
spots of the tip's look found in it, and once the tip is followed at its speed it is followed back through them as
it is followed forward (a straight-line prediction from the two nearest places known, a gate that grows with the
frames since, the spot nearest the prediction that keeps the tip's look).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from .spot import SpotFit

__all__ = ["follow_back"]


def follow_back(lately: Sequence, start_px: tuple[float, float], gate_px: Callable[[int], float],
                keeps_look: Callable[[SpotFit], bool], max_misses: int) -> tuple[SpotFit | None, ...]:
    """The tip followed back from ``start_px`` (its place in the latest frame of ``lately``) through the frames before.

    ``lately``: one entry per frame, the latest last: where the tip was taken ``(x, y)`` [px], or the spots of its look
    found there (a list of fits; None: none kept).  ``gate_px(steps)``: how far from the prediction a spot may lie,
    ``steps`` frames from the nearest place known.  In each frame the tip was not taken in, the spot that
    ``keeps_look`` nearest the prediction within the gate; the walk ends after ``max_misses`` frames in a row without
    one.  Returns the fits by frame from the one before the latest back, the latest first (None where the tip was
    taken or no spot was in the gate; none after the last fit)."""
    known = [(0, np.asarray(start_px, float))]  # (frames back, place), the nearest last
    out: list[SpotFit | None] = []
    misses = 0
    for back in range(1, len(lately)):
        entry = lately[-1 - back]
        if isinstance(entry, tuple):
            known.append((back, np.asarray(entry, float)))
            out.append(None)
            misses = 0
            continue
        (j0, p0), (j1, p1) = known[-2] if len(known) > 1 else known[-1], known[-1]
        predicted = p1 + (p1 - p0) * (back - j1) / (j1 - j0) if j1 > j0 else p1
        near = [(math.hypot(f.x_px - predicted[0], f.y_px - predicted[1]), k, f) for k, f in enumerate(entry or ())]
        near = [n for n in near if n[0] <= gate_px(back - j1) and keeps_look(n[2])]
        if near:
            found = min(near)[2]
            known.append((back, np.array([found.x_px, found.y_px])))
            out.append(found)
            misses = 0
            continue
        out.append(None)
        misses += 1
        if misses > max_misses:
            break
    while out and out[-1] is None:
        out.pop()
    return tuple(out)
