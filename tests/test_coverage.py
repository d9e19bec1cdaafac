"""Calibration coverage (campaign/coverage.py): ROS camera_calibration's X / Y / size / skew, checked on
boards projected by a known camera, and the bars, the occupancy map and discarding a view."""

from __future__ import annotations

import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from stereo_bench.campaign.coverage import Coverage, coverage_bars, occupancy, view_parameters
from stereo_bench.targets import Checkerboard

BOARD = Checkerboard(9, 6, 25.0)
SIZE = (1920, 1080)
K = np.array([[1333.0, 0, 959.5], [0, 1333.0, 539.5], [0, 0, 1]])


def project(rvec, tvec) -> np.ndarray:
    """The board's corners (ids 0..53, row-major) seen by an undistorted camera, (N, 2) px."""
    points, _ = cv2.projectPoints(BOARD.object_points.astype(np.float64), np.asarray(rvec, float),
                                  np.asarray(tvec, float), K, None)
    return points.reshape(-1, 2)


def centred_tvec(distance_mm: float) -> list[float]:
    width, height = BOARD.grid_size_mm
    return [-width / 2, -height / 2, distance_mm]


def test_a_square_on_board_in_the_centre():
    corners = project([0, 0, 0], centred_tvec(600))
    params = view_parameters(corners, np.arange(BOARD.n_corners), BOARD, SIZE)
    # Square-on and centred: X = Y = 0.5 whatever the size, no skew; size from the outline's area.
    width_px = 200 * 1333.0 / 600
    height_px = 125 * 1333.0 / 600
    assert params.x == pytest.approx(0.5, abs=1e-3) and params.y == pytest.approx(0.5, abs=1e-3)
    assert params.skew == pytest.approx(0.0, abs=1e-9)
    assert params.size == pytest.approx(math.sqrt(width_px * height_px / (SIZE[0] * SIZE[1])), rel=1e-6)


def test_a_turned_board_has_skew_and_an_off_centre_one_moves_x():
    turned = view_parameters(project([0, math.radians(40), 0], centred_tvec(600)), np.arange(54), BOARD, SIZE)
    assert 0.05 < turned.skew <= 1.0
    # An in-plane rotation keeps the corners' right angles: no skew.
    rolled = view_parameters(project([0, 0, math.radians(30)], centred_tvec(600)), np.arange(54), BOARD, SIZE)
    assert rolled.skew == pytest.approx(0.0, abs=1e-6)
    right = view_parameters(project([0, 0, 0], [150.0, -62.5, 600]), np.arange(54), BOARD, SIZE)
    assert right.x > 0.8 and right.y == pytest.approx(0.5, abs=1e-3)


def test_a_partial_view_without_its_outline_corners_has_an_area_but_no_skew():
    corners = project([0, 0, 0], centred_tvec(600))
    ids = np.array([i for i in range(54) if i not in (0, 8)])  # two outline corners cut off
    params = view_parameters(corners[ids], ids, BOARD, SIZE)
    assert params.skew is None and 0 < params.size < 0.5


def test_bars_follow_ros_progress_and_discard_forgets_a_view():
    coverage = Coverage(SIZE, BOARD)
    left = project([0, 0, 0], [-400.0, -200.0, 600])  # upper left
    right = project([0, 0, 0], [200.0, 80.0, 600])  # lower right
    for index, corners in enumerate((left, right)):
        detection = SimpleNamespace(corners_px=corners, ids=np.arange(54))
        coverage.add("left", index, detection)
        coverage.add("right", index, detection)
    bars = {bar.name: bar for bar in coverage.bars("left")}
    span_x = bars["X"].high - bars["X"].low
    assert bars["X"].progress == pytest.approx(min(span_x / 0.7, 1.0))
    assert bars["size"].low == 0.0 and bars["size"].progress == pytest.approx(min(bars["size"].high / 0.4, 1.0))
    grid = coverage.occupancy("left")
    assert grid.sum() == 2 * 54 and grid.shape == (20, 20)
    assert grid[:10, :10].sum() == 54  # the upper-left view's corners
    coverage.discard(0)
    assert coverage.occupancy("left").sum() == 54 and coverage.as_dict()["right"]["views"] == [1]
    assert "coverage left X" in coverage.summary()


def test_no_views_no_progress_and_occupancy_clips_to_the_image():
    assert all(bar.progress == 0.0 for bar in coverage_bars([]))
    grid = occupancy([np.array([[-5.0, -5.0], [1919.9, 1079.9], [5000.0, 10.0]])], SIZE, cells=4)
    assert grid[0, 0] == 1 and grid[3, 3] == 1 and grid[0, 3] == 1 and grid.sum() == 3


def test_the_bench_presenter_offers_capture_and_discard_and_its_coverage_forgets_a_discarded_view():
    from stereo_bench.campaign.operator import CAPTURE_NOW, CONTINUE, DISCARD_LAST_VIEW
    from stereo_bench.campaign.presenters import OperatorPresenter

    presenter = OperatorPresenter(image_size=SIZE, target_description="9x6 board", calibration_board=BOARD)
    presenter.prepare_calibration(3)
    assert presenter.present_calibration_view(0).actions == (CONTINUE, CAPTURE_NOW)  # nothing to discard yet
    detection = SimpleNamespace(corners_px=project([0, 0, 0], centred_tvec(600)), ids=np.arange(54))
    presenter.calibration_view_captured(0, detection, detection)
    second = presenter.present_calibration_view(1)
    assert DISCARD_LAST_VIEW in second.actions and "d + Enter" in second.message
    size = view_parameters(detection.corners_px, detection.ids, BOARD, SIZE).size
    # One square-on view in the middle: no X/Y span, no skew, size counted from 0 (ROS range 0.4).
    assert f"left X 0% Y 0% size {min(size / 0.4, 1):.0%} skew 0%" in second.message
    presenter.calibration_view_discarded(0)
    assert presenter.coverage.occupancy("left").sum() == 0
    review = presenter.review_calibration()
    assert review.kind == "calibration_review" and review.actions == (CONTINUE, DISCARD_LAST_VIEW)
