"""Lab tables for ``gyrorig identify``: CSV files with the unit in each column name, read into SI.

One file per kind (``spin_down``, ``precession``, ``nutation``), given by a ``kind`` column or by
the file name containing the kind.  A column is ``<name>_<unit>`` (``spin_rev_per_min``,
``precession_period_s`` or ``precession_rate_deg_per_s``, ``added_mass_g``, ``lever_arm_cm``, ``tilt_deg``), its
standard deviation ``<name>_<unit>_sd`` in the same unit.  Every problem is an :class:`IdentifyInputError` naming
the file, the row (as the line number in the file) and the column.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import _io

__all__ = ["IdentifyInputError", "Table", "read_table", "UNITS", "KINDS", "COLUMNS"]


class IdentifyInputError(ValueError):
    """A table, fit.json or prior that cannot be used (the message names the file, row and column)."""


#: unit suffix -> (dimension, factor to SI); longest suffixes are matched first
UNITS = {"_rev_per_min": ("rate", 2 * math.pi / 60), "_rad_s": ("rate", 1.0), "_hz": ("rate", 2 * math.pi),
         "_deg_per_s": ("rate", math.pi / 180),
         "_min": ("time", 60.0), "_s": ("time", 1.0), "_kg": ("mass", 1.0), "_g": ("mass", 1e-3),
         "_cm": ("length", 1e-2), "_mm": ("length", 1e-3), "_m": ("length", 1.0),
         "_deg": ("angle", math.pi / 180), "_rad": ("angle", 1.0),
         "_kg_m2": ("inertia", 1.0), "_g_cm2": ("inertia", 1e-7)}
#: what each column measures
COLUMNS = {"t": "time", "spin": "rate", "spin_start": "rate", "spin_end": "rate", "precession_period": "time",
           "precession_rate": "rate", "tilt_min": "angle", "tilt_max": "angle",
           "added_mass": "mass", "lever_arm": "length", "tilt": "angle", "nutation_frequency": "rate",
           "nutation_period": "time", "cone_angle": "angle", "added_outer_inertia": "inertia"}
#: the kinds, with their required columns (alternatives as tuples) and optional ones
KINDS = {
    "spin_down": {"required": ("t", "spin"), "optional": ()},
    "precession": {"required": (("spin", ("spin_start", "spin_end")), ("precession_period", "precession_rate")),
                   "optional": ("added_mass", "lever_arm", "tilt")},
    "nutation": {"required": ("spin", ("nutation_frequency", "nutation_period")),
                 "optional": ("added_mass", "lever_arm", "tilt", "cone_angle", "added_outer_inertia", "tilt_min",
                              "tilt_max")},
}
#: columns whose values must be > 0
POSITIVE = ("precession_period", "precession_rate", "nutation_period", "nutation_frequency", "spin", "spin_start",
            "spin_end")
#: the physical range of other columns (SI): ``(low, high, what it is)``
RANGES = {"tilt": (0.0, math.pi, "the tilt's range [0, 180] deg (from the vertical)"),
          "tilt_min": (0.0, math.pi, "the tilt's range [0, 180] deg (from the vertical)"),
          "tilt_max": (0.0, math.pi, "the tilt's range [0, 180] deg (from the vertical)"),
          "cone_angle": (0.0, 0.5 * math.pi, "a nutation cone's half-angle, [0, 90) deg"),
          "t": (0.0, math.inf, "times from the start, >= 0"),
          "added_mass": (0.0, math.inf, "an added mass, >= 0"),
          "added_outer_inertia": (0.0, math.inf, "an inertia added to the outer gimbal ring, >= 0")}


@dataclass(frozen=True)
class Table:
    """One lab table in SI: ``values[name]`` and ``sd[name]`` (0 where not given), by column name without unit."""

    path: str
    kind: str
    values: dict[str, np.ndarray]
    sd: dict[str, np.ndarray]
    #: the file's line number of each row (for messages)
    lines: np.ndarray

    @property
    def n(self) -> int:
        return len(self.lines)

    def has(self, name: str) -> bool:
        return name in self.values


def _split_unit(path: str, column: str) -> tuple[str, str, bool]:
    """``(name, suffix, is_sd)`` of a column; IdentifyInputError for an unknown unit or name."""
    is_sd = column.endswith("_sd")
    core = column[:-3] if is_sd else column
    for suffix in sorted(UNITS, key=len, reverse=True):
        if core.endswith(suffix):
            name = core[: -len(suffix)]
            if name not in COLUMNS:
                raise IdentifyInputError(f"{path}: column {column!r}: unknown quantity {name!r}; known: "
                                         + ", ".join(COLUMNS))
            if COLUMNS[name] != UNITS[suffix][0]:
                raise IdentifyInputError(f"{path}: column {column!r}: {name} is a {COLUMNS[name]}, "
                                         f"but {suffix[1:]} is a unit of {UNITS[suffix][0]}")
            return name, suffix, is_sd
    raise IdentifyInputError(f"{path}: column {column!r}: no known unit suffix; allowed: "
                             + ", ".join(s[1:] for s in UNITS))


def _kind(path: Path, frame: pd.DataFrame) -> str:
    if "kind" in frame.columns:
        kinds = set(frame["kind"].astype(str).str.strip())
        if len(kinds) != 1 or not kinds <= set(KINDS):
            raise IdentifyInputError(f"{path}: column 'kind' must hold one of {', '.join(KINDS)} in every row; "
                                     f"found {sorted(kinds)}")
        return kinds.pop()
    found = [k for k in KINDS if k in path.name.lower().replace("-", "_")]
    if len(found) != 1:
        raise IdentifyInputError(f"{path}: say what the table holds: a 'kind' column, or a file name containing "
                                 f"one of {', '.join(KINDS)}")
    return found[0]


def _check_required(path: Path, kind: str, names: set[str]) -> None:
    for req in KINDS[kind]["required"]:
        options = req if isinstance(req, tuple) else (req,)
        ok = any(all(n in names for n in (o if isinstance(o, tuple) else (o,))) for o in options)
        if not ok:
            alts = " or ".join("+".join(o) if isinstance(o, tuple) else o for o in options)
            raise IdentifyInputError(f"{path}: a {kind} table needs a column {alts} (with a unit suffix, e.g. "
                                     f"{(options[0] if isinstance(options[0], str) else options[0][0])}_s or _rad_s)")
    allowed = {n for r in KINDS[kind]["required"] for o in (r if isinstance(r, tuple) else (r,))
               for n in (o if isinstance(o, tuple) else (o,))} | set(KINDS[kind]["optional"])
    extra = sorted(names - allowed)
    if extra:
        raise IdentifyInputError(f"{path}: column(s) {', '.join(extra)} do not belong in a {kind} table; allowed: "
                                 + ", ".join(sorted(allowed)))


def read_table(path: str | Path) -> Table:
    """Read one lab table into SI units (see the module docstring)."""
    path = Path(path)
    try:
        frame = _io.read_table_csv(path, skipinitialspace=True, comment="#")
    except FileNotFoundError:
        raise IdentifyInputError(f"{path}: no such file") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise IdentifyInputError(f"{path}: not a readable CSV table ({exc})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    kind = _kind(path, frame)
    values: dict[str, np.ndarray] = {}
    sd: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    for column in frame.columns:
        if column == "kind":
            continue
        name, suffix, is_sd = _split_unit(str(path), column)
        raw = pd.to_numeric(frame[column], errors="coerce").to_numpy(float)
        bad = np.flatnonzero(~np.isfinite(raw))
        if len(bad) and not is_sd:
            raise IdentifyInputError(f"{path}, line {bad[0] + 2}, column {column!r}: {frame[column].iloc[bad[0]]!r} is "
                                     "not a finite number")
        if is_sd:
            raw = np.where(np.isfinite(raw), raw, 0.0)
            neg = np.flatnonzero(raw < 0)
            if len(neg):
                raise IdentifyInputError(f"{path}, line {neg[0] + 2}, column {column!r}: a standard deviation must "
                                         f"be >= 0; got {raw[neg[0]]!r}")
            sd[name] = raw * UNITS[suffix][1]
        else:
            if name in values:
                raise IdentifyInputError(f"{path}: {name} is given twice (column {column!r} and {units[name]!r})")
            values[name], units[name] = raw * UNITS[suffix][1], column
        if is_sd and f"{name}{suffix}" not in frame.columns:
            raise IdentifyInputError(f"{path}: column {column!r} has no column {name}{suffix} beside it")
    _check_required(path, kind, set(values))
    for name in POSITIVE:
        if name in values:
            neg = np.flatnonzero(values[name] <= 0)
            if len(neg):
                raise IdentifyInputError(f"{path}, line {neg[0] + 2}, column {units[name]!r}: must be > 0; got "
                                         f"{frame[units[name]].iloc[neg[0]]!r}")
    for name, (lo, hi, what) in RANGES.items():
        if name in values:
            off = np.flatnonzero(~((values[name] >= lo) & (values[name] <= hi)))
            if len(off):
                raise IdentifyInputError(f"{path}, line {off[0] + 2}, column {units[name]!r}: "
                                         f"{frame[units[name]].iloc[off[0]]!r} is outside {what}")
    if len(frame) == 0:
        raise IdentifyInputError(f"{path}: no rows")
    if kind == "spin_down" and len(frame) >= 3 and np.ptp(values["t"]) <= 0:
        raise IdentifyInputError(f"{path}, column {units['t']!r}: every row has the same time: a spin-down needs "
                                 "readings at different times")
    if kind == "spin_down" and len(frame) < 3:
        raise IdentifyInputError(f"{path}: a spin-down table has {len(frame)} row(s); it needs at least 3 (its "
                                 "initial spin, the viscous rate and the friction are fitted)")
    for name in values:
        sd.setdefault(name, np.zeros(len(frame)))
    return Table(str(path), kind, values, sd, np.arange(len(frame)) + 2)
