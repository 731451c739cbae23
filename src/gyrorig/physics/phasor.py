"""The paper's space-phasor formulation as an integrator (eqs. 5, 9; with torques eqs. 23, 28).

State ``[theta, phi, psi, Re W, Im W, omega_o]`` (plus ``[omega_f, psi_f]`` for a
gyrostat), with ``W = omega_d + j omega_q`` the transverse rate in the rotor's own
axes.  The dynamics are the paper's eq. (5) generalised to any torque and to a
gyrostat,

    I dW/dt = Gamma_d + j Gamma_q + j (L3 - I omega_o) W      (= -j I nu W for a rigid top),

and the kinematics its eq. (9), ``theta' + j phi' sin(theta) = W e^{j psi}``, with
``psi' = omega_o - phi' cos(theta)``.  This is an exact reformulation, but eq. (9)
divides by ``sin(theta)``: it is **singular at tilt 0 and pi**, and a run that
reaches ``|sin(theta)| < 1e-9`` fails with a :class:`~gyrorig.physics.SimulationError`.
The torques are the same objects the quaternion simulator uses (``torques.py``),
evaluated on the rotor's ``d, q, o`` axes.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..protocols import Protocol
from .torques import sum_torques, torques_for

__all__ = ["PhasorSingularity", "phasor_initial_state", "make_phasor_rhs", "phasor_states_to_arrays"]

#: |sin(theta)| below which eq. (9) is declared singular
SIN_THETA_MIN = 1e-9


class PhasorSingularity(ArithmeticError):
    """The phasor formulation reached a pole, where eq. (9) cannot give phi-dot."""


def phasor_initial_state(protocol: Protocol) -> NDArray[np.float64]:
    """State vector at t = 0 from the launch (eq. 9 for ``W``, eq. 8c for ``omega_o``)."""
    lau, rig = protocol.launch, protocol.rig
    th, ph, ps = lau.tilt_rad, lau.azimuth_rad, lau.spin_angle_rad
    w = complex(lau.tilt_rate_rad_s, lau.precession_rate_rad_s * math.sin(th)) * complex(math.cos(ps), -math.sin(ps))
    omega_o = lau.spin_rate_rad_s + lau.precession_rate_rad_s * math.cos(th)
    state = [th, ph, ps, w.real, w.imag, omega_o]
    if rig.is_gyrostat:
        state += [lau.frame_spin_rate_rad_s + lau.precession_rate_rad_s * math.cos(th), 0.0]
    return np.asarray(state, dtype=float)


def make_phasor_rhs(protocol: Protocol) -> Any:
    """Right-hand side ``f(t, y)`` of the phasor formulation."""
    rig = protocol.rig
    comps = [t.components for t in torques_for(protocol)]
    i_t, i_o = rig.inertia_transverse_kg_m2, rig.inertia_axial_kg_m2
    i_f = rig.frame_axial_inertia_kg_m2
    gyrostat = i_f is not None

    def rhs(t: float, y: NDArray[np.float64]) -> list[float]:
        th, ph, ps, wr, wi, om = y[0], y[1], y[2], y[3], y[4], y[5]
        om_f = y[6] if gyrostat else None
        sth, cth = math.sin(th), math.cos(th)
        if abs(sth) < SIN_THETA_MIN:
            raise PhasorSingularity(f"sin(theta) = {sth:.3g} at t = {t:.6g} s")
        sph, cph, sps, cps = math.sin(ph), math.cos(ph), math.sin(ps), math.cos(ps)
        # rotor axes d, q, o in lab coordinates (rows of the paper's eq. 7)
        d = (cph * cps - cth * sph * sps, sph * cps + cth * cph * sps, sth * sps)
        q = (-cph * sps - cth * sph * cps, -sph * sps + cth * cph * cps, sth * cps)
        o = (sth * sph, -sth * cph, cth)
        g1, g2, gr, gf = sum_torques(comps, t, d, q, o, wr, wi, om, om_f)
        l3 = i_o * om + (i_f * om_f if gyrostat else 0.0)
        k = l3 - i_t * om  # = -I nu for a rigid top
        # eq. (9): theta' + j phi' sin(theta) = W e^{j psi}
        er = wr * cps - wi * sps
        ei = wr * sps + wi * cps
        phidot = ei / sth
        out = [er, phidot, om - phidot * cth, (g1 - k * wi) / i_t, (g2 + k * wr) / i_t, gr / i_o]
        if gyrostat:
            out += [gf / i_f, om_f - phidot * cth]
        return out

    return rhs


def phasor_states_to_arrays(states: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    """Split raw phasor states into named arrays."""
    out = {"phi": states[:, 1], "theta": states[:, 0], "psi": states[:, 2],
           "rates": np.column_stack([states[:, 3], states[:, 4], states[:, 5]])}
    if states.shape[1] > 6:
        out["omega_f"], out["psi_f"] = states[:, 6], states[:, 7]
    return out
