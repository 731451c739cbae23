"""What each measurement says about the rig: one :class:`Observation` per table row or fit.json quantity.

Each observation has its measured value ``y`` (SI) with its standard deviation, the conditions it
was taken under (``x``: spin, added mass, lever arm, tilt, time, each with a standard deviation
that enters as effective variance), and two models of ``y`` given the rig: the exact one and the
fast-top formula (for showing its bias).

The models, with ``M, h, I, Io`` the rig's mass, centre-of-mass distance and inertias, an added
mass ``m`` at ``l`` along the axis (``M' = M + m``, ``M' h' = M h + m l``, ``I' = I + m l^2``) and
``Omega`` the spin ``psi'`` (as the protocols' ``launch.spin_rate_rad_s``):

* precession period: ``2 pi / phi'`` with ``phi'`` the slow root of the exact steady precession at the
  tilt (``Mgh' = phi' (Io omega_o - I' phi' cos theta)``, ``omega_o = Omega + phi' cos theta``;
  horizontal when no tilt is given); fast top: ``2 pi Io Omega / (M' g h')``;
* nutation frequency: the elliptic solution's, for a release from rest at the tilt (the protocol's
  launch tilt when none is given), or for a kicked top swinging between measured extremes (``tilt_min`` and
  ``tilt_max`` columns; its spin is then ``omega_3``, the rotor's rate about its axis: :func:`launch_between`);
  for a balanced rig (``M h = 0``: no torque, the nutation set off by a kick)
  the rate at which the axis circles the angular momentum, ``L / I = Io Omega / (I cos theta_c)`` with
  ``theta_c`` the cone angle (a ``cone_angle`` column; 0 when not given); fast top: ``Io Omega / I'``;
* a video's fit.json: its mean precession rate and nutation frequency from the elliptic solution of
  its protocol's launch; fast top: ``Mgh / (Io Omega)`` and ``Io Omega / I``;
* spin-down: ``omega(t) = omega_0 exp(-k t) - f (1 - exp(-k t)) / k`` (``d omega / dt = -k omega - f``);
* a gyro in gimbals (the prior's ``[gimbal]``, :mod:`gyrorig.gimbals`): precession by the slow root of its steady
  precession at the tilt (horizontal when no tilt is given), nutation (balanced, at the tilt, horizontal when none
  is given) by ``Io Omega sin theta / sqrt(a(theta) I)`` with ``a`` the inertia about the vertical (an
  ``added_outer_inertia`` column adds to it: cylinders on the outer ring); no video.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..gimbals import gimbal_nutation_frequency, gimbal_precession_rate
from ..physics.exact import ExactSolutionError, exact_solution
from ..protocols import Launch, Pivot, Protocol, ProtocolError
from ..theory import exact_steady_precession_rates
from .tables import IdentifyInputError, Table

__all__ = ["Observation", "observations_from_table", "observations_from_fit", "rig_with", "FORMULAS",
           "spin_down_model", "launch_between"]

#: which formula serves each kind of observation
FORMULAS = {
    "precession": "exact steady precession at the finite tilt (slow root; Goldstein eq. 5.76)",
    "nutation": "exact elliptic solution of the heavy top released from rest at the tilt, or turning at the "
                "measured tilt extremes (a kick); a balanced rig's torque-free nutation L / I",
    "fit_precession": "exact elliptic solution's mean precession rate for the video's launch",
    "fit_nutation": "exact elliptic solution's nutation frequency for the video's launch",
    "spin_down": "d omega/dt = -k omega - f (viscous, plus constant friction when the data need it)",
}
#: the value a model returns where the rig admits no such motion (keeps the solver away)
_IMPOSSIBLE = 1e9


@dataclass(frozen=True)
class Observation:
    """One measured number and how the rig's parameters predict it."""

    kind: str
    source: str
    line: int
    y: float
    y_sd: float
    #: the conditions (SI) and their standard deviations
    x: dict[str, float]
    x_sd: dict[str, float] = field(default_factory=dict)
    #: ``model(params, x) -> y`` (exact) and the fast-top formula
    exact: Callable | None = None
    fast: Callable | None = None
    #: the parameter only this observation's table or video has (a spin-down's initial spin, a video's spin)
    table_key: str = ""
    #: that parameter's prior (mean, sd) where it has one (a video's spin, not measured directly)
    table_prior: tuple[float, float] | None = None
    #: parameters of the configuration this was measured in, with their priors: ``(name, mean, sd)``
    own_priors: tuple[tuple[str, float, float], ...] = ()

    def predict(self, params: dict, x: dict | None = None, fast: bool = False) -> float:
        f = self.fast if fast and self.fast is not None else self.exact
        return float(f(params, x if x is not None else self.x))

    def effective_sd(self, params: dict, fast: bool = False) -> float:
        """``sqrt(sd_y^2 + sum_j (d model / d x_j sd_j)^2)``: the conditions' errors carried into y."""
        var = self.y_sd ** 2
        for k, s in self.x_sd.items():
            if s > 0:
                xp, xm = dict(self.x), dict(self.x)
                xp[k] += 0.5 * s
                xm[k] -= 0.5 * s
                var += (self.predict(params, xp, fast) - self.predict(params, xm, fast)) ** 2
        return math.sqrt(var)


