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
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from ..markers import Marker
from ..camera import Camera
from .transfer import TRANSFERS, linear_level

__all__ = ["MarkerImage"]

_CHANNEL = {"red": 0, "green": 1, "blue": 2}


class MarkerImage:
    """Turns decoded frames (RGB for a coloured marker) into the tracker's image (module docstring); calling it
    maps one decoded frame; ``keeps_sensor_model`` whether the sensor's noise model still describes the result."""

    def __init__(self, marker: Marker, camera: Camera, levels: tuple[int, int] | None = None):
        self.colour = marker.colour != "any"
        self.dark = marker.polarity == "dark"
        self.keeps_sensor_model = not (self.colour or self.dark)
        self.top = float(camera.max_adu)
        self.channel = _CHANNEL.get(marker.colour)
        self._linear = _linearizer(camera, None if self.colour else levels)

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

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        image = frame if self._linear is None else self._linear(frame)
        if self.colour:
            rgb = np.asarray(image, np.float32)
            others = [c for c in range(3) if c != self.channel]
            image = rgb[:, :, self.channel] - 0.5 * (rgb[:, :, others[0]] + rgb[:, :, others[1]])
        if self.dark:
            image = (self.top if not self.colour else 0.0) - np.asarray(image, np.float32)
        return image


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

