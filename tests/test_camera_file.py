"""camera.json enters through one gate: every value the tracker uses is checked against its range, and a
bad file is bad input (exit 2, nothing written, no traceback), never a crash of the decoder or a silent
wrong answer (issue 23: dist_coeffs of length 3 or 7 and a zero gain aborted the interpreter; fps 0 or
negative gave zero or negative frame numbers; a pivot behind the camera was accepted)."""

import copy
import json
import math

import pytest

from conftest import PROTOCOL_DIR
from gyrorig.cli import main
from gyrorig.tracking import CameraFileError, load_camera

GOOD = {
    "camera_matrix": [[1000.0, 0.0, 320.0], [0.0, 1000.0, 240.0], [0.0, 0.0, 1.0]],
    "dist_coeffs": [-0.1, 0.05, 0.0, 0.0, 0.0],
    "image_size": [640, 480],
    "rvec": [math.pi, 0.0, 0.0],
    "tvec": [0.0, 0.0, 0.7],
    "fps": 200.0,
    "exposure_s": 3e-4,
    "psf_sigma_px": 1.0,
    "sensor": {"gain_e_per_adu": 2.0, "read_noise_e": 3.0, "bit_depth": 8},
}


def _with(path_keys, value):
    d = copy.deepcopy(GOOD)
    *head, last = path_keys
    target = d
    for k in head:
        target = target[k]
    if value is _DELETE:
        del target[last]
    else:
        target[last] = value
    return d


_DELETE = object()

BAD = {
    "null": None,
    "dist-3": _with(["dist_coeffs"], [0.1, 0.0, 0.0]),
    "dist-7": _with(["dist_coeffs"], [0.1] * 7),
    "dist-nan": _with(["dist_coeffs"], [0.1, None, 0.0, 0.0, 0.0]),
    "gain-0": _with(["sensor", "gain_e_per_adu"], 0.0),
    "fps-0": _with(["fps"], 0.0),
    "fps-negative": _with(["fps"], -200.0),
    "image-size-short": _with(["image_size"], [640]),
    "rvec-2": _with(["rvec"], [0.1, 0.2]),
    "pivot-behind": _with(["tvec"], [0.0, 0.0, -0.7]),
    "psf-0": _with(["psf_sigma_px"], 0.0),
    "singular-matrix": _with(["camera_matrix"], [[0.0, 0.0, 320.0], [0.0, 1000.0, 240.0], [0.0, 0.0, 1.0]]),
    "no-dist": _with(["dist_coeffs"], _DELETE),
    "shutter": _with(["shutter"], "sideways"),
    "gamma-0": _with(["sensor", "gamma"], 0.0),
    "transfer-pq": _with(["sensor", "transfer"], "pq"),  # HDR10's display light is not undone
    "transfer-number": _with(["sensor", "transfer"], 2.2),
}


def test_a_good_camera_file_loads(tmp_path):
    (tmp_path / "camera.json").write_text(json.dumps(GOOD))
    cam = load_camera(tmp_path / "camera.json")
    assert cam.fps == 200.0 and cam.width_px == 640 and cam.sensor_known
    # OpenCV writes its distortion as a 1 x n array
    (tmp_path / "nested.json").write_text(json.dumps(_with(["dist_coeffs"], [GOOD["dist_coeffs"]])))
    assert load_camera(tmp_path / "nested.json").dist_coeffs.tolist() == GOOD["dist_coeffs"]


@pytest.mark.parametrize("keys,unknown,readout", [({"shutter": "rolling", "readout_time_s": None}, True, None),
                                                  ({"shutter": "rolling"}, True, None),
                                                  ({"shutter": "rolling", "readout_time_s": 0.02}, False, 0.02),
                                                  ({"readout_time_s": None}, False, 0.0), ({}, False, 0.0)])
def test_a_rolling_shutter_without_its_readout_is_one_the_fit_finds(tmp_path, keys, unknown, readout):
    """A phone's rolling shutter, its readout time not known (null or left out): no row delay is put on the frames'
    times, and the camera says it is unknown (the tracker then gives each tip's row to the fit); a readout stated
    is used; a global shutter has none.  The camera writes its shutter back as it read it."""
    (tmp_path / "camera.json").write_text(json.dumps({**GOOD, **keys}))
    cam = load_camera(tmp_path / "camera.json")
    assert cam.readout_unknown is unknown
    assert cam.row_delay_s(240.0) == (0.0 if unknown or readout == 0.0 else 0.5 * readout)
    written = {k: cam.to_json()[k] for k in ("shutter", "readout_time_s")}
    (tmp_path / "again.json").write_text(json.dumps({**GOOD, **written}))
    assert load_camera(tmp_path / "again.json").readout_unknown is unknown


