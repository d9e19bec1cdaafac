"""The simulated lab bench is a function of its seed and the plan only (issue 19, item 2).

Its time is the bench clock's (drivers/sim/clock.py), its draws are keyed by configuration, and a resumed
run re-approaches each configuration as the uninterrupted one did (campaign/approach.py). So on the lab
bench (backlash, landing errors, placement errors, heads ringing for 0.24 s after a move), with a settle
of 0.1 s, shorter than the ringing, a run gives the same results.csv and the same truth at any
``time_scale``, and so does a run stopped or killed at any point and resumed. (The benchmark with CPU hogs
beside the runs and kills at random moments is scripts/bench_determinism.py; nothing here is timed.)
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stereo_bench.campaign.execute import RunControl, run_campaign
from stereo_bench.campaign.session import SessionReader
from tests.campaigns import LAB, lab_config, recorded_outcome, stop_at_move

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def lab_reference(tmp_path_factory) -> Path:
    """The lab campaign, uninterrupted, at its time scale (50)."""
    out = tmp_path_factory.mktemp("lab") / "reference"
    summary = run_campaign(lab_config(), out, yes=True)
    assert summary.exit_status == "success" and summary.counts() == {"measured": 4}, summary
    return out


def test_the_settle_is_shorter_than_the_ringing_so_the_frames_ring(lab_reference):
    """Not vacuous: the captures see the heads ring (on the wall clock, their phase would follow the machine's load)."""
    assert any(event.data.left.meta["truth"]["ringing_deg"] != 0.0
               for event in SessionReader(lab_reference).events(kind="calibration_view"))


def test_a_run_at_another_time_scale_records_the_same_results_and_truth(lab_reference, tmp_path):
    out = tmp_path / "slower"
    summary = run_campaign(lab_config(rig={"time_scale": 7}), out, yes=True)
    assert summary.exit_status == "success"
    assert recorded_outcome(out) == recorded_outcome(lab_reference)


def test_a_run_stopped_mid_distance_and_resumed_records_what_an_uninterrupted_one_does(lab_reference, tmp_path):
    """Stopped as the rig reached the fourth configuration (the same target placement as the first three):
    the resume homes, re-approaches the slide from B = 100 mm (from home it would come from above), goes to the
    third configuration's pose and moves from there, as the uninterrupted run did; the placement is kept."""
    config, out, control = lab_config(), tmp_path / "stopped", RunControl()
    summary = run_campaign(config, out, yes=True, bench_factory=stop_at_move(control, 4), control=control)
    assert summary.exit_status == "interrupted" and len(SessionReader(out).completed_config_ids()) == 3
    assert run_campaign(config, out, resume=True, yes=True).exit_status == "success"
    reader = SessionReader(out)
    approaches = [event.data.target for event in reader.events(kind="approach", attempt=2)]
    assert approaches == [{"baseline_mm": 100.0},
                          {"baseline_mm": 150.0, "toe_in_left_deg": 3.0, "toe_in_right_deg": 3.0}]
    assert not reader.events(kind="approach", attempt=1)  # an uninterrupted run never re-approaches
    assert recorded_outcome(out, clock=False) == recorded_outcome(lab_reference, clock=False)


def test_a_run_killed_and_resumed_records_what_an_uninterrupted_one_does(lab_reference, tmp_path):
    """SIGKILL as soon as two configurations have their results (the rig at the third or the fourth, its captures
    or analyses still to come), at another time scale: the resume re-approaches, runs the rest, and every number
    is the uninterrupted run's."""
    plan = tmp_path / "lab.toml"
    plan.write_text(LAB.replace("time_scale = 50", "time_scale = 20"))
    out = tmp_path / "killed"
    command = [sys.executable, "-m", "stereo_bench", "campaign", "run", str(plan), "--out", str(out), "--yes",
               "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    stream, deadline = out / "documents.jsonl", time.monotonic() + 120
    while process.poll() is None and not (stream.exists() and stream.read_text().count('"type": "result"') >= 2):
        assert time.monotonic() < deadline, "no two results recorded"
        time.sleep(0.005)
    os.kill(process.pid, signal.SIGKILL)
    process.wait(timeout=30)
    assert len(SessionReader(out).completed_config_ids()) < 4  # it really was interrupted
    resumed = subprocess.run(command + ["--resume"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert SessionReader(out).events(kind="approach", attempt=2)  # the rig re-approached after homing
    assert recorded_outcome(out, clock=False) == recorded_outcome(lab_reference, clock=False)
