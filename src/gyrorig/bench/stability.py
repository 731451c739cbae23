"""Numerical stability on stiff and extreme cases (``gyrorig bench stability``).

Each named case runs every method; each run is checked for

* the quaternion norm (quaternion formulations),
* the invariants the case conserves (energy, angular momentum about the effective
  vertical, axial momentum ``L3``), drift relative to their moving part (energy:
  ``max(M g_eff h, I |omega_perp|^2 / 2)``, not the constant spin energy),
* monotone energy loss where the case is damped,
* agreement with an independent reference: the exact solution where it applies,
  otherwise the implicit ``gyro-radau`` at a tight tolerance.

The verdict of a case is the verdict of the automatic method choice; every other
method's failures are listed with their reason.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..physics import SimulationError, choose_method, exact_solution, exact_solution_applies, simulate
from ..physics.invariants import invariants
from ..protocols import Protocol, top_protocol
from .methods import benchmark_top

__all__ = ["StabilityCase", "stability_cases", "run_stability", "INVARIANT_RTOL", "AGREEMENT_TOL_RAD"]

#: relative drift allowed for conserved quantities (default tolerances)
INVARIANT_RTOL = 1e-7
#: tip-direction agreement with the reference [rad]
AGREEMENT_TOL_RAD = 1e-6
#: quaternion norm drift allowed
NORM_TOL = 1e-9
#: long run: relative energy drift allowed over the whole run
LONG_RUN_ENERGY_RTOL = 1e-6

METHODS = ("auto", "gyro", "gyro-radau", "DOP853-jit", "phasor")


@dataclass(frozen=True)
class StabilityCase:
    """One extreme case: a protocol, how long to run it, what it conserves."""

    name: str
    description: str
    protocol: Protocol
    duration_s: float
    conserved: tuple[str, ...]
    damped: bool = False
    samples: int = 2001
    methods: tuple[str, ...] = METHODS


def _top(*, tilt, spin, tilt_rate=0.0, precession_rate=0.0, inertia_axial=0.6, gravity=True, acceleration=None,
         damping=None) -> Protocol:
    return top_protocol(tilt_rad=tilt, spin_rate_rad_s=spin, tilt_rate_rad_s=tilt_rate,
                        precession_rate_rad_s=precession_rate, inertia_axial_kg_m2=inertia_axial,
                        gravity_m_s2=9.81 if gravity else None, acceleration_m_s2=acceleration, damping=damping,
                        name="stability")


ALL = ("energy_J", "l_vertical_kg_m2_s", "l_axial_kg_m2_s")


def stability_cases(quick: bool = False) -> list[StabilityCase]:
    """The named cases (``quick``: shorter runs, same cases)."""
    spin_period = 2 * math.pi / 60.0
    long_periods = 1e4 if quick else 1e6
    cases = [
        StabilityCase("very-fast-spin", "spin 2000 rad/s: spin / slow precession = 2.4e6",
                      _top(tilt=0.2, spin=2000.0), 0.5 if quick else 2.0, ALL),
        StabilityCase("damping-faster-than-precession", "paper damping gamma = 2 1/s, slow precession 0.027 rad/s",
                      _top(tilt=0.3, spin=60.0, damping={"model": "paper", "gamma_per_s": 2.0}), 5.0, ("l_axial_kg_m2_s",),
                      damped=True),
        StabilityCase("damping-faster-than-nutation", "gamma = 1000 1/s vs nutation 36 rad/s (stiff)",
                      _top(tilt=0.3, spin=60.0, damping={"model": "paper", "gamma_per_s": 1000.0}), 2.0,
                      ("l_axial_kg_m2_s",), damped=True),
        StabilityCase("damping-faster-than-spin", "gamma = 1e4 1/s vs spin 60 rad/s (very stiff)",
                      _top(tilt=0.3, spin=60.0, damping={"model": "paper", "gamma_per_s": 1e4}), 1.0,
                      ("l_axial_kg_m2_s",), damped=True),
        StabilityCase("tilt-exactly-0", "sleeping top on the Euler-angle singularity",
                      _top(tilt=0.0, spin=30.0), 5.0, ALL),
        StabilityCase("tilt-1e-12-kicked", "1e-12 rad from vertical with a tilt kick: passes through the pole",
                      _top(tilt=1e-12, tilt_rate=-0.3, spin=30.0), 5.0, ALL),
        StabilityCase("tilt-near-pi", "hanging: pi - 1e-6 rad, precessing",
                      _top(tilt=math.pi - 1e-6, spin=20.0, precession_rate=0.5), 5.0, ALL),
        StabilityCase("flat-disc", "Io / I = 1.97 (limit 2 (I - M h^2) = 1.98): eq. 15's nutation frequency blows up",
                      _top(tilt=0.5, spin=30.0, inertia_axial=1.97), 5.0, ALL),
        StabilityCase("thin-rod", "Io / I = 1e-4: almost no gyroscopic stiffness, swings as a pendulum",
                      _top(tilt=0.5, spin=60.0, inertia_axial=1e-4), 5.0, ALL),
        StabilityCase("resonance-Omega-equals-nu", "launch with phi' = Io Omega / (I - Io), i.e. Omega - nu = 0",
                      _top(tilt=0.3, spin=40.0, precession_rate=0.6 * 40.0 / 0.4), 3.0, ALL),
        StabilityCase("zero-gravity", "free top", _top(tilt=0.5, tilt_rate=1.0, spin=60.0, gravity=False), 5.0, ALL),
        StabilityCase("pivot-acceleration-20g", "pivot accelerating at 200 m/s^2 horizontally",
                      _top(tilt=0.3, spin=60.0, acceleration=[200.0, 0.0, 0.0]), 2.0, ALL),
        StabilityCase(f"long-run-{long_periods:.0e}-spin-periods",
                      f"{long_periods:.0e} spin periods at spin 60 rad/s: energy drift per period",
                      benchmark_top(60.0), long_periods * spin_period, ALL, samples=1001, methods=("auto",)),
    ]
    return cases


def _reference(case: StabilityCase, t: np.ndarray) -> tuple[pd.DataFrame | None, str]:
    ok, _ = exact_solution_applies(case.protocol)
    if ok:
        return exact_solution(case.protocol, t), "exact"
    try:
        return simulate(case.protocol, method="gyro-radau", rtol=1e-11, atol=1e-13, t_eval_s=t), \
            "gyro-radau rtol 1e-11"
    except SimulationError:
        return None, "none"


def _check(case: StabilityCase, df: pd.DataFrame, info, ref: pd.DataFrame | None) -> tuple[list[str], dict]:
    problems = []
    meas: dict = {}
    if info.formulation != "phasor":
        meas["quaternion_norm_drift"] = info.quaternion_norm_drift
        if info.quaternion_norm_drift > NORM_TOL:
            problems.append(f"|q| drift {info.quaternion_norm_drift:.2g}")
    inv = invariants(case.protocol, df)
    rig = case.protocol.rig
    # energy scale: what can move (gravity Mgh_eff and transverse kinetic energy), not the constant spin energy
    acc = case.protocol.pivot.acceleration
    a0 = np.zeros(3) if acc is None else np.asarray(acc.acceleration_m_s2[0])
    mgh_eff = rig.mass_kg * rig.com_distance_m * float(np.linalg.norm(np.array([0, 0, -(rig.gravity_m_s2 or 0)]) - a0))
    transverse = 0.5 * rig.inertia_transverse_kg_m2 * float((df.omega_d_rad_s**2 + df.omega_q_rad_s**2).max())
    scales = {"energy_J": max(mgh_eff, transverse, 1e-300),
              "l_vertical_kg_m2_s": max(float(np.abs(inv.l_vertical_kg_m2_s).max()),
                                        abs(inv.l_axial_kg_m2_s.iloc[0]), 1e-300),
              "l_axial_kg_m2_s": max(abs(inv.l_axial_kg_m2_s.iloc[0]), 1e-300)}
    for col in case.conserved:
        drift = float(np.abs(inv[col] - inv[col].iloc[0]).max() / scales[col])
        meas[f"{col}_drift"] = drift
        limit = LONG_RUN_ENERGY_RTOL if case.name.startswith("long-run") else INVARIANT_RTOL
        if drift > limit:
            problems.append(f"{col} drift {drift:.2g}")
    if case.damped:
        rise = float(np.diff(inv.energy_J.to_numpy()).max() / scales["energy_J"])
        meas["max_energy_rise"] = rise
        if rise > 1e-12:
            problems.append(f"energy rose by {rise:.2g}")
    if ref is not None:
        err = float(np.linalg.norm(df[["tip_x", "tip_y", "tip_z"]].to_numpy()
                                   - ref[["tip_x", "tip_y", "tip_z"]].to_numpy(), axis=1).max())
        meas["max_tip_error_vs_reference_rad"] = err
        if err > AGREEMENT_TOL_RAD and not case.name.startswith("long-run"):
            problems.append(f"tip differs from reference by {err:.2g} rad")
    return problems, meas


def run_stability(quick: bool = False, progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Run every case with every method; one row per (case, method)."""
    rows = []
    for case in stability_cases(quick):
        t = np.linspace(0.0, case.duration_s, case.samples)
        ref, ref_name = _reference(case, t)
        auto = choose_method(case.protocol)
        for method in case.methods:
            m = auto if method == "auto" else method
            row = dict(case=case.name, description=case.description, method=method, resolved_method=m,
                       reference=ref_name)
            start = time.perf_counter()
            try:
                df, info = simulate(case.protocol, method=m, t_eval_s=t, return_info=True)
                problems, meas = _check(case, df, info, ref)
                row.update(meas, n_rhs_evaluations=info.n_rhs_evaluations)
                row["status"] = "pass" if not problems else "FAIL: " + "; ".join(problems)
            except SimulationError as exc:
                row["status"] = f"FAIL: {exc}"
            row["wall_time_s"] = time.perf_counter() - start
            if case.name.startswith("long-run") and "energy_J_drift" in row:
                periods = case.duration_s / (2 * math.pi / 60.0)
                row["energy_drift_per_spin_period"] = row["energy_J_drift"] / periods
            rows.append(row)
        if progress:
            auto_row = next(r for r in rows[::-1] if r["case"] == case.name and r["method"] == "auto")
            progress(f"{case.name}: auto ({auto}) {auto_row['status']}")
    return pd.DataFrame(rows)


def verdicts(table: pd.DataFrame) -> pd.DataFrame:
    """One line per case: the automatic choice's verdict and the methods that failed (with reasons)."""
    out = []
    for case, g in table.groupby("case", sort=False):
        auto = g[g.method == "auto"].iloc[0]
        failures = [f"{r.method}: {r.status[6:]}" for r in g.itertuples() if r.method != "auto" and
                    r.status != "pass"]
        out.append(dict(case=case, auto_method=auto.resolved_method,
                        verdict="pass" if auto.status == "pass" else auto.status,
                        other_methods_failing="; ".join(failures) if failures else "none"))
    return pd.DataFrame(out)
