"""Fits against theory: truth recovered within errors, scene-chosen models, honest refusals.

Synthetic angles here come from the simulator (plus Gaussian noise of known sigma);
never from the formulas being tested.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from gyrorig.fit import FitError, fit_angles, model_for_scene
from gyrorig.physics.exact import exact_solution
from gyrorig.physics.simulate import simulate
from gyrorig.protocols import load_protocol
from gyrorig.theory import predict

from conftest import PROTOCOL_DIR, make_protocol


def _noisy(protocol, duration, rate=200.0, sigma=2e-4, seed=0):
    df = simulate(protocol, duration_s=duration, rate_hz=rate)
    rng = np.random.default_rng(seed)
    n = len(df)
    sph = sigma / np.maximum(np.sin(df.theta_rad.to_numpy()), 0.05)
    angles = pd.DataFrame({
        "frame": np.arange(n), "t_s": df.t_s,
        "theta_rad": df.theta_rad + sigma * rng.normal(size=n),
        "phi_rad": np.angle(np.exp(1j * (df.phi_rad + sph * rng.normal(size=n)))),
        "theta_sigma_rad": sigma, "phi_sigma_rad": sph, "theta_phi_corr": 0.0,
    })
    return angles, df


def test_heavy_top_recovers_exact_values_within_errors():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    angles, truth = _noisy(p, 4.0)
    pred = predict(p, simulate_damping=False)
    r = fit_angles(angles, p, prediction=pred, truth=truth)
    assert not r.spec.damped and not r.spec.fit_axis and r.spec.harmonics >= 2
    assert r.errors == "formal"
    assert 0.9 < r.chi2_red < 1.1
    sol = exact_solution(p)
    exact = {"precession_rate_rad_s": sol.mean_precession_rate_rad_s,
             "nutation_frequency_rad_s": sol.nutation_frequency_rad_s,
             "nutation_amplitude_rad": 0.5 * (sol.tilt_range_rad[1] - sol.tilt_range_rad[0])}
    for k, v in exact.items():
        q = r.quantities[k]
        assert q.status == "determined"
        assert abs(q.value - v) < 4 * q.standard_error, k
        # the model is exact for an undamped top (to its harmonics): truth gives the exact value
        assert abs(q.truth - v) < 0.2 * q.standard_error, k
    # an undamped scene fits no tau and no equilibrium
    assert "tilt_time_constant_s" not in r.quantities and "equilibrium_tilt_rad" not in r.quantities
    # the paper's eq. for the mean precession is 1.9 % off: many standard errors here
    assert abs(r.quantities["precession_rate_rad_s"].diff_paper_se) > 10


def test_nutation_the_camera_cannot_resolve_is_undetermined_not_a_number():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    angles, _ = _noisy(p, 4.0, rate=15.0)  # Nyquist 7.5 Hz < nutation 9.5 Hz
    r = fit_angles(angles, p, prediction=predict(p, simulate_damping=False))
    for k in ("nutation_frequency_rad_s", "nutation_amplitude_rad"):
        assert r.quantities[k].status == "undetermined" and r.quantities[k].value is None
        assert "cannot resolve" in r.quantities[k].reason
    assert r.quantities["precession_rate_rad_s"].status == "determined"


def test_no_visible_nutation_is_undetermined_by_the_data():
    p = make_protocol(tilt=0.5, spin=200.0, duration=3.0)
    # launched at the exact steady precession: no nutation to see
    from gyrorig.theory import steady_launch
    p = steady_launch(p)
    angles, _ = _noisy(p, 3.0)
    r = fit_angles(angles, p)
    assert r.quantities["nutation_amplitude_rad"].status == "undetermined"
    assert "no significant nutation" in r.quantities["nutation_amplitude_rad"].reason


def test_damped_top_tilt_rate_recovered_and_tau_reported():
    p = load_protocol(PROTOCOL_DIR / "eddy-damped-top-b2.toml")
    angles, truth = _noisy(p, 6.0, sigma=5e-5)
    pred = predict(p)
    r = fit_angles(angles, p, prediction=pred, truth=truth)
    assert r.spec.damped
    lam = r.quantities["tilt_growth_rate_per_s"]
    assert lam.status == "determined" and abs(lam.pull) < 4
    # grows, as the simulator says (the paper's eq. 25a predicts decay)
    assert lam.value > 0 and lam.paper < 0
    assert r.quantities["tilt_time_constant_s"].status == "determined"


def test_free_top_fits_the_axis_and_no_nutation():
    p = make_protocol(tilt=0.3, spin=60.0, gravity=None, tilt_rate=1.0, precession_rate=2.0, duration=2.0)
    angles, _ = _noisy(p, 2.0)
    pred = predict(p)
    scene = model_for_scene(p, pred)
    assert scene.spec.fit_axis and not scene.nutation_expected
    r = fit_angles(angles, p, prediction=pred)
    q = r.quantities["precession_rate_rad_s"]
    assert abs(q.value - pred["precession_rate_rad_s"]["exact"]) < 4 * q.standard_error
    assert "nutation_frequency_rad_s" not in r.quantities


def test_accelerated_pivot_equilibrium_leans_towards_acceleration():
    p = make_protocol(tilt=0.3, spin=60.0, acceleration=[1.0, 0.0, 0.0], duration=4.0)
    angles, _ = _noisy(p, 4.0)
    pred = predict(p, simulate_damping=False)
    r = fit_angles(angles, p, prediction=pred)
    th, az = r.quantities["equilibrium_tilt_rad"], r.quantities["equilibrium_azimuth_rad"]
    assert abs(th.value - np.arctan(1.0 / 9.81)) < 4 * th.standard_error
    assert abs(np.angle(np.exp(1j * (az.value - az.exact)))) < 4 * az.standard_error
    assert abs(az.diff_paper_se) > 10  # eq. 31 leans the wrong way


def test_gap_longer_than_half_a_precession_period_splits_the_azimuth():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    angles, _ = _noisy(p, 6.0)
    angles.loc[(angles.t_s > 1.0) & (angles.t_s < 3.5), ["theta_rad", "phi_rad"]] = np.nan
    r = fit_angles(angles, p, prediction=predict(p, simulate_damping=False))
    assert r.spec.segments == 2
    assert any("split the azimuth into 2 segments" in n for n in r.notes)
    q = r.quantities["precession_rate_rad_s"]
    assert abs(q.value - exact_solution(p).mean_precession_rate_rad_s) < 4 * q.standard_error


def test_bad_input_is_refused_by_name():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    angles, _ = _noisy(p, 0.2)
    with pytest.raises(FitError, match="phi_sigma_rad"):
        fit_angles(angles.drop(columns=["phi_sigma_rad"]), p)
    with pytest.raises(FitError, match="at least 10"):
        fit_angles(angles.iloc[:5], p)


@pytest.mark.parametrize("spec_kw", [dict(harmonics=3), dict(fit_axis=True, damped=True, harmonics=3, segments=2,
                                                              persistent=True, nutation_origin_s=-1.0),
                                      dict(fit_axis=True, damped=True, harmonics=2, persistent=True, transient=True,
                                           transient_min_rate_per_s=5.0, sidebands=True, precession_second=True,
                                           nutation_origin_s=-1.0),
                                      dict(fit_axis=True)])
def test_analytic_jacobian_matches_finite_differences(spec_kw):
    from scipy.optimize._numdiff import approx_derivative

    from gyrorig.fit import FitData, ModelSpec, _Model, _residual_fn

    spec = ModelSpec(**spec_kw)
    m = _Model(spec)
    rng = np.random.default_rng(0)
    p = rng.normal(size=len(m.names)) * 0.1
    ix = m.index
    p[ix["log_cone_angle"]], p[ix["precession_rate_rad_s"]] = np.log(0.5), 1.7
    for name, v in (("nutation_frequency_rad_s", 59.0), ("persistent_frequency_rad_s", 59.5), ("axis_tilt_rad", 0.05),
                    ("axis_azimuth_rad", 1.5), ("transient_rate_logit", -1.0)):
        if name in ix:
            p[ix[name]] = v
    n = 400
    t = np.arange(n) / 200.0
    seg = (t > 1.0).astype(int) if spec.segments == 2 else np.zeros(n, int)
    cov = np.zeros((n, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = 1e-8, 2e-8
    cov[:, 0, 1] = cov[:, 1, 0] = 3e-9
    _, white = _residual_fn(m, FitData(np.arange(n), t, np.full(n, 0.5), np.zeros(n), cov, seg, 1.0))
    jn = approx_derivative(white, p, method="3-point")
    ja = white.jac(p)
    assert np.max(np.abs(ja - jn).max(axis=0) / np.abs(jn).max(axis=0)) < 1e-5
