"""The rig and target terms of a prediction (stereo_bench.errormodel.rig): the campaign budget's terms, at a planned
configuration, and `model predict` / `advise` taking them by default."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from stereo_bench.campaign.config import RigTolerances
from stereo_bench.cli import main
from stereo_bench.errormodel.rig import RigErrors, structure_covariance
from stereo_bench.errormodel.rigorous import (
    CalibrationPlan,
    Setup,
    calibration_of,
    predict,
    project_both,
    visible_corners,
)
from stereo_bench.kinematics import nominal_covariance
from stereo_bench.vision.measure import measure_square
from stereo_bench.vision.uncertainty import FrameCorners, configuration_budget

LAB = RigTolerances().sigmas()


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _frame(setup: Setup) -> FrameCorners:
    ids, _ = visible_corners(setup)
    left_px, right_px, _ = project_both(setup, setup.corners_rig[ids])
    return FrameCorners(ids, left_px, right_px, 0.0, (0.1, 0.1))


def test_nominal_structure_term_is_the_campaign_budgets():
    """The same covariance through the same sensitivities the campaign's budget uses: equal to rounding."""
    setup = Setup.make(110.0, 550.0, 81.0)
    prediction = predict(setup, 0.1, rig=RigErrors(mode="nominal", tolerances=LAB))
    covariance = nominal_covariance(110.0, 81.0, 81.0, tolerances=LAB)
    budget = configuration_budget([_frame(setup)], calibration_of(setup), setup.board, covariance=None,
                                  structure_covariance=covariance, extrinsics_from_calibration=False, adequacy=None)
    assert prediction.sigma_structure_mm == pytest.approx(budget.structure, rel=1e-9)
    assert 0.5 < prediction.sigma_structure_mm < 5.0  # the hobby-grade rig's mm-scale error (coverage: 1.1-2.3 mm)


def test_structure_term_holds_against_a_monte_carlo_of_the_extrinsics():
    """Draw (rvec, T) from the covariance, measure the noise-free square with each: its scatter is the term."""
    setup = Setup.make(170.0, 700.0, 86.0)
    rig = RigErrors(mode="nominal", tolerances=LAB)
    predicted = predict(setup, 0.1, rig=rig).sigma_structure_mm
    covariance = structure_covariance(rig, 170.0, 86.0, 86.0)
    calib = calibration_of(setup)
    ids, _ = visible_corners(setup)
    left_px, right_px, _ = project_both(setup, setup.corners_rig[ids])
    rvec0 = cv2.Rodrigues(calib.R)[0].ravel()
    rng = np.random.default_rng(7)
    squares = []
    for x in rng.multivariate_normal(np.zeros(6), covariance, size=400):
        moved = type(calib)(**{**calib.__dict__, "R": cv2.Rodrigues(rvec0 + x[:3])[0], "T": calib.T + x[3:]})
        squares.append(measure_square(moved, setup.board, ids, left_px, right_px).mean_mm)
    # 400 samples give a standard deviation to 1/sqrt(800) = 3.5 %; the first order holds to a few % more.
    assert np.std(squares) == pytest.approx(predicted, rel=0.12)


def test_per_config_has_no_structure_term_and_the_boards_scale():
    setup = Setup.make(100.0, 500.0)
    prediction = predict(setup, 0.1, calibration=CalibrationPlan(), rig=RigErrors())
    assert prediction.sigma_structure_mm == 0.0 and prediction.extrinsics_mode == "per-config"
    assert prediction.sigma_target_mm == pytest.approx(27.0 * math.hypot(0.001 / math.sqrt(3.0), 1e-4))
    # Where R, T come from elsewhere, the calibration counts with its intrinsics only and its board scales nothing.
    nominal = predict(setup, 0.1, calibration=CalibrationPlan(), rig=RigErrors(mode="nominal", tolerances=LAB))
    assert nominal.sigma_target_mm == pytest.approx(27.0 * 0.001 / math.sqrt(3.0))
    assert "intrinsics" in nominal.calibration_note


def test_kinematic_without_a_model_counts_the_landing_repeatability():
    setup = Setup.make(110.0, 550.0, 81.0)
    kinematic = predict(setup, 0.1, rig=RigErrors(mode="kinematic")).sigma_structure_mm
    still = predict(setup, 0.1, rig=RigErrors(mode="kinematic", repeatability_mm=0.0,
                                              repeatability_deg=0.0)).sigma_structure_mm
    assert still == 0.0
    # 0.002 deg per head at ~2.4 mm of square per degree (docs/ERROR_MODEL.md s4), two heads: ~7 um.
    assert 0.003 < kinematic < 0.015


