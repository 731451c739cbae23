"""Planning: camera checks, expected errors from the Cramer-Rao bound, advice, sweeps."""

from __future__ import annotations

import copy
import json
from dataclasses import replace

import numpy as np
import pytest

from gyrorig.cli import main
from gyrorig.fit import FitTerms
from gyrorig.plan import parse_sweep, plan_experiment, sweep
from gyrorig.plan_record import AdviceKind, DampingAssessment
from gyrorig.protocols import load_protocol, parse_protocol

from _stats import sd_ratio_band
from conftest import PROTOCOL_DIR


def _with_camera(p, **kw):
    return replace(p, extra={**p.extra, "camera": dict(p.extra["camera"], **kw)})


def test_plan_of_the_air_cushion_rig():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    plan = plan_experiment(p, duration_s=4.0, simulate_damping=False)
    cam = plan.camera
    assert 10 < cam["radius_px"] < 30 and not cam["saturates"]
    assert 0 < cam["sigma_px"] < 0.05
    assert cam["frames_per_nutation_period"] == pytest.approx(200 / 9.4714, rel=1e-3)
    q = plan.quantities
    for name in ("precession_rate_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad"):
        assert q[name].resolvable and 0 < q[name].expected_standard_error < 1e-3 * abs(q[name].simulated)
    # the simulated value, not a formula, is what the camera would see
    assert q["precession_rate_rad_s"].simulated == pytest.approx(q["precession_rate_rad_s"].predicted_exact, rel=1e-8)
    assert "tilt_growth_rate_per_s" not in q  # undamped
    assert cam["resolves_nutation"] and cam["minimum_fps"] == pytest.approx(4 * 9.4714, rel=1e-3)
    # noisy records of this length, fitted in full, converge where the linearised fit puts them
    draws = plan.recording["noisy_draws"]
    assert draws["draws"] == 8 and draws["failed"] == 0 and draws["ok"] and plan.recording["linear_regime"]
    assert set(draws["rms_departure_se"]) == {"precession_rate_rad_s", "nutation_frequency_rad_s",
                                              "nutation_amplitude_rad", "cone_angle_rad"}
    assert max(draws["rms_departure_se"].values()) < 0.01
    # the undamped model describes the simulated record (to its harmonics)
    assert plan.recording["model_misfit"]["chi2_per_dof"] < 0.01
    # reproducible: the same seed gives the same draws
    again = plan_experiment(p, duration_s=4.0, simulate_damping=False, rng=np.random.default_rng(0))
    assert again.recording["noisy_draws"]["rms_departure_se"] == draws["rms_departure_se"]


def test_noisy_draws_see_a_fit_that_is_not_linear_where_the_noiseless_check_passes():
    from types import SimpleNamespace

    from gyrorig.camera import with_image_size
    from gyrorig.fit import fit_angles
    from gyrorig.expectation import expected_record
    from gyrorig.plan import noisy_draws
    from gyrorig.theory import predict

    # 1 s of the air-cushion rig with 3000x the camera's per-frame noise (~8e-3 rad against a
    # 0.02 rad nutation): the noiseless fit leaves 0.2 rad of nutation phase uncertain (below the
    # 0.3 rad limit), yet in noisy records the fit can lock onto another frequency
    p = with_image_size(load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), 640, 480)
    pred = predict(p, simulate_damping=False)
    ex = expected_record(p, 1.0)
    k = 3000.0
    angles = ex.angles.assign(theta_sigma_rad=ex.angles.theta_sigma_rad * k, phi_sigma_rad=ex.angles.phi_sigma_rad * k)
    ex = SimpleNamespace(**{**vars(ex), "cov": ex.cov * k * k, "angles": angles})
    fit = fit_angles(angles, p, prediction=pred, check_residuals=False, terms="noiseless")
    assert fit.linear_regime and fit.spec.harmonics >= 1
    checks = noisy_draws(p, ex, fit, pred, 8, np.random.default_rng(1))
    assert not checks["ok"] and "nutation_frequency_rad_s" in checks["nonlinear"]
    assert checks["rms_departure_se"]["nutation_frequency_rad_s"] > 10
    assert checks["rms_departure_se"]["precession_rate_rad_s"] < 0.3  # the precession is still linear
    with pytest.raises(ValueError, match="--draws"):
        plan_experiment(p, duration_s=1.0, draws=-1)


