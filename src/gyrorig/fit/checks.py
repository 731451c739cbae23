"""Notes that hold a fit against the protocol it was run with: doubtful inputs, unit slips, a launch that disagrees.

- The protocol's implausible values (:func:`gyrorig.plausibility.protocol_doubts`).
- Frames further apart than half a turn of theory's precession (frame times in ms).
- A fitted rate that is a units factor away from theory (:func:`gyrorig.plausibility.unit_slip`): angles in
  degrees, times in ms, a spin in Hz or rev/min.
- The record's tilt at the launch against the protocol's ``launch.tilt``: a tip marker stated in the wrong place
  or a wrong camera pose moves every tilt the tracker reports by degrees while the fit stays good (chi-square near
  1).  When the record starts at the launch (t = 0), the fitted model's tilt at t = 0 is compared; when it starts
  later, an undamped top's tilt stays within cone +- nutation amplitude, and the launch tilt must lie there.
  The launch tilt's standard deviation is the protocol's (``tilt_deg = { value, sd }``), else
  :data:`LAUNCH_TILT_SD_RAD`; a difference beyond :data:`GEOMETRY_SIGMAS` combined standard deviations is noted.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import angles_from_tip, tip_from_angles
from ..plausibility import protocol_doubts, unit_slip
from ..protocols import Protocol
from .data import FitData
from .model import FitModel
from .result import Note, NoteKind, Quantity
from .solver import Solution

__all__ = ["check_notes", "LAUNCH_TILT_SD_RAD", "GEOMETRY_SIGMAS"]

#: the launch tilt's standard deviation when the protocol states none: a tilt set by hand against a scale [rad]
LAUNCH_TILT_SD_RAD = math.radians(1.0)
#: a record's launch tilt this many combined standard deviations from the protocol's is noted
GEOMETRY_SIGMAS = 5.0
#: a rate is named as a unit slip only when it also differs from theory by this many standard errors
SLIP_SIGMAS = 5.0


def _unit_slip_notes(quantities: dict[str, Quantity]) -> list[Note]:
    out = []
    for name in ("precession_rate_rad_s", "nutation_frequency_rad_s"):
        q = quantities.get(name)
        if q is None or not q.determined or not q.standard_error:
            continue
        ref = q.exact if q.exact is not None else q.paper
        if ref is None:
            continue
        slip = unit_slip(q.value, ref)
        if slip is None or abs(q.value - ref) < SLIP_SIGMAS * q.standard_error:
            continue
        factor, what = slip
        out.append(Note(NoteKind.PLAUSIBILITY,
                        f"the fitted {name} {q.value:.5g} is {q.value / ref:.4g} times theory's {ref:.5g} "
                        f"(a factor {factor:.4g}): {what}?"))
    return out


def _sampling_note(data: FitData, quantities: dict[str, Quantity]) -> Note | None:
    """Frames too far apart for theory's precession (more than half a turn between frames): times in ms?"""
    q = quantities.get("precession_rate_rad_s")
    ref = None if q is None else (q.exact if q.exact is not None else q.paper)
    if ref is None or not math.isfinite(ref) or data.n < 2:
        return None
    dt = float(np.median(np.diff(data.t_s)))
    turn = abs(ref) * dt
    if turn <= math.pi:
        return None
    hint = ("; frame times in milliseconds where seconds are meant (t_s)?" if turn / 1000.0 < 0.5 else
            "; the record cannot measure this precession")
    return Note(NoteKind.PLAUSIBILITY,
                f"the frames are {dt:.4g} s apart (median), but theory's precession ({ref:.4g} rad/s) turns "
                f"{turn:.3g} rad between frames, more than half a turn{hint}")


def _launch_note(sol: Solution, data: FitData, protocol: Protocol, quantities: dict[str, Quantity]) -> Note | None:
    spec = sol.spec
    cone = quantities.get("cone_angle_rad")
    if cone is None or not cone.determined or data.n < 2:
        return None
    # the fit's errors may be scaled or bootstrapped: the same factor as the cone angle's
    scale = cone.standard_error / cone.formal_standard_error if cone.formal_standard_error else 1.0
    theta0 = protocol.launch.tilt_rad
    dt = float(np.median(np.diff(data.t_s)))
    if data.t_s[0] <= 2.0 * dt:
        model = FitModel(spec)
        tau = np.array([-data.t_ref_s])
        seg = np.zeros(1, int)
        th, ph = model.lab(sol.x, tau, seg)
        if spec.lean:  # the launch's tilt is from the true vertical: the fitted axis
            th, _ = angles_from_tip(tip_from_angles(th, ph) @ model.rotation(sol.x))
        dth, _ = model.lab_jacobian(sol.x, tau, seg)
        g = np.zeros(len(sol.x))
        g[:dth.shape[1]] = dth[0]
        fitted = float(th[0])
        se = math.sqrt(max(float(g @ sol.cov @ g), 0.0)) * max(scale, 1.0)
        gap = abs(fitted - theta0)
        what = f"the record's tilt at the launch (t = 0) is {math.degrees(fitted):.4g} deg"
    elif not spec.damped and (spec.lean or not spec.fit_axis):
        amp = quantities.get("nutation_amplitude_rad")
        a = amp.value if amp is not None and amp.determined else 0.0
        fitted, se = cone.value, cone.standard_error
        gap = max(0.0, abs(fitted - theta0) - a)
        what = (f"the record's tilt stays within {math.degrees(fitted - a):.4g} to {math.degrees(fitted + a):.4g} deg "
                "(cone +- nutation amplitude)")
    else:
        return None
    stated = protocol.uncertainty.sd_of("launch.tilt_rad")
    sd = stated or LAUNCH_TILT_SD_RAD
    sigma = math.hypot(se, sd)
    if gap <= GEOMETRY_SIGMAS * sigma:
        return None
    tip = ""
    markers = protocol.extra.get("markers")
    if isinstance(markers, dict) and isinstance(markers.get("tip"), dict) and "position_m" in markers["tip"]:
        tip = f" (markers.tip.position_m = {list(markers['tip']['position_m'])})"
    return Note(NoteKind.GEOMETRY,
                f"{what}, {math.degrees(gap):.3g} deg from the protocol's launch tilt "
                f"{math.degrees(theta0):.4g} +- {math.degrees(sd):.2g} deg"
                + ("" if stated else " (assumed; state it as launch.tilt_deg = { value = ..., sd = ... })")
                + f": {gap / sigma:.1f} combined standard deviations.  If the launch tilt is right, the tip marker's "
                f"stated place{tip} or the camera's pose is wrong: either moves every tilt the tracker reports, while "
                "the fit itself stays good")


def check_notes(sol: Solution, data: FitData, protocol: Protocol, quantities: dict[str, Quantity]) -> list[Note]:
    """The notes of this module (see its docstring)."""
    notes = [Note(NoteKind.PLAUSIBILITY, f"the protocol's {d}") for d in protocol_doubts(protocol)]
    notes += _unit_slip_notes(quantities)
    sampling = _sampling_note(data, quantities)
    if sampling is not None:
        notes.append(sampling)
    launch = _launch_note(sol, data, protocol, quantities)
    if launch is not None:
        notes.append(launch)
    return notes
