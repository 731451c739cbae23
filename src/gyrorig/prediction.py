"""Typed records of what theory predicts for a scene (:func:`gyrorig.theory.predict`).

A :class:`Prediction` holds, per predicted quantity, a :class:`PredictedQuantity`: the paper's value as
printed, the corrected form where the printed one is wrong, and the exact value (no approximation; from the
elliptic solution, an exact condition or the simulator, named in ``exact_source``).  With a protocol whose
parameters carry standard deviations, :func:`gyrorig.propagate.predict_with_uncertainty` returns the same record
with each value's standard deviation and a :class:`PredictionUncertainty`.  All records are frozen;
:meth:`Prediction.to_dict` gives the JSON layout of ``theory.json`` and ``plan.json``'s ``prediction``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, Mapping

import numpy as np
import pandas as pd

from ._frozen import FrozenDict

__all__ = ["Prediction", "PredictedQuantity", "PredictionFlags", "PredictionUncertainty", "EquilibriumTip",
           "PREDICTED_KINDS"]

#: the predicted values a quantity can carry (each may have a standard deviation)
PREDICTED_KINDS = ("paper", "corrected", "exact")


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


@dataclass(frozen=True)
class PredictionUncertainty:
    """How a predicted value's standard deviation was found from the protocol's parameter uncertainties."""

    #: ``linear`` (central differences, one sd either way) or ``sampled`` (parameter draws)
    method: str
    #: draws used (0: linear)
    draws: int
    #: the largest curvature ratio ``|f(+sd) + f(-sd) - 2 f(0)| / |f(+sd) - f(-sd)|`` over the parameters
    nonlinearity: float
    #: each parameter's share of the exact value's variance (correlations left out)
    by_parameter: Mapping[str, float]

    def __post_init__(self):
        object.__setattr__(self, "by_parameter", FrozenDict(dict(self.by_parameter)))

    @property
    def largest_share(self) -> tuple[str, float] | None:
        """The parameter with the largest share and its share (None without parameters)."""
        return max(self.by_parameter.items(), key=lambda kv: kv[1]) if self.by_parameter else None

    def to_dict(self) -> dict:
        return {"method": self.method, "draws": self.draws, "nonlinearity": self.nonlinearity,
                "by_parameter": dict(self.by_parameter)}


@dataclass(frozen=True)
class PredictedQuantity:
    """One predicted quantity (SI units, named in ``name``'s suffix)."""

    name: str
    #: the paper's formula as printed (None where the paper has none)
    paper: float | None
    #: no small-angle or fast-top approximation (NaN where it could not be had)
    exact: float
    #: where ``exact`` comes from
    exact_source: str
    #: the corrected form, where the printed one is wrong (None: the paper's stands)
    corrected: float | None = None
    note: str = ""
    #: standard deviations from the protocol's parameter uncertainties (None: exact inputs)
    paper_sd: float | None = None
    corrected_sd: float | None = None
    exact_sd: float | None = None
    uncertainty: PredictionUncertainty | None = None
    #: for a time constant: ``growth``, ``decay`` or ``none`` by the paper's sign and by the exact one
    direction_paper: str | None = None
    direction_exact: str | None = None

    def value(self, kind: str) -> float | None:
        """The value of ``kind`` (:data:`PREDICTED_KINDS`)."""
        if kind not in PREDICTED_KINDS:
            raise ValueError(f"kind = {kind!r}: allowed {PREDICTED_KINDS}")
        return getattr(self, kind)

    def sd(self, kind: str) -> float | None:
        """The standard deviation of ``kind``'s value (None: no parameter uncertainties)."""
        self.value(kind)
        return getattr(self, f"{kind}_sd")

    @property
    def relative_difference(self) -> float | None:
        """``(paper - exact) / |exact|``; None where either is missing or the exact value is zero at the paper's
        scale (a sleeping top's nutation)."""
        if not (_finite(self.paper) and _finite(self.exact)) or abs(self.exact) <= 1e-6 * abs(self.paper):
            return None
        return (self.paper - self.exact) / abs(self.exact)

    @property
    def sign_agrees(self) -> bool | None:
        """Whether the paper's value has the exact one's sign (None where :attr:`relative_difference` is)."""
        if self.relative_difference is None:
            return None
        return bool(np.sign(self.paper) == np.sign(self.exact))

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"paper": self.paper, "exact": self.exact, "exact_source": self.exact_source}
        if self.corrected is not None:
            out["corrected"] = self.corrected
        for kind in PREDICTED_KINDS:
            if getattr(self, f"{kind}_sd") is not None:
                out[f"{kind}_sd"] = getattr(self, f"{kind}_sd")
        if self.relative_difference is not None:
            out["relative_difference"] = self.relative_difference
            out["sign_agrees"] = self.sign_agrees
        if self.direction_paper is not None:
            out["direction"] = {"paper": self.direction_paper, "exact": self.direction_exact}
        if self.uncertainty is not None:
            out["uncertainty"] = self.uncertainty.to_dict()
        if self.note:
            out["note"] = self.note
        return out


