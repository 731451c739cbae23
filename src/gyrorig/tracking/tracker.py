"""The tracking loop: frames in, the tip's angle table and the marker detections out.

Per frame (a sensor with gamma is linearised first):

1. **find** the tip spot (:class:`gyrorig.tracking.follow.TipFollower`): blobs above a threshold
   in a window around the position predicted from the previous frames, a full-frame search
   only to acquire (confirmed by the next frame) or reacquire; a spot is taken for the tip only
   when its shape, size, appearance and motion are the tip's, and it is not a lab marker.
2. **localise** it: the sphere model (:func:`gyrorig.tracking.spot.fit_spot`, weighted least
   squares with the sensor's noise model, jointly with a neighbouring spot when one reaches
   into the window) or, for disc and blob markers, the elliptical one
   (:mod:`gyrorig.tracking.ellipse`).
3. **3D**: the undistorted ray through the spot centre meets the sphere of the tip's radius
   about the pivot (the nearer intersection); ``theta, phi`` follow, with their covariance.
4. the frame's dots, if any (:mod:`gyrorig.tracking.dots`), give the frame angle ``psi``.

After the loop a codec's copies of the tip's picture get the tip's motion over them in their errors
(:mod:`gyrorig.tracking.copies`), the per-frame errors are checked against the tip's scatter about its path
(through each frame's neighbours, or where that cannot follow, sinusoids over the whole record:
:mod:`gyrorig.tracking.harmonic`) and scaled when needed, outliers removed (:mod:`gyrorig.tracking.scatter`), and
the camera model's uncertainty is propagated as angle modes (:func:`gyrorig.tracking.pose.camera_modes`); a pose
found from this same recording's tip motion (``gyrorig pose --video``) marks its modes as found from the frames, not
known beside them (``cam_k_prior`` 0).  The tables' columns are in :mod:`gyrorig.tables`.
"""

from __future__ import annotations

import logging

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from .. import _io
from ..markers import Marker, MarkerSet, parse_markers
from ..protocols import Protocol, ProtocolError
from ..stillness import still_ends
from ..tables import camera_mode_count, camera_mode_prior_column
from ..camera import Camera
from .detect import detection_threshold, opening_size_px
from .appearance import MarkerImage, lab_marker_image
from .transfer import settle_transfer
from .follow import MAX_SIGMA_RADII, SIZE_RANGE, TipFollower
from .dots import DotTracker
from .errors import BadInputError, TrackingError
from .fields import judged_fields, read_as_fields
from .pose import add_camera_modes, estimate_pose
from .copies import RepeatedFrames
from .rows import TrackRows, drop_tip, streak_caveat
from .harmonic import harmonic_check
from .scatter import NOISE_ACF, SigmaCheck, b_picture_runs, check_sigmas, local_factors
from .steady import CameraMotion, CameraWatch, steady_angle_rows
from .timing import (FrameClock, capture_on_grid, check_frame_rate, checked_frame_times, frame_interval_stats,
                     settle_timing)
from .sources import as_source, fingerprint, prepended
from .pace import off_pace_rows

__all__ = ["TrackResult", "track", "track_video", "tip_marker", "frame_interval_stats", "check_frame_rate"]

Progress = Callable[[int, int], None]
logger = logging.getLogger(__name__)

#: a tip whose expected image radius exceeds this fraction of the image's smaller side is refused (a camera pose or a
#: tip size far off: the detection's opening would take minutes per frame)
MAX_TIP_IMAGE_FRACTION = 0.25
#: errors the sensor and spot models give are scaled up when the scatter exceeds them by this many standard
#: errors of the check
SIGMA_CHECK_Z = 4.0
#: a video whose decoded frames fall short of its header's count by more than this fraction is reported as cut short
#: (a Matroska file's count is estimated from its duration, which frames its camera dropped also fill)
CUT_SHORT = 0.9
#: a class of frames (blended or clear) needs this many checked coordinates for a factor of its own
MIN_CLASS_COORDINATES = 30
#: ... and a relative standard error below this (the classes' factors are told apart only when frames of one
#: class have neighbours of the same class often enough)
MAX_CLASS_RELATIVE_SE = 0.15


