"""The analysis chain on files: track -> smooth -> fit -> report, for one video or a batch.

File wrappers around :mod:`gyrorig.pipeline`.  Outputs of :func:`analyze_video` in ``out``:

- ``track/angles.csv``, ``track/markers.csv``: the tracker's tables (:mod:`gyrorig.tables`), written
  as soon as tracking is done;
- ``smoothed.csv``: the smoother's table (:data:`gyrorig.smooth.SMOOTH_COLUMNS` and the
  covariance ``cov_ij`` of ``[theta, theta', phi, phi']``), ``smooth.json`` (noise levels);
- ``fit.json``: each quantity with value, standard error, units, the paper's, corrected and
  exact predictions, the differences in standard errors, status and reason; the model,
  chi-square, notes; ``fit_residuals.csv``; ``fit.png``;
- ``report.html``: one self-contained page (plots embedded) a browser opens offline.

Every file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from . import _io
from .fit import QUANTITY_UNITS, Constraints, FitResult, FitTerms
from .pipeline import Analysis, Fitted, analyze, smooth_and_fit
from .prediction import Prediction
from .protocols import Protocol, load_protocol, protocol_summary
from .report import plot_fit, write_report
from .smooth import SmoothResult, smooth_angles
from .tables import quality_counts, tip_truth
from .tracking import TrackResult

logger = logging.getLogger(__name__)

__all__ = ["load_truth", "smooth_file", "fit_file", "analyze_video", "analyze_batch", "fit_document", "write_analysis",
           "VIDEO_SUFFIXES"]

Progress = Callable[[int, int], None]
#: the files of a folder analysed as videos (any case): common containers, a camcorder's AVCHD (``.mts``, ``.m2ts``),
#: MPEG, Windows Media, raw streams, a Phantom high-speed camera's ``.cine``
VIDEO_SUFFIXES = (".mkv", ".mp4", ".avi", ".mov", ".m4v", ".webm", ".mts", ".m2ts", ".ts", ".3gp", ".mpg", ".mpeg",
                  ".wmv", ".asf", ".flv", ".mxf", ".ogv", ".dv", ".vob", ".nut", ".y4m", ".h264", ".264", ".hevc",
                  ".265", ".cine")


def load_truth(path: str | Path, marker: str = "tip") -> pd.DataFrame:
    """Tip angles from a renderer's ``truth.csv`` (:func:`gyrorig.tables.tip_truth`)."""
    try:
        return tip_truth(pd.read_csv(path), marker)
    except FileNotFoundError:
        raise ValueError(f"--truth {path}: no such file") from None
    except UnicodeDecodeError:
        raise ValueError(f"--truth {path}: not UTF-8 text (a truth.csv is expected)") from None
    except ValueError as exc:  # includes pandas' parser errors
        raise ValueError(f"{path}: {exc}") from exc


