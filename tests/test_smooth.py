"""Kalman smoother: agreement with filterpy, gaps, gating, noise levels from the data."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from gyrorig.smooth import SmoothingError, kalman_smooth, prepare_measurements, smooth_angles


def _angles(n=600, rate=200.0, sigma=2e-4, rng=None, jitter=0.0):
    rng = rng or np.random.default_rng(1)
    t = np.arange(n) / rate + jitter * rng.uniform(0, 1 / rate, n)
    t.sort()
    theta = 0.6 + 0.02 * np.cos(60 * t)
    phi = 1.7 * t + 0.03 * np.sin(60 * t)
    df = pd.DataFrame({
        "frame": np.arange(n), "t_s": t,
        "theta_rad": theta + sigma * rng.normal(size=n),
        "phi_rad": np.angle(np.exp(1j * (phi + 1.5 * sigma * rng.normal(size=n)))),
        "theta_sigma_rad": sigma, "phi_sigma_rad": 1.5 * sigma, "theta_phi_corr": 0.0,
    })
    return df, theta, phi


def test_fast_engine_matches_filterpy_with_gaps_outliers_and_uneven_times():
    df, *_ = _angles(jitter=0.5)
    df.loc[100:120, ["theta_rad", "phi_rad"]] = np.nan  # a gap
    df.loc[300, "theta_rad"] += 0.05  # a spurious detection
    df["theta_phi_corr"] = 0.3
    m = prepare_measurements(df)
    a = kalman_smooth(m, 5.0, 20.0, engine="fast")
    b = kalman_smooth(m, 5.0, 20.0, engine="filterpy")
    assert np.array_equal(a[4], b[4])
    assert abs(a[0] - b[0]) < 1e-9 * abs(b[0])
    sd = np.sqrt(np.einsum("nii->ni", b[2]))
    assert np.max(np.abs(a[1] - b[1]) / sd) < 1e-9
    rel = np.abs(a[2] - b[2]) / np.sqrt(sd[:, :, None] ** 2 * sd[:, None, :] ** 2)
    # from the second frame on; at the first, the flat rate prior meets the first
    # measurement and both engines lose ~7 digits to cancellation
    assert np.max(rel[1:]) < 1e-9
    assert np.max(rel[0]) < 1e-6


def test_outlier_is_gated_and_marked_and_gap_is_marked():
    df, theta, _ = _angles()
    df.loc[100:110, ["theta_rad", "phi_rad"]] = np.nan
    df.loc[300, "theta_rad"] += 0.05
    r = smooth_angles(df)
    status = r.table.status
    assert status[300] == "outlier"
    assert (status[100:111] == "gap").all()
    assert r.n_outliers == 1 and r.n_resets == 0
    # the smoothed tilt ignores the outlier and bridges the gap
    assert abs(r.table.theta_rad[300] - theta[300]) < 5 * r.table.theta_sigma_rad[300]
    gap_err = np.abs(r.table.theta_rad[100:111] - theta[100:111]) / r.table.theta_sigma_rad[100:111]
    assert gap_err.max() < 5


def test_persistent_jump_restarts_instead_of_locking_out():
    df, *_ = _angles()
    df.loc[400:, "theta_rad"] += 0.1
    r = smooth_angles(df)
    assert r.n_resets == 1
    assert (r.table.status[403:] == "measured").sum() > 150


def test_noise_levels_from_the_data_give_calibrated_smoothed_errors():
    df, theta, phi = _angles(n=2000, rng=np.random.default_rng(7))
    r = smooth_angles(df)
    assert r.info["ml_converged"]
    pull_t = (r.table.theta_rad - theta) / r.table.theta_sigma_rad
    pull_p = (r.table.phi_rad - np.unwrap(phi)) / r.table.phi_sigma_rad
    assert abs(pull_t.std() - 1) < 0.15 and abs(pull_p.std() - 1) < 0.15
    # innovation consistency (2 expected; a sinusoid is not a random walk, so only roughly)
    assert 1.5 < r.nis_mean < 2.5
    # smoothing beats the raw measurement error
    assert r.table.theta_sigma_rad.median() < 2e-4


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.drop(columns=["phi_sigma_rad"]), "phi_sigma_rad"),
    (lambda d: d.assign(t_s=d.t_s[::-1].to_numpy()), "decreases"),
    (lambda d: d.assign(theta_sigma_rad=np.nan), "sigma"),
    (lambda d: d.assign(theta_rad=np.nan), "at least 3"),
])
def test_bad_tables_are_refused_by_name(mutate, match):
    df, *_ = _angles(n=50)
    with pytest.raises(SmoothingError, match=match):
        smooth_angles(mutate(df))


def test_azimuth_stays_continuous_across_a_gap_longer_than_half_a_turn():
    n, rate = 2000, 200.0
    t = np.arange(n) / rate
    phi = 2.5 * t  # a turn in 2.5 s
    df = pd.DataFrame({"frame": np.arange(n), "t_s": t, "theta_rad": 0.6, "phi_rad": np.angle(np.exp(1j * phi)),
                       "theta_sigma_rad": 1e-4, "phi_sigma_rad": 1e-4, "theta_phi_corr": 0.0})
    df.loc[(t > 2.0) & (t < 3.8), ["theta_rad", "phi_rad"]] = np.nan  # 1.8 s: 0.7 of a turn
    r = smooth_angles(df)
    assert r.n_resets == 0 and r.n_outliers == 0
    assert np.max(np.abs(r.table.phi_rad - phi)) < 1e-2
