"""Singularity-free simulation of a symmetric top (or gyrostat) on a pivot.

State
-----
The orientation is a unit quaternion of a *reference frame* whose third axis is
the symmetry axis, so nothing is singular at tilt 0 or pi.  Two reference frames
are available ("formulations"):

``axis``  (gyrorig's own method, ``method="gyro"``: compiled DOP853, see ``_jit.py``;
         ``"gyro-scipy"``: the same equations on scipy's DOP853)
    A frame that follows the axis but does not turn about it (axial rate 0).  The
    fast spin never enters the orientation; the rotor angle relative to the frame
    is integrated as a separate scalar, ``chi' = omega_o``.  Steps are set by the
    nutation and precession, not by the spin period.
``body``  (the textbook choice, used with the plain scipy methods)
    The spinning rotor's own frame: quaternion plus Euler's equations.  Steps must
    resolve the spin period.

With the reference frame turning at axial rate ``rho`` (0 or ``omega_o``) and
``L3 = Io omega_o + I_f omega_f`` (``I_f omega_f`` only for a gyrostat), Euler's
equations for the transverse rates ``W = w1 + j w2`` read

    I dW/dt = T1 + j T2 + j (L3 - rho I) W,

which for ``rho = omega_o`` is the paper's eq. (5): ``dW/dt + j nu W = Gamma / I``.
The axial equations are ``Io d(omega_o)/dt = T_rotor`` and, for a gyrostat,
``I_f d(omega_f)/dt = T_frame``.

State vector: ``[q0, q1, q2, q3, w1, w2, omega_o, chi]`` plus ``[omega_f, chi_f]``
for a gyrostat (``chi``, ``chi_f``: rotor and frame angles about the axis relative
to the reference frame).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from .._methods import METHODS
from ..gimbals import refuse_gimbal
from ..protocols import EddyFieldDamping, Protocol
from .rotations import unwrapped_angles_from_tip, euler_from_matrix, euler_to_matrix, matrix_to_quaternion, quaternion_to_matrix
from ._jit import STATUS_MESSAGES, integrate_dop853, pack_torques
from .phasor import PhasorSingularity, make_phasor_rhs, phasor_initial_state, phasor_states_to_arrays
from .torques import sum_torques, torques_for

logger = logging.getLogger(__name__)

__all__ = [
    "make_rhs",
    "output_times",
    "SimulationError",
    "SimulationInfo",
    "METHODS",
    "TRAJECTORY_COLUMNS",
    "simulate",
    "choose_method",
    "initial_state",
]


#: default relative tolerance per solver
DEFAULT_RTOL = {"DOP853-jit": 1e-10, "DOP853": 1e-10, "RK45": 1e-8, "RK23": 1e-6, "Radau": 1e-8, "BDF": 1e-8, "LSODA": 1e-9}

#: columns of the trajectory DataFrame (gyrostats add ``psi_frame_rad, omega_frame_rad_s``)
TRAJECTORY_COLUMNS = (
    "t_s", "theta_rad", "phi_rad", "psi_rad", "tip_x", "tip_y", "tip_z",
    "omega_d_rad_s", "omega_q_rad_s", "omega_o_rad_s",
)

#: largest tolerated drift of |q| from 1 before a run is declared failed
QUATERNION_NORM_TOLERANCE = 1e-6


class SimulationError(RuntimeError):
    """The integration failed or produced an unusable result."""


@dataclass(frozen=True, slots=True)
class SimulationInfo:
    """How a trajectory was computed (written to ``manifest.json``).

    Attributes
    ----------
    method, formulation, solver : str
    rtol, atol : float
    n_rhs_evaluations : int
    wall_time_s : float
    quaternion_norm_drift : float
        Largest ``| |q| - 1 |`` over the output samples.
    """

    method: str
    formulation: str
    solver: str
    rtol: float
    atol: float
    n_rhs_evaluations: int
    wall_time_s: float
    quaternion_norm_drift: float


def choose_method(protocol: Protocol) -> str:
    """Pick a method for the scene: ``gyro`` unless damping makes the problem stiff.

    The problem is called stiff when the fastest damping rate exceeds 20 times the
    fastest oscillation of the undamped motion (nutation ``L3/I``, pendulum
    ``sqrt(Mgh/I)``, launch rates); then the implicit ``gyro-radau`` is used.
    """
    rig, launch = protocol.rig, protocol.launch
    i_t = rig.inertia_transverse_kg_m2
    damping_rates = [0.0]
    for d in protocol.pivot.damping:
        c = d.coefficient(i_t)
        damping_rates.append(c / i_t)
        if isinstance(d, EddyFieldDamping) and rig.is_gyrostat:
            damping_rates.append(c / (rig.frame_axial_inertia_kg_m2 or math.inf))
        axial = getattr(d, "axial_coefficient_N_m_s", 0.0)
        if axial and not getattr(d, "spin_compensated", True):
            damping_rates.append(axial / rig.inertia_axial_kg_m2)
    accel = 0.0
    if protocol.pivot.acceleration is not None:
        accel = max(math.sqrt(sum(a * a for a in row)) for row in protocol.pivot.acceleration.acceleration_m_s2)
    spin_l3 = abs(rig.inertia_axial_kg_m2 * launch.spin_rate_rad_s)
    oscill = max(
        spin_l3 / i_t,
        math.sqrt(rig.mass_kg * ((rig.gravity_m_s2 or 0.0) + accel) * rig.com_distance_m / i_t),
        abs(launch.precession_rate_rad_s),
        abs(launch.tilt_rate_rad_s),
        1.0 / protocol.scene.duration_s,
    )
    return "gyro-radau" if max(damping_rates) > 20.0 * oscill else "gyro"


def initial_state(protocol: Protocol, formulation: str) -> NDArray[np.float64]:
    """State vector at t = 0 for a formulation (``"axis"`` or ``"body"``)."""
    lau, rig = protocol.launch, protocol.rig
    th, ph, ps = lau.tilt_rad, lau.azimuth_rad, lau.spin_angle_rad
    abc = euler_to_matrix(ph, th, 0.0)  # columns: line of nodes a, b, symmetry axis c
    a_hat, c_hat = abc[:, 0], abc[:, 2]
    z_hat = np.array([0.0, 0.0, 1.0])
    w_lab = lau.tilt_rate_rad_s * a_hat + lau.precession_rate_rad_s * z_hat + lau.spin_rate_rad_s * c_hat
    omega_o = float(w_lab @ c_hat)
    if formulation == "axis":
        ref, chi = abc, ps
    elif formulation == "body":
        ref, chi = euler_to_matrix(ph, th, ps), 0.0
    else:
        raise ValueError(f"formulation must be 'axis' or 'body', got {formulation!r}")
    w_ref = ref.T @ w_lab
    state = [*matrix_to_quaternion(ref), w_ref[0], w_ref[1], omega_o, chi]
    if rig.is_gyrostat:
        omega_f = lau.frame_spin_rate_rad_s + lau.precession_rate_rad_s * math.cos(th)
        chi_f = -ps if formulation == "body" else 0.0  # frame's own psi is 0 at launch
        state += [omega_f, chi_f]
    return np.asarray(state, dtype=float)


def make_rhs(protocol: Protocol, formulation: str) -> Any:
    """The right-hand side ``f(t, y)`` of the ``"axis"`` or ``"body"`` formulation in Python: the reference
    for the compiled one (:mod:`gyrorig.physics._jit`) and the scipy methods' right-hand side."""
    rig = protocol.rig
    torques = torques_for(protocol)
    comps = [t.components for t in torques]
    i_t = rig.inertia_transverse_kg_m2
    i_o = rig.inertia_axial_kg_m2
    i_f = rig.frame_axial_inertia_kg_m2
    body = formulation == "body"
    gyrostat = i_f is not None

    def rhs(t: float, y: NDArray[np.float64]) -> list[float]:
        q0, q1, q2, q3, w1, w2, om = y[0], y[1], y[2], y[3], y[4], y[5], y[6]
        om_f = y[8] if gyrostat else None
        rho = om if body else 0.0
        n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
        s = 2.0 / n2
        # columns of the rotation matrix of the (normalised) quaternion
        e1 = (1.0 - s * (q2 * q2 + q3 * q3), s * (q1 * q2 + q0 * q3), s * (q1 * q3 - q0 * q2))
        e2 = (s * (q1 * q2 - q0 * q3), 1.0 - s * (q1 * q1 + q3 * q3), s * (q2 * q3 + q0 * q1))
        e3 = (s * (q1 * q3 + q0 * q2), s * (q2 * q3 - q0 * q1), 1.0 - s * (q1 * q1 + q2 * q2))
        t1, t2, tr, tf = sum_torques(comps, t, e1, e2, e3, w1, w2, om, om_f)
        l3 = i_o * om + (i_f * om_f if gyrostat else 0.0)
        k = l3 - rho * i_t
        # quaternion kinematics q' = q (x) (0, w1, w2, rho) / 2
        out = [
            0.5 * (-q1 * w1 - q2 * w2 - q3 * rho),
            0.5 * (q0 * w1 + q2 * rho - q3 * w2),
            0.5 * (q0 * w2 + q3 * w1 - q1 * rho),
            0.5 * (q0 * rho + q1 * w2 - q2 * w1),
            (t1 - k * w2) / i_t,
            (t2 + k * w1) / i_t,
            tr / i_o,
            om - rho,
        ]
        if gyrostat:
            out += [tf / i_f, om_f - rho]
        return out

    return rhs


