"""Tracking on footage unlike the tracker's own assumptions: ``gyrorig bench variants``.

Each variant renders the air-cushion rig (set A, released from rest at 45 deg, 80 Hz spin) with
something the tracker was not written for, and tracks it with a protocol that names only what a
user would write down (the tip marker and the rotor can; the camera pose in ``camera.json``).
Against the renderer's truth it reports, per variant: the fraction of frames with the tip visible
that were tracked, and of those whose tip is clear of other markers (:func:`clear_frames`), frames whose position is wrong by more than 5 sigma (all, and those flagged
``ok``), the SD of (error / sigma) in theta and phi, the RMS pixel error of the tip against that of a
plain 50 %-threshold weighted centroid on the same frames (windowed on the truth: the centroid's best
case), and the tracking speed (frames per second of ``track``, the compiled kernels loaded first) beside that
of decoding the same file alone, measured one after the other.

Variants (:data:`VARIANTS`):

- ``sphere``: the bundled rig at 640x480 (the tracker's own model; precision reference);
- ``disc``: 1280x720 at 240 fps, 0.5 ms, an 8 mm flat retroreflective tip dot facing along the stem
  (ray-cast, independent of the tracker's model), two 5 mm dots on the spinning rotor, a lens with
  k1, k2, p1, p2, k3, the camera 15 deg off vertical, +-5 % illumination drift, FFV1;
- ``disc-mp4``: the same through mp4v (lossy), a 3 ms rolling shutter and gamma 2.2;
- ``plain-top``: no separate frame (the crossbar dots spin with the rotor), 640x480;
- ``dim-tip``: the tip 4x dimmer than the crossbar dots, 640x480.

Recorded like a phone (:mod:`gyrorig.render.phone`: the markers in front of a real photograph drifting behind
the rig under flickering light, gamma 2.2, YUV 4:2:0, frame times on a 90 kHz clock with 5 % jitter and 2 %
of the frames dropped; the user's camera.json has no sensor numbers), 1280x720 at 240 fps:

- ``phone-coffee-hevc``: scikit-image's ``coffee``, HEVC (libx265, CRF 23);
- ``phone-brick-h264``: ``brick``, H.264 (libx264, CRF 23), 10 % jitter;
- ``phone-brick-red``: ``brick``, a red sticker for a tip (``colour = "red"`` in the user's protocol), HEVC
  (in front of ``astronaut``'s orange suit or ``rocket``'s lit pad the sticker is lost: they are as red);
- ``phone-astronaut-10bit``: ``astronaut``, 10-bit HEVC;
- ``phone-slowmo``: ``gravel``, captured at 240 fps and stored at 30 (the user states ``capture_fps``), HEVC;
- ``phone-handheld``: ``coffee``, HEVC, the phone held in the hand: the whole picture moves by 2 px RMS at 3-7 Hz;
- ``phone-camera-ippp``: ``camera`` (the cameraman, in grey), HEVC with no B pictures (I and P only, as many phones'
  hardware encoders write);
- ``phone-brick-crf32``: ``brick``, H.264 at CRF 32 (a file shrunk for sharing: the codec smooths the noise away and
  moves runs of B pictures alike by about 0.2 px);
- ``phone-30fps``: ``coffee``, HEVC, at 30 fps (most phones' default rate: the heavy top's nod moves the tip by up to
  three of its radii between frames), eight times as long, so that it holds as many frames as the others;
- ``phone-held``: ``coffee`` standing still (a phone on a tripod), HEVC, the top held still for 0.5 s before its release
  (the phone records from before it), the clip that much longer;
- ``phone-video`` (only with a recording given, ``--background-video``): a real recording plays behind the rig at
  its own speed, as it was exposed (hands, people, their own sensor noise and codec), HEVC; e.g. OpenCV's sample
  clips (Debian's ``opencv-doc``: ``box.mp4``, ``cup.mp4`` of a hand over a white table, ``vtest.avi``).
"""

from __future__ import annotations

import copy
import json
import math
import tempfile
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from ..protocols import BUNDLED_PROTOCOL_DIR, parse_protocol
from ..render import render_video
from ..render.phone import PhoneStyle, render_phone_video
from ..tracking import VideoFile, load_camera, track, warm_up

__all__ = ["VARIANTS", "VIDEO_VARIANTS", "variant_protocols", "centroid_50", "clear_frames", "track_variant",
           "variant_benchmark"]

