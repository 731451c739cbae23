"""Error bars checked on the record itself: the tip's frame-to-frame scatter about its smooth path.

The tip's image moves smoothly: over seven consecutive frames a polynomial of degree 5 through six
of them predicts the seventh to far below the noise (the residual of a sinusoid of ``omega dt``
per frame is ``(2 sin(omega dt / 2))^6 / 20`` of its amplitude: 1e-4 at 0.25 rad per frame).  So each
frame's leave-one-out residual ``r`` about the path of its six nearest neighbours has the variance
``sigma_0^2 + sum c_j^2 sigma_j^2`` (``c_j`` the interpolation weights, ``sigma`` the per-frame errors
the tracker reports), if those errors are right.  :func:`check_sigmas` compares: the RMS of
``r / sqrt(that)`` over the record is the factor by which the reported errors are off, known to about
``1 / sqrt(2 N)`` from ``N`` checked coordinates; single frames far off the path (more than
:data:`OUTLIER_Z` of their scaled error: the record's median residual, or their stretch's where that is larger)
are outliers: a position that is not the tip's, or one that light from another marker pulled away.  A stretch of
the record whose errors fall short by more than the rest's is not a run of outliers: it is widened
(:func:`local_factors`).

Beside the factors the check can solve an error common to every frame (a lossy codec's floor) and one common to
the frames of each group (a codec's run of B pictures), and it says when the path cannot follow the motion at all
(the residuals then correlated from frame to frame as a motion, not as noise: a frame rate too low for it).

This needs no model of the sensor or of the spot: it is how the tracker's errors are made honest
for footage whose sensor response is unknown (no gain, gamma, a lossy codec) or whose marker has no
exact model, and how they are checked otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import median_filter
from scipy.optimize import lsq_linear
from scipy.signal import lombscargle
from scipy.stats import chi2

__all__ = ["SigmaCheck", "check_sigmas", "b_picture_runs", "path_residuals", "neighbour_positions", "motion_frequency",
           "local_factors", "check_summary", "OUTLIER_Z", "HALF_WINDOW", "MAX_SPAN", "NOISE_ACF", "LOCAL_FRAMES"]

#: neighbours on each side that predict a frame
HALF_WINDOW = 3
#: the most frames the seven frames of a check may span (a gap of up to four frames inside)
MAX_SPAN = 2 * HALF_WINDOW + 4
#: a frame whose residual exceeds this many of its (scaled) standard deviations is an outlier
OUTLIER_Z = 5.0
#: a path that leaves more than this share of the checked frames off it does not follow the motion (a frame rate
#: too low for it: the frames near each turn of the path off it together), whatever its residuals' correlations say
MAX_OUTLIER_SHARE = 0.1
#: the most times the outliers are looked for again with the errors the variance model found, and the model solved
#: again without them (:func:`check_sigmas` with ``floor``)
MAX_RESEARCH_PASSES = 3


#: the scatter is also compared with the errors over each stretch of this many checked frames (:func:`local_factors`)
LOCAL_FRAMES = 40

#: the residuals' correlations from frame to frame are compared at lags 1 to this
ACF_LAGS = 4


def _noise_acf() -> np.ndarray:
    """The correlation of residuals ``k = 1 ..`` :data:`ACF_LAGS` frames apart when they hold only noise, independent
    and alike from frame to frame, on a uniform grid: ``sum_j c_j c_(j+k) / sum_j c_j^2`` of the stencil's weights
    (-0.857, 0.536, -0.238, 0.071)."""
    n = 2 * HALF_WINDOW + 1
    _, _, w = _stencils(np.arange(n, dtype=float), np.arange(n), np.ones(n, bool))  # the one stencil of n frames
    c = np.r_[-w[0, :HALF_WINDOW], 1.0, -w[0, HALF_WINDOW:]]
    return np.array([np.sum(c[:-k] * c[k:]) for k in range(1, ACF_LAGS + 1)]) / np.sum(c * c)


#: how far the correlations may depart from :data:`NOISE_ACF` before it counts: noise correlated from frame to frame
#: (a P-picture chain's, AR(1) 0.6-0.85) moves them by up to 0.06; a share ``s`` of the residuals' variance from the
#: tip's own motion moves them by ``s`` times the difference from the motion's (``cos k omega`` for a nod of
#: ``omega`` per frame), so 0.1 lets through up to about 5-10 % of it
ACF_TOLERANCE = 0.1
#: the path is taken as not following the motion when the correlations' departures beyond the tolerance are this
#: unlikely for noise (chi-square with :data:`ACF_LAGS` degrees of freedom, Bartlett's variance of each)
ACF_TAIL = 1e-4


@dataclass(frozen=True)
class SigmaCheck:
    """The outcome of :func:`check_sigmas`.

    ``factor``: RMS of the normalised residuals (1: the errors are right; 2: they are half the scatter),
    ``factor_se`` its standard error, ``coordinates`` how many residuals entered (two per checked
    frame), ``outliers`` the indices (into the arrays given) of frames off the path, ``applied`` whether
    the tracker scaled its errors by ``factor``, ``reason`` why (or why not)."""

    factor: float
    factor_se: float
    coordinates: int
    outliers: tuple[int, ...]
    #: the same per class of frame (e.g. ``blended`` and the rest): ``{class: (factor, factor_se, coordinates)}``
    by_class: dict = field(default_factory=dict)
    applied: bool = False
    #: the factor each class's errors were multiplied by
    applied_factors: dict = field(default_factory=dict)
    reason: str = ""
    #: an error the same for every frame, independent from frame to frame, beside the reported ones (per axis) [px],
    #: and its standard error; 0 when not looked for
    floor_px: float = 0.0
    floor_px_se: float = 0.0
    #: the correlations of checked frames' residuals 1 .. :data:`ACF_LAGS` frames apart (empty when too few frames are
    #: neighbours), and whether they say that the residuals hold noise (:data:`NOISE_ACF`): where the tip moves too far
    #: between frames for the path to follow it (a low frame rate for the motion) the residuals hold the motion, and
    #: the check says nothing of the errors
    residual_acf: tuple = ()
    smooth_path: bool = True
    #: an error common to the frames of each group (``check_sigmas``' ``groups``), independent from group to group
    #: (per axis) [px], and its standard error; 0 when not looked for
    shared_px: float = 0.0
    shared_px_se: float = 0.0
    #: the angular frequency of the sinusoid in the path's basis (:func:`motion_frequency`) [rad/s]; NaN: the
    #: polynomial path
    omega_rad_s: float = math.nan
    #: frames whose errors were widened further by their stretch's own scatter (:func:`local_factors`), and the
    #: largest such factor
    local_frames: int = 0
    local_max_factor: float = 1.0
    #: frames whose errors were widened after the check by a second view of the scene under the tip's edge
    #: (:func:`~gyrorig.tracking.scene_spot.near_ring_move`)
    scene_frames: int = 0
    #: frames of the record's still ends (the top held before its release, caught at the end:
    #: :mod:`gyrorig.stillness`) left out of the check
    still_frames: int = 0

    def as_dict(self) -> dict:
        return {"factor": self.factor, "factor_se": self.factor_se, "coordinates": self.coordinates,
                "outliers": len(self.outliers),
                "by_class": {k: {"factor": f, "factor_se": se, "coordinates": n}
                             for k, (f, se, n) in self.by_class.items()},
                "applied": self.applied, "applied_factors": self.applied_factors, "reason": self.reason,
                "floor_px": self.floor_px, "floor_px_se": self.floor_px_se,
                "residual_acf": list(self.residual_acf), "smooth_path": self.smooth_path,
                "shared_px": self.shared_px, "shared_px_se": self.shared_px_se,
                "omega_rad_s": None if math.isnan(self.omega_rad_s) else self.omega_rad_s,
                "local_frames": self.local_frames, "local_max_factor": self.local_max_factor,
                "scene_frames": self.scene_frames, "still_frames": self.still_frames}


def check_summary(check: dict) -> str:
    """One sentence for a user on a :meth:`SigmaCheck.as_dict` (as ``track.json`` holds it)."""
    local = check.get("local_frames", 0)
    return (f"per-frame errors against the tip's scatter about its path: factor {check['factor']:.3g} +- "
            f"{check['factor_se']:.2g} ({check['coordinates']} coordinates), "
            f"{'applied' if check['applied'] else 'not applied'}: {check['reason']}; "
            + (f"widened further in {local} frame(s) where the scatter grew along the record (up to "
               f"{check['local_max_factor']:.3g}x); " if local else "")
            + (f"widened in {check['scene_frames']} frame(s) where the scene under the tip's edge is not as its "
               "ring shows; " if check.get("scene_frames") else "")
            + (f"{check['still_frames']} frame(s) of the tip held still at an end of the record left out of it; "
               if check.get("still_frames") else "")
            + f"{check['outliers']} outlier frame(s)")


def _stencils(t_s: np.ndarray, frames: np.ndarray, active: np.ndarray, omega_rad_s: float = math.nan
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frames that can be checked, their six neighbours (m, 6) and the neighbours' interpolation
    weights (m, 6): three active frames before and three after, spanning at most :data:`MAX_SPAN` frames.  The
    path through them is a polynomial of degree 5, or with ``omega_rad_s`` one of degree 3 and a sinusoid of that
    angular frequency (:func:`motion_frequency`)."""
    h = HALF_WINDOW
    act = np.flatnonzero(active)
    if len(act) < 2 * h + 1:
        return np.empty(0, int), np.empty((0, 2 * h), int), np.empty((0, 2 * h))
    pos = np.arange(h, len(act) - h)
    pos = pos[frames[act[pos + h]] - frames[act[pos - h]] <= MAX_SPAN]
    offsets = [j for j in range(-h, h + 1) if j != 0]
    nb = np.column_stack([act[pos + j] for j in offsets]) if len(pos) else np.empty((0, 2 * h), int)
    idx = act[pos]
    t0 = t_s[idx]
    if math.isfinite(omega_rad_s):
        return idx, nb, _sinusoid_weights(t_s[nb] - t0[:, None], omega_rad_s)
    weights = np.ones(nb.shape)
    for a in range(nb.shape[1]):
        for b in range(nb.shape[1]):
            if a != b:
                weights[:, a] *= (t0 - t_s[nb[:, b]]) / (t_s[nb[:, a]] - t_s[nb[:, b]])
    return idx, nb, weights


