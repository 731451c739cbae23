"""Footage that looks recorded: the rig's markers on a real photograph, through a phone's encoder.

The markers come from the renderer (:func:`gyrorig.render.render_frames`: the simulator's trajectory,
the camera model, motion blur, rolling shutter) as each pixel's coverage by a marker; the scene
behind them is a real photograph (one of scikit-image's, e.g. ``coffee``, ``brick``, ``astronaut``),
drifting across the field (something moving behind the rig) under flickering light.  Composited in
linear light, with shot and read noise, then encoded as a phone does: the BT.709 transfer curve (the
file tagged with it, as phones tag theirs; or an untagged power law), 8-bit YUV 4:2:0 in the limited range,
H.264 or HEVC at a constant quality, frame times on a 90 kHz clock with jitter and dropped frames, or a
slow-motion file whose container rate is lower than the capture rate.

The truth beside the video is the renderer's (frame numbers on the capture grid); the camera file is the
one a user would write: intrinsics and pose, frame rate and exposure, no sensor numbers (and the gamma only
for an untagged file).
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd

from .. import _io
from ..camera import camera_setup
from ..protocols import Protocol, parse_protocol
from .paths import marker_paths
from .video import TRUTH_COLUMNS, render_frames

__all__ = ["PhoneStyle", "PHOTOS", "render_phone_video", "photo_background"]

#: scikit-image's bundled photographs used as backgrounds
PHOTOS = ("coffee", "brick", "astronaut", "camera", "rocket", "gravel", "chelsea")

#: the renderer's marker brightness in the composite's helper render (every marker alike): light / this = coverage
_COVERAGE_E_PER_S = 1.0e9


@dataclass(frozen=True)
class PhoneStyle:
    """How the recording is made and stored."""

    #: a scikit-image photograph (:data:`PHOTOS`), or None for a flat grey background
    photo: str | None = "coffee"
    #: a real recording (any file FFmpeg reads) played behind the rig at its own speed from ``video_start_s``,
    #: in place of the photograph: its own sensor noise, codec and motion (hands, people) behind the tip
    background_video: str | None = None
    video_start_s: float = 0.0
    #: background brightness (linear, 0-1, of the photograph's brightest value)
    background_level: float = 0.55
    #: the background drifts by this many pixels per second (something moving behind the rig); 0: static
    drift_px_per_s: float = 40.0
    #: the photograph's place behind the rig is drawn per seed, up to this many pixels either way along each axis
    #: (each seed sees other texture under the tip: the texture's errors vary between seeds as between recordings)
    photo_shift_px: float = 80.0
    #: light flicker: relative amplitude and frequency [Hz]
    flicker_fraction: float = 0.03
    flicker_hz: float = 7.0
    #: lamps on the mains (an LED lamp's light rippling at twice the mains frequency, by up to its whole level):
    #: relative amplitude and frequency [Hz], and the time the phone's rolling shutter takes from the top row to
    #: the bottom one [s] (the ripple then lies across the picture as bands); 0: no ripple
    mains_fraction: float = 0.0
    mains_hz: float = 100.0
    mains_readout_s: float = 0.004
    #: the markers' linear RGB (a white retroreflective dot near full scale; a red sticker (0.7, 0.05, 0.05))
    marker_rgb: tuple[float, float, float] = (0.97, 0.97, 0.97)
    #: "libx264" or "libx265"; "ffv1" keeps every value
    codec: str = "libx265"
    #: constant-quality factor of the encoder (phones record at about 20-28)
    crf: int = 23
    #: the most B pictures in a row (0: only I and P pictures, as many phones' hardware encoders write); None: the
    #: encoder's own choice
    b_frames: int | None = None
    #: 8 or 10 bits per value in the file
    bit_depth: int = 8
    #: the transfer curve of the stored values, tagged in the file ("bt709", as phones record SDR video); None: the
    #: power law ``gamma`` (recorded = linear^(1/gamma)), the file untagged and the gamma written in camera.json
    transfer: str | None = "bt709"
    gamma: float = 2.2
    #: full well and read noise of a phone pixel [e]
    full_well_e: float = 6000.0
    read_noise_e: float = 3.0
    #: frame-time jitter (SD, as a fraction of the frame interval) and the fraction of frames dropped
    jitter_fraction: float = 0.05
    drop_fraction: float = 0.02
    #: the container's frame rate when it differs from the capture rate (slow motion); None: the capture rate
    container_fps: float | None = None
    #: a slow-motion file as a phone's gallery app shares it: the first and last this many seconds of the capture
    #: play at normal speed (every ``fps / container_fps``-th captured frame kept), the speed ramping down to and up
    #: from the slowed middle over a few frames, all stored at the one container rate (nothing in the file says
    #: where the speed changes); (0, 0): the original file, every captured frame kept
    normal_speed_ends_s: tuple[float, float] = (0.0, 0.0)
    #: a hand-held phone: the whole picture (rig and scene) moves by this RMS per axis [px] (a small rotation of the
    #: camera), smoothly at about ``shake_hz``; 0: on a tripod
    shake_px: float = 0.0
    shake_hz: float = 3.0
    #: ... and turns about its optical axis by this RMS [deg] (the picture rotates about its centre), alike in time
    shake_roll_deg: float = 0.0
    #: the phone's rolling shutter: the time from its top row to its bottom one [s], which its user does not know
    #: (camera.json then says ``"shutter": "rolling"`` with ``readout_time_s`` null); 0: the scene's own shutter
    readout_s: float = 0.0
    #: the phone records from before the release: the top held still (its rotor spinning) for so long first [s]
    hold_s: float = 0.0

    def check(self) -> None:
        if self.photo is not None and self.photo not in PHOTOS:
            raise ValueError(f"photo = {self.photo!r}: allowed {', '.join(PHOTOS)} or None")
        if self.background_video is not None and not Path(self.background_video).is_file():
            raise ValueError(f"background_video = {self.background_video!r}: not a file")
        if not 0.0 <= self.video_start_s < 1e5:
            raise ValueError(f"video_start_s = {self.video_start_s}: allowed [0, 1e5) s")
        if self.codec not in ("libx264", "libx265", "ffv1"):
            raise ValueError(f"codec = {self.codec!r}: allowed 'libx264', 'libx265', 'ffv1'")
        if self.transfer not in ("bt709", None):
            raise ValueError(f"transfer = {self.transfer!r}: allowed 'bt709' or None")
        if self.bit_depth not in (8, 10):
            raise ValueError(f"bit_depth = {self.bit_depth}: allowed 8, 10")
        if self.b_frames is not None and not 0 <= self.b_frames <= 16:
            raise ValueError(f"b_frames = {self.b_frames}: allowed 0-16 or None")
        if not 0.0 <= self.drop_fraction < 0.5:
            raise ValueError(f"drop_fraction = {self.drop_fraction}: allowed [0, 0.5)")
        if not 0.0 <= self.jitter_fraction < 0.25:
            raise ValueError(f"jitter_fraction = {self.jitter_fraction}: allowed [0, 0.25)")
        if not 0.0 <= self.photo_shift_px <= 1000.0:
            raise ValueError(f"photo_shift_px = {self.photo_shift_px}: allowed [0, 1000] px")
        if any(not 0.0 <= e < 1e3 for e in self.normal_speed_ends_s) or (
                any(self.normal_speed_ends_s) and not self.container_fps):
            raise ValueError(f"normal_speed_ends_s = {self.normal_speed_ends_s}: allowed [0, 1000) s each, and only "
                             "with container_fps (a slow-motion file)")
        if not 0.0 <= self.shake_px < 50.0 or not self.shake_hz > 0.0:
            raise ValueError(f"shake_px = {self.shake_px}, shake_hz = {self.shake_hz}: allowed [0, 50) px, > 0 Hz")
        if not 0.0 <= self.mains_fraction <= 1.0 or not self.mains_hz > 0.0 or not self.mains_readout_s >= 0.0:
            raise ValueError(f"mains_fraction = {self.mains_fraction}, mains_hz = {self.mains_hz}, mains_readout_s = "
                             f"{self.mains_readout_s}: allowed [0, 1], > 0 Hz, >= 0 s")
        if not 0.0 <= self.readout_s < 1.0:
            raise ValueError(f"readout_s = {self.readout_s}: allowed [0, 1) s (the scene's camera refuses one beyond "
                             "its frame interval)")
        if not 0.0 <= self.shake_roll_deg < 5.0:
            raise ValueError(f"shake_roll_deg = {self.shake_roll_deg}: allowed [0, 5) deg")
        if not 0.0 <= self.hold_s < 1e3:
            raise ValueError(f"hold_s = {self.hold_s}: allowed [0, 1000) s")


#: FFmpeg's code of the BT.709 transfer characteristic (AVCOL_TRC_BT709)
_TRC_BT709 = 1


def _encoder_options(style: PhoneStyle) -> dict[str, str]:
    """The lossy encoder's options: constant quality, a fast preset, and the B pictures the style asks for."""
    options = {"crf": str(style.crf), "preset": "veryfast"}
    if style.codec == "libx265":
        bframes = f":bframes={style.b_frames}" if style.b_frames is not None else ""
        options["x265-params"] = "log-level=error" + bframes
    elif style.b_frames is not None:
        options["bf"] = str(style.b_frames)
    return options