def test_slow_camera_cannot_resolve_nutation_and_says_so():
    p = _with_camera(load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), fps=15.0)
    plan = plan_experiment(p, duration_s=6.0, simulate_damping=False)
    q = plan.quantities["nutation_amplitude_rad"]
    assert not q.resolvable and q.reason_kind == "camera-too-slow"
    assert not plan.camera["resolves_nutation"]
    assert plan.quantities["precession_rate_rad_s"].resolvable
    assert [a.problem for a in plan.advice_of(AdviceKind.FRAME_RATE)] == [True]


def test_expected_error_shrinks_with_record_length_as_t_to_the_three_halves():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    a = plan_experiment(p, duration_s=4.0, simulate_damping=False).quantities["precession_rate_rad_s"]
    b = plan_experiment(p, duration_s=16.0, simulate_damping=False).quantities["precession_rate_rad_s"]
    ratio = a.expected_standard_error / b.expected_standard_error
    assert ratio == pytest.approx(4**1.5, rel=0.2)


def test_no_camera_means_no_resolution_claims():
    p = load_protocol(PROTOCOL_DIR / "free-top.toml")
    plan = plan_experiment(p)
    assert plan.camera is None and [a.kind for a in plan.advice] == [AdviceKind.NO_CAMERA]
    assert not plan.quantities and not plan.measures_nothing


def test_eddy_field_realisation_is_flagged_as_unable_to_test_eq_25a():
    p = load_protocol(PROTOCOL_DIR / "eddy-damped-top.toml")
    plan = plan_experiment(p, duration_s=3.0)
    assert plan.damping == DampingAssessment(("eddy-field",), tests_tilt_drift=False)
    b2 = plan_experiment(load_protocol(PROTOCOL_DIR / "eddy-damped-top-b2.toml"), duration_s=2.0, draws=0)
    assert b2.damping == DampingAssessment(("magnet-in-ball",), tests_tilt_drift=True)


def test_sweep_parsing_and_a_small_sweep(tmp_path, capsys):
    with pytest.raises(ValueError, match="KEY=START:STOP:N"):
        parse_sweep("camera.fps=100")
    key, values = parse_sweep("camera.fps=100:200:2")
    assert key == "camera.fps" and np.allclose(values, [100, 200])
    table = sweep(PROTOCOL_DIR / "air-cushion-heavy-top.toml", key, values, duration_s=3.0)
    e = table["precession_rate_rad_s_relative_error"].to_numpy()
    assert e[1] < e[0]  # more frames, smaller error
    with pytest.raises(ValueError, match="no key"):
        sweep(PROTOCOL_DIR / "air-cushion-heavy-top.toml", "camera.fsp", values)
    assert main(["plan", str(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), "--duration", "3", "--out",
                 str(tmp_path)]) == 0
    assert "expected errors" in capsys.readouterr().out
    doc = json.loads((tmp_path / "plan.json").read_text())
    direct = plan_experiment(load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), duration_s=3.0)
    for name, q in direct.quantities.items():
        assert doc["quantities"][name]["expected_standard_error"] == pytest.approx(q.expected_standard_error,
                                                                                  rel=1e-9), name
    assert FitTerms.from_dict(doc["fit_terms"]).harmonics == direct.fit_terms["harmonics"]
    assert [a["kind"] for a in doc["advice"]] == [str(a.kind) for a in direct.advice]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["air-cushion-heavy-top", "eddy-damped-top-b2", "accelerated-pivot"])
