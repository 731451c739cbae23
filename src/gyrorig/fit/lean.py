"""The cone's axis leaning from the camera's vertical on a scene whose vertical is known: a table not quite level, or
a pose whose vertical is off (the :class:`~gyrorig.fit.terms.Axis` term with ``ModelSpec.lean``).

The cone turns about the true vertical; seen in the camera's lab it leans: a circle at the precession's rate in both
angles.  :func:`lean_trial` looks for the lean on the slow model (before the nod's harmonics, which would otherwise
stand in for its circle), :func:`lean_kept` on the final one; :func:`gyrorig.fit.selection.fit_model` fits the nod
from both starts and keeps the better (docs/methods.md, "A table not level").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from scipy.stats import f as f_dist

from .data import FitData
from .model import FitModel
from .result import TERM_P_VALUE, Note, NoteKind
from .solver import Solution, linear_start, plane_axis, solve
from .uncertainty import har_threshold, long_run_ratio

__all__ = ["lean_trial", "lean_kept", "leaned", "lean_wanted", "f_test", "LEAN_MIN_TURN_RAD", "LEAN_MIN_TURN_DAMPED_RAD",
           "LEAN_MIN_TILT_SIGMAS", "LEAN_LABEL"]

#: a cone's axis leaning from the vertical is looked for only in a record over which the tip precesses half a turn, a
#: whole turn under damping (less, and its circle stands in for a change of the cone, the precession rate and the tilt's
#: growth), of a cone this many of its errors wide about the circle's axis (narrower, the azimuth about it is the
#: noise's)
LEAN_MIN_TURN_RAD = math.pi
LEAN_MIN_TURN_DAMPED_RAD = 2 * math.pi
LEAN_MIN_TILT_SIGMAS = 3.0
#: what the lean's note calls it
LEAN_LABEL = "the cone's axis leaning from the vertical (a table not level, or the pose's vertical off)"


def leaned(cur: Solution, data: FitData) -> Solution | None:
    """``cur`` refitted with the cone's axis (:class:`~gyrorig.fit.terms.Axis`) started from the axis of the circle
    the tip traces (:func:`~gyrorig.fit.solver.plane_axis`), the slow motion about it by linear least squares (where
    ``cur`` is the slow model alone) or as ``cur`` has it; None where a lean is not looked for (an axis fitted already;
    about that axis under :data:`LEAN_MIN_TURN_RAD` of precession, damped :data:`LEAN_MIN_TURN_DAMPED_RAD`, or a tilt
    within :data:`LEAN_MIN_TILT_SIGMAS` of its errors) or the fit fails.

    A scene whose vertical is known (no accelerating pivot) filmed on a table not quite level, or with a pose whose
    vertical is off, shows a cone about an axis leaning from the camera's vertical: a circle at the precession's rate
    in both angles.  A cone narrower than the lean does not circle the camera's vertical at all (its azimuth there
    swings to and fro): the precession about the circle's own axis decides."""
    if not cur.ok or cur.spec.fit_axis:
        return None
    spec = replace(cur.spec, fit_axis=True, lean=True)
    axis = plane_axis(data)
    about = linear_start(spec, data, axis)
    turn = LEAN_MIN_TURN_DAMPED_RAD if cur.spec.damped else LEAN_MIN_TURN_RAD
    sigma = float(np.median(np.sqrt(np.clip(data.cov[:, 0, 0], 0.0, None))))
    cone = math.exp(about["log_cone_angle"])
    if (abs(about["precession_rate_rad_s"]) * data.duration_s < turn
            or min(cone, math.pi - cone) < LEAN_MIN_TILT_SIGMAS * sigma):
        return None
    start = {**cur.values(), **(about if cur.spec.harmonics == 0 else {})}
    start["axis_tilt_rad"], start["axis_azimuth_rad"] = axis
    sol = solve(spec, data, start, near=cur.spec.harmonics > 0)
    return sol if sol.ok and sol.chi2 < cur.chi2 else None


