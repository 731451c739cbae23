"""The analysis chain on files: track -> smooth -> fit -> report, for one video or a batch.

Outputs of :func:`analyze_video` in ``out``:

- ``track/angles.csv``, ``track/markers.csv``: the tracker's tables (:mod:`gyrorig.tracking`);
- ``smoothed.csv``: the smoother's table (:data:`gyrorig.smooth.SMOOTH_COLUMNS` and the
  covariance ``cov_ij`` of ``[theta, theta', phi, phi']``), ``smooth.json`` (noise levels);
- ``fit.json``: each quantity with value, standard error, units, the paper's, corrected and
  exact predictions, the differences in standard errors, status and reason; the model,
  chi-square, notes; ``fit_residuals.csv``; ``fit.png``;
- ``report.html``: one self-contained page (plots embedded) a browser opens offline.

Every file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import base64
import html
import io
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from . import _io
from .fit import QUANTITY_UNITS, FitResult, FitTerms, fit_angles
from .protocols import Protocol, load_protocol
from .smooth import SmoothResult, smooth_angles

logger = logging.getLogger(__name__)

__all__ = ["load_truth", "quality_counts", "smooth_file", "fit_file", "analyze_video", "analyze_batch", "write_report", "fit_document"]

Progress = Callable[[int, int], None]


def quality_counts(angles: pd.DataFrame) -> dict[str, int]:
    """How many frames carry each tracking ``quality`` flag (a frame may carry several)."""
    return angles["quality"].fillna("").str.split(",").explode().value_counts().to_dict()


def load_truth(path: str | Path, marker: str = "tip") -> pd.DataFrame:
    """Tip angles from a renderer's ``truth.csv`` (times of the marker's own exposure)."""
    df = pd.read_csv(path)
    missing = [c for c in ("t_s", "theta_rad", "phi_rad") if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: truth table lacks column(s) {missing}")
    if "marker" in df.columns:
        df = df[df["marker"] == marker]
        if df.empty:
            raise ValueError(f"{path}: no rows for marker {marker!r}")
    df = df.copy()
    if "t_marker_s" in df.columns:
        df["t_s"] = df["t_marker_s"]
    return df[["t_s", "theta_rad", "phi_rad"]].reset_index(drop=True)


def _read_angles(path: str | Path) -> pd.DataFrame:
    try:
        return pd.read_csv(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise ValueError(f"cannot read angle table {path}: {exc}") from exc


def smooth_file(angles_csv: str | Path, out: str | Path) -> SmoothResult:
    """``gyrorig smooth``: write ``smoothed.csv`` and ``smooth.json``."""
    out = Path(out)
    res = smooth_angles(_read_angles(angles_csv))
    _io.write_csv(res.table, out / "smoothed.csv")
    _io.write_json({"input": str(angles_csv), **res.summary(), "versions": _io.versions()}, out / "smooth.json")
    return res


def fit_document(fit: FitResult, protocol: Protocol, prediction: dict | None, smooth: SmoothResult | None = None,
                 extra: dict | None = None) -> dict:
    """The content of ``fit.json``."""
    doc = {"protocol": protocol.name, "description": protocol.description, **fit.summary(),
           "theory_flags": (prediction or {}).get("flags", {}), "versions": _io.versions()}
    if smooth is not None:
        doc["smoother"] = smooth.summary()
    if extra:
        doc.update(extra)
    return _io.json_safe(doc)


def fit_file(angles_csv: str | Path, protocol: Protocol, out: str | Path, *, truth_csv: str | Path | None = None,
             smooth: SmoothResult | None = None, prediction: dict | None = None,
             rng: np.random.Generator | None = None, terms: "str | FitTerms" = "data") -> FitResult:
    """``gyrorig fit``: smooth (for the outlier marks) unless given, fit, write ``fit.json`` and plots."""
    from .report import plot_fit
    from .theory import predict

    out = Path(out)
    angles = _read_angles(angles_csv)
    if smooth is None:
        smooth = smooth_angles(angles)
    if prediction is None:
        prediction = predict(protocol)
    truth = load_truth(truth_csv) if truth_csv is not None else None
    exclude = (smooth.table["status"] == "outlier").to_numpy()
    fit = fit_angles(angles, protocol, prediction=prediction, exclude=exclude, truth=truth, rng=rng, terms=terms)
    _io.write_csv(fit.residuals, out / "fit_residuals.csv")
    fig = plot_fit(angles, smooth.table, fit, title=f"{protocol.name}: tracked, smoothed and fitted")
    with _io.atomic_path(out / "fit.png") as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    _io.write_json(fit_document(fit, protocol, prediction, smooth, {"input": str(angles_csv)}), out / "fit.json")
    return fit


# ------------------------------------------------------------------------------------------ report
def _fig_data_uri(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _fmt(v, digits: int = 6) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, float | int | np.floating):
        return f"{v:.{digits}g}"
    return html.escape(str(v))


def _value_cell(q) -> str:
    if q.status != "determined":
        return f"<em>undetermined</em><br><small>{html.escape(q.reason)}</small>"
    cell = f"{_fmt(q.value)} ± {_fmt(q.standard_error, 2)}"
    if q.camera_standard_error:
        cell += f"<br><small>camera model: {_fmt(q.camera_standard_error, 2)} of it</small>"
    return cell


def _diff_cell(d) -> str:
    if d is None:
        return "–"
    cls = "bad" if abs(d) > 3 else "ok"
    return f'<span class="{cls}">{d:+.2f}</span>'


def write_report(path: str | Path, *, protocol: Protocol, fit: FitResult, angles: pd.DataFrame,
                 smooth: SmoothResult | None, prediction: dict | None, tracking: dict | None = None,
                 title: str | None = None) -> Path:
    """A self-contained HTML report (plots embedded as PNG data URIs)."""
    from .report import plot_fit

    pred = prediction or {}
    rows = []
    has_truth = any(q.truth is not None for q in fit.quantities.values())
    for name, q in fit.quantities.items():
        cells = [f"<code>{name}</code>", html.escape(q.units), _value_cell(q), _fmt(q.paper), _diff_cell(q.diff_paper_se),
                 _fmt(q.corrected), _fmt(q.exact), _diff_cell(q.diff_exact_se)]
        if has_truth:
            cells += [_fmt(q.truth), _diff_cell(q.pull)]
        note = q.note or (q.exact_source and f"exact: {q.exact_source}") or ""
        cells.append(f"<small>{html.escape(note)}</small>")
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    head = ["quantity", "units", "fitted ± s.e.", "paper", "(fit−paper)/s.e.", "corrected", "exact",
            "(fit−exact)/s.e."] + (["truth (simulator)", "pull"] if has_truth else []) + ["note"]
    table = ("<table><thead><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr></thead><tbody>"
             + "".join(rows) + "</tbody></table>")
    flags = pred.get("flags", {})
    validity = []
    ratio = flags.get("fast_top_ratio")
    if ratio is not None:
        validity.append(f"fast-top ratio {ratio:.3g}: the paper's closed forms assume a fast top (ratio ≥ 10)"
                        + (" — <b>not satisfied</b>, expect percent-level differences" if ratio < 10 else ""))
    if flags.get("small_tilt") is False:
        validity.append("launch tilt is not small: small-tilt formulas are approximate here")
    for key, v in pred.items():
        if isinstance(v, dict) and v.get("sign_agrees") is False:
            validity.append(f"<code>{key}</code>: the paper's formula has the <b>wrong sign</b> "
                            f"(paper {_fmt(v.get('paper'))}, exact {_fmt(v.get('exact'))}); see docs/theory.md")
    notes = "".join(f"<li>{html.escape(n.text)}</li>" for n in fit.notes)
    fig = plot_fit(angles, smooth.table if smooth else None, fit)
    img = _fig_data_uri(fig)
    sm = ""
    if smooth is not None:
        sm = (f"<p>Kalman/RTS smoother (constant-velocity process, noise levels by maximum likelihood): "
              f"q<sub>θ</sub> = {smooth.q_theta_rad2_s3:.3g}, q<sub>φ</sub> = {smooth.q_phi_rad2_s3:.3g} rad²/s³; "
              f"{smooth.n_measured} frames used, {smooth.n_outliers} outliers gated, {smooth.n_resets} restarts; "
              f"mean normalised innovation {smooth.nis_mean:.3f} (2 expected).</p>")
    tr = ""
    if tracking:
        q = tracking.get("quality_counts", {})
        tr = ("<p>Tracking: " + html.escape(", ".join(f"{k}: {v}" for k, v in q.items())) + f"; "
              f"{tracking.get('frames', '?')} frames.</p>")
    spec = fit.spec
    model = (f"axis {'fitted' if spec.fit_axis else 'vertical'}; {'damped' if spec.damped else 'undamped'}; "
             f"{spec.harmonics} nutation harmonic(s){'; persistent oscillation' if spec.persistent else ''}; "
             f"{spec.segments} azimuth segment(s); reference time t_ref = {fit.t_ref_s:.4g} s")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title or protocol.name)} — gyrorig report</title>
<style>
body {{ font-family: sans-serif; max-width: 1200px; margin: 1em auto; color: #222; }}
table {{ border-collapse: collapse; font-size: 0.9em; }}
th, td {{ border: 1px solid #ccc; padding: 3px 6px; text-align: right; vertical-align: top; }}
th {{ background: #eee; }} td:first-child, td:last-child {{ text-align: left; }}
.bad {{ color: #b00; font-weight: bold; }} .ok {{ color: #060; }}
img {{ max-width: 100%; }}
</style></head><body>
<h1>{html.escape(title or protocol.name)}</h1>
<p>{html.escape(protocol.description)}</p>
<h2>Fitted quantities against theory</h2>
{table}
<p>Fit: {html.escape(model)}. χ² = {fit.chi2:.1f} for {fit.dof} degrees of freedom (reduced {fit.chi2_red:.3f});
standard errors: {html.escape(fit.errors)}. Differences are in standard errors of the fit; |difference| &gt; 3 is in red.</p>
<h2>Validity of the paper's approximations</h2>
<ul>{''.join(f'<li>{v}</li>' for v in validity) or '<li>no flags</li>'}</ul>
{f'<h2>Notes</h2><ul>{notes}</ul>' if notes else ''}
<h2>Data, smoothing, fit and residuals</h2>
{tr}{sm}
<img alt="tilt, azimuth, tip path, residuals" src="{img}">
<p><small>gyrorig {html.escape(_io.versions()['gyrorig'])}; generated {time.strftime('%Y-%m-%d %H:%M:%S')}</small></p>
</body></html>
"""
    with _io.atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return Path(path)


