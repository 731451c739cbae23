"""``fit_angles``: the fit of an angle table against the scene's model, compared with theory."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
import pandas as pd
from scipy.stats import chi2 as chi2_dist

from .._format import with_error
from ..prediction import Prediction
from ..protocols import AirDamping, Protocol
from .breaks import find_break
from .checks import check_notes
from .constraints import Constraints
from .data import FitData, FitError, fit_data_from_angles
from .model import FitModel, Residuals, model_for_scene
from .quantities import build_quantities, quantity_functions, truth_values
from .result import NONLINEAR_PHASE_RAD, ErrorKind, FitResult, MotionBreak, Note, NoteKind, Reason, Undetermined
from .selection import PLANNED_NONCENTRALITY, fit_model, left_out_noncentrality
from .solver import Solution, solve
from .spec import FitTerms
from .terms import BFrameShrink, RollingShutter
from .uncertainty import choose_errors, delta_se, phase_uncertainty, shared_pose_prior_root, statistical_covariance

__all__ = ["fit_angles", "linear_response", "record_state", "state_values", "TERM_CHOICES", "STATE_NAMES"]

TERM_CHOICES = ("data", "noiseless")
#: above this reduced chi-square the residuals are dominated by a systematic, and the report says so
SYSTEMATIC_CHI2_RED = 10.0
#: an undamped scene's record is said to show a changing spin when the spin-down model lowers its chi-square this many
#: times and finds the precession's growth this many standard errors from 0
SPIN_DOWN_CHI2_GAIN = 4.0
SPIN_DOWN_SIGMAS = 5.0
#: breaks in the motion looked for, one after another in the part kept (:mod:`gyrorig.fit.breaks`)
MAX_BREAKS = 3


def _choose_model(data: FitData, scene, terms: FitTerms | str) -> tuple[Solution, list[Note], dict, FitTerms]:
    """The solution with its terms chosen as ``terms`` says; notes; undetermined quantities; the terms."""
    if isinstance(terms, str) and terms not in TERM_CHOICES:
        raise ValueError(f"terms must be one of {', '.join(TERM_CHOICES)} or a FitTerms; got {terms!r}")
    if isinstance(terms, FitTerms):
        sol, notes, undetermined = fit_model(data, scene, terms=terms)
        notes = [Note(NoteKind.TERMS_GIVEN, f"model terms ({terms.describe()}) {terms.source or 'given'}")] + notes
        return sol, notes, undetermined, terms
    sol, notes, undetermined = fit_model(data, scene,
                                         noncentrality=PLANNED_NONCENTRALITY if terms == "noiseless" else None)
    chosen = (FitTerms.of(sol.spec, "chosen by chi-square tests on the data") if terms == "data" else
              FitTerms.of(sol.spec, f"chosen on noiseless data (non-centrality above {PLANNED_NONCENTRALITY:g})",
                          left_out_noncentrality(sol, data)))
    return sol, notes, undetermined, chosen


def _standard_errors(sol: Solution, data: FitData, fns: dict, error_kind: ErrorKind, bootstrap_sd: dict
                     ) -> tuple[dict, dict, dict]:
    """Each quantity's value and reported standard error, its formal (Cramér-Rao) error, and the camera
    model's share."""
    values, formal, camera_se = {}, {}, {}
    cov_stat = statistical_covariance(sol.spec, sol.x, sol.cov, data)
    chi2_red = sol.chi2 / max(sol.dof, 1)
    for k, f in fns.items():
        v, se = delta_se(f, sol.x, sol.cov)
        formal[k] = se
        se_stat = se
        if cov_stat is not None:
            se_stat = delta_se(f, sol.x, cov_stat)[1]
            camera_se[k] = math.sqrt(max(se * se - se_stat * se_stat, 0.0))
        if error_kind is ErrorKind.SCALED:
            se_stat *= math.sqrt(chi2_red)
        if k in bootstrap_sd:
            se_stat = max(se_stat, bootstrap_sd[k])
        values[k] = (v, math.hypot(se_stat, camera_se.get(k, 0.0)))
    return values, formal, camera_se


