"""The commands: each parses nothing and computes little; it calls the library and prints what came back."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pandas as pd

from .. import _io
from ..demo import run_demo
from ..physics import METHODS, exact_solution, exact_solution_applies, simulate
from ..physics.exact import ExactSolutionError
from ..physics.simulate import output_times
from .._validate import number
from ..protocols import load_protocol, protocol_summary
from .codes import EXIT_FAILED, EXIT_OK
from .bench_commands import _cmd_bench_length, _cmd_bench_smooth  # noqa: F401 (dispatched by name)
from .camera_commands import _cmd_calibrate, _cmd_pose  # noqa: F401 (dispatched by name)
from .gimbal_commands import gimbal_theory, simulate_gimbal_scene
from .parser import clipped
from .printing import print_data, print_fit, print_plan, print_prediction, progress_printer



def terms_arg(value: str):
    """``--terms``: 'data', or a JSON file with the fit terms (a plan.json's ``fit_terms``, or the terms alone)."""
    from ..fit import FitTerms

    if value == "data":
        return "data"
    path = Path(value)
    if not path.is_file():
        raise ValueError(f"--terms: expected 'data' or a plan.json from 'gyrorig plan --out DIR'; {value} is not a file")
    _io.check_settings_size(path, "plan.json")
    try:
        doc = json.loads(_io.read_settings_text(path))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"--terms: {value} is not JSON ({exc})") from exc
    terms = doc.get("fit_terms", doc) if isinstance(doc, dict) else None
    if not isinstance(terms, dict):
        raise ValueError(f"--terms: {value} has no fit_terms object")
    return FitTerms.from_dict(terms)


def _cmd_simulate(args: argparse.Namespace) -> int:
    protocol = load_protocol(args.protocol)
    out = Path(args.out)
    if protocol.gimbal is not None:
        df, info = simulate_gimbal_scene(protocol, args)
    elif args.method == "exact":
        ok, why = exact_solution_applies(protocol)
        if not ok:
            raise ExactSolutionError(f"--method exact: no exact solution for {protocol.name}: {why}")
        t = output_times(protocol, args.duration, args.rate)
        start = time.perf_counter()
        df = exact_solution(protocol, t)
        info = {"method": "exact", "wall_time_s": time.perf_counter() - start}
    else:
        df, sim_info = simulate(protocol, method=args.method, rtol=args.rtol, atol=args.atol,
                                duration_s=args.duration, rate_hz=args.rate, return_info=True)
        info = asdict(sim_info)
    manifest = {"command": "simulate", "protocol": protocol_summary(protocol), "simulation": info,
                "n_rows": len(df), "columns": list(df.columns), "versions": _io.versions()}
    _io.write_csv(df, out / "trajectory.csv")
    _io.write_json(manifest, out / "manifest.json")
    print(f"{protocol.name}: {len(df)} rows, method {info['method']}, {info['wall_time_s']:.3f} s wall "
          f"-> {out / 'trajectory.csv'}")
    return EXIT_OK


def _cmd_bench_methods(args: argparse.Namespace) -> int:
    from ..bench import DEFAULT_COMPARE_METHODS, compare_methods

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
    from ..bench import accuracy_scenes, speed_ratio, work_precision
    from ..report import markdown_table, plot_work_precision

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
    from ..report import markdown_table, plot_stability
    from ..bench.stability import AGREEMENT_TOL_RAD, INVARIANT_RTOL, run_stability, verdicts

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


def _cmd_render(args: argparse.Namespace) -> int:
    from ..render import render_video

    protocol = load_protocol(args.protocol)
    if args.duration is not None:
        number("", "--duration", args.duration, lo=0.0, lo_open=True, hi=1e5)
    number("", "--calibration-views", args.calibration_views, lo=0, hi=1000)
    number("", "--hold", args.hold, lo=0.0, hi=1e5)
    out = Path(args.out)
    summary = render_video(protocol, out, seed=args.seed, codec=args.codec, duration_s=args.duration,
                           calibration_views=args.calibration_views, progress=progress_printer("render"),
                           hold_s=args.hold)
    n, r, e = summary["frames"], summary["render_s"], summary["encode_s"]
    print(f"{protocol.name}: {n} frames -> {summary['video']} (rendering {n / max(r, 1e-9):.0f} frames/s, "
          f"encoding {n / max(e, 1e-9):.0f} frames/s); truth.csv, camera.json"
          + (f", calibration/ ({summary['calibration']['views']} views)" if summary["calibration"] else ""))
    return EXIT_OK


