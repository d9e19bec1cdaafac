"""Corner detection: fast on 1920x1080 frames, sub-pixel accurate, identically ordered in both views.

Speed: ``findChessboardCorners`` on a full-resolution frame without a board can run for tens of
seconds and cannot be interrupted. We therefore search a reduced image (longest side
``search_width_px``) with ``CALIB_CB_FAST_CHECK``, which rejects a board-less frame in a few
milliseconds, and refine the corners with ``cornerSubPix`` on the full-resolution image.

Order: OpenCV may return a grid in either of its two half-turn orders. We put corner 0 where the
board's own colours say it is (the square diagonally outside corner 0 is black, the square beside
it along the row is white). Only a board whose colours are point-symmetric (cols + rows even) falls
back on image layout (first row runs left to right); that is stated in the result.

ChArUco speed: OpenCV identifies every square candidate by scanning its dictionary in id order
and taking the first marker within the correction distance. With the default DICT_5X5_1000 that
scan over 1000 markers x 4 rotations is ~90 % of ``CharucoDetector.detectBoard`` (measured:
100-350 ms of 110-380 ms on a 1080p view; thresholding and contours ~11 ms, interpolation and
corner refinement < 1 ms). We identify against the board's own markers only (the first
max(id) + 1 entries of the same dictionary, same correction distance): the scan stops at the same
first match for every board marker, so ids and corners are those of the default detector, in
~15-30 ms (scripts/bench_vision.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereo_bench.targets import CharucoTarget, Checkerboard, Target

# 640 px rejects a board-less 1080p frame in ~4 ms (960 px: ~9 ms) and still finds a 27 mm board
# out to Z ~ 900 mm at f = 1333 px (squares >= ~13 px in the search image).
DEFAULT_SEARCH_WIDTH_PX = 640
THOROUGH_SEARCH_WIDTH_PX = 960
SUBPIX_WINDOW_FRACTION = 0.4
# The smallest squares the detectors find (what `campaign plan` predicts feasibility with, and `run` skips below).
# Measured on rendered views (drivers/sim/render, 2 DN noise, 0.7 px blur, 4 seeds, fronto-parallel): the
# classic detector finds 9x6 and 5x4 checkerboards (27 and 40 mm squares) whose squares measure >= 13.3 px in the
# search image and none at <= 12.6 px, at the same search-image size for 640-, 960- and 1920-px-wide frames;
# the partial-capable search (SB at 960 px) found every corner down to 13.8 px there (not measured below).
# ChArUco (DICT_5X5, marker 0.75 of the square, full resolution; identified corner by corner, so a view is usable
# with part of them): 40 of 40 corners at 24 px squares (18 px markers), 30-38 at 22.5 px (16.9 px markers), 16-24
# at 21.2 px, none at <= 20 px. The limit keeps most of the board: markers of 17 px.
MIN_SEARCH_SQUARE_PX = 13.0
MIN_CHARUCO_MARKER_PX = 17.0
CHARUCO_HALF_WINDOW = 3  # CharucoDetector refines with a 3 px half-window by default
# cornerSubPix's corner scatter relative to the structure-tensor (Foerstner) bound, measured on
# rendered views (scripts/bench_corner_noise.py): median 2.04, range 1.83-2.41 over Z 300-700 mm,
# alpha 70-90 deg, 1-5 DN noise and 0.5-1.2 px blur.
CORNER_NOISE_FACTOR = 2.1
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.001)


@dataclass(frozen=True)
class Detection:
    """Corners found in one image.

    ``ids`` (N,) index the target's ``object_points``; ``corners_px`` (N, 2) float64 full-resolution
    pixel coordinates (OpenCV pixel-centre convention). ``order`` says how the ids were assigned:
    'colour', 'layout' (point-symmetric board), 'edges' (partial checkerboard) or 'ids' (ChArUco).
    """

    ids: np.ndarray
    corners_px: np.ndarray
    image_size: tuple[int, int]
    order: str
    sigma_px: np.ndarray | None = None  # (N,) per-coordinate random corner noise, see corner_noise_px()

    @property
    def n(self) -> int:
        return len(self.ids)


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 view of a grey or BGR image."""
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image


class AmbiguousViewError(ValueError):
    """A partial checkerboard was found but which board corners it shows cannot be proven."""


def _sb(small: np.ndarray, pattern_size: tuple[int, int], flags: int) -> tuple:
    """``cv2.findChessboardCornersSB``, from OpenCV's random generator as a fresh thread has it.

    SB draws from ``cv::theRNG()``, the calling thread's generator, which anything else (the renderer's noise) moves
    on: with ``CALIB_CB_LARGER`` present_cjn's leftPic07 came back as a 4 x 11 grid in 38 of 40 successive calls and
    4 x 8 in 2, so a detection depended on what ran before it on that thread (a test order, the thread pool's
    assignment of images, a replay that renders nothing). Seeded here (0: the generator's default state), the same
    pixels give the same grid."""
    cv2.setRNGSeed(0)
    return cv2.findChessboardCornersSB(small, pattern_size, flags=flags)


def _sb_with_meta(small: np.ndarray, pattern_size: tuple[int, int], flags: int) -> tuple:
    """``cv2.findChessboardCornersSBWithMeta``, seeded as :func:`_sb`."""
    cv2.setRNGSeed(0)
    return cv2.findChessboardCornersSBWithMeta(small, pattern_size, flags)


