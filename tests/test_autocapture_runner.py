"""Calibration views taken automatically by the campaign runner (``[capture] calibration_capture = "auto"``) on the
simulated lab bench, the board presented by the simulated hand (drivers/sim/hand.py), against Enter-to-capture with
the same hand; and the replay of such a session."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stereo_bench.campaign import presentation
from stereo_bench.campaign.config import load_campaign
from stereo_bench.campaign.documents import (
    CalibrationEvent,
    CalibrationSelectionEvent,
    CalibrationViewEvent,
    PresentationTimeEvent,
)
from stereo_bench.campaign.eta import forecast_groups
from stereo_bench.campaign.execute.planned import CampaignPlan
from stereo_bench.campaign.execute.replay import replay_session
from stereo_bench.campaign.execute.run import run_campaign
from stereo_bench.campaign.session import SessionReader
from stereo_bench.campaign.stream import Collector
from stereo_bench.cli import main
from stereo_bench.vision.calibrate import calibrate_stereo
from stereo_bench.vision.detect import detect
from tests.campaigns import lab_config

VIEWS = 8
ONE = {"baseline_mm": [100], "distance_mm": [450], "alpha_deg": [90]}


def hand_config(mode: str, **capture):
    return lab_config(capture={"calibration_views": VIEWS, "calibration_capture": mode, "coverage_gate": "count",
                               **capture}, sim={"presenter": "hand"}, plan=ONE)


def ungated_rms(session, config) -> float:
    """Stereo RMS (px) of a session's calibration views calibrated jointly as they are, no quality gate (Enter's
    views with the hand are refused by the sharpness gate: the RMS says how much worse they fit)."""
    reader = SessionReader(session)
    board = config.calibration_board.build()
    views = []
    for event in reader.events(kind=CalibrationViewEvent):
        left, right = (detect(reader.frame(event.frames[side]), board) for side in ("left", "right"))
        if left is not None and right is not None and left.n == right.n == len(board.object_points):
            views.append((left, right))
    objects = [np.asarray(board.object_points, np.float64)[left.ids] for left, _ in views]
    size = views[0][0].image_size
    stereo = calibrate_stereo(objects, [left.corners_px for left, _ in views],
                              [right.corners_px[np.argsort(right.ids)][left.ids] for left, right in views], size,
                              covariance=False)
    return float(stereo.rms_px)


@pytest.fixture(scope="module")
def hand_sessions(tmp_path_factory):
    """One configuration on the lab bench, the board presented by the simulated hand: views taken automatically
    (kept as detections) and by Enter as the hand stops. (summary, collector, config) per mode."""
    base = tmp_path_factory.mktemp("hand")
    sessions = {}
    for mode, capture in (("auto", {"keep_frames": "measurement"}), ("enter", {})):
        config = hand_config(mode, **capture)
        collected = Collector()
        # each in a directory of its own: the presentation time is written beside the session
        summary = run_campaign(config, base / mode / "session", yes=True, subscribers=[collected])
        assert summary.exit_status == "success"
        sessions[mode] = (summary, collected, config)
    return sessions


def test_auto_capture_keeps_still_new_views_of_the_hand_and_fits_better_than_enter(hand_sessions):
    auto, collected, _ = hand_sessions["auto"]
    (row,) = auto.rows
    assert row["status"] == "measured", row.get("reason")
    (selection,) = collected.of(CalibrationSelectionEvent)
    data = selection.data
    # The count gate opened at VIEWS kept; every pair offered has its decision, the rejected ones their reasons.
    assert data.kept == VIEWS and data.ended_by == "the coverage gate" and len(data.decisions) == data.offered
    assert data.tally["kept"] == VIEWS and sum(data.tally.values()) == data.offered
    for reason in ("moving", "settling", "not new", "not in both views"):
        assert data.tally[reason] > 0, (reason, data.tally)
    views = collected.of(CalibrationViewEvent)
    assert [v.data.index for v in views] == list(range(VIEWS))
    # Every view kept was still (30 px/s) in both cameras and new (0.2) against the ones before it.
    assert all(v.data.auto.speed_px_s <= 30.0 for v in views)
    assert all(v.data.auto.novelty is None or v.data.auto.novelty >= 0.2 for v in views)
    kept_times = [d[0] for d in data.decisions if d[1] == "kept"]
    assert kept_times == [v.data.auto.time_s for v in views]
    # The presentation time is the hand's, on the bench clock: from the first pair to the gate (hand: 0.6 s moves,
    # 0.6-1.8 s holds; at 10 fps a view every ~1.5-3 s).
    (presented,) = collected.of(PresentationTimeEvent)
    assert presented.data.views == VIEWS and presented.data.clock == "bench" and presented.data.capture == "auto"
    # (from before the first pair's exposure to after the last one's: collect_s is between their time stamps)
    assert presented.data.seconds == pytest.approx(data.collect_s, abs=0.05)
    assert 1.0 < presented.data.seconds / VIEWS < 4.0
    auto_rms = collected.of(CalibrationEvent)[0].data.rms_px

    enter, enter_collected, enter_config = hand_sessions["enter"]
    assert not enter_collected.of(CalibrationSelectionEvent)
    assert len(enter_collected.of(CalibrationViewEvent)) == VIEWS
    enter_rms = ungated_rms(enter.session, enter_config)
    # Enter as the hand stops takes some views moving: they fit worse (scripts/bench_autocapture_runner.py, 5 seeds:
    # auto 0.204-0.220 px; Enter 0.214-0.363 px without the gates, 3 of 5 refused by the sharpness gate; this seed
    # 0.211 against 0.363, 2026-12-08).
    assert auto_rms < 0.25 and enter_rms > auto_rms + 0.02, (auto_rms, enter_rms, enter.rows[0].get("reason"))


@pytest.mark.replay
def test_a_session_of_views_taken_automatically_replays(hand_sessions):
    auto, _, _ = hand_sessions["auto"]
    # The views it kept (as detections here) calibrate to the same numbers.
    summary = replay_session(auto.session)
    assert summary.compared == 1 and summary.identical == 1 and not summary.differences
    assert summary.from_detections == [auto.rows[0]["config_id"]]


def test_a_replay_into_a_new_session_carries_how_the_views_were_taken(hand_sessions, tmp_path):
    from stereo_bench.campaign.session import SessionReader

    auto, _, _ = hand_sessions["auto"]
    replay_session(auto.session, tmp_path / "again")
    recorded, again = SessionReader(auto.session), SessionReader(tmp_path / "again")
    for kind in ("calibration_selection", "presentation_time"):
        before = [e.data.model_dump() for e in recorded.events(kind=kind, attempt=None)]
        after = [e.data.model_dump() for e in again.events(kind=kind, attempt=None)]
        assert before and after == before, kind


BENCH = """\
[plan]
baseline_mm = [100, 150]
distance_mm = [400]
alpha_deg = [90]
[rig]
kind = "grbl"
port = "/dev/ttyUSB7"
[cameras]
kind = "v4l2"
left = "usb-port:1-1"
right = "usb-port:1-2"
"""


def test_the_measured_presentation_time_feeds_the_next_plan_and_its_eta(hand_sessions, tmp_path, capsys):
    auto, collected, _ = hand_sessions["auto"]
    (presented,) = collected.of(PresentationTimeEvent)
    written = auto.session.parent / presentation.FILE_NAME
    assert auto.presentation_file == written and written.is_file()
    following = auto.session.parent / "next"  # the next run's --out, beside the first
    measured, note = presentation.read_beside(following)
    assert note is None and measured.views == VIEWS and measured.capture == "auto" and measured.clock == "bench"
    assert measured.seconds_per_view == pytest.approx(presented.data.seconds / VIEWS)

    path = tmp_path / "bench.toml"
    path.write_text(BENCH)
    assert main(["campaign", "plan", str(path), "--json"]) == 0
    assumed = json.loads(capsys.readouterr().out)
    assert main(["campaign", "plan", str(path), "--json", "--out", str(following)]) == 0
    planned = json.loads(capsys.readouterr().out)
    # 2 configurations x 12 calibration views presented by hand: 5 s each assumed, the measured figure now
    views = planned["calibration_presentations"]["total"]
    assert views == 24 and assumed["presentation_time"]["source"] == "assumed"
    assert planned["presentation_time"] == {**planned["presentation_time"], "source": "measured",
                                            "file": str(written)}
    assert assumed["duration"]["operator_s"] - planned["duration"]["operator_s"] == pytest.approx(
        views * (5.0 - measured.seconds_per_view))
    assert main(["campaign", "plan", str(path), "--out", str(following)]) == 0
    text = capsys.readouterr().out
    assert f"presentation time: measured, {measured.seconds_per_view:.2f} s per view, from {written}" in text
    assert f"{measured.seconds_per_view:.2f} s per calibration view presented by hand, measured over {VIEWS}" in text
    # The run's ETA starts from the same model: 12 views per configuration at the measured figure, and the one
    # target prompt (one distance) at 30 s
    config = load_campaign(path)
    forecast = forecast_groups(config, CampaignPlan.of(config).steps, presentation=measured)
    assert [g.operator_s for g in forecast.groups] == pytest.approx(
        [30.0 + 12 * measured.seconds_per_view, 12 * measured.seconds_per_view])
    assert sum(g.operator_s for g in forecast.groups) == pytest.approx(planned["duration"]["operator_s"])
    # a file that is not one is said in one line and the assumed figure is used
    written_text = written.read_text()
    try:
        written.write_text("{")
        assert main(["campaign", "plan", str(path), "--out", str(following)]) == 0
        out, err = capsys.readouterr()
        assert f"note: {written}: unreadable" in err and "presentation time: assumed, 5 s per view" in out
    finally:
        written.write_text(written_text)
