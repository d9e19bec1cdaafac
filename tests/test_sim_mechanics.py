"""Each imperfection of the simulated bench on its own, against the geometry it must produce."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.mechanics import (
    MoveHistory,
    camera_pose,
    kinematic_parameters,
    pair_state,
    ringing_deg,
)
from drivers.sim.profile import IDEAL, LAB, CameraErrors, SimProfile
from stereo_bench.geometry import RigPose, invert_transform, stereo_structure
from stereo_bench.kinematics import NAMES, chain


def only(section: str, **values) -> SimProfile:
    """The ideal profile with one section's values changed."""
    data = IDEAL.model_dump()
    sections = ("left_head", "right_head") if section == "heads" else (section,)
    for name in sections:
        data[name] = {**data[name], **values}
    return SimProfile.model_validate(data)


def axes(baseline_mm: float, toe_in_left_deg: float, toe_in_right_deg: float | None = None) -> dict:
    right = toe_in_left_deg if toe_in_right_deg is None else toe_in_right_deg
    return {"baseline_mm": baseline_mm, "toe_in_left_deg": toe_in_left_deg, "toe_in_right_deg": right}


def structure(profile: SimProfile, values: dict, **kwargs) -> dict:
    state = pair_state(profile, values, **kwargs)
    T = invert_transform(state.T_bench_right) @ state.T_bench_left
    return {**stereo_structure(T[:3, :3], T[:3, 3]), "R": T[:3, :3], "T": T[:3, 3]}


def rotation_between_deg(R1: np.ndarray, R2: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R1.T @ R2) - 1.0) / 2.0))))


@pytest.mark.parametrize("toe_in", [0.0, 5.0, 12.0, 25.0])
def test_the_ideal_mechanics_are_the_nominal_geometry(toe_in):
    state = pair_state(IDEAL, {**axes(120.0, toe_in, toe_in / 2), "tilt_left_deg": 3.0})
    pose = RigPose(120.0, 90.0 - toe_in, 90.0 - toe_in / 2, 3.0, 0.0)
    np.testing.assert_allclose(state.T_bench_left, pose.T_rig_left, atol=1e-12)
    np.testing.assert_allclose(state.T_bench_right, pose.T_rig_right, atol=1e-12)


@pytest.mark.parametrize("toe_in", [0.0, 10.0, 20.0, 30.0])
def test_a_pan_axis_behind_the_optical_centre_shortens_the_baseline_by_2_f_sin_t(toe_in):
    f = 22.0
    s = structure(only("heads", centre_forward_mm=f), axes(100.0, toe_in))
    assert s["baseline_mm"] == pytest.approx(100.0 - 2 * f * math.sin(math.radians(toe_in)), abs=1e-9)
    # The centres move along the baseline only: the angles stay the commanded ones.
    assert s["alpha_left_deg"] == pytest.approx(90.0 - toe_in, abs=1e-9)
    assert s["alpha_right_deg"] == pytest.approx(90.0 - toe_in, abs=1e-9)


@pytest.mark.parametrize("toe_in", [0.0, 15.0, 30.0])
def test_a_sideways_offset_moves_the_centre_on_a_circle_about_the_pan_axis(toe_in):
    side = 2.5
    s = structure(only("left_head", centre_sideways_mm=side), axes(100.0, toe_in))
    t = math.radians(toe_in)
    left = np.array([-50.0 + side * math.cos(t), 0.0, -side * math.sin(t)])
    assert s["baseline_mm"] == pytest.approx(float(np.linalg.norm(np.array([50.0, 0.0, 0.0]) - left)), abs=1e-9)


