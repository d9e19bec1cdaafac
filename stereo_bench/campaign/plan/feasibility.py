"""Geometry of feasibility (pure): how much of a target or a calibration board both nominal cameras see, and where
the calibration board fits."""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stereo_bench.geometry import (
    VIEW_MARGIN_PX,
    CameraModel,
    RigPose,
    board_pose_facing_rig,
    calibration_views_fit,
    transform_points,
)
from stereo_bench.targets import CharucoTarget, Checkerboard
from stereo_bench.vision.detect import MIN_CHARUCO_MARKER_PX, MIN_SEARCH_SQUARE_PX
from stereo_bench.vision.pipeline import MIN_COMMON_CORNERS

MIN_CORNERS_IN_BOTH = MIN_COMMON_CORNERS  # what the measurement needs, not a planning guess
FEASIBILITY_MARGIN_PX = VIEW_MARGIN_PX
CALIBRATION_DISTANCES_MM = (250.0, 1500.0)
CALIBRATION_DISTANCE_STEP_MM = 10.0


Target = Checkerboard | CharucoTarget


@dataclass(frozen=True)
class Visibility:
    """How many of a board's ``n_corners`` inner corners each camera, and both cameras, see."""

    n_corners: int
    in_both: int
    in_left: int
    in_right: int
    square_px_left: float = math.inf  # the smallest side of a target square the left camera sees whole, px
    square_px_right: float = math.inf

    @property
    def fraction_in_both(self) -> float:
        return self.in_both / self.n_corners


def target_visibility(
    target: Target, rig: RigPose, *, distance_mm: float, left: CameraModel, right: CameraModel,
    margin_px: float = FEASIBILITY_MARGIN_PX,
) -> Visibility:
    """Corners of ``target`` in view when it faces the rig, centred on the rig z axis at ``distance_mm``."""
    return target_visibilities(target, [rig], distance_mm=distance_mm, left=left, right=right,
                               margin_px=margin_px)[0]


def target_visibilities(
    target: Target, rigs: Sequence[RigPose], *, distance_mm: float, left: CameraModel, right: CameraModel,
    margin_px: float = FEASIBILITY_MARGIN_PX,
) -> list[Visibility]:
    """:func:`target_visibility` for several rig poses at one distance, projected together (a plan of 10,000
    configurations asks for thousands)."""
    T_rig_board = board_pose_facing_rig(distance_mm=distance_mm, board_size_mm=target.grid_size_mm)
    points = transform_points(T_rig_board, np.asarray(target.object_points, dtype=float))  # (P, 3) rig frame
    n_points = len(points)
    pairs = target.adjacent_pairs()
    out: list[list] = []  # per camera: (visible (N, P), smallest square side (N,))
    for side, camera in enumerate((left, right)):
        T = np.stack([rig.T_cameras_rig[side] for rig in rigs])  # (N, 4, 4)
        points_cam = points @ T[:, :3, :3].transpose(0, 2, 1) + T[:, None, :3, 3]  # (N, P, 3)
        pixels, valid = camera.project(points_cam.reshape(-1, 3))
        visible = (valid & camera.in_image(pixels, margin_px=margin_px)).reshape(len(rigs), n_points)
        pixels = pixels.reshape(len(rigs), n_points, 2)
        sides = np.linalg.norm(pixels[:, pairs[:, 0]] - pixels[:, pairs[:, 1]], axis=2)  # (N, pairs)
        whole = visible[:, pairs[:, 0]] & visible[:, pairs[:, 1]]  # both corners of a square's side in view
        out.append([visible, np.where(whole, sides, np.inf).min(axis=1)])
    (seen_left, square_left), (seen_right, square_right) = out
    in_both = (seen_left & seen_right).sum(axis=1)
    in_left, in_right = seen_left.sum(axis=1), seen_right.sum(axis=1)
    return [Visibility(n_corners=n_points, in_both=int(in_both[k]), in_left=int(in_left[k]), in_right=int(in_right[k]),
                       square_px_left=float(square_left[k]), square_px_right=float(square_right[k]))
            for k in range(len(rigs))]


