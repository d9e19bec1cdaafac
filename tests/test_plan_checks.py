"""Issue 9, second half B: strict config types, ``campaign plan`` checking what ``run`` checks (one function), a
feasibility rule that knows the corner detector's limit, a plan of 10,000 configurations computed the same way
faster, and summaries whose word agrees with the exit status."""

from __future__ import annotations

import io
import shutil
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.rig.config import RigConfigError, load_rig_config
from drivers.sim.render import Optics, StereoRenderer
from stereo_bench.campaign.config import (
    MAX_PLAN_CONFIGURATIONS,
    ConfigError,
    campaign_from_dict,
    load_campaign,
    recorded_campaign,
)
from stereo_bench.campaign.execute import run_campaign
from stereo_bench.campaign.plan import calibration_distance_range, expand_plan, target_visibility
from stereo_bench.campaign.preflight import check_campaign
from stereo_bench.cli import main
from stereo_bench.geometry import (
    CameraModel,
    RigPose,
    board_pose_facing_rig,
    calibration_view_fits,
    calibration_views_fit,
    distort_normalised,
    invert_transform,
)
from stereo_bench.targets import CharucoTarget, Checkerboard
from stereo_bench.vision.detect import detect
from tests.campaigns import SMALL, small_config

PLAN = "[plan]\nbaseline_mm = [100]\ndistance_mm = [500]\n"

# -- strict types --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("text", "says"), [
    ('[plan]\nbaseline_mm = ["100", "1_50"]\ndistance_mm = [500]\n',
     "plan.baseline_mm[0]: '100' is a string, not a number: write 100 without quotes"),
    ("[plan]\nbaseline_mm = [true]\ndistance_mm = [500]\n", "plan.baseline_mm[0]: true is a boolean, not a number"),
    ('[rig]\nhoming = "yes"\n' + PLAN, "rig.homing: 'yes' is a string, not true or false"),
    ('[rig]\nhoming = "true"\n' + PLAN, "rig.homing: 'true' is a string, not true or false: write true without quotes"),
    ("[capture]\nframes_per_config = 2.0\n" + PLAN, "capture.frames_per_config: 2.0 is not a whole number"),
    ("[capture]\nsettle_s = true\n" + PLAN, "capture.settle_s: true is a boolean, not a number"),
    ("[calibration_board]\ncols = true\n" + PLAN, "calibration_board.cols: true is a boolean, not a whole number"),
    ('[plan]\nbaseline_mm = [100]\ndistance_mm = [500]\ntilt_deg = "5"\n', "plan.tilt_deg: '5' is a string"),
    ('[cameras.optics]\nfocal_mm = "4"\n' + PLAN, "cameras.optics.focal_mm: '4' is a string"),
    ('[cameras.settings]\nfps = "30"\n' + PLAN, "cameras.settings: fps: Input should be a valid number"),
    ('[sim.slide]\nbacklash_mm = "0.1"\n' + PLAN, "sim: slide.backlash_mm: Input should be a valid number"),
    ('[sim.cameras]\nthin_prism_left = ["0", 0, 0, 0]\n' + PLAN, "sim: cameras.thin_prism_left.0"),
    ('[rig.quantities.baseline_mm]\naxis = "X"\nmin = "0"\nmax = 300\n' + PLAN,
     "rig.quantities.baseline_mm.min: '0' is a string"),
    ("[rig.controller]\nreset_on_open = 1\n" + PLAN, "rig.controller.reset_on_open"),
    ('[extrinsics]\nrepeatability_mm = "0.01"\n' + PLAN, "extrinsics.repeatability_mm: '0.01' is a string"),
])
def test_no_string_or_boolean_is_taken_for_a_number(tmp_path, text, says):
    path = tmp_path / "lax.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as refused:
        load_campaign(path)
    message = str(refused.value)
    assert message.startswith(f"{path}: ") and says in message and "\n" not in message