def _without(angles: pd.DataFrame, exclude: np.ndarray | None, data: FitData, drop: np.ndarray, scene,
             constraints: Constraints, terms):
    """The record without the fit's frames ``drop``: the angles' exclusion mask, the fit's data and the model
    chosen again (:func:`_choose_model`)."""
    gone = np.isin(angles["t_s"].to_numpy(float), data.t_s[drop])
    exclude = gone if exclude is None else np.asarray(exclude, bool) | gone
    data = fit_data_from_angles(angles, exclude, scene.precession_hint_rad_s, constraints, leave_out_still_ends=True)
    return exclude, data, _choose_model(data, scene, terms)


def _break_notes(breaks: list[MotionBreak], data: FitData, after: bool) -> list[Note]:
    """A note for each break in the motion found (:mod:`gyrorig.fit.breaks`), and one that says which part was
    fitted (``after``: one that starts after a break)."""
    if not breaks:
        return []
    out = [Note(NoteKind.MOTION_BREAK, f"{brk.describe()}; the longer part is kept") for brk in breaks]
    out.append(Note(NoteKind.MOTION_BREAK, f"fitted: the frames from {data.t_s[0]:.4g} s to {data.t_s[-1]:.4g} s "
                    "(--start and --end fit another part)" + (
                        "; it starts after a break, not from the protocol's launch: theory at the launch is shown "
                        "beside it, not compared" if after else "")))
    return out


def _limb_note(angles: pd.DataFrame) -> list[Note]:
    """A note when the tracker flagged the record ``near-limb`` (:func:`gyrorig.tracking.rays.limb_flags`)."""
    if "quality" not in angles.columns:
        return []
    flagged = angles.quality.astype(str).str.contains("near-limb") & angles.theta_rad.notna()
    if not flagged.any():
        return []
    return [Note(NoteKind.NEAR_LIMB, f"{int(flagged.sum())} of the record's frames are flagged near-limb: the tip came "
                 "near the edge of its sphere as the camera saw it, beyond which it is read on the wrong side, and the "
                 "fitted values may describe a motion the top did not make, whatever the chi-square says; film from "
                 "above")]


#: frames between a still end and the free motion (the hand letting the top go, or catching it) are left out where
#: the first fit leaves them beyond this many of their errors, in a run from the still end of at most this share of
#: the frames (a longer run is a misfit of the whole record, not a hand's)
TRANSITION_Z, TRANSITION_MAX_SHARE = 5.0, 0.1


def _transition_frames(sol: Solution, data: FitData) -> tuple[int, int]:
    """How many frames next to the still head and tail (:mod:`gyrorig.stillness`) are the hand's, not the free
    motion's (:data:`TRANSITION_Z`, :data:`TRANSITION_MAX_SHARE`)."""
    still = data.still
    if still is None or not still.any:
        return 0, 0
    z = np.max(np.abs(Residuals(sol.model, data)(sol.x)[:2 * data.n].reshape(2, -1)), axis=0)
    off = z > TRANSITION_Z

    def run(flags: np.ndarray) -> int:
        k = len(flags) if flags.all() else int(np.argmin(flags))
        return k if k <= TRANSITION_MAX_SHARE * len(flags) else 0
    return (run(off) if still.head else 0), (run(off[::-1]) if still.tail else 0)


def _still_note(data: FitData, hand: tuple[int, int]) -> list[Note]:
    """A note when the record's still ends were left out (:mod:`gyrorig.stillness`), with the ``hand`` frames after
    the head and before the tail (:func:`_transition_frames`)."""
    still = data.still
    if still is None or not still.any:
        return []
    parts = []
    for end, which, why, k in ((still.head, "first", "the top held before its release?", hand[0]),
                               (still.tail, "last", "the top caught, or at rest against a stop?", hand[1])):
        if end is not None:
            parts.append(f"within {math.degrees(end.radius):.2g} deg of one place for the {which} "
                         f"{end.duration_s:.3g} s of the record's angles ({end.frames} frames: {why}), where elsewhere "
                         f"it stays at most {end.dwell_s:.2g} s" + (
                             f" (and the {k} frames {'after' if which == 'first' else 'before'} it, beyond "
                             f"{TRANSITION_Z:g} of their errors from the motion: the hand's)" if k else ""))
    text = (f"the tip stayed {' and '.join(parts)}: not the scene's motion, left out; the fit's frames run from t = "
            f"{data.t_s[0]:.4g} s to {data.t_s[-1]:.4g} s (--start and --end choose the span yourself)")
    return [Note(NoteKind.STILL_ENDS, text)]


