"""Campaign config: defaults, validation messages (one line naming file and field), presets, JSON Schema."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereo_bench.campaign.config import (
    PRESETS,
    CampaignConfig,
    ConfigError,
    TargetConfig,
    campaign_from_dict,
    campaign_json_schema,
    load_campaign,
    load_preset,
)
from stereo_bench.targets import CharucoTarget, Checkerboard

MINIMAL = """\
[plan]
baseline_mm = [100, 150]
distance_mm = [400, 500]
alpha_deg = [90]
"""


def _write(tmp_path: Path, text: str, name: str = "campaign.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _error(tmp_path: Path, text: str) -> str:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as caught:
        load_campaign(path)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    return message.removeprefix(f"{path}: ")


def test_minimal_plan_gets_working_defaults(tmp_path):
    config = load_campaign(_write(tmp_path, MINIMAL))
    assert config.plan.baseline_mm == [100.0, 150.0] and config.plan.distance_mm == [400.0, 500.0]
    assert config.plan.angles_deg() == [(90.0, 0.0)]
    assert config.rig.kind == "simulated" and config.cameras.kind == "simulated" and config.fully_simulated
    assert config.rig.rig_config().driven == {"baseline_mm": "X", "toe_in_left_deg": "Y", "toe_in_right_deg": "Z"}
    assert config.target.build() == Checkerboard(9, 6, 27.0)
    assert config.calibration_board.build() == Checkerboard(11, 8, 25.0)
    assert (config.extrinsics.mode, config.extrinsics.intrinsics) == ("per-config", "joint")
    assert config.capture.settle_s == 0.3 and config.capture.frames_per_config == 3
    camera = config.cameras.optics.camera_model("left")
    assert camera.fx == pytest.approx(4000 / 3) and camera.image_size == (1920, 1080)


def test_angle_defaults_to_parallel_and_toe_in_converts():
    config = campaign_from_dict({"plan": {"baseline_mm": [100], "distance_mm": [500]}})
    assert config.plan.alpha_deg == [90.0] and config.plan.toe_in_deg is None
    config = campaign_from_dict({"plan": {"baseline_mm": [100], "distance_mm": [500], "toe_in_deg": [5, 15]}})
    assert config.plan.angles_deg() == [(85.0, 5.0), (75.0, 15.0)]


@pytest.mark.parametrize("text, expected", [
    (MINIMAL.replace("alpha_deg", "alpha"), "plan.alpha: unknown key; known: baseline_mm, distance_mm, alpha_deg"),
    (MINIMAL + "[cameras.optics]\nfocal = 4\n", "cameras.optics.focal: unknown key; known: focal_mm"),
    (MINIMAL + "[cameras.settings]\nexposure = 100\n", "cameras.settings: exposure: unknown camera setting"),
    (MINIMAL + "[cameras.settings]\nexposure_us = -1\n", "cameras.settings: exposure_us: Input should be greater"),
    (MINIMAL + "[captur]\nsettle_s = 1\n", "captur: unknown key; known: name, description, seed, rig"),
    ("[plan]\nbaseline_mm = [100, 'x']\ndistance_mm = [400]\n", "plan.baseline_mm[1]: 'x' is a string, not a number"),
    ("[plan]\nbaseline_mm = [100, 100]\ndistance_mm = [400]\n", "plan.baseline_mm: lists 100 more"),
    ("[plan]\nbaseline_mm = [100]\ndistance_mm = [0]\n", "plan.distance_mm: value 0 outside (0, 100000]"),
    ("[plan]\nbaseline_mm = []\ndistance_mm = [400]\n", "plan.baseline_mm: needs at least one value"),
    ("[plan]\nbaseline_mm = [100]\ndistance_mm = [400]\nalpha_deg = [180]\n", "plan.alpha_deg: value 180"),
    (MINIMAL + "toe_in_deg = [5]\n", "plan: give alpha_deg or toe_in_deg, not both"),
    ("name = 'x'\n", "plan: missing (required)"),
    (MINIMAL + "[rig]\nkind = 'grbl'\n", "rig: kind = \"grbl\" needs port"),
    (MINIMAL + "[rig]\nport = '/dev/ttyUSB0'\n", "rig: port is set but kind is \"simulated\""),
    (MINIMAL + "[rig]\nkind = 'grbl'\nport = '/dev/ttyUSB0'\ntime_scale = 5\n", "rig: time_scale is for the simulated"),
    (MINIMAL + "[rig.quantities.baseline_mm]\naxis = 'Y'\nmin = 0\nmax = 300\n",
     "rig.quantities: axis Y drives both baseline_mm and toe_in_left_deg"),
    (MINIMAL + "[rig.quantities.baseline_mm]\naxis = 'X'\n", "rig.quantities.baseline_mm: a quantity "
                                                               "driven by axis X needs soft limits"),
    (MINIMAL + "[cameras]\nkind = 'v4l2'\n", "cameras: kind = \"v4l2\" needs left and right"),
    (MINIMAL + "[cameras]\nkind = 'v4l2'\nleft = 'usb-port:1-1'\nright = 'usb-port:1-2'\n",
     "rig.kind = \"simulated\" with cameras.kind = \"v4l2\" is not a bench: real cameras cannot film"),
    (MINIMAL + "[capture]\ncalibration_views = 3\n", "capture.calibration_views: per-config extrinsics need"),
    (MINIMAL + "[capture]\nframes_per_config = 0\n", "capture.frames_per_config: Input should be greater"),
    (MINIMAL + "[extrinsics]\nmode = 'fixed'\n", "extrinsics: mode = \"fixed\" needs calib_dir"),
    (MINIMAL + "[extrinsics]\nmode = 'fixd'\n",
     "extrinsics.mode: Input should be 'per-config', 'kinematic', 'nominal' or 'fixed'"),
    (MINIMAL + "[target]\ncols = 7\nrows = 7\n", "target: a 7x7 board is square"),
    (MINIMAL + "[target]\nmarker_mm = 20\n", "target: marker_mm is only for kind = \"charuco\""),
    (MINIMAL + "[cameras.optics]\ndist = [0.1, 0.2, 0.3]\n", "cameras.optics.dist: OpenCV takes 4, 5, 8"),
    ("[plan\n", "invalid TOML"),
    ("seed = -1\n" + MINIMAL, "seed: Input should be greater than or equal to 0"),
    ("seed = 4294967296\n" + MINIMAL, "seed: Input should be less than or equal to 4294967295"),
    ("[plan]\nbaseline_mm = [100, 100.0000001]\ndistance_mm = [400]\n",
     "plan.baseline_mm: lists 100.0 and 100.0000001, closer than 1e-06: the same position twice"),
    (MINIMAL + "[calibration]\nexclude_views = [3, 99]\n",
     "calibration.exclude_views: no view 99: a configuration takes views 0 to 11 (capture.calibration_views)"),
    (MINIMAL + "[calibration]\nexclude_views = [0, 1, 2, 3, 4, 5, 6, 7]\n",
     "calibration.exclude_views: leaves 4 of capture.calibration_views = 12, fewer than the 5"),
])
def test_bad_config_is_one_line_naming_the_field(tmp_path, text, expected):
    assert expected in _error(tmp_path, text)


def test_several_errors_are_counted_on_the_one_line(tmp_path):
    message = _error(tmp_path, "[plan]\nbaseline_mm = ['a', 'b']\ndistance_mm = [400]\n")
    assert message.startswith("plan.baseline_mm[0]: ") and message.endswith("(and 1 more)")


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(ConfigError, match="no such campaign file"):
        load_campaign(tmp_path / "absent.toml")
    with pytest.raises(ConfigError, match="is a directory"):
        load_campaign(tmp_path)


def test_rig_config_file_is_resolved_next_to_the_campaign_file_and_read_at_load(tmp_path):
    (tmp_path / "rigs").mkdir()
    (tmp_path / "rigs" / "bench.toml").write_text("[quantities.baseline_mm]\naxis = 'X'\nmin = 20\nmax = 200\n")
    path = _write(tmp_path, MINIMAL + "[rig]\nconfig_file = 'rigs/bench.toml'\n")
    config = load_campaign(path)
    assert config.rig.config_file == tmp_path / "rigs" / "bench.toml"
    assert config.rig.rig_config().quantities["baseline_mm"].max == 200.0

    (tmp_path / "rigs" / "bench.toml").write_text("[quantities.baseline_mm]\naxis = 'X'\nmin = 20\nmax = 2\n")
    message = _error(tmp_path, MINIMAL + "[rig]\nconfig_file = 'rigs/bench.toml'\n")
    assert message.startswith("rig.config_file: ") and "bench.toml: quantities.baseline_mm: min (20.0)" in message
    message = _error(tmp_path, MINIMAL + "[rig]\nconfig_file = 'nope.toml'\n")
    assert message.startswith("rig.config_file: ") and "no such rig configuration file" in message
    (tmp_path / "rigs" / "bench.toml").write_text("[quantities.baseline_mm]\naxis = 'X'\nmin = 20\nmax = 200\n")
    message = _error(tmp_path, MINIMAL + "[rig]\nconfig_file = 'rigs/bench.toml'\n[rig.quantities.baseline_mm]\n"
                                         "axis = 'X'\nmin = 0\nmax = 100\n")
    assert "rig: give the rig mapping in config_file or inline" in message


def test_inline_rig_mapping_keeps_defaults_for_the_rest():
    config = campaign_from_dict({
        "rig": {"quantities": {"target_distance_mm": {"axis": "C", "min": 200, "max": 1500}},
                "controller": {"rx_buffer_size": 1024}},
        "plan": {"baseline_mm": [100], "distance_mm": [500]},
    })
    rig = config.rig.rig_config()
    assert rig.driven == {"baseline_mm": "X", "toe_in_left_deg": "Y", "toe_in_right_deg": "Z",
                          "target_distance_mm": "C"}
    assert rig.controller.rx_buffer_size == 1024


def test_calibration_directory_must_hold_the_files_the_mode_needs(tmp_path):
    calib = tmp_path / "calib"
    message = _error(tmp_path, MINIMAL + "[extrinsics]\nmode = 'fixed'\ncalib_dir = 'calib'\n")
    assert message == f"extrinsics.calib_dir: no such directory: {calib}"
    calib.mkdir()
    (calib / "intrinsics.yml").write_text("%YAML:1.0\n")
    message = _error(tmp_path, MINIMAL + "[extrinsics]\nmode = 'fixed'\ncalib_dir = 'calib'\n")
    assert message == f"extrinsics.calib_dir: {calib} has no extrinsics.yml"
    # per-config with fixed intrinsics needs only the intrinsics
    config = load_campaign(_write(tmp_path, MINIMAL + "[extrinsics]\nintrinsics = 'fixed'\ncalib_dir = 'calib'\n"))
    assert config.extrinsics.calib_dir == calib
    (calib / "extrinsics.yml").write_text("%YAML:1.0\n")
    config = load_campaign(_write(tmp_path, MINIMAL + "[extrinsics]\nmode = 'fixed'\ncalib_dir = 'calib'\n"))
    assert config.extrinsics.mode == "fixed"


def test_v4l2_cameras_and_their_settings():
    config = campaign_from_dict({
        "rig": {"kind": "grbl", "port": "/dev/ttyUSB0"},
        "cameras": {"kind": "v4l2", "left": "by-id:usb-cam-L", "right": "usb-port:1-2",
                    "settings": {"exposure_us": 5000, "fps": 15, "pixel_format": "mjpg"}},
        "plan": {"baseline_mm": [100], "distance_mm": [500]},
    })
    settings = config.cameras.camera_settings()
    assert settings.exposure_us == 5000 and settings.pixel_format == "MJPG" and settings.auto_exposure is False
    assert not config.fully_simulated and config.bench_kind == "hardware"


@pytest.mark.parametrize("rig, cameras, kind", [
    ({}, {}, "simulated"),
    ({"kind": "grbl", "port": "/dev/ttyUSB0"}, {}, "bring-up"),
    ({"kind": "grbl", "port": "/dev/ttyUSB0"}, {"kind": "v4l2", "left": "usb-port:1-1", "right": "usb-port:1-2"},
     "hardware"),
])
def test_every_supported_rig_and_camera_combination_is_a_bench(rig, cameras, kind):
    config = campaign_from_dict({"rig": rig, "cameras": cameras, "plan": {"baseline_mm": [100], "distance_mm": [500]}})
    assert config.bench_kind == kind


def test_target_build_checkerboard_and_charuco():
    assert TargetConfig().build() == Checkerboard(9, 6, 27.0)
    board = TargetConfig(kind="charuco", cols=10, rows=7, square_mm=20.0).build()
    assert isinstance(board, CharucoTarget)
    assert (board.squares_x, board.squares_y, board.cols, board.rows) == (10, 7, 9, 6)
    assert board.marker_mm == pytest.approx(15.0) and board.dictionary == "DICT_5X5_1000"
    with pytest.raises(ValueError, match="unknown ArUco dictionary"):
        TargetConfig(kind="charuco", cols=10, rows=7, dictionary="DICT_NOPE")


def test_presets_reproduce_the_paper():
    assert set(PRESETS) == {"paper-exp1", "paper-exp2", "paper-exp2-toe-in", "paper-exp2-measurable"}
    for name, description in PRESETS.items():
        config = load_preset(name)
        assert config.name == name and config.description == description
        # the measurable exp2 preset keeps the 27 mm squares on a smaller board (its description says why)
        board = Checkerboard(6, 4, 27.0) if name == "paper-exp2-measurable" else Checkerboard(9, 6, 27.0)
        assert config.rig.kind == "simulated" and config.target.build() == board
    exp1 = load_preset("paper-exp1").plan
    assert exp1.distance_mm == [300, 400, 500, 600, 700] and exp1.baseline_mm == [50, 100, 150, 200, 250]
    assert exp1.alpha_deg == [90]
    exp2 = load_preset("paper-exp2").plan
    assert (exp2.distance_mm, exp2.baseline_mm, exp2.alpha_deg) == ([500], [100], [5, 15, 25, 35, 45, 55])
    toe_in = load_preset("paper-exp2-toe-in").plan
    assert [alpha for alpha, _ in toe_in.angles_deg()] == [85, 75, 65, 55, 45, 35]
    with pytest.raises(ConfigError, match="unknown preset 'paper-exp3'; known: paper-exp1"):
        load_preset("paper-exp3")


def test_json_schema_describes_the_file():
    schema = campaign_json_schema()
    json.dumps(schema)
    assert schema["required"] == ["plan"] and schema["additionalProperties"] is False
    sections = {"rig", "cameras", "calibration_board", "target", "capture", "extrinsics", "plan"}
    assert sections <= set(schema["properties"])
    plan = schema["$defs"]["PlanSection"]
    assert plan["additionalProperties"] is False and set(plan["required"]) == {"baseline_mm", "distance_mm"}
    assert CampaignConfig.model_validate({"plan": {"baseline_mm": [8], "distance_mm": [1]}}).name == "campaign"


def test_the_default_optics_are_the_default_camera():
    from stereo_bench.campaign.config import OpticsConfig
    from stereo_bench.geometry import CameraModel

    assert OpticsConfig().camera_model("left") == CameraModel.from_sensor(name="left")
