"""The fitted quantities: derived from the parameters, compared with theory, and with a synthetic truth.

``precession_rate_rad_s``, ``nutation_frequency_rad_s``, ``nutation_amplitude_rad`` (half the
peak-to-peak of the periodic tilt; under damping, at the first frame, the third-order term
included), ``tilt_growth_rate_per_s`` and ``tilt_time_constant_s = 1 / rate`` (damping),
``equilibrium_tilt_rad`` / ``equilibrium_azimuth_rad`` (a fitted axis), ``cone_angle_rad``, and where the rotor's spin
decays ``precession_growth_rate_per_s`` (the precession rate's relative change at t_ref, ``d ln(Omega)/dt``), and
where the tip marker is found off the stem's axis ``tip_offset_rad`` (its distance from the axis over the pivot's).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

from ..geometry import angles_from_tip, wrap_angle
from ..prediction import PredictedQuantity, Prediction
from ..protocols import Protocol
from .constraints import Constraints
from .data import FitData, FitError
from .result import QUANTITY_UNITS, FitResult, Quantity, QuantityStatus, Reason, Undetermined
from .spec import ModelSpec
from .terms import RollingShutter

__all__ = ["quantity_functions", "nutation_amplitude", "theory_values", "build_quantities", "truth_values",
           "at_record_state"]


def nutation_amplitude(spec: ModelSpec, names: list[str], x: np.ndarray) -> float:
    """Half the peak-to-peak of the nutation's tilt over one period (at the first frame when damped). [rad]"""
    ix = {n: i for i, n in enumerate(names)}
    psi = np.linspace(0, 2 * np.pi, 721)[:-1]
    y = np.zeros_like(psi)
    for k in range(1, spec.harmonics + 1):
        y += x[ix[f"tilt_cos_{k}_rad"]] * np.cos(k * psi) + x[ix[f"tilt_sin_{k}_rad"]] * np.sin(k * psi)
    if spec.third_order:
        # at the first frame the third-order term is part of the fundamental (it only decays faster);
        # the two are nearly degenerate, their sum is what the record determines
        y += x[ix["tilt_third_cos_rad"]] * np.cos(psi) + x[ix["tilt_third_sin_rad"]] * np.sin(psi)

    def extreme(sign: float) -> float:  # refined with a parabola through the grid's best points
        i = int(np.argmax(sign * y))
        a, b, c = y[i - 1], y[i], y[(i + 1) % len(y)]
        den = a - 2 * b + c
        return b - 0.125 * (a - c) ** 2 / den if den != 0 else b

    return 0.5 * (extreme(1.0) - extreme(-1.0))


def quantity_functions(spec: ModelSpec) -> dict:
    """Each quantity the model determines, as a function of the parameter vector."""
    names = spec.names()
    ix = {n: i for i, n in enumerate(names)}
    fns = {
        "precession_rate_rad_s": lambda x: x[ix["precession_rate_rad_s"]],
        "cone_angle_rad": lambda x: math.exp(x[ix["log_cone_angle"]]),
    }
    if spec.harmonics:
        fns["nutation_frequency_rad_s"] = lambda x: x[ix["nutation_frequency_rad_s"]]
        fns["nutation_amplitude_rad"] = lambda x: nutation_amplitude(spec, names, x)
    if spec.damped:
        fns["tilt_growth_rate_per_s"] = lambda x: x[ix["tilt_growth_rate_per_s"]]
    if spec.tip_offset:
        fns["tip_offset_rad"] = lambda x: math.hypot(x[ix["tip_offset_a_rad"]], x[ix["tip_offset_b_rad"]])
    if spec.spin_decay:
        fns["precession_growth_rate_per_s"] = lambda x: x[ix["precession_acceleration_rad_s2"]] / x[
            ix["precession_rate_rad_s"]]
    if spec.fit_axis:
        fns["equilibrium_tilt_rad"] = lambda x: x[ix["axis_tilt_rad"]]
        fns["equilibrium_azimuth_rad"] = lambda x: wrap_angle(x[ix["axis_azimuth_rad"]])
    return fns


