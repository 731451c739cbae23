"""Least-squares fits of tracked angles against the scene's motion, compared with theory.

**Data.**  The fit uses the *tracked* angles with the tracker's per-frame 2x2 covariance
(``theta_sigma_rad, phi_sigma_rad, theta_phi_corr``), not the smoothed ones (smoothing
correlates neighbouring samples, which would make the least-squares errors wrong).  Frames
the smoother gated out as outliers are left out.

**Model** (chosen by the scene; :func:`model_for_scene`).  The tip moves on a cone about an
axis ``n``: the vertical under gravity; the *fitted* effective vertical when the pivot
accelerates; the fitted angular-momentum direction for a free top.  In the frame whose z is
``n``, with ``tau = t - t_ref`` (``t_ref`` the middle of the record):

    theta'(tau) = exp(c0 + lambda tau) + exp(-mu (tau - tau0)) sum_k [a_k cos(k w tau) + b_k sin(k w tau)]
    phi'(tau)   = phi0_s + Omega tau + (1/2) Omegadot tau^2
                  + exp(-mu tau) sum_k [c_k cos(k w tau) + d_k sin(k w tau)]

- ``lambda`` (tilt growth rate), ``mu`` (nutation decay) and ``Omegadot`` exist only with
  damping; an undamped scene fits none of them (a heavy top's theta is then exactly periodic
  and ``phi - Omega t`` has the same period, so the model is exact given enough harmonics).
- The nutation terms exist only when the camera can resolve the nutation (frame rate above
  twice its predicted frequency, record longer than two periods) and the data show it
  (a chi-square test against the fit without it).  The number of harmonics is chosen by
  the same test.  A free top has no nutation about ``L``.
- ``phi0_s`` is one offset per segment: a gap longer than half a precession period splits
  the record, since the turns made in the gap are not observed.

**Camera model.**  When the tracker propagated the camera model's uncertainty (columns
``theta_cam_k_rad, phi_cam_k_rad``: each frame's angle shift for a one-sigma move of camera
mode ``k``), the model adds ``sum_k a_k * shift_k`` with one nuisance parameter ``a_k`` per mode
and a unit Gaussian prior on each (an extra residual ``a_k``).  The data may then refine the
camera (a cone seen through a wrong lens model is not a cone), and every standard error
includes the camera's share; ``Quantity.camera_standard_error`` says how much.

Residuals are whitened with each frame's covariance; ``scipy.optimize.least_squares``
minimises their sum of squares, and the parameter covariance is ``(J^T J)^-1`` (the
Cramér-Rao bound of this model for these measurement errors).  Derived quantities get
their standard error by the delta method.  The residuals are checked: reduced chi-square,
and their lag-1 autocorrelation; where they are not white, a moving-block bootstrap gives
the standard errors instead and the report says so.

**Quantities** (``FitResult.quantities``): ``precession_rate_rad_s``,
``nutation_frequency_rad_s``, ``nutation_amplitude_rad`` (half the peak-to-peak of the
periodic tilt; under damping, at the first frame), ``tilt_growth_rate_per_s`` and ``tilt_time_constant_s``
(damping), ``equilibrium_tilt_rad``/``equilibrium_azimuth_rad`` (pivot acceleration),
``cone_angle_rad``.  One the data cannot determine is reported as undetermined with the
reason, never as a number.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline
from scipy.optimize import least_squares
from scipy.special import expit
from scipy.stats import chi2, ncx2

from .protocols import Protocol
from .smooth import measurement_covariance

logger = logging.getLogger(__name__)

__all__ = ["FitError", "ModelSpec", "FitTerms", "Quantity", "FitResult", "FitData", "model_for_scene",
           "fit_data_from_angles", "fit_angles", "fit_model", "plan_terms", "phase_uncertainty", "left_out_noncentrality",
           "linear_response",
           "OPTIONAL_TERMS", "QUANTITY_UNITS"]

QUANTITY_UNITS = {
    "precession_rate_rad_s": "rad/s",
    "nutation_frequency_rad_s": "rad/s",
    "nutation_amplitude_rad": "rad",
    "tilt_growth_rate_per_s": "1/s",
    "tilt_time_constant_s": "s",
    "equilibrium_tilt_rad": "rad",
    "equilibrium_azimuth_rad": "rad",
    "cone_angle_rad": "rad",
}
#: significance for adding a model term (nutation, a harmonic): chi-square tail probability
TERM_P_VALUE = 1e-3
#: planning a model on noiseless simulated angles: a term is kept when it changes the chi-square
#: by more than this (its non-centrality: leaving it out could bias a quantity by up to
#: sqrt(this) standard errors)
PLANNED_NONCENTRALITY = 1.0
#: planning on noiseless data keeps a term with a free frequency (the persistent oscillation)
#: only above this chi-square change: below it, noisy records cannot locate the frequency
FREE_FREQUENCY_NONCENTRALITY = 25.0
#: a persistent oscillation whose first-order chi-square gain (score statistic) is below this
#: fraction of the threshold is not fitted: the score equals the fitted gain for a small term, and
#: was within 10 % of it on the bundled rigs (e.g. 39.4 against 43.3, 18.71 against 18.66)
SCORE_SCREEN_FRACTION = 0.75
#: nutation counts as resolved by the camera below this fraction of the Nyquist frequency
NYQUIST_FRACTION = 0.9
MAX_HARMONICS = 6
#: the drifting nutation shape's two parameters (real and imaginary part of ``s``, 1/s).  With the
#: fundamental written as complex amplitudes ``z_t = a - i b`` (tilt) and ``z_p = c - i d`` (azimuth),
#: the shape drift adds ``(tau - tau0) e^{-mu (tau - tau0)} Re[u e^{i psi}]`` with
#: ``(u_t, u_p) = s (-conj(z_p), conj(z_t))``: the complex direction orthogonal to ``(z_t, z_p)``.
#: A drift along ``(z_t, z_p)`` itself (four free coefficients) is, to first order, a change of the
#: decay rate (real ``s``) or of the nutation frequency (imaginary ``s``): with it, those two were
#: fixed only by the weak higher-order terms (the accelerated pivot over 5.7 s: the nutation
#: frequency's standard error 23x, the decay rate's 36x larger) and the fit was not linear over one
#: standard error.
SHAPE_DRIFT_NAMES = ("shape_drift_re_per_s", "shape_drift_im_per_s")
#: the optional terms of a damped model beyond the nutation harmonics, in the order they are tried
#: (the nutation's own slow changes first: the later terms could otherwise stand in for them)
OPTIONAL_TERMS = ("shape_drift", "third_order", "persistent", "transient", "precession_second", "sidebands")
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
#: above this reduced chi-square the residuals are dominated by a systematic, and the report says so
SYSTEMATIC_CHI2_RED = 10.0
#: a rate-like parameter whose standard error leaves more than this phase (rad) uncertain at the
#: record's ends puts the fit outside its linear regime (see :func:`phase_uncertainty`)
NONLINEAR_PHASE_RAD = 0.3
#: a parameter whose value is below this many standard errors is "not significant"
SIGNIFICANCE_SE = 3.0


class FitError(ValueError):
    """The angles cannot be fitted (missing columns, too few frames for the model, no data)."""


@dataclass(frozen=True)
class ModelSpec:
    """Which terms the fit model has (see the module docstring)."""

    fit_axis: bool = False
    damped: bool = False
    harmonics: int = 0
    segments: int = 1
    persistent: bool = False
    #: tau at which a damped nutation's envelope is 1 (the first frame): amplitudes are quoted there
    nutation_origin_s: float = 0.0
    #: a fast exponential transient from the first frame (damped scenes: the gyrostat frame's
    #: own spin relaxes in I_frame / c, tens of ms, after release)
    transient: bool = False
    #: the transient decays at least this fast (1/s): ten e-folds within the record, so that it
    #: cannot stand in for the slow terms
    transient_min_rate_per_s: float = 0.0
    #: ... and at most this fast (a few e-folds per frame): the rate is bounded smoothly between the two
    transient_max_rate_per_s: float = 1e3
    #: nutation sidebands at w +- Omega (damped, fitted axis: damping about the lab vertical
    #: modulates the nutation with the precession phase)
    sidebands: bool = False
    #: second precession harmonic (damped, fitted axis: an elliptical cone)
    precession_second: bool = False
    #: third order in the damped nutation's amplitude: a term at the nutation frequency decaying
    #: three times as fast (the nutation's shape depends on its amplitude, so the ratio of its
    #: tilt and azimuth parts drifts as it decays; B2 rig over 4 s at full resolution)
    third_order: bool = False
    #: the damped nutation's shape drifts: the ratio and relative phase of its tilt and azimuth parts
    #: change linearly in time (the mode shape depends on the tilt, which drifts; first order, like
    #: the frequency chirp).  Two parameters: a drift of all four fundamental coefficients would
    #: contain the fundamental's own decay and frequency (see :data:`SHAPE_DRIFT_NAMES`)
    shape_drift: bool = False
    #: nuisance parameters for the camera model's uncertainty (one per mode, unit prior)
    camera_modes: int = 0

    def transient_rate(self, logit: float) -> float:
        """The transient's decay rate, bounded smoothly between its minimum and maximum. [1/s]"""
        return self.transient_min_rate_per_s + (self.transient_max_rate_per_s - self.transient_min_rate_per_s) * \
            float(expit(logit))

    def names(self) -> list[str]:
        n = []
        if self.fit_axis:
            n += ["axis_tilt_rad", "axis_azimuth_rad"]
        n += ["log_cone_angle", "precession_rate_rad_s"]
        if self.damped:
            n += ["tilt_growth_rate_per_s", "tilt_growth_curvature_per_s2", "precession_acceleration_rad_s2"]
        n += [f"azimuth_offset_{s}_rad" for s in range(self.segments)]
        if self.harmonics:
            n += ["nutation_frequency_rad_s"]
            if self.damped:
                n += ["nutation_decay_rate_per_s", "nutation_chirp_rad_s2", "tilt_decaying_offset_rad",
                      "azimuth_decaying_offset_rad"]
            for k in range(1, self.harmonics + 1):
                n += [f"tilt_cos_{k}_rad", f"tilt_sin_{k}_rad", f"azimuth_cos_{k}_rad", f"azimuth_sin_{k}_rad"]
        if self.damped and self.fit_axis:
            # azimuth only: a tilt term locked to the precession phase is, to first order, a shift
            # of the fitted axis (the two made the fit two-valued)
            n += ["azimuth_precession_cos_rad", "azimuth_precession_sin_rad"]
        if self.persistent:
            n += ["persistent_frequency_rad_s", "persistent_tilt_cos_rad", "persistent_tilt_sin_rad",
                  "persistent_azimuth_cos_rad", "persistent_azimuth_sin_rad"]
        if self.transient:
            n += ["transient_rate_logit", "transient_tilt_rad", "transient_azimuth_rad"]
        if self.sidebands:
            for side in ("upper", "lower"):
                n += [f"tilt_{side}_cos_rad", f"tilt_{side}_sin_rad", f"azimuth_{side}_cos_rad", f"azimuth_{side}_sin_rad"]
        if self.shape_drift:
            n += list(SHAPE_DRIFT_NAMES)
        if self.third_order:
            n += ["tilt_third_cos_rad", "tilt_third_sin_rad", "azimuth_third_cos_rad", "azimuth_third_sin_rad"]
        if self.precession_second:
            n += ["tilt_precession2_cos_rad", "tilt_precession2_sin_rad", "azimuth_precession2_cos_rad",
                  "azimuth_precession2_sin_rad"]
        n += [f"camera_mode_{k + 1}" for k in range(self.camera_modes)]  # always last
        return n


