"""Detection's fast paths give bit-identical numbers to the plain computations they replace (replay must reproduce
recorded sessions to the last bit): the search image, the structure tensors of corner_noise_px, and whole
detections on rendered frames, the real image sets, odd sizes and colour input.

The replay as a whole is checked against recorded numbers in tests/test_campaign_run.py.
"""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np
import pytest

from stereo_bench.targets import CharucoTarget, Checkerboard
from stereo_bench.vision import detect as detect_module
from stereo_bench.vision.detect import (
    _SEARCH_FLAGS,
    CORNER_NOISE_FACTOR,
    corner_noise_px,
    detect,
    grid_spacing_px,
    image_noise_dn,
    subpix_half_window,
)
from tests.campaigns import sample_session_frames
from tests.real_data import OPENCV_SAMPLE, PRESENT_CJN

SAMPLE_TARGET = Checkerboard(9, 6, 27.0)


def plain_search_image(gray: np.ndarray, search_width_px: int) -> np.ndarray:
    """The search image as it was made before the box-sum fast path."""
    height, width = gray.shape
    scale = min(1.0, search_width_px / max(width, height))
    return cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1.0 else gray


def plain_corner_noise_px(gray: np.ndarray, corners_px: np.ndarray, *, half: int) -> np.ndarray:
    """corner_noise_px as it was computed before: one float64 patch stack, per-pixel gradient products."""
    sigma_image = image_noise_dn(gray)
    size = 2 * half + 3
    patches = np.stack([
        cv2.getRectSubPix(gray, (size, size), (float(x), float(y))) for x, y in corners_px
    ]).astype(np.float64)
    gx = 0.5 * (patches[:, 1:-1, 2:] - patches[:, 1:-1, :-2])
    gy = 0.5 * (patches[:, 2:, 1:-1] - patches[:, :-2, 1:-1])
    axx, axy, ayy = (gx * gx).sum(axis=(1, 2)), (gx * gy).sum(axis=(1, 2)), (gy * gy).sum(axis=(1, 2))
    det = axx * ayy - axy**2
    with np.errstate(divide="ignore", invalid="ignore"):
        sigmas = CORNER_NOISE_FACTOR * sigma_image * np.sqrt((axx + ayy) / det / 2.0)
    return np.where(det > 1e-9, sigmas, np.nan)


def plain_find_chessboard(small: np.ndarray, pattern_size: tuple[int, int]) -> tuple[bool, np.ndarray | None]:
    return cv2.findChessboardCorners(small, pattern_size, flags=_SEARCH_FLAGS | cv2.CALIB_CB_FAST_CHECK)


def assert_same_bits(fast: np.ndarray, plain: np.ndarray, what: str) -> None:
    assert fast.dtype == plain.dtype and fast.shape == plain.shape, what
    assert fast.tobytes() == plain.tobytes(), what  # NaN where NaN, and -0.0 apart from 0.0


def rendered_frames() -> tuple[np.ndarray, ...]:
    frames = sample_session_frames(3)
    assert len(frames) >= 10
    return frames


@cache
def real_images() -> tuple[tuple[np.ndarray, Checkerboard], ...]:
    """Every third image of both real sets, in colour (BGR) as the JPEG files hold them."""
    sets = ((OPENCV_SAMPLE, "*.jpg", Checkerboard(9, 6, 30.0)), (PRESENT_CJN, "*.jpg", Checkerboard(8, 11, 12.0)))
    images = tuple((cv2.imread(str(path), cv2.IMREAD_COLOR), board)
                   for folder, pattern, board in sets for path in sorted(folder.glob(pattern))[::3])
    assert len(images) >= 20 and all(image is not None for image, _ in images)
    return images