def theory_values(prediction: Prediction | None) -> dict[str, PredictedQuantity]:
    """Theory's predictions (:func:`gyrorig.theory.predict`) keyed by fit quantity (the equilibrium direction as
    its tilt and azimuth)."""
    if prediction is None:
        return {}
    out = {}
    for key in ("nutation_frequency_rad_s", "nutation_amplitude_rad", "tilt_growth_rate_per_s",
                "tilt_time_constant_s", "precession_growth_rate_per_s"):
        if key in prediction.quantities:
            out[key] = prediction.quantities[key]
    precession = prediction.get("mean_precession_rate_rad_s") or prediction.get("precession_rate_rad_s")
    if precession is not None:
        out["precession_rate_rad_s"] = precession
    e = prediction.equilibrium_tip
    if e is not None:
        paper = angles_from_tip(np.asarray(e.paper) / np.linalg.norm(e.paper))
        exact = angles_from_tip(np.asarray(e.exact) / np.linalg.norm(e.exact))
        for i, name in enumerate(("equilibrium_tilt_rad", "equilibrium_azimuth_rad")):
            out[name] = PredictedQuantity(name, paper=float(paper[i]), exact=float(exact[i]),
                                          exact_source=e.exact_source)
    return out


def _difference(name: str, a: float, b: float) -> float:
    """``a - b``, wrapped for an azimuth."""
    return wrap_angle(a - b) if name.endswith("azimuth_rad") else a - b


def _compare(q: Quantity, theory: dict[str, PredictedQuantity], comparable: bool, note: str = "") -> Quantity:
    """``q`` with the theory's values beside it and, where comparable, the differences in standard errors."""
    if q.name not in theory:
        return q
    p = theory[q.name]
    paper, exact = p.paper, p.exact
    upd = dict(paper=paper, corrected=p.corrected, exact=exact, exact_source=p.exact_source,
               note="; ".join(n for n in (q.note, note) if n), theory_note=note,
               paper_standard_error=p.paper_sd, exact_standard_error=p.exact_sd)
    if comparable and q.value is not None and q.standard_error:
        se = q.standard_error
        for kind, value in (("paper", paper), ("exact", exact)):
            if value is None or not np.isfinite(value):
                continue
            diff = _difference(q.name, q.value, value)
            upd[f"diff_{kind}_se"] = diff / se
            psd = p.sd(kind)
            if psd is not None and np.isfinite(psd):
                upd[f"diff_{kind}_combined_se"] = diff / math.hypot(se, psd)
                if kind == "exact":
                    upd["prediction_share"] = psd**2 / (se**2 + psd**2)
    return replace(q, **upd)


def _comparison_note(name: str, spec: ModelSpec, protocol: Protocol, cone_rad: float) -> tuple[bool, str]:
    """Whether the prediction is comparable with the fitted value, and what to say beside it."""
    if name == "nutation_amplitude_rad" and spec.damped:
        return False, ("prediction is for the undamped launch; under damping the fitted amplitude is the one at the "
                       "first frame of the record")
    if name in ("precession_rate_rad_s", "nutation_frequency_rad_s") and spec.damped:
        return False, ("predictions are for the undamped top at the launch tilt; under damping the tilt, and with it "
                       "this quantity, drift: no difference in standard errors is given")
    if name in ("tilt_growth_rate_per_s", "tilt_time_constant_s"):
        launch = protocol.launch.tilt_rad
        if abs(cone_rad - launch) > 1e-3:
            return True, (f"theory is for steady precession at the launch tilt {launch:.4g} rad; the fitted cone is at "
                          f"{cone_rad:.4g} rad at t_ref, and the rate depends on the tilt")
        return True, ""
    if name in ("equilibrium_tilt_rad", "equilibrium_azimuth_rad") and spec.damped:
        return True, ("the effective vertical is the cone axis of the undamped top; damping displaces the axis "
                      "from it, so a difference of many standard errors can be the damping rather than the formula")
    return True, ""


