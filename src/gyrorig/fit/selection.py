"""Which terms a record's fit model gets: the nutation harmonics and the damped scenes' optional terms.

Terms are chosen in one of three ways (:class:`Selector`):

- by the data (default): a term is added when a chi-square test on the record wants it
  (p < :data:`TERM_P_VALUE`);
- on noiseless planning data: a term is kept when it changes the chi-square by more than a
  non-centrality (:data:`PLANNED_NONCENTRALITY`);
- planned in advance (:class:`~gyrorig.fit.spec.FitTerms`): the planned terms are kept whenever
  they converge; a term the plan left out is added only when the record needs it beyond what the
  plan expected (the p < :data:`TERM_P_VALUE` tail of the non-central chi-square with the plan's
  non-centrality) and it can be told apart from the planned model.

Terms with a free nonlinear parameter (the persistent oscillation's frequency, the transient's
rate) are screened first by their score statistic, the chi-square gain to first order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2, ncx2

from .data import FitConvergenceError, FitData, FitError
from .lean import lean_kept, lean_trial
from .model import FitModel, Residuals, SceneModel
from .result import NONLINEAR_PHASE_RAD, TERM_P_VALUE, Note, NoteKind, Reason, Undetermined
from .solver import (Solution, conditional_amplitudes, dominant_frequency, linear_harmonics, linear_start, mean_axis,
                     solve)
from .spec import FitTerms
from .terms import MAX_HARMONICS, OPTIONAL, OPTIONAL_TERMS, Persistent, RollingShutter, TipOffset, Transient
from .uncertainty import phase_uncertainty

__all__ = ["Selector", "fit_model", "trial_term", "score_term", "left_out_noncentrality", "plan_terms",
           "TERM_P_VALUE", "PLANNED_NONCENTRALITY"]

#: planning a model on noiseless simulated angles: a term is kept when it changes the chi-square
#: by more than this (its non-centrality: leaving it out could bias a quantity by up to
#: sqrt(this) standard errors)
PLANNED_NONCENTRALITY = 1.0
#: planning on noiseless data keeps a term with a free frequency (the persistent oscillation)
#: only above this chi-square change: below it, noisy records cannot locate the frequency
FREE_FREQUENCY_NONCENTRALITY = 25.0
#: a screened term whose first-order chi-square gain (score statistic) is below this fraction of
#: the threshold is not fitted (the score equals the fitted gain for a small term)
SCORE_SCREEN_FRACTION = 0.75
#: nutation counts as resolved by the camera below this fraction of the Nyquist frequency
NYQUIST_FRACTION = 0.9
#: an unplanned term that would widen the error of a parameter of the planned model by more than
#: this factor is not identifiable on the record: it is left out
DEGENERATE_SE_GROWTH = 5.0
#: at most this many nutation harmonics in a damped model (harmonic k decays k times as fast)
DAMPED_MAX_HARMONICS = 3


@dataclass(frozen=True)
class Selector:
    """How :func:`fit_model` decides whether to add a term."""

    #: terms planned in advance: kept whenever they converge
    terms: FitTerms | None = None
    #: noiseless data: keep a term whose chi-square change exceeds this (instead of the p-value test)
    noncentrality: float | None = None

    def need(self, ddof: int, flag: str = "", k: int = 0) -> float:
        """The chi-square change that adds a term of ``ddof`` parameters.

        On noisy data: the p < TERM_P_VALUE point of chi-square(ddof); for a term the plan left out
        although it changed the plan's noiseless chi-square by lambda, the same point of the
        non-central chi-square(ddof, lambda): a record adds it only when it needs the term more than
        the plan's own simulated motion does."""
        if self.noncentrality is not None:
            return self.noncentrality
        need = float(chi2.isf(TERM_P_VALUE, ddof))
        lam = 0.0
        if self.terms is not None and flag and (flag != "harmonics" or k == self.terms.harmonics + 1):
            lam = self.terms.noncentrality(flag)
        return max(need, float(ncx2.isf(TERM_P_VALUE, ddof, lam))) if lam > 0 else need

    def planned(self, flag: str, k: int = 0) -> bool:
        return self.terms is not None and self.terms.has(flag, k)

    def wants(self, ref: Solution, sol: Solution, flag: str, notes: list[Note], label: str, k: int = 0) -> bool:
        """Keep ``sol`` (``ref`` plus a term)?  Planned terms stay if they converge; others by the test."""
        planned = self.planned(flag, k)
        if not sol.ok:
            if planned:
                notes.append(Note(NoteKind.PLANNED_TERM_FAILED, f"the planned term ({label}) did not converge and is "
                                  f"left out: {sol.message}", flag))
            return False
        if planned:
            return True
        if ref.chi2 - sol.chi2 > self.need(ref.dof - sol.dof, flag, k):
            if self.terms is not None:
                grown = _degenerate_growth(ref, sol)
                if grown is not None:
                    notes.append(Note(NoteKind.TERM_NOT_IDENTIFIABLE, f"the data ask for a term the plan did not have "
                                      f"({label}), but on this record it cannot be told apart from the planned model "
                                      f"(the error of {grown[0]} would grow {grown[1]:.3g}x): it is left out", flag))
                    return False
                notes.append(Note(NoteKind.TERM_BEYOND_PLAN, f"the data need a term the plan did not have ({label}): it "
                                  "is added", flag))
            return True
        return False


