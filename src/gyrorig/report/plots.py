"""Plots of trajectories.  Functions return a matplotlib ``Figure``; they never show it."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

__all__ = ["plot_trajectory"]


def plot_trajectory(df: pd.DataFrame, *, reference: pd.DataFrame | None = None, title: str = "") -> Figure:
    """Tilt and azimuth against time, the tip path seen from above, and (optionally) the error.

    Parameters
    ----------
    df : DataFrame
        Trajectory with ``t_s, theta_rad, phi_rad, tip_x, tip_y, tip_z``.
    reference : DataFrame, optional
        Same columns at the same times (e.g. the exact solution): adds a panel with the
        tip-direction error on a log scale.
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    n = 4 if reference is not None else 3
    fig = Figure(figsize=(11, 3.2 * ((n + 1) // 2)), layout="constrained")
    axes = fig.subplots((n + 1) // 2, 2).ravel()
    t = df.t_s.to_numpy()
    axes[0].plot(t, np.degrees(df.theta_rad), lw=0.8)
    axes[0].set(xlabel="t [s]", ylabel="tilt theta [deg]", title="tilt")
    axes[1].plot(t, np.degrees(df.phi_rad), lw=0.8)
    axes[1].set(xlabel="t [s]", ylabel="azimuth phi [deg] (unwrapped)", title="precession")
    ax = axes[2]
    ax.plot(df.tip_x, df.tip_y, lw=0.5)
    ax.plot([0], [0], "k+")
    ax.set(xlabel="tip x", ylabel="tip y", title="tip path seen from above (unit sphere)")
    ax.set_aspect("equal", adjustable="datalim")
    if reference is not None:
        cols = ["tip_x", "tip_y", "tip_z"]
        err = np.linalg.norm(df[cols].to_numpy() - reference[cols].to_numpy(), axis=1)
        axes[3].semilogy(t, np.maximum(err, 1e-17), lw=0.8)
        axes[3].set(xlabel="t [s]", ylabel="|tip - tip_exact| [rad]", title="error against the exact solution")
    for ax in axes[n:]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title)
    return fig