def _time_constant(values: dict, formal: dict) -> Quantity:
    """``tau = 1 / rate``, undetermined while the rate is within 2 standard errors of zero."""
    name = "tilt_time_constant_s"
    lam, se = values["tilt_growth_rate_per_s"]
    if abs(lam) < 2 * se:
        return Quantity(name, QUANTITY_UNITS[name], None, None, QuantityStatus.UNDETERMINED,
                        f"the tilt rate {lam:.3g} +- {se:.2g} 1/s is consistent with zero: |tau| > "
                        f"{1 / (abs(lam) + 2 * se):.3g} s (2 standard errors)",
                        reason_kind=Undetermined.CONSISTENT_WITH_ZERO)
    return Quantity(name, QUANTITY_UNITS[name], 1 / lam, se / lam**2, QuantityStatus.DETERMINED,
                    formal_standard_error=formal["tilt_growth_rate_per_s"] / lam**2,
                    note=("tilt grows: tau is an e-folding time of growth" if lam > 0
                          else "tilt decays: tau is an e-folding time of decay"))


_DIFFERENCES = ("diff_paper_se", "diff_exact_se", "diff_paper_combined_se", "diff_exact_combined_se")


def _time_constant_tested_as_rate(quantities: dict[str, Quantity]) -> dict[str, Quantity]:
    """The time constant's differences from theory in standard errors are its rate's, sign turned (``tau = 1 / rate``
    moves against it): the rate is the fitted parameter, and a reciprocal's linearised error fails where the rate
    is a few of its errors from zero (theory's, for a top that does not drift, is zero: tau infinite)."""
    rate, tau = quantities.get("tilt_growth_rate_per_s"), quantities.get("tilt_time_constant_s")
    if rate is None or tau is None or not (rate.determined and tau.determined):
        return quantities
    flipped = {k: (None if getattr(rate, k) is None else -getattr(rate, k)) for k in _DIFFERENCES}
    return {**quantities, "tilt_time_constant_s": replace(tau, **flipped, prediction_share=rate.prediction_share)}


def build_quantities(spec: ModelSpec, values: dict, formal: dict, camera_se: dict, undetermined: dict[str, Reason],
                     protocol: Protocol, prediction: Prediction | None, truth: dict[str, float], *,
                     after_break: bool = False) -> dict[str, Quantity]:
    """The quantities of the scene, with theory and truth beside them.

    ``values``: quantity -> (value, standard error); ``formal``: quantity -> formal standard error;
    ``camera_se``: the camera model's share; ``undetermined``: quantity -> why not; ``truth``:
    quantity -> true value (synthetic runs); ``after_break``: the frames fitted start after a break in the motion
    (:mod:`gyrorig.fit.breaks`), where the launch's theory is shown beside them but not compared.
    """
    theory = theory_values(prediction)
    out: dict[str, Quantity] = {}
    for name, units in QUANTITY_UNITS.items():
        in_scene = (name in values or name in undetermined
                    or (name == "tilt_time_constant_s" and "tilt_growth_rate_per_s" in values))
        if not in_scene:
            continue
        if name in undetermined:
            why = undetermined[name]
            q = Quantity(name, units, None, None, QuantityStatus.UNDETERMINED, why.text, reason_kind=why.kind)
        elif name == "tilt_time_constant_s":
            q = _time_constant(values, formal)
        else:
            v, se = values[name]
            q = Quantity(name, units, v, se, QuantityStatus.DETERMINED, formal_standard_error=formal[name],
                         camera_standard_error=camera_se.get(name))
        comparable, cnote = _comparison_note(name, spec, protocol, values["cone_angle_rad"][0])
        if name == "tilt_time_constant_s":
            comparable = q.value is not None
        if after_break:
            comparable, cnote = False, ("the frames fitted start after a break in the motion: the prediction is for "
                                        "the protocol's launch, which they do not start from; no difference in "
                                        "standard errors is given")
        q = _compare(q, theory, comparable and q.determined, cnote)
        if name in truth and q.determined:
            tv = truth[name]
            pull = _difference(name, q.value, tv) / q.standard_error if q.standard_error else None
            q = replace(q, truth=tv, pull=pull)
        out[name] = q
    return _time_constant_tested_as_rate(out)


#: a truth whose fitted axis is within this of the vertical is level: its axis has no azimuth [rad]
LEVEL_TRUTH_RAD = 1e-6


