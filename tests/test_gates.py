"""Calibration quality gates (issue 22 item 3): silent on every real set, each fires on its own fault built from
real images, with a line that names the cause; the detector finds every board plain OpenCV finds."""

from __future__ import annotations

import importlib.util
import json
from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereo_bench.cli import main
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.calibio import read_gates, write_calibration
from stereo_bench.vision.calibrate import calibrate_stereo_lens
from stereo_bench.vision.detect import common_corners, detect
from stereo_bench.vision.gates import (
    GATE_NAMES,
    CalibrationRefused,
    GateView,
    PoseCache,
    board_may_be_larger,
    run_gates,
    stereo_view_rms_px,
    view_residuals,
)
from stereo_bench.vision.pipeline import calibrate_from_images
from tests.real_data import OPENCV_SAMPLE, PRESENT_CJN, REAL

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


faults = _script("gates_real")
compare = _script("compare_detect_opencv")

SMILER = REAL / "smiler488_box"  # copied into calib_data by the issue 22 "budget" work; skipped until then
SETS = {
    "opencv_sample": (OPENCV_SAMPLE, "left*.jpg", "right*.jpg", Checkerboard(9, 6, 30.0)),
    "present_cjn": (PRESENT_CJN, "leftPic*.jpg", "rightPic*.jpg", Checkerboard(8, 11, 12.0)),
    "smiler488_box": (SMILER, "L_*.png", "R_*.png", Checkerboard(8, 5, 15.0)),
}


@cache
def load(name: str):
    folder, left_glob, right_glob, board = SETS[name]
    left = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(folder.glob(left_glob))]
    right = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(folder.glob(right_glob))]
    if not left:
        pytest.skip(f"{folder} is not in calib_data yet")
    return left, right, board


def refused(left, right, board, **kwargs) -> CalibrationRefused:
    with pytest.raises(CalibrationRefused) as caught:
        calibrate_from_images(left, right, board, **kwargs)
    return caught.value


@pytest.mark.parametrize("name", list(SETS))
def test_real_sets_pass_every_gate(name):
    left, right, board = load(name)
    report = calibrate_from_images(left, right, board).gates
    assert [r.name for r in report.results] == list(GATE_NAMES)
    verdicts = {r.name: r.verdict for r in report.results}
    assert set(verdicts.values()) == {"pass"}, [r.line for r in report.results]
    values = {r.name: r.value for r in report.results}
    # Margins seen on the three sets (docs/CALIBRATION.md): none of them within 2x of its threshold.
    assert values["synchronised"] < 0.5 * report.results[1].threshold
    assert values["flatness"] < 0.5 * report.results[4].threshold


