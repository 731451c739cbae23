"""Tracking footage unlike the tracker's own assumptions (issue 18), and the pieces that make it honest.

Round trips run :func:`gyrorig.bench.variants.track_variant`: the renderer draws the scene with what
a user's protocol does not say (disc markers by ray casting, dots on the spinning rotor, gamma, mp4,
rolling shutter, an oblique camera with k3, a plain top, a dim tip); the tracker gets only the tip
marker and the can.  Tolerances: every frame whose tip is clear of other markers is tracked
(``>= 99 %``); no frame flagged ``ok`` is off by more than 5 sigma; the SD of (error / sigma) lies
in the chi band of its frame count (:func:`_stats.sd_ratio_band`, about 1 +- 0.25 for 180 frames);
the tip's RMS pixel error is no worse than a plain 50 % centroid's on the same frames.
"""

import math
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from scipy.signal import lombscargle

from _stats import sd_ratio_band
from test_tracking import gray_frames
from gyrorig.bench.variants import track_variant, variant_protocols
from gyrorig.montecarlo import scene_protocol
from gyrorig.physics import exact_solution, simulate
from gyrorig.protocols import parse_protocol
from gyrorig.render import render_video
from gyrorig.camera import Camera, Sensor
from gyrorig.tracking import FrameArrays, load_camera, track
from gyrorig.tracking.ellipse import DiscGeometry, disc_image, fit_ellipse_spot
from gyrorig.tracking.harmonic import Periodogram, harmonic_check
from gyrorig.tracking.scatter import LOCAL_FRAMES, NOISE_ACF, check_sigmas, local_factors, motion_frequency


@pytest.mark.parametrize("name", ["disc", "disc-mp4", "plain-top", "dim-tip"])
def test_variant_round_trip(name):
    r = track_variant(name, duration_s=1.0, seed=3)
    assert r["tracked_clear_fraction"] >= 0.99
    assert r["wrong_ok"] == 0
    n = int(r["tracked_fraction"] * r["tip_visible"])
    lo, hi = sd_ratio_band(n)
    assert lo <= r["pull_sd_theta"] <= hi and lo <= r["pull_sd_phi"] <= hi, r
    assert r["rms_error_px"] <= r["centroid_rms_px"]


def test_lossy_gamma_footage_takes_its_errors_from_the_data():
    r = track_variant("disc-mp4", duration_s=0.5, seed=1)
    assert r["sigma_scaled"] and r["sigma_factor"] > 1.0


@pytest.mark.slow  # renders and tracks 8 s of 1280x720 HEVC; the path of sinusoids is checked on pixel tracks
def test_a_phone_at_30_frames_per_second_has_its_errors_checked_on_the_record():
    """At a phone's 30 frames/s (HEVC, coffee, 8 s) the nod moves the tip by up to three radii between frames: no
    path through a frame's neighbours follows it, and the errors were the spot fits' own, too small for the codec
    (pull SDs 1.26/1.44 at seed 0).  A path of sinusoids over the record checks them: the pulls' SDs within the
    chi band of their frames (4 sigma), nothing beyond 5 sigma flagged ok."""
    r = track_variant("phone-30fps", duration_s=1.0, seed=2)
    assert r["sigma_scaled"] and r["wrong_ok"] == 0 and r["tracked_clear_fraction"] >= 0.99
    lo, hi = sd_ratio_band(int(r["tracked_fraction"] * r["tip_visible"]))
    assert lo <= r["pull_sd_theta"] <= hi and lo <= r["pull_sd_phi"] <= hi, r


def _path(n=400, fps=240.0):
    t = np.arange(n) / fps
    xy = np.column_stack([300 + 40 * np.cos(7.0 * t) + 5 * np.sin(58.0 * t), 200 + 30 * np.sin(7.0 * t)])
    return t, np.arange(n), xy


