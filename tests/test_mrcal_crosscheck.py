"""``calibrate --cross-check mrcal``: mrcal fits the same corners (issue 26 item 2; docs/FORMATS.md).

Skipped, saying why, where no Python imports mrcal (Debian's python3-mrcal, installed by .ci/run; or
STEREO_BENCH_MRCAL_PYTHON).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.sim.render import calibration_board_poses
from stereo_bench.vision.calibrate import calibrate_stereo
from stereo_bench.vision.mrcal_bridge import MRCAL_PYTHON_ENV, cross_check, mrcal_python, unavailable_reason
from tests.real_data import SMILER488_BOX
from tests.synthetic_rig import CALIBRATION_BOARD, CAMERA, Configuration, project_pair
from tests.test_cli_vision import run

needs_mrcal = pytest.mark.skipif(mrcal_python() is None, reason=unavailable_reason())


@needs_mrcal
def test_both_fits_find_the_true_baseline_of_a_synthetic_rig():
    """Exact projections of a known rig plus 0.2 px of seeded noise: both |T| within 3 of their own sigmas of the
    truth (B = 120 mm), and of each other; the same model on the same corners gives the same RMS."""
    rng = np.random.default_rng(26)
    config = Configuration(120.0, 600.0, 90.0)
    poses = calibration_board_poses(config.rig, CALIBRATION_BOARD, n_views=14, rng=rng, distance_mm=(400.0, 800.0))
    points = np.asarray(CALIBRATION_BOARD.object_points, float)
    views = [project_pair(config.rig, pose, points, rng, 0.2) for pose in poses]
    calib = calibrate_stereo([points] * len(views), [v[0] for v in views], [v[1] for v in views], CAMERA.image_size)
    corners = tuple((points, views[i][0], views[i][1]) for i in calib.views_used)
    check = cross_check(calib, corners, CALIBRATION_BOARD.object_points, CALIBRATION_BOARD.square_mm)
    b = check["baseline_mm"]
    assert abs(b["ours"] - 120.0) <= 3 * b["ours_sigma"]
    assert abs(b["mrcal"] - 120.0) <= 3 * b["mrcal_sigma"]
    assert b["mrcal_sigma"] < 0.1  # 0.2 px noise on 14 views: the baseline is known to ~0.02 mm
    assert b["ours_sigma_residuals"] == pytest.approx(b["mrcal_sigma"], rel=0.05)
    assert check["agree"] and abs(b["z"]) <= 2
    assert check["rms_px"]["mrcal"] == pytest.approx(check["rms_px"]["ours"], rel=0.01)
    assert check["rms_px"]["mrcal"] == pytest.approx(0.2 * np.sqrt(2), rel=0.1)  # 2-D RMS of 0.2 px per coordinate
    for camera in check["projection"]:
        assert camera["diff_median_px"] < camera["uncertainty_median_px"]


@needs_mrcal
def test_calibrate_cross_check_on_a_real_set(capsys, tmp_path):
    """smiler488_box with the model both fit alike (OPENCV4): the same |T| and RMS to the solvers' tolerance."""
    code, out, _ = run(capsys, "calibrate", "--board", "8x5", "--square", "15",
                       "--left", str(SMILER488_BOX / "L_*.png"), "--right", str(SMILER488_BOX / "R_*.png"),
                       "--out", str(tmp_path / "c"), "--lens-model", "opencv4", "--cross-check", "mrcal", "--json")
    assert code == 0
    check = json.loads(out)["cross_check"]
    b, r = check["baseline_mm"], check["rms_px"]
    assert b["ours"] == pytest.approx(59.98, abs=0.01)
    assert abs(b["difference"]) < 0.01 and check["agree"]
    # Our covariance from the residuals alone is mrcal's formulation: the same sigma of |T| (ours as stated is the
    # views' jackknife, larger on real views: docs/UNCERTAINTY.md).
    assert b["ours_sigma_residuals"] == pytest.approx(b["mrcal_sigma"], rel=0.05)
    assert b["ours_sigma_source"] == "views" and b["ours_sigma"] > b["ours_sigma_residuals"]
    assert r["mrcal"] == pytest.approx(r["ours"], rel=0.005) and r["mrcal_outliers"] == 0
    assert all(camera["diff_median_px"] < 0.1 for camera in check["projection"])
    # mrcal's own default, a board-warp term, explains its lower published RMS (SOURCE.md: 0.127 px, 59.60 mm).
    warp = check["mrcal_with_board_warp"]
    assert warp["rms_px"] < r["mrcal"] and warp["baseline_mm"] == pytest.approx(59.60, abs=0.1)
    code, out, _ = run(capsys, "calibrate", "--board", "8x5", "--square", "15",
                       "--left", str(SMILER488_BOX / "L_*.png"), "--right", str(SMILER488_BOX / "R_*.png"),
                       "--out", str(tmp_path / "t"), "--lens-model", "opencv4", "--cross-check", "mrcal")
    assert code == 0 and "cross-check with mrcal" in out and "(agree)" in out


def test_without_mrcal_the_cross_check_is_refused_before_anything_is_fitted(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv(MRCAL_PYTHON_ENV, str(tmp_path / "no-such-python"))
    assert mrcal_python() is None
    code, _, err = run(capsys, "calibrate", "--board", "8x5", "--square", "15",
                       "--left", str(SMILER488_BOX / "L_*.png"), "--right", str(SMILER488_BOX / "R_*.png"),
                       "--out", str(tmp_path / "c"), "--cross-check", "mrcal")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "--cross-check mrcal: mrcal is not importable by" in err and MRCAL_PYTHON_ENV in err
    assert not (tmp_path / "c").exists()


@needs_mrcal
def test_the_environment_variable_names_the_python(monkeypatch):
    python = mrcal_python()
    monkeypatch.setenv(MRCAL_PYTHON_ENV, python)
    assert mrcal_python() == python
