"""The analysis chain on files: render -> analyze (track, smooth, fit, report), batch, bad input."""

from __future__ import annotations

import json
import numpy as np
import pandas as pd
import pytest

from gyrorig.camera import with_image_size
from gyrorig.cli import main
from gyrorig.protocols import load_protocol
from gyrorig.render import render_video

from _stats import chi2_red_band
from conftest import PROTOCOL_DIR


def _small(name: str):
    return with_image_size(load_protocol(PROTOCOL_DIR / f"{name}.toml"), 640, 480)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("analysis")
    p = _small("air-cushion-heavy-top")
    render_video(p, root / "video", seed=3, duration_s=2.0, calibration_views=0)
    proto = root / "protocol.toml"
    # the analysis reads a protocol file: write the 640x480 variant next to the video
    text = (PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
    text = text.replace("width_px = 1440", "width_px = 640").replace("height_px = 1080", "height_px = 480")
    text = text.replace("pixel_size_um = 3.45", f"pixel_size_um = {3.45 * 2.25}")
    proto.write_text(text)
    return root, proto


def test_analyze_recovers_truth_within_errors_and_writes_a_report(rendered, capsys):
    root, proto = rendered
    out = root / "an"
    code = main(["analyze", str(root / "video" / "video.mkv"), "--camera", str(root / "video" / "camera.json"),
                 "--protocol", str(proto), "--out", str(out), "--truth", str(root / "video" / "truth.csv")])
    assert code == 0
    doc = json.loads((out / "fit.json").read_text())
    q = doc["quantities"]
    for name in ("precession_rate_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad"):
        assert q[name]["status"] == "determined"
        assert abs(q[name]["pull"]) < 4, (name, q[name])
        # against the exact (elliptic) prediction too: the model is exact for this scene
        assert abs(q[name]["diff_exact_se"]) < 4, (name, q[name])
        assert q[name]["units"] in ("rad/s", "rad")
    assert "tilt_time_constant_s" not in q  # undamped: no tau
    assert "psi_rad" not in pd.read_csv(out / "track" / "angles.csv")  # the fit does not use the frame's dots
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html and "wrong sign" in html
    sm = pd.read_csv(out / "smoothed.csv")
    assert {"theta_rate_rad_s", "phi_rate_rad_s", "cov_00", "status"} <= set(sm.columns)
    assert "report:" in capsys.readouterr().out


def test_fit_refuses_a_table_without_sigmas_and_writes_nothing(rendered, tmp_path, capsys):
    root, proto = rendered
    assert main(["-q", "track", str(root / "video" / "video.mkv"), "--camera", str(root / "video" / "camera.json"),
                 "--protocol", str(proto), "--out", str(tmp_path / "t")]) == 0
    a = pd.read_csv(tmp_path / "t" / "angles.csv").drop(columns=["phi_sigma_rad"])
    a.to_csv(tmp_path / "angles.csv", index=False)
    assert main(["fit", str(tmp_path / "angles.csv"), "--protocol", str(proto), "--out", str(tmp_path / "o")]) == 2
    assert "phi_sigma_rad" in capsys.readouterr().err
    assert not (tmp_path / "o" / "fit.json").exists()


def test_a_folder_of_camcorder_files_is_a_batch(rendered, tmp_path):
    """A camcorder's AVCHD file (``.MTS``, upper case as cameras name them) in a folder is one of its videos (the
    folder was refused as holding no videos)."""
    root, proto = rendered
    folder = tmp_path / "card"
    folder.mkdir()
    (folder / "00001.MTS").symlink_to(root / "video" / "video.mkv")  # FFmpeg reads a file by its content
    code = main(["-q", "analyze", str(folder), "--camera", str(root / "video" / "camera.json"), "--protocol",
                 str(proto), "--out", str(tmp_path / "batch")])
    assert code == 0
    s = pd.read_csv(tmp_path / "batch" / "summary.csv")
    assert list(s.status) == ["ok"] and s.video[0].endswith("00001.MTS")


def test_batch_skips_an_unreadable_video_and_summarises(rendered, tmp_path, capsys):
    root, proto = rendered
    folder = tmp_path / "videos"
    folder.mkdir()
    (folder / "a_good.mkv").symlink_to(root / "video" / "video.mkv")
    (folder / "b_broken.mkv").write_bytes(b"not a video at all" * 100)
    code = main(["analyze", str(folder), "--camera", str(root / "video" / "camera.json"), "--protocol", str(proto),
                 "--out", str(tmp_path / "batch")])
    assert code == 3  # not every video could be analysed
    s = pd.read_csv(tmp_path / "batch" / "summary.csv")
    assert list(s.status) == ["ok", "failed"]
    assert np.isfinite(s.precession_rate_rad_s[0]) and "b_broken" in s.video[1]
    assert isinstance(s.error[1], str) and s.error[1]
    # the batch analyses a video as the single command does
    assert main(["-q", "analyze", str(root / "video" / "video.mkv"), "--camera", str(root / "video" / "camera.json"),
                 "--protocol", str(proto), "--out", str(tmp_path / "single")]) == 0
    single = json.loads((tmp_path / "single" / "fit.json").read_text())["quantities"]
    assert s.precession_rate_rad_s[0] == pytest.approx(single["precession_rate_rad_s"]["value"], rel=1e-12)
    assert "precession_rate_rad_s" in (tmp_path / "batch" / "a_good" / "report.html").read_text()
    # asked for, the frame's dots are tracked too (psi); the tip's frames are the same but for where a dot is near
    # it, so the fit agrees within a small part of its standard error
    assert main(["-q", "analyze", str(root / "video" / "video.mkv"), "--camera", str(root / "video" / "camera.json"),
                 "--protocol", str(proto), "--out", str(tmp_path / "dots"), "--frame-dots"]) == 0
    assert pd.read_csv(tmp_path / "dots" / "track" / "angles.csv").psi_rad.notna().mean() > 0.9
    dots = json.loads((tmp_path / "dots" / "fit.json").read_text())["quantities"]["precession_rate_rad_s"]
    assert abs(dots["value"] - single["precession_rate_rad_s"]["value"]) < 0.5 * dots["standard_error"]


def test_batch_rows_get_their_own_folders_inside_out_and_inert_cells(rendered, tmp_path, monkeypatch):
    """Issue 33: manifest rows a/take.mkv and b/take.mkv shared one result folder (the second won), a row sub/..
    wrote into the folder above --out, and a video named like a spreadsheet formula reached summary.csv as one."""
    root, proto = rendered
    for sub in ("a", "b", "sub"):
        (tmp_path / sub).mkdir()
    (tmp_path / "a" / "take.mkv").symlink_to(root / "video" / "video.mkv")
    (tmp_path / "b" / "take.mkv").symlink_to(root / "video" / "video.mkv")
    (tmp_path / "=HYPERLINK(1).mkv").write_bytes(b"not a video")
    rows = ["a/take.mkv", "b/take.mkv", "sub/..", "=HYPERLINK(1).mkv"]
    manifest = tmp_path / "manifest.csv"
    manifest.write_text("video,protocol,camera\n" + "".join(f"{v},{proto},{root / 'video' / 'camera.json'}\n"
                                                            for v in rows))
    out = tmp_path / "batch"
    monkeypatch.chdir(tmp_path)  # the manifest named relative to the working folder, as a user types it
    assert main(["analyze", "manifest.csv", "--out", "batch"]) == 3  # two rows cannot be analysed
    s = pd.read_csv(out / "summary.csv")
    assert list(s.status) == ["ok", "ok", "failed", "failed"]
    folders = [(tmp_path / p).resolve() for p in s.out]
    assert len(set(folders)) == 4 and all(f.parent == out.resolve() for f in folders)
    assert all((f / "fit.json").is_file() for f in folders[:2])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["a", "b", "sub", "=HYPERLINK(1).mkv", "manifest.csv",
                                                                 "batch"])  # nothing written beside --out
    assert not any(str(v).startswith("=") for v in s.video)


