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
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([calib.R, np.asarray(calib.T, float).reshape(3, 1)])
    homogeneous = cv2.triangulatePoints(P1, P2, left_norm.T.copy(), right_norm.T.copy())
    return (homogeneous[:3] / homogeneous[3]).T


def triangulation_jacobian(
    calib: StereoCalibration, left_px: np.ndarray, right_px: np.ndarray, *, step_px: float = 1e-3
) -> np.ndarray:
    """(N, 3, 4) derivatives of each triangulated point (mm) w.r.t. (u_left, v_left, u_right, v_right) (px).

    Central differences: the DLT solution is smooth in the pixel coordinates, and four extra
    vectorised triangulations cost far less than deriving the SVD's derivative by hand.
    """
    jac = np.zeros((len(left_px), 3, 4))
    for k in range(4):
        delta = np.zeros((len(left_px), 4))
        delta[:, k] = step_px
        plus = triangulate(calib, left_px + delta[:, :2], right_px + delta[:, 2:])
        minus = triangulate(calib, left_px - delta[:, :2], right_px - delta[:, 2:])
        jac[:, :, k] = (plus - minus) / (2 * step_px)
    return jac