def _degenerate_growth(ref: Solution, sol: Solution) -> tuple[str, float] | None:
    """The parameter of ``ref`` whose standard error grows most in ``sol`` (``ref`` plus a term), with
    the factor, when that exceeds :data:`DEGENERATE_SE_GROWTH`; else None."""
    names_ref, names_sol = ref.spec.names(), FitModel(sol.spec).index
    worst = (None, 1.0)
    for i, n in enumerate(names_ref):
        j = names_sol.get(n)
        if j is None or not ref.cov[i, i] > 0:
            continue
        g = math.sqrt(max(sol.cov[j, j], 0.0) / ref.cov[i, i])
        if g > worst[1]:
            worst = (n, g)
    return worst if worst[0] is not None and worst[1] > DEGENERATE_SE_GROWTH else None


def _nutation_unresolvable(data: FitData, hint: float | None) -> Reason | None:
    """Why the camera or the record cannot show the predicted nutation (None if they can)."""
    if hint is None:
        return None
    nyq = data.nyquist_rad_s
    if hint > NYQUIST_FRACTION * nyq:
        return Reason(Undetermined.CAMERA_TOO_SLOW,
                      f"the camera cannot resolve the nutation: predicted {hint / (2 * np.pi):.3g} Hz, frame rate "
                      f"{nyq / np.pi:.3g} fps (Nyquist {nyq / (2 * np.pi):.3g} Hz)")
    periods = data.duration_s * hint / (2 * np.pi)
    if periods < 2:
        return Reason(Undetermined.TOO_FEW_PERIODS,
                      f"the record covers {periods:.2g} predicted nutation periods; at least 2 are needed")
    # across a gap of more than half a period the cycles cannot be counted: some stretch without one must
    # show the periods itself
    period = 2 * np.pi / hint
    run = data.longest_run_s(0.5 * period)
    if run / period < 2:
        return Reason(Undetermined.TOO_FEW_PERIODS,
                      f"the longest stretch without a gap of half a nutation period covers {run / period:.2g} "
                      "predicted periods; at least 2 are needed (the record has gaps)")
    return None


