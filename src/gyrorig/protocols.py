"""Experiment protocols: TOML files parsed into frozen, validated dataclasses.

A protocol states only what its scene has.  A missing section or key means the
corresponding physics is *absent*, never a silently supplied default: a protocol
without ``gravity_m_s2`` has no gravity torque, one without ``[pivot.damping]`` is
undamped, one without ``acceleration_m_s2`` has a pivot at rest, a launch without rates
is a release from rest (at azimuth 0).  Without ``[scene]`` a simulation or render runs
:data:`DEFAULT_DURATION_S` (a recording's analysis uses no scene).

Every problem is reported as a :class:`ProtocolError` naming the key, the value
found and the range allowed.  The full format, with every key and unit, is
documented in ``docs/user-guide.md`` (section "Protocol format").
"""

from __future__ import annotations

import importlib.resources
import logging
import math
import tomllib
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Union

from ._validate import ProtocolError, angle, boolean, check_keys, finite, number, vector3
from .gimbals import Gimbal, parse_gimbal
from .parameters import Uncertainty, split_uncertain

logger = logging.getLogger(__name__)

__all__ = ["ProtocolError", "Rig", "Launch", "PaperDamping", "EddyFieldDamping", "MagnetInBallDamping", "AirDamping",
           "Damping", "PivotAcceleration", "Pivot", "Scene", "Protocol", "load_protocol", "load_tracking_protocol",
           "parse_protocol", "read_protocol_tables", "top_protocol", "protocol_summary", "BUNDLED_PROTOCOL_DIR",
           "bundled_protocols", "protocol_path", "Uncertainty", "checked_rig"]


#: the bundled protocol files: the repository's ``protocols/``, installed as the package
#: ``gyrorig.bundled_protocols`` (from a clone, an sdist or a wheel alike)
BUNDLED_PROTOCOL_DIR = Path(str(importlib.resources.files("gyrorig.bundled_protocols")))


@dataclass(frozen=True, slots=True)
class Rig:
    """Mass properties of the top (a symmetric rigid body on a fixed-point pivot).

    Attributes
    ----------
    mass_kg : float
        Total mass. [kg]
    com_distance_m : float
        Pivot to centre of mass, along the symmetry axis (``h``). [m]
    inertia_axial_kg_m2 : float
        Axial moment of inertia of the spinning part (``Io``). [kg m^2]
    inertia_transverse_kg_m2 : float
        Transverse moment of inertia of the whole top about the pivot (``I``). [kg m^2]
    gravity_m_s2 : float or None
        Gravitational acceleration; ``None`` means no gravity (free top). [m s^-2]
    frame_axial_inertia_kg_m2 : float or None
        Present for a gyrostat: the rotor turns on bearings in a non-spinning frame
        (ball, stem, markers) of this axial inertia. ``None``: one rigid body. [kg m^2]
    """

    mass_kg: float
    com_distance_m: float
    inertia_axial_kg_m2: float
    inertia_transverse_kg_m2: float
    gravity_m_s2: float | None = None
    frame_axial_inertia_kg_m2: float | None = None

    @property
    def is_gyrostat(self) -> bool:
        """True when the spinning rotor rides in a separate, non-spinning frame."""
        return self.frame_axial_inertia_kg_m2 is not None

    @property
    def mgh_N_m(self) -> float:
        """Gravitational torque scale ``M g h`` (0 without gravity). [N m]"""
        return self.mass_kg * (self.gravity_m_s2 or 0.0) * self.com_distance_m


@dataclass(frozen=True, slots=True)
class Launch:
    """Initial conditions in the paper's Euler angles (Goldstein x-convention).

    Attributes
    ----------
    tilt_rad : float
        theta at t = 0, in [0, pi]. [rad]
    azimuth_rad : float
        phi at t = 0 (line of nodes angle from x). [rad]
    tilt_rate_rad_s, precession_rate_rad_s, spin_rate_rad_s : float
        theta-dot, phi-dot and psi-dot at t = 0 (psi-dot of the spinning rotor). [rad s^-1]
    spin_angle_rad : float
        psi at t = 0. [rad]
    frame_spin_rate_rad_s : float
        psi-dot of the non-spinning frame of a gyrostat at t = 0 (0: the frame is
        released without turning about its own axis). [rad s^-1]
    """

    tilt_rad: float
    azimuth_rad: float
    tilt_rate_rad_s: float
    precession_rate_rad_s: float
    spin_rate_rad_s: float
    spin_angle_rad: float = 0.0
    frame_spin_rate_rad_s: float = 0.0


