"""Judge every closed form of the paper against the simulator over parameter sweeps.

``validate(quick=...)`` returns a table with one row per (formula, parameter point):
the paper's value as printed, the corrected value where the printed form is wrong,
the exact value where one exists, and the value *measured by the simulator* (the
judge).  Relative errors and sign agreement are computed against the simulator.
``summarize`` condenses it to one verdict per formula.  ``gyrorig theory --validate``
writes both as CSV and Markdown, with plots.

The test top is the benchmark top of issue 4 (I = 1, Io = 0.6, M = 1, h = 0.1,
g = 9.81 in SI units); its spin is set from the fast-top ratio
``r = (Io Omega)^2 / (4 I M g h)``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pandas as pd

from . import theory as th
from .physics import SimulationError, exact_solution, simulate
from .physics.rotations import euler_from_matrix, euler_to_matrix
from .protocols import Protocol, top_protocol

logger = logging.getLogger(__name__)

__all__ = ["validate", "summarize", "TEST_TOP", "spin_for_ratio"]

#: the benchmark top [SI]
TEST_TOP = dict(inertia=1.0, inertia_axial=0.6, mass=1.0, com=0.1, gravity=9.81)
MGH = TEST_TOP["mass"] * TEST_TOP["gravity"] * TEST_TOP["com"]

#: in-regime tolerances: the fast-top formulas are first order in 1/r and in the tilt
FAST_TOP_MIN_RATIO = 10.0
SMALL_TILT_MAX_RAD = 0.3


def spin_for_ratio(ratio: float, *, inertia: float = 1.0, inertia_axial: float = 0.6, mgh: float = MGH) -> float:
    """Spin giving the fast-top ratio ``(Io Omega)^2 / (4 I Mgh)``. [rad/s]"""
    return math.sqrt(4.0 * inertia * mgh * ratio) / inertia_axial


def _top(*, tilt: float, spin: float, tilt_rate: float = 0.0, precession_rate: float = 0.0, gravity: bool = True,
         inertia_axial: float = 0.6, acceleration: list[float] | None = None, damping: dict | None = None,
         duration: float = 10.0) -> Protocol:
    return top_protocol(tilt_rad=tilt, spin_rate_rad_s=spin, tilt_rate_rad_s=tilt_rate,
                        precession_rate_rad_s=precession_rate, gravity_m_s2=TEST_TOP["gravity"] if gravity else None,
                        inertia_axial_kg_m2=inertia_axial, acceleration_m_s2=acceleration, damping=damping,
                        duration_s=duration, name="validation")


def _rel(a: float, ref: float) -> float:
    return (a - ref) / abs(ref) if ref != 0 and math.isfinite(a) else math.nan


def _row(formula: str, equation: str, quantity: str, *, paper: float, simulator: float, corrected: float = math.nan,
         exact: float = math.nan, ratio: float = math.nan, tilt: float = math.nan, in_regime: bool = True,
         **params: float) -> dict:
    return dict(
        formula=formula, equation=equation, quantity=quantity, fast_top_ratio=ratio, tilt_rad=tilt,
        params=", ".join(f"{k}={v:.4g}" for k, v in params.items()),
        paper=paper, corrected=corrected, exact=exact, simulator=simulator,
        rel_error_paper=_rel(paper, simulator), rel_error_corrected=_rel(corrected, simulator),
        sign_agrees_paper=bool(np.sign(paper) == np.sign(simulator)),
        sign_agrees_corrected=bool(np.sign(corrected) == np.sign(simulator)) if math.isfinite(corrected) else None,
        in_regime=in_regime,
    )


# --------------------------------------------------------------------------------------
# sweeps


def _sweep_steady_precession(ratios, tilts) -> list[dict]:
    rows = []
    kw = dict(inertia=1.0, inertia_axial=0.6, mgh=MGH)
    for r in ratios:
        spin = spin_for_ratio(r)
        paper = th.paper_heavy_precession_rates(spin, **kw)
        corr = th.corrected_heavy_precession_rates(spin, **kw)
        for tilt in tilts:
            exact = th.exact_steady_precession_rates(spin, tilt, **kw)
            for k, mode in enumerate(["slow", "fast"]):
                sim = th.steady_launch(_top(tilt=tilt, spin=spin), mode=mode).launch.precession_rate_rad_s
                rows.append(_row(f"heavy top, {mode} steady precession", "20", f"precession_rate_{mode}_rad_s",
                                 paper=paper[k], corrected=corr[k], exact=exact[k], simulator=sim, ratio=r,
                                 tilt=tilt, in_regime=tilt <= SMALL_TILT_MAX_RAD and r >= FAST_TOP_MIN_RATIO,
                                 spin=spin))
    return rows


def _sweep_release(ratios, tilts) -> list[dict]:
    rows = []
    kw = dict(inertia=1.0, inertia_axial=0.6, mgh=MGH)
    for r in ratios:
        spin = spin_for_ratio(r)
        for tilt in tilts:
            p = _top(tilt=tilt, spin=spin)
            sol = exact_solution(p)
            period = 2 * math.pi / sol.nutation_frequency_rad_s
            t = np.arange(0, 12 * 80 + 1) * period / 80
            meas = th.measure_nutation(simulate(p, method="gyro", rtol=1e-11, t_eval_s=t))
            ft = th.fast_top_release(spin, tilt, **kw)
            lo, hi = sol.tilt_range_rad
            in_regime = r >= FAST_TOP_MIN_RATIO
            common = dict(ratio=r, tilt=tilt, in_regime=in_regime, spin=spin)
            rows.append(_row("release from rest: nutation frequency", "Omega - nu (11, 21)",
                             "nutation_frequency_rad_s", paper=ft["nutation_frequency_rad_s"],
                             exact=sol.nutation_frequency_rad_s, simulator=meas.frequency_rad_s, **common))
            rows.append(_row("release from rest: nutation amplitude", "Goldstein 5.7 (fast top)",
                             "nutation_amplitude_rad", paper=ft["nutation_amplitude_rad"], exact=0.5 * (hi - lo),
                             simulator=meas.amplitude_rad, **common))
            rows.append(_row("release from rest: mean precession", "20 slow root (corrected), Goldstein 5.7",
                             "mean_precession_rate_rad_s", paper=ft["mean_precession_rate_rad_s"],
                             exact=sol.mean_precession_rate_rad_s, simulator=meas.mean_precession_rate_rad_s,
                             **common))
    return rows


def _l_frame_rates(p: Protocol, duration: float) -> tuple[float, float, float]:
    """Simulate a free top; return (coning rate about L, psi' in the L frame, cone angle)."""
    df = simulate(p, method="gyro", rtol=1e-11, duration_s=duration, rate_hz=200.0)
    sol = exact_solution(p)
    ell = sol.l_over_i / np.linalg.norm(sol.l_over_i)
    zx = np.array([1.0, 0.0, 0.0]) if abs(ell[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = zx - (zx @ ell) * ell
    x /= np.linalg.norm(x)
    basis = np.column_stack([x, np.cross(ell, x), ell])
    rot = euler_to_matrix(df.phi_rad.to_numpy(), df.theta_rad.to_numpy(), df.psi_rad.to_numpy())
    ph, tl, ps = euler_from_matrix(basis.T @ rot)
    t = df.t_s.to_numpy()
    phi_rate = np.polyfit(t, np.unwrap(ph), 1)[0]
    psi_rate = np.polyfit(t, np.unwrap(ps), 1)[0]
    return float(phi_rate), float(psi_rate), float(np.mean(tl))


def _sweep_free(ratios_io, cones) -> list[dict]:
    rows = []
    spin = 40.0
    for io in ratios_io:
        for cone in cones:
            # launch: a transverse kick whose size sets the cone angle: tan(alpha) = I w / L3
            kick = math.tan(cone) * io * spin / 1.0
            p = _top(tilt=0.3, spin=spin, tilt_rate=kick, gravity=False, inertia_axial=io)
            rate_l = th.exact_free_precession_rate(float(np.linalg.norm(exact_solution(p).l_over_i)), inertia=1.0)
            coning, spin_l, alpha = _l_frame_rates(p, duration=min(10.0, 40 * 2 * math.pi / abs(rate_l)))
            paper = th.paper_free_precession_rate(spin_l, inertia=1.0, inertia_axial=io)
            rows.append(_row("free top: precession about L", "12", "precession_rate_rad_s", paper=paper,
                             exact=rate_l, simulator=coning, tilt=alpha, in_regime=alpha <= SMALL_TILT_MAX_RAD,
                             io_over_i=io, spin_in_L_frame=spin_l))
            # eqs. 15-16 in the frame whose z is the launch axis: the tip circles through that axis, so
            # phi' = (coning rate) / 2 and the largest tilt from it is twice the cone angle.  The paper's
            # Omega' is psi' in that frame, Omega' = omega_o - phi' (theta' ~ 0), which makes eq. 15
            # phi' = Io omega_o / (2 I) and eq. 16's amplitude 2 I |omega_perp(0)| / (Io omega_o).
            sol = exact_solution(p)
            omega_o = sol.omega_rotor_rad_s
            paper15 = th.paper_free_precession_rate_launch_frame(omega_o, inertia=1.0, inertia_axial=io)
            paper16 = th.paper_free_nutation_amplitude_launch_frame(abs(kick), omega_o, inertia=1.0, inertia_axial=io)
            df = simulate(p, method="gyro", rtol=1e-11, duration_s=2 * math.pi / abs(coning), rate_hz=2000.0)
            tip = df[["tip_x", "tip_y", "tip_z"]].to_numpy()
            widest = float(np.arccos(np.clip(tip @ tip[0], -1.0, 1.0)).max())
            common = dict(tilt=alpha, in_regime=alpha <= SMALL_TILT_MAX_RAD, io_over_i=io)
            rows.append(_row("free top in the launch-axis frame: precession", "15", "precession_rate_rad_s",
                             paper=paper15, exact=rate_l / 2, simulator=coning / 2, **common))
            rows.append(_row("free top in the launch-axis frame: tilt amplitude", "16", "nutation_amplitude_rad",
                             paper=paper16, exact=2 * alpha, simulator=widest, **common))
    return rows


def _sweep_damped(ratios, gammas, tilt=0.3) -> list[dict]:
    rows = []
    kw = dict(inertia=1.0, inertia_axial=0.6, mgh=MGH)
    for r in ratios:
        spin = spin_for_ratio(r)
        for gamma in gammas:
            p = _top(tilt=tilt, spin=spin, damping={"model": "paper", "gamma_per_s": gamma})
            start = th.steady_launch(p)
            corr = th.corrected_damped_tilt_rate(spin, gamma, **kw)
            duration = float(np.clip(0.3 / abs(corr), 2.0, 30.0))
            sim = th.measure_tilt_growth_rate(simulate(start, duration_s=duration, rate_hz=50.0))
            rows.append(_row("damped compensated top: tilt rate", "25a", "tilt_growth_rate_per_s",
                             paper=th.paper_damped_tilt_rate(spin, gamma, **kw), corrected=corr, simulator=sim,
                             ratio=r, tilt=tilt, in_regime=r >= FAST_TOP_MIN_RATIO, gamma=gamma, spin=spin))
            tau = th.paper_damped_time_constant(spin, gamma, **kw)
            rows.append(_row("damped compensated top: time constant", "26", "tilt_time_constant_s",
                             paper=-tau, corrected=tau, simulator=1.0 / sim, ratio=r, tilt=tilt,
                             in_regime=r >= FAST_TOP_MIN_RATIO, gamma=gamma, spin=spin))
    return rows


def _sweep_spin_down(ratios, decays, tilt=0.3) -> list[dict]:
    """A rotor slowed by a drag no motor holds (``-k omega_o``: the spin decays at ``k / Io``), launched in steady
    precession: eq. 20's ``Mgh / (Io omega)`` grows as the spin decays, at ``k / Io``; the simulator's precession
    rate's growth ``d ln(phi')/dt`` judges it."""
    rows = []
    for r in ratios:
        spin = spin_for_ratio(r)
        for decay in decays:
            p = _top(tilt=tilt, spin=spin, damping={"model": "air", "coefficient_N_m_s": 0.0,
                                                    "axial_coefficient_N_m_s": decay * 0.6, "spin_compensated": False})
            duration = float(np.clip(0.3 / decay, 2.0, 30.0))
            sim = th.measure_precession_growth_rate(simulate(th.steady_launch(p), duration_s=duration, rate_hz=50.0))
            rows.append(_row("spinning-down top: precession growth", "20", "precession_growth_rate_per_s",
                             paper=decay, simulator=sim, ratio=r, tilt=tilt, in_regime=r >= FAST_TOP_MIN_RATIO,
                             decay=decay, spin=spin))
    return rows


def _sweep_accelerated(accels, ratio=10.0) -> list[dict]:
    rows = []
    g = TEST_TOP["gravity"]
    spin = spin_for_ratio(ratio)
    for a in accels:
        paper_tip = th.paper_accelerated_equilibrium_tip(a, g)
        exact_tip = th.exact_accelerated_equilibrium_tip((-a, 0.0, 0.0), g)
        th0, ph0 = math.acos(paper_tip[2]), math.atan2(paper_tip[0], -paper_tip[1])
        # sleeping launch at the paper's equilibrium; the top precesses about the true one
        p = _top(tilt=th0, spin=spin, acceleration=[-a, 0.0, 0.0])
        p = replace(p, launch=replace(p.launch, azimuth_rad=ph0))
        mgh_eff = MGH * math.hypot(1.0, a / g)
        period = 2 * math.pi * 0.6 * spin / mgh_eff
        df = simulate(p, method="gyro", rtol=1e-10, duration_s=2 * period, rate_hz=max(50.0, 40 * 0.6 * spin / 6.28))
        axis = th.measure_cone_axis(df)
        rows.append(_row("accelerated pivot: equilibrium lean (x of tip)", "31", "equilibrium_tip_x",
                         paper=float(paper_tip[0]), exact=float(exact_tip[0]), simulator=float(axis[0]),
                         corrected=float(exact_tip[0]), ratio=ratio, tilt=math.acos(float(axis[2])),
                         in_regime=a / g <= SMALL_TILT_MAX_RAD, a_m_s2=a))
    return rows


def _phasor_rows(quick: bool) -> list[dict]:
    """The phasor formulation (eqs. 5 + 9) used as an integrator, against the exact solution."""
    rows = []
    cases = [dict(tilt=0.5, tilt_rate=1.5, precession_rate=-2.0, spin=40.0), dict(tilt=2.5, spin=20.0)]
    for c in cases[: 1 if quick else 2]:
        p = _top(duration=5.0, **c)
        t = np.linspace(0.0, 5.0, 501)
        ex = exact_solution(p, t)
        df = simulate(p, method="phasor", rtol=1e-12, atol=1e-14, t_eval_s=t)
        err = float(np.linalg.norm(df[["tip_x", "tip_y", "tip_z"]].to_numpy()
                                   - ex[["tip_x", "tip_y", "tip_z"]].to_numpy(), axis=1).max())
        rows.append(dict(formula="phasor formulation as integrator (max tip error vs exact, rad)", equation="5, 9",
                         quantity="max_tip_error_rad", tilt_rad=c["tilt"], paper=err, simulator=0.0,
                         params=f"spin={c['spin']:g}", in_regime=True, sign_agrees_paper=True))
    try:
        simulate(_top(tilt=0.0, tilt_rate=0.5, spin=30.0, duration=1.0), method="phasor")
        status = "ran"
    except SimulationError:
        status = "singular (refused) at tilt 0"
    rows.append(dict(formula="phasor formulation at a pole", equation="9", quantity="status", tilt_rad=0.0,
                     params=status, in_regime=False))
    return rows


SWEEPS: dict[str, Callable[[bool], list[dict]]] = {
    "steady precession (eq. 20)": lambda q: _sweep_steady_precession([3, 30] if q else [2, 5, 10, 30, 100],
                                                                     [0.1, 0.8] if q else [0.05, 0.1, 0.3, 0.8]),
    "release from rest": lambda q: _sweep_release([3, 30] if q else [2, 5, 10, 30, 100],
                                                  [0.1, 0.8] if q else [0.05, 0.1, 0.3, 0.8]),
    "free top (eq. 12)": lambda q: _sweep_free([0.6, 1.8] if q else [0.2, 0.6, 1.2, 1.8],
                                               [0.05] if q else [0.02, 0.1, 0.3]),
    "damped top (eqs. 25a, 26)": lambda q: _sweep_damped([5, 30] if q else [5, 30, 100],
                                                         [0.5] if q else [0.05, 0.5, 5.0]),
    "spinning-down top (eq. 20)": lambda q: _sweep_spin_down([5, 30] if q else [5, 10, 30, 100],
                                                             [0.05] if q else [0.01, 0.05]),
    "accelerated pivot (eq. 31)": lambda q: _sweep_accelerated([2.0] if q else [0.5, 2.0, 5.0]),
    "phasor formulation (eqs. 5, 9)": _phasor_rows,
}


def validate(*, quick: bool = False, progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Run every sweep; one row per formula and parameter point (see the module docstring)."""
    rows: list[dict] = []
    for name, sweep in SWEEPS.items():
        start = time.perf_counter()
        new = sweep(quick)
        for r in new:
            r["sweep"] = name
        rows += new
        if progress:
            progress(f"{name}: {len(new)} points in {time.perf_counter() - start:.1f} s")
    return pd.DataFrame(rows)


def summarize(table: pd.DataFrame) -> pd.DataFrame:
    """One verdict per formula: worst relative error in its regime, and sign agreement everywhere."""
    out = []
    for (formula, eq), g in table.groupby(["formula", "equation"], sort=False):
        if g.quantity.iloc[0] in ("status", "max_tip_error_rad"):
            verdict = g.params.iloc[0] if g.quantity.iloc[0] == "status" else (
                f"exact reformulation: max tip error {g.paper.max():.1e} rad")
            out.append(dict(formula=formula, equation=eq, points=len(g), max_rel_error_in_regime=math.nan,
                            max_rel_error_corrected_in_regime=math.nan, sign_agrees_paper="", verdict=verdict))
            continue
        reg = g[g.in_regime.astype(bool)]
        err_p = float(np.nanmax(np.abs(reg.rel_error_paper))) if len(reg) else math.nan
        err_c = float(np.nanmax(np.abs(reg.rel_error_corrected))) if len(reg) and reg.rel_error_corrected.notna().any() \
            else math.nan
        signs = bool(g.sign_agrees_paper.all())
        if not signs:
            verdict = "DISAGREES: wrong sign/direction"
            if math.isfinite(err_c) and bool(g.sign_agrees_corrected.fillna(False).all()):
                verdict += f"; corrected form agrees ({err_c:.1%} in regime)"
        elif err_p <= 0.1:
            verdict = f"agrees within its approximation ({err_p:.1%} in regime)"
        else:
            verdict = f"right sign, {err_p:.0%} off in regime"
        out.append(dict(formula=formula, equation=eq, points=len(g), max_rel_error_in_regime=err_p,
                        max_rel_error_corrected_in_regime=err_c,
                        sign_agrees_paper=f"{int(g.sign_agrees_paper.sum())}/{len(g)}", verdict=verdict))
    return pd.DataFrame(out)
