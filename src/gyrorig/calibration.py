"""Camera calibration from checkerboard images (``gyrorig calibrate``), with OpenCV.

Refuses a calibration too poor to use, and says why: too few views with the board
found, or a reprojection error above the limit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

__all__ = ["CalibrationError", "CalibrationInputError", "LENS_MODELS", "choose_lens_model", "CalibrationResult",
           "calibrate_camera", "intrinsics_covariance", "find_board_corners", "read_gray", "MIN_VIEWS", "MAX_RMS_PX",
           "INTRINSIC_PARAMETERS"]

MIN_VIEWS = 6
MAX_RMS_PX = 1.0
#: the intrinsics ``calibrate`` fits (k3 is held at 0), in the order of the covariance
INTRINSIC_PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"}
#: the lens models calibrate can fit, as OpenCV flags: k3 held at 0 (a dozen views at similar depths rarely
#: separate it from k1, k2), or free (short and wide-angle lenses)
LENS_MODELS = {"k1k2": cv2.CALIB_FIX_K3, "k1k2k3": 0}
#: k3 is freed only when the views it helps are this improbable under "k3 fits noise" (sign test)
LENS_CHOICE_P = 0.05


class CalibrationError(ValueError):
    """The images do not give a usable calibration; the message says why."""


class CalibrationInputError(CalibrationError):
    """The input is not a set of calibration images (none in the folder, mixed sizes): bad input."""


@dataclass(frozen=True)
class CalibrationResult:
    """Intrinsics and the per-image reprojection errors (RMS, px)."""

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    image_size: tuple[int, int]
    rms_px: float
    per_image_rms_px: dict[str, float]
    not_found: tuple[str, ...]
    #: covariance of ``intrinsics_parameters`` (fx, fy, cx, cy in px; k1, k2, p1, p2[, k3])
    intrinsics_covariance: np.ndarray | None = None
    #: the lens model used (:data:`LENS_MODELS`) and each candidate's held-out reprojection error (RMS, px)
    lens_model: str = "k1k2"
    held_out_rms_px: dict = field(default_factory=dict)

    @property
    def intrinsics_parameters(self) -> tuple[str, ...]:
        return INTRINSIC_PARAMETERS + (("k3",) if self.lens_model == "k1k2k3" else ())

    def to_json(self) -> dict:
        """OpenCV-convention camera file (no pose: add rvec/tvec of the camera relative to the pivot)."""
        return {"camera_matrix": self.camera_matrix.tolist(), "dist_coeffs": self.dist_coeffs.ravel().tolist(),
                "image_size": list(self.image_size), "calibration_rms_px": self.rms_px,
                "per_image_rms_px": self.per_image_rms_px, "board_not_found_in": list(self.not_found),
                "lens_model": self.lens_model, "held_out_rms_px": dict(self.held_out_rms_px),
                **({} if self.intrinsics_covariance is None else
                   {"intrinsics_parameters": list(self.intrinsics_parameters),
                    "intrinsics_covariance": self.intrinsics_covariance.tolist()})}


def read_gray(path: Path) -> np.ndarray | None:
    """An image as 8-bit grey (None when it cannot be read)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


def find_board_corners(gray: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """The board's ``cols x rows`` inner corners to sub-pixel precision (OpenCV's order), or None."""
    ok, corners = cv2.findChessboardCorners(gray, (cols, rows))
    if not ok:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    return cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), crit)


def _held_out_errors(objpoints, imgpoints, size, flags: int) -> np.ndarray:
    """Each view's reprojection RMS (px) under intrinsics calibrated on the other views (its pose by solvePnP)."""
    out = []
    for i in range(len(objpoints)):
        rest_o = objpoints[:i] + objpoints[i + 1:]
        rest_i = imgpoints[:i] + imgpoints[i + 1:]
        _, k, dist, _, _ = cv2.calibrateCamera(rest_o, rest_i, size, None, None, flags=flags)
        ok, rv, tv = cv2.solvePnP(objpoints[i], imgpoints[i], k, dist)
        proj = cv2.projectPoints(objpoints[i], rv, tv, k, dist)[0].reshape(-1, 2)
        out.append(float(np.sqrt(np.mean(np.sum((proj - imgpoints[i].reshape(-1, 2)) ** 2, axis=-1)))))
    return np.array(out)


def choose_lens_model(objpoints, imgpoints, size) -> tuple[str, dict[str, float]]:
    """The lens model the views choose: k3 is freed only when it lowers the held-out (leave-one-view-out)
    reprojection error of significantly many views (one-sided sign test, p < :data:`LENS_CHOICE_P`) and
    in total; a k3 that only fits noise makes held-out views slightly worse as often as better.  (A sign
    test, not a mean: the gain concentrates in the few views that reach the field's corners.)  Returns the
    model and each candidate's held-out RMS (px)."""
    from scipy.stats import binomtest

    err = {m: _held_out_errors(objpoints, imgpoints, size, f) for m, f in LENS_MODELS.items()}
    better = int(np.sum(err["k1k2k3"] < err["k1k2"]))
    p = binomtest(better, len(err["k1k2"]), 0.5, alternative="greater").pvalue
    rms = {m: float(np.sqrt(np.mean(e ** 2))) for m, e in err.items()}
    model = "k1k2k3" if p < LENS_CHOICE_P and rms["k1k2k3"] < rms["k1k2"] else "k1k2"
    return model, rms