@dataclass(frozen=True, slots=True)
class PaperDamping:
    """The paper's law (eqs. 22-23): torque ``-gamma I omega_perp`` in the body frame, no axial torque.

    Attributes
    ----------
    gamma_per_s : float
        Damping rate ``gamma``. [s^-1]
    """

    gamma_per_s: float
    model: str = field(default="paper", init=False)

    def coefficient(self, inertia_transverse_kg_m2: float) -> float:
        """Transverse viscous coefficient ``c = gamma I``. [N m s]"""
        return self.gamma_per_s * inertia_transverse_kg_m2


@dataclass(frozen=True, slots=True)
class MagnetInBallDamping:
    """Axisymmetric body-fixed field (magnet in the ball, conducting cup): ``-c omega_perp``.

    Attributes
    ----------
    coefficient_N_m_s : float
        ``c``; equivalent to the paper's law with ``gamma = c / I``. [N m s]
    """

    coefficient_N_m_s: float
    model: str = field(default="magnet-in-ball", init=False)

    def coefficient(self, inertia_transverse_kg_m2: float) -> float:
        """Transverse viscous coefficient ``c`` (the scale of the damping torque). [N m s]"""
        return self.coefficient_N_m_s


@dataclass(frozen=True, slots=True)
class EddyFieldDamping:
    """Conducting ball in a uniform lab-fixed field: ``-c (w - (w.b) b)``, ``b`` the field direction.

    ``w`` is the angular velocity of the body that carries the ball: the frame of a
    gyrostat, or the whole top otherwise.

    Attributes
    ----------
    coefficient_N_m_s : float
        ``c = (2 pi / 15) sigma a^5 B^2``. [N m s]
    field_direction : tuple of 3 floats
        Unit vector of ``B`` in the lab frame.
    spin_compensated : bool
        If true, a motor cancels this torque's component along the rotor axis when the
        ball turns with the rotor (plain top); its reaction goes to the frame of a gyrostat.
    """

    coefficient_N_m_s: float
    field_direction: tuple[float, float, float]
    spin_compensated: bool
    model: str = field(default="eddy-field", init=False)

    def coefficient(self, inertia_transverse_kg_m2: float) -> float:
        """Transverse viscous coefficient ``c`` (the scale of the damping torque). [N m s]"""
        return self.coefficient_N_m_s


@dataclass(frozen=True, slots=True)
class AirDamping:
    """Residual viscous air drag: ``-c omega_perp`` transverse and ``-c_axial omega_o`` on the rotor spin.

    Attributes
    ----------
    coefficient_N_m_s : float
        Transverse coefficient ``c``. [N m s]
    axial_coefficient_N_m_s : float
        Drag on the rotor spin (0 when the rotor runs in a frame-fixed can). [N m s]
    spin_compensated : bool
        A motor holds the rotor spin against the axial drag.
    """

    coefficient_N_m_s: float
    axial_coefficient_N_m_s: float = 0.0
    spin_compensated: bool = True
    model: str = field(default="air", init=False)

    def coefficient(self, inertia_transverse_kg_m2: float) -> float:
        """Transverse viscous coefficient ``c`` (the scale of the damping torque). [N m s]"""
        return self.coefficient_N_m_s


Damping = Union[PaperDamping, MagnetInBallDamping, EddyFieldDamping, AirDamping]


