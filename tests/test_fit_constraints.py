"""Fixed parameters and priors in the fit (``gyrorig fit --fix NAME=VALUE --prior NAME=VALUE+-SD``).

A Gaussian prior on one parameter is one more independent measurement of it: the parameter's
marginal must update as a scalar measurement does (precision-weighted mean, precisions add),
whatever the correlations with the rest.  That is a property of least squares, not of the code,
so it checks the code.  Angles come from the simulator plus Gaussian noise.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gyrorig.cli import main
from gyrorig.fit import Constraints, NoteKind, fit_angles
from gyrorig.fit.constraints import parse_fix, parse_prior
from gyrorig.protocols import load_protocol
from gyrorig.theory import predict

from conftest import PROTOCOL_DIR
from test_fit import _noisy


@pytest.fixture(scope="module")
def heavy():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    angles, truth = _noisy(p, 2.0, seed=3)
    pred = predict(p, simulate_damping=False)
    free = fit_angles(angles, p, prediction=pred, truth=truth)
    return p, angles, truth, pred, free


def test_a_prior_updates_the_parameter_like_one_more_measurement(heavy):
    p, angles, truth, pred, free = heavy
    name = "precession_rate_rad_s"
    v, se = free.params[name]
    # a prior one standard error above the fit, as precise as the fit: the posterior sits half-way, with
    # the standard error / sqrt(2) (exact for a linear model; the fit is linear to ~1e-3 of an error here)
    mean, sd = v + se, se
    r = fit_angles(angles, p, prediction=pred, truth=truth, constraints=Constraints(priors=((name, mean, sd),)))
    w = 1 / se**2 + 1 / sd**2
    v_post, se_post = r.params[name]
    assert v_post == pytest.approx((v / se**2 + mean / sd**2) / w, abs=0.02 * se)
    assert se_post == pytest.approx(1 / math.sqrt(w), rel=0.02)
    assert r.dof == free.dof + 1
    assert r.spec == free.spec
    assert r.notes_of(NoteKind.CONSTRAINED)


def test_a_vague_prior_changes_nothing(heavy):
    p, angles, truth, pred, free = heavy
    name = "nutation_frequency_rad_s"
    v, se = free.params[name]
    r = fit_angles(angles, p, prediction=pred, constraints=Constraints(priors=((name, v + 3 * se, 1e6 * se),)))
    for k, (val, s) in free.params.items():
        assert r.params[k][0] == pytest.approx(val, abs=1e-3 * s + 1e-15), k
        assert r.params[k][1] == pytest.approx(s, rel=1e-3), k


@pytest.mark.parametrize("kind", ["prior", "fix"])
def test_a_constraint_that_disagrees_with_the_record_is_flagged_and_one_that_agrees_is_not(heavy, kind):
    """A prior 10 of the record's standard errors away (as precise as the record: 7 combined), or a value fixed
    there, is a conflict; one 1 standard error away is not (|z| = 0.7 and 1, below the 3 used)."""
    p, angles, truth, pred, free = heavy
    name = "precession_rate_rad_s"
    v, se = free.params[name]
    for offset, flagged in ((10.0, True), (1.0, False)):
        c = (Constraints(priors=((name, v + offset * se, se),)) if kind == "prior"
             else Constraints(fixed=((name, v + offset * se),)))
        r = fit_angles(angles, p, prediction=pred, constraints=c)
        assert [n.term for n in r.notes_of(NoteKind.PRIOR_CONFLICT)] == ([name] if flagged else [])


def test_a_fixed_parameter_keeps_its_value_and_the_rest_still_fit(heavy):
    p, angles, truth, pred, free = heavy
    name = "nutation_frequency_rad_s"
    exact = free.quantities[name].truth  # the model's own value on the noiseless truth
    r = fit_angles(angles, p, prediction=pred, truth=truth, constraints=Constraints(fixed=((name, exact),)))
    assert r.params[name] == (exact, 0.0)
    assert r.dof == free.dof + 1
    i = list(r.params).index(name)
    assert np.all(r.covariance[i] == 0) and np.all(r.covariance[:, i] == 0)
    # the other quantities still agree with the truth within errors (4 sigma: a handful of quantities)
    for k in ("precession_rate_rad_s", "nutation_amplitude_rad"):
        q = r.quantities[k]
        assert abs(q.value - q.truth) < 4 * q.standard_error, k
    # fixing a parameter at its true value removes its uncertainty from the correlated ones
    k = "nutation_amplitude_rad"
    assert r.quantities[k].standard_error <= free.quantities[k].standard_error * (1 + 1e-6)


def test_constraints_in_fit_json_and_unused_names(heavy):
    p, angles, _, pred, _ = heavy
    c = Constraints(fixed=(("tilt_growth_rate_per_s", 0.0),), priors=(("precession_rate_rad_s", 0.9, 0.5),))
    r = fit_angles(angles, p, prediction=pred, constraints=c)
    doc = json.loads(json.dumps(r.summary()))["constraints"]
    assert doc["fixed"] == {"tilt_growth_rate_per_s": 0.0}
    assert doc["priors"] == {"precession_rate_rad_s": {"mean": 0.9, "sd": 0.5}}
    assert doc["unused"] == ["tilt_growth_rate_per_s"]  # an undamped model has no tilt growth


@pytest.mark.parametrize("text", ["nutation_frequency_rad_s", "bogus_rad=1", "nutation_frequency_rad_s=abc",
                                  "nutation_frequency_rad_s=nan"])
def test_bad_fix_is_refused(text):
    with pytest.raises(ValueError):
        parse_fix(text)


@pytest.mark.parametrize("text", ["precession_rate_rad_s=1", "precession_rate_rad_s=1+-0", "precession_rate_rad_s=1+-x",
                                  "bogus=1+-1", "precession_rate_rad_s=1+--2"])
def test_bad_prior_is_refused(text):
    with pytest.raises(ValueError):
        parse_prior(text)


def test_prior_forms_and_duplicates():
    assert parse_prior("precession_rate_rad_s = 0.86 +- 0.01") == ("precession_rate_rad_s", 0.86, 0.01)
    assert parse_prior("precession_rate_rad_s=0.86±0.01") == ("precession_rate_rad_s", 0.86, 0.01)
    assert parse_fix("azimuth_offset_2_rad=0.5") == ("azimuth_offset_2_rad", 0.5)
    with pytest.raises(ValueError):
        Constraints.from_options(["precession_rate_rad_s=1"], ["precession_rate_rad_s=1+-1"])


def test_cli_fit_with_fix_and_prior(tmp_path, heavy):
    p, angles, *_ = heavy
    csv = tmp_path / "angles.csv"
    angles.to_csv(csv, index=False)
    proto = str(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    out = tmp_path / "fit"
    code = main(["fit", str(csv), "--protocol", proto, "--out", str(out), "--fix", "nutation_frequency_rad_s=59.5",
                 "--prior", "precession_rate_rad_s=0.86+-0.05"])
    assert code == 0
    doc = json.loads((out / "fit.json").read_text())
    assert doc["parameters"]["nutation_frequency_rad_s"] == {"value": 59.5, "standard_error": 0.0}
    assert doc["constraints"]["priors"]["precession_rate_rad_s"]["sd"] == 0.05
    bad = tmp_path / "bad"
    assert main(["fit", str(csv), "--protocol", proto, "--out", str(bad), "--fix", "no_such_rad=1"]) == 2
    assert not bad.exists()


def test_a_fit_that_finds_no_minimum_is_a_failed_computation_not_bad_input(tmp_path, monkeypatch, heavy):
    """Issue 23: a non-converging fit exited 2 (bad input); it is a failed computation: exit 3."""
    import gyrorig.fit.fitting as fitting
    from gyrorig.fit import FitConvergenceError

    def no_minimum(*args, **kwargs):
        raise FitConvergenceError("the fit did not converge: test")

    monkeypatch.setattr(fitting, "fit_model", no_minimum)
    _, angles, *_ = heavy
    csv = tmp_path / "angles.csv"
    angles.to_csv(csv, index=False)
    out = tmp_path / "fit"
    assert main(["fit", str(csv), "--protocol", str(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), "--out",
                 str(out)]) == 3
    assert not out.exists()
