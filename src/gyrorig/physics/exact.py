"""Exact solution of the undamped symmetric top (Lagrange top), free or heavy.

Heavy top (Goldstein 3rd ed. sec. 5.7; Whittaker, *Analytical Dynamics* sec. 71)
--------------------------------------------------------------------------------
With ``u = cos(theta)`` measured from the effective vertical (``-(g_vec - a_pivot)``;
a constant pivot acceleration just tilts it), ``a = L3 / I``, ``b = Lz / I``,
``beta = 2 M g_eff h / I`` and ``alpha - beta u0 = |omega_perp|^2``:

    u'^2 = f(u) = (alpha - beta u)(1 - u^2) - (b - a u)^2 = beta (u - u1)(u - u2)(u - u3),

with ``-1 <= u1 <= u <= u2 <= 1 <= u3``.  Then

    u(t)   = u1 + (u2 - u1) sn^2(tau, m),    tau = lambda t + tau0,
    m      = (u2 - u1) / (u3 - u1),          lambda = sqrt(beta (u3 - u1)) / 2,
    phi'   = (b - a u) / (1 - u^2) = (b - a) / (2 (1 - u)) + (b + a) / (2 (1 + u)),
    psi'   = omega_o - u phi' = omega_o - a - (b - a) / (2 (1 - u)) + (b + a) / (2 (1 + u)),

and the integrals of ``1 / (1 -+ u)`` are incomplete elliptic integrals of the third
kind, ``int_0^tau dtau / (1 - n sn^2) = tau + (n/3) sn^3 R_J(cn^2, dn^2, 1, 1 - n sn^2)``
on ``|tau| <= K`` (Carlson's symmetric form, DLMF 19.25.14), continued periodically.
The cubic's roots are found in the shifted variable ``x = u - u0`` whose constant
coefficient ``f(u0) = u'(0)^2`` is known exactly, so a turning-point launch
(release from rest) has its root exactly at the launch tilt.  Near a pole ``u`` rounds to
``+-1`` (below about 1e-8 rad it holds no tilt at all), so the distances from the poles,
``1 - u = 2 sin^2(theta/2)`` and ``1 + u``, are carried from the launch's tip direction
through the shifted roots, and ``sin(theta)``, ``phi'`` and the tilts are formed from them.

A trajectory through a pole (``b = a`` with ``u2 = 1``, or ``b = -a`` with ``u1 = -1``)
is handled with a signed ``sin(theta)`` so the tip moves smoothly across it.

Free top
--------
Without gravity the rotor's orientation is ``R(t) = Rot(L, |L| t / I) R0 Rot_z(nu t)``
with ``nu = omega_o - L3 / I`` (a rotation about the fixed angular momentum, composed
with a body-fixed rotation about the axis; for a rigid top ``nu = (I - Io) omega_o / I``,
the paper's eq. 4).

Damped scenes and time-dependent pivot accelerations have no exact solution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy.special import ellipj, ellipk, elliprf, elliprj

from ..gimbals import refuse_gimbal
from ..protocols import Protocol
from .rotations import euler_from_matrix, euler_matrix_cs, euler_to_matrix
from .simulate import initial_state, rot_z, trajectory_frame

__all__ = ["ExactSolutionError", "LagrangeTopSolution", "exact_solution", "exact_solution_applies"]


class ExactSolutionError(ValueError):
    """The scene has no exact solution (damping, or a time-dependent pivot acceleration)."""


def exact_solution_applies(protocol: Protocol) -> tuple[bool, str]:
    """Whether :func:`exact_solution` covers the scene, and if not, why."""
    if protocol.pivot.damping:
        return False, "the scene is damped"
    acc = protocol.pivot.acceleration
    if acc is not None and not acc.is_constant:
        return False, "the pivot acceleration changes with time"
    return True, ""


def _rodrigues(axis: NDArray[np.float64], angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices about a fixed unit axis by each angle; shape (n, 3, 3)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def _frame_with_z(z: NDArray[np.float64]) -> NDArray[np.float64]:
    """A right-handed orthonormal basis (columns) whose third column is ``z``.

    Keeps the lab x axis in the x'-z' plane where possible, so that for a vertical
    ``z`` the basis is the identity.
    """
    z = z / np.linalg.norm(z)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = ref - (ref @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _sorted_cubic_roots(c3: float, c2: float, c1: float, c0: float) -> NDArray[np.float64]:
    """Real roots of ``c3 x^3 + c2 x^2 + c1 x + c0`` (three real roots expected), polished."""
    if c0 == 0.0:
        # x = 0 exactly; the others from c3 x^2 + c2 x + c1 = 0 (stable quadratic formula)
        disc = max(c2 * c2 - 4.0 * c3 * c1, 0.0)
        qq = -0.5 * (c2 + math.copysign(math.sqrt(disc), c2 if c2 != 0 else 1.0))
        r1 = qq / c3
        r2 = c1 / qq if qq != 0.0 else 0.0
        roots = np.array([0.0, r1, r2])
    else:
        roots = np.sort(np.roots([c3, c2, c1, c0]).real)
        for _ in range(3):  # Newton polish
            p = ((c3 * roots + c2) * roots + c1) * roots + c0
            dp = (3.0 * c3 * roots + 2.0 * c2) * roots + c1
            step = np.where(dp != 0.0, p / np.where(dp != 0.0, dp, 1.0), 0.0)
            roots = roots - step
    return np.sort(roots)


@dataclass(frozen=True)
class LagrangeTopSolution:
    """Closed-form motion of the undamped top for one protocol; call :meth:`evaluate`.

    Attributes (all derived from the launch; SI units)
    ----------
    kind : str
        ``"free"``, ``"steady"`` (theta constant: steady precession or sleeping) or ``"nutating"``.
    up : ndarray (3,)
        Effective vertical (lab coordinates) about which the top precesses.
    u1, u2, u3 : float
        Roots of the cubic (cosines of the turning tilts about ``up``; ``u3 >= 1``).
    one_minus_u1, one_plus_u1, spread, u1_minus_u0 : float
        ``1 - u1``, ``1 + u1``, ``u2 - u1`` and ``u1 - u0``, each to its own relative precision (near a pole
        ``u`` rounds).
    sin2_0 : float
        ``sin^2`` of the launch tilt about ``up``.
    wz_per_s : float
        ``b - a u0``: the component of the launch's transverse angular velocity along ``up``. [rad/s]
    a_per_s, b_per_s : float
        ``L3 / I`` and ``L_up / I``. [rad/s]
    modulus_m : float
        Parameter ``m`` of the Jacobi functions.
    lam_per_s : float
        ``lambda``; the nutation angular frequency is ``pi lambda / K(m)``. [rad/s]
    """

    protocol: Protocol
    kind: str
    up: NDArray[np.float64]
    basis: NDArray[np.float64]
    u0: float
    u1: float
    u2: float
    u3: float
    one_minus_u1: float
    one_plus_u1: float
    spread: float
    u1_minus_u0: float
    sin2_0: float
    wz_per_s: float
    a_per_s: float
    b_per_s: float
    bma_per_s: float
    bpa_per_s: float
    omega_rotor_rad_s: float
    omega_frame_rad_s: float | None
    modulus_m: float
    lam_per_s: float
    tau0: float
    phi0_rad: float
    psi0_rad: float
    psi_frame0_rad: float
    pole_north: bool
    pole_south: bool
    # free top
    l_over_i: NDArray[np.float64]
    rotor0: NDArray[np.float64]
    frame0: NDArray[np.float64] | None

    # ----------------------------------------------------------------------------------
    @property
    def nutation_frequency_rad_s(self) -> float:
        """Angular frequency of the tilt oscillation (0 when theta is constant). [rad/s]"""
        if self.kind != "nutating":
            return 0.0
        return math.pi * self.lam_per_s / float(ellipk(self.modulus_m))

    @property
    def tilt_range_rad(self) -> tuple[float, float]:
        """Smallest and largest tilt from the effective vertical. [rad]"""
        if self.kind == "free":
            return (math.nan, math.nan)
        w1, v1 = self.one_minus_u1, self.one_plus_u1
        w2, v2 = max(w1 - self.spread, 0.0), max(v1 + self.spread, 0.0)
        return (2.0 * math.atan2(math.sqrt(w2), math.sqrt(v2)), 2.0 * math.atan2(math.sqrt(w1), math.sqrt(v1)))

    @property
    def mean_precession_rate_rad_s(self) -> float:
        """Average phi-dot over a nutation period (the observable precession rate). [rad/s]"""
        if self.kind == "free":
            return float(np.linalg.norm(self.l_over_i))
        if self.kind == "steady":
            return 0.0 if self.sin2_0 == 0.0 else self.wz_per_s / self.sin2_0
        k = float(ellipk(self.modulus_m))
        return float(self._phi_increment(np.array([2.0 * k]))[0] / (2.0 * k / self.lam_per_s))

    def _phi_increment(self, tau_span: NDArray[np.float64]) -> NDArray[np.float64]:
        """phi advance over ``tau in [tau0, tau0 + span]`` (helper for the mean rate)."""
        j1, j2 = self._integrals(self.tau0 + tau_span)
        return 0.5 * self.bma_per_s * j1 + 0.5 * self.bpa_per_s * j2

    # ----------------------------------------------------------------------------------
    def _p_integral(self, n: float, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        """``int_0^tau dtau' / (1 - n sn^2(tau'))``, continued over all tau."""
        m = self.modulus_m
        k = float(ellipk(m))
        j = np.round(tau / (2.0 * k))
        r = tau - 2.0 * k * j
        sn, cn, dn, _ = ellipj(r, m)
        part = r + (n / 3.0) * sn**3 * elliprj(cn * cn, dn * dn, 1.0, 1.0 - n * sn * sn)
        full = 2.0 * (k + (n / 3.0) * float(elliprj(0.0, 1.0 - m, 1.0, 1.0 - n)))
        return j * full + part

    def _integrals(self, tau: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``int_0^t dt / (1 - u)`` and ``int_0^t dt / (1 + u)`` as functions of tau."""
        w1, v1, lam = self.one_minus_u1, self.one_plus_u1, self.lam_per_s
        zero = np.zeros_like(tau)
        j1 = j2 = zero
        if not self.pole_north:
            n1 = self.spread / w1
            j1 = (self._p_integral(n1, tau) - self._p_integral(n1, np.array([self.tau0]))) / (lam * w1)
        if not self.pole_south:
            n2 = -self.spread / v1
            j2 = (self._p_integral(n2, tau) - self._p_integral(n2, np.array([self.tau0]))) / (lam * v1)
        return j1, j2

    # ----------------------------------------------------------------------------------
    def evaluate(self, t_s: ArrayLike) -> pd.DataFrame:
        """Trajectory at the given times, with the simulator's columns (see ``simulate``)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        if self.kind == "free":
            return self._evaluate_free(t)
        om, om_f = self.omega_rotor_rad_s, self.omega_frame_rad_s
        a = self.a_per_s
        if self.kind == "steady":
            u = np.full_like(t, self.u0)
            sin_th = np.full_like(t, math.sqrt(self.sin2_0))
            phidot = self.mean_precession_rate_rad_s
            phi = self.phi0_rad + phidot * t
            dpsi = (om - phidot * self.u0) * t
            dpsi_f = ((om_f or 0.0) - phidot * self.u0) * t
            thetadot = np.zeros_like(t)
            phidot_sin = phidot * sin_th
        else:
            u1, spread, lam, m = self.u1, self.spread, self.lam_per_s, self.modulus_m
            w1, v1 = self.one_minus_u1, self.one_plus_u1
            tau = lam * t + self.tau0
            k = float(ellipk(m))
            jper = np.round(tau / (2.0 * k))
            sign = np.where(np.mod(jper, 2.0) == 0.0, 1.0, -1.0)
            sn_r, cn_r, dn, _ = ellipj(tau - 2.0 * k * jper, m)
            sn, cn = sign * sn_r, sign * cn_r
            sn2 = sn * sn
            u = u1 + spread * sn2
            n1 = spread / w1 if not self.pole_north else 1.0
            n2 = -spread / v1 if not self.pole_south else 0.0
            # signed sqrt(1 - u) = p1 g1 and sqrt(1 + u) = p2 g2
            p1 = math.sqrt(w1)
            g1 = cn if self.pole_north else np.sqrt(1.0 - n1 * sn2)
            p2 = math.sqrt(spread) if self.pole_south else math.sqrt(v1)
            g2 = sn if self.pole_south else np.sqrt(1.0 - n2 * sn2)
            sin_th = p1 * g1 * p2 * g2
            cn_over_g1 = np.ones_like(t) if self.pole_north else cn / g1
            sn_over_g2 = np.ones_like(t) if self.pole_south else sn / g2
            # theta' = -u' / sin(theta), u' = 2 (u2 - u1) lam sn cn dn
            thetadot = -2.0 * spread * lam * dn * cn_over_g1 * sn_over_g2 / (p1 * p2)
            # phi' sin(theta) = (b - a u) / sin(theta), simplified at a pole
            if self.pole_north:
                phidot_sin = a * (p1 * g1) / (p2 * g2) if not self.pole_south else np.zeros_like(t)
            elif self.pole_south:
                phidot_sin = -a * (p2 * g2) / (p1 * g1)
            else:
                # b - a u = (b - a u0) - a (u - u0), with u - u0 = (u1 - u0) + spread sn^2 kept small near a pole
                phidot_sin = (self.wz_per_s - a * (self.u1_minus_u0 + spread * sn2)) / sin_th
            j1, j2 = self._integrals(tau)
            common = 0.5 * self.bpa_per_s * j2 - 0.5 * self.bma_per_s * j1
            phi = self.phi0_rad + 0.5 * self.bma_per_s * j1 + 0.5 * self.bpa_per_s * j2
            dpsi = (om - a) * t + common
            dpsi_f = ((om_f or 0.0) - a) * t + common
        psi = self.psi0_rad + dpsi
        rotor = self.basis @ euler_matrix_cs(phi, u, sin_th, psi)
        w = (thetadot + 1j * phidot_sin) * np.exp(-1j * psi)
        rates = np.column_stack([w.real, w.imag, np.full_like(t, om)])
        frame = None
        if om_f is not None:
            frame = (self.basis @ euler_matrix_cs(phi, u, sin_th, self.psi_frame0_rad + dpsi_f), np.full_like(t, om_f))
        return trajectory_frame(self.protocol, t, rotor, rates, frame=frame)

    def _evaluate_free(self, t: NDArray[np.float64]) -> pd.DataFrame:
        ell = self.l_over_i
        norm = float(np.linalg.norm(ell))
        axis = ell / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
        spin_about_l = _rodrigues(axis, norm * t)
        om, om_f = self.omega_rotor_rad_s, self.omega_frame_rad_s
        nu = om - self.a_per_s
        rotor = spin_about_l @ self.rotor0 @ rot_z(nu * t)
        # body rates: R^T (L/I) + nu e3
        rates = np.einsum("nji,j->ni", rotor, ell)
        rates[:, 2] += nu
        frame = None
        if om_f is not None and self.frame0 is not None:
            frame = (spin_about_l @ self.frame0 @ rot_z((om_f - self.a_per_s) * t), np.full_like(t, om_f))
        return trajectory_frame(self.protocol, t, rotor, rates, frame=frame)


def exact_solution(protocol: Protocol, t_s: ArrayLike | None = None) -> LagrangeTopSolution | pd.DataFrame:
    """Exact solution of an undamped scene.

    Parameters
    ----------
    protocol : Protocol
        Undamped, with no or a constant pivot acceleration.
    t_s : array_like, optional
        If given, return the trajectory DataFrame at these times; otherwise the
        :class:`LagrangeTopSolution` object (for repeated evaluation and derived
        quantities: nutation frequency, tilt range, mean precession rate).

    Raises
    ------
    ExactSolutionError
        If the scene has no exact solution.
    """
    ok, why = exact_solution_applies(protocol)
    if not ok:
        raise ExactSolutionError(f"no exact solution for {protocol.name}: {why}")
    refuse_gimbal(protocol, "the exact solution of the heavy top")
    sol = _build(protocol)
    return sol if t_s is None else sol.evaluate(t_s)


def _launch_phase(x1: float, x2: float, m: float, udot0: float) -> float:
    """``tau0`` of a launch at ``u0`` between the turning points ``u0 + x1 <= u0 <= u0 + x2``, moving as ``udot0``
    says (``u = u1 + (u2 - u1) sn^2(tau)``: ``sn^2(tau0) = -x1 / (x2 - x1)``, on the rising or falling side)."""
    s = math.sqrt(-x1 / (x2 - x1))
    c = math.sqrt(x2 / (x2 - x1))
    f_inc = s * float(elliprf(c * c, 1.0 - m * s * s, 1.0)) if s > 0 else 0.0
    if udot0 > 0:
        return f_inc
    if udot0 < 0:
        return -f_inc
    return float(ellipk(m)) if x2 == 0.0 else 0.0


def _build(protocol: Protocol) -> LagrangeTopSolution:
    rig, lau = protocol.rig, protocol.launch
    i_t = rig.inertia_transverse_kg_m2
    # launch state from the simulator's own construction (axis formulation)
    y0 = initial_state(protocol, "axis")
    abc = euler_to_matrix(lau.azimuth_rad, lau.tilt_rad, 0.0)
    c_hat = abc[:, 2]
    w_perp = abc @ np.array([y0[4], y0[5], 0.0])
    om = float(y0[6])
    om_f = float(y0[8]) if rig.is_gyrostat else None
    l3 = rig.inertia_axial_kg_m2 * om + (rig.frame_axial_inertia_kg_m2 or 0.0) * (om_f or 0.0)
    a = l3 / i_t
    rotor0 = abc @ rot_z(np.array([lau.spin_angle_rad]))[0]
    frame0 = abc if rig.is_gyrostat else None
    acc = protocol.pivot.acceleration
    a_p = np.zeros(3) if acc is None else np.asarray(acc.acceleration_m_s2[0], dtype=float)
    g_vec = np.array([0.0, 0.0, -(rig.gravity_m_s2 or 0.0)])
    g_eff = g_vec - a_p
    beta = 2.0 * rig.mass_kg * float(np.linalg.norm(g_eff)) * rig.com_distance_m / i_t
    common = dict(protocol=protocol, a_per_s=a, omega_rotor_rad_s=om, omega_frame_rad_s=om_f,
                  rotor0=rotor0, frame0=frame0)
    if beta == 0.0:
        ell = w_perp + a * c_hat
        return LagrangeTopSolution(
            kind="free", up=np.array([0.0, 0.0, 1.0]), basis=np.eye(3), u0=float(c_hat[2]), u1=math.nan,
            u2=math.nan, u3=math.nan, one_minus_u1=math.nan, one_plus_u1=math.nan, spread=math.nan,
            u1_minus_u0=math.nan, sin2_0=math.nan, wz_per_s=math.nan, b_per_s=float(ell[2]), bma_per_s=math.nan,
            bpa_per_s=math.nan,
            modulus_m=0.0, lam_per_s=0.0, tau0=0.0, phi0_rad=lau.azimuth_rad, psi0_rad=lau.spin_angle_rad,
            psi_frame0_rad=0.0, pole_north=False, pole_south=False, l_over_i=ell, **common,
        )
    up = -g_eff / np.linalg.norm(g_eff)
    basis = _frame_with_z(up)
    cp = basis.T @ c_hat  # tip in the primed frame
    wp = basis.T @ w_perp
    u0 = float(cp[2])
    rho2 = float(cp[0] ** 2 + cp[1] ** 2)
    one_minus = rho2 / (1.0 + u0) if u0 > 0 else 1.0 - u0
    one_plus = rho2 / (1.0 - u0) if u0 <= 0 else 1.0 + u0
    tipdot = np.cross(wp, cp)
    udot0 = float(tipdot[2])
    wz = float(wp[2])  # omega_perp . up = b - a u0
    bma = wz - a * one_minus
    bpa = wz + a * one_plus
    b = wz + a * u0
    wperp2 = float(wp @ wp)  # alpha - beta u0
    s2 = rho2
    f0 = udot0 * udot0
    f1 = -beta * s2 - 2.0 * u0 * wperp2 + 2.0 * a * wz
    f2 = 2.0 * beta * u0 - wperp2 - a * a
    x1, x2, x3 = _sorted_cubic_roots(beta, f2, f1, f0)
    x1, x2 = min(x1, 0.0), max(x2, 0.0)
    u1, u2, u3 = u0 + x1, u0 + x2, u0 + x3
    # azimuth and spin at launch in the primed frame
    # within 1e-10 rad of a pole the launch azimuth is taken from the departure direction
    at_pole = rho2 < 1e-20
    if at_pole:
        tdot = float(np.hypot(tipdot[0], tipdot[1]))
        phi0 = math.atan2(tipdot[0], -tipdot[1]) if tdot > 0 else (lau.azimuth_rad if np.allclose(basis, np.eye(3)) else 0.0)
    else:
        phi0 = math.atan2(cp[0], -cp[1])
    pole_tol = 1e-10 if at_pole else 0.0
    _, _, psi0 = euler_from_matrix((basis.T @ rotor0)[None], phi_hint_rad=[phi0], pole_tolerance=pole_tol)
    psi_f0 = 0.0
    if frame0 is not None:
        _, _, pf = euler_from_matrix((basis.T @ frame0)[None], phi_hint_rad=[phi0], pole_tolerance=pole_tol)
        psi_f0 = float(pf[0])
    spread = x2 - x1
    kw = dict(up=up, basis=basis, u0=u0, sin2_0=s2, wz_per_s=wz, b_per_s=b, bma_per_s=bma, bpa_per_s=bpa,
              phi0_rad=phi0, psi0_rad=float(psi0[0]), psi_frame0_rad=psi_f0, l_over_i=np.zeros(3), **common)
    # the roots' rounding scales with sin^2 of the launch tilt (every coefficient but the cubic's does)
    if spread <= 1e-14 * s2:
        return LagrangeTopSolution(kind="steady", u1=u0, u2=u0, u3=u3, one_minus_u1=one_minus, one_plus_u1=one_plus,
                                   spread=0.0, u1_minus_u0=0.0, modulus_m=0.0, lam_per_s=0.0, tau0=0.0,
                                   pole_north=False, pole_south=False, **kw)
    m = min(max(spread / (x3 - x1), 0.0), 1.0)
    lam = 0.5 * math.sqrt(beta * (x3 - x1))
    # through a pole: b -+ a = 0 and the turning tilt on the pole, both to rounding (of the tilts' own size)
    one_minus_u1, one_plus_u1 = one_minus - x1, one_plus + x1
    one_plus_u2 = one_plus + x2
    pole_north = (abs(bma) <= 1e-13 * max(abs(a) * one_minus_u1, abs(wz), 1e-300)
                  and one_minus - x2 <= 1e-12 * one_minus_u1)
    pole_south = (abs(bpa) <= 1e-13 * max(abs(a) * one_plus_u2, abs(wz), 1e-300)
                  and one_plus_u1 <= 1e-12 * one_plus_u2)
    if pole_north:
        u2 = 1.0
        spread = one_minus_u1
    x1_shift = x1
    if pole_south:
        u1, one_minus_u1, one_plus_u1 = -1.0, 2.0, 0.0
        x1_shift = -one_plus
        spread = x2 - x1_shift
    if at_pole and (pole_north or pole_south):
        tau0 = -float(ellipk(m)) if pole_north else 0.0  # the tip leaves the north pole along +theta
    else:
        tau0 = _launch_phase(x1, x2, m, udot0)
    return LagrangeTopSolution(kind="nutating", u1=u1, u2=u2, u3=u3, one_minus_u1=one_minus_u1,
                               one_plus_u1=one_plus_u1, spread=spread, u1_minus_u0=x1_shift, modulus_m=m, lam_per_s=lam,
                               tau0=tau0,
                               pole_north=pole_north, pole_south=pole_south, **kw)
