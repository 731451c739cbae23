"""Whether the camera held still: a hand-held phone turns a little from frame to frame.

The tip's direction comes from its pixel through the camera's pose; a camera that turns by a fraction of a
degree moves every pixel by several (``f`` times the angle) and the tip's direction with them, in every frame, by
far more than its error bars: each such frame would be wrong and flagged ``ok``.  The protocol's lab-fixed markers
(fiducials) do not move, so their images show the camera's motion: every :data:`CHECK_EVERY` frames (every frame
once they have moved) each fiducial in view is fitted near where the pose puts it (plus the motion found so far)
and the frame's displacement is the mean of theirs (one far from the others' median left out), its error the
larger of their scatter about it and the displacements' scatter about their own smooth path.  A small turn of the
camera moves the whole picture alike (a rotation about the camera's centre maps the image by a homography that is
a shift to first order, whatever the depth), so where the displacements, averaged over :data:`SMOOTH_CHECKS`
neighbouring checks and counted once per frame, scatter about their median by more than :data:`MIN_STEADY_PX` and 4
of that average's errors, the camera moved (a hand's tremor, or a tripod knocked once): each tip pixel is taken back by its frame's
displacement (interpolated between checks) before its direction is found, and the displacement's error joins the
tip's (between checks, the interpolation's too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from .rays import angles_with_covariance
from .scatter import path_residuals
from .scene_spot import fit_round_spot

__all__ = ["CameraWatch", "CameraMotion", "steady_angle_rows", "CHECK_EVERY", "MIN_MOTION_PX", "MIN_STEADY_PX"]

#: the fiducials are fitted in every this many frames (until they move; five fits cost about as much as the tip's)
CHECK_EVERY = 8
#: once the fiducials have moved this far [px] from where they were first seen, they are fitted in every frame
MIN_MOTION_PX = 0.3
#: the camera is taken as held still when the picture's displacement, averaged over :data:`SMOOTH_CHECKS` checks, stays
#: within this RMS over the record [px] (or 4 of that average's errors): below the tip's own errors on a phone's
#: footage (0.1-0.3 px)
MIN_STEADY_PX = 0.1
#: checks averaged to tell whether the camera moved
SMOOTH_CHECKS = 9
#: a fiducial's fit counts when it lies within this many of its radii (and 3 px) of where it was expected
REACH_RADII = 1.5
#: ... and within this distance of the median of the others' displacements [px]
OUTLIER_PX = 1.0


@dataclass(frozen=True)
class CameraMotion:
    """The camera's motion over a record, from its fiducials: the ``frame`` numbers of the checks and the picture's
    displacement there from where the pose puts the fiducials, ``dx_px, dy_px``, its standard error per axis
    ``sd_px``; ``rms_px`` the displacements' RMS per axis about their median, every frame counted once (how much the
    camera moved), ``moved`` whether it moved (module docstring)."""

    frame: np.ndarray
    dx_px: np.ndarray
    dy_px: np.ndarray
    sd_px: float
    rms_px: float
    moved: bool
    #: the displacement's RMS change per frame between checks [px] (what a frame between checks may differ by)
    speed_px: float = 0.0

    def at(self, frame: float) -> tuple[float, float]:
        """The displacement in a frame [px] (its own check's; linear between checks, held beyond them)."""
        return float(np.interp(frame, self.frame, self.dx_px)), float(np.interp(frame, self.frame, self.dy_px))

    def sd_at(self, frame: float) -> float:
        """The displacement's error per axis in a frame [px]: ``sd_px`` where the frame was checked; between or
        beyond checks the interpolation's too, taken as half the RMS change per frame times the frames to the
        nearest check (the checks are sparse until the camera is seen to move)."""
        gap = float(np.min(np.abs(self.frame - frame)))
        return math.hypot(self.sd_px, 0.5 * self.speed_px * gap)


class CameraWatch:
    """Collects the fiducials' displacements while the record is tracked (module docstring)."""

    def __init__(self, camera: Camera, fiducials_px: list[tuple[float, float, float]]):
        margin = 10.0
        self.camera = camera
        self.spots = [(x, y, r) for x, y, r in fiducials_px
                      if margin + 3 * r < x < camera.width_px - margin - 3 * r
                      and margin + 3 * r < y < camera.height_px - margin - 3 * r]
        self.samples: list[tuple] = []  # (frame, dx, dy, each fiducial's displacement about theirs)
        self.last = (0.0, 0.0)
        self.every = CHECK_EVERY

    def observe(self, frame: np.ndarray, count: int, index: int) -> None:
        """Fit the fiducials in every :data:`CHECK_EVERY`-th frame (``count`` the frames seen before this one), and
        in every frame once they have moved by :data:`MIN_MOTION_PX` from where they were first seen (a shaking
        camera's displacement is then measured in each frame, not interpolated); ``index`` the frame's number."""
        if len(self.spots) < 2 or count % self.every:
            return
        moves = []
        for x, y, r in self.spots:
            x0, y0 = x + self.last[0], y + self.last[1]
            fit = fit_round_spot(frame, x0, y0, r, self.camera)
            if (fit is None or not 0.6 * r <= fit.radius_px <= 1.6 * r
                    or math.hypot(fit.x_px - x0, fit.y_px - y0) > max(3.0, REACH_RADII * r)):
                continue
            moves.append((fit.x_px - x, fit.y_px - y, 0.0))
        m = np.array(moves).reshape(-1, 3)
        if len(m):  # a fiducial far from the others' median (another spot taken for it) is left out
            m = m[np.hypot(m[:, 0] - np.median(m[:, 0]), m[:, 1] - np.median(m[:, 1])) <= OUTLIER_PX]
        if len(m) < 2:
            return
        dx, dy = float(np.mean(m[:, 0])), float(np.mean(m[:, 1]))
        self.samples.append((index, dx, dy, m[:, :2] - [dx, dy]))
        self.last = (dx, dy)
        if math.hypot(dx - self.samples[0][1], dy - self.samples[0][2]) > MIN_MOTION_PX:
            self.every = 1

    def motion(self) -> CameraMotion | None:
        """The record's :class:`CameraMotion` (None with fewer than 3 checks: the fiducials were not seen)."""
        if len(self.samples) < 3:
            return None
        samples = sorted(self.samples, key=lambda v: v[0])
        s = np.array([v[:3] for v in samples], float)
        # each check's displacement is the mean of its fiducials': its error from their scatter about it, pooled
        # over the record (their own fits' covariances leave out the scene under their edges)
        resid = np.concatenate([v[3] for v in samples])
        dof = sum(len(v[3]) - 1 for v in samples)
        var = float(np.sum(resid ** 2)) / (2 * dof) / float(np.mean([len(v[3]) for v in samples]))
        # ... and from the displacements' own scatter about their smooth path (a hand's tremor is smooth from frame
        # to frame): an error common to the fiducials (the codec's treatment of a moving picture) shows there
        idx, z = path_residuals(s[:, 0], s[:, 0].astype(int), s[:, 1:3], np.ones((len(s), 2)), np.ones(len(s), bool))
        sd = math.sqrt(max(var, float(np.mean(z ** 2)) if len(idx) >= 10 else 0.0))
        # how far the picture moved over the record, every frame counted once (_spread)
        grid = np.arange(s[0, 0], s[-1, 0] + 1.0)
        rms = _spread(grid, s[:, 0], s[:, 1], s[:, 2])
        # whether it moved, from the displacements averaged over SMOOTH_CHECKS neighbouring checks (a knock's step
        # holds over many checks; their noise averages down by the root of their number)
        n = min(SMOOTH_CHECKS, len(s))
        mean = np.ones(n) / n
        moved = _spread(grid, s[:, 0], *(np.convolve(np.pad(v, (n // 2, n - 1 - n // 2), mode="edge"), mean, "valid")
                                         for v in (s[:, 1], s[:, 2])))
        moved_beyond = max(MIN_STEADY_PX, 4.0 * sd / math.sqrt(n))
        steps = np.diff(s[:, 0])
        speed = math.sqrt(float(np.mean((np.diff(s[:, 1]) ** 2 + np.diff(s[:, 2]) ** 2) / (2 * steps ** 2))))
        return CameraMotion(s[:, 0], s[:, 1], s[:, 2], sd, rms, bool(moved > moved_beyond), speed)


def _spread(grid: np.ndarray, frames: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> float:
    """The RMS per axis about their medians of the displacements ``dx, dy`` checked in ``frames``, interpolated to
    every frame of ``grid``: each frame counted once (the checks are dense once the fiducials have moved and sparse
    before, so counting checks would weigh the record's part after a knock)."""
    gx, gy = np.interp(grid, frames, dx), np.interp(grid, frames, dy)
    return math.sqrt(float(np.mean((gx - np.median(gx)) ** 2 + (gy - np.median(gy)) ** 2)) / 2)


def steady_angle_rows(rows: list, tip_px: dict, tip_cov: dict, motion: CameraMotion, camera: Camera,
                      length_m: float) -> None:
    """Each tracked row's direction found again from its tip pixel taken back by the camera's displacement in its
    frame (``rows[r] = (frame, t, theta, phi, sd theta, sd phi, corr, tip x, y, z, quality)``, replaced in place; the
    pixel in ``tip_px`` taken back too, and the displacement's variance added to its covariance in ``tip_cov``: the
    record's checks then see the steadied path).  A pixel whose ray then misses the tip's sphere keeps its row but
    loses its angles (quality ``off-sphere``)."""
    for r in sorted(tip_px):
        row = rows[r]
        dx, dy = motion.at(row[0])
        cov = np.asarray(tip_cov[r], float) + motion.sd_at(row[0]) ** 2 * np.eye(2)
        geo = angles_with_covariance(tip_px[r][0] - dx, tip_px[r][1] - dy, cov, camera, length_m)
        if geo is None:
            rows[r] = (row[0], row[1], *([math.nan] * 8), "off-sphere")
            del tip_px[r], tip_cov[r]
            continue
        th, ph, n, c = geo
        sth, sph = math.sqrt(c[0, 0]), math.sqrt(c[1, 1])
        rows[r] = (row[0], row[1], th, ph, sth, sph, c[0, 1] / (sth * sph), n[0], n[1], n[2], row[10])
        tip_px[r], tip_cov[r] = (tip_px[r][0] - dx, tip_px[r][1] - dy), cov
