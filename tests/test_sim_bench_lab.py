"""The lab bench end to end: what the cameras see follows the true mechanics, and the bench tells the truth."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from drivers.rig.config import QuantityMapping, RigConfig
from drivers.rig.grbl import GrblResetError
from drivers.rig.rig import GrblRig
from drivers.sim.bench import BenchSimulator, true_lens
from drivers.sim.grbl.faults import ResetMidMove
from drivers.sim.mechanics import MoveHistory, pair_state, ringing_deg
from drivers.sim.profile import IDEAL, LAB, BoardErrors, CameraErrors, SimProfile, SlideErrors
from drivers.sim.render import BoardShape, Optics, StereoRenderer, calibration_board_poses
from stereo_bench.campaign.operator import OperatorDesk, SimulatedOperator, move_and_ask
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig, invert_transform, transform_points
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import StereoCalibration, calibrate_mono
from stereo_bench.vision.detect import detect
from stereo_bench.vision.pipeline import measure_pair

BOARD = Checkerboard(9, 6, 27.0)
HALF = {"image_size": (960, 540), "pixel_um": 6.0}  # the same field of view at a quarter of the pixels

#: Stands in for the operator at the manual steps (the target distance), as a campaign's simulator does.
OPERATORS = OperatorDesk([SimulatedOperator()])


def cameras(**kwargs) -> dict:
    return {"left": CameraModel.from_sensor(name="left", **HALF, **kwargs),
            "right": CameraModel.from_sensor(name="right", **HALF, **kwargs)}


def calibration(left: CameraModel, right: CameraModel, R, T) -> StereoCalibration:
    return StereoCalibration(K1=left.K, D1=left.dist.reshape(1, -1), K2=right.K, D2=right.dist.reshape(1, -1),
                             R=np.asarray(R, float), T=np.asarray(T, float), image_size=left.image_size)


@pytest.fixture(scope="module")
def lab_bench():
    with BenchSimulator(time_scale=50.0, profile=LAB, seed=3, **cameras()) as bench:
        bench.warm_up(BOARD)
        with GrblRig(bench.tty_path, bench.rig_config) as rig:
            rig.home()
            yield bench, rig


def test_the_ideal_bench_renders_exactly_what_the_nominal_geometry_shows():
    """The ideal profile is today's bench: the frame the renderer draws at the commanded pose, bit for bit."""
    T_rig_board = board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm)
    with BenchSimulator(time_scale=50.0, profile=IDEAL, **cameras()) as bench:
        with GrblRig(bench.tty_path, bench.rig_config) as rig:
            rig.home()
            rig.move_to(baseline_mm=120.0, alpha_left_deg=85.0, alpha_right_deg=80.0).wait()
        bench.show(BOARD, T_rig_board, seed=7)
        images = {side: bench.render(side)[0] for side in ("left", "right")}
        pose = bench.rig_pose()
        renderer = StereoRenderer(BOARD, bench.left_model, bench.right_model, optics=bench.optics)
        for index, side in enumerate(("left", "right")):
            T_rig_cam = pose.T_rig_left if side == "left" else pose.T_rig_right
            view = renderer.render_view(side, np.linalg.inv(T_rig_cam) @ T_rig_board,
                                        np.random.default_rng([7, index, 0]))
            np.testing.assert_array_equal(images[side], view.image)


def test_the_frames_truth_reproduces_the_images():
    """Measured with the R, T a lab frame carries as truth (and the true lenses), the square is the printed one.

    The pattern's random jitter (``cameras.corner_noise_px``, 0.2 px: the real sets' corner scatter) is off
    here: it scatters one frame's mean square by ~0.016 mm, while this test is about the geometry the truth
    carries (JPEG, sensor noise, blur and everything else of the lab bench stay on)."""
    profile = LAB.model_copy(update={"cameras": LAB.cameras.model_copy(update={"corner_noise_px": 0.0})})
    with BenchSimulator(time_scale=50.0, profile=profile, seed=3, **cameras()) as bench, \
            GrblRig(bench.tty_path, bench.rig_config) as rig:
        rig.home()
        _the_frames_truth_reproduces_the_images(bench, rig)


