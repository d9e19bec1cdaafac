"""Rig configuration (pure) and the rig in physical units (GrblRig against the pty emulator)."""

from __future__ import annotations

import pytest

from drivers.rig import GrblRig, Rig, RigError
from drivers.rig.config import (
    LimitError,
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
from drivers.sim.grbl_emulator import AxisSpec, GrblEmulator
from stereo_bench.geometry import RigPose

FAST = 50.0

SIX_AXIS_TOML = """
[controller]
rx_buffer_size = 1024
move_timeout_s = 20

[quantities.baseline_mm]
axis = "X"
offset = 10.0          # the slide's zero is 10 mm before B = 0
scale = 1.0
min = 40.0
max = 300.0
feed_per_min = 2400

[quantities.toe_in_left_deg]
axis = "Y"
min = 0
max = 30

[quantities.toe_in_right_deg]
axis = "Z"
scale = -1.0           # the right head turns the other way
offset = 45.0
min = 0
max = 30

[quantities.tilt_left_deg]
axis = "A"
min = -10
max = 10

[quantities.tilt_right_deg]
axis = "B"
min = -10
max = 10

[quantities.target_distance_mm]
axis = "C"
min = 200
max = 1500
"""


def _write(tmp_path, text: str):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------------------------- config


def test_default_mapping():
    config = RigConfig()
    assert config.driven == {"baseline_mm": "X", "toe_in_left_deg": "Y", "toe_in_right_deg": "Z"}
    assert config.axes == "XYZ"
    assert config.machine_travel() == {"X": (0.0, 350.0), "Y": (0.0, 90.0), "Z": (0.0, 90.0)}
    assert config.quantities["tilt_left_deg"].axis == "fixed" and config.quantities["tilt_left_deg"].value == 0.0
    assert config.quantities["target_distance_mm"].axis == "manual"


def test_load_six_axis_toml(tmp_path):
    config = load_rig_config(_write(tmp_path, SIX_AXIS_TOML))
    assert config.axes == "XYZABC"
    assert config.controller.rx_buffer_size == 1024
    assert config.machine_travel()["Z"] == (15.0, 45.0)
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
    assert machine == {"X": 60.0, "Y": 3.0, "Z": 37.5}
    back = to_physical(config, machine)
    assert back == {"baseline_mm": 25.0, "toe_in_left_deg": 3.0, "toe_in_right_deg": 7.5}


def test_limits_name_every_violation():
    config = RigConfig()
    check_limits(config, {"baseline_mm": 350.0, "toe_in_left_deg": 0.0})
    with pytest.raises(LimitError) as info:
        check_limits(config, {"baseline_mm": 351.0, "toe_in_left_deg": -1.0, "toe_in_right_deg": 10.0})
    assert len(info.value.violations) == 2
    assert "baseline_mm = 351 outside [0, 350]" in str(info.value)
    assert "toe_in_left_deg = -1 outside [0, 90]" in str(info.value)


def test_plan_move_splits_driven_and_manual_and_refuses_fixed_changes():
    config = RigConfig()
    plan = plan_move(config, physical_request(baseline_mm=120.0, alpha_left_deg=85.0, alpha_right_deg=80.0,
                                              tilt_left_deg=0.0, target_distance_mm=400.0))
    assert plan.machine_targets == {"X": 120.0, "Y": 5.0, "Z": 10.0}
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
    prompts: list[str] = []
    with _rig(emulator.tty_path, prompt=prompts.append) as rig:
        assert isinstance(rig, Rig)
        rig.home(timeout_s=5.0)
        reading = rig.move_to(baseline_mm=120.0, alpha_left_deg=85.0, alpha_right_deg=84.0, target_distance_mm=400.0)
        assert reading.state == "Idle"
        assert reading.baseline_mm == 120.0
        assert reading.toe_in_left_deg == 5.0 and reading.alpha_left_deg == 85.0
        assert reading.toe_in_right_deg == 6.0 and reading.alpha_right_deg == 84.0
        assert reading.tilt_left_deg == 0.0 and reading.sources["tilt_left_deg"] == "fixed"
        assert reading.target_distance_mm == 400.0 and reading.sources["target_distance_mm"] == "operator"
        assert reading.machine_position == {"X": 120.0, "Y": 5.0, "Z": 6.0} == emulator.machine_position()
        assert prompts == ["move the target to Z = 400 mm, then press Enter"]
        # Same target again: nothing for the operator to do.
        rig.move_to(target_distance_mm=400.0, baseline_mm=100.0)
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
            rig.move_to(baseline_mm=400.0)
        with pytest.raises(MoveRequestError, match="fixed"):
            rig.move_to(tilt_left_deg=5.0)
        with pytest.raises(MoveRequestError, match="no operator prompt"):
            rig.move_to(baseline_mm=10.0, target_distance_mm=500.0)
        assert list(emulator.lines_received) == received
        assert emulator.machine_position()["X"] == 0.0


def test_move_to_pose_from_geometry(emulator):
    with _rig(emulator.tty_path) as rig:
        rig.home(timeout_s=5.0)
        reading = rig.move_to_pose(RigPose.symmetric(150.0, alpha_deg=82.5))
        assert reading.baseline_mm == 150.0 and reading.alpha_left_deg == reading.alpha_right_deg == 82.5


def test_six_axis_mapping_offsets_scales_and_feeds(tmp_path):
    config = load_rig_config(_write(tmp_path, SIX_AXIS_TOML))
    specs = {axis: AxisSpec(travel=travel) for axis, travel in config.machine_travel().items()}
    with GrblEmulator(time_scale=FAST, axes="XYZABC", axis_specs=specs, firmware="grblhal") as emu:
        with _rig(emu.tty_path, config) as rig:
            rig.home(timeout_s=5.0)
            reading = rig.move_to(baseline_mm=100.0, toe_in_left_deg=4.0, toe_in_right_deg=4.0, tilt_left_deg=-2.0,
                                  tilt_right_deg=3.0, target_distance_mm=600.0)
            assert emu.machine_position() == {"X": 110.0, "Y": 4.0, "Z": 41.0, "A": -2.0, "B": 3.0, "C": 600.0}
            assert reading.baseline_mm == 100.0 and reading.toe_in_right_deg == 4.0
            assert reading.tilt_right_deg == 3.0 and reading.target_distance_mm == 600.0
            assert reading.sources["target_distance_mm"] == "controller axis C"
            # A baseline-only move runs at the configured feed (a G1, not a rapid).
            rig.move_to(baseline_mm=200.0)
            assert emu.lines_received[-2] == "G53 G1 X210.000 F2400.0"


def test_config_axis_missing_on_the_controller(tmp_path):
    config = load_rig_config(_write(tmp_path, SIX_AXIS_TOML))
    with GrblEmulator(time_scale=FAST) as emu:  # a 3-axis board
        rig = _rig(emu.tty_path, config)
        with pytest.raises(RigError, match="drives axis A, B, C but the controller .* reports only X, Y, Z"):
            rig.open()
        assert not rig.controller.is_open