def test_scatter_check_finds_the_true_error_scale_and_an_outlier():
    rng = np.random.default_rng(5)
    t, frames, xy = _path()
    sigma_true, sigma_reported = 0.02, 0.01
    noisy = xy + rng.normal(0, sigma_true, xy.shape)
    noisy[150] += [0.3, -0.2]  # 15 sigma off the path
    check = check_sigmas(t, frames, noisy, np.full(xy.shape, sigma_reported**2))
    assert check.outliers == (150,)
    se = 1 / math.sqrt(2 * check.coordinates)
    assert abs(check.factor / (sigma_true / sigma_reported) - 1) < 4 * se


def test_scatter_check_per_class_and_across_gaps():
    rng = np.random.default_rng(6)
    t, frames, xy = _path(600)
    keep = np.ones(len(t), bool)
    keep[[50, 51, 52, 300, 420]] = False  # dropped frames: gaps the check bridges
    t, frames, xy = t[keep], frames[keep], xy[keep]
    blended = (frames % 3) == 0
    sigma = np.where(blended, 0.03, 0.01)
    noisy = xy + rng.normal(0, 1, xy.shape) * sigma[:, None]
    check = check_sigmas(t, frames, noisy, np.full(xy.shape, 0.01**2), np.where(blended, "blended", "clear"))
    assert check.outliers == ()
    for label, truth in (("blended", 3.0), ("clear", 1.0)):
        f, se, n = check.by_class[label]
        assert n > 300 and abs(f / truth - 1) < 4 * se, (label, f)


def test_scatter_check_finds_an_error_common_to_every_frame():
    """A lossy codec moves the whole spot by an error no frame's own fit reports: here 0.05 px on every frame beside
    reported errors of 0.005-0.02 px (clear) and 0.03-0.06 px (blended), both right.  The floor comes out within 4
    of its standard errors, and the classes' factors (held at 1 or above) at 1."""
    rng = np.random.default_rng(7)
    t, frames, xy = _path(2000)
    blended = (frames % 4) == 0
    sigma = np.where(blended, rng.uniform(0.03, 0.06, len(t)), rng.uniform(0.005, 0.02, len(t)))
    floor = 0.05
    noisy = xy + rng.normal(0, 1, xy.shape) * np.hypot(sigma, floor)[:, None]
    check = check_sigmas(t, frames, noisy, np.repeat(sigma[:, None] ** 2, 2, axis=1),
                         np.where(blended, "blended", "clear"), floor=True, min_factor=1.0)
    assert abs(check.floor_px - floor) < 4 * check.floor_px_se
    for label in ("blended", "clear"):
        f, se, n = check.by_class[label]
        assert f >= 1.0 and (f - 1.0) <= 4 * max(se, 0.02), (label, f, se)


def test_frames_whose_own_errors_are_far_below_the_floor_are_not_taken_for_outliers():
    """A saturated phone tip's fit reports 0.01-0.02 px in some stretches where the codec's floor is 0.08 px: judged by
    their reported errors alone, those frames lie 5-7 of them off the path (a 120 frames/s phone render lost two
    clear frames 0.12 and 0.26 px off so).  With the floor the check finds, only the frames truly off the path are
    outliers: the four moved by 2 px (9 or more of their residuals' SDs, two of them inside such stretches), no other
    (a unit normal passes 5 in 1 of 1.7 million coordinates), and the floor within 4 of its standard errors.  Before,
    the check took 10 of the stretches' frames for outliers besides the four, and found the floor 0.070 px."""
    rng = np.random.default_rng(9)
    t, frames, xy = _path(1200)
    quiet = (frames % 60) < 10  # stretches of 10 frames whose fits report far less than the floor
    sigma = np.where(quiet, rng.uniform(0.01, 0.02, len(t)), rng.uniform(0.03, 0.12, len(t)))
    floor = 0.08
    noisy = xy + rng.normal(0, 1, xy.shape) * np.hypot(sigma, floor)[:, None]
    planted = [125, 304, 500, 790]  # 125 and 304 inside quiet stretches
    assert quiet[[125, 304]].all() and not quiet[[500, 790]].any()
    noisy[planted] += [2.0, 0.0]
    check = check_sigmas(t, frames, noisy, np.repeat(sigma[:, None] ** 2, 2, axis=1), floor=True, min_factor=1.0)
    assert check.outliers == tuple(planted)
    assert abs(check.floor_px - floor) < 4 * check.floor_px_se


