"""Experiment planning: what a rig and camera will measure, before anyone builds them.

:func:`plan_experiment` takes a protocol and answers, for the scene's quantities:

- the predicted values (:func:`gyrorig.theory.predict`) and the validity flags;
- whether the camera resolves each: the per-frame localisation bound of the tip marker, the
  nutation amplitude at the marker in pixels against it, frame rate against the nutation
  frequency, motion blur during the exposure, rolling-shutter skew, saturation
  (:mod:`gyrorig.expectation`);
- the expected standard error of every fitted quantity: the Cramér-Rao bound of the fit
  model (:mod:`gyrorig.fit`) for the simulated motion sampled at the camera's frame times,
  with the per-frame angle covariance the tracker will reach;
- the recording length needed for a target relative precision (rates and frequencies
  scale as T^-3/2, amplitudes as T^-1/2, at a fixed frame rate);
- whether the fit model describes a record of that length at all (its chi-square on the
  noiseless record), and whether the errors can be trusted: the model must be linear over
  one standard error (the phase each rate leaves uncertain, and a few noisy draws of the
  record fitted in full, each of which must converge and land where the linearised fit puts
  it); otherwise the plan names a length that is;
- recommendations: minimum frame rate, maximum exposure, recording length, marker size and
  placement, and which damping realisation tests which prediction.

The synthetic motion comes from the simulator, never from the formulas being tested.
:func:`gyrorig.montecarlo.monte_carlo_check` confirms the bounds with the full render -> track
-> smooth -> fit chain.
"""

from __future__ import annotations

import copy
import logging
import math
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from . import _io, protocols
from .expectation import ExpectedRecord, expected_record, plan_fit_terms, project, tip_setup
from .tracking.rays import LIMB_MARGIN_RAD, near_limb
from .fit import FitConvergenceError, FitError, FitResult, fit_angles, linear_response
from .fit.lean import LEAN_MIN_TURN_DAMPED_RAD, LEAN_MIN_TURN_RAD
from .geometry import wrap_angle
from .plan_record import Advice, AdviceKind, DampingAssessment, ExpectedQuantity, Plan
from .prediction import Prediction
from .protocols import Protocol, parse_protocol
from .propagate import predict_with_uncertainty

logger = logging.getLogger(__name__)

__all__ = ["plan_experiment", "plan_fit_terms", "sweep", "parse_sweep", "TARGET_RELATIVE_SE", "DEFAULT_PLAN_DRAWS",
           "MISFIT_NOTE", "MISFIT_LIMIT", "LINEAR_DEPARTURE_SE", "noisy_draws"]

#: record length assessed by default (longer scenes: the advice extrapolates; --duration overrides)
DEFAULT_PLAN_LENGTH_S = 20.0
#: relative standard error a recording should reach, per quantity (recording-length advice)
TARGET_RELATIVE_SE = {"precession_rate_rad_s": 1e-3, "nutation_frequency_rad_s": 1e-3, "nutation_amplitude_rad": 1e-2,
                      "tilt_growth_rate_per_s": 0.1, "equilibrium_tilt_rad": 1e-2}
#: noisy records drawn and fitted in full by the plan (Gaussian noise with the per-frame covariance)
DEFAULT_PLAN_DRAWS = 8
#: the root-mean-square distance [standard errors] between the full fit of a drawn record and the
#: linearised fit, above which the model is not linear over the noise: the spread of the estimates
#: then exceeds the Cramér-Rao bound by more than ~5 % (sqrt(1 + 0.3^2)), and a record's own error
#: bar is no longer what the plan says
LINEAR_DEPARTURE_SE = 0.3
#: the fit model "misses part of the motion" when its fit to the simulated (noiseless) record
#: leaves a chi-square above this fraction of the degrees of freedom: real records then show a
#: reduced chi-square of about 1 + this, residuals that are not white, and quantities that can be
#: off by up to sqrt(chi-square) standard errors
MISFIT_NOTE = 0.1
#: above this the model does not describe the record at all: every expected error is marked not
#: reliable and a shorter record named
MISFIT_LIMIT = 1.0
#: how the standard error of a quantity falls with the record length T (T^-exponent; default 1.5)
_T_EXPONENT = {"nutation_amplitude_rad": 0.5, "cone_angle_rad": 0.5, "equilibrium_tilt_rad": 0.5,
               "equilibrium_azimuth_rad": 0.5}


def _draw_rng(seed: int, duration_s: float) -> np.random.Generator:
    """The draws' generator for one record length: a plan of that length gives the same verdict
    whether it is asked for directly or reached while searching for a long-enough record."""
    return np.random.default_rng([seed, int(round(duration_s * 1e6))])