def test_whole_numbers_load_as_floats_and_a_recorded_config_loads_again(tmp_path):
    config = campaign_from_dict(tomllib.loads(
        '[capture]\nsettle_s = 1\n[rig.quantities.baseline_mm]\naxis = "X"\nmin = 0\nmax = 300\noffset = -300\n'
        "[sim.cameras]\nthin_prism_left = [0, 0, 0.001, 0]\n" + PLAN), base_dir=tmp_path)
    assert config.capture.settle_s == 1.0 and isinstance(config.capture.settle_s, float)
    assert config.plan.baseline_mm == [100.0] and isinstance(config.plan.baseline_mm[0], float)
    assert config.sim.resolve().cameras.thin_prism_left == (0.0, 0.0, 0.001, 0.0)
    # What a session records (JSON: paths as strings, tuples as lists) validates under the strict types.
    fixed = small_config(extrinsics={"mode": "fixed", "calib_dir": str(tmp_path)})
    assert recorded_campaign(fixed.model_dump(mode="json")) == fixed


def test_a_recording_made_before_lens_models_were_compared_replays_with_the_fit_it_ran():
    """A v4l2 session recorded without ``extrinsics.lens_model`` calibrated with the default flags, no comparison;
    a recording made since says ``null`` (today's default: auto for v4l2 cameras) or a name."""
    recorded = small_config().model_dump(mode="json")  # the section's reading is the cameras' kind's: asked below
    assert recorded["extrinsics"]["lens_model"] is None
    assert recorded_campaign(recorded).extrinsics.lens_model_for("v4l2") == "auto"
    old = {**recorded, "extrinsics": {k: v for k, v in recorded["extrinsics"].items() if k != "lens_model"}}
    assert recorded_campaign(old).extrinsics.lens_model == "legacy"
    assert recorded_campaign(old).extrinsics.lens_model_for("v4l2") is None
    named = {**recorded, "extrinsics": {**recorded["extrinsics"], "lens_model": "rational"}}
    assert recorded_campaign(named).extrinsics.lens_model_for("v4l2") == "rational"


