"""A stereo calibration predicted before any view: where its views will be shown (:func:`planned_board_poses`) and
the covariance its parameters will have (:func:`planned_stereo_calibration`), from geometry and an assumed image
noise. The error model (``errormodel.rigorous``) predicts a configuration's calibration with them, and a campaign's
plan the lens calibration a fixed-board design starts with (``campaign.plan.lens``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import cv2
import numpy as np

from stereo_bench.geometry import (
    CameraModel,
    RigPose,
    board_pose_in_view,
    calibration_view_fits,
    invert_transform,
    mean_view_frame,
    transform_points,
)
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibrate import DEFAULT_FLAGS, StereoCalibration
from stereo_bench.vision.covariance import mono_linearisation, stereo_covariance


def project_into_both(rig: RigPose, left: CameraModel, right: CameraModel,
                      points_rig: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True pixels of rig-frame points (N, 3): (left (N, 2), right (N, 2), in_front_of_both (N,) bool)."""
    points_rig = np.asarray(points_rig, dtype=float).reshape(-1, 3)
    if not len(points_rig):
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, dtype=bool)
    out, ok = [], np.ones(len(points_rig), dtype=bool)
    for camera, T_rig_cam in ((left, rig.T_rig_left), (right, rig.T_rig_right)):
        pixels, valid = camera.project(transform_points(invert_transform(T_rig_cam), points_rig))
        out.append(pixels)
        ok &= valid
    return out[0], out[1], ok


def true_calibration(rig: RigPose, left: CameraModel, right: CameraModel) -> StereoCalibration:
    """The rig's exact stereo calibration (X_right = R X_left + T, mm) as the pipeline would hold it."""
    R, T = rig.stereo_extrinsics()
    return StereoCalibration(
        K1=np.asarray(left.K, float), D1=np.asarray(left.dist, float).ravel(),
        K2=np.asarray(right.K, float), D2=np.asarray(right.dist, float).ravel(),
        R=R, T=T, image_size=tuple(left.image_size), mode="true geometry",
    )


def planned_board_poses(rig: RigPose, board: Checkerboard, left: CameraModel, right: CameraModel, *, n_views: int,
                        distance_mm: tuple[float, float], max_tilt_deg: float = 40.0) -> list[np.ndarray]:
    """T_rig_board (4x4, mm) of ``n_views`` calibration views, deterministic, each a view the project's rule accepts
    (:func:`stereo_bench.geometry.calibration_view_fits`: the whole board and its outer squares in both images, no
    more than 60 deg oblique), the rule the simulated presenter places its views by.

    The spread of the simulated campaign's choreography (drivers.sim.render.calibration_board_poses):
    distances stratified over ``distance_mm`` (near, far) along the rig's mean viewing direction, tilts of
    0.4-1 x ``max_tilt_deg`` about the board's axes with the direction stepping round the circle, a
    +-10 deg roll, and three views in four pushed toward the edge of the common field of view
    (where distortion shows), the fourth near its centre. A view that does not fit is eased (less
    offset, then less tilt, then farther) until it does.

    Raises:
        ValueError: a view cannot be placed (the views overlap too little for this board).
    """
    near, far = distance_mm
    width, height = board.grid_size_mm
    centre = np.array([width / 2.0, height / 2.0, 0.0])
    R_view = mean_view_frame(rig.T_rig_left, rig.T_rig_right)
    f = 0.5 * (left.fx + right.fx)
    half_fov = np.array(left.image_size, float) / 2.0 / f

    def fits(T_rig_board):
        return calibration_view_fits(board, T_rig_board, rig=rig, left=left, right=right)

    golden = 0.618034
    order = [int(v) for v in np.argsort([(i * golden) % 1.0 for i in range(n_views)])]
    poses = []
    for i in range(n_views):
        distance = near + (far - near) * (order[i] + 0.5) / n_views
        phi = 2 * np.pi * i / n_views
        tilt = max_tilt_deg * (0.4 + 0.6 * ((i * golden * 2) % 1.0))
        theta = 2 * np.pi * ((i * golden) % 1.0)
        push = 0.3 if i % 4 == 3 else 0.85
        roll = 10.0 * (1 if i % 2 else -1)
        for ease in np.linspace(0.0, 1.0, 11):
            d = distance + (far - distance) * max(0.0, ease - 0.5) * 2
            t = tilt * (1.0 - ease)
            # The largest offset the board's size leaves in the mean field of view, scaled by the push.
            room = np.maximum(half_fov - np.array([width, height]) / 2.0 / d, 0.0)
            offset = push * (1.0 - ease) * room * np.array([math.cos(theta), math.sin(theta)])
            candidate = board_pose_in_view(R_view, centre, d, offset, t * math.cos(phi), t * math.sin(phi),
                                           roll * (1.0 - ease))
            if fits(candidate):
                poses.append(candidate)
                break
        else:
            raise ValueError(f"calibration view {i + 1} of {n_views} does not fit both images at "
                             f"{near:g}-{far:g} mm: the views overlap too little for a {board.cols}x{board.rows} "
                             f"board of {board.square_mm:g} mm squares")
    return poses


