"""Least-squares fits of tracked angles against the scene's motion, compared with theory.

**Data.**  The fit uses the *tracked* angles with the tracker's per-frame 2x2 covariance
(``theta_sigma_rad, phi_sigma_rad, theta_phi_corr``), not the smoothed ones (smoothing
correlates neighbouring samples, which would make the least-squares errors wrong).  Frames the
smoother gated out as outliers are left out.

Modules, like lmfit's Model / Parameters / MinimizerResult:

* :mod:`~gyrorig.fit.terms`: one class per model term (parameters, value, Jacobian, when it applies);
* :mod:`~gyrorig.fit.spec`: which terms a model has (:class:`ModelSpec`), terms fixed in advance (:class:`FitTerms`);
* :mod:`~gyrorig.fit.data`: the measured frames (:class:`FitData`);
* :mod:`~gyrorig.fit.constraints`: parameters held fixed or given priors (:class:`Constraints`);
* :mod:`~gyrorig.fit.model`: the scene's model (:func:`model_for_scene`), its evaluation in the lab
  (:class:`FitModel`) and its whitened residuals (:class:`Residuals`);
* :mod:`~gyrorig.fit.solver`: the least-squares solution (:class:`Solution`) and start values;
* :mod:`~gyrorig.fit.selection`: which terms a record gets (chi-square tests, planned terms, score screens);
* :mod:`~gyrorig.fit.uncertainty`: the delta method, residual checks, bootstrap, the camera's share;
* :mod:`~gyrorig.fit.quantities`: the fitted quantities with theory and truth beside them;
* :mod:`~gyrorig.fit.result`: :class:`Quantity`, :class:`FitResult`, outcomes as enums and :class:`Note` records;
* :mod:`~gyrorig.fit.fitting`: :func:`fit_angles`, :func:`linear_response`.

One quantity the data cannot determine is reported as undetermined with the reason, never as
a number.
"""

from .constraints import Constraints, constrainable_names
from .data import FIT_REQUIRED, FitConvergenceError, FitData, FitError, fit_data_from_angles
from .fitting import STATE_NAMES, TERM_CHOICES, fit_angles, linear_response, record_state, state_values
from .model import FitModel, Residuals, SceneModel, model_for_scene
from .result import (NONLINEAR_PHASE_RAD, QUANTITY_UNITS, ErrorKind, FitResult, MotionBreak, Note, NoteKind, Quantity,
                     QuantityStatus, Undetermined)
from .selection import (PLANNED_NONCENTRALITY, TERM_P_VALUE, Selector, fit_model, left_out_noncentrality, plan_terms,
                        score_term, trial_term)
from .solver import Solution, solve
from .spec import FitTerms, ModelSpec
from .terms import MAX_HARMONICS, OPTIONAL_TERMS
from .uncertainty import phase_uncertainty

__all__ = ["Constraints", "constrainable_names", "FitError", "FitConvergenceError", "ModelSpec", "FitTerms", "Quantity", "FitResult", "FitData", "FitModel", "Residuals",
           "SceneModel", "Solution", "Selector", "model_for_scene", "fit_data_from_angles", "fit_angles", "fit_model",
           "solve", "plan_terms", "phase_uncertainty", "left_out_noncentrality", "linear_response", "score_term",
           "trial_term", "ErrorKind", "MotionBreak", "Note", "NoteKind", "QuantityStatus", "Undetermined",
           "OPTIONAL_TERMS", "QUANTITY_UNITS", "MAX_HARMONICS", "NONLINEAR_PHASE_RAD", "PLANNED_NONCENTRALITY", "TERM_P_VALUE",
           "TERM_CHOICES", "FIT_REQUIRED", "record_state", "state_values", "STATE_NAMES"]
