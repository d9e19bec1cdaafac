"""The rigorous model: textbook limits, the paper's own geometry, its Monte Carlo, sensitivities, feasibility."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereo_bench.errormodel import paper
from stereo_bench.errormodel.montecarlo import monte_carlo, monte_carlo_samples, run_task
from stereo_bench.errormodel.rigorous import (
    Setup,
    believed_setup,
    calibration_of,
    parallel_depth_sigma_mm,
    predict,
    project_both,
    sensitivities,
    square_means,
    visible_corners,
)
from stereo_bench.errormodel.surfaces import compare_with_paper, optimum, surface_alpha, surface_bz
from stereo_bench.geometry import CameraModel, RigPose, board_pose_facing_rig
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.measure import measure_square

PINHOLE = CameraModel.from_sensor(dist=(0.0,) * 5)
SIGMA = 0.1


def pinhole_setup(baseline, distance, alpha=90.0, **kwargs):
    return Setup.make(baseline, distance, alpha, left=PINHOLE, right=PINHOLE, **kwargs)


@pytest.mark.parametrize(("baseline", "distance"), [(100.0, 500.0), (60.0, 300.0), (250.0, 700.0)])
def test_parallel_rig_matches_textbook_depth_error(baseline, distance):
    """sigma_Z = Z^2 sigma_d / (f B) at the board centre, sigma_d = sqrt(2) sigma_px (independent L/R noise)."""
    expected = parallel_depth_sigma_mm(distance, baseline, PINHOLE.fx, SIGMA)
    assert expected == pytest.approx(distance**2 * math.sqrt(2) * SIGMA / (PINHOLE.fx * baseline))
    pred = predict(pinhole_setup(baseline, distance), SIGMA)
    assert pred.sigma_z_mm == pytest.approx(expected, rel=1e-6)
    # Lateral: the midpoint of two rays each off by sigma/f, i.e. Z sigma / (sqrt(2) f).
    assert pred.sigma_x_mm == pytest.approx(distance * SIGMA / (math.sqrt(2) * PINHOLE.fx), rel=1e-6)
    # With the simulator's mild distortion the centre's off-axis pixels change this by < 1 %.
    distorted = predict(Setup.make(baseline, distance), SIGMA)
    assert distorted.sigma_z_mm == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize("k", [0.5, 1.0, math.sqrt(2.0), 2.0])
def test_converging_rig_reproduces_the_papers_components(k):
    """With the optical axes meeting at the board centre the rigorous point error is the paper's, exactly."""
    distance = 500.0
    alpha = float(paper.converging_alpha_deg(k))
    pred = predict(Setup.make(k * distance, distance, alpha), SIGMA)  # centre on both axes: distortion-free there
    dx, dz = paper.components_mm(k, distance, PINHOLE.fx, SIGMA)
    assert pred.sigma_x_mm == pytest.approx(dx, rel=1e-6)
    assert pred.sigma_z_mm == pytest.approx(dz, rel=1e-6)
    assert pred.gamma_xz_mm == pytest.approx(paper.gamma_mm(k, distance, PINHOLE.fx, SIGMA), rel=1e-6)


@pytest.mark.parametrize(
    ("baseline", "distance", "alpha"),
    [(100.0, 500.0, 90.0), (300.0, 500.0, 70.0), (60.0, 400.0, 86.0)],
)
def test_first_order_agrees_with_monte_carlo(baseline, distance, alpha):
    """N = 2000 seeded samples: sample sigma within 10 % (its own standard error is ~1.6 %)."""
    setup = Setup.make(baseline, distance, alpha)
    pred = predict(setup, SIGMA)
    mc = monte_carlo(setup, SIGMA, 2000, seed=7)
    for field in ("sigma_square_mm", "sigma_x_mm", "sigma_y_mm", "sigma_z_mm"):
        assert getattr(mc, field) == pytest.approx(getattr(pred, field), rel=0.10), field
    # The second-order noise bias of the square, against the sample mean (standard error ~3 % here).
    assert mc.bias_square_mm == pytest.approx(pred.bias_square_mm, rel=0.25, abs=2e-4)


