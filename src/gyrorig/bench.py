"""Benchmarks: accuracy against run time of the simulator's methods.

These print figures; they are not timed unit tests.  Compare ratios measured in
one run (the machines are shared and noisy).
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from collections.abc import Sequence

import numpy as np
import pandas as pd

from .physics import METHODS, SimulationError, exact_solution, exact_solution_applies, simulate
from .protocols import BUNDLED_PROTOCOL_DIR, Protocol

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
    from .protocols import top_protocol

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
    from .physics.rotations import tip_from_angles

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
    from .theory import measure_nutation

    try:
        m = measure_nutation(df)
        return m.mean_precession_rate_rad_s, m.amplitude_rad
    except ValueError:
        return float("nan"), float("nan")


def accuracy_scenes(quick: bool) -> dict[str, Protocol]:
    """Scenes of the work-precision study."""
    from .protocols import load_protocol

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


# --------------------------------------------------------------------------------------
# rendering throughput (gyrorig bench render)


def render_throughput(n_frames: int = 100) -> pd.DataFrame:
    """Frames per second of rendering (no encoding) and of OpenCV's FFV1 encoder, same frames.

    Sizes 640x480 and 1440x1080, with motion blur (8 sub-exposure samples) and without (1),
    on the air-cushion protocol's markers and sensor.  The target is rendering at least as
    fast as encoding, so that the disk encoder is the limit.
    """
    import tempfile
    from dataclasses import replace

    from .protocols import load_protocol
    from .render import _open_writer, marker_paths, render_frames
    from .camera import camera_setup

    base = load_protocol(BUNDLED_PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    rows = []
    for (w, h) in [(640, 480), (1440, 1080)]:
        for nsub in (1, 8):
            cam_t = dict(base.extra["camera"])
            scale = w / 1440
            cam_t.update(width_px=w, height_px=h, pixel_size_um=3.45 / scale, motion_blur_samples=nsub)
            p = replace(base, extra={**base.extra, "camera": cam_t})
            setup = camera_setup(p)
            duration = n_frames / setup.camera.fps
            paths = marker_paths(p, setup, duration)
            start = time.perf_counter()
            frames = [img for img, _ in render_frames(p, duration_s=duration, setup=setup, paths=paths)]
            t_render = time.perf_counter() - start
            with tempfile.TemporaryDirectory() as tmp:
                writer = _open_writer(Path(tmp) / "v.mkv", setup.camera, "lossless")
                start = time.perf_counter()
                for f in frames:
                    writer.write(f)
                writer.release()
                t_encode = time.perf_counter() - start
            rows.append(dict(width_px=w, height_px=h, motion_blur_samples=nsub, frames=len(frames),
                             render_fps=len(frames) / t_render, ffv1_encode_fps=len(frames) / t_encode,
                             render_over_encode=t_encode / t_render,
                             encoding_share=t_encode / (t_encode + t_render)))
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------------------
# tracking precision and speed (gyrorig bench track)


def track_benchmark(*, duration_s: float = 1.0, sizes=((1440, 1080), (640, 480)), seed: int = 0) -> pd.DataFrame:
    """Render the air-cushion rig, track it, and compare with the truth and the bound.

    For each image size: FFV1 with motion blur off (the bound's model is exact) and on, and
    uncompressed video (blur off), which shows the tracker's own speed when decoding is free, tracking
    the tip alone and with the frame's dots:
    RMS position error of the tip against the truth, the Cramer-Rao bound, their ratio,
    the standard deviation of the normalised errors of x, y, theta and phi, and the
    tracking speed with and without video decoding.
    """
    import tempfile
    from dataclasses import replace

    import cv2

    from .camera import camera_setup
    from .physics import simulate as _simulate
    from .protocols import load_protocol
    from .render import render_video
    from .tracking import load_camera, spot_crb_px, track_video, warm_up

    warm_up()
    base = load_protocol(BUNDLED_PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    rows = []
    for (w, h) in sizes:
        for codec, nsub, dots in (("lossless", 1, False), ("lossless", 8, False), ("raw", 1, False), ("raw", 1, True)):
            cam_t = dict(base.extra["camera"])
            cam_t.update(width_px=w, height_px=h, pixel_size_um=3.45 * 1440 / w, motion_blur_samples=nsub)
            p = replace(base, extra={**base.extra, "camera": cam_t})
            with tempfile.TemporaryDirectory() as tmp:
                video = render_video(p, f"{tmp}/v", seed=seed, duration_s=duration_s, calibration_views=0,
                                     codec=codec)["video"]
                cam = load_camera(f"{tmp}/v/camera.json")
                start = time.perf_counter()
                cap = cv2.VideoCapture(video, cv2.CAP_FFMPEG)
                cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
                while cap.read()[0]:
                    pass
                cap.release()
                decode_only = time.perf_counter() - start
                start = time.perf_counter()
                summary = track_video(video, cam, p, f"{tmp}/t", frame_dots=dots)
                wall = time.perf_counter() - start
                mk = pd.read_csv(f"{tmp}/t/markers.csv")
                mk = mk[mk.marker == "tip"]
                angles = pd.read_csv(f"{tmp}/t/angles.csv").dropna(subset=["theta_rad"])
                truth = pd.read_csv(f"{tmp}/v/truth.csv")
            truth = truth[truth.marker == "tip"]
            m = mk.merge(truth, on="frame", suffixes=("", "_true"))
            setup = camera_setup(p)
            c = setup.camera
            tip = next(x for x in setup.markers if x.name == "tip")
            amp = tip.brightness_e_per_s * c.exposure_s / cam.gain_e_per_adu
            bg = c.sensor.background_e_per_s * c.exposure_s / cam.gain_e_per_adu
            crb = np.array([spot_crb_px(r.x_px_true, r.y_px_true, r.radius_px, amp, bg, cam) for r in m.itertuples()])
            err = np.hypot(m.x_px - m.x_px_true, m.y_px - m.y_px_true) / math.sqrt(2)
            sim = _simulate(p, t_eval_s=angles.t_s.to_numpy())
            e_th = (angles.theta_rad.to_numpy() - sim.theta_rad.to_numpy()) / angles.theta_sigma_rad.to_numpy()
            e_ph = np.angle(np.exp(1j * (angles.phi_rad.to_numpy() - sim.phi_rad.to_numpy()))) / \
                angles.phi_sigma_rad.to_numpy()
            n = summary["frames"]
            rows.append(dict(
                width_px=w, height_px=h, codec=codec, motion_blur_samples=nsub, frame_dots=dots, frames=n,
                tracked_fraction=summary["tracked_fraction"],
                rms_error_px=float(np.sqrt(np.mean(err**2))), crb_px=float(np.sqrt(np.mean(crb**2))),
                error_over_crb=float(np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(crb**2))),
                pull_std_x=float(np.std((m.x_px - m.x_px_true) / m.sigma_x_px)),
                pull_std_y=float(np.std((m.y_px - m.y_px_true) / m.sigma_y_px)),
                pull_std_theta=float(np.std(e_th)), pull_std_phi=float(np.std(e_ph)),
                track_fps=n / summary["track_s"], decode_only_fps=n / decode_only, end_to_end_fps=n / wall))
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------------- fit Monte Carlo
FIT_MC_SCENES = ("air-cushion-heavy-top", "eddy-damped-top-b2", "accelerated-pivot")


def fit_monte_carlo_run(scene: str | Protocol, seed: int, duration_s: float,
                        camera_size: tuple[int, int] | None = (640, 480), prediction: dict | None = None,
                        terms="planned") -> list[dict]:
    """One run of the full chain (render -> track -> smooth -> fit) with the truth unseen.

    Returns one row per fitted quantity: value, standard error, the truth (same model fitted to
    the simulator's noiseless angles), pull.  A failure is returned as a row with ``error``.
    """
    import tempfile

    from .camera import with_image_size
    from .fit import fit_angles
    from .protocols import load_protocol
    from .render import render_video
    from .smooth import smooth_angles
    from .tracking import load_camera, track_video

    p = scene if isinstance(scene, Protocol) else load_protocol(BUNDLED_PROTOCOL_DIR / f"{scene}.toml")
    scene = p.name
    if camera_size is not None:
        p = with_image_size(p, *camera_size)
    if prediction is None:
        from .theory import predict

        prediction = predict(p, simulate_damping=False)
    start = time.perf_counter()
    if terms == "planned":  # chosen before the run, from the protocol alone (fit_monte_carlo does it once per scene)
        from .plan import plan_fit_terms

        terms = plan_fit_terms(p, duration_s, prediction=prediction)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            render_video(p, f"{tmp}/v", seed=seed, duration_s=duration_s, calibration_views=0)
            track_video(f"{tmp}/v/video.mkv", load_camera(f"{tmp}/v/camera.json"), p, f"{tmp}/t")
            angles = pd.read_csv(f"{tmp}/t/angles.csv")
            truth = pd.read_csv(f"{tmp}/v/truth.csv")
        truth = truth[truth.marker == "tip"].assign(t_s=lambda d: d.t_marker_s)
        sm = smooth_angles(angles)
        fit = fit_angles(angles, p, prediction=prediction, exclude=(sm.table.status == "outlier").to_numpy(),
                         truth=truth, rng=np.random.default_rng(seed), terms=terms)
    except Exception as exc:  # reported in the table, not hidden
        return [{"scene": scene, "seed": seed, "duration_s": duration_s, "error": f"{type(exc).__name__}: {exc}"}]
    rows = []
    for name, q in fit.quantities.items():
        rows.append({"scene": scene, "seed": seed, "duration_s": duration_s, "quantity": name, "status": q.status,
                     "value": q.value,
                     "standard_error": q.standard_error, "formal_standard_error": q.formal_standard_error, "truth": q.truth, "pull": q.pull, "chi2_red": fit.chi2_red,
                     "errors": fit.errors, "error_kind": str(fit.error_kind), "harmonics": fit.spec.harmonics,
                     "terms": fit.terms.describe(), "added_terms": ",".join(fit.terms_beyond_plan),
                     "refused_terms": ",".join(fit.terms_not_identifiable),
                     "wall_s": time.perf_counter() - start,
                     "error": ""})
    return rows


def combine_fit_runs(paths: Sequence[str | Path]) -> pd.DataFrame:
    """Concatenate the ``runs.csv`` of several ``bench fit --out`` batches into one table.

    Each path is a ``runs.csv`` or the folder holding it.  Refuses a seed that appears in two
    batches for the same scene and record length (it would be counted twice: a seed
    reproduces its run exactly), and batches of one scene at different lengths.
    """
    tables = []
    for k, path in enumerate(paths):
        f = Path(path)
        f = f / "runs.csv" if f.is_dir() else f
        if not f.is_file():
            raise ValueError(f"bench fit --combine: {path}: no runs.csv there")
        t = pd.read_csv(f)
        missing = {"scene", "seed"} - set(t.columns)
        if missing:
            raise ValueError(f"bench fit --combine: {f}: missing column(s) {sorted(missing)}")
        tables.append(t.assign(batch=k))
    runs = pd.concat(tables, ignore_index=True)
    if "duration_s" in runs:
        lengths = runs.dropna(subset=["duration_s"]).groupby("scene").duration_s.unique()
        mixed = {s: sorted(v) for s, v in lengths.items() if len(v) > 1}
        if mixed:
            raise ValueError(f"bench fit --combine: record lengths differ within a scene: {mixed}")
    seen = runs[["scene", "seed", "batch"]].drop_duplicates()
    twice = seen[seen.duplicated(["scene", "seed"], keep=False)]
    if len(twice):
        first = twice.iloc[0]
        raise ValueError(f"bench fit --combine: seed {first.seed} of {first.scene} is in more than one batch "
                         f"({len(twice)} batch rows overlap); run batches with distinct --first-seed")
    return runs.drop(columns="batch")


def fit_monte_carlo(scenes: Sequence[str | Protocol] = FIT_MC_SCENES, *, seeds: int = 40, duration_s: float = 2.0,
                    workers: int | None = None, progress=None, scheduler: str | None = None,
                    camera_size: tuple[int, int] | None = (640, 480), first_seed: int = 0,
                    terms: str = "planned") -> pd.DataFrame:
    """The fit benchmark: many seeds per scene, in parallel; one row per quantity and run.

    Runs in local processes, or on a Dask cluster when ``scheduler`` is its address
    (``pip install 'gyrorig[dask]'``).  Scenes are bundled protocol names or protocols.
    ``terms="planned"``: each scene's fit model is chosen once, before the runs, by
    :func:`gyrorig.plan.plan_fit_terms` for this record length and camera; ``"data"``: each
    run chooses its own by chi-square tests.
    """
    import os
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from .protocols import load_protocol
    from .theory import predict

    protos = [s if isinstance(s, Protocol) else load_protocol(BUNDLED_PROTOCOL_DIR / f"{s}.toml") for s in scenes]
    preds = [predict(p, simulate_damping=False) for p in protos]
    if terms == "planned":
        from .camera import with_image_size
        from .plan import plan_fit_terms

        plans = [plan_fit_terms(with_image_size(p, *camera_size) if camera_size else p, duration_s, prediction=pr)
                 for p, pr in zip(protos, preds)]
    else:
        plans = [terms] * len(protos)
    jobs = [(i, seed) for i in range(len(protos)) for seed in range(first_seed, first_seed + seeds)]
    rows: list[dict] = []

    def collect(futures, completed) -> None:
        for k, f in enumerate(completed(futures)):
            rows.extend(f.result())
            if progress:
                progress(k + 1, len(jobs))

    if scheduler is not None:
        try:
            from dask.distributed import Client
            from dask.distributed import as_completed as dask_completed
        except ImportError as exc:
            raise ValueError("--scheduler needs Dask: pip install 'gyrorig[dask]'") from exc
        with Client(scheduler) as client:
            collect([client.submit(fit_monte_carlo_run, protos[i], seed, duration_s, camera_size, preds[i], plans[i],
                                       pure=False)
                     for i, seed in jobs], dask_completed)
        return pd.DataFrame(rows)
    workers = workers or min(len(jobs), os.cpu_count() or 1)
    if workers <= 1:
        for k, (i, seed) in enumerate(jobs):
            rows += fit_monte_carlo_run(protos[i], seed, duration_s, camera_size, preds[i], plans[i])
            if progress:
                progress(k + 1, len(jobs))
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            collect([pool.submit(fit_monte_carlo_run, protos[i], seed, duration_s, camera_size, preds[i], plans[i])
                     for i, seed in jobs], as_completed)
    return pd.DataFrame(rows)


def summarize_fit_monte_carlo(runs: pd.DataFrame) -> pd.DataFrame:
    """Per scene and quantity: mean and SD of the pulls, SD of the estimates over the median standard error.

    ``median_crb`` is the formal standard error ``(J^T J)^-1`` (the Cramer-Rao bound of the fit
    model for the tracker's stated per-frame errors, before any bootstrap), so ``sd/CRB`` is the
    efficiency figure; the tracker's own errors are within a few percent of the localisation
    bound (``bench track``).  ``median_se`` is what the fit reported.
    """
    # runs.csv read back gives NaN where a run had no error
    err = (runs["error"].map(lambda v: "" if pd.isna(v) else str(v)) if "error" in runs
           else pd.Series("", index=runs.index))
    ok = runs[(err == "") & (runs.status == "determined")] if "status" in runs else runs.iloc[0:0]
    rows = []
    for (scene, name), g in ok.groupby(["scene", "quantity"], sort=False):
        n = len(g)
        pulls = g.pull.astype(float)
        sd_est = float(np.std(g.value.astype(float) - g.truth.astype(float), ddof=1)) if n > 1 else math.nan
        se_col = g.formal_standard_error if "formal_standard_error" in g else g.standard_error
        crb = float(np.median(se_col.astype(float)))
        rows.append({"scene": scene, "quantity": name, "runs": n, "mean_pull": float(pulls.mean()),
                     "mean_pull_se": float(pulls.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan,
                     "sd_pull": float(pulls.std(ddof=1)) if n > 1 else math.nan,
                     "sd_over_crb": sd_est / crb if crb > 0 else math.nan, "median_crb": crb,
                     "median_se": float(np.median(g.standard_error.astype(float))),
                     "bootstrap_runs": (int((g.error_kind == "bootstrap").sum()) if "error_kind" in g
                                        else math.nan)})
    failed = runs[err != ""] if "error" in runs else None
    table = pd.DataFrame(rows)
    if failed is not None and len(failed):
        table.attrs["failed_runs"] = int(failed[["scene", "seed"]].drop_duplicates().shape[0])
    return table


# ------------------------------------------------------------------------------------- smoother speed
def smooth_benchmark(n_frames: int = 100_000, n_filterpy: int = 20_000, seed: int = 0) -> dict:
    """Speed of the compiled smoother against filterpy on the same model, and their agreement.

    Synthetic tracked angles (a nutating, precessing tip with white noise, 200 fps, 2 %
    of frames missing, uneven frame times).  filterpy runs on the first ``n_filterpy``
    frames (it takes ~90 us per frame); both engines are compared there.
    """
    from .smooth import estimate_noise, kalman_smooth, prepare_measurements

    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / 200.0 + rng.uniform(0, 1e-3, n_frames)
    theta = 0.79 + 0.02 * np.cos(59.5 * t)
    phi = 1.72 * t + 0.028 * np.sin(59.5 * t)
    th = theta + 2e-5 * rng.normal(size=n_frames)
    ph = phi + 3e-5 * rng.normal(size=n_frames)
    gone = rng.uniform(size=n_frames) < 0.02
    th[gone] = ph[gone] = np.nan
    df = pd.DataFrame({"frame": np.arange(n_frames), "t_s": t, "theta_rad": th,
                       "phi_rad": np.angle(np.exp(1j * ph)), "theta_sigma_rad": 2e-5, "phi_sigma_rad": 3e-5,
                       "theta_phi_corr": 0.1})
    m = prepare_measurements(df)
    kalman_smooth(m, 1.0, 1.0)  # compile (cached on disk after the first run)
    times = []
    for _ in range(3):
        start = time.perf_counter()
        kalman_smooth(m, 10.0, 10.0)
        times.append(time.perf_counter() - start)
    start = time.perf_counter()
    qt, qp, _, info = estimate_noise(m)
    ml_s = time.perf_counter() - start
    sub = prepare_measurements(df.iloc[:n_filterpy])
    start = time.perf_counter()
    ref = kalman_smooth(sub, qt, qp, engine="filterpy")
    fp_s = time.perf_counter() - start
    fast = kalman_smooth(sub, qt, qp)
    sd = np.sqrt(np.einsum("nii->ni", ref[2]))
    dx = float(np.max(np.abs(fast[1] - ref[1]) / sd))
    dP = np.abs(fast[2] - ref[2]) / (sd[:, :, None] * sd[:, None, :])
    return {"frames": n_frames, "fast_s": float(np.median(times)), "fast_us_per_frame": float(np.median(times)) / n_frames * 1e6,
            "ml_noise_s": ml_s, "ml_evaluations": info["ml_evaluations"], "q_theta": qt, "q_phi": qp,
            "filterpy_frames": n_filterpy, "filterpy_s": fp_s, "filterpy_us_per_frame": fp_s / n_filterpy * 1e6,
            "speedup": (fp_s / n_filterpy) / (float(np.median(times)) / n_frames),
            "max_state_diff_in_sigma": dx, "max_cov_diff_rel_after_first": float(np.max(dP[1:])),
            "max_cov_diff_rel_first": float(np.max(dP[0])), "same_gating": bool(np.array_equal(fast[4], ref[4]))}
