"""A record's still ends: the top held by hand before its release, or caught and held (or come to rest against a
stop) before the recording ends.  A phone records from before the release to after the catch; those frames are not
the scene's motion: fitted with it they make every quantity wrong (:mod:`gyrorig.fit.data` leaves them out), and a
tracker's error check that takes their scatter for the motion's makes the moving frames' errors too small
(:mod:`gyrorig.tracking.tracker` leaves them out of it), as does the pose's fit to the motion
(:mod:`gyrorig.tracking.motion_pose`).  The tip's places are points in any space: its directions (unit vectors:
distances are angles) or its image's pixels.

The tip is *still* while it stays within a radius of one place: two radii are tried (:func:`still_radii`), one of
the frames' noise (a top held in a clamp, or the few frames a tracker gives back from before the motion it acquired
the tip by) and one of a hand's tremor.  :func:`still_ends` measures, at each, how long the record's first frames stay
within it of where they start (the head), and its last frames of where they end (the tail), and compares each with the
longest the tip stays within the same radius of any one place in the rest of the record (its *dwell*: at most the
time it takes to cross the radius at the motion's slowest).  A head or tail :data:`STILL_FACTOR` times longer than that
is left out (the longer of the two radii's); a motion that only changes speed (a rotor spinning down) has no such step,
since the rest begins as slowly as the end it is compared with.  A tip that leaves the radius counts as having left
only when two frames in a row are outside it, so that one wrong frame does not end a hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geometry import tip_from_angles

__all__ = ["StillEnd", "StillEnds", "still_ends", "angle_still_ends", "still_radii", "STILL_FACTOR", "STILL_MIN_FRAMES",
           "STILL_RADIUS_SIGMAS", "STILL_RADIUS_EXTENT"]

#: a still end is left out when it lasts this many times the longest dwell in the rest of the record
STILL_FACTOR = 4.0
#: ... and holds at least this many frames
STILL_MIN_FRAMES = 5
#: the still radii: this many of the frames' median error (the noise alone does not carry a still tip out of it) ...
STILL_RADIUS_SIGMAS = 5.0
#: ... and this fraction of the motion's extent where larger (a hand's tremor, a fraction of a degree, stays within it)
STILL_RADIUS_EXTENT = 0.05
#: frames at each end whose median is the place a still end is measured from
_END_FRAMES = 5


@dataclass(frozen=True)
class StillEnd:
    """One still end of a record: how long it lasted and within what, against the rest of the record."""

    #: frames left out
    frames: int
    #: how long the tip stayed still, as the frames show it [s]
    duration_s: float
    #: the radius it stayed within, in the points' units (an angle [rad] for tip directions)
    radius: float
    #: the longest the tip stayed within that radius of one place in the rest of the record [s]
    dwell_s: float


@dataclass(frozen=True)
class StillEnds:
    """What :func:`still_ends` found: the frames kept, and the still ends left out (None: none)."""

    #: (n,) the frames that are the scene's motion
    keep: np.ndarray
    head: StillEnd | None = None
    tail: StillEnd | None = None

    @property
    def any(self) -> bool:
        return self.head is not None or self.tail is not None


def still_radii(points: np.ndarray, error: np.ndarray) -> tuple[float, ...]:
    """The radii within which the tip counts as still, in the points' units: :data:`STILL_RADIUS_SIGMAS` of the points'
    median error (``error``: each point's, the root of its covariance's trace; the noise alone does not carry a still
    tip out of it), and :data:`STILL_RADIUS_EXTENT` of the motion's extent (the 95th percentile of the points'
    distance from their median: a hand's tremor stays within it) where that is larger."""
    extent = float(np.percentile(np.linalg.norm(points - np.median(points, axis=0), axis=1), 95))
    noise = STILL_RADIUS_SIGMAS * float(np.median(error))
    return (noise, STILL_RADIUS_EXTENT * extent) if STILL_RADIUS_EXTENT * extent > noise else (noise,)


def _first_departure(d: np.ndarray, r: float) -> int:
    """The first index of two in a row with ``d > r`` (``len(d)``: none)."""
    out = d > r
    both = np.flatnonzero(out[:-1] & out[1:]) if len(d) > 1 else np.array([], int)
    return int(both[0]) if len(both) else len(d)


def _longest_dwell(p: np.ndarray, t: np.ndarray, lo: int, hi: int, r: float, enough_s: float) -> float:
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
        outside = np.linalg.norm(p[j] - p[idx], axis=1) > r
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


def _ends_within(p: np.ndarray, t: np.ndarray, r: float) -> tuple[StillEnd | None, StillEnd | None]:
    """The still head and tail within radius ``r`` (module docstring), each None unless left out."""
    n = len(t)
    start = np.median(p[:_END_FRAMES], axis=0)
    end = np.median(p[-_END_FRAMES:], axis=0)
    h = _first_departure(np.linalg.norm(p - start, axis=1), r)  # frames [0, h) still at the start
    e = n - _first_departure(np.linalg.norm(p[::-1] - end, axis=1), r)  # frames [e, n) still at the end
    if h >= e:
        return None, None
    head_s = float(t[h - 1] - t[0]) if h else 0.0
    tail_s = float(t[-1] - t[e]) if e < n else 0.0
    longest = max(head_s, tail_s)
    if longest <= 0:
        return None, None
    dwell = _longest_dwell(p, t, h, e, r, longest / STILL_FACTOR)
    head = StillEnd(h, head_s, r, dwell) if h >= STILL_MIN_FRAMES and head_s >= STILL_FACTOR * dwell else None
    tail = StillEnd(n - e, tail_s, r, dwell) if n - e >= STILL_MIN_FRAMES and tail_s >= STILL_FACTOR * dwell else None
    return head, tail


def still_ends(t_s: np.ndarray, points: np.ndarray, error: np.ndarray) -> StillEnds:
    """The record's still head and tail (module docstring): ``points`` (n, d) the tip's places in time order ``t_s``
    (n,), ``error`` (n,) each one's (:func:`still_radii`)."""
    n = len(t_s)
    keep = np.ones(n, bool)
    if n < 4 * _END_FRAMES:
        return StillEnds(keep)
    points = np.asarray(points, float)
    found = [_ends_within(points, t_s, r) for r in still_radii(points, np.asarray(error, float))]
    heads = [h for h, _ in found if h is not None]
    tails = [e for _, e in found if e is not None]
    head = max(heads, key=lambda end: end.frames) if heads else None
    tail = max(tails, key=lambda end: end.frames) if tails else None
    if head is not None:
        keep[:head.frames] = False
    if tail is not None:
        keep[n - tail.frames:] = False
    return StillEnds(keep, head, tail)


def angle_still_ends(t_s: np.ndarray, theta_rad: np.ndarray, phi_rad: np.ndarray, theta_sigma_rad: np.ndarray,
                     phi_sigma_rad: np.ndarray) -> StillEnds:
    """:func:`still_ends` of an angle table's frames: the tip's unit directions, each one's angular error."""
    error = np.hypot(theta_sigma_rad, np.sin(theta_rad) * phi_sigma_rad)
    return still_ends(t_s, tip_from_angles(theta_rad, phi_rad), error)
