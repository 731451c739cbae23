"""Standard errors: the delta method, the checks on the residuals, the bootstrap, the camera's share.

The parameter covariance is ``(J^T J)^-1`` of the whitened residuals: the Cramér-Rao bound of the
model for the tracker's per-frame errors.  It is what the fit reports when the residuals are
consistent with those errors.  Where they are not white (lag-1 autocorrelation beyond
``4 / sqrt(N)``) a moving-block bootstrap of the residuals gives the errors instead; where the
reduced chi-square is significantly above 1 the errors are scaled by ``sqrt(chi2_red)``.  The
least-squares errors are Cramér-Rao bounds only while the model is linear over one standard
error: :func:`phase_uncertainty` says whether the record is long enough for that.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.fft import dct
from scipy.stats import chi2
from scipy.stats import f as f_dist

from .data import FitData
from .model import FitModel, Residuals
from .result import ErrorKind, Note, NoteKind
from .spec import ModelSpec

__all__ = ["delta_se", "phase_uncertainty", "lag1_autocorrelation", "long_run_ratio", "har_threshold",
           "block_bootstrap", "statistical_covariance",
           "shared_pose_prior_root",
           "choose_errors", "RATE_PARAMETERS"]

#: parameters that enter the model as phase or log-amplitude rates: (name, power of tau)
RATE_PARAMETERS = (("precession_rate_rad_s", 1), ("nutation_frequency_rad_s", 1), ("persistent_frequency_rad_s", 1),
                   ("nutation_decay_rate_per_s", 1), ("tilt_growth_rate_per_s", 1),
                   ("precession_acceleration_rad_s2", 2), ("nutation_chirp_rad_s2", 2),
                   ("tilt_growth_curvature_per_s2", 2), ("precession_rate_curvature_rad_s3", 3),
                   ("nutation_frequency_curvature_rad_s3", 3))


def delta_se(f, x: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """``f(x)`` and its standard error by the delta method (central differences)."""
    v = f(x)
    g = np.zeros_like(x)
    for i in range(len(x)):
        h = 1e-6 * max(abs(x[i]), np.sqrt(max(cov[i, i], 0.0)), 1e-12)
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        g[i] = (f(xp) - f(xm)) / (2 * h)
    return float(v), float(np.sqrt(max(g @ cov @ g, 0.0)))


def phase_uncertainty(spec: ModelSpec, x: np.ndarray, cov: np.ndarray, data: FitData) -> dict[str, float]:
    """For each rate-like parameter, one standard error times the longest ``|tau|`` (``tau^2 / 2``
    for second-order terms, ``tau^3 / 3`` for third-order ones): the phase or log-amplitude it leaves uncertain at
    the record's ends, in radians.  The least-squares errors are Cramér-Rao bounds only while these are
    well below 1 (the model is linear over one standard error); above
    :data:`gyrorig.fit.result.NONLINEAR_PHASE_RAD` the record is too short for the model."""
    names = spec.names()
    tau = float(np.max(np.abs(data.tau)))
    out = {}
    for name, power in RATE_PARAMETERS:
        if name in names:
            i = names.index(name)
            se = math.sqrt(max(float(cov[i, i]), 0.0))
            out[name] = se * {1: tau, 2: tau**2 / 2, 3: tau**3 / 3}[power]
    return out


def lag1_autocorrelation(model: FitModel, data: FitData, x: np.ndarray) -> tuple[float, float]:
    """Lag-1 autocorrelation of the whitened residuals in theta and in phi."""
    r = Residuals(model, data)(x)[:2 * data.n].reshape(2, -1)
    rho = [float(np.sum(ri[1:] * ri[:-1]) / np.sum(ri * ri)) for ri in r]
    return rho[0], rho[1]


def long_run_ratio(model: FitModel, data: FitData, x: np.ndarray) -> tuple[float, int]:
    """How much more the whitened residuals vary at the lowest frequencies than white noise would: their long-run
    variance over their variance (the larger of theta's and phi's), and the degrees of freedom ``nu`` of that estimate.

    The equal-weighted cosine estimate (Lazarus, Lewis, Stock and Watson, "HAR inference: recommendations for
    practice", 2018): the mean square of the residuals' projections on the ``nu = 0.4 T^(2/3)`` slowest cosines
    ``sqrt(2 / T) cos(pi j (t + 1/2) / T)`` over the record's ``T`` frames.  A term as slow as the record (a lean's
    circle) takes up that much more of such noise than of white noise; a statistic divided by the ratio is
    ``F``-distributed with ``nu`` denominator degrees of freedom (:func:`har_threshold`)."""
    r = Residuals(model, data)(x)[:2 * data.n].reshape(2, -1)
    n = r.shape[1]
    nu = max(int(round(0.4 * n ** (2.0 / 3.0))), 3)
    # DCT-II: 2 sum_t r_t cos(pi j (t + 1/2) / T), the projections up to a factor
    projections = math.sqrt(2.0 / n) * 0.5 * dct(r, type=2, axis=1)[:, 1:nu + 1]
    white = np.mean(r * r, axis=1)
    ratio = np.mean(projections ** 2, axis=1) / np.where(white > 0, white, 1.0)
    return float(np.max(ratio)), nu


def har_threshold(need: float, ddof: int, nu: int) -> float:
    """The value a statistic of ``ddof`` parameters divided by a :func:`long_run_ratio` of ``nu`` degrees of freedom
    must exceed, at the p-value at which chi-square(``ddof``) needs ``need``: ``ddof nu / (nu - ddof + 1)`` times that
    point of ``F(ddof, nu - ddof + 1)`` (the long-run variance is itself estimated)."""
    p = float(chi2.sf(need, ddof))
    dof = max(nu - ddof + 1, 1)
    return float(ddof * nu / dof * f_dist.isf(p, ddof, dof))


def block_bootstrap(spec: ModelSpec, x: np.ndarray, data: FitData, fns: dict, rng: np.random.Generator,
                    replicates: int, block: int) -> dict[str, float]:
    """Moving-block bootstrap of the residuals (refits start at the solution): the SD of each quantity.

    The residuals are resampled in units of their own frame's error (each ``(theta, phi)`` pair through the
    Cholesky factor of its covariance) and put back in the units of the frame they land on: a frame's error
    bars vary (codec picture types, blends, the scene), and a large residual of a down-weighted frame moved
    raw onto a precise one would count as noise the fit never saw.

    The camera modes are held at their fitted values (taken out of the data, left out of the refits):
    the bootstrap measures the statistical part, to which the fit adds the camera's share as it does
    to the formal errors (modes refitted on each replicate would count a free mode's share twice)."""
    from .solver import solve

    model = FitModel(spec)
    r0, r1 = Residuals(model, data).raw(x)
    m = spec.camera_modes
    th_fit, ph_fit = data.theta_rad - r0, data.phi_rad - r1  # the model, camera modes included
    if m:
        th_fit = th_fit - np.tensordot(x[-m:], data.camera_shift[:, :, 0], axes=1)
        ph_fit = ph_fit - np.tensordot(x[-m:], data.camera_shift[:, :, 1], axes=1)
    spec0 = replace(spec, camera_modes=0)
    data0 = replace(data, camera_shift=None, camera_prior=None, camera_prior_root=None)
    start = FitModel(spec0).values(x[:len(x) - m])
    n = data.n
    root = np.linalg.cholesky(data.cov)  # (n, 2, 2): each frame's residual = root @ (its standard normal pair)
    unit = np.linalg.solve(root, np.stack([r0, r1], axis=1)[:, :, None])
    out = {k: [] for k in fns}
    for _ in range(replicates):
        starts = rng.integers(0, max(n - block, 1), size=int(math.ceil(n / block)))
        idx = np.concatenate([np.arange(s, s + block) for s in starts])[:n]
        idx = np.minimum(idx, n - 1)
        moved = (root @ unit[idx])[:, :, 0]
        d = replace(data0, theta_rad=th_fit + moved[:, 0], phi_rad=ph_fit + moved[:, 1])
        s = solve(spec0, d, start)
        xs = np.concatenate([s.x, x[len(x) - m:]])
        for k, f in fns.items():
            out[k].append(f(xs))
    return {k: float(np.std(v, ddof=1)) for k, v in out.items()}


def statistical_covariance(spec: ModelSpec, x: np.ndarray, cov: np.ndarray, data: FitData) -> np.ndarray | None:
    """Parameter covariance with the camera modes held at their fitted values (None without modes).

    Padded with zeros for the modes, so that the difference from the full covariance is the
    camera model's share.
    """
    m = spec.camera_modes
    if not m:
        return None
    nb = len(x) - m
    J = Residuals(FitModel(spec), data).jac(x)
    J = np.vstack([J[:2 * data.n, :nb], J[2 * data.n + m:, :nb]])  # the frames and the user's priors
    out = np.zeros_like(cov)
    out[:nb, :nb] = np.linalg.pinv(J.T @ J, rcond=1e-14, hermitian=True)
    return out


def shared_pose_prior_root(spec: ModelSpec, x: np.ndarray, data: FitData) -> np.ndarray:
    """The camera modes' prior rows when some are moves of a pose found from these same frames.

    Such a pose's covariance (unit in each mode) holds information the frames also hold: a unit prior
    beside the frames would count it twice and shrink the fit's error bars.  No prior at all fails
    where the angles do not fix a move that the pose fit's pixels did (the depth of a camera above
    the pivot): the move is then free to run off.  The prior kept is the pose's information less what the frames hold on their own: with
    ``S`` the frames' information on the free modes (the Schur complement of the normal matrix, every
    other parameter fitted, the held modes' and the user's priors in), the prior precision is
    ``V diag(max(1 - s, 0)) V^T`` for ``S = V diag(s) V^T``.  The frames and the prior then hold the
    pose's own information once; a move the frames determine (``s >= 1``) is theirs to fit.

    Returns ``R`` (m x m) for :attr:`FitData.camera_prior_root`: identity rows for the held modes."""
    m = spec.camera_modes
    flags = np.ones(m) if data.camera_prior is None else np.asarray(data.camera_prior, float)
    free = np.flatnonzero(flags == 0.0)
    root = np.eye(m)
    if not len(free):
        return root
    J = Residuals(FitModel(spec), replace(data, camera_prior_root=None)).jac(x)
    nb = len(x) - m
    keep = np.ones(J.shape[0], bool)
    keep[2 * data.n + free] = False  # the free modes' own unit priors
    N = J[keep].T @ J[keep]
    f = nb + free
    o = np.setdiff1d(np.arange(len(x)), f)
    S = N[np.ix_(f, f)] - N[np.ix_(f, o)] @ np.linalg.pinv(N[np.ix_(o, o)], rcond=1e-14, hermitian=True) @ N[np.ix_(o, f)]
    s, V = np.linalg.eigh(0.5 * (S + S.T))
    w = np.sqrt(np.clip(1.0 - s, 0.0, 1.0))
    root[np.ix_(free, free)] = w[:, None] * V.T
    return root


def choose_errors(spec: ModelSpec, x: np.ndarray, chi2_value: float, dof: int, data: FitData, fns: dict,
                  rng: np.random.Generator | None, replicates: int, check_residuals: bool
                  ) -> tuple[ErrorKind, tuple[int, int] | None, dict[str, float], list[Note]]:
    """Where the standard errors come from, after the residual checks.

    Returns the kind, the bootstrap's ``(replicates, block)`` (None without), the bootstrap's SD of
    each quantity (empty without) and the notes saying why.
    """
    if not check_residuals:
        return ErrorKind.FORMAL, None, {}, []
    rho = lag1_autocorrelation(FitModel(spec), data, x)
    white_limit = 4.0 / math.sqrt(data.n)
    chi2_red = chi2_value / max(dof, 1)
    large = [] if not chi2.cdf(chi2_value, dof) < 1e-3 else [Note(
        NoteKind.ERRORS_LARGE,
        f"reduced chi-square {chi2_red:.3g} is significantly below 1: the frames' error bars are larger than the "
        f"residuals' scatter (by about {1 / math.sqrt(max(chi2_red, 1e-12)):.3g}x; at a low frame rate the tracker "
        "cannot tell the motion from noise when it checks them); formal standard errors are then conservative, and "
        "the chi-square tests that choose the model's terms may leave out a term the record holds")]
    if max(abs(rho[0]), abs(rho[1])) > white_limit:
        rng = rng if rng is not None else np.random.default_rng(0)
        block = max(2, int(math.ceil(1 + 2 * max(abs(rho[0]), abs(rho[1])) / (1 - min(0.99, max(abs(r) for r in rho)))
                                     * 5)))
        block = min(block, max(2, data.n // 10))  # at least ten blocks, or the bootstrap has nothing to resample
        sd = block_bootstrap(spec, x, data, fns, rng, replicates, block)
        note = Note(NoteKind.RESIDUALS_NOT_WHITE,
                    f"residuals are not white (lag-1 autocorrelation {rho[0]:.3f} in theta, {rho[1]:.3f} in phi; "
                    f"limit {white_limit:.3f}): standard errors from the bootstrap")
        return ErrorKind.BOOTSTRAP, (replicates, block), sd, [note, *large]
    if chi2.sf(chi2_value, dof) < 1e-3 and chi2_red > 1:
        note = Note(NoteKind.ERRORS_SCALED,
                    f"reduced chi-square {chi2_red:.3f} is significantly above 1 (the tracker's error bars are too "
                    "small or the model misses something): standard errors scaled by sqrt(chi2_red)")
        return ErrorKind.SCALED, None, {}, [note]
    return ErrorKind.FORMAL, None, {}, large
