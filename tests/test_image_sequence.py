"""Image sequences (issue 19): a folder of PNG, TIFF or BMP frames in name order, or a multi-page TIFF stack, with
frame times from a timestamps table or from camera.json's fps, tracks exactly like the video it was copied from
(a folder of JPEGs as a lossy copy); bad folders and timestamps are bad input (exit 2, the file, row and column
named, nothing written)."""

import copy
import json
import tomllib

import cv2
import numpy as np
import pandas as pd
import pytest

from conftest import PROTOCOL_DIR
from test_tracking import gray_frames
from gyrorig import parse_protocol
from gyrorig.cli import main
from gyrorig.render import render_video
from gyrorig.tracking import BadInputError, ImageFolder, load_camera, track

BASE = tomllib.loads((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text())


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    d = copy.deepcopy(BASE)
    d["camera"].update(width_px=640, height_px=480, pixel_size_um=3.45 * 2.25)
    d["scene"]["duration_s"] = 0.15
    out = tmp_path_factory.mktemp("seq")
    render_video(parse_protocol(d), out / "v", seed=4, calibration_views=0)
    frames = gray_frames(out / "v" / "video.mkv")
    return out, parse_protocol(d), load_camera(out / "v" / "camera.json"), frames


def _write(folder, frames, suffix, dtype, names=None):
    folder.mkdir()
    for k, f in enumerate(frames):
        name = names[k] if names else f"frame{k}{suffix}"  # no zero padding: name order must be numeric
        assert cv2.imwrite(str(folder / name), f.astype(dtype))
    return folder


@pytest.mark.parametrize("suffix,dtype", [(".png", np.uint16), (".tif", np.uint8), (".bmp", np.uint8),
                                          ("stack", np.uint16), ("stack", np.uint8)])
def test_an_image_copy_tracks_like_the_video(rendered, tmp_path, suffix, dtype):
    out, protocol, cam, frames = rendered
    if suffix == "stack":  # one multi-page TIFF, as a scientific camera or ImageJ saves a recording
        folder = tmp_path / "stack.tif"
        assert cv2.imwritemulti(str(folder), [f.astype(dtype) for f in frames])
    else:
        folder = _write(tmp_path / "images", frames, suffix, dtype)
    from_video = track(out / "v" / "video.mkv", cam, protocol, frame_dots=False).angles
    from_images = track(folder, cam, protocol, frame_dots=False).angles
    assert from_images.frame.tolist() == from_video.frame.tolist()
    for col in ("t_s", "theta_rad", "phi_rad", "theta_sigma_rad"):
        np.testing.assert_allclose(from_images[col], from_video[col], rtol=0, atol=1e-12)


def test_timestamps_with_dropped_frames_give_gaps(rendered, tmp_path):
    out, protocol, cam, frames = rendered
    dropped = {7, 12}
    kept = [k for k in range(len(frames)) if k not in dropped]
    folder = _write(tmp_path / "images", [frames[k] for k in kept], ".png", np.uint8)
    pd.DataFrame({"frame": kept, "t_s": np.array(kept) / cam.fps}).to_csv(folder / "timestamps.csv", index=False)
    angles = track(folder, cam, protocol, frame_dots=False).angles
    assert angles.frame.tolist() == kept
    np.testing.assert_allclose(angles.t_s, np.array(kept) / cam.fps + cam.exposure_s / 2, rtol=0, atol=1e-12)


def test_a_tiff_stacks_timestamps_beside_it_give_gaps(rendered, tmp_path):
    out, protocol, cam, frames = rendered
    kept = [k for k in range(len(frames)) if k not in {5, 6, 20}]
    assert cv2.imwritemulti(str(tmp_path / "take.tif"), [frames[k] for k in kept])
    pd.DataFrame({"frame": kept, "t_s": np.array(kept) / cam.fps}).to_csv(tmp_path / "take.timestamps.csv",
                                                                         index=False)
    angles = track(tmp_path / "take.tif", cam, protocol, frame_dots=False).angles
    assert angles.frame.tolist() == kept


@pytest.mark.parametrize("kind", ["not-a-tiff", "times-count", "folder-of-stacks"])
def test_a_bad_tiff_stack_is_bad_input(rendered, tmp_path, kind):
    out, protocol, cam, frames = rendered
    stack = tmp_path / "take.tif"
    if kind == "not-a-tiff":
        stack.write_bytes(b"II*\0 not a tiff")
    elif kind == "folder-of-stacks":  # each file many frames: not a folder of one image per frame
        for name in ("a.tif", "b.tif"):
            assert cv2.imwritemulti(str(tmp_path / name), frames[:10])
        stack = tmp_path
    else:
        assert cv2.imwritemulti(str(stack), frames[:10])
        pd.DataFrame({"frame": range(9), "t_s": np.arange(9) / 200.0}).to_csv(tmp_path / "take.timestamps.csv",
                                                                              index=False)
    with pytest.raises(BadInputError):
        track(stack, cam, protocol, frame_dots=False)


def test_a_colour_tiff_stack_keeps_its_channels(tmp_path):
    """A colour stack's pages come as RGB (a red sticker's channel is the red one), 16-bit values as stored."""
    from gyrorig.tracking.images import TiffStack

    bgr = np.zeros((6, 8, 3), np.uint8)
    bgr[..., 2] = 200  # red, in OpenCV's order
    grey16 = np.arange(48, dtype=np.uint16).reshape(6, 8) * 1000
    assert cv2.imwritemulti(str(tmp_path / "rgb.tif"), [bgr, bgr])
    assert cv2.imwritemulti(str(tmp_path / "grey.tif"), [grey16] * 3)
    with TiffStack(tmp_path / "rgb.tif").open(colour=True) as frames:
        rgb = [f for f, _ in frames]
    assert len(rgb) == 2 and rgb[0][..., 0].min() == 200 and rgb[0][..., 2].max() == 0
    with TiffStack(tmp_path / "grey.tif").open() as frames:
        assert all(np.array_equal(f, grey16) for f, _ in frames)


def test_a_folder_of_jpegs_is_tracked_as_a_lossy_copy(rendered, tmp_path):
    """JPEG changes pixel values: the frames are read (all of them) and the sensor's noise model is not used;
    each frame's angles stay within 5 of their errors of the lossless video's (whose own errors are far smaller)."""
    out, protocol, cam, frames = rendered
    folder = tmp_path / "jpeg"
    folder.mkdir()
    for k, f in enumerate(frames):
        assert cv2.imwrite(str(folder / f"f{k:03d}.jpg"), f.astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90])
    with ImageFolder(folder).open() as opened:
        assert opened.lossy and opened.count == len(frames)
    exact = track(out / "v" / "video.mkv", cam, protocol, frame_dots=False).angles
    lossy = track(folder, cam, protocol, frame_dots=False).angles
    m = exact.merge(lossy, on="frame", suffixes=("", "_jpeg")).dropna(subset=["theta_rad", "theta_rad_jpeg"])
    assert len(m) >= len(frames) - 2
    for angle in ("theta", "phi"):
        pull = (m[f"{angle}_rad_jpeg"] - m[f"{angle}_rad"]) / m[f"{angle}_sigma_rad_jpeg"]
        assert pull.abs().max() < 5


