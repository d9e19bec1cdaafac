"""The stereo renderer against its ground truth: detectors find the corners where the truth says.

Every test uses a seeded generator. Tolerances are stated next to the asserts; the measured figures
on OpenCV 5.0 (printed with ``pytest -s``) are about a third of them.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from drivers.sim.render import (
    Optics,
    RenderedPair,
    RenderedView,
    StereoRenderer,
    _bisect_largest,
    calibration_board_poses,
)
from stereo_bench.geometry import (
    CameraModel,
    RigPose,
    board_pose_facing_rig,
    invert_transform,
    make_transform,
    transform_points,
    visible_in_both,
)
from stereo_bench.targets import CharucoTarget, Checkerboard

BOARD = Checkerboard(9, 6, 27.0)
CHARUCO = CharucoTarget(10, 7, 25.0, 18.0)
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 1e-3)


@pytest.fixture(scope="module")
def renderer() -> StereoRenderer:
    return StereoRenderer(BOARD)


def detect_chessboard(image: np.ndarray, pattern_size: tuple[int, int]) -> np.ndarray | None:
    """(N, 2) corners: detect on a reduced frame (fast, per the brief), refine at full resolution (11x11)."""
    h, w = image.shape
    for factor in (4, 2):
        small = cv2.resize(image, (w // factor, h // factor), interpolation=cv2.INTER_AREA)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        found, corners = cv2.findChessboardCorners(small, pattern_size, flags=flags)
        if found:
            # INTER_AREA by an integer factor: small pixel k is centred on full pixel f*k + (f-1)/2.
            guess = corners.reshape(-1, 1, 2) * factor + (factor - 1) / 2.0
            refined = cv2.cornerSubPix(image, guess.astype(np.float32), (5, 5), (-1, -1), SUBPIX_CRITERIA)
            return refined.reshape(-1, 2).astype(np.float64)
    return None


def in_truth_order(detected: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The detection in truth order: it must be the same order or its exact reverse."""
    forward = np.abs(detected - truth).max()
    backward = np.abs(detected[::-1] - truth).max()
    assert min(forward, backward) < 0.5, f"detected corners match truth in neither order ({forward}, {backward})"
    return detected if forward <= backward else detected[::-1]


def rms(errors: np.ndarray) -> float:
    return float(np.sqrt((errors**2).sum(axis=1).mean()))


# --------------------------------------------------------------------------------------------
# Geometry of the image formation


def test_distortion_map_inverts_the_camera_projection(renderer):
    """The per-camera remap samples the pinhole image exactly where CameraModel.project says."""
    camera = renderer.left
    raster = renderer._rasters["left"]
    s = raster.s
    rng = np.random.default_rng(1)
    rows = rng.integers(0, raster.map_x.shape[0], 4000)
    cols = rng.integers(0, raster.map_x.shape[1], 4000)
    # Supersample (row, col) sits at sensor pixel ((col - (s-1)/2) / s, ...).
    sensor = np.column_stack([(cols - (s - 1) / 2) / s, (rows - (s - 1) / 2) / s])
    ideal = (np.column_stack([raster.map_x[rows, cols], raster.map_y[rows, cols]]) - raster.S[:2, 2]) / s
    rays = np.column_stack([(ideal - camera.K[:2, 2]) / np.diag(camera.K)[:2], np.ones(len(ideal))])
    reprojected, _ = camera.project(rays)
    assert np.abs(reprojected - sensor).max() < 2e-3  # px; measured ~2e-4 (float32 maps)


