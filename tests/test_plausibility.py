"""Plausibility (issue 33): values in range but in the wrong unit, and a record whose geometry disagrees with its
protocol, are named (a warning and a fit note), not passed in silence.

Angle tables here come from the simulator's tip, projected through the bundled camera to pixels and turned back
into angles by the tracker's own ray geometry, as :mod:`gyrorig.tracking` does with a video.
"""

from __future__ import annotations

import copy
import json
import tomllib

import cv2
import numpy as np
import pandas as pd
import pytest

from conftest import PROTOCOL_DIR
from gyrorig import parse_protocol
from gyrorig.camera import Camera, Sensor, camera_setup
from gyrorig.cli import main
from gyrorig.fit import FitError, NoteKind, fit_angles
from gyrorig.physics.simulate import simulate
from gyrorig.plausibility import protocol_doubts
from gyrorig.protocols import load_protocol
from gyrorig.theory import predict
from gyrorig.tracking.rays import angle_covariances

HEAVY = PROTOCOL_DIR / "air-cushion-heavy-top.toml"
BASE = tomllib.loads(HEAVY.read_text())
PIXEL_SIGMA = 0.05


def _with(**changes) -> dict:
    d = copy.deepcopy(BASE)
    for dotted, value in changes.items():
        section, key = dotted.split("__")
        d[section][key] = value
    return d