def test_a_rig_config_file_is_strict(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text('[quantities.baseline_mm]\naxis = "X"\nmin = 0\nmax = true\n')
    with pytest.raises(RigConfigError, match=r"quantities\.baseline_mm\.max"):
        load_rig_config(path)


# -- the checks plan and run share ----------------------------------------------------------------------------------


@pytest.mark.parametrize(("rig", "tilt_deg", "refused"), [
    ({"quantities": {"baseline_mm": {"axis": "manual"}}}, 0.0, "rig.quantities.baseline_mm: axis = \"manual\""),
    ({"quantities": {"toe_in_left_deg": {"axis": "manual"}}}, 0.0, "rig.quantities.toe_in_left_deg"),
    ({"kind": "grbl", "port": "/dev/ttyNOPE9", "time_scale": 1.0, "quantities": {"baseline_mm": {"axis": "manual"}}},
     0.0, "cannot run on bring-up"),
    ({"quantities": {"tilt_left_deg": {"axis": "manual"}}}, 5.0, "rig.quantities.tilt_left_deg"),
    ({"quantities": {"tilt_left_deg": {"axis": "manual"}}}, 0.0, None),  # renders as 0, what the plan asks
])
def test_a_manual_quantity_simulated_cameras_cannot_render_is_refused(rig, tilt_deg, refused):
    config = small_config(rig=rig, plan={"tilt_deg": tilt_deg})
    if refused is None:
        check_campaign(config)
        return
    with pytest.raises(ConfigError, match=refused):
        check_campaign(config, source="c.toml")


def test_run_calls_the_same_check_before_the_session_exists(tmp_path):
    config = small_config(rig={"quantities": {"baseline_mm": {"axis": "manual"}}})
    with pytest.raises(ConfigError, match="baseline_mm"):
        run_campaign(config, tmp_path / "session", yes=True)
    assert not (tmp_path / "session").exists()  # was: the session written, the rig homed, then "drives axis Z"


def _calibration(small_reference: Path, directory: Path) -> Path:
    shutil.copytree(next((small_reference / "calib").glob("*/a1")), directory)
    return directory


def test_a_calibration_plan_cannot_use_is_refused_naming_the_file(small_reference, tmp_path):
    corrupt = _calibration(small_reference, tmp_path / "corrupt")
    (corrupt / "intrinsics.yml").write_text("%YAML:1.0\nM1: [this is not\n")
    for mode in ("fixed", "per-config", "nominal"):
        config = small_config(extrinsics={"mode": mode, "calib_dir": str(corrupt)})
        with pytest.raises(ConfigError, match=r"extrinsics\.calib_dir: .*corrupt/intrinsics\.yml: not a readable"):
            check_campaign(config)
    other_size = small_config(extrinsics={"mode": "fixed", "calib_dir": str(_calibration(small_reference,
                                                                                           tmp_path / "good"))},
                              cameras={"optics": {"width_px": 1920, "height_px": 1080, "pixel_um": 3.0}})
    with pytest.raises(ConfigError, match="a calibration of 960x540 images, the cameras give 1920x1080"):
        check_campaign(other_size)


# -- feasibility: the detector's limit ------------------------------------------------------------------------------


def test_a_target_too_small_in_the_images_is_infeasible_and_says_which_limit():
    far, = expand_plan(small_config(plan={"baseline_mm": [100], "distance_mm": [100_000], "alpha_deg": [90]}))
    assert far.corners_in_both == far.n_corners  # every corner in both views: the old rule said "100 % feasible"
    assert not far.feasible and not far.runnable
    assert "minimum board size in pixels" in far.reason and "px in the left view at Z = 100000 mm" in far.reason


@pytest.mark.parametrize("target", [Checkerboard(9, 6, 27.0), CharucoTarget(9, 6, 27.0, 20.25)],
                         ids=["checkerboard", "charuco"])
def test_the_plans_pixel_limit_is_where_the_detector_stops_finding_the_board(target):
    """At the default 1920x1080 optics: the farthest distance the plan calls feasible shows a board the detector
    finds in rendered views; 15 % farther (called infeasible) it finds nothing."""
    kind = "checkerboard" if isinstance(target, Checkerboard) else "charuco"
    board = {"kind": kind, "cols": 9, "rows": 6, "square_mm": 27.0}
    distances = list(range(500, 2600, 25))
    config = campaign_from_dict({"target": board, "extrinsics": {"mode": "nominal"},
                                 "plan": {"baseline_mm": [100], "distance_mm": distances, "alpha_deg": [90]}})
    feasible = [c.distance_mm for c in expand_plan(config) if c.feasible]
    assert feasible and max(feasible) < distances[-1]
    camera = config.cameras.optics.camera_model()
    renderer = StereoRenderer(target, camera, camera, optics=Optics(noise_sigma_dn=2.0, blur_sigma_px=0.7))
    rig = RigPose.symmetric(100.0, 90.0)

    def found(distance_mm: float, seed: int) -> int:
        T_cam_board = invert_transform(rig.T_rig_left) @ board_pose_facing_rig(
            distance_mm=distance_mm, board_size_mm=target.grid_size_mm)
        detection = detect(renderer.render_view("left", T_cam_board, np.random.default_rng(seed)).image, target)
        return 0 if detection is None else len(detection.ids)

    # A checkerboard is found whole or not at all; a ChArUco board corner by corner: most of it at the limit.
    needed = target.n_corners if isinstance(target, Checkerboard) else target.n_corners // 2
    assert all(found(max(feasible), seed) >= needed for seed in range(2))
    assert not any(found(1.15 * max(feasible), seed) for seed in range(2))


# -- the same plan, faster --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("board", [Checkerboard(11, 8, 25.0), CharucoTarget(12, 9, 20.0, 15.0)],
                         ids=["checkerboard", "charuco"])
def test_the_hinted_calibration_range_is_the_full_scan(board):
    camera = CameraModel.from_sensor()
    for alpha in (90.0, 85.0, 78.0, 70.0):
        hint = None
        for baseline in np.arange(20.0, 341.0, 16.0):
            rig = RigPose.symmetric(float(baseline), alpha)
            full = calibration_distance_range(board, rig, left=camera, right=camera)
            assert calibration_distance_range(board, rig, left=camera, right=camera, hint=hint) == full
            assert calibration_distance_range(board, rig, left=camera, right=camera, hint=(250.0, 1500.0)) == full
            hint = full if full is not None else hint


