"""The simulated bench's tilt joint (issue 25 item 2): a rig config that maps the tilts to grblHAL's A and B axes
moves them through the real serial driver, and the heads' tilt joints put the cameras where their own errors say.

A rig without a tilt axis is the bench it was: the joint exists only where the rig drives the tilt.
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from drivers.rig.config import rig_config_from_dict
from drivers.rig.rig import GrblRig
from drivers.sim.bench import BenchSimulator
from drivers.sim.mechanics import (
    TILTS,
    MoveHistory,
    camera_pose,
    kinematic_parameters,
    pair_state,
    true_pan_deg,
    true_separation_mm,
    true_tilt_deg,
)
from drivers.sim.profile import IDEAL, LAB, PanHeadErrors
from stereo_bench.geometry import invert_transform

FAST = 50.0
#: grblHAL with the tilts on A and B: -20..20 deg (> 0 looks down), homing leaves them at -20 deg (machine -1).
TILT_RIG = '''[controller]
rx_buffer_size = 1024
[quantities.tilt_left_deg]
axis = "A"
offset = -21.0
scale = -1.0
min = -20
max = 20
[quantities.tilt_right_deg]
axis = "B"
offset = -21.0
scale = -1.0
min = -20
max = 20
'''
AXES = {"baseline_mm": 120.0, "toe_in_left_deg": 4.0, "toe_in_right_deg": 3.0}
NO_TILT_ERRORS = {name: 0.0 for name in PanHeadErrors.model_fields if name.startswith("tilt_")}


def _tilt_config():
    return rig_config_from_dict(tomllib.loads(TILT_RIG))


def _angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))


def test_an_ideal_tilt_joint_is_the_nominal_tilt_about_the_optical_centre():
    for side in ("left", "right"):
        for tilt in (-12.0, 0.0, 7.5):
            fixed = camera_pose(IDEAL, side, separation_mm=100.0, pan_deg=5.0, tilt_deg=tilt)
            joint = camera_pose(IDEAL, side, separation_mm=100.0, pan_deg=5.0, tilt_deg=tilt, tilt_joint=True)
            np.testing.assert_allclose(joint, fixed, atol=1e-12)


def test_without_a_driven_tilt_the_tilt_errors_do_nothing():
    """Bit for bit: the lab build's tilt-joint values change no pose of a rig whose tilt is fixed."""
    untilted = LAB.model_copy(update={"left_head": LAB.left_head.model_copy(update=NO_TILT_ERRORS),
                                      "right_head": LAB.right_head.model_copy(update=NO_TILT_ERRORS)})
    reported = {**AXES, "tilt_left_deg": 3.0, "tilt_right_deg": 3.0}
    for profile_history in (None, 7):
        histories = [None if profile_history is None else MoveHistory(p, profile_history) for p in (LAB, untilted)]
        for history in histories:
            if history is not None:
                history.moved(reported, end_s=1.0, approach={q: 1 for q in AXES})
        a = pair_state(LAB, reported, history=histories[0], now_s=1.05)
        b = pair_state(untilted, reported, history=histories[1], now_s=1.05)
        np.testing.assert_array_equal(a.T_bench_left, b.T_bench_left)
        np.testing.assert_array_equal(a.T_bench_right, b.T_bench_right)
        assert a.tilt_deg == {}


