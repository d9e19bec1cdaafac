"""Calibration coverage: where the kept calibration views put the board, per camera, as ROS shows it.

ROS ``camera_calibration`` (``calibrator.py``) describes every board view by four numbers in [0, 1]
and shows, for each, how much of a wanted range the kept views span:

- **X**, **Y**: the board's mean corner position, with the image shrunk by half the board's apparent
  size on every side (``(mean_x - border/2) / (width - border)``, ``border = sqrt(area)``), so that a
  large board is not penalised for having less room to move;
- **size**: ``sqrt(area / (width * height))``, the board's outline area (the quadrilateral through its
  four outer corners) relative to the image;
- **skew**: ``min(1, 2 * |90 deg - angle|)`` (radians) at the board's upper-right outer corner.

Progress of a parameter is ``min((high - low) / range, 1)`` over the kept views, with ranges
X 0.7, Y 0.7, size 0.4, skew 0.5; size and skew count from 0 (a small or square-on view is not
rewarded). The occupancy map is a 20 x 20 grid of the image counting the kept views' corners.

    coverage = Coverage((1920, 1080), board)
    coverage.add("left", 0, detection)          # a kept view (its index in the configuration)
    coverage.discard(0)                         # the operator dropped it
    coverage.bars("left")                       # [Bar(name="X", low=..., high=..., progress=...), ...]
    coverage.summary()                          # one line for a terminal prompt

One definition for the terminal prompts (``OperatorPresenter``) and the live page.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stereo_bench.targets import Target

SIDES = ("left", "right")
PARAMETER_NAMES = ("X", "Y", "size", "skew")
#: How much of each parameter's span the kept views should cover (ROS camera_calibration's param_ranges).
PARAMETER_RANGES = (0.7, 0.7, 0.4, 0.5)
OCCUPANCY_CELLS = 20  # ROS: cell_size 0.05 of the image per side


@dataclass(frozen=True)
class ViewParameters:
    """One view of the board: X, Y, size in [0, 1]; skew in [0, 1] or None when no outer corner angle is seen."""

    x: float
    y: float
    size: float
    skew: float | None

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.x, self.y, self.size, 0.0 if self.skew is None else self.skew)


@dataclass(frozen=True)
class Bar:
    """One coverage bar: the span [low, high] the kept views reach, and progress toward the wanted range."""

    name: str
    low: float
    high: float
    progress: float

    def as_dict(self) -> dict:
        return {"name": self.name, "low": self.low, "high": self.high, "progress": self.progress}


def outer_corners(corners_px: np.ndarray, ids: np.ndarray, cols: int) -> np.ndarray | None:
    """(4, 2) up-left, up-right, down-right, down-left corners of the detected part of the grid, or None.

    ``ids`` index a row-major grid of ``cols`` columns; the outline is the rectangle of grid rows and
    columns the detection spans, which needs its four corner ids present (a whole board always has them).
    """
    ids = np.asarray(ids, int)
    rows_of, cols_of = ids // cols, ids % cols
    lookup = {int(i): k for k, i in enumerate(ids)}
    r0, r1, c0, c1 = rows_of.min(), rows_of.max(), cols_of.min(), cols_of.max()
    if r0 == r1 or c0 == c1:
        return None
    wanted = [r0 * cols + c0, r0 * cols + c1, r1 * cols + c1, r1 * cols + c0]
    if any(int(w) not in lookup for w in wanted):
        return None
    return np.asarray(corners_px, np.float64)[[lookup[int(w)] for w in wanted]]


def _angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """Angle at ``b`` between ``b->a`` and ``b->c``, radians."""
    ab, cb = a - b, c - b
    cosine = float(np.dot(ab, cb) / (np.linalg.norm(ab) * np.linalg.norm(cb)))
    return math.acos(min(1.0, max(-1.0, cosine)))


def view_parameters(corners_px: np.ndarray, ids: np.ndarray, board: Target,
                    image_size: tuple[int, int]) -> ViewParameters:
    """ROS-style (X, Y, size, skew) of one detected view (see the module docstring).

    ``corners_px`` (N, 2) pixels, ``ids`` (N,) into ``board``'s row-major corner grid, ``image_size``
    (width, height). A partial view whose outline corners are missing uses its corners' convex hull for
    the area and has no skew.
    """
    width, height = image_size
    corners = np.asarray(corners_px, np.float64).reshape(-1, 2)
    outline = outer_corners(corners, ids, board.cols)
    if outline is not None:
        up_left, up_right, down_right, down_left = outline
        a, b, c = up_right - up_left, down_right - up_right, down_left - down_right
        p, q = b + c, a + b
        area = abs(p[0] * q[1] - p[1] * q[0]) / 2.0
        skew: float | None = min(1.0, 2.0 * abs(math.pi / 2.0 - _angle(up_left, up_right, down_right)))
    else:
        import cv2

        area = float(cv2.contourArea(cv2.convexHull(corners.astype(np.float32)))) if len(corners) >= 3 else 0.0
        skew = None
    border = math.sqrt(area)
    mean_x, mean_y = corners.mean(axis=0)
    x = min(1.0, max(0.0, (mean_x - border / 2.0) / max(width - border, 1e-9)))
    y = min(1.0, max(0.0, (mean_y - border / 2.0) / max(height - border, 1e-9)))
    return ViewParameters(x=float(x), y=float(y), size=float(math.sqrt(area / (width * height))), skew=skew)


def coverage_bars(views: list[ViewParameters]) -> list[Bar]:
    """ROS's progress bars over ``views`` (empty: all zero)."""
    if not views:
        return [Bar(name, 0.0, 0.0, 0.0) for name in PARAMETER_NAMES]
    values = np.array([view.as_tuple() for view in views])
    low, high = values.min(axis=0), values.max(axis=0)
    low[2:] = 0.0  # a small board or a square-on view is not rewarded
    return [Bar(name, float(lo), float(hi), float(min((hi - lo) / wanted, 1.0)))
            for name, lo, hi, wanted in zip(PARAMETER_NAMES, low, high, PARAMETER_RANGES, strict=True)]