@dataclass(frozen=True, slots=True)
class PivotAcceleration:
    """Lab-frame acceleration of the pivot: constant, or piecewise linear in time.

    Attributes
    ----------
    t_s : tuple of float
        Knot times (one knot with t = 0 for a constant acceleration). [s]
    acceleration_m_s2 : tuple of 3-tuples
        Acceleration at each knot; held constant before the first and after the last. [m s^-2]
    """

    t_s: tuple[float, ...]
    acceleration_m_s2: tuple[tuple[float, float, float], ...]

    @property
    def is_constant(self) -> bool:
        """True when the acceleration never changes."""
        return len(set(self.acceleration_m_s2)) == 1

    def at(self, t_s: float) -> tuple[float, float, float]:
        """Acceleration at time ``t_s`` (linear interpolation between knots). [m s^-2]"""
        ts, acc = self.t_s, self.acceleration_m_s2
        if t_s <= ts[0]:
            return acc[0]
        if t_s >= ts[-1]:
            return acc[-1]
        lo, hi = 0, len(ts) - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if ts[mid] <= t_s:
                lo = mid
            else:
                hi = mid
        f = (t_s - ts[lo]) / (ts[hi] - ts[lo])
        a0, a1 = acc[lo], acc[hi]
        return (a0[0] + f * (a1[0] - a0[0]), a0[1] + f * (a1[1] - a0[1]), a0[2] + f * (a1[2] - a0[2]))


@dataclass(frozen=True, slots=True)
class Pivot:
    """Pivot effects present in the scene (empty: an ideal fixed, frictionless pivot)."""

    damping: tuple[Damping, ...] = ()
    acceleration: PivotAcceleration | None = None


@dataclass(frozen=True, slots=True)
class Scene:
    """What is simulated: ``duration_s``, the length of the run [s]; ``output_rate_hz``, the rate of the rows written
    to ``trajectory.csv`` [Hz]."""

    duration_s: float
    output_rate_hz: float = 1000.0


@dataclass(frozen=True, slots=True)
class Protocol:
    """A whole experiment description; ``extra`` keeps sections read by later stages (camera, markers...)."""

    name: str
    description: str
    #: rig, launch and scene are None only in a protocol read for tracking alone (:func:`load_tracking_protocol`)
    rig: Rig
    launch: Launch
    pivot: Pivot
    scene: Scene
    source: str = ""
    extra: Mapping[str, Any] = field(default_factory=dict)
    #: standard deviations (and correlations) of the parameters given as ``{ value, sd }``
    #: (:mod:`gyrorig.parameters`); empty: every number exact
    uncertainty: Uncertainty = field(default_factory=Uncertainty)
    #: a gyro in gimbals (:mod:`gyrorig.gimbals`); None: a top on a pivot
    gimbal: Gimbal | None = None

    @property
    def has_gravity(self) -> bool:
        """True when a gravity torque acts (gravity given and non-zero, h non-zero)."""
        return bool(self.rig.gravity_m_s2) and self.rig.com_distance_m != 0.0

    @property
    def is_damped(self) -> bool:
        """True when any damping torque is present."""
        return len(self.pivot.damping) > 0


# --------------------------------------------------------------------------------------
# parsing

def protocol_summary(p: Protocol) -> dict:
    """The protocol as parsed (its physics sections as plain dicts), for manifests."""
    out = {"name": p.name, "source": p.source, "description": p.description, "rig": asdict(p.rig),
           "launch": asdict(p.launch), "pivot": asdict(p.pivot), "scene": asdict(p.scene)}
    if p.uncertainty:
        out["uncertainty"] = p.uncertainty.as_dict()
    if p.gimbal is not None:
        out["gimbal"] = asdict(p.gimbal)
    return out


_LATER_SECTIONS = {"camera", "markers", "measure", "configuration"}  # read by later stages, validated there
_SECTIONS = {"protocol", "rig", "launch", "pivot", "scene", "uncertainty", "gimbal"} | _LATER_SECTIONS


def _check_sections(data: Mapping[str, Any]) -> None:
    """ProtocolError naming the sections a protocol does not know."""
    unknown = sorted(set(data) - _SECTIONS)
    if unknown:
        raise ProtocolError(f"unknown section(s) {', '.join(unknown)}; allowed: {', '.join(sorted(_SECTIONS))}")


