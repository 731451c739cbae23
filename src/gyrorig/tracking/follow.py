"""Following the tip from frame to frame, and refusing what is not the tip.

A spot is taken for the tip only when it looks like the tip at that instant and is where the tip can
be; otherwise the frame is ``missing`` (a wrong position flagged ``ok`` is worse than a gap):

- **shape and size**: a sphere's fitted radius against its image's (:data:`SIZE_RANGE`); a flat disc on the stem axis
  must make the ellipse that the camera and the axis at that position predict (semi-axes and orientation,
  :class:`~gyrorig.tracking.ellipse.DiscGeometry`); a blob of unknown appearance only a loose size range;
- **appearance**: once the tip has been followed for a few frames, its fitted radius, amplitude and reduced
  chi-square must stay near their running medians (a different marker, or a neighbour's light under it, changes them);
  its level is compared in the light at its rows or as seen (:meth:`TipFollower._as_bright`);
- **motion**: the spot must lie within a gate around the position predicted from the last frames
  (the gate grows with the tip's observed speed and acceleration in pixels; once the tip has been seen to move
  more than its radius in a frame, it holds any step up to the fastest speed seen twice, :data:`SPEED_MEMORY`); a
  spot farther and fainter (in peak contrast) than a nearer one the fit cannot describe (a streak, a tip partly
  hidden), which may be the tip, is not taken;
- **lab markers**: a spot where one of the protocol's lab-fixed markers appears, and nearer its size than the
  tip's, is never the tip;
- **acquisition**: with no history (the first frames, or after the tip was lost) a candidate is taken
  only when the next frame confirms it nearby and it has moved unlike the scene since the search began
  (of those, the nearest to the tip's expected size): dots on the spinning rotor jump by a large fraction
  of a turn between frames, a static spot of the wrong size fails the size test, and one of the right size
  (a highlight, a screw head) never moves.  The frames searched meanwhile get the tip's positions back once
  it is taken.  A sleeping top's tip, at the pole, need not move;
- **following back**: at a frame rate low for the motion the tip is taken only where it turns and lost at the next
  step until it has been seen to move fast; once it has, and has been followed for :data:`BACK_AFTER` frames, it is
  followed back through the frames it was not taken in, among the spots of its look kept from each, as it is
  followed forward.

A sphere's spot fitted jointly with a neighbour (``blended``) that fails these is fitted again with the neighbour's
light masked out (a whirling dot is a streak, not a disc); if that fails too, the frame is ``missing``.

Localisation follows the shape: the sphere model (:func:`~gyrorig.tracking.spot.fit_spot`) for
spheres; the elliptical model (:func:`~gyrorig.tracking.ellipse.fit_ellipse_spot`) for discs and
blobs.  A disc's position is then moved from its ellipse's centre to the image of its centre (the
perspective offset); a blob's is the ellipse's centre, and a disc whose normal is not the stem axis
is followed as a blob (its appearance depends on the spin angle).
"""

from __future__ import annotations

import heapq
import math
import statistics
from collections import deque
from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..markers import Marker
from ..camera import Camera
from .backward import follow_back
from .detect import Blob, Detection, find_blobs, stands_out
from .ellipse import DiscGeometry, fit_ellipse_spot
from .first_look import MAX_RECORDED, Candidate, FirstLook, Verdict
from .light import RowLight, scene_shift
from .rays import sphere_box, tip_from_pixel, tips_from_pixels
from .scene_spot import fit_round_spot
from .spot import SpotFit

__all__ = ["TipFollower", "Located", "SIZE_RANGE", "Verdict", "Candidate", "FirstLook"]