def rig_with(prior: Protocol, params: dict, added_mass_kg: float = 0.0, lever_arm_m: float = 0.0) -> Protocol:
    """The prior protocol with the rig's parameters (``rig.*`` names) and an added point mass on the axis;
    no damping and a fixed pivot.  Not checked for being a possible rigid body: the models are smooth
    through that bound, so the solver can cross it on its way (:func:`~gyrorig.identify.estimate.identify_parameters`
    checks the result)."""
    rig = replace(prior.rig, **{k.split(".", 1)[1]: v for k, v in params.items() if k.startswith("rig.")})
    gimbal = prior.gimbal
    if gimbal is not None:
        gimbal = replace(gimbal, **{k.split(".", 1)[1]: v for k, v in params.items() if k.startswith("gimbal.")})
    if added_mass_kg:
        mass = rig.mass_kg + added_mass_kg
        rig = replace(rig, mass_kg=mass, com_distance_m=(rig.mass_kg * rig.com_distance_m
                                                         + added_mass_kg * lever_arm_m) / mass,
                      inertia_transverse_kg_m2=rig.inertia_transverse_kg_m2 + added_mass_kg * lever_arm_m ** 2)
        if gimbal is not None and gimbal.cross_inertia_kg_m2 is not None:  # a point on the spin axis: both axes
            gimbal = replace(gimbal, cross_inertia_kg_m2=gimbal.cross_inertia_kg_m2 + added_mass_kg * lever_arm_m ** 2)
    return replace(prior, rig=rig, pivot=Pivot(), gimbal=gimbal)


def _mgh_inertias(prior: Protocol, params: dict, x: dict) -> tuple[float, float, float]:
    p = rig_with(prior, params, x.get("added_mass", 0.0), x.get("lever_arm", 0.0))
    return p.rig.mgh_N_m, p.rig.inertia_transverse_kg_m2, p.rig.inertia_axial_kg_m2


def _guard(f):
    def g(params, x):
        try:
            v = f(params, x)
        except (ProtocolError, ExactSolutionError, ValueError, ZeroDivisionError):
            return _IMPOSSIBLE
        return v if math.isfinite(v) else _IMPOSSIBLE
    return g


def _precession(prior: Protocol):
    def exact(params, x):
        mgh, i_t, i_o = _mgh_inertias(prior, params, x)
        slow, _ = exact_steady_precession_rates(x["spin"], x.get("tilt", math.pi / 2), inertia=i_t,
                                                inertia_axial=i_o, mgh=mgh)
        return 2 * math.pi / abs(slow)

    def fast(params, x):
        mgh, _, i_o = _mgh_inertias(prior, params, x)
        return 2 * math.pi * i_o * x["spin"] / mgh
    return _guard(exact), _guard(fast)


def _released(prior: Protocol, params: dict, x: dict, launch=None):
    p = rig_with(prior, params, x.get("added_mass", 0.0), x.get("lever_arm", 0.0))
    launch = launch or replace(p.launch, tilt_rad=x["tilt"], spin_rate_rad_s=x["spin"], tilt_rate_rad_s=0.0,
                               precession_rate_rad_s=0.0)
    return exact_solution(replace(p, launch=launch))


