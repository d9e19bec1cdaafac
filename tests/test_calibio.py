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


def test_covariance_round_trip_in_both_files(tmp_path):
    from stereo_bench.vision.calibio import read_intrinsics_covariance
    from stereo_bench.vision.covariance import EXTRINSIC_NAMES, CalibrationCovariance

    names = ("left.fx", "left.fy", "left.cx", "left.cy", "right.fx", "right.fy", "right.cx", "right.cy")
    names += EXTRINSIC_NAMES
    rng = np.random.default_rng(1)
    root = rng.normal(size=(len(names), len(names))) * 0.1
    covariance = CalibrationCovariance(names, root @ root.T, sigma_px=0.07, dof=1234, pixel_locking_px=(0.02, -0.001))
    calib = sample_calibration()
    calib = StereoCalibration(**{**calib.__dict__, "covariance": covariance})
    write_calibration(tmp_path, calib)
    loaded = read_calibration(tmp_path).covariance
    assert loaded.names == names and loaded.dof == 1234 and loaded.sigma_px == pytest.approx(0.07)
    assert loaded.pixel_locking_px == pytest.approx((0.02, -0.001))
    np.testing.assert_allclose(loaded.matrix, covariance.matrix, rtol=1e-12)
    intrinsic = read_intrinsics_covariance(tmp_path)
    assert intrinsic.names == names[:8]
    np.testing.assert_allclose(intrinsic.matrix, covariance.matrix[:8, :8], rtol=1e-12)


def test_a_file_without_covariance_loads_with_the_uncertainty_unknown(tmp_path):
    from stereo_bench.vision.calibio import read_intrinsics_covariance

    calib = read_calibration(OPENCV_FORMAT, image_size=(640, 480))  # OpenCV's own sample: no covariance keys
    assert calib.covariance is None and "unknown" in calib.covariance_note
    assert read_intrinsics_covariance(OPENCV_FORMAT) is None
    # Written without one, the reason travels with the files.
    write_calibration(tmp_path, StereoCalibration(**{**sample_calibration().__dict__,
                                                     "covariance_note": "intrinsics given without covariance"}))
    assert read_calibration(tmp_path).covariance_note == "intrinsics given without covariance"


def test_a_covariance_of_the_wrong_size_names_the_file_and_key(tmp_path):
    from stereo_bench.vision.covariance import EXTRINSIC_NAMES, CalibrationCovariance

    calib = StereoCalibration(**{**sample_calibration().__dict__, "covariance": CalibrationCovariance(
        EXTRINSIC_NAMES, np.eye(6), sigma_px=0.1)})
    write_calibration(tmp_path, calib)
    text = (tmp_path / "extrinsics.yml").read_text().replace("rvec.x rvec.y ", "")
    (tmp_path / "extrinsics.yml").write_text(text)
    with pytest.raises(CalibrationFileError, match="extrinsics.yml: key 'covariance' has shape"):
        read_calibration(tmp_path)
