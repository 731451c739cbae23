"""Interlaced video read field by field.

An interlaced camera (a camcorder's 1080i or 576i, DV, broadcast cameras) exposes the even rows and the odd rows
of each stored picture at two moments half a frame interval apart.  A moving tip is then two half-images, one in
each set of rows, a few pixels apart: no spot the tracker knows.  Read field by field, each picture gives two
images, each with its own rows kept and the others interpolated between them (the mean of the rows above and
below: "bob"), at its own time; a 25-frame/s file gives 50 images/s, each sharp.

Which field was exposed first is what the stream says (FFmpeg's field order; top first when it says nothing), or
what ``camera.json``'s ``interlace`` states.  :func:`field_timing_evidence` checks it on the tip's own path: in
the right order the tip's step inside a picture is the same as its step to the next picture; in the wrong order it
turns back, a third as long; in progressive pictures stored as interlaced ones ("PsF", 25p in a 50i stream) there
is no step inside a picture at all.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Iterator

import numpy as np

from .errors import BadInputError

__all__ = ["INTERLACE_MODES", "FIELD_ORDERS", "field_order_of", "field_frames", "bob", "field_timing_evidence",
           "FieldEvidence", "read_as_fields", "judged_fields"]

logger = logging.getLogger(__name__)

#: what ``camera.json``'s ``interlace`` may say: the file's own flags, or the scan stated
INTERLACE_MODES = ("auto", "progressive", "top-field-first", "bottom-field-first")
FIELD_ORDERS = ("top-field-first", "bottom-field-first")

#: FFmpeg's ``AVFieldOrder``: which field of a picture is displayed (exposed) first
_FIRST_SHOWN = {2: "top-field-first", 5: "top-field-first", 3: "bottom-field-first", 4: "bottom-field-first",
                "tt": "top-field-first", "bt": "top-field-first", "bb": "bottom-field-first",
                "tb": "bottom-field-first"}


def field_order_of(frame, stream) -> str | None:
    """The field order of an interlaced stream (:data:`FIELD_ORDERS`), from its first decoded ``frame``'s interlace
    flag and the stream's field order; where the stream does not say, DV's (bottom first, as its standard fixes it)
    or top first (HD's); None for progressive pictures."""
    if frame is None or not bool(getattr(frame, "interlaced_frame", False)):
        return None
    order = getattr(stream.codec_context, "field_order", None)
    key = order.lower() if isinstance(order, str) else int(order or 0)
    unsaid = "bottom-field-first" if stream.codec_context.name == "dvvideo" else "top-field-first"
    return _FIRST_SHOWN.get(key, unsaid)


def bob(image: np.ndarray, first_row: int) -> np.ndarray:
    """The field of ``image`` whose rows start at ``first_row`` (0: the top field, 1: the bottom one), its other rows
    each the mean of the field's rows above and below (at the picture's edge, its one neighbour); the same shape and
    type as ``image`` (2-D, or rows x columns x channels)."""
    rows = image[first_row::2]
    others = np.arange(1 - first_row, image.shape[0], 2)
    above = np.clip((others - 1 - first_row) // 2, 0, len(rows) - 1)
    below = np.clip((others + 1 - first_row) // 2, 0, len(rows) - 1)
    out = np.empty_like(image)
    out[first_row::2] = rows
    if image.dtype.kind in "ui":
        out[others] = (rows[above].astype(np.uint32) + rows[below] + 1) // 2
    else:
        out[others] = (rows[above] + rows[below]) / 2
    return out


def field_frames(frames, order: str, half_interval_s: float):
    """``frames`` (:class:`~gyrorig.tracking.frames.Frames` of interlaced pictures) as a source of fields: two
    images per picture (:func:`bob`), the first exposed at the picture's time, the second ``half_interval_s``
    later; twice the rate and count; picture types and damaged stretches given per field."""
    if order not in FIELD_ORDERS:
        raise ValueError(f"field order {order!r}: allowed {', '.join(FIELD_ORDERS)}")
    rows = (0, 1) if order == "top-field-first" else (1, 0)
    types = [] if frames.frame_types is not None else None
    damaged: list = []

    def items() -> Iterator[tuple[np.ndarray, float]]:
        for image, t in frames.items:  # the picture's type is appended to frames.frame_types before it comes
            for j, first_row in enumerate(rows):
                if types is not None:
                    types.append(frames.frame_types[-1] if frames.frame_types else "")
                yield bob(image, first_row), t + j * half_interval_s
        damaged.extend((2 * first, 2 * end, message) for first, end, message in frames.damaged)

    return replace(frames, fps=2 * frames.fps, count=2 * frames.count, items=items(), frame_types=types,
                   damaged=damaged, interlaced=None, fields=order)


@dataclass(frozen=True)
class FieldEvidence:
    """What the tip's path says of the fields' timing (:func:`field_timing_evidence`).

    ``ratio``: the tip's step between the two fields of a picture projected on its step from that picture's second
    field to the next picture's first, over the latter's mean square, the noise's share taken off (1: fields half a
    frame apart in the order read, each step the same; -1/3: the order reversed, the step inside a picture turned
    back and the one across three times as long; 0: both fields one instant, progressive pictures); ``pairs``:
    pictures with both fields and the next picture's first tracked; ``signal``: the steps' mean square over the
    noise's (NaN ratio when too small to judge)."""

    ratio: float
    pairs: int
    signal: float

    @property
    def verdict(self) -> str | None:
        """"reversed", "progressive", "as read", or None when the path cannot tell (a ratio between)."""
        if not math.isfinite(self.ratio):
            return None
        if self.ratio > 0.6:
            return "as read"
        if abs(self.ratio) < 0.12:
            return "progressive"
        if -0.55 < self.ratio < -0.2:
            return "reversed"
        return None


#: fewest pictures with both fields (and the next picture's first) tracked, and the least motion (the steps' mean
#: square over the noise's), for :func:`field_timing_evidence` to judge
MIN_FIELD_PAIRS = 10
MIN_FIELD_SIGNAL = 25.0


def field_timing_evidence(frame: np.ndarray, xy: np.ndarray, var: np.ndarray) -> FieldEvidence:
    """The fields' timing as the tip's path shows it (:class:`FieldEvidence`): ``frame`` (n,) the fields' numbers
    (a picture's two fields are ``2k`` and ``2k + 1``, numbered on the field rate from the first), ``xy`` (n, 2)
    the tip's positions [px], ``var`` (n, 2) their variances; untracked rows NaN."""
    frame = np.asarray(frame, int)
    xy, var = np.asarray(xy, float), np.asarray(var, float)
    ok = np.all(np.isfinite(xy), axis=1)
    at = {int(f): i for i, f in enumerate(frame) if ok[i]}
    dots, squares, noise = [], [], []
    for f, i in at.items():
        if f % 2 == 0 and f + 1 in at and f + 2 in at:
            j, n = at[f + 1], at[f + 2]
            inside, across = xy[j] - xy[i], xy[n] - xy[j]
            dots.append(float(inside @ across) + float(np.sum(var[j])))  # the shared field's noise enters as -var
            squares.append(float(across @ across) - float(np.sum(var[j] + var[n])))
            noise.append(float(np.sum(var[j] + var[n])))
    if len(dots) < MIN_FIELD_PAIRS:
        return FieldEvidence(math.nan, len(dots), math.nan)
    step, level = float(np.mean(squares)), float(np.mean(noise))
    signal = step / level if level > 0 else math.inf
    if not signal > MIN_FIELD_SIGNAL:
        return FieldEvidence(math.nan, len(dots), signal)
    return FieldEvidence(float(np.mean(dots)) / step, len(dots), signal)


def read_as_fields(frames, camera, source):
    """``(frames, camera)`` as the tracker reads them: an interlaced video's fields (:func:`field_frames`; the order
    camera.json's ``interlace`` states, else the one the file says), with the camera's rate the field rate (camera.json
    may give either the pictures' rate or the fields'); the frames and camera unchanged for progressive video."""
    mode = camera.interlace
    order = frames.interlaced if mode == "auto" else (None if mode == "progressive" else mode)
    if order is None:
        return frames, camera
    fps = frames.fps
    if not (math.isfinite(fps) and fps > 0):
        interval = source.frame_interval_s()
        fps = 1.0 / interval if math.isfinite(interval) and interval > 0 else math.nan
    if not (math.isfinite(fps) and fps > 0):
        raise BadInputError(f"{source}: an interlaced video without a frame rate: its fields cannot be timed")
    if math.isfinite(camera.fps) and abs(camera.fps / fps - 1.0) < 0.02:
        camera = replace(camera, fps=2.0 * camera.fps)  # camera.json gave the pictures' rate
    logger.warning("%s: interlaced video (%s, %s): each picture's two fields are tracked as two images %.4g ms apart "
                   "(%.4g fields/s, each field's other rows interpolated); if the camera recorded progressive pictures "
                   "stored as interlaced ones (PsF), set interlace = \"progressive\" in camera.json", source,
                   order.replace("-", " "), "as the file says" if mode == "auto" else "as camera.json says",
                   500.0 / fps, 2.0 * fps)
    return field_frames(frames, order, 0.5 / fps), camera


def judged_fields(frames, camera, frame: np.ndarray, tip_px: dict, tip_cov: dict, source) -> tuple[str | None, tuple]:
    """What the tip's path says of the field order the tracker read an interlaced video with
    (:func:`field_timing_evidence`; ``frame`` the angle table's frame numbers, ``tip_px`` and ``tip_cov`` the tip's
    positions and covariances by row): ``(mode, problems)``, the ``interlace`` mode to track again with when the order
    came from the file's flags and the path contradicts it (None: keep), and what to say when camera.json stated the
    order the path contradicts."""
    if frames.fields is None:
        return None, ()
    index = np.array(sorted(tip_px), int)
    xy = np.array([tip_px[r] for r in index], float).reshape(-1, 2)
    var = np.array([np.diag(tip_cov[r]) for r in index], float).reshape(-1, 2)
    evidence = field_timing_evidence(np.asarray(frame)[index], xy, var)
    verdict = evidence.verdict
    if verdict in (None, "as read"):
        return None, ()
    other = "progressive" if verdict == "progressive" else next(o for o in FIELD_ORDERS if o != frames.fields)
    seen = (f"the tip's step between a picture's two fields is {evidence.ratio:.2g} of its step to the next picture "
            f"({evidence.pairs} pictures; 1 for fields half a frame apart in the order read, -1/3 for the other "
            "order, 0 for progressive pictures)")
    if camera.interlace == "auto":
        logger.warning("%s: %s: the file's fields read %s look %s; tracked again as %s", source, seen,
                       frames.fields.replace("-", " "), verdict, other)
        return other, ()
    problem = (f"camera.json says interlace = {camera.interlace!r}, but {seen}: the pictures look {verdict} "
               f"(interlace = {other!r}?); the frames' times are off by up to half a picture interval")
    logger.warning("%s: %s", source, problem)
    return None, (problem,)
