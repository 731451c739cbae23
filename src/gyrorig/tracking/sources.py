"""Where frames come from: a video file (decoded in a background thread), a folder of images, or
frames held in memory.

A source opens to :class:`Frames`: the image size, the nominal frame rate (NaN when unknown),
the frame count (0 when unknown) and an iterator of ``(image, t_s)`` pairs, ``image`` a 2-D
array (the first channel of a colour frame) and ``t_s`` the frame's start time from the
container's timestamps (NaN when the source has none: the tracker then counts frames at the
camera's rate).

An image folder (:class:`ImageFolder`) holds one image per frame (PNG or TIFF, 8 or 16 bit; a
16-bit file may carry 12-bit values), in name order (numbers in names compare as numbers:
``f9.png`` before ``f10.png``); its frame times come from ``timestamps.csv`` in the folder (or a
file given), with columns ``frame, t_s`` and one row per image in the same order (a camera that
dropped frames leaves gaps in ``t_s``), or else from the camera's rate.
"""

from __future__ import annotations

import hashlib
import math
import queue
import re
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .errors import BadInputError, TrackingError

__all__ = ["Frames", "VideoFile", "ImageFolder", "FrameArrays", "as_source", "fingerprint", "IMAGE_SUFFIXES"]


#: container codes (FourCC) of codecs that keep every pixel value: FFV1, raw, Y800/GREY/Y16, HuffYUV, PNG
LOSSLESS_FOURCC = {"ffv1", "FFV1", "\x00\x00\x00\x00", "Y800", "GREY", "Y16 ", "HFYU", "huff", "FFVH", "png ",
                   "MPNG", "rawv", "DIB "}


@dataclass
class Frames:
    """An opened source; iterate it for ``(image, t_s)``, close it when done (or use ``with``).

    ``lossy``: the codec changes pixel values (mp4v, H.264, MJPEG ...): the sensor's noise model then
    does not describe them."""

    width_px: int
    height_px: int
    fps: float
    count: int
    items: Iterator[tuple[np.ndarray, float]]
    lossy: bool = False

    def __iter__(self) -> Iterator[tuple[np.ndarray, float]]:
        return self.items

    def close(self) -> None:
        close = getattr(self.items, "close", None)
        if close is not None:
            close()

    def __enter__(self) -> "Frames":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class VideoFile:
    """A video container read through OpenCV's FFmpeg backend (frame times from its timestamps)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def __str__(self) -> str:
        return str(self.path)

    def fingerprint(self) -> str:
        """The file's size and its first and last MiB, hashed: the same recording wherever it is copied."""
        h = hashlib.sha256()
        try:
            size = self.path.stat().st_size
            h.update(str(size).encode())
            with open(self.path, "rb") as f:
                h.update(f.read(_FINGERPRINT_BYTES))
                f.seek(max(size - _FINGERPRINT_BYTES, 0))
                h.update(f.read(_FINGERPRINT_BYTES))
        except OSError as exc:
            raise BadInputError(f"cannot read video {self.path}: {exc}") from exc
        return h.hexdigest()

    def open(self) -> Frames:
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            why = "no such file" if not self.path.exists() else "empty file" if self.path.stat().st_size == 0 else \
                "not a video OpenCV's FFmpeg can decode"
            raise BadInputError(f"cannot open video {self.path}: {why}")
        # unconverted frames: 16-bit FFV1 stays 16-bit, a YUV codec gives its luma plane (OpenCV warns
        # about that on every frame; its warnings are silenced while the file is read)
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode("latin-1")
        return Frames(w, h, float(cap.get(cv2.CAP_PROP_FPS)), int(cap.get(cv2.CAP_PROP_FRAME_COUNT)),
                      _decoded_frames(cap, on_close=lambda: cv2.utils.logging.setLogLevel(level)),
                      lossy=fourcc not in LOSSLESS_FOURCC)


class FrameArrays:
    """Frames held in memory (2-D arrays of one size), with their start times [s] if known."""

    def __init__(self, frames: Sequence[np.ndarray], t_s: Sequence[float] | None = None, *, name: str = "frames"):
        if not len(frames):
            raise TrackingError(f"{name}: no frames")
        shapes = {np.shape(f)[:2] for f in frames}
        if len(shapes) != 1:
            raise TrackingError(f"{name}: frames of different sizes {sorted(shapes)}")
        if t_s is not None and len(t_s) != len(frames):
            raise TrackingError(f"{name}: {len(t_s)} times for {len(frames)} frames")
        self.frames, self.t_s, self.name = frames, t_s, name

    def __str__(self) -> str:
        return self.name

    def fingerprint(self) -> None:
        """Frames in memory have no recording to recognise later."""
        return None

    def open(self) -> Frames:
        h, w = np.shape(self.frames[0])[:2]
        times = self.t_s if self.t_s is not None else [math.nan] * len(self.frames)
        items = ((f[:, :, 0] if f.ndim == 3 else f, float(t)) for f, t in zip(self.frames, times))
        return Frames(int(w), int(h), math.nan, len(self.frames), items)