@pytest.mark.parametrize("distance_mm, offset_mm", [(300.0, 0.07), (500.0, 0.0), (500.0, 0.19), (800.0, 0.31)])
def test_edges_lie_where_the_truth_says(distance_mm, offset_mm):
    """Edge positions, measured without a corner detector, match the projection to a few 0.001 px.

    Distortion-free, fronto-parallel board, faint noise (1 DN, to dither the 8-bit rounding): every
    vertical edge is a straight column whose position is the centroid of the horizontal gradient,
    exact for a symmetric blur. cornerSubPix itself locks to pixels by up to ~0.03 px, so this is
    the sharper check of the texture's half-pixel convention, the pyramid alignment and the
    anti-aliasing.
    """
    camera = CameraModel.from_sensor(dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    optics = Optics(noise_sigma_dn=1.0, vignetting=0.0)
    r = StereoRenderer(BOARD, camera, camera, optics=optics)
    T = board_pose_facing_rig(distance_mm=distance_mm, board_size_mm=BOARD.grid_size_mm,
                              centre_offset_mm=(offset_mm, 0.0))
    view = r.render_view("left", T, np.random.default_rng(0))
    image = view.image.astype(np.float64)
    corners = view.corners_px.reshape(BOARD.rows, BOARD.cols, 2)
    margin = 0.2 * np.linalg.norm(corners[1, 0] - corners[0, 0])
    errors = []
    for row in range(BOARD.rows - 1):
        for col in range(BOARD.cols):
            x_true = corners[row, col, 0]
            y_top, y_bottom = corners[row, col, 1] + margin, corners[row + 1, col, 1] - margin
            # +-4.5 px holds the whole edge (sigma ~0.75 px) but little noise; the signed gradient keeps
            # the noise in the flanks unbiased.
            first = int(round(x_true)) - 4
            band = image[int(y_top) : int(y_bottom), first : first + 10].mean(axis=0)
            gradient = np.diff(band) * np.sign(band[-1] - band[0])
            centres = first + np.arange(len(gradient)) + 0.5
            errors.append((gradient * centres).sum() / gradient.sum() - x_true)
    errors = np.array(errors)
    print(f"Z {distance_mm:g} mm, offset {offset_mm} mm: edge error mean {errors.mean():+.4f} px, "
          f"max {np.abs(errors).max():.4f} px")
    assert abs(errors.mean()) < 0.005  # px; measured <= 0.003
    assert np.abs(errors).max() < 0.04  # single edges carry the (1 DN) noise: ~0.007 px each


def test_checkerboard_corners_found_where_the_truth_says(renderer):
    """Issue 2 (a): B = 100, Z = 500, alpha = 90: quarter-res detect + 11x11 cornerSubPix vs truth."""
    rig = RigPose.symmetric(100.0, 90.0)
    T_rig_board = board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm)
    pair = renderer.render_pair(rig, T_rig_board, np.random.default_rng(2))
    for view in (pair.left, pair.right):
        assert view.visible.all()
        detected = detect_chessboard(view.image, BOARD.pattern_size)
        assert detected is not None
        errors = in_truth_order(detected, view.corners_px) - view.corners_px
        print(f"corner RMS {rms(errors):.4f} px, bias {errors.mean(axis=0)}, max {np.abs(errors).max():.4f} px")
        assert rms(errors) <= 0.1  # px; measured 0.03-0.05
        assert np.abs(errors).max() < 0.25


def test_corner_bias_is_negligible_over_varied_poses(renderer):
    """Mean detected - truth over many corners at varied sub-pixel phases: no half-pixel slip."""
    rng = np.random.default_rng(3)
    errors = []
    for _ in range(6):
        T = board_pose_facing_rig(
            distance_mm=rng.uniform(400, 650), board_size_mm=BOARD.grid_size_mm,
            centre_offset_mm=tuple(rng.uniform(-60, 60, 2)), yaw_deg=rng.uniform(-25, 25),
            pitch_deg=rng.uniform(-25, 25),
        )
        view = renderer.render_view("left", T, rng)
        detected = detect_chessboard(view.image, BOARD.pattern_size)
        assert detected is not None
        errors.append(in_truth_order(detected, view.corners_px) - view.corners_px)
    errors = np.vstack(errors)
    print(f"{len(errors)} corners: RMS {rms(errors):.4f} px, bias {errors.mean(axis=0)}")
    assert np.abs(errors.mean(axis=0)).max() < 0.02  # px; measured < 0.01
    assert rms(errors) < 0.08