def test_noise_bias_grows_as_the_baseline_shrinks():
    small, large = predict(Setup.make(40.0, 500.0), SIGMA), predict(Setup.make(200.0, 500.0), SIGMA)
    assert small.bias_square_mm > 10 * large.bias_square_mm > 0
    assert small.bias_square_mm > small.sigma_square_mm  # at B = 40 mm the bias outweighs the scatter


def test_square_statistic_is_the_pipelines():
    setup = Setup.make(120.0, 450.0, 80.0)
    ids, _ = visible_corners(setup)
    left, right, _ = project_both(setup, setup.corners_rig[ids])
    rng = np.random.default_rng(3)
    left, right = left + rng.normal(0, 0.3, left.shape), right + rng.normal(0, 0.3, right.shape)
    calib = calibration_of(setup)
    from stereo_bench.vision.triangulate import triangulate

    ours = square_means(triangulate(calib, left, right), ids, setup.board)
    theirs = measure_square(calib, setup.board, ids, left, right, pixel_sigma_px=0.1).mean_mm
    assert float(ours) == pytest.approx(theirs, abs=1e-12)


def test_true_calibration_measures_the_nominal_square():
    pred = predict(Setup.make(150.0, 600.0, 82.0), SIGMA)
    assert pred.square_true_mean_mm == pytest.approx(27.0, abs=1e-6)


def test_monte_carlo_samples_do_not_depend_on_task_grouping():
    setup = Setup.make(100.0, 500.0)
    a = monte_carlo_samples(setup, SIGMA, 1200, seed=5, n_tasks=1)
    b = monte_carlo_samples(setup, SIGMA, 1200, seed=5, n_tasks=3)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    c = monte_carlo_samples(setup, SIGMA, 1200, seed=6)
    assert not np.array_equal(a[0], c[0])
    assert callable(run_task)


# ----------------------------------------------------------------------------------------------
# Structural sensitivities against closed forms


def test_parallel_rig_sensitivities_match_closed_forms():
    z, b = 500.0, 100.0
    sens = sensitivities(pinhole_setup(b, z))
    # A calibrated baseline too long by dB scales everything: dZ/dB = Z/B, d(square)/dB = s/B.
    assert sens["baseline_mm"].depth_mm_per_unit == pytest.approx(z / b, rel=1e-6)
    assert sens["baseline_mm"].square_mm_per_unit == pytest.approx(27.0 / b, rel=1e-6)
    # Focal length: Z = f B / d with the disparity fixed: dZ/df = Z / f; lateral scale unchanged.
    assert sens["focal_both_px"].depth_mm_per_unit == pytest.approx(z / PINHOLE.fx, rel=1e-4)
    assert abs(sens["focal_both_px"].square_mm_per_unit) < 1e-3
    # One camera turned outward by d(alpha): the disparity drops by f d(alpha) / cos^2 of the ray angle,
    # so dZ = Z^2 / B (1 + (B / 2Z)^2) d(alpha) at the centre (rad).
    expected = z**2 / b * (1 + (b / (2 * z)) ** 2) * math.pi / 180
    assert sens["alpha_right_deg"].depth_mm_per_unit == pytest.approx(expected, rel=1e-4)
    assert sens["alpha_both_deg"].depth_mm_per_unit == pytest.approx(2 * expected, rel=1e-4)
    # Principal point of one camera: a disparity error of 1 px: dZ = -Z^2 / (f B) (its sign: u_R grows).
    assert sens["cx_right_px"].depth_mm_per_unit == pytest.approx(-(z**2) / (PINHOLE.fx * b), rel=1e-3)
    assert abs(sens["cy_right_px"].depth_mm_per_unit) < 1e-6


