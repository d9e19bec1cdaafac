"""The benches a campaign runs on, the operators who do its manual steps, and what stopping does.

Bring-up (a real GRBL controller, simulated cameras), fixed extrinsics on every bench, prompts as
recorded steps where the first operator to answer wins, a stop that cuts a settle short, and no
motion when nothing is left to run.
"""

from __future__ import annotations

import io
import json
import os
import shlex
import shutil
import threading
from dataclasses import replace

import pytest

from drivers.sim.grbl.emulator import GrblEmulator
from drivers.sim.grbl.faults import AlarmMidMove, VanishMidMove
from drivers.sim.grbl.firmware import DEFAULT_AXES
from stereo_bench.campaign.config import load_campaign
from stereo_bench.campaign.documents import MoveEvent
from stereo_bench.campaign.execute import RunControl, replay_session, run_campaign
from stereo_bench.campaign.operator import (
    OperatorAbsent,
    OperatorDesk,
    Prompt,
    SimulatedOperator,
    StopRequested,
    TerminalOperator,
)
from stereo_bench.campaign.session import SessionReader
from stereo_bench.cli import main
from tests.campaigns import SAMPLE_SESSION, SMALL, act_at_move, motion_commands, small_config, transcript_commands

HALF_RES = {"optics": {"width_px": 960, "height_px": 540, "pixel_um": 6.0}}


# -- bring-up: the real controller moves, simulated cameras render from what it reports ----------------------------


def test_bring_up_mode_renders_from_the_positions_the_controller_reports(tmp_path, capsys):
    """``campaign run`` end to end with [rig] kind = "grbl" and simulated cameras. A GRBL controller on a
    pty stands in for the real one, in Grbl's negative machine space (X = B - 350); its X axis moves in 4 mm
    steps, so for B = 100 mm (X = -250) it lands and reports X = -252, B = 98 mm: the cameras must see 98."""
    coarse_x = {"X": replace(DEFAULT_AXES["X"], steps_per_unit=0.25)}
    plan = tmp_path / "bring-up.toml"
    out = tmp_path / "bring-up"
    with GrblEmulator(axes="XYZ", axis_specs=coarse_x, time_scale=20.0) as controller:
        rig = (f'[rig]\nkind = "grbl"\nport = "{controller.tty_path}"\n'
               '[rig.quantities.baseline_mm]\naxis = "X"\noffset = -350\nmin = 0\nmax = 350\ntolerance = 3.0\n')
        text = SMALL.replace("[rig]\ntime_scale = 50\n", rig)
        plan.write_text(text.replace("alpha_deg = [90, 35]", "alpha_deg = [90]"))
        assert load_campaign(plan).bench_kind == "bring-up"
        assert main(["campaign", "run", str(plan), "--out", str(out), "--yes", "--quiet"]) == 0
        assert controller.machine_position()["X"] == -200.0  # B = 150 mm: a whole number of steps
    assert "campaign success" in capsys.readouterr().out
    reader = SessionReader(out)
    assert reader.start().bench == "bring-up"
    reported = {e.config_id: e.data.rig.baseline_mm for e in reader.events(kind="move")}
    assert reported == {"B100_Z450_A90": 98.0, "B150_Z450_A90": 150.0}
    rows = {row["config_id"]: row for row in [row.stored() for row in reader.results()]}
    for config_id, baseline in reported.items():
        # The stereo calibration finds the baseline the cameras were rendered at: the reported one.
        assert rows[config_id]["status"] == "measured" and abs(rows[config_id]["error_mm"]) < 0.05
        assert rows[config_id]["baseline_estimated_mm"] == pytest.approx(baseline, abs=0.2)
    sent = transcript_commands(next((out / "transcripts").glob("serial-*.jsonl")))
    assert sent.index("$H") < min(i for i, line in enumerate(sent) if "G0" in line)  # homed, then moved


