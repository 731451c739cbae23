"""``gyrorig identify`` on files: read the inputs, identify, write ``identified.toml``, ``identify.json``,
``identify.png`` (each atomically)."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import tomli_w

from .. import _io
from ..protocols import Protocol, ProtocolError, load_protocol, protocol_path
from .configurations import configuration_of, configured, configured_prior, parse_configurations
from .estimate import Identification, extra_priors, formulas_used, identify_parameters, prior_rig_values
from .observations import Observation, observations_from_fit, observations_from_table
from .tables import WORKBOOK_SUFFIXES, IdentifyInputError, read_tables

__all__ = ["read_observations", "identify_files", "identified_toml", "identify_document", "plot_identification"]


def read_observations(inputs: list[str | Path], prior: Protocol) -> list[Observation]:
    """Every observation of the inputs: lab tables (CSV files, Excel workbooks: :func:`read_tables`) and fit.json
    files, each with the configuration it was measured in (:mod:`~gyrorig.identify.configurations`)."""
    obs: list[Observation] = []
    configurations = parse_configurations(prior)
    for path in map(Path, inputs):
        cfg = configuration_of(path, configurations)
        if cfg is not None:
            obs += configured(read_observations([path], configured_prior(prior, cfg)), cfg)
            continue
        if path.suffix.lower() == ".json":
            try:
                _io.check_settings_size(path, "fit.json")
                doc = json.loads(_io.read_settings_text(path))
            except _io.InputTooLarge as exc:
                raise IdentifyInputError(str(exc)) from None
            except FileNotFoundError:
                raise IdentifyInputError(f"{path}: no such file") from None
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise IdentifyInputError(f"{path}: not a fit.json ({exc})") from None
            obs += observations_from_fit(str(path), doc, prior)
        elif path.suffix.lower() in (".csv", ".txt", ".tsv", *WORKBOOK_SUFFIXES):
            for table in read_tables(path):
                obs += observations_from_table(table, prior)
        else:
            raise IdentifyInputError(f"{path}: an input is a fit.json, a CSV table or an Excel workbook (.xlsx)")
    return obs


def identified_toml(prior_text: str, ident: Identification, prior: Protocol, inputs: list[str] | None = None) -> str:
    """The prior protocol (parsed from its text) with each identified ``[rig]`` (and ``[gimbal]``) value as
    ``{ value, sd }`` and their
    correlations in ``[uncertainty]``, written by a TOML serialiser (tomli-w): it loads as a protocol, and serves
    again as a prior.  Comments of the prior are not kept; a header says where the values come from."""
    data = tomllib.loads(prior_text)
    se = ident.standard_errors
    rig_names = [n for n in ident.names if n.startswith(("rig.", "gimbal."))]
    for section in ("rig", "gimbal"):
        table = dict(data.get(section, {}))
        for n in rig_names:
            if n.startswith(section + "."):
                i = ident.names.index(n)
                table[n.split(".", 1)[1]] = {"value": float(ident.values[i]), "sd": float(se[i])}
        if table:
            data[section] = table
    for cfg in data.get("configuration", []) if isinstance(data.get("configuration"), list) else []:
        for n in ident.names:
            head = f"configuration[{cfg.get('name')}]."
            if n.startswith(head):
                section, key = n[len(head):].split(".", 1)
                i = ident.names.index(n)
                cfg.setdefault(section, {})[key] = {"value": float(ident.values[i]), "sd": float(se[i])}
    corr = ident.correlation
    pairs = [[a, b, float(max(-0.999999, min(0.999999, corr[ident.names.index(a), ident.names.index(b)])))]
             for i, a in enumerate(rig_names) for b in rig_names[i + 1:]]
    pairs = [p for p in pairs if math.isfinite(p[2]) and abs(p[2]) > 1e-6]
    data.pop("uncertainty", None)
    if pairs:
        data["uncertainty"] = {"correlations": pairs}
    header = (f"# {prior.name}: the rig identified by gyrorig identify"
              + (f" from {', '.join(map(str, inputs))}" if inputs else "") + "\n"
              "# the identified [rig] (and [gimbal]) values are { value, sd }; their correlations are in "
              "[uncertainty]\n\n")
    return header + tomli_w.dumps(data)


def identify_document(ident: Identification, prior: Protocol, inputs: list[str]) -> dict:
    """The content of ``identify.json``."""
    se = ident.standard_errors
    p = ident.params()
    rows = []
    for o, s in zip(ident.observations, ident.sd_eff):
        pred = o.predict({**prior_rig_values(prior), **p})
        fast = o.predict({**prior_rig_values(prior), **p}, fast=True) if o.fast is not None else None
        rows.append({"source": o.source, "line": o.line, "kind": o.kind, "observed": o.y, "sd": s, "predicted": pred,
                     "residual": o.y - pred, "normalised_residual": (o.y - pred) / s,
                     "predicted_fast_top": fast,
                     "fast_top_residual_sd": None if fast is None else (o.y - fast) / s,
                     "conditions": o.x})
    return _io.json_safe({
        "prior": prior.source, "inputs": inputs,
        "parameters": {n: {"value": float(v), "standard_error": float(e), "prior": _prior_of(n, ident, prior)}
                       for n, v, e in zip(ident.names, ident.values, se)},
        "derived": {k: {"value": v, "standard_error": e} for k, (v, e) in ident.derived(prior).items()},
        "correlation": {"names": list(ident.names), "matrix": ident.correlation.tolist()},
        "chi2": ident.chi2, "dof": ident.dof, "chi2_red": ident.chi2_red, "p_value": ident.p_value,
        "lack_of_fit": ident.lack_of_fit,
        "formulas": formulas_used(ident), "damping_law": ident.damping_law or None,
        "friction_chi2_gain": ident.friction_chi2_gain, "sd_from_scatter": list(ident.sd_from_scatter),
        "notes": list(ident.notes), "rows": rows,
    })


def _prior_of(name: str, ident: Identification, prior: Protocol) -> dict | None:
    """A parameter's prior ``{value, sd}`` (None: flat)."""
    if name not in ident.prior_names:
        return None
    u = prior.uncertainty
    if name in u.names:
        return {"value": u.values[u.names.index(name)], "sd": u.sd_of(name)}
    mean, sd = extra_priors(list(ident.observations))[name]
    return {"value": mean, "sd": sd}