def _gimbal_precession(prior: Protocol):
    def exact(params, x):
        p = rig_with(prior, params, x.get("added_mass", 0.0), x.get("lever_arm", 0.0))
        return 2 * math.pi / abs(gimbal_precession_rate(p.rig, p.gimbal, x["spin"], x.get("tilt", math.pi / 2)))

    def fast(params, x):
        mgh, _, i_o = _mgh_inertias(prior, params, x)
        return 2 * math.pi * i_o * x["spin"] / mgh
    return _guard(exact), _guard(fast)


def _gimbal_nutation(prior: Protocol):
    def exact(params, x):
        p = rig_with(prior, params)
        gimbal = replace(p.gimbal, outer_inertia_kg_m2=p.gimbal.outer_inertia_kg_m2 + x.get("added_outer_inertia", 0.0))
        return gimbal_nutation_frequency(p.rig, gimbal, x["spin"], x["tilt"])

    def fast(params, x):
        _, i_t, i_o = _mgh_inertias(prior, params, x)
        return i_o * x["spin"] / i_t
    return _guard(exact), _guard(fast)


def launch_between(rig, spin_rad_s: float, tilt_min_rad: float, tilt_max_rad: float) -> Launch:
    """The launch of a heavy top spinning at ``omega_3 = spin_rad_s`` (the rotor's rate about its axis, a constant
    of the motion; a gyrostat's frame not turning about it) whose tilt swings between ``tilt_min_rad`` and
    ``tilt_max_rad``: at the smaller tilt, tilt rate 0, with the precession rate that makes the larger one the other
    turning point.  In ``u = cos theta``
    (Goldstein's ``u'^2 = (1 - u^2)(alpha - beta u) - (b - a u)^2``, ``a = Io omega_3 / I``) both ``u`` are roots,
    which fixes ``b`` by a quadratic: of its two roots (a wavy and a looping motion) the one whose precession at the
    top turning point is the slower is taken (the release from rest where the swing is a release's).  ValueError
    where no motion turns at both tilts."""
    i_t, i_o = rig.inertia_transverse_kg_m2, rig.inertia_axial_kg_m2
    u1, u2 = math.cos(tilt_min_rad), math.cos(tilt_max_rad)
    s1, s2 = 1.0 - u1 * u1, 1.0 - u2 * u2
    if not (s1 > 0 and s2 > 0 and u1 > u2):
        raise ValueError(f"tilts {tilt_min_rad!r} < {tilt_max_rad!r} strictly inside (0, pi) are needed")
    beta, a = 2.0 * rig.mgh_N_m / i_t, i_o * spin_rad_s / i_t
    # (b - a u1)^2 / s1 - (b - a u2)^2 / s2 = beta (u2 - u1): A b^2 + B b + C = 0
    qa, qb = 1.0 / s1 - 1.0 / s2, -2.0 * a * (u1 / s1 - u2 / s2)
    qc = a * a * (u1 * u1 / s1 - u2 * u2 / s2) - beta * (u2 - u1)
    if abs(qa) <= 1e-12 * abs(qb):
        roots = [-qc / qb]
    else:
        disc = qb * qb - 4.0 * qa * qc
        if disc < 0:
            raise ValueError("no motion of this top turns at these two tilts")
        roots = [(-qb + sgn * math.sqrt(disc)) / (2.0 * qa) for sgn in (1.0, -1.0)]
    phid = min(((b - a * u1) / s1 for b in roots), key=abs)
    # a gyrostat's frame does not turn about the axis (its axial rate psi_f' + phi' cos theta is 0)
    return Launch(tilt_rad=tilt_min_rad, azimuth_rad=0.0, tilt_rate_rad_s=0.0, precession_rate_rad_s=phid,
                  spin_rate_rad_s=spin_rad_s - phid * u1,
                  frame_spin_rate_rad_s=-phid * u1 if rig.is_gyrostat else 0.0)


