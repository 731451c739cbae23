"""Output folders (issue 23): a command writes into a fresh temporary folder beside --out and renames it into
place only when complete; an existing non-empty --out is refused (exit 2) unless --overwrite, which replaces it
whole; a failed or interrupted run leaves the earlier output as it was; concurrent runs never share a name."""

from __future__ import annotations

import json
import os

import pytest

from gyrorig import _io
from gyrorig.cli import commands, main

from conftest import PROTOCOL_DIR

AIR = str(PROTOCOL_DIR / "air-cushion-heavy-top.toml")


def _tree(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _no_leftovers(parent):
    return not [p for p in parent.iterdir() if ".partial-" in p.name or ".old-" in p.name]


def test_a_second_render_into_one_folder_is_refused_and_overwrite_replaces_it_whole(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["render", AIR, "--out", str(out), "--duration", "0.1", "--calibration-views", "2"]) == 0
    first = _tree(out)
    truth = (out / "truth.csv").read_bytes()
    capsys.readouterr()
    assert main(["render", AIR, "--out", str(out), "--duration", "0.2", "--codec", "mp4"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert _tree(out) == first and (out / "truth.csv").read_bytes() == truth
    assert main(["render", AIR, "--out", str(out), "--duration", "0.1", "--codec", "mp4", "--calibration-views", "0",
                 "--overwrite"]) == 0
    after = _tree(out)
    assert "video.mp4" in after and "video.mkv" not in after  # nothing of the first run is left
    assert not any(p.startswith("calibration") for p in after)
    assert _no_leftovers(tmp_path)
    # files that name their folder name the final one, never the temporary one
    for f in out.rglob("*"):
        if f.suffix in (".json", ".csv"):
            assert ".partial-" not in f.read_text()


def test_an_interrupted_or_failed_run_leaves_the_earlier_output(tmp_path, monkeypatch, capsys):
    out = tmp_path / "sim"
    assert main(["simulate", AIR, "--out", str(out), "--duration", "0.1"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def half_then(exc):
        def run(args):
            (_io.Path(args.out) / "trajectory.csv").write_text("half written")
            raise exc
        return run

    # Ctrl-C inside compiled (numba) code comes back as a SystemError caused by the KeyboardInterrupt
    in_kernel = SystemError("CPUDispatcher(...) returned a result with an exception set")
    in_kernel.__cause__ = KeyboardInterrupt()
    for exc, code in ((KeyboardInterrupt(), 130), (in_kernel, 130), (RuntimeError("boom"), 3), (ValueError("bad"), 2)):
        monkeypatch.setattr(commands, "_cmd_simulate", half_then(exc))
        assert main(["simulate", AIR, "--out", str(out), "--duration", "0.1", "--overwrite"]) == code
        assert {p.name: p.read_bytes() for p in out.iterdir()} == before
        assert _no_leftovers(tmp_path)
        assert "Traceback" not in capsys.readouterr().err


def test_an_output_holding_an_input_is_refused_even_with_overwrite(tmp_path):
    out = tmp_path / "sim"
    assert main(["simulate", AIR, "--out", str(out), "--duration", "0.1"]) == 0
    angles = out / "trajectory.csv"
    assert main(["smooth", str(angles), "--out", str(out), "--overwrite"]) == 2
    assert angles.exists()


def test_concurrent_runs_get_their_own_temporary_folders_and_the_rule_holds_at_the_end(tmp_path):
    final = tmp_path / "out"
    with pytest.raises(_io.OutputExistsError):
        with _io.output_folder(final) as a:          # run A starts
            with _io.output_folder(final) as b:      # run B starts, into the same --out
                assert a != b and a.parent == b.parent == tmp_path
                (a / "x.txt").write_text("a")
                (b / "x.txt").write_text("b")
            # B finished first: the folder is B's; A, finishing without --overwrite, is refused
    assert (final / "x.txt").read_text() == "b"
    with _io.output_folder(final, overwrite=True) as c:
        (c / "y.txt").write_text("c")
    assert sorted(p.name for p in final.iterdir()) == sorted([_io.OUTPUT_MARKER, "y.txt"])  # replaced whole
    assert _no_leftovers(tmp_path)


def test_calibrate_refuses_an_existing_camera_file(tmp_path):
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps({"keep": True}))
    assert main(["calibrate", str(tmp_path), "--board", "9x6", "--square-mm", "20", "--out", str(cam)]) == 2
    assert json.loads(cam.read_text()) == {"keep": True}


def test_overwrite_never_removes_what_gyrorig_did_not_write(tmp_path, monkeypatch):
    """Issue 33: an input reached through a symbolic link inside --out passed the 'holds an input' check and was
    deleted with --overwrite; --out . and --out .. replaced the working folder; a folder of the user's own files
    was replaced whole.  Now each is refused (exit 2) and nothing is touched."""
    work = tmp_path / "proj"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["simulate", AIR, "--out", "sim", "--duration", "0.1"]) == 0
    link = tmp_path / "link"
    link.symlink_to(work / "sim")
    angles = link / "trajectory.csv"
    before = angles.read_bytes()
    assert main(["smooth", str(angles), "--out", str(work / "sim"), "--overwrite"]) == 2
    assert angles.read_bytes() == before
    (work / "notes.txt").write_text("mine")
    for out in (".", "..", str(tmp_path)):
        assert main(["simulate", AIR, "--out", out, "--duration", "0.1", "--overwrite"]) == 2
    assert (work / "notes.txt").read_text() == "mine" and (work / "sim" / "trajectory.csv").exists()
    mine = work / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    assert main(["simulate", AIR, "--out", str(mine), "--duration", "0.1", "--overwrite"]) == 2
    assert (mine / "thesis.tex").read_text() == "years of work"
    # a folder gyrorig wrote is replaced as before
    assert main(["simulate", AIR, "--out", "sim", "--duration", "0.1", "--overwrite"]) == 0
    assert (work / "sim" / _io.OUTPUT_MARKER).is_file() and _no_leftovers(work)


@pytest.fixture(scope="module")
def long_video(tmp_path_factory):
    """A 1.5 s render of the bundled rig (rendered once for the signal tests)."""
    from gyrorig.protocols import load_protocol
    from gyrorig.render import render_video

    folder = tmp_path_factory.mktemp("signals") / "v"
    render_video(load_protocol(AIR), folder, seed=0, duration_s=1.5, calibration_views=0)
    return folder


@pytest.mark.parametrize("signame, code", [("SIGINT", 130), ("SIGTERM", 143), ("SIGHUP", 129)])
def test_a_signal_while_tracking_leaves_nothing(tmp_path, long_video, signame, code):
    """Ctrl-C while the decoding thread reads the video (issue 23: SIGABRT 'exception not rethrown' in 2 of 3
    tries), and SIGTERM or SIGHUP (issue 33: they left the temporary folder behind): exit 128 + the signal, one
    line, no output folder, no temporary folder."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "track"
    # the child gets the default SIGINT action a terminal's foreground job has: a test run started in the
    # background (`cmd &` in a script, nohup) ignores SIGINT, and its children inherit that
    command = [sys.executable, "-m", "gyrorig", "track", str(long_video / "video.mkv"), "--camera",
               str(long_video / "camera.json"), "--protocol", AIR, "--out", str(out)]
    foreground = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
                  "os.execv(sys.argv[1], sys.argv[1:])")
    # PYTHONFAULTHANDLER: a child that hangs is aborted below and prints every thread's stack
    proc = subprocess.Popen([sys.executable, "-c", foreground, *command], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONFAULTHANDLER": "1"})
    seen = []
    for line in proc.stderr:  # wait for the first progress line: frames are being decoded and tracked
        seen.append(line)
        if line.startswith("track:"):
            break
    assert proc.poll() is None, "tracking finished before the interrupt: the test needs a longer video"
    time.sleep(0.3)
    proc.send_signal(getattr(signal, signame))
    try:
        _, rest = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        _, rest = proc.communicate(timeout=30)
        pytest.fail(f"still running 30 s after {signame}; its threads:\n" + "".join(seen) + rest)
    err = "".join(seen) + rest
    assert proc.returncode == code, err
    assert err.strip().splitlines()[-1].startswith("gyrorig:") and "Traceback" not in err
    assert not out.exists() and _no_leftovers(tmp_path)


def test_a_board_that_cannot_fit_the_view_is_refused_not_looped_on(tmp_path):
    """Issue 23: render with a narrow field of view never finished (the calibration board was placed at
    random until it fitted, which it never did).  Now a bounded search and a clear refusal, exit 2."""
    text = (PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
    narrow = tmp_path / "narrow.toml"
    narrow.write_text(text.replace("focal_length_mm = 10.2", "focal_length_mm = 100.0")
                      .replace("position_m = [0.0, 0.0, 0.75]", "position_m = [0.0, 0.0, 3.5]"))
    from gyrorig.camera import camera_setup
    from gyrorig.protocols import load_protocol
    from gyrorig.render.board import render_calibration_images

    cam = camera_setup(load_protocol(narrow)).camera
    with pytest.raises(ValueError):
        render_calibration_images(cam, tmp_path / "cal", n_views=2)
