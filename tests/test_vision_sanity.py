"""Physical sanity of calibrations and measurements (issue 9): the rules and their thresholds, on exact synthetic
rigs (no images), each checked on both sides of its threshold."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig, invert_transform, transform_points
from stereo_bench.targets import MAX_BOARD_CORNERS, CharucoTarget, Checkerboard, parse_pattern
from stereo_bench.vision.calibrate import MIN_BASELINE_MM, StereoCalibration, calibration_problems, camera_problems
from stereo_bench.vision.pipeline import (
    EPIPOLAR_FACTOR,
    EPIPOLAR_FLOOR_PX,
    MIN_PARALLAX_PX,
    ImplausibleMeasurement,
    check_epipolar,
    check_measurement,
    epipolar_limit_px,
)
from stereo_bench.vision.triangulate import camera_depths_mm, parallax_px, triangulate

CAMERA = CameraModel.from_sensor()  # the simulated rig's: 1920x1080, f = 1333.3 px
TARGET = Checkerboard(9, 6, 27.0)


def _calibration(rig: RigPose, **changes) -> StereoCalibration:
    """The exact calibration of a rig (R, T from its camera poses), with fields changed as given."""
    T_right_left = invert_transform(rig.T_rig_right) @ rig.T_rig_left
    D = CAMERA.dist.reshape(1, -1)
    calib = StereoCalibration(K1=CAMERA.K, D1=D, K2=CAMERA.K, D2=D, R=T_right_left[:3, :3], T=T_right_left[:3, 3],
                              image_size=CAMERA.image_size)
    return dataclasses.replace(calib, **changes)


def _pixels(rig: RigPose, distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
    T_rig_board = board_pose_facing_rig(distance_mm=distance_mm, board_size_mm=TARGET.grid_size_mm)
    points = np.asarray(TARGET.object_points, float)
    views = []
    for T_rig_cam in (rig.T_rig_left, rig.T_rig_right):
        pixels, _ = CAMERA.project(transform_points(invert_transform(T_rig_cam) @ T_rig_board, points))
        views.append(pixels)
    return views[0], views[1]


def test_a_real_rig_passes_and_its_parallax_is_f_b_over_z():
    rig = RigPose.symmetric(100.0, 90.0)
    calib = _calibration(rig)
    assert calibration_problems(calib) == []
    left, right = _pixels(rig, 500.0)
    points = triangulate(calib, left, right)
    check_measurement(calib, points)  # no exception
    depth_left, depth_right = camera_depths_mm(calib, points)
    assert np.all(depth_left > 0) and np.all(depth_right > 0)
    # The rig's centre line at Z = 500 mm (left frame x = +B/2): the rays differ by 2 atan(B/2 / Z).
    centre = np.array([[50.0, 0.0, 500.0]])
    assert parallax_px(calib, centre)[0] == pytest.approx(2 * np.arctan(50.0 / 500.0) * CAMERA.fx, rel=1e-9)


def test_swapped_images_put_the_corners_behind_the_cameras():
    rig = RigPose.symmetric(100.0, 90.0)
    calib = _calibration(rig)
    left, right = _pixels(rig, 500.0)
    points = triangulate(calib, right, left)
    assert np.median(points[:, 2]) < 0  # what the issue saw: a square at depth -500 mm
    with pytest.raises(ImplausibleMeasurement, match="swapped"):
        check_measurement(calib, points)


def test_the_same_image_twice_has_no_parallax():
    rig = RigPose.symmetric(100.0, 90.0)
    calib = _calibration(rig)
    left, _ = _pixels(rig, 500.0)
    # Identical pixels: the rays are parallel and meet at infinity, or numerically just in front of it.
    points = triangulate(calib, left, left)
    assert not np.all(np.isfinite(points)) or np.median(parallax_px(calib, points)) < MIN_PARALLAX_PX
    with pytest.raises(ImplausibleMeasurement):
        check_measurement(calib, points)


def test_parallax_threshold_is_one_pixel():
    rig = RigPose.symmetric(100.0, 90.0)
    calib = _calibration(rig)
    f_b = CAMERA.fx * 100.0  # mm: the depth at which a parallel rig's parallax is one pixel
    near = np.array([[0.0, 0.0, 0.9 * f_b]])
    far = np.array([[0.0, 0.0, 1.1 * f_b]])
    check_measurement(calib, near)
    with pytest.raises(ImplausibleMeasurement, match="parallax"):
        check_measurement(calib, far)


@pytest.mark.parametrize(("baseline_mm", "degenerate"), [(0.0, True), (0.5, True), (2.0, False)])
def test_a_baseline_under_one_millimetre_is_degenerate(baseline_mm, degenerate):
    calib = _calibration(RigPose.symmetric(100.0, 90.0), T=np.array([-baseline_mm, 0.0, 0.0]))
    problems = calibration_problems(calib)
    assert any("baseline" in p for p in problems) == degenerate
    assert MIN_BASELINE_MM == 1.0


def test_non_finite_entries_and_a_non_rotation_are_refused():
    rig = RigPose.symmetric(100.0, 90.0)
    assert "non-finite" in calibration_problems(_calibration(rig, T=np.array([np.nan, 0.0, 0.0])))[0]
    K = CAMERA.K.copy()
    K[0, 0] = np.inf
    assert "non-finite" in calibration_problems(_calibration(rig, K1=K))[0]
    assert "rotation" in calibration_problems(_calibration(rig, R=2.0 * np.eye(3)))[0]
    assert "rotation" in calibration_problems(_calibration(rig, R=np.diag([1.0, 1.0, -1.0])))[0]  # a reflection


def test_intrinsics_of_another_image_size_put_the_principal_point_outside():
    # The case: 1920x1080 intrinsics (cx = 959.5) for 640x480 images.
    problems = camera_problems(CAMERA.K, CAMERA.dist, (640, 480), "left camera")
    assert problems and "principal point (959.5, 539.5)" in problems[0] and "640x480" in problems[0]
    assert camera_problems(CAMERA.K, CAMERA.dist, (1920, 1080), "left camera") == []


def test_epipolar_far_beyond_the_calibration_is_3x_and_over_1_px():
    assert (EPIPOLAR_FACTOR, EPIPOLAR_FLOOR_PX) == (3.0, 1.0)
    assert epipolar_limit_px(0.5) == pytest.approx(1.5)  # 3 x the calibration's
    assert epipolar_limit_px(0.1) == pytest.approx(1.0)  # the floor
    assert epipolar_limit_px(None) == pytest.approx(1.0)  # a calibration that recorded nothing
    check_epipolar(1.49, 0.5)
    with pytest.raises(ImplausibleMeasurement, match="3x the calibration's 0.500 px"):
        check_epipolar(1.51, 0.5)
    check_epipolar(0.99, 0.1)
    with pytest.raises(ImplausibleMeasurement):
        check_epipolar(float("nan"), 0.1)


def test_board_size_bounds():
    assert parse_pattern("100x100") == (100, 100)  # 10,000 corners: the bound itself
    with pytest.raises(ValueError, match="at most 10000"):
        parse_pattern("1000x999")
    with pytest.raises(ValueError, match="at most"):
        Checkerboard(101, 100, 1.0)
    assert Checkerboard(100, 99, 1.0).n_corners <= MAX_BOARD_CORNERS
    CharucoTarget(44, 45, 10.0, 7.5)  # 990 markers: fits DICT_5X5_1000
    with pytest.raises(ValueError, match="DICT_5X5_1000 holds only 1000"):
        CharucoTarget(45, 46, 10.0, 7.5)  # 1035 markers
    with pytest.raises(ValueError, match="DICT_4X4_50 holds only 50"):
        CharucoTarget(11, 10, 10.0, 7.5, dictionary="DICT_4X4_50")


def test_a_campaign_records_an_impossible_frame_as_failed():
    from stereo_bench.campaign.analysis import AnalysisError, ConfigurationAnalysis, measure_configuration
    from stereo_bench.vision.detect import Detection
    from stereo_bench.vision.rectify import rectify

    rig = RigPose.symmetric(100.0, 90.0)
    calib = _calibration(rig)
    left, right = _pixels(rig, 500.0)
    ids = np.arange(TARGET.n_corners)
    detected = [Detection(ids, px, CAMERA.image_size, "colour", np.full(len(ids), 0.05)) for px in (right, left)]
    blank = np.zeros(CAMERA.image_size[::-1], np.uint8)  # the detections stand for the images
    analysis = ConfigurationAnalysis(calib=calib, rect=rectify(calib))
    with pytest.raises(AnalysisError, match="swapped"):  # the frame is failed with the reason, nothing crashes
        measure_configuration(analysis, [(blank, blank)], TARGET, partial=False, detections=[tuple(detected)])
    assert analysis.frames_failed and "behind the cameras" in analysis.frames_failed[0]["reason"]