#: :func:`_noise_acf`
NOISE_ACF = _noise_acf()

#: a sinusoid in the path's basis is looked for between these turns per frame (below, the polynomial follows it;
#: above, the frames no longer sample it), among this many of the track's strongest periodogram peaks (over a few
#: seconds the precession's arc leaks past the quadratic taken off, and its peaks can outrank the nod's)
SINUSOID_TURN_RANGE = (0.3, 2.5)
SINUSOID_PEAKS = 12


def _sinusoid_weights(tau: np.ndarray, omega_rad_s: float) -> np.ndarray:
    """Interpolation weights (m, 6) at 0 from six neighbours at ``tau`` (m, 6) [s] through a cubic and a sinusoid
    of ``omega_rad_s``: the weights reproduce each of the six basis functions at 0 exactly."""
    scale = np.abs(tau).max(axis=1, keepdims=True)
    basis = np.stack([(tau / scale) ** d for d in range(4)] + [np.cos(omega_rad_s * tau), np.sin(omega_rad_s * tau)],
                     axis=1)  # (m, basis, neighbour)
    at_zero = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    return np.linalg.solve(basis, np.broadcast_to(at_zero, (len(tau), 6))[..., None])[..., 0]


def motion_frequency(t_s, frames, xy) -> float:
    """The angular frequency [rad/s] of a sinusoid that, put in the path's basis (a cubic and that sinusoid
    through six neighbours), leaves the least scatter about the path: of the strongest peaks of the track's
    Lomb-Scargle periodogram (both axes, a quadratic taken off) between :data:`SINUSOID_TURN_RANGE` per frame.
    A nod the polynomial path cannot follow at a low frame rate (60 frames/s: 1 rad per frame) is then followed.
    NaN with too few frames."""
    t_s, frames, xy = np.asarray(t_s, float), np.asarray(frames, int), np.asarray(xy, float)
    if len(t_s) < 4 * (2 * HALF_WINDOW + 1):
        return math.nan
    dt = float(np.median(np.diff(t_s)))
    omegas = np.linspace(*SINUSOID_TURN_RANGE, 400) / dt
    tau = t_s - t_s.mean()
    power = sum(lombscargle(tau, xy[:, j] - np.polyval(np.polyfit(tau, xy[:, j], 2), tau), omegas) for j in (0, 1))
    peaks = [k for k in range(1, len(omegas) - 1) if power[k] >= power[k - 1] and power[k] >= power[k + 1]]
    best, best_ms = math.nan, math.inf
    for k in sorted(peaks, key=lambda k: -power[k])[:SINUSOID_PEAKS]:
        try:
            idx, nb, w = _stencils(t_s, frames, np.ones(len(t_s), bool), float(omegas[k]))
        except np.linalg.LinAlgError:  # six neighbours on which the cubic and the sinusoid are not independent
            continue
        if len(idx) == 0:
            continue
        r = xy[idx] - np.einsum("mj,mjk->mk", w, xy[nb])
        ms = float(np.mean(r * r) / np.mean(1.0 + np.sum(w * w, axis=1)))
        if ms < best_ms:
            best, best_ms = float(omegas[k]), ms
    return best


