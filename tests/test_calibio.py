"""Calibration files: OpenCV stereo_calib layout, round trip, and clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from stereo_bench.vision.calibio import CalibrationFileError, read_calibration, read_intrinsics, write_calibration
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.rectify import rectify
from tests.real_data import OPENCV_FORMAT


def sample_calibration() -> StereoCalibration:
    K = np.array([[1333.3, 0, 959.5], [0, 1333.3, 539.5], [0, 0, 1]])
    angle = np.radians(5.0)
    R = np.array([[np.cos(angle), 0, -np.sin(angle)], [0, 1, 0], [np.sin(angle), 0, np.cos(angle)]])
    return StereoCalibration(
        K1=K, D1=np.array([[-0.05, 0.02, 0, 0, 0]]), K2=K * [[1.001], [1.0], [1]],
        D2=np.array([[-0.04, 0.01, 0, 0, 0]]),
        R=R, T=np.array([-99.6, 0.1, 8.7]), image_size=(1920, 1080), rms_px=0.0412, mode="joint",
    )


def test_round_trip_keeps_every_matrix_and_the_extra_keys(tmp_path):
    calib = sample_calibration()
    rect = rectify(calib)
    write_calibration(tmp_path, calib, rect, board="checkerboard 9x6 square 27 mm")
    loaded = read_calibration(tmp_path)
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        np.testing.assert_allclose(getattr(loaded, name), getattr(calib, name), rtol=1e-12, err_msg=name)
    assert loaded.image_size == (1920, 1080)
    assert loaded.rms_px == pytest.approx(0.0412)
    assert loaded.mode == "joint"
    text = (tmp_path / "extrinsics.yml").read_text()
    for key in ("R:", "T:", "R1:", "R2:", "P1:", "P2:", "Q:", "board:", "date:", "image_width:"):
        assert key in text
    assert set(k.split(":")[0] for k in (tmp_path / "intrinsics.yml").read_text().splitlines()
               if k and not k.startswith((" ", "%", "-"))) >= {"M1", "D1", "M2", "D2"}
    assert not list(tmp_path.glob(".*")), "temporary files left behind"


def test_files_written_by_opencvs_own_sample_load():
    calib = read_calibration(OPENCV_FORMAT, image_size=(640, 480))
    assert calib.D1.shape == (1, 8)  # rational model
    assert calib.baseline_mm == pytest.approx(3.33, abs=0.05)  # in squares: the sample uses squareSize = 1
    np.testing.assert_allclose(calib.R @ calib.R.T, np.eye(3), atol=1e-9)
    K1, D1, K2, D2, size = read_intrinsics(OPENCV_FORMAT / "intrinsics.yml")
    assert size is None and K1[2, 2] == 1.0


def test_sample_files_without_image_size_need_it_from_the_caller():
    with pytest.raises(CalibrationFileError, match="image size"):
        read_calibration(OPENCV_FORMAT)


def test_missing_key_names_the_file_and_the_key(tmp_path):
    write_calibration(tmp_path, sample_calibration())
    text = (tmp_path / "extrinsics.yml").read_text().replace("\nT:", "\nT_renamed:")
    (tmp_path / "extrinsics.yml").write_text(text)
    with pytest.raises(CalibrationFileError, match=r"extrinsics.yml: missing key 'T'"):
        read_calibration(tmp_path)


def test_missing_and_corrupt_files(tmp_path):
    with pytest.raises(CalibrationFileError, match="not found"):
        read_calibration(tmp_path / "nowhere")
    (tmp_path / "intrinsics.yml").write_text("this: [is not: an opencv file\n")
    with pytest.raises(CalibrationFileError, match="intrinsics.yml"):
        read_calibration(tmp_path)