def plot_identification(ident: Identification, prior: Protocol):
    """Observed against predicted, one panel per kind (normalised residuals beneath the diagonal)."""
    from matplotlib.figure import Figure

    kinds = sorted({o.kind for o in ident.observations})
    fig = Figure(figsize=(4.2 * len(kinds), 4.0), layout="constrained")
    axes = fig.subplots(1, len(kinds), squeeze=False)[0]
    p = {**prior_rig_values(prior), **ident.params()}
    for ax, kind in zip(axes, kinds):
        sel = [(o, s) for o, s in zip(ident.observations, ident.sd_eff) if o.kind == kind]
        y = np.array([o.y for o, _ in sel])
        s = np.array([s for _, s in sel])
        pred = np.array([o.predict(p) for o, _ in sel])
        ax.errorbar(pred, y, yerr=s, fmt="o", ms=4, label="exact model")
        if sel[0][0].fast is not None:
            fast = np.array([o.predict(p, fast=True) for o, _ in sel])
            ax.plot(fast, y, "x", color="C3", label="fast-top formula")
        lo, hi = float(min(y.min(), pred.min())), float(max(y.max(), pred.max()))
        ax.plot([lo, hi], [lo, hi], "k-", lw=0.8)
        ax.set_xlabel("predicted (SI)")
        ax.set_ylabel("observed (SI)")
        ax.set_title(kind.replace("_", " "))
        ax.legend(fontsize=8)
    fig.suptitle(f"{prior.name}: identified rig, chi2_red {ident.chi2_red:.3g}")
    return fig


def identify_files(inputs: list[str | Path], prior_path: str | Path, out: str | Path) -> Identification:
    """``gyrorig identify``: read, identify, write the three files into ``out``."""
    prior = load_protocol(prior_path)
    if not (prior.rig.gravity_m_s2 and prior.rig.mass_kg):
        raise ProtocolError(f"{prior_path}: identify needs rig.mass_kg and rig.gravity_m_s2 (the known numbers)")
    obs = read_observations(inputs, prior)
    ident = identify_parameters(obs, prior)
    if not all(math.isfinite(v) for v in ident.standard_errors):
        raise IdentifyInputError("the inputs do not determine every parameter (infinite standard error)")
    out = Path(out)
    text = identified_toml(_io.read_settings_text(protocol_path(prior_path)), ident, prior, [str(i) for i in inputs])
    with _io.atomic_path(out / "identified.toml") as tmp:
        Path(tmp).write_text(text)
    _io.write_json(identify_document(ident, prior, [str(i) for i in inputs]), out / "identify.json")
    fig = plot_identification(ident, prior)
    with _io.atomic_path(out / "identify.png") as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    return ident
