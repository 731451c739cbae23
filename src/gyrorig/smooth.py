"""Kalman filter and Rauch-Tung-Striebel smoother for tracked angles.

Input: a tracking table (``angles.csv``: ``frame, t_s, theta_rad, phi_rad, theta_sigma_rad,
phi_sigma_rad[, theta_phi_corr]``; rows with NaN angles are frames without a measurement).

**Process model** (the design decision): each angle is a continuous white-noise-acceleration
("constant velocity") process, state ``x = [theta, theta', phi, phi']`` with

    F(dt) = blockdiag([[1, dt], [0, 1]], [[1, dt], [0, 1]])
    Q(dt) = blockdiag(q_theta * C(dt), q_phi * C(dt)),  C(dt) = [[dt^3/3, dt^2/2], [dt^2/2, dt]]

so uneven frame intervals and gaps are exact (no resampling).  The spectral densities
``q_theta, q_phi`` [rad^2/s^3] come from the data: they maximise the innovation
log-likelihood (``estimate_noise``), never tuned per video.  The measurement covariance of
each frame is the tracker's own (sigmas and correlation), so the filter weighs each frame as
the tracker says it deserves.  Each azimuth measurement is taken on the 2 pi branch nearest
the prediction, so the smoothed azimuth stays continuous across gaps longer than half a turn.

**What it is for, and what it is not for.**  The smoother gives rates, covariances, gap
bridging, an unwrapped azimuth, and outlier rejection by innovation gating (a frame whose
squared Mahalanobis distance of the innovation exceeds ``gate_d2`` is not used and is
marked ``outlier``; after ``max_rejections`` consecutive rejections the filter restarts
at the measurement and marks ``reset``, so a genuine jump does not lock it out).  The fits
(:mod:`gyrorig.fit`) use the *tracked* angles with the tracker's covariances and only the
smoother's outlier marks: smoothed samples are correlated with their neighbours, and
fitting them as independent would make least-squares errors wrong.  That is how the
process model cannot distort what is fitted (and where it gates more frames than its model
allows, :func:`gyrorig.pipeline.smooth_and_fit` lets the fit's model judge them instead).

Two engines run the same model: ``"fast"`` (a compiled loop, ~1 us per frame) and
``"filterpy"`` (filterpy 2.0's ``KalmanFilter.predict/update`` and ``rts_smoother``: the
reference).  They agree to 1e-9 (tested); filterpy remains for checking and for models the
fast path does not have.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from numba import njit
from scipy.optimize import minimize
from scipy.stats import chi2

from .tables import ANGLE_REQUIRED, missing_columns

logger = logging.getLogger(__name__)

__all__ = ["SmoothResult", "SmoothingError", "prepare_measurements", "measurement_covariance", "smooth_angles", "estimate_noise",
           "kalman_smooth", "SMOOTH_COLUMNS", "REQUIRED_COLUMNS", "DEFAULT_GATE_D2"]

REQUIRED_COLUMNS = ANGLE_REQUIRED
#: gate on the innovation's squared Mahalanobis distance (2 dof): the 5-sigma tail probability
DEFAULT_GATE_D2 = float(chi2.isf(5.733e-7, 2))
SMOOTH_COLUMNS = ("frame", "t_s", "theta_rad", "theta_rate_rad_s", "phi_rad", "phi_rate_rad_s",
                  "theta_sigma_rad", "theta_rate_sigma_rad_s", "phi_sigma_rad", "phi_rate_sigma_rad_s",
                  "theta_phi_corr", "innovation_d2", "status")
# status codes (in the compiled loop) and their names
_GAP, _MEASURED, _OUTLIER, _RESET = 0, 1, 2, 3
STATUS_NAMES = {_GAP: "gap", _MEASURED: "measured", _OUTLIER: "outlier", _RESET: "reset"}
_INITIAL_RATE_VAR = 1.0e2  # (rad/s)^2: the prior on the rates is effectively flat


class SmoothingError(ValueError):
    """The angle table cannot be smoothed (missing columns, too few measurements, bad values)."""


@dataclass(frozen=True)
class Measurements:
    """Measurements ready for the filter: times, z (n, 2) with NaN rows for gaps, R (n, 2, 2)."""

    frame: np.ndarray
    t_s: np.ndarray
    z: np.ndarray
    R: np.ndarray
    has: np.ndarray


@dataclass(frozen=True)
class SmoothResult:
    """Smoothed states and covariances, with the estimated noise levels.

    ``table`` has the columns :data:`SMOOTH_COLUMNS` (and ``cov_ij`` for the full 4x4
    covariance of ``[theta, theta', phi, phi']``, upper triangle); ``x`` (n, 4) and
    ``P`` (n, 4, 4) the same as arrays.
    """

    table: pd.DataFrame
    x: np.ndarray
    P: np.ndarray
    q_theta_rad2_s3: float
    q_phi_rad2_s3: float
    log_likelihood: float
    n_measured: int
    n_outliers: int
    n_resets: int
    nis_mean: float
    engine: str
    wall_time_s: float
    info: dict = field(default_factory=dict)

    def summary(self) -> dict:
        return {"q_theta_rad2_s3": self.q_theta_rad2_s3, "q_phi_rad2_s3": self.q_phi_rad2_s3,
                "log_likelihood": self.log_likelihood, "n_frames": int(len(self.table)),
                "n_measured": self.n_measured, "n_outliers": self.n_outliers, "n_resets": self.n_resets,
                "nis_mean": self.nis_mean, "nis_expected": 2.0, "engine": self.engine,
                "wall_time_s": self.wall_time_s, **self.info}


def prepare_measurements(angles: pd.DataFrame) -> Measurements:
    """Check an angle table and turn it into filter inputs (azimuth unwrapped).

    Raises :class:`SmoothingError` naming the problem: missing columns, unsorted or
    non-finite times, non-positive sigmas, too few measurements.
    """
    missing = missing_columns(angles, REQUIRED_COLUMNS)
    if missing:
        raise SmoothingError(f"angle table lacks column(s) {missing}; required: {list(REQUIRED_COLUMNS)}")
    t = angles["t_s"].to_numpy(float)
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise SmoothingError(f"t_s is not finite in row {bad} (frame {angles['frame'].iloc[bad]}): every frame needs a time")
    if np.any(np.diff(t) < 0):
        bad = int(np.flatnonzero(np.diff(t) < 0)[0]) + 1
        raise SmoothingError(f"t_s decreases at row {bad} (frame {angles['frame'].iloc[bad]}): times must be "
                             "non-decreasing")
    th = angles["theta_rad"].to_numpy(float)
    ph = angles["phi_rad"].to_numpy(float)
    sth = angles["theta_sigma_rad"].to_numpy(float)
    sph = angles["phi_sigma_rad"].to_numpy(float)
    corr = angles["theta_phi_corr"].to_numpy(float) if "theta_phi_corr" in angles.columns else np.zeros(len(t))
    corr = np.where(np.isfinite(corr), corr, 0.0)
    has = np.isfinite(th) & np.isfinite(ph)
    partial = has & ~(np.isfinite(sth) & np.isfinite(sph))
    if partial.any():
        bad = int(np.flatnonzero(partial)[0])
        raise SmoothingError(f"row {bad} (frame {angles['frame'].iloc[bad]}) has angles but no finite "
                             "theta_sigma_rad/phi_sigma_rad")
    if np.any(has & ((sth <= 0) | (sph <= 0))):
        bad = int(np.flatnonzero(has & ((sth <= 0) | (sph <= 0)))[0])
        raise SmoothingError(f"row {bad}: theta_sigma_rad and phi_sigma_rad must be > 0")
    if np.any(np.abs(corr) >= 1):
        raise SmoothingError("theta_phi_corr must lie in (-1, 1)")
    if has.sum() < 3:
        raise SmoothingError(f"only {int(has.sum())} frames have angles; at least 3 are needed to smooth")
    z = np.full((len(t), 2), np.nan)
    z[has, 0] = th[has]
    z[has, 1] = np.unwrap(ph[has])
    # frames without a measurement get a placeholder the filter never reads
    R = measurement_covariance(np.where(has, sth, 1.0), np.where(has, sph, 1.0), np.where(has, corr, 0.0))
    frame = angles["frame"].to_numpy()
    return Measurements(frame=frame, t_s=t, z=z, R=R, has=has)


def measurement_covariance(theta_sigma_rad: np.ndarray, phi_sigma_rad: np.ndarray,
                           theta_phi_corr: np.ndarray | None = None) -> np.ndarray:
    """Per-frame 2x2 covariance of ``(theta, phi)`` from the tracker's sigmas and correlation.

    A missing or NaN correlation counts as 0.  Shape ``(n, 2, 2)``.
    """
    sth = np.asarray(theta_sigma_rad, float)
    sph = np.asarray(phi_sigma_rad, float)
    corr = np.zeros_like(sth) if theta_phi_corr is None else np.asarray(theta_phi_corr, float)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    cov = np.empty((len(sth), 2, 2))
    cov[:, 0, 0] = sth**2
    cov[:, 1, 1] = sph**2
    cov[:, 0, 1] = cov[:, 1, 0] = corr * sth * sph
    return cov


def transition(dt: float, q_theta: float, q_phi: float) -> tuple[np.ndarray, np.ndarray]:
    """``F(dt)`` and ``Q(dt)`` of the process model (see the module docstring)."""
    F = np.eye(4)
    F[0, 1] = F[2, 3] = dt
    C = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    Q = np.zeros((4, 4))
    Q[:2, :2] = q_theta * C
    Q[2:, 2:] = q_phi * C
    return F, Q


# ----------------------------------------------------------------------------------------- fast engine
@njit(cache=True)
def _predict(x, P, dt, qt, qp, xo, Po, tmp):
    # F x, F P F' + Q for the block-diagonal constant-velocity model
    xo[0] = x[0] + dt * x[1]
    xo[1] = x[1]
    xo[2] = x[2] + dt * x[3]
    xo[3] = x[3]
    for j in range(4):  # tmp = F P
        tmp[0, j] = P[0, j] + dt * P[1, j]
        tmp[1, j] = P[1, j]
        tmp[2, j] = P[2, j] + dt * P[3, j]
        tmp[3, j] = P[3, j]
    for i in range(4):  # Po = tmp F'
        Po[i, 0] = tmp[i, 0] + dt * tmp[i, 1]
        Po[i, 1] = tmp[i, 1]
        Po[i, 2] = tmp[i, 2] + dt * tmp[i, 3]
        Po[i, 3] = tmp[i, 3]
    c00, c01, c11 = dt**3 / 3.0, dt**2 / 2.0, dt
    Po[0, 0] += qt * c00
    Po[0, 1] += qt * c01
    Po[1, 0] += qt * c01
    Po[1, 1] += qt * c11
    Po[2, 2] += qp * c00
    Po[2, 3] += qp * c01
    Po[3, 2] += qp * c01
    Po[3, 3] += qp * c11


@njit(cache=True)
def _mul4(A, B, out):
    """out = A B for 4x4 matrices (no allocation)."""
    for i in range(4):
        for j in range(4):
            s = 0.0
            for m in range(4):
                s += A[i, m] * B[m, j]
            out[i, j] = s


@njit(cache=True)
def _mul4_bt(A, B, out):
    """out = A B' for 4x4 matrices (no allocation)."""
    for i in range(4):
        for j in range(4):
            s = 0.0
            for m in range(4):
                s += A[i, m] * B[j, m]
            out[i, j] = s


