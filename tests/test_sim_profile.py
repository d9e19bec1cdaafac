"""The simulated bench's profiles and the campaign's [sim] table."""

from __future__ import annotations

import pytest

from drivers.sim.profile import IDEAL, LAB, LAB_JUSTIFICATIONS, SimProfile, SimSettings
from stereo_bench.campaign.config import ConfigError, campaign_from_dict, load_preset, recorded_campaign

PLAN = {"plan": {"baseline_mm": [100], "distance_mm": [500]}}


def test_every_lab_value_has_a_one_line_justification():
    names = [name for name, _, _ in LAB.rows()]
    assert sorted(names) == sorted(LAB_JUSTIFICATIONS)
    for name, text in LAB_JUSTIFICATIONS.items():
        assert text.strip() and "\n" not in text, name


def test_every_parameter_is_described_with_its_unit_or_meaning():
    for name, _, description in IDEAL.rows():
        assert len(description) > 10, name


def test_ideal_is_the_default_profile_and_has_no_imperfection():
    assert SimProfile() == IDEAL
    assert IDEAL.mechanically_ideal and not IDEAL.moves_need_history
    assert IDEAL.target.flat_and_true and IDEAL.calibration_board.flat_and_true
    assert IDEAL.cameras.jpeg_quality is None


def test_lab_is_imperfect_in_every_group_the_issue_names():
    assert not LAB.mechanically_ideal and LAB.moves_need_history
    for head in (LAB.left_head, LAB.right_head):
        assert 15.0 <= head.centre_forward_mm <= 30.0  # the centre 15-30 mm in front of the pan axis
        assert 0.0 < abs(head.centre_sideways_mm) < 5.0  # a few mm sideways
        assert 0.0 < max(abs(head.axis_tilt_x_deg), abs(head.axis_tilt_z_deg)) < 1.0  # tenths of a degree
        assert head.mount_roll_deg and head.mount_pitch_deg and head.mount_yaw_deg
        assert head.scale_error and head.backlash_deg and head.repeatability_deg
    slide = LAB.slide
    assert slide.direction_yaw_deg and slide.scale_error and slide.backlash_mm and slide.repeatability_mm
    assert LAB.target.print_scale_error and LAB.target.bow_mm
    assert LAB.target.placement_distance_sigma_mm and LAB.target.placement_yaw_sigma_deg
    assert LAB.cameras.jpeg_quality and LAB.cameras.radial_high_order_left and LAB.cameras.vibration_yaw_deg


def test_campaigns_run_on_the_lab_bench_by_default_and_say_ideal_explicitly():
    assert campaign_from_dict(PLAN).sim.resolve() == LAB
    assert load_preset("paper-exp1").sim.profile == "lab"
    assert campaign_from_dict({**PLAN, "sim": {"profile": "ideal"}}).sim.resolve() == IDEAL


def test_single_values_can_be_overridden():
    config = campaign_from_dict({**PLAN, "sim": {"slide": {"backlash_mm": 0.0}, "cameras": {"jpeg_quality": 95}}})
    profile = config.sim.resolve()
    assert profile.slide.backlash_mm == 0.0 and profile.cameras.jpeg_quality == 95
    assert profile.slide.scale_error == LAB.slide.scale_error  # the rest stays the lab's
    assert profile.name == "lab+overrides"
    ideal = SimSettings(profile="ideal", target={"bow_mm": 1.5}).resolve()
    assert ideal.target.bow_mm == 1.5 and ideal.slide == IDEAL.slide


@pytest.mark.parametrize("sim, message", [
    ({"profile": "workshop"}, "sim.profile: Input should be 'lab' or 'ideal'"),
    ({"slide": {"backlsh_mm": 0.0}}, "sim: slide.backlsh_mm: unknown key; known: direction_yaw_deg"),
    ({"slide": {"backlash_mm": -1.0}}, "sim: slide.backlash_mm: Input should be greater than or equal to 0"),
    ({"cameras": {"jpeg_quality": 0}}, "sim: cameras.jpeg_quality: Input should be greater than or equal to 1"),
    ({"calibration_board": {"placement_yaw_sigma_deg": 1.0}}, "placement errors apply to the manually placed target"),
    ({"heads": {}}, "sim.heads: unknown key; known: profile, slide, left_head"),
])
def test_bad_sim_tables_are_one_line_errors_naming_the_field(sim, message):
    with pytest.raises(ConfigError) as error:
        campaign_from_dict({**PLAN, "sim": sim}, source="c.toml")
    text = str(error.value)
    assert text.startswith("c.toml: ") and message in text and "\n" not in text


