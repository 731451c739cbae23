"""Which terms a fit model has (:class:`ModelSpec`), and optional terms fixed in advance (:class:`FitTerms`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from .terms import MAX_HARMONICS, OPTIONAL, OPTIONAL_TERMS, TERMS

__all__ = ["ModelSpec", "FitTerms"]


@dataclass(frozen=True)
class ModelSpec:
    """Which terms the fit model has (see :mod:`gyrorig.fit.terms` for each)."""

    fit_axis: bool = False
    #: the axis is fitted on a scene whose vertical is known (no accelerating pivot): the cone's axis leaning from the
    #: camera's vertical, a table not level or a pose's vertical off (:func:`gyrorig.fit.selection.fit_model`)
    lean: bool = False
    damped: bool = False
    #: (damped) the rotor's spin decays (a drag on it no motor holds): the precession rate and the nutation frequency
    #: change exponentially in time, each at its own rate (:func:`~gyrorig.fit.phases.rate_phase`), not linearly
    spin_decay: bool = False
    harmonics: int = 0
    segments: int = 1
    persistent: bool = False
    #: tau at which a damped nutation's envelope is 1 (the first frame): amplitudes are quoted there
    nutation_origin_s: float = 0.0
    transient: bool = False
    #: the transient decays at least this fast (1/s): ten e-folds within the record, so that it
    #: cannot stand in for the slow terms
    transient_min_rate_per_s: float = 0.0
    #: ... and at most this fast (a few e-folds per frame): the rate is bounded smoothly between the two
    transient_max_rate_per_s: float = 1e3
    sidebands: bool = False
    precession_second: bool = False
    third_order: bool = False
    shape_drift: bool = False
    #: a tip marker off the stem's axis (:class:`~gyrorig.fit.terms.TipOffset`); offered only on a gyrostat
    tip_offset: bool = False
    #: the scene's top is a gyrostat (its markers on a frame that does not spin with the rotor), whose frame spins at
    #: ``frame_spin_rad_s`` about the axis [rad/s]
    gyrostat: bool = False
    frame_spin_rad_s: float = 0.0
    #: nuisance parameters for the camera model's uncertainty (one per mode, unit prior)
    camera_modes: int = 0
    #: the record has a lossy codec's bi-predicted pictures beside others: their fast motion's shrink is fitted
    #: (:class:`~gyrorig.fit.terms.BFrameShrink`)
    b_frames: bool = False
    #: the frames' times lack their rows' delay under a rolling shutter: its readout time is fitted
    #: (:class:`~gyrorig.fit.terms.RollingShutter`)
    rolling_shutter: bool = False

    @property
    def axis_label(self) -> str:
        """How the cone's axis is modelled, for the report: ``vertical``, ``fitted`` or ``leaning (fitted)``."""
        return "leaning (fitted)" if self.lean else "fitted" if self.fit_axis else "vertical"

    def names(self) -> list[str]:
        """The model's parameter names, in the order of its parameter vector."""
        return [n for term in TERMS if term.present(self) for n in term.names(self)]

    def summary(self) -> dict:
        """The model's terms for ``fit.json``."""
        out = {"fit_axis": self.fit_axis, "lean": self.lean, "damped": self.damped, "spin_decay": self.spin_decay,
               "nutation_harmonics": self.harmonics,
               "azimuth_segments": self.segments}
        out.update({term.summary_key: bool(getattr(self, term.flag)) for term in OPTIONAL.values()})
        out["camera_modes"] = self.camera_modes
        out["b_frame_shrink"] = self.b_frames and self.harmonics > 0
        out["readout_time"] = self.rolling_shutter
        return out


@dataclass(frozen=True)
class FitTerms:
    """The optional terms of a fit model, fixed before the data are fitted.

    :func:`gyrorig.fit.plan_terms` chooses them on noiseless simulated angles of the scene, so
    that every run of an experiment is fitted with the same model: a model chosen afresh by
    each run's own chi-square tests switches terms on and off between runs, and the runs that
    gain a term get wider error bars than those that do not.
    """

    harmonics: int = 0
    transient: bool = False
    precession_second: bool = False
    sidebands: bool = False
    persistent: bool = False
    third_order: bool = False
    shape_drift: bool = False
    tip_offset: bool = False
    #: where the terms come from (for the report)
    source: str = ""
    #: for each optional term the plan left out, the chi-square change it made on the plan's noiseless
    #: record (its expected non-centrality; ``harmonics``: the next harmonic): a record adds a left-out
    #: term only when its chi-square gain is improbable for that non-centrality
    left_out_noncentrality: tuple[tuple[str, float], ...] = ()

    def __post_init__(self):
        # one order, so that equal terms compare equal
        object.__setattr__(self, "left_out_noncentrality",
                           tuple(sorted((str(k), float(v)) for k, v in self.left_out_noncentrality)))

    @classmethod
    def of(cls, spec: ModelSpec, source: str = "", left_out_noncentrality: dict[str, float] | None = None
           ) -> "FitTerms":
        """The optional terms of a model."""
        return cls(harmonics=spec.harmonics, **{f: bool(getattr(spec, f)) for f in OPTIONAL_TERMS}, source=source,
                   left_out_noncentrality=tuple((left_out_noncentrality or {}).items()))

    def has(self, flag: str, k: int = 0) -> bool:
        """Whether the optional term ``flag`` (or nutation harmonic ``k``, flag ``"harmonics"``) is in these terms."""
        return k <= self.harmonics if flag == "harmonics" else bool(getattr(self, flag))

    def noncentrality(self, flag: str) -> float:
        """The plan's expected chi-square change for a term it left out (0 when it did not measure one)."""
        return dict(self.left_out_noncentrality).get(flag, 0.0)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["left_out_noncentrality"] = dict(self.left_out_noncentrality)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "FitTerms":
        """From :meth:`as_dict` (or a plan.json's ``fit_terms``); unknown keys are refused by name."""
        allowed = {f.name for f in fields(cls)}
        bad = sorted(set(d) - allowed)
        if bad:
            raise ValueError(f"fit terms: unknown key(s) {', '.join(bad)}; allowed: {', '.join(sorted(allowed))}")
        h = d.get("harmonics", 0)
        if not isinstance(h, int) or isinstance(h, bool) or not 0 <= h <= MAX_HARMONICS:
            raise ValueError(f"fit terms: harmonics must be an integer in [0, {MAX_HARMONICS}]; got {h!r}")
        for k in OPTIONAL_TERMS:
            if k in d and not isinstance(d[k], bool):
                raise ValueError(f"fit terms: {k} must be true or false; got {d[k]!r}")
        d = dict(d)
        lam = d.pop("left_out_noncentrality", {}) or {}
        if not isinstance(lam, dict):
            raise ValueError(f"fit terms: left_out_noncentrality must be an object {{term: chi-square change}}; got {lam!r}")
        for k, v in lam.items():
            if k not in ("harmonics",) + OPTIONAL_TERMS:
                raise ValueError(f"fit terms: left_out_noncentrality has unknown term {k!r}; allowed: harmonics, "
                                 + ", ".join(OPTIONAL_TERMS))
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"fit terms: left_out_noncentrality.{k} must be a number >= 0; got {v!r}")
        return cls(**d, left_out_noncentrality=tuple(lam.items()))

    def describe(self) -> str:
        parts = [f"{self.harmonics} nutation harmonic(s)" if self.harmonics else "no nutation"]
        parts += [term.label for flag, term in OPTIONAL.items() if getattr(self, flag)]
        return ", ".join(parts)
