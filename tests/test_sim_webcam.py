"""The lab bench's cameras as noisy as real webcams (issue 22): corner noise, rolling shutter, capture skew.

Every draw is seeded. Tolerances are stated beside the asserts.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.bench import board_at_exposure, camera_optics
from drivers.sim.profile import IDEAL, LAB, CameraErrors, SimProfile, SimSettings
from drivers.sim.render import Optics, StereoRenderer
from stereo_bench.geometry import CameraModel, board_pose_facing_rig
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.detect import detect

BOARD = Checkerboard(9, 6, 27.0)
CAMERA = CameraModel.from_sensor(name="left")


def _view(distance_mm: float = 500.0, yaw_deg: float = 15.0, pitch_deg: float = -10.0) -> np.ndarray:
    return board_pose_facing_rig(distance_mm=distance_mm, board_size_mm=BOARD.grid_size_mm, yaw_deg=yaw_deg,
                                 pitch_deg=pitch_deg)


def _errors(renderer: StereoRenderer, seeds, **kwargs) -> np.ndarray:
    """(n, 2) detected minus true corner positions over views rendered with ``seeds``."""
    out = []
    for seed in seeds:
        view = renderer.render_view("left", _view(), np.random.default_rng(seed), **kwargs)
        found = detect(view.image, BOARD, noise=False)
        assert found is not None and found.n == len(BOARD.object_points)
        out.append(found.corners_px - view.corners_px[found.ids])
    return np.concatenate(out)


def test_the_ideal_profile_leaves_the_optics_and_every_draw_alone():
    """No imperfection: camera_optics returns the optics itself and the renderer draws nothing more from the
    frame's generator (the ideal bench's frames stay bit-identical)."""
    optics = Optics()
    assert camera_optics(optics, IDEAL.cameras) is optics
    renderer = StereoRenderer(BOARD, CAMERA, CAMERA, optics=optics)
    rng, reference = np.random.default_rng(4), np.random.default_rng(4)
    moving = renderer.render_view("left", _view(), rng, velocity_px_s=(200.0, 0.0))  # no line time: no shear
    reference.integers(0, 2**31 - 1)  # the sensor noise's one draw
    assert rng.bit_generator.state == reference.bit_generator.state
    still = renderer.render_view("left", _view(), np.random.default_rng(4))
    np.testing.assert_array_equal(moving.image, still.image)


def test_the_lab_optics_add_defocus_and_noise_in_quadrature():
    optics = camera_optics(Optics(), LAB.cameras)
    assert optics.blur_sigma_px == pytest.approx(np.hypot(0.7, LAB.cameras.defocus_sigma_px))
    assert optics.noise_sigma_dn == pytest.approx(np.hypot(2.0, LAB.cameras.extra_read_noise_dn))
    assert optics.shot_noise_gain == LAB.cameras.shot_noise_gain
    assert optics.jitter_px == LAB.cameras.corner_noise_px
    assert optics.line_time_s == pytest.approx(LAB.cameras.line_time_us * 1e-6)


def test_corner_noise_scatters_the_detected_corners_by_about_its_figure():
    """Without the jitter the detector finds the corners within ~0.03 px; with 0.2 px at the field's nodes the
    detected corners scatter about their true projections by 0.10-0.25 px per coordinate (bilinear between
    independent nodes: 0.5-1 of the node std; the detector's window averages a little more), with no bias
    (|mean| < 0.03 px over 4 views, 216 corners)."""
    quiet = _errors(StereoRenderer(BOARD, CAMERA, CAMERA, optics=Optics()), range(4))
    noisy = _errors(StereoRenderer(BOARD, CAMERA, CAMERA, optics=Optics(jitter_px=0.2)), range(4))
    rms_quiet, rms_noisy = np.sqrt(np.mean(quiet**2)), np.sqrt(np.mean(noisy**2))
    assert rms_quiet < 0.05, rms_quiet
    assert 0.10 < rms_noisy < 0.25, rms_noisy
    assert np.all(np.abs(noisy.mean(axis=0)) < 0.03), noisy.mean(axis=0)


def test_a_rolling_shutter_shears_a_moving_image_by_row_time_times_velocity():
    """Image moving at 2000 px/s along x, 29 us a row: each row's content stands 0.058 px further along x per
    row below the middle one. Detected corners against the truth: slope of the x error over the row within
    10 % of that, no y error (< 0.02 px)."""
    line_time = 29e-6
    renderer = StereoRenderer(BOARD, CAMERA, CAMERA, optics=Optics(line_time_s=line_time))
    view = renderer.render_view("left", _view(), np.random.default_rng(0), velocity_px_s=(2000.0, 0.0))
    found = detect(view.image, BOARD, noise=False)
    truth = view.corners_px[found.ids]
    error = found.corners_px - truth
    rows = truth[:, 1] - (CAMERA.image_size[1] - 1) / 2.0
    slope, offset = np.polyfit(rows, error[:, 0], 1)
    assert slope == pytest.approx(2000.0 * line_time, rel=0.1)
    assert abs(np.mean(error[:, 1])) < 0.02


def test_a_synchronised_pair_sees_the_board_where_the_scene_has_it():
    T = _view()
    for profile in (IDEAL, LAB):
        for side in ("left", "right"):
            pose, skew = board_at_exposure(profile, T, seed=3, index=2, side=side)
            assert pose is T and skew is None


def _unsynchronised(speed: float = 50.0) -> SimProfile:
    return SimSettings.model_validate({"profile": "lab", "cameras": {"synchronised": False},
                                       "calibration_board": {"hand_held_speed_mm_s": speed}}).resolve()


def test_an_unsynchronised_pair_sees_a_hand_held_board_move_between_its_exposures():
    """The right frame is exposed a skew ~ N(0, capture_skew_sigma_ms) after the left one (std within 10 % over
    2000 pairs), the same draw for both frames of a pair and for the same (seed, index) again; the board has
    moved by speed x skew in the right frame, the left frame sees the scene's pose; the measured target stands."""
    profile = _unsynchronised()
    T = _view()
    skews = []
    for index in range(2000):
        left, skew_left = board_at_exposure(profile, T, seed=9, index=index, side="left")
        right, skew = board_at_exposure(profile, T, seed=9, index=index, side="right")
        assert skew == skew_left and np.array_equal(left, T)
        assert np.linalg.norm(right[:3, 3] - T[:3, 3]) == pytest.approx(50.0 * abs(skew), rel=1e-9)
        assert np.array_equal(right[:3, :3], T[:3, :3])
        skews.append(skew)
    assert np.std(skews) * 1e3 == pytest.approx(LAB.cameras.capture_skew_sigma_ms, rel=0.1)
    again, _ = board_at_exposure(profile, T, seed=9, index=5, side="right")
    assert np.array_equal(again, board_at_exposure(profile, T, seed=9, index=5, side="right")[0])
    other_seed, _ = board_at_exposure(profile, T, seed=10, index=5, side="right")
    assert not np.array_equal(again, other_seed)
    standing, skew = board_at_exposure(profile, T, seed=9, index=5, side="right", measured_target=True)
    assert standing is T and skew is None


def test_the_unsynchronised_option_is_a_named_value_and_the_target_never_moves():
    assert LAB.cameras.synchronised and IDEAL.cameras.synchronised
    assert CameraErrors().synchronised and CameraErrors().capture_skew_sigma_ms == 0.0
    with pytest.raises(ValueError, match="cameras.synchronised"):
        SimSettings.model_validate({"profile": "lab", "cameras": {"synchronised": "no"}})
    with pytest.raises(ValueError, match="calibration board only"):
        SimSettings.model_validate({"profile": "lab", "target": {"hand_held_speed_mm_s": 10.0}})
