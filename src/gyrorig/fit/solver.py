"""Least-squares solution of a fit model, and the start values that get it there.

Levenberg-Marquardt (scipy, analytic Jacobian) with a modest budget, then undamped
Gauss-Newton steps, repeated (up to 4 rounds) until one more Gauss-Newton step would move no
parameter by :data:`STATIONARY_STEP_SE` standard errors, or a whole round lowers the
chi-square by less than :data:`STALLED_CHI2_GAIN` (where a term's amplitude is ~0 its rate is
free, the model is not quadratic and the step points nowhere useful); after the last round a
step below :data:`ACCEPTABLE_STEP_SE` is accepted.  In the damped models exponentials and
sinusoids of nearby rates make Levenberg-Marquardt crawl along a curved valley; Gauss-Newton
gets to the minimum in a few steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from ..geometry import angles_from_tip, axis_rotation, tip_from_angles, wrap_angle
from .data import FitData, FitError
from .model import FitModel, Residuals
from .spec import ModelSpec

__all__ = ["Solution", "solve", "gauss_newton_polish", "remaining_step_se", "conditional_amplitudes", "linear_start",
           "plane_axis", "dominant_frequency", "linear_harmonics", "mean_axis"]

#: Levenberg-Marquardt tolerances (xtol, ftol, gtol); undamped Gauss-Newton steps finish the job
LM_TOL = 1e-9
#: a solution counts as converged when a further Gauss-Newton step would move no parameter by
#: more than this many standard errors
STATIONARY_STEP_SE = 1e-3
#: when the rounds run out, a solution this close (standard errors) still counts as converged
ACCEPTABLE_STEP_SE = 1e-2
#: ... or when a further round of Levenberg-Marquardt and Gauss-Newton lowers the chi-square by
#: less than this
STALLED_CHI2_GAIN = 1e-6


@dataclass
class Solution:
    """A least-squares solution of one model: parameters, their covariance ``(J^T J)^-1``, chi-square."""

    spec: ModelSpec
    x: np.ndarray
    cov: np.ndarray
    chi2: float
    dof: int
    ok: bool
    message: str

    @property
    def model(self) -> FitModel:
        return FitModel(self.spec)

    def values(self) -> dict[str, float]:
        """The parameters by name."""
        return dict(zip(self.spec.names(), self.x))


def _covariance(J: np.ndarray, fixed=()) -> np.ndarray:
    """``(J^T J)^-1`` (pseudo-inverse); exactly zero in the rows and columns of fixed parameters."""
    cov = np.linalg.pinv(J.T @ J, rcond=1e-14, hermitian=True)
    idx = list(fixed)
    cov[idx, :] = 0.0
    cov[:, idx] = 0.0
    return cov


def solve(spec: ModelSpec, data: FitData, start: dict[str, float], *, near: bool = False) -> Solution:
    """Least-squares fit of ``spec`` from ``start``.

    ``near``: the start is a converged model plus a new term's amplitudes at their conditional
    least-squares values (a trial term): Gauss-Newton is tried first, and Levenberg-Marquardt
    only if it does not reach a stationary point (from such a start LM can spend thousands of
    evaluations creeping to where a few Gauss-Newton steps go).
    """
    model = FitModel(spec)
    white = Residuals(model, data)
    x0 = white.start(model.vector(start))
    n_res = white.informative_size  # the frames, the camera modes' priors (as much as they hold) and the user's
    n_free = white.free
    if n_res <= n_free:
        raise FitError(f"{data.n} frames are too few for a model with {n_free} free parameters")
    if near:
        with np.errstate(over="ignore", invalid="ignore"):
            r0 = white(x0)
        if np.all(np.isfinite(r0)):
            x, r, J = gauss_newton_polish(white, x0, r0, white.jac(x0), max_steps=60)
            if remaining_step_se(J, r) < STATIONARY_STEP_SE and np.all(np.isfinite(x)):
                return Solution(spec, x, _covariance(J, white.fixed), float(r @ r), n_res - n_free, True,
                                "Gauss-Newton from a near start")
            x0 = x
    x = x0
    chi2_prev = math.inf
    for _round in range(4):
        # a trial step may send the damped model's exponentials beyond the floats: infinite residuals, a step refused
        with np.errstate(over="ignore", invalid="ignore"):
            res = least_squares(white, x, jac=white.jac, method="lm", x_scale="jac", xtol=LM_TOL, ftol=LM_TOL,
                                gtol=LM_TOL, max_nfev=50 * (len(x0) + 1))
            x, r, J = gauss_newton_polish(white, res.x, res.fun, res.jac)
        chi2_now = float(r @ r)
        stationary = (remaining_step_se(J, r) < STATIONARY_STEP_SE
                      or chi2_prev - chi2_now < STALLED_CHI2_GAIN)
        if stationary:
            break
        chi2_prev = chi2_now
    if not stationary:
        # the rounds ran out while still creeping: accept a solution within ACCEPTABLE_STEP_SE of the minimum
        stationary = remaining_step_se(J, r) < ACCEPTABLE_STEP_SE
    ok = bool(stationary and np.all(np.isfinite(x)))
    if ok:
        message = res.message
    else:
        message = (f"no minimum after {_round + 1} rounds of Levenberg-Marquardt and Gauss-Newton (one more step "
                   f"would move a parameter by {remaining_step_se(J, r):.3g} standard errors; the chi-square still "
                   "falls slowly): the parameters are nearly degenerate over this record")
    try:
        cov = _covariance(J, white.fixed)
    except np.linalg.LinAlgError:
        cov = np.full((len(x0), len(x0)), np.nan)
    return Solution(spec, x, cov, float(np.sum(r**2)), n_res - n_free, ok, message)


def remaining_step_se(J: np.ndarray, r: np.ndarray) -> float:
    """The largest move, in standard errors, that one more Gauss-Newton step would make (0 at a minimum).

    Scale-free, and meaningful when the residuals are tiny (noiseless planning data), where the
    angle between the residuals and the Jacobian's columns is set by rounding."""
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms
    step, *_ = np.linalg.lstsq(Js, -r, rcond=1e-13)
    cov_s = np.linalg.pinv(Js.T @ Js, rcond=1e-14, hermitian=True)
    se = np.sqrt(np.maximum(np.diag(cov_s), 0.0))
    se[se == 0] = np.inf
    return float(np.max(np.abs(step) / se)) if np.all(np.isfinite(step)) else math.inf