@dataclass(frozen=True)
class TrackResult:
    """What :func:`track` found.

    ``angles``: one row per decoded frame, :data:`gyrorig.tables.ANGLE_COLUMNS`, then ``psi_rad,
    psi_sigma_rad`` (with frame dots), ``exposure_s``, ``theta_cam_k_rad, phi_cam_k_rad`` per
    camera mode and, from a video file, ``frame_type`` (the picture type the codec coded it as:
    ``I``, ``P``, ``B`` ...).  ``markers``: one row per detected marker, :data:`gyrorig.tables.MARKER_COLUMNS`.
    """

    angles: pd.DataFrame
    markers: pd.DataFrame
    #: decoded frames
    frames: int
    #: fraction of frames with a tip angle
    tracked_fraction: float
    #: time spent waiting for decoded frames, and tracking them [s]
    decode_s: float
    track_s: float
    #: the camera as used (with the pose found from the fiducials, if it was)
    camera: Camera
    #: the fiducial pose summary (None when camera.json had a pose)
    pose: dict | None = None
    camera_sigma_rad: list[float] = field(default_factory=lambda: [math.nan, math.nan])
    #: the per-frame errors checked against the tip's scatter about its path (:mod:`gyrorig.tracking.scatter`)
    sigma_check: SigmaCheck | None = None
    #: the measured frame intervals against camera.json's fps (:func:`frame_interval_stats`)
    frame_times: dict = field(default_factory=dict)
    #: the camera's motion seen on its fiducials (:mod:`gyrorig.tracking.steady`; None: none in view)
    camera_motion: CameraMotion | None = None
    #: what went wrong reading the source (a file cut short, damaged data whose pictures were left out, a decoder
    #: that stopped), as the warnings said it
    source_problems: tuple[str, ...] = ()

    @property
    def camera_modes(self) -> int:
        """Number of camera-model modes in the angle table."""
        return camera_mode_count(self.angles.columns)

    @property
    def camera_modes_from_frames(self) -> int:
        """How many of them are moves of a pose found from this record's own tip motion (no prior in the fit)."""
        cols = [camera_mode_prior_column(k + 1) for k in range(self.camera_modes)]
        return sum(int(c in self.angles and self.angles[c].iloc[0] == 0.0) for c in cols)

    def summary(self) -> dict:
        return {"frames": self.frames, "fps": self.camera.fps, "tracked_fraction": self.tracked_fraction, "decode_s": self.decode_s,
                "track_s": self.track_s, "pose": self.pose, "camera_modes": self.camera_modes,
                "camera_modes_from_frames": self.camera_modes_from_frames,
                "camera_sigma_rad": self.camera_sigma_rad, "rvec": self.camera.rvec.tolist(),
                "tvec": self.camera.tvec.tolist(),
                "sigma_check": self.sigma_check.as_dict() if self.sigma_check is not None else None,
                "frame_times": self.frame_times, "source_problems": list(self.source_problems)}


def _markers_and_tip(protocol: Protocol) -> tuple[MarkerSet, Marker]:
    if "markers" not in protocol.extra:
        raise ProtocolError(f"{protocol.name}: tracking needs a [markers] section with the tip marker")
    markers = parse_markers(protocol)
    return markers, tip_marker(protocol, markers)


def tip_marker(protocol: Protocol, markers: MarkerSet | None = None) -> Marker:
    """The protocol's tip marker (from ``markers``, the protocol's parsed once, when given): named ``tip``, on the
    frame, on the axis above the pivot."""
    if markers is None:
        if "markers" not in protocol.extra:
            raise ProtocolError(f"{protocol.name}: tracking needs a [markers] section with the tip marker")
        markers = parse_markers(protocol)
    tip = markers.tip()
    x, y, z = tip.position_m
    if abs(x) > 1e-9 or abs(y) > 1e-9 or z <= 0:
        raise ProtocolError(f"markers.tip.position_m = {list(tip.position_m)!r}: the tip must be on the axis, above "
                            "the pivot ([0, 0, L] with L > 0)")
    return tip


