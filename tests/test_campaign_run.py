"""Campaigns end to end on the simulated rig: record, refuse to overwrite, SIGKILL + resume, Ctrl-C, replay."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stereo_bench.campaign.bench import simulated_bench
from stereo_bench.campaign.config import campaign_from_dict
from stereo_bench.campaign.documents import MoveEvent
from stereo_bench.campaign.execute import RunControl, run_campaign
from stereo_bench.campaign.session import SessionReader
from stereo_bench.cli import main

SAMPLE_SESSION = Path(__file__).resolve().parents[1] / "calib_data" / "sample_session"
REQUIRED_COLUMNS = ["config_id", "baseline_mm", "distance_mm", "alpha_deg", "status", "square_mean_mm",
                    "square_std_mm", "n_squares", "error_mm", "sigma_mm", "rms_px", "epipolar_rms_px"]
SMALL = """
name = "small"
seed = 7
[rig]
time_scale = 50
[cameras.optics]
width_px = 960
height_px = 540
pixel_um = 6.0
[calibration_board]
cols = 9
rows = 6
square_mm = 25
[capture]
calibration_views = 6
frames_per_config = 2
settle_s = 0.1
[plan]
baseline_mm = [100, 150]
distance_mm = [450]
alpha_deg = [90, 35]
"""


@pytest.fixture
def plan_file(tmp_path) -> Path:
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    return path


def results_csv(session: Path) -> list[dict]:
    with open(session / "results.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def test_campaign_records_a_complete_session(plan_file, tmp_path, capsys):
    out = tmp_path / "session"
    assert main(["campaign", "run", str(plan_file), "--out", str(out), "--yes", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert str(out / "results.csv") in printed and "stereo-bench report" in printed
    rows = results_csv(out)
    with open(out / "results.csv", newline="") as handle:
        assert next(csv.reader(handle))[: len(REQUIRED_COLUMNS)] == REQUIRED_COLUMNS
    by_id = {row["config_id"]: row for row in rows}
    assert sorted(by_id) == ["B100_Z450_A35", "B100_Z450_A90", "B150_Z450_A35", "B150_Z450_A90"]
    for config_id in ("B100_Z450_A90", "B150_Z450_A90"):
        assert by_id[config_id]["status"] == "measured"
        assert abs(float(by_id[config_id]["error_mm"])) <= 0.1
        assert int(by_id[config_id]["n_squares"]) == 2 * 93
    assert by_id["B100_Z450_A35"]["status"] == "infeasible" and "view" in by_id["B100_Z450_A35"]["reason"]
    reader = SessionReader(out)
    kinds = [doc.get("kind") for doc in reader.events()]
    assert kinds.count("calibration_view") == 2 * 6 and kinds.count("measurement_frame") == 2 * 2
    for event in reader.events(kind="measurement_frame"):
        assert reader.frame(event["frames"]["left"]).shape == (540, 960)
    assert (out / "calib").is_dir() and list((out / "calib").rglob("extrinsics.yml"))
    assert list((out / "transcripts").glob("serial-*.jsonl"))  # every byte to and from the controller
    assert reader.stops()[-1]["exit_status"] == "success"


def test_an_existing_session_is_never_overwritten(plan_file, tmp_path, capsys):
    out = tmp_path / "session"
    out.mkdir()
    (out / "notes.txt").write_text("precious")
    assert main(["campaign", "run", str(plan_file), "--out", str(out), "--yes", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and len(err.strip().splitlines()) == 1
    assert (out / "notes.txt").read_text() == "precious"


def test_manual_steps_without_an_operator_are_a_clear_error(plan_file, tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "stereo_bench", "campaign", "run", str(plan_file), "--out", str(tmp_path / "s"),
         "--quiet"], stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2
    assert "standard input is closed" in result.stderr and "--yes" in result.stderr


def _numbers(session: Path) -> dict[str, tuple]:
    return {row["config_id"]: (row["status"], row["square_mean_mm"], row["square_std_mm"], row["sigma_mm"],
                               row["rms_px"]) for row in results_csv(session)}


def test_sigkill_mid_campaign_then_resume_gives_every_configuration_once_with_the_same_numbers(plan_file, tmp_path):
    reference = tmp_path / "reference"
    run_campaign(campaign_from_dict(__import__("tomllib").loads(SMALL)), reference, yes=True)
    out = tmp_path / "killed"
    command = [sys.executable, "-m", "stereo_bench", "campaign", "run", str(plan_file), "--out", str(out), "--yes",
               "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    stream = out / "documents.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # kill once the first measured result is on disk
        if stream.exists() and '"measured"' in stream.read_text():
            break
        time.sleep(0.05)
    os.kill(process.pid, signal.SIGKILL)
    process.wait(timeout=30)
    assert len(SessionReader(out).completed_config_ids()) < 4  # it really was interrupted
    resumed = subprocess.run(command + ["--resume"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    reader = SessionReader(out)
    results = [doc for doc in reader.documents() if doc["type"] == "result"]
    assert sorted(doc["config_id"] for doc in results) == sorted(set(doc["config_id"] for doc in results))
    assert _numbers(out) == _numbers(reference)
    assert reader.attempts() == [1, 2]


def test_stop_request_leaves_a_resumable_session(tmp_path):
    config = campaign_from_dict(__import__("tomllib").loads(SMALL))
    out = tmp_path / "stopped"
    control = RunControl()
    moves = []

    def stop_at_second_move(document):  # a subscriber, as a live page's Stop button would be
        if isinstance(document, MoveEvent):
            moves.append(document)
            if len(moves) == 2:
                control.request_stop()

    summary = run_campaign(config, out, yes=True, subscribers=[stop_at_second_move], control=control,
                           resume_command="stereo-bench campaign run small.toml --out stopped --resume")
    assert summary.exit_status == "interrupted"
    stop = SessionReader(out).stops()[-1]
    assert stop["exit_status"] == "interrupted" and stop["resume_command"].endswith("--resume")
    done = SessionReader(out).completed_config_ids()
    assert 1 <= len(done) < 4
    resumed = run_campaign(config, out, resume=True, yes=True)
    assert resumed.exit_status == "success" and resumed.skipped == len(done)
    assert len(SessionReader(out).completed_config_ids()) == 4


def test_replay_of_the_shipped_session_reproduces_its_results_exactly(capsys):
    assert main(["replay", str(SAMPLE_SESSION), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["compared"] >= 2 and report["identical"] == report["compared"] and report["differences"] == []


def test_replay_into_a_new_session_and_reanalysis(tmp_path, capsys):
    out = tmp_path / "replayed"
    assert main(["replay", str(SAMPLE_SESSION), "--out", str(out)]) == 0
    assert _numbers(out) == _numbers(SAMPLE_SESSION)
    assert main(["replay", str(SAMPLE_SESSION), "--intrinsics", "fixed"]) == 2  # a re-analysis needs --out
    assert "--out" in capsys.readouterr().err
    assert main(["replay", str(SAMPLE_SESSION), "--intrinsics", "fixed", "--out", str(tmp_path / "fixed")]) == 0
    reanalysed = _numbers(tmp_path / "fixed")
    assert reanalysed.keys() == _numbers(SAMPLE_SESSION).keys()


def test_replay_refuses_a_manifest_path_outside_the_session(tmp_path, capsys):
    session = tmp_path / "tampered"
    shutil.copytree(SAMPLE_SESSION, session)
    stream = session / "documents.jsonl"
    lines = stream.read_text().splitlines()
    for i, line in enumerate(lines):
        doc = json.loads(line)
        if doc.get("kind") == "measurement_frame":
            doc["frames"]["left"] = "../../../etc/passwd"
            lines[i] = json.dumps(doc)
            break
    stream.write_text("\n".join(lines) + "\n")
    assert main(["replay", str(session)]) == 2
    err = capsys.readouterr().err
    assert "outside" in err or "refus" in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("executor", ["local", "dask"])
def test_batch_reanalysis_of_several_sessions_goes_through_the_executor(executor, tmp_path, capsys):
    if executor == "dask":
        pytest.importorskip("distributed")
    first, second = tmp_path / "first", tmp_path / "second"
    shutil.copytree(SAMPLE_SESSION, first)
    shutil.copytree(SAMPLE_SESSION, second)
    code = main(["replay", str(first), str(second), "--intrinsics", "fixed", "--out", str(tmp_path / "re"),
                 "--executor", executor, "--workers", "2", "--json"])
    assert code == 0
    reports = json.loads(capsys.readouterr().out)["sessions"]
    assert [Path(r["session"]).name for r in reports] == ["first", "second"]
    # Same frames, same pipeline: the two re-analyses agree to the last digit, whichever worker ran them.
    assert _numbers(tmp_path / "re" / "first") == _numbers(tmp_path / "re" / "second")


def test_a_frame_without_the_target_is_captured_again_and_replays(tmp_path):
    config = campaign_from_dict(__import__("tomllib").loads(SMALL))
    out = tmp_path / "retry"

    def bench_where_someone_walks_in_front_once(config, **options):
        bench = simulated_bench(config, **options)
        presenter, shown = bench.presenter, []

        def present_target(frame_index):
            presenter.__class__.present_target(presenter, frame_index)
            if not shown:  # someone walked in front of the rig: the first frame shows only the wall
                shown.append(frame_index)
                presenter.bench.show(None)

        presenter.present_target = present_target
        return bench

    summary = run_campaign(config, out, yes=True, bench_factory=bench_where_someone_walks_in_front_once)
    assert summary.counts()["measured"] == 2
    reader = SessionReader(out)
    missed = reader.events(kind="target_not_found")
    assert len(missed) == 1 and missed[0]["data"]["retry"] == 0 and missed[0]["data"]["missing"] == ["left", "right"]
    first = [e["data"] for e in reader.events(config_id=missed[0]["config_id"], kind="measurement_frame")]
    assert [(d["index"], d["retry"]) for d in first][:2] == [(0, 0), (0, 1)]
    # The replay asks for the same re-capture and finds the same numbers.
    assert main(["replay", str(out)]) == 0
