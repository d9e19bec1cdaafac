"""Issue 19 item 6: the bad inputs of the second bad-input trial, as a user meets them on the CLI.

Each case goes through the real command line (``main([...])`` with fd capture, or a subprocess where the old code
would hang or the input is a FIFO, always with a timeout so that a regression fails instead of hanging the
suite): the documented exit status, one line on stderr, and that line names the field or the file.

- every input that scales a campaign's work is bounded where it enters (the config), with generous bounds: the
  values a real bench uses pass;
- the inputs that ended in tracebacks (a TOML nested 50,000 deep, ``/dev/zero`` as a plan, rig config or
  kinematic file, a ``calib_dir`` that is a symlink loop) and the ones that hung (a FIFO as a plan, a FIFO as a
  recorded frame) are one-line errors, through the one reader of input files (``drivers/files.py``);
- ``baseline_mm = [1e-300]``, a zero focal length in ``calib_dir``, a NaN in ``[sim.cameras]`` are refused by
  ``campaign plan`` naming the field or the file and entry;
- what a command will write is checked before the first move or presentation (``rig calibrate-kinematics
  --model /proc/kin.toml``, ``--out`` under ``/proc``, a FIFO as the spy log), and a reversed range is refused;
- the live page answers a 100,000-character path with 414, never 500;
- ``rig move --alpha 0`` asks for ``--yes``; a plan's alpha 0 is refused;
- ``campaign plan`` refuses cameras named ``/dev/video0`` and one camera as both sides, as ``run`` does.
"""

from __future__ import annotations

import asyncio
import os
import resource
import shutil
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from drivers.files import MAX_TOML_BYTES, MAX_TOML_NESTING, InputFileError, read_regular_file, toml_nesting
from drivers.sim.grbl.emulator import GrblEmulator
from stereo_bench.campaign.session import SessionError, SessionReader
from stereo_bench.cli import main
from tests.test_session import record

ROOT = Path(__file__).resolve().parents[1]
PLAN = "[plan]\nbaseline_mm = [100]\ndistance_mm = [500]\n"
HARDWARE = '[rig]\nkind = "grbl"\nport = "/dev/ttyNOPE9"\n[cameras]\nkind = "v4l2"\n'


def _one_line(capfd) -> str:
    out, err = capfd.readouterr()
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def _cli(capfd, *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    return code, _one_line(capfd)


def _limit_memory() -> None:
    # 4 GB of address space: a reader of /dev/zero fails with MemoryError here instead of taking the machine's memory
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))


def _subprocess(*argv: str, timeout: float = 60.0) -> tuple[int, str]:
    """``stereo-bench ARGV`` in a child, with a timeout and a memory limit (a FIFO must not hang the suite, nor
    /dev/zero fill the machine's memory): (exit status, its one stderr line)."""
    done = subprocess.run([sys.executable, "-m", "stereo_bench", *argv], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, preexec_fn=_limit_memory)
    assert "Traceback" not in done.stderr, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    return done.returncode, lines[0]


