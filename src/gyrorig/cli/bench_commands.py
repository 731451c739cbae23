"""The command line's benchmarks of the chain's later stages: ``gyrorig bench smooth``, ``bench length``."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import _io
from .._validate import number
from .codes import EXIT_OK
from .printing import print_data

__all__ = ["_cmd_bench_smooth", "_cmd_bench_length"]


def _cmd_bench_smooth(args: argparse.Namespace) -> int:
    from ..bench import smooth_benchmark

    r = smooth_benchmark(args.frames, args.filterpy_frames)
    print(f"compiled smoother (filter + RTS), {r['frames']:,} frames: {r['fast_s']:.3f} s "
          f"({r['fast_us_per_frame']:.2f} us/frame; target < 0.2 s)")
    print(f"filterpy 2.0 KalmanFilter + rts_smoother, same model, {r['filterpy_frames']:,} frames: {r['filterpy_s']:.2f} s "
          f"({r['filterpy_us_per_frame']:.0f} us/frame): {r['speedup']:.0f}x slower per frame")
    print(f"agreement: states {r['max_state_diff_in_sigma']:.1e} sigma; covariances {r['max_cov_diff_rel_after_first']:.1e} "
          f"of sqrt(P_ii P_jj) (first frame {r['max_cov_diff_rel_first']:.1e}); same gating: {r['same_gating']}")
    print(f"maximum-likelihood noise levels: {r['ml_noise_s']:.2f} s ({r['ml_evaluations']} filter passes)")
    return EXIT_OK


def _cmd_bench_length(args: argparse.Namespace) -> int:
    from ..bench.length import record_length_benchmark
    from ..protocols import bundled_protocols

    if args.protocol not in bundled_protocols():
        raise ValueError(f"protocol {args.protocol!r}: a bundled protocol's name ({', '.join(bundled_protocols())})")
    for n in args.frames:
        number("", "--frames", n, lo=200, hi=1_000_000)
    number("", "--fps", args.fps, lo=1.0, hi=10_000.0)

    def say(row: dict) -> None:
        print_data(f"{row['frames']:>7,} frames ({row['record_s']:.0f} s): check {row['check_s']:.2f} s "
                   f"({row['path']}, factor {row['factor']:.3f}), smooth {row['smooth_s']:.2f} s, fit {row['fit_s']:.2f} s")

    table = record_length_benchmark(args.protocol, frames=sorted(args.frames), fps=args.fps, seed=args.seed,
                                    progress=say)
    columns = ["frames", "record_s"] + [f"{s}_{k}" for s in ("check", "smooth", "fit")
                                        for k in ("s", "us_per_frame", "exponent")]
    print(table[columns].to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.out:
        _io.write_csv(table, Path(args.out) / "length.csv")
    return EXIT_OK
