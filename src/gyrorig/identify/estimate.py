"""Weighted least squares of the rig's parameters from observations and the prior protocol.

Free parameters: the rig's ``inertia_axial_kg_m2``, ``inertia_transverse_kg_m2`` and ``com_distance_m`` (and a
gyro in gimbals' ``[gimbal]`` inertias) where the prior gives them a standard deviation (their priors, with the
prior's correlations, enter as whitened residuals; a number without one is known and held); each video's spin and
each configuration's own parameters, with their priors; and, with spin-down tables, the viscous rate ``k``, the
constant friction ``f`` (only when the data need it: a chi-square gain above the 1 % point of chi-square with one
degree of freedom, or with errors from the scatter an F-test at 1 %) and each table's initial spin.  Residuals are
``(y - model) / sd_eff`` with the conditions' errors carried in as effective variance; a kind whose rows give no
standard deviation gets one from its scatter (iterated with the fit).  The covariance is ``(J^T J)^-1``, scaled by
the reduced chi-square when the chi-square's p-value is below :data:`LACK_OF_FIT_P` (flagged and noted).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2 as chi2_dist
from scipy.stats import f as f_dist

from ..protocols import Protocol, ProtocolError, checked_rig
from .observations import FORMULAS, Observation
from .tables import IdentifyInputError

__all__ = ["Identification", "identify_parameters", "prior_rig_values", "extra_priors", "RIG_PARAMETERS",
           "GIMBAL_PARAMETERS", "FRICTION_P_VALUE", "LACK_OF_FIT_P"]

RIG_PARAMETERS = ("rig.inertia_axial_kg_m2", "rig.inertia_transverse_kg_m2", "rig.com_distance_m")
#: the constant friction is kept when dropping it raises the chi-square by more than this quantile's value (stated
#: errors), or when the F-test of the two laws gives a p-value below it (errors from the scatter)
FRICTION_P_VALUE = 0.01
#: a chi-square whose p-value is below this says the data, their stated errors and the model disagree
LACK_OF_FIT_P = 1e-3


#: a gyro in gimbals (the prior's ``[gimbal]``): what turns only in azimuth, and the tilting assembly's inertia across
#: the inner gimbal axis and the spin axis (:mod:`gyrorig.gimbals`)
GIMBAL_PARAMETERS = ("gimbal.outer_inertia_kg_m2", "gimbal.cross_inertia_kg_m2")


def prior_rig_values(prior: Protocol) -> dict[str, float]:
    """The prior's values of :data:`RIG_PARAMETERS` (and of :data:`GIMBAL_PARAMETERS` for a gyro in gimbals; the
    cross inertia only where the prior states it), by name."""
    out = {n: getattr(prior.rig, n.split(".")[1]) for n in RIG_PARAMETERS}
    if prior.gimbal is not None:
        for n in GIMBAL_PARAMETERS:
            v = getattr(prior.gimbal, n.split(".")[1])
            if v is not None:
                out[n] = v
    return out


def _is_model_parameter(name: str) -> bool:
    return name.startswith(("rig.", "gimbal."))


@dataclass(frozen=True)
class Identification:
    """The identified parameters, their covariance, and every observation's residual."""

    names: tuple[str, ...]
    values: np.ndarray
    covariance: np.ndarray
    chi2: float
    dof: int
    observations: tuple[Observation, ...]
    #: effective standard deviation of each observation (after any scatter estimate)
    sd_eff: np.ndarray
    #: kinds whose standard deviations came from their scatter
    sd_from_scatter: tuple[str, ...] = ()
    damping_law: str = ""
    friction_chi2_gain: float | None = None
    fast_top: bool = False
    #: parameters with priors: the rig's (from the prior protocol) and each video's spin
    prior_names: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)
    #: the chi-square's p-value (the probability of a chi-square at least this large if model and errors are right)
    p_value: float = math.nan
    #: the p-value is below :data:`LACK_OF_FIT_P`: the covariance is scaled by the reduced chi-square (noted)
    lack_of_fit: bool = False

    @property
    def standard_errors(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def chi2_red(self) -> float:
        return self.chi2 / max(self.dof, 1)

    @property
    def correlation(self) -> np.ndarray:
        s = self.standard_errors
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.outer(s, s) > 0, self.covariance / np.outer(s, s), np.nan)

    def value(self, name: str) -> float:
        return float(self.values[self.names.index(name)])

    def params(self) -> dict[str, float]:
        return dict(zip(self.names, map(float, self.values)))

    def derived(self, prior: Protocol) -> dict[str, tuple[float, float]]:
        """``mgh_N_m``, ``io_over_i``, ``mgh_over_io_rad2_s2`` and (with spin-down) the axial drag
        ``k Io`` [N m s], with standard errors by the delta method."""
        m, g = prior.rig.mass_kg, prior.rig.gravity_m_s2 or 0.0
        fns = {"mgh_N_m": lambda p: m * g * p["rig.com_distance_m"],
               "io_over_i": lambda p: p["rig.inertia_axial_kg_m2"] / p["rig.inertia_transverse_kg_m2"],
               "mgh_over_io_rad2_s2": lambda p: m * g * p["rig.com_distance_m"] / p["rig.inertia_axial_kg_m2"]}
        if "spin_down.viscous_rate_per_s" in self.names:
            fns["axial_drag_N_m_s"] = lambda p: p["spin_down.viscous_rate_per_s"] * p["rig.inertia_axial_kg_m2"]
        base = {**prior_rig_values(prior), **self.params()}
        out = {}
        for k, f in fns.items():
            v = f(base)
            grad = np.zeros(len(self.names))
            for i, n in enumerate(self.names):
                h = 1e-6 * max(abs(self.values[i]), 1e-12)
                bp = dict(base)
                bp[n] += h
                grad[i] = (f(bp) - v) / h
            out[k] = (float(v), float(math.sqrt(max(grad @ self.covariance @ grad, 0.0))))
        return out


