"""Corner detection: fast on 1920x1080 frames, sub-pixel accurate, identically ordered in both views.

Speed: ``findChessboardCorners`` on a full-resolution frame without a board can run for tens of
seconds and cannot be interrupted. We therefore search a reduced image (longest side
``search_width_px``) with ``CALIB_CB_FAST_CHECK``, which rejects a board-less frame in a few
milliseconds, and refine the corners with ``cornerSubPix`` on the full-resolution image.

Order: OpenCV may return a grid in either of its two half-turn orders. We put corner 0 where the
board's own colours say it is (the square diagonally outside corner 0 is black, the square beside
it along the row is white). Only a board whose colours are point-symmetric (cols + rows even) falls
back on image layout (first row runs left to right); that is stated in the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereo_bench.targets import CharucoTarget, Checkerboard, Target

DEFAULT_SEARCH_WIDTH_PX = 960
SUBPIX_WINDOW_FRACTION = 0.4
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.001)


@dataclass(frozen=True)
class Detection:
    """Corners found in one image.

    ``ids`` (N,) index the target's ``object_points``; ``corners_px`` (N, 2) float64 full-resolution
    pixel coordinates (OpenCV pixel-centre convention). ``order`` says how corner 0 was identified:
    'colour', 'layout' (point-symmetric board) or 'ids' (ChArUco markers).
    """

    ids: np.ndarray
    corners_px: np.ndarray
    image_size: tuple[int, int]
    order: str

    @property
    def n(self) -> int:
        return len(self.ids)


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 view of a grey or BGR image."""
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image


def detect(
    image: np.ndarray, target: Target, *, search_width_px: int = DEFAULT_SEARCH_WIDTH_PX, thorough: bool = False
) -> Detection | None:
    """Find the target's corners in ``image``; None when it is not there.

    ``thorough`` adds a second, slower search (see :func:`detect_checkerboard`) for stored images,
    where finding every board matters more than 20-40 ms per image.
    """
    if isinstance(target, Checkerboard):
        return detect_checkerboard(image, target, search_width_px=search_width_px, thorough=thorough)
    if isinstance(target, CharucoTarget):
        return detect_charuco(image, target)
    raise TypeError(f"unsupported target {target!r}")


def detect_checkerboard(
    image: np.ndarray, board: Checkerboard, *, search_width_px: int = DEFAULT_SEARCH_WIDTH_PX, thorough: bool = False
) -> Detection | None:
    """Whole-board detection: all ``board.n_corners`` corners, or None.

    ``CALIB_CB_FAST_CHECK`` occasionally rejects a real board (one of present_cjn's 29 views); with
    ``thorough`` a miss is retried with ``findChessboardCornersSB``, which is bounded in time
    (20-40 ms on a 960-pixel image without a board) unlike the classic detector without FAST_CHECK.
    """
    gray = to_gray(image)
    height, width = gray.shape
    scale = min(1.0, search_width_px / max(width, height))
    small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1.0 else gray
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(small, board.pattern_size, flags=flags)
    if not found and thorough:
        found, corners = cv2.findChessboardCornersSB(small, board.pattern_size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    corners = corners.reshape(-1, 2).astype(np.float64)
    if scale < 1.0:
        # resize() maps pixel centres by (x + 0.5) / scale - 0.5, not x / scale.
        corners = (corners + 0.5) / scale - 0.5
    corners = refine_corners(gray, corners, board)
    corners, order = canonical_order(gray, corners, board)
    return Detection(ids=np.arange(board.n_corners), corners_px=corners, image_size=(width, height), order=order)


def refine_corners(gray: np.ndarray, corners_px: np.ndarray, board: Checkerboard) -> np.ndarray:
    """Sub-pixel refinement at full resolution with a window scaled to the imaged square size.

    The window stays within about half a square: a larger one reaches the neighbouring corners'
    edges and breaks on OpenCV's sample images. A small window cannot pull in a corner whose first
    estimate is far off (seen: 5 px at the border of a present_cjn view), so a corner that breaks
    the grid's smoothness is refined again from the position its neighbours predict.
    """
    spacing = grid_spacing_px(corners_px, board)
    half = int(np.clip(np.floor(SUBPIX_WINDOW_FRACTION * spacing), 2, 11))
    refined = _subpix(gray, corners_px, half)
    suspects, predicted = _grid_outliers(refined, board, tolerance_px=max(1.0, 0.15 * spacing))
    if suspects.any():
        retry = _subpix(gray, predicted[suspects], half)
        refined[suspects] = retry
    return refined


def _subpix(gray: np.ndarray, corners_px: np.ndarray, half: int) -> np.ndarray:
    refined = cv2.cornerSubPix(
        gray, corners_px.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), SUBPIX_CRITERIA
    )
    return refined.reshape(-1, 2).astype(np.float64)


def grid_spacing_px(corners_px: np.ndarray, board: Checkerboard) -> float:
    """Shortest distance (px) between row- or column-adjacent corners."""
    grid = corners_px.reshape(board.rows, board.cols, 2)
    return float(min(
        np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
        np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
    ))