#: the phone-recorded variants: the :class:`~gyrorig.render.phone.PhoneStyle` of each, and what the user's
#: protocol says of the tip beyond its place and size
PHONE_VARIANTS = {
    "phone-coffee-hevc": (dict(photo="coffee", codec="libx265"), {}),
    "phone-brick-h264": (dict(photo="brick", codec="libx264", jitter_fraction=0.1), {}),
    "phone-brick-red": (dict(photo="brick", codec="libx265", marker_rgb=(0.75, 0.06, 0.05)), {"colour": "red"}),
    "phone-astronaut-10bit": (dict(photo="astronaut", codec="libx265", bit_depth=10), {}),
    "phone-slowmo": (dict(photo="gravel", codec="libx265", container_fps=30.0), {}),
    "phone-handheld": (dict(photo="coffee", codec="libx265", shake_px=2.0), {}),
    "phone-camera-ippp": (dict(photo="camera", codec="libx265", b_frames=0), {}),
    "phone-brick-crf32": (dict(photo="brick", codec="libx264", crf=32), {}),
    "phone-30fps": (dict(photo="coffee", codec="libx265"), {}),
    "phone-held": (dict(photo="coffee", codec="libx265", drift_px_per_s=0.0, hold_s=0.5), {}),
    "phone-video": (dict(photo=None, codec="libx265", background_level=1.0, drift_px_per_s=0.0), {}),
}
#: variants that need a recording to play behind the rig (``background_video``)
VIDEO_VARIANTS = ("phone-video",)
VARIANTS = ("sphere", "disc", "disc-mp4", "plain-top", "dim-tip",
            *(n for n in PHONE_VARIANTS if n not in VIDEO_VARIANTS))
#: phone variants filmed at another frame rate than the others' 240 fps (their records as many frames long)
PHONE_FPS = {"phone-30fps": 30.0}