def _check_and_scale(angles: pd.DataFrame, markers: pd.DataFrame, rows: TrackRows, doubts: str, lossy: bool,
                     tip_name: str, camera: Camera, length_m: float, largest_error_px: float) -> SigmaCheck:
    """Check the tip's errors against its scatter about its path (:mod:`gyrorig.tracking.scatter`), for
    blended frames and the rest apart, and correct them where the check shows them wrong; turn the outliers into
    ``outlier`` rows without angles.

    When the models are in doubt (``doubts``: a recording, a lossy codec, an approximate marker model) each
    class's errors are scaled by its factor, never down (the path sees only what changes from frame to frame;
    what the scene or the codec does to several frames alike it cannot see); for a ``lossy`` codec, or a camera
    without a sensor gain (a recording, whose frames may be a lossless copy of a lossy one), an error the
    same for every frame is found beside the factors and added (the codec's displacement of the whole spot,
    which no single frame shows), with the error shared by a run of B pictures; these are solved twice, with the
    factors held at 1 or above and with them free (a codec that smooths the noise away leaves the spot fits' own
    errors too large, and its shared errors hidden under them), and each frame takes the larger of the two
    errors (the returned check is the solve most frames took).  Otherwise a
    class's errors are scaled only when evidently too small (by :data:`SIGMA_CHECK_Z` of the check's standard
    errors).  A class whose factor is not known well enough (:data:`MIN_CLASS_COORDINATES`,
    :data:`MAX_CLASS_RELATIVE_SE`) takes the overall factor.  Where that path cannot follow the tip (a low frame
    rate for its motion), a path of sinusoids over the whole record checks them (:func:`_harmonic_scaled`)."""
    index = np.array(sorted(rows.tip_px))
    if len(index) == 0:
        return SigmaCheck(math.nan, math.nan, 0, ())
    blended = angles.quality.to_numpy()[index].astype(str)
    classes = np.where(np.char.find(blended, "blended") >= 0, "blended", "clear")
    var = np.array([np.diag(rows.tip_cov[r]) for r in index])
    runs = b_picture_runs(angles)[index] if lossy else None
    # an error the same for every frame: a lossy codec's, or any recording's whose pixels no sensor model describes
    # (frames exported losslessly from a phone's video keep its codec's errors but not its codec's name)
    floor = lossy or not math.isfinite(camera.gain_e_per_adu)
    t, xy = angles.t_s.to_numpy()[index], np.array([rows.tip_px[r] for r in index])
    # a still end (the top held before its release) scatters as the codec leaves a still picture, not as the motion's
    # frames do: left out of the check, its frames take the errors the moving ones' check gives
    still = still_ends(t, xy, np.sqrt(var[:, 0] + var[:, 1]))
    path = (t, angles.frame.to_numpy()[index], np.where(still.keep[:, None], xy, np.nan))
    check = check_sigmas(*path, var, classes, floor=floor, min_factor=1.0 if doubts else 0.0, groups=runs,
                         follow_motion=True, largest_error_px=largest_error_px)
    if not math.isfinite(check.factor):
        return replace(check, reason="too few runs of 7 nearby tracked frames to check")
    if not check.smooth_path:
        b_run = np.where(runs >= 0, "B pictures", "others") if runs is not None else None
        return _harmonic_scaled(angles, markers, rows, index, path, var, b_run, check, doubts, camera, length_m,
                                tip_name)
    in_run = np.zeros(len(index), bool) if runs is None else runs >= 0
    own = np.array([rows.tip_cov[r] for r in index]).reshape(-1, 2, 2)
    factors, scale, added = _error_terms(check, classes, in_run, doubts, floor)
    if floor:
        # the same residuals solved again with the spot fits' own errors free to be too large (a codec that smooths
        # the noise away makes them so, and then hides its shared errors under them): each frame takes the larger
        free = check_sigmas(*path, var, classes, floor=True, min_factor=0.0, groups=runs, omega_rad_s=check.omega_rad_s)
        factors_free, scale_free, added_free = _error_terms(free, classes, in_run, doubts, floor, own_unknown=True)
        larger = (scale_free**2 * np.trace(own, axis1=1, axis2=2) + 2 * added_free
                  > scale**2 * np.trace(own, axis1=1, axis2=2) + 2 * added)
        scale, added = np.where(larger, scale_free, scale), np.where(larger, added_free, added)
        if np.mean(larger) > 0.5:
            check, factors = replace(free, outliers=check.outliers), factors_free
    if doubts:  # and stretch by stretch: the record's errors change along it (module scatter's local_factors)
        kept = ~np.isin(np.arange(len(index)), check.outliers) & still.keep
        local = local_factors(*path, scale[:, None] ** 2 * var + added[:, None], kept, check.omega_rad_s)
        scale, added = scale * local, added * local**2
        check = replace(check, local_frames=int(np.sum(local > 1.0)), local_max_factor=float(local.max()))
    reasons = [f"{label} frames' errors are smaller than their scatter" for label in factors]
    reason = doubts or "; ".join(reasons) or "sensor and spot models hold"
    changed = np.isin(classes, list(factors))
    if changed.any():
        rows.scale_tip_errors(angles, markers, index[changed], scale[changed], np.repeat(added[changed, None], 2, 1),
                              camera, length_m, tip_name)
    bad = index[list(check.outliers)]
    if len(bad):
        drop_tip(rows, angles, markers, bad, "outlier", tip_name=tip_name)
    return replace(check, applied=bool(factors), applied_factors=factors, reason=reason,
                   still_frames=int(np.count_nonzero(~still.keep)))


