"""The argument parser of ``gyrorig`` (argparse only; the commands are in :mod:`gyrorig.cli.commands`)."""

from __future__ import annotations

import argparse

from .. import __version__
from .._methods import METHODS

__all__ = ["build_parser"]


def add_fit_options(parser: argparse.ArgumentParser) -> None:
    """``--truth``, ``--terms``, ``--fix`` and ``--prior``, shared by fit and analyze."""
    parser.add_argument("--truth", default=None, help="truth.csv of a synthetic run: adds true values and pulls")
    parser.add_argument("--terms", default="data",
                        help="how the model's optional terms (nutation harmonics, damped-scene terms) are chosen: "
                        "'data' (default) by chi-square tests on this record, or a plan.json from 'gyrorig plan "
                        "--duration T --out DIR' (its fit_terms: the same model for every record of the scene)")
    parser.add_argument("--fix", action="append", default=None, metavar="NAME=VALUE",
                        help="hold a fit parameter at a value (SI units; names as in fit.json's parameters, e.g. "
                        "nutation_frequency_rad_s); repeatable")
    parser.add_argument("--prior", action="append", default=None, metavar="NAME=VALUE+-SD",
                        help="a Gaussian prior on a fit parameter, e.g. precession_rate_rad_s=0.86+-0.01: one more "
                        "measurement of it, combined with the record; repeatable")


def add_board_placement_options(parser: argparse.ArgumentParser) -> None:
    """Where a board lying face up is, relative to the pivot, and how well that is known."""
    g = parser.add_argument_group("board at a known place (the pose)")
    g.add_argument("--board-origin-mm", default=None, metavar="X,Y,Z",
                   help="where the board's first inner corner is, in the pivot frame (z up) [mm]: the inner corner "
                        "of a dark corner square on the side whose two corner squares are both dark, the one on the "
                        "left when you look along the board's long side (its x axis) from that side")
    g.add_argument("--board-yaw-deg", type=float, default=0.0,
                   help="azimuth of the board's x axis from lab x, counter-clockwise seen from above [deg]")
    g.add_argument("--origin-sd-mm", type=float, default=0.0, help="uncertainty of each origin coordinate [mm]")
    g.add_argument("--yaw-sd-deg", type=float, default=0.0, help="uncertainty of the yaw [deg]")
    g.add_argument("--tilt-sd-deg", type=float, default=0.0,
                   help="how far from level the board may lie, about each horizontal axis [deg]")


