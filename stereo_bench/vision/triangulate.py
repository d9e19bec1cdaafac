"""Triangulation of matched corners into the left camera frame."""

from __future__ import annotations

import cv2
import numpy as np

from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.rectify import undistort_points


def triangulate(calib: StereoCalibration, left_px: np.ndarray, right_px: np.ndarray) -> np.ndarray:
    """(N, 2) + (N, 2) matched raw pixels -> (N, 3) points in the left camera frame (mm).

    Linear (DLT) triangulation on undistorted normalised coordinates with P1 = [I | 0] and
    P2 = [R | T]. cv2.triangulatePoints wants 2xN arrays: an Nx2 array gives a silently wrong result.
    """
    left_norm = undistort_points(left_px, calib.K1, calib.D1)
    right_norm = undistort_points(right_px, calib.K2, calib.D2)
    return triangulate_normalised(calib.R, calib.T, left_norm, right_norm)


#: P1 = [I | 0] of every triangulation (read only).
_P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
_P1.flags.writeable = False


def triangulate_normalised(R: np.ndarray, T: np.ndarray, left_norm: np.ndarray, right_norm: np.ndarray) -> np.ndarray:
    """(N, 2) + (N, 2) undistorted normalised coordinates -> (N, 3) points in the left camera frame (mm).

    The DLT step of :func:`triangulate`, for a caller that undistorts once and triangulates many times
    (a perturbed right camera leaves the left's undistorted corners as they were). OpenCV triangulates
    point by point, so points stacked into one call come out as from calls of their own.
    """
    P2 = np.hstack([R, np.asarray(T, float).reshape(3, 1)])
    homogeneous = cv2.triangulatePoints(_P1, P2, left_norm.T.copy(), right_norm.T.copy())
    return (homogeneous[:3] / homogeneous[3]).T


def triangulation_jacobian(
    calib: StereoCalibration, left_px: np.ndarray, right_px: np.ndarray, *, step_px: float = 1e-3
) -> np.ndarray:
    """(N, 3, 4) derivatives of each triangulated point (mm) w.r.t. (u_left, v_left, u_right, v_right) (px).

    Central differences: the DLT solution is smooth in the pixel coordinates, and eight extra
    triangulations cost far less than deriving the SVD's derivative by hand. All eight go through one
    call (OpenCV undistorts and triangulates point by point, so each point comes out as from a call
    of its own), which saves the per-call cost of 15 more.
    """
    left_px, right_px = np.asarray(left_px, float), np.asarray(right_px, float)
    n = len(left_px)
    steps = np.zeros((4, 2, n, 4))  # (coordinate k, +/-, point, (u_l, v_l, u_r, v_r))
    steps[np.arange(4), 0, :, np.arange(4)] = step_px
    steps[np.arange(4), 1, :, np.arange(4)] = -step_px
    moved = triangulate(calib, (left_px + steps[..., :2]).reshape(-1, 2),
                        (right_px + steps[..., 2:]).reshape(-1, 2)).reshape(4, 2, n, 3)
    return np.moveaxis((moved[:, 0] - moved[:, 1]) / (2 * step_px), 0, 2)


def camera_depths_mm(calib: StereoCalibration, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((N,), (N,)) depth of each left-frame point along the left and the right optical axis (mm).

    A corner both cameras see lies in front of both: a depth <= 0 means the points are behind a camera,
    which happens when the left and right images are swapped.
    """
    points = np.asarray(points_mm, float).reshape(-1, 3)
    right = points @ np.asarray(calib.R, float).T + np.asarray(calib.T, float).reshape(1, 3)
    return points[:, 2], right[:, 2]


def parallax_px(calib: StereoCalibration, points_mm: np.ndarray) -> np.ndarray:
    """(N,) angle between the two cameras' rays to each left-frame point, in pixels of the mean focal length.

    Triangulation needs the rays to differ: under one pixel of parallax the point cannot be told from
    one at infinity, and its depth is noise (the same image given as left and right has none).
    """
    points = np.asarray(points_mm, float).reshape(-1, 3)
    R, T = np.asarray(calib.R, float), np.asarray(calib.T, float).reshape(3)
    right_centre = -R.T @ T  # the right camera's optical centre in the left frame
    to_left, to_right = points, points - right_centre
    cos = np.sum(to_left * to_right, axis=1) / np.maximum(
        np.linalg.norm(to_left, axis=1) * np.linalg.norm(to_right, axis=1), 1e-300)
    focal_px = 0.25 * (calib.K1[0, 0] + calib.K1[1, 1] + calib.K2[0, 0] + calib.K2[1, 1])
    return np.arccos(np.clip(cos, -1.0, 1.0)) * focal_px