@pytest.mark.parametrize("path", sorted(PROTOCOL_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_bundled_protocols_raise_no_doubt(path):
    assert protocol_doubts(load_protocol(path)) == ()


# each mistake a user makes with the units of a tabletop rig, and the key that must be named
MISTAKES = {
    "inertias in g cm^2": ({"rig__inertia_axial_kg_m2": 4725.0, "rig__inertia_transverse_kg_m2": 38390.0},
                           "rig.inertia_axial_kg_m2"),
    "mass in g (a balanced gyro)": ({"rig__mass_kg": 529.2, "rig__com_distance_m": 0.001}, "rig.mass_kg"),
    "com distance in cm": ({"rig__com_distance_m": 7.715, "rig__inertia_transverse_kg_m2": 40.0},
                           "rig.com_distance_m"),
    "gravity in cm/s^2": ({"rig__gravity_m_s2": 981.0}, "rig.gravity_m_s2"),
    "spin in rev/min": ({"launch__spin_rate_rad_s": 4800.0}, "launch.spin_rate_rad_s"),  # the rig's 80 Hz
}


@pytest.mark.parametrize("mistake", MISTAKES, ids=list(MISTAKES))
def test_a_unit_mistake_is_doubted_by_its_key(mistake):
    changes, key = MISTAKES[mistake]
    doubts = protocol_doubts(parse_protocol(_with(**changes)))
    assert key in {d.key for d in doubts}


def test_theory_warns_of_inertias_in_g_cm2_and_lists_the_doubts(tmp_path, capsys, caplog):
    text = HEAVY.read_text().replace("inertia_axial_kg_m2 = 4.725e-4", "inertia_axial_kg_m2 = 4725.0").replace(
        "inertia_transverse_kg_m2 = 3.839e-3", "inertia_transverse_kg_m2 = 38390.0")
    path = tmp_path / "gcm.toml"
    path.write_text(text)
    assert main(["theory", str(path), "--json", "--no-simulate"]) == 0  # a warning, not a refusal
    captured = capsys.readouterr()
    assert {r.levelname for r in caplog.records if r.name == "gyrorig.protocols"} == {"WARNING"}
    assert [d["key"] for d in json.loads(captured.out)["doubts"]] == ["rig.inertia_axial_kg_m2",
                                                                      "rig.inertia_transverse_kg_m2"]


def _camera(protocol) -> Camera:
    cam = camera_setup(protocol).camera
    dist = np.zeros(5)
    dist[:4] = cam.dist_coeffs[:4]
    return Camera(cam.camera_matrix, dist, cam.rvec, cam.tvec, cam.width_px, cam.height_px, cam.fps,
                          cam.exposure_s, "global", 0.0, 1.0, Sensor(gain_e_per_adu=1.0))


def _tracked(protocol, stated_length_m: float, seed: int = 0, duration_s: float = 2.0) -> pd.DataFrame:
    """The angle table a tracker makes of the simulated tip (at the protocol's true place) when the tip is stated
    ``stated_length_m`` from the pivot."""
    true_length = float(protocol.extra["markers"]["tip"]["position_m"][2])
    truth = simulate(protocol, duration_s=duration_s, rate_hz=100.0)
    th, ph = truth.theta_rad.to_numpy(), truth.phi_rad.to_numpy()
    tips = true_length * np.column_stack([np.sin(th) * np.sin(ph), -np.sin(th) * np.cos(ph), np.cos(th)])
    cam = _camera(protocol)
    px = cv2.projectPoints(tips, cam.rvec, cam.tvec, cam.camera_matrix, cam.dist_coeffs)[0].reshape(-1, 2)
    px = px + PIXEL_SIGMA * np.random.default_rng(seed).normal(size=px.shape)
    cov_px = np.broadcast_to(PIXEL_SIGMA**2 * np.eye(2), (len(px), 2, 2))
    t_m, p_m, _, cov = angle_covariances(px, cov_px, cam, stated_length_m)
    sth, sph = np.sqrt(cov[:, 0, 0]), np.sqrt(cov[:, 1, 1])
    return pd.DataFrame({"frame": np.arange(len(th)), "t_s": truth.t_s, "theta_rad": t_m, "phi_rad": np.unwrap(p_m),
                         "theta_sigma_rad": sth, "phi_sigma_rad": sph, "theta_phi_corr": cov[:, 0, 1] / (sth * sph)})


def _kinds(fit) -> set:
    return {n.kind for n in fit.notes}


def test_a_tip_marker_stated_1_cm_low_is_named_and_the_right_one_is_not():
    p = load_protocol(HEAVY)
    pred = predict(p)
    right = fit_angles(_tracked(p, 0.14), p, prediction=pred)
    assert NoteKind.GEOMETRY not in _kinds(right) and NoteKind.PLAUSIBILITY not in _kinds(right)
    low = fit_angles(_tracked(p, 0.13), p, prediction=pred)
    # the fit itself is good: only the comparison with the protocol can tell
    assert low.chi2_red < 2.0
    assert NoteKind.GEOMETRY in _kinds(low)


def test_a_stated_launch_tilt_sd_widens_what_passes():
    """A launch tilt stated as 50 +- 2 degrees where the top left at 45: 2.5 sd, not noted; stated +- 0.5: noted."""
    p = load_protocol(HEAVY)
    angles = _tracked(p, 0.14)
    for sd, noted in ((2.0, False), (0.5, True)):
        d = _with(launch__tilt_deg={"value": 50.0, "sd": sd})
        q = parse_protocol(d)
        assert (NoteKind.GEOMETRY in _kinds(fit_angles(angles, q, prediction=predict(q)))) is noted


def test_the_geometry_note_reaches_fit_json(tmp_path, capsys):
    p = load_protocol(HEAVY)
    _tracked(p, 0.13).to_csv(tmp_path / "angles.csv", index=False)
    assert main(["fit", str(tmp_path / "angles.csv"), "--protocol", str(HEAVY), "--out", str(tmp_path / "f")]) == 0
    fit = json.loads((tmp_path / "f" / "fit.json").read_text())
    assert "geometry" in {n["kind"] for n in fit["notes"]}


def test_angles_in_degrees_are_refused_by_the_column():
    p = load_protocol(HEAVY)
    angles = _tracked(p, 0.14, duration_s=0.5)
    for c in ("theta_rad", "phi_rad", "theta_sigma_rad", "phi_sigma_rad"):
        angles[c] = np.degrees(angles[c])
    with pytest.raises(FitError):
        fit_angles(angles, p)


@pytest.mark.parametrize("slip", ["azimuth in degrees", "times in ms"])
def test_a_unit_slip_in_the_angle_table_is_noted(slip):
    p = load_protocol(HEAVY)
    angles = _tracked(p, 0.14, duration_s=0.5)
    if slip == "azimuth in degrees":
        angles["phi_rad"] = np.degrees(angles.phi_rad)
        angles["phi_sigma_rad"] = np.degrees(angles.phi_sigma_rad)
    else:
        angles["t_s"] = angles.t_s * 1000.0
    fit = fit_angles(angles, p, prediction=predict(p))
    assert NoteKind.PLAUSIBILITY in _kinds(fit)