def test_scatter_check_finds_an_error_common_to_each_run_of_b_pictures():
    """A codec renders the B pictures between two reference pictures from the same two, and moves them alike: here
    a 0.06 px error common to each run of four B pictures (P, B, B, B, B, P, ...), beside reported errors of
    0.01-0.02 px that are right and a floor of 0.02 px.  The record check finds the shared error within 4 of its
    standard errors; with it added to the B pictures' errors (and the floor and the factor to all) the SD of the
    B pictures' pulls is 1 within 4 of its standard errors (below), where without it it is 3-4."""
    from gyrorig.tracking.scatter import b_picture_runs

    rng = np.random.default_rng(8)
    t, frames, xy = _path(2000)
    types = np.where(frames % 5 == 0, "P", "B")
    runs = b_picture_runs(pd.DataFrame({"frame_type": types}))
    assert np.array_equal(runs >= 0, types == "B") and len(set(runs[runs >= 0])) == 400
    sigma = rng.uniform(0.01, 0.02, len(t))
    shared, floor = 0.06, 0.02
    common = rng.normal(0, shared, (runs.max() + 1, 2))
    error = rng.normal(0, 1, xy.shape) * np.hypot(sigma, floor)[:, None] + np.where(runs[:, None] >= 0,
                                                                                    common[runs], 0.0)
    check = check_sigmas(t, frames, xy + error, np.repeat(sigma[:, None] ** 2, 2, axis=1), floor=True,
                         min_factor=1.0, groups=runs)
    assert abs(check.shared_px - shared) < 4 * check.shared_px_se, (check.shared_px, check.shared_px_se)
    assert abs(check.floor_px - floor) < 4 * check.floor_px_se + 0.005, (check.floor_px, check.floor_px_se)
    b = runs >= 0
    f = check.by_class["all"][0]
    total = np.sqrt((f * sigma) ** 2 + check.floor_px**2 + check.shared_px**2)
    pulls = error[b] / total[b, None]
    # the pulls' SD is known to 1 / sqrt(2 n) from the n = 800 independent run errors that dominate it, and the
    # shared error's estimate moves it by its relative standard error
    se = math.sqrt(1 / (2 * 2 * len(common)) + (check.shared_px_se / check.shared_px) ** 2)
    assert abs(pulls.std() - 1) < 4 * se, (pulls.std(), se)
    assert (error[b] / np.hypot(f * sigma, check.floor_px)[b, None]).std() > 2.0


