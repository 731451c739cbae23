"""The camera pose from one checkerboard image with the board at a known place (``gyrorig pose --board-image``).

The board lies face up (on the table, or on a plate at a stated height): its first inner corner
(OpenCV's object-point origin) at ``origin_m`` in the pivot frame, its x axis (along its ``cols``
corners) at azimuth ``yaw_rad`` from lab x (:func:`gyrorig.geometry.board_lab_rotation`).  The
pose is the PnP solution of the corners with those lab positions.

**Which corner is the origin.**  OpenCV returns the corners in one of four orders (either end
of either side first).  A board with an even number of squares along one side and an odd number
along the other (9 x 6 inner corners: 10 x 7 squares) has its two dark corner squares on one short
side: of the four orders, two start beside a dark corner square, and of those only one sees the
printed side (the other is the mirror image, whose pose puts the camera behind the board).  Boards
with both counts even or both odd are point-symmetric and refused.

**Uncertainty.**  The pose covariance is the corners' localisation (their scatter about the
fitted projection) plus the placement's stated uncertainty (origin, yaw, the table's tilt), each
propagated through the PnP solution.  The corners' lab positions and pixels go into the camera
file as ``pose_points``, so that the tracker re-solves the pose when it moves the intrinsics
within their covariance (:func:`gyrorig.tracking.pose.camera_modes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .calibration import CalibrationInputError, find_board_corners, read_gray
from .geometry import board_lab_rotation, same_rotation_near
from .tracking.pose import pose_covariance_from_points

__all__ = ["BoardPlacement", "BoardPose", "pose_from_board", "check_board_asymmetric"]

#: the corners' reprojection RMS above which the board image is refused (a wrong board size or square, a
#: bent board, or intrinsics that do not belong to this camera)
MAX_POSE_RMS_PX = 1.0


@dataclass(frozen=True)
class BoardPlacement:
    """Where the board lies in the pivot frame, and how well that is known (one standard deviation)."""

    origin_m: tuple[float, float, float]
    yaw_rad: float = 0.0
    #: each coordinate of the origin [m]
    origin_sd_m: float = 0.0
    yaw_sd_rad: float = 0.0
    #: the board's tilt from horizontal about each lab axis (the table's level) [rad]
    tilt_sd_rad: float = 0.0

    def lab_points(self, board_points: np.ndarray, delta: np.ndarray | None = None) -> np.ndarray:
        """Board points in the lab; ``delta`` = (dx, dy, dz, dyaw, tilt about x, tilt about y) moves the board."""
        d = np.zeros(6) if delta is None else np.asarray(delta, float)
        rot = board_lab_rotation(self.yaw_rad + d[3])
        if d[4] or d[5]:
            rot = cv2.Rodrigues(np.array([d[4], d[5], 0.0]))[0] @ rot
        return board_points @ rot.T + np.asarray(self.origin_m, float) + d[:3]

    @property
    def sd(self) -> np.ndarray:
        return np.array([self.origin_sd_m] * 3 + [self.yaw_sd_rad] + [self.tilt_sd_rad] * 2)

    def to_json(self) -> dict:
        return {"origin_mm": [v * 1e3 for v in self.origin_m], "yaw_deg": math.degrees(self.yaw_rad),
                "origin_sd_mm": self.origin_sd_m * 1e3, "yaw_sd_deg": math.degrees(self.yaw_sd_rad),
                "tilt_sd_deg": math.degrees(self.tilt_sd_rad)}


@dataclass(frozen=True)
class BoardPose:
    """The camera pose relative to the pivot (lab -> camera, OpenCV) found from a board at a known place."""

    rvec: np.ndarray
    tvec: np.ndarray
    #: covariance of (rvec, tvec): the corners' localisation plus the placement's uncertainty
    covariance: np.ndarray
    #: the part from the placement alone
    placement_covariance: np.ndarray
    object_points_m: np.ndarray
    image_points_px: np.ndarray
    rms_px: float
    placement: BoardPlacement

    def camera_fields(self, image: str) -> dict:
        """The keys this pose adds to ``camera.json``."""
        return {"rvec": self.rvec.tolist(), "tvec": self.tvec.tolist(), "pose_covariance": self.covariance.tolist(),
                "pose_points": {"object_points_m": self.object_points_m.tolist(),
                                "image_points_px": self.image_points_px.tolist()},
                "pose_source": {"method": "board at a known place", "image": image, "rms_px": self.rms_px,
                                "placement": self.placement.to_json(),
                                "sigma_rvec_rad": np.sqrt(np.diag(self.covariance[:3, :3])).tolist(),
                                "sigma_tvec_m": np.sqrt(np.diag(self.covariance[3:, 3:])).tolist(),
                                "placement_share_of_variance": float(np.trace(self.placement_covariance)
                                                                     / max(np.trace(self.covariance), 1e-300))}}


def check_board_asymmetric(cols: int, rows: int) -> None:
    """Refuse a board whose corner order cannot be told from its image (see the module's notes)."""
    if (cols + 1) % 2 == (rows + 1) % 2:
        raise CalibrationInputError(
            f"--board {cols}x{rows}: {cols + 1} x {rows + 1} squares look the same turned half round, so the "
            "board's origin is ambiguous; for a pose use a board with an even number of squares along one side "
            "and an odd number along the other (an odd and an even count of inner corners, e.g. 9x6)")


def _mean_level(gray: np.ndarray, xy: np.ndarray, half: int) -> float:
    x, y = int(round(xy[0])), int(round(xy[1]))
    h, w = gray.shape
    if not (0 <= x < w and 0 <= y < h):
        return math.nan
    return float(gray[max(y - half, 0):y + half + 1, max(x - half, 0):x + half + 1].mean())


def order_corners(gray: np.ndarray, corners: np.ndarray, cols: int, rows: int, obj_board: np.ndarray,
                  camera_matrix: np.ndarray, dist_coeffs: np.ndarray) -> np.ndarray:
    """The corners in the order of ``obj_board``: the origin beside a dark corner square, the printed side seen."""
    grid = corners.reshape(rows, cols, 2)
    found = []
    for flip_rows in (False, True):
        for flip_cols in (False, True):
            g = grid[::-1 if flip_rows else 1, ::-1 if flip_cols else 1]
            c0, dx, dy = g[0, 0], g[0, 1] - g[0, 0], g[1, 0] - g[0, 0]
            half = max(1, int(0.15 * min(np.linalg.norm(dx), np.linalg.norm(dy))))
            outer = _mean_level(gray, c0 - 0.5 * dx - 0.5 * dy, half)  # the corner square
            beside = _mean_level(gray, c0 + 0.5 * dx - 0.5 * dy, half)  # its neighbour, the other colour
            if not outer < beside:
                continue
            pts = g.reshape(-1, 2)
            ok, rv, tv = cv2.solvePnP(obj_board, pts, camera_matrix, dist_coeffs, flags=cv2.SOLVEPNP_IPPE)
            centre_board = -cv2.Rodrigues(rv)[0].T @ tv.ravel()
            if ok and centre_board[2] < 0:  # OpenCV's board z points away from a viewer of the printed side
                found.append(pts)
    if len(found) != 1:
        raise CalibrationInputError(
            f"the board's origin corner cannot be told in the image ({len(found)} of the 4 corner orders fit a dark "
            "corner square seen from the printed side): is the whole board, with its margin, in view and lit evenly?")
    return found[0]


def pose_from_board(image: str | Path, camera_matrix: np.ndarray, dist_coeffs: np.ndarray, *, cols: int, rows: int,
                    square_m: float, placement: BoardPlacement) -> BoardPose:
    """The camera's pose relative to the pivot from one image of a board lying at ``placement``.

    Raises :class:`gyrorig.calibration.CalibrationInputError` (bad input) for an unreadable image, a board
    not found or not told apart from its turned copy, or corners that do not fit (RMS above
    :data:`MAX_POSE_RMS_PX`)."""
    check_board_asymmetric(cols, rows)
    gray = read_gray(Path(image))
    if gray is None:
        raise CalibrationInputError(f"{image}: not a readable image")
    corners = find_board_corners(gray, cols, rows)
    if corners is None:
        raise CalibrationInputError(f"{image}: no {cols}x{rows} board found")
    obj_board = np.zeros((rows * cols, 3))
    obj_board[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_m
    k, dist = np.asarray(camera_matrix, float), np.asarray(dist_coeffs, float).ravel()
    img = order_corners(gray, corners.reshape(-1, 2).astype(np.float64), cols, rows, obj_board, k, dist)
    obj = placement.lab_points(obj_board)
    rvec, tvec = _solve(obj, img, k, dist)
    proj = cv2.projectPoints(obj, rvec, tvec, k, dist)[0].reshape(-1, 2)
    resid = img - proj
    rms = float(np.sqrt(np.mean(np.sum(resid ** 2, axis=1))))
    if rms > MAX_POSE_RMS_PX:
        raise CalibrationInputError(f"{image}: the board's corners fit with {rms:.3g} px RMS (limit {MAX_POSE_RMS_PX} "
                                    "px): check --board and that the camera file is this camera's (a wrong --square-mm cannot show in one "
                                    "image: a larger board farther away projects the same)")
    # each corner's variance per coordinate from the scatter about the fit (2N - 6 degrees of freedom)
    s2 = max(float(np.sum(resid ** 2)) / max(2 * len(obj) - 6, 1), 1e-8)
    cov_corners = pose_covariance_from_points(obj, img, [s2 * np.eye(2)] * len(obj), k, dist, rvec, tvec)
    cov_place = _placement_covariance(obj_board, img, placement, k, dist, rvec, tvec)
    return BoardPose(rvec, tvec, cov_corners + cov_place, cov_place, obj, img, rms, placement)


def _solve(obj: np.ndarray, img: np.ndarray, k: np.ndarray, dist: np.ndarray, guess=None):
    if guess is None:
        ok, rv, tv = cv2.solvePnP(obj, img, k, dist, flags=cv2.SOLVEPNP_SQPNP)
    else:
        rv, tv = (g.copy().reshape(3, 1) for g in guess)
    ok, rv, tv = cv2.solvePnP(obj, img, k, dist, rv, tv, useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    rv = rv.ravel()
    if guess is not None:
        rv = same_rotation_near(rv, guess[0])
    return rv, tv.ravel()


def _placement_covariance(obj_board, img, placement: BoardPlacement, k, dist, rvec, tvec) -> np.ndarray:
    """The pose's covariance from the placement's uncertainty: central differences of the PnP solution."""
    sd = placement.sd
    jac = np.zeros((6, 6))
    for j in np.flatnonzero(sd > 0):
        d = np.zeros(6)
        d[j] = sd[j]
        plus = np.concatenate(_solve(placement.lab_points(obj_board, d), img, k, dist, (rvec, tvec)))
        minus = np.concatenate(_solve(placement.lab_points(obj_board, -d), img, k, dist, (rvec, tvec)))
        jac[:, j] = 0.5 * (plus - minus)  # per one sd
    return jac @ jac.T
