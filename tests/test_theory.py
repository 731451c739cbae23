"""Each closed form of the paper against the simulator, in its regime, with sign checks.

The simulator is the judge; tolerances are the formulas' approximation errors,
stated per formula.  Where the paper's printed form has the wrong sign, the test
asserts that the validation *detects* it and that the corrected form agrees.
"""

import json
import math
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from _asserts import assert_plot
from conftest import PROTOCOL_DIR, make_protocol, max_tip_error
from gyrorig import SimulationError, exact_solution, load_protocol, simulate
from gyrorig import theory as th
from gyrorig.cli import main
from gyrorig.protocols import AirDamping, Pivot
from gyrorig.validation import (
    _sweep_accelerated,
    _sweep_damped,
    _sweep_free,
    _sweep_release,
    _sweep_steady_precession,
    summarize,
    validate,
)

KW = dict(inertia=1.0, inertia_axial=0.6, mgh=0.981)

#: approximation errors at fast-top ratio 30 (first order in 1/ratio), small tilt
FAST_TOP_RTOL_AT_30 = 0.03
#: small-tilt (theta^2) and fast-top error of the corrected steady and damped forms at ratio 30, tilt 0.1-0.3
CORRECTED_RTOL = 0.02


def test_steady_launch_finds_the_exact_finite_tilt_rates():
    for tilt in (0.05, 0.7, 2.0):
        p = make_protocol(tilt=tilt, spin=25.0)
        exact = th.exact_steady_precession_rates(25.0, tilt, **KW)
        for k, mode in enumerate(["slow", "fast"]):
            rate = th.steady_launch(p, mode=mode).launch.precession_rate_rad_s
            assert rate == pytest.approx(exact[k], rel=1e-9)
    # and the top launched at that rate does not nutate
    steady = th.steady_launch(make_protocol(tilt=0.7, spin=25.0, duration=3.0))
    df = simulate(steady, rtol=1e-12, rate_hz=100.0)
    assert np.ptp(df.theta_rad) < 1e-9


def test_a_horizontal_axis_has_one_steady_precession():
    """At 90 degrees the steady-precession condition is linear: one (slow) root, which the simulator's steady
    launch finds; no fast one (a tilt of 90 degrees in radians leaves a cosine of 6e-17, which gave 1e18 rad/s)."""
    tilt = math.radians(90.0)
    slow, fast = th.exact_steady_precession_rates(25.0, tilt, **KW)
    assert math.isnan(fast)
    p = make_protocol(tilt=tilt, spin=25.0)
    assert th.steady_launch(p, mode="slow").launch.precession_rate_rad_s == pytest.approx(slow, rel=1e-9)
    with pytest.raises(ValueError):
        th.steady_launch(p, mode="fast")


@pytest.mark.parametrize("tilt", [0.0, math.pi])
def test_a_damped_top_launched_on_the_vertical_has_no_tilt_growth_to_predict(tilt):
    """Upright or hanging, a damped top launched on the vertical stays there (the simulator says so): the prediction
    has no simulated growth rate, where the hanging top's steady-precession search stopped on a bracket."""
    p = make_protocol(tilt=tilt, spin=40.0, duration=2.0, frame_inertia=0.05,
                      damping={"model": "eddy-field", "coefficient_N_m_s": 0.3, "field_direction": [0, 0, 1],
                               "spin_compensated": True})
    df = simulate(p, rtol=1e-12, rate_hz=50.0)
    assert np.ptp(df.theta_rad) < 1e-9
    growth = th.predict(p).get("tilt_growth_rate_per_s")
    assert math.isnan(growth.exact) and growth.paper is not None


def test_a_damped_top_too_slow_to_precess_steadily_is_still_predicted():
    """Below the spin that allows a steady precession at the launch tilt the damped prediction has no simulated
    growth (no steady launch to start from), and the rest of the prediction stands (it was refused whole)."""
    p = make_protocol(tilt=0.7, spin=1.0, duration=2.0, frame_inertia=0.05,
                      damping={"model": "eddy-field", "coefficient_N_m_s": 0.3, "field_direction": [0, 0, 1],
                               "spin_compensated": True})
    assert all(math.isnan(r) for r in th.exact_steady_precession_rates(1.0, 0.7, **KW))
    pred = th.predict(p)
    assert math.isnan(pred.get("tilt_growth_rate_per_s").exact)
    assert pred.exact("nutation_frequency_rad_s") > 0


