"""The kinematic rig model on exact projections through the simulator's mechanics (no rendering).

The views are the board's corners projected through the true camera poses of the lab profile's
mechanics (backlash by approach, one landing error per move) plus Gaussian pixel noise, so the fit
is checked against known parameters with nothing else in the way. tests/test_kinematics_lab.py does
the same through the rendered lab bench.
"""

from __future__ import annotations

import math
import tomllib
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.sim.mechanics import MoveHistory, kinematic_parameters, pair_state
from drivers.sim.profile import LAB
from drivers.sim.render import calibration_board_poses
from stereo_bench.geometry import CameraModel, RigPose, invert_transform, stereo_structure, transform_points
from stereo_bench.kinematics import (
    AXES,
    NAMES,
    ConfigurationViews,
    KinematicFileError,
    approach_directions,
    chain,
    fit_kinematics,
    kinematic_design,
    load_model,
    nominal_extrinsics,
    nominal_parameters,
    predict,
    save_model,
)
from stereo_bench.targets import Checkerboard

BOARD = Checkerboard(11, 8, 25.0)
CAMERA = CameraModel.from_sensor()
HOME = {"baseline_mm": 0.0, "toe_in_left_deg": 0.0, "toe_in_right_deg": 0.0}
CHI2_999 = {22: 48.27, 10: 29.59}  # 99.9 % quantiles of chi-square with that many degrees of freedom


def simulated_views(design, *, n_views: int, pixel_sigma: float, seed: int, history: MoveHistory):
    """ConfigurationViews of a design visited in order from home, as the lab mechanics place the cameras."""
    rng = np.random.default_rng(seed)
    previous, approach, out, now = dict(HOME), {}, [], 0.0
    for config in design:
        values = config.axes()
        now += 10.0
        history.moved(values, end_s=now, approach={  # at rest: the landing error is drawn
            q: 1 if v > previous[q] else -1 for q, v in values.items() if v != previous[q]})
        approach = approach_directions(previous, values, approach)
        previous = values
        state = pair_state(LAB, values, history=history, now_s=now + 5.0)
        poses = calibration_board_poses(RigPose(config.baseline_mm, config.alpha_left_deg, config.alpha_right_deg),
                                        BOARD, n_views=n_views, rng=rng, distance_mm=(300.0, 700.0))
        views = []
        for T_rig_board in poses:
            detections = []
            for T_rig_cam in (state.T_bench_left, state.T_bench_right):
                T_cam_board = invert_transform(T_rig_cam) @ T_rig_board
                px, ok = CAMERA.project(transform_points(T_cam_board, BOARD.object_points))
                ids = np.flatnonzero(ok & CAMERA.in_image(px, margin_px=5.0))
                noisy = px[ids] + rng.normal(0, pixel_sigma, (len(ids), 2))
                detections.append(SimpleNamespace(ids=ids, corners_px=noisy))
            views.append(tuple(detections))
        out.append(ConfigurationViews(axes=values, approach=dict(approach), views=views))
    return out, previous, approach


def fit(design, *, n_views=12, pixel_sigma=0.05, seed=0, landing=True):
    history = MoveHistory(LAB if landing else LAB.model_copy(update={
        "slide": LAB.slide.model_copy(update={"repeatability_mm": 0.0}),
        "left_head": LAB.left_head.model_copy(update={"repeatability_deg": 0.0}),
        "right_head": LAB.right_head.model_copy(update={"repeatability_deg": 0.0})}), seed=seed)
    configurations, previous, approach = simulated_views(design, n_views=n_views, pixel_sigma=pixel_sigma, seed=seed,
                                                         history=history)
    result = fit_kinematics(configurations, BOARD.object_points, CAMERA.image_size,
                            intrinsics=(CAMERA.K, CAMERA.dist, CAMERA.K, CAMERA.dist), refine_intrinsics=False,
                            repeatability_mm=LAB.slide.repeatability_mm,
                            repeatability_left_deg=LAB.left_head.repeatability_deg,
                            repeatability_right_deg=LAB.right_head.repeatability_deg)
    return result, previous, approach