def _read_angles(path: str | Path) -> pd.DataFrame:
    try:
        return pd.read_csv(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise ValueError(f"cannot read angle table {path}: {exc}") from exc
    except UnicodeDecodeError:
        raise ValueError(f"cannot read angle table {path}: not UTF-8 text (a CSV table is expected)") from None


def _span(angles: pd.DataFrame, start, end) -> pd.DataFrame:
    """The rows of an angle table between two cuts (times on its own clock, or its frame numbers)."""
    if start is None and end is None:
        return angles
    keep = np.ones(len(angles), bool)
    for cut, option, after in ((start, "--start", True), (end, "--end", False)):
        if cut is None:
            continue
        column = "t_s" if cut.unit == "s" else "frame"
        if column not in angles.columns:
            raise ValueError(f"{option} {cut}: the angle table has no {column} column")
        v = angles[column].to_numpy(float)
        keep &= (v >= cut.value) if after else (v <= cut.value)
    if not keep.any():
        raise ValueError(f"no rows of the angle table lie between --start and --end ({start}, {end})")
    return angles[keep].reset_index(drop=True)


def smooth_file(angles_csv: str | Path, out: str | Path) -> SmoothResult:
    """``gyrorig smooth``: write ``smoothed.csv`` and ``smooth.json``."""
    out = Path(out)
    res = smooth_angles(_read_angles(angles_csv))
    _io.write_csv(res.table, out / "smoothed.csv")
    _io.write_json({"input": str(angles_csv), **res.summary(), "versions": _io.versions()}, out / "smooth.json")
    return res


def fit_document(fit: FitResult, protocol: Protocol, prediction: Prediction | None,
                 smooth: SmoothResult | None = None, extra: dict | None = None) -> dict:
    """The content of ``fit.json``."""
    doc = {"protocol": protocol.name, "description": protocol.description, **fit.summary(),
           "protocol_summary": protocol_summary(protocol),
           "theory_flags": prediction.flags.to_dict() if prediction is not None else {}, "versions": _io.versions()}
    if smooth is not None:
        doc["smoother"] = smooth.summary()
    if extra:
        doc.update(extra)
    return _io.json_safe(doc)


def _write_fit(out: Path, angles: pd.DataFrame, fitted: Fitted, protocol: Protocol, input_name: str) -> None:
    """``fit_residuals.csv``, ``fit.png`` and ``fit.json``."""
    _io.write_csv(fitted.fit.residuals, out / "fit_residuals.csv")
    fig = plot_fit(angles, fitted.smooth.table, fitted.fit, title=f"{protocol.name}: tracked, smoothed and fitted")
    with _io.atomic_path(out / "fit.png") as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    _io.write_json(fit_document(fitted.fit, protocol, fitted.prediction, fitted.smooth, {"input": input_name}),
                   out / "fit.json")


def fit_file(angles_csv: str | Path, protocol: Protocol, out: str | Path, *, truth_csv: str | Path | None = None,
             smooth: SmoothResult | None = None, prediction: Prediction | None = None,
             rng: np.random.Generator | None = None, terms: FitTerms | str = "data",
             constraints: Constraints | None = None, start=None, end=None) -> FitResult:
    """``gyrorig fit``: smooth (for the outlier marks) unless given, fit, write ``fit.json`` and plots.

    ``start``, ``end``: :class:`gyrorig.tracking.sources.Cut` s (None: the table's first or last row): the part of the
    table to use, by its own times (``t_s``) or its ``frame`` column."""
    angles = _span(_read_angles(angles_csv), start, end)
    truth = load_truth(truth_csv) if truth_csv is not None else None
    fitted = smooth_and_fit(angles, protocol, prediction=prediction, truth=truth, rng=rng, terms=terms, smooth=smooth,
                            constraints=constraints)
    _write_fit(Path(out), angles, fitted, protocol, str(angles_csv))
    return fitted.fit


def _write_tracking(out: Path, tracked: TrackResult) -> None:
    _io.write_csv(tracked.angles, out / "track" / "angles.csv")
    _io.write_csv(tracked.markers, out / "track" / "markers.csv")
    _io.write_json(tracked.summary(), out / "track" / "track.json")


def write_analysis(out: str | Path, analysis: Analysis, protocol: Protocol, *, title: str) -> Path:
    """Everything after tracking: ``smoothed.csv``, ``smooth.json``, the fit's files, ``report.html``."""
    out = Path(out)
    _io.write_csv(analysis.smooth.table, out / "smoothed.csv")
    _io.write_json({"input": str(out / "track" / "angles.csv"), **analysis.smooth.summary()}, out / "smooth.json")
    fitted = Fitted(analysis.smooth, analysis.prediction, analysis.fit, analysis.time_s)
    _write_fit(out, analysis.angles, fitted, protocol, str(out / "track" / "angles.csv"))
    check = analysis.tracking.sigma_check
    tracking = {"frames": analysis.tracking.frames, "tracked_fraction": analysis.tracking.tracked_fraction,
                "quality_counts": quality_counts(analysis.angles),
                "sigma_check": check.as_dict() if check is not None else None,
                "source_problems": list(analysis.tracking.source_problems)}
    return write_report(out / "report.html", protocol=protocol, fit=analysis.fit, angles=analysis.angles,
                        smooth=analysis.smooth, prediction=analysis.prediction, tracking=tracking, title=title)


def analyze_video(video, camera, protocol: Protocol, out: str | Path, *, truth_csv: str | Path | None = None,
                  progress: Progress | None = None, rng: np.random.Generator | None = None,
                  stage: Callable[[str], None] | None = None, terms: FitTerms | str = "data",
                  constraints: Constraints | None = None, prediction: Prediction | None = None,
                  title: str | None = None, frame_dots: bool = False) -> dict:
    """Track, smooth, fit and report one video (:func:`gyrorig.pipeline.analyze`); returns a summary dict
    (``video, out, report, fit, analysis, frames, tracked_fraction, time_s``).  ``frame_dots``: track the frame's
    dots too (``psi_rad`` in ``track/angles.csv``; the fit does not use it).

    ``progress(done, total)`` follows the tracking frame by frame; ``stage(message)`` is told
    when each later step starts.
    """
    out = Path(out)
    truth = load_truth(truth_csv) if truth_csv is not None else None
    res = analyze(video, camera, protocol, truth=truth, prediction=prediction, terms=terms, constraints=constraints,
                  rng=rng, progress=progress, frame_dots=frame_dots,
                  stage=stage, on_tracked=lambda tracked: _write_tracking(out, tracked))
    (stage or logger.info)("writing the report ...")
    report = write_analysis(out, res, protocol, title=title or f"{protocol.name}: {Path(str(video)).name}")
    return {"video": str(video), "out": str(out), "report": str(report), "fit": res.fit, "analysis": res,
            "frames": res.tracking.frames, "tracked_fraction": res.tracking.tracked_fraction, "time_s": res.time_s}


def _batch_jobs(source: Path, camera, protocol: Protocol | None) -> list[tuple[Path, Path, Protocol | Path]]:
    """(video, camera, protocol) for each video of a folder or manifest CSV."""
    jobs: list[tuple[Path, Path, Protocol | Path]] = []
    if source.is_dir():
        if camera is None or protocol is None:
            raise ValueError("a folder of videos needs --camera and --protocol (or give a manifest CSV)")
        for v in sorted(p for p in source.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES):
            jobs.append((v, Path(camera), protocol))
        if not jobs:
            raise ValueError(f"no videos ({', '.join(VIDEO_SUFFIXES)}) in {source}")
        return jobs
    try:
        man = _io.read_table_csv(source, numbers=False, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ValueError(f"manifest {source}: not a readable CSV table ({exc})") from None
    man.columns = [str(c).strip() for c in man.columns]
    if "video" not in man.columns or ("protocol" not in man.columns and protocol is None):
        raise ValueError(f"manifest {source} needs columns video, protocol[, camera]; has {', '.join(man.columns)}")
    if man.empty:
        raise ValueError(f"manifest {source}: no rows (one row per video: video, protocol[, camera])")
    for i, row in man.iterrows():
        line = int(i) + 2
        for col in ("video", "protocol"):
            if col in man.columns and not row[col].strip():
                raise ValueError(f"manifest {source}, line {line}: the {col} cell is empty")
        cam = row["camera"].strip() if "camera" in man.columns and row["camera"].strip() else camera
        if cam is None:
            raise ValueError(f"manifest {source}, line {line}: no camera for {row['video']} and no --camera given")
        prot = source.parent / row["protocol"].strip() if "protocol" in man.columns else protocol
        jobs.append((source.parent / row["video"].strip(), source.parent / cam if isinstance(cam, str) else cam, prot))
    return jobs


def _result_name(video: Path, base: Path, taken: set[str]) -> str:
    """A video's result folder name inside the batch's ``--out``, unique within the batch: its path relative to the
    batch's folder (or its name) without the suffix, the folders joined by ``__``, characters other than letters,
    digits, ``.``, ``_`` and ``-`` replaced by ``_``, no ``.`` or ``..`` parts (a manifest row ``sub/..`` must not
    write outside ``--out``); ``-2``, ``-3`` ... when taken."""
    try:
        rel = video.relative_to(base)
    except ValueError:
        rel = Path(video.name)
    parts = [re.sub(r"[^A-Za-z0-9._-]", "_", p) for p in rel.with_suffix("").parts]
    name = "__".join(p for p in parts if p.strip(".")) or "video"
    unique, k = name, 1
    while unique.lower() in taken or unique.lower() == "summary.csv":
        k += 1
        unique = f"{name}-{k}"
    taken.add(unique.lower())
    return unique


def analyze_batch(source: str | Path, out: str | Path, *, camera: str | Path | None = None,
                  protocol: Protocol | None = None, progress_line: Callable[[str], None] | None = None,
                  terms: FitTerms | str = "data", frame_dots: bool = False) -> pd.DataFrame:
    """Analyse a folder of videos (one camera and protocol) or a manifest CSV (``frame_dots`` as in
    :func:`analyze_video`).

    The manifest has columns ``video, protocol[, camera]`` (paths relative to the manifest).
    A video that fails is reported in the summary and skipped; the batch goes on.  Writes
    ``out/<video>/...`` per video (:func:`_result_name`: its path relative to the batch, unique) and ``out/summary.csv`` (one row per video: status,
    error, and value/standard error of each quantity).
    """
    source, out = Path(source), Path(out)
    jobs = _batch_jobs(source, camera, protocol)
    base = source if source.is_dir() else source.parent
    rows = []
    taken: set[str] = set()
    for i, (video, cam, prot) in enumerate(jobs):
        stem = _result_name(video, base, taken)
        row: dict = {"video": str(video), "out": str(out / stem)}
        try:
            p = prot if isinstance(prot, Protocol) else load_protocol(prot)
            row["protocol"] = p.name
            res = analyze_video(video, cam, p, out / stem, terms=terms, frame_dots=frame_dots)
            row.update(status="ok", error="", frames=res["frames"], tracked_fraction=res["tracked_fraction"],
                       chi2_red=res["fit"].chi2_red)
            for name, q in res["fit"].quantities.items():
                row[name] = q.value
                row[f"{name}_se"] = q.standard_error
                row[f"{name}_camera_se"] = q.camera_standard_error
        except Exception as exc:  # one bad video must not stop the batch; the summary says why
            logger.debug("analysis of %s failed", video, exc_info=True)  # the summary and progress line say why
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
