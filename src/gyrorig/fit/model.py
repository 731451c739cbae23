"""The fit model: which one the scene calls for, its evaluation and Jacobian in the lab, and its residuals.

The tip moves on a cone about an axis ``n``: the vertical under gravity, the *fitted* effective
vertical when the pivot accelerates, the fitted angular-momentum direction for a free top.
:class:`FitModel` sums the terms of :mod:`gyrorig.fit.terms` in the frame whose z is ``n`` and
rotates the result to the lab.  :class:`Residuals` compares it with :class:`~gyrorig.fit.data.FitData`:
residuals whitened with each frame's covariance, the model averaged over each exposure, and one
prior residual per camera-model mode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry import angles_from_tip, axis_rotation, tip_from_angles, wrap_angle
from ..drag import rotor_spin_decay_rate_per_s
from ..prediction import Prediction
from ..protocols import Protocol
from .data import FitData, FitError
from .spec import ModelSpec
from .phases import rate_phase
from .terms import NUTATION_CURVATURE, TERMS, BFrameShrink, RollingShutter

__all__ = ["FitModel", "Residuals", "SceneModel", "model_for_scene", "whitener"]


class FitModel:
    """Evaluates the fit model of a :class:`ModelSpec` at given times (``tau = t - t_ref``)."""

    def __init__(self, spec: ModelSpec):
        self.spec = spec
        self.names = spec.names()
        self.index = {n: i for i, n in enumerate(self.names)}
        self._terms = [t for t in TERMS if t.present(spec)]
        #: the B pictures' shrink parameter's place in the vector (None: the model has none)
        self.shrink_index = self.index.get(BFrameShrink.NAME)
        #: the rolling shutter's readout time's place in the vector (None: the model has none)
        self.readout_index = self.index.get(RollingShutter.NAME)

    def vector(self, values: dict[str, float]) -> np.ndarray:
        """The parameter vector from named values (0 for a name not given)."""
        return np.array([values.get(n, 0.0) for n in self.names], float)

    def values(self, p: np.ndarray) -> dict[str, float]:
        """Named values of a parameter vector."""
        return dict(zip(self.names, p))

    def envelope(self, p: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The damped nutation's envelope, 1 at the first frame: ``exp(-mu (tau - tau0))``."""
        return np.exp(-p[self.index["nutation_decay_rate_per_s"]] * (tau - self.spec.nutation_origin_s))

    def nutation_phase(self, p: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """``psi = w tau (+ w' tau^2 / 2 when damped; a spin decaying: exponential in time, see
        :func:`~gyrorig.fit.phases.rate_phase`, plus w'' tau^3 / 3)``."""
        return self.nutation_phase_terms(p, tau)[0]

    def nutation_phase_terms(self, p: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`nutation_phase` and its derivative with respect to each parameter it has (by name)."""
        ix = self.index
        chirp = p[ix["nutation_chirp_rad_s2"]] if self.spec.damped else 0.0
        psi, d_rate, d_change = rate_phase(p[ix["nutation_frequency_rad_s"]], chirp, tau, self.spec.spin_decay)
        columns = {"nutation_frequency_rad_s": d_rate}
        if self.spec.damped:
            columns["nutation_chirp_rad_s2"] = d_change
        if self.spec.spin_decay:
            psi = psi + p[ix[NUTATION_CURVATURE]] * tau**3 / 3
            columns[NUTATION_CURVATURE] = tau**3 / 3
        return psi, columns

    def _fast_part(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray):
        """theta', phi' in the axis frame, and the part of them the fast terms make."""
        th, ph = np.zeros_like(tau), np.zeros_like(tau)
        fth, fph = np.zeros_like(tau), np.zeros_like(tau)
        for term in self._terms:
            th1, ph1 = term.add(self, p, tau, segment, th, ph)
            if term.fast:
                fth, fph = fth + (th1 - th), fph + (ph1 - ph)
            th, ph = th1, ph1
        return th, ph, fth, fph

    def axis_frame(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray, b_rows: np.ndarray | None = None):
        """theta', phi' in the axis frame; ``b_rows`` (a lossy codec's bi-predicted pictures) with their fast part
        shrunk by the model's ``b_frame_shrink``."""
        th, ph, fth, fph = self._fast_part(p, tau, segment)
        if b_rows is not None and self.shrink_index is not None:
            g = p[self.shrink_index] * b_rows
            th, ph = th - g * fth, ph - g * fph
        return th, ph

    def axis_frame_jacobian(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray,
                            b_rows: np.ndarray | None = None):
        """d(theta')/dp and d(phi')/dp, each (n, P), analytic (axis columns zero)."""
        shrink = b_rows is not None and self.shrink_index is not None
        dth = np.zeros((len(tau), len(p)))
        dph = np.zeros((len(tau), len(p)))
        fast = (np.zeros_like(dth), np.zeros_like(dph)) if shrink else (dth, dph)
        for term in self._terms:  # a term fills its own columns and adds to shared ones: the two parts can be summed
            term.jacobian(self, p, tau, segment, *(fast if term.fast else (dth, dph)))
        if shrink:
            _, _, fth, fph = self._fast_part(p, tau, segment)
            g = 1.0 - p[self.shrink_index] * b_rows
            dth += g[:, None] * fast[0]
            dph += g[:, None] * fast[1]
            dth[:, self.shrink_index] = -b_rows * fth
            dph[:, self.shrink_index] = -b_rows * fph
        return dth, dph

    def rotation(self, p: np.ndarray) -> np.ndarray | None:
        """Rotation from the axis frame to the lab (None for the vertical)."""
        if not self.spec.fit_axis:
            return None
        return axis_rotation(p[self.index["axis_tilt_rad"]], p[self.index["axis_azimuth_rad"]])

    def lab(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray, b_rows: np.ndarray | None = None):
        """theta, phi in the lab (``b_rows``: see :meth:`axis_frame`)."""
        th, ph = self.axis_frame(p, tau, segment, b_rows)
        R = self.rotation(p)
        return (th, ph) if R is None else angles_from_tip(tip_from_angles(th, ph) @ R.T)

    def lab_jacobian(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray, b_rows: np.ndarray | None = None):
        """d(theta, phi)_lab / dp, each (n, P): analytic in the axis frame, chain rule to the lab."""
        dth, dph = self.axis_frame_jacobian(p, tau, segment, b_rows)
        if not self.spec.fit_axis:
            return dth, dph
        ix = self.index
        th, ph = self.axis_frame(p, tau, segment, b_rows)
        a, b = p[ix["axis_tilt_rad"]], p[ix["axis_azimuth_rad"]]

        def conv(t_, p_, a_=a, b_=b):
            return angles_from_tip(tip_from_angles(t_, p_) @ axis_rotation(a_, b_).T)

        h = 1e-7
        tp, pp = conv(th + h, ph)
        tm, pm = conv(th - h, ph)
        g00, g10 = (tp - tm) / (2 * h), wrap_angle(pp - pm) / (2 * h)
        tp, pp = conv(th, ph + h)
        tm, pm = conv(th, ph - h)
        g01, g11 = (tp - tm) / (2 * h), wrap_angle(pp - pm) / (2 * h)
        jt = g00[:, None] * dth + g01[:, None] * dph
        jp = g10[:, None] * dth + g11[:, None] * dph
        for name, da, db in (("axis_tilt_rad", h, 0.0), ("axis_azimuth_rad", 0.0, h)):
            tp, pp = conv(th, ph, a + da, b + db)
            tm, pm = conv(th, ph, a - da, b - db)
            jt[:, ix[name]] = (tp - tm) / (2 * h)
            jp[:, ix[name]] = wrap_angle(pp - pm) / (2 * h)
        return jt, jp

    def in_axis_frame(self, p: np.ndarray, data: FitData) -> tuple[np.ndarray, np.ndarray]:
        """The measured angles in this model's axis frame (the lab angles for the vertical)."""
        R = self.rotation(p)
        if R is None:
            return data.theta_rad, data.phi_rad
        return angles_from_tip(tip_from_angles(data.theta_rad, data.phi_rad) @ R)


def whitener(cov: np.ndarray) -> np.ndarray:
    """Per-frame W with W^T W = cov^-1 (inverse Cholesky factor), shape (n, 2, 2)."""
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    l00 = np.sqrt(a)
    l10 = b / l00
    l11 = np.sqrt(c - l10**2)
    W = np.zeros_like(cov)
    W[:, 0, 0] = 1 / l00
    W[:, 1, 0] = -l10 / (l00 * l11)
    W[:, 1, 1] = 1 / l11
    return W


class Residuals:
    """A model against the data: raw residuals (theta, phi), whitened ones (2n, then one prior residual
    per camera mode, then one per prior of :class:`~gyrorig.fit.constraints.Constraints`) and their
    Jacobian (zero in the columns of fixed parameters).

    With exposures the model is the mean over each frame's exposure, by two-point Gauss-Legendre
    (exact for a cubic; for a sinusoid of angular frequency w off by (w T)^4 / 2900, 1e-11 at
    59 rad/s and 300 us).  With camera modes the model adds ``sum_k a_k (theta_cam_k, phi_cam_k)``
    and the ``a_k`` have the prior residuals ``R a`` with ``R = FitData.camera_prior_root`` (the
    identity when None: a unit Gaussian prior on each; see
    :func:`gyrorig.fit.uncertainty.shared_pose_prior_root` for a pose found from the same frames).
    """

    def __init__(self, model: FitModel, data: FitData):
        m = model.spec.camera_modes
        if m and data.camera_modes != m:
            raise FitError(f"the model has {m} camera modes, the data {data.camera_modes}")
        self.model, self.data, self.modes = model, data, m
        self.tau = data.tau
        if model.shrink_index is not None and data.b_frame is None:
            raise FitError("the model fits the B pictures' shrink, but the data do not say which frames are B pictures")
        self.b_rows = data.b_frame.astype(float) if model.shrink_index is not None else None
        if model.readout_index is not None and data.row_fraction is None:
            raise FitError("the model fits a rolling shutter's readout, but the data do not give the tips' rows")
        self.rows = data.row_fraction if model.readout_index is not None else None
        self.W = whitener(data.cov)
        self.shift = data.camera_shift if m else None
        root = data.camera_prior_root if m else None
        self.mode_root = np.eye(m) if root is None else root
        ix = model.index
        c = data.constraints
        self.fixed = {ix[n]: v for n, v in c.fixed if n in ix}
        priors = [(ix[n], mu, sd) for n, mu, sd in c.priors if n in ix]
        self.prior_index = np.array([i for i, _, _ in priors], int)
        self.prior_mean = np.array([mu for _, mu, _ in priors], float)
        self.prior_sd = np.array([sd for _, _, sd in priors], float)
        ex = data.exposure_s
        if ex is not None and np.any(ex > 0):
            half = ex / (2.0 * math.sqrt(3.0))
            self.taus = (self.tau - half, self.tau + half)
        else:
            self.taus = None

    @property
    def size(self) -> int:
        """Number of whitened residuals."""
        return 2 * self.data.n + self.modes + len(self.prior_index)

    @property
    def informative_size(self) -> int:
        """Residuals the degrees of freedom count: the camera modes' priors as many as the information they
        hold (``trace(R^T R)``, rounded; ``m`` for unit priors)."""
        return 2 * self.data.n + int(round(float(np.sum(self.mode_root**2)))) + len(self.prior_index)

    @property
    def free(self) -> int:
        """Number of parameters the fit moves (the model's, less the fixed ones)."""
        return len(self.model.names) - len(self.fixed)

    def start(self, x: np.ndarray) -> np.ndarray:
        """``x`` with the fixed parameters set to their values."""
        x = np.array(x, float)
        for i, v in self.fixed.items():
            x[i] = v
        return x

    def _times(self, p: np.ndarray) -> tuple[np.ndarray, ...]:
        """The times the model is evaluated at: each frame's (or its exposure's two Gauss-Legendre points), moved by
        its row's delay under a fitted rolling shutter."""
        taus = (self.tau,) if self.taus is None else self.taus
        if self.rows is None:
            return taus
        delay = self.rows * p[self.model.readout_index]
        return tuple(tt + delay for tt in taus)

    def lab(self, p: np.ndarray):
        seg, b = self.data.segment, self.b_rows
        taus = self._times(p)
        if len(taus) == 1:
            return self.model.lab(p, taus[0], seg, b)
        (t1, p1), (t2, p2) = (self.model.lab(p, tt, seg, b) for tt in taus)
        return 0.5 * (t1 + t2), p1 + 0.5 * wrap_angle(p2 - p1)

    def lab_jacobian(self, p: np.ndarray):
        seg, b = self.data.segment, self.b_rows
        parts = []
        for tt in self._times(p):
            jt, jp = self.model.lab_jacobian(p, tt, seg, b)
            if self.rows is not None:  # the readout moves each frame's time by its row: d/dtau times the row
                h = 1e-6
                (t_hi, p_hi), (t_lo, p_lo) = (self.model.lab(p, tt + s, seg, b) for s in (h, -h))
                jt[:, self.model.readout_index] = self.rows * (t_hi - t_lo) / (2 * h)
                jp[:, self.model.readout_index] = self.rows * wrap_angle(p_hi - p_lo) / (2 * h)
            parts.append((jt, jp))
        if len(parts) == 1:
            return parts[0]
        (a1, b1), (a2, b2) = parts
        return 0.5 * (a1 + a2), 0.5 * (b1 + b2)

    def raw(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measured minus model, (theta, phi) [rad]."""
        th, ph = self.lab(p)
        m = self.modes
        if m:
            a = p[-m:]
            th = th + np.tensordot(a, self.shift[:, :, 0], axes=1)
            ph = ph + np.tensordot(a, self.shift[:, :, 1], axes=1)
        return self.data.theta_rad - th, wrap_angle(self.data.phi_rad - ph)

    def __call__(self, p: np.ndarray) -> np.ndarray:
        """Whitened residuals."""
        r0, r1 = self.raw(p)
        W = self.W
        parts = [W[:, 0, 0] * r0, W[:, 1, 0] * r0 + W[:, 1, 1] * r1]
        if self.modes:
            parts.append(self.mode_root @ p[-self.modes:])  # the camera modes' priors
        if len(self.prior_index):
            parts.append((p[self.prior_index] - self.prior_mean) / self.prior_sd)
        return np.concatenate(parts)

    def jac(self, p: np.ndarray) -> np.ndarray:
        """Jacobian of the whitened residuals."""
        jt, jp = self.lab_jacobian(p)
        m, W = self.modes, self.W
        if m:
            jt[:, -m:] = self.shift[:, :, 0].T
            jp[:, -m:] = self.shift[:, :, 1].T
        J = -np.concatenate([W[:, 0, 0, None] * jt, W[:, 1, 0, None] * jt + W[:, 1, 1, None] * jp])
        if m:
            prior = np.zeros((m, J.shape[1]))
            prior[:, -m:] = self.mode_root
            J = np.vstack([J, prior])
        if len(self.prior_index):
            prior = np.zeros((len(self.prior_index), J.shape[1]))
            prior[np.arange(len(self.prior_index)), self.prior_index] = 1.0 / self.prior_sd
            J = np.vstack([J, prior])
        if self.fixed:
            J[:, list(self.fixed)] = 0.0
        return J


@dataclass(frozen=True)
class SceneModel:
    """What the scene says the fit should contain."""

    spec: ModelSpec
    nutation_expected: bool
    nutation_frequency_hint_rad_s: float | None
    precession_hint_rad_s: float | None
    reasons: tuple[str, ...] = ()


def model_for_scene(protocol: Protocol, prediction: Prediction | None = None) -> SceneModel:
    """The fit model the scene calls for, with hints from theory (never used as fitted values).

    A fitted axis when the pivot accelerates (the effective vertical) or without gravity (the
    angular momentum); damped terms only with damping; nutation only under gravity (a free top
    has none about ``L``).  The nutation harmonics and optional terms are chosen by the data
    (:func:`gyrorig.fit.selection.fit_model`).
    """
    gravity = bool(protocol.rig.gravity_m_s2)
    acc = protocol.pivot.acceleration
    accelerating = acc is not None and any(any(v != 0 for v in a) for a in acc.acceleration_m_s2)
    damped = bool(protocol.pivot.damping)
    reasons = []
    if accelerating and not acc.is_constant:
        reasons.append("the pivot acceleration varies in time: no fixed equilibrium direction to fit; the "
                       "cone axis is fitted as if constant")
    fit_axis = accelerating or not gravity
    prec_key = "mean_precession_rate_rad_s" if gravity else "precession_rate_rad_s"
    nut = prediction.exact("nutation_frequency_rad_s") if gravity and prediction is not None else None
    prec = prediction.exact(prec_key) if prediction is not None else None
    gyrostat = protocol.rig.is_gyrostat
    spec = ModelSpec(fit_axis=fit_axis, damped=damped, spin_decay=damped and rotor_spin_decay_rate_per_s(protocol) > 0,
                     gyrostat=gyrostat, frame_spin_rad_s=protocol.launch.frame_spin_rate_rad_s if gyrostat else 0.0)
    return SceneModel(spec=spec, nutation_expected=gravity, nutation_frequency_hint_rad_s=nut,
                      precession_hint_rad_s=prec, reasons=tuple(reasons))