@dataclass(frozen=True)
class EquilibriumTip:
    """Where the axis settles with the pivot accelerating: unit tip vectors in the lab."""

    paper: tuple[float, float, float]
    exact: tuple[float, float, float]
    exact_source: str
    #: the angle between the two [rad]
    angle_between_rad: float
    #: whether each leans towards the horizontal acceleration
    paper_leans_towards_acceleration: bool
    exact_leans_towards_acceleration: bool
    note: str = ""

    def to_dict(self) -> dict:
        return {"paper": list(self.paper), "exact": list(self.exact), "exact_source": self.exact_source,
                "angle_between_rad": self.angle_between_rad,
                "leans_towards_acceleration": {"paper": self.paper_leans_towards_acceleration,
                                               "exact": self.exact_leans_towards_acceleration},
                "note": self.note}


@dataclass(frozen=True)
class PredictionFlags:
    """Where the paper's approximations stand for the scene (None: not applicable to it)."""

    #: ``Io^2 Omega^2 / (I Mgh)``: the fast-top formulas want it >= 10
    fast_top_ratio: float | None = None
    fast_top: bool | None = None
    #: launch tilt <= 0.3 rad (the small-tilt forms)
    small_tilt: bool | None = None
    launch_tilt_rad: float | None = None
    #: a free top: the angle between the axis and the angular momentum [rad]
    cone_angle_rad: float | None = None

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class Prediction:
    """What theory predicts for one scene: only the quantities the scene has.

    ``quantities`` maps a quantity's name (``precession_rate_slow_rad_s``, ``precession_rate_fast_rad_s``,
    ``nutation_frequency_rad_s``, ``nutation_amplitude_rad``, ``mean_precession_rate_rad_s``,
    ``tilt_growth_rate_per_s``, ``tilt_time_constant_s``; ``precession_rate_rad_s`` for a free top) to its
    :class:`PredictedQuantity`.
    """

    protocol: str
    flags: PredictionFlags = field(default_factory=PredictionFlags)
    quantities: Mapping[str, PredictedQuantity] = field(default_factory=dict)
    equilibrium_tip: EquilibriumTip | None = None
    #: the protocol's parameter uncertainties the standard deviations come from (None: exact inputs)
    parameter_uncertainty: Mapping[str, Any] | None = None

    def __post_init__(self):
        object.__setattr__(self, "quantities", FrozenDict(dict(self.quantities)))

    def get(self, name: str) -> PredictedQuantity | None:
        """The named quantity, None where the scene has none."""
        return self.quantities.get(name)

    def exact(self, name: str) -> float | None:
        """The named quantity's exact value (None where the scene has none or it is not finite)."""
        q = self.quantities.get(name)
        return q.exact if q is not None and _finite(q.exact) else None

    def with_quantities(self, quantities: Mapping[str, PredictedQuantity], **changes) -> "Prediction":
        """A copy with the quantities replaced (and other fields changed)."""
        return replace(self, quantities=quantities, **changes)

    def table(self) -> pd.DataFrame:
        """One row per quantity (indexed by name): ``paper``, ``corrected``, ``exact``, their standard deviations,
        ``relative_difference``, ``sign_agrees``, ``exact_source``."""
        cols = ("paper", "corrected", "exact", "paper_sd", "corrected_sd", "exact_sd", "relative_difference",
                "sign_agrees", "exact_source")
        return pd.DataFrame([{c: getattr(q, c) for c in cols} for q in self.quantities.values()],
                            index=pd.Index(list(self.quantities), name="quantity"), columns=list(cols))

    def _repr_html_(self) -> str:
        return self.table()._repr_html_()

    def to_dict(self) -> dict:
        """The JSON layout: ``protocol``, ``flags``, one entry per quantity, ``equilibrium_tip`` and
        ``parameter_uncertainty`` where present."""
        out: dict[str, Any] = {"protocol": self.protocol, "flags": self.flags.to_dict()}
        out.update({k: q.to_dict() for k, q in self.quantities.items()})
        if self.equilibrium_tip is not None:
            out["equilibrium_tip"] = self.equilibrium_tip.to_dict()
        if self.parameter_uncertainty is not None:
            out["parameter_uncertainty"] = dict(self.parameter_uncertainty)
        return out
