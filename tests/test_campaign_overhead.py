"""What makes a campaign cheaper must not change what it records: frames rendered ahead by the simulator."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from stereo_bench.campaign.bench import simulated_bench
from stereo_bench.campaign.execute import run_campaign
from stereo_bench.campaign.session import SessionReader
from tests.campaigns import numbers, small_config


def _frames(session) -> dict[str, np.ndarray]:
    reader = SessionReader(session)
    return {f"{event.config_id}/{event.kind}/{event.data.index}/{side}": reader.frame(relative)
            for event in reader.events() if event.frames for side, relative in event.frames.items()}


@pytest.mark.slow
def test_a_campaign_records_the_same_frames_with_and_without_rendering_ahead(tmp_path):
    benches = []

    def counting_bench(config, **options):
        bench = simulated_bench(config, **options)
        benches.append(bench)
        return bench

    ahead, now = tmp_path / "ahead", tmp_path / "now"
    assert run_campaign(small_config(), ahead, yes=True, bench_factory=counting_bench).exit_status == "success"
    assert run_campaign(small_config(), now, yes=True,
                        bench_factory=functools.partial(simulated_bench, render_ahead=False)).exit_status == "success"
    # Pairs of the run that rendered ahead came from a render ahead (2 measured configurations x 8 pairs),
    # so the comparison below compares the two paths. How many is the machine's load's business: a pair
    # whose render had not started when the rig was triggered, after a settle of 2 ms at this time scale,
    # is rendered at the trigger (in a quiet run 8-16 were served ahead; on a loaded 2-core machine fewer).
    # scripts/bench_campaign.py measures the fraction.
    assert 1 <= benches[0].presenter.bench.prerendered_used <= 16
    frames_ahead, frames_now = _frames(ahead), _frames(now)
    assert sorted(frames_ahead) == sorted(frames_now) and len(frames_ahead) == 32
    for key, image in frames_ahead.items():
        np.testing.assert_array_equal(image, frames_now[key], err_msg=key)
    assert numbers(ahead) == numbers(now)


@pytest.mark.slow
def test_calibration_views_are_detected_once_while_capturing_and_the_analysis_uses_those(
        tmp_path, monkeypatch, small_reference):
    """An operator's coverage display and the calibration share one detection per image."""
    from stereo_bench.campaign import runner
    from stereo_bench.vision import pipeline

    board = small_config().calibration_board.build()
    detected: dict[int, int] = {}
    feedback = []

    def counting(real):
        def detect(image, target, **options):
            if target == board:
                detected[id(image)] = detected.get(id(image), 0) + 1
            return real(image, target, **options)
        return detect

    monkeypatch.setattr(runner, "detect", counting(runner.detect))
    monkeypatch.setattr(pipeline, "detect", counting(pipeline.detect))

    def operator_bench(config, **options):
        bench = simulated_bench(config, **options)
        bench.presenter.wants_detections = True  # as an operator's presenter: coverage after every view
        bench.presenter.calibration_view_captured = lambda index, left, right: feedback.append((left, right))
        return bench

    out = tmp_path / "session"
    assert run_campaign(small_config(), out, yes=True, bench_factory=operator_bench).exit_status == "success"
    assert len(feedback) == 2 * 6 and all(left is not None and right is not None for left, right in feedback)
    assert len(detected) == 2 * 6 * 2 and set(detected.values()) == {1}  # every view image, once
    assert numbers(out) == numbers(small_reference)