@pytest.mark.parametrize("name", ["opencv_sample", "present_cjn"])
def test_pairs_not_taken_together_are_named(name):
    left, right, board = load(name)
    n = len(left)
    shifted = list(right)
    moved = (1, n // 2, n - 2)
    for i in moved:
        shifted[i] = right[i + 1]  # the board moved between the left and the right shot of these pairs
    error = refused(left, shifted, board)
    assert [r.name for r in error.report.failed] == ["synchronised"]
    assert set(error.report.failed[0].views) == set(moved)
    assert "not taken at the same moment" in str(error) and f"pair {moved[0]}" in str(error)


def test_a_board_that_does_not_fit_its_own_camera_is_named_as_that_not_as_two_moments():
    """A wrong detection in one image (here one row on: its ids a row off and its last row on the background past the
    board's edge, as SB once found a cut board, tests/test_detect_other_cameras.py) gives a huge stereo residual, as
    two moments do; but its own image alone does not fit the camera either, which no pair taken at two moments
    shows: the line says which image, and why."""
    from dataclasses import replace

    from stereo_bench.vision.detect import detect

    left, right, board = load("smiler488_box")
    detections = [(detect(a, board, thorough=True, noise=False), detect(b, board, thorough=True, noise=False))
                  for a, b in zip(left, right, strict=True)]
    bad = 12
    found = detections[bad][1].corners_px.reshape(board.rows, board.cols, 2)
    grid = np.concatenate([found[1:], found[-1:] + 0.6 * (found[-1:] - found[-2:-1])])  # a row on, off the board
    detections[bad] = (detections[bad][0], replace(detections[bad][1], corners_px=grid.reshape(-1, 2)))
    error = refused(left, right, board, detections=detections)
    assert [r.name for r in error.report.failed] == ["synchronised"] and error.report.failed[0].views == (bad,)
    assert f"pair {bad}'s right image alone fits only to " in str(error), str(error)
    assert "not taken at the same moment" not in str(error)
    assert "wrong detection" in error.report.view_diagnoses[bad]


@pytest.mark.parametrize("moved", [(), (1, 14, 27)])
def test_gates_on_the_fits_own_poses_equal_gates_solving_every_pose(moved):
    """The gates take each view's poses from the calibration's fits (PoseCache.of_fit) instead of solving them
    again: the same residuals to 1e-6, the same verdicts and lines, also for views the stereo fit dropped (pairs
    not taken together: their poses are solved, as before)."""
    left, right, board = load("present_cjn")
    right = list(right)
    for i in moved:
        right[i] = right[i + 1]
    objects, lefts, rights = [], [], []
    for image_left, image_right in zip(left, right, strict=True):
        found = detect(image_left, board, thorough=True, noise=False), detect(image_right, board, thorough=True,
                                                                              noise=False)
        if None not in found:
            ids, left_px, right_px = common_corners(*found)
            objects.append(board.object_points[ids])
            lefts.append(left_px)
            rights.append(right_px)
    calib = calibrate_stereo_lens(objects, lefts, rights, left[0].shape[::-1], lens_model="opencv4")
    assert len(calib.board_poses) == len(calib.views_used)
    assert len(calib.views_used) == len(objects) - len(moved)  # the stereo fit drops the pairs not taken together
    views = [GateView(k, objects[k], lefts[k], rights[k]) for k in range(len(objects))]
    fitted = PoseCache.of_fit(calib, views)
    assert sum(fitted.joint(k) is not None for k in range(len(views))) == len(calib.views_used)
    for view in views:
        a, b = view_residuals(calib, view, fitted), view_residuals(calib, view, PoseCache())
        assert np.allclose([a.mono_left_px, a.mono_right_px, a.stereo_px],
                           [b.mono_left_px, b.mono_right_px, b.stereo_px], rtol=1e-6, atol=0), view.index
        if fitted.joint(view.index) is not None:  # the fit's pose of this very view: its residual without a step
            at_fit = stereo_view_rms_px(calib, view.object_points, view.left_px, view.right_px,
                                        (fitted.joint(view.index),), iterations=0)
            assert at_fit == pytest.approx(b.stereo_px, rel=1e-6), view.index
    dropped = [(r.index, r.reason) for r in calib.views_rejected]
    ours = run_gates(calib, views, board, dropped=dropped, poses=PoseCache.of_fit(calib, views))
    solved = run_gates(calib, views, board, dropped=dropped)
    assert [(r.name, r.verdict, r.line, r.views) for r in ours.results] == \
        [(r.name, r.verdict, r.line, r.views) for r in solved.results]
    assert np.allclose([r.value for r in ours.results], [r.value for r in solved.results], rtol=1e-6, equal_nan=True)
    assert ours.results[0].verdict == ("fail" if moved else "pass")


def test_every_pair_not_taken_together_is_refused_for_its_cause_not_a_symptom():
    left, right, board = load("opencv_sample")
    error = refused(left[:-1], right[1:], board)  # today: "principal point ... outside the image"
    assert error.report.failed[0].name == "synchronised"
    assert "principal point" not in str(error)
    with pytest.raises(ValueError, match="principal point.*because: left and right images not taken"):
        calibrate_from_images(left[:-1], right[1:], board, accept_poor=True)


def test_left_and_right_swapped():
    left, right, board = load("opencv_sample")
    error = refused(right, left, board)
    assert [r.name for r in error.report.failed] == ["left_right"]
    assert "swapped" in str(error)


@pytest.mark.parametrize("kind", ["defocus", "motion"])
def test_blurred_views(kind):
    left, right, board = load("smiler488_box" if SMILER.is_dir() else "opencv_sample")
    blur = ((lambda x: cv2.GaussianBlur(x, (0, 0), faults.BLUR_SIGMA_PX)) if kind == "defocus" else faults.motion_blur)
    error = refused([blur(x) for x in left], [blur(x) for x in right], board)
    assert [r.name for r in error.report.failed] == ["sharpness"]
    assert ("motion blur" if kind == "motion" else "out of focus") in str(error)


def test_board_size_that_does_not_fit():
    left, right, _ = load("opencv_sample")
    # Six pairs are enough (the gate runs before the fit): each missed image costs the whole thorough search.
    error = refused(left[:6], right[:6], Checkerboard(8, 5, 30.0))
    assert [r.name for r in error.report.failed] == ["board_fit"]
    assert "use --board 9x6" in str(error)


def test_board_larger_than_named():
    left, right, _ = load("present_cjn")
    error = refused(left[:4], right[:4], Checkerboard(7, 10, 12.0))
    assert "use --board 8x11" in str(error)


@pytest.mark.parametrize("name", list(SETS))
def test_board_size_search_skips_only_boards_whose_pattern_ends(name):
    """The board-size search's pre-check (gates.board_may_be_larger) on every found board of the real sets: the
    whole board never reads as larger where its pattern visibly ends (present_cjn, smiler488_box: every side of
    every image ends; opencv_sample's dark surround keeps some sides unjudged, which is searched), and every grid
    one row or column short of it (a board named smaller than it is) reads as possibly larger."""
    left, right, board = load(name)
    whole, shorter = [], []
    for image in left + right:
        found = detect(image, board, thorough=True, noise=False)
        if found is None:
            continue
        grid = found.corners_px.reshape(board.rows, board.cols, 2)
        whole.append(board_may_be_larger(image, grid))
        shorter += [board_may_be_larger(image, sub) for sub in (grid[:-1], grid[1:], grid[:, :-1], grid[:, 1:])]
    assert len(whole) >= 0.9 * len(left + right)
    assert all(shorter)
    if name != "opencv_sample":
        assert not any(whole)


def test_bent_board():
    left, right, board = load("opencv_sample")
    bow = faults.BEND_OF_WIDTH * board.grid_size_mm[0]
    error = refused(left, right, board, detections=faults.bent_detections(left, right, board, bow))
    assert [r.name for r in error.report.failed] == ["flatness"]
    assert "not flat" in str(error)


def test_accept_poor_keeps_the_calibration_and_records_the_gates(tmp_path):
    left, right, board = load("opencv_sample")
    result = calibrate_from_images(right, left, board, accept_poor=True)
    assert [r.name for r in result.gates.failed] == ["left_right"] and not result.gates.refused
    write_calibration(tmp_path, result.calib, result.rect, extra=result.gates.file_items())
    gates = read_gates(tmp_path)
    assert list(gates) == list(GATE_NAMES)
    assert gates["left_right"]["verdict"] == "fail" and gates["synchronised"]["verdict"] == "pass"
    assert gates["synchronised"]["value"] == pytest.approx(result.gates.results[1].value)


def test_files_without_gates_still_load(tmp_path):
    left, right, board = load("opencv_sample")
    result = calibrate_from_images(left, right, board, gates=False)
    assert result.gates is None
    write_calibration(tmp_path, result.calib, result.rect)
    assert read_gates(tmp_path) is None
    assert read_gates(REAL / "opencv_stereo_calib_format") is None  # OpenCV's own sample layout


def test_cli_refuses_with_exit_2_and_accept_poor_writes(capsys, tmp_path):
    for i, name in enumerate(("left03.jpg", "left04.jpg", "left05.jpg", "left06.jpg", "left07.jpg", "left08.jpg",
                              "left09.jpg")):
        (tmp_path / f"l{i}.jpg").write_bytes((OPENCV_SAMPLE / name).read_bytes())
        swapped = "right" + name[4:]
        (tmp_path / f"r{i}.jpg").write_bytes((OPENCV_SAMPLE / swapped).read_bytes())
    args = ["calibrate", "--board", "9x6", "--square", "30", "--left", str(tmp_path / "r*.jpg"),
            "--right", str(tmp_path / "l*.jpg"), "--out", str(tmp_path / "c")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "left and right swapped" in err[0] and "--accept-poor" in err[0]
    assert not (tmp_path / "c" / "extrinsics.yml").exists()
    assert main(args + ["--accept-poor", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["gates"]["gates"]["left_right"]["verdict"] == "fail"
    assert read_gates(tmp_path / "c")["left_right"]["verdict"] == "fail"


@pytest.mark.parametrize("name", list(SETS))
def test_detector_finds_every_board_opencv_finds(name):
    folder, left_glob, right_glob, board = SETS[name]
    paths = sorted(folder.glob(left_glob)) + sorted(folder.glob(right_glob))
    if not paths:
        pytest.skip(f"{folder} is not in calib_data yet")
    ours = theirs = 0
    for path in paths:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        found = detect(gray, board, thorough=True, noise=False) is not None
        opencv = compare.opencv_classic(gray, board) is not None or compare.opencv_sb(gray, board) is not None
        assert found or not opencv, f"{path.name}: plain OpenCV finds the board, stereo-bench does not"
        ours, theirs = ours + found, theirs + opencv
    assert ours >= theirs


def test_detector_finds_hand_held_prints_in_1280x720_frames():
    """The views of present_cjn that, held as a print in a 1280x720 room, the detector missed before and
    plain OpenCV (findChessboardCornersSB) found: the SB search with CALIB_CB_NORMALIZE_IMAGE was the cause."""
    board = SETS["present_cjn"][3]
    for name in ("leftPic17.jpg", "rightPic01.jpg", "rightPic09.jpg", "rightPic11.jpg"):
        frame = compare.webcam_views(cv2.imread(str(PRESENT_CJN / name), cv2.IMREAD_GRAYSCALE))
        assert frame.shape == (720, 1280)
        assert compare.opencv_sb(frame, board) is not None
        found = detect(frame, board, thorough=True, noise=False)
        assert found is not None, name
        sb = compare.opencv_sb(frame, board)
        assert compare.agreement_px(found.corners_px, sb) < 0.5 and np.isfinite(found.corners_px).all()
