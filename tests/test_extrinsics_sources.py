"""Extrinsics sources (kinematic, nominal, calibrated) and their uncertainty, against the simulator's mechanics.

The nominal geometry's covariance (the rig's stated tolerances) is checked against builds drawn from those
tolerances and put together by drivers.sim.mechanics (a separate implementation of the chain); the budgets
of every source against the scatter of their errors on the synthetic rig (tests/synthetic_mechanics.py: the
lab profile's mechanics, exact projections plus corner noise, no rendering), over 20 seeds x 5
configurations spanning B, Z and alpha.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from drivers.sim.mechanics import pair_state
from drivers.sim.profile import IDEAL, LAB, drawn_build
from stereo_bench.campaign.config import RigTolerances
from stereo_bench.campaign.sources import ApproachTracker, kinematic_source, nominal_source, reported_axes
from stereo_bench.geometry import invert_transform, stereo_structure
from stereo_bench.kinematics import (
    TOLERANCE_NAMES,
    load_model,
    model_from_toml,
    model_toml,
    nominal_covariance,
    nominal_extrinsics,
    save_model,
)
from stereo_bench.vision.calibrate import StereoCalibration
from tests.synthetic_mechanics import CAMERA, EXACT_BOARDS, SyntheticRig, fit_design, measure, rms

TOLERANCES = RigTolerances().sigmas()
CONFIGURATIONS = [(60.0, 400.0, 0.0), (110.0, 550.0, 9.0), (170.0, 700.0, 4.0), (140.0, 600.0, 12.0),
                  (240.0, 450.0, 13.0)]  # (B, Z, toe-in): the coverage script's
SEEDS = range(20)


def _rvec_t(R: np.ndarray, T: np.ndarray) -> np.ndarray:
    return np.concatenate([cv2.Rodrigues(np.asarray(R, float))[0].ravel(), np.asarray(T, float).ravel()])


def _true_pair(profile, baseline: float, toe_in: float) -> np.ndarray:
    state = pair_state(profile, {"baseline_mm": baseline, "toe_in_left_deg": toe_in, "toe_in_right_deg": toe_in})
    T_right_left = invert_transform(state.T_bench_right) @ state.T_bench_left
    return _rvec_t(T_right_left[:3, :3], T_right_left[:3, 3])


def test_the_ideal_geometry_is_the_chain_without_deviations_and_exact_tolerances_claim_nothing():
    zero = dict.fromkeys(TOLERANCE_NAMES, 0.0)
    assert np.array_equal(nominal_covariance(150.0, 80.0, 84.0, tolerances=zero), np.zeros((6, 6)))
    # The simulator's ideal bench is the nominal geometry, at any toe-in.
    for toe_in in (0.0, 12.0):
        assert np.allclose(_true_pair(IDEAL, 150.0, toe_in), _rvec_t(*nominal_extrinsics(150.0, 90 - toe_in,
                                                                                        90 - toe_in)), atol=1e-9)
    with pytest.raises(ValueError, match="missing"):
        nominal_covariance(150.0, tolerances={"yaw_deg": 0.3})


@pytest.mark.parametrize("toe_in", [0.0, 12.0])
def test_nominal_covariance_matches_the_scatter_of_builds_drawn_from_the_tolerances(toe_in):
    """Builds drawn from the stated tolerances and assembled by the simulator's mechanics (the optical
    centres 15-30 mm ahead of the pan axes: a bias the nominal geometry ignores): the RMS deviation of
    each of (rvec, T) from the nominal geometry equals the sigma nominal_covariance claims (within 15 %,
    400 builds: the standard error of an RMS is ~4 %)."""
    rng = np.random.default_rng(11)
    baseline = 150.0
    nominal = _rvec_t(*nominal_extrinsics(baseline, 90.0 - toe_in, 90.0 - toe_in))
    deviations = np.array([_true_pair(drawn_build(LAB, TOLERANCES, rng), baseline, toe_in) - nominal
                           for _ in range(400)])
    claimed = np.sqrt(np.diag(nominal_covariance(baseline, 90.0 - toe_in, 90.0 - toe_in, tolerances=TOLERANCES)))
    # The landing term (pan_repeat_deg: backlash and repeatability) is per move: the mechanics add it only with
    # a move history.
    no_landing = np.sqrt(np.diag(nominal_covariance(baseline, 90.0 - toe_in, 90.0 - toe_in,
                                                    tolerances={**TOLERANCES, "pan_repeat_deg": 0.0})))
    ratio = np.sqrt(np.mean(deviations**2, axis=0)) / no_landing
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio
    assert np.all(claimed >= no_landing)


def test_the_optical_baseline_uncertainty_grows_with_toe_in_as_the_centres_swing_about_the_pan_axes():
    """The centres stand f ~ 23 mm ahead of the pan axes: a toe-in t shortens the baseline by ~2 f sin t,
    which the nominal geometry ignores; its stated sigma says so."""
    sigma = {}
    for toe_in in (0.0, 8.0, 16.0):
        source = nominal_source(_intrinsics(), baseline_mm=150.0, alpha_left_deg=90.0 - toe_in,
                                alpha_right_deg=90.0 - toe_in, tilt_deg=0.0, tolerances=TOLERANCES,
                                board_scale=EXACT_BOARDS)
        sigma[toe_in] = source.structure_sigma["baseline_mm"]
    swing = 2.0 * TOLERANCES["centre_forward_mm"] * math.sin(math.radians(16.0))
    assert sigma[0.0] < sigma[8.0] < sigma[16.0]
    assert math.isclose(math.sqrt(sigma[16.0] ** 2 - sigma[0.0] ** 2), swing, rel_tol=0.1)
    # On the lab bench the true baseline at toe-in 16 is shorter than nominal by about that swing.
    true_baseline = stereo_structure(cv2.Rodrigues(_true_pair(LAB, 150.0, 16.0)[:3])[0],
                                     _true_pair(LAB, 150.0, 16.0)[3:])["baseline_mm"]
    lab_forward = 0.5 * (LAB.left_head.centre_forward_mm + LAB.right_head.centre_forward_mm)
    shortening = 150.0 - true_baseline - (150.0 - stereo_structure(
        cv2.Rodrigues(_true_pair(LAB, 150.0, 0.0)[:3])[0], _true_pair(LAB, 150.0, 0.0)[3:])["baseline_mm"])
    assert math.isclose(shortening, 2.0 * lab_forward * math.sin(math.radians(16.0)), rel_tol=0.1)


def _intrinsics() -> StereoCalibration:
    return StereoCalibration(K1=CAMERA.K, D1=np.asarray(CAMERA.dist, float).reshape(1, -1), K2=CAMERA.K,
                             D2=np.asarray(CAMERA.dist, float).reshape(1, -1), R=np.eye(3),
                             T=np.array([-1.0, 0.0, 0.0]), image_size=CAMERA.image_size)


def test_approach_directions_follow_every_reported_position_from_home():
    tracker = ApproachTracker()
    assert tracker.reached({"baseline_mm": 349.0, "toe_in_left_deg": 1.0, "toe_in_right_deg": 1.0}) == \
        {"baseline_mm": 0, "toe_in_left_deg": 0, "toe_in_right_deg": 0}  # homed: nothing known yet
    assert tracker.reached({"baseline_mm": 100.0, "toe_in_left_deg": 5.0, "toe_in_right_deg": 1.0}) == \
        {"baseline_mm": -1, "toe_in_left_deg": 1, "toe_in_right_deg": 0}
    # An axis that does not move keeps the direction it last arrived from.
    assert tracker.reached({"baseline_mm": 150.0, "toe_in_left_deg": 5.0, "toe_in_right_deg": 0.0}) == \
        {"baseline_mm": 1, "toe_in_left_deg": 1, "toe_in_right_deg": -1}

    class Reading:
        baseline_mm, toe_in_left_deg, toe_in_right_deg = 100.004, None, 3.0

    assert reported_axes(Reading(), {"baseline_mm": 100.0, "toe_in_left_deg": 2.0, "toe_in_right_deg": 3.0}) == \
        {"baseline_mm": 100.004, "toe_in_left_deg": 2.0, "toe_in_right_deg": 3.0}


# --------------------------------------------------------------------------------------------------
# Coverage on the synthetic lab bench


@pytest.fixture(scope="module")
def lab_runs():
    """Per seed: the kinematic model fitted to the design (2 views per visit), then the 5 configurations
    measured with the kinematic source (the per-config budget's coverage on synthetic corners is
    tests/test_uncertainty.py's; on rendered frames scripts/coverage_campaign.py's)."""
    runs = []
    for seed in SEEDS:
        rig = SyntheticRig(LAB, seed)
        model = fit_design(rig, ((60.0, 240.0), (0.0, 13.0)), views=2)
        runs.append({"model": model, "results": [measure(rig, model, c, frames=2, tolerances=TOLERANCES,
                                                         nominal=False) for c in CONFIGURATIONS]})
    return runs


def _z(runs, source: str) -> np.ndarray:
    return np.array([result[source]["z"] for run in runs for result in run["results"]])


def _within_U(runs, source: str) -> float:
    return float(np.mean([abs(result[source]["error_mm"]) <= result[source]["budget"].expanded
                          for run in runs for result in run["results"]]))


@pytest.mark.slow
def test_kinematic_budget_covers_its_errors_on_the_lab_mechanics(lab_runs):
    """Kinematic extrinsics at configurations not in the design (new moves: landing errors, backlash):
    (measured - true) / u_c has RMS in [0.7, 1.4] and >= 90 % of errors are within U."""
    z = _z(lab_runs, "kinematic")
    assert len(z) == 100
    assert 0.7 <= rms(z) <= 1.4, rms(z)
    assert _within_U(lab_runs, "kinematic") >= 0.9


@pytest.mark.slow
def test_kinematic_prediction_is_within_its_stated_sigma_of_the_true_structure(lab_runs):
    """The predicted optical baseline and alphas against the mechanics' truth, normalised by the sigma the
    prediction states (parameters, landing repeatability, backlash): RMS near 1, none beyond 4."""
    normalised = []
    for run in lab_runs:
        for configuration, result in zip(CONFIGURATIONS, run["results"], strict=True):
            kin = result["kinematic"]
            truth = stereo_structure(kin["R_true"], kin["T_true"])
            used = stereo_structure(kin["R"], kin["T"])
            baseline, _, toe_in = configuration
            sigma = kinematic_source(run["model"], {"baseline_mm": baseline, "toe_in_left_deg": toe_in,
                                                   "toe_in_right_deg": toe_in}, {}, EXACT_BOARDS).structure_sigma
            normalised += [(used[k] - truth[k]) / sigma[k] for k in ("baseline_mm", "alpha_left_deg",
                                                                    "alpha_right_deg")]
    normalised = np.array(normalised)
    assert 0.5 <= rms(normalised) <= 1.4, rms(normalised)
    assert np.max(np.abs(normalised)) < 4.0


@pytest.mark.slow
def test_nominal_budget_covers_builds_drawn_from_the_stated_tolerances():
    """Each seed a bench drawn from the stated tolerances (a sample of builds, as the tolerances describe
    them): nominal extrinsics' (measured - true) / u_c has RMS in [0.7, 1.4], >= 90 % within U."""
    z, within = [], []
    for seed in SEEDS:
        rng = np.random.default_rng([seed, 5])
        rig = SyntheticRig(drawn_build(LAB, TOLERANCES, rng), seed)
        intrinsics = None  # one calibration at the first configuration, as nominal mode does
        for configuration in CONFIGURATIONS:
            results = measure(rig, None, configuration, frames=2, tolerances=TOLERANCES, intrinsics=intrinsics,
                              calibration_views=0 if intrinsics is not None else 6)
            intrinsics = intrinsics or results["calibrated"]["calib"]
            z.append(results["nominal"]["z"])
            within.append(abs(results["nominal"]["error_mm"]) <= results["nominal"]["budget"].expanded)
    assert 0.7 <= rms(z) <= 1.4, rms(z)
    assert np.mean(within) >= 0.9


