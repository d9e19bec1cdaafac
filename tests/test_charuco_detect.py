"""The fast ChArUco detector against OpenCV's plain default one, on rendered views with ground truth.

The exp2 presets calibrate with a 12x9 board of 15 mm squares at 300-700 mm, up to ~55 deg toe-in.
stereo-bench must give the same ids and corners as ``cv2.aruco.CharucoDetector(board).detectBoard``
with default parameters, and so the same accuracy against the renderer's truth.
Timing is measured by scripts/bench_vision.py, not here.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from drivers.sim.render import StereoRenderer, calibration_board_poses
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
from stereo_bench.targets import CharucoTarget, Checkerboard
from stereo_bench.vision.detect import _charuco_detector, board_markers_only, detect

CAMERA = CameraModel.from_sensor()
BOARD = CharucoTarget(12, 9, 15.0, 11.25)  # the exp2 presets' calibration board (marker 0.75 x square)
SAME_CORNER_TOLERANCE_PX = 1e-3  # observed: bit-identical


def _views():
    """{name: RenderedView}: whole boards at the presets' distances, tilted calibration views, and
    partial views at strong toe-in (seeded)."""
    renderer = StereoRenderer(BOARD, CAMERA, CAMERA)
    rng = np.random.default_rng(14)
    views = {}
    parallel = RigPose.symmetric(100.0, 90.0)
    for z in (300.0, 500.0, 700.0):
        pose = board_pose_facing_rig(distance_mm=z, board_size_mm=BOARD.grid_size_mm)
        views[f"parallel Z={z:g}"] = renderer.render_pair(parallel, pose, rng).left
    toed = RigPose.symmetric(100.0, 65.0)
    for i, pose in enumerate(calibration_board_poses(toed, BOARD, n_views=2, rng=rng, min_fraction_visible=0.5,
                                                     distance_mm=(300.0, 650.0))):
        views[f"tilted calibration view {i}"] = renderer.render_pair(toed, pose, rng).right
    for toe_in_deg, z in ((45.0, 500.0), (55.0, 300.0)):
        pose = board_pose_facing_rig(distance_mm=z, board_size_mm=BOARD.grid_size_mm)
        views[f"toe-in {toe_in_deg:g} Z={z:g}"] = renderer.render_pair(
            RigPose.symmetric(100.0, 90.0 - toe_in_deg), pose, rng).left
    return views


@pytest.fixture(scope="module")
def views():
    return _views()


@pytest.fixture(scope="module")
def detections(views):
    """{name: (view, the default detector's (ids, corners), ours)}: the default detector is slow, run it once."""
    return {name: (view, default_detection(view.image), detect(view.image, BOARD)) for name, view in views.items()}


def default_detection(image: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(ids (N,), corners (N, 2)) of OpenCV's default ChArUco detector, in id order; None if nothing."""
    corners, ids, _, _ = cv2.aruco.CharucoDetector(BOARD.cv_board).detectBoard(image)
    if ids is None or len(ids) == 0:
        return None
    ids = np.asarray(ids).reshape(-1)
    order = np.argsort(ids)
    return ids[order], np.asarray(corners, np.float64).reshape(-1, 2)[order]


def rms_px(corners: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((corners - truth) ** 2, axis=1))))


def test_identifies_against_the_boards_own_markers_only():
    fast = _charuco_detector(BOARD).getBoard()
    assert fast.getDictionary().bytesList.shape[0] == BOARD.squares_x * BOARD.squares_y // 2 == 54
    assert fast.getDictionary().maxCorrectionBits == BOARD.cv_board.getDictionary().maxCorrectionBits
    np.testing.assert_array_equal(fast.getIds(), BOARD.cv_board.getIds())
    np.testing.assert_array_equal(fast.getChessboardCorners(), BOARD.cv_board.getChessboardCorners())


def test_legacy_pattern_survives_the_cut():
    assert board_markers_only(CharucoTarget(5, 7, 20.0, 15.0, legacy_pattern=True).cv_board).getLegacyPattern()


def test_same_ids_and_corners_as_the_default_detector(detections):
    for name, (view, expected, found) in detections.items():
        assert expected is not None and found is not None, name
        np.testing.assert_array_equal(found.ids, expected[0], err_msg=name)
        np.testing.assert_allclose(found.corners_px, expected[1], atol=SAME_CORNER_TOLERANCE_PX, rtol=0, err_msg=name)
        assert set(found.ids) <= set(np.flatnonzero(view.visible)), name


def test_partial_views_at_strong_toe_in_are_found(detections):
    for name in ("toe-in 45 Z=500", "toe-in 55 Z=300"):
        _, _, found = detections[name]
        assert 4 <= found.n < 0.5 * BOARD.n_corners, name  # partial, and still measured


def test_accuracy_against_truth_within_5_percent_of_the_default(detections):
    ours, theirs = [], []
    for view, (expected_ids, expected_corners), found in detections.values():
        ours.append(rms_px(found.corners_px, view.corners_px[found.ids]))
        theirs.append(rms_px(expected_corners, view.corners_px[expected_ids]))
    ours_rms, theirs_rms = np.sqrt(np.mean(np.square(ours))), np.sqrt(np.mean(np.square(theirs)))
    assert ours_rms <= 1.05 * theirs_rms, f"{ours_rms:.4f} px vs default {theirs_rms:.4f} px"
    assert theirs_rms < 0.2  # the comparison means something: both are sub-pixel against the truth


def test_a_marker_from_beyond_the_board_changes_nothing(views):
    """A DICT_5X5_1000 marker the board does not use (id 600) stuck on the wall: the default detector
    identifies and then ignores it; ours rejects it. Same corners either way."""
    image = views["parallel Z=700"].image.copy()
    marker = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_1000).generateImageMarker(600, 70)
    image[60:190, 60:190] = 225
    image[90:160, 90:160] = np.where(marker > 0, 225, 25).astype(np.uint8)
    _, ids, _, marker_ids = cv2.aruco.CharucoDetector(BOARD.cv_board).detectBoard(image)
    assert 600 in np.asarray(marker_ids).reshape(-1)  # the default did see it
    expected = default_detection(image)
    found = detect(image, BOARD)
    np.testing.assert_array_equal(found.ids, expected[0])
    np.testing.assert_allclose(found.corners_px, expected[1], atol=SAME_CORNER_TOLERANCE_PX, rtol=0)


def test_a_frame_without_the_board_gives_none():
    renderer = StereoRenderer(BOARD, CAMERA, CAMERA)
    rng = np.random.default_rng(3)
    behind = board_pose_facing_rig(distance_mm=-500.0, board_size_mm=BOARD.grid_size_mm)  # a frame of the wall
    wall = renderer.render_pair(RigPose.symmetric(100.0, 90.0), behind, rng).left.image
    assert default_detection(wall) is None
    assert detect(wall, BOARD) is None
    target = Checkerboard(9, 6, 27.0)  # the measured target, which has squares but no markers
    pose = board_pose_facing_rig(distance_mm=400.0, board_size_mm=target.grid_size_mm)
    checkerboard = StereoRenderer(target, CAMERA, CAMERA).render_pair(RigPose.symmetric(100.0, 90.0), pose, rng)
    assert detect(checkerboard.left.image, BOARD) is None
