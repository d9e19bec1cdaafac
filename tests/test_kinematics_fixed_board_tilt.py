"""The fixed-board fit of a rig that drives its cameras' tilts (issue 25: grblHAL's A/B axes), on exact projections
through the simulator's own mechanics (drivers.sim.mechanics: the heads' tilt joints with the lab build's errors).

One board stands still while the rig moves through the fixed-board design with tilt positions; its corners are
projected exactly, or with seeded Gaussian noise and the lab's landing errors. The truth in the model's
parametrisation is ``kinematic_parameters(..., tilting=...)``, derived from the simulator's chain.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.mechanics import MOVED, TILTS, MoveHistory, kinematic_parameters, pair_state
from drivers.sim.profile import LAB
from stereo_bench.geometry import invert_transform
from stereo_bench.kinematics import ConfigurationViews, chain, predict
from stereo_bench.kinematics.fixed_board import (
    _chains,
    design_identifiability,
    fit_fixed_board,
    fixed_board_design,
    identifiability_table,
)
from stereo_bench.kinematics.model import model_axes, parameter_specs
from tests.test_kinematics_fixed_board import BOARD, CAMERA, T_BOARD, fixed_board_views

K, D = CAMERA.K, np.asarray(CAMERA.dist, float).ravel()[:5].reshape(1, 5)
BOTH = {"tilt_left_deg": (0.0, 0.0), "tilt_right_deg": (0.0, 0.0)}  # a campaign at tilt 0: widened to -5..5
EXACT = LAB.model_copy(update={
    "slide": LAB.slide.model_copy(update={"repeatability_mm": 0.0}),
    "left_head": LAB.left_head.model_copy(update={"repeatability_deg": 0.0, "tilt_repeatability_deg": 0.0}),
    "right_head": LAB.right_head.model_copy(update={"repeatability_deg": 0.0, "tilt_repeatability_deg": 0.0})})
CHI2_999 = {34: 65.25, 28: 56.89}  # 99.9 % quantiles of chi-square with that many degrees of freedom


def tilt_views(design, profile, tilts, *, noise_px: float, seed: int) -> list[ConfigurationViews]:
    """The design visited in order from home in front of the board, the cameras where the mechanics (with ``tilts``
    driven through the heads' joints) put them; one view per visit."""
    return fixed_board_views(design, profile, noise_px=noise_px, seed=seed, tilts=tuple(tilts))


def _fit(configurations, profile):
    return fit_fixed_board(configurations, BOARD.object_points, CAMERA.image_size, intrinsics=(K, D, K, D),
                           repeatability_mm=profile.slide.repeatability_mm,
                           repeatability_left_deg=profile.left_head.repeatability_deg,
                           repeatability_right_deg=profile.right_head.repeatability_deg,
                           repeatability_tilt_left_deg=profile.left_head.tilt_repeatability_deg,
                           repeatability_tilt_right_deg=profile.right_head.tilt_repeatability_deg)


def _design(tilt_ranges=BOTH):
    return fixed_board_design((60.0, 240.0), (0.0, 13.0), tilt_ranges_deg=tilt_ranges)


@pytest.fixture(scope="module")
def lab_fit():
    """The lab bench (landing errors on every axis, 0.1 px corner noise) through the tilting design."""
    return _fit(tilt_views(_design(), LAB, TILTS, noise_px=0.1, seed=2), LAB)


def test_the_design_steps_each_driven_tilt_up_and_down_at_every_slide_and_pan_position():
    plain, tilted = fixed_board_design((60.0, 240.0), (0.0, 13.0)), _design()
    assert [(d.baseline_mm, d.toe_in_left_deg, d.toe_in_right_deg) for d in tilted] == [
        (d.baseline_mm, d.toe_in_left_deg, d.toe_in_right_deg) for d in plain]  # the same 32 slide and pan visits
    assert all(set(d.axes()) == set(MOVED) for d in plain)  # no tilt on a rig that drives none
    for axis in TILTS:
        values = [d.axes()[axis] for d in tilted]
        assert sorted(set(values)) == [-5.0, 0.0, 5.0]  # tilt 0 widened to 10 deg about it
        steps = np.sign(np.diff(values))
        assert (steps > 0).any() and (steps < 0).any(), axis
        for b in {d.baseline_mm for d in tilted}:
            assert len({d.axes()[axis] for d in tilted if d.baseline_mm == b}) == 3, (axis, b)
    assert [d.tilt_left_deg for d in tilted[:4]] == [-5.0, 0.0, 5.0, 0.0]
    assert [d.tilt_right_deg for d in tilted[:4]] == [5.0, 0.0, -5.0, 0.0]  # half a period behind
    left_only = _design({"tilt_left_deg": (2.0, 14.0)})
    assert {d.tilt_left_deg for d in left_only} == {2.0, 8.0, 14.0} and {d.tilt_right_deg for d in left_only} == {None}
    with pytest.raises(ValueError, match="tilt_ranges_deg: tilt_deg not of"):
        fixed_board_design((60.0, 240.0), tilt_ranges_deg={"tilt_deg": (0.0, 1.0)})


def test_the_batched_chain_with_tilt_joints_is_the_model_chain():
    rng = np.random.default_rng(3)
    truth = kinematic_parameters(LAB, 150.0, tilting=TILTS)
    from stereo_bench.kinematics.model import vector_specs

    p = np.array([truth[s.name] for s in vector_specs(model_axes(TILTS))])
    b, tl, tr = rng.uniform(50, 250, 7), rng.uniform(-5, 20, 7), rng.uniform(-5, 20, 7)
    til, tir = rng.uniform(-15, 15, 7), rng.uniform(-15, 15, 7)
    _, T_R_L = _chains(p, 150.0, b, tl, tr, til, tir)
    for k in range(7):
        np.testing.assert_allclose(T_R_L[k], chain(p, 150.0, b[k], tl[k], tr[k], til[k], tir[k]), atol=1e-12)


def test_the_fit_recovers_the_noiseless_tilting_mechanics_to_1e_6():
    """Exact projections, exact landings: every parameter, the tilt joints' 12 with them, within 1e-6 (mm, deg, 1)."""
    fit = _fit(tilt_views(_design(), EXACT, TILTS, noise_px=0.0, seed=1), EXACT)
    truth = kinematic_parameters(EXACT, fit.model.reference_baseline_mm, tilting=TILTS)
    assert fit.model.tilts == TILTS and len(fit.model.parameters) == 34
    assert all(row.identified for row in fit.identifiability), identifiability_table(fit.identifiability)
    errors = {name: value.value - truth[name] for name, value in fit.model.parameters.items()}
    assert max(abs(e) for e in errors.values()) < 1e-6, errors
    assert fit.model.fit.rms_px < 1e-5 and fit.landing.shape == (32, 5)


def test_the_fit_with_noise_and_landings_holds_within_its_stated_covariance(lab_fit):
    """Each parameter within 4 of its sigma, and all 34 together within the 99.9 % chi-square of their covariance
    (the sum of the marginal z^2 is no chi-square: the parameters are correlated, and it was 68 here)."""
    model = lab_fit.model
    truth = kinematic_parameters(LAB, model.reference_baseline_mm, tilting=TILTS)
    z = {n: (v.value - truth[n]) / v.sigma for n, v in model.parameters.items()}
    assert max(abs(v) for v in z.values()) < 4.0, z
    error = np.array([model.parameters[n].value - truth[n] for n in model.covariance_names])
    assert len(error) == 34 and error @ np.linalg.solve(model.covariance_matrix(), error) < CHI2_999[34]
    assert 0.05 < lab_fit.model.fit.pixel_sigma_px < 0.15
    for side in ("left", "right"):  # the joints' offsets from the optical centres, found to a fraction of a mm
        assert lab_fit.model.parameters[f"{side}_tilt_axis_y_mm"].sigma < 0.5
        assert lab_fit.model.parameters[f"{side}_tilt_axis_z_mm"].sigma < 0.5


#: Off the design: a baseline and toe-ins between its levels, tilts between its levels (and one past its span).
OFF_DESIGN = [
    {"baseline_mm": 200.0, "toe_in_left_deg": 7.0, "toe_in_right_deg": 5.0, "tilt_left_deg": 3.5,
     "tilt_right_deg": -2.5},
    {"baseline_mm": 90.0, "toe_in_left_deg": 2.0, "toe_in_right_deg": 11.0, "tilt_left_deg": -1.5,
     "tilt_right_deg": 4.0},
    {"baseline_mm": 150.0, "toe_in_left_deg": 10.0, "toe_in_right_deg": 10.0, "tilt_left_deg": 7.0,
     "tilt_right_deg": 7.0},
]


@pytest.mark.parametrize("k", range(len(OFF_DESIGN)))
def test_r_and_t_at_an_off_design_configuration_with_tilt_hold_within_their_stated_sigma(lab_fit, k):
    """The lab bench's true R, T (the pair at rest after a move from below on every axis, without the landing
    error, which is the rig's repeatability) against the prediction from the reported axes: each of rvec and T
    within 4 of the prediction's own sigma (its parameter part). This small design (one view of a 9x6 board per
    visit, 0.1 px) predicts T to ~0.1 mm (sigma of T_z) with or without tilt: 0.20 mm and 0.043 deg off without tilt,
    0.17 mm and 0.046 deg with it, at the first configuration (seed 2): issue 25's 0.05 mm and 0.01 deg are the
    campaign design's target, not this one's. The bounds below are 2x those errors."""
    axes = OFF_DESIGN[k]
    history = MoveHistory(LAB.model_copy(update={
        "slide": LAB.slide.model_copy(update={"repeatability_mm": 0.0}),
        "left_head": LAB.left_head.model_copy(update={"repeatability_deg": 0.0, "tilt_repeatability_deg": 0.0}),
        "right_head": LAB.right_head.model_copy(update={"repeatability_deg": 0.0, "tilt_repeatability_deg": 0.0})}),
        0, quantities=MOVED + TILTS)
    history.moved(axes, end_s=0.0, approach={q: 1 for q in axes})
    state = pair_state(LAB, axes, history=history, tilting=TILTS)
    true = invert_transform(state.T_bench_right) @ state.T_bench_left
    prediction = predict(lab_fit.model, axes, {q: 1 for q in axes})
    rotation_deg = math.degrees(math.acos(min(1.0, (np.trace(prediction.R.T @ true[:3, :3]) - 1.0) / 2.0)))
    translation_mm = float(np.linalg.norm(prediction.T - true[:3, 3]))
    J, C = prediction.parameter_jacobian, lab_fit.model.covariance_matrix()
    sigma = np.sqrt(np.diag(J @ C @ J.T))
    from stereo_bench.kinematics.model import _rvec

    error = np.concatenate([_rvec(true[:3, :3] @ prediction.R.T), prediction.T - true[:3, 3]])
    assert np.all(np.abs(error) < 4.0 * sigma), (error, sigma)
    assert rotation_deg < 0.1 and translation_mm < 0.45, (rotation_deg, translation_mm)
    assert prediction.extrapolated == (["tilt_left_deg", "tilt_right_deg"] if k == 2 else [])


def test_a_rig_that_tilts_one_camera_has_that_joint_only():
    tilts = ("tilt_left_deg",)
    design = _design({"tilt_left_deg": (0.0, 0.0)})
    fit = _fit(tilt_views(design, EXACT, tilts, noise_px=0.0, seed=4), EXACT)
    names = {row.name for row in fit.identifiability}
    assert fit.model.axes == list(model_axes(tilts)) and "right_tilt_scale" not in fit.model.parameters
    assert {s.name for s in parameter_specs(fit.model.axes)} == set(fit.model.parameters) == names
    truth = kinematic_parameters(EXACT, fit.model.reference_baseline_mm, tilting=tilts)
    assert max(abs(v.value - truth[n]) for n, v in fit.model.parameters.items()) < 1e-6


def test_the_plans_table_with_tilt_says_what_the_fit_then_finds(lab_fit):
    design = _design()
    planned = design_identifiability(design, BOARD.object_points, T_BOARD, (K, D, K, D), pixel_sigma_px=0.1,
                                     repeatability_mm=LAB.slide.repeatability_mm,
                                     repeatability_deg=LAB.left_head.repeatability_deg)
    assert [r.name for r in planned] == [r.name for r in lab_fit.identifiability]
    assert [r.identified for r in planned] == [r.identified for r in lab_fit.identifiability]
    for a, b in zip(planned, lab_fit.identifiability, strict=True):
        assert a.sigma == pytest.approx(b.sigma, rel=0.35), (a, b)  # the nominal rig against the lab's