def _harmonic_scaled(angles: pd.DataFrame, markers: pd.DataFrame, rows: TrackRows, index: np.ndarray, path: tuple,
                     var: np.ndarray, b_run: np.ndarray | None, check: SigmaCheck, doubts: str, camera: Camera,
                     length_m: float, tip_name: str) -> SigmaCheck:
    """Where the path through a frame's neighbours cannot follow the tip: its errors checked against a path of
    sinusoids over the whole record (:mod:`gyrorig.tracking.harmonic`) and scaled as the record's check would
    (never down when the models are in doubt, else only when evidently too small; a lossy codec's B pictures,
    ``b_run``, apart from the rest when each class's factor is known well enough), its outliers dropped; left
    the spot fits' own, unchecked, when that path does not follow either."""
    why = (f"the tip moves too far between frames for a path through its neighbours to predict it (their residuals' "
           f"correlations 1-4 frames apart {_rounded(check.residual_acf)}, {_rounded(NOISE_ACF)} for noise)")
    h = harmonic_check(*path, var, b_run)
    if h is None or not h.follows:
        why += ": the errors are the spot fits' own, unchecked" + ("" if h is None else (
            f" (nor does a path of {len(h.omegas_rad_s)} sinusoids over the record follow it: "
            + ("" if h.converged else f"{h.coordinates // 2} frames are too few for the sinusoids it needs; ")
            + f"its residuals' correlations 1-3 frames apart {_rounded(h.residual_acf)})"))
        logger.warning("%s; a higher frame rate lets the record check them", why)
        return replace(check, outliers=(), reason=why)
    factors = {}
    for label, (f, se, n) in (h.by_class or {"all": (h.factor, h.factor_se, h.coordinates)}).items():
        if n < MIN_CLASS_COORDINATES or not se < MAX_CLASS_RELATIVE_SE * f:
            f, se = h.factor, h.factor_se
        f = max(f, 1.0) if doubts else (f if f > 1.0 + SIGMA_CHECK_Z * se else 1.0)
        if f != 1.0:
            factors[label] = f
    scale = np.array([factors.get(label, 1.0) for label in (b_run if h.by_class else ["all"] * len(index))])
    if factors:
        rows.scale_tip_errors(angles, markers, index, scale, np.zeros((len(index), 2)), camera, length_m, tip_name)
    if h.outliers:
        drop_tip(rows, angles, markers, index[list(h.outliers)], "outlier", tip_name=tip_name)
    reason = f"{why}: checked against a path of {len(h.omegas_rad_s)} sinusoids over the record" + (
        f"; {doubts}" if doubts else "")
    return replace(check, factor=h.factor, factor_se=h.factor_se, coordinates=h.coordinates, outliers=h.outliers,
                   by_class=h.by_class, floor_px=0.0, floor_px_se=0.0, shared_px=0.0, shared_px_se=0.0,
                   applied=bool(factors), applied_factors=factors, reason=reason)


