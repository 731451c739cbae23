"""Synthetic lab tables from the simulator, and the identification benchmark (``gyrorig bench identify``).

The true values of each row come from simulating the rig (never from the formulas ``gyrorig identify`` fits): a
precession period is the mean azimuth rate of a simulated top launched in steady precession at the row's tilt (a
wrong steady-precession formula shows as nutation and a different mean rate); a nutation frequency is measured
from the tilt maxima of a simulated release from rest, or of a kick (with the tilt's extremes); a balanced gyro's
nutation (``balanced-gyro``: centre of mass on the pivot, kicked) is the rate at which its simulated axis circles
its mean direction, with the cone's half-angle; a gyro in gimbals (``gimbal-gyro``) is simulated by
:mod:`gyrorig.physics.gimbal`; a spin-down curve is integrated from ``d omega/dt = -k omega - f`` by scipy.  Noise
of the stated standard deviations is then added to the observed values and to the recorded conditions, and the
priors are drawn about the truth with their own standard deviations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from ..identify import identify_parameters, observations_from_table, read_table
from ..gimbals import Gimbal, gimbal_nutation_frequency, gimbal_precession_rate
from ..identify.estimate import prior_rig_values
from ..identify.observations import rig_with
from ..parameters import Uncertainty
from ..physics import simulate
from ..physics.gimbal import simulate_gimbal
from ..protocols import Launch, Protocol, load_protocol, BUNDLED_PROTOCOL_DIR
from ..theory import exact_steady_precession_rates

__all__ = ["SyntheticRig", "simulated_precession_period", "simulated_nutation_frequency", "simulated_circling_rate",
           "simulated_kicked_nutation",
           "synthetic_tables",
           "identify_pulls", "RIGS"]


def simulated_precession_period(rig: Protocol, spin_rad_s: float, tilt_rad: float, added_mass_kg: float = 0.0,
                                lever_arm_m: float = 0.0) -> float:
    """Period of the mean azimuth motion of the rig launched in steady precession at the tilt. [s]"""
    p = rig_with(rig, {}, added_mass_kg, lever_arm_m)
    slow, _ = exact_steady_precession_rates(spin_rad_s, tilt_rad, inertia=p.rig.inertia_transverse_kg_m2,
                                            inertia_axial=p.rig.inertia_axial_kg_m2, mgh=p.rig.mgh_N_m)
    launch = Launch(tilt_rad=tilt_rad, azimuth_rad=0.0, tilt_rate_rad_s=0.0, precession_rate_rad_s=slow,
                    spin_rate_rad_s=spin_rad_s)
    duration = min(2 * math.pi / abs(slow), 2.0)
    df = simulate(replace(p, launch=launch), duration_s=duration, rate_hz=2000.0, rtol=1e-11)
    phi = np.unwrap(df.phi_rad.to_numpy())
    rate = np.polyfit(df.t_s.to_numpy(), phi, 1)[0]
    return 2 * math.pi / abs(rate)


def simulated_nutation_frequency(rig: Protocol, spin_rad_s: float, tilt_rad: float, added_mass_kg: float = 0.0,
                                 lever_arm_m: float = 0.0, periods: int = 12) -> float:
    """Nutation frequency of the rig released from rest at the tilt, from the simulated tilt maxima. [rad/s]"""
    p = rig_with(rig, {}, added_mass_kg, lever_arm_m)
    guess = p.rig.inertia_axial_kg_m2 * spin_rad_s / p.rig.inertia_transverse_kg_m2
    launch = Launch(tilt_rad=tilt_rad, azimuth_rad=0.0, tilt_rate_rad_s=0.0, precession_rate_rad_s=0.0,
                    spin_rate_rad_s=spin_rad_s)
    duration = (periods + 1.5) * 2 * math.pi / guess
    rate = 400 * guess / (2 * math.pi)
    df = simulate(replace(p, launch=launch), duration_s=duration, rate_hz=rate, rtol=1e-11)
    return _peak_frequency(df.t_s.to_numpy(), df.theta_rad.to_numpy())


def simulated_circling_rate(rig: Protocol, spin_rad_s: float, tilt_rad: float, kick_rad_s: float
                            ) -> tuple[float, float]:
    """A kicked top (tilt rate ``kick_rad_s`` at the tilt) simulated for 1 s: the rate at which its axis circles its
    mean direction [rad/s] and the cone's half-angle about it [rad].  For a balanced rig the mean direction is the
    angular momentum and the circling its torque-free nutation."""
    launch = Launch(tilt_rad=tilt_rad, azimuth_rad=0.0, tilt_rate_rad_s=kick_rad_s, precession_rate_rad_s=0.0,
                    spin_rate_rad_s=spin_rad_s)
    df = simulate(replace(rig, launch=launch), duration_s=1.0, rate_hz=4000.0, rtol=1e-11)
    tip = df[["tip_x", "tip_y", "tip_z"]].to_numpy()
    axis = tip.mean(axis=0) / np.linalg.norm(tip.mean(axis=0))
    e1 = np.cross(axis, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    rate = np.polyfit(df.t_s.to_numpy(), np.unwrap(np.arctan2(tip @ e2, tip @ e1)), 1)[0]
    return float(abs(rate)), float(np.mean(np.arccos(np.clip(tip @ axis, -1.0, 1.0))))


def simulated_gimbal_nutation(rig: Protocol, spin_rad_s: float, tilt_rad: float, kick_rad_s: float,
                              added_outer_inertia_kg_m2: float = 0.0, periods: int = 12) -> float:
    """A balanced gyro in gimbals kicked at the tilt (``rig.gimbal``, cylinders of ``added_outer_inertia_kg_m2`` on
    its outer ring): its nutation frequency from the simulated tilt maxima. [rad/s]"""
    g = replace(rig.gimbal, outer_inertia_kg_m2=rig.gimbal.outer_inertia_kg_m2 + added_outer_inertia_kg_m2)
    guess = gimbal_nutation_frequency(rig.rig, g, spin_rad_s, tilt_rad)  # sets the record's length and sampling
    launch = Launch(tilt_rad=tilt_rad, azimuth_rad=0.0, tilt_rate_rad_s=kick_rad_s, precession_rate_rad_s=0.0,
                    spin_rate_rad_s=spin_rad_s)
    df = simulate_gimbal(replace(rig, gimbal=g, launch=launch), duration_s=(periods + 1.5) * 2 * math.pi / guess,
                         rate_hz=400 * guess / (2 * math.pi))
    return _peak_frequency(df.t_s.to_numpy(), df.theta_rad.to_numpy())


def simulated_gimbal_precession_period(rig: Protocol, spin_rad_s: float, tilt_rad: float, added_mass_kg: float = 0.0,
                                       lever_arm_m: float = 0.0) -> float:
    """Period of the mean azimuth motion of a gyro in gimbals launched in steady precession at the tilt (a weight
    ``added_mass_kg`` at ``lever_arm_m`` on the spin axis). [s]"""
    p = rig_with(rig, {}, added_mass_kg, lever_arm_m)
    slow = gimbal_precession_rate(p.rig, p.gimbal, spin_rad_s, tilt_rad)
    launch = Launch(tilt_rad=tilt_rad, azimuth_rad=0.0, tilt_rate_rad_s=0.0, precession_rate_rad_s=slow,
                    spin_rate_rad_s=spin_rad_s)
    df = simulate_gimbal(replace(p, launch=launch), duration_s=min(2 * math.pi / abs(slow), 2.0), rate_hz=2000.0)
    return 2 * math.pi / abs(np.polyfit(df.t_s.to_numpy(), df.phi_rad.to_numpy(), 1)[0])


def _peak_frequency(t: np.ndarray, th: np.ndarray) -> float:
    """The frequency of a record's maxima (parabola through each sample maximum and its neighbours). [rad/s]"""
    i = np.flatnonzero((th[1:-1] > th[:-2]) & (th[1:-1] >= th[2:])) + 1
    a, b, c = th[i - 1], th[i], th[i + 1]
    peaks = t[i] + 0.5 * (a - c) / (a - 2 * b + c) * (t[1] - t[0])
    return 2 * math.pi / float(np.mean(np.diff(peaks)))