def test_a_folder_of_several_image_kinds_is_read_as_its_most_numerous(rendered, tmp_path, caplog):
    """A stray picture of another kind (a preview, a snapshot of the set-up) is left out, with a warning."""
    out, protocol, cam, frames = rendered
    folder = _write(tmp_path / "images", frames, ".png", np.uint8)
    cv2.imwrite(str(folder / "setup.jpg"), frames[0][::2, ::2])
    with caplog.at_level("WARNING", logger="gyrorig.tracking.images"):
        source = ImageFolder(folder)
    assert [f.suffix for f in source.files] == [".png"] * len(frames)
    assert any(r.levelname == "WARNING" for r in caplog.records)
    assert track(folder, cam, protocol, frame_dots=False).angles.frame.tolist() == list(range(len(frames)))


def _bad_folder(tmp_path, frames, kind):
    folder = _write(tmp_path / "images", frames[:12], ".png", np.uint8)
    n = 12
    if kind == "mixed-sizes":
        cv2.imwrite(str(folder / "frame5.png"), frames[5][:200, :300])
    elif kind == "unreadable":
        (folder / "frame3.png").write_bytes(b"not an image")
    elif kind == "times-not-increasing":
        t = np.arange(n) / 200.0
        t[6] = t[4]
        pd.DataFrame({"frame": range(n), "t_s": t}).to_csv(folder / "timestamps.csv", index=False)
    elif kind == "times-count":
        pd.DataFrame({"frame": range(n - 2), "t_s": np.arange(n - 2) / 200.0}).to_csv(folder / "timestamps.csv",
                                                                                      index=False)
    elif kind == "times-column":
        pd.DataFrame({"frame": range(n), "time": np.arange(n) / 200.0}).to_csv(folder / "timestamps.csv", index=False)
    elif kind == "empty":
        for f in folder.iterdir():
            f.unlink()
    return folder


