"""The marker spot in a recording: an opaque disc in front of a real scene.

On a recording (no sensor model: gamma, a lossy codec, a phone's processing) the background behind the
marker is whatever the room shows, and it is not flat: a texture's edge, a shadow or a highlight next to
the marker pulls a flat-background fit towards it by far more than the noise would.  Here the disc
covers the scene: ``mu = B (1 - c) + M c``, ``c`` the disc's coverage blurred by the PSF
(``erfc((rho - r) / (sqrt(2) sigma)) / 2``), ``M`` the marker's level and ``B`` the scene **just outside
the disc at the same angle**: the mean of the ring ``r + 3 sigma <= rho < r + 3 sigma + 2`` px in
:data:`ANGLE_BINS` bins around the centre, interpolated in angle.  Only the pixels inside the ring are
fitted (``x, y, r, M`` and the blur; weighted least squares, the ring taken again about the first few centres); what the
scene does between the ring and the disc's edge is left in the residuals, and the centre's covariance
comes from them (:func:`sandwich_covariance`) and from what the unseen scene under the edge may differ from the
ring (:func:`_scene_covariance`: the ring's own texture at that distance), so it grows where the scene behind
the edge is busy.

A bin of the ring much brighter than the rest (light of another marker touching the ring) marks the fit
``blended``; the model still holds there to first order (that light is outside the disc), and the
residuals carry what it does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import erfc

from .camera_file import TrackingCamera
from .spot import SpotFit, fit_spot, spot_window

__all__ = ["fit_scene_spot", "fit_round_spot", "sandwich_covariance", "ANGLE_BINS", "RING_WIDTH_PX"]

#: angular bins of the ring that gives the scene behind the disc's edge
ANGLE_BINS = 32
#: the ring's radial width [px]
RING_WIDTH_PX = 2.0
#: the ring starts this many PSF sigmas beyond the disc's edge (where the disc's light has fallen to 1e-3)
RING_GAP_SIGMAS = 3.0
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
#: the edge's departures from a circle are read from its harmonics up to this order (:func:`_edge_roughness`)
EDGE_HARMONICS = 5
#: ... where at least this fraction of the bins has an edge point
MIN_ARC_FRACTION = 0.5


#: the spatial kernel of :func:`sandwich_covariance`: Bartlett weights over a 5 x 5 neighbourhood (a positive-definite
#: kernel, so the estimate is positive semi-definite), reaching residuals correlated over a PSF, a texture's grain or
#: a codec's block edge
_BARTLETT = np.outer([1 / 3, 2 / 3, 1.0, 2 / 3, 1 / 3], [1 / 3, 2 / 3, 1.0, 2 / 3, 1 / 3])


def sandwich_covariance(jac: np.ndarray, weight: np.ndarray, resid: np.ndarray, fisher_inv: np.ndarray
                        ) -> np.ndarray:
    """The parameters' covariance from the residuals themselves: ``F^-1 M F^-1`` with
    ``M = sum_ij k(i - j) u_i u_j^T``, ``u_i = J_i w_i r_i`` over the fitted pixels (``weight`` 0 elsewhere)
    and ``k`` a Bartlett kernel over neighbours up to 2 px apart.

    Where the noise model is right and the pixels independent, ``E M = F`` and this is ``F^-1``; where the
    residuals hold what the model lacks (the scene behind the spot's edge, a lossy codec's ringing,
    spatially correlated noise) it grows by what those do to the centre: a heteroscedasticity- and
    autocorrelation-consistent estimate (White; Newey-West, in two dimensions).  ``jac`` (h, w, n),
    ``weight, resid`` (h, w)."""
    u = (jac * (weight * resid)[:, :, None]).astype(np.float64)
    n = u.shape[2]
    smooth = np.stack([cv2.filter2D(u[:, :, a], -1, _BARTLETT, borderType=cv2.BORDER_CONSTANT) for a in range(n)],
                      axis=2)
    meat = u.reshape(-1, n).T @ smooth.reshape(-1, n)
    meat = 0.5 * (meat + meat.T)
    return fisher_inv @ meat @ fisher_inv


def _ring(win, th, rho, r_out: float):
    """The ring's bin means, the scene ``B`` at every pixel (interpolated in angle) and the ring pixels'
    robust SD about their bins' means; ``(None, None, None)`` when a bin is empty."""
    ring = (rho >= r_out) & (rho < r_out + RING_WIDTH_PX)
    b = ((th[ring] + math.pi) / (2 * math.pi) * ANGLE_BINS).astype(int) % ANGLE_BINS
    counts = np.bincount(b, None, ANGLE_BINS)
    if np.any(counts == 0):
        return None, None, None
    values = win[ring]
    bins = np.bincount(b, values, ANGLE_BINS) / counts
    u = (th + math.pi) / (2 * math.pi) * ANGLE_BINS - 0.5
    i0 = np.floor(u).astype(int)
    f = u - i0
    spread = 1.4826 * float(np.median(np.abs(values - bins[b])))
    return bins, (1.0 - f) * bins[i0 % ANGLE_BINS] + f * bins[(i0 + 1) % ANGLE_BINS], spread