@pytest.mark.parametrize("side", ["left", "right"])
def test_the_lab_tilt_joint_turns_the_camera_about_its_own_axis_by_its_own_scale(side):
    """Between two commanded tilts the camera turns by (1 + scale) x the difference about one line: its direction
    and where it crosses the camera's x = 0 plane are the joint's (kinematic_parameters), ~12 mm behind and ~8 mm
    below the optical centre, and the optical centre moves on a circle about it."""
    head = LAB.head(side)
    separation = true_separation_mm(LAB.slide, 150.0)
    pan = true_pan_deg(head, 0.0)

    def pose(commanded: float) -> np.ndarray:
        return camera_pose(LAB, side, separation_mm=separation, pan_deg=pan, tilt_deg=true_tilt_deg(head, commanded),
                           tilt_joint=True)

    T0 = pose(0.0)
    T1 = pose(10.0)
    relative = invert_transform(T0) @ T1  # the camera at tilt 10 in its frame at tilt 0
    assert _angle_deg(relative[:3, :3]) == pytest.approx(10.0 * (1.0 + head.tilt_scale_error), abs=1e-9)
    truth = kinematic_parameters(LAB, 150.0, tilting=TILTS)
    w = np.array([relative[2, 1] - relative[1, 2], relative[0, 2] - relative[2, 0], relative[1, 0] - relative[0, 1]])
    direction = -w / np.linalg.norm(w)  # > 0 looks down: a turn about -x
    assert math.degrees(math.atan2(-direction[2], direction[0])) == pytest.approx(
        truth[f"{side}_tilt_axis_yaw_deg"], abs=1e-9)
    assert math.degrees(math.asin(direction[1])) == pytest.approx(truth[f"{side}_tilt_axis_roll_deg"], abs=1e-9)
    point = np.array([0.0, truth[f"{side}_tilt_axis_y_mm"], truth[f"{side}_tilt_axis_z_mm"]])
    np.testing.assert_allclose(relative[:3, :3] @ point + relative[:3, 3], point, atol=1e-9)  # a point of the axis
    assert point[1] == pytest.approx(head.tilt_centre_height_mm, abs=0.2)
    assert point[2] == pytest.approx(-head.tilt_centre_forward_mm, abs=0.2)
    moved = np.linalg.norm(T1[:3, 3] - T0[:3, 3])
    lever = math.hypot(head.tilt_centre_height_mm, head.tilt_centre_forward_mm)
    assert moved == pytest.approx(2 * lever * math.sin(math.radians(10.0 * (1 + head.tilt_scale_error)) / 2), rel=1e-3)


def test_the_grblhal_bench_moves_the_tilts_on_a_and_b_through_the_serial_driver():
    """The real driver against the emulated grblHAL (five axes): A and B go where the config maps the tilts, and
    the cameras turn by the joint's scale, zero and half its backlash: the same commanded tilt approached from
    above and from below lands the camera 0.02 deg (the lab backlash) apart, within the landing scatter."""
    config = _tilt_config()
    with BenchSimulator(rig_config=config, time_scale=FAST, profile=LAB, seed=3) as bench:
        assert bench.emulator.firmware == "grblhal" and bench.emulator.axes == "XYZAB"
        with GrblRig(bench.tty_path, config) as rig:
            rig.home()
            assert rig.read().tilt_left_deg == pytest.approx(-20.0)
            landed = {}
            for via in (-10.0, 12.0):  # reach 5 / -4 from below, then from above
                rig.move_to(**AXES, tilt_left_deg=via, tilt_right_deg=via).wait()
                reading = rig.move_to(tilt_left_deg=5.0, tilt_right_deg=-4.0).wait()
                assert (reading.tilt_left_deg, reading.tilt_right_deg) == pytest.approx((5.0, -4.0), abs=1e-9)
                assert reading.machine_position["A"] == pytest.approx(-26.0) and reading.machine_position["B"] == \
                    pytest.approx(-17.0)
                truth = bench.truth()
                landed[via] = truth["axes"]
                history = truth["axes"]["history"]
                assert history["tilt_left_deg"]["approach"] == (1 if via < 5.0 else -1)
    for side, commanded in (("left", 5.0), ("right", -4.0)):
        head = LAB.head(side)
        for via, axes in landed.items():
            approach = 1 if via < commanded else -1
            landing = axes["history"][f"tilt_{side}_deg"]["landing"]
            assert axes[f"tilt_{side}_deg"] == pytest.approx(
                true_tilt_deg(head, commanded, approach=approach, landing_deg=landing), abs=1e-12)
            assert abs(landing) < 5 * head.tilt_repeatability_deg
        gap = landed[12.0][f"tilt_{side}_deg"] - landed[-10.0][f"tilt_{side}_deg"]
        assert gap == pytest.approx(head.tilt_backlash_deg, abs=6 * head.tilt_repeatability_deg)


def test_a_bench_without_tilt_axes_keeps_grbl_and_three_axes():
    with BenchSimulator(time_scale=FAST, profile=LAB, seed=3) as bench:
        assert bench.emulator.firmware == "grbl" and bench.emulator.axes == "XYZ" and bench.tilting == ()
        assert set(bench.history.axes) == {"baseline_mm", "toe_in_left_deg", "toe_in_right_deg"}
