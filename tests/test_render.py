"""Synthetic video: geometry against cv2.projectPoints, spot centroids, noise statistics, I/O."""

import copy
import hashlib
import math
import os
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from conftest import PROTOCOL_DIR
from gyrorig import ProtocolError, parse_protocol, simulate
from gyrorig.camera import camera_setup
from gyrorig.physics.rotations import euler_to_matrix
from gyrorig.render import background_distribution, render_frames, render_video

#: brightness-weighted centroid of a noiseless, blur-free spot vs the projected centre [px]
CENTROID_TOL_PX = 0.02

BASE = tomllib.loads((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text())


def small(**camera) -> dict:
    """The air-cushion protocol with a small, fast camera (320 x 240 at 100 fps, same field of view)."""
    d = copy.deepcopy(BASE)
    d["camera"].update(width_px=320, height_px=240, fps=100.0, pixel_size_um=3.45 * 4.5, **camera)
    d["scene"]["duration_s"] = 0.2
    return d


def test_truth_matches_independent_projection_of_the_simulated_markers():
    p = parse_protocol(small(motion_blur_samples=1))
    setup = camera_setup(p)
    cam = setup.camera
    truth = pd.concat([t for _, t in render_frames(p, noise=False)], ignore_index=True)
    df = simulate(p, t_eval_s=np.unique(truth.t_marker_s.to_numpy()))
    rot = euler_to_matrix(df.phi_rad.to_numpy(), df.theta_rad.to_numpy(), df.psi_frame_rad.to_numpy())
    for m in setup.markers:
        sel = truth[truth.marker == m.name]
        pos = np.broadcast_to(m.position_m, (len(df), 3)) if m.body == "lab" else rot @ np.asarray(m.position_m)
        px = cv2.projectPoints(np.ascontiguousarray(pos), cam.rvec, cam.tvec, cam.camera_matrix,
                               cam.dist_coeffs)[0].reshape(-1, 2)
        assert np.abs(px - sel[["x_px", "y_px"]].to_numpy()).max() < 1e-6, m.name
    # theta, phi at mid-exposure agree with the simulator
    mid = truth.drop_duplicates("frame")
    ref = simulate(p, t_eval_s=mid.t_s.to_numpy())
    assert np.abs(mid.theta_rad.to_numpy() - ref.theta_rad.to_numpy()).max() < 1e-9


@pytest.mark.parametrize("distortion", [[0, 0, 0, 0, 0], [-0.2, 0.05, 0.001, -0.001, 0.0]])
def test_noiseless_blur_free_spot_centroid_is_at_the_truth(distortion):
    p = parse_protocol(small(motion_blur_samples=1, distortion=distortion))
    cam = camera_setup(p).camera
    bg = cam.sensor.background_e_per_s * cam.exposure_s
    worst = 0.0
    for image, truth in render_frames(p, noise=False, duration_s=0.05):
        for r in truth[truth.visible].itertuples():
            x0, y0 = int(round(r.x_px)), int(round(r.y_px))
            win = image[y0 - 12:y0 + 13, x0 - 12:x0 + 13].astype(np.float64) - bg
            if win.shape != (25, 25):
                continue
            yy, xx = np.mgrid[y0 - 12:y0 + 13, x0 - 12:x0 + 13]
            cx, cy = (win * xx).sum() / win.sum(), (win * yy).sum() / win.sum()
            worst = max(worst, math.hypot(cx - r.x_px, cy - r.y_px))
    assert worst < CENTROID_TOL_PX


def test_background_statistics_match_the_sensor_model():
    p = parse_protocol(small())
    cam = camera_setup(p).camera
    s = cam.sensor
    bg = s.background_e_per_s * cam.exposure_s
    pmf = background_distribution(bg, s)
    k = np.arange(len(pmf))
    mean_model = (k * pmf).sum()
    var_model = ((k - mean_model) ** 2 * pmf).sum()
    # the exact model against its Gaussian approximation: mean bg/gain, variance (bg + rn^2)/gain^2 + 1/12
    assert mean_model == pytest.approx(bg / s.gain_e_per_adu, rel=0.02)
    assert var_model == pytest.approx((bg + s.read_noise_e**2) / s.gain_e_per_adu**2 + 1 / 12, rel=0.05)
    frames = [img for img, _ in render_frames(p, seed=5, duration_s=0.1)]
    patch = np.stack([f[:40, :40] for f in frames]).astype(float)  # a corner no marker reaches
    n = patch.size
    assert patch.mean() == pytest.approx(mean_model, abs=4 * math.sqrt(var_model / n))
    assert patch.var() == pytest.approx(var_model, rel=6 * math.sqrt(2 / n))
    # the distribution itself: a direct Monte Carlo of Poisson + read noise + quantisation
    rng = np.random.default_rng(0)
    e = rng.poisson(bg, 400_000) + rng.normal(0, s.read_noise_e, 400_000)
    adu = np.clip(np.floor(np.clip(e, 0, s.full_well_e) / s.gain_e_per_adu + 0.5), 0, s.max_adu).astype(int)
    mc = np.bincount(adu, minlength=len(pmf))[: len(pmf)] / len(adu)
    assert np.abs(mc - pmf).max() < 5e-3


def test_saturated_marker_clips_at_full_well():
    d = small(motion_blur_samples=1)
    d["markers"]["tip"]["brightness_e_per_s"] = 1e9
    p = parse_protocol(d)
    image, truth = next(render_frames(p, seed=1, duration_s=0.01))
    r = truth[truth.marker == "tip"].iloc[0]
    cam = camera_setup(p).camera
    peak = image[int(round(r.y_px)) - 2:int(round(r.y_px)) + 3, int(round(r.x_px)) - 2:int(round(r.x_px)) + 3]
    assert peak.max() == min(cam.sensor.max_adu, round(cam.sensor.full_well_e / cam.sensor.gain_e_per_adu))


def test_video_decodes_to_the_stated_frames_and_is_reproducible(tmp_path):
    p = parse_protocol(small())
    a = render_video(p, tmp_path / "a", seed=3, calibration_views=0)
    render_video(p, tmp_path / "b", seed=3, calibration_views=0)
    render_video(p, tmp_path / "c", seed=4, calibration_views=0)
    cap = cv2.VideoCapture(a["video"])
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f[:, :, 0] if f.ndim == 3 else f)
    assert len(frames) == a["frames"] == 20 and frames[0].shape == (240, 320)
    expected = [img for img, _ in render_frames(p, seed=3)]
    assert all(np.array_equal(x, y) for x, y in zip(frames, expected))  # lossless
    # same seed, same bits: every decoded pixel and the truth files.  (The Matroska header still
    # differs: FFmpeg writes a random segment UID and the date, and OpenCV cannot ask it for bitexact.)
    decoded = {}
    for d in "abc":
        cap = cv2.VideoCapture(str(tmp_path / d / "video.mkv"))
        decoded[d] = np.stack([cap.read()[1] for _ in range(20)])
    assert np.array_equal(decoded["a"], decoded["b"]) and not np.array_equal(decoded["a"], decoded["c"])
    digest = lambda d, f: hashlib.sha256((tmp_path / d / f).read_bytes()).hexdigest()  # noqa: E731
    assert digest("a", "truth.csv") == digest("b", "truth.csv")
    assert digest("a", "camera.json") == digest("b", "camera.json")
    truth = pd.read_csv(tmp_path / "a" / "truth.csv")
    assert list(truth.columns[:6]) == ["frame", "t_s", "marker", "x_px", "y_px", "visible"]
    cam = tmp_path / "a" / "camera.json"
    assert "camera_matrix" in cam.read_text()
    assert sorted(x.name for x in (tmp_path / "a").iterdir()) == ["camera.json", "truth.csv", "video.mkv"]


