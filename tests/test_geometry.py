"""Rig conventions against hand-computed poses and the issue's visibility figures."""

import numpy as np
import pytest

from stereo_bench.geometry import (
    CameraModel,
    RigPose,
    board_pose_facing_rig,
    invert_transform,
    toe_in_from_alpha,
    transform_points,
    visible_in_both,
)
from stereo_bench.targets import Checkerboard


def test_parallel_rig_extrinsics_match_stereo_calibrate_convention():
    R, T = RigPose.symmetric(100.0, 90.0).stereo_extrinsics()
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
    # X_right = X_left + T: the left centre is 100 mm to the right camera's left.
    np.testing.assert_allclose(T, [-100.0, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("alpha_deg", [90.0, 75.0, 55.0])
def test_optical_axes_follow_the_brief(alpha_deg):
    rig = RigPose.symmetric(120.0, alpha_deg)
    a = np.radians(alpha_deg)
    np.testing.assert_allclose(rig.T_rig_left[:3, 2], [np.cos(a), 0, np.sin(a)], atol=1e-12)
    np.testing.assert_allclose(rig.T_rig_right[:3, 2], [-np.cos(a), 0, np.sin(a)], atol=1e-12)
    np.testing.assert_allclose(rig.T_rig_left[:3, 3], [-60.0, 0, 0])
    np.testing.assert_allclose(rig.T_rig_right[:3, 3], [60.0, 0, 0])
    assert toe_in_from_alpha(alpha_deg) == pytest.approx(90.0 - alpha_deg)


def test_positive_tilt_turns_the_axis_down():
    rig = RigPose(100.0, tilt_left_deg=10.0)
    axis = rig.T_rig_left[:3, 2]
    assert axis[1] == pytest.approx(np.sin(np.radians(10.0)))


def test_converging_axes_meet_on_the_z_axis():
    # cot(alpha) = K / 2 puts the intersection of the optical axes at distance Z.
    baseline, distance = 100.0, 500.0
    alpha = np.degrees(np.arctan2(2 * distance, baseline))
    rig = RigPose.symmetric(baseline, alpha)
    point_rig = np.array([[0.0, 0.0, distance]])
    for T_rig_cam in (rig.T_rig_left, rig.T_rig_right):
        p = transform_points(invert_transform(T_rig_cam), point_rig)[0]
        assert abs(p[0]) < 1e-9 and abs(p[1]) < 1e-9 and p[2] > 0


@pytest.mark.parametrize("alpha_deg, expected", [(90.0, 1.0), (55.0, 30 / 54), (50.0, 6 / 54), (45.0, 0.0)])
def test_board_fraction_in_both_views(alpha_deg, expected):
    # Figures from issue 2: Z = 500 mm, B = 100 mm, 9x6 board of 27 mm squares, 1920x1080, f = 1333 px.
    board = Checkerboard(9, 6, 27.0)
    camera = CameraModel.from_sensor()
    T_rig_board = board_pose_facing_rig(distance_mm=500.0, board_size_mm=board.grid_size_mm)
    points = transform_points(T_rig_board, board.object_points)
    seen = visible_in_both(points, rig=RigPose.symmetric(100.0, alpha_deg), left=camera, right=camera, margin_px=0)
    assert seen.mean() == pytest.approx(expected, abs=1e-9)


def test_projection_rejects_points_behind_or_far_outside():
    camera = CameraModel.from_sensor()
    pixels, valid = camera.project(np.array([[0, 0, 500.0], [0, 0, -500.0], [5000.0, 0, 10.0]]))
    assert valid.tolist() == [True, False, False]
    np.testing.assert_allclose(pixels[0], camera.K[:2, 2])


def test_camera_models_compare_and_hash_by_value():
    a, b = CameraModel.from_sensor(name="left"), CameraModel.from_sensor(name="right")
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    assert a != CameraModel.from_sensor(focal_mm=6.0)


def test_board_pose_in_view_puts_the_grid_centre_on_the_view_ray_facing_the_rig():
    from stereo_bench.geometry import board_pose_in_view, mean_view_frame, rotation_deg

    rig = RigPose(baseline_mm=150.0, alpha_left_deg=80.0, alpha_right_deg=85.0)
    R_view = mean_view_frame(rig.T_rig_left, rig.T_rig_right)
    np.testing.assert_allclose(R_view.T @ R_view, np.eye(3), atol=1e-12)
    assert abs(R_view[1, 0]) < 1e-15 and R_view[:, 2] @ rig.T_rig_left[:3, 2] > 0.9  # x in the rig's x-z plane
    grid_centre = np.array([100.0, 60.0, 0.0])
    T = board_pose_in_view(R_view, grid_centre, 500.0, (0.1, -0.05), 0.0, 0.0, 0.0)
    centre_rig = T[:3, :3] @ grid_centre + T[:3, 3]
    np.testing.assert_allclose(centre_rig, 500.0 * R_view @ np.array([0.1, -0.05, 1.0]), atol=1e-9)
    np.testing.assert_allclose(T[:3, 2], centre_rig / np.linalg.norm(centre_rig), atol=1e-12)  # faces the rig
    turned = board_pose_in_view(R_view, grid_centre, 500.0, (0.1, -0.05), 20.0, 0.0, 0.0)
    np.testing.assert_allclose(turned[:3, :3], T[:3, :3] @ rotation_deg("y", 20.0), atol=1e-12)
    with pytest.raises(ValueError, match="axis"):
        rotation_deg("w", 1.0)