def simulated_kicked_nutation(rig: Protocol, spin_rad_s: float, tilt_rad: float, kick_rad_s: float,
                              periods: int = 12) -> tuple[float, float, float]:
    """A heavy top kicked (tilt rate ``kick_rad_s``) at the tilt, its rotor at ``omega_3 = spin_rad_s``: its
    nutation frequency [rad/s] from the simulated tilt maxima, and the tilt's extremes [rad] (parabola through the
    sampled extremes)."""
    guess = rig.rig.inertia_axial_kg_m2 * spin_rad_s / rig.rig.inertia_transverse_kg_m2
    launch = Launch(tilt_rad=tilt_rad, azimuth_rad=0.0, tilt_rate_rad_s=kick_rad_s, precession_rate_rad_s=0.0,
                    spin_rate_rad_s=spin_rad_s)
    df = simulate(replace(rig, launch=launch), duration_s=(periods + 1.5) * 2 * math.pi / guess,
                  rate_hz=400 * guess / (2 * math.pi), rtol=1e-11)
    t, th = df.t_s.to_numpy(), df.theta_rad.to_numpy()

    def extreme(v):
        i = int(np.argmax(v[1:-1])) + 1
        a, b, c = v[i - 1], v[i], v[i + 1]
        return b + 0.125 * (a - c) ** 2 / (2 * b - a - c) if 2 * b - a - c > 0 else b
    return _peak_frequency(t, th), -extreme(-th), extreme(th)


