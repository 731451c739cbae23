"""What the fit is given: the measured frames with their covariances (:class:`FitData`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..smooth import measurement_covariance
from ..tables import camera_mode_columns, camera_mode_count, camera_mode_prior_column, missing_columns
from .constraints import Constraints
from ..stillness import StillEnds, angle_still_ends

__all__ = ["FitError", "FitConvergenceError", "FitData", "fit_data_from_angles", "FIT_REQUIRED"]

#: columns the fit needs of an angle table (``theta_phi_corr``, ``frame``, ``exposure_s``, ``frame_type`` and the
#: camera modes are used when present)
FIT_REQUIRED = ("t_s", "theta_rad", "phi_rad", "theta_sigma_rad", "phi_sigma_rad")


class FitError(ValueError):
    """The angles cannot be fitted (missing columns, too few frames for the model, no data)."""


class FitConvergenceError(FitError):
    """The least squares found no minimum: a failed computation (the command line exits 3), not bad input."""

    exit_code = 3


@dataclass(frozen=True)
class FitData:
    """Measurements for the fit: times, angles and the covariance of each frame."""

    frame: np.ndarray
    t_s: np.ndarray
    theta_rad: np.ndarray
    phi_rad: np.ndarray
    cov: np.ndarray  # (n, 2, 2)
    segment: np.ndarray  # (n,) int
    t_ref_s: float
    #: (m, n, 2) angle shifts (theta, phi) of each frame for a one-sigma move of camera mode k
    camera_shift: np.ndarray | None = None
    #: (m,) per camera mode, from the table's ``cam_k_prior``: 1, its sigma is knowledge from outside the
    #: record; 0, a move of a pose found from this record's own tip motion; None: all 1
    camera_prior: np.ndarray | None = None
    #: (m, m) the camera modes' prior residuals are ``camera_prior_root @ a``; None: the identity (unit priors)
    camera_prior_root: np.ndarray | None = None
    #: (n,) exposure of each frame [s], ``t_s`` at its middle: the model is averaged over it
    #: (a blurred spot's centroid is the mean position over the exposure, which shrinks an
    #: oscillation of angular frequency w by sinc(w T / 2)); None: instantaneous samples
    exposure_s: np.ndarray | None = None
    #: parameters held fixed or given priors (outside information about the record's parameters)
    constraints: Constraints = Constraints()
    #: (n,) frames a lossy codec coded as bi-predicted (B) pictures, from the table's ``frame_type``; None when the
    #: table does not say, or when the record lacks either kind (:data:`MIN_PICTURES` of each)
    b_frame: np.ndarray | None = None
    #: the table's ``frame_type`` shows predicted (P or B) pictures: a lossy codec coded most frames from others
    inter_coded: bool = False
    #: (n,) where in the frame each tip was read out (its row over the frame's height), from the table's
    #: ``row_fraction``: a rolling shutter whose readout time is not known, which the fit finds
    #: (:class:`~gyrorig.fit.terms.RollingShutter`); None when the table does not have it
    row_fraction: np.ndarray | None = None
    #: the record's still ends left out (a top held before its release, caught before the recording ends:
    #: :mod:`gyrorig.stillness`); None when they were not looked for
    still: StillEnds | None = None

    @property
    def rolling_shutter(self) -> bool:
        """Whether the frames' times lack their rows' delay under a rolling shutter (its readout fitted)."""
        return self.row_fraction is not None

    @property
    def b_frames(self) -> bool:
        """Whether the record has B pictures beside others (their fast motion's shrink can be fitted)."""
        return self.b_frame is not None

    @property
    def camera_modes(self) -> int:
        return 0 if self.camera_shift is None else int(self.camera_shift.shape[0])

    @property
    def n(self) -> int:
        return len(self.t_s)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    @property
    def tau(self) -> np.ndarray:
        """Times relative to the reference time (the middle of the record). [s]"""
        return self.t_s - self.t_ref_s

    def longest_run_s(self, max_gap_s: float) -> float:
        """The longest stretch of frames whose spacing never exceeds ``max_gap_s``, as a duration (its span
        plus one frame interval). [s]"""
        if len(self.t_s) < 2:
            return 0.0
        dt = np.diff(self.t_s)
        breaks = np.flatnonzero(dt > max_gap_s)
        starts = np.concatenate([[0], breaks + 1])
        ends = np.concatenate([breaks, [len(self.t_s) - 1]])
        return float(np.max(self.t_s[ends] - self.t_s[starts]) + np.median(dt))

    @property
    def nyquist_rad_s(self) -> float:
        dt = float(np.median(np.diff(self.t_s)))
        return math.pi / dt


def _camera_shifts(a: pd.DataFrame) -> np.ndarray | None:
    k_modes = camera_mode_count(a.columns)
    if not k_modes:
        return None
    shift = np.stack([np.column_stack([a[c].to_numpy(float) for c in camera_mode_columns(k)])
                      for k in range(1, k_modes + 1)])
    if not np.all(np.isfinite(shift)):
        raise FitError("theta_cam_k_rad / phi_cam_k_rad (camera modes) must be finite wherever there are angles")
    return shift


def _camera_priors(a: pd.DataFrame, k_modes: int) -> np.ndarray | None:
    """Each mode's ``cam_k_prior`` (1 without the column); FitError for anything but a constant 0 or 1."""
    if not k_modes:
        return None
    out = np.ones(k_modes)
    for k in range(1, k_modes + 1):
        col = camera_mode_prior_column(k)
        if col in a.columns:
            v = np.unique(a[col].to_numpy(float))
            if len(v) != 1 or v[0] not in (0.0, 1.0):
                raise FitError(f"{col} must be 0 (mode found from the frames) or 1 (unit prior), the same in every "
                               f"row; found {v[:4].tolist()}")
            out[k - 1] = v[0]
    return out


def _exposures(a: pd.DataFrame, t: np.ndarray) -> np.ndarray | None:
    if "exposure_s" not in a.columns:
        return None
    exposure = a["exposure_s"].to_numpy(float)
    if not (np.all(np.isfinite(exposure)) and np.all(exposure >= 0)):
        raise FitError("exposure_s must be finite and >= 0 wherever there are angles")
    frame_interval = float(np.median(np.diff(t))) if len(t) > 1 else np.inf
    if np.any(exposure > 1.5 * frame_interval):
        raise FitError(f"exposure_s reaches {exposure.max():.3g} s, longer than the frame interval "
                       f"({frame_interval:.3g} s, median): not an exposure time")
    return exposure


#: a record's B pictures are told from its others (their shrink fitted) with at least this many of each kind
MIN_PICTURES = 10


def _picture_types(a: pd.DataFrame) -> tuple[np.ndarray | None, bool]:
    """The B pictures (None unless there are :data:`MIN_PICTURES` of them and of the others), and whether any frame
    is a predicted (P or B) picture."""
    if "frame_type" not in a.columns:
        return None, False
    kind = a["frame_type"].astype(str).str.strip().str.upper().to_numpy()
    b = kind == "B"
    inter = bool(np.any(b | (kind == "P")))
    return (b if MIN_PICTURES <= int(b.sum()) <= len(b) - MIN_PICTURES else None), inter


def fit_data_from_angles(angles: pd.DataFrame, exclude: np.ndarray | None = None,
                         precession_hint_rad_s: float | None = None, constraints: Constraints | None = None, *,
                         leave_out_still_ends: bool = False) -> FitData:
    """The measured frames of an angle table (:mod:`gyrorig.tables`), minus ``exclude`` (e.g. the
    smoother's outliers) and, with ``leave_out_still_ends``, minus the record's still ends (:mod:`gyrorig.stillness`:
    a top held before its release).  A gap longer than half a precession period (``precession_hint_rad_s``)
    starts a new azimuth segment."""
    missing = missing_columns(angles, FIT_REQUIRED)
    if missing:
        raise FitError(f"angle table lacks column(s) {missing}; required: {list(FIT_REQUIRED)}")
    ok = np.isfinite(angles["theta_rad"].to_numpy(float)) & np.isfinite(angles["phi_rad"].to_numpy(float))
    if exclude is not None:
        ok &= ~np.asarray(exclude, bool)
    a = angles.loc[ok]
    if len(a) < 10:
        raise FitError(f"only {len(a)} frames have usable angles; a fit needs at least 10")
    sth = a["theta_sigma_rad"].to_numpy(float)
    sph = a["phi_sigma_rad"].to_numpy(float)
    if not (np.all(np.isfinite(sth)) and np.all(np.isfinite(sph)) and np.all(sth > 0) and np.all(sph > 0)):
        raise FitError("theta_sigma_rad and phi_sigma_rad must be finite and > 0 wherever there are angles")
    theta = a["theta_rad"].to_numpy(float)
    outside = np.flatnonzero((theta < -5 * sth) | (theta > math.pi + 5 * sth))
    if len(outside):
        i = int(outside[0])
        degrees = bool(np.all((theta >= -1.0) & (theta <= 181.0)) and np.max(theta) > math.pi)
        raise FitError(f"theta_rad = {theta[i]:.6g} in row {i + 1} of the measured frames ({len(outside)} rows "
                       f"outside the range): theta is a tilt from the vertical, allowed [0, pi] rad"
                       + ("; the column looks like degrees (convert theta, phi and their sigmas with radians())"
                          if degrees else ""))
    cov = measurement_covariance(sth, sph, a["theta_phi_corr"] if "theta_phi_corr" in a.columns else None)
    t = a["t_s"].to_numpy(float)
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise FitError("t_s must be finite and non-decreasing")
    still = None
    if leave_out_still_ends:
        still = angle_still_ends(t, theta, a["phi_rad"].to_numpy(float), sth, sph)
        if still.any:
            if int(still.keep.sum()) < 10:
                raise FitError(f"only {int(still.keep.sum())} frames lie between the record's still ends (the tip "
                               "held still before its release, or caught at the end); a fit needs at least 10")
            a, cov, t = a.loc[still.keep], cov[still.keep], t[still.keep]
    frame = a["frame"].to_numpy() if "frame" in a.columns else np.arange(len(a))
    segment = np.zeros(len(a), int)
    if precession_hint_rad_s is not None and precession_hint_rad_s != 0:
        half_period = math.pi / abs(precession_hint_rad_s)
        segment = np.concatenate([[0], np.cumsum(np.diff(t) > half_period)])
    b_frame, inter_coded = _picture_types(a)
    return FitData(frame=frame, t_s=t, theta_rad=a["theta_rad"].to_numpy(float), phi_rad=a["phi_rad"].to_numpy(float),
                   cov=cov, segment=segment, t_ref_s=0.5 * (t[0] + t[-1]), camera_shift=_camera_shifts(a),
                   camera_prior=_camera_priors(a, camera_mode_count(a.columns)),
                   exposure_s=_exposures(a, t), constraints=constraints or Constraints(), b_frame=b_frame,
                   inter_coded=inter_coded, row_fraction=_row_fractions(a), still=still)


def _row_fractions(a: pd.DataFrame) -> np.ndarray | None:
    """The table's ``row_fraction`` (None without it); each in [0, 1] (a row of the frame over its height)."""
    if "row_fraction" not in a.columns:
        return None
    rows = a["row_fraction"].to_numpy(float)
    bad = np.flatnonzero(~(np.isfinite(rows) & (rows >= -0.01) & (rows <= 1.01)))
    if len(bad):
        raise FitError(f"row_fraction = {rows[bad[0]]!r} in row {int(bad[0]) + 1} of the measured frames: a tip's "
                       "row over the frame's height, allowed [0, 1] wherever there are angles")
    return rows
