"""The camera model (:class:`Camera`, :class:`Sensor`), shared by rendering and tracking, and the protocol
sections that describe it (``[camera]``; ``[markers]`` through :mod:`gyrorig.markers`).

Conventions are OpenCV's: a lab point ``X`` maps to camera coordinates
``R(rvec) X + tvec`` (x right, y down, z forward), then through the pinhole ``K`` and
the radial/tangential distortion ``(k1, k2, p1, p2, k3)`` to pixels whose centres are
at integer coordinates (``x_px`` right, ``y_px`` down).

Protocol keys (SI, units in the names):

``[camera]``: ``width_px, height_px, fps, exposure_s``; focal length as
``focal_length_mm`` + ``pixel_size_um`` or as ``horizontal_fov_deg``; optional
``principal_point_px = [cx, cy]`` (default: image centre), ``distortion = [k1, k2, p1,
p2, k3]`` (default 0), ``position_m`` (required: camera centre in the lab, pivot at the
origin), ``look_at_m`` (default the pivot), ``up_hint = [x, y, z]`` (lab direction that
appears upwards in the image; default ``+y``), ``shutter = "global" | "rolling"``,
``readout_time_s`` (rolling only: first to last row), ``psf_sigma_px`` (Gaussian
point-spread function, default 0.8), ``motion_blur_samples`` (sub-exposure samples,
default 8; 1 = no motion blur), ``illumination_drift_fraction`` (default 0) and
``illumination_drift_period_s`` (default 1): the lighting (markers and background) varies as
``1 + f sin(2 pi t / P)``.

``[camera.sensor]``: ``bit_depth`` (8, 10 or 12), ``full_well_e``, ``read_noise_e``,
``gain_e_per_adu``, ``background_e_per_s`` (lighting: electrons per pixel per second),
``gamma`` (default 1: a linear response; 2.2: the recorded value is ``max (linear / max)^(1/2.2)``,
as many cameras write).

``[markers]``: see :mod:`gyrorig.markers` (the renderer needs every dot's ``brightness_e_per_s``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from .markers import Marker, Occluder, parse_markers
from ._validate import ProtocolError, check_keys, number, vector3
from .protocols import Protocol

__all__ = ["placement_pose", "Sensor", "Camera", "INTRINSIC_PARAMETERS", "Marker", "Occluder", "CameraSetup",
           "camera_setup", "look_at_pose", "with_image_size"]


#: intrinsics an ``intrinsics_covariance`` may refer to (``gyrorig calibrate`` writes the first eight); a pose
#: covariance is over ``(rvec, tvec)``
INTRINSIC_PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class Sensor:
    """Photon-to-ADU model: electrons = Poisson(signal) + Normal(0, read noise); ADU = electrons / gain.

    A number not known (a recording's gain, full well, lighting) is NaN: rendering needs them all, tracking uses
    the gain and read noise where known (:attr:`Camera.sensor_known`)."""

    bit_depth: int = 8
    full_well_e: float = math.nan
    read_noise_e: float = 0.0
    gain_e_per_adu: float = math.nan
    background_e_per_s: float = math.nan
    #: response exponent: recorded = max (linear / max)^(1 / gamma); 1 is linear
    gamma: float = 1.0
    #: a standard transfer curve instead of the power law (:data:`gyrorig.tracking.transfer.TRANSFERS`: ``bt709``,
    #: ``srgb``, ``hlg``, ``linear``); ``"video"``: camera.json stated neither, the video's own tag decides
    #: (tracking); None: the power law ``gamma``
    transfer: str | None = None

    @property
    def max_adu(self) -> int:
        """Largest pixel value (saturation). [ADU]"""
        return (1 << self.bit_depth) - 1


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with distortion, pose, timing and sensor (OpenCV conventions): the one camera model of
    rendering (from a protocol's ``[camera]``, :func:`camera_setup`) and of tracking (from ``camera.json``,
    :func:`gyrorig.tracking.load_camera`).  What an analysis does not know is NaN (the pose before it is found,
    a recording's sensor numbers) or None (covariances: exact)."""

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    width_px: int
    height_px: int
    fps: float
    exposure_s: float
    shutter: str = "global"
    readout_time_s: float = 0.0
    psf_sigma_px: float = 1.0
    sensor: Sensor = Sensor()
    #: sub-exposure samples the renderer draws motion blur with (1: none)
    motion_blur_samples: int = 8
    #: lighting varies as 1 + fraction sin(2 pi t / period) (rendering)
    illumination_drift_fraction: float = 0.0
    illumination_drift_period_s: float = 1.0
    #: covariance of the intrinsics named in ``intrinsics_parameters`` (None: exact)
    intrinsics_covariance: np.ndarray | None = None
    intrinsics_parameters: tuple[str, ...] = ()
    #: covariance of ``(rvec, tvec)`` (None: exact, or found from the fiducials)
    pose_covariance: np.ndarray | None = None
    #: the points the pose was solved from (``object_points_m`` in the lab, ``image_points_px``): moving the
    #: intrinsics then re-solves the pose from them (None: the pose is held)
    pose_points: dict | None = None
    #: the fingerprint (:func:`gyrorig.tracking.sources.fingerprint`) of the recording whose tip motion gave the
    #: pose (``pose_source.video_fingerprint``): tracking that recording marks the pose's modes as found from
    #: its own frames (None: the pose is outside knowledge)
    pose_recording: str | None = None
    #: the rate the frames were captured at when the file stores them at another (slow motion: captured at 240,
    #: stored at 30); NaN: the file's own times are real times [frames/s]
    capture_fps: float = math.nan
    #: how the pictures were scanned: "auto" (as the video file says), "progressive", or an interlaced camera's field
    #: order, "top-field-first" or "bottom-field-first" (:mod:`gyrorig.tracking.fields`)
    interlace: str = "auto"

    @property
    def gain_e_per_adu(self) -> float:
        return self.sensor.gain_e_per_adu

    @property
    def read_noise_e(self) -> float:
        return self.sensor.read_noise_e

    @property
    def max_adu(self) -> int:
        return self.sensor.max_adu

    @property
    def gamma(self) -> float:
        return self.sensor.gamma

    @property
    def has_pose(self) -> bool:
        """True when the pose relative to the pivot is known."""
        return bool(np.all(np.isfinite(self.rvec)) and np.all(np.isfinite(self.tvec)))

    @property
    def sensor_known(self) -> bool:
        """True when pixel variances follow from the sensor model: a known gain and a linear response."""
        return (math.isfinite(self.sensor.gain_e_per_adu) and self.sensor.gamma == 1.0
                and self.sensor.transfer in (None, "linear", "video"))

    def with_sensor(self, **changes) -> "Camera":
        """The camera with the sensor's numbers changed (``bit_depth``, ``gain_e_per_adu``, ...)."""
        return replace(self, sensor=replace(self.sensor, **changes))

    def illumination(self, t_s: np.ndarray | float) -> np.ndarray | float:
        """The lighting's factor at times ``t_s`` (1 without drift)."""
        return 1.0 + self.illumination_drift_fraction * np.sin(2 * np.pi * np.asarray(t_s) /
                                                              self.illumination_drift_period_s)

    @cached_property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation matrix ``R(rvec)`` (computed once per camera)."""
        import cv2

        return cv2.Rodrigues(np.asarray(self.rvec, dtype=float))[0]

    @cached_property
    def centre_m(self) -> np.ndarray:
        """Camera centre in the lab (pivot frame). [m]"""
        return -self.rotation.T @ np.ravel(self.tvec)

    def row_delay_s(self, y_px: float) -> float:
        """Start of row ``y_px``'s exposure after the frame's start (rolling shutter; 0 for a global one, and for a
        rolling one whose readout is not known: :attr:`readout_unknown`). [s]"""
        rolling = self.shutter == "rolling" and math.isfinite(self.readout_time_s)
        return (y_px / self.height_px) * self.readout_time_s if rolling else 0.0

    @property
    def readout_unknown(self) -> bool:
        """A rolling shutter whose readout time camera.json does not state (a phone's): the frames' times are their
        first row's, and the fit finds the readout from the motion (:class:`gyrorig.fit.terms.RollingShutter`)."""
        return self.shutter == "rolling" and not math.isfinite(self.readout_time_s)

    @property
    def focal_sd_rel(self) -> float:
        """The focal length's relative sd from the intrinsics covariance (0 when it states none)."""
        names = self.intrinsics_parameters
        if self.intrinsics_covariance is None or "fx" not in names:
            return 0.0
        i = names.index("fx")
        return math.sqrt(max(float(self.intrinsics_covariance[i, i]), 0.0)) / float(self.camera_matrix[0, 0])

    def with_intrinsics(self, names: tuple[str, ...], delta: np.ndarray) -> "Camera":
        """The camera with the named intrinsics (:data:`INTRINSIC_PARAMETERS`) moved by ``delta``."""
        K = self.camera_matrix.copy()
        dist = np.zeros(max(5, self.dist_coeffs.size))
        dist[:self.dist_coeffs.size] = self.dist_coeffs
        where = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
        for name, d in zip(names, delta):
            if name in where:
                K[where[name]] += d
            else:
                dist[("k1", "k2", "p1", "p2", "k3").index(name)] += d
        return replace(self, camera_matrix=K, dist_coeffs=dist)

    def to_json(self) -> dict[str, Any]:
        """The camera in OpenCV's terms, for ``camera.json`` (as rendering writes it)."""
        s = self.sensor
        return {
            "image_size": [self.width_px, self.height_px],
            "camera_matrix": self.camera_matrix.tolist(),
            "dist_coeffs": self.dist_coeffs.tolist(),
            "rvec": np.ravel(self.rvec).tolist(),
            "tvec": np.ravel(self.tvec).tolist(),
            "fps": self.fps,
            "exposure_s": self.exposure_s,
            "shutter": self.shutter,
            "readout_time_s": None if self.readout_unknown else self.readout_time_s,
            "psf_sigma_px": self.psf_sigma_px,
            "motion_blur_samples": self.motion_blur_samples,
            **({"interlace": self.interlace} if self.interlace != "auto" else {}),
            "sensor": {"bit_depth": s.bit_depth, "full_well_e": s.full_well_e, "read_noise_e": s.read_noise_e,
                       "gain_e_per_adu": s.gain_e_per_adu, "background_e_per_s": s.background_e_per_s,
                       "gamma": s.gamma, **({"transfer": s.transfer} if s.transfer not in (None, "video") else {})},
            "conventions": "x_cam = R(rvec) X_lab + tvec (OpenCV); pixel centres at integer coordinates; "
                           "rolling shutter: row y starts its exposure at t_frame + (y / height_px) * readout_time_s",
        }


@dataclass(frozen=True)
class CameraSetup:
    """Everything the renderer needs besides the trajectory."""

    camera: Camera
    markers: tuple[Marker, ...]
    occluders: tuple[Occluder, ...]


def look_at_pose(position: np.ndarray, target: np.ndarray, up_hint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV ``rvec, tvec`` of a camera at ``position`` looking at ``target``, ``up_hint`` up in the image."""
    import cv2

    z = target - position
    z = z / np.linalg.norm(z)
    down = -(up_hint - (up_hint @ z) * z)
    if np.linalg.norm(down) < 1e-9:
        raise ProtocolError("camera.up_hint is parallel to the viewing direction; give another up_hint")
    y = down / np.linalg.norm(down)
    x = np.cross(y, z)
    rot = np.vstack([x, y, z])  # rows: camera axes in the lab
    rvec = cv2.Rodrigues(rot)[0].ravel()
    return rvec, -rot @ position


def placement_pose(t: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV ``rvec, tvec`` of the camera placement a ``[camera]`` table states: ``position_m`` (required),
    ``look_at_m`` (default the pivot), ``up_hint`` (default +y).  Reads nothing else: analysing a recording needs
    only a rough placement (``gyrorig pose --video`` starts from it), not the renderer's sensor numbers."""
    s = "camera"
    if "position_m" not in t:
        raise ProtocolError("[camera] is missing required key(s) position_m (the camera centre in the lab, pivot at "
                            "the origin)")
    position = np.array(vector3(s, "position_m", t["position_m"]))
    target = np.array(vector3(s, "look_at_m", t.get("look_at_m", [0.0, 0.0, 0.0])))
    if np.linalg.norm(target - position) == 0:
        raise ProtocolError("camera.centre_m equals camera.look_at_m")
    up = np.array(vector3(s, "up_hint", t.get("up_hint", [0.0, 1.0, 0.0])))
    return look_at_pose(position, target, up)


def _parse_sensor(t: Mapping[str, Any]) -> Sensor:
    s = "camera.sensor"
    check_keys(s, t, {"bit_depth", "full_well_e", "read_noise_e", "gain_e_per_adu", "background_e_per_s"}, {"gamma"})
    bits = t["bit_depth"]
    if bits not in (8, 10, 12):
        raise ProtocolError(f"camera.sensor.bit_depth = {bits!r}: allowed 8, 10, 12")
    return Sensor(int(bits), number(s, "full_well_e", t["full_well_e"], lo=0.0, lo_open=True),
                  number(s, "read_noise_e", t["read_noise_e"], lo=0.0),
                  number(s, "gain_e_per_adu", t["gain_e_per_adu"], lo=0.0, lo_open=True),
                  number(s, "background_e_per_s", t["background_e_per_s"], lo=0.0),
                  number(s, "gamma", t.get("gamma", 1.0), lo=0.2, hi=5.0))


def _parse_camera(t: Mapping[str, Any]) -> Camera:
    s = "camera"
    required = {"width_px", "height_px", "fps", "exposure_s", "position_m", "sensor"}
    optional = {"focal_length_mm", "pixel_size_um", "horizontal_fov_deg", "principal_point_px", "distortion",
                "look_at_m", "up_hint", "shutter", "readout_time_s", "psf_sigma_px", "motion_blur_samples",
                "illumination_drift_fraction", "illumination_drift_period_s"}
    check_keys(s, t, required, optional)
    w = int(number(s, "width_px", t["width_px"], lo=16, hi=20000))
    h = int(number(s, "height_px", t["height_px"], lo=16, hi=20000))
    fps = number(s, "fps", t["fps"], lo=0.0, lo_open=True, hi=1e6)
    exposure = number(s, "exposure_s", t["exposure_s"], lo=0.0, lo_open=True)
    if exposure > 1.0 / fps * (1 + 1e-12):
        raise ProtocolError(f"camera.exposure_s = {exposure!r} is longer than the frame interval 1/fps = "
                            f"{1.0 / fps:.6g} s; allowed (0, {1.0 / fps:.6g}]")
    if "horizontal_fov_deg" in t:
        if "focal_length_mm" in t:
            raise ProtocolError("[camera] gives both horizontal_fov_deg and focal_length_mm; give one")
        fov = number(s, "horizontal_fov_deg", t["horizontal_fov_deg"], lo=0.0, hi=179.0, lo_open=True)
        fx = (w / 2.0) / math.tan(math.radians(fov) / 2.0)
    else:
        if "focal_length_mm" not in t or "pixel_size_um" not in t:
            raise ProtocolError("[camera] needs focal_length_mm and pixel_size_um, or horizontal_fov_deg")
        f_mm = number(s, "focal_length_mm", t["focal_length_mm"], lo=0.0, lo_open=True)
        pix = number(s, "pixel_size_um", t["pixel_size_um"], lo=0.0, lo_open=True)
        fx = f_mm * 1e3 / pix
    cx, cy = ((w - 1) / 2.0, (h - 1) / 2.0)
    if "principal_point_px" in t:
        pp = t["principal_point_px"]
        if not isinstance(pp, list) or len(pp) != 2:
            raise ProtocolError(f"camera.principal_point_px = {pp!r}: expected [cx, cy]")
        cx = number(s, "principal_point_px[0]", pp[0], lo=0.0, hi=w - 1)
        cy = number(s, "principal_point_px[1]", pp[1], lo=0.0, hi=h - 1)
    dist = t.get("distortion", [0.0] * 5)
    if not isinstance(dist, list) or len(dist) != 5:
        raise ProtocolError(f"camera.dist_coeffs = {dist!r}: expected [k1, k2, p1, p2, k3]")
    dist = np.array([number(s, f"distortion[{i}]", v, lo=-10, hi=10) for i, v in enumerate(dist)])
    shutter = t.get("shutter", "global")
    if shutter not in ("global", "rolling"):
        raise ProtocolError(f"camera.shutter = {shutter!r}: allowed 'global', 'rolling'")
    readout = 0.0
    if shutter == "rolling":
        if "readout_time_s" not in t:
            raise ProtocolError("camera.shutter = 'rolling' needs camera.readout_time_s")
        readout = number(s, "readout_time_s", t["readout_time_s"], lo=0.0, lo_open=True, hi=1.0 / fps)
    elif "readout_time_s" in t:
        raise ProtocolError("camera.readout_time_s is only meaningful with shutter = 'rolling'")
    rvec, tvec = placement_pose(t)
    k = np.array([[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]])
    sigma = number(s, "psf_sigma_px", t.get("psf_sigma_px", 0.8), lo=0.3, hi=20.0)
    nsub = int(number(s, "motion_blur_samples", t.get("motion_blur_samples", 8), lo=1, hi=256))
    drift = number(s, "illumination_drift_fraction", t.get("illumination_drift_fraction", 0.0), lo=0.0, hi=0.5)
    period = number(s, "illumination_drift_period_s", t.get("illumination_drift_period_s", 1.0), lo=0.0, lo_open=True)
    return Camera(k, dist, rvec, tvec, w, h, fps, exposure, shutter=shutter, readout_time_s=readout,
                  psf_sigma_px=sigma, sensor=_parse_sensor(t["sensor"]), motion_blur_samples=nsub,
                  illumination_drift_fraction=drift, illumination_drift_period_s=period)


def with_image_size(protocol: Protocol, width_px: int, height_px: int) -> Protocol:
    """The protocol with its camera's sensor cropped or binned to ``width_px x height_px``.

    The pixel pitch scales with the width, so the field of view and the optics stay the same
    (a 640x480 stand-in for a 1440x1080 camera sees the same scene, 2.25x coarser).
    """
    if "camera" not in protocol.extra:
        raise ProtocolError("the protocol has no [camera] section")
    cam = dict(protocol.extra["camera"])
    if "pixel_size_um" in cam:
        cam["pixel_size_um"] = cam["pixel_size_um"] * cam["width_px"] / width_px
    cam.update(width_px=width_px, height_px=height_px)
    return replace(protocol, extra={**protocol.extra, "camera": cam})


def camera_setup(protocol: Protocol) -> CameraSetup:
    """Parse and validate the protocol's ``[camera]`` and ``[markers]`` sections.

    Raises
    ------
    ProtocolError
        Missing sections, impossible cameras (focal length <= 0, exposure longer than
        the frame interval, the pivot outside the field of view), malformed markers.
    """
    if "camera" not in protocol.extra or "markers" not in protocol.extra:
        missing = [k for k in ("camera", "markers") if k not in protocol.extra]
        raise ProtocolError(f"{protocol.name}: rendering needs the section(s) {', '.join(missing)}")
    cam = _parse_camera(protocol.extra["camera"])
    marker_set = parse_markers(protocol.extra["markers"])
    marker_set.require_brightness("rendering")
    # the pivot must be in front of the camera and inside the image
    import cv2

    pc = cam.rotation @ np.zeros(3) + cam.tvec
    px = cv2.projectPoints(np.zeros((1, 3)), cam.rvec, cam.tvec, cam.camera_matrix, cam.dist_coeffs)[0].reshape(2)
    if pc[2] <= 0 or not (0 <= px[0] <= cam.width_px - 1 and 0 <= px[1] <= cam.height_px - 1):
        raise ProtocolError(f"camera.centre_m / look_at_m: the pivot projects to pixel ({px[0]:.1f}, {px[1]:.1f}), "
                            f"outside the {cam.width_px} x {cam.height_px} image")
    return CameraSetup(cam, marker_set.dots, marker_set.occluders)
