"""The paper's theory as code: closed forms, their corrected and exact counterparts.

Every formula of the seed paper is here with its equation number, exactly as
printed (functions ``paper_*``).  Where the simulator shows the printed form is wrong,
the corrected form is given beside it (``corrected_*``) and the derivation is in
``docs/theory.md``; gyrorig's own predictions use the corrected form.  The exact
counterparts (``exact_*``) make no small-angle or fast-top approximation; quantities
with no closed form are *measured from the simulator* (``measure_*``).

Symbols: ``I`` transverse inertia about the pivot, ``Io`` axial inertia of the
rotor, ``Omega`` the spin ``psi'``, ``Mgh`` the gravity torque scale, ``gamma`` the
paper's damping rate.  All SI.

Sign conventions (from ``r x F`` in code): gravity exerts ``+Mgh sin(theta)`` along
the line of nodes ``a`` (the paper's eq. 17 says ``-a``); with ``Omega > 0`` the slow
precession is positive (counter-clockwise seen from above).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from scipy.optimize import brentq

from .physics import exact_solution, simulate
from .drag import rotor_spin_decay_rate_per_s
from .prediction import EquilibriumTip, PredictedQuantity, Prediction, PredictionFlags
from .protocols import Pivot, Protocol, ProtocolError

__all__ = [
    "paper_heavy_precession_rates",
    "corrected_heavy_precession_rates",
    "exact_steady_precession_rates",
    "fast_top_release",
    "paper_free_precession_rate",
    "exact_free_precession_rate",
    "paper_free_precession_rate_launch_frame",
    "paper_free_nutation_amplitude_launch_frame",
    "paper_damped_tilt_rate",
    "corrected_damped_tilt_rate",
    "paper_damped_time_constant",
    "paper_accelerated_equilibrium_tip",
    "exact_accelerated_equilibrium_tip",
    "fast_top_ratio",
    "measure_nutation",
    "measure_tilt_growth_rate",
    "measure_precession_growth_rate",
    "measure_cone_axis",
    "NutationMeasurement",
]


# --------------------------------------------------------------------------------------
# heavy top: steady precession (eqs. 18-20)


def _quadratic_roots(a2: float, a1: float, a0: float) -> tuple[float, float]:
    """Real roots of ``a2 x^2 + a1 x + a0`` ordered (smaller |x|, larger |x|); NaN if complex."""
    if a2 == 0.0:
        return (-a0 / a1, math.nan)
    disc = a1 * a1 - 4.0 * a2 * a0
    if disc < 0.0:
        return (math.nan, math.nan)
    q = -0.5 * (a1 + math.copysign(math.sqrt(disc), a1 if a1 != 0 else 1.0))
    r1, r2 = (a0 / q if q != 0 else 0.0), q / a2
    return (r1, r2) if abs(r1) <= abs(r2) else (r2, r1)


def paper_heavy_precession_rates(spin_rad_s: float, *, inertia: float, inertia_axial: float,
                                 mgh: float) -> tuple[float, float]:
    """Eq. (20) as printed: ``(Io - I) phi'^2 + Io Omega phi' + Mgh = 0``; (slow, fast) roots. [rad/s]

    The ``+Mgh`` sign is wrong (see :func:`corrected_heavy_precession_rates`): the slow
    root comes out with the opposite sense to the spin.
    """
    return _quadratic_roots(inertia_axial - inertia, inertia_axial * spin_rad_s, mgh)


def corrected_heavy_precession_rates(spin_rad_s: float, *, inertia: float, inertia_axial: float,
                                     mgh: float) -> tuple[float, float]:
    """Eq. (20) with the gravity torque's sign corrected: ``(Io - I) phi'^2 + Io Omega phi' - Mgh = 0``.

    Small-tilt form (``cos theta = 1``); slow root ``~ Mgh / (Io Omega)``, fast root
    ``~ Io Omega / (I - Io)``. [rad/s]
    """
    return _quadratic_roots(inertia_axial - inertia, inertia_axial * spin_rad_s, -mgh)


def exact_steady_precession_rates(spin_rad_s: float, tilt_rad: float, *, inertia: float, inertia_axial: float,
                                  mgh: float) -> tuple[float, float]:
    """Exact steady precession at finite tilt: ``Mgh = phi' (Io omega_o - I phi' cos theta)``.

    With ``omega_o = Omega + phi' cos theta``: ``(Io - I) cos(theta) phi'^2 + Io Omega phi' - Mgh = 0``
    (Goldstein 3rd ed. eq. 5.76 rearranged).  (slow, fast); NaN where no steady precession exists: at a
    horizontal axis the condition is linear and has no fast root. [rad/s]
    """
    cos_tilt = math.cos(tilt_rad)
    if abs(cos_tilt) < 1e-12:  # 90 degrees in radians leaves a cosine of 6e-17: the axis is horizontal
        cos_tilt = 0.0
    return _quadratic_roots((inertia_axial - inertia) * cos_tilt, inertia_axial * spin_rad_s, -mgh)


# --------------------------------------------------------------------------------------
# heavy top released from rest: standard fast-top results (Goldstein sec. 5.7)


def fast_top_ratio(spin_rad_s: float, *, inertia: float, inertia_axial: float, mgh: float) -> float:
    """``(Io Omega)^2 / (4 I Mgh)``: the fast-top formulas hold when this is large (>~ 10)."""
    return (inertia_axial * spin_rad_s) ** 2 / (4.0 * inertia * mgh) if mgh > 0 else math.inf


def fast_top_release(spin_rad_s: float, tilt_rad: float, *, inertia: float, inertia_axial: float,
                     mgh: float) -> dict[str, float]:
    """Fast-top approximations for a release from rest at tilt ``theta0``.

    Returns ``nutation_frequency_rad_s = Io Omega / I`` (the paper's ``Omega - nu`` for the
    slow mode), ``nutation_amplitude_rad = I Mgh sin(theta0) / (Io Omega)^2`` (half the
    tilt range), ``mean_precession_rate_rad_s = Mgh / (Io Omega)``.
    """
    l3 = inertia_axial * spin_rad_s
    return {
        "nutation_frequency_rad_s": abs(l3) / inertia,
        "nutation_amplitude_rad": inertia * mgh * math.sin(tilt_rad) / l3**2,
        "mean_precession_rate_rad_s": mgh / l3,
    }


# --------------------------------------------------------------------------------------
# free top (eq. 12)


def paper_free_precession_rate(spin_rad_s: float, *, inertia: float, inertia_axial: float) -> float:
    """Eq. (12): ``phi' = Io Omega / (I - Io)``, precession about the angular momentum. [rad/s]

    ``Omega`` is ``psi'`` measured in the frame whose ``z`` is along ``L``.  Exact up to a
    factor ``cos(cone angle)``: ``phi' = Io Omega / ((I - Io) cos(alpha))``.
    """
    return inertia_axial * spin_rad_s / (inertia - inertia_axial)


def paper_free_precession_rate_launch_frame(omega_o_rad_s: float, *, inertia: float, inertia_axial: float) -> float:
    """Eq. (15) ``phi' = Io Omega' / (2 I - Io)`` with ``Omega' = omega_o - phi'`` (its own frame): ``Io omega_o / (2 I)``.

    In the frame whose ``z`` is the launch axis (the paper's ``C = 0`` choice), ``Omega'`` is
    ``psi'`` there; with ``theta' ~ 0``, ``omega_o = Omega' + phi'``. [rad/s]
    """
    return inertia_axial * omega_o_rad_s / (2.0 * inertia)


def paper_free_nutation_amplitude_launch_frame(omega_perp0_rad_s: float, omega_o_rad_s: float, *, inertia: float,
                                               inertia_axial: float) -> float:
    """Eq. (16): amplitude ``(2 I - Io) |omega_00| / (Io Omega')`` of theta in the launch-axis frame. [rad]

    With ``Omega' = omega_o (2 I - Io) / (2 I)`` (see :func:`paper_free_precession_rate_launch_frame`)
    this is ``2 I |omega_perp(0)| / (Io omega_o)``: twice the small cone angle.
    """
    omega_prime = omega_o_rad_s * (2.0 * inertia - inertia_axial) / (2.0 * inertia)
    return (2.0 * inertia - inertia_axial) * omega_perp0_rad_s / (inertia_axial * abs(omega_prime))


def exact_free_precession_rate(angular_momentum: float, *, inertia: float) -> float:
    """Coning rate of the axis about the fixed angular momentum: ``|L| / I``. [rad/s]"""
    return angular_momentum / inertia


# --------------------------------------------------------------------------------------
# damped, spin-compensated top (eqs. 25-26)


def paper_damped_tilt_rate(spin_rad_s: float, gamma_per_s: float, *, inertia: float, inertia_axial: float,
                           mgh: float) -> float:
    """Eq. (25a) as printed, slow mode (``Omega - nu = Io Omega / I``): ``theta'/theta``. [1/s]

    ``-gamma Mgh / (I (gamma^2 + (Io Omega / I)^2))``: negative, the paper's "levitation".
    The sign is wrong: see :func:`corrected_damped_tilt_rate`.
    """
    w = inertia_axial * spin_rad_s / inertia
    return -gamma_per_s * mgh / (inertia * (gamma_per_s**2 + w**2))


def corrected_damped_tilt_rate(spin_rad_s: float, gamma_per_s: float, *, inertia: float, inertia_axial: float,
                               mgh: float) -> float:
    """Eq. (25a) with the gravity torque's sign corrected: the tilt *grows*. [1/s]

    ``+gamma Mgh / (I (gamma^2 + (Io Omega / I)^2))`` (small tilt, slow mode).
    """
    return -paper_damped_tilt_rate(spin_rad_s, gamma_per_s, inertia=inertia, inertia_axial=inertia_axial, mgh=mgh)


def paper_damped_time_constant(spin_rad_s: float, gamma_per_s: float, *, inertia: float, inertia_axial: float,
                               mgh: float) -> float:
    """Eq. (26): ``tau = (I^2 gamma^2 + Io^2 Omega^2) / (gamma I Mgh)``. [s]

    The paper calls it the decay time of the tilt; with the corrected sign it is the
    e-folding time of its growth.  Without transverse damping (``gamma = 0``: a drag on the spin alone) infinite.
    """
    if gamma_per_s == 0.0:
        return math.inf
    return (inertia**2 * gamma_per_s**2 + inertia_axial**2 * spin_rad_s**2) / (gamma_per_s * inertia * mgh)


# --------------------------------------------------------------------------------------
# accelerated pivot (eq. 31)


def paper_accelerated_equilibrium_tip(acceleration_m_s2: float, gravity_m_s2: float) -> np.ndarray:
    """Eq. (31) for a pivot accelerating with magnitude ``a`` along ``-x``: ``phi = pi/2, theta = a/g``.

    Returned as the unit tip vector ``(sin th sin ph, -sin th cos ph, cos th)``: it leans
    towards ``+x``, i.e. *against* the acceleration, contradicting the paper's own text
    ("in the direction of the acceleration").
    """
    th = acceleration_m_s2 / gravity_m_s2
    return np.array([math.sin(th), 0.0, math.cos(th)])


def exact_accelerated_equilibrium_tip(acceleration_m_s2: tuple[float, float, float] | np.ndarray,
                                      gravity_m_s2: float) -> np.ndarray:
    """Effective vertical ``-(g_vec - a)/|g_vec - a|``: the axis the top precesses about.

    For ``a`` along ``-x`` it is ``theta = atan(a/g)``, ``phi = -pi/2`` (leaning towards ``-x``).
    """
    g_eff = np.array([0.0, 0.0, -gravity_m_s2]) - np.asarray(acceleration_m_s2, dtype=float)
    return -g_eff / np.linalg.norm(g_eff)


# --------------------------------------------------------------------------------------
# measurements from a simulated trajectory (the simulator is the judge)


@dataclass(frozen=True)
class NutationMeasurement:
    """Nutation seen in a trajectory: from the maxima and minima of theta(t).

    Attributes
    ----------
    frequency_rad_s : float
        ``2 pi / (mean spacing of maxima)``.
    amplitude_rad : float
        Half of (mean maximum - mean minimum) of theta.
    mean_precession_rate_rad_s : float
        phi advance between the first and last maximum over the time between them.
    n_periods : int
    """

    frequency_rad_s: float
    amplitude_rad: float
    mean_precession_rate_rad_s: float
    n_periods: int


def _peaks(y: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Times and values of interior local maxima, refined by a parabola through 3 samples."""
    i = np.where((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:]))[0] + 1
    y0, y1, y2 = y[i - 1], y[i], y[i + 1]
    den = y0 - 2 * y1 + y2
    off = np.where(den != 0, 0.5 * (y0 - y2) / np.where(den != 0, den, 1.0), 0.0)
    dt = t[1] - t[0]
    return t[i] + off * dt, y1 - 0.25 * (y0 - y2) * off


def measure_nutation(trajectory: pd.DataFrame) -> NutationMeasurement:
    """Measure nutation frequency, amplitude and mean precession from ``theta(t), phi(t)``.

    Needs uniform sampling with at least ~30 samples per nutation period and several
    periods.  Raises ``ValueError`` when fewer than 2 full periods are seen.
    """
    t = trajectory.t_s.to_numpy()
    th = trajectory.theta_rad.to_numpy()
    tmax, vmax = _peaks(th, t)
    tmin, vmin = _peaks(-th, t)
    if len(tmax) < 3 or len(tmin) < 2:
        raise ValueError("fewer than 2 nutation periods in the trajectory")
    period = (tmax[-1] - tmax[0]) / (len(tmax) - 1)
    phi = np.interp(tmax[[0, -1]], t, trajectory.phi_rad.to_numpy())
    return NutationMeasurement(
        frequency_rad_s=2 * math.pi / period,
        amplitude_rad=0.5 * (float(np.mean(vmax)) + float(np.mean(vmin))),
        mean_precession_rate_rad_s=float((phi[1] - phi[0]) / (tmax[-1] - tmax[0])),
        n_periods=len(tmax) - 1,
    )


def measure_tilt_growth_rate(trajectory: pd.DataFrame, *, axis: np.ndarray | None = None) -> float:
    """Exponential rate of the tilt, ``d ln(theta) / dt`` by least squares over the run. [1/s]

    ``theta`` is measured from ``axis`` (default ``z``).  Positive: the tilt grows.
    """
    tip = trajectory[["tip_x", "tip_y", "tip_z"]].to_numpy()
    up = np.array([0.0, 0.0, 1.0]) if axis is None else np.asarray(axis, dtype=float)
    tilt = np.arctan2(np.linalg.norm(np.cross(tip, up), axis=1), tip @ up)
    return float(np.polyfit(trajectory.t_s.to_numpy(), np.log(tilt), 1)[0])


def measure_precession_growth_rate(trajectory: pd.DataFrame) -> float:
    """Exponential rate of the precession rate, ``d ln(phi') / dt`` by least squares over the run (a run without
    nutation: a steady launch). [1/s]"""
    t = trajectory.t_s.to_numpy()
    rate = np.gradient(np.unwrap(trajectory.phi_rad.to_numpy()), t)
    return float(np.polyfit(t, np.log(np.abs(rate)), 1)[0])


def measure_cone_axis(trajectory: pd.DataFrame) -> np.ndarray:
    """Axis of the cone the tip sweeps: normal of the least-squares plane through the tip points.

    Independent of how many precession periods the run covers; oriented upwards.
    """
    tip = trajectory[["tip_x", "tip_y", "tip_z"]].to_numpy()
    _, _, vt = np.linalg.svd(tip - tip.mean(axis=0), full_matrices=False)
    axis = vt[-1]
    return axis if axis @ tip.mean(axis=0) > 0 else -axis


def steady_launch(protocol: Protocol, *, mode: str = "slow") -> Protocol:
    """The protocol relaunched in steady precession at its launch tilt (no nutation).

    The steady rate is found with the *simulator*, not a closed form: ``theta0`` is a
    turning point of every launch with ``theta' = 0``, so the tilt stays on one side of
    it, rising if the precession is too fast and dipping if too slow; the steady rate is
    the root of the mean tilt change over one nutation period.  The exact finite-tilt
    condition only brackets the search (+-40 %).

    Parameters
    ----------
    protocol : Protocol
        Damping and pivot acceleration are ignored for the search.
    mode : {"slow", "fast"}
    """
    rig, lau = protocol.rig, protocol.launch
    undamped = replace(protocol, pivot=Pivot())
    kw = dict(inertia=rig.inertia_transverse_kg_m2, inertia_axial=rig.inertia_axial_kg_m2, mgh=rig.mgh_N_m)
    roots = exact_steady_precession_rates(lau.spin_rate_rad_s, lau.tilt_rad, **kw)
    guess = roots[0] if mode == "slow" else roots[1]
    if not math.isfinite(guess):
        raise ValueError(f"no steady {mode} precession exists at tilt {lau.tilt_rad:.4g} rad for this spin")
    if abs(math.sin(lau.tilt_rad)) < 1e-12:  # on the vertical the axis stays put whatever the rate: nothing to search
        return replace(protocol, launch=replace(lau, tilt_rate_rad_s=0.0, precession_rate_rad_s=guess))
    l3 = abs(rig.inertia_axial_kg_m2 * lau.spin_rate_rad_s)
    scale = max(l3 / rig.inertia_transverse_kg_m2, abs(guess), 1e-3)
    t = np.linspace(0.0, 2 * math.pi / scale, 101)

    def mean_tilt_change(rate: float) -> float:
        p = replace(undamped, launch=replace(lau, tilt_rate_rad_s=0.0, precession_rate_rad_s=rate))
        df = simulate(p, method="gyro", rtol=1e-12, atol=1e-14, t_eval_s=t)
        return float(df.theta_rad.mean() - lau.tilt_rad)

    lo, hi = sorted((0.6 * guess, 1.4 * guess))
    rate = brentq(mean_tilt_change, lo, hi, xtol=1e-13 * abs(guess), rtol=1e-12)
    return replace(protocol, launch=replace(lau, tilt_rate_rad_s=0.0, precession_rate_rad_s=rate))


# --------------------------------------------------------------------------------------
# predictions for one protocol (``gyrorig theory PROTOCOL``)


def _entry(name: str, paper: float | None, exact: float, *, source: str, corrected: float | None = None,
           note: str = "") -> PredictedQuantity:
    """One quantity: paper value, corrected value, exact/simulated value."""
    return PredictedQuantity(name=name, paper=None if paper is None else float(paper), exact=float(exact),
                             exact_source=source, corrected=None if corrected is None else float(corrected),
                             note=note)


def _direction(rate_per_s: float, tiny: float = 1e-9) -> str:
    """'growth', 'decay' or 'none' for a signed exponential rate."""
    if not math.isfinite(rate_per_s) or abs(rate_per_s) <= tiny:
        return "none"
    return "growth" if rate_per_s > 0 else "decay"


def _damping_gamma(protocol: Protocol) -> tuple[float, str]:
    """Equivalent paper gamma of the scene's damping, and which law it is."""
    i_t = protocol.rig.inertia_transverse_kg_m2
    gamma, laws = 0.0, []
    for d in protocol.pivot.damping:
        laws.append(d.model)
        gamma += d.coefficient(i_t) / i_t
    return gamma, "+".join(laws)


def _damped_predictions(protocol: Protocol, a_vec: np.ndarray, g: float, kw: dict,
                        simulate_damping: bool) -> list[PredictedQuantity]:
    """The damped tilt's growth rate and time constant: the paper's, corrected, and simulated."""
    spin, acc = protocol.launch.spin_rate_rad_s, protocol.pivot.acceleration
    gamma, law = _damping_gamma(protocol)
    paper_rate = paper_damped_tilt_rate(spin, gamma, **kw)
    corr_rate = corrected_damped_tilt_rate(spin, gamma, **kw)
    sim_rate = growth = math.nan
    source = "simulator, from steady slow precession at the launch tilt"
    on_vertical = acc is None and abs(math.sin(protocol.launch.tilt_rad)) < 1e-12
    if on_vertical:
        source = "none: the launch is on the vertical and stays there (no tilt to grow)"
    elif simulate_damping and (acc is None or acc.is_constant):
        up = exact_accelerated_equilibrium_tip(a_vec, g)
        if acc is None:
            try:
                start = steady_launch(protocol)
            except ValueError:  # the spin is too slow for a steady precession at this tilt: the top falls
                start = None
                source = "none: no steady slow precession at the launch tilt for this spin (the top is too slow)"
        else:
            start, source = protocol, "simulator, from the protocol's launch (about the effective vertical)"
        if start is not None:
            df = simulate(start, duration_s=min(protocol.scene.duration_s, 20.0), rate_hz=20.0)
            sim_rate = measure_tilt_growth_rate(df, axis=up)
            growth = measure_precession_growth_rate(df) if acc is None else math.nan
    note = f"damping law {law}; paper eq. 25a with gamma = {gamma:.4g} 1/s (slow mode)"
    if law != "paper" and law != "magnet-in-ball":
        note += "; the paper's law differs from this scene's, compare with the simulated value"
    tau = paper_damped_time_constant(spin, gamma, **kw)
    spin_decay = rotor_spin_decay_rate_per_s(protocol)
    # measured about the lab's vertical: a pivot that accelerates precesses about another
    growth_source = source if acc is None else "none: the pivot accelerates (the precession is about another axis)"
    spin_down = [_entry("precession_growth_rate_per_s", spin_decay, growth, source=growth_source,
                        note="the rotor's spin decays (a drag no motor holds) at this rate, 1/s: eq. 20's "
                             "precession, Mgh / (Io omega), grows at it")] if spin_decay > 0 else []
    return spin_down + [_entry("tilt_growth_rate_per_s", paper_rate, sim_rate, source=source, corrected=corr_rate,
                               note=note),
            PredictedQuantity("tilt_time_constant_s", paper=tau, exact=1.0 / abs(sim_rate) if sim_rate else math.inf,
                              exact_source="1 / |simulated growth rate|", direction_paper="decay",
                              direction_exact=_direction(sim_rate),
                              note="eq. 26; with the corrected sign it is the e-folding time of the tilt's growth")]


def predict(protocol: Protocol, *, simulate_damping: bool = True) -> Prediction:
    """What theory predicts for the scene: only the quantities the scene has.

    Parameters
    ----------
    protocol : Protocol
    simulate_damping : bool
        Measure the damped tilt growth rate with the simulator (a run of up to 20 s).

    Returns
    -------
    Prediction
        ``flags`` (:class:`~gyrorig.prediction.PredictionFlags`) and, per quantity, a
        :class:`~gyrorig.prediction.PredictedQuantity` with ``paper`` (as printed), ``corrected`` (where the
        printed form is wrong) and ``exact`` (no approximation; from the elliptic solution, an exact condition
        or the simulator, named in ``exact_source``): ``precession_rate_slow_rad_s``,
        ``precession_rate_fast_rad_s``, ``nutation_frequency_rad_s``, ``nutation_amplitude_rad``,
        ``mean_precession_rate_rad_s``, ``tilt_growth_rate_per_s``, ``tilt_time_constant_s``,
        ``precession_growth_rate_per_s`` (a rotor a drag slows), ``precession_rate_rad_s`` (free top);
        ``equilibrium_tip`` with the pivot accelerating.
    """
    rig, lau = protocol.rig, protocol.launch
    i_t, i_o = rig.inertia_transverse_kg_m2, rig.inertia_axial_kg_m2
    spin, tilt = lau.spin_rate_rad_s, lau.tilt_rad
    if spin == 0.0 and protocol.has_gravity:
        raise ProtocolError("launch.spin_rate_rad_s = 0: the paper's formulas are for a spinning top (a heavy "
                            "top without spin is a pendulum); allowed: any non-zero spin (simulate still runs it)")
    acc = protocol.pivot.acceleration
    a_vec = np.zeros(3) if acc is None else np.asarray(acc.acceleration_m_s2[0], dtype=float)
    g = rig.gravity_m_s2 or 0.0
    mgh_eff = rig.mass_kg * rig.com_distance_m * float(np.linalg.norm(np.array([0, 0, -g]) - a_vec))
    kw = dict(inertia=i_t, inertia_axial=i_o, mgh=mgh_eff)
    undamped = replace(protocol, pivot=Pivot((), acc if acc is not None and acc.is_constant else None))
    if mgh_eff == 0.0:
        sol = exact_solution(undamped)
        ell = sol.l_over_i * i_t
        l_norm = float(np.linalg.norm(ell))
        cos_alpha = float(ell @ np.array([math.sin(tilt) * math.sin(lau.azimuth_rad),
                                          -math.sin(tilt) * math.cos(lau.azimuth_rad), math.cos(tilt)])) / l_norm
        spin_l = sol.omega_rotor_rad_s - (l_norm / i_t) * cos_alpha  # psi' in the frame with z along L
        free = _entry("precession_rate_rad_s", paper_free_precession_rate(spin_l, inertia=i_t, inertia_axial=i_o),
                      exact_free_precession_rate(l_norm, inertia=i_t), source="exact: |L|/I",
                      note="eq. 12 with Omega = psi' in the frame whose z is along L")
        return Prediction(protocol.name, PredictionFlags(cone_angle_rad=math.acos(max(-1.0, min(1.0, cos_alpha)))),
                          {free.name: free})
    ratio = fast_top_ratio(spin, **kw)
    flags = PredictionFlags(fast_top_ratio=ratio, fast_top=ratio >= 10.0, small_tilt=tilt <= 0.3,
                            launch_tilt_rad=tilt)
    slow_p, fast_p = paper_heavy_precession_rates(spin, **kw)
    slow_c, fast_c = corrected_heavy_precession_rates(spin, **kw)
    slow_x, fast_x = exact_steady_precession_rates(spin, tilt, **kw)
    src = "exact steady-precession condition at the launch tilt"
    qs = [_entry("precession_rate_slow_rad_s", slow_p, slow_x, source=src, corrected=slow_c),
          _entry("precession_rate_fast_rad_s", fast_p, fast_x, source=src, corrected=fast_c)]
    if acc is None or acc.is_constant:
        sol = exact_solution(undamped)
        ft = fast_top_release(spin, tilt, **kw)
        l3 = i_o * sol.omega_rotor_rad_s + (rig.frame_axial_inertia_kg_m2 or 0.0) * (sol.omega_frame_rad_s or 0.0)
        homog = math.hypot(lau.tilt_rate_rad_s, (lau.precession_rate_rad_s - slow_c) * math.sin(tilt))
        amp = homog * i_t / abs(l3)
        th_lo, th_hi = sol.tilt_range_rad
        src = "exact elliptic solution (undamped)"
        qs += [_entry("nutation_frequency_rad_s", ft["nutation_frequency_rad_s"], sol.nutation_frequency_rad_s,
                      source=src, note="paper: Omega - nu = Io Omega / I"),
               _entry("nutation_amplitude_rad", amp, 0.5 * (th_hi - th_lo), source=src,
                      note="fast-top: I |omega_perp(0) - slow steady| / L3 (half range)"),
               _entry("mean_precession_rate_rad_s", ft["mean_precession_rate_rad_s"], sol.mean_precession_rate_rad_s,
                      source=src, note="fast-top: Mgh / (Io Omega)")]
    if protocol.is_damped:
        qs += _damped_predictions(protocol, a_vec, g, kw, simulate_damping)
    tip = None
    if acc is not None and acc.is_constant and np.linalg.norm(a_vec[:2]) > 0:
        a_h = float(np.linalg.norm(a_vec[:2]))
        paper_tip = paper_accelerated_equilibrium_tip(a_h, g)
        # eq. 31 is for a along -x; rotate it to the scene's horizontal acceleration direction
        ang = math.atan2(a_vec[1], a_vec[0]) - math.pi
        rot = np.array([[math.cos(ang), -math.sin(ang), 0], [math.sin(ang), math.cos(ang), 0], [0, 0, 1]])
        exact_tip = exact_accelerated_equilibrium_tip(a_vec, g)
        p_tip = rot @ paper_tip
        tip = EquilibriumTip(
            paper=tuple(float(v) for v in p_tip), exact=tuple(float(v) for v in exact_tip),
            exact_source="effective vertical",
            angle_between_rad=float(math.acos(min(1.0, float(p_tip @ exact_tip)))),
            paper_leans_towards_acceleration=bool(p_tip[:2] @ a_vec[:2] > 0),
            exact_leans_towards_acceleration=bool(exact_tip[:2] @ a_vec[:2] > 0),
            note="eq. 31: phi = pi/2, theta = a/g for a along -x")
    return Prediction(protocol.name, flags, {q.name: q for q in qs}, equilibrium_tip=tip)
