import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import BUNDLED_PROTOCOLS, TIP, make_protocol, max_tip_error
from gyrorig import SimulationError, load_protocol, simulate
from gyrorig.physics import TRAJECTORY_COLUMNS, choose_method
from gyrorig.physics.invariants import invariants
from gyrorig.physics.rotations import euler_to_matrix
from gyrorig.physics.torques import EddyFieldTorque
from gyrorig.protocols import Pivot, PivotAcceleration

#: relative drift of conserved quantities allowed at the default tolerances
INVARIANT_RTOL = 1e-8


@pytest.mark.parametrize("path", BUNDLED_PROTOCOLS, ids=lambda p: p.stem)
def test_every_bundled_protocol_simulates(path):
    p = load_protocol(path)
    df, info = simulate(p, duration_s=0.5, rate_hz=200.0, return_info=True)
    assert list(df.columns[: len(TRAJECTORY_COLUMNS)]) == list(TRAJECTORY_COLUMNS)
    assert len(df) == 101 and df.t_s.iloc[-1] == pytest.approx(0.5)
    assert np.isfinite(df.to_numpy()).all()
    assert np.allclose(np.linalg.norm(df[TIP].to_numpy(), axis=1), 1.0, atol=1e-12)
    assert info.quaternion_norm_drift < 1e-9
    assert ("psi_frame_rad" in df) == p.rig.is_gyrostat
    assert df.theta_rad.iloc[0] == pytest.approx(p.launch.tilt_rad, abs=1e-15)


UNDAMPED = {
    "heavy": dict(tilt=0.3, tilt_rate=0.4, precession_rate=0.5, spin=60.0),
    "accelerated": dict(tilt=0.3, spin=60.0, acceleration=[2.0, 1.0, -0.5]),
    "gyrostat": dict(tilt=1.0, precession_rate=-0.4, spin=80.0, frame_inertia=0.1),
    "free": dict(tilt=0.3, tilt_rate=1.0, spin=60.0, gravity=None),
    "hanging": dict(tilt=3.0, tilt_rate=0.5, spin=5.0),
}


@pytest.mark.parametrize("method", ["gyro", "DOP853"])
@pytest.mark.parametrize("name", list(UNDAMPED))
def test_invariants_are_conserved_without_damping(name, method):
    p = make_protocol(duration=5.0, **UNDAMPED[name])
    inv = invariants(p, simulate(p, method=method, rate_hz=50.0))
    for col in ["energy_J", "l_vertical_kg_m2_s", "l_axial_kg_m2_s"]:
        v = inv[col].to_numpy()
        scale = max(abs(v[0]), 1.0)
        assert np.abs(v - v[0]).max() < INVARIANT_RTOL * scale, col


DAMPERS = {
    "paper": dict(damping={"model": "paper", "gamma_per_s": 0.8}),
    "magnet-in-ball": dict(damping={"model": "magnet-in-ball", "coefficient_N_m_s": 0.5}),
    "air": dict(damping={"model": "air", "coefficient_N_m_s": 0.2, "axial_coefficient_N_m_s": 0.01,
                         "spin_compensated": False}),
    "eddy-plain-braking-spin": dict(damping={"model": "eddy-field", "coefficient_N_m_s": 0.01,
                                             "field_direction": [0.3, 0, 1], "spin_compensated": False}),
    "eddy-gyrostat": dict(damping={"model": "eddy-field", "coefficient_N_m_s": 0.5,
                                   "field_direction": [0, 0, 1], "spin_compensated": True}, frame_inertia=0.1),
}


@pytest.mark.parametrize("name", list(DAMPERS))
def test_damping_only_dissipates(name):
    p = make_protocol(tilt=0.5, tilt_rate=0.5, precession_rate=1.0, spin=40.0, duration=4.0, **DAMPERS[name])
    df = simulate(p, rate_hz=100.0)
    energy = invariants(p, df).energy_J.to_numpy()
    assert np.all(np.diff(energy) <= 1e-12 * abs(energy[0])), "energy must never increase"
    # the transverse motion starts with ~0.24 J; at these rates well over 0.01 J is dissipated in 4 s
    assert energy[-1] < energy[0] - 0.01


