"""Parameters held fixed or given a Gaussian prior (``gyrorig fit --fix NAME=VALUE --prior NAME=VALUE+-SD``).

A fixed parameter keeps its value: its Jacobian column is zero, so the solver never moves it and its
standard error is 0.  A prior adds one whitened residual ``(p - mean) / sd``: an independent
measurement of that parameter, combined with the record by least squares.  Both act on the fit
model's parameters by name (``fit.json``'s ``parameter_covariance.names``: e.g.
``precession_rate_rad_s``, ``nutation_frequency_rad_s``, ``nutation_decay_rate_per_s``,
``axis_tilt_rad``); a constraint on a parameter the chosen model lacks is reported as unused.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from .spec import ModelSpec
from .terms import MAX_HARMONICS, OPTIONAL_TERMS

__all__ = ["Constraints", "constrainable_names", "parse_fix", "parse_prior"]

_SEGMENT_OFFSET = re.compile(r"azimuth_offset_\d+_rad")


def constrainable_names() -> list[str]:
    """Every parameter a fit model can have (the azimuth offsets as ``azimuth_offset_<k>_rad``), camera modes excepted."""
    full = ModelSpec(fit_axis=True, damped=True, harmonics=MAX_HARMONICS, segments=1,
                     **{flag: True for flag in OPTIONAL_TERMS})
    return full.names()


def _check_name(name: str, option: str) -> str:
    name = name.strip()
    if name in constrainable_names() or _SEGMENT_OFFSET.fullmatch(name):
        return name
    raise ValueError(f"{option}: {name!r} is not a fit parameter; allowed: {', '.join(constrainable_names())} "
                     "(and azimuth_offset_<k>_rad)")


def _number(text: str, option: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"{option}: {what} {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{option}: {what} must be finite; got {text!r}")
    return v


def parse_fix(text: str) -> tuple[str, float]:
    """``"NAME=VALUE"`` -> ``(name, value)``; a clear error naming the option otherwise."""
    name, sep, value = text.partition("=")
    if not sep:
        raise ValueError(f"--fix: expected NAME=VALUE; got {text!r}")
    return _check_name(name, "--fix"), _number(value.strip(), "--fix", "value")


def parse_prior(text: str) -> tuple[str, float, float]:
    """``"NAME=VALUE+-SD"`` (or ``±``) -> ``(name, mean, sd)``, sd > 0."""
    name, sep, rest = text.partition("=")
    parts = re.split(r"\+-|±|\+/-", rest)
    if not sep or len(parts) != 2:
        raise ValueError(f"--prior: expected NAME=VALUE+-SD; got {text!r}")
    mean = _number(parts[0].strip(), "--prior", "value")
    sd = _number(parts[1].strip(), "--prior", "SD")
    if sd <= 0:
        raise ValueError(f"--prior: SD must be > 0; got {parts[1].strip()!r} (use --fix to hold a parameter)")
    return _check_name(name, "--prior"), mean, sd


@dataclass(frozen=True)
class Constraints:
    """Fixed parameters ``(name, value)`` and Gaussian priors ``(name, mean, sd)`` of a fit."""

    fixed: tuple[tuple[str, float], ...] = ()
    priors: tuple[tuple[str, float, float], ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "fixed", tuple((str(n), float(v)) for n, v in self.fixed))
        object.__setattr__(self, "priors", tuple((str(n), float(m), float(s)) for n, m, s in self.priors))
        for n, v in self.fixed:
            _check_name(n, "fixed")
            if not math.isfinite(v):
                raise ValueError(f"fixed {n}: value must be finite; got {v!r}")
        for n, m, s in self.priors:
            _check_name(n, "prior")
            if not (math.isfinite(m) and math.isfinite(s) and s > 0):
                raise ValueError(f"prior {n}: mean must be finite and sd > 0; got {m!r} +- {s!r}")
        names = [n for n, _ in self.fixed] + [n for n, _, _ in self.priors]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"a parameter is fixed or given a prior more than once: {', '.join(dup)}")

    @classmethod
    def from_options(cls, fix: list[str] | None = None, prior: list[str] | None = None) -> "Constraints":
        """From the command line's ``--fix`` and ``--prior`` strings."""
        return cls(fixed=tuple(parse_fix(s) for s in fix or ()), priors=tuple(parse_prior(s) for s in prior or ()))

    def __bool__(self) -> bool:
        return bool(self.fixed or self.priors)

    def unused(self, spec: ModelSpec) -> list[str]:
        """Constrained names the model ``spec`` does not have."""
        have = set(spec.names())
        return [n for n, *_ in self.fixed + self.priors if n not in have]

    def as_dict(self) -> dict:
        return {"fixed": dict(self.fixed), "priors": {n: {"mean": m, "sd": s} for n, m, s in self.priors}}