def _line_predictions(grid: np.ndarray, axis: int) -> np.ndarray:
    """Each corner predicted from its neighbours along ``axis``: midpoint inside, extrapolation at the ends."""
    g = np.moveaxis(grid, axis, 0)
    pred = np.empty_like(g)
    pred[1:-1] = 0.5 * (g[:-2] + g[2:])
    if len(g) >= 3:
        pred[0] = 2 * g[1] - g[2]
        pred[-1] = 2 * g[-2] - g[-3]
    else:
        pred[0], pred[-1] = g[0], g[-1]
    return np.moveaxis(pred, 0, axis)


def _grid_outliers(
    corners_px: np.ndarray, board: Checkerboard, *, tolerance_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """(N,) corners that disagree with BOTH their row and column neighbours, and their predicted positions.

    Requiring both keeps a good corner next to a bad one (which disagrees along one line only) off the list.
    """
    grid = corners_px.reshape(board.rows, board.cols, 2)
    by_row, by_col = _line_predictions(grid, 1), _line_predictions(grid, 0)
    dev_row = np.linalg.norm(grid - by_row, axis=2)
    dev_col = np.linalg.norm(grid - by_col, axis=2)
    suspects = (dev_row > tolerance_px) & (dev_col > tolerance_px)
    predicted = np.where((dev_row <= dev_col)[..., None], by_row, by_col)
    predicted = np.where(suspects[..., None], 0.5 * (by_row + by_col), predicted)
    return suspects.reshape(-1), predicted.reshape(-1, 2)


def _mean_intensity(gray: np.ndarray, points_px: np.ndarray, radius: int = 1) -> float:
    height, width = gray.shape
    values = []
    for x, y in np.rint(points_px).astype(int):
        x0, x1 = max(x - radius, 0), min(x + radius + 1, width)
        y0, y1 = max(y - radius, 0), min(y + radius + 1, height)
        if x0 < x1 and y0 < y1:
            values.append(gray[y0:y1, x0:x1].mean())
    return float(np.mean(values)) if values else float("nan")


def corner_zero_is_black_diagonal(gray: np.ndarray, corners_px: np.ndarray, board: Checkerboard) -> bool | None:
    """Does the colour around corner 0 match the board convention? None when it cannot be seen."""
    grid = corners_px.reshape(board.rows, board.cols, 2)
    p0 = grid[0, 0]
    along_row = grid[0, 1] - p0
    down_col = grid[1, 0] - p0
    diagonal_out = p0 - 0.5 * along_row - 0.5 * down_col  # square (0, 0): black by convention
    beside = p0 + 0.5 * along_row - 0.5 * down_col  # square (1, 0): white
    dark, light = _mean_intensity(gray, diagonal_out[None]), _mean_intensity(gray, beside[None])
    if not np.isfinite(dark) or not np.isfinite(light) or abs(light - dark) < 10:
        return None
    return bool(dark < light)


def canonical_order(gray: np.ndarray, corners_px: np.ndarray, board: Checkerboard) -> tuple[np.ndarray, str]:
    """Put the corners in the board's own row-major order; returns (corners, how it was decided)."""
    if not board.is_point_symmetric:
        verdict = corner_zero_is_black_diagonal(gray, corners_px, board)
        if verdict is not None:
            return (corners_px if verdict else corners_px[::-1].copy()), "colour"
    row_direction = corners_px[board.cols - 1] - corners_px[0]
    return (corners_px if row_direction[0] >= 0 else corners_px[::-1].copy()), "layout"


def detect_charuco(image: np.ndarray, target: CharucoTarget, *, min_corners: int = 4) -> Detection | None:
    """ChArUco detection: every identified corner, partial views included; None below ``min_corners``."""
    gray = to_gray(image)
    detector = _charuco_detector(target)
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < min_corners:
        return None
    ids = np.asarray(ids).reshape(-1).astype(int)
    order = np.argsort(ids)
    height, width = gray.shape
    return Detection(
        ids=ids[order], corners_px=np.asarray(corners, np.float64).reshape(-1, 2)[order],
        image_size=(width, height), order="ids",
    )


_CHARUCO_DETECTORS: dict[CharucoTarget, cv2.aruco.CharucoDetector] = {}


def _charuco_detector(target: CharucoTarget) -> cv2.aruco.CharucoDetector:
    if target not in _CHARUCO_DETECTORS:
        _CHARUCO_DETECTORS[target] = cv2.aruco.CharucoDetector(target.cv_board)
    return _CHARUCO_DETECTORS[target]


def common_corners(left: Detection, right: Detection) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ids (N,), left_px (N, 2), right_px (N, 2)) for the corners seen in both views."""
    ids, left_index, right_index = np.intersect1d(left.ids, right.ids, assume_unique=True, return_indices=True)
    return ids, left.corners_px[left_index], right.corners_px[right_index]