def _spin_down(t_s: np.ndarray, omega0: float, k: float, f: float) -> np.ndarray:
    sol = solve_ivp(lambda t, w: -k * w - f, (0.0, float(t_s[-1])), [omega0], t_eval=t_s, rtol=1e-12, atol=1e-12)
    return sol.y[0]


@dataclass(frozen=True)
class SyntheticRig:
    """A rig and the experiments done on it (the truth of a synthetic identification)."""

    name: str
    protocol: Protocol
    #: relative standard deviation of the priors on Io, I, h
    prior_rel_sd: float = 0.2
    precession_rows: tuple = ()     # (spin, tilt, added mass, lever arm)
    nutation_rows: tuple = ()       # (spin, tilt, added mass, lever arm)
    spin_down: tuple | None = None  # (omega0, k, f, duration)
    kicked_rows: tuple = ()         # (spin, tilt, kick): nutation of a kicked top, with its cone angle
    gimbal_rows: tuple = ()         # (spin, tilt, kick, added outer inertia): a balanced gyro in gimbals nutating
    #: rig parameters known exactly (held at the truth, no prior sd), e.g. a balanced rig's com_distance_m = 0
    held: tuple = ()


def _bundled(name: str) -> Protocol:
    return load_protocol(BUNDLED_PROTOCOL_DIR / f"{name}.toml")


