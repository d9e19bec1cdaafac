"""Automatic capture of calibration views (stereo_bench.campaign.autocapture) and the simulated hand that presents
the board (drivers.sim.hand)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.hand import HandFigures, HandPresentation
from stereo_bench.campaign.autocapture import AutoCaptureRule, ViewSelector, corner_speed_px_s, novelty
from stereo_bench.campaign.coverage import ViewParameters
from stereo_bench.targets import Checkerboard
from stereo_bench.vision.detect import Detection

BOARD = Checkerboard(11, 8, 25.0)
SIZE = (1920, 1080)


def seen(offset_px=(0.0, 0.0), scale=1.0, ids=None) -> Detection:
    """A detection of the board as a camera 1 px per 0.25 mm... would see it: its grid scaled and shifted."""
    points = np.asarray(BOARD.object_points, np.float64)[:, :2] * 2.0 * scale + np.array([400.0, 300.0])
    points = points + np.asarray(offset_px)
    ids = np.arange(len(points)) if ids is None else np.asarray(ids)
    return Detection(ids=ids, corners_px=points[ids], image_size=SIZE, order="colour")


def test_corner_speed_and_novelty():
    assert corner_speed_px_s(seen(), seen((3.0, 4.0)), 0.5) == pytest.approx(10.0)
    assert corner_speed_px_s(seen(ids=[0, 1]), seen(ids=[5, 6]), 0.1) is None
    a, b = ViewParameters(0.1, 0.2, 0.3, 0.4), ViewParameters(0.2, 0.2, 0.3, 0.1)
    assert novelty(a, []) == float("inf") and novelty(a, [b, a]) == 0.0 and novelty(a, [b]) == pytest.approx(0.4)


def offer_still(selector, t0, detection, *, fps=10.0, seconds=1.0):
    decisions = []
    for k in range(int(seconds * fps)):
        decisions.append(selector.offer(t0 + k / fps, detection, detection))
    return decisions


def test_a_still_new_whole_board_is_kept_once_it_has_settled():
    selector = ViewSelector(AutoCaptureRule(settle_s=0.3, min_views=2, gate="count"), BOARD, SIZE)
    reasons = [d.reason for d in offer_still(selector, 0.0, seen())]
    # the first pair has no speed yet; still from it on, kept once 0.3 s have passed; the same view again is not new
    assert reasons[:3] == ["settling", "settling", "settling"] and reasons[3] == "kept"
    assert set(reasons[4:]) == {"not new"} and selector.n_kept == 1
    # moving: 50 px between frames at 10 fps is 500 px/s
    moving = [selector.offer(2.0 + k / 10, seen((50.0 * k, 0)), seen((50.0 * k, 0))) for k in range(3)]
    assert [d.reason for d in moving][1:] == ["moving", "moving"] and moving[2].speed_px_s == pytest.approx(500.0)
    # half out of a view: not kept however still
    half = seen(ids=np.arange(44))
    assert {selector.offer(3.0 + k / 10, seen((600, 400)), half).reason for k in range(10)} == {"not in both views"}
    # a new pose, held: kept, and with two views the count gate opens
    assert "kept" in [d.reason for d in offer_still(selector, 5.0, seen((900.0, 500.0), scale=0.8))]
    assert selector.gate_open() == (True, "2 views kept")
    assert selector.offer(9.0, seen(), seen()).reason == "gate open"
    tally = selector.tally()
    # moving: the two moves, and the first pair at the new pose (the board came from half out of view)
    assert tally["kept"] == 2 and tally["moving"] == 3 and tally["not in both views"] == 10


def test_the_bars_gate_waits_for_full_coverage():
    selector = ViewSelector(AutoCaptureRule(settle_s=0.0, min_views=2, max_views=40), BOARD, SIZE)
    offer_still(selector, 0.0, seen(), seconds=0.3)
    offer_still(selector, 1.0, seen((900.0, 0.0)), seconds=0.3)
    is_open, why = selector.gate_open()
    assert not is_open and why.startswith("bars short: left X")
    with pytest.raises(ValueError, match="min_views"):
        AutoCaptureRule(min_views=50, max_views=40)


def test_the_hand_is_a_function_of_seed_and_time():
    poses = []
    for k in range(6):
        pose = np.eye(4)
        pose[:3, 3] = [-150.0 + 60.0 * k, -80.0 + 30.0 * (k % 3), 450.0 + 20.0 * k]
        poses.append(pose)
    hand = HandPresentation(poses, seed=3, figures=HandFigures(p_half_out=0.5))
    again = HandPresentation(poses, seed=3, figures=HandFigures(p_half_out=0.5))
    times = np.arange(0.0, hand.duration_s, 0.01)
    track = np.array([hand.pose_at(t)[:3, 3] for t in times])
    assert np.array_equal(track, np.array([again.pose_at(t)[:3, 3] for t in times]))
    speed = np.linalg.norm(np.diff(track, axis=0), axis=1) / 0.01
    # a minimum-jerk move peaks at 1.875x its mean speed; tremor adds ~2 pi 10 Hz x 0.2 mm x 2 waves
    assert speed.max() < 1.875 * 250.0 + 40.0
    assert len(hand.holds) == 6 and any(s.kind == "move" for s in hand.segments)
    for start, end, index in hand.holds:
        held = np.array([hand.pose_at(t)[:3, 3] for t in np.arange(start, end, 0.01)])
        # while held: within the sag (5 mm/s x 1.8 s) and the tremor of the presented pose
        assert np.abs(held - poses[index][:3, 3]).max() < 5.0 * 1.8 + 1.0
        assert hand.still_at(0.5 * (start + end)) == index
    # with p_half_out 0.5 some presentations first swing the board a board's width aside
    assert len(hand.segments) > 2 * len(poses)
