"""Issue 9, first half: every bad input and bench fault a user can cause, as the user meets it on the CLI.

One table of cases, each run through ``main([...])`` with file-descriptor capture (so that what C libraries
such as libjpeg print counts too): the documented exit status, exactly one line on stderr, naming the
option, file, field or device, and no traceback. The cases the issue found, plus the same kinds of case for
the commands and options other issues added (session schema, rig chained actions and shell, measure's
uncertainty flags, model's calibration flags, --sim, campaign run --json).
"""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import re
import shutil
import socket
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from drivers.sim.grbl.emulator import GrblEmulator
from stereo_bench.cli import main
from tests.campaigns import SMALL
from tests.real_data import OPENCV_SAMPLE

SAMPLE_LEFT, SAMPLE_RIGHT = str(OPENCV_SAMPLE / "left0*.jpg"), str(OPENCV_SAMPLE / "right0*.jpg")
PAIR = (str(OPENCV_SAMPLE / "left03.jpg"), str(OPENCV_SAMPLE / "right03.jpg"))


def _hd_calibration(directory: Path) -> Path:
    """The simulated rig's true 1920x1080 calibration (B = 100 mm)."""
    from stereo_bench.geometry import CameraModel
    from stereo_bench.vision.calibio import write_calibration
    from stereo_bench.vision.calibrate import StereoCalibration

    camera = CameraModel.from_sensor(focal_mm=4.0, pixel_um=3.0)
    D = camera.dist.reshape(1, -1)
    write_calibration(directory, StereoCalibration(K1=camera.K, D1=D, K2=camera.K, D2=D, R=np.eye(3),
                                                   T=np.array([-100.0, 0.0, 0.0]), image_size=camera.image_size))
    return directory


def _with_nan_in_T(source: Path, directory: Path) -> Path:
    """A copy of a calibration whose T has a '.nan' entry, as a hand edit would leave it."""
    shutil.copytree(source, directory)
    lines = (directory / "extrinsics.yml").read_text().splitlines()
    row = next(i for i in range(lines.index(next(l for l in lines if l.startswith("T:"))), len(lines))
               if "data:" in lines[i])
    lines[row] = re.sub(r"\[\s*[-+0-9.eE]+", "[ .nan", lines[row])
    (directory / "extrinsics.yml").write_text("\n".join(lines) + "\n")
    return directory


def _damage_session(source: Path, target: Path, change: Callable[[dict], dict | None]) -> Path:
    shutil.copytree(source, target)
    lines = (target / "documents.jsonl").read_text().splitlines()
    kept = [change(json.loads(line)) for line in lines]
    (target / "documents.jsonl").write_text("".join(json.dumps(doc) + "\n" for doc in kept if doc is not None))
    return target


def _second_move(doc: dict) -> bool:
    return doc.get("kind") == "move" and doc.get("config_id") == "B150_Z450_A90"