def lean_trial(base: Solution, data: FitData) -> Solution | None:
    """The slow model ``base`` with the lean (:func:`leaned`) where an F test on the residuals wants it (the nod not
    yet modelled: their scale is the misfit's, not the errors'), else None.  A lean found here is in the model before
    the nod's harmonics, which would otherwise stand in for its circle (a lean of degrees, one wider than the cone) or
    fail beside it (under damping); but the nod's misfit (or another systematic's) can lend itself to a lean, so the
    nod is fitted from both starts (:func:`gyrorig.fit.selection.fit_model`)."""
    sol = leaned(base, data)
    return sol if sol is not None and f_test(base, sol) else None


def f_test(ref: Solution, sol: Solution) -> bool:
    """Whether ``sol`` (``ref`` plus parameters) lowers the chi-square beyond what its own residuals' scale allows (p
    < :data:`~gyrorig.fit.result.TERM_P_VALUE`): the chi-square test where those residuals are noise, and a harder
    one where a misfit dominates them (whose part along any new parameters is larger than noise's)."""
    ddof, dof = ref.dof - sol.dof, max(sol.dof, 1)
    f = (ref.chi2 - sol.chi2) / ddof / (sol.chi2 / dof)
    return bool(f_dist.sf(f, ddof, dof) < TERM_P_VALUE)


def lean_wanted(plain: Solution, lean: Solution, data: FitData, need: Callable[[int], float]) -> bool:
    """Whether the chi-square test and the F test (:func:`f_test`) want the lean in ``lean`` over ``plain``, its
    chi-square gain divided by how much more the residuals vary at the lowest frequencies than white noise would
    (:func:`~gyrorig.fit.uncertainty.long_run_ratio` of ``lean``'s residuals, whose own lean is taken out): the lean's
    circle is as slow as the record, and noise correlated over many frames (a codec's drifting errors, a texture
    passing behind the tip) lends a slow term that much more; the threshold is then the F distribution's for that
    ratio's degrees of freedom (:func:`~gyrorig.fit.uncertainty.har_threshold`).  The lean itself must pass the same
    test (its squared tilt over its variance, scaled by the reduced chi-square where above 1; not for a lean the user
    fixed, ``--fix axis_tilt_rad=...``): a refit from another start can lower the chi-square by converging further, not
    by the lean."""
    ratio, nu = long_run_ratio(FitModel(lean.spec), data, lean.x)
    ratio = max(ratio, 1e-12)
    gain = (plain.chi2 - lean.chi2) / ratio
    ddof, dof = plain.dof - lean.dof, max(lean.dof, 1)
    threshold = har_threshold(need(ddof), ddof, nu)
    i = lean.spec.names().index("axis_tilt_rad")
    var = float(lean.cov[i, i]) * max(1.0, lean.chi2 / dof)
    stated = "axis_tilt_rad" in dict(data.constraints.fixed)  # a lean the user measured: no error of its own
    wald = math.inf if stated else lean.values()["axis_tilt_rad"] ** 2 / var / ratio if var > 0 else 0.0
    return (gain > threshold and wald > threshold
            and bool(f_dist.sf(gain / ddof / (lean.chi2 / dof), ddof, dof) < TERM_P_VALUE))


def lean_kept(cur: Solution, data: FitData, notes: list[Note], need: Callable[[int], float]) -> Solution:
    """The final model ``cur`` with the lean where :func:`lean_wanted` wants it (``need``: the chi-square gain a term of
    so many parameters needs), noted; else without it.  ``cur`` holds the lean already (found on the slow model) or
    not (then it is tried: a small lean that the nod hid)."""
    if cur.spec.fit_axis:
        level = solve(replace(cur.spec, fit_axis=False, lean=False), data, cur.values(), near=True)
        lean, plain = cur, level
    else:
        lean, plain = leaned(cur, data), cur
    if lean is None or (plain.ok and not lean_wanted(plain, lean, data, need)):
        return plain
    v = lean.values()
    tilt, towards = v["axis_tilt_rad"], v["axis_azimuth_rad"] + (math.pi if v["axis_tilt_rad"] < 0 else 0.0)
    notes.append(Note(NoteKind.TERM_MODELLED, f"{LEAN_LABEL}: modelled, {math.degrees(abs(tilt)):.3g} deg towards "
                      f"azimuth {math.degrees(towards) % 360:.4g} deg", "lean"))
    return lean