def noisy_draws(protocol: Protocol, ex: ExpectedRecord, fit: FitResult, pred: Prediction, draws: int,
                rng: np.random.Generator, progress=None) -> dict:
    """Fit ``draws`` noisy versions of the expected record with the planned model.

    Each draw adds Gaussian noise with the per-frame covariance to the simulated angles and is
    fitted in full, with the terms the noiseless fit chose (as ``gyrorig fit --terms plan.json``
    would).  The noiseless check (:func:`gyrorig.fit.phase_uncertainty`) does not see a fit
    that fails to converge on real noise, or a chi-square surface with another minimum: these
    draws do.  For each quantity the departure is the distance between the full fit and the
    linearised one (:func:`gyrorig.fit.linear_response`), in standard errors; a quantity is
    linear over the noise when the root mean square of its departures is at most
    :data:`LINEAR_DEPARTURE_SE`, and the model when every draw converges and every quantity is.
    With a few draws this catches what happens in a sizeable fraction of records (a failure in
    one record in four, a second minimum), not what is rare.

    Returns ``draws, failed, failures, model_changed, rms_departure_se`` (per quantity),
    ``max_departure_se, worst_quantity, nonlinear`` (the quantities above the limit), ``ok``.
    """
    out = {"draws": draws, "failed": 0, "failures": [], "model_changed": 0, "rms_departure_se": {},
           "max_departure_se": 0.0, "worst_quantity": None, "nonlinear": [], "ok": True}
    if draws <= 0:
        return out
    respond = linear_response(ex.angles, fit, protocol, prediction=pred)
    chol = np.linalg.cholesky(ex.cov)
    departures: dict[str, list[float]] = {}
    for i in range(draws):
        e = np.einsum("nij,nj->ni", chol, rng.standard_normal((len(ex.theta), 2)))
        # frames without the tip in view stay gaps (NaN in ex.angles), as in the noiseless record
        noisy = ex.angles.assign(theta_rad=ex.angles.theta_rad + e[:, 0], phi_rad=ex.angles.phi_rad + e[:, 1])
        try:
            f = fit_angles(noisy, protocol, prediction=pred, terms=fit.terms, check_residuals=False)
        except FitError as exc:
            out["failed"] += 1
            out["failures"].append(f"draw {i + 1}: {exc}")
            if progress:
                progress(i + 1, draws)
            continue
        if f.spec != fit.spec:
            out["model_changed"] += 1
        for k, v in respond(noisy).items():
            q, q0 = f.quantities.get(k), fit.quantities[k]
            if q is None or not q.determined or not q0.standard_error:
                continue
            diff = q.value - v
            if k == "equilibrium_azimuth_rad":
                diff = wrap_angle(diff)
            d = abs(diff) / q0.standard_error
            departures.setdefault(k, []).append(d)
            if d > out["max_departure_se"]:
                out["max_departure_se"], out["worst_quantity"] = float(d), k
        if progress:
            progress(i + 1, draws)
    out["rms_departure_se"] = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in departures.items()}
    out["nonlinear"] = [k for k, v in out["rms_departure_se"].items() if v > LINEAR_DEPARTURE_SE]
    out["ok"] = out["failed"] == 0 and not out["nonlinear"]
    return out