class AnyBoardSearch:
    """``findChessboardCornersSBWithMeta(image at <= 960 px, (3, 3), CALIB_CB_LARGER | flags)``: the largest
    checkerboard of any size in an image, each (image, flags) searched once (~50 ms at 640x480).

    Two users of one calibration's images share it: the thorough detection of an image the classic detector missed
    asks it (without CALIB_CB_NORMALIZE_IMAGE) before running SB for the named board without that flag (where SB
    with CALIB_CB_LARGER finds no checkerboard at all, SB for the named board finds none either: every one of the
    453 SB finds on the three real sets' 126 images, as stored and as 1280x720 prints, was also found so:
    scripts/check_any_board_search.py), and the board-size gate's search of the missed images
    (:func:`stereo_bench.vision.gates.found_board_shape`) asks the same question. Keyed by the image array's
    identity, which the cache keeps alive; the same call on the same pixels: the same answer."""

    def __init__(self) -> None:
        self._found: dict[tuple[int, int], tuple[np.ndarray, tuple]] = {}

    def search(self, gray: np.ndarray, flags: int) -> tuple:
        """(found, corners, meta) of the search of ``gray`` (full resolution, grey) with ``flags``."""
        key = (id(gray), flags)
        if key not in self._found:
            small, _ = _search_image(gray, THOROUGH_SEARCH_WIDTH_PX)
            self._found[key] = (gray, _sb_with_meta(small, (3, 3), cv2.CALIB_CB_LARGER | flags))
        return self._found[key][1]


def detect(
    image: np.ndarray, target: Target, *, search_width_px: int = DEFAULT_SEARCH_WIDTH_PX, thorough: bool = False,
    partial: bool = False, noise: bool = True, any_board: AnyBoardSearch | None = None,
) -> Detection | None:
    """Find the target's corners in ``image``; None when it is not there.

    ``thorough`` adds a second, slower search (see :func:`detect_checkerboard`) for stored images,
    where finding every board matters more than 20-40 ms per image. ``partial`` accepts a
    checkerboard cut by the image border (see :func:`detect_checkerboard_partial`) at ~3x the cost
    of the fast whole-board search; ChArUco views are always partial-capable. ``noise=False`` leaves
    ``sigma_px`` None (unknown) instead of estimating it (:func:`corner_noise_px`, 1.0 ms of a 1080p
    view's 4.8: scripts/results/bench_detect.json): for views whose corner noise nothing reads, such as
    calibration views, whose fit takes the noise from its own residuals. The corners and ids are the same
    either way. ``any_board``: an :class:`AnyBoardSearch` shared with the board-size gate (``thorough`` only).
    """
    if isinstance(target, Checkerboard):
        if partial:
            # The classic detector spends ~180 ms failing on a cut board (FAST_CHECK passes); SB
            # with CALIB_CB_LARGER finds whole and cut boards alike in ~40 ms at 960 px (at 640 px
            # it is faster but loses the column nearest the image border).
            width = max(search_width_px, THOROUGH_SEARCH_WIDTH_PX)
            ambiguous: AmbiguousViewError | None = None
            try:
                found = detect_checkerboard_partial(image, target, search_width_px=width, noise=noise)
            except AmbiguousViewError as error:
                found, ambiguous = None, error
            if found is not None:
                return found
            # A whole board partial mode did not place (SB's larger grid can take in the board's edge against a
            # dark background, a row more than the board has, or only some of its rows) is still a whole board:
            # what the whole-board search finds, partial mode finds too.
            whole = detect_checkerboard(image, target, search_width_px=search_width_px, thorough=thorough,
                                        noise=noise, any_board=any_board)
            if whole is None and ambiguous is not None:
                raise ambiguous
            return whole
        return detect_checkerboard(image, target, search_width_px=search_width_px, thorough=thorough, noise=noise,
                                   any_board=any_board)
    if isinstance(target, CharucoTarget):
        return detect_charuco(image, target, noise=noise)
    raise TypeError(f"unsupported target {target!r}")


def min_detectable_square_px(target: Target, image_size: tuple[int, int], *, partial: bool = False) -> float:
    """The smallest side (px, full resolution) of the target's squares :func:`detect` finds in a
    ``image_size`` (width, height) frame; ``partial`` as :func:`detect` takes it. Measured limits
    (:data:`MIN_SEARCH_SQUARE_PX`, :data:`MIN_CHARUCO_MARKER_PX`), not a margin of safety."""
    if isinstance(target, CharucoTarget):
        return MIN_CHARUCO_MARKER_PX * target.square_mm / target.marker_mm
    width = max(DEFAULT_SEARCH_WIDTH_PX, THOROUGH_SEARCH_WIDTH_PX) if partial else DEFAULT_SEARCH_WIDTH_PX
    scale = min(1.0, width / max(image_size))
    return MIN_SEARCH_SQUARE_PX / scale


def _search_image(gray: np.ndarray, search_width_px: int) -> tuple[np.ndarray, float]:
    height, width = gray.shape
    scale = min(1.0, search_width_px / max(width, height))
    if scale >= 1.0:
        return gray, scale
    factor = max(width, height) // search_width_px
    if factor * search_width_px == max(width, height) and _box_shrinks_exactly(gray, factor):
        return _box_shrink(gray, factor), scale
    return cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA), scale


# Largest odd shrink factor whose box sums (<= 255 factor^2) fit the uint16 sums of _box_shrink.
_MAX_BOX_FACTOR = 15


def _box_shrinks_exactly(gray: np.ndarray, factor: int) -> bool:
    """Does :func:`_box_shrink` give INTER_AREA's result for this image and whole-number shrink ``factor``?

    INTER_AREA at 1/factor is the mean of each factor x factor block rounded to the nearest grey level. For an
    odd factor that mean is never half-way between two levels (its fraction is a multiple of 1/factor^2), so
    every rounding rule agrees and the float errors of both computations (< 1e-3) cannot change the level.
    An even factor can tie, where OpenCV's fast paths round half up and its general one half to even.
    """
    height, width = gray.shape
    return (gray.dtype == np.uint8 and factor % 2 == 1 and 3 <= factor <= _MAX_BOX_FACTOR
            and height % factor == 0 and width % factor == 0)