def _scipy_segments(rhs: Any, solver: str, rtol: float, atol: float, method: str) -> Any:
    """``run(y, lo, hi, t_out) -> (states at t_out, state at hi, rhs calls)`` with scipy's ``solve_ivp``."""

    def run(y, lo, hi, t_out):
        # always end the segment exactly at its breakpoint, to restart from there
        te = t_out if len(t_out) and t_out[-1] == hi else np.append(t_out, hi)
        sol = solve_ivp(rhs, (lo, hi), y, method=solver, t_eval=te, rtol=rtol, atol=atol)
        if not sol.success:
            t_fail = sol.t[-1] if len(sol.t) else lo
            raise SimulationError(f"{method} failed at t = {t_fail:.6g} s: {sol.message}")
        if not np.all(np.isfinite(sol.y)):
            raise SimulationError(f"{method} produced non-finite values")
        return sol.y[:, : len(t_out)].T, sol.y[:, -1], int(sol.nfev)

    return run


def _jit_segments(protocol: Protocol, formulation: str, rtol: float, atol: float, method: str) -> Any:
    """The same interface as :func:`_scipy_segments`, with the compiled DOP853 (``_jit.py``)."""
    rig = protocol.rig
    packed = pack_torques(torques_for(protocol), inertia_transverse=rig.inertia_transverse_kg_m2,
                          inertia_axial=rig.inertia_axial_kg_m2, frame_axial=rig.frame_axial_inertia_kg_m2,
                          body_frame=formulation == "body")

    def run(y, lo, hi, t_out):
        out, y_end, n_calls, status, t_reached = integrate_dop853(packed, y, lo, hi, t_out, rtol, atol)
        if status != 0:
            raise SimulationError(f"{method} failed at t = {t_reached:.6g} s: {STATUS_MESSAGES[status]}")
        return out, y_end, n_calls

    return run