def _record_notes(sol: Solution, data: FitData, phases: dict, camera_se: dict, check_residuals: bool) -> list[Note]:
    """Notes on the record: too short for the model, a dominating systematic, the camera's share."""
    notes = []
    nonlinear = {k: v for k, v in phases.items() if v > NONLINEAR_PHASE_RAD}
    if nonlinear:
        notes.append(Note(NoteKind.RECORD_TOO_SHORT, "the record is too short for this model: " + ", ".join(
            f"{k} leaves {v:.2g} rad of phase uncertain over the record" for k, v in nonlinear.items())
            + f" (above {NONLINEAR_PHASE_RAD:g}); the model is not linear over one standard error, so the standard "
            "errors are not reliable (they vary from record to record); a longer record resolves the terms"))
    chi2_red = sol.chi2 / max(sol.dof, 1)
    if check_residuals and chi2_red > SYSTEMATIC_CHI2_RED:
        notes.append(Note(NoteKind.SYSTEMATIC,
                          f"the residuals are far larger than the tracker's errors (reduced chi-square {chi2_red:.3g}): "
                          "a systematic error dominates (camera calibration or pose, a table not level, a tip marker "
                          "off the stem's axis, or a motion the model does not describe); the standard errors cover "
                          "the statistical part only and understate the true error"
                          + ("; the fitted lean of the cone's axis may stand in for part of it" if sol.spec.lean else "")))
    if data.inter_coded and sol.spec.harmonics > 0:
        shrink = ""
        if BFrameShrink.NAME in sol.spec.names():
            i = sol.spec.names().index(BFrameShrink.NAME)
            shrink = (f"; here its B pictures show the nutation {100 * sol.x[i]:.2g} % +- "
                      f"{100 * math.sqrt(sol.cov[i, i]):.2g} % smaller than its other pictures (fitted, and taken off)")
        notes.append(Note(NoteKind.CODEC_SMOOTHING,
                          "the video is inter-coded (P and B pictures): the codec builds a picture from its neighbours, "
                          "which smooths fast motion, so the nutation amplitude may come out low by more than its "
                          "error bar (0.5-1.5 % on HEVC renders of the air-cushion rig at 200 fps, CRF 23; none "
                          "with intra-only or lossless video)" + shrink))
    if RollingShutter.NAME in sol.spec.names():
        i = sol.spec.names().index(RollingShutter.NAME)
        readout, se = float(sol.x[i]), math.sqrt(max(float(sol.cov[i, i]), 0.0))
        interval = float(np.median(np.diff(data.t_s))) if data.n > 1 else math.inf
        # a video's rows are all read within its frame interval
        beyond = not -3.0 * se <= readout <= interval + 3.0 * se
        notes.append(Note(NoteKind.ROLLING_SHUTTER,
                          f"camera.json states a rolling shutter without its readout time: fitted from the motion, "
                          f"{1e3 * readout:.3g} ms +- {1e3 * se:.2g} ms (each frame's time moved by its tip's row "
                          "times it; left out, the delay warps the record's clock and biases the rates); a "
                          "readout_time_s stated in camera.json makes the rest more precise"))
        if beyond:
            notes.append(Note(NoteKind.READOUT_BEYOND_FRAME,
                              f"the fitted readout ({1e3 * readout:.3g} ms) lies outside the frame interval "
                              f"({1e3 * interval:.3g} ms), where no rolling shutter reads its rows: the model misses "
                              "something else (a pose found from this same motion?) and the rates are not to be "
                              "trusted; state readout_time_s in camera.json"))
    if camera_se:
        notes.append(Note(NoteKind.CAMERA_MODES,
                          f"the camera model's uncertainty ({data.camera_modes} modes from the tracker) is in the fit "
                          "as nuisance parameters with their priors: every standard error includes it (camera share: "
                          + ", ".join(f"{k} {camera_se[k]:.2g}" for k in ("precession_rate_rad_s",
                                                                          "nutation_amplitude_rad",
                                                                          "tilt_growth_rate_per_s",
                                                                          "equilibrium_tilt_rad") if k in camera_se)
                          + ")"))
    return notes