def _parse_rig(t: Mapping[str, Any]) -> Rig:
    s = "rig"
    check_keys(
        s,
        t,
        {"mass_kg", "com_distance_m", "inertia_axial_kg_m2", "inertia_transverse_kg_m2"},
        {"gravity_m_s2", "frame_axial_inertia_kg_m2"},
    )
    mass = number(s, "mass_kg", t["mass_kg"], lo=0.0, lo_open=True)
    h = number(s, "com_distance_m", t["com_distance_m"], lo=0.0)
    io = number(s, "inertia_axial_kg_m2", t["inertia_axial_kg_m2"], lo=0.0, lo_open=True)
    it = number(s, "inertia_transverse_kg_m2", t["inertia_transverse_kg_m2"], lo=0.0, lo_open=True)
    g = number(s, "gravity_m_s2", t["gravity_m_s2"], lo=0.0) if "gravity_m_s2" in t else None
    frame = (
        number(s, "frame_axial_inertia_kg_m2", t["frame_axial_inertia_kg_m2"], lo=0.0, lo_open=True)
        if "frame_axial_inertia_kg_m2" in t
        else None
    )
    # A rigid symmetric body obeys I_axial <= 2 I_transverse about its centre of mass.
    i_cm = it - mass * h * h
    axial_total = io + (frame or 0.0)
    if i_cm <= 0.0:
        raise ProtocolError(
            f"rig.inertia_transverse_kg_m2 = {it!r} is out of range: it must exceed mass_kg * com_distance_m^2 "
            f"= {mass * h * h:.6g} (the transverse inertia about the pivot includes M h^2)"
        )
    if axial_total > 2.0 * i_cm * (1 + 1e-12):
        raise ProtocolError(
            f"rig.inertia_axial_kg_m2 = {io!r} is out of range: no rigid body has an axial inertia "
            f"({axial_total:.6g} with the frame) above twice its transverse inertia about the centre of mass "
            f"(2 * (I - M h^2) = {2 * i_cm:.6g}); allowed (0, {2 * i_cm - (frame or 0.0):.6g}]"
        )
    return Rig(mass, h, io, it, g, frame)


def _parse_launch(t: Mapping[str, Any], rig: Rig) -> Launch:
    s = "launch"
    optional = {
        "tilt_rad", "tilt_deg", "azimuth_rad", "azimuth_deg", "spin_angle_rad", "spin_angle_deg",
        "frame_spin_rate_rad_s",
    }
    # released from rest at azimuth 0 unless said otherwise: a recording's launch is rarely known better
    check_keys(s, t, {"spin_rate_rad_s"}, optional | {"tilt_rate_rad_s", "precession_rate_rad_s"})
    tilt = angle(s, t, "tilt", lo=0.0, hi=math.pi, required=True)
    azimuth = angle(s, t, "azimuth", lo=-1e6, hi=1e6, required=False)
    spin_angle = angle(s, t, "spin_angle", lo=-1e6, hi=1e6, required=False)
    if "frame_spin_rate_rad_s" in t and not rig.is_gyrostat:
        raise ProtocolError(
            "launch.frame_spin_rate_rad_s is only meaningful for a gyrostat: give rig.frame_axial_inertia_kg_m2"
        )
    return Launch(
        tilt_rad=tilt,
        azimuth_rad=azimuth,
        tilt_rate_rad_s=number(s, "tilt_rate_rad_s", t.get("tilt_rate_rad_s", 0.0)),
        precession_rate_rad_s=number(s, "precession_rate_rad_s", t.get("precession_rate_rad_s", 0.0)),
        spin_rate_rad_s=number(s, "spin_rate_rad_s", t["spin_rate_rad_s"]),
        spin_angle_rad=spin_angle,
        frame_spin_rate_rad_s=number(s, "frame_spin_rate_rad_s", t.get("frame_spin_rate_rad_s", 0.0)),
    )