def _nutation(prior: Protocol):
    def exact(params, x):
        mgh, i_t, i_o = _mgh_inertias(prior, params, x)
        if mgh == 0.0:  # balanced: no torque; a kick sets the axis circling the angular momentum at L / I
            return i_o * x["spin"] / (i_t * math.cos(x.get("cone_angle", 0.0)))
        if "tilt_min" in x:  # a kicked heavy top: the tilt's measured extremes
            p = rig_with(prior, params, x.get("added_mass", 0.0), x.get("lever_arm", 0.0))
            launch = launch_between(p.rig, x["spin"], x["tilt_min"], x["tilt_max"])
            return exact_solution(replace(p, launch=launch)).nutation_frequency_rad_s
        return _released(prior, params, x).nutation_frequency_rad_s

    def fast(params, x):
        _, i_t, i_o = _mgh_inertias(prior, params, x)
        return i_o * x["spin"] / i_t
    return _guard(exact), _guard(fast)


def spin_down_model(t_s, omega0: float, k: float, f: float):
    """``omega(t)`` for ``d omega/dt = -k omega - f`` (``k -> 0``: ``omega0 - f t``). [rad/s]"""
    t = np.asarray(t_s, float)
    e = np.exp(-k * t)
    lin = -np.expm1(-k * t) / k if abs(k) > 1e-12 else t
    return omega0 * e - f * lin


def observations_from_table(table: Table, prior: Protocol) -> list[Observation]:
    """The observations of one lab table."""
    v, sd, out = table.values, table.sd, []
    for i in range(table.n):
        x = {k: float(a[i]) for k, a in v.items()}
        x_sd = {k: float(a[i]) for k, a in sd.items()}
        line = int(table.lines[i])
        if table.kind == "spin_down":
            key = f"spin_down.initial_spin_rad_s[{table.path}]"
            y, y_sd = x.pop("spin"), x_sd.pop("spin")

            def exact(params, xx, key=key):
                return float(spin_down_model(xx["t"], params[key], params["spin_down.viscous_rate_per_s"],
                                             params.get("spin_down.friction_rad_s2", 0.0)))
            out.append(Observation("spin_down", table.path, line, y, y_sd, x, x_sd, exact, None, key))
            continue
        if "spin_start" in x:
            # the logarithmic mean: exact for an exponential decay between the two readings
            a, b = x.pop("spin_start"), x.pop("spin_end")
            sa, sb = x_sd.pop("spin_start"), x_sd.pop("spin_end")
            x["spin"] = (a - b) / math.log(a / b) if a != b else a
            x_sd["spin"] = 0.5 * math.hypot(sa, sb)
        if table.kind == "precession":
            if "precession_period" in x:
                y, y_sd = x.pop("precession_period"), x_sd.pop("precession_period")
            else:  # a rate read off a protractor and a stopwatch: the period of one turn at that rate
                rate, s = x.pop("precession_rate"), x_sd.pop("precession_rate")
                y, y_sd = 2 * math.pi / rate, 2 * math.pi * s / rate ** 2
            exact, fast = _precession(prior) if prior.gimbal is None else _gimbal_precession(prior)
        elif prior.gimbal is not None:
            y, y_sd = _nutation_value(x, x_sd)
            x.setdefault("tilt", math.pi / 2)
            x_sd.setdefault("tilt", 0.0)
            if prior.rig.com_distance_m != 0.0 or x.get("added_mass", 0.0) != 0.0:
                raise IdentifyInputError(
                    f"{table.path}, line {line}: a gyro in gimbals nutates by the model only when balanced "
                    f"(the prior's rig.com_distance_m = {prior.rig.com_distance_m!r}, added mass "
                    f"{x.get('added_mass', 0.0)!r} kg): measure its nutation with the weight removed")
            exact, fast = _gimbal_nutation(prior)
        else:
            y, y_sd = _nutation_value(x, x_sd)
            if ("tilt_min" in x) != ("tilt_max" in x) or ("tilt_min" in x and not x["tilt_min"] < x["tilt_max"]):
                raise IdentifyInputError(f"{table.path}, line {line}: a kicked top's nutation needs both tilt_min and "
                                         "tilt_max (the tilt's extremes), the first the smaller")
            x.setdefault("tilt", prior.launch.tilt_rad)
            x_sd.setdefault("tilt", 0.0)
            exact, fast = _nutation(prior)
        out.append(Observation(table.kind, table.path, line, y, y_sd, x, x_sd, exact, fast))
    return out