def _rigs() -> dict[str, SyntheticRig]:
    air = _bundled("air-cushion-heavy-top")
    horizontal = tuple((s, math.pi / 2, m, 0.12) for s in (300.0, 400.0, 500.0) for m in (0.0, 0.02, 0.05))
    at45 = tuple((s, math.pi / 4, m, 0.12) for s in (250.0, 400.0) for m in (0.0, 0.05))
    nut = tuple((s, math.pi / 4, m, 0.12) for s in (300.0, 500.0) for m in (0.0, 0.05))
    eddy = _bundled("eddy-damped-top-b2")
    balanced = replace(air, rig=replace(air.rig, com_distance_m=0.0))
    kicked = tuple((s, 0.5, 1.5) for s in (150.0, 200.0, 260.0, 320.0, 400.0))
    gimballed = replace(balanced, gimbal=Gimbal(outer_inertia_kg_m2=4.0e-4, cross_inertia_kg_m2=2.6e-3))
    return {
        "gimbal-gyro": SyntheticRig(
            "gimbal-gyro", gimballed, 0.2, tuple((s, th, m, 0.12) for s in (300.0, 450.0)
                                                 for th in (math.pi / 2, math.pi / 3) for m in (0.03, 0.06)),
            gimbal_rows=tuple((s, th, 0.5, j) for s in (250.0, 400.0) for th in (math.pi / 2, math.pi / 3)
                              for j in (0.0, 5.0e-4)),
            held=("rig.com_distance_m",)),
        "balanced-gyro": SyntheticRig("balanced-gyro", balanced, 0.2, kicked_rows=kicked,
                                      held=("rig.com_distance_m",)),
        "air-horizontal": SyntheticRig("air-horizontal", air, 0.2, horizontal, nut, (502.65, 2e-3, 0.2, 600.0)),
        "air-45deg": SyntheticRig("air-45deg", air, 0.2, at45, nut),
        "eddy-rig": SyntheticRig("eddy-rig", eddy, 0.2, horizontal[::2] + at45, nut[:2], (400.0, 5e-3, 0.0, 300.0)),
    }


RIGS = ("air-horizontal", "air-45deg", "eddy-rig", "balanced-gyro", "gimbal-gyro")


def _truth_rows(rig: SyntheticRig) -> dict[str, list]:
    p = rig.protocol
    if p.gimbal is not None:
        return {"precession": [simulated_gimbal_precession_period(p, *r) for r in rig.precession_rows],
                "gimbal": [simulated_gimbal_nutation(p, *r) for r in rig.gimbal_rows]}
    return {"precession": [simulated_precession_period(p, *r) for r in rig.precession_rows],
            "nutation": [simulated_nutation_frequency(p, *r) for r in rig.nutation_rows],
            "kicked": [simulated_circling_rate(p, *r) for r in rig.kicked_rows]}


def synthetic_tables(rig: SyntheticRig, folder: Path, rng: np.random.Generator, truth: dict | None = None,
                     rel_sd: float = 0.005, spin_rel_sd: float = 0.003) -> tuple[list[Path], Protocol]:
    """Noisy tables of the rig's experiments in ``folder`` and a prior protocol (priors drawn about the
    truth); ``truth`` (from :func:`_truth_rows`) saves re-simulating for each draw."""
    truth = truth or _truth_rows(rig)
    folder.mkdir(parents=True, exist_ok=True)
    files = []

    def noisy(v, rel):
        return v * (1 + rel * rng.normal())
    for kind, rows_in, column in (("precession", rig.precession_rows, "precession_period_s"),
                                  ("nutation", rig.nutation_rows, "nutation_frequency_rad_s")):
        if not rows_in:
            continue
        rows = [{"spin_rad_s": noisy(s, spin_rel_sd), "spin_rad_s_sd": s * spin_rel_sd, "tilt_rad": th,
                 "added_mass_g": 1e3 * m, "lever_arm_cm": 1e2 * ell, column: noisy(y, rel_sd),
                 f"{column}_sd": y * rel_sd}
                for (s, th, m, ell), y in zip(rows_in, truth[kind])]
        files.append(folder / f"{kind}.csv")
        pd.DataFrame(rows).to_csv(files[-1], index=False)
    if rig.gimbal_rows:
        rows = [{"spin_rad_s": noisy(s, spin_rel_sd), "spin_rad_s_sd": s * spin_rel_sd, "tilt_deg": math.degrees(th),
                 "added_outer_inertia_g_cm2": 1e7 * j, "nutation_frequency_rad_s": noisy(y, rel_sd),
                 "nutation_frequency_rad_s_sd": y * rel_sd}
                for (s, th, _, j), y in zip(rig.gimbal_rows, truth["gimbal"])]
        files.append(folder / "nutation.csv")
        pd.DataFrame(rows).to_csv(files[-1], index=False)
    if rig.kicked_rows:  # a video or stroboscope gives the circling rate and the cone (to 0.2 deg)
        rows = [{"spin_rad_s": noisy(s, spin_rel_sd), "spin_rad_s_sd": s * spin_rel_sd,
                 "nutation_frequency_rad_s": noisy(y, rel_sd), "nutation_frequency_rad_s_sd": y * rel_sd,
                 "cone_angle_deg": math.degrees(cone) + 0.2 * rng.normal(), "cone_angle_deg_sd": 0.2}
                for (s, _, _), (y, cone) in zip(rig.kicked_rows, truth["kicked"])]
        files.append(folder / "nutation.csv")
        pd.DataFrame(rows).to_csv(files[-1], index=False)
    if rig.spin_down:
        w0, k, f, dur = rig.spin_down
        t = np.linspace(0.0, dur, 13)
        w = _spin_down(t, w0, k, f)
        sd = 0.002 * w0
        pd.DataFrame({"t_s": t, "spin_rad_s": w + sd * rng.normal(size=len(t)), "spin_rad_s_sd": sd}).to_csv(
            folder / "spin_down.csv", index=False)
        files.append(folder / "spin_down.csv")
    p = rig.protocol
    names, values, sds = [], [], []
    for n, v in prior_rig_values(p).items():
        if n in rig.held:
            continue
        sd = rig.prior_rel_sd * v
        names.append(n)
        values.append(v + sd * rng.normal())
        sds.append(sd)
    eye = tuple(tuple(float(i == j) for j in range(len(names))) for i in range(len(names)))
    drawn = rig_with(p, dict(zip(names, values)))
    prior = replace(p, rig=drawn.rig, gimbal=drawn.gimbal,
                    uncertainty=Uncertainty(tuple(names), tuple(values), tuple(sds), eye))
    return files, prior


