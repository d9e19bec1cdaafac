"""Target models: the plain checkerboard and the ChArUco board.

Both put their 3-D corner coordinates in the board frame OpenCV uses for object points: origin at
the first inner corner, x along a row (to the right when the board is seen upright), y down the
columns, z = 0 on the board. Corner ``i`` has id ``i``; for the checkerboard the id is
``row * cols + col``, for ChArUco it is OpenCV's charuco id (same row-major order).

A leaf module (numpy + OpenCV only): the simulators draw the very boards the detectors look for.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import cv2
import numpy as np

ARUCO_DICTIONARIES = {name: getattr(cv2.aruco, name) for name in dir(cv2.aruco) if name.startswith("DICT_")}

#: Most inner corners a board may have. The largest calibration targets sold have ~2,000; everything that
#: draws or searches a board scales with it: rendering a 100x99 board took 2 s and 113 MB more memory, a
#: 240x239 one 21 s and 1.7 GB (scripts/bench_input_bounds.py, load 16), and a 1000x999 one ran for minutes
#: (its printable texture alone is 4 GB).
MAX_BOARD_CORNERS = 10_000


def aruco_dictionary_size(name: str) -> int:
    """How many distinct markers the OpenCV ArUco dictionary ``name`` holds."""
    return int(cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARIES[name]).bytesList.shape[0])


@dataclass(frozen=True)
class Texture:
    """A printable image of a target and where it lies in the board frame.

    Pixel (u, v) covers board x in [x0 + u * mm_per_px, x0 + (u + 1) * mm_per_px], likewise y.
    """

    image: np.ndarray  # (H, W) uint8
    origin_mm: tuple[float, float]  # board (x, y) of the texture's top-left pixel edge
    mm_per_px: float


def parse_pattern(text: str) -> tuple[int, int]:
    """'9x6' -> (9, 6): inner corners per row (cols) and per column (rows)."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX*]\s*(\d+)\s*", text)
    if not match:
        raise ValueError(f"board pattern must look like COLSxROWS (e.g. 9x6), not {text!r}")
    cols, rows = int(match.group(1)), int(match.group(2))
    if cols < 2 or rows < 2:
        raise ValueError(f"board pattern {text!r} needs at least 2x2 inner corners")
    if cols * rows > MAX_BOARD_CORNERS:
        raise ValueError(f"board pattern {text!r} has {cols * rows} corners; at most {MAX_BOARD_CORNERS}")
    return cols, rows


def grid_adjacent_pairs(cols: int, rows: int) -> np.ndarray:
    """(M, 2) ids of row-major grid corners that are one square apart horizontally or vertically."""
    ids = np.arange(cols * rows).reshape(rows, cols)
    horizontal = np.column_stack([ids[:, :-1].ravel(), ids[:, 1:].ravel()])
    vertical = np.column_stack([ids[:-1, :].ravel(), ids[1:, :].ravel()])
    return np.vstack([horizontal, vertical])