def _camera_checks(protocol: Protocol, ex: ExpectedRecord, inside: np.ndarray, pred: Prediction,
                   rec: list[Advice]) -> dict:
    """The camera against the motion: spot, per-frame errors, nutation, blur, skew, field of view (``inside``:
    :func:`_spot_in_view`); advice to ``rec``."""
    setup, marker = tip_setup(protocol)
    cam = setup.camera
    lever = float(np.linalg.norm(marker.position_m))
    if marker.body == "frame" and np.hypot(*marker.position_m[:2]) > 1e-9:
        rec.append(Advice(AdviceKind.MARKER_OFF_AXIS, f"marker {marker.name} is off the symmetry axis: its spin "
                          "smears it during the exposure; put the tip marker on the axis", problem=True))
    spot, cov = ex.spot, ex.cov
    px = project(setup, ex.pos)
    speed_px_s = np.linalg.norm(np.gradient(px, 1 / cam.fps, axis=0), axis=1)
    blur_px = float(np.max(speed_px_s) * cam.exposure_s)
    skew_px = float(np.max(speed_px_s) * cam.readout_time_s) if cam.shutter == "rolling" else 0.0
    camera = {"fps": cam.fps, "exposure_s": cam.exposure_s, "lever_arm_m": lever, "marker_depth_m": ex.depth, **spot,
              "theta_sigma_rad_median": _median_or_nan(np.sqrt(cov[:, 0, 0])),
              "phi_sigma_rad_median": _median_or_nan(np.sqrt(cov[:, 1, 1])),
              "max_marker_speed_px_s": float(np.max(speed_px_s)), "motion_blur_px": blur_px,
              "rolling_shutter_skew_px": skew_px, "marker_in_view_fraction": float(inside.mean())}
    nut = pred.exact("nutation_frequency_rad_s")
    amp = pred.exact("nutation_amplitude_rad")
    if nut is not None and nut > 0:  # 0: a steady launch (or a sleeping top) does not nutate
        nyq = math.pi * cam.fps
        camera["nutation_hz"] = nut / (2 * math.pi)
        camera["frames_per_nutation_period"] = 2 * math.pi * cam.fps / nut
        camera["minimum_fps"] = 4 * nut / (2 * math.pi)  # 4 frames per nutation period
        camera["resolves_nutation"] = bool(nut <= 0.9 * nyq)
        if amp is not None:
            camera["nutation_amplitude_px"] = amp * lever * spot["px_per_m"]
            camera["nutation_amplitude_over_sigma_px"] = camera["nutation_amplitude_px"] / spot["sigma_px"]
        fps = {"minimum_fps": camera["minimum_fps"], "fps": cam.fps}
        if not camera["resolves_nutation"]:
            rec.append(Advice(AdviceKind.FRAME_RATE, f"frame rate {cam.fps:g} fps cannot resolve the nutation at "
                              f"{nut / (2 * math.pi):.3g} Hz: use at least {4 * nut / (2 * math.pi):.0f} fps (4 frames "
                              "per period)", problem=True, values=fps))
        else:
            rec.append(Advice(AdviceKind.FRAME_RATE, f"minimum frame rate: {4 * nut / (2 * math.pi):.0f} fps (4 frames "
                              f"per nutation period; this camera has {camera['frames_per_nutation_period']:.1f})",
                              values=fps))
    if not inside.all():
        rec.append(Advice(AdviceKind.FIELD_OF_VIEW, f"the tip marker's spot is not wholly in the image in "
                          f"{1 - inside.mean():.0%} of the frames (gaps in the expected record): widen the view (a "
                          "shorter camera.focal_length_mm, or the camera further away)", problem=True,
                          values={"marker_in_view_fraction": float(inside.mean())}))
    near = near_limb(ex.pos / lever, cam, lever) & inside
    camera["near_limb_fraction"] = float(near.mean())
    if near.any():
        limb_deg = math.degrees(math.acos(min(1.0, lever / float(np.linalg.norm(cam.centre_m)))))
        rec.append(Advice(AdviceKind.LIMB, f"the tip comes within {math.degrees(LIMB_MARGIN_RAD):.2g} deg of the limb "
                          f"of its sphere as the camera sees it, or passes beyond it, in {near.mean():.0%} of the "
                          f"frames: beyond {limb_deg:.3g} deg from the camera's direction (seen from the pivot) the ray "
                          "through the tip meets the sphere first nearer the camera, and the tracker cannot tell where "
                          f"the tip is (it flags the record near-limb); film from above: the camera's direction within "
                          f"{limb_deg:.3g} deg less the top's largest tilt of the vertical (camera.position_m)",
                          problem=True, values={"near_limb_fraction": float(near.mean()), "limb_deg": limb_deg}))
    if spot["saturates"]:
        rec.append(Advice(AdviceKind.SATURATION, "the marker saturates the sensor: shorten the exposure or dim the "
                          "marker (saturated pixels carry no position information)", problem=True))
    max_exposure = 0.5 / max(float(np.max(speed_px_s)), 1e-9)
    rec.append(Advice(AdviceKind.EXPOSURE, f"maximum exposure for under 0.5 px of motion blur: "
                      f"{max_exposure * 1e6:.0f} us (now {cam.exposure_s * 1e6:.0f} us, {blur_px:.2f} px)",
                      values={"maximum_exposure_s": max_exposure, "exposure_s": cam.exposure_s,
                              "motion_blur_px": blur_px}))
    if skew_px > 0.5:
        rec.append(Advice(AdviceKind.ROLLING_SHUTTER, f"rolling shutter moves the marker {skew_px:.2f} px during "
                          "readout: per-row timing is applied by the tracker, but a global shutter is simpler",
                          values={"rolling_shutter_skew_px": skew_px}))
    if spot["radius_px"] < 2:
        rec.append(Advice(AdviceKind.MARKER_SIZE, f"the marker is only {spot['radius_px']:.1f} px in radius: make it "
                          f"larger (>= {2 / spot['px_per_m'] * 1e3:.1f} mm radius) for a robust centroid", problem=True,
                          values={"radius_px": spot["radius_px"], "minimum_radius_m": 2 / spot["px_per_m"]}))
    rec.append(Advice(AdviceKind.MARKER_PLACEMENT, f"marker placement: on the symmetry axis, as far from the pivot as "
                      f"the rig allows (the angle error scales as 1/lever arm, now {lever * 1e3:.0f} mm); lab "
                      "fiducials around the pivot fix the camera pose", values={"lever_arm_m": lever}))
    return camera