def test_sensitivity_of_a_converging_rig_to_angle_is_z_times_e2():
    """The paper's e2 is also d(depth)/d(one ray's angle) / Z: one camera 1 deg off moves Z by Z e2 pi/180."""
    z = 500.0
    for k in (0.5, 1.0, 2.0):
        setup = Setup.make(k * z, z, float(paper.converging_alpha_deg(k)))
        d = sensitivities(setup, ("alpha_right_deg",))["alpha_right_deg"].depth_mm_per_unit
        assert d == pytest.approx(z * float(paper.e2(k)) * math.pi / 180, rel=1e-5)


def test_believed_setup_rejects_unknown_parameters():
    with pytest.raises(ValueError, match="unknown structural parameter"):
        believed_setup(Setup.make(100.0, 500.0), "tilt_deg", 0.1)


# ----------------------------------------------------------------------------------------------
# Feasibility


def test_feasibility_of_the_papers_experiment_two():
    """B = 100 mm, Z = 500 mm: the paper's alpha = 35 deg leaves nothing in view; a parallel rig sees it all."""
    steep = predict(Setup.make(100.0, 500.0, 35.0), SIGMA)
    assert not steep.feasible and not steep.measurable and steep.n_in_both == 0
    assert "0/54" in steep.reason and steep.sigma_square_mm is None
    parallel = predict(Setup.make(100.0, 500.0, 90.0), SIGMA)
    assert parallel.feasible and parallel.n_in_both == 54 and parallel.n_pairs == 93 and parallel.reason == ""


def test_partial_view_is_measured_but_not_feasible():
    pred = predict(Setup.make(100.0, 500.0, 55.0), SIGMA)
    assert pred.measurable and not pred.feasible
    assert 6 <= pred.n_in_both < 54 and pred.sigma_square_mm is not None


def test_board_seen_from_behind_is_reported():
    T = board_pose_facing_rig(distance_mm=500.0, board_size_mm=(216.0, 135.0), yaw_deg=180.0)
    _, vis = visible_corners(Setup.make(100.0, 500.0, T_rig_board=T))
    assert not vis.measurable and "back of the board" in vis.reason


def test_setup_matches_the_simulated_rig_objects():
    """predict takes the very objects the simulator takes (rig, board pose, board, cameras)."""
    board = Checkerboard(7, 5, 30.0)
    camera = CameraModel.from_sensor(focal_mm=6.0)
    T = board_pose_facing_rig(distance_mm=600.0, board_size_mm=board.grid_size_mm, yaw_deg=10.0)
    setup = Setup(rig=RigPose.symmetric(120.0, 85.0), board=board, T_rig_board=T, left=camera, right=camera)
    pred = predict(setup, SIGMA)
    assert pred.feasible and pred.n_in_both == 35
    assert pred.distance_mm == pytest.approx(600.0)
    assert pred.square_true_mean_mm == pytest.approx(30.0, abs=1e-6)


def test_setup_validation():
    with pytest.raises(ValueError, match="baseline"):
        Setup.make(0.0, 500.0)
    with pytest.raises(ValueError, match="alpha"):
        Setup.make(100.0, 500.0, 180.0)
    with pytest.raises(ValueError, match="pixel_sigma"):
        predict(Setup.make(100.0, 500.0), -1.0)


# ----------------------------------------------------------------------------------------------
# Surfaces and the comparison with the paper