# ------------------------------------------------------------------------------------- whole chain
def analyze_video(video: str | Path, camera: str | Path, protocol: Protocol, out: str | Path, *,
                  truth_csv: str | Path | None = None, progress: Progress | None = None,
                  rng: np.random.Generator | None = None, stage: Callable[[str], None] | None = None,
                  terms: "str | FitTerms" = "data") -> dict:
    """Track, smooth, fit and report one video; returns a summary dict.

    ``progress(done, total)`` follows the tracking frame by frame; ``stage(message)`` is told
    when each later stage starts (fits of long damped records take minutes).
    """
    say = stage or (lambda msg: logger.info(msg))
    from .theory import predict
    from .tracking import load_camera, track_video

    out = Path(out)
    t0 = time.perf_counter()
    tracked = track_video(video, load_camera(camera, require_pose=False), protocol, out / "track", progress=progress)
    angles = pd.read_csv(out / "track" / "angles.csv")
    t1 = time.perf_counter()
    say(f"smoothing {len(angles)} frames (noise levels by maximum likelihood) ...")
    smooth = smooth_angles(angles)
    _io.write_csv(smooth.table, out / "smoothed.csv")
    _io.write_json({"input": str(out / "track" / "angles.csv"), **smooth.summary()}, out / "smooth.json")
    t2 = time.perf_counter()
    say("theory predictions and the fit ...")
    prediction = predict(protocol)
    fit = fit_file(out / "track" / "angles.csv", protocol, out, truth_csv=truth_csv, smooth=smooth,
                   prediction=prediction, rng=rng, terms=terms)
    t3 = time.perf_counter()
    say("writing the report ...")
    tracking = {"frames": tracked["frames"], "tracked_fraction": tracked["tracked_fraction"],
                "quality_counts": quality_counts(angles)}
    write_report(out / "report.html", protocol=protocol, fit=fit, angles=angles, smooth=smooth, prediction=prediction,
                 tracking=tracking, title=f"{protocol.name}: {Path(video).name}")
    return {"video": str(video), "out": str(out), "report": str(out / "report.html"), "fit": fit,
            "frames": tracked["frames"], "tracked_fraction": tracked["tracked_fraction"],
            "time_s": {"track": t1 - t0, "smooth": t2 - t1, "fit": t3 - t2, "total": time.perf_counter() - t0}}