def planned_stereo_calibration(rig: RigPose, board: Checkerboard, left: CameraModel, right: CameraModel,
                               poses: Sequence[np.ndarray], *, pixel_sigma_px: float,
                               mode: str = "joint") -> StereoCalibration:
    """The rig's true calibration with the covariance the views at ``poses`` (T_rig_board) would give, projected
    without noise, at image noise ``pixel_sigma_px``; ``mode`` "joint" refines the intrinsics with R, T, "fixed"
    takes them from mono calibrations of the same views.

    Raises:
        CovarianceUnavailable: the views leave the parameters undetermined.
    """
    calib = true_calibration(rig, left, right)
    D1, D2 = np.asarray(calib.D1, float).reshape(1, -1), np.asarray(calib.D2, float).reshape(1, -1)
    calib = replace(calib, D1=D1, D2=D2)
    points = np.asarray(board.object_points, float)
    T_left_rig = invert_transform(rig.T_rig_left)
    objects, lefts, rights, rvecs, tvecs = [], [], [], [], []
    for T_rig_board in poses:
        left_px, right_px, in_front = project_into_both(rig, left, right, transform_points(T_rig_board, points))
        seen = in_front & left.in_image(left_px) & right.in_image(right_px)
        T_left_board = T_left_rig @ T_rig_board
        objects.append(points[seen])
        lefts.append(left_px[seen])
        rights.append(right_px[seen])
        rvecs.append(cv2.Rodrigues(T_left_board[:3, :3])[0].ravel())
        tvecs.append(T_left_board[:3, 3])
    if mode == "joint":
        flags = DEFAULT_FLAGS | cv2.CALIB_USE_INTRINSIC_GUESS
        covariance = stereo_covariance(objects, lefts, rights, calib.K1, D1, calib.K2, D2, calib.R, calib.T,
                                       rvecs, tvecs, flags=flags, sigma_px=pixel_sigma_px)
    else:
        views = list(range(len(objects)))
        T_right_left = invert_transform(rig.T_rig_right) @ rig.T_rig_left
        right_poses = [T_right_left @ np.vstack([np.column_stack([cv2.Rodrigues(r)[0], t]), [0, 0, 0, 1]])
                       for r, t in zip(rvecs, tvecs, strict=True)]
        right_rvecs = [cv2.Rodrigues(T[:3, :3])[0].ravel() for T in right_poses]
        monos = (
            mono_linearisation(objects, lefts, calib.K1, D1, rvecs, tvecs, flags=DEFAULT_FLAGS, view_indices=views,
                               side="left"),
            mono_linearisation(objects, rights, calib.K2, D2, right_rvecs, [T[:3, 3] for T in right_poses],
                               flags=DEFAULT_FLAGS, view_indices=views, side="right"),
        )
        covariance = stereo_covariance(objects, lefts, rights, calib.K1, D1, calib.K2, D2, calib.R, calib.T, rvecs,
                                       tvecs, flags=DEFAULT_FLAGS | cv2.CALIB_FIX_INTRINSIC, intrinsics_from=monos,
                                       view_indices=views, sigma_px=pixel_sigma_px)
    return replace(calib, covariance=covariance, mode=f"planned ({mode})")


__all__ = ["planned_board_poses", "planned_stereo_calibration", "project_into_both",
           "true_calibration"]
