"""Benchmarks: accuracy against run time of the simulator's methods.

These print figures; they are not timed unit tests.  Compare ratios measured in
one run (the machines are shared and noisy).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np
import pandas as pd

from .physics import METHODS, SimulationError, exact_solution, exact_solution_applies, simulate
from .protocols import Protocol

logger = logging.getLogger(__name__)

__all__ = ["compare_methods", "DEFAULT_COMPARE_METHODS"]

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
