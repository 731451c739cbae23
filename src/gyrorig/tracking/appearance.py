"""The image the tracker works on: one where the tip marker is brighter than what is around it.

- a bright marker (``polarity = "bright"``, ``colour = "any"``): the frame's luma, linearised when the
  camera records with a gamma or a standard transfer curve, from the video's black and white levels (a
  phone's limited range, 16-235, stretched to full scale: its white is the full scale, saturated);
- a dark marker (``polarity = "dark"``): the linearised luma turned over (full scale minus it);
- a coloured sticker (``colour = "red" | "green" | "blue"``): from the RGB frame, each channel linearised,
  that channel minus the mean of the other two (grey, white and black scenes give about 0, the sticker
  its colour's excess; a dark coloured marker is turned over as well).

Only the first keeps the sensor's noise model; the others are judged by the recorded-footage models
(:mod:`gyrorig.tracking.scene_spot`, the scatter check).

Each marker is fitted in the image of its own colour and polarity: the lab markers (fiducials), when they share one
other than the tip's, in theirs (:func:`lab_marker_image`; a white dot's colour excess is about 0, so a red tip's
image does not show white fiducials).  From RGB frames (a coloured tip's) a bright or dark marker's image is the
luma the video coded (BT.709's weights on the encoded values), linearised.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import cv2
import numpy as np

from ..markers import Marker
from ..camera import Camera
from .transfer import TRANSFERS, linear_level

__all__ = ["MarkerImage", "MappedFrame", "decoded_pixels", "lab_marker_image"]

_CHANNEL = {"red": 0, "green": 1, "blue": 2}
#: BT.709's luma weights of R', G', B' (as a 1 x 3 matrix for ``cv2.transform``)
_LUMA = np.array([[0.2126, 0.7152, 0.0722]])


class MarkerImage:
    """Turns decoded frames (RGB for a coloured marker) into the tracker's image (module docstring); calling it
    maps one decoded frame; ``keeps_sensor_model`` whether the sensor's noise model still describes the result."""

    def __init__(self, marker: Marker, camera: Camera, levels: tuple[int, int] | None = None, *,
                 rgb: bool | None = None):
        """``rgb``: whether the decoded frames are RGB (default: for a coloured marker; a bright or dark marker's
        image from RGB frames is their luma)."""
        self.colour = marker.colour != "any"
        self.rgb = self.colour if rgb is None else bool(rgb)
        self.dark = marker.polarity == "dark"
        self.keeps_sensor_model = not (self.colour or self.dark or self.rgb)
        self.top = float(camera.max_adu)
        self.channel = _CHANNEL.get(marker.colour)
        #: the colour's excess over the mean of the other two channels (a 1 x 3 matrix for ``cv2.transform``)
        self._excess = np.array([[1.0 if c == self.channel else -0.5 for c in range(3)]], np.float32)
        self._linear = _linearizer(camera, None if self.rgb else levels)

    def doubts(self, camera: Camera, lossy: bool, shape: str, marker: Marker) -> str:
        """Why the per-frame errors cannot come from the sensor and spot models alone ('' when they can): the camera
        file, the codec (``lossy``), the tip's ``shape`` and this image (:meth:`describe`)."""
        doubts = []
        if not math.isfinite(camera.gain_e_per_adu):
            doubts.append("no sensor gain in camera.json")
        if camera.sensor.transfer not in (None, "linear"):
            doubts.append(f"transfer curve {camera.sensor.transfer}")
        elif camera.gamma != 1.0:
            doubts.append(f"sensor gamma {camera.gamma:g}")
        if lossy:
            doubts.append("lossy codec")
        if shape == "blob":
            doubts.append("a tip marker of no exact model (blob)")
        elif shape == "disc":
            doubts.append("a disc marker's model is approximate (first-order edge)")
        own = self.describe(marker)
        return "; ".join(doubts + ([own] if own else []))

    def describe(self, marker: Marker) -> str:
        """Why the sensor model no longer holds ('' when it does)."""
        parts = ([f"a {marker.colour} marker's colour contrast"] if self.colour else []) + (
            ["a dark marker (the image turned over)"] if self.dark else [])
        return "; ".join(parts)

    def drift_caveat(self, marker: Marker, frame_types) -> str:
        """What a coloured marker's errors cannot show in a file of predicted pictures (``frame_types`` holds a P
        or B): '' otherwise."""
        if not self.colour or not {"P", "B"} & set(frame_types):
            return ""
        return (f"the {marker.colour} marker's place comes from the video's colour planes, which the codec stores at "
                "half resolution and carries from picture to picture: their errors drift over many frames, which "
                "the record's check cannot see, and the error bars may be too small (most at a low bit rate); a "
                "white or retroreflective tip is tracked from the full-resolution brightness")

    def lazy(self, frame: np.ndarray) -> "MappedFrame | np.ndarray":
        """The tracker's image of a decoded frame, mapped where it is read (:class:`MappedFrame`); the frame itself
        when the image is the decoded frame (a linear sensor's luma on the full scale)."""
        if not (self.rgb or self.colour or self.dark) and self._linear is None:
            return frame
        return MappedFrame(frame, self)

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        if self.rgb and not self.colour:
            frame = cv2.transform(frame, _LUMA)
        image = frame if self._linear is None else self._linear(frame)
        if self.colour:  # the channel minus the mean of the other two, in one pass
            image = cv2.transform(np.asarray(image, np.float32), self._excess)
        if self.dark:
            image = (self.top if not self.colour else 0.0) - np.asarray(image, np.float32)
        return image