BAD_KINDS = ["mixed-sizes", "unreadable", "times-not-increasing", "times-count", "times-column", "empty"]


@pytest.mark.parametrize("kind", BAD_KINDS)
def test_bad_image_folders_are_bad_input(rendered, tmp_path, kind):
    out, protocol, cam, frames = rendered
    folder = _bad_folder(tmp_path, frames, kind)
    with pytest.raises(BadInputError):
        track(ImageFolder(folder) if kind != "empty" else folder, cam, protocol, frame_dots=False)


@pytest.mark.parametrize("kind", ["mixed-sizes", "times-not-increasing"])
def test_track_exits_2_on_a_bad_image_folder(rendered, tmp_path, capsys, kind):
    out, protocol, cam, frames = rendered
    folder = _bad_folder(tmp_path, frames, kind)
    code = main(["track", str(folder), "--camera", str(out / "v" / "camera.json"), "--protocol",
                 str(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), "--out", str(tmp_path / "t"), "--tip-only"])
    assert code == 2 and not (tmp_path / "t").exists()
    assert "Traceback" not in capsys.readouterr().err


def test_frame_interval_statistics_and_the_warnings():
    """Issue 19: the tracker reports the measured frame intervals and says when they disagree with
    camera.json (another rate, or a variable frame rate as phone video has); dropped frames are counted."""
    import numpy as np

    from gyrorig.tracking.timing import frame_interval_stats

    t = np.arange(200) / 200.0
    good = frame_interval_stats(np.delete(t, [50, 51, 120]), 200.0)
    assert good["agrees_with_camera"] and good["dropped_frames"] == 3
    assert good["median_interval_s"] == pytest.approx(0.005)
    other = frame_interval_stats(t, 210.0)
    assert not other["agrees_with_camera"] and other["measured_fps"] == pytest.approx(200.0)
    rng = np.random.default_rng(0)
    vfr = np.cumsum(0.005 * (1 + 0.2 * rng.uniform(-1, 1, 200)))
    jittery = frame_interval_stats(vfr, 200.0)
    assert not jittery["agrees_with_camera"] and jittery["jitter_rel"] > 0.05


@pytest.mark.parametrize("capture", ["grid", "file"])
def test_the_tips_path_tells_a_jittering_clock_from_a_varying_capture(capture):
    """A file's times scattered by 15 % of the interval (SD): either the sensor's true times of a capture whose pace
    varied, or a clock jittering about a steady capture.  The tip (1.5 px per frame on a circle, 0.1 px errors)
    is where the capture put it; the times whose residuals about its path are smaller are taken: each frame's
    capture time, to 1e-9 s, the frames near the grid too."""
    import numpy as np
    import pandas as pd

    from gyrorig.tracking.timing import FrameClock, capture_on_grid

    fps, n = 240.0, 240
    rng = np.random.default_rng(4)
    grid = np.arange(n) / fps
    stamps = grid + rng.normal(0.0, 0.15 / fps, n)
    stamps[0] = 0.0
    taken = grid if capture == "grid" else stamps
    xy = 300.0 + 57.3 * np.column_stack([np.cos(taken * fps / 38.2), np.sin(taken * fps / 38.2)])
    xy += rng.normal(0.0, 0.1, xy.shape)
    clock = FrameClock(fps, 1.0, "clip", check_rate=False)
    numbered = [clock.number(t, k) for k, t in enumerate(stamps)]
    assert np.sum(np.abs(stamps - grid) > 0.3 / fps) >= 10  # frames the clock alone would keep off the grid
    angles = pd.DataFrame({"frame": [f for f, _ in numbered], "t_s": [t for _, t in numbered]})
    markers = angles.copy()
    said = capture_on_grid(angles, markers, {k: tuple(p) for k, p in enumerate(xy)},
                           {k: 0.01 * np.eye(2) for k in range(n)}, clock)
    assert said["capture"] == capture and said["off_grid_frames"] == n - 1 and abs(said["z"]) > 3
    np.testing.assert_allclose(angles.t_s, taken, atol=1e-9)
    np.testing.assert_allclose(markers.t_s, taken, atol=1e-9)