def _encoded(linear: np.ndarray, style: PhoneStyle) -> np.ndarray:
    """Stored values (0-1) of linear light (0-1): the BT.709 OETF, or the power law ``1 / gamma``."""
    if style.transfer == "bt709":
        return np.where(linear < 0.018, 4.5 * linear, 1.099 * np.power(linear, 0.45) - 0.099)
    return linear ** (1.0 / style.gamma)


def _shake(style: PhoneStyle, rng: np.random.Generator):
    """The picture's displacement ``(dx, dy)`` [px] and turn about its centre [rad] at a time: per axis two sines
    (``shake_hz`` and 2.3 times it, the second at half the amplitude) with random phases, ``shake_px`` and
    ``shake_roll_deg`` RMS.  None without shake (no draws)."""
    if style.shake_px == 0.0 and style.shake_roll_deg == 0.0:
        return None
    phases = rng.uniform(0.0, 2 * math.pi, (2, 2)) if style.shake_px else np.zeros((2, 2))
    roll = rng.uniform(0.0, 2 * math.pi, 2) if style.shake_roll_deg else np.zeros(2)
    unit = 1.0 / math.sqrt(0.5 * (1.0 + 0.25))
    amps = (style.shake_px * unit, style.shake_px * unit, math.radians(style.shake_roll_deg) * unit)

    def at(t: float) -> tuple[float, float, float]:
        w = 2 * math.pi * style.shake_hz * t
        return tuple(a * (math.sin(w + p[0]) + 0.5 * math.sin(2.3 * w + p[1])) for a, p in zip(amps, (*phases, roll)))
    return at


