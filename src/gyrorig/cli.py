"""Command line: ``gyrorig <command> ...`` (thin layer over the public functions).

Exit codes: 0 success; 2 bad input (protocol, arguments); 3 a computation failed
(integration error, lost quaternion norm).  Nothing is written under a final file
name unless the whole computation succeeded.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np

from . import _io
from .physics import METHODS, SimulationError, exact_solution, exact_solution_applies, simulate
from .physics.exact import ExactSolutionError
from .protocols import BUNDLED_PROTOCOL_DIR, Protocol, ProtocolError, load_protocol

logger = logging.getLogger("gyrorig")

DEMO_PROTOCOL = "air-cushion-heavy-top.toml"

EXIT_OK, EXIT_BAD_INPUT, EXIT_FAILED = 0, 2, 3


def _protocol_summary(p: Protocol) -> dict:
    return {"name": p.name, "source": p.source, "description": p.description, "rig": asdict(p.rig),
            "launch": asdict(p.launch), "pivot": asdict(p.pivot), "scene": asdict(p.scene)}


def _cmd_simulate(args: argparse.Namespace) -> int:
    protocol = load_protocol(args.protocol)
    out = Path(args.out)
    if args.method == "exact":
        ok, why = exact_solution_applies(protocol)
        if not ok:
            raise ExactSolutionError(f"--method exact: no exact solution for {protocol.name}: {why}")
        duration = protocol.scene.duration_s if args.duration is None else args.duration
        rate = protocol.scene.output_rate_hz if args.rate is None else args.rate
        t = np.arange(int(np.floor(duration * rate + 1e-9)) + 1) / rate
        start = time.perf_counter()
        df = exact_solution(protocol, t)
        info = {"method": "exact", "wall_time_s": time.perf_counter() - start}
    else:
        df, sim_info = simulate(protocol, method=args.method, rtol=args.rtol, atol=args.atol,
                                duration_s=args.duration, rate_hz=args.rate, return_info=True)
        info = asdict(sim_info)
    manifest = {"command": "simulate", "protocol": _protocol_summary(protocol), "simulation": info,
                "n_rows": len(df), "columns": list(df.columns), "versions": _io.versions()}
    _io.write_csv(df, out / "trajectory.csv")
    _io.write_json(manifest, out / "manifest.json")
    print(f"{protocol.name}: {len(df)} rows, method {info['method']}, {info['wall_time_s']:.3f} s wall "
          f"-> {out / 'trajectory.csv'}")
    return EXIT_OK


def _cmd_bench_methods(args: argparse.Namespace) -> int:
    from .bench import DEFAULT_COMPARE_METHODS, compare_methods

    protocol = load_protocol(args.protocol)
    methods = args.methods or list(DEFAULT_COMPARE_METHODS)
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"--methods: unknown method {m!r}; allowed {', '.join(METHODS)}")
    print(f"{protocol.name}: {args.duration:g} s simulated, errors at {args.rate:g} Hz samples", flush=True)
    table, reference = compare_methods(protocol, duration_s=args.duration, rate_hz=args.rate, methods=methods,
                                       rtol=args.rtol, repeats=args.repeats)
    print(f"reference: {reference}")
    cols = ["method", "formulation", "rtol", "wall_time_s", "n_rhs_evaluations", "max_tip_error_rad", "status"]
    print(table[cols].to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    dop = table[table.method == "DOP853"]
    gyro = table[table.method == "gyro"]
    if len(dop) and len(gyro) and dop.status.iloc[0] == "ok" and gyro.status.iloc[0] == "ok":
        ratio = dop.wall_time_s.iloc[0] / gyro.wall_time_s.iloc[0]
        print(f"speed ratio DOP853(body) / gyro, same run: {ratio:.2f}")
    if args.out:
        _io.write_csv(table, Path(args.out) / "methods.csv")
    return EXIT_OK


#: the issue's figures for the same case, measured elsewhere on this kind of machine (not re-measured here)
REFERENCE_FIGURES = {
    "release-spin60": "MuJoCo 4.0 RK4: 1.6e-10 rad in 0.16 s, 4e-12 in 0.5 s; scipy DOP853 (plain Python rhs): "
                      "1.5e-10 in 0.9 s",
    "release-spin300": "MuJoCo 4.0 RK4: 9e-11 rad in 0.5 s; scipy DOP853: 3.3 s",
}


def _cmd_bench_accuracy(args: argparse.Namespace) -> int:
    from .bench import accuracy_scenes, speed_ratio, work_precision
    from .report import markdown_table, plot_work_precision

    out = Path(args.out or "bench-accuracy")
    md = ["# Work-precision study\n",
          "Error: max tip-direction error against the exact solution (undamped) or the tightest converged "
          "`gyro` run (damped), 10 s simulated.  Wall time: median of repeats in one process.\n"]
    cols = ["method", "rtol", "wall_time_s", "n_rhs_evaluations", "max_tip_error_rad",
            "precession_rate_error_rad_s", "nutation_amplitude_error_rad", "status"]
    for name, protocol in accuracy_scenes(args.quick).items():
        print(f"{name}: running ...", flush=True)
        table, reference = work_precision(protocol, quick=args.quick)
        table.insert(0, "scene", name)
        ratios = speed_ratio(table)
        _io.write_csv(table, out / f"{name}.csv")
        fig = plot_work_precision(table, title=f"{name} (reference: {reference})")
        with _io.atomic_path(out / f"{name}.png") as tmp:
            fig.savefig(tmp, format="png", dpi=100)
        print(f"reference: {reference}")
        print(table[cols].to_string(index=False, float_format=lambda v: f"{v:.3g}"))
        if len(ratios):
            print("speed-up of gyro over scipy DOP853 (body frame, plain Python rhs) at equal or better error, "
                  "same run:")
            print(ratios[["baseline_rtol", "baseline_error_rad", "baseline_wall_s", "method_rtol",
                          "method_error_rad", "method_wall_s", "speedup"]].to_string(
                index=False, float_format=lambda v: f"{v:.3g}"))
        if name in REFERENCE_FIGURES:
            print(f"issue's reference figures: {REFERENCE_FIGURES[name]}")
        md += [f"\n## {name}\n\nreference: {reference}\n\n", markdown_table(table[cols])]
        if len(ratios):
            md += ["\nSpeed-up of `gyro` over scipy DOP853 at equal or better error (same run):\n\n",
                   markdown_table(ratios)]
        md.append(f"\n![{name}]({name}.png)\n")
    with _io.atomic_path(out / "accuracy.md") as tmp:
        tmp.write_text("".join(md))
    print(f"wrote {out / 'accuracy.md'} and one CSV and PNG per scene")
    return EXIT_OK


def _cmd_bench_stability(args: argparse.Namespace) -> int:
    from .report import markdown_table, plot_stability
    from .stability import AGREEMENT_TOL_RAD, INVARIANT_RTOL, run_stability, verdicts

    out = Path(args.out or "bench-stability")
    print(f"stability suite ({'quick' if args.quick else 'full'})", flush=True)
    table = run_stability(quick=args.quick, progress=lambda m: print("  " + m, flush=True))
    summary = verdicts(table)
    _io.write_csv(table, out / "stability.csv")
    fig = plot_stability(table)
    with _io.atomic_path(out / "stability.png") as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    detail_cols = [c for c in ["case", "method", "resolved_method", "status", "wall_time_s", "n_rhs_evaluations",
                               "quaternion_norm_drift", "energy_J_drift", "l_vertical_kg_m2_s_drift",
                               "l_axial_kg_m2_s_drift", "max_energy_rise", "max_tip_error_vs_reference_rad",
                               "energy_drift_per_spin_period", "reference"] if c in table]
    md = (f"# Stability on stiff and extreme cases\n\nChecks: |q| drift <= 1e-9; conserved quantities drift <= "
          f"{INVARIANT_RTOL:g} (relative; long run 1e-6); energy never rises when damped; tip within "
          f"{AGREEMENT_TOL_RAD:g} rad of the reference (exact solution, or gyro-radau at rtol 1e-11).\n\n"
          "## Verdicts (automatic method choice)\n\n" + markdown_table(summary)
          + "\n## Every run\n\n" + markdown_table(table[detail_cols]) + "\n![matrix](stability.png)\n")
    with _io.atomic_path(out / "stability.md") as tmp:
        tmp.write_text(md)
    print(summary.to_string(index=False))
    long = table[table.case.str.startswith("long-run")]
    if len(long) and "energy_drift_per_spin_period" in long:
        r = long.iloc[0]
        print(f"long run: relative energy drift {r.energy_J_drift:.3g} over the run, "
              f"{r.energy_drift_per_spin_period:.3g} per spin period, {r.wall_time_s:.1f} s wall")
    print(f"wrote {out / 'stability.md'}, {out / 'stability.csv'}, {out / 'stability.png'}")
    return EXIT_OK if (summary.verdict == "pass").all() else EXIT_FAILED


def _progress_printer(label: str):
    """A progress bar on a terminal (stderr); elsewhere (a log file) a line at every tenth of the work."""
    tty = sys.stderr.isatty()
    start = time.perf_counter()
    logged = [-1]

    def show(done: int, total: int) -> None:
        if not tty:
            tenth = 10 * done // max(total, 1)
            if tenth > logged[0]:
                logged[0] = tenth
                sys.stderr.write(f"{label}: {done}/{total} after {time.perf_counter() - start:.0f} s\n")
                sys.stderr.flush()
            return
        frac = done / max(total, 1)
        rate = done / max(time.perf_counter() - start, 1e-9)
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{label} [{bar:<30}] {done}/{total} ({rate:.0f}/s)")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


def _cmd_render(args: argparse.Namespace) -> int:
    from .render import render_video

    protocol = load_protocol(args.protocol)
    out = Path(args.out)
    summary = render_video(protocol, out, seed=args.seed, codec=args.codec, duration_s=args.duration,
                           calibration_views=args.calibration_views, progress=_progress_printer("render"))
    n, r, e = summary["frames"], summary["render_s"], summary["encode_s"]
    print(f"{protocol.name}: {n} frames -> {summary['video']} (rendering {n / max(r, 1e-9):.0f} frames/s, "
          f"encoding {n / max(e, 1e-9):.0f} frames/s); truth.csv, camera.json"
          + (f", calibration/ ({summary['calibration']['views']} views)" if summary["calibration"] else ""))
    return EXIT_OK


def _cmd_bench_render(args: argparse.Namespace) -> int:
    from .bench import render_throughput

    table = render_throughput(n_frames=args.frames)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.out:
        _io.write_csv(table, Path(args.out) / "render.csv")
    return EXIT_OK


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from .calibration import CalibrationError, calibrate_camera

    try:
        cols, rows = (int(v) for v in args.board.lower().split("x"))
    except ValueError:
        raise ValueError(f"--board {args.board!r}: expected COLSxROWS inner corners, e.g. 9x6") from None
    try:
        result = calibrate_camera(args.images, cols=cols, rows=rows, square_m=args.square_mm / 1000.0)
    except CalibrationError as exc:
        print(f"gyrorig: calibration refused: {exc}", file=sys.stderr)
        return EXIT_FAILED
    for name, err in result.per_image_rms_px.items():
        print(f"  {name}: {err:.3f} px")
    if result.not_found:
        print(f"  board not found in: {', '.join(result.not_found)}")
    k = result.camera_matrix
    print(f"RMS reprojection error {result.rms_px:.3f} px; fx {k[0, 0]:.2f}, fy {k[1, 1]:.2f}, "
          f"cx {k[0, 2]:.2f}, cy {k[1, 2]:.2f}, dist {np.round(result.dist_coeffs, 5).tolist()}")
    _io.write_json(result.to_json(), args.out)
    print(f"wrote {args.out}, with the intrinsics' covariance (tracking propagates it into the error bars). It has no "
          "pose: `gyrorig track` finds it from the protocol's lab fiducials, or add rvec, tvec relative to the pivot")
    return EXIT_OK


def _cmd_track(args: argparse.Namespace) -> int:
    from .tracking import TrackingError, load_camera, track_video

    protocol = load_protocol(args.protocol)
    try:
        summary = track_video(args.video, load_camera(args.camera, require_pose=False), protocol, args.out,
                              progress=_progress_printer("track"), frame_dots=not args.tip_only)
    except TrackingError as exc:
        print(f"gyrorig: tracking failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    n = summary["frames"]
    if summary["pose"]:
        pose = summary["pose"]
        print(f"camera pose from {len(pose['fiducials_matched'])} fiducials ({', '.join(pose['fiducials_matched'])}), "
              f"reprojection error {pose['pose_rms_px']:.3f} px: rvec {np.round(summary['rvec'], 5).tolist()}, "
              f"tvec {np.round(summary['tvec'], 5).tolist()} m")
    if summary["camera_modes"]:
        sth, sph = summary["camera_sigma_rad"]
        print(f"camera model uncertainty: {summary['camera_modes']} modes, RMS {sth:.2g} rad in theta, {sph:.2g} rad in "
              "phi, common to all frames (columns theta_cam_k_rad, phi_cam_k_rad; the fit includes them)")
    else:
        print("camera model taken as exact (camera.json has no intrinsics_covariance or pose_covariance)")
    print(f"{n} frames, tip tracked in {summary['tracked_fraction']:.1%}; "
          f"{n / (summary['track_s'] + summary['decode_s']):.0f} frames/s -> {summary['angles']}, {summary['markers']}")
    return EXIT_OK


def _cmd_bench_track(args: argparse.Namespace) -> int:
    from .bench import track_benchmark

    sizes = ((640, 480),) if args.quick else ((1440, 1080), (640, 480))
    table = track_benchmark(duration_s=args.duration, sizes=sizes)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.out:
        _io.write_csv(table, Path(args.out) / "track.csv")
    return EXIT_OK


def _cmd_bench_fit(args: argparse.Namespace) -> int:
    from .bench import FIT_MC_SCENES, combine_fit_runs, fit_monte_carlo, summarize_fit_monte_carlo

    if args.combine:
        runs = combine_fit_runs(args.combine)
        table = summarize_fit_monte_carlo(runs)
        lengths = (", ".join(f"{s} {d:g} s" for s, d in runs.groupby("scene").duration_s.first().items())
                   if "duration_s" in runs else "lengths not recorded")
        print(f"{len(args.combine)} batch(es) combined: {runs.groupby('scene').seed.nunique().to_dict()} seeds "
              f"({lengths})")
    else:
        scenes = args.scenes or (FIT_MC_SCENES[:1] if args.quick else FIT_MC_SCENES)
        seeds = args.seeds if args.seeds is not None else (4 if args.quick else 40)
        start = time.perf_counter()
        runs = fit_monte_carlo(scenes, seeds=seeds, duration_s=args.duration, workers=args.workers,
                               progress=_progress_printer("runs"), first_seed=args.first_seed, terms=args.terms)
        table = summarize_fit_monte_carlo(runs)
        print(f"{len(scenes)} scene(s) x {seeds} seeds (from {args.first_seed}), {args.duration:g} s of 640x480 "
              f"video each, model terms {args.terms}, {time.perf_counter() - start:.0f} s")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if table.attrs.get("failed_runs"):
        print(f"{table.attrs['failed_runs']} run(s) failed: see runs.csv")
    print("targets: |mean pull| <= 0.2, sd of pulls 0.9-1.1, sd / CRB <= 1.2")
    if args.out:
        _io.write_csv(runs, Path(args.out) / "runs.csv")
        _io.write_csv(table, Path(args.out) / "fit.csv")
    return EXIT_OK


def _cmd_plan(args: argparse.Namespace) -> int:
    from .plan import DEFAULT_PLAN_DRAWS, monte_carlo_check, parse_sweep, plan_experiment, plot_sweep, sweep

    out = Path(args.out) if args.out else None
    if args.sweep:
        if not args.protocol:
            raise ValueError("plan --sweep needs a protocol file")
        for spec in args.sweep:
            key, values = parse_sweep(spec)
            table = sweep(args.protocol, key, values, duration_s=args.duration, progress=_progress_printer("sweep"))
            print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
            if out:
                name = key.replace(".", "_")
                _io.write_csv(table, out / f"sweep_{name}.csv")
                with _io.atomic_path(out / f"sweep_{name}.png") as tmp:
                    plot_sweep(table, key).savefig(tmp, format="png", dpi=100)
                print(f"-> {out / f'sweep_{name}.csv'}, {out / f'sweep_{name}.png'}")
        return EXIT_OK
    if not args.protocol:
        raise ValueError("plan needs a protocol file")
    protocol = load_protocol(args.protocol)
    plan = plan_experiment(protocol, duration_s=args.duration,
                           draws=args.draws if args.draws is not None else DEFAULT_PLAN_DRAWS,
                           rng=np.random.default_rng(args.seed), progress=_progress_printer("noisy draws"))
    if args.monte_carlo:
        table = monte_carlo_check(protocol, args.monte_carlo, duration_s=args.mc_duration, scheduler=args.scheduler,
                                  progress=_progress_printer("monte carlo"))
        plan["monte_carlo"] = {"duration_s": args.mc_duration, "runs": args.monte_carlo,
                               "failed_runs": table.attrs.get("failed_runs", 0),
                               "table": table.to_dict(orient="records")}
    doc = _io.json_safe(plan)
    if out:
        _io.write_json(doc, out / "plan.json")
    if args.json:
        print(json.dumps(doc, indent=2, sort_keys=True))
        return EXIT_OK
    _print_plan(plan)
    if out:
        print(f"-> {out / 'plan.json'}")
    return EXIT_OK


def _print_plan(plan: dict) -> None:
    from .plan import MISFIT_NOTE

    print(f"plan for {plan['protocol']}")
    cam = plan.get("camera")
    if cam:
        print(f"  camera: {cam['fps']:g} fps, {cam['exposure_s'] * 1e6:.0f} us; tip marker {cam['radius_px']:.1f} px "
              f"radius, {cam['signal_adu']:.0f} ADU on {cam['background_adu']:.0f}; localisation bound "
              f"{cam['sigma_px']:.4f} px -> theta {cam['theta_sigma_rad_median']:.2e} rad, phi "
              f"{cam['phi_sigma_rad_median']:.2e} rad per frame")
        if "nutation_hz" in cam:
            print(f"  nutation {cam['nutation_hz']:.3g} Hz: {cam['frames_per_nutation_period']:.1f} frames per period, "
                  f"amplitude {cam.get('nutation_amplitude_px', float('nan')):.2f} px "
                  f"({cam.get('nutation_amplitude_over_sigma_px', float('nan')):.3g} x the bound)")
        print(f"  motion blur {cam['motion_blur_px']:.2f} px; rolling-shutter skew {cam['rolling_shutter_skew_px']:.2f} px"
              f"; saturates: {cam['saturates']}")
        rec = plan["recording"]
        print(f"  expected errors for a {rec['length_s']:g} s record (Cramer-Rao bound of the fit):")
        for name, q in plan["quantities"].items():
            if not q["resolvable"]:
                print(f"    {name}: not resolvable: {q['reason']}")
                continue
            pe = q.get("paper_vs_exact_in_se")
            print(f"    {name}: {q['simulated']:.6g} +- {q['expected_standard_error']:.2g} {q['units']}"
                  + (f" (paper {q['predicted_paper']:.6g}: {pe:+.3g} s.e. from exact)" if pe is not None else "")
                  + ("" if q.get("reliable", True) else "  [not reliable at this length]"))
        mf = rec.get("model_misfit")
        if mf:
            print(f"  fit model on the simulated record: chi-square {mf['noiseless_chi2']:.3g} for {mf['dof']} degrees "
                  f"of freedom ({mf['chi2_per_dof']:.2g} per degree of freedom"
                  + ("; describes the motion)" if mf["chi2_per_dof"] <= MISFIT_NOTE else "; MISSES part of the motion)"))
        draws = rec.get("noisy_draws")
        if draws and draws["draws"]:
            rms = draws["rms_departure_se"]
            print(f"  {draws['draws']} noisy records fitted in full: {draws['draws'] - draws['failed']} converged; "
                  f"distance from the linearised fit (root mean square) at most "
                  f"{max(rms.values(), default=0.0):.2g} s.e."
                  + (f" ({max(rms, key=rms.get)})" if rms else "")
                  + (": linear over the noise" if draws["ok"] else
                     f": NOT linear over the noise ({', '.join(draws['nonlinear']) or 'failed draws'})"))
        print(f"  note: {plan['note']}")
    for r in plan["recommendations"]:
        print(f"  - {r}")
    mc = plan.get("monte_carlo")
    if mc:
        import pandas as pd

        print(f"  Monte Carlo of render -> track -> smooth -> fit ({mc['runs']} runs of {mc['duration_s']:g} s, "
              f"{mc['failed_runs']} failed):")
        print(pd.DataFrame(mc["table"]).to_string(index=False, float_format=lambda v: f"{v:.3g}"))


def _cmd_bench_smooth(args: argparse.Namespace) -> int:
    from .bench import smooth_benchmark

    r = smooth_benchmark(args.frames, args.filterpy_frames)
    print(f"compiled smoother (filter + RTS), {r['frames']:,} frames: {r['fast_s']:.3f} s "
          f"({r['fast_us_per_frame']:.2f} us/frame; target < 0.2 s)")
    print(f"filterpy 2.0 KalmanFilter + rts_smoother, same model, {r['filterpy_frames']:,} frames: {r['filterpy_s']:.2f} s "
          f"({r['filterpy_us_per_frame']:.0f} us/frame): {r['speedup']:.0f}x slower per frame")
    print(f"agreement: states {r['max_state_diff_in_sigma']:.1e} sigma; covariances {r['max_cov_diff_rel_after_first']:.1e} "
          f"of sqrt(P_ii P_jj) (first frame {r['max_cov_diff_rel_first']:.1e}); same gating: {r['same_gating']}")
    print(f"maximum-likelihood noise levels: {r['ml_noise_s']:.2f} s ({r['ml_evaluations']} filter passes)")
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    import pandas as pd

    from .camera import with_image_size
    from .render import render_video
    from .report import plot_tracking, plot_trajectory
    from .theory import predict
    from .tracking import load_camera, track_video

    out = Path(args.out)
    path = BUNDLED_PROTOCOL_DIR / DEMO_PROTOCOL
    if not path.exists():
        raise ProtocolError(f"bundled protocol {DEMO_PROTOCOL} not found at {path}: install gyrorig from a clone "
                            "of the repository with 'pip install -e .'")
    protocol = load_protocol(path)
    start = time.perf_counter()
    print(f"demo: {protocol.description}")

    # 1. simulate, and judge the simulator by the exact solution
    print(f"[1/5] simulating {args.duration:g} s ...", flush=True)
    t0 = time.perf_counter()
    simulate(protocol, duration_s=0.01)  # compiles the integrator on first use (then cached on disk)
    if time.perf_counter() - t0 > 0.5:
        print(f"      (compiled the integrator once: {time.perf_counter() - t0:.1f} s)")
    df, info = simulate(protocol, duration_s=args.duration, rate_hz=500.0, return_info=True)
    sol = exact_solution(protocol)
    ref = sol.evaluate(df.t_s.to_numpy())
    tips = ["tip_x", "tip_y", "tip_z"]
    err = float(np.linalg.norm(df[tips].to_numpy() - ref[tips].to_numpy(), axis=1).max())
    fig = plot_trajectory(df, reference=ref, title=f"{protocol.name}: simulator ({info.method}) vs exact solution")
    with _io.atomic_path(out / "trajectory.png") as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    _io.write_csv(df, out / "trajectory.csv")
    th_min, th_max = sol.tilt_range_rad
    print(f"      method {info.method}: {info.wall_time_s * 1e3:.1f} ms, max tip error vs exact {err:.1e} rad; "
          f"tilt {np.degrees(th_min):.3f}..{np.degrees(th_max):.3f} deg, nutation "
          f"{sol.nutation_frequency_rad_s / (2 * np.pi):.3f} Hz, mean precession {sol.mean_precession_rate_rad_s:.4f} rad/s")

    # 2. the paper's predictions for this rig, judged
    print("[2/5] the paper's formulas for this rig (paper / exact):", flush=True)
    pred = predict(protocol, simulate_damping=False)
    _io.write_json(_io.json_safe(pred), out / "theory.json")
    for key in ("precession_rate_slow_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad",
                "mean_precession_rate_rad_s"):
        v = pred[key]
        flag = "  ** WRONG SIGN **" if v.get("sign_agrees") is False else ""
        print(f"      {key}: {v['paper']:.5g} / {v['exact']:.5g} ({v['relative_difference']:+.1%}){flag}")
    print(f"      fast-top ratio {pred['flags']['fast_top_ratio']:.2f} (the formulas want >= 10)")

    # 3. a short synthetic video through the rig's camera (640x480 here, for speed)
    print(f"[3/5] rendering {args.video_duration:g} s of video (640x480, 200 fps) ...", flush=True)
    video_protocol = with_image_size(protocol, 640, 480)
    rendered = render_video(video_protocol, out / "video", seed=0, duration_s=args.video_duration, calibration_views=0,
                            progress=_progress_printer("      render"))

    # 4. track it without looking at the truth, then compare
    print("[4/5] tracking the tip marker ...", flush=True)
    tracked = track_video(rendered["video"], load_camera(out / "video" / "camera.json"), video_protocol,
                          out / "track", progress=_progress_printer("      track"))
    angles = pd.read_csv(out / "track" / "angles.csv").dropna(subset=["theta_rad"])
    truth = simulate(protocol, t_eval_s=angles.t_s.to_numpy())
    e_th = angles.theta_rad.to_numpy() - truth.theta_rad.to_numpy()
    e_ph = np.angle(np.exp(1j * (angles.phi_rad.to_numpy() - truth.phi_rad.to_numpy())))
    fig = plot_tracking(angles, truth, title="tip tracked from the synthetic video vs the simulator")
    with _io.atomic_path(out / "tracking.png") as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    print(f"      {tracked['tracked_fraction']:.1%} of {tracked['frames']} frames tracked; theta error "
          f"{np.sqrt(np.mean(e_th**2)):.2e} rad rms (reported sigma {angles.theta_sigma_rad.mean():.2e}), "
          f"phi error {np.sqrt(np.mean(e_ph**2)):.2e} rad rms (sigma {angles.phi_sigma_rad.mean():.2e})")
    # 5. smooth, fit against theory, report
    print("[5/5] smoothing, fitting and writing the report ...", flush=True)
    from .analysis import fit_file, quality_counts, write_report
    from .smooth import smooth_angles

    raw = pd.read_csv(out / "track" / "angles.csv")
    smooth = smooth_angles(raw)
    _io.write_csv(smooth.table, out / "smoothed.csv")
    full_pred = predict(protocol)
    fit = fit_file(out / "track" / "angles.csv", video_protocol, out, truth_csv=out / "video" / "truth.csv",
                   smooth=smooth, prediction=full_pred)
    write_report(out / "report.html", protocol=video_protocol, fit=fit, angles=raw, smooth=smooth,
                 prediction=full_pred, title=f"gyrorig demo: {protocol.name}",
                 tracking={"frames": tracked["frames"], "quality_counts": quality_counts(raw)})
    print(f"      {'quantity':<26} {'paper':>11} {'exact':>11} {'fitted':>11} {'+- s.e.':>9} {'true':>11} {'pull':>6}")
    for name, q in fit.quantities.items():
        if q.status != "determined":
            print(f"      {name:<26} undetermined: {q.reason}")
            continue
        f = lambda v: "-" if v is None else f"{v:.6g}"  # noqa: E731
        pull = "-" if q.pull is None else f"{q.pull:+.2f}"
        print(f"      {name:<26} {f(q.paper):>11} {f(q.exact):>11} {q.value:>11.6g} {q.standard_error:>9.2g} "
              f"{f(q.truth):>11} {pull:>6}")
    _io.write_json({"command": "demo", "protocol": _protocol_summary(protocol), "simulation": asdict(info),
                    "max_tip_error_vs_exact_rad": err, "tracking": {k: v for k, v in tracked.items()},
                    "fit": {k: q.as_dict() for k, q in fit.quantities.items()},
                    "wall_time_s": time.perf_counter() - start, "versions": _io.versions()}, out / "manifest.json")
    print(f"done in {time.perf_counter() - start:.0f} s. Report: {out / 'report.html'} (open it in a browser); "
          f"plots {out / 'trajectory.png'}, {out / 'tracking.png'}, {out / 'fit.png'}; data in {out}/")
    return EXIT_OK


def _print_fit(fit, out: Path) -> None:
    print(f"fit: {fit.spec.harmonics} nutation harmonic(s), axis {'fitted' if fit.spec.fit_axis else 'vertical'}, "
          f"{'damped' if fit.spec.damped else 'undamped'}; chi2_red {fit.chi2_red:.3f}; errors {fit.errors}")
    for name, q in fit.quantities.items():
        if q.status != "determined":
            print(f"  {name}: undetermined ({q.reason})")
            continue
        line = f"  {name}: {q.value:.7g} +- {q.standard_error:.2g} {q.units}"
        if q.camera_standard_error:
            line += f" (camera model {q.camera_standard_error:.2g} of it)"
        if q.paper is not None and q.diff_paper_se is not None:
            line += f"; paper {q.paper:.6g} ({q.diff_paper_se:+.1f} s.e.)"
        if q.exact is not None and q.diff_exact_se is not None:
            line += f"; exact {q.exact:.6g} ({q.diff_exact_se:+.1f} s.e.)"
        if q.truth is not None:
            line += f"; truth {q.truth:.7g} (pull {q.pull:+.2f})"
        print(line)
    for n in fit.notes:
        print(f"  note: {n}")
    print(f"-> {out / 'fit.json'}, {out / 'fit.png'}, {out / 'fit_residuals.csv'}")


def _cmd_smooth(args: argparse.Namespace) -> int:
    from .analysis import smooth_file

    out = Path(args.out)
    res = smooth_file(args.angles, out)
    print(f"{len(res.table)} frames: {res.n_measured} used, {res.n_outliers} outliers gated, {res.n_resets} restarts; "
          f"q_theta {res.q_theta_rad2_s3:.3g}, q_phi {res.q_phi_rad2_s3:.3g} rad^2/s^3 (maximum likelihood); "
          f"mean NIS {res.nis_mean:.3f} (2 expected); {res.wall_time_s:.2f} s -> {out / 'smoothed.csv'}")
    return EXIT_OK


def _terms_arg(value: str):
    """``--terms``: 'data', or a JSON file with the fit terms (a plan.json's ``fit_terms``, or the terms alone)."""
    from .fit import FitTerms

    if value == "data":
        return "data"
    path = Path(value)
    if not path.is_file():
        raise ValueError(f"--terms: expected 'data' or a plan.json from 'gyrorig plan --out DIR'; {value} is not a file")
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"--terms: {value} is not JSON ({exc})") from exc
    terms = doc.get("fit_terms", doc) if isinstance(doc, dict) else None
    if not isinstance(terms, dict):
        raise ValueError(f"--terms: {value} has no fit_terms object")
    return FitTerms.from_dict(terms)