def test_a_still_tip_leaves_the_capture_times_unknown_and_the_clocks_times_kept():
    """A tip that does not move cannot tell the file's times from the grid's: ``unknown``, and each frame keeps
    the time the clock gave it (the grid's within 0.3 of an interval, else the file's)."""
    import numpy as np
    import pandas as pd

    from gyrorig.tracking.timing import FrameClock, capture_on_grid

    fps, n = 240.0, 120
    rng = np.random.default_rng(5)
    stamps = np.arange(n) / fps + rng.normal(0.0, 0.15 / fps, n)
    stamps[0] = 0.0
    clock = FrameClock(fps, 1.0, "clip", check_rate=False)
    numbered = [clock.number(t, k) for k, t in enumerate(stamps)]
    angles = pd.DataFrame({"frame": [f for f, _ in numbered], "t_s": [t for _, t in numbered]})
    given = angles.t_s.to_numpy().copy()
    xy = 300.0 + rng.normal(0.0, 0.1, (n, 2))
    said = capture_on_grid(angles, angles.copy(), {k: tuple(p) for k, p in enumerate(xy)},
                           {k: 0.01 * np.eye(2) for k in range(n)}, clock)
    assert said["capture"] == "unknown" and abs(said["z"]) <= 3
    np.testing.assert_array_equal(angles.t_s, given)


def test_container_rounding_is_not_a_variable_rate():
    """240 fps stored to 1 ms (Matroska) alternates 4 and 5 ms intervals: on camera.json's grid, no warning."""
    import numpy as np

    from gyrorig.tracking.timing import frame_interval_stats

    t = np.round(np.arange(480) / 240.0, 3)
    stats = frame_interval_stats(t, 240.0)
    assert stats["agrees_with_camera"] and stats["jitter_rel"] > 0.05


def test_a_recording_is_recognised_by_its_fingerprint_wherever_it_is_copied(tmp_path):
    """``sources.fingerprint``: the same for a copy (file or image folder), different for another recording, None
    for frames in memory (what lets the tracker know that a motion-found pose came from the record it tracks)."""
    from gyrorig.tracking.sources import FrameArrays, fingerprint

    rng = np.random.default_rng(0)
    (tmp_path / "a.bin").write_bytes(rng.integers(0, 256, 3_000_000, dtype=np.uint8).tobytes())
    (tmp_path / "b.bin").write_bytes((tmp_path / "a.bin").read_bytes())
    (tmp_path / "c.bin").write_bytes((tmp_path / "a.bin").read_bytes()[:-1] + b"x")  # differs only at the end
    assert fingerprint(tmp_path / "a.bin") == fingerprint(tmp_path / "b.bin") != fingerprint(tmp_path / "c.bin")
    for name in ("f", "g"):
        (tmp_path / name).mkdir()
    for k in range(3):
        image = rng.integers(0, 4096, (20, 30), dtype=np.uint16)
        for name in ("f", "g"):
            cv2.imwrite(str(tmp_path / name / f"frame{k}.png"), image)
    assert fingerprint(tmp_path / "f") == fingerprint(tmp_path / "g")
    (tmp_path / "g" / "frame2.png").unlink()
    assert fingerprint(tmp_path / "f") != fingerprint(tmp_path / "g")
    assert fingerprint(FrameArrays([np.zeros((4, 4), np.uint8)])) is None


