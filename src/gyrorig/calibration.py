"""Camera calibration from checkerboard images (``gyrorig calibrate``), with OpenCV.

Refuses a calibration too poor to use, and says why: too few views with the board
found, or a reprojection error above the limit.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

__all__ = ["CalibrationError", "CalibrationResult", "calibrate_camera", "MIN_VIEWS", "MAX_RMS_PX"]

MIN_VIEWS = 6
MAX_RMS_PX = 1.0
_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"}


class CalibrationError(ValueError):
    """The images do not give a usable calibration; the message says why."""


@dataclass(frozen=True)
class CalibrationResult:
    """Intrinsics and the per-image reprojection errors (RMS, px)."""

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    image_size: tuple[int, int]
    rms_px: float
    per_image_rms_px: dict[str, float]
    not_found: tuple[str, ...]

    def to_json(self) -> dict:
        """OpenCV-convention camera file (no pose: add rvec/tvec of the camera relative to the pivot)."""
        return {"camera_matrix": self.camera_matrix.tolist(), "dist_coeffs": self.dist_coeffs.ravel().tolist(),
                "image_size": list(self.image_size), "calibration_rms_px": self.rms_px,
                "per_image_rms_px": self.per_image_rms_px, "board_not_found_in": list(self.not_found)}


def calibrate_camera(images_dir: str | Path, *, cols: int, rows: int, square_m: float) -> CalibrationResult:
    """Calibrate from checkerboard images (``cols x rows`` inner corners, squares of ``square_m``)."""
    images = sorted(p for p in Path(images_dir).iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES) \
        if Path(images_dir).is_dir() else []
    if not images:
        raise CalibrationError(f"no images (.png, .jpg, .tif, .bmp) in {images_dir}")
    obj = np.zeros((rows * cols, 3), np.float32)
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_m
    objpoints, imgpoints, names, not_found = [], [], [], []
    size = None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    for path in images:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            not_found.append(path.name)
            continue
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if img.dtype != np.uint8:
            img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
        if size is None:
            size = (img.shape[1], img.shape[0])
        elif size != (img.shape[1], img.shape[0]):
            raise CalibrationError(f"{path.name} is {img.shape[1]} x {img.shape[0]}, the others {size[0]} x {size[1]}")
        ok, corners = cv2.findChessboardCorners(img, (cols, rows))
        if not ok:
            not_found.append(path.name)
            continue
        corners = cv2.cornerSubPix(img, corners, (5, 5), (-1, -1), crit)
        objpoints.append(obj)
        imgpoints.append(corners)
        names.append(path.name)
    if len(objpoints) < MIN_VIEWS:
        raise CalibrationError(f"board {cols}x{rows} found in {len(objpoints)} of {len(images)} images; "
                               f"need at least {MIN_VIEWS} views (not found in: {', '.join(not_found) or '-'})")
    # k3 is fixed at 0: a dozen views at similar depths cannot separate it from k1, k2 (it overfits)
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(objpoints, imgpoints, size, None, None,
                                                     flags=cv2.CALIB_FIX_K3)
    per = {}
    for name, o, ip, rv, tv in zip(names, objpoints, imgpoints, rvecs, tvecs):
        # OpenCV 5 returns corners as (N, 2), 4.x as (N, 1, 2): compare as (N, 2)
        proj = cv2.projectPoints(o, rv, tv, k, dist)[0].reshape(-1, 2)
        per[name] = float(np.sqrt(np.mean(np.sum((proj - ip.reshape(-1, 2)) ** 2, axis=-1))))
    if rms > MAX_RMS_PX:
        worst = max(per, key=per.get)
        raise CalibrationError(f"reprojection error {rms:.3g} px exceeds {MAX_RMS_PX} px (worst image {worst}: "
                               f"{per[worst]:.3g} px); check the board size and square size, or remove bad images")
    return CalibrationResult(k, dist.ravel(), size, float(rms), per, tuple(not_found))
