"""Fuzz suite (issue 23): mutated protocols, camera files, angle tables, manifests, videos and options, run
through the command line in-process.

Every case must end with an exit code in {0, 2, 3}, no traceback, nothing under the final --out after a
failure, and the inputs unchanged.  The cases come from a seeded generator (a table of mutations per input
kind, issue 33's among them: inputs nested too deep, output folders that would replace the user's files, lab
tables): ``-m slow`` runs 560 of them, the default suite a fixed sample of 40.
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
import warnings
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from gyrorig.cli import main

from conftest import PROTOCOL_DIR

AIR = PROTOCOL_DIR / "air-cushion-heavy-top.toml"
B2 = PROTOCOL_DIR / "eddy-damped-top-b2.toml"
ANGLES = Path(__file__).parent / "data" / "b2_seed104_640x480_angles.csv"

#: values a number can be replaced by
BAD_VALUES = [0, -1, -1e-300, 1e300, float("nan"), float("inf"), -float("inf"), "text", True, [], [1, 2], {"a": 1},
              "", 1e-300, 2**63]


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(v)


def _toml(doc: dict, prefix: str = "") -> str:
    """A small TOML writer for the protocol documents (tables of scalars, lists and sub-tables)."""
    plain = {k: v for k, v in doc.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in doc.items() if isinstance(v, dict)}
    lines = [f"[{prefix[:-1]}]"] if prefix else []
    lines += [f"{k} = {_toml_value(v)}" for k, v in plain.items()]
    lines += [_toml(v, prefix=f"{prefix}{k}.") for k, v in tables.items()]
    return "\n".join(lines) + "\n"


def _paths(doc: dict, prefix=()) -> list[tuple]:
    out = []
    for k, v in doc.items():
        if isinstance(v, dict):
            out += _paths(v, prefix + (k,))
        else:
            out.append(prefix + (k,))
    return out


def _set(doc: dict, path: tuple, value, delete: bool = False) -> dict:
    doc = json.loads(json.dumps(doc))
    d = doc
    for k in path[:-1]:
        d = d[k]
    if delete:
        d.pop(path[-1])
    else:
        d[path[-1]] = value
    return doc


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A rendered 0.1 s video with its camera.json and protocol, an angle table, a manifest: the good inputs."""
    from gyrorig.camera import with_image_size
    from gyrorig.protocols import load_protocol
    from gyrorig.render import render_video

    root = tmp_path_factory.mktemp("fuzz-base")
    p = with_image_size(load_protocol(B2), 640, 480)
    render_video(p, root / "render", seed=1, duration_s=0.1, calibration_views=0)
    text = B2.read_text()
    doc = tomllib.loads(text)
    doc["camera"]["width_px"], doc["camera"]["height_px"] = 640, 480
    (root / "b2.toml").write_text(_toml(doc))
    return root


def _hash(paths) -> dict:
    out = {}
    for p in paths:
        p = Path(p)
        files = sorted(p.rglob("*")) if p.is_dir() else [p] if p.exists() else []
        for f in files:
            if f.is_file():
                out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


# ---------------------------------------------------------------- case families

def _protocol_case(rng, base: Path, case_dir: Path):
    source = [AIR, B2][rng.integers(2)]
    doc = tomllib.loads(source.read_text())
    paths = [p for p in _paths(doc) if p[0] in ("rig", "launch", "pivot", "scene", "camera", "markers")]
    path = paths[rng.integers(len(paths))]
    how = rng.integers(4)
    if how == 0:
        doc = _set(doc, path, None, delete=True)
    elif how == 1:
        doc = _set(doc, path[:-1] + ("unknown_key_xyz",), 1.0)
    else:
        doc = _set(doc, path, BAD_VALUES[rng.integers(len(BAD_VALUES))])
    proto = case_dir / "p.toml"
    proto.write_text(_toml(doc))
    command = rng.integers(4)
    out = case_dir / "out"
    if command == 0:
        return ["theory", str(proto), "--no-simulate"], [proto], None
    if command == 1:
        return ["simulate", str(proto), "--out", str(out), "--duration", "0.05", "--rate", "200"], [proto], out
    if command == 2:
        return ["plan", str(proto), "--duration", "0.5", "--draws", "0"], [proto], None
    return ["render", str(proto), "--out", str(out), "--duration", "0.02", "--calibration-views", "0"], [proto], out


CAMERA_KEYS = ["camera_matrix", "dist_coeffs", "exposure_s", "fps", "image_size", "psf_sigma_px", "readout_time_s",
               "rvec", "tvec", "sensor.gain_e_per_adu", "sensor.read_noise_e", "sensor.bit_depth", "sensor.gamma",
               "shutter", "motion_blur_samples"]


