"""Lab tables for ``gyrorig identify``: CSV files with the unit in each column name, read into SI.

One file per kind (``spin_down``, ``precession``, ``nutation``), given by a ``kind`` column or by
the file name containing the kind.  A column is ``<name>_<unit>`` (``spin_rev_per_min``,
``precession_period_s`` or ``precession_rate_deg_per_s``, ``added_mass_g``, ``lever_arm_cm``, ``tilt_deg``), its
standard deviation ``<name>_<unit>_sd``; or as a spreadsheet's header is written, the unit in brackets or after a
slash (``Spin (rpm)``, ``Precession period [s]``, ``t / s``, ``Tilt (°)``), the name's words joined by ``_``
(``time`` for ``t``), a standard deviation marked ``sd``, ``std``, ``sigma`` or ``±`` after the name
(``spin sd (rpm)``), or a column of its own (``± (rpm)``, ``sd [s]``) right of its value's column, or in each cell after
its value (``4000 ± 10``); the units may stand in a row of their own under the header (``Time, Spin`` then
``s, rpm``), or after ``in`` (DIN's ``t in s``), and a title may stand above the header.  A time may be a stopwatch's
reading (``1:05.5``).  Unit spellings: :data:`UNIT_WORDS`.  Every problem is an :class:`IdentifyInputError` naming
the file, the row (as the line number in the file) and the column as written.
"""

from __future__ import annotations

import datetime
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import _io

__all__ = ["IdentifyInputError", "Table", "read_table", "read_tables", "WORKBOOK_SUFFIXES", "UNITS", "UNIT_WORDS", "KINDS", "COLUMNS"]


class IdentifyInputError(ValueError):
    """A table, fit.json or prior that cannot be used (the message names the file, row and column)."""


#: unit suffix -> (dimension, factor to SI); longest suffixes are matched first
UNITS = {"_rev_per_min": ("rate", 2 * math.pi / 60), "_rpm": ("rate", 2 * math.pi / 60),
         "_rev_per_s": ("rate", 2 * math.pi), "_rad_s": ("rate", 1.0), "_hz": ("rate", 2 * math.pi),
         "_deg_per_s": ("rate", math.pi / 180),
         "_min": ("time", 60.0), "_s": ("time", 1.0), "_ms": ("time", 1e-3), "_kg": ("mass", 1.0), "_g": ("mass", 1e-3),
         "_cm": ("length", 1e-2), "_mm": ("length", 1e-3), "_m": ("length", 1.0),
         "_deg": ("angle", math.pi / 180), "_rad": ("angle", 1.0),
         "_kg_m2": ("inertia", 1.0), "_g_cm2": ("inertia", 1e-7)}
#: a unit as a header writes it in brackets or after a slash (lower case, spaces, ``*`` and ``·`` dropped, ``²`` and
#: ``^2`` as ``2``) -> its suffix in :data:`UNITS`; ``1/s`` is not one (radians or turns per second?)
UNIT_WORDS = {"rpm": "_rpm", "rev/min": "_rpm", "r/min": "_rpm", "u/min": "_rpm", "turns/min": "_rpm",
              "1/min": "_rpm", "min^-1": "_rpm", "min-1": "_rpm", "min⁻¹": "_rpm",
              "rps": "_rev_per_s", "rev/s": "_rev_per_s", "turns/s": "_rev_per_s", "hz": "_hz",
              "rad/s": "_rad_s", "deg/s": "_deg_per_s", "°/s": "_deg_per_s",
              "s": "_s", "sec": "_s", "ms": "_ms", "min": "_min", "g": "_g", "kg": "_kg",
              "cm": "_cm", "mm": "_mm", "m": "_m", "deg": "_deg", "°": "_deg", "degrees": "_deg", "rad": "_rad",
              "kgm2": "_kg_m2", "gcm2": "_g_cm2"}
#: other names a header may give a quantity
NAME_WORDS = {"time": "t", "spin_rate": "spin"}
#: words that mark a standard deviation: after a name, or alone (the column to the left's)
SD_WORDS = ("sd", "std", "sigma", "σ", "±", "+/-", "+-", "uncertainty")
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