def test_the_batched_calibration_rule_is_the_single_pose_rule():
    board, camera = Checkerboard(11, 8, 25.0), CameraModel.from_sensor()
    rig = RigPose.symmetric(150.0, 80.0)
    poses = np.stack([board_pose_facing_rig(distance_mm=d, board_size_mm=board.grid_size_mm, yaw_deg=yaw)
                      for d in (200.0, 400.0, 700.0, 1500.0) for yaw in (-70.0, 0.0, 30.0)])
    batched = calibration_views_fit(board, poses, rig=rig, left=camera, right=camera)
    one_by_one = [calibration_view_fits(board, T, rig=rig, left=camera, right=camera) for T in poses]
    assert batched.tolist() == one_by_one and any(one_by_one) and not all(one_by_one)


def test_target_visibility_counts_the_corners_and_the_smallest_square():
    target, camera = Checkerboard(9, 6, 27.0), CameraModel.from_sensor(dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    vis = target_visibility(target, RigPose.symmetric(100.0, 90.0), distance_mm=500.0, left=camera, right=camera)
    assert vis.in_both == vis.in_left == vis.in_right == 54
    # Fronto-parallel at 500 mm, no distortion: a 27 mm square is f * 27 / 500 px, the same everywhere on the board.
    assert vis.square_px_left == pytest.approx(camera.fx * 27.0 / 500.0, rel=1e-9)


@pytest.mark.parametrize("dist", [(-0.05, 0.02, 0.0, 0.0, 0.0), (0.1, -0.2, 0.001, -0.002),
                                  (0.1, -0.2, 0.001, -0.002, 0.05, 0.01, -0.02, 0.03),
                                  (0.1, -0.2, 0.001, -0.002, 0.05, 0.01, -0.02, 0.03, 1e-3, -2e-3, 3e-3, 5e-4)])
def test_the_numpy_distortion_is_opencvs(dist):
    camera = CameraModel.from_sensor(dist=dist)
    normalised = np.random.default_rng(3).uniform(-0.6, 0.6, (500, 2))
    expected, _ = cv2.projectPoints(np.column_stack([normalised, np.ones(500)]).reshape(-1, 1, 3), np.zeros(3),
                                    np.zeros(3), camera.K, camera.dist)
    assert np.abs(distort_normalised(normalised, camera.K, np.asarray(dist)) - expected.reshape(-1, 2)).max() < 1e-9


def test_duplicates_are_still_named_and_a_plan_is_bounded():
    with pytest.raises(ConfigError, match=r"plan\.baseline_mm: lists 100 more than once"):
        small_config(plan={"baseline_mm": [100, 150, 100]})
    too_many = [8.0 + 0.25 * b for b in range(MAX_PLAN_CONFIGURATIONS + 1)]  # 8 to 5008 mm: inside the bounds
    with pytest.raises(ConfigError, match=r"plan: 20,001 configurations \(20,001 baselines x 1 distances x 2 angles"
                                          r"|plan: 40,002 configurations"):
        small_config(plan={"baseline_mm": too_many})


# -- honest summaries -----------------------------------------------------------------------------------------------


def test_a_campaign_that_measured_nothing_says_failed_and_exits_1(tmp_path, capsys):
    path = tmp_path / "far.toml"
    data = SMALL.replace("distance_mm = [450]", "distance_mm = [100000]").replace("baseline_mm = [100, 150]",
                                                                                   "baseline_mm = [100]")
    path.write_text(data)
    code = main(["campaign", "run", str(path), "--out", str(tmp_path / "s"), "--yes", "--quiet"])
    out = capsys.readouterr().out
    assert code == 1
    assert "campaign failed in" in out and "(nothing was measured)" in out and "success" not in out


def test_the_progress_bar_is_erased_before_an_error_line():
    from stereo_bench.campaign.execute import CampaignPlan
    from stereo_bench.cli.progress import Progress

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    terminal = Terminal()
    config = small_config()
    progress = Progress(CampaignPlan.of(config), config, quiet=False, stream=terminal, refresh_s=None)
    progress.line.refresh()
    progress.close(clear=True)
    print("stereo-bench campaign: error: the last line", file=terminal)
    screen = terminal.getvalue()
    assert "small 0/4" in screen  # it was drawn on the terminal ...
    last_redraw = screen.rsplit("\r", 1)[-1]
    # ... and erased (carriage return, clear to the end of the line) before the error
    assert last_redraw == "\x1b[Kstereo-bench campaign: error: the last line\n"


def test_render_charuco_hints_a_measure_command_that_works(tmp_path, capsys):
    assert main(["render", "--baseline", "100", "--distance", "500", "--charuco", "--out", str(tmp_path / "r")]) == 0
    hint = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("next: stereo-bench "))
    argv = hint.removeprefix("next: stereo-bench ").split()
    assert "--charuco" in argv
    assert main(argv) == 0