def _free_rig(prior: Protocol) -> list[str]:
    return [n for n in prior_rig_values(prior) if prior.uncertainty.sd_of(n) > 0]


def _prior_whitener(prior: Protocol, names: list[str]):
    """``(mean, L^-1)`` of the prior on ``names`` (Cholesky of their covariance)."""
    u = prior.uncertainty
    idx = [u.names.index(n) for n in names]
    cov = u.covariance()[np.ix_(idx, idx)]
    mean = np.array([u.values[i] for i in idx])
    return mean, np.linalg.inv(np.linalg.cholesky(cov))


def _start(obs: list[Observation], prior: Protocol, names: list[str]) -> np.ndarray:
    x0, extra = [], extra_priors(obs)
    for n in names:
        if _is_model_parameter(n):
            x0.append(prior_rig_values(prior)[n])
        elif n in extra:
            x0.append(extra[n][0])
        elif n.startswith("spin_down.initial_spin_rad_s"):
            rows = sorted((o for o in obs if o.table_key == n), key=lambda o: o.x["t"])
            x0.append(rows[0].y)
        elif n == "spin_down.viscous_rate_per_s":
            rows = [o for o in obs if o.kind == "spin_down"]
            t = np.array([o.x["t"] for o in rows])
            y = np.array([o.y for o in rows])
            x0.append(max(-np.polyfit(t, np.log(y), 1)[0], 1e-9) if np.ptp(t) > 0 else 1e-3)
        else:
            x0.append(0.0)
    return np.array(x0, float)


def extra_priors(obs: list[Observation]) -> dict[str, tuple[float, float]]:
    """Priors ``(mean, sd)`` beside the prior protocol's: each video's spin, each configuration's own parameters."""
    out = {o.table_key: o.table_prior for o in obs if o.table_prior is not None}
    out.update({n: (m, s) for o in obs for n, m, s in o.own_priors})
    return out


