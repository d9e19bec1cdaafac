"""The simulated bench: the real GRBL driver over a pty, cameras rendering from the emulator's axes."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera.stereo import StereoCamera
from drivers.rig.rig import GrblRig
from drivers.sim.bench import BenchSimulator
from stereo_bench.campaign.operator import OperatorDesk, SimulatedOperator, move_and_ask
from stereo_bench.geometry import RigPose, board_pose_facing_rig
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.pipeline import ImplausibleMeasurement, measure_pair

BOARD = Checkerboard(9, 6, 27.0)

#: Stands in for the operator at the manual steps (the target distance), as a campaign's simulator does.
OPERATORS = OperatorDesk([SimulatedOperator()])


@pytest.fixture(scope="module")
def bench():
    with BenchSimulator(time_scale=50.0) as bench:
        yield bench


def calibration_for(pose: RigPose, bench: BenchSimulator) -> StereoCalibration:
    R, T = pose.stereo_extrinsics()
    camera = bench.left_model
    D = camera.dist.reshape(1, -1)
    return StereoCalibration(K1=camera.K, D1=D, K2=camera.K, D2=D, R=R, T=T, image_size=camera.image_size)


def test_cameras_see_the_board_from_where_the_motors_are(bench):
    with GrblRig(bench.tty_path, bench.rig_config) as rig:
        rig.home()
        move_and_ask(rig, OPERATORS, baseline_mm=120.0, alpha_left_deg=80.0, alpha_right_deg=80.0,
                     target_distance_mm=500.0)
        last_prompt = OPERATORS.operators[0].prompts[-1].message
        assert "500" in last_prompt  # the target distance is manual: the operator was asked
        pose = bench.rig_pose()
        assert pose.baseline_mm == pytest.approx(120.0, abs=0.01)
        assert pose.alpha_left_deg == pytest.approx(80.0, abs=0.01)
        bench.show(BOARD, board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm), seed=3)
        with StereoCamera(*bench.cameras()) as cameras:
            cameras.flush()
            pair = cameras.capture_pair()
        assert pair.dt_s == 0.0  # the simulated pair is hardware-triggered
        assert pair.left.meta["baseline_mm"] == pytest.approx(120.0, abs=0.01)
        result = measure_pair(pair.left.image, pair.right.image, calibration_for(pose, bench), BOARD)
        assert abs(result.square.mean_mm - 27.0) < 0.05
        # With the calibration of another pose (parallel instead of 10 deg toe-in) the rays meet behind the
        # cameras and the measurement is refused: the images really follow the axes.
        with pytest.raises(ImplausibleMeasurement, match="behind the cameras"):
            measure_pair(pair.left.image, pair.right.image, calibration_for(RigPose.symmetric(120.0, 90.0), bench),
                         BOARD)


def test_a_stereo_pair_takes_one_exposure_for_both_cameras(bench):
    """Both cameras expose on one trigger: the second grab of a pair does not wait a second exposure."""
    import time

    bench.show(BOARD, board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm), seed=4)
    bench.render("left")  # builds the renderer (~1 s) before the timed exposure
    exposure_s = bench.exposure_s
    bench.exposure_s = 1.0 * bench.time_scale  # 1 s of real time: longer than a render, even on a busy machine
    try:
        left, right = bench.cameras()
        slept = {"left": [], "right": []}
        for side, camera in (("left", left), ("right", right)):
            camera._sleep = lambda s, side=side: (slept[side].append(s), time.sleep(s))
        with StereoCamera(left, right) as cameras:
            started = time.monotonic()
            pair = cameras.capture_pair()
            took_s = time.monotonic() - started
    finally:
        bench.exposure_s = exposure_s
    assert pair.dt_s == 0.0
    assert len(slept["left"]) == 1 and slept["right"] == []  # the right frame was read out with the left one
    assert took_s >= 1.0


def test_frames_of_a_scene_are_reproducible(bench):
    bench.show(BOARD, board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm), seed=9)
    first, _ = bench.render("left")
    bench.show(BOARD, board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm), seed=9)
    again, _ = bench.render("left")
    np.testing.assert_array_equal(first, again)
    other, _ = bench.render("left")  # the next frame of the same scene has fresh noise
    assert np.any(other != first)


def test_an_empty_scene_shows_no_board(bench):
    bench.show(None)
    image, _ = bench.render("right")
    assert image.shape == (1080, 1920)
    assert image.std() < 30  # the wall only