@pytest.mark.slow  # one re-analysis (a stereo calibration per configuration)
def test_a_batch_re_analysis_reports_a_bad_session_and_goes_on(small_reference, tmp_path, capsys):
    """Already true on main (the first half of issue 9 made replay_job return errors as data); kept as a test."""
    damaged = tmp_path / "damaged"
    shutil.copytree(small_reference, damaged)
    next(p for p in sorted((damaged / "frames").rglob("*.png"))).unlink()
    code = main(["replay", str(small_reference), str(damaged), "--intrinsics", "fixed", "--out",
                 str(tmp_path / "again"), "--executor", "serial"])
    out, err = capsys.readouterr()
    assert code == 2 and "Traceback" not in err
    assert f"re-analysed 2 measured configurations of {small_reference}" in out
    (line,) = [text for text in out.splitlines() if text.startswith(f"{damaged}: error: ")]
    assert ".png" in line


def test_a_campaign_outcome_is_partial_when_fewer_than_planned_were_measured():
    from stereo_bench.campaign.documents import campaign_outcome

    assert campaign_outcome("success", {"measured": 2}) == ("success", "")
    assert campaign_outcome("success", {"measured": 1, "infeasible": 5}) == (
        "partial", "1 of 6 planned configurations measured")
    assert campaign_outcome("success", {"infeasible": 2, "limit": 1})[0] == "failed"
    assert campaign_outcome("interrupted", {"measured": 1, "not run": 3}) == ("interrupted", "")


def test_a_campaign_that_measured_some_of_its_plan_says_partial_and_exits_0(tmp_path, capsys):
    path = tmp_path / "part.toml"
    path.write_text(SMALL.replace("baseline_mm = [100, 150]", "baseline_mm = [100, 5000]"))
    code = main(["campaign", "run", str(path), "--out", str(tmp_path / "s"), "--yes", "--quiet"])
    out = capsys.readouterr().out
    assert code == 0
    assert "campaign partial in" in out and "(1 of 4 planned configurations measured)" in out
    assert "success" not in out
    from stereo_bench.report.collect import read_session
    from stereo_bench.report.html import _comparison_table

    session = read_session(tmp_path / "s", "s")
    assert session.status == "partial"  # the report's badge: the word the CLI printed
    table = _comparison_table(session)
    assert "outside" in table and "B5000" in table  # each missing configuration with its reason


def test_the_measurable_exp2_preset_holds_the_whole_board_in_both_views_at_every_alpha():
    from stereo_bench.campaign.config import load_preset
    from stereo_bench.campaign.plan import expand_plan

    configurations = expand_plan(load_preset("paper-exp2-measurable"))
    assert [c.alpha_deg for c in configurations] == [5, 15, 25, 35, 45, 55]
    assert all(c.runnable and c.fraction_in_both == 1.0 for c in configurations), \
        [(c.config_id, c.reason, c.limit_violation) for c in configurations]
    assert "deviates from the paper" in load_preset("paper-exp2-measurable").description