def test_motor_feeds_energy_when_the_ball_spins_with_the_rotor_in_a_lab_field():
    """A conducting ball spinning with the rotor in a lab field, spin held by a motor.

    Not a pure damper: the torque has a transverse part ``c omega_o (e3.b) b_perp`` and
    the motor that holds ``omega_o`` does work.  Energy balance:
    ``dE/dt = -c |w - (w.b) b|^2 + tau_motor omega_o`` with ``tau_motor = c (omega_o - (w.b) b.e3)``.
    (Design constraint 1 of the rig note: the ball must not spin with the rotor.)
    """
    c = 0.5
    p = make_protocol(tilt=0.5, tilt_rate=0.5, precession_rate=1.0, spin=40.0, duration=2.0,
                      damping={"model": "eddy-field", "coefficient_N_m_s": c, "field_direction": [0, 0, 1],
                               "spin_compensated": True})
    df = simulate(p, method="gyro", rtol=1e-12, rate_hz=2000.0)
    energy = invariants(p, df).energy_J.to_numpy()
    rot = euler_to_matrix(df.phi_rad.to_numpy(), df.theta_rad.to_numpy(), df.psi_rad.to_numpy())
    w = np.einsum("nij,nj->ni", rot, df[["omega_d_rad_s", "omega_q_rad_s", "omega_o_rad_s"]].to_numpy())
    b = np.array([0.0, 0.0, 1.0])
    wb = w @ b
    dissipation = -c * np.einsum("ni,ni->n", w - wb[:, None] * b, w - wb[:, None] * b)
    motor = c * (df.omega_o_rad_s.to_numpy() - wb * df.tip_z.to_numpy()) * df.omega_o_rad_s.to_numpy()
    power = dissipation + motor
    predicted = energy[0] + np.concatenate([[0.0], np.cumsum(0.5 * (power[1:] + power[:-1]) * np.diff(df.t_s))])
    assert energy[-1] > energy[0] + 1.0  # the motor pumps energy in
    assert np.abs(energy - predicted).max() < 1e-4 * np.ptp(energy)


def test_compensated_spin_is_held_and_uncompensated_spin_is_braked():
    paper = make_protocol(spin=40.0, damping={"model": "paper", "gamma_per_s": 2.0})
    assert np.ptp(simulate(paper, rate_hz=20.0).omega_o_rad_s) == 0.0
    p = make_protocol(spin=40.0, duration=2.0, **DAMPERS["eddy-plain-braking-spin"])
    om = simulate(p, rate_hz=20.0).omega_o_rad_s.to_numpy()
    assert np.all(np.diff(om) < 0)


def test_eddy_torque_opposes_the_carrier_rotation():
    rng = np.random.default_rng(7)
    for _ in range(100):
        b = rng.normal(size=3)
        torque = EddyFieldTorque(0.3, tuple(b / np.linalg.norm(b)), spin_compensated=False)
        frame = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        e1, e2, e3 = (tuple(frame[:, i]) for i in range(3))
        w1, w2, w3 = rng.normal(size=3)
        t1, t2, tr, tf = torque.components(0.0, e1, e2, e3, w1, w2, w3, None)
        assert t1 * w1 + t2 * w2 + tr * w3 <= 1e-15
        # torque about the field direction vanishes
        t_lab = frame @ np.array([t1, t2, tr])
        assert abs(t_lab @ torque.field_direction) < 1e-14


def test_gravity_torque_tips_a_non_spinning_top_over():
    # tilted towards +x (phi = pi/2 puts the tip at (sin th, 0, cos th)): it falls further towards +x
    p = make_protocol(tilt=0.3, azimuth=math.pi / 2, spin=0.0, duration=0.2)
    df = simulate(p, rate_hz=100.0)
    assert df.theta_rad.iloc[-1] > 0.3 + 1e-3
    assert df.tip_x.iloc[-1] > df.tip_x.iloc[0]
    assert abs(df.tip_y).max() < 1e-12


def test_pivot_acceleration_pseudo_force_points_against_the_acceleration():
    # no gravity; pivot accelerates along +x, so the centre of mass is pushed towards -x
    p = make_protocol(tilt=0.3, azimuth=math.pi / 2, spin=0.0, gravity=None, acceleration=[2.0, 0.0, 0.0],
                      duration=0.2)
    df = simulate(p, rate_hz=100.0)
    assert df.tip_x.iloc[-1] < df.tip_x.iloc[0] - 1e-3