def _residual_tables(sol: Solution, data: FitData) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per-frame residuals (raw and normalised), and the model curve on a fine grid."""
    model = FitModel(sol.spec)
    res = Residuals(model, data)
    r0, r1 = res.raw(sol.x)
    wr = res(sol.x)[:2 * data.n].reshape(2, -1)
    residuals = pd.DataFrame({"frame": data.frame, "t_s": data.t_s, "theta_resid_rad": r0, "phi_resid_rad": r1,
                              "theta_resid_norm": wr[0], "phi_resid_norm": wr[1]})
    tt = np.linspace(data.t_s[0], data.t_s[-1], min(20000, max(2000, 20 * data.n)))
    seg = np.searchsorted(data.t_s, tt, side="right") - 1
    th_c, ph_c = model.lab(sol.x, tt - data.t_ref_s, data.segment[np.clip(seg, 0, data.n - 1)])
    return residuals, pd.DataFrame({"t_s": tt, "theta_rad": th_c, "phi_rad": ph_c})


def fit_angles(angles: pd.DataFrame, protocol: Protocol, *, prediction: Prediction | None = None,
               exclude: np.ndarray | None = None, truth: pd.DataFrame | None = None,
               rng: np.random.Generator | None = None, bootstrap_replicates: int = 50,
               check_residuals: bool = True, terms: FitTerms | str = "data",
               constraints: Constraints | None = None) -> FitResult:
    """Fit an angle table with the scene's model and compare with theory (and truth, if given).

    Parameters
    ----------
    angles : DataFrame
        ``t_s, theta_rad, phi_rad, theta_sigma_rad, phi_sigma_rad[, theta_phi_corr, frame, exposure_s,
        theta_cam_k_rad, phi_cam_k_rad]`` (:mod:`gyrorig.tables`).
    protocol : Protocol
        The scene (decides the model).
    prediction : Prediction, optional
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
        Cramér-Rao bound for the stated per-frame errors).
    terms : {"data", "noiseless"} or FitTerms
        How the optional model terms are chosen (:mod:`gyrorig.fit.selection`).  ``"data"``
        (default): by chi-square tests on these data.  A :class:`FitTerms` (from
        :func:`gyrorig.expectation.plan_fit_terms`, i.e. ``gyrorig plan``): these terms, the same for
        every record of the scene; a term the data need beyond them is still added (noted).
        ``"noiseless"``: the angles are noiseless model data (planning): a term is kept above a
        non-centrality of :data:`~gyrorig.fit.selection.PLANNED_NONCENTRALITY`.
    constraints : Constraints, optional
        Parameters held fixed or given Gaussian priors, by name (:mod:`gyrorig.fit.constraints`).
    """
    start_time = time.perf_counter()
    scene = model_for_scene(protocol, prediction)
    constraints = constraints or Constraints()
    data = fit_data_from_angles(angles, exclude, scene.precession_hint_rad_s, constraints, leave_out_still_ends=True)
    sol, notes, undetermined, chosen = _choose_model(data, scene, terms)
    hand = _transition_frames(sol, data)
    if any(hand):  # the frames between a still end and the free motion left out too, and the model chosen again
        drop = np.zeros(data.n, bool)
        drop[:hand[0]] = drop[data.n - hand[1]:] = True
        exclude, data, (sol, notes, undetermined, chosen) = _without(angles, exclude, data, drop, scene, constraints,
                                                                     terms)
    breaks = []
    while check_residuals and len(breaks) < MAX_BREAKS and chi2_dist.sf(sol.chi2, sol.dof) < 1e-3:
        brk = find_break(sol, data)
        if brk is None:
            break
        # the longer part kept, and its model chosen again (a part may hold terms the whole record's misfit hid)
        before = data.t_s <= brk.t_before_s
        drop = ~before if before.sum() >= data.n - before.sum() else before
        exclude, data, (sol, notes, undetermined, chosen) = _without(angles, exclude, data, drop, scene, constraints,
                                                                     terms)
        breaks.append(brk)
    after_break = any(b.t_after_s <= data.t_s[0] for b in breaks)
    notes = _still_note(data, hand) + _break_notes(breaks, data, after_break) + notes
    if data.camera_prior is not None and sol.spec.camera_modes and np.any(data.camera_prior == 0.0):
        # a pose found from these frames: its modes' priors less what the frames hold, the chosen model refitted
        data = replace(data, camera_prior_root=shared_pose_prior_root(sol.spec, sol.x, data))
        sol = solve(sol.spec, data, FitModel(sol.spec).values(sol.x), near=True)
    if constraints:
        notes.append(_constraint_note(constraints, sol.spec))
        notes += _prior_conflicts(constraints, sol, data)
    at_pole = _azimuth_undefined(data, sol.spec)
    if at_pole is not None:
        # the tilt's size too: a mean distance from the vertical within a few errors is mostly the noise's (biased up)
        undetermined = {**undetermined, "precession_rate_rad_s": at_pole,
                        "cone_angle_rad": Reason(Undetermined.AZIMUTH_UNDEFINED, at_pole.text + "; the cone angle, a "
                                                 "tilt this near the errors, is mostly the noise's (biased upwards)")}
    fns = quantity_functions(sol.spec)
    error_kind, bootstrap, bootstrap_sd, error_notes = choose_errors(
        sol.spec, sol.x, sol.chi2, sol.dof, data, fns, rng, bootstrap_replicates, check_residuals)
    phases = phase_uncertainty(sol.spec, sol.x, sol.cov, data)
    values, formal, camera_se = _standard_errors(sol, data, fns, error_kind, bootstrap_sd)
    notes += error_notes + _record_notes(sol, data, phases, camera_se, check_residuals) + _limb_note(angles)
    if check_residuals and not sol.spec.damped and protocol.has_gravity and sol.chi2 > SYSTEMATIC_CHI2_RED * sol.dof:
        notes += _spin_down_note(angles, protocol, prediction, exclude, constraints, sol, data)
    truth_vals = truth_values(truth, data, sol.spec, sol.x) if truth is not None else {}
    quantities = build_quantities(sol.spec, values, formal, camera_se, undetermined, protocol, prediction, truth_vals,
                                  after_break=after_break)
    notes += check_notes(sol, data, protocol, quantities)
    residuals, curve = _residual_tables(sol, data)
    names = sol.spec.names()
    params = {n: (float(v), float(np.sqrt(max(sol.cov[i, i], 0.0)))) for i, (n, v) in enumerate(zip(names, sol.x))}
    return FitResult(spec=sol.spec, params=params, quantities=quantities, chi2=sol.chi2, dof=sol.dof,
                     residuals=residuals, model_curve=curve, t_ref_s=data.t_ref_s, error_kind=error_kind,
                     notes=tuple(notes), x=sol.x, covariance=sol.cov, wall_time_s=time.perf_counter() - start_time,
                     terms=chosen, phase_uncertainty_rad=phases, bootstrap=bootstrap, constraints=constraints,
                     breaks=tuple(breaks))


def _spin_down_note(angles: pd.DataFrame, protocol: Protocol, prediction: Prediction | None,
                    exclude: np.ndarray | None, constraints: Constraints, sol: Solution, data: FitData) -> list[Note]:
    """A note when an undamped scene's record is described by the rates a changing spin gives and far better than
    by the undamped model (:data:`SPIN_DOWN_CHI2_GAIN`, :data:`SPIN_DOWN_SIGMAS`; reduced chi-square below
    :data:`SYSTEMATIC_CHI2_RED`), with the nutation frequency changing the other way at a like relative rate (a
    factor 2; where the record has a nod): the same angles fitted as if a drag no motor held acted on the rotor
    (the spin-down model: the precession and nutation rates exponential in time).  A misfit of another cause (a
    marker off the axis, a pose stated wrong) the spin-down model's freedom may lower, but not describe."""
    drag = AirDamping(0.0, 1e-12, spin_compensated=False)  # its size does not enter the model, only that it acts
    spinning = replace(protocol, pivot=replace(protocol.pivot, damping=protocol.pivot.damping + (drag,)))
    try:
        trial = fit_angles(angles, spinning, prediction=prediction, exclude=exclude, check_residuals=False,
                           constraints=constraints, terms=FitTerms(harmonics=min(sol.spec.harmonics, 2),
                                                                   source="the spin-down check"))
    except FitError:
        return []
    growth = trial.quantities.get("precession_growth_rate_per_s")
    if (growth is None or not growth.determined or not growth.standard_error
            or trial.chi2 * SPIN_DOWN_CHI2_GAIN > sol.chi2 or trial.chi2 > SYSTEMATIC_CHI2_RED * trial.dof
            or abs(growth.value) < SPIN_DOWN_SIGMAS * growth.standard_error):
        return []
    if "nutation_chirp_rad_s2" in trial.params:
        slowing = -trial.params["nutation_chirp_rad_s2"][0] / trial.params["nutation_frequency_rad_s"][0]
        if not 0.5 < slowing / growth.value < 2.0:
            return []
    g, span = growth.value, float(data.t_s[-1] - data.t_s[0])
    return [Note(NoteKind.SPIN_DOWN,
                 f"the precession rate changes by {100 * g:+.2g} % per second along the record "
                 f"({100 * math.expm1(g * span):+.2g} % over its {span:.3g} s) and the nutation frequency the other "
                 f"way: the rotor's spin {'decays' if g > 0 else 'grows'}, which the protocol does not say; fitted "
                 f"with the rates a changing spin gives, the reduced chi-square is {trial.chi2_red:.3g} (here "
                 f"{sol.chi2 / max(sol.dof, 1):.3g}): state the drag on the rotor in [pivot.damping] (model = \"air\", "
                 f"spin_compensated = false, axial_coefficient_N_m_s = Io times the spin's decay rate, about "
                 f"{g:.2g} 1/s) and fit again")]