def _error_terms(check: SigmaCheck, classes: np.ndarray, in_run: np.ndarray, doubts: str, floor: bool, *,
                 own_unknown: bool = False) -> tuple[dict, np.ndarray, np.ndarray]:
    """What the record's check makes of each frame's error: the classes' factors applied (``{class: factor}``),
    and per frame the factor on its own error and the variance added to it (the floor's, and the shared error of
    a run of B pictures for a frame in one) [px^2].  A class whose factor is not known well enough
    (:data:`MIN_CLASS_COORDINATES`, :data:`MAX_CLASS_RELATIVE_SE`) takes the overall factor, or with
    ``own_unknown`` (a solve whose floor and shared error the overall factor holds already) keeps its own errors."""
    factors = {}
    for label in ("clear", "blended"):
        f, se, n = check.by_class.get(label, (check.factor, check.factor_se, 0))
        if n < MIN_CLASS_COORDINATES or not se < MAX_CLASS_RELATIVE_SE * f:
            f, se = (1.0, 0.0) if own_unknown else (check.factor, check.factor_se)
        if doubts:
            # interleaved classes are told apart imprecisely: a class is never given narrower errors than the record
            # as a whole shows (without a floor, which the overall factor would count again), nor scaled down
            f = max(f, 1.0) if floor else max(f, check.factor, 1.0)
        if doubts or f > 1.0 + SIGMA_CHECK_Z * se:
            factors[label] = f
    scale = np.array([factors.get(label, 1.0) for label in classes])
    added = np.where(np.isin(classes, list(factors)), check.floor_px**2 + check.shared_px**2 * in_run, 0.0)
    return factors, scale, added


def _off_pace_left_out(rows: "TrackRows", angles: pd.DataFrame, markers: pd.DataFrame, tip_name: str, ratio: float,
                       source) -> tuple[str, ...]:
    """A slow-motion record's ends at another pace (a gallery's copy: normal-speed ends, their times unknown) lose
    their tip (:mod:`gyrorig.tracking.pace`); what to tell the user, as a source problem."""
    positions, note = off_pace_rows(angles, ratio)
    if len(positions):
        drop_tip(rows, angles, markers, positions, "off-pace", tip_name=tip_name)
    return _said(source, note)


def _said(source, problem: str) -> tuple[str, ...]:
    """A problem with the source, warned about and returned as a source problem (none when empty)."""
    if not problem:
        return ()
    logger.warning("%s: %s", source, problem)
    return (problem,)


def _caveats(source, appearance: MarkerImage, tip: Marker, frame_types: dict, lossy: bool, rows: TrackRows,
             camera: Camera, angles: pd.DataFrame, markers: pd.DataFrame) -> tuple[str, ...]:
    """What the record's error bars may not hold, warned about: a coloured marker's drift in a lossy file, a tip
    streaked by its motion during the exposure (those frames flagged, :meth:`TrackRows.flag_streaks`, once their
    times are the capture's and the record's outliers are out), a tip near the limb of its sphere as the camera sees
    it (:meth:`TrackRows.flag_near_limb`)."""
    drift = appearance.drift_caveat(tip, frame_types.values()) if lossy else ""
    streaks = rows.flag_streaks(angles, markers, camera.exposure_s, camera.fps, tip.name)
    limb = rows.flag_near_limb(angles, markers, camera, tip.position_m[2], tip.name)
    return (_said(source, drift) + _said(source, streak_caveat(*streaks, rows.tip_radius_px, camera.exposure_s))
            + _said(source, limb))


def _rounded(values) -> str:
    """Numbers as ``(a, b, ...)`` to two decimals, for a message."""
    return "(" + ", ".join(f"{v:.2f}" for v in values) + ")"


def _follower(camera: Camera, tip: Marker, markers: MarkerSet, source) -> TipFollower:
    """The tip's follower, refusing a tip that would fill the image (:data:`MAX_TIP_IMAGE_FRACTION`)."""
    follower = TipFollower(camera, tip, markers.fiducials())
    if not follower.r_expected < MAX_TIP_IMAGE_FRACTION * min(camera.width_px, camera.height_px):
        raise BadInputError(f"{source}: with this camera the tip (markers.{tip.name}.radius_m = {tip.radius_m:g}) would "
                            f"appear {2 * follower.r_expected:.0f} px wide in a {camera.width_px} x {camera.height_px} "
                            "image; check the tip's radius and the camera's pose and focal length")
    return follower


