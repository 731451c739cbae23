"""A gyroscope in gimbals: the protocol's ``[gimbal]`` section and its closed forms.

A teaching lab's gimbal-mounted gyro is not a top on a ball pivot.  The rotor (axial inertia ``Io``, the rig's
``inertia_axial_kg_m2``) spins in an inner ring that tilts about a horizontal axis (the inner gimbal axis); the
inner ring turns with an outer ring about the vertical.  With the Euler angles of the paper (``theta`` the spin
axis's tilt from the vertical, ``phi`` the outer ring's azimuth, ``psi`` the rotor's angle in the inner ring) the
kinetic energy is

    T = 1/2 a(theta) phi'^2 + 1/2 b theta'^2 + 1/2 Io (psi' + phi' cos theta)^2,
    a(theta) = J + I2 sin^2 theta + Cf cos^2 theta,

with ``b`` the tilting assembly's inertia about the inner gimbal axis (``rig.inertia_transverse_kg_m2``),
``I2`` its inertia about the axis across the inner gimbal axis and the spin axis (``cross_inertia_kg_m2``; the
same as ``b`` for a top), ``Cf`` its non-spinning parts about the spin axis (``rig.frame_axial_inertia_kg_m2``,
0 without) and ``J`` what turns only in azimuth, the outer ring, about the vertical (``outer_inertia_kg_m2``).
A top on a pivot is ``J = 0``, ``I2 = b``.  Gravity acts through ``M g h cos theta`` (``rig.com_distance_m``
along the spin axis from the gimbals' centre).

Closed forms (small oscillations; judged against :func:`gyrorig.physics.gimbal.simulate_gimbal`):

- nutation about a steady tilt ``theta_0`` of a balanced gyro (``h = 0``) spinning at ``omega_3``:
  ``omega_n = Io omega_3 sin theta_0 / sqrt(a(theta_0) b)``; with the spin axis horizontal, ``Io omega_3`` over
  the geometric mean of the inertias about the vertical and about the inner axis;
- steady precession: the slow root of ``(I2 - Cf) cos theta phi'^2 - Io omega_3 phi' + M g h = 0`` with
  ``omega_3 = psi' + phi' cos theta``, i.e. of ``(I2 - Cf - Io) cos theta phi'^2 - Io psi' phi' + M g h = 0``
  (``M g h / (Io psi')`` with the spin axis horizontal; Goldstein's eq. 5.76 for a top).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validate import ProtocolError, check_keys, number

__all__ = ["Gimbal", "parse_gimbal", "azimuth_inertia", "gimbal_nutation_frequency", "gimbal_precession_rate",
           "refuse_gimbal", "gimbal_prediction"]


@dataclass(frozen=True, slots=True)
class Gimbal:
    """The gimbals of a gimbal-mounted gyro (module docstring).

    Attributes
    ----------
    outer_inertia_kg_m2 : float
        What turns only in azimuth (the outer ring, cylinders on it) about the vertical axis (``J``). [kg m^2]
    cross_inertia_kg_m2 : float or None
        The tilting assembly about the axis across the inner gimbal axis and the spin axis (``I2``); None: the
        same as ``rig.inertia_transverse_kg_m2`` (about the inner gimbal axis). [kg m^2]
    """

    outer_inertia_kg_m2: float = 0.0
    cross_inertia_kg_m2: float | None = None

    def cross(self, rig) -> float:
        """``I2``: the cross inertia, the rig's transverse one where none is given. [kg m^2]"""
        return rig.inertia_transverse_kg_m2 if self.cross_inertia_kg_m2 is None else self.cross_inertia_kg_m2


def parse_gimbal(t: Mapping[str, Any]) -> Gimbal:
    """The ``[gimbal]`` section: ``outer_inertia_kg_m2`` (>= 0) and ``cross_inertia_kg_m2`` (> 0), both optional."""
    check_keys("gimbal", t, set(), {"outer_inertia_kg_m2", "cross_inertia_kg_m2"})
    outer = number("gimbal", "outer_inertia_kg_m2", t.get("outer_inertia_kg_m2", 0.0), lo=0.0)
    cross = (number("gimbal", "cross_inertia_kg_m2", t["cross_inertia_kg_m2"], lo=0.0, lo_open=True)
             if "cross_inertia_kg_m2" in t else None)
    return Gimbal(outer, cross)