def _constraint_note(constraints: Constraints, spec) -> Note:
    parts = [f"{n} fixed at {v:.6g}" for n, v in constraints.fixed]
    parts += [f"{n} with prior {m:.6g} +- {s:.3g}" for n, m, s in constraints.priors]
    unused = constraints.unused(spec)
    text = "constrained by the user: " + "; ".join(parts) + " (a fixed parameter has standard error 0; a prior " \
        "counts as one more measurement of its parameter)"
    if unused:
        text += f"; unused, the model has no such parameter: {', '.join(unused)}"
    return Note(NoteKind.CONSTRAINED, text)


#: a user's fixed value or prior this many combined standard errors from what the record alone says is a conflict
PRIOR_CONFLICT_SIGMAS = 3.0


def _prior_conflicts(constraints: Constraints, sol: Solution, data: FitData) -> list[Note]:
    """The record refitted without the user's constraints: each fixed value or prior further than
    :data:`PRIOR_CONFLICT_SIGMAS` combined standard errors from the record's own estimate is a conflict (a prior
    that disagrees with the data pulls the result while the chi-square hides it)."""
    names = sol.spec.names()
    wanted = [(n, m, 0.0) for n, m in constraints.fixed] + list(constraints.priors)
    wanted = [w for w in wanted if w[0] in names]
    if not wanted:
        return []
    try:
        free = solve(sol.spec, replace(data, constraints=Constraints()), FitModel(sol.spec).values(sol.x), near=True)
    except FitError as exc:
        return [Note(NoteKind.PRIOR_CONFLICT, f"the constraints could not be checked against the record alone: the "
                                              f"unconstrained fit failed ({exc})")]
    scale = math.sqrt(max(1.0, free.chi2 / max(free.dof, 1)))
    out = []
    for name, mean, sd in wanted:
        i = names.index(name)
        value, se = float(free.x[i]), math.sqrt(max(float(free.cov[i, i]), 0.0)) * scale
        combined = math.hypot(se, sd)
        z = (value - mean) / combined if combined > 0 else math.inf
        if abs(z) > PRIOR_CONFLICT_SIGMAS:
            given = f"fixed at {mean:.6g}" if sd == 0 else f"given the prior {mean:.6g} +- {sd:.3g}"
            out.append(Note(NoteKind.PRIOR_CONFLICT,
                            f"{name} is {given}, but the record alone says {with_error(value, se)}: {z:+.3g} combined "
                            "standard errors apart; the constrained result mixes two measurements that disagree "
                            "(check the prior, or leave it out)", term=name))
    return out


