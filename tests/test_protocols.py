import copy
import math
import tomllib

import pytest

from conftest import BUNDLED_PROTOCOLS, PROTOCOL_DIR
from gyrorig.physics.torques import EddyFieldTorque, GravityTorque, TransverseViscousTorque, torques_for
from gyrorig.protocols import ProtocolError, load_protocol, parse_protocol

BASE = tomllib.loads((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text())


def test_bundled_protocols_exist():
    names = {p.name for p in BUNDLED_PROTOCOLS}
    assert {"air-cushion-heavy-top.toml", "eddy-damped-top.toml", "eddy-damped-top-b2.toml",
            "accelerated-pivot.toml", "free-top.toml"} <= names


@pytest.mark.parametrize("path", BUNDLED_PROTOCOLS, ids=lambda p: p.stem)
def test_bundled_protocols_load(path):
    p = load_protocol(path)
    assert p.name == path.stem
    # the later sections parse too: a camera that sees the pivot, and a tip the tracker can follow
    if "camera" in p.extra:
        from gyrorig.camera import camera_setup
        from gyrorig.tracking.tracker import tip_marker

        camera_setup(p)  # raises ProtocolError naming the bad key
        assert tip_marker(p).name == "tip"


def test_each_scene_carries_only_its_torques():
    kinds = {p.stem: [type(t) for t in torques_for(load_protocol(p))] for p in BUNDLED_PROTOCOLS}
    assert kinds["free-top"] == []
    assert kinds["air-cushion-heavy-top"] == [GravityTorque]
    assert kinds["eddy-damped-top"] == [GravityTorque, EddyFieldTorque]
    assert kinds["eddy-damped-top-b2"] == [GravityTorque, TransverseViscousTorque]
    assert kinds["accelerated-pivot"] == [GravityTorque, EddyFieldTorque]
    acc = load_protocol(PROTOCOL_DIR / "accelerated-pivot.toml").pivot.acceleration
    assert acc is not None and acc.at(1.0) == (0.5, 0.0, 0.0)


def test_degrees_are_converted():
    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    assert p.launch.tilt_rad == pytest.approx(math.pi / 4, rel=1e-15)


def _with(section, key, value):
    data = copy.deepcopy(BASE)
    if value is _DELETE:
        del data[section][key]
    else:
        data[section][key] = value
    return data


class _Delete:
    """The key is removed (a stable repr keeps parametrize ids equal across pytest-xdist workers)."""

    def __repr__(self) -> str:
        return "<deleted>"


_DELETE = _Delete()

BAD = [
    # (section, key, value, words the message must contain)
    ("rig", "mass_kg", -1.0, ["rig.mass_kg", "-1", "(0, inf]"]),
    ("rig", "mass_kg", 0.0, ["rig.mass_kg", "(0, inf]"]),
    ("rig", "inertia_axial_kg_m2", 0.0, ["rig.inertia_axial_kg_m2", "(0, inf]"]),
    ("rig", "inertia_transverse_kg_m2", -3e-3, ["rig.inertia_transverse_kg_m2"]),
    ("rig", "inertia_axial_kg_m2", 2e-3, ["rig.inertia_axial_kg_m2", "twice", "allowed (0, "]),
    ("rig", "inertia_transverse_kg_m2", 1e-3, ["rig.inertia_transverse_kg_m2", "M h^2"]),
    ("rig", "mass_kg", float("nan"), ["rig.mass_kg", "finite"]),
    ("rig", "gravity_m_s2", float("inf"), ["rig.gravity_m_s2", "finite"]),
    ("rig", "mass_kg", "heavy", ["rig.mass_kg", "number"]),
    ("rig", "mass_kg", _DELETE, ["[rig]", "mass_kg"]),
    ("rig", "colour", "red", ["[rig]", "colour", "allowed keys"]),
    ("launch", "tilt_deg", 181.0, ["launch.tilt_deg", "181", "[0, 180]"]),
    ("launch", "tilt_deg", -1.0, ["launch.tilt_deg", "[0, 180]"]),
    ("launch", "tilt_rad", 0.5, ["tilt_rad", "tilt_deg", "one"]),
    ("launch", "spin_rate_rad_s", _DELETE, ["[launch]", "spin_rate_rad_s"]),
    ("scene", "duration_s", 0.0, ["scene.duration_s", "(0, "]),
]


@pytest.mark.parametrize("section,key,value,words", BAD, ids=[f"{b[0]}.{b[1]}={b[2]!r}"[:40] for b in BAD])
def test_bad_values_are_refused_with_key_and_range(section, key, value, words):
    with pytest.raises(ProtocolError) as info:
        parse_protocol(_with(section, key, value))
    msg = str(info.value)
    for w in words:
        assert w in msg, f"{w!r} not in {msg!r}"


def test_tilt_rad_outside_range():
    data = _with("launch", "tilt_deg", _DELETE)
    data["launch"]["tilt_rad"] = 3.2
    with pytest.raises(ProtocolError, match=r"launch\.tilt_rad = 3\.2 .*\[0, 3\.14159\]"):
        parse_protocol(data)


def test_unknown_section_and_damping_model():
    data = copy.deepcopy(BASE)
    data["lighting"] = {}
    with pytest.raises(ProtocolError, match="unknown section.*lighting"):
        parse_protocol(data)
    data = copy.deepcopy(BASE)
    data["pivot"] = {"damping": {"model": "sticky", "gamma_per_s": 1.0}}
    with pytest.raises(ProtocolError, match=r"pivot\.damping\.model = 'sticky'.*'paper'"):
        parse_protocol(data)
    data["pivot"] = {"damping": {"model": "paper", "gamma_per_s": -1.0}}
    with pytest.raises(ProtocolError, match=r"pivot\.damping\.gamma_per_s = -1\.0"):
        parse_protocol(data)
    data["pivot"] = {"damping": {"model": "eddy-field", "coefficient_N_m_s": 1e-3, "field_direction": [0, 0, 0],
                                 "spin_compensated": True}}
    with pytest.raises(ProtocolError, match="field_direction"):
        parse_protocol(data)


def test_acceleration_table_validation_and_interpolation():
    data = copy.deepcopy(BASE)
    data["pivot"] = {"acceleration_table": {"t_s": [0.0, 1.0, 0.5], "acceleration_m_s2": [[0, 0, 0]] * 3}}
    with pytest.raises(ProtocolError, match="strictly increasing"):
        parse_protocol(data)
    data["pivot"] = {"acceleration_table": {"t_s": [0.0, 2.0], "acceleration_m_s2": [[0, 0, 0], [1.0, -2.0, 0]]}}
    acc = parse_protocol(data).pivot.acceleration
    assert acc.at(-1.0) == (0, 0, 0)
    assert acc.at(1.0) == pytest.approx((0.5, -1.0, 0.0))
    assert acc.at(5.0) == (1.0, -2.0, 0)


def test_free_top_has_no_gravity_and_frame_key_needs_gyrostat():
    p = load_protocol(PROTOCOL_DIR / "free-top.toml")
    assert p.rig.gravity_m_s2 is None and not p.has_gravity
    data = tomllib.loads((PROTOCOL_DIR / "free-top.toml").read_text())
    data["launch"]["frame_spin_rate_rad_s"] = 1.0
    with pytest.raises(ProtocolError, match="frame_spin_rate_rad_s.*gyrostat"):
        parse_protocol(data)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ProtocolError, match="not found"):
        load_protocol(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[rig\nmass_kg = 1")
    with pytest.raises(ProtocolError, match="not valid TOML"):
        load_protocol(bad)


def test_files_saved_by_a_windows_editor_load_as_written(tmp_path):
    """Notepad and Excel's JSON/TOML export write a UTF-8 byte-order mark and CRLF line ends; TOML and JSON
    readers refuse the mark ('not valid TOML' at line 1, column 1)."""
    import json
    from dataclasses import replace

    from gyrorig.camera import camera_setup
    from gyrorig.tracking import load_camera

    source = PROTOCOL_DIR / "air-cushion-heavy-top.toml"
    path = tmp_path / "windows.toml"
    path.write_bytes(b"\xef\xbb\xbf" + source.read_text().replace("\n", "\r\n").encode("utf-8"))
    assert replace(load_protocol(path), source="") == replace(load_protocol(source), source="")
    cam = camera_setup(load_protocol(source)).camera
    json_path = tmp_path / "camera.json"
    json_path.write_bytes(b"\xef\xbb\xbf" + json.dumps(cam.to_json()).encode("utf-8"))
    loaded = load_camera(json_path)
    assert loaded.camera_matrix.tolist() == cam.camera_matrix.tolist()
    assert loaded.centre_m == pytest.approx(cam.centre_m)


def test_a_recordings_protocol_states_only_what_its_analysis_needs():
    """A recording's analysis compares with theory from the rig, the launch tilt and the spin: a protocol without
    [scene] and without the launch's azimuth and rates (a top released from rest) reads with those defaults, where
    each was refused as missing."""
    d = tomllib.loads((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text())
    whole = parse_protocol(d)
    del d["scene"]
    for key in ("azimuth_rad", "tilt_rate_rad_s", "precession_rate_rad_s"):
        del d["launch"][key]
    p = parse_protocol(d)
    assert p.launch == whole.launch  # the bundled rig is released from rest at azimuth 0
    assert p.scene.duration_s > 0 and p.rig == whole.rig
