"""Synthetic videos of the rigs: the simulator's trajectory seen through a real camera model.

Pipeline per video:

1. simulate the scene on a dense grid (>= 2 kHz, >= 40 samples per nutation period) and
   interpolate every marker's lab position with a cubic spline (error < 1e-12 m);
2. for each frame and marker, the sub-exposure sample times (global shutter: the same for
   the whole frame; rolling shutter: shifted by the marker's row, ``t = t_frame + (y/H)
   readout``), positions projected with ``cv2.projectPoints`` (pinhole + distortion);
3. each sample drawn as a sphere's disc of radius ``f R / depth`` convolved with the
   Gaussian PSF (``0.5 erfc((|p - c| - r) / (sqrt(2) sigma))``), only in a window around the
   marker; samples hidden behind an occluder (the rotor can) or outside the image are
   skipped; the sum over samples is the motion blur;
4. sensor: electrons = Poisson(expected) + Normal(0, read noise), clipped at the full
   well; ADU = round(electrons / gain), clipped at ``2^bits - 1``.  Near the markers this
   is drawn directly; elsewhere every pixel has the same distribution, computed exactly
   once (:func:`background_distribution`) and sampled through a 2^16-entry inverse-CDF
   table (probabilities resolved to 1.5e-5; 5x faster than drawing the noise);
5. frames go to ``video.mkv`` (FFV1, lossless; 16-bit grey for 10/12-bit sensors) or
   ``video.mp4`` (mp4v, 8-bit, lossy) under a temporary name, renamed when complete.

Truth is written beside: ``truth.csv`` (per frame and marker) and ``camera.json``.
Nothing here is read by the tracker.
"""

from .board import render_calibration_images
from .paths import MarkerPaths, marker_paths
from .sensor import background_distribution
from .video import TRUTH_COLUMNS, VIDEO_CODECS, open_writer, render_frames, render_video

__all__ = ["MarkerPaths", "marker_paths", "render_frames", "render_video", "render_calibration_images",
           "TRUTH_COLUMNS", "VIDEO_CODECS", "background_distribution", "open_writer"]