# --------------------------------------------------------------------------------------------------
# The model file


def test_the_model_file_keeps_the_intrinsics_covariance_and_reads_files_without_it(tmp_path, lab_runs):
    model = lab_runs[0]["model"]
    assert len(model.intrinsics_covariance_names) == 16 and model.intrinsics_covariance_matrix().shape == (16, 16)
    assert model.cross_covariance_matrix().shape == (16, len(model.covariance_names))
    assert np.all(np.diag(model.intrinsics_covariance_matrix()) > 0)
    path = save_model(model, tmp_path / "kinematic_model.toml")
    again = load_model(path)
    assert model_toml(again) == path.read_text()
    assert again.intrinsics_covariance == model.intrinsics_covariance
    assert again.cross_covariance == model.cross_covariance
    # A file written before these keys existed still loads; the calibration component is then unknown.
    older = model_from_toml(model_toml(model.model_copy(update={
        "intrinsics_covariance_names": [], "intrinsics_covariance": [], "cross_covariance": [],
        "pixel_locking_px": None})))
    assert older.intrinsics_covariance_matrix() is None
    source = kinematic_source(older, {"baseline_mm": 150.0, "toe_in_left_deg": 5.0, "toe_in_right_deg": 5.0},
                              {}, EXACT_BOARDS)
    assert source.calib.covariance is None and "no intrinsics covariance" in source.calib.covariance_note


def test_board_scale_uncertainty_defaults_by_role_and_states_the_lab_print():
    """The measured target is a print (+-0.1 %), the calibration board a certified reference: the budget's target
    component takes each board's own default unless the config states it; the lab bench's print (0.08 % large)
    lies within two of its stated standard uncertainties."""
    from stereo_bench.campaign.config import load_preset
    from stereo_bench.campaign.execute import runner_options

    config = load_preset("paper-exp1")
    scale = runner_options(config).board_scale
    assert scale.target_u_rel == pytest.approx(0.001 / math.sqrt(3.0))
    assert scale.calibration_board_u_rel == pytest.approx(1e-4)
    assert LAB.target.print_scale_error <= 2.0 * scale.target_u_rel
    stated = config.model_copy(update={"target": config.target.model_copy(update={"scale_u_rel": 2e-5})})
    assert runner_options(stated).board_scale.target_u_rel == 2e-5
