"""Lens models (stereo_bench.vision.lensmodels): every model's coefficient vector through the whole chain (fit,
covariance, calibration files, rectify, triangulate, the uncertainty's parameter perturbation), and the held-out
choice on images rendered with each kind of distortion (seeded; the rule's own threshold CHOICE_Z decides)."""

from __future__ import annotations

import json
from functools import cache

import cv2
import numpy as np
import pytest

from drivers.sim.render import StereoRenderer, calibration_board_poses
from stereo_bench.cli import main
from stereo_bench.geometry import CameraModel, RigPose
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibio import read_calibration, recorded_lens_choice, write_calibration
from stereo_bench.vision.calibrate import calibrate_stereo_lens
from stereo_bench.vision.lensmodels import MODELS, choose, lens_model
from stereo_bench.vision.pipeline import calibrate_from_images
from stereo_bench.vision.rectify import epipolar_errors_px, rectification_maps, rectify
from stereo_bench.vision.triangulate import triangulate
from stereo_bench.vision.uncertainty import perturbed
from tests.real_data import OPENCV_SAMPLE

BOARD = Checkerboard(9, 6, 20.0)
RIG = RigPose.symmetric(80.0, 90.0)
# The distortion each model names, on a 640x480 camera (pixel 6 um: f = 667 px; 12 um: f = 333 px, ~100 deg
# diagonal, where k3 and the rational denominator are visible).
LENSES = {
    "opencv4": (6.0, (-0.12, 0.05, 0.0008, -0.0006, 0.0), 1.0),
    "anamorphic": (6.0, (-0.12, 0.05, 0.0, 0.0, 0.0), 0.5),  # fx = fy / 2 (a squeezed side-by-side webcam)
    "opencv5": (12.0, (-0.28, 0.09, 0.0, 0.0, -0.015), 1.0),
    "rational": (12.0, (0.2, 0.01, 0.0, 0.0, 0.0, 0.55, 0.05, 0.0), 1.0),
    "thin-prism": (6.0, (-0.1, 0.04, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.004, 0.0, -0.003, 0.0), 1.0),
}
# The model auto must choose for each lens: the true one, or (square pixels) fixed-aspect, which is the true
# model when fx = fy (the renderer's cameras have square pixels unless squeezed).
EXPECTED = {
    "opencv4": {"fixed-aspect", "opencv4"},
    "anamorphic": {"opencv4"},
    "opencv5": {"opencv5"},
    "rational": {"rational"},
    "thin-prism": {"thin-prism"},
}


def _camera(lens: str, name: str) -> CameraModel:
    pixel_um, dist, aspect = LENSES[lens]
    camera = CameraModel.from_sensor(image_size=(640, 480), pixel_um=pixel_um, dist=dist, name=name)
    K = camera.K.copy()
    K[0, 0] *= aspect
    return CameraModel(K=K, dist=camera.dist, image_size=camera.image_size, name=name)


@cache
def rendered(lens: str, n_views: int = 16, seed: int = 1) -> tuple[list, list]:
    left, right = _camera(lens, "left"), _camera(lens, "right")
    rng = np.random.default_rng(seed)
    poses = calibration_board_poses(RIG, BOARD, n_views=n_views, rng=rng, left=left, right=right,
                                    distance_mm=(250.0, 500.0))
    renderer = StereoRenderer(BOARD, left, right)
    pairs = [renderer.render_pair(RIG, pose, rng) for pose in poses]
    return [p.left.image for p in pairs], [p.right.image for p in pairs]


