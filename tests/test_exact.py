"""The simulator against the exact (elliptic-function) solution of the undamped top.

Both formulations of the simulator (``gyro``: axis frame; ``DOP853``: textbook body
frame) are compared with the closed form over a sweep of launches.  At rtol 1e-12
the integrators reach ~1e-11 rad; the tolerance below leaves room for error growth
over the run, not for disagreement in the physics.
"""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from conftest import max_tip_error, make_protocol
from gyrorig import simulate
from gyrorig.physics import ExactSolutionError, exact_solution

#: agreement between a tight integration (rtol 1e-12) and the exact solution [rad]
TIP_TOL_RAD = 1e-9
RATE_TOL_RAD_S = 1e-8


def _steady_precession_rate(tilt, spin, inertia=1.0, inertia_axial=0.6, mgh=0.981):
    """Slow root of the exact steady-precession condition at finite tilt."""
    c = math.cos(tilt)
    f = lambda pd: pd * (inertia_axial * (spin + pd * c) - inertia * pd * c) - mgh  # noqa: E731
    return brentq(f, 1e-9, 1.0)


SWEEP = {
    "release-spin60": dict(tilt=0.2, spin=60.0),
    "release-spin300": dict(tilt=0.2, spin=300.0),
    "release-spin10-slow-top": dict(tilt=1.0, spin=10.0),
    "release-large-tilt": dict(tilt=2.0, spin=40.0),
    "kick-up-and-back": dict(tilt=0.5, tilt_rate=1.5, precession_rate=-2.0, spin=40.0),
    "kick-down-forward": dict(tilt=0.8, tilt_rate=-1.0, precession_rate=3.0, spin=25.0),
    "negative-spin": dict(tilt=0.6, precession_rate=0.4, spin=-50.0),
    "tilt-0-kicked": dict(tilt=0.0, tilt_rate=0.8, spin=30.0),
    "tilt-0-kicked-negative": dict(tilt=0.0, tilt_rate=-0.8, spin=30.0),
    "tilt-1e-12-kicked-back": dict(tilt=1e-12, tilt_rate=-0.5, spin=30.0),
    "sleeping": dict(tilt=0.0, spin=30.0),
    "hanging-near-pi": dict(tilt=math.pi - 0.3, tilt_rate=0.2, precession_rate=1.0, spin=20.0),
    "hanging-at-pi-kicked": dict(tilt=math.pi, tilt_rate=0.5, spin=20.0),
    "hanging-at-pi-rest": dict(tilt=math.pi, spin=20.0),
    "accelerated-pivot": dict(tilt=0.4, spin=50.0, acceleration=[3.0, -2.0, 0.5]),
    "gyrostat": dict(tilt=0.6, tilt_rate=0.3, precession_rate=0.5, spin=50.0, frame_inertia=0.05),
    "free-top": dict(tilt=0.5, tilt_rate=0.7, precession_rate=2.0, spin=40.0, gravity=None),
    "free-top-gyrostat": dict(tilt=0.5, precession_rate=2.0, spin=40.0, gravity=None, frame_inertia=0.05),
    "steady-precession": dict(tilt=0.5, precession_rate=_steady_precession_rate(0.5, 40.0), spin=40.0),
}


def _compare(df, ex):
    assert max_tip_error(df, ex) < TIP_TOL_RAD
    rate_err = np.hypot(df.omega_d_rad_s - ex.omega_d_rad_s, df.omega_q_rad_s - ex.omega_q_rad_s).max()
    assert rate_err < RATE_TOL_RAD_S
    assert np.abs(df.omega_o_rad_s - ex.omega_o_rad_s).max() < RATE_TOL_RAD_S
    # psi agrees modulo the representation at a pole
    dpsi = np.angle(np.exp(1j * (df.psi_rad - ex.psi_rad).to_numpy()))
    dphi = np.angle(np.exp(1j * (df.phi_rad - ex.phi_rad).to_numpy()))
    off_pole = np.sin(df.theta_rad.to_numpy()) > 1e-6
    assert np.abs(dphi[off_pole]).max(initial=0.0) < 1e-7
    assert np.abs(dpsi[off_pole]).max(initial=0.0) < 1e-7
    if "psi_frame_rad" in df:
        dpf = np.angle(np.exp(1j * (df.psi_frame_rad - ex.psi_frame_rad).to_numpy()))
        assert np.abs(dpf[off_pole]).max(initial=0.0) < 1e-7


