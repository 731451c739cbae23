"""A gyro in gimbals (issue 32): its simulator against the rigid-body one, its closed forms against its simulator,
its protocol section, and its identification from lab tables."""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from gyrorig.bench.identify import simulated_gimbal_nutation
from gyrorig.cli import main
from gyrorig.gimbals import Gimbal, gimbal_nutation_frequency, gimbal_precession_rate
from gyrorig.physics import SimulationError, simulate
from gyrorig.physics.gimbal import simulate_gimbal
from gyrorig.protocols import ProtocolError, load_protocol, parse_protocol
from gyrorig.theory import exact_steady_precession_rates

from conftest import PROTOCOL_DIR

AIR = PROTOCOL_DIR / "air-cushion-heavy-top.toml"


def _top():
    """The air-cushion rig as one rigid body (no separate frame)."""
    p = load_protocol(AIR)
    return replace(p, rig=replace(p.rig, frame_axial_inertia_kg_m2=None))


def test_a_top_in_gimbals_moves_as_the_rigid_body_simulator_says():
    """With nothing turning only in azimuth and the same inertia across both transverse axes the gimbal equations
    are the heavy symmetric top's: over 0.5 s of a kicked, precessing top the two simulators (Lagrange in the
    gimbal angles; quaternions in the body frame) agree to 1e-8 rad (1e-10 measured)."""
    p = _top()
    p = replace(p, launch=replace(p.launch, spin_rate_rad_s=300.0, tilt_rate_rad_s=0.7, precession_rate_rad_s=0.3))
    rigid = simulate(p, duration_s=0.5, rate_hz=1000, rtol=1e-11)
    gimbal = simulate_gimbal(p, duration_s=0.5, rate_hz=1000)
    assert np.abs(rigid.theta_rad.to_numpy() - gimbal.theta_rad.to_numpy()).max() < 1e-8
    assert np.abs(np.unwrap(rigid.phi_rad.to_numpy()) - gimbal.phi_rad.to_numpy()).max() < 1e-8


def test_the_gimbal_simulator_keeps_its_energy_and_refuses_the_lock():
    """Energy is a constant of the gimbal equations (to 1e-9 of itself over 2 s with an outer ring, a cross inertia
    and a frame); a gyro driven through the vertical (the gimbals lock there) is refused, not integrated."""
    p = load_protocol(AIR)
    p = replace(p, gimbal=Gimbal(4e-4, 2.6e-3), launch=replace(p.launch, spin_rate_rad_s=200.0, tilt_rate_rad_s=2.0))
    energy = simulate_gimbal(p, duration_s=2.0, rate_hz=500).energy_J.to_numpy()
    assert np.ptp(energy) < 1e-9 * abs(energy[0])
    slow = replace(p, launch=replace(p.launch, tilt_rad=0.2, spin_rate_rad_s=0.0, tilt_rate_rad_s=-3.0))
    with pytest.raises(SimulationError):
        simulate_gimbal(slow, duration_s=1.0, rate_hz=500)


@pytest.mark.parametrize("outer", [0.0, 4e-4])
@pytest.mark.parametrize("cross_factor", [0.5, 1.5])
@pytest.mark.parametrize("tilt_deg", [90.0, 60.0])
def test_the_nutation_formula_holds_for_small_oscillations(outer, cross_factor, tilt_deg):
    """``Io omega sin theta / sqrt(a(theta) I)`` against the simulated balanced gyro kicked by 0.5 rad/s (about 1 deg
    of nutation): within 3e-4 (measured 0.4-1.4e-4 over this sweep; the formula is the small-oscillation limit, its
    error grows as the amplitude squared, 0.1-0.5 x amplitude^2 in rad: 5e-3 at 6 deg)."""
    p = load_protocol(AIR)
    rig = replace(p.rig, com_distance_m=0.0)
    g = Gimbal(outer, cross_factor * rig.inertia_transverse_kg_m2)
    q = replace(p, rig=rig, gimbal=g)
    tilt = math.radians(tilt_deg)
    measured = simulated_gimbal_nutation(q, 300.0, tilt, 0.5)
    assert abs(measured / gimbal_nutation_frequency(rig, g, 300.0, tilt) - 1) < 3e-4


