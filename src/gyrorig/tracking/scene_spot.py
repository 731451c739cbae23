"""The marker spot in a recording: an opaque disc in front of a real scene.

On a recording (no sensor model: gamma, a lossy codec, a phone's processing) the background behind the
marker is whatever the room shows, and it is not flat: a texture's edge, a shadow or a highlight next to
the marker pulls a flat-background fit towards it by far more than the noise would.  Here the disc
covers the scene: ``mu = B (1 - c) + M c``, ``c`` the disc's coverage blurred by the PSF
(``erfc((rho - r) / (sqrt(2) sigma)) / 2``), ``M`` the marker's level and ``B`` the scene **just outside
the disc at the same angle**: the mean of the ring ``r + g sigma <= rho < r + g sigma + 2`` px in
:data:`ANGLE_BINS` bins around the centre, interpolated in angle (``g`` :data:`RING_GAP_SIGMAS`).  Only the
pixels inside the ring are fitted (``x, y, r, M`` and the blur; weighted least squares, the ring taken again about
the first few centres); what the scene does between the ring and the disc's edge is left in the residuals, and the
centre's covariance comes from them (:func:`sandwich_covariance`) and from what the unseen scene under the edge may
differ from the ring (:func:`_scene_covariance`: the ring's own texture at that distance), so it grows where the
scene behind the edge is busy.  A second fit with the ring nearer the edge (:func:`near_ring_move`) says where the
scene changes between the edge and the ring.  Near the image's edge the window is cut there (the disc and its blur
inside the image): the ring's bins beyond it take the scene of the bins beside them, and their sectors' edge points
are left out of the edge's roughness and the unseen scene's share.

A bin of the ring much brighter than the rest (light of another marker touching the ring) marks the fit
``blended``; the model still holds there to first order (that light is outside the disc), and the
residuals carry what it does not.  A saturated pixel is censored: it says only that the light there is at least
full scale (an overexposed marker is fitted by where its image leaves the plateau).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..camera import Camera
from . import ellipse, spot
from .sandwich import _projected_meat, sandwich_covariance
from .scene_edge import (ANGLE_BINS, RING_WIDTH_PX, _bin_of, _edge_radii, _edge_roughness, fill_empty_bins,
                         on_image_bins)
from .small_solve import lu_solve
from .spot import SpotFit, fit_spot, window_levels

__all__ = ["fit_scene_spot", "fit_round_spot", "sandwich_covariance", "warm_up", "ANGLE_BINS", "RING_WIDTH_PX",
           "near_ring_move", "NEAR_RING_GAP_SIGMAS"]

#: the ring starts this many PSF sigmas beyond the disc's edge (where the disc's light has fallen to 1e-3)
RING_GAP_SIGMAS = 3.0
#: a second view of the scene under the edge (:func:`near_ring_move`): a ring this many sigmas beyond the edge (the
#: disc's light there 7 % of its contrast, 1-4 % averaged over the ring's width for a blur of 0.5-3.5 px, alike at
#: every angle: it moves the ring's levels, not the centre)
NEAR_RING_GAP_SIGMAS = 1.5
#: the two views' centres differ when they are farther apart than this many of their errors (the two fits' covariances
#: summed: their errors are correlated, so chance differences stay well inside this)
RING_MOVE_Z = 2.0
#: the edge's blur is fitted (a recording's optics, focus and codec widen the PSF), up to this factor (+1 px) of the
#: camera file's PSF sigma
MAX_BLUR = 2.5
#: the ring (and the pixels inside it) is taken again about the new centre for this many passes, then held
RING_PASSES = 3
#: the fit has converged when a full Gauss-Newton step moves the centre by less than this [px] (the ring is taken
#: again about each new centre, so the steps settle at a small fraction of the centre's error, not at zero)
CONVERGED_PX = 1e-3
#: the marker's own noise is measured on at least this many pixels inside its edge (else the ring's holds there)
MIN_INNER_PIXELS = 8
#: a ring bin brighter than the ring's median by this many robust SDs of the ring's bins, and by this fraction
#: of the marker's contrast, holds another spot's light
FOREIGN_Z = 5.0
FOREIGN_CONTRAST = 0.1
#: a saturated marker's level (censored pixels: :func:`_pass`) is held below this many times full scale (4 stops)
MAX_OVER_TOP = 16.0
#: near the image's edge the fit's window is cut there where the disc's centre lies at least its radius and this many
#: PSF sigmas (+1 px) inside the image (its edge's blur inside too); up to this many of the ring's bins may then lie
#: beyond the image (a quarter of the ring: the rest gives the scene there, their sectors' edge points left out)
EDGE_MARGIN_SIGMAS = 3.0
MAX_OFF_IMAGE_BINS = 8


@njit(cache=True)
def _ring(win, x_first, y_first, cx, cy, r_out, allowed, inside=True, max_empty=0):
    """The ring about ``(cx, cy)`` starting at ``r_out``, and the pixels inside it: ``(ok, bins, pick, scene,
    spread)``.  ``bins`` the ring's bin means; ``pick`` the flat indices of the allowed pixels nearer than
    ``r_out``, ``scene`` the scene ``B`` at each (the bins interpolated in angle); ``spread`` the ring pixels'
    robust SD about their bins' means.  ``ok`` False when more than ``max_empty`` bins are empty (a window cut at
    the image's edge: those take the line between the bins beside them, :func:`fill_empty_bins`).  Without
    ``inside`` only ``ok`` and ``bins`` are made (``pick`` and ``scene`` empty, ``spread`` 0)."""
    h, w = win.shape
    sums = np.zeros(ANGLE_BINS)
    counts = np.zeros(ANGLE_BINS)
    ring_values = np.empty(h * w)
    ring_bins = np.empty(h * w, np.int64)
    pick = np.empty(h * w, np.int64)
    angle = np.empty(h * w)
    n_ring = 0
    n_pick = 0
    # only the rows and columns the ring's outer circle reaches (a pixel beyond them is off it in x or y alone)
    reach = r_out + RING_WIDTH_PX
    iy0, iy1, ix0, ix1 = 0, h, 0, w
    if math.isfinite(cx) and math.isfinite(cy) and math.isfinite(reach):
        iy0, iy1 = max(0, int(math.floor(cy - reach - y_first))), min(h, int(math.ceil(cy + reach - y_first)) + 1)
        ix0, ix1 = max(0, int(math.floor(cx - reach - x_first))), min(w, int(math.ceil(cx + reach - x_first)) + 1)
    for iy in range(iy0, iy1):
        dy = y_first + iy - cy
        for ix in range(ix0, ix1):
            dx = x_first + ix - cx
            rho = math.sqrt(dx * dx + dy * dy) + 1e-12
            if rho < r_out:
                if inside and allowed[iy, ix]:
                    pick[n_pick] = iy * w + ix
                    angle[n_pick] = math.atan2(dy, dx)
                    n_pick += 1
            elif rho < r_out + RING_WIDTH_PX:
                b = _bin_of(dx, dy)
                sums[b] += win[iy, ix]
                counts[b] += 1.0
                ring_values[n_ring] = win[iy, ix]
                ring_bins[n_ring] = b
                n_ring += 1
    bins = np.zeros(ANGLE_BINS)
    scene = np.empty(n_pick)
    empty = 0
    for b in range(ANGLE_BINS):
        if counts[b] == 0:
            empty += 1
        else:
            bins[b] = sums[b] / counts[b]
    if empty > min(max_empty, ANGLE_BINS - 2):
        return False, bins, pick[:n_pick], scene, 0.0
    if empty:
        fill_empty_bins(bins, counts)
    if not inside:
        return True, bins, pick[:0], scene, 0.0
    dev = np.empty(n_ring)
    for k in range(n_ring):
        dev[k] = abs(ring_values[k] - bins[ring_bins[k]])
    spread = 1.4826 * np.median(dev)
    for k in range(n_pick):
        u = (angle[k] + math.pi) / (2 * math.pi) * ANGLE_BINS - 0.5
        i0 = math.floor(u)
        f = u - i0
        lo = (int(i0) + ANGLE_BINS) % ANGLE_BINS
        scene[k] = (1.0 - f) * bins[lo] + f * bins[(lo + 1) % ANGLE_BINS]
    return True, bins, pick[:n_pick], scene, spread


@njit(cache=True)
def _pass(xs, ys, values, scene, p, var_out, var_in, measure_inner, top):
    """One Gauss-Newton pass over the fitted pixels: ``(fisher, gradient, jac, resid, weight, coverage,
    var_in)``.  With ``measure_inner`` the marker's noise ``var_in`` is measured from the residuals where the
    disc covers the pixel (at least :data:`MIN_INNER_PIXELS` of them; NaN: use the ring's); the weights are
    ``1 / ((1 - c) var_out + c var_in)``.  A pixel at full scale ``top`` (saturated) says only that the light
    there is at least that: where the model reaches it too, its residual and its Jacobian row are 0 (censored),
    else the model is pulled up to it."""
    n = xs.size
    jac = np.empty((n, 5))
    resid = np.empty(n)
    cover = np.empty(n)
    censored = np.zeros(n, np.bool_)
    s2 = math.sqrt(2.0) * p[4]
    norm = 1.0 / (math.sqrt(2.0 * math.pi) * p[4])
    for k in range(n):
        dx, dy = xs[k] - p[0], ys[k] - p[1]
        rho = math.sqrt(dx * dx + dy * dy) + 1e-12
        arg = (rho - p[2]) / s2
        c = 0.5 * math.erfc(arg)
        gauss = math.exp(-arg * arg) * norm
        level = p[3] - scene[k]
        edge = -level * gauss  # d mu / d rho
        jac[k, 0] = edge * (-dx / rho)
        jac[k, 1] = edge * (-dy / rho)
        jac[k, 2] = -edge
        jac[k, 3] = c
        jac[k, 4] = level * gauss * (rho - p[2]) / p[4]
        model = scene[k] * (1.0 - c) + p[3] * c
        resid[k] = min(values[k], top) - model
        cover[k] = c
        if values[k] >= top and model >= top:
            censored[k] = True
            resid[k] = 0.0
            for a in range(5):
                jac[k, a] = 0.0
    if measure_inner:
        inner = resid[(cover > 0.99) & ~censored]
        if inner.size >= MIN_INNER_PIXELS:
            var_in = max(np.median(inner * inner) / 0.4549, 1.0 / 12.0)
    v_in = var_out if math.isnan(var_in) else var_in
    weight = 1.0 / (var_out * (1.0 - cover) + v_in * cover)
    fisher = np.zeros((5, 5))
    grad = np.zeros(5)
    for k in range(n):
        wk = weight[k]
        for a in range(5):
            wja = wk * jac[k, a]
            grad[a] += wja * resid[k]
            for b in range(a, 5):
                fisher[a, b] += wja * jac[k, b]
    for a in range(5):
        for b in range(a):
            fisher[a, b] = fisher[b, a]
    return fisher, grad, jac, resid, weight, cover, var_in


@njit(cache=True)
def _sector_effects(xs, ys, cx, cy, jac, weight, coverage):
    """Each ring bin's effect on the parameters per unit error of its level: the fitted pixels' Jacobian rows
    times ``weight (1 - c)``, summed over the pixels of each angular sector about ``(cx, cy)``."""
    v = np.zeros((ANGLE_BINS, jac.shape[1]))
    for k in range(xs.size):
        b = _bin_of(xs[k] - cx, ys[k] - cy)
        f = weight[k] * (1.0 - coverage[k])
        for a in range(jac.shape[1]):
            v[b, a] += jac[k, a] * f
    return v


@njit(cache=True)
def _fitted_bins(xs, ys, cx, cy):
    """Which angular bins about ``(cx, cy)`` hold fitted pixels (at ``xs, ys``; the others' sectors were left out)."""
    out = np.zeros(ANGLE_BINS, np.bool_)
    for k in range(xs.size):
        out[_bin_of(xs[k] - cx, ys[k] - cy)] = True
    return out


@njit(cache=True)
def _scene_covariance(p, xs, ys, jac, weight, coverage, bins, fisher_inv, kept, gap_sigmas):
    """What the scene behind the disc's edge, unseen, may do to the parameters ``p``: the ring stands in for it, but
    the edge lies ``gap_sigmas sigma + 1`` px further in.  Taking the scene's texture as isotropic, it changes over that
    distance as much as it does along the ring over the same arc: the ring's structure function at that lag
    (mean square difference of ``bins`` that far apart) is the variance of each bin's error, independent from bin to
    bin, and it reaches the fit through the pixels it lies behind (``(1 - c)`` of each, by their Jacobian rows).
    Only the ``kept`` bins enter the structure function (a dark object's edge, whose sectors are left out of the fit,
    is not the scene behind the pixels fitted)."""
    gap = gap_sigmas * p[4]
    arc = 2 * math.pi * (p[2] + gap + RING_WIDTH_PX / 2) / ANGLE_BINS
    lag = max(1, int(np.round((gap + 1.0) / arc)))
    v = _sector_effects(xs, ys, p[0], p[1], jac, weight, coverage)
    kept_sum, kept_n, all_sum = 0.0, 0, 0.0
    for b in range(ANGLE_BINS):
        a = (b - lag) % ANGLE_BINS  # the bin ``lag`` before
        square = (bins[a] - bins[b]) ** 2
        all_sum += square
        if kept[a] and kept[b]:
            kept_sum += square
            kept_n += 1
    var_bin = kept_sum / kept_n if kept_n else all_sum / ANGLE_BINS
    return fisher_inv @ (var_bin * (v.T @ v)) @ fisher_inv


@njit(cache=True)
def _centre_errors(win, x_first, y_first, p, pick, xs, ys, weight, jac, resid, fisher, bins, coverage, kept, top,
                   gap_sigmas):
    """A converged fit's centre covariance (2, 2) and reduced chi-square: the sandwich of its residuals
    (:func:`sandwich_covariance`), the scene behind its edge (:func:`_scene_covariance`) and its edge's roughness
    (:func:`_edge_roughness`); ``ok`` False when the edge has too few points (the Fisher matrix's inverse raises
    ``LinAlgError`` when singular)."""
    finv = np.linalg.inv(fisher)
    rough = _edge_roughness(win, p[0] - x_first, p[1] - y_first, p, bins, kept, top, gap_sigmas)
    if not math.isfinite(rough):
        return False, np.zeros((2, 2)), math.nan
    cov = (_projected_meat(pick, win.shape, jac, weight, resid, np.ascontiguousarray(finv[:2]))
           + _scene_covariance(p, xs, ys, jac, weight, coverage, bins, finv, kept, gap_sigmas)[:2, :2])
    cov[0, 0] += rough
    cov[1, 1] += rough
    return True, cov, float(np.sum(resid ** 2 * weight)) / max(pick.size - 5, 1)


@dataclass
class _Solution:
    """A converged fit (:func:`_solve` returns None otherwise): its parameters and, for each fitted pixel (flat indices ``pick`` into the window, at
    ``xs, ys``), its Jacobian row, weight, residual and the disc's coverage; the Fisher matrix and the ring's
    bins."""

    p: np.ndarray
    pick: np.ndarray
    xs: np.ndarray
    ys: np.ndarray
    weight: np.ndarray
    jac: np.ndarray
    resid: np.ndarray
    fisher: np.ndarray
    bins: np.ndarray
    coverage: np.ndarray


@njit(cache=True)
def _median(values):
    """The median of a few numbers, compiled (called once per fit)."""
    return np.median(values)


@njit(cache=True)
def _foreign_bins(bins: np.ndarray, marker_level: float, sign: float = 1.0) -> np.ndarray:
    """Ring bins holding another spot's light: above the ring's median by :data:`FOREIGN_Z` robust SDs of the
    bins and by :data:`FOREIGN_CONTRAST` of the marker's contrast (``sign = -1``: below it by as much, a dark
    object's edge)."""
    med = np.median(bins)
    sd = max(1.4826 * np.median(np.abs(bins - med)), math.sqrt(1.0 / 12.0))
    return sign * (bins - med) > max(FOREIGN_Z * sd, FOREIGN_CONTRAST * (marker_level - med))


@njit(cache=True)
def _without_sectors(allowed, x_first, y_first, cx, cy, foreign):
    """``allowed`` without the pixels in the angular sectors about ``(cx, cy)`` of the ``foreign`` bins and of
    one bin either side of each."""
    near = foreign.copy()
    for b in range(ANGLE_BINS):
        if foreign[b]:
            near[(b + 1) % ANGLE_BINS] = True
            near[(b - 1 + ANGLE_BINS) % ANGLE_BINS] = True
    h, w = allowed.shape
    out = allowed.copy()
    for iy in range(h):
        for ix in range(w):
            if near[_bin_of(x_first + ix - cx, y_first + iy - cy)]:
                out[iy, ix] = False
    return out


@njit(cache=True)
def _solve_core(win, x_first, y_first, allowed, p0, r0, sigma, sigma_max, iterations, top, gap_sigmas, max_empty):
    """:func:`_solve`'s iterations, compiled: ``(ok, p, pick, xs, ys, weight, jac, resid, fisher, bins,
    coverage)``; ``max_empty`` the ring's bins that may lie beyond the image (:func:`_ring`)."""
    h, w = win.shape
    p = p0.copy()
    converged = False
    var_in = math.nan
    var_out = 1.0 / 12.0
    pick = np.empty(0, np.int64)
    bins = np.zeros(ANGLE_BINS)
    scene = np.empty(0)
    xs, ys, values = np.empty(0), np.empty(0), np.empty(0)
    fisher, grad = np.zeros((5, 5)), np.zeros(5)
    jac, resid, weight, cover = np.empty((0, 5)), np.empty(0), np.empty(0), np.empty(0)
    for it in range(iterations):
        if it < RING_PASSES:  # then the ring and the fitted pixels stay put: their edges would make the steps flip
            ok, bins, pick, scene, spread = _ring(win, x_first, y_first, p[0], p[1],
                                                  p[2] + gap_sigmas * p[4], allowed, True, max_empty)
            if not ok:
                return False, p, pick, xs, ys, weight, jac, resid, fisher, bins, cover
            xs, ys, values = np.empty(pick.size), np.empty(pick.size), np.empty(pick.size)
            for k in range(pick.size):
                iy, ix = pick[k] // w, pick[k] % w
                xs[k], ys[k], values[k] = x_first + ix, y_first + iy, win[iy, ix]
            var_out = max(spread * spread, 1.0 / 12.0)
        # the marker's noise is held with the ring (a median's jumps would make the steps cycle)
        fisher, grad, jac, resid, weight, cover, var_in = _pass(xs, ys, values, scene, p, var_out, var_in,
                                                                 it < RING_PASSES, top)
        if converged:
            break
        step, ok = lu_solve(fisher, grad)
        if not ok:
            return False, p, pick, xs, ys, weight, jac, resid, fisher, bins, cover
        # converged when the full step is small (one more pass then evaluates the weights, residuals and Fisher
        # matrix at the solution); a step is halved until the radius and the blur stay in range
        converged = abs(step[0]) < CONVERGED_PX and abs(step[1]) < CONVERGED_PX
        inside = False
        for _ in range(12):
            if (p[2] + step[2] > 0.3 * r0 and 0.2 * sigma < p[4] + step[4] < sigma_max and abs(step[0]) <= r0
                    and abs(step[1]) <= r0 and p[3] + step[3] <= MAX_OVER_TOP * top):
                inside = True
                break
            step = step / 2
            converged = False
        if not inside:
            return False, p, pick, xs, ys, weight, jac, resid, fisher, bins, cover
        p = p + step
    return converged, p, pick, xs, ys, weight, jac, resid, fisher, bins, cover


def _solve(win, x_first: float, y_first: float, allowed, p, r0: float, sigma: float, sigma_max: float,
           iterations: int, top: float, gap_sigmas: float, max_empty: int = 0) -> _Solution | None:
    """Weighted Gauss-Newton of ``(x, y, r, M, blur)`` over the allowed pixels inside the ring (the window's first
    column and row at ``x_first, y_first``), the ring taken
    again about each new centre; the weights ``1 / ((1 - c) var_ring + c var_marker)``, both measured.  None when
    more than ``max_empty`` ring bins are empty, a step cannot be solved or kept in range, or the iterations do not
    converge.  Pixels at ``top`` are censored (:func:`_pass`); the ring lies ``gap_sigmas`` blur sigmas beyond the
    edge."""
    ok, p, pick, xs, ys, weight, jac, resid, fisher, bins, cover = _solve_core(
        win, float(x_first), float(y_first), np.ascontiguousarray(allowed), np.asarray(p, np.float64), float(r0),
        float(sigma), float(sigma_max), int(iterations), float(top), float(gap_sigmas), int(max_empty))
    if not ok:
        return None
    return _Solution(p, pick, xs, ys, weight, jac, resid, fisher, bins, cover)


def _joined(win, x_first, y_first, sol: "_Solution", sectors: np.ndarray, top: float, gap_sigmas: float) -> bool:
    """Whether the light in any of the ``sectors`` joins the fitted disc: along its ray the image never falls
    half-way from the disc's level to the scene's (the median of the other bins) before the ring: the disc is then
    part of a larger bright shape (a band's middle), not a spot beside another light."""
    scene = np.full(ANGLE_BINS, _median(sol.bins[~sectors]))
    p = sol.p
    radii = _edge_radii(win, p[0] - x_first, p[1] - y_first, p[2], p[4], min(p[3], top), scene, gap_sigmas)
    return bool(np.any(np.isposinf(radii[sectors])))


def fit_scene_spot(image: np.ndarray, x0: float, y0: float, r0: float, cam: Camera, *,
                   iterations: int = 15) -> SpotFit | None:
    """Fit the opaque disc in front of the scene (module docstring) around ``(x0, y0)``, start radius ``r0``.

    Saturated pixels say only that the light there is at least full scale (censored, :func:`_pass`; a marker
    overexposed to a plateau is fitted by where its image leaves it); the light of another spot that reaches inside
    the ring is left out
    (pixels off the disc brighter than the model by 5 of their SDs, grown by 2 px; the fit is then repeated
    without them and marked ``blended``).  ``SpotFit.background_adu`` is the ring's median,
    ``amplitude_adu`` the marker's level above it, ``chi2_red`` and ``chi2_own`` the weighted residuals' mean
    square (about 1 when the disc's region is as smooth as the scene around it).  None when the window
    leaves the image, the ring is incomplete, or the fit diverges.
    """
    return _fit_with_ring(image, x0, y0, r0, cam, iterations, RING_GAP_SIGMAS)


def near_ring_move(image: np.ndarray, fit: SpotFit, r0: float, cam: Camera, *, iterations: int = 15) -> np.ndarray:
    """How far [px] (dx, dy) the centre of ``fit`` (:func:`fit_scene_spot`'s) moves when the disc is fitted again from
    there (start radius ``r0``) with the ring :data:`NEAR_RING_GAP_SIGMAS` beyond its edge, where that move exceeds
    what the two fits' own errors allow (:data:`RING_MOVE_Z`, or where they cannot be compared); zeros where it does
    not, or where that fit fails.

    The two rings are two views of the scene under the disc's edge; where the scene changes between the edge and
    the far ring (the tip in front of a patch a little larger than itself) the far ring's view is wrong and the
    centre moves by about its error, which neither fit's covariance holds."""
    near = _fit_with_ring(image, fit.x_px, fit.y_px, r0, cam, iterations, NEAR_RING_GAP_SIGMAS)
    if near is None:
        return np.zeros(2)
    move = np.array([near.x_px - fit.x_px, near.y_px - fit.y_px])
    try:
        z2 = float(move @ np.linalg.solve(fit.cov_xy + near.cov_xy, move))
    except np.linalg.LinAlgError:  # errors that cannot be compared: the move is kept
        return move
    return np.zeros(2) if z2 <= RING_MOVE_Z**2 else move


def _fit_with_ring(image: np.ndarray, x0: float, y0: float, r0: float, cam: Camera, iterations: int,
                   gap_sigmas: float) -> SpotFit | None:
    """:func:`fit_scene_spot` with the ring ``gap_sigmas`` blur sigmas beyond the disc's edge."""
    sigma = cam.psf_sigma_px
    sigma_max = MAX_BLUR * sigma + 1.0
    half = int(math.ceil(1.3 * r0 + gap_sigmas * sigma_max + RING_WIDTH_PX + 2))
    # near the image's edge the window is cut there, the disc and its blur inside the image
    window = window_levels(image, x0, y0, half, r0 + EDGE_MARGIN_SIGMAS * sigma + 1.0)
    if window is None:
        return None
    win, x_first, y_first, _, background, amplitude = window
    x_first, y_first = float(x_first), float(y_first)
    max_empty = MAX_OFF_IMAGE_BINS if win.shape != (2 * half + 1, 2 * half + 1) else 0
    saturated = bool(win.max() >= cam.max_adu)
    top = float(cam.max_adu) if saturated else math.inf
    allowed = np.ones(win.shape, np.bool_)
    ok, bins, *_ = _ring(win, x_first, y_first, x0, y0, r0 + gap_sigmas * sigma_max, allowed, False, max_empty)
    dark = _foreign_bins(bins, background + amplitude, -1.0) if ok else np.zeros(ANGLE_BINS, np.bool_)
    if dark.any():  # a dark object's edge within the widest ring: its sectors are left out
        allowed = _without_sectors(allowed, x_first, y_first, x0, y0, dark)
    start = np.array([x0, y0, r0, background + amplitude, sigma])
    sol = _solve(win, x_first, y_first, allowed, start, r0, sigma, sigma_max, iterations, top, gap_sigmas, max_empty)
    bright = _foreign_bins(bins, background + amplitude) if ok and sol is None else np.zeros(ANGLE_BINS, np.bool_)
    if bright.any():  # another light within the widest ring (a hand beside the tip) pulled the fit away: left out
        allowed = _without_sectors(allowed, x_first, y_first, x0, y0, bright)
        sol = _solve(win, x_first, y_first, allowed, start, r0, sigma, sigma_max, iterations, top, gap_sigmas,
                     max_empty)
        if sol is not None and _joined(win, x_first, y_first, sol, bright, top, gap_sigmas):
            return None
    if sol is None:
        return None
    kept = _fitted_bins(sol.xs, sol.ys, sol.p[0], sol.p[1])  # all but a dark object's sectors ...
    if max_empty:  # ... and the bins whose ring lies beyond the image
        kept &= on_image_bins(win.shape, x_first, y_first, sol.p[0], sol.p[1], sol.p[2] + gap_sigmas * sol.p[4])
    foreign = _foreign_bins(sol.bins, min(sol.p[3], top))
    if foreign.any():  # another spot's light on the ring: its sectors (and one bin either side) are left out
        allowed = _without_sectors(allowed, x_first, y_first, sol.p[0], sol.p[1], foreign)
        sol = _solve(win, x_first, y_first, allowed, sol.p, r0, sigma, sigma_max, iterations, top, gap_sigmas,
                     max_empty)
        if sol is None:
            return None
    p, n_used = sol.p, sol.pick.size
    if abs(p[0] - x0) > half or abs(p[1] - y0) > half or n_used <= 8:
        return None
    background = _median(sol.bins)
    contrast = min(p[3], top) - background  # a saturated marker's: as far as it is seen
    if contrast <= 0:
        return None
    try:
        ok, cov, chi2 = _centre_errors(win, x_first, y_first, p, sol.pick, sol.xs, sol.ys, sol.weight, sol.jac,
                                       sol.resid, sol.fisher, sol.bins, sol.coverage, kept, top,
                                       gap_sigmas)
    except np.linalg.LinAlgError:
        return None
    if not ok:
        return None
    return SpotFit(float(p[0]), float(p[1]), float(p[2]), contrast, background, cov, chi2,
                   saturated, True, bool(foreign.any()), chi2_own=chi2)


def fit_round_spot(image: np.ndarray, x0: float, y0: float, r0: float, cam: Camera, *,
                   neighbour: str = "joint") -> SpotFit | None:
    """A round spot's fit as the footage asks: the sensor model's (:func:`gyrorig.tracking.spot.fit_spot`,
    flat background) for a camera whose pixels it describes, else the disc in front of the scene
    (:func:`fit_scene_spot`)."""
    if cam.sensor_known:
        return fit_spot(image, x0, y0, r0, cam, neighbour=neighbour)
    return fit_scene_spot(image, x0, y0, r0, cam)


def warm_up() -> None:
    """Load every compiled spot-fit kernel now (numba; compiled once and cached on disk, then loaded in ~0.05 s
    each per process), not in the first frames: a disc of radius 5 px on a flat scene, fitted."""
    spot.warm_up()
    ellipse.warm_up()
    yy, xx = np.mgrid[0:41, 0:41].astype(np.float64)
    win = 20.0 + 100.0 * (np.hypot(xx - 20.2, yy - 19.9) < 5.0)
    allowed = np.ones(win.shape, bool)
    ok, p, pick, xs, ys, weight, jac, resid, fisher, bins, cover = _solve_core(
        win, 0.0, 0.0, allowed, np.array([20.0, 20.0, 5.0, 120.0, 1.0]), 5.0, 1.0, 3.5, 15, math.inf, RING_GAP_SIGMAS, 0)
    _ring(win, 0.0, 0.0, 20.0, 20.0, 8.0, allowed, False, 0)
    fill_empty_bins(bins, np.r_[0.0, np.ones(ANGLE_BINS - 1)])
    _foreign_bins(bins, float(p[3]))
    _median(bins)
    _without_sectors(allowed, 0.0, 0.0, float(p[0]), float(p[1]), np.zeros(ANGLE_BINS, np.bool_))
    kept = _fitted_bins(xs, ys, float(p[0]), float(p[1]))
    _centre_errors(win, 0.0, 0.0, p, pick, xs, ys, weight, jac, resid, fisher, bins, cover, kept, math.inf,
                   RING_GAP_SIGMAS)