def _the_frames_truth_reproduces_the_images(bench, rig):
    move_and_ask(rig, OPERATORS, baseline_mm=100.0, alpha_left_deg=80.0, alpha_right_deg=82.0, target_distance_mm=450.0)
    bench.clock.advance(0.4)  # settled
    bench.place_target(BOARD, distance_mm=450.0, seed=1)
    (left, meta_left), (right, meta_right) = bench.render("left"), bench.render("right")
    truth = meta_left["truth"]
    assert meta_right["truth"]["R"] == truth["R"] and meta_right["truth"]["T"] == truth["T"]  # one trigger
    result = measure_pair(left, right, calibration(bench.left_model, bench.right_model, truth["R"], truth["T"]), BOARD)
    square_true = bench.truth()["target"]["square_true_mm"]
    assert square_true == pytest.approx(27.0 * (1 + LAB.target.print_scale_error))
    assert result.square.mean_mm == pytest.approx(square_true, abs=0.005)
    # The structure differs from the commanded one (centres ahead of the pan axes, mounts, ...).
    assert truth["structure"]["baseline_mm"] < 100.0 - 5.0
    assert meta_left["baseline_mm"] == pytest.approx(100.0)  # what the controller reports


def test_truth_is_json_and_consistent(lab_bench):
    bench, _ = lab_bench
    truth = json.loads(json.dumps(bench.truth()))
    assert truth["profile"] == "lab" and truth["profile_values"]["slide"]["backlash_mm"] == LAB.slide.backlash_mm
    T_left = np.array(truth["cameras"]["left"]["T_bench_cam"])
    T_right = np.array(truth["cameras"]["right"]["T_bench_cam"])
    T_rl = invert_transform(T_right) @ T_left
    np.testing.assert_allclose(T_rl[:3, :3], truth["R"], atol=1e-12)
    np.testing.assert_allclose(T_rl[:3, 3], truth["T"], atol=1e-9)
    assert truth["structure"]["baseline_mm"] == pytest.approx(float(np.linalg.norm(truth["T"])))
    assert set(truth["axes"]["history"]) == {"baseline_mm", "toe_in_left_deg", "toe_in_right_deg"}


def test_backlash_through_the_controller_depends_on_the_approach():
    profile = SimProfile(slide=SlideErrors(backlash_mm=0.04))
    separations = []
    with BenchSimulator(time_scale=50.0, profile=profile, **cameras()) as bench:
        with GrblRig(bench.tty_path, bench.rig_config) as rig:
            rig.home()
            for via in (60.0, 140.0):  # reach 100 mm from below, then from above
                rig.move_to(baseline_mm=via).wait()
                rig.move_to(baseline_mm=100.0).wait()
                separations.append(bench.truth()["axes"]["separation_mm"])
    assert separations == pytest.approx([100.0 - 0.02, 100.0 + 0.02], abs=1e-9)


def test_the_mechanics_follow_where_the_motors_stand_when_the_step_counters_do_not():
    """A reboot mid-move restarts Grbl's step counters at 0 (B = 350 mm by the default mapping) wherever the
    axes stopped: the cameras stand where the axes are, through the mechanics (here a 0.1 % lead error)."""
    profile = SimProfile(slide=SlideErrors(scale_error=0.001))
    with BenchSimulator(time_scale=50.0, profile=profile, **cameras()) as bench:
        with GrblRig(bench.tty_path, bench.rig_config) as rig:
            rig.home()
            bench.emulator.inject(ResetMidMove(fraction=0.5))
            with pytest.raises(GrblResetError):
                rig.move_to(baseline_mm=100.0).wait()
        assert bench.emulator.machine_position()["X"] == 0.0
        stood_mm = bench.emulator.physical_position()["X"] + 350.0
        assert 150.0 < stood_mm < 300.0  # halfway from 349 mm to 100 mm
        assert bench.rig_pose().baseline_mm == pytest.approx(stood_mm, abs=1e-9)
        assert bench.truth()["axes"]["separation_mm"] == pytest.approx(1.001 * stood_mm, abs=1e-9)