def _plan(tmp_path: Path, text: str, name: str = "plan.toml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


# -- inputs that scale the work, bounded where they enter --------------------------------------------------------

UNBOUNDED = [  # (id, TOML after the plan, the field the line names); each passed `campaign plan` before
    ("frames-per-config-1e9", "[capture]\nframes_per_config = 1000000000\n", "capture.frames_per_config"),
    ("calibration-views-1e6", "[capture]\ncalibration_views = 1000000\n", "capture.calibration_views"),
    ("settle-1e9", "[capture]\nsettle_s = 1e9\n", "capture.settle_s"),
    ("board-retries-1e9", "[capture]\nboard_retries = 1000000000\n", "capture.board_retries"),
    ("exposure-1e9", "[cameras.optics]\nexposure_s = 1e9\n", "cameras.optics.exposure_s"),
    ("image-1e6-px", "[cameras.optics]\nwidth_px = 1000000\n", "cameras.optics.width_px"),
    ("blur-1e4", "[cameras.optics]\nblur_px = 10000\n", "cameras.optics.blur_px"),
    ("focal-1e300", "[cameras.optics]\nfocal_mm = 1e300\n", "cameras.optics.focal_mm"),
    ("home-timeout-inf", "[rig.controller]\nhome_timeout_s = inf\n", "rig.controller.home_timeout_s"),
    ("connect-timeout-1e12", "[rig.controller]\nconnect_timeout_s = 1e12\n", "rig.controller.connect_timeout_s"),
    ("move-timeout-1e12", "[rig.controller]\nmove_timeout_s = 1e12\n", "rig.controller.move_timeout_s"),
    ("baudrate-1e12", "[rig.controller]\nbaudrate = 1000000000000\n", "rig.controller.baudrate"),
    ("feed-1e-300", '[rig.quantities.baseline_mm]\naxis = "X"\noffset = -350\nmin = 0\nmax = 350\n'
                    "feed_per_min = 1e-300\n", "rig.quantities.baseline_mm.feed_per_min"),
    ("soft-limit-1e12", '[rig.quantities.baseline_mm]\naxis = "X"\noffset = -1e12\nmin = 0\nmax = 1e12\n',
     "rig.quantities.baseline_mm"),
    ("camera-exposure-inf", "[cameras.settings]\nexposure_us = inf\n", "exposure_us"),
    ("sim-thin-prism-nan", "[sim.cameras]\nthin_prism_left = [nan, 0, 0, 0]\n", "cameras.thin_prism_left"),
]


@pytest.mark.parametrize(("extra", "field"), [case[1:] for case in UNBOUNDED], ids=[case[0] for case in UNBOUNDED])
def test_an_input_that_scales_the_work_is_bounded_in_the_config(tmp_path, capfd, extra, field):
    code, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, PLAN + extra))
    assert code == 2, line
    assert "plan.toml: " in line and field in line


def test_the_bounds_say_why(tmp_path, capfd):
    _, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, PLAN + "[rig.controller]\nhome_timeout_s = 1e6\n"))
    assert line.endswith("rig.controller.home_timeout_s: Input should be less than or equal to 3600: a homing cycle "
                         "takes 10-15 s")
    _, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, PLAN + "[capture]\nframes_per_config = 5000\n"))
    assert "less than or equal to 1000: a 1080p stereo frame costs" in line


def test_the_bounds_are_generous_for_a_real_bench(tmp_path, capfd):
    """50 calibration views, a settle of a few seconds, 20 frames, a 4K camera, a long homing: all pass."""
    generous = PLAN + ("[capture]\ncalibration_views = 50\nsettle_s = 5\nframes_per_config = 20\nboard_retries = 5\n"
                       "[cameras.optics]\nwidth_px = 3840\nheight_px = 2160\nexposure_s = 0.5\n"
                       "[rig.controller]\nhome_timeout_s = 600\nconnect_timeout_s = 30\nmove_timeout_s = 3600\n"
                       "baudrate = 921600\n")
    assert main(["campaign", "plan", _plan(tmp_path, generous)]) == 0
    capfd.readouterr()


def test_a_rig_config_file_is_bounded_as_the_inline_one(tmp_path, capfd):
    rig = tmp_path / "rig.toml"
    rig.write_text("[controller]\nhome_timeout_s = inf\n")
    code, line = _cli(capfd, "rig", "--rig-config", str(rig), "--port", "/dev/ttyNOPE9", "status")
    assert code == 2 and "rig.toml: controller.home_timeout_s: Input should be a finite number" in line


def test_a_baseline_below_a_cameras_width_is_refused_by_the_plan(tmp_path, capfd):
    code, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, PLAN.replace("[100]", "[1e-300]")))
    assert code == 2 and "plan.baseline_mm: value 1e-300 outside [8, 10000]" in line and "housings" in line
    # 1 mm, the measurement's own floor, was planned feasible and then refused at the run (as swapped, or as one
    # viewpoint): refused by the plan now
    code, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, PLAN.replace("[100]", "[1]")))
    assert code == 2 and "plan.baseline_mm: value 1 outside [8, 10000]" in line
    assert main(["campaign", "plan", _plan(tmp_path, PLAN.replace("[100]", "[8]"))]) == 0


