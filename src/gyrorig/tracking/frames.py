"""What every frame source opens to (:class:`Frames`), and what sources share: a frame as the tracker asked for
it (luma or RGB), the frames' own rate from their times (:func:`grid_fit`), a file's fingerprint."""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .errors import BadInputError

__all__ = ["Frames", "grid_fit", "file_fingerprint"]


@dataclass
class Frames:
    """An opened source; iterate it for ``(image, t_s)``, close it when done (or use ``with``).

    ``lossy``: the codec changes pixel values (mp4v, H.264, MJPEG ...): the sensor's noise model then
    does not describe them.  ``bit_depth``: bits per value as stored (None when the source does not say;
    16-bit files may carry fewer significant bits, as camera.json says)."""

    width_px: int
    height_px: int
    fps: float
    count: int
    items: Iterator[tuple[np.ndarray, float]]
    lossy: bool = False
    bit_depth: int | None = None
    #: each frame's picture type as the codec coded it (``I``, ``P``, ``B`` ...), filled as the frames are read;
    #: None when the source has none (image files, frames in memory)
    frame_types: list[str] | None = None
    #: the luma values that mean black and white (a YUV video in the "limited" range most phones record, and
    #: FFmpeg assumes when a file does not say, stores 16-235 at 8 bits, 64-940 at 10); None: 0 and the bit
    #: depth's largest value.  RGB frames (``colour``) come converted to the full range.
    levels: tuple[int, int] | None = None
    #: the transfer characteristic the stream states (:func:`gyrorig.tracking.transfer.transfer_of_video`: ``bt709``,
    #: ``hlg`` ...); None when it says none or the source is not a video
    transfer: str | None = None
    #: what went wrong while reading, filled as the frames are read (a stream that breaks off: the decoder's
    #: message); the frames before it stand
    problems: list[str] = field(default_factory=list)
    #: stretches of pictures the decoder reported damaged data in, or predicted from such (``(first, end,
    #: message)``, positions in the order delivered, ``end`` exclusive: up to the next key picture), filled when the
    #: stream has been read
    damaged: list[tuple[int, int, str]] = field(default_factory=list)
    #: the field order (:data:`~gyrorig.tracking.fields.FIELD_ORDERS`) of a video whose decoder flags its pictures
    #: interlaced; None: progressive, or not said
    interlaced: str | None = None
    #: the field order when these are the fields of interlaced pictures (:func:`~gyrorig.tracking.fields.field_frames`)
    fields: str | None = None

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


def grid_fit(t_s) -> tuple[float, float, int]:
    """The frames' interval: the slope of their times against their grid numbers, its standard error (from the times'
    scatter about the line) and the number of frames: ``(interval, se, n)``; NaN for fewer than two frames (the error
    for fewer than three).  The grid is found first as the rate at which the times line up best (their phases'
    coherence, searched within :data:`GRID_SEARCH` of the median interval's rate on ever longer stretches, each
    search narrowed to the last one's resolution), so that a clock's jitter, a first frame off the grid and dropped
    frames neither bias the rate nor make a late frame's number slip by one."""
    t = np.sort(np.asarray(t_s, float)[np.isfinite(np.asarray(t_s, float))])
    dt = np.diff(t)
    dt = dt[dt > 0]
    if not len(dt):
        return math.nan, math.nan, len(t)
    t = t - t[0]
    rate, width, m = 1.0 / float(np.median(dt)), GRID_SEARCH, min(len(t), 64)
    while True:
        part = t[:m]
        if part[-1] <= 0:
            break
        # the coherence's peak is 1 / (the stretch's duration) wide: searched in eighths of that
        count = int(math.ceil(2.0 * width * rate * part[-1] * 8.0)) + 1
        rates = rate * (1.0 + np.linspace(-width, width, count))
        rate = float(rates[np.argmax(_coherence(rates, part))])
        if m == len(t):
            break
        width, m = 4.0 / (rate * part[-1]), min(len(t), 4 * m)
    origin = float(np.angle(np.exp(2j * np.pi * rate * t).sum())) / (2.0 * np.pi * rate)
    n = np.round((t - origin) * rate)
    if len(np.unique(n)) < 2:
        return 1.0 / rate, math.nan, len(t)
    (step, _), resid = np.polyfit(n, t, 1, full=True)[:2]
    spread = float(np.sum((n - n.mean()) ** 2))
    se = math.sqrt(float(resid[0]) / (len(n) - 2) / spread) if len(resid) and len(n) > 2 else math.nan
    return float(step), se, len(t)


#: the frame rate :func:`grid_fit` looks for lies within this fraction of the median interval's
GRID_SEARCH = 0.05


def _coherence(rates: np.ndarray, t: np.ndarray, block: int = 1 << 20) -> np.ndarray:
    """How well the times ``t`` line up on a grid of each rate: the length of the mean of their phases' unit vectors,
    summed over blocks of the times (a long record's phases would not fit in memory at once)."""
    step = max(1, block // max(len(rates), 1))
    total = np.zeros(len(rates), complex)
    for k in range(0, len(t), step):
        total += np.exp(2j * np.pi * np.outer(rates, t[k:k + step])).sum(axis=1)
    return np.abs(total) / max(len(t), 1)


def _as_wanted(image: np.ndarray, colour: bool, order: str) -> np.ndarray:
    """A frame as the tracker asked for it: luma (Rec. 601 weights) or RGB; ``order`` is a colour frame's
    channel order (``RGB`` for frames in memory, ``BGR`` from OpenCV's image reader).  A grey frame asked
    for in colour is three equal channels."""
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[:, :, :3]
    if colour:
        if image.ndim == 2:
            return np.repeat(image[:, :, None], 3, axis=2)
        return image[:, :, ::-1] if order == "BGR" else image
    if image.ndim == 3:
        if image.dtype in (np.uint8, np.uint16):
            return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if order == "BGR" else cv2.COLOR_RGB2GRAY)
        return image @ (np.array([0.114, 0.587, 0.299]) if order == "BGR" else np.array([0.299, 0.587, 0.114]))
    return image


#: bytes read from each end of a video file for its fingerprint
_FINGERPRINT_BYTES = 1 << 20


def file_fingerprint(path: Path) -> str:
    """A file's size and its first and last MiB, hashed."""
    h = hashlib.sha256()
    try:
        size = path.stat().st_size
        h.update(str(size).encode())
        with open(path, "rb") as f:
            h.update(f.read(_FINGERPRINT_BYTES))
            f.seek(max(size - _FINGERPRINT_BYTES, 0))
            h.update(f.read(_FINGERPRINT_BYTES))
    except OSError as exc:
        raise BadInputError(f"cannot read {path}: {exc}") from exc
    return h.hexdigest()
