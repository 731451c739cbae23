"""The analysis chain, written once and in memory: track -> smooth -> fit against theory.

:func:`analyze` runs a video (or frames in memory) through the pure steps and returns an
:class:`Analysis`; :func:`smooth_and_fit` does the part after tracking, for an angle table.
File wrappers (``gyrorig analyze``, ``gyrorig fit``) are in :mod:`gyrorig.analysis`; the Monte
Carlo of the full chain (:mod:`gyrorig.montecarlo`) and the demo (:mod:`gyrorig.demo`) call
these too.  Like pvlib's ``ModelChain``, but a function over frozen results, not a mutable object.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from .fit import STATE_NAMES, Constraints, FitResult, FitTerms, fit_angles, record_state, state_values
from .fit.result import Note, NoteKind
from .fit.quantities import at_record_state
from .prediction import Prediction
from .protocols import Protocol
from .smooth import SmoothResult, smooth_angles
from .propagate import predict_with_uncertainty
from .physics.simulate import simulate
from .camera import Camera
from .tracking import TrackResult, load_camera, track

logger = logging.getLogger(__name__)

__all__ = ["Analysis", "Fitted", "analyze", "smooth_and_fit"]

Progress = Callable[[int, int], None]
Stage = Callable[[str], None]

#: a smoother that gates more than this share of the frames cannot follow the record's motion with its one process
#: noise (a nod too fast for the frame rate, a transient at the start of a long record): its gate at 5 sigma would
#: leave out a share of 6e-7 of frames its model fits
SMOOTHER_OUTLIER_SHARE = 0.01
#: the fit's own outliers: frames whose normalised residual (over the residuals' robust SD, where larger than 1)
#: exceeds this
FIT_OUTLIER_Z = 5.0


@dataclass(frozen=True)
class Fitted:
    """An angle table smoothed (for its outlier marks and rates) and fitted against theory."""

    #: the smoother's result (``smooth.table``: :data:`gyrorig.smooth.SMOOTH_COLUMNS`)
    smooth: SmoothResult
    #: :func:`gyrorig.theory.predict` for the protocol
    prediction: Prediction
    fit: FitResult
    #: wall time of each step [s]: ``smooth``, ``fit``
    time_s: dict


@dataclass(frozen=True)
class Analysis:
    """One video through the whole chain."""

    #: the tracker's tables and summary (``tracking.angles``: :data:`gyrorig.tables.ANGLE_COLUMNS` ...)
    tracking: TrackResult
    smooth: SmoothResult
    prediction: Prediction
    fit: FitResult
    #: wall time of each step [s]: ``track``, ``smooth``, ``fit``, ``total``
    time_s: dict

    @property
    def angles(self) -> pd.DataFrame:
        return self.tracking.angles


def smooth_and_fit(angles: pd.DataFrame, protocol: Protocol, *, prediction: Prediction | None = None,
                   truth: pd.DataFrame | None = None, rng: np.random.Generator | None = None,
                   terms: FitTerms | str = "data", smooth: SmoothResult | None = None,
                   stage: Stage | None = None, constraints: Constraints | None = None) -> Fitted:
    """Smooth an angle table (its outlier marks leave frames out of the fit), predict, fit.

    ``prediction`` defaults to :func:`gyrorig.propagate.predict_with_uncertainty` of the protocol (the
    predictions with error bars from its parameter uncertainties); ``truth`` (noiseless
    ``t_s, theta_rad, phi_rad``, e.g. :func:`gyrorig.tables.tip_truth`) adds true values and pulls;
    ``terms`` and ``constraints`` as in :func:`gyrorig.fit.fit_angles`; ``smooth``: an earlier result for
    these angles.
    """
    say = stage or logger.info
    t0 = time.perf_counter()
    if smooth is None:
        say(f"smoothing {len(angles)} frames (noise levels by maximum likelihood) ...")
        smooth = smooth_angles(angles)
    t1 = time.perf_counter()
    say("theory predictions and the fit ...")
    if prediction is None:
        prediction = predict_with_uncertainty(protocol)
    exclude = (smooth.table["status"] == "outlier").to_numpy()
    note = None
    if exclude.mean() > SMOOTHER_OUTLIER_SHARE:
        exclude, note = _outliers_by_fit(angles, protocol, prediction, exclude, terms, constraints)
    fit = fit_angles(angles, protocol, prediction=prediction, exclude=exclude, truth=truth, rng=rng, terms=terms,
                     constraints=constraints)
    if note is not None:
        fit = replace(fit, notes=fit.notes + (note,))
    if fit.spec.damped:
        say("theory at the record's own state (the simulator from its fitted first frame) ...")
    fit = _at_record_state(fit, angles, protocol, prediction)
    return Fitted(smooth, prediction, fit, {"smooth": t1 - t0, "fit": time.perf_counter() - t1})


def _outliers_by_fit(angles: pd.DataFrame, protocol: Protocol, prediction: Prediction, gated: np.ndarray,
                     terms: FitTerms | str, constraints: Constraints | None) -> tuple[np.ndarray, Note]:
    """The frames to leave out when the smoother gated more than :data:`SMOOTHER_OUTLIER_SHARE` of them: those the
    fit of every frame leaves beyond :data:`FIT_OUTLIER_Z` of its residuals' robust SD (where above 1), and a note
    that says so."""
    every = fit_angles(angles, protocol, prediction=prediction, terms=terms, constraints=constraints,
                       check_residuals=False)
    z = every.residuals[["theta_resid_norm", "phi_resid_norm"]].to_numpy(float)
    spread = max(1.0, 1.4826 * float(np.median(np.abs(z))))
    off = every.residuals.t_s.to_numpy(float)[np.max(np.abs(z), axis=1) > FIT_OUTLIER_Z * spread]
    exclude = np.isin(angles.t_s.to_numpy(float), off)
    text = (f"the smoother gated {int(gated.sum())} of {len(gated)} frames ({100 * gated.mean():.1f} %), more than "
            f"its model allows ({100 * SMOOTHER_OUTLIER_SHARE:g} %: one process noise cannot follow this motion at "
            f"this frame rate); the fit's model judged them instead: {int(exclude.sum())} frame(s) beyond "
            f"{FIT_OUTLIER_Z:g} of its residuals' spread left out")
    logger.warning(text)
    return exclude, Note(NoteKind.OUTLIERS_BY_FIT, text)


def _at_record_state(fit: FitResult, angles: pd.DataFrame, protocol: Protocol, prediction: Prediction) -> FitResult:
    """A damped record compared with theory at its own state: the simulator launched from the fitted motion at the
    record's first frame (tilt, azimuth and their rates; the rotor's and a gyrostat frame's rates about the axis as
    the protocol's launch at the record's time 0 gives them then: :func:`_axial_rates_at`), over the record's frames,
    fitted with the same model (:func:`gyrorig.fit.quantities.at_record_state`); the state's uncertainty (from the
    fit) carried to each prediction by differences over one standard deviation of each state number.  The protocol's
    launch is not the record's: a damped top drifts, and a recording starts after the release."""
    if not fit.spec.damped:
        return fit
    t0, state, cov = record_state(fit)
    if not 0.0 < state["tilt_rad"] < math.pi:
        return fit
    t = np.unique(fit.residuals.t_s.to_numpy(float)) - t0
    rotor, frame = _axial_rates_at(protocol, t0)

    def values(s: dict[str, float]) -> dict[str, float]:
        # a launch's spin rates are psi' (the rotor's, a gyrostat frame's): their rates about the axis less
        # phi' cos(theta)
        turn = s["precession_rate_rad_s"] * math.cos(s["tilt_rad"])
        launch = replace(protocol.launch, **s, spin_rate_rad_s=rotor - turn)
        if frame is not None:
            launch = replace(launch, frame_spin_rate_rad_s=frame - turn)
        motion = simulate(replace(protocol, launch=launch), t_eval_s=t)
        return state_values(fit, angles, protocol, motion.assign(t_s=motion.t_s + t0), prediction=prediction)

    try:
        v0 = values(state)
        keys = [k for k in v0 if k != "cone_angle_rad"]  # the cone is the state itself, not a prediction
        jac = np.zeros((len(keys), len(STATE_NAMES)))
        for j, name in enumerate(STATE_NAMES):
            step = math.sqrt(max(cov[j, j], 0.0))
            if step > 0:
                moved = values({**state, name: state[name] + step})
                jac[:, j] = [(moved[k] - v0[k]) / step for k in keys]
    except (ValueError, ArithmeticError, RuntimeError) as exc:  # the launch's comparison stays, and says so
        logger.warning("no prediction at the record's fitted state: %s", exc)
        return fit
    sd = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", jac, cov, jac), 0.0, None))
    source = (f"simulator from the record's fitted state at t = {t0:.4g} s (tilt {state['tilt_rad']:.5g} rad), "
              "fitted with the same model")
    return at_record_state(fit, {k: (v0[k], float(s)) for k, s in zip(keys, sd)}, source)