def _expected_errors(fit: FitResult, T: float, nut: float | None) -> tuple[dict, dict]:
    """Each quantity's expected error, and the recording length each needs for its target precision."""
    quantities, recording = {}, {}
    for name, q in fit.quantities.items():
        entry = {"units": q.units, "resolvable": q.determined, "reason": q.reason,
                 "reason_kind": None if q.reason_kind is None else str(q.reason_kind), "reliable": True,
                 "predicted_paper": q.paper, "predicted_exact": q.exact, "simulated": q.value,
                 "expected_standard_error": q.standard_error,
                 "prediction_standard_error": q.exact_standard_error}
        if q.determined and q.value:
            rel = q.standard_error / abs(q.value)
            entry["expected_relative_error"] = rel
            if q.paper is not None and q.exact is not None and q.standard_error:
                entry["paper_vs_exact_in_se"] = (q.paper - q.exact) / q.standard_error
            target = TARGET_RELATIVE_SE.get(name)
            if target is not None:
                need = T * (rel / target) ** (1 / _T_EXPONENT.get(name, 1.5))
                # the scaling holds only over whole cycles: at least one precession period,
                # and two nutation periods for the nutation
                prec_rate = abs(fit.quantities["precession_rate_rad_s"].value or 0.0)
                floor = 2 * math.pi / prec_rate if prec_rate > 0 else 0.0
                if name.startswith("nutation") and nut:
                    floor = max(floor, 4 * math.pi / nut)
                recording[name] = {"target_relative_error": target, "length_needed_s": max(need, floor),
                                   "length_for_target_by_scaling_s": need}
        quantities[name] = entry
    lam = quantities.get("tilt_growth_rate_per_s", {}).get("simulated")
    if lam:
        recording["tilt_time_constants_in_record"] = T * abs(lam)
    prec = quantities.get("precession_rate_rad_s", {}).get("simulated")
    if prec:
        recording["precession_periods_in_record"] = T * abs(prec) / (2 * math.pi)
    return quantities, recording


def _level_advice(fit: FitResult, T: float, turns: float) -> Advice | None:
    """Where the record's ``turns`` of precession are too few for the fit to look for a table not level
    (:data:`gyrorig.fit.lean.LEAN_MIN_TURN_RAD`, ``LEAN_MIN_TURN_DAMPED_RAD``)."""
    need = (LEAN_MIN_TURN_DAMPED_RAD if fit.spec.damped else LEAN_MIN_TURN_RAD) / (2 * math.pi)
    if turns >= need or fit.spec.fit_axis:
        return None
    return Advice(AdviceKind.LEVEL, f"{turns:.2g} precession turns in {T:g} s: under {need:g} the fit cannot tell a table "
                  f"not level (or a pose's vertical off) from the cone and does not fit it; level the table or record "
                  f"{need * T / turns:.3g} s", values={"length_s": need * T / turns, "turns": turns})


def _misfit_advice(protocol: Protocol, fit: FitResult, T: float, pred: Prediction, misfit: dict) -> Advice | None:
    """Advice when the fit model misses part of the simulated motion (None when it describes it)."""
    if misfit["chi2_per_dof"] <= MISFIT_NOTE:
        return None
    shorter = _adequate_length(protocol, T, pred) if misfit["chi2_per_dof"] > MISFIT_LIMIT else None
    misfit["adequate_length_s"] = shorter
    return Advice(AdviceKind.MODEL_MISFIT, problem=True, values={"chi2_per_dof": misfit["chi2_per_dof"],
                                                                  "adequate_length_s": shorter}, text=(
            f"over {T:g} s the fit model misses part of the simulated motion: noiseless chi-square "
            f"{fit.chi2:.3g} for {fit.dof} degrees of freedom, so real records show a reduced chi-square of "
            f"about {1 + misfit['chi2_per_dof']:.3g}, residuals that are not white (errors from the bootstrap) "
            f"and quantities off by up to {math.sqrt(fit.chi2):.3g} standard errors"
            + ("" if misfit["chi2_per_dof"] <= MISFIT_LIMIT else
               "; the expected errors above are not reliable; "
               + (f"a {shorter:.3g} s record is described by the model" if shorter else
                  "no shorter record tried is described by it"))))


