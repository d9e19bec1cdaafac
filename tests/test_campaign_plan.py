"""Plans as data: configuration order, predicted feasibility (the issue's figures), limits, steps, duration."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from drivers.rig.motion import REFERENCE_AXIS_MOTION, move_time_s
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.firmware import DEFAULT_AXES
from stereo_bench.campaign.config import campaign_from_dict, load_preset
from stereo_bench.campaign.plan import (
    CaptureCalibration,
    CaptureMeasurement,
    Checkpoint,
    Flush,
    Move,
    PromptManual,
    PromptTarget,
    Settle,
    calibration_distance_range,
    estimate_duration,
    expand_plan,
    format_id_value,
    plan_steps,
    plan_summary,
    predict_duration_s,
)
from stereo_bench.geometry import CameraModel, RigPose
from stereo_bench.targets import CharucoTarget, Checkerboard


def _config(plan: dict, **sections):
    return campaign_from_dict({"plan": plan, **sections})


def _by_alpha(configurations):
    return {c.alpha_deg: c for c in configurations}


# ---------------------------------------------------------------------------------------------- feasibility


def test_paper_exp2_as_written_shows_no_corner_in_both_views_for_alpha_up_to_45():
    # The figure: centred 9x6 board of 27 mm squares, f = 1333 px, 1920x1080, Z = 500, B = 100.
    configurations = expand_plan(load_preset("paper-exp2"), margin_px=0.0)
    assert [c.alpha_deg for c in configurations] == [5, 15, 25, 35, 45, 55]
    for c in configurations:
        if c.alpha_deg <= 45:
            assert c.corners_in_both == 0 and c.fraction_in_both == 0.0 and not c.feasible
            assert c.reason.startswith("0 of 54 target corners in both views")
            assert f"alpha = {c.alpha_deg:g} deg" in c.reason
    assert "the cameras' views do not overlap on the board at alpha = 45 deg" in _by_alpha(configurations)[45].reason
    assert "outside both cameras' views" in _by_alpha(configurations)[25].reason


def test_paper_exp2_toe_in_fractions_per_angle():
    # alpha = 55: 30/54 with margin 0, as tests/test_geometry.py finds; 10 px margin gives the same here.
    for margin in (0.0, 10.0):
        by_alpha = _by_alpha(expand_plan(load_preset("paper-exp2-toe-in"), margin_px=margin))
        assert list(by_alpha) == [85, 75, 65, 55, 45, 35]
        fractions = {alpha: c.fraction_in_both for alpha, c in by_alpha.items()}
        assert fractions == {85: 1.0, 75: 1.0, 65: 1.0, 55: 30 / 54, 45: 0.0, 35: 0.0}
        assert {alpha: c.toe_in_deg for alpha, c in by_alpha.items()} == {85: 5, 75: 15, 65: 25, 55: 35, 45: 45,
                                                                          35: 55}
    # alpha = 50 (toe-in 40) shows 6 corners with margin 0: exactly the minimum, still feasible (partial).
    config = _config({"baseline_mm": [100], "distance_mm": [500], "toe_in_deg": [40]},
                     extrinsics={"mode": "fixed", "calib_dir": "."})
    (c,) = expand_plan(config, margin_px=0.0)
    assert (c.corners_in_both, c.feasible, c.status) == (6, True, "partial")


def test_alpha_55_needs_a_calibration_board_that_fits_the_narrow_overlap():
    # With the default 11x8 checkerboard of 25 mm squares, the calibration board never fits both views.
    checkerboard = load_preset("paper-exp2-toe-in").model_copy(
        update={"calibration_board": campaign_from_dict({"plan": {"baseline_mm": [8], "distance_mm": [1]}})
                .calibration_board})
    by_alpha = _by_alpha(expand_plan(checkerboard))
    c55 = by_alpha[55]
    assert c55.corners_in_both == 30 and not c55.feasible and c55.status == "infeasible"
    assert c55.reason.startswith("calibration board (checkerboard 11x8 inner corners, 25 mm squares) never whole in "
                                 "both views fronto-parallel at 250-1500 mm")
    assert c55.calibration_range_mm is None
    assert [by_alpha[a].runnable for a in (85, 75, 65)] == [True, True, True]
    assert by_alpha[65].calibration_range_mm[0] > by_alpha[85].calibration_range_mm[0]  # the overlap starts later
    # The preset's ChArUco board calibrates from partial views: alpha = 55 is measured (partly).
    preset = _by_alpha(expand_plan(load_preset("paper-exp2-toe-in")))[55]
    assert preset.feasible and preset.status == "partial" and preset.calibration_range_mm is not None
    # With extrinsics from a calibration directory only the target matters.
    fixed = checkerboard.model_copy(
        update={"extrinsics": campaign_from_dict({"plan": {"baseline_mm": [8], "distance_mm": [1]},
                                                  "extrinsics": {"mode": "fixed", "calib_dir": "."}}).extrinsics})
    c55 = _by_alpha(expand_plan(fixed))[55]
    assert c55.feasible and c55.status == "partial" and c55.reason is None and c55.calibration_range_mm is None


def test_partial_view_is_feasible_and_flagged():
    configurations = expand_plan(load_preset("paper-exp1"))
    assert len(configurations) == 25 and all(c.feasible and c.runnable for c in configurations)
    partial = [c for c in configurations if c.status == "partial"]
    assert [(c.config_id, c.corners_in_both) for c in partial] == [("B250_Z300_A90", 42)]
    assert partial[0].reason is None and partial[0].fraction_in_both == pytest.approx(42 / 54)


def test_calibration_range_checkerboard_needs_the_whole_board_charuco_half():
    camera = CameraModel.from_sensor()
    rig = RigPose.symmetric(100.0, 90.0)
    near, far = calibration_distance_range(Checkerboard(11, 8, 25.0), rig, left=camera, right=camera)
    assert 250 < near < 400 and far == 1500
    # A board too big for the common view at any listed distance.
    assert calibration_distance_range(Checkerboard(11, 8, 25.0), rig, left=camera, right=camera,
                                      distances_mm=(250.0, 280.0)) is None
    # alpha = 55: the common view is ~0.1 m wide; half of a small ChArUco board fits, a whole checkerboard doesn't.
    toed_in = RigPose.symmetric(100.0, 55.0)
    assert calibration_distance_range(Checkerboard(11, 8, 25.0), toed_in, left=camera, right=camera) is None
    assert calibration_distance_range(CharucoTarget(8, 6, 15.0, 11.0), toed_in, left=camera, right=camera) is not None


def test_where_the_plan_finds_the_board_fits_the_simulator_places_every_view():
    """One calibration-fit rule: a configuration the plan calls feasible is one the presenter can fill."""
    from drivers.sim.render import calibration_board_poses
    from stereo_bench.geometry import calibration_view_fits

    camera = CameraModel.from_sensor()
    for board in (Checkerboard(11, 8, 25.0), CharucoTarget(8, 6, 15.0, 11.0)):
        for alpha in (90.0, 80.0, 70.0, 62.0):
            rig = RigPose.symmetric(100.0, alpha)
            fits = calibration_distance_range(board, rig, left=camera, right=camera)
            if fits is None:
                continue
            poses = calibration_board_poses(rig, board, n_views=8, rng=np.random.default_rng(int(alpha)),
                                            distance_mm=fits, left=camera, right=camera)
            assert len(poses) == 8
            assert all(calibration_view_fits(board, T, rig=rig, left=camera, right=camera) for T in poses)


def test_tilt_moves_the_bisector_and_the_config_id():
    config = _config({"baseline_mm": [100], "distance_mm": [500], "tilt_deg": 5},
                     rig={"quantities": {"tilt_left_deg": {"axis": "A", "min": -20, "max": 20},
                                         "tilt_right_deg": {"axis": "B", "min": -20, "max": 20}}})
    (c,) = expand_plan(config)
    assert c.config_id == "B100_Z500_A90_T5" and c.tilt_deg == 5.0 and c.limit_violation is None
    assert c.rig_pose() == RigPose.symmetric(100.0, 90.0, 5.0)
    assert c.corners_in_both == 54 and c.calibration_range_mm is not None


# ---------------------------------------------------------------------------------------------- order and ids


def test_order_is_distance_outer_then_serpentine_baseline_and_angle():
    config = _config({"baseline_mm": [100, 150], "distance_mm": [400, 500], "alpha_deg": [90, 85]})
    configurations = expand_plan(config)
    assert [(c.distance_mm, c.baseline_mm, c.alpha_deg) for c in configurations] == [
        (400, 100, 90), (400, 100, 85), (400, 150, 85), (400, 150, 90),
        (500, 150, 90), (500, 150, 85), (500, 100, 85), (500, 100, 90),
    ]
    assert [c.index for c in configurations] == list(range(8))
    for before, after in zip(configurations, configurations[1:], strict=False):
        changed = [before.distance_mm != after.distance_mm, before.baseline_mm != after.baseline_mm,
                   before.alpha_deg != after.alpha_deg]
        assert sum(changed) == 1  # one quantity at a time


def test_config_ids_are_unique_and_filesystem_safe_for_any_values():
    assert [format_id_value(v) for v in (100, 100.5, 87.25, -5, 1e-05, 1e20)] == [
        "100", "100p5", "87p25", "m5", "1em05", "1e20"]
    config = _config({"baseline_mm": [100, 100.5, 100.05], "distance_mm": [400, 400.1],
                      "toe_in_deg": [-2.5, 0, 2.5, 2.55]})
    ids = [c.config_id for c in expand_plan(config)]
    assert len(ids) == len(set(ids)) == 24
    assert all(re.fullmatch(r"[A-Za-z0-9_]+", i) for i in ids)
    assert "B100p5_Z400p1_A92p5" in ids and "B100p05_Z400_A87p45" in ids


def test_configurations_and_steps_serialise_to_json():
    config = load_preset("paper-exp2-toe-in")
    configurations = expand_plan(config)
    text = json.dumps({"c": [c.as_dict() for c in configurations],
                       "s": [s.as_dict() for s in plan_steps(config, configurations)]})
    data = json.loads(text)
    assert data["c"][0]["config_id"] == "B100_Z500_A85" and data["c"][0]["status"] == "feasible"
    assert data["c"][0]["calibration_range_mm"] == [250.0, 1500.0]  # the preset's small ChArUco board
    assert data["s"][0] == {"step": "move", "config_id": "B100_Z500_A85", "index": 0, "request": {
        "baseline_mm": 100.0, "toe_in_left_deg": 5.0, "toe_in_right_deg": 5.0, "tilt_left_deg": 0.0,
        "tilt_right_deg": 0.0, "target_distance_mm": 500.0}}


# ---------------------------------------------------------------------------------------------- limits


def test_soft_limit_violations_are_reported_and_not_run():
    config = _config({"baseline_mm": [100, 150], "distance_mm": [500]},
                     rig={"quantities": {"baseline_mm": {"axis": "X", "min": 0, "max": 120}}})
    configurations = expand_plan(config)
    ok, bad = configurations
    assert ok.limit_violation is None and ok.runnable
    assert bad.feasible and not bad.runnable and bad.limit_violation == "baseline_mm = 150 outside [0, 120]"
    steps = plan_steps(config, configurations)
    assert steps[-1] == Checkpoint("B150_Z500_A90", skipped=True, reason="baseline_mm = 150 outside [0, 120]")
    assert sum(isinstance(s, Move) for s in steps) == 1


def test_tilt_on_a_rig_without_tilt_axes_is_a_mapping_violation():
    (c,) = expand_plan(_config({"baseline_mm": [100], "distance_mm": [500], "tilt_deg": 3}))
    assert c.feasible and not c.runnable
    assert c.limit_violation.startswith("tilt_left_deg is fixed at 0 on this rig")


def test_toe_in_beyond_the_pan_limits():
    (c,) = expand_plan(_config({"baseline_mm": [100], "distance_mm": [500], "toe_in_deg": [-5]},
                               extrinsics={"mode": "fixed", "calib_dir": "."}))
    assert c.limit_violation == "toe_in_left_deg = -5 outside [0, 88]; toe_in_right_deg = -5 outside [0, 88]"


# ---------------------------------------------------------------------------------------------- steps


def test_steps_per_configuration_and_target_prompts_only_when_z_changes():
    config = _config({"baseline_mm": [100, 150], "distance_mm": [400, 500]})
    configurations = expand_plan(config)
    steps = plan_steps(config, configurations)
    first = configurations[0]
    assert steps[:7] == [Move(first), PromptTarget(400.0), Settle(0.3), Flush(), CaptureCalibration(12),
                         CaptureMeasurement(3), Checkpoint(first.config_id)]
    assert [s.distance_mm for s in steps if isinstance(s, PromptTarget)] == [400.0, 500.0]
    assert len(steps) == 4 * 6 + 2
    assert [s.config_id for s in steps if isinstance(s, Checkpoint)] == [c.config_id for c in configurations]


def test_infeasible_configurations_get_only_a_checkpoint_with_the_reason():
    config = load_preset("paper-exp2")
    configurations = expand_plan(config)
    steps = plan_steps(config, configurations)
    infeasible = [c for c in configurations if not c.feasible]
    assert [c.alpha_deg for c in infeasible] == [5, 15, 25, 35, 45]  # as the paper writes alpha
    skipped = [s for s in steps if isinstance(s, Checkpoint) and s.skipped]
    assert [s.reason for s in skipped] == [c.reason for c in infeasible]
    assert sum(isinstance(s, Move) for s in steps) == 1  # only alpha = 55 runs


def test_fixed_extrinsics_capture_no_calibration_views_and_driven_target_needs_no_prompt():
    config = _config({"baseline_mm": [100], "distance_mm": [400, 500]},
                     extrinsics={"mode": "fixed", "calib_dir": "."},
                     rig={"quantities": {"target_distance_mm": {"axis": "C", "min": 200, "max": 1500}}})
    steps = plan_steps(config, expand_plan(config))
    kinds = [s.kind for s in steps]
    assert "capture_calibration" not in kinds and "prompt_target" not in kinds
    assert kinds[:5] == ["move", "settle", "flush", "capture_measurement", "checkpoint"]


def test_a_manual_baseline_is_prompted_when_it_changes():
    config = _config({"baseline_mm": [100, 150], "distance_mm": [500]},
                     rig={"quantities": {"baseline_mm": {"axis": "manual"}}})
    steps = plan_steps(config, expand_plan(config))
    assert [s for s in steps if isinstance(s, PromptManual)] == [PromptManual("baseline_mm", 100.0),
                                                                 PromptManual("baseline_mm", 150.0)]
    assert sum(isinstance(s, PromptTarget) for s in steps) == 1


# ---------------------------------------------------------------------------------------------- duration


@pytest.mark.parametrize("deltas, feed", [
    ({"X": 50.0}, None), ({"X": 2.0}, None), ({"X": 120.0, "Y": 30.0, "Z": -30.0}, None), ({"Y": 0.5}, None),
    ({"X": 80.0}, 600.0),
])
def test_move_time_matches_the_emulators_motion_model(deltas, feed):
    emulator = GrblEmulator(axes="XYZ")  # constructing it opens nothing
    start = {"X": 0.0, "Y": 0.0, "Z": 40.0}
    end = {a: start[a] + deltas.get(a, 0.0) for a in start}
    block = emulator._make_block(start, end, feed, kind="G1" if feed else "G0", line="")
    rates = {a: DEFAULT_AXES[a].max_rate_per_min for a in "XYZ"}
    accels = {a: DEFAULT_AXES[a].acceleration for a in "XYZ"}
    predicted = move_time_s(deltas, max_rate_per_min=rates, acceleration=accels, feed_per_min=feed)
    assert predicted == block.motion_duration  # one model, so equal to the last digit


def test_the_emulator_and_the_plan_share_the_reference_axes():
    for axis, motion in REFERENCE_AXIS_MOTION.items():
        assert (DEFAULT_AXES[axis].max_rate_per_min, DEFAULT_AXES[axis].acceleration) == (
            motion.max_rate_per_min, motion.acceleration)


def test_move_time_by_hand():
    rates, accels = {"X": 3000.0}, {"X": 200.0}
    # 50 mm at 50 mm/s, 200 mm/s^2: 0.25 s ramps covering 6.25 mm each, 37.5 mm cruise (0.75 s).
    assert move_time_s({"X": 50.0}, max_rate_per_min=rates, acceleration=accels) == pytest.approx(1.25)
    assert move_time_s({"X": -2.0}, max_rate_per_min=rates, acceleration=accels) == pytest.approx(2 * math.sqrt(0.01))
    assert move_time_s({"X": 0.0}, max_rate_per_min=rates, acceleration=accels) == 0.0


def test_duration_of_paper_exp1_on_the_simulated_rig():
    config = load_preset("paper-exp1")
    configurations = expand_plan(config)
    steps = plan_steps(config, configurations)
    estimate = estimate_duration(config, configurations, steps)
    # Homing from machine 0, where the simulated rig powers up (on the switches): per cycle (Z, then X and Y; both
    # at 30 mm/s, 180 mm/s^2: the slowest axis' $11x/$12x) no seek, a 1 mm pull-off (triangle, 2 x sqrt(1/180) =
    # 0.149 s), a 1 mm locate at 200 mm/min (0.0185 s ramp, then 0.969 mm at 3.33 mm/s: 0.309 s), a pull-off, and
    # four 0.1 s debounces: 1.0074 s a cycle. Motion: from where homing leaves the rig (X = -1, B = 349 mm) to
    # B = 50 mm, 299 mm in 6.23 s (0.25 s ramps of 6.25 mm, 286.5 mm at 50 mm/s), then 20 baseline moves of 50 mm
    # (1.25 s each); the baseline stays put when only Z changes (serpentine); alpha = 90 is where homing leaves
    # the heads. 25 x (0.3 s settle + 15 frames x 0.02 s).
    cycle = 2 * math.sqrt(1 / 180) + (30 / 9 / 180 + (1 - 0.5 * 180 * (30 / 9 / 180) ** 2) / (30 / 9)) \
        + 2 * math.sqrt(1 / 180) + 4 * 0.1
    assert estimate.homing_s == pytest.approx(2 * cycle) == pytest.approx(2.0148, abs=1e-4)
    assert estimate.motion_s == pytest.approx(6.23 + 20 * 1.25)
    assert estimate.settle_s == pytest.approx(25 * 0.3)
    assert estimate.capture_s == pytest.approx(25 * 15 * 0.02)
    assert estimate.operator_s == 0.0 and estimate.flush_s == 0.0
    assert predict_duration_s(config, configurations, steps) == pytest.approx(estimate.total_s) == pytest.approx(
        2 * cycle + 6.23 + 25 + 7.5 + 7.5)
    assert any("no operator time" in a for a in estimate.assumptions)


def test_duration_counts_the_operator_on_a_real_bench_and_time_scale_on_the_simulator():
    plan = {"baseline_mm": [100, 150], "distance_mm": [400, 500]}
    real = _config(plan, rig={"kind": "grbl", "port": "/dev/ttyUSB0"},
                   cameras={"kind": "v4l2", "left": "usb-port:1-1", "right": "usb-port:1-2",
                            "settings": {"fps": 10, "buffer_count": 2}})
    steps = plan_steps(real, expand_plan(real))
    estimate = estimate_duration(real, [], steps)
    assert estimate.operator_s == pytest.approx(2 * 30.0 + 4 * 12 * 5.0)  # 2 target prompts, 48 views by hand
    assert estimate.capture_s == pytest.approx(4 * 15 * 0.1) and estimate.flush_s == pytest.approx(4 * 2 * 0.1)
    fast = _config(plan, rig={"time_scale": 10})
    slow = _config(plan)
    fast_estimate = estimate_duration(fast, [], plan_steps(fast, expand_plan(fast)))
    slow_estimate = estimate_duration(slow, [], plan_steps(slow, expand_plan(slow)))
    assert fast_estimate.motion_s == pytest.approx(slow_estimate.motion_s / 10)
    assert fast_estimate.homing_s == pytest.approx(slow_estimate.homing_s / 10)
    assert fast_estimate.settle_s == slow_estimate.settle_s


def test_bring_up_is_planned_as_it_runs_real_time_motion_simulated_frames_no_hand_placed_boards():
    plan = {"baseline_mm": [100, 150], "distance_mm": [400, 500]}
    bring_up = _config(plan, rig={"kind": "grbl", "port": "/dev/ttyUSB0"})
    simulated = _config(plan)
    assert bring_up.bench_kind == "bring-up" and not bring_up.fully_simulated
    estimate = estimate_duration(bring_up, [], plan_steps(bring_up, expand_plan(bring_up)))
    reference = estimate_duration(simulated, [], plan_steps(simulated, expand_plan(simulated)))
    assert estimate.operator_s == 0.0  # the target and the calibration board are in the simulated scene
    assert estimate.capture_s == reference.capture_s and estimate.flush_s == 0.0  # simulated frames
    assert estimate.motion_s == pytest.approx(reference.motion_s)  # the real controller, at real time
    manual_baseline = _config(plan, rig={"kind": "grbl", "port": "/dev/ttyUSB0",
                                         "quantities": {"baseline_mm": {"axis": "manual"}}})
    estimate = estimate_duration(manual_baseline, [], plan_steps(manual_baseline, expand_plan(manual_baseline)))
    # The baseline is set by hand on the real slide: 100, 150, (150 stays for Z = 500: serpentine), 100.
    assert estimate.operator_s == pytest.approx(3 * 30.0)


def test_plan_summary_counts():
    summary = plan_summary(load_preset("paper-exp2-toe-in"))
    assert summary["n_configurations"] == 6 and summary["infeasible"] == 2 and summary["runnable"] == 4
    assert summary["n_steps"] == 4 * 6 + 1 + 2  # 6 steps per run, one target prompt, 2 skipped checkpoints
    assert summary["n_steps"] == len(summary["steps"])
    assert summary["predicted_duration_s"] == pytest.approx(summary["duration"]["total_s"])
    assert np.isclose(summary["configurations"][3]["fraction_in_both"], 30 / 54)


def test_the_plan_table_keeps_long_ids_aligned_and_close_values_apart(tmp_path, capsys):
    """Ids past the table's 18 characters (fractional B, Z and toe-ins) widen their column instead of pushing the
    rest out of line, and values the plan tells apart print apart (100 and 100.0001, not both '100')."""
    from stereo_bench.cli import main

    path = tmp_path / "c.toml"
    path.write_text("[plan]\nbaseline_mm = [87.25, 100.0001, 100]\ndistance_mm = [432.125]\n"
                    "toe_in_deg = [2.5, 12.75]\n")
    assert main(["campaign", "plan", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    header = next(i for i, line in enumerate(lines) if "config_id" in line)
    rows = lines[header + 1:header + 7]
    ends = {line.index(" feasible") for line in rows}
    assert len(rows) == 6 and len(ends) == 1  # every row's status in one column
    b_end = lines[header].index("B mm") + len("B mm")
    assert sorted(line[:b_end].split()[-1] for line in rows) == ["100", "100", "100.0001", "100.0001", "87.25",
                                                                 "87.25"]
