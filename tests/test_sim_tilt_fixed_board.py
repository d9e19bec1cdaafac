"""The fixed-board fit on the rendered lab bench that tilts (issue 25): grblHAL's A and B drive the tilts through
the real serial driver, the bench renders one board that stays put from where the heads' tilt joints put the
cameras, the corners are found by stereo_bench.vision.detect and fitted in one adjustment, and the fitted model
predicts R, T at configurations outside the design, non-zero tilts included, against the bench's own truth.

Half resolution and the lab profile without its corner jitter (as tests/test_kinematics_lab.py, for the same
reason: the bounds are the fit's precision on the bench's image noise, JPEG, blur and the lens's unmodelled term).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.rig.rig import GrblRig
from drivers.sim.bench import BenchSimulator
from drivers.sim.mechanics import TILTS, kinematic_parameters
from stereo_bench.kinematics import ConfigurationViews, approach_directions, predict
from stereo_bench.kinematics.fixed_board import fit_fixed_board, fixed_board_design, identifiability_table
from stereo_bench.kinematics.model import _rvec
from stereo_bench.vision.detect import detect
from tests.test_kinematics_fixed_board import BOARD, T_BOARD
from tests.test_kinematics_fixed_board_tilt import OFF_DESIGN
from tests.test_kinematics_lab import PROFILE, SETTLE_S, SIZE, TIME_SCALE, _camera
from tests.test_sim_tilt import _tilt_config

pytestmark = pytest.mark.slow

#: Not in the design (its levels: B 60/120/180/240, toe-ins 0/4.3/8.7/13, tilts -5/0/5), inside its span.
UNSEEN = [*OFF_DESIGN[:2], {"baseline_mm": 150.0, "toe_in_left_deg": 10.0, "toe_in_right_deg": 10.0,
                              "tilt_left_deg": 0.0, "tilt_right_deg": 0.0}]


def _detections(bench):
    images = [bench.render(side)[0] for side in ("left", "right")]
    return tuple(detect(image, BOARD) for image in images)


@pytest.fixture(scope="module")
def session():
    config = _tilt_config()
    with BenchSimulator(rig_config=config, time_scale=TIME_SCALE, profile=PROFILE, seed=7, left=_camera("left"),
                        right=_camera("right")) as bench:
        bench.warm_up(BOARD)
        with GrblRig(bench.tty_path, config) as rig:
            home = rig.home()
            previous = {q: getattr(home, q) for q in ("baseline_mm", "toe_in_left_deg", "toe_in_right_deg", *TILTS)}
            approach = rig.homing_approach()
            assert set(TILTS) <= set(approach)
            bench.show(BOARD, T_BOARD, seed=1)  # placed once; it stays
            configurations = []
            design = fixed_board_design((60.0, 240.0), (0.0, 13.0), tilt_ranges_deg=dict.fromkeys(TILTS, (0.0, 0.0)))
            for k, visit in enumerate(design):
                rig.move_to(**visit.axes()).wait()
                bench.clock.advance(SETTLE_S)
                approach = approach_directions(previous, visit.axes(), approach)
                previous = visit.axes()
                bench.show(BOARD, T_BOARD, seed=10 + k)  # the same board, a new noise stream
                configurations.append(ConfigurationViews(visit.axes(), dict(approach), [_detections(bench)]))
            # The lenses as their data sheet has them (the bench's true lenses add a term the 5-coefficient model
            # cannot follow; k3 is held, so starting from their k3 would hold a wrong one).
            left, right = _camera("left"), _camera("right")
            intrinsics = (np.asarray(left.K), np.asarray(left.dist).ravel()[:5].reshape(1, 5), np.asarray(right.K),
                          np.asarray(right.dist).ravel()[:5].reshape(1, 5))
            fit = fit_fixed_board(configurations, BOARD.object_points, SIZE, intrinsics=intrinsics,
                                  repeatability_mm=PROFILE.slide.repeatability_mm,
                                  repeatability_left_deg=PROFILE.left_head.repeatability_deg,
                                  repeatability_right_deg=PROFILE.right_head.repeatability_deg,
                                  repeatability_tilt_left_deg=PROFILE.left_head.tilt_repeatability_deg,
                                  repeatability_tilt_right_deg=PROFILE.right_head.tilt_repeatability_deg)
            unseen = []
            for axes in UNSEEN:
                rig.move_to(**axes).wait()
                bench.clock.advance(SETTLE_S)
                approach = approach_directions(previous, axes, approach)
                previous = dict(axes)
                unseen.append((axes, dict(approach), bench.truth_without_landing()))
    return fit, unseen


def test_the_fit_on_the_rendered_tilting_bench_identifies_every_joint_and_finds_the_lab_build(session):
    """All 34 parameters identified; the tilt joints' pivots (12 and 8 mm off the lens on the lab build) within
    1 mm and 4 of their sigma, their directions and scales within 4 sigma (measured: within 2.7 sigma, every one of
    the 34); the residual at the image noise (0.047 px RMS)."""
    fit, _ = session
    model = fit.model
    assert all(r.identified for r in fit.identifiability), identifiability_table(fit.identifiability)
    truth = kinematic_parameters(PROFILE, model.reference_baseline_mm, tilting=TILTS)
    for side in ("left", "right"):
        for name in (f"{side}_tilt_axis_y_mm", f"{side}_tilt_axis_z_mm", f"{side}_tilt_scale",
                     f"{side}_tilt_axis_yaw_deg", f"{side}_tilt_axis_roll_deg"):
            value = model.parameters[name]
            assert abs(value.value - truth[name]) < 4.0 * value.sigma, (name, value, truth[name])
        for name in (f"{side}_tilt_axis_y_mm", f"{side}_tilt_axis_z_mm"):
            assert abs(model.parameters[name].value - truth[name]) < 1.0, name
    assert model.fit.rms_px < 0.1


@pytest.mark.parametrize("k", range(len(UNSEEN)))
def test_r_and_t_at_unseen_tilted_configurations_hold_within_their_stated_sigma(session, k):
    """The prediction from the reported axes against the bench's truth at rest there (landing errors left out:
    the rig's repeatability): rvec and T within 4 of the prediction's parameter sigma, and under 0.05 deg and
    0.15 mm (measured at the first two: 0.018 and 0.013 deg, 0.043 and 0.033 mm; the same bench and design
    without tilt: 0.005 deg and 0.079 / 0.077 mm at their tilt-0 twins: issue 25's 0.01 deg is met there, not
    with the tilt joints' 12 more parameters from the same 32 views)."""
    fit, unseen = session
    axes, approach, truth = unseen[k]
    prediction = predict(fit.model, axes, approach)
    R_true, T_true = np.asarray(truth["R"]), np.asarray(truth["T"])
    J = prediction.parameter_jacobian
    sigma = np.sqrt(np.diag(J @ fit.model.covariance_matrix() @ J.T))
    error = np.concatenate([_rvec(R_true @ prediction.R.T), prediction.T - T_true])
    assert np.all(np.abs(error) < 4.0 * sigma), (error, sigma)
    rotation = math.degrees(float(np.linalg.norm(error[:3])))
    assert rotation < 0.05 and float(np.linalg.norm(error[3:])) < 0.15, (rotation, error[3:])