def _scene_covariance(xx, yy, sol: "_Solution", fisher_inv: np.ndarray) -> np.ndarray:
    """What the scene behind the disc's edge, unseen, may do to the parameters: the ring stands in for it, but
    the edge lies ``3 sigma + 1`` px further in.  Taking the scene's texture as isotropic, it changes over that
    distance as much as it does along the ring over the same arc: the ring's structure function at that lag
    (mean square difference of bins that far apart) is the variance of each bin's error, independent from bin to
    bin, and it reaches the fit through the pixels it lies behind (``(1 - c)`` of each, by their Jacobian rows)."""
    p = sol.p
    gap = RING_GAP_SIGMAS * p[4]
    arc = 2 * math.pi * (p[2] + gap + RING_WIDTH_PX / 2) / ANGLE_BINS
    lag = max(1, int(round((gap + 1.0) / arc)))
    var_bin = float(np.mean((np.roll(sol.bins, lag) - sol.bins) ** 2))
    th = np.arctan2(yy - p[1], xx - p[0])
    sector = ((th + math.pi) / (2 * math.pi) * ANGLE_BINS).astype(int) % ANGLE_BINS
    u = (sol.jac * (sol.weight * (1.0 - sol.coverage))[:, :, None]).reshape(-1, sol.jac.shape[2])
    v = np.column_stack([np.bincount(sector.ravel(), u[:, k], ANGLE_BINS)  # each bin's effect per unit error
                         for k in range(u.shape[1])])
    return fisher_inv @ (var_bin * v.T @ v) @ fisher_inv


@dataclass
class _Solution:
    p: np.ndarray
    converged: bool
    use: np.ndarray
    weight: np.ndarray
    jac: np.ndarray
    resid: np.ndarray
    fisher: np.ndarray
    bins: np.ndarray
    coverage: np.ndarray


def _foreign_bins(bins: np.ndarray, marker_level: float) -> np.ndarray:
    """Ring bins holding another spot's light: above the ring's median by :data:`FOREIGN_Z` robust SDs of the
    bins and by :data:`FOREIGN_CONTRAST` of the marker's contrast."""
    med = float(np.median(bins))
    sd = max(1.4826 * float(np.median(np.abs(bins - med))), math.sqrt(1.0 / 12.0))
    return bins > med + max(FOREIGN_Z * sd, FOREIGN_CONTRAST * (marker_level - med))


_BIN_ANGLES = -math.pi + (np.arange(ANGLE_BINS) + 0.5) * (2 * math.pi / ANGLE_BINS)


