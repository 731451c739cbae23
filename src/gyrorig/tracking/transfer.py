"""How a video's values relate to light: the transfer characteristic a stream states, and its inverse.

Cameras store a nonlinear function of the light (the opto-electronic transfer function, OETF); the spot models add
light linearly, so the tracker undoes it.  camera.json may state ``sensor.gamma`` (a power law,
``recorded = linear^(1/gamma)``) or ``sensor.transfer`` (a standard curve by name, :data:`TRANSFERS`); when it
states neither, the video's own tag is used (a phone's H.264 or HEVC file says ``bt709``, an iPhone's HDR file
``hlg``), and an untagged file is taken as linear (a compressed one with a warning).

The curves, each on values normalised to black 0 and white 1 (the inverse of the standard's OETF):

- ``bt709`` (also BT.601 and BT.2020's SDR curve): ``V/4.5`` below 0.081, else ``((V + 0.099)/1.099)^(1/0.45)``;
- ``srgb``: ``V/12.92`` below 0.04045, else ``((V + 0.055)/1.055)^2.4``;
- ``hlg`` (ITU-R BT.2100 hybrid log-gamma): ``V^2/3`` up to 0.5, else ``(exp((V - c)/a) + b)/12``;
- ``linear``: ``V``.

PQ (SMPTE ST 2084, HDR10) describes display light in absolute units, not the scene's: it is not undone, and the
tracker says so.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ..camera import Camera

__all__ = ["TRANSFERS", "transfer_of_video", "linear_level", "settle_transfer"]

logger = logging.getLogger(__name__)

#: transfer curves the tracker can undo, by name
TRANSFERS = ("bt709", "srgb", "hlg", "linear")

# FFmpeg's AVColorTransferCharacteristic codes
_CODES = {1: "bt709", 6: "bt709", 7: "bt709", 11: "bt709", 14: "bt709", 15: "bt709", 13: "srgb", 8: "linear",
          18: "hlg", 16: "pq", 4: "gamma 2.2", 5: "gamma 2.8"}

_HLG_A = 0.17883277
_HLG_B = 1.0 - 4.0 * _HLG_A
_HLG_C = 0.5 - _HLG_A * math.log(4.0 * _HLG_A)


def transfer_of_video(code: int | None) -> str | None:
    """The name of a stream's transfer characteristic from FFmpeg's code: one of :data:`TRANSFERS`, ``"pq"``,
    ``"gamma 2.2"`` or ``"gamma 2.8"`` (BT.470's power laws); None when the stream does not say."""
    return _CODES.get(int(code or 0))


def linear_level(v: np.ndarray, transfer: str) -> np.ndarray:
    """Linear light (0 black, 1 white) from stored values ``v`` normalised to black 0 and white 1 (values
    outside that range follow the curve's formula beyond its ends; below 0 gives 0)."""
    v = np.maximum(np.asarray(v, dtype=float), 0.0)
    if transfer == "linear":
        return v
    if transfer == "bt709":
        return np.where(v < 0.081, v / 4.5, ((v + 0.099) / 1.099) ** (1 / 0.45))
    if transfer == "srgb":
        return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    if transfer == "hlg":
        return np.where(v <= 0.5, v * v / 3.0, (np.exp((v - _HLG_C) / _HLG_A) + _HLG_B) / 12.0)
    raise ValueError(f"transfer {transfer!r}: allowed {', '.join(TRANSFERS)}")


def settle_transfer(camera: Camera, video: str | None, source, *, lossy: bool = False) -> Camera:
    """The camera with its transfer curve settled: when camera.json states neither ``gamma`` nor ``transfer``
    the video's tag (``video``) is used (untagged: linear, with a warning for a ``lossy`` file, which consumer
    cameras write with a curve); a stated one is kept, with a warning when the video says it is HDR (its values
    then follow HLG or PQ, not the stated curve)."""
    stated = camera.sensor.transfer != "video"
    if stated:
        if video in ("hlg", "pq") and camera.sensor.transfer != video:
            logger.warning("%s: the video says it is HDR (%s); camera.json's %s is used to linearise it (state "
                           "sensor.transfer = \"hlg\", or leave gamma and transfer out to use the video's)", source,
                           video.upper(), f"transfer {camera.sensor.transfer}" if camera.sensor.transfer else
                           f"gamma {camera.gamma:g}")
        return camera
    if video in TRANSFERS:
        logger.info("%s: camera.json states no gamma: the video's transfer curve (%s) is undone", source, video)
        return camera.with_sensor(transfer=video)
    if video is not None and video.startswith("gamma "):
        return camera.with_sensor(gamma=float(video.split()[1]), transfer=None)
    if video == "pq":
        logger.warning("%s: the video is HDR10 (PQ), display light in absolute units; it is tracked as stored "
                       "(not linearised)", source)
    elif video is None and lossy:
        logger.warning("%s: neither the video nor camera.json says how its values relate to light: taken as linear; "
                       "a phone's or camera's compressed video seldom is (state sensor.gamma, e.g. 2.2, or "
                       "sensor.transfer = \"bt709\" in camera.json)", source)
    return camera.with_sensor(transfer=None)