#: a tilt below this many of its per-frame errors (medians over the record) leaves the azimuth undefined
POLE_TILT_SIGMAS = 3.0


def _azimuth_undefined(data: FitData, spec) -> Reason | None:
    """Why the precession rate is not defined (None when it is): a tilt within :data:`POLE_TILT_SIGMAS` of its
    errors of the vertical, up or down (a hanging top), where the measured azimuth is the direction of the noise."""
    if spec.fit_axis and not spec.lean:
        return None
    tilt = float(np.median(np.minimum(data.theta_rad, math.pi - data.theta_rad)))
    sigma = float(np.median(np.sqrt(np.clip(data.cov[:, 0, 0], 0.0, None))))
    if tilt < POLE_TILT_SIGMAS * sigma:
        return Reason(Undetermined.AZIMUTH_UNDEFINED,
                      f"the tilt ({tilt:.2g} rad) is within {POLE_TILT_SIGMAS:g} of its errors ({sigma:.2g} rad) of "
                      "the vertical: the azimuth, and so the precession, is not defined (a sleeping top)")
    return None


def linear_response(angles: pd.DataFrame, fit: FitResult, protocol: Protocol, *,
                    prediction: Prediction | None = None):
    """The linearised estimator about a fit of noiseless ``angles``.

    Returns a function that takes other angles at the same frames (the same motion plus noise)
    and gives each determined quantity after one Gauss-Newton step from ``fit.x``:
    ``x = x0 - (J^T J)^-1 J^T r(x0)``.  That is what the fit would return if the model were
    linear over the noise; where a real fit of the same record lands elsewhere (by a sizeable
    fraction of a standard error), its error bars are not Cramér-Rao bounds.
    """
    scene = model_for_scene(protocol, prediction)
    model = FitModel(fit.spec)
    J0 = Residuals(model, fit_data_from_angles(angles, None, scene.precession_hint_rad_s)).jac(fit.x)
    cov0 = np.linalg.pinv(J0.T @ J0, rcond=1e-14, hermitian=True)
    fns = quantity_functions(fit.spec)
    keys = [k for k in fns if k in fit.quantities and fit.quantities[k].determined]

    def respond(noisy: pd.DataFrame) -> dict[str, float]:
        white = Residuals(model, fit_data_from_angles(noisy, None, scene.precession_hint_rad_s))
        x = fit.x - cov0 @ (J0.T @ white(fit.x))
        return {k: float(fns[k](x)) for k in keys}

    return respond


