"""Tracking: from a video to the tip direction theta(t), phi(t) with honest error bars.

Works on any video OpenCV decodes, or on frames held in memory; it reads only the frames,
``camera.json`` and the protocol's marker geometry, never the simulator or a renderer's
``truth.csv`` (this package imports neither).

* :mod:`~gyrorig.tracking.camera_file`: ``camera.json`` (:class:`gyrorig.camera.Camera`, :func:`load_camera`);
* :mod:`~gyrorig.tracking.sources`: video files, image folders (with a timestamps file) and in-memory frames;
* :mod:`~gyrorig.tracking.detect`: blobs above a threshold (start points);
* :mod:`~gyrorig.tracking.follow`: which spot is the tip (shape, appearance, motion, acquisition gates);
* :mod:`~gyrorig.tracking.spot`: the spot model, its weighted least-squares fit and its Cramér-Rao bound;
* :mod:`~gyrorig.tracking.ellipse`: elliptical spots of disc and blob markers, a disc's perspective offset;
* :mod:`~gyrorig.tracking.scatter`: the per-frame errors checked on the record itself;
* :mod:`~gyrorig.tracking.rays`: pixels -> rays -> the tip's sphere -> angles with covariance;
* :mod:`~gyrorig.tracking.pose`: the pose from the fiducials, the camera model's uncertainty as modes;
* :mod:`~gyrorig.tracking.dots`: the frame's dots and its angle ``psi``;
* :mod:`~gyrorig.tracking.tracker`: the loop (:func:`track` returns the tables, :func:`track_video`
  writes ``angles.csv`` and ``markers.csv``).
"""

from ..tables import ANGLE_COLUMNS, MARKER_COLUMNS
from ..camera import INTRINSIC_PARAMETERS, Camera
from .camera_file import load_camera
from .errors import BadInputError, CameraFileError, TrackingError
from .pose import camera_modes, estimate_pose
from .rays import sphere_box, tip_from_pixel, tips_from_pixels
from .images import ImageFolder, TiffStack
from .sources import FrameArrays, VideoFile
from .scatter import SigmaCheck, check_sigmas
from .scene_spot import warm_up
from .spot import SpotFit, fit_spot, spot_crb_px
from .tracker import TrackResult, track, track_video

__all__ = ["Camera", "load_camera", "estimate_pose", "SpotFit", "fit_spot", "spot_crb_px", "warm_up",
           "tip_from_pixel", "tips_from_pixels", "camera_modes", "track", "track_video", "TrackResult",
           "TrackingError", "BadInputError", "CameraFileError", "VideoFile", "ImageFolder", "TiffStack", "FrameArrays", "sphere_box", "SigmaCheck", "check_sigmas", "ANGLE_COLUMNS", "MARKER_COLUMNS", "INTRINSIC_PARAMETERS"]