def _parse_one_damping(s: str, t: Mapping[str, Any]) -> Damping:
    if not isinstance(t, Mapping):
        raise ProtocolError(f"[{s}] must be a table, found {t!r}")
    models = ("paper", "eddy-field", "magnet-in-ball", "air")
    model = t.get("model")
    if model not in models:
        raise ProtocolError(f"{s}.model = {model!r}: allowed {', '.join(repr(m) for m in models)}")
    if model == "paper":
        check_keys(s, t, {"model", "gamma_per_s"}, set())
        return PaperDamping(number(s, "gamma_per_s", t["gamma_per_s"], lo=0.0))
    if model == "magnet-in-ball":
        check_keys(s, t, {"model", "coefficient_N_m_s"}, set())
        return MagnetInBallDamping(number(s, "coefficient_N_m_s", t["coefficient_N_m_s"], lo=0.0))
    if model == "eddy-field":
        check_keys(s, t, {"model", "coefficient_N_m_s", "field_direction", "spin_compensated"}, set())
        d = vector3(s, "field_direction", t["field_direction"])
        norm = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        if norm == 0.0:
            raise ProtocolError(f"{s}.field_direction = {list(d)!r}: must be a non-zero vector")
        return EddyFieldDamping(
            number(s, "coefficient_N_m_s", t["coefficient_N_m_s"], lo=0.0),
            (d[0] / norm, d[1] / norm, d[2] / norm),
            boolean(s, "spin_compensated", t["spin_compensated"]),
        )
    check_keys(s, t, {"model", "coefficient_N_m_s"}, {"axial_coefficient_N_m_s", "spin_compensated"})
    return AirDamping(
        number(s, "coefficient_N_m_s", t["coefficient_N_m_s"], lo=0.0),
        number(s, "axial_coefficient_N_m_s", t.get("axial_coefficient_N_m_s", 0.0), lo=0.0),
        boolean(s, "spin_compensated", t.get("spin_compensated", True)),
    )


def _parse_acceleration_table(s: str, t: Mapping[str, Any]) -> PivotAcceleration:
    check_keys(s, t, {"t_s", "acceleration_m_s2"}, set())
    ts, acc = t["t_s"], t["acceleration_m_s2"]
    if not isinstance(ts, list) or len(ts) < 2:
        raise ProtocolError(f"{s}.t_s = {ts!r}: expected a list of at least 2 times")
    if not isinstance(acc, list) or len(acc) != len(ts):
        raise ProtocolError(f"{s}.acceleration_m_s2: expected {len(ts)} rows of [ax, ay, az], one per t_s")
    times = tuple(finite(s, f"t_s[{i}]", v) for i, v in enumerate(ts))
    if any(b <= a for a, b in zip(times, times[1:])):
        raise ProtocolError(f"{s}.t_s = {list(times)!r}: times must be strictly increasing")
    rows = tuple(vector3(s, f"acceleration_m_s2[{i}]", row) for i, row in enumerate(acc))
    return PivotAcceleration(times, rows)


def _parse_pivot(t: Mapping[str, Any]) -> Pivot:
    s = "pivot"
    check_keys(s, t, set(), {"damping", "acceleration_m_s2", "acceleration_table"})
    damping: tuple[Damping, ...] = ()
    if "damping" in t:
        d = t["damping"]
        if isinstance(d, list):  # [[pivot.damping]] array of tables: several mechanisms at once
            damping = tuple(_parse_one_damping(f"pivot.damping[{i}]", x) for i, x in enumerate(d))
        else:
            damping = (_parse_one_damping("pivot.damping", d),)
    if "acceleration_m_s2" in t and "acceleration_table" in t:
        raise ProtocolError("[pivot] gives both acceleration_m_s2 and acceleration_table; give one")
    acceleration = None
    if "acceleration_m_s2" in t:
        acceleration = PivotAcceleration((0.0,), (vector3(s, "acceleration_m_s2", t["acceleration_m_s2"]),))
    elif "acceleration_table" in t:
        acceleration = _parse_acceleration_table("pivot.acceleration_table", t["acceleration_table"])
    return Pivot(damping, acceleration)


#: the simulated length when a protocol does not state scene.duration_s (a recording's analysis needs none) [s]
DEFAULT_DURATION_S = 20.0