#: the fitted radius over the marker's expected image radius allowed for the tip (a sphere, or a blob)
SIZE_RANGE = {"sphere": (0.7, 1.4), "blob": (0.4, 2.5)}
#: once followed, the fitted radius and amplitude must stay within these factors of their running medians
RADIUS_CHANGE = (0.8, 1.25)
AMPLITUDE_CHANGE = (0.6, 1.6)
#: once followed, the fit's reduced chi-square may exceed its running median by at most this factor (foreign
#: light under the tip's own, which no mask can separate, makes the fit much worse than usual)
CHI2_CHANGE = 2.0
#: ... or its logarithm the running median of the logarithms by this many of their robust SDs, whichever is more
CHI2_SPREADS = 4.0
#: the smallest motion gate around the prediction [px]
MIN_GATE_PX = 3.0
#: the tip's speed [px/frame] is remembered over this many accepted steps; once it has moved more than its own
#: radius in a frame (a frame rate low for the motion: a heavy top's nod at 30 frames/s turns by 2 rad between
#: frames, so the last steps do not predict the next), the gate holds any step up to that speed (a constant-velocity
#: prediction is then off by up to twice the speed per frame) and a candidate confirms one of the last frame's
#: within that speed times :data:`FAST_REACH`
SPEED_MEMORY = 60
FAST_REACH = 1.5
#: the tip is fitted straight from its prediction only when no other spot lies within this many of its radii (plus
#: that spot's radius and the motion gate)
CLEAR_RADII = 3.0
#: a candidate confirms one of the last frame's when it lies within this many expected radii (+5 px) of it
ACQUIRE_REACH = 1.0
#: a scene with this many candidates of the tip's size or more is busy (a texture's spots, not the rig's few): the tip
#: is then the candidate that moved unlike the scene, by more than this between the two frames [px]
BUSY_CANDIDATES = 12
SCENE_MOTION_PX = 0.5
#: a reacquired tip lies within this many expected radii of where it was lost, plus this many times its speed for every
#: frame since: the :data:`REACQUIRE_QUANTILE` of its steps remembered (:data:`SPEED_MEMORY`), or its last steps'
#: median if more (a heavy top's tip stops at each cusp of its nod, where it is often lost)
REACQUIRE_RADII, REACQUIRE_SPEEDS, REACQUIRE_QUANTILE = 3.0, 2.0, 0.9
#: a spot whose centre is known worse than this fraction of the tip's expected radius is not a clean image of it
#: (a texture's blob, a tip partly hidden)
MAX_SIGMA_RADII = 0.25
#: when searching, the candidates of highest contrast considered, and how many of them (the nearest the tip's size)
#: are fitted: a faint tip on a pale road ranks 16th-21st by contrast among people walking past
ACQUIRE_CANDIDATES, ACQUIRE_FITS = 32, 12
#: frames the follower coasts on its prediction after a rejected frame before it searches anew
COAST_FRAMES = 3
#: a spot within this tilt of the vertical is a sleeping top's tip, taken without moving [rad]
SLEEPING_TILT_RAD = 0.05
#: while searching, a candidate's anchor (where it was first seen, :meth:`TipFollower._anchor_of`) is the nearest one
#: within this many expected radii, and is forgotten after this many frames searched
ANCHOR_REACH_RADII, ANCHOR_FRAMES = 4.0, 240
#: once the tip has been followed this many frames after an acquisition and seen to move fast (:data:`SPEED_MEMORY`),
#: it is followed back through the frames before in which it was not taken (:meth:`TipFollower._follow_back`): at a
#: frame rate low for the motion it is found only where it turns until a speed has been seen
BACK_AFTER = 10


@dataclass(frozen=True)
class Located:
    """The follower's verdict on one frame: the tip's fit (None: missing), its quality flag, and, when this frame
    completed an acquisition or the tip was followed back from it, the tip's fits in the frames before it (the latest
    first; None where the frame is left as it was), which were left missing while the tip could not yet be told."""

    fit: SpotFit | None
    quality: str
    earlier: tuple[SpotFit | None, ...] = ()


def _lab_images(camera: Camera, markers: tuple[Marker, ...]) -> list[tuple[float, float, float]]:
    """Where the lab-fixed markers appear: ``(x, y, radius)`` [px] of each one in front of the camera."""
    out = []
    for m in markers:
        p = np.asarray(m.position_m, float)
        depth = float((camera.rotation @ p + camera.tvec.ravel())[2])
        if depth <= 0:
            continue
        xy = cv2.projectPoints(p[None], camera.rvec, camera.tvec, camera.camera_matrix, camera.dist_coeffs)[0].ravel()
        out.append((float(xy[0]), float(xy[1]), camera.camera_matrix[0, 0] * m.radius_m / depth))
    return out