def test_plan_agrees_with_a_monte_carlo_of_the_full_chain(name):
    from gyrorig.montecarlo import monte_carlo_check

    p = load_protocol(PROTOCOL_DIR / f"{name}.toml")
    duration = 1.5
    plan = plan_experiment(p, duration_s=duration, simulate_damping=False)
    if not plan.recording["linear_regime"]:
        # too short for this scene's model (the accelerated pivot covers 0.4 precession periods
        # in 1.5 s, and its noisy records need a term the plan left out): the plan must say so and
        # name a length that is long enough; the check runs there
        assert not all(q.reliable for q in plan.quantities.values())
        assert plan.advice_of(AdviceKind.RECORD_TOO_SHORT)
        duration = plan.recording["length_for_linear_regime_s"]
        assert duration is not None and duration <= p.scene.duration_s
    table = monte_carlo_check(p, 12, duration_s=duration)
    print(f"{name}, {duration:g} s:\n{table.to_string()}")  # shown with -s
    assert table.attrs["failed_runs"] == 0 and table.attrs["linear_regime"]
    # the spread of n runs over the planned error lies in the chi distribution's band for n - 1 degrees
    # of freedom (12 runs: 0.29-1.91): above it the plan is optimistic, below it pessimistic (tau is
    # reported only in the runs whose rate is not consistent with zero, so its spread has no lower bound)
    for row in table.itertuples():
        if np.isfinite(row.sd_over_planned):
            lo, hi = sd_ratio_band(row.runs)
            assert row.sd_over_planned < hi, row
            assert row.quantity == "tilt_time_constant_s" or row.sd_over_planned > lo, row
    # every run is fitted with the model the plan chose, so the errors it reports are the plan's
    # (not for tau = 1/rate: it is reported only in the runs whose rate is not consistent with zero,
    # and its error, se(rate)/rate^2, is smaller in just those runs)
    for row in table.itertuples():
        if row.quantity != "tilt_time_constant_s":
            assert 0.8 < row.fit_se_over_planned < 1.25, row


def test_plan_writes_the_fit_terms_and_fit_uses_them(tmp_path, capsys):
    import json

    from gyrorig.expectation import expected_record

    proto = PROTOCOL_DIR / "eddy-damped-top-b2.toml"
    assert main(["plan", str(proto), "--duration", "1.5", "--out", str(tmp_path / "plan")]) == 0
    terms = json.loads((tmp_path / "plan" / "plan.json").read_text())["fit_terms"]
    assert terms["harmonics"] >= 1 and "1.5 s records" in terms["source"]
    # what the plan left out, with the chi-square change each would make on its noiseless record
    assert isinstance(terms["left_out_noncentrality"], dict)
    assert all(not terms.get(k) or k == "harmonics" for k in terms["left_out_noncentrality"])
    # a record of that length through that camera (simulated motion + the planned per-frame noise)
    ex = expected_record(load_protocol(proto), 1.5)
    e = np.einsum("nij,nj->ni", np.linalg.cholesky(ex.cov), np.random.default_rng(1).standard_normal((len(ex.theta), 2)))
    ex.angles.assign(theta_rad=ex.theta + e[:, 0], phi_rad=ex.phi + e[:, 1]).to_csv(tmp_path / "angles.csv", index=False)
    assert main(["fit", str(tmp_path / "angles.csv"), "--protocol", str(proto), "--out", str(tmp_path / "fit"),
                 "--terms", str(tmp_path / "plan" / "plan.json")]) == 0
    model = json.loads((tmp_path / "fit" / "fit.json").read_text())["model"]
    assert model["nutation_harmonics"] >= terms["harmonics"]
    for key, flag in (("transient", "transient"), ("elliptical_cone", "precession_second"),
                      ("nutation_sidebands", "sidebands"), ("persistent_oscillation", "persistent"),
                      ("third_order_nutation", "third_order"), ("nutation_shape_drift", "shape_drift")):
        assert model[key] or not terms[flag], key  # every planned term is in the fit
    assert "gyrorig plan of eddy-damped-top-b2" in model["terms_chosen"]
    capsys.readouterr()
    # a bad --terms names the problem and writes nothing
    assert main(["fit", str(tmp_path / "angles.csv"), "--protocol", str(proto), "--out", str(tmp_path / "bad"),
                 "--terms", str(tmp_path / "nope.json")]) == 2
    assert "--terms" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


@pytest.mark.slow
def test_plan_says_when_the_fit_model_does_not_describe_a_long_damped_record():
    """B2 over 20 s at 1440x1080: the tilt grows by 0.2 rad and the damped model's linear shape
    drift no longer describes the motion (noiseless chi-square ~4e6 for 8,000 degrees of
    freedom); the plan must say so, mark its errors not reliable and name a shorter record."""
    p = load_protocol(PROTOCOL_DIR / "eddy-damped-top-b2.toml")
    plan = plan_experiment(p, duration_s=20.0)
    mf = plan.recording["model_misfit"]
    assert mf["chi2_per_dof"] > 1.0
    assert 0 < mf["adequate_length_s"] < 20.0
    assert all(not q.reliable for q in plan.quantities.values())
    assert "noisy_draws" not in plan.recording
    assert [a.problem for a in plan.advice_of(AdviceKind.MODEL_MISFIT)] == [True]


