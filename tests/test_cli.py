import json

import numpy as np
import pandas as pd
import pytest

from _asserts import assert_plot
from conftest import PROTOCOL_DIR
from gyrorig import _io
from gyrorig.cli import main
from gyrorig.physics import TRAJECTORY_COLUMNS

AIR = str(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
EDDY = str(PROTOCOL_DIR / "eddy-damped-top.toml")


def test_simulate_writes_trajectory_and_manifest(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", AIR, "--out", str(out), "--duration", "0.5", "--rate", "100"]) == 0
    df = pd.read_csv(out / "trajectory.csv")
    assert list(df.columns[:10]) == list(TRAJECTORY_COLUMNS)
    assert len(df) == 51
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["simulation"]["method"] == "gyro"
    assert manifest["protocol"]["name"] == "air-cushion-heavy-top"
    assert manifest["versions"]["gyrorig"]
    assert sorted(p.name for p in out.iterdir()) == [".gyrorig-output", "manifest.json", "trajectory.csv"]
    assert "51 rows" in capsys.readouterr().out


def test_simulate_exact_method_and_its_refusal_for_damped_scenes(tmp_path, capsys):
    assert main(["simulate", AIR, "--out", str(tmp_path / "a"), "--method", "exact", "--duration", "0.2"]) == 0
    exact = pd.read_csv(tmp_path / "a" / "trajectory.csv")
    assert main(["simulate", AIR, "--out", str(tmp_path / "b"), "--duration", "0.2", "--rtol", "1e-12"]) == 0
    sim = pd.read_csv(tmp_path / "b" / "trajectory.csv")
    assert np.abs(exact[["tip_x", "tip_y", "tip_z"]].to_numpy() - sim[["tip_x", "tip_y", "tip_z"]].to_numpy()).max() < 1e-10
    assert main(["simulate", EDDY, "--out", str(tmp_path / "c"), "--method", "exact"]) == 2
    assert "damped" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def test_bad_protocol_exits_2_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text((PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text().replace("mass_kg = 0.5292", "mass_kg = -2"))
    out = tmp_path / "out"
    assert main(["simulate", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "rig.mass_kg = -2.0" in err and "(0, inf]" in err
    assert not out.exists()


def test_failed_integration_exits_3_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["simulate", AIR, "--out", str(out), "--method", "RK23", "--rtol", "0.5", "--duration", "2"])
    assert code == 3
    assert "diverged" in capsys.readouterr().err
    assert not out.exists()


def test_atomic_path_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "x.csv"
    with pytest.raises(RuntimeError):
        with _io.atomic_path(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_bench_methods_prints_a_table(tmp_path, capsys):
    code = main(["bench", "methods", AIR, "--duration", "0.5", "--methods", "gyro", "DOP853", "--out", str(tmp_path)])
    assert code == 0
    text = capsys.readouterr().out
    assert "reference: exact" in text and "speed ratio" in text
    table = pd.read_csv(tmp_path / "methods.csv")
    assert set(table.method) == {"exact", "gyro", "DOP853"}
    assert (table[table.method != "exact"].max_tip_error_rad < 1e-7).all()


def test_bench_length_checks_a_30_fps_record_against_its_sinusoids(tmp_path):
    """``bench length`` runs the record's check, the smoother and the fit on 30 frames/s tracks of the simulated
    top; at 30 frames/s the check is the path of sinusoids, and the errors it finds match the 0.1 px of noise added
    to the stated 0.1 px: factor 1 within 4 of its standard errors (1 / sqrt(2 N), N = 2 coordinates a frame)."""
    assert main(["bench", "length", "--frames", "300", "600", "--out", str(tmp_path)]) == 0
    table = pd.read_csv(tmp_path / "length.csv")
    assert list(table.frames) == [300, 600]
    assert (table.path == "sinusoids").all()
    assert (np.abs(table.factor - 1.0) < 4.0 / np.sqrt(2 * 2 * table.frames)).all(), table.factor.tolist()
    assert np.isfinite(table.check_exponent.iloc[1]) and (table[["check_s", "smooth_s", "fit_s"]] > 0).all().all()


def test_demo_runs_the_chain_and_writes_its_plots(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--duration", "1", "--video-duration", "1.5"]) == 0
    for name in ("trajectory.png", "tracking.png", "fit.png"):
        assert_plot(tmp_path / name)
    text = capsys.readouterr().out
    assert "max tip error vs exact" in text and "WRONG SIGN" in text and "frames tracked" in text
    assert "pull" in text and "Report:" in text
    # the simulator agrees with the exact solution; the fit recovers the truth within its errors
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["max_tip_error_vs_exact_rad"] < 1e-8
    fit = json.loads((tmp_path / "fit.json").read_text())
    for name in ("precession_rate_rad_s", "nutation_frequency_rad_s", "nutation_amplitude_rad"):
        assert abs(fit["quantities"][name]["pull"]) < 4, name
    angles = pd.read_csv(tmp_path / "track" / "angles.csv")
    assert len(angles) == manifest["tracking"]["frames"] == 300  # 1.5 s at 200 fps
    assert len(pd.read_csv(tmp_path / "trajectory.csv")) == 501  # 1 s at 500 Hz
    theory = json.loads((tmp_path / "theory.json").read_text())
    assert theory["precession_rate_slow_rad_s"]["sign_agrees"] is False
    report = (tmp_path / "report.html").read_text()
    assert all(name in report for name in fit["quantities"])


def test_version_and_a_light_command_line():
    """``gyrorig --version`` prints the installed version; parsing the command line imports neither the
    physics nor the commands (they load after the arguments are read)."""
    import subprocess
    import sys

    import gyrorig

    out = subprocess.run([sys.executable, "-c", "import sys; from gyrorig.cli import main\n"
                          "try:\n    main(['--version'])\nexcept SystemExit as e:\n    code = e.code\n"
                          "print(code, 'gyrorig.physics' in sys.modules, 'gyrorig.cli.commands' in sys.modules)"],
                         capture_output=True, text=True, check=True)
    lines = out.stdout.split()
    assert lines[:2] == ["gyrorig", gyrorig.__version__]
    assert lines[2:] == ["0", "False", "False"]


@pytest.mark.parametrize("case", ["protocol-is-a-folder", "seeds-0", "plan-duration-0", "demo-video-duration-0",
                                  "out-is-a-file", "board-0x0", "square-mm-0"])
def test_bad_invocations_exit_2_with_one_line(tmp_path, capsys, case):
    """Issue 23: each of these printed a traceback (exit 1) or a message naming neither the option nor the
    file; now exit 2 and one line, no traceback."""
    blocker = tmp_path / "blocker"
    blocker.write_text("a file where the output folder should go")
    argv = {
        "protocol-is-a-folder": ["theory", str(tmp_path)],
        "seeds-0": ["bench", "fit", "--seeds", "0", "--quick"],
        "plan-duration-0": ["plan", AIR, "--duration", "0"],
        "demo-video-duration-0": ["demo", "--video-duration", "0", "--out", str(tmp_path / "d")],
        "out-is-a-file": ["simulate", AIR, "--out", str(blocker / "sub"), "--duration", "0.1"],
        "board-0x0": ["calibrate", str(tmp_path), "--board", "0x0", "--square-mm", "20", "--out",
                      str(tmp_path / "c.json")],
        "square-mm-0": ["calibrate", str(tmp_path), "--board", "9x6", "--square-mm", "0", "--out",
                        str(tmp_path / "c.json")],
    }[case]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_quiet_prints_only_the_data_asked_for(tmp_path, capsys):
    """``-q``: a script gets nothing but the --json it asked for (parseable as a whole), and errors on stderr."""
    assert main(["-q", "simulate", AIR, "--out", str(tmp_path / "s"), "--duration", "0.2"]) == 0
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err == ""
    assert (tmp_path / "s" / "trajectory.csv").exists()
    assert main(["-q", "theory", AIR, "--json", "--no-simulate"]) == 0
    cap = capsys.readouterr()
    assert "mean_precession_rate_rad_s" in json.loads(cap.out)
    assert cap.err == ""
    assert main(["-q", "theory", str(tmp_path)]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and len(cap.err.strip().splitlines()) == 1
    # and the next command in the same process talks again
    assert main(["simulate", AIR, "--out", str(tmp_path / "t"), "--duration", "0.2"]) == 0
    assert capsys.readouterr().out


def test_the_one_time_compile_is_announced_once(tmp_path):
    """With an empty numba cache the first run says (one line on stderr) that it compiles; the next run,
    loading the kernels from the cache, says nothing."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    runs = [subprocess.run([sys.executable, "-m", "gyrorig", "simulate", AIR, "--out", str(tmp_path / f"s{k}"),
                            "--duration", "0.1"], capture_output=True, text=True, env=env) for k in range(2)]
    assert [r.returncode for r in runs] == [0, 0]
    assert len(runs[0].stderr.strip().splitlines()) == 1
    assert runs[1].stderr == ""


def test_sleeping_and_non_spinning_tops_in_theory(tmp_path, capsys):
    """Issue 23: at tilt 0 theory flagged 'WRONG SIGN' against exact values that are 0 (a sleeping top neither
    nutates nor precesses); at spin 0 theory and plan crashed (ZeroDivisionError, exit 3)."""
    from gyrorig.protocols import load_protocol
    from gyrorig.theory import predict

    text = (PROTOCOL_DIR / "air-cushion-heavy-top.toml").read_text()
    tilt0 = tmp_path / "tilt0.toml"
    tilt0.write_text(text.replace("tilt_deg = 45.0", "tilt_deg = 0.0"))
    pred = predict(load_protocol(tilt0), simulate_damping=False)
    for key in ("nutation_frequency_rad_s", "mean_precession_rate_rad_s"):
        assert pred.quantities[key].exact == 0.0
        assert pred.quantities[key].sign_agrees is None
    # the paper's real sign error stays flagged
    assert pred.quantities["precession_rate_slow_rad_s"].sign_agrees is False
    spin0 = tmp_path / "spin0.toml"
    spin0.write_text(text.replace("spin_rate_rad_s = 502.65", "spin_rate_rad_s = 0.0"))
    capsys.readouterr()
    assert main(["theory", str(spin0), "--no-simulate"]) == 2
    assert main(["plan", str(spin0), "--draws", "0", "--duration", "1"]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_a_settings_file_larger_than_any_real_one_is_refused(tmp_path, capsys):
    """A valid protocol padded to 17 MiB with a comment is bad input (read whole before), not parsed."""
    from gyrorig._io import MAX_SETTINGS_BYTES

    path = tmp_path / "p.toml"
    path.write_text((PROTOCOL_DIR / "free-top.toml").read_text() + "#" + "x" * (MAX_SETTINGS_BYTES + 2**20) + "\n")
    assert main(["theory", str(path), "--no-simulate"]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_progress_of_a_source_of_unknown_length_is_a_count_not_a_line_per_call(capsys):
    """A source that states no length (total 0) in a log file: the count so far at most every 5 s, not a line per
    call (each call once made a new tenth of the work), and the last call (done of done) gives the total."""
    from gyrorig.cli.printing import progress_printer

    show = progress_printer("track")
    for done in range(50, 5050, 50):
        show(done, 0)
    show(5000, 5000)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("track")]
    assert len(lines) <= 3 and lines[-1].startswith("track: 5000/5000")
