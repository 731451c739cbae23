"""The protocol's ``[markers]`` section, parsed once into typed markers.

``[markers.NAME]``: ``body = "frame" | "rotor" | "lab"`` ("frame": fixed to the non-spinning
frame of a gyrostat, coordinates with ``z`` along the symmetry axis; "rotor": fixed to the
spinning rotor, same coordinates; a plain top (no ``rig.frame_axial_inertia_kg_m2``) has no
separate frame, and its "frame" markers turn with the rotor; "lab": a fiducial fixed in the
lab, pivot at the origin), ``position_m = [x, y, z]``, ``radius_m``, ``shape`` (``"sphere"``,
the default: a ball of that radius; ``"disc"``: a flat dot of that radius, e.g. retroreflective
tape, facing along ``normal = [x, y, z]`` in the same coordinates, default the stem axis
``[0, 0, 1]``; ``"blob"``: an appearance the tracker must not assume, drawn as a sphere),
``brightness_e_per_s`` (electrons per pixel per second inside the dot; needed to render or
plan, not to track), ``colour`` (``"any"``, the default: the dot is told by its brightness; ``"red"``,
``"green"``, ``"blue"``: a coloured sticker, told by that colour) and ``polarity`` (``"bright"``, the
default, or ``"dark"``: a black dot on a light rotor).  ``kind = "occluder"`` instead describes an opaque cylinder about the axis
(``radius_m, z_min_m, z_max_m``, on the frame), e.g. the rotor can.

The renderer draws every dot; the tracker follows the ``tip`` (on the axis), the frame's dots
off the axis (their azimuth about the axis gives the frame angle ``psi``) and finds the
camera pose from the lab fiducials; the plan assesses the tip.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validate import ProtocolError, check_keys, number, vector3
from .protocols import Protocol

__all__ = ["Marker", "Occluder", "MarkerSet", "parse_markers", "TIP_MARKER", "MARKER_SHAPES", "MARKER_BODIES",
           "MARKER_COLOURS", "MARKER_POLARITIES"]

MARKER_SHAPES = ("sphere", "disc", "blob")
#: what sets a marker apart from what is around it: its brightness (``any``) or one colour of sticker
MARKER_COLOURS = ("any", "red", "green", "blue")
#: a marker brighter than its surroundings (a retroreflective or white dot) or darker (a black dot on a light rotor)
MARKER_POLARITIES = ("bright", "dark")
MARKER_BODIES = ("frame", "rotor", "lab")

#: the marker the tracker follows (on the symmetry axis, on the frame)
TIP_MARKER = "tip"


@dataclass(frozen=True)
class Marker:
    """A bright dot (sphere, disc or blob) on the frame, on the rotor, or fixed in the lab (see the module docstring)."""

    name: str
    body: str
    position_m: tuple[float, float, float]
    radius_m: float
    #: electrons per pixel per second inside the dot (None: not given; tracking does not need it)
    brightness_e_per_s: float | None = None
    #: "sphere", "disc" or "blob" (see the module docstring)
    shape: str = "sphere"
    #: a disc's unit normal, in the coordinates of its body
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    #: :data:`MARKER_COLOURS`: "any" (found by brightness) or the colour of a sticker (found by that colour)
    colour: str = "any"
    #: :data:`MARKER_POLARITIES`: brighter or darker than what is around it
    polarity: str = "bright"

    @property
    def off_axis_m(self) -> float:
        """Distance from the symmetry axis (frame dots). [m]"""
        return math.hypot(self.position_m[0], self.position_m[1])

    @property
    def lever_m(self) -> float:
        """Distance from the pivot. [m]"""
        return float(np.linalg.norm(self.position_m))


@dataclass(frozen=True)
class Occluder:
    """An opaque cylinder about the top's axis, ``z_min_m <= z <= z_max_m`` in frame coordinates."""

    name: str
    radius_m: float
    z_min_m: float
    z_max_m: float


