"""Pixel tracks made by other tools, turned into gyrorig's angle table through the camera model.

Two formats:

- **OSP Tracker** ``.trk`` (the XML a Tracker project is saved as): one point-mass track's marks, each the image
  position [px, image axes: x right, y down] of the tip in one video frame, the frame being the mark's index
  (``framedata`` ``[n]``).  Frame times: the video's ``start_times`` [ms] where the file has them, else the clip
  control's ``delta_t`` [ms per step] over the clip's ``stepsize``, else camera.json's fps.  The track is the one
  named (``track_name``), or the file's only point mass.
- **CSV** with columns ``frame, t_s, x_px, y_px`` and optionally ``sigma_px`` (the position's standard error per
  axis) or ``sigma_x_px, sigma_y_px``.

Each position becomes the tip's direction where its ray meets the tip's sphere about the pivot (the same geometry
as the tracker's, :mod:`gyrorig.tracking.rays`), with its covariance.  Positions without stated errors get one
error for all, from the track's own scatter about its smooth path (:func:`gyrorig.tracking.scatter.check_sigmas`:
a seven-frame polynomial predicts each frame far below any click's or centroid's error); stated errors are checked
the same way and scaled up when the scatter shows them too small.  Frames off the path by more than 5 errors are
``outlier`` rows without angles.  The camera's modes (its calibration's and pose's uncertainty) are added as the
tracker adds them.  Times are the frames' start times plus half camera.json's exposure (gyrorig's mid-exposure).
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd

from .. import _io
from ..protocols import Protocol
from ..camera import Camera
from .errors import BadInputError
from .rays import angle_covariances, limb_flags
from .rows import with_flag
from .harmonic import harmonic_check
from .scatter import NOISE_ACF, check_sigmas
from .pose import add_camera_modes
from .tracker import SIGMA_CHECK_Z, tip_marker

logger = logging.getLogger(__name__)

__all__ = ["read_pixel_track", "angles_from_pixel_track", "import_pixel_track", "is_pixel_track", "POINT_MASS"]

#: the class of a Tracker point-mass track
POINT_MASS = "org.opensourcephysics.cabrillo.tracker.PointMass"


def _property(element: ET.Element, name: str) -> ET.Element | None:
    for p in element.findall("property"):
        if p.get("name") == name:
            return p
    return None


def _object(element: ET.Element | None) -> ET.Element | None:
    return None if element is None else element.find("object")


def _number(element: ET.Element | None, name: str) -> float:
    p = None if element is None else _property(element, name)
    if p is None or p.text is None:
        return math.nan
    try:
        return float(p.text)
    except ValueError:
        return math.nan


def _trk_times(root: ET.Element, frames: np.ndarray, fps: float, path: Path) -> np.ndarray:
    clip = _object(_property(root, "videoclip"))
    video = _object(_property(clip, "video")) if clip is not None else None
    starts = _property(video, "start_times") if video is not None else None
    if starts is not None:
        text = "".join(starts.itertext()).strip().strip("{}")
        try:
            t_ms = np.array([float(v) for v in text.split(",") if v.strip()])
        except ValueError:
            t_ms = np.zeros(0)
        if len(t_ms) > frames.max():
            return t_ms[frames] / 1000.0
    control = _object(_property(root, "clipcontrol"))
    dt_ms, step = _number(control, "delta_t"), _number(clip, "stepsize")
    if math.isfinite(dt_ms) and dt_ms > 0:
        return frames * (dt_ms / 1000.0) / (step if math.isfinite(step) and step >= 1 else 1.0)
    if math.isfinite(fps) and fps > 0:
        return frames / fps
    raise BadInputError(f"{path}: no frame times (no start_times or clip delta_t) and camera.json gives no fps")


def _read_trk(path: Path, track_name: str | None, fps: float) -> pd.DataFrame:
    _io.check_settings_size(path, "Tracker file")
    text = path.read_bytes()
    if b"<!DOCTYPE" in text.upper() or b"<!ENTITY" in text.upper():
        raise BadInputError(f"{path}: an XML document type or entity declaration; a Tracker file has none")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise BadInputError(f"{path}: not a Tracker file (XML: {exc})") from None
    tracks = _property(root, "tracks")
    masses = [o for o in (tracks.iter("object") if tracks is not None else ()) if o.get("class") == POINT_MASS]
    names = [(_property(m, "name").text or "") if _property(m, "name") is not None else "" for m in masses]
    if not masses:
        raise BadInputError(f"{path}: no point-mass track (a Tracker project with the tip tracked as a point mass)")
    if track_name is None:
        if len(masses) > 1:
            raise BadInputError(f"{path}: {len(masses)} point-mass tracks ({', '.join(names)}): name the tip's with "
                                "--track-name")
        mass = masses[0]
    elif track_name in names:
        mass = masses[names.index(track_name)]
    else:
        raise BadInputError(f"{path}: no point-mass track named {track_name!r}; the file has {', '.join(names)}")
    rows = []
    data = _property(mass, "framedata")
    for p in (data.findall("property") if data is not None else ()):
        index = (p.get("name") or "").strip("[]")
        point = p.find("object")
        if not index.isdigit() or point is None:
            continue
        x, y = _number(point, "x"), _number(point, "y")
        if math.isfinite(x) and math.isfinite(y):
            rows.append((int(index), x, y))
    if not rows:
        raise BadInputError(f"{path}: the track has no marks")
    frames = np.array([r[0] for r in rows])
    table = pd.DataFrame({"frame": frames, "t_s": _trk_times(root, frames, fps, path),
                          "x_px": [r[1] for r in rows], "y_px": [r[2] for r in rows], "sigma_px": math.nan})
    return table.sort_values("frame").reset_index(drop=True)


def _read_csv(path: Path) -> pd.DataFrame:
    try:
        table = _io.read_table_csv(path)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise BadInputError(f"cannot read pixel track {path}: {exc}") from exc
    missing = [c for c in ("frame", "t_s", "x_px", "y_px") if c not in table.columns]
    if missing:
        raise BadInputError(f"{path}: a pixel track needs columns frame, t_s, x_px, y_px[, sigma_px]; missing "
                            f"{', '.join(missing)}")
    out = pd.DataFrame({c: pd.to_numeric(table[c], errors="coerce") for c in ("frame", "t_s", "x_px", "y_px")})
    if "sigma_x_px" in table.columns and "sigma_y_px" in table.columns:
        sx = pd.to_numeric(table.sigma_x_px, errors="coerce")
        sy = pd.to_numeric(table.sigma_y_px, errors="coerce")
        out["sigma_px"] = np.sqrt(0.5 * (sx**2 + sy**2))
    else:
        out["sigma_px"] = pd.to_numeric(table["sigma_px"], errors="coerce") if "sigma_px" in table.columns else np.nan
    for col in ("frame", "t_s", "x_px", "y_px"):
        bad = np.flatnonzero(~np.isfinite(out[col].to_numpy(float)))
        if len(bad):
            raise BadInputError(f"{path}: row {int(bad[0]) + 1}, column {col}: not a number")
    sigma = out.sigma_px.to_numpy(float)
    if np.any(np.isfinite(sigma) & (sigma <= 0)):
        raise BadInputError(f"{path}: sigma_px must be > 0 where given")
    if np.any(out.frame != np.round(out.frame)):
        raise BadInputError(f"{path}: column frame must hold whole frame numbers")
    out["frame"] = out.frame.astype(int)
    if np.any(np.diff(out.t_s.to_numpy(float)) <= 0):
        raise BadInputError(f"{path}: t_s must increase from row to row")
    return out


def read_pixel_track(path: str | Path, *, track_name: str | None = None, fps: float = math.nan) -> pd.DataFrame:
    """A pixel track (module docstring) as ``frame, t_s, x_px, y_px, sigma_px`` (frame start times [s];
    ``sigma_px`` NaN where the file states no error)."""
    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".trk":
        table = _read_trk(path, track_name, fps)
    elif suffix == ".csv":
        table = _read_csv(path)
    else:
        raise BadInputError(f"{path}: a pixel track is a Tracker .trk or a .csv")
    if len(table) < 2:
        raise BadInputError(f"{path}: {len(table)} position(s); a track needs at least 2")
    return table


def angles_from_pixel_track(track: pd.DataFrame, camera: Camera, protocol: Protocol
                            ) -> tuple[pd.DataFrame, dict]:
    """The angle table (:mod:`gyrorig.tables`) of a pixel track (:func:`read_pixel_track`), and a summary: the
    error check (``sigma_check``; ``checked_by``: the path through each frame's ``neighbours``, ``sinusoids`` over
    the record, or ``unchecked`` where neither follows), the errors used (``sigma_px``, ``sigma_source``), the
    camera's modes."""
    if not camera.has_pose:
        raise BadInputError("the camera file has no pose: a pixel track needs one (gyrorig pose --board-image or "
                            "--video, or lab fiducials tracked in a video)")
    tip = tip_marker(protocol)
    length = float(np.linalg.norm(tip.position_m))
    xy = track[["x_px", "y_px"]].to_numpy(float)
    frames = track.frame.to_numpy(int)
    t = track.t_s.to_numpy(float)
    stated = track.sigma_px.to_numpy(float)
    given = np.isfinite(stated)
    var = np.where(given, stated**2, 1.0)[:, None] * np.ones((1, 2))
    check = check_sigmas(t, frames, xy, var, follow_motion=True)
    if not math.isfinite(check.factor):
        raise BadInputError("the pixel track has too few runs of 7 nearby frames to find its errors from its scatter "
                            "(give sigma_px)")
    sinusoids = None if check.smooth_path else harmonic_check(t, frames, xy, var)
    followed = check.smooth_path or (sinusoids is not None and sinusoids.follows)
    if sinusoids is not None and followed:  # a path of sinusoids over the record follows where none local did
        check = replace(check, factor=sinusoids.factor, factor_se=sinusoids.factor_se,
                        coordinates=sinusoids.coordinates, outliers=sinusoids.outliers, floor_px=0.0, floor_px_se=0.0,
                        reason=f"a path of {len(sinusoids.omegas_rad_s)} sinusoids over the track (none through a "
                               "frame's neighbours follows it)")
    if not followed:
        if not given.all():
            raise BadInputError(
                f"the tip moves too far between the track's frames for its errors to come from its scatter (the "
                f"residuals about its path are correlated {np.round(check.residual_acf, 2).tolist()} 1-4 frames apart, "
                f"{np.round(NOISE_ACF, 2).tolist()} for noise): give sigma_px")
        check = replace(check, outliers=())
        scale, source = 1.0, "stated (the track moves too far between frames to check them)"
    elif given.all():
        scale = check.factor if check.factor > 1.0 + SIGMA_CHECK_Z * check.factor_se else 1.0
        source = "stated" + (f", scaled by {scale:.3g} (the scatter about the path)" if scale != 1.0 else "")
    else:
        scale = check.factor  # unit variances: the factor is the scatter itself [px]
        source = "the track's scatter about its smooth path" + (" (stated ones ignored: not given for every frame)"
                                                                 if given.any() else "")
    sigma = np.sqrt(var[:, 0]) * scale if given.all() else np.full(len(t), scale)
    cov = sigma[:, None, None] ** 2 * np.eye(2)
    th, ph, tips, c = angle_covariances(xy, cov, camera, length)
    quality = np.where(np.isfinite(th), "ok", "off-sphere").astype(object)
    outliers = list(check.outliers)
    th[outliers] = np.nan
    quality[outliers] = "outlier"
    tips[~np.isfinite(th)] = np.nan
    near, limb = limb_flags(tips, camera, length)
    quality[near] = [with_flag(q, "near-limb") for q in quality[near]]
    if limb:
        logger.warning("%s", limb)
    sth, sph = np.sqrt(c[:, 0, 0]), np.sqrt(c[:, 1, 1])
    ok = np.isfinite(th)
    phi = np.full(len(t), np.nan)
    phi[ok] = np.unwrap(ph[ok])
    # each tip's own time: its row's delay under a rolling shutter (none when camera.json states no readout: then
    # its row goes to the fit, which finds the readout)
    delay = np.array([camera.row_delay_s(y) if math.isfinite(y) else 0.0 for y in xy[:, 1]])
    angles = pd.DataFrame({
        "frame": frames, "t_s": t + delay + 0.5 * (camera.exposure_s if math.isfinite(camera.exposure_s) else 0.0),
        "theta_rad": th, "phi_rad": phi, "theta_sigma_rad": np.where(ok, sth, np.nan),
        "phi_sigma_rad": np.where(ok, sph, np.nan), "theta_phi_corr": np.where(ok, c[:, 0, 1] / (sth * sph), np.nan),
        "tip_x": tips[:, 0], "tip_y": tips[:, 1], "tip_z": tips[:, 2], "quality": quality})
    if camera.readout_unknown:
        angles["row_fraction"] = np.where(ok, xy[:, 1] / camera.height_px, np.nan)
    pixels = {i: xy[i] for i in np.flatnonzero(ok)}
    camera_sigma = add_camera_modes(angles, pixels, camera, length, camera.pose_points, False)
    summary = {"frames": len(angles), "tracked_fraction": float(ok.mean()), "outliers": len(outliers),
               "off_sphere": int(np.sum(quality == "off-sphere")), "sigma_px": float(np.median(sigma)),
               "sigma_source": source, "sigma_check": check.as_dict(), "camera_sigma_rad": camera_sigma,
               "checked_by": "neighbours" if check.smooth_path else ("sinusoids" if followed else "unchecked"),
               "tip_distance_m": length, "near_limb": int(near.sum())}
    return angles, summary


