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


# ----------------------------------------------------------------------------------------------
# Kinematic mode: the planned fit of a campaign's design (stereo_bench.errormodel.rigorous.planned_kinematic_model)

def _design_rig(n_views: int = 12, **repeatability: float) -> tuple[RigErrors, CalibrationPlan]:
    from stereo_bench.kinematics import kinematic_design

    design = tuple(kinematic_design((60.0, 240.0), (0.0, 13.0), (0.0, 13.0)))
    rig = RigErrors(mode="kinematic", tolerances=LAB, target_scale_u_rel=0.0, calibration_board_scale_u_rel=0.0,
                    design=design, design_distance_mm=550.0, **repeatability)
    return rig, CalibrationPlan(n_views=n_views)


def test_the_rotation_vector_is_exact_down_to_the_identity():
    # cv2.Rodrigues returns 0 below 1e-5 rad: a central difference at parallel cameras saw no rotation.
    from stereo_bench.kinematics.model import _rvec

    rng = np.random.default_rng(3)
    for angle in (1e-9, 1e-6, 1e-4, 0.01, 1.0, 3.0):
        axis = rng.normal(size=3)
        rvec = axis / np.linalg.norm(axis) * angle
        assert np.abs(_rvec(cv2.Rodrigues(rvec)[0]) - rvec).max() <= 1e-14 * max(1.0, angle)


def test_the_kinematic_calibration_term_is_continuous_at_parallel_cameras():
    from stereo_bench.errormodel.rigorous import kinematic_sigmas

    rig, plan = _design_rig(n_views=6)  # a smaller design fits faster; the terms compare alike
    parallel = kinematic_sigmas(Setup.make(60.0, 400.0, 90.0), rig, plan, 0.15)
    near = kinematic_sigmas(Setup.make(60.0, 400.0, 89.9), rig, plan, 0.15)
    assert parallel is not None and near is not None
    for a, b in zip(parallel[:4], near[:4], strict=True):
        assert a == pytest.approx(b, rel=0.1)


def test_the_joint_kinematic_term_is_below_the_intrinsics_apart_and_says_so():
    rig, plan = _design_rig(n_views=6)  # a smaller design fits faster; the terms compare alike
    setup = Setup.make(110.0, 550.0, 81.0)
    joint = predict(setup, 0.15, calibration=plan, rig=rig)
    apart = predict(setup, 0.15, calibration=plan, rig=RigErrors(
        mode="kinematic", tolerances=LAB, target_scale_u_rel=0.0, calibration_board_scale_u_rel=0.0,
        intrinsics_visits=len(rig.design)))
    assert "planned kinematic fit" in joint.calibration_note and "over-prediction" in apart.calibration_note
    # Measured on the lab bench (docs/ERROR_MODEL.md section 5): 2.7 against 18.6 um at this configuration.
    assert joint.sigma_calibration_mm < 0.3 * apart.sigma_calibration_mm


def test_the_planned_kinematic_calibration_term_holds_against_refits_of_noisy_views():
    """The square's error from the fit alone (exact target pixels), over fits of freshly noisy design views,
    against the predicted calibration term: the prediction is the fit's own covariance at this noise."""
    from dataclasses import dataclass

    from stereo_bench.campaign.sources import kinematic_source
    from stereo_bench.errormodel.rigorous import kinematic_sigmas, planned_board_poses
    from stereo_bench.geometry import alpha_from_toe_in, transform_points
    from stereo_bench.kinematics import ConfigurationViews, fit_kinematics
    from stereo_bench.vision.uncertainty import BoardScale

    @dataclass
    class Corners:
        ids: np.ndarray
        corners_px: np.ndarray

    sigma = 0.3
    # Exact landings on both sides: the refits' data has none, so the prediction must not carry them.
    rig, plan = _design_rig(n_views=6, repeatability_mm=0.0, repeatability_deg=0.0)
    points = np.asarray(plan.board.object_points, float)
    exact = []
    for d in rig.design:
        setup = Setup.make(d.baseline_mm, 550.0, alpha_from_toe_in(d.toe_in_left_deg),
                           alpha_right_deg=alpha_from_toe_in(d.toe_in_right_deg))
        views = []
        for T in planned_board_poses(setup, plan):
            left_px, right_px, front = project_both(setup, transform_points(T, points))
            ids = np.flatnonzero(front & setup.left.in_image(left_px) & setup.right.in_image(right_px))
            views.append((ids, left_px[ids], right_px[ids]))
        exact.append((d.axes(), views))
    target = Setup.make(110.0, 550.0, 81.0)
    ids, _ = visible_corners(target)
    left_px, right_px, _ = project_both(target, target.corners_rig[ids])
    truth = measure_square(calibration_of(target), target.board, ids, left_px, right_px, pixel_sigma_px=0.0).mean_mm
    axes = {"baseline_mm": 110.0, "toe_in_left_deg": 9.0, "toe_in_right_deg": 9.0}
    rng = np.random.default_rng(11)
    cal = calibration_of(target)
    errors = []
    for _ in range(12):
        configurations = [ConfigurationViews(axes=a, approach=dict.fromkeys(a, 1), views=[
            (Corners(i, lp + rng.normal(0, sigma, lp.shape)), Corners(i, rp + rng.normal(0, sigma, rp.shape)))
            for i, lp, rp in views]) for a, views in exact]
        model = fit_kinematics(configurations, points, tuple(target.left.image_size),
                               intrinsics=(cal.K1, np.asarray(cal.D1).reshape(1, -1), cal.K2,
                                           np.asarray(cal.D2).reshape(1, -1)),
                               pixel_sigma_px=sigma).model
        calib = kinematic_source(model, axes, dict.fromkeys(axes, 1), BoardScale()).calib
        errors.append(measure_square(calib, target.board, ids, left_px, right_px, pixel_sigma_px=0.0).mean_mm - truth)
    predicted = kinematic_sigmas(target, rig, plan, sigma)[0]
    scatter = float(np.sqrt(np.mean(np.square(errors))))
    # 12 draws: the RMS is known to ~20 % (1 sigma); a 2x error in either direction fails.
    assert 0.6 < scatter / predicted < 1.6, (scatter, predicted)