def _cmd_bench_render(args: argparse.Namespace) -> int:
    from ..bench import render_throughput

    table = render_throughput(n_frames=args.frames)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.out:
        _io.write_csv(table, Path(args.out) / "render.csv")
    return EXIT_OK


def _with_capture_fps(camera, capture_fps: float | None):
    """The camera with ``--capture-fps`` applied (checked: a positive finite rate)."""
    if capture_fps is None:
        return camera
    if not (math.isfinite(capture_fps) and 0 < capture_fps <= 1e6):
        raise ValueError(f"--capture-fps {capture_fps:g}: allowed (0, 1e6] frames per second")
    return replace(camera, capture_fps=float(capture_fps))


def _cmd_track(args: argparse.Namespace) -> int:
    from ..protocols import load_tracking_protocol
    from ..tracking import load_camera, track_video
    from ..tracking.scatter import check_summary

    protocol = load_tracking_protocol(args.protocol)
    camera = _with_capture_fps(load_camera(args.camera, require_pose=False), args.capture_fps)
    from ..tracking.imported import import_pixel_track, is_pixel_track

    if is_pixel_track(args.video):
        if args.start is not None or args.end is not None or args.overlay:
            raise ValueError("--start, --end and --overlay apply to a video, not to a pixel track")
        summary = import_pixel_track(args.video, camera, protocol, args.out, track_name=args.track_name)
        print(f"{summary['frames']} positions from {args.video}: {summary['tracked_fraction']:.1%} with angles, "
              f"{summary['outliers']} outlier(s); errors {summary['sigma_px']:.3g} px ({summary['sigma_source']}) "
              f"-> {summary['angles']}")
        return EXIT_OK
    video = clipped(args.video, args)
    summary = track_video(video, camera, protocol, args.out, progress=progress_printer("track"),
                          frame_dots=not args.tip_only)
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
    check = summary.get("sigma_check")
    if check and check["coordinates"]:
        print(check_summary(check))
    ft = summary.get("frame_times") or {}
    if ft:
        print(f"frame times: median interval {ft['median_interval_s'] * 1e3:.4g} ms ({ft['measured_fps']:.5g} fps; "
              f"camera.json {ft['camera_fps']:g}), jitter {ft['jitter_rel']:.2%}, {ft['dropped_frames']} dropped"
              + ("" if ft["agrees_with_camera"] else f"  ** {ft['warning']} **"))
    print(f"{n} frames, tip tracked in {summary['tracked_fraction']:.1%}; "
          f"{n / (summary['track_s'] + summary['decode_s']):.0f} frames/s -> {summary['angles']}, {summary['markers']}")
    if args.overlay:
        import pandas as pd

        from ..report.overlay import write_overlay

        path = write_overlay(video, pd.read_csv(summary["angles"]), pd.read_csv(summary["markers"]),
                             Path(args.out) / "overlay.png", fps=summary["fps"],
                             time_scale=(summary.get("frame_times") or {}).get("time_scale", 1.0), title=str(video))
        print(f"overlay: {path} (the tip as found in chosen frames, with its path and flags)")
    return EXIT_OK


def _cmd_bench_track(args: argparse.Namespace) -> int:
    from ..bench import track_benchmark

    sizes = ((640, 480),) if args.quick else ((1440, 1080), (640, 480))
    table = track_benchmark(duration_s=args.duration, sizes=sizes)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.out:
        _io.write_csv(table, Path(args.out) / "track.csv")
    return EXIT_OK


def _cmd_bench_variants(args: argparse.Namespace) -> int:
    from ..bench.variants import VARIANTS, VIDEO_VARIANTS, variant_benchmark

    video = args.background_video
    names = args.variants or (VARIANTS + (VIDEO_VARIANTS if video else ()))
    unknown = [n for n in names if n not in VARIANTS + VIDEO_VARIANTS]
    if unknown:
        raise ValueError(f"--variants {' '.join(unknown)}: allowed {', '.join(VARIANTS + VIDEO_VARIANTS)}")
    if video is None and set(names) & set(VIDEO_VARIANTS):
        raise ValueError(f"--variants {' '.join(VIDEO_VARIANTS)} plays a recording behind the rig: give it "
                         "(--background-video)")
    if video is not None and not Path(video).is_file():
        raise ValueError(f"--background-video {video}: not a file")
    number("", "--duration", args.duration, lo=0.0, lo_open=True, hi=60.0)
    number("", "--video-start", args.video_start, lo=0.0, hi=1e5)
    table = variant_benchmark(names, duration_s=args.duration, seed=args.seed, progress=progress_printer("variants"),
                              background_video=video, video_start_s=args.video_start)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.out:
        _io.write_csv(table, Path(args.out) / "variants.csv")
    return EXIT_OK