def random_image(shape: tuple[int, ...], seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


@pytest.mark.parametrize("search_width_px", [640, 960])
def test_search_image_is_bit_identical_to_inter_area_on_rendered_frames(search_width_px):
    for frame in rendered_frames():
        small, scale = detect_module._search_image(frame, search_width_px)
        assert scale == min(1.0, search_width_px / max(frame.shape))
        assert_same_bits(small, plain_search_image(frame, search_width_px), f"{frame.shape} at {search_width_px}")


@pytest.mark.parametrize("shape, search_width_px", [
    ((1080, 1920), 640),  # 1/3: the box-sum path
    ((1920, 1080), 640),  # portrait
    ((1200, 1920), 640),
    ((1800, 3200), 640),  # 1/5
    ((99, 3 * 640), 640),
    ((1080, 1920), 960),  # 1/2: ties possible, INTER_AREA
    ((1081, 1920), 640),  # not a whole number of blocks: INTER_AREA
    ((1080, 1921), 640),  # not a whole-number factor: INTER_AREA
    ((480, 640), 640),  # no reduction
    ((720, 1280), 640),
])
def test_search_image_is_bit_identical_to_inter_area_on_any_image(shape, search_width_px):
    # Random levels give block sums of every remainder, the nearest to half-way included (9 k + 4, 9 k + 5).
    height, width = shape
    ramp = np.add.outer(np.arange(height), np.arange(width)).astype(np.uint8)
    for name, image in (("random", random_image(shape, 1)), ("white", np.full(shape, 255, np.uint8)), ("ramp", ramp)):
        assert_same_bits(detect_module._search_image(image, search_width_px)[0],
                         plain_search_image(image, search_width_px), f"{shape} {name}")


def test_box_shrink_is_used_for_full_hd_frames():
    """The fast path is the one taken by the replay's 1920x1080 frames at the default search width."""
    assert detect_module._box_shrinks_exactly(np.zeros((1080, 1920), np.uint8), 3)
    assert not detect_module._box_shrinks_exactly(np.zeros((1080, 1920), np.uint8), 2)
    assert not detect_module._box_shrinks_exactly(np.zeros((1081, 1920), np.uint8), 3)


def test_corner_noise_is_bit_identical_on_detected_corners_of_rendered_and_real_images():
    cases = [(frame, SAMPLE_TARGET) for frame in rendered_frames()] + list(real_images())
    checked = 0
    for image, board in cases:
        detection = detect(image, board, thorough=True)
        if detection is None:
            continue
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        half = subpix_half_window(grid_spacing_px(detection.corners_px.reshape(board.rows, board.cols, 2)))
        assert_same_bits(detection.sigma_px, plain_corner_noise_px(gray, detection.corners_px, half=half),
                         "the detection's sigmas")
        for other_half in (2, 11):
            assert_same_bits(corner_noise_px(gray, detection.corners_px, half=other_half),
                             plain_corner_noise_px(gray, detection.corners_px, half=other_half), f"half {other_half}")
        checked += 1
    assert checked >= 30


@pytest.mark.parametrize("shape", [(1080, 1920), (480, 640), (37, 300), (60, 41)])
def test_corner_noise_is_bit_identical_at_any_point_and_at_the_image_border(shape):
    rng = np.random.default_rng(shape[0])
    height, width = shape
    # Random texture, a smooth ramp (gradients everywhere equal) and a flat image (no gradient: NaN sigmas).
    ramp = np.add.outer(np.arange(height), 2 * np.arange(width)).astype(np.uint8)
    for image in (random_image(shape, 3), ramp, np.full(shape, 90, np.uint8)):
        inside = rng.uniform([0, 0], [width - 1, height - 1], (200, 2))
        corners = np.vstack([inside, [[0, 0], [width - 1, height - 1], [0.5, height / 2], [width - 1.5, 3.25]]])
        for half in (2, 5, 11):
            assert_same_bits(corner_noise_px(image, corners, half=half),
                             plain_corner_noise_px(image, corners, half=half), f"{shape} half {half}")


def test_detections_of_colour_and_grey_input_are_the_same():
    image, board = real_images()[0]
    colour, grey = detect(image, board), detect(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), board)
    assert colour is not None and grey is not None
    for field in ("ids", "corners_px", "sigma_px"):
        assert_same_bits(getattr(colour, field), getattr(grey, field), field)


def assert_same_search(small: np.ndarray, pattern_size: tuple[int, int], what: str) -> bool:
    found, corners = detect_module._find_chessboard_fast_checked(small, pattern_size)
    plain_found, plain_corners = plain_find_chessboard(small, pattern_size)
    assert found == plain_found, what
    if plain_corners is None:
        assert corners is None, what
    else:
        assert_same_bits(corners, plain_corners, what)
    return found


def test_chessboard_search_is_the_fast_checked_one_on_rendered_frames_and_their_cut_and_empty_parts():
    found = 0
    for frame in rendered_frames():
        for width in (640, 960):
            small, _ = detect_module._search_image(frame, width)
            if not assert_same_search(small, SAMPLE_TARGET.pattern_size, f"frame at {width} px"):
                continue
            found += 1
            if found > 2:  # a cut board passes the gate and is searched for long (~0.3 s), in both
                continue
            # The board cut by the image border through its middle row of corners, and a strip beside it.
            corners = plain_find_chessboard(small, SAMPLE_TARGET.pattern_size)[1].reshape(-1, 2)
            cut = int(np.median(corners[:, 1]))
            assert not assert_same_search(np.ascontiguousarray(small[:cut]), SAMPLE_TARGET.pattern_size, "cut")
            left = int(corners[:, 0].min()) - 2
            assert not assert_same_search(np.ascontiguousarray(small[:, :left]), SAMPLE_TARGET.pattern_size, "beside")
        assert_same_search(detect_module._search_image(frame, 640)[0], (11, 8), "another board's size")
    assert found >= 20  # the shortcut was taken