def test_mp4_and_sixteen_bit(tmp_path):
    p = parse_protocol(small())
    r = render_video(p, tmp_path / "m", codec="mp4", calibration_views=0, duration_s=0.05)
    assert r["video"].endswith("video.mp4") and cv2.VideoCapture(r["video"]).read()[0]
    d = small()
    d["camera"]["sensor"].update(bit_depth=12, gain_e_per_adu=10500 / 4095)
    r = render_video(parse_protocol(d), tmp_path / "s", calibration_views=0, duration_s=0.05)
    cap = cv2.VideoCapture(r["video"], cv2.CAP_FFMPEG)
    cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    ok, f = cap.read()
    assert ok and f.dtype == np.uint16 and f.max() > 255


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="resident memory read from /proc")
def test_a_long_render_does_not_hold_its_frames_in_memory(tmp_path):
    """The bundled rig's 1440 x 1080 camera over 2 s (400 frames): the process's resident memory grows by less than
    150 MB from frame 100 to the end.  Each frame's small truth table kept until the end fragmented the heap under
    the encoder's frame buffers: 2.3 MB a frame never given back (700 MB here; a 60 s protocol, 12,000 frames, was
    killed for want of memory)."""
    p = parse_protocol(BASE)
    page = os.sysconf("SC_PAGE_SIZE")
    resident = {}

    def progress(done, total):
        resident[done] = int(Path("/proc/self/statm").read_text().split()[1]) * page

    render_video(p, tmp_path / "long", codec="mp4", calibration_views=0, duration_s=2.0, progress=progress)
    first = min(k for k in resident if k > 100)
    assert max(resident.values()) - resident[first] < 150e6, {k: v // 10**6 for k, v in resident.items()}


def test_rolling_shutter_times_each_marker_by_its_row():
    readout = 4e-3
    p = parse_protocol(small(shutter="rolling", readout_time_s=readout))
    truth = pd.concat([t for _, t in render_frames(p, noise=False, duration_s=0.05)], ignore_index=True)
    shift = truth.t_marker_s - truth.t_s
    expected = truth.y_px.clip(0, 239) / 240 * readout
    assert np.abs(shift - expected).max() < 1e-3 * readout + 2 * readout / 240  # fixed point to ~1 row


def test_occluded_markers_are_hidden_and_marked():
    p = parse_protocol(small(motion_blur_samples=1))
    truth = pd.concat([t for _, t in render_frames(p, noise=False, duration_s=1.0)], ignore_index=True)
    hidden = truth[~truth.visible]
    assert len(hidden) > 0 and set(hidden.marker) <= {f"fiducial_{k}" for k in range(1, 6)}


BAD_CAMERAS = [
    (dict(focal_length_mm=0.0), "camera.focal_length_mm"),
    (dict(focal_length_mm=-5.0), "camera.focal_length_mm"),
    (dict(exposure_s=0.02), "camera.exposure_s"),
    (dict(look_at_m=[0.5, 0.0, 0.0]), "pivot projects"),
    (dict(shutter="rolling"), "readout_time_s"),
]


@pytest.mark.parametrize("change,words", BAD_CAMERAS, ids=[w for _, w in BAD_CAMERAS])
def test_impossible_cameras_are_refused(change, words):
    with pytest.raises(ProtocolError, match=words.replace(".", r"\.")):
        camera_setup(parse_protocol(small(**change)))


def test_marker_never_visible_and_interrupted_render_leave_nothing(tmp_path):
    d = small()
    d["markers"]["hidden"] = {"body": "lab", "position_m": [1.0, 0.0, 0.0], "radius_m": 0.002,
                              "brightness_e_per_s": 1e7}  # far outside the field of view
    with pytest.raises(ProtocolError, match="markers.hidden: never in the camera's field of view"):
        render_video(parse_protocol(d), tmp_path / "x", calibration_views=0)
    assert not (tmp_path / "x" / "video.mkv").exists() and not list((tmp_path / "x").glob("*.mkv"))

    def interrupt(done, total):
        if done > 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        render_video(parse_protocol(small()), tmp_path / "y", calibration_views=0, progress=interrupt,
                     duration_s=2.0)
    assert list((tmp_path / "y").iterdir()) == []


def test_calibration_images_show_the_board_where_the_camera_says(tmp_path):
    from gyrorig.render import render_calibration_images

    cam = camera_setup(parse_protocol(BASE)).camera
    info = render_calibration_images(cam, tmp_path, seed=2, n_views=3)
    board = __import__("json").loads((tmp_path / "board.json").read_text())
    obj = np.array([[i * board["square_m"], j * board["square_m"], 0.0] for j in range(6) for i in range(9)])
    for k, view in enumerate(board["views"]):
        img = cv2.imread(str(tmp_path / f"view_{k:02d}.png"), cv2.IMREAD_UNCHANGED)
        ok, corners = cv2.findChessboardCorners(img, (9, 6))
        assert ok, f"board not found in view {k}"
        corners = cv2.cornerSubPix(img, corners, (5, 5), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)).reshape(-1, 2)
        proj = cv2.projectPoints(obj, np.array(view["rvec"]), np.array(view["tvec"]), cam.camera_matrix,
                                 cam.dist_coeffs)[0].reshape(-1, 2)
        # OpenCV may order the corners from either end of the board
        err = min(np.abs(corners - proj).max(), np.abs(corners[::-1] - proj).max())
        assert err < 0.5
    assert info["views"] == 3


