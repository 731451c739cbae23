"""The rows of the angle and marker tables as the tracking loop produces them (:class:`TrackRows`), and a tip taken
out of them again (:func:`drop_tip`).  The tables' columns are in :mod:`gyrorig.tables`."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ..camera import Camera
from ..markers import Marker
from ..tables import ANGLE_COLUMNS, MARKER_COLUMNS
from .copies import RecentPictures, copy_extents, copy_groups
from .detect import Detection
from .dots import DotTracker, dot_circles
from .follow import ANCHOR_FRAMES, TipFollower
from .rays import angle_covariances, angles_with_covariance, limb_flags
from .scene_spot import near_ring_move
from .spot import SpotFit

__all__ = ["TrackRows", "drop_tip", "empty_angle_row", "marker_row", "unwrap_nan", "with_flag", "streak_caveat",
           "STREAK_RADII"]

#: a tip that moves more than this many of its image radii during an exposure is a streak, which the round spot fit
#: does not describe (its error bars may be too small there: docs/recordings.md, "Streaks")
STREAK_RADII = 1.0


def empty_angle_row(index: int, t_s: float, quality: str) -> tuple:
    nan = float("nan")
    return (index, t_s, nan, nan, nan, nan, nan, nan, nan, nan, quality)


def marker_row(index: int, t_s: float, name: str, fit: SpotFit, quality: str) -> tuple:
    return (index, t_s, name, fit.x_px, fit.y_px, math.sqrt(fit.cov_xy[0, 0]), math.sqrt(fit.cov_xy[1, 1]),
            fit.radius_px, fit.amplitude_adu, fit.background_adu, fit.chi2_red, quality)


def with_flag(quality: str, flag: str) -> str:
    """A quality (:data:`gyrorig.tables.QUALITY_FLAGS`, comma-separated) with ``flag`` added (``ok`` gives way)."""
    return flag if quality == "ok" else quality + "," + flag


def unwrap_nan(phi: np.ndarray) -> np.ndarray:
    """Unwrap the azimuth across the tracked frames, leaving gaps as NaN."""
    ok = np.isfinite(phi)
    out = phi.copy()
    if ok.any():
        out[ok] = np.unwrap(phi[ok])
    return out


class TrackRows:
    """Rows of the angle and marker tables as the loop produces them, for a tip of ``tip_radius_px`` (its expected
    image radius)."""

    def __init__(self, tip_radius_px: float = math.nan, loose_dots: tuple[Marker, ...] = ()):
        self.angles: list[tuple] = []
        self.markers: list[tuple] = []
        self.tip_px: dict[int, tuple[float, float]] = {}  # angle row -> tip pixel position
        self.tip_cov: dict[int, np.ndarray] = {}  # angle row -> its covariance in (x, y) [px^2]
        #: angle row -> the variance along x and y [px^2] that a second view of the scene under the tip's edge adds
        #: (:func:`~gyrorig.tracking.scene_spot.near_ring_move`; a recording's sphere in the luma only)
        self.scene_var: dict[int, np.ndarray] = {}
        self.psi: dict[int, tuple[float, float]] = {}
        #: the frames the follower saw (a duplicate frame is not shown it), latest last:
        #: (row, index, t_frame, threshold)
        self.seen: list[tuple[int, int, float, Detection]] = []
        #: the other spots that can stand near the tip, (x, y, r) [px]: the frame dots fitted in the last frame and
        #: where the dots not followed (``loose_dots``: the rotor's, or all without the frame's dots followed) can be
        #: about the axis the tip gave (:func:`~gyrorig.tracking.dots.dot_circles`); None when not known (a frame dot
        #: not found, or no tip in the last frame to place the others by)
        self.others: tuple | None = ()
        self.loose_dots = loose_dots
        self.recent, self.alike = RecentPictures(), []  # the last frames; rows alike (a codec's copies: module copies)
        #: the rows of frames whose picture repeats the one before's, with their frames' times (:meth:`repeat`)
        self.repeated: list[tuple[int, float]] = []
        self.tip_radius_px = tip_radius_px

    def frame(self, camera: Camera, tip: Marker, follower: TipFollower, dots: DotTracker | None,
              frame: np.ndarray, index: int, t_frame: float, threshold: Detection) -> None:
        """Track one (new) frame and add its rows."""
        located = follower.locate(frame, threshold, self.others)
        self.others = () if dots is None and not self.loose_dots else None
        for fit, (row, *seen) in zip(located.earlier, reversed(self.seen)):
            # an acquisition, or the tip followed back: the frames before get the tip's positions back
            if fit is None:  # taken in that frame, or not found in it
                continue
            self._tip_rows(camera, tip, follower, None, None, *seen, fit, located.quality, row=row)
        self.seen = self.seen[-ANCHOR_FRAMES:] + [(len(self.angles), index, t_frame, threshold)]
        if located.fit is None:
            self.recent.see(frame, None)
            self.angles.append(empty_angle_row(index, t_frame + camera.exposure_s / 2, "missing"))
            return
        self._tip_rows(camera, tip, follower, dots, frame, index, t_frame, threshold, located.fit, located.quality)
        self.alike.append(self.recent.see(frame, len(self.angles) - 1, located.fit))

    def repeat(self, camera: Camera, index: int, t_frame: float) -> None:
        """Add the row of a frame whose picture is the frame before's, bit for bit (a still scene a codec coded as a
        copy, or a picture repeated by a rate conversion); :meth:`tables` gives it that frame's tip
        (:meth:`_fill_repeats`)."""
        self.angles.append(empty_angle_row(index, t_frame + camera.exposure_s / 2, "duplicate"))
        self.repeated.append((len(self.angles) - 1, t_frame))

    def _fill_repeats(self, camera: Camera, tip_name: str) -> None:
        """Each repeated picture's row (:meth:`repeat`) with the tip's fit of the row before it, when that has one, at
        its own time, joined to it as a codec's copy (:meth:`widen_copies` adds the tip's motion over the two frames
        to both errors: which of them holds the picture's own time is unknown); the others stay ``duplicate``."""
        tip_marker = {m[0]: m for m in self.markers if m[2] == tip_name}  # frame -> the tip's marker row
        for row, t_frame in self.repeated:
            before = row - 1
            source = tip_marker.get(self.angles[before][0]) if before >= 0 and before in self.tip_px else None
            if source is None:
                continue
            index = self.angles[row][0]
            t_mid = t_frame + camera.exposure_s / 2 + camera.row_delay_s(self.tip_px[before][1])
            self.angles[row] = (index, t_mid, *self.angles[before][2:])
            tip_marker[index] = (index, t_mid, *source[2:])
            self.markers.append(tip_marker[index])
            self.tip_px[row], self.tip_cov[row] = self.tip_px[before], self.tip_cov[before].copy()
            if before in self.scene_var:
                self.scene_var[row] = self.scene_var[before]
            self.alike.append({before, row})

    def _tip_rows(self, camera, tip, follower, dots, frame, index, t_frame, threshold, fit: SpotFit, quality: str,
                  row: int | None = None) -> None:
        """The angle row (appended, or put in place of ``row``) and the marker rows of a tip fit."""
        t_mid = t_frame + camera.exposure_s / 2 + camera.row_delay_s(fit.y_px)
        for flag, on in (("saturated", fit.saturated), ("blended", fit.blended)):
            if on:
                quality = with_flag(quality, flag)
        geo = angles_with_covariance(fit.x_px, fit.y_px, fit.cov_xy, camera, tip.position_m[2])
        if geo is None:
            angle_row = empty_angle_row(index, t_mid, "off-sphere")
            follower.lost()
        else:
            th, ph, n, cov = geo
            sth, sph = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
            angle_row = (index, t_mid, th, ph, sth, sph, cov[0, 1] / (sth * sph), n[0], n[1], n[2], quality)
        if row is None:
            self.angles.append(angle_row)
            row = len(self.angles) - 1
        else:
            self.angles[row] = angle_row
        if geo is not None:
            self.tip_px[row] = (fit.x_px, fit.y_px)
            self.tip_cov[row] = np.asarray(fit.cov_xy, float)
            self.scene_var.pop(row, None)
            # not on a colour's image (the codec's half-resolution chroma): there the two rings' views differ in front
            # of a plain scene too
            if frame is not None and follower.shape == "sphere" and not camera.sensor_known and tip.colour == "any":
                move = near_ring_move(frame, fit, follower.r_expected, camera)
                if move.any():
                    self.scene_var[row] = move**2
            # placed by this frame's tip for the next frame's (not for a frame given back: frame None)
            loose = dot_circles(self.loose_dots, geo[2], camera) if frame is not None and self.loose_dots else ()
            if dots is None and loose:
                self.others = loose
            if dots is not None:
                psi, psi_sigma, found = dots.step(frame, t_mid, geo[2], (fit.x_px, fit.y_px), fit.radius_px, threshold)
                self.psi[row] = (psi, psi_sigma)
                if len(found) == len(dots.dots):
                    self.others = tuple((f.x_px, f.y_px, f.radius_px) for _, f in found) + loose
                for name, dfit in found:
                    t_dot = t_frame + camera.exposure_s / 2 + camera.row_delay_s(dfit.y_px)
                    self.markers.append(marker_row(index, t_dot, name, dfit, "blended" if dfit.blended else "ok"))
        self.markers.append(marker_row(index, t_mid, tip.name, fit, quality))

    def tables(self, camera: Camera, with_dots: bool, tip: Marker) -> tuple[pd.DataFrame, pd.DataFrame]:
        """The angle and marker tables, a codec's copies of the tip's picture given the tip's motion over them
        (:meth:`widen_copies`)."""
        self._fill_repeats(camera, tip.name)
        angles = pd.DataFrame(self.angles, columns=list(ANGLE_COLUMNS))
        angles["phi_rad"] = unwrap_nan(angles.phi_rad.to_numpy())
        if with_dots:
            psi_col = np.full((len(angles), 2), np.nan)
            for r_, v_ in self.psi.items():
                psi_col[r_] = v_
            angles["psi_rad"], angles["psi_sigma_rad"] = psi_col[:, 0], psi_col[:, 1]
        angles["exposure_s"] = float(camera.exposure_s)
        if camera.readout_unknown:  # where in the frame each tip was read out: the fit finds the readout time
            rows = np.full(len(angles), np.nan)
            for r_, (_, y_) in self.tip_px.items():
                rows[r_] = y_ / camera.height_px
            angles["row_fraction"] = rows
        markers = pd.DataFrame(self.markers, columns=list(MARKER_COLUMNS)).sort_values("frame", kind="stable")
        markers = markers.reset_index(drop=True)
        self.widen_copies(angles, markers, camera, tip)
        return angles, markers

    def flag_streaks(self, angles: pd.DataFrame, markers: pd.DataFrame, exposure_s: float, fps: float,
                     tip_name: str) -> tuple[int, float]:
        """The frames whose tip may have moved more than :data:`STREAK_RADII` of its image radii during the exposure
        flagged ``streaked``: ``(how many, the most the tip moved during an exposure [px])``.  Its speed is the mean
        of its chords to the frames either side tracked within 2.5 frame intervals: where the frame rate is low for
        the motion, an overestimate near a turn, where a central difference would be an underestimate of a tip that
        turns between its neighbours.  Their errors stay the round fit's own."""
        rows = np.array(sorted(self.tip_px), int)
        if not exposure_s > 0 or rows.size < 2 or not self.tip_radius_px > 0:
            return 0, 0.0
        t = angles.t_s.to_numpy()[rows]
        gap = np.diff(t)
        near = (gap > 0) & (gap <= 2.5 / fps)
        p = np.array([self.tip_px[r] for r in rows])
        chord = np.where(near, np.hypot(*np.diff(p, axis=0).T) / np.where(near, gap, 1.0), 0.0)
        speeds = np.zeros((rows.size, 2))
        speeds[1:, 0], speeds[:-1, 1] = chord, chord
        seen = np.zeros((rows.size, 2), bool)
        seen[1:, 0], seen[:-1, 1] = near, near
        travel = speeds.sum(axis=1) / np.maximum(seen.sum(axis=1), 1) * exposure_s
        streaked = rows[travel > STREAK_RADII * self.tip_radius_px]
        angles.loc[streaked, "quality"] = angles.quality[streaked].map(lambda q: with_flag(q, "streaked"))
        sel = (markers.marker == tip_name) & markers.frame.isin(angles.frame.to_numpy()[streaked])
        markers.loc[sel, "quality"] = markers.quality[sel].map(lambda q: with_flag(q, "streaked"))
        return int(streaked.size), float(travel.max())

    def flag_near_limb(self, angles: pd.DataFrame, markers: pd.DataFrame, camera: Camera, length_m: float,
                       tip_name: str) -> str:
        """The tracked frames flagged ``near-limb`` when the tip came near the limb of its sphere as the camera sees
        it (:func:`~gyrorig.tracking.rays.limb_flags`); what to say about them (empty when it did not)."""
        near, said = limb_flags(angles[["tip_x", "tip_y", "tip_z"]].to_numpy(float), camera, length_m)
        if near.any():
            angles.loc[near, "quality"] = angles.quality[near].map(lambda q: with_flag(q, "near-limb"))
            sel = (markers.marker == tip_name) & markers.frame.isin(angles.frame[near])
            markers.loc[sel, "quality"] = markers.quality[sel].map(lambda q: with_flag(q, "near-limb"))
        return said

    def widen_copies(self, angles: pd.DataFrame, markers: pd.DataFrame, camera: Camera, tip: Marker) -> None:
        """The frames whose tip's pixels a codec copied (:mod:`gyrorig.tracking.copies`): the tip's motion over each
        group added to their errors along x and y, their quality flagged ``copied``; where the motion is unknown,
        their tip dropped (``duplicate``)."""
        copied, extents, unknown = copy_extents(copy_groups(self.alike), angles.frame.to_numpy(), self.tip_px)
        if copied:
            self.scale_tip_errors(angles, markers, np.array(copied), np.ones(len(copied)), extents**2, camera,
                                  tip.position_m[2], tip.name)
            angles.loc[copied, "quality"] = angles.quality[copied].map(lambda q: with_flag(q, "copied"))
            sel = (markers.marker == tip.name) & markers.frame.isin(angles.frame.to_numpy()[copied])
            markers.loc[sel, "quality"] = markers.quality[sel].map(lambda q: with_flag(q, "copied"))
        drop_tip(self, angles, markers, unknown, "duplicate", tip_name=tip.name)

    def widen_by_scene(self, angles: pd.DataFrame, markers: pd.DataFrame, camera: Camera, length_m: float,
                       tip_name: str) -> int:
        """The tip's errors widened by :attr:`scene_var` in the rows still tracked (after the record's check, which
        then judged the spot fits' own errors); how many rows."""
        rows = np.array([r for r in sorted(self.scene_var) if r in self.tip_px], int)
        if len(rows):
            self.scale_tip_errors(angles, markers, rows, np.ones(len(rows)),
                                  np.array([self.scene_var[r] for r in rows]), camera, length_m, tip_name)
        return len(rows)

    def scale_tip_errors(self, angles: pd.DataFrame, markers: pd.DataFrame, rows: np.ndarray, scale: np.ndarray,
                         added: np.ndarray, camera: Camera, length_m: float, tip_name: str) -> None:
        """The tip's errors in angle table ``rows`` multiplied by ``scale`` (n,) and widened by the variances
        ``added`` (n, 2) along x and y [px^2]: its pixel covariance, its angles' errors and its marker rows."""
        covs = (scale[:, None, None] ** 2 * np.array([self.tip_cov[r] for r in rows])
                + added[:, :, None] * np.eye(2))
        c = angle_covariances(np.array([self.tip_px[r] for r in rows]).reshape(-1, 2), covs, camera, length_m)[3]
        sth, sph = np.sqrt(c[:, 0, 0]), np.sqrt(c[:, 1, 1])
        angles.loc[rows, ["theta_sigma_rad", "phi_sigma_rad", "theta_phi_corr"]] = np.column_stack(
            [sth, sph, c[:, 0, 1] / (sth * sph)])
        for r, cov in zip(rows, covs):
            self.tip_cov[r] = cov
        frames = angles.frame.to_numpy()[rows]
        sel = (markers.marker == tip_name) & markers.frame.isin(frames)
        at = markers.loc[sel, "frame"].map(dict(zip(frames, range(len(frames))))).to_numpy(int)
        for axis, col in enumerate(("sigma_x_px", "sigma_y_px")):
            markers.loc[sel, col] = np.sqrt(scale[at] ** 2 * markers.loc[sel, col] ** 2 + added[at, axis])