@cache
def projected(lens: str, n_views: int = 14, seed: int = 2):
    """Exact projections of the board through ``lens`` plus 0.05 px of noise: the solver's work without rendering."""
    left, right = _camera(lens, "left"), _camera(lens, "right")
    rng = np.random.default_rng(seed)
    poses = calibration_board_poses(RIG, BOARD, n_views=n_views, rng=rng, left=left, right=right,
                                    distance_mm=(250.0, 500.0))
    objects, lefts, rights = [], [], []
    for T_rig_board in poses:
        sides = []
        for camera, T_rig_cam in ((left, RIG.T_rig_left), (right, RIG.T_rig_right)):
            T_cam_board = np.linalg.inv(T_rig_cam) @ T_rig_board
            px, _ = cv2.projectPoints(BOARD.object_points.astype(np.float64), cv2.Rodrigues(T_cam_board[:3, :3])[0],
                                      T_cam_board[:3, 3], camera.K, camera.dist)
            sides.append(px.reshape(-1, 2) + rng.normal(0, 0.05, (len(BOARD.object_points), 2)))
        objects.append(BOARD.object_points)
        lefts.append(sides[0])
        rights.append(sides[1])
    return objects, lefts, rights, left.image_size


def test_models_are_named_and_unknown_names_refused():
    assert set(MODELS) == {"fixed-aspect", "opencv4", "opencv5", "thin-prism", "rational"}
    with pytest.raises(ValueError, match="unknown lens model 'fisheye'"):
        lens_model("fisheye")
    with pytest.raises(ValueError, match="unknown lens model"):
        calibrate_stereo_lens(*projected("opencv4")[:3], (640, 480), lens_model="fisheye")


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_model_goes_through_files_rectification_triangulation_and_perturbation(name, tmp_path):
    objects, lefts, rights, size = projected("thin-prism")
    calib = calibrate_stereo_lens(objects, lefts, rights, size, lens_model=name)
    expected_length = {"rational": 8, "thin-prism": 12}.get(name, 5)
    assert calib.lens_model == name
    assert calib.D1.shape == calib.D2.shape == (1, expected_length)
    if MODELS[name].square_pixels:
        assert calib.K1[0, 0] == pytest.approx(calib.K1[1, 1], rel=1e-12)
    assert calib.covariance is not None, calib.covariance_note
    # Round trip: the coefficients, the model's name and its record.
    write_calibration(tmp_path, calib, rectify(calib))
    loaded = read_calibration(tmp_path)
    np.testing.assert_allclose(loaded.D1, calib.D1, rtol=1e-12, atol=0)
    np.testing.assert_allclose(loaded.D2, calib.D2, rtol=1e-12, atol=0)
    assert loaded.lens_model == name
    assert recorded_lens_choice(tmp_path)["chosen"] == name
    assert loaded.covariance.names == calib.covariance.names
    # Downstream: rectification and maps, undistortion, triangulation of a view's corners near the board's size.
    rect = rectify(loaded)
    rectification_maps(loaded, rect)
    assert np.sqrt(np.mean(epipolar_errors_px(loaded, rect, lefts[0], rights[0]) ** 2)) < 0.2
    points = triangulate(loaded, lefts[0], rights[0])
    assert np.linalg.norm(points[1] - points[0]) == pytest.approx(BOARD.square_mm, abs=0.05)
    # Every covariance parameter (the model's coefficients included) can be perturbed.
    for parameter in loaded.covariance.names:
        moved = perturbed(loaded, parameter, 1e-6)
        assert moved.D1.shape == loaded.D1.shape
    coefficients = {n.split(".", 1)[1] for n in loaded.covariance.names if n.startswith("left.")}
    assert {"k1", "k2", "p1", "p2"} <= coefficients
    assert ("k3" in coefficients) == (name in ("opencv5", "rational"))
    assert ("k6" in coefficients) == (name == "rational")
    assert ("s1" in coefficients) == (name == "thin-prism")


def test_old_files_without_lens_keys_load(tmp_path):
    objects, lefts, rights, size = projected("opencv4")
    calib = calibrate_stereo_lens(objects, lefts, rights, size, lens_model="opencv4")
    from dataclasses import replace

    write_calibration(tmp_path, replace(calib, lens_model="", lens_choice=None))
    assert "lens_model" not in (tmp_path / "extrinsics.yml").read_text()
    assert read_calibration(tmp_path).lens_model == ""
    assert recorded_lens_choice(tmp_path) is None