def test_surfaces_shapes_and_paper_gamma_on_the_converging_rig():
    rows = surface_bz([100.0, 300.0], [400.0, 600.0], alpha="converge", with_sensitivities=False)
    assert [(r.baseline_mm, r.distance_mm) for r in rows] == [(100, 400), (100, 600), (300, 400), (300, 600)]
    for r in rows:
        assert r.gamma_xz_mm == pytest.approx(r.paper_gamma_mm, rel=1e-6)
    parallel = surface_bz([100.0, 300.0], [500.0], alpha="parallel", with_sensitivities=False)
    assert parallel[1].sigma_z_mm < parallel[0].sigma_z_mm  # a longer baseline helps a parallel rig
    alphas = surface_alpha([40.0, 60.0, 90.0], baseline_mm=100.0, distance_mm=500.0)
    assert [r.feasible for r in alphas] == [False, False, True]
    assert optimum(alphas).alpha_deg == 90.0


def test_comparison_with_the_paper_on_a_small_grid():
    c = compare_with_paper(k_values=np.arange(0.2, 3.21, 0.2), alphas_deg=np.arange(20.0, 90.01, 5.0),
                           bench_baseline_range_mm=(100.0, 300.0), bench_steps=(100.0, 10.0))
    by_metric = {o.metric: o for o in c.converge}
    # The centre-point error of the converging rig is the paper's: optimum at K = sqrt 2.
    assert by_metric["gamma_xz_mm"].x == pytest.approx(math.sqrt(2.0), abs=2e-3)
    # The measured square's noise has its optimum elsewhere (K ~ 0.8), and the depth's sensitivity
    # to one camera's angle error is smallest at K = 2 (alpha = 45 deg), where e2 = 1.
    assert 0.6 < by_metric["sigma_square_mm"].x < 1.0
    assert by_metric["depth_per_deg_alpha"].x == pytest.approx(2.0, abs=2e-3)
    assert not c.experiment2_claimed_alpha_measurable
    assert c.experiment2_feasible_alpha_deg[1] == 90.0 and c.experiment2_feasible_alpha_deg[0] > 55.0
    assert {o.metric: o for o in c.parallel}["sigma_square_mm"].limit == "feasibility"
    assert c.bench_optimum is not None and c.bench_optimum.feasible


# ----------------------------------------------------------------------------------------------
# The advisor


def test_largest_rectangle():
    from stereo_bench.errormodel.advisor import _largest_rectangle

    ok = np.array([
        [0, 0, 1, 0],
        [1, 1, 1, 1],
        [1, 1, 1, 0],
        [0, 0, 1, 0],
    ], bool)
    assert _largest_rectangle(ok) == (1, 2, 0, 2)
    assert _largest_rectangle(np.zeros((2, 2), bool)) is None


def test_advice_meets_the_target_only_where_the_board_is_in_view():
    from stereo_bench.errormodel.advisor import advise, predicted_error_mm

    advice = advise(500.0, 0.05, baselines_mm=[20.0, 100.0, 300.0], alphas_deg=[40.0, 70.0, 90.0])
    assert advice.meets_target and advice.n_meeting <= advice.n_feasible
    by_b = {row.baseline_mm: row for row in advice.rows}
    assert 40.0 not in by_b[100.0].alphas_ok_deg  # nothing in view there
    # At B = 20 mm the noise bias of the square (~0.06 mm) alone breaks 0.05 mm.
    assert by_b[20.0].alphas_ok_deg == []
    rows = surface_bz([20.0], [500.0], alpha="parallel")
    assert predicted_error_mm(rows[0], "square") > rows[0].bias_square_mm > 0.05
    # A baseline error of 0.5 mm costs 27/B * 0.5 mm on the square: 0.045 mm at B = 300 mm.
    with_structure = advise(500.0, 0.05, baseline_error_mm=0.5, baselines_mm=[100.0, 300.0], alphas_deg=[90.0])
    assert [row.alphas_ok_deg for row in with_structure.rows] == [[], [90.0]]
    assert with_structure.best.predicted_error_mm == pytest.approx(math.hypot(0.045, 0.0032), abs=0.002)



