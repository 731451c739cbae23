"""Predictions with error bars: a protocol's parameter uncertainties carried into theory's predictions.

Each uncertain parameter (:mod:`gyrorig.parameters`) is moved by one standard deviation either way
and :func:`gyrorig.theory.predict` re-run: the central difference is the linear map, the
asymmetry of the two moves its curvature.  The linearised covariance is ``G C G^T`` with ``C`` the
parameters' covariance.  Where a prediction is not linear over one standard deviation of some
parameter (a curvature above :data:`NONLINEAR_RATIO` of the slope), its standard deviation comes
from ``draws`` samples of the parameters instead, and says so.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from .gimbals import gimbal_prediction
from .prediction import PREDICTED_KINDS, Prediction, PredictionUncertainty
from .protocols import Protocol, ProtocolError, checked_rig
from .theory import predict

__all__ = ["perturbed", "predict_with_uncertainty", "prediction_scalars", "gimbal_prediction_with_uncertainty",
           "NONLINEAR_RATIO"]
#: |f(+sd) + f(-sd) - 2 f(0)| / |f(+sd) - f(-sd)| above this: the prediction is sampled, not linearised
NONLINEAR_RATIO = 0.1
_DAMPING = re.compile(r"pivot\.damping(?:\[(\d+)\])?\.(\w+)")


def perturbed(protocol: Protocol, changes: dict[str, float]) -> Protocol:
    """The protocol with the named parameters (``rig.mass_kg``, ``launch.spin_rate_rad_s``,
    ``pivot.damping.coefficient_N_m_s``, ``gimbal.outer_inertia_kg_m2`` ...) set to new values; ProtocolError for an
    impossible rig."""
    rig, launch, damping, gimbal = protocol.rig, protocol.launch, list(protocol.pivot.damping), protocol.gimbal
    for name, value in changes.items():
        section, _, key = name.partition(".")
        if section == "rig":
            rig = replace(rig, **{key: float(value)})
        elif section == "launch":
            launch = replace(launch, **{key: float(value)})
        elif section == "gimbal" and gimbal is not None:
            if float(value) < 0 or (key == "cross_inertia_kg_m2" and float(value) <= 0):
                raise ProtocolError(f"{name} = {value:g}: an inertia must be positive")
            gimbal = replace(gimbal, **{key: float(value)})
        elif (m := _DAMPING.fullmatch(name)) and damping:
            i = int(m.group(1) or 0)
            damping[i] = replace(damping[i], **{m.group(2): float(value)})
        else:
            raise ProtocolError(f"{name}: not a parameter this protocol has")
    return replace(protocol, rig=checked_rig(rig), launch=launch, pivot=replace(protocol.pivot, damping=tuple(damping)),
                   gimbal=gimbal)


def prediction_scalars(prediction: Prediction) -> dict[tuple[str, str], float]:
    """The finite numbers of a prediction: ``(quantity, kind) -> value`` for kind in
    :data:`~gyrorig.prediction.PREDICTED_KINDS`."""
    out = {}
    for name, q in prediction.quantities.items():
        for kind in PREDICTED_KINDS:
            v = q.value(kind)
            if v is not None and math.isfinite(v):
                out[(name, kind)] = float(v)
    return out


def _vector(pred: Prediction, keys: list) -> np.ndarray:
    s = prediction_scalars(pred)
    return np.array([s.get(k, np.nan) for k in keys])


def _moves(protocol: Protocol, name: str, x0: float, sd: float, values: Callable[[Protocol], np.ndarray]):
    """``values`` at ``x0 + h`` and ``x0 - h`` of parameter ``name``, and ``h``: ``h = sd``, or ``sd / 10`` when a
    whole sd makes the rig impossible."""
    for h in (sd, 0.1 * sd):
        try:
            return values(perturbed(protocol, {name: x0 + h})), values(perturbed(protocol, {name: x0 - h})), h
        except ProtocolError:
            continue
    raise ProtocolError(f"{name} = {x0:g} +- {sd:g}: moving it by even a tenth of its sd makes the rig impossible")


def _sampled_sd(protocol: Protocol, names: list, x0: np.ndarray, cov: np.ndarray, keys: list, draws: int,
                simulate_damping: bool, rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """The SD of each prediction over parameter draws (impossible rigs rejected), and the draws used."""
    rows = []
    for x in rng.multivariate_normal(x0, cov, size=draws, method="eigh"):
        try:
            p = perturbed(protocol, dict(zip(names, x)))
        except ProtocolError:
            continue
        rows.append(_vector(predict(p, simulate_damping=simulate_damping), keys))
    if len(rows) < 2:
        return np.full(len(keys), np.nan), len(rows)
    return np.nanstd(np.array(rows), axis=0, ddof=1), len(rows)


def predict_with_uncertainty(protocol: Protocol, *, prediction: Prediction | None = None,
                             simulate_damping: bool = True, draws: int = 100,
                             rng: np.random.Generator | None = None) -> Prediction:
    """:func:`gyrorig.theory.predict`, with each predicted number's standard deviation from the protocol's
    parameter uncertainties.

    Every quantity gains ``<kind>_sd`` for ``paper``, ``corrected`` and ``exact`` (where it has
    them) and an ``uncertainty`` (:class:`~gyrorig.prediction.PredictionUncertainty`: ``method``,
    ``linear`` or ``sampled``; ``by_parameter``, each parameter's share of the exact value's variance,
    correlations left out; ``nonlinearity``, the largest curvature ratio).  Without uncertain parameters
    the prediction is returned as is.
    """
    pred = prediction if prediction is not None else predict(protocol, simulate_damping=simulate_damping)
    unc = protocol.uncertainty
    if not unc:
        return pred
    idx = [i for i, s in enumerate(unc.sd) if s > 0]
    names = [unc.names[i] for i in idx]
    x0 = np.array([unc.values[i] for i in idx])
    cov = unc.covariance()[np.ix_(idx, idx)]
    keys = list(prediction_scalars(pred))
    f0 = _vector(pred, keys)
    G = np.zeros((len(keys), len(names)))
    curvature = np.zeros((len(keys), len(names)))
    for j, name in enumerate(names):
        plus, minus, h = _moves(protocol, name, x0[j], math.sqrt(cov[j, j]),
                                lambda p: _vector(predict(p, simulate_damping=simulate_damping), keys))
        G[:, j] = (plus - minus) / (2 * h)
        with np.errstate(divide="ignore", invalid="ignore"):
            curvature[:, j] = np.where(np.abs(plus - minus) > 0, np.abs(plus + minus - 2 * f0) / np.abs(plus - minus),
                                       np.where(np.abs(plus + minus - 2 * f0) > 0, np.inf, 0.0))
    G = np.nan_to_num(G)
    var = np.einsum("ij,jk,ik->i", G, cov, G)
    sd = np.sqrt(np.maximum(var, 0.0))
    nonlinear = np.max(curvature, axis=1) > NONLINEAR_RATIO
    used = 0
    if np.any(nonlinear) and draws > 1:
        sampled, used = _sampled_sd(protocol, names, x0, cov, keys, draws, simulate_damping,
                                    rng if rng is not None else np.random.default_rng(0))
        sd = np.where(nonlinear & np.isfinite(sampled), sampled, sd)
    changes: dict[str, dict] = {name: {} for name in pred.quantities}
    for i, (q, kind) in enumerate(keys):
        changes[q][f"{kind}_sd"] = float(sd[i])
        if kind == "exact":
            share = G[i] ** 2 * np.diag(cov)
            total = float(share.sum())
            changes[q]["uncertainty"] = PredictionUncertainty(
                method="sampled" if nonlinear[i] and used > 1 else "linear",
                draws=used if nonlinear[i] else 0,
                nonlinearity=float(np.max(curvature[i])),
                by_parameter={n: (float(s / total) if total > 0 else 0.0) for n, s in zip(names, share)})
    return pred.with_quantities({name: replace(q, **changes[name]) for name, q in pred.quantities.items()},
                                parameter_uncertainty=unc.as_dict())


#: the quantities and kinds of :func:`gyrorig.gimbals.gimbal_prediction` that carry error bars
_GIMBAL_KEYS = tuple((q, kind) for q in ("nutation_frequency_rad_s", "precession_rate_slow_rad_s")
                     for kind in ("gimbal", "fast_top"))


def gimbal_prediction_with_uncertainty(protocol: Protocol) -> dict:
    """:func:`gyrorig.gimbals.gimbal_prediction` with each value's standard deviation (``gimbal_sd``,
    ``fast_top_sd``) from the protocol's parameter uncertainties (``[gimbal]``'s included): linear, by central
    differences over one sd of each parameter (a tenth of one where a whole sd makes the rig impossible), and
    their covariance; ``parameter_uncertainty`` beside.  Without uncertain parameters the prediction as is."""
    pred = gimbal_prediction(protocol)
    unc = protocol.uncertainty
    keys = [(q, kind) for q, kind in _GIMBAL_KEYS if q in pred and math.isfinite(pred[q].get(kind, math.nan))]
    if not unc or not keys:
        return pred
    idx = [i for i, s in enumerate(unc.sd) if s > 0]
    cov = unc.covariance()[np.ix_(idx, idx)]

    def values(p: Protocol) -> np.ndarray:
        moved = gimbal_prediction(p)
        return np.array([moved.get(q, {}).get(kind, math.nan) for q, kind in keys])

    G = np.zeros((len(keys), len(idx)))
    for j, i in enumerate(idx):
        plus, minus, h = _moves(protocol, unc.names[i], unc.values[i], math.sqrt(cov[j, j]), values)
        G[:, j] = (plus - minus) / (2 * h)
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", G, cov, G), 0.0))
    for (q, kind), s in zip(keys, sd):
        pred[q][f"{kind}_sd"] = float(s)
    pred["parameter_uncertainty"] = unc.as_dict()
    return pred