def test_charuco_board_renders_real_markers():
    """Issue 2 (b): CharucoDetector finds the ids the truth says are visible, at the true positions."""
    r = StereoRenderer(CHARUCO)
    rig = RigPose.symmetric(100.0, 90.0)
    T_rig_board = board_pose_facing_rig(distance_mm=550.0, board_size_mm=CHARUCO.grid_size_mm, yaw_deg=20,
                                        pitch_deg=-15)
    pair = r.render_pair(rig, T_rig_board, np.random.default_rng(4))
    detector = cv2.aruco.CharucoDetector(CHARUCO.cv_board)
    for view in (pair.left, pair.right):
        corners, ids, _, marker_ids = detector.detectBoard(view.image)
        assert ids is not None and marker_ids is not None
        ids = ids.ravel()
        assert len(marker_ids) == CHARUCO.squares_x * CHARUCO.squares_y // 2
        assert set(ids) == set(np.flatnonzero(view.visible))
        errors = corners.reshape(-1, 2) - view.corners_px[ids]
        print(f"charuco: {len(ids)} corners, RMS {rms(errors):.4f} px, bias {errors.mean(axis=0)}")
        assert rms(errors) < 0.15  # px; measured ~0.06 (the detector's own refinement)
        assert np.abs(errors).max() < 0.4


# --------------------------------------------------------------------------------------------
# Photometry


def _square_interiors(view: RenderedView, colour: str) -> list[tuple[slice, slice]]:
    """Pixel windows well inside the squares between inner corners, of one colour."""
    corners = view.corners_px.reshape(BOARD.rows, BOARD.cols, 2)
    windows = []
    for row in range(BOARD.rows - 1):
        for col in range(BOARD.cols - 1):
            # Square (i, j) of the print is black when i + j is even; the one right-below inner
            # corner (row, col) is square (row + 1, col + 1).
            black = (row + col) % 2 == 0
            if black != (colour == "black"):
                continue
            (x0, y0), (x1, y1) = corners[row, col], corners[row + 1, col + 1]
            windows.append((slice(int(y0) + 12, int(y1) - 11), slice(int(x0) + 12, int(x1) - 11)))
    return windows


def test_image_statistics_are_plausible(renderer):
    """Issue 2 (c): print levels under the lab light, noise std, an unsaturated background."""
    optics = renderer.optics
    T = board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm)
    view = renderer.render_view("left", T, np.random.default_rng(5))
    image = view.image.astype(np.float64)
    gain = renderer._rasters["left"].gain * 256.0  # vignetting
    for colour, level in (("white", optics.white_dn), ("black", optics.black_dn)):
        windows = _square_interiors(view, colour)
        assert len(windows) >= 10
        means = np.array([image[w].mean() for w in windows])
        expected = np.array([level * gain[w].mean() for w in windows])
        assert np.abs(means - expected).max() < 0.6, colour  # DN; 2 DN noise over ~2000 px
        # Noise: std in a flat window, minus the (sub-0.1 DN) vignetting trend; rounding adds 1/12 DN^2.
        stds = np.array([np.std(image[w] - level * gain[w]) for w in windows])
        expected_std = np.sqrt(optics.noise_sigma_dn**2 + 1 / 12)
        print(f"{colour}: mean {means.mean():.2f} DN (expected {expected.mean():.2f}), noise std {stds.mean():.3f} DN")
        assert abs(stds.mean() - expected_std) < 0.08 * expected_std
    # The wall: mid-grey, gently lit, never clipped.
    wall = image[:, :200]
    assert 60 < wall.mean() < 170 and wall.min() > 20 and wall.max() < 235
    assert 1.0 < np.std(cv2.GaussianBlur(wall, (0, 0), 4)) < 25  # visible but low-contrast structure


def test_shot_noise_grows_with_signal():
    optics = Optics(shot_noise_gain=0.5, vignetting=0.0)
    r = StereoRenderer(BOARD, optics=optics)
    T = board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm)
    view = r.render_view("left", T, np.random.default_rng(6))
    image = view.image.astype(np.float64)
    for colour, level in (("white", optics.white_dn), ("black", optics.black_dn)):
        variance = np.mean([image[w].var() for w in _square_interiors(view, colour)])
        expected = optics.noise_sigma_dn**2 + optics.shot_noise_gain * level + 1 / 12
        assert abs(variance - expected) < 0.1 * expected, colour


def test_background_holds_nothing_a_board_detector_finds(renderer):
    T_behind = make_transform(np.eye(3), [-100.0, -70.0, -400.0])  # behind the camera
    view = renderer.render_view("left", T_behind, np.random.default_rng(7))
    assert not view.visible.any()
    small = cv2.resize(view.image, (480, 270), interpolation=cv2.INTER_AREA)
    found, _ = cv2.findChessboardCorners(small, BOARD.pattern_size, flags=cv2.CALIB_CB_FAST_CHECK)
    assert not found
    gx = cv2.Sobel(view.image, cv2.CV_64F, 1, 0, ksize=3)
    assert np.percentile(np.abs(gx), 99.9) < 40  # no edges: only noise and gentle shading