def _why_too_small(vis: Visibility, need_px: float, *, distance_mm: float, target: Target) -> str | None:
    """Why the corner detector would not find the target (its squares too small in a view), or None."""
    side, smallest = min((("left", vis.square_px_left), ("right", vis.square_px_right)), key=lambda item: item[1])
    if smallest >= need_px:
        return None
    if isinstance(target, CharucoTarget):
        limit = f"ChArUco markers of {MIN_CHARUCO_MARKER_PX:g} px"
    else:
        limit = f"{MIN_SEARCH_SQUARE_PX:g} px in the checkerboard detector's reduced search image"
    return (f"target squares {smallest:.1f} px in the {side} view at Z = {distance_mm:g} mm, below the "
            f"{need_px:.1f} px the corner detector finds (minimum board size in pixels: {limit}); "
            f"a larger target or a longer lens reaches farther")


def calibration_distance_range(
    board: Target, rig: RigPose, *, left: CameraModel, right: CameraModel,
    distances_mm: tuple[float, float] = CALIBRATION_DISTANCES_MM, step_mm: float = CALIBRATION_DISTANCE_STEP_MM,
    hint: tuple[float, float] | None = None,
) -> tuple[float, float] | None:
    """(nearest, farthest) distance, mm along the bisector of the optical axes, at which the calibration
    board, fronto-parallel to that bisector and centred on it, is a usable calibration view; None if at none.

    Usable by the one rule the simulator's board poses follow too,
    :func:`stereo_bench.geometry.calibration_view_fits`, so a configuration the plan calls feasible is
    one where the presenter can place the board.

    ``hint``: the range of a nearby rig pose (a neighbouring baseline). The distances where the board fits
    form one interval (each corner's image moves monotonically along a line as the board slides along the
    bisector, and the image is convex), so the hint is the answer when both its ends fit and the grid steps
    just outside them do not: 2-4 poses tried instead of all 126. Otherwise every distance is tried.
    tests/test_campaign_plan.py checks the two agree over baselines, angles and boards.
    """
    grid = np.arange(distances_mm[0], distances_mm[1] + 1e-9, step_mm)
    bisector = rig.T_rig_left[:3, 2] + rig.T_rig_right[:3, 2]
    bisector = bisector / np.linalg.norm(bisector)
    # Board frame: z along the bisector (away from the rig), x along the baseline made orthogonal to it.
    x_axis = np.array([1.0, 0.0, 0.0]) - bisector[0] * bisector
    x_axis /= np.linalg.norm(x_axis)
    R = np.column_stack([x_axis, np.cross(bisector, x_axis), bisector])
    centre_board = np.array([board.grid_size_mm[0] / 2.0, board.grid_size_mm[1] / 2.0, 0.0])

    offset = R @ centre_board

    def fits(indices: np.ndarray) -> np.ndarray:
        poses = np.zeros((len(indices), 4, 4))
        poses[:, :3, :3] = R
        poses[:, :3, 3] = grid[indices, None] * bisector - offset
        poses[:, 3, 3] = 1.0
        return calibration_views_fit(board, poses, rig=rig, left=left, right=right)

    if hint is not None:
        low, high = (int(np.argmin(np.abs(grid - value))) for value in hint)
        probes = np.array([k for k in (low - 1, low, high, high + 1) if 0 <= k < len(grid)])
        expected = (probes >= low) & (probes <= high)
        if np.array_equal(fits(probes), expected):
            return float(grid[low]), float(grid[high])
    inside = np.flatnonzero(fits(np.arange(len(grid))))
    return (float(grid[inside[0]]), float(grid[inside[-1]])) if len(inside) else None


def _nearest_range(computed: tuple[list[float], list], baseline: float) -> tuple[float, float] | None:
    """The calibration range computed for the baseline nearest ``baseline`` (a hint; None if none or no range)."""
    baselines, ranges = computed
    k = bisect.bisect_left(baselines, baseline)
    near = [j for j in (k - 1, k) if 0 <= j < len(baselines)]
    if not near:
        return None
    return ranges[min(near, key=lambda j: abs(baselines[j] - baseline))]


