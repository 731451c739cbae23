"""Checkerboard images through the camera, for ``gyrorig calibrate`` (each pixel integrates its area)."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from .. import _io
from ..camera import Camera
from ..geometry import board_lab_rotation

__all__ = ["render_calibration_images", "render_pose_board", "MAX_TRIES_PER_VIEW"]

#: random board poses tried per view before the field of view is declared too narrow for the board
MAX_TRIES_PER_VIEW = 500


class _BoardView:
    """Rays through every pixel of a camera (3 x 3 sub-samples each) and the board drawn along them."""

    def __init__(self, cam: Camera):
        self.cam = cam
        h, w = cam.height_px, cam.width_px
        grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), axis=-1)
        self.norm = cv2.undistortPoints(grid.reshape(-1, 1, 2), cam.camera_matrix, cam.dist_coeffs).reshape(-1, 2)
        self.rays = np.column_stack([self.norm, np.ones(len(self.norm))])
        # local Jacobian of the normalised coordinates with respect to the pixel position
        grid_n = self.norm.reshape(h, w, 2)
        jac_x = np.zeros((h, w, 3))
        jac_y = np.zeros((h, w, 3))
        jac_x[:, :, :2] = np.gradient(grid_n, axis=1)
        jac_y[:, :, :2] = np.gradient(grid_n, axis=0)
        self.jac_x, self.jac_y = jac_x.reshape(-1, 3), jac_y.reshape(-1, 3)

    def image(self, rmat: np.ndarray, origin: np.ndarray, cols: int, rows: int, square_m: float,
              rng: np.random.Generator) -> np.ndarray:
        """The sensor's image of a checker of ``(cols + 1) x (rows + 1)`` squares (square (0, 0) dark) whose
        outer corner is at ``origin`` and whose axes are ``rmat``'s columns (camera frame), with a white
        margin of one square; each pixel integrates its area, then shot and read noise, quantised."""
        cam, s = self.cam, self.cam.sensor
        h, w = cam.height_px, cam.width_px
        size = np.array([(cols + 1) * square_m, (rows + 1) * square_m])
        white_e = 0.6 * s.full_well_e
        dark_e = 0.08 * s.full_well_e
        nrm = rmat[:, 2]
        e = np.zeros(h * w)
        for dy in (-1 / 3, 0.0, 1 / 3):
            for dx in (-1 / 3, 0.0, 1 / 3):
                r = self.rays + dx * self.jac_x + dy * self.jac_y
                with np.errstate(divide="ignore", invalid="ignore"):
                    sdist = (nrm @ origin) / (r @ nrm)
                hit = r * sdist[:, None] - origin
                bx, by = hit @ rmat[:, 0], hit @ rmat[:, 1]
                on_board = (sdist > 0) & (bx >= -square_m) & (bx <= size[0] + square_m) & (by >= -square_m) & \
                    (by <= size[1] + square_m)
                in_checker = (bx >= 0) & (bx < size[0]) & (by >= 0) & (by < size[1])
                dark = in_checker & ((np.floor(bx / square_m) + np.floor(by / square_m)) % 2 == 0)
                e += np.where(on_board, np.where(dark, dark_e, white_e), s.background_e_per_s * cam.exposure_s)
        e /= 9.0
        img = cv2.GaussianBlur(e.reshape(h, w).astype(np.float32), (0, 0), cam.psf_sigma_px)
        noisy = rng.poisson(np.maximum(img, 0)).astype(np.float64) + rng.normal(0, s.read_noise_e, img.shape)
        adu = np.clip(np.floor(np.clip(noisy, 0, s.full_well_e) / s.gain_e_per_adu + 0.5), 0, s.max_adu)
        return adu.astype(np.uint8 if s.bit_depth == 8 else np.uint16)


def render_pose_board(cam: Camera, out_dir: str | Path, *, origin_m, yaw_rad: float = 0.0, seed: int = 0,
                      cols: int = 9, rows: int = 6, square_m: float = 0.02) -> dict:
    """One image of a checkerboard lying face up at a known place, for ``gyrorig pose --board-image``.

    The board's first inner corner (the corner OpenCV's object points start from, beside the dark
    corner square) is at ``origin_m`` in the lab (pivot frame), its x axis at azimuth ``yaw_rad``
    (:func:`board_lab_rotation`).  Writes ``board.png`` and ``placement.json`` (what a user would
    measure and state: the board, the origin and the yaw) into ``out_dir``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    a = board_lab_rotation(yaw_rad)
    origin_lab = np.asarray(origin_m, float) - a @ np.array([square_m, square_m, 0.0])  # the checker's outer corner
    rmat = cam.rotation @ a
    origin = cam.rotation @ origin_lab + cam.tvec
    corners = np.array([[(i + 1) * square_m, (j + 1) * square_m, 0.0] for j in range(rows) for i in range(cols)])
    px = cv2.projectPoints(corners @ rmat.T + origin, np.zeros(3), np.zeros(3), cam.camera_matrix,
                           cam.dist_coeffs)[0].reshape(-1, 2)
    if not ((px > 10).all() and (px[:, 0] < cam.width_px - 10).all() and (px[:, 1] < cam.height_px - 10).all()):
        raise ValueError(f"the pose board at {list(origin_m)} m is not wholly in the camera's view")
    adu = _BoardView(cam).image(rmat, origin, cols, rows, square_m, np.random.default_rng([seed, 104729]))
    ok, png = cv2.imencode(".png", adu)
    with _io.atomic_path(out / "board.png") as tmp:
        tmp.write_bytes(png.tobytes())
    placement = {"board": f"{cols}x{rows}", "square_mm": square_m * 1e3,
                 "origin_mm": [float(v) * 1e3 for v in origin_m], "yaw_deg": math.degrees(yaw_rad)}
    _io.write_json(placement, out / "placement.json")
    return {"dir": str(out), **placement}