def test_bring_up_renders_the_lab_bench_at_rest_from_the_reported_pose():
    """No emulator: the profile's static mechanics act on the pose the controller reports; motion errors
    (backlash, landing, ringing) need the axes' history and are left out."""
    reported = RigPose(150.0, 85.0, 80.0)
    T_rig_board = board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm)
    with BenchSimulator(profile=LAB, seed=3, pose_source=lambda: reported, **cameras()) as bench:
        assert bench.emulator is None and bench.history is None
        assert bench.rig_pose() == reported
        at_rest = pair_state(LAB, bench.reported_values())
        truth = bench.truth()
        np.testing.assert_allclose(truth["cameras"]["left"]["T_bench_cam"], at_rest.T_bench_left, atol=1e-12)
        np.testing.assert_allclose(truth["cameras"]["right"]["T_bench_cam"], at_rest.T_bench_right, atol=1e-12)
        assert truth["axes"]["separation_mm"] == pytest.approx(LAB.slide.zero_offset_mm
                                                               + (1 + LAB.slide.scale_error) * 150.0, abs=1e-9)
        # Not the nominal pose: the lab heads turn the cameras about axes behind their optical centres.
        assert abs(truth["structure"]["baseline_mm"] - 150.0) > 0.5
        bench.show(BOARD, T_rig_board, seed=1)
        image, meta = bench.render("left")
        np.testing.assert_allclose(meta["truth"]["T_bench_cam"], at_rest.T_bench_left[:3], atol=1e-12)
        assert image.shape == (540, 960) and meta["baseline_mm"] == 150.0


def test_frames_taken_while_the_heads_ring_carry_it_and_a_settled_one_does_not():
    """The ringing a frame sees is on the bench clock: half an exposure after the move's exact end, then what a
    settle advances it by, at any time scale (on the wall clock the two scales' frames would differ)."""
    profile = SimProfile(cameras=CameraErrors(vibration_yaw_deg=0.02, vibration_rock_deg=0.01))
    seen = {}
    for time_scale in (2.0, 40.0):
        with BenchSimulator(time_scale=time_scale, profile=profile, **cameras()) as bench:
            with GrblRig(bench.tty_path, bench.rig_config) as rig:
                rig.home()
                rig.move_to(baseline_mm=20.0).wait()
                time.sleep(0.05)  # real time passes; the bench's does not
                at_once = bench.render("left")[1]["truth"]
                bench.clock.advance(0.3)  # a settle longer than the ringing (0.24 s)
                bench.show(BOARD, board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm))
                settled = bench.render("left")[1]["truth"]
        seen[time_scale] = (at_once, settled)
        since = 0.5 * bench.exposure_s  # the move ended when the frame's exposure began
        assert at_once["ringing_deg"] == pytest.approx(ringing_deg(profile.cameras, 0.02, since)[0], abs=1e-12)
        assert at_once["rock_deg"] == pytest.approx(ringing_deg(profile.cameras, 0.01, since)[0], abs=1e-12)
        assert at_once["ringing_deg"] != 0.0
        assert settled["ringing_deg"] == 0.0 and settled["rock_deg"] == 0.0
    assert seen[2.0] == seen[40.0]


