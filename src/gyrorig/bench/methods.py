"""Accuracy against run time of the simulator's methods: ``gyrorig bench methods`` and ``bench accuracy``.

These print figures; they are not timed unit tests.  Compare ratios measured in
one run (the machines are shared and noisy).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np
import pandas as pd

from ..physics import METHODS, SimulationError, exact_solution, exact_solution_applies, simulate
from ..geometry import tip_from_angles
from ..protocols import BUNDLED_PROTOCOL_DIR, Protocol, load_protocol, top_protocol
from ..theory import measure_nutation

logger = logging.getLogger(__name__)

__all__ = ["compare_methods", "DEFAULT_COMPARE_METHODS", "benchmark_top", "accuracy_scenes", "work_precision", "speed_ratio"]

DEFAULT_COMPARE_METHODS = ("gyro", "gyro-radau", "DOP853", "RK45", "LSODA", "Radau", "BDF")

_TIP = ["tip_x", "tip_y", "tip_z"]


def _errors(df: pd.DataFrame, ref: pd.DataFrame) -> dict[str, float]:
    tip_err = np.linalg.norm(df[_TIP].to_numpy() - ref[_TIP].to_numpy(), axis=1)
    rate = np.hypot(df.omega_d_rad_s - ref.omega_d_rad_s, df.omega_q_rad_s - ref.omega_q_rad_s)
    return {
        "max_tip_error_rad": float(tip_err.max()),
        "max_theta_error_rad": float(np.abs(df.theta_rad - ref.theta_rad).max()),
        "max_transverse_rate_error_rad_s": float(rate.max()),
    }


def compare_methods(
    protocol: Protocol,
    *,
    duration_s: float = 10.0,
    rate_hz: float = 100.0,
    methods: Sequence[str] = DEFAULT_COMPARE_METHODS,
    rtol: float | None = None,
    repeats: int = 1,
) -> tuple[pd.DataFrame, str]:
    """Run each method on the scene and measure its error against a reference.

    The reference is the exact solution where it applies, otherwise a ``gyro`` run
    at ``rtol = 1e-13``.

    Parameters
    ----------
    protocol : Protocol
    duration_s : float
        Simulated time. [s]
    rate_hz : float
        Rate of the samples compared. [Hz]
    methods : sequence of str
        Simulator methods (see :data:`gyrorig.physics.METHODS`).
    rtol : float, optional
        Same tolerance for every method (default: each solver's own default).
    repeats : int
        Wall time is the median of this many runs.

    Returns
    -------
    table : DataFrame
        One row per method: ``method, formulation, solver, rtol, wall_time_s,
        n_rhs_evaluations, max_tip_error_rad, max_theta_error_rad,
        max_transverse_rate_error_rad_s, status``; plus an ``exact`` row when it applies.
    reference : str
        ``"exact"`` or ``"gyro rtol=1e-13"``.
    """
    t = np.arange(int(round(duration_s * rate_hz)) + 1) / rate_hz
    rows = []
    ok, _ = exact_solution_applies(protocol)
    if ok:
        walls = []
        for _ in range(max(repeats, 1)):
            start = time.perf_counter()
            ref = exact_solution(protocol, t)
            walls.append(time.perf_counter() - start)
        reference = "exact"
        rows.append(dict(method="exact", formulation="closed form", solver="elliptic", rtol=np.nan,
                         wall_time_s=float(np.median(walls)), n_rhs_evaluations=0, max_tip_error_rad=0.0,
                         max_theta_error_rad=0.0, max_transverse_rate_error_rad_s=0.0, status="reference"))
    else:
        ref = simulate(protocol, method="gyro", rtol=1e-13, atol=1e-15, t_eval_s=t)
        reference = "gyro rtol=1e-13"
    for m in methods:
        formulation, solver = METHODS[m]
        walls = []
        try:
            simulate(protocol, method=m, duration_s=min(duration_s, 0.01), rate_hz=1000.0)  # load / compile first
            for _ in range(max(repeats, 1)):
                df, info = simulate(protocol, method=m, rtol=rtol, t_eval_s=t, return_info=True)
                walls.append(info.wall_time_s)
            row = dict(method=m, formulation=formulation, solver=solver, rtol=info.rtol,
                       wall_time_s=float(np.median(walls)), n_rhs_evaluations=info.n_rhs_evaluations,
                       **_errors(df, ref), status="ok")
        except SimulationError as exc:
            row = dict(method=m, formulation=formulation, solver=solver, rtol=rtol, wall_time_s=np.nan,
                       n_rhs_evaluations=0, max_tip_error_rad=np.nan, max_theta_error_rad=np.nan,
                       max_transverse_rate_error_rad_s=np.nan, status=f"failed: {exc}")
        logger.info("%s: %s", m, row["status"])
        rows.append(row)
    return pd.DataFrame(rows), reference


# --------------------------------------------------------------------------------------
# work-precision study (gyrorig bench accuracy)

#: the issue's reference top (SI): I = 1, Io = 0.6, M = 1, h = 0.1, g = 9.81, tilt 0.2, released from rest
def benchmark_top(spin_rad_s: float, *, duration_s: float = 10.0, damping: dict | None = None) -> Protocol:
    """The benchmark top of the work-precision study, released from rest at tilt 0.2 rad."""
    return top_protocol(tilt_rad=0.2, spin_rate_rad_s=spin_rad_s, damping=damping, duration_s=duration_s,
                        name=f"release-spin{spin_rad_s:g}" + ("-damped" if damping else ""))


def _ladders(quick: bool) -> dict[str, list[float]]:
    if quick:
        return {"gyro": [1e-6, 1e-8, 1e-10, 1e-12], "DOP853-jit": [1e-6, 1e-8, 1e-10, 1e-12],
                "phasor": [1e-10], "gyro-scipy": [1e-10], "DOP853": [1e-8, 1e-10]}
    return {
        "gyro": [1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13],
        "DOP853-jit": [1e-6, 1e-8, 1e-10, 1e-12, 1e-13],
        "gyro-scipy": [1e-6, 1e-8, 1e-10, 1e-12],
        "phasor": [1e-6, 1e-8, 1e-10, 1e-12],
        "DOP853": [1e-6, 1e-8, 1e-10, 1e-12],
        "RK45": [1e-5, 1e-7, 1e-9],
        "LSODA": [1e-6, 1e-8, 1e-10],
        "gyro-radau": [1e-5, 1e-7, 1e-9],
        "Radau": [1e-5],
    }


def _fast_top_trajectory(protocol: Protocol, t: np.ndarray) -> pd.DataFrame:
    """Goldstein's fast-top solution after release from rest (first order in the nutation).

    ``theta = theta0 + A (1 - cos(a t))``, ``phi = (Mgh / L3) (t - sin(a t) / a)``,
    ``a = L3 / I``, ``A = I Mgh sin(theta0) / L3^2``.
    """
    rig, lau = protocol.rig, protocol.launch
    l3 = rig.inertia_axial_kg_m2 * lau.spin_rate_rad_s
    a = l3 / rig.inertia_transverse_kg_m2
    amp = rig.inertia_transverse_kg_m2 * rig.mgh_N_m * np.sin(lau.tilt_rad) / l3**2
    theta = lau.tilt_rad + amp * (1 - np.cos(a * t))
    phi = lau.azimuth_rad + rig.mgh_N_m / l3 * (t - np.sin(a * t) / a)
    tip = tip_from_angles(theta, phi)
    return pd.DataFrame({"t_s": t, "theta_rad": theta, "phi_rad": phi, "tip_x": tip[:, 0], "tip_y": tip[:, 1],
                         "tip_z": tip[:, 2]})


def _observables(df: pd.DataFrame) -> tuple[float, float]:
    try:
        m = measure_nutation(df)
        return m.mean_precession_rate_rad_s, m.amplitude_rad
    except ValueError:
        return float("nan"), float("nan")


def accuracy_scenes(quick: bool) -> dict[str, Protocol]:
    """Scenes of the work-precision study."""
    scenes = {"release-spin60": benchmark_top(60.0), "release-spin300": benchmark_top(300.0)}
    if not quick:
        for name in ("air-cushion-heavy-top", "eddy-damped-top-b2", "accelerated-pivot"):
            p = load_protocol(BUNDLED_PROTOCOL_DIR / f"{name}.toml")
            scenes[name] = p
        scenes["release-spin60-damped"] = benchmark_top(60.0, damping={"model": "paper", "gamma_per_s": 2.0})
    return scenes


def work_precision(protocol: Protocol, *, quick: bool = False, duration_s: float = 10.0,
                   progress=None) -> tuple[pd.DataFrame, str]:
    """Error against wall time for every method and tolerance on one scene.

    Returns the table (``method, rtol, wall_time_s, n_rhs_evaluations, max_tip_error_rad,
    precession_rate_error_rad_s, nutation_amplitude_error_rad, status``) and the
    reference used (``exact`` or the tightest ``gyro`` run).
    """
    duration = min(duration_s, protocol.scene.duration_s)
    ok, _ = exact_solution_applies(protocol)
    rig = protocol.rig
    nut = abs(rig.inertia_axial_kg_m2 * protocol.launch.spin_rate_rad_s) / rig.inertia_transverse_kg_m2
    rate = max(100.0, 40.0 * nut / (2 * np.pi))  # >= 40 samples per nutation period
    t = np.arange(int(round(duration * rate)) + 1) / rate
    repeats = 1 if quick else 3
    rows = []
    if ok:
        walls = []
        for _ in range(repeats):
            start = time.perf_counter()
            ref = exact_solution(protocol, t)
            walls.append(time.perf_counter() - start)
        reference = "exact"
    else:
        ref = simulate(protocol, method="gyro", rtol=1e-13, atol=1e-15, t_eval_s=t)
        reference = "gyro rtol=1e-13"
    ref_obs = _observables(ref)

    def record(method, rtol, df, wall, nfev, status="ok"):
        obs = _observables(df) if df is not None else (np.nan, np.nan)
        err = float(np.linalg.norm(df[_TIP].to_numpy() - ref[_TIP].to_numpy(), axis=1).max()) if df is not None \
            else np.nan
        rows.append(dict(method=method, rtol=rtol, wall_time_s=wall, n_rhs_evaluations=nfev, max_tip_error_rad=err,
                         precession_rate_error_rad_s=abs(obs[0] - ref_obs[0]),
                         nutation_amplitude_error_rad=abs(obs[1] - ref_obs[1]), status=status))

    if ok:
        record("exact", np.nan, ref, float(np.median(walls)), 0, "reference")
        if protocol.launch.tilt_rate_rad_s == 0 and protocol.launch.precession_rate_rad_s == 0:
            start = time.perf_counter()
            approx = _fast_top_trajectory(protocol, t)
            record("fast-top closed form", np.nan, approx, time.perf_counter() - start, 0)
    for method, rtols in _ladders(quick).items():
        simulate(protocol, method=method, duration_s=min(duration, 0.01), rate_hz=1000.0)  # warm-up / compile
        for rtol in rtols:
            walls, df, info = [], None, None
            try:
                for k in range(repeats):
                    df, info = simulate(protocol, method=method, rtol=rtol, atol=rtol * 1e-2, t_eval_s=t,
                                        return_info=True)
                    walls.append(info.wall_time_s)
                    if info.wall_time_s > 2.0:
                        break  # slow runs: one timing is enough
                record(method, rtol, df, float(np.median(walls)), info.n_rhs_evaluations)
            except SimulationError as exc:
                record(method, rtol, None, np.nan, 0, f"failed: {exc}")
        if progress:
            progress(f"  {protocol.name}: {method} done")
    return pd.DataFrame(rows), reference


def speed_ratio(table: pd.DataFrame, baseline: str = "DOP853", method: str = "gyro") -> pd.DataFrame:
    """For each baseline run: the fastest ``method`` run at least as accurate, and the time ratio."""
    out = []
    mine = table[(table.method == method) & (table.status == "ok")]
    for _, b in table[(table.method == baseline) & (table.status == "ok")].iterrows():
        good = mine[mine.max_tip_error_rad <= b.max_tip_error_rad]
        if len(good):
            best = good.loc[good.wall_time_s.idxmin()]
            out.append(dict(baseline=baseline, baseline_rtol=b.rtol, baseline_error_rad=b.max_tip_error_rad,
                            baseline_wall_s=b.wall_time_s, method=method, method_rtol=best.rtol,
                            method_error_rad=best.max_tip_error_rad, method_wall_s=best.wall_time_s,
                            speedup=b.wall_time_s / best.wall_time_s))
    return pd.DataFrame(out)