def test_nominal_needs_every_tolerance():
    with pytest.raises(ValueError, match="missing"):
        RigErrors(mode="nominal", tolerances={"yaw_deg": 0.3})
    with pytest.raises(ValueError, match="mode must be"):
        RigErrors(mode="fixed")


def test_model_predict_takes_the_rig_by_default(capsys):
    argv = ("model", "predict", "--baseline", "110", "--distance", "550", "--alpha", "81", "--no-sensitivities",
            "--json")
    code, out, _ = run(capsys, *argv)
    default = json.loads(out)
    assert code == 0 and default["extrinsics_mode"] == "per-config" and default["dominant_term"] == "target"
    terms = default["terms_mm"]
    assert set(terms) == {"noise", "bias", "calibration", "structure", "target"}
    assert default["sigma_square_total_mm"] == pytest.approx(math.sqrt(sum(v * v for v in terms.values())))
    code, out, _ = run(capsys, *argv, "--extrinsics", "nominal")
    nominal = json.loads(out)
    assert nominal["dominant_term"] == "structure" and nominal["sigma_square_total_mm"] > 100 * terms["noise"]
    code, out, _ = run(capsys, *argv, "--no-rig")
    bare = json.loads(out)
    assert bare["extrinsics_mode"] is None and set(bare["terms_mm"]) == {"noise", "bias", "calibration"}
    code, out, _ = run(capsys, *argv[:-1])
    assert code == 0 and "the largest: target" in out and "boards' scale" in out


def test_rig_errors_come_from_a_campaign_file(capsys, tmp_path):
    config = tmp_path / "bench.toml"
    config.write_text('[plan]\nbaseline_mm = [100]\ndistance_mm = [500]\n[extrinsics]\nmode = "nominal"\n'
                      "[extrinsics.tolerances]\n" + "".join(f"{name} = 0.0\n" for name in LAB)
                      + "[target]\nscale_u_rel = 0.0\n")
    argv = ("model", "predict", "--baseline", "100", "--distance", "500", "--no-sensitivities", "--json")
    code, out, _ = run(capsys, *argv, "--config", str(config))
    exact = json.loads(out)
    assert code == 0 and exact["extrinsics_mode"] == "nominal" and exact["sigma_structure_mm"] == 0.0
    assert exact["sigma_target_mm"] == 0.0 and str(config) in exact["rig_note"]
    code, out, _ = run(capsys, *argv, "--config", "paper-exp1")
    assert code == 0 and "preset paper-exp1" in json.loads(out)["rig_note"]


@pytest.mark.parametrize(("extra", "message"), [
    (("--config", "no-such-file.toml"), "no-such-file.toml"),
    (("--no-rig", "--extrinsics", "nominal"), "--no-rig"),
    (("--kinematic-file", "x.toml"), "--kinematic-file needs --extrinsics kinematic"),
    (("--extrinsics", "kinematic", "--kinematic-file", "missing-model.toml"), "missing-model.toml"),
])
def test_bad_rig_options_are_one_line_exit_2(capsys, extra, message):
    code, _, err = run(capsys, "model", "predict", "--baseline", "100", "--distance", "500", "--no-sensitivities",
                       *extra)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1


def test_advise_names_the_largest_term(capsys):
    argv = ("advise", "--distance", "500", "--target-error-mm", "0.05", "--baselines", "100", "300", "200",
            "--alphas", "80", "90", "10", "--executor", "serial", "--json")
    code, out, _ = run(capsys, *argv)
    advice = json.loads(out)
    assert code == 0 and advice["extrinsics_mode"] == "per-config" and advice["best"]["dominant_term"] == "target"
    # The print's scale (27 mm x 5.8e-4 = 16 um) is what the bench measures beside a few um of noise.
    assert advice["best"]["predicted_error_mm"] > 0.015 and "largest term" in advice["message"]
    code, out, _ = run(capsys, *argv, "--extrinsics", "nominal")
    nominal = json.loads(out)
    assert code == 1 and nominal["best"]["dominant_term"] == "structure" and not nominal["meets_target"]