@pytest.mark.parametrize("name", sorted(BAD))
def test_a_bad_camera_file_is_refused_where_it_enters(tmp_path, name):
    (tmp_path / "camera.json").write_text(json.dumps(BAD[name]))
    with pytest.raises(CameraFileError):
        load_camera(tmp_path / "camera.json")


@pytest.mark.parametrize("name", ["dist-7", "gain-0", "fps-negative", "pivot-behind"])
def test_track_exits_2_on_a_bad_camera_file_and_writes_nothing(tmp_path, capsys, name):
    (tmp_path / "camera.json").write_text(json.dumps(BAD[name]))
    code = main(["track", str(tmp_path / "any.mkv"), "--camera", str(tmp_path / "camera.json"), "--protocol",
                 str(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), "--out", str(tmp_path / "out")])
    assert code == 2
    assert not (tmp_path / "out").exists()
    assert "Traceback" not in capsys.readouterr().err


def test_a_camera_file_that_is_not_utf8_is_bad_input(tmp_path):
    (tmp_path / "camera.json").write_bytes(b"\xff\xfe{\x00")
    with pytest.raises(CameraFileError):
        load_camera(tmp_path / "camera.json")


def test_an_fps_that_does_not_match_the_video_is_bad_input(tmp_path, capsys):
    """camera.json's fps at half the video's rate numbered two frames alike (issue 23): now exit 2."""
    import tomllib

    from gyrorig import parse_protocol
    from gyrorig.render import render_video

    d = tomllib.loads((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text())
    d["camera"].update(width_px=320, height_px=240, pixel_size_um=3.45 * 4.5)
    d["scene"]["duration_s"] = 0.1
    render_video(parse_protocol(d), tmp_path / "v", seed=0, calibration_views=0)
    cam = json.loads((tmp_path / "v" / "camera.json").read_text())
    cam["fps"] = cam["fps"] / 2
    (tmp_path / "half.json").write_text(json.dumps(cam))
    code = main(["track", str(tmp_path / "v" / "video.mkv"), "--camera", str(tmp_path / "half.json"), "--protocol",
                 str(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), "--out", str(tmp_path / "t"), "--tip-only"])
    assert code == 2 and not (tmp_path / "t").exists()
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.parametrize("stated, rel_sd", [(26.0, 0.15), ({"value": 26.0, "sd": 1.3}, 0.05)])
def test_a_phones_35mm_equivalent_focal_length_gives_its_angle_of_view(tmp_path, stated, rel_sd):
    """A phone's lens stated as its 35 mm-equivalent focal length (26 mm): the diagonal of its 4:3 still picture, as
    wide as the 1920-pixel video, subtends what a 36 x 24 mm frame's diagonal does 26 mm behind a lens (79.5 deg);
    the focal length's relative sd is the stated one's, or 15 % without one (the video's share of the sensor's width
    is not known).  Given beside another focal length key, the file is refused."""
    doc = {"image_size": [1920, 1080], "focal_length_35mm": stated, "rvec": [math.pi, 0.0, 0.0],
           "tvec": [0.0, 0.0, 0.7], "fps": 30.0}
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(doc))
    cam = load_camera(path)
    f = cam.camera_matrix[0, 0]
    diagonal_px = math.hypot(1920.0, 0.75 * 1920.0)
    assert 2 * math.degrees(math.atan(0.5 * diagonal_px / f)) == pytest.approx(
        2 * math.degrees(math.atan(0.5 * math.hypot(36.0, 24.0) / 26.0)), abs=1e-9)
    i = cam.intrinsics_parameters.index("fx")
    assert math.sqrt(cam.intrinsics_covariance[i, i]) / f == pytest.approx(rel_sd, rel=1e-9)
    path.write_text(json.dumps({**doc, "focal_length_px": 1500.0}))
    with pytest.raises(CameraFileError):
        load_camera(path)