def path_residuals(t_s: np.ndarray, frames: np.ndarray, xy: np.ndarray, var: np.ndarray, active: np.ndarray,
                   omega_rad_s: float = math.nan) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-out residuals about the degree-5 path through each frame's six nearest active neighbours
    (three before, three after, spanning at most :data:`MAX_SPAN` frames: a gap or a removed frame
    does not stop its neighbours from being checked).

    ``t_s, frames`` (n,), ``xy, var`` (n, 2) sorted by time; ``active`` (n,) which frames may take part.
    Returns ``(centres, z)``: the indices of the frames checked and their residuals over their
    predicted standard deviations (m, 2).
    """
    idx, nb, w = _stencils(t_s, frames, active, omega_rad_s)
    if len(idx) == 0:
        return idx, np.empty((0, 2))
    pred = np.einsum("mj,mjk->mk", w, xy[nb])
    pvar = var[idx] + np.einsum("mj,mjk->mk", w * w, var[nb])
    return idx, (xy[idx] - pred) / np.sqrt(pvar)


def neighbour_positions(t_s: np.ndarray, frames: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Each frame's position as its neighbours predict it, its own measurement left out: the degree-5 path
    of :func:`path_residuals` where a frame has its six neighbours, else the straight line between the
    nearest frame before and after it (the nearest one at an end of the record).

    Quantities evaluated at these positions carry no part of the frame's own noise: a correction
    computed at the measured position would be correlated with the measurement it corrects (the
    camera modes are: their least-squares amplitudes would then be biased).  ``t_s, frames`` (n,) and
    ``xy`` (n, 2), sorted by time; at least two frames."""
    xy = np.asarray(xy, float)
    pred = np.empty_like(xy)
    pred[0], pred[-1] = xy[1], xy[-2]
    u = ((t_s[1:-1] - t_s[:-2]) / (t_s[2:] - t_s[:-2]))[:, None]
    pred[1:-1] = (1.0 - u) * xy[:-2] + u * xy[2:]
    idx, nb, w = _stencils(t_s, frames, np.ones(len(t_s), bool))
    if len(idx):
        pred[idx] = np.einsum("mj,mjk->mk", w, xy[nb])
    return pred


