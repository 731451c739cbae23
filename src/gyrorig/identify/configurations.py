"""Several configurations of one rig in one identification: the prior's ``[[configuration]]`` tables.

A lab measures one gyro in more than one way: with and without its rod and weight, with a ring added, its gimbals
locked or free.  What the configurations share (the rotor's ``Io``, say) is one parameter; what differs is given
per configuration, and the tables measured in it are named::

    [[configuration]]
    name = "no rod"
    tables = ["nutation-no-rod.csv"]     # inputs measured in it (by file name)
    [configuration.rig]
    mass_kg = 0.41                        # held at this value in this configuration
    com_distance_m = 0.0
    inertia_transverse_kg_m2 = { value = 3.0e-3, sd = 0.6e-3 }   # its own parameter, with its prior
    [configuration.gimbal]               # for a gyro in gimbals ([gimbal] in the prior)
    outer_inertia_kg_m2 = { value = 2e-4, sd = 1e-4 }

A key given as a number is held in that configuration; one given as ``{ value, sd }`` is a parameter of its own,
``configuration[<name>].rig.<key>``; a key not given is the prior's (shared, free or held as the prior says).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

from ..protocols import Protocol, ProtocolError, checked_rig
from .observations import Observation
from .tables import IdentifyInputError

__all__ = ["Configuration", "parse_configurations", "configuration_of", "configured_prior", "configured"]

#: the keys a configuration may give, per section
KEYS = {"rig": ("mass_kg", "com_distance_m", "inertia_axial_kg_m2", "inertia_transverse_kg_m2",
                "frame_axial_inertia_kg_m2"),
        "gimbal": ("outer_inertia_kg_m2", "cross_inertia_kg_m2")}


@dataclass(frozen=True)
class Configuration:
    """One configuration: its name, the inputs measured in it, the values it holds and its own parameters'
    priors (``section.key`` -> value, or -> ``(mean, sd)``)."""

    name: str
    tables: tuple[str, ...]
    held: dict[str, float]
    free: dict[str, tuple[float, float]]

    def parameter(self, key: str) -> str:
        """The name of this configuration's own parameter for ``key`` (``rig.x`` or ``gimbal.x``)."""
        return f"configuration[{self.name}].{key}"


def _value(where: str, v) -> tuple[float, float]:
    """``(value, sd)`` of a number or ``{ value, sd }`` (sd 0: held)."""
    if isinstance(v, dict):
        if set(v) != {"value", "sd"}:
            raise IdentifyInputError(f"{where}: give a number or {{ value, sd }}, found {v!r}")
        value, sd = v["value"], v["sd"]
    else:
        value, sd = v, 0.0
    for what, x in (("value", value), ("sd", sd)):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise IdentifyInputError(f"{where}: {what} {x!r} is not a finite number")
    if sd < 0:
        raise IdentifyInputError(f"{where}: sd {sd!r} must be >= 0")
    return float(value), float(sd)


def parse_configurations(prior: Protocol) -> list[Configuration]:
    """The prior's ``[[configuration]]`` tables (module docstring); IdentifyInputError naming the configuration and
    the key for anything else."""
    raw = prior.extra.get("configuration", [])
    if isinstance(raw, dict):
        raw = [raw]
    if not isinstance(raw, list) or not all(isinstance(c, dict) for c in raw):
        raise IdentifyInputError(f"{prior.source}: [[configuration]] must be tables")
    out, names, files = [], set(), {}
    for k, c in enumerate(raw):
        where = f"{prior.source}: [[configuration]] {k + 1}"
        unknown = sorted(set(c) - {"name", "tables", *KEYS})
        if unknown:
            raise IdentifyInputError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: name, tables, "
                                     + ", ".join(KEYS))
        name = c.get("name")
        if not isinstance(name, str) or not name or name in names:
            raise IdentifyInputError(f"{where}: name = {name!r}: give each configuration a name of its own")
        names.add(name)
        tables = c.get("tables")
        if not isinstance(tables, list) or not tables or not all(isinstance(t, str) and t for t in tables):
            raise IdentifyInputError(f"{where} ({name}): tables = {tables!r}: give the file names measured in it")
        for t in tables:
            if Path(t).name in files:
                raise IdentifyInputError(f"{where} ({name}): {t} is also in configuration {files[Path(t).name]!r}")
            files[Path(t).name] = name
        held, free = {}, {}
        for section, keys in KEYS.items():
            table = c.get(section, {})
            if not isinstance(table, dict):
                raise IdentifyInputError(f"{where} ({name}): [{section}] must be a table")
            if section == "gimbal" and table and prior.gimbal is None:
                raise IdentifyInputError(f"{where} ({name}): [gimbal] values for a prior without [gimbal]")
            for key, v in table.items():
                if key not in keys:
                    raise IdentifyInputError(f"{where} ({name}): {section}.{key} is not a configuration's key; "
                                             f"allowed: {', '.join(keys)}")
                value, sd = _value(f"{where} ({name}): {section}.{key}", v)
                if sd > 0:
                    free[f"{section}.{key}"] = (value, sd)
                else:
                    held[f"{section}.{key}"] = value
        out.append(Configuration(name, tuple(tables), held, free))
    return out


def configuration_of(path: str | Path, configurations: list[Configuration]) -> Configuration | None:
    """The configuration an input was measured in (by its file name), or None (the prior's)."""
    name = Path(path).name
    return next((c for c in configurations if name in {Path(t).name for t in c.tables}), None)


def configured_prior(prior: Protocol, cfg: Configuration) -> Protocol:
    """The prior with the configuration's values (held, and its own parameters' prior means)."""
    values = {**cfg.held, **{k: m for k, (m, _) in cfg.free.items()}}
    rig = replace(prior.rig, **{k.split(".", 1)[1]: v for k, v in values.items() if k.startswith("rig.")})
    gimbal = prior.gimbal
    if gimbal is not None:
        gimbal = replace(gimbal, **{k.split(".", 1)[1]: v for k, v in values.items() if k.startswith("gimbal.")})
    try:
        checked_rig(rig)
    except ProtocolError as exc:
        raise IdentifyInputError(f"{prior.source}: configuration {cfg.name!r}: {exc}") from None
    extra = {k: v for k, v in prior.extra.items() if k != "configuration"}
    return replace(prior, rig=rig, gimbal=gimbal, extra=extra)


def configured(obs: list[Observation], cfg: Configuration) -> list[Observation]:
    """The observations of an input measured in ``cfg`` (built on :func:`configured_prior`): their models take
    the configuration's own parameters for its keys and ignore the shared values of the keys it holds."""
    own = {k: cfg.parameter(k) for k in cfg.free}
    given = set(cfg.held) | set(cfg.free)

    def wrap(f):
        if f is None:
            return None

        def g(params, x):
            p = {k: v for k, v in params.items() if k not in given}
            p.update({k: params[name] for k, name in own.items()})
            return f(p, x)
        return g
    priors = tuple((cfg.parameter(k), m, s) for k, (m, s) in cfg.free.items())
    return [replace(o, exact=wrap(o.exact), fast=wrap(o.fast), own_priors=priors) for o in obs]
