import numpy as np
import pytest

from gyrorig.physics.rotations import (
    unwrapped_angles_from_tip,
    euler_from_matrix,
    euler_to_matrix,
    matrix_to_quaternion,
    quaternion_to_matrix,
    tip_from_angles,
)

ROUND_TRIP_TOL = 1e-12


def test_tip_is_third_column_and_matches_paper_formula():
    rng = np.random.default_rng(1)
    for _ in range(20):
        ph, th, ps = rng.uniform(-np.pi, np.pi), rng.uniform(0, np.pi), rng.uniform(-np.pi, np.pi)
        m = euler_to_matrix(ph, th, ps)
        assert np.allclose(m[:, 2], [np.sin(th) * np.sin(ph), -np.sin(th) * np.cos(ph), np.cos(th)], atol=1e-15)
        assert np.allclose(tip_from_angles(th, ph), m[:, 2], atol=1e-15)
        assert np.allclose(m.T @ m, np.eye(3), atol=1e-14)
        assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-14)


def test_line_of_nodes_is_first_axis_for_zero_spin():
    # Goldstein x-convention: after phi about z, theta turns about the new x axis a = (cos phi, sin phi, 0)
    m = euler_to_matrix(0.7, 0.3, 0.0)
    assert np.allclose(m[:, 0], [np.cos(0.7), np.sin(0.7), 0.0], atol=1e-15)


def test_quaternion_round_trip():
    rng = np.random.default_rng(2)
    for _ in range(50):
        m = euler_to_matrix(*rng.uniform(-3, 3, size=3))
        q = matrix_to_quaternion(m)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
        assert np.allclose(quaternion_to_matrix(q), m, atol=ROUND_TRIP_TOL)


def test_euler_round_trip_away_from_poles():
    rng = np.random.default_rng(3)
    angles = np.column_stack([rng.uniform(-3, 3, 100), rng.uniform(0.01, np.pi - 0.01, 100), rng.uniform(-3, 3, 100)])
    mats = np.array([euler_to_matrix(*a) for a in angles])
    ph, th, ps = euler_from_matrix(mats)
    wrap = lambda x: np.angle(np.exp(1j * x))  # noqa: E731
    assert np.allclose(th, angles[:, 1], atol=ROUND_TRIP_TOL)
    assert np.allclose(wrap(ph - angles[:, 0]), 0, atol=ROUND_TRIP_TOL)
    assert np.allclose(wrap(ps - angles[:, 2]), 0, atol=ROUND_TRIP_TOL)


@pytest.mark.parametrize("theta", [0.0, np.pi])
def test_euler_at_the_poles_uses_the_hint_and_reproduces_the_matrix(theta):
    m = euler_to_matrix(0.4, theta, 1.1)
    ph, th, ps = euler_from_matrix(m[None], phi_hint_rad=[0.4])
    assert th[0] == pytest.approx(theta, abs=1e-15)
    assert np.allclose(euler_to_matrix(ph[0], th[0], ps[0]), m, atol=1e-14)


def test_angles_from_tip_unwraps_and_holds_azimuth_on_pole():
    phi_true = np.linspace(0.0, 20.0, 400)
    tip = tip_from_angles(np.full_like(phi_true, 0.3), phi_true)
    th, ph = unwrapped_angles_from_tip(tip, phi_at_pole_rad=0.0)
    assert np.allclose(ph, phi_true, atol=1e-12)
    assert np.allclose(th, 0.3, atol=1e-15)
    pole = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [np.sin(0.1), 0.0, np.cos(0.1)]])
    th, ph = unwrapped_angles_from_tip(pole, phi_at_pole_rad=1.5)
    assert th[0] == 0.0
    assert ph[0] == ph[1] == 1.5
