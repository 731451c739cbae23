"""Monte Carlo of the full chain: render -> track -> smooth -> fit, many seeds, truth unseen by the estimate.

:func:`fit_monte_carlo` runs it (local processes or a Dask cluster), one row per run and quantity;
:func:`summarize_fit_monte_carlo` gives mean and SD of the pulls and the spread over the Cramér-Rao
bound; :func:`combine_fit_runs` joins batches run separately; :func:`monte_carlo_check` compares the
spread with the plan's expected errors.  Each run renders with the simulator
(:mod:`gyrorig.render`) and analyses with :func:`gyrorig.pipeline.analyze`; the truth enters only
the comparison.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from .camera import with_image_size
from .expectation import plan_fit_terms
from .pipeline import analyze
from .plan import plan_experiment
from .prediction import Prediction
from .protocols import BUNDLED_PROTOCOL_DIR, Protocol, load_protocol
from .render import render_video
from .render.phone import PhoneStyle, render_phone_video
from .tables import tip_truth
from .theory import predict

__all__ = ["FIT_MC_SCENES", "RUN_COLUMNS", "DataSheet", "fit_monte_carlo_run", "fit_monte_carlo", "combine_fit_runs",
           "summarize_fit_monte_carlo", "monte_carlo_check", "scene_protocol"]

FIT_MC_SCENES = ("air-cushion-heavy-top", "eddy-damped-top-b2", "accelerated-pivot")
#: ``runs.csv``: one row per run and quantity (a failed run: one row with ``error``)
RUN_COLUMNS = ("scene", "seed", "duration_s", "quantity", "status", "value", "standard_error",
               "formal_standard_error", "truth", "pull", "chi2_red", "errors", "error_kind", "harmonics", "terms",
               "added_terms", "refused_terms", "breaks", "wall_s", "error")


@dataclass(frozen=True)
class DataSheet:
    """A user without calibration or fiducials: the camera moved off the vertical (the motion then fixes its
    distance), a camera.json with only a data sheet's focal length (drawn ``focal_sd_rel`` off the true one, stated
    with that sd) and the placement measured to ``placement_sd_m`` per coordinate; the pose and the focal length come
    from ``pose --video`` (:func:`gyrorig.tracking.motion_pose.pose_from_motion`)."""

    focal_sd_rel: float = 0.05
    placement_sd_m: float = 0.03
    camera_position_m: tuple[float, float, float] = (0.0, -0.2, 0.75)

    def scene(self, p: Protocol) -> Protocol:
        """The protocol with its camera at :attr:`camera_position_m`, looking at the pivot, z up in the image."""
        cam = {**p.extra["camera"], "position_m": list(self.camera_position_m), "look_at_m": [0.0, 0.0, 0.0],
               "up_hint": [0.0, 0.0, 1.0]}
        return replace(p, extra={**p.extra, "camera": cam})

    def posed_camera(self, video, camera_json: str | Path, protocol: Protocol, seed: int, out: str | Path) -> dict:
        """Write the data-sheet camera.json and the posed one (``out``); returns what was drawn and found."""
        from .camera import placement_pose
        from .tracking import load_camera
        from .tracking.motion_pose import pose_from_motion

        rng = np.random.default_rng([seed, 20261126])
        d = json.loads(Path(camera_json).read_text())
        off = self.focal_sd_rel * rng.normal()
        f = d["camera_matrix"][0][0] * (1.0 + off)
        sheet = {k: v for k, v in d.items() if k not in ("rvec", "tvec", "camera_matrix", "pose_covariance",
                                                         "pose_points", "intrinsics_covariance",
                                                         "intrinsics_parameters")}
        sheet["focal_length_px"] = {"value": f, "sd": self.focal_sd_rel * f}
        sheet_path = Path(out).with_name("sheet.json")
        sheet_path.write_text(json.dumps(sheet))
        rough = np.asarray(self.camera_position_m) + self.placement_sd_m * rng.normal(size=3)
        rvec, tvec = placement_pose({"position_m": rough.tolist(), "look_at_m": [0.0, 0.0, 0.0],
                                     "up_hint": [0.0, 0.0, 1.0]})
        cam = load_camera(sheet_path, require_pose=False)
        pose = pose_from_motion(video, replace(cam, rvec=rvec, tvec=tvec), protocol)
        Path(out).write_text(json.dumps({**sheet, **pose.camera_fields(str(video))}))
        return {"focal_off_rel": off, "focal_found_rel": (1 + off) * (1 + pose.focal_scale) - 1,
                "focal_found_sd_rel": pose.focal_scale_sd}


def scene_protocol(scene: str | Protocol) -> Protocol:
    """A bundled protocol by name (``protocols/NAME.toml``), or the protocol given."""
    return scene if isinstance(scene, Protocol) else load_protocol(BUNDLED_PROTOCOL_DIR / f"{scene}.toml")


def fit_monte_carlo_run(scene: str | Protocol, seed: int, duration_s: float,
                        camera_size: tuple[int, int] | None = (640, 480), prediction: Prediction | None = None,
                        terms="planned", phone: PhoneStyle | None = None,
                        datasheet: DataSheet | None = None) -> list[dict]:
    """One run of the full chain (render -> track -> smooth -> fit) with the truth unseen.

    ``phone``: the video is recorded as a phone would (:func:`gyrorig.render.phone.render_phone_video`: in front of
    a photograph, gamma, a lossy codec, jittered times and dropped frames, a camera file without sensor numbers)
    instead of through the sensor model.  ``datasheet``: no calibration and no fiducials (:class:`DataSheet`): the
    camera off the vertical, the pose and focal length from the tip's motion.

    Returns one row per fitted quantity (:data:`RUN_COLUMNS`): value, standard error, the truth
    (the same model fitted to the simulator's noiseless angles), pull.  A failure is returned as a
    row with ``error``.
    """
    p = scene_protocol(scene)
    scene = p.name
    if camera_size is not None:
        p = with_image_size(p, *camera_size)
    if datasheet is not None:
        p = datasheet.scene(p)
    drawn: dict = {}
    if prediction is None:
        prediction = predict(p, simulate_damping=False)
    start = time.perf_counter()
    if terms == "planned":  # chosen before the run, from the protocol alone (fit_monte_carlo does it once per scene)
        terms = plan_fit_terms(p, duration_s, prediction=prediction)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            if phone is None:
                video = render_video(p, f"{tmp}/v", seed=seed, duration_s=duration_s, calibration_views=0)["video"]
            else:
                video = render_phone_video(p, f"{tmp}/v", style=phone, seed=seed, duration_s=duration_s)["video"]
            truth = tip_truth(pd.read_csv(f"{tmp}/v/truth.csv"))
            camera = f"{tmp}/v/camera.json"
            if datasheet is not None:
                drawn = datasheet.posed_camera(video, camera, p, seed, f"{tmp}/posed.json")
                camera = f"{tmp}/posed.json"
            res = analyze(video, camera, p, truth=truth, prediction=prediction,
                          terms=terms, rng=np.random.default_rng(seed))
    except Exception as exc:  # reported in the table, not hidden
        return [{"scene": scene, "seed": seed, "duration_s": duration_s, "error": f"{type(exc).__name__}: {exc}"}]
    fit = res.fit
    return [{"scene": scene, "seed": seed, "duration_s": duration_s, "quantity": name, "status": str(q.status),
             "value": q.value, "standard_error": q.standard_error, "formal_standard_error": q.formal_standard_error,
             "truth": q.truth, "pull": q.pull, "chi2_red": fit.chi2_red, "errors": fit.errors,
             "error_kind": str(fit.error_kind), "harmonics": fit.spec.harmonics, "terms": fit.terms.describe(),
             "added_terms": ",".join(fit.terms_beyond_plan), "refused_terms": ",".join(fit.terms_not_identifiable),
             "breaks": len(fit.breaks), "wall_s": time.perf_counter() - start, "error": "", **drawn}
            for name, q in fit.quantities.items()]


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


def _run_jobs(jobs, submit, completed, progress) -> list[dict]:
    rows: list[dict] = []
    for k, f in enumerate(completed([submit(*job) for job in jobs])):
        rows.extend(f.result())
        if progress:
            progress(k + 1, len(jobs))
    return rows


def fit_monte_carlo(scenes: Sequence[str | Protocol] = FIT_MC_SCENES, *, seeds: int = 40, duration_s: float = 2.0,
                    workers: int | None = None, progress=None, scheduler: str | None = None,
                    camera_size: tuple[int, int] | None = (640, 480), first_seed: int = 0,
                    terms: str = "planned", phone: PhoneStyle | None = None,
                    datasheet: DataSheet | None = None) -> pd.DataFrame:
    """The fit benchmark: many seeds per scene, in parallel; one row per quantity and run.

    Runs in local processes, or on a Dask cluster when ``scheduler`` is its address
    (``pip install 'gyrorig[dask]'``).  Scenes are bundled protocol names or protocols.
    ``terms="planned"``: each scene's fit model is chosen once, before the runs, by
    :func:`gyrorig.expectation.plan_fit_terms` for this record length and camera; ``"data"``: each
    run chooses its own by chi-square tests.  ``phone``: every video recorded as a phone would
    (:func:`fit_monte_carlo_run`).
    """
    protos = [scene_protocol(s) for s in scenes]
    preds = [predict(p, simulate_damping=False) for p in protos]
    if terms == "planned":
        plans = [plan_fit_terms(with_image_size(p, *camera_size) if camera_size else p, duration_s, prediction=pr)
                 for p, pr in zip(protos, preds)]
    else:
        plans = [terms] * len(protos)
    jobs = [(protos[i], seed, duration_s, camera_size, preds[i], plans[i], phone, datasheet)
            for i in range(len(protos)) for seed in range(first_seed, first_seed + seeds)]
    if scheduler is not None:
        try:
            from dask.distributed import Client
            from dask.distributed import as_completed as dask_completed
        except ImportError as exc:
            raise ValueError("--scheduler needs Dask: pip install 'gyrorig[dask]'") from exc
        with Client(scheduler) as client:
            return pd.DataFrame(_run_jobs(jobs, lambda *a: client.submit(fit_monte_carlo_run, *a, pure=False),
                                          dask_completed, progress))
    workers = workers or min(len(jobs), os.cpu_count() or 1)
    if workers <= 1:
        rows: list[dict] = []
        for k, job in enumerate(jobs):
            rows += fit_monte_carlo_run(*job)
            if progress:
                progress(k + 1, len(jobs))
        return pd.DataFrame(rows)
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return pd.DataFrame(_run_jobs(jobs, lambda *a: pool.submit(fit_monte_carlo_run, *a), as_completed, progress))


def summarize_fit_monte_carlo(runs: pd.DataFrame) -> pd.DataFrame:
    """Per scene and quantity: mean and SD of the pulls, SD of the estimates over the median standard error.

    ``median_crb`` is the formal standard error ``(J^T J)^-1`` (the Cramér-Rao bound of the fit
    model for the tracker's stated per-frame errors, before any bootstrap), so ``sd/CRB`` is the
    efficiency figure.  ``median_se`` is what the fit reported; ``bootstrap_runs`` how many runs
    took their errors from the bootstrap (NaN for tables without ``error_kind``).
    """
    # runs.csv read back gives NaN where a run had no error
    err = (runs["error"].map(lambda v: "" if pd.isna(v) else str(v)) if "error" in runs
           else pd.Series("", index=runs.index))
    ok = runs[(err == "") & (runs.status == "determined")] if "status" in runs else runs.iloc[0:0]
    rows = []
    for (scene, name), g in (ok.groupby(["scene", "quantity"], sort=False) if len(ok) else ()):
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
    table = pd.DataFrame(rows)
    failed = runs[err != ""] if "error" in runs else None
    if failed is not None and len(failed):
        table.attrs["failed_runs"] = int(failed[["scene", "seed"]].drop_duplicates().shape[0])
    return table


def monte_carlo_check(protocol: Protocol, n: int, *, duration_s: float = 2.0, scheduler: str | None = None,
                      workers: int | None = None, progress=None) -> pd.DataFrame:
    """Confirm the plan's expected errors with N runs of render -> track -> smooth -> fit.

    Returns, per quantity: the planned standard error for the same record, the Monte Carlo
    spread of the estimates and its ratio to the plan, the median standard error the fits reported
    and its ratio to the plan, and the mean and SD of the pulls.
    """
    runs = fit_monte_carlo([protocol], seeds=n, duration_s=duration_s, workers=workers, progress=progress,
                           scheduler=scheduler, camera_size=None)
    plan = plan_experiment(protocol, duration_s=duration_s, simulate_damping=False)
    rows = []
    ok = runs[runs["error"].fillna("") == ""] if "error" in runs else runs
    for name, g in ok[ok.status == "determined"].groupby("quantity", sort=False):
        planned = plan.quantities[name].expected_standard_error if name in plan.quantities else None
        err = g.value.astype(float) - g.truth.astype(float)
        sd = float(np.std(err, ddof=1)) if len(g) > 1 else math.nan
        rows.append({"quantity": name, "runs": len(g), "planned_se": planned, "monte_carlo_sd": sd,
                     "sd_over_planned": sd / planned if planned else math.nan,
                     "median_fit_se": float(np.median(g.standard_error)),
                     "fit_se_over_planned": float(np.median(g.standard_error)) / planned if planned else math.nan,
                     "mean_pull": float(g.pull.mean()),
                     "sd_pull": float(g.pull.std(ddof=1)) if len(g) > 1 else math.nan})
    table = pd.DataFrame(rows)
    table.attrs["failed_runs"] = int((runs["error"].fillna("") != "").sum()) if "error" in runs else 0
    table.attrs["linear_regime"] = bool((plan.recording or {}).get("linear_regime", True))
    return table
