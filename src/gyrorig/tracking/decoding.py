"""Decoding a video stream with FFmpeg (through PyAV): each picture's luma plane at its own bit depth (or RGB),
its presentation time and picture type, in a background thread; and the stretches of pictures damaged data
reaches, told by the decoder."""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Iterator, Sequence

import numpy as np

#: codecs whose FFmpeg decoder flags no concealed picture corrupt but, asked to (``err_detect=explode``), returns an
#: error for a packet whose data it cannot parse (and drops its picture): their damage is told by those errors
ERROR_REPORTING_CODECS = {"hevc", "mjpeg"}


#: FFmpeg's colour range of a frame that says it holds full-range values (AVCOL_RANGE_JPEG)
_RANGE_FULL = 2


def _luma_levels(frame, bits: int) -> tuple[int, int] | None:
    """The luma values of black and white as :func:`_plane_image` gives them: a YUV picture's own luma plane,
    unless marked full-range (a "yuvj" format or the JPEG range), holds the limited range, 16-235 scaled to its
    bit depth, as FFmpeg and every player read it; None (0 to full scale) for grey formats, full-range YUV and
    pictures FFmpeg converts to grey (which it stretches to the full range)."""
    if frame is None or not _luma_plane(frame.format) or len(frame.format.components) < 3:
        return None
    if frame.format.name.startswith("yuvj") or int(getattr(frame, "color_range", 0) or 0) == _RANGE_FULL:
        return None
    scale = 1 << max(bits - 8, 0)
    return 16 * scale, 235 * scale


def _luma_plane(fmt) -> bool:
    """Whether a picture of format ``fmt`` stores its luma as its own first plane (read as it is)."""
    luma = fmt.components[0]
    return bool(fmt.is_planar and luma.is_luma and luma.plane == 0 and not fmt.is_big_endian)


def _plane_image(frame, colour: bool) -> np.ndarray:
    """One decoded frame as a 2-D luma array (no conversion where the codec stores luma) or an RGB array, at the
    stream's bit depth (FFmpeg's 16-bit conversions of a 10- or 12-bit picture span the full 16 bits: shifted back)."""
    fmt = frame.format
    bits = fmt.components[0].bits
    if colour:
        return _at_depth(frame.to_ndarray(format="rgb48le" if bits > 8 else "rgb24"), bits)
    if _luma_plane(fmt):
        plane = frame.planes[0]
        dtype = np.uint16 if bits > 8 else np.uint8
        row = np.frombuffer(plane, dtype=dtype).reshape(frame.height, -1)
        return np.array(row[:, :frame.width])  # a copy: the decoder reuses its buffers
    if fmt.name == "pal8":  # a grey palette (QuickTime's 8-bit grey, inverted) gives its levels exactly
        index = np.frombuffer(frame.planes[0], np.uint8).reshape(frame.height, -1)[:, :frame.width]
        palette = np.frombuffer(frame.planes[1], np.uint8)[:1024].reshape(256, 4)  # B, G, R, A
        if (palette[:, 0] == palette[:, 1]).all() and (palette[:, 1] == palette[:, 2]).all():
            return palette[index, 2]
    return _at_depth(frame.to_ndarray(format="gray16le" if bits > 8 else "gray"), bits)


def _at_depth(image: np.ndarray, bits: int) -> np.ndarray:
    """A 16-bit conversion of a picture of ``bits`` per value (9-15) brought back to that depth."""
    return image >> (16 - bits) if image.dtype == np.uint16 and 8 < bits < 16 else image


#: FFmpeg's picture types (``AVPictureType``), as the angle table's ``frame_type`` names them
PICTURE_TYPES = {1: "I", 2: "P", 3: "B", 4: "S", 5: "SI", 6: "SP", 7: "BI"}


def _damaged_stretches(errors: list[tuple[int, str]], keys: list[int], count: int,
                       known: Sequence[tuple[int, int, str]] = ()) -> list[tuple[int, int, str]]:
    """Stretches ``(first, end, message)`` of pictures damaged data reach: from each picture the decoder flagged
    corrupt (``errors``: its position and what to say) up to the next key picture (``keys``: positions of the
    pictures decodable on their own; the ones between are predicted from the damaged one), with the stretches
    ``known`` already, merged where they overlap."""
    spans = sorted([(at, next((k for k in keys if k > at), count), message) for at, message in errors] + list(known))
    out: list[tuple[int, int, str]] = []
    for at, end, message in spans:
        if out and at <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], end), out[-1][2])
        else:
            out.append((at, end, message))
    return out