def _split_unit(path: str, column: str, left: tuple[str, str, bool] | None = None) -> tuple[str, str, bool]:
    """``(name, suffix, is_sd)`` of a column (``left``: the column to its left's, whose deviation a column holding
    only a unit and a deviation's mark is); IdentifyInputError for an unknown unit or name."""
    written = _written(path, column, left)
    if written is not None:
        return written
    is_sd = column.endswith("_sd")
    core = column[:-3] if is_sd else column
    for suffix in sorted(UNITS, key=len, reverse=True):
        if core.endswith(suffix):
            return _known(path, column, core[: -len(suffix)], suffix), suffix, is_sd
    raise IdentifyInputError(f"{path}: column {column!r}: no known unit suffix; allowed: "
                             + ", ".join(s[1:] for s in UNITS) + "; or the unit in brackets, e.g. 'spin (rpm)'")


def _known(path: str, column: str, name: str, suffix: str) -> str:
    name = NAME_WORDS.get(name, name)
    if name not in COLUMNS:
        raise IdentifyInputError(f"{path}: column {column!r}: unknown quantity {name!r}; known: " + ", ".join(COLUMNS))
    if COLUMNS[name] != UNITS[suffix][0]:
        raise IdentifyInputError(f"{path}: column {column!r}: {name} is a {COLUMNS[name]}, "
                                 f"but {suffix[1:]} is a unit of {UNITS[suffix][0]}")
    return name


_WRITTEN = re.compile(r"^(?P<name>[^(\[]*?)\s*[(\[](?P<unit>[^)\]]*)[)\]]\s*(\.\d+)?$")


def _written(path: str, column: str, left: tuple[str, str, bool] | None) -> tuple[str, str, bool] | None:
    """A header as a spreadsheet writes it (``Spin (rpm)``, ``t / s``, ``t in s``, ``± [rpm]``), or None for another
    form."""
    match = _WRITTEN.match(column)
    if match is not None:
        name, unit = match["name"], match["unit"]
    elif " in " in column and _unit_key(column.rpartition(" in ")[2]) in UNIT_WORDS:  # DIN's 't in s'
        name, _, unit = column.rpartition(" in ")
    elif "/" in column and not column.endswith("_sd"):
        name, _, unit = column.partition(" / ") if " / " in column else column.partition("/")
    else:
        return None
    key = _unit_key(unit)
    if key not in UNIT_WORDS:
        raise IdentifyInputError(f"{path}: column {column!r}: unknown unit {unit.strip()!r}; known: "
                                 + ", ".join(UNIT_WORDS))
    suffix = UNIT_WORDS[key]
    words = re.sub(r"[\s-]+", "_", name.strip().lower())
    for mark in SD_WORDS:
        if words == mark:
            if left is None or left[2]:
                raise IdentifyInputError(f"{path}: column {column!r}: a standard deviation needs its value's column "
                                         "to its left")
            return _known(path, column, left[0], suffix), suffix, True
        tail = ("_" + mark) if mark.isalpha() else mark  # 'spin_sd', 'spin±'
        if words.endswith(tail) and len(words) > len(tail):
            return _known(path, column, words[: -len(tail)].rstrip("_"), suffix), suffix, True
    return _known(path, column, words, suffix), suffix, False


def _unit_key(unit: str) -> str:
    """A unit as written (``m²``, ``kg * m^2``, ``S``), in :data:`UNIT_WORDS`' spelling."""
    return re.sub(r"[\s*·]", "", unit.lower()).replace("²", "2").replace("^2", "2")


def _below_title(frame: pd.DataFrame, lines: np.ndarray) -> tuple[pd.DataFrame, np.ndarray]:
    """A title read as the header (its first cell alone filled: ``Spin-down of gyro B,,`` as Excel writes a title
    row): the first row under it that fills two cells or more, none of them a number, is the header."""
    if len(frame.columns) < 2 or not all(c.startswith("Unnamed: ") for c in frame.columns[1:]):
        return frame, lines
    cells = frame.apply(lambda c: c.map(lambda v: "" if pd.isna(v) else str(v).strip()))
    rows = np.flatnonzero((cells != "").sum(axis=1).to_numpy() >= 2)
    if len(rows) == 0:
        return frame, lines
    k = int(rows[0])
    filled = cells.iloc[k][cells.iloc[k] != ""]
    if pd.to_numeric(filled, errors="coerce").notna().any():  # values under a header with a column unnamed
        return frame, lines
    out = frame.iloc[k + 1:].copy()
    out.columns = [v if v else f"Unnamed: {i}" for i, v in enumerate(cells.iloc[k])]
    return out.reset_index(drop=True), lines[k + 1:]