@pytest.mark.parametrize("tilt", [math.pi / 2, math.pi / 3, 2.2])
def test_the_steady_precession_formula_is_a_steady_state_of_the_simulator(tilt):
    """Launched at the formula's slow rate (a weight on the axis, an outer ring, a cross inertia and a frame), the
    simulated gyro keeps its tilt (to 1e-9 rad over 1 s) and precesses at that rate (to 1e-9); with the gimbals
    taken away it is Goldstein's steady precession of the top (theory.exact_steady_precession_rates)."""
    p = load_protocol(AIR)
    g = Gimbal(1e-3, 6e-3)
    for spin in (150.0, 400.0):
        rate = gimbal_precession_rate(p.rig, g, spin, tilt)
        q = replace(p, gimbal=g, launch=replace(p.launch, tilt_rad=tilt, tilt_rate_rad_s=0.0,
                                                precession_rate_rad_s=rate, spin_rate_rad_s=spin))
        df = simulate_gimbal(q, duration_s=1.0, rate_hz=2000)
        assert np.ptp(df.theta_rad) < 1e-9
        assert abs(np.polyfit(df.t_s, df.phi_rad, 1)[0] / rate - 1) < 1e-9
        top = _top().rig
        slow, _ = exact_steady_precession_rates(spin, tilt, inertia=top.inertia_transverse_kg_m2,
                                                inertia_axial=top.inertia_axial_kg_m2, mgh=top.mgh_N_m)
        assert abs(gimbal_precession_rate(top, None, spin, tilt) / slow - 1) < 1e-12


def test_the_gimbal_section_is_checked_and_the_video_chain_refuses_it(tmp_path):
    """``[gimbal]`` loads with its numbers (a ``{ value, sd }`` becomes an uncertain parameter); an unknown key, a
    negative and a zero inertia are refused; the rigid-body simulator refuses a gyro in gimbals instead of ignoring
    them."""
    data = tomllib.loads(AIR.read_text())
    data["gimbal"] = {"outer_inertia_kg_m2": {"value": 4e-4, "sd": 1e-4}, "cross_inertia_kg_m2": 2.6e-3}
    p = parse_protocol(data)
    assert p.gimbal == Gimbal(4e-4, 2.6e-3)
    assert p.uncertainty.sd_of("gimbal.outer_inertia_kg_m2") == 1e-4
    for bad in ({"outer_inertia_kg_m2": -1e-4}, {"inner_inertia_kg_m2": 1e-4}, {"cross_inertia_kg_m2": 0.0}):
        with pytest.raises(ProtocolError):
            parse_protocol({**data, "gimbal": bad})
    with pytest.raises(ProtocolError):
        simulate(p, duration_s=0.1)


def _gimbal_prior(tmp_path, com_distance: float = 0.0):
    text = AIR.read_text().replace("com_distance_m = 0.07715", f"com_distance_m = {com_distance!r}")
    text = text.replace("inertia_axial_kg_m2 = 4.725e-4", "inertia_axial_kg_m2 = { value = 4.9e-4, sd = 1e-4 }")
    text = text.replace("inertia_transverse_kg_m2 = 3.839e-3",
                        "inertia_transverse_kg_m2 = { value = 3.5e-3, sd = 0.8e-3 }")
    text += ("\n[gimbal]\nouter_inertia_kg_m2 = { value = 3e-4, sd = 1.5e-4 }\n"
             "cross_inertia_kg_m2 = { value = 2.2e-3, sd = 0.6e-3 }\n")
    path = tmp_path / "gimbal-prior.toml"
    path.write_text(text)
    return path


