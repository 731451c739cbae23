"""The tables stages pass along: column names in one place, and the check that a table has them.

**Angle table** (``angles.csv``, written by the tracker, read by the smoother and the fit):
``frame, t_s`` (mid-exposure time; with a rolling shutter plus the tip's row delay),
``theta_rad, phi_rad`` (unwrapped), ``theta_sigma_rad, phi_sigma_rad, theta_phi_corr``,
``tip_x, tip_y, tip_z`` (unit tip vector), ``quality`` (:data:`QUALITY_FLAGS`, comma-separated
when several apply); then, when present, ``psi_rad, psi_sigma_rad`` (the frame's angle about
the axis), ``exposure_s`` (the angles are averaged over it), ``row_fraction`` (the tip's row over the frame's
height, under a rolling shutter whose readout camera.json does not state: the fit finds it) and ``theta_cam_k_rad,
phi_cam_k_rad`` for each camera-model mode ``k = 1, 2, ...`` (each frame's angle shift for a
one-sigma move of that mode) with ``cam_k_prior`` (the same in every row: 1 when the mode's sigma is
knowledge from outside the record, a calibration or a pose from fiducials or a board, which the fit
takes as a unit Gaussian prior; 0 when the pose was found from this record's own tip motion, so
that the fit keeps only the part of that prior the frames do not hold; a table without the column: 1).

**Marker table** (``markers.csv``): one row per detected marker and frame, :data:`MARKER_COLUMNS`.

**Truth table** (``truth.csv``, written by the renderer beside its video, never read by the tracker):
``frame, t_s`` (mid-exposure), ``marker, x_px, y_px, visible, theta_rad, phi_rad, t_marker_s``
(the marker's own mid-exposure time, which a rolling shutter moves; the marker's position and the
tip's angles on its row are at that time) ``, in_view``; :func:`tip_truth` turns it into the noiseless
tip angles a fit compares with.
"""

from __future__ import annotations

from collections.abc import Iterable

import pandas as pd

__all__ = ["ANGLE_COLUMNS", "ANGLE_REQUIRED", "MARKER_COLUMNS", "QUALITY_FLAGS", "camera_mode_columns",
           "camera_mode_prior_column", "camera_mode_count", "missing_columns", "quality_counts", "tip_truth"]

ANGLE_COLUMNS = ("frame", "t_s", "theta_rad", "phi_rad", "theta_sigma_rad", "phi_sigma_rad", "theta_phi_corr",
                 "tip_x", "tip_y", "tip_z", "quality")
#: what the smoother needs of an angle table (the fit needs the same but ``frame``)
ANGLE_REQUIRED = ("frame", "t_s", "theta_rad", "phi_rad", "theta_sigma_rad", "phi_sigma_rad")
MARKER_COLUMNS = ("frame", "t_s", "marker", "x_px", "y_px", "sigma_x_px", "sigma_y_px", "radius_px",
                  "amplitude_adu", "background_adu", "chi2_red", "quality")
#: ``ok``; ``blended`` (fitted jointly with a neighbouring spot); ``saturated``; ``reacquired`` (found
#: by a full-frame search after a loss); ``missing`` (no position: a gap); ``off-sphere`` (the ray
#: misses the tip's sphere); ``duplicate`` (a repeated frame, or a codec's copy of the tip's picture, whose motion is
#: unknown); ``outlier`` (off the tip's smooth path by more
#: than 5 of its errors: angles removed, see :mod:`gyrorig.tracking.scatter`); ``damaged`` (the decoder reported
#: damaged data in this picture or one it is predicted from: angles removed, see :mod:`gyrorig.tracking.sources`);
#: ``off-pace`` (in an end of a slow-motion record that runs at another pace, a gallery copy's normal-speed end:
#: its time unknown, angles removed, see :mod:`gyrorig.tracking.pace`); ``copied`` (the tip's pixels bit for bit
#: another frame's, a codec's skipped block or a whole picture repeated: its error holds the tip's motion between
#: them, see :mod:`gyrorig.tracking.copies`); ``streaked`` (the tip moved more than its image radius during the exposure: a
#: streak, which the round spot fit does not describe; its error bars may be too small, see
#: :meth:`gyrorig.tracking.rows.TrackRows.flag_streaks`); ``near-limb`` (every tracked frame of a record whose tip
#: came near the limb of its sphere as the camera sees it, beyond which a tip is read at the wrong one of the two
#: points its ray meets: see :func:`gyrorig.tracking.rays.limb_flags`)
QUALITY_FLAGS = ("ok", "blended", "saturated", "reacquired", "missing", "off-sphere", "duplicate", "outlier",
                 "damaged", "off-pace", "copied", "streaked", "near-limb")


def camera_mode_columns(k: int) -> tuple[str, str]:
    """The (theta, phi) columns of camera-model mode ``k`` (1-based)."""
    return f"theta_cam_{k}_rad", f"phi_cam_{k}_rad"


def camera_mode_prior_column(k: int) -> str:
    """The column saying whether camera-model mode ``k`` (1-based) is knowledge from outside the record (1) or a
    move of a pose found from the record's own frames (0)."""
    return f"cam_{k}_prior"


def camera_mode_count(columns: Iterable[str]) -> int:
    """How many consecutive camera-model modes (1, 2, ...) a table has both columns of."""
    cols = set(columns)
    k = 0
    while all(c in cols for c in camera_mode_columns(k + 1)):
        k += 1
    return k


def missing_columns(table: pd.DataFrame, required: Iterable[str]) -> list[str]:
    """The required columns the table lacks (in the order given)."""
    return [c for c in required if c not in table.columns]


def quality_counts(angles: pd.DataFrame) -> dict[str, int]:
    """How many frames carry each tracking ``quality`` flag (a frame may carry several)."""
    return angles["quality"].fillna("").str.split(",").explode().value_counts().to_dict()


def tip_truth(truth: pd.DataFrame, marker: str = "tip") -> pd.DataFrame:
    """The noiseless angles of one marker from a truth table: ``t_s, theta_rad, phi_rad``, at the marker's
    own mid-exposure times (``t_marker_s``, which a rolling shutter moves) when the table has them.

    Raises ValueError naming the missing columns, or when the marker has no rows.
    """
    missing = missing_columns(truth, ("t_s", "theta_rad", "phi_rad"))
    if missing:
        raise ValueError(f"truth table lacks column(s) {missing}")
    if "marker" in truth.columns:
        truth = truth[truth["marker"] == marker]
        if truth.empty:
            raise ValueError(f"truth table has no rows for marker {marker!r}")
    truth = truth.copy()
    if "t_marker_s" in truth.columns:
        truth["t_s"] = truth["t_marker_s"]
    return truth[["t_s", "theta_rad", "phi_rad"]].reset_index(drop=True)
