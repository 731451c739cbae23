"""Validation of protocol tables: every bad value gets a :class:`ProtocolError` naming the key and the allowed range.

Used by :mod:`gyrorig.protocols`, :mod:`gyrorig.camera` and :mod:`gyrorig.markers`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["ProtocolError", "where", "finite", "number", "vector3", "boolean", "check_keys", "angle"]


class ProtocolError(ValueError):
    """A protocol file or table is invalid; the message names the key and the allowed range."""


def where(section: str, key: str) -> str:
    return f"{section}.{key}" if section else key


def finite(section: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(f"{where(section, key)} = {value!r}: expected a number")
    value = float(value)
    if not math.isfinite(value):
        raise ProtocolError(f"{where(section, key)} = {value!r}: must be finite (not NaN or inf)")
    return value


def number(
    section: str,
    key: str,
    value: Any,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    hi_open: bool = False,
) -> float:
    v = finite(section, key, value)
    bad_lo = lo is not None and (v <= lo if lo_open else v < lo)
    bad_hi = hi is not None and (v >= hi if hi_open else v > hi)
    if bad_lo or bad_hi:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        lo_s = "-inf" if lo is None else f"{lo:g}"
        hi_s = "inf" if hi is None else f"{hi:g}"
        raise ProtocolError(
            f"{where(section, key)} = {v!r} is out of range; allowed {left}{lo_s}, {hi_s}{right}"
        )
    return v


def vector3(section: str, key: str, value: Any) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ProtocolError(f"{where(section, key)} = {value!r}: expected a list of 3 numbers")
    x, y, z = (finite(section, f"{key}[{i}]", v) for i, v in enumerate(value))
    return (x, y, z)


def boolean(section: str, key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ProtocolError(f"{where(section, key)} = {value!r}: expected true or false")
    return value


def check_keys(section: str, table: Mapping[str, Any], required: set[str], optional: set[str]) -> None:
    if not isinstance(table, Mapping):
        raise ProtocolError(f"[{section}] must be a table, found {table!r}")
    unknown = sorted(set(table) - required - optional)
    if unknown:
        allowed = ", ".join(sorted(required | optional))
        raise ProtocolError(f"[{section}] has unknown key(s) {', '.join(unknown)}; allowed keys: {allowed}")
    missing = sorted(required - set(table))
    if missing:
        raise ProtocolError(f"[{section}] is missing required key(s) {', '.join(missing)}")


def angle(
    section: str, table: Mapping[str, Any], stem: str, *, lo: float, hi: float, required: bool, default: float = 0.0
) -> float:
    """Read ``stem_rad`` or ``stem_deg`` (exactly one); range given in radians."""
    rad_key, deg_key = f"{stem}_rad", f"{stem}_deg"
    if rad_key in table and deg_key in table:
        raise ProtocolError(f"[{section}] gives both {rad_key} and {deg_key}; give one")
    if rad_key in table:
        return number(section, rad_key, table[rad_key], lo=lo, hi=hi)
    if deg_key in table:
        v = number(section, deg_key, table[deg_key], lo=math.degrees(lo), hi=math.degrees(hi))
        # exact endpoints survive the conversion (180 deg -> pi)
        return min(max(math.radians(v), lo), hi)
    if required:
        raise ProtocolError(f"[{section}] is missing required key {rad_key} (or {deg_key})")
    return default


# --------------------------------------------------------------------------------------
# records