def test_a_too_short_settle_shows_in_the_measured_square():
    """Square measured with the rest calibration, on frames 0 s and 0.3 s after a slide move."""
    profile = SimProfile(cameras=CameraErrors(vibration_yaw_deg=0.02, vibration_rock_deg=0.01))
    cams = cameras()
    renderer = StereoRenderer(BOARD, cams["left"], cams["right"])
    values = {"baseline_mm": 100.0, "toe_in_left_deg": 0.0, "toe_in_right_deg": 0.0}
    history = MoveHistory(profile)
    history.moved(values, end_s=1.0, approach={"baseline_mm": 1})  # from B = 90 mm
    rest = pair_state(profile, values)
    T_rl = invert_transform(rest.T_bench_right) @ rest.T_bench_left
    calib = calibration(cams["left"], cams["right"], T_rl[:3, :3], T_rl[:3, 3])
    T_rig_board = board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm)
    errors = {}
    for settle in (0.0, 0.3):
        state = pair_state(profile, values, history=history, now_s=1.0 + settle)
        views = [renderer.render_view(side, invert_transform(state.T_bench_cam(side)) @ T_rig_board,
                                      np.random.default_rng(k)) for k, side in enumerate(("left", "right"))]
        errors[settle] = abs(measure_pair(views[0].image, views[1].image, calib, BOARD).square.mean_mm - 27.0)
    assert errors[0.0] > 0.05  # measured 0.098 mm at full resolution
    assert errors[0.3] < 0.01 and errors[0.0] > 5 * errors[0.3]


def test_the_target_is_placed_once_per_manual_placement(lab_bench):
    bench, _ = lab_bench
    first = bench.place_target(BOARD, distance_mm=500.0, seed=1)
    retry = bench.place_target(BOARD, distance_mm=500.0, seed=2)  # the next frame or a retry: not moved
    np.testing.assert_array_equal(first, retry)
    nominal = board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm)
    assert not np.allclose(first, nominal, atol=1e-3)  # off by the operator's error
    moved = bench.place_target(BOARD, distance_mm=400.0, seed=1)
    back = bench.place_target(BOARD, distance_mm=500.0, seed=1)
    assert not np.allclose(back, first, atol=1e-6)  # placed again: a new error
    placement = bench.truth()["target"]["placement"]
    assert placement["distance_mm"] == 500.0
    assert abs(placement["distance_error_mm"]) < 5 * LAB.target.placement_distance_sigma_mm
    assert abs(placement["yaw_error_deg"]) < 5 * LAB.target.placement_yaw_sigma_deg
    assert moved[2, 3] != pytest.approx(first[2, 3])


def test_a_motorised_target_distance_has_no_placement_error():
    quantities = {"target_distance_mm": QuantityMapping(axis="C", min=200.0, max=1500.0)}
    with BenchSimulator(rig_config=RigConfig(quantities=quantities), profile=LAB, **cameras()) as bench:
        placed = bench.place_target(BOARD, distance_mm=500.0)
    np.testing.assert_array_equal(placed, board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm))