def truth_values(truth: pd.DataFrame, data: FitData, spec: ModelSpec, x: np.ndarray) -> dict[str, float]:
    """The quantities of the same model fitted to noiseless truth (``t_s, theta_rad, phi_rad``) at the
    measured frame times, with the data's weights: the truth is what this estimator converges to
    without noise."""
    from .solver import solve

    t = truth["t_s"].to_numpy(float)
    order = np.argsort(t)
    t = t[order]
    th = truth["theta_rad"].to_numpy(float)[order]
    ph = np.unwrap(truth["phi_rad"].to_numpy(float)[order])
    lo, hi = data.t_s[0], data.t_s[-1]
    # container timestamps are rounded (to 1 ms, say): allow half a frame at either end; a whole one when the frames'
    # times lack their rows' delay under a rolling shutter (the truth's are the tip's own, up to a readout later)
    slack = (1.0 if data.rolling_shutter else 0.5) * float(np.median(np.diff(data.t_s))) if data.n > 1 else 0.0
    if t[0] > lo + slack or t[-1] < hi - slack:
        raise FitError(f"the truth table ({t[0]:.6g}..{t[-1]:.6g} s) does not cover the measured times "
                       f"({lo:.6g}..{hi:.6g} s)")
    keep = np.concatenate([[True], np.diff(t) > 0])
    t_eval = data.t_s
    names = list(spec.names())
    if data.row_fraction is not None and RollingShutter.NAME in names:
        # frame times without their rows' delay: the truth at the tip's own times, as the fitted readout puts them
        # (between a slow record's frames its spline through the truth's samples is not the motion)
        t_eval = data.t_s + data.row_fraction * float(x[names.index(RollingShutter.NAME)])
    th_i = CubicSpline(t[keep], th[keep])(t_eval)
    ph_i = wrap_angle(CubicSpline(t[keep], ph[keep])(t_eval))
    # instantaneous, and free of the user's constraints: the truth is the unconstrained estimator's limit
    d = replace(data, t_s=t_eval, theta_rad=th_i, phi_rad=ph_i, camera_shift=None, exposure_s=None,
                constraints=Constraints(), b_frame=None, row_fraction=None)
    spec0 = replace(spec, camera_modes=0, b_frames=False, rolling_shutter=False)
    sol = solve(spec0, d, dict(zip(spec0.names(), x)))
    out = {k: float(f(sol.x)) for k, f in quantity_functions(spec).items()}
    if spec.lean and abs(out["equilibrium_tilt_rad"]) < LEVEL_TRUTH_RAD:  # a vertical axis has no azimuth
        del out["equilibrium_azimuth_rad"]
    return out


def at_record_state(fit: FitResult, state_values: dict[str, tuple[float, float]], source: str) -> FitResult:
    """``fit`` compared with theory at the record's own state: ``state_values`` (quantity -> (value, standard
    deviation)) are the same model's quantities on the motion theory gives from the record's fitted state
    (:mod:`gyrorig.pipeline`); each becomes ``exact`` (``exact_source`` = ``source``), the launch's prediction moves
    to ``exact_nominal``, and the difference is given in combined standard errors (the two errors added in
    quadrature: they come from the same record and are positively correlated, so this errs on the wide side).  Under
    damping the launch's prediction is not comparable (the top has drifted).  The paper's values stay."""
    values = dict(state_values)
    if "tilt_growth_rate_per_s" in values and values["tilt_growth_rate_per_s"][0]:
        rate, sd = values["tilt_growth_rate_per_s"]
        values["tilt_time_constant_s"] = (1.0 / rate, sd / rate**2)
    quantities = dict(fit.quantities)
    for name, (exact, sd) in values.items():
        q = quantities.get(name)
        if q is None or not q.determined or not math.isfinite(exact):
            continue
        own = q.note[:len(q.note) - len(q.theory_note)].rstrip("; ") if q.theory_note else q.note
        at_launch = f"theory at the protocol's launch: {q.exact:.6g}" if q.exact is not None else ""
        kept = [n for n in (own, at_launch) if n]
        diff = _difference(name, q.value, exact)
        se = q.standard_error or 0.0
        quantities[name] = replace(
            q, exact=exact, exact_source=source, exact_standard_error=sd,
            diff_exact_se=diff / se if se else None,
            diff_exact_combined_se=diff / math.hypot(se, sd) if math.hypot(se, sd) > 0 else None,
            prediction_share=sd**2 / (se**2 + sd**2) if se or sd else None,
            note="; ".join(kept), theory_note=at_launch, prediction_at="record", exact_nominal=q.exact)
    return replace(fit, quantities=_time_constant_tested_as_rate(quantities))