@pytest.mark.parametrize("toe_in", [0.0, 10.0, 25.0])
def test_a_tilted_pan_axis_turns_the_camera_out_of_plane_by_2_tau_sin_half_t(toe_in):
    tau = 0.4
    s = structure(only("left_head", axis_tilt_x_deg=tau), axes(100.0, toe_in))
    R_nominal, _ = RigPose(100.0, 90.0 - toe_in, 90.0 - toe_in).stereo_extrinsics()
    extra = rotation_between_deg(R_nominal, s["R"])
    expected = math.degrees(2 * math.radians(tau) * math.sin(math.radians(toe_in) / 2))
    assert extra == pytest.approx(expected, rel=0.01, abs=1e-9)


@pytest.mark.parametrize("toe_in", [0.0, 10.0, 20.0])
def test_a_camera_yawed_on_its_head_is_toed_in_by_that_much_more(toe_in):
    s = structure(only("left_head", mount_yaw_deg=0.3), axes(100.0, toe_in))
    assert s["alpha_left_deg"] == pytest.approx(90.0 - toe_in - 0.3, abs=1e-9)
    assert s["alpha_right_deg"] == pytest.approx(90.0 - toe_in, abs=1e-9)
    assert s["baseline_mm"] == pytest.approx(100.0, abs=1e-9)


def test_a_camera_rolled_on_its_head_keeps_alpha_and_baseline():
    s = structure(only("right_head", mount_roll_deg=0.5), axes(100.0, 0.0))
    assert s["rotation_deg"] == pytest.approx(0.5, abs=1e-9)
    assert (s["alpha_left_deg"], s["alpha_right_deg"], s["baseline_mm"]) == pytest.approx((90.0, 90.0, 100.0))


def test_a_slide_not_perpendicular_to_the_optical_axes_turns_the_baseline():
    psi = 0.25
    s = structure(only("slide", direction_yaw_deg=psi), axes(150.0, 0.0))
    assert s["baseline_mm"] == pytest.approx(150.0, abs=1e-9)
    assert s["alpha_left_deg"] == pytest.approx(90.0 + psi, abs=1e-9)
    assert s["alpha_right_deg"] == pytest.approx(90.0 - psi, abs=1e-9)


@pytest.mark.parametrize("baseline", [50.0, 150.0, 300.0])
def test_lead_screw_scale_and_zero_offset(baseline):
    s = structure(only("slide", scale_error=6e-4, zero_offset_mm=0.4), axes(baseline, 0.0))
    assert s["baseline_mm"] == pytest.approx(0.4 + 1.0006 * baseline, abs=1e-9)


@pytest.mark.parametrize("toe_in", [0.0, 10.0, 30.0])
def test_pan_angle_scale_and_zero(toe_in):
    s = structure(only("left_head", scale_error=2e-3, zero_offset_deg=0.15), axes(100.0, toe_in))
    assert s["alpha_left_deg"] == pytest.approx(90.0 - (0.15 + 1.002 * toe_in), abs=1e-9)


def test_backlash_depends_on_the_direction_of_approach():
    profile = only("slide", backlash_mm=0.04)
    profile = SimProfile.model_validate({**profile.model_dump(), "left_head": {"backlash_deg": 0.03}})
    seen = {}
    for start in (80.0, 120.0):  # reach B = 100 mm / toe-in 10 deg from below, then from above
        history = MoveHistory(profile)
        direction = 1 if start < 100.0 else -1
        history.moved(axes(100.0, 10.0), end_s=1.0, approach={"baseline_mm": direction, "toe_in_left_deg": direction})
        state = pair_state(profile, axes(100.0, 10.0), history=history)
        seen[start] = (state.separation_mm, state.pan_left_deg)
    assert seen[80.0] == pytest.approx((100.0 - 0.02, 10.0 - 0.015), abs=1e-12)  # trails the motor going up
    assert seen[120.0] == pytest.approx((100.0 + 0.02, 10.0 + 0.015), abs=1e-12)