@njit(cache=True)
def _init_state(x, P, z, R, k):
    """State at measurement k: the measured angles, flat prior on the rates."""
    x[:] = 0.0
    x[0] = z[k, 0]
    x[2] = z[k, 1]
    P[:, :] = 0.0
    P[0, 0] = R[k, 0, 0]
    P[0, 2] = R[k, 0, 1]
    P[2, 0] = R[k, 1, 0]
    P[2, 2] = R[k, 1, 1]
    P[1, 1] = _INITIAL_RATE_VAR
    P[3, 3] = _INITIAL_RATE_VAR


@njit(cache=True)
def _filter(t, z, R, has, qt, qp, gate, max_rej, xf, Pf, xp, Pp, d2, status):
    """Forward pass; fills filtered (xf, Pf) and predicted (xp, Pp); returns the log-likelihood."""
    tmp = np.zeros((4, 4))
    n = t.shape[0]
    ll = 0.0
    rej = 0
    started = False
    x = np.zeros(4)
    P = np.zeros((4, 4))
    K = np.zeros((4, 2))
    A = np.zeros((4, 4))
    AP = np.zeros((4, 4))
    Pn = np.zeros((4, 4))
    for k in range(n):
        if not started:
            if has[k]:
                _init_state(x, P, z, R, k)
                started = True
                status[k] = _MEASURED
            else:
                status[k] = _GAP
            d2[k] = np.nan
            xp[k, :] = x
            Pp[k, :, :] = P
            xf[k, :] = x
            Pf[k, :, :] = P
            continue
        dt = t[k] - t[k - 1]
        _predict(x, P, dt, qt, qp, xp[k], Pp[k], tmp)
        x[:] = xp[k]
        P[:, :] = Pp[k]
        d2[k] = np.nan
        status[k] = _GAP
        if has[k]:
            # innovation y = z - H x, S = H P H' + R (H picks states 0 and 2)
            # the azimuth on the 2 pi branch nearest the prediction (gaps longer than half a turn)
            z1 = z[k, 1] + 2.0 * math.pi * np.round((x[2] - z[k, 1]) / (2.0 * math.pi))
            y0 = z[k, 0] - x[0]
            y1 = z1 - x[2]
            s00 = P[0, 0] + R[k, 0, 0]
            s01 = P[0, 2] + R[k, 0, 1]
            s11 = P[2, 2] + R[k, 1, 1]
            det = s00 * s11 - s01 * s01
            i00 = s11 / det
            i01 = -s01 / det
            i11 = s00 / det
            dd = y0 * (i00 * y0 + i01 * y1) + y1 * (i01 * y0 + i11 * y1)
            d2[k] = dd
            if dd > gate and rej < max_rej:
                status[k] = _OUTLIER
                rej += 1
            elif dd > gate:
                # restart at this measurement: a persistent jump is not an outlier
                _init_state(x, P, z, R, k)
                status[k] = _RESET
                rej = 0
            else:
                rej = 0
                status[k] = _MEASURED
                ll += -0.5 * (dd + math.log(det)) - math.log(2.0 * math.pi)
                # K = P H' S^-1  (4x2)
                for i in range(4):
                    K[i, 0] = P[i, 0] * i00 + P[i, 2] * i01
                    K[i, 1] = P[i, 0] * i01 + P[i, 2] * i11
                for i in range(4):
                    x[i] += K[i, 0] * y0 + K[i, 1] * y1
                # Joseph form P = (I - K H) P (I - K H)' + K R K'
                for i in range(4):
                    for j in range(4):
                        A[i, j] = 1.0 if i == j else 0.0
                    A[i, 0] -= K[i, 0]
                    A[i, 2] -= K[i, 1]
                _mul4(A, P, AP)
                _mul4_bt(AP, A, Pn)
                for i in range(4):
                    for j in range(4):
                        Pn[i, j] += (K[i, 0] * (R[k, 0, 0] * K[j, 0] + R[k, 0, 1] * K[j, 1])
                                     + K[i, 1] * (R[k, 1, 0] * K[j, 0] + R[k, 1, 1] * K[j, 1]))
                for i in range(4):
                    for j in range(i, 4):
                        v = 0.5 * (Pn[i, j] + Pn[j, i])
                        P[i, j] = v
                        P[j, i] = v
        xf[k, :] = x
        Pf[k, :, :] = P
    return ll