def _with_nutation(base: Solution, data: FitData, scene: SceneModel, sel: Selector, notes: list[Note],
                   max_harmonics: int) -> tuple[Solution | None, Reason | None]:
    """The slow model ``base`` plus as many nutation harmonics as the selector keeps (None and the reason
    when it keeps none)."""
    spec0 = base.spec
    nyq = data.nyquist_rad_s
    model0 = FitModel(spec0)
    p0 = model0.values(base.x)
    th0, _ = model0.axis_frame(base.x, data.tau, data.segment)
    th_obs, _ = model0.in_axis_frame(base.x, data)
    w0 = dominant_frequency(data.t_s, th_obs - th0, NYQUIST_FRACTION * nyq, scene.nutation_frequency_hint_rad_s,
                            window=not spec0.damped)
    start = dict(p0, nutation_frequency_rad_s=w0)
    if spec0.damped:
        start["nutation_decay_rate_per_s"] = 0.0
    cur, reason = None, None
    k_max = min(max_harmonics, DAMPED_MAX_HARMONICS) if spec0.damped else max_harmonics
    for k in range(1, k_max + 1):
        if k * w0 > nyq:
            notes.append(Note(NoteKind.HARMONIC_ABOVE_NYQUIST,
                              f"harmonic {k} of the nutation is above the Nyquist frequency; not modelled", "harmonics"))
            break
        spec_k = replace(spec0 if cur is None else cur.spec, harmonics=k)
        sol = solve(spec_k, data, linear_harmonics(spec_k, data, start))
        ref = cur if cur is not None else base
        if not sel.wants(ref, sol, "harmonics", notes, f"nutation harmonic {k}", k):
            if cur is None and not sol.ok:
                reason = Reason(Undetermined.NOT_CONVERGED, f"the fit with nutation did not converge: {sol.message}")
            elif cur is None:
                dchi, ddof = ref.chi2 - sol.chi2, ref.dof - sol.dof
                reason = Reason(Undetermined.NOT_SIGNIFICANT,
                                f"no significant nutation in the data (chi-square improves by {dchi:.3g} for "
                                f"{ddof} more parameters; {sel.need(ddof):.3g} needed)")
            break
        # a rolling shutter's readout is fitted once the nod is in: the slow model alone leaves the nod as residual,
        # which a readout far beyond any shutter's can warp into
        cur = _with_readout(sol, data)
        start = cur.values()
    if cur is not None:
        w_fit = cur.values()["nutation_frequency_rad_s"]
        if not 0 < w_fit < nyq:
            return None, Reason(Undetermined.OUT_OF_BAND, "the fit did not settle on a nutation frequency inside "
                                f"(0, Nyquist): {w_fit:.4g} rad/s")
    return cur, reason


def fit_model(data: FitData, scene: SceneModel, max_harmonics: int = MAX_HARMONICS, *,
              terms: FitTerms | None = None, noncentrality: float | None = None
              ) -> tuple[Solution, list[Note], dict[str, Reason]]:
    """Fit the scene's model, with its optional terms (nutation harmonics, and under damping the
    terms of :data:`gyrorig.fit.terms.OPTIONAL`) chosen in this order.

    Parameters
    ----------
    terms : FitTerms, optional
        Terms planned in advance (:func:`plan_terms`): each is kept whenever it converges.  A
        term not in the plan is still added when the data's chi-square test wants it (noted).
        Without ``terms`` every term is chosen by that test (p < :data:`TERM_P_VALUE`).
    noncentrality : float, optional
        For noiseless data (planning): a term is kept when it lowers the chi-square by more
        than this, instead of by the p-value test.

    Returns the solution, notes, and the reason for each quantity that cannot be determined.
    """
    sel = Selector(terms=terms, noncentrality=noncentrality)
    spec0 = replace(scene.spec, harmonics=0, segments=int(data.segment.max()) + 1, camera_modes=data.camera_modes,
                    b_frames=data.b_frames, rolling_shutter=False,
                    nutation_origin_s=float(data.t_s[0] - data.t_ref_s) if scene.spec.damped else 0.0)
    notes = [Note(NoteKind.SCENE, r) for r in scene.reasons]
    undetermined: dict[str, Reason] = {}
    if spec0.segments > 1:
        gaps = np.diff(data.t_s)[np.diff(data.segment) > 0]
        notes.append(Note(NoteKind.AZIMUTH_SEGMENTS,
                          f"{len(gaps)} gap(s) longer than half a precession period ({', '.join(f'{g:.3g} s' for g in gaps)}) "
                          f"split the azimuth into {spec0.segments} segments with their own offsets: the turns made in "
                          "a gap are not counted, and the precession rate comes from within the segments"))
    base = solve(spec0, data, linear_start(spec0, data, mean_axis(data) if spec0.fit_axis else None))
    if not base.ok and not (scene.nutation_expected and np.all(np.isfinite(base.x))):
        raise FitConvergenceError(f"the fit did not converge: {base.message}")
    # without the nutation the slow model may find no clean minimum over a short record (the residual is
    # the nutation itself): it is only the start of the full model, which must converge
    best = base
    if scene.nutation_expected:
        unresolvable = _nutation_unresolvable(data, scene.nutation_frequency_hint_rad_s)
        paths = [_nutation_path(start, data, scene, sel, max_harmonics, unresolvable)
                 for start in (base, lean_trial(base, data)) if start is not None]
        best, path_notes, reason = _chosen_path(paths, sel)
        notes += path_notes
        if spec0.damped:
            best = _with_optional_terms(best, data, notes, sel)
        elif OPTIONAL["tip_offset"].can_add(best.spec):
            best = _consider_term(best, data, notes, sel, "tip_offset")
        if reason is not None:
            undetermined["nutation_frequency_rad_s"] = reason
            undetermined["nutation_amplitude_rad"] = reason
    else:
        best = _with_readout(best, data)
    if not best.ok:
        raise FitConvergenceError(f"the fit did not converge: {best.message}")
    return best, notes, undetermined