def _camera_without_fps(out, tmp_path):
    d = json.loads((out / "v" / "camera.json").read_text())
    d.pop("fps")
    (tmp_path / "camera.json").write_text(json.dumps(d))
    return load_camera(tmp_path / "camera.json")


def test_without_any_frame_rate_the_folder_is_bad_input(rendered, tmp_path):
    out, protocol, cam, frames = rendered
    folder = _write(tmp_path / "images", frames[:12], ".png", np.uint8)
    with pytest.raises(BadInputError):
        track(folder, _camera_without_fps(out, tmp_path), protocol, frame_dots=False)


def test_timestamps_in_milliseconds_are_named(rendered, tmp_path, caplog):
    """Times in ms: refused against camera.json's fps; without one, tracked at the times' rate with a warning."""
    out, protocol, cam, frames = rendered
    folder = _write(tmp_path / "images", frames[:12], ".png", np.uint8)
    pd.DataFrame({"frame": range(12), "t_s": np.arange(12) / cam.fps * 1000.0}).to_csv(folder / "timestamps.csv",
                                                                                      index=False)
    with pytest.raises(BadInputError):
        track(folder, cam, protocol, frame_dots=False)
    result = track(folder, _camera_without_fps(out, tmp_path), protocol, frame_dots=False)
    assert result.angles.theta_rad.notna().all()
    assert "WARNING" in {r.levelname for r in caplog.records if r.name.startswith("gyrorig.tracking.")}


def test_a_clip_tracks_its_part_of_the_recording_with_the_files_numbers(rendered, tmp_path):
    """--start/--end: the frames between the ends, numbered and timed as in the whole recording, the same angles
    within their errors (the tracker acquires the tip afresh at the clip's start)."""
    from gyrorig.tracking.sources import Clip, Cut

    out, protocol, cam, frames = rendered
    video = out / "v" / "video.mkv"
    whole = track(video, cam, protocol, frame_dots=False).angles.set_index("frame")
    for start, end in ((Cut(0.05), Cut(0.1)), (Cut(10, "f"), Cut(20, "f"))):
        part = track(Clip(video, start, end), cam, protocol, frame_dots=False).angles.set_index("frame")
        first, last = 10, 20  # at 200 fps 0.05 s is frame 10 and 0.1 s frame 20
        assert part.index.tolist() == list(range(first, last + 1))
        np.testing.assert_allclose(part.t_s, whole.loc[part.index, "t_s"], rtol=0, atol=1e-9)
        ok = part.theta_rad.notna()
        dev = (part.theta_rad[ok] - whole.loc[part.index[ok], "theta_rad"]) / part.theta_sigma_rad[ok]
        assert ok.mean() > 0.9 and np.all(np.abs(dev) < 1.0)


@pytest.mark.parametrize("ends", [("0.1", "0.05"), ("abc", None), ("-1", None), ("2.5f", None), ("5", None)])
def test_bad_clip_ends_are_bad_input(rendered, tmp_path, capsys, ends):
    out, protocol, cam, frames = rendered
    argv = ["track", str(out / "v" / "video.mkv"), "--camera", str(out / "v" / "camera.json"), "--protocol",
            str(PROTOCOL_DIR / "air-cushion-heavy-top.toml"), "--out", str(tmp_path / "t"), "--tip-only",
            "--start", ends[0]] + (["--end", ends[1]] if ends[1] else [])
    assert main(argv) == 2 and not (tmp_path / "t").exists()
    assert "Traceback" not in capsys.readouterr().err