def test_rendering_is_reproducible(renderer):
    T = board_pose_facing_rig(distance_mm=600.0, board_size_mm=BOARD.grid_size_mm, yaw_deg=10)
    a = renderer.render_view("left", T, np.random.default_rng(8)).image
    b = renderer.render_view("left", T, np.random.default_rng(8)).image
    c = renderer.render_view("left", T, np.random.default_rng(9)).image
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c) and np.abs(a.astype(int) - c.astype(int)).mean() < 3


# --------------------------------------------------------------------------------------------
# Visibility


def test_visible_agrees_with_geometry_for_a_toed_in_rig(renderer):
    """Issue 2 (d): alpha = 55, B = 100, Z = 500: 30 of 54 corners in both views."""
    rig = RigPose.symmetric(100.0, 55.0)
    T_rig_board = board_pose_facing_rig(distance_mm=500.0, board_size_mm=BOARD.grid_size_mm)
    pair = renderer.render_pair(rig, T_rig_board, np.random.default_rng(10))
    assert isinstance(pair, RenderedPair)
    both = pair.left.visible & pair.right.visible
    expected = visible_in_both(transform_points(T_rig_board, BOARD.object_points), rig=rig, left=renderer.left,
                               right=renderer.right, margin_px=0.0)
    assert np.array_equal(both, expected)
    assert both.sum() == 30
    R, T = rig.stereo_extrinsics()
    np.testing.assert_allclose(pair.R, R)
    np.testing.assert_allclose(pair.T, T)
    np.testing.assert_allclose(pair.left.T_cam_board, invert_transform(rig.T_rig_left) @ T_rig_board)
    # The visible corners really are in the picture: dark/light structure around each of them.
    for view in (pair.left, pair.right):
        for u, v in view.corners_px[view.visible & (view.corners_px[:, 0] > 20) & (view.corners_px[:, 0] < 1900)]:
            patch = view.image[int(v) - 8 : int(v) + 9, int(u) - 8 : int(u) + 9]
            assert patch.max() - patch.min() > 120


def test_board_seen_from_behind_shows_its_plain_back(renderer):
    T = board_pose_facing_rig(distance_mm=450.0, board_size_mm=BOARD.grid_size_mm, yaw_deg=180.0)
    view = renderer.render_view("left", T, np.random.default_rng(11))
    assert not view.visible.any()
    centre = view.corners_px.mean(axis=0).astype(int)
    patch = view.image[centre[1] - 60 : centre[1] + 60, centre[0] - 60 : centre[0] + 60].astype(float)
    assert abs(patch.mean() - renderer.optics.back_dn) < 3 and patch.std() < 3


def test_nothing_behind_the_camera_is_drawn(renderer):
    """A board reaching behind the camera: only rays that meet it in front of the camera see it."""
    camera = renderer.left
    # Board plane at 80 deg to the image plane, its grid centre 150 mm ahead and 60 mm to the right.
    T = board_pose_facing_rig(distance_mm=150.0, board_size_mm=BOARD.grid_size_mm, centre_offset_mm=(60.0, 0.0),
                              yaw_deg=-80.0)
    depths = transform_points(T, np.array([[-200.0, 0.0, 0.0], [400.0, 0.0, 0.0]]))[:, 2]
    assert depths.min() < 0 < depths.max()  # the print straddles the camera plane
    board_view = renderer.render_view("left", T, np.random.default_rng(12)).image.astype(int)
    empty = renderer.render_view("left", make_transform(np.eye(3), [0, 0, -500.0]), np.random.default_rng(12))
    empty_view = empty.image.astype(int)
    # Which pixels' rays meet the print in front of the camera (analytic, every 8th pixel).
    w, h = camera.image_size
    grid = np.stack(np.meshgrid(np.arange(4, w, 8.0), np.arange(4, h, 8.0)), axis=-1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(grid, camera.K, camera.dist,
                               criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)).reshape(-1, 2)
    rays = np.column_stack([rays, np.ones(len(rays))])
    n, t = T[:3, 2], T[:3, 3]
    lam = (n @ t) / (rays @ n)
    on_board = transform_points(invert_transform(T), lam[:, None] * rays)
    texture = BOARD.texture()
    x0, y0 = texture.origin_mm
    x1 = x0 + texture.image.shape[1] * texture.mm_per_px
    y1 = y0 + texture.image.shape[0] * texture.mm_per_px
    hit = (lam > 0) & (on_board[:, 0] > x0 - 5) & (on_board[:, 0] < x1 + 5) & (on_board[:, 1] > y0 - 5) & (
        on_board[:, 1] < y1 + 5)
    px = grid.reshape(-1, 2).astype(int)
    missed = ~hit
    assert missed.sum() > 1000 and hit.sum() > 1000
    # Where no ray meets the board, the frame is the bare background, pixel for pixel (same noise seed).
    diff = np.abs(board_view[px[missed, 1], px[missed, 0]] - empty_view[px[missed, 1], px[missed, 0]])
    assert np.percentile(diff, 99) <= 1 and diff.mean() < 0.05
    # Where rays do meet it, the board is drawn.
    drawn = np.abs(board_view[px[hit, 1], px[hit, 0]] - empty_view[px[hit, 1], px[hit, 0]])
    assert np.mean(drawn > 10) > 0.8


