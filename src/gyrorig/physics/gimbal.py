"""The simulator of a gyro in gimbals (:mod:`gyrorig.gimbals`): Lagrange's equations in the gimbal angles.

The gimbal angles are the configuration of the mechanism itself, so its equations are written in them (the
inner gimbal axis meets the outer ring's at ``theta = 0`` and ``pi``, where the mechanism locks: refused).  With
``T = 1/2 a(theta) phi'^2 + 1/2 b theta'^2 + 1/2 Io (psi' + phi' cos theta)^2`` and ``V = M g h cos theta``, the
azimuth and the spin are cyclic: ``p_psi = Io omega_3`` and ``p_phi = a(theta) phi' + Io omega_3 cos theta`` are
constants of the motion, and

    b theta'' = 1/2 a'(theta) phi'^2 - Io omega_3 phi' sin theta + M g h sin theta,
    phi' = (p_phi - Io omega_3 cos theta) / a(theta),     psi' = omega_3 - phi' cos theta.

Integrated by scipy's DOP853 at tight tolerances; the energy ``T + V`` is returned per sample to check it.  For a
top on a pivot (``J = 0``, ``I2 = b``, no frame) these are the heavy symmetric top's equations, and the test
suite checks them against :func:`gyrorig.physics.simulate` there.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from .._validate import ProtocolError
from ..gimbals import Gimbal, azimuth_inertia
from .simulate import SimulationError

__all__ = ["simulate_gimbal", "GIMBAL_COLUMNS"]

#: columns of :func:`simulate_gimbal`'s table
GIMBAL_COLUMNS = ("t_s", "theta_rad", "phi_rad", "psi_rad", "theta_dot_rad_s", "phi_dot_rad_s", "psi_dot_rad_s",
                  "energy_J")
#: the gimbals lock within this angle of the vertical [rad]
LOCK_MARGIN_RAD = 1e-3


def simulate_gimbal(protocol, *, duration_s: float, rate_hz: float, rtol: float = 1e-11) -> pd.DataFrame:
    """Integrate the protocol's gyro in its gimbals (``protocol.gimbal``; a top's values when None) from its launch
    (``tilt_rad``, ``tilt_rate_rad_s``, ``precession_rate_rad_s`` the outer ring's rate, ``spin_rate_rad_s`` the
    rotor's ``psi'``; azimuth and spin angle from their launch values).  Returns :data:`GIMBAL_COLUMNS` at
    ``rate_hz``; :class:`SimulationError` when the integration fails or the spin axis reaches the vertical (the
    gimbals lock)."""
    rig, launch = protocol.rig, protocol.launch
    gimbal = protocol.gimbal if getattr(protocol, "gimbal", None) is not None else Gimbal()
    if protocol.pivot.damping or protocol.pivot.acceleration is not None:
        raise ProtocolError(f"{protocol.source or protocol.name}: [pivot]: the gimbal simulator has no damping or "
                            "pivot acceleration (the gimbals' bearings are taken as free)")
    if not duration_s > 0 or not rate_hz > 0:
        raise ValueError(f"duration_s = {duration_s!r} and rate_hz = {rate_hz!r} must be > 0")
    io, b, mgh = rig.inertia_axial_kg_m2, rig.inertia_transverse_kg_m2, rig.mgh_N_m
    cross, frame = gimbal.cross(rig), rig.frame_axial_inertia_kg_m2 or 0.0
    th0, phid0 = launch.tilt_rad, launch.precession_rate_rad_s
    omega3 = launch.spin_rate_rad_s + phid0 * math.cos(th0)
    p_phi = azimuth_inertia(rig, gimbal, th0) * phid0 + io * omega3 * math.cos(th0)

    def rates(th):
        a = azimuth_inertia(rig, gimbal, th)
        return (p_phi - io * omega3 * np.cos(th)) / a, a

    def rhs(_t, y):
        th, thd = y[0], y[1]
        phid, _ = rates(th)
        da = 2.0 * (cross - frame) * math.sin(th) * math.cos(th)
        thdd = (0.5 * da * phid * phid - io * omega3 * phid * math.sin(th) + mgh * math.sin(th)) / b
        return [thd, thdd, phid, omega3 - phid * math.cos(th)]

    def locked(_t, y):
        return min(y[0], math.pi - y[0]) - LOCK_MARGIN_RAD
    locked.terminal = True

    t = np.arange(int(math.floor(duration_s * rate_hz + 1e-9)) + 1) / rate_hz
    y0 = [th0, launch.tilt_rate_rad_s, launch.azimuth_rad, launch.spin_angle_rad]
    sol = solve_ivp(rhs, (0.0, float(t[-1])), y0, method="DOP853", t_eval=t, rtol=rtol, atol=rtol * 1e-3,
                    events=locked)
    if sol.status == 1:
        raise SimulationError(f"the spin axis reached the vertical at t = {sol.t_events[0][0]:.6g} s: the gimbals "
                              "lock there (the inner axis meets the outer one)")
    if sol.status != 0:
        raise SimulationError(f"the gimbal integration failed: {sol.message}")
    th, thd, ph, ps = sol.y
    phid, a = rates(th)
    energy = 0.5 * a * phid ** 2 + 0.5 * b * thd ** 2 + 0.5 * io * omega3 ** 2 + mgh * np.cos(th)
    return pd.DataFrame(dict(zip(GIMBAL_COLUMNS, (sol.t, th, ph, ps, thd, phid, omega3 - phid * np.cos(th), energy))))

