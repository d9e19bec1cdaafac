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
    return {f"{event['config_id']}/{event['kind']}/{event['data']['index']}/{side}": reader.frame(relative)
            for event in reader.events() if event.get("frames") for side, relative in event["frames"].items()}


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
    # Every pair of the run that rendered ahead came from a render ahead (2 measured configurations x 8 pairs).
    assert benches[0].presenter.bench.prerendered_used == 16
    frames_ahead, frames_now = _frames(ahead), _frames(now)
    assert sorted(frames_ahead) == sorted(frames_now) and len(frames_ahead) == 32
    for key, image in frames_ahead.items():
        np.testing.assert_array_equal(image, frames_now[key], err_msg=key)
    assert numbers(ahead) == numbers(now)