def test_a_nan_in_the_simulated_cameras_is_refused_naming_the_field(tmp_path, capfd):
    code, line = _cli(capfd, "campaign", "plan",
                      _plan(tmp_path, PLAN + "[sim.cameras]\nthin_prism_right = [0, nan, 0, 0]\n"))
    assert code == 2 and "sim: cameras.thin_prism_right.1: Input should be a finite number" in line


def test_a_zero_focal_length_in_calib_dir_is_refused_naming_the_file_and_entry(tmp_path, capfd):
    from stereo_bench.geometry import CameraModel
    from stereo_bench.vision.calibio import write_calibration
    from stereo_bench.vision.calibrate import StereoCalibration

    camera = CameraModel.from_sensor()
    broken = camera.K.copy()
    broken[0, 0] = 0.0
    D = camera.dist.reshape(1, -1)
    write_calibration(tmp_path / "calib", StereoCalibration(K1=broken, D1=D, K2=camera.K, D2=D, R=np.eye(3),
                                                           T=np.array([-100.0, 0.0, 0.0]),
                                                           image_size=camera.image_size))
    plan = _plan(tmp_path, PLAN + '[extrinsics]\nmode = "nominal"\ncalib_dir = "calib"\n')
    code, line = _cli(capfd, "campaign", "plan", plan)
    assert code == 2, line
    assert "extrinsics.calib_dir" in line and "calib/intrinsics.yml" in line and "M1, D1 (left camera)" in line
    assert "fx = 0" in line


# -- input files: one reader, regular files of bounded size and nesting ------------------------------------------


@pytest.mark.parametrize(("name", "text", "where"), [
    ("array", "[plan]\nbaseline_mm = " + "[" * 50_000 + "]" * 50_000 + "\n", "line 2"),
    ("inline-table", "x = " + "{a = " * 5_000 + "1" + "}" * 5_000 + "\n", "line 1"),
])
def test_toml_nested_deeper_than_any_config_is_one_line(tmp_path, capfd, name, text, where):
    code, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, text))
    assert code == 2 and f"plan.toml: arrays or inline tables nested over {MAX_TOML_NESTING} deep ({where})" in line


def test_the_nesting_scan_counts_no_bracket_in_a_string_or_comment():
    text = ('[a]\nx = [[1, 2], [3]]  # [[[[[[\ns = "[[[[{{"\nt = """\n[[[[\n"""\nu = \'[[[\'\n'
            "v = '''[[[['''\n[[b]]\ny = {c = {d = 1}}\n")
    assert toml_nesting(text)[0] == 2
    assert toml_nesting("z = " + "[" * 40 + "]" * 40)[0] == 40


def test_a_toml_file_over_the_size_bound_is_refused(tmp_path, capfd):
    code, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, PLAN + "#" * MAX_TOML_BYTES + "\n"))
    assert code == 2 and f"plan.toml: over {MAX_TOML_BYTES:,} bytes: too large for a campaign file" in line


@pytest.mark.parametrize("argv", [
    ["campaign", "plan", "/dev/zero"],
    ["rig", "--rig-config", "/dev/zero", "--port", "/dev/ttyNOPE9", "status"],
])
def test_a_device_as_an_input_file_is_not_a_regular_file(argv):
    code, line = _subprocess(*argv)
    assert code == 2 and "/dev/zero: not a regular file (a character device)" in line


def test_a_device_as_the_kinematic_file_is_named(tmp_path):
    plan = _plan(tmp_path, PLAN + '[extrinsics]\nmode = "kinematic"\nkinematic_file = "/dev/zero"\n')
    code, line = _subprocess("campaign", "plan", plan)
    assert code == 2 and "extrinsics.kinematic_file: /dev/zero: not a regular file (a character device)" in line


def test_a_fifo_as_the_plan_is_refused_without_waiting_for_a_writer(tmp_path):
    fifo = tmp_path / "plan.toml"
    os.mkfifo(fifo)
    code, line = _subprocess("campaign", "plan", str(fifo))
    assert code == 2 and "plan.toml: not a regular file (a FIFO): give a campaign file" in line