@pytest.fixture(scope="module")
def lab_fit():
    return fit(kinematic_design((50.0, 250.0), (0.0, 20.0)))


def true_pose(values: dict, approach: dict) -> np.ndarray:
    """T_right_left of the lab mechanics at rest after an approach, without a landing error."""
    history = MoveHistory(LAB.model_copy(update={
        "slide": LAB.slide.model_copy(update={"repeatability_mm": 0.0}),
        "left_head": LAB.left_head.model_copy(update={"repeatability_deg": 0.0}),
        "right_head": LAB.right_head.model_copy(update={"repeatability_deg": 0.0})}))
    history.moved(values, end_s=1.0, approach={axis: approach[axis] for axis in AXES if approach.get(axis)})
    state = pair_state(LAB, values, history=history)
    return invert_transform(state.T_bench_right) @ state.T_bench_left


def test_the_nominal_model_is_the_nominal_geometry():
    p = nominal_parameters(150.0)
    for b, tl, tr in [(150.0, 0.0, 0.0), (60.0, 10.0, 25.0), (300.0, 5.0, 0.0)]:
        T = chain(p, 150.0, b, tl, tr)
        R, t = nominal_extrinsics(b, 90.0 - tl, 90.0 - tr)
        np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)
        np.testing.assert_allclose(T[:3, 3], t, atol=1e-9)


def test_the_design_spans_the_ranges_and_approaches_every_axis_from_both_sides():
    design = kinematic_design((50.0, 250.0), (0.0, 20.0), (5.0, 25.0))
    assert len(design) == 9
    assert sorted({c.baseline_mm for c in design}) == [50.0, 150.0, 250.0]
    assert sorted({c.toe_in_left_deg for c in design}) == [0.0, 10.0, 20.0]
    assert sorted({c.toe_in_right_deg for c in design}) == [5.0, 15.0, 25.0]
    assert all(sum(c.baseline_mm == b for c in design) == 3 for b in (50.0, 150.0, 250.0))
    assert any(c.toe_in_left_deg - c.toe_in_right_deg != -5.0 for c in design)  # the heads are not always paired
    # Neighbouring levels only: no large asymmetric pair, whose views may not overlap.
    assert all(abs((c.toe_in_left_deg - 0.0) - (c.toe_in_right_deg - 5.0)) <= 10.0 for c in design)
    previous, approach, seen = dict(HOME), {}, {axis: set() for axis in AXES}
    for config in design:
        approach = approach_directions(previous, config.axes(), approach)
        previous = config.axes()
        for axis in AXES:
            seen[axis].add(approach[axis])
    assert all({1, -1} <= directions for directions in seen.values())


def test_a_parallel_plan_revisits_its_baselines_from_both_sides():
    design = kinematic_design((50.0, 250.0))
    assert len(design) == 9 and {c.toe_in_left_deg for c in design} == {0.0}


def test_approach_directions_keep_the_last_one_for_an_axis_that_did_not_move():
    first = approach_directions(HOME, {**HOME, "baseline_mm": 100.0})
    assert first == {"baseline_mm": 1, "toe_in_left_deg": 0, "toe_in_right_deg": 0}
    second = approach_directions({**HOME, "baseline_mm": 100.0}, {**HOME, "baseline_mm": 50.0, "toe_in_left_deg": 3.0},
                                 first)
    assert second == {"baseline_mm": -1, "toe_in_left_deg": 1, "toe_in_right_deg": 0}


def test_the_fit_recovers_the_simulated_mechanics_within_their_stated_sigma(lab_fit):
    result, _, _ = lab_fit
    model = result.model
    truth = kinematic_parameters(LAB, model.reference_baseline_mm)
    z = {name: (model.parameters[name].value - truth[name]) / model.parameters[name].sigma for name in NAMES}
    assert all(model.parameters[name].identifiable for name in NAMES)
    assert max(abs(v) for v in z.values()) < 3.5, z
    assert sum(v * v for v in z.values()) < CHI2_999[22], z
    assert model.fit.pixel_sigma_px == pytest.approx(0.05, rel=0.1)  # the noise it was given