def test_the_recorded_config_keeps_the_sim_table():
    config = campaign_from_dict({**PLAN, "sim": {"profile": "ideal", "slide": {"backlash_mm": 0.1}}})
    again = campaign_from_dict(config.model_dump(mode="json"))
    assert again.sim.resolve() == config.sim.resolve()


def test_a_recording_without_a_sim_table_is_the_ideal_bench_and_a_new_campaign_the_lab_one():
    """Sessions recorded before [sim] existed ran on the ideal bench; today's default is for new campaigns."""
    assert campaign_from_dict(PLAN).sim.resolve() == LAB
    assert recorded_campaign(PLAN).sim.resolve() == IDEAL
    recorded_lab = campaign_from_dict({**PLAN, "sim": {"profile": "lab"}}).model_dump(mode="json")
    assert recorded_campaign(recorded_lab).sim.resolve() == LAB


def test_campaign_run_sim_flag_picks_the_bench_and_refuses_real_cameras(tmp_path):
    from stereo_bench.cli import CliError
    from stereo_bench.cli.campaign_run import config_from_args

    assert config_from_args(None, "paper-exp1").sim.resolve() == LAB
    assert config_from_args(None, "paper-exp1", sim="ideal").sim.resolve() == IDEAL
    rig = '[rig]\nkind = "grbl"\nport = "/dev/ttyUSB0"\n[plan]\nbaseline_mm = [100]\ndistance_mm = [500]\n'
    bring_up = tmp_path / "bring_up.toml"  # the real controller, simulated cameras: the profile renders them
    bring_up.write_text(rig)
    assert config_from_args(bring_up, None, sim="ideal").sim.resolve() == IDEAL
    real = tmp_path / "real.toml"
    real.write_text(rig + '[cameras]\nkind = "v4l2"\nleft = "usb-port:1-1"\nright = "usb-port:1-2"\n')
    with pytest.raises(CliError, match="--sim applies to simulated cameras only"):
        config_from_args(real, None, sim="ideal")


def test_the_resume_command_resumes_the_recorded_bench_whatever_the_command_line_gave(small_reference):
    """The rest of an interrupted campaign must render on the bench its first part did: the resume command names
    no campaign file and no option, so it continues with the recorded config (``--sim``, ``--time-scale`` and the
    file's own values), and only ``--yes`` (who does the manual steps) is carried."""
    import argparse
    from pathlib import Path

    from stereo_bench.campaign.session import SessionReader
    from stereo_bench.cli.campaign_run import _resume_command, config_from_args

    args = argparse.Namespace(plan="small.toml", preset=None, sim="lab", time_scale=10.0, yes=False)
    assert _resume_command(args, Path("my out")) == "stereo-bench campaign run --out 'my out' --resume"
    args.yes = True
    assert _resume_command(args, Path("out")) == "stereo-bench campaign run --out out --resume --yes"
    resumed = config_from_args(None, None, session=small_reference)
    # What the session writer compares a resume's config with: equal, so it is never refused as a different config.
    assert resumed.model_dump(mode="json") == SessionReader(small_reference).start().config
    assert resumed.sim.resolve() == IDEAL
    assert config_from_args(None, None, session=small_reference, sim="lab").sim.resolve() != IDEAL  # then refused


def test_the_documented_lab_table_is_the_code():
    from pathlib import Path

    from drivers.sim.profile import lab_table_markdown

    doc = (Path(__file__).resolve().parents[1] / "docs" / "SIMULATED_BENCH.md").read_text(encoding="utf-8")
    assert lab_table_markdown() in doc, "regenerate the table with drivers.sim.profile.lab_table_markdown()"
