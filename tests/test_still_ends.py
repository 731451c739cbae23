"""A record's still ends (:mod:`gyrorig.stillness`): a phone records the top held by hand before its release and caught
after it; the fit leaves those frames out, and nothing out of a record that moves throughout."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from gyrorig.fit import NoteKind, fit_angles
from gyrorig.stillness import angle_still_ends
from gyrorig.physics.simulate import simulate
from gyrorig.protocols import AirDamping, Pivot, load_protocol
from gyrorig.theory import predict

from _stats import chi2_red_band
from conftest import PROTOCOL_DIR

SIGMA_RAD = 2e-4


def _table(theta, phi, t, rng, sigma=SIGMA_RAD):
    n = len(t)
    sph = sigma / np.maximum(np.sin(theta), 0.05)
    return pd.DataFrame({"frame": np.arange(n), "t_s": t, "theta_rad": theta + sigma * rng.normal(size=n),
                         "phi_rad": phi + sph * rng.normal(size=n), "theta_sigma_rad": sigma,
                         "phi_sigma_rad": sph, "theta_phi_corr": 0.0})


def _held(theta0, phi0, n, rng, tremor_rad):
    """``n`` frames of a tip held by hand at ``theta0, phi0``: a slow wander of ``tremor_rad``."""
    walk = np.cumsum(rng.normal(size=(n, 2)), axis=0) * tremor_rad / np.sqrt(n)
    return theta0 + walk[:, 0], phi0 + walk[:, 1] / np.sin(theta0)


def _caught(motion: pd.DataFrame, n: int, rate: float, rng, tau_s: float = 0.05):
    """``n`` frames after a hand catches the tip at the end of ``motion``: its velocity dies away in ``tau_s`` (the
    first 0.1 s), then it is held (:func:`_held`)."""
    t = motion.t_s.to_numpy()
    th, ph = motion.theta_rad.to_numpy(), np.unwrap(motion.phi_rad.to_numpy())
    k = np.arange(1, n + 1) / rate
    stop = tau_s * (1 - np.exp(-np.minimum(k, 0.1) / tau_s))
    held_th, held_ph = _held(th[-1], ph[-1], n, rng, 1e-3)
    return held_th + np.gradient(th, t)[-1] * stop, held_ph + np.gradient(ph, t)[-1] * stop


def _with_still_ends(motion: pd.DataFrame, hold_s: float, caught_s: float, rate: float, seed: int):
    """The noisy record of ``motion`` (the simulator's, from its release at ``t = 0``) and the same record as a phone
    takes it: ``hold_s`` of the tip held before the release and ``caught_s`` after a hand catches it at the end
    (:func:`_caught`), the motion's frames carrying the same noise in both."""
    rng = np.random.default_rng(seed)
    free = _table(motion.theta_rad.to_numpy(), motion.phi_rad.to_numpy(), motion.t_s.to_numpy() + hold_s, rng)
    n_hold, n_caught = int(round(hold_s * rate)), int(round(caught_s * rate))
    th0, ph0 = _held(motion.theta_rad.iloc[0], motion.phi_rad.iloc[0], n_hold, rng, 1e-3)
    th1, ph1 = _caught(motion, n_caught, rate, rng)
    t_end = free.t_s.iloc[-1]
    head = _table(th0, ph0, np.arange(n_hold) / rate, rng)
    tail = _table(th1, ph1, t_end + np.arange(1, n_caught + 1) / rate, rng)
    record = pd.concat([head, free, tail], ignore_index=True).assign(frame=lambda d: np.arange(len(d)))
    return free, record


@pytest.mark.parametrize("name, duration_s, rate", [("air-cushion-heavy-top", 8.0, 100.0),
                                                     ("eddy-damped-top-b2", 6.0, 100.0),
                                                     ("air-cushion-heavy-top", 4.0, 30.0)])
def test_a_record_held_before_the_release_and_caught_at_the_end_is_fitted_between(name, duration_s, rate):
    """A phone records from before the release: 1 s of the tip held (wandering 1e-3 rad, a hand's tremor) and 0.5 s
    after a hand catches it (its speed dying away in 0.05 s).  Fitted whole, the bundled rig's record gave a reduced
    chi-square of 3.3e5 and the nutation at 1.47 rad/s for 59.5.  The still ends are now left out (the note says so),
    and the catch's frames before the still tail (with the still tail alone left out: reduced chi-square 13.4, the
    precession +6.9 s.e. from the exact solution): the fit's frames start after the release (within the time the tip
    takes to leave the still radius, a few frames) and end before the catch, the chi-square is white noise's, and every
    quantity is the one the motion's own frames over that span give (the same frames: the hand's have no say)."""
    p = load_protocol(PROTOCOL_DIR / f"{name}.toml")
    motion = simulate(p, duration_s=duration_s, rate_hz=rate)
    hold_s, caught_s = 1.0, 0.5
    free, record = _with_still_ends(motion, hold_s, caught_s, rate, seed=3)
    pred = predict(p, simulate_damping=False)
    r = fit_angles(record, p, prediction=pred)
    assert [n.kind for n in r.notes].count(NoteKind.STILL_ENDS) == 1
    t = r.residuals.t_s.to_numpy()
    assert hold_s <= t[0] < hold_s + 0.15 and free.t_s.iloc[-1] - 0.15 < t[-1] <= free.t_s.iloc[-1]
    lo, hi = chi2_red_band(r.dof)
    assert lo < r.chi2_red < hi
    plain = fit_angles(free[(free.t_s >= t[0]) & (free.t_s <= t[-1])], p, prediction=pred)
    assert NoteKind.STILL_ENDS not in [n.kind for n in plain.notes]
    for key, q in plain.quantities.items():
        if q.determined and q.standard_error:
            assert abs(r.quantities[key].value - q.value) < 1e-6 * q.standard_error, key


def _scenes():
    spinning_down = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    spinning_down = replace(spinning_down, pivot=Pivot((AirDamping(0.0, 5.2e-5, spin_compensated=False),)))
    names = ["air-cushion-heavy-top", "eddy-damped-top-b2", "eddy-damped-top", "free-top", "accelerated-pivot"]
    return [(n, load_protocol(PROTOCOL_DIR / f"{n}.toml")) for n in names] + [("spinning down", spinning_down)]


@pytest.mark.parametrize("name, protocol", _scenes())
def test_a_record_that_moves_throughout_has_no_still_ends(name, protocol):
    """Every bundled scene (and a rotor spinning down 10 times faster than the rig's air drag, its precession
    speeding up 1.8 times over the 6 s record), at 30, 100 and 240 frames/s, at two noise levels and three seeds:
    nothing left out.  Nor when the tip is lost for 0.5 s right after the first frames (the gap is not a still time)."""
    for rate in (30.0, 100.0, 240.0):
        motion = simulate(protocol, duration_s=6.0, rate_hz=rate)
        for seed in range(3):
            for sigma in (SIGMA_RAD, 10 * SIGMA_RAD):
                a = _table(motion.theta_rad.to_numpy(), motion.phi_rad.to_numpy(), motion.t_s.to_numpy(),
                           np.random.default_rng(seed), sigma)
                found = angle_still_ends(a.t_s.to_numpy(), a.theta_rad.to_numpy(), a.phi_rad.to_numpy(),
                                   a.theta_sigma_rad.to_numpy(), a.phi_sigma_rad.to_numpy())
                assert not found.any, (rate, seed, sigma)
                gap = (a.t_s < 0.03) | (a.t_s > 0.53)
                b = a[gap]
                found = angle_still_ends(b.t_s.to_numpy(), b.theta_rad.to_numpy(), b.phi_rad.to_numpy(),
                                   b.theta_sigma_rad.to_numpy(), b.phi_sigma_rad.to_numpy())
                assert not found.any, (rate, seed, sigma, "gap")


def test_a_rendered_record_of_a_top_held_before_its_release_is_analysed_from_the_release(tmp_path):
    """Through the chain: the damped B2 rig held still for 0.5 s (its rotor spinning) before its release, rendered
    (640x480) and analysed as a user would: the still head is left out, the fit's first frame is after the release,
    and every quantity agrees with the truth within 4 of its errors; the damped record is compared with theory at its
    own first frame, after the release (within 4 combined errors)."""
    from gyrorig.analysis import analyze_video
    from gyrorig.camera import with_image_size
    from gyrorig.render import render_video

    p = with_image_size(load_protocol(PROTOCOL_DIR / "eddy-damped-top-b2.toml"), 640, 480)
    render_video(p, tmp_path / "video", seed=2, duration_s=2.0, calibration_views=0, hold_s=0.5)
    fit = analyze_video(tmp_path / "video" / "video.mkv", tmp_path / "video" / "camera.json", p, tmp_path / "an",
                        truth_csv=tmp_path / "video" / "truth.csv")["fit"]
    assert NoteKind.STILL_ENDS in [n.kind for n in fit.notes]
    assert 0.5 <= fit.residuals.t_s.iloc[0] < 0.65
    for q in fit.quantities.values():
        if q.determined and q.pull is not None:
            assert abs(q.pull) < 4, (q.name, q.pull)
        if q.diff_exact_combined_se is not None:
            assert abs(q.diff_exact_combined_se) < 4, (q.name, q.diff_exact_combined_se)


def test_the_fit_plot_shows_the_fitted_motion_of_a_record_held_before_its_release():
    """The fit's figure zooms on the first second: of the tracked frames, it showed only the held second, without the
    fitted curve.  It now zooms on the first second the fit describes (the curve drawn there), and the overview
    shades the held second as left out of the fit."""
    from gyrorig.report.plots import plot_fit

    p = load_protocol(PROTOCOL_DIR / "air-cushion-heavy-top.toml")
    _, record = _with_still_ends(simulate(p, duration_s=4.0, rate_hz=100.0), 1.0, 0.0, 100.0, seed=1)
    fit = fit_angles(record, p)
    fig = plot_fit(record, None, fit)
    overview, zoom = fig.axes[0], fig.axes[1]
    curve = [line for line in zoom.get_lines() if line.get_label() == "fit"][0]
    assert len(curve.get_xdata()) > 0 and min(curve.get_xdata()) >= 1.0
    shaded = [patch for patch in overview.patches if patch.get_label() == "left out of the fit"]
    assert len(shaded) == 1
