"""The operator's hand work a real bench timed feeds the next plan (campaign/presentation.py): seconds per target
move and per fixed-board placement from the prompts a person answered, beside the seconds per presented view; the
simulated bench's prompts (answered by the simulator, or by a person in front of a simulated scene) time nothing."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from stereo_bench.campaign import presentation
from stereo_bench.campaign.documents import PresentationTimeData, PromptData
from stereo_bench.campaign.presentation import PresentationTime
from stereo_bench.cli import main
from tests.test_fixed_board_plan import HARDWARE, PAPER_EXP1


def _prompt(kind: str, waited_s: float, by: str = "terminal"):
    return SimpleNamespace(data=PromptData(prompt=kind, message="", answered_by=by, waited_s=waited_s))


PROMPTS = ([_prompt("target", s) for s in (30.0, 40.0, 50.0, 20.0, 35.0)] + [_prompt("fixed_board", 72.0)]
           + [_prompt("target", 0.01, by="simulator"), _prompt("calibration_review", 9.0)])


def test_a_real_bench_times_its_target_moves_and_placement_and_the_simulated_one_nothing():
    measured = PresentationTime.of_events([], session="s", prompts=PROMPTS, real_scene=True)
    assert measured.seconds_per_view is None and measured.views == 0
    assert measured.seconds_per_target_move == pytest.approx(35.0) and measured.target_moves == 5
    assert measured.seconds_per_placement == pytest.approx(72.0) and measured.placements == 1
    assert measured.clock == "wall"
    assert measured.describe_prompts() == ["35.0 s per target move, measured over 5 moves in session s",
                                           "72.0 s per fixed-board placement, measured over 1 placements in session s"]
    assert PresentationTime.of_events([], session="s", prompts=PROMPTS, real_scene=False) is None
    # with presented views too: each figure from its own events
    views = [SimpleNamespace(data=PresentationTimeData(views=12, seconds=54.0, capture="enter", clock="wall"))]
    both = PresentationTime.of_events(views, session="s", prompts=PROMPTS, real_scene=True)
    assert both.seconds_per_view == pytest.approx(4.5) and both.seconds_per_target_move == pytest.approx(35.0)


def test_a_file_written_before_the_prompt_figures_still_reads(tmp_path):
    old = {"schema_version": 1, "seconds_per_view": 2.5, "views": 24, "seconds": 60.0, "capture": "auto",
           "clock": "bench", "session": "x", "measured_at": "2026-12-02T10:00:00+00:00"}
    path = tmp_path / presentation.FILE_NAME
    path.write_text(json.dumps(old))
    measured, note = presentation.read(path)
    assert note is None and measured.seconds_per_view == 2.5 and measured.seconds_per_target_move is None


def test_the_next_plan_of_paper_exp1_counts_the_measured_placement_and_target_moves(tmp_path, capsys):
    """paper-exp1 on hardware with the fixed board: 5 target moves and 1 placement, no presentation; assumed
    5 x 30 s + 20 s = 2:50, with this bench's measured 35 s and 72 s: 5 x 35 + 72 = 4:07."""
    measured = PresentationTime.of_events([], session="earlier", prompts=PROMPTS, real_scene=True)
    presentation.write_beside(tmp_path / "earlier", measured)
    config = tmp_path / "exp1.toml"
    config.write_text(
        "[plan]\n" + "".join(f"{k} = {v}\n" for k, v in PAPER_EXP1.items())
        + '[extrinsics]\nmode = "kinematic"\ndesign = "fixed-board"\n'
        + "".join(f"[{section}]\n" + "".join(f'{k} = "{v}"\n' for k, v in values.items())
                  for section, values in HARDWARE.items()))
    assert main(["campaign", "plan", str(config), "--json"]) == 0
    assumed = json.loads(capsys.readouterr().out)
    assert main(["campaign", "plan", str(config), "--json", "--out", str(tmp_path / "next")]) == 0
    planned = json.loads(capsys.readouterr().out)
    assert assumed["duration"]["operator_s"] == pytest.approx(5 * 30.0 + 20.0)
    assert planned["duration"]["operator_s"] == pytest.approx(5 * 35.0 + 72.0)
    figure = planned["presentation_time"]
    assert figure["target_move_source"] == figure["placement_source"] == "measured" and figure["source"] == "assumed"
    assert main(["campaign", "plan", str(config), "--out", str(tmp_path / "next")]) == 0
    text = capsys.readouterr().out
    assert "target move: measured, 35.0 s" in text and "board placement: measured, 72.0 s" in text
    assert "35.0 s per target move, measured over 5 moves in session earlier" in text
    assert "20 s to place the fixed board (assumed)" not in text