def _base() -> dict:
    return tomllib.loads((BUNDLED_PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text())


def _small_camera(d: dict) -> None:
    d["camera"].update(width_px=640, height_px=480, pixel_size_um=3.45 * 2.25)


def _independent_camera(d: dict, *, lossy: bool) -> None:
    """1280x720 at 240 fps, 0.5 ms, 63 deg field of view, 15 deg off vertical, a lens with k3."""
    tilt = math.radians(15.0)
    cam = d["camera"]
    cam.pop("focal_length_mm")
    cam.pop("pixel_size_um")
    cam.update(width_px=1280, height_px=720, fps=240.0, exposure_s=5e-4, horizontal_fov_deg=63.0,
               position_m=[0.75 * math.sin(tilt), 0.0, 0.75 * math.cos(tilt)],
               distortion=[-0.12, 0.08, 5e-4, -3e-4, -0.02], illumination_drift_fraction=0.05,
               illumination_drift_period_s=1.3)
    if lossy:
        cam.update(shutter="rolling", readout_time_s=3e-3)
        cam["sensor"]["gamma"] = 2.2


def _phone_camera(d: dict) -> None:
    """A phone on a stand 0.75 m above the pivot, 10 deg off the vertical: 1280x720 at 240 fps, 1 ms, 60 deg
    field of view, a mild lens distortion."""
    tilt = math.radians(10.0)
    cam = d["camera"]
    cam.pop("focal_length_mm")
    cam.pop("pixel_size_um")
    cam.update(width_px=1280, height_px=720, fps=240.0, exposure_s=1e-3, horizontal_fov_deg=60.0,
               position_m=[0.75 * math.sin(tilt), 0.0, 0.75 * math.cos(tilt)], distortion=[0.05, -0.02, 0, 0, 0],
               psf_sigma_px=1.0)


def _disc_markers(d: dict) -> None:
    """The tip an 8 mm flat dot; two 5 mm dots on the rotor (they whirl at the spin); no crossbar, no fiducials."""
    markers = d["markers"]
    for name in [n for n, m in markers.items() if n != "can" and n != "tip"]:
        del markers[name]
    markers["tip"].update(shape="disc", brightness_e_per_s=1.2e7)
    for k, ang in enumerate((0.4, 0.4 + math.pi)):
        markers[f"rotor_{k + 1}"] = {"body": "rotor", "position_m": [0.035 * math.cos(ang), 0.035 * math.sin(ang),
                                                                      0.0965],
                                     "radius_m": 0.0025, "brightness_e_per_s": 1.2e7}


def variant_protocols(name: str, duration_s: float) -> tuple[dict, dict, str]:
    """The rendered scene, the protocol the tracker is given (what a user would write), and the codec."""
    if name not in VARIANTS + VIDEO_VARIANTS:
        raise ValueError(f"variant {name!r}: allowed {', '.join(VARIANTS + VIDEO_VARIANTS)}")
    d = _base()
    d["scene"]["duration_s"] = duration_s
    codec = "lossless"
    if name == "sphere":
        _small_camera(d)
    elif name in ("disc", "disc-mp4"):
        _independent_camera(d, lossy=name == "disc-mp4")
        _disc_markers(d)
        codec = "mp4" if name == "disc-mp4" else "lossless"
    elif name == "plain-top":
        _small_camera(d)
        del d["rig"]["frame_axial_inertia_kg_m2"]
    elif name == "dim-tip":
        _small_camera(d)
        d["markers"]["tip"]["brightness_e_per_s"] = 0.25 * d["markers"]["crossbar_a"]["brightness_e_per_s"]
    if name in PHONE_VARIANTS:
        _phone_camera(d)
        codec = "phone"
    if name in PHONE_FPS:
        d["scene"]["duration_s"] = duration_s * d["camera"]["fps"] / PHONE_FPS[name]
        d["camera"]["fps"] = PHONE_FPS[name]
    user = copy.deepcopy(d)
    if name in PHONE_VARIANTS:  # what a user writes down: where the markers are and how big, the tip's colour
        user["markers"] = {k: {kk: vv for kk, vv in m.items() if kk != "brightness_e_per_s"}
                           for k, m in d["markers"].items()}
        user["markers"]["tip"].update(PHONE_VARIANTS[name][1])
    if name in ("disc", "disc-mp4"):
        user["markers"] = {"tip": {k: v for k, v in d["markers"]["tip"].items() if k != "brightness_e_per_s"},
                           "can": d["markers"]["can"]}
    return d, user, codec


def centroid_50(image: np.ndarray, x: float, y: float, half: int = 12) -> tuple[float, float]:
    """A plain weighted centroid: the window's border median as background, the pixels above half the peak
    (the connected region around the brightest one), weighted by their value above background."""
    xi, yi = int(round(x)), int(round(y))
    win = image[yi - half:yi + half + 1, xi - half:xi + half + 1].astype(np.float64)
    bg = float(np.median(np.concatenate([win[0], win[-1], win[:, 0], win[:, -1]])))
    w = win - bg
    mask = (w > 0.5 * w.max()).astype(np.uint8)
    _, labels = cv2.connectedComponents(mask, connectivity=8)
    iy, ix = np.unravel_index(int(np.argmax(w)), w.shape)
    w = np.where(labels == labels[iy, ix], w, 0.0)
    yy, xx = np.mgrid[yi - half:yi + half + 1, xi - half:xi + half + 1]
    return float((w * xx).sum() / w.sum()), float((w * yy).sum() / w.sum())


def _centroid_rms(video: Path, truth: pd.DataFrame, frames: np.ndarray, kept: list | None = None) -> float:
    """The plain centroid's RMS error on the frames given (``kept``: the frame number of each stored frame, when
    some were dropped)."""
    tip = truth[truth.marker == "tip"].set_index("frame")
    errs = []
    wanted = set(int(f) for f in frames)
    with VideoFile(video).open() as source:
        for n, (img, _) in enumerate(source):
            k = kept[n] if kept is not None else n
            if k in wanted:
                r = tip.loc[k]
                cx, cy = centroid_50(img, r.x_px, r.y_px)
                errs.append((cx - r.x_px) ** 2 + (cy - r.y_px) ** 2)
    return float(np.sqrt(np.mean(errs) / 2)) if errs else math.nan


#: a frame's tip is clear when no other visible marker's centre lies within this many tip radii plus its own
#: radius (image radii, from the camera's focal length and the markers' distances)
CLEAR_TIP_RADII = 3.0


def clear_frames(truth: pd.DataFrame, scene: dict, camera: dict) -> pd.Index:
    """Frames whose tip is visible and clear of every other visible marker (:data:`CLEAR_TIP_RADII`)."""
    focal = float(camera["camera_matrix"][0][0])
    rot = cv2.Rodrigues(np.asarray(camera["rvec"], float))[0]
    centre = -rot.T @ np.asarray(camera["tvec"], float).ravel()
    radius_px = {name: focal * m["radius_m"] / float(np.linalg.norm(centre - np.asarray(m["position_m"], float)))
                 for name, m in scene["markers"].items() if "position_m" in m and "radius_m" in m}
    tip = truth[(truth.marker == "tip") & truth.visible].set_index("frame")
    others = truth[(truth.marker != "tip") & truth.visible & truth.frame.isin(tip.index)
                   & truth.marker.isin(list(radius_px))]
    gap = (np.hypot(others.x_px.to_numpy() - tip.loc[others.frame, "x_px"].to_numpy(),
                    others.y_px.to_numpy() - tip.loc[others.frame, "y_px"].to_numpy())
           - CLEAR_TIP_RADII * radius_px["tip"] - others.marker.map(radius_px).to_numpy())
    crowded = set(others.frame.to_numpy()[gap < 0])
    return pd.Index([f for f in tip.index if f not in crowded])


def _phone_style(name: str, background_video: str | None, video_start_s: float) -> PhoneStyle:
    """The variant's recording style; a :data:`VIDEO_VARIANTS` one plays ``background_video`` behind the rig."""
    style = PhoneStyle(**PHONE_VARIANTS[name][0])
    if name not in VIDEO_VARIANTS:
        return style
    if background_video is None:
        raise ValueError(f"variant {name!r} plays a recording behind the rig: give one (background_video, "
                         "--background-video)")
    return replace(style, background_video=str(background_video), video_start_s=video_start_s)


def track_variant(name: str, *, duration_s: float = 1.0, seed: int = 0, protocols: tuple | None = None,
                  background_video: str | None = None, video_start_s: float = 0.0) -> dict:
    """Render one variant, track it with the user's protocol, and compare with the truth.

    ``protocols``: ``(scene, user, codec)`` to use instead of :func:`variant_protocols`'s (e.g. a user
    protocol that describes the marker differently); ``background_video`` (from ``video_start_s`` [s]): the
    recording a :data:`VIDEO_VARIANTS` variant plays behind the rig."""
    scene, user, codec = protocols if protocols is not None else variant_protocols(name, duration_s)
    with tempfile.TemporaryDirectory() as tmp:
        if codec == "phone":
            rendered = render_phone_video(scene, f"{tmp}/v", style=_phone_style(name, background_video, video_start_s),
                                          seed=seed)
        else:
            rendered = render_video(parse_protocol(scene), f"{tmp}/v", seed=seed, codec=codec, calibration_views=0)
        camera = load_camera(f"{tmp}/v/camera.json")
        warm_up()
        start = time.perf_counter()
        colour = user.get("markers", {}).get("tip", {}).get("colour", "any") != "any"
        with VideoFile(rendered["video"]).open(colour=colour) as frames:
            decoded = sum(1 for _ in frames)
        decode_wall = time.perf_counter() - start
        start = time.perf_counter()
        res = track(rendered["video"], camera, parse_protocol(user))
        wall = time.perf_counter() - start
        truth = pd.read_csv(f"{tmp}/v/truth.csv")
        clear = clear_frames(truth, scene, json.loads(Path(f"{tmp}/v/camera.json").read_text()))
        clear = clear[clear.isin(res.angles.frame)]  # frames the camera dropped are not in the record
        tip = truth[truth.marker == "tip"]
        m = res.angles.merge(tip[["frame", "visible", "theta_rad", "phi_rad", "x_px", "y_px"]], on="frame",
                             suffixes=("", "_true"))
        visible = m[m.visible_true if "visible_true" in m else m.visible]
        found = visible.dropna(subset=["theta_rad"])
        e_th = (found.theta_rad - found.theta_rad_true) / found.theta_sigma_rad
        e_ph = np.angle(np.exp(1j * (found.phi_rad - found.phi_rad_true))) / found.phi_sigma_rad
        wrong = (e_th.abs() > 5) | (e_ph.abs() > 5)
        mk = res.markers[res.markers.marker == "tip"].merge(tip[["frame", "x_px", "y_px"]], on="frame",
                                                            suffixes=("", "_true"))
        mk = mk[mk.frame.isin(found.frame)]
        err_px = np.sqrt(((mk.x_px - mk.x_px_true) ** 2 + (mk.y_px - mk.y_px_true) ** 2).mean() / 2)
        centroid = _centroid_rms(Path(rendered["video"]), truth, found.frame.to_numpy(), rendered.get("kept"))
    ok = ~wrong
    return {"variant": name, "frames": res.frames, "tip_visible": int(len(visible)),
            "tracked_fraction": len(found) / max(len(visible), 1), "tip_clear": int(len(clear)),
            "tracked_clear_fraction": float(found.frame.isin(clear).sum() / max(len(clear), 1)),
            "wrong": int(wrong.sum()),
            "wrong_ok": int((wrong & (found.quality == "ok")).sum()),
            "pull_sd_theta": float(e_th[ok].std()), "pull_sd_phi": float(e_ph[ok].std()),
            "rms_error_px": float(err_px), "centroid_rms_px": centroid, "frames_per_s": res.frames / wall,
            "loop_frames_per_s": res.frames / res.track_s, "decode_frames_per_s": decoded / decode_wall,
            "sigma_factor": res.sigma_check.factor if res.sigma_check else math.nan,
            "sigma_scaled": bool(res.sigma_check.applied) if res.sigma_check else False}


def variant_benchmark(names=VARIANTS, *, duration_s: float = 1.0, seed: int = 0, progress=None,
                      background_video: str | None = None, video_start_s: float = 0.0) -> pd.DataFrame:
    """:func:`track_variant` for each variant; one row each."""
    rows = []
    for k, name in enumerate(names):
        rows.append(track_variant(name, duration_s=duration_s, seed=seed, background_video=background_video,
                                  video_start_s=video_start_s))
        if progress:
            progress(k + 1, len(names))
    return pd.DataFrame(rows)