def test_identify_finds_a_gimbal_gyros_inertias_and_writes_them_back(tmp_path):
    """Lab tables of a balanced gyro in gimbals from its simulator (nutation at two tilts with and without cylinders
    on the outer ring, precession with weights on the axis, 0.3 % noise): every inertia within 4 of its standard
    errors of the truth, the outer ring's to better than 30 % (its prior 50 %), and identified.toml loads as a
    protocol carrying the identified [gimbal] values (and serves as the next prior)."""
    from gyrorig.bench.identify import _rigs, synthetic_tables

    rig = _rigs()["gimbal-gyro"]
    files, _ = synthetic_tables(rig, tmp_path / "tables", np.random.default_rng(3), rel_sd=0.003)
    out = tmp_path / "out"
    assert main(["identify", *map(str, files), "--protocol", str(_gimbal_prior(tmp_path)), "--out", str(out)]) == 0
    par = json.loads((out / "identify.json").read_text())["parameters"]
    truth = {"rig.inertia_axial_kg_m2": rig.protocol.rig.inertia_axial_kg_m2,
             "rig.inertia_transverse_kg_m2": rig.protocol.rig.inertia_transverse_kg_m2,
             "gimbal.outer_inertia_kg_m2": rig.protocol.gimbal.outer_inertia_kg_m2,
             "gimbal.cross_inertia_kg_m2": rig.protocol.gimbal.cross_inertia_kg_m2}
    for key, true in truth.items():
        assert abs(par[key]["value"] - true) < 4 * par[key]["standard_error"], key
    assert par["gimbal.outer_inertia_kg_m2"]["standard_error"] < 0.3 * truth["gimbal.outer_inertia_kg_m2"]
    identified = load_protocol(out / "identified.toml")
    assert identified.gimbal.outer_inertia_kg_m2 == pytest.approx(par["gimbal.outer_inertia_kg_m2"]["value"])
    assert identified.uncertainty.sd_of("gimbal.cross_inertia_kg_m2") == pytest.approx(
        par["gimbal.cross_inertia_kg_m2"]["standard_error"])
    again = tmp_path / "again"
    assert main(["identify", *map(str, files), "--protocol", str(out / "identified.toml"), "--out", str(again)]) == 0


def test_identify_refuses_what_its_gimbal_models_do_not_cover(tmp_path, capsys):
    """A weighted gyro's nutation in gimbals (the model is the balanced one) is refused naming the file and line,
    and so is a video's fit.json against a prior in gimbals (the video chain models a top on a pivot)."""
    table = tmp_path / "nutation.csv"
    table.write_text("spin_rad_s,nutation_frequency_rad_s,nutation_frequency_rad_s_sd\n300,40,0.1\n400,53,0.1\n"
                     "500,66,0.1\n")
    assert main(["identify", str(table), "--protocol", str(_gimbal_prior(tmp_path, 0.02)), "--out",
                 str(tmp_path / "o1")]) == 2
    assert "nutation.csv, line 2" in capsys.readouterr().err
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({"protocol_summary": {"launch": {}}, "quantities": {}}))
    assert main(["identify", str(fit), "--protocol", str(_gimbal_prior(tmp_path)), "--out", str(tmp_path / "o2")]) == 2


def test_configurations_share_what_they_share(tmp_path):
    """Issue 32: one gyro measured in two configurations, its rod on (nutation, and precession with weights) and off
    (nutation: the rod's inertia gone from both transverse axes).  The prior's [[configuration]] gives the rod-off
    tables their own transverse inertias (with priors) and shares Io and the outer ring: every parameter within 4 of
    its standard errors of the simulator's truth, one Io for both, and identified.toml carries the configuration's
    identified values."""
    from gyrorig.bench.identify import simulated_gimbal_precession_period

    rng = np.random.default_rng(7)
    p = load_protocol(AIR)
    rod = replace(p, rig=replace(p.rig, com_distance_m=0.0), gimbal=Gimbal(4e-4, 2.6e-3))
    off = replace(rod, rig=replace(rod.rig, inertia_transverse_kg_m2=2.9e-3), gimbal=Gimbal(4e-4, 1.7e-3))

    def noisy(v):
        return v * (1 + 0.003 * rng.normal())
    head = ("spin_rad_s,spin_rad_s_sd,tilt_deg,added_outer_inertia_g_cm2,nutation_frequency_rad_s,"
            "nutation_frequency_rad_s_sd\n")
    for name, q in (("nutation.csv", rod), ("nutation-no-rod.csv", off)):
        rows = [(s, th, j, simulated_gimbal_nutation(q, s, math.radians(th), 0.5, j * 1e-7))
                for s in (250.0, 400.0) for th in (90.0, 60.0) for j in (0.0, 5000.0)]
        (tmp_path / name).write_text(head + "".join(f"{noisy(s)},{0.003 * s},{th},{j},{noisy(y)},{0.003 * y}\n"
                                                    for s, th, j, y in rows))
    rows = [(s, m, simulated_gimbal_precession_period(rod, s, math.pi / 2, m, 0.12)) for s in (300.0, 450.0)
            for m in (0.03, 0.06)]
    (tmp_path / "precession.csv").write_text(
        "spin_rad_s,spin_rad_s_sd,added_mass_g,lever_arm_cm,precession_period_s,precession_period_s_sd\n"
        + "".join(f"{noisy(s)},{0.003 * s},{1e3 * m},12,{noisy(t)},{0.003 * t}\n" for s, m, t in rows))
    prior = _gimbal_prior(tmp_path)
    prior.write_text(prior.read_text() + '\n[[configuration]]\nname = "no rod"\ntables = ["nutation-no-rod.csv"]\n'
                     "[configuration.rig]\ninertia_transverse_kg_m2 = { value = 2.5e-3, sd = 0.8e-3 }\n"
                     "[configuration.gimbal]\ncross_inertia_kg_m2 = { value = 2.0e-3, sd = 0.6e-3 }\n")
    out = tmp_path / "out"
    inputs = [str(tmp_path / f) for f in ("nutation.csv", "nutation-no-rod.csv", "precession.csv")]
    assert main(["identify", *inputs, "--protocol", str(prior), "--out", str(out)]) == 0
    par = json.loads((out / "identify.json").read_text())["parameters"]
    truth = {"rig.inertia_axial_kg_m2": p.rig.inertia_axial_kg_m2, "rig.inertia_transverse_kg_m2": 3.839e-3,
             "gimbal.outer_inertia_kg_m2": 4e-4, "gimbal.cross_inertia_kg_m2": 2.6e-3,
             "configuration[no rod].rig.inertia_transverse_kg_m2": 2.9e-3,
             "configuration[no rod].gimbal.cross_inertia_kg_m2": 1.7e-3}
    assert set(truth) <= set(par)
    for key, true in truth.items():
        assert abs(par[key]["value"] - true) < 4 * par[key]["standard_error"], key
    written = tomllib.loads((out / "identified.toml").read_text())["configuration"][0]
    assert written["rig"]["inertia_transverse_kg_m2"]["value"] == pytest.approx(
        par["configuration[no rod].rig.inertia_transverse_kg_m2"]["value"])
    assert load_protocol(out / "identified.toml").gimbal is not None


