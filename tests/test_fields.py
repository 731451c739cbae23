"""Interlaced video: each picture's two fields tracked as two images at their own times (gyrorig.tracking.fields)."""

from __future__ import annotations

import json
from dataclasses import replace
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pandas as pd
import pytest

from gyrorig.bench.variants import variant_protocols
from gyrorig.protocols import parse_protocol
from gyrorig.render.phone import PhoneStyle, render_phone_video
from gyrorig.tracking import CameraFileError, VideoFile, load_camera, track
from gyrorig.tracking.fields import bob, field_timing_evidence

FIELD_FPS = 50.0


def test_bob_keeps_its_fields_rows_and_interpolates_the_others():
    """A picture whose values rise linearly down its rows is reproduced exactly on every interpolated row inside
    the field (the mean of the rows above and below is the ramp's value there), for both fields and odd heights;
    a field's own rows are kept as they are (colour frames too)."""
    for height in (8, 9):
        ramp = np.repeat((10 * np.arange(height, dtype=np.uint16))[:, None], 5, axis=1)
        for first_row in (0, 1):
            out = bob(ramp, first_row)
            assert out.dtype == ramp.dtype and out.shape == ramp.shape
            np.testing.assert_array_equal(out[first_row::2], ramp[first_row::2])
            rows = np.arange(height)
            inside = (rows % 2 != first_row) & (rows > first_row) & (rows < height - 1)
            np.testing.assert_array_equal(out[inside], ramp[inside])
        rgb = np.dstack([ramp, 2 * ramp, 3 * ramp]).astype(np.uint8)
        np.testing.assert_array_equal(bob(rgb, 1)[1::2], rgb[1::2])


def _circle(t_s: np.ndarray, rng) -> np.ndarray:
    """A tip going round a 30 px circle 1.5 times a second, measured with 0.1 px of noise."""
    xy = 30.0 * np.column_stack([np.cos(3 * np.pi * t_s), np.sin(3 * np.pi * t_s)])
    return xy + rng.normal(0.0, 0.1, xy.shape)


