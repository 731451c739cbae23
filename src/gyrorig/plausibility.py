"""Values that are allowed but unlikely for a tabletop gyroscope, with the likely mistake named.

A protocol's numbers are checked for their range when read (:mod:`gyrorig.protocols`); a number in range can still
be in the wrong unit (an inertia in g cm^2 under a ``_kg_m2`` key, a mass in grams, a distance in cm).  A
:class:`Doubt` is a warning, never a refusal: gyrorig says what it doubts and goes on.  Doubts are logged when a
protocol file is loaded and carried into every fit's notes (fit.json, the report).

The bounds describe tabletop rigs (``../shared/rig-parameters.md`` and the teaching-lab gyros): a top of 1 g to
50 kg, its centre of mass within 1 m of the pivot, radii of gyration of 0.5 mm to 0.5 m (axial) and 1 mm to 1 m
(transverse, about the pivot), spins below 4000 rad/s (38,000 rev/min), markers within 1 m of the pivot, Earth's gravity.

:func:`unit_slip` names the unit mistake behind a fitted value that is a units factor away from its prediction
(degrees for radians, ms for s, Hz or rev/min for rad/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Doubt", "rig_doubts", "protocol_doubts", "unit_slip", "TABLETOP"]

#: the bounds a tabletop rig stays within (SI units; see the module docstring)
TABLETOP = {
    "mass_kg": (1e-3, 50.0),
    "com_distance_m": (0.0, 1.0),
    "axial_gyration_radius_m": (5e-4, 0.5),
    "transverse_gyration_radius_m": (1e-3, 1.0),
    "gravity_m_s2": (9.76, 9.84),
    "spin_rate_rad_s": (0.0, 4000.0),
    "marker_distance_m": (0.0, 1.0),
}

#: unit factors a value can be off by, and the mistake each one means (value given / value meant)
_INERTIA_UNITS = ((1e7, "g cm^2", 1e-7), (1e4, "kg cm^2", 1e-4), (1e6, "kg mm^2", 1e-6), (1e9, "g mm^2", 1e-9),
                  (1e3, "g m^2", 1e-3))
_LENGTH_UNITS = ((100.0, "cm", 0.01), (1000.0, "mm", 0.001))


@dataclass(frozen=True)
class Doubt:
    """One implausible value: the input key, its value, and the text naming the likely mistake."""

    key: str
    value: float
    text: str

    def __str__(self) -> str:
        return self.text

    def as_dict(self) -> dict:
        return {"key": self.key, "value": self.value, "text": self.text}


def _inertia_doubt(key: str, inertia: float, mass: float, bounds: tuple[float, float]) -> Doubt | None:
    k = math.sqrt(inertia / mass) if inertia > 0 and mass > 0 else math.nan
    lo, hi = bounds
    if not math.isfinite(k) or lo <= k <= hi:
        return None
    text = (f"{key} = {inertia:.4g} with mass_kg = {mass:.4g} is a radius of gyration of {k:.3g} m; a tabletop top's "
            f"is {lo:g} to {hi:g} m")
    if k > hi:
        meant = [(unit, inertia * f) for _, unit, f in _INERTIA_UNITS if lo <= math.sqrt(inertia * f / mass) <= hi]
        if meant:
            text += ": " + " or ".join(f"{unit} (= {v:.4g} kg m^2)" for unit, v in meant[:2]) + " where kg m^2 is meant?"
    else:
        text += ": a mass in grams, or an inertia in a unit larger than kg m^2?"
    return Doubt(key, inertia, text)


def rig_doubts(rig) -> tuple[Doubt, ...]:
    """Doubts about a :class:`~gyrorig.protocols.Rig`'s mass, centre of mass, inertias and gravity (:data:`TABLETOP`)."""
    out: list[Doubt] = []
    lo, hi = TABLETOP["mass_kg"]
    if not lo <= rig.mass_kg <= hi:
        hint = (f": grams where kg is meant (= {rig.mass_kg / 1000:.4g} kg)?" if rig.mass_kg > hi
                else ": a unit smaller than kg?")
        out.append(Doubt("rig.mass_kg", rig.mass_kg, f"rig.mass_kg = {rig.mass_kg:.4g}: a tabletop top weighs "
                                                     f"{lo:g} to {hi:g} kg{hint}"))
    h = abs(rig.com_distance_m)
    if h > TABLETOP["com_distance_m"][1]:
        meant = " or ".join(f"{unit} (= {rig.com_distance_m * f:.4g} m)" for _, unit, f in _LENGTH_UNITS)
        out.append(Doubt("rig.com_distance_m", rig.com_distance_m,
                         f"rig.com_distance_m = {rig.com_distance_m:.4g}: the centre of mass of a tabletop top is within "
                         f"{TABLETOP['com_distance_m'][1]:g} m of the pivot: {meant} where m is meant?"))
    for key, value, bounds in (("rig.inertia_axial_kg_m2", rig.inertia_axial_kg_m2,
                                TABLETOP["axial_gyration_radius_m"]),
                               ("rig.inertia_transverse_kg_m2", rig.inertia_transverse_kg_m2,
                                TABLETOP["transverse_gyration_radius_m"])):
        d = _inertia_doubt(key, value, rig.mass_kg, bounds)
        if d is not None:
            out.append(d)
    g = rig.gravity_m_s2
    glo, ghi = TABLETOP["gravity_m_s2"]
    if g is not None and g > 0 and not glo <= g <= ghi:
        hint = " (cm/s^2 where m/s^2 is meant?)" if 900 <= g <= 1000 else ""
        out.append(Doubt("rig.gravity_m_s2", g, f"rig.gravity_m_s2 = {g:.4g}: Earth's is {glo:g} to {ghi:g}{hint}"))
    return tuple(out)


