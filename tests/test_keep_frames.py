"""[capture] keep_frames: which frames a session keeps, and what its replay can reproduce then."""

from __future__ import annotations

import json
import shutil

import pytest

from stereo_bench.campaign.execute import replay_session, run_campaign
from stereo_bench.campaign.session import SessionReader
from stereo_bench.cli import main
from tests.campaigns import interrupt_at_presentation, numbers, small_config

MEASURED = ["B100_Z450_A90", "B150_Z450_A90"]


@pytest.fixture(scope="module")
def kept(tmp_path_factory, small_reference):
    """The small campaign recorded with keep_frames = "measurement" and "none"."""
    root = tmp_path_factory.mktemp("keep_frames")
    sessions = {}
    for keep in ("measurement", "none"):
        out = root / keep
        summary = run_campaign(small_config(capture={"keep_frames": keep}), out, yes=True)
        assert summary.exit_status == "success"
        sessions[keep] = out
    return sessions


def test_keep_frames_is_all_by_default_and_names_are_exact():
    assert small_config().capture.keep_frames == "all"
    with pytest.raises(Exception, match="keep_frames"):
        small_config(capture={"keep_frames": "calibration"})


@pytest.mark.replay
@pytest.mark.slow
def test_measurement_keeps_measurement_frames_and_the_calibration_views_detections(kept, small_reference,
                                                                                  tmp_path):
    session = kept["measurement"]
    reader = SessionReader(session)
    views = reader.events(kind="calibration_view")
    assert len(views) == 2 * 6 and all(view.frames == {} for view in views)
    detections = reader.events(kind="calibration_detections")
    assert sorted((d.config_id, d.data.index) for d in detections) == sorted(
        (v.config_id, v.data.index) for v in views)
    assert all(len(getattr(d.data, side).ids) == 54 for d in detections for side in ("left", "right"))
    # Recorded detections carry their corner noise (views whose frames are kept are detected without it).
    assert all(len(getattr(d.data, side).sigma_px) == 54 and all(v > 0 for v in getattr(d.data, side).sigma_px)
               for d in detections for side in ("left", "right"))
    frames = reader.events(kind="measurement_frame")
    on_disk = sorted(p.relative_to(session).as_posix() for p in (session / "frames").rglob("*.png"))
    assert on_disk == sorted(f.frames[side] for f in frames for side in ("left", "right"))
    assert list(session.rglob("extrinsics.yml"))  # the calibrations are kept
    assert numbers(session) == numbers(small_reference)  # what is kept changes no number
    summary = replay_session(session)
    assert summary.compared == 2 and summary.identical == 2 and summary.differences == []
    assert summary.from_detections == MEASURED and summary.not_reproducible == {}
    # Replayed into a new session, it keeps what the recording kept (the recorded config says so).
    again = replay_session(session, tmp_path / "again")
    assert again.identical == 2
    assert len(SessionReader(tmp_path / "again").events(kind="calibration_detections")) == 2 * 6
    assert numbers(tmp_path / "again") == numbers(small_reference)


@pytest.mark.slow
def test_none_keeps_no_frame_and_its_replay_reproduces_nothing_and_fails(kept, small_reference, capsys):
    session = kept["none"]
    assert not list(session.rglob("*.png"))
    assert numbers(session) == numbers(small_reference)
    summary = replay_session(session)
    assert summary.compared == 0 and sorted(summary.not_reproducible) == MEASURED
    assert all('keep_frames = "none"' in why for why in summary.not_reproducible.values())
    assert main(["replay", str(session)]) == 1
    out = capsys.readouterr().out
    assert ('cannot reproduce, measurement frames not kept ([capture] keep_frames = "none"): all 2 ('
            + ", ".join(MEASURED) + ")") in out
    assert main(["replay", str(session), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["compared"] == 0 and sorted(report["not_reproducible"]) == MEASURED


@pytest.mark.replay
@pytest.mark.slow
def test_a_replay_reproduces_what_was_kept_and_succeeds(small_reference, tmp_path, capsys):
    """One configuration's measurement frames missing from the stream, the other's kept: exit 0, one listed."""
    session = tmp_path / "mixed"
    shutil.copytree(small_reference, session)
    lines = []
    for line in (session / "documents.jsonl").read_text().splitlines():
        doc = json.loads(line)
        if doc.get("kind") == "measurement_frame" and doc.get("config_id") == MEASURED[1]:
            doc["frames"] = {}
            line = json.dumps(doc)
        lines.append(line)
    (session / "documents.jsonl").write_text("\n".join(lines) + "\n")
    assert main(["replay", str(session)]) == 0
    out = capsys.readouterr().out
    assert "replayed 1 measured configurations" in out and "1 identical" in out
    assert f"cannot reproduce, measurement frames not kept ([capture] keep_frames = \"all\"): {MEASURED[1]}" in out


@pytest.mark.slow
def test_a_stop_at_once_while_detections_are_pending_still_leaves_a_session_that_resumes(tmp_path, small_reference):
    """keep_frames = "measurement": a view's detections are recorded once made; a second Ctrl-C mid-views
    drops the ones still queued, and the session resumes to the same numbers."""
    from stereo_bench.campaign.execute import RunControl

    config = small_config(capture={"keep_frames": "measurement"})
    out = tmp_path / "at-once"
    control = RunControl()
    # The tenth view presented: the second configuration's fourth.
    bench_interrupted = interrupt_at_presentation(control, "present_calibration_view", 6 + 4)

    summary = run_campaign(config, out, yes=True, control=control, bench_factory=bench_interrupted)
    assert summary.exit_status == "interrupted"
    reader = SessionReader(out)
    assert reader.stops()[-1].exit_status == "interrupted"
    detected = {(d.config_id, d.data.index) for d in reader.events(kind="calibration_detections",
                                                                          attempt=None)}
    views = {(v.config_id, v.data.index) for v in reader.events(kind="calibration_view", attempt=None)}
    assert detected <= views
    assert run_campaign(config, out, resume=True, yes=True).exit_status == "success"
    assert numbers(out) == numbers(small_reference)
    assert replay_session(out).identical == 2


def test_a_detection_cancelled_while_its_record_waits_for_it_is_recorded_as_none():
    # The recorder waits for a view's detections; a stop at once cancels those still queued meanwhile. Checking
    # cancelled() and then waiting raced: the wait raised CancelledError and failed the recording.
    import threading
    from concurrent.futures import Future

    from stereo_bench.campaign.runner import _record_or_none

    pending: Future = Future()
    threading.Timer(0.05, pending.cancel).start()
    assert _record_or_none(pending) is None
    failed: Future = Future()
    failed.set_exception(ValueError("corrupt image"))
    assert _record_or_none(failed) is None
    found: Future = Future()
    found.set_result(None)  # the board was not in the view
    assert _record_or_none(found) is None
