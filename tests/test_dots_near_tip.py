"""A tip passing one of the top's other dots (a crossbar's), tracked without following them, as ``gyrorig analyse``
tracks: the places those dots can take about the axis (:func:`gyrorig.tracking.dots.dot_circles`) tell the follower
where a fit started from its prediction could take a dot's light into the tip's disc."""

import numpy as np
import pandas as pd
import pytest

from gyrorig.bench.variants import variant_protocols
from gyrorig.markers import parse_markers
from gyrorig.protocols import parse_protocol
from gyrorig.render.phone import PhoneStyle, render_phone_video
from gyrorig.tracking import load_camera, track
from gyrorig.tracking.dots import dot_circles

#: a crossbar dot within this many of the tip's image radii of it: the frames where its light reaches the tip's fit
NEAR_RADII = 4.0


@pytest.fixture(scope="module")
def crossing(tmp_path_factory):
    """1.5 s of the phone variants' rig (a phone 0.75 m above the pivot, 10 deg off the vertical) at 640 x 360 and 240
    frames/s, in front of the coffee photograph, HEVC: the tip passes within 4 of its radii of a crossbar dot in about
    150 frames."""
    scene, user, _ = variant_protocols("phone-coffee-hevc", 1.5)
    for d in (scene, user):
        d["camera"].update(width_px=640, height_px=360)
    rendered = render_phone_video(scene, tmp_path_factory.mktemp("crossing"),
                                  style=PhoneStyle(photo="coffee", codec="libx265"), seed=0)
    return parse_protocol(user), rendered, pd.read_csv(rendered["truth"])


def _near_frames(truth: pd.DataFrame, radius_px: float) -> list[int]:
    """Frames whose tip is visible and has a visible crossbar dot's centre within :data:`NEAR_RADII` of its radii."""
    tip = truth[truth.marker == "tip"].set_index("frame")
    dots = truth[truth.marker.str.startswith("crossbar") & truth.visible]
    gap = np.hypot(dots.x_px.to_numpy() - tip.loc[dots.frame, "x_px"].to_numpy(),
                   dots.y_px.to_numpy() - tip.loc[dots.frame, "y_px"].to_numpy())
    near = dots.frame[gap < NEAR_RADII * radius_px].unique()
    return [int(f) for f in near if tip.loc[f, "visible"]]


def test_every_place_a_dot_takes_lies_on_its_circle(crossing):
    """The crossbar dots as rendered, in every frame: each within the reach of one of its circle's points
    (:func:`dot_circles` for the tip's true direction), beyond its image radius by no more than half the points'
    largest gap."""
    protocol, rendered, truth = crossing
    cam = load_camera(rendered["camera"])
    dots = parse_markers(protocol).frame_dots()
    assert len(dots) == 2
    tip = truth[truth.marker == "tip"].set_index("frame")
    checked = 0
    for frame in tip.index[::10]:
        th, ph = tip.loc[frame, "theta_rad"], tip.loc[frame, "phi_rad"]
        n = np.array([np.sin(th) * np.sin(ph), -np.sin(th) * np.cos(ph), np.cos(th)])
        places = np.array(dot_circles(dots, n, cam))
        seen = truth[(truth.frame == frame) & truth.marker.isin([d.name for d in dots])]
        for x, y in seen[["x_px", "y_px"]].to_numpy():
            assert np.any(np.hypot(places[:, 0] - x, places[:, 1] - y) <= places[:, 2])
            checked += 1
    assert checked >= 60


def test_a_tip_passing_a_crossbar_dot_is_followed_alike_without_the_dots(crossing):
    """Tracked without the frame's dots, the tip near a crossbar dot is followed as when they are followed: every such
    frame tracked, and the angle table the same frame for frame (following the dots adds their angle, nothing else).
    Before, the tip alone was fitted from its prediction beside an unseen dot: the dot's light drawn into its disc,
    127 of those 147 frames tracked, the RMS error 0.90 px there against 0.67, 13 frames fewer in all."""
    protocol, rendered, truth = crossing
    cam = load_camera(rendered["camera"])
    alone = track(rendered["video"], cam, protocol, frame_dots=False)
    followed = track(rendered["video"], cam, protocol, frame_dots=True)
    radius = float(alone.markers[alone.markers.marker == "tip"].radius_px.median())
    near = [f for f in _near_frames(truth, radius) if f in set(alone.angles.frame)]  # (dropped frames: not recorded)
    assert len(near) >= 100
    got = alone.angles.set_index("frame").loc[near]
    assert got.theta_rad.notna().all()
    cols = ["frame", "theta_rad", "phi_rad", "theta_sigma_rad", "phi_sigma_rad", "quality"]
    pd.testing.assert_frame_equal(alone.angles[cols], followed.angles[cols])