def _with_readout(cur: Solution, data: FitData) -> Solution:
    """``cur`` with a rolling shutter's readout time fitted (:class:`~gyrorig.fit.terms.RollingShutter`), started
    from 0 at ``cur``'s solution, where the data's frames lack their rows' delay and ``cur`` has no readout yet; else
    ``cur``."""
    if not data.rolling_shutter or cur.spec.rolling_shutter:
        return cur
    spec_x = replace(cur.spec, rolling_shutter=True)
    return solve(spec_x, data, {**cur.values(), RollingShutter.NAME: 0.0}, near=True)


def _nutation_path(start: Solution, data: FitData, scene: SceneModel, sel: Selector, max_harmonics: int,
                   reason: Reason | None) -> tuple[Solution, list[Note], Reason | None]:
    """The nod's harmonics chosen from the slow model ``start`` (unless ``reason`` says the record cannot resolve
    it), then the lean tested on the result (:func:`~gyrorig.fit.lean.lean_kept`) where the scene's vertical is
    known: the solution, its notes, and why the nod is undetermined (None: it is not)."""
    notes: list[Note] = []
    best = start
    if reason is None:
        cur, reason = _with_nutation(start, data, scene, sel, notes, max_harmonics)
        best = cur if cur is not None else start
    best = _with_readout(best, data)
    if not scene.spec.fit_axis:
        best = lean_kept(best, data, notes, sel.need)
    return best, notes, reason


def _chosen_path(paths: list, sel: Selector) -> tuple[Solution, list[Note], Reason | None]:
    """The first of :func:`_nutation_path`'s outcomes (from the slow model about the vertical) unless the second
    (from the slow model with a lean) ends with its lean and a chi-square lower by more than its extra parameters
    need (:meth:`Selector.need`)."""
    plain = paths[0]
    if len(paths) < 2 or not paths[1][0].spec.lean:
        return plain
    lean, ref = paths[1][0], plain[0]
    extra = ref.dof - lean.dof
    wins = lean.ok and (ref.chi2 - lean.chi2 > sel.need(extra) if extra > 0 else lean.chi2 < ref.chi2)
    return paths[1] if wins or not ref.ok else plain