def _matched(camera: Camera, frames, source) -> Camera:
    """The camera at the video's bit depth, its transfer curve settled
    (:func:`~gyrorig.tracking.transfer.settle_transfer`); BadInputError when its picture size is not the video's."""
    if frames.bit_depth is not None and frames.bit_depth < 16 and (1 << frames.bit_depth) - 1 != camera.max_adu:
        logger.info("%s: %d-bit video; camera.json's bit_depth says %d: the video's is used", source,
                    frames.bit_depth, camera.max_adu.bit_length())
        camera = camera.with_sensor(bit_depth=frames.bit_depth)
    elif frames.bit_depth == 16 and camera.max_adu < 65535:
        # a 16-bit file may hold fewer significant bits (camera.json's); values above them say it holds all 16
        first = next(frames.items, None)
        if first is not None:
            frames.items = prepended(first, frames.items)
            if float(np.max(first[0])) > camera.max_adu:
                logger.warning("%s: 16-bit values up to %.0f, above camera.json's sensor.bit_depth = %d (largest %d): "
                               "taken as 16-bit (state sensor.bit_depth = 16 in camera.json)", source,
                               float(np.max(first[0])), camera.max_adu.bit_length(), camera.max_adu)
                camera = camera.with_sensor(bit_depth=16)
    camera = settle_transfer(camera, frames.transfer, source, lossy=frames.lossy)
    if (frames.width_px, frames.height_px) != (camera.width_px, camera.height_px):
        sx, sy = frames.width_px / camera.width_px, frames.height_px / camera.height_px
        hint = (f" (a {sx:.4g}x picture: if the camera records the same field of view at both sizes, its intrinsics "
                f"scale by {sx:.4g}; many phones crop the sensor differently per video mode, so calibrate or pose at "
                "the video's size)" if abs(sx - sy) < 1e-3 else
                " (another aspect ratio: the camera crops differently in this mode; calibrate or pose at the video's "
                "size)")
        raise BadInputError(f"{source}: the camera file says {camera.width_px} x {camera.height_px}, the video is "
                            f"{frames.width_px} x {frames.height_px}{hint}")
    return camera


def _steadied(rows: TrackRows, watch: CameraWatch, camera: Camera, length_m: float,
              source) -> CameraMotion | None:
    """The camera's motion seen on the fiducials; where it moved, the tip's rows steadied (and a warning)."""
    motion = watch.motion()
    if motion is not None and motion.moved:
        logger.warning("%s: the camera moved during the recording (its fiducials by %.2g px RMS, turned about its axis "
                       "by %.2g deg RMS): each tip pixel is taken back by their displacement in its frame", source,
                       motion.rms_px, motion.roll_rms_deg)
        steady_angle_rows(rows.angles, rows.tip_px, rows.tip_cov, motion, camera, length_m)
    elif motion is None and len(watch.spots) >= 2:
        logger.warning("%s: the protocol's fiducials (%d in view) were not found in the frames: whether the camera "
                       "moved is not known (a hand-held camera's motion would be taken for the tip's); check their "
                       "place, size, colour and polarity in the protocol", source, len(watch.spots))
    return motion