def azimuth_inertia(rig, gimbal: Gimbal | None, tilt_rad):
    """``a(theta)``: the inertia about the vertical of everything but the rotor's spin (module docstring), at a tilt
    or an array of them. [kg m^2]"""
    g = gimbal or Gimbal()
    frame = rig.frame_axial_inertia_kg_m2 or 0.0
    return g.outer_inertia_kg_m2 + g.cross(rig) * np.sin(tilt_rad) ** 2 + frame * np.cos(tilt_rad) ** 2


def gimbal_nutation_frequency(rig, gimbal: Gimbal | None, spin_rad_s: float, tilt_rad: float) -> float:
    """Small-oscillation nutation frequency of a balanced gyro about the steady tilt ``tilt_rad``:
    ``Io omega_3 sin theta_0 / sqrt(a(theta_0) b)``. [rad/s]"""
    a = azimuth_inertia(rig, gimbal, tilt_rad)
    return rig.inertia_axial_kg_m2 * abs(spin_rad_s) * math.sin(tilt_rad) / math.sqrt(a * rig.inertia_transverse_kg_m2)


def gimbal_precession_rate(rig, gimbal: Gimbal | None, spin_rad_s: float, tilt_rad: float) -> float:
    """The slow steady precession rate at the tilt for the rotor's spin ``psi' = spin_rad_s``: the root of
    ``(I2 - Cf - Io) cos theta x^2 - Io psi' x + M g h = 0`` that tends to ``M g h / (Io psi')``; ValueError where
    the spin is too slow for steady precession. [rad/s]"""
    io = rig.inertia_axial_kg_m2
    k = ((gimbal or Gimbal()).cross(rig) - (rig.frame_axial_inertia_kg_m2 or 0.0) - io) * math.cos(tilt_rad)
    lw, mgh = io * spin_rad_s, rig.mgh_N_m
    disc = lw * lw - 4.0 * k * mgh
    if disc < 0:
        raise ValueError(f"no steady precession at spin {spin_rad_s:g} rad/s and tilt {tilt_rad:g} rad: the spin is "
                         "below the fast-top limit")
    return 2.0 * mgh / (lw + math.copysign(math.sqrt(disc), lw))


def refuse_gimbal(protocol, what: str) -> None:
    """ProtocolError when ``protocol`` describes a gyro in gimbals, which ``what`` does not model."""
    if getattr(protocol, "gimbal", None) is not None:
        raise ProtocolError(f"{protocol.source or protocol.name}: [gimbal]: {what} models a top on a pivot, not a gyro "
                            "in gimbals; gimbals are modelled by 'gyrorig identify' (lab tables), 'gyrorig theory' "
                            "and 'gyrorig simulate' (gyrorig.physics.gimbal)")


def gimbal_prediction(protocol) -> dict:
    """What the closed forms say of a gyro in gimbals at its launch tilt and spin: the balanced gyro's nutation
    frequency (small oscillations; for a weighted one only when its centre of mass is on the pivot) and, with a
    weight, the slow steady precession rate; each beside the fast-top formula of a top on a pivot (``Io Omega /
    I``, ``M g h / (Io Omega)``).  With error bars: :func:`gyrorig.propagate.gimbal_prediction_with_uncertainty`."""
    rig, launch = protocol.rig, protocol.launch
    spin, tilt = launch.spin_rate_rad_s, launch.tilt_rad
    out: dict = {"protocol": protocol.name, "kind": "gyro in gimbals", "tilt_rad": tilt, "spin_rate_rad_s": spin}
    if rig.mgh_N_m == 0.0:
        out["nutation_frequency_rad_s"] = {
            "gimbal": gimbal_nutation_frequency(rig, protocol.gimbal, spin, tilt),
            "fast_top": rig.inertia_axial_kg_m2 * abs(spin) / rig.inertia_transverse_kg_m2,
            "note": "small oscillations about the launch tilt (the error grows as the nutation's amplitude squared)"}
    else:
        try:
            rate = gimbal_precession_rate(rig, protocol.gimbal, spin, tilt)
        except ValueError as exc:
            rate, out["precession_note"] = math.nan, str(exc)
        out["precession_rate_slow_rad_s"] = {"gimbal": rate,
                                             "fast_top": rig.mgh_N_m / (rig.inertia_axial_kg_m2 * spin)}
    return out