def test_advices_structural_terms_match_the_scatter_of_calibrations_wrong_within_those_errors():
    # advise(--baseline-error, --alpha-error) adds per_B * e_B and sqrt(2) * per_alpha * e_alpha (each camera's
    # toe-in wrong on its own): square errors of calibrations drawn with those errors must scatter as claimed.
    from stereo_bench.errormodel.advisor import predicted_error_mm
    from stereo_bench.errormodel.rigorous import believed_setup, measured_with, project_both, visible_corners
    from stereo_bench.errormodel.surfaces import evaluate_configs

    e_b, e_a = 0.3, 0.05  # mm, deg: the two terms comparable (0.054 and 0.11 mm)
    (point,) = evaluate_configs([(150.0, 500.0, 80.0, 80.0)])
    claimed = math.sqrt(predicted_error_mm(point, "square", baseline_error_mm=e_b, alpha_error_deg=e_a) ** 2
                        - predicted_error_mm(point, "square") ** 2)
    setup = Setup.make(150.0, 500.0, 80.0)
    ids, _ = visible_corners(setup)
    pixels = (*project_both(setup, setup.corners_rig[ids])[:2], *project_both(setup, setup.board_centre_rig)[:2])
    true_square = measured_with(setup, setup, ids, *pixels)[0]
    rng = np.random.default_rng(1)
    errors = []
    for _ in range(300):
        d_b, d_left, d_right = rng.standard_normal(3) * (e_b, e_a, e_a)
        believed = believed_setup(believed_setup(believed_setup(setup, "baseline_mm", d_b), "alpha_left_deg", d_left),
                                  "alpha_right_deg", d_right)
        errors.append(measured_with(setup, believed, ids, *pixels)[0] - true_square)
    ratio = float(np.sqrt(np.mean(np.square(errors)))) / claimed
    assert 0.85 <= ratio <= 1.15, ratio  # 300 draws: standard error of the RMS 4 %; 1.30 without the sqrt(2)

def test_advice_validation():
    from stereo_bench.errormodel.advisor import advise

    with pytest.raises(ValueError, match="metric"):
        advise(500.0, 0.05, metric="volume")
    with pytest.raises(ValueError, match="target_error_mm"):
        advise(500.0, -1.0)


def test_planned_calibration_views_show_the_whole_board_in_both_images_over_the_range():
    from stereo_bench.errormodel.rigorous import CalibrationPlan, planned_board_poses, project_both
    from stereo_bench.geometry import transform_points

    setup = Setup.make(200.0, 500.0, 80.0)
    plan = CalibrationPlan(n_views=12)
    poses = planned_board_poses(setup, plan)
    assert len(poses) == 12
    points = np.asarray(plan.board.object_points, float)
    depths = []
    for T_rig_board in poses:
        left, right, in_front = project_both(setup, transform_points(T_rig_board, points))
        assert in_front.all() and setup.left.in_image(left, margin_px=20).all()
        assert setup.right.in_image(right, margin_px=20).all()
        depths.append(T_rig_board[2, 3])
    near, far = plan.distance_range(500.0)
    assert (near, far) == (300.0, 650.0)
    assert max(depths) - min(depths) > 0.5 * (far - near)  # spread over the range, not bunched
    with pytest.raises(ValueError, match="does not fit both images"):
        planned_board_poses(Setup.make(300.0, 300.0, 90.0), CalibrationPlan(distance_mm=(150.0, 160.0)))


@pytest.mark.parametrize("baseline_mm, alpha_deg, distance_mm", [(50.0, 90.0, 300.0), (150.0, 85.0, 300.0),
                                                                  (250.0, 85.0, 500.0)])
