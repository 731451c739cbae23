"""A slow-motion video as a phone's gallery shares it: normal-speed ends found and left out (gyrorig.tracking.pace)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from gyrorig.bench.variants import variant_protocols
from gyrorig.physics import simulate
from gyrorig.protocols import BUNDLED_PROTOCOL_DIR, load_protocol, parse_protocol
from gyrorig.render.phone import PhoneStyle, render_phone_video
from gyrorig.theory import steady_launch
from gyrorig.tracking import load_camera, track
from gyrorig.tracking.pace import off_pace_ends


def _gallery_copy(n: int, ratio: int, head: int, tail: int) -> np.ndarray:
    """The captured frames a gallery copy keeps: every ``ratio``-th for ``head`` captured frames, a ramp of steps
    ``ratio - 1 .. 2``, every frame, the ramp back and every ``ratio``-th for the last ``tail`` captured frames."""
    ramp = list(range(ratio - 1, 1, -1))
    steps = [ratio] * (head // ratio) + ramp + [1] * (n - 1 - head - tail - 2 * sum(ramp)) + ramp[::-1] + \
        [ratio] * (tail // ratio)
    return np.cumsum([0] + steps)


def _tip(name: str, rate_hz: float, duration_s: float, steady: bool = False) -> np.ndarray:
    """The tip's unit direction from the simulator, sampled at ``rate_hz``."""
    protocol = load_protocol(BUNDLED_PROTOCOL_DIR / f"{name}.toml")
    if steady:
        protocol = steady_launch(protocol)
    traj = simulate(protocol, duration_s=duration_s, rate_hz=rate_hz)
    th, ph = traj.theta_rad.to_numpy(), traj.phi_rad.to_numpy()
    return np.column_stack([np.sin(th) * np.sin(ph), -np.sin(th) * np.cos(ph), np.cos(th)])


def test_normal_speed_ends_of_a_steadily_precessing_top_are_found():
    """A heavy top precessing steadily, captured at 240 frames/s and kept as a gallery copy at 30 (8x, 0.5 s and
    0.3 s at normal speed): the ends turn 8 times as far per frame.  Every row whose time the file misplaces (a
    step of more than one captured frame to its neighbour in the middle) is in an end found, and the ends reach at
    most the margin (3 rows) and one row beyond; the original file, all captured frames, has no end off pace."""
    rng = np.random.default_rng(3)
    xyz = _tip("air-cushion-heavy-top", 240.0, 3.0, steady=True)
    xyz = xyz + rng.normal(0.0, 2e-4, xyz.shape)  # a few tenths of a pixel
    kept = _gallery_copy(len(xyz), 8, 120, 72)
    assert kept[-1] < len(xyz)
    step = np.diff(kept)
    first_slow = int(np.argmax(step == 1))  # rows before it are closer in the file than in time to the next one
    last_slow = len(kept) - 1 - int(np.argmax(step[::-1] == 1))
    found = off_pace_ends(np.arange(len(kept)), xyz[kept], np.zeros(len(kept), bool), 8.0)
    assert first_slow <= found.head_rows <= first_slow + 4
    assert len(kept) - 1 - last_slow <= found.tail_rows <= len(kept) - 1 - last_slow + 4
    assert 6.0 < found.head_speed_ratio < 10.0 and 6.0 < found.tail_speed_ratio < 10.0
    original = off_pace_ends(np.arange(len(xyz)), xyz, np.zeros(len(xyz), bool), 8.0)
    assert not original.found


@pytest.mark.parametrize("name", ["air-cushion-heavy-top", "eddy-damped-top"])
def test_a_nodding_or_damped_top_in_the_original_file_has_no_end_off_pace(name):
    """Released from rest (cusps: the tip stops and starts every nod) or damped by eddy currents: in the original
    slow-motion file (every captured frame, 240 frames/s) the tip's pace varies, but no end is taken for one at
    another pace (8x, or 4x for 120 frames/s); nor where the tip leaves the view for the record's last 60 frames
    (the top fallen: a run of lost frames, no pace at all)."""
    xyz = _tip(name, 240.0, 4.0)
    for ratio, every in ((8.0, 1), (4.0, 2)):
        sampled = xyz[::every]
        found = off_pace_ends(np.arange(len(sampled)), sampled, np.zeros(len(sampled), bool), ratio)
        assert not found.found, (ratio, found)
    gone = np.arange(len(xyz)) >= len(xyz) - 60
    found = off_pace_ends(np.arange(len(xyz)), np.where(gone[:, None], np.nan, xyz), gone, 8.0)
    assert not found.found, found


def test_a_gallery_copy_of_a_slow_motion_video_keeps_only_frames_at_their_times(tmp_path):
    """Rendered and tracked: the air-cushion top nodding with cusps, captured at 200 frames/s and stored at 25 as a
    gallery shares it (the first 0.25 s and last 0.2 s of the capture at normal speed).  Numbered on the capture
    rate, the ends' frames would be up to 8x too close in time.  After tracking, every frame with a position is at
    its true time (one offset for the whole record: the ends' missing time), the ends' frames with a position are
    flagged off-pace, and the track says why; the slowed middle keeps its positions."""
    scene, user, _ = variant_protocols("sphere", 1.2)
    style = PhoneStyle(photo="coffee", codec="libx264", container_fps=25.0, normal_speed_ends_s=(0.25, 0.2))
    rendered = render_phone_video(scene, tmp_path, seed=4, style=style)
    kept = np.asarray(rendered["kept"])
    res = track(rendered["video"], load_camera(rendered["camera"]), parse_protocol(user), frame_dots=False)
    angles = res.angles
    assert len(angles) == len(kept)
    truth = pd.read_csv(rendered["truth"])
    true_t = truth[truth.marker == "tip"].set_index("frame").t_s.reindex(kept).to_numpy()
    placed = angles.theta_rad.notna().to_numpy()
    offset = angles.t_s.to_numpy()[placed] - true_t[placed]
    np.testing.assert_allclose(offset, np.median(offset), atol=1e-6)
    step = np.diff(kept)
    first, last = int(np.argmax(step == 1)), len(kept) - 1 - int(np.argmax(step[::-1] == 1))
    middle = np.zeros(len(kept), bool)
    middle[first: last + 1] = True
    # the record's check may take a few frames beside a ramp as off the path; beyond 16 rows (two ramps) of the
    # middle's ends the frames are tracked as in any slow-motion file
    assert np.mean(placed[first + 16: last - 15]) >= 0.95
    assert (angles.quality[~middle] == "off-pace").any()
    assert any("off-pace" in problem for problem in res.source_problems)