def _axial_rates_at(protocol: Protocol, t0: float) -> tuple[float, float | None]:
    """The rotor's and a gyrostat frame's rates about the axis [rad/s] at the record's time ``t0``, as the protocol's
    launch at time 0 gives them (the rotor's conserved where no drag slows it or a motor holds it; a drag's decay, the
    frame's relaxation, simulated); the frame's None for a plain top."""
    launch = protocol.launch
    gyrostat = protocol.rig.frame_axial_inertia_kg_m2 is not None
    if t0 <= 0:
        turn = launch.precession_rate_rad_s * math.cos(launch.tilt_rad)
        return launch.spin_rate_rad_s + turn, (launch.frame_spin_rate_rad_s + turn) if gyrostat else None
    early = simulate(protocol, t_eval_s=np.array([0.0, t0])).iloc[-1]
    return float(early.omega_o_rad_s), float(early.omega_frame_rad_s) if gyrostat else None


def analyze(video, camera: Camera | str | Path, protocol: Protocol, *, truth: pd.DataFrame | None = None,
            prediction: Prediction | None = None, terms: FitTerms | str = "data",
            constraints: Constraints | None = None, rng: np.random.Generator | None = None,
            progress: Progress | None = None, stage: Stage | None = None, frame_dots: bool = False,
            on_tracked: Callable[[TrackResult], None] | None = None) -> Analysis:
    """Track, smooth and fit one video.

    Parameters
    ----------
    video : path or frame source
        A container OpenCV decodes, or frames in memory (:class:`gyrorig.tracking.FrameArrays`).
    camera : Camera or path of ``camera.json``
        Without a pose, the tracker finds it from the protocol's lab fiducials.
    protocol : Protocol
        The scene: its markers, and the model the fit uses.
    truth, prediction, terms, rng
        As in :func:`smooth_and_fit`.
    progress : callable, optional
        ``progress(done, total)`` frame by frame during tracking.
    stage : callable, optional
        Told when each later step starts (fits of long damped records take minutes).
    frame_dots : bool
        Track the frame's dots too (its angle ``psi`` in the angles table).  The fit does not use them, so by
        default they are not tracked (that takes 30-40 % of the tracking time on a rig with two crossbar dots).
    on_tracked : callable, optional
        Given the tracking result as soon as it exists (a file wrapper saves it there, so that a
        fit that fails loses nothing).
    """
    cam = camera if isinstance(camera, Camera) else load_camera(camera, require_pose=False)
    t0 = time.perf_counter()
    tracked = track(video, cam, protocol, progress=progress, frame_dots=frame_dots)
    t1 = time.perf_counter()
    if on_tracked is not None:
        on_tracked(tracked)
    fitted = smooth_and_fit(tracked.angles, protocol, prediction=prediction, truth=truth, rng=rng, terms=terms,
                            constraints=constraints,
                            stage=stage)
    return Analysis(tracked, fitted.smooth, fitted.prediction, fitted.fit,
                    {"track": t1 - t0, **fitted.time_s, "total": time.perf_counter() - t0})
