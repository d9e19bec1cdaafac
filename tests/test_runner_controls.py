"""The runner's operator controls: pause (feed hold mid-move, resumed), discard the last calibration view,
capture now, and lending the cameras to a preview only while nothing is captured.

All on the simulated rig (the real GRBL driver against the emulator on a pty), compared with the small
reference session recorded without any of it: the controls must not change a single recorded number.
"""

from __future__ import annotations

import io
import json
import os
import threading
import time

import numpy as np

from stereo_bench.campaign.bench import simulated_bench
from stereo_bench.campaign.camera_gate import CameraGate
from stereo_bench.campaign.execute import RunControl, run_campaign
from stereo_bench.campaign.operator import (
    CAPTURE_NOW,
    CONTINUE,
    DISCARD_LAST_VIEW,
    Prompt,
    TerminalOperator,
    Ticket,
)
from stereo_bench.campaign.session import SessionReader
from stereo_bench.cli import main
from tests.campaigns import numbers, small_config


class ScriptedOperator:
    """Answers every prompt at once, with the next scripted action for calibration prompts (else continue)."""

    name = "script"

    def __init__(self, actions: list[str], on_offer=None):
        self.actions = list(actions)
        self.offered: list[Prompt] = []
        self.on_offer = on_offer

    def offer(self, ticket: Ticket) -> None:
        self.offered.append(ticket.prompt)
        if self.on_offer is not None:
            self.on_offer(ticket)
        wants = [a for a in ticket.prompt.actions if a != CONTINUE]
        action = self.actions.pop(0) if wants and self.actions else CONTINUE
        ticket.answer(self.name, action)

    def withdraw(self, ticket: Ticket) -> None:
        return None


def prompting_bench(config, **options):
    """The simulated bench whose presenter also asks for every calibration view and a review, as at the bench."""
    bench = simulated_bench(config, **options)
    presenter = bench.presenter
    discarded: list[int] = []
    real_present = presenter.present_calibration_view

    def present_calibration_view(index):
        real_present(index)
        actions = (CONTINUE, CAPTURE_NOW, DISCARD_LAST_VIEW) if index > 0 else (CONTINUE, CAPTURE_NOW)
        return Prompt("calibration_view", f"view {index + 1}", config_id=presenter._configuration.config_id,
                      index=index, actions=actions)

    presenter.present_calibration_view = present_calibration_view
    presenter.review_calibration = lambda: Prompt("calibration_review", "review", actions=(CONTINUE, DISCARD_LAST_VIEW),
                                                  config_id=presenter._configuration.config_id)
    presenter.calibration_view_discarded = discarded.append
    presenter.discarded = discarded
    return bench


def test_discard_last_view_and_capture_now_are_recorded_and_the_session_replays(tmp_path, small_reference):
    out = tmp_path / "discard"
    # First configuration: view 0 by Capture now, view 1 kept, then view 1 discarded at view 2's prompt and
    # taken again, ..., and the last view discarded at the review (taken again, reviewed again).
    script = [CAPTURE_NOW, CONTINUE, DISCARD_LAST_VIEW, CONTINUE, CONTINUE, CONTINUE, CONTINUE, CONTINUE,
              DISCARD_LAST_VIEW]
    operator = ScriptedOperator(script)
    benches = []

    def factory(config, **options):
        benches.append(prompting_bench(config, **options))
        return benches[-1]

    summary = run_campaign(small_config(), out, operators=[operator], bench_factory=factory)
    assert summary.exit_status == "success"
    reader = SessionReader(out)
    first = summary.rows[0]["config_id"]
    discards = reader.events(kind="calibration_view_discarded", config_id=first)
    assert [(d.data.index, d.data.answered_by) for d in discards] == [(1, "script"), (5, "script")]
    assert benches[0].presenter.discarded == [1, 5]
    views = [e.data.index for e in reader.events(kind="calibration_view", config_id=first)]
    assert views == [0, 1, 1, 2, 3, 4, 5, 5]  # every capture recorded, the discarded ones too
    prompts = [p.data for p in reader.events(kind="prompt", config_id=first)]
    view_prompts = [p for p in prompts if p.prompt == "calibration_view"]
    assert view_prompts[0].action == CAPTURE_NOW and view_prompts[1].action is None
    assert view_prompts[2].action == DISCARD_LAST_VIEW
    assert [p.prompt for p in prompts].count("calibration_review") == 2
    # The same views were taken again (the simulator shows view i at the same pose with the same noise),
    # so the numbers are the reference's; and the replay serves the views that were kept.
    assert numbers(out) == numbers(small_reference)
    assert reader.events(kind="calibration", config_id=first)[0].data.views_used == list(range(6))
    assert main(["replay", str(out)]) == 0