def _units_row(frame: pd.DataFrame, lines: np.ndarray) -> tuple[pd.DataFrame, np.ndarray]:
    """A row of units under the header (``Time, Spin`` then ``s, rpm``, as data loggers' and many spreadsheets'
    exports write them) taken into the header (``Time (s)``), where every filled cell of the first row is a known
    unit (bracketed or not); a column whose header already states a unit keeps it."""
    if len(frame) == 0:
        return frame, lines
    cells = {c: str(v).strip() for c, v in frame.iloc[0].items() if not pd.isna(v) and str(v).strip()}
    units = {c: v[1:-1] if v[:1] in "([" and v[-1:] in ")]" else v for c, v in cells.items()}
    if not units or any(_unit_key(u) not in UNIT_WORDS for u in units.values()):
        return frame, lines
    named = {c: f"{c} ({u})" for c, u in units.items() if _WRITTEN.match(c) is None and "/" not in c}
    return frame.iloc[1:].rename(columns=named).reset_index(drop=True), lines[1:]


#: the columns that tell a table's kind when neither a ``kind`` column nor the file name does
KIND_SIGNS = {"nutation": ("nutation_frequency", "nutation_period"),
              "precession": ("precession_period", "precession_rate"), "spin_down": ("t",)}


def _kind(label: str, kind_name: str, frame: pd.DataFrame, names: set[str]) -> str:
    """The table's kind: its ``kind`` column, else the kind its file name contains, else the only kind whose
    measured quantity (:data:`KIND_SIGNS`) is among its columns ``names``."""
    if "kind" in frame.columns:
        kinds = set(frame["kind"].astype(str).str.strip())
        if len(kinds) != 1 or not kinds <= set(KINDS):
            raise IdentifyInputError(f"{label}: column 'kind' must hold one of {', '.join(KINDS)} in every row; "
                                     f"found {sorted(kinds)}")
        return kinds.pop()
    found = [k for k in KINDS if k in kind_name.lower().replace("-", "_").replace(" ", "_")]
    if len(found) != 1:
        found = [k for k, signs in KIND_SIGNS.items() if names & set(signs)]
    if len(found) != 1:
        raise IdentifyInputError(f"{label}: say what the table holds: a 'kind' column, or a file name containing "
                                 f"one of {', '.join(KINDS)}" + (f" (its columns fit {' and '.join(found)})"
                                                                 if found else ""))
    return found[0]


#: a cell holding a value and its standard deviation (``1200 ± 20``, ``12.5 +/- 0.3``)
_PLUS_MINUS = re.compile(r"^\s*(?P<value>[^±]+?)\s*(?:±|\+/-|\+-)\s*(?P<sd>[^±]+?)\s*$")
#: a stopwatch's reading: ``m:ss`` or ``h:mm:ss``, seconds with decimals
_CLOCK = re.compile(r"^\s*(?:(?P<h>\d+):)?(?P<m>\d+):(?P<s>[0-5]?\d(?:\.\d*)?)\s*$")


def _clock_header(column: str, cells: pd.Series) -> tuple[str, str, bool] | None:
    """A time column headed by its name alone (``time``, ``t``) whose cells are stopwatch readings (``1:05.3``):
    ``(name, '_s', False)``; None for any other column."""
    words = NAME_WORDS.get(w := re.sub(r"[\s-]+", "_", column.strip().lower()), w)
    text = cells.dropna().astype(str).str.strip()
    text = text[text != ""]
    if COLUMNS.get(words) != "time" or text.empty or not text.map(lambda v: bool(_CLOCK.match(v))).all():
        return None
    return words, "_s", False