def _edge_radii(win: np.ndarray, cx: float, cy: float, sol: "_Solution") -> np.ndarray:
    """Where the edge lies in each angular bin: along the ray from the window's point ``(cx, cy)`` through the
    bin's centre angle, the first radius at which the image falls below half-way between the marker's level and
    that bin's ring (bilinear samples 0.25 px apart, from ``r - 4 sigma`` out to the ring's outer edge; linear
    between samples).  ``+inf`` where it never falls that far (light beyond the disc), ``-inf`` where it starts
    below (something in front of the disc)."""
    r, blur = sol.p[2], sol.p[4]
    radii = np.arange(max(r - 4.0 * blur, 0.3 * r), r + RING_GAP_SIGMAS * blur + RING_WIDTH_PX, 0.25)
    mx = (cx + np.cos(_BIN_ANGLES)[:, None] * radii[None, :]).astype(np.float32)
    my = (cy + np.sin(_BIN_ANGLES)[:, None] * radii[None, :]).astype(np.float32)
    prof = cv2.remap(win.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    level = 0.5 * (sol.p[3] + sol.bins)[:, None]
    below = prof < level
    first = np.argmax(below, axis=1)
    out = np.full(ANGLE_BINS, np.inf)
    out[below[:, 0]] = -np.inf
    inside = below.any(axis=1) & ~below[:, 0]
    k = np.flatnonzero(inside)
    j = first[k]
    v0, v1 = prof[k, j - 1], prof[k, j]
    frac = (v0 - level[k, 0]) / np.maximum(v0 - v1, 1e-12)
    out[k] = radii[j - 1] + 0.25 * frac
    return out


def _edge_roughness(win: np.ndarray, xx: np.ndarray, yy: np.ndarray, sol: "_Solution") -> float:
    """The variance [px^2] per axis of the centre that the edge's own departures from a circle imply: the edge
    points (:func:`_edge_radii`) as a Fourier series in angle, whose first harmonic is a shift of the centre and is
    therefore absorbed by the fit; its unseen power is taken as the mean power per coefficient of harmonics
    2 to :data:`EDGE_HARMONICS`.  Noise independent from bin to bin gives ``2 var / bins`` (what the pixels' own
    covariance already holds); a bump of another spot's light merged with the edge, a bulge of texture under it
    or something in front of the disc spread over neighbouring harmonics and give what they shift the centre by.
    NaN when fewer than half the bins have an edge point."""
    x0, y0 = float(xx[0, 0]), float(yy[0, 0])
    radii = _edge_radii(win, sol.p[0] - x0, sol.p[1] - y0, sol)
    good = np.isfinite(radii)
    if np.count_nonzero(good) < MIN_ARC_FRACTION * ANGLE_BINS:
        return math.nan
    ang = _BIN_ANGLES[good]
    basis = np.column_stack([np.ones(len(ang))] + [f(n * ang) for n in range(1, EDGE_HARMONICS + 1)
                                                    for f in (np.cos, np.sin)])
    coef = np.linalg.lstsq(basis, radii[good], rcond=None)[0]
    return float(np.mean(coef[3:] ** 2))


def _solve(win, xx, yy, allowed, p, r0: float, sigma: float, sigma_max: float, iterations: int) -> _Solution | None:
    """Weighted Gauss-Newton of ``(x, y, r, M, blur)`` over the allowed pixels inside the ring, the ring taken
    again about each new centre; the weights ``1 / ((1 - c) var_ring + c var_marker)``, both measured.  The
    passes work on the fitted pixels alone; the solution's arrays are the window's (0 off those pixels)."""
    converged = False
    var_in = None  # the residuals' variance on the marker (unknown before the first pass)
    for it in range(iterations):
        if it < RING_PASSES:  # then the ring and the fitted pixels stay put: their edges would make the steps flip
            dx, dy = xx - p[0], yy - p[1]
            rho = np.hypot(dx, dy) + 1e-12
            gap = RING_GAP_SIGMAS * p[4]
            bins, scene_all, spread = _ring(win, np.arctan2(dy, dx), rho, p[2] + gap)
            if bins is None:
                return None
            use = (rho < p[2] + gap) & allowed
            pick = np.flatnonzero(use)
            xs, ys, values, scene = xx.ravel()[pick], yy.ravel()[pick], win.ravel()[pick], scene_all.ravel()[pick]
            var_out = max(spread * spread, 1.0 / 12.0)
        dx, dy = xs - p[0], ys - p[1]
        rho = np.hypot(dx, dy) + 1e-12
        arg = (rho - p[2]) / (math.sqrt(2.0) * p[4])
        c = 0.5 * erfc(arg)
        gauss = np.exp(-arg * arg) / (math.sqrt(2.0 * math.pi) * p[4])
        level = p[3] - scene
        edge = -level * gauss  # d mu / d rho
        jac = np.column_stack([edge * (-dx / rho), edge * (-dy / rho), -edge, c, level * gauss * (rho - p[2]) / p[4]])
        resid = values - (scene * (1.0 - c) + p[3] * c)
        inner = c > 0.99
        if it < RING_PASSES and int(inner.sum()) >= MIN_INNER_PIXELS:  # held with the ring (a median's jumps
            var_in = max(float(np.median(resid[inner] ** 2)) / 0.4549, 1.0 / 12.0)  # would make the steps cycle)
        weight = 1.0 / (var_out * (1.0 - c) + (var_in if var_in is not None else var_out) * c)
        wj = jac * weight[:, None]
        fisher = wj.T @ jac
        if converged:
            break
        try:
            step = np.linalg.solve(fisher, wj.T @ resid)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(step)):
            return None
        # converged when the full step is small (one more pass then evaluates the weights, residuals and Fisher
        # matrix at the solution); a step is halved until the radius and the blur stay in range
        converged = abs(step[0]) < CONVERGED_PX and abs(step[1]) < CONVERGED_PX
        for _ in range(12):
            if (p[2] + step[2] > 0.3 * r0 and 0.2 * sigma < p[4] + step[4] < sigma_max and abs(step[0]) <= r0
                    and abs(step[1]) <= r0):
                break
            step = step / 2
            converged = False
        else:
            return None
        p = p + step
    if not converged:
        return None

    def window(v: np.ndarray) -> np.ndarray:
        out = np.zeros(win.shape + v.shape[1:])
        out.reshape((-1,) + v.shape[1:])[pick] = v
        return out

    return _Solution(p, converged, use, window(weight), window(jac), window(resid), fisher, bins, window(c))


