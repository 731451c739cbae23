"""Rig parameters known only to a standard deviation: ``key = { value = ..., sd = ... }`` in a protocol.

Any number of ``[rig]``, ``[launch]`` or ``[pivot]`` (its damping tables included) may be given as a
value with a standard deviation; plain numbers stay exact.  Correlations go in an
``[uncertainty]`` section::

    [rig]
    inertia_axial_kg_m2 = { value = 4.725e-4, sd = 0.05e-4 }
    inertia_transverse_kg_m2 = { value = 3.839e-3, sd = 0.04e-3 }

    [uncertainty]
    correlations = [["rig.inertia_axial_kg_m2", "rig.inertia_transverse_kg_m2", 0.3]]

Parameters are named ``section.key`` (``pivot.damping.coefficient_N_m_s``; with several damping
tables ``pivot.damping[1].coefficient_N_m_s``), always in SI units: an uncertain ``tilt_deg`` becomes
``launch.tilt_rad`` with its standard deviation in radians.  :class:`Uncertainty` holds them;
:mod:`gyrorig.propagate` carries them into the predictions.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validate import ProtocolError

__all__ = ["Uncertainty", "split_uncertain", "UNCERTAIN_SECTIONS"]

#: the sections whose numbers may carry a standard deviation
UNCERTAIN_SECTIONS = ("rig", "launch", "pivot", "gimbal")


@dataclass(frozen=True)
class Uncertainty:
    """Standard deviations and correlations of a protocol's uncertain parameters (SI units)."""

    names: tuple[str, ...] = ()
    values: tuple[float, ...] = ()
    sd: tuple[float, ...] = ()
    #: the correlation matrix, row by row (the identity when none is given)
    correlation: tuple[tuple[float, ...], ...] = ()

    def __bool__(self) -> bool:
        return any(s > 0 for s in self.sd)

    def covariance(self) -> np.ndarray:
        s = np.asarray(self.sd, float)
        return np.asarray(self.correlation, float).reshape(len(s), len(s)) * np.outer(s, s)

    def sd_of(self, name: str) -> float:
        """The standard deviation of one parameter (0 when it is exact)."""
        return self.sd[self.names.index(name)] if name in self.names else 0.0

    def as_dict(self) -> dict:
        return {"names": list(self.names), "values": list(self.values), "sd": list(self.sd),
                "correlation": [list(r) for r in self.correlation]}


def _uncertain_number(where: str, t: Mapping[str, Any]) -> tuple[float, float]:
    bad = sorted(set(t) - {"value", "sd"})
    if bad or "value" not in t or "sd" not in t:
        raise ProtocolError(f"{where} = {dict(t)!r}: a number with an uncertainty is {{ value = ..., sd = ... }}"
                            + (f"; unknown key(s) {', '.join(bad)}" if bad else ""))
    out = []
    for k in ("value", "sd"):
        v = t[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ProtocolError(f"{where}.{k} = {v!r}: must be a finite number")
        out.append(float(v))
    if out[1] < 0:
        raise ProtocolError(f"{where}.sd = {out[1]!r} is out of range; allowed [0, inf)")
    return out[0], out[1]


def _walk(prefix: str, table: Any, found: list) -> Any:
    """``table`` with each ``{value, sd}`` replaced by its value; ``found`` gets ``(name, value_si, sd_si)``."""
    if isinstance(table, list):
        if table and all(isinstance(x, Mapping) for x in table):
            return [_walk(f"{prefix}[{i}]", x, found) for i, x in enumerate(table)]
        return table
    if not isinstance(table, Mapping):
        return table
    out = {}
    for key, v in table.items():
        where = f"{prefix}.{key}"
        if isinstance(v, Mapping) and ("sd" in v or "value" in v):
            value, sd = _uncertain_number(where, v)
            out[key] = value
            if key.endswith("_deg"):  # inside, angles are radians
                found.append((where[:-4] + "_rad", math.radians(value), math.radians(sd)))
            else:
                found.append((where, value, sd))
        elif isinstance(v, (Mapping, list)):
            out[key] = _walk(where, v, found)
        else:
            out[key] = v
    return out


def _correlation(names: list[str], section: Any) -> np.ndarray:
    n = len(names)
    rho = np.eye(n)
    if section is None:
        return rho
    if not isinstance(section, Mapping) or set(section) - {"correlations"}:
        raise ProtocolError("[uncertainty] takes one key, correlations = [[name_a, name_b, rho], ...]")
    rows = section.get("correlations", [])
    if not isinstance(rows, list):
        raise ProtocolError(f"uncertainty.correlations = {rows!r}: expected a list of [name_a, name_b, rho]")
    for i, row in enumerate(rows):
        where = f"uncertainty.correlations[{i}]"
        if not (isinstance(row, list) and len(row) == 3 and all(isinstance(x, str) for x in row[:2])):
            raise ProtocolError(f"{where} = {row!r}: expected [name_a, name_b, rho]")
        a, b, r = row
        for name in (a, b):
            if name not in names:
                raise ProtocolError(f"{where}: {name!r} has no standard deviation; uncertain parameters: "
                                    + (", ".join(names) or "none"))
        if a == b or isinstance(r, bool) or not isinstance(r, (int, float)) or not -1 < r < 1:
            raise ProtocolError(f"{where}: needs two different names and a correlation in (-1, 1); got {row!r}")
        rho[names.index(a), names.index(b)] = rho[names.index(b), names.index(a)] = float(r)
    if np.min(np.linalg.eigvalsh(rho)) <= 0:
        raise ProtocolError("uncertainty.correlations: the correlation matrix is not positive definite "
                            "(the correlations contradict each other)")
    return rho


def split_uncertain(data: Mapping[str, Any]) -> tuple[dict, Uncertainty]:
    """The protocol document with every ``{value, sd}`` replaced by its value, and the uncertainties."""
    found: list = []
    plain = dict(data)
    for sec in UNCERTAIN_SECTIONS:
        if sec in plain:
            plain[sec] = _walk(sec, plain[sec], found)
    names = [n for n, _, _ in found]
    rho = _correlation(names, plain.pop("uncertainty", None))
    unc = Uncertainty(tuple(names), tuple(v for _, v, _ in found), tuple(s for _, _, s in found),
                      tuple(tuple(float(x) for x in r) for r in rho))
    return plain, unc
