"""``camera.json``: what the tracker needs to know about the camera (OpenCV conventions).

Written by ``gyrorig render`` (intrinsics, pose, sensor) or ``gyrorig calibrate`` (intrinsics
and their covariance, no pose).  A lab point ``X`` maps to ``R(rvec) X + tvec``, then through
the pinhole ``camera_matrix`` and the distortion ``dist_coeffs`` to pixels.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from .. import _io
from ..camera import INTRINSIC_PARAMETERS, Camera, Sensor
from .errors import CameraFileError
from .fields import INTERLACE_MODES
from .transfer import TRANSFERS

__all__ = ["load_camera"]

#: lengths of ``dist_coeffs`` OpenCV accepts (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]])
DIST_COEFFS_LENGTHS = (4, 5, 8, 12, 14)


def _array(path, key, value, shape) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise CameraFileError(f"{path}: {key} = {value!r}: expected numbers of shape {shape}") from None
    if a.shape != shape and a.size != int(np.prod(shape)):
        raise CameraFileError(f"{path}: {key} has shape {a.shape}; expected {shape}")
    if not np.all(np.isfinite(a)):
        raise CameraFileError(f"{path}: {key} must be finite (no NaN or inf)")
    return a.reshape(shape)


def _scalar(path, key, value, lo: float, *, lo_open: bool = False, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CameraFileError(f"{path}: {key} = {value!r}: expected a number")
    v = float(value)
    if not (math.isfinite(v) and (v > lo if lo_open else v >= lo) and v <= hi):
        left = "(" if lo_open else "["
        raise CameraFileError(f"{path}: {key} = {value!r} is out of range; allowed {left}{lo:g}, {hi:g}]")
    return v


def _check_camera_values(path: Path, d: dict) -> None:
    """Every value the tracker uses, against its allowed range (the file and the key named)."""
    k = _array(path, "camera_matrix", d["camera_matrix"], (3, 3))
    if not (k[0, 0] > 0 and k[1, 1] > 0 and np.allclose(k[2], [0, 0, 1]) and k[1, 0] == 0):
        raise CameraFileError(f"{path}: camera_matrix must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    try:  # a flat list, or OpenCV's 1 x n or n x 1 array
        n_dist = np.asarray(d["dist_coeffs"], dtype=float).size
    except (TypeError, ValueError):
        n_dist = -1
    if n_dist not in DIST_COEFFS_LENGTHS:
        raise CameraFileError(f"{path}: dist_coeffs must hold {', '.join(map(str, DIST_COEFFS_LENGTHS))} "
                              "numbers (k1 k2 p1 p2 [k3 ...], OpenCV's order)")
    _array(path, "dist_coeffs", d["dist_coeffs"], (n_dist,))
    size = d["image_size"]
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
        raise CameraFileError(f"{path}: image_size = {size!r}: expected [width, height], positive integers")
    for key in ("rvec", "tvec"):
        if key in d:
            _array(path, key, d[key], (3,))
    if "rvec" in d and "tvec" in d:
        if float(np.asarray(d["tvec"], float).ravel()[2]) <= 0:
            raise CameraFileError(f"{path}: the pose (rvec, tvec) puts the pivot behind the camera (tvec z <= 0)")
    if "fps" in d:
        _scalar(path, "fps", d["fps"], 0.0, lo_open=True, hi=1e6)
    if "exposure_s" in d:
        _scalar(path, "exposure_s", d["exposure_s"], 0.0, hi=10.0)
    if "capture_fps" in d:
        _scalar(path, "capture_fps", d["capture_fps"], 0.0, lo_open=True, hi=1e6)
    if d.get("shutter", "global") not in ("global", "rolling"):
        raise CameraFileError(f"{path}: shutter = {d['shutter']!r}: allowed 'global', 'rolling'")
    if d.get("readout_time_s") is not None:
        _scalar(path, "readout_time_s", d["readout_time_s"], 0.0, hi=10.0)
    if d.get("interlace", "auto") not in INTERLACE_MODES:
        raise CameraFileError(f"{path}: interlace = {d['interlace']!r}: allowed "
                              f"{', '.join(map(repr, INTERLACE_MODES))}")
    if "psf_sigma_px" in d:
        _scalar(path, "psf_sigma_px", d["psf_sigma_px"], 0.05, hi=100.0)
    sensor = d.get("sensor", {})
    if not isinstance(sensor, dict):
        raise CameraFileError(f"{path}: sensor must be an object (gain_e_per_adu, read_noise_e, bit_depth, gamma)")
    if "gain_e_per_adu" in sensor:
        _scalar(path, "sensor.gain_e_per_adu", sensor["gain_e_per_adu"], 0.0, lo_open=True, hi=1e6)
    if "read_noise_e" in sensor:
        _scalar(path, "sensor.read_noise_e", sensor["read_noise_e"], 0.0, hi=1e6)
    for key in ("full_well_e", "background_e_per_s"):  # as rendering writes them; tracking does not use them
        if sensor.get(key) is not None:
            _scalar(path, f"sensor.{key}", sensor[key], 0.0, hi=1e12)
    bits = sensor.get("bit_depth", 8)
    if isinstance(bits, bool) or not isinstance(bits, int) or not 8 <= bits <= 16:
        raise CameraFileError(f"{path}: sensor.bit_depth = {bits!r}: allowed integers 8 to 16")
    if "gamma" in sensor:
        _scalar(path, "sensor.gamma", sensor["gamma"], 0.1, hi=10.0)
    if sensor.get("transfer") is not None and sensor["transfer"] not in TRANSFERS:
        raise CameraFileError(f"{path}: sensor.transfer = {sensor['transfer']!r}: allowed {', '.join(TRANSFERS)}")


#: the principal point's standard deviation, as a fraction of the image width, when a data-sheet camera states none
#: (a phone's or webcam's lens is centred on its sensor to about 1 % of the width; twice that to be safe)
PRINCIPAL_POINT_SD_FRACTION = 0.02


def _value_sd(path: Path, key: str, value, lo: float = 0.0) -> tuple[float, float]:
    """A number, or ``{ "value": v, "sd": s }`` -> (v, s); the file and key named when wrong."""
    if isinstance(value, dict):
        extra = sorted(set(value) - {"value", "sd"})
        if extra or "value" not in value or "sd" not in value:
            raise CameraFileError(f"{path}: {key} = {value!r}: a number with an uncertainty is "
                                  '{"value": ..., "sd": ...}')
        return (_scalar(path, f"{key}.value", value["value"], lo, lo_open=True),
                _scalar(path, f"{key}.sd", value["sd"], 0.0))
    return _scalar(path, key, value, lo, lo_open=True), 0.0


#: the diagonal of a 36 x 24 mm frame, which a 35 mm-equivalent focal length refers to [mm]
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
#: a phone's still picture is 4:3, and its video spans the same width: the picture's diagonal over its width
STILL_DIAGONAL_OVER_WIDTH = 1.25
#: the relative sd of a focal length in pixels from a 35 mm-equivalent one stated without an sd: how much of the
#: sensor's width the video uses is not known (stabilisation crops it, and some video modes do)
FOCAL_35MM_SD_FRACTION = 0.15
#: the keys that give the focal length without a calibration
FOCAL_KEYS = ("focal_length_px", "focal_length_mm", "focal_length_35mm")


def datasheet_intrinsics(path: Path, d: dict) -> dict:
    """camera.json without a calibration: the intrinsics from the lens's focal length and the sensor's width (a data
    sheet: ``focal_length_mm`` and ``sensor_width_mm``, the width the video's ``image_size[0]`` pixels span), the
    focal length in pixels (``focal_length_px``), or a phone's 35 mm-equivalent focal length (``focal_length_35mm``,
    as its specifications and its photos' EXIF state it: the diagonal angle of view of its 4:3 still picture, whose
    width the video is taken to span; without an sd, :data:`FOCAL_35MM_SD_FRACTION` of it), each a number or
    ``{"value", "sd"}``; the principal point
    ``principal_point_px`` ([x, y], or ``{"value": [x, y], "sd": s}``; default the image centre with
    :data:`PRINCIPAL_POINT_SD_FRACTION` of the width); ``dist_coeffs`` default 0.  Returns ``d`` with
    ``camera_matrix``, ``dist_coeffs`` and ``intrinsics_covariance`` over fx, fy (one focal length: fully
    correlated), cx, cy, and ``intrinsics_source``; ``d`` as it is when it has a ``camera_matrix``."""
    given = [k for k in FOCAL_KEYS if k in d]
    if "camera_matrix" in d or not given:
        return d
    if len(given) > 1:
        raise CameraFileError(f"{path}: give one of focal_length_px, focal_length_mm (with sensor_width_mm) or "
                              f"focal_length_35mm, not {' and '.join(given)}")
    size = d.get("image_size")
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
        raise CameraFileError(f"{path}: image_size = {size!r}: expected [width, height], positive integers (the "
                              "focal length in pixels needs it)")
    w, h = size
    if "focal_length_px" in d:
        f, f_sd = _value_sd(path, "focal_length_px", d["focal_length_px"])
        source = "focal_length_px"
    elif "focal_length_35mm" in d:
        f35, f35_sd = _value_sd(path, "focal_length_35mm", d["focal_length_35mm"])
        f = f35 * STILL_DIAGONAL_OVER_WIDTH * w / FULL_FRAME_DIAGONAL_MM
        f_sd = f * (f35_sd / f35 if isinstance(d["focal_length_35mm"], dict) else FOCAL_35MM_SD_FRACTION)
        source = "focal_length_35mm"
    else:
        if "sensor_width_mm" not in d:
            raise CameraFileError(f"{path}: focal_length_mm needs sensor_width_mm (the width the video's "
                                  f"{w} pixels span on the sensor), or give focal_length_px")
        f_mm, f_mm_sd = _value_sd(path, "focal_length_mm", d["focal_length_mm"])
        s_mm, s_mm_sd = _value_sd(path, "sensor_width_mm", d["sensor_width_mm"])
        f = f_mm * w / s_mm
        f_sd = f * math.hypot(f_mm_sd / f_mm, s_mm_sd / s_mm)
        source = "focal_length_mm and sensor_width_mm"
    pp = d.get("principal_point_px")
    if pp is None:
        c, c_sd = np.array([(w - 1) / 2.0, (h - 1) / 2.0]), PRINCIPAL_POINT_SD_FRACTION * w
    elif isinstance(pp, dict):
        if sorted(pp) != ["sd", "value"]:
            raise CameraFileError(f"{path}: principal_point_px = {pp!r}: expected [x, y] or "
                                  '{"value": [x, y], "sd": s}')
        c = _array(path, "principal_point_px.value", pp["value"], (2,))
        c_sd = _scalar(path, "principal_point_px.sd", pp["sd"], 0.0)
    else:
        c, c_sd = _array(path, "principal_point_px", pp, (2,)), 0.0
    out = {**d, "camera_matrix": [[f, 0.0, float(c[0])], [0.0, f, float(c[1])], [0.0, 0.0, 1.0]],
           "dist_coeffs": d.get("dist_coeffs", [0.0] * 5), "intrinsics_source": source}
    if "intrinsics_covariance" not in d and (f_sd > 0 or c_sd > 0):
        out["intrinsics_parameters"] = ["fx", "fy", "cx", "cy"]
        out["intrinsics_covariance"] = [[f_sd**2, f_sd**2, 0.0, 0.0], [f_sd**2, f_sd**2, 0.0, 0.0],
                                        [0.0, 0.0, c_sd**2, 0.0], [0.0, 0.0, 0.0, c_sd**2]]
    return out


def load_camera(path: str | Path, *, require_pose: bool = True) -> Camera:
    """Read ``camera.json`` (as written by ``gyrorig render``, or by ``gyrorig calibrate``).

    Without a pose (``rvec``, ``tvec``) the camera is returned with NaN pose when
    ``require_pose=False``; :func:`gyrorig.tracking.estimate_pose` then finds it from the fiducials.
    """
    path = Path(path)
    try:
        _io.check_settings_size(path, "camera file")
    except _io.InputTooLarge as exc:
        raise CameraFileError(str(exc)) from None
    try:
        d = json.loads(_io.read_settings_text(path))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CameraFileError(f"cannot read camera file {path}: {exc}") from exc
    if not isinstance(d, dict):
        raise CameraFileError(f"{path}: expected a JSON object with camera_matrix, dist_coeffs, image_size")
    d = datasheet_intrinsics(path, d)
    missing = [k for k in ("camera_matrix", "dist_coeffs", "image_size") if k not in d]
    if missing:
        raise CameraFileError(f"{path}: missing key(s) {', '.join(missing)} (or, without a calibration, the focal "
                              "length: focal_length_mm with sensor_width_mm, focal_length_px, or a phone's 35 mm-"
                              'equivalent focal_length_35mm, each a number or {"value", "sd"})')
    if ("rvec" not in d or "tvec" not in d) and require_pose:
        raise CameraFileError(f"{path}: no camera pose (rvec, tvec) relative to the pivot; "
                              "the tracker needs it to turn pixels into directions")
    _check_camera_values(path, d)
    sensor = d.get("sensor", {})
    bits = int(sensor.get("bit_depth", 8))
    cov_i = names = cov_p = None
    if "intrinsics_covariance" in d:
        names = tuple(d.get("intrinsics_parameters", INTRINSIC_PARAMETERS[:8]))
        unknown = [n for n in names if n not in INTRINSIC_PARAMETERS]
        cov_i = np.asarray(d["intrinsics_covariance"], dtype=float)
        if unknown or cov_i.shape != (len(names), len(names)):
            raise CameraFileError(f"{path}: intrinsics_covariance must be a {len(names)} x {len(names)} matrix over "
                                f"intrinsics_parameters (any of {', '.join(INTRINSIC_PARAMETERS)}); unknown: {unknown}")
    if "pose_covariance" in d:
        cov_p = np.asarray(d["pose_covariance"], dtype=float)
        if cov_p.shape != (6, 6):
            raise CameraFileError(f"{path}: pose_covariance must be 6 x 6 over (rvec, tvec), not {cov_p.shape}")
    points = _pose_points(path, d["pose_points"]) if "pose_points" in d else None
    for key, c in (("intrinsics_covariance", cov_i), ("pose_covariance", cov_p)):
        if c is not None and (not np.all(np.isfinite(c)) or np.linalg.eigvalsh(0.5 * (c + c.T)).min()
                              < -1e-9 * max(np.abs(c).max(), 1e-300)):
            raise CameraFileError(f"{path}: {key} must be finite, symmetric and positive semi-definite")
    def given(key: str, default: float) -> float:  # render writes NaN numbers as null
        return float(sensor[key]) if sensor.get(key) is not None else default

    known = Sensor(bits, full_well_e=given("full_well_e", math.nan), read_noise_e=given("read_noise_e", 0.0),
                   gain_e_per_adu=given("gain_e_per_adu", math.nan),
                   background_e_per_s=given("background_e_per_s", math.nan), gamma=given("gamma", 1.0),
                   transfer=sensor.get("transfer") or (None if sensor.get("gamma") is not None else "video"))
    return Camera(
        np.asarray(d["camera_matrix"], dtype=float), np.asarray(d["dist_coeffs"], dtype=float).ravel(),
        np.asarray(d.get("rvec", [np.nan] * 3), dtype=float).ravel(),
        np.asarray(d.get("tvec", [np.nan] * 3), dtype=float).ravel(),
        int(d["image_size"][0]), int(d["image_size"][1]), float(d.get("fps", np.nan)), float(d.get("exposure_s", 0.0)),
        shutter=d.get("shutter", "global"), readout_time_s=_readout(d),
        psf_sigma_px=float(d.get("psf_sigma_px", 1.0)), sensor=known,
        motion_blur_samples=int(d.get("motion_blur_samples", 1)), intrinsics_covariance=cov_i,
        intrinsics_parameters=names or (), pose_covariance=cov_p, pose_points=points,
        pose_recording=_pose_recording(path, d), capture_fps=float(d.get("capture_fps", np.nan)),
        interlace=d.get("interlace", "auto"))


def _pose_recording(path: Path, d: dict) -> str | None:
    """``pose_source.video_fingerprint`` (a pose found from a recording's own motion), checked."""
    source = d.get("pose_source")
    value = source.get("video_fingerprint") if isinstance(source, dict) else None
    if value is None:
        return None
    if not isinstance(value, str) or not re.fullmatch(r"[0-9a-f]{64}", value):
        raise CameraFileError(f"{path}: pose_source.video_fingerprint must be a 64-digit hex digest (as gyrorig pose "
                              "writes it)")
    return value


def _pose_points(path: Path, value) -> dict:
    """``pose_points``: ``object_points_m`` (n x 3, lab) and ``image_points_px`` (n x 2), n >= 4."""
    if not isinstance(value, dict) or set(value) != {"object_points_m", "image_points_px"}:
        raise CameraFileError(f"{path}: pose_points must be an object with object_points_m and image_points_px")
    try:
        obj = np.asarray(value["object_points_m"], dtype=float)
        img = np.asarray(value["image_points_px"], dtype=float)
    except (TypeError, ValueError):
        raise CameraFileError(f"{path}: pose_points must hold numbers") from None
    if obj.ndim != 2 or obj.shape[1] != 3 or img.shape != (len(obj), 2) or len(obj) < 4:
        raise CameraFileError(f"{path}: pose_points: object_points_m must be n x 3 and image_points_px n x 2 with "
                              f"n >= 4 (got {obj.shape} and {img.shape})")
    if not (np.all(np.isfinite(obj)) and np.all(np.isfinite(img))):
        raise CameraFileError(f"{path}: pose_points must be finite (no NaN or inf)")
    return {"object_points_m": obj.tolist(), "image_points_px": img.tolist()}


def _readout(d: dict) -> float:
    """camera.json's readout time: NaN for a rolling shutter that states none (null or left out: a phone's, which
    the fit finds), else the value given (0 by default)."""
    given = d.get("readout_time_s")
    if given is None:
        return math.nan if d.get("shutter", "global") == "rolling" else 0.0
    return float(given)