def _cmd_bench_fit(args: argparse.Namespace) -> int:
    from ..montecarlo import FIT_MC_SCENES, combine_fit_runs, fit_monte_carlo, scene_protocol, summarize_fit_monte_carlo

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
        if seeds < 1:
            raise ValueError(f"--seeds {seeds}: at least 1 run per scene")
        number("", "--duration", args.duration, lo=0.0, lo_open=True)
        start = time.perf_counter()
        phone = None
        if args.phone is not None:
            from ..render.phone import PhoneStyle

            # a rolling shutter reads its rows within the frame interval of every scene run
            fastest = max(float(scene_protocol(s).extra["camera"]["fps"]) for s in scenes)
            number("", "--readout-ms", args.readout_ms, lo=0.0, hi=1e3 / fastest)
            phone = PhoneStyle(photo=args.phone, readout_s=args.readout_ms / 1e3)
            phone.check()
        datasheet = None
        if args.datasheet_focal_sd is not None:
            from ..montecarlo import DataSheet

            number("", "--datasheet-focal-sd", args.datasheet_focal_sd, lo=0.0, lo_open=True, hi=0.5)
            datasheet = DataSheet(focal_sd_rel=args.datasheet_focal_sd)
        runs = fit_monte_carlo(scenes, seeds=seeds, duration_s=args.duration, workers=args.workers,
                               progress=progress_printer("runs"), first_seed=args.first_seed, terms=args.terms,
                               phone=phone, datasheet=datasheet)
        table = summarize_fit_monte_carlo(runs)
        how = f"recorded like a phone in front of {args.phone}" if phone else "through the sensor model"
        if phone is not None and phone.readout_s:
            how += f", a {args.readout_ms:g} ms rolling shutter camera.json does not state"
        if datasheet is not None:
            how += (f"; no calibration, no fiducials: camera at {list(datasheet.camera_position_m)} m, focal length "
                    f"drawn and stated +- {datasheet.focal_sd_rel:.0%}, placement +- {datasheet.placement_sd_m:g} m, "
                    "pose and focal length from the motion")
            if "focal_found_rel" in runs:
                found = runs.drop_duplicates(["scene", "seed"]).dropna(subset=["focal_found_rel"])
                z = found.focal_found_rel / found.focal_found_sd_rel
                print(f"focal length found: error / sd over {len(found)} runs: mean {z.mean():+.2f}, sd "
                      f"{z.std(ddof=1):.2f}; found to {100 * found.focal_found_sd_rel.median():.2g} % (median)")
        print(f"{len(scenes)} scene(s) x {seeds} seeds (from {args.first_seed}), {args.duration:g} s of 640x480 "
              f"video each ({how}), model terms {args.terms}, {time.perf_counter() - start:.0f} s")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if table.attrs.get("failed_runs"):
        print(f"{table.attrs['failed_runs']} run(s) failed: see runs.csv")
    print("targets: |mean pull| <= 0.2, sd of pulls 0.9-1.1, sd / CRB <= 1.2")
    if args.out:
        _io.write_csv(runs, Path(args.out) / "runs.csv")
        _io.write_csv(table, Path(args.out) / "fit.csv")
    return EXIT_OK


def _cmd_plan(args: argparse.Namespace) -> int:
    from ..montecarlo import monte_carlo_check
    from ..plan import DEFAULT_PLAN_DRAWS, parse_sweep, plan_experiment, sweep
    from ..plan_record import AdviceKind
    from ..report import plot_sweep

    out = Path(args.out) if args.out else None
    if args.sweep:
        if not args.protocol:
            raise ValueError("plan --sweep needs a protocol file")
        for spec in args.sweep:
            key, values = parse_sweep(spec)
            table = sweep(args.protocol, key, values, duration_s=args.duration, progress=progress_printer("sweep"))
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
    if args.duration is not None:
        number("", "--duration", args.duration, lo=0.0, lo_open=True)
    plan = plan_experiment(protocol, duration_s=args.duration,
                           draws=args.draws if args.draws is not None else DEFAULT_PLAN_DRAWS,
                           rng=np.random.default_rng(args.seed), progress=progress_printer("noisy draws"))
    if args.monte_carlo:
        table = monte_carlo_check(protocol, args.monte_carlo, duration_s=args.mc_duration, scheduler=args.scheduler,
                                  progress=progress_printer("monte carlo"))
        plan = replace(plan, monte_carlo={"duration_s": args.mc_duration, "runs": args.monte_carlo,
                                          "failed_runs": table.attrs.get("failed_runs", 0),
                                          "table": table.to_dict(orient="records")})
    doc = _io.json_safe(plan)
    if out:
        _io.write_json(doc, out / "plan.json")
    # a camera that never sees the tip measures nothing: the plan says so, and the exit code too (and stderr: with -q
    # it is all the user sees)
    blind = plan.measures_nothing
    if blind and plan.advice_of(AdviceKind.AZIMUTH_UNDEFINED):
        print("gyrorig: failed: the tip stays on the vertical (a sleeping top): the plan measures nothing (launch the "
              "top tilted or moving)", file=sys.stderr)
    elif blind and plan.advice_of(AdviceKind.FIT_FAILED):
        print(f"gyrorig: failed: {plan.advice_of(AdviceKind.FIT_FAILED)[0].text}", file=sys.stderr)
    elif blind:
        print("gyrorig: failed: the camera never sees the tip marker: the plan measures nothing (check the camera's "
              "placement and field of view against the tip's path)", file=sys.stderr)
    if args.json:
        print_data(json.dumps(doc, indent=2, sort_keys=True))
        return EXIT_FAILED if blind else EXIT_OK
    print_plan(plan)
    if out:
        print(f"-> {out / 'plan.json'}")
    return EXIT_FAILED if blind else EXIT_OK