@njit(cache=True)
def _spd_inverse(A, L, out):
    """Inverse of a symmetric positive-definite 4x4 matrix by Cholesky (no allocation)."""
    n = 4
    for i in range(n):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    # out = (L L')^-1, column by column
    for c in range(n):
        y = np.zeros(4)
        for i in range(n):
            s = 1.0 if i == c else 0.0
            for k in range(i):
                s -= L[i, k] * y[k]
            y[i] = s / L[i, i]
        for i in range(n - 1, -1, -1):
            s = y[i]
            for k in range(i + 1, n):
                s -= L[k, i] * out[k, c]
            out[i, c] = s / L[i, i]


@njit(cache=True)
def _rts(t, xf, Pf, xp, Pp, status, xs, Ps):
    n = t.shape[0]
    xs[n - 1, :] = xf[n - 1]
    Ps[n - 1, :, :] = Pf[n - 1]
    L = np.zeros((4, 4))
    inv = np.zeros((4, 4))
    C = np.zeros((4, 4))
    G = np.zeros((4, 4))
    D = np.zeros((4, 4))
    GD = np.zeros((4, 4))
    GDG = np.zeros((4, 4))
    dx = np.zeros(4)
    for k in range(n - 2, -1, -1):
        if status[k + 1] == _RESET:
            # across a restart the two segments are independent
            xs[k, :] = xf[k]
            Ps[k, :, :] = Pf[k]
            continue
        dt = t[k + 1] - t[k]
        P = Pf[k]
        for i in range(4):  # C = P F'
            C[i, 0] = P[i, 0] + dt * P[i, 1]
            C[i, 1] = P[i, 1]
            C[i, 2] = P[i, 2] + dt * P[i, 3]
            C[i, 3] = P[i, 3]
        _spd_inverse(Pp[k + 1], L, inv)
        _mul4(C, inv, G)
        for i in range(4):
            dx[i] = xs[k + 1, i] - xp[k + 1, i]
            for j in range(4):
                D[i, j] = Ps[k + 1, i, j] - Pp[k + 1, i, j]
        for i in range(4):
            s = xf[k, i]
            for m in range(4):
                s += G[i, m] * dx[m]
            xs[k, i] = s
        _mul4(G, D, GD)
        _mul4_bt(GD, G, GDG)
        for i in range(4):
            for j in range(i, 4):
                v = P[i, j] + 0.5 * (GDG[i, j] + GDG[j, i])
                Ps[k, i, j] = v
                Ps[k, j, i] = v