def test_a_bent_oversized_print_is_rendered_as_it_is():
    """Triangulated with the true calibration, the squares are the print's and the centre bulges by the bow."""
    bow, scale = 0.6, 1.0008
    shape = BoardShape(scale=scale, bow_mm=bow)
    points = shape.object_points(BOARD)
    assert points[:, 2].min() == pytest.approx(-bow)  # the centre column stands bow_mm nearer
    assert points[[0, BOARD.cols - 1], 2] == pytest.approx([0.0, 0.0], abs=1e-12)
    cams = cameras()
    renderer = StereoRenderer(BOARD, cams["left"], cams["right"])
    pose = RigPose.symmetric(100.0)
    T_rig_board = board_pose_facing_rig(distance_mm=400.0, board_size_mm=BOARD.grid_size_mm)
    views = [renderer.render_view(side, invert_transform(T) @ T_rig_board, np.random.default_rng(k), shape=shape)
             for k, (side, T) in enumerate((("left", pose.T_rig_left), ("right", pose.T_rig_right)))]
    R, T = pose.stereo_extrinsics()
    result = measure_pair(views[0].image, views[1].image, calibration(cams["left"], cams["right"], R, T), BOARD)
    assert result.square.mean_mm == pytest.approx(27.0 * scale, abs=0.004)
    flat_views = [renderer.render_view(side, invert_transform(T_c) @ T_rig_board, np.random.default_rng(k)).image
                  for k, (side, T_c) in enumerate((("left", pose.T_rig_left), ("right", pose.T_rig_right)))]
    flat = measure_pair(*flat_views, calibration(cams["left"], cams["right"], R, T), BOARD)
    assert flat.square.mean_mm == pytest.approx(27.0, abs=0.004)
    # The rendered corners are where the bent surface projects (the renderer's own accuracy).
    for view in views:
        found = detect(view.image, BOARD)
        assert np.sqrt(((found.corners_px - view.corners_px[found.ids]) ** 2).sum(axis=1).mean()) < 0.06
    bent_px = views[0].corners_px
    flat_px = renderer.truth("left", invert_transform(pose.T_rig_left) @ T_rig_board)[0]
    assert np.abs(bent_px - flat_px).max() > 0.3  # the bend and scale really moved the corners


def test_jpeg_frames_still_detect_with_a_small_accuracy_loss():
    """MJPG at quality 85: corner RMS against the truth within 10 % of the lossless frames' (measured +4 %)."""
    cams = cameras()
    rms = {}
    for quality in (None, 85):
        renderer = StereoRenderer(BOARD, cams["left"], cams["right"], optics=Optics(jpeg_quality=quality))
        errors = []
        for seed, (distance, yaw) in enumerate([(400.0, -10.0), (450.0, 0.0), (500.0, 10.0), (600.0, 5.0)]):
            T = invert_transform(RigPose.symmetric(100.0).T_rig_left) @ board_pose_facing_rig(
                distance_mm=distance, board_size_mm=BOARD.grid_size_mm, yaw_deg=yaw)
            view = renderer.render_view("left", T, np.random.default_rng(seed))
            found = detect(view.image, BOARD)
            assert found is not None and found.n == BOARD.n_corners
            errors.append(found.corners_px - view.corners_px[found.ids])
        rms[quality] = float(np.sqrt((np.concatenate(errors) ** 2).sum(axis=1).mean()))
    assert rms[85] < 1.10 * rms[None] and rms[85] < 0.06
    assert rms[85] != rms[None]  # the frames really went through JPEG


def test_the_lens_term_is_not_absorbed_by_the_5_coefficient_calibration():
    """Exact projections through the lab lens: stereo_bench's calibration fits the views, but not the lens.

    Its reprojection error stays tiny (0.006 px measured) while the calibrated model misses the true
    lens by 0.4 px RMS over the frame (2.6 px in the corners the boards did not reach).
    """
    import cv2

    nominal = CameraModel.from_sensor()
    board = Checkerboard(11, 8, 25.0)
    poses = calibration_board_poses(RigPose.symmetric(100.0), board, n_views=15, rng=np.random.default_rng(0))
    T_cam_rig = invert_transform(RigPose.symmetric(100.0).T_rig_left)
    grid = np.stack(np.meshgrid(np.linspace(0, 1919, 40), np.linspace(0, 1079, 24)), -1).reshape(-1, 1, 2)
    misses = {}
    for name, lens in (("ideal", nominal), ("lab", true_lens(nominal, LAB.cameras.radial_high_order_left,
                                                             LAB.cameras.thin_prism_left))):
        image_points = [lens.project(transform_points(T_cam_rig @ T, board.object_points))[0] for T in poses]
        calibrated = calibrate_mono([board.object_points] * len(poses), image_points, lens.image_size)
        assert calibrated.rms_px < 0.02
        rays = cv2.undistortPoints(grid, lens.K, lens.dist).reshape(-1, 2)
        seen = cv2.projectPoints(np.column_stack([rays, np.ones(len(rays))]).reshape(-1, 1, 3), np.zeros(3),
                                 np.zeros(3), calibrated.K, calibrated.dist)[0].reshape(-1, 2)
        misses[name] = float(np.sqrt(((seen - grid.reshape(-1, 2)) ** 2).sum(axis=1).mean()))
    assert misses["ideal"] < 0.01
    assert misses["lab"] > 0.2


