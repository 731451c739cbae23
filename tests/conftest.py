"""Shared fixtures and helpers.  Floating-point errors raise inside tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gyrorig.protocols import Protocol, parse_protocol

REPO = Path(__file__).resolve().parents[1]
PROTOCOL_DIR = REPO / "protocols"
BUNDLED_PROTOCOLS = sorted(PROTOCOL_DIR.glob("*.toml"))


@pytest.fixture(autouse=True)
def _strict_floats():
    # underflow is benign (scipy step-size code hits it routinely); the rest raise
    with np.errstate(divide="raise", over="raise", invalid="raise", under="ignore"):
        yield


def make_protocol(
    *,
    tilt: float = 0.2,
    tilt_rate: float = 0.0,
    precession_rate: float = 0.0,
    spin: float = 60.0,
    gravity: float | None = 9.81,
    inertia: float = 1.0,
    inertia_axial: float = 0.6,
    mass: float = 1.0,
    com: float = 0.1,
    frame_inertia: float | None = None,
    acceleration: list[float] | None = None,
    damping: dict[str, Any] | None = None,
    duration: float = 5.0,
    azimuth: float = 0.0,
) -> Protocol:
    """A protocol from keyword values (defaults: the benchmark top I=1, Io=0.6, M=1, h=0.1)."""
    rig: dict[str, Any] = dict(mass_kg=mass, com_distance_m=com, inertia_axial_kg_m2=inertia_axial,
                               inertia_transverse_kg_m2=inertia)
    if gravity is not None:
        rig["gravity_m_s2"] = gravity
    if frame_inertia is not None:
        rig["frame_axial_inertia_kg_m2"] = frame_inertia
    data: dict[str, Any] = {
        "rig": rig,
        "launch": dict(tilt_rad=tilt, azimuth_rad=azimuth, tilt_rate_rad_s=tilt_rate,
                       precession_rate_rad_s=precession_rate, spin_rate_rad_s=spin),
        "scene": dict(duration_s=duration),
    }
    pivot: dict[str, Any] = {}
    if acceleration is not None:
        pivot["acceleration_m_s2"] = acceleration
    if damping is not None:
        pivot["damping"] = damping
    if pivot:
        data["pivot"] = pivot
    return parse_protocol(data)


TIP = ["tip_x", "tip_y", "tip_z"]


def max_tip_error(a, b) -> float:
    """Largest angle (small-angle chord) between the tip directions of two trajectories. [rad]"""
    return float(np.linalg.norm(a[TIP].to_numpy() - b[TIP].to_numpy(), axis=1).max())
