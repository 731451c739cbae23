"""Plots of trajectories.  Functions return a matplotlib ``Figure``; they never show it."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from ..geometry import tip_from_angles

__all__ = ["plot_trajectory", "plot_tracking", "plot_fit", "plot_work_precision", "plot_stability", "plot_validation",
           "plot_sweep"]


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


def plot_validation(table: pd.DataFrame) -> Figure:
    """Four panels judging the paper's formulas against the simulator.

    (a) relative error against the fast-top ratio for the fast-top formulas (small
    tilt); (b) slow steady precession, paper vs simulator (signed); (c) damped tilt rate,
    paper / corrected / simulated (signed); (d) accelerated pivot: x of the equilibrium tip.
    """
    fig = Figure(figsize=(12, 8.5), layout="constrained")
    ax = fig.subplots(2, 2).ravel()
    small = table[(table.tilt_rad <= 0.3) & table.fast_top_ratio.notna()]
    for formula, g in small.groupby("formula", sort=False):
        col = "rel_error_corrected" if g.rel_error_corrected.notna().any() else "rel_error_paper"
        g = g.sort_values("fast_top_ratio")
        label = formula + (" (corrected)" if col == "rel_error_corrected" else "")
        ax[0].loglog(g.fast_top_ratio, np.maximum(np.abs(g[col]), 1e-8), "o", ms=4, alpha=0.8, label=label)
    ax[0].set(xlabel="fast-top ratio (Io Omega)^2 / (4 I Mgh)", ylabel="|relative error| vs simulator",
              title="(a) closed forms at tilt <= 0.3 rad")
    ax[0].legend(fontsize=6)
    for a, quantity, paper, corrected, labels in (
            (ax[1], "precession_rate_slow_rad_s", "paper eq. 20 as printed", "eq. 20, Mgh sign corrected",
             dict(xlabel="sweep point (spin, tilt)", ylabel="slow precession [rad/s]",
                  title="(b) steady slow precession")),
            (ax[2], "tilt_growth_rate_per_s", "paper eq. 25a", "sign corrected",
             dict(xlabel="sweep point (spin, gamma)", ylabel="d ln(theta)/dt [1/s] (>0: tilt grows)",
                  title="(c) damped compensated top"))):
        rows = table[table.quantity == quantity]
        x = np.arange(len(rows))
        a.plot(x, rows.simulator, "ko", label="simulator")
        a.plot(x, rows.paper, "rx", label=paper)
        a.plot(x, rows.corrected, "g+", ms=10, label=corrected)
        a.axhline(0, color="0.7", lw=0.5)
        a.set(**labels)
        a.legend(fontsize=7)
    acc = table[table.quantity == "equilibrium_tip_x"]
    a = acc.params.str.extract(r"a_m_s2=([0-9.e+-]+)")[0].astype(float)
    ax[3].plot(a, acc.simulator, "ko", label="simulator (cone axis)")
    ax[3].plot(a, acc.paper, "rx", label="paper eq. 31")
    ax[3].plot(a, acc.exact, "g+", ms=10, label="effective vertical")
    ax[3].axhline(0, color="0.7", lw=0.5)
    ax[3].set(xlabel="pivot acceleration a along -x [m/s^2]", ylabel="x component of equilibrium tip",
              title="(d) accelerated pivot: which way it leans")
    ax[3].legend(fontsize=7)
    return fig


def plot_work_precision(table: pd.DataFrame, *, title: str = "") -> Figure:
    """Max tip error against wall time (log-log), one line per method; closed forms as points."""
    fig = Figure(figsize=(7.5, 5.5), layout="constrained")
    ax = fig.subplots()
    ok = table[table.status.isin(["ok", "reference"])]
    for method, g in ok.groupby("method", sort=False):
        g = g.sort_values("wall_time_s")
        err = np.maximum(g.max_tip_error_rad.to_numpy(), 1e-16)
        style = "o-" if len(g) > 1 else "s"
        label = method if method != "exact" else "exact (elliptic; error floored at 1e-16)"
        ax.loglog(g.wall_time_s, err, style, ms=4, label=label)
    ax.set(xlabel="wall time [s] (median, same process)", ylabel="max tip-direction error [rad]",
           title=title or "work-precision")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7)
    return fig


def plot_stability(table: pd.DataFrame) -> Figure:
    """Pass/fail matrix of the stability suite: cases (rows) by methods (columns)."""
    cases = list(dict.fromkeys(table.case))
    methods = list(dict.fromkeys(table.method))
    grid = np.full((len(cases), len(methods)), np.nan)
    for r in table.itertuples():
        grid[cases.index(r.case), methods.index(r.method)] = 1.0 if r.status == "pass" else 0.0
    fig = Figure(figsize=(2 + 1.3 * len(methods), 1 + 0.42 * len(cases)), layout="constrained")
    ax = fig.subplots()
    ax.imshow(np.ma.masked_invalid(grid), cmap="RdYlGn", vmin=0, vmax=1, aspect="auto")
    for i in range(len(cases)):
        for j in range(len(methods)):
            if not np.isnan(grid[i, j]):
                ax.text(j, i, "pass" if grid[i, j] else "FAIL", ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(methods)), methods, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(cases)), cases, fontsize=8)
    ax.set_title("stability suite (see stability.md for the reasons)")
    return fig


def plot_tracking(angles: pd.DataFrame, truth: pd.DataFrame, *, title: str = "") -> Figure:
    """Tracked theta, phi with their error bars against the true values, and the normalised errors."""
    fig = Figure(figsize=(11, 6.5), layout="constrained")
    ax = fig.subplots(2, 2).ravel()
    t = angles.t_s.to_numpy()
    for i, (col, label) in enumerate([("theta_rad", "tilt theta"), ("phi_rad", "azimuth phi")]):
        ax[i].plot(truth.t_s, np.degrees(truth[col]), "k-", lw=0.8, label="truth (simulator)")
        ax[i].errorbar(t, np.degrees(angles[col]), yerr=np.degrees(angles[col.replace("_rad", "_sigma_rad")]),
                       fmt=".", ms=2, lw=0.5, label="tracked from the video")
        ax[i].set(xlabel="t [s]", ylabel=f"{label} [deg]", title=label)
        ax[i].legend(fontsize=7)
    for i, col in enumerate(["theta_rad", "phi_rad"]):
        err = np.interp(t, truth.t_s, truth[col]) - angles[col]
        pull = -err / angles[col.replace("_rad", "_sigma_rad")]
        ax[2 + i].plot(t, pull, ".", ms=2)
        ax[2 + i].axhline(0, color="0.6", lw=0.5)
        ax[2 + i].set(xlabel="t [s]", ylabel="(tracked - true) / sigma",
                      title=f"{col.split('_')[0]}: normalised error, std {np.nanstd(pull):.2f}")
    if title:
        fig.suptitle(title)
    return fig


def plot_fit(angles: pd.DataFrame, smoothed: pd.DataFrame | None, fit, *, title: str = "") -> Figure:
    """Measured, smoothed and fitted angles; a zoom on the nutation; the tip path from above;
    the smoother's rates; normalised residuals.

    Parameters
    ----------
    angles : DataFrame
        Tracked angles (``t_s, theta_rad, phi_rad``).
    smoothed : DataFrame, optional
        Smoother output (``t_s, theta_rad, theta_rate_rad_s, phi_rate_rad_s, status``).
    fit : gyrorig.fit.FitResult
    """
    fig = Figure(figsize=(11, 13), layout="constrained")
    axes = fig.subplots(4, 2)
    t = angles.t_s.to_numpy()
    ok = np.isfinite(angles.theta_rad.to_numpy())
    curve = fit.model_curve
    th_deg = np.degrees(angles.theta_rad.to_numpy())
    fitted = fit.residuals.t_s.to_numpy()
    t0 = fitted[0] if len(fitted) else (t[ok][0] if ok.any() else 0.0)  # the zoom starts where the fit does
    for ax, zoom in ((axes[0, 0], False), (axes[0, 1], True)):
        sel = ok & (((t >= t0) & (t <= t0 + 1.0)) if zoom else True)
        csel = (curve.t_s <= t0 + 1.0) if zoom else np.ones(len(curve), bool)
        ax.plot(t[sel], th_deg[sel], ".", ms=2 if not zoom else 4, color="0.5", label="tracked")
        if smoothed is not None:
            ssel = ((smoothed.t_s >= t0) & (smoothed.t_s <= t0 + 1.0)) if zoom else np.ones(len(smoothed), bool)
            ax.plot(smoothed.t_s[ssel], np.degrees(smoothed.theta_rad[ssel]), lw=0.6, color="C0",
                    label="smoothed (Kalman/RTS)")
            out = (smoothed.status.to_numpy() == "outlier") & sel
            if out.any():
                ax.plot(t[out], th_deg[out], "rx", ms=5, label="outlier (gated)")
        ax.plot(curve.t_s[csel], np.degrees(curve.theta_rad[csel]), lw=0.8, color="C1", label="fit")
        if not zoom and len(fitted) and ok.any():  # the record's ends the fit left out (a top held still, caught)
            spans = [(lo, hi) for lo, hi in ((t[ok][0], fitted[0]), (fitted[-1], t[ok][-1])) if hi > lo]
            for k, (lo, hi) in enumerate(spans):
                ax.axvspan(lo, hi, color="0.85", zorder=0, label=None if k else "left out of the fit")
            for k, brk in enumerate(fit.breaks):  # where the motion broke (a knock, a touch)
                ax.axvline(0.5 * (brk.t_before_s + brk.t_after_s), color="C3", ls="--", lw=0.8,
                           label=None if k else "break in the motion")
        ax.set(xlabel="t [s]", ylabel="tilt theta [deg]", title="tilt, first second fitted" if zoom else "tilt")
        # below the axes: inside, the legend hides the oscillation it labels
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=4, frameon=False)
    ax = axes[1, 0]
    phi_meas = np.unwrap(angles.phi_rad.to_numpy()[ok])
    phi_fit = np.interp(t[ok], curve.t_s, np.unwrap(curve.phi_rad))
    # the fit drawn over the span it fitted, its turns counted as the tracked azimuth's where that span starts
    inside = (t[ok] >= curve.t_s.min()) & (t[ok] <= curve.t_s.max()) if len(curve) else np.zeros(ok.sum(), bool)
    first = int(np.argmax(inside)) if inside.any() else 0
    phi_fit += 2 * np.pi * np.round((phi_meas[first] - phi_fit[first]) / (2 * np.pi))
    ax.plot(t[ok], np.degrees(phi_meas), ".", ms=2, color="0.5", label="tracked")
    ax.plot(t[ok][inside], np.degrees(phi_fit[inside]), lw=0.8, color="C1", label="fit")
    ax.set(xlabel="t [s]", ylabel="azimuth phi [deg] (unwrapped)", title="precession")
    ax.legend(fontsize=7)
    ax = axes[1, 1]
    th, ph = angles.theta_rad.to_numpy()[ok], angles.phi_rad.to_numpy()[ok]
    tip = tip_from_angles(th, ph)
    ax.plot(tip[:, 0], tip[:, 1], ".", ms=1.5, color="0.5", label="tracked")
    ct, cp = curve.theta_rad.to_numpy(), curve.phi_rad.to_numpy()
    tip = tip_from_angles(ct, cp)
    ax.plot(tip[:, 0], tip[:, 1], lw=0.5, color="C1", label="fit")
    ax.plot([0], [0], "k+")
    ax.set(xlabel="tip x", ylabel="tip y", title="tip path seen from above (unit sphere)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=7)
    ax = axes[2, 0]
    if smoothed is not None and "theta_rate_rad_s" in smoothed:
        ax.plot(smoothed.t_s, smoothed.theta_rate_rad_s, lw=0.6, label="theta' (tilt rate)")
        ax.plot(smoothed.t_s, smoothed.phi_rate_rad_s, lw=0.6, label="phi' (precession rate)")
        ax.legend(fontsize=7)
    ax.set(xlabel="t [s]", ylabel="rate [rad/s]", title="smoothed rates")
    ax = axes[2, 1]
    res = fit.residuals
    ax.hist(res.theta_resid_norm, bins=60, histtype="step", density=True, label="theta")
    ax.hist(res.phi_resid_norm, bins=60, histtype="step", density=True, label="phi")
    x = np.linspace(-5, 5, 200)
    ax.plot(x, np.exp(-x**2 / 2) / np.sqrt(2 * np.pi), "k--", lw=0.8, label="N(0, 1)")
    ax.set(xlabel="residual / sigma", ylabel="density", title=f"normalised residuals (chi2_red {fit.chi2_red:.3f})")
    ax.legend(fontsize=7)
    for ax, col, name in ((axes[3, 0], "theta_resid_rad", "tilt"), (axes[3, 1], "phi_resid_rad", "azimuth")):
        ax.plot(res.t_s, res[col] * 1e3, ".", ms=1.5)
        ax.axhline(0, color="k", lw=0.5)
        ax.set(xlabel="t [s]", ylabel=f"{name} residual [mrad]", title=f"{name} residuals (data - fit)")
    if title:
        fig.suptitle(title)
    return fig


def plot_sweep(table: pd.DataFrame, key: str) -> Figure:
    """Expected relative errors (columns ``<quantity>_relative_error``) against a scanned protocol key (log scale)."""
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.subplots()
    for c in table.columns:
        if c.endswith("_relative_error") and np.isfinite(table[c]).any():
            ax.semilogy(table[key], table[c], "o-", label=c.removesuffix("_relative_error"))
    ax.set(xlabel=key, ylabel="expected relative standard error", title=f"precision against {key}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return fig