def _reliability(protocol: Protocol, ex: ExpectedRecord, fit: FitResult, T: float, pred: Prediction, draws: int,
                 draw_seed: int, out: dict, rec: list[Advice], progress) -> None:
    """Whether the expected errors hold for a record of ``T``: the phase check and the noisy draws; marks
    unreliable quantities in ``out`` and names a long-enough record."""
    quantities = out["quantities"]
    checks = (noisy_draws(protocol, ex, fit, pred, draws, _draw_rng(draw_seed, T), progress)
              if fit.linear_regime else None)
    if checks is not None:
        out["recording"]["noisy_draws"] = checks
        if checks["model_changed"]:
            rec.append(Advice(AdviceKind.MODEL_CHANGED, f"{checks['model_changed']} of {draws} noisy records of "
                              f"{T:g} s needed a term the plan left out (the fit adds it and says so; those records' "
                              "error bars are wider than planned)", values={"records": checks["model_changed"]}))
    if fit.linear_regime and checks["ok"]:
        out["recording"]["linear_regime"] = True
        return
    unreliable = list(quantities)
    if not fit.linear_regime:
        worst = max(fit.phase_uncertainty_rad.items(), key=lambda kv: kv[1])
        why = (f"{worst[0]} leaves {worst[1]:.2g} rad of phase uncertain over the record, so the model is not "
               "linear over one standard error")
    elif checks["failed"]:
        why = f"{checks['failed']} of {draws} noisy records of this length did not converge ({checks['failures'][0]})"
    else:
        unreliable = checks["nonlinear"] + (["tilt_time_constant_s"] if "tilt_growth_rate_per_s" in
                                            checks["nonlinear"] else [])
        why = (f"in {draws} noisy records the full fit of " + ", ".join(
            f"{k} landed {checks['rms_departure_se'][k]:.2g}" for k in checks["nonlinear"])
            + f" standard errors (root mean square) from where the linearised fit puts it (limit "
            f"{LINEAR_DEPARTURE_SE:g}): the model is not linear over the noise there")
    longer = _linear_length(protocol, T, pred, draws, draw_seed)
    out["recording"]["linear_regime"] = False
    out["recording"]["length_for_linear_regime_s"] = longer
    for name in unreliable:
        if name in quantities:
            quantities[name]["reliable"] = False
    rec.append(Advice(AdviceKind.RECORD_TOO_SHORT, problem=True, values={"length_s": longer,
                                                                           "unreliable": tuple(unreliable)}, text=(
        f"a {T:g} s record is too short for the scene's fit model: {why}; the expected errors of "
        + ("every quantity" if len(unreliable) == len(quantities) else ", ".join(unreliable))
        + " above are not reliable (runs will scatter beyond them); "
        + (f"a {longer:.3g} s record is long enough" if longer else
           f"no record up to the scene's {protocol.scene.duration_s:g} s is long enough"))))