def _analyze_rendered(tmp_path, name: str, duration: float, seed: int = 5):
    from gyrorig.analysis import analyze_video

    p = _small(name)
    render_video(p, tmp_path / "video", seed=seed, duration_s=duration, calibration_views=0)
    res = analyze_video(tmp_path / "video" / "video.mkv", tmp_path / "video" / "camera.json", p, tmp_path / "an",
                        truth_csv=tmp_path / "video" / "truth.csv")
    return res["fit"]


def test_analyze_damped_b2_rig_recovers_the_growing_tilt(tmp_path):
    fit = _analyze_rendered(tmp_path, "eddy-damped-top-b2", 2.0)
    lam = fit.quantities["tilt_growth_rate_per_s"]
    assert lam.status == "determined" and abs(lam.pull) < 4
    assert lam.value > 0 > lam.paper  # grows; the paper's eq. 25a says it decays
    for name in ("precession_rate_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad"):
        assert abs(fit.quantities[name].pull) < 4, name


@pytest.mark.slow
@pytest.mark.parametrize("name", ["air-cushion-heavy-top", "eddy-damped-top", "eddy-damped-top-b2",
                                  "accelerated-pivot"])
def test_analyze_each_rig_recovers_truth_within_errors(tmp_path, name):
    fit = _analyze_rendered(tmp_path, name, 4.0)
    for q in fit.quantities.values():
        if q.status == "determined" and q.pull is not None:
            assert abs(q.pull) < 4, (q.name, q.value, q.standard_error, q.truth)


