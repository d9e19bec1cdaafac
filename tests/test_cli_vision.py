"""`stereo-bench calibrate` and `measure` as a user runs them: JSON keys, text, one-line errors."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from stereo_bench.cli import main
from tests.real_data import OPENCV_SAMPLE


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def calib_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("calib")
    code = main(["calibrate", "--board", "9x6", "--square", "30", "--left", str(OPENCV_SAMPLE / "left*.jpg"),
                 "--right", str(OPENCV_SAMPLE / "right*.jpg"), "--out", str(out), "--force"])
    assert code == 0
    return out


def test_calibrate_json(capsys, tmp_path):
    code, out, _ = run(capsys, "calibrate", "--board", "9x6", "--square", "30",
                       "--left", str(OPENCV_SAMPLE / "left*.jpg"), "--right", str(OPENCV_SAMPLE / "right*.jpg"),
                       "--out", str(tmp_path / "c"), "--json")
    assert code == 0
    report = json.loads(out)
    for key in ("rms_px", "views_used", "views_rejected", "baseline_mm", "epipolar_rms_px", "left", "right"):
        assert key in report
    for side in ("left", "right"):
        assert set(report[side]) >= {"fx", "fy", "cx", "cy"}
    # Pair 7 (left08/right08) dropped by the held-out check (test_real_data.py), with its reason.
    assert report["views_used"] == 12 and [v["index"] for v in report["views_rejected"]] == [7]
    assert "held out" in report["views_rejected"][0]["reason"]
    assert report["baseline_mm"] == pytest.approx(99.81, rel=0.005)
    assert (tmp_path / "c" / "intrinsics.yml").is_file() and (tmp_path / "c" / "extrinsics.yml").is_file()


def test_calibrate_fits_on_one_blas_thread_and_restores_the_threads(capsys, tmp_path, monkeypatch):
    """`calibrate` runs its calibration with every BLAS library (numpy's OpenBLAS, OpenCV's) on one thread, where a
    threaded OpenBLAS spins on a loaded machine (docs/CALIBRATION.md, Speed), and gives the threads back after."""
    from threadpoolctl import threadpool_info

    import stereo_bench.vision.pipeline as pipeline

    def blas_threads() -> list[int]:
        return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]

    before, during = blas_threads(), []
    real = pipeline.calibrate_from_images

    def spy(*args, **kwargs):
        during.extend(blas_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(pipeline, "calibrate_from_images", spy)
    code, _, _ = run(capsys, "calibrate", "--board", "9x6", "--square", "30", "--lens-model", "opencv4",
                     "--left", str(OPENCV_SAMPLE / "left*.jpg"), "--right", str(OPENCV_SAMPLE / "right*.jpg"),
                     "--out", str(tmp_path / "c"), "--json")
    assert code == 0
    assert during and set(during) == {1}
    assert blas_threads() == before


def test_calibrate_refuses_to_overwrite(capsys, calib_dir):
    code, _, err = run(capsys, "calibrate", "--board", "9x6", "--square", "30",
                       "--left", str(OPENCV_SAMPLE / "left*.jpg"), "--right", str(OPENCV_SAMPLE / "right*.jpg"),
                       "--out", str(calib_dir))
    assert code == 2 and "exists" in err and len(err.strip().splitlines()) == 1


def test_calibrate_with_fixed_intrinsics_from_a_directory(capsys, calib_dir, tmp_path):
    code, out, _ = run(capsys, "calibrate", "--board", "9x6", "--square", "30", "--intrinsics", str(calib_dir),
                       "--left", str(OPENCV_SAMPLE / "left*.jpg"), "--right", str(OPENCV_SAMPLE / "right*.jpg"),
                       "--out", str(tmp_path / "fixed"), "--json")
    report = json.loads(out)
    assert code == 0 and report["mode"] == "fixed"
    assert report["baseline_mm"] == pytest.approx(99.81, rel=0.005)


def test_calibrate_with_unequal_counts_is_a_clear_error(capsys, tmp_path):
    code, _, err = run(capsys, "calibrate", "--board", "9x6", "--square", "30",
                       "--left", str(OPENCV_SAMPLE / "left0*.jpg"), "--right", str(OPENCV_SAMPLE / "right*.jpg"),
                       "--out", str(tmp_path / "c"))
    assert code == 2
    assert "--left matches 9 files but --right matches 13" in err
    assert len(err.strip().splitlines()) == 1


def test_measure_json_and_text(capsys, calib_dir):
    left, right = OPENCV_SAMPLE / "left03.jpg", OPENCV_SAMPLE / "right03.jpg"
    code, out, _ = run(capsys, "measure", "--calib", str(calib_dir), "--board", "9x6", "--square", "30",
                       str(left), str(right), "--json")
    assert code == 0
    report = json.loads(out)
    assert set(report["square_mm"]) >= {"mean", "std", "n", "sigma_mean"}
    assert report["nominal_mm"] == 30.0
    assert report["error_mm"] == pytest.approx(report["square_mm"]["mean"] - 30.0)
    assert report["square_mm"]["n"] == 8 * 6 + 9 * 5  # every adjacent pair of a 9x6 grid
    assert abs(report["error_mm"]) < 0.15
    assert 200 < report["depth_mm"] < 600 and report["epipolar_rms_px"] < 0.5
    code, out, _ = run(capsys, "measure", "--calib", str(calib_dir), "--board", "9x6", "--square", "30",
                       str(left), str(right))
    assert code == 0 and "square:" in out and "nominal 30" in out


def test_measure_errors_are_one_line_with_exit_2(capsys, calib_dir, tmp_path):
    left, right = OPENCV_SAMPLE / "left03.jpg", OPENCV_SAMPLE / "right03.jpg"
    no_board = tmp_path / "blank.png"
    import cv2
    import numpy as np
    cv2.imwrite(str(no_board), np.full((480, 640), 128, np.uint8))
    not_image = tmp_path / "notes.png"
    not_image.write_text("hello")
    broken = tmp_path / "broken"
    shutil.copytree(calib_dir, broken)
    text = (broken / "intrinsics.yml").read_text().replace("\nD2:", "\nD9:")
    (broken / "intrinsics.yml").write_text(text)
    cases = [
        (["--calib", str(calib_dir), str(left), str(no_board)], "not found in the right image"),
        (["--calib", str(calib_dir), str(not_image), str(right)], "cannot read image"),
        (["--calib", str(broken), str(left), str(right)], "missing key 'D2'"),
        (["--calib", str(calib_dir), str(left), str(tmp_path / "absent.png")], "image not found"),
    ]
    for extra, message in cases:
        code, out, err = run(capsys, "measure", "--board", "9x6", "--square", "30", *extra)
        assert code == 2, (extra, err)
        assert message in err and len(err.strip().splitlines()) == 1


def test_measure_reports_the_uncertainty_budget(capsys, calib_dir):
    left, right = OPENCV_SAMPLE / "left03.jpg", OPENCV_SAMPLE / "right03.jpg"
    args = ("measure", "--calib", str(calib_dir), "--board", "9x6", "--square", "30", str(left), str(right))
    code, out, _ = run(capsys, *args, "--json")
    assert code == 0
    report = json.loads(out)
    u = report["uncertainty_mm"]
    # "adequacy": the calibration's held-out check of its own board (issue 22), present when it was computed.
    assert list(u) == ["noise", "calibration", "structure", "target", "adequacy", "combined", "expanded", "k"]
    assert u["structure"] is None and report["uncertainty"]["unknown"] == ["structure"]  # not zero: unknown
    # k: Student's t at the Welch-Satterthwaite degrees of freedom (the adequacy component's are 12: 13 views).
    from stereo_bench.vision.uncertainty import coverage_factor
    assert u["k"] == pytest.approx(coverage_factor(report["uncertainty"]["effective_dof"])) and 2 < u["k"] < 2.3
    assert u["expanded"] == pytest.approx(u["k"] * u["combined"])
    assert u["calibration"] > 0 and u["noise"] >= report["uncertainty"]["noise_random_mm"] > 0
    assert u["combined"] == pytest.approx(float(np.sqrt(u["noise"] ** 2 + u["calibration"] ** 2 + u["target"] ** 2
                                                        + u["adequacy"] ** 2)))
    # Two boards, 1e-4 each (calibrate records its board's; measure's default): 30 mm x sqrt(2) x 1e-4.
    assert u["target"] == pytest.approx(30 * np.sqrt(2) * 1e-4)
    code, out, _ = run(capsys, *args, "--json", "--same-board")
    assert json.loads(out)["uncertainty_mm"]["target"] == 0.0
    code, out, _ = run(capsys, *args, "--json", "--board-scale-u", "1e-3")
    assert json.loads(out)["uncertainty_mm"]["target"] == pytest.approx(30 * np.hypot(1e-3, 1e-4))
    code, out, _ = run(capsys, *args)
    assert code == 0 and f"+- {u['expanded']:.4f} mm (k={u['k']:.3g})" in out and "structure unknown" in out
    code, _, err = run(capsys, *args, "--board-scale-u=-1")
    assert code == 2 and "--board-scale-u: must be" in err and len(err.strip().splitlines()) == 1


def test_measure_with_a_calibration_without_covariance_says_unknown(capsys, calib_dir, tmp_path):
    old = tmp_path / "old"
    shutil.copytree(calib_dir, old)
    for name in ("intrinsics.yml", "extrinsics.yml"):  # as an older stereo-bench or OpenCV's sample wrote them
        text = (old / name).read_text()
        (old / name).write_text(text[:text.index("covariance_parameters:")])
    code, out, _ = run(capsys, "measure", "--calib", str(old), "--board", "9x6", "--square", "30",
                       str(OPENCV_SAMPLE / "left03.jpg"), str(OPENCV_SAMPLE / "right03.jpg"), "--json")
    report = json.loads(out)
    assert code == 0 and report["uncertainty_mm"]["calibration"] is None
    assert report["uncertainty"]["unknown"] == ["calibration", "structure"]
    assert "no covariance" in report["uncertainty"]["calibration_note"]


def test_calibrate_reports_parameter_sigmas(capsys, tmp_path):
    argv = ("calibrate", "--board", "9x6", "--square", "30", "--left", str(OPENCV_SAMPLE / "left*.jpg"),
            "--right", str(OPENCV_SAMPLE / "right*.jpg"))
    code, out, _ = run(capsys, *argv, "--out", str(tmp_path / "c"), "--json")
    assert code == 0
    u = json.loads(out)["uncertainty"]
    for side in ("left", "right"):
        assert set(u[side]) >= {"fx", "fy", "cx", "cy", "k1", "k2"}
        assert 0.05 < u[side]["fx"] < 2.0  # px: 12 views of a 9x6 board at 640x480
    assert 0.005 < u["baseline_mm"] < 0.5 and len(u["T_mm"]) == 3 and len(u["rvec_deg"]) == 3
    assert 0 < u["rotation_deg"] < 0.5 and 0.05 < u["sigma_px"] < 0.5
    code, out, _ = run(capsys, *argv, "--out", str(tmp_path / "t"))
    assert code == 0 and "baseline |T| = 99.8" in out and f"+- {u['baseline_mm']:.3f} mm" in out
    assert "fx 533." in out and f"+- {u['left']['fx']:.2f}" in out


def test_measure_takes_the_board_and_square_from_the_calibration(capsys, calib_dir):
    # Issue 22: without --square, measure assumed 27 mm on a 30 mm calibration ("error -3 mm", exit 0).
    left, right = OPENCV_SAMPLE / "left03.jpg", OPENCV_SAMPLE / "right03.jpg"
    code, out, _ = run(capsys, "measure", "--calib", str(calib_dir), str(left), str(right), "--json")
    assert code == 0
    report = json.loads(out)
    assert report["nominal_mm"] == 30 and abs(report["error_mm"]) < 0.3
    assert report["board"]["pattern"] == "9x6" and report["board"]["square_from"].endswith("(recorded)")
    code, out, _ = run(capsys, "measure", "--calib", str(calib_dir), "--square", "27", str(left), str(right),
                       "--json")
    assert code == 0 and json.loads(out)["nominal_mm"] == 27  # told otherwise
    code, out, _ = run(capsys, "measure", "--calib", str(calib_dir), str(left), str(right))
    assert code == 0 and "0.0000" not in out and " 0.000 px" not in out


def test_measure_asks_for_the_square_of_a_board_the_calibration_does_not_record(capsys, calib_dir, tmp_path):
    """--board of another board without --square used to measure against 27 mm in silence (+2.97 mm on the 30 mm
    board given as 8x6); the recorded board with its sides the other way round is the same board; --same-board
    with another square contradicts the calibration; a missing --calib is named as that."""
    left, right = OPENCV_SAMPLE / "left03.jpg", OPENCV_SAMPLE / "right03.jpg"
    code, out, _ = run(capsys, "measure", "--calib", str(calib_dir), "--board", "6x9", str(left), str(right), "--json")
    assert code == 0 and json.loads(out)["nominal_mm"] == 30
    code, _, err = run(capsys, "measure", "--calib", str(calib_dir), "--board", "8x6", str(left), str(right))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"--square: {calib_dir} records the squares of a 9x6 board (30 mm), not of the --board 8x6" in err
    code, _, err = run(capsys, "measure", "--calib", str(calib_dir), "--square", "25", "--same-board", str(left),
                       str(right))
    assert code == 2 and "--same-board: " in err and "30 mm squares, not the 9x6 of 25 mm" in err
    code, out, _ = run(capsys, "measure", "--calib", str(calib_dir), "--square", "30", "--same-board", str(left),
                       str(right), "--json")
    assert code == 0 and json.loads(out)["nominal_mm"] == 30
    code, _, err = run(capsys, "measure", "--calib", str(tmp_path / "nowhere"), str(left), str(right))
    assert code == 2 and "nowhere: calibration directory not found" in err and "--board" not in err


def test_fixed_or_significant_never_prints_zero_for_a_nonzero_value():
    from stereo_bench.cli.vision import fixed_or_significant

    assert fixed_or_significant(3.9e-05, 4) == "3.9e-05"
    assert fixed_or_significant(0.1234, 4) == "0.1234"
    assert fixed_or_significant(0.0, 4) == "0.0000"
    assert fixed_or_significant(-2.1e-06, 3) == "-2.1e-06"


def test_an_inverted_charuco_board_is_calibrated_with_inverted_and_named_without(capsys, tmp_path):
    """caliscope's board is printed white on black: without --inverted no image shows a board, and the line says
    what to give; with it the boards are found (the calibration then runs to its gates)."""
    import cv2

    from tests.real_data import CALISCOPE_BOARD, caliscope_frames, caliscope_views

    frames, _ = caliscope_views()
    left, right = caliscope_frames()
    for k in frames[::2][:12]:
        cv2.imwrite(str(tmp_path / f"l{k:03d}.png"), left[k])
        cv2.imwrite(str(tmp_path / f"r{k:03d}.png"), right[k])
    argv = ["calibrate", "--charuco", "--board", "4x5", "--square", "54", "--marker", "40.5", "--dictionary",
            "DICT_4X4_1000", "--left", str(tmp_path / "l*.png"), "--right", str(tmp_path / "r*.png")]
    code, _, err = run(capsys, *argv, "--out", str(tmp_path / "a"))
    assert code == 2 and "in none of the images: a ChArUco board printed white on black needs --inverted" in err
    code, out, err = run(capsys, *argv, "--inverted", "--accept-poor", "--out", str(tmp_path / "b"), "--json")
    assert code == 0, err
    assert json.loads(out)["views_used"] >= 8 and CALISCOPE_BOARD.inverted
    # measure reads the board back, its colours, marker and dictionary included, and measures a frame not in the
    # calibration.
    held = frames[1]
    cv2.imwrite(str(tmp_path / "hl.png"), left[held])
    cv2.imwrite(str(tmp_path / "hr.png"), right[held])
    code, out, err = run(capsys, "measure", "--calib", str(tmp_path / "b"), str(tmp_path / "hl.png"),
                         str(tmp_path / "hr.png"), "--json")
    assert code == 0, err
    assert json.loads(out)["nominal_mm"] == 54 and json.loads(out)["board"]["board_from"].endswith("(recorded)")
    code, _, err = run(capsys, "calibrate", "--board", "9x6", "--square", "30", "--inverted", "--left",
                       str(OPENCV_SAMPLE / "left*.jpg"), "--right", str(OPENCV_SAMPLE / "right*.jpg"), "--out",
                       str(tmp_path / "c"))
    assert code == 2 and "--inverted is for a ChArUco board" in err


def test_images_of_two_sizes_are_named_with_their_sizes(capsys, tmp_path):
    import cv2

    for name in ("left01", "left02", "right01", "right02"):
        image = cv2.imread(str(OPENCV_SAMPLE / f"{name}.jpg"))
        cv2.imwrite(str(tmp_path / f"{name}.png"), cv2.resize(image, (960, 720)) if name == "left02" else image)
    code, _, err = run(capsys, "calibrate", "--board", "9x6", "--square", "30", "--left", str(tmp_path / "left*.png"),
                       "--right", str(tmp_path / "right*.png"), "--out", str(tmp_path / "c"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{tmp_path / 'left01.png'} is 640x480, but {tmp_path / 'left02.png'} is 960x720" in err