@dataclass(frozen=True)
class FitTerms:
    """The optional terms of a fit model, fixed before the data are fitted.

    :func:`plan_terms` chooses them on noiseless simulated angles of the scene, so that every
    run of an experiment is fitted with the same model: a model chosen afresh by each run's
    own chi-square tests switches terms on and off between runs, and the runs that gain a
    term get wider error bars than those that do not.
    """

    harmonics: int = 0
    transient: bool = False
    precession_second: bool = False
    sidebands: bool = False
    persistent: bool = False
    third_order: bool = False
    shape_drift: bool = False
    #: where the terms come from (for the report)
    source: str = ""
    #: for each optional term the plan left out, the chi-square change it made on the plan's noiseless
    #: record (its expected non-centrality; ``harmonics``: the next harmonic): a record adds a left-out
    #: term only when its chi-square gain is improbable (p < TERM_P_VALUE) for that non-centrality
    left_out_noncentrality: tuple[tuple[str, float], ...] = ()

    def __post_init__(self):
        # one order, so that equal terms compare equal
        object.__setattr__(self, "left_out_noncentrality",
                           tuple(sorted((str(k), float(v)) for k, v in self.left_out_noncentrality)))

    @classmethod
    def of(cls, spec: ModelSpec, source: str = "", left_out_noncentrality: dict[str, float] | None = None
           ) -> "FitTerms":
        return cls(harmonics=spec.harmonics, transient=spec.transient, precession_second=spec.precession_second,
                   sidebands=spec.sidebands, persistent=spec.persistent, third_order=spec.third_order,
                   shape_drift=spec.shape_drift, source=source,
                   left_out_noncentrality=tuple((left_out_noncentrality or {}).items()))

    def noncentrality(self, flag: str) -> float:
        """The plan's expected chi-square change for a term it left out (0 when it did not measure one)."""
        return dict(self.left_out_noncentrality).get(flag, 0.0)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["left_out_noncentrality"] = dict(self.left_out_noncentrality)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "FitTerms":
        """From :meth:`as_dict` (or a plan.json's ``fit_terms``); unknown keys are refused by name."""
        allowed = {f.name for f in fields(cls)}
        bad = sorted(set(d) - allowed)
        if bad:
            raise ValueError(f"fit terms: unknown key(s) {', '.join(bad)}; allowed: {', '.join(sorted(allowed))}")
        h = d.get("harmonics", 0)
        if not isinstance(h, int) or isinstance(h, bool) or not 0 <= h <= MAX_HARMONICS:
            raise ValueError(f"fit terms: harmonics must be an integer in [0, {MAX_HARMONICS}]; got {h!r}")
        for k in OPTIONAL_TERMS:
            if k in d and not isinstance(d[k], bool):
                raise ValueError(f"fit terms: {k} must be true or false; got {d[k]!r}")
        d = dict(d)
        lam = d.pop("left_out_noncentrality", {}) or {}
        if not isinstance(lam, dict):
            raise ValueError(f"fit terms: left_out_noncentrality must be an object {{term: chi-square change}}; got {lam!r}")
        for k, v in lam.items():
            if k not in ("harmonics",) + OPTIONAL_TERMS:
                raise ValueError(f"fit terms: left_out_noncentrality has unknown term {k!r}; allowed: harmonics, "
                                 + ", ".join(OPTIONAL_TERMS))
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"fit terms: left_out_noncentrality.{k} must be a number >= 0; got {v!r}")
        return cls(**d, left_out_noncentrality=tuple(lam.items()))

    def describe(self) -> str:
        parts = [f"{self.harmonics} nutation harmonic(s)" if self.harmonics else "no nutation"]
        parts += [name for name, on in (("transient", self.transient), ("elliptical cone", self.precession_second),
                                        ("nutation sidebands", self.sidebands),
                                        ("persistent oscillation", self.persistent),
                                        ("third-order nutation", self.third_order),
                                        ("drifting nutation shape", self.shape_drift)) if on]
        return ", ".join(parts)


@dataclass(frozen=True)
class _Selector:
    """How fit_model decides whether to add a term."""

    #: terms planned in advance: kept whenever they converge
    terms: FitTerms | None = None
    #: noiseless data: keep a term whose chi-square change exceeds this (instead of the p-value test)
    noncentrality: float | None = None

    def need(self, ddof: int, flag: str = "", k: int = 0) -> float:
        """The chi-square change that adds a term of ``ddof`` parameters.

        On noisy data: the p < TERM_P_VALUE point of chi-square(ddof); for a term the plan left out
        although it changed the plan's noiseless chi-square by lambda, the same point of the
        non-central chi-square(ddof, lambda): a record adds it only when it needs the term more than
        the plan's own simulated motion does (the plan weighed that term and left it out)."""
        if self.noncentrality is not None:
            return self.noncentrality
        need = float(chi2.isf(TERM_P_VALUE, ddof))
        lam = 0.0
        if self.terms is not None and flag and (flag != "harmonics" or k == self.terms.harmonics + 1):
            lam = self.terms.noncentrality(flag)
        return max(need, float(ncx2.isf(TERM_P_VALUE, ddof, lam))) if lam > 0 else need

    def planned(self, flag: str, k: int = 0) -> bool:
        if self.terms is None:
            return False
        return k <= self.terms.harmonics if flag == "harmonics" else bool(getattr(self.terms, flag))

    def wants(self, ref: _Solved, sol: _Solved, flag: str, notes: list[str], note: str, k: int = 0) -> bool:
        """Keep ``sol`` (``ref`` plus a term)?  Planned terms stay if they converge; others by the test."""
        planned = self.planned(flag, k)
        if not sol.ok:
            if planned:
                notes.append(f"the planned term ({note}) did not converge and is left out: {sol.message}")
            return False
        if planned:
            return True
        if ref.chi2 - sol.chi2 > self.need(ref.dof - sol.dof, flag, k):
            if self.terms is not None:
                grown = _degenerate_growth(ref, sol)
                if grown is not None:
                    notes.append(f"the data ask for a term the plan did not have ({note}), but on this record it "
                                 f"cannot be told apart from the planned model (the error of {grown[0]} would grow "
                                 f"{grown[1]:.3g}x): it is left out")
                    return False
                notes.append(f"the data need a term the plan did not have ({note}): it is added")
            return True
        return False


#: an unplanned term that would widen the error of a parameter of the planned model by more than
#: this factor is not identifiable on the record: it is left out (B2 over 2 s at 640x480, 1 record
#: in 200: an unplanned persistent oscillation gained chi-square 28 by cancelling against a shape
#: drift 2e4 times its planned size, widening the amplitude's error 18x)
DEGENERATE_SE_GROWTH = 5.0


def _degenerate_growth(ref: _Solved, sol: _Solved) -> tuple[str, float] | None:
    """The parameter of ``ref`` whose standard error grows most in ``sol`` (``ref`` plus a term), with
    the factor, when that exceeds :data:`DEGENERATE_SE_GROWTH`; else None."""
    names_ref, names_sol = _Model(ref.spec).names, _Model(sol.spec).index
    worst = (None, 1.0)
    for i, n in enumerate(names_ref):
        j = names_sol.get(n)
        if j is None or not ref.cov[i, i] > 0:
            continue
        g = math.sqrt(max(sol.cov[j, j], 0.0) / ref.cov[i, i])
        if g > worst[1]:
            worst = (n, g)
    return worst if worst[0] is not None and worst[1] > DEGENERATE_SE_GROWTH else None


@dataclass(frozen=True)
class FitData:
    """Measurements for the fit: times, angles and the whitening factor of each frame."""

    frame: np.ndarray
    t_s: np.ndarray
    theta_rad: np.ndarray
    phi_rad: np.ndarray
    cov: np.ndarray  # (n, 2, 2)
    segment: np.ndarray  # (n,) int
    t_ref_s: float
    #: (m, n, 2) angle shifts (theta, phi) of each frame for a one-sigma move of camera mode k
    camera_shift: np.ndarray | None = None
    #: (n,) exposure of each frame [s], ``t_s`` at its middle: the model is averaged over it
    #: (a blurred spot's centroid is the mean position over the exposure, which shrinks an
    #: oscillation of angular frequency w by sinc(w T / 2)); None: instantaneous samples
    exposure_s: np.ndarray | None = None

    @property
    def camera_modes(self) -> int:
        return 0 if self.camera_shift is None else int(self.camera_shift.shape[0])

    @property
    def n(self) -> int:
        return len(self.t_s)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    @property
    def nyquist_rad_s(self) -> float:
        dt = float(np.median(np.diff(self.t_s)))
        return math.pi / dt