#: the record's state at its first frame, in this order (:func:`record_state`)
STATE_NAMES = ("tilt_rad", "azimuth_rad", "tilt_rate_rad_s", "precession_rate_rad_s")


def _state_vector(model: FitModel, x: np.ndarray, t0: float, t_ref: float) -> np.ndarray:
    """Tilt, azimuth and their rates at ``t0``: in the lab, or from the fitted axis where that is the true vertical
    leaning in the camera's lab (``lean``: the simulator's gravity is along the true vertical)."""
    h = 1e-4
    angles = model.axis_frame if model.spec.lean else model.lab
    th, ph = angles(x, np.array([t0 - h, t0, t0 + h]) - t_ref, np.zeros(3, int))
    ph = np.unwrap(ph)
    return np.array([th[1], ph[1], (th[2] - th[0]) / (2 * h), (ph[2] - ph[0]) / (2 * h)])


def record_state(fit: FitResult) -> tuple[float, dict[str, float], np.ndarray]:
    """The fitted motion at the record's first frame: its time [s], the state (:data:`STATE_NAMES`: the model
    curve and its central differences over 0.1 ms) and the state's covariance (4, 4) from the fit's (scaled by
    chi2_red when above 1)."""
    model = FitModel(fit.spec)
    t0 = float(fit.residuals.t_s.iloc[0])
    s0 = _state_vector(model, fit.x, t0, fit.t_ref_s)
    sd = np.sqrt(np.clip(np.diag(fit.covariance), 0.0, None))
    jac = np.zeros((len(s0), len(fit.x)))
    for i in np.flatnonzero(sd > 0):
        step = np.zeros(len(fit.x))
        step[i] = 1e-3 * sd[i]
        jac[:, i] = (_state_vector(model, fit.x + step, t0, fit.t_ref_s)
                     - _state_vector(model, fit.x - step, t0, fit.t_ref_s)) / (2 * step[i])
    cov = jac @ fit.covariance @ jac.T * max(1.0, fit.chi2_red)
    return t0, dict(zip(STATE_NAMES, map(float, s0))), cov


def state_values(fit: FitResult, angles: pd.DataFrame, protocol: Protocol, motion: pd.DataFrame, *,
                 prediction: Prediction | None = None) -> dict[str, float]:
    """The quantities of ``fit``'s model fitted to a noiseless ``motion`` (``t_s, theta_rad, phi_rad``) at the
    frames ``fit`` used of the record ``angles``, with their weights (:func:`gyrorig.fit.quantities.truth_values`):
    what this estimator gives for that motion."""
    scene = model_for_scene(protocol, prediction)
    unused = ~angles["t_s"].isin(fit.residuals.t_s).to_numpy()
    data = fit_data_from_angles(angles, unused, scene.precession_hint_rad_s, fit.constraints)
    return truth_values(motion, data, fit.spec, fit.x)