def _with_optional_terms(best: Solution, data: FitData, notes: list[Note], sel: Selector) -> Solution:
    """A damped model's optional terms (:data:`OPTIONAL_TERMS`), each kept as the selector decides.

    Chosen by the data (or on noiseless planning data), they are tried in order, each against
    the model so far, and a persistent oscillation is dropped again at the end if the later
    terms leave it little to do.  With planned terms, the planned model is built first; then
    each term the plan left out is tried against the whole planned model (not against a part
    of it, where it could stand in for a planned term that is not yet in), with the threshold
    of :meth:`Selector.need`.
    """
    rounds = [OPTIONAL_TERMS] if sel.terms is None else [
        [f for f in OPTIONAL_TERMS if sel.planned(f)], [f for f in OPTIONAL_TERMS if not sel.planned(f)]]
    for flags in rounds:
        for flag in flags:
            if OPTIONAL[flag].can_add(best.spec):
                best = _consider_term(best, data, notes, sel, flag)
    return _prune_persistent(best, data, notes, sel)


#: a tip marker off the axis is looked for only in a record over which the frame turns this far about the axis (a
#: whole turn: less, and its circle stands in for a change of the cone and the precession rate)
TIP_OFFSET_MIN_TURN_RAD = 2 * math.pi


def frame_turn_rate(cur: Solution) -> float:
    """How fast a gyrostat's frame turns about the axis by ``cur``'s slow motion: its spin less the precession's share
    along the axis [rad/s]."""
    v = cur.values()
    return cur.spec.frame_spin_rad_s - math.cos(math.exp(v["log_cone_angle"])) * v["precession_rate_rad_s"]


def _turns_with_the_frame(sol: Solution) -> bool:
    """Whether a fitted tip offset's circle turns at the frame's rate rather than the precession's: a cone whose axis
    leans from the vertical (a table not level, a pose stated wrong) makes a circle at the precession's own rate,
    ``1 / cos(theta_c)`` of the frame's; the fitted rate must be nearer the frame's, the two told apart by 4 of its
    standard errors."""
    v = sol.values()
    frame = frame_turn_rate(sol)
    precession = sol.spec.frame_spin_rad_s - v["precession_rate_rad_s"]
    i = sol.spec.names().index(TipOffset.RATE)
    se = math.sqrt(max(float(sol.cov[i, i]), 0.0))
    gap = abs(frame - precession)
    return gap > 4 * se and abs(v[TipOffset.RATE] - frame) < 0.5 * gap


def _consider_term(cur: Solution, data: FitData, notes: list[Note], sel: Selector, flag: str) -> Solution:
    """``cur`` with the optional term ``flag`` if the selector wants it, else ``cur``."""
    if flag == "tip_offset" and abs(frame_turn_rate(cur)) * data.duration_s < TIP_OFFSET_MIN_TURN_RAD:
        return cur
    start = None
    if flag in _SCREENED and not sel.planned(flag) and cur.ok:
        # a term with a free frequency or rate makes the full trial slow (where its amplitude is ~0
        # the solver creeps along it); its score statistic approximates the chi-square gain to first
        # order, and a term far below the threshold is not tried
        start, score = score_term(cur, data, flag)
        if score < SCORE_SCREEN_FRACTION * sel.need(_SCREENED[flag][1], flag):
            return cur
    sol, label = trial_term(cur, data, flag, start if flag == "persistent" else None)
    if flag == "persistent" and _persistent_unresolved(sol, data, sel):
        return cur
    if flag == "tip_offset" and not (sol.ok and _turns_with_the_frame(sol)):
        return cur
    if sel.wants(cur, sol, flag, notes, label):
        notes.append(Note(NoteKind.TERM_MODELLED, f"{label}: modelled", flag))
        return sol
    return cur