@pytest.fixture(scope="module")
def ctx(tmp_path_factory, small_reference, request) -> dict[str, str]:
    """Every input file the table needs, made once (and a local port another program listens on)."""
    root = tmp_path_factory.mktemp("errors")
    paths: dict[str, str] = {"root": str(root), "session": str(small_reference)}
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    request.addfinalizer(taken.close)
    paths["taken_port"] = str(taken.getsockname()[1])

    calib = root / "calib"
    assert main(["calibrate", "--board", "9x6", "--square", "30", "--left", SAMPLE_LEFT, "--right", SAMPLE_RIGHT,
                 "--out", str(calib)]) == 0
    paths["calib"] = str(calib)
    # The sample rig's calibration with its cameras turned 1 degree about x: vertical disparity ~9 px.
    from stereo_bench.vision.calibio import read_calibration, write_calibration

    good = read_calibration(calib)
    c, s = np.cos(np.radians(1.0)), np.sin(np.radians(1.0))
    turned = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ good.R
    write_calibration(root / "tilted", dataclasses.replace(good, R=turned, covariance=None))
    paths["tilted"] = str(root / "tilted")
    paths["hd"] = str(_hd_calibration(root / "hd"))
    paths["nan"] = str(_with_nan_in_T(calib, root / "nan"))

    # Damaged JPEGs: one truncated, one with bytes flipped in its entropy-coded data.
    jpegs = root / "jpegs"
    shutil.copytree(OPENCV_SAMPLE, jpegs, ignore=shutil.ignore_patterns("*1[0-9].jpg", "*.md", "SHA*"))
    truncated = (jpegs / "left03.jpg").read_bytes()
    (jpegs / "left03.jpg").write_bytes(truncated[: len(truncated) // 2])
    flipped = bytearray((jpegs / "right05.jpg").read_bytes())
    for k in range(len(flipped) // 3, len(flipped) // 3 + 400, 7):
        flipped[k] ^= 0x5A
    (jpegs / "right05.jpg").write_bytes(bytes(flipped))
    flipped_only = root / "flipped"
    shutil.copytree(jpegs, flipped_only)
    shutil.copy(OPENCV_SAMPLE / "left03.jpg", flipped_only / "left03.jpg")
    paths["jpegs"], paths["flipped"] = str(jpegs), str(flipped_only)
    import cv2

    for side, image in zip(("small_left", "small_right"), PAIR, strict=True):  # the pair at half size
        cv2.imwrite(str(root / f"{side}.png"), cv2.resize(cv2.imread(image), (320, 240)))
        paths[side] = str(root / f"{side}.png")

    # Campaign files.
    (root / "nonutf8.toml").write_bytes(b'name = "caf\xe9"\n' + SMALL.encode())
    (root / "rig_nonutf8.toml").write_bytes(b"# r\xe9glage\n[controller]\n")
    bring_up = SMALL.replace("[rig]\ntime_scale = 50", '[rig]\nkind = "grbl"\nport = "/dev/ttyNOPE9"')
    (root / "port_missing.toml").write_text(bring_up)
    (root / "a_file").write_text("not a directory")
    corrupt = root / "corrupt_calib"
    shutil.copytree(next((small_reference / "calib").glob("*/a1")), corrupt)
    (corrupt / "extrinsics.yml").write_text("%YAML:1.0\nR: [this is not\n")
    (root / "corrupt_calib.toml").write_text(SMALL + f'\n[extrinsics]\nmode = "fixed"\ncalib_dir = "{corrupt}"\n')

    # What `campaign plan` must refuse as `run` would (issue 9, second half B).
    (root / "manual_baseline.toml").write_text(SMALL + '\n[rig.quantities.baseline_mm]\naxis = "manual"\n')
    (root / "string_baseline.toml").write_text(SMALL.replace("baseline_mm = [100, 150]",
                                                             'baseline_mm = ["100", "1_50"]'))
    (root / "bool_baseline.toml").write_text(SMALL.replace("baseline_mm = [100, 150]", "baseline_mm = [true]"))
    (root / "homing_yes.toml").write_text(SMALL.replace("time_scale = 50", 'time_scale = 50\nhoming = "yes"'))
    (root / "sim_rig_v4l2.toml").write_text(SMALL.replace("[cameras.optics]", '[cameras]\nkind = "v4l2"\n'
                                                          'left = "usb-port:9-8"\nright = "usb-port:9-9"\n'
                                                          "[cameras.optics]"))
    many = ", ".join(f"{8 + k * 0.25:g}" for k in range(30_000))  # 8 to 7507.75 mm: each inside the plan's bounds
    (root / "too_many.toml").write_text(SMALL.replace("baseline_mm = [100, 150]", f"baseline_mm = [{many}]"))

    # Damaged sessions: a move missing, a move that does not match, a recorded config that no longer validates.
    paths["missing_move"] = str(_damage_session(small_reference, root / "missing_move",
                                                lambda d: None if _second_move(d) else d))

    def mismatch(doc: dict) -> dict:
        if _second_move(doc):
            doc["data"]["rig"]["baseline_mm"] = 151.0
        return doc

    paths["mismatch_move"] = str(_damage_session(small_reference, root / "mismatch_move", mismatch))

    def bad_config(doc: dict) -> dict:
        if doc["type"] == "start":
            doc["config"]["capture"]["frames_per_config"] = -1
        return doc

    paths["bad_config"] = str(_damage_session(small_reference, root / "bad_config", bad_config))
    _confinement_cases(small_reference, root, paths)
    return paths


ESCAPED = "../../ESCAPED"


def _escape_config_id(value):
    """A document with the configuration B100_Z450_A90 renamed to a path that leads out of a report."""
    if isinstance(value, dict):
        return {k: ESCAPED if k == "config_id" and v == "B100_Z450_A90" else _escape_config_id(v)
                for k, v in value.items()}
    return [_escape_config_id(v) for v in value] if isinstance(value, list) else value


def _confinement_cases(small_reference: Path, root: Path, paths: dict[str, str]) -> None:
    """Sessions whose ids or symlinks lead outside them, and a torn one (issue 9, 'What must exist' 2)."""
    (root / "small.toml").write_text(SMALL)
    paths["escaped_id"] = str(_damage_session(small_reference, root / "escaped_id", _escape_config_id))
    outside = root / "outside"
    outside.mkdir()
    docs = root / "docs_symlink"
    shutil.copytree(small_reference, docs)
    (docs / "documents.jsonl").rename(outside / "documents.jsonl")
    (docs / "documents.jsonl").symlink_to(outside / "documents.jsonl")
    frames = root / "frames_symlink"
    shutil.copytree(small_reference, frames)
    (frames / "frames" / "B100_Z450_A90").rename(outside / "frames_B100")
    (frames / "frames" / "B100_Z450_A90").symlink_to(outside / "frames_B100")
    torn = root / "torn"
    shutil.copytree(small_reference, torn)
    lines = (torn / "documents.jsonl").read_bytes().splitlines(keepends=True)
    (torn / "documents.jsonl").write_bytes(lines[0] + lines[1][: len(lines[1]) // 2])  # the start, then cut
    (root / "not_empty").mkdir()
    (root / "not_empty" / "notes.txt").write_text("mine")
    paths["docs_symlink"], paths["frames_symlink"], paths["torn"] = str(docs), str(frames), str(torn)


def _resume_argv(c: dict, session: str) -> list[str]:
    return ["campaign", "run", c["root"] + "/small.toml", "--out", session, "--yes", "--quiet", "--resume"]


def _v4l2_campaign(path: Path, port: str, left: str) -> Path:
    """A hardware campaign (grbl + v4l2) whose cameras are not there."""
    path.write_text(f'[rig]\nkind = "grbl"\nport = "{port}"\n[cameras]\nkind = "v4l2"\nleft = "{left}"\n'
                    'right = "usb-port:9-8"\n[plan]\nbaseline_mm = [100]\ndistance_mm = [450]\nalpha_deg = [90]\n')
    return path


def _rig_argv(*more: str) -> list[str]:
    return ["rig", "--port", "/dev/ttyNOPE9", *more]


def _run_ui_argv(c: dict, *more: str) -> list[str]:
    return ["campaign", "run", "--preset", "paper-exp1", "--out", c["root"] + "/ui", "--yes", "--quiet", *more]


TEST_NET = "192.0.2.1"  # RFC 5737's documentation range: the address of no machine's interface

P, S = PAIR
# (id, argv from the fixture's paths, exit status, text the one line must contain, or a function of the paths)
CASES: list[tuple[str, Callable[[dict], list[str]], int, str | Callable[[dict], str]]] = [
    # --- numbers where they enter: render ---
    ("render-baseline-nan", lambda c: ["render", "--baseline", "nan", "--distance", "500", "--out", c["root"] + "/r"],
     2, "--baseline: must be a finite number > 0"),
    ("render-tilt-nan", lambda c: ["render", "--baseline", "100", "--distance", "500", "--tilt", "nan", "--out",
                                   c["root"] + "/r"], 2, "--tilt"),
    ("render-pixel-0", lambda c: ["render", "--baseline", "100", "--distance", "500", "--pixel", "0", "--out",
                                  c["root"] + "/r"], 2, "--pixel"),
    ("render-seed-negative", lambda c: ["render", "--baseline", "100", "--distance", "500", "--seed", "-1", "--out",
                                        c["root"] + "/r"], 2, "--seed: must be a whole number >= 0"),
    ("render-blur-1000", lambda c: ["render", "--baseline", "100", "--distance", "500", "--blur", "1000", "--out",
                                    c["root"] + "/r"], 2, "--blur"),
    ("render-charuco-1000x999", lambda c: ["render", "--baseline", "100", "--distance", "500", "--charuco", "--board",
                                           "1000x999", "--out", c["root"] + "/r"], 2, "--board"),
    ("render-out-under-a-file", lambda c: ["render", "--baseline", "100", "--distance", "500", "--out",
                                           c["root"] + "/a_file/r"], 2, "a_file"),
    # --- model and advise ---
    ("predict-seed-negative", lambda c: ["model", "predict", "--baseline", "100", "--distance", "500", "--monte-carlo",
                                         "10", "--seed", "-1"], 2, "--seed"),
    ("predict-distance-inf", lambda c: ["model", "predict", "--baseline", "100", "--distance", "inf"], 2,
     "--distance"),
    ("advise-distance-inf", lambda c: ["advise", "--distance", "inf", "--target-error-mm", "0.1"], 2, "--distance"),
    ("predict-monte-carlo-1e9", lambda c: ["model", "predict", "--baseline", "100", "--distance", "500",
                                           "--monte-carlo", "1000000000"], 2, "--monte-carlo"),
    ("predict-calibration-views-huge", lambda c: ["model", "predict", "--baseline", "100", "--distance", "500",
                                                  "--calibration-views", "100000"], 2, "--calibration-views"),
    ("predict-calibration-distance-nan", lambda c: ["model", "predict", "--baseline", "100", "--distance", "500",
                                                    "--calibration-distance", "nan", "500"], 2,
     "--calibration-distance"),
    ("predict-calibration-board-huge", lambda c: ["model", "predict", "--baseline", "100", "--distance", "500",
                                                  "--calibration-board", "1000x999"], 2, "--calibration-board"),
    ("predict-workers-huge", lambda c: ["model", "predict", "--baseline", "100", "--distance", "500",
                                        "--monte-carlo", "10", "--workers", "100000"], 2, "--workers"),
    ("paper-distance-inf-json", lambda c: ["model", "paper", "--distance", "inf", "--json"], 2, "--distance"),
    ("surface-grid-inf", lambda c: ["model", "surface", "--over", "bz", "--baselines", "50", "inf", "10",
                                    "--distances", "300", "500", "100", "--out", c["root"] + "/s.csv"], 2,
     "--baselines"),
    ("surface-grid-huge", lambda c: ["model", "surface", "--over", "bz", "--baselines", "1", "100000", "1",
                                     "--distances", "1", "100000", "1", "--out", c["root"] + "/s.csv"], 2,
     "--baselines x --distances"),
    ("advise-grid-huge", lambda c: ["advise", "--distance", "500", "--target-error-mm", "0.1", "--baselines", "1",
                                    "100000", "1", "--alphas", "1", "179", "0.01"], 2, "--baselines x --alphas"),
    # --- measure and calibrate inputs ---
    ("measure-pixel-sigma-nan-json", lambda c: ["measure", "--calib", c["calib"], "--board", "9x6", "--square", "30",
                                                P, S, "--pixel-sigma", "nan", "--json"], 2, "--pixel-sigma"),
    ("measure-pixel-sigma-negative", lambda c: ["measure", "--calib", c["calib"], "--board", "9x6", "--square", "30",
                                                P, S, "--pixel-sigma", "-1"], 2, "--pixel-sigma"),
    ("measure-board-scale-u-nan", lambda c: ["measure", "--calib", c["calib"], "--board", "9x6", "--square", "30",
                                             P, S, "--board-scale-u", "nan"], 2, "--board-scale-u"),
    ("measure-calib-board-scale-u-0.5", lambda c: ["measure", "--calib", c["calib"], "--board", "9x6", "--square",
                                                   "30", P, S, "--calib-board-scale-u", "0.5"], 2,
     "--calib-board-scale-u"),
    ("measure-charuco-1000x999", lambda c: ["measure", "--calib", c["calib"], "--board", "1000x999", "--charuco",
                                            P, S], 2, "--board"),
    ("calibrate-out-under-a-file", lambda c: ["calibrate", "--board", "9x6", "--square", "30", "--left", SAMPLE_LEFT,
                                              "--right", SAMPLE_RIGHT, "--out", c["root"] + "/a_file/c"], 2, "a_file"),
    # --- physical sanity ---
    ("measure-swapped", lambda c: ["measure", "--calib", c["calib"], "--board", "9x6", "--square", "30", S, P], 2,
     "swapped"),
    ("measure-same-image", lambda c: ["measure", "--calib", c["calib"], "--board", "9x6", "--square", "30", P, P], 2,
     "same image"),
    ("measure-nan-calibration", lambda c: ["measure", "--calib", c["nan"], "--board", "9x6", P, S], 2,
     "extrinsics.yml: key 'T' has non-finite entries"),
    ("measure-other-image-size", lambda c: ["measure", "--calib", c["calib"], "--board", "9x6", c["small_left"],
                                            c["small_right"]], 2, "640x480"),
    ("measure-epipolar-far-beyond", lambda c: ["measure", "--calib", c["tilted"], "--board", "9x6", "--square", "30",
                                               P, S], 2, "epipolar RMS"),
    ("calibrate-same-images", lambda c: ["calibrate", "--board", "9x6", "--square", "30", "--left", SAMPLE_LEFT,
                                         "--right", SAMPLE_LEFT, "--out", c["root"] + "/same"], 2, "same image"),
    ("calibrate-intrinsics-other-size", lambda c: ["calibrate", "--board", "9x6", "--square", "30", "--intrinsics",
                                                   c["hd"], "--left", SAMPLE_LEFT, "--right", SAMPLE_RIGHT, "--out",
                                                   c["root"] + "/hd_for_vga"], 2, "is for 1920x1080 images"),
    ("calibrate-truncated-jpeg", lambda c: ["calibrate", "--board", "9x6", "--square", "30", "--left",
                                            c["jpegs"] + "/left0*.jpg", "--right", c["jpegs"] + "/right0*.jpg",
                                            "--out", c["root"] + "/cj"], 2, "left03.jpg: corrupt image"),
    ("calibrate-bit-flipped-jpeg", lambda c: ["calibrate", "--board", "9x6", "--square", "30", "--left",
                                              c["flipped"] + "/left0*.jpg", "--right", c["flipped"] + "/right0*.jpg",
                                              "--out", c["root"] + "/cf"], 2, "right05.jpg: corrupt image"),
    # --- rig: numbers, files and devices, chained actions ---
    ("rig-timeout-0", lambda c: ["rig", "--port", "/dev/ttyNOPE9", "--timeout", "0", "home"], 2, "--timeout"),
    ("rig-timeout-nan", lambda c: _rig_argv("--timeout", "nan", "status"), 2, "--timeout"),
    ("rig-move-nan-chained", lambda c: _rig_argv("home", "move", "--baseline", "nan", "status"), 2, "--baseline"),
    ("rig-spy-log-missing-directory", lambda c: _rig_argv("--spy-log", c["root"] + "/nodir/spy.jsonl", "status"), 2,
     "--spy-log"),
    ("rig-port-missing", lambda c: _rig_argv("status"), 2, "/dev/ttyNOPE9"),
    ("rig-kinematics-distance-nan", lambda c: ["rig", "calibrate-kinematics", "--out", c["root"] + "/kn",
                                                "--distance", "nan"], 2, "--distance"),
    ("rig-kinematics-toe-in-95", lambda c: ["rig", "calibrate-kinematics", "--out", c["root"] + "/kt",
                                            "--toe-in-range", "0", "95"], 2, "--toe-in-range"),
    ("rig-port-missing-resume", lambda c: _rig_argv("resume"), 2, "/dev/ttyNOPE9"),
    ("rig-shell-chained", lambda c: _rig_argv("home", "shell"), 2, "shell runs on its own"),
    ("rig-reset-unknown-option", lambda c: _rig_argv("reset", "--hard"), 2, "--hard"),
    ("rig-config-not-utf8", lambda c: _rig_argv("--rig-config", c["root"] + "/rig_nonutf8.toml", "status"), 2,
     "rig_nonutf8.toml: not UTF-8"),
    ("sim-controller-time-scale-nan", lambda c: ["sim-controller", "--link", c["root"] + "/grbl", "--time-scale",
                                                 "nan"], 2, "--time-scale"),
    ("sim-controller-fault-nan", lambda c: ["sim-controller", "--link", c["root"] + "/grbl", "--fault",
                                            "alarm:1:nan"], 2, "--fault: bad fault 'alarm:1:nan': FRACTION"),
    # --- campaigns ---
    ("plan-not-utf8", lambda c: ["campaign", "plan", c["root"] + "/nonutf8.toml"], 2, "nonutf8.toml: not UTF-8"),
    ("run-not-utf8", lambda c: ["campaign", "run", c["root"] + "/nonutf8.toml", "--out", c["root"] + "/n", "--yes"],
     2, "nonutf8.toml: not UTF-8"),
    *[(f"run-time-scale-{value}", lambda c, v=value: ["campaign", "run", "--preset", "paper-exp1", "--out",
                                                      c["root"] + "/ts", "--yes", "--time-scale", v], 2,
       "--time-scale") for value in ("0", "-1", "nan", "1e-300")],
    ("run-sim-unknown", lambda c: ["campaign", "run", "--preset", "paper-exp1", "--out", c["root"] + "/sim", "--sim",
                                   "perfect"], 2, "--sim"),
    ("run-out-under-a-file", lambda c: ["campaign", "run", "--preset", "paper-exp1", "--out", c["root"] + "/a_file/s",
                                        "--yes"], 2, "a_file"),
    ("run-port-missing", lambda c: ["campaign", "run", c["root"] + "/port_missing.toml", "--out",
                                    c["root"] + "/pm", "--yes", "--quiet"], 2, "/dev/ttyNOPE9"),
    ("run-corrupt-calibration", lambda c: ["campaign", "run", c["root"] + "/corrupt_calib.toml", "--out",
                                           c["root"] + "/cc", "--yes", "--quiet"], 2,
     "corrupt_calib/extrinsics.yml: not a readable OpenCV YAML"),
    # --- the live page: campaign run --ui and stereo-bench live ---
    ("run-ui-port-out-of-range", lambda c: _run_ui_argv(c, "--ui", "--ui-port", "70000"), 2,
     "argument --ui-port: must be a whole number >= 0 and <= 65535"),
    ("run-ui-port-in-use", lambda c: _run_ui_argv(c, "--ui", "--ui-port", c["taken_port"]), 2,
     lambda c: f"cannot serve on 127.0.0.1:{c['taken_port']}: the port is in use"),
    ("run-ui-host-not-this-machine", lambda c: _run_ui_argv(c, "--ui", "--ui-host", TEST_NET, "--ui-port", "0"), 2,
     f"cannot serve on {TEST_NET}:0: no network interface of this machine has that address"),
    ("run-ui-port-without-ui", lambda c: _run_ui_argv(c, "--ui-port", "8080"), 2, "--ui-port applies to the live page"),
    ("live-ui-port-out-of-range", lambda c: ["live", "--ui-port", "-1"], 2, "argument --ui-port"),
    ("live-ui-port-in-use", lambda c: ["live", "--ui-port", c["taken_port"]], 2,
     lambda c: f"cannot serve on 127.0.0.1:{c['taken_port']}: the port is in use"),
    ("live-ui-host-not-this-machine", lambda c: ["live", "--ui-host", TEST_NET, "--ui-port", "0"], 2,
     f"cannot serve on {TEST_NET}:0"),
    ("live-baseline-nan", lambda c: ["live", "--baseline", "nan", "--ui-port", "0"], 2,
     "argument --baseline: must be a finite number > 0"),
    ("live-alpha-180", lambda c: ["live", "--alpha", "180", "--ui-port", "0"], 2, "argument --alpha"),
    ("live-distance-negative", lambda c: ["live", "--distance", "-5", "--ui-port", "0"], 2, "argument --distance"),
    ("live-time-scale-0", lambda c: ["live", "--time-scale", "0", "--ui-port", "0"], 2, "argument --time-scale"),
    ("live-baseline-beyond-the-soft-limits", lambda c: ["live", "--baseline", "5000", "--ui-port", "0"], 2,
     "baseline_mm = 5000 outside"),
    ("live-port-missing", lambda c: ["live", "--port", "/dev/ttyNOPE9", "--ui-port", "0"], 2, "/dev/ttyNOPE9"),
    ("session-schema-unknown-option", lambda c: ["session", "schema", "--rows"], 2, "--rows"),
    # --- replay ---
    ("replay-missing-move", lambda c: ["replay", c["missing_move"], "--out", c["root"] + "/rmm"], 2,
     "cannot be replayed"),
    ("replay-mismatched-move", lambda c: ["replay", c["mismatch_move"]], 2,
     "baseline_mm = 150, the recording holds 151"),
    ("replay-config-no-longer-validates", lambda c: ["replay", c["bad_config"]], 2, "frames_per_config"),
    # --- paths confined to their roots (issue 9, "What must exist" 2) ---
    ("report-config-id-escapes", lambda c: ["report", c["escaped_id"], "--out", c["root"] + "/esc_report/r"], 2,
     f"config_id '{ESCAPED}' is not a valid name"),
    ("resume-documents-symlink-outside", lambda c: _resume_argv(c, c["docs_symlink"]), 2,
     "docs_symlink/documents.jsonl: is a symlink to"),
    ("resume-frames-symlink-outside", lambda c: _resume_argv(c, c["frames_symlink"]), 2,
     "frames_symlink/frames/B100_Z450_A90: is a symlink to"),
    ("replay-out-inside-source", lambda c: ["replay", c["session"], "--out", c["session"] + "/replayed"], 2,
     "is or lies inside the session"),
    ("replay-out-is-source", lambda c: ["replay", c["session"], "--out", c["session"]], 2,
     "is or lies inside the session"),
    ("replay-out-holds-source", lambda c: ["replay", c["session"], "--out", str(Path(c["session"]).parent)], 2,
     "holds the session"),
    ("replay-out-exists", lambda c: ["replay", c["session"], "--out", c["root"] + "/not_empty"], 2,
     "exists; a replay records a new session"),  # was "pass --resume", an option replay does not have
    ("replay-torn-nothing-recorded", lambda c: ["replay", c["torn"]], 2, "nothing to replay"),
    # --- campaign plan checks what run checks, with strict types (issue 9, second half B) ---
    ("plan-corrupt-calibration", lambda c: ["campaign", "plan", c["root"] + "/corrupt_calib.toml"], 2,
     "corrupt_calib/extrinsics.yml: not a readable OpenCV YAML"),
    ("plan-manual-baseline-on-the-simulated-rig", lambda c: ["campaign", "plan", c["root"] + "/manual_baseline.toml"],
     2, 'manual_baseline.toml: rig.quantities.baseline_mm: axis = "manual" cannot run on the simulated bench'),
    ("run-manual-baseline-on-the-simulated-rig", lambda c: ["campaign", "run", c["root"] + "/manual_baseline.toml",
                                                            "--out", c["root"] + "/mb", "--yes"], 2,
     "rig.quantities.baseline_mm: axis = \"manual\""),
    ("plan-string-as-number", lambda c: ["campaign", "plan", c["root"] + "/string_baseline.toml"], 2,
     "string_baseline.toml: plan.baseline_mm[0]: '100' is a string, not a number"),
    ("plan-bool-as-number", lambda c: ["campaign", "plan", c["root"] + "/bool_baseline.toml"], 2,
     "bool_baseline.toml: plan.baseline_mm[0]: true is a boolean, not a number"),
    ("plan-homing-yes", lambda c: ["campaign", "plan", c["root"] + "/homing_yes.toml"], 2,
     "homing_yes.toml: rig.homing: 'yes' is a string, not true or false"),
    ("plan-simulated-rig-with-v4l2-cameras", lambda c: ["campaign", "plan", c["root"] + "/sim_rig_v4l2.toml"], 2,
     'sim_rig_v4l2.toml: rig.kind = "simulated" with cameras.kind = "v4l2" is not a bench'),
    ("plan-too-many-configurations", lambda c: ["campaign", "plan", c["root"] + "/too_many.toml"], 2,
     "too_many.toml: plan: 60,000 configurations (30,000 baselines x 1 distances x 2 angles): at most 20,000"),
    ("run-error-after-no-progress-bar-line", lambda c: ["campaign", "run", c["root"] + "/port_missing.toml", "--out",
                                                        c["root"] + "/pm_bar", "--yes"], 2, "/dev/ttyNOPE9"),
]


def _one_line(capfd) -> tuple[str, str]:
    out, err = capfd.readouterr()
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return out, lines[0]


@pytest.mark.parametrize(("argv", "status", "names"), [case[1:] for case in CASES], ids=[case[0] for case in CASES])
def test_a_bad_input_is_one_line_naming_it(ctx, capfd, argv, status, names):
    code = main(argv(ctx))
    out, line = _one_line(capfd)
    assert code == status, line
    assert line.startswith("stereo-bench ") and ": error: " in line
    assert (names(ctx) if callable(names) else names) in line


@pytest.fixture
def emulator():
    with GrblEmulator(time_scale=50.0) as emu:
        yield emu


@pytest.mark.parametrize(("left", "names"), [("usb-port:9-9", "usb-port:9-9"), ("/dev/video0", "/dev/video0")])
def test_cameras_that_are_not_there_are_exit_2_naming_them(capfd, emulator, tmp_path, left, names):
    plan = _v4l2_campaign(tmp_path / "hardware.toml", emulator.tty_path, left)
    code = main(["campaign", "run", str(plan), "--out", str(tmp_path / "s"), "--quiet"])
    _, line = _one_line(capfd)
    assert code == 2 and names in line  # was 1: a camera that is not there is the user's to fix, as in 'rig'


def test_campaign_run_json_keeps_stdout_json_on_failure(ctx, capfd):
    code = main(["campaign", "run", ctx["root"] + "/port_missing.toml", "--out", ctx["root"] + "/pm_json", "--yes",
                 "--quiet", "--json"])
    out, line = _one_line(capfd)
    assert code == 2 and "/dev/ttyNOPE9" in line
    documents = [json.loads(text) for text in out.splitlines()]
    assert documents[0]["type"] == "start" and documents[-1]["type"] == "stop"


@pytest.mark.slow  # a render or campaign runs first (3-5 s)
def test_a_batch_replay_survives_a_session_that_cannot_be_replayed(ctx, capfd):
    code = main(["replay", ctx["session"], ctx["mismatch_move"], "--executor", "serial", "--json"])
    out, err = capfd.readouterr()
    assert "Traceback" not in err
    reports = {Path(r["session"]).name: r for r in json.loads(out)["sessions"]}
    assert code == 2
    assert "cannot be replayed" in reports["mismatch_move"]["error"]
    assert reports[Path(ctx["session"]).name]["identical"] == reports[Path(ctx["session"]).name]["compared"] > 0


def test_the_rig_shell_reports_a_bad_value_and_goes_on(emulator, capfd, monkeypatch):
    import io

    monkeypatch.setattr("sys.stdin", io.StringIO("move --baseline nan\nstatus\nquit\n"))
    code = main(["rig", "--port", emulator.tty_path, "shell"])
    out, err = capfd.readouterr()
    assert code == 0 and "Traceback" not in err
    assert err.strip().splitlines() == ["error: rig move: argument --baseline: must be a finite number, not 'nan'"]
    assert out.count("Alarm:") >= 2  # connected, then the status after the refused move


# --------------------------------------------------------------------------------------------- disks


class _OsWith:
    """The os module with some functions replaced, for one module's ``os`` (the real one stays untouched)."""

    def __init__(self, **replaced):
        self.__dict__.update(replaced)

    def __getattr__(self, name):
        return getattr(os, name)


def _full_disk(monkeypatch, *, after: int = 0) -> None:
    """Atomic writes (calibrations, frames, figures) fail with ENOSPC after ``after`` successful os.write calls."""
    import stereo_bench.atomic as atomic

    calls = {"n": 0}

    def write(fd, data):
        calls["n"] += 1
        if calls["n"] > after:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as the kernel says it: no file name
        return os.write(fd, data)

    monkeypatch.setattr(atomic, "os", _OsWith(write=write))


def test_calibrate_on_a_full_disk_names_the_file_and_writes_nothing(capfd, monkeypatch, tmp_path):
    _full_disk(monkeypatch)
    code = main(["calibrate", "--board", "9x6", "--square", "30", "--left", SAMPLE_LEFT, "--right", SAMPLE_RIGHT,
                 "--out", str(tmp_path / "c")])
    _, line = _one_line(capfd)
    assert code == 2 and "intrinsics.yml: No space left on device" in line
    assert not (tmp_path / "c" / "intrinsics.yml").exists()  # was: two empty YAML files and exit 0


@pytest.mark.slow  # a render or campaign runs first (3-5 s)
def test_render_on_a_full_disk_names_the_file(capfd, monkeypatch, tmp_path):
    _full_disk(monkeypatch)
    code = main(["render", "--baseline", "100", "--distance", "500", "--out", str(tmp_path / "r")])
    _, line = _one_line(capfd)
    assert code == 2 and "left.png: No space left on device" in line


@pytest.mark.slow  # a render or campaign runs first (3-5 s)
def test_campaign_on_a_full_disk_stops_resumable_and_says_how(capfd, monkeypatch, tmp_path):
    from tests.campaigns import SMALL as text

    plan = tmp_path / "small.toml"
    plan.write_text(text)
    _full_disk(monkeypatch, after=8)  # a few frames, then the disk is full
    code = main(["campaign", "run", str(plan), "--out", str(tmp_path / "s"), "--yes", "--quiet"])
    _, line = _one_line(capfd)
    assert code == 2 and "No space left on device" in line and "--resume" in line
    assert line.index(str(tmp_path / "s")) < line.index("No space left")  # names the file it could not write
    monkeypatch.undo()
    assert main(["campaign", "run", str(plan), "--out", str(tmp_path / "s"), "--yes", "--quiet", "--resume"]) == 0


def test_resume_on_a_read_only_disk_is_one_line(capfd, monkeypatch, small_copy):
    import stereo_bench.campaign.session.writer as session  # where the stream is opened

    lines = (small_copy / "documents.jsonl").read_text().splitlines(keepends=True)
    (small_copy / "documents.jsonl").write_text("".join(lines[:-1]))  # no stop document: interrupted
    real_open = os.open

    def read_only(path, flags, *args, **kwargs):
        if flags & (os.O_WRONLY | os.O_RDWR):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(session, "os", _OsWith(open=read_only))
    plan = small_copy.parent / "small.toml"
    plan.write_text(SMALL)
    code = main(["campaign", "run", str(plan), "--out", str(small_copy), "--yes", "--quiet", "--resume"])
    _, line = _one_line(capfd)
    assert code == 2 and "Read-only file system" in line and "documents.jsonl" in line


# --------------------------------------------------------------------------------------------- the error path


def test_a_bug_prints_its_traceback_and_exits_70(capfd, monkeypatch):
    import stereo_bench.cli.session as session_cli

    def broken(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(session_cli, "_cmd_schema", broken)
    code = main(["session", "schema"])
    _, err = capfd.readouterr()
    assert code == 70
    assert "Traceback" in err and err.strip().splitlines()[-1].startswith("stereo-bench session: internal error")


def _failures():
    import cv2
    from pydantic import BaseModel, ValidationError

    from drivers.camera.base import CameraBandwidthError, CameraGone, CameraNotFound, CaptureFailed
    from drivers.camera.stereo import StereoSkewError
    from drivers.camera.usb_identity import UnstableCameraName
    from drivers.replay import ReplayMismatch
    from drivers.rig.config import LimitError, RigConfigError
    from drivers.rig.grbl import GrblAlarm, GrblConnectionError, GrblConnectionLost, GrblLocked, GrblTimeout
    from stereo_bench.campaign.session import SessionError
    from stereo_bench.live.server import LiveServerError
    from stereo_bench.vision.calibio import CalibrationFileError

    class Model(BaseModel):
        x: int

    try:
        Model.model_validate({"x": "one", "y": 2})
    except ValidationError as error:
        invalid = error
    try:
        cv2.resize(np.zeros((0, 0), np.uint8), (0, 0))
    except cv2.error as error:
        refused = error
    return [
        (GrblAlarm(2, "during a move"), 1, "ALARM:2"), (GrblTimeout("no answer from /dev/ttyUSB0"), 1, "ttyUSB0"),
        (GrblConnectionLost("/dev/ttyUSB0 went away"), 1, "ttyUSB0"), (GrblLocked("in Alarm"), 1, "Alarm"),
        (GrblConnectionError("cannot open serial port /dev/ttyUSB9"), 2, "ttyUSB9"),
        (LimitError(["baseline_mm = 400 outside [0, 350]"]), 2, "baseline_mm = 400"),
        (RigConfigError("rig.toml: x"), 2, "rig.toml"),
        (CameraNotFound("usb-port:1-2: no such camera"), 2, "usb-port:1-2"),
        (UnstableCameraName("/dev/video0: use by-id:"), 2, "/dev/video0"),
        (CameraBandwidthError("/dev/video2: No space left on device (USB bandwidth)"), 2, "/dev/video2"),
        (CameraGone("/dev/video0 disappeared"), 1, "/dev/video0"), (CaptureFailed("left: grab failed"), 1, "left"),
        (StereoSkewError("left-right 40 ms apart"), 1, "40 ms"),
        (ReplayMismatch("move asks baseline_mm = 150"), 2, "cannot be replayed: move asks baseline_mm"),
        (SessionError("s/documents.jsonl line 3: not JSON"), 2, "documents.jsonl line 3"),
        (CalibrationFileError("c/extrinsics.yml: missing key 'T'"), 2, "extrinsics.yml"),
        (invalid, 2, "Model: x: Input should be a valid integer"),
        (OSError(errno.ENOSPC, "No space left on device", "out/x.png"), 2, "out/x.png: No space left on device"),
        (OSError(errno.EROFS, "Read-only file system", "out"), 2, "out: Read-only file system"),
        (UnicodeDecodeError("utf-8", b"ab\xff", 2, 3, "invalid start byte"), 2, "not UTF-8"),
        (refused, 2, "OpenCV refused the input"),
        (LiveServerError("live page: cannot serve on 127.0.0.1:8765: the port is in use"), 2, "127.0.0.1:8765"),
    ]


def test_the_one_mapping_of_exception_types():
    from stereo_bench.cli import failure

    for error, status, text in _failures():
        mapped = failure(error)
        assert mapped is not None, error
        assert (mapped.exit_code, "\n" in str(mapped)) == (status, False), (error, mapped)
        assert text in str(mapped), (text, str(mapped))
    assert failure(ValueError("a bug")) is None and failure(KeyError("x")) is None  # bugs keep their traceback


def test_usage_errors_are_one_line(capfd):
    for argv in (["campaign"], ["model", "predict"], ["render", "--bogus"], ["measure"]):
        assert main(argv) == 2
        _one_line(capfd)


def test_json_output_has_no_nan(capsys):
    from stereo_bench.cli import json_ready, print_json

    value = {"square_mm": {"mean": 27.0, "std": float("nan")}, "sigmas": np.array([1.0, np.inf]),
             "n": np.int64(3), "rows": [{"x": -np.inf}]}
    clean, reasons = json_ready(value)
    assert clean == {"square_mm": {"mean": 27.0, "std": None}, "sigmas": [1.0, None], "n": 3, "rows": [{"x": None}]}
    assert set(reasons) == {"square_mm.std", "sigmas[1]", "rows[0].x"} and "NaN" in reasons["square_mm.std"]
    print_json(value)
    printed = json.loads(capsys.readouterr().out, parse_constant=lambda name: pytest.fail(f"{name} in JSON"))
    assert printed["square_mm"]["std"] is None and set(printed["null_reasons"]) == set(reasons)


def test_a_closed_output_pipe_ends_quietly_with_141():
    """``stereo-bench ... --json | head -c 100``: the reader goes away; no traceback, no error line."""
    import subprocess
    import sys

    k_values = [f"{k:.3f}" for k in np.arange(0.01, 3.0, 0.001)]  # ~200 kB of JSON: more than a pipe holds
    process = subprocess.Popen([sys.executable, "-m", "stereo_bench", "model", "paper", "--json", "--k", *k_values],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout.read(100).startswith(b"{")
    process.stdout.close()
    err = process.stderr.read().decode()
    assert process.wait(timeout=60) == 141 and err == ""