def track(video, camera: Camera, protocol: Protocol, *, progress: Progress | None = None,
          frame_dots: bool = True, watch_camera: bool = True) -> TrackResult:
    """Track the tip marker through a video (a path, or a frame source of :mod:`gyrorig.tracking.sources`).

    With ``frame_dots`` (and frame-fixed dots off the axis in the protocol, like the crossbar) these are tracked
    too: their detections go to ``markers`` and the frame's angle about the axis to ``angles`` (``psi_rad,
    psi_sigma_rad``; modulo pi for a symmetric pair).  Frame numbers come from the container's timestamps on
    camera.json's frame rate (frames a camera dropped are gaps; a variable rate's frames keep their order and own
    times; a slow-motion file's times are scaled by its rate over ``camera.capture_fps``; an interlaced video's fields
    are frames, :mod:`~gyrorig.tracking.fields`); a frame identical to the one before keeps its tip as a codec's copy
    (:meth:`~gyrorig.tracking.rows.TrackRows.repeat`; ``duplicate`` where its motion is unknown).  Frames
    are read at the video's own bit depth.  With ``watch_camera`` (and lab fiducials in the protocol) the camera's own
    motion is followed on the fiducials and taken off the tip (:mod:`gyrorig.tracking.steady`); not with a rough pose
    (it puts the fiducials where they are not).  Raises :class:`TrackingError` for an unreadable video, a camera that
    does not match the video, or a tip that is never found.
    """
    markers, tip = _markers_and_tip(protocol)  # parsed once per call
    source, given = as_source(video), camera
    pose_info = None
    if not camera.has_pose:
        camera, pose_info = estimate_pose(source, camera, protocol, markers=markers)
    camera = _protocol_exposure(camera, protocol)
    with source.open(colour=tip.colour != "any") as frames:
        frames, camera = read_as_fields(frames, camera, source)
        camera, time_scale = settle_timing(camera, frames, source)
        camera = _matched(camera, frames, source)
        lossy = frames.lossy
        appearance = MarkerImage(tip, camera, frames.levels)
        if (lossy or not appearance.keeps_sensor_model) and camera.sensor_known:
            # the codec changed the pixel values, or the image is not the sensor's: the noise model does not hold
            camera = camera.with_sensor(gain_e_per_adu=math.nan)
        follower = _follower(camera, tip, markers, source)
        watch = CameraWatch(camera, follower.lab_px if watch_camera else [],
                            lab_marker_image(markers.fiducials(), tip, camera, frames.levels))
        dot_markers = markers.frame_dots() if frame_dots else ()
        dots = DotTracker(dot_markers, camera) if dot_markers else None
        # the local-contrast opening must be wider than the largest spot the follower takes for the tip
        scale_px = opening_size_px(SIZE_RANGE["blob"][1] * follower.r_expected, camera.psf_sigma_px)
        rows = TrackRows(follower.r_expected, tuple(m for m in markers.moving_dots() if m not in dot_markers))
        frame_types: dict[int, str] = {}  # frame number -> picture type (video files)
        repeated = RepeatedFrames()
        clock = FrameClock(camera.fps, time_scale, source)
        k = 0
        t_decode = t_track = 0.0  # t_decode: time spent waiting for decoded frames
        it = iter(frames)
        while True:
            t0 = time.perf_counter()
            item = next(it, None)
            t1 = time.perf_counter()
            t_decode += t1 - t0
            if item is None:
                break
            frame, t_frame = item
            index, t_frame = clock.number(t_frame, k)
            if frames.frame_types is not None:
                frame_types[index] = frames.frame_types[k]
            if repeated.repeats(frame):
                rows.repeat(camera, index, t_frame)
                k += 1
                continue
            raw, frame = frame, appearance.lazy(frame)
            if k % 100 == 0:  # the contrast's spread, refreshed every 100 frames (drifting light, moving scenes)
                threshold = detection_threshold(frame, scale_px, floor=4.0 * camera.max_adu / 255.0)
            watch.observe(frame, k, index, raw)
            follower.shift_px = watch.last
            rows.frame(camera, tip, follower, dots, frame, index, t_frame, threshold)
            t_track += time.perf_counter() - t1
            k += 1
            if progress and (k % 50 == 0):
                progress(k, frames.count)
    if k == 0:
        said = "; ".join(frames.problems) or "unreadable or truncated video"
        raise TrackingError(f"{source}: no frame could be decoded ({said})")
    check_frame_rate(np.asarray(clock.times), camera.fps, source)
    motion = _steadied(rows, watch, camera, tip.position_m[2], source)
    angles, markers = rows.tables(camera, dots is not None, tip)
    source_problems = _source_problems(frames, k, source, rows, angles, markers)
    if frame_types:
        angles["frame_type"] = angles.frame.map(frame_types).fillna("")
    if not angles.theta_rad.notna().any():
        raise _never_found(follower, source, k)
    again, said = judged_fields(frames, camera, angles.frame.to_numpy(), rows.tip_px, rows.tip_cov, source)
    if again:
        return track(video, replace(given, interlace=again), protocol, progress=progress, frame_dots=frame_dots,
                     watch_camera=watch_camera)
    times = checked_frame_times(clock, camera, time_scale, source, frames.fields,
                                capture_on_grid(angles, markers, rows.tip_px, rows.tip_cov, clock))
    check = _check_and_scale(angles, markers, rows, appearance.doubts(camera, lossy, follower.shape, tip), lossy,
                             tip.name, camera, tip.position_m[2], MAX_SIGMA_RADII * follower.r_expected)
    check = replace(check, scene_frames=rows.widen_by_scene(angles, markers, camera, tip.position_m[2], tip.name))
    source_problems += _off_pace_left_out(rows, angles, markers, tip.name, 1.0 / time_scale, source) + said
    source_problems += _caveats(source, appearance, tip, frame_types, lossy, rows, camera, angles, markers)
    own_pose = camera.pose_recording is not None and camera.pose_recording == fingerprint(source)
    camera_sigma = add_camera_modes(angles, rows.tip_px, camera, tip.position_m[2],
                                     pose_info or camera.pose_points, own_pose)
    if progress:
        progress(k, k)
    return TrackResult(angles, markers, k, float(angles.theta_rad.notna().mean()), t_decode, t_track, camera,
                       pose_info, camera_sigma, check, times, motion, source_problems)