def _run_fast(m: Measurements, q_theta: float, q_phi: float, gate_d2: float, max_rejections: int,
              smooth: bool = True):
    n = len(m.t_s)
    xf = np.zeros((n, 4))
    Pf = np.zeros((n, 4, 4))
    xp = np.zeros((n, 4))
    Pp = np.zeros((n, 4, 4))
    d2 = np.full(n, np.nan)
    status = np.zeros(n, np.int64)
    z = np.where(np.isfinite(m.z), m.z, 0.0)
    ll = _filter(m.t_s, z, m.R, m.has, q_theta, q_phi, gate_d2, max_rejections, xf, Pf, xp, Pp, d2, status)
    if not smooth:
        return ll, None, None, d2, status
    xs = np.zeros((n, 4))
    Ps = np.zeros((n, 4, 4))
    first = int(np.flatnonzero(m.has)[0])
    _rts(m.t_s[first:], xf[first:], Pf[first:], xp[first:], Pp[first:], status[first:], xs[first:], Ps[first:])
    # before the first measurement: the smoothed state of the first, predicted backwards is not
    # something to invent; leave those rows empty
    xs[:first] = np.nan
    Ps[:first] = np.nan
    return ll, xs, Ps, d2, status


# --------------------------------------------------------------------------------- filterpy engine
def _run_filterpy(m: Measurements, q_theta: float, q_phi: float, gate_d2: float, max_rejections: int):
    from filterpy.kalman import KalmanFilter

    n = len(m.t_s)
    H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.H = H
    first = int(np.flatnonzero(m.has)[0])
    xs_f = np.full((n, 4), np.nan)
    Ps_f = np.full((n, 4, 4), np.nan)
    Fs = [np.eye(4) for _ in range(n)]
    Qs = [np.zeros((4, 4)) for _ in range(n)]
    d2 = np.full(n, np.nan)
    status = np.zeros(n, np.int64)
    ll = 0.0
    rej = 0
    segments = []  # (start, stop) of independent filter runs (split at restarts)
    start = first

    def init(k: int) -> None:
        kf.x = np.array([m.z[k, 0], 0.0, m.z[k, 1], 0.0])
        P = np.zeros((4, 4))
        P[np.ix_([0, 2], [0, 2])] = m.R[k]
        P[1, 1] = P[3, 3] = _INITIAL_RATE_VAR
        kf.P = P

    init(first)
    status[first] = _MEASURED
    xs_f[first], Ps_f[first] = kf.x.copy(), kf.P.copy()
    for k in range(first + 1, n):
        F, Q = transition(m.t_s[k] - m.t_s[k - 1], q_theta, q_phi)
        Fs[k], Qs[k] = F, Q
        kf.predict(F=F, Q=Q)
        if m.has[k]:
            zk = m.z[k].copy()
            zk[1] += 2 * np.pi * np.round((kf.x[2] - zk[1]) / (2 * np.pi))  # branch nearest the prediction
            S = H @ kf.P @ H.T + m.R[k]
            y = zk - H @ kf.x
            dd = float(y @ np.linalg.solve(S, y))
            d2[k] = dd
            if dd > gate_d2 and rej < max_rejections:
                status[k] = _OUTLIER
                rej += 1
            elif dd > gate_d2:
                segments.append((start, k))
                start = k
                init(k)
                status[k] = _RESET
                rej = 0
            else:
                kf.update(zk, R=m.R[k])
                ll += float(kf.log_likelihood)
                status[k] = _MEASURED
                rej = 0
        xs_f[k], Ps_f[k] = kf.x.copy(), kf.P.copy()
    segments.append((start, n))
    xs = np.full((n, 4), np.nan)
    Ps = np.full((n, 4, 4), np.nan)
    for a, b in segments:
        if b - a == 1:
            xs[a], Ps[a] = xs_f[a], Ps_f[a]
            continue
        x, P, _, _ = kf.rts_smoother(xs_f[a:b], Ps_f[a:b], Fs=Fs[a:b], Qs=Qs[a:b])
        xs[a:b], Ps[a:b] = x, P
    return ll, xs, Ps, d2, status