def test_fifos_as_the_files_a_plan_names_are_refused(tmp_path):
    os.mkfifo(tmp_path / "kin.toml")
    (tmp_path / "calib").mkdir()
    os.mkfifo(tmp_path / "calib" / "intrinsics.yml")
    code, line = _subprocess("campaign", "plan", _plan(
        tmp_path, PLAN + '[extrinsics]\nmode = "kinematic"\nkinematic_file = "kin.toml"\n', "k.toml"))
    assert code == 2 and "extrinsics.kinematic_file" in line and "kin.toml: not a regular file (a FIFO)" in line
    code, line = _subprocess("campaign", "plan", _plan(
        tmp_path, PLAN + '[extrinsics]\nmode = "nominal"\ncalib_dir = "calib"\n', "c.toml"))
    assert code == 2 and "calib/intrinsics.yml: not a regular file (a FIFO)" in line


def test_a_calib_dir_that_is_a_symlink_loop_is_one_line(tmp_path, capfd):
    (tmp_path / "loop").symlink_to("loop")
    code, line = _cli(capfd, "campaign", "plan",
                      _plan(tmp_path, PLAN + '[extrinsics]\nmode = "nominal"\ncalib_dir = "loop"\n'))
    assert code == 2 and "extrinsics.calib_dir" in line and "loop: cannot be resolved" in line


def test_the_reader_bounds_what_it_reads_not_only_what_stat_says(tmp_path):
    """/proc files state size 0; the bound holds on the bytes read."""
    with pytest.raises(InputFileError, match="over 10 bytes"):
        read_regular_file("/proc/self/status", what="campaign file", max_bytes=10)
    (tmp_path / "f").write_bytes(b"0123456789")
    assert read_regular_file(tmp_path / "f", what="f", max_bytes=10) == b"0123456789"


# -- recorded frames ---------------------------------------------------------------------------------------------


def _read_in_thread(fn) -> BaseException | object:
    """``fn()`` on a thread joined with a timeout: a read that blocks fails the test instead of hanging it."""
    outcome: list = []

    def target() -> None:
        try:
            outcome.append(fn())
        except BaseException as error:  # noqa: BLE001 - handed to the test
            outcome.append(error)

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(timeout=20)
    assert not thread.is_alive(), "the read blocked (a FIFO opened for reading waits for a writer)"
    return outcome[0]


def test_a_frame_that_is_a_fifo_is_refused_naming_it(tmp_path):
    out = record(tmp_path / "s")
    frame = out / "frames" / "c0" / "a1" / "000001_left.png"
    frame.unlink()
    os.mkfifo(frame)
    outcome = _read_in_thread(lambda: SessionReader(out).frame("frames/c0/a1/000001_left.png"))
    assert isinstance(outcome, SessionError)
    assert "frames/c0/a1/000001_left.png: not a regular file (a FIFO)" in str(outcome)


def test_a_frame_directory_that_is_a_symlink_loop_is_refused(tmp_path):
    out = record(tmp_path / "s")
    shutil.rmtree(out / "frames" / "c1")
    (out / "frames" / "c1").symlink_to("c1")
    with pytest.raises(SessionError, match=r"frames/c1/a1/000004_left.png' refused: cannot be resolved"):
        SessionReader(out).frame("frames/c1/a1/000004_left.png")


def test_replay_of_a_session_with_a_fifo_frame_stops_naming_it(small_copy, tmp_path):
    frame = sorted((small_copy / "frames").rglob("*.png"))[0]
    frame.unlink()
    os.mkfifo(frame)
    code, line = _subprocess("replay", str(small_copy), "--out", str(tmp_path / "r"), timeout=120)
    assert code == 2 and f"{frame.name}: not a regular file (a FIFO)" in line
    assert not (tmp_path / "r").exists()


# -- what an action will write, checked before it starts; ranges in order ----------------------------------------


def test_calibrate_kinematics_refuses_a_model_path_it_cannot_write_before_the_design(tmp_path, capfd):
    code, line = _cli(capfd, "rig", "calibrate-kinematics", "--out", str(tmp_path / "k"), "--model",
                      "/proc/kin.toml", "--yes")
    assert code == 2 and "--model /proc/kin.toml: cannot create a file in /proc" in line
    assert not (tmp_path / "k").exists()  # no session: nothing was visited


