"""Where frames come from: a video file (decoded in a background thread), images (module
:mod:`~gyrorig.tracking.images`: a folder of images, a TIFF stack), or frames held in memory.

A source opens to :class:`~gyrorig.tracking.frames.Frames`: the image size, the nominal frame rate (NaN when unknown),
the frame count (0 when unknown) and an iterator of ``(image, t_s)`` pairs, ``image`` a 2-D
array of luma (a colour frame's luma, not one of its channels) or, opened with ``colour=True``, an
RGB array, and ``t_s`` the frame's start time from the
container's timestamps (NaN when the source has none: the tracker then counts frames at the
camera's rate).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .decoding import _decoded_frames, _luma_levels
from .frames import Frames, _as_wanted, file_fingerprint, grid_fit
from .errors import BadInputError, TrackingError
from .fields import field_order_of
from .images import ImageFolder, TiffStack
from .transfer import transfer_of_video

__all__ = ["VideoFile", "FrameArrays", "Clip", "Cut", "parse_cut", "as_source", "fingerprint", "video_stream"]


#: FFmpeg decoders of codecs that keep every pixel value (anything else changes them: H.264, HEVC, mp4v, MJPEG)
LOSSLESS_CODECS = {"ffv1", "rawvideo", "huffyuv", "ffvhuff", "png", "apng", "tiff", "utvideo", "magicyuv", "qtrle",
                   "zlib", "v210", "v410", "r210", "y41p", "ayuv"}


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
        return file_fingerprint(self.path)

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


def as_source(video):
    """A path (str or Path) becomes a :class:`VideoFile`, an :class:`ImageFolder` when it is a folder, or a
    :class:`TiffStack` when it is a TIFF file (of one page or many);
    a source is returned as it is."""
    if isinstance(video, (str, Path)):
        if Path(video).is_dir():
            return ImageFolder(video)
        return TiffStack(video) if Path(video).suffix.lower() in (".tif", ".tiff") else VideoFile(video)
    if hasattr(video, "open"):
        return video
    raise TypeError(f"expected a video path or a frame source, got {type(video).__name__}")