def _integrate(run: Any, y: NDArray[np.float64], t_eval: NDArray[np.float64], bounds: list[float],
               states: NDArray[np.float64]) -> int:
    """Integrate segment by segment (restarting at breakpoints), filling ``states``; returns rhs calls."""
    nfev = 0
    for lo, hi in zip(bounds, bounds[1:]):
        sel = (t_eval > lo) & (t_eval <= hi)
        states[sel], y, n_calls = run(y, lo, hi, t_eval[sel])
        nfev += n_calls
    return nfev


def _segments(protocol: Protocol, t_end: float) -> list[float]:
    """Integration breakpoints: start, knots of an acceleration table, end."""
    bounds = [0.0, t_end]
    acc = protocol.pivot.acceleration
    if acc is not None and not acc.is_constant:
        bounds += [t for t in acc.t_s if 0.0 < t < t_end]
    return sorted(set(bounds))


#: the most rows a simulation writes (a trajectory of 1e8 rows is already 10 GB of CSV)
MAX_OUTPUT_ROWS = 1e8


def output_times(protocol: Protocol, duration_s: float | None, rate_hz: float | None,
                 t_eval_s: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """The output times of :func:`simulate`: ``t_eval_s``, or a grid at ``rate_hz`` up to ``duration_s``
    (protocol defaults), ending exactly at the duration."""
    if t_eval_s is not None:
        t_eval = np.asarray(t_eval_s, dtype=float)
        if t_eval.ndim != 1 or len(t_eval) == 0 or t_eval[0] < 0 or np.any(np.diff(t_eval) <= 0):
            raise ValueError("t_eval_s must be a non-empty, strictly increasing array of times >= 0")
        return t_eval
    t_end = protocol.scene.duration_s if duration_s is None else float(duration_s)
    rate = protocol.scene.output_rate_hz if rate_hz is None else float(rate_hz)
    if not (t_end > 0.0 and math.isfinite(t_end)):
        raise ValueError(f"duration_s = {t_end!r}: must be a finite number > 0")
    if not (rate > 0.0 and math.isfinite(rate)):
        raise ValueError(f"rate_hz = {rate!r}: must be a finite number > 0")
    if t_end * rate > MAX_OUTPUT_ROWS:
        raise ValueError(f"duration_s * rate_hz = {t_end:g} s * {rate:g} Hz = {t_end * rate:.3g} rows: at most "
                         f"{MAX_OUTPUT_ROWS:.0e} (a shorter run or a lower rate)")
    n = int(math.floor(t_end * rate + 1e-9)) + 1
    t_eval = np.arange(n) / rate
    if t_eval[-1] < t_end * (1 - 1e-12):
        t_eval = np.append(t_eval, t_end)
    return t_eval


def simulate(
    protocol: Protocol,
    *,
    method: str = "auto",
    rtol: float | None = None,
    atol: float | None = None,
    duration_s: float | None = None,
    rate_hz: float | None = None,
    t_eval_s: NDArray[np.float64] | None = None,
    return_info: bool = False,
) -> pd.DataFrame | tuple[pd.DataFrame, SimulationInfo]:
    """Integrate the protocol's scene.

    Parameters
    ----------
    protocol : Protocol
    method : str
        ``"auto"`` (see :func:`choose_method`); ``"gyro"`` (axis formulation, compiled
        DOP853), ``"gyro-scipy"`` (same on scipy's DOP853), ``"gyro-radau"`` (implicit
        Radau); ``"phasor"`` (the paper's eqs. 5 and 9, singular at the poles);
        ``"DOP853-jit"`` (compiled DOP853 on the body formulation); or a scipy
        ``solve_ivp`` method on the body formulation: ``"RK23", "RK45", "DOP853",
        "Radau", "BDF", "LSODA"``.
    rtol, atol : float, optional
        Tolerances (defaults per solver: :data:`DEFAULT_RTOL`; ``atol = rtol * 1e-2``).
    duration_s : float, optional
        Overrides ``protocol.scene.duration_s``. [s]
    rate_hz : float, optional
        Output sample rate; overrides ``protocol.scene.output_rate_hz``. [Hz]
    t_eval_s : ndarray, optional
        Explicit output times (overrides ``duration_s`` and ``rate_hz``). [s]
    return_info : bool
        Also return a :class:`SimulationInfo`.

    Returns
    -------
    DataFrame
        Columns :data:`TRAJECTORY_COLUMNS`: ``t_s`` [s]; ``theta_rad``, ``phi_rad``
        (unwrapped), ``psi_rad`` (unwrapped, of the rotor) [rad]; unit tip vector
        ``tip_x, tip_y, tip_z``; body rates ``omega_d_rad_s, omega_q_rad_s,
        omega_o_rad_s`` of the rotor in its own d-q-o axes [rad/s].  A gyrostat adds
        ``psi_frame_rad`` and ``omega_frame_rad_s`` (the frame's axial rate).
    SimulationInfo
        Only with ``return_info=True``.

    Raises
    ------
    ValueError
        Unknown method or bad tolerances/times.
    SimulationError
        The solver failed or the quaternion norm drifted beyond
        :data:`QUATERNION_NORM_TOLERANCE`.
    """
    refuse_gimbal(protocol, "the rigid-body simulator")
    if method == "auto":
        method = choose_method(protocol)
    if method not in METHODS:
        raise ValueError(f"method = {method!r}: allowed 'auto', {', '.join(repr(m) for m in METHODS)}")
    formulation, solver = METHODS[method]
    rtol = DEFAULT_RTOL[solver] if rtol is None else float(rtol)
    atol = rtol * 1e-2 if atol is None else float(atol)
    if not (0.0 < rtol < 1.0) or not (atol > 0.0):
        raise ValueError(f"rtol = {rtol!r} must be in (0, 1) and atol = {atol!r} > 0")
    t_eval = output_times(protocol, duration_s, rate_hz, t_eval_s)
    t_end = float(t_eval[-1])
    if formulation == "phasor":
        y = phasor_initial_state(protocol)
        run = _scipy_segments(make_phasor_rhs(protocol), solver, rtol, atol, method)
    else:
        y = initial_state(protocol, formulation)
        run = _jit_segments(protocol, formulation, rtol, atol, method) if solver == "DOP853-jit" else \
            _scipy_segments(make_rhs(protocol, formulation), solver, rtol, atol, method)
    states = np.empty((len(t_eval), len(y)))
    start = time.perf_counter()
    states[t_eval == 0.0] = y
    try:
        # a diverging solution overflows: report it as a failed run instead of warnings and NaN
        with np.errstate(over="raise", invalid="raise", divide="raise"):
            nfev = _integrate(run, y, t_eval, _segments(protocol, t_end), states)
    except FloatingPointError as exc:
        raise SimulationError(f"{method}: the solution diverged ({exc}); tighten rtol or choose another method") \
            from None
    except PhasorSingularity as exc:
        raise SimulationError(f"phasor formulation is singular at the poles (eq. 9 divides by sin theta): {exc}; "
                              "use method 'gyro'") from None
    wall = time.perf_counter() - start
    if formulation == "phasor":
        df = _phasor_frame(protocol, t_eval, states)
        info = SimulationInfo(method, formulation, solver, rtol, atol, nfev, wall, 0.0)
        return (df, info) if return_info else df
    drift = float(np.max(np.abs(np.linalg.norm(states[:, :4], axis=1) - 1.0)))
    if drift > QUATERNION_NORM_TOLERANCE:
        raise SimulationError(
            f"{method}: quaternion norm drifted by {drift:.3g} (> {QUATERNION_NORM_TOLERANCE:g}); "
            "tighten rtol or choose another method"
        )
    df = states_to_frame(protocol, t_eval, states)
    info = SimulationInfo(method, formulation, solver, rtol, atol, nfev, wall, drift)
    logger.info("simulated %s with %s in %.3f s (%d rhs calls)", protocol.name, method, wall, nfev)
    return (df, info) if return_info else df


def states_to_frame(protocol: Protocol, t_s: NDArray[np.float64], states: NDArray[np.float64]) -> pd.DataFrame:
    """Convert raw state rows (see the module docstring) to the trajectory DataFrame."""
    ref = quaternion_to_matrix(states[:, :4])
    chi = states[:, 7]
    wb = (states[:, 4] + 1j * states[:, 5]) * np.exp(-1j * chi)
    frame = None
    if states.shape[1] > 8:
        frame = (ref @ rot_z(states[:, 9]), states[:, 8])
    return trajectory_frame(
        protocol, t_s, ref @ rot_z(chi), np.column_stack([wb.real, wb.imag, states[:, 6]]), frame=frame
    )


def trajectory_frame(
    protocol: Protocol,
    t_s: NDArray[np.float64],
    rotor_to_lab: NDArray[np.float64],
    body_rates_rad_s: NDArray[np.float64],
    *,
    frame: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> pd.DataFrame:
    """Build the documented trajectory DataFrame from rotor orientations and body rates.

    Parameters
    ----------
    protocol : Protocol
        Supplies the launch azimuth and spin angle (branch choice at the poles).
    t_s : ndarray, shape (n,)
    rotor_to_lab : ndarray, shape (n, 3, 3)
        Body-to-lab matrices of the spinning rotor.
    body_rates_rad_s : ndarray, shape (n, 3)
        ``omega_d, omega_q, omega_o`` in the rotor's axes. [rad/s]
    frame : (ndarray (n, 3, 3), ndarray (n,)), optional
        Gyrostat frame orientations and axial rates.
    """
    tip = rotor_to_lab[:, :, 2]
    theta, phi = unwrapped_angles_from_tip(tip, phi_at_pole_rad=protocol.launch.azimuth_rad)
    _, _, psi = euler_from_matrix(rotor_to_lab, phi_hint_rad=phi)
    data: dict[str, Any] = {
        "t_s": t_s,
        "theta_rad": theta,
        "phi_rad": phi,
        "psi_rad": _unwrap_near(psi, protocol.launch.spin_angle_rad),
        "tip_x": tip[:, 0],
        "tip_y": tip[:, 1],
        "tip_z": tip[:, 2],
        "omega_d_rad_s": body_rates_rad_s[:, 0],
        "omega_q_rad_s": body_rates_rad_s[:, 1],
        "omega_o_rad_s": body_rates_rad_s[:, 2],
    }
    if frame is not None:
        _, _, psi_f = euler_from_matrix(frame[0], phi_hint_rad=phi)
        data["psi_frame_rad"] = _unwrap_near(psi_f, 0.0)
        data["omega_frame_rad_s"] = frame[1]
    return pd.DataFrame(data)


def _phasor_frame(protocol: Protocol, t_s: NDArray[np.float64], states: NDArray[np.float64]) -> pd.DataFrame:
    a = phasor_states_to_arrays(states)
    rotor = euler_to_matrix(a["phi"], a["theta"], a["psi"])
    frame = None
    if "omega_f" in a:
        frame = (euler_to_matrix(a["phi"], a["theta"], a["psi_f"]), a["omega_f"])
    return trajectory_frame(protocol, t_s, rotor, a["rates"], frame=frame)


def rot_z(angle: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices about z by each angle; shape (n, 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros((len(angle), 3, 3))
    m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1], m[:, 2, 2] = c, -s, s, c, 1.0
    return m


def _unwrap_near(angle: NDArray[np.float64], reference: float) -> NDArray[np.float64]:
    out = np.unwrap(angle)
    if len(out):
        out = out + 2 * np.pi * np.round((reference - out[0]) / (2 * np.pi))
    return out