def _light(style: PhoneStyle, t_s: float, exposure_s: float, height_px: int):
    """The light on the scene in the frame starting at ``t_s``: the slow flicker, times the mains ripple at each row's
    mid-exposure (each row exposed a little later than the one above it) as an (h, 1, 1) array when there is one."""
    light = 1.0 + style.flicker_fraction * math.sin(2 * math.pi * style.flicker_hz * t_s)
    if not style.mains_fraction:
        return light
    rows = t_s + exposure_s / 2 + style.mains_readout_s * np.arange(height_px) / height_px
    return (light * (1.0 + style.mains_fraction * np.sin(2 * np.pi * style.mains_hz * rows))).astype(
        np.float32)[:, None, None]


def _shaken(linear: np.ndarray, truth: pd.DataFrame, move: tuple[float, float, float]
            ) -> tuple[np.ndarray, pd.DataFrame]:
    """The picture moved by ``(dx, dy, turn)`` (a turn about its centre [rad], then the shift [px]), and the truth's
    pixels with it."""
    h, w = linear.shape[:2]
    dx, dy, turn = move
    m = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), math.degrees(turn), 1.0) + np.array([[0, 0, dx],
                                                                                                 [0, 0, dy]])
    linear = cv2.warpAffine(linear, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    moved = m @ np.vstack([truth.x_px, truth.y_px, np.ones(len(truth))])
    return linear, truth.assign(x_px=moved[0], y_px=moved[1])


def photo_background(name: str | None, width_px: int, height_px: int, margin_px: int) -> np.ndarray:
    """The photograph in linear RGB (0-1), resized to cover the frame plus ``margin_px`` on every side."""
    w, h = width_px + 2 * margin_px, height_px + 2 * margin_px
    if name is None:
        return np.full((h, w, 3), 0.5, np.float32)
    import skimage.data

    img = getattr(skimage.data, name)()
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return _covering(img[:, :, :3].astype(np.float32) / 255.0, w, h)


def _covering(img: np.ndarray, w: int, h: int) -> np.ndarray:
    """An RGB image (0-1) scaled to cover ``w`` x ``h`` and cut to it, in linear light (the power law 2.2)."""
    scale = max(w / img.shape[1], h / img.shape[0])
    img = cv2.resize(img, (int(math.ceil(img.shape[1] * scale)), int(math.ceil(img.shape[0] * scale))),
                     interpolation=cv2.INTER_CUBIC)
    return np.clip(img[:h, :w], 0.0, 1.0) ** 2.2


class _Recording:
    """A real recording behind the rig: its picture at a time [s from ``start_s``], cross-faded between the two
    frames around it, in linear RGB covering the frame plus ``margin_px`` on every side.  Frames are decoded once,
    in order (times asked for must not decrease)."""

    def __init__(self, path: str, width_px: int, height_px: int, margin_px: int, start_s: float):
        import av

        self._path, self._start = path, start_s
        self._size = (width_px + 2 * margin_px, height_px + 2 * margin_px)
        self._container = av.open(path)
        stream = self._container.streams.video[0]
        rate = stream.guessed_rate or stream.average_rate  # for frames without times (a raw H.264 stream)
        self._rate, self._count = float(rate) if rate else 0.0, 0
        self._frames = self._container.decode(stream)
        self._t0: float | None = None
        self._before = self._after = self._next()

    def _next(self) -> tuple[float, np.ndarray]:
        try:
            frame = next(self._frames)
        except StopIteration:
            raise ValueError(f"background_video = {self._path!r}: the recording ends before the render does "
                             f"(from video_start_s = {self._start} s)") from None
        if frame.time is not None:
            t = float(frame.time)
        elif self._rate > 0.0:
            t = self._count / self._rate
        else:
            raise ValueError(f"background_video = {self._path!r}: its frames carry no times and its stream no frame "
                             "rate")
        self._count += 1
        self._t0 = t if self._t0 is None else self._t0
        img = frame.to_ndarray(format="rgb24").astype(np.float32) / 255.0
        return t - self._t0, _covering(img, *self._size)

    def at(self, t_s: float) -> np.ndarray:
        t = self._start + t_s
        while self._after[0] < t:
            self._before, self._after = self._after, self._next()
        (ta, a), (tb, b) = self._before, self._after
        if tb <= ta or t <= ta:
            return b if t >= tb else a
        f = np.float32((t - ta) / (tb - ta))
        return a * (1.0 - f) + b * f

    def close(self) -> None:
        self._container.close()


def _coverage_protocol(scene: Mapping[str, Any] | Protocol, readout_s: float = 0.0) -> Protocol:
    """The scene (a protocol, or its dict) with every dot of one brightness and no background: the render is each
    pixel's coverage; with ``readout_s``, through a rolling shutter of that readout."""
    d = copy.deepcopy(dict(scene.extra if isinstance(scene, Protocol) else scene))
    for m in d["markers"].values():
        if m.get("kind", "dot") != "occluder":
            m["brightness_e_per_s"] = _COVERAGE_E_PER_S
    d["camera"] = dict(d["camera"])
    d["camera"]["sensor"] = {**d["camera"].get("sensor", {}), "background_e_per_s": 0.0}
    d["camera"]["illumination_drift_fraction"] = 0.0
    if readout_s:
        d["camera"].update(shutter="rolling", readout_time_s=readout_s)
    if isinstance(scene, Protocol):
        return replace(scene, extra={**scene.extra, "markers": d["markers"], "camera": d["camera"]})
    return parse_protocol(d)


def _frame_times(n: int, fps: float, style: PhoneStyle, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Which capture frames are kept, and their stored times [s] (container clock)."""
    if any(style.normal_speed_ends_s):
        return _gallery_frames(n, fps, style)
    keep = np.ones(n, bool)
    if style.drop_fraction > 0 and n > 2:
        drop = rng.random(n) < style.drop_fraction
        drop[0] = drop[-1] = False
        keep &= ~drop
    k = np.flatnonzero(keep)
    store_fps = style.container_fps or fps
    t = k / store_fps + rng.normal(0.0, style.jitter_fraction / store_fps, len(k))
    t[0] = 0.0
    t = np.maximum.accumulate(t + 1e-9 * np.arange(len(k)))  # times keep their order
    return k, t


def _gallery_frames(n: int, fps: float, style: PhoneStyle) -> tuple[np.ndarray, np.ndarray]:
    """A gallery copy's frames (:attr:`PhoneStyle.normal_speed_ends_s`): every ``r``-th captured frame in the
    normal-speed ends, steps of ``r - 1 .. 2`` frames in the ramps, every frame in the middle; stored one container
    interval apart."""
    r = max(int(round(fps / style.container_fps)), 1)
    head, tail = (int(round(e * fps)) for e in style.normal_speed_ends_s)
    ramp = list(range(r - 1, 1, -1))
    steps = [r] * (head // r) + ramp if head else []
    k, frames = 0, [0]
    for step in steps:
        k += step
        frames.append(k)
    last_slow = n - 1 - (tail + sum(ramp) if tail else 0)
    frames += list(range(k + 1, max(last_slow, k) + 1))
    k = frames[-1]
    for step in (ramp[::-1] + [r] * (tail // r) if tail else []):
        k += step
        if k >= n:
            break
        frames.append(k)
    keep = np.asarray(frames, int)
    return keep, np.arange(len(keep)) / float(style.container_fps)


def _video_stream(container, style: PhoneStyle, cam):
    """The output's video stream, as a phone's encoder sets it up: the codec, YUV 4:2:0 (4:4:4 for FFV1) at the
    style's depth, a 90 kHz clock, the transfer curve stated."""
    stream = container.add_stream(style.codec, rate=Fraction(round(cam.fps * 1000), 1000))
    stream.width, stream.height = cam.width_px, cam.height_px
    ten = style.bit_depth == 10
    stream.pix_fmt = ("yuv420p10le" if ten else "yuv420p") if style.codec != "ffv1" else \
        ("yuv444p10le" if ten else "yuv444p")
    stream.time_base = stream.codec_context.time_base = Fraction(1, 90000)
    if style.transfer == "bt709":
        stream.codec_context.color_trc = _TRC_BT709
    if style.codec != "ffv1":
        stream.options = _encoder_options(style)
    return stream


def render_phone_video(scene: Mapping[str, Any] | Protocol, out_dir: str | Path, *, style: PhoneStyle = PhoneStyle(),
                       seed: int = 0, duration_s: float | None = None) -> dict:
    """Render the scene (a protocol, or its dict, with ``[camera]`` and ``[markers]``) as a phone recording.

    Writes ``video.mp4`` (or ``video.mkv`` for FFV1), ``truth.csv`` (the renderer's, every capture frame) and
    ``camera.json`` (what a user knows: intrinsics, pose, capture fps, exposure, gamma; no sensor numbers),
    each under a temporary name renamed when complete.  Returns the paths, the frames kept and the stored
    times.
    """
    import av

    style.check()
    rng = np.random.default_rng(seed)
    protocol = _coverage_protocol(scene, style.readout_s)
    setup = camera_setup(protocol)
    cam = setup.camera
    duration = (protocol.scene.duration_s if duration_s is None else float(duration_s)) + style.hold_s
    n = int(math.floor(duration * cam.fps + 1e-9))
    paths = marker_paths(protocol, setup, duration, style.hold_s)
    keep, t_store = _frame_times(n, cam.fps, style, rng)
    shake = _shake(style, rng)
    placed = rng.uniform(-style.photo_shift_px, style.photo_shift_px, 2)
    margin = int(math.ceil(abs(style.drift_px_per_s) * duration + style.photo_shift_px)) + 2
    photo = photo_background(style.photo, cam.width_px, cam.height_px, margin) if not style.background_video else None
    peak = _COVERAGE_E_PER_S * cam.exposure_s
    rgb = np.asarray(style.marker_rgb, np.float32)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = "video.mkv" if style.codec == "ffv1" else "video.mp4"
    tmp = out / f".{name}.partial{Path(name).suffix}"
    kept = set(int(k) for k in keep)
    stored = dict(zip((int(k) for k in keep), t_store))
    records = []  # the truth's rows as tuples (a frame's small table kept per frame fragments the heap)
    recording = None
    container = av.open(str(tmp), "w", format="matroska" if style.codec == "ffv1" else "mp4")
    try:
        if photo is None:
            recording = _Recording(style.background_video, cam.width_px, cam.height_px, margin, style.video_start_s)
        stream = _video_stream(container, style, cam)
        clock, ten, top = Fraction(1, 90000), style.bit_depth == 10, (1 << style.bit_depth) - 1
        frames = render_frames(protocol, seed=seed, duration_s=duration, noise=False, setup=setup, paths=paths)
        for k, (image, truth) in enumerate(frames):
            if k not in kept:
                records.extend(truth.itertuples(index=False, name=None))
                continue
            t = k / cam.fps
            shift = style.drift_px_per_s * t  # along (0.8, 0.6), by fractions of a pixel (bilinear)
            centre = (margin + placed[0] + 0.8 * shift + (cam.width_px - 1) / 2,
                      margin + placed[1] + 0.6 * shift + (cam.height_px - 1) / 2)
            bg = cv2.getRectSubPix(photo if recording is None else recording.at(t), (cam.width_px, cam.height_px),
                                   centre) * style.background_level
            alpha = np.clip(np.asarray(image, np.float32) / peak, 0.0, 1.0)[:, :, None]
            linear = (bg * (1.0 - alpha) + alpha * rgb) * _light(style, t, cam.exposure_s, cam.height_px)
            if shake is not None:  # the camera turned a little: the whole picture moves (the truth's pixels with it)
                linear, truth = _shaken(linear, truth, shake(t + cam.exposure_s / 2))
            records.extend(truth.itertuples(index=False, name=None))
            electrons = rng.poisson(np.clip(linear, 0.0, 1.0) * style.full_well_e).astype(np.float32)
            electrons += rng.normal(0.0, style.read_noise_e, electrons.shape).astype(np.float32)
            value = _encoded(np.clip(electrons / style.full_well_e, 0.0, 1.0), style)
            quantised = np.round(value * top)
            if ten:  # quantised to 10 bits, given as rgb48le (16-bit values: scaled up to its full range)
                frame = av.VideoFrame.from_ndarray((quantised * (65535 / top)).astype(np.uint16), format="rgb48le")
            else:
                frame = av.VideoFrame.from_ndarray(quantised.astype(np.uint8), format="rgb24")
            frame.pts = int(round(stored[k] * 90000))
            frame.time_base = clock
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
        container.close()
        os.chmod(tmp, 0o644)
        os.replace(tmp, out / name)
    finally:
        if recording is not None:
            recording.close()
        try:
            container.close()
        except Exception:  # noqa: BLE001 - already closed, or failed while writing: the file is removed below
            pass
        if tmp.exists():
            tmp.unlink()
    truth = pd.DataFrame(records, columns=list(TRUTH_COLUMNS))
    _io.write_csv(truth, out / "truth.csv")
    camera = {k: v for k, v in cam.to_json().items() if k not in ("sensor", "psf_sigma_px", "motion_blur_samples")}
    camera["sensor"] = {"bit_depth": style.bit_depth, **({} if style.transfer else {"gamma": style.gamma})}
    if style.container_fps:  # slow motion: the user states the capture rate
        camera["capture_fps"] = cam.fps
    if style.readout_s:  # a phone's rolling shutter, its readout not known to its user
        camera["readout_time_s"] = None
    _io.write_json(camera, out / "camera.json")
    return {"video": str(out / name), "truth": str(out / "truth.csv"), "camera": str(out / "camera.json"),
            "frames": n, "kept": keep.tolist(), "stored_t_s": t_store.tolist()}

