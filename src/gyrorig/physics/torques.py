"""Composable torques on the top, evaluated in the simulator's reference frame.

Every torque is a small frozen object with one method, ``components``, called by
the right-hand side of the equations of motion with plain floats (no arrays: the
vectors have three entries and Python floats are faster than numpy for them):

``components(t_s, e1, e2, e3, w1, w2, omega_rotor, omega_frame) -> (T1, T2, T_rotor, T_frame)``

* ``e1, e2, e3``: the reference frame's axes in lab coordinates (``e3`` is the
  symmetry axis, i.e. the tip direction).
* ``w1, w2``: transverse angular velocity of the axis in that frame. [rad/s]
* ``omega_rotor``: absolute axial rate of the spinning rotor (the paper's ``omega_o``). [rad/s]
* ``omega_frame``: absolute axial rate of a gyrostat's non-spinning frame, or ``None``. [rad/s]
* Returns the transverse torque ``(T1, T2)`` in the reference frame and the axial
  torques on the rotor and on the frame. [N m]

Each torque is built only when the protocol asks for it (:func:`torques_for`).
Directions are from ``r x F`` in code, never from prose: the gravity torque about
the pivot is ``h e3 x F`` with ``F = M (g_vec - a_pivot)`` (gravity plus the
pseudo-force of an accelerating pivot).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ..protocols import AirDamping, EddyFieldDamping, MagnetInBallDamping, PaperDamping, Protocol

Vec = tuple[float, float, float]
TorqueOut = tuple[float, float, float, float]

__all__ = ["GravityTorque", "TransverseViscousTorque", "EddyFieldTorque", "sum_torques", "torques_for"]


def _dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@dataclass(frozen=True, slots=True)
class GravityTorque:
    """Weight plus the pivot-acceleration pseudo-force acting at the centre of mass.

    ``T = h e3 x M (g_vec - a_pivot(t))`` with ``g_vec = (0, 0, -g)``.

    Attributes
    ----------
    mass_kg, com_distance_m, gravity_m_s2 : float
    acceleration : callable or None
        ``t_s -> (ax, ay, az)`` lab pivot acceleration [m s^-2]; ``None`` for a fixed pivot.
    """

    mass_kg: float
    com_distance_m: float
    gravity_m_s2: float
    acceleration: Callable[[float], Vec] | None = None

    def force_N(self, t_s: float) -> Vec:
        """Lab-frame force on the centre of mass in the pivot's frame. [N]"""
        m = self.mass_kg
        if self.acceleration is None:
            return (0.0, 0.0, -m * self.gravity_m_s2)
        ax, ay, az = self.acceleration(t_s)
        return (-m * ax, -m * ay, -m * (self.gravity_m_s2 + az))

    def components(
        self, t_s: float, e1: Vec, e2: Vec, e3: Vec, w1: float, w2: float, omega_rotor: float,
        omega_frame: float | None,
    ) -> TorqueOut:
        f = self.force_N(t_s)
        h = self.com_distance_m
        # (0, 0, h) x (F.e1, F.e2, F.e3) = (-h F.e2, h F.e1, 0)
        return (-h * _dot(f, e2), h * _dot(f, e1), 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class TransverseViscousTorque:
    """``-c omega_perp`` on the axis, plus optional ``-c_axial omega_rotor`` on the spin.

    Covers the paper's law (``c = gamma I``), the magnet-in-ball damper and air drag.

    Attributes
    ----------
    coefficient_N_m_s : float
    axial_coefficient_N_m_s : float
    spin_compensated : bool
        A motor cancels the axial part on the rotor (its reaction goes to a gyrostat frame).
    """

    coefficient_N_m_s: float
    axial_coefficient_N_m_s: float = 0.0
    spin_compensated: bool = True

    def components(
        self, t_s: float, e1: Vec, e2: Vec, e3: Vec, w1: float, w2: float, omega_rotor: float,
        omega_frame: float | None,
    ) -> TorqueOut:
        c = self.coefficient_N_m_s
        axial = -self.axial_coefficient_N_m_s * omega_rotor
        if self.spin_compensated:
            # the motor holds the rotor; it pushes back on the frame (if there is one)
            return (-c * w1, -c * w2, 0.0, axial if omega_frame is not None else 0.0)
        return (-c * w1, -c * w2, axial, 0.0)


@dataclass(frozen=True, slots=True)
class EddyFieldTorque:
    """Conducting ball in a uniform lab field: ``T = -c (w - (w.b) b)``.

    ``w`` is the angular velocity of the body carrying the ball: the frame of a
    gyrostat (axial rate ``omega_frame``) or else the whole top (``omega_rotor``).

    Attributes
    ----------
    coefficient_N_m_s : float
        ``(2 pi / 15) sigma a^5 B^2``. [N m s]
    field_direction : tuple
        Unit field direction in the lab.
    spin_compensated : bool
        When the ball turns with the rotor, a motor cancels the axial part.
    """

    coefficient_N_m_s: float
    field_direction: Vec
    spin_compensated: bool

    def components(
        self, t_s: float, e1: Vec, e2: Vec, e3: Vec, w1: float, w2: float, omega_rotor: float,
        omega_frame: float | None,
    ) -> TorqueOut:
        b = self.field_direction
        b1, b2, b3 = _dot(b, e1), _dot(b, e2), _dot(b, e3)
        w3 = omega_rotor if omega_frame is None else omega_frame
        wb = w1 * b1 + w2 * b2 + w3 * b3
        c = self.coefficient_N_m_s
        t1, t2, t3 = -c * (w1 - wb * b1), -c * (w2 - wb * b2), -c * (w3 - wb * b3)
        if omega_frame is not None:
            return (t1, t2, 0.0, t3)
        if self.spin_compensated:
            return (t1, t2, 0.0, 0.0)
        return (t1, t2, t3, 0.0)


Torque = GravityTorque | TransverseViscousTorque | EddyFieldTorque


def sum_torques(comps, t_s: float, e1: Vec, e2: Vec, e3: Vec, w1: float, w2: float, omega_rotor: float,
                omega_frame: float | None) -> TorqueOut:
    """Sum of ``components`` of several torques (transverse, rotor-axial, frame-axial)."""
    t1 = t2 = tr = tf = 0.0
    for comp in comps:
        a, b, c, d = comp(t_s, e1, e2, e3, w1, w2, omega_rotor, omega_frame)
        t1 += a
        t2 += b
        tr += c
        tf += d
    return t1, t2, tr, tf


def torques_for(protocol: Protocol) -> tuple[Torque, ...]:
    """The torques the protocol's scene has, and only those.

    Parameters
    ----------
    protocol : Protocol

    Returns
    -------
    tuple
        Gravity (with the pivot pseudo-force) when gravity or a pivot acceleration is
        given, one damping torque per ``[pivot.damping]`` entry; empty for a free top.
    """
    rig = protocol.rig
    out: list[Torque] = []
    acc = protocol.pivot.acceleration
    if protocol.has_gravity or acc is not None:
        out.append(
            GravityTorque(
                rig.mass_kg, rig.com_distance_m, rig.gravity_m_s2 or 0.0, None if acc is None else acc.at
            )
        )
    for d in protocol.pivot.damping:
        if isinstance(d, (PaperDamping, MagnetInBallDamping)):
            out.append(TransverseViscousTorque(d.coefficient(rig.inertia_transverse_kg_m2)))
        elif isinstance(d, AirDamping):
            out.append(TransverseViscousTorque(d.coefficient_N_m_s, d.axial_coefficient_N_m_s, d.spin_compensated))
        elif isinstance(d, EddyFieldDamping):
            out.append(EddyFieldTorque(d.coefficient_N_m_s, d.field_direction, d.spin_compensated))
        else:  # pragma: no cover - the parser admits no other model
            raise TypeError(f"unknown damping model {d!r}")
    return tuple(out)