# ------------------------------------------------------------------------------------- noise levels
def _initial_q(m: Measurements) -> tuple[float, float]:
    """A starting guess from second differences of the measured angles."""
    idx = np.flatnonzero(m.has)
    t, z = m.t_s[idx], m.z[idx]
    dt = np.median(np.diff(t)) if len(t) > 1 else 1.0
    dt = dt if dt > 0 else 1.0
    out = []
    for j in range(2):
        d2 = np.diff(z[:, j], 2)
        v = float(np.var(d2)) if d2.size else 0.0
        out.append(max(v / dt**3, 1e-12))
    return out[0], out[1]


def estimate_noise(m: Measurements, gate_d2: float = DEFAULT_GATE_D2, max_rejections: int = 3,
                   q0: tuple[float, float] | None = None) -> tuple[float, float, float, dict]:
    """Maximum-likelihood ``q_theta, q_phi`` [rad^2/s^3] from the innovations.

    Returns ``(q_theta, q_phi, log_likelihood, info)``.  The search is over log q
    (Nelder-Mead, since the gate makes the likelihood piecewise smooth).
    """
    q0 = q0 or _initial_q(m)
    z = np.where(np.isfinite(m.z), m.z, 0.0)
    n = len(m.t_s)
    bufs = (np.zeros((n, 4)), np.zeros((n, 4, 4)), np.zeros((n, 4)), np.zeros((n, 4, 4)), np.zeros(n),
            np.zeros(n, np.int64))

    def nll(logq: np.ndarray) -> float:
        qt, qp = np.exp(np.clip(logq, -200, 200))
        return -_filter(m.t_s, z, m.R, m.has, qt, qp, gate_d2, max_rejections, *bufs)

    start = np.log(np.asarray(q0, float))
    res = minimize(nll, start, method="Nelder-Mead",
                   options={"xatol": 1e-3, "fatol": 1e-4, "maxiter": 400, "initial_simplex": start + np.array(
                       [[0, 0], [2.0, 0], [0, 2.0]])})
    qt, qp = np.exp(res.x)
    return float(qt), float(qp), float(-res.fun), {"ml_evaluations": int(res.nfev), "ml_converged": bool(res.success)}


