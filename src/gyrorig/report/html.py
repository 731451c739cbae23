"""The self-contained HTML report of one analysis (plots embedded as PNG data URIs, opens offline)."""

from __future__ import annotations

import base64
import html
import io
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

from .. import _io
from .._format import with_error
from ..fit import FitResult, FitTerms
from ..prediction import Prediction
from ..protocols import Protocol
from ..smooth import SmoothResult
from ..tracking.scatter import check_summary
from .plots import plot_fit

__all__ = ["write_report"]


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


def _pm(value, sd) -> str:
    """A value to the digits its standard error resolves (:func:`gyrorig._format.with_error`), with a ±."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return html.escape(with_error(float(value), sd).replace("+-", "±"))


def _value_cell(q) -> str:
    if q.status != "determined":
        return f"<em>undetermined</em><br><small>{html.escape(q.reason)}</small>"
    cell = _pm(q.value, q.standard_error)
    if q.camera_standard_error:
        cell += f"<br><small>camera model: {_fmt(q.camera_standard_error, 2)} of it</small>"
    return cell


def _predicted_cell(value, sd) -> str:
    """A prediction, with its own standard error when the rig's parameters carry uncertainties."""
    return _pm(value, sd) if sd else _fmt(value)


def _combined(q, kind: str):
    """The difference in standard errors: combined (measurement and prediction) where the prediction has one."""
    combined = getattr(q, f"diff_{kind}_combined_se")
    return combined if combined is not None else getattr(q, f"diff_{kind}_se")


def _diff_cell(d, q=None, kind: str = "") -> str:
    """The difference from a prediction in standard errors, and in % of the prediction where known."""
    if d is None:
        return "–"
    cls = "bad" if abs(d) > 3 else "ok"
    pct = ""
    ref = getattr(q, kind, None) if q is not None and kind else None
    if ref and q.value is not None and math.isfinite(ref):
        pct = f"{100 * (q.value - ref) / abs(ref):+.3g} %<br>"
    return f'{pct}<span class="{cls}">{d:+.3g}</span>'


def write_report(path: str | Path, *, protocol: Protocol, fit: FitResult, angles: pd.DataFrame,
                 smooth: SmoothResult | None, prediction: Prediction | None, tracking: dict | None = None,
                 title: str | None = None) -> Path:
    """A self-contained HTML report (plots embedded as PNG data URIs)."""
    pred = prediction if prediction is not None else Prediction(protocol.name)
    rows = []
    has_truth = any(q.truth is not None for q in fit.quantities.values())
    for name, q in fit.quantities.items():
        cells = [f"<code>{name}</code>", html.escape(q.units), _value_cell(q),
                 _predicted_cell(q.paper, q.paper_standard_error), _diff_cell(_combined(q, "paper"), q, "paper"),
                 _fmt(q.corrected), _predicted_cell(q.exact, q.exact_standard_error),
                 _diff_cell(_combined(q, "exact"), q, "exact")]
        if has_truth:
            cells += [_fmt(q.truth), _diff_cell(q.pull)]
        note = q.note or (q.exact_source and f"exact: {q.exact_source}") or ""
        if q.prediction_at == "record" and q.exact_source:
            note = f"exact: {q.exact_source}; {q.note}" if q.note else f"exact: {q.exact_source}"
        cells.append(f"<small>{html.escape(note)}</small>")
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    head = ["quantity", "units", "fitted ± s.e.", "paper", "fit−paper: % and s.e.", "corrected", "exact",
            "fit−exact: % and s.e."] + (["truth (simulator)", "pull"] if has_truth else []) + ["note"]
    table = ("<table><thead><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr></thead><tbody>"
             + "".join(rows) + "</tbody></table>")
    validity = []
    ratio = pred.flags.fast_top_ratio
    if ratio is not None:
        validity.append(f"fast-top ratio {ratio:.3g}: the paper's closed forms assume a fast top (ratio ≥ 10)"
                        + (" — <b>not satisfied</b>, expect percent-level differences" if ratio < 10 else ""))
    if pred.flags.small_tilt is False:
        validity.append("launch tilt is not small: small-tilt formulas are approximate here")
    if pred.parameter_uncertainty:
        validity.append("the rig's parameters carry standard deviations (protocol): each prediction has its own "
                        "± and the differences count both errors, s.e. = sqrt(s.e.<sub>fit</sub>² + "
                        "s.e.<sub>prediction</sub>²)")
    for key, v in pred.quantities.items():
        if v.sign_agrees is False:
            validity.append(f"<code>{key}</code>: the paper's formula has the <b>wrong sign</b> "
                            f"(paper {_fmt(v.paper)}, exact {_fmt(v.exact)}); see docs/theory.md")
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
              f"{tracking.get('frames', '?')} frames.")
        check = tracking.get("sigma_check")
        if check and check.get("coordinates"):
            summary = check_summary(check)
            tr += html.escape(f" {summary[0].upper()}{summary[1:]}.")
        tr += "</p>"
        tr += "".join(f'<p class="bad">The video: {html.escape(problem)}.</p>'
                      for problem in tracking.get("source_problems", ()))
    spec = fit.spec
    model = (f"axis {spec.axis_label}; {'damped' if spec.damped else 'undamped'}"
             f"{' (the spin decaying)' if spec.spin_decay else ''}; "
             f"{FitTerms.of(spec).describe()}; "
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