def protocol_doubts(protocol) -> tuple[Doubt, ...]:
    """Doubts about a :class:`~gyrorig.protocols.Protocol`: its rig (:func:`rig_doubts`), its launch spin, its markers' and camera's places."""
    out = list(rig_doubts(protocol.rig))
    spin = abs(protocol.launch.spin_rate_rad_s)
    if spin > TABLETOP["spin_rate_rad_s"][1]:
        out.append(Doubt("launch.spin_rate_rad_s", protocol.launch.spin_rate_rad_s,
                         f"launch.spin_rate_rad_s = {protocol.launch.spin_rate_rad_s:.4g} rad/s is "
                         f"{spin * 60 / (2 * math.pi):.3g} rev/min: rev/min or degrees/s where rad/s is meant "
                         f"(x {2 * math.pi / 60:.4g} or x {math.pi / 180:.4g})?"))
    markers = protocol.extra.get("markers")
    if isinstance(markers, dict):
        for name, m in markers.items():
            pos = m.get("position_m") if isinstance(m, dict) else None
            try:
                r = float(np.linalg.norm(np.asarray(pos, float)))
            except (TypeError, ValueError):
                continue  # malformed markers are refused where they are parsed
            if math.isfinite(r) and r > TABLETOP["marker_distance_m"][1]:
                out.append(Doubt(f"markers.{name}.position_m", r,
                                 f"markers.{name}.position_m is {r:.4g} m from the pivot: the markers of a tabletop "
                                 f"rig are within {TABLETOP['marker_distance_m'][1]:g} m: cm or mm where m is meant?"))
    return tuple(out)


#: a fitted value within this fraction of a units factor times its prediction is named as that unit mistake
UNIT_SLIP_TOLERANCE = 0.03

#: (ratio fitted / predicted, the mistake it means), for rates in rad/s
_RATE_SLIPS = (
    (180.0 / math.pi, "angles in degrees where radians are meant (in the angle table), or a protocol rate in rad/s "
                      "given in degrees/s"),
    (math.pi / 180.0, "a protocol rate in degrees/s where rad/s is meant, or angles in radians given as degrees"),
    (1e-3, "frame times in milliseconds where seconds are meant (t_s)"),
    (1e3, "frame times in seconds where ms are meant, or a protocol rate 1000 x too small"),
    (2.0 * math.pi, "a rate in Hz (rev/s) where rad/s is meant"),
    (1.0 / (2.0 * math.pi), "a rate in Hz (rev/s) where rad/s is meant"),
    (60.0 / (2.0 * math.pi), "a rate in rev/min where rad/s is meant"),
    (2.0 * math.pi / 60.0, "a rate in rev/min where rad/s is meant"),
)


def unit_slip(fitted: float, predicted: float) -> tuple[float, str] | None:
    """The units factor (and its mistake) that ``fitted / predicted`` matches within :data:`UNIT_SLIP_TOLERANCE`,
    else None."""
    if not (math.isfinite(fitted) and math.isfinite(predicted)) or predicted == 0 or fitted == 0:
        return None
    ratio = abs(fitted / predicted)
    for factor, what in _RATE_SLIPS:
        if abs(math.log(ratio / factor)) < UNIT_SLIP_TOLERANCE:
            return factor, what
    return None