@dataclass(frozen=True)
class Quantity:
    """One fitted quantity with what theory says about it."""

    name: str
    units: str
    value: float | None
    standard_error: float | None
    status: str  # "determined" | "undetermined" | "not in scene"
    reason: str = ""
    paper: float | None = None
    corrected: float | None = None
    exact: float | None = None
    exact_source: str = ""
    diff_paper_se: float | None = None
    diff_exact_se: float | None = None
    truth: float | None = None
    pull: float | None = None
    note: str = ""
    #: the Cramer-Rao bound of the fit model for the tracker's errors ((J^T J)^-1, before any
    #: chi-square scaling or bootstrap)
    formal_standard_error: float | None = None
    #: the camera model's share of the standard error (in quadrature; 0 for an exact camera)
    camera_standard_error: float | None = None

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_angles`."""

    spec: ModelSpec
    params: dict[str, tuple[float, float]]
    quantities: dict[str, Quantity]
    chi2: float
    dof: int
    residuals: pd.DataFrame
    model_curve: pd.DataFrame
    t_ref_s: float
    errors: str  # "formal" | "bootstrap" | "formal x sqrt(chi2_red)"
    notes: tuple[str, ...] = ()
    x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    wall_time_s: float = 0.0
    #: how the optional model terms were chosen
    terms: FitTerms | None = None
    #: phase left uncertain at the record's ends by each rate-like parameter (:func:`phase_uncertainty`)
    phase_uncertainty_rad: dict[str, float] = field(default_factory=dict)

    @property
    def linear_regime(self) -> bool:
        """True when every rate-like parameter is known well enough for the errors to be Cramer-Rao bounds."""
        return all(v <= NONLINEAR_PHASE_RAD for v in self.phase_uncertainty_rad.values())

    @property
    def chi2_red(self) -> float:
        return self.chi2 / max(self.dof, 1)

    def summary(self) -> dict:
        return {
            "model": {"fit_axis": self.spec.fit_axis, "damped": self.spec.damped,
                      "nutation_harmonics": self.spec.harmonics, "azimuth_segments": self.spec.segments,
                      "transient": self.spec.transient, "elliptical_cone": self.spec.precession_second,
                      "nutation_sidebands": self.spec.sidebands, "persistent_oscillation": self.spec.persistent,
                      "third_order_nutation": self.spec.third_order, "nutation_shape_drift": self.spec.shape_drift,
                      "camera_modes": self.spec.camera_modes,
                      "terms_chosen": self.terms.source if self.terms is not None else "",
                      "linear_regime": self.linear_regime, "phase_uncertainty_rad": dict(self.phase_uncertainty_rad)},
            "t_ref_s": self.t_ref_s, "chi2": self.chi2, "dof": self.dof, "chi2_red": self.chi2_red,
            "errors": self.errors, "notes": list(self.notes),
            "quantities": {k: q.as_dict() for k, q in self.quantities.items()},
            "parameters": {k: {"value": v, "standard_error": s} for k, (v, s) in self.params.items()},
            "wall_time_s": self.wall_time_s,
        }


# ------------------------------------------------------------------------------------------ geometry
def _axis_rotation(alpha: float, beta: float) -> np.ndarray:
    """Rotation taking z to n = (sin a sin b, -sin a cos b, cos a): Rz(b) Rx(a)."""
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    rx = np.array([[1.0, 0, 0], [0, ca, -sa], [0, sa, ca]])
    rz = np.array([[cb, -sb, 0], [sb, cb, 0], [0, 0, 1.0]])
    return rz @ rx


def _tip(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    s = np.sin(theta)
    return np.stack([s * np.sin(phi), -s * np.cos(phi), np.cos(theta)], axis=-1)


def _angles(tip: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x, y, z = tip[..., 0], tip[..., 1], tip[..., 2]
    return np.arctan2(np.hypot(x, y), z), np.arctan2(x, -y)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------------------------------- the model
class _Model:
    """Evaluates the fit model of a :class:`ModelSpec` on given times."""

    def __init__(self, spec: ModelSpec):
        self.spec = spec
        self.names = spec.names()
        self.index = {n: i for i, n in enumerate(self.names)}

    def envelope(self, p: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The damped nutation's envelope, 1 at the first frame: ``exp(-mu (tau - tau0))``."""
        return np.exp(-p[self.index["nutation_decay_rate_per_s"]] * (tau - self.spec.nutation_origin_s))

    def nutation_phase(self, p: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """``psi = w tau (+ w' tau^2 / 2 when damped)``."""
        psi = p[self.index["nutation_frequency_rad_s"]] * tau
        if self.spec.damped:
            psi = psi + 0.5 * p[self.index["nutation_chirp_rad_s2"]] * tau**2
        return psi

    def axis_frame(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray):
        """theta', phi' in the axis frame."""
        s, ix = self.spec, self.index
        slow = p[ix["log_cone_angle"]]
        if s.damped:
            slow = slow + p[ix["tilt_growth_rate_per_s"]] * tau + p[ix["tilt_growth_curvature_per_s2"]] * tau**2
        th = np.exp(slow) * np.ones_like(tau)
        offsets = p[[ix[f"azimuth_offset_{k}_rad"] for k in range(s.segments)]]
        ph = offsets[segment] + p[ix["precession_rate_rad_s"]] * tau
        if s.damped:
            ph = ph + 0.5 * p[ix["precession_acceleration_rad_s2"]] * tau**2
        if s.harmonics:
            env1 = self.envelope(p, tau) if s.damped else np.ones_like(tau)
            if s.damped:
                # second order in the decaying amplitude: the mean tilt and the mean
                # precession rate shift with amplitude^2, so these decay twice as fast
                env2 = env1 * env1
                th = th + p[ix["tilt_decaying_offset_rad"]] * env2
                ph = ph + p[ix["azimuth_decaying_offset_rad"]] * env2
            env = env1
            psi = self.nutation_phase(p, tau)  # damped: the frequency follows the tilt (a chirp)
            for k in range(1, s.harmonics + 1):
                c, sn = np.cos(k * psi), np.sin(k * psi)
                th = th + env * (p[ix[f"tilt_cos_{k}_rad"]] * c + p[ix[f"tilt_sin_{k}_rad"]] * sn)
                ph = ph + env * (p[ix[f"azimuth_cos_{k}_rad"]] * c + p[ix[f"azimuth_sin_{k}_rad"]] * sn)
                if s.damped:
                    env = env * env1  # harmonic k of a decaying oscillation decays k times as fast
        if s.damped and s.fit_axis:
            # damping that is symmetric about the lab vertical, not about the tilted cone axis,
            # makes the cone uneven: terms locked to the precession phase
            cp, sp = np.cos(p[ix["precession_rate_rad_s"]] * tau), np.sin(p[ix["precession_rate_rad_s"]] * tau)
            ph = ph + p[ix["azimuth_precession_cos_rad"]] * cp + p[ix["azimuth_precession_sin_rad"]] * sp
        if s.persistent:
            # under damping the drifting slow mode keeps a small undamped oscillation near the
            # nutation frequency alive (found in the simulator: B2 rig, ~3e-5 rad)
            wp = p[ix["persistent_frequency_rad_s"]]
            c, sn = np.cos(wp * tau), np.sin(wp * tau)
            th = th + p[ix["persistent_tilt_cos_rad"]] * c + p[ix["persistent_tilt_sin_rad"]] * sn
            ph = ph + p[ix["persistent_azimuth_cos_rad"]] * c + p[ix["persistent_azimuth_sin_rad"]] * sn
        if s.transient:
            e = np.exp(-s.transient_rate(p[ix["transient_rate_logit"]]) * (tau - s.nutation_origin_s))
            th = th + p[ix["transient_tilt_rad"]] * e
            ph = ph + p[ix["transient_azimuth_rad"]] * e
        if s.sidebands:
            psi = self.nutation_phase(p, tau)
            env1 = self.envelope(p, tau)
            for side, sign in (("upper", 1.0), ("lower", -1.0)):
                arg = psi + sign * p[ix["precession_rate_rad_s"]] * tau
                c, sn = env1 * np.cos(arg), env1 * np.sin(arg)
                th = th + p[ix[f"tilt_{side}_cos_rad"]] * c + p[ix[f"tilt_{side}_sin_rad"]] * sn
                ph = ph + p[ix[f"azimuth_{side}_cos_rad"]] * c + p[ix[f"azimuth_{side}_sin_rad"]] * sn
        if s.shape_drift:
            f = (tau - s.nutation_origin_s) * self.envelope(p, tau)
            psi = self.nutation_phase(p, tau)
            (at, bt, ap, bp), _ = self._shape_drift(p)
            c, sn = f * np.cos(psi), f * np.sin(psi)
            th = th + at * c + bt * sn
            ph = ph + ap * c + bp * sn
        extras = self._nutation_extras(tau)
        if extras:
            env1, psi = self.envelope(p, tau), self.nutation_phase(p, tau)
        for stem, unit, factor, power in extras:
            f = factor * env1**power
            c, sn = f * np.cos(psi), f * np.sin(psi)
            th = th + p[ix[f"tilt_{stem}_cos_{unit}"]] * c + p[ix[f"tilt_{stem}_sin_{unit}"]] * sn
            ph = ph + p[ix[f"azimuth_{stem}_cos_{unit}"]] * c + p[ix[f"azimuth_{stem}_sin_{unit}"]] * sn
        if s.precession_second:
            c2, s2 = np.cos(2 * p[ix["precession_rate_rad_s"]] * tau), np.sin(2 * p[ix["precession_rate_rad_s"]] * tau)
            th = th + p[ix["tilt_precession2_cos_rad"]] * c2 + p[ix["tilt_precession2_sin_rad"]] * s2
            ph = ph + p[ix["azimuth_precession2_cos_rad"]] * c2 + p[ix["azimuth_precession2_sin_rad"]] * s2
        return th, ph

    def axis_frame_jacobian(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray):
        """d(theta')/dp and d(phi')/dp, each (n, P), analytic (axis columns zero)."""
        s, ix = self.spec, self.index
        n, P = len(tau), len(p)
        dth = np.zeros((n, P))
        dph = np.zeros((n, P))
        slow = p[ix["log_cone_angle"]]
        if s.damped:
            slow = slow + p[ix["tilt_growth_rate_per_s"]] * tau + p[ix["tilt_growth_curvature_per_s2"]] * tau**2
        e = np.exp(slow) * np.ones_like(tau)
        dth[:, ix["log_cone_angle"]] = e
        dph[:, ix["precession_rate_rad_s"]] = tau
        for k in range(s.segments):
            dph[:, ix[f"azimuth_offset_{k}_rad"]] = segment == k
        if s.damped:
            dth[:, ix["tilt_growth_rate_per_s"]] = tau * e
            dth[:, ix["tilt_growth_curvature_per_s2"]] = tau**2 * e
            dph[:, ix["precession_acceleration_rad_s2"]] = 0.5 * tau**2
        if s.harmonics:
            dt0 = tau - s.nutation_origin_s
            env1 = self.envelope(p, tau) if s.damped else np.ones_like(tau)
            psi = self.nutation_phase(p, tau)
            if s.damped:
                env2 = env1 * env1
                a0, c0 = p[ix["tilt_decaying_offset_rad"]], p[ix["azimuth_decaying_offset_rad"]]
                dth[:, ix["tilt_decaying_offset_rad"]] = env2
                dph[:, ix["azimuth_decaying_offset_rad"]] = env2
                dth[:, ix["nutation_decay_rate_per_s"]] += -2 * dt0 * env2 * a0
                dph[:, ix["nutation_decay_rate_per_s"]] += -2 * dt0 * env2 * c0
            env = env1
            for k in range(1, s.harmonics + 1):
                c, sn = np.cos(k * psi), np.sin(k * psi)
                a, b = p[ix[f"tilt_cos_{k}_rad"]], p[ix[f"tilt_sin_{k}_rad"]]
                cc, dd = p[ix[f"azimuth_cos_{k}_rad"]], p[ix[f"azimuth_sin_{k}_rad"]]
                dth[:, ix[f"tilt_cos_{k}_rad"]] = env * c
                dth[:, ix[f"tilt_sin_{k}_rad"]] = env * sn
                dph[:, ix[f"azimuth_cos_{k}_rad"]] = env * c
                dph[:, ix[f"azimuth_sin_{k}_rad"]] = env * sn
                dpsi_t = env * k * (-a * sn + b * c)  # d/d psi of the tilt term
                dpsi_p = env * k * (-cc * sn + dd * c)
                dth[:, ix["nutation_frequency_rad_s"]] += dpsi_t * tau
                dph[:, ix["nutation_frequency_rad_s"]] += dpsi_p * tau
                if s.damped:
                    dth[:, ix["nutation_chirp_rad_s2"]] += dpsi_t * 0.5 * tau**2
                    dph[:, ix["nutation_chirp_rad_s2"]] += dpsi_p * 0.5 * tau**2
                    dth[:, ix["nutation_decay_rate_per_s"]] += -k * dt0 * env * (a * c + b * sn)
                    dph[:, ix["nutation_decay_rate_per_s"]] += -k * dt0 * env * (cc * c + dd * sn)
                    env = env * env1
        if s.damped and s.fit_axis:
            self._sinusoid_columns(p, tau, dth, dph, "precession_rate_rad_s", "precession")
        if s.persistent:
            self._sinusoid_columns(p, tau, dth, dph, "persistent_frequency_rad_s", "persistent")
        if s.transient:
            u = p[ix["transient_rate_logit"]]
            dt0 = tau - s.nutation_origin_s
            e = np.exp(-s.transient_rate(u) * dt0)
            sg = expit(u)
            dk = (s.transient_max_rate_per_s - s.transient_min_rate_per_s) * sg * (1 - sg)
            dth[:, ix["transient_tilt_rad"]] = e
            dph[:, ix["transient_azimuth_rad"]] = e
            dth[:, ix["transient_rate_logit"]] = -dk * dt0 * e * p[ix["transient_tilt_rad"]]
            dph[:, ix["transient_rate_logit"]] = -dk * dt0 * e * p[ix["transient_azimuth_rad"]]
        if s.sidebands:
            psi = self.nutation_phase(p, tau)
            dt0 = tau - s.nutation_origin_s
            env1 = self.envelope(p, tau)
            for side, sign in (("upper", 1.0), ("lower", -1.0)):
                arg = psi + sign * p[ix["precession_rate_rad_s"]] * tau
                c, sn = env1 * np.cos(arg), env1 * np.sin(arg)
                for d, q in ((dth, "tilt"), (dph, "azimuth")):
                    a, b = p[ix[f"{q}_{side}_cos_rad"]], p[ix[f"{q}_{side}_sin_rad"]]
                    d[:, ix[f"{q}_{side}_cos_rad"]] = c
                    d[:, ix[f"{q}_{side}_sin_rad"]] = sn
                    darg = -a * sn + b * c  # d/d arg
                    d[:, ix["nutation_frequency_rad_s"]] += darg * tau
                    d[:, ix["nutation_chirp_rad_s2"]] += darg * 0.5 * tau**2
                    d[:, ix["precession_rate_rad_s"]] += darg * sign * tau
                    d[:, ix["nutation_decay_rate_per_s"]] += -dt0 * (a * c + b * sn)
        if s.precession_second:
            self._sinusoid_columns(p, tau, dth, dph, "precession_rate_rad_s", "precession2", factor=2.0)
        if s.shape_drift:
            dt0 = tau - s.nutation_origin_s
            f = dt0 * self.envelope(p, tau)
            psi = self.nutation_phase(p, tau)
            c, sn = f * np.cos(psi), f * np.sin(psi)
            (at, bt, ap, bp), (names, dcoef) = self._shape_drift(p)
            for j, name in enumerate(names):
                dth[:, ix[name]] += dcoef[0, j] * c + dcoef[1, j] * sn
                dph[:, ix[name]] += dcoef[2, j] * c + dcoef[3, j] * sn
            for d, a, b in ((dth, at, bt), (dph, ap, bp)):
                dpsi = -a * sn + b * c
                d[:, ix["nutation_frequency_rad_s"]] += dpsi * tau
                d[:, ix["nutation_chirp_rad_s2"]] += dpsi * 0.5 * tau**2
                d[:, ix["nutation_decay_rate_per_s"]] += -dt0 * (a * c + b * sn)
        extras = self._nutation_extras(tau)
        if extras:
            dt0 = tau - s.nutation_origin_s
            env1, psi = self.envelope(p, tau), self.nutation_phase(p, tau)
        for stem, unit, factor, power in extras:
            f = factor * env1**power
            c, sn = f * np.cos(psi), f * np.sin(psi)
            for d, q in ((dth, "tilt"), (dph, "azimuth")):
                nc, ns = f"{q}_{stem}_cos_{unit}", f"{q}_{stem}_sin_{unit}"
                a, b = p[ix[nc]], p[ix[ns]]
                d[:, ix[nc]] = c
                d[:, ix[ns]] = sn
                dpsi = -a * sn + b * c
                d[:, ix["nutation_frequency_rad_s"]] += dpsi * tau
                d[:, ix["nutation_chirp_rad_s2"]] += dpsi * 0.5 * tau**2
                d[:, ix["nutation_decay_rate_per_s"]] += -power * dt0 * (a * c + b * sn)
        return dth, dph

    def _nutation_extras(self, tau: np.ndarray) -> list[tuple[str, str, np.ndarray, int]]:
        """Damped-nutation terms at the fundamental beyond the harmonics, with four free coefficients:
        (name stem, amplitude unit, factor, envelope power).

        ``third_order``: ``e^{-3 mu (tau - tau0)}`` (third order in the amplitude)."""
        s = self.spec
        out = []
        if s.third_order:
            out.append(("third", "rad", np.ones_like(tau), 3))
        return out

    def _shape_drift(self, p: np.ndarray) -> tuple[tuple[float, float, float, float], tuple[list[str], np.ndarray]]:
        """The drifting shape's coefficients of ``f cos psi, f sin psi`` in tilt and azimuth
        ``(A_t, B_t, A_p, B_p)`` (see :data:`SHAPE_DRIFT_NAMES`), and their derivatives (4 x 6) with
        respect to the parameters they depend on (``s`` and the fundamental's amplitudes)."""
        ix = self.index
        sr, si = (p[ix[n]] for n in SHAPE_DRIFT_NAMES)
        fund = ["tilt_cos_1_rad", "tilt_sin_1_rad", "azimuth_cos_1_rad", "azimuth_sin_1_rad"]
        a, b, c, d = (p[ix[n]] for n in fund)
        # u_t = -s conj(z_p), u_p = s conj(z_t); a term Re[u e^{i psi}] = Re(u) cos psi - Im(u) sin psi
        coef = (-(sr * c - si * d), sr * d + si * c, sr * a - si * b, -(sr * b + si * a))
        #              d/d sr, si,  a,   b,   c,   d
        dcoef = np.array([[-c, d, 0.0, 0.0, -sr, si],
                          [d, c, 0.0, 0.0, si, sr],
                          [a, -b, sr, -si, 0.0, 0.0],
                          [-b, -a, -si, -sr, 0.0, 0.0]])
        return coef, (list(SHAPE_DRIFT_NAMES) + fund, dcoef)

    def _sinusoid_columns(self, p, tau, dth, dph, freq: str, stem: str, factor: float = 1.0) -> None:
        """Columns of a pair of sinusoids ``X_cos cos(f w tau) + X_sin sin(f w tau)`` in tilt and azimuth
        (or in the azimuth only, when the model has no tilt pair).

        ``stem`` names the amplitudes (``tilt_<stem>_cos_rad`` ..., or ``<stem>_tilt_cos_rad``
        ...); their derivative with respect to the frequency parameter ``freq`` is added.
        """
        ix = self.index
        prefixed = f"azimuth_{stem}_cos_rad" in ix
        names = ([f"tilt_{stem}_cos_rad", f"tilt_{stem}_sin_rad", f"azimuth_{stem}_cos_rad", f"azimuth_{stem}_sin_rad"]
                 if prefixed else
                 [f"{stem}_tilt_cos_rad", f"{stem}_tilt_sin_rad", f"{stem}_azimuth_cos_rad", f"{stem}_azimuth_sin_rad"])
        w = factor * p[ix[freq]]
        c, sn = np.cos(w * tau), np.sin(w * tau)
        for d, (nc, ns) in ((dth, names[:2]), (dph, names[2:])):
            if nc not in ix:
                continue
            d[:, ix[nc]] = c
            d[:, ix[ns]] = sn
            d[:, ix[freq]] += factor * tau * (-p[ix[nc]] * sn + p[ix[ns]] * c)

    def lab_jacobian(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray):
        """d(theta, phi)_lab / dp, each (n, P): analytic in the axis frame, chain rule to the lab."""
        dth, dph = self.axis_frame_jacobian(p, tau, segment)
        if not self.spec.fit_axis:
            return dth, dph
        ix = self.index
        th, ph = self.axis_frame(p, tau, segment)
        a, b = p[ix["axis_tilt_rad"]], p[ix["axis_azimuth_rad"]]

        def conv(t_, p_, a_=a, b_=b):
            return _angles(_tip(t_, p_) @ _axis_rotation(a_, b_).T)

        h = 1e-7
        tp, pp = conv(th + h, ph)
        tm, pm = conv(th - h, ph)
        g00, g10 = (tp - tm) / (2 * h), _wrap(pp - pm) / (2 * h)
        tp, pp = conv(th, ph + h)
        tm, pm = conv(th, ph - h)
        g01, g11 = (tp - tm) / (2 * h), _wrap(pp - pm) / (2 * h)
        jt = g00[:, None] * dth + g01[:, None] * dph
        jp = g10[:, None] * dth + g11[:, None] * dph
        for name, da, db in (("axis_tilt_rad", h, 0.0), ("axis_azimuth_rad", 0.0, h)):
            tp, pp = conv(th, ph, a + da, b + db)
            tm, pm = conv(th, ph, a - da, b - db)
            jt[:, ix[name]] = (tp - tm) / (2 * h)
            jp[:, ix[name]] = _wrap(pp - pm) / (2 * h)
        return jt, jp

    def lab(self, p: np.ndarray, tau: np.ndarray, segment: np.ndarray):
        th, ph = self.axis_frame(p, tau, segment)
        if not self.spec.fit_axis:
            return th, ph
        R = _axis_rotation(p[self.index["axis_tilt_rad"]], p[self.index["axis_azimuth_rad"]])
        return _angles(_tip(th, ph) @ R.T)


def _whitener(cov: np.ndarray) -> np.ndarray:
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


def _residual_fn(model: _Model, data: FitData):
    """Raw residuals (theta, phi) and whitened ones (2n, then one prior residual per camera mode)."""
    tau = data.t_s - data.t_ref_s
    W = _whitener(data.cov)
    m = model.spec.camera_modes
    if m and data.camera_modes != m:
        raise FitError(f"the model has {m} camera modes, the data {data.camera_modes}")
    S = data.camera_shift if m else None

    ex = data.exposure_s
    if ex is not None and np.any(ex > 0):
        # mean over the exposure by two-point Gauss-Legendre: exact for a cubic, for a sinusoid
        # of angular frequency w off by (w T)^4 / 2900 (1e-11 at 59 rad/s and 300 us)
        half = ex / (2.0 * math.sqrt(3.0))
        taus = (tau - half, tau + half)
    else:
        taus = None

    def lab(p):
        if taus is None:
            return model.lab(p, tau, data.segment)
        (t1, p1), (t2, p2) = (model.lab(p, tt, data.segment) for tt in taus)
        return 0.5 * (t1 + t2), p1 + 0.5 * _wrap(p2 - p1)

    def lab_jacobian(p):
        if taus is None:
            return model.lab_jacobian(p, tau, data.segment)
        (a1, b1), (a2, b2) = (model.lab_jacobian(p, tt, data.segment) for tt in taus)
        return 0.5 * (a1 + a2), 0.5 * (b1 + b2)

    def raw(p):
        th, ph = lab(p)
        if m:
            a = p[-m:]
            th = th + np.tensordot(a, S[:, :, 0], axes=1)
            ph = ph + np.tensordot(a, S[:, :, 1], axes=1)
        return data.theta_rad - th, _wrap(data.phi_rad - ph)

    def white(p):
        r0, r1 = raw(p)
        parts = [W[:, 0, 0] * r0, W[:, 1, 0] * r0 + W[:, 1, 1] * r1]
        if m:
            parts.append(p[-m:])  # unit Gaussian prior on each camera mode
        return np.concatenate(parts)

    def white_jac(p):
        jt, jp = lab_jacobian(p)
        if m:
            jt[:, -m:] = S[:, :, 0].T
            jp[:, -m:] = S[:, :, 1].T
        J = -np.concatenate([W[:, 0, 0, None] * jt, W[:, 1, 0, None] * jt + W[:, 1, 1, None] * jp])
        if m:
            prior = np.zeros((m, J.shape[1]))
            prior[:, -m:] = np.eye(m)
            J = np.vstack([J, prior])
        return J

    white.jac = white_jac

    return raw, white


# -------------------------------------------------------------------------------------------- inputs
def fit_data_from_angles(angles: pd.DataFrame, exclude: np.ndarray | None = None,
                         precession_hint_rad_s: float | None = None) -> FitData:
    """Measured frames of an angle table (minus ``exclude``, e.g. the smoother's outliers)."""
    need = ("t_s", "theta_rad", "phi_rad", "theta_sigma_rad", "phi_sigma_rad")
    missing = [c for c in need if c not in angles.columns]
    if missing:
        raise FitError(f"angle table lacks column(s) {missing}; required: {list(need)}")
    ok = np.isfinite(angles["theta_rad"].to_numpy(float)) & np.isfinite(angles["phi_rad"].to_numpy(float))
    if exclude is not None:
        ok &= ~np.asarray(exclude, bool)
    a = angles.loc[ok]
    if len(a) < 10:
        raise FitError(f"only {len(a)} frames have usable angles; a fit needs at least 10")
    sth = a["theta_sigma_rad"].to_numpy(float)
    sph = a["phi_sigma_rad"].to_numpy(float)
    if not (np.all(np.isfinite(sth)) and np.all(np.isfinite(sph)) and np.all(sth > 0) and np.all(sph > 0)):
        raise FitError("theta_sigma_rad and phi_sigma_rad must be finite and > 0 wherever there are angles")
    cov = measurement_covariance(sth, sph, a["theta_phi_corr"] if "theta_phi_corr" in a.columns else None)
    t = a["t_s"].to_numpy(float)
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise FitError("t_s must be finite and non-decreasing")
    frame = a["frame"].to_numpy() if "frame" in a.columns else np.arange(len(a))
    shift = None
    k_modes = 0
    while f"theta_cam_{k_modes + 1}_rad" in a.columns and f"phi_cam_{k_modes + 1}_rad" in a.columns:
        k_modes += 1
    if k_modes:
        shift = np.stack([np.column_stack([a[f"theta_cam_{k}_rad"].to_numpy(float), a[f"phi_cam_{k}_rad"].to_numpy(float)])
                          for k in range(1, k_modes + 1)])
        if not np.all(np.isfinite(shift)):
            raise FitError("theta_cam_k_rad / phi_cam_k_rad (camera modes) must be finite wherever there are angles")
    exposure = None
    if "exposure_s" in a.columns:
        exposure = a["exposure_s"].to_numpy(float)
        if not (np.all(np.isfinite(exposure)) and np.all(exposure >= 0)):
            raise FitError("exposure_s must be finite and >= 0 wherever there are angles")
        frame_interval = float(np.median(np.diff(t))) if len(t) > 1 else np.inf
        if np.any(exposure > 1.5 * frame_interval):
            raise FitError(f"exposure_s reaches {exposure.max():.3g} s, longer than the frame interval "
                           f"({frame_interval:.3g} s, median): not an exposure time")
    segment = np.zeros(len(a), int)
    if precession_hint_rad_s is not None and precession_hint_rad_s != 0:
        half_period = math.pi / abs(precession_hint_rad_s)
        segment = np.concatenate([[0], np.cumsum(np.diff(t) > half_period)])
    return FitData(frame=frame, t_s=t, theta_rad=a["theta_rad"].to_numpy(float), phi_rad=a["phi_rad"].to_numpy(float),
                   cov=cov, segment=segment, t_ref_s=0.5 * (t[0] + t[-1]), camera_shift=shift,
                   exposure_s=exposure)


@dataclass(frozen=True)
class SceneModel:
    """What the scene says the fit should contain."""

    spec: ModelSpec
    nutation_expected: bool
    nutation_frequency_hint_rad_s: float | None
    precession_hint_rad_s: float | None
    reasons: tuple[str, ...] = ()


def model_for_scene(protocol: Protocol, prediction: dict | None = None) -> SceneModel:
    """The fit model the scene calls for, with hints from theory (never used as fitted values)."""
    gravity = bool(protocol.rig.gravity_m_s2)
    acc = protocol.pivot.acceleration
    accelerating = acc is not None and any(any(v != 0 for v in a) for a in acc.acceleration_m_s2)
    damped = bool(protocol.pivot.damping)
    pred = prediction or {}
    reasons = []
    if accelerating and not acc.is_constant:
        reasons.append("the pivot acceleration varies in time: no fixed equilibrium direction to fit; the "
                       "cone axis is fitted as if constant")
    fit_axis = accelerating or not gravity
    nut = pred.get("nutation_frequency_rad_s", {}).get("exact") if gravity else None
    prec_key = "mean_precession_rate_rad_s" if gravity else "precession_rate_rad_s"
    prec = pred.get(prec_key, {}).get("exact")
    spec = ModelSpec(fit_axis=fit_axis, damped=damped)  # nutation terms: chosen by the data in fit_model
    return SceneModel(spec=spec, nutation_expected=gravity, nutation_frequency_hint_rad_s=nut,
                      precession_hint_rad_s=prec, reasons=tuple(reasons))


# ------------------------------------------------------------------------------------ initial values
def _linear_start(spec: ModelSpec, data: FitData, axis: tuple[float, float] | None) -> dict[str, float]:
    tau = data.t_s - data.t_ref_s
    if axis is not None:
        R = _axis_rotation(*axis)
        th, ph = _angles(_tip(data.theta_rad, data.phi_rad) @ R)
    else:
        th, ph = data.theta_rad, data.phi_rad
    start: dict[str, float] = {}
    if axis is not None:
        start["axis_tilt_rad"], start["axis_azimuth_rad"] = axis
    # azimuth: unwrap within segments, common slope (and curvature) with per-segment offsets
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


def _dominant_frequency(t: np.ndarray, y: np.ndarray, w_max: float, hint: float | None) -> float:
    """Peak of the periodogram of y (resampled on a uniform grid), refined by interpolation."""
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1], dt)
    yy = np.interp(grid, t, y)
    yy = (yy - yy.mean()) * np.hanning(len(yy))
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


# ------------------------------------------------------------------------------------------ fitting
@dataclass
class _Solved:
    spec: ModelSpec
    x: np.ndarray
    cov: np.ndarray
    chi2: float
    dof: int
    ok: bool
    message: str


def _solve(spec: ModelSpec, data: FitData, start: dict[str, float], *, near: bool = False) -> _Solved:
    """Least-squares fit of ``spec`` from ``start``.

    ``near``: the start is a converged model plus a new term's amplitudes at their conditional
    least-squares values (a trial term): Gauss-Newton is tried first, and Levenberg-Marquardt
    only if it does not reach a stationary point (from such a start LM can spend thousands of
    evaluations creeping to where a few Gauss-Newton steps go).
    """
    model = _Model(spec)
    x0 = np.array([start.get(n, 0.0) for n in model.names], float)
    _, white = _residual_fn(model, data)
    n_res = 2 * data.n + spec.camera_modes  # the priors add a residual per camera mode
    if n_res <= len(x0):
        raise FitError(f"{data.n} frames are too few for a model with {len(x0)} parameters")
    if near:
        with np.errstate(over="ignore", invalid="ignore"):
            r0 = white(x0)
        if np.all(np.isfinite(r0)):
            x, r, J = _gauss_newton_polish(white, x0, r0, white.jac(x0), max_steps=60)
            if _remaining_step_se(J, r) < STATIONARY_STEP_SE and np.all(np.isfinite(x)):
                cov = np.linalg.pinv(J.T @ J, rcond=1e-14, hermitian=True)
                return _Solved(spec, x, cov, float(r @ r), n_res - len(x0), True, "Gauss-Newton from a near start")
            x0 = x
    # Levenberg-Marquardt with a modest budget, then undamped Gauss-Newton; again from there
    # until one more step would move no parameter by STATIONARY_STEP_SE (LM alone can crawl
    # for 10^4 steps in these models).
    # Where the model is far from quadratic over one standard error (a term whose amplitude is
    # ~0 leaves its rate free), the Gauss-Newton step can point 1 s.e. away while no step
    # lowers the chi-square: a round of both solvers that gains nothing also ends it.
    x = x0
    chi2_prev = math.inf
    for _round in range(4):
        res = least_squares(white, x, jac=white.jac, method="lm", x_scale="jac", xtol=LM_TOL, ftol=LM_TOL,
                            gtol=LM_TOL, max_nfev=50 * (len(x0) + 1))
        x, r, J = _gauss_newton_polish(white, res.x, res.fun, res.jac)
        chi2_now = float(r @ r)
        stationary = (_remaining_step_se(J, r) < STATIONARY_STEP_SE
                      or chi2_prev - chi2_now < STALLED_CHI2_GAIN)
        if stationary:
            break
        chi2_prev = chi2_now
    if not stationary:
        # the rounds ran out while still creeping: accept a solution within 0.01 s.e. of the minimum
        stationary = _remaining_step_se(J, r) < ACCEPTABLE_STEP_SE
    ok = bool(stationary and np.all(np.isfinite(x)))
    if ok:
        message = res.message
    else:
        message = (f"no minimum after {_round + 1} rounds of Levenberg-Marquardt and Gauss-Newton (one more step "
                   f"would move a parameter by {_remaining_step_se(J, r):.3g} standard errors; the chi-square still "
                   "falls slowly): the parameters are nearly degenerate over this record")
    try:
        JTJ = J.T @ J
        cov = np.linalg.pinv(JTJ, rcond=1e-14, hermitian=True)
    except np.linalg.LinAlgError:
        cov = np.full((len(x0), len(x0)), np.nan)
    chi2v = float(np.sum(r**2))
    return _Solved(spec, x, cov, chi2v, n_res - len(x0), ok, message)


def _remaining_step_se(J: np.ndarray, r: np.ndarray) -> float:
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


def _gauss_newton_polish(white, x: np.ndarray, r: np.ndarray, J: np.ndarray, max_steps: int = 30
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Finish a least-squares minimisation with undamped Gauss-Newton steps.

    Where parameters are strongly correlated (exponentials and sinusoids of nearby rates in the
    damped models), Levenberg-Marquardt's damping makes it crawl along the valley: thousands of
    steps, each lowering the chi-square a little.  Near the minimum of a small-residual problem,
    Gauss-Newton (a column-scaled least-squares solve of ``J dx = -r``) converges in a few steps
    there; a step that does not lower the chi-square is halved.  Stops when a step's predicted
    gain is below 1e-9 in chi-square.
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


def _conditional_amplitudes(spec: ModelSpec, data: FitData, start: dict[str, float], names: list[str]
                            ) -> tuple[dict[str, float], float]:
    """Start values for parameters the model is linear in (the amplitudes of a new term): their
    least-squares values with every other parameter held at ``start`` (one Gauss-Newton step
    in those parameters alone).  Returns the start and its chi-square."""
    model = _Model(spec)
    x0 = np.array([start.get(n, 0.0) for n in model.names], float)
    _, white = _residual_fn(model, data)
    cols = [model.index[n] for n in names]
    r = white(x0)
    J = white.jac(x0)[:, cols]
    step, *_ = np.linalg.lstsq(J, -r, rcond=None)
    x0[cols] += step
    out = dict(zip(model.names, x0))
    return out, float(np.sum(white(x0) ** 2))


def _linear_harmonics(spec: ModelSpec, data: FitData, start: dict[str, float]) -> dict[str, float]:
    """Given the nonlinear parameters, the harmonic amplitudes by linear least squares."""
    base = replace(spec, harmonics=0)
    model = _Model(base)
    p = np.array([start.get(n, 0.0) for n in model.names])
    tau = data.t_s - data.t_ref_s
    th0, ph0 = model.axis_frame(p, tau, data.segment)
    if spec.fit_axis:
        R = _axis_rotation(start["axis_tilt_rad"], start["axis_azimuth_rad"])
        th, ph = _angles(_tip(data.theta_rad, data.phi_rad) @ R)
    else:
        th, ph = data.theta_rad, data.phi_rad
    rth, rph = th - th0, _wrap(ph - ph0)
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


def fit_model(data: FitData, scene: SceneModel, max_harmonics: int = MAX_HARMONICS, *,
              terms: FitTerms | None = None, noncentrality: float | None = None
              ) -> tuple[_Solved, list[str], dict[str, str]]:
    """Fit the scene's model, with its optional terms (nutation harmonics, and under damping the
    transient, elliptical cone, sidebands and persistent oscillation) chosen in this order.

    Parameters
    ----------
    terms : FitTerms, optional
        Terms planned in advance (:func:`plan_terms`): each is kept whenever it converges.  A
        term not in the plan is still added when the data's chi-square test wants it (noted).
        Without ``terms`` every term is chosen by that test (p < :data:`TERM_P_VALUE`).
    noncentrality : float, optional
        For noiseless data (planning): a term is kept when it lowers the chi-square by more
        than this, instead of by the p-value test.

    Returns the solution, notes, and reasons for quantities that cannot be determined.
    """
    sel = _Selector(terms=terms, noncentrality=noncentrality)
    spec0 = replace(scene.spec, harmonics=0, segments=int(data.segment.max()) + 1, camera_modes=data.camera_modes,
                    nutation_origin_s=float(data.t_s[0] - data.t_ref_s) if scene.spec.damped else 0.0)
    notes: list[str] = list(scene.reasons)
    undetermined: dict[str, str] = {}
    if spec0.segments > 1:
        gaps = np.diff(data.t_s)[np.diff(data.segment) > 0]
        notes.append(f"{len(gaps)} gap(s) longer than half a precession period ({', '.join(f'{g:.3g} s' for g in gaps)}) "
                     f"split the azimuth into {spec0.segments} segments with their own offsets: the turns made in a "
                     "gap are not counted, and the precession rate comes from within the segments")
    axis = None
    if spec0.fit_axis:
        m = _tip(data.theta_rad, data.phi_rad).mean(axis=0)
        m /= np.linalg.norm(m)
        th_a, ph_a = _angles(m)
        axis = (float(th_a), float(ph_a))
    start = _linear_start(spec0, data, axis)
    base = _solve(spec0, data, start)
    if not base.ok and not (scene.nutation_expected and np.all(np.isfinite(base.x))):
        raise FitError(f"the fit did not converge: {base.message}")
    # without the nutation the slow model may find no clean minimum over a short record (the residual is
    # the nutation itself): it is only the start of the full model, which must converge
    best = base
    if scene.nutation_expected:
        reason = None
        hint = scene.nutation_frequency_hint_rad_s
        nyq = data.nyquist_rad_s
        periods = None
        if hint is not None:
            periods = data.duration_s * hint / (2 * np.pi)
        if hint is not None and hint > NYQUIST_FRACTION * nyq:
            reason = (f"the camera cannot resolve the nutation: predicted {hint / (2 * np.pi):.3g} Hz, frame rate "
                      f"{nyq / np.pi:.3g} fps (Nyquist {nyq / (2 * np.pi):.3g} Hz)")
        elif periods is not None and periods < 2:
            reason = f"the record covers {periods:.2g} predicted nutation periods; at least 2 are needed"
        if reason is None:
            names0 = _Model(spec0).names
            p0 = dict(zip(names0, base.x))
            model0 = _Model(spec0)
            tau = data.t_s - data.t_ref_s
            th0, _ = model0.axis_frame(base.x, tau, data.segment)
            if spec0.fit_axis:
                R = _axis_rotation(p0["axis_tilt_rad"], p0["axis_azimuth_rad"])
                th_obs, _ = _angles(_tip(data.theta_rad, data.phi_rad) @ R)
            else:
                th_obs = data.theta_rad
            w0 = _dominant_frequency(data.t_s, th_obs - th0, NYQUIST_FRACTION * nyq, hint)
            start1 = dict(p0, nutation_frequency_rad_s=w0)
            if spec0.damped:
                start1["nutation_decay_rate_per_s"] = 0.0
            cur = None
            # harmonic k of a damped nutation decays k times as fast: a few suffice
            k_max = min(max_harmonics, 3) if spec0.damped else max_harmonics
            for k in range(1, k_max + 1):
                if k * w0 > nyq:
                    notes.append(f"harmonic {k} of the nutation is above the Nyquist frequency; not modelled")
                    break
                spec_k = replace(spec0, harmonics=k)
                s_k = _linear_harmonics(spec_k, data, start1)
                sol = _solve(spec_k, data, s_k)
                ref = cur if cur is not None else base
                if not sel.wants(ref, sol, "harmonics", notes, f"nutation harmonic {k}", k):
                    if cur is None and not sol.ok:
                        reason = f"the fit with nutation did not converge: {sol.message}"
                    elif cur is None:
                        dchi, ddof = ref.chi2 - sol.chi2, ref.dof - sol.dof
                        reason = (f"no significant nutation in the data (chi-square improves by {dchi:.3g} for "
                                  f"{ddof} more parameters; {sel.need(ddof):.3g} needed)")
                    break
                cur = sol
                start1 = dict(zip(_Model(spec_k).names, sol.x))
            if cur is not None:
                w_fit = dict(zip(_Model(cur.spec).names, cur.x))["nutation_frequency_rad_s"]
                if not 0 < w_fit < nyq:
                    reason = (f"the fit did not settle on a nutation frequency inside (0, Nyquist): {w_fit:.4g} rad/s")
                    cur = None
            if cur is not None:
                best = cur
        if spec0.damped:
            best = _with_optional_terms(best, data, notes, sel)
        if reason is not None:
            undetermined["nutation_frequency_rad_s"] = reason
            undetermined["nutation_amplitude_rad"] = reason
    if not best.ok:
        raise FitError(f"the fit did not converge: {best.message}")
    return best, notes, undetermined


_TERM_NOTES = {
    "shape_drift": "a drifting nutation shape (its tilt and azimuth parts change linearly in time as the tilt drifts)",
    "third_order": "a third-order nutation term decaying three times as fast (the nutation's shape changes with its "
                   "amplitude)",
    "persistent": "a persistent oscillation near the nutation frequency",
    "transient": "a fast transient from the first frame",
    "precession_second": "a second harmonic of the precession (an elliptical cone)",
    "sidebands": "nutation sidebands at the nutation frequency +- the precession rate (damping about the lab vertical "
                 "modulates the nutation)",
}


def _term_applies(flag: str, spec: ModelSpec) -> bool:
    """Whether the optional term ``flag`` can be added to a damped model ``spec`` (and is not in it)."""
    if getattr(spec, flag):
        return False
    if flag in ("shape_drift", "third_order", "persistent") and not spec.harmonics:
        return False
    if flag == "precession_second" and not spec.fit_axis:
        return False
    if flag == "sidebands" and not (spec.fit_axis and spec.harmonics):
        return False
    return True


def _with_optional_terms(best: _Solved, data: FitData, notes: list[str], sel: _Selector) -> _Solved:
    """A damped model's optional terms (:data:`OPTIONAL_TERMS`), each kept as the selector decides.

    Chosen by the data (or on noiseless planning data), they are tried in order, each against
    the model so far, and a persistent oscillation is dropped again at the end if the later
    terms leave it little to do.  With planned terms, the planned model is built first; then
    each term the plan left out is tried against the whole planned model (not against a part
    of it, where it could stand in for a planned term that is not yet in), with the threshold
    of :meth:`_Selector.need`.
    """
    if sel.terms is None:
        for flag in OPTIONAL_TERMS:
            if _term_applies(flag, best.spec):
                best = _consider_term(best, data, notes, sel, flag)
        return _prune_persistent(best, data, notes, sel)
    for flag in OPTIONAL_TERMS:
        if sel.planned(flag) and _term_applies(flag, best.spec):
            best = _consider_term(best, data, notes, sel, flag)
    for flag in OPTIONAL_TERMS:
        if not sel.planned(flag) and _term_applies(flag, best.spec):
            best = _consider_term(best, data, notes, sel, flag)
    return _prune_persistent(best, data, notes, sel)


def _consider_term(cur: _Solved, data: FitData, notes: list[str], sel: _Selector, flag: str) -> _Solved:
    """``cur`` with the optional term ``flag`` if the selector wants it, else ``cur``."""
    if flag in _SCREENED and not sel.planned(flag) and cur.ok:
        # a term with a free frequency or rate makes the full trial slow (where its amplitude is ~0
        # the solver creeps along it: a 20 s B2 record spent 74 s on a transient it then rejected);
        # its score statistic approximates the chi-square gain to first order, and a term far below
        # the threshold is not tried
        score_fn, ddof = _SCREENED[flag]
        knob, score = score_fn(cur, data)
        if score < SCORE_SCREEN_FRACTION * sel.need(ddof, flag):
            return cur
        sol, note = ((_trial_persistent(cur, data, knob), _TERM_NOTES[flag]) if flag == "persistent"
                     else _trial_term(cur, data, flag))
    else:
        sol, note = _trial_term(cur, data, flag)
    if flag == "persistent" and _persistent_unresolved(sol, data, sel):
        return cur
    if sel.wants(cur, sol, flag, notes, note):
        notes.append(f"{note}: modelled")
        return sol
    return cur


def _trial_term(cur: _Solved, data: FitData, flag: str) -> tuple[_Solved, str]:
    """The fit of ``cur``'s model plus the optional term ``flag`` (or the next nutation harmonic,
    ``"harmonics"``), started from ``cur``'s solution; and the term's description."""
    if flag == "persistent":
        return _trial_persistent(cur, data, _persistent_score(cur, data)[0]), _TERM_NOTES[flag]
    if flag == "transient":
        return _trial_transient(cur, data)
    spec_x = replace(cur.spec, harmonics=cur.spec.harmonics + 1) if flag == "harmonics" else \
        replace(cur.spec, **{flag: True})
    new = [n for n in _Model(spec_x).names if n not in _Model(cur.spec).index]
    st, _ = _conditional_amplitudes(spec_x, data, dict(zip(_Model(cur.spec).names, cur.x)), new)
    note = f"nutation harmonic {spec_x.harmonics}" if flag == "harmonics" else _TERM_NOTES[flag]
    return _solve(spec_x, data, st, near=True), note


_PERSISTENT_AMPLITUDES = ("persistent_tilt_cos_rad", "persistent_tilt_sin_rad", "persistent_azimuth_cos_rad",
                          "persistent_azimuth_sin_rad")


def _score_over_grid(cur: _Solved, data: FitData, spec_x: ModelSpec, amplitudes: Sequence[str], knob: str,
                     grid: np.ndarray) -> tuple[float, float]:
    """Score (Lagrange-multiplier) statistic of a new term whose ``amplitudes`` enter linearly,
    for each value of its nonlinear parameter ``knob`` on ``grid``; returns the best value and its
    score.

    For each value the score is ``g^T M^-1 g`` with ``g = A^T r`` and ``M = A^T (1 - P_J) A``,
    ``A`` the amplitudes' whitened columns, ``P_J`` the projection on ``cur``'s Jacobian, ``r``
    its residuals: the chi-square gain to first order with every parameter of ``cur`` free.  It
    equals the fitted gain for a small term and needs no nonlinear fit.
    """
    model = _Model(cur.spec)
    _, white = _residual_fn(model, data)
    r = white(cur.x)
    Q, _ = np.linalg.qr(white.jac(cur.x))
    r = r - Q @ (Q.T @ r)
    model_x = _Model(spec_x)
    _, white_x = _residual_fn(model_x, data)
    p_cur = dict(zip(model.names, cur.x))
    cols = [model_x.index[k] for k in amplitudes]
    best = (float(grid[0]), -math.inf)
    for v in grid:
        x = np.array([p_cur.get(n, 0.0) for n in model_x.names])
        x[model_x.index[knob]] = v
        A0 = white_x.jac(x)[:, cols]
        norms = np.linalg.norm(A0, axis=0)
        norms[norms == 0] = 1.0
        A = A0 - Q @ (Q.T @ A0)
        # directions of the term that the model already spans (to 1e-6 of the columns' size: the
        # projection leaves ~1e-12 of rounding) can gain nothing; without the cut, noise over
        # noise (e.g. a transient as slow as the record, 2.7e6 for a term that gains nothing)
        U, sv, _ = np.linalg.svd(A / norms, full_matrices=False)
        keep = sv > 1e-6
        score = float(np.sum((U[:, keep].T @ r) ** 2))
        if score > best[1]:
            best = (float(v), score)
    return best


def _persistent_score(cur: _Solved, data: FitData) -> tuple[float, float]:
    """The frequency near the nutation (within 3 frequency bins ``2 pi / T``) at which a persistent
    oscillation would lower the chi-square of ``cur`` most, and that drop to first order
    (:func:`_score_over_grid` on a grid of 0.1 bin)."""
    w_n = float(cur.x[_Model(cur.spec).index["nutation_frequency_rad_s"]])
    bin_w = 2 * np.pi / data.duration_s
    grid = np.array([w_n + dw for dw in np.arange(-3.0, 3.0001, 0.1) * bin_w if abs(dw) > 1e-9])
    return _score_over_grid(cur, data, replace(cur.spec, persistent=True), _PERSISTENT_AMPLITUDES,
                            "persistent_frequency_rad_s", grid)


def _transient_spec(cur: _Solved, data: FitData) -> ModelSpec:
    """``cur``'s model plus the fast transient, its rate bounded to what the record can see: at
    least 10 e-folds per record (so that it cannot stand in for the slow terms), at most 3 per frame."""
    floor = 10.0 / data.duration_s
    dt = float(np.median(np.diff(data.t_s)))
    cap = max(3.0 / dt, 2 * floor)
    return replace(cur.spec, transient=True, transient_min_rate_per_s=floor, transient_max_rate_per_s=cap)


def _transient_logit(spec_t: ModelSpec, rate_per_s: float) -> float:
    lo, hi = spec_t.transient_min_rate_per_s, spec_t.transient_max_rate_per_s
    frac = (rate_per_s - lo) / (hi - lo)
    return math.log(frac / (1 - frac))


def _transient_score(cur: _Solved, data: FitData) -> tuple[float, float]:
    """The transient's rate logit (over 48 rates spanning its range) at which it would lower the
    chi-square of ``cur`` most, and that drop to first order (:func:`_score_over_grid`)."""
    spec_t = _transient_spec(cur, data)
    lo, hi = spec_t.transient_min_rate_per_s, spec_t.transient_max_rate_per_s
    grid = np.array([_transient_logit(spec_t, k) for k in np.geomspace(1.02 * lo, 0.98 * hi, 48)])
    return _score_over_grid(cur, data, spec_t, ("transient_tilt_rad", "transient_azimuth_rad"),
                            "transient_rate_logit", grid)


#: optional terms with a free nonlinear parameter, screened by their score statistic before a
#: trial fit: (score function, number of parameters the term adds)
_SCREENED = {"persistent": (_persistent_score, 5), "transient": (_transient_score, 3)}


def _trial_persistent(cur: _Solved, data: FitData, w_start: float | None = None) -> _Solved:
    """Add a persistent oscillation near the nutation frequency, started at ``w_start`` or else one
    frequency bin either side of the nutation.

    Under damping the drifting slow mode can keep a small undamped oscillation alive (B2 rig,
    ~3e-5 rad, before the drifting-shape term described it)."""
    p_cur = dict(zip(_Model(cur.spec).names, cur.x))
    w_n = p_cur["nutation_frequency_rad_s"]
    trial = []
    spec_p = replace(cur.spec, persistent=True)
    amps = list(_PERSISTENT_AMPLITUDES)
    starts = [w_start] if w_start is not None else [w_n + 2 * np.pi / data.duration_s,
                                                    w_n - 2 * np.pi / data.duration_s]
    for w in starts:
        st = dict(p_cur, persistent_frequency_rad_s=w, **{k: 0.0 for k in amps})
        st, _ = _conditional_amplitudes(spec_p, data, st, amps)
        trial.append(_solve(spec_p, data, st, near=True))
    ok = [s_ for s_ in trial if s_.ok] or trial
    return min(ok, key=lambda s_: s_.chi2)


def _persistent_unresolved(sol: _Solved, data: FitData, sel: _Selector) -> bool:
    """A persistent oscillation (not planned) whose frequency this record does not resolve."""
    if not sol.spec.persistent or sel.planned("persistent") or not sol.ok:
        return False
    return phase_uncertainty(sol.spec, sol.x, sol.cov, data)["persistent_frequency_rad_s"] > NONLINEAR_PHASE_RAD


def _prune_persistent(best: _Solved, data: FitData, notes: list[str], sel: _Selector) -> _Solved:
    """Take the persistent oscillation out again when, with the terms added after it, the record
    no longer resolves its frequency or no longer needs it (it was tried before the transient
    and the axis terms, and can stand in for them).  A free frequency needs a clear detection
    to be estimable: on noiseless planning data at least :data:`FREE_FREQUENCY_NONCENTRALITY`."""
    if not best.spec.persistent or sel.planned("persistent") or not best.ok:
        return best
    spec = replace(best.spec, persistent=False)
    sol = _solve(spec, data, dict(zip(_Model(best.spec).names, best.x)), near=True)
    if not sol.ok:
        return best
    gain, ddof = sol.chi2 - best.chi2, sol.dof - best.dof
    need = sel.need(ddof, "persistent")
    if sel.noncentrality is not None:
        need = max(need, FREE_FREQUENCY_NONCENTRALITY)
    unresolved = _persistent_unresolved(best, data, sel)
    if not unresolved and gain > need:
        return best
    notes[:] = [n for n in notes if not n.startswith(_TERM_NOTES["persistent"])
                and not n.endswith(f"({_TERM_NOTES['persistent']}): it is added")]
    why = ("the record does not resolve its frequency" if unresolved else
           f"the other terms leave it little to do (chi-square {gain:+.3g} without it; {need:.3g} needed)")
    notes.append(f"{_TERM_NOTES['persistent']} is left out: {why}")
    return sol


def _trial_transient(cur: _Solved, data: FitData) -> tuple[_Solved, str]:
    """Add a fast exponential transient from the first frame.

    After release, a damped gyrostat's frame spin relaxes in ``I_frame / c`` (27 ms on the
    bundled rigs), which moves the tip by ~1e-4 rad for a few frames; the rates tried span
    what a frame rate can see (at least 10 e-folds per record, so that it cannot stand in for
    the slow terms, at most 3 per frame).
    """
    p_cur = dict(zip(_Model(cur.spec).names, cur.x))
    spec_t = _transient_spec(cur, data)
    floor, cap = spec_t.transient_min_rate_per_s, spec_t.transient_max_rate_per_s
    # the amplitudes are linear: solve them for a ladder of rates, start from the best rate
    best_start, best_chi2 = None, math.inf
    for kappa in np.geomspace(1.05 * floor, 0.95 * cap, 16):
        st = dict(p_cur, transient_rate_logit=_transient_logit(spec_t, kappa), transient_tilt_rad=0.0,
                  transient_azimuth_rad=0.0)
        st, c2 = _conditional_amplitudes(spec_t, data, st, ["transient_tilt_rad", "transient_azimuth_rad"])
        if c2 < best_chi2:
            best_start, best_chi2 = st, c2
    return _solve(spec_t, data, best_start, near=True), f"{_TERM_NOTES['transient']} (decaying faster than {floor:.3g} 1/s)"


def left_out_noncentrality(sol: _Solved, data: FitData) -> dict[str, float]:
    """For a model chosen on noiseless data: the chi-square change each term it left out would make
    (the next nutation harmonic, and in a damped model the optional terms; for the persistent
    oscillation and the transient, with a free frequency or rate, the first-order change: their
    score statistics).  A noisy record of the
    scene shows these terms with that non-centrality; see :meth:`_Selector.need`."""
    out = {}
    spec = sol.spec
    if spec.harmonics and spec.harmonics < (3 if spec.damped else MAX_HARMONICS) and \
            (spec.harmonics + 1) * sol.x[_Model(spec).index["nutation_frequency_rad_s"]] < data.nyquist_rad_s:
        trial, _ = _trial_term(sol, data, "harmonics")
        if trial.ok:
            out["harmonics"] = max(sol.chi2 - trial.chi2, 0.0)
    if spec.damped:
        for flag in OPTIONAL_TERMS:
            if not _term_applies(flag, spec):
                continue
            if flag in _SCREENED:
                # its first-order gain (the score statistic; within 10 % (persistent) and 1 %
                # (transient) of the fitted gain on the bundled rigs, without a solver creeping along
                # a free frequency or rate)
                out[flag] = max(_SCREENED[flag][0](sol, data)[1], 0.0)
                continue
            trial, _ = _trial_term(sol, data, flag)
            if trial.ok:
                out[flag] = max(sol.chi2 - trial.chi2, 0.0)
    return out


# --------------------------------------------------------------------------------- derived quantities
def _nutation_amplitude(spec: ModelSpec, names: list[str], x: np.ndarray) -> float:
    ix = {n: i for i, n in enumerate(names)}
    psi = np.linspace(0, 2 * np.pi, 721)[:-1]
    y = np.zeros_like(psi)
    for k in range(1, spec.harmonics + 1):
        y += x[ix[f"tilt_cos_{k}_rad"]] * np.cos(k * psi) + x[ix[f"tilt_sin_{k}_rad"]] * np.sin(k * psi)
    if spec.third_order:
        # at the first frame the third-order term is part of the fundamental (it only decays faster);
        # the two are nearly degenerate, their sum is what the record determines
        y += x[ix["tilt_third_cos_rad"]] * np.cos(psi) + x[ix["tilt_third_sin_rad"]] * np.sin(psi)
    # refine the extremes with a parabola through the grid's best points
    def extreme(sign: float) -> float:
        i = int(np.argmax(sign * y))
        a, b, c = y[i - 1], y[i], y[(i + 1) % len(y)]
        den = a - 2 * b + c
        return b - 0.125 * (a - c) ** 2 / den if den != 0 else b
    return 0.5 * (extreme(1.0) - extreme(-1.0))


def _delta_se(f, x: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    v = f(x)
    g = np.zeros_like(x)
    for i in range(len(x)):
        h = 1e-6 * max(abs(x[i]), np.sqrt(max(cov[i, i], 0.0)), 1e-12)
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        g[i] = (f(xp) - f(xm)) / (2 * h)
    return float(v), float(np.sqrt(max(g @ cov @ g, 0.0)))


def _quantity_functions(spec: ModelSpec, names: list[str]):
    ix = {n: i for i, n in enumerate(names)}
    fns = {
        "precession_rate_rad_s": lambda x: x[ix["precession_rate_rad_s"]],
        "cone_angle_rad": lambda x: math.exp(x[ix["log_cone_angle"]]),
    }
    if spec.harmonics:
        fns["nutation_frequency_rad_s"] = lambda x: x[ix["nutation_frequency_rad_s"]]
        fns["nutation_amplitude_rad"] = lambda x: _nutation_amplitude(spec, names, x)
    if spec.damped:
        fns["tilt_growth_rate_per_s"] = lambda x: x[ix["tilt_growth_rate_per_s"]]
    if spec.fit_axis:
        fns["equilibrium_tilt_rad"] = lambda x: x[ix["axis_tilt_rad"]]
        fns["equilibrium_azimuth_rad"] = lambda x: float(_wrap(np.array(x[ix["axis_azimuth_rad"]])))
    return fns


#: parameters that enter the model as phase or log-amplitude rates: (name, power of tau)
_RATE_PARAMETERS = (("precession_rate_rad_s", 1), ("nutation_frequency_rad_s", 1), ("persistent_frequency_rad_s", 1),
                    ("nutation_decay_rate_per_s", 1), ("tilt_growth_rate_per_s", 1),
                    ("precession_acceleration_rad_s2", 2), ("nutation_chirp_rad_s2", 2),
                    ("tilt_growth_curvature_per_s2", 2))


def phase_uncertainty(spec: ModelSpec, x: np.ndarray, cov: np.ndarray, data: FitData) -> dict[str, float]:
    """For each rate-like parameter, one standard error times the longest ``|tau|`` (``tau^2 / 2``
    for second-order terms): the phase or log-amplitude it leaves uncertain at the record's
    ends, in radians.  The least-squares errors are Cramer-Rao bounds only while these are
    well below 1 (the model is linear over one standard error); above :data:`NONLINEAR_PHASE_RAD`
    the record is too short for the model and the errors are not reliable."""
    names = _Model(spec).names
    tau = float(np.max(np.abs(data.t_s - data.t_ref_s)))
    out = {}
    for name, power in _RATE_PARAMETERS:
        if name in names:
            i = names.index(name)
            se = math.sqrt(max(float(cov[i, i]), 0.0))
            out[name] = se * (tau if power == 1 else 0.5 * tau * tau)
    return out


def _residual_check(model: _Model, data: FitData, x: np.ndarray) -> tuple[float, float]:
    _, white = _residual_fn(model, data)
    r = white(x)[:2 * data.n].reshape(2, -1)
    rho = [float(np.sum(ri[1:] * ri[:-1]) / np.sum(ri * ri)) for ri in r]
    return rho[0], rho[1]


def _block_bootstrap(sol: _Solved, data: FitData, fns: dict, rng: np.random.Generator, replicates: int,
                     block: int) -> dict[str, float]:
    """Moving-block bootstrap of the whitened residuals (refits start at the solution)."""
    model = _Model(sol.spec)
    raw, _ = _residual_fn(model, data)
    r0, r1 = raw(sol.x)
    th_fit, ph_fit = data.theta_rad - r0, data.phi_rad - r1
    n = data.n
    out = {k: [] for k in fns}
    for _ in range(replicates):
        starts = rng.integers(0, max(n - block, 1), size=int(math.ceil(n / block)))
        idx = np.concatenate([np.arange(s, s + block) for s in starts])[:n]
        idx = np.minimum(idx, n - 1)
        d = replace(data, theta_rad=th_fit + r0[idx], phi_rad=ph_fit + r1[idx])
        s = _solve(sol.spec, d, dict(zip(model.names, sol.x)))
        for k, f in fns.items():
            out[k].append(f(s.x))
    return {k: float(np.std(v, ddof=1)) for k, v in out.items()}


def _compare(q: Quantity, prediction: dict | None, key: str | None, comparable: bool, note: str = "") -> Quantity:
    if not prediction or key is None or key not in prediction:
        return q
    p = prediction[key]
    paper, corr, exact = p.get("paper"), p.get("corrected"), p.get("exact")
    upd = dict(paper=paper, corrected=corr, exact=exact, exact_source=p.get("exact_source", ""),
               note="; ".join(n for n in (q.note, note) if n))
    if comparable and q.value is not None and q.standard_error:
        def diff(ref: float) -> float:
            d = q.value - ref
            return float(_wrap(np.array(d))) if q.name.endswith("azimuth_rad") else d
        if paper is not None and np.isfinite(paper):
            upd["diff_paper_se"] = diff(paper) / q.standard_error
        if exact is not None and np.isfinite(exact):
            upd["diff_exact_se"] = diff(exact) / q.standard_error
    return replace(q, **upd)


def _theory_values(prediction: dict | None) -> dict:
    """Theory predictions keyed by fit quantity (angles for the equilibrium direction)."""
    if not prediction:
        return {}
    out = {}
    for key in ("nutation_frequency_rad_s", "nutation_amplitude_rad", "tilt_growth_rate_per_s",
                "tilt_time_constant_s"):
        if key in prediction:
            out[key] = prediction[key]
    if "mean_precession_rate_rad_s" in prediction:
        out["precession_rate_rad_s"] = prediction["mean_precession_rate_rad_s"]
    elif "precession_rate_rad_s" in prediction:
        out["precession_rate_rad_s"] = prediction["precession_rate_rad_s"]
    if "equilibrium_tip" in prediction:
        e = prediction["equilibrium_tip"]
        tilts, azis = {}, {}
        for k in ("paper", "exact"):
            v = np.asarray(e[k], float)
            th, ph = _angles(v / np.linalg.norm(v))
            tilts[k], azis[k] = float(th), float(ph)
        out["equilibrium_tilt_rad"] = {**tilts, "exact_source": e.get("exact_source", "")}
        out["equilibrium_azimuth_rad"] = {**azis, "exact_source": e.get("exact_source", "")}
    return out


def plan_terms(data: FitData, scene: SceneModel, source: str = "") -> FitTerms:
    """The model terms that noiseless angles ``data`` (with the per-frame errors real data will
    have) call for: each term is kept when it changes the chi-square by more than
    :data:`PLANNED_NONCENTRALITY`, i.e. when leaving it out could bias a fitted quantity by a
    sizeable fraction of its standard error."""
    d = replace(data, camera_shift=None)
    sol, _, _ = fit_model(d, scene, noncentrality=PLANNED_NONCENTRALITY)
    return FitTerms.of(sol.spec, source, left_out_noncentrality(sol, d))


TERM_CHOICES = ("data", "noiseless")


def fit_angles(angles: pd.DataFrame, protocol: Protocol, *, prediction: dict | None = None,
               exclude: np.ndarray | None = None, truth: pd.DataFrame | None = None,
               rng: np.random.Generator | None = None, bootstrap_replicates: int = 50,
               check_residuals: bool = True, terms: FitTerms | str = "data") -> FitResult:
    """Fit an angle table with the scene's model and compare with theory (and truth, if given).

    Parameters
    ----------
    angles : DataFrame
        ``t_s, theta_rad, phi_rad, theta_sigma_rad, phi_sigma_rad[, theta_phi_corr, frame]``.
    protocol : Protocol
        The scene (decides the model).
    prediction : dict, optional
        :func:`gyrorig.theory.predict` output, for the comparison columns and for hints
        (predicted nutation frequency: resolvable by the camera or not).
    exclude : bool array, optional
        Rows to leave out (the smoother's outliers).
    truth : DataFrame, optional
        Noiseless angles of a synthetic run (``t_s, theta_rad, phi_rad``), e.g. the tip rows of
        a renderer's ``truth.csv``: the same model is fitted to them, giving the true value
        of each quantity and the pull ``(fit - truth) / standard error``.
    rng : numpy Generator, optional
        For the block bootstrap (used only when residuals are not white).
    check_residuals : bool
        Test the residuals (whiteness, chi-square) and fall back on the bootstrap or scaled
        errors.  Off only for noiseless model data (planning: the formal errors are then the
        Cramer-Rao bound for the stated per-frame errors).
    terms : {"data", "noiseless"} or FitTerms
        How the optional model terms (nutation harmonics; under damping the transient,
        elliptical cone, sidebands, persistent oscillation) are chosen.  ``"data"`` (default):
        by chi-square tests on these data.  A :class:`FitTerms` (from :func:`gyrorig.plan.plan_fit_terms`,
        i.e. ``gyrorig plan``): these terms, the same for every record of the scene; a term the
        data need beyond them is still added (noted).  ``"noiseless"``: the angles are noiseless
        model data (planning): a term is kept above a non-centrality of :data:`PLANNED_NONCENTRALITY`.
    """
    start_time = time.perf_counter()
    scene = model_for_scene(protocol, prediction)
    data = fit_data_from_angles(angles, exclude, scene.precession_hint_rad_s)
    pre_notes: list[str] = []
    if isinstance(terms, str) and terms not in TERM_CHOICES:
        raise ValueError(f"terms must be one of {', '.join(TERM_CHOICES)} or a FitTerms; got {terms!r}")
    if isinstance(terms, FitTerms):
        sol, notes, undetermined = fit_model(data, scene, terms=terms)
        pre_notes.append(f"model terms ({terms.describe()}) {terms.source or 'given'}")
    else:
        sol, notes, undetermined = fit_model(
            data, scene, noncentrality=PLANNED_NONCENTRALITY if terms == "noiseless" else None)
        terms = (FitTerms.of(sol.spec, "chosen by chi-square tests on the data") if terms == "data" else
                 FitTerms.of(sol.spec, f"chosen on noiseless data (non-centrality above {PLANNED_NONCENTRALITY:g})",
                             left_out_noncentrality(sol, data)))
    notes = pre_notes + notes
    names = _Model(sol.spec).names
    fns = _quantity_functions(sol.spec, names)
    chi2_red = sol.chi2 / max(sol.dof, 1)
    rho = _residual_check(_Model(sol.spec), data, sol.x)
    white_limit = 4.0 / math.sqrt(data.n)
    errors = "formal"
    se_override: dict[str, float] = {}
    not_white = check_residuals and max(abs(rho[0]), abs(rho[1])) > white_limit
    if not_white:
        rng = rng if rng is not None else np.random.default_rng(0)
        block = max(2, int(math.ceil(1 + 2 * max(abs(rho[0]), abs(rho[1])) / (1 - min(0.99, max(abs(r) for r in rho)))
                                     * 5)))
        block = min(block, max(2, data.n // 10))  # at least ten blocks, or the bootstrap has nothing to resample
        se_override = _block_bootstrap(sol, data, fns, rng, bootstrap_replicates, block)
        errors = f"moving-block bootstrap ({bootstrap_replicates} replicates, block {block} frames)"
        notes.append(f"residuals are not white (lag-1 autocorrelation {rho[0]:.3f} in theta, {rho[1]:.3f} in phi; "
                     f"limit {white_limit:.3f}): standard errors from the bootstrap")
    elif check_residuals and chi2.sf(sol.chi2, sol.dof) < 1e-3 and chi2_red > 1:
        errors = "formal x sqrt(chi2_red)"
        notes.append(f"reduced chi-square {chi2_red:.3f} is significantly above 1 (the tracker's error bars are too "
                     "small or the model misses something): standard errors scaled by sqrt(chi2_red)")
    phases = phase_uncertainty(sol.spec, sol.x, sol.cov, data)
    nonlinear = {k: v for k, v in phases.items() if v > NONLINEAR_PHASE_RAD}
    if nonlinear:
        notes.append("the record is too short for this model: " + ", ".join(
            f"{k} leaves {v:.2g} rad of phase uncertain over the record" for k, v in nonlinear.items())
            + f" (above {NONLINEAR_PHASE_RAD:g}); the model is not linear over one standard error, so the standard "
            "errors are not reliable (they vary from record to record); a longer record resolves the terms")
    if check_residuals and chi2_red > SYSTEMATIC_CHI2_RED:
        notes.append(f"the residuals are far larger than the tracker's errors (reduced chi-square {chi2_red:.3g}): a "
                     "systematic error dominates (camera calibration or pose, or a motion the model does not describe);"
                     " the standard errors cover the statistical part only and understate the true error")
    values = {}
    formal = {}
    camera_se = {}
    cov_stat = _statistical_covariance(sol, data)
    for k, f in fns.items():
        v, se = _delta_se(f, sol.x, sol.cov)
        formal[k] = se
        se_stat = se
        if cov_stat is not None:
            se_stat = _delta_se(f, sol.x, cov_stat)[1]
            camera_se[k] = math.sqrt(max(se * se - se_stat * se_stat, 0.0))
        if errors.startswith("formal x"):
            se_stat *= math.sqrt(chi2_red)
        if k in se_override:
            se_stat = max(se_stat, se_override[k])
        values[k] = (v, math.hypot(se_stat, camera_se.get(k, 0.0)))
    if cov_stat is not None:
        notes.append(f"the camera model's uncertainty ({data.camera_modes} modes from the tracker) is in the fit as "
                     "nuisance parameters with their priors: every standard error includes it (camera share: "
                     + ", ".join(f"{k} {camera_se[k]:.2g}" for k in ("precession_rate_rad_s", "nutation_amplitude_rad",
                                                                       "tilt_growth_rate_per_s", "equilibrium_tilt_rad")
                                 if k in camera_se) + ")")

    truth_values: dict[str, float] = {}
    if truth is not None:
        truth_values = _truth_values(truth, data, sol.spec, sol.x, fns)

    theory = _theory_values(prediction)
    quantities: dict[str, Quantity] = {}
    for name, units in QUANTITY_UNITS.items():
        in_scene = (name in fns or name in undetermined
                    or (name == "tilt_time_constant_s" and "tilt_growth_rate_per_s" in fns))
        if not in_scene:
            continue
        if name in undetermined:
            q = Quantity(name, units, None, None, "undetermined", undetermined[name])
        elif name == "tilt_time_constant_s":
            lam, se = values["tilt_growth_rate_per_s"]
            if abs(lam) < 2 * se:
                q = Quantity(name, units, None, None, "undetermined",
                             f"the tilt rate {lam:.3g} +- {se:.2g} 1/s is consistent with zero: |tau| > "
                             f"{1 / (abs(lam) + 2 * se):.3g} s (2 standard errors)")
            else:
                q = Quantity(name, units, 1 / lam, se / lam**2, "determined",
                             formal_standard_error=formal["tilt_growth_rate_per_s"] / lam**2,
                             note=("tilt grows: tau is an e-folding time of growth" if lam > 0
                                   else "tilt decays: tau is an e-folding time of decay"))
        else:
            v, se = values[name]
            q = Quantity(name, units, v, se, "determined", formal_standard_error=formal[name],
                         camera_standard_error=camera_se.get(name))
        comparable = True
        cnote = ""
        if name == "nutation_amplitude_rad" and sol.spec.damped:
            comparable = False
            cnote = ("prediction is for the undamped launch; under damping the fitted amplitude is the one at the "
                     "first frame of the record")
        elif name in ("precession_rate_rad_s", "nutation_frequency_rad_s") and sol.spec.damped:
            comparable = False
            cnote = ("predictions are for the undamped top at the launch tilt; under damping the tilt, and with it "
                     "this quantity, drift: no difference in standard errors is given")
        elif name in ("tilt_growth_rate_per_s", "tilt_time_constant_s"):
            launch = protocol.launch.tilt_rad
            cone = values["cone_angle_rad"][0]
            if abs(cone - launch) > 1e-3:
                cnote = (f"theory is for steady precession at the launch tilt {launch:.4g} rad; the fitted cone is at "
                         f"{cone:.4g} rad at t_ref, and the rate depends on the tilt")
        elif name in ("equilibrium_tilt_rad", "equilibrium_azimuth_rad") and sol.spec.damped:
            cnote = ("the effective vertical is the cone axis of the undamped top; damping displaces the axis "
                     "from it, so a difference of many standard errors can be the damping rather than the formula")
        if name == "tilt_time_constant_s":
            comparable = q.value is not None
        q = _compare(q, theory, name, comparable and q.status == "determined", cnote)
        if name in truth_values and q.status == "determined":
            tv = truth_values[name]
            pull = (q.value - tv) / q.standard_error if q.standard_error else None
            if name == "equilibrium_azimuth_rad" and pull is not None:
                pull = float(_wrap(np.array(q.value - tv))) / q.standard_error
            q = replace(q, truth=tv, pull=pull)
        quantities[name] = q

    model = _Model(sol.spec)
    raw, white = _residual_fn(model, data)
    r0, r1 = raw(sol.x)
    wr = white(sol.x)[:2 * data.n].reshape(2, -1)
    residuals = pd.DataFrame({"frame": data.frame, "t_s": data.t_s, "theta_resid_rad": r0, "phi_resid_rad": r1,
                              "theta_resid_norm": wr[0], "phi_resid_norm": wr[1]})
    tt = np.linspace(data.t_s[0], data.t_s[-1], min(20000, max(2000, 20 * data.n)))
    seg = np.searchsorted(data.t_s, tt, side="right") - 1
    th_c, ph_c = model.lab(sol.x, tt - data.t_ref_s, data.segment[np.clip(seg, 0, data.n - 1)])
    curve = pd.DataFrame({"t_s": tt, "theta_rad": th_c, "phi_rad": ph_c})
    params = {n: (float(v), float(np.sqrt(max(sol.cov[i, i], 0.0)))) for i, (n, v) in enumerate(zip(names, sol.x))}
    return FitResult(spec=sol.spec, params=params, quantities=quantities, chi2=sol.chi2, dof=sol.dof,
                     residuals=residuals, model_curve=curve, t_ref_s=data.t_ref_s, errors=errors, notes=tuple(notes),
                     x=sol.x, covariance=sol.cov, wall_time_s=time.perf_counter() - start_time, terms=terms,
                     phase_uncertainty_rad=phases)


def linear_response(angles: pd.DataFrame, fit: FitResult, protocol: Protocol, *, prediction: dict | None = None):
    """The linearised estimator about a fit of noiseless ``angles``.

    Returns a function that takes other angles at the same frames (the same motion plus noise)
    and gives each determined quantity after one Gauss-Newton step from ``fit.x``:
    ``x = x0 - (J^T J)^-1 J^T r(x0)``.  That is what the fit would return if the model were
    linear over the noise; where a real fit of the same record lands elsewhere (by a sizeable
    fraction of a standard error), its error bars are not Cramer-Rao bounds.
    """
    scene = model_for_scene(protocol, prediction)
    model = _Model(fit.spec)
    data0 = fit_data_from_angles(angles, None, scene.precession_hint_rad_s)
    _, white0 = _residual_fn(model, data0)
    J0 = white0.jac(fit.x)
    cov0 = np.linalg.pinv(J0.T @ J0, rcond=1e-14, hermitian=True)
    fns = _quantity_functions(fit.spec, model.names)
    keys = [k for k in fns if k in fit.quantities and fit.quantities[k].status == "determined"]

    def respond(noisy: pd.DataFrame) -> dict[str, float]:
        _, white = _residual_fn(model, fit_data_from_angles(noisy, None, scene.precession_hint_rad_s))
        x = fit.x - cov0 @ (J0.T @ white(fit.x))
        return {k: float(fns[k](x)) for k in keys}

    return respond


def _statistical_covariance(sol: _Solved, data: FitData) -> np.ndarray | None:
    """Parameter covariance with the camera modes held at their fitted values (None without modes).

    Padded with zeros for the modes, so that the difference from the full covariance is the
    camera model's share.
    """
    m = sol.spec.camera_modes
    if not m:
        return None
    model = _Model(sol.spec)
    _, white = _residual_fn(model, data)
    nb = len(sol.x) - m
    J = white.jac(sol.x)[:2 * data.n, :nb]
    cov = np.zeros_like(sol.cov)
    cov[:nb, :nb] = np.linalg.pinv(J.T @ J, rcond=1e-14, hermitian=True)
    return cov


def _truth_values(truth: pd.DataFrame, data: FitData, spec: ModelSpec, x: np.ndarray, fns: dict) -> dict[str, float]:
    """The same model fitted to noiseless truth at the measured frame times."""
    t = truth["t_s"].to_numpy(float)
    order = np.argsort(t)
    t = t[order]
    th = truth["theta_rad"].to_numpy(float)[order]
    ph = np.unwrap(truth["phi_rad"].to_numpy(float)[order])
    lo, hi = data.t_s[0], data.t_s[-1]
    # container timestamps are rounded (to 1 ms, say): allow half a frame at either end
    slack = 0.5 * float(np.median(np.diff(data.t_s))) if data.n > 1 else 0.0
    if t[0] > lo + slack or t[-1] < hi - slack:
        raise FitError(f"the truth table ({t[0]:.6g}..{t[-1]:.6g} s) does not cover the measured times "
                       f"({lo:.6g}..{hi:.6g} s)")
    keep = np.concatenate([[True], np.diff(t) > 0])
    th_i = CubicSpline(t[keep], th[keep])(data.t_s)
    ph_i = _wrap(CubicSpline(t[keep], ph[keep])(data.t_s))
    # the data's own weights: the truth is what this estimator converges to without noise
    d = replace(data, theta_rad=th_i, phi_rad=ph_i, camera_shift=None, exposure_s=None)  # instantaneous
    spec = replace(spec, camera_modes=0)
    names = _Model(spec).names
    sol = _solve(spec, d, dict(zip(names, x)))
    return {k: float(f(sol.x)) for k, f in fns.items()}