@pytest.mark.parametrize(("model", "names"), [
    ("{tmp}", "is a directory"),
    ("{tmp}/nodir/kin.toml", "does not exist"),
    ("{session}/kin.toml", "lies inside the recorded session"),
    ("{out}/frames/kin.toml", "lies inside the session --out"),
    ("{out}/documents.jsonl", "lies inside the session --out"),
    ("{fifo}", "not a regular file (a FIFO)"),
])
def test_calibrate_kinematics_checks_the_model_path_first(tmp_path, capfd, model, names):
    session = record(tmp_path / "session")
    os.mkfifo(tmp_path / "fifo")
    path = model.format(tmp=tmp_path, session=session, out=tmp_path / "k", fifo=tmp_path / "fifo")
    code, line = _cli(capfd, "rig", "calibrate-kinematics", "--out", str(tmp_path / "k"), "--model", path, "--yes")
    assert code == 2 and "--model" in line and names in line
    assert not (tmp_path / "k").exists()


@pytest.mark.parametrize("argv", [
    ["campaign", "run", "--preset", "paper-exp1", "--out", "/proc/stereo-bench-x", "--yes"],
    ["rig", "calibrate-kinematics", "--out", "/proc/stereo-bench-x", "--yes"],
])
def test_an_out_directory_where_nothing_can_be_created_is_refused_before_the_run(capfd, argv):
    code, line = _cli(capfd, *argv)
    assert code == 2 and "argument --out: /proc/stereo-bench-x: cannot create anything in /proc" in line


def test_a_spy_log_that_is_a_fifo_is_refused_before_the_port_opens(tmp_path):
    os.mkfifo(tmp_path / "spy")  # opened for appending it would wait for a reader for ever
    code, line = _subprocess("rig", "--port", "/dev/ttyNOPE9", "--spy-log", str(tmp_path / "spy"), "status")
    assert code == 2 and "--spy-log" in line and "not a regular file (a FIFO)" in line


@pytest.mark.parametrize(("argv", "option"), [
    (["rig", "calibrate-kinematics", "--out", "{out}", "--baseline-range", "200", "50", "--yes"], "--baseline-range"),
    (["rig", "calibrate-kinematics", "--out", "{out}", "--toe-in-range", "20", "0", "--yes"], "--toe-in-range"),
    (["model", "predict", "--baseline", "100", "--distance", "500", "--calibration-distance", "600", "300"],
     "--calibration-distance"),
])
def test_a_reversed_range_is_refused(tmp_path, capfd, argv, option):
    code, line = _cli(capfd, *[a.format(out=tmp_path / "k") for a in argv])
    assert code == 2 and f"{option} " in line and "the first value must not exceed the second" in line
    assert not (tmp_path / "k").exists()


# -- the live page -----------------------------------------------------------------------------------------------


class _Page:
    token = "t"


def _asgi_status(app, path: str) -> int:
    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "GET", "scheme": "http",
             "path": path, "raw_path": path.encode(), "query_string": b"", "headers": [], "server": ("x", 80),
             "client": ("c", 1), "root_path": ""}
    sent: list[dict] = []

    async def receive():
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message):
        sent.append(message)

    asyncio.run(app(scope, receive, send))
    return next(m["status"] for m in sent if m["type"] == "http.response.start")


def test_a_long_url_is_414_or_404_never_500(tmp_path):
    """httpx (and so Starlette's TestClient) refuses URLs over 64 kB itself: the app is called as ASGI directly, then
    a real request goes to uvicorn over a socket."""
    from stereo_bench.live.server import LiveApp, LiveServer

    (tmp_path / "loop").symlink_to("loop")
    live = LiveApp(_Page(), session_dir=tmp_path)
    assert _asgi_status(live.app, "/session/" + "a" * 100_000) == 414
    assert _asgi_status(live.app, "/" + "a" * 100_000) == 414
    assert _asgi_status(live.app, "/session/" + "a" * 4000) == 404  # under the bound; was 500: ENAMETOOLONG
    assert _asgi_status(live.app, "/session/loop") in (403, 404)
    server = LiveServer(live, port=0).start()
    try:
        for path, status in (("/session/" + "a" * 100_000, b"414"), ("/session/" + "a" * 4000, b"404")):
            with socket.create_connection(("127.0.0.1", server.port), timeout=10) as connection:
                connection.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".encode())
                assert connection.recv(64).split()[1] == status
    finally:
        server.stop()