def trial_term(cur: Solution, data: FitData, flag: str, start: float | None = None) -> tuple[Solution, str]:
    """The fit of ``cur``'s model plus the optional term ``flag`` (or the next nutation harmonic,
    ``"harmonics"``), started from ``cur``'s solution; and the term's description.

    ``start``: the persistent oscillation's start frequency (default: from its score statistic).
    """
    if flag == "persistent":
        w = start if start is not None else score_term(cur, data, "persistent")[0]
        return _trial_persistent(cur, data, w), Persistent.description
    if flag == "transient":
        return _trial_transient(cur, data)
    spec_x = replace(cur.spec, harmonics=cur.spec.harmonics + 1) if flag == "harmonics" else \
        replace(cur.spec, **{flag: True})
    old = FitModel(cur.spec).index
    new = [n for n in spec_x.names() if n not in old]
    values = cur.values()
    if flag == "tip_offset":  # its turning rate started from the slow motion's, its amplitudes solved there
        values[TipOffset.RATE] = frame_turn_rate(cur)
        new = list(TipOffset.NAMES)
    st, _ = conditional_amplitudes(spec_x, data, values, new)
    label = f"nutation harmonic {spec_x.harmonics}" if flag == "harmonics" else OPTIONAL[flag].description
    return solve(spec_x, data, st, near=True), label


def _score_over_grid(cur: Solution, data: FitData, spec_x, amplitudes: Sequence[str], knob: str,
                     grid: np.ndarray) -> tuple[float, float]:
    """Score (Lagrange-multiplier) statistic of a new term whose ``amplitudes`` enter linearly,
    for each value of its nonlinear parameter ``knob`` on ``grid``; returns the best value and its
    score.

    For each value the score is ``g^T M^-1 g`` with ``g = A^T r`` and ``M = A^T (1 - P_J) A``,
    ``A`` the amplitudes' whitened columns, ``P_J`` the projection on ``cur``'s Jacobian, ``r``
    its residuals: the chi-square gain to first order with every parameter of ``cur`` free.  It
    equals the fitted gain for a small term and needs no nonlinear fit.  Directions of the term
    that the model already spans (to 1e-6 of the columns' size) can gain nothing and are dropped.
    """
    white = Residuals(FitModel(cur.spec), data)
    r = white(cur.x)
    Q, _ = np.linalg.qr(white.jac(cur.x))
    r = r - Q @ (Q.T @ r)
    model_x = FitModel(spec_x)
    white_x = Residuals(model_x, data)
    p_cur = cur.values()
    cols = [model_x.index[k] for k in amplitudes]
    best = (float(grid[0]), -math.inf)
    for v in grid:
        x = model_x.vector(p_cur)
        x[model_x.index[knob]] = v
        A0 = white_x.jac(x)[:, cols]
        norms = np.linalg.norm(A0, axis=0)
        norms[norms == 0] = 1.0
        A = A0 - Q @ (Q.T @ A0)
        U, sv, _ = np.linalg.svd(A / norms, full_matrices=False)
        keep = sv > 1e-6
        score = float(np.sum((U[:, keep].T @ r) ** 2))
        if score > best[1]:
            best = (float(v), score)
    return best


def _persistent_score(cur: Solution, data: FitData) -> tuple[float, float]:
    """The frequency near the nutation (within 3 frequency bins ``2 pi / T``, on a grid of 0.1 bin) at
    which a persistent oscillation would lower the chi-square of ``cur`` most, and that drop to first order."""
    w_n = float(cur.values()["nutation_frequency_rad_s"])
    bin_w = 2 * np.pi / data.duration_s
    grid = np.array([w_n + dw for dw in np.arange(-3.0, 3.0001, 0.1) * bin_w if abs(dw) > 1e-9])
    return _score_over_grid(cur, data, replace(cur.spec, persistent=True), Persistent.AMPLITUDES,
                            "persistent_frequency_rad_s", grid)


def _transient_spec(cur: Solution, data: FitData):
    """``cur``'s model plus the fast transient, its rate bounded to what the record can see: at
    least 10 e-folds per record (so that it cannot stand in for the slow terms), at most 3 per frame."""
    floor = 10.0 / data.duration_s
    dt = float(np.median(np.diff(data.t_s)))
    cap = max(3.0 / dt, 2 * floor)
    return replace(cur.spec, transient=True, transient_min_rate_per_s=floor, transient_max_rate_per_s=cap)