def _solve(obs: list[Observation], prior: Protocol, names: list[str], fast: bool, sd_scatter: dict[str, float],
           x0: np.ndarray | None = None):
    rig_free = [n for n in names if _is_model_parameter(n)]
    mean, Linv = _prior_whitener(prior, rig_free) if rig_free else (np.zeros(0), np.zeros((0, 0)))
    ridx = [names.index(n) for n in rig_free]
    fixed = {n: v for n, v in prior_rig_values(prior).items() if n not in names}
    if x0 is None:
        x0 = _start(obs, prior, names)
        if not fast:
            # the fast-top formulas are defined everywhere: their solution starts the exact models inside the
            # region where the rig has steady precession for every row
            x0 = _solve(obs, prior, names, True, sd_scatter, x0)[0]
    sd_eff = np.ones(len(obs))

    def params(x):
        return {**fixed, **dict(zip(names, x))}

    def weights(x):
        p = params(x)
        return np.array([math.hypot(o.effective_sd(p, fast), sd_scatter.get(o.kind, 0.0)) for o in obs])

    extra = {n: v for n, v in extra_priors(obs).items() if n in names}  # video spins, configurations' own
    sidx = [names.index(n) for n in extra]
    s_mean = np.array([m for m, _ in extra.values()])
    s_sd = np.array([sd for _, sd in extra.values()])

    def residuals(x):
        p = params(x)
        r = np.array([(o.y - o.predict(p, fast=fast)) for o in obs]) / sd_eff
        parts = [r, Linv @ (x[ridx] - mean)] if rig_free else [r]
        return np.concatenate(parts + [(x[sidx] - s_mean) / s_sd])

    x = x0
    for _ in range(3):  # the effective variances depend on the parameters: re-weight and re-solve
        sd_eff = weights(x)
        if np.any(sd_eff <= 0):
            bad = obs[int(np.argmin(sd_eff))]
            raise IdentifyInputError(f"{bad.source}, line {bad.line}: no standard deviation for this {bad.kind} "
                                     "row (give a _sd column)")
        res = least_squares(residuals, x, x_scale="jac", method="trf", jac="3-point", xtol=1e-10, ftol=1e-10,
                            gtol=1e-10, max_nfev=50 * (len(x) + 1))
        x = res.x
    J = res.jac
    # the parameters' scales differ by many orders (inertias ~1e-4 kg m^2, spins ~1e2 rad/s): the normal matrix is
    # inverted with its columns scaled to unit norm, so that no direction is cut for its units alone
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    cov = np.linalg.pinv((J / scale).T @ (J / scale), rcond=1e-12, hermitian=True) / np.outer(scale, scale)
    r = res.fun
    return x, cov, float(r @ r), sd_eff, J[:len(obs)]


def identify_parameters(obs: list[Observation], prior: Protocol, *, fast_top: bool = False) -> Identification:
    """Identify the rig (and spin-down law) from ``obs`` with the prior protocol (see the module docstring)."""
    if not obs:
        raise IdentifyInputError("no observations")
    spin_tables = sorted({o.table_key for o in obs if o.kind == "spin_down"})
    rig_names = _free_rig(prior)
    extra_names = sorted(extra_priors(obs))  # each video's spin, each configuration's own parameters
    base = rig_names + extra_names + ([*spin_tables, "spin_down.viscous_rate_per_s"] if spin_tables else [])
    if not base:
        raise IdentifyInputError(f"{prior.source or prior.name}: no rig parameter has a standard deviation, so there is "
                                 "nothing to identify: give the numbers to identify as { value, sd } (e.g. "
                                 "inertia_transverse_kg_m2 = { value = 4e-3, sd = 1e-3 })")
    n_res = len(obs) + len(rig_names) + len(extra_names)
    if n_res <= len(base) + (1 if spin_tables else 0):
        raise IdentifyInputError(f"{len(obs)} observation(s) and {len(rig_names)} prior(s) are too few for "
                                 f"{len(base) + (1 if spin_tables else 0)} parameters: "
                                 + ", ".join(sorted({o.source for o in obs})))
    no_sd = {o.kind for o in obs if o.y_sd == 0 and not any(s > 0 for s in o.x_sd.values())}
    # a first guess for the kinds without errors (1 % of their typical value); then their scatter about the fit
    sd_scatter = {k: 0.01 * float(np.median([abs(o.y) for o in obs if o.kind == k])) for k in no_sd}
    laws = {"viscous": base}
    if spin_tables:
        laws["viscous+friction"] = base + ["spin_down.friction_rad_s2"]
    solutions = {}
    for law, names in laws.items():
        scatter = dict(sd_scatter)
        for _ in range(4 if no_sd else 1):
            x, cov, chi2, sd_eff, jac = _solve(obs, prior, names, fast_top, scatter)
            if not no_sd:
                break
            p = {**prior_rig_values(prior), **dict(zip(names, x))}
            for kind in no_sd:
                rows = [o for o in obs if o.kind == kind]
                resid = np.array([o.y - o.predict(p, fast=fast_top) for o in rows])
                n_par = sum(1 for n in names if n.startswith("spin_down")) if kind == "spin_down" else 0
                scatter[kind] = float(np.sqrt(np.sum(resid ** 2) / max(len(rows) - n_par, 1)))
        solutions[law] = (names, x, cov, chi2, sd_eff, scatter, jac)
    law, gain = "", None
    notes = []
    if spin_tables:
        gain = solutions["viscous"][3] - solutions["viscous+friction"][3]
        if "spin_down" in no_sd:
            # the rows' errors come from their scatter about each law's own fit, so both chi-squares sit near their
            # degrees of freedom: compare the laws by the F-test on the spin-down rows' residual sums of squares
            law, f_stat, p_f = _spin_down_f_test(obs, prior, solutions, len(spin_tables), fast_top)
            notes.append(f"spin-down law by the F-test (the rows have no stated errors): F = {f_stat:.4g}, p = "
                         f"{p_f:.3g} for the constant friction")
        else:
            law = "viscous+friction" if gain > chi2_dist.isf(FRICTION_P_VALUE, 1) else "viscous"
    names, x, cov, chi2, sd_eff, scatter, jac = solutions[law or "viscous"]
    _check_informative(obs, jac, cov)
    try:
        checked_rig(replace(prior.rig, **{n.split(".")[1]: v for n, v in zip(names, x) if n.startswith("rig.")}))
    except ProtocolError as exc:
        notes.append(f"the identified rig is not a possible rigid body ({exc}): the data or the prior are "
                     "inconsistent with one")
    if no_sd:
        notes.append("no standard deviations given for " + ", ".join(sorted(no_sd)) + ": taken from the scatter of "
                     "those rows about the fit (their errors are then not checked by the chi-square)")
    dof = n_res - len(names)
    p_value = float(chi2_dist.sf(chi2, max(dof, 1)))
    lack_of_fit = p_value < LACK_OF_FIT_P
    if lack_of_fit:
        chi2_red = chi2 / max(dof, 1)
        cov = cov * chi2_red
        notes.append(f"the data and their stated errors disagree with the model (chi-square {chi2:.4g} for {dof} degrees "
                     f"of freedom, p = {p_value:.2g}): the standard errors are scaled by sqrt(chi2_red) = "
                     f"{math.sqrt(chi2_red):.3g}, which holds only if the errors are too small by one factor; check the "
                     "units in the column names (a rate in Hz under _rad_s is 2 pi off, a period in ms under _s 1000x), "
                     "the stated errors, and whether the rig is the model's (a fixed pivot, one transverse inertia)")
    return Identification(tuple(names), x, cov, chi2, dof, tuple(obs), sd_eff,
                          tuple(sorted(no_sd)), law, gain, fast_top, tuple(rig_names + extra_names), tuple(notes),
                          p_value, lack_of_fit)


