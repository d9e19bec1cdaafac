"""Names that mean one thing (issue 21 item 4): ``[extrinsics] intrinsics = "held"`` (the intrinsics not refined),
beside ``mode = "fixed"`` (R, T from a file); the old spelling ``intrinsics = "fixed"`` still accepted with a note."""

from __future__ import annotations

import pytest

from stereo_bench.campaign import config as config_module
from stereo_bench.campaign.config import campaign_from_dict, recorded_campaign
from stereo_bench.campaign.execute import runner_options

PLAN = {"plan": {"baseline_mm": [100.0], "distance_mm": [400.0]}}


@pytest.fixture(autouse=True)
def _fresh_notes(monkeypatch):
    monkeypatch.setattr(config_module, "_noted", set())


def test_held_and_its_old_spelling_hold_the_intrinsics(capsys):
    held = campaign_from_dict({**PLAN, "extrinsics": {"intrinsics": "held"}})
    old = campaign_from_dict({**PLAN, "extrinsics": {"intrinsics": "fixed"}})
    joint = campaign_from_dict(PLAN)
    assert held.extrinsics.intrinsics_held and old.extrinsics.intrinsics_held and not joint.extrinsics.intrinsics_held
    # the stereo calibration's mode (vision.calibrate), as before the new name
    assert runner_options(held).intrinsics_mode == runner_options(old).intrinsics_mode == "fixed"
    assert runner_options(joint).intrinsics_mode == "joint"
    # what the user wrote is what the start document records
    assert old.model_dump(mode="json")["extrinsics"]["intrinsics"] == "fixed"
    assert held.model_dump(mode="json")["extrinsics"]["intrinsics"] == "held"


def test_the_old_spelling_is_noted_once_in_one_line(capsys):
    campaign_from_dict({**PLAN, "extrinsics": {"intrinsics": "fixed"}}, source="plan.toml")
    campaign_from_dict({**PLAN, "extrinsics": {"intrinsics": "fixed"}}, source="plan.toml")
    err = capsys.readouterr().err
    assert err == ('note: plan.toml: [extrinsics] intrinsics = "fixed" is now spelled "held" '
                   '(the old spelling still works)\n')
    campaign_from_dict({**PLAN, "extrinsics": {"intrinsics": "held"}})
    assert capsys.readouterr().err == ""


def test_a_recorded_config_with_the_old_spelling_reads_without_a_note(capsys):
    recorded = campaign_from_dict({**PLAN, "extrinsics": {"intrinsics": "fixed"}}).model_dump(mode="json")
    capsys.readouterr()
    config_module._noted.clear()
    assert recorded_campaign(recorded).extrinsics.intrinsics_held
    assert capsys.readouterr().err == ""