# ------------------------------------------------------------------------------------------ public
def kalman_smooth(m: Measurements, q_theta: float, q_phi: float, gate_d2: float = DEFAULT_GATE_D2,
                  max_rejections: int = 3, engine: str = "fast"):
    """Filter + smoother of the model with given noise levels.

    Returns ``(log_likelihood, xs (n,4), Ps (n,4,4), innovation_d2 (n,), status (n,) int)``.
    """
    if q_theta <= 0 or q_phi <= 0:
        raise ValueError(f"q_theta and q_phi must be > 0 (got {q_theta}, {q_phi})")
    if engine == "fast":
        return _run_fast(m, q_theta, q_phi, gate_d2, max_rejections)
    if engine == "filterpy":
        return _run_filterpy(m, q_theta, q_phi, gate_d2, max_rejections)
    raise ValueError(f"engine must be 'fast' or 'filterpy' (got {engine!r})")


def smooth_angles(angles: pd.DataFrame, q: tuple[float, float] | None = None, gate_d2: float = DEFAULT_GATE_D2,
                  max_rejections: int = 3, engine: str = "fast") -> SmoothResult:
    """Smooth a tracking table; noise levels by maximum likelihood unless ``q`` is given.

    The returned table has one row per input row (gaps included, marked ``gap``).
    """
    if gate_d2 <= 0:
        raise ValueError(f"gate_d2 must be > 0 (got {gate_d2})")
    if max_rejections < 1:
        raise ValueError(f"max_rejections must be >= 1 (got {max_rejections})")
    start = time.perf_counter()
    m = prepare_measurements(angles)
    info: dict = {}
    if q is None:
        qt, qp, _, info = estimate_noise(m, gate_d2, max_rejections)
    else:
        qt, qp = q
    ll, xs, Ps, d2, status = kalman_smooth(m, qt, qp, gate_d2, max_rejections, engine)
    used = status == _MEASURED
    nis = float(np.nanmean(d2[used])) if used.any() else math.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        sd = np.sqrt(np.diagonal(Ps, axis1=1, axis2=2))
        corr = Ps[:, 0, 2] / (sd[:, 0] * sd[:, 2])
    table = pd.DataFrame({
        "frame": m.frame, "t_s": m.t_s,
        "theta_rad": xs[:, 0], "theta_rate_rad_s": xs[:, 1], "phi_rad": xs[:, 2], "phi_rate_rad_s": xs[:, 3],
        "theta_sigma_rad": sd[:, 0], "theta_rate_sigma_rad_s": sd[:, 1], "phi_sigma_rad": sd[:, 2],
        "phi_rate_sigma_rad_s": sd[:, 3], "theta_phi_corr": corr, "innovation_d2": d2,
        "status": pd.Series(status).map(STATUS_NAMES).to_numpy(),
    })
    for i in range(4):
        for j in range(i, 4):
            table[f"cov_{i}{j}"] = Ps[:, i, j]
    return SmoothResult(table=table, x=xs, P=Ps, q_theta_rad2_s3=qt, q_phi_rad2_s3=qp, log_likelihood=ll,
                        n_measured=int(used.sum()), n_outliers=int((status == _OUTLIER).sum()),
                        n_resets=int((status == _RESET).sum()), nis_mean=nis, engine=engine,
                        wall_time_s=time.perf_counter() - start, info=info)