def test_chessboard_search_is_the_fast_checked_one_on_real_images():
    """Both real sets, in both orientations of the pattern size; FAST_CHECK rejects a real board in present_cjn."""
    found = 0
    for image, board in real_images():
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        for pattern_size in (board.pattern_size, board.pattern_size[::-1]):
            found += assert_same_search(gray, pattern_size, f"{board} {pattern_size}")
    assert found >= 20
    # leftPic17: the board is there, FAST_CHECK turns it away (checkChessboard too); leftPic07: no board.
    for name in ("leftPic17.jpg", "leftPic07.jpg"):
        gray = cv2.imread(str(PRESENT_CJN / name), cv2.IMREAD_GRAYSCALE)
        assert not assert_same_search(gray, (8, 11), name)
    assert cv2.findChessboardCorners(cv2.imread(str(PRESENT_CJN / "leftPic17.jpg"), cv2.IMREAD_GRAYSCALE), (8, 11),
                                     flags=_SEARCH_FLAGS)[0]  # the gate, not the search, decides there


@pytest.mark.parametrize("shape", [(360, 640), (37, 300), (60, 41), (5, 5)])
def test_chessboard_search_is_the_fast_checked_one_without_a_board(shape):
    ramp = np.add.outer(np.arange(shape[0]), np.arange(shape[1])).astype(np.uint8)
    for image in (random_image(shape, 5), np.full(shape, 128, np.uint8), ramp):
        assert not assert_same_search(image, (9, 6), f"{shape}")


def test_without_noise_the_corners_and_ids_are_the_same_and_sigma_is_unknown():
    """detect(noise=False) (calibration views whose frames are kept) skips only the corner-noise estimate."""
    cases = [(frame, SAMPLE_TARGET, partial) for frame in rendered_frames()[:3] for partial in (False, True)]
    cases += [(image, board, False) for image, board in real_images()[:3]]
    charuco = CharucoTarget(squares_x=7, squares_y=5, square_mm=30.0, marker_mm=22.0)
    board_image = charuco.cv_board.generateImage((1400, 1000), marginSize=60)
    cases.append((board_image, charuco, False))
    checked = 0
    for image, target, partial in cases:
        with_noise = detect(image, target, partial=partial)
        without = detect(image, target, partial=partial, noise=False)
        assert (with_noise is None) == (without is None)
        if with_noise is None:
            continue
        checked += 1
        assert without.sigma_px is None and with_noise.sigma_px is not None
        for field in ("ids", "corners_px"):
            assert_same_bits(getattr(without, field), getattr(with_noise, field), field)
        assert (without.order, without.image_size) == (with_noise.order, with_noise.image_size)
    assert checked >= 6


def full_chain_corners(image: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """The thorough search's corners in the search image as before repeated steps were skipped: every step of
    THOROUGH_CHAIN in turn after plain OpenCV's search (no FAST_CHECK gate: stored images)."""
    gray = detect_module.to_gray(image)
    small, _ = detect_module._search_image(gray, detect_module.DEFAULT_SEARCH_WIDTH_PX)
    found, corners = cv2.findChessboardCorners(small, board.pattern_size, flags=_SEARCH_FLAGS)
    for step in detect_module.THOROUGH_CHAIN:
        if found:
            break
        found, corners, _ = detect_module._thorough_step(gray, board, step, detect_module.DEFAULT_SEARCH_WIDTH_PX)
    return corners if found else None


def test_thorough_detection_skipping_repeated_steps_finds_what_the_full_chain_finds_on_real_images():
    """present_cjn holds views the fast search misses (leftPic17, found by the search without the FAST_CHECK gate
    that the thorough one starts with; leftPic07, found by none): 640x480 frames, where the chain's classic step at
    960 px and SB at full resolution repeat earlier searches and are skipped."""
    board, missed_fast = Checkerboard(8, 11, 12.0), 0
    board_views = 0
    for path in sorted(PRESENT_CJN.glob("*.jpg")):
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        missed_fast += not plain_find_chessboard(image, board.pattern_size)[0]
        chain = full_chain_corners(image, board)
        found = detect(image, board, thorough=True, noise=False)
        assert (found is None) == (chain is None)
        if found is not None:
            board_views += 1
            gray = detect_module.to_gray(image)
            scale = min(1.0, detect_module.THOROUGH_SEARCH_WIDTH_PX / max(gray.shape))
            grid = detect_module.refine_grid(
                gray, detect_module._to_full_resolution(chain, scale).reshape(board.rows, board.cols, 2))
            grid, _ = detect_module.canonical_order(gray, grid, board)
            assert_same_bits(found.corners_px, grid.reshape(-1, 2), "thorough corners")
    assert board_views > 0 and missed_fast >= 2
