"""Rig parameters with standard deviations: parsed, propagated into the predictions, combined in the fit.

The propagated error bars are checked two ways that share nothing with the code's finite
differences: a closed form (the fast-top mean precession ``Mgh / (Io Omega)`` has relative variance
``(sd_h/h)^2 + (sd_Io/Io)^2 + (sd_Omega/Omega)^2 - 2 rho ...``) and plain sampling of the parameters
through :func:`gyrorig.theory.predict`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gyrorig.plan_record import AdviceKind
from gyrorig.propagate import perturbed, predict_with_uncertainty
from gyrorig.protocols import ProtocolError, load_protocol, parse_protocol
from gyrorig.theory import predict

from conftest import PROTOCOL_DIR

AIR = PROTOCOL_DIR / "air-cushion-heavy-top.toml"


def _with_uncertainty(tmp_path: Path, correlation: float | None = None) -> Path:
    text = AIR.read_text()
    text = text.replace("inertia_axial_kg_m2 = 4.725e-4", "inertia_axial_kg_m2 = { value = 4.725e-4, sd = 0.05e-4 }")
    text = text.replace("com_distance_m = 0.07715", "com_distance_m = { value = 0.07715, sd = 0.0005 }")
    text = text.replace("spin_rate_rad_s = 502.65", "spin_rate_rad_s = { value = 502.65, sd = 3.0 }")
    if correlation is not None:
        text += ("\n[uncertainty]\ncorrelations = [[\"rig.inertia_axial_kg_m2\", \"launch.spin_rate_rad_s\", "
                 f"{correlation}]]\n")
    path = tmp_path / "air-uncertain.toml"
    path.write_text(text)
    return path


def test_uncertain_numbers_parse_to_their_values_with_sd(tmp_path):
    p = load_protocol(_with_uncertainty(tmp_path, correlation=-0.5))
    exact = load_protocol(AIR)
    assert p.rig == exact.rig and p.launch == exact.launch  # the values are the plain numbers
    u = p.uncertainty
    assert u.names == ("rig.com_distance_m", "rig.inertia_axial_kg_m2", "launch.spin_rate_rad_s")
    assert u.sd == (0.0005, 0.05e-4, 3.0)
    cov = u.covariance()
    assert cov[1, 2] == pytest.approx(-0.5 * 0.05e-4 * 3.0)
    assert not exact.uncertainty


def test_fast_top_precession_error_bar_matches_its_closed_form(tmp_path):
    for rho in (0.0, -0.5):
        p = load_protocol(_with_uncertainty(tmp_path, correlation=rho))
        pred = predict_with_uncertainty(p)
        q = pred.quantities["mean_precession_rate_rad_s"]
        # paper: Mgh / (Io Omega); Io and Omega correlated by rho
        rel = (0.0005 / 0.07715) ** 2 + (0.05e-4 / 4.725e-4) ** 2 + (3.0 / 502.65) ** 2 \
            + 2 * rho * (0.05e-4 / 4.725e-4) * (3.0 / 502.65)
        # central differences over +-1 sd of a product of powers: exact to second order, ~1e-4 here
        assert q.paper_sd == pytest.approx(abs(q.paper) * math.sqrt(rel), rel=2e-3)
        assert q.uncertainty.method == "linear"
        assert sum(q.uncertainty.by_parameter.values()) == pytest.approx(1.0)


def test_linearised_error_bars_agree_with_sampling(tmp_path):
    p = load_protocol(_with_uncertainty(tmp_path))
    pred = predict_with_uncertainty(p)
    rng = np.random.default_rng(7)
    u = p.uncertainty
    n = 400
    draws = rng.multivariate_normal(u.values, u.covariance(), size=n)
    keys = ("nutation_frequency_rad_s", "nutation_amplitude_rad", "precession_rate_fast_rad_s")
    samples = {k: [] for k in keys}
    for x in draws:
        pr = predict(perturbed(p, dict(zip(u.names, x))), simulate_damping=False)
        for k in keys:
            samples[k].append(pr.quantities[k].exact)
    for k in keys:
        sd = float(np.std(samples[k], ddof=1))
        # an SD from n draws is known to 1/sqrt(2n) = 3.5 %; 4 of those
        assert pred.quantities[k].exact_sd == pytest.approx(sd, rel=4 / math.sqrt(2 * n)), k


def test_a_prediction_without_uncertainty_is_unchanged():
    p = load_protocol(AIR)
    assert predict_with_uncertainty(p) == predict(p)


@pytest.mark.parametrize("rig_value, extra", [
    ("{ value = 4.725e-4, sd = -1e-5 }", ""),
    ("{ value = 4.725e-4, sd = 1e-5, unit = 'g' }", ""),
    ("{ value = 4.725e-4 }", ""),
    ("{ value = 'x', sd = 1e-5 }", ""),
    ("{ value = 4.725e-4, sd = 1e-5 }", "[uncertainty]\ncorrelations = [['rig.inertia_axial_kg_m2', 'rig.mass_kg', 0.5]]"),
    ("{ value = 4.725e-4, sd = 1e-5 }", "[uncertainty]\ncorrelations = [['rig.inertia_axial_kg_m2', "
                                        "'rig.inertia_axial_kg_m2', 0.5]]"),
    ("{ value = 4.725e-4, sd = 1e-5 }", "[uncertainty]\ncorrelations = 3"),
])
def test_bad_uncertainties_are_refused(tmp_path, rig_value, extra):
    text = AIR.read_text().replace("inertia_axial_kg_m2 = 4.725e-4", f"inertia_axial_kg_m2 = {rig_value}")
    path = tmp_path / "bad.toml"
    path.write_text(text + "\n" + extra + "\n")
    with pytest.raises(ProtocolError):
        load_protocol(path)


def test_contradictory_correlations_are_refused():
    import tomllib

    doc = tomllib.loads(AIR.read_text())
    for k in ("mass_kg", "com_distance_m", "inertia_axial_kg_m2"):
        doc["rig"][k] = {"value": doc["rig"][k], "sd": 0.01 * doc["rig"][k]}
    doc["uncertainty"] = {"correlations": [["rig.mass_kg", "rig.com_distance_m", 0.9],
                                           ["rig.mass_kg", "rig.inertia_axial_kg_m2", 0.9],
                                           ["rig.com_distance_m", "rig.inertia_axial_kg_m2", -0.9]]}
    with pytest.raises(ProtocolError):
        parse_protocol(doc)


def test_fit_counts_the_prediction_error(tmp_path):
    """fit.json gives the prediction's own standard error and the pull with both errors; when the
    prediction is far less certain than the measurement, the combined pull is ~ difference / prediction sd."""
    from gyrorig.fit import fit_angles

    from test_fit import _noisy

    p = load_protocol(_with_uncertainty(tmp_path))
    angles, _ = _noisy(p, 2.0)
    pred = predict_with_uncertainty(p, simulate_damping=False)
    r = fit_angles(angles, p, prediction=pred)
    q = r.quantities["nutation_frequency_rad_s"]
    assert q.exact_standard_error == pred.quantities["nutation_frequency_rad_s"].exact_sd
    diff = q.value - q.exact
    assert q.diff_exact_combined_se == pytest.approx(diff / math.hypot(q.standard_error, q.exact_standard_error))
    assert q.prediction_share > 0.99  # 0.6 rad/s from the rig against ~1e-3 from 2 s of record
    assert abs(q.diff_exact_combined_se) < 3
    assert q.as_dict()["exact_standard_error"] == q.exact_standard_error


def test_plan_says_which_parameter_limits_the_comparison_with_theory(tmp_path):
    """With Io known to 1 % and a camera good to 1e-6, every prediction's own error dwarfs the measurement's:
    the plan names the parameter with the largest share of each (Io here: the three uncertain inputs' shares
    follow from the closed form of the fast top, Io's relative sd being the largest)."""
    from gyrorig.plan import plan_experiment

    p = load_protocol(_with_uncertainty(tmp_path))
    plan = plan_experiment(p, duration_s=4.0, draws=0)
    limits = {a.values["quantity"]: a.values for a in plan.advice_of(AdviceKind.PREDICTION_LIMIT)}
    assert {"precession_rate_rad_s", "nutation_frequency_rad_s"} <= set(limits)
    for name, item in limits.items():
        q = plan.quantities[name]
        assert item["prediction_standard_error"] == q.prediction_standard_error > q.expected_standard_error
        assert item["parameter"] == "rig.inertia_axial_kg_m2"
        assert 0.5 < item["share"] <= 1.0
    assert not plan_experiment(load_protocol(AIR), duration_s=4.0, draws=0).advice_of(AdviceKind.PREDICTION_LIMIT)