def _shared_coefficients(idx: np.ndarray, nb: np.ndarray, w: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """How much of an error common to the frames of each group reaches each stencil's residual: with the residual
    ``x_i - sum_j w_j x_j`` and ``S_G`` the signed weights of group ``G``'s frames in it (1 for the frame itself),
    ``sum_G S_G^2`` over the groups (``groups`` >= 0; -1 is no group).  A stencil inside one group gives 0 (the
    common error moves the path with the frame); one that reaches across a group's end sees it."""
    members = np.column_stack([idx, nb])
    signed = np.column_stack([np.ones(len(idx)), -w])
    g = groups[members]
    coef = np.zeros(len(idx))
    for a in range(members.shape[1]):
        same = np.sum(signed * (g == g[:, [a]]), axis=1)
        coef += np.where(g[:, a] >= 0, signed[:, a] * same, 0.0)
    return coef


def _variance_model(t_s, frames, xy, var, active, labels, floor: bool, min_factor: float, groups=None,
                    omega_rad_s: float = math.nan) -> tuple[dict, float, float, float, float]:
    """Each class's factor and, with ``floor``, an error added to every frame, solved jointly: a residual's expected
    square is linear in the classes' squared factors and the floor's variance (``E r^2 = sum_c f_c^2 A_c + tau^2 B``,
    ``A_c`` the reported variances of the stencil's frames of class ``c`` times their squared weights, ``B`` the
    stencil's squared weights summed, 1 for the frame itself), so they follow from weighted least squares of
    ``r^2`` (weights ``1 / (2 (E r^2)^2)``, found in passes).  Factors below ``min_factor`` are held there and the
    rest solved again.  With ``groups`` (n,) (an integer per frame, -1 for none) an error common to the frames of
    each group, independent from group to group, is solved beside them (its variance ``kappa^2`` enters with
    :func:`_shared_coefficients`).  Returns ``({class: (factor, se, coordinates)}, tau^2, its se, kappa^2, its se)``;
    ``({}, nan, nan, nan, nan)`` when the check has too few frames."""
    idx, nb, w = _stencils(t_s, frames, active, omega_rad_s)
    if len(idx) == 0:
        return {}, math.nan, math.nan, math.nan, math.nan
    shared = groups is not None and bool(np.any(np.asarray(groups)[idx] >= 0))
    classes = sorted(set(labels[idx]) | set(labels[nb].ravel()))
    pred = np.einsum("mj,mjk->mk", w, xy[nb])
    r2 = ((xy[idx] - pred) ** 2).ravel()
    columns = []
    for label in classes:
        col = np.where((labels[idx] == label)[:, None], var[idx], 0.0)
        columns.append((col + np.einsum("mj,mjk->mk", w * w * (labels[nb] == label), var[nb])).ravel())
    if floor:
        columns.append(np.repeat(1.0 + np.sum(w * w, axis=1), 2))
    if shared:
        columns.append(np.repeat(_shared_coefficients(idx, nb, w, np.asarray(groups, int)), 2))
    design = np.column_stack(columns)
    k = len(classes)
    lower = np.array([min_factor**2] * k + [0.0] * (design.shape[1] - k))
    x = np.maximum(np.r_[np.ones(k), np.zeros(design.shape[1] - k)], lower)
    for _ in range(4):  # reweighting passes; bounded least squares (the floor and a class's factor are told apart
        # only by how the reported errors vary within the class: where they do not, any split gives the same errors)
        expected = np.maximum(design @ x, 1e-300)
        sw = 1.0 / (math.sqrt(2.0) * expected)
        scale = np.maximum(np.abs(design * sw[:, None]).max(axis=0), 1e-300)
        fit = lsq_linear(design * sw[:, None] / scale, r2 * sw, bounds=(lower * scale, np.inf))
        x = fit.x / scale
    a = design * sw[:, None]
    cov = np.linalg.pinv(a.T @ a)
    active = x > lower * (1 + 1e-9) + 1e-300  # a value at its bound has no error of its own
    full = np.where(np.outer(active, active), cov, 0.0)
    out = {}
    for c, label in enumerate(classes):
        f = math.sqrt(max(x[c], 1e-12))
        out[str(label)] = (f, math.sqrt(max(full[c, c], 0.0)) / (2 * f), 2 * int(np.sum(labels[idx] == label)))
    extra = [(float(x[j]), math.sqrt(max(full[j, j], 0.0))) for j in range(k, design.shape[1])]
    tau = extra.pop(0) if floor else (0.0, 0.0)
    kappa = extra.pop(0) if shared else (0.0, 0.0)
    return out, *tau, *kappa


def check_sigmas(t_s, frames, xy, var, classes=None, *, floor: bool = False, min_factor: float = 0.0,
                 groups=None, omega_rad_s: float = math.nan, follow_motion: bool = False,
                 largest_error_px: float = math.inf) -> SigmaCheck:
    """Compare the reported errors with the scatter about the path (module docstring); outliers removed
    one at a time (the worst first, since its residual also reaches its neighbours' predictions).

    ``classes`` (n,), optional: a label per frame (e.g. its quality flag); the factor is then also found
    per label, from the residuals of the frames that carry it.  With ``floor`` an error the same for every
    frame and independent from frame to frame (a lossy codec's) is found beside the factors
    (:attr:`SigmaCheck.floor_px`), and the factors are held at ``min_factor`` or above; the outliers are then
    looked for again with the errors so found (each class's factor on the reported errors, the floor added) and
    the errors solved again without them, until the outliers stay the same (the reported errors alone make frames
    whose own errors are far below the floor look far off the path, and the scale they give a stretch of such frames
    hides a frame truly off it).  ``groups`` (n,),
    optional: an integer per frame (-1: none); an error common to the frames of each group and independent
    from group to group (a codec's run of B pictures between two reference pictures, predicted from the same
    two) is found beside them (:attr:`SigmaCheck.shared_px`).  ``omega_rad_s``: the path holds a sinusoid of
    that angular frequency (:func:`_stencils`); with ``follow_motion``, when the polynomial path cannot follow the
    motion (:attr:`SigmaCheck.smooth_path` false) the check is made again through the sinusoid of
    :func:`motion_frequency` and that one is returned if its path follows the motion.  A path does not follow the
    motion either when it leaves more than :data:`MAX_OUTLIER_SHARE` of the frames off it, or when its residuals
    put the frames' error above ``largest_error_px`` (the worst a position can be known and still be taken for the
    tip's: residuals that large are the motion's, not the spots')."""
    t_s, frames = np.asarray(t_s, float), np.asarray(frames, int)
    xy, var = np.asarray(xy, float), np.asarray(var, float)
    active = np.all(np.isfinite(xy), axis=1) & np.all(np.isfinite(var) & (var > 0), axis=1)
    finite = active.copy()
    active, outliers = _outlier_search(t_s, frames, xy, var, finite, omega_rad_s)
    by_class, tau2, tau2_se, kappa2, kappa2_se = {}, 0.0, 0.0, 0.0, 0.0
    if classes is not None or floor or groups is not None:
        labels = np.asarray(classes).astype(str) if classes is not None else np.full(len(t_s), "all")
        for attempt in range(MAX_RESEARCH_PASSES + 1):
            if len(path_residuals(t_s, frames, xy, var, active, omega_rad_s)[0]) < 5:
                break
            by_class, tau2, tau2_se, kappa2, kappa2_se = _variance_model(t_s, frames, xy, var, active, labels, floor,
                                                                         min_factor, groups, omega_rad_s)
            if not floor or not math.isfinite(tau2) or attempt == MAX_RESEARCH_PASSES:
                break
            factors = np.array([by_class.get(str(label), (1.0,))[0] for label in labels])
            again = _outlier_search(t_s, frames, xy, var * factors[:, None] ** 2 + tau2, finite, omega_rad_s)
            if set(again[1]) == set(outliers):
                break
            active, outliers = again
    centres, z = path_residuals(t_s, frames, xy, var, active, omega_rad_s)
    if len(centres) < 5:
        return SigmaCheck(math.nan, math.nan, 2 * len(centres), tuple(sorted(outliers)))
    factor = math.sqrt(float(np.mean(z * z)))
    floor_px, floor_se = _root(tau2, tau2_se)
    shared_px, shared_se = _root(kappa2, kappa2_se)
    acf, smooth = _path_follows(centres, z)
    smooth = (smooth and len(outliers) <= MAX_OUTLIER_SHARE * (len(centres) + len(outliers))
              and not (math.isfinite(largest_error_px)
                       and _path_error_px(t_s, frames, xy, active, omega_rad_s) > largest_error_px))
    if follow_motion and not smooth and math.isnan(omega_rad_s):
        omega = motion_frequency(t_s[active], frames[active], xy[active])
        try:
            retried = None if not math.isfinite(omega) else check_sigmas(
                t_s, frames, xy, var, classes, floor=floor, min_factor=min_factor, groups=groups, omega_rad_s=omega,
                largest_error_px=largest_error_px)
        except np.linalg.LinAlgError:  # a stencil of the frames left after the outliers on which the basis is singular
            retried = None
        if retried is not None and retried.smooth_path:
            return retried
    return SigmaCheck(factor, factor / math.sqrt(2 * z.size), int(z.size), tuple(sorted(outliers)), by_class,
                      floor_px=floor_px, floor_px_se=floor_se, shared_px=shared_px, shared_px_se=shared_se,
                      residual_acf=acf, smooth_path=smooth, omega_rad_s=omega_rad_s)


def _outlier_search(t_s, frames, xy, var, active, omega_rad_s) -> tuple[np.ndarray, list[int]]:
    """The frames off the path by more than :data:`OUTLIER_Z` of their residuals' standard deviations under the
    errors ``var``, removed one at a time, the worst first (its residual also reaches its neighbours'
    predictions), against a robust scale while outliers may remain (the median of ``z^2`` is 0.4549 for a unit
    normal; over the record, or over each frame's stretch where that is larger).  Returns the frames left active
    (a copy of ``active`` without them) and the outliers in the order found."""
    active = active.copy()
    outliers: list[int] = []
    while True:
        centres, z = path_residuals(t_s, frames, xy, var, active, omega_rad_s)
        if len(centres) < 5:
            return active, outliers
        scale = np.sqrt(np.maximum(float(np.median(z * z)), _running_median(z * z, LOCAL_FRAMES)) / 0.4549)
        worst = np.max(np.abs(z), axis=1) / scale
        k = int(np.argmax(worst))
        if worst[k] <= OUTLIER_Z:
            return active, outliers
        active[centres[k]] = False
        outliers.append(int(centres[k]))


def local_factors(t_s, frames, xy, var, active, omega_rad_s: float = math.nan, *,
                  window: int = LOCAL_FRAMES) -> np.ndarray:
    """The factor by which each frame's errors fall short of the scatter about the path around it: the RMS of the
    normalised residuals (:func:`path_residuals`) of the ``window`` checked frames centred on it (nearest in the
    record), where that exceeds 1, else 1: widened wherever the scatter says so, never narrowed, as the record's own
    factor is applied when the models are in doubt (each known to ``sqrt((1 + 2 sum rho_k^2) / (2 N))`` from ``N``
    coordinates: neighbouring residuals share frames, their squares correlated as :data:`NOISE_ACF` squared).

    A record's errors change along it (the scene behind the tip, the tip's speed, the light), which one factor for the
    whole record averages away: where the scatter grows, its stretch's errors grow with it.  ``t_s, frames`` (n,),
    ``xy, var`` (n, 2) sorted by time, ``active`` (n,) the frames the path may use.  Returns (n,); frames not checked
    take their nearest checked frame's factor (all 1 with fewer than ``window`` checked frames)."""
    idx, z = path_residuals(np.asarray(t_s, float), np.asarray(frames, int), np.asarray(xy, float),
                            np.asarray(var, float), np.asarray(active, bool), omega_rad_s)
    n = len(np.asarray(t_s))
    if len(idx) < window:
        return np.ones(n)
    f = np.maximum(_window_rms(z, window), 1.0)
    nearest = np.clip(np.searchsorted(idx, np.arange(n)), 0, len(idx) - 1)
    before = np.clip(nearest - 1, 0, len(idx) - 1)
    closer = np.abs(idx[before] - np.arange(n)) < np.abs(idx[nearest] - np.arange(n))
    return f[np.where(closer, before, nearest)]


def _running_median(z2: np.ndarray, window: int) -> np.ndarray:
    """The median of ``z2`` (m, 2) over the ``window`` rows centred on each row (both columns; the record's ends
    repeated beyond them)."""
    return np.mean(median_filter(z2.ravel(), size=2 * window + 1, mode="nearest").reshape(-1, 2), axis=1)


def _window_rms(z: np.ndarray, window: int) -> np.ndarray:
    """The RMS of the residuals ``z`` (m, 2) over the ``window`` rows centred on each row (held inside the record at
    its ends; all rows when there are fewer)."""
    window = min(window, len(z))
    sums = np.r_[0.0, np.cumsum(np.sum(z * z, axis=1))]
    lo = np.clip(np.arange(len(z)) - window // 2, 0, len(z) - window)
    return np.sqrt((sums[lo + window] - sums[lo]) / (2.0 * window))


def _path_error_px(t_s, frames, xy, active, omega_rad_s: float) -> float:
    """The per-frame error [px] the residuals about the path imply on their own (their mean square over the
    stencils' mean noise gain ``1 + sum w^2``), whatever errors were reported."""
    idx, nb, w = _stencils(t_s, frames, active, omega_rad_s)
    if len(idx) == 0:
        return math.nan
    r = xy[idx] - np.einsum("mj,mjk->mk", w, xy[nb])
    return math.sqrt(float(np.mean(r * r)) / float(np.mean(1.0 + np.sum(w * w, axis=1))))


def _path_follows(centres: np.ndarray, z: np.ndarray) -> tuple[tuple, bool]:
    """The residuals' correlations 1 .. :data:`ACF_LAGS` checked frames apart (both axes pooled, over frames that
    many apart in the record), and whether they are noise's (:data:`NOISE_ACF` within :data:`ACF_TOLERANCE`, the
    rest no more than chance: :data:`ACF_TAIL`).  ``((), True)`` with fewer than 20 pairs at some lag.

    A motion the path cannot follow leaves residuals that correlate at lag 1 as ``cos(omega)`` for a motion of
    ``omega`` per frame, above noise's -0.857 for any ``omega`` below 0.83 of the Nyquist rate (2.6 rad per frame).
    Residuals that alternate more than noise's (the lag-1 correlation below noise's: errors that flip sign from
    frame to frame, as a codec's pictures coded alternately well and poorly give) are taken as errors, not as a
    motion: read as errors they make the error bars larger (by up to 2.1 times their size: the stencil passes an
    error that alternates 3.2 times, white noise 1.52 times), where a motion that fast is not resolved anyway."""
    acf, counts = [], []
    for k in range(1, ACF_LAGS + 1):
        pair = np.flatnonzero(centres[k:] - centres[:-k] == k)
        if len(pair) < 20:
            return (), True
        a, b = z[pair], z[pair + k]
        acf.append(float(np.sum(a * b) / math.sqrt(np.sum(a * a) * np.sum(b * b))))
        counts.append(a.size)
    if acf[0] < NOISE_ACF[0]:
        return tuple(round(v, 4) for v in acf), True
    excess = np.maximum(np.abs(np.array(acf) - NOISE_ACF) - ACF_TOLERANCE, 0.0)
    bartlett = 1.0 + 2.0 * float(np.sum(NOISE_ACF**2))  # the variance of a sample correlation, times its count
    stat = float(np.sum(excess**2 * np.array(counts) / bartlett))
    return tuple(round(v, 4) for v in acf), bool(stat <= chi2.isf(ACF_TAIL, ACF_LAGS))


def b_picture_runs(angles) -> np.ndarray:
    """Each angle table row's run of B pictures (its ``frame_type`` column): the B pictures between two others (I
    or P, which they are predicted from) share a number, counted from 0; -1 for any other row, and for every row
    when the table has no picture types or no B picture.  A codec renders such a run from the same two pictures,
    so an error it makes in one of them it makes in its neighbours too."""
    types = angles["frame_type"].to_numpy().astype(str) if "frame_type" in angles else np.array([], str)
    if not np.any(types == "B"):
        return np.full(len(angles), -1)
    b = types == "B"
    return np.where(b, np.cumsum(~b), -1)


def _root(value: float, se: float) -> tuple[float, float]:
    """A variance's root and the root's standard error (the variance's own where the root is 0)."""
    if not value > 0:
        return 0.0, se
    root = math.sqrt(value)
    return root, se / (2 * root)