def test_predictions_at_configurations_outside_the_design_hold_within_their_sigma(lab_fit):
    result, previous, approach = lab_fit
    for values in ({"baseline_mm": 75.0, "toe_in_left_deg": 5.0, "toe_in_right_deg": 5.0},
                   {"baseline_mm": 200.0, "toe_in_left_deg": 15.0, "toe_in_right_deg": 8.0},
                   {"baseline_mm": 125.0, "toe_in_left_deg": 12.0, "toe_in_right_deg": 18.0}):
        approach = approach_directions(previous, values, approach)
        previous = values
        prediction = predict(result.model, values, approach)
        T = true_pose(values, approach)
        truth = stereo_structure(T[:3, :3], T[:3, 3])
        assert not prediction.extrapolated
        for key in ("baseline_mm", "alpha_left_deg", "alpha_right_deg", "rotation_deg"):
            error = prediction.structure[key] - truth[key]
            assert abs(error) < 4 * prediction.structure_sigma[key], (values, key, error)
        assert abs(prediction.structure["baseline_mm"] - truth["baseline_mm"]) < 0.05
        assert abs(prediction.structure["alpha_left_deg"] - truth["alpha_left_deg"]) < 0.01


def test_an_unknown_approach_widens_the_prediction_by_the_backlash(lab_fit):
    model = lab_fit[0].model
    values = {"baseline_mm": 120.0, "toe_in_left_deg": 8.0, "toe_in_right_deg": 8.0}
    known = predict(model, values, {"baseline_mm": 1, "toe_in_left_deg": 1, "toe_in_right_deg": 1})
    unknown = predict(model, values)
    assert unknown.structure_sigma["baseline_mm"] > known.structure_sigma["baseline_mm"]
    assert unknown.covariance.shape == (6, 6) and np.all(np.linalg.eigvalsh(unknown.covariance) > 0)
    assert predict(model, {**values, "baseline_mm": 320.0}).extrapolated == ["baseline_mm"]
    with pytest.raises(ValueError, match="missing toe_in_right_deg"):
        predict(model, {"baseline_mm": 100.0, "toe_in_left_deg": 0.0})


def test_the_model_file_is_readable_toml_and_round_trips(lab_fit, tmp_path):
    model = lab_fit[0].model
    path = save_model(model, tmp_path / "kinematics.toml")
    text = path.read_text()
    data = tomllib.loads(text)
    assert data["parameters"]["left_axis_z_mm"]["unit"] == "mm" and "sigma" in data["parameters"]["slide_scale"]
    assert "# left pan axis" in text  # every parameter says what it is
    again = load_model(path)
    assert again.model_dump() == model.model_dump()
    values = {"baseline_mm": 90.0, "toe_in_left_deg": 3.0, "toe_in_right_deg": 4.0}
    np.testing.assert_array_equal(predict(again, values).covariance, predict(model, values).covariance)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("[parameters.slide_scale]", "[parameters.slide_scales]"), "missing slide_scale"),
    (lambda t: t.replace('schema = "', 'schema = "x'), "schema: expected"),
    (lambda t: t + "\n[[[", "invalid TOML"),
])
def test_a_bad_model_file_is_one_line_naming_the_file(lab_fit, tmp_path, edit, message):
    path = save_model(lab_fit[0].model, tmp_path / "k.toml")
    path.write_text(edit(path.read_text()))
    with pytest.raises(KinematicFileError) as error:
        load_model(path)
    assert str(error.value).startswith(str(path)) and message in str(error.value) and "\n" not in str(error.value)
    with pytest.raises(KinematicFileError, match="no such kinematic model file"):
        load_model(tmp_path / "missing.toml")