def _never_found(follower: TipFollower, source, decoded: int) -> TrackingError:
    """The error for a record in which the tip was never found, with why each candidate of the first frame searched
    was refused."""
    look = follower.first_look
    why = "" if look is None else "; in the first frame searched " + (", ".join(
        f"{n} {reason}" for reason, n in look.reasons().items()) or "no spot stood out from its surroundings")
    return TrackingError(f"{source}: the tip marker was never found in {decoded} frames{why}", first_look=look)


def _source_problems(frames, decoded: int, source, rows: "TrackRows", angles: pd.DataFrame, markers: pd.DataFrame
                     ) -> tuple[str, ...]:
    """What went wrong reading (damaged data, a decoder that stopped on it, a video that ended before its header
    said it would), each logged as a warning.  The pictures damaged data reaches (``frames.damaged``) lose their
    tip (quality ``damaged``): a decoder conceals damage by copying picture parts from elsewhere, which puts a
    spot where no marker was."""
    problems = [f"{problem} (the {decoded} frames decoded are tracked)" for problem in frames.problems]
    for first, end, message in frames.damaged:
        drop_tip(rows, angles, markers, np.arange(first, min(end, len(angles))), "damaged")
        problems.append(f"the decoder reported damaged data ({message!r}); frames {angles.frame.iloc[first]}-"
                        f"{angles.frame.iloc[min(end, len(angles)) - 1]} (up to the next key picture) are left out")
    if frames.count and decoded < CUT_SHORT * frames.count and not frames.problems:  # else said why
        problems.append(f"the video ends after {decoded} of the {frames.count} frames its header states: a file cut "
                        "short (copied before the recording stopped, or truncated in transfer); the frames it has "
                        "are tracked")
    for problem in problems:
        logger.warning("%s: %s", source, problem)
    return tuple(problems)


def _protocol_exposure(camera: Camera, protocol: Protocol) -> Camera:
    """The camera with the protocol's ``[camera] exposure_s`` when camera.json has none (a calibration's file
    records no exposure; 0 is no exposure at all, which no camera has): the frames' mid-exposure times and the
    fit's average over the exposure need it."""
    if camera.exposure_s > 0:
        return camera
    stated = protocol.extra.get("camera", {}).get("exposure_s") if isinstance(protocol.extra.get("camera"), dict) \
        else None
    if isinstance(stated, (int, float)) and not isinstance(stated, bool) and 0 < stated <= 10.0:
        logger.info("camera.json states no exposure: the protocol's [camera] exposure_s = %g s is used", stated)
        return replace(camera, exposure_s=float(stated))
    return camera


def track_video(video, camera: Camera, protocol: Protocol, out_dir: str | Path, *,
                progress: Progress | None = None, frame_dots: bool = True) -> dict:
    """:func:`track`, then write ``angles.csv``, ``markers.csv`` and ``track.json`` (the summary) into
    ``out_dir`` (nothing on failure).

    Returns :meth:`TrackResult.summary` with the paths written (``angles``, ``markers``).
    """
    result = track(video, camera, protocol, progress=progress, frame_dots=frame_dots)
    out = Path(out_dir)
    _io.write_csv(result.angles, out / "angles.csv")
    _io.write_csv(result.markers, out / "markers.csv")
    _io.write_json(result.summary(), out / "track.json")
    return {**result.summary(), "angles": str(out / "angles.csv"), "markers": str(out / "markers.csv")}