# --------------------------------------------------------------------------------------------
# Calibration views


def test_calibration_poses_recover_the_cameras(renderer):
    """Issue 2 (e): 20 rendered views calibrate fx to 0.1 %, the distortion, and abs(T) to 0.1 %."""
    rig = RigPose.symmetric(100.0, 90.0)
    rng = np.random.default_rng(13)
    poses = calibration_board_poses(rig, BOARD, n_views=20, rng=rng)
    assert len(poses) == 20
    object_points, left_points, right_points = [], [], []
    tilts = []
    for T_rig_board in poses:
        pair = renderer.render_pair(rig, T_rig_board, rng)
        assert pair.left.visible.all() and pair.right.visible.all()
        detections = [detect_chessboard(v.image, BOARD.pattern_size) for v in (pair.left, pair.right)]
        assert all(d is not None for d in detections)
        object_points.append(BOARD.object_points)
        left_points.append(in_truth_order(detections[0], pair.left.corners_px).astype(np.float32))
        right_points.append(in_truth_order(detections[1], pair.right.corners_px).astype(np.float32))
        tilts.append(np.degrees(np.arccos(abs(T_rig_board[2, 2]))))
    assert max(tilts) > 30  # operators tilt the board
    # The views cover the common field of view: corners reach near every border of both images
    # (a parallel rig shares only x > f B / Z of the left image with the right one: 190 px at 700 mm).
    for points in (left_points, right_points):
        everything = np.vstack(points)
        lo, hi = everything.min(axis=0), everything.max(axis=0)
        print(f"coverage x {lo[0]:.0f}-{hi[0]:.0f}, y {lo[1]:.0f}-{hi[1]:.0f} px")
        assert hi[0] - lo[0] > 1300 and lo[1] < 200 and hi[1] > 880

    size = renderer.left.image_size
    flags = cv2.CALIB_FIX_K3
    mono = []
    for points, camera in ((left_points, renderer.left), (right_points, renderer.right)):
        err, K, dist, _, _ = cv2.calibrateCamera(object_points, points, size, None, None, flags=flags)
        print(f"mono: rms {err:.4f} px, fx {K[0, 0]:.3f} (true {camera.fx:.3f}), dist {dist.ravel()}")
        assert abs(K[0, 0] / camera.fx - 1) < 1e-3 and abs(K[1, 1] / camera.K[1, 1] - 1) < 1e-3
        assert np.abs(K[:2, 2] - camera.K[:2, 2]).max() < 3.0  # px
        # Distortion "recovered well": the two models move pixels alike over the whole frame.
        assert _distortion_difference_px(camera, K, dist) < 0.25
        mono.append((K, dist))
    err, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
        object_points, left_points, right_points, mono[0][0], mono[0][1], mono[1][0], mono[1][1], size,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3,
    )
    R_true, T_true = rig.stereo_extrinsics()
    print(f"stereo: rms {err:.4f} px, |T| {np.linalg.norm(T):.4f} mm (true {np.linalg.norm(T_true):.4f})")
    assert abs(np.linalg.norm(T) / np.linalg.norm(T_true) - 1) < 1e-3
    angle = np.degrees(np.linalg.norm(cv2.Rodrigues(R @ R_true.T)[0]))
    assert angle < 0.05


