"""Rig configuration (pure) and the rig in physical units (GrblRig against the pty emulator)."""

from __future__ import annotations

import json
import threading
import time

import pytest

from drivers.rig import GrblAlarm, GrblRig, Rig, RigError
from drivers.rig.config import (
    LimitError,
    MachineSpaceError,
    MoveRequestError,
    RigConfig,
    RigConfigError,
    check_limits,
    load_rig_config,
    plan_move,
    rig_config_from_dict,
    to_machine,
    to_physical,
)
from drivers.rig.rig import manual_instruction, physical_request
from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.firmware import AxisSpec, axis_specs_for_travel
from stereo_bench.campaign.operator import OperatorDesk, SimulatedOperator, move_and_ask
from stereo_bench.geometry import RigPose

FAST = 50.0

SIX_AXIS_TOML = """
[controller]
rx_buffer_size = 1024
move_timeout_s = 20

# Grbl's machine space is [-$13x, 0] once homed: every mapping lands there.
[quantities.baseline_mm]
axis = "X"
offset = -310.0        # B = 310 mm at the homing switch
scale = 1.0
min = 40.0
max = 300.0
feed_per_min = 2400

[quantities.toe_in_left_deg]
axis = "Y"
scale = -1.0           # toe-in grows away from the switch
min = 0
max = 30

[quantities.toe_in_right_deg]
axis = "Z"
scale = 1.0            # the right head turns the other way: its switch is at toe-in 45
offset = -45.0
min = 0
max = 30

[quantities.tilt_left_deg]
axis = "A"
offset = -10.0
min = -10
max = 10

[quantities.tilt_right_deg]
axis = "B"
offset = -10.0
min = -10
max = 10

[quantities.target_distance_mm]
axis = "C"
offset = -1700.0
min = 200
max = 1500
"""


def _write(tmp_path, text: str):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------------------------- config


def test_default_mapping_is_grbls_machine_space_one_pull_off_inside():
    # A stock Grbl 1.1h homes to its switches and counts negative from them: [-$13x, 0] (limits.c). The default
    # mapping keeps one pull-off ($27 = 1) off both ends ($130=350, $131=$132=90), so no target trips a switch
    # with hard limits on; homing (-$27) leaves the heads parallel.
    config = RigConfig()
    assert config.driven == {"baseline_mm": "X", "toe_in_left_deg": "Y", "toe_in_right_deg": "Z"}
    assert config.axes == "XYZ"
    assert config.machine_travel() == {"X": (-349.0, -1.0), "Y": (-89.0, -1.0), "Z": (-89.0, -1.0)}
    assert to_machine(config, {"baseline_mm": 349.0, "toe_in_left_deg": 0.0}) == {"X": -1.0, "Y": -1.0}
    assert to_physical(config, {"X": -250.0, "Y": -6.0, "Z": -1.0}) == {
        "baseline_mm": 100.0, "toe_in_left_deg": 5.0, "toe_in_right_deg": 0.0}
    assert config.quantities["tilt_left_deg"].axis == "fixed" and config.quantities["tilt_left_deg"].value == 0.0
    assert config.quantities["target_distance_mm"].axis == "manual"


def test_load_six_axis_toml(tmp_path):
    config = load_rig_config(_write(tmp_path, SIX_AXIS_TOML))
    assert config.axes == "XYZABC"
    assert config.controller.rx_buffer_size == 1024
    assert config.machine_travel()["Z"] == (-45.0, -15.0)
    assert config.axis_feeds_per_min() == {"X": 2400.0, "Y": None, "Z": None, "A": None, "B": None, "C": None}


def test_partial_file_keeps_the_other_defaults(tmp_path):
    config = load_rig_config(_write(tmp_path, '[quantities.baseline_mm]\naxis = "X"\nmin = 50\nmax = 250\n'))
    assert config.quantities["baseline_mm"].max == 250.0
    assert config.quantities["toe_in_left_deg"].axis == "Y"
    assert config.quantities["target_distance_mm"].axis == "manual"