def test_pause_mid_move_feed_holds_and_resume_finishes_the_move(tmp_path, small_reference):
    config = small_config(rig={"time_scale": 2})  # the 50 mm move to B = 150 takes ~0.7 s
    control = RunControl()
    out = tmp_path / "paused"
    moves: list[dict] = []
    paused_at: list[float] = []

    def factory(config, **options):
        bench = simulated_bench(config, **options)
        real_move = bench.rig.move_to

        def move_to(**request):
            moves.append(request)
            if len(moves) == 2:  # into the move to the second configuration: pause, then resume a bit later
                def pause_then_resume():
                    time.sleep(0.15)
                    paused_at.append(time.monotonic())
                    control.request_pause()
                    time.sleep(0.5)
                    control.request_resume()
                threading.Thread(target=pause_then_resume, daemon=True).start()
            return real_move(**request)

        bench.rig.move_to = move_to
        return bench

    summary = run_campaign(config, out, yes=True, control=control, bench_factory=factory)
    assert summary.exit_status == "success"
    reader = SessionReader(out)
    controls = [e.data for e in reader.events(kind="run_control")]
    assert [(c.action, c.feed_hold) for c in controls] == [("pause", True), ("resume", False)]
    sent = [json.loads(line) for line in (out / reader.events(kind="transcript")[0].files["serial"]).open()]
    realtime = [record["data"] for record in sent if record.get("dir") == "tx" and record["data"] in "!~"]
    assert realtime == ["!", "~"]  # one feed hold, one cycle start
    # The held move was finished: the rig reached B = 150 mm, and nothing recorded differs from the run
    # that was never paused.
    second = reader.events(kind="move")[1].data.rig
    assert abs(second.baseline_mm - 150.0) < 0.01
    assert numbers(out) == numbers(small_reference)


def test_stop_while_paused_leaves_a_resumable_session(tmp_path):
    control = RunControl()
    out = tmp_path / "stopped"

    def pause_then_stop(document):
        if document.type == "event" and document.kind == "run_control":
            threading.Timer(0.1, control.request_stop).start()

    control.request_pause()  # before the run starts: it holds at the first step
    summary = run_campaign(small_config(), out, yes=True, control=control, subscribers=[pause_then_stop],
                           resume_command="resume me")
    assert summary.exit_status == "interrupted"
    reader = SessionReader(out)
    assert reader.stops()[-1].resume_command == "resume me" and not reader.completed_config_ids()
    resumed = run_campaign(small_config(), out, resume=True, yes=True)
    assert resumed.exit_status == "success"


def test_the_cameras_are_lent_only_while_the_operator_works_and_previews_change_nothing(tmp_path, small_reference):
    """A preview that grabs a pair at every prompt (as the live page does) leaves the recording unchanged."""
    out = tmp_path / "previewed"
    benches, grabbed, lent_during_capture = [], [], []

    def preview_grab(ticket):
        bench = benches[0]
        with bench.camera_gate.borrowed() as allowed:
            assert allowed
            left, right, dt_s = bench.grab_preview()
            grabbed.append(left.shape)

    def factory(config, **options):
        bench = prompting_bench(config, **options)  # a prompt between showing each view and capturing it
        real_capture = bench.cameras.capture_pair

        def capture_pair():
            lent_during_capture.append(bench.camera_gate.lent_out)
            return real_capture()

        bench.cameras.capture_pair = capture_pair
        benches.append(bench)
        return bench

    summary = run_campaign(small_config(), out, operators=[ScriptedOperator([], on_offer=preview_grab)],
                           bench_factory=factory)
    assert summary.exit_status == "success" and len(grabbed) == 1 + 2 * (6 + 1)  # target, views, reviews
    assert not any(lent_during_capture)
    assert numbers(out) == numbers(small_reference)
    recorded = SessionReader(out)
    reference = SessionReader(small_reference)
    for ours, theirs in zip(recorded.events(kind="calibration_view"), reference.events(kind="calibration_view"),
                            strict=True):
        assert np.array_equal(recorded.frame(ours.frames["left"]), reference.frame(theirs.frames["left"]))


def test_camera_gate_waits_for_a_borrowed_grab_before_taking_the_cameras_back():
    gate = CameraGate()
    with gate.borrowed() as allowed:
        assert not allowed  # never lent: a preview does not grab
    order = []
    inside = threading.Event()

    def borrower():
        with gate.borrowed() as allowed:
            assert allowed
            inside.set()
            time.sleep(0.2)
            order.append("grab done")

    with gate.lent():
        thread = threading.Thread(target=borrower)
        thread.start()
        inside.wait(2)
    order.append("taken back")
    thread.join()
    assert order == ["grab done", "taken back"] and not gate.lent_out


def test_terminal_d_discards_where_the_prompt_allows_it_and_is_enter_elsewhere():
    read_fd, write_fd = os.pipe()
    with open(read_fd) as stream_in, open(write_fd, "w") as typed:
        terminal = TerminalOperator(stream_in=stream_in, stream_out=io.StringIO())
        allows = Ticket(Prompt("calibration_view", "view 2", index=1, actions=(CONTINUE, DISCARD_LAST_VIEW)), 1)
        terminal.offer(allows)
        typed.write("d\n")
        typed.flush()
        assert allows.wait(2) and allows.action == DISCARD_LAST_VIEW
        plain = Ticket(Prompt("target", "move the target"), 1)
        terminal.offer(plain)
        typed.write("d\n")
        typed.flush()
        assert plain.wait(2) and plain.action == CONTINUE and plain.answered_by == "terminal"
