"""Where frames come from: a video file (decoded in a background thread) or frames held in memory.

A source opens to :class:`Frames`: the image size, the nominal frame rate (NaN when unknown),
the frame count (0 when unknown) and an iterator of ``(image, t_s)`` pairs, ``image`` a 2-D
array (the first channel of a colour frame) and ``t_s`` the frame's start time from the
container's timestamps (NaN when the source has none: the tracker then counts frames at the
camera's rate).
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .errors import TrackingError

__all__ = ["Frames", "VideoFile", "FrameArrays", "as_source"]


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

    def open(self) -> Frames:
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            raise TrackingError(f"cannot open video {self.path}")
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

    def open(self) -> Frames:
        h, w = np.shape(self.frames[0])[:2]
        times = self.t_s if self.t_s is not None else [math.nan] * len(self.frames)
        items = ((f[:, :, 0] if f.ndim == 3 else f, float(t)) for f, t in zip(self.frames, times))
        return Frames(int(w), int(h), math.nan, len(self.frames), items)


def as_source(video) -> VideoFile | FrameArrays:
    """A path (str or Path) becomes a :class:`VideoFile`; a source is returned as it is."""
    if isinstance(video, (str, Path)):
        return VideoFile(video)
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