def render_calibration_images(cam: Camera, out_dir: str | Path, *, seed: int = 0, n_views: int = 12,
                              cols: int = 9, rows: int = 6, square_m: float = 0.02, spread: float | None = None) -> dict:
    """Checkerboard images through the same camera at varied poses, for ``gyrorig calibrate``.

    ``cols x rows`` inner corners (OpenCV's pattern size), squares of ``square_m``; boards
    near the pivot, tilted up to 35 deg, their centres within the central field (``spread``: within
    that fraction of the whole field instead, to reach the corners where a wide lens's k3 shows).
    Writes ``view_NN.png`` and ``board.json`` (the board and the true pose of each view, for tests).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([seed, 7919])
    h, w = cam.height_px, cam.width_px
    view = _BoardView(cam)
    norm = view.norm
    dist_to_pivot = float(np.linalg.norm(cam.tvec))
    poses = []
    tries = 0
    while len(poses) < n_views:
        tries += 1
        if tries > MAX_TRIES_PER_VIEW * n_views:
            raise ValueError(f"calibration views: a {cols + 1} x {rows + 1} board of {square_m * 1e3:g} mm squares "
                             f"fits in the {w} x {h} image at the pivot's distance in {len(poses)} of {tries - 1} "
                             "random poses: the field of view is too narrow for it (render with "
                             "--calibration-views 0, and calibrate this lens with a smaller board)")
        angles = np.radians(rng.uniform(-35, 35, 2))
        rot_board = cv2.Rodrigues(np.array([angles[0], angles[1], rng.uniform(-np.pi, np.pi)]))[0]
        # board centre: ahead of the camera near the pivot's depth, within the central field
        if spread is None:
            centre = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), 1.0]) * \
                dist_to_pivot * rng.uniform(0.8, 1.05)
        else:  # anywhere in that fraction of the field (normalised image coordinates of the corners)
            half = np.abs(np.asarray(norm).reshape(h, w, 2)[[0, -1]][:, [0, -1]]).reshape(-1, 2).min(axis=0)
            centre = np.array([rng.uniform(-1, 1) * spread * half[0], rng.uniform(-1, 1) * spread * half[1], 1.0]) \
                * dist_to_pivot * rng.uniform(0.8, 1.05)
        rmat = rot_board  # board -> camera
        size = np.array([(cols + 1) * square_m, (rows + 1) * square_m])
        origin = centre - rmat @ np.array([size[0] / 2, size[1] / 2, 0.0])
        corners = np.array([[(i + 1) * square_m, (j + 1) * square_m, 0.0] for j in range(rows) for i in range(cols)])
        pts = (rmat @ corners.T).T + origin
        px = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.camera_matrix, cam.dist_coeffs)[0].reshape(-1, 2)
        margin = 20
        if not ((px[:, 0] > margin).all() and (px[:, 0] < w - margin).all() and (px[:, 1] > margin).all()
                and (px[:, 1] < h - margin).all()):
            continue
        adu = view.image(rmat, origin, cols, rows, square_m, rng)
        ok, png = cv2.imencode(".png", adu)
        with _io.atomic_path(out / f"view_{len(poses):02d}.png") as tmp:
            tmp.write_bytes(png.tobytes())
        # pose of the board in the camera frame with OpenCV's object points (corner grid from (0,0))
        obj_origin = origin + rmat @ np.array([square_m, square_m, 0.0])
        poses.append({"rvec": cv2.Rodrigues(rmat)[0].ravel().tolist(), "tvec": obj_origin.tolist()})
    board = {"cols": cols, "rows": rows, "square_m": square_m, "views": poses,
             "object_points": "corner (i, j) at (i * square_m, j * square_m, 0), i < cols fastest"}
    _io.write_json(board, out / "board.json")
    return {"dir": str(out), "views": n_views}