def test_auto_records_the_comparison_in_the_files(tmp_path):
    objects, lefts, rights, size = projected("opencv5")
    calib = calibrate_stereo_lens(objects, lefts, rights, size, lens_model="auto")
    choice = calib.lens_choice
    assert choice.requested == "auto" and calib.lens_model == choice.chosen
    assert [h.model for h in choice.comparison] == ["fixed-aspect", "opencv4", "opencv5", "thin-prism", "rational"]
    write_calibration(tmp_path, calib)
    recorded = recorded_lens_choice(tmp_path)
    assert recorded["chosen"] == choice.chosen and recorded["requested"] == "auto"
    assert [row["model"] for row in recorded["comparison"]] == [h.model for h in choice.comparison]
    for row, held in zip(recorded["comparison"], choice.comparison, strict=True):
        assert row["held_out_rms_px"] == pytest.approx(held.reprojection_rms_px, nan_ok=True)
        assert row["held_out_square_rms_mm"] == pytest.approx(held.square_rms_mm, nan_ok=True)


def test_auto_without_comparison_keeps_the_default_fit_bit_for_bit():
    """calibrate_from_images(lens_model=None) is the fit of before lens models (simulated campaigns' numbers)."""
    lefts, rights = rendered("opencv4")
    before = calibrate_from_images(lefts, rights, BOARD)
    named = calibrate_from_images(lefts, rights, BOARD, lens_model="opencv4")
    assert before.calib.lens_choice is None
    np.testing.assert_array_equal(before.calib.K1, named.calib.K1)
    np.testing.assert_array_equal(before.calib.T, named.calib.T)


@pytest.mark.parametrize("lens", sorted(LENSES))
def test_auto_chooses_the_rendered_lens_model(lens):
    lefts, rights = rendered(lens)
    result = calibrate_from_images(lefts, rights, BOARD, lens_model="auto")
    choice = result.calib.lens_choice
    assert choice.chosen in EXPECTED[lens], f"{lens}: chose {choice.chosen} ({choice.reason})\n{choice.table()}"
    held = {h.model: h for h in choice.comparison}
    # The chosen model measures the held-out squares to within 0.2 % of the board's 20 mm, and within 1.5x of the
    # best model's held-out square error.
    best = min(h.square_rms_mm for h in choice.comparison if np.isfinite(h.square_rms_mm))
    assert held[choice.chosen].square_rms_mm < 0.04, choice.table()
    assert held[choice.chosen].square_rms_mm <= 1.5 * best, choice.table()
    assert choose(list(choice.comparison)) == (choice.chosen, choice.reason)


def test_calibrate_cli_lists_the_models_and_shows_the_choice(capsys, tmp_path):
    assert main(["calibrate", "--help"]) == 0
    help_text = " ".join(capsys.readouterr().out.split())
    for name in ("auto", *MODELS):
        assert name in help_text
    args = ["calibrate", "--board", "9x6", "--square", "30", "--left", str(OPENCV_SAMPLE / "left*.jpg"),
            "--right", str(OPENCV_SAMPLE / "right*.jpg")]
    assert main([*args, "--out", str(tmp_path / "auto"), "--json"]) == 0
    lens = json.loads(capsys.readouterr().out)["lens_model"]
    assert lens["requested"] == "auto" and lens["chosen"] in MODELS
    assert {row["model"] for row in lens["comparison"]} == set(MODELS)
    assert read_calibration(tmp_path / "auto").lens_model == lens["chosen"]
    assert main([*args, "--out", str(tmp_path / "named"), "--lens-model", "opencv5"]) == 0
    text = capsys.readouterr().out
    assert "lens model opencv5" in text
    assert read_calibration(tmp_path / "named").D1.shape == (1, 5)
    assert main([*args, "--out", str(tmp_path / "text")]) == 0
    text = capsys.readouterr().out
    assert "held-out" in text and all(name in text for name in MODELS)
