"""What a fit returns: quantities with theory beside them, the model, and its outcomes as data.

Outcomes that other code acts on are fields and enums, never text to search: a quantity's
:class:`QuantityStatus` and :class:`Undetermined` reason, the fit's :class:`ErrorKind`, and its
notes as :class:`Note` records (a :class:`NoteKind` and the model term concerned, with the text
for people).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import pandas as pd

from .._format import with_error
from .constraints import Constraints
from .spec import FitTerms, ModelSpec

__all__ = ["QUANTITY_UNITS", "QuantityStatus", "Undetermined", "Reason", "ErrorKind", "NoteKind", "Note", "Quantity",
           "MotionBreak", "FitResult", "NONLINEAR_PHASE_RAD", "TERM_P_VALUE"]

QUANTITY_UNITS = {
    "precession_rate_rad_s": "rad/s",
    "nutation_frequency_rad_s": "rad/s",
    "nutation_amplitude_rad": "rad",
    "tilt_growth_rate_per_s": "1/s",
    "tilt_time_constant_s": "s",
    "precession_growth_rate_per_s": "1/s",
    "tip_offset_rad": "rad",
    "equilibrium_tilt_rad": "rad",
    "equilibrium_azimuth_rad": "rad",
    "cone_angle_rad": "rad",
}
#: a rate-like parameter whose standard error leaves more than this phase (rad) uncertain at the
#: record's ends puts the fit outside its linear regime (see :func:`gyrorig.fit.uncertainty.phase_uncertainty`)
NONLINEAR_PHASE_RAD = 0.3
#: significance for adding a model term (nutation, a harmonic, the lean): chi-square (or F) tail probability
TERM_P_VALUE = 1e-3


class QuantityStatus(StrEnum):
    DETERMINED = "determined"
    UNDETERMINED = "undetermined"


class Undetermined(StrEnum):
    """Why a quantity is not determined."""

    #: the frame rate does not resolve the predicted nutation frequency
    CAMERA_TOO_SLOW = "camera-too-slow"
    #: the record covers fewer than two predicted nutation periods
    TOO_FEW_PERIODS = "too-few-periods"
    #: the chi-square does not want a nutation term
    NOT_SIGNIFICANT = "not-significant"
    #: the fit with the term did not converge
    NOT_CONVERGED = "not-converged"
    #: the fitted frequency left the band (0, Nyquist)
    OUT_OF_BAND = "out-of-band"
    #: tau = 1 / rate with a rate consistent with zero
    CONSISTENT_WITH_ZERO = "consistent-with-zero"
    #: the tilt is within a few of its errors of the pole: the azimuth (and its rate) is not defined
    AZIMUTH_UNDEFINED = "azimuth-undefined"


@dataclass(frozen=True)
class Reason:
    """Why something is not determined: the kind, and the text for people."""

    kind: Undetermined
    text: str


class ErrorKind(StrEnum):
    """Where the standard errors come from."""

    #: the Cramer-Rao bound of the model for the tracker's errors, ``(J^T J)^-1``
    FORMAL = "formal"
    #: formal, times sqrt(chi2_red) (reduced chi-square significantly above 1)
    SCALED = "scaled"
    #: a moving-block bootstrap of the residuals (residuals not white)
    BOOTSTRAP = "bootstrap"


class NoteKind(StrEnum):
    """What a note of the fit is about."""

    SCENE = "scene"
    TERMS_GIVEN = "terms-given"
    AZIMUTH_SEGMENTS = "azimuth-segments"
    HARMONIC_ABOVE_NYQUIST = "harmonic-above-nyquist"
    TERM_MODELLED = "term-modelled"
    #: the record needed a term the plan did not have: added
    TERM_BEYOND_PLAN = "term-beyond-plan"
    #: ... but it cannot be told apart from the planned model on this record: left out
    TERM_NOT_IDENTIFIABLE = "term-not-identifiable"
    PLANNED_TERM_FAILED = "planned-term-failed"
    TERM_LEFT_OUT = "term-left-out"
    RESIDUALS_NOT_WHITE = "residuals-not-white"
    ERRORS_SCALED = "errors-scaled"
    #: the residuals scatter far less than the frames' errors say: the standard errors are conservative
    ERRORS_LARGE = "errors-large"
    RECORD_TOO_SHORT = "record-too-short"
    SYSTEMATIC = "systematic"
    CAMERA_MODES = "camera-modes"
    #: parameters held fixed or given priors by the user
    CONSTRAINED = "constrained"
    #: the frames come from an inter-coded video (P, B pictures): its motion compensation can smooth fast motion
    CODEC_SMOOTHING = "codec-smoothing"
    ROLLING_SHUTTER = "rolling-shutter"
    READOUT_BEYOND_FRAME = "readout-beyond-frame"
    #: a fixed value or prior far from what the record alone says (the term is the parameter)
    PRIOR_CONFLICT = "prior-conflict"
    #: an input value that is allowed but unlikely (a unit slip, :mod:`gyrorig.plausibility`)
    PLAUSIBILITY = "plausibility"
    #: the record's geometry disagrees with the protocol's (the launch tilt): a tip marker or pose stated wrong
    GEOMETRY = "geometry"
    #: the smoother gated more frames than its model allows: the fit's own model judged which to leave out
    OUTLIERS_BY_FIT = "outliers-by-fit"
    #: the track is flagged near-limb: the tip may have been read on the wrong side of its sphere
    NEAR_LIMB = "near-limb"
    #: an undamped scene's record whose precession and nutation rates change as a changing spin makes them: the
    #: rotor spins down (or up), which the protocol does not say
    SPIN_DOWN = "spin-down"
    #: the record's still ends (a top held before its release, caught before the recording ends) left out
    STILL_ENDS = "still-ends"
    #: the motion changes in a moment (a touch, a bump): the model fits each part but not both; the longer fitted
    MOTION_BREAK = "motion-break"


@dataclass(frozen=True)
class Note:
    """A note of the fit: its kind, the model term it concerns (``""``: none), and the text for people."""

    kind: NoteKind
    text: str
    term: str = ""

    def __str__(self) -> str:
        return self.text

    def as_dict(self) -> dict:
        return {"kind": str(self.kind), "term": self.term, "text": self.text}


@dataclass(frozen=True)
class Quantity:
    """One fitted quantity with what theory says about it."""

    name: str
    units: str
    value: float | None
    standard_error: float | None
    status: QuantityStatus
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
    #: the part of ``note`` that qualifies the comparison with theory (it ends ``note``; "" when none)
    theory_note: str = ""
    #: the Cramer-Rao bound of the fit model for the tracker's errors ((J^T J)^-1, before any
    #: chi-square scaling or bootstrap)
    formal_standard_error: float | None = None
    #: the camera model's share of the standard error (in quadrature; 0 for an exact camera)
    camera_standard_error: float | None = None
    #: why the quantity is undetermined (None when it is determined)
    reason_kind: Undetermined | None = None
    #: the predictions' own standard errors, from the rig's parameter uncertainties (None: exact inputs)
    paper_standard_error: float | None = None
    exact_standard_error: float | None = None
    #: (fit - prediction) / sqrt(s.e.^2 + prediction s.e.^2): the pull against theory, both errors counted
    diff_paper_combined_se: float | None = None
    diff_exact_combined_se: float | None = None
    #: the prediction's share of that combined variance (0: all measurement, 1: all prediction)
    prediction_share: float | None = None
    #: where ``exact`` is evaluated: ``"launch"`` (the protocol's launch) or ``"record"`` (the record's own fitted
    #: state, for a quantity that depends on where a damped top has drifted to; ``exact_nominal`` then holds the
    #: launch's value)
    prediction_at: str = "launch"
    exact_nominal: float | None = None

    @property
    def determined(self) -> bool:
        return self.status is QuantityStatus.DETERMINED

    def as_dict(self) -> dict:
        return {k: (str(v) if isinstance(v, StrEnum) else v)
                for k, v in ((k, getattr(self, k)) for k in self.__dataclass_fields__)}


def _quantity_lines(q: Quantity) -> list[str]:
    """A quantity for :meth:`FitResult.report`: value, error, relative error; theory; truth."""
    if not q.determined:
        return [f"    {q.name}: undetermined ({q.reason})"]
    rel = f" ({abs(q.standard_error / q.value):.2g} relative)" if q.value and q.standard_error else ""
    out = [f"    {q.name}: {with_error(q.value, q.standard_error)} {q.units}{rel}"]
    if q.camera_standard_error:
        out[0] += f"; camera model {q.camera_standard_error:.2g} of the error"
    for kind in ("exact", "paper"):
        value = getattr(q, kind)
        if value is None or not math.isfinite(value):
            continue
        psd = getattr(q, f"{kind}_standard_error")
        label = "exact at the record's state" if kind == "exact" and q.prediction_at == "record" else kind
        line = f"        {label}: {with_error(value, psd)}" + (f" ({q.exact_source})" if kind == "exact" and
                                                               q.exact_source else "")
        if value != 0:
            line += f"; fit - {kind} {100 * (q.value - value) / abs(value):+.3g} %"
        diff = getattr(q, f"diff_{kind}_combined_se")
        if diff is None:
            diff = getattr(q, f"diff_{kind}_se")
        if diff is not None:
            line += f", {diff:+.3g} combined s.e." if psd else f", {diff:+.3g} s.e."
        out.append(line)
    if q.note:
        out.append(f"        ({q.note})")
    if q.truth is not None:
        out.append(f"        truth: {q.truth:.8g}" + (f"; pull {q.pull:+.2f}" if q.pull is not None else ""))
    return out


@dataclass(frozen=True)
class MotionBreak:
    """Where the record's motion breaks: the times of the last frame before it and the first after [s], the reduced
    chi-squares of the frames fitted when it was found, whole and each part alone, and the split's F statistic
    (:mod:`gyrorig.fit.breaks`)."""

    t_before_s: float
    t_after_s: float
    chi2_red_whole: float
    chi2_red_before: float
    chi2_red_after: float
    f_statistic: float

    def as_dict(self) -> dict:
        return {"t_before_s": self.t_before_s, "t_after_s": self.t_after_s, "chi2_red_whole": self.chi2_red_whole,
                "chi2_red_before": self.chi2_red_before, "chi2_red_after": self.chi2_red_after,
                "f_statistic": self.f_statistic}

    def describe(self) -> str:
        return (f"the motion breaks between {self.t_before_s:.4g} s and {self.t_after_s:.4g} s (a touch, a bump "
                f"against a stop, a knock?): the model fits the frames before it and those after it each on its "
                f"own (reduced chi-square {self.chi2_red_before:.3g} and {self.chi2_red_after:.3g}) but not both "
                f"with one set of parameters ({self.chi2_red_whole:.3g})")


@dataclass(frozen=True, repr=False)
class FitResult:
    """Outcome of :func:`gyrorig.fit.fit_angles`.  ``print(result)`` shows :meth:`report`."""

    spec: ModelSpec
    params: dict[str, tuple[float, float]]
    quantities: dict[str, Quantity]
    chi2: float
    dof: int
    residuals: pd.DataFrame
    model_curve: pd.DataFrame
    t_ref_s: float
    error_kind: ErrorKind
    notes: tuple[Note, ...] = ()
    x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    wall_time_s: float = 0.0
    #: how the optional model terms were chosen
    terms: FitTerms | None = None
    #: phase left uncertain at the record's ends by each rate-like parameter
    phase_uncertainty_rad: dict[str, float] = field(default_factory=dict)
    #: with bootstrap errors: (replicates, block length in frames)
    bootstrap: tuple[int, int] | None = None
    #: parameters held fixed or given priors (:class:`gyrorig.fit.constraints.Constraints`)
    constraints: Constraints = Constraints()
    #: breaks in the motion found (:mod:`gyrorig.fit.breaks`), in the order found; the fit is of the part kept
    breaks: tuple[MotionBreak, ...] = ()

    @property
    def starts_after_break(self) -> bool:
        """Whether the part fitted starts after a break in the motion (the protocol's launch is then not its start)."""
        t0 = float(self.residuals.t_s.min()) if len(self.residuals) else math.nan
        return any(b.t_after_s <= t0 for b in self.breaks)

    @property
    def linear_regime(self) -> bool:
        """True when every rate-like parameter is known well enough for the errors to be Cramer-Rao bounds."""
        return all(v <= NONLINEAR_PHASE_RAD for v in self.phase_uncertainty_rad.values())

    @property
    def chi2_red(self) -> float:
        return self.chi2 / max(self.dof, 1)

    @property
    def errors(self) -> str:
        """Where the standard errors come from, for people."""
        if self.error_kind is ErrorKind.BOOTSTRAP:
            reps, block = self.bootstrap
            return f"moving-block bootstrap ({reps} replicates, block {block} frames)"
        return "formal x sqrt(chi2_red)" if self.error_kind is ErrorKind.SCALED else "formal"

    def notes_of(self, *kinds: NoteKind) -> tuple[Note, ...]:
        """The notes of the given kinds."""
        return tuple(n for n in self.notes if n.kind in kinds)

    @property
    def terms_beyond_plan(self) -> tuple[str, ...]:
        """Optional terms the record needed beyond the planned model (added)."""
        return tuple(n.term for n in self.notes_of(NoteKind.TERM_BEYOND_PLAN))

    @property
    def terms_not_identifiable(self) -> tuple[str, ...]:
        """Optional terms the record asked for but could not tell apart from the planned model (left out)."""
        return tuple(n.term for n in self.notes_of(NoteKind.TERM_NOT_IDENTIFIABLE))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The fitted parameters, in the order of ``x`` and ``covariance``."""
        return tuple(self.params)

    @property
    def correlation(self) -> np.ndarray:
        """The parameters' correlation matrix (from ``covariance``; the same whatever scales the errors)."""
        sd = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            corr = self.covariance / np.outer(sd, sd)
        return np.where(np.outer(sd, sd) > 0, corr, np.nan)

    @property
    def p_value(self) -> float:
        """The chance of a chi-square this large or larger if the model and the per-frame errors were right."""
        from scipy.stats import chi2

        return float(chi2.sf(self.chi2, self.dof)) if self.dof > 0 else math.nan

    def report(self) -> str:
        """The fit for people (in the manner of lmfit's ``fit_report``): the model and its chi-square, each
        quantity to the digits its standard error resolves, with its relative error, theory beside it (the
        difference in % and in combined standard errors), the truth and pull of a synthetic run, and the notes."""
        spec = self.spec
        lines = ["[[Fit]]",
                 f"    model: {spec.harmonics} nutation harmonic(s), axis {spec.axis_label}, "
                 f"{'damped' if spec.damped else 'undamped'}{', spin decaying' if spec.spin_decay else ''}, "
                 f"{len(self.params)} parameters",
                 f"    chi-square: {self.chi2:.5g} for {self.dof} degrees of freedom (reduced {self.chi2_red:.4g}, "
                 f"p = {self.p_value:.2g})",
                 f"    errors: {self.errors}",
                 "[[Quantities]]"]
        for q in self.quantities.values():
            lines += _quantity_lines(q)
        if self.notes:
            lines.append("[[Notes]]")
            lines += [f"    - {n.text} [{n.kind}]" for n in self.notes]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        names = ", ".join(self.quantities)
        return (f"<FitResult chi2_red={self.chi2_red:.4g} dof={self.dof} errors={self.error_kind!s} "
                f"quantities=[{names}] notes={len(self.notes)}>")

    def to_frame(self) -> pd.DataFrame:
        """The quantities as a table, one row each (:class:`Quantity`'s fields as columns), indexed by name."""
        return pd.DataFrame([q.as_dict() for q in self.quantities.values()]).set_index("name")

    def _repr_html_(self) -> str:
        """Jupyter: quantity, value, standard error, the exact prediction and the pull against it."""
        cols = ["value", "standard_error", "exact", "diff_exact_se", "truth", "pull", "status"]
        frame = self.to_frame()
        table = frame[[c for c in cols if c in frame]].to_html(float_format=lambda v: f"{v:.6g}", na_rep="")
        return (f"<p>gyrorig fit: chi2_red = {self.chi2_red:.3g} ({self.dof} dof), errors {self.errors}</p>"
                + table)

    def summary(self) -> dict:
        """The content of ``fit.json`` that comes from the fit."""
        model = {**self.spec.summary(), "terms_chosen": self.terms.source if self.terms is not None else "",
                 "linear_regime": self.linear_regime, "phase_uncertainty_rad": dict(self.phase_uncertainty_rad)}
        return {
            "model": model, "t_ref_s": self.t_ref_s, "chi2": self.chi2, "dof": self.dof, "chi2_red": self.chi2_red,
            "errors": self.errors, "error_kind": str(self.error_kind), "notes": [n.as_dict() for n in self.notes],
            "quantities": {k: q.as_dict() for k, q in self.quantities.items()},
            "parameters": {k: {"value": v, "standard_error": s} for k, (v, s) in self.params.items()},
            # the formal covariance (J^T J)^-1 of the parameters above, and their correlation
            "parameter_covariance": {"names": list(self.parameter_names),
                                     "covariance": self.covariance.tolist(),
                                     "correlation": self.correlation.tolist()},
            "constraints": {**self.constraints.as_dict(), "unused": self.constraints.unused(self.spec)},
            "breaks": [b.as_dict() for b in self.breaks],
            "wall_time_s": self.wall_time_s,
        }