def fit_scene_spot(image: np.ndarray, x0: float, y0: float, r0: float, cam: TrackingCamera, *,
                   iterations: int = 15) -> SpotFit | None:
    """Fit the opaque disc in front of the scene (module docstring) around ``(x0, y0)``, start radius ``r0``.

    Saturated pixels are left out, and so is the light of another spot that reaches inside the ring
    (pixels off the disc brighter than the model by 5 of their SDs, grown by 2 px; the fit is then repeated
    without them and marked ``blended``).  ``SpotFit.background_adu`` is the ring's median,
    ``amplitude_adu`` the marker's level above it, ``chi2_red`` and ``chi2_own`` the weighted residuals' mean
    square (about 1 when the disc's region is as smooth as the scene around it).  None when the window
    leaves the image, the ring is incomplete, or the fit diverges.
    """
    sigma = cam.psf_sigma_px
    sigma_max = MAX_BLUR * sigma + 1.0
    half = int(math.ceil(1.3 * r0 + RING_GAP_SIGMAS * sigma_max + RING_WIDTH_PX + 2))
    window = spot_window(image, x0, y0, half, cam)
    if window is None:
        return None
    win, xx, yy, saturated, _, background, amplitude = window
    allowed = ~saturated
    start = np.array([x0, y0, r0, background + amplitude, sigma])
    sol = _solve(win, xx, yy, allowed, start, r0, sigma, sigma_max, iterations)
    if sol is None:
        return None
    foreign = _foreign_bins(sol.bins, sol.p[3])
    if foreign.any():  # another spot's light on the ring: its sectors (and one bin either side) are left out
        near = foreign | np.roll(foreign, 1) | np.roll(foreign, -1)
        th = np.arctan2(yy - sol.p[1], xx - sol.p[0])
        sector = ((th + math.pi) / (2 * math.pi) * ANGLE_BINS).astype(int) % ANGLE_BINS
        sol = _solve(win, xx, yy, allowed & ~near[sector], sol.p, r0, sigma, sigma_max, iterations)
        if sol is None:
            return None
    p, use = sol.p, sol.use
    if abs(p[0] - x0) > half or abs(p[1] - y0) > half or int(use.sum()) <= 8:
        return None
    background = float(np.median(sol.bins))
    contrast = p[3] - background
    if contrast <= 0:
        return None
    blended = bool(foreign.any())
    try:
        finv = np.linalg.inv(sol.fisher)
    except np.linalg.LinAlgError:
        return None
    rough = _edge_roughness(win, xx, yy, sol)
    if not math.isfinite(rough):
        return None
    cov = (sandwich_covariance(sol.jac, sol.weight, sol.resid, finv)
           + _scene_covariance(xx, yy, sol, finv))[:2, :2] + rough * np.eye(2)
    chi2 = float(np.sum(sol.resid[use] ** 2 * sol.weight[use])) / max(int(use.sum()) - 5, 1)
    return SpotFit(float(p[0]), float(p[1]), float(p[2]), contrast, background, cov, chi2,
                   bool(saturated.any()), sol.converged, blended, chi2_own=chi2)


def fit_round_spot(image: np.ndarray, x0: float, y0: float, r0: float, cam: TrackingCamera, *,
                   neighbour: str = "joint") -> SpotFit | None:
    """A round spot's fit as the footage asks: the sensor model's (:func:`gyrorig.tracking.spot.fit_spot`,
    flat background) for a camera whose pixels it describes, else the disc in front of the scene
    (:func:`fit_scene_spot`)."""
    if cam.sensor_known:
        return fit_spot(image, x0, y0, r0, cam, neighbour=neighbour)
    return fit_scene_spot(image, x0, y0, r0, cam)