def test_landing_errors_have_the_stated_scatter_are_seeded_and_differ_per_visit():
    profile = only("slide", repeatability_mm=0.003)

    def landings(seed: int) -> list[float]:
        history, out = MoveHistory(profile, seed=seed), []
        for visit in range(400):
            target = 100.0 if visit % 2 == 0 else 150.0
            history.moved(axes(target, 0.0), end_s=2.0 * visit, approach={"baseline_mm": 1 if target > 100 else -1})
            out.append(history.axes["baseline_mm"].landing)
        return out

    first = landings(seed=1)
    assert np.std(first) == pytest.approx(0.003, rel=0.12)  # 400 draws: the std is known to ~4 %
    assert first == landings(seed=1) and first != landings(seed=2)
    assert len(set(first[::2])) == 200  # every return to B = 100 lands somewhere new


def test_ringing_decays_and_is_stopped_by_friction():
    cams = CameraErrors(vibration_yaw_deg=0.02, vibration_frequency_hz=15.0, vibration_decay_s=0.08,
                        vibration_stop_deg=0.001)
    assert ringing_deg(cams, 0.02, -0.01) == (0.0, 0.0)  # before the move ends
    assert ringing_deg(cams, 0.02, 0.0)[0] == pytest.approx(0.02)
    for t in (0.05, 0.1, 0.2):
        assert abs(ringing_deg(cams, 0.02, t)[0]) <= 0.02 * math.exp(-t / 0.08) + 1e-15
    stop = 0.08 * math.log(0.02 / 0.001)  # 0.24 s
    assert ringing_deg(cams, 0.02, stop - 1e-3)[0] != 0.0
    assert ringing_deg(cams, 0.02, stop + 1e-3) == (0.0, 0.0)


def test_a_move_excites_ringing_of_the_heads_it_moved():
    profile = SimProfile(cameras=CameraErrors(vibration_yaw_deg=0.02, vibration_rock_deg=0.01))
    history = MoveHistory(profile)
    history.moved(axes(100.0, 5.0, 0.0), end_s=1.0, approach={"toe_in_left_deg": 1})  # only the left head moves
    state = pair_state(profile, axes(100.0, 5.0, 0.0), history=history, now_s=1.0)
    assert state.ringing_deg["left"] == pytest.approx(0.02) and state.ringing_deg["right"] == 0.0
    assert state.rock_deg == {"left": 0.0, "right": 0.0}  # rocking follows slide moves
    later = pair_state(profile, axes(100.0, 5.0, 0.0), history=history, now_s=1.3)
    assert later.ringing_deg == {"left": 0.0, "right": 0.0}


def test_the_mechanics_in_the_estimators_parametrisation_reproduce_the_simulated_pose():
    values = kinematic_parameters(LAB, 150.0)
    p = np.array([values[name] for name in NAMES])
    for b, tl, tr in [(150.0, 0.0, 0.0), (50.0, 20.0, 10.0), (250.0, 5.0, 25.0)]:
        state = pair_state(LAB, axes(b, tl, tr))
        np.testing.assert_allclose(chain(p, 150.0, b, tl, tr),
                                   invert_transform(state.T_bench_right) @ state.T_bench_left, atol=1e-9)


def test_camera_pose_rejects_an_unknown_side():
    with pytest.raises(ValueError, match="side must be"):
        camera_pose(LAB, "middle", separation_mm=100.0, pan_deg=0.0)


def test_axis_rotation_is_right_handed_about_each_axis():
    from stereo_bench.geometry import rotation_deg

    for axis, before, after in (("x", (0, 1, 0), (0, 0, 1)), ("y", (0, 0, 1), (1, 0, 0)), ("z", (1, 0, 0), (0, 1, 0))):
        R = rotation_deg(axis, 90.0)
        np.testing.assert_allclose(R @ np.array(before, float), after, atol=1e-15)
        np.testing.assert_allclose(R @ rotation_deg(axis, -90.0), np.eye(3), atol=1e-15)
    with pytest.raises(ValueError, match="'w'"):
        rotation_deg("w", 1.0)