def test_eq20_slow_root_has_the_wrong_sign_and_the_corrected_form_agrees():
    rows = _sweep_steady_precession([30, 100], [0.1, 0.3])
    slow = [r for r in rows if r["quantity"] == "precession_rate_slow_rad_s"]
    assert all(r["simulator"] > 0 for r in slow)  # same sense as the positive spin
    assert not any(r["sign_agrees_paper"] for r in slow)
    assert all(abs(r["rel_error_corrected"]) < 1e-3 for r in slow)
    fast = [r for r in rows if r["quantity"] == "precession_rate_fast_rad_s"]
    assert all(r["sign_agrees_paper"] and abs(r["rel_error_paper"]) < 0.05 for r in fast)


def test_fast_top_release_formulas_converge_as_one_over_the_ratio():
    rows = _sweep_release([10, 30, 100], [0.1])
    for quantity in ["nutation_frequency_rad_s", "nutation_amplitude_rad", "mean_precession_rate_rad_s"]:
        errs = {r["fast_top_ratio"]: abs(r["rel_error_paper"]) for r in rows if r["quantity"] == quantity}
        assert errs[30] < FAST_TOP_RTOL_AT_30, quantity
        assert errs[100] < errs[10] / 5, quantity  # first order in 1/ratio: x10 ratio, ~x10 smaller error
        # the measured values agree with the exact elliptic solution
    for r in rows:
        assert r["simulator"] == pytest.approx(r["exact"], rel=2e-3)


def test_free_top_eqs_12_15_16_agree_in_the_small_cone_regime():
    rows = _sweep_free([0.3, 1.5], [0.05])
    assert {r["equation"] for r in rows} == {"12", "15", "16"}
    for r in rows:
        assert abs(r["rel_error_paper"]) < 3e-3  # O(cone angle^2) = 2.5e-3
        # eq. 16's simulated amplitude is a maximum over 2 kHz samples: good to ~1e-5
        assert r["simulator"] == pytest.approx(r["exact"], rel=1e-4)


def test_eq25a_predicts_decay_but_the_simulator_shows_growth():
    rows = _sweep_damped([30], [0.2, 2.0])
    rates = [r for r in rows if r["quantity"] == "tilt_growth_rate_per_s"]
    assert all(r["simulator"] > 0 for r in rates)
    assert all(r["paper"] < 0 for r in rates)
    assert all(abs(r["rel_error_corrected"]) < CORRECTED_RTOL for r in rates)


def test_eq31_leans_against_the_acceleration_and_the_top_precesses_about_the_effective_vertical():
    (row,) = _sweep_accelerated([2.0])
    assert row["paper"] > 0 > row["simulator"]  # acceleration along -x: the cone axis leans to -x
    assert row["simulator"] == pytest.approx(row["exact"], abs=1e-3)


def test_summary_names_every_disagreement():
    table = validate(quick=True)
    summary = summarize(table).set_index("equation")
    for eq in ["20", "25a", "26", "31"]:
        verdicts = " ".join(summary.loc[[eq], "verdict"])
        assert "DISAGREES" in verdicts, eq
    assert "agrees" in summary.loc["12", "verdict"]
    assert "singular" in summary.loc["9", "verdict"]


def test_phasor_integrator_is_exact_away_from_the_poles_and_refuses_them():
    p = make_protocol(tilt=0.5, tilt_rate=1.5, precession_rate=-2.0, spin=40.0, duration=3.0)
    t = np.linspace(0, 3, 301)
    assert max_tip_error(simulate(p, method="phasor", rtol=1e-12, atol=1e-14, t_eval_s=t), exact_solution(p, t)) < 1e-9
    damped = make_protocol(tilt=0.5, spin=40.0, duration=3.0, frame_inertia=0.05,
                           damping={"model": "eddy-field", "coefficient_N_m_s": 0.3, "field_direction": [0, 0, 1],
                                    "spin_compensated": True})
    a = simulate(damped, method="phasor", rtol=1e-12, t_eval_s=t)
    b = simulate(damped, method="gyro", rtol=1e-12, t_eval_s=t)
    assert max_tip_error(a, b) < 1e-8
    with pytest.raises(SimulationError, match="singular at the poles"):
        simulate(make_protocol(tilt=0.0, tilt_rate=0.5, spin=30.0), method="phasor")