def plan_experiment(protocol: Protocol, *, duration_s: float | None = None, prediction: Prediction | None = None,
                    simulate_damping: bool = True, draws: int = DEFAULT_PLAN_DRAWS,
                    rng: np.random.Generator | None = None, progress=None) -> Plan:
    """What the rig and camera of ``protocol`` will measure (see the module docstring).

    Parameters
    ----------
    draws : int
        Noisy records (simulated motion + Gaussian noise with the camera's per-frame
        covariance) fitted in full to check that the fit converges and is linear over the
        noise at this length (:func:`noisy_draws`); 0 skips the check.
    rng : numpy Generator, optional
        Seeds those draws (default: a fixed seed, so a plan is reproducible).
    progress : callable, optional
        ``progress(done, total)`` after each draw.

    Returns a :class:`~gyrorig.plan_record.Plan`: ``prediction``, ``camera`` (resolution checks),
    ``quantities`` (:class:`~gyrorig.plan_record.ExpectedQuantity`: predicted value, expected standard error,
    resolvable, reliable, reason), ``recording`` (length needed per quantity; ``model_misfit``,
    ``linear_regime``, ``noisy_draws``), ``fit_model``, ``fit_terms``, ``damping`` and ``advice``
    (:class:`~gyrorig.plan_record.Advice`, each with its kind).
    """
    if draws < 0:
        raise ValueError(f"--draws {draws}: the number of noisy records must be >= 0")
    draw_seed = int((rng if rng is not None else np.random.default_rng(0)).integers(2**62))
    start = time.perf_counter()
    pred = prediction if prediction is not None else predict_with_uncertainty(protocol,
                                                                              simulate_damping=simulate_damping)
    out: dict = {}
    rec: list[Advice] = []
    if "camera" not in protocol.extra:
        rec.append(Advice(AdviceKind.NO_CAMERA, "no [camera] in the protocol: resolution and precision not assessed; "
                          "add a camera section"))
        return Plan(protocol.name, pred, rec, wall_time_s=time.perf_counter() - start)
    T = float(duration_s if duration_s is not None else min(protocol.scene.duration_s, DEFAULT_PLAN_LENGTH_S))
    ex = expected_record(protocol, T)
    # frames where the tip's spot is not wholly in the image are gaps of the record, as the tracker will have them
    inside = _spot_in_view(protocol, ex)
    out["camera"] = _camera_checks(protocol, ex, inside, pred, rec)
    if not inside.all():
        angles = ex.angles.copy()
        angles.loc[~inside, ["theta_rad", "phi_rad"]] = np.nan
        ex = replace(ex, angles=angles)
    on_axis = np.isnan(ex.cov[:, 1, 1])
    if (inside & ~on_axis).sum() < MIN_FRAMES_IN_VIEW <= inside.sum():
        rec.append(Advice(AdviceKind.AZIMUTH_UNDEFINED, f"the tip stays on the vertical (a sleeping top) in "
                          f"{int((inside & on_axis).sum())} of {len(inside)} frames, within its pixel error: its "
                          "azimuth is not defined there, so there is no precession or nutation to measure; launch "
                          "the top tilted (launch.tilt_deg) or moving (launch.tilt_rate_rad_s)", problem=True,
                          values={"frames_on_vertical": int((inside & on_axis).sum())}))
        return Plan(protocol.name, pred, rec, camera=out["camera"], wall_time_s=time.perf_counter() - start)
    if inside.sum() < MIN_FRAMES_IN_VIEW:
        rec.append(Advice(AdviceKind.FIELD_OF_VIEW, f"the tip marker's spot is wholly in the image in "
                          f"{int(inside.sum())} of {len(inside)} frames: nothing can be measured; widen the view (a "
                          "shorter camera.focal_length_mm, the camera further away, or camera.look_at_m on the pivot)",
                          problem=True, values={"marker_in_view_fraction": float(inside.mean())}))
        return Plan(protocol.name, pred, rec, camera=out["camera"], wall_time_s=time.perf_counter() - start)
    # the expected errors: Cramér-Rao bound of the fit model for this motion and camera
    try:
        fit = fit_angles(ex.angles, protocol, prediction=pred, check_residuals=False, terms="noiseless")
    except FitConvergenceError as exc:
        rec.append(Advice(AdviceKind.FIT_FAILED, f"the scene's fit model finds no minimum on the simulated {T:g} s "
                          f"record itself ({exc}): no expected errors; a record of another length, or a camera that "
                          "resolves the motion, may be described", problem=True, values={"length_s": T}))
        return Plan(protocol.name, pred, rec, camera=out["camera"], wall_time_s=time.perf_counter() - start)
    misfit = {"noiseless_chi2": float(fit.chi2), "dof": int(fit.dof), "chi2_per_dof": float(fit.chi2 / max(fit.dof, 1))}
    nut = pred.exact("nutation_frequency_rad_s")
    quantities, recording = _expected_errors(fit, T, nut)
    out["quantities"] = quantities
    out["note"] = ("expected errors are statistical (Cramér-Rao) bounds for the camera's per-frame localisation "
                   "limit; camera-model systematics (calibration, pose: ~3e-4 rad with a 12-view calibration, see "
                   "'gyrorig bench track') and marker blends add to them")
    out["recording"] = {"length_s": T, **recording, "model_misfit": misfit}
    out["fit_model"] = fit.summary()["model"]
    # the model every record of this length should be fitted with: gyrorig fit --terms plan.json
    out["fit_terms"] = {**fit.terms.as_dict(), "source": f"gyrorig plan of {protocol.name} for {T:g} s records"}
    if recording:
        longest = max((v["length_needed_s"], k) for k, v in recording.items() if isinstance(v, dict))
        rec.append(Advice(AdviceKind.RECORDING_LENGTH, f"recording length: {longest[0]:.3g} s for every quantity to "
                          f"reach its target precision (set by {longest[1]}); precession periods in {T:g} s: "
                          f"{recording.get('precession_periods_in_record', float('nan')):.2g}",
                          values={"length_s": longest[0], "quantity": longest[1]}))
    rec += [a for a in (_level_advice(fit, T, recording.get("precession_periods_in_record", math.inf)),
                        _misfit_advice(protocol, fit, T, pred, misfit)) if a]
    if misfit["chi2_per_dof"] > MISFIT_LIMIT:
        for entry in quantities.values():
            entry["reliable"] = False
        out["recording"]["linear_regime"] = None  # not assessed: the model does not describe the record
    else:
        _reliability(protocol, ex, fit, T, pred, draws, draw_seed, out, rec, progress)
    if out["camera"]["near_limb_fraction"] > 0:  # the tracker flags such a record: it may be read on the wrong side
        for entry in quantities.values():
            entry["reliable"] = False
    rec.extend(_parameter_advice(quantities, pred))
    rec.extend(_damping_advice(protocol, pred))
    return Plan(protocol.name, pred, rec, camera=out["camera"],
                quantities={k: ExpectedQuantity(name=k, **v) for k, v in quantities.items()},
                recording=out["recording"], fit_model=out["fit_model"], fit_terms=out["fit_terms"],
                damping=_damping_assessment(protocol, pred), note=out["note"], wall_time_s=time.perf_counter() - start)


#: the measurement that pins each rig parameter down best (for the advice)
PARAMETER_MEASUREMENTS = {
    "rig.inertia_axial_kg_m2": "precession periods with added masses on the axis (their slope fixes Io)",
    "rig.inertia_transverse_kg_m2": "nutation frequencies at several spins (Io Omega / I, with Io known)",
    "rig.com_distance_m": "precession periods without added mass (Mgh / Io)",
    "rig.mass_kg": "a balance",
    "launch.spin_rate_rad_s": "the spin at release (stroboscope or tachometer), or spin-down tables",
    "launch.tilt_rad": "the launch tilt (the video's first frames)",
}