def test_a_camera_file_without_exposure_takes_the_protocols(rendered, tmp_path):
    """A calibration's camera.json records no exposure: the protocol's [camera] exposure_s is used (mid-exposure
    times, the fit's exposure average) instead of 0."""
    out, protocol, cam, frames = rendered
    d = json.loads((out / "v" / "camera.json").read_text())
    d.pop("exposure_s")
    (tmp_path / "camera.json").write_text(json.dumps(d))
    result = track(out / "v" / "video.mkv", load_camera(tmp_path / "camera.json"), protocol, frame_dots=False)
    stated = protocol.extra["camera"]["exposure_s"]
    assert result.camera.exposure_s == stated
    np.testing.assert_allclose(result.angles.t_s - result.angles.frame / cam.fps, stated / 2, rtol=0, atol=1e-12)


def test_a_track_call_parses_the_markers_once(rendered, monkeypatch):
    """One track() call parses the protocol's [markers] once (three times before: the tip, the follower's fiducials,
    the frame's dots; the pose from the fiducials takes the same parse)."""
    import gyrorig.markers
    import gyrorig.tracking.pose
    import gyrorig.tracking.tracker

    out, protocol, cam, frames = rendered
    calls = []
    real = gyrorig.markers.parse_markers

    def counting(source):
        calls.append(source)
        return real(source)

    for module in (gyrorig.tracking.tracker, gyrorig.tracking.pose):
        monkeypatch.setattr(module, "parse_markers", counting)
    result = track(out / "v" / "video.mkv", cam, protocol)
    assert result.angles.theta_rad.notna().any()
    assert len(calls) == 1


def test_tracking_needs_only_the_markers(rendered, tmp_path):
    """A recording's rig need not be known to track it: a protocol of its markers alone (no [rig], [launch],
    [scene]) gives the same track as the whole protocol; the fit, which compares with theory, still needs the rig."""
    out, protocol, cam, frames = rendered
    text = (PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
    kept, keep = [], True
    for line in text.splitlines():
        if line.startswith("["):
            keep = line.strip() not in ("[rig]", "[launch]", "[scene]")
        if keep:
            kept.append(line)
    markers_only = tmp_path / "markers-only.toml"
    markers_only.write_text("\n".join(kept) + "\n")
    assert "rig" not in tomllib.loads(markers_only.read_text())
    video, camera = str(out / "v" / "video.mkv"), str(out / "v" / "camera.json")
    for name, path in (("whole", PROTOCOL_DIR / "air-cushion-heavy-top.toml"), ("markers", markers_only)):
        assert main(["track", video, "--camera", camera, "--protocol", str(path), "--out", str(tmp_path / name)]) == 0
    whole, markers = (pd.read_csv(tmp_path / name / "angles.csv") for name in ("whole", "markers"))
    assert whole.theta_rad.notna().sum() > 0.9 * len(whole)
    pd.testing.assert_frame_equal(whole, markers)
    assert main(["fit", str(tmp_path / "markers" / "angles.csv"), "--protocol", str(markers_only),
                 "--out", str(tmp_path / "fit")]) == 2


def test_a_clip_ended_early_reports_no_damage(rendered):
    """A lossless recording cut at --end: the packets in the decoder's threads when reading stops have no pictures
    yet, which is no damage (they were reported as packets the decoder skipped)."""
    from gyrorig.tracking.sources import Clip, parse_cut

    out, protocol, cam, frames = rendered
    res = track(Clip(out / "v" / "video.mkv", None, parse_cut("12f", "--end")), cam, protocol)
    assert len(res.angles) == 13 and res.source_problems == ()


def test_a_grey_quicktime_raw_file_reads_its_own_levels(tmp_path):
    """An 8-bit grey raw QuickTime file (a scientific camera's export) is decoded as a palette of greys (inverted):
    its levels are read through that palette exactly, where FFmpeg's grey conversion put some 1 off."""
    import av

    from gyrorig.tracking.sources import VideoFile

    rng = np.random.default_rng(0)
    written = [rng.integers(0, 256, (48, 64), dtype=np.uint8) for _ in range(3)]
    path = tmp_path / "grey.mov"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("rawvideo", rate=30)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "gray"
        for f in written:
            for packet in stream.encode(av.VideoFrame.from_ndarray(f, format="gray")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    with VideoFile(path).open() as frames:
        read = [np.asarray(image) for image, _ in frames]
    assert len(read) == 3
    for a, b in zip(read, written):
        np.testing.assert_array_equal(a, b)
