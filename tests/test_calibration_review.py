"""The per-view error chart with a threshold and an exclude list, then recalibration (issue 24 item 2): the operator's
one-screen review in a real terminal (pexpect + pyte), and the same choices made non-interactively by
``[calibration] max_view_rms_px`` / ``exclude_views``; a replay leaves out what the recording left out."""

from __future__ import annotations

import numpy as np
import pytest

from stereo_bench.campaign.documents import AnalysisEvent, CalibrationExclusionsEvent, PromptEvent
from stereo_bench.campaign.execute.replay import replay_session
from stereo_bench.campaign.execute.run import run_campaign
from stereo_bench.campaign.operator import CONTINUE, EXCLUDE_VIEW, RECALIBRATE, SET_THRESHOLD, terminal_answer
from stereo_bench.campaign.review import ReviewState, review_message
from stereo_bench.campaign.session import SessionReader
from stereo_bench.campaign.stream import Collector
from tests.campaigns import SMALL, small_config
from tests.test_terminal_screen import STEREO_BENCH, Terminal, _keep

ONE = {"baseline_mm": [100], "distance_mm": [450], "alpha_deg": [90]}
CAMPAIGN = (SMALL.replace("baseline_mm = [100, 150]", "baseline_mm = [100]").replace("alpha_deg = [90, 35]",
                                                                                      "alpha_deg = [90]")
            + "[calibration]\nreview = true\n")


def test_terminal_keys():
    assert terminal_answer("t 0.25\n") == (SET_THRESHOLD, 0.25)
    assert terminal_answer("x 3\n") == (EXCLUDE_VIEW, 3.0)
    assert terminal_answer("r\n") == (RECALIBRATE, None)
    assert terminal_answer("x\n") == (EXCLUDE_VIEW, None)  # the review says what is missing
    assert terminal_answer("\n") == (CONTINUE, None) and terminal_answer("yes\n") == (CONTINUE, None)


def analysis_of(session):
    reader = SessionReader(session)
    (event,) = reader.events(kind=AnalysisEvent)
    return event.data.calibration  # a dict: rms_px, per_view_rms_px, views_used, views_rejected, ...


@pytest.mark.slow
def test_the_operator_excludes_a_view_and_recalibrates_on_one_screen(tmp_path):
    (tmp_path / "c.toml").write_text(CAMPAIGN)
    terminal = Terminal([*STEREO_BENCH, "campaign", "run", "c.toml", "--out", "s"], tmp_path)
    terminal.until(lambda t: t.last_line().endswith("then press Enter"), what="the target prompt")
    terminal.child.send("\r")
    terminal.until(lambda t: "Enter alone  accept" in t.last_line(), what="the per-view error summary")
    screen = terminal.lines()
    (head,) = [line for line in screen if "[B100_Z450_A90] calibration: 6 views, 6 used, stereo RMS" in line]
    bars = [line for line in screen if line.strip()[:1].isdigit() and "#" in line]
    assert len(bars) == 6, terminal.text()  # one bar per view, its RMS after it
    _keep("calibration-review.txt", terminal)

    terminal.child.send("x 2\r")
    terminal.until(lambda t: any("view 2 excluded: r recalibrates without it" in line for line in t.lines()),
                   what="view 2 marked for exclusion")
    terminal.child.send("r\r")
    # The new summary's heading, then its chart and keys line (on a loaded machine the heading may show first).
    terminal.until(lambda t: any("calibration: 6 views, 5 used" in line for line in t.lines())
                   and "Enter alone  accept" in t.last_line(), what="the calibration again without view 2")
    (excluded,) = [line for line in terminal.lines()[-10:] if line.strip().startswith("2 ")]
    assert "excluded by the operator" in excluded and "#" not in excluded, terminal.text()
    _keep("calibration-review-recalibrated.txt", terminal)
    terminal.child.send("t abc\r")  # not a number: said, nothing changes
    terminal.until(lambda t: any("t needs a threshold in px above 0" in line for line in t.lines()),
                   what="the note on a threshold that is not a number")
    terminal.child.send("\r")
    assert terminal.exit_status() == 0, terminal.text()

    calibration = analysis_of(tmp_path / "s")
    assert 2 not in calibration["views_used"] and len(calibration["views_used"]) == 5
    assert {"index": 2, "reason": "excluded by the operator"} in calibration["views_rejected"]
    reader = SessionReader(tmp_path / "s")
    (chosen,) = reader.events(kind=CalibrationExclusionsEvent)
    assert chosen.data.excluded == [(2, "excluded by the operator")] and chosen.data.recalibrations == 1
    actions = [e.data.action for e in reader.events(kind=PromptEvent) if e.data.prompt == "calibration_errors"]
    assert actions == ["exclude_view", "recalibrate", "set_threshold", None]
    # The replay leaves view 2 out as the operator did (the replay's operator answers nothing).
    summary = replay_session(tmp_path / "s")
    assert summary.identical == 1 and not summary.differences


