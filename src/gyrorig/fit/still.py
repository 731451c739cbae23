"""A record's still ends: the top held by hand before its release, or caught and held (or come to rest against a
stop) before the recording ends.  A phone records from before the release to after the catch; those frames are not
the scene's motion, and fitted with it they make every quantity wrong.

The tip is *still* while it stays within :func:`still_radius` of one place.  :func:`still_ends` measures how long the
record's first frames stay within it of where they start (the head), and its last frames of where they end (the
tail), and compares each with the longest the tip stays within the same radius of any one place in the rest of the
record (its *dwell*: at most the time it takes to cross the radius at the motion's slowest).  A head or tail
:data:`STILL_FACTOR` times longer than that is left out; a motion that only changes speed (a rotor spinning down) has
no such step, since the rest begins as slowly as the end it is compared with.  A tip that leaves the radius counts as
having left only when two frames in a row are outside it, so that one wrong frame does not end a hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["StillEnds", "still_ends", "still_radius", "STILL_FACTOR", "STILL_MIN_FRAMES", "STILL_RADIUS_SIGMAS",
           "STILL_RADIUS_EXTENT"]

#: a still end is left out when it lasts this many times the longest dwell in the rest of the record
STILL_FACTOR = 4.0
#: ... and holds at least this many frames
STILL_MIN_FRAMES = 5
#: the still radius: at least this many of the frames' median angular error (the noise alone does not carry a still
#: tip out of it) ...
STILL_RADIUS_SIGMAS = 5.0
#: ... and at least this fraction of the motion's extent (a hand's tremor, a fraction of a degree, stays within it)
STILL_RADIUS_EXTENT = 0.05
#: frames at each end whose median is the place a still end is measured from
_END_FRAMES = 5


@dataclass(frozen=True)
class StillEnds:
    """What :func:`still_ends` found: the frames kept, and the still ends left out."""

    #: (n,) the frames that are the scene's motion
    keep: np.ndarray
    #: how long the tip stayed still at the record's start and end, as the frames show it (0: not left out) [s]
    head_s: float
    tail_s: float
    #: frames left out at each end
    head_frames: int
    tail_frames: int
    #: the longest the tip stayed within the radius of one place in the rest of the record [s]
    dwell_s: float
    #: the still radius (angle on the unit sphere of tip directions) [rad]
    radius_rad: float

    @property
    def any(self) -> bool:
        return bool(self.head_frames or self.tail_frames)


def _unit(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    s = np.sin(theta)
    return np.column_stack([s * np.sin(phi), -s * np.cos(phi), np.cos(theta)])


def still_radius(u: np.ndarray, theta: np.ndarray, theta_sigma: np.ndarray, phi_sigma: np.ndarray) -> float:
    """The radius within which the tip counts as still: :data:`STILL_RADIUS_SIGMAS` of the frames' median angular
    error, or :data:`STILL_RADIUS_EXTENT` of the motion's extent (the 95th percentile of the tip's distance from its
    median direction), whichever is larger. [rad]"""
    error = np.sqrt(theta_sigma ** 2 + (np.sin(theta) * phi_sigma) ** 2)
    extent = float(np.percentile(np.linalg.norm(u - np.median(u, axis=0), axis=1), 95))
    return max(STILL_RADIUS_SIGMAS * float(np.median(error)), STILL_RADIUS_EXTENT * extent)


def _first_departure(d: np.ndarray, r: float) -> int:
    """The first index of two in a row with ``d > r`` (``len(d)``: none)."""
    out = d > r
    both = np.flatnonzero(out[:-1] & out[1:]) if len(d) > 1 else np.array([], int)
    return int(both[0]) if len(both) else len(d)


def _longest_dwell(u: np.ndarray, t: np.ndarray, lo: int, hi: int, r: float, enough_s: float) -> float:
    """The longest time any frame in ``[lo, hi)`` stays within ``r`` of its own place, going forward and counting
    only frames in ``[lo, hi)`` (to the last frame inside before two in a row outside); ``inf`` as soon as one
    reaches ``enough_s``. [s]"""
    idx = np.arange(lo, hi)
    last_in = idx.copy()  # the last frame seen inside each frame's ball
    out_before = np.zeros(len(idx), bool)  # the frame before the one looked at was outside
    longest = 0.0
    k = 1
    while len(idx):
        j = idx + k
        live = j < hi
        if not live.all():  # the record's rest ends: what these stayed is as far as it can be seen
            longest = max(longest, float(np.max(t[last_in[~live]] - t[idx[~live]])))
            idx, last_in, out_before, j = idx[live], last_in[live], out_before[live], j[live]
        outside = np.linalg.norm(u[j] - u[idx], axis=1) > r
        gone = outside & out_before
        if gone.any():
            longest = max(longest, float(np.max(t[last_in[gone]] - t[idx[gone]])))
        last_in = np.where(outside, last_in, j)
        stay = ~gone
        idx, last_in, out_before = idx[stay], last_in[stay], outside[stay]
        if len(idx) and float(np.max(t[last_in] - t[idx])) >= enough_s:
            return math.inf
        k += 1
    return longest


def still_ends(t_s: np.ndarray, theta_rad: np.ndarray, phi_rad: np.ndarray, theta_sigma_rad: np.ndarray,
               phi_sigma_rad: np.ndarray) -> StillEnds:
    """The record's still head and tail (module docstring); the arrays are the measured frames in time order."""
    n = len(t_s)
    u = _unit(theta_rad, phi_rad)
    r = still_radius(u, theta_rad, theta_sigma_rad, phi_sigma_rad)
    nothing = StillEnds(keep=np.ones(n, bool), head_s=0.0, tail_s=0.0, head_frames=0, tail_frames=0,
                        dwell_s=math.nan, radius_rad=r)
    if n < 4 * _END_FRAMES:
        return nothing
    start = np.median(u[:_END_FRAMES], axis=0)
    end = np.median(u[-_END_FRAMES:], axis=0)
    h = _first_departure(np.linalg.norm(u - start, axis=1), r)  # frames [0, h) still at the start
    e = n - _first_departure(np.linalg.norm(u[::-1] - end, axis=1), r)  # frames [e, n) still at the end
    if h >= e:
        return nothing
    head_s = float(t_s[h - 1] - t_s[0]) if h else 0.0
    tail_s = float(t_s[-1] - t_s[e]) if e < n else 0.0
    longest = max(head_s, tail_s)
    if longest <= 0:
        return nothing
    dwell = _longest_dwell(u, t_s, h, e, r, longest / STILL_FACTOR)
    head = h >= STILL_MIN_FRAMES and head_s >= STILL_FACTOR * dwell
    tail = n - e >= STILL_MIN_FRAMES and tail_s >= STILL_FACTOR * dwell
    if not (head or tail):
        return replace(nothing, dwell_s=dwell)
    keep = np.ones(n, bool)
    if head:
        keep[:h] = False
    if tail:
        keep[e:] = False
    return StillEnds(keep=keep, head_s=head_s if head else 0.0, tail_s=tail_s if tail else 0.0,
                     head_frames=h if head else 0, tail_frames=n - e if tail else 0, dwell_s=dwell, radius_rad=r)