def _camera_case(rng, base: Path, case_dir: Path):
    cam = json.loads((base / "render" / "camera.json").read_text())
    key = CAMERA_KEYS[rng.integers(len(CAMERA_KEYS))].split(".")
    target = cam
    for k in key[:-1]:
        target = target[k]
    how = rng.integers(5)
    if how == 0:
        target.pop(key[-1], None)
    elif how == 1 and isinstance(target.get(key[-1]), list):
        v = target[key[-1]]
        target[key[-1]] = v[: rng.integers(len(v))] if len(v) else [1.0]  # a short array
    elif how == 2 and isinstance(target.get(key[-1]), list):
        target[key[-1]] = target[key[-1]] + [0.0] * int(rng.integers(1, 4))  # a long one
    else:
        target[key[-1]] = BAD_VALUES[rng.integers(len(BAD_VALUES))]
    camera = case_dir / "camera.json"
    text = json.dumps(cam, allow_nan=True)
    if rng.integers(10) == 0:
        text = text[: len(text) // 2]  # truncated JSON
    camera.write_text(text)
    out = case_dir / "out"
    return (["track", str(base / "render" / "video.mkv"), "--camera", str(camera), "--protocol", str(base / "b2.toml"),
             "--out", str(out), "--tip-only"], [camera, base / "render"], out)


def _angles_case(rng, base: Path, case_dir: Path):
    a = pd.read_csv(ANGLES)
    how = rng.integers(9)
    col = a.columns[rng.integers(len(a.columns))]
    if pd.api.types.is_integer_dtype(a[col]) and how in (1, 7):
        a[col] = a[col].astype(float)  # NaN and inf cells in an integer column (frame): as a spreadsheet writes them
    if how == 0:
        a = a.drop(columns=[col])
    elif how == 1:
        a.loc[rng.integers(len(a), size=20), col] = np.nan
    elif how == 2:
        a[col] = a[col].astype(object)
        a.loc[rng.integers(len(a)), col] = "x"
    elif how == 3:
        a = a.iloc[::-1]
    elif how == 4:
        a["t_s"] = a["t_s"].iloc[0]
    elif how == 5:
        a["theta_sigma_rad"] = [0.0, -1.0, np.inf][rng.integers(3)]
    elif how == 6:
        a = a.iloc[: rng.integers(0, 12)]
    elif how == 7:
        a.loc[rng.integers(len(a), size=5), col] = [1e300, -1e300, np.inf, -np.inf, 0.0]
    else:
        a = a.iloc[rng.permutation(len(a))[: len(a) // 2]].sort_index()
    csv = case_dir / "angles.csv"
    a.to_csv(csv, index=False)
    out = case_dir / "out"
    if rng.integers(2):
        return ["fit", str(csv), "--protocol", str(B2), "--out", str(out)], [csv], out
    return ["smooth", str(csv), "--out", str(out)], [csv], out


def _manifest_case(rng, base: Path, case_dir: Path):
    video, cam = base / "render" / "video.mkv", base / "render" / "camera.json"
    rows = [{"video": str(video), "protocol": str(base / "b2.toml"), "camera": str(cam)}]
    how = rng.integers(6)
    frame = pd.DataFrame(rows)
    if how == 0:
        frame = frame.iloc[0:0]
    elif how == 1:
        frame.loc[0, "protocol"] = ""
    elif how == 2:
        frame = frame.drop(columns=["video"])
    elif how == 3:
        frame.loc[0, "video"] = str(case_dir / "missing.mkv")
    elif how == 4:
        frame.loc[0, "camera"] = str(base / "b2.toml")  # a protocol where the camera should be
    else:
        frame = pd.concat([frame, frame.assign(video="")])
    manifest = case_dir / "manifest.csv"
    frame.to_csv(manifest, index=False)
    out = case_dir / "out"
    return ["analyze", str(manifest), "--out", str(out)], [manifest, base / "render"], out


def _video_case(rng, base: Path, case_dir: Path):
    good = (base / "render" / "video.mkv").read_bytes()
    how = rng.integers(5)
    video = case_dir / "video.mkv"
    if how == 0:
        video.write_bytes(good[: len(good) // int(rng.integers(2, 10))])
    elif how == 1:
        video.write_bytes(b"")
    elif how == 2:
        video.write_bytes(rng.integers(0, 256, size=5000, dtype=np.uint8).tobytes())
    else:
        size = (640, 480) if how == 3 else (320, 240)
        video = case_dir / "video.avi"
        w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 200.0, size, isColor=False)
        for _ in range(10):
            w.write(np.zeros(size[::-1], np.uint8))  # blacked out (and the wrong size when 320 x 240)
        w.release()
    out = case_dir / "out"
    return (["track", str(video), "--camera", str(base / "render" / "camera.json"), "--protocol",
             str(base / "b2.toml"), "--out", str(out)], [video, base / "render"], out)


OPTION_CASES = [
    ["simulate", str(AIR), "--duration", "{bad}", "--out", "{out}"],
    ["simulate", str(AIR), "--rate", "{bad}", "--duration", "0.1", "--out", "{out}"],
    ["simulate", str(AIR), "--rtol", "{bad}", "--duration", "0.1", "--out", "{out}"],
    ["render", str(AIR), "--duration", "{bad}", "--out", "{out}"],
    ["render", str(AIR), "--seed", "{bad}", "--duration", "0.02", "--calibration-views", "0", "--out", "{out}"],
    ["render", str(AIR), "--calibration-views", "{bad}", "--duration", "0.02", "--out", "{out}"],
    ["plan", str(AIR), "--duration", "{bad}", "--draws", "0"],
    ["plan", str(AIR), "--draws", "{bad}", "--duration", "0.5"],
    ["plan", str(AIR), "--sweep", "camera.fps={bad}:100:2", "--duration", "0.5", "--draws", "0"],
    ["plan", str(AIR), "--sweep", "camera.fps=50:100:{bad}", "--duration", "0.5", "--draws", "0"],
    ["plan", str(AIR), "--sweep", "camera.fps=50:100:100000000", "--duration", "0.5", "--draws", "0"],
    ["demo", "--video-duration", "{bad}", "--out", "{out}"],
    ["calibrate", "{dir}", "--board", "{bad}x6", "--square-mm", "20", "--out", "{out}"],
    ["calibrate", "{dir}", "--board", "9x6", "--square-mm", "{bad}", "--out", "{out}"],
    ["fit", str(ANGLES), "--protocol", str(B2), "--out", "{out}", "--fix", "nutation_frequency_rad_s={bad}"],
    ["fit", str(ANGLES), "--protocol", str(B2), "--out", "{out}", "--prior", "precession_rate_rad_s=1+-{bad}"],
    ["bench", "variants", "--duration", "{bad}"],
]
BAD_OPTIONS = ["0", "-1", "nan", "inf", "-inf", "1e308", "abc", "", "1e-320", "-0"]


def _option_case(rng, base: Path, case_dir: Path):
    template = OPTION_CASES[rng.integers(len(OPTION_CASES))]
    bad = BAD_OPTIONS[rng.integers(len(BAD_OPTIONS))]
    out = case_dir / "out"
    argv = [a.replace("{bad}", bad).replace("{out}", str(out)).replace("{dir}", str(case_dir)) for a in template]
    return argv, [], out if "{out}" in template else None


def _nesting_case(rng, base: Path, case_dir: Path):
    """A protocol or camera file nested thousands of levels deep (the parsers recurse: RecursionError, exit 3)."""
    depth = int(rng.integers(2000, 20000))
    if rng.integers(2):
        proto = case_dir / "deep.toml"
        proto.write_text(AIR.read_text() + "\n[deep]\nx = " + "[" * depth + "]" * depth + "\n")
        return ["theory", str(proto), "--no-simulate"], [proto], None
    camera = case_dir / "deep.json"
    camera.write_text('{"a": ' * depth + "1" + "}" * depth)
    out = case_dir / "out"
    return (["track", str(base / "render" / "video.mkv"), "--camera", str(camera), "--protocol", str(base / "b2.toml"),
             "--out", str(out), "--tip-only"], [camera], out)


def _place_case(rng, base: Path, case_dir: Path):
    """--out where replacing it would remove what gyrorig did not write: the working folder (the case's folder),
    a folder above it, a folder of the user's own files, a folder holding an input reached through a symbolic
    link; with --overwrite or without."""
    mine = case_dir / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's")
    (case_dir / "keep.txt").write_text("the user's too")
    link = case_dir / "link"
    link.symlink_to(mine)
    how = int(rng.integers(4))
    out = [".", "..", str(mine), str(mine)][how]
    if how == 3:
        argv = ["smooth", str(link / "notes.txt"), "--out", out]
    else:
        argv = ["simulate", str(AIR), "--out", out, "--duration", "0.02", "--rate", "100"]
    if rng.integers(4):
        argv.append("--overwrite")
    return argv, [mine, case_dir / "keep.txt"], None


def _table_case(rng, base: Path, case_dir: Path):
    """A lab table for identify with a unit, a range or a cell made wrong."""
    rows = ["spin_rev_per_min,precession_period_s,tilt_deg,added_mass_g", "3000,3.1,90,0", "3500,2.7,90,20",
            "4000,2.4,80,0", "4500,2.1,85,20"]
    how = int(rng.integers(6))
    if how == 0:
        rows[0] = rows[0].replace("_rev_per_min", ["_furlongs", "_s", "_kg", ""][rng.integers(4)])
    elif how == 1:
        rows[2] = rows[2].replace(",90,", f",{['200', '-30', 'nan', 'inf', 'ninety'][rng.integers(5)]},")
    elif how == 2:
        rows = rows[: int(rng.integers(1, 2))]
    elif how == 3:
        rows[1] = rows[1].replace("3.1", ["0", "-1", "", "1e308"][rng.integers(4)])
    elif how == 4:
        rows[0] += ",added_mass_g"
    table = case_dir / "precession.csv"
    table.write_text("\n".join(rows) + "\n")
    prior = case_dir / "prior.toml"
    prior.write_text(AIR.read_text().replace("inertia_transverse_kg_m2 = 3.839e-3",
                                             "inertia_transverse_kg_m2 = { value = 4.0e-3, sd = 1.0e-3 }"))
    out = case_dir / "out"
    return ["identify", str(table), "--protocol", str(prior), "--out", str(out)], [table, prior], out


#: unit slips a user makes in a protocol: the keys scaled together and the factor (each value stays in range)
UNIT_SLIPS = [
    ((("rig", "inertia_axial_kg_m2"), ("rig", "inertia_transverse_kg_m2"), ("rig", "frame_axial_inertia_kg_m2")),
     1e7),  # g cm^2
    ((("rig", "inertia_axial_kg_m2"), ("rig", "inertia_transverse_kg_m2"), ("rig", "frame_axial_inertia_kg_m2")),
     1e4),  # kg cm^2
    ((("rig", "mass_kg"),), 1000.0),  # g
    ((("rig", "com_distance_m"), ("rig", "inertia_transverse_kg_m2")), 100.0),  # cm (with an inertia kept possible)
    ((("rig", "gravity_m_s2"),), 100.0),  # cm/s^2
    ((("launch", "spin_rate_rad_s"),), 60.0 / (2.0 * np.pi)),  # rev/min
    ((("markers", "tip", "position_m"),), 100.0),  # cm
]


def _units_case(rng, base: Path, case_dir: Path):
    source = [AIR, B2][rng.integers(2)]
    doc = tomllib.loads(source.read_text())
    keys, factor = UNIT_SLIPS[rng.integers(len(UNIT_SLIPS))]
    for path in keys:
        node = doc
        for p in path[:-1]:
            node = node[p]
        v = node[path[-1]]
        node[path[-1]] = [x * factor for x in v] if isinstance(v, list) else v * factor
    proto = case_dir / "p.toml"
    proto.write_text(_toml(doc))
    if rng.integers(2):
        return ["theory", str(proto), "--no-simulate"], [proto], None
    out = case_dir / "out"
    return ["fit", str(ANGLES), "--protocol", str(proto), "--out", str(out)], [proto], out


def _gimbal_case(rng, base: Path, case_dir: Path):
    """A gyro in gimbals: its [gimbal] section or a [[configuration]] of the prior made wrong (or left good), run
    through identify on a nutation table or through simulate."""
    gimbal = {"outer_inertia_kg_m2": "{ value = 3e-4, sd = 1.5e-4 }", "cross_inertia_kg_m2": "2.6e-3"}
    how = int(rng.integers(7))
    if how == 0:
        gimbal[["outer_inertia_kg_m2", "cross_inertia_kg_m2"][rng.integers(2)]] = \
            ["-1e-4", "0.0", '"heavy"', "nan", "inf", "1e300", "{ value = 3e-4, sd = -1.0 }"][rng.integers(7)]
    elif how == 1:
        gimbal[["inner_inertia_kg_m2", "outer_inertia_g_cm2", "gimbal"][rng.integers(3)]] = "1.0"
    text = AIR.read_text().replace("com_distance_m = 0.07715", f"com_distance_m = {['0.0', '0.02'][rng.integers(2)]}")
    text += "\n[gimbal]\n" + "".join(f"{k} = {v}\n" for k, v in gimbal.items())
    if how == 2:
        text += "\n[[configuration]]\n" + ['name = "a"\ntables = ["nutation.csv"]\n[configuration.rig]\n'
                                            'inertia_transverse_kg_m2 = { value = 3e-3, sd = 5e-4 }\n',
                                            'name = "a"\ntables = "nutation.csv"\n',
                                            'name = 3\ntables = ["nutation.csv"]\n',
                                            'name = "a"\ntables = ["nutation.csv"]\n[configuration.gimbal]\n'
                                            'outer_inertia_kg_m2 = { value = "x", sd = 1 }\n'][rng.integers(4)]
    prior = case_dir / "prior.toml"
    prior.write_text(text)
    if how == 3:
        out = case_dir / "sim"
        return ["simulate", str(prior), "--out", str(out), "--duration", ["0.5", "0", "-1"][rng.integers(3)],
                "--rate", "100"], [prior], out
    rows = ["spin_rad_s,tilt_deg,added_outer_inertia_g_cm2,nutation_frequency_rad_s,nutation_frequency_rad_s_sd",
            "250,90,0,33,0.1", "250,90,5000,31,0.1", "400,60,0,51,0.1", "400,90,5000,50,0.1"]
    if how == 4:
        rows[2] = rows[2].replace(",5000,", f",{['-5', 'x', 'nan'][rng.integers(3)]},")
    elif how == 5:
        rows[0] = rows[0].replace("_g_cm2", ["_kg", "_cm2", ""][rng.integers(3)])
    table = case_dir / "nutation.csv"
    table.write_text("\n".join(rows) + "\n")
    out = case_dir / "out"
    return ["identify", str(table), "--protocol", str(prior), "--out", str(out)], [table, prior], out


FAMILIES = [_protocol_case, _camera_case, _angles_case, _manifest_case, _video_case, _option_case, _nesting_case,
            _place_case, _table_case, _units_case, _gimbal_case]
#: families whose every case is bad input: exit 2
BAD_INPUT_FAMILIES = (_nesting_case, _place_case)


def _run_case(k: int, base: Path, tmp: Path, capsys, monkeypatch, caplog):
    rng = np.random.default_rng(1000 + k)
    family = FAMILIES[k % len(FAMILIES)]
    case_dir = tmp / f"case{k}"
    case_dir.mkdir()
    monkeypatch.chdir(case_dir)  # the working folder a case may name (--out .)
    argv, inputs, out = family(rng, base, case_dir)
    before = _hash(inputs)
    capsys.readouterr()
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # as on a user's terminal: warnings do not end a run
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse refuses a malformed option this way (usage and one line, exit 2)
            code = exc.code
    err = capsys.readouterr().err
    assert code in (0, 2, 3), (family.__name__, argv, code, err)
    if family in BAD_INPUT_FAMILIES:  # these are the user's input, never a failed computation
        assert code == 2, (family.__name__, argv, code, err)
    assert "Traceback" not in err, (family.__name__, argv, err)
    if code != 0:
        assert err.strip(), (family.__name__, argv)  # a failure says why, on stderr (-q shows nothing else)
        if out is not None and argv[0] == "analyze" and code == 3 and out.exists():
            # a batch keeps what it analysed: its summary names each failed video and why
            summary = pd.read_csv(out / "summary.csv")
            assert (summary.status != "ok").any() and summary.error.notna().any()
        elif out is not None:
            assert not out.exists(), (family.__name__, argv, code)
    assert _hash(inputs) == before, (family.__name__, argv)
    if family is _units_case:  # in range but in the wrong unit: refused, or run with a warning naming a scaled key
        assert code in (0, 2), (argv, code, err)
        if code == 0:
            doubted = [r for r in caplog.records if r.name == "gyrorig.protocols" and r.levelname == "WARNING"]
            assert doubted, (argv, err)
    leftovers = [p.name for p in case_dir.iterdir() if ".partial-" in p.name or ".old-" in p.name]
    assert not leftovers, (family.__name__, argv, leftovers)


#: the cases: -m slow runs them all, the default suite every 13th (48; 13 is prime to the number of families, so
#: the sample meets every family)
CASES = 616
SAMPLE_STEP = 13


@pytest.mark.parametrize("k", range(0, CASES, SAMPLE_STEP))
def test_fuzz_sample(k, base, tmp_path, capsys, monkeypatch, caplog):
    _run_case(k, base, tmp_path, capsys, monkeypatch, caplog)


@pytest.mark.slow
@pytest.mark.parametrize("k", [k for k in range(CASES) if k % SAMPLE_STEP])
def test_fuzz_all(k, base, tmp_path, capsys, monkeypatch, caplog):
    _run_case(k, base, tmp_path, capsys, monkeypatch, caplog)