def _parameter_advice(quantities: dict, pred: Prediction) -> list[Advice]:
    """Where a prediction's own error exceeds the expected measurement error: which parameter limits it,
    and the measurement that would shrink it most (the largest share of its variance)."""
    out = []
    for name, q in quantities.items():
        psd, se = q.get("prediction_standard_error"), q.get("expected_standard_error")
        key = "mean_precession_rate_rad_s" if name == "precession_rate_rad_s" else name
        entry = pred.get(key)
        unc = entry.uncertainty if entry is not None else None
        if not psd or not se or unc is None or unc.largest_share is None or psd <= se:
            continue
        param, share = unc.largest_share
        how = PARAMETER_MEASUREMENTS.get(param, "a direct measurement of it")
        out.append(Advice(AdviceKind.PREDICTION_LIMIT, values={
            "quantity": name, "prediction_standard_error": psd, "expected_standard_error": se, "parameter": param,
            "share": share, "measurement": how}, text=(
            f"{name}: theory's prediction is uncertain by {psd:.2g} ({psd / se:.3g} x the expected measurement "
            f"error), {share:.0%} of it from {param}: the comparison with theory is limited by the rig, not the "
            f"camera; measure {param} better: {how} (gyrorig identify)")))
    return out


#: fewer frames with the tip in view than this and a plan measures nothing
MIN_FRAMES_IN_VIEW = 10


def _median_or_nan(values: np.ndarray) -> float:
    """The median of the finite values (the frames with an azimuth); NaN when there are none."""
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if len(finite) else math.nan


def _spot_in_view(protocol: Protocol, ex: ExpectedRecord) -> np.ndarray:
    """Per frame: whether the tip marker's spot (its radius and 2 px) lies wholly inside the image."""
    setup, _ = tip_setup(protocol)
    cam = setup.camera
    px = project(setup, ex.pos)
    margin = float(ex.spot.get("radius_px", 0.0)) + 2.0
    return ((px[:, 0] >= margin) & (px[:, 0] <= cam.width_px - 1 - margin)
            & (px[:, 1] >= margin) & (px[:, 1] <= cam.height_px - 1 - margin))


def _damping_assessment(protocol: Protocol, pred: Prediction) -> DampingAssessment:
    """The damping models, and whether the scene shows the tilt drift eqs. 25a/26 are about (a simulated
    drift of at least a tenth of the paper's)."""
    growth = pred.get("tilt_growth_rate_per_s")
    exact, paper = (growth.exact, growth.paper) if growth is not None else (None, None)
    shows = bool(exact is not None and math.isfinite(exact) and abs(exact) >= 0.1 * abs(paper or 1.0))
    return DampingAssessment(tuple(d.model for d in protocol.pivot.damping), shows)


def _linear_length(protocol: Protocol, duration_s: float, pred: Prediction, draws: int, draw_seed: int) -> float | None:
    """The shortest of a few longer records (x1.5 .. x4, up to the scene's length) over which the
    fit model is in its linear regime (and its noisy draws converge where the linearised fit puts
    them); None if none is."""
    tried = set()
    for factor in (1.5, 2.0, 3.0, 4.0):
        T = min(duration_s * factor, protocol.scene.duration_s)
        if T <= duration_s or T in tried:
            continue
        tried.add(T)
        ex = expected_record(protocol, T)
        try:
            fit = fit_angles(ex.angles, protocol, prediction=pred, check_residuals=False, terms="noiseless")
        except FitError:
            continue
        if fit.chi2 > MISFIT_LIMIT * max(fit.dof, 1):
            return None  # longer records are described no better
        if fit.linear_regime and noisy_draws(protocol, ex, fit, pred, draws, _draw_rng(draw_seed, T))["ok"]:
            return T
    return None


def _adequate_length(protocol: Protocol, duration_s: float, pred: Prediction) -> float | None:
    """The longest of ``duration_s`` / 2, / 4, / 8 whose simulated record the fit model describes
    (noiseless chi-square per degree of freedom at most :data:`MISFIT_LIMIT`), or None."""
    for k in (2, 4, 8):
        T = duration_s / k
        try:
            fit = fit_angles(expected_record(protocol, T).angles, protocol, prediction=pred, check_residuals=False,
                             terms="noiseless")
        except FitError:
            continue
        if fit.chi2 <= MISFIT_LIMIT * max(fit.dof, 1):
            return T
    return None