def test_predict_reports_only_what_the_scene_has():
    preds = {p.stem: th.predict(load_protocol(p), simulate_damping=False) for p in sorted(PROTOCOL_DIR.glob("*.toml"))}
    assert set(preds["free-top"].quantities) == {"precession_rate_rad_s"}
    assert preds["free-top"].flags.fast_top_ratio is None and preds["free-top"].equilibrium_tip is None
    air = preds["air-cushion-heavy-top"]
    assert "tilt_growth_rate_per_s" not in air.quantities and air.equilibrium_tip is None
    assert {"precession_rate_slow_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad"} <= set(air.quantities)
    assert "tilt_growth_rate_per_s" in preds["eddy-damped-top-b2"].quantities
    assert preds["accelerated-pivot"].equilibrium_tip is not None
    # the rig is at fast-top ratio ~9 and 45 deg: the flags say the approximations are stretched
    assert air.flags.fast_top_ratio == pytest.approx(9.17, abs=0.01)
    assert air.flags.fast_top is False and air.flags.small_tilt is False
    assert air.quantities["precession_rate_slow_rad_s"].sign_agrees is False


def test_predict_damped_rig_simulates_the_growth():
    pred = th.predict(load_protocol(PROTOCOL_DIR / "eddy-damped-top-b2.toml"))
    g = pred.quantities["tilt_growth_rate_per_s"]
    assert g.paper < 0 < g.exact
    assert g.exact == pytest.approx(g.corrected, rel=0.15)  # small-tilt formula at 45 deg
    tau = pred.quantities["tilt_time_constant_s"]
    assert (tau.direction_paper, tau.direction_exact) == ("decay", "growth")
    lab_field = th.predict(load_protocol(PROTOCOL_DIR / "eddy-damped-top.toml"))
    assert abs(lab_field.quantities["tilt_growth_rate_per_s"].exact) < 1e-9  # damps theta-dot only


def test_theory_cli_json_and_validate(tmp_path, capsys):
    assert main(["theory", str(PROTOCOL_DIR / "accelerated-pivot.toml"), "--json", "--no-simulate"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["equilibrium_tip"]["leans_towards_acceleration"] == {"paper": False, "exact": True}
    assert math.isclose(np.linalg.norm(data["equilibrium_tip"]["exact"]), 1.0)
    assert main(["theory", "--validate", "--quick", "--out", str(tmp_path)]) == 0
    assert_plot(tmp_path / "validation.png")
    summary = pd.read_csv(tmp_path / "summary.csv")
    points = pd.read_csv(tmp_path / "validation.csv")
    assert set(summary.formula) == set(points.formula)
    # the paper's slow precession root (eq. 20) has the wrong sign at every sweep point
    assert summary.sign_agrees_paper.fillna("").str.startswith("0/").any()
    assert "DISAGREES" in (tmp_path / "validation.md").read_text()


def test_a_spinning_down_tops_precession_grows_as_its_spin_decays_for_a_fast_top():
    """Eq. 20's precession, Mgh / (Io omega), with the spin decaying at k / Io grows at k / Io: the simulator's growth
    approaches it as the top gets faster (first order in 1 / r: 13 % off at r = 5, 2 % at 30, 0.7 % at 100)."""
    from gyrorig.validation import _sweep_spin_down

    rows = _sweep_spin_down([5, 30, 100], [0.05])
    errors = [abs(row["rel_error_paper"]) for row in rows]
    assert all(row["sign_agrees_paper"] for row in rows)
    assert errors[0] > errors[1] > errors[2]
    # first order in 1/r: the error times r stays within a factor 2 from r = 5 to 100
    scaled = [e * r for e, r in zip(errors, (5, 30, 100))]
    assert max(scaled) < 2 * min(scaled)
    pred = th.predict(replace(load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml"),
                              pivot=Pivot((AirDamping(0.0, 5.2e-6, spin_compensated=False),))))
    q = pred.quantities["precession_growth_rate_per_s"]
    assert q.paper == pytest.approx(5.2e-6 / 4.725e-4) and q.exact == pytest.approx(q.paper, rel=0.1)