def _parse_scene(t: Mapping[str, Any]) -> Scene:
    s = "scene"
    check_keys(s, t, set(), {"duration_s", "output_rate_hz"})
    return Scene(
        number(s, "duration_s", t.get("duration_s", DEFAULT_DURATION_S), lo=0.0, lo_open=True, hi=1e7),
        number(s, "output_rate_hz", t.get("output_rate_hz", 1000.0), lo=0.0, lo_open=True, hi=1e7),
    )


def parse_protocol(data: Mapping[str, Any], *, source: str = "") -> Protocol:
    """Validate a protocol given as a nested mapping (the parsed TOML).

    Parameters
    ----------
    data : mapping
        Top-level tables ``protocol`` (optional: ``name``, ``description``), ``rig``,
        ``launch`` (required), ``scene``, ``pivot``, ``gimbal`` (optional), ``uncertainty`` (optional:
        correlations of the numbers given as ``{ value, sd }``, :mod:`gyrorig.parameters`), and
        the sections read by later stages (``camera``, ``markers``, ``measure``).
    source : str
        Where the data came from, for messages.

    Returns
    -------
    Protocol

    Raises
    ------
    ProtocolError
        Naming the offending key, its value and the allowed range.
    """
    _check_sections(data)
    data, uncertainty = split_uncertain(data)
    for sec in ("rig", "launch"):
        if sec not in data:
            raise ProtocolError(f"missing required section [{sec}] (tracking alone needs only [markers])")
    meta = data.get("protocol", {})
    check_keys("protocol", meta, set(), {"name", "description"})
    rig = _parse_rig(data["rig"])
    launch = _parse_launch(data["launch"], rig)
    pivot = _parse_pivot(data.get("pivot", {}))
    scene = _parse_scene(data.get("scene", {}))
    if pivot.acceleration is not None and rig.com_distance_m == 0.0:
        raise ProtocolError("pivot acceleration given but rig.com_distance_m = 0: it would exert no torque")
    extra = {k: v for k, v in data.items() if k in _LATER_SECTIONS}
    name = str(meta.get("name", Path(source).stem if source else "protocol"))
    gimbal = parse_gimbal(data["gimbal"]) if "gimbal" in data else None
    return Protocol(name, str(meta.get("description", "")), rig, launch, pivot, scene, source, extra, uncertainty,
                    gimbal)


def checked_rig(rig: Rig) -> Rig:
    """``rig`` validated as if read from a protocol (e.g. after changing a value): ProtocolError otherwise."""
    return _parse_rig({k: v for k, v in asdict(rig).items() if v is not None})


def protocol_path(path: str | Path) -> Path:
    """``path``, or the bundled protocol of that name where no such file exists (``gyrorig plan free-top``)."""
    path, bundled = Path(path), BUNDLED_PROTOCOL_DIR / f"{Path(path).stem}.toml"
    named = not path.exists() and path.name == str(path) and path.suffix in ("", ".toml")
    return bundled if named and bundled.is_file() else path