def _numbers(label: str, frame: pd.DataFrame, column: str, name: str, suffix: str, lines: np.ndarray,
             row_word: str) -> tuple[np.ndarray, np.ndarray | None]:
    """A column's values in SI (NaN where a cell holds no number), and the standard deviations written after them
    in its cells (``1200 ± 20``; None when no cell has one; 0 where a cell gives none).  A time's cells may be
    stopwatch readings (``m:ss``, ``h:mm:ss``: seconds whatever the header's unit)."""
    factor = UNITS[suffix][1]
    cells = frame[column]
    dated = np.flatnonzero(cells.map(lambda v: isinstance(v, (datetime.time, datetime.date, datetime.timedelta))))
    if len(dated):  # a spreadsheet reads '1:05' as 1 h 5 min, a stopwatch means 1 min 5 s
        raise IdentifyInputError(f"{label}, {row_word} {lines[dated[0]]}, column {column!r}: {_cell(frame, column, dated[0])}"
                                 " is a time of day or a date (a spreadsheet reads '1:05' as 1 h 5 min): write seconds, "
                                 "or the stopwatch's reading as text ('1:05' is then 1 min 5 s)")
    if pd.api.types.is_numeric_dtype(cells):
        return cells.to_numpy(float) * factor, None
    text = cells.astype(str).str.strip().where(cells.notna(), "")
    parts = text.str.extract(_PLUS_MINUS)
    signed = parts["value"].notna().to_numpy()
    value_text = parts["value"].where(signed, text)
    values = pd.to_numeric(value_text, errors="coerce").to_numpy(float) * factor
    clock = value_text.str.extract(_CLOCK)
    timed = clock["m"].notna().to_numpy()
    if timed.any():
        if COLUMNS.get(name) != "time":
            row = int(np.flatnonzero(timed)[0])
            raise IdentifyInputError(f"{label}, {row_word} {lines[row]}, column {column!r}: {_cell(frame, column, row)} "
                                     f"is a clock reading, but {name} is not a time")
        seconds = (clock["h"].astype(float).fillna(0.0) * 3600 + clock["m"].astype(float) * 60
                   + clock["s"].astype(float)).to_numpy()
        values = np.where(timed, seconds, values)
    if not signed.any():
        return values, None
    given = pd.to_numeric(parts["sd"], errors="coerce").to_numpy(float) * factor
    bad = np.flatnonzero(signed & ~np.isfinite(given))
    if len(bad):
        raise IdentifyInputError(f"{label}, {row_word} {lines[bad[0]]}, column {column!r}: "
                                 f"{_cell(frame, column, bad[0])}: the standard deviation after '±' is not a number")
    return values, np.where(signed, given, 0.0)


def _check_sd(label: str, column: str, sd: np.ndarray, lines: np.ndarray, row_word: str) -> None:
    neg = np.flatnonzero(sd < 0)
    if len(neg):
        raise IdentifyInputError(f"{label}, {row_word} {lines[neg[0]]}, column {column!r}: a standard deviation must "
                                 f"be >= 0; got {sd[neg[0]]!r}")


def _check_required(path: str, kind: str, names: set[str]) -> None:
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


#: columns of notes, left out (a header of one of these words, any case)
NOTE_COLUMNS = ("note", "notes", "comment", "comments", "remark", "remarks")


def _cell(frame: pd.DataFrame, column: str, row: int) -> str:
    """A cell as its file wrote it, quoted (for messages); one pandas read as missing may have held ``n/a`` or
    ``NA`` as well as nothing."""
    value = frame[column].iloc[row]
    if pd.isna(value):
        return "a cell without a reading (empty, n/a, NA or nan)"
    return "an empty cell" if str(value).strip() == "" else repr(str(value))


def _text_lines(path: Path) -> list[tuple[int, str]]:
    """The file's lines that are neither blank nor a ``#`` comment, with their numbers (from 1)."""
    with open(path, encoding=_io.table_encoding(path), errors="replace") as fh:
        return [(n, line) for n, line in enumerate(fh, start=1) if line.strip() and not line.lstrip().startswith("#")]


def _title_lines(lines: list[tuple[int, str]]) -> list[int]:
    """The numbers (from 1) of title lines above the header (``Spin-down of gyro B``): lines with no separator
    before the first that has one (a table has two columns at least, so a header has one)."""
    titles = []
    for number, line in lines:
        if any(sep in line for sep in ",;\t"):
            return titles
        titles.append(number)
    return []