@dataclass(frozen=True)
class MarkerSet:
    """All markers of a protocol."""

    dots: tuple[Marker, ...]
    occluders: tuple[Occluder, ...]

    def tip(self) -> Marker:
        """The tip marker (named ``tip``, on the frame); :class:`ProtocolError` if there is none."""
        for m in self.dots:
            if m.name == TIP_MARKER:
                if m.body != "frame":
                    break
                return m
        raise ProtocolError(f"markers.{TIP_MARKER}: a marker named '{TIP_MARKER}' on the frame (body = 'frame') "
                            "is needed")

    def fiducials(self) -> tuple[Marker, ...]:
        """Lab-fixed dots (for the camera pose)."""
        return tuple(m for m in self.dots if m.body == "lab")

    def frame_dots(self) -> tuple[Marker, ...]:
        """Frame-fixed dots off the axis, other than the tip (they give the frame's angle about the axis)."""
        return tuple(m for m in self.dots if m.name != TIP_MARKER and m.body == "frame" and m.off_axis_m > 1e-6)

    def moving_dots(self) -> tuple[Marker, ...]:
        """Every dot on the top but the tip (frame and rotor): what can stand near the tip in an image."""
        return tuple(m for m in self.dots if m.name != TIP_MARKER and m.body != "lab")

    def require_brightness(self, purpose: str) -> None:
        """Raise :class:`ProtocolError` naming the first dot without ``brightness_e_per_s``."""
        for m in self.dots:
            if m.brightness_e_per_s is None:
                raise ProtocolError(f"[markers.{m.name}] is missing required key(s) brightness_e_per_s ({purpose} "
                                    "needs each dot's brightness)")


def parse_markers(source: Protocol | Mapping[str, Any]) -> MarkerSet:
    """Parse and validate a ``[markers]`` table (or a protocol's); errors name the key and the allowed range."""
    if isinstance(source, Protocol):
        if "markers" not in source.extra:
            raise ProtocolError(f"{source.name}: the protocol has no [markers] section")
        source = source.extra["markers"]
    if not isinstance(source, Mapping) or not source:
        raise ProtocolError("[markers] must contain at least one [markers.NAME] table")
    dots, occluders = [], []
    for name, m in source.items():
        s = f"markers.{name}"
        if not isinstance(m, Mapping):
            raise ProtocolError(f"[{s}] must be a table")
        if m.get("kind", "dot") == "occluder":
            check_keys(s, m, {"kind", "radius_m", "z_min_m", "z_max_m"}, set())
            occluders.append(Occluder(name, number(s, "radius_m", m["radius_m"], lo=0.0, lo_open=True),
                                      number(s, "z_min_m", m["z_min_m"], lo=-1.0, hi=1.0),
                                      number(s, "z_max_m", m["z_max_m"], lo=-1.0, hi=1.0)))
            continue
        check_keys(s, m, {"body", "position_m", "radius_m"},
                   {"kind", "brightness_e_per_s", "shape", "normal", "colour", "polarity"})
        if m.get("kind", "dot") != "dot":
            raise ProtocolError(f"{s}.kind = {m['kind']!r}: allowed 'dot', 'occluder'")
        if m["body"] not in MARKER_BODIES:
            raise ProtocolError(f"{s}.body = {m['body']!r}: allowed {', '.join(map(repr, MARKER_BODIES))}")
        shape = m.get("shape", "sphere")
        if shape not in MARKER_SHAPES:
            raise ProtocolError(f"{s}.shape = {shape!r}: allowed {', '.join(map(repr, MARKER_SHAPES))}")
        if "normal" in m and shape != "disc":
            raise ProtocolError(f"{s}.normal is only meaningful with shape = 'disc'")
        normal = vector3(s, "normal", m.get("normal", [0.0, 0.0, 1.0]))
        length = math.sqrt(sum(v * v for v in normal))
        if length == 0:
            raise ProtocolError(f"{s}.normal = {list(normal)!r}: must not be zero")
        colour, polarity = m.get("colour", "any"), m.get("polarity", "bright")
        if colour not in MARKER_COLOURS:
            raise ProtocolError(f"{s}.colour = {colour!r}: allowed {', '.join(map(repr, MARKER_COLOURS))}")
        if polarity not in MARKER_POLARITIES:
            raise ProtocolError(f"{s}.polarity = {polarity!r}: allowed {', '.join(map(repr, MARKER_POLARITIES))}")
        brightness = (None if "brightness_e_per_s" not in m else
                      number(s, "brightness_e_per_s", m["brightness_e_per_s"], lo=0.0, lo_open=True))
        dots.append(Marker(name, m["body"], vector3(s, "position_m", m["position_m"]),
                           number(s, "radius_m", m["radius_m"], lo=0.0, lo_open=True, hi=0.1), brightness, shape,
                           tuple(v / length for v in normal), colour, polarity))
    if not dots:
        raise ProtocolError("[markers] has no dot (kind = 'dot'): nothing to track")
    return MarkerSet(tuple(dots), tuple(occluders))