def test_plan_respects_the_field_of_view(tmp_path):
    """Issue 23: a long lens planned 1e-7 rad per frame for a tip outside the image in every frame, and a
    sweep over the focal length promised better precision where the tip leaves the view.  Frames without the
    tip are gaps of the expected record; a camera that never sees it measures nothing (exit 3)."""
    import tomllib

    text = (PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
    base = tomllib.loads(text)
    assert base["camera"]["focal_length_mm"] < 14
    blind = copy.deepcopy(base)
    blind["camera"]["focal_length_mm"] = 300.0
    plan = plan_experiment(parse_protocol(blind), draws=0)
    assert plan.camera["marker_in_view_fraction"] == 0.0 and not plan.quantities
    assert plan.measures_nothing and plan.advice_of(AdviceKind.FIELD_OF_VIEW)[0].problem
    path = tmp_path / "long-lens.toml"
    path.write_text(text.replace(f"focal_length_mm = {base['camera']['focal_length_mm']}", "focal_length_mm = 300.0"))
    assert main(["plan", str(path), "--draws", "0"]) == 3
    table = sweep(PROTOCOL_DIR / "air-cushion-heavy-top.toml", "camera.focal_length_mm", np.array([8.0, 32.0]))
    wide, narrow = table.iloc[0], table.iloc[1]
    assert wide.marker_in_view_fraction == 1.0 and narrow.marker_in_view_fraction == 0.0
    assert np.isfinite(wide.precession_rate_rad_s_relative_error)
    assert np.isnan(narrow.precession_rate_rad_s_relative_error)


def test_a_camera_that_sees_the_tip_part_of_the_time_plans_with_noisy_draws():
    """A lens that loses the tip for part of each precession turn: the noisy draws are the same record with its
    gaps (they were drawn over every frame and the planner stopped on a shape mismatch)."""
    p = _with_camera(load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), focal_length_mm=13.0)
    plan = plan_experiment(p, duration_s=4.0, simulate_damping=False, rng=np.random.default_rng(0))
    assert 0.2 < plan.camera["marker_in_view_fraction"] < 0.95
    draws = plan.recording["noisy_draws"]
    assert draws["draws"] == 8 and draws["failed"] == 0 and draws["ok"]
    # the linearised fit of the same gapped record is where the full fits land (to far below one s.e.)
    assert max(draws["rms_departure_se"].values()) < 0.05
    for name in ("precession_rate_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad"):
        assert 0 < plan.quantities[name].expected_standard_error < np.inf