def _nutation_value(x: dict, x_sd: dict) -> tuple[float, float]:
    """A nutation row's frequency and its sd [rad/s], from a frequency or a period column (removed from ``x``)."""
    if "nutation_frequency" in x:
        return x.pop("nutation_frequency"), x_sd.pop("nutation_frequency")
    period, s = x.pop("nutation_period"), x_sd.pop("nutation_period")
    return 2 * math.pi / period, 2 * math.pi * s / period ** 2


def observations_from_fit(path: str, doc: dict, prior: Protocol) -> list[Observation]:
    """A video's fit.json: its mean precession rate and nutation frequency, for its protocol's launch."""
    if prior.gimbal is not None:
        raise IdentifyInputError(f"{path}: a video's fit.json describes a top on a pivot; the prior is a gyro in "
                                 "gimbals ([gimbal]): give its lab tables")
    summary = doc.get("protocol_summary")
    if not isinstance(summary, dict) or "launch" not in summary:
        raise IdentifyInputError(f"{path}: no protocol_summary with the launch (fit.json from an older gyrorig?): "
                                 "re-run 'gyrorig fit' or 'gyrorig analyze'")
    pivot = summary.get("pivot") or {}
    if pivot.get("damping") or pivot.get("acceleration"):
        raise IdentifyInputError(f"{path}: a damped or accelerated scene: its precession and nutation drift, and "
                                 "identify models only a fixed, undamped pivot")
    fields = summary["launch"] if isinstance(summary["launch"], dict) else {}
    for key, value in fields.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise IdentifyInputError(f"{path}: protocol_summary.launch.{key} = {value!r}: not a finite number")
    if not 0.0 <= fields.get("tilt_rad", 0.0) <= math.pi:
        raise IdentifyInputError(f"{path}: protocol_summary.launch.tilt_rad = {fields['tilt_rad']!r}: outside [0, pi]")
    try:
        launch = Launch(**fields)
    except TypeError as exc:
        raise IdentifyInputError(f"{path}: protocol_summary.launch: {exc}") from None
    out = []
    spin = launch.spin_rate_rad_s
    # a video does not measure the spin: where the prior gives launch.spin_rate_rad_s an sd, each video's spin is
    # a parameter with that relative sd about its own protocol's value
    u = prior.uncertainty
    rel = u.sd_of("launch.spin_rate_rad_s") / abs(prior.launch.spin_rate_rad_s) if prior.launch.spin_rate_rad_s else 0
    spin_key, spin_prior = (f"spin[{path}]", (spin, rel * abs(spin))) if rel > 0 else ("", None)
    for key, kind in (("precession_rate_rad_s", "fit_precession"), ("nutation_frequency_rad_s", "fit_nutation")):
        q = (doc.get("quantities") or {}).get(key)
        if not q or q.get("status") != "determined" or not q.get("standard_error"):
            continue

        def exact(params, x, key=key, launch=launch, spin_key=spin_key):
            if spin_key:
                launch = replace(launch, spin_rate_rad_s=params[spin_key])
            sol = _released(prior, params, x, launch)
            return sol.mean_precession_rate_rad_s if key == "precession_rate_rad_s" else sol.nutation_frequency_rad_s

        def fast(params, x, key=key, spin_key=spin_key):
            mgh, i_t, i_o = _mgh_inertias(prior, params, x)
            w = params[spin_key] if spin_key else x["spin"]
            return mgh / (i_o * w) if key == "precession_rate_rad_s" else i_o * w / i_t
        out.append(Observation(kind, path, 0, float(q["value"]), float(q["standard_error"]), {"spin": spin}, {},
                               _guard(exact), _guard(fast), spin_key, spin_prior))
    if not out:
        raise IdentifyInputError(f"{path}: neither the precession rate nor the nutation frequency is determined")
    return out
