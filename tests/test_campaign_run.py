"""Campaigns end to end on the simulated rig: record, --json, refuse to overwrite, SIGKILL + resume, stop, replay."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import select
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from stereo_bench.campaign.bench import simulated_bench
from stereo_bench.campaign.execute import RunControl, replay_session, run_campaign
from stereo_bench.campaign.session import SessionReader
from stereo_bench.cli import main
from tests.campaigns import (
    SAMPLE_SESSION,
    SMALL,
    interrupt_at_presentation,
    numbers,
    results_csv,
    small_config,
    stop_at_move,
)

REQUIRED_COLUMNS = ["config_id", "baseline_mm", "distance_mm", "alpha_deg", "status", "square_mean_mm",
                    "square_std_mm", "n_squares", "error_mm", "sigma_mm", "rms_px", "epipolar_rms_px"]


@pytest.fixture
def plan_file(tmp_path) -> Path:
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    return path


@pytest.mark.slow
def test_campaign_records_a_complete_session_and_streams_every_document_as_json(plan_file, tmp_path, capsys):
    out = tmp_path / "session"
    assert main(["campaign", "run", str(plan_file), "--out", str(out), "--yes", "--quiet", "--json"]) == 0
    captured = capsys.readouterr()
    # --json: stdout is the document stream, line for line as recorded; the summary goes to stderr.
    assert captured.out == (out / "documents.jsonl").read_text()
    assert str(out / "results.csv") in captured.err and "stereo-bench report" in captured.err
    types = [json.loads(line)["type"] for line in captured.out.splitlines()]
    assert types[0] == "start" and types[-1] == "stop" and types.count("result") == 4
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
    kinds = [doc.kind for doc in reader.events()]
    assert kinds.count("calibration_view") == 2 * 6 and kinds.count("measurement_frame") == 2 * 2
    for event in reader.events(kind="measurement_frame"):
        assert reader.frame(event.frames["left"]).shape == (540, 960)
    # The target distance is set by hand: one prompt (Z = 450 once), answered by the simulator (--yes).
    (prompt,) = reader.events(kind="prompt")
    assert prompt.data.quantity == "target_distance_mm" and prompt.data.value == 450.0
    assert prompt.data.answered_by == "simulator" and "Z = 450 mm" in prompt.data.message
    assert reader.start().bench == "simulated"
    assert (out / "calib").is_dir() and list((out / "calib").rglob("extrinsics.yml"))
    assert list((out / "transcripts").glob("serial-*.jsonl"))  # every byte to and from the controller
    assert reader.stops()[-1].exit_status == "success"


def test_an_existing_session_is_never_overwritten(plan_file, tmp_path, capsys):
    out = tmp_path / "session"
    out.mkdir()
    (out / "notes.txt").write_text("precious")
    assert main(["campaign", "run", str(plan_file), "--out", str(out), "--yes", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and len(err.strip().splitlines()) == 1
    assert (out / "notes.txt").read_text() == "precious"


@pytest.mark.slow
def test_manual_steps_without_an_operator_are_a_clear_error(plan_file, tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "stereo_bench", "campaign", "run", str(plan_file), "--out", str(tmp_path / "s"),
         "--quiet"], stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 2
    assert "standard input is closed" in result.stderr and "--yes" in result.stderr


@pytest.fixture
def long_settle_plan_file(tmp_path) -> Path:
    """The small plan with a settle of 1 s (real): time to signal or kill a run at a configuration before its
    captures, which take a few ms once the simulator has rendered them ahead (the numbers do not depend on it)."""
    path = tmp_path / "small-long-settle.toml"
    path.write_text(SMALL.replace("settle_s = 0.1", "settle_s = 50"))
    return path


def _launch(plan_file: Path, out: Path, *more: str) -> subprocess.Popen:
    command = [sys.executable, "-m", "stereo_bench", "campaign", "run", str(plan_file), "--out", str(out), "--yes",
               "--quiet", *more]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_first_result(process: subprocess.Popen, out: Path) -> None:
    stream = out / "documents.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if stream.exists() and '"measured"' in stream.read_text():
            return
        time.sleep(0.05)
    raise AssertionError(f"no measured result before the campaign ended: {process.communicate()}")


def _wait_for_the_last_move(process: subprocess.Popen, out: Path) -> None:
    """Until the rig stands at the last configuration (B150_Z450_A90): its settle and captures are still ahead."""
    stream = out / "documents.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if stream.exists() and stream.read_text().count('"kind": "move"') == 2:
            return
        time.sleep(0.02)
    raise AssertionError(f"the rig never reached the last configuration: {process.communicate()}")


@pytest.mark.slow
def test_sigkill_mid_campaign_then_resume_gives_every_configuration_once_with_the_same_numbers(
        long_settle_plan_file, tmp_path, small_reference):
    out = tmp_path / "killed"
    process = _launch(long_settle_plan_file, out)
    _wait_for_first_result(process, out)
    os.kill(process.pid, signal.SIGKILL)
    process.wait(timeout=30)
    assert len(SessionReader(out).completed_config_ids()) < 4  # it really was interrupted
    resumed = subprocess.run(process.args + ["--resume"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    reader = SessionReader(out)
    results = [doc for doc in reader.documents() if doc.type == "result"]
    assert sorted(doc.config_id for doc in results) == sorted(set(doc.config_id for doc in results))
    assert numbers(out) == numbers(small_reference)
    assert reader.attempts() == [1, 2]


def _run_printed(command: str, **options) -> subprocess.CompletedProcess:
    """Run a command the CLI printed (``stereo-bench ...``) as a user would paste it, with this interpreter."""
    argv = shlex.split(command)
    assert argv[0] == "stereo-bench", command
    return subprocess.run([sys.executable, "-m", "stereo_bench", *argv[1:]], capture_output=True, text=True,
                          timeout=300, **options)


@pytest.mark.slow
def test_sigterm_stops_like_ctrl_c_and_the_printed_command_resumes(long_settle_plan_file, tmp_path, small_reference):
    """The printed resume command carries whatever went into the recorded config: a run started with --time-scale
    (not in the file) printed one without it, which was refused ("cannot resume with a different config")."""
    out = tmp_path / "terminated out"  # a space: the command must still paste as one --out
    process = _launch(long_settle_plan_file, out, "--time-scale", "40")
    _wait_for_the_last_move(process, out)
    process.send_signal(signal.SIGTERM)  # what systemd and docker stop send
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    stop = SessionReader(out).stops()[-1]
    assert stop.exit_status == "interrupted" and stop.reason == "stopped by SIGTERM"
    assert stop.resume_command == f"stereo-bench campaign run --out '{out}' --resume --yes"
    assert f"resume:   {stop.resume_command}\n" in stdout and "SIGTERM: stopping at the next safe point" in stderr
    assert len(SessionReader(out).completed_config_ids()) == 3
    resumed = _run_printed(stop.resume_command, cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert SessionReader(out).start().config["rig"]["time_scale"] == 40
    assert numbers(out) == numbers(small_reference)


@pytest.mark.slow
def test_sighup_of_a_closed_terminal_stops_like_ctrl_c_and_the_session_resumes(long_settle_plan_file, tmp_path,
                                                                              small_reference):
    """An ssh session that ends: the terminal hangs up (every write to it fails) and SIGHUP comes. The run stops at
    the next safe point with its stop recorded (it was killed without one) and exits 130."""
    out = tmp_path / "hung-up"
    master, slave = os.openpty()
    command = [sys.executable, "-m", "stereo_bench", "campaign", "run", str(long_settle_plan_file), "--out", str(out),
               "--yes"]  # not --quiet: it writes progress to the terminal until it hangs up
    process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=slave, stderr=slave)
    os.close(slave)
    written = bytearray()
    try:
        stream = out / "documents.jsonl"
        deadline = time.monotonic() + 120
        while process.poll() is None and time.monotonic() < deadline:
            if select.select([master], [], [], 0.05)[0]:
                written += os.read(master, 65536)  # the terminal is read, as a terminal would be
            if stream.exists() and stream.read_text().count('"kind": "move"') == 2:
                break
        assert process.poll() is None, written.decode(errors="replace")
    finally:
        os.close(master)  # the terminal hangs up ...
    process.send_signal(signal.SIGHUP)  # ... and its session's processes get SIGHUP
    assert process.wait(timeout=60) == 130
    stop = SessionReader(out).stops()[-1]
    # A progress line written between the hang-up and the signal fails first, and stops the run just the same.
    assert stop.exit_status == "interrupted"
    assert stop.reason in ("stopped by SIGHUP", "stopped: the terminal of stderr hung up")
    assert len(SessionReader(out).completed_config_ids()) == 3
    resumed = _run_printed(stop.resume_command)
    assert resumed.returncode == 0, resumed.stderr
    assert numbers(out) == numbers(small_reference)


@pytest.mark.slow  # a campaign, then its resume
def test_a_closed_stdout_stops_the_run_at_a_safe_point_with_status_141(plan_file, tmp_path, small_reference):
    """``campaign run --json | head -1``: the reader goes away after the first line. It failed the run (exit 2, or
    134 when a renderer was still being built at exit); now the run stops as at Ctrl-C, says so in one line on
    stderr, exits 141 (docs/EXIT_STATUS.md) and the session resumes."""
    out = tmp_path / "piped"
    process = _launch(plan_file, out, "--json")
    first = json.loads(process.stdout.readline())
    process.stdout.close()  # head -1 exits
    stderr = process.stderr.read()
    assert process.wait(timeout=120) == 141, stderr
    assert first["type"] == "start"
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stereo-bench campaign: stdout closed (its reader went away)")
    stop = SessionReader(out).stops()[-1]
    assert stop.exit_status == "interrupted" and stop.reason == "stopped: the reader of stdout went away"
    assert lines[0].endswith(f"resume: {stop.resume_command}")
    resumed = _run_printed(stop.resume_command)
    assert resumed.returncode == 0, resumed.stderr
    assert numbers(out) == numbers(small_reference)


@pytest.mark.slow
def test_ctrl_c_twice_records_interrupted_with_the_resume_command(long_settle_plan_file, tmp_path):
    out = tmp_path / "aborted"
    process = _launch(long_settle_plan_file, out)
    _wait_for_the_last_move(process, out)
    process.send_signal(signal.SIGINT)
    time.sleep(0.02)  # two separate signals (the kernel merges two pending ones)
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    stop = SessionReader(out).stops()[-1]
    assert stop.exit_status == "interrupted"
    assert stop.resume_command == f"stereo-bench campaign run --out {out} --resume --yes"
    assert f"resume:   {stop.resume_command}" in stdout


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_replay_stopped_by_a_signal_exits_130_reports_nothing_and_leaves_no_out(small_reference, tmp_path, signum):
    """Ctrl-C while the replay runs its configurations: the runner stopped, and the replay went on to announce the
    partial recording as a new session, comparing it ("not reproduced" for every configuration), exit 1."""
    out = tmp_path / "replayed"
    command = [sys.executable, "-m", "stereo_bench", "replay", str(small_reference), "--out", str(out)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while process.poll() is None and time.monotonic() < deadline:  # until the replay moves to its first configuration
        streams = list(tmp_path.glob(f".{out.name}.*/documents.jsonl"))
        if streams and '"kind": "move"' in streams[0].read_text():
            break
        time.sleep(0.01)
    assert process.poll() is None, process.communicate()
    process.send_signal(signum)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stdout + stderr
    assert stdout == "" and stderr.strip() == "stereo-bench replay: interrupted"
    assert sorted(path.name for path in tmp_path.iterdir()) == []  # neither --out nor its temporary directory


def test_a_second_interrupt_stops_at_once_and_the_session_still_resumes(tmp_path):
    """KeyboardInterrupt (the second Ctrl-C) mid-capture, while the first stop is pending: no waiting for
    analyses, yet the stop document says 'interrupted', with the resume command, and resume completes."""
    config = small_config()
    out = tmp_path / "at-once"
    control = RunControl()

    # The second configuration's first frame: Ctrl-C, and again.
    bench_interrupted_twice = interrupt_at_presentation(control, "present_target", 3)

    summary = run_campaign(config, out, yes=True, control=control, bench_factory=bench_interrupted_twice,
                           resume_command="stereo-bench campaign run small.toml --out at-once --resume")
    assert summary.exit_status == "interrupted" and "second interrupt" in summary.reason
    stop = SessionReader(out).stops()[-1]
    assert stop.exit_status == "interrupted" and stop.resume_command.endswith("--resume")
    resumed = run_campaign(config, out, resume=True, yes=True)
    assert resumed.exit_status == "success" and len(SessionReader(out).completed_config_ids()) == 4


def test_stop_request_leaves_a_resumable_session_and_resume_runs_the_recorded_plan(tmp_path, monkeypatch):
    config = small_config()
    out = tmp_path / "stopped"
    control = RunControl()
    summary = run_campaign(config, out, yes=True, bench_factory=stop_at_move(control, 2), control=control,
                           resume_command="stereo-bench campaign run small.toml --out stopped --resume")
    assert summary.exit_status == "interrupted"
    stop = SessionReader(out).stops()[-1]
    assert stop.exit_status == "interrupted" and stop.resume_command.endswith("--resume")
    done = SessionReader(out).completed_config_ids()
    assert 1 <= len(done) < 4
    # Today's planner disagrees with the recorded plan (as after an upgrade): the recorded plan runs.
    import stereo_bench.campaign.execute.planned as execute  # where plan_drift re-plans

    real_expand_plan = execute.expand_plan
    monkeypatch.setattr(execute, "expand_plan", lambda config: [
        dataclasses.replace(c, feasible=False, reason="a stricter rule") for c in real_expand_plan(config)])
    resumed = run_campaign(config, out, resume=True, yes=True)
    assert resumed.exit_status == "success" and resumed.skipped == len(done)
    assert "plan[0].feasible: recorded true, now false" in resumed.plan_drift
    reader = SessionReader(out)
    assert len(reader.completed_config_ids()) == 4 and reader.resumes()[0].plan_drift == resumed.plan_drift
    assert {row.status for row in reader.results()} == {"measured", "infeasible"}


@pytest.mark.replay
def test_replay_of_the_shipped_session_reproduces_its_results(capsys):
    """Recorded on another CPU: bit-identical where the BLAS kernels are the recording's, else within the
    tolerance of docs/REPLAY.md (was: exit 1 on any CPU whose kernels give other last digits)."""
    assert main(["replay", str(SAMPLE_SESSION), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["compared"] >= 2 and report["differences"] == []
    assert report["identical"] + report["reproduced"] == report["compared"]
    largest = report["largest_deviation"]
    assert (largest is None) == (report["reproduced"] == 0)
    if largest is not None:  # another CPU's kernels: the last digits moved, far inside the tolerance
        assert largest["verdict"] == "reproduced" and largest["relative_to_scale"] <= 1e-9
    assert report["numeric_environment"]["recorded"] is None  # recorded before the environment was kept


@pytest.mark.replay
def test_replay_runs_the_recorded_plan_and_reports_drift(monkeypatch):
    """A change in the feasibility code must not make a recorded session unreplayable."""
    import stereo_bench.campaign.execute.planned as execute  # where plan_drift re-plans

    real_expand_plan = execute.expand_plan
    monkeypatch.setattr(execute, "expand_plan", lambda config: [
        dataclasses.replace(c, feasible=False, reason="a stricter rule") for c in real_expand_plan(config)])
    summary = replay_session(SAMPLE_SESSION)
    assert summary.compared == 2 and summary.identical + summary.reproduced == 2 and summary.differences == []
    assert "plan[0].feasible: recorded true, now false" in summary.plan_drift


@pytest.mark.replay
def test_replay_into_a_new_session_and_reanalysis(tmp_path, capsys):
    from stereo_bench.campaign.config import recorded_campaign
    from stereo_bench.campaign.reproduce import RecordedContext, compare_rows

    out = tmp_path / "replayed"
    assert main(["replay", str(SAMPLE_SESSION), "--out", str(out)]) == 0
    # The new session's numbers are the recording's within the replay tolerance (bit-identical on the
    # recording's kernels), and it records the numeric environment it was computed in.
    recorded, replayed = SessionReader(SAMPLE_SESSION), SessionReader(out)
    context = RecordedContext.of(recorded_campaign(recorded.start().config), recorded)
    new_rows = {row["config_id"]: row for row in [row.stored() for row in replayed.results()]}
    assert new_rows.keys() == {row.config_id for row in recorded.results()}
    for row in [row.stored() for row in recorded.results()]:
        assert all(d.verdict != "differs" for d in compare_rows(row, new_rows[row["config_id"]], context)), row
    assert replayed.start().numeric_environment.numpy == np.__version__
    assert SessionReader(out).start().bench == "replay"
    # Recorded before [sim] existed, on the ideal bench: the replay records that bench, not today's default.
    assert "sim" not in SessionReader(SAMPLE_SESSION).start().config
    assert SessionReader(out).start().config["sim"]["profile"] == "ideal"
    assert main(["replay", str(SAMPLE_SESSION), "--intrinsics", "fixed"]) == 2  # a re-analysis needs --out
    assert "--out" in capsys.readouterr().err
    fixed = tmp_path / "fixed"
    assert main(["replay", str(SAMPLE_SESSION), "--intrinsics", "fixed", "--out", str(fixed)]) == 0
    assert "2 measured again" in capsys.readouterr().out
    recorded = {row["config_id"]: row for row in results_csv(SAMPLE_SESSION)}
    reanalysed = {row["config_id"]: row for row in results_csv(fixed)}
    assert reanalysed.keys() == recorded.keys()
    reader = SessionReader(fixed)
    assert reader.start().config["extrinsics"]["intrinsics"] == "fixed"
    for config_id, row in reanalysed.items():
        if recorded[config_id]["status"] != "measured":
            assert row["status"] == recorded[config_id]["status"]  # carried over
            continue
        # Measured again, with the intrinsics held fixed: close to the truth, and not the joint numbers.
        assert row["status"] == "measured" and int(row["n_squares"]) == int(recorded[config_id]["n_squares"])
        assert abs(float(row["error_mm"])) < 0.05
        assert row["rms_px"] != recorded[config_id]["rms_px"]
        (calibration,) = reader.events(config_id, kind="calibration")
        assert calibration.data.mode == "fixed"


def test_a_reanalysis_that_measures_nothing_fails(tmp_path, capsys, monkeypatch):
    from stereo_bench.campaign import runner
    from stereo_bench.campaign.analysis import AnalysisError

    def calibration_impossible(*args, **kwargs):
        raise AnalysisError("calibration board found in only 0 of 7 view pairs (need 3)")

    monkeypatch.setattr(runner, "calibrate_configuration", calibration_impossible)
    assert main(["replay", str(SAMPLE_SESSION), "--intrinsics", "fixed", "--out", str(tmp_path / "none")]) == 1
    assert "0 measured again" in capsys.readouterr().out
    assert {row["status"] for row in results_csv(tmp_path / "none")} == {"failed", "infeasible"}


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
def test_batch_reanalysis_of_several_sessions_goes_through_the_executor(executor, tmp_path, capsys, request):
    args = ["--executor", executor, "--workers", "2"]
    if executor == "dask":
        args = ["--executor", "dask", "--scheduler", request.getfixturevalue("dask_scheduler")]
    first, second = tmp_path / "first", tmp_path / "second"
    shutil.copytree(SAMPLE_SESSION, first)
    shutil.copytree(SAMPLE_SESSION, second)
    code = main(["replay", str(first), str(second), "--intrinsics", "fixed", "--out", str(tmp_path / "re"),
                 *args, "--json"])
    assert code == 0
    reports = json.loads(capsys.readouterr().out)["sessions"]
    assert [Path(r["session"]).name for r in reports] == ["first", "second"]
    assert [r["measured"] for r in reports] == [2, 2]
    # Same frames, same pipeline: the two re-analyses agree to the last digit, whichever worker ran them.
    assert numbers(tmp_path / "re" / "first") == numbers(tmp_path / "re" / "second")


@pytest.mark.replay
def test_a_frame_without_the_target_is_captured_again_and_replays(tmp_path):
    config = small_config()
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
    assert len(missed) == 1 and missed[0].data.retry == 0 and missed[0].data.missing == ["left", "right"]
    first = [e.data for e in reader.events(config_id=missed[0].config_id, kind="measurement_frame")]
    assert [(d.index, d.retry) for d in first][:2] == [(0, 0), (0, 1)]
    # The replay of this fresh session asks for the same re-capture and finds the same numbers.
    assert main(["replay", str(out)]) == 0


def test_the_result_line_shows_the_expanded_uncertainty_and_says_when_only_noise_is_known():
    from stereo_bench.cli.progress import format_row as _format_row

    row = {"config_id": "B250_Z700_A90", "baseline_mm": 250.0, "distance_mm": 700.0, "alpha_deg": 90.0,
           "status": "measured", "square_mean_mm": 28.2697, "error_mm": 1.2697, "sigma_mm": 0.00004,
           "n_squares": 279, "rms_px": 0.032, "U_expanded_mm": 2.4431}
    assert "error +1.2697 +- 2.4431 mm (U, k=2)" in _format_row(row)
    for unknown in (None, math.nan):  # a session recorded without a budget, or a budget that is unknown
        line = _format_row({**row, "U_expanded_mm": unknown})
        assert "+- 0.0000 mm (sigma of image noise only)" in line and "k=2" not in line