def _damping_advice(protocol: Protocol, pred: Prediction) -> list[Advice]:
    assessment = _damping_assessment(protocol, pred)
    models, growth = assessment.models, pred.get("tilt_growth_rate_per_s")
    values = {"models": models, "tests_tilt_drift": assessment.tests_tilt_drift}
    if not models:
        return [Advice(AdviceKind.DAMPING, "no damping: this scene tests eqs. 12/20 (precession, nutation); eqs. "
                       "25a/26 need a damped pivot (magnet in the ball, realisation B2)", values=values)]
    if growth is None:
        return []
    paper = growth.paper if growth.paper is not None else float("nan")
    if not math.isfinite(growth.exact):  # theory's source says why ("none: ..."), else the drift was not simulated
        why = growth.exact_source.split(": ", 1)[1] if growth.exact_source.startswith("none: ") else "not simulated"
        return [Advice(AdviceKind.DAMPING, values=values, text=(
            f"damping ({', '.join(models)}): no simulated tilt drift ({why}), so this launch cannot test eqs. "
            "25a/26"))]
    if not assessment.tests_tilt_drift:
        return [Advice(AdviceKind.DAMPING, values=values, text=(
            f"damping ({', '.join(models)}) shows no tilt drift: the simulated drift is {growth.exact:+.2g} 1/s "
            f"against the paper's {paper:+.3g} 1/s, so this rig cannot test eqs. 25a/26"
            + ("; the lab field damps only theta': use the magnet-in-ball realisation (B2)"
               if "eddy-field" in models else "")))]
    return [Advice(AdviceKind.DAMPING, values=values, text=f"damping realisation {', '.join(models)} tests eqs. "
                   f"25a/26: simulated tilt growth {growth.exact:+.3g} 1/s against the paper's {paper:+.3g} 1/s")]


# ------------------------------------------------------------------------------------------- sweeps
#: the most points a sweep takes (each is a full plan)
MAX_SWEEP_POINTS = 200


def parse_sweep(spec: str) -> tuple[str, np.ndarray]:
    """``KEY=START:STOP:N`` (KEY a dotted protocol path, e.g. ``launch.spin_rate_rad_s``); N in
    [2, :data:`MAX_SWEEP_POINTS`], START and STOP finite."""
    try:
        key, rng = spec.split("=", 1)
        a, b, n = rng.split(":")
        start, stop, count = float(a), float(b), int(n)
    except ValueError:
        raise ValueError(f"--sweep {spec!r}: expected KEY=START:STOP:N, e.g. camera.fps=100:400:7") from None
    if not 2 <= count <= MAX_SWEEP_POINTS:
        raise ValueError(f"--sweep {spec!r}: N must be in [2, {MAX_SWEEP_POINTS}] (each point is a full plan, a few "
                         "seconds)")
    if not (math.isfinite(start) and math.isfinite(stop)):
        raise ValueError(f"--sweep {spec!r}: START and STOP must be finite numbers")
    return key.strip(), np.linspace(start, stop, count)


def _set_key(data: dict, key: str, value: float) -> None:
    parts = key.split(".")
    node = data
    for p in parts[:-1]:
        if p not in node or not isinstance(node[p], dict):
            raise ValueError(f"--sweep key {key!r}: the protocol has no table [{'.'.join(parts[:parts.index(p) + 1])}]")
        node = node[p]
    if parts[-1] not in node:
        raise ValueError(f"--sweep key {key!r}: the protocol has no key {parts[-1]!r} in [{'.'.join(parts[:-1])}]")
    node[parts[-1]] = value


def sweep(protocol_path: str | Path, key: str, values: np.ndarray, *, duration_s: float | None = None,
          progress=None) -> pd.DataFrame:
    """Expected relative error of every quantity as one protocol key is scanned.

    Columns: the key, ``<quantity>_relative_error`` (NaN where not resolvable, or where the camera does not
    see the tip), ``motion_blur_px``, ``sigma_px``, ``marker_in_view_fraction`` (the frames whose tip spot is
    wholly in the image: below 1 the setting loses the marker, and its frames are gaps of the expected record).
    """
    base = tomllib.loads(_io.read_settings_text(protocols.protocol_path(protocol_path)))
    rows = []
    for i, v in enumerate(values):
        data = copy.deepcopy(base)
        _set_key(data, key, float(v))
        p = parse_protocol(data, source=str(protocol_path))
        plan = plan_experiment(p, duration_s=duration_s, simulate_damping=False, draws=0)
        row = {key: float(v)}
        for name, q in plan.quantities.items():
            rel = q.expected_relative_error
            row[f"{name}_relative_error"] = rel if q.resolvable and rel is not None else math.nan
        cam = plan.camera or {}
        row["motion_blur_px"] = cam.get("motion_blur_px", math.nan)
        row["sigma_px"] = cam.get("sigma_px", math.nan)
        row["marker_in_view_fraction"] = cam.get("marker_in_view_fraction", math.nan)
        rows.append(row)
        if progress:
            progress(i + 1, len(values))
    return pd.DataFrame(rows)