def test_errors_are_widened_where_the_record_scatters_more():
    """A record's errors change along it (the scene behind the tip, its speed): here 0.02 px everywhere as reported,
    but 0.05 px over frames 400-520 of 1000.  One factor for the record (1.3) leaves that stretch's pulls at 2; the
    local factors find 2.5 there, each known to sqrt((1 + 2 sum rho^2) / (2 N)) from the N = 80 coordinates of its
    window (rho the noise's residual correlations: 4 of those 57 %), and elsewhere 1 or the window's chance excess
    (their mean within 1 + 4 of those standard errors over the window's count of independent stretches)."""
    rng = np.random.default_rng(11)
    t, frames, xy = _path(1000)
    sigma = np.where((frames >= 400) & (frames < 520), 0.05, 0.02)
    var = np.full(xy.shape, 0.02**2)
    local = local_factors(t, frames, xy + rng.normal(0, 1, xy.shape) * sigma[:, None], var, np.ones(len(t), bool))
    inner = (frames >= 400 + LOCAL_FRAMES // 2) & (frames < 520 - LOCAL_FRAMES // 2)
    se = math.sqrt((1 + 2 * np.sum(NOISE_ACF**2)) / (2 * 2 * LOCAL_FRAMES))
    assert np.all(np.abs(local[inner] / 2.5 - 1) < 4 * se), local[inner]
    outside = (frames < 400 - LOCAL_FRAMES) | (frames >= 520 + LOCAL_FRAMES)
    assert np.all(local >= 1.0) and np.mean(local[outside]) - 1.0 < 4 * se / math.sqrt(outside.sum() / LOCAL_FRAMES)
    assert np.mean(local[outside] > 1.0) < 0.9  # not widened everywhere
    few = local_factors(t[:20], frames[:20], xy[:20], var[:20], np.ones(20, bool))
    assert np.array_equal(few, np.ones(20))  # too few checked frames for a window: nothing widened


def test_scatter_check_knows_when_the_path_cannot_follow_the_motion():
    """The check holds while a path through six neighbours predicts a frame far below its noise.  A 9.5 Hz nod seen
    at 30 frames/s (2 rad per frame) leaves residuals that are the motion: the check says so (``smooth_path``) rather
    than read them as errors 50x too large.  Noise correlated from frame to frame as a P-picture chain's (AR(1), 0.6)
    at 240 frames/s is still noise to it (its residuals' correlations at lags 1-4 move by up to 0.1 from white
    noise's, where the coarse path's move by 0.4-1.2)."""
    rng = np.random.default_rng(9)
    t = np.arange(120) / 30.0
    xy = np.column_stack([300 + 40 * np.cos(1.7 * t) + 6 * np.sin(59.5 * t), 200 + 30 * np.sin(1.7 * t)
                          + 6 * np.cos(59.5 * t)])
    coarse = check_sigmas(t, np.arange(120), xy + rng.normal(0, 0.1, xy.shape), np.full(xy.shape, 0.01))
    assert not coarse.smooth_path
    t, frames, xy = _path(1000)
    noise = np.zeros(xy.shape)
    for k in range(1, len(t)):
        noise[k] = 0.6 * noise[k - 1] + rng.normal(0, 0.05, 2)
    fine = check_sigmas(t, frames, xy + noise, np.full(xy.shape, 0.05**2))
    assert fine.smooth_path, fine.residual_acf


def _nod_at_30_frames_per_second(rng, n: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """A top's tip seen at 30 frames/s (5 % jitter): a precession of 1.7 rad/s and a 9.5 Hz nod (2 rad per frame)
    with cusps (its second harmonic), decaying with a time constant of 20 s, in pixels: ``(t_s, xy)``."""
    t = (np.arange(n) + rng.normal(0, 0.05, n)) / 30.0
    nod = 6 * np.exp(-t / 20.0)
    return t, np.column_stack([300 + 40 * np.cos(1.7 * t) + nod * (np.sin(59.5 * t) + 0.4 * np.cos(119.0 * t)),
                               200 + 30 * np.sin(1.7 * t) + nod * (np.cos(59.5 * t) + 0.4 * np.sin(119.0 * t))])


def test_a_path_of_sinusoids_checks_the_errors_where_the_neighbours_cannot_follow():
    """At 30 frames/s a 9.5 Hz nod turns by 2 rad between frames: no path through six neighbours follows it, and
    the errors went unchecked (on the phone-30fps variant pull SDs 1.26/1.44).  A path of sinusoids over the whole
    record follows it: 0.1 px of noise against 0.05 reported gives the factor 2, and against 0.1 the factor 1,
    each within 4 of its standard errors (1 / sqrt(2 N), N coordinates); a frame 1.5 px off (15 sigma) is an
    outlier and no other frame is, also with the first 30 frames given no position (a still end left out of the
    check: they made every residual NaN).  B pictures with twice the noise of the rest are told apart by class."""
    rng = np.random.default_rng(21)
    t, xy = _nod_at_30_frames_per_second(rng)
    frames = np.round(t * 30).astype(int)
    noisy = xy + rng.normal(0, 0.1, xy.shape)
    noisy[100] += [1.2, -0.9]
    assert not check_sigmas(t, frames, noisy, np.full(xy.shape, 0.01), follow_motion=True).smooth_path
    for reported, expected in ((0.05, 2.0), (0.1, 1.0)):
        h = harmonic_check(t, frames, noisy, np.full(xy.shape, reported**2))
        assert h.follows and h.outliers == (100,), (h.residual_acf, h.outliers)
        assert abs(h.factor - expected) < 4 * h.factor_se, (h.factor, h.factor_se)
    # frames left out of the check (a still end's: no position given) are neither fitted nor outliers
    held = noisy.copy()
    held[:30] = np.nan
    h = harmonic_check(t, frames, held, np.full(xy.shape, 0.1**2))
    assert h.follows and h.outliers == (100,) and abs(h.factor - 1.0) < 4 * h.factor_se, (h.outliers, h.factor)
    b = np.arange(len(t)) % 4 != 0  # three B pictures to a reference picture
    noisy = xy + rng.normal(0, 1, xy.shape) * np.where(b, 0.2, 0.1)[:, None]
    h = harmonic_check(t, frames, noisy, np.full(xy.shape, 0.01), np.where(b, "B", "ref"))
    for label, expected in (("B", 2.0), ("ref", 1.0)):
        f, se, _ = h.by_class[label]
        assert abs(f - expected) < 4 * se, (label, f, se)


@pytest.mark.parametrize("jitter, dropped", [(0.0, 0), (0.1, 15), (0.45, 40)])
def test_the_periodogram_by_fft_is_scipys_lombscargle(jitter, dropped):
    """The path of sinusoids finds each frequency on a periodogram made by FFT (:class:`Periodogram`): it is
    :func:`scipy.signal.lombscargle` with a floating mean (the direct sums, an independent definition) on the check's
    own grid, summed over both axes, to 1e-9 of its peak (the FFT's sums are exact but for a Taylor series carried
    to 1e-13), on frame times on the grid, jittered, and with frames dropped."""
    rng = np.random.default_rng(int(jitter * 100) + dropped)
    frames = np.sort(rng.choice(400 + dropped, 400, replace=False))
    t = 5.0 + (frames + rng.uniform(-jitter, jitter, 400)) / 30.0
    y = np.column_stack([np.sin(2 * np.pi * 9.3 * t) + rng.normal(0, 1, 400), rng.normal(0, 1, 400)])
    span = float(np.ptp(t))
    d_omega, m = 0.1 * 2 * np.pi / span, math.ceil(2 * span * 30 / 2 / 0.1) - 1
    omegas = np.arange(1, m + 1) * d_omega
    expected = sum(lombscargle(t - t.mean(), y[:, k], omegas, floating_mean=True) for k in (0, 1))
    got = Periodogram(t, d_omega, m).power(y)
    assert np.max(np.abs(got - expected)) < 1e-9 * expected.max()
    single = Periodogram(t, d_omega, m).power(y[:, 0])
    assert np.max(np.abs(single - lombscargle(t, y[:, 0], omegas, floating_mean=True))) < 1e-9 * expected.max()


def test_a_path_of_sinusoids_that_cannot_follow_says_so():
    """A tip wandering at random (a random walk of 2 px per frame) is no sum of a few sinusoids: the path's
    residuals stay correlated from frame to frame and the check says it does not follow, rather than take them for
    errors."""
    rng = np.random.default_rng(22)
    t = np.arange(240) / 30.0
    xy = 300 + np.cumsum(rng.normal(0, 2.0, (240, 2)), axis=0) + rng.normal(0, 0.1, (240, 2))
    h = harmonic_check(t, np.arange(240), xy, np.full(xy.shape, 0.01))
    assert not h.follows, h.residual_acf


def test_a_nod_too_fast_for_the_polynomial_path_is_followed_by_its_own_frequency():
    """At 60 frames/s (5 % jitter) a 9.5 Hz nod of 6 px turns by 1 rad between frames: a degree-5 path through six
    neighbours leaves the motion in its residuals (``smooth_path`` false: the errors would stay unchecked; on phone
    renders 1-4 frames per record beyond 5 sigma flagged ok).  With ``follow_motion`` the check finds the nod's
    frequency on the track (within 2 %) and puts it in the path's basis: the path follows, and the factor is the
    true one, 0.1 px of noise against 0.05 reported, within 4 of its standard errors (1 / sqrt(2 N))."""
    rng = np.random.default_rng(12)
    n = 600
    t = (np.arange(n) + rng.normal(0, 0.05, n)) / 60.0
    nod, precession = 2 * np.pi * 9.5, 1.3
    xy = np.column_stack([320 + 80 * np.cos(precession * t) + 6 * np.cos(nod * t),
                          240 + 60 * np.sin(precession * t) + 6 * np.sin(nod * t)])
    noisy = xy + rng.normal(0, 0.1, xy.shape)
    var = np.full(xy.shape, 0.05**2)
    plain = check_sigmas(t, np.arange(n), noisy, var)
    assert not plain.smooth_path
    check = check_sigmas(t, np.arange(n), noisy, var, follow_motion=True)
    assert check.smooth_path and check.omega_rad_s == pytest.approx(nod, rel=0.02)
    assert abs(check.factor - 2.0) < 4 * check.factor_se, (check.factor, check.factor_se)


def test_errors_that_alternate_from_frame_to_frame_are_errors_not_motion():
    """A codec that codes every other picture worse (a B-picture pyramid's unreferenced pictures) moves those
    pictures' positions by an error that flips sign from frame to frame, its size following the tip's speed (a
    10 Hz nod at 240 frames/s).  The residuals then correlate at lag 1 below white noise's -0.857, where a motion
    the path cannot follow would give ``cos(omega)`` above it; the check reads them as errors instead of leaving the
    errors unchecked (a rocket render at CRF 28 gave pulls of 1.7-2.0 that way).  Its factor is their size, 0.09 px
    RMS against 0.03 reported (3.0), or up to 2.1 times more: the path's stencil passes an error that alternates
    1 + 44/20 = 3.2 times, white noise sqrt(1 + 524/400) = 1.52 times (bounds widened by 10 %)."""
    rng = np.random.default_rng(11)
    t, frames, xy = _path(1000)
    sign = np.where(frames % 2 == 1, 1.0, -1.0)
    error = 0.14 * np.sin(2 * np.pi * 10.0 * t)[:, None] * sign[:, None] * np.array([1.0, 0.7])
    check = check_sigmas(t, frames, xy + error + rng.normal(0, 0.03, xy.shape), np.full(xy.shape, 0.03**2))
    assert check.residual_acf[0] < NOISE_ACF[0] - 0.05
    true = math.sqrt(np.mean(error**2) + 0.03**2) / 0.03
    assert check.smooth_path and 0.9 * true < check.factor < 1.1 * 2.1 * true, (check.residual_acf, check.factor)


def _camera():
    """1280x720, f = 1000 px, a lens with k1, k2, k3, looking down at the pivot from 0.7 m, 10 deg off
    vertical."""
    k = np.array([[1000.0, 0, 640], [0, 1000, 360], [0, 0, 1]])
    rot = cv2.Rodrigues(np.array([math.pi - math.radians(10.0), 0.0, 0.0]))[0]
    centre = np.array([0.0, -0.7 * math.sin(math.radians(10.0)), 0.7 * math.cos(math.radians(10.0))])
    return Camera(k, np.array([-0.1, 0.05, 0.0, 0.0, -0.01]), cv2.Rodrigues(rot)[0].ravel(),
                          -rot @ centre, 1280, 720, 240.0, 5e-4, "global", 0.0, 0.8, Sensor(bit_depth=16))


def _ray_cast_disc(cam, centre, normal, radius, s=8):
    """A second rendering of a flat disc sharing no code with the tracker's model: supersampled rays
    through the distorted pixel grid meet the disc's plane (then the PSF)."""
    px = cv2.projectPoints(centre[None], cam.rvec, cam.tvec, cam.camera_matrix, cam.dist_coeffs)[0].ravel()
    x0, y0 = int(px[0]) - 20, int(px[1]) - 20
    sub = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(x0, x0 + 41)[:, None] + sub).ravel()
    ys = (np.arange(y0, y0 + 41)[:, None] + sub).ravel()
    grid = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(grid, cam.camera_matrix, cam.dist_coeffs).reshape(-1, 2)
    rays = np.column_stack([und, np.ones(len(und))]) @ cam.rotation
    origin = cam.centre_m
    dist = ((centre - origin) @ normal) / (rays @ normal)
    hit = origin + dist[:, None] * rays - centre
    cover = (np.einsum("ij,ij->i", hit, hit) <= radius**2).reshape(41, s, 41, s).mean(axis=(1, 3))
    image = np.zeros((720, 1280))
    image[y0:y0 + 41, x0:x0 + 41] = 20 + 3000 * cv2.GaussianBlur(cover, (0, 0), cam.psf_sigma_px)
    return image, px


@pytest.mark.parametrize("tilt_deg", [20.0, 45.0, 60.0])
def test_disc_centre_is_recovered_from_an_independent_ray_cast(tilt_deg):
    """The elliptical fit plus the perspective offset finds the disc centre's image; the ellipse's own
    centre is off by the offset :func:`disc_image` predicts (a few 0.01 px)."""
    cam = _camera()
    length = 0.14
    a = math.radians(tilt_deg)
    n = np.array([math.sin(a) * 0.6, -math.sin(a) * 0.8, math.cos(a)])
    image, truth_px = _ray_cast_disc(cam, length * n, n, 0.004)
    image += np.random.default_rng(0).normal(0, 0.5, image.shape)
    fit = fit_ellipse_spot(image, truth_px[0] + 0.4, truth_px[1] - 0.3, 5.0, cam)
    geo = DiscGeometry(cam, length, 0.004)
    centre = np.array(geo.centre_px(fit))
    sigma = math.sqrt(max(fit.cov_xy[0, 0], fit.cov_xy[1, 1]))
    predicted = disc_image(length * n, n, 0.004, cam)
    offset = predicted.ellipse_centre_px - predicted.centre_px
    assert np.linalg.norm(offset) > 0.005
    # within its own error plus 0.005 px of model error (the first-order edge; measured on these renders)
    assert np.linalg.norm(centre - truth_px) < 4 * sigma + 0.005
    assert np.linalg.norm(np.array([fit.x_px, fit.y_px]) - truth_px - offset) < 4 * sigma + 0.005
    assert abs(fit.major_px / predicted.major_px - 1) < 0.05 and abs(fit.minor_px / predicted.minor_px - 1) < 0.1


def test_container_time_rounding_gives_the_nominal_frame_times(tmp_path):
    """240 fps frames stamped to the millisecond (Matroska's clock) are tracked at their own times."""
    scene, user, _ = variant_protocols("sphere", 0.2)
    scene["camera"]["fps"] = 240.0
    render_video(parse_protocol(scene), tmp_path / "v", seed=0, calibration_views=0)
    cam = load_camera(tmp_path / "v" / "camera.json")
    frames = gray_frames(tmp_path / "v" / "video.mkv")
    t_ms = np.round(np.arange(len(frames)) / 240.0, 3)
    res = track(FrameArrays(frames, t_ms), cam, parse_protocol(user))
    np.testing.assert_allclose(res.angles.t_s, np.arange(len(frames)) / 240.0 + cam.exposure_s / 2, rtol=0,
                               atol=1e-12)


def test_a_blob_tip_is_tracked_with_errors_from_the_data():
    """A user who does not know the marker's appearance says ``shape = "blob"``: the tracker then
    uses the elliptical model and takes the errors' scale from the record."""
    scene, user, codec = variant_protocols("sphere", 1.0)
    user["markers"]["tip"]["shape"] = "blob"
    r = track_variant("sphere", duration_s=1.0, seed=2, protocols=(scene, user, codec))
    assert r["sigma_scaled"] and r["wrong_ok"] == 0 and r["tracked_clear_fraction"] >= 0.99
    lo, hi = sd_ratio_band(r["tip_visible"])
    assert lo <= r["pull_sd_theta"] <= hi and lo <= r["pull_sd_phi"] <= hi, r


def test_track_overlay_shows_the_chosen_frames(tmp_path):
    """``gyrorig track --overlay`` writes a contact sheet of frames spread over the record plus those
    not flagged ``ok``."""
    import tomllib

    from conftest import PROTOCOL_DIR
    from gyrorig.cli import main
    from gyrorig.report.overlay import overlay_frames

    proto = PROTOCOL_DIR / "air-cushion-heavy-top.toml"
    d = tomllib.loads(proto.read_text())
    d["camera"].update(width_px=640, height_px=480, pixel_size_um=3.45 * 2.25)
    d["scene"]["duration_s"] = 0.3
    render_video(parse_protocol(d), tmp_path / "v", seed=0, calibration_views=0)
    code = main(["track", str(tmp_path / "v" / "video.mkv"), "--camera", str(tmp_path / "v" / "camera.json"),
                 "--protocol", str(proto), "--out", str(tmp_path / "t"), "--overlay", "--tip-only"])
    assert code == 0
    # camera crops are dark: the sheet decodes, is large, and is not a blank or solid image
    sheet = cv2.imread(str(tmp_path / "t" / "overlay.png"), cv2.IMREAD_GRAYSCALE)
    assert sheet is not None and min(sheet.shape) >= 300 and sheet.std() > 20
    angles = pd.read_csv(tmp_path / "t" / "angles.csv")
    chosen = overlay_frames(angles)
    assert 12 <= len(chosen) <= 20 and chosen[0] == 0 and chosen[-1] == angles.frame.iloc[-1]
    assert set(angles.frame[angles.quality != "ok"]) <= set(chosen) or len(set(chosen)) >= 20


def test_a_path_that_leaves_many_frames_off_it_does_not_follow_the_motion():
    """The tip's pixel track as the tracker checked it on a 1280x720 render at 50 frames/s (the air-cushion top
    nodding with cusps, up to 12 px per frame; stored losslessly; ``tests/data/heavy_top_50fps_1280x720_tip_track.csv``
    holds what the check was given, and the renderer's truth).  The polynomial path through six neighbours misses
    the frames at every turn of the nod, and taking them out one by one left too few neighbours for its residuals'
    correlations to show it: 35 of 98 frames were called outliers, every one within 2.7 of its own sigmas of the
    truth.  A path that leaves more than a tenth of the frames off it is a path that does not follow the motion (the
    tracker then tries the nod's own frequency: :func:`motion_frequency`); with the outliers' scale taken over each
    frame's stretch where that is larger, the turns' frames stay in and their residuals' correlations show it."""
    track = pd.read_csv(Path(__file__).parent / "data" / "heavy_top_50fps_1280x720_tip_track.csv")
    xy = track[["x_px", "y_px"]].to_numpy()
    var = track[["var_x_px2", "var_y_px2"]].to_numpy()
    check = check_sigmas(track.t_s, track.frame, xy, var, track["class"].to_numpy(), floor=True, min_factor=1.0)
    truth_z = np.abs(xy - track[["x_true_px", "y_true_px"]].to_numpy()) / np.sqrt(var)
    assert truth_z.max() < 5.0 and not check.smooth_path


def test_the_nods_frequency_is_found_beyond_the_periodograms_first_peaks():
    """4 s of the simulator's nodding top seen at 50 frames/s (its precession circle, 35 px of radius, on the track;
    0.03 px of noise): a quadratic does not take the precession off over 4 s, and its leakage makes the
    periodogram's strongest peaks below the nod's (the nod's was the sixth).  The sinusoid that leaves the least
    scatter about the path is the nod's: within 4 % of the exact solution's nutation frequency (the periodogram's
    grid is 0.28 rad/s apart and the projection's harmonics pull it)."""
    protocol = scene_protocol("air-cushion-heavy-top")
    t_s = np.arange(200) / 50.0
    traj = simulate(protocol, t_eval_s=t_s)
    th, ph = traj.theta_rad.to_numpy(), traj.phi_rad.to_numpy()
    xy = 640 + 250 * np.column_stack([np.sin(th) * np.sin(ph), -np.sin(th) * np.cos(ph)])
    xy += np.random.default_rng(0).normal(0.0, 0.03, xy.shape)
    nod = exact_solution(protocol).nutation_frequency_rad_s
    assert motion_frequency(t_s, np.arange(200), xy) == pytest.approx(nod, rel=0.04)
