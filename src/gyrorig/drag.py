"""What a scene's drags do to the rotor's spin: how fast the drags no motor holds slow it (the fit's spin-down model
and theory's prediction of the precession's growth read it from the protocol)."""

from __future__ import annotations

import math

from .protocols import AirDamping, EddyFieldDamping, Protocol

__all__ = ["rotor_spin_decay_rate_per_s"]


def rotor_spin_decay_rate_per_s(protocol: Protocol) -> float:
    """The rate at which the drags no motor holds slow the rotor's spin at the launch (``-d ln(omega_o)/dt``, from the
    rotor-axial part of each damping torque over ``Io``; 0: the spin is kept). [1/s]"""
    rig, lau = protocol.rig, protocol.launch
    axis = (math.sin(lau.tilt_rad) * math.sin(lau.azimuth_rad), -math.sin(lau.tilt_rad) * math.cos(lau.azimuth_rad),
            math.cos(lau.tilt_rad))
    coefficient = 0.0
    for d in protocol.pivot.damping:
        if isinstance(d, AirDamping) and not d.spin_compensated:
            coefficient += d.axial_coefficient_N_m_s
        elif isinstance(d, EddyFieldDamping) and not d.spin_compensated and not rig.is_gyrostat:
            coefficient += d.coefficient_N_m_s * (1.0 - sum(f * a for f, a in zip(d.field_direction, axis)) ** 2)
    return coefficient / rig.inertia_axial_kg_m2