def _distortion_difference_px(truth: CameraModel, K: np.ndarray, dist: np.ndarray) -> float:
    """Max over the frame of the difference between the true and estimated distortion displacements."""
    w, h = truth.image_size
    grid = np.stack(np.meshgrid(np.linspace(0, w - 1, 25), np.linspace(0, h - 1, 15)), axis=-1).reshape(-1, 2)
    rays = np.column_stack([(grid - truth.K[:2, 2]) / np.diag(truth.K)[:2], np.ones(len(grid))])
    true_px, _ = truth.project(rays)
    # Same rays through the estimated model, compared as displacements from each model's pinhole image.
    est_px, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    est_pinhole = rays[:, :2] * np.diag(K)[:2] + K[:2, 2]
    true_pinhole = grid
    return float(np.abs((est_px.reshape(-1, 2) - est_pinhole) - (true_px - true_pinhole)).max())


def test_calibration_poses_refuse_a_rig_that_cannot_see_the_board():
    rig = RigPose.symmetric(100.0, 45.0)  # axes cross 50 mm in front of the rig
    with pytest.raises(ValueError, match="overlap too little"):
        calibration_board_poses(rig, BOARD, n_views=3, rng=np.random.default_rng(14), max_attempts=20)


@pytest.mark.parametrize("seed", range(6))
def test_the_batched_bisection_finds_what_one_midpoint_at_a_time_finds(seed):
    """The view placer asks the view rule for several bisection levels at once; whatever the rule answers (a
    threshold, or answers that are not monotone at all), it must land where the plain bisection lands."""
    rng = np.random.default_rng(seed)
    threshold = rng.uniform(-0.2, 1.7)
    noise = {}

    def rule(x: float) -> bool:
        if seed % 2:  # not monotone: a fixed random answer per point, as a rule may be near a corner case
            return noise.setdefault(x, bool(rng.uniform() < 0.6)) if x != 0.0 else True
        return x <= threshold

    def plain(steps: int) -> float | None:
        if not rule(0.0):
            return None
        good, bad = 0.0, 1.5
        for _ in range(steps):
            mid = 0.5 * (good + bad)
            good, bad = (mid, bad) if rule(mid) else (good, mid)
        return good

    calls = []

    def batched(xs: np.ndarray) -> np.ndarray:
        calls.append(len(xs))
        return np.array([rule(float(x)) for x in xs])

    for steps in (1, 5, 12):
        for levels in (1, 3, 4):
            calls.clear()
            assert _bisect_largest(batched, 0.0, 1.5, steps=steps, levels_per_call=levels) == plain(steps)
            if plain(steps) is not None:
                assert len(calls) == -(-steps // levels)


def test_optics_are_validated():
    with pytest.raises(ValueError, match="supersample"):
        Optics(supersample=0)
    with pytest.raises(ValueError, match="vignetting"):
        Optics(vignetting=1.5)


def test_partial_calibration_views_keep_the_requested_fraction():
    rig = RigPose.symmetric(100.0, 70.0)
    left = right = CameraModel.from_sensor()
    poses = calibration_board_poses(rig, BOARD, n_views=6, rng=np.random.default_rng(15), distance_mm=(250.0, 400.0),
                                    min_fraction_visible=0.5, margin_px=10.0)
    for T_rig_board in poses:
        both = visible_in_both(transform_points(T_rig_board, BOARD.object_points), rig=rig, left=left, right=right,
                               margin_px=10.0)
        assert both.mean() >= 0.5


def test_single_sample_mode_renders_a_detectable_board():
    """supersample = 1 (one sample per pixel, Gaussian stand-in for the pixel box) still renders truthfully."""
    r = StereoRenderer(BOARD, optics=Optics(supersample=1))
    T = board_pose_facing_rig(distance_mm=600.0, board_size_mm=BOARD.grid_size_mm, yaw_deg=15.0, pitch_deg=10.0)
    view = r.render_view("right", T, np.random.default_rng(16))
    detected = detect_chessboard(view.image, BOARD.pattern_size)
    assert detected is not None
    errors = in_truth_order(detected, view.corners_px) - view.corners_px
    assert rms(errors) < 0.1