def _transient_logit(spec_t, rate_per_s: float) -> float:
    lo, hi = spec_t.transient_min_rate_per_s, spec_t.transient_max_rate_per_s
    frac = (rate_per_s - lo) / (hi - lo)
    return math.log(frac / (1 - frac))


def _transient_score(cur: Solution, data: FitData) -> tuple[float, float]:
    """The transient's rate logit (over 48 rates spanning its range) at which it would lower the
    chi-square of ``cur`` most, and that drop to first order."""
    spec_t = _transient_spec(cur, data)
    lo, hi = spec_t.transient_min_rate_per_s, spec_t.transient_max_rate_per_s
    grid = np.array([_transient_logit(spec_t, k) for k in np.geomspace(1.02 * lo, 0.98 * hi, 48)])
    return _score_over_grid(cur, data, spec_t, Transient.AMPLITUDES, "transient_rate_logit", grid)


def _tip_offset_score(cur: Solution, data: FitData) -> tuple[float, float]:
    """What a tip marker off the axis (:class:`~gyrorig.fit.terms.TipOffset`) would lower the chi-square of ``cur`` by,
    to first order (its amplitudes are linear: one point, no grid)."""
    return _score_over_grid(cur, data, replace(cur.spec, tip_offset=True), TipOffset.NAMES, TipOffset.RATE,
                            np.array([frame_turn_rate(cur)]))


#: optional terms screened by their score statistic before a trial fit (those with a free nonlinear parameter, and
#: the tip's offset, tried on every gyrostat's record): (score function, number of parameters the term adds)
_SCREENED = {"persistent": (_persistent_score, 5), "transient": (_transient_score, 3),
             "tip_offset": (_tip_offset_score, 2)}


def score_term(cur: Solution, data: FitData, flag: str) -> tuple[float, float]:
    """For a screened term (``"persistent"``, ``"transient"``): the value of its nonlinear parameter at
    which it would lower the chi-square of ``cur`` most (the frequency [rad/s], or the rate's logit),
    and that chi-square drop to first order (its score statistic)."""
    if flag not in _SCREENED:
        raise ValueError(f"score_term: {flag!r} has no score screen; allowed: {', '.join(_SCREENED)}")
    return _SCREENED[flag][0](cur, data)


def _trial_persistent(cur: Solution, data: FitData, w_start: float | None = None) -> Solution:
    """Add a persistent oscillation near the nutation frequency, started at ``w_start`` or else one
    frequency bin either side of the nutation."""
    p_cur = cur.values()
    w_n = p_cur["nutation_frequency_rad_s"]
    spec_p = replace(cur.spec, persistent=True)
    amps = list(Persistent.AMPLITUDES)
    starts = [w_start] if w_start is not None else [w_n + 2 * np.pi / data.duration_s,
                                                    w_n - 2 * np.pi / data.duration_s]
    trial = []
    for w in starts:
        st = dict(p_cur, persistent_frequency_rad_s=w, **{k: 0.0 for k in amps})
        st, _ = conditional_amplitudes(spec_p, data, st, amps)
        trial.append(solve(spec_p, data, st, near=True))
    ok = [s_ for s_ in trial if s_.ok] or trial
    return min(ok, key=lambda s_: s_.chi2)


def _persistent_unresolved(sol: Solution, data: FitData, sel: Selector) -> bool:
    """A persistent oscillation (not planned) whose frequency this record does not resolve."""
    if not sol.spec.persistent or sel.planned("persistent") or not sol.ok:
        return False
    return phase_uncertainty(sol.spec, sol.x, sol.cov, data)["persistent_frequency_rad_s"] > NONLINEAR_PHASE_RAD


