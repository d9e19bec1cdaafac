"""The vectorised DLT of triangulate_normalised is OpenCV's triangulatePoints to round-off, on well and badly
conditioned rays, and falls back on it where its iteration does not settle (rays nearly parallel)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereo_bench.vision import triangulate as module
from stereo_bench.vision.triangulate import triangulate_normalised

P1 = np.hstack([np.eye(3), np.zeros((3, 1))])


def opencv_dlt(R: np.ndarray, T: np.ndarray, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    homogeneous = cv2.triangulatePoints(P1, np.hstack([R, T.reshape(3, 1)]), left.T.copy(), right.T.copy())
    return (homogeneous[:3] / homogeneous[3]).T


def rays(seed: int, n: int, baseline_mm: float, noise: float, far_mm: float) -> tuple[np.ndarray, ...]:
    """(R, T, left, right): normalised coordinates of random points seen by a rig, with per-coordinate noise."""
    rng = np.random.default_rng(seed)
    R = cv2.Rodrigues(np.array([0.02, -0.1, 0.01]))[0]
    T = np.array([-baseline_mm, 1.0, 3.0])
    points = np.column_stack([rng.uniform(-200, 200, n), rng.uniform(-150, 150, n), rng.uniform(300, far_mm, n)])
    moved = points @ R.T + T
    left = points[:, :2] / points[:, 2:] + rng.normal(0, noise, (n, 2))
    right = moved[:, :2] / moved[:, 2:] + rng.normal(0, noise, (n, 2))
    return R, T, left, right


@pytest.mark.parametrize(("baseline_mm", "noise", "far_mm", "tolerance"), [
    (100.0, 3e-4, 900.0, 1e-12),  # a calibration's views: 0.3 px at f = 1000 px
    (100.0, 1e-2, 900.0, 1e-12),  # 10 px: the inconsistent views of an unsynchronised pair
    (1000.0, 3e-4, 3000.0, 1e-12),
    (5.0, 1e-2, 3000.0, 1e-7),  # nearly parallel rays (a parallax of 1/600): OpenCV's own round-off is large
    (5.0, 0.1, 3000.0, 1e-7),  # and with noise beyond any camera's: Newton overshoots past the first pole
])
def test_the_vectorised_dlt_is_opencvs(baseline_mm, noise, far_mm, tolerance):
    R, T, left, right = rays(7, 20000, baseline_mm, noise, far_mm)
    expected = opencv_dlt(R, T, left, right)
    got = triangulate_normalised(R, T, left, right)
    relative = np.abs(got - expected).max(axis=1) / np.linalg.norm(expected, axis=1)
    assert got.shape == (20000, 3)
    assert relative.max() < tolerance
    # the DLT solves to ~1e-16 of a point: the median point agrees to a few of those (not to 1e-12 by luck)
    assert np.median(relative) < 1e-14


def test_unsettled_points_go_through_opencv_and_settled_ones_do_not(monkeypatch):
    calls = []
    original = module.cv2.triangulatePoints

    def counted(*args):
        calls.append(args[2].shape[1])
        return original(*args)

    monkeypatch.setattr(module.cv2, "triangulatePoints", counted)
    triangulate_normalised(*rays(3, 5000, 100.0, 3e-4, 900.0))
    assert calls == []  # a calibration's rays settle in the Newton steps
    triangulate_normalised(*rays(3, 5000, 5.0, 0.1, 3000.0))
    assert len(calls) == 1 and 0 < calls[0] < 5000  # some do not: those alone go to OpenCV


def test_parallel_rays_give_opencvs_points_at_infinity():
    """The same image as left and right: rays parallel, the DLT's W ~ 0 (the parallax check then refuses)."""
    left = np.random.default_rng(1).uniform(-0.3, 0.3, (50, 2))
    R, T = np.eye(3), np.array([-100.0, 0.0, 0.0])
    np.testing.assert_array_equal(triangulate_normalised(R, T, left, left), opencv_dlt(R, T, left, left))


def test_points_stacked_into_one_call_come_out_as_from_calls_of_their_own():
    R, T, left, right = rays(11, 40, 100.0, 1e-3, 900.0)
    stacked = triangulate_normalised(R, T, left, right)
    for i in range(len(left)):
        np.testing.assert_array_equal(triangulate_normalised(R, T, left[i:i + 1], right[i:i + 1])[0], stacked[i])