#: the help of every protocol argument
PROTOCOL_HELP = "protocol TOML file, or a bundled protocol's name ('gyrorig protocols' lists them)"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (exposed for documentation and tests)."""
    p = argparse.ArgumentParser(prog="gyrorig", description="experiment design and data fitting for air-bearing gyroscope rigs")
    talk = p.add_mutually_exclusive_group()
    talk.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    talk.add_argument("-q", "--quiet", action="store_true",
                      help="for scripts: no progress and no summary, only errors on stderr and the output asked for "
                           "(--json); the exit code says how it went")
    p.add_argument("--version", action="version", version=f"gyrorig {__version__}")
    p.add_argument("--debug", action="store_true", help="show the traceback of an unexpected error")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="integrate a protocol's scene; write trajectory.csv and manifest.json")
    s.add_argument("protocol", help=PROTOCOL_HELP)
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--method", default="auto", choices=["auto", "exact", *METHODS],
                   help="integration method (default: chosen from the scene); 'exact' for undamped scenes")
    s.add_argument("--rtol", type=float, default=None, help="relative tolerance (default per method)")
    s.add_argument("--atol", type=float, default=None, help="absolute tolerance (default rtol/100)")
    s.add_argument("--duration", type=float, default=None, help="override scene.duration_s [s]")
    s.add_argument("--rate", type=float, default=None, help="output sample rate [Hz]")
    s.set_defaults(func="_cmd_simulate")

    b = sub.add_parser("bench", help="benchmarks that print figures")
    bsub = b.add_subparsers(dest="bench", required=True)
    bm = bsub.add_parser("methods", help="error against the exact solution and wall time of each method")
    bm.add_argument("protocol")
    bm.add_argument("--duration", type=float, default=10.0, help="simulated time [s] (default 10)")
    bm.add_argument("--rate", type=float, default=100.0, help="comparison sample rate [Hz]")
    bm.add_argument("--methods", nargs="+", default=None, help="methods to run (default: all but RK23)")
    bm.add_argument("--rtol", type=float, default=None, help="one tolerance for all methods")
    bm.add_argument("--repeats", type=int, default=1, help="median of this many timings")
    bm.add_argument("--out", default=None, help="also write methods.csv here")
    bm.set_defaults(func="_cmd_bench_methods")
    ba = bsub.add_parser("accuracy", help="work-precision study: error against wall time of every method")
    ba.add_argument("--quick", action="store_true", help="two scenes, short tolerance ladders (< 1 minute)")
    ba.add_argument("--out", default=None, help="output directory (default ./bench-accuracy)")
    ba.set_defaults(func="_cmd_bench_accuracy")
    bs = bsub.add_parser("stability", help="stiff and extreme cases: invariants, agreement, verdict per case")
    bs.add_argument("--quick", action="store_true", help="shorter runs (long run: 1e4 instead of 1e6 spin periods)")
    bs.add_argument("--out", default=None, help="output directory (default ./bench-stability)")
    bs.set_defaults(func="_cmd_bench_stability")
    br = bsub.add_parser("render", help="rendering and encoding throughput (frames per second)")
    br.add_argument("--frames", type=int, default=100, help="frames per measurement")
    br.add_argument("--out", default=None, help="also write render.csv here")
    br.set_defaults(func="_cmd_bench_render")
    bt = bsub.add_parser("track", help="tracking precision against the Cramer-Rao bound, pull widths, speed")
    bt.add_argument("--duration", type=float, default=1.0, help="video length [s] (default 1)")
    bt.add_argument("--quick", action="store_true", help="640x480 only")
    bt.add_argument("--out", default=None, help="also write track.csv here")
    bt.set_defaults(func="_cmd_bench_track")
    bv = bsub.add_parser("variants", help="tracking footage unlike the tracker's own assumptions: disc markers, "
                                          "rotor dots, gamma, mp4, rolling shutter, a plain top, a dim tip")
    bv.add_argument("--variants", nargs="+", default=None, help="variants to run (default: all)")
    bv.add_argument("--duration", type=float, default=1.0, help="video length [s] (default 1)")
    bv.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    bv.add_argument("--background-video", default=None,
                    help="a real recording to play behind the rig: adds the phone-video variant (e.g. OpenCV's sample "
                         "clips, Debian's opencv-doc: box.mp4, cup.mp4, vtest.avi)")
    bv.add_argument("--video-start", type=float, default=0.0, help="where in the recording to start [s] (default 0)")
    bv.add_argument("--out", default=None, help="also write variants.csv here")
    bv.set_defaults(func="_cmd_bench_variants")

    bi = bsub.add_parser("identify", help="identification from simulated lab tables: pulls over noisy draws, exact "
                         "models against the fast-top formulas")
    bi.add_argument("--rigs", nargs="+", default=None, help="synthetic rigs (default: all)")
    bi.add_argument("--draws", type=int, default=30, help="noisy draws per rig (default 30)")
    bi.add_argument("--seed", type=int, default=0, help="seed of the draws")
    bi.add_argument("--out", default=None, help="also write identify_pulls.csv here")
    bi.set_defaults(func="_cmd_bench_identify")

    bsm = bsub.add_parser("smooth", help="compiled smoother against filterpy: speed and agreement")
    bsm.add_argument("--frames", type=int, default=100_000, help="frames for the compiled path (default 100000)")
    bsm.add_argument("--filterpy-frames", type=int, default=20_000, help="frames for filterpy (default 20000)")
    bsm.set_defaults(func="_cmd_bench_smooth")
    bl = bsub.add_parser("length", help="how the record checks, smoothing and fit grow with the record's length")
    bl.add_argument("protocol", nargs="?", default="air-cushion-heavy-top",
                    help="a bundled protocol's name (default air-cushion-heavy-top)")
    bl.add_argument("--frames", type=int, nargs="+", default=[1000, 4000, 16000],
                    help="record lengths in frames (default 1000 4000 16000)")
    bl.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30: a phone's default)")
    bl.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    bl.add_argument("--out", default=None, help="also write length.csv here")
    bl.set_defaults(func="_cmd_bench_length")
    bf = bsub.add_parser("fit", help="Monte Carlo of render -> track -> smooth -> fit: pulls, bias, sd / CRB")
    bf.add_argument("--scenes", nargs="+", default=None, help="bundled protocol names (default: three rigs)")
    bf.add_argument("--seeds", type=int, default=None, help="runs per scene (default 40; 4 with --quick)")
    bf.add_argument("--duration", type=float, default=2.0, help="video length [s] (default 2)")
    bf.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    bf.add_argument("--first-seed", type=int, default=0, help="seeds run from this one (default 0)")
    bf.add_argument("--terms", choices=("planned", "data"), default="planned",
                    help="'planned' (default): each scene's model terms are chosen once by the plan for the "
                         "record length, before the runs; 'data': by chi-square tests in each run")
    bf.add_argument("--quick", action="store_true", help="one scene, 4 seeds")
    bf.add_argument("--phone", default=None, metavar="PHOTO",
                    help="record each video as a phone would, in front of this scikit-image photograph (coffee, "
                         "brick, astronaut, camera, rocket, gravel, chelsea): gamma 2.2, HEVC, jittered times, "
                         "dropped frames, no sensor numbers (needs scikit-image)")
    bf.add_argument("--readout-ms", type=float, default=0.0, metavar="MS",
                    help="with --phone: the phone's rolling shutter reads its rows over this many ms, which camera.json "
                         "does not state (the fit finds it)")
    bf.add_argument("--datasheet-focal-sd", type=float, default=None, metavar="REL",
                    help="no calibration and no fiducials: the camera 0.2 m off the vertical, its focal length drawn "
                         "and stated with this relative sd (0.05: a data sheet's 5 %%), the placement known to 3 cm; "
                         "the pose and the focal length from the tip's motion (pose --video)")
    bf.add_argument("--out", default=None, help="also write runs.csv and fit.csv here")
    bf.add_argument("--combine", nargs="+", default=None, metavar="DIR",
                    help="run nothing: summarise the runs.csv of earlier --out batches together "
                         "(batches must have distinct seeds)")
    bf.set_defaults(func="_cmd_bench_fit")

    pl = sub.add_parser("plan", help="what a rig and camera will measure: resolution, expected errors, advice")
    pl.add_argument("protocol", nargs="?", help=PROTOCOL_HELP)
    pl.add_argument("--json", action="store_true", help="print JSON")
    pl.add_argument("--out", default=None, help="write plan.json (and sweep tables/plots) here")
    pl.add_argument("--duration", type=float, default=None, help="recording length [s] (default: scene.duration_s, at most 20)")
    pl.add_argument("--draws", type=int, default=None, metavar="N",
                    help="noisy records fitted in full to check that the fit converges and is linear over the noise "
                         "at this length (default 8; 0 skips)")
    pl.add_argument("--seed", type=int, default=0, help="seed of those draws")
    pl.add_argument("--monte-carlo", type=int, default=0, metavar="N",
                    help="confirm the expected errors with N runs of render -> track -> smooth -> fit")
    pl.add_argument("--mc-duration", type=float, default=2.0, help="video length of each Monte Carlo run [s]")
    pl.add_argument("--scheduler", default=None, help="Dask scheduler address for the Monte Carlo (gyrorig[dask])")
    pl.add_argument("--sweep", nargs="+", default=None, metavar="KEY=START:STOP:N",
                    help="scan protocol keys, e.g. launch.spin_rate_rad_s=200:800:7 camera.fps=50:400:8")
    pl.set_defaults(func="_cmd_plan")

    t = sub.add_parser("theory", help="the paper's predictions for a scene, or --validate them all")
    t.add_argument("protocol", nargs="?", help=PROTOCOL_HELP)
    t.add_argument("--json", action="store_true", help="print JSON (keys carry units)")
    t.add_argument("--no-simulate", action="store_true", help="skip the simulated damped tilt rate")
    t.add_argument("--validate", action="store_true", help="judge every formula against the simulator over sweeps")
    t.add_argument("--quick", action="store_true", help="with --validate: small sweeps (seconds)")
    t.add_argument("--out", default=None, help="with --validate: output directory (default ./theory-validation)")
    t.set_defaults(func="_cmd_theory")

    r = sub.add_parser("render", help="synthetic video of a protocol's scene, with truth and calibration images")
    r.add_argument("protocol", help=PROTOCOL_HELP + " with [camera] and [markers]")
    r.add_argument("--out", required=True, help="output directory")
    r.add_argument("--seed", type=int, default=0, help="noise seed (same seed, same bits)")
    r.add_argument("--codec", choices=["lossless", "raw", "mp4"], default="lossless",
                   help="lossless: video.mkv (FFV1); raw: video.avi (uncompressed 8-bit, 1.5 MB per 1440x1080 frame, "
                        "decodes ~50x faster); mp4: video.mp4 (mp4v, 8-bit, lossy)")
    r.add_argument("--duration", type=float, default=None, help="override scene.duration_s [s]")
    r.add_argument("--calibration-views", type=int, default=12, help="checkerboard images (0: none)")
    r.add_argument("--hold", type=float, default=0.0, metavar="S",
                   help="the top held still (its rotor spinning) for S seconds before its release, as a phone records "
                        "from before it; the video is S longer [s] (default 0)")
    r.set_defaults(func="_cmd_render")

    cal = sub.add_parser("calibrate", help="camera calibration from checkerboard images (OpenCV)")
    cal.add_argument("images", help="directory of checkerboard images")
    cal.add_argument("--board", required=True, help="inner corners COLSxROWS, e.g. 9x6")
    cal.add_argument("--square-mm", type=float, required=True, help="square size [mm]")
    cal.add_argument("--out", required=True, help="camera.json to write")
    cal.add_argument("--lens-model", default="auto", choices=["auto", "k1k2", "k1k2k3"],
                     help="distortion model: k3 held at 0, k3 free, or 'auto' (default): the views choose by "
                          "leave-one-view-out reprojection error")
    cal.add_argument("--pose-image", default=None,
                     help="also the pose: one image of the same board lying face up at --board-origin-mm (not one of "
                          "the calibration views)")
    add_board_placement_options(cal)
    cal.set_defaults(func="_cmd_calibrate")

    po = sub.add_parser("pose", help="the camera's pose relative to the pivot, into a copy of camera.json: from one "
                        "image of a checkerboard lying at a known place, or from the tip's motion in a video")
    po.add_argument("--camera", required=True, help="camera.json with the intrinsics (from 'gyrorig calibrate')")
    po.add_argument("--board-image", default=None, help="the image of the board lying face up at --board-origin-mm")
    po.add_argument("--board", default="9x6", help="inner corners COLSxROWS, one odd and one even (default 9x6)")
    po.add_argument("--square-mm", type=float, default=None, help="square size [mm] (with --board-image)")
    po.add_argument("--video", default=None,
                    help="instead of a board: a video (or image folder) of the rig; the pose is fitted jointly with "
                         "the tip's motion (a fixed pivot, a steady precession about the vertical, nutation)")
    po.add_argument("--protocol", default=None,
                    help="with --video: the protocol (the tip marker; its [camera] placement is the rough start)")
    add_board_placement_options(po)
    add_clip_options(po)
    m = po.add_argument_group("azimuth origin of a pose from the motion (default: phi's slow part 0 at the first frame)")
    m.add_argument("--azimuth-mark-px", default=None, metavar="X,Y",
                   help="with --video: a lab mark's position in the video's image [px]; the pose is turned about "
                        "the vertical so that the mark lies at the azimuth of --mark-position-mm")
    m.add_argument("--mark-position-mm", default=None, metavar="X,Y,Z",
                   help="the mark's position relative to the pivot (z up) [mm], e.g. a dot on the table")
    m.add_argument("--mark-sd-px", type=float, default=1.0, help="uncertainty of each mark pixel coordinate (default 1)")
    m.add_argument("--mark-position-sd-mm", type=float, default=1.0,
                   help="uncertainty of each mark position coordinate [mm] (default 1)")
    po.add_argument("--out", required=True, help="camera.json to write (the input's keys, with the pose)")
    po.set_defaults(func="_cmd_pose", out_is_file=True)

    k = sub.add_parser("track", help="track the markers: video -> angles.csv, markers.csv")
    k.add_argument("video", help="any video FFmpeg can decode, a folder of PNG/TIFF/BMP/JPEG images in name order "
                                 "(frame times from its timestamps.csv: frame, t_s; else camera.json's fps), a "
                                 "multi-page TIFF stack (times from NAME.timestamps.csv beside it), or the "
                                 "tip's pixel track from another tool: an OSP Tracker .trk, or a CSV with frame, t_s, "
                                 "x_px, y_px[, sigma_px]")
    k.add_argument("--camera", required=True, help="camera.json with intrinsics and the pose relative to the pivot")
    k.add_argument("--protocol", required=True, help="protocol with the [markers] geometry")
    k.add_argument("--out", required=True, help="output directory")
    add_capture_fps(k)
    add_clip_options(k)
    k.add_argument("--track-name", default=None,
                   help="with a Tracker .trk holding several point masses: the tip's track's name")
    k.add_argument("--tip-only", action="store_true",
                   help="skip the frame's off-axis dots (no psi_rad; 10-25 %% less tracking time)")
    k.add_argument("--overlay", action="store_true",
                   help="also write overlay.png: a contact sheet of frames with the tip as found, its path and "
                        "the quality flags, to see without any truth that the tracker followed the tip")
    k.set_defaults(func="_cmd_track")

    sm = sub.add_parser("smooth", help="Kalman/RTS smoothing of angles.csv (noise levels by maximum likelihood)")
    sm.add_argument("angles", help="angles.csv from 'gyrorig track'")
    sm.add_argument("--out", required=True, help="output directory (smoothed.csv, smooth.json)")
    sm.set_defaults(func="_cmd_smooth")

    f = sub.add_parser("fit", help="least-squares fit of angles.csv with the scene's model, against theory")
    f.add_argument("angles", help="angles.csv from 'gyrorig track'")
    f.add_argument("--protocol", required=True, help=PROTOCOL_HELP + " (decides the model)")
    f.add_argument("--out", required=True, help="output directory (fit.json, fit.png, fit_residuals.csv)")
    for name, where in (("--start", "first"), ("--end", "last")):
        f.add_argument(name, default=None, metavar="T", help=f"the {where} moment of the table to fit: a time on its "
                       "own clock (its t_s column, seconds: 12.5) or a frame (its frame column: 300f)")
    add_fit_options(f)
    f.set_defaults(func="_cmd_fit")

    an = sub.add_parser("analyze", help="track -> smooth -> fit -> report.html; a folder or manifest CSV for a batch")
    an.add_argument("video", help="a video, a folder of videos, or a manifest CSV (video, protocol[, camera])")
    an.add_argument("--camera", default=None, help="camera.json")
    an.add_argument("--protocol", default=None, help=PROTOCOL_HELP)
    an.add_argument("--out", required=True, help="output directory")
    add_capture_fps(an)
    add_clip_options(an)
    add_fit_options(an)
    an.add_argument("--frame-dots", action="store_true",
                    help="also track the frame's off-axis dots (psi_rad in track/angles.csv; the fit does not use it, "
                         "and it takes 10-40 %% more tracking time)")
    an.set_defaults(func="_cmd_analyze")

    idf = sub.add_parser("identify", help="a rig's parameters with covariance from its measurements: fit.json files "
                         "and lab tables (spin-down, precession, nutation)")
    idf.add_argument("inputs", nargs="+", help="fit.json files and CSV tables (units in the column names; the kind in "
                     "a 'kind' column or the file name: spin_down, precession, nutation)")
    idf.add_argument("--protocol", required=True, help="prior protocol: the known numbers (mass, g) and priors "
                     "{ value, sd } for the rest")
    idf.add_argument("--out", required=True, help="output directory (identified.toml, identify.json, identify.png)")
    idf.set_defaults(func="_cmd_identify")

    pr = sub.add_parser("protocols", help="the bundled protocols: names (usable wherever a protocol file is asked "
                                          "for) and descriptions")
    pr.set_defaults(func="_cmd_protocols")

    d = sub.add_parser("demo", help="the chain on the bundled air-cushion rig: simulate, theory, render, track, smooth, fit, report")
    d.add_argument("--out", default="gyrorig-demo", help="output directory (default ./gyrorig-demo)")
    d.add_argument("--duration", type=float, default=10.0, help="simulated time [s] (default 10)")
    d.add_argument("--video-duration", type=float, default=3.0, help="length of the rendered video [s] (default 3)")
    d.set_defaults(func="_cmd_demo")
    cal.set_defaults(out_is_file=True)
    _add_overwrite(sub)
    return p


def add_clip_options(parser) -> None:
    """``--start`` and ``--end``: the part of a recording to use (seconds from its first frame, or frames)."""
    for name, where in (("--start", "first"), ("--end", "last")):
        parser.add_argument(name, default=None, metavar="T",
                            help=f"the {where} moment of the recording to use: seconds from its first frame as a "
                                 "player shows them (12.5), or a frame counted from 0 (300f); the file's own frame "
                                 "numbers and times are kept")


def clipped(video, args: argparse.Namespace):
    """The video, or the part of it between ``--start`` and ``--end`` (:class:`gyrorig.tracking.sources.Clip`)."""
    start, end = getattr(args, "start", None), getattr(args, "end", None)
    if start is None and end is None:
        return video
    from ..tracking.sources import Clip, parse_cut

    return Clip(video, None if start is None else parse_cut(start, "--start"),
                None if end is None else parse_cut(end, "--end"))


def add_capture_fps(parser) -> None:
    """``--capture-fps``: the rate a slow-motion file was captured at (its stored rate is lower)."""
    parser.add_argument("--capture-fps", type=float, default=None,
                        help="the rate the frames were captured at, when the file stores them at a lower one (slow "
                             "motion: captured at 240, stored at 30); overrides camera.json's capture_fps")


def _add_overwrite(sub) -> None:
    """``--overwrite`` on every command that writes an ``--out``: without it an existing non-empty output is refused."""
    for parser in sub.choices.values():
        dests = {a.dest for a in parser._actions}
        if "out" in dests and "overwrite" not in dests:
            parser.add_argument("--overwrite", action="store_true",
                                help="replace an existing --out whole (without it an existing non-empty output is "
                                     "refused)")
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                _add_overwrite(action)