#: image files an :class:`ImageFolder` reads
IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


def _name_key(path: Path) -> list:
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", path.name.lower())]


class ImageFolder:
    """A folder of images, one per frame (see the module docstring)."""

    def __init__(self, path: str | Path, timestamps: str | Path | None = None):
        self.path = Path(path)
        if not self.path.is_dir():
            raise BadInputError(f"{self.path}: not a folder of images")
        self.files = sorted((f for f in self.path.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES and f.is_file()),
                            key=_name_key)
        if not self.files:
            raise BadInputError(f"{self.path}: no images ({', '.join(IMAGE_SUFFIXES)})")
        stamps = Path(timestamps) if timestamps is not None else self.path / "timestamps.csv"
        self.t_s = self._read_timestamps(stamps) if (timestamps is not None or stamps.exists()) else None

    def _read_timestamps(self, path: Path) -> np.ndarray:
        import pandas as pd

        try:
            table = pd.read_csv(path)
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise BadInputError(f"cannot read timestamps {path}: {exc}") from exc
        if "t_s" not in table.columns:
            raise BadInputError(f"{path}: needs a column t_s (and frame), one row per image")
        t = pd.to_numeric(table["t_s"], errors="coerce").to_numpy(float)
        if len(t) != len(self.files):
            raise BadInputError(f"{path}: {len(t)} rows for {len(self.files)} images in {self.path}")
        bad = np.flatnonzero(~np.isfinite(t))
        if len(bad):
            raise BadInputError(f"{path}: row {int(bad[0]) + 1}, column t_s: not a number")
        back = np.flatnonzero(np.diff(t) <= 0)
        if len(back):
            raise BadInputError(f"{path}: row {int(back[0]) + 2}, column t_s: times must increase "
                                f"({t[back[0]]:g} then {t[back[0] + 1]:g})")
        return t

    def __str__(self) -> str:
        return str(self.path)

    def fingerprint(self) -> str:
        """The images' names and sizes and the frame times, hashed."""
        h = hashlib.sha256()
        for f in self.files:
            h.update(f"{f.name}\0{f.stat().st_size}\0".encode())
        if self.t_s is not None:
            h.update(np.asarray(self.t_s, float).tobytes())
        return h.hexdigest()

    def _read(self, k: int) -> np.ndarray:
        image = cv2.imread(str(self.files[k]), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise BadInputError(f"{self.files[k]}: unreadable image")
        if image.dtype not in (np.uint8, np.uint16):
            raise BadInputError(f"{self.files[k]}: {image.dtype} pixels; allowed 8- or 16-bit")
        return image[:, :, 0] if image.ndim == 3 else image

    def open(self) -> Frames:
        first = self._read(0)
        h, w = first.shape
        times = self.t_s if self.t_s is not None else [math.nan] * len(self.files)

        def items():
            for k, t in enumerate(times):
                image = first if k == 0 else self._read(k)
                if image.shape != (h, w):
                    raise BadInputError(f"{self.files[k]}: {image.shape[1]} x {image.shape[0]} pixels; the first "
                                        f"image ({self.files[0].name}) is {w} x {h}")
                yield np.ascontiguousarray(image), float(t)

        return Frames(int(w), int(h), math.nan, len(self.files), items())


#: bytes read from each end of a video file for its fingerprint
_FINGERPRINT_BYTES = 1 << 20


def fingerprint(video) -> str | None:
    """A digest that recognises a recording again (a copy of it too); None for frames in memory."""
    source = as_source(video)
    return source.fingerprint() if hasattr(source, "fingerprint") else None


def as_source(video) -> VideoFile | ImageFolder | FrameArrays:
    """A path (str or Path) becomes a :class:`VideoFile`, or an :class:`ImageFolder` when it is a folder;
    a source is returned as it is."""
    if isinstance(video, (str, Path)):
        return ImageFolder(video) if Path(video).is_dir() else VideoFile(video)
    if hasattr(video, "open"):
        return video
    raise TypeError(f"expected a video path or a frame source, got {type(video).__name__}")


def _decoded_frames(cap: cv2.VideoCapture, depth: int = 8, on_close=None) -> Iterator[tuple[np.ndarray, float]]:
    """Yield ``(frame, start time s)``, decoding in a background thread.

    OpenCV releases the GIL while decoding, so decoding the next frames overlaps with
    tracking this one (two cores: throughput is the slower of the two, not their sum).
    """
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            ok, frame = cap.read()
            q.put((frame, cap.get(cv2.CAP_PROP_POS_MSEC)) if ok else None)
            if not ok:
                return

    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is None:
                return
            frame, pos_ms = item
            yield (frame[:, :, 0] if frame.ndim == 3 else frame), (pos_ms / 1000.0 if pos_ms >= 0 else math.nan)
    finally:
        stop.set()
        while thread.is_alive():  # unblock a reader waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                pass
            thread.join(timeout=0.05)
        cap.release()
        if on_close is not None:
            on_close()