def _disc_scene(**camera) -> dict:
    d = small(motion_blur_samples=1, **camera)
    d["markers"]["tip"].update(shape="disc")  # a flat dot facing along the stem
    return d


def test_disc_marker_spot_has_the_projected_ellipse_flux_and_centre():
    """The ray-cast disc (independent of the tracker's spot model): its electrons are the brightness times
    the projected area pi a b (a = f R / depth, b = a |cos| of the viewing angle), and its light centroid
    is the image of the disc's centre to within the perspective shift of a 4 mm disc (< 0.05 px here)."""
    p = parse_protocol(_disc_scene())
    setup = camera_setup(p)
    cam = setup.camera
    tip = next(m for m in setup.markers if m.name == "tip")
    bg = cam.sensor.background_e_per_s * cam.exposure_s
    df = simulate(p, t_eval_s=np.array([0.0025]))
    for image, truth in render_frames(p, noise=False, duration_s=0.01):
        r = truth[truth.marker == "tip"].iloc[0]
        x0, y0 = int(round(r.x_px)), int(round(r.y_px))
        win = image[y0 - 15:y0 + 16, x0 - 15:x0 + 16].astype(float) - bg
        # the tip's axis and the direction to the camera give the viewing angle of the disc
        axis = df[["tip_x", "tip_y", "tip_z"]].to_numpy()[0]
        centre = 0.14 * axis
        view = cam.centre_m - centre
        depth = float((cam.rotation @ centre + cam.tvec)[2])
        a_px = cam.camera_matrix[0, 0] * tip.radius_m / depth
        cos_view = abs(axis @ view) / np.linalg.norm(view)
        flux = tip.brightness_e_per_s * cam.exposure_s * np.pi * a_px * a_px * cos_view
        assert win.sum() == pytest.approx(flux, rel=0.03)
        yy, xx = np.mgrid[y0 - 15:y0 + 16, x0 - 15:x0 + 16]
        cx, cy = (win * xx).sum() / win.sum(), (win * yy).sum() / win.sum()
        assert math.hypot(cx - r.x_px, cy - r.y_px) < 0.05
        # an ellipse, not a circle: its second moments' ratio is the viewing angle's cosine squared
        cov = np.cov(np.vstack([xx.ravel(), yy.ravel()]), aweights=np.clip(win.ravel(), 0, None))
        ev = np.linalg.eigvalsh(cov)
        psf2 = cam.psf_sigma_px**2 + 1 / 12  # the PSF and the pixel's area add to each axis
        assert math.sqrt((ev[0] - psf2) / (ev[1] - psf2)) == pytest.approx(cos_view, rel=0.05)
        break