def _bring_up_plan(path, port: str, *, one_configuration: bool = False):
    text = SMALL.replace("[rig]\ntime_scale = 50\n", f'[rig]\nkind = "grbl"\nport = "{port}"\n'
                                                     "[rig.controller]\nconnect_timeout_s = 0.5\n")
    if one_configuration:
        text = text.replace("baseline_mm = [100, 150]", "baseline_mm = [100]").replace("[90, 35]", "[90]")
    path.write_text(text)
    return path


@pytest.mark.parametrize("port", ["missing", "/dev/null", "directory", "silent pty"])
@pytest.mark.parametrize("out_before", ["absent", "empty"])
def test_a_run_refused_before_anything_moved_leaves_out_as_it_was(tmp_path, capsys, port, out_before):
    """A port that is not there, not a serial port, or a controller that never answers is the user's to fix: one
    line, exit 2 (docs/EXIT_STATUS.md), and --out as it was (it held a failed session, so the corrected command
    was refused: a session is never written over)."""
    master = None
    if port == "missing":
        port = str(tmp_path / "no-tty")
    elif port == "directory":
        port = str(tmp_path)
    elif port == "silent pty":  # a pty nobody serves: no banner, no answer to '?'
        master, slave = os.openpty()
        port = os.ttyname(slave)
    out = tmp_path / "nested" / "s" if out_before == "absent" else tmp_path / "s"
    if out_before == "empty":
        out.mkdir()  # the user's: it stays, empty
    plan = _bring_up_plan(tmp_path / "bring-up.toml", port)
    try:
        assert main(["campaign", "run", str(plan), "--out", str(out), "--yes", "--quiet"]) == 2
    finally:
        if master is not None:
            os.close(master)
            os.close(slave)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and port in err[0] and f"nothing was recorded: --out {out} is as it was" in err[0], err
    if out_before == "absent":
        assert not (tmp_path / "nested").exists()  # nor the parent the run created for it
    else:
        assert out.is_dir() and not any(out.iterdir())


def test_the_corrected_command_runs_where_a_refused_one_left_out(tmp_path, capsys):
    out = tmp_path / "s"
    plan = _bring_up_plan(tmp_path / "bring-up.toml", str(tmp_path / "no-tty"), one_configuration=True)
    assert main(["campaign", "run", str(plan), "--out", str(out), "--yes", "--quiet"]) == 2
    with GrblEmulator(axes="XYZ", time_scale=50.0) as controller:
        _bring_up_plan(plan, controller.tty_path, one_configuration=True)  # the port corrected
        assert main(["campaign", "run", str(plan), "--out", str(out), "--yes", "--quiet"]) == 0
    assert SessionReader(out).attempts() == [1] and len(SessionReader(out).completed_config_ids()) == 1


