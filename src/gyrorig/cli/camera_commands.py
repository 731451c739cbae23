"""The camera's commands: ``gyrorig calibrate`` (intrinsics, and the pose from a board at a known place) and
``gyrorig pose``."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from .. import _io
from .._validate import number
from .codes import EXIT_FAILED, EXIT_OK


def _board_size(args: argparse.Namespace) -> tuple[int, int, float]:
    """--board COLSxROWS and --square-mm, checked: (cols, rows, square_m)."""
    try:
        cols, rows = (int(v) for v in args.board.lower().split("x"))
    except ValueError:
        raise ValueError(f"--board {args.board!r}: expected COLSxROWS inner corners, e.g. 9x6") from None
    if not (3 <= cols <= 200 and 3 <= rows <= 200):
        raise ValueError(f"--board {args.board!r}: inner corners per side must be 3 to 200 (OpenCV's detector "
                         "needs more than 2)")
    if args.square_mm is None:
        raise ValueError("--square-mm is required with a board: the size of its squares [mm]")
    number("", "--square-mm", args.square_mm, lo=0.0, lo_open=True, hi=1e4)
    return cols, rows, args.square_mm / 1000.0


def _numbers(option: str, text: str, axes: str, example: str, limit: float) -> list[float]:
    """A comma-separated list of ``len(axes)`` numbers, each within +-limit, or ValueError naming the option."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != len(axes):
        raise ValueError(f"{option} {text!r}: expected {','.join(axes)}, e.g. {example}")
    for axis, v in zip(axes, values):
        number("", f"{option} {axis}", v, lo=-limit, hi=limit)
    return values


def _azimuth_mark(args: argparse.Namespace):
    """--azimuth-mark-px with --mark-position-mm, checked (None without either)."""
    from ..tracking.motion_pose import AzimuthMark

    if args.azimuth_mark_px is None and args.mark_position_mm is None:
        return None
    if args.azimuth_mark_px is None or args.mark_position_mm is None:
        raise ValueError("--azimuth-mark-px and --mark-position-mm go together: the mark's pixel and its lab position")
    if args.video is None:
        raise ValueError("--azimuth-mark-px fixes the azimuth origin of a pose from the motion (--video); a board's "
                         "pose has its own")
    px = _numbers("--azimuth-mark-px", args.azimuth_mark_px, "XY", "812.5,402", 1e5)
    pos = _numbers("--mark-position-mm", args.mark_position_mm, "XYZ", "150,0,-60", 1e5)
    number("", "--mark-sd-px", args.mark_sd_px, lo=0.0, hi=1e3)
    number("", "--mark-position-sd-mm", args.mark_position_sd_mm, lo=0.0, hi=1e3)
    return AzimuthMark(tuple(px), tuple(v / 1000.0 for v in pos), args.mark_sd_px, args.mark_position_sd_mm / 1000.0)


def _board_placement(args: argparse.Namespace):
    """--board-origin-mm and the placement's uncertainties, checked (None without --board-origin-mm)."""
    from ..board_pose import BoardPlacement

    if args.board_origin_mm is None:
        return None
    origin = _numbers("--board-origin-mm", args.board_origin_mm, "XYZ", "-80,50,-50", 1e5)
    number("", "--board-yaw-deg", args.board_yaw_deg, lo=-360.0, hi=360.0)
    number("", "--origin-sd-mm", args.origin_sd_mm, lo=0.0, hi=1e3)
    number("", "--yaw-sd-deg", args.yaw_sd_deg, lo=0.0, hi=90.0)
    number("", "--tilt-sd-deg", args.tilt_sd_deg, lo=0.0, hi=45.0)
    return BoardPlacement(tuple(v / 1000.0 for v in origin), np.radians(args.board_yaw_deg),
                          args.origin_sd_mm / 1000.0, np.radians(args.yaw_sd_deg), np.radians(args.tilt_sd_deg))


def _print_board_pose(pose, image: str) -> None:
    src = pose.camera_fields(image)["pose_source"]
    stated = "" if pose.placement.sd.any() else (" (the placement taken as exact: give --origin-sd-mm, --yaw-sd-deg, "
                                                "--tilt-sd-deg for its uncertainty)")
    print(f"pose from the board in {image}: corners fit with {pose.rms_px:.3f} px RMS; rotation sd "
          f"{np.degrees(np.linalg.norm(src['sigma_rvec_rad'])):.3g} deg, position sd "
          f"{np.linalg.norm(src['sigma_tvec_m']) * 1e3:.3g} mm; the placement's share of the variance "
          f"{src['placement_share_of_variance']:.0%}{stated}")


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from ..board_pose import check_board_asymmetric, pose_from_board
    from ..calibration import CalibrationError, CalibrationInputError, calibrate_camera

    cols, rows, square_m = _board_size(args)
    placement = _board_placement(args)
    if (placement is None) != (args.pose_image is None):
        raise ValueError("--pose-image and --board-origin-mm go together (the image of the board lying at that place)")
    if placement is not None:
        check_board_asymmetric(cols, rows)
    try:
        result = calibrate_camera(args.images, cols=cols, rows=rows, square_m=square_m, lens_model=args.lens_model)
    except CalibrationInputError:
        raise  # bad input: exit 2
    except CalibrationError as exc:
        print(f"gyrorig: calibration refused: {exc}", file=sys.stderr)
        return EXIT_FAILED
    for name, err in result.per_image_rms_px.items():
        print(f"  {name}: {err:.3f} px")
    if result.not_found:
        print(f"  board not found in: {', '.join(result.not_found)}")
    k = result.camera_matrix
    if result.held_out_rms_px:
        print("lens model chosen by the views: " + result.lens_model + " (held-out reprojection RMS: "
              + ", ".join(f"{m} {e:.4f} px" for m, e in result.held_out_rms_px.items()) + ")")
    print(f"RMS reprojection error {result.rms_px:.3f} px; fx {k[0, 0]:.2f}, fy {k[1, 1]:.2f}, "
          f"cx {k[0, 2]:.2f}, cy {k[1, 2]:.2f}, dist {np.round(result.dist_coeffs, 5).tolist()}")
    out = result.to_json()
    if placement is not None:
        pose = pose_from_board(args.pose_image, result.camera_matrix, result.dist_coeffs, cols=cols, rows=rows,
                               square_m=square_m, placement=placement)
        out.update(pose.camera_fields(str(args.pose_image)))
        _print_board_pose(pose, args.pose_image)
    _io.write_json(out, args.out)
    if placement is None:
        print(f"wrote {args.out}, with the intrinsics' covariance (tracking propagates it into the error bars). It "
              "has no pose: `gyrorig track` finds it from the protocol's lab fiducials; or give --pose-image (or "
              "run `gyrorig pose`) with a board lying at a known place")
    else:
        print(f"wrote {args.out}, with the intrinsics' and the pose's covariance (tracking propagates both)")
    return EXIT_OK