def _box_shrink(gray: np.ndarray, factor: int) -> np.ndarray:
    """``cv2.resize(gray, None, fx=1/factor, fy=1/factor, interpolation=INTER_AREA)`` when
    :func:`_box_shrinks_exactly`, bit for bit (tests/test_detect_fast_paths.py), in 65-75 % of the time (1080p to
    640 px: 0.86 -> 0.5 ms on a frame in cache, 1.0 -> 0.7 ms on a new one): each block row's lines are added
    exactly in uint16, then OpenCV's box filter adds ``factor`` neighbouring column sums, and only every
    ``factor``-th sum (a block's) is kept and divided."""
    height, width = gray.shape
    rows = gray.reshape(height // factor, factor, width)  # each block row's lines side by side
    column_sums = np.add(rows[:, 0], rows[:, 1], dtype=np.uint16)
    for line in range(2, factor):
        column_sums += rows[:, line]
    sums = cv2.boxFilter(column_sums, cv2.CV_16U, (factor, 1), anchor=(0, 0), normalize=False,
                         borderType=cv2.BORDER_CONSTANT)
    return cv2.convertScaleAbs(sums[:, ::factor], alpha=1.0 / factor**2)


def _to_full_resolution(corners: np.ndarray, scale: float) -> np.ndarray:
    corners = np.asarray(corners, np.float64).reshape(-1, 2)
    # resize() maps pixel centres by (x + 0.5) / scale - 0.5, not x / scale.
    return (corners + 0.5) / scale - 0.5 if scale != 1.0 else corners


def detect_checkerboard(
    image: np.ndarray, board: Checkerboard, *, search_width_px: int = DEFAULT_SEARCH_WIDTH_PX, thorough: bool = False,
    noise: bool = True, any_board: AnyBoardSearch | None = None,
) -> Detection | None:
    """Whole-board detection: all ``board.n_corners`` corners, or None.

    ``CALIB_CB_FAST_CHECK`` occasionally rejects a real board (present_cjn's leftPic17), so ``thorough`` (stored
    images) searches without it, as plain OpenCV does; a miss is retried along :data:`THOROUGH_CHAIN` (the classic
    detector at 960 px, then
    ``findChessboardCornersSB``, which is bounded in time (20-40 ms on a 960-pixel image without a board)
    unlike the classic detector without FAST_CHECK, at 960 px and at full resolution). With ``any_board``, an SB
    step at 960 px without CALIB_CB_NORMALIZE_IMAGE runs only where :class:`AnyBoardSearch` finds a checkerboard of
    some size in the same image.
    """
    gray = to_gray(image)
    small, scale = _search_image(gray, search_width_px)
    if thorough:
        # Stored images, where the board is expected: the search plain OpenCV makes (no FAST_CHECK gate, whose
        # checkChessboard costs ~1.4 ms of a 640x480 image's ~5 ms and can only turn a board away). It finds every
        # board the gated search finds, the same corners (the gate decides only whether the search runs).
        found, corners = cv2.findChessboardCorners(small, board.pattern_size, flags=_SEARCH_FLAGS)
    else:
        found, corners = _find_chessboard_fast_checked(small, board.pattern_size)
    grid = _whole_grid(gray, corners, scale, board, checked=False) if found else None
    if grid is None and thorough:
        # A step whose search image and detector were tried already gives the same answer (the detectors are
        # deterministic): on frames no wider than the search widths (640x480) classic at 960 px repeats the fast
        # search and SB at full resolution repeats SB at 960 px, so they are skipped.
        tried = {("classic", min(search_width_px, max(gray.shape)), _SEARCH_FLAGS)}
        for step in THOROUGH_CHAIN:
            key = (step[0], _thorough_search_width(gray, step, search_width_px), step[2])
            if key in tried:
                continue
            tried.add(key)
            found, corners, scale = _thorough_step(gray, board, step, search_width_px, any_board)
            grid = _whole_grid(gray, corners, scale, board, checked=step[0] == "sb") if found else None
            if grid is not None:
                break
        if grid is None and max(gray.shape) < UPSCALE_BELOW_PX:
            grid = _upscaled_search(gray, board)
    if grid is None:
        return None
    grid = refine_grid(gray, grid)
    grid, order = canonical_order(gray, grid, board)
    return _grid_detection(gray, grid, np.arange(board.n_corners), order, noise=noise)


#: A stored image whose longest side is below this (px) is searched once more at :data:`UPSCALE_FACTOR` times its size
#: (bicubic) when every other step missed: the classic detector's quads lose squares only a few pixels wide
#: (present_cjn at 320x240 and at 320x480 anamorphic: 1 of 60 views each found only so). On misses only: 5 ms median,
#: 69 ms at the 90th percentile, 123 ms at most over 378 searches of the real sets at 0.5x, anamorphic and cropped.
UPSCALE_BELOW_PX = 640
UPSCALE_FACTOR = 2.0


def _upscaled_search(gray: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """The whole board's full-resolution grid from the classic detector on the image enlarged :data:`UPSCALE_FACTOR`
    times; None when it finds none. Not SB: on the enlarged image it doubled the cost of a miss (0.21 -> 0.41 s on
    present_cjn's cut boards at 512 x 384) and found no board the classic detector did not."""
    big = cv2.resize(gray, None, fx=UPSCALE_FACTOR, fy=UPSCALE_FACTOR, interpolation=cv2.INTER_CUBIC)
    found, corners = cv2.findChessboardCorners(big, board.pattern_size, flags=_SEARCH_FLAGS)
    return _whole_grid(gray, corners, UPSCALE_FACTOR, board, checked=False) if found else None


def _whole_grid(gray: np.ndarray, corners: np.ndarray, scale: float, board: Checkerboard, *,
                checked: bool) -> np.ndarray | None:
    """A detector's corners as the (rows, cols, 2) full-resolution grid of the whole board; ``checked`` (an SB
    search's), None when its squares do not make a whole checkerboard (:func:`squares_alternate`). The classic
    detector's are not checked: it finds the board only as quads of whole black squares, and it finds boards whose
    outer squares the border cuts (present_cjn cropped to 80 %: 36 of 60 images, 16 of them so), which the check
    would refuse."""
    grid = _to_full_resolution(corners, scale).reshape(board.rows, board.cols, 2)
    return grid if not checked or squares_alternate(gray, grid) else None


def square_centres(grid: np.ndarray) -> np.ndarray:
    """(rows + 1, cols + 1, 2) centres (px) of the squares of a whole board's (rows, cols, 2) inner-corner grid, its
    outer ring included (the grid's lines extended by one step each way)."""
    rows, cols = grid.shape[:2]
    ext = np.empty((rows + 2, cols + 2, 2))
    ext[1:-1, 1:-1] = grid
    ext[0, 1:-1] = 2 * grid[0] - grid[1]
    ext[-1, 1:-1] = 2 * grid[-1] - grid[-2]
    ext[:, 0] = 2 * ext[:, 1] - ext[:, 2]
    ext[:, -1] = 2 * ext[:, -2] - ext[:, -3]
    return 0.25 * (ext[:-1, :-1] + ext[1:, :-1] + ext[:-1, 1:] + ext[1:, 1:])


def squares_alternate(gray: np.ndarray, grid: np.ndarray) -> bool:
    """Are these the squares of a whole checkerboard: every square, the outer ring included, inside the image, and
    each darker (or brighter, by its place) than every square it shares an edge with?

    ``findChessboardCornersSB`` can return a grid of the board's size on a board the image border cuts: a line of its
    "corners" runs along the board's edge against the background, or its outer squares lie off the image (a cropped
    opencv_sample and smiler488_box view: the grid's ids then name the wrong corners). On every whole board of the
    real sets (125 views) the order holds by at least 14 % of the squares' contrast and every square is inside.
    Grids smaller than 2 x 2 are not judged (True).
    """
    rows, cols = grid.shape[:2]
    if rows < 2 or cols < 2:
        return True
    radius = int(np.clip(0.15 * grid_spacing_px(grid), 1, 4))
    values = _intensity(gray, square_centres(grid).reshape(-1, 2), radius=radius).reshape(rows + 1, cols + 1)
    if not np.all(np.isfinite(values)):
        return False
    even = (np.add.outer(np.arange(rows + 1), np.arange(cols + 1)) % 2) == 0
    dark = np.where(even, 1.0, -1.0) * (1.0 if np.median(values[even]) < np.median(values[~even]) else -1.0)
    # Along both directions: the expected-bright square of each adjacent pair minus the expected-dark one.
    across = (values[:, 1:] - values[:, :-1]) * dark[:, :-1]
    down = (values[1:, :] - values[:-1, :]) * dark[:-1, :]
    return bool(across.min() > 0.0 and down.min() > 0.0)


_SEARCH_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE

# The thorough search's fallbacks after the fast one missed, in order: (detector, search width px; 0 = full
# resolution, flags). Measured on the real sets and on 1280x720 frames holding their boards as a hand-held print
# in a room (scripts/compare_detect_opencv.py): SB with CALIB_CB_NORMALIZE_IMAGE misses boards whose frame is
# mostly an even background (the histogram equalisation it asks for spreads that background's noise over the
# whole grey range), SB without it finds them (4 of 60 present_cjn views at 1280x720: 20-40 ms each at 640-960
# px); full resolution is last, for squares too small for the reduced image (SB: ~120-200 ms at 1280x720,
# ~330 ms at 1080p, bounded even without a board).
THOROUGH_CHAIN = (
    ("classic", THOROUGH_SEARCH_WIDTH_PX, _SEARCH_FLAGS),
    ("sb", THOROUGH_SEARCH_WIDTH_PX, 0),
    ("sb", THOROUGH_SEARCH_WIDTH_PX, cv2.CALIB_CB_NORMALIZE_IMAGE),
    ("sb", 0, 0),
)


def _thorough_search_width(gray: np.ndarray, step: tuple[str, int, int], search_width_px: int) -> int:
    """The longest side (px) of the search image one :data:`THOROUGH_CHAIN` step searches: steps of one detector
    and flags at the same width search the same image (:func:`_search_image` of the same arguments)."""
    width = max(gray.shape) if step[1] == 0 else max(search_width_px, step[1])
    return min(width, max(gray.shape))


def _thorough_step(gray: np.ndarray, board: Checkerboard, step: tuple[str, int, int], search_width_px: int,
                   any_board: AnyBoardSearch | None = None) -> tuple[bool, np.ndarray | None, float]:
    """(found, corners in the search image, its scale) of one :data:`THOROUGH_CHAIN` step."""
    detector, width, flags = step
    width = max(gray.shape) if width == 0 else max(search_width_px, width)
    small, scale = _search_image(gray, width)
    if detector == "classic":
        found, corners = _find_chessboard_fast_checked(small, board.pattern_size)
    elif any_board is not None and width == THOROUGH_SEARCH_WIDTH_PX and flags == 0 and \
            not any_board.search(gray, 0)[0]:
        # No checkerboard of any size in this search image. Only the step without CALIB_CB_NORMALIZE_IMAGE asks: the
        # board-size gate searches a missed image with that flag only when the search without it finds nothing, so
        # asking with it here would add an SB search to an image with a board cut by its border (present_cjn's
        # leftPic07), where the search without it finds the cut grid.
        found, corners = False, None
    else:
        found, corners = _sb(small, board.pattern_size, flags)
    return bool(found), corners, scale


def _find_chessboard_fast_checked(small: np.ndarray, pattern_size: tuple[int, int]) -> tuple[bool, np.ndarray | None]:
    """``cv2.findChessboardCorners(small, pattern_size, flags=_SEARCH_FLAGS | CALIB_CB_FAST_CHECK)``, the same
    result (tests/test_detect_fast_paths.py), ~1 ms (a third) less CPU when the board is there.

    In OpenCV (4.x and 5.x alike) CALIB_CB_FAST_CHECK is only a gate in front of the search: the search goes on
    if ``checkChessboardBinary`` on the histogram-thresholded image accepts, or else if ``cv::checkChessboard``
    on the image does; nothing after the gate reads the flag. On our frames the binary check (~0.9 ms) fails
    and checkChessboard (~0.65 ms) accepts, so asking checkChessboard first and, when it accepts, searching
    without the flag takes the same path minus the binary check. When it refuses, the flagged call decides as
    before (a board-less frame then costs those 0.65 ms more).
    """
    if small.dtype == np.uint8 and small.ndim == 2 and min(pattern_size) > 2 and \
            cv2.checkChessboard(small, pattern_size):
        return cv2.findChessboardCorners(small, pattern_size, flags=_SEARCH_FLAGS)
    return cv2.findChessboardCorners(small, pattern_size, flags=_SEARCH_FLAGS | cv2.CALIB_CB_FAST_CHECK)


def _grid_detection(gray: np.ndarray, grid: np.ndarray, ids: np.ndarray, order: str, *, noise: bool) -> Detection:
    height, width = gray.shape
    corners = grid.reshape(-1, 2)
    sigma = corner_noise_px(gray, corners, half=subpix_half_window(grid_spacing_px(grid))) if noise else None
    return Detection(ids=ids, corners_px=corners, image_size=(width, height), order=order, sigma_px=sigma)


def subpix_half_window(spacing_px: float) -> int:
    """cornerSubPix half-window (px) for corners ``spacing_px`` apart."""
    return int(np.clip(np.floor(SUBPIX_WINDOW_FRACTION * spacing_px), 2, 11))


def refine_grid(gray: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Sub-pixel refinement of a (rows, cols, 2) corner grid at full resolution.

    The window stays within about half a square: a larger one reaches the neighbouring corners'
    edges and breaks on OpenCV's sample images. A small window cannot pull in a corner whose first
    estimate is far off (seen: 5 px at the border of a present_cjn view), so a corner that breaks
    the grid's smoothness is refined again from the position its neighbours predict. A border corner whose
    window reaches the board's edge is refined again with half of it (:func:`_narrow_border`).
    """
    spacing = grid_spacing_px(grid)
    half = subpix_half_window(spacing)
    refined = _subpix(gray, grid.reshape(-1, 2), half).reshape(grid.shape)
    suspects, predicted = _grid_outliers(refined, tolerance_px=max(1.0, 0.15 * spacing))
    # A prediction off the image (a corner at the border extrapolated from its neighbours) cannot be refined there.
    height, width = gray.shape
    suspects &= (predicted[..., 0] >= 0) & (predicted[..., 0] <= width - 1) & (predicted[..., 1] >= 0) & (
        predicted[..., 1] <= height - 1)
    if suspects.any():
        refined[suspects] = _subpix(gray, predicted[suspects], half)
    return _narrow_border(gray, refined, half)


#: A corner on the grid's border refined again with half the window moves more than this (px) only when the full
#: window reaches past the outer squares (the board's edge, its margin, the background) or the board is smeared by
#: motion, not by noise: on the real sets the two agree within 0.44 px (99 % within 0.2) wherever the board has a
#: full outer ring, and disagree by up to 3.9 px where it has not (opencv_sample, foreshortened:
#: scripts/bench_border_corners.py).
BORDER_AGREEMENT_PX = 0.5


def _narrow_border(gray: np.ndarray, grid: np.ndarray, half: int) -> np.ndarray:
    """The (rows, cols, 2) refined grid with each border corner whose refinement depends on the window taken from
    half the window, unless the inner corners' does too.

    An inner corner's window lies within the four squares about it; a border corner's reaches into the outer
    squares, and on a board seen obliquely, or printed with a thin outer ring, past them to the board's edge, whose
    contrast pulls cornerSubPix's saddle off the junction (opencv_sample's right05: 3.9 px at full resolution). The
    half window starts where the full one ended, near the junction even when the detector's first estimate was not.
    On a board smeared by motion the two windows disagree everywhere, inner corners too (the lab bench's hand, seed 1,
    4.7 px of blur: a median of 3.8-4.1 px over the inner corners, against 0.04-0.06 px on its 7 sharp views), and
    neither is the junction: there the grid is left as the full window refined it, for the sharpness gate to judge.
    No real set holds a smeared view; smiler488_box smeared 13 px (tests/test_detect_other_cameras.py) gives inner
    medians of 0.0-3.7 px, and where they stay under the limit the border is still narrowed.
    """
    narrow = max(2, half // 2)
    if narrow >= half:
        return grid
    border = np.zeros(grid.shape[:2], bool)
    border[[0, -1], :] = True
    border[:, [0, -1]] = True
    edge = grid[border]
    again = _subpix(gray, edge, narrow)
    moved = np.linalg.norm(again - edge, axis=1) > BORDER_AGREEMENT_PX
    if not moved.any():
        return grid
    if (~border).any():
        inner = grid[~border]
        if np.median(np.linalg.norm(_subpix(gray, inner, narrow) - inner, axis=1)) > BORDER_AGREEMENT_PX:
            return grid
    grid = grid.copy()
    rows, cols = np.nonzero(border)
    grid[rows[moved], cols[moved]] = again[moved]
    return grid


def _subpix(gray: np.ndarray, corners_px: np.ndarray, half: int) -> np.ndarray:
    refined = cv2.cornerSubPix(
        gray, corners_px.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), SUBPIX_CRITERIA
    )
    return refined.reshape(-1, 2).astype(np.float64)


def grid_spacing_px(grid: np.ndarray) -> float:
    """Shortest distance (px) between row- or column-adjacent corners of a (rows, cols, 2) grid."""
    steps = [np.linalg.norm(np.diff(grid, axis=axis), axis=2) for axis in (0, 1) if grid.shape[axis] > 1]
    return float(min(step.min() for step in steps))


def _line_predictions(grid: np.ndarray, axis: int) -> np.ndarray:
    """Each corner predicted from its neighbours along ``axis``: midpoint inside, extrapolation at the ends."""
    g = np.moveaxis(grid, axis, 0)
    pred = g.copy()
    if len(g) >= 3:
        pred[1:-1] = 0.5 * (g[:-2] + g[2:])
        pred[0] = 2 * g[1] - g[2]
        pred[-1] = 2 * g[-2] - g[-3]
    return np.moveaxis(pred, 0, axis)


def _grid_outliers(grid: np.ndarray, *, tolerance_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) corners that disagree with BOTH their row and column neighbours, and predicted positions.

    Requiring both keeps a good corner next to a bad one (which disagrees along one line only) off the list.
    """
    by_row, by_col = _line_predictions(grid, 1), _line_predictions(grid, 0)
    dev_row = np.linalg.norm(grid - by_row, axis=2)
    dev_col = np.linalg.norm(grid - by_col, axis=2)
    suspects = (dev_row > tolerance_px) & (dev_col > tolerance_px)
    return suspects, 0.5 * (by_row + by_col)


_NOISE_KERNEL = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def image_noise_dn(gray: np.ndarray, *, tile_px: int = 128, tiles_per_side: int = 4) -> float:
    """Standard deviation (grey levels) of white sensor noise in ``gray``.

    Immerkaer's estimator (1996): the 3x3 operator [[1,-2,1],[-2,4,-2],[1,-2,1]] cancels smooth image
    content and leaves 6 x sigma of white noise. Taken as the median over a grid of tiles, so tiles
    crossed by strong edges do not inflate it; ~0.5 ms on a 1080p frame.

    The tiles are filtered as one stack (one OpenCV call instead of one per tile, half the time): a
    tile's border rows and columns, the only ones its neighbours in the stack reach, are not used, so
    each tile's mean response is bit-identical to filtering it alone (tests/test_replay_speed.py).
    """
    height, width = gray.shape
    tile_px = min(tile_px, height, width)
    tops = np.linspace(0, height - tile_px, tiles_per_side).astype(int)
    lefts = np.linspace(0, width - tile_px, tiles_per_side).astype(int)
    tiles = np.stack([gray[y : y + tile_px, x : x + tile_px] for y in tops for x in lefts]).astype(np.float32)
    response = cv2.filter2D(tiles.reshape(-1, tile_px), -1, _NOISE_KERNEL).reshape(tiles.shape)
    means = np.abs(response[:, 1:-1, 1:-1]).mean(axis=(1, 2))  # (tiles,) float32, as tile by tile
    return float(np.median([np.sqrt(np.pi / 2) * mean / 6.0 for mean in means]))


def corner_noise_px(gray: np.ndarray, corners_px: np.ndarray, *, half: int) -> np.ndarray:
    """(N,) per-coordinate standard deviation (px) of each refined corner under the image's sensor noise.

    First-order: sigma^2 = c^2 * sigma_I^2 * trace(A^-1) / 2 with A the structure tensor (sum of
    g g^T over the refinement window) and sigma_I from :func:`image_noise_dn`; the factor c =
    CORNER_NOISE_FACTOR accounts for cornerSubPix's estimator, which also suffers noise in the
    gradients it weights with. This is the random part only: lens-model misfit and print errors are
    systematic and do not average away.
    """
    sigma_image = image_noise_dn(gray)
    axx, axy, ayy = _structure_tensors(gray, corners_px, 2 * half + 3)
    det = axx * ayy - axy**2
    # trace(A^-1) of a 2x2 matrix is (axx + ayy) / det.
    with np.errstate(divide="ignore", invalid="ignore"):
        sigmas = CORNER_NOISE_FACTOR * sigma_image * np.sqrt((axx + ayy) / det / 2.0)
    return np.where(det > 1e-9, sigmas, np.nan)


def _structure_tensors(gray: np.ndarray, corners_px: np.ndarray, size: int) -> tuple[np.ndarray, ...]:
    """(axx, axy, ayy), each (N,): sums of gx^2, gx gy, gy^2 over the (size - 2)^2 central-difference gradients
    gx = (p[x + 1] - p[x - 1]) / 2 of the size x size sub-pixel patch around each corner (uint8, as
    ``cv2.getRectSubPix`` gives it; OpenCV's IPP path rounds its own way, so the patches stay its).

    Exact, hence in any order: the gradients are multiples of 1/2 below 128 in magnitude, their products
    multiples of 1/4, and a sum of fewer than 2^20 of them is an integer number of quarters below 2^36, which
    float64 holds without rounding. So one dot product per corner gives the numbers the per-pixel
    (N, size - 2, size - 2) float64 arithmetic gave, bit for bit (tests/test_detect_fast_paths.py); with the
    patches written into one stack: 0.39 -> 0.24 ms for an 11x8 board's 88 corners.
    """
    patches = np.empty((len(corners_px), size, size), np.uint8)
    for patch, centre in zip(patches, np.asarray(corners_px, np.float64).tolist(), strict=True):
        # Written into its slot of the stack; the assignment only matters if OpenCV ever gave a new array.
        patch[...] = cv2.getRectSubPix(gray, (size, size), centre, patch)
    signed = patches.astype(np.int16)
    steps_x = (signed[:, 1:-1, 2:] - signed[:, 1:-1, :-2]).reshape(len(signed), -1).astype(np.float64)
    steps_y = (signed[:, 2:, 1:-1] - signed[:, :-2, 1:-1]).reshape(len(signed), -1).astype(np.float64)
    # Twice the gradients: each sum of products is 4x the tensor's entry, and / 4 is exact.
    return tuple(np.einsum("ij,ij->i", a, b) / 4.0 for a, b in ((steps_x, steps_x), (steps_x, steps_y),
                                                                   (steps_y, steps_y)))


def _intensity(gray: np.ndarray, points_px: np.ndarray, radius: int = 1) -> np.ndarray:
    """(N,) mean grey level in a (2 radius + 1)^2 patch around each point; NaN outside the image."""
    height, width = gray.shape
    values = np.full(len(points_px), np.nan)
    for i, (x, y) in enumerate(np.rint(np.asarray(points_px).reshape(-1, 2)).astype(int)):
        if radius <= x < width - radius and radius <= y < height - radius:
            values[i] = gray[y - radius : y + radius + 1, x - radius : x + radius + 1].mean()
    return values


def _cell_is_black(gray: np.ndarray, grid: np.ndarray) -> bool | None:
    """Is the square between grid corners (0, 0) and (1, 1) black? None when the contrast is too low.

    Compared with the next square inside the grid (never outside it, which may be off the image).
    """
    def centre(r: int, c: int) -> np.ndarray:
        return 0.25 * (grid[r, c] + grid[r + 1, c] + grid[r, c + 1] + grid[r + 1, c + 1])

    if grid.shape[0] < 2 or grid.shape[1] < 2 or max(grid.shape[:2]) < 3:
        return None
    neighbour = centre(0, 1) if grid.shape[1] >= 3 else centre(1, 0)
    square, other = _intensity(gray, np.array([centre(0, 0), neighbour]), radius=2)
    if not np.isfinite(square) or not np.isfinite(other) or abs(square - other) < 10:
        return None
    return bool(square < other)


def canonical_order(gray: np.ndarray, grid: np.ndarray, board: Checkerboard) -> tuple[np.ndarray, str]:
    """Put a whole-board grid in the board's own row-major order; returns (grid, how it was decided).

    By convention the square diagonally outside corner 0 is black, so the square inside the grid
    between corners (0, 0) and (1, 1) is black too; after a half turn it is white unless the
    board is point-symmetric.
    """
    if not board.is_point_symmetric:
        black = _cell_is_black(gray, grid)
        if black is not None:
            return (grid if black else grid[::-1, ::-1].copy()), "colour"
    row_direction = grid[0, -1] - grid[0, 0]
    return (grid if row_direction[0] >= 0 else grid[::-1, ::-1].copy()), "layout"


def _front_handed(grid: np.ndarray) -> bool:
    """Is a (rows, cols, 2) grid's lattice as a board's seen from its front: the row direction turned clockwise in the
    image (y down) gives the column direction? Every whole board of the real sets and the renderer's is."""
    along, down = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    return bool(along[0] * down[1] - along[1] * down[0] > 0)


def _upright(grid: np.ndarray) -> np.ndarray:
    """Orient a (rows, cols, 2) grid so columns run toward +u and rows toward +v in the image.

    A stereo rig sees its target roughly upright (roll well under 45 degrees), which is what makes
    the assignment of a partial grid's axes to the board's axes unambiguous.
    """
    along = grid[:, -1] - grid[:, 0]
    if np.abs(along[:, 0]).mean() < np.abs(along[:, 1]).mean():
        grid = grid.transpose(1, 0, 2)
    if (grid[:, -1, 0] - grid[:, 0, 0]).mean() < 0:
        grid = grid[:, ::-1]
    if (grid[-1, :, 1] - grid[0, :, 1]).mean() < 0:
        grid = grid[::-1, :]
    return np.ascontiguousarray(grid)


def _ends_at_board_edge(gray: np.ndarray, grid: np.ndarray, axis: int, side: int, white_level: float) -> bool:
    """Does the board end just beyond the ``side`` (0: first, -1: last) line of corners along ``axis``?

    One step beyond the last inner corners lie the board's outer squares; 1.3 steps beyond, the
    white margin — or, if the board went on, squares of both colours. The board edge is proven
    when every sample there is inside the image and white.
    """
    g = np.moveaxis(grid, axis, 0)
    last, previous = (g[0], g[1]) if side == 0 else (g[-1], g[-2])
    # Sample between lines of the other axis so we hit square centres, not edges.
    beyond = last + 1.3 * (last - previous)
    midpoints = 0.5 * (beyond[:-1] + beyond[1:])
    values = _intensity(gray, midpoints, radius=2)
    return bool(len(values) >= 2 and np.all(np.isfinite(values)) and np.all(values > white_level))


def detect_checkerboard_partial(
    image: np.ndarray, board: Checkerboard, *, search_width_px: int = DEFAULT_SEARCH_WIDTH_PX, min_corners: int = 6,
    noise: bool = True,
) -> Detection | None:
    """A checkerboard cut by the image border: the visible corners with their board ids.

    ``findChessboardCornersSB`` with ``CALIB_CB_LARGER`` returns the visible grid. Which board
    corners it holds is proven, per axis, from the board's own edges: where the detected grid stops
    inside the image with white margin beyond, the board ends (SB would otherwise have found the
    next corners); the other end is the image border. The colour of the first square must then
    agree with the board's colour convention at the inferred position, or the view is refused.
    Needs a white margin of at least a third of a square around the printed squares.

    Raises:
        AmbiguousViewError: a grid was found but its place on the board cannot be proven.
    """
    gray = to_gray(image)
    small, scale = _search_image(gray, search_width_px)
    found, corners, meta = _sb_with_meta(small, (3, 3), cv2.CALIB_CB_LARGER | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found or corners is None or meta is None or meta.size != len(corners):
        return None
    # SB returns the found grid row-major; meta has its (rows, cols) shape.
    found_grid = _to_full_resolution(corners, scale).reshape(*meta.shape, 2)
    if sorted(found_grid.shape[:2]) == sorted((board.rows, board.cols)):
        # The whole board, at any roll in the image: in the board's own order up to a half turn (which
        # canonical_order decides) once its axes are the board's and its handedness a board's seen from the front.
        grid = found_grid if found_grid.shape[:2] == (board.rows, board.cols) else found_grid.transpose(1, 0, 2)
        grid = np.ascontiguousarray(grid if _front_handed(grid) else grid[:, ::-1])
        if not squares_alternate(gray, grid):
            return None
        grid, order = canonical_order(gray, refine_grid(gray, grid), board)
        return _grid_detection(gray, grid, np.arange(board.n_corners), order, noise=noise)
    grid = _upright(found_grid)
    rows_seen, cols_seen = grid.shape[:2]
    if rows_seen > board.rows or cols_seen > board.cols or rows_seen * cols_seen < min_corners:
        return None
    grid = refine_grid(gray, grid)
    black_level, white_level = _square_levels(gray, grid)
    threshold = 0.5 * (black_level + white_level)
    offsets = []
    for axis, n_board, name in ((0, board.rows, "rows"), (1, board.cols, "columns")):
        n_seen = grid.shape[axis]
        if n_seen == n_board:
            offsets.append(0)
            continue
        first = _ends_at_board_edge(gray, grid, axis, 0, threshold)
        last = _ends_at_board_edge(gray, grid, axis, -1, threshold)
        if first == last:
            raise AmbiguousViewError(
                f"partial checkerboard: {n_seen} of {n_board} {name} visible and "
                + ("both" if first else "neither") + " end(s) show the board's edge, so which "
                f"{name} they are cannot be proven; use a ChArUco target for views this partial"
            )
        offsets.append(0 if first else n_board - n_seen)
    row0, col0 = offsets
    black = _cell_is_black(gray, grid)
    if black is None or black != ((row0 + col0) % 2 == 0):
        raise AmbiguousViewError("partial checkerboard: square colours contradict the board edges found")
    ids = ((row0 + np.arange(rows_seen))[:, None] * board.cols + (col0 + np.arange(cols_seen))[None, :]).ravel()
    return _grid_detection(gray, grid, ids, "edges", noise=noise)


def _square_levels(gray: np.ndarray, grid: np.ndarray) -> tuple[float, float]:
    """(black, white) grey levels of the squares inside the grid."""
    values = _intensity(gray, square_centres(grid)[1:-1, 1:-1].reshape(-1, 2), radius=2)
    values = values[np.isfinite(values)]
    middle = np.median(values)
    return float(values[values <= middle].mean()), float(values[values > middle].mean())


def detect_charuco(image: np.ndarray, target: CharucoTarget, *, min_corners: int = 4,
                   noise: bool = True) -> Detection | None:
    """ChArUco detection: every identified corner, partial views included; None below ``min_corners``.

    An ``inverted`` target is looked for in the inverted grey image (the corner noise estimate is the same
    either way: it depends on gradient magnitudes only)."""
    gray = to_gray(image)
    if target.inverted:
        gray = 255 - gray
    detector = _charuco_detector(target)
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < min_corners:
        return None
    ids = np.asarray(ids).reshape(-1).astype(int)
    order = np.argsort(ids)
    height, width = gray.shape
    corners = np.asarray(corners, np.float64).reshape(-1, 2)[order]
    return Detection(
        ids=ids[order], corners_px=corners, image_size=(width, height), order="ids",
        sigma_px=corner_noise_px(gray, corners, half=CHARUCO_HALF_WINDOW) if noise else None,
    )


_CHARUCO_DETECTORS: dict[CharucoTarget, cv2.aruco.CharucoDetector] = {}


def _charuco_detector(target: CharucoTarget) -> cv2.aruco.CharucoDetector:
    if target not in _CHARUCO_DETECTORS:
        _CHARUCO_DETECTORS[target] = cv2.aruco.CharucoDetector(board_markers_only(target.cv_board))
    return _CHARUCO_DETECTORS[target]


def board_markers_only(board: cv2.aruco.CharucoBoard) -> cv2.aruco.CharucoBoard:
    """The same board with its dictionary cut to the markers up to the board's largest id.

    ``Dictionary.identify`` returns the first marker, in id order, within the correction distance
    (OpenCV 4.x and 5.x alike), so for every id the board uses the cut dictionary gives the same
    answer as the whole one; a candidate that matches only a marker beyond the board's ids, which
    the board would ignore anyway, is rejected instead. Candidates, thresholds and refinement are
    untouched. Cost: the identification scan shrinks from all of DICT_5X5_1000 to 54 markers for a
    12x9 board.
    """
    dictionary = board.getDictionary()
    n_markers = int(np.max(board.getIds())) + 1
    cut = cv2.aruco.Dictionary(
        np.ascontiguousarray(dictionary.bytesList[:n_markers]), dictionary.markerSize, dictionary.maxCorrectionBits
    )
    fast = cv2.aruco.CharucoBoard(
        board.getChessboardSize(), board.getSquareLength(), board.getMarkerLength(), cut, board.getIds()
    )
    fast.setLegacyPattern(board.getLegacyPattern())
    return fast


def common_corners(left: Detection, right: Detection) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ids (N,), left_px (N, 2), right_px (N, 2)) for the corners seen in both views."""
    ids, left_index, right_index = np.intersect1d(left.ids, right.ids, assume_unique=True, return_indices=True)
    return ids, left.corners_px[left_index], right.corners_px[right_index]


def common_sigmas(left: Detection, right: Detection) -> tuple[np.ndarray, np.ndarray] | None:
    """Per-corner noise (left (N,), right (N,)) in the order of :func:`common_corners`, if both views have it."""
    if left.sigma_px is None or right.sigma_px is None:
        return None
    _, left_index, right_index = np.intersect1d(left.ids, right.ids, assume_unique=True, return_indices=True)
    return left.sigma_px[left_index], right.sigma_px[right_index]