# -- angles: a camera looking along the baseline ----------------------------------------------------------------


# Heads whose soft limits reach toe-in 90 deg (alpha 0), one pull-off clear of a switch at machine 0 of a $131=91 axis:
# the default rig config stops at toe-in 88 deg, where the soft limits alone refuse alpha 0.
TOE_IN_90 = """
[quantities.toe_in_left_deg]
axis = "Y"
offset = -1.0
scale = -1.0
min = 0.0
max = 90.0

[quantities.toe_in_right_deg]
axis = "Z"
offset = -1.0
scale = -1.0
min = 0.0
max = 90.0
"""


def test_rig_move_to_alpha_0_asks_for_yes_before_the_port_is_opened(tmp_path, capfd):
    rig_config = tmp_path / "rig.toml"
    rig_config.write_text(TOE_IN_90)
    code, line = _cli(capfd, "rig", "--port", "/dev/ttyNOPE9", "--rig-config", str(rig_config), "move", "--alpha", "0")
    assert code == 2 and "alpha 0 deg (toe-in 90 deg) turns the left camera to look along the baseline" in line
    assert "--yes" in line
    code, line = _cli(capfd, "rig", "--port", "/dev/ttyNOPE9", "--rig-config", str(rig_config), "move",
                      "--toe-in-right", "90")
    assert code == 2 and "right camera" in line


def test_rig_move_to_alpha_0_is_refused_by_the_default_soft_limits(capfd):
    code, line = _cli(capfd, "rig", "--port", "/dev/ttyNOPE9", "move", "--alpha", "0", "--yes")
    assert code == 2 and "outside soft limits" in line and "toe_in_left_deg = 90 outside [0, 88]" in line


def test_rig_move_to_alpha_0_with_yes_moves(tmp_path, capfd):
    from drivers.rig.config import load_rig_config
    from drivers.sim.grbl.firmware import axis_specs_for_travel

    rig_config = tmp_path / "rig.toml"
    rig_config.write_text(TOE_IN_90)
    specs, _ = axis_specs_for_travel(load_rig_config(rig_config).machine_travel(), margin=1.0)
    with GrblEmulator(time_scale=100.0, axis_specs=specs) as emulator:
        code = main(["rig", "--port", emulator.tty_path, "--rig-config", str(rig_config), "home", "move", "--alpha",
                     "0", "--yes", "status"])
    out, err = capfd.readouterr()
    assert code == 0, err
    assert "toe-in L = 90.000 deg" in out.splitlines()[-1]


@pytest.mark.parametrize(("angles", "field"), [("alpha_deg = [0]", "plan.alpha_deg: value 0"),
                                               ("alpha_deg = [180]", "plan.alpha_deg: value 180"),
                                               ("toe_in_deg = [90]", "plan.toe_in_deg: value 90")])
def test_a_plan_angle_that_looks_along_the_baseline_is_refused(tmp_path, capfd, angles, field):
    code, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, PLAN + angles + "\n"))
    assert code == 2 and field in line and "look along (or behind) the baseline" in line


# -- campaign plan refuses what run refuses ----------------------------------------------------------------------


@pytest.mark.parametrize(("cameras", "names"), [
    ('left = "/dev/video0"\nright = "usb-port:1-2"\n', "cameras.left: /dev/video0: /dev/videoN numbers change"),
    ('left = "usb-port:1-1"\nright = "video2"\n', "cameras.right: video2: /dev/videoN numbers change"),
    ('left = "usb-port:1-2"\nright = "usb-port:1-2"\n', "cameras.right: usb-port:1-2 is also cameras.left"),
    ('left = "by-id:usb-cam"\nright = "/dev/v4l/by-id/usb-cam"\n', "is also cameras.left"),
])
def test_campaign_plan_refuses_camera_names_run_refuses(tmp_path, capfd, cameras, names):
    code, line = _cli(capfd, "campaign", "plan", _plan(tmp_path, HARDWARE + cameras + PLAN))
    assert code == 2 and names in line