@dataclass(frozen=True)
class Checkerboard:
    """Plain checkerboard with ``cols`` x ``rows`` inner corners and ``square_mm`` squares.

    The square left-above the first inner corner is black (OpenCV's pattern convention).
    """

    cols: int
    rows: int
    square_mm: float
    kind: Literal["checkerboard"] = "checkerboard"

    def __post_init__(self):
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"a checkerboard needs at least 2x2 inner corners, not {self.cols}x{self.rows}")
        if self.n_corners > MAX_BOARD_CORNERS:
            raise ValueError(f"a {self.cols}x{self.rows} checkerboard has {self.n_corners} inner corners; "
                             f"at most {MAX_BOARD_CORNERS}")
        if self.cols == self.rows:
            # A square grid can be detected in four rotations; corner order would be unprovable.
            raise ValueError(
                f"a {self.cols}x{self.rows} board is square: use different corner counts per row and column"
            )
        if not self.square_mm > 0:
            raise ValueError(f"square size must be positive, not {self.square_mm}")

    @property
    def pattern_size(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def grid_size_mm(self) -> tuple[float, float]:
        """(width, height) spanned by the inner corners."""
        return ((self.cols - 1) * self.square_mm, (self.rows - 1) * self.square_mm)

    @cached_property
    def object_points(self) -> np.ndarray:
        """(cols*rows, 3) float32 corner coordinates (mm), row-major."""
        rows, cols = np.mgrid[0 : self.rows, 0 : self.cols]
        points = np.zeros((self.n_corners, 3), np.float32)
        points[:, 0] = cols.ravel() * self.square_mm
        points[:, 1] = rows.ravel() * self.square_mm
        return points

    @property
    def is_point_symmetric(self) -> bool:
        """True when a 180-degree turn maps the board's colours onto themselves.

        A half turn maps square (i, j) to (cols - i, rows - j), changing its colour parity by
        cols + rows. When that is even the two orderings of a detected grid cannot be told apart by
        colour and the detector falls back on image layout.
        """
        return (self.cols + self.rows) % 2 == 0

    @property
    def min_calibration_fraction(self) -> float:
        """Share of the corners a calibration view must show: all (detected whole, with its outer squares)."""
        return 1.0

    def adjacent_pairs(self) -> np.ndarray:
        """(M, 2) corner-id pairs one square apart along a row or a column."""
        return grid_adjacent_pairs(self.cols, self.rows)

    def texture(self, *, px_per_square: int = 64, margin_squares: float = 1.0) -> Texture:
        """Printable image: (cols+1) x (rows+1) squares plus a white quiet zone."""
        margin_px = int(round(margin_squares * px_per_square))
        squares = np.indices((self.rows + 1, self.cols + 1)).sum(axis=0) % 2  # 0 = black
        board = np.kron(squares, np.ones((px_per_square, px_per_square))).astype(np.uint8) * 255
        image = cv2.copyMakeBorder(board, margin_px, margin_px, margin_px, margin_px, cv2.BORDER_CONSTANT, value=255)
        mm_per_px = self.square_mm / px_per_square
        origin = -self.square_mm - margin_px * mm_per_px
        return Texture(image=image, origin_mm=(origin, origin), mm_per_px=mm_per_px)


@dataclass(frozen=True)
class CharucoTarget:
    """ChArUco board of ``squares_x`` x ``squares_y`` squares; every identified corner counts on its own.

    ``inverted``: printed with white and black swapped (white markers on black squares, as caliscope's boards
    are): the detector inverts the grey image first, since OpenCV's ArUco detector looks for black-bordered
    markers only and finds none on such a board (0 of caliscope_charuco_2cam's 111 frames without it).
    """

    squares_x: int
    squares_y: int
    square_mm: float
    marker_mm: float
    dictionary: str = "DICT_5X5_1000"
    legacy_pattern: bool = False
    inverted: bool = False
    kind: Literal["charuco"] = "charuco"

    def __post_init__(self):
        if self.dictionary not in ARUCO_DICTIONARIES:
            raise ValueError(f"unknown ArUco dictionary {self.dictionary!r}")
        if not 0 < self.marker_mm < self.square_mm:
            raise ValueError("marker_mm must be positive and smaller than square_mm")
        if self.squares_x < 2 or self.squares_y < 2:
            raise ValueError(f"a ChArUco board needs at least 2x2 squares, not {self.squares_x}x{self.squares_y}")
        if self.n_corners > MAX_BOARD_CORNERS:
            raise ValueError(f"a {self.squares_x}x{self.squares_y} ChArUco board has {self.n_corners} inner corners; "
                             f"at most {MAX_BOARD_CORNERS}")
        # Markers sit on every other square, each with an id of its own: a board needing more ids than the
        # dictionary holds would repeat markers (OpenCV builds it, then fails drawing it).
        markers, available = self.squares_x * self.squares_y // 2, aruco_dictionary_size(self.dictionary)
        if markers > available:
            raise ValueError(f"a {self.squares_x}x{self.squares_y} ChArUco board has {markers} markers but "
                             f"{self.dictionary} holds only {available}: use fewer squares or a larger dictionary")

    @property
    def cols(self) -> int:
        return self.squares_x - 1

    @property
    def rows(self) -> int:
        return self.squares_y - 1

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def grid_size_mm(self) -> tuple[float, float]:
        return ((self.cols - 1) * self.square_mm, (self.rows - 1) * self.square_mm)

    @cached_property
    def cv_board(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARIES[self.dictionary])
        board = cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y), self.square_mm, self.marker_mm, dictionary
        )
        board.setLegacyPattern(self.legacy_pattern)
        return board

    @cached_property
    def object_points(self) -> np.ndarray:
        """(n_corners, 3) float32, indexed by charuco id, origin at the first inner corner."""
        corners = np.asarray(self.cv_board.getChessboardCorners(), np.float32).reshape(-1, 3)
        return corners - corners[0]

    @property
    def min_calibration_fraction(self) -> float:
        """Share of the corners a calibration view must show: half (every corner is identified on its own)."""
        return 0.5

    def adjacent_pairs(self) -> np.ndarray:
        """(M, 2) corner-id pairs one square apart along a row or a column."""
        return grid_adjacent_pairs(self.cols, self.rows)

    def texture(self, *, px_per_square: int = 64, margin_squares: float = 0.5) -> Texture:
        margin_px = int(round(margin_squares * px_per_square))
        size = (self.squares_x * px_per_square + 2 * margin_px, self.squares_y * px_per_square + 2 * margin_px)
        image = self.cv_board.generateImage(size, marginSize=margin_px, borderBits=1)
        if self.inverted:
            image = 255 - image
        mm_per_px = self.square_mm / px_per_square
        origin = -self.square_mm - margin_px * mm_per_px
        return Texture(image=image, origin_mm=(origin, origin), mm_per_px=mm_per_px)


Target = Checkerboard | CharucoTarget