def _add_fit_options(parser: argparse.ArgumentParser) -> None:
    """``--truth`` and ``--terms``, shared by fit and analyze."""
    parser.add_argument("--truth", default=None, help="truth.csv of a synthetic run: adds true values and pulls")
    parser.add_argument("--terms", default="data",
                        help="how the model's optional terms (nutation harmonics, damped-scene terms) are chosen: "
                        "'data' (default) by chi-square tests on this record, or a plan.json from 'gyrorig plan "
                        "--duration T --out DIR' (its fit_terms: the same model for every record of the scene)")


def _cmd_fit(args: argparse.Namespace) -> int:
    from .analysis import fit_file

    out = Path(args.out)
    fit = fit_file(args.angles, load_protocol(args.protocol), out, truth_csv=args.truth, terms=_terms_arg(args.terms))
    _print_fit(fit, out)
    return EXIT_OK


def _cmd_analyze(args: argparse.Namespace) -> int:
    from .analysis import analyze_batch, analyze_video
    from .tracking import TrackingError

    src = Path(args.video)
    out = Path(args.out)
    protocol = load_protocol(args.protocol) if args.protocol else None
    if src.is_dir() or src.suffix.lower() == ".csv":
        summary = analyze_batch(src, out, camera=args.camera, protocol=protocol, progress_line=print,
                                terms=_terms_arg(args.terms))
        ok = int((summary.status == "ok").sum())
        print(f"{ok} of {len(summary)} videos analysed -> {out / 'summary.csv'}")
        return EXIT_OK if ok == len(summary) else EXIT_FAILED
    if protocol is None or args.camera is None:
        raise ValueError("analyze VIDEO needs --camera and --protocol")
    try:
        res = analyze_video(src, args.camera, protocol, out, truth_csv=args.truth, progress=_progress_printer("track"),
                            terms=_terms_arg(args.terms),
                            stage=lambda msg: print(msg, flush=True))
    except TrackingError as exc:
        print(f"gyrorig: tracking failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    ts = res["time_s"]
    print(f"{res['frames']} frames, {res['tracked_fraction']:.1%} tracked; track {ts['track']:.1f} s, smooth "
          f"{ts['smooth']:.2f} s, fit {ts['fit']:.2f} s")
    _print_fit(res["fit"], out)
    print(f"report: {res['report']}")
    return EXIT_OK


def _print_prediction(pred: dict) -> None:
    print(f"{pred['protocol']}: theory for this scene (paper as printed / corrected / exact or simulated)")
    for k, v in pred["flags"].items():
        print(f"  flag {k} = {v:.4g}" if isinstance(v, float) else f"  flag {k} = {v}")
    fmt = lambda x: "-" if x is None else (f"{x:.6g}" if isinstance(x, float) else str(x))  # noqa: E731
    for key, v in pred.items():
        if key in ("protocol", "flags"):
            continue
        if key == "equilibrium_tip":
            print(f"  {key}: paper {np.round(v['paper'], 5).tolist()}, exact {np.round(v['exact'], 5).tolist()}, "
                  f"{v['angle_between_rad']:.4g} rad apart; leans towards the acceleration: "
                  f"paper {v['leans_towards_acceleration']['paper']}, exact {v['leans_towards_acceleration']['exact']}")
            continue
        line = f"  {key}: paper {fmt(v.get('paper'))}"
        if "corrected" in v:
            line += f", corrected {fmt(v['corrected'])}"
        line += f", exact {fmt(v.get('exact'))} ({v['exact_source']})"
        if "relative_difference" in v:
            line += f"; paper off by {v['relative_difference']:+.2%}"
        if v.get("sign_agrees") is False:
            line += "  ** WRONG SIGN **"
        if "direction" in v:
            line += f"; direction: paper {v['direction']['paper']}, simulated {v['direction']['exact']}"
        print(line)


def _cmd_theory(args: argparse.Namespace) -> int:
    from . import theory

    if args.validate:
        return _cmd_validate(args)
    if not args.protocol:
        raise ValueError("give a PROTOCOL, or --validate")
    pred = theory.predict(load_protocol(args.protocol), simulate_damping=not args.no_simulate)
    if args.json:
        print(json.dumps(_io.json_safe(pred), indent=2))
    else:
        _print_prediction(pred)
    return EXIT_OK


def _cmd_validate(args: argparse.Namespace) -> int:
    from .report import markdown_table, plot_validation
    from .validation import summarize, validate

    out = Path(args.out or "theory-validation")
    print(f"validating the paper's formulas against the simulator ({'quick' if args.quick else 'full'} sweeps)",
          flush=True)
    table = validate(quick=args.quick, progress=lambda m: print("  " + m, flush=True))
    summary = summarize(table)
    _io.write_csv(table, out / "validation.csv")
    _io.write_csv(summary, out / "summary.csv")
    cols = ["formula", "equation", "fast_top_ratio", "tilt_rad", "params", "paper", "corrected", "exact",
            "simulator", "rel_error_paper", "rel_error_corrected", "sign_agrees_paper", "in_regime"]
    md = ("# The paper's formulas judged by the simulator\n\n"
          "Relative errors are against the value measured by the simulator. `in_regime`: fast-top ratio >= 10 "
          "(fast-top formulas) or tilt <= 0.3 rad (small-angle formulas). Derivations of the corrected forms: "
          "`docs/theory.md`.\n\n## Verdicts\n\n" + markdown_table(summary)
          + "\n## All points\n\n" + markdown_table(table[cols]))
    with _io.atomic_path(out / "validation.md") as tmp:
        tmp.write_text(md)
    fig = plot_validation(table)
    with _io.atomic_path(out / "validation.png") as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    print(summary[["formula", "equation", "verdict"]].to_string(index=False))
    print(f"wrote {out / 'validation.md'}, {out / 'validation.csv'}, {out / 'summary.csv'}, {out / 'validation.png'}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (exposed for documentation and tests)."""
    p = argparse.ArgumentParser(prog="gyrorig", description=__doc__.splitlines()[0])
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="integrate a protocol's scene; write trajectory.csv and manifest.json")
    s.add_argument("protocol", help="protocol TOML file")
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--method", default="auto", choices=["auto", "exact", *METHODS],
                   help="integration method (default: chosen from the scene); 'exact' for undamped scenes")
    s.add_argument("--rtol", type=float, default=None, help="relative tolerance (default per method)")
    s.add_argument("--atol", type=float, default=None, help="absolute tolerance (default rtol/100)")
    s.add_argument("--duration", type=float, default=None, help="override scene.duration_s [s]")
    s.add_argument("--rate", type=float, default=None, help="output sample rate [Hz]")
    s.set_defaults(func=_cmd_simulate)

    b = sub.add_parser("bench", help="benchmarks that print figures")
    bsub = b.add_subparsers(dest="bench", required=True)
    bm = bsub.add_parser("methods", help="error against the exact solution and wall time of each method")
    bm.add_argument("protocol")
    bm.add_argument("--duration", type=float, default=10.0, help="simulated time [s] (default 10)")
    bm.add_argument("--rate", type=float, default=100.0, help="comparison sample rate [Hz]")
    bm.add_argument("--methods", nargs="+", default=None, help="methods to run (default: all but RK23)")
    bm.add_argument("--rtol", type=float, default=None, help="one tolerance for all methods")
    bm.add_argument("--repeats", type=int, default=1, help="median of this many timings")
    bm.add_argument("--out", default=None, help="also write methods.csv here")
    bm.set_defaults(func=_cmd_bench_methods)
    ba = bsub.add_parser("accuracy", help="work-precision study: error against wall time of every method")
    ba.add_argument("--quick", action="store_true", help="two scenes, short tolerance ladders (< 1 minute)")
    ba.add_argument("--out", default=None, help="output directory (default ./bench-accuracy)")
    ba.set_defaults(func=_cmd_bench_accuracy)
    bs = bsub.add_parser("stability", help="stiff and extreme cases: invariants, agreement, verdict per case")
    bs.add_argument("--quick", action="store_true", help="shorter runs (long run: 1e4 instead of 1e6 spin periods)")
    bs.add_argument("--out", default=None, help="output directory (default ./bench-stability)")
    bs.set_defaults(func=_cmd_bench_stability)
    br = bsub.add_parser("render", help="rendering and encoding throughput (frames per second)")
    br.add_argument("--frames", type=int, default=100, help="frames per measurement")
    br.add_argument("--out", default=None, help="also write render.csv here")
    br.set_defaults(func=_cmd_bench_render)
    bt = bsub.add_parser("track", help="tracking precision against the Cramer-Rao bound, pull widths, speed")
    bt.add_argument("--duration", type=float, default=1.0, help="video length [s] (default 1)")
    bt.add_argument("--quick", action="store_true", help="640x480 only")
    bt.add_argument("--out", default=None, help="also write track.csv here")
    bt.set_defaults(func=_cmd_bench_track)

    bsm = bsub.add_parser("smooth", help="compiled smoother against filterpy: speed and agreement")
    bsm.add_argument("--frames", type=int, default=100_000, help="frames for the compiled path (default 100000)")
    bsm.add_argument("--filterpy-frames", type=int, default=20_000, help="frames for filterpy (default 20000)")
    bsm.set_defaults(func=_cmd_bench_smooth)
    bf = bsub.add_parser("fit", help="Monte Carlo of render -> track -> smooth -> fit: pulls, bias, sd / CRB")
    bf.add_argument("--scenes", nargs="+", default=None, help="bundled protocol names (default: three rigs)")
    bf.add_argument("--seeds", type=int, default=None, help="runs per scene (default 40; 4 with --quick)")
    bf.add_argument("--duration", type=float, default=2.0, help="video length [s] (default 2)")
    bf.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    bf.add_argument("--first-seed", type=int, default=0, help="seeds run from this one (default 0)")
    bf.add_argument("--terms", choices=("planned", "data"), default="planned",
                    help="'planned' (default): each scene's model terms are chosen once by the plan for the "
                         "record length, before the runs; 'data': by chi-square tests in each run")
    bf.add_argument("--quick", action="store_true", help="one scene, 4 seeds")
    bf.add_argument("--out", default=None, help="also write runs.csv and fit.csv here")
    bf.add_argument("--combine", nargs="+", default=None, metavar="DIR",
                    help="run nothing: summarise the runs.csv of earlier --out batches together "
                         "(batches must have distinct seeds)")
    bf.set_defaults(func=_cmd_bench_fit)

    pl = sub.add_parser("plan", help="what a rig and camera will measure: resolution, expected errors, advice")
    pl.add_argument("protocol", nargs="?", help="protocol TOML file")
    pl.add_argument("--json", action="store_true", help="print JSON")
    pl.add_argument("--out", default=None, help="write plan.json (and sweep tables/plots) here")
    pl.add_argument("--duration", type=float, default=None, help="recording length [s] (default: scene.duration_s, at most 20)")
    pl.add_argument("--draws", type=int, default=None, metavar="N",
                    help="noisy records fitted in full to check that the fit converges and is linear over the noise "
                         "at this length (default 8; 0 skips)")
    pl.add_argument("--seed", type=int, default=0, help="seed of those draws")
    pl.add_argument("--monte-carlo", type=int, default=0, metavar="N",
                    help="confirm the expected errors with N runs of render -> track -> smooth -> fit")
    pl.add_argument("--mc-duration", type=float, default=2.0, help="video length of each Monte Carlo run [s]")
    pl.add_argument("--scheduler", default=None, help="Dask scheduler address for the Monte Carlo (gyrorig[dask])")
    pl.add_argument("--sweep", nargs="+", default=None, metavar="KEY=START:STOP:N",
                    help="scan protocol keys, e.g. launch.spin_rate_rad_s=200:800:7 camera.fps=50:400:8")
    pl.set_defaults(func=_cmd_plan)

    t = sub.add_parser("theory", help="the paper's predictions for a scene, or --validate them all")
    t.add_argument("protocol", nargs="?", help="protocol TOML file")
    t.add_argument("--json", action="store_true", help="print JSON (keys carry units)")
    t.add_argument("--no-simulate", action="store_true", help="skip the simulated damped tilt rate")
    t.add_argument("--validate", action="store_true", help="judge every formula against the simulator over sweeps")
    t.add_argument("--quick", action="store_true", help="with --validate: small sweeps (seconds)")
    t.add_argument("--out", default=None, help="with --validate: output directory (default ./theory-validation)")
    t.set_defaults(func=_cmd_theory)

    r = sub.add_parser("render", help="synthetic video of a protocol's scene, with truth and calibration images")
    r.add_argument("protocol", help="protocol TOML file with [camera] and [markers]")
    r.add_argument("--out", required=True, help="output directory")
    r.add_argument("--seed", type=int, default=0, help="noise seed (same seed, same bits)")
    r.add_argument("--codec", choices=["lossless", "raw", "mp4"], default="lossless",
                   help="lossless: video.mkv (FFV1); raw: video.avi (uncompressed 8-bit, 1.5 MB per 1440x1080 frame, "
                        "decodes ~50x faster); mp4: video.mp4 (mp4v, 8-bit, lossy)")
    r.add_argument("--duration", type=float, default=None, help="override scene.duration_s [s]")
    r.add_argument("--calibration-views", type=int, default=12, help="checkerboard images (0: none)")
    r.set_defaults(func=_cmd_render)

    c = sub.add_parser("calibrate", help="camera calibration from checkerboard images (OpenCV)")
    c.add_argument("images", help="directory of checkerboard images")
    c.add_argument("--board", required=True, help="inner corners COLSxROWS, e.g. 9x6")
    c.add_argument("--square-mm", type=float, required=True, help="square size [mm]")
    c.add_argument("--out", required=True, help="camera.json to write")
    c.set_defaults(func=_cmd_calibrate)

    k = sub.add_parser("track", help="track the markers: video -> angles.csv, markers.csv")
    k.add_argument("video", help="any video OpenCV can decode")
    k.add_argument("--camera", required=True, help="camera.json with intrinsics and the pose relative to the pivot")
    k.add_argument("--protocol", required=True, help="protocol with the [markers] geometry")
    k.add_argument("--out", required=True, help="output directory")
    k.add_argument("--tip-only", action="store_true",
                   help="skip the frame's off-axis dots (no psi_rad; about twice as fast)")
    k.set_defaults(func=_cmd_track)

    sm = sub.add_parser("smooth", help="Kalman/RTS smoothing of angles.csv (noise levels by maximum likelihood)")
    sm.add_argument("angles", help="angles.csv from 'gyrorig track'")
    sm.add_argument("--out", required=True, help="output directory (smoothed.csv, smooth.json)")
    sm.set_defaults(func=_cmd_smooth)

    f = sub.add_parser("fit", help="least-squares fit of angles.csv with the scene's model, against theory")
    f.add_argument("angles", help="angles.csv from 'gyrorig track'")
    f.add_argument("--protocol", required=True, help="protocol TOML (decides the model)")
    f.add_argument("--out", required=True, help="output directory (fit.json, fit.png, fit_residuals.csv)")
    _add_fit_options(f)
    f.set_defaults(func=_cmd_fit)

    an = sub.add_parser("analyze", help="track -> smooth -> fit -> report.html; a folder or manifest CSV for a batch")
    an.add_argument("video", help="a video, a folder of videos, or a manifest CSV (video, protocol[, camera])")
    an.add_argument("--camera", default=None, help="camera.json")
    an.add_argument("--protocol", default=None, help="protocol TOML")
    an.add_argument("--out", required=True, help="output directory")
    _add_fit_options(an)
    an.set_defaults(func=_cmd_analyze)

    d = sub.add_parser("demo", help="the chain on the bundled air-cushion rig: simulate, theory, render, track, smooth, fit, report")
    d.add_argument("--out", default="gyrorig-demo", help="output directory (default ./gyrorig-demo)")
    d.add_argument("--duration", type=float, default=10.0, help="simulated time [s] (default 10)")
    d.add_argument("--video-duration", type=float, default=3.0, help="length of the rendered video [s] (default 3)")
    d.set_defaults(func=_cmd_demo)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s")
    try:
        return int(args.func(args))
    except (ProtocolError, ExactSolutionError, ValueError) as exc:
        print(f"gyrorig: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SimulationError as exc:
        print(f"gyrorig: simulation failed: {exc}", file=sys.stderr)
        return EXIT_FAILED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