@pytest.mark.parametrize("name", list(SWEEP))
def test_gyro_method_matches_exact_solution(name):
    p = make_protocol(duration=5.0, **SWEEP[name])
    t = np.linspace(0.0, 5.0, 501)
    ex = exact_solution(p, t)
    df = simulate(p, method="gyro", rtol=1e-12, atol=1e-14, t_eval_s=t)
    _compare(df, ex)


@pytest.mark.parametrize("name", ["release-spin60", "kick-up-and-back", "tilt-0-kicked", "hanging-at-pi-kicked",
                                  "gyrostat", "free-top"])
def test_body_frame_dop853_matches_exact_solution(name):
    p = make_protocol(duration=2.0, **SWEEP[name])
    t = np.linspace(0.0, 2.0, 201)
    ex = exact_solution(p, t)
    df = simulate(p, method="DOP853", rtol=1e-12, atol=1e-14, t_eval_s=t)
    _compare(df, ex)


def test_exact_solution_kinds_and_derived_quantities():
    sol = exact_solution(make_protocol(**SWEEP["steady-precession"]))
    assert sol.kind == "steady"
    assert sol.mean_precession_rate_rad_s == pytest.approx(SWEEP["steady-precession"]["precession_rate"], rel=1e-12)
    assert exact_solution(make_protocol(**SWEEP["sleeping"])).kind == "steady"
    assert exact_solution(make_protocol(**SWEEP["free-top"])).kind == "free"
    rel = exact_solution(make_protocol(**SWEEP["release-spin60"]))
    assert rel.kind == "nutating"
    # released from rest: the launch tilt is the top turning point
    assert rel.tilt_range_rad[0] == pytest.approx(0.2, abs=1e-14)


def test_exact_nutation_period_and_mean_precession_against_simulation():
    p = make_protocol(tilt=0.7, spin=25.0, duration=20.0)
    sol = exact_solution(p)
    period = 2 * math.pi / sol.nutation_frequency_rad_s
    t = np.linspace(0.0, 10 * period, 20001)
    df = simulate(p, method="gyro", rtol=1e-12, t_eval_s=t)
    # after an integer number of nutation periods the tilt returns to its launch value
    assert df.theta_rad.iloc[-1] == pytest.approx(0.7, abs=1e-9)
    mean_rate = (df.phi_rad.iloc[-1] - df.phi_rad.iloc[0]) / t[-1]
    assert mean_rate == pytest.approx(sol.mean_precession_rate_rad_s, rel=1e-9)


def test_no_exact_solution_for_damped_or_time_dependent_scenes():
    with pytest.raises(ExactSolutionError, match="damped"):
        exact_solution(make_protocol(damping={"model": "paper", "gamma_per_s": 0.5}))


@pytest.mark.parametrize("tilt", [1e-7, math.pi - 1e-7], ids=["upright", "hanging"])
def test_a_launch_within_a_millionth_of_a_radian_of_the_vertical_keeps_its_tilt(tilt):
    # cos(1e-7) = 1 - 5e-15 holds the tilt to 2 % only: the solution must not be built on it
    p = make_protocol(tilt=tilt, spin=60.0, duration=2.0)
    sol = exact_solution(p)
    off = min(tilt, math.pi - tilt)
    lo, hi = sol.tilt_range_rad
    # released from rest: the launch tilt is a turning point, to the tilt's own rounding
    assert min(abs(lo - tilt), abs(hi - tilt)) < 1e-9 * off
    assert hi - lo > 1e-3 * off
    period = 2 * math.pi / sol.nutation_frequency_rad_s
    t = np.linspace(0.0, 20 * period, 4001)
    ex = sol.evaluate(t)
    df = simulate(p, method="gyro", rtol=1e-12, atol=1e-14, t_eval_s=t)
    # the integrator's atol (1e-14 on unit vectors) is 1e-7 of this tilt; 1e-5 leaves room for its growth
    assert max_tip_error(df, ex) < 1e-5 * off
    advance = np.unwrap(df.phi_rad.to_numpy())
    assert (advance[-1] - advance[0]) / t[-1] == pytest.approx(sol.mean_precession_rate_rad_s, rel=1e-6)