def test_the_calibration_board_is_shown_as_the_profile_has_it():
    profile = SimProfile(calibration_board=BoardErrors(bow_mm=1.0))
    with BenchSimulator(profile=profile, **cameras()) as bench:
        bench.show(BOARD, board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm))
        target = bench.truth()["target"]
    assert target["kind"] == "calibration_board" and target["bow_mm"] == 1.0 and target["print_scale"] == 1.0


def test_the_truth_without_landing_errors_differs_from_the_truth_by_the_moves_landing_alone(lab_bench):
    bench, rig = lab_bench
    rig.move_to(baseline_mm=140.0, alpha_left_deg=84.0, alpha_right_deg=86.0).wait()
    bench.clock.advance(0.4)  # settled: the heads no longer ring (the truth would include it, the rest pose not)
    truth, knowable = bench.truth(), bench.truth_without_landing()
    assert truth["axes"]["ringing_deg"] == {"left": 0.0, "right": 0.0}
    history = truth["axes"]["history"]
    assert history["baseline_mm"]["landing"] != 0.0
    # Only the landing errors separate them: the slide's, plus the heads' turning centres that stand
    # ~23 mm ahead of their pan axes.
    heads_rad = np.radians(abs(history["toe_in_left_deg"]["landing"]) + abs(history["toe_in_right_deg"]["landing"]))
    difference = truth["structure"]["baseline_mm"] - knowable["structure"]["baseline_mm"]
    assert abs(difference - history["baseline_mm"]["landing"]) <= 25.0 * heads_rad + 1e-9
    assert abs(truth["structure"]["alpha_left_deg"] - knowable["structure"]["alpha_left_deg"]) < 5 * 0.002
    with BenchSimulator(profile=IDEAL, **cameras()) as ideal:
        assert ideal.truth_without_landing() == {key: value for key, value in ideal.truth().items()
                                                 if key in ("R", "T", "structure")}


def _wait_rendered_ahead(bench: BenchSimulator, n: int, timeout_s: float = 60.0) -> None:
    """Until ``n`` staged scenes are rendered and checked against the rig at rest: a trigger before that (a
    loaded machine, the heads still ringing) renders anew, and the test would depend on the timing."""
    deadline = time.monotonic() + timeout_s
    while bench.staged_rendered() < n or not all(entry.checked for entry in bench._staged if entry.frames):
        assert time.monotonic() < deadline, "the staged scenes were never rendered ahead"
        time.sleep(0.01)


def test_scenes_rendered_ahead_are_the_frames_a_render_at_the_trigger_gives(lab_bench):
    """Rendered once the rig rests (landing errors drawn, ringing stopped), served at the trigger, bit for bit."""
    from drivers.camera.stereo import StereoCamera

    bench, rig = lab_bench
    move_and_ask(rig, OPERATORS, baseline_mm=140.0, alpha_left_deg=84.0, alpha_right_deg=84.0, target_distance_mm=450.0)
    bench.clock.advance(0.3)  # the settle: the heads stop ringing (on the bench clock)
    poses = [board_pose_facing_rig(distance_mm=distance, board_size_mm=BOARD.grid_size_mm, yaw_deg=yaw)
             for distance, yaw in ((400.0, 10.0), (470.0, -5.0))]
    bench.stage([("board", BOARD, pose, 50 + i) for i, pose in enumerate(poses)],
                at=RigPose.symmetric(140.0, 84.0))
    _wait_rendered_ahead(bench, 2)
    with StereoCamera(*bench.cameras()) as cameras:
        for i, pose in enumerate(poses):
            used = bench.prerendered_used
            bench.show(BOARD, pose, seed=50 + i)
            pair = cameras.capture_pair()
            assert bench.prerendered_used == used + 1
            snapshot = bench._snapshot()  # the pair at rest: what the trigger saw
            for side, frame in (("left", pair.left), ("right", pair.right)):
                image, meta = bench._render_job(side, snapshot, bench._scene, 0)
                np.testing.assert_array_equal(frame.image, image)
                assert frame.meta == meta
            assert pair.left.meta["truth"]["ringing_deg"] == 0.0


