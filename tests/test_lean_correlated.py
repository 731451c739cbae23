"""The lean's test on noise correlated over many frames (a codec's drifting errors, a texture passing behind the tip):
a level record gets no lean beyond the test's own rate, and a real lean is still found."""

import math

import numpy as np
import pandas as pd
import pytest

from gyrorig.fit import fit_angles
from gyrorig.fit.uncertainty import har_threshold
from gyrorig.geometry import angles_from_tip
from gyrorig.physics.simulate import simulate
from gyrorig.protocols import BUNDLED_PROTOCOL_DIR, load_protocol
from gyrorig.theory import predict

SIGMA_RAD = 2e-4


@pytest.fixture(scope="module")
def motion():
    """The bundled heavy top over 3 s at 200 frames/s (a phone record's length), and its prediction."""
    p = load_protocol(BUNDLED_PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    return p, simulate(p, duration_s=3.0, rate_hz=200.0), predict(p, simulate_damping=False)


def _drifting(truth: pd.DataFrame, seed: int, lean_deg: float = 0.0, drift: float = 0.3,
              rho: float = 0.97) -> pd.DataFrame:
    """The angles seen on a table leaning ``lean_deg`` towards azimuth 0, with white noise of :data:`SIGMA_RAD` plus
    a drift of ``drift`` times it correlated at ``rho`` from frame to frame (AR(1)), in each angle (phi's scaled by
    1 / sin(theta), as a pixel's error is)."""
    c, s = math.cos(math.radians(lean_deg)), math.sin(math.radians(lean_deg))
    tip = truth[["tip_x", "tip_y", "tip_z"]].to_numpy() @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]])
    theta, phi = angles_from_tip(tip / np.linalg.norm(tip, axis=1)[:, None])
    rng = np.random.default_rng(seed)
    n = len(truth)

    def noise() -> np.ndarray:
        slow = np.empty(n)
        slow[0] = rng.normal()
        for k in range(1, n):
            slow[k] = rho * slow[k - 1] + math.sqrt(1 - rho * rho) * rng.normal()
        return rng.normal(size=n) + drift * slow

    sph = SIGMA_RAD / np.maximum(np.sin(theta), 0.05)
    return pd.DataFrame({"frame": np.arange(n), "t_s": truth.t_s, "theta_rad": theta + SIGMA_RAD * noise(),
                         "phi_rad": np.angle(np.exp(1j * (phi + sph * noise()))), "theta_sigma_rad": SIGMA_RAD,
                         "phi_sigma_rad": sph, "theta_phi_corr": 0.0})


def test_noise_correlated_over_many_frames_lends_no_lean(motion):
    """40 level records: white noise plus a drift of 0.3 of it correlated at 0.97 from frame to frame (about 30
    frames; the lag-1 correlation of the sum 0.08, its long-run variance 7 times the white noise's).  The lean's gain
    divided by the lag-1 factor let a lean through in 7 of them (26 of 100 in another draw of the same noise); divided
    by the residuals' own long-run variance and tested on the F distribution for its estimate, none (0 and 2 of 100).
    At most 3: a rate of 2 % gives 3 or fewer in 40 with probability 0.99, one of 26 % with probability 0.003."""
    p, truth, pred = motion
    leans = sum(bool(fit_angles(_drifting(truth, seed), p, prediction=pred).spec.lean) for seed in range(40))
    assert leans <= 3


def test_a_lean_is_found_through_noise_correlated_over_many_frames(motion):
    """The same noise on a table leaning 0.01 deg (1.7e-4 rad, the white noise's size): the lean is found in at least 9
    of 10 records (all of 40 when tried) and measured within 4 of its errors."""
    p, truth, pred = motion
    found = 0
    for seed in range(10):
        fit = fit_angles(_drifting(truth, seed, lean_deg=0.01), p, prediction=pred)
        if fit.spec.lean:
            found += 1
            tilt = fit.quantities["equilibrium_tilt_rad"]
            assert abs(tilt.value - math.radians(0.01)) < 4 * tilt.standard_error
    assert found >= 9


@pytest.mark.parametrize("ddof, nu", [(1, 10), (2, 28), (2, 200)])
def test_the_threshold_for_an_estimated_long_run_variance_tends_to_chi_square(ddof, nu):
    """The threshold a statistic divided by an estimated long-run variance must pass is above chi-square's (the
    estimate's own scatter), and tends to it as the estimate's degrees of freedom grow (within 5 % at 200)."""
    from scipy.stats import chi2

    need = float(chi2.isf(1e-3, ddof))
    threshold = har_threshold(need, ddof, nu)
    assert threshold > need
    if nu >= 200:
        assert threshold < 1.05 * need