def drop_tip(rows: "TrackRows", angles: pd.DataFrame, markers: pd.DataFrame, positions, quality: str, *,
            tip_name: str | None = None) -> None:
    """The angle rows at ``positions`` lose their tip (angles NaN, ``quality``); with ``tip_name`` its marker rows
    in those frames are marked so, without it every marker row of those frames."""
    positions = np.asarray(positions, int)
    cols = [c for c in ("theta_rad", "phi_rad", "theta_sigma_rad", "phi_sigma_rad", "theta_phi_corr",
                        "tip_x", "tip_y", "tip_z", "psi_rad", "psi_sigma_rad") if c in angles]
    angles.loc[positions, cols] = np.nan
    angles.loc[positions, "quality"] = quality
    at = markers.frame.isin(angles.frame.to_numpy()[positions])
    markers.loc[at & (markers.marker == tip_name) if tip_name is not None else at, "quality"] = quality
    for r in positions:
        rows.tip_px.pop(int(r), None)
        rows.tip_cov.pop(int(r), None)


def streak_caveat(n: int, most: float, radius: float, exposure_s: float) -> str:
    """What ``n`` frames flagged ``streaked`` (:meth:`TrackRows.flag_streaks`; the tip moving up to ``most`` px
    during an exposure of ``exposure_s``, its image radius ``radius`` px) mean, and the exposure that would keep it a
    disc; '' when there are none."""
    if not n:
        return ""
    shorter = exposure_s * STREAK_RADII * radius / most
    return (f"the tip moves up to {most:.1f} px ({most / radius:.1f} of its image radii) during an exposure of "
            f"{exposure_s * 1e3:.3g} ms: in {n} frames it may be a streak, which the round spot fit does not describe "
            f"(flagged streaked; their error bars may be too small); an exposure of {shorter * 1e3:.2g} ms or less "
            "keeps it a disc")