def _data_lines(lines: list[tuple[int, str]], titles: list[int]) -> np.ndarray:
    """The file's line number of each row pandas reads (the lines after the title and the header)."""
    return np.array([n for n, _ in lines if n not in titles][1:], int)


def _cleaned(label: str, frame: pd.DataFrame, lines: np.ndarray, row_word: str) -> tuple[pd.DataFrame, np.ndarray]:
    """The table without what a spreadsheet adds around the data (columns with neither header nor values, rows
    with every cell empty: cells once formatted, then cleared) and without notes (:data:`NOTE_COLUMNS`), with
    each row's line number in the file.  IdentifyInputError for values in a column without a header."""
    empty = frame.apply(lambda c: c.isna() | (c.astype(str).str.strip() == ""))
    for i, column in enumerate(frame.columns):
        if column.startswith("Unnamed: ") and not empty[column].all():
            row = int(np.flatnonzero(~empty[column].to_numpy())[0])
            raise IdentifyInputError(f"{label}, {row_word} {lines[row]}: column {i + 1} holds {_cell(frame, column, row)} "
                                     "but has no header (give it one, e.g. 'spin (rpm)', or clear it)")
    keep = [c for c in frame.columns if not c.startswith("Unnamed: ") and c.lower() not in NOTE_COLUMNS]
    rows = ~empty[keep].all(axis=1).to_numpy() if keep else np.zeros(len(frame), bool)
    return frame.loc[rows, keep].reset_index(drop=True), lines[rows]


def read_table(path: str | Path) -> Table:
    """Read one lab table (a CSV file) into SI units (see the module docstring)."""
    path = Path(path)
    try:
        text = _text_lines(path)
        titles = _title_lines(text)
        frame = _io.read_table_csv(path, skipinitialspace=True, comment="#", skiprows=[n - 1 for n in titles])
    except FileNotFoundError:
        raise IdentifyInputError(f"{path}: no such file") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise IdentifyInputError(f"{path}: not a readable CSV table ({exc})") from None
    lines = _data_lines(text, titles)
    if len(lines) != len(frame):  # a cell quoted across lines: rows counted from the header
        lines = np.arange(len(frame)) + 2
    return _table(str(path), path.name, frame, lines, "line")


def read_tables(path: str | Path) -> list[Table]:
    """Every lab table in a file: a CSV file's one, or each sheet of an Excel workbook (``.xlsx``, ``.xlsm``) that
    holds any cell, its kind from a ``kind`` column, the sheet's name, the file's name or its columns."""
    path = Path(path)
    if path.suffix.lower() not in WORKBOOK_SUFFIXES:
        return [read_table(path)]
    return [_table(f"{path}, sheet {sheet!r}", f"{sheet} {path.name}", frame, rows, "row")
            for sheet, frame, rows in _sheets(path)]


#: file name endings read as Excel workbooks
WORKBOOK_SUFFIXES = (".xlsx", ".xlsm")


def _sheets(path: Path) -> list[tuple[str, pd.DataFrame, np.ndarray]]:
    """Each sheet of a workbook that holds a cell: its name, its table (the first row with a cell is the header;
    rows whose first cell is a ``#`` comment left out) and each row's number in the sheet."""
    try:
        book = pd.read_excel(path, sheet_name=None, header=None, dtype=object, engine="openpyxl")
    except FileNotFoundError:
        raise IdentifyInputError(f"{path}: no such file") from None
    except ImportError:
        raise IdentifyInputError(f"{path}: reading an Excel workbook needs openpyxl (pip install openpyxl); or save "
                                 "each sheet as CSV") from None
    except Exception as exc:  # noqa: BLE001 - openpyxl raises many kinds for a file that is not a workbook
        raise IdentifyInputError(f"{path}: not a readable Excel workbook ({type(exc).__name__}: {exc})") from None
    out = []
    for sheet, raw in book.items():
        text = raw.apply(lambda c: c.map(lambda v: "" if pd.isna(v) else str(v).strip()))
        used = ((text != "").any(axis=1) & ~text.iloc[:, 0].str.startswith("#")).to_numpy() if raw.size else []
        rows = np.flatnonzero(used)
        if len(rows) == 0:
            continue
        header = [str(v).strip() if v != "" else f"Unnamed: {i}" for i, v in enumerate(text.iloc[rows[0]])]
        frame = raw.iloc[rows[1:]].copy()
        frame.columns = header
        out.append((str(sheet), frame.reset_index(drop=True), rows[1:] + 1))
    if not out:
        raise IdentifyInputError(f"{path}: no sheet holds a table")
    return out