def _cmd_protocols(args: argparse.Namespace) -> int:
    from ..protocols import bundled_protocols

    names = bundled_protocols()
    width = max(map(len, names), default=0)
    for name, description in names.items():
        print_data(f"{name:<{width}}  {description}")
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    for option, value in (("--duration", args.duration), ("--video-duration", args.video_duration)):
        if value is not None:
            number("", option, value, lo=0.0, lo_open=True)
    run_demo(args.out, duration_s=args.duration, video_duration_s=args.video_duration,
             say=lambda line: print(line, flush=True), progress_for=progress_printer)
    return EXIT_OK


def _cmd_smooth(args: argparse.Namespace) -> int:
    from ..analysis import smooth_file

    out = Path(args.out)
    res = smooth_file(args.angles, out)
    print(f"{len(res.table)} frames: {res.n_measured} used, {res.n_outliers} outliers gated, {res.n_resets} restarts; "
          f"q_theta {res.q_theta_rad2_s3:.3g}, q_phi {res.q_phi_rad2_s3:.3g} rad^2/s^3 (maximum likelihood); "
          f"mean NIS {res.nis_mean:.3f} (2 expected); {res.wall_time_s:.2f} s -> {out / 'smoothed.csv'}")
    return EXIT_OK


def _constraints(args: argparse.Namespace):
    from ..fit import Constraints

    return Constraints.from_options(args.fix, args.prior)


def _cmd_fit(args: argparse.Namespace) -> int:
    from ..analysis import fit_file

    out = Path(args.out)
    from ..tracking.sources import parse_cut

    start, end = (None if v is None else parse_cut(v, o) for v, o in ((args.start, "--start"), (args.end, "--end")))
    fit = fit_file(args.angles, load_protocol(args.protocol), out, truth_csv=args.truth, terms=terms_arg(args.terms),
                   constraints=_constraints(args), start=start, end=end)
    print_fit(fit, out)
    return EXIT_OK


def _cmd_analyze(args: argparse.Namespace) -> int:
    from ..analysis import analyze_batch, analyze_video

    src = Path(args.video)
    out = Path(args.out)
    constraints = _constraints(args)
    protocol = load_protocol(args.protocol) if args.protocol else None
    from ..analysis import VIDEO_SUFFIXES
    from ..tracking.images import IMAGE_SUFFIXES

    # a folder of images with no videos is one image sequence; a folder of videos (or a manifest) a batch
    sequence = src.is_dir() and not any(p.suffix.lower() in VIDEO_SUFFIXES for p in src.iterdir()) and any(
        p.suffix.lower() in IMAGE_SUFFIXES for p in src.iterdir())
    if (src.is_dir() and not sequence) or src.suffix.lower() == ".csv":
        if constraints:
            raise ValueError("--fix and --prior apply to one video, not to a batch (each run has its own parameters)")
        if args.start is not None or args.end is not None:
            raise ValueError("--start and --end apply to one video, not to a batch")
        summary = analyze_batch(src, out, camera=args.camera, protocol=protocol, progress_line=print,
                                terms=terms_arg(args.terms), frame_dots=args.frame_dots)
        ok = int((summary.status == "ok").sum())
        print(f"{ok} of {len(summary)} videos analysed -> {out / 'summary.csv'}")
        if ok < len(summary):  # on stderr too: with -q it is all the user sees
            print(f"gyrorig: failed: {len(summary) - ok} of {len(summary)} videos could not be analysed (status and "
                  f"error of each in {out / 'summary.csv'})", file=sys.stderr)
            return EXIT_FAILED
        return EXIT_OK
    if protocol is None or args.camera is None:
        raise ValueError("analyze VIDEO needs --camera and --protocol")
    camera = args.camera
    if args.capture_fps is not None:
        from ..tracking import load_camera

        camera = _with_capture_fps(load_camera(args.camera, require_pose=False), args.capture_fps)
    res = analyze_video(clipped(src, args), camera, protocol, out, truth_csv=args.truth, progress=progress_printer("track"),
                        terms=terms_arg(args.terms), constraints=constraints, frame_dots=args.frame_dots,
                        stage=lambda msg: print(msg, flush=True))
    ts = res["time_s"]
    print(f"{res['frames']} frames, {res['tracked_fraction']:.1%} tracked; track {ts['track']:.1f} s, smooth "
          f"{ts['smooth']:.2f} s, fit {ts['fit']:.2f} s")
    print_fit(res["fit"], out)
    print(f"report: {res['report']}")
    return EXIT_OK


