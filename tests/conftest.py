"""Shared fixtures and helpers.  Floating-point errors raise inside tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gyrorig.protocols import Protocol, top_protocol

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
    """Short-named wrapper of :func:`gyrorig.protocols.top_protocol` for the tests."""
    return top_protocol(tilt_rad=tilt, tilt_rate_rad_s=tilt_rate, precession_rate_rad_s=precession_rate,
                        spin_rate_rad_s=spin, gravity_m_s2=gravity, inertia_transverse_kg_m2=inertia,
                        inertia_axial_kg_m2=inertia_axial, mass_kg=mass, com_distance_m=com,
                        frame_axial_inertia_kg_m2=frame_inertia, acceleration_m_s2=acceleration, damping=damping,
                        duration_s=duration, azimuth_rad=azimuth)


TIP = ["tip_x", "tip_y", "tip_z"]


def max_tip_error(a, b) -> float:
    """Largest angle (small-angle chord) between the tip directions of two trajectories. [rad]"""
    return float(np.linalg.norm(a[TIP].to_numpy() - b[TIP].to_numpy(), axis=1).max())