def test_planned_calibration_views_are_views_the_presenter_could_show(baseline_mm, alpha_deg, distance_mm):
    """The planner places its views by the project's one rule of a usable calibration view
    (geometry.calibration_view_fits: the outer squares sampled along every side, no more than 60 deg oblique),
    the rule the simulated presenter places its own by. With its own check (the outline's four corners, no
    obliquity limit) 1-4 of these 12 views, of a strongly distorted 640x480 camera, were views the rule refuses."""
    from stereo_bench.geometry import calibration_view_fits
    from stereo_bench.vision.planned import planned_board_poses

    camera = CameraModel.from_sensor(image_size=(640, 480), pixel_um=6.0, dist=(-0.3, 0.1, 0.0, 0.0, 0.0), name="w")
    board = Checkerboard(11, 8, 25.0)
    rig = RigPose.symmetric(baseline_mm, alpha_deg)
    poses = planned_board_poses(rig, board, camera, camera, n_views=12,
                                distance_mm=(max(250.0, 0.6 * distance_mm), 1.3 * distance_mm))
    assert len(poses) == 12
    assert all(calibration_view_fits(board, T, rig=rig, left=camera, right=camera) for T in poses)


def test_prediction_includes_the_calibration_component_that_more_views_shrink():
    from stereo_bench.errormodel.rigorous import CalibrationPlan

    setup = Setup.make(200.0, 500.0, 80.0)
    assert predict(setup, SIGMA).sigma_calibration_mm is None  # not asked for
    few = predict(setup, SIGMA, calibration=CalibrationPlan(n_views=6))
    many = predict(setup, SIGMA, calibration=CalibrationPlan(n_views=24))
    assert few.calibration_views == 6 and "6 planned views" in few.calibration_note
    assert few.sigma_calibration_mm > 0 and few.sigma_calibration_depth_mm > 0
    assert 1.4 < few.sigma_calibration_mm / many.sigma_calibration_mm < 2.8  # about sqrt(4)
    # Linear in the image noise, like the noise term.
    double = predict(setup, 2 * SIGMA, calibration=CalibrationPlan(n_views=6))
    assert double.sigma_calibration_mm == pytest.approx(2 * few.sigma_calibration_mm, rel=1e-6)
    # Intrinsics from mono calibrations of the same views, held fixed: a larger error here.
    fixed = predict(setup, SIGMA, calibration=CalibrationPlan(n_views=6, mode="fixed"))
    assert fixed.sigma_calibration_mm > few.sigma_calibration_mm


def test_unplaceable_calibration_views_leave_the_component_unknown_with_the_reason():
    from stereo_bench.errormodel.rigorous import CalibrationPlan

    pred = predict(Setup.make(300.0, 300.0, 90.0), SIGMA, calibration=CalibrationPlan(distance_mm=(150.0, 160.0)))
    assert pred.sigma_calibration_mm is None and "does not fit both images" in pred.calibration_note


def test_advice_includes_the_calibrations_error_by_default():
    from stereo_bench.errormodel.advisor import advise
    from stereo_bench.errormodel.rigorous import CalibrationPlan

    grid = {"baselines_mm": [100.0, 300.0], "alphas_deg": [80.0, 90.0]}
    noise_only = advise(800.0, 1.0, calibration=None, **grid)
    plan = CalibrationPlan(n_views=6, mode="fixed")  # few views, intrinsics fixed: a large calibration error
    with_calibration = advise(800.0, 1.0, calibration=plan, **grid)
    assert noise_only.calibration_views == 0 and "no calibration, rig or target error" in noise_only.message
    assert with_calibration.calibration_views == 6 and "calibration from 6 views" in with_calibration.message
    best, best_noise = with_calibration.best, noise_only.best
    assert best.sigma_calibration_mm > 0.3 * best.predicted_error_mm  # it matters here
    assert best.predicted_error_mm == pytest.approx(
        math.sqrt(best.sigma_noise_mm**2 + best.bias_mm**2 + best.sigma_calibration_mm**2))
    # A target the image noise alone would meet is out of reach once the calibration counts.
    target = 0.5 * (best_noise.predicted_error_mm + best.predicted_error_mm)
    assert advise(800.0, target, calibration=None, **grid).meets_target
    assert not advise(800.0, target, calibration=plan, **grid).meets_target