def _refused_stretches(refused: list[tuple[int, str]], packets: list[tuple[float, bool]], shown: list[float],
                       lag: int, drops_dependents: bool) -> tuple[list[tuple[int, int, str]], int, int]:
    """The stretches ``(first, end, message)`` of delivered pictures the refused packets' damage may reach, how
    many refused packets were dropped whole, and how many other packets' pictures never came (from the first
    picture delivered on: a decoder that skipped them without a word).

    A decoder with frame threads returns a packet's error up to ``lag`` packets late: the damaged packet is one
    of those from ``lag`` before the refused one.  A packet of these whose picture never came was dropped whole,
    and one refusal is put down to each such packet.  A decoder that ``drops_dependents`` (asked to refuse what it
    cannot parse, ``err_detect=explode``) refuses the pictures predicted from a dropped one too, so no delivered
    picture holds its damage; any other may predict later pictures from a stale one.  Such a picture, and a
    refused one delivered anyway, start a stretch: every picture decoded after it up to the next key packet may be
    predicted from it, B pictures shown before it too, so the delivered pictures from the earliest time stamp
    among those packets to the key packet's (``packets``: time stamp and key flag in decode order; ``shown``: the
    delivered pictures' time stamps in order).  Without time stamps, decode positions stand for them."""
    if not packets:
        return [], 0, 0
    times = np.asarray(shown, float)
    stamps = np.asarray([t for t, _ in packets], float)
    if not (np.isfinite(times).all() and np.isfinite(stamps).all()):
        times, stamps = np.arange(len(shown), dtype=float), np.arange(len(packets), dtype=float)
    keys = [j for j, (_, key) in enumerate(packets) if key]
    dropped = set(np.flatnonzero(~np.isin(stamps, times)).tolist())
    out = []
    whole = 0
    for at, message in refused:
        window = range(max(at - lag, 0), min(at + 1, len(packets)))
        lost = next((d for d in window if d in dropped), None)
        if lost is not None:
            dropped.discard(lost)
            whole += 1
            if drops_dependents:
                continue
            window = range(lost, lost + 1)
        start = min(window.start, len(packets) - 1)
        hi = next((j for j in keys if j > window.stop - 1), len(packets))
        stop = stamps[hi] if hi < len(packets) else np.inf
        inside = np.flatnonzero((times >= stamps[start:max(hi, start + 1)].min()) & (times < stop))
        if inside.size:
            out.append((int(inside[0]), int(inside[-1]) + 1, f"the decoder refused a damaged packet ({message})"))
    first_shown = times.min() if times.size else np.inf
    return out, whole, sum(1 for d in dropped if stamps[d] >= first_shown)


def _decoded_frames(container, stream, colour: bool, types: list[str], depth: int = 8, turns: int = 0,
                    problems: list[str] | None = None, damaged: list | None = None
                    ) -> Iterator[tuple[np.ndarray, float]]:
    """Yield ``(frame, start time s)``, decoding in a background thread (decoding the next frames overlaps
    with tracking this one: two cores give the slower of the two, not their sum); each yielded frame's
    picture type (:data:`PICTURE_TYPES`, '' when the codec does not say) is appended to ``types`` first.
    Each picture is turned by ``turns`` quarter turns counter-clockwise (its display orientation).

    Times are the presentation times from the first frame's; a frame without one gets NaN (the tracker
    then counts it at the camera's rate).  A container that breaks off mid-way ends the frames there, its
    message appended to ``problems``.  Damaged data marks the stretches of pictures it reaches in
    ``damaged`` (:func:`_damaged_stretches`), filled when the stream has been read: the pictures the decoder
    flags corrupt (H.264's concealed ones) and the packets it refuses (:func:`_refused_stretches`; decoding goes on
    with the next packet), asked to for :data:`ERROR_REPORTING_CODECS`; pictures it skipped without a word are
    counted in ``problems``.  FFmpeg's log is not captured: PyAV's log
    callback, called from the decoder's own threads, can deadlock threaded decoding.
    """
    import av

    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    base = stream.time_base
    refusing = stream.codec_context.name in ERROR_REPORTING_CODECS
    if refusing:
        stream.codec_context.options = {**stream.codec_context.options, "err_detect": "explode"}

    def reader() -> None:
        first = None
        keys: list[int] = []
        errors: list[tuple[int, str]] = []
        packets: list[tuple[float, bool]] = []  # each packet's presentation time stamp and key flag, decode order
        refused: list[tuple[int, str]] = []  # (packet's decode index, decoder's message)
        shown: list[float] = []  # each delivered picture's time stamp
        try:
            for packet in container.demux(stream):
                if stop.is_set():
                    return
                if packet.size:
                    packets.append((math.nan if packet.pts is None else float(packet.pts), bool(packet.is_keyframe)))
                try:
                    pictures = stream.decode(packet)
                except av.FFmpegError as exc:
                    refused.append((len(packets) - 1, str(exc)))
                    continue
                for frame in pictures:
                    if frame.is_corrupt:
                        errors.append((len(shown), "the decoder found damaged data (the picture concealed from "
                                                   "others)"))
                    if frame.key_frame:
                        keys.append(len(shown))
                    shown.append(math.nan if frame.pts is None else float(frame.pts))
                    if frame.pts is None or base is None:
                        t = math.nan
                    else:
                        first = frame.pts if first is None else first
                        t = float((frame.pts - first) * base)
                    image = _plane_image(frame, colour)
                    if turns:
                        image = np.ascontiguousarray(np.rot90(image, turns))
                    q.put((image, t, PICTURE_TYPES.get(int(frame.pict_type or 0), "")))
        except (av.FFmpegError, ValueError, MemoryError) as exc:  # the frames decoded so far stand
            if problems is not None:
                problems.append(f"decoding stopped: {exc}")
        finally:
            try:
                lag = max(int(stream.codec_context.thread_count or 1), 1) + 1
                known, whole, skipped = _refused_stretches(refused, packets, shown, lag, refusing)
                if stop.is_set():  # closed before the stream's end: the packets in flight have no pictures yet
                    skipped = 0
                if damaged is not None and (errors or known):
                    damaged.extend(_damaged_stretches(errors, keys, len(shown), known))
                if problems is not None and whole + skipped:
                    why = refused[-1][1] if refused else "skipped without a message"
                    problems.append(f"damaged data, most likely: the decoder delivered no picture for "
                                    f"{whole + skipped} packets ({why}); those frames are missing from the record")
            finally:
                q.put(None)  # the consumer waits for it whatever happened here

    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is None:
                return
            types.append(item[2])
            yield item[:2]
    finally:
        stop.set()
        while thread.is_alive():  # unblock a reader waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                pass
            thread.join(timeout=0.05)
        container.close()
