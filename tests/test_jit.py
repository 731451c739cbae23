"""The compiled integrator against its Python references."""

import numpy as np
import pytest

from conftest import make_protocol, max_tip_error
from gyrorig import simulate
from gyrorig.physics._jit import pack_torques, rhs_reference_check
from gyrorig.physics.simulate import make_rhs, initial_state
from gyrorig.physics.torques import torques_for

SCENES = {
    "gravity": dict(),
    "accel-table": dict(acceleration=[1.0, -2.0, 0.3]),
    "paper": dict(damping={"model": "paper", "gamma_per_s": 0.7}),
    "air-braking": dict(damping={"model": "air", "coefficient_N_m_s": 0.1, "axial_coefficient_N_m_s": 0.02,
                                 "spin_compensated": False}),
    "eddy-plain": dict(damping={"model": "eddy-field", "coefficient_N_m_s": 0.3, "field_direction": [0.2, 0.1, 1.0],
                                "spin_compensated": False}),
    "eddy-gyrostat": dict(frame_inertia=0.05, damping={"model": "eddy-field", "coefficient_N_m_s": 0.3,
                                                        "field_direction": [0, 0, 1], "spin_compensated": True}),
    "air-gyrostat": dict(frame_inertia=0.05, damping={"model": "air", "coefficient_N_m_s": 0.1,
                                                       "axial_coefficient_N_m_s": 0.02}),
    "free": dict(gravity=None),
}


@pytest.mark.parametrize("formulation", ["axis", "body"])
@pytest.mark.parametrize("name", list(SCENES))
def test_compiled_rhs_equals_python_rhs(name, formulation):
    p = make_protocol(tilt=0.4, tilt_rate=0.3, precession_rate=0.2, spin=30.0, **SCENES[name])
    rig = p.rig
    packed = pack_torques(torques_for(p), inertia_transverse=rig.inertia_transverse_kg_m2,
                          inertia_axial=rig.inertia_axial_kg_m2, frame_axial=rig.frame_axial_inertia_kg_m2,
                          body_frame=formulation == "body")
    rhs = make_rhs(p, formulation)
    rng = np.random.default_rng(3)
    y0 = initial_state(p, formulation)
    for _ in range(20):
        y = y0 + rng.normal(scale=0.5, size=y0.shape)
        t = rng.uniform(0, 3)
        assert np.allclose(rhs_reference_check(packed, t, y), rhs(t, y), rtol=1e-13, atol=1e-13)


def test_compiled_dop853_reproduces_scipy_dop853():
    p = make_protocol(tilt=0.3, tilt_rate=0.2, spin=50.0, duration=3.0,
                      damping={"model": "paper", "gamma_per_s": 0.3})
    t = np.linspace(0, 3, 301)
    a, ia = simulate(p, method="gyro", rtol=1e-9, t_eval_s=t, return_info=True)
    b, ib = simulate(p, method="gyro-scipy", rtol=1e-9, t_eval_s=t, return_info=True)
    assert ia.n_rhs_evaluations == ib.n_rhs_evaluations  # same steps, same rejections
    assert max_tip_error(a, b) < 1e-12


def test_compiled_integrator_restarts_at_acceleration_knots():
    from dataclasses import replace

    from gyrorig.protocols import Pivot, PivotAcceleration

    base = make_protocol(tilt=0.3, spin=40.0, duration=2.0)
    ramp = replace(base, pivot=Pivot((), PivotAcceleration((0.0, 0.7, 1.3), ((0, 0, 0), (2.0, 0, 0), (0, 1.0, 0)))))
    a = simulate(ramp, method="gyro", rtol=1e-12, rate_hz=50.0)
    b = simulate(ramp, method="gyro-scipy", rtol=1e-12, rate_hz=50.0)
    assert max_tip_error(a, b) < 1e-11


def test_compiled_integrator_reports_divergence():
    from gyrorig import SimulationError

    with pytest.raises(SimulationError, match="failed|diverged|norm drifted"):
        simulate(make_protocol(spin=300.0, duration=2.0), method="DOP853-jit", rtol=0.9, atol=10.0)


def test_dop853_tableau_is_the_published_one():
    """The project's copy of the DOP853 constants: order conditions, and the same numbers as SciPy's
    private copy where that module exists."""
    import importlib

    from gyrorig.physics import _dop853_tableau as t

    np.testing.assert_allclose(t.A[:t.N_STAGES].sum(axis=1), t.C[:t.N_STAGES], rtol=0, atol=1e-14)
    assert abs(t.B.sum() - 1.0) < 1e-14
    try:
        ref = importlib.import_module("scipy.integrate._ivp.dop853_coefficients")
    except ImportError:
        return
    for name in ("A", "B", "C", "E3", "E5", "D"):
        np.testing.assert_array_equal(getattr(t, name), getattr(ref, name))
