"""Where frames come from: a video file (decoded in a background thread), a folder of images, or
frames held in memory.

A source opens to :class:`Frames`: the image size, the nominal frame rate (NaN when unknown),
the frame count (0 when unknown) and an iterator of ``(image, t_s)`` pairs, ``image`` a 2-D
array of luma (a colour frame's luma, not one of its channels) or, opened with ``colour=True``, an
RGB array, and ``t_s`` the frame's start time from the
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
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .decoding import _decoded_frames, _luma_levels
from .errors import BadInputError, TrackingError
from .fields import field_order_of
from .transfer import transfer_of_video

__all__ = ["Frames", "VideoFile", "ImageFolder", "FrameArrays", "Clip", "Cut", "parse_cut", "as_source", "fingerprint",
           "IMAGE_SUFFIXES", "video_stream"]


#: FFmpeg decoders of codecs that keep every pixel value (anything else changes them: H.264, HEVC, mp4v, MJPEG)
LOSSLESS_CODECS = {"ffv1", "rawvideo", "huffyuv", "ffvhuff", "png", "apng", "tiff", "utvideo", "magicyuv", "qtrle",
                   "zlib", "v210", "v410", "r210", "y41p", "ayuv"}


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


class VideoFile:
    """A video container decoded by FFmpeg through PyAV.

    Frames come as the codec stores them, without a colour conversion: the luma plane (Y of a YUV
    codec, the one plane of a grey one) at the stream's own bit depth (a 10-bit HEVC phone clip gives
    values 0-1023), or RGB when ``colour`` is asked for (converted by FFmpeg at the stream's depth).
    Frame times are the presentation times (``pts`` x time base, from the first frame's), so a
    variable frame rate and dropped frames keep their real times.  Decoding runs in FFmpeg's own
    threads and in a background thread of ours (PyAV releases the GIL while decoding).
    """

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

    def frame_interval_s(self) -> float:
        """The interval between the stream's frames [s] from its packets' presentation times, read without
        decoding them (:func:`grid_fit`; NaN when the stream has no times)."""
        return self.frame_grid()[0]

    def frame_grid(self) -> tuple[float, float, int]:
        """:meth:`frame_interval_s` with its standard error and the number of frames (:func:`grid_fit`)."""
        import av

        try:
            with av.open(str(self.path), "r") as container:
                stream = video_stream(container)
                pts = [p.pts for p in container.demux(stream) if p.pts is not None]
                base = stream.time_base
        except (av.FFmpegError, IndexError, ValueError, OSError) as exc:
            raise BadInputError(f"cannot read video {self.path}: {exc}") from exc
        return grid_fit(np.sort(np.asarray(pts, float)) * float(base)) if base else (math.nan, math.nan, len(pts))

    def open(self, *, colour: bool = False) -> Frames:
        import av

        if not self.path.is_file():
            raise BadInputError(f"cannot open video {self.path}: no such file")
        if self.path.stat().st_size == 0:
            raise BadInputError(f"cannot open video {self.path}: empty file")
        try:
            container = av.open(str(self.path), "r")
            stream = video_stream(container)
        except (av.FFmpegError, IndexError, ValueError) as exc:
            raise BadInputError(f"cannot open video {self.path}: not a video FFmpeg can decode ({exc})"
                                f"{_cut_hint(self.path)}") from exc
        stream.thread_type = "AUTO"
        ctx = stream.codec_context
        pix = ctx.format
        if pix is None or not ctx.width or not ctx.height:
            container.close()
            raise BadInputError(f"cannot open video {self.path}: no picture size or pixel format in the stream")
        bits = int(pix.components[0].bits)
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        fps = float(rate) if rate else math.nan
        lossy = ctx.name not in LOSSLESS_CODECS
        count = int(stream.frames or 0)
        if not count and math.isfinite(fps):  # Matroska states no count: the duration in the stream or its header
            if stream.duration and stream.time_base:
                count = int(round(float(stream.duration * stream.time_base) * fps))
            elif container.duration:
                count = int(round(container.duration / av.time_base * fps))
        types: list[str] = []
        first = self._first_frame()
        turns = self.display_turns(first)
        levels = None if colour else _luma_levels(first, bits)
        transfer = transfer_of_video(getattr(first, "color_trc", None)) if first is not None else None
        width, height = (int(ctx.height), int(ctx.width)) if turns % 2 else (int(ctx.width), int(ctx.height))
        problems: list[str] = []
        damaged: list[tuple[int, int, str]] = []
        return Frames(width, height, fps, count,
                      _decoded_frames(container, stream, colour, types, turns=turns, problems=problems,
                                      damaged=damaged),
                      lossy=lossy, bit_depth=bits, frame_types=types, levels=levels, transfer=transfer,
                      problems=problems, damaged=damaged, interlaced=field_order_of(first, stream))

    def _first_frame(self):
        """The stream's first decoded frame (None when it has none): what its display matrix and colour range say."""
        import av

        try:
            with av.open(str(self.path), "r") as container:
                return next(container.decode(video_stream(container)), None)
        except (av.FFmpegError, IndexError, ValueError) as exc:
            raise BadInputError(f"cannot open video {self.path}: not a video FFmpeg can decode ({exc})") from exc

    def display_turns(self, first=None) -> int:
        """Quarter turns counter-clockwise from the stored picture to the displayed one: a phone held upright stores
        its sensor's landscape picture and says in the stream's display matrix how to turn it (PyAV's
        ``VideoFrame.rotation``, read from the first frame, decoded here unless given).  Frames are delivered as
        displayed, so what the user sees, what camera.json describes and what is tracked agree.  A rotation that is
        not a quarter turn is refused."""
        frame = self._first_frame() if first is None else first
        # VideoFrame.rotation (the display matrix's turn) is read where this PyAV has it; older ones give none
        degrees = int(round(float(getattr(frame, "rotation", 0) or 0))) if frame is not None else 0
        if degrees % 90:
            raise BadInputError(f"video {self.path}: its display matrix turns the picture by {degrees} degrees; only "
                                "quarter turns are supported (re-encode it upright)")
        return (degrees // 90) % 4


def video_stream(container):
    """The recording's video stream in an opened container: of its video streams, one that is not a picture
    attached to the file (a cover image, which FFmpeg shows as a video stream of one frame), the one with the most
    frames, else the longest, else the largest pictures (a Matroska file states neither count nor length per
    stream).  IndexError when the file has no video stream."""
    import av

    streams = list(container.streams.video)
    if not streams:
        raise IndexError("the file holds no video stream")

    def rank(stream):
        attached = bool(stream.disposition & av.stream.Disposition.attached_pic)
        length = float(stream.duration * stream.time_base) if stream.duration and stream.time_base else 0.0
        ctx = stream.codec_context
        return not attached, int(stream.frames or 0), length, int(ctx.width or 0) * int(ctx.height or 0)

    return max(streams, key=rank)


def _cut_hint(path: Path) -> str:
    """What an MP4 or MOV file FFmpeg cannot open most often is: one copied or sent before the recording ended."""
    if path.suffix.lower() not in (".mp4", ".mov", ".m4v", ".3gp"):
        return ""
    return ("; an MP4 or MOV file cut short (copied before the recording stopped, or truncated in transfer) has no "
            "index, which the camera writes when recording stops: a complete copy of the file is needed")


class FrameArrays:
    """Frames held in memory (2-D arrays of one size), with their start times [s] if known, and, for frames taken
    from a video, its black and white levels and transfer tag (:class:`Frames`' ``levels`` and ``transfer``)."""

    def __init__(self, frames: Sequence[np.ndarray], t_s: Sequence[float] | None = None, *, name: str = "frames",
                 levels: tuple[int, int] | None = None, transfer: str | None = None):
        if not len(frames):
            raise TrackingError(f"{name}: no frames")
        shapes = {np.shape(f)[:2] for f in frames}
        if len(shapes) != 1:
            raise TrackingError(f"{name}: frames of different sizes {sorted(shapes)}")
        if t_s is not None and len(t_s) != len(frames):
            raise TrackingError(f"{name}: {len(t_s)} times for {len(frames)} frames")
        self.frames, self.t_s, self.name = frames, t_s, name
        self.levels, self.transfer = levels, transfer

    def __str__(self) -> str:
        return self.name

    def fingerprint(self) -> None:
        """Frames in memory have no recording to recognise later."""
        return None

    def frame_interval_s(self) -> float:
        """The interval between the frames [s] from their times (:func:`grid_fit`; NaN without times)."""
        return self.frame_grid()[0]

    def frame_grid(self) -> tuple[float, float, int]:
        """:meth:`frame_interval_s` with its standard error and the number of frames (:func:`grid_fit`)."""
        return grid_fit(self.t_s) if self.t_s is not None else (math.nan, math.nan, 0)

    def open(self, *, colour: bool = False) -> Frames:
        h, w = np.shape(self.frames[0])[:2]
        times = self.t_s if self.t_s is not None else [math.nan] * len(self.frames)
        items = ((_as_wanted(np.asarray(f), colour, "RGB"), float(t)) for f, t in zip(self.frames, times))
        return Frames(int(w), int(h), math.nan, len(self.frames), items, levels=None if colour else self.levels,
                      transfer=self.transfer)


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

    def frame_interval_s(self) -> float:
        """The interval between the frames [s] from their times (:func:`grid_fit`; NaN without timestamps)."""
        return self.frame_grid()[0]

    def frame_grid(self) -> tuple[float, float, int]:
        """:meth:`frame_interval_s` with its standard error and the number of frames (:func:`grid_fit`)."""
        return grid_fit(self.t_s) if self.t_s is not None else (math.nan, math.nan, 0)

    def _read(self, k: int) -> np.ndarray:
        image = cv2.imread(str(self.files[k]), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise BadInputError(f"{self.files[k]}: unreadable image")
        if image.dtype not in (np.uint8, np.uint16):
            raise BadInputError(f"{self.files[k]}: {image.dtype} pixels; allowed 8- or 16-bit")
        return image

    def open(self, *, colour: bool = False) -> Frames:
        first = self._read(0)
        h, w = first.shape[:2]
        times = self.t_s if self.t_s is not None else [math.nan] * len(self.files)

        def items():
            for k, t in enumerate(times):
                image = first if k == 0 else self._read(k)
                if image.shape[:2] != (h, w):
                    raise BadInputError(f"{self.files[k]}: {image.shape[1]} x {image.shape[0]} pixels; the first "
                                        f"image ({self.files[0].name}) is {w} x {h}")
                yield np.ascontiguousarray(_as_wanted(image, colour, "BGR")), float(t)

        return Frames(int(w), int(h), math.nan, len(self.files), items())


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


def prepended(first, items):
    """``first``, then ``items``; closing it closes ``items`` (a video's decoding thread)."""
    try:
        yield first
        yield from items
    finally:
        close = getattr(items, "close", None)
        if close is not None:
            close()


def fingerprint(video) -> str | None:
    """A digest that recognises a recording again (a copy of it too); None for frames in memory."""
    source = as_source(video)
    return source.fingerprint() if hasattr(source, "fingerprint") else None


@dataclass(frozen=True)
class Cut:
    """One end of a clip: a time in the file [s] (``unit = "s"``) or a frame's place in it (``"f"``, 0 = first)."""

    value: float
    unit: str = "s"

    def __str__(self) -> str:
        return f"{self.value:g} s" if self.unit == "s" else f"frame {int(self.value)}"


def parse_cut(text: str, option: str = "--start") -> Cut:
    """``"12.5"`` or ``"12.5s"`` (seconds from the file's first frame, as a player shows them) or ``"300f"`` (the
    300th frame, counting from 0) -> :class:`Cut`; a :class:`BadInputError` naming the option otherwise."""
    t = str(text).strip().lower()
    unit = "f" if t.endswith("f") else "s"
    number = t[:-1] if t.endswith(("f", "s")) else t
    try:
        value = float(number)
    except ValueError:
        raise BadInputError(f"{option} {text!r}: expected seconds (12.5) or a frame (300f)") from None
    if not math.isfinite(value) or value < 0 or (unit == "f" and value != int(value)):
        raise BadInputError(f"{option} {text!r}: allowed: seconds >= 0, or a whole frame number >= 0 with f")
    return Cut(value, unit)


class Clip:
    """The part of a source between two :class:`Cut` s (either may be None: the start or end of the source).

    Frames outside are decoded and passed over (a file's own frame numbers and times are kept, so a clip's angle
    table lines up with the whole recording's); the same recording as its source (:meth:`fingerprint`)."""

    def __init__(self, source, start: Cut | None = None, end: Cut | None = None):
        self.source = as_source(source)
        self.start, self.end = start, end
        if start is not None and end is not None and start.unit == end.unit and end.value <= start.value:
            raise BadInputError(f"--end ({end}) must come after --start ({start})")

    def __str__(self) -> str:
        return f"{self.source} [{self.start or 'start'} to {self.end or 'end'}]"

    def fingerprint(self):
        return self.source.fingerprint()

    def frame_interval_s(self) -> float:
        return self.frame_grid()[0]

    def frame_grid(self) -> tuple[float, float, int]:
        return self.source.frame_grid() if hasattr(self.source, "frame_grid") else (math.nan, math.nan, 0)

    def _inside(self, cut: Cut, k: int, t: float, t0: float, fps: float, after: bool) -> bool:
        if cut.unit == "f":
            return k >= cut.value if after else k <= cut.value
        if not math.isfinite(t):
            if not (math.isfinite(fps) and fps > 0):
                raise BadInputError(f"{self.source}: its frames carry no times and no rate: give the clip's ends "
                                    "as frames (300f)")
            t, t0 = k / fps, 0.0
        rel = t - t0
        slack = 1e-6  # a container's rounding of the cut's own frame
        return rel >= cut.value - slack if after else rel <= cut.value + slack

    def open(self, *, colour: bool = False) -> Frames:
        inner = self.source.open(colour=colour)
        types: list[str] | None = [] if inner.frame_types is not None else None
        damaged: list[tuple[int, int, str]] = []

        def items():
            t0 = math.nan
            kept = 0
            first = -1  # the source's position of the clip's first frame
            try:
                for k, (image, t) in enumerate(inner):
                    if not math.isfinite(t0) and math.isfinite(t):
                        t0 = t
                    if self.end is not None and not self._inside(self.end, k, t, t0, inner.fps, after=False):
                        break
                    if self.start is not None and not self._inside(self.start, k, t, t0, inner.fps, after=True):
                        continue
                    if types is not None:
                        types.append(inner.frame_types[k] if k < len(inner.frame_types) else "")
                    first = k if first < 0 else first
                    kept += 1
                    yield image, t
            finally:
                inner.close()  # its damaged stretches are complete once it is closed; here in the clip's positions
                damaged.extend((max(a - first, 0), min(b - first, kept), why) for a, b, why in inner.damaged
                               if kept and b > first and a < first + kept)
            if not kept:
                raise BadInputError(f"{self}: no frame lies between the clip's ends")

        return Frames(inner.width_px, inner.height_px, inner.fps, 0, items(), lossy=inner.lossy,
                      bit_depth=inner.bit_depth, frame_types=types, levels=inner.levels, transfer=inner.transfer,
                      problems=inner.problems, damaged=damaged)


def as_source(video) -> VideoFile | ImageFolder | FrameArrays:
    """A path (str or Path) becomes a :class:`VideoFile`, or an :class:`ImageFolder` when it is a folder;
    a source is returned as it is."""
    if isinstance(video, (str, Path)):
        return ImageFolder(video) if Path(video).is_dir() else VideoFile(video)
    if hasattr(video, "open"):
        return video
    raise TypeError(f"expected a video path or a frame source, got {type(video).__name__}")
