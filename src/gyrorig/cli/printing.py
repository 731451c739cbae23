"""What the command line prints: progress bars, the plan, the fit, the theory."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from .._format import with_error
from ..plan_record import Plan
from ..prediction import PredictedQuantity, Prediction

__all__ = ["progress_printer", "print_plan", "print_fit", "print_prediction", "print_data", "set_quiet"]

#: ``-q/--quiet``: no progress and no summary; only the data asked for (``--json``) and errors
_QUIET = {"on": False, "data": None}


def set_quiet(data_stream) -> None:
    """Quiet mode (``data_stream`` not None): progress printers go silent and :func:`print_data` writes to
    ``data_stream`` (the real stdout); None: normal output."""
    _QUIET.update(on=data_stream is not None, data=data_stream)


def print_data(text: str) -> None:
    """Output a script asked for (``--json``): printed even with ``--quiet``."""
    stream = _QUIET["data"] if _QUIET["on"] else sys.stdout
    stream.write(text + "\n")
    stream.flush()


def progress_printer(label: str):
    """A progress bar on a terminal (stderr); elsewhere (a log file) a line at every tenth of the work;
    nothing with ``--quiet``."""
    if _QUIET["on"]:
        return lambda done, total: None
    tty = sys.stderr.isatty()
    start = time.perf_counter()
    logged = [-1]

    def show(done: int, total: int) -> None:
        if total < done or total <= 0:  # a length the source does not state: the count so far, every 5 s
            now = time.perf_counter() - start
            if tty:
                sys.stderr.write(f"\r{label}: {done} ({done / max(now, 1e-9):.0f}/s)")
            elif now >= 5.0 * (logged[0] + 1):
                logged[0] = int(now // 5.0)
                sys.stderr.write(f"{label}: {done} after {now:.0f} s\n")
            sys.stderr.flush()
            return
        if not tty:
            tenth = 10 * done // max(total, 1)
            if tenth > logged[0]:
                logged[0] = tenth
                sys.stderr.write(f"{label}: {done}/{total} after {time.perf_counter() - start:.0f} s\n")
                sys.stderr.flush()
            return
        frac = done / max(total, 1)
        rate = done / max(time.perf_counter() - start, 1e-9)
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{label} [{bar:<30}] {done}/{total} ({rate:.0f}/s)")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return show


def print_plan(plan: Plan) -> None:
    from ..plan import MISFIT_NOTE

    print(f"plan for {plan.protocol}")
    cam = plan.camera
    if cam:
        print(f"  camera: {cam['fps']:g} fps, {cam['exposure_s'] * 1e6:.0f} us; tip marker {cam['radius_px']:.1f} px "
              f"radius, {cam['signal_adu']:.0f} ADU on {cam['background_adu']:.0f}; localisation bound "
              f"{cam['sigma_px']:.4f} px -> theta {cam['theta_sigma_rad_median']:.2e} rad, phi "
              f"{cam['phi_sigma_rad_median']:.2e} rad per frame")
        if "nutation_hz" in cam:
            print(f"  nutation {cam['nutation_hz']:.3g} Hz: {cam['frames_per_nutation_period']:.1f} frames per period, "
                  f"amplitude {cam.get('nutation_amplitude_px', float('nan')):.2f} px "
                  f"({cam.get('nutation_amplitude_over_sigma_px', float('nan')):.3g} x the bound)")
        print(f"  motion blur {cam['motion_blur_px']:.2f} px; rolling-shutter skew {cam['rolling_shutter_skew_px']:.2f} px"
              f"; saturates: {cam['saturates']}")
        rec = plan.recording or {}
        if not rec:
            print("  expected errors: none (nothing to measure: see the advice)")
        else:
            print(f"  expected errors for a {rec['length_s']:g} s record (Cramer-Rao bound of the fit):")
        for name, q in plan.quantities.items():
            if not q.resolvable:
                print(f"    {name}: not resolvable: {q.reason}")
                continue
            pe = q.paper_vs_exact_in_se
            print(f"    {name}: {q.simulated:.6g} +- {q.expected_standard_error:.2g} {q.units}"
                  + (f" (paper {q.predicted_paper:.6g}: {pe:+.3g} s.e. from exact)" if pe is not None else "")
                  + (f"; theory itself +- {q.prediction_standard_error:.2g} from the rig's parameters"
                     if q.prediction_standard_error else "")
                  + ("" if q.reliable else "  [not reliable: see the advice]"))
        mf = rec.get("model_misfit")
        if mf:
            print(f"  fit model on the simulated record: chi-square {mf['noiseless_chi2']:.3g} for {mf['dof']} degrees "
                  f"of freedom ({mf['chi2_per_dof']:.2g} per degree of freedom"
                  + ("; describes the motion)" if mf["chi2_per_dof"] <= MISFIT_NOTE else "; MISSES part of the motion)"))
        draws = rec.get("noisy_draws")
        if draws and draws["draws"]:
            rms = draws["rms_departure_se"]
            print(f"  {draws['draws']} noisy records fitted in full: {draws['draws'] - draws['failed']} converged; "
                  f"distance from the linearised fit (root mean square) at most "
                  f"{max(rms.values(), default=0.0):.2g} s.e."
                  + (f" ({max(rms, key=rms.get)})" if rms else "")
                  + (": linear over the noise" if draws["ok"] else
                     f": NOT linear over the noise ({', '.join(draws['nonlinear']) or 'failed draws'})"))
        if plan.note:
            print(f"  note: {plan.note}")
    for a in plan.advice:
        print(f"  {'!' if a.problem else '-'} {a.text}")
    mc = plan.monte_carlo
    if mc:
        import pandas as pd

        print(f"  Monte Carlo of render -> track -> smooth -> fit ({mc['runs']} runs of {mc['duration_s']:g} s, "
              f"{mc['failed_runs']} failed):")
        print(pd.DataFrame(mc["table"]).to_string(index=False, float_format=lambda v: f"{v:.3g}"))


def print_fit(fit, out: Path) -> None:
    print(fit.report())
    print(f"-> {out / 'fit.json'}, {out / 'fit.png'}, {out / 'fit_residuals.csv'}")


def print_prediction(pred: Prediction) -> None:
    print(f"{pred.protocol}: theory for this scene (paper as printed / corrected / exact or simulated)")
    for k, v in pred.flags.to_dict().items():
        print(f"  flag {k} = {v:.4g}" if isinstance(v, float) else f"  flag {k} = {v}")
    fmt = lambda x: "-" if x is None else (f"{x:.6g}" if isinstance(x, float) else str(x))  # noqa: E731
    def pm(v: PredictedQuantity, kind: str) -> str:  # to the digits the prediction's own sd resolves, if it has one
        sd, x = v.sd(kind), v.value(kind)
        return with_error(x, sd) if sd and isinstance(x, float) else fmt(x)

    for key, v in pred.quantities.items():
        line = f"  {key}: paper {pm(v, 'paper')}"
        if v.corrected is not None:
            line += f", corrected {pm(v, 'corrected')}"
        line += f", exact {pm(v, 'exact')} ({v.exact_source})"
        if v.uncertainty is not None and v.uncertainty.largest_share is not None:
            top = v.uncertainty.largest_share
            line += (f" [+- from the rig's parameters, {v.uncertainty.method}; largest share {top[0]} "
                     f"{top[1]:.0%}]")
        if v.relative_difference is not None:
            line += f"; paper off by {v.relative_difference:+.2%}"
        if v.sign_agrees is False:
            line += "  ** WRONG SIGN **"
        if v.direction_paper is not None:
            line += f"; direction: paper {v.direction_paper}, simulated {v.direction_exact}"
        print(line)
    e = pred.equilibrium_tip
    if e is not None:
        print(f"  equilibrium_tip: paper {np.round(e.paper, 5).tolist()}, exact {np.round(e.exact, 5).tolist()}, "
              f"{e.angle_between_rad:.4g} rad apart; leans towards the acceleration: "
              f"paper {e.paper_leans_towards_acceleration}, exact {e.exact_leans_towards_acceleration}")