def test_the_tips_path_tells_the_field_order_and_progressive_pictures():
    """The tip's step inside a picture projected on its step to the next picture: about 1 in the order read, -1/3
    in the other, 0 for both fields from one instant; none when the tip is still (its steps are noise).  Bounds:
    99 pictures, steps of 5.7 px against 0.14 px of noise per step (the ratio known to a few per cent)."""
    rng = np.random.default_rng(4)
    frame = np.arange(200)
    t_s = frame / FIELD_FPS
    var = np.full((200, 2), 0.01)
    assert field_timing_evidence(frame, _circle(t_s, rng), var).ratio == pytest.approx(1.0, abs=0.1)
    swapped = frame ^ 1  # each picture's fields exposed the other way round
    evidence = field_timing_evidence(frame, _circle(t_s[swapped], rng), var)
    assert evidence.ratio == pytest.approx(-1 / 3, abs=0.05) and evidence.verdict == "reversed"
    evidence = field_timing_evidence(frame, _circle((frame // 2) * 2 / FIELD_FPS, rng), var)
    assert abs(evidence.ratio) < 0.05 and evidence.verdict == "progressive"
    assert field_timing_evidence(frame, rng.normal(0.0, 0.1, (200, 2)), var).verdict is None


@pytest.fixture(scope="module")
def field_rate_render(tmp_path_factory):
    """1 s of the air-cushion rig at 640 x 480 rendered at the field rate (50/s, 2 ms exposures) in front of the
    coffee photograph, stored losslessly, and its pictures as RGB arrays."""
    scene, user, _ = variant_protocols("sphere", 1.0)
    scene["camera"].update(fps=FIELD_FPS, exposure_s=2e-3)
    user["camera"].update(fps=FIELD_FPS, exposure_s=2e-3)
    out = tmp_path_factory.mktemp("fields")
    rendered = render_phone_video(scene, out, style=PhoneStyle(photo="coffee", codec="ffv1", transfer=None,
                                                               jitter_fraction=0.0, drop_fraction=0.0), seed=3)
    with av.open(rendered["video"]) as container:
        pictures = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    return user, rendered, pictures


def _interlaced(path, pictures, order: str, progressive: bool = False) -> str:
    """The field-rate pictures woven into interlaced H.264 at half the rate (x264's interlaced coding, the field
    order flagged): each stored picture's field exposed first from one rendered picture, the other from the next
    (``progressive``: both from the first, as a 25p camera storing its pictures in a 50i stream)."""
    first, second = (0, 1) if order == "top-field-first" else (1, 0)
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=Fraction(int(FIELD_FPS), 2))
        stream.width, stream.height, stream.pix_fmt = pictures[0].shape[1], pictures[0].shape[0], "yuv420p"
        stream.options = {"crf": "20", "x264-params": f"interlaced=1:{'tff' if first == 0 else 'bff'}=1"}
        for k in range(len(pictures) // 2):
            woven = pictures[2 * k].copy()
            if not progressive:
                woven[second::2] = pictures[2 * k + 1][second::2]
            for packet in stream.encode(av.VideoFrame.from_ndarray(woven, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return str(path)


def _errors(res, truth_csv, picture_rate: bool = False):
    """Each tracked row against the renderer's truth at its time (a row of a picture-rate record is the picture's
    first field: truth frame 2k); returns (rows with the tip visible, tracked rows, pulls theta, pulls phi)."""
    truth = pd.read_csv(truth_csv)
    tip = truth[truth.marker == "tip"].set_index("frame")
    a = res.angles.copy()
    a["truth_frame"] = 2 * a.frame if picture_rate else a.frame
    m = a.join(tip[["theta_rad", "phi_rad", "visible", "t_marker_s"]].add_suffix("_true"), on="truth_frame")
    found = m.dropna(subset=["theta_rad"])
    e_th = (found.theta_rad - found.theta_rad_true) / found.theta_sigma_rad
    e_ph = np.angle(np.exp(1j * (found.phi_rad - found.phi_rad_true))) / found.phi_sigma_rad
    return m[m.visible_true.astype(bool)], found, e_th, e_ph


@pytest.mark.parametrize("order", ["top-field-first", "bottom-field-first"])
def test_an_interlaced_video_is_tracked_field_by_field(tmp_path, field_rate_render, order):
    """A 25-picture/s interlaced file of a 50-field/s camera: every field an image at its own time.  At least 95 %
    of the fields with the tip visible tracked (read as pictures, the tip's two half-images a few pixels apart were
    no spot: 2 of 50 pictures), each at its field's time, none beyond 5 sigma flagged ok, the record says it read
    fields in the file's order."""
    user, rendered, pictures = field_rate_render
    video = _interlaced(tmp_path / "interlaced.mp4", pictures, order)
    camera = replace(load_camera(rendered["camera"]), fps=FIELD_FPS / 2)  # the camera's picture rate, as its menu says
    res = track(video, camera, parse_protocol(user))
    visible, found, e_th, e_ph = _errors(res, rendered["truth"])
    assert res.frame_times["fields"] == order and res.frames == len(pictures)
    assert len(found) >= 0.95 * len(visible)
    np.testing.assert_allclose(found.t_s, found.t_marker_s_true, atol=1e-3)
    wrong = (e_th.abs() > 5) | (e_ph.abs() > 5)
    assert not (wrong & (found.quality == "ok")).any()


def test_a_fast_nod_at_50_frames_per_second_keeps_its_frames(field_rate_render):
    """The field-rate render itself, progressive at 50 frames/s: the tip released from rest gathers speed before the
    follower has seen it accelerate, then nods by up to 12 px per frame, crossing a bright patch of the photograph;
    the path through six neighbours cannot follow it.  Before: 41 of 50 frames tracked (the first steps outran the
    gate, the tip joined to the patch was no candidate) and the frames at the nod's turns left out as outliers (31
    of 100 on a 1280x720 render).  Now at least 48 of 50, none left out as an outlier, none beyond 5 sigma."""
    user, rendered, pictures = field_rate_render
    res = track(rendered["video"], load_camera(rendered["camera"]), parse_protocol(user))
    visible, found, e_th, e_ph = _errors(res, rendered["truth"])
    assert len(found) >= 0.95 * len(visible) and not (res.angles.quality == "outlier").any()
    assert not ((e_th.abs() > 5) | (e_ph.abs() > 5)).any()


def test_progressive_pictures_stored_as_interlaced_are_found_and_tracked_as_pictures(tmp_path, field_rate_render):
    """A 25p camera storing its pictures in a 50i stream (PsF): the file flags them interlaced, but the tip does not
    move between a picture's fields; the record is tracked again as pictures, at the pictures' times.  At 25
    pictures/s no path through six neighbours follows the nod: the errors stay the spot fits' own (before, the
    residuals, 4 px, were taken for the codec's floor and every error scaled by 68: pull SDs 0.01-0.02)."""
    user, rendered, pictures = field_rate_render
    video = _interlaced(tmp_path / "psf.mp4", pictures, "top-field-first", progressive=True)
    camera = replace(load_camera(rendered["camera"]), fps=FIELD_FPS / 2)
    res = track(video, camera, parse_protocol(user))
    assert res.frame_times["fields"] is None and res.frames == len(pictures) // 2
    visible, found, e_th, e_ph = _errors(res, rendered["truth"], picture_rate=True)
    assert len(found) >= 0.85 * len(visible)
    np.testing.assert_allclose(found.t_s, found.t_marker_s_true, atol=1e-3)
    wrong = (e_th.abs() > 5) | (e_ph.abs() > 5)
    assert not (wrong & (found.quality == "ok")).any()
    assert not res.sigma_check.smooth_path and min(e_th[~wrong].std(), e_ph[~wrong].std()) > 0.5


def test_a_field_order_stated_against_the_tips_path_is_said(tmp_path, field_rate_render):
    """camera.json stating the other field order than the pictures were exposed in: tracked as stated, and the
    record says that the tip's path contradicts it."""
    user, rendered, pictures = field_rate_render
    video = _interlaced(tmp_path / "interlaced.mp4", pictures, "top-field-first")
    camera = replace(load_camera(rendered["camera"]), interlace="bottom-field-first")
    res = track(video, camera, parse_protocol(user))
    assert res.frame_times["fields"] == "bottom-field-first" and len(res.source_problems) == 1


def test_camera_json_states_the_scan_or_is_refused_naming_it(tmp_path, field_rate_render):
    """``interlace`` in camera.json: one of the modes, read into the camera; anything else refused, naming the key."""
    _, rendered, _ = field_rate_render
    d = json.loads(Path(rendered["camera"]).read_text())
    for mode in ("progressive", "top-field-first", "bottom-field-first"):
        (tmp_path / "c.json").write_text(json.dumps({**d, "interlace": mode}))
        assert load_camera(tmp_path / "c.json").interlace == mode
    (tmp_path / "c.json").write_text(json.dumps({**d, "interlace": "upper"}))
    with pytest.raises(CameraFileError, match="interlace"):
        load_camera(tmp_path / "c.json")


@pytest.mark.parametrize("codec, size, expected", [("dvvideo", (720, 576), "bottom-field-first"),
                                                   ("libx264", (320, 240), "top-field-first")])
def test_the_field_order_is_read_from_the_stream_or_its_standard(tmp_path, codec, size, expected):
    """An interlaced stream's field order: x264's flag (top first) as the stream states it; DV states none, and its
    standard fixes the bottom field first (PAL and NTSC alike)."""
    path = tmp_path / ("v.dv" if codec == "dvvideo" else "v.mp4")
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=25)
        stream.width, stream.height, stream.pix_fmt = *size, "yuv420p"
        if codec == "libx264":
            stream.options = {"x264-params": "interlaced=1:tff=1"}
        for _ in range(4):
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.zeros((size[1], size[0], 3), np.uint8),
                                                                   format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    with VideoFile(path).open() as frames:
        assert frames.interlaced == expected
