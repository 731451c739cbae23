"""The command line for a gyro in gimbals (``[gimbal]``): ``gyrorig simulate`` and ``gyrorig theory`` on it."""

from __future__ import annotations

import argparse
import json
import math
import time

from .. import _io
from .._validate import number
from .codes import EXIT_OK
from .printing import print_data

__all__ = ["simulate_gimbal_scene", "gimbal_theory"]


def simulate_gimbal_scene(protocol, args: argparse.Namespace):
    """A gyro in gimbals through its own simulator (:mod:`gyrorig.physics.gimbal`): ``(table, info)``."""
    from ..physics.gimbal import simulate_gimbal

    if args.method != "auto":
        raise ValueError(f"--method {args.method}: a gyro in gimbals has its own simulator; allowed: auto")
    number("", "--rtol", args.rtol if args.rtol is not None else 1e-11, lo=1e-14, hi=1e-3)
    start = time.perf_counter()
    df = simulate_gimbal(protocol, duration_s=protocol.scene.duration_s if args.duration is None else args.duration,
                         rate_hz=protocol.scene.output_rate_hz if args.rate is None else args.rate,
                         rtol=args.rtol if args.rtol is not None else 1e-11)
    return df, {"method": "gimbal (Lagrange's equations in the gimbal angles, DOP853)",
                "wall_time_s": time.perf_counter() - start}


def gimbal_theory(protocol, args: argparse.Namespace) -> int:
    """``gyrorig theory`` for a gyro in gimbals: its closed forms (:func:`gyrorig.gimbals.gimbal_prediction`), with
    error bars from the protocol's parameter uncertainties
    (:func:`gyrorig.propagate.gimbal_prediction_with_uncertainty`)."""
    from .._format import with_error
    from ..propagate import gimbal_prediction_with_uncertainty

    pred = gimbal_prediction_with_uncertainty(protocol)
    if args.json:
        print_data(json.dumps(_io.json_safe(pred), indent=2))
        return EXIT_OK
    print(f"{protocol.name}: a gyro in gimbals, tilt {math.degrees(pred['tilt_rad']):.4g} deg, spin "
          f"{pred['spin_rate_rad_s']:.6g} rad/s"
          + (" (+- from the rig's parameter uncertainties)" if "parameter_uncertainty" in pred else ""))

    def pm(q: dict, kind: str) -> str:
        return with_error(q[kind], q[f"{kind}_sd"]) if q.get(f"{kind}_sd") else f"{q[kind]:.6g}"

    for key in ("nutation_frequency_rad_s", "precession_rate_slow_rad_s"):
        if key in pred:
            q = pred[key]
            print(f"  {key}: {pm(q, 'gimbal')} (a top on a pivot, fast-top formula: {pm(q, 'fast_top')})"
                  + (f"; {q['note']}" if "note" in q else ""))
    return EXIT_OK
