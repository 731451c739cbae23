"""Typed records of an experiment plan (:func:`gyrorig.plan.plan_experiment`).

A :class:`Plan` is frozen; its advice is data (:class:`Advice`: a kind, the numbers it is about, the text for
people), its quantities :class:`ExpectedQuantity` records.  :meth:`Plan.to_dict` gives the layout of
``plan.json`` (``recommendations`` as the advice's texts, ``advice`` with the kinds).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Mapping

from ._frozen import FrozenDict
from .prediction import Prediction

__all__ = ["Plan", "Advice", "AdviceKind", "ExpectedQuantity", "DampingAssessment"]


class AdviceKind(StrEnum):
    """What a piece of a plan's advice is about."""

    #: the protocol has no camera: nothing assessed
    NO_CAMERA = "no-camera"
    #: the tip's spot leaves the image (in some frames, or in all: nothing measurable)
    FIELD_OF_VIEW = "field-of-view"
    #: the tip stays on the vertical (a sleeping top): no azimuth, nothing to measure
    AZIMUTH_UNDEFINED = "azimuth-undefined"
    #: the tip comes near (or beyond) the limb of its sphere as the camera sees it: read at a wrong tilt there
    LIMB = "limb"
    #: the tip marker is off the symmetry axis
    MARKER_OFF_AXIS = "marker-off-axis"
    #: the frame rate against the nutation (``values``: ``minimum_fps``; a problem when it cannot resolve it)
    FRAME_RATE = "frame-rate"
    SATURATION = "saturation"
    #: the longest exposure for under half a pixel of blur (``values``: ``maximum_exposure_s``)
    EXPOSURE = "exposure"
    ROLLING_SHUTTER = "rolling-shutter"
    #: the marker is too small for a robust centroid
    MARKER_SIZE = "marker-size"
    MARKER_PLACEMENT = "marker-placement"
    #: the length for every quantity's target precision (``values``: ``length_s``, ``quantity``)
    RECORDING_LENGTH = "recording-length"
    #: the record holds too little precession for the fit to tell a table not level from the cone (``values``:
    #: ``length_s``, ``turns``)
    LEVEL = "level"
    #: the fit model finds no minimum on the simulated record: no expected errors
    FIT_FAILED = "fit-failed"
    #: the fit model misses part of the simulated motion
    MODEL_MISFIT = "model-misfit"
    #: noisy records needed a term the plan left out
    MODEL_CHANGED = "model-changed"
    #: the record is too short for the fit model to be linear over the noise (``values``: ``length_s``)
    RECORD_TOO_SHORT = "record-too-short"
    #: theory's own error exceeds the expected measurement error (``values``: ``quantity``, ``parameter`` ...)
    PREDICTION_LIMIT = "prediction-limit"
    #: which of the paper's equations the damping lets the rig test
    DAMPING = "damping"


@dataclass(frozen=True)
class Advice:
    """One piece of advice: its kind, whether it is a problem of the rig or camera as planned (not a
    suggestion), the numbers it is about, and the text for people."""

    kind: AdviceKind
    text: str
    problem: bool = False
    values: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "values", FrozenDict(dict(self.values)))

    def __str__(self) -> str:
        return self.text

    def to_dict(self) -> dict:
        return {"kind": str(self.kind), "problem": self.problem, "text": self.text, "values": dict(self.values)}