def gauss_newton_polish(white: Residuals, x: np.ndarray, r: np.ndarray, J: np.ndarray, max_steps: int = 30
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Finish a least-squares minimisation with undamped Gauss-Newton steps.

    Each step is a column-scaled least-squares solve of ``J dx = -r``; a step that does not
    lower the chi-square is halved.  Stops when a step's predicted gain is below 1e-9 in
    chi-square.
    """
    c = float(r @ r)
    for _ in range(max_steps):
        norms = np.linalg.norm(J, axis=0)
        norms[norms == 0] = 1.0
        step, *_ = np.linalg.lstsq(J / norms, -r, rcond=1e-13)
        dx = step / norms
        gain = float(np.sum(((J / norms) @ step) ** 2))
        if not np.all(np.isfinite(dx)) or gain < 1e-9:
            break
        for _half in range(12):
            x_new = x + dx
            with np.errstate(over="ignore", invalid="ignore"):  # a trial step can overflow: it is then halved
                r_new = white(x_new)
                c_new = float(r_new @ r_new)
            if np.isfinite(c_new) and c_new < c:
                break
            dx = 0.5 * dx
        else:
            break
        done = c - c_new < 1e-12 * c
        x, r, c = x_new, r_new, c_new
        J = white.jac(x)
        if done:
            break
    return x, r, J


def conditional_amplitudes(spec: ModelSpec, data: FitData, start: dict[str, float], names: list[str]
                           ) -> tuple[dict[str, float], float]:
    """Start values for parameters the model is linear in (the amplitudes of a new term): their
    least-squares values with every other parameter held at ``start`` (one Gauss-Newton step
    in those parameters alone).  Returns the start and its chi-square."""
    model = FitModel(spec)
    white = Residuals(model, data)
    x0 = white.start(model.vector(start))
    cols = [model.index[n] for n in names if model.index[n] not in white.fixed]
    r = white(x0)
    J = white.jac(x0)[:, cols]
    step, *_ = np.linalg.lstsq(J, -r, rcond=None)
    x0[cols] += step
    return model.values(x0), float(np.sum(white(x0) ** 2))


def mean_axis(data: FitData) -> tuple[float, float]:
    """Tilt and azimuth of the mean tip direction (a start for a fitted axis). [rad]"""
    m = tip_from_angles(data.theta_rad, data.phi_rad).mean(axis=0)
    m /= np.linalg.norm(m)
    th_a, ph_a = angles_from_tip(m)
    return float(th_a), float(ph_a)


def plane_axis(data: FitData) -> tuple[float, float]:
    """Tilt and azimuth of the axis of the circle the tip's directions trace: the normal of the plane nearest them
    (least squares), on the upper side (a hanging top's cone turns about the upward vertical too). [rad]"""
    tips = tip_from_angles(data.theta_rad, data.phi_rad)
    _, vectors = np.linalg.eigh(np.cov(tips.T))
    n = vectors[:, 0] if vectors[2, 0] >= 0 else -vectors[:, 0]
    th_a, ph_a = angles_from_tip(n)
    return float(th_a), float(ph_a)


def linear_start(spec: ModelSpec, data: FitData, axis: tuple[float, float] | None) -> dict[str, float]:
    """Start values of the slow model by linear least squares: the unwrapped azimuth's slope (and
    curvature) with per-segment offsets, and the log tilt's mean (and slope)."""
    tau = data.tau
    if axis is not None:
        th, ph = angles_from_tip(tip_from_angles(data.theta_rad, data.phi_rad) @ axis_rotation(*axis))
    else:
        th, ph = data.theta_rad, data.phi_rad
    start: dict[str, float] = {}
    if axis is not None:
        start["axis_tilt_rad"], start["axis_azimuth_rad"] = axis
    cols = [tau] + ([0.5 * tau**2] if spec.damped else [])
    seg_cols = [(data.segment == s).astype(float) for s in range(spec.segments)]
    phu = np.empty_like(ph)
    for s in range(spec.segments):
        m = data.segment == s
        phu[m] = np.unwrap(ph[m])
    A = np.column_stack(cols + seg_cols)
    coef, *_ = np.linalg.lstsq(A, phu, rcond=None)
    start["precession_rate_rad_s"] = coef[0]
    if spec.damped:
        start["precession_acceleration_rad_s2"] = coef[1]
    for s in range(spec.segments):
        start[f"azimuth_offset_{s}_rad"] = coef[len(cols) + s]
    B = np.column_stack([np.ones_like(tau)] + ([tau] if spec.damped else []))
    cth, *_ = np.linalg.lstsq(B, np.log(np.maximum(th, 1e-9)), rcond=None)
    start["log_cone_angle"] = cth[0]
    if spec.damped:
        start["tilt_growth_rate_per_s"] = cth[1]
    return start


def dominant_frequency(t: np.ndarray, y: np.ndarray, w_max: float, hint: float | None, *,
                       window: bool = True) -> float:
    """Peak of the periodogram of y (resampled on a uniform grid), refined by interpolation. [rad/s]

    ``window``: a Hann window against leakage, for a motion that lasts the record; not for one that dies out
    (a damped nod at the record's start, which the window would take away)."""
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1], dt)
    yy = np.interp(grid, t, y)
    yy = (yy - yy.mean()) * (np.hanning(len(yy)) if window else 1.0)
    nfft = 1 << int(math.ceil(math.log2(len(yy) * 8)))
    spec = np.abs(np.fft.rfft(yy, nfft))
    w = 2 * np.pi * np.fft.rfftfreq(nfft, dt)
    lo = 2 * np.pi * 1.5 / (t[-1] - t[0])
    sel = (w > lo) & (w < w_max)
    if not sel.any():
        return hint or lo
    i = np.flatnonzero(sel)[np.argmax(spec[sel])]
    if 0 < i < len(spec) - 1:
        a, b, c = np.log(spec[i - 1:i + 2] + 1e-300)
        den = a - 2 * b + c
        shift = 0.5 * (a - c) / den if den != 0 else 0.0
        return float(w[i] + shift * (w[1] - w[0]))
    return float(w[i])