@pytest.mark.parametrize(("text", "expected"), [
    ('[quantities.baseline_mm]\naxis = "X"\nmin = 0\nmax = "far"\n', r"quantities\.baseline_mm\.max"),
    ('[quantities.baseline_mm]\naxis = "Q"\nmin = 0\nmax = 1\n', r"quantities\.baseline_mm\.axis"),
    ('[quantities.baseline_mm]\naxis = "X"\nmin = 0\nmax = 1\nspeed = 3\n', r"quantities\.baseline_mm\.speed"),
    ('[quantities.baseline_mm]\naxis = "X"\n', r"quantities\.baseline_mm.*needs soft limits"),
    ('[quantities.baseline_mm]\naxis = "X"\nmin = 5\nmax = 1\n', r"min \(5\.0\) is greater than max"),
    ('[quantities.baseline_mm]\naxis = "X"\nmin = 0\nmax = 1\nscale = 0\n', r"scale must not be 0"),
    ('[quantities.tilt_left_deg]\naxis = "fixed"\n', r"tilt_left_deg.*needs its value"),
    ('[quantities.baseline_mm]\naxis = "Y"\nmin = 0\nmax = 1\n', r"axis Y drives both"),
    ('[quantities.baseline]\naxis = "X"\nmin = 0\nmax = 1\n', r"unknown quantity 'baseline'"),
    ('[controller]\nbaudrate = -5\n', r"controller\.baudrate"),
    ('[quantities.baseline_mm\naxis = "X"\n', r"invalid TOML"),
])
def test_errors_name_the_file_and_the_field(tmp_path, text, expected):
    path = _write(tmp_path, text)
    with pytest.raises(RigConfigError, match=expected) as info:
        load_rig_config(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(RigConfigError, match="no such rig configuration file"):
        load_rig_config(tmp_path / "nope.toml")


def test_physical_machine_round_trip_with_offset_and_negative_scale():
    config = rig_config_from_dict({"quantities": {
        "baseline_mm": {"axis": "X", "offset": 10.0, "scale": 2.0, "min": 0, "max": 100},
        "toe_in_right_deg": {"axis": "Z", "offset": 45.0, "scale": -1.0, "min": 0, "max": 30},
    }})
    physical = {"baseline_mm": 25.0, "toe_in_left_deg": 3.0, "toe_in_right_deg": 7.5, "tilt_left_deg": 0.0}
    machine = to_machine(config, physical)
    assert machine == {"X": 60.0, "Y": -4.0, "Z": 37.5}  # Y: the default mapping, toe-in 0 at Y = -1
    back = to_physical(config, machine)
    assert back == {"baseline_mm": 25.0, "toe_in_left_deg": 3.0, "toe_in_right_deg": 7.5}


def test_limits_name_every_violation():
    config = RigConfig()
    check_limits(config, {"baseline_mm": 349.0, "toe_in_left_deg": 0.0})
    with pytest.raises(LimitError) as info:
        check_limits(config, {"baseline_mm": 350.0, "toe_in_left_deg": -1.0, "toe_in_right_deg": 10.0})
    assert len(info.value.violations) == 2
    assert "baseline_mm = 350 outside [1, 349]" in str(info.value)
    assert "toe_in_left_deg = -1 outside [0, 88]" in str(info.value)


def test_plan_move_splits_driven_and_manual_and_refuses_fixed_changes():
    config = RigConfig()
    plan = plan_move(config, physical_request(baseline_mm=120.0, alpha_left_deg=85.0, alpha_right_deg=80.0,
                                              tilt_left_deg=0.0, target_distance_mm=400.0))
    assert plan.machine_targets == {"X": -230.0, "Y": -6.0, "Z": -11.0}
    assert plan.manual == {"target_distance_mm": 400.0}
    with pytest.raises(MoveRequestError, match="tilt_left_deg is fixed at 0"):
        plan_move(config, {"tilt_left_deg": 2.0})
    with pytest.raises(MoveRequestError, match="unknown quantity"):
        plan_move(config, {"baseline": 2.0})
    with pytest.raises(MoveRequestError, match="not both"):
        physical_request(toe_in_left_deg=1.0, alpha_left_deg=89.0)
    with pytest.raises(LimitError):
        plan_move(config, {"toe_in_left_deg": float("nan")})


def test_manual_instructions():
    assert manual_instruction("target_distance_mm", 400.0) == "move the target to Z = 400 mm, then press Enter"
    assert "alpha 85 deg" in manual_instruction("toe_in_left_deg", 5.0)


# ---------------------------------------------------------------------------------------------- GrblRig


@pytest.fixture
def emulator():
    with GrblEmulator(time_scale=FAST) as emu:
        yield emu


def _rig(port, config=None, **kwargs) -> GrblRig:
    return GrblRig(port, config, connect_timeout_s=3.0, ok_grace_s=0.2, poll_interval_s=0.02, **kwargs)


def test_grbl_rig_moves_in_physical_units(emulator):
    operator = SimulatedOperator()  # the manual quantities go to the operators through a desk, as in a campaign
    desk = OperatorDesk([operator])
    with _rig(emulator.tty_path) as rig:
        prompts = operator.prompts
        assert isinstance(rig, Rig)
        rig.home(timeout_s=5.0)
        reading = move_and_ask(rig, desk, baseline_mm=120.0, alpha_left_deg=85.0, alpha_right_deg=84.0,
                               target_distance_mm=400.0)
        assert reading.state == "Idle"
        assert reading.baseline_mm == 120.0
        assert reading.toe_in_left_deg == 5.0 and reading.alpha_left_deg == 85.0
        assert reading.toe_in_right_deg == 6.0 and reading.alpha_right_deg == 84.0
        assert reading.tilt_left_deg == 0.0 and reading.sources["tilt_left_deg"] == "fixed"
        assert reading.target_distance_mm == 400.0 and reading.sources["target_distance_mm"] == "operator"
        assert reading.machine_position == {"X": -230.0, "Y": -6.0, "Z": -7.0} == emulator.machine_position()
        assert [p.message for p in prompts] == ["move the target to Z = 400 mm, then press Enter"]
        # Same target again: nothing for the operator to do.
        move_and_ask(rig, desk, target_distance_mm=400.0, baseline_mm=100.0)
        assert len(prompts) == 1
        data = rig.read().to_dict()
        for key in ("state", "baseline_mm", "toe_in_left_deg", "toe_in_right_deg", "alpha_left_deg",
                    "alpha_right_deg", "machine_position", "timestamp"):
            assert key in data


def test_refused_moves_send_nothing(emulator):
    with _rig(emulator.tty_path) as rig:
        rig.home(timeout_s=5.0)
        received = list(emulator.lines_received)
        with pytest.raises(LimitError, match="baseline_mm = 400"):
            rig.move_to(baseline_mm=400.0).wait()
        with pytest.raises(MoveRequestError, match="fixed"):
            rig.move_to(tilt_left_deg=5.0).wait()
        with pytest.raises(MoveRequestError, match="no operator prompt"):
            rig.move_to(baseline_mm=10.0, target_distance_mm=500.0).wait()
        assert list(emulator.lines_received) == received
        assert emulator.machine_position()["X"] == -1.0


def test_move_to_pose_from_geometry(emulator):
    with _rig(emulator.tty_path) as rig:
        rig.home(timeout_s=5.0)
        reading = rig.move_to_pose(RigPose.symmetric(150.0, alpha_deg=82.5)).wait()
        assert reading.baseline_mm == 150.0 and reading.alpha_left_deg == reading.alpha_right_deg == 82.5


def test_six_axis_mapping_offsets_scales_and_feeds(tmp_path):
    config = load_rig_config(_write(tmp_path, SIX_AXIS_TOML))
    specs, force_set_origin = axis_specs_for_travel(config.machine_travel())
    assert not force_set_origin and specs["X"].max_travel == 270.0 and specs["C"].max_travel == 1500.0
    with GrblEmulator(time_scale=FAST, axes="XYZABC", axis_specs=specs, firmware="grblhal") as emu:
        with _rig(emu.tty_path, config) as rig:
            assert rig.warnings == []
            rig.home(timeout_s=5.0)
            reading = rig.move_to(baseline_mm=100.0, toe_in_left_deg=4.0, toe_in_right_deg=4.0, tilt_left_deg=-2.0,
                                  tilt_right_deg=3.0, target_distance_mm=600.0).wait()
            assert emu.machine_position() == {"X": -210.0, "Y": -4.0, "Z": -41.0, "A": -12.0, "B": -7.0,
                                              "C": -1100.0}
            assert reading.baseline_mm == 100.0 and reading.toe_in_right_deg == 4.0
            assert reading.tilt_right_deg == 3.0 and reading.target_distance_mm == 600.0
            assert reading.sources["target_distance_mm"] == "controller axis C"
            # A baseline-only move runs at the configured feed (a G1, not a rapid).
            rig.move_to(baseline_mm=200.0).wait()
            assert emu.lines_received[-2] == "G21 G90 G53 G1 X-110.000 F2400.0"


def test_config_axis_missing_on_the_controller(tmp_path):
    config = load_rig_config(_write(tmp_path, SIX_AXIS_TOML))
    with GrblEmulator(time_scale=FAST) as emu:  # a 3-axis board
        rig = _rig(emu.tty_path, config)
        with pytest.raises(RigError, match="drives axis A, B, C but the controller .* reports only X, Y, Z"):
            rig.open()
        assert not rig.controller.is_open


# ---------------------------------------------------------------------------------------------- vs the controller

POSITIVE = {"quantities": {  # the mapping this project used to default to: every target positive
    "baseline_mm": {"axis": "X", "min": 0, "max": 350},
    "toe_in_left_deg": {"axis": "Y", "min": 0, "max": 90},
    "toe_in_right_deg": {"axis": "Z", "min": 0, "max": 90},
}}


def test_a_positive_mapping_is_warned_at_connect_and_its_moves_refused_before_sending(emulator):
    config = rig_config_from_dict(POSITIVE)
    with _rig(emulator.tty_path, config) as rig:
        warnings = rig.warnings
        assert len(warnings) == 3 and all("Grbl homes to 0 and counts negative" in w for w in warnings)
        assert "baseline_mm = 0..350 maps to X 0..350, but the controller's machine space is X -350..0" in warnings[0]
        rig.home(timeout_s=5.0)
        received = list(emulator.lines_received)
        with pytest.raises(MachineSpaceError, match=r"X=120 is outside the controller's machine space X -350..0 "
                                                    r"\(\$130=350; soft limits would halt it with ALARM:2\)"):
            rig.move_to(baseline_mm=120.0).wait()
        assert list(emulator.lines_received) == received and not emulator.halted  # no ALARM:2, nothing sent


#: The mapping this project defaulted to before: alpha = 90 deg and B = 350 mm exactly on the homing switches.
AT_THE_SWITCHES = {"quantities": {
    "baseline_mm": {"axis": "X", "offset": -350, "min": 0, "max": 350},
    "toe_in_left_deg": {"axis": "Y", "scale": -1.0, "min": 0, "max": 90},
    "toe_in_right_deg": {"axis": "Z", "scale": -1.0, "min": 0, "max": 90},
}}


def test_with_hard_limits_a_mapping_onto_the_switches_is_warned_and_trips_alarm_1():
    # limits.c: with $21=1 a target where the homing switch closes halts the controller with ALARM:1; the old
    # default mapping put the first parallel configuration there, and neither the driver nor the emulator said so.
    with GrblEmulator(time_scale=FAST, hard_limits=True) as emu, _rig(emu.tty_path,
                                                                      rig_config_from_dict(AT_THE_SWITCHES)) as rig:
        switch_warnings = [w for w in rig.warnings if "hard limits are on" in w]
        assert len(switch_warnings) == 1
        assert "baseline_mm = 350 mm maps to X0" in switch_warnings[0]
        assert "toe_in_left_deg = 0 deg maps to Y0" in switch_warnings[0] and "$27=1" in switch_warnings[0]
        rig.home(timeout_s=5.0)
        with pytest.raises(GrblAlarm, match="ALARM:1"):
            rig.move_to(baseline_mm=200.0, alpha_left_deg=90.0, alpha_right_deg=90.0).wait()


def test_with_hard_limits_the_default_mapping_stays_clear_of_the_switches():
    with GrblEmulator(time_scale=FAST, hard_limits=True) as emu, _rig(emu.tty_path) as rig:
        assert rig.warnings == []
        rig.home(timeout_s=5.0)
        for baseline, alpha in ((349.0, 90.0), (1.0, 2.0), (100.0, 90.0)):  # both ends of every range
            reading = rig.move_to(baseline_mm=baseline, alpha_left_deg=alpha, alpha_right_deg=alpha).wait()
            assert (reading.baseline_mm, reading.alpha_left_deg, reading.state) == (baseline, alpha, "Idle")
        assert not emu.halted


def test_a_mapping_reaching_past_the_travel_is_warned_and_only_those_moves_refused(emulator):
    config = rig_config_from_dict({"quantities": {"baseline_mm": {"axis": "X", "offset": -400, "min": 0, "max": 400}}})
    with _rig(emulator.tty_path, config) as rig:
        assert rig.warnings == ["baseline_mm = 0..400 maps to X -400..0, but the controller's machine space is "
                                "X -350..0 ($130=350): moves of baseline_mm beyond it will be refused"]
        rig.home(timeout_s=5.0)
        assert rig.move_to(baseline_mm=100.0).wait().machine_position["X"] == -300.0
        with pytest.raises(MachineSpaceError, match="X=-360 is outside"):
            rig.move_to(baseline_mm=40.0).wait()


def test_a_tolerance_finer_than_a_step_is_warned_and_a_step_used(emulator):
    fine = {"quantities": {"baseline_mm": {"axis": "X", "offset": -350, "min": 0, "max": 350, "tolerance": 0.001}}}
    with _rig(emulator.tty_path, rig_config_from_dict(fine)) as rig:
        assert rig.warnings == ["baseline_mm: tolerance 0.001 mm is finer than one step of axis X (0.004 mm at "
                                "$100=250): using one step"]
        rig.home(timeout_s=5.0)
        # X = -249.9985 is not on the 0.004 mm grid: the controller stops at -250.000 (0.0015 off).
        reading = rig.move_to(baseline_mm=100.0015).wait()
        assert reading.machine_position["X"] == -250.0


def test_homing_disabled_is_warned(tmp_path):
    with GrblEmulator(time_scale=FAST, homing_enabled=False) as emu, _rig(emu.tty_path) as rig:
        assert len(rig.warnings) == 1 and "homing is disabled ($22=0)" in rig.warnings[0]
        # No fixed machine frame: nothing is refused for lying outside one.
        assert rig.move_to(baseline_mm=300.0).wait().machine_position["X"] == -50.0


def test_controller_info_is_json_ready(emulator):
    with _rig(emulator.tty_path) as rig:
        info = json.loads(json.dumps(rig.controller_info()))
    for key in ("build", "options", "settings", "startup_lines", "rx_buffer_size", "boot_detected", "warnings"):
        assert key in info
    assert info["build"] == "1.1h.20190830" and info["settings"]["$22"] == 1 and info["rx_buffer_size"] == 128


def test_grbl_rig_stop_resume_and_reset(emulator):
    with _rig(emulator.tty_path) as rig:
        rig.home(timeout_s=5.0)
        resets = emulator.resets
        errors = []
        mover = threading.Thread(
            target=lambda: errors.append(_catch(lambda: rig.move_to(baseline_mm=50.0).wait())))
        mover.start()
        deadline = time.monotonic() + 5.0
        while emulator.state != "Run" and time.monotonic() < deadline:
            time.sleep(0.001)
        rig.stop()
        mover.join(5.0)
        assert errors and "feed hold" in str(errors[0])
        reading = rig.resume(timeout_s=5.0)
        assert reading.state == "Idle" and reading.baseline_mm == 50.0
        assert rig.reset().state == "Idle" and emulator.resets == resets + 1


def _catch(action):
    try:
        action()
    except RigError as error:
        return error
    return None


def test_the_emulator_is_sized_for_any_mapping():
    specs, force = axis_specs_for_travel({"X": (-350.0, 0.0), "Y": (-90.0, -2.0)})
    assert not force and specs["X"].max_travel == 350.0 and specs["Y"].max_travel == 90.0
    # Positive targets exist only on a HOMING_FORCE_SET_ORIGIN build, homing toward - ($23 bit set).
    specs, force = axis_specs_for_travel(RigConfig.model_validate(POSITIVE).machine_travel())
    assert force and specs["X"] == AxisSpec(max_travel=350.0, home_negative=True)
    with GrblEmulator(time_scale=FAST, axis_specs=specs, force_set_origin=force) as emu:
        with _rig(emu.tty_path, rig_config_from_dict(POSITIVE)) as rig:
            assert rig.warnings == []
            rig.home(timeout_s=5.0)
            assert rig.move_to(baseline_mm=120.0, toe_in_left_deg=5.0).wait().machine_position == {"X": 120.0, "Y": 5.0,
                                                                                             "Z": 0.0}


def test_homing_approach_is_the_direction_of_the_last_pull_off():
    # limits.c: the cycle ends pulling off the switch, toward - machine units (toward + on a $23 axis); the mapping's
    # scale turns that into the physical direction the kinematic model's backlash correction needs.
    specs = {"Y": AxisSpec(max_travel=90.0, home_negative=True)}
    config = rig_config_from_dict({"quantities": {"toe_in_left_deg": {"axis": "Y", "offset": -89, "scale": 1.0,
                                                                       "min": 0, "max": 88}}})
    with GrblEmulator(time_scale=FAST, axis_specs=specs) as emu, _rig(emu.tty_path, config) as rig:
        assert rig.homing_approach() == {"baseline_mm": -1, "toe_in_left_deg": 1, "toe_in_right_deg": 1}
        home = rig.home(timeout_s=5.0)
        assert home.toe_in_left_deg == 0.0 and emu.physical_position()["Y"] == -89.0  # -$131 + $27