class MappedFrame:
    """A decoded frame (``decoded``) seen as the tracker's image (``shape`` its rows and columns): a part read
    by slicing (``image[y0:y1, x0:x1]``, steps allowed) is mapped alone, so a frame of which the tracker reads a few
    windows is never mapped whole; any other read (an index, ``np.asarray``) maps the whole frame once and keeps it.
    Each pixel's value is the same either way: the map is pixel by pixel."""

    __slots__ = ("decoded", "_map", "_whole")
    ndim = 2

    def __init__(self, decoded: np.ndarray, mapping: Callable[[np.ndarray], np.ndarray]):
        self.decoded = decoded
        self._map = mapping
        self._whole: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.decoded.shape[:2]

    def whole(self) -> np.ndarray:
        """The whole frame's image (mapped once)."""
        if self._whole is None:
            self._whole = self._map(self.decoded)
        return self._whole

    def __getitem__(self, key):
        if self._whole is not None or not (isinstance(key, tuple) and len(key) == 2
                                           and all(isinstance(k, slice) for k in key)):
            return self.whole()[key]
        part = self.decoded[key]
        if part.size == 0:
            return np.zeros(part.shape[:2], np.float32)
        return self._map(np.ascontiguousarray(part))

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        whole = self.whole()
        if dtype is not None and np.dtype(dtype) != whole.dtype:
            return whole.astype(dtype)
        return whole.copy() if copy else whole


def decoded_pixels(image: "MappedFrame | np.ndarray") -> np.ndarray:
    """The decoded frame behind a tracker's image (:meth:`MarkerImage.lazy`)."""
    return image.decoded if isinstance(image, MappedFrame) else image


def lab_marker_image(lab: Sequence[Marker], tip: Marker, camera: Camera,
                     levels: tuple[int, int] | None = None) -> MarkerImage | None:
    """The image the lab markers ``lab`` are fitted in, when it is not the tip's: the one of the colour and polarity
    they share, made from the frames decoded for the tip (RGB for a coloured tip, else luma).  None when the tip's
    image serves: they are alike to it, differ among themselves, or are coloured where the frames are luma (then
    fitted in the luma, where a sticker shows by its brightness)."""
    kinds = {(m.colour, m.polarity) for m in lab}
    if len(kinds) != 1 or kinds == {(tip.colour, tip.polarity)} or (tip.colour == "any" and lab[0].colour != "any"):
        return None
    return MarkerImage(lab[0], camera, levels, rgb=tip.colour != "any")


def _linearizer(camera: Camera, levels: tuple[int, int] | None) -> Callable[[np.ndarray], np.ndarray] | None:
    """A function that maps recorded values back to linear ones on the full scale (float32): ``levels`` (the
    values of black and white; None: 0 and full scale) stretched to 0 and full scale (below black: 0; above
    white: beyond full scale), then the sensor's transfer curve (:mod:`gyrorig.tracking.transfer`) or its gamma
    undone.  None for a linear sensor recorded on the full scale."""
    top = float(camera.max_adu)
    black, white = levels if levels is not None else (0, camera.max_adu)
    curve = camera.sensor.transfer if camera.sensor.transfer in TRANSFERS else None
    if curve in (None, "linear") and camera.gamma == 1.0 and (black, white) == (0, camera.max_adu):
        return None
    level = np.maximum(np.arange(camera.max_adu + 1) - black, 0) / float(white - black)
    table = (top * (linear_level(level, curve) if curve else level ** camera.gamma)).astype(np.float32)
    if camera.max_adu == 255:
        return lambda frame: cv2.LUT(frame, table) if frame.dtype == np.uint8 else table[np.minimum(frame, 255)]
    return lambda frame: table[np.minimum(frame, camera.max_adu)]