def linear_harmonics(spec: ModelSpec, data: FitData, start: dict[str, float]) -> dict[str, float]:
    """Given the nonlinear parameters, the harmonic amplitudes by linear least squares."""
    model = FitModel(replace(spec, harmonics=0))
    p = model.vector(start)
    tau = data.tau
    th0, ph0 = model.axis_frame(p, tau, data.segment)
    th, ph = model.in_axis_frame(p, data)
    rth, rph = th - th0, wrap_angle(ph - ph0)
    w = start["nutation_frequency_rad_s"]
    env = np.exp(-start.get("nutation_decay_rate_per_s", 0.0) * (tau - spec.nutation_origin_s))
    cols = []
    for k in range(1, spec.harmonics + 1):
        cols += [env * np.cos(k * w * tau), env * np.sin(k * w * tau)]
    A = np.column_stack(cols)
    at, *_ = np.linalg.lstsq(A, rth, rcond=None)
    ap, *_ = np.linalg.lstsq(A, rph, rcond=None)
    out = dict(start)
    for k in range(1, spec.harmonics + 1):
        out[f"tilt_cos_{k}_rad"], out[f"tilt_sin_{k}_rad"] = at[2 * k - 2], at[2 * k - 1]
        out[f"azimuth_cos_{k}_rad"], out[f"azimuth_sin_{k}_rad"] = ap[2 * k - 2], ap[2 * k - 1]
    return out