def _cmd_pose(args: argparse.Namespace) -> int:
    from ..tracking import load_camera

    if (args.board_image is None) == (args.video is None):
        raise ValueError("give one of --board-image (a board lying at a known place) and --video (the rig's motion)")
    mark = _azimuth_mark(args)  # checked before any work
    cam = load_camera(args.camera, require_pose=False)
    out = json.loads(_io.read_settings_text(args.camera))
    out = {k: v for k, v in out.items() if k not in ("pose_points", "pose_source", "pose_covariance")}
    if args.video is not None:
        out.update(_pose_from_motion(args, cam, mark))
    else:
        from ..board_pose import pose_from_board

        cols, rows, square_m = _board_size(args)
        placement = _board_placement(args)
        if placement is None:
            raise ValueError("--board-origin-mm is required with --board-image: where the board's first inner corner "
                             "lies, in the pivot frame")
        pose = pose_from_board(args.board_image, cam.camera_matrix, cam.dist_coeffs, cols=cols, rows=rows,
                               square_m=square_m, placement=placement)
        out.update(pose.camera_fields(str(args.board_image)))
        _print_board_pose(pose, args.board_image)
    _io.write_json(out, args.out)
    print(f"wrote {args.out}")
    return EXIT_OK


def _pose_from_motion(args: argparse.Namespace, cam, mark) -> dict:
    """``gyrorig pose --video``: the rough pose from the protocol's camera placement, then the fit."""
    from dataclasses import replace

    from ..camera import placement_pose
    from ..protocols import load_tracking_protocol
    from ..tracking.motion_pose import fix_azimuth, pose_from_motion
    from .printing import progress_printer

    if args.protocol is None:
        raise ValueError("--protocol is required with --video (the tip's marker, and its [camera] placement as the "
                         "rough starting pose)")
    protocol = load_tracking_protocol(args.protocol)
    if "camera" not in protocol.extra:
        raise ValueError(f"{args.protocol}: no [camera] section; its position_m and look_at_m give the rough pose the "
                         "fit starts from")
    rvec, tvec = placement_pose(protocol.extra["camera"])
    from .parser import clipped

    video = clipped(args.video, args)
    pose = pose_from_motion(video, replace(cam, rvec=rvec, tvec=tvec), protocol, progress=progress_printer("pose"))
    if mark is not None:
        fitted = cam if pose.camera_matrix is None else replace(cam, camera_matrix=pose.camera_matrix)
        pose = fix_azimuth(pose, fitted, mark)
    sd = np.sqrt(np.diag(pose.covariance))
    held = f" (and {pose.still_frames} of the tip held still at an end, left out)" if pose.still_frames else ""
    print(f"pose from the tip's motion in {video}: {pose.frames} frames{held}, chi2_red {pose.chi2_red:.3g}, nutation "
          f"{pose.nutation_frequency_rad_s:.5g} rad/s; rotation sd {np.degrees(np.linalg.norm(sd[:3])):.3g} deg, "
          f"position sd {np.linalg.norm(sd[3:]) * 1e3:.3g} mm, depth scale sd {pose.depth_scale_sd_rel:.2%}")
    if pose.focal_scale_sd > 0:
        print(f"focal length fitted with the pose: {pose.camera_matrix[0, 0]:.1f} px, {100 * pose.focal_scale:+.2f} % "
              f"+- {100 * pose.focal_scale_sd:.2f} % from camera.json's (its sd {100 * cam.focal_sd_rel:.2g} %)")
    if np.isfinite(pose.readout_time_s):
        print(f"rolling shutter's readout fitted with the pose: {pose.readout_time_s * 1e3:.3g} ms +- "
              f"{pose.readout_time_sd_s * 1e3:.2g} ms (camera.json keeps it unknown: the analysis fits it again)")
    fields = pose.camera_fields(str(args.video))
    print(f"azimuth origin: {fields['pose_source']['azimuth_origin']}")
    if pose.azimuth_mark is not None:
        r = pose.azimuth_mark["distance_from_vertical_m"]
        print(f"  turned by {np.degrees(pose.azimuth_mark['turn_rad']):.3f} deg; the mark lies "
              f"{r['as_posed'] * 1e3:.2f} mm from the vertical as posed, {r['stated'] * 1e3:.2f} mm as stated")
    return fields
