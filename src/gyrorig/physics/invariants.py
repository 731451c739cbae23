"""Conserved quantities of a trajectory: energy, angular momentum about the vertical and the axis."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..protocols import Protocol
from .rotations import euler_to_matrix

__all__ = ["invariants"]


def invariants(protocol: Protocol, trajectory: pd.DataFrame) -> pd.DataFrame:
    """Energy and angular momenta along a trajectory.

    Parameters
    ----------
    protocol : Protocol
    trajectory : DataFrame
        Output of :func:`gyrorig.simulate` or the exact solution.

    Returns
    -------
    DataFrame
        ``t_s``; ``energy_J``: kinetic energy plus the potential of gravity and of a
        pivot acceleration, ``-h e3 . M (g_vec - a_pivot(t))`` (conserved without
        damping when the acceleration is constant); ``l_vertical_kg_m2_s``: angular
        momentum about the effective vertical ``-(g_vec - a_pivot)`` (about ``z`` for
        a free top); ``l_axial_kg_m2_s``: ``Io omega_o + I_f omega_f`` (conserved
        without axial torque).
    """
    rig = protocol.rig
    df = trajectory
    rot = euler_to_matrix(df.phi_rad.to_numpy(), df.theta_rad.to_numpy(), df.psi_rad.to_numpy())
    body = np.column_stack([df.omega_d_rad_s, df.omega_q_rad_s, np.zeros(len(df))])
    w_perp = np.einsum("nij,nj->ni", rot, body)
    tip = df[["tip_x", "tip_y", "tip_z"]].to_numpy()
    om = df.omega_o_rad_s.to_numpy()
    om_f = df["omega_frame_rad_s"].to_numpy() if "omega_frame_rad_s" in df else np.zeros(len(df))
    l3 = rig.inertia_axial_kg_m2 * om + (rig.frame_axial_inertia_kg_m2 or 0.0) * om_f
    kinetic = 0.5 * (
        rig.inertia_transverse_kg_m2 * np.einsum("ni,ni->n", w_perp, w_perp)
        + rig.inertia_axial_kg_m2 * om**2
        + (rig.frame_axial_inertia_kg_m2 or 0.0) * om_f**2
    )
    g_vec = np.array([0.0, 0.0, -(rig.gravity_m_s2 or 0.0)])
    acc = protocol.pivot.acceleration
    t = df.t_s.to_numpy()
    a_p = np.zeros((len(df), 3)) if acc is None else np.array([acc.at(ti) for ti in t])
    force = rig.mass_kg * (g_vec - a_p)
    potential = -rig.com_distance_m * np.einsum("ni,ni->n", tip, force)
    fnorm = np.linalg.norm(force, axis=1, keepdims=True)
    up = np.where(fnorm > 0, -force / np.where(fnorm > 0, fnorm, 1.0), np.array([0.0, 0.0, 1.0]))
    ang = rig.inertia_transverse_kg_m2 * w_perp + l3[:, None] * tip
    return pd.DataFrame({
        "t_s": t,
        "energy_J": kinetic + potential,
        "l_vertical_kg_m2_s": np.einsum("ni,ni->n", ang, up),
        "l_axial_kg_m2_s": l3,
    })