def test_threshold_and_exclude_list_from_the_config_and_a_replay(tmp_path):
    plain = Collector()
    views = {"calibration_views": 9}  # two left out: 7, above the calibration's 5
    base = run_campaign(small_config(plan=ONE, capture=views), tmp_path / "plain", yes=True, subscribers=[plain])
    assert base.exit_status == "success"
    first = analysis_of(tmp_path / "plain")
    worst = [max(pair) for pair in first["per_view_rms_px"]]
    # A threshold between the two worst views' RMS leaves out exactly the worst; view 0 is excluded by name.
    ranked = sorted(range(len(worst)), key=worst.__getitem__)
    threshold = 0.5 * (worst[ranked[-1]] + worst[ranked[-2]])
    config = small_config(plan=ONE, capture=views, calibration={"max_view_rms_px": threshold, "exclude_views": [0]})
    summary = run_campaign(config, tmp_path / "chosen", yes=True)
    assert summary.exit_status == "success" and summary.rows[0]["status"] == "measured", summary.rows[0]
    chosen = analysis_of(tmp_path / "chosen")
    worst_view = first["views_used"][ranked[-1]]
    assert 0 not in chosen["views_used"] and worst_view not in chosen["views_used"]
    reasons = {r["index"]: r["reason"] for r in chosen["views_rejected"]}
    assert reasons[0] == "excluded by [calibration] exclude_views"
    assert reasons[worst_view].startswith("per-view RMS") and f"over the threshold {threshold:g} px" in reasons[
        worst_view]
    assert chosen["rms_px"] < first["rms_px"]
    assert replay_session(tmp_path / "chosen").identical == 1


def test_the_summary_marks_what_is_over_the_threshold_and_what_is_pending():
    class Calib:
        rms_px = 0.3
        per_view_rms_px = np.array([[0.2, 0.1], [0.5, 0.6], [0.3, 0.25]])

    class Analysis:
        calib = Calib()
        calibration_views_used = [0, 1, 3]
        calibration_views_rejected = [{"index": 2, "reason": "board not found in the right image"}]

    state = ReviewState(n_views=4)
    state.shown(Analysis(), None)
    assert not state.answer(SET_THRESHOLD, 0.4) and state.threshold == 0.4 and state.pending
    text = review_message("B1", state)
    lines = text.splitlines()
    assert lines[0] == "[B1] calibration: 4 views, 3 used, stereo RMS 0.300 px; threshold 0.4 px"
    assert lines[3].endswith("0.600  over the threshold") and lines[3].count("#") == 30  # the longest bar
    assert lines[4].endswith("-  board not found in the right image") and "#" not in lines[4]
    assert lines[2].count("#") == round(30 * 0.2 / 0.6)
    assert not state.answer(EXCLUDE_VIEW, 7) and "x needs a view number from 0 to 3" in state.note
    assert state.answer(RECALIBRATE, None)


def test_the_options_replace_the_config_keys_and_are_recorded(tmp_path, capsys):
    from stereo_bench.cli import main

    (tmp_path / "c.toml").write_text(CAMPAIGN.replace("calibration_views = 6", "calibration_views = 8"))
    code = main(["campaign", "run", str(tmp_path / "c.toml"), "--out", str(tmp_path / "s"), "--yes", "--quiet",
                 "--exclude-views", "1,3", "--max-view-rms-px", "5", "--no-review"])
    assert code == 0, capsys.readouterr().err
    recorded = SessionReader(tmp_path / "s").start().config["calibration"]
    assert recorded == {"max_view_rms_px": 5.0, "exclude_views": [1, 3], "review": False}
    calibration = analysis_of(tmp_path / "s")
    assert sorted(set(range(8)) - set(calibration["views_used"])) == [1, 3]
    for bad, message in ((["--max-view-rms-px", "0"], "must be a finite number"),
                         (["--exclude-views", "1,x"], "give view indices separated by commas"),
                         # checked against the views a configuration takes, before any motion
                         (["--exclude-views", "1,8"], "--exclude-views 1,8: calibration.exclude_views: no view 8: a "
                                                      "configuration takes views 0 to 7"),
                         (["--exclude-views", "0,1,2,3"], "leaves 4 of capture.calibration_views = 8, fewer than")):
        code = main(["campaign", "run", str(tmp_path / "c.toml"), "--out", str(tmp_path / "t"), "--yes", *bad])
        assert code == 2 and message in capsys.readouterr().err
        assert not (tmp_path / "t").exists()


@pytest.mark.slow
def test_views_taken_automatically_are_said_above_the_prompt_that_ends_them(tmp_path):
    auto = (CAMPAIGN.replace("[calibration]\nreview = true\n", "")
            .replace("settle_s = 0.1", 'settle_s = 0.1\ncalibration_capture = "auto"\ncoverage_gate = "count"')
            .replace('profile = "ideal"', 'profile = "ideal"\npresenter = "hand"'))
    (tmp_path / "c.toml").write_text(auto)
    terminal = Terminal([*STEREO_BENCH, "campaign", "run", "c.toml", "--out", "s"], tmp_path)
    terminal.until(lambda t: t.last_line().endswith("then press Enter"), what="the target prompt")
    terminal.child.send("\r")
    ending = "press Enter to calibrate with the views kept so far"
    terminal.until(lambda t: any("calibration view 2 kept (B100_Z450_A90, corners at" in line for line in t.lines())
                   and t.last_line().endswith(ending), what="a kept view said above the stream's prompt")
    _keep("calibration-stream.txt", terminal)
    terminal.until(lambda t: any("B100_Z450_A90: 6 calibration views kept of" in line for line in t.lines()),
                   what="the collection's summary")
    assert terminal.exit_status() == 0, terminal.text()
    lines = terminal.lines()
    (summary,) = [line for line in lines if "calibration views kept of" in line]
    assert "moving" in summary and "not new" in summary, summary
    assert "; the coverage gate ended it" in "".join(lines), terminal.text()  # (the line may wrap)
    assert sum("kept (B100_Z450_A90" in line for line in lines) == 6, terminal.text()
    assert any(line.endswith("(done: the coverage gate ended the collection)") for line in lines), terminal.text()
