"""Compiled (numba) DOP853 integrator for the simulator's equations of motion.

Why numba: the equations are 8-10 scalars and a step costs ~100 floating-point
operations, so an integrator whose step loop runs in Python spends >95 % of its time
in interpreter overhead (~15 us per right-hand-side call).  Compiling the loop and
the right-hand side together makes a step cost well under a microsecond.

The algorithm is scipy's DOP853 (Hairer, Norsett & Wanner, *Solving ODEs I*,
sec. II.10) ported line by line: same coefficients (read from scipy), same error
norm, same step-size control and initial step, and the same 7th-order dense output
for the requested output times.  The right-hand side mirrors ``simulate.make_rhs``
(the reference implementation, tested to agree on random states); the torques are
packed into arrays by :func:`pack_torques`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from . import _dop853_tableau as _dop
from .torques import EddyFieldTorque, GravityTorque, TransverseViscousTorque

__all__ = ["pack_torques", "integrate_dop853", "rhs_reference_check", "STATUS_MESSAGES"]

_A = np.ascontiguousarray(_dop.A, dtype=np.float64)
_B = np.ascontiguousarray(_dop.B, dtype=np.float64)
_C = np.ascontiguousarray(_dop.C, dtype=np.float64)
_E3 = np.ascontiguousarray(_dop.E3, dtype=np.float64)
_E5 = np.ascontiguousarray(_dop.E5, dtype=np.float64)
_D = np.ascontiguousarray(_dop.D, dtype=np.float64)
_N_STAGES = int(_dop.N_STAGES)
_N_EXT = int(_dop.N_STAGES_EXTENDED)

STATUS_MESSAGES = {
    0: "ok",
    1: "required step size fell below the spacing of floating-point numbers",
    2: "maximum number of steps exceeded",
    3: "the solution became non-finite (diverged)",
}

# parameter vector layout
_I_T, _I_O, _I_F, _MH, _G, _VISC, _VISC_AX_ROTOR, _VISC_AX_FRAME, _BODY = range(9)


def pack_torques(torques, *, inertia_transverse: float, inertia_axial: float, frame_axial: float | None,
                 body_frame: bool) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                            NDArray[np.float64]]:
    """Arrays describing the equations: ``(params, eddy, acc_t, acc_v)``.

    ``params``: inertias, gravity (``M h``, ``g``), summed transverse viscous coefficient
    and axial drags, formulation flag.  ``eddy``: one row ``(c, bx, by, bz, compensated)``
    per lab-field eddy torque.  ``acc_t, acc_v``: pivot-acceleration knots (empty: fixed).
    """
    p = np.zeros(9)
    p[_I_T], p[_I_O], p[_I_F] = inertia_transverse, inertia_axial, frame_axial or 0.0
    p[_BODY] = 1.0 if body_frame else 0.0
    eddy = []
    acc_t, acc_v = np.zeros(0), np.zeros((0, 3))
    for t in torques:
        if isinstance(t, GravityTorque):
            p[_MH], p[_G] = t.mass_kg * t.com_distance_m, t.gravity_m_s2
            if t.acceleration is not None:
                src = t.acceleration.__self__  # bound PivotAcceleration.at
                acc_t = np.asarray(src.t_s, dtype=float)
                acc_v = np.asarray(src.acceleration_m_s2, dtype=float).reshape(-1, 3)
        elif isinstance(t, TransverseViscousTorque):
            p[_VISC] += t.coefficient_N_m_s
            if t.spin_compensated:
                p[_VISC_AX_FRAME] += t.axial_coefficient_N_m_s
            else:
                p[_VISC_AX_ROTOR] += t.axial_coefficient_N_m_s
        elif isinstance(t, EddyFieldTorque):
            eddy.append([t.coefficient_N_m_s, *t.field_direction, 1.0 if t.spin_compensated else 0.0])
        else:  # pragma: no cover - torques_for builds no other kind
            raise TypeError(f"no compiled form for torque {t!r}")
    return p, np.asarray(eddy, dtype=float).reshape(-1, 5), acc_t, acc_v


@njit(cache=True)
def _rhs(t, y, out, p, eddy, acc_t, acc_v):
    q0, q1, q2, q3, w1, w2, om = y[0], y[1], y[2], y[3], y[4], y[5], y[6]
    i_t, i_o, i_f = p[0], p[1], p[2]
    gyro = i_f > 0.0
    om_f = y[8] if gyro else 0.0
    rho = om if p[8] > 0.0 else 0.0
    s = 2.0 / (q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    e1x, e1y, e1z = 1.0 - s * (q2 * q2 + q3 * q3), s * (q1 * q2 + q0 * q3), s * (q1 * q3 - q0 * q2)
    e2x, e2y, e2z = s * (q1 * q2 - q0 * q3), 1.0 - s * (q1 * q1 + q3 * q3), s * (q2 * q3 + q0 * q1)
    e3x, e3y, e3z = s * (q1 * q3 + q0 * q2), s * (q2 * q3 - q0 * q1), 1.0 - s * (q1 * q1 + q2 * q2)
    t1 = 0.0
    t2 = 0.0
    tr = 0.0
    tf = 0.0
    mh = p[3]
    if mh != 0.0:
        ax = 0.0
        ay = 0.0
        az = 0.0
        k = acc_t.shape[0]
        if k > 0:
            if t <= acc_t[0]:
                ax, ay, az = acc_v[0, 0], acc_v[0, 1], acc_v[0, 2]
            elif t >= acc_t[k - 1]:
                ax, ay, az = acc_v[k - 1, 0], acc_v[k - 1, 1], acc_v[k - 1, 2]
            else:
                j = 0
                while acc_t[j + 1] <= t:
                    j += 1
                f = (t - acc_t[j]) / (acc_t[j + 1] - acc_t[j])
                ax = acc_v[j, 0] + f * (acc_v[j + 1, 0] - acc_v[j, 0])
                ay = acc_v[j, 1] + f * (acc_v[j + 1, 1] - acc_v[j, 1])
                az = acc_v[j, 2] + f * (acc_v[j + 1, 2] - acc_v[j, 2])
        # F / M = g_vec - a_pivot; T = h e3 x F = (-h F.e2, h F.e1, 0)
        fx, fy, fz = -ax, -ay, -(p[4] + az)
        t1 += -mh * (fx * e2x + fy * e2y + fz * e2z)
        t2 += mh * (fx * e1x + fy * e1y + fz * e1z)
    c = p[5]
    t1 -= c * w1
    t2 -= c * w2
    tr -= p[6] * om
    if gyro:
        tf -= p[7] * om
    for r in range(eddy.shape[0]):
        ce, bx, by, bz = eddy[r, 0], eddy[r, 1], eddy[r, 2], eddy[r, 3]
        b1 = bx * e1x + by * e1y + bz * e1z
        b2 = bx * e2x + by * e2y + bz * e2z
        b3 = bx * e3x + by * e3y + bz * e3z
        w3 = om_f if gyro else om
        wb = w1 * b1 + w2 * b2 + w3 * b3
        t1 -= ce * (w1 - wb * b1)
        t2 -= ce * (w2 - wb * b2)
        t3 = -ce * (w3 - wb * b3)
        if gyro:
            tf += t3
        elif eddy[r, 4] == 0.0:
            tr += t3
    l3 = i_o * om + i_f * om_f
    kk = l3 - rho * i_t
    out[0] = 0.5 * (-q1 * w1 - q2 * w2 - q3 * rho)
    out[1] = 0.5 * (q0 * w1 + q2 * rho - q3 * w2)
    out[2] = 0.5 * (q0 * w2 + q3 * w1 - q1 * rho)
    out[3] = 0.5 * (q0 * rho + q1 * w2 - q2 * w1)
    out[4] = (t1 - kk * w2) / i_t
    out[5] = (t2 + kk * w1) / i_t
    out[6] = tr / i_o
    out[7] = om - rho
    if gyro:
        out[8] = tf / i_f
        out[9] = om_f - rho


@njit(cache=True)
def _norm(v, scale):
    acc = 0.0
    for i in range(v.shape[0]):
        x = v[i] / scale[i]
        acc += x * x
    return math.sqrt(acc / v.shape[0])


@njit(cache=True)
def _stages(s0, s1, t, y, h, K, tmp, A, C, p, eddy, acc_t, acc_v):
    """Runge-Kutta stages s0 .. s1-1: K[s] = f(t + C[s] h, y + h sum_j A[s, j] K[j])."""
    n = y.shape[0]
    for s in range(s0, s1):
        for i in range(n):
            acc = 0.0
            for j in range(s):
                acc += A[s, j] * K[j, i]
            tmp[i] = y[i] + h * acc
        _rhs(t + C[s] * h, tmp, K[s], p, eddy, acc_t, acc_v)


@njit(cache=True)
def _integrate(y0, t0, t1, t_eval, rtol, atol, p, eddy, acc_t, acc_v, A, B, C, E3, E5, D, n_stages, n_ext,
               max_steps, states):
    n = y0.shape[0]
    K = np.zeros((n_ext, n))
    y = y0.copy()
    f = np.empty(n)
    tmp = np.empty(n)
    y_new = np.empty(n)
    scale = np.empty(n)
    _rhs(t0, y, f, p, eddy, acc_t, acc_v)
    nfev = 1
    # initial step (scipy select_initial_step, order 8)
    for i in range(n):
        scale[i] = atol + abs(y[i]) * rtol
    d0 = _norm(y, scale)
    d1 = _norm(f, scale)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, t1 - t0)
    for i in range(n):
        tmp[i] = y[i] + h0 * f[i]
    _rhs(t0 + h0, tmp, K[1], p, eddy, acc_t, acc_v)
    nfev += 1
    for i in range(n):
        K[1, i] = (K[1, i] - f[i])
    d2 = _norm(K[1], scale) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / 9.0)
    h_abs = min(100 * h0, h1, t1 - t0)
    t = t0
    i_out = 0
    n_out = t_eval.shape[0]
    while i_out < n_out and t_eval[i_out] <= t0:
        for i in range(n):
            states[i_out, i] = y[i]
        i_out += 1
    F = np.zeros((7, n))
    steps = 0
    while t < t1:
        steps += 1
        if steps > max_steps:
            return nfev, 2, t
        min_step = 10.0 * abs(np.nextafter(t, np.inf) - t)
        if h_abs < min_step:
            h_abs = min_step
        rejected = False
        while True:
            if h_abs < min_step:
                return nfev, 1, t
            t_new = t + h_abs
            if t_new > t1:
                t_new = t1
            h = t_new - t
            h_abs = abs(h)
            for i in range(n):
                K[0, i] = f[i]
            _stages(1, n_stages, t, y, h, K, tmp, A, C, p, eddy, acc_t, acc_v)
            for i in range(n):
                acc = 0.0
                for j in range(n_stages):
                    acc += B[j] * K[j, i]
                y_new[i] = y[i] + h * acc
            _rhs(t + h, y_new, K[n_stages], p, eddy, acc_t, acc_v)
            nfev += n_stages
            finite = True
            for i in range(n):
                if not math.isfinite(y_new[i]) or not math.isfinite(K[n_stages, i]):
                    finite = False
            if not finite:
                return nfev, 3, t
            for i in range(n):
                scale[i] = atol + max(abs(y[i]), abs(y_new[i])) * rtol
            e5 = 0.0
            e3 = 0.0
            for i in range(n):
                a5 = 0.0
                a3 = 0.0
                for j in range(n_stages + 1):
                    a5 += E5[j] * K[j, i]
                    a3 += E3[j] * K[j, i]
                a5 /= scale[i]
                a3 /= scale[i]
                e5 += a5 * a5
                e3 += a3 * a3
            if e5 == 0.0 and e3 == 0.0:
                err = 0.0
            else:
                err = h_abs * e5 / math.sqrt((e5 + 0.01 * e3) * n)
            if err < 1.0:
                factor = 10.0 if err == 0.0 else min(10.0, 0.9 * err ** (-1.0 / 8.0))
                if rejected:
                    factor = min(1.0, factor)
                h_abs *= factor
                break
            h_abs *= max(0.2, 0.9 * err ** (-1.0 / 8.0))
            rejected = True
        # dense output for requested times in (t, t_new]
        if i_out < n_out and t_eval[i_out] <= t_new:
            _stages(n_stages + 1, n_ext, t, y, h, K, tmp, A, C, p, eddy, acc_t, acc_v)
            nfev += n_ext - n_stages - 1
            for i in range(n):
                dy = y_new[i] - y[i]
                F[0, i] = dy
                F[1, i] = h * K[0, i] - dy
                F[2, i] = 2.0 * dy - h * (K[n_stages, i] + K[0, i])
                for r in range(4):
                    acc = 0.0
                    for j in range(n_ext):
                        acc += D[r, j] * K[j, i]
                    F[3 + r, i] = h * acc
            while i_out < n_out and t_eval[i_out] <= t_new:
                x = (t_eval[i_out] - t) / h
                for i in range(n):
                    v = 0.0
                    for r in range(7):
                        v += F[6 - r, i]
                        v *= x if r % 2 == 0 else (1.0 - x)
                    states[i_out, i] = y[i] + v
                i_out += 1
        t = t_new
        for i in range(n):
            y[i] = y_new[i]
            f[i] = K[n_stages, i]
    for i in range(n):
        y0[i] = y[i]  # hand the end state back for the next segment
    return nfev, 0, t


def integrate_dop853(packed, y0: NDArray[np.float64], t0: float, t1: float, t_eval: NDArray[np.float64],
                     rtol: float, atol: float, max_steps: int = 50_000_000):
    """Integrate from ``t0`` to ``t1``; returns ``(states at t_eval, end state, nfev, status, t_reached)``."""
    p, eddy, acc_t, acc_v = packed
    y = np.array(y0, dtype=np.float64)
    states = np.empty((len(t_eval), len(y)))
    nfev, status, t_reached = _integrate(y, float(t0), float(t1), np.ascontiguousarray(t_eval, dtype=np.float64),
                                         float(rtol), float(atol), p, eddy, acc_t, acc_v, _A, _B, _C, _E3, _E5, _D,
                                         _N_STAGES, _N_EXT, max_steps, states)
    return states, y, int(nfev), int(status), float(t_reached)


def rhs_reference_check(packed, t: float, y: NDArray[np.float64]) -> NDArray[np.float64]:
    """The compiled right-hand side at one state (for tests against the Python one)."""
    p, eddy, acc_t, acc_v = packed
    out = np.empty(len(y))
    _rhs(float(t), np.asarray(y, dtype=np.float64), out, p, eddy, acc_t, acc_v)
    return out