def identify_pulls(rig_name: str, draws: int, folder: Path, seed: int = 0, fast_top: bool = False) -> pd.DataFrame:
    """``draws`` noisy tables of one rig identified: per draw and parameter, value, s.e., truth and pull."""
    rig = _rigs()[rig_name]
    truth_rows = _truth_rows(rig)
    rng = np.random.default_rng(seed)
    truth = {n: v for n, v in prior_rig_values(rig.protocol).items() if n not in rig.held}
    if rig.spin_down:
        truth["spin_down.viscous_rate_per_s"] = rig.spin_down[1]
        truth["spin_down.friction_rad_s2"] = rig.spin_down[2]
    r = rig.protocol.rig
    truth_derived = {"io_over_i": r.inertia_axial_kg_m2 / r.inertia_transverse_kg_m2,
                     "mgh_over_io_rad2_s2": r.mgh_N_m / r.inertia_axial_kg_m2}
    if r.mgh_N_m == 0.0:
        del truth_derived["mgh_over_io_rad2_s2"]
    rows = []
    for d in range(draws):
        files, prior = synthetic_tables(rig, folder / f"{rig_name}-{d}", rng, truth_rows)
        obs = [o for f in files for o in observations_from_table(read_table(f), prior)]
        ident = identify_parameters(obs, prior, fast_top=fast_top)
        se = ident.standard_errors
        for n, v, e in zip(ident.names, ident.values, se):
            if n in truth:
                rows.append({"rig": rig_name, "draw": d, "parameter": n, "value": v, "standard_error": e,
                             "truth": truth[n], "pull": (v - truth[n]) / e, "chi2_red": ident.chi2_red,
                             "lack_of_fit": ident.lack_of_fit, "damping_law": ident.damping_law,
                             "fast_top": fast_top})
        for k, (v, e) in ident.derived(prior).items():
            if k in truth_derived:
                rows.append({"rig": rig_name, "draw": d, "parameter": k, "value": v, "standard_error": e,
                             "truth": truth_derived[k], "pull": (v - truth_derived[k]) / e,
                             "chi2_red": ident.chi2_red, "lack_of_fit": ident.lack_of_fit,
                             "damping_law": ident.damping_law, "fast_top": fast_top})
    return pd.DataFrame(rows)