def _table(label: str, kind_name: str, frame: pd.DataFrame, lines: np.ndarray, row_word: str) -> Table:
    """One table in SI from its cells as read (``label`` names it in messages, ``kind_name`` is searched for its
    kind, ``lines`` are its rows' numbers in the file, called ``row_word``)."""
    frame.columns = [str(c).strip() for c in frame.columns]
    frame, lines = _cleaned(label, *_below_title(frame, lines), row_word)
    frame, lines = _units_row(frame, lines)
    values: dict[str, np.ndarray] = {}
    sd: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    parsed: dict[str, tuple[str, str, bool]] = {}
    left = None
    inline: dict[str, tuple[str, np.ndarray]] = {}
    for column in frame.columns:
        if column != "kind":
            parsed[column] = left = _clock_header(column, frame[column]) or _split_unit(label, column, left)
    kind = _kind(label, kind_name, frame, {name for name, _, _ in parsed.values()})
    for column, (name, suffix, is_sd) in parsed.items():
        raw, given = _numbers(label, frame, column, name, suffix, lines, row_word)
        if given is not None:
            inline[name] = (column, given)
        bad = np.flatnonzero(~np.isfinite(raw))
        if len(bad) and not is_sd:
            raise IdentifyInputError(f"{label}, {row_word} {lines[bad[0]]}, column {column!r}: {_cell(frame, column, bad[0])} is "
                                     "not a finite number")
        if is_sd:
            if not any(n == name and not sd_ for n, _, sd_ in parsed.values()):
                raise IdentifyInputError(f"{label}: column {column!r} is a standard deviation of {name}, and no "
                                         f"column gives {name} itself")
            if name in sd:
                raise IdentifyInputError(f"{label}: column {column!r}: {name}'s standard deviation is given twice")
            raw = np.where(np.isfinite(raw), raw, 0.0)
            _check_sd(label, column, raw, lines, row_word)
            sd[name] = raw
        else:
            if name in values:
                raise IdentifyInputError(f"{label}: {name} is given twice (column {column!r} and {units[name]!r})")
            values[name], units[name] = raw, column
    for name, (column, given) in inline.items():  # 'value ± sd' in the cells
        if name in sd:
            raise IdentifyInputError(f"{label}: column {column!r}: {name}'s standard deviation is given twice (after "
                                     "its values and in a column of its own)")
        _check_sd(label, column, given, lines, row_word)
        sd[name] = given
    _check_required(label, kind, set(values))
    for name in POSITIVE:
        if name in values:
            neg = np.flatnonzero(values[name] <= 0)
            if len(neg):
                raise IdentifyInputError(f"{label}, {row_word} {lines[neg[0]]}, column {units[name]!r}: must be > 0; got "
                                         f"{_cell(frame, units[name], neg[0])}")
    for name, (lo, hi, what) in RANGES.items():
        if name in values:
            off = np.flatnonzero(~((values[name] >= lo) & (values[name] <= hi)))
            if len(off):
                raise IdentifyInputError(f"{label}, {row_word} {lines[off[0]]}, column {units[name]!r}: "
                                         f"{_cell(frame, units[name], off[0])} is outside {what}")
    if len(frame) == 0:
        raise IdentifyInputError(f"{label}: no rows")
    if kind == "spin_down" and len(frame) >= 3 and np.ptp(values["t"]) <= 0:
        raise IdentifyInputError(f"{label}, column {units['t']!r}: every row has the same time: a spin-down needs "
                                 "readings at different times")
    if kind == "spin_down" and len(frame) < 3:
        raise IdentifyInputError(f"{label}: a spin-down table has {len(frame)} row(s); it needs at least 3 (its "
                                 "initial spin, the viscous rate and the friction are fitted)")
    for name in values:
        sd.setdefault(name, np.zeros(len(frame)))
    return Table(label, kind, values, sd, lines)