def test_rotor_markers_whirl_with_the_spin_and_frame_markers_do_not():
    d = small(motion_blur_samples=1)
    d["markers"]["rotor_dot"] = {"body": "rotor", "position_m": [0.03, 0.0, 0.1], "radius_m": 0.0025,
                                 "brightness_e_per_s": 2.5e7}
    p = parse_protocol(d)
    truth = pd.concat([t for _, t in render_frames(p, noise=False, duration_s=0.05)], ignore_index=True)
    df = simulate(p, t_eval_s=np.unique(truth.t_marker_s.to_numpy()))
    cam = camera_setup(p).camera
    for name, psi in (("rotor_dot", df.psi_rad), ("crossbar_a", df.psi_frame_rad)):
        rot = euler_to_matrix(df.phi_rad.to_numpy(), df.theta_rad.to_numpy(), psi.to_numpy())
        pos = rot @ (np.array([0.03, 0.0, 0.1]) if name == "rotor_dot" else np.array([0.03, 0.0, 0.11]))
        px = cv2.projectPoints(np.ascontiguousarray(pos), cam.rvec, cam.tvec, cam.camera_matrix,
                               cam.dist_coeffs)[0].reshape(-1, 2)
        sel = truth[truth.marker == name]
        # the renderer's spline paths: 64 samples per turn for markers that whirl (interpolation error
        # ~(2 pi / 64)^4 / 384 of the radius, 1e-5 px here), far denser for the others
        tol = 1e-4 if name == "rotor_dot" else 1e-6
        assert np.abs(px - sel[["x_px", "y_px"]].to_numpy()).max() < tol, name


def test_gamma_and_illumination_drift_change_the_recorded_values_as_stated():
    linear = parse_protocol(small(motion_blur_samples=1))
    d = small(motion_blur_samples=1, illumination_drift_fraction=0.05, illumination_drift_period_s=0.08)
    d["camera"]["sensor"]["gamma"] = 2.2
    bent = parse_protocol(d)
    a = [im for im, _ in render_frames(linear, seed=1, duration_s=0.05)]
    b = [im for im, _ in render_frames(bent, seed=1, duration_s=0.05)]
    cam = camera_setup(bent).camera
    top = cam.sensor.max_adu
    for k, (x, y) in enumerate(zip(a, b)):
        # the background's median follows the lighting and the response curve
        light = cam.illumination((k + 0.5) / cam.fps - 0.5 / cam.fps + cam.exposure_s / 2)
        expected = top * (np.median(x) * light / top) ** (1 / 2.2)
        assert abs(np.median(y) - expected) <= 0.02 * expected + 1.0
    with pytest.raises(ProtocolError, match="gamma"):
        d["camera"]["sensor"]["gamma"] = 0.0
        parse_protocol(d) and camera_setup(parse_protocol(d))


@pytest.mark.parametrize("change,key", [({"shape": "cube"}, "shape"), ({"normal": [0, 0, 1]}, "normal"),
                                        ({"shape": "disc", "normal": [0, 0, 0]}, "normal"),
                                        ({"body": "stem"}, "body")])
def test_bad_marker_shapes_are_refused_by_name(change, key):
    d = small()
    d["markers"]["tip"].update(change)
    with pytest.raises(ProtocolError, match=f"markers.tip.{key}"):
        camera_setup(parse_protocol(d))