@dataclass(frozen=True)
class ExpectedQuantity:
    """What a record of the planned length will give for one quantity (SI units, in ``units``)."""

    name: str
    units: str
    #: whether the record determines it (else ``reason``, ``reason_kind``)
    resolvable: bool
    reason: str | None
    reason_kind: str | None
    #: whether the expected error can be trusted at this length (the fit model linear over the noise)
    reliable: bool
    predicted_paper: float | None
    predicted_exact: float | None
    #: the value the planned fit gives on the simulated record
    simulated: float | None
    #: the Cramér-Rao bound of the fit model for this camera and length
    expected_standard_error: float | None
    #: theory's own standard error from the rig's parameter uncertainties (None: exact inputs)
    prediction_standard_error: float | None
    expected_relative_error: float | None = None
    #: (paper - exact) in expected standard errors: whether the record can tell the paper's formula from exact
    paper_vs_exact_in_se: float | None = None

    def to_dict(self) -> dict:
        out = {k: getattr(self, k) for k in ("units", "resolvable", "reason", "reason_kind", "reliable",
                                             "predicted_paper", "predicted_exact", "simulated",
                                             "expected_standard_error", "prediction_standard_error")}
        for k in ("expected_relative_error", "paper_vs_exact_in_se"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        return out


@dataclass(frozen=True)
class DampingAssessment:
    """The scene's damping models, and whether it shows the tilt drift eqs. 25a/26 are about."""

    models: tuple[str, ...]
    tests_tilt_drift: bool

    def to_dict(self) -> dict:
        return {"models": list(self.models), "tests_tilt_drift": self.tests_tilt_drift}


def _frozen(m: Mapping | None) -> Mapping | None:
    return None if m is None else FrozenDict(dict(m))


@dataclass(frozen=True)
class Plan:
    """What a rig and camera will measure (:func:`gyrorig.plan.plan_experiment`).

    ``camera`` (the resolution checks: ``fps``, ``exposure_s``, the spot's ``radius_px``, ``sigma_px``,
    ``signal_adu``, ``background_adu``, ``saturates``, per-frame angle errors, ``nutation_hz``,
    ``frames_per_nutation_period``, ``resolves_nutation``, ``motion_blur_px``, ``rolling_shutter_skew_px``,
    ``marker_in_view_fraction``) and ``recording`` (``length_s``, each quantity's ``length_needed_s``,
    ``model_misfit``, ``noisy_draws``, ``linear_regime``, ``length_for_linear_regime_s``) are read-only
    mappings; None where the protocol has no camera.
    """

    protocol: str
    prediction: Prediction
    advice: tuple[Advice, ...] = ()
    camera: Mapping[str, Any] | None = None
    quantities: Mapping[str, ExpectedQuantity] = field(default_factory=dict)
    recording: Mapping[str, Any] | None = None
    #: the fit model chosen on the simulated record, and the terms every record of this length should be fitted
    #: with (``gyrorig fit --terms plan.json``)
    fit_model: Mapping[str, Any] | None = None
    fit_terms: Mapping[str, Any] | None = None
    damping: DampingAssessment | None = None
    note: str = ""
    wall_time_s: float = 0.0
    #: a Monte Carlo of render -> track -> smooth -> fit beside the plan (``gyrorig plan --monte-carlo``)
    monte_carlo: Mapping[str, Any] | None = None

    def __post_init__(self):
        object.__setattr__(self, "advice", tuple(self.advice))
        object.__setattr__(self, "quantities", FrozenDict(dict(self.quantities)))
        for name in ("camera", "recording", "fit_model", "fit_terms", "monte_carlo"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))

    @property
    def recommendations(self) -> tuple[str, ...]:
        """The advice's texts, in order."""
        return tuple(a.text for a in self.advice)

    def advice_of(self, kind: AdviceKind | str) -> tuple[Advice, ...]:
        """The advice of one kind."""
        return tuple(a for a in self.advice if a.kind == AdviceKind(kind))

    @property
    def problems(self) -> tuple[Advice, ...]:
        """The advice that names a problem of the rig or camera as planned."""
        return tuple(a for a in self.advice if a.problem)

    @property
    def measures_nothing(self) -> bool:
        """True when there is a camera but the plan has no expected errors (the camera never sees the tip, or sees
        it only on the vertical, where the tip has no azimuth, or the fit model finds no minimum on the record)."""
        return self.camera is not None and not self.quantities

    def to_dict(self) -> dict:
        """The layout of ``plan.json``."""
        out: dict[str, Any] = {"protocol": self.protocol, "prediction": self.prediction.to_dict(),
                               "recommendations": list(self.recommendations),
                               "advice": [a.to_dict() for a in self.advice],
                               "camera": None if self.camera is None else dict(self.camera)}
        if self.camera is not None:
            out["quantities"] = {k: q.to_dict() for k, q in self.quantities.items()}
        for name in ("recording", "fit_model", "fit_terms", "monte_carlo"):
            if getattr(self, name) is not None:
                out[name] = dict(getattr(self, name))
        out["prediction_limits"] = [{**a.values, "text": a.text} for a in self.advice_of(AdviceKind.PREDICTION_LIMIT)]
        if self.damping is not None:
            out["damping"] = self.damping.to_dict()
        if self.note:
            out["note"] = self.note
        out["wall_time_s"] = self.wall_time_s
        return out
