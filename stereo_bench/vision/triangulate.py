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
    (a perturbed right camera leaves the left's undistorted corners as they were).

    The DLT point of OpenCV's ``triangulatePoints`` (the unit vector X minimising |A X| for the 4x4 system A of
    the two views, divided by its last entry), computed for all points at once instead of by one SVD per point
    (4-8x faster: the calibration's leave-one-view-out check triangulates ~10^5 corners). With X = (p, 1) the
    minimiser solves (B - lambda I) p = -b, lambda = b.p + d (B, b, d: the blocks of A^T A), lambda its smallest
    eigenvalue: Newton's method on that secular equation from lambda = 0 (where p is the least-squares point)
    converges to it from below, in 2-3 steps to round-off (agrees with triangulatePoints to ~1e-13 relative,
    tests/test_triangulate_dlt.py). A point it leaves unconverged (rays nearly parallel: a point near infinity)
    goes through triangulatePoints. Arithmetic is element by element, so points stacked into one call come out
    as from calls of their own.
    """
    R = np.asarray(R, float)
    T = np.asarray(T, float).reshape(3)
    left_norm, right_norm = np.asarray(left_norm, float).reshape(-1, 2), np.asarray(right_norm, float).reshape(-1, 2)
    x1, y1, x2, y2 = left_norm[:, 0], left_norm[:, 1], right_norm[:, 0], right_norm[:, 1]
    # A's rows for P1 = [I | 0] are (-1, 0, x1, 0) and (0, -1, y1, 0); for P2 = [R | T], u P2[2] - P2[k].
    r3 = [x2 * R[2, j] - R[0, j] for j in range(3)] + [x2 * T[2] - T[0]]
    r4 = [y2 * R[2, j] - R[1, j] for j in range(3)] + [y2 * T[2] - T[1]]
    b00 = 1.0 + r3[0] * r3[0] + r4[0] * r4[0]
    b01 = r3[0] * r3[1] + r4[0] * r4[1]
    b02 = -x1 + r3[0] * r3[2] + r4[0] * r4[2]
    b11 = 1.0 + r3[1] * r3[1] + r4[1] * r4[1]
    b12 = -y1 + r3[1] * r3[2] + r4[1] * r4[2]
    b22 = x1 * x1 + y1 * y1 + r3[2] * r3[2] + r4[2] * r4[2]
    c0, c1, c2 = (r3[j] * r3[3] + r4[j] * r4[3] for j in range(3))
    d = r3[3] * r3[3] + r4[3] * r4[3]
    lam = np.zeros_like(x1)
    p0 = p1 = p2 = step = None
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(_DLT_STEPS):
            a00, a11, a22 = b00 - lam, b11 - lam, b22 - lam
            m00, m01, m02 = a11 * a22 - b12 * b12, b02 * b12 - b01 * a22, b01 * b12 - b02 * a11
            m11, m12, m22 = a00 * a22 - b02 * b02, b01 * b02 - a00 * b12, a00 * a11 - b01 * b01
            det = a00 * m00 + b01 * m01 + b02 * m02
            q0 = -(m00 * c0 + m01 * c1 + m02 * c2) / det
            q1 = -(m01 * c0 + m11 * c1 + m12 * c2) / det
            q2 = -(m02 * c0 + m12 * c1 + m22 * c2) / det
            if p0 is not None:
                step = np.maximum(np.maximum(np.abs(q0 - p0), np.abs(q1 - p1)), np.abs(q2 - p2))
            p0, p1, p2 = q0, q1, q2
            norm2 = p0 * p0 + p1 * p1 + p2 * p2
            lam = lam + (p0 * c0 + p1 * c1 + p2 * c2 + d - lam) / (norm2 + 1.0)
        # Settled, and on the smallest eigenvalue's branch (B - lambda I positive definite: lambda below B's
        # smallest eigenvalue, left of the secular equation's first pole; a Newton step can overshoot past it).
        below_pole = (a00 > 0) & (m22 > 0) & (det > 0)
        unsettled = ~(np.isfinite(step) & (step <= _DLT_SETTLED * np.sqrt(norm2)) & below_pole)
    p = np.stack([p0, p1, p2], axis=1)
    if np.any(unsettled):
        P2 = np.hstack([R, T.reshape(3, 1)])
        homogeneous = cv2.triangulatePoints(_P1, P2, left_norm[unsettled].T.copy(), right_norm[unsettled].T.copy())
        p[unsettled] = (homogeneous[:3] / homogeneous[3]).T
    return p


#: Newton steps of :func:`triangulate_normalised` (the last one's change must be below ``_DLT_SETTLED`` of the point's
#: distance, else the point goes through ``cv2.triangulatePoints``).
_DLT_STEPS = 5
_DLT_SETTLED = 1e-8


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