def test_a_frame_rendered_ahead_is_dropped_when_the_rig_stands_elsewhere_at_the_trigger(lab_bench):
    from drivers.camera.stereo import StereoCamera

    bench, rig = lab_bench
    move_and_ask(rig, OPERATORS, baseline_mm=160.0, alpha_left_deg=86.0, alpha_right_deg=86.0, target_distance_mm=450.0)
    bench.clock.advance(0.3)
    pose = board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm)
    bench.stage([("board", BOARD, pose, 61)], at=RigPose.symmetric(160.0, 86.0))
    _wait_rendered_ahead(bench, 1)
    move_and_ask(rig, OPERATORS, baseline_mm=161.0, alpha_left_deg=86.0, alpha_right_deg=86.0, target_distance_mm=450.0)
    bench.clock.advance(0.4)  # the ringing has stopped
    used = bench.prerendered_used
    with StereoCamera(*bench.cameras()) as cameras:
        bench.show(BOARD, pose, seed=61)
        pair = cameras.capture_pair()
    assert bench.prerendered_used == used  # rendered for B = 160 mm: not served
    assert pair.left.meta["baseline_mm"] == pytest.approx(161.0, abs=0.01)
    image, _ = bench._render_job("left", bench._snapshot(), bench._scene, 0)
    np.testing.assert_array_equal(pair.left.image, image)


def test_nothing_is_rendered_ahead_before_the_move_to_where_the_scenes_need_the_rig_is_queued(lab_bench):
    bench, rig = lab_bench
    move_and_ask(rig, OPERATORS, baseline_mm=120.0, alpha_left_deg=85.0, alpha_right_deg=85.0, target_distance_mm=450.0)
    pose = board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm)
    bench.stage([("board", BOARD, pose, 70)], at=RigPose.symmetric(200.0, 85.0))
    time.sleep(0.2)
    assert bench.staged_rendered() == 0
    move_and_ask(rig, OPERATORS, baseline_mm=200.0, alpha_left_deg=85.0, alpha_right_deg=85.0, target_distance_mm=450.0)
    bench.clock.advance(0.3)
    _wait_rendered_ahead(bench, 1)
    bench.stage([], at=RigPose.symmetric(200.0, 85.0))  # nothing left staged


@pytest.mark.slow
def capture_served_ahead_bit_for_bit(bench: BenchSimulator, pose: np.ndarray) -> None:
    """Show the staged board (seed 80) and capture a pair: it comes from the render ahead, and is bit for bit
    (image and truth) the pair a render at the trigger gives."""
    from drivers.camera.stereo import StereoCamera

    with StereoCamera(*bench.cameras()) as cameras_:
        bench.show(BOARD, pose, seed=80)
        pair = cameras_.capture_pair()
    assert bench.prerendered_used == 1
    snapshot = bench._snapshot()
    for side, frame in (("left", pair.left), ("right", pair.right)):
        image, meta = bench._render_job(side, snapshot, bench._scene, 0)
        np.testing.assert_array_equal(frame.image, image)
        assert frame.meta == meta


