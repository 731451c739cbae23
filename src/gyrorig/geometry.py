"""Shared geometry of the tip direction: angles <-> unit vectors, angle wrapping, rays meeting spheres.

Conventions (``docs/conventions.md``): Goldstein x-convention Euler angles, the tip direction
``(sin(theta) sin(phi), -sin(theta) cos(phi), cos(theta))``, the pivot at the origin.  Every
stage (simulator, renderer, tracker, fit, plan) uses these functions; none of them imports
anything but numpy.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["tip_from_angles", "angles_from_tip", "wrap_angle", "axis_rotation", "ray_sphere_distances",
           "board_lab_rotation", "same_rotation_near"]


def tip_from_angles(theta_rad: ArrayLike, phi_rad: ArrayLike) -> NDArray[np.float64]:
    """Unit tip direction ``(sin th sin ph, -sin th cos ph, cos th)``; shape ``(..., 3)``."""
    th = np.asarray(theta_rad, dtype=float)
    ph = np.asarray(phi_rad, dtype=float)
    s = np.sin(th)
    return np.stack([s * np.sin(ph), -s * np.cos(ph), np.cos(th)], axis=-1)


def angles_from_tip(tip: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Tilt ``theta`` in [0, pi] and azimuth ``phi`` in (-pi, pi] of directions ``(..., 3)`` (any length).

    ``theta = atan2(hypot(x, y), z)`` is accurate at both poles; at a pole ``phi`` is 0.
    """
    v = np.asarray(tip, dtype=float)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.arctan2(np.hypot(x, y), z), np.arctan2(x, -y)


def wrap_angle(angle_rad: ArrayLike) -> NDArray[np.float64] | float:
    """An angle (or array of them) reduced to [-pi, pi); exact (unchanged) where it is already inside. [rad]"""
    a = np.asarray(angle_rad, dtype=float)
    out = np.fmod(a, 2 * np.pi)  # exact, with the sign of a
    out = np.where(out >= np.pi, out - 2 * np.pi, np.where(out < -np.pi, out + 2 * np.pi, out))
    return float(out) if out.ndim == 0 else out


def axis_rotation(tilt_rad: float, azimuth_rad: float) -> NDArray[np.float64]:
    """Rotation taking ``z`` to the direction of tilt ``a`` and azimuth ``b``: ``Rz(b) Rx(a)``."""
    ca, sa, cb, sb = math.cos(tilt_rad), math.sin(tilt_rad), math.cos(azimuth_rad), math.sin(azimuth_rad)
    rx = np.array([[1.0, 0, 0], [0, ca, -sa], [0, sa, ca]])
    rz = np.array([[cb, -sb, 0], [sb, cb, 0], [0, 0, 1.0]])
    return rz @ rx


def ray_sphere_distances(origin: ArrayLike, direction: ArrayLike, radius: float
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Distances along unit rays ``origin + s d`` to the sphere ``|X| = radius`` about the origin.

    Parameters
    ----------
    origin : (3,) array
        Start of every ray (a camera centre). [m]
    direction : (..., 3) array
        Unit directions.
    radius : float
        Sphere radius. [m]

    Returns
    -------
    near, far : arrays of shape ``(...)``
        The two intersections, nearer first; NaN where a ray misses the sphere.
    """
    c = np.asarray(origin, dtype=float)
    d = np.asarray(direction, dtype=float)
    b = d @ c
    disc = b * b - (c @ c - radius**2)
    with np.errstate(invalid="ignore"):
        root = np.sqrt(np.where(disc >= 0, disc, np.nan))
    return -b - root, -b + root


def board_lab_rotation(yaw_rad: float) -> np.ndarray:
    """Board -> lab rotation of a board lying face up (its printed side towards +z): the board's x axis (along
    its ``cols`` corners) at azimuth ``yaw_rad`` from lab x, its z axis (OpenCV's, away from a viewer of the
    printed side) pointing down, its y axis = z x x."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])


def same_rotation_near(rvec: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The rotation vector of ``rvec``'s rotation closest to ``ref`` (a rotation by angle a about u is also one
    by a - 2 pi about u: near a half turn, e.g. a camera looking straight down, solvers return either)."""
    a = float(np.linalg.norm(rvec))
    if a == 0.0:
        return rvec
    other = rvec * (1.0 - 2.0 * math.pi / a)
    return other if np.linalg.norm(other - ref) < np.linalg.norm(rvec - ref) else rvec