def is_pixel_track(path: str | Path) -> bool:
    """True for a Tracker ``.trk``, or a ``.csv`` whose header has ``x_px`` and ``y_px``."""
    path = Path(path)
    if path.suffix.lower() == ".trk":
        return True
    if path.suffix.lower() != ".csv" or not path.is_file():
        return False
    try:
        with path.open(encoding="utf-8", errors="replace") as fh:
            header = fh.readline()
    except OSError:
        return False
    columns = {c.strip().strip('"') for c in header.split(",")}
    return {"x_px", "y_px"} <= columns


def import_pixel_track(path: str | Path, camera: Camera, protocol: Protocol, out_dir: str | Path, *,
                       track_name: str | None = None) -> dict:
    """:func:`read_pixel_track` and :func:`angles_from_pixel_track`, writing ``angles.csv`` and ``track.json`` (the
    summary) into ``out_dir``; returns the summary with the paths written."""
    track = read_pixel_track(path, track_name=track_name, fps=camera.fps)
    angles, summary = angles_from_pixel_track(track, camera, protocol)
    out = Path(out_dir)
    summary = {"source": str(path), **summary}
    _io.write_csv(angles, out / "angles.csv")
    _io.write_json(summary, out / "track.json")
    return {**summary, "angles": str(out / "angles.csv")}