@pytest.mark.parametrize("config", [
    'name = "a"\ntables = ["t.csv"]\nwheels = 2\n',                                   # unknown key
    'tables = ["t.csv"]\n',                                                            # no name
    'name = "a"\ntables = []\n',                                                       # no tables
    'name = "a"\ntables = ["t.csv"]\n[configuration.rig]\nspin_rad_s = 3.0\n',        # not a rig key
    'name = "a"\ntables = ["t.csv"]\n[configuration.rig]\nmass_kg = { value = 1.0, sd = -0.1 }\n',
    'name = "a"\ntables = ["t.csv"]\n[configuration.rig]\nmass_kg = "heavy"\n',
    'name = "a"\ntables = ["t.csv"]\n[configuration.rig]\ninertia_transverse_kg_m2 = 1e-9\n',  # not a rigid body
    'name = "a"\ntables = ["t.csv"]\n[[configuration]]\nname = "a"\ntables = ["u.csv"]\n',   # the same name twice
    'name = "a"\ntables = ["t.csv"]\n[[configuration]]\nname = "b"\ntables = ["t.csv"]\n',   # a table in two
])
def test_a_bad_configuration_is_refused(tmp_path, config):
    """Each malformed [[configuration]] exits 2 (bad input), never runs on a guess."""
    table = tmp_path / "t.csv"
    table.write_text("spin_rad_s,nutation_frequency_rad_s,nutation_frequency_rad_s_sd\n300,40,0.1\n400,53,0.1\n"
                     "500,66,0.1\n")
    prior = _gimbal_prior(tmp_path)
    prior.write_text(prior.read_text() + "\n[[configuration]]\n" + config)
    assert main(["identify", str(table), "--protocol", str(prior), "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def test_gyrorig_simulate_runs_a_gyro_in_gimbals(tmp_path):
    """``gyrorig simulate`` on a protocol with [gimbal] uses the gimbal simulator (energy kept to 1e-9), refuses the
    rigid-body methods and pivot torques it does not model (exit 2, nothing written)."""
    text = AIR.read_text() + "\n[gimbal]\nouter_inertia_kg_m2 = 4e-4\ncross_inertia_kg_m2 = 2.6e-3\n"
    proto = tmp_path / "gimbal.toml"
    proto.write_text(text)
    assert main(["simulate", str(proto), "--out", str(tmp_path / "a"), "--duration", "1", "--rate", "200"]) == 0
    energy = pd.read_csv(tmp_path / "a" / "trajectory.csv").energy_J.to_numpy()
    assert len(energy) == 201 and np.ptp(energy) < 1e-9 * abs(energy[0])
    assert main(["simulate", str(proto), "--out", str(tmp_path / "b"), "--method", "gyro"]) == 2
    damped = tmp_path / "damped.toml"
    damped.write_text(text + '\n[pivot.damping]\nmodel = "paper"\ngamma_per_s = 0.01\n')
    assert main(["simulate", str(damped), "--out", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


def test_gyrorig_theory_predicts_a_gimbal_gyros_nutation_as_its_simulator_measures_it(tmp_path, capsys):
    """``gyrorig theory --json`` on a balanced gyro in gimbals: its nutation frequency within 3e-4 of the one its
    simulator measures for a small kick (the formula is the small-oscillation limit); a weighted one's slow
    precession rate within 1e-9 of its simulated steady precession."""
    text = AIR.read_text() + "\n[gimbal]\nouter_inertia_kg_m2 = 4e-4\ncross_inertia_kg_m2 = 2.6e-3\n"
    balanced = tmp_path / "balanced.toml"
    balanced.write_text(text.replace("com_distance_m = 0.07715", "com_distance_m = 0.0"))
    capsys.readouterr()
    assert main(["theory", str(balanced), "--json"]) == 0
    pred = json.loads(capsys.readouterr().out)["nutation_frequency_rad_s"]["gimbal"]
    q = load_protocol(balanced)
    measured = simulated_gimbal_nutation(q, q.launch.spin_rate_rad_s, q.launch.tilt_rad, 0.5)
    assert abs(pred / measured - 1) < 3e-4
    weighted = tmp_path / "weighted.toml"
    weighted.write_text(text)
    assert main(["theory", str(weighted), "--json"]) == 0
    rate = json.loads(capsys.readouterr().out)["precession_rate_slow_rad_s"]["gimbal"]
    q = load_protocol(weighted)
    df = simulate_gimbal(replace(q, launch=replace(q.launch, precession_rate_rad_s=rate, tilt_rate_rad_s=0.0)),
                         duration_s=0.5, rate_hz=2000)
    assert np.ptp(df.theta_rad) < 1e-9 and abs(np.polyfit(df.t_s, df.phi_rad, 1)[0] / rate - 1) < 1e-9


def test_a_gimbal_gyros_theory_carries_its_parameters_errors(tmp_path, capsys):
    """``{ value, sd }`` on the outer ring's inertia ``J`` and on the rotor's ``Io``: the nutation frequency
    ``Io Omega sin(theta) / sqrt(a I)``, ``a = J + I2 sin^2 theta``, moves by ``-omega / (2 a)`` per unit ``J`` and by
    ``omega / Io`` per unit ``Io``: its sd is those in quadrature.  The propagation takes central differences over one
    sd, which differ from the derivative by h^2/6 times the third derivative over the first: for ``a^(-1/2)``,
    ``0.625 (sd_J / a)^2`` = 0.2 % here (``sd_J / a`` = 6 %), for ``Io`` 0 (linear); the fast-top formula
    ``Io Omega / I`` does not see ``J``."""
    from gyrorig.propagate import gimbal_prediction_with_uncertainty

    text = AIR.read_text().replace("com_distance_m = 0.07715", "com_distance_m = 0.0")
    text = text.replace("inertia_axial_kg_m2 = 4.725e-4", "inertia_axial_kg_m2 = { value = 4.725e-4, sd = 0.1e-4 }")
    path = tmp_path / "gimbal.toml"
    path.write_text(text + "\n[gimbal]\nouter_inertia_kg_m2 = { value = 4e-4, sd = 1e-4 }\n"
                           "cross_inertia_kg_m2 = 2.6e-3\n")
    p = load_protocol(path)
    q = gimbal_prediction_with_uncertainty(p)["nutation_frequency_rad_s"]
    th = p.launch.tilt_rad
    a = 4e-4 + 2.6e-3 * math.sin(th) ** 2 + (p.rig.frame_axial_inertia_kg_m2 or 0.0) * math.cos(th) ** 2
    w = q["gimbal"]
    assert q["gimbal_sd"] == pytest.approx(math.hypot(w / (2 * a) * 1e-4, w / 4.725e-4 * 0.1e-4), rel=3e-3)
    assert q["fast_top_sd"] == pytest.approx(q["fast_top"] * 0.1e-4 / 4.725e-4, rel=1e-4)
    capsys.readouterr()
    assert main(["theory", str(path)]) == 0
    assert "+-" in capsys.readouterr().out