def _prune_persistent(best: Solution, data: FitData, notes: list[Note], sel: Selector) -> Solution:
    """Take the persistent oscillation out again when, with the terms added after it, the record
    no longer resolves its frequency or no longer needs it (it was tried before the transient
    and the axis terms, and can stand in for them).  A free frequency needs a clear detection
    to be estimable: on noiseless planning data at least :data:`FREE_FREQUENCY_NONCENTRALITY`."""
    if not best.spec.persistent or sel.planned("persistent") or not best.ok:
        return best
    sol = solve(replace(best.spec, persistent=False), data, best.values(), near=True)
    if not sol.ok:
        return best
    gain, ddof = sol.chi2 - best.chi2, sol.dof - best.dof
    need = sel.need(ddof, "persistent")
    if sel.noncentrality is not None:
        need = max(need, FREE_FREQUENCY_NONCENTRALITY)
    unresolved = _persistent_unresolved(best, data, sel)
    if not unresolved and gain > need:
        return best
    notes[:] = [n for n in notes if not (n.term == "persistent" and
                                         n.kind in (NoteKind.TERM_MODELLED, NoteKind.TERM_BEYOND_PLAN))]
    why = ("the record does not resolve its frequency" if unresolved else
           f"the other terms leave it little to do (chi-square {gain:+.3g} without it; {need:.3g} needed)")
    notes.append(Note(NoteKind.TERM_LEFT_OUT, f"{Persistent.description} is left out: {why}", "persistent"))
    return sol


def _trial_transient(cur: Solution, data: FitData) -> tuple[Solution, str]:
    """Add a fast exponential transient from the first frame; the rates tried span what a frame rate
    can see (at least 10 e-folds per record, at most 3 per frame)."""
    p_cur = cur.values()
    spec_t = _transient_spec(cur, data)
    floor, cap = spec_t.transient_min_rate_per_s, spec_t.transient_max_rate_per_s
    # the amplitudes are linear: solve them for a ladder of rates, start from the best rate
    best_start, best_chi2 = None, math.inf
    for kappa in np.geomspace(1.05 * floor, 0.95 * cap, 16):
        st = dict(p_cur, transient_rate_logit=_transient_logit(spec_t, kappa), transient_tilt_rad=0.0,
                  transient_azimuth_rad=0.0)
        st, c2 = conditional_amplitudes(spec_t, data, st, list(Transient.AMPLITUDES))
        if c2 < best_chi2:
            best_start, best_chi2 = st, c2
    return (solve(spec_t, data, best_start, near=True),
            f"{Transient.description} (decaying faster than {floor:.3g} 1/s)")


def left_out_noncentrality(sol: Solution, data: FitData) -> dict[str, float]:
    """For a model chosen on noiseless data: the chi-square change each term it left out would make
    (the next nutation harmonic, and in a damped model the optional terms; for the screened terms
    the first-order change, their score statistics).  A noisy record of the scene shows these
    terms with that non-centrality; see :meth:`Selector.need`."""
    out = {}
    spec = sol.spec
    if spec.harmonics and spec.harmonics < (DAMPED_MAX_HARMONICS if spec.damped else MAX_HARMONICS) and \
            (spec.harmonics + 1) * sol.values()["nutation_frequency_rad_s"] < data.nyquist_rad_s:
        trial, _ = trial_term(sol, data, "harmonics")
        if trial.ok:
            out["harmonics"] = max(sol.chi2 - trial.chi2, 0.0)
    if spec.damped:
        for flag, term in OPTIONAL.items():
            if not term.can_add(spec):
                continue
            if flag in _SCREENED:
                out[flag] = max(score_term(sol, data, flag)[1], 0.0)
                continue
            trial, _ = trial_term(sol, data, flag)
            if trial.ok:
                out[flag] = max(sol.chi2 - trial.chi2, 0.0)
    return out


def plan_terms(data: FitData, scene: SceneModel, source: str = "") -> FitTerms:
    """The model terms that noiseless angles ``data`` (with the per-frame errors real data will
    have) call for: each term is kept when it changes the chi-square by more than
    :data:`PLANNED_NONCENTRALITY`, i.e. when leaving it out could bias a fitted quantity by a
    sizeable fraction of its standard error."""
    d = replace(data, camera_shift=None)
    sol, _, _ = fit_model(d, scene, noncentrality=PLANNED_NONCENTRALITY)
    return FitTerms.of(sol.spec, source, left_out_noncentrality(sol, d))