def test_scenes_are_rendered_during_the_move_for_where_it_will_rest_and_served_bit_for_bit():
    """The move's end is planned (whole steps) and its landing drawn as the mechanics will draw it: the
    frames rendered while the rig still moves are those a render at the trigger gives after it."""
    import threading


    # The move must last long enough for the render-ahead thread to start while it runs, on a loaded machine too
    # (at 5x it once ended before that thread was scheduled, in a full suite beside other work).
    with BenchSimulator(time_scale=2.5, profile=LAB, seed=5, **cameras()) as bench:
        with GrblRig(bench.tty_path, bench.rig_config) as rig:
            rig.home()
            move_and_ask(rig, OPERATORS, baseline_mm=60.0, alpha_left_deg=88.0, alpha_right_deg=88.0,
                         target_distance_mm=450.0)
            bench.warm_up(BOARD)
            pose = board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm, yaw_deg=4.0)
            bench.stage([("board", BOARD, pose, 80)], at=RigPose.symmetric(220.0, 84.0))
            moving = threading.Thread(target=lambda: move_and_ask(rig, OPERATORS,
                baseline_mm=220.0, alpha_left_deg=84.0, alpha_right_deg=84.0, target_distance_mm=450.0))
            moving.start()
            rendered_while_moving = False
            while moving.is_alive():
                rendered_while_moving |= bench.staged_rendered() > 0 and bench.emulator.state == "Run"
                time.sleep(0.005)
            moving.join()
        assert rendered_while_moving
        bench.clock.advance(0.5)  # the settle: the ringing has stopped
        capture_served_ahead_bit_for_bit(bench, pose)


def test_frames_rendered_for_a_wrong_prediction_are_rendered_again_once_the_rig_rests(lab_bench, monkeypatch):
    import dataclasses

    from drivers.camera.stereo import StereoCamera

    bench, rig = lab_bench
    real_predict = bench._predicted_snapshot
    wrong = []

    def predict_wrongly():  # the right pose, a camera 0.1 mm off
        snapshot = real_predict()
        if snapshot is None:
            return None
        T = {side: matrix.copy() for side, matrix in snapshot.T_rig_cam.items()}
        T["left"][0, 3] += 0.1
        wrong.append(True)
        return dataclasses.replace(snapshot, T_rig_cam=T)

    real_render = bench._render_job
    renders = []

    def render_job(side, snapshot, scene, index):
        renders.append((side, scene.seed))
        return real_render(side, snapshot, scene, index)

    monkeypatch.setattr(bench, "_predicted_snapshot", predict_wrongly)
    monkeypatch.setattr(bench, "_render_job", render_job)
    pose = board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm)
    # The prediction is made while the rig moves: on a loaded machine the render-ahead thread may not run
    # before the move ends (then nothing is predicted and the frames are simply rendered at rest), so the
    # move is made again until a prediction was made during one.
    for _ in range(5):
        renders.clear()
        move_and_ask(rig, OPERATORS, baseline_mm=40.0, alpha_left_deg=87.0, alpha_right_deg=87.0,
                     target_distance_mm=450.0)
        wrong.clear()
        bench.stage([("board", BOARD, pose, 90)], at=RigPose.symmetric(300.0, 87.0))
        move_and_ask(rig, OPERATORS, baseline_mm=300.0, alpha_left_deg=87.0, alpha_right_deg=87.0,
                     target_distance_mm=450.0)
        bench.clock.advance(0.5)
        deadline = time.monotonic() + 30
        while not all(entry.checked for entry in bench._staged):
            assert time.monotonic() < deadline
            time.sleep(0.01)
        if wrong:
            break
    used = bench.prerendered_used
    with StereoCamera(*bench.cameras()) as cameras_:
        bench.show(BOARD, pose, seed=90)
        pair = cameras_.capture_pair()
    assert bench.prerendered_used == used + 1
    assert wrong and renders.count(("left", 90)) == 2  # for the prediction, then again for the real state
    image, _ = real_render("left", bench._snapshot(), bench._scene, 0)
    np.testing.assert_array_equal(pair.left.image, image)