class TipFollower:
    """Finds the tip spot in each frame (see the module docstring)."""

    def __init__(self, camera: Camera, tip: Marker, lab_markers: tuple[Marker, ...] = ()):
        self.camera, self.tip = camera, tip
        #: images of the protocol's lab-fixed markers (x, y, radius) [px]: a spot there is never the tip
        self.lab_px = _lab_images(camera, lab_markers)
        #: how far the picture has moved from where the pose puts it (a hand-held camera; :mod:`.steady`) [px]
        self.shift_px = (0.0, 0.0)
        self.length_m = tip.position_m[2]
        axial = tip.shape == "disc" and abs(abs(tip.normal[2]) - 1.0) < 1e-9
        #: the disc model, for a disc facing along the stem; None: a sphere, or followed as a blob
        self.disc = DiscGeometry(camera, self.length_m, tip.radius_m) if axial else None
        self.shape = "blob" if tip.shape == "disc" and not axial else tip.shape
        depth = float(np.linalg.norm(camera.centre_m - np.array([0, 0, self.length_m])))
        self.r_expected = camera.camera_matrix[0, 0] * tip.radius_m / depth  # tip upright [px]
        self.last: deque[tuple[float, float]] = deque(maxlen=4)  # accepted positions, latest last
        #: the tip's speed over each step between frames it was followed in [px/frame]
        self.speeds: deque[float] = deque(maxlen=SPEED_MEMORY)
        #: the speed the last two reacquisitions implied (from where the tip was lost, over the frames between)
        #: [px/frame], and the steps followed since the last
        self.gap_speeds: deque[float] = deque(maxlen=2)
        self.steps_since_gap = 0
        self.last_r = self.r_expected
        self.radii: deque[float] = deque(maxlen=15)
        self.amplitudes: deque[float] = deque(maxlen=15)  # the tip's levels in the first frame's light
        self.raw_levels: deque[float] = deque(maxlen=15)  # ... and as they were seen
        self.chi2s: deque[float] = deque(maxlen=15)
        self.misses = 0
        self.pending: list[SpotFit] = []  # the last frame's candidates, when searching
        self.pending_frame: np.ndarray | None = None  # ... and that frame
        #: while searching, where each candidate was first seen (its fit, that frame, the search count then): a
        #: candidate is taken once it has moved unlike the scene since then
        self.anchors: list[tuple[SpotFit, np.ndarray, int]] = []
        self.history: list[list[SpotFit]] = []  # each searched frame's candidates, the latest last
        self.earlier: tuple[SpotFit, ...] = ()  # the acquired tip's fits in the frames searched before
        #: each frame seen lately, the latest last: where the tip was (x, y) [px] if it was taken there, else the spots
        #: of its look found in the frame (a list of fits), through which a tip seen to move fast is followed back
        #: (:meth:`_follow_back`)
        self.lately: deque = deque(maxlen=ANCHOR_FRAMES)
        self.followed = 0  # frames followed since the tip was last acquired
        self.confirmed: SpotFit | None = None  # the candidate of the last frame that this frame confirmed
        self.had_lock = False
        #: the first frame searched: every spot that stood out and what became of it
        self.first_look: FirstLook | None = None
        self.lost_at: tuple[float, float, float] | None = None  # where the tip was lost (x, y), its speed [px/frame]
        self.since_lost = 0  # frames since
        self.searched = 0  # frames searched so far
        self.light = RowLight()  # the light at the tip's rows relative to the first frame's
        #: the part of the image where the tip's sphere appears (a search anywhere looks only there; None: nowhere)
        self.sphere_px = sphere_box(camera, self.length_m)

    # ------------------------------------------------------------------------------- checks
    def _appearance_ok(self, fit: SpotFit) -> bool:
        if len(self.radii) < 3:
            return True
        r0 = statistics.median(self.radii)  # 15 numbers: no array needed
        # a disc's size changes with its view (its shape gate follows that); a sphere's and a blob's do not
        radius_ok = self.disc is not None or RADIUS_CHANGE[0] * r0 <= fit.radius_px <= RADIUS_CHANGE[1] * r0
        # the limit follows the chi-square's own scatter so far (on a log scale): steady on a flat background,
        # wider where the fit's quality varies from frame to frame
        logs = [math.log(max(c, 1e-12)) for c in self.chi2s]
        med = statistics.median(logs)
        spread = 1.4826 * statistics.median([abs(v - med) for v in logs])
        limit = max(CHI2_CHANGE * max(math.exp(med), 1.0), math.exp(med + CHI2_SPREADS * spread))
        # a recording's sphere is fitted in front of the scene (gyrorig.tracking.scene_spot), whose residuals
        # follow the codec's quality from frame to frame; another spot's light is left out there by its sectors
        chi2_ok = fit.chi2_own <= limit or (self.shape == "sphere" and not self.camera.sensor_known)
        return radius_ok and chi2_ok and self._as_bright(fit)

    def _nearer_size(self, radius_px: float, other_px: float) -> bool:
        """Whether a spot of ``radius_px`` is nearer (in ratio) to ``other_px`` than to the tip's expected radius."""
        return abs(math.log(radius_px / other_px)) < abs(math.log(radius_px / self.r_expected))

    def _level(self, fit: SpotFit) -> float:
        """How bright the tip is: its amplitude above a flat background; in a recording (the sphere fitted in
        front of the scene) its own level, which does not change with what passes behind it; in the light of the
        first frame (:meth:`_see_light`)."""
        if self.shape == "sphere" and not self.camera.sensor_known:
            return (fit.amplitude_adu + fit.background_adu) / self.light.index
        return fit.amplitude_adu / self.light.index

    def _as_bright(self, fit: SpotFit) -> bool:
        """The fit's level (:meth:`_level`) within :data:`AMPLITUDE_CHANGE` of the tip's running median, in the light
        the rows say or as seen (the rows' light changes with the scene behind them too: a fade, a person passing);
        True without one."""
        return self._brightness(fit) != (False, False)

    def _brightness(self, fit: SpotFit) -> tuple[bool, bool]:
        """Whether the fit is as bright as the tip in the rows' light and as seen (:meth:`_as_bright`)."""
        if len(self.amplitudes) < 3:
            return True, True
        lo, hi = AMPLITUDE_CHANGE
        level, a0 = self._level(fit), statistics.median(self.amplitudes)
        seen, s0 = level * self.light.index, statistics.median(self.raw_levels)
        return lo * a0 <= level <= hi * a0, lo * s0 <= seen <= hi * s0

    def _see_light(self, frame: np.ndarray) -> None:
        """Follow the light at the tip's rows (:class:`~gyrorig.tracking.light.RowLight`).  A bright marker's only (a
        colour's or a dark marker's image is not light)."""
        if self.tip.colour == "any" and self.tip.polarity == "bright":
            at = self.last[-1] if self.last else self.lost_at
            self.light.see(frame, None if at is None else at[1])

    def _looks_like_tip(self, fit: SpotFit) -> bool:
        """The shape and size test for a fit whose position is already the tip's (see the module docstring); not one
        where a lab marker appears, nearer its size (the rougher radius of its blob may have let it through)."""
        if not math.sqrt(max(float(np.max(np.linalg.eigvalsh(fit.cov_xy))), 0.0)) <= MAX_SIGMA_RADII * self.r_expected:
            return False
        if self._on_lab_marker(fit.x_px, fit.y_px, fit.radius_px):
            return False
        if self.disc is None:
            lo, hi = SIZE_RANGE[self.shape]
            return bool(math.isfinite(fit.radius_px) and lo * self.r_expected <= fit.radius_px <= hi * self.r_expected)
        img = self.disc.at_centre(fit.x_px, fit.y_px)
        return img is not None and self.disc.looks_right(fit, img)

    def _fit(self, frame: np.ndarray, x0: float, y0: float, r0: float, neighbour: str = "joint") -> SpotFit | None:
        """The shape's spot fit at a start point; for a disc, moved to its centre's image."""
        if self.shape == "sphere":
            return fit_round_spot(frame, x0, y0, r0, self.camera, neighbour=neighbour)
        fit = fit_ellipse_spot(frame, x0, y0, max(r0, 0.5 * self.r_expected), self.camera)
        if fit is None or self.disc is None:
            return fit
        centre = self.disc.centre_px(fit)
        return None if centre is None else replace(fit, x_px=centre[0], y_px=centre[1])

    def _prediction(self) -> tuple[np.ndarray, float]:
        """The predicted position (constant velocity, coasting over missed frames) and the motion gate [px]: at least
        the tip's radius per frame while no acceleration has been seen (a top released from rest gathers speed)."""
        p = np.array(self.last)
        v = p[-1] - p[-2] if len(p) >= 2 else np.zeros(2)
        acc = max((float(np.linalg.norm(p[k + 1] - 2 * p[k] + p[k - 1])) for k in range(1, len(p) - 1)), default=0.0)
        steps = 1 + self.misses
        gate = MIN_GATE_PX + 0.5 * float(np.linalg.norm(v)) * steps + 2.0 * acc * steps * steps
        if len(p) < 3:  # no acceleration seen yet
            gate = max(gate, MIN_GATE_PX + self.r_expected * steps)
        fast = self._fast_speed()
        return p[-1] + v * steps, max(gate, MIN_GATE_PX + 2.0 * fast * steps)

    def _fast_speed(self) -> float:
        """The tip's second largest remembered speed [px/frame] (one step to a wrong spot is not a speed) when it
        exceeds the tip's radius per frame (see :data:`SPEED_MEMORY`), else 0; a speed two reacquisitions in a row
        implied counts too (a tip too fast to be followed between frames is found again only where it turns)."""
        gap = min(self.gap_speeds) if len(self.gap_speeds) == 2 and self.steps_since_gap < SPEED_MEMORY else 0.0
        fast = max(heapq.nlargest(2, self.speeds)[-1] if len(self.speeds) > 1 else 0.0, gap)
        return fast if fast > self.r_expected else 0.0

    def _acceptable(self, fit: SpotFit | None, predicted: np.ndarray | None, gate: float, threshold: Detection) -> bool:
        if fit is None or not (stands_out(fit, threshold) and self._looks_like_tip(fit) and self._appearance_ok(fit)):
            return False
        return predicted is None or math.hypot(fit.x_px - predicted[0], fit.y_px - predicted[1]) <= gate

    def _clear(self, at: np.ndarray, gate: float, others) -> bool:
        """Whether no other spot (``others`` and the lab markers, each ``(x, y, r)`` [px]) lies within
        :data:`CLEAR_RADII` of the tip's radii, plus its own radius and ``gate``, of ``at``; False when ``others``
        is None (not known)."""
        if others is None:
            return False
        reach = CLEAR_RADII * self.last_r + gate
        return all(math.hypot(x - at[0], y - at[1]) > reach + r for x, y, r in (*others, *self._lab_now()))

    # ------------------------------------------------------------------------------- search
    def _candidates(self, frame: np.ndarray, threshold, centre=None, reach: int = 0,
                    refused: list | None = None) -> list[Blob]:
        """Blobs of a plausible size for the tip (brightest first), off the lab markers, whose ray meets the
        tip's sphere; with ``refused``, the others are appended to it as :class:`Candidate` with the reason."""
        h, w = frame.shape
        # a tilted disc's inscribed circle is its minor semi-axis: accept down to a steep view of it
        lo = (0.2 if self.tip.shape != "sphere" else 0.5) * self.r_expected
        smallest = 0.0 if refused is not None else max(lo - 1.0, 0.0)  # a first look records the small ones too
        widest = 1.6 * self.r_expected
        if centre is not None:
            x0, y0, x1, y1 = (max(int(centre[0]) - reach, 0), max(int(centre[1]) - reach, 0),
                              min(int(centre[0]) + reach, w), min(int(centre[1]) + reach, h))
        elif refused is None and self.sphere_px is not None:  # a blob centred off the sphere's image is refused
            m = int(widest) + 2
            sx0, sy0, sx1, sy1 = self.sphere_px
            x0, y0, x1, y1 = max(sx0 - m, 0), max(sy0 - m, 0), min(sx1 + m, w), min(sy1 + m, h)
        else:  # a first look shows every spot that stood out
            x0, y0, x1, y1 = 0, 0, w, h
        blobs = find_blobs(frame, x0, y0, x1, y1, threshold, min_radius_px=smallest, max_radius_px=widest)
        out = []
        meets = np.isfinite(tips_from_pixels(np.array([(c.x, c.y) for c in blobs]).reshape(-1, 2), self.camera,
                                             self.length_m)[:, 0])
        for c, on_sphere in zip(blobs, meets):
            why = Verdict.SIZE if not lo <= c.r <= widest else self._verdict(c.x, c.y, c.r, on_sphere)
            if why is None:
                out.append(c)
            elif refused is not None and len(refused) < MAX_RECORDED:
                refused.append(Candidate(c.x, c.y, c.r, why))
        return out

    def _lab_now(self) -> list[tuple[float, float, float]]:
        """Where the lab markers appear in this frame: the pose's places moved with the picture (:attr:`shift_px`)."""
        sx, sy = self.shift_px
        return [(x + sx, y + sy, r) for x, y, r in self.lab_px]

    def _on_lab_marker(self, x: float, y: float, r: float) -> bool:
        """Whether a spot at ``(x, y)`` of radius ``r`` [px] sits where a lab marker appears and is nearer its size."""
        return any(math.hypot(x - lx, y - ly) <= lr + 2 and self._nearer_size(r, lr) for lx, ly, lr in self._lab_now())

    def _verdict(self, x: float, y: float, r: float, on_sphere: bool | None = None) -> Verdict | None:
        """Why a spot at ``(x, y)`` of radius ``r`` [px] cannot be the tip whatever its size: where a lab marker
        appears and nearer its size (the tip may pass in front of one, visible or not), or off the tip's sphere
        (``on_sphere``: whether its ray meets the sphere, if already known); None when it can be."""
        if self._on_lab_marker(x, y, r):
            return Verdict.LAB_MARKER
        if on_sphere is None:
            on_sphere = tip_from_pixel(x, y, self.camera, self.length_m) is not None
        if not on_sphere:
            return Verdict.OFF_SPHERE
        return None

    def _track(self, frame: np.ndarray, threshold: Detection, others: tuple | None = ()) -> SpotFit | None:
        """The tip near its prediction, or None.

        Followed without a miss and clear of every other spot (``others``, the frame dots' last fits, and the lab
        markers: none within :data:`CLEAR_RADII` tip radii plus its own radius and the motion gate), the fit starts
        at the prediction and is taken when it stays there and passes the tip's tests; otherwise, and always
        beside another spot (whose light a fit from the prediction can take into the disc), the candidates near
        the prediction are searched, nearest first (one farther and fainter than a spot not fitted is not taken)."""
        predicted, gate = self._prediction()
        if self.misses == 0 and len(self.last) >= 2 and self._clear(predicted, gate, others):
            fit = self._fit(frame, float(predicted[0]), float(predicted[1]), self.last_r)
            if (fit is not None and not fit.blended
                    and math.hypot(fit.x_px - predicted[0], fit.y_px - predicted[1]) < max(2.0, 0.3 * fit.radius_px)
                    and tip_from_pixel(fit.x_px, fit.y_px, self.camera, self.length_m) is not None
                    and self._acceptable(fit, predicted, gate, threshold)):  # (the lab markers: _looks_like_tip)
                return fit
        cand = self._candidates(frame, threshold, predicted, int(2 * self.r_expected + 10 + gate))
        cand.sort(key=lambda c: (c[0] - predicted[0]) ** 2 + (c[1] - predicted[1]) ** 2)
        unfitted = -math.inf  # the highest peak contrast of a nearer spot that could not be fitted
        for x0, y0, r0, peak in cand[:3]:
            if math.hypot(x0 - predicted[0], y0 - predicted[1]) < max(2.0, 0.3 * r0):
                # the motion prediction is sub-pixel; the blob's inscribed centre is not: fewer iterations
                x0, y0, r0 = float(predicted[0]), float(predicted[1]), self.last_r
            fit = self._fit(frame, x0, y0, r0)
            if fit is None:
                unfitted = max(unfitted, peak)
            elif self._acceptable(fit, predicted, gate, threshold):
                return fit if peak > unfitted else None
            elif fit.blended and self.shape == "sphere" and self.camera.sensor_known:
                fit = self._fit(frame, x0, y0, r0, neighbour="mask")
                if self._acceptable(fit, predicted, gate, threshold):
                    return fit if peak > unfitted else None
        return None

    def _acquire(self, frame: np.ndarray, threshold: Detection) -> SpotFit | None:
        """The spots of the tip's look anywhere (:meth:`_look`); the one nearest to a candidate of the previous frame
        (within :data:`ACQUIRE_REACH`, of similar amplitude, moved unlike the scene), or None (this frame's
        candidates then wait for the next)."""
        record = [] if self.first_look is None else None  # the first search is kept, to show why it failed
        fits, busy = self._look(frame, threshold, record)
        self.lately.append(fits)
        return self._acquire_among(frame, threshold, fits, busy, record)

    def _look(self, frame: np.ndarray, threshold: Detection, record: list | None = None
              ) -> tuple[list[SpotFit], bool]:
        """The spots of the tip's look anywhere in the frame: the highest-contrast candidates of a plausible size (a
        textured background offers many), the ones nearest the tip's expected size fitted first; and whether the
        scene is busy (:data:`BUSY_CANDIDATES`).  ``record``: the candidates' fates are appended to it."""
        everything = self._candidates(frame, threshold, refused=record)
        busy = len(everything) >= BUSY_CANDIDATES
        cand = sorted(everything[:ACQUIRE_CANDIDATES], key=lambda c: abs(c.r - self.r_expected))
        fits = []
        for k, (x0, y0, r0, _) in enumerate(cand):
            if k >= ACQUIRE_FITS:
                if record is not None and len(record) < MAX_RECORDED:
                    record.append(Candidate(x0, y0, r0, Verdict.NOT_FITTED))
                continue
            fit = self._fit(frame, x0, y0, r0)
            if (fit is not None and fit.blended and self.shape == "sphere" and self.camera.sensor_known
                    and not self._looks_like_tip(fit)):
                fit = self._fit(frame, x0, y0, r0, neighbour="mask")
            # a reacquired tip is as bright as before it was lost (its image's size may have changed meanwhile)
            if fit is not None and stands_out(fit, threshold) and self._looks_like_tip(fit) and (
                    not self.had_lock or self._as_bright(fit)):
                fits.append(fit)
                if record is not None:
                    record.append(Candidate(fit.x_px, fit.y_px, fit.radius_px, Verdict.UNCONFIRMED))
            elif record is not None:
                why = Verdict.NO_FIT if fit is None else Verdict.NOT_ALIKE if self.had_lock else Verdict.SHAPE
                record.append(Candidate(x0, y0, r0, why))
        return fits, busy

    def _acquire_among(self, frame: np.ndarray, threshold: Detection, fits: list[SpotFit], busy: bool,
                       record: list | None) -> SpotFit | None:
        """:meth:`_acquire` among this frame's ``fits``."""
        reach = max(ACQUIRE_REACH * self.r_expected + 5.0, FAST_REACH * self._fast_speed())
        pairs = [(abs(math.log(f.radius_px / self.r_expected)), math.hypot(f.x_px - g.x_px, f.y_px - g.y_px), k, f, g)
                 for k, (f, g) in enumerate((f, g) for f in fits for g in self.pending)
                 if AMPLITUDE_CHANGE[0] <= self._level(f) / self._level(g) <= AMPLITUDE_CHANGE[1]]
        pairs = [p for p in pairs if p[1] <= reach]
        near = pairs
        if pairs:
            pairs = self._unlike_the_scene(pairs, scene_shift(self.pending_frame, frame), busy)
        if pairs:  # a top's tip moves: a spot of the scene (a highlight, a screw head) of its size does not
            pairs = self._moved_since_anchor(pairs, frame, fits)
        best = min(pairs, key=lambda p: p[:3]) if pairs else None  # the confirmed one nearest the tip's size
        if self.first_look is not None and not self.first_look.settled:
            self.first_look.settle(self.pending, near, [best] if best else [])
        if record is not None:
            self.first_look = FirstLook(np.array(frame, copy=True), threshold, record, self.r_expected)
        if best is not None:
            _, _, _, fit, self.confirmed = best
            self.earlier = self._trace_back(self.confirmed)
            self.anchors, self.history = [], []
            return fit
        self.pending, self.pending_frame = fits, frame
        self.anchors = [a for a in self.anchors if self.searched - a[2] <= ANCHOR_FRAMES]
        for f in fits:
            if self._anchor_of(f, fits) is None:
                self.anchors.append((f, frame, self.searched))
        self.history = [*self.history[-ANCHOR_FRAMES:], fits]
        return None

    def _anchor_of(self, fit: SpotFit, fits: list[SpotFit]) -> tuple[SpotFit, np.ndarray, int] | None:
        """The anchor nearest the fit within :data:`ANCHOR_REACH_RADII` expected radii, of which no other of this
        frame's ``fits`` is nearer (None: a spot not seen before; two spots close together each keep their own)."""
        reach = ANCHOR_REACH_RADII * self.r_expected

        def dist(f, a):
            return math.hypot(f.x_px - a[0].x_px, f.y_px - a[0].y_px)
        near = [a for a in self.anchors if dist(fit, a) <= reach and all(dist(g, a) >= dist(fit, a) for g in fits)]
        return min(near, key=lambda a: dist(fit, a)) if near else None

    def _trace_back(self, confirmed: SpotFit) -> tuple[SpotFit, ...]:
        """The tip's fits in the frames searched before the acquisition, the latest first: from the candidate the
        acquiring frame confirmed, each earlier frame's candidate nearest the one after it (within
        :data:`ACQUIRE_REACH`), as far back as the chain holds."""
        chain = [confirmed]
        reach = max(ACQUIRE_REACH * self.r_expected + 5.0, FAST_REACH * self._fast_speed())
        for fits in reversed(self.history[:-1]):
            last = chain[-1]
            near = [f for f in fits if math.hypot(f.x_px - last.x_px, f.y_px - last.y_px) <= reach]
            if not near:
                break
            chain.append(min(near, key=lambda f: math.hypot(f.x_px - last.x_px, f.y_px - last.y_px)))
        return tuple(chain)

    def _moved_since_anchor(self, pairs: list, frame: np.ndarray, fits: list[SpotFit]) -> list:
        """The confirmed spots that moved unlike the scene since they were first seen in this search (their anchor,
        :meth:`_anchor_of` among this frame's ``fits``): by more than :data:`SCENE_MOTION_PX` and 5 of the two fits'
        combined SDs, the scene's own motion since then taken off; and its confirming spot in the frame before too
        (a still spot whose fit slipped once has not moved; a moving tip had).  A top released from rest barely
        moves in its first frames, and a highlight in the scene of the tip's size and shape never does; until the
        tip has moved, nothing is taken (those frames get their positions back when it is: :meth:`_trace_back`).  A
        spot where a sleeping top's tip would be passes unmoved (:meth:`_at_the_pole`)."""
        out, shifts = [], {}
        for p in pairs:
            f, before_f = p[3], p[4]  # this frame's spot and the one it confirmed in the frame before
            anchor = self._anchor_of(f, fits)
            if anchor is None:
                if self._at_the_pole(f):
                    out.append(p)
                continue
            a, before, _ = anchor
            if id(before) not in shifts:
                shift = scene_shift(before, frame)
                shifts[id(before)] = np.zeros(2) if shift is None else shift
            shift = shifts[id(before)]
            if self._at_the_pole(f) or all(
                    math.hypot(s.x_px - a.x_px - shift[0], s.y_px - a.y_px - shift[1])
                    > max(SCENE_MOTION_PX, 5.0 * math.sqrt(max(np.trace(s.cov_xy) + np.trace(a.cov_xy), 0.0)))
                    for s in (f, before_f)):
                out.append(p)
        return out

    def _at_the_pole(self, fit: SpotFit) -> bool:
        """Whether the spot is where a sleeping top's tip is (tilt below :data:`SLEEPING_TILT_RAD`), which need not
        move."""
        tip = tip_from_pixel(fit.x_px, fit.y_px, self.camera, self.length_m)
        return tip is not None and float(tip[2]) > math.cos(SLEEPING_TILT_RAD)

    def _unlike_the_scene(self, pairs: list, shift: np.ndarray | None, busy: bool) -> list:
        """The confirmed candidates that moved unlike the scene between the two frames: a spot of a textured
        scene moves with it (still, or drifting), the tip with the top.  The scene's motion is ``shift`` (the
        frames' registration, when there is something to register) or their median motion.  The test is made
        in a busy scene (``busy``: :data:`BUSY_CANDIDATES` spots of the tip's size or more, a texture's), and
        when reacquiring a tip that moved faster than twice :data:`SCENE_MOTION_PX` per frame before it was
        lost (a slow tip cannot be told from the scene in two frames; the rig's own few spots in a quiet scene
        are told apart by size).  When none moved unlike the scene
        (the tip not among them, or a still top in a busy scene) none is taken.  A reacquisition only considers
        candidates within reach of where the tip was lost (:data:`REACQUIRE_RADII`, :data:`REACQUIRE_SPEEDS`)."""
        fast = False
        if self.had_lock and self.lost_at is not None:  # the tip cannot have gone further than its speed allows
            x, y, speed = self.lost_at
            reach = REACQUIRE_RADII * self.r_expected + REACQUIRE_SPEEDS * speed * self.since_lost
            pairs = [p for p in pairs if math.hypot(p[3].x_px - x, p[3].y_px - y) <= reach]
            fast = speed > 2 * SCENE_MOTION_PX
        if not pairs or not (busy or fast):
            return pairs
        moves = np.array([[f.x_px - g.x_px, f.y_px - g.y_px] for *_, f, g in pairs])
        scene = shift if shift is not None else np.median(moves, axis=0)
        odd = np.hypot(*(moves - scene).T)
        # moved by more than the two fits' errors allow (5 of their combined SDs), and by SCENE_MOTION_PX at least
        noise = np.array([math.sqrt(max(np.trace(f.cov_xy) + np.trace(g.cov_xy), 0.0)) for *_, f, g in pairs])
        return [p for p, o, s in zip(pairs, odd, noise) if o > max(SCENE_MOTION_PX, 5.0 * s)]

    # ------------------------------------------------------------------------------- per frame
    def locate(self, frame: np.ndarray, threshold: Detection, others: tuple | None = ()) -> Located:
        """The tip in this frame; ``others`` the other spots followed in the last frame (``(x, y, r)`` [px]; None
        when some were not found there)."""
        self._see_light(frame)
        if self.last:
            fit = self._track(frame, threshold, others)
            if fit is not None:
                self._accept(fit)
                self.lately.append((fit.x_px, fit.y_px))
                self.followed += 1
                if self.followed != BACK_AFTER or not self._fast_speed():
                    return Located(fit, "ok")
                return Located(fit, "ok", self._follow_back(fit))
            self.misses += 1
            self.lately.append(self._look(frame, threshold)[0])  # the tip may be followed back here (_follow_back)
            if self.misses > COAST_FRAMES:
                self._lose()
            return Located(None, "missing")
        self.since_lost += 1
        self.searched += 1
        fit = self._acquire(frame, threshold)
        if fit is None:
            return Located(None, "missing")
        chain, self.pending, self.confirmed, self.earlier = self.earlier, [], None, ()
        quality = "reacquired" if self.had_lock else "ok"
        if self.had_lock and self.lost_at is not None and self.since_lost > 0:
            self.gap_speeds.append(math.hypot(fit.x_px - self.lost_at[0], fit.y_px - self.lost_at[1]) / self.since_lost)
            self.steps_since_gap = 0
        for f in reversed(chain):
            self._accept(f)
        self._accept(fit)
        self.followed = 0
        self._taken(chain)
        self.lately[-1] = (fit.x_px, fit.y_px)
        return Located(fit, quality, chain)

    def _follow_back(self, fit: SpotFit) -> tuple[SpotFit | None, ...]:
        """The tip followed back from this frame through the frames seen lately (:func:`.backward.follow_back`), with
        the gate it is followed forward with once seen to move fast (:meth:`_prediction`); the frames given back are
        followed ones from now on."""
        fast = self._fast_speed()
        earlier = follow_back(self.lately, (fit.x_px, fit.y_px), lambda steps: MIN_GATE_PX + 2.0 * fast * steps,
                              self._appearance_ok, COAST_FRAMES)
        self._taken(earlier)
        return earlier

    def _taken(self, earlier: tuple[SpotFit | None, ...]) -> None:
        """Mark the frames before the latest in :attr:`lately` where ``earlier`` (the latest first) gives the tip."""
        for back, f in enumerate(earlier[:len(self.lately) - 1], start=2):
            if f is not None:
                self.lately[-back] = (f.x_px, f.y_px)

    def _lose(self) -> None:
        """Forget the track; remember where it ended and how fast the tip moved (a reacquisition's reach)."""
        if self.last:
            p = np.array(self.last)
            speed = max(float(np.median(np.hypot(*np.diff(p, axis=0).T))) if len(p) > 1 else 0.0,
                        float(np.quantile(np.asarray(self.speeds), REACQUIRE_QUANTILE)) if self.speeds else 0.0)
            self.lost_at = (float(p[-1, 0]), float(p[-1, 1]), speed)
            self.since_lost = self.misses
        self.last.clear()

    def _accept(self, fit: SpotFit) -> None:
        if self.last:
            self.speeds.append(math.hypot(fit.x_px - self.last[-1][0], fit.y_px - self.last[-1][1]) / (1 + self.misses))
            self.steps_since_gap += 1
        self.last.append((fit.x_px, fit.y_px))
        self.last_r = fit.radius_px
        self.radii.append(fit.radius_px)
        if self._brightness(fit) == (False, True):  # the tip as bright as seen: the rows' light changed behind it
            self.light.index = self._level(fit) * self.light.index / statistics.median(self.amplitudes)
        self.amplitudes.append(self._level(fit))
        self.raw_levels.append(self._level(fit) * self.light.index)
        self.chi2s.append(fit.chi2_own)
        self.misses = 0
        self.had_lock = True

    def lost(self) -> None:
        """The located spot was not usable (its ray misses the tip's sphere): search anew."""
        self._lose()
        self.misses = 0
