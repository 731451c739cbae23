"""Whether the camera held still: a hand-held phone turns a little from frame to frame.

The tip's direction comes from its pixel through the camera's pose; a camera that turns by a fraction of a
degree moves every pixel by several (``f`` times the angle) and the tip's direction with them, in every frame, by
far more than its error bars: each such frame would be wrong and flagged ``ok``.  The protocol's lab-fixed markers
(fiducials) do not move, so their images show the camera's motion: every :data:`CHECK_EVERY` frames (every frame
once they have moved) each fiducial in view is fitted near where the pose puts it (plus the motion found so far), and
the picture's move is fitted to their displacements, each weighted by its fit's own error: a shift, and with three or
more fiducials a turn about the camera's axis and a scale (``d = t + (a I + b J) r``, ``r`` the place about the
fiducials' centre; with four or more each is checked against the others' fit and one they miss left out, as is a fit
much less sure than the fiducials' usual: a spot partly covered).  A small turn of the camera about a horizontal axis
moves the whole picture alike (a rotation about the camera's centre maps the image by a homography that is a shift to
first order, whatever the depth); a turn about its own axis rotates the picture, which moves the tip, far from the
fiducials' centre, unlike any one shift (a hand-held phone turns by a tenth of a degree or so every way).  Where the
displacements, averaged over :data:`SMOOTH_CHECKS` neighbouring checks and counted once per frame, scatter about their
median by more than :data:`MIN_STEADY_PX` and 4 of that average's errors, or as they are by more than their noise (a
tremor faster than the average, at a low frame rate: :func:`_beyond_noise`; the turn and scale counted as the
displacement they give at the fiducials' distance from their centre), the camera moved (a hand's tremor, or a tripod
knocked once): each tip pixel is taken back by its frame's displacement at that pixel (interpolated between checks)
before its direction is found, and the displacement's error joins the tip's (between checks, the interpolation's
too).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from .appearance import MarkerImage
from .rays import angles_with_covariance
from .scatter import path_residuals
from .scene_spot import fit_round_spot

__all__ = ["CameraWatch", "CameraMotion", "steady_angle_rows", "CHECK_EVERY", "MIN_MOTION_PX", "MIN_STEADY_PX",
           "MIN_TURN_FIDUCIALS"]

#: the fiducials are fitted in every this many frames (until they move; five fits cost about as much as the tip's)
CHECK_EVERY = 8
#: once the fiducials have moved this far [px] from where they were first seen, and by this many of the move's
#: errors (their fits' own, scaled by their scatter), they are fitted in every frame
MIN_MOTION_PX = 0.3
MOTION_SIGMAS = 4.0
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
    #: where the camera also turned about its axis (the picture rotating, ``roll_rad``) or moved along it (the picture
    #: scaled by ``1 + scale``) [per check], about ``centre_px``, the fiducials' centre (``dx_px, dy_px`` are the
    #: displacement there), whose RMS distance from it is ``lever_px``; None when the camera did not (module docstring)
    roll_rad: np.ndarray | None = None
    scale: np.ndarray | None = None
    centre_px: tuple[float, float] = (0.0, 0.0)
    lever_px: float = math.inf
    #: the turn's and scale's error per check, as the displacement they give at ``lever_px`` [px]
    turn_sd_px: float = 0.0

    @property
    def roll_rms_deg(self) -> float:
        """How far the camera turned about its axis: the turn's RMS about its median over the checks [deg] (0 when it
        was not seen to turn)."""
        return 0.0 if self.roll_rad is None else math.degrees(float(np.std(self.roll_rad - np.median(self.roll_rad))))

    def at(self, frame: float, x_px: float | None = None, y_px: float | None = None) -> tuple[float, float]:
        """The displacement in a frame [px] (its own check's; linear between checks, held beyond them), at the pixel
        ``(x_px, y_px)`` (where the picture also turned or scaled; else the same everywhere)."""
        dx, dy = float(np.interp(frame, self.frame, self.dx_px)), float(np.interp(frame, self.frame, self.dy_px))
        if self.roll_rad is None or x_px is None:
            return dx, dy
        a, b = float(np.interp(frame, self.frame, self.scale)), float(np.interp(frame, self.frame, self.roll_rad))
        rx, ry = x_px - self.centre_px[0], y_px - self.centre_px[1]
        return dx + a * rx - b * ry, dy + b * rx + a * ry

    def sd_at(self, frame: float, x_px: float | None = None, y_px: float | None = None) -> float:
        """The displacement's error per axis in a frame [px]: ``sd_px`` where the frame was checked; between or
        beyond checks the interpolation's too, taken as half the RMS change per frame times the frames to the
        nearest check (the checks are sparse until the camera is seen to move); where the picture turned, the turn's
        and scale's errors times the pixel's distance from the fiducials' centre over theirs."""
        gap = float(np.min(np.abs(self.frame - frame)))
        sd = math.hypot(self.sd_px, 0.5 * self.speed_px * gap)
        if self.roll_rad is None or x_px is None:
            return sd
        lever = math.hypot(x_px - self.centre_px[0], y_px - self.centre_px[1]) / self.lever_px
        return math.hypot(sd, self.turn_sd_px * lever)


class CameraWatch:
    """Collects the fiducials' displacements while the record is tracked (module docstring)."""

    def __init__(self, camera: Camera, fiducials_px: list[tuple[float, float, float]],
                 image: MarkerImage | None = None):
        """``image``: the image the fiducials are fitted in, when that is not the tip's
        (:func:`gyrorig.tracking.appearance.lab_marker_image`); None: the tip's image serves."""
        margin = 10.0
        self.camera = camera
        self.image = image
        #: whether the fiducials are fitted in their own image (None: not yet decided, at the first check)
        self.own_image: bool | None = None
        self.spots = [(x, y, r) for x, y, r in fiducials_px
                      if margin + 3 * r < x < camera.width_px - margin - 3 * r
                      and margin + 3 * r < y < camera.height_px - margin - 3 * r]
        xy = np.array([(x, y) for x, y, _ in self.spots]).reshape(-1, 2)
        self.centre = tuple(xy.mean(axis=0)) if len(xy) else (0.0, 0.0)
        self.lever = math.sqrt(float(np.mean(np.sum((xy - self.centre) ** 2, axis=1)))) if len(xy) else 0.0
        self.samples: list[tuple] = []  # (frame, dx, dy, scale, roll, residuals, weights, covariance): _similarity
        #: the samples' fiducials' weighted squared residuals about their checks' fits, and their degrees of freedom
        self._chi2, self._dof = 0.0, 0
        self.last = (0.0, 0.0)
        self.turn = (0.0, 0.0)
        #: how much the fitted turn changed from one check to the next (each component of ``(a, b)``, as a distance)
        self.turn_steps: deque[float] = deque(maxlen=FIT_MEMORY)
        self.turn_fitted = False
        #: how far each fiducial kept lately was from the others' fit [px], and each fit's own variance [px^2]
        self.misses: deque[float] = deque(maxlen=FIT_MEMORY)
        self.variances: deque[float] = deque(maxlen=FIT_MEMORY)
        self.every = CHECK_EVERY

    def _miss_limit(self) -> float:
        """How far a fiducial may be from the others' fit (:data:`TURN_OUTLIER_SIGMAS`): the misses' scale from their
        median (a miss in two dimensions with sd ``s`` per axis has the median ``1.1774 s``)."""
        if len(self.misses) < TURN_OUTLIER_SAMPLES:
            return TURN_OUTLIER_PX
        return max(TURN_OUTLIER_MIN_PX, TURN_OUTLIER_SIGMAS * float(np.median(self.misses)) / 1.1774)

    def _turn_sd(self) -> float | None:
        """The last fitted turn's error for the next check, per component of ``(a, b)``: the turn's change from one
        check to the next, from its median over the record so far (None before a turn was fitted twice)."""
        if not self.turn_steps:
            return None
        return float(np.median(self.turn_steps)) / 1.1774

    def _starts(self) -> list[tuple[float, float, float, float, float, float, float]]:
        """Where each fiducial is looked for: ``(x, y, r, rx, ry, x0, y0)``, its place in the pose ``x, y``, radius
        ``r``, place about the fiducials' centre ``rx, ry`` and where the last fit puts it ``x0, y0`` [px]."""
        out = []
        a, b = self.turn
        for x, y, r in self.spots:
            rx, ry = x - self.centre[0], y - self.centre[1]
            out.append((x, y, r, rx, ry, x + self.last[0] + a * rx - b * ry, y + self.last[1] + b * rx + a * ry))
        return out

    def _moves(self, frame: np.ndarray) -> np.ndarray:
        """Each fiducial found in ``frame`` near where it is expected: (rx, ry, dx, dy, variance) rows, ``rx, ry`` its
        place about the fiducials' centre, ``dx, dy`` its displacement, ``variance`` its fit's per axis."""
        moves = []
        for x, y, r, rx, ry, x0, y0 in self._starts():
            fit = fit_round_spot(frame, x0, y0, r, self.camera)
            if (fit is None or not 0.6 * r <= fit.radius_px <= 1.6 * r
                    or math.hypot(fit.x_px - x0, fit.y_px - y0) > max(3.0, REACH_RADII * r)):
                continue
            moves.append((rx, ry, fit.x_px - x, fit.y_px - y, max(float(np.trace(fit.cov_xy)) / 2, 1e-8)))
        return np.array(moves).reshape(-1, 5)

    def observe(self, frame: np.ndarray, count: int, index: int, decoded: np.ndarray | None = None) -> None:
        """Fit the fiducials in every :data:`CHECK_EVERY`-th frame (``count`` the frames seen before this one), and
        in every frame once they have moved by :data:`MIN_MOTION_PX` and :data:`MOTION_SIGMAS` of the move's errors
        from where they were first seen (a shaking camera's displacement is then measured in each frame, not
        interpolated); ``index`` the frame's number; ``frame`` the tip's image, ``decoded`` the frame as decoded (for
        the fiducials' own image)."""
        if len(self.spots) < 2 or count % self.every:
            return
        if self.image is not None and decoded is not None and self.own_image is not False:
            own = self.image.lazy(decoded)  # mapped where the fits look
            if self.own_image is None:  # the first check: their own image, unless the tip's shows them better
                self.own_image = _score(self._moves(own)) >= _score(self._moves(frame))
            frame = own if self.own_image else frame
        m = self._moves(frame)
        if len(self.variances) >= TURN_OUTLIER_SAMPLES:  # a fit far less sure than the fiducials' usual is not clean
            m = m[m[:, 4] <= MAX_SIGMA_RATIO ** 2 * float(np.median(self.variances))]
        self.variances.extend(m[:, 4].tolist())
        fitted = _similarity(m, self.turn, self._miss_limit(), self.misses, self._turn_sd())
        if fitted is None:
            return
        (dx, dy, a, b), resid, weights, cov = fitted
        self.samples.append((index, dx, dy, a, b, resid, weights, cov))
        self._chi2 += float(np.sum(weights[:, None] * resid ** 2))
        self._dof += max(2 * len(resid) - (2 if math.isnan(a) else 4), 0)
        self.last = (dx, dy)
        if math.isfinite(a):
            if self.turn_fitted:
                self.turn_steps.append(math.hypot(a - self.turn[0], b - self.turn[1]))
            self.turn, self.turn_fitted = (a, b), True
        first = self.samples[0]
        turned = self.lever * math.hypot(self.turn[0] - first[3], self.turn[1] - first[4])
        moved = math.hypot(dx - first[1], dy - first[2]) + (turned if math.isfinite(turned) else 0.0)
        if self.every > 1 and moved > max(MIN_MOTION_PX, MOTION_SIGMAS * self._move_sd(first[7], cov)):
            self.every = 1

    def _move_sd(self, before: np.ndarray, now: np.ndarray) -> float:
        """The error of the move :meth:`observe` measures between two checks whose fits' covariances of ``(tx, ty, a,
        b)`` are ``before`` and ``now``: the shift's per axis plus the turn's at the fiducials' distance (0 where a
        check fitted no turn), scaled by the fiducials' scatter about the checks' fits so far where it exceeds their
        fits' errors (:meth:`_scatter_scale`)."""
        both = before + now
        turn = self.lever * math.sqrt((both[2, 2] + both[3, 3]) / 2)
        sd = math.sqrt((both[0, 0] + both[1, 1]) / 2) + (turn if math.isfinite(turn) else 0.0)
        return sd * math.sqrt(max(self._scatter_scale(), 1.0))

    def _scatter_scale(self) -> float:
        """The fiducials' scatter about their checks' fits over what their fits' own errors say: the chi-square per
        degree of freedom pooled over the checks so far (1 without any)."""
        return self._chi2 / self._dof if self._dof > 0 else 1.0

    def motion(self) -> CameraMotion | None:
        """The record's :class:`CameraMotion` (None with fewer than 3 checks: the fiducials were not seen)."""
        if len(self.samples) < 3:
            return None
        samples = sorted(self.samples, key=lambda v: v[0])
        s = np.array([v[:5] for v in samples], float)
        # each check's displacement is fitted to its fiducials', weighted by their fits' own errors: its error from
        # those, scaled by the fiducials' scatter about the fits pooled over the record (their own fits' covariances
        # leave out the scene under their edges)
        scale = self._scatter_scale()
        var = scale * float(np.median([(v[7][0, 0] + v[7][1, 1]) / 2 for v in samples]))
        turn_var = [(v[7][2, 2] + v[7][3, 3]) / 2 for v in samples if math.isfinite(v[3])]
        turn_var = scale * self.lever ** 2 * float(np.median(turn_var)) if turn_var else var
        # ... and from the displacements' own scatter about their smooth path (a hand's tremor is smooth from frame
        # to frame): an error common to the fiducials (the codec's treatment of a moving picture) shows there
        idx, z = path_residuals(s[:, 0], s[:, 0].astype(int), s[:, 1:3], np.ones((len(s), 2)), np.ones(len(s), bool))
        sd = math.sqrt(max(var, float(np.mean(z ** 2)) if len(idx) >= 10 else 0.0))
        # how far the picture moved over the record, every frame counted once (_spread)
        grid = np.arange(s[0, 0], s[-1, 0] + 1.0)
        rms = _spread(grid, s[:, 0], s[:, 1], s[:, 2])
        n = min(SMOOTH_CHECKS, len(s))
        # a turn about the axis (or a scale), as the displacement it gives at the fiducials' distance from their centre
        # (checks with too few fiducials for it take their neighbours')
        fitted = np.isfinite(s[:, 3])
        turned = bool(np.sum(fitted) >= 3)
        if turned:
            for c in (3, 4):
                s[:, c] = np.interp(s[:, 0], s[fitted, 0], s[fitted, c])
            # its error from the fits' scatter as the shift's, or from its own scatter about its smooth path
            idx, z = path_residuals(s[:, 0], s[:, 0].astype(int), self.lever * s[:, 3:5], np.ones((len(s), 2)),
                                    np.ones(len(s), bool))
            turn_sd = math.sqrt(max(turn_var, float(np.mean(z ** 2)) if len(idx) >= 10 else 0.0))
            turned = _beyond_noise(grid, s[:, 0], self.lever * s[:, 3], self.lever * s[:, 4], sd, n,
                                   max(sd, turn_sd))
        moved = turned or _beyond_noise(grid, s[:, 0], s[:, 1], s[:, 2], sd, n)
        steps = np.diff(s[:, 0])
        speed = math.sqrt(float(np.mean((np.diff(s[:, 1]) ** 2 + np.diff(s[:, 2]) ** 2) / (2 * steps ** 2))))
        turn = dict(roll_rad=s[:, 4], scale=s[:, 3], centre_px=self.centre, lever_px=self.lever,
                    turn_sd_px=turn_sd) if turned else {}
        return CameraMotion(s[:, 0], s[:, 1], s[:, 2], sd, rms, bool(moved), speed, **turn)


#: the fewest fiducials in a check from which a turn about the camera's axis and a scale are fitted (with fewer, the
#: shift alone); with one more, each of them is checked against the others' fit
MIN_TURN_FIDUCIALS = 3
#: a fiducial whose displacement the others' turn and shift miss by more than :data:`TURN_OUTLIER_SIGMAS` times the
#: misses' scale (from their median over the record so far; at least :data:`TURN_OUTLIER_MIN_PX`, and
#: :data:`TURN_OUTLIER_PX` until :data:`TURN_OUTLIER_SAMPLES` misses are known) and by more than that many of its own
#: fit's errors is left out: a spot passing over it, or the rotor's can covering part of it, moves it by tenths of a
#: pixel, which a fit of four parameters to four or five fiducials would take in for the most part (a fiducial
#: partly covered whose fit says so weighs little anyway: the fits are weighted by their own errors)
TURN_OUTLIER_SIGMAS = 4.0
TURN_OUTLIER_MIN_PX = 0.02
TURN_OUTLIER_PX = 0.5
TURN_OUTLIER_SAMPLES = 20
#: a fiducial whose fit's own error exceeds this many times the median of the fiducials' fits so far is left out (a
#: spot partly covered, or with another spot on it: its fit says it is unsure, and a biased one drags the turn)
MAX_SIGMA_RATIO = 4.0
#: the fiducials' latest misses and fit variances kept for those scales
FIT_MEMORY = 500


def _similarity_fit(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(tx, ty, a, b)`` of ``d = t + (a I + b J) r`` by least squares weighted by the fiducials' own errors, and its
    covariance from those errors; ``m`` (k, 5): ``rx, ry, dx, dy`` and the fit's variance per axis."""
    r, w = m[:, :2], 1.0 / m[:, 4]
    ones, zeros = np.ones(len(r)), np.zeros(len(r))
    design = np.vstack([np.column_stack([ones, zeros, r[:, 0], -r[:, 1]]),
                        np.column_stack([zeros, ones, r[:, 1], r[:, 0]])])
    sw = np.sqrt(np.r_[w, w])
    x, *_ = np.linalg.lstsq(design * sw[:, None], np.r_[m[:, 2], m[:, 3]] * sw, rcond=None)
    return x, np.linalg.pinv((design * sw[:, None]).T @ (design * sw[:, None]))


def _moved_by(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The displacements ``(tx, ty, a, b)`` gives at the places ``r`` (k, 2)."""
    return x[:2] + np.column_stack([x[2] * r[:, 0] - x[3] * r[:, 1], x[3] * r[:, 0] + x[2] * r[:, 1]])


def _score(moves: np.ndarray) -> tuple[int, float]:
    """How well fiducials were found (:meth:`CameraWatch._moves`): more of them, then smaller errors."""
    return len(moves), -float(np.median(moves[:, 4])) if len(moves) else 0.0


def _left_out(m: np.ndarray, turn: tuple[float, float], turn_sd: float | None) -> tuple[np.ndarray, np.ndarray]:
    """For each fiducial of ``m`` (:func:`_similarity`): how far the others' fit misses it [px], and that miss in its
    standard errors (its own fit's and the others' fit's at its place: a deleted residual).  With only
    :data:`MIN_TURN_FIDUCIALS` others their turn is not fitted (three places leave two equations over, which a drift or
    an outlier among them fits as a false turn): their shift under the turn ``turn`` held from the last check, whose
    change since then (``turn_sd`` per component of ``(a, b)``) counts as the held turn's error; ``turn_sd`` None (no
    turn fitted yet: the pose's own may be off) fits the others' turn whatever their number."""
    miss, z = np.empty(len(m)), np.empty(len(m))
    for j in range(len(m)):
        others = np.delete(m, j, axis=0)
        rx, ry = m[j, :2]
        if len(others) > MIN_TURN_FIDUCIALS or turn_sd is None:
            x, cov = _similarity_fit(others)
            at = np.array([[1.0, 0.0, rx, -ry], [0.0, 1.0, ry, rx]])
            predicted = float(np.trace(at @ cov @ at.T)) / 2
        else:
            x = np.r_[_held_shift(others, turn)[0], turn]
            predicted = 1.0 / float(np.sum(1.0 / others[:, 4])) + (turn_sd * math.hypot(rx, ry)) ** 2
        miss[j] = math.hypot(*(m[j, 2:4] - _moved_by(x, m[[j], :2])[0]))
        z[j] = miss[j] / math.sqrt(m[j, 4] + predicted)
    return miss, z


def _held_shift(m: np.ndarray, turn: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The shift of the fiducials ``m`` under the turn ``(a, b)`` held, weighted by their fits' own errors: ``(t,
    residuals, weights)``."""
    d = m[:, 2:4] - _moved_by(np.r_[0.0, 0.0, turn], m[:, :2])
    w = 1.0 / m[:, 4]
    t = (w[:, None] * d).sum(axis=0) / w.sum()
    return t, d - t, w


def _similarity(m: np.ndarray, turn: tuple[float, float], limit_px: float, misses,
                turn_sd: float | None = None) -> tuple | None:
    """The picture's move from the fiducials' ``m`` (k, 5): each one's place about their centre, its displacement and
    its fit's variance per axis.  With :data:`MIN_TURN_FIDUCIALS` or more, a shift, scale and turn
    ``d = t + (a I + b J) r`` (:func:`_similarity_fit`); with more, each is checked against the others' fit
    (:func:`_left_out`) and, while one misses by more than ``limit_px`` and :data:`TURN_OUTLIER_SIGMAS` of the miss's
    errors, the one missed by most of them left out (the misses of those kept appended to ``misses``): an outlier
    among the others drags their fit, and the miss in the errors of both fits picks it rather than a good fiducial
    whose own fit is the surest.  With fewer, or as few after one was left out (once a turn was fitted: ``turn_sd``
    not None), the shift alone under the turn ``turn`` found before (``turn_sd`` its error since, per component), a and
    b returned NaN, a fiducial far from the others' median (:data:`OUTLIER_PX`) left out.  Returns ``((tx, ty, a, b),
    residuals (k', 2), weights (k',), covariance of (tx, ty, a, b))``; None with fewer than two fiducials."""
    left_out = False
    while len(m) > MIN_TURN_FIDUCIALS:
        miss, z = _left_out(m, turn, None)
        off = (miss > limit_px) & (z > TURN_OUTLIER_SIGMAS)
        if len(m) == MIN_TURN_FIDUCIALS + 1 and turn_sd is not None and off.any():
            # off against the others' own turn, and against their shift under the turn held: a fiducial one of them
            # drags their turn, or the camera's turn changed since, would be missed by one fit or the other
            miss_held, z = _left_out(m, turn, turn_sd)
            off &= (miss_held > limit_px) & (z > TURN_OUTLIER_SIGMAS)
        if not off.any():
            misses.extend(miss.tolist())
            break
        m = np.delete(m, int(np.argmax(np.where(off, z, -1.0))), axis=0)
        left_out = True
    if len(m) > MIN_TURN_FIDUCIALS or (len(m) == MIN_TURN_FIDUCIALS and not (left_out and turn_sd is not None)):
        x, cov = _similarity_fit(m)
        return x, m[:, 2:4] - _moved_by(x, m[:, :2]), 1.0 / m[:, 4], cov
    if len(m) < 2:
        return None
    d = m[:, 2:4] - _moved_by(np.r_[0.0, 0.0, turn], m[:, :2])  # the displacements under the turn held
    near = np.hypot(d[:, 0] - np.median(d[:, 0]), d[:, 1] - np.median(d[:, 1])) <= OUTLIER_PX
    m = m[near]
    if len(m) < 2:
        return None
    t, resid, w = _held_shift(m, turn)
    return np.r_[t, math.nan, math.nan], resid, w, np.diag([1.0 / w.sum()] * 2 + [math.nan] * 2)


def _beyond_noise(grid: np.ndarray, frames: np.ndarray, dx: np.ndarray, dy: np.ndarray, sd: float, n: int,
                  sd_each: float | None = None) -> bool:
    """Whether the displacements ``dx, dy`` checked in ``frames`` (each with the error ``sd`` per axis; ``sd_each``
    where one check's differs from what their average is taken to carry) move by more than :data:`MIN_STEADY_PX` and
    more than their noise: averaged over ``n`` neighbouring checks, by 4 of the average's errors (a knock's step, or a
    slow drift), or as they are, by 4 standard errors of their noise's RMS over the checks (``sd (1 + 4 / sqrt(2
    N))``: a tremor faster than ``n`` checks, which the average takes away, at a low frame rate)."""
    each = sd if sd_each is None else sd_each
    slow = _moved(grid, frames, dx, dy, n) > max(MIN_STEADY_PX, 4.0 * sd / math.sqrt(n))
    return slow or _moved(grid, frames, dx, dy, 1) > max(MIN_STEADY_PX, each * (1.0 + 4.0 / math.sqrt(2 * len(frames))))


def _moved(grid: np.ndarray, frames: np.ndarray, dx: np.ndarray, dy: np.ndarray, n: int) -> float:
    """How far the picture moved, from the displacements averaged over ``n`` neighbouring checks (a knock's step holds
    over many checks; their noise averages down by the root of their number): :func:`_spread` of the averages."""
    mean = np.ones(n) / n
    return _spread(grid, frames, *(np.convolve(np.pad(v, (n // 2, n - 1 - n // 2), mode="edge"), mean, "valid")
                                   for v in (dx, dy)))


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
        dx, dy = motion.at(row[0], *tip_px[r])
        cov = np.asarray(tip_cov[r], float) + motion.sd_at(row[0], *tip_px[r]) ** 2 * np.eye(2)
        geo = angles_with_covariance(tip_px[r][0] - dx, tip_px[r][1] - dy, cov, camera, length_m)
        if geo is None:
            rows[r] = (row[0], row[1], *([math.nan] * 8), "off-sphere")
            del tip_px[r], tip_cov[r]
            continue
        th, ph, n, c = geo
        sth, sph = math.sqrt(c[0, 0]), math.sqrt(c[1, 1])
        rows[r] = (row[0], row[1], th, ph, sth, sph, c[0, 1] / (sth * sph), n[0], n[1], n[2], row[10])
        tip_px[r], tip_cov[r] = (tip_px[r][0] - dx, tip_px[r][1] - dy), cov