def test_a_steady_launch_is_planned_without_a_nutation():
    """A top launched in steady precession (the paper's eq. 20 tested directly) does not nutate: the plan gives the
    precession's error and no nutation figures (its zero nutation frequency stopped the planner)."""
    from gyrorig.theory import steady_launch

    p = steady_launch(load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml"))
    plan = plan_experiment(p, duration_s=4.0, simulate_damping=False, rng=np.random.default_rng(0))
    assert "frames_per_nutation_period" not in plan.camera and not plan.advice_of(AdviceKind.FRAME_RATE)
    q = plan.quantities
    assert q["precession_rate_rad_s"].resolvable and 0 < q["precession_rate_rad_s"].expected_standard_error < 1e-3
    assert not q["nutation_frequency_rad_s"].resolvable
    assert plan.recording["noisy_draws"]["ok"]


@pytest.mark.parametrize("tilt_deg", [0.0, 180.0])
def test_a_sleeping_top_measures_nothing_and_says_why(tmp_path, tilt_deg):
    """A top launched on the vertical stays there: its azimuth is not defined, there is nothing to measure, and the
    plan says so (exit 3) instead of stopping on a singular matrix."""
    import tomllib

    d = tomllib.loads((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text())
    d["launch"]["tilt_deg"] = tilt_deg
    plan = plan_experiment(parse_protocol(d), duration_s=2.0, draws=0)
    assert plan.measures_nothing
    (advice,) = plan.advice_of(AdviceKind.AZIMUTH_UNDEFINED)
    assert advice.problem and advice.values["frames_on_vertical"] == 401
    path = tmp_path / "sleeping.toml"
    path.write_text((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
                    .replace("tilt_deg = 45.0", f"tilt_deg = {tilt_deg}"))
    assert main(["plan", str(path), "--duration", "2", "--draws", "0"]) == 3


def test_a_tip_that_nods_past_the_limb_of_its_sphere_is_a_problem_of_the_camera_placement():
    """From 0.75 m above, the camera's rays graze the tip's sphere at 79 deg from the vertical: a release at 80 deg
    is read at a wrong tilt (the tracker flags it ``near-limb``), and the plan says so before anything is built."""
    import tomllib

    d = tomllib.loads((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text())
    assert not plan_experiment(parse_protocol(d), duration_s=2.0, draws=0).advice_of(AdviceKind.LIMB)
    d["launch"]["tilt_deg"] = 80.0
    plan = plan_experiment(parse_protocol(d), duration_s=2.0, draws=0)
    (advice,) = plan.advice_of(AdviceKind.LIMB)
    assert advice.problem and advice.values["limb_deg"] == pytest.approx(79.2, abs=0.1)
    assert 0.5 < plan.camera["near_limb_fraction"] <= plan.camera["marker_in_view_fraction"]
    assert plan.quantities and not any(q.reliable for q in plan.quantities.values())


def test_a_record_the_fit_model_cannot_converge_on_is_a_plan_without_errors(tmp_path):
    """The accelerated pivot at 20,000 rad/s precesses through 0.7 % of a turn in 1 s: the tilted axis, the cone and
    the rate are nearly degenerate and the noiseless fit finds no minimum.  The plan says so (exit 3) with its
    camera checks, where it stopped on the fit's error."""
    import tomllib

    text = (PROTOCOL_DIR / "accelerated-pivot.toml").read_text()
    d = tomllib.loads(text)
    spin = d["launch"]["spin_rate_rad_s"]
    d["launch"]["spin_rate_rad_s"] = 20000.0
    plan = plan_experiment(parse_protocol(d), duration_s=1.0, draws=0)
    assert plan.measures_nothing and plan.camera["marker_in_view_fraction"] == 1.0
    (advice,) = plan.advice_of(AdviceKind.FIT_FAILED)
    assert advice.problem and advice.values["length_s"] == 1.0
    path = tmp_path / "fast.toml"
    path.write_text(text.replace(f"spin_rate_rad_s = {spin}", "spin_rate_rad_s = 20000.0"))
    assert main(["plan", str(path), "--duration", "1", "--draws", "0"]) == 3


def test_plan_and_prediction_records_are_frozen_and_cross_processes():
    """The Monte Carlo hands the prediction to worker processes: the records pickle, and stay read-only."""
    import pickle

    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    plan = plan_experiment(p, duration_s=2.0, simulate_damping=False, draws=0)
    again = pickle.loads(pickle.dumps(plan))
    assert again.to_dict() == plan.to_dict()
    assert again.prediction.quantities["nutation_frequency_rad_s"] == plan.prediction.quantities[
        "nutation_frequency_rad_s"]
    with pytest.raises(TypeError):
        again.prediction.quantities["nutation_frequency_rad_s"] = None
    with pytest.raises(TypeError):
        again.advice[0].values["x"] = 1.0


def test_a_record_too_short_to_fit_a_table_not_level_says_how_long_one_is():
    """Under half a precession turn the fit does not look for a table not level (its circle would stand in for the
    cone and the precession rate): the plan says so and names the length where it does; a record 0.3 deg off level
    over the plan's length keeps the vertical, one over the advised length gets its lean."""
    import math

    from gyrorig.fit import fit_angles
    from test_fit import _leaning, _noisy

    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    short = plan_experiment(p, duration_s=1.5, simulate_damping=False, draws=0)
    [advice] = short.advice_of(AdviceKind.LEVEL)
    length = advice.values["length_s"]
    assert 1.5 < length and not plan_experiment(p, duration_s=1.05 * length, simulate_damping=False,
                                                 draws=0).advice_of(AdviceKind.LEVEL)
    for duration, leans in ((1.5, False), (1.05 * length, True)):
        angles, truth = _noisy(p, duration, rate=100.0, seed=5)
        assert fit_angles(_leaning(angles, truth, math.radians(0.3)), p).spec.lean is leans, duration