def test_a_parallel_design_holds_the_pan_axes_nominal_and_says_why():
    design = kinematic_design((50.0, 250.0))
    result, _, _ = fit(design, n_views=6)
    model = result.model
    for name in ("left_axis_x_mm", "right_angle_scale"):
        assert not model.parameters[name].identifiable and model.parameters[name].sigma is None
        assert "holds toe_in" in model.parameters[name].note
    assert model.parameters["slide_backlash_mm"].identifiable  # revisited from both sides
    assert model.parameters["slide_scale"].value == pytest.approx(1.0 + LAB.slide.scale_error, abs=5e-5)
    truth = kinematic_parameters(LAB, model.reference_baseline_mm)
    free = [n for n in NAMES if model.parameters[n].identifiable]
    assert len(free) == 10  # slide direction and scale, the right camera's pose, the slide's backlash
    chi2 = sum(((model.parameters[n].value - truth[n]) / model.parameters[n].sigma) ** 2 for n in free)
    assert chi2 < CHI2_999[10]
    assert predict(model, {"baseline_mm": 100.0, "toe_in_left_deg": 5.0, "toe_in_right_deg": 0.0}).extrapolated == [
        "toe_in_left_deg"]


def test_a_design_too_thin_to_fit_is_a_clear_error():
    with pytest.raises(ValueError, match="needs calibration views"):
        fit_kinematics([], BOARD.object_points, CAMERA.image_size)
    lone = ConfigurationViews(axes={"baseline_mm": 100.0, "toe_in_left_deg": 0.0, "toe_in_right_deg": 0.0},
                              approach={}, views=[(None, None)])
    with pytest.raises(ValueError, match="at least 3 views seen by both cameras"):
        fit_kinematics([lone], BOARD.object_points, CAMERA.image_size)


@pytest.mark.slow
def test_the_predicted_sigma_matches_the_scatter_of_repeated_fits():
    """12 fits on independent noise and landings: the scatter of a prediction against the sigma each claims."""
    design = kinematic_design((50.0, 250.0), (0.0, 20.0))
    values = {"baseline_mm": 110.0, "toe_in_left_deg": 7.0, "toe_in_right_deg": 13.0}
    approach = {"baseline_mm": 1, "toe_in_left_deg": 1, "toe_in_right_deg": 1}
    predicted, claimed = [], []
    for seed in range(12):
        result, _, _ = fit(design, n_views=5, pixel_sigma=0.1, seed=100 + seed)
        prediction = predict(result.model, values, approach)
        predicted.append([prediction.structure[k] for k in ("baseline_mm", "alpha_left_deg", "alpha_right_deg")])
        # The parameters' part of the claimed sigma (the landing at this configuration is not in the scatter).
        model = result.model.model_copy(update={"repeatability_mm": 0.0, "repeatability_left_deg": 0.0,
                                                "repeatability_right_deg": 0.0})
        p = predict(model, values, approach)
        claimed.append([p.structure_sigma[k] for k in ("baseline_mm", "alpha_left_deg", "alpha_right_deg")])
    scatter = np.std(predicted, axis=0, ddof=1)
    ratio = scatter / np.mean(claimed, axis=0)
    # 12 samples: the std is known to about +-20 %; allow for it.
    assert np.all((ratio > 0.55) & (ratio < 1.6)), ratio


def test_the_fit_keeps_its_residuals_binned_over_the_image(lab_fit):
    """What the budget reads the corner error beyond noise from (as a per-config calibration's residual map): every
    used corner binned, and for independent noise (this fit's) bin means within their standard errors of zero."""
    result = lab_fit[0]
    maps = result.model.residual_map_objects()
    assert set(maps) == {"left", "right"}
    assert sum(float(m.count.sum()) for m in maps.values()) == result.model.fit.n_observations
    for m in maps.values():
        full = m.count >= 8
        z = m.mean[full] / np.maximum(m.standard_error()[full], 1e-12)
        assert np.sqrt(np.mean(z**2)) < 1.5  # 1 expected for zero-mean noise
        assert math.sqrt(float(m.sumsq.sum()) / (2 * m.count.sum())) == pytest.approx(
            result.model.fit.pixel_sigma_px, rel=0.2)