def test_a_resume_refused_at_connect_keeps_the_session_and_says_how_to_resume(small_copy, capsys, monkeypatch):
    """Only a new session is removed: a resume whose controller is not there keeps all it had (its stream only
    grows, by this attempt's resume and stop), and the line says how to resume once it is fixed."""
    import stereo_bench.campaign.bench as bench_module
    from drivers.rig.grbl import GrblConnectionError

    def no_controller(config, **options):
        raise GrblConnectionError("cannot open serial port /dev/ttyGONE: No such file or directory")

    monkeypatch.setattr(bench_module, "simulated_bench", no_controller)
    # The session as a crash leaves it (no stop): a finished one is not reopened at all (test below).
    stream = small_copy / "documents.jsonl"
    *kept, last = stream.read_bytes().splitlines(keepends=True)
    assert json.loads(last)["type"] == "stop"
    stream.write_bytes(b"".join(kept))
    before = stream.read_bytes()
    assert main(["campaign", "run", "--out", str(small_copy), "--resume", "--yes", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/dev/ttyGONE" in err[0], err
    assert f"session {small_copy} stopped as failed; once fixed: stereo-bench campaign run --out {small_copy} " \
           "--resume --yes" in err[0]
    assert (small_copy / "documents.jsonl").read_bytes().startswith(before)
    assert SessionReader(small_copy).stops()[-1].exit_status == "failed"


# -- a controller fault mid-campaign: soft reset, then home; a rig that cannot be recovered fails the campaign ------


def test_an_alarm_mid_move_is_reset_and_homed_away_and_the_campaign_goes_on(tmp_path, capsys):
    """ALARM:1 halts the controller: it answers nothing but a soft reset, so the recovery resets first (homing
    alone was refused, and the campaign ended as 'interrupted', exit 130), then homes; the configuration fails
    with the alarm, the next one is measured."""
    out = tmp_path / "s"
    with GrblEmulator(axes="XYZ", time_scale=50.0, faults=[AlarmMidMove(code=1, fraction=0.5)]) as controller:
        plan = _bring_up_plan(tmp_path / "bring-up.toml", controller.tty_path)
        plan.write_text(plan.read_text().replace("alpha_deg = [90, 35]", "alpha_deg = [90]"))
        assert main(["campaign", "run", str(plan), "--out", str(out), "--yes", "--quiet"]) == 0
    reader = SessionReader(out)
    rows = {row["config_id"]: row for row in [row.stored() for row in reader.results()]}
    assert rows["B100_Z450_A90"]["status"] == "failed" and "ALARM:1: Hard limit" in rows["B100_Z450_A90"]["reason"]
    assert rows["B150_Z450_A90"]["status"] == "measured"
    (recovered,) = reader.events(kind="rig_recovered")
    assert recovered.data.action == "soft reset, then homed after a failed move"
    assert reader.stops()[-1].exit_status == "success"
    records = [json.loads(line) for line in next((out / "transcripts").glob("serial-*.jsonl")).read_text().splitlines()]
    sent = [r["data"] for r in records if r.get("dir") == "tx"]
    reset_at = sent.index("\x18")
    assert "$H\n" in sent[reset_at:], "homed after the reset"


@pytest.mark.parametrize("fault", ["alarm:1 on a rig without homing", "vanish"])
def test_a_rig_that_cannot_be_recovered_fails_the_campaign_in_one_line_and_resumes(tmp_path, capfd, fault):
    """Exit status 1 (docs/EXIT_STATUS.md: a controller fault during work), one line on stderr naming the fault
    and the recovery step that failed, the stop document 'failed' with both and the command that resumes, which
    completes the session once the controller is back. (It ended 'interrupted': exit 130, nothing on stderr.)"""
    port = tmp_path / "grbl"  # a stable name for the controller, as /dev/serial/by-id/... is at the bench
    plan = _bring_up_plan(tmp_path / "bring-up.toml", str(port), one_configuration=True)
    without_homing = fault != "vanish"
    if without_homing:  # a hard limit on a rig without homing: after the reset it stays in Alarm and cannot be homed
        plan.write_text(plan.read_text().replace("[rig.controller]", "homing = false\n[rig.controller]"))
        injected = AlarmMidMove(code=1, fraction=0.5)
        expected = ["rig: GRBL ALARM:1: Hard limit triggered", "(at B100_Z450_A90); recovery (soft reset, then "
                    "homing) failed at the homing: GRBL error:5 for '$H'"]
    else:
        injected = VanishMidMove(fraction=0.5)
        expected = ["rig: lost the connection to", "recovery (soft reset, then homing) failed at the soft reset"]
    out = tmp_path / "s"
    with GrblEmulator(axes="XYZ", time_scale=50.0, homing_enabled=not without_homing, faults=[injected]) as emulator:
        port.symlink_to(emulator.tty_path)
        code = main(["campaign", "run", str(plan), "--out", str(out), "--yes", "--quiet"])
    captured = capfd.readouterr()
    errors = [line for line in captured.err.splitlines() if "error:" in line]
    assert code == 1 and len(errors) == 1, captured.err
    resume = f"stereo-bench campaign run --out {out} --resume --yes"
    assert errors[0].startswith("stereo-bench campaign: error: ") and all(text in errors[0] for text in expected)
    assert errors[0].endswith(f"(session {out} stopped as failed; once fixed: {resume})")
    assert "campaign failed" in captured.out and "resume:" not in captured.out
    reader = SessionReader(out)
    stop = reader.stops()[-1]
    assert stop.exit_status == "failed" and all(text in stop.reason for text in expected)
    assert stop.resume_command == resume and reader.events(kind="rig_unrecoverable")
    assert not reader.completed_config_ids()  # the configuration the fault struck runs again on resume
    with GrblEmulator(axes="XYZ", time_scale=50.0, homing_enabled=not without_homing) as controller:  # it is back
        port.unlink()
        port.symlink_to(controller.tty_path)
        assert main(shlex.split(resume)[1:] + ["--quiet"]) == 0
    assert SessionReader(out).completed_config_ids() == {"B100_Z450_A90"}


# -- fixed extrinsics work on every bench ------------------------------------------------------------------------


@pytest.mark.replay
def test_fixed_extrinsics_measure_on_the_simulated_rig_and_replay_from_inside_the_session(tmp_path):
    """The sample session's calibration at B = 100 mm, alpha = 90 deg, used as fixed extrinsics."""
    calib_dir = tmp_path / "calib"
    shutil.copytree(SAMPLE_SESSION / "calib" / "B100_Z450_A90" / "a1", calib_dir)
    config = small_config(extrinsics={"mode": "fixed", "calib_dir": str(calib_dir)},
                          plan={"baseline_mm": [100], "distance_mm": [400, 500], "alpha_deg": [90]})
    out = tmp_path / "fixed"
    summary = run_campaign(config, out, yes=True)
    assert summary.counts() == {"measured": 2}
    for row in summary.rows:  # the target was placed at each distance (it used to stay at 0: blank frames)
        assert abs(row["error_mm"]) < 0.05 and row["depth_mm"] == pytest.approx(row["distance_mm"], abs=5.0)
    reader = SessionReader(out)
    assert not reader.events(kind="calibration_view")
    (used,) = reader.events(kind="calibration", config_id=None)
    assert used.data.board == f"fixed: {calib_dir}"
    shutil.rmtree(calib_dir)  # the replay reads the calibration the session recorded, nothing outside it
    replayed = replay_session(out)
    assert replayed.identical == replayed.compared == 2


# -- operators ---------------------------------------------------------------------------------------------------


class _Web:
    """A second operator (as a live page would be) that answers after ``delay_s`` unless withdrawn."""

    name = "web"

    def __init__(self, delay_s: float | None):
        self.delay_s = delay_s
        self.withdrawn = []

    def offer(self, ticket) -> None:
        if self.delay_s is not None:
            threading.Timer(self.delay_s, ticket.answer, args=(self.name,)).start()

    def withdraw(self, ticket) -> None:
        self.withdrawn.append(ticket.prompt)


def test_the_first_operator_to_answer_wins_and_the_other_withdraws():
    read_end, write_end = os.pipe()
    with open(read_end, encoding="utf-8") as stdin, open(write_end, "w", encoding="utf-8") as keyboard:
        terminal = TerminalOperator(stdin, io.StringIO())
        web = _Web(delay_s=0.05)
        desk = OperatorDesk([terminal, web])
        stop = threading.Event()
        answer = desk.ask(Prompt("target", "move the target to Z = 400 mm"), stop=stop)
        assert answer.operator == "web" and answer.waited_s >= 0.05
        web.delay_s = None  # the page is closed: the terminal answers the next prompt
        threading.Timer(0.05, lambda: (keyboard.write("\n"), keyboard.flush())).start()
        second = Prompt("target", "move the target to Z = 500 mm")
        assert desk.ask(second, stop=stop).operator == "terminal"
        assert web.withdrawn[-1] == second
        threading.Timer(0.05, stop.set).start()
        with pytest.raises(StopRequested):  # a stop request cuts a prompt short
            desk.ask(Prompt("target", "move the target to Z = 600 mm"), stop=stop)
        keyboard.close()
        with pytest.raises(OperatorAbsent, match="terminal: standard input is closed"):
            OperatorDesk([terminal]).ask(Prompt("target", "anyone?"), stop=threading.Event())


def test_manual_steps_are_prompts_the_runner_records_and_the_rig_never_prompts(tmp_path):
    """The target distance and a hand-set tilt: the runner asks (recorded), the rig only moves its motors."""
    simulator = SimulatedOperator()
    config = small_config(rig={"quantities": {"tilt_left_deg": {"axis": "manual"},
                                              "tilt_right_deg": {"axis": "manual"}}},
                          plan={"baseline_mm": [100], "distance_mm": [450, 500], "alpha_deg": [90]},
                          capture={"calibration_views": 6, "frames_per_config": 1, "settle_s": 0.1})
    summary = run_campaign(config, tmp_path / "manual", operators=[simulator])
    assert summary.counts() == {"measured": 2}
    prompts = [e.data for e in SessionReader(tmp_path / "manual").events(kind="prompt")]
    assert [(p.quantity, p.value) for p in prompts] == [
        ("tilt_left_deg", 0.0), ("tilt_right_deg", 0.0), ("target_distance_mm", 450.0),
        ("target_distance_mm", 500.0)]
    assert {p.answered_by for p in prompts} == {"simulator"} and len(simulator.prompts) == 4
    moves = SessionReader(tmp_path / "manual").events(kind="move")
    assert all(m.data.rig.sources["target_distance_mm"] == "unknown (manual)" for m in moves)


# -- stopping ------------------------------------------------------------------------------------------------------


def test_a_stop_request_cuts_a_settle_short(tmp_path):
    # the longest settle a config allows (MAX_SETTLE_S, 60 s): 30 s at time_scale 2
    config = small_config(capture={"settle_s": 60.0}, rig={"time_scale": 2.0})
    control = RunControl()

    def stop_soon_after_the_first_move(document):
        if isinstance(document, MoveEvent):
            threading.Timer(0.2, control.request_stop).start()

    summary = run_campaign(config, tmp_path / "settle", yes=True, control=control,
                           subscribers=[stop_soon_after_the_first_move])
    assert summary.exit_status == "interrupted"
    reader = SessionReader(tmp_path / "settle")
    (move,) = reader.events(kind="move")
    waited = reader.stops()[-1].monotonic - move.monotonic
    assert waited < 15.0  # the settle alone would have taken 30 s
    assert not reader.events(kind="calibration_view")


def test_nothing_moves_when_nothing_is_left_to_run(tmp_path, small_copy):
    # Resuming a finished session: the session is left as it was (no attempt appended) and the bench is not opened
    # (no connection, so no controller reset, no homing, no motion).
    before = {path: path.read_bytes() for path in small_copy.rglob("*") if path.is_file()}
    summary = run_campaign(small_config(), small_copy, resume=True, yes=True)
    assert summary.exit_status == "success" and summary.skipped == 4 and summary.rows == []
    assert {path: path.read_bytes() for path in small_copy.rglob("*") if path.is_file()} == before
    assert SessionReader(small_copy).attempts() == [1]
    assert not (small_copy / "transcripts" / "serial-a2.jsonl").exists()
    # A campaign whose every configuration is infeasible: recorded with the reasons, and nothing moves.
    out = tmp_path / "infeasible"
    summary = run_campaign(small_config(plan={"baseline_mm": [100], "distance_mm": [450], "alpha_deg": [35]}), out,
                           yes=True)
    assert summary.counts() == {"infeasible": 1}
    assert motion_commands(out / "transcripts" / "serial-a1.jsonl") == []
    assert not SessionReader(out).events(kind="home")


def test_pause_holds_the_run_at_a_step_boundary_until_resumed(tmp_path):
    config = small_config(plan={"baseline_mm": [100], "distance_mm": [450], "alpha_deg": [90]},
                          capture={"settle_s": 5.0})
    control = RunControl()

    def pause_after_the_move():  # the step boundary after the move (and its settle) holds the run
        control.request_pause()
        threading.Timer(0.5, control.request_resume).start()

    summary = run_campaign(config, tmp_path / "paused", yes=True, control=control,
                           bench_factory=act_at_move(1, pause_after_the_move))
    assert summary.counts() == {"measured": 1}
    reader = SessionReader(tmp_path / "paused")
    first_view = reader.events(kind="calibration_view")[0]
    (move,) = reader.events(kind="move")
    assert first_view.monotonic - move.monotonic >= 0.5  # held until resumed


def test_the_runner_owns_prompting_grbl_rig_gets_no_prompt(tmp_path):
    from stereo_bench.campaign.bench import open_bench

    with open_bench(small_config(), operators=[SimulatedOperator()], transcript=None) as bench:
        # GrblRig has no prompt path at all now (issue 21): the runner's OperatorDesk is the one.
        assert bench.kind == "simulated" and getattr(bench.rig, "prompt", None) is None


# -- the simulated presenter stages what each configuration and design visit captures --------------------------------


class _StagingBench:
    """Records what a SimulatedPresenter stages (the scene kinds, in order); renders nothing."""

    def __init__(self, optics):
        self.left_model, self.right_model = optics.camera_model("left"), optics.camera_model("right")
        self.staged: list[list[str]] = []

    def warm_up(self, *targets) -> None:
        pass

    def begin_configuration(self, config_id, *, targets, arrivals) -> None:
        pass

    def stage(self, scenes, *, at, ahead) -> None:
        self.staged.append([kind for kind, *_ in scenes])


@pytest.mark.parametrize("mode", ["per-config", "kinematic", "nominal"])
def test_the_simulated_presenter_stages_what_plan_steps_captures(mode):
    """A design visit (kinematic, nominal) captures calibration views only: the presenter stages its boards, not
    the measurement frames a configuration takes; each group of plan_steps captures what planned_captures says."""
    import functools

    from stereo_bench.campaign.bench import SimulatedPresenter, planned_captures
    from stereo_bench.campaign.execute import CampaignPlan
    from stereo_bench.campaign.plan import CaptureCalibration, CaptureMeasurement
    from stereo_bench.campaign.runner import group_steps

    config = small_config(extrinsics={"mode": mode})
    plan = CampaignPlan.of(config)
    runnable = {c.config_id: c for c in [*plan.visits, *plan.configurations] if c.runnable}
    assert (len(plan.visits) > 0) == (mode != "per-config")
    for config_id, group in group_steps(plan.steps):
        if config_id in runnable:
            views = sum(step.n_views for step in group if isinstance(step, CaptureCalibration))
            frames = sum(step.n_frames for step in group if isinstance(step, CaptureMeasurement))
            assert planned_captures(config, runnable[config_id]) == (views, frames), config_id

    bench = _StagingBench(config.cameras.optics)
    presenter = SimulatedPresenter(bench, config.calibration_board.build(), config.target.build(), seed=config.seed,
                                   stage_ahead=functools.partial(planned_captures, config))
    try:
        for configuration in runnable.values():
            views, frames = planned_captures(config, configuration)
            presenter.begin_configuration(configuration)
            if views:
                presenter.prepare_calibration(views)  # waits for the staging thread
            else:
                presenter._planned.result()
            assert bench.staged[-1] == ["board"] * views + ["target"] * frames, configuration.config_id
    finally:
        presenter.close()
    assert len(bench.staged) == len(runnable)