def occupancy(corner_sets: list[np.ndarray], image_size: tuple[int, int], cells: int = OCCUPANCY_CELLS) -> np.ndarray:
    """(cells, cells) int counts of corners per cell of the image (row = y), over every (N, 2) set given."""
    width, height = image_size
    grid = np.zeros((cells, cells), np.int64)
    for corners in corner_sets:
        corners = np.asarray(corners, np.float64).reshape(-1, 2)
        u = np.clip((corners[:, 0] / width * cells).astype(int), 0, cells - 1)
        v = np.clip((corners[:, 1] / height * cells).astype(int), 0, cells - 1)
        np.add.at(grid, (v, u), 1)
    return grid


@dataclass(frozen=True)
class KeptView:
    index: int
    corners_px: np.ndarray
    parameters: ViewParameters


class Coverage:
    """The kept calibration views of one configuration, per camera (see the module docstring)."""

    def __init__(self, image_size: tuple[int, int], board: Target):
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.board = board
        self.views: dict[str, list[KeptView]] = {side: [] for side in SIDES}

    def add(self, side: str, index: int, detection) -> ViewParameters:
        """Keep ``detection`` (ids, corners_px) of view ``index`` seen by ``side``; returns its parameters."""
        parameters = view_parameters(detection.corners_px, detection.ids, self.board, self.image_size)
        self.views[side].append(KeptView(index, np.asarray(detection.corners_px, np.float64), parameters))
        return parameters

    def discard(self, index: int) -> None:
        """Forget view ``index`` in both cameras (the operator dropped it)."""
        for side in SIDES:
            self.views[side] = [view for view in self.views[side] if view.index != index]

    def bars(self, side: str) -> list[Bar]:
        return coverage_bars([view.parameters for view in self.views[side]])

    def occupancy(self, side: str, cells: int = OCCUPANCY_CELLS) -> np.ndarray:
        return occupancy([view.corners_px for view in self.views[side]], self.image_size, cells)

    def covered_fraction(self, side: str) -> float:
        """Share of the occupancy cells that hold at least one kept corner."""
        return float((self.occupancy(side) > 0).mean())

    def summary(self) -> str:
        """E.g. 'left X 80% Y 45% size 60% skew 20%, 31% of the image; right ...' (progress per bar)."""
        parts = []
        for side in SIDES:
            bars = " ".join(f"{bar.name} {bar.progress:.0%}" for bar in self.bars(side))
            parts.append(f"{side} {bars}, {self.covered_fraction(side):.0%} of the image")
        return "coverage " + "; ".join(parts)

    def as_dict(self, cells: int = OCCUPANCY_CELLS) -> dict:
        """JSON-ready: per side its bars, occupancy grid (rows = image y), covered fraction and kept views."""
        return {side: {"bars": [bar.as_dict() for bar in self.bars(side)],
                       "occupancy": self.occupancy(side, cells).tolist(),
                       "covered": self.covered_fraction(side),
                       "views": [view.index for view in self.views[side]]}
                for side in SIDES}