def _check_informative(obs: list[Observation], jac: np.ndarray, cov: np.ndarray) -> None:
    """Refuse a kind of observation whose rows say nothing about any parameter (their predictions do not move when
    a parameter moves by its standard error): the fit would silently return the prior."""
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    for kind in sorted({o.kind for o in obs}):
        rows = [i for i, o in enumerate(obs) if o.kind == kind]
        if float(np.max(np.abs(jac[rows] * se))) < 1e-6:
            first = obs[rows[0]]
            raise IdentifyInputError(
                f"{first.source}: the {kind} rows carry no information about the rig (the model predicts the same "
                "whatever its parameters)"
                + (": a balanced rig (com_distance_m = 0) released from rest does not nutate; its nutation is set "
                   "off by a kick, which the model takes as torque-free when com_distance_m is exactly 0 and held"
                   if kind == "nutation" else ""))


def _spin_down_f_test(obs: list[Observation], prior: Protocol, solutions: dict, tables: int, fast: bool
                      ) -> tuple[str, float, float]:
    """The spin-down law chosen by the F-test of the nested laws on the spin-down rows' residual sums of squares:
    ``F = (RSS_v - RSS_vf) / (RSS_vf / (n - p_vf))`` with one degree of freedom over ``n - p_vf`` (``p_vf``: each
    table's initial spin, the viscous rate and the friction).  Returns the law, F and its p-value."""
    rows = [o for o in obs if o.kind == "spin_down"]
    rss = {}
    for law in ("viscous", "viscous+friction"):
        names, x = solutions[law][0], solutions[law][1]
        p = {**prior_rig_values(prior), **dict(zip(names, x))}
        rss[law] = float(sum((o.y - o.predict(p, fast=fast)) ** 2 for o in rows))
    dof = len(rows) - (tables + 2)
    if dof < 1 or rss["viscous+friction"] <= 0:
        return "viscous", math.nan, math.nan
    f_stat = max(rss["viscous"] - rss["viscous+friction"], 0.0) / (rss["viscous+friction"] / dof)
    p_f = float(f_dist.sf(f_stat, 1, dof))
    return ("viscous+friction" if p_f < FRICTION_P_VALUE else "viscous"), f_stat, p_f


def formulas_used(ident: Identification) -> dict[str, str]:
    """The formula that served each kind of observation."""
    kinds = sorted({o.kind for o in ident.observations})
    if ident.fast_top:
        return {k: "fast-top formula" if k != "spin_down" else FORMULAS[k] for k in kinds}
    return {k: FORMULAS[k] for k in kinds}