def calibrate_camera(images_dir: str | Path, *, cols: int, rows: int, square_m: float,
                     lens_model: str = "auto") -> CalibrationResult:
    """Calibrate from checkerboard images (``cols x rows`` inner corners, squares of ``square_m``).

    ``lens_model``: ``"k1k2"`` (k3 held at 0), ``"k1k2k3"``, or ``"auto"`` (the views choose by held-out
    reprojection error, :func:`choose_lens_model`)."""
    if lens_model not in ("auto", *LENS_MODELS):
        raise CalibrationInputError(f"--lens-model {lens_model!r}: allowed auto, {', '.join(LENS_MODELS)}")
    images = sorted(p for p in Path(images_dir).iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES) \
        if Path(images_dir).is_dir() else []
    if not images:
        raise CalibrationInputError(f"no images (.png, .jpg, .tif, .bmp) in {images_dir}")
    obj = np.zeros((rows * cols, 3), np.float32)
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_m
    objpoints, imgpoints, names, not_found = [], [], [], []
    size = None
    loaded = []
    for path in images:
        img = read_gray(path)
        if img is None:
            not_found.append(path.name)
            continue
        if size is None:
            size = (img.shape[1], img.shape[0])
        elif size != (img.shape[1], img.shape[0]):
            raise CalibrationInputError(f"{path}: {img.shape[1]} x {img.shape[0]}, the others {size[0]} x {size[1]}")
        loaded.append((path, img))
    # the corner detector takes seconds per large image to give up on a board of the wrong size; the
    # sector-based detector says so in a fraction of a second: when it finds the board in no image,
    # the classic detector is not run
    if not any(cv2.findChessboardCornersSB(img, (cols, rows))[0] for _, img in loaded):
        not_found += [path.name for path, _ in loaded]
        loaded = []
    for path, img in loaded:
        corners = find_board_corners(img, cols, rows)
        if corners is None:
            not_found.append(path.name)
            continue
        objpoints.append(obj)
        imgpoints.append(corners)
        names.append(path.name)
    if len(objpoints) < MIN_VIEWS:
        raise CalibrationError(f"board {cols}x{rows} found in {len(objpoints)} of {len(images)} images; "
                               f"need at least {MIN_VIEWS} views (not found in: {', '.join(not_found) or '-'})")
    held_out: dict[str, float] = {}
    if lens_model == "auto":
        lens_model, held_out = choose_lens_model(objpoints, imgpoints, size)
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(objpoints, imgpoints, size, None, None,
                                                     flags=LENS_MODELS[lens_model])
    per = {}
    for name, o, ip, rv, tv in zip(names, objpoints, imgpoints, rvecs, tvecs):
        # OpenCV 5 returns corners as (N, 2), 4.x as (N, 1, 2): compare as (N, 2)
        proj = cv2.projectPoints(o, rv, tv, k, dist)[0].reshape(-1, 2)
        per[name] = float(np.sqrt(np.mean(np.sum((proj - ip.reshape(-1, 2)) ** 2, axis=-1))))
    if rms > MAX_RMS_PX:
        worst = max(per, key=per.get)
        raise CalibrationError(f"reprojection error {rms:.3g} px exceeds {MAX_RMS_PX} px (worst image {worst}: "
                               f"{per[worst]:.3g} px); check the board size and square size, or remove bad images")
    n_int = len(INTRINSIC_PARAMETERS) + (1 if lens_model == "k1k2k3" else 0)
    cov = intrinsics_covariance(objpoints, imgpoints, k, dist, rvecs, tvecs, n_int=n_int)
    return CalibrationResult(k, dist.ravel(), size, float(rms), per, tuple(not_found), cov, lens_model, held_out)


def intrinsics_covariance(objpoints, imgpoints, camera_matrix, dist_coeffs, rvecs, tvecs, n_int: int = 8
                          ) -> np.ndarray:
    """Covariance of the fitted intrinsics (the first ``n_int`` of fx, fy, cx, cy, k1, k2, p1, p2, k3), with
    their correlations.

    The calibration is a least-squares problem in the intrinsics and each view's pose; its
    Jacobian (from ``cv2.projectPoints``) gives the full covariance ``s^2 (J^T J)^-1``, with
    ``s^2`` the residual variance per coordinate.  The intrinsic block is the uncertainty of
    the camera model that tracking propagates into the angles.  (OpenCV's
    ``calibrateCameraExtended`` reports only the standard deviations; the correlations, e.g.
    between fx and fy or the principal point and the pose, matter for the propagation.)
    """
    n_views = len(objpoints)
    dist5 = np.zeros(5)
    d = np.asarray(dist_coeffs, float).ravel()
    dist5[:min(5, d.size)] = d[:5]
    blocks, resid = [], []
    for o, ip, rv, tv in zip(objpoints, imgpoints, rvecs, tvecs):
        proj, jac = cv2.projectPoints(o, rv, tv, camera_matrix, dist5)
        resid.append((ip.reshape(-1, 2) - proj.reshape(-1, 2)).ravel())
        # columns: rvec(3), tvec(3), fx, fy, cx, cy, k1, k2, p1, p2, k3
        blocks.append((jac[:, 6:6 + n_int], jac[:, :6]))
    rows = sum(b[0].shape[0] for b in blocks)
    J = np.zeros((rows, n_int + 6 * n_views))
    r0 = 0
    for v, (ji, je) in enumerate(blocks):
        J[r0:r0 + ji.shape[0], :n_int] = ji
        J[r0:r0 + ji.shape[0], n_int + 6 * v:n_int + 6 * v + 6] = je
        r0 += ji.shape[0]
    r = np.concatenate(resid)
    s2 = float(r @ r) / max(rows - J.shape[1], 1)
    cov = s2 * np.linalg.pinv(J.T @ J, hermitian=True)
    return cov[:n_int, :n_int]
