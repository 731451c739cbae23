"""A check a human can look at: a contact sheet of tracked frames (``gyrorig track --overlay``).

Each panel is a crop of one frame around the tip, enlarged, with the tip's position as the tracker
found it (a cross), its path over the neighbouring frames (dots: where it came from and went), the
frame's quality flag and the position's error ellipse scaled up so it can be seen.  Panels are
spread evenly over the record, and frames the tracker did not take as ``ok`` (``missing``,
``outlier``, ``reacquired``, ``blended``) are added so a user can see what happened there.  No
truth is needed: a track that left the tip shows as a cross beside the marker, or a path that jumps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from .. import _io

__all__ = ["overlay_frames", "overlay_crops", "plot_overlay", "write_overlay", "write_first_look"]

#: half-width of a panel's crop [px]
CROP_HALF_PX = 24
#: the error ellipse is drawn this many times its size (sub-pixel errors are invisible otherwise)
ELLIPSE_SCALE = 100.0


def overlay_frames(angles: pd.DataFrame, n_even: int = 12, n_flagged: int = 8) -> list[int]:
    """The frame numbers to show: ``n_even`` spread over the record, and up to ``n_flagged`` frames not
    flagged ``ok`` (spread over those)."""
    frames = angles.frame.to_numpy()
    pick = set(frames[np.linspace(0, len(frames) - 1, min(n_even, len(frames))).round().astype(int)].tolist())
    flagged = angles.frame[angles.quality.astype(str) != "ok"].to_numpy()
    if len(flagged):
        pick |= set(flagged[np.linspace(0, len(flagged) - 1, min(n_flagged, len(flagged))).round().astype(int)])
    return sorted(int(f) for f in pick)


def plot_overlay(crops: dict, markers: pd.DataFrame, angles: pd.DataFrame, *, title: str = "") -> Figure:
    """The contact sheet.  ``crops``: ``{frame: (image crop, x0, y0)}`` (the crop's top-left pixel);
    ``markers``: the tracker's marker table; ``angles``: its angle table."""
    tip = markers[markers.marker == "tip"].set_index("frame")
    quality = angles.set_index("frame").quality.astype(str)
    frames = sorted(crops)
    cols = min(5, max(len(frames), 1))
    rows = max(1, -(-len(frames) // cols))
    fig = Figure(figsize=(2.6 * cols, 2.9 * rows))
    for k, f in enumerate(frames):
        ax = fig.add_subplot(rows, cols, k + 1)
        img, x0, y0 = crops[f]
        ax.imshow(img, cmap="gray", extent=(x0 - 0.5, x0 + img.shape[1] - 0.5, y0 + img.shape[0] - 0.5, y0 - 0.5))
        near = tip[(tip.index >= f - 5) & (tip.index <= f + 5)]
        ax.plot(near.x_px, near.y_px, ".", color="tab:cyan", ms=3, label="path, frames +-5")
        flag = quality.get(f, "?")
        if f in tip.index:
            r = tip.loc[[f]].iloc[0]
            colour = "tab:green" if flag == "ok" else "tab:orange"
            ax.plot(r.x_px, r.y_px, "+", color=colour, ms=12, mew=1.5)
            ax.add_patch(Ellipse((r.x_px, r.y_px), 2 * ELLIPSE_SCALE * r.sigma_x_px, 2 * ELLIPSE_SCALE * r.sigma_y_px,
                                 fill=False, color=colour, lw=0.8))
        ax.set_xlim(x0 - 0.5, x0 + img.shape[1] - 0.5)
        ax.set_ylim(y0 + img.shape[0] - 0.5, y0 - 0.5)
        ax.set_title(f"frame {f}: {flag}", fontsize=8, color="black" if flag == "ok" else "tab:red")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle((title + "\n" if title else "") + f"cross: tip as found (ellipse: its error x{ELLIPSE_SCALE:g}); "
                 "dots: its path over frames +-5", fontsize=9)
    fig.tight_layout()
    return fig


def overlay_crops(video, angles: pd.DataFrame, markers: pd.DataFrame, *, fps: float,
                  time_scale: float = 1.0) -> dict[int, tuple[np.ndarray, int, int]]:
    """The chosen frames (:func:`overlay_frames`) of ``video`` read again (a path or a frame source), each
    cropped about the tip: ``{frame: (crop, x0, y0)}``.  The frames are numbered as the tracker numbered them
    (:class:`gyrorig.tracking.timing.FrameClock`): ``fps`` the rate it numbered them on
    (``TrackResult.camera.fps``), ``time_scale`` the factor from the file's times to real ones (slow motion:
    ``TrackResult.frame_times["time_scale"]``)."""
    from ..tracking.sources import as_source
    from ..tracking.timing import FrameClock

    wanted = overlay_frames(angles)
    tip = markers[markers.marker == "tip"].set_index("frame").sort_index()
    crops = {}
    clock = FrameClock(fps, time_scale, video, check_rate=False)
    with as_source(video).open() as frames:
        for k, (image, t_s) in enumerate(frames):
            index, _ = clock.number(t_s, k)
            if index not in wanted:
                continue
            if index in tip.index:
                cx, cy = tip.loc[index, ["x_px", "y_px"]].to_numpy(float)
            else:  # no position this frame: centre on the nearest frame that has one
                if tip.empty:
                    continue
                nearest = tip.index[np.argmin(np.abs(tip.index.to_numpy() - index))]
                cx, cy = tip.loc[nearest, ["x_px", "y_px"]].to_numpy(float)
            h, w = image.shape
            x0 = int(np.clip(round(cx) - CROP_HALF_PX, 0, max(w - 2 * CROP_HALF_PX - 1, 0)))
            y0 = int(np.clip(round(cy) - CROP_HALF_PX, 0, max(h - 2 * CROP_HALF_PX - 1, 0)))
            crops[index] = (image[y0:y0 + 2 * CROP_HALF_PX + 1, x0:x0 + 2 * CROP_HALF_PX + 1], x0, y0)
    return crops


def write_overlay(video, angles: pd.DataFrame, markers: pd.DataFrame, path: str | Path, *, fps: float,
                  time_scale: float = 1.0, title: str = "") -> Path:
    """Read the chosen frames of ``video`` again (:func:`overlay_crops`) and write the contact sheet (PNG,
    written under a temporary name and renamed)."""
    crops = overlay_crops(video, angles, markers, fps=fps, time_scale=time_scale)
    fig = plot_overlay(crops, markers, angles, title=title)
    path = Path(path)
    with _io.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    return path


def write_first_look(look, path: str | Path, title: str = "") -> Path:
    """The first frame the tracker searched, every spot that stood out in it circled in the colour of what
    became of it (legend: the verdicts and their counts), written atomically to ``path`` (PNG)."""
    from ..tracking.first_look import Verdict

    colours = {Verdict.TAKEN: "lime", Verdict.WITH_SCENE: "orange", Verdict.UNCONFIRMED: "yellow", Verdict.SHAPE: "red",
               Verdict.NOT_ALIKE: "red", Verdict.NO_FIT: "magenta", Verdict.SIZE: "cyan",
               Verdict.OFF_SPHERE: "deepskyblue", Verdict.LAB_MARKER: "white"}  # the rest grey
    fig = Figure(figsize=(10, 10 * look.frame.shape[0] / look.frame.shape[1] + 0.8), dpi=100)
    ax = fig.add_subplot(1, 1, 1)
    image = np.asarray(look.frame, float)
    lo, hi = np.percentile(image, [1, 99.8])
    ax.imshow(image, cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1, interpolation="nearest")
    seen = {}
    for c in look.candidates:
        colour = colours.get(c.verdict, "0.6")
        ax.add_patch(Ellipse((c.x_px, c.y_px), 2 * c.radius_px + 6, 2 * c.radius_px + 6, fill=False, lw=1.2,
                             ec=colour))
        seen[c.verdict.value] = (colour, seen.get(c.verdict.value, (colour, 0))[1] + 1)
    for label, (colour, n) in seen.items():
        ax.plot([], [], "o", mfc="none", mec=colour, label=f"{label} ({n})")
    if seen:
        ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    ax.set_title(title or f"first frame searched: spots above {look.threshold.threshold:.3g} of local contrast; the "
                 f"tip's image expected {look.expected_radius_px:.3g} px in radius (upright)", fontsize=9)
    ax.set_axis_off()
    fig.tight_layout()
    path = Path(path)
    with _io.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    return path
