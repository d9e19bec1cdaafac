"""Calibration on synthetic projections: parameter sigmas, per-view errors and the outlier rule."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereo_bench.geometry import CameraModel, RigPose, invert_transform, make_transform, transform_points
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import OUTLIER_FLOOR_PX, calibrate_mono, calibrate_stereo

BOARD = Checkerboard(11, 8, 25.0)
CAMERA = CameraModel.from_sensor()


def synthetic_views(n_views: int, rng: np.random.Generator, noise_px: float = 0.05):
    """Board poses in front of a parallel rig, projected exactly, plus Gaussian corner noise."""
    rig = RigPose.symmetric(100.0, 90.0)
    objects, lefts, rights = [], [], []
    centre = np.array([BOARD.grid_size_mm[0] / 2, BOARD.grid_size_mm[1] / 2, 0.0])
    while len(objects) < n_views:
        rvec = rng.uniform(-0.5, 0.5, 3) * [1, 1, 0.3]
        R, _ = cv2.Rodrigues(rvec)
        position = [rng.uniform(-80, 80), rng.uniform(-50, 50), rng.uniform(450, 800)]
        T_rig_board = make_transform(R, np.array(position) - R @ centre)
        views = []
        for T_rig_cam in (rig.T_rig_left, rig.T_rig_right):
            points = transform_points(invert_transform(T_rig_cam) @ T_rig_board, BOARD.object_points)
            pixels, valid = CAMERA.project(points)
            if not (valid & CAMERA.in_image(pixels, margin_px=5)).all():
                break
            views.append(pixels + rng.normal(0, noise_px, pixels.shape))
        if len(views) == 2:
            objects.append(BOARD.object_points)
            lefts.append(views[0])
            rights.append(views[1])
    return rig, objects, lefts, rights


def test_mono_calibration_reports_sigmas_and_per_view_errors():
    _, objects, lefts, _ = synthetic_views(15, np.random.default_rng(1))
    mono = calibrate_mono(objects, lefts, CAMERA.image_size)
    assert mono.fx == pytest.approx(CAMERA.fx, rel=1e-3)
    assert len(mono.per_view_rms_px) == 15 and mono.views_rejected == []
    assert mono.rms_px == pytest.approx(0.05 * np.sqrt(2), rel=0.1)  # OpenCV reports 2-D distances
    # The reported standard deviation of fx describes its actual error (within 4 sigma).
    assert 0 < mono.std_intrinsics["fx"] < 2.0
    assert abs(mono.fx - CAMERA.fx) < 4 * mono.std_intrinsics["fx"]


def test_a_gross_outlier_view_is_rejected_and_the_calibration_repeated():
    rig, objects, lefts, rights = synthetic_views(14, np.random.default_rng(2))
    rng = np.random.default_rng(3)
    rights[5] = rights[5] + rng.normal(0, 2.0, rights[5].shape)  # a view spoiled by motion blur, say
    result = calibrate_stereo(objects, lefts, rights, CAMERA.image_size)
    assert [r.index for r in result.views_rejected] == [5]
    assert "right" in result.views_rejected[0].reason and "px >" in result.views_rejected[0].reason
    assert 5 not in result.views_used and len(result.views_used) == 13
    _, T_true = rig.stereo_extrinsics()
    assert result.baseline_mm == pytest.approx(np.linalg.norm(T_true), rel=1e-3)
    assert result.rms_px < OUTLIER_FLOOR_PX


def test_uniformly_good_views_are_all_kept():
    _, objects, lefts, rights = synthetic_views(12, np.random.default_rng(4))
    result = calibrate_stereo(objects, lefts, rights, CAMERA.image_size, mode="joint")
    assert result.views_rejected == [] and len(result.views_used) == 12
    assert result.per_view_rms_px.shape == (12, 2)


def test_too_few_views_is_a_clear_error():
    _, objects, lefts, rights = synthetic_views(3, np.random.default_rng(5))
    with pytest.raises(ValueError, match="at least 5 views"):
        calibrate_stereo(objects, lefts, rights, CAMERA.image_size)