def test_a_calibrated_camera_without_pose_gives_error_bars_that_cover_truth(tmp_path, capsys):
    """The lab's path: calibrate from board images, pose from the fiducials, analyze.

    The calibration's error is a systematic common to all frames; with its covariance
    propagated, the fit stays consistent (chi-square ~1, white residuals) and truth lies
    within 4 standard errors.  Without it, the same run had reduced chi-square ~3e4.
    """
    p = _small("air-cushion-heavy-top")
    render_video(p, tmp_path / "v", seed=5, duration_s=2.0, calibration_views=10)
    assert main(["calibrate", str(tmp_path / "v" / "calibration"), "--board", "9x6", "--square-mm", "20",
                 "--out", str(tmp_path / "cal.json")]) == 0
    cal = json.loads((tmp_path / "cal.json").read_text())
    rendered_cam = json.loads((tmp_path / "v" / "camera.json").read_text())
    for k in ("fps", "exposure_s", "psf_sigma_px", "sensor"):
        cal[k] = rendered_cam[k]
    (tmp_path / "cal.json").write_text(json.dumps(cal))
    proto = tmp_path / "protocol.toml"
    text = (PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
    text = text.replace("width_px = 1440", "width_px = 640").replace("height_px = 1080", "height_px = 480")
    proto.write_text(text.replace("pixel_size_um = 3.45", f"pixel_size_um = {3.45 * 2.25}"))
    capsys.readouterr()
    assert main(["analyze", str(tmp_path / "v" / "video.mkv"), "--camera", str(tmp_path / "cal.json"),
                 "--protocol", str(proto), "--out", str(tmp_path / "an"), "--truth",
                 str(tmp_path / "v" / "truth.csv")]) == 0
    fit = json.loads((tmp_path / "an" / "fit.json").read_text())
    lo, hi = chi2_red_band(fit["dof"])
    assert lo < fit["chi2_red"] < hi
    for k in ("precession_rate_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad"):
        q = fit["quantities"][k]
        assert q["camera_standard_error"] > 0, k
        assert abs(q["pull"]) < 4, (k, q["pull"])


def test_a_manifest_from_a_european_spreadsheet_is_read(tmp_path, monkeypatch):
    """A manifest saved by Excel in a European locale has ';' between cells: its rows are run (here one, whose
    video is not a video: that row fails and summary.csv says so), not refused for lacking a video column; a
    comma in a file name is kept."""
    (tmp_path / "take 1,5.mkv").write_bytes(b"not a video")
    proto = PROTOCOL_DIR / "air-cushion-heavy-top.toml"
    (tmp_path / "manifest.csv").write_text(f"video;protocol;camera\ntake 1,5.mkv;{proto};camera.json\n")
    monkeypatch.chdir(tmp_path)
    assert main(["analyze", "manifest.csv", "--out", "batch"]) == 3
    s = pd.read_csv(tmp_path / "batch" / "summary.csv")
    assert list(s.status) == ["failed"] and s.video[0].endswith("take 1,5.mkv")
