"""The quick forms of the benchmarks run in CI: they must finish and their figures must make sense.

Timings are reported, never asserted (shared, noisy machines); what is asserted is
accuracy and the verdicts.
"""

import numpy as np
import pandas as pd
import pytest

from conftest import PROTOCOL_DIR
from gyrorig import exact_solution, load_protocol

from gyrorig.bench import speed_ratio, work_precision, benchmark_top
from gyrorig.cli import main

from _asserts import assert_plot


def test_work_precision_errors_fall_with_tolerance_and_beat_scipy_at_equal_error():
    table, reference = work_precision(benchmark_top(60.0), quick=True)
    assert reference == "exact"
    gyro = table[(table.method == "gyro") & (table.status == "ok")].sort_values("rtol", ascending=False)
    assert (gyro.max_tip_error_rad.diff().dropna() < 0).all()  # tighter tolerance, smaller error
    assert gyro.max_tip_error_rad.min() < 1e-12
    closed = table[table.method == "fast-top closed form"].iloc[0]
    assert 1e-5 < closed.max_tip_error_rad < 1e-3  # first-order fast-top solution at ratio ~37
    # every scipy DOP853 run has a gyro run at least as accurate (its speed is reported, not asserted)
    baseline = table[(table.method == "DOP853") & (table.status == "ok")]
    assert len(baseline) >= 1 and len(speed_ratio(table)) == len(baseline)


def test_bench_accuracy_quick_cli(tmp_path, capsys):
    assert main(["bench", "accuracy", "--quick", "--out", str(tmp_path)]) == 0
    for scene in ["release-spin60", "release-spin300"]:
        t = pd.read_csv(tmp_path / f"{scene}.csv")
        assert {"method", "rtol", "wall_time_s", "max_tip_error_rad", "precession_rate_error_rad_s"} <= set(t.columns)
        assert_plot(tmp_path / f"{scene}.png")
    assert "speed-up of gyro over scipy DOP853" in capsys.readouterr().out


def test_bench_stability_quick_cli(tmp_path, capsys):
    code = main(["bench", "stability", "--quick", "--out", str(tmp_path)])
    text = capsys.readouterr().out
    assert code == 0, text
    table = pd.read_csv(tmp_path / "stability.csv")
    auto = table[table.method == "auto"]
    assert (auto.status == "pass").all()
    assert set(auto.case) >= {"very-fast-spin", "damping-faster-than-spin", "tilt-exactly-0", "tilt-1e-12-kicked",
                              "tilt-near-pi", "flat-disc", "thin-rod", "resonance-Omega-equals-nu", "zero-gravity",
                              "pivot-acceleration-20g"}
    # the phasor formulation's singularity is listed, not hidden
    phasor_pole = table[(table.method == "phasor") & (table.case == "tilt-exactly-0")].iloc[0]
    assert phasor_pole.status.startswith("FAIL") and "singular" in phasor_pole.status
    assert "stiff" in table[table.case == "damping-faster-than-nutation"].description.iloc[0]
    assert auto.set_index("case").loc["damping-faster-than-spin", "resolved_method"] == "gyro-radau"


def test_fit_monte_carlo_runs_the_chain_and_summarises(tmp_path, capsys):
    from gyrorig.montecarlo import combine_fit_runs, fit_monte_carlo, summarize_fit_monte_carlo

    runs = fit_monte_carlo(["air-cushion-heavy-top"], seeds=2, duration_s=1.0, workers=1)
    assert (runs.error.fillna("") == "").all()
    table = summarize_fit_monte_carlo(runs)
    row = table[table.quantity == "precession_rate_rad_s"].iloc[0]
    assert row.runs == 2 and np.isfinite(row.sd_pull)
    assert (runs.truth.notna() & runs.pull.notna()).all() and (runs.pull.abs() < 4).all()
    # the truth is the same model fitted to the simulator's noiseless angles: for the undamped top that
    # model is exact, so the true precession is the elliptic solution's mean precession
    exact = exact_solution(load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")).mean_precession_rate_rad_s
    prec = runs[runs.quantity == "precession_rate_rad_s"]
    assert (abs(prec.truth - exact) < 1e-3 * prec.standard_error).all()

    # batches written with --out and read back combine to the same table; an overlap is refused
    for seed in (0, 1):
        (tmp_path / f"b{seed}").mkdir()
        runs[runs.seed == seed].to_csv(tmp_path / f"b{seed}" / "runs.csv", index=False)
    back = summarize_fit_monte_carlo(combine_fit_runs([tmp_path / "b0", tmp_path / "b1" / "runs.csv"]))
    pd.testing.assert_frame_equal(back, table, check_dtype=False)
    assert main(["bench", "fit", "--combine", str(tmp_path / "b0"), str(tmp_path / "b1")]) == 0
    assert "precession_rate_rad_s" in capsys.readouterr().out
    with pytest.raises(ValueError, match="seed 0 of air-cushion-heavy-top is in more than one batch"):
        combine_fit_runs([tmp_path / "b0", tmp_path / "b0" / "runs.csv"])
    with pytest.raises(ValueError, match="no runs.csv"):
        combine_fit_runs([tmp_path / "nowhere"])


def test_a_readout_longer_than_the_frame_interval_is_refused_before_any_run(capsys):
    """bench fit --readout-ms beyond the scene's frame interval (5 ms at 200 fps): no rolling shutter reads its rows
    so slowly; refused with exit 2 before rendering anything."""
    assert main(["bench", "fit", "--phone", "coffee", "--readout-ms", "9", "--quick"]) == 2
    assert main(["bench", "fit", "--phone", "coffee", "--readout-ms", "-1", "--quick"]) == 2


def test_a_batch_whose_every_run_failed_is_summarised_as_failed():
    """Runs that all failed (each a row with its error, no quantity) give an empty table that counts them, not a
    crash (``bench fit`` once exited 3 with a KeyError after 7 minutes of runs)."""
    from gyrorig.montecarlo import summarize_fit_monte_carlo

    runs = pd.DataFrame([{"scene": "s", "seed": k, "duration_s": 1.0, "error": "FitError: no"} for k in range(3)])
    table = summarize_fit_monte_carlo(runs)
    assert table.empty and table.attrs["failed_runs"] == 3


@pytest.mark.slow
def test_the_data_sheet_run_finds_the_focal_length_and_keeps_its_pulls():
    """bench fit --datasheet-focal-sd: one run without calibration or fiducials; the focal length found is within 3
    of its sd of the truth, and the quantities' pulls within 3."""
    from gyrorig.montecarlo import DataSheet, fit_monte_carlo_run

    rows = fit_monte_carlo_run("air-cushion-heavy-top", 4, 2.0, datasheet=DataSheet())
    assert rows[0]["error"] == "", rows[0]["error"]
    assert abs(rows[0]["focal_found_rel"]) < 3 * rows[0]["focal_found_sd_rel"]
    for row in rows:
        assert abs(row["pull"]) < 3, (row["quantity"], row["pull"])