@pytest.mark.parametrize("spin", [60.0, -60.0])
def test_precession_sense_follows_the_spin(spin):
    p = make_protocol(tilt=0.4, spin=spin, duration=3.0)
    df = simulate(p, rate_hz=100.0)
    mean_rate = (df.phi_rad.iloc[-1] - df.phi_rad.iloc[0]) / 3.0
    assert np.sign(mean_rate) == np.sign(spin)


@pytest.mark.parametrize("tilt", [0.0, math.pi])
def test_exact_poles_stay_put(tilt):
    p = make_protocol(tilt=tilt, spin=30.0, duration=3.0)
    df = simulate(p, rate_hz=10.0)
    # tilt 0 is exact in floating point; pi is not (sin(pi) = 1.2e-16), so the hanging top sits 1e-16 off
    assert np.abs(df.theta_rad - tilt).max() <= (0.0 if tilt == 0.0 else 1e-10)
    # at a pole only phi + psi (tilt 0) or phi - psi (tilt pi) is defined: the rotation about z,
    # which advances by +-30 rad/s * 0.1 s per sample
    about_z = df.phi_rad + df.psi_rad if tilt == 0.0 else df.phi_rad - df.psi_rad
    step = np.angle(np.exp(1j * about_z.diff().dropna().to_numpy()))
    expected = np.angle(np.exp(1j * (3.0 if tilt == 0.0 else -3.0)))
    assert np.allclose(step, expected, atol=1e-9)


def test_sleeping_top_stability_follows_the_spin_threshold():
    # sleeping is stable when (Io w)^2 > 4 I M g h: here 4 I M g h = 3.924, so w > 3.30 rad/s
    fast = simulate(make_protocol(tilt=1e-6, spin=10.0, duration=20.0), rate_hz=10.0)
    slow = simulate(make_protocol(tilt=1e-6, spin=2.0, duration=20.0), rate_hz=10.0)
    assert fast.theta_rad.max() < 1e-5
    assert slow.theta_rad.max() > 0.1


def test_stiff_damping_picks_the_implicit_method_and_agrees():
    stiff = make_protocol(tilt=0.3, spin=60.0, duration=1.0, damping={"model": "paper", "gamma_per_s": 2000.0})
    assert choose_method(stiff) == "gyro-radau"
    assert choose_method(make_protocol()) == "gyro"
    for path in BUNDLED_PROTOCOLS:
        assert choose_method(load_protocol(path)) == "gyro"
    a, info = simulate(stiff, rate_hz=50.0, return_info=True)
    b = simulate(stiff, method="gyro", rate_hz=50.0)
    assert info.method == "gyro-radau"
    assert max_tip_error(a, b) < 1e-6


def test_acceleration_table_equals_constant_when_flat_and_restarts_at_knots():
    base = dict(tilt=0.3, spin=40.0, duration=2.0)
    const = make_protocol(acceleration=[1.0, 0.0, 0.0], **base)
    flat = replace(const, pivot=Pivot((), PivotAcceleration((0.0, 1.0, 2.0), ((1.0, 0, 0),) * 3)))
    ramp = replace(const, pivot=Pivot((), PivotAcceleration((0.0, 1.0), ((0.0, 0, 0), (1.0, 0, 0)))))
    a = simulate(const, method="gyro", rtol=1e-12, rate_hz=20.0)
    assert max_tip_error(a, simulate(flat, method="gyro", rtol=1e-12, rate_hz=20.0)) < 1e-11
    r = simulate(ramp, method="gyro", rtol=1e-12, rate_hz=20.0)
    assert np.isfinite(r.to_numpy()).all() and max_tip_error(a, r) > 1e-4


def test_bad_arguments_and_lost_norm_are_reported():
    p = make_protocol(spin=300.0, duration=2.0)
    with pytest.raises(ValueError, match="method"):
        simulate(p, method="Euler")
    with pytest.raises(ValueError, match="rtol"):
        simulate(p, rtol=2.0)
    with pytest.raises(SimulationError, match="quaternion norm drifted"):
        simulate(p, method="RK23", rtol=1e-2)
