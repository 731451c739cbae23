"""The quick-start demo: the whole chain on the bundled air-cushion rig, with what it found said as it goes.

simulate (and judge the simulator by the exact solution) -> the paper's formulas for this rig ->
a synthetic video through the rig's camera (640x480) -> :func:`gyrorig.analysis.analyze_video`
(track without the truth, smooth, fit, report) -> fitted against predicted and true values.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from . import _io
from .analysis import analyze_video
from .camera import with_image_size
from .geometry import wrap_angle
from .physics import exact_solution, simulate
from .protocols import BUNDLED_PROTOCOL_DIR, Protocol, ProtocolError, load_protocol, protocol_summary
from .render import render_video
from .report import plot_tracking, plot_trajectory
from .theory import predict

__all__ = ["DEMO_PROTOCOL", "run_demo"]

DEMO_PROTOCOL = "air-cushion-heavy-top.toml"

Say = Callable[[str], None]
ProgressFor = Callable[[str], Callable[[int, int], None] | None]


def _save_png(fig, path: Path, dpi: int = 110) -> None:
    with _io.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)


def _simulate_step(protocol: Protocol, out: Path, duration_s: float, say: Say):
    """Simulate, and compare with the exact solution; returns the simulation info and the max tip error."""
    say(f"[1/5] simulating {duration_s:g} s ...")
    t0 = time.perf_counter()
    simulate(protocol, duration_s=0.01)  # compiles the integrator on first use (then cached on disk)
    if time.perf_counter() - t0 > 0.5:
        say(f"      (compiled the integrator once: {time.perf_counter() - t0:.1f} s)")
    df, info = simulate(protocol, duration_s=duration_s, rate_hz=500.0, return_info=True)
    sol = exact_solution(protocol)
    ref = sol.evaluate(df.t_s.to_numpy())
    tips = ["tip_x", "tip_y", "tip_z"]
    err = float(np.linalg.norm(df[tips].to_numpy() - ref[tips].to_numpy(), axis=1).max())
    _save_png(plot_trajectory(df, reference=ref, title=f"{protocol.name}: simulator ({info.method}) vs exact "
                                                       "solution"), out / "trajectory.png")
    _io.write_csv(df, out / "trajectory.csv")
    th_min, th_max = sol.tilt_range_rad
    say(f"      method {info.method}: {info.wall_time_s * 1e3:.1f} ms, max tip error vs exact {err:.1e} rad; "
        f"tilt {np.degrees(th_min):.3f}..{np.degrees(th_max):.3f} deg, nutation "
        f"{sol.nutation_frequency_rad_s / (2 * np.pi):.3f} Hz, mean precession {sol.mean_precession_rate_rad_s:.4f} "
        "rad/s")
    return info, err


def _theory_step(protocol: Protocol, out: Path, say: Say) -> None:
    say("[2/5] the paper's formulas for this rig (paper / exact):")
    pred = predict(protocol, simulate_damping=False)
    _io.write_json(_io.json_safe(pred), out / "theory.json")
    for key in ("precession_rate_slow_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad",
                "mean_precession_rate_rad_s"):
        v = pred.quantities[key]
        flag = "  ** WRONG SIGN **" if v.sign_agrees is False else ""
        say(f"      {key}: {v.paper:.5g} / {v.exact:.5g} ({v.relative_difference:+.1%}){flag}")
    say(f"      fast-top ratio {pred.flags.fast_top_ratio:.2f} (the formulas want >= 10)")


def _tracking_check(protocol: Protocol, res, out: Path, say: Say) -> None:
    """The tracked angles against the simulator (the tracker never saw it)."""
    angles = res.angles.dropna(subset=["theta_rad"])
    truth = simulate(protocol, t_eval_s=angles.t_s.to_numpy())
    e_th = angles.theta_rad.to_numpy() - truth.theta_rad.to_numpy()
    e_ph = wrap_angle(angles.phi_rad.to_numpy() - truth.phi_rad.to_numpy())
    _save_png(plot_tracking(angles, truth, title="tip tracked from the synthetic video vs the simulator"),
              out / "tracking.png")
    say(f"      {res.tracking.tracked_fraction:.1%} of {res.tracking.frames} frames tracked; theta error "
        f"{np.sqrt(np.mean(e_th**2)):.2e} rad rms (reported sigma {angles.theta_sigma_rad.mean():.2e}), "
        f"phi error {np.sqrt(np.mean(e_ph**2)):.2e} rad rms (sigma {angles.phi_sigma_rad.mean():.2e})")


def _fit_table(fit, say: Say) -> None:
    say(f"      {'quantity':<26} {'paper':>11} {'exact':>11} {'fitted':>11} {'+- s.e.':>9} {'true':>11} {'pull':>6}")

    def f(v):
        return "-" if v is None else f"{v:.6g}"

    for name, q in fit.quantities.items():
        if not q.determined:
            say(f"      {name:<26} undetermined: {q.reason}")
            continue
        pull = "-" if q.pull is None else f"{q.pull:+.2f}"
        say(f"      {name:<26} {f(q.paper):>11} {f(q.exact):>11} {q.value:>11.6g} {q.standard_error:>9.2g} "
            f"{f(q.truth):>11} {pull:>6}")


def run_demo(out: str | Path, *, duration_s: float = 10.0, video_duration_s: float = 3.0, say: Say = print,
             progress_for: ProgressFor | None = None) -> dict:
    """Run the demo into ``out``; ``say`` prints each line, ``progress_for(label)`` gives a progress callback.

    Returns the manifest written to ``out/manifest.json``.
    """
    out = Path(out)
    progress_for = progress_for or (lambda label: None)
    path = BUNDLED_PROTOCOL_DIR / DEMO_PROTOCOL
    if not path.exists():
        raise ProtocolError(f"bundled protocol {DEMO_PROTOCOL} not found at {path}: the installation is incomplete "
                            "(reinstall gyrorig)")
    protocol = load_protocol(path)
    start = time.perf_counter()
    say(f"demo: {protocol.description}")
    info, err = _simulate_step(protocol, out, duration_s, say)
    _theory_step(protocol, out, say)
    say(f"[3/5] rendering {video_duration_s:g} s of video (640x480, 200 fps) ...")
    video_protocol = with_image_size(protocol, 640, 480)
    rendered = render_video(video_protocol, out / "video", seed=0, duration_s=video_duration_s, calibration_views=0,
                            progress=progress_for("      render"))
    say("[4/5] tracking the tip marker, smoothing, fitting and writing the report ...")
    summary = analyze_video(rendered["video"], out / "video" / "camera.json", video_protocol, out,
                            truth_csv=out / "video" / "truth.csv", progress=progress_for("      track"),
                            prediction=predict(protocol), title=f"gyrorig demo: {protocol.name}",
                            stage=lambda msg: None)
    res = summary["analysis"]
    _tracking_check(protocol, res, out, say)
    say("[5/5] fitted against the paper's and the exact predictions, and the truth:")
    _fit_table(res.fit, say)
    manifest = {"command": "demo", "protocol": protocol_summary(protocol), "simulation": asdict(info),
                "max_tip_error_vs_exact_rad": err,
                "tracking": {**res.tracking.summary(), "angles": str(out / "track" / "angles.csv"),
                             "markers": str(out / "track" / "markers.csv")},
                "fit": {k: q.as_dict() for k, q in res.fit.quantities.items()},
                "wall_time_s": time.perf_counter() - start, "versions": _io.versions()}
    _io.write_json(manifest, out / "manifest.json")
    say(f"done in {time.perf_counter() - start:.0f} s. Report: {out / 'report.html'} (open it in a browser); "
        f"plots {out / 'trajectory.png'}, {out / 'tracking.png'}, {out / 'fit.png'}; data in {out}/")
    return manifest
