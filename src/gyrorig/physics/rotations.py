"""Rotation helpers: Goldstein x-convention Euler angles, quaternions, tip direction.

Conventions (see ``docs/conventions.md``):

* Lab frame ``x, y, z`` with gravity along ``-z``.
* Euler angles ``(phi, theta, psi)`` in Goldstein's x-convention: rotate by ``phi``
  about ``z``, then ``theta`` about the new ``x`` (the line of nodes ``a``), then
  ``psi`` about the symmetry axis.  The symmetry axis (tip direction) is
  ``(sin th sin ph, -sin th cos ph, cos th)``.
* A rotation matrix ``R`` maps body coordinates to lab coordinates; its columns
  are the body axes ``d, q, o`` written in the lab frame.  (Goldstein's matrix
  ``A`` of the paper's eq. 7 is ``R.T``.)
* Quaternions are scalar-first ``(w, x, y, z)`` and represent the same ``R``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..geometry import angles_from_tip, tip_from_angles

__all__ = [
    "euler_to_matrix",
    "euler_matrix_cs",
    "matrix_to_quaternion",
    "quaternion_to_matrix",
    "tip_from_angles",
    "unwrapped_angles_from_tip",
    "euler_from_matrix",
]


def euler_to_matrix(phi_rad: ArrayLike, theta_rad: ArrayLike, psi_rad: ArrayLike) -> NDArray[np.float64]:
    """Body-to-lab rotation matrices for Goldstein x-convention Euler angles.

    Parameters
    ----------
    phi_rad, theta_rad, psi_rad : float or array_like
        Precession, nutation (tilt) and spin angles (broadcast together). [rad]

    Returns
    -------
    ndarray, shape (..., 3, 3)
        ``R`` with columns ``d, q, o`` in lab coordinates (transpose of the
        paper's eq. 7).
    """
    th = np.asarray(theta_rad, dtype=float)
    return euler_matrix_cs(phi_rad, np.cos(th), np.sin(th), psi_rad)


def euler_matrix_cs(phi_rad: ArrayLike, cos_theta: ArrayLike, sin_theta: ArrayLike, psi_rad: ArrayLike) -> NDArray[np.float64]:
    """As :func:`euler_to_matrix`, from ``cos`` and (possibly negative) ``sin`` of theta.

    A signed ``sin(theta)`` lets a path cross a pole smoothly: ``(phi, -theta, psi)``
    is the same rotation as ``(phi + pi, theta, psi + pi)``.
    """
    phi, cth, sth, psi = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in
                                               (phi_rad, cos_theta, sin_theta, psi_rad)))
    cph, sph, cps, sps = np.cos(phi), np.sin(phi), np.cos(psi), np.sin(psi)
    # rows of the paper's eq. (7) are d, q, o in lab coordinates; R is its transpose
    a = np.empty(phi.shape + (3, 3))
    a[..., 0, 0] = cph * cps - cth * sph * sps
    a[..., 0, 1] = sph * cps + cth * cph * sps
    a[..., 0, 2] = sth * sps
    a[..., 1, 0] = -cph * sps - cth * sph * cps
    a[..., 1, 1] = -sph * sps + cth * cph * cps
    a[..., 1, 2] = sth * cps
    a[..., 2, 0] = sth * sph
    a[..., 2, 1] = -sth * cph
    a[..., 2, 2] = cth
    return np.swapaxes(a, -1, -2)


def quaternion_to_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices from scalar-first quaternions (normalised on the fly).

    Parameters
    ----------
    q : array_like, shape (4,) or (n, 4)

    Returns
    -------
    ndarray, shape (3, 3) or (n, 3, 3)
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = 1 - 2 * (y * y + z * z)
    m[..., 0, 1] = 2 * (x * y - w * z)
    m[..., 0, 2] = 2 * (x * z + w * y)
    m[..., 1, 0] = 2 * (x * y + w * z)
    m[..., 1, 1] = 1 - 2 * (x * x + z * z)
    m[..., 1, 2] = 2 * (y * z - w * x)
    m[..., 2, 0] = 2 * (x * z - w * y)
    m[..., 2, 1] = 2 * (y * z + w * x)
    m[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def matrix_to_quaternion(m: ArrayLike) -> NDArray[np.float64]:
    """Scalar-first unit quaternion of a rotation matrix (Shepperd's method)."""
    m = np.asarray(m, dtype=float)
    tr = np.trace(m)
    diag = np.diag(m)
    k = int(np.argmax(np.concatenate([[tr], diag])))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def unwrapped_angles_from_tip(
    tip: ArrayLike, *, phi_at_pole_rad: float = 0.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Tilt and unwrapped azimuth of a sequence of tip directions.

    ``theta = atan2(hypot(x, y), z)`` is accurate at both poles.  Where the tip is
    exactly on a pole the azimuth is undefined; it is held at the last defined value
    (``phi_at_pole_rad`` before any is defined), so the series stays continuous.

    Parameters
    ----------
    tip : array_like, shape (n, 3)
    phi_at_pole_rad : float
        Azimuth reported while the tip has been on a pole since the start. [rad]

    Returns
    -------
    theta_rad, phi_rad : ndarray, shape (n,)
        ``phi_rad`` is unwrapped (continuous, not reduced to an interval).
    """
    tip = np.atleast_2d(np.asarray(tip, dtype=float))
    rho = np.hypot(tip[:, 0], tip[:, 1])
    theta, phi = angles_from_tip(tip)
    if len(phi) == 0:
        return theta, phi
    defined = rho > 0.0
    if not defined.all():
        # hold the last defined azimuth across pole samples
        idx = np.where(defined, np.arange(len(phi)), -1)
        np.maximum.accumulate(idx, out=idx)
        phi = np.where(idx >= 0, phi[np.maximum(idx, 0)], phi_at_pole_rad)
    phi = np.unwrap(phi)
    # choose the branch closest to the reference azimuth
    phi = phi + 2 * np.pi * np.round((phi_at_pole_rad - phi[0]) / (2 * np.pi))
    return theta, phi


def euler_from_matrix(
    m: ArrayLike, *, phi_hint_rad: ArrayLike | None = None, pole_tolerance: float = 0.0
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Goldstein x-convention angles ``(phi, theta, psi)`` of body-to-lab matrices.

    Where ``sin(theta) == 0`` only ``phi + psi`` (or ``phi - psi`` at ``theta = pi``)
    is defined; ``phi`` is then taken from ``phi_hint_rad`` and ``psi`` follows.

    Parameters
    ----------
    m : array_like, shape (n, 3, 3)
    phi_hint_rad : array_like, shape (n,), optional
        Azimuth to use where it is undefined (e.g. from :func:`unwrapped_angles_from_tip`).
    pole_tolerance : float
        Treat ``sin(theta) <= pole_tolerance`` as on the pole (default: exactly 0).

    Returns
    -------
    phi_rad, theta_rad, psi_rad : ndarray, shape (n,)
        Angles wrapped to (-pi, pi]; unwrap as needed.
    """
    m = np.asarray(m, dtype=float).reshape(-1, 3, 3)
    a = np.swapaxes(m, 1, 2)  # Goldstein A: rows d, q, o
    rho = np.hypot(a[:, 2, 0], a[:, 2, 1])
    theta = np.arctan2(rho, a[:, 2, 2])
    phi = np.arctan2(a[:, 2, 0], -a[:, 2, 1])
    psi = np.arctan2(a[:, 0, 2], a[:, 1, 2])
    pole = rho <= pole_tolerance
    if pole.any():
        hint = np.zeros(len(m)) if phi_hint_rad is None else np.asarray(phi_hint_rad, dtype=float)
        north = a[:, 2, 2] > 0
        # theta = 0: A = Rz(phi + psi)-like, A00 = cos(phi+psi), A01 = sin(phi+psi)
        # theta = pi: A00 = cos(phi - psi), A01 = sin(phi - psi)
        total = np.arctan2(a[:, 0, 1], a[:, 0, 0])
        phi = np.where(pole, hint, phi)
        psi = np.where(pole & north, total - hint, psi)
        psi = np.where(pole & ~north, hint - total, psi)
    return phi, theta, psi