def _cmd_theory(args: argparse.Namespace) -> int:
    if args.validate:
        return _cmd_validate(args)
    if not args.protocol:
        raise ValueError("give a PROTOCOL, or --validate")
    from ..propagate import predict_with_uncertainty

    from ..plausibility import protocol_doubts

    protocol = load_protocol(args.protocol)  # logs its doubts as warnings
    if protocol.gimbal is not None:
        return gimbal_theory(protocol, args)
    pred = predict_with_uncertainty(protocol, simulate_damping=not args.no_simulate)
    if args.json:
        doubts = [d.as_dict() for d in protocol_doubts(protocol)]
        print_data(json.dumps(_io.json_safe({**pred.to_dict(), "doubts": doubts}), indent=2))
    else:
        print_prediction(pred)
    return EXIT_OK


def _cmd_validate(args: argparse.Namespace) -> int:
    from ..report import markdown_table, plot_validation
    from ..validation import summarize, validate

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


def _cmd_identify(args: argparse.Namespace) -> int:
    from ..identify import identify_files
    from ..identify.estimate import formulas_used

    out = Path(args.out)
    ident = identify_files(args.inputs, args.protocol, out)
    prior = load_protocol(args.protocol)
    print(f"identified from {len(ident.observations)} observations and {len(ident.prior_names)} priors: "
          f"chi2_red {ident.chi2_red:.3g} ({ident.dof} dof)")
    for n, v, e in zip(ident.names, ident.values, ident.standard_errors):
        print(f"  {n}: {v:.6g} +- {e:.2g}")
    for k, (v, e) in ident.derived(prior).items():
        print(f"  {k}: {v:.6g} +- {e:.2g}")
    if ident.damping_law:
        print(f"  spin-down law: {ident.damping_law} (friction's chi-square gain {ident.friction_chi2_gain:.3g})")
    for kind, formula in formulas_used(ident).items():
        print(f"  {kind}: {formula}")
    for note in ident.notes:
        print(f"  note: {note}")
    print(f"-> {out / 'identified.toml'}, {out / 'identify.json'}, {out / 'identify.png'}")
    return EXIT_OK


def _cmd_bench_identify(args: argparse.Namespace) -> int:
    import tempfile

    from ..bench.identify import RIGS, identify_pulls

    rigs = args.rigs or list(RIGS)
    unknown = [r for r in rigs if r not in RIGS]
    if unknown:
        raise ValueError(f"--rigs {' '.join(unknown)}: allowed {', '.join(RIGS)}")
    number("", "--draws", args.draws, lo=2, hi=10000)
    frames = []
    with tempfile.TemporaryDirectory() as tmp:
        for rig in rigs:
            for fast in (False, True):
                frames.append(identify_pulls(rig, args.draws, Path(tmp) / ("fast" if fast else "exact"),
                                             seed=args.seed, fast_top=fast))
    runs = pd.concat(frames, ignore_index=True)
    table = (runs.groupby(["rig", "fast_top", "parameter"]).pull.agg(["count", "mean", "std"])
             .rename(columns={"count": "draws", "mean": "mean_pull", "std": "sd_pull"}).reset_index())
    table["models"] = np.where(table.fast_top, "fast-top", "exact")
    print(table.drop(columns="fast_top").to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    print("targets (exact models): sd of pulls 0.8-1.2; the fast-top rows show the bias the exact models remove")
    if args.out:
        _io.write_csv(runs, Path(args.out) / "identify_pulls.csv")
    return EXIT_OK