VIDEO_SUFFIXES = (".mkv", ".mp4", ".avi", ".mov", ".m4v", ".webm")


def analyze_batch(source: str | Path, out: str | Path, *, camera: str | Path | None = None,
                  protocol: Protocol | None = None, progress_line: Callable[[str], None] | None = None,
                  terms: "str | FitTerms" = "data") -> pd.DataFrame:
    """Analyse a folder of videos (one camera and protocol) or a manifest CSV.

    The manifest has columns ``video, protocol[, camera]`` (paths relative to the manifest).
    A video that fails is reported in the summary and skipped; the batch goes on.  Writes
    ``out/<video stem>/...`` per video and ``out/summary.csv`` (one row per video: status,
    error, and value/standard error of each quantity).
    """
    source, out = Path(source), Path(out)
    jobs: list[tuple[Path, Path, Protocol | Path]] = []
    if source.is_dir():
        if camera is None or protocol is None:
            raise ValueError("a folder of videos needs --camera and --protocol (or give a manifest CSV)")
        for v in sorted(p for p in source.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES):
            jobs.append((v, Path(camera), protocol))
        if not jobs:
            raise ValueError(f"no videos ({', '.join(VIDEO_SUFFIXES)}) in {source}")
    else:
        man = pd.read_csv(source)
        if "video" not in man.columns or ("protocol" not in man.columns and protocol is None):
            raise ValueError(f"manifest {source} needs columns video, protocol[, camera]")
        for _, row in man.iterrows():
            cam = row["camera"] if "camera" in man.columns and isinstance(row["camera"], str) else camera
            if cam is None:
                raise ValueError(f"manifest row for {row['video']} has no camera and no --camera was given")
            prot = source.parent / row["protocol"] if "protocol" in man.columns else protocol
            jobs.append((source.parent / row["video"], source.parent / cam if isinstance(cam, str) else cam, prot))
    rows = []
    stems: dict[str, int] = {}
    for i, (video, cam, prot) in enumerate(jobs):
        stem = video.stem
        stems[stem] = stems.get(stem, 0) + 1
        if stems[stem] > 1:
            stem = f"{stem}-{stems[stem]}"
        row: dict = {"video": str(video), "out": str(out / stem)}
        try:
            p = prot if isinstance(prot, Protocol) else load_protocol(prot)
            row["protocol"] = p.name
            res = analyze_video(video, cam, p, out / stem, terms=terms)
            row.update(status="ok", error="", frames=res["frames"], tracked_fraction=res["tracked_fraction"],
                       chi2_red=res["fit"].chi2_red)
            for name, q in res["fit"].quantities.items():
                row[name] = q.value
                row[f"{name}_se"] = q.standard_error
                row[f"{name}_camera_se"] = q.camera_standard_error
        except Exception as exc:  # one bad video must not stop the batch; the summary says why
            logger.exception("analysis of %s failed", video)
            row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
        rows.append(row)
        if progress_line:
            progress_line(f"[{i + 1}/{len(jobs)}] {video.name}: {row['status']}"
                          + (f" ({row['error']})" if row["status"] != "ok" else ""))
    cols = ["video", "protocol", "status", "error", "frames", "tracked_fraction", "chi2_red"]
    for name in QUANTITY_UNITS:
        cols += [name, f"{name}_se"]
    summary = pd.DataFrame(rows)
    summary = summary.reindex(columns=[c for c in cols if c in summary.columns] + ["out"])
    _io.write_csv(summary, out / "summary.csv")
    return summary