def read_protocol_tables(path: str | Path) -> tuple[Path, dict]:
    """The protocol file (or the bundled protocol of that name where no such file exists) and its tables as parsed
    TOML; ProtocolError when it cannot be read or parsed."""
    path = protocol_path(path)
    from . import _io

    try:
        _io.check_settings_size(path, "protocol")
    except _io.InputTooLarge as exc:
        raise ProtocolError(str(exc)) from None
    try:
        return path, tomllib.loads(_io.read_settings_text(path))
    except FileNotFoundError as exc:
        raise ProtocolError(f"protocol file not found: {path}") from exc
    except IsADirectoryError as exc:
        raise ProtocolError(f"{path}: is a folder; expected a protocol TOML file") from exc
    except OSError as exc:
        raise ProtocolError(f"cannot read protocol file {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ProtocolError(f"{path}: not UTF-8 text: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ProtocolError(f"{path}: not valid TOML: {exc}") from exc


def load_protocol(path: str | Path) -> Protocol:
    """A protocol TOML file (or bundled protocol's name) read and validated; ProtocolError naming what is wrong."""
    return _validated(*read_protocol_tables(path))


def _validated(path: Path, data: dict) -> Protocol:
    """The protocol file's tables parsed (:func:`parse_protocol`), its doubts logged as warnings."""
    try:
        protocol = parse_protocol(data, source=str(path))
    except ProtocolError as exc:
        raise ProtocolError(f"{path}: {exc}") from None
    from .plausibility import protocol_doubts

    for doubt in protocol_doubts(protocol):
        logger.warning("%s: %s", path, doubt)
    return protocol


def load_tracking_protocol(path: str | Path) -> Protocol:
    """A protocol for tracking, which reads only ``[markers]`` (and ``[camera]``'s placement, ``[pivot]``): the whole
    protocol when it has ``[rig]`` and ``[launch]``, else those sections alone, with ``rig``, ``launch`` and ``scene``
    None (a recording's rig need not be known to track it)."""
    path, data = read_protocol_tables(path)
    if all(sec in data for sec in ("rig", "launch")):
        return _validated(path, data)
    try:
        _check_sections(data)
        if "markers" not in data:
            raise ProtocolError("missing section [markers]: tracking needs the tip marker (markers.tip)")
        data, uncertainty = split_uncertain(data)
        meta = data.get("protocol", {})
        check_keys("protocol", meta, set(), {"name", "description"})
        pivot = _parse_pivot(data.get("pivot", {}))
    except ProtocolError as exc:
        raise ProtocolError(f"{path}: {exc}") from None
    return Protocol(str(meta.get("name", path.stem)), str(meta.get("description", "")), None, None, pivot, None,
                    str(path), {k: v for k, v in data.items() if k in _LATER_SECTIONS}, uncertainty)


def bundled_protocols() -> dict[str, str]:
    """The protocols that come with gyrorig, by name (what ``load_protocol`` accepts on its own): name ->
    description."""
    out = {}
    for f in sorted(BUNDLED_PROTOCOL_DIR.glob("*.toml")):
        with f.open("rb") as fh:
            meta = tomllib.load(fh).get("protocol", {})
        out[f.stem] = str(meta.get("description", ""))
    return out


def top_protocol(
    *,
    tilt_rad: float,
    spin_rate_rad_s: float,
    tilt_rate_rad_s: float = 0.0,
    precession_rate_rad_s: float = 0.0,
    azimuth_rad: float = 0.0,
    mass_kg: float = 1.0,
    com_distance_m: float = 0.1,
    inertia_axial_kg_m2: float = 0.6,
    inertia_transverse_kg_m2: float = 1.0,
    gravity_m_s2: float | None = 9.81,
    frame_axial_inertia_kg_m2: float | None = None,
    acceleration_m_s2: list[float] | None = None,
    damping: Mapping[str, Any] | None = None,
    duration_s: float = 1.0,
    name: str = "top",
) -> Protocol:
    """A validated protocol from keyword values (defaults: the benchmark top I = 1, Io = 0.6, M = 1, h = 0.1).

    ``gravity_m_s2=None`` leaves gravity out (free top); ``damping`` is one
    ``[pivot.damping]`` table as a mapping.
    """
    rig: dict[str, Any] = dict(mass_kg=mass_kg, com_distance_m=com_distance_m,
                               inertia_axial_kg_m2=inertia_axial_kg_m2, inertia_transverse_kg_m2=inertia_transverse_kg_m2)
    if gravity_m_s2 is not None:
        rig["gravity_m_s2"] = gravity_m_s2
    if frame_axial_inertia_kg_m2 is not None:
        rig["frame_axial_inertia_kg_m2"] = frame_axial_inertia_kg_m2
    pivot: dict[str, Any] = {}
    if acceleration_m_s2 is not None:
        pivot["acceleration_m_s2"] = list(acceleration_m_s2)
    if damping is not None:
        pivot["damping"] = dict(damping)
    launch = dict(tilt_rad=tilt_rad, azimuth_rad=azimuth_rad, tilt_rate_rad_s=tilt_rate_rad_s,
                  precession_rate_rad_s=precession_rate_rad_s, spin_rate_rad_s=spin_rate_rad_s)
    data: dict[str, Any] = {"protocol": {"name": name}, "rig": rig, "launch": launch,
                            "scene": {"duration_s": duration_s}}
    if pivot:
        data["pivot"] = pivot
    return parse_protocol(data)