def _remember(computed: tuple[list[float], list], baseline: float, found: tuple[float, float] | None) -> None:
    baselines, ranges = computed
    k = bisect.bisect_left(baselines, baseline)
    baselines.insert(k, baseline)
    ranges.insert(k, found)


def _why_too_few(vis: Visibility, *, alpha_deg: float) -> str:
    if vis.in_left == 0 and vis.in_right == 0:
        cause = "the board is outside both cameras' views"
    elif vis.in_left == 0:
        cause = "the board is outside the left camera's view"
    elif vis.in_right == 0:
        cause = "the board is outside the right camera's view"
    elif vis.in_both == 0:
        cause = "the cameras' views do not overlap on the board"
    else:
        cause = "too little of the board lies where the two views overlap"
    return (f"{vis.in_both} of {vis.n_corners} target corners in both views (left {vis.in_left}, "
            f"right {vis.in_right}; {MIN_CORNERS_IN_BOTH} needed): {cause} at alpha = {alpha_deg:g} deg")


#: The fixed board's requested orientation (issue 25): turned about the vertical and about the horizontal, so each
#: view's perspective separates each camera's focal length from the board's distance (a board facing the rig
#: squarely leaves the right camera's depth offset, and with it the alphas, to the ratio of the two focal lengths:
#: on tests/synthetic_mechanics' lab rig, 2 seeds x 5 configurations, max baseline / alpha error 0.17 mm / 0.04 deg
#: facing at 500 mm against 0.05 mm / 0.019 deg turned 30/20 deg at 350 mm; a one-off experiment, not a script).
FIXED_BOARD_YAW_DEG = 30.0
FIXED_BOARD_PITCH_DEG = 20.0
#: Room kept around the board's image at every visit for the operator's placement error (a few mm and degrees
#: move the corners of a board at 300-500 mm by up to ~40 px at 1080p).
FIXED_BOARD_EXTRA_MARGIN_PX = 60.0


def fixed_board_placement(
    board: Target, poses: Sequence[RigPose], *, left: CameraModel, right: CameraModel,
    distances_mm: tuple[float, float] = CALIBRATION_DISTANCES_MM, step_mm: float = CALIBRATION_DISTANCE_STEP_MM,
    yaw_deg: float = FIXED_BOARD_YAW_DEG, pitch_deg: float = FIXED_BOARD_PITCH_DEG,
) -> tuple[np.ndarray | None, list[bool]]:
    """Where to ask the operator to put the calibration board once, for the rig to see it at every pose of ``poses``.

    The nearest distance (along the rig z axis, grid centred on it, turned ``yaw_deg`` about the vertical and
    ``pitch_deg`` about the horizontal) at which the board is a usable view (:func:`calibration_view_fits`, with
    :data:`FIXED_BOARD_EXTRA_MARGIN_PX` more margin) at the most poses; nearer is better (each view's pose is more
    precise). Returns (T_rig_board 4x4 or None if it fits at none, per pose whether it fits there).
    """
    from stereo_bench.geometry import CALIBRATION_MARGIN_PX, calibration_view_fits

    best: tuple[int, np.ndarray | None, list[bool]] = (0, None, [False] * len(poses))
    for distance in np.arange(distances_mm[0], distances_mm[1] + 1e-9, step_mm):
        T = board_pose_facing_rig(distance_mm=float(distance), board_size_mm=board.grid_size_mm, yaw_deg=yaw_deg,
                                  pitch_deg=pitch_deg)
        fits = [calibration_view_fits(board, T, rig=pose, left=left, right=right,
                                      margin_px=CALIBRATION_MARGIN_PX + FIXED_BOARD_EXTRA_MARGIN_PX) for pose in poses]
        if sum(fits) > best[0]:
            best = (sum(fits), T, fits)
        if all(fits):
            break
    return best[1], best[2]
